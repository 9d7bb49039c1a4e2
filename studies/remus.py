"""The REMUS-class example vehicle: a small AUV with REMUS-like linear coefficients, and
synthetic experiments simulated exactly from the linear model (`prediction.synthetic`).

The data's model is known exactly, so the studies (Monte Carlo against the Cramér-Rao bounds,
the bad-input corpus), the benchmarks and the tests use it wherever an estimator is to be checked
against the coefficients the data were simulated from rather than against the MuJoCo plant. Two Scenario-II-like experiments: a
rudder PRBS, and an elevator PRBS with a differential part for roll; all ten states measured.
"""

from __future__ import annotations

import numpy as np

from testbed.data import Experiment, ModelConfig
from testbed.identification.prediction import synthetic
from testbed.models.linear import COEFFICIENTS, Vehicle

__all__ = [
    "EXAMPLE_COEFFICIENTS",
    "FREE",
    "NOISE",
    "VEHICLE",
    "example_config",
    "experiments",
    "inputs",
    "prior_config",
    "unstable_config",
]

VEHICLE = Vehicle(
    mass=30.51,
    Ix=0.177,
    Iy=3.45,
    Iz=3.45,
    weight=299.0,
    buoyancy=306.0,
    xB=0.0,
    yB=0.0,
    zB=-0.0196,
    speed=1.54,
)
_U = VEHICLE.speed
# REMUS-like linear coefficients (Prestero 2001, linearised at U), with the Munk moments and the
# rate damping adjusted so that the linear model is stable in both planes.
EXAMPLE_COEFFICIENTS = dict.fromkeys(COEFFICIENTS, 0.0) | dict(
    X_udot=-0.93,
    X_u=-2 * 1.62 * _U,
    Y_vdot=-35.5,
    Y_rdot=1.93,
    Y_v=-28.6 * _U,
    Y_r=5.22 * _U,
    Y_dr=9.64 * _U**2,
    Z_wdot=-35.5,
    Z_qdot=-1.93,
    Z_w=-28.6 * _U,
    Z_q=-5.22 * _U,
    Z_de=-9.64 * _U**2,
    K_pdot=-0.0141,
    K_p=-0.3,
    K_der=0.5,
    K_del=0.5,
    M_wdot=-1.93,
    M_qdot=-4.88,
    M_w=6.0,
    M_q=-8.0,
    M_de=-6.15 * _U**2,
    N_vdot=1.93,
    N_rdot=-4.88,
    N_v=-6.0,
    N_r=-8.0,
    N_dr=-6.15 * _U**2,
)
# Well posed (no structural null direction): damping and control terms, added-mass terms fixed.
FREE = (
    "Y_v",
    "Y_r",
    "Y_dr",
    "N_v",
    "N_r",
    "N_dr",
    "Z_w",
    "Z_q",
    "Z_de",
    "M_w",
    "M_q",
    "M_de",
    "K_p",
    "K_der",
    "K_del",
)
NOISE = dict(u=0.01, v=0.01, w=0.01, p=0.003, q=0.003, r=0.003, phi=0.002, theta=0.002, psi=0.002, z=0.02)


def example_config(free=FREE) -> ModelConfig:
    """The example vehicle at its own coefficients, `free` to be identified."""
    return ModelConfig(VEHICLE, dict(EXAMPLE_COEFFICIENTS), tuple(free), "example")


def prior_config(free=FREE, error: float = 0.3) -> ModelConfig:
    """A-priori values `error` off the example's coefficients, alternating sign (a stable starting model)."""
    off = {n: EXAMPLE_COEFFICIENTS[n] * (1 + error if i % 3 == 0 else 1 - error) for i, n in enumerate(free)}
    return example_config(free).with_coefficients(off)


def unstable_config(free=FREE) -> ModelConfig:
    """The example vehicle with its yaw damping N_r reversed (−0.62 × the example's): a sway-yaw
    mode growing at +0.80 1/s, course-unstable as published linear AUV models often are; an
    a-priori model whose response diverges over a record of more than a few seconds."""
    return example_config(free).with_coefficients({"N_r": -0.62 * EXAMPLE_COEFFICIENTS["N_r"]})


def _prbs(rng: np.random.Generator, n: int, hold: int, amplitude: float) -> np.ndarray:
    levels = rng.integers(0, 2, size=n // hold + 1) * 2.0 - 1.0
    return np.repeat(levels, hold)[:n] * amplitude


def inputs(duration: float = 60.0, dt: float = 0.05, seed: int = 0) -> dict[str, tuple]:
    """Scenario-II-like designs: name → (t, inputs (N, 3))."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration, dt)
    n = len(t)
    horizontal = np.zeros((n, 3))
    horizontal[:, 0] = _prbs(rng, n, int(1.5 / dt), 0.1)
    vertical = np.zeros((n, 3))
    common, differential = _prbs(rng, n, int(1.5 / dt), 0.1), _prbs(rng, n, int(0.85 / dt), 0.05)
    vertical[:, 1], vertical[:, 2] = common + differential, common - differential
    return {"horizontal": (t, horizontal), "vertical": (t, vertical)}


def experiments(
    seed: int, duration: float = 60.0, dt: float = 0.05, noise: dict | None = NOISE
) -> list[Experiment]:
    """The two experiments with noise realisation `seed` (the input design is fixed)."""
    rng = np.random.default_rng(10_000 + seed)
    return [
        synthetic(example_config(), t, u, noise, rng=rng, name=name)
        for name, (t, u) in inputs(duration, dt).items()
    ]
