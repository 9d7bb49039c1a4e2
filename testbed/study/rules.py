"""The rules that decide the paper's conclusions from a campaign's results (docs/studies.md).

`conclusions(rows, regime, drift)` reads the rows of results.csv (one per cell and coefficient),
the analytic model's open-loop fit per data set (`regime`) and the drift measured per data set
(`drift`), both keyed "{scenario}/{truth}", and gives per conclusion whether it holds (None: no
evidence to decide), its rule in one sentence and the numbers. A success is a cell whose fit
reached its data set's best-likelihood optimum (`priors.judge`, the `outcome` column); a cell's
distance is measured from that optimum (`relative_distance`: even the optimum sits away from the
analytic model, since the a-priori model's fixed coefficients are wrong too), and its error
against the analytic model (`relative_error`, `coefficient_ok`) is reported beside it; the
analytic model is the truth only where the linear reference is valid: the linear truth, or a
data set the analytic model fits ≥ `VALID_FIT` %. Success proportions carry Wilson score
intervals at `LEVEL`.
"""

from __future__ import annotations

import math
from statistics import NormalDist

import numpy as np

from testbed.study.priors import cost_bound

__all__ = [
    "ACCURATE",
    "ACCEPTABLE",
    "CONDITION_RATIO",
    "COEFFICIENT_SIGMAS",
    "COEFFICIENT_TOLERANCE",
    "FACTORIAL",
    "INFORMATION_ARM",
    "LEVEL",
    "MEKF_ARMS",
    "MEKF_GAP",
    "MEKF_RATIO",
    "NM_ARM",
    "NR_ARM",
    "SHARED_SCATTER_RATIO",
    "SIGMA_RATIO",
    "UNSATISFACTORY",
    "VALID_FIT",
    "accurate",
    "cells",
    "coefficient_ok",
    "conclusions",
    "relative_distance",
    "relative_error",
    "relative_sigma",
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
SHARED_SCATTER_RATIO = 2.0  # ... and the coefficients both forms estimate scatter ≥ 2× as much in it
SIGMA_RATIO = 1.25  # conclusion 3: PRBS's median relative σ no worse than 1.25× the best other input's
MEKF_RATIO = 2.0  # the MEKF's median distances on I and II "similar": within a factor 2 ...
MEKF_GAP = 0.01  # ... or within 1 % of each other: a tenth of the tolerance, below what a user sees
ACCURATE = 1.0  # a cell is accurate when this fraction (all) of its coefficients are acceptable
NM_ARM, NR_ARM = "ml-nm-paper", "ml-nr"  # the paper's Nelder-Mead and its Newton-Raphson (SI units)
INFORMATION_ARM = "ml-gn"  # conclusion 3: whose σ measures an input's information (it reaches the optimum)
MEKF_ARMS = ("mekf-paper", "mekf")  # the paper's MEKF (decides) and the covariance-matched one
# the input factorial's data sets, PRBS first: Scenario II is the PRBS level, the others change
# only its fins' signal (on the plant truth)
FACTORIAL = ("II", "inputs-square", "inputs-3211", "inputs-multisine")


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


def _value(v) -> float:
    """A results.csv number: NaN where it is empty or missing."""
    return math.nan if v is None or v == "" else float(v)


def relative_distance(rows: list[dict]) -> float:
    """A cell's median |θ − θ_optimum| / |θ_optimum| over its coefficients whose optimum is not 0;
    ∞ for a cell without coefficients (a failed fit) or with a non-finite estimate; NaN — the
    cell does not count — where its data set's optimum is unknown (an empty or NaN `optimum`)."""
    coef = [r for r in rows if r["coefficient"]]
    if not coef:
        return math.inf
    optimum = [_value(r.get("optimum")) for r in coef]
    if not all(map(math.isfinite, optimum)):
        return math.nan
    estimate = [_value(r["estimate"]) for r in coef]
    if not all(map(math.isfinite, estimate)):
        return math.inf
    rel = [abs(e - o) / abs(o) for e, o in zip(estimate, optimum) if o]
    return float(np.median(rel)) if rel else math.nan


def relative_sigma(rows: list[dict]) -> float:
    """A cell's median σ / |θ_optimum| (σ / |θ_analytic| where the optimum is unknown) over its
    coefficients whose reference is not 0: the information its data hold, independent of where
    the fit ended; NaN — the cell does not count — where a σ is not finite or there is none."""
    rel = []
    for r in rows:
        if not r["coefficient"]:
            continue
        ref = _value(r.get("optimum"))
        ref = ref if math.isfinite(ref) else _value(r["analytic"])
        sigma = _value(r["std"])
        if not math.isfinite(sigma):
            return math.nan
        if ref:
            rel.append(sigma / abs(ref))
    return float(np.median(rel)) if rel else math.nan


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


def _in_region(cell) -> bool:
    """A cell's fit inside the optimum's 95 % likelihood-ratio region (ΔJ ≤ χ²₀.₉₅(p)/2, p its
    coefficients), however far in σ: the half of success the paper's stopping rule aims at."""
    rows = [r for r in cell[1] if r["coefficient"]]
    return bool(rows) and float(rows[0].get("delta_cost", math.nan)) <= cost_bound(len(rows))


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


def _median(picked, of) -> float:
    """The median of `of(cell rows)` over the picked cells that count (not NaN); NaN for none."""
    v = [x for x in (of(rs) for _, rs in picked) if not math.isnan(x)]
    return float(np.median(v)) if v else math.nan


def _median_error(picked) -> float:
    return _median(picked, relative_error)


def _spreads(picked) -> list[float]:
    return sorted({k[2] for k, _ in picked})


# -- the rules -------------------------------------------------------------------------------------


def _drift(drift: dict, regime: dict) -> dict:
    rule = (
        f"On every data set with a valid linear reference whose drift was measured (≥ 2 seeds), the "
        f"Mt-form's Fisher condition number is ≥ {CONDITION_RATIO:g}× the A-form's and the coefficients "
        f"both forms estimate scatter over the seeds ≥ {SHARED_SCATTER_RATIO:g}× as much with the inertia "
        "free (shared_scatter_mt against shared_scatter_a)."
    )
    needed = ("condition_mt", "condition_a", "shared_scatter_mt", "shared_scatter_a")
    measured = {
        k: d
        for k, d in sorted(drift.items())
        if valid_reference(k, regime)
        and int(d.get("seeds") or 0) >= 2
        and not any(math.isnan(_number(d, v)) for v in needed)
    }
    if not measured:
        return {
            "holds": None,
            "rule": rule,
            "evidence": "no data set with a valid reference had its drift measured",
        }
    parts, holds = [], True
    for k, d in measured.items():
        mt, a, s_mt, s_a = (_number(d, v) for v in needed)
        ratio = mt / a if a > 0 else math.inf
        scatter = s_mt / s_a if s_a > 0 else math.inf
        ok = ratio >= CONDITION_RATIO and scatter >= SHARED_SCATTER_RATIO
        holds &= ok
        converged = (
            f"; converged fits {d['converged_mt']} (Mt-form) and {d['converged_a']} (A-form)"
            if "converged_mt" in d and "converged_a" in d
            else ""
        )
        parts.append(
            f"{k} ({d['seeds']} seeds): condition {mt:.2g} (Mt-form) against {a:.2g} (A-form), ratio "
            f"{ratio:.2g}; shared coefficients' relative scatter {s_mt:.3g} against {s_a:.3g}, ratio "
            f"{scatter:.3g}; relative drift along each form's worst direction "
            f"{_number(d, 'relative_drift_mt'):.3g} (Mt-form) and {_number(d, 'relative_drift_a'):.3g} "
            f"(A-form); null scatter / Cramér-Rao σ {_number(d, 'null_scatter_mt'):.2g} (Mt-form) "
            f"against {_number(d, 'null_scatter_a'):.2g} (A-form){converged}" + ("" if ok else " — fails")
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
        f"{arm} within the likelihood region of the optimum in {sum(map(_in_region, p))}/{len(p)} "
        f"cells, accurate against the analytic model in {sum(accurate(rs) for _, rs in p)}/{len(p)} "
        f"cells, median relative error {_pct(_median_error(p))}"
        for arm, p in ((NM_ARM, nm), (NR_ARM, nr))
    )
    evidence = f"success on {', '.join(sets)}: " + "; ".join(parts) + f"; {accuracy}"
    return {"holds": holds, "rule": rule, "evidence": evidence}


def _inputs(table, regime) -> dict:
    rule = (
        f"From realistic starts, on the factorial data sets (on the plant) with a valid linear reference, "
        f"{NM_ARM} on {FACTORIAL[0]} (the PRBS) reaches the optimum in ≥ {100 * ACCEPTABLE:.0f} % of its "
        f"cells at every spread, and {FACTORIAL[0]} informs the coefficients no worse than the best other "
        f"input: the median over its {INFORMATION_ARM} cells that reach the optimum (their σ is the "
        f"data's Cramér-Rao bound there) of their median relative σ (std / |optimum|, or / |analytic| "
        f"where the optimum is unknown) is ≤ {SIGMA_RATIO:g}× the smallest other input's."
    )

    def on(s):
        return lambda key: key == f"{s}/plant" and valid_reference(key, regime)

    prbs = _pick(table, NM_ARM, on(FACTORIAL[0]))
    informed_by = {s: _pick(table, INFORMATION_ARM, on(s)) for s in FACTORIAL}
    if not prbs or not any(informed_by[s] for s in FACTORIAL[1:]):
        return {
            "holds": None,
            "rule": rule,
            "evidence": f"no {NM_ARM} cells on {FACTORIAL[0]}, or no {INFORMATION_ARM} cells on another "
            "input, with a valid reference",
        }
    holds, parts = True, []
    for s in _spreads(prbs):
        k, n = _success([c for c in prbs if c[0][2] == s])
        holds &= k >= ACCEPTABLE * n
        parts.append(f"spread {s:g} {_proportion(k, n)}")
    sigma = {
        s: _median([c for c in p if c[1][0]["outcome"] == "success"], relative_sigma)
        for s, p in informed_by.items()
        if p
    }
    informed = {s: v for s, v in sigma.items() if s != FACTORIAL[0] and not math.isnan(v)}
    if math.isnan(sigma.get(FACTORIAL[0], math.nan)) or not informed:
        best, verdict = "none (no finite σ)", False if not holds else None
    else:
        best = min(informed, key=informed.get)
        verdict = bool(holds and sigma[FACTORIAL[0]] <= SIGMA_RATIO * informed[best])
    detail = "; ".join(
        f"{s} median relative σ {_pct(sigma[s])} ({INFORMATION_ARM} at the optimum in "
        f"{_proportion(*_success(informed_by[s]))})"
        for s in sigma
    )
    evidence = (
        f"{NM_ARM} on {FACTORIAL[0]} reaches the optimum: "
        + ", ".join(parts)
        + f", median relative distance from the optimum {_pct(_median(prbs, relative_distance))}"
        + f"; per input: {detail}; the best other input: {best}"
    )
    return {"holds": verdict, "rule": rule, "evidence": evidence}


def _mekf(table) -> dict:
    rule = (
        f"From realistic starts, on the linear-truth data sets I/linear and II/linear, "
        f"{MEKF_ARMS[0]}'s median relative distance from the data set's best-likelihood optimum "
        f"(the optimum, not the analytic model: the fixed coefficients of every start are perturbed "
        f"too) is ≤ {100 * COEFFICIENT_TOLERANCE:.0f} % on both and the larger is within "
        f"{MEKF_RATIO:g}× the smaller or {100 * MEKF_GAP:g} % of it (its error against the analytic "
        f"model, and {MEKF_ARMS[1]}'s, reported beside it)."
    )
    cells_of = {
        arm: {s: _pick(table, arm, lambda key, s=s: key == f"{s}/linear") for s in ("I", "II")}
        for arm in MEKF_ARMS
    }
    decide = {s: _median(p, relative_distance) for s, p in cells_of[MEKF_ARMS[0]].items()}
    evidence = "; ".join(
        f"{arm}: median relative distance from the optimum "
        + ", ".join(f"{_pct(_median(c[s], relative_distance))} on {s}/linear" for s in c)
        + "; median relative error against the analytic model "
        + ", ".join(f"{_pct(_median_error(c[s]))} on {s}/linear" for s in c)
        for arm, c in cells_of.items()
        if any(c.values())
    )
    if any(math.isnan(v) for v in decide.values()):
        return {
            "holds": None,
            "rule": rule,
            "evidence": f"no {MEKF_ARMS[0]} cells with a known optimum on both I/linear and II/linear"
            + (f" ({evidence})" if evidence else ""),
        }
    lo, hi = sorted(decide.values())
    holds = hi <= COEFFICIENT_TOLERANCE and (hi <= MEKF_RATIO * lo or hi - lo <= MEKF_GAP)
    return {"holds": bool(holds), "rule": rule, "evidence": evidence}
