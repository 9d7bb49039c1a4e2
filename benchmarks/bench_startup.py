"""Start-up of the command line against `python -c "import numpy"`, measured in one run.

    python benchmarks/bench_startup.py [--rounds 10]

Each command runs as a fresh process, as a user starts it: the `testbed` console script
installed beside this interpreter, and `python -m testbed`, each for `--help` and
`identify --help`; the reference is the same interpreter importing numpy and nothing else. The
processes run alternately in rounds, from an empty folder (so `-m testbed` finds the installed
package, not a checkout in the working folder), and each one's best round counts: on a shared
machine other work only ever slows a process down. Goal: every command within 0.3 s.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

GOAL_S = 0.3


# Python caches compiled byte code beside the sources, as it does for any user; a shell that
# switched that off would time the compiler instead of the start-up.
ENV = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}


def wall(argv: list[str], cwd: str, env: dict = ENV) -> float:
    """Wall time of one run of `argv` in `env` to its exit, its output discarded; it must succeed."""
    t0 = time.perf_counter()
    subprocess.run(argv, cwd=cwd, env=env, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=10, help="runs of each command (the best counts)")
    args = ap.parse_args()
    python = sys.executable
    script = Path(python).parent / "testbed"
    if not script.exists():
        print(
            f"no console script {script}: install the package into this interpreter (pip install -e .)",
            file=sys.stderr,
        )
        return 2
    commands = {
        'python -c "import numpy"': [python, "-c", "import numpy"],
        "testbed --help": [str(script), "--help"],
        "testbed identify --help": [str(script), "identify", "--help"],
        "python -m testbed --help": [python, "-m", "testbed", "--help"],
        "python -m testbed identify --help": [python, "-m", "testbed", "identify", "--help"],
    }
    with tempfile.TemporaryDirectory() as cwd:
        package = subprocess.run(
            [python, "-c", "import testbed; print(testbed.__file__)"],
            cwd=cwd,
            env=ENV,
            check=True,
            capture_output=True,
            text=True,
        ).stdout.strip()
        for argv in commands.values():  # warm the file cache and the byte-code caches
            wall(argv, cwd)
        times = {name: [] for name in commands}
        for _ in range(args.rounds):
            for name, argv in commands.items():
                times[name].append(wall(argv, cwd))
    best = {name: min(t) for name, t in times.items()}
    numpy = best['python -c "import numpy"']
    print(f"interpreter: {python}\nconsole script: {script}\npackage: {package}")
    print(f"best of {args.rounds} runs each, alternating")
    print(f"{'command':36s} {'best s':>8s} {'median s':>9s} {'/ numpy':>8s}  goal <= {GOAL_S} s")
    for name, t in times.items():
        med = sorted(t)[len(t) // 2]
        verdict = "" if name.startswith("python -c") else ("met" if best[name] <= GOAL_S else "NOT met")
        print(f"{name:36s} {best[name]:8.3f} {med:9.3f} {best[name] / numpy:8.2f}  {verdict}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
