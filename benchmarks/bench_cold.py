"""The first `testbed simulate --scenario I` after installing against the same command warm.

    python benchmarks/bench_cold.py [--rounds 3]

Each run is a fresh process, `python -m testbed simulate --scenario I` from an empty folder, as
a user starts it. Cold: with an empty compiler cache (a new NUMBA_CACHE_DIR, where numba then
reads and writes its cache, for an installed package and a checkout alike), so the plant's step
is compiled; warm: the same command again with that cache, as every later run is (the byte code
Python caches beside the sources is there in both, as pip writes it at install). The reference
is the warm run, measured in the same round. Rounds alternate cold and warm and each side's best
round counts: on a shared machine other work only ever slows a run down. Goal: cold <= 3x warm.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks.bench_startup import ENV, wall  # noqa: E402

GOAL = 3.0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3, help="cold and warm runs each (the best counts)")
    args = ap.parse_args()
    python = sys.executable
    env = dict(ENV, OPENBLAS_NUM_THREADS="1")
    cold, warm = [], []
    with tempfile.TemporaryDirectory() as cwd:
        package = subprocess.run(
            [python, "-c", "import testbed; print(testbed.__file__)"],
            cwd=cwd,
            env=env,
            check=True,
            capture_output=True,
            text=True,
        ).stdout.strip()
        for r in range(args.rounds):
            env["NUMBA_CACHE_DIR"] = os.path.join(cwd, f"numba-cache-{r}")  # empty: nothing compiled
            for times, name in ((cold, "cold"), (warm, "warm")):
                argv = [python, "-m", "testbed", "simulate", "--scenario", "I", "--quiet"]
                times.append(wall([*argv, "--out", os.path.join(cwd, f"run-{r}-{name}")], cwd, env))
    print(f"interpreter: {python}\npackage: {package}")
    print(f"`testbed simulate --scenario I`, best of {args.rounds} rounds, alternating")
    print(f"cold (empty compiler cache) : {min(cold):6.2f} s")
    print(f"warm (cache filled)         : {min(warm):6.2f} s")
    ratio = min(cold) / min(warm)
    verdict = "met" if ratio <= GOAL else "NOT met"
    print(f"cold / warm                 : {ratio:6.2f}   (goal <= {GOAL:g}: {verdict})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
