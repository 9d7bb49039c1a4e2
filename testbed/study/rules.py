"""The rules that decide the paper's conclusions from a campaign's results (docs/studies.md).

`conclusions(rows, regime, drift)` reads the rows of results.csv (one per cell and coefficient),
the analytic model's open-loop fit per data set (`regime`) and the drift measured per data set
(`drift`), both keyed "{scenario}/{truth}", and gives per conclusion whether it holds (None: no
evidence to decide), its rule in one sentence and the numbers. A success is a cell whose fit
reached its data set's best-likelihood optimum (`priors.judge`, the `outcome` column); accuracy
is against the analytic model (`coefficient_ok`), which is the truth only where the linear
reference is valid: the linear truth, or a data set the analytic model fits ≥ `VALID_FIT` %.
Success proportions carry Wilson score intervals at `LEVEL`.
"""

from __future__ import annotations

import math
from statistics import NormalDist

import numpy as np

__all__ = [
    "ACCURATE",
    "ACCEPTABLE",
    "CONDITION_RATIO",
    "COEFFICIENT_SIGMAS",
    "COEFFICIENT_TOLERANCE",
    "FACTORIAL",
    "LEVEL",
    "MEKF_ARMS",
    "MEKF_RATIO",
    "NM_ARM",
    "NR_ARM",
    "RELATIVE_DRIFT",
    "UNSATISFACTORY",
    "VALID_FIT",
    "accurate",
    "cells",
    "coefficient_ok",
    "conclusions",
    "relative_error",
    "valid_reference",
    "wilson",
]

COEFFICIENT_TOLERANCE = 0.10  # a coefficient is acceptable within 10 % of the analytic value ...
COEFFICIENT_SIGMAS = 3.0  # ... or within 3 of its (coloured-residual) σ; an infinite σ never passes
VALID_FIT = 99.0  # % lowest truth fit of the analytic model: the linear reference is valid above it
LEVEL = 0.95  # of the Wilson intervals
ACCEPTABLE = 0.8  # a method is acceptable when it succeeds in ≥ 80 % of its cells ...
UNSATISFACTORY = 0.5  # ... and unsatisfactory when in fewer than 50 %
CONDITION_RATIO = 10.0  # conclusion 1: the Mt-form's Fisher condition number ≥ 10× the A-form's ...
RELATIVE_DRIFT = COEFFICIENT_TOLERANCE  # ... and its seeds drift ≥ 10 % along its worst direction
MEKF_RATIO = 2.0  # the MEKF's median errors on I and II "similar": within a factor 2
ACCURATE = 1.0  # a cell is accurate when this fraction (all) of its coefficients are acceptable
NM_ARM, NR_ARM = "ml-nm-paper", "ml-nr"  # the paper's Nelder-Mead and its Newton-Raphson (SI units)
MEKF_ARMS = ("mekf-paper", "mekf")  # the paper's MEKF (decides) and the covariance-matched one
FACTORIAL = ("inputs-prbs", "inputs-square", "inputs-3211", "inputs-multisine")  # PRBS first


def wilson(k: int, n: int, level: float = LEVEL) -> tuple[float, float]:
    """The Wilson score interval of a proportion k/n at `level`: the p whose normal test of k
    successes in n trials is not rejected at 1 − level; (0, 1) for n = 0."""
    if n == 0:
        return 0.0, 1.0
    z = NormalDist().inv_cdf(0.5 + level / 2)
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z / (1 + z * z / n) * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    return max(0.0, centre - half), min(1.0, centre + half)


def coefficient_ok(r: dict) -> bool:
    """Within `COEFFICIENT_TOLERANCE` of the analytic value or `COEFFICIENT_SIGMAS` of its σ; an
    infinite (or missing) σ bounds nothing, so only the first clause can pass such a coefficient."""
    err = abs(float(r["estimate"]) - float(r["analytic"]))
    sigma = float(r["std"])
    return bool(
        math.isfinite(err)
        and (
            err <= COEFFICIENT_TOLERANCE * abs(float(r["analytic"]))
            or (math.isfinite(sigma) and err <= COEFFICIENT_SIGMAS * sigma)
        )
    )


def cells(rows: list[dict]) -> dict[tuple, list[dict]]:
    """The rows of each cell: (scenario, truth, spread, arm, seed) → its rows."""
    out: dict[tuple, list[dict]] = {}
    for r in rows:
        key = (r["scenario"], r["truth"], float(r["spread"]), r["arm"], int(r["seed"]))
        out.setdefault(key, []).append(r)
    return out


def accurate(rows: list[dict]) -> bool:
    """A cell's coefficients against the analytic model: it has some, and at least `ACCURATE`
    of them pass `coefficient_ok`."""
    coef = [r for r in rows if r["coefficient"]]
    return bool(coef) and sum(map(coefficient_ok, coef)) >= ACCURATE * len(coef)


def relative_error(rows: list[dict]) -> float:
    """A cell's median |θ − θ_analytic| / |θ_analytic| over its coefficients not analysed at 0;
    ∞ for a cell without any, or with a non-finite estimate (a diverged fit is not ignored)."""
    rel = [
        abs(float(r["estimate"]) - float(r["analytic"])) / abs(float(r["analytic"]))
        for r in rows
        if r["coefficient"] and float(r["analytic"])
    ]
    return float(np.median(rel)) if rel and all(map(math.isfinite, rel)) else math.inf


def valid_reference(key: str, regime: dict) -> bool:
    """Whether the analytic model is the truth of data set `key` ("{scenario}/{truth}"): the
    linear truth, or a data set it fits ≥ `VALID_FIT` % on every excited channel."""
    if key.endswith("/linear"):
        return True
    fit = (regime.get(key) or {}).get("lowest_truth_fit")
    return fit is not None and float(fit) >= VALID_FIT


def conclusions(rows: list[dict], regime: dict, drift: dict) -> dict:
    """The paper's conclusions "1", "2", "3" and the MEKF's "mekf": each {"holds": True, False
    or None (no evidence), "rule": its rule, "evidence": the numbers}."""
    table = cells(rows)
    return {
        "1": _drift(drift, regime),
        "2": _methods(table, regime),
        "3": _inputs(table, regime),
        "mekf": _mekf(table),
    }


# -- helpers on the cell table ---------------------------------------------------------------------


def _number(d: dict, key: str) -> float:
    """d[key] as a float; NaN where it is missing or null (a NaN written to JSON)."""
    v = d.get(key)
    return math.nan if v is None else float(v)


def _pick(table, arm, keep) -> list[tuple[tuple, list[dict]]]:
    """The cells of `arm` from realistic starts (spread > 0) on the data sets ("{scenario}/{truth}")
    `keep` accepts."""
    return [(k, rs) for k, rs in table.items() if k[3] == arm and k[2] > 0 and keep(f"{k[0]}/{k[1]}")]


def _success(picked) -> tuple[int, int]:
    return sum(rs[0]["outcome"] == "success" for _, rs in picked), len(picked)


def _proportion(k: int, n: int) -> str:
    lo, hi = wilson(k, n)
    return (
        f"{k}/{n} ({100 * k / n:.0f} %, {100 * LEVEL:.0f} % CI {100 * lo:.0f}–{100 * hi:.0f} %)"
        if n
        else "0/0"
    )


def _pct(v: float) -> str:
    if math.isnan(v):
        return "n/a (no cells)"
    return f"{100 * v:.1f} %" if math.isfinite(v) else "∞ (a diverged or empty fit)"


def _median_error(picked) -> float:
    return float(np.median([relative_error(rs) for _, rs in picked])) if picked else math.nan


def _spreads(picked) -> list[float]:
    return sorted({k[2] for k, _ in picked})


# -- the rules -------------------------------------------------------------------------------------


def _drift(drift: dict, regime: dict) -> dict:
    rule = (
        f"On every data set with a valid linear reference whose drift was measured (≥ 2 seeds), the "
        f"Mt-form's Fisher condition number is ≥ {CONDITION_RATIO:g}× the A-form's and its seeds' rms "
        f"relative deviation along its worst direction is ≥ {100 * RELATIVE_DRIFT:.0f} %."
    )
    measured = {
        k: d
        for k, d in sorted(drift.items())
        if valid_reference(k, regime)
        and int(d.get("seeds") or 0) >= 2
        and not any(math.isnan(_number(d, v)) for v in ("condition_mt", "condition_a", "relative_drift_mt"))
    }
    if not measured:
        return {
            "holds": None,
            "rule": rule,
            "evidence": "no data set with a valid reference had its drift measured",
        }
    parts, holds = [], True
    for k, d in measured.items():
        mt, a, moved = (_number(d, v) for v in ("condition_mt", "condition_a", "relative_drift_mt"))
        ratio = mt / a if a > 0 else math.inf
        ok = ratio >= CONDITION_RATIO and moved >= RELATIVE_DRIFT
        holds &= ok
        parts.append(
            f"{k} ({d['seeds']} seeds): condition {mt:.2g} (Mt-form) against {a:.2g} (A-form), ratio "
            f"{ratio:.2g}; relative drift along the worst direction {moved:.3g}; null scatter / "
            f"Cramér-Rao σ {_number(d, 'null_scatter_mt'):.2g} (Mt-form) against "
            f"{_number(d, 'null_scatter_a'):.2g} (A-form)" + ("" if ok else " — fails")
        )
    return {"holds": holds, "rule": rule, "evidence": "; ".join(parts)}


def _methods(table, regime) -> dict:
    rule = (
        f"From realistic starts (spread > 0), on the data sets with a valid linear reference, "
        f"{NM_ARM} reaches the optimum in ≥ {100 * ACCEPTABLE:.0f} % of its cells and {NR_ARM} in "
        f"< {100 * UNSATISFACTORY:.0f} %, at every spread."
    )
    nm, nr = (_pick(table, arm, lambda key: valid_reference(key, regime)) for arm in (NM_ARM, NR_ARM))
    spreads = sorted(set(_spreads(nm)) & set(_spreads(nr)))
    if not spreads:
        return {
            "holds": None,
            "rule": rule,
            "evidence": f"no {NM_ARM} and {NR_ARM} cells at a common spread > 0 on a valid data set",
        }
    parts, holds = [], True
    for s in spreads:
        (k1, n1), (k2, n2) = (_success([c for c in p if c[0][2] == s]) for p in (nm, nr))
        holds &= k1 >= ACCEPTABLE * n1 and k2 < UNSATISFACTORY * n2
        parts.append(f"spread {s:g}: {NM_ARM} {_proportion(k1, n1)}, {NR_ARM} {_proportion(k2, n2)}")
    sets = sorted({f"{k[0]}/{k[1]}" for k, _ in nm + nr})
    accuracy = "; ".join(
        f"{arm} accurate against the analytic model in {sum(accurate(rs) for _, rs in p)}/{len(p)} "
        f"cells, median relative error {_pct(_median_error(p))}"
        for arm, p in ((NM_ARM, nm), (NR_ARM, nr))
    )
    evidence = f"success on {', '.join(sets)}: " + "; ".join(parts) + f"; {accuracy}"
    return {"holds": holds, "rule": rule, "evidence": evidence}


def _inputs(table, regime) -> dict:
    rule = (
        f"From realistic starts, {NM_ARM} on {FACTORIAL[0]} reaches the optimum in "
        f"≥ {100 * ACCEPTABLE:.0f} % of its cells at every spread, and its share of accurate cells "
        f"(every coefficient within {100 * COEFFICIENT_TOLERANCE:.0f} % or {COEFFICIENT_SIGMAS:g} σ of "
        f"the analytic model) has a {100 * LEVEL:.0f} % Wilson interval reaching the best share among "
        "the other inputs (PRBS no worse within sampling error); only data sets with a valid linear "
        "reference count."
    )
    picked = {
        s: _pick(table, NM_ARM, lambda key, s=s: key.split("/")[0] == s and valid_reference(key, regime))
        for s in FACTORIAL
    }
    prbs, others = picked[FACTORIAL[0]], {s: p for s, p in picked.items() if s != FACTORIAL[0] and p}
    if not prbs or not others:
        return {
            "holds": None,
            "rule": rule,
            "evidence": f"no {NM_ARM} cells on {FACTORIAL[0]} and another input with a valid reference",
        }
    holds, parts = True, []
    for s in _spreads(prbs):
        k, n = _success([c for c in prbs if c[0][2] == s])
        holds &= k >= ACCEPTABLE * n
        parts.append(f"spread {s:g} {_proportion(k, n)}")
    share = {s: (sum(accurate(rs) for _, rs in p), len(p)) for s, p in picked.items() if p}
    best = max(others, key=lambda s: share[s][0] / share[s][1])
    k, n = share[FACTORIAL[0]]
    holds &= wilson(k, n)[1] >= share[best][0] / share[best][1]
    accuracy = "; ".join(
        f"{s} {_proportion(*share[s])} accurate, median relative error {_pct(_median_error(picked[s]))}"
        for s in share
    )
    evidence = (
        f"{NM_ARM} on {FACTORIAL[0]} reaches the optimum: "
        + ", ".join(parts)
        + f"; accuracy: {accuracy}; the best other input: {best}"
    )
    return {"holds": holds, "rule": rule, "evidence": evidence}


def _mekf(table) -> dict:
    rule = (
        f"From realistic starts, on the linear-truth data sets I/linear and II/linear, "
        f"{MEKF_ARMS[0]}'s median relative error against the (exact) analytic model is "
        f"≤ {100 * COEFFICIENT_TOLERANCE:.0f} % on both and the larger is within {MEKF_RATIO:g}× the "
        f"smaller ({MEKF_ARMS[1]} reported beside it)."
    )
    errors = {
        arm: {s: _median_error(_pick(table, arm, lambda key, s=s: key == f"{s}/linear")) for s in ("I", "II")}
        for arm in MEKF_ARMS
    }
    decide = errors[MEKF_ARMS[0]]
    if any(math.isnan(v) for v in decide.values()):
        return {
            "holds": None,
            "rule": rule,
            "evidence": f"no {MEKF_ARMS[0]} cells on both I/linear and II/linear",
        }
    lo, hi = sorted(decide.values())
    holds = hi <= COEFFICIENT_TOLERANCE and hi <= MEKF_RATIO * lo
    evidence = "; ".join(
        f"{arm}: median relative error {_pct(e['I'])} on I/linear, {_pct(e['II'])} on II/linear"
        for arm, e in errors.items()
        if not all(math.isnan(v) for v in e.values())
    )
    return {"holds": bool(holds), "rule": rule, "evidence": evidence}
