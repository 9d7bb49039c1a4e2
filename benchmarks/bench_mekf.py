"""MEKF throughput on Scenario II-like data: `python3 benchmarks/bench_mekf.py`.

Data: the SPEC linear model of a torpedo like the bundled one at 20 m/s, simulated exactly (ZOH)
for a horizontal run (rudder PRBS, small elevator PRBS) and a vertical run (elevator PRBS, with
a small differential so the roll controls stay apart), 60 s each, all ten states measured with
noise, at 20 and 50 Hz; the 21 free coefficients are all but the *dot terms, started 20 % off.
Prints samples per second, the ratio to the sample rate (goal ≥ 20× real time), and the plain
linear filterpy `KalmanFilter` (10 states, known model) on the same data as the in-run reference.
"""

from __future__ import annotations

import time

import numpy as np
from filterpy.kalman import KalmanFilter

from testbed.data import Experiment, ModelConfig
from testbed.estimators import identify
from testbed.model import COEFFICIENTS, STATES, Vehicle, continuous, discretize, structure, theta_vector

VEHICLE = Vehicle(170.75, 2.16, 67.25, 67.24, 1675.1, 1675.1, 0.0, 0.0, -0.0179, 20.0)
TRUTH = dict(zip(COEFFICIENTS, (
    -8.11, -265.6, -158.6, -2.99, -2.35, -2135.1, -4.30, 2217.8, 42505.7, -158.6, 2.35, -2135.1,
    -2217.8, -42505.7, -2.99, -0.395, -0.426, -4.30, -124.8, 2.48, 0.0, -3613.0, -3613.0, 2.35,
    -55.76, 630.6, -2791.2, -47273.4, -2.35, -0.426, -55.76, -630.6, -55.41, -2791.1, -47273.4,
)))  # fmt: skip
FREE = tuple(n for n in COEFFICIENTS if not n.endswith("dot"))
NOISE = np.array([0.01, 0.01, 0.01, 0.002, 0.002, 0.002, 0.002, 0.002, 0.002, 0.01])
DURATION = 60.0


def prbs(rng, n, dt, amp, hold):
    k = max(1, round(hold / dt))
    return np.repeat(rng.choice([-amp, amp], size=n // k + 1), k)[:n]


def scenario_ii(dt, seed=0):
    """The two experiments and the true discrete model."""
    rng = np.random.default_rng(seed)
    n, a = round(DURATION / dt), np.deg2rad(2.0)
    horizontal = np.column_stack([prbs(rng, n, dt, a, 0.5), prbs(rng, n, dt, 0.3 * a, 1.0),
                                  prbs(rng, n, dt, 0.3 * a, 1.0)])  # fmt: skip
    elevator = prbs(rng, n, dt, a, 0.5)
    vertical = np.column_stack([prbs(rng, n, dt, 0.3 * a, 1.0),
                                elevator + prbs(rng, n, dt, 0.2 * a, 0.7),
                                elevator - prbs(rng, n, dt, 0.2 * a, 0.7)])  # fmt: skip
    model = discretize(*continuous(structure(VEHICLE), theta_vector(TRUTH)), dt)
    Phi, Gamma, s = model
    experiments = []
    for name, inputs in (("horizontal", horizontal), ("vertical", vertical)):
        x, X = np.zeros(10), np.zeros((n, 10))
        for k, d in enumerate(inputs):
            X[k], x = x, Phi @ x + Gamma @ d + s
        Y = X + rng.normal(size=X.shape) * NOISE
        Y[:, 0] += VEHICLE.speed
        experiments.append(Experiment(name, np.arange(n) * dt, STATES, Y, inputs))
    return experiments, model


def filterpy_rate(experiments, model) -> float:
    """Samples per second of filterpy's linear KalmanFilter (10 states, known model)."""
    Phi, Gamma, s = model
    start = time.perf_counter()
    count = 0
    for e in experiments:
        kf = KalmanFilter(dim_x=10, dim_z=10, dim_u=4)
        kf.F, kf.B, kf.H = Phi, np.column_stack([Gamma, s]), np.eye(10)
        kf.R, kf.Q = np.diag(NOISE**2), np.diag((0.1 * NOISE) ** 2)
        y = e.y - np.eye(10)[0] * VEHICLE.speed
        for k in range(len(e.t)):
            kf.update(y[k])
            kf.predict(np.append(e.inputs[k], 1.0))
            count += 1
    return count / (time.perf_counter() - start)


def main() -> None:
    rng = np.random.default_rng(1)
    start = {n: TRUTH[n] * (1 + 0.2 * rng.choice([-1, 1])) for n in FREE}
    config = ModelConfig(VEHICLE, dict(TRUTH), FREE).with_coefficients(start)
    truth = np.array([TRUTH[n] for n in FREE])
    print(f"Scenario II-like: 2 × {DURATION:g} s, 10 states measured, {len(FREE)} free coefficients")
    for rate in (20.0, 50.0):
        experiments, model = scenario_ii(1.0 / rate)
        samples = sum(len(e.t) for e in experiments)
        reference = filterpy_rate(experiments, model)
        for method, opts, label in (("mekf", {}, "mekf (refresh_tol=0.1, default)"),
                                    ("mekf", {"refresh_tol": 0.0}, "mekf (exact model every sample)"),
                                    ("ekf", {}, "ekf (conventional)")):  # fmt: skip
            est = identify(experiments, config, method, **opts)
            sps = samples / est.wall_time_s
            z = np.abs(est.values - truth) / est.std
            print(f"  {rate:4.0f} Hz  {label:34s} {sps:8.0f} samples/s = {sps / rate:6.1f}× real "
                  f"time = {sps / reference:5.3f}× filterpy KF  [{est.status.name}, "
                  f"max |error|/σ {z.max():.2f}]")  # fmt: skip
        print(f"  {rate:4.0f} Hz  {'filterpy KalmanFilter (linear, known)':34s} {reference:8.0f} "
              f"samples/s = {reference / rate:6.1f}× real time")  # fmt: skip


if __name__ == "__main__":
    main()
