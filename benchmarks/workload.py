"""The fixed numpy workload the benchmarks time beside a command, to say how fast the machine
was in the same run, a command timed as a user runs it, and where a `testbed identify` spends
its time.

    from workload import command, console, machine, why

`machine()`: seconds for a fixed piece of numpy work shaped like the fits' (a 10-state
recursion stepped in Python, one small product per step, and dense 200 × 200 products), best of
five. `REFERENCE_S` is its time on the 2-core development machine on 2026-12-06, the day the
commands' goals in seconds were measured against: a goal of G seconds is G / `REFERENCE_S`
workloads, whatever the machine's speed in the run.

`beside(user, cwd, rounds, name, cell_s, cell)`: a `testbed identify` command timed beside its
library cell, as the lines a benchmark prints. `why(argv, cwd, cell_s, command_s, cell)`: where a command and the library cell it is set beside
differ by more than `APART` times, one line saying why, measured: one more run of the command
(`stages`) in a process of this interpreter that calls `testbed.cli.main` as the console script
does, with the library's stages timed inside it (the interpreter's start, the imports, reading,
the screen besides its fits, every fit with its iterations and starts, the comparison with the
analytic model, validation, the rest of the job: checks, the JSON and writing; printing and
exit). `fit_summary(path)`: the fit an estimates JSON reports (`wall_time_s`, `iterations`,
`start`, `starts`, the screen's fixes).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

__all__ = ["APART", "REFERENCE_S", "beside", "command", "console", "fit_summary", "machine", "stages", "why"]

REFERENCE_S = 0.065  # `machine()` on the development machine, 2026-12-06, idle (0.0652–0.0655 s)
APART = 3.0  # command / cell beyond this (either way): the benchmark says why

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
    """Wall time of one run of `argv` from `cwd` to its exit, its output discarded; it must succeed
    (else the benchmark stops with the command's exit status and standard error)."""
    t0 = time.perf_counter()
    _run([str(a) for a in argv], cwd, argv)
    return time.perf_counter() - t0


def _run(args: list[str], cwd, argv: list) -> None:
    done = subprocess.run(
        args, cwd=cwd, env=ENV, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, check=False
    )
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(map(str, argv))} failed (exit {done.returncode}):\n{done.stderr}")


def fit_summary(path: str | os.PathLike) -> str:
    """The fit an estimates JSON at `path` reports: its own wall time, iterations, start, every
    start tried, how many coefficients it estimated, and how many the screen fixed (or, only
    reported for an explicit free list, which it would fix)."""
    doc = json.loads(Path(path).read_text())
    starts = ", ".join(f"{s['start']} {s['iterations']}" for s in doc.get("starts") or ())
    return (
        f"{doc['method']} {doc['wall_time_s']:.2f} s, {doc['iterations']} "
        f"{'samples' if 'filter' in doc else 'iterations'}, {doc['status']}, start {doc['start']}"
        + (f" (starts tried, iterations: {starts})" if starts else "")
        + f", {len(doc['coefficients'])} estimated, "
        + (
            f"{len(doc.get('fixed', {}))} fixed by the screen"
            if "screen" not in doc
            else f"the screen (only reported) would fix {', '.join(doc['screen']) or 'none'}"
        )
    )


# `testbed.cli.main` on argv[2:] with the library's stages timed inside the process (`stages`);
# the times (absolute, time.time(), to meet the parent's clock) are written to argv[1]
_STAGED = r"""
import json, sys, time

first = time.time()
record, argv = sys.argv[1], sys.argv[2:]
import testbed.cli  # first: it sets the BLAS threads before numpy loads
from testbed.jobs import identify as jobs
from testbed.analysis import screening
from testbed.estimators import lookup

imported = time.time()
frames, own, fits, kept, job = [], {}, [], [], []


def timed(module, name, label, after=None):
    function = getattr(module, name)

    def run(*args, **kwargs):
        frames.append([label, 0.0])
        t0 = time.perf_counter()
        try:
            result = function(*args, **kwargs)
        finally:
            seconds = time.perf_counter() - t0
            inner = frames.pop()[1]
            own[label] = own.get(label, 0.0) + seconds - inner
            if frames:
                frames[-1][1] += seconds
        if after is not None:
            after(result)
        return result

    setattr(module, name, run)


def fitted(module):
    function = module.identify

    def run(*args, **kwargs):
        where = frames[-1][0] if frames else "job"
        t0 = time.perf_counter()
        e = function(*args, **kwargs)
        seconds = time.perf_counter() - t0
        if frames:
            frames[-1][1] += seconds
        fits.append(dict(
            where=where, method=e.method, seconds=seconds, iterations=e.iterations,
            unit="samples" if lookup(e.method).online else "iterations", free=len(e.free),
            start=e.start, starts=[[s.get("start"), s.get("iterations")] for s in e.starts],
            key=[e.method, e.cost, e.iterations],
        ))
        return e

    module.identify = run


def job_times(function):
    def run(*args, **kwargs):
        job.append(time.time())
        try:
            return function(*args, **kwargs)
        finally:
            job.append(time.time())

    return run


timed(jobs, "inputs", "reading")
timed(jobs, "truth_data", "reading")
timed(
    jobs,
    "identify_screened",
    "screen",
    lambda r: kept.append([r.estimate.method, r.estimate.cost, r.estimate.iterations]),
)
timed(jobs, "screening", "screening")
timed(jobs, "truth_comparison", "comparison")
timed(jobs, "validate", "validation")
timed(jobs, "identify_data", "job")
jobs.identify_data = job_times(jobs.identify_data)
fitted(screening)
fitted(jobs)
try:
    status = testbed.cli.main(argv)
finally:
    for f in fits:
        f["kept"] = f.pop("key") in kept
    with open(record, "w") as out:
        json.dump(dict(first=first, imported=imported, job=job, own=own, fits=fits), out)
sys.exit(status)
"""


def stages(argv: list, cwd: str | os.PathLike) -> dict:
    """One more run of the `testbed identify` command `argv` (the console script first) from
    `cwd`: `testbed.cli.main` on its arguments in a process of this interpreter, as the console
    script runs it, with the library's stages timed inside (`_STAGED`). Seconds by stage, in the
    order they run, summing to `total` (the process from its start to its exit): `interpreter`
    (its start), `imports` (the command line and the library), `arguments` (to the job's start),
    `reading` (the data, the config, a run's noise-free records), `screen` (besides its fits:
    the noise read off the data, the Fisher information at the a-priori and at the estimate),
    `fits`, `comparison` (besides its fit to the noise-free records), `validation`, `job rest`
    (the job's own: options, checks, the JSON, writing), `exit` (printing the tables, the
    interpreter's exit); and `fits list`, every fit in the order run: `where` (`screening`: the
    screen's `ml-gn`; `screen`: the method's fit after it; `comparison`: the fit to the
    noise-free records), `method`, `seconds`, `iterations` (`unit`: iterations or samples),
    `free`, `start`, `starts` ([name, iterations] of every start tried) and `kept` (the estimate
    written). Compiled code loads from numba's cache in the stage that first calls it."""
    with tempfile.TemporaryDirectory() as tmp:
        record = Path(tmp) / "stages.json"
        spawned = time.time()
        _run([sys.executable, "-c", _STAGED, str(record), *map(str, argv[1:])], cwd, argv)
        ended = time.time()
        m = json.loads(record.read_text())
    own, (begun, done) = m["own"], m["job"]
    fits = m["fits"]
    times = {
        "interpreter": m["first"] - spawned,
        "imports": m["imported"] - m["first"],
        "arguments": begun - m["imported"],
        "reading": own.get("reading", 0.0),
        "screen": own.get("screen", 0.0) + own.get("screening", 0.0),
        "fits": sum(f["seconds"] for f in fits),
        "comparison": own.get("comparison"),
        "validation": own.get("validation", 0.0),
        "job rest": own.get("job", 0.0),
        "exit": ended - done,
    }
    return {**{k: v for k, v in times.items() if v is not None}, "total": ended - spawned, "fits list": fits}


def breakdown(parts: dict) -> str:
    """`stages` in words: the fits, each with its seconds, iterations and starts, then the other
    stages' seconds."""

    def fit(f):
        starts = " + ".join(f"{name} {n}" for name, n in f["starts"]) if len(f["starts"]) > 1 else ""
        where = {"screening": " in the screen", "comparison": " to the noise-free records"}.get(
            f["where"], ""
        )
        return (
            f"{f['method']}{where}{' (the estimate)' if f['kept'] else ''} {f['seconds']:.2f} s, "
            f"{f['iterations']} {f['unit']}{f' ({starts})' if starts else ''}, {f['free']} free, "
            f"start {f['start']}"
        )

    words = {
        "interpreter": "interpreter start",
        "screen": "screen besides its fits",
        "comparison": "comparison besides its fit",
        "job rest": "checks, JSON and writing",
        "exit": "printing and exit",
    }
    rest = [(k, v) for k, v in parts.items() if k not in ("fits", "total", "fits list")]
    return (
        f"one more run, timed inside it: {parts['total']:.2f} s = fits {parts['fits']:.2f} s "
        f"[{'; '.join(map(fit, parts['fits list']))}] + the rest {sum(v for _, v in rest):.2f} s: "
        + ", ".join(f"{words.get(k, k)} {v:.2f} s" for k, v in rest)
    )


def why(argv: list, cwd: str | os.PathLike, cell_s: float, command_s: float, cell: str) -> str | None:
    """Where `command_s` and `cell_s` differ by more than `APART` times (either way), one line
    saying why, measured (`stages`, `breakdown`), with `cell` (what the cell fits) beside it;
    None where they do not (the command is then not run again)."""
    ratio = command_s / cell_s
    if 1 / APART <= ratio <= APART:
        return None
    return f"why command / cell = {ratio:.1f}x (beyond {APART:g}x): the cell is {cell}; " + breakdown(
        stages(argv, cwd)
    )


def beside(user, cwd: str | os.PathLike, rounds: int, name: str, cell_s: float, cell: str) -> list[str]:
    """The command `user(out)` (its argv, the estimates written to `out`, relative to `cwd`) timed
    beside the library cell `name` of `cell_s` seconds (`cell`: what the cell fits): one untimed
    run first (Python's byte code cached, as for any user), then the best of `rounds`. The lines
    to print: the command with the fit its estimates JSON reports, both times and their ratio,
    the measured reason where they differ by more than `APART` (`why`), both in workloads."""
    command(user("est0.json"), cwd)
    t_cmd = min(command(user(f"est{k}.json"), cwd) for k in range(1, rounds + 1))
    fit = fit_summary(Path(cwd) / "est1.json")
    reason = why(user("why.json"), cwd, cell_s, t_cmd, cell)
    work = machine()
    shown = " ".join(Path(a).name if k == 0 else str(a) for k, a in enumerate(user("est.json")))
    return [
        f"command `{shown}`: {t_cmd:.3f} s (best of {rounds}); its fit (estimates JSON): {fit}",
        f"cell {name} {cell_s:.3f} s, command {t_cmd:.3f} s: command / cell {t_cmd / cell_s:.1f}x",
        *([reason] if reason else []),
        f"workload {work:.3f} s (reference {REFERENCE_S:.3f} s): cell {cell_s / work:.1f}, "
        f"command {t_cmd / work:.1f} workloads",
    ]
