"""Trial imperfections: what a real trial does to the vehicle and its fins that a perfect one does not.

A scenario file's `[trial]` table (every key optional; the default is none of them):

| key | what | unit |
|---|---|---|
| `fin_offset = {delta_r = .., delta_er = .., delta_el = ..}` | each fin encoder's zero error: the servo holds the encoder at the command, so the fin's true angle is the command minus it, and the record reads the true angle plus it | rad |
| `fin_log_delay` | the recorded fin angle lags the fin: each sample is the mean angle over the sample interval ending `fin_log_delay` earlier | s |
| `actuator_delay` | the fin follows its command late (rounded to the plant's step) | s |
| `backlash` | the servo's dead band (full width): the fin moves only once the command is more than half of it away, and then follows it that far behind | rad |
| `current` | the water's steady velocity over the ground, north-east-down | m/s |
| `roll_moment` | a constant roll moment: a propeller's torque | N m |
| `weight_excess` | weight − buoyancy of the true vehicle (positive: heavy) | N |
| `cg_offset` | the true CG from the nominal one, body axes | m |
| `[trial.turbulence] force_std, moment_std, time` | coloured process noise: body-axis force (N) and moment (N m) disturbances, each an independent first-order Gauss-Markov process of standard deviation σ and correlation time τ (s): spectrum S(ω) = 2σ²τ / (1 + ω²τ²), autocorrelation σ² e^{−|t|/τ} | N, N m, s |

The model config of a run keeps the nominal vehicle, as a real trial's would. The vehicle's
states are relative to the water: a steady uniform current moves the water and the vehicle
together (Galilean invariance: a uniform steady current changes no force on the body), so it
adds to the vehicle's track and to what ground-referenced sensors read (a DVL; the
`testbed.models.sensors` map), not to its motion through the water. (MuJoCo's `opt.wind`, its fluid model's medium velocity,
is subtracted from each body's velocity in MuJoCo's fluid forces only; the plant's added-mass
completion, −M9 γ with γ from the velocity over the ground, would not see it: with the states
relative to the water, no part of the plant needs it.) The loads — turbulence,
the propeller's torque, the weight's excess at the true CG (its force Δw Cᵀ e₃ and its moment
r_g × w Cᵀ e₃ about the nominal CG) — enter the truth as an external wrench at the CG, held over
each of the plant's steps: the MuJoCo plant's `wrench`, and the linear truth's equivalent
forcing Mt⁻¹ (wrench, 0).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from testbed.data import number
from testbed.errors import InputError, check_keys, is_number
from testbed.models.linear import INPUTS
from testbed.models.sensors import rotation

__all__ = [
    "TRIAL_KEYS",
    "TURBULENCE_STREAM",
    "Backlash",
    "Trial",
    "Turbulence",
    "gauss_markov",
    "parse_trial",
    "trial_table",
]

_ZERO3 = (0.0, 0.0, 0.0)
TURBULENCE_STREAM = 8  # the turbulence's random stream of an experiment (`measurements.rng_for`)


@dataclass(frozen=True)
class Turbulence:
    """Body-axis force (N) and moment (N m) disturbances: first-order Gauss-Markov, σ and τ (s)."""

    force_std: tuple[float, float, float] = _ZERO3
    moment_std: tuple[float, float, float] = _ZERO3
    time: float = 1.0

    def __post_init__(self):
        for key in ("force_std", "moment_std"):
            v = getattr(self, key)
            if not isinstance(v, tuple) or len(v) != 3 or not all(is_number(a) and a >= 0 for a in v):
                raise InputError(f"trial.turbulence.{key} = {v!r}; expected three finite numbers >= 0")
        if not (is_number(self.time) and self.time > 0):
            raise InputError(f"trial.turbulence.time = {self.time!r}; expected a finite number > 0 (s)")

    @property
    def std(self) -> np.ndarray:
        return np.array([*self.force_std, *self.moment_std], float)


@dataclass(frozen=True)
class Trial:
    """The imperfections of a trial (all zero: a perfect one)."""

    fin_offset: Mapping[str, float] = field(default_factory=dict)  # rad, per fin
    fin_log_delay: float = 0.0  # s
    actuator_delay: float = 0.0  # s
    backlash: float = 0.0  # rad, full width
    current: tuple[float, float, float] = _ZERO3  # m/s, NED
    roll_moment: float = 0.0  # N m
    weight_excess: float = 0.0  # N
    cg_offset: tuple[float, float, float] = _ZERO3  # m, body axes
    turbulence: Turbulence = field(default_factory=Turbulence)

    def __post_init__(self):
        for fin, v in self.fin_offset.items():
            if fin not in INPUTS:
                raise InputError(f"trial.fin_offset.{fin}: not a fin; expected {', '.join(INPUTS)}")
            if not (is_number(v) and abs(v) <= 0.05):
                raise InputError(
                    f"trial.fin_offset.{fin} = {v!r}; expected a finite number within ±0.05 (rad)"
                )
        for key, high in (("fin_log_delay", 1.0), ("actuator_delay", 1.0), ("backlash", 0.05)):
            v = getattr(self, key)
            if not (is_number(v) and 0 <= v <= high):
                raise InputError(f"trial.{key} = {v!r}; expected a finite number 0 to {high:g}")
        for key, high in (("current", 5.0), ("cg_offset", 0.5)):
            v = getattr(self, key)
            if not isinstance(v, tuple) or len(v) != 3 or not all(is_number(a) and abs(a) <= high for a in v):
                raise InputError(f"trial.{key} = {v!r}; expected three finite numbers within ±{high:g}")
        for key in ("roll_moment", "weight_excess"):
            if not is_number(getattr(self, key)):
                raise InputError(f"trial.{key} = {getattr(self, key)!r}; expected a finite number")

    @property
    def is_perfect(self) -> bool:
        return self == Trial()

    @property
    def offsets(self) -> np.ndarray:
        """The fin encoders' zero errors, `delta_r, delta_er, delta_el` (rad)."""
        return np.array([self.fin_offset.get(f, 0.0) for f in INPUTS])

    @property
    def has_loads(self) -> bool:
        """Whether anything acts on the vehicle as an external wrench."""
        return bool(
            self.roll_moment or self.weight_excess or any(self.cg_offset) or self.turbulence.std.any()
        )

    def loads(self, x: np.ndarray, weight: float) -> np.ndarray:
        """The steady loads' wrench at the CG, body axes (6,), at the state x (its attitude):
        the propeller's torque and the true vehicle's weight excess and CG offset."""
        C = rotation(x[6], x[7], x[8])
        down = C[2]  # Cᵀ e₃: the earth's down in body axes
        moment = np.cross(np.asarray(self.cg_offset, float), (weight + self.weight_excess) * down)
        moment[0] += self.roll_moment
        return np.concatenate([self.weight_excess * down, moment])


def gauss_markov(std: np.ndarray, tau: float, dt: float, n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, len(std)) samples every `dt` of independent stationary first-order Gauss-Markov
    processes (σ = std, correlation time τ): the exact discretisation
    w_{k+1} = a w_k + σ √(1 − a²) n_k, a = e^{−dt/τ}, from w_0 ~ N(0, σ²)."""
    std = np.asarray(std, float)
    a = math.exp(-dt / tau)
    e = rng.standard_normal((n, len(std)))
    w = np.empty((n, len(std)))
    w[0] = e[0]
    b = math.sqrt(1.0 - a * a)
    for k in range(1, n):
        w[k] = a * w[k - 1] + b * e[k]
    return w * std


class Backlash:
    """A servo's dead band (play) of full width `width`: the output stays put while the input is
    within half the band of it, and is dragged along that far behind otherwise."""

    def __init__(self, width: float, start: np.ndarray):
        self.half = 0.5 * width
        self.out = np.array(start, float)

    def __call__(self, command: np.ndarray) -> np.ndarray:
        self.out = np.clip(self.out, command - self.half, command + self.half)
        return self.out.copy()


# -- the scenario file's [trial] table ----------------------------------------------------------

TRIAL_KEYS = (
    "fin_offset",
    "fin_log_delay",
    "actuator_delay",
    "backlash",
    "current",
    "roll_moment",
    "weight_excess",
    "cg_offset",
    "turbulence",
)
_TURBULENCE_KEYS = ("force_std", "moment_std", "time")


def _triple(v, where: str) -> tuple[float, float, float]:
    if not isinstance(v, list) or len(v) != 3:
        raise InputError(f"{where} = {v!r}; expected a list of three numbers")
    return tuple(number(a, where) for a in v)


def parse_trial(doc, where: str) -> Trial:
    """The `Trial` of a scenario file's `[trial]` table (`where`: the file and table, for messages)."""
    if not isinstance(doc, Mapping):
        raise InputError(f"{where}: expected a table")
    check_keys(doc, TRIAL_KEYS, where)
    kw = {}
    for key in ("fin_log_delay", "actuator_delay", "backlash", "roll_moment", "weight_excess"):
        if key in doc:
            kw[key] = number(doc[key], f"{where}.{key}")
    for key in ("current", "cg_offset"):
        if key in doc:
            kw[key] = _triple(doc[key], f"{where}.{key}")
    if "fin_offset" in doc:
        offsets = doc["fin_offset"]
        if not isinstance(offsets, Mapping):
            raise InputError(f"{where}.fin_offset: expected a table of fin = rad ({', '.join(INPUTS)})")
        kw["fin_offset"] = {k: number(v, f"{where}.fin_offset.{k}") for k, v in offsets.items()}
    if "turbulence" in doc:
        t = doc["turbulence"]
        if not isinstance(t, Mapping):
            raise InputError(f"{where}.turbulence: expected a table of {', '.join(_TURBULENCE_KEYS)}")
        check_keys(t, _TURBULENCE_KEYS, f"{where}.turbulence")
        tk = {k: _triple(t[k], f"{where}.turbulence.{k}") for k in ("force_std", "moment_std") if k in t}
        if "time" in t:
            tk["time"] = number(t["time"], f"{where}.turbulence.time")
        try:
            kw["turbulence"] = Turbulence(**tk)
        except InputError as exc:
            raise InputError(f"{where.rsplit('trial', 1)[0]}{exc}") from None
    try:
        return Trial(**kw)
    except InputError as exc:
        raise InputError(f"{where.rsplit('trial', 1)[0]}{exc}") from None


def trial_table(t: Trial) -> dict:
    """The `[trial]` table of `t`, its keys that differ from a perfect trial's (parse_trial reads it back)."""
    out = {}
    perfect = Trial()
    for key in TRIAL_KEYS:
        v = getattr(t, key)
        if v == getattr(perfect, key):
            continue
        if key == "turbulence":
            v = {"force_std": list(v.force_std), "moment_std": list(v.moment_std), "time": v.time}
        elif isinstance(v, tuple):
            v = list(v)
        elif isinstance(v, Mapping):
            v = dict(v)
        out[key] = v
    return out
