"""The paper's study as a campaign: data sets × noise seeds × start spreads × arms, on Dask.

A data set is a scenario flown on a truth (`cells.Cell`): Scenario I and II on the MuJoCo plant
and on the analytic linear model flown as the plant (where the linear reference is exact), and
the input factorial (`FACTORIAL`: Scenario II's layout with PRBS, square, 3-2-1-1 and multisine
inputs) on the plant. Per data set, seed and spread one a-priori model, screened at itself
(`cells.start`), is where every arm (`arms.ARMS`) starts; the `OPTIMUM` cell looks for the data's
best-likelihood optimum, against which each arm is judged (`results`); on Scenario I on the
plant the nonlinear cells (`arms.NONLINEAR_ARMS`) fit the nonlinear model, judged against the
captive reference. The verdicts on the
paper's conclusions are `rules.conclusions` of results.csv, of the analytic model's open-loop
fit per data set (`regime.json`) and of the drift measured per data set (`drift.json`).

Cells are tasks on a `dask.distributed` cluster: a `LocalCluster` (2 single-threaded worker
processes) by default, or a running cluster by its scheduler address. A worker that dies
mid-cell has its task resubmitted by the scheduler; a cell whose task fails anyway (an exception
escaping it, a worker lost too often) is recorded as failed with its reason.

Every finished cell is written at once to `DIR/cells/<key>.json` (a temporary file renamed), the
key a hash of everything the cell's result depends on (scenario text, truth, spread, arm and its
options, seed, and the package's code: `hashing.code_hash`): after a crash or Ctrl-C,
`reproduce` again computes only the cells that have no file. The outputs are derived from the
cell files and the run directories alone.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os
import socket
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable

import numpy as np
from dask.distributed import Client, LocalCluster, WorkerPlugin, as_completed
from distributed.comm.addressing import parse_address, parse_host_port

from testbed.analysis.drift import evidence, forms
from testbed.analysis.regime import open_loop_fit
from testbed.data import load_data
from testbed.outputs import atomic_write_text, check_output_directory
from testbed.errors import InputError, is_number, one_line
from testbed.memory import keep_freed_memory
from testbed.presentation.figures import write_report
from testbed.simulation.scenario import TRUTHS
from testbed.study.arms import ARMS, DEFAULT_ARMS, DRIFT_ARMS, FACTORIAL_ARMS, NONLINEAR_ARM, NONLINEAR_ARMS
from testbed.study.arms import arms as checked_arms
from testbed.study.cells import OPTIMUM, Cell, load_run, run_cell, start
from testbed.study.results import (
    SUMMARY_COLUMNS,
    captive_table,
    read_results,
    results_csv,
    results_rows,
    summary_table,
)
from testbed.study.rules import DRIFT_AT, FACTORIAL, NM_ARM, conclusions

__all__ = [
    "CONNECT_S",
    "FACTORIAL",
    "KeepFreedMemory",
    "CAMPAIGN_MARKER",
    "MAX_SEEDS",
    "Reproduction",
    "QUICK_DURATION",
    "SCENARIOS",
    "SPREADS",
    "TRUTHS",
    "check_folder",
    "make_folder",
    "plan",
    "read_cell",
    "reproduce",
    "run_order",
    "write_outputs",
]

SCENARIOS = ("I", "II")  # the paper's, fitted by every arm on every truth
SPREADS = (0.4,)  # the default start spread: a user's a-priori model (`priors.SPREAD`)
MAX_SEEDS = 1000  # noise seeds 1..N: weeks of one machine's time at the most
MAX_SPREAD = 3.0  # e^±3σ_c: beyond it an a-priori model is no model
CAMPAIGN_MARKER = ".testbed-campaign"  # the file that makes a folder a campaign's, which reproduce resumes
QUICK_DURATION = 30.0  # s per experiment in --quick
CONNECT_S = 10.0  # s a scheduler given by its address has to answer


def run_order(cells: list[Cell]) -> list[Cell]:
    """`cells` in the order their tasks are prioritised: seed by seed (a campaign stopped early has
    whole seeds), and in each seed its nonlinear cells first, the plan's order otherwise.
    Those cells are the longest by far and the first to compile the nonlinear model's kernels
    (`testbed reproduce --quick`: 47 of its 70 s from an empty compile cache): begun after the
    others, one runs alone at the end while the other workers wait."""
    return sorted(cells, key=lambda c: (c.seed, c.arm not in NONLINEAR_ARMS))


def plan(
    seeds: int,
    quick: bool = False,
    arms=DEFAULT_ARMS,
    spreads=SPREADS,
    truths=TRUTHS,
    scenarios=SCENARIOS,
    factorial=FACTORIAL,
    duration: float | None = None,
) -> list[Cell]:
    """The campaign's cells, seed by seed, spread by spread, data set by data set: the `OPTIMUM`
    cell, then `arms` (`all`: every arm); the input factorial's data sets with `FACTORIAL_ARMS`
    among them only, the drift arms on `scenarios` only; on Scenario I on the plant (with some
    arm) the `NONLINEAR_ARM` cell and the other `NONLINEAR_ARMS` among `arms` after them. Seeds 1..N; `quick`: experiments of `QUICK_DURATION` s
    (unless `duration` says otherwise)."""
    if isinstance(seeds, bool) or not isinstance(seeds, int) or not 1 <= seeds <= MAX_SEEDS:
        raise InputError(f"seeds={seeds!r}; expected an integer from 1 to {MAX_SEEDS}")
    arms = checked_arms(arms)
    nonlinear = tuple(a for a in arms if a in NONLINEAR_ARMS and a != NONLINEAR_ARM)
    some, arms = bool(arms), tuple(a for a in arms if a in ARMS)
    spreads = tuple(dict.fromkeys(spreads))
    for s in spreads:
        if isinstance(s, bool) or not is_number(s) or not 0 <= s <= MAX_SPREAD:
            raise InputError(f"start spread {s!r}; expected a number from 0 to {MAX_SPREAD:g}")
    if not spreads:
        raise InputError(f"start spread: none given; expected at least one number from 0 to {MAX_SPREAD:g}")
    for t in truths:
        if t not in TRUTHS:
            raise InputError(f"truth {t!r}; expected one of {', '.join(TRUTHS)}")
    duration = duration if duration is not None else (QUICK_DURATION if quick else None)
    sets = [(s, t, arms) for s in scenarios for t in truths]
    sets += [  # (Scenario II, the PRBS level, with every arm when among the scenarios)
        (s, "plant", tuple(a for a in arms if a in FACTORIAL_ARMS or (s == FACTORIAL[0] and a == NM_ARM)))
        for s in factorial
        if "plant" in truths and s not in scenarios
    ]
    # seed by seed: the cells run in this order, so a campaign stopped early has whole seeds
    return [
        Cell(s, a, seed, float(sp), t, duration)
        for seed in range(1, seeds + 1)
        for sp in spreads
        for s, t, chosen in sets
        for a in ((OPTIMUM, *chosen) if chosen else ()) + (_nonlinear(s, t, nonlinear) if some else ())
    ]


def _nonlinear(scenario: str, truth: str, chosen: tuple[str, ...]) -> tuple[str, ...]:
    """The nonlinear cells where a data set has them: on Scenario I on the plant (the captive
    reference is the plant's; the linear truth has no nonlinear reference) the `NONLINEAR_ARM`
    cell and the `chosen` others."""
    return (NONLINEAR_ARM, *chosen) if (scenario, truth) == ("I", "plant") else ()


# -- the campaign (runs on the client) -------------------------------------------------------------


@dataclass(frozen=True)
class Reproduction:
    """What `reproduce` did: the files it wrote, the verdicts, the cells computed now and before."""

    out: Path
    computed: int
    reused: int
    failed: int
    conclusions: dict
    wall_time_s: float


def reproduce(
    out,
    seeds: int | None = None,
    scheduler: str | None = None,
    quick: bool = False,
    progress: Callable[[float, str], None] | None = None,
    workers: int = 2,
    arms=DEFAULT_ARMS,
    spreads=SPREADS,
    truths=TRUTHS,
    scenarios=SCENARIOS,
    factorial=FACTORIAL,
    duration: float | None = None,
) -> Reproduction:
    """Run (or resume) the campaign into `out` and write results.csv, summary.csv,
    conclusions.json, regime.json, drift.json, report.html with its figures and report.rrd.
    `scheduler`: the address of a running Dask scheduler (its workers must see `out`); default
    a LocalCluster of `workers` processes. `seeds`: 1..N (default 20, or 1 with `quick`)."""
    t0 = time.perf_counter()
    out = Path(out)
    seeds = seeds if seeds is not None else (1 if quick else 20)
    arms, spreads, truths = (
        d if v is None else v for v, d in ((arms, DEFAULT_ARMS), (spreads, SPREADS), (truths, TRUTHS))
    )
    cells = plan(seeds, quick, arms, spreads, truths, scenarios, factorial, duration)
    check_folder(out)
    cells_dir = out / "cells"
    todo = run_order([c for c in cells if read_cell(cells_dir / f"{c.key}.json") is None])
    # a task's priority is its first cell's place in `todo` (Dask runs the higher first), so each
    # run and start runs just before the cells that need it
    first_run, first_start = {}, {}
    for i, c in enumerate(todo):
        first_run.setdefault(_run(c), i)
        first_start.setdefault(_start(c), i)
    failed = 0
    with _client(scheduler, workers) as client:
        make_folder(out)  # only once the scheduler answered
        where = hashlib.sha256(str(out.resolve()).encode()).hexdigest()[
            :8
        ]  # unique per DIR on a shared scheduler
        data = {
            r: client.submit(load_run, str(out.resolve()), *r, key=f"run-{_name(r)}-{where}", priority=-i)
            for r, i in first_run.items()
        }
        begun = {
            k: client.submit(
                start, data[k[:4]], k[4], k[2], key=f"start-{_name(k[:4])}-s{k[4]:g}-{where}", priority=-i
            )
            for k, i in first_start.items()
        }
        futures = {
            client.submit(run_cell, c, data[_run(c)], begun[_start(c)], key=f"cell-{c.key}", priority=-i): c
            for i, c in enumerate(todo)
        }
        done = len(cells) - len(todo)
        for future in as_completed(futures):
            cell = futures[future]
            try:
                doc = future.result()
            except Exception as exc:  # the task itself failed: a lost worker, a lost run
                doc = {
                    "key": cell.key,
                    "cell": asdict(cell),
                    "status": "failed",
                    "reason": one_line(exc),
                    "converged": False,
                    "iterations": 0,
                    "evaluations": 0,
                    "wall_time_s": 0.0,
                    "free": [],
                    "values": {},
                }
            failed += doc["status"] == "failed"
            atomic_write_text(cells_dir / f"{cell.key}.json", json.dumps(doc, indent=1) + "\n", force=True)
            done += 1
            if progress is not None:
                progress(
                    done / len(cells),
                    f"{cell.scenario}/{cell.truth} s={cell.spread:g} {cell.arm} seed {cell.seed}: {doc['status']}",
                )
        for f in list(data.values()) + list(begun.values()):
            f.cancel()
    docs = [read_cell(cells_dir / f"{c.key}.json") for c in cells]
    write_outputs(out, docs, cells)
    verdicts = json.loads((out / "conclusions.json").read_text())
    return Reproduction(out, len(todo), len(cells) - len(todo), failed, verdicts, time.perf_counter() - t0)


def _run(c: Cell) -> tuple:
    return (c.scenario, c.truth, c.seed, c.duration)


def _start(c: Cell) -> tuple:
    return (*_run(c), c.spread)


def _name(r: tuple) -> str:
    return Cell(r[0], "", r[2], truth=r[1], duration=r[3]).run_name


def read_cell(path: Path) -> dict | None:
    """A finished cell's file, or None where there is none or it cannot be read as one (cut
    short, edited): that cell is computed again and its file replaced."""
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError, RecursionError):
        return None
    return doc if isinstance(doc, dict) and isinstance(doc.get("cell"), dict) and "status" in doc else None


def check_folder(out: Path) -> None:
    """`InputError` unless `out` can hold the campaign: a new folder (its parents made), an empty
    one or a campaign's (holding `CAMPAIGN_MARKER`, which it resumes). A folder of anything else is a
    user's, whose files (a results.csv, say) the campaign's would replace."""
    if not os.path.lexists(out):
        check_output_directory(out, label=f"out={out}")  # a file in the way of its parents
        return
    try:
        if not out.is_dir():
            raise InputError(f"out={out}: is a file; expected a folder for the campaign")
        if not (out / CAMPAIGN_MARKER).is_file() and any(out.iterdir()):
            raise InputError(
                f"out={out}: holds files that are not a campaign's (no {CAMPAIGN_MARKER}); expected a new "
                "or empty folder, or a campaign's folder to resume"
            )
    except OSError as exc:
        raise InputError(f"out={out}: cannot read ({exc.strerror or exc})") from None


def make_folder(out: Path) -> None:
    """Make the campaign's folder `out` (checked by `check_folder`), its `CAMPAIGN_MARKER` and `cells/`."""
    try:
        (out / "cells").mkdir(parents=True, exist_ok=True)
        if not (out / CAMPAIGN_MARKER).is_file():
            atomic_write_text(
                out / CAMPAIGN_MARKER, "a testbed reproduce campaign: `testbed reproduce --out` resumes it\n"
            )
    except OSError as exc:
        raise InputError(f"out={out}: cannot create ({exc.strerror or exc})") from None


class KeepFreedMemory(WorkerPlugin):
    """On every worker, local or remote, freed memory kept for reuse (`testbed.memory`): Dask's
    nanny starts workers set to hand it back at once, which makes every cell several times slower."""

    name = "testbed-keep-freed-memory"

    def setup(self, worker) -> None:
        keep_freed_memory()


def _reachable(address: str) -> None:
    """OSError where a tcp:// `address` cannot be reached by a plain connection within
    `CONNECT_S` (nothing listens on its port, the host unknown or silent). Dask's client retries a
    refused connection until its timeout, so a mistyped port would otherwise cost the whole wait.
    Another scheme, or an address Dask parses otherwise, is left to Dask's client."""
    try:
        scheme, location = parse_address(address)
        host, port = parse_host_port(location) if scheme == "tcp" else (None, None)
    except (ValueError, TypeError):
        return
    if host is not None:
        socket.create_connection((host, port), timeout=CONNECT_S).close()


class _client:
    """A Dask client on the scheduler at `address`, or on a LocalCluster of `workers`
    single-threaded processes (closed on exit)."""

    def __init__(self, address: str | None, workers: int):
        self.address, self.workers, self.cluster = address, workers, None

    def __enter__(self):
        if self.address:
            try:
                _reachable(self.address)
                self.client = Client(self.address, timeout=f"{CONNECT_S:g}s")
            except (OSError, TimeoutError, ValueError) as exc:
                raise InputError(
                    f"scheduler={self.address}: cannot connect ({one_line(exc)}); "
                    "expected the address of a running Dask scheduler, e.g. tcp://host:8786"
                ) from None
        else:
            self.cluster = LocalCluster(
                n_workers=self.workers,
                threads_per_worker=1,
                processes=True,
                dashboard_address=None,
                silence_logs=logging.CRITICAL,  # (a worker's heartbeat to a closing scheduler logs an error)
            )
            self.client = Client(self.cluster)
        try:
            self.client.register_plugin(KeepFreedMemory())
        except BaseException:
            self.__exit__()
            raise
        return self.client

    def __exit__(self, *exc):
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()


# -- the outputs ------------------------------------------------------------------------------------


def regime(out: Path, cells: list[Cell]) -> dict[str, dict]:
    """Per data set ("scenario/truth"), the analytic model's open-loop fit (`regime.open_loop_fit`)
    on its first seed's run, with `lowest_fit_to_truth` the median over the seeds' runs of each
    run's lowest (the input sequences and noise differ by seed: one seed's margin does not
    decide) and `lowest_fit_to_truth_seeds` each seed's; a run that cannot be read is left out."""
    fits: dict[str, dict[int, dict]] = {}
    for c in cells:
        runs = fits.setdefault(f"{c.scenario}/{c.truth}", {})
        if c.seed in runs:
            continue
        try:
            runs[c.seed] = open_loop_fit(out / "runs" / c.run_name).to_dict()
        except (InputError, OSError):
            runs[c.seed] = None
    found = {}
    for key, runs in fits.items():
        read = {seed: r for seed, r in sorted(runs.items()) if r is not None}
        if not read:
            continue
        lowest = {seed: r["lowest_fit_to_truth"] for seed, r in read.items()}
        finite = [v for v in lowest.values() if v is not None]
        found[key] = {
            **next(iter(read.values())),
            "lowest_fit_to_truth": float(np.median(finite)) if finite else None,
            "lowest_fit_to_truth_seeds": {str(seed): v for seed, v in lowest.items()},
        }
    return found


def drift(out: Path, docs: list[dict], cells: list[Cell]) -> dict[str, dict]:
    """Per data set and spread with drift cells ("scenario/truth s=spread", `rules.DRIFT_AT`): the
    Mt-form against the A-form, `drift.forms` at the analytic model of the first seed's run and
    `drift.evidence` of every seed's finite estimates at that spread, converged or not (a fit
    that drifts off to its limit is the evidence), with how many of each form's fits converged."""
    found, forms_of = {}, {}
    for c in cells:
        key = f"{c.scenario}/{c.truth}{DRIFT_AT}{c.spread:g}"
        if key in found or c.arm != DRIFT_ARMS[0]:
            continue
        mine = [
            d
            for d in docs
            if d
            and d["status"] != "failed"
            and (d["cell"]["scenario"], d["cell"]["truth"], d["cell"]["spread"])
            == (c.scenario, c.truth, c.spread)
        ]
        picked = {
            a: [d for d in mine if d["cell"]["arm"] == a and all(map(math.isfinite, d["values"].values()))]
            for a in DRIFT_ARMS
        }
        try:
            if (c.scenario, c.truth) not in forms_of:  # the first seed's run (the plan's order)
                experiments, analytic = load_data([out / "runs" / c.run_name])
                forms_of[c.scenario, c.truth] = forms(experiments, analytic)
            measured = evidence(
                forms_of[c.scenario, c.truth], *([d["values"] for d in picked[a]] for a in DRIFT_ARMS)
            )
        except (InputError, OSError, np.linalg.LinAlgError, ValueError):
            continue
        found[key] = {
            "spread": c.spread,
            **measured,
            **{f"converged_{a.split('-')[1]}": sum(d["converged"] for d in picked[a]) for a in DRIFT_ARMS},
        }
    return found


def write_outputs(out: Path, docs: list[dict], cells: list[Cell]) -> None:
    """results.csv, summary.csv, regime.json, drift.json, conclusions.json, the figures,
    report.html and report.rrd from the cells and the runs."""
    rows = results_rows(docs)
    atomic_write_text(out / "results.csv", results_csv(rows), force=True)  # a resumed campaign's, redone
    rows = read_results(out / "results.csv")  # the verdicts are computed from the file itself
    found_regime, found_drift = regime(out, cells), drift(out, docs, cells)
    atomic_write_text(out / "regime.json", json.dumps(found_regime, indent=2) + "\n", force=True)
    atomic_write_text(out / "drift.json", json.dumps(found_drift, indent=2) + "\n", force=True)
    verdicts = conclusions(rows, found_regime, found_drift)
    atomic_write_text(out / "conclusions.json", json.dumps(verdicts, indent=2) + "\n", force=True)
    summary = summary_table(rows)
    atomic_write_text(out / "summary.csv", results_csv(summary, SUMMARY_COLUMNS), force=True)
    inputs = {}
    for s in dict.fromkeys(c.scenario for c in cells):
        first = next(c for c in cells if c.scenario == s)
        try:
            inputs[s] = load_data([out / "runs" / first.run_name])[0]
        except (InputError, OSError):
            inputs[s] = None  # the report says which figure is missing
    write_report(
        out,
        docs,
        rows,
        verdicts,
        inputs,
        summary,
        found_regime,
        found_drift,
        tuple(ARMS),
        captive_table(rows, docs),
    )
