"""The linear regime of an experiment: the peaks of the quantities that bound it, the check
that the analytic model tracks the truth plant flying it (`linearity`, the rule that sized
Scenario II: fit ≥ 99 % on every excited channel, second-order residual below a fifth of the
sensor noise on every fitted channel), and the same comparison on a run directory
(`open_loop_fit`): how far a data set lies from the analytic model's linear regime.

Both simulate the analytic model open loop (`open_loop`): from the first noise-free truth sample,
driven by the flown fin angles (each sample interval's mean, the zero-order hold of the model).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from testbed.fit_percent import fit_percent
from testbed.data import MIN_NOISE_STD, Experiment, ModelConfig, read_config, read_csv, run_csvs
from testbed.errors import InputError
from testbed.identification.prediction import predict
from testbed.models.linear import IX, STATES
from testbed.simulation.analytic import model_config
from testbed.simulation.flight import fly_scenario
from testbed.simulation.scenario import Scenario, read_scenario

__all__ = [
    "EXCITED_SNR",
    "FITTED",
    "FIT_LIMIT",
    "RESIDUAL_LIMIT",
    "SEED",
    "Limits",
    "Linearity",
    "OpenLoopFit",
    "linearity",
    "open_loop",
    "open_loop_fit",
    "peaks",
    "speed_loss",
]

SEED = 1  # the PRBS phases and noise streams the design is evaluated and flown with
FITTED = tuple(s for s in STATES if s != "z")  # a run's model.toml fits every state but depth
RESIDUAL_LIMIT = 0.2  # second-order residual / sensor noise on fitted channels (Scenario II's rule)
FIT_LIMIT = 99.0  # % fit of the analytic model on every excited channel, depth included
# A run's channel counts as excited (`open_loop_fit`) where its noise-free truth's standard
# deviation is at least EXCITED_SNR times its sensor noise σ: a response that stands out of the
# noise in the data (σ at least `MIN_NOISE_STD`). Weaker motion (cross-coupling below the noise, rounding in a channel the
# experiment leaves alone) is reported but does not set the lowest fit.
EXCITED_SNR = 2.0


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


def open_loop(truth: Sequence[Experiment], config: ModelConfig) -> list[np.ndarray]:
    """The model of `config` simulated open loop on each noise-free experiment (every state):
    from its first sample, driven by its inputs. Per experiment (N, 10), absolute u."""
    return predict(truth, config, {e.name: dict(zip(e.measured, e.y[0])) for e in truth})


def speed_loss(truth: Experiment, speed: float) -> float:
    """The largest loss of speed below the trim `speed` over a noise-free experiment, a fraction."""
    return float((speed - truth.column("u").min()) / speed)


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
        U = lin.vehicle.speed
        for e, yhat in zip(truth, open_loop(truth, config)):
            fits = {c: fit_percent(e.column(c), yhat[:, IX[c]]) for c in excited[e.name]}
            res = {c: float(np.std(e.column(c) - yhat[:, IX[c]])) / s.sensors.noise_std[c] for c in FITTED}
            c1, c2 = min(fits, key=fits.get), max(res, key=res.get)
            if e.name not in fit or fits[c1] < fit[e.name][1]:
                fit[e.name] = (c1, fits[c1])
            if e.name not in residual or res[c2] > residual[e.name][1]:
                residual[e.name] = (c2, res[c2])
            loss[e.name] = max(loss.get(e.name, 0.0), speed_loss(e, U))
    return Linearity(fit, residual, loss, tuple(seeds))


@dataclass(frozen=True)
class OpenLoopFit:
    """The analytic model open loop against a run (`open_loop_fit`). Per experiment: its fit %
    (`fit_percent`) per channel against the measured data and against the noise-free truth, the
    excited channels (`EXCITED_SNR`), the speed loss (% of U), the peak pitch (deg) and pitch
    rate (deg/s). NaN where a channel does not vary."""

    speed: float  # trim speed U, m/s
    data: Mapping[str, Mapping[str, float]]  # experiment -> measured channel -> fit %
    truth: Mapping[str, Mapping[str, float]]  # experiment -> state -> fit %
    excited: Mapping[str, tuple[str, ...]]  # experiment -> its excited states
    speed_loss: Mapping[str, float]  # experiment -> %, of U
    peak_pitch: Mapping[str, float]  # experiment -> deg
    peak_pitch_rate: Mapping[str, float]  # experiment -> deg/s

    @property
    def lowest(self) -> tuple[str, str, float] | None:
        """(experiment, channel, fit %) of the lowest fit % to the truth over the excited channels; None
        where no channel is excited."""
        fits = [(n, c, self.truth[n][c]) for n, cs in self.excited.items() for c in cs]
        return min(fits, key=lambda f: f[2]) if fits else None

    @property
    def lowest_fit_to_truth(self) -> float:
        """The lowest fit % to the truth over the excited channels of every experiment (NaN: none)."""
        return self.lowest[2] if self.lowest else math.nan

    def to_dict(self) -> dict:
        """JSON-able (NaN as None), with the derived `lowest_fit_to_truth` and `lowest`."""
        lowest = self.lowest
        return {
            "speed": self.speed,
            "lowest_fit_to_truth": _json(self.lowest_fit_to_truth),
            "lowest": None if lowest is None else {"experiment": lowest[0], "channel": lowest[1]},
            "excited_snr": EXCITED_SNR,
            "data": {n: {c: _json(v) for c, v in fits.items()} for n, fits in self.data.items()},
            "truth": {n: {c: _json(v) for c, v in fits.items()} for n, fits in self.truth.items()},
            "excited": {n: list(cs) for n, cs in self.excited.items()},
            "speed_loss": dict(self.speed_loss),
            "peak_pitch": dict(self.peak_pitch),
            "peak_pitch_rate": dict(self.peak_pitch_rate),
        }

    @classmethod
    def from_dict(cls, d: Mapping) -> "OpenLoopFit":
        """The inverse of `to_dict` (its derived keys are recomputed, not read)."""
        fits = lambda key: {  # noqa: E731
            n: {c: math.nan if v is None else float(v) for c, v in f.items()} for n, f in d[key].items()
        }
        return cls(
            speed=float(d["speed"]),
            data=fits("data"),
            truth=fits("truth"),
            excited={n: tuple(cs) for n, cs in d["excited"].items()},
            speed_loss={n: float(v) for n, v in d["speed_loss"].items()},
            peak_pitch={n: float(v) for n, v in d["peak_pitch"].items()},
            peak_pitch_rate={n: float(v) for n, v in d["peak_pitch_rate"].items()},
        )


def _json(v: float) -> float | None:
    return None if math.isnan(v) else float(v)


def open_loop_fit(run: str | Path) -> OpenLoopFit:
    """The analytic model of a run directory (its `model.toml`) simulated open loop on each
    experiment (`open_loop`: from the first `<experiment>.truth.csv` sample, with its fin
    angles), against the measured data (`<experiment>.csv`) and the noise-free truth; the
    excited channels, the truth's speed loss and peak pitch and pitch rate (see `OpenLoopFit`).
    The sensor noise σ that decides which channels are excited is the run's `scenario.toml`'s."""
    run = Path(run)
    config = read_config(run / "model.toml")
    sigma = read_scenario(run / "scenario.toml").sensors.noise_std
    data = [read_csv(f) for f in run_csvs(run)]
    truth = [read_csv(run / f"{e.name}.truth.csv", keep_repeats=True) for e in data]
    for e in truth:
        if e.measured != STATES:
            raise InputError(
                f"{e.source}: columns {', '.join(e.measured)}; expected every state ({', '.join(STATES)})"
            )
    U = config.vehicle.speed
    fields = ("data", "truth", "excited", "speed_loss", "peak_pitch", "peak_pitch_rate")
    out = {key: {} for key in fields}  # field -> experiment -> its value
    for d, e, yhat in zip(data, truth, open_loop(truth, config)):
        p = peaks(e.y, e.inputs, U, e.dt)
        values = (
            {c: fit_percent(d.column(c), yhat[:, IX[c]]) for c in d.measured},
            {c: fit_percent(e.column(c), yhat[:, IX[c]]) for c in STATES},
            tuple(c for c in STATES if np.std(e.column(c)) >= EXCITED_SNR * max(sigma[c], MIN_NOISE_STD)),
            100.0 * speed_loss(e, U),
            math.degrees(p["pitch"]),
            math.degrees(p["pitch_rate"]),
        )
        for key, v in zip(fields, values):
            out[key][d.name] = v
    return OpenLoopFit(speed=U, **out)
