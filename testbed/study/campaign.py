"""The paper's study as a campaign: Scenario I and II × {ml-nr, ml-nm, mekf, ml-gn} × noise seeds.

Each cell flies its scenario with its seed (a run directory shared by the four methods of that
scenario and seed, cached under `DIR/runs/`), screens the candidates of the run's model.toml
and identifies those the data determine starting from the analytic model
(`analysis.identify_screened`, as `testbed identify` does), and compares with the analytic
model. Cells are tasks on a `dask.distributed` cluster: a `LocalCluster` (2 single-threaded
worker processes) by default, or a running cluster by its scheduler address. A worker that dies
mid-cell has its task resubmitted by the scheduler; a cell whose task fails anyway (an exception
escaping it, a worker lost too often) is recorded as failed with its reason.

Every finished cell is written at once to `DIR/cells/<key>.json` (a temporary file renamed), the
key a hash of everything the cell's result depends on (scenario text, method, seed, options,
and the package's code: every source and data file of `testbed`): after a crash or Ctrl-C,
`reproduce` again computes only the cells that have no file. The results (`results.csv`), the
verdicts on the paper's three conclusions (`conclusions.json`, `conclusions`) and the report
(`testbed.presentation.figures`) are derived from the cell files alone.
"""

from __future__ import annotations

import csv
import functools
import hashlib
import io
import json
import logging
import math
import os
import time
import traceback
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Callable

import mujoco
import numpy as np
from dask.distributed import Client, LocalCluster, as_completed

from testbed.analysis.identifiability import compare, identify_screened, structural
from testbed.data import load_data
from testbed.errors import InputError, atomic_write_text, check_output_directory
from testbed.estimators import FilterEstimate, lookup
from testbed.presentation.figures import write_report
from testbed.models.linear import COEFFICIENTS, structure, theta_vector
from testbed.simulation.runs import simulate
from testbed.simulation.scenario import scenario, scenario_text

__all__ = [
    "CODE_FILES",
    "COLUMNS",
    "Cell",
    "MARKER",
    "MAX_SEEDS",
    "Outcome",
    "QUICK_DURATION",
    "check_folder",
    "code_hash",
    "coefficient_ok",
    "conclusions",
    "load_run",
    "make_folder",
    "plan",
    "read_cell",
    "read_results",
    "reproduce",
    "results_csv",
    "results_rows",
    "run_cell",
    "source_hash",
]

SCENARIOS = ("I", "II")
METHODS = ("ml-nr", "ml-nm", "mekf", "ml-gn")  # the paper's three, then the modern reference
COLUMNS = (
    "scenario",
    "method",
    "seed",
    "coefficient",
    "analytic",
    "estimate",
    "std",
    "converged",
    "iterations",
    "wall_time_s",
    "status",
    "reason",
)
FORMAT = 2  # version of the cell file: part of every key, so a new format recomputes
MAX_SEEDS = 1000  # noise seeds 1..N: 8000 cells at most, weeks of one machine's time
MARKER = ".testbed-campaign"  # the file that makes a folder a campaign's, which reproduce resumes
QUICK_DURATION = 30.0  # s per experiment in --quick
HISTORY_POINTS = 400  # the MEKF's per-sample history, thinned to this many points per cell

# The rules that decide the paper's conclusions (docs/studies.md).
COEFFICIENT_TOLERANCE = 0.10  # a coefficient is acceptable within 10 % of the analytic value ...
COEFFICIENT_SIGMAS = 3.0  # ... or within 3 of its Cramér-Rao σ
CELL_FRACTION = 0.8  # a cell is acceptable when it converged and ≥ 80 % of its coefficients are
ACCEPTABLE = 0.8  # a method is acceptable when ≥ 80 % of its cells are
UNSATISFACTORY = 0.5  # and unsatisfactory when fewer than 50 % are


CODE_FILES = ("*.py", "*.toml", "*.xml")  # what the package computes with: its modules and data


def source_hash(root: str | os.PathLike) -> str:
    """SHA-256 of the package's code under `root`: every file matching `CODE_FILES`, by its path
    relative to `root` and its bytes, in path order (compiled caches and other files ignored)."""
    root = Path(root)
    files = sorted({p for pattern in CODE_FILES for p in root.rglob(pattern) if "__pycache__" not in p.parts})
    h = hashlib.sha256()
    for p in files:
        data = p.read_bytes()
        h.update(f"{p.relative_to(root).as_posix()}\0{len(data)}\0".encode())
        h.update(data)
    return h.hexdigest()


@functools.lru_cache(maxsize=None)
def code_hash() -> str:
    """`source_hash` of this installation of testbed: a cell computed by other code is computed again."""
    return source_hash(Path(__file__).resolve().parents[1])


@dataclass(frozen=True)
class Cell:
    """One identification: a scenario's data with one noise seed, fitted by one method."""

    scenario: str
    method: str
    seed: int
    duration: float | None = None  # s per experiment (None: the scenario's own)

    @property
    def run_name(self) -> str:
        """The cached run directory's name, shared by the methods of a scenario and seed."""
        return f"{self.scenario}-seed{self.seed}" + (f"-{self.duration:g}s" if self.duration else "")

    @functools.cached_property  # reads the scenario file: once per cell
    def key(self) -> str:
        """`<scenario>-<method>-seed<N>-<hash>`: the hash of every input the result depends on."""
        flown = scenario(self.scenario).with_overrides(duration=self.duration)
        doc = {
            "format": FORMAT,
            "scenario": scenario_text(replace(flown, source="")),
            "method": self.method,
            "seed": self.seed,
            "code": code_hash(),
        }
        h = hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:12]
        return f"{self.scenario}-{self.method}-seed{self.seed}-{h}"


def plan(
    seeds: int, quick: bool = False, methods=METHODS, scenarios=SCENARIOS, duration: float | None = None
) -> list[Cell]:
    """The campaign's cells, scenario by scenario, seed by seed, method by method; seeds 1..N.
    `quick`: experiments of `QUICK_DURATION` s (unless `duration` says otherwise)."""
    if isinstance(seeds, bool) or not isinstance(seeds, int) or not 1 <= seeds <= MAX_SEEDS:
        raise InputError(f"seeds={seeds!r}; expected an integer from 1 to {MAX_SEEDS}")
    for m in methods:
        if m not in METHODS:
            raise InputError(f"method {m!r} is not in the study; expected one of {', '.join(METHODS)}")
    duration = duration if duration is not None else (QUICK_DURATION if quick else None)
    return [Cell(s, m, seed, duration) for s in scenarios for seed in range(1, seeds + 1) for m in methods]


# -- the work of one cell (runs on a worker) -------------------------------------------------------


def load_run(out: str, scenario: str, seed: int, duration: float | None):
    """The experiments and analytic model config of a run, flying it into `out/runs/` first
    unless it is there (several workers may fly the same run at once: the first rename wins)."""
    mujoco.set_mju_user_warning(lambda message: None)  # the plant raises its warnings as errors
    run = Path(out) / "runs" / Cell(scenario, "", seed, duration).run_name
    if not (run / "manifest.json").exists():
        run.parent.mkdir(parents=True, exist_ok=True)
        try:
            simulate(scenario, seed=seed, out=run, duration=duration)
        except (InputError, OSError):
            if not (run / "manifest.json").exists():  # not a lost race with another worker
                raise
    return load_data([run])


def drift_directions(config, experiments) -> dict:
    """Exact (structural) unidentifiability of the Mt-form model on these outputs: with all 35
    coefficients free, and with the inertia terms (the `*_dot`, i.e. Mt) known — the general
    state equation ẋ = A x + B δ in its At, Bt entries."""

    measured = sorted({m for e in config.fitted(experiments) for m in e.measured})
    theta = theta_vector(config.coefficients)
    s = structure(config.vehicle)
    all_free = structural(s, theta, COEFFICIENTS, measured)
    no_inertia = structural(s, theta, tuple(n for n in COEFFICIENTS if not n.endswith("dot")), measured)
    return {
        "null_directions": all_free.null_directions,
        "drift_groups": [list(g) for g in all_free.drift_groups],
        "null_directions_inertia_known": no_inertia.null_directions,
    }


def run_cell(cell: Cell, data) -> dict:
    """Screen, identify from the analytic model and compare one cell; never raises: a failure is
    returned as a result with `status` "failed" and its reason."""
    t0 = time.perf_counter()
    doc = {"key": cell.key, "cell": asdict(cell)}
    try:
        experiments, analytic = data
        doc["drift"] = drift_directions(analytic, experiments)
        costs = []
        method = lookup(cell.method)
        options = {"start": "config"} if method.starts else {}
        callback = (lambda step: costs.append(float(step.cost))) if method.iterative else None
        screened = identify_screened(experiments, analytic, cell.method, options, callback, apply=True)
        doc["fixed"] = {
            n: {"value": float(analytic.coefficients[n]), "reason": why} for n, why in screened.fixed.items()
        }
        est = screened.estimate
        comparison = compare(est, analytic)
        doc.update(
            status=est.status.name.lower().replace("_", " "),
            reason=_reason(est),
            converged=bool(est.converged),
            iterations=int(est.iterations),
            wall_time_s=float(est.wall_time_s),
            free=list(est.free),
            rows=[
                {
                    "coefficient": r["name"],
                    "analytic": r["analytic"],
                    "estimate": r["identified"],
                    "std": r["std"],
                }
                for r in comparison.rows()
            ],
            history=_history(est, comparison.analytic, costs),
        )
    except Exception as exc:  # a failed cell is a result too
        doc.update(
            status="failed",
            reason=_one_line(exc),
            converged=False,
            iterations=0,
            wall_time_s=time.perf_counter() - t0,
            rows=[],
            traceback=traceback.format_exc(),
        )
    return doc


def _reason(est) -> str:
    if est.converged:
        return ""
    return est.status.message + (f" ({est.message})" if est.message else "")


def _one_line(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {' '.join(str(exc).split())}"


def _history(est, analytic: np.ndarray, costs: list[float]) -> dict:
    """The estimates over the fit, divided by the analytic values: per iteration for the off-line
    methods (with J_M), per sample (thinned to `HISTORY_POINTS`, with the time) for the filters."""
    h = est.history
    if h is None:
        return {}
    h = np.asarray(h, float)
    scale = np.where(analytic != 0, analytic, 1.0)
    out = {}
    if isinstance(est, FilterEstimate):
        t = est.history_t
        pick = np.unique(np.linspace(0, len(h) - 1, min(len(h), HISTORY_POINTS)).round().astype(int))
        h, out["x"], out["x_name"] = h[pick], np.asarray(t, float)[pick].tolist(), "time (s)"
    else:
        out["x"], out["x_name"] = list(range(len(h))), "iteration"
        out["cost"] = costs
    out["ratio"] = np.where(np.isfinite(h / scale), h / scale, None).tolist()
    return out


# -- the campaign (runs on the client) -------------------------------------------------------------


@dataclass(frozen=True)
class Outcome:
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
    methods=METHODS,
    scenarios=SCENARIOS,
    duration: float | None = None,
) -> Outcome:
    """Run (or resume) the campaign into `out` and write results.csv, conclusions.json,
    report.html with its figures and report.rrd. `scheduler`: the address of a running Dask
    scheduler (its workers must see `out`); default a LocalCluster of `workers` processes.
    `seeds`: 1..N (default 20, or 1 with `quick`)."""
    t0 = time.perf_counter()
    out = Path(out)
    seeds = seeds if seeds is not None else (1 if quick else 20)
    cells = plan(seeds, quick, methods, scenarios, duration)
    check_folder(out)
    cells_dir = out / "cells"
    todo = [c for c in cells if read_cell(cells_dir / f"{c.key}.json") is None]
    # the first seed of each scenario is always loaded: its inputs are the report's Figs. 3 and 5
    runs = sorted(
        {(c.scenario, c.seed, c.duration) for c in todo} | {(s, 1, cells[0].duration) for s in scenarios}
    )
    failed = 0
    with _client(scheduler, workers) as client:
        make_folder(out)  # only once the scheduler answered
        where = hashlib.sha256(str(out.resolve()).encode()).hexdigest()[
            :8
        ]  # unique per DIR on a shared scheduler
        data = {
            r: client.submit(
                load_run, str(out.resolve()), *r, key=f"run-{Cell(r[0], '', r[1], r[2]).run_name}-{where}"
            )
            for r in runs
        }
        futures = {
            client.submit(run_cell, c, data[(c.scenario, c.seed, c.duration)], key=f"cell-{c.key}"): c
            for c in todo
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
                    "reason": _one_line(exc),
                    "converged": False,
                    "iterations": 0,
                    "wall_time_s": 0.0,
                    "rows": [],
                }
            failed += doc["status"] == "failed"
            atomic_write_text(cells_dir / f"{cell.key}.json", json.dumps(doc, indent=1) + "\n")
            done += 1
            if progress is not None:
                progress(
                    done / len(cells), f"{cell.scenario} {cell.method} seed {cell.seed}: {doc['status']}"
                )
        inputs = {}
        for (s, seed, d), future in data.items():
            if seed == 1 and d == cells[0].duration:
                try:
                    inputs[s] = future.result()[0]
                except Exception:  # the report says which figure is missing
                    inputs[s] = None
    docs = [read_cell(cells_dir / f"{c.key}.json") for c in cells]
    write_outputs(out, docs, inputs)
    conclusions = json.loads((out / "conclusions.json").read_text())
    return Outcome(out, len(todo), len(cells) - len(todo), failed, conclusions, time.perf_counter() - t0)


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
    one or a campaign's (holding `MARKER`, which it resumes). A folder of anything else is a
    user's, whose files (a results.csv, say) the campaign's would replace."""
    if not os.path.lexists(out):
        check_output_directory(out, label=f"out={out}")  # a file in the way of its parents
        return
    try:
        if not out.is_dir():
            raise InputError(f"out={out}: is a file; expected a folder for the campaign")
        if not (out / MARKER).is_file() and any(out.iterdir()):
            raise InputError(
                f"out={out}: holds files that are not a campaign's (no {MARKER}); expected a new "
                "or empty folder, or a campaign's folder to resume"
            )
    except OSError as exc:
        raise InputError(f"out={out}: cannot read ({exc.strerror or exc})") from None


def make_folder(out: Path) -> None:
    """Make the campaign's folder `out` (checked by `check_folder`), its `MARKER` and `cells/`."""
    try:
        (out / "cells").mkdir(parents=True, exist_ok=True)
        if not (out / MARKER).is_file():
            atomic_write_text(
                out / MARKER, "a testbed reproduce campaign: `testbed reproduce --out` resumes it\n"
            )
    except OSError as exc:
        raise InputError(f"out={out}: cannot create ({exc.strerror or exc})") from None


class _client:
    """A Dask client on the scheduler at `address`, or on a LocalCluster of `workers`
    single-threaded processes (closed on exit)."""

    def __init__(self, address: str | None, workers: int):
        self.address, self.workers, self.cluster = address, workers, None

    def __enter__(self):
        if self.address:
            try:
                self.client = Client(self.address, timeout="10s")
            except (OSError, TimeoutError, ValueError) as exc:
                raise InputError(
                    f"scheduler={self.address}: cannot connect ({_one_line(exc)}); "
                    "expected the address of a running Dask scheduler, e.g. tcp://host:8786"
                ) from None
            return self.client
        self.cluster = LocalCluster(
            n_workers=self.workers,
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            silence_logs=logging.ERROR,
        )
        self.client = Client(self.cluster)
        return self.client

    def __exit__(self, *exc):
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()


# -- results, conclusions, report ------------------------------------------------------------------


def results_rows(docs: list[dict]) -> list[dict]:
    """One row per cell and coefficient; a cell without coefficients (failed) keeps one row with
    an empty coefficient and its reason."""
    rows = []
    for d in docs:
        c = d["cell"]
        base = {
            "scenario": c["scenario"],
            "method": c["method"],
            "seed": c["seed"],
            "converged": d["converged"],
            "iterations": d["iterations"],
            "wall_time_s": round(d["wall_time_s"], 3),
            "status": d["status"],
            "reason": d.get("reason", ""),
        }
        for r in d["rows"] or [
            {"coefficient": "", "analytic": math.nan, "estimate": math.nan, "std": math.nan}
        ]:
            rows.append({**base, **r})
    return rows


def results_csv(rows: list[dict]) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, COLUMNS, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow(
            {k: (format(v, ".10g") if isinstance(v, float) else v) for k, v in r.items() if k in COLUMNS}
        )
    return buf.getvalue()


def read_results(path) -> list[dict]:
    """results.csv back as rows with numbers, booleans and ints."""
    rows = []
    with open(path, newline="") as f:
        for r in csv.DictReader(f):
            rows.append(
                {
                    **r,
                    "seed": int(r["seed"]),
                    "analytic": float(r["analytic"]),
                    "estimate": float(r["estimate"]),
                    "std": float(r["std"]),
                    "converged": r["converged"] == "True",
                    "iterations": int(r["iterations"]),
                    "wall_time_s": float(r["wall_time_s"]),
                }
            )
    return rows


def coefficient_ok(r: dict) -> bool:
    """Within `COEFFICIENT_TOLERANCE` of the analytic value or `COEFFICIENT_SIGMAS` of its σ; an
    infinite (or missing) σ bounds nothing, so only the first clause can pass such a coefficient."""
    err = abs(r["estimate"] - r["analytic"])
    sigma = r["std"]
    return bool(
        np.isfinite(err)
        and (
            err <= COEFFICIENT_TOLERANCE * abs(r["analytic"])
            or (np.isfinite(sigma) and err <= COEFFICIENT_SIGMAS * sigma)
        )
    )


def cell_table(rows: list[dict]) -> dict[tuple, dict]:
    """Per cell (scenario, method, seed): converged, the fraction of acceptable coefficients, the
    median relative error, and whether the cell is acceptable."""
    cells: dict[tuple, list[dict]] = {}
    for r in rows:
        cells.setdefault((r["scenario"], r["method"], r["seed"]), []).append(r)
    out = {}
    for k, rs in cells.items():
        coef = [r for r in rs if r["coefficient"]]
        ok = np.mean([coefficient_ok(r) for r in coef]) if coef else 0.0
        rel = [abs(r["estimate"] - r["analytic"]) / abs(r["analytic"]) for r in coef if r["analytic"]]
        rel = float(np.median(rel)) if rel and np.all(np.isfinite(rel)) else math.inf
        converged = rs[0]["converged"]
        out[k] = {
            "converged": converged,
            "fraction_ok": float(ok),
            "median_relative_error": rel,
            "acceptable": bool(converged and ok >= CELL_FRACTION),
            "status": rs[0]["status"],
        }
    return out


def _share(table, method, scenarios=SCENARIOS) -> tuple[int, int]:
    picked = [v for (s, m, _), v in table.items() if m == method and s in scenarios]
    return sum(v["acceptable"] for v in picked), len(picked)


def conclusions(rows: list[dict], drift: dict[str, dict]) -> dict:
    """The paper's three conclusions, each decided by its rule (README) from the results and,
    for the first, the structural analysis recorded with the cells (`drift`, per scenario)."""
    table = cell_table(rows)
    out = {}
    # 1. no global identifiability; simultaneous drift because of the inertia matrix
    parts, holds = [], bool(drift)
    for s, d in sorted(drift.items()):
        inertia = all(any(n.endswith("dot") for n in g) for g in d["drift_groups"])
        holds &= d["null_directions"] > 0 and inertia and d["null_directions_inertia_known"] == 0
        parts.append(
            f"Scenario {s}: with all 35 coefficients free, {d['null_directions']} exactly "
            f"unidentifiable direction(s) in {len(d['drift_groups'])} drift group(s) of "
            f"{sum(map(len, d['drift_groups']))} coefficients"
            f"{', each with inertia (…dot) terms' if inertia else ', not all with inertia terms'}; "
            f"with the inertia matrix known (a general state equation in At, Bt): "
            f"{d['null_directions_inertia_known']}"
        )
    out["1"] = {"holds": holds, "evidence": "; ".join(parts) or "no cell recorded the structural analysis"}
    # 2. ML with Nelder-Mead acceptable; ML with Newton-Raphson and steepest descent unsatisfactory
    nm_ok, nm_n = _share(table, "ml-nm")
    nr_ok, nr_n = _share(table, "ml-nr")
    nr_conv = sum(v["converged"] for (s, m, _), v in table.items() if m == "ml-nr")
    holds = nm_n > 0 and nr_n > 0 and nm_ok >= ACCEPTABLE * nm_n and nr_ok < UNSATISFACTORY * nr_n
    out["2"] = {
        "holds": bool(holds),
        "evidence": (
            f"ml-nm acceptable in {nm_ok}/{nm_n} cells (rule: ≥ {ACCEPTABLE:.0%}); ml-nr acceptable in "
            f"{nr_ok}/{nr_n} cells (rule: < {UNSATISFACTORY:.0%}), converged in {nr_conv}/{nr_n}; "
            + _medians(table, ("ml-nm", "ml-nr"))
        ),
    }
    # 3. Nelder-Mead satisfactory when the inputs are PRBS (Scenario II) — better than Scenario I
    ok2, n2 = _share(table, "ml-nm", ("II",))
    med = {s: _median(table, "ml-nm", s) for s in SCENARIOS}
    holds = n2 > 0 and ok2 >= ACCEPTABLE * n2 and med["II"] < med["I"]
    out["3"] = {
        "holds": bool(holds),
        "evidence": (
            f"ml-nm on Scenario II (PRBS inputs) acceptable in {ok2}/{n2} cells (rule: ≥ {ACCEPTABLE:.0%}); "
            f"median relative error {_pct(med['II'])} on Scenario II against {_pct(med['I'])} on "
            "Scenario I (rule: smaller on II)"
        ),
    }
    return out


def _median(table, method, scenario) -> float:
    v = [x["median_relative_error"] for (s, m, _), x in table.items() if m == method and s == scenario]
    return float(np.median(v)) if v else math.inf


def _medians(table, methods) -> str:
    return "; ".join(
        f"median relative error of {m}: "
        + ", ".join(f"Scenario {s} {_pct(_median(table, m, s))}" for s in SCENARIOS)
        for m in methods
    )


def _pct(v: float) -> str:
    return f"{100 * v:.1f} %" if np.isfinite(v) else "n/a (no converged estimate)"


def summary_table(rows: list[dict]) -> list[dict]:
    """Per scenario and method: cells, converged, acceptable, median relative error, wall time."""
    table = cell_table(rows)
    times = {}
    for r in rows:
        times.setdefault((r["scenario"], r["method"]), {})[r["seed"]] = r["wall_time_s"]
    out = []
    for s, m in dict.fromkeys((s, m) for s, m, _ in table):
        v = [x for (a, b, _), x in table.items() if (a, b) == (s, m)]
        rel = [x["median_relative_error"] for x in v if np.isfinite(x["median_relative_error"])]
        out.append(
            {
                "scenario": s,
                "method": m,
                "cells": len(v),
                "converged": sum(x["converged"] for x in v),
                "acceptable": sum(x["acceptable"] for x in v),
                "failed": sum(x["status"] == "failed" for x in v),
                "median_relative_error": float(np.median(rel)) if rel else math.nan,
                "median_wall_time_s": float(np.median(list(times[(s, m)].values()))),
            }
        )
    return out


def write_outputs(out: Path, docs: list[dict], inputs: dict) -> None:
    """results.csv, conclusions.json, the figures, report.html and report.rrd from the cells."""

    rows = results_rows(docs)
    atomic_write_text(out / "results.csv", results_csv(rows))
    rows = read_results(out / "results.csv")  # the verdicts are computed from the file itself
    drift = {d["cell"]["scenario"]: d["drift"] for d in docs if "drift" in d}
    verdicts = conclusions(rows, drift)
    atomic_write_text(out / "conclusions.json", json.dumps(verdicts, indent=2) + "\n")
    write_report(out, docs, rows, verdicts, inputs, summary_table(rows), METHODS, SCENARIOS)
