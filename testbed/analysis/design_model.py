"""The model an experiment design is made at (`design` module doc): the linear model with its
autopilots (`Model`), flown through a candidate experiment, its Fisher information there and
the design criteria (D, A, E) in the coefficients' scales, and the linear regime's limits.
"""

from __future__ import annotations
import math
from dataclasses import dataclass, replace
from typing import Mapping
import numpy as np
from testbed.analysis.regime import FITTED, SEED, Limits, peaks
from testbed.data import Experiment, ModelConfig
from testbed.errors import InputError
from testbed.identification import bounds
from testbed.models.linear import (
    COEFFICIENTS,
    IX,
    NX,
    STATES,
    continuous,
    derivatives,
    inertia_defect,
    structure,
    theta_vector,
)
from testbed.simulation.autopilot import Autopilot, fly_linear
from testbed.simulation.measurements import NOISE_STD
from testbed.simulation.flight import program
from testbed.simulation.scenario import ExperimentSpec, Scenario, scenario
from testbed.simulation.vehicle import FinLimits

__all__ = [
    "CRITERIA",
    "GROWING",
    "MAX_EXPERIMENT",
    "Model",
    "criterion",
    "experiment",
    "design_fisher",
    "fly_model",
    "instability",
    "model",
    "regime_limits",
    "scales",
    "scenario_flights",
    "scenario_information",
]


CRITERIA = ("D", "A", "E")


GROWING = 1e-6  # 1/s: a mode whose real part exceeds it grows (the design model must be stable)


# s, the longest record: the depth integrates the second-order pitch drift (it grows as the cube
# of the time), and Scenario II's regime was measured on 60 s records; more time for a type is
# flown as several records (each its own initial state and PRBS phase)
MAX_EXPERIMENT = 60.0


@dataclass(frozen=True)
class Model:
    """The linear model and its autopilots: what the design simulates and differentiates."""

    config: ModelConfig  # coefficients; `free` the ones designed for; outputs: every state but z
    A: np.ndarray
    B: np.ndarray
    autopilot: Autopilot
    fins: FinLimits  # the vehicle's fin range and slew rate (its MJCF's)
    noise_std: Mapping[str, float]
    control_rate: float = 50.0
    depth: float = 100.0

    @property
    def speed(self) -> float:
        return self.config.vehicle.speed


def model(
    config: ModelConfig,
    fins: FinLimits,
    noise_std: Mapping[str, float] | None = None,
    control_rate: float = 50.0,
) -> Model:
    """The design model of `config` (its coefficients, its free list), autopilots designed on it,
    with the vehicle's fins `fins`."""
    why = instability(config)
    if why is not None:
        raise InputError(
            f"{config.source or 'model'}: {why}; expected the coefficients of a stable vehicle to design at"
        )
    A, B, _ = continuous(structure(config.vehicle), theta_vector(config.coefficients))
    speed = config.vehicle.speed
    ap = Autopilot.designed(A, B, speed, 1.0 / control_rate, fins.angle)
    config = replace(config, outputs=FITTED)
    return Model(config, A, B, ap, fins, dict(noise_std or NOISE_STD), control_rate)


def instability(config: ModelConfig) -> str | None:
    """Why the linear model of `config` is no vehicle to design at, or None: its Mt is not a
    body's, or it is not finite, or its least stable mode grows. A growing mode is named by its
    largest states (the eigenvector's components) and by the coefficients its growth rate
    depends on most: those of largest |Re ∂λ/∂θ_i · θ_i| (the change of the rate per relative
    change of θ_i, ∂λ/∂θ_i = wᴴ ∂A/∂θ_i v with w, v its left and right eigenvectors, wᴴv = 1)."""
    s, theta = structure(config.vehicle), theta_vector(config.coefficients)
    defect = inertia_defect(s, theta)
    if defect:
        return f"the inertia matrix Mt is not a body's: {defect}"
    A, B, S = continuous(s, theta)
    if not np.all(np.isfinite(A)):
        return "the linear model is not finite"
    lam, V = np.linalg.eig(A)
    k = int(np.argmax(lam.real))
    if lam[k].real <= GROWING:
        return None
    v = np.abs(V[:, k])
    states = [STATES[i] for i in np.argsort(-v)[:3] if v[i] >= 0.1 * v.max()]
    dA = derivatives(s, theta, A, B, S)[0]
    effect = np.abs((np.linalg.inv(V)[k] @ dA @ V[:, k]).real * theta)
    top = [i for i in np.argsort(-effect)[:3] if effect[i] > 0]
    oscillating = (
        f", oscillating at {abs(lam[k].imag) / (2 * np.pi):.3g} Hz" if abs(lam[k].imag) > GROWING else ""
    )
    return (
        f"the linear model is unstable: a mode in {', '.join(states)} grows at {lam[k].real:.3g} 1/s"
        f"{oscillating}; its growth depends most on "
        + ", ".join(f"{COEFFICIENTS[i]} = {theta[i]:.4g}" for i in top)
    )


def fly_model(m: Model, e: ExperimentSpec, duration: float, seed: int = SEED, index: int = 0):
    """Experiment `e` flown by the linear model with its autopilots: (t, states, fin angles)."""
    s = Scenario(name="design", experiments=(e,), speed=m.speed, depth=m.depth, control_rate=m.control_rate)
    x0 = np.zeros(NX)
    x0[IX["z"]] = m.depth
    m.autopilot.reset()
    return fly_linear(m.A, m.B, m.autopilot, program(s, e, seed, index), duration, x0, rate_limit=m.fins.rate)


def experiment(m: Model, t: np.ndarray, xs: np.ndarray, fins: np.ndarray, name: str = "design") -> Experiment:
    """A flight of `fly_model` as noise-free data: every state (u absolute) and the fin angles."""
    y = xs.copy()
    y[:, IX["u"]] += m.speed
    return Experiment(name, t, STATES, y, fins)


def design_fisher(
    m: Model, t: np.ndarray, xs: np.ndarray, fins: np.ndarray, name: str = "design"
) -> np.ndarray:
    """Fisher information of `m.config.free` from one noise-free experiment (initial states
    eliminated), with the sensor noise `m.noise_std`."""
    e = experiment(m, t, xs, fins, name)
    return bounds.fisher(m.config.fitted([e]), m.config, noise_std=m.noise_std)


def scales(config: ModelConfig) -> np.ndarray:
    """s_i of the relative coefficients: |θ_i|, or for a coefficient at 0 the largest |value| of
    its row's coefficients."""
    out = []
    for n in config.free:
        v = abs(config.coefficients.get(n, 0.0))
        if v == 0:
            row = [abs(config.coefficients.get(c, 0.0)) for c in COEFFICIENTS if c[0] == n[0]]
            v = max(row) if max(row) > 0 else 1.0
        out.append(v)
    return np.array(out)


def criterion(F: np.ndarray, s: np.ndarray, kind: str) -> float:
    """The design criterion of information `F` (free coefficients) at scales `s`; larger is better."""
    Fr = F * np.outer(s, s)
    w = np.linalg.eigvalsh((Fr + Fr.T) / 2)
    if w.min() <= 1e-12 * max(w.max(), 1e-300):
        return -math.inf
    if kind == "D":
        return float(np.sum(np.log(w)))
    if kind == "A":
        return -float(np.sum(1.0 / w))
    if kind == "E":
        return float(w.min())
    raise InputError(f"criterion={kind!r}; expected one of {', '.join(CRITERIA)}")


def regime_limits(m: Model, base: Scenario | str = "II") -> Limits:
    """The peaks Scenario II's experiments reach on the design model (at 60 s each): the
    largest of each quantity over its experiments, each its own experiment type's bound."""
    base = scenario(base)
    worst: dict[str, float] = {}
    for k, e in enumerate(base.experiments):
        t, xs, fins = fly_model(m, e, base.duration_of(e), SEED, k)
        for key, v in peaks(xs, fins, m.speed, 1.0 / m.control_rate).items():
            worst[key] = max(worst.get(key, 0.0), v)
    return Limits(
        **{
            k: worst[k] for k in ("yaw_rate", "pitch_rate", "roll_rate", "sideslip", "heave", "pitch", "roll")
        },
        fin=m.fins.angle,
        fin_rate=m.fins.rate,
    )


def scenario_flights(m: Model, total: float, base: Scenario | str = "II") -> list[Experiment]:
    """Scenario II flown by the design model for `total` s (split evenly, as it is)."""
    base = scenario(base)
    each = total / len(base.experiments)
    return [experiment(m, *fly_model(m, e, each, SEED, k), e.name) for k, e in enumerate(base.experiments)]


def scenario_information(m: Model, total: float, base: Scenario | str = "II") -> np.ndarray:
    """Fisher information of Scenario II flown for `total` s."""
    F = 0.0
    for e in scenario_flights(m, total, base):
        F = F + bounds.fisher(m.config.fitted([e]), m.config, noise_std=m.noise_std)
    return F
