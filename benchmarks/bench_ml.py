"""Benchmark: `ml-gn` against a plain `scipy.optimize.least_squares` output-error fit.

Same data (the Monte Carlo study's two experiments, 60 s each at 20 Hz, all states measured),
same start (a-priori values 30 % off, best-fitting initial states), same free set (15
coefficients) and the same estimated initial states (20 more parameters). The reference is
`benchmarks/scipy_reference.py`: scipy's defaults (trf, 2-point finite-difference Jacobian) on
the same simulator, with the noise covariance relaxed the same way (R from the residuals, refit,
until R settles). Goal: ml-gn ≥ 10× faster at equal or better accuracy; each timed as the best
of five runs, the two alternating. Both run with single-threaded BLAS (set before numpy loads):
the matrices are small, and on a shared 2-core machine BLAS threads only add synchronisation
noise. (`benchmarks/bench_command.py` measures the same two as whole commands.)

    python3 benchmarks/bench_ml.py [--rounds 5]

The command beside the library cell (`identify(data, prior, method="ml-gn", start="config")`):
the same two records written as measurement CSVs (`testbed.data.write_csv`, `horizontal.csv`,
`vertical.csv`) and the same prior as a model config (`write_config`, `prior.toml`: its 15
coefficients an explicit free list) into a temporary folder, then `testbed identify
horizontal.csv vertical.csv --config prior.toml --out est.json` with default options, as a
process from its start to its exit (the console script beside this interpreter; one untimed run
first, so Python's byte code is cached as for any user; best of `--rounds`): start-up, reading,
the screen (only reported for an explicit list; its `ml-gn` fit, from the default `auto` starts,
is the fit itself), the Cramér-Rao analysis, validation and writing. Printed: both times, the
ratio command / cell, the fit the command's estimates JSON reports (`wall_time_s`,
`iterations`, the starts tried), and where the two differ by more than 3× a line saying why,
measured stage by stage in one more run of the command (`workload.why`); both also in units of
a fixed numpy workload timed in the same run (`workload.machine`).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

from testbed.threads import one_blas_thread

one_blas_thread()  # as the command line does, before numpy loads

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks.scipy_reference import scipy_fit  # noqa: E402
from benchmarks.workload import beside, console  # noqa: E402
from testbed.data import write_config, write_csv  # noqa: E402
from testbed.estimators import identify  # noqa: E402
from studies.remus import FREE, EXAMPLE_COEFFICIENTS, experiments, prior_config  # noqa: E402


def _best(runs, rounds: int = 5):
    """Per run: the shortest wall time of `rounds` calls, and the last call's result. The runs
    alternate, so a slow spell of a shared machine hits both alike."""
    times, out = [[] for _ in runs], [None] * len(runs)
    for _ in range(rounds):
        for i, run in enumerate(runs):
            t0 = time.perf_counter()
            out[i] = run()
            times[i].append(time.perf_counter() - t0)
    return [(min(t), o) for t, o in zip(times, out)]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=5, help="runs of the command (the best counts)")
    args = ap.parse_args(argv)
    data = experiments(seed=0)
    prior = prior_config(error=0.3)
    simulated = np.array([EXAMPLE_COEFFICIENTS[n] for n in FREE])
    # best of five each: the first call in a process also loads compiled code from numba's cache
    (t_gn, est), (t_ls, (values, nfev, rounds)) = _best(
        [lambda: identify(data, prior, method="ml-gn", start="config"), lambda: scipy_fit(data, prior)]
    )
    z_gn = (est.values - simulated) / est.std
    z_ls = (values - simulated) / est.std
    print(
        f"BLAS threads: {os.environ['OPENBLAS_NUM_THREADS']}; "
        f"data: 2 experiments x {len(data[0].t)} samples, {len(FREE)} coefficients + "
        f"{sum(len(e.measured) for e in data)} initial states, start 30 % off"
    )
    print(
        f"{'coefficient':12s} {'simulated':>10s} {'ml-gn':>10s} {'scipy':>10s} {'gn err/σ':>9s} {'ls err/σ':>9s}"
    )
    for n, t, a, b, za, zb in zip(FREE, simulated, est.values, values, z_gn, z_ls):
        print(f"{n:12s} {t:10.4g} {a:10.4g} {b:10.4g} {za:9.2f} {zb:9.2f}")
    print(
        f"ml-gn : {t_gn:7.3f} s, {est.iterations} iterations, {est.status.name}, "
        f"rms error {np.sqrt(np.mean(z_gn**2)):.3f} σ"
    )
    print(
        f"scipy : {t_ls:7.3f} s, {nfev} model evaluations in {rounds} R-relaxation rounds, "
        f"rms error {np.sqrt(np.mean(z_ls**2)):.3f} σ"
    )
    print(
        f"speed ratio scipy/ml-gn: {t_ls / t_gn:.1f}x (goal >= 10x); "
        f"max |ml-gn − scipy| = {np.max(np.abs(z_gn - z_ls)):.3f} σ"
    )
    testbed = console()
    with tempfile.TemporaryDirectory() as tmp:
        csvs = [write_csv(Path(tmp) / f"{e.name}.csv", e.t, e.y, e.inputs, e.measured).name for e in data]
        write_config(Path(tmp) / "prior.toml", prior)

        def user(out):  # the command as a user types it, default options
            return [testbed, "identify", *csvs, "--config", "prior.toml", "--out", out]

        cell = f"ml-gn from the config start, {est.iterations} iterations, {len(FREE)} free"
        lines = beside(user, tmp, args.rounds, "ml-gn", t_gn, cell)
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
