"""The campaign's results from its cell files: every judged cell against its data set's
best-likelihood optimum, results.csv, and the table per data set, spread and arm.

The optimum of a data set, seed and spread is the lowest `cost` (the output-error negative
log-likelihood at the estimate, the same measure for every method) among its `OPTIMUM` cell
(the multi-start search, `cells.REFERENCE_SEARCH`) and its judged arms' end points. Its σ are the
`OPTIMUM` cell's Cramér-Rao σ (corrected for coloured residuals), the lowest cell's own where
those are not finite; they are the σ of every accuracy measure (`optimum_std`). Each judged cell
is then judged by `priors.judge`: success (inside the optimum's likelihood region), diverged,
stalled at the limit or converged elsewhere; a cell whose fit failed is "failed"; the drift arms
are not judged (their outcome is empty). `search_delta_cost` is a cell's cost less the search's:
below −`SEARCH_TIE` the arm found what the search missed (`beat_search` in the summary counts
those cells, which should be none: the search is then too small). The nonlinear cells
(`NONLINEAR_ARMS`) are judged against the captive reference instead: their rows carry the
captive value in the `analytic` column (the reference of `rules.accurate` and
`rules.relative_error` in the summary), the data's σ in `optimum_std` (the nonlinear model's ML
fit's, the `NONLINEAR_ARM` cell of the same seed and spread) and the largest |θ − θ_captive|/σ
in `sigmas`; their outcome is empty.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass

import numpy as np

from testbed.estimators.base import Status
from testbed.study.arms import ARMS, NONLINEAR_ARM, NONLINEAR_ARMS
from testbed.study.cells import OPTIMUM, Cell
from testbed.study.priors import Judgement, judge
from testbed.study.rules import accurate, cells, coefficient_ok, relative_error, wilson

__all__ = [
    "COLUMNS",
    "SEARCH_TIE",
    "SUMMARY_COLUMNS",
    "Judged",
    "captive_table",
    "judgements",
    "read_results",
    "results_csv",
    "results_rows",
    "summary_table",
]

COLUMNS = (
    "scenario",
    "truth",
    "spread",
    "arm",
    "method",
    "seed",
    "coefficient",
    "analytic",
    "optimum",
    "estimate",
    "std",
    "optimum_std",
    "converged",
    "status",
    "outcome",
    "sigmas",
    "delta_cost",
    "search_delta_cost",
    "iterations",
    "evaluations",
    "wall_time_s",
    "reason",
)
SUMMARY_COLUMNS = (
    "scenario",
    "truth",
    "spread",
    "arm",
    "cells",
    "success",
    "judged",
    "success_low",
    "success_high",
    "diverged",
    "stalled",
    "elsewhere",
    "failed",
    "beat_search",
    "min_search_delta_cost",
    "accurate",
    "median_relative_error",
    "median_evaluations",
    "median_wall_time_s",
)
SEARCH_TIE = 0.01  # ΔJ: a cost this much below the search's is one the search missed

NUMBERS = (
    "spread",
    "analytic",
    "optimum",
    "estimate",
    "std",
    "optimum_std",
    "sigmas",
    "delta_cost",
    "search_delta_cost",
    "wall_time_s",
)
INTEGERS = ("seed", "iterations", "evaluations")


@dataclass(frozen=True)
class Judged:
    """A cell's estimate as the judge reads it: free names, values, σ, cost and status."""

    free: tuple
    coefficients: dict
    std: tuple
    cost: float
    status: Status


def _point(doc: dict, sigma: dict | None = None) -> Judged:
    """`doc` as the judge reads it; with `sigma` (the `OPTIMUM` cell's σ), those σ where finite,
    the doc's own elsewhere."""
    free = tuple(doc["free"])
    std = {n: v for n, v in doc.get("std", {}).items() if v is not None and math.isfinite(v)}
    std |= {n: v for n, v in (sigma or {}).items() if math.isfinite(v)}
    s = tuple(float(std.get(n, math.inf)) for n in free)
    status = Status[doc["status"].upper().replace(" ", "_")] if doc["status"] != "failed" else Status.DIVERGED
    return Judged(free, dict(doc["values"]), s, float(doc.get("cost", math.inf)), status)


def _group(doc: dict) -> tuple:
    c = doc["cell"]
    return (c["scenario"], c["truth"], c["spread"], c["seed"], c["duration"])


def judgements(docs: list[dict]) -> dict[str, tuple[Judgement, Judged, float] | None]:
    """Per judged cell's key: its judgement, the optimum it was judged against and its cost less
    the search's (NaN without one); None where the cell failed or its group has no finite
    optimum."""
    groups: dict[tuple, list[dict]] = {}
    for d in docs:
        groups.setdefault(_group(d), []).append(d)
    out = {}
    for group in groups.values():
        reference = next((d for d in group if d["cell"]["arm"] == OPTIMUM and d["status"] != "failed"), None)
        judged = [d for d in group if d["cell"]["arm"] in ARMS and ARMS[d["cell"]["arm"]].judged]
        sigma = {n: s for n, s in zip(reference["free"], _point(reference).std)} if reference else {}
        candidates = [
            d
            for d in judged + ([reference] if reference else [])
            if d["status"] != "failed" and math.isfinite(d.get("cost", math.inf))
        ]
        best = _point(min(candidates, key=lambda d: d["cost"]), sigma) if candidates else None
        finite = reference is not None and math.isfinite(reference.get("cost", math.inf))
        search = reference["cost"] if finite else math.nan
        for d in judged:
            if d["status"] == "failed" or best is None or set(d["free"]) != set(best.free):
                out[d["key"]] = None
                continue
            out[d["key"]] = (judge(_point(d), best), best, float(d["cost"]) - search)
    return out


def results_rows(docs: list[dict]) -> list[dict]:
    """One row per cell and coefficient (the `OPTIMUM` cells appear as the `optimum` column of
    the others); a cell without coefficients (failed) keeps one row with an empty coefficient."""
    verdicts = judgements(docs)
    # the nonlinear model's σ of the data, per seed and spread: its ML fit's (the NONLINEAR_ARM cell's)
    nonlinear_sigma = {
        (d["cell"]["seed"], d["cell"]["spread"]): {n: _std(d, n) for n in d.get("free", [])}
        for d in docs
        if d["cell"]["arm"] == NONLINEAR_ARM and d.get("free")
    }
    rows = []
    for d in docs:
        c = d["cell"]
        if c["arm"] == OPTIMUM:
            continue
        nonlinear = c["arm"] in NONLINEAR_ARMS
        verdict = verdicts.get(d["key"])
        judged = ARMS[c["arm"]].judged if c["arm"] in ARMS else False
        outcome = (
            "failed" if d["status"] == "failed" else (verdict[0].outcome.name.lower() if verdict else "")
        )
        if judged and outcome == "" and d["status"] != "failed":
            outcome = "unjudged"
        reference = d.get("captive") if nonlinear else d.get("analytic")
        sigmas = verdict[0].sigmas if verdict else math.nan
        # accuracy is judged in the data's Cramér-Rao σ: the optimum's; a nonlinear cell's, the
        # nonlinear model's ML fit's of the same seed and spread (its own where there is none)
        if verdict:
            sigma = dict(zip(verdict[1].free, verdict[1].std))
        elif nonlinear:
            own = {n: _std(d, n) for n in d.get("free", [])}
            sigma = {**own, **nonlinear_sigma.get((c["seed"], c["spread"]), {})}
            if d.get("values"):
                sigmas = max(
                    (
                        abs(d["values"][n] - reference[n]) / sigma[n] if sigma[n] > 0 else math.inf
                        for n in d["values"]
                    ),
                    default=math.nan,
                )
        else:
            sigma = {}
        base = {
            "scenario": c["scenario"],
            "truth": c["truth"],
            "spread": c["spread"],
            "arm": c["arm"],
            "method": Cell(**c).method if c["arm"] in ARMS or nonlinear else "",
            "seed": c["seed"],
            "converged": d["converged"],
            "status": d["status"],
            "outcome": outcome,
            "sigmas": sigmas,
            "delta_cost": verdict[0].delta_cost if verdict else math.nan,
            "search_delta_cost": verdict[2] if verdict else math.nan,
            "iterations": d["iterations"],
            "evaluations": d.get("evaluations", 0),
            "wall_time_s": round(d["wall_time_s"], 3),
            "reason": d.get("reason", ""),
        }
        optimum = verdict[1].coefficients if verdict else {}
        names = d.get("free") or [""]
        for n in names:
            rows.append(
                {
                    **base,
                    "coefficient": n,
                    "analytic": reference[n] if n else math.nan,
                    "optimum": optimum.get(n, math.nan),
                    "estimate": d["values"][n] if n else math.nan,
                    "std": _std(d, n),
                    "optimum_std": float(sigma.get(n, math.nan)),
                }
            )
    return rows


def _std(doc: dict, name: str) -> float:
    v = doc.get("std", {}).get(name) if name else None
    return math.nan if v is None else float(v)


def results_csv(rows: list[dict], columns=COLUMNS) -> str:
    """`rows` as CSV with `columns` (results.csv; `SUMMARY_COLUMNS`: summary.csv), floats to 10 digits."""
    buf = io.StringIO()
    w = csv.DictWriter(buf, columns, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow(
            {k: (format(v, ".10g") if isinstance(v, float) else v) for k, v in r.items() if k in columns}
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
                    **{k: float(r[k]) for k in NUMBERS},
                    **{k: int(r[k]) for k in INTEGERS},
                    "converged": r["converged"] == "True",
                }
            )
    return rows


def summary_table(rows: list[dict]) -> list[dict]:
    """Per data set, spread and arm: cells, each outcome's count, the success proportion with its
    Wilson 95 % interval, the cells whose cost is below the reference search's (`beat_search`,
    beyond `SEARCH_TIE`) and the least cost difference from it, the cells whose coefficients are
    acceptable against the analytic model
    (`rules.accurate`), the median of the cells' relative errors against it (`rules.relative_error`,
    those finite), and the median evaluations and wall time."""
    groups: dict[tuple, list[list[dict]]] = {}
    for (s, t, sp, a, _), rs in cells(rows).items():
        groups.setdefault((s, t, sp, a), []).append(rs)
    out = []
    for (s, t, sp, a), cs in groups.items():
        outcomes = [rs[0]["outcome"] for rs in cs]
        judged = [o for o in outcomes if o and o != "unjudged"]
        k, n = outcomes.count("success"), len(judged)
        lo, hi = wilson(k, n) if n else (math.nan, math.nan)
        rel = [v for v in map(relative_error, cs) if np.isfinite(v)]
        below = [rs[0]["search_delta_cost"] for rs in cs if math.isfinite(rs[0]["search_delta_cost"])]
        out.append(
            {
                "scenario": s,
                "truth": t,
                "spread": sp,
                "arm": a,
                "cells": len(cs),
                "success": k,
                "judged": n,
                "success_low": lo,
                "success_high": hi,
                **{o: outcomes.count(o) for o in ("diverged", "stalled", "elsewhere", "failed")},
                "beat_search": sum(v < -SEARCH_TIE for v in below),
                "min_search_delta_cost": min(below, default=math.nan),
                "accurate": sum(map(accurate, cs)),
                "median_relative_error": float(np.median(rel)) if rel else math.nan,
                "median_evaluations": float(np.median([rs[0]["evaluations"] for rs in cs])),
                "median_wall_time_s": float(np.median([rs[0]["wall_time_s"] for rs in cs])),
            }
        )
    return out


def captive_table(rows: list[dict], docs: list[dict]) -> dict[str, list[dict]]:
    """The nonlinear cells (`NONLINEAR_ARMS`) against the captive reference: "coefficients", per
    arm, spread and coefficient (results.csv's rows, the captive value in `analytic`, σ the data's
    in `optimum_std`), the captive value, the cells, the median estimate, the median error in σ
    ((θ − θ_captive)/σ) and in % of the captive value, and the cells within
    `rules.coefficient_ok` (max(3 σ, 10 %) of the captive value); "cells", per cell (`docs`) its
    arm, seed, spread, status, iterations, wall time and open-loop fit % per experiment and
    channel."""
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        if r["arm"] in NONLINEAR_ARMS and r["coefficient"]:
            groups.setdefault((r["arm"], r["spread"], r["coefficient"]), []).append(r)
    order = list(NONLINEAR_ARMS)
    out = []
    for (a, sp, n), rs in sorted(groups.items(), key=lambda g: (order.index(g[0][0]), g[0][1])):
        sigmas = [(r["estimate"] - r["analytic"]) / r["optimum_std"] for r in rs]
        out.append(
            {
                "arm": a,
                "spread": sp,
                "coefficient": n,
                "captive": rs[0]["analytic"],
                "cells": len(rs),
                "median_estimate": float(np.median([r["estimate"] for r in rs])),
                "median_error_sigmas": float(np.median(sigmas)),
                "median_error_percent": float(
                    np.median([100 * (r["estimate"] - r["analytic"]) / r["analytic"] for r in rs])
                ),
                "within": sum(map(coefficient_ok, rs)),
            }
        )
    fits = [
        {
            **{k: d["cell"][k] for k in ("arm", "seed", "spread")},
            **{k: d[k] for k in ("status", "iterations", "wall_time_s")},
            "fit": d.get("fit", {}),
            "fit_note": d.get("fit_note", ""),
        }
        for d in docs
        if d and d["cell"]["arm"] in NONLINEAR_ARMS
    ]
    return {"coefficients": out, "cells": fits}
