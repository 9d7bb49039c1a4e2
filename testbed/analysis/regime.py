"""The linear regime of an experiment: the peaks of the quantities that bound it, and the check
that the analytic model tracks the truth plant flying it (`linearity`, the rule that sized
Scenario II: fit ≥ 99 % on every excited channel, second-order residual below a fifth of the
sensor noise on every fitted channel).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence


import numpy as np

from testbed.analysis.validation import fit_percent
from testbed.data import Experiment
from testbed.identification.prediction import predict
from testbed.models.linear import IX, STATES
from testbed.simulation.analytic import model_config
from testbed.simulation.scenario import Scenario, fly_scenario

__all__ = ["FITTED", "FIT_LIMIT", "RESIDUAL_LIMIT", "SEED", "Limits", "Linearity", "linearity", "peaks"]

SEED = 1  # the PRBS phases and noise streams the design is evaluated and flown with
FITTED = tuple(s for s in STATES if s != "z")  # a run's model.toml fits every state but depth
RESIDUAL_LIMIT = 0.2  # second-order residual / sensor noise on fitted channels (Scenario II's rule)
FIT_LIMIT = 99.0  # % fit of the analytic model on every excited channel, depth included


@dataclass(frozen=True)
class Limits:
    """Peak bounds of the linear regime: rates rad/s, angles rad, velocities m/s."""

    yaw_rate: float
    pitch_rate: float
    roll_rate: float
    sideslip: float  # |v|/U, rad
    heave: float  # |w|, m/s
    pitch: float
    roll: float
    fin: float  # rad, the vehicle's fin range
    fin_rate: float  # rad/s, its fins' slew rate

    def ratios(self, peaks: Mapping[str, float]) -> dict[str, float]:
        """Each peak over its bound (≤ 1 inside the regime)."""
        return {k: peaks[k] / getattr(self, k) for k in peaks}


def peaks(xs: np.ndarray, fins: np.ndarray, speed: float, dt: float) -> dict[str, float]:
    """The limited quantities' peaks over a flight (states (N, 10), fin angles (N, 3))."""
    i = IX
    return {
        "yaw_rate": float(np.abs(xs[:, i["r"]]).max()),
        "pitch_rate": float(np.abs(xs[:, i["q"]]).max()),
        "roll_rate": float(np.abs(xs[:, i["p"]]).max()),
        "sideslip": float(np.abs(xs[:, i["v"]]).max() / speed),
        "heave": float(np.abs(xs[:, i["w"]]).max()),
        "pitch": float(np.abs(xs[:, i["theta"]]).max()),
        "roll": float(np.abs(xs[:, i["phi"]]).max()),
        "fin": float(np.abs(fins).max()),
        "fin_rate": float(np.abs(np.diff(fins, axis=0)).max() / dt),
    }


@dataclass(frozen=True)
class Linearity:
    """Per experiment, the worst over the seeds flown: the lowest fit of the analytic model on
    its excited channels, and the largest second-order residual over the sensor noise on the
    fitted channels."""

    fit: Mapping[str, tuple[str, float]]  # experiment -> (channel, fit %)
    residual: Mapping[str, tuple[str, float]]  # experiment -> (channel, rms residual / noise)
    speed_loss: Mapping[str, float]  # experiment -> peak speed loss, fraction of U
    seeds: tuple[int, ...] = (SEED,)

    def passed(self, name: str, margin: float = 1.0) -> bool:
        """The rule, its two tolerances (100 % − fit, residual) times `margin` (≤ 1: stricter)."""
        return (
            self.fit[name][1] >= 100.0 - margin * (100.0 - FIT_LIMIT)
            and self.residual[name][1] < margin * RESIDUAL_LIMIT
        )

    def table(self) -> str:
        return "\n".join(
            f"{n}: lowest fit {c} {f:.2f} %, largest second-order residual "
            f"{self.residual[n][0]} {self.residual[n][1]:.3f} of the noise, speed loss "
            f"{100 * self.speed_loss[n]:.3f} %"
            for n, (c, f) in self.fit.items()
        )


def linearity(
    s: Scenario, excited: Mapping[str, Sequence[str]], mjcf=None, seeds: Sequence[int] = (SEED,)
) -> Linearity:
    """Fly `s` noise-free on the truth plant with each seed's PRBS phases; compare with the
    analytic model simulated open loop with the flown inputs from the first sample (`excited`:
    experiment -> its channels). The worst over the seeds."""
    fit, residual, loss = {}, {}, {}
    for seed in seeds:
        flights, lin = fly_scenario(s, seed=seed, mjcf=mjcf)
        config = model_config(lin)[0]
        truth = [Experiment(f.name, f.t, STATES, f.truth, f.fins) for f in flights]
        start = {e.name: dict(zip(STATES, e.y[0])) for e in truth}
        U = lin.vehicle.speed
        for e, yhat in zip(truth, predict(truth, config, start)):
            fits = {c: fit_percent(e.column(c), yhat[:, IX[c]]) for c in excited[e.name]}
            res = {c: float(np.std(e.column(c) - yhat[:, IX[c]])) / s.sensors.noise_std[c] for c in FITTED}
            c1, c2 = min(fits, key=fits.get), max(res, key=res.get)
            if e.name not in fit or fits[c1] < fit[e.name][1]:
                fit[e.name] = (c1, fits[c1])
            if e.name not in residual or res[c2] > residual[e.name][1]:
                residual[e.name] = (c2, res[c2])
            loss[e.name] = max(loss.get(e.name, 0.0), float((U - e.column("u").min()) / U))
    return Linearity(fit, residual, loss, tuple(seeds))
