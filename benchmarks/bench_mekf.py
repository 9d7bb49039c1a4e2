"""MEKF throughput: `python benchmarks/bench_mekf.py [--repeat N] [--no-synthetic]`.

Goal: the MEKF processes Scenario II data at least 20× faster than real time (samples per second
over the sample rate).

Primary case, the real one: a Scenario II run made here as `testbed simulate --scenario II
--seed 1` makes it (MuJoCo plant, autopilots, sensor noise; 50 Hz, 2 × 60 s, ten states
measured) and identified as `testbed identify RUN --method mekf` does: the run's `model.toml`
as the a-priori config with its default free list (20 coefficients), noise σ from the data.
Printed for each filter variant: samples per second, the ratio to the sample rate (× real time),
the ratio to the in-run reference — filterpy's plain linear `KalmanFilter` (10 states, the
config's model known and fixed) over the same samples — and the largest change of a final
estimate against the filter that recomputes the exact model every sample (refresh_tol=0), in
units of its σ (the price of the default's model refresh policy).

Secondary, synthetic: the linear model of a torpedo like the bundled one simulated exactly
(ZOH), 20 and 50 Hz, 21 free coefficients started 20 % off; here the coefficients the data were simulated from are known, so the
largest |error|/σ against it is printed as well.

Timing: single-threaded BLAS as the command line sets it; best of `--repeat` runs (other load on
the machine only ever slows a run down).

The command beside the library cell (the default variant's fit above, its own clock
`wall_time_s`): `testbed identify II-seed1 --method mekf --out est.json` on the same freshly
made run directory, with default options, as a process from its start to its exit (the console
script beside this interpreter; one untimed run first, so Python's byte code is cached as for
any user; best of `--repeat`): start-up, reading the run and its noise-free `.truth.csv` files,
the screen of model.toml's candidate list (its own `ml-gn` fit; the MEKF then fits only the
candidates it leaves free, where the cell fits all 20), the MEKF, the comparison with the
analytic model (an `ml-gn` fit to the noise-free records), validation and writing (the estimates
and their `.history.csv`). Printed: both times, the ratio command / cell, the fit the command's
estimates JSON reports (`wall_time_s`, samples, the screen's fixes), and where the two differ by
more than 3× a line saying why, measured stage by stage in one more run of the command
(`workload.why`); both also in units of a fixed numpy workload timed in the same run
(`workload.machine`).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

from testbed.threads import one_blas_thread

one_blas_thread()  # as the command line does, before numpy loads

import numpy as np  # noqa: E402
from filterpy.kalman import KalmanFilter  # noqa: E402

from testbed.data import Experiment, ModelConfig, load_data  # noqa: E402
from testbed.estimators import Estimate, identify  # noqa: E402
from testbed.simulation.measurements import noise_from_data  # noqa: E402
from testbed.models.linear import (  # noqa: E402
    COEFFICIENTS,
    STATES,
    Vehicle,
    continuous,
    discretize,
    structure,
    theta_vector,
)
from workload import beside, console  # noqa: E402

GOAL = 20.0  # × real time
VARIANTS = (
    ("mekf (default: refresh_tol=0.2)", "mekf", {}),
    ("mekf (exact model every sample)", "mekf", {"refresh_tol": 0.0}),
    ("mekf (sqrt='svd', the paper's)", "mekf", {"sqrt": "svd"}),
    ("ekf (conventional)", "ekf", {}),
)


def filterpy_rate(experiments, config: ModelConfig, noise: dict[str, float]) -> float:
    """Samples per second of filterpy's linear KalmanFilter (10 states, the config's model)."""
    Phi, Gamma, s = discretize(
        *continuous(structure(config.vehicle), theta_vector(config.coefficients)), experiments[0].dt
    )
    start = time.perf_counter()
    count = 0
    for e in experiments:
        sr = np.array([noise[n] for n in e.measured])
        kf = KalmanFilter(dim_x=10, dim_z=len(e.measured), dim_u=4)
        kf.F, kf.B = Phi, np.column_stack([Gamma, s])
        kf.H = np.eye(10)[[STATES.index(n) for n in e.measured]]
        kf.R, kf.Q = np.diag(sr**2), np.diag(np.full(10, 1e-6))
        y = e.y.copy()
        if "u" in e.measured:
            y[:, e.measured.index("u")] -= config.vehicle.speed
        for k in range(len(e.t)):
            kf.update(y[k])
            kf.predict(np.append(e.inputs[k], 1.0))
            count += 1
    return count / (time.perf_counter() - start)


def measure(experiments, config, repeat: int, simulated=None, indent="  ") -> tuple[float, Estimate]:
    """Print one line per variant; returns the default's × real time and its fastest fit."""
    samples = sum(len(e.t) for e in experiments)
    rate = 1.0 / experiments[0].dt
    reference = max(filterpy_rate(experiments, config, noise_from_data(experiments)) for _ in range(repeat))
    exact, default_ratio = None, None
    for label, method, opts in VARIANTS:
        runs = [identify(experiments, config, method, **opts) for _ in range(repeat)]
        est = min(runs, key=lambda r: r.wall_time_s)
        sps = samples / est.wall_time_s
        if method == "mekf" and opts.get("refresh_tol") == 0.0:
            exact = est
        line = (
            f"{indent}{rate:4.0f} Hz  {label:34s} {sps:7.0f} samples/s = {sps / rate:6.1f}× real "
            f"time = {sps / reference:5.3f}× filterpy KF  [{est.status.name}"
        )
        if simulated is not None:
            line += f", max |error|/σ {np.max(np.abs(est.values - simulated) / est.std):.2f}"
        print(line + "]", flush=True)
        if default_ratio is None:
            default, default_ratio = est, sps / rate
    if exact is not None and exact.status.name != "DIVERGED":
        dev = np.max(np.abs(default.values - exact.values) / exact.std)
        print(f"{indent}      default vs exact model every sample: max |Δ estimate| = {dev:.3f} σ")
    print(
        f"{indent}{rate:4.0f} Hz  {'filterpy KalmanFilter (linear, known)':34s} {reference:7.0f} "
        f"samples/s = {reference / rate:6.1f}× real time"
    )
    return default_ratio, default


# ---------------------------------------------------------------- the synthetic case

VEHICLE = Vehicle(170.75, 2.16, 67.25, 67.24, 1675.1, 1675.1, 0.0, 0.0, -0.0179, 20.0)
SIMULATED = dict(
    zip(
        COEFFICIENTS,
        (
            -8.11,
            -265.6,
            -158.6,
            -2.99,
            -2.35,
            -2135.1,
            -4.30,
            2217.8,
            42505.7,
            -158.6,
            2.35,
            -2135.1,
            -2217.8,
            -42505.7,
            -2.99,
            -0.395,
            -0.426,
            -4.30,
            -124.8,
            2.48,
            0.0,
            -3613.0,
            -3613.0,
            2.35,
            -55.76,
            630.6,
            -2791.2,
            -47273.4,
            -2.35,
            -0.426,
            -55.76,
            -630.6,
            -55.41,
            -2791.1,
            -47273.4,
        ),
    )
)
FREE = tuple(n for n in COEFFICIENTS if not n.endswith("dot"))
NOISE = np.array([0.01, 0.01, 0.01, 0.002, 0.002, 0.002, 0.002, 0.002, 0.002, 0.01])
DURATION = 60.0


def prbs(rng, n, dt, amp, hold):
    k = max(1, round(hold / dt))
    return np.repeat(rng.choice([-amp, amp], size=n // k + 1), k)[:n]


def synthetic(dt, seed=0):
    """A horizontal run (rudder PRBS, small elevator PRBS) and a vertical one (elevator PRBS with
    a small differential so the roll controls stay apart), exact ZOH, all ten states measured."""
    rng = np.random.default_rng(seed)
    n, a = round(DURATION / dt), np.deg2rad(2.0)
    horizontal = np.column_stack(
        [prbs(rng, n, dt, a, 0.5), prbs(rng, n, dt, 0.3 * a, 1.0), prbs(rng, n, dt, 0.3 * a, 1.0)]
    )
    elevator = prbs(rng, n, dt, a, 0.5)
    vertical = np.column_stack(
        [
            prbs(rng, n, dt, 0.3 * a, 1.0),
            elevator + prbs(rng, n, dt, 0.2 * a, 0.7),
            elevator - prbs(rng, n, dt, 0.2 * a, 0.7),
        ]
    )
    Phi, Gamma, s = discretize(*continuous(structure(VEHICLE), theta_vector(SIMULATED)), dt)
    experiments = []
    for name, inputs in (("horizontal", horizontal), ("vertical", vertical)):
        x, X = np.zeros(10), np.zeros((n, 10))
        for k, d in enumerate(inputs):
            X[k], x = x, Phi @ x + Gamma @ d + s
        Y = X + rng.normal(size=X.shape) * NOISE
        Y[:, 0] += VEHICLE.speed
        experiments.append(Experiment(name, np.arange(n) * dt, STATES, Y, inputs))
    return experiments


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=3, help="runs of each measurement (best kept)")
    ap.add_argument("--no-synthetic", action="store_true", help="the real Scenario II run only")
    args = ap.parse_args(argv)

    from testbed.simulation.runs import simulate

    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        run = simulate("II", seed=1, out=Path(tmp) / "II-seed1")
        made = time.perf_counter() - t0
        experiments, config = load_data([run])  # as `testbed identify RUN --method mekf`
        samples = sum(len(e.t) for e in experiments)
        print(
            f"Scenario II run (testbed simulate --scenario II --seed 1, made in {made:.1f} s): "
            f"{len(experiments)} experiments, {samples} samples at {1 / experiments[0].dt:g} Hz, "
            f"{len(config.free)} free coefficients (model.toml), BLAS threads "
            f"{os.environ['OPENBLAS_NUM_THREADS']}, best of {args.repeat}"
        )
        ratio, cell = measure(experiments, config, args.repeat)
        print(
            f"  goal ≥ {GOAL:g}× real time: {'met' if ratio >= GOAL else 'NOT MET'} "
            f"({ratio:.1f}×, margin {ratio / GOAL:.1f}×)"
        )
        testbed = console()

        def user(out):  # the command as a user types it, default options
            return [testbed, "identify", run.name, "--method", "mekf", "--out", out]

        what = (
            f"the default MEKF on model.toml's {len(cell.free)} candidates unscreened, "
            f"{cell.iterations} samples"
        )
        lines = beside(user, tmp, args.repeat, "(default variant)", cell.wall_time_s, what)
    print("\n".join(f"  {line}" for line in lines))

    if args.no_synthetic:
        return
    rng = np.random.default_rng(1)
    start = {n: SIMULATED[n] * (1 + 0.2 * rng.choice([-1, 1])) for n in FREE}
    config = ModelConfig(VEHICLE, dict(SIMULATED), FREE).with_coefficients(start)
    simulated = np.array([SIMULATED[n] for n in FREE])
    print(
        f"Synthetic (linear model, exact ZOH): 2 × {DURATION:g} s, 10 states measured, "
        f"{len(FREE)} free coefficients started 20 % off"
    )
    for rate in (20.0, 50.0):
        measure(synthetic(1.0 / rate), config, args.repeat, simulated)


if __name__ == "__main__":
    main()
