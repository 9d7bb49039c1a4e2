"""Sensor noise: what a torpedo's navigation sensors add to the true state.

Defaults (one standard deviation, white, independent per channel), typical of the sensors a
lightweight torpedo or a survey AUV carries:

| channel | sensor | noise |
|---|---|---|
| u | Doppler velocity log, along track (0.25 % of 20 m/s) | 0.05 m/s |
| v, w | Doppler velocity log, across track | 0.02 m/s |
| p, q, r | fibre-optic gyros | 0.002 rad/s (0.11 deg/s) |
| phi, theta | AHRS attitude | 0.003 rad (0.17 deg) |
| psi | AHRS heading | 0.01 rad (0.57 deg) |
| z | pressure depth sensor | 0.05 m |
| fin angles | absolute servo encoders (16-bit over the ±0.4 rad range: 12 µrad steps) | 2e-5 rad |

The fin encoders must resolve the linear regime's deflections (Scenario II's elevator PRBS is
0.3 mrad): a 12-bit encoder's 0.2 mrad steps would make the recorded input mostly noise, and
output error would then attribute part of the outputs to noise on the inputs.

Noise is drawn from a numpy Generator seeded by (seed, experiment), so a run is bit-for-bit
reproducible for its seed.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np

from testbed.data import MIN_NOISE_STD, Experiment, median
from testbed.errors import InputError
from testbed.models.linear import STATES

__all__ = [
    "NOISE_STD",
    "Sensors",
    "check_seed",
    "interval_means",
    "measure",
    "noise_free_channels",
    "noise_from_data",
    "rng_for",
]

NOISE_STD = {
    "u": 0.05,
    "v": 0.02,
    "w": 0.02,
    "p": 0.002,
    "q": 0.002,
    "r": 0.002,
    "phi": 0.003,
    "theta": 0.003,
    "psi": 0.01,
    "z": 0.05,
}
FIN_NOISE_STD = 2e-5


@dataclass(frozen=True)
class Sensors:
    """Sample rate (or the logger's repeating steps), per-channel noise (standard deviations,
    SI) and the fins' log rate."""

    rate: float = 50.0  # Hz; with `steps`, the mean rate len(steps) / sum(steps)
    noise_std: Mapping[str, float] = field(default_factory=lambda: dict(NOISE_STD))
    fin_std: float = FIN_NOISE_STD
    fin_rate: float | None = None  # Hz: the fin angles logged this often (None: at `rate`)
    # s: the steps between the record's rows, repeated from t = 0 (None: uniform at `rate`)
    steps: tuple[float, ...] | None = None

    def __post_init__(self):
        if not 0 < self.rate < math.inf:
            raise InputError(f"sample rate {self.rate}; expected a finite number > 0 (Hz)")
        if self.fin_rate is not None and not 0 < self.fin_rate < math.inf:
            raise InputError(f"fin_rate {self.fin_rate}; expected a finite number > 0 (Hz)")
        for name, s in self.noise_std.items():
            if name not in STATES:
                raise InputError(f"noise for {name!r}: not a state; expected one of {', '.join(STATES)}")
            if not 0 <= s < math.inf:
                raise InputError(f"noise for {name!r} = {s}; expected a finite number >= 0")
        if not 0 <= self.fin_std < math.inf:
            raise InputError(f"fin noise {self.fin_std}; expected a finite number >= 0 (rad)")
        if self.steps is not None:
            if not self.steps or not all(isinstance(d, float) and 0 < d < math.inf for d in self.steps):
                raise InputError(
                    f"steps {list(self.steps)!r}; expected a non-empty list of finite numbers > 0 (s)"
                )
            # the mean rate: that of a uniform log with as many rows
            object.__setattr__(self, "rate", len(self.steps) / math.fsum(self.steps))

    @property
    def std(self) -> np.ndarray:
        """The noise's standard deviation per state, in `STATES` order (0 where none is given)."""
        return np.array([self.noise_std.get(s, 0.0) for s in STATES])


def check_seed(seed) -> int:
    """`seed` as an int; InputError unless it is a non-negative integer (numpy's seeds are)."""
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral) or seed < 0:
        raise InputError(f"seed {seed!r}; expected a non-negative integer")
    return int(seed)


def rng_for(seed: int, experiment: int, stream: int = 0) -> np.random.Generator:
    """The generator of one experiment's random stream (0: sensor noise, 1: input sequences)."""
    seed = check_seed(seed)
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(experiment, stream)))


def interval_means(integral: np.ndarray, t: np.ndarray, rate: float | None = None) -> np.ndarray:
    """Each interval's mean of a quantity from its running integral at the instants t (N, k):
    (I_k+1 − I_k) / (t_k+1 − t_k), (N − 1, k); `rate`: the instants' rate where they are
    uniform, 1 / (t_k+1 − t_k) without its rounding."""
    d = np.diff(integral, axis=0)
    return d * rate if rate is not None else d / np.diff(t)[:, None]


def measure(
    truth: np.ndarray,
    fins: np.ndarray,
    sensors: Sensors,
    rng: np.random.Generator,
    noise: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Noisy copies of the true states (N, 10) and fin angles (N, 3); `noise`: the states' noise
    where it was drawn already (the readings an autopilot flew on), else drawn from `rng`."""
    if noise is None:
        noise = rng.standard_normal(truth.shape) * sensors.std
    states = truth + noise
    angles = fins + rng.standard_normal(fins.shape) * sensors.fin_std
    return states, angles


def _third_differences(experiments: Sequence[Experiment]) -> dict[str, list[np.ndarray]]:
    """Per measured state, the third differences `Δ³y` of each experiment that measures it, over
    its samples present (a missing sample skipped: a slower sensor's at its own rate)."""
    out: dict[str, list[np.ndarray]] = {}
    for e in experiments:
        for j, name in enumerate(e.measured):
            y = e.y[:, j]
            out.setdefault(name, []).append(np.diff(y[~np.isnan(y)], 3))
    return out


def noise_from_data(
    experiments: Sequence[Experiment], given: Mapping[str, float] | None = None
) -> dict[str, float]:
    """Measurement noise σ per measured state: `given[state]` where it is given (the sensors' σ,
    known: a model config's `noise_std`), else read off the data, pooled over the experiments:
    robust third differences: for white noise `Var(Δ³e) = 20 σ²`, and a signal smooth over four
    samples adds little to `Δ³y` (where it is fast, the σ is an upper bound).
    A state so read but measured only in records of fewer than 4 samples: `InputError`."""
    given = given or {}
    pooled = _third_differences(experiments)
    out = {}
    for name in (s for s in STATES if s in pooled):
        if name in given:
            out[name] = float(given[name])
            continue
        d = np.concatenate(pooled[name])
        if not d.size:
            where = ", ".join(e.source or e.name for e in experiments if name in e.measured)
            raise InputError(
                f"{where}: {name} has fewer than 4 samples; the noise estimate "
                "(third differences) expected at least 4"
            )
        mad = 1.4826 * median(np.abs(d - median(d)))
        out[name] = max(mad / math.sqrt(20.0), MIN_NOISE_STD)  # R must stay positive definite
    return out


def noise_free_channels(experiments: Sequence[Experiment]) -> list[str]:
    """Measured states whose data carry no measurement noise: the third differences of a
    noisy channel are noise, whose neighbours have the same sign a quarter of the time
    (correlation −3/4: ½ + asin(−¾)/π = 0.23); a smooth channel's keep their sign (→ 1). Above
    0.45, or all zero, the channel is taken as noise-free."""
    quiet = []
    for name, ds in _third_differences(experiments).items():
        kept = sum(int(np.sum(d[:-1] * d[1:] > 0)) for d in ds)  # neighbours keeping their sign
        pairs = sum(max(len(d) - 1, 0) for d in ds)
        if not any(np.any(d != 0) for d in ds) or kept > 0.45 * max(pairs, 1):
            quiet.append(name)
    return [n for n in STATES if n in quiet]
