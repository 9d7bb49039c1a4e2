"""The rules that decide the paper's claims from a campaign's results (docs/studies.md).

`conclusions(rows, regime, drift)` reads the rows of results.csv (one per cell and coefficient),
the analytic model's open-loop fit per data set (`regime`, keyed "{scenario}/{truth}") and the
drift measured per data set and spread (`drift`, keyed "{scenario}/{truth} s={spread}"), and
gives per claim its verdict — reproduced, not reproduced, or not decided (no evidence, or a
Wilson interval at `INTERVAL_LEVEL` straddling the rule's threshold) — its rule in one sentence and the
numbers. Each claim is decided as the paper makes it, on each data set where the linear
reference is valid (the linear truth, or a data set the analytic model fits ≥ `VALID_FIT` %)
and at each spread, and holds only where it holds on each.

A success is a cell whose fit ended inside its data set's optimum's likelihood region
(`priors.judge`, the `outcome` column): what a stopping rule on the cost, or a filter, can
deliver. Its distance from the optimum in the optimum's σ, and its error against the analytic
model (`relative_error`; `coefficient_ok` in the optimum's σ, never a cell's own), are reported
beside it.
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
    "DRIFT_AT",
    "FACTORIAL",
    "INFORMATION_ARM",
    "INTERVAL_LEVEL",
    "LONGER",
    "MEKF_ARMS",
    "NM_ARM",
    "NR_ARM",
    "SHARED_SCATTER_RATIO",
    "UNSATISFACTORY",
    "VALID_FIT",
    "VERDICTS",
    "accurate",
    "cells",
    "coefficient_ok",
    "conclusions",
    "decide",
    "relative_error",
    "relative_sigma",
    "valid_reference",
    "wilson",
]

COEFFICIENT_TOLERANCE = 0.10  # a coefficient is acceptable within 10 % of the analytic value ...
COEFFICIENT_SIGMAS = 3.0  # ... or within 3 of the optimum's (coloured-residual) σ; an infinite σ never passes
VALID_FIT = 99.0  # % lowest fit of the analytic model to the truth: the linear reference is valid above it
INTERVAL_LEVEL = 0.95  # of the Wilson intervals
ACCEPTABLE = 0.8  # a method is acceptable when it succeeds in ≥ 80 % of its cells ...
UNSATISFACTORY = 0.5  # ... and unsatisfactory when in fewer than 50 %
CONDITION_RATIO = 10.0  # conclusion 1: the Mt-form's Fisher condition number ≥ 10× the A-form's ...
SHARED_SCATTER_RATIO = 2.0  # ... and the coefficients both forms estimate scatter ≥ 2× as much in it
ACCURATE = 1.0  # a cell is accurate when this fraction (all) of its coefficients are acceptable
NM_ARM, NR_ARM = "ml-nm-paper", "ml-nr"  # the paper's Nelder-Mead and its Newton-Raphson (SI units)
LONGER = {NM_ARM: "ml-nm-paper-10x", NR_ARM: "ml-nr-10x"}  # each with ten times its iteration limit
INFORMATION_ARM = "ml-gn"  # the arm the input factorial's other inputs are fitted with
MEKF_ARMS = ("mekf-paper", "mekf")  # the paper's MEKF (decides) and the covariance-matched one
# the input factorial's data sets, PRBS first: Scenario II is the PRBS level, the others change
# only its fins' signal (on the plant truth)
FACTORIAL = ("II", "inputs-square", "inputs-3211", "inputs-multisine")
DRIFT_AT = " s="  # drift.json's keys: "{scenario}/{truth} s={spread}"
VERDICTS = {True: "reproduced", False: "not reproduced", None: "not decided"}
_WORD = {True: "yes", False: "no", None: "not decided"}


def wilson(k: int, n: int, level: float = INTERVAL_LEVEL) -> tuple[float, float]:
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
    """Within `COEFFICIENT_TOLERANCE` of the analytic value or `COEFFICIENT_SIGMAS` σ of it, σ the
    data's Cramér-Rao bound (`optimum_std`: the optimum's, the same for every arm, never a cell's
    own, which a fit stopped far off can inflate); an infinite (or missing) σ bounds nothing, so
    only the first clause can pass such a coefficient."""
    err = abs(float(r["estimate"]) - float(r["analytic"]))
    sigma = _value(r.get("optimum_std"))
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


def relative_sigma(rows: list[dict]) -> float:
    """A cell's median σ / |θ_optimum| (σ / |θ_analytic| where the optimum is unknown) over its
    coefficients whose reference is not 0, σ the optimum's Cramér-Rao bound (`optimum_std`): the
    information its data hold, independent of where the fit ended; NaN — the cell does not
    count — where a σ is not finite or there is none."""
    rel = []
    for r in rows:
        if not r["coefficient"]:
            continue
        ref = _value(r.get("optimum"))
        ref = ref if math.isfinite(ref) else _value(r["analytic"])
        sigma = _value(r.get("optimum_std"))
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
    fit = (regime.get(key) or {}).get("lowest_fit_to_truth")
    return fit is not None and float(fit) >= VALID_FIT


def conclusions(rows: list[dict], regime: dict, drift: dict) -> dict:
    """The paper's claims, each as the paper makes it: conclusion "1" (drift), "2-nr" (Newton-
    Raphson unsatisfactory), "2-nm" (Nelder-Mead acceptable), "3" (Scenario II's data better than
    I's) and "mekf" (the MEKF similar on both): each {"verdict": `VERDICTS`'s word, "holds": True,
    False or None (not decided: no evidence, or an interval straddling its threshold), "rule":
    its rule, "evidence": the numbers}."""
    table = cells(rows)
    return {
        "1": _drift(drift, regime),
        "2-nr": _nr(table, regime),
        "2-nm": _nm(table, regime),
        "3": _scenarios(table, regime),
        "mekf": _mekf(table),
    }


def decide(k: int, n: int, threshold: float, at_least: bool = True, strict: bool = False) -> bool | None:
    """Whether the proportion behind k of n is ≥ `threshold` (`at_least`; > with `strict`) or
    < it (not `at_least`), by its Wilson interval at `INTERVAL_LEVEL`: True where the whole interval lies
    on the claim's side, False where it lies on the other, None (not decided) where it straddles
    the threshold or there are no trials."""
    if n == 0:
        return None
    lo, hi = wilson(k, n)
    above = lo > threshold if strict else lo >= threshold
    below = hi <= threshold if strict else hi < threshold
    if above:
        return at_least
    if below:
        return not at_least
    return None


def _all(decisions) -> bool | None:
    """False if any decision is False, else None if any is None (or there is none), else True."""
    decisions = list(decisions)
    if any(d is False for d in decisions):
        return False
    return None if not decisions or any(d is None for d in decisions) else True


def _verdict(holds: bool | None, rule: str, evidence: str) -> dict:
    return {"verdict": VERDICTS[holds], "holds": holds, "rule": rule, "evidence": evidence}


# -- helpers on the cell table ---------------------------------------------------------------------


def _number(d: dict, key: str) -> float:
    """d[key] as a float; NaN where it is missing or null (a NaN written to JSON)."""
    v = d.get(key)
    return math.nan if v is None else float(v)


def _pick(table, arm, keep) -> list[tuple[tuple, list[dict]]]:
    """The cells of `arm` from realistic starts (spread > 0) on the data sets ("{scenario}/{truth}")
    `keep` accepts."""
    return [(k, rs) for k, rs in table.items() if k[3] == arm and k[2] > 0 and keep(f"{k[0]}/{k[1]}")]


def _coefficients(rows: list[dict]) -> list[dict]:
    return [r for r in rows if r["coefficient"]]


def _delta(rows: list[dict]) -> float:
    """A cell's ΔJ from its data set's optimum in units of the likelihood region's bound
    χ²₀.₉₅(p)/2 (1: the region's edge, whatever p; NaN: unknown, the cell does not count)."""
    return _value(rows[0].get("delta_cost")) / cost_bound(max(len(_coefficients(rows)), 1))


def _sigmas(rows: list[dict]) -> float:
    """A cell's largest |θ − θ̂|/σ from the optimum, in the optimum's σ (NaN: unknown)."""
    return _value(rows[0].get("sigmas"))


def _linear(table, arm: str, scenario: str) -> list[tuple[tuple, list[dict]]]:
    """`_pick`: `arm`'s cells on `scenario` flown by the linear truth."""
    return _pick(table, arm, lambda key: key == f"{scenario}/linear")


def _success(picked) -> tuple[int, int]:
    return sum(rs[0]["outcome"] == "success" for _, rs in picked), len(picked)


def _proportion(k: int, n: int) -> str:
    lo, hi = wilson(k, n)
    return (
        f"{k}/{n} ({100 * k / n:.0f} %, {100 * INTERVAL_LEVEL:.0f} % CI {100 * lo:.0f}–{100 * hi:.0f} %)"
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


# -- the rules -------------------------------------------------------------------------------------


def _drift(drift: dict, regime: dict) -> dict:
    rule = (
        f"At every start spread, on every data set with a valid linear reference whose drift was "
        f"measured (≥ 2 seeds), the Mt-form's Fisher condition number is ≥ {CONDITION_RATIO:g}× the "
        f"A-form's and the coefficients both forms estimate scatter over the seeds ≥ "
        f"{SHARED_SCATTER_RATIO:g}× as much with the inertia free (shared_scatter_mt against "
        "shared_scatter_a)."
    )
    needed = ("condition_mt", "condition_a", "shared_scatter_mt", "shared_scatter_a")
    measured = {
        k: d
        for k, d in sorted(drift.items())
        if valid_reference(k.split(DRIFT_AT)[0], regime)
        and int(d.get("seeds") or 0) >= 2
        and not any(math.isnan(_number(d, v)) for v in needed)
    }
    if not measured:
        return _verdict(None, rule, "no data set with a valid reference had its drift measured")
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
    return _verdict(holds, rule, "; ".join(parts))


def _proportion_rule(table, regime, arm: str, claim: str, at_least: bool, threshold: float) -> dict:
    """A claim on `arm`'s success from realistic starts, decided on each data set with a valid
    linear reference and each spread by the Wilson interval against `threshold`; where the
    campaign ran the arm with ten times its iteration limit too (`LONGER`), the same claim
    decided on that arm under "longer"."""
    word = "≥" if at_least else "<"
    rule = (
        f"{claim}: from realistic starts (spread > 0), on each data set with a valid linear reference "
        f"and at each spread, {arm} ends inside the optimum's likelihood region in {word} "
        f"{100 * threshold:.0f} % of its cells, decided by the {100 * INTERVAL_LEVEL:.0f} % Wilson interval "
        f"(not decided where it straddles {100 * threshold:.0f} %), at the testbed's iteration limit "
        f"(the paper states none); {LONGER[arm]} runs it with ten times that limit."
    )

    def valid(key) -> bool:
        return valid_reference(key, regime)

    picked = _pick(table, arm, valid)
    if not picked:
        return _verdict(None, rule, f"no {arm} cells from a spread > 0 on a data set with a valid reference")
    holds, evidence = _share(picked, arm, at_least, threshold)
    out = _verdict(holds, rule, evidence)
    longer = _pick(table, LONGER[arm], valid)
    if longer:
        holds, evidence = _share(longer, LONGER[arm], at_least, threshold)
        out["longer"] = {"arm": LONGER[arm], "verdict": VERDICTS[holds], "holds": holds, "evidence": evidence}
    return out


def _share(picked, arm: str, at_least: bool, threshold: float) -> tuple[bool | None, str]:
    """`_proportion_rule`'s decision on `arm`'s cells `picked`: whether the claim holds (None:
    not decided) and the evidence."""
    parts, decisions = [], []
    for key, s in sorted({(f"{k[0]}/{k[1]}", k[2]) for k, _ in picked}):
        here = [c for c in picked if (f"{c[0][0]}/{c[0][1]}", c[0][2]) == (key, s)]
        k, n = _success(here)
        decisions.append(decide(k, n, threshold, at_least))
        parts.append(f"{key} spread {s:g}: {_proportion(k, n)} — {_WORD[decisions[-1]]}")
    accuracy = (
        f"{arm} over these cells: median ΔJ from the optimum {_median(picked, _delta):.3g} of the "
        f"likelihood region's bound, median distance "
        f"{_median(picked, _sigmas):.3g} of the optimum's σ, accurate against the analytic model in "
        f"{sum(accurate(rs) for _, rs in picked)}/{len(picked)} cells, median relative error "
        f"{_pct(_median_error(picked))}"
    )
    return _all(decisions), "; ".join(parts) + f"; {accuracy}"


def _nr(table, regime) -> dict:
    return _proportion_rule(
        table, regime, NR_ARM, "ML with Newton-Raphson is unsatisfactory", False, UNSATISFACTORY
    )


def _nm(table, regime) -> dict:
    return _proportion_rule(table, regime, NM_ARM, "ML with Nelder-Mead is acceptable", True, ACCEPTABLE)


def _scenarios(table, regime) -> dict:
    rule = (
        f"Scenario II's data identify the coefficients better than Scenario I's with {NM_ARM}: on the "
        f"linear truth (the reference valid on both), at each spread > 0, its estimate from a seed's "
        f"prior is closer to the analytic model (median relative error) on II than on I in more than "
        f"half of the seeds, decided by the {100 * INTERVAL_LEVEL:.0f} % Wilson interval of that share against "
        "½; every method's success, the optimum's σ and the error on both are reported beside it, "
        "and the input factorial on the plant."
    )
    pairs = _paired(table, NM_ARM, relative_error)
    if not pairs:
        return _verdict(
            None, rule, f"no {NM_ARM} cells of the same seed and spread on both I/linear and II/linear"
        )
    parts, decisions = [], []
    for s, (better, n) in sorted(pairs.items()):
        decisions.append(decide(better, n, 0.5, True, strict=True))
        parts.append(f"spread {s:g}: closer on II in {_proportion(better, n)} — {_WORD[decisions[-1]]}")
    # the judged arms: those with an outcome (the drift arms and the nonlinear cell have none)
    arms = sorted(
        {k[3] for k, rs in table.items() if k[:2] in (("I", "linear"), ("II", "linear")) and rs[0]["outcome"]}
    )
    methods = "; ".join(_on_both(table, a) for a in arms)
    return _verdict(
        _all(decisions), rule, "; ".join(parts) + f"; per method: {methods}; {_factorial(table, regime)}"
    )


def _mekf(table) -> dict:
    arm = MEKF_ARMS[0]
    rule = (
        f"The MEKF gives similar, acceptable results on both scenarios: on the linear truth (I/linear "
        f"and II/linear, where the analytic model is the exact reference on both), at each spread > 0, "
        f"{arm} ends inside the optimum's likelihood region in ≥ {100 * ACCEPTABLE:.0f} % of its cells "
        f"on each, decided by the {100 * INTERVAL_LEVEL:.0f} % Wilson interval (not decided where it straddles "
        f"{100 * ACCEPTABLE:.0f} %); its ΔJ, distance in σ and error, and {MEKF_ARMS[1]}'s, reported beside it."
    )
    picked = {s: _linear(table, arm, s) for s in ("I", "II")}
    if not all(picked.values()):
        return _verdict(None, rule, f"no {arm} cells from a spread > 0 on both I/linear and II/linear")
    parts, decisions = [], []
    for s in sorted({k[2] for p in picked.values() for k, _ in p}):
        for scenario, p in picked.items():
            k, n = _success([c for c in p if c[0][2] == s])
            decisions.append(decide(k, n, ACCEPTABLE, True))
            parts.append(f"{scenario}/linear spread {s:g}: {_proportion(k, n)} — {_WORD[decisions[-1]]}")
    beside = "; ".join(
        f"{a} on {s}/linear: median ΔJ {_median(p, _delta):.3g} of the region's bound, median distance "
        f"{_median(p, _sigmas):.3g} σ, "
        f"median relative error {_pct(_median_error(p))}"
        for a in MEKF_ARMS
        for s in ("I", "II")
        if (p := picked[s] if a == arm else _linear(table, a, s))
    )
    return _verdict(_all(decisions), rule, "; ".join(parts) + f"; {beside}")


# -- conclusion 3's comparisons --------------------------------------------------------------------


def _paired(table, arm: str, measure) -> dict[float, tuple[int, int]]:
    """Per spread > 0: (the seeds whose `measure` of `arm`'s cell is smaller on II/linear than on
    I/linear, the seeds with a finite measure on one of them at least)."""
    out: dict[float, list[int]] = {}
    for (scenario, truth, s, a, seed), rows in table.items():
        if (
            (scenario, truth, a) != ("II", "linear", arm)
            or s <= 0
            or (("I", "linear", s, arm, seed) not in table)
        ):
            continue
        two, one = measure(rows), measure(table["I", "linear", s, arm, seed])
        if math.isnan(two) or math.isnan(one) or (math.isinf(two) and math.isinf(one)):
            continue
        k = out.setdefault(s, [0, 0])
        k[0] += two < one
        k[1] += 1
    return {s: (k, n) for s, (k, n) in out.items()}


def _on_both(table, arm: str) -> str:
    """`arm` on I/linear against II/linear: success, the optimum's median relative σ, the median
    relative error, the seeds closer on II."""
    p = {s: _linear(table, arm, s) for s in ("I", "II")}
    pairs = _paired(table, arm, relative_error)
    better = sum(k for k, _ in pairs.values()), sum(n for _, n in pairs.values())
    return (
        f"{arm}: "
        + ", ".join(
            f"{s}/linear success {_proportion(*_success(p[s]))}, σ {_pct(_median(p[s], relative_sigma))}, "
            f"error {_pct(_median_error(p[s]))}"
            for s in ("I", "II")
        )
        + f", closer on II in {better[0]}/{better[1]} seeds"
    )


def _factorial(table, regime) -> str:
    """The input factorial on the plant: each input's optimum median relative σ and `ml-gn`'s success."""

    def on(s):
        return lambda key: key == f"{s}/plant" and valid_reference(key, regime)

    parts = [
        f"{s} median relative σ {_pct(_median(p, relative_sigma))} ({INFORMATION_ARM} success "
        f"{_proportion(*_success(p))})"
        for s in FACTORIAL
        if (p := _pick(table, INFORMATION_ARM, on(s)))
    ]
    return "input factorial on the plant: " + ("; ".join(parts) if parts else "not run")
