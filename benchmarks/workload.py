"""The fixed numpy workload the benchmarks time beside a command, to say how fast the machine
was in the same run, and a command timed as a user runs it.

    from workload import command, machine

`machine()`: seconds for a fixed piece of numpy work shaped like the fits' (a 10-state
recursion stepped in Python, one small product per step, and dense 200 × 200 products), best of
five. `REFERENCE_S` is its time on the 2-core development machine on 2026-12-06, the day the
commands' goals in seconds were measured against: a goal of G seconds is G / `REFERENCE_S`
workloads, whatever the machine's speed in the run.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

__all__ = ["REFERENCE_S", "command", "console", "machine"]

REFERENCE_S = 0.065  # `machine()` on the development machine, 2026-12-06, idle (0.0652–0.0655 s)

# Python caches compiled byte code beside the sources, as it does for any user
ENV = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}


def machine(rounds: int = 5) -> float:
    """The workload's best time of `rounds` (other work on a shared machine only slows it)."""
    rng = np.random.default_rng(0)
    A, B = rng.normal(size=(10, 10)) / 10, rng.normal(size=(200, 200)) / 200
    best = np.inf
    for _ in range(rounds):
        t0 = time.perf_counter()
        x = np.zeros(10)
        for _ in range(20_000):
            x = A @ x + 1.0
        C = B
        for _ in range(40):
            C = B @ C
        best = min(best, time.perf_counter() - t0)
    return best


def console(name: str = "testbed") -> Path:
    """The console script `name` installed beside this interpreter."""
    script = Path(sys.executable).parent / name
    if not script.exists():
        raise SystemExit(
            f"no console script {script}: install the package into this interpreter (pip install -e .)"
        )
    return script


def command(argv: list, cwd: str | os.PathLike) -> float:
    """Wall time of one run of `argv` from `cwd` to its exit, its output discarded; it must succeed."""
    t0 = time.perf_counter()
    subprocess.run(
        [str(a) for a in argv],
        cwd=cwd,
        env=ENV,
        check=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    return time.perf_counter() - t0
