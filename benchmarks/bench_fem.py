"""Benchmark: `ml-fem` against `ml-gn` on the same Scenario-II-like data with process noise.

The bundled torpedo's analytic linear model flies three 60 s experiments at 50 Hz (a rudder PRBS,
an elevator PRBS, a differential-elevator PRBS, each held 1 s), every state measured with the
sensors' noise, process noise on every body row (σ 0.02 m/s/√s on u v w, 0.005 rad/s/√s on p q r).
Both fit the 17 coefficients Scenario II's screen keeps (the analytic candidates but Y_p, K_r,
K_dr) from the same start, the a-priori values × exp(0.3 N(0, 1)); each timed as the best of
three runs, the two alternating, with single-threaded BLAS. Prints both times, their ratio, the
iterations and each method's errors in its own σ.

    python3 benchmarks/bench_fem.py [--rounds 3]

The command beside the library cell (`identify(data, start, method="ml-fem")`): the same three
records written as measurement CSVs (`testbed.data.write_csv`: `horizontal.csv`, `vertical.csv`,
`roll.csv`) and the same start as a model config (`write_config`, `start.toml`: the 17
coefficients an explicit free list) into a temporary folder, then `testbed identify
horizontal.csv vertical.csv roll.csv --config start.toml --method ml-fem --out est.json` with
default options, as a process from its start to its exit (the console script beside this
interpreter; one untimed run first, so Python's byte code is cached as for any user; best of
`--rounds`): start-up, reading, the screen (only reported for an explicit list, but run: its
own `ml-gn` fit from the default `auto` starts), the `ml-fem` fit (its default start `config`),
validation and writing. Printed: both times, the ratio command / cell, the fit the command's
estimates JSON reports (`wall_time_s`, `iterations`), and where the two differ by more than 3×
a line saying why, measured stage by stage in one more run of the command (`workload.why`);
both also in units of a fixed numpy workload timed in the same run (`workload.machine`).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import tempfile
import time
from pathlib import Path

from testbed.threads import one_blas_thread

one_blas_thread()  # as the command line does, before numpy loads

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks.workload import beside, console  # noqa: E402
from testbed.data import Experiment, write_config, write_csv  # noqa: E402
from testbed.estimators import identify  # noqa: E402
from testbed.identification.innovations import process_covariance  # noqa: E402
from testbed.models.linear import INPUTS, IX, STATES, continuous, discretize, structure, theta_vector  # noqa: E402
from testbed.simulation.analytic import FREE as CANDIDATES, analytic_config  # noqa: E402
from testbed.simulation.measurements import NOISE_STD  # noqa: E402

FREE = tuple(n for n in CANDIDATES if n not in ("Y_p", "K_r", "K_dr"))
DT, DURATION = 0.02, 60.0
F = dict(u=0.02, v=0.02, w=0.02, p=0.005, q=0.005, r=0.005)


def _data(config, seed: int) -> list[Experiment]:
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, DURATION, DT)
    A, B, S = continuous(structure(config.vehicle), theta_vector(config.coefficients))
    Phi, Gamma, s = discretize(A, B, S, DT)
    lam, V = np.linalg.eigh(process_covariance(A, np.array([F[n] ** 2 for n in STATES[:6]]), DT))
    L = V * np.sqrt(np.maximum(lam, 0.0))
    sigma = np.array([NOISE_STD[n] for n in STATES])

    def prbs(amplitude):
        return amplitude * np.repeat(rng.choice([-1.0, 1.0], size=len(t) // 50 + 1), 50)[: len(t)]

    designs = {
        "horizontal": (prbs(0.01), 0.0, 0.0),
        "vertical": (0.0, prbs(0.005), 0.0),
        "roll": (0.0, 0.0, 1.0),
    }
    out = []
    for name, (rudder, elevator, roll) in designs.items():
        u = np.zeros((len(t), len(INPUTS)))
        u[:, 0] = rudder
        differential = prbs(0.005) * roll
        u[:, 1], u[:, 2] = elevator + differential, elevator - differential
        x = np.zeros((len(t), len(STATES)))
        for k in range(len(t) - 1):
            x[k + 1] = Phi @ x[k] + Gamma @ u[k] + s + L @ rng.normal(size=len(STATES))
        x[:, IX["u"]] += config.vehicle.speed
        out.append(Experiment(name, t, STATES, x + sigma * rng.normal(size=x.shape), u))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=3, help="runs of the command (the best counts)")
    args = ap.parse_args(argv)
    config, _ = analytic_config()
    config = dataclasses.replace(config, free=FREE, screen=False)
    data = _data(config, seed=1)
    rng = np.random.default_rng(2)
    start = config.with_coefficients({n: config.coefficients[n] * np.exp(0.3 * rng.normal()) for n in FREE})
    runs = {
        "ml-fem": lambda: identify(data, start, method="ml-fem"),
        "ml-gn": lambda: identify(data, start, method="ml-gn", start="config"),
    }
    times, est = {m: [] for m in runs}, {}
    for _ in range(3):
        for m, run in runs.items():
            t0 = time.perf_counter()
            est[m] = run()
            times[m].append(time.perf_counter() - t0)
    truth = np.array([config.coefficients[n] for n in FREE])
    print(
        f"BLAS threads: {os.environ['OPENBLAS_NUM_THREADS']}; data: 3 experiments x {len(data[0].t)} samples, "
        f"10 states measured, process noise on the six body rows; {len(FREE)} coefficients, start × exp(0.3 N(0,1))"
    )
    print(f"{'coefficient':12s} {'analytic':>11s} {'fem err/σ':>10s} {'gn err/σ':>10s}")
    z = {m: (e.values - truth) / e.std for m, e in est.items()}
    for n, v, a, b in zip(FREE, truth, z["ml-fem"], z["ml-gn"]):
        print(f"{n:12s} {v:11.5g} {a:10.2f} {b:10.2f}")
    for m, e in est.items():
        print(
            f"{m:7s}: {min(times[m]):6.2f} s, {e.iterations} iterations, {e.status.name}, "
            f"rms error {np.sqrt(np.mean(z[m] ** 2)):.2f} σ"
        )
    print(f"time ratio ml-fem / ml-gn: {min(times['ml-fem']) / min(times['ml-gn']):.1f}x")
    print(
        "process noise σ (true / ml-fem):",
        {k: (F[k], round(v["value"], 4)) for k, v in est["ml-fem"].process_noise_std.items()},
    )
    testbed, t_fem = console(), min(times["ml-fem"])
    with tempfile.TemporaryDirectory() as tmp:
        csvs = [write_csv(Path(tmp) / f"{e.name}.csv", e.t, e.y, e.inputs, e.measured).name for e in data]
        write_config(Path(tmp) / "start.toml", start)

        def user(out):  # the command as a user types it, default options
            return [testbed, "identify", *csvs, "--config", "start.toml", "--method", "ml-fem", "--out", out]

        cell = f"ml-fem from the start, {est['ml-fem'].iterations} iterations, {len(FREE)} free"
        lines = beside(user, tmp, args.rounds, "ml-fem", t_fem, cell)
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
