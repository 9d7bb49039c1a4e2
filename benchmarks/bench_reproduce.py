"""Benchmark: `testbed reproduce --seeds 20` at one start spread, as a user runs it (goal ≤ 10 min
on 2 cores).

    python benchmarks/bench_reproduce.py [--seeds 20] [--spread 0.4] [--keep DIR]

The command (the console script beside this interpreter) runs from its start to its exit in a new
folder: every run flown, every start screened, every cell of the default arms fitted, the report
written. The reference measured in the same run is the cells' own compute time (each cell's
`wall_time_s` in results.csv) divided by the 2 workers: the time the campaign would take with no
flying, screening, scheduling or report. Printed: the command's time against the goal, and
against that reference (what the campaign spends besides fitting), and the arms' shares of the
fitting time.
"""

from __future__ import annotations

import argparse
import csv
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

GOAL = 600.0  # s, 20 seeds at one spread on 2 cores
WORKERS = 2


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--spread", type=float, default=0.4, help="the start spread (default: the command's own)")
    ap.add_argument("--keep", help="write the campaign here (a new folder) instead of a temporary one")
    args = ap.parse_args(argv)
    testbed = Path(sys.executable).with_name("testbed")
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(args.keep) if args.keep else Path(tmp) / "study"
        command = [str(testbed), "reproduce", "--seeds", str(args.seeds), "--start-spread", str(args.spread)]
        command += ["--out", str(out)]  # (its default: a LocalCluster of 2 workers)
        t0 = time.perf_counter()
        subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
        wall = time.perf_counter() - t0
        with open(out / "results.csv", newline="", encoding="utf-8") as f:
            cells = {}
            for row in csv.DictReader(f):  # one row per coefficient: a cell's time once
                key = (row["scenario"], row["truth"], row["spread"], row["arm"], row["seed"])
                cells[key] = (row["arm"], float(row["wall_time_s"] or 0))
        total = len(list((out / "cells").glob("*.json")))
    per_arm = Counter()
    for arm, t in cells.values():
        per_arm[arm] += t
    fitting = sum(per_arm.values()) / WORKERS
    print(
        f"testbed reproduce --seeds {args.seeds} --start-spread {args.spread:g}: {total} cells "
        f"({len(cells)} judged, the others the optimum's)"
    )
    print(f"command: {wall:7.1f} s; goal {GOAL:g} s: {wall / GOAL:.2f}")
    print(
        f"fitting alone (cells' time / {WORKERS} workers): {fitting:7.1f} s; command / fitting: {wall / fitting:.2f}"
    )
    print(
        "fitting time per arm: "
        + ", ".join(f"{a} {100 * t / sum(per_arm.values()):.0f} %" for a, t in per_arm.most_common())
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
