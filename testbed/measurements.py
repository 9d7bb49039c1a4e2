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
from typing import Mapping

import numpy as np

from testbed.errors import InputError
from testbed.model import STATES

NOISE_STD = {"u": 0.05, "v": 0.02, "w": 0.02, "p": 0.002, "q": 0.002, "r": 0.002,
             "phi": 0.003, "theta": 0.003, "psi": 0.01, "z": 0.05}  # fmt: skip
FIN_NOISE_STD = 2e-5


@dataclass(frozen=True)
class Sensors:
    """Sample rate and per-channel noise (standard deviations, SI)."""

    rate: float = 50.0  # Hz
    noise_std: Mapping[str, float] = field(default_factory=lambda: dict(NOISE_STD))
    fin_std: float = FIN_NOISE_STD

    def __post_init__(self):
        if not 0 < self.rate < math.inf:
            raise InputError(f"sample rate {self.rate}; expected a finite number > 0 (Hz)")
        for name, s in self.noise_std.items():
            if name not in STATES:
                raise InputError(f"noise for {name!r}: not a state; expected one of {', '.join(STATES)}")
            if not 0 <= s < math.inf:
                raise InputError(f"noise for {name!r} = {s}; expected a finite number >= 0")
        if not 0 <= self.fin_std < math.inf:
            raise InputError(f"fin noise {self.fin_std}; expected a finite number >= 0 (rad)")


def check_seed(seed) -> int:
    """`seed` as an int; InputError unless it is a non-negative integer (numpy's seeds are)."""
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral) or seed < 0:
        raise InputError(f"seed {seed!r}; expected a non-negative integer")
    return int(seed)


def rng_for(seed: int, experiment: int, stream: int = 0) -> np.random.Generator:
    """The generator of one experiment's random stream (0: sensor noise, 1: input sequences)."""
    seed = check_seed(seed)
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(experiment, stream)))


def measure(truth: np.ndarray, fins: np.ndarray, sensors: Sensors,
            rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Noisy copies of the true states (N, 10) and fin angles (N, 3)."""
    std = np.array([sensors.noise_std.get(s, 0.0) for s in STATES])
    states = truth + rng.standard_normal(truth.shape) * std
    angles = fins + rng.standard_normal(fins.shape) * sensors.fin_std
    return states, angles
