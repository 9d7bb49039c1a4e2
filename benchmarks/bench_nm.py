"""Benchmark: `ml-nm` on the default Scenario II run, as a campaign cell fits it and as a user's
command (goal ≤ 10 s on one core for each).

    python benchmarks/bench_nm.py [--seed 1] [--rounds 2]

The data: `testbed simulate --scenario II --seed 1` (three 60 s records at 50 Hz, all states
measured) in a temporary folder. The fit: what `testbed reproduce` does in a cell
(`study.campaign.run_cell` → `analysis.identify_screened`): the run's candidates screened at the
analytic model (model.toml), then the ones the screen leaves free fitted from the analytic
model (`start = "config"`). The screen is run once and not timed; the reference measured in the
same run is `ml-gn` on the same data, free set and start. Simulations are counted by wrapping
the cost the simplex evaluates (`concentrated.Cost`), each a simulation of every record at one
θ with its initial states solved. The estimates are compared in Cramér-Rao σ (ml-gn's `std`)
and the costs in units of ½χ²₁. Single-threaded BLAS and numba, set before numpy loads; the
compiled recursions are loaded before the clock starts (as in a campaign's worker, which fits
many cells).

The command: `testbed identify RUN --method ml-nm --out est.json` on a fresh run directory
(`testbed simulate --scenario II --seed 1 --out RUN`, untimed), default options, as a process
from its start to its exit (best of `--rounds`): start-up, reading, the screen (its own
`ml-gn` fit), `ml-nm` from the default starts (the a-priori values and the equation-error
estimate, which stops where it enters the first one's basin), the Cramér-Rao analysis, the
comparison with the analytic model, validation and writing. Both are also printed in units of
a fixed numpy workload timed in the same run (`workload.machine`), against the goal in those
units (10 s at the workload's reference time).
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
os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from testbed.analysis.screening import screening  # noqa: E402
from testbed.data import load_data  # noqa: E402
from testbed.estimators import identify  # noqa: E402
from testbed.identification import concentrated  # noqa: E402
from testbed.simulation.runs import simulate  # noqa: E402
from workload import REFERENCE_S, command, console, machine  # noqa: E402

GOAL = 10.0  # s, ml-nm on one core


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seed", type=int, default=1, help="the run's noise seed")
    ap.add_argument("--rounds", type=int, default=2, help="runs of the command (the best counts)")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        run = Path(tmp) / "run"
        simulate("II", seed=args.seed, out=run)
        experiments, analytic = load_data([run])
    fitted = screening(experiments, analytic).config
    samples = sum(len(e.t) for e in experiments)

    count = [0]
    call = concentrated.Cost.__call__

    def counted(self, *a, **k):
        count[0] += 1
        return call(self, *a, **k)

    identify(experiments, fitted, method="ml-nm", start="config", max_iter=1)  # compiled code loaded
    concentrated.Cost.__call__ = counted
    try:
        count[0] = 0
        t0 = time.perf_counter()
        nm = identify(experiments, fitted, method="ml-nm", start="config")
        t_nm = time.perf_counter() - t0
    finally:
        concentrated.Cost.__call__ = call
    t0 = time.perf_counter()
    gn = identify(experiments, fitted, method="ml-gn", start="config")
    t_gn = time.perf_counter() - t0

    z = (nm.values - gn.values) / gn.std
    print(
        f"BLAS threads: {os.environ['OPENBLAS_NUM_THREADS']}, numba threads: {os.environ['NUMBA_NUM_THREADS']}; "
        f"data: Scenario II seed {args.seed}, {len(experiments)} records, {samples} samples; "
        f"{len(fitted.free)} coefficients free after the screen, start: the analytic model"
    )
    print(
        f"ml-nm : {t_nm:7.2f} s, {nm.status.name}, {nm.iterations} iterations, "
        f"{count[0]} simulations, {1e3 * t_nm / max(count[0], 1):.2f} ms per simulation"
    )
    print(f"ml-gn : {t_gn:7.2f} s, {gn.status.name}, {gn.iterations} iterations")
    print(
        f"ml-nm / goal ({GOAL:g} s): {t_nm / GOAL:.2f}; ml-nm / ml-gn: {t_nm / t_gn:.0f}x; "
        f"cost ml-nm − ml-gn: {nm.cost - gn.cost:+.2e}; "
        f"max |ml-nm − ml-gn| = {np.max(np.abs(z)):.3f} σ ({fitted.free[int(np.argmax(np.abs(z)))]})"
    )
    testbed = console()
    with tempfile.TemporaryDirectory() as tmp:
        run = Path(tmp) / "run"
        command([testbed, "simulate", "--scenario", "II", "--seed", args.seed, "--out", run], tmp)
        t_cmd = min(
            command([testbed, "identify", run, "--method", "ml-nm", "--out", Path(tmp) / f"est{k}.json"], tmp)
            for k in range(args.rounds)
        )
    work = machine()
    goal = GOAL / REFERENCE_S
    print(
        f"command `testbed identify RUN --method ml-nm`: {t_cmd:.2f} s (best of {args.rounds}), "
        f"{t_cmd / t_nm:.1f}x the library cell"
    )
    print(
        f"workload {work:.3f} s (reference {REFERENCE_S:.3f} s): cell {t_nm / work:.1f}, command "
        f"{t_cmd / work:.1f} workloads; goal {goal:.1f} ({GOAL:g} s at the reference): "
        f"cell {t_nm / work / goal:.2f}, command {t_cmd / work / goal:.2f} of the goal"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
