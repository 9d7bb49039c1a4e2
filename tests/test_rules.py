"""The rules that decide the paper's conclusions: each made to hold and to fail on hand-made rows."""

from __future__ import annotations

import json
import math

import pytest
from scipy.stats import binomtest

from testbed.study import rules
from testbed.study.rules import (
    accurate,
    coefficient_ok,
    conclusions,
    relative_distance,
    relative_error,
    relative_sigma,
    valid_reference,
    wilson,
)

VALID = {"II/plant": {"lowest_truth_fit": 99.4}, "I/plant": {"lowest_truth_fit": 42.0}}
FACTORIAL_REGIME = {f"{s}/plant": {"lowest_truth_fit": 99.3} for s in rules.FACTORIAL}


def cell(
    scenario,
    truth,
    spread,
    arm,
    seed,
    outcome="success",
    error=0.02,
    coefficients=4,
    std=math.inf,
    optimum=0.0,
):
    """One cell's rows: `coefficients` coefficients analysed at 1, 2, …, each estimated `error` off
    (relative), with σ `std` (relative), the data set's optimum `optimum` off the analytic value
    (relative; None: unknown, written empty); an empty coefficient for a failed cell."""
    base = {
        "scenario": scenario,
        "truth": truth,
        "spread": spread,
        "arm": arm,
        "seed": seed,
        "outcome": outcome,
        "delta_cost": 0.0 if outcome == "success" else 100.0,  # inside the likelihood region or far out
    }
    if outcome == "failed":
        return [
            {
                **base,
                "coefficient": "",
                "analytic": math.nan,
                "optimum": "",
                "estimate": math.nan,
                "std": math.nan,
            }
        ]
    return [
        {
            **base,
            "coefficient": f"c{i}",
            "analytic": float(i),
            "optimum": "" if optimum is None else i * (1 + optimum),
            "estimate": i * (1 + error),
            "std": i * std,
        }
        for i in range(1, coefficients + 1)
    ]


def arm_cells(scenario, truth, arm, successes, n=10, spreads=(0.2, 0.4), **kw):
    """n cells per spread of which the first `successes` reached the optimum, the rest stalled."""
    return [
        r
        for s in spreads
        for seed in range(1, n + 1)
        for r in cell(scenario, truth, s, arm, seed, "success" if seed <= successes else "stalled", **kw)
    ]


# -- the building blocks ---------------------------------------------------------------------------


@pytest.mark.parametrize("k, n", [(0, 10), (1, 10), (8, 10), (10, 10), (17, 20), (3, 7), (50, 51)])
@pytest.mark.parametrize("level", [0.9, 0.95, 0.99])
def test_wilson_matches_scipy(k, n, level):
    ci = binomtest(k, n).proportion_ci(confidence_level=level, method="wilson")
    assert wilson(k, n, level) == pytest.approx((ci.low, ci.high), abs=1e-12)


def test_wilson_of_no_trials_is_the_whole_interval():
    assert wilson(0, 0) == (0.0, 1.0)


def test_coefficient_ok_within_ten_percent_or_three_finite_sigmas():
    r = {"analytic": -2.0, "std": math.inf}
    assert coefficient_ok({**r, "estimate": -2.19})  # 9.5 %
    assert not coefficient_ok({**r, "estimate": -2.21})  # 10.5 %, an infinite σ bounds nothing
    assert coefficient_ok({**r, "estimate": -2.5, "std": 0.17})  # 2.9 σ
    assert not coefficient_ok({**r, "estimate": -2.5, "std": 0.16})  # 3.1 σ
    assert not coefficient_ok({**r, "estimate": math.nan, "std": 1.0})
    assert not coefficient_ok({**r, "estimate": -2.5, "std": math.nan})
    assert coefficient_ok({"analytic": 0.0, "estimate": 0.02, "std": 0.01})  # at 0: only σ can pass it


def test_cell_accuracy_and_relative_error():
    rows = cell("II", "linear", 0.2, "ml-gn", 1, error=0.05)
    assert accurate(rows) and relative_error(rows) == pytest.approx(0.05)
    rows[0]["estimate"] = 1.5  # one coefficient 50 % off: not every one acceptable
    assert not accurate(rows) and relative_error(rows) == pytest.approx(0.05)
    rows[1]["estimate"] = math.inf  # a diverged estimate is infinitely wrong, not skipped
    assert relative_error(rows) == math.inf
    failed = cell("II", "linear", 0.2, "ml-gn", 1, "failed")
    assert not accurate(failed) and relative_error(failed) == math.inf


def test_relative_distance_is_from_the_optimum():
    rows = cell("II", "linear", 0.2, "ml-gn", 1, error=0.1, optimum=0.1)
    assert relative_error(rows) == pytest.approx(0.1) and relative_distance(rows) == pytest.approx(0.0)
    rows = cell("II", "linear", 0.2, "ml-gn", 1, error=0.21, optimum=0.1)
    assert relative_distance(rows) == pytest.approx(0.1)  # 1.21 against 1.1
    rows[0]["optimum"] = 0.0  # an optimum at 0 has no relative distance: left out of the median
    rows[0]["estimate"] = 5.0
    assert relative_distance(rows) == pytest.approx(0.1)
    rows[1]["estimate"] = math.nan  # a diverged estimate is infinitely far
    assert relative_distance(rows) == math.inf
    assert math.isnan(relative_distance(cell("II", "linear", 0.2, "ml-gn", 1, optimum=None)))  # unknown
    assert relative_distance(cell("II", "linear", 0.2, "ml-gn", 1, "failed")) == math.inf


def test_relative_sigma_over_the_optimum_or_the_analytic_value():
    rows = cell("II", "linear", 0.2, "ml-gn", 1, std=0.03, optimum=0.5)
    assert relative_sigma(rows) == pytest.approx(0.02)  # 0.03 i / 1.5 i
    assert relative_sigma(cell("II", "linear", 0.2, "ml-gn", 1, std=0.03, optimum=None)) == pytest.approx(
        0.03
    )
    assert math.isnan(relative_sigma(cell("II", "linear", 0.2, "ml-gn", 1)))  # σ infinite: no information
    assert math.isnan(relative_sigma(cell("II", "linear", 0.2, "ml-gn", 1, "failed")))


def test_the_arms_the_rules_name_exist():
    from testbed.study.arms import ARMS

    assert {rules.NM_ARM, rules.NR_ARM, *rules.MEKF_ARMS} <= set(ARMS)


def test_valid_reference_is_the_linear_truth_or_a_fit_of_99_percent():
    assert valid_reference("I/linear", {})
    assert valid_reference("II/plant", VALID)
    assert not valid_reference("I/plant", VALID)
    assert not valid_reference("inputs-square/plant", VALID)  # no regime measured: not known valid


def test_no_rows_leave_every_conclusion_undecided():
    out = conclusions([], {}, {})
    assert set(out) == {"1", "2", "3", "mekf"}
    for v in out.values():
        assert v["holds"] is None and v["rule"] and v["evidence"]
    json.dumps(out)


# -- conclusion 1: drift is more probable with Mt free ---------------------------------------------


def drift_of(condition_mt=2e14, condition_a=4e7, shared_mt=0.3, shared_a=0.05, seeds=8, **extra):
    return {
        "condition_mt": condition_mt,
        "condition_a": condition_a,
        "correlation_mt": ["M_de", "M_wdot", 0.9999998],
        "correlation_a": ["K_v", "K_r", 0.955],
        "null_scatter_mt": 3.4,
        "null_scatter_a": 1.5,
        "relative_drift_mt": 660.0,
        "relative_drift_a": 0.04,
        "shared_scatter_mt": shared_mt,
        "shared_scatter_a": shared_a,
        "seeds": seeds,
        **extra,
    }


def test_conclusion_1_holds_when_mt_form_is_ill_conditioned_and_its_shared_coefficients_scatter():
    drift = {"II/plant": drift_of(converged_mt=1, converged_a=8), "II/linear": drift_of(shared_mt=0.1)}
    out = conclusions([], VALID, drift)["1"]
    assert out["holds"] is True  # II/linear: 0.1 against 0.05, exactly 2×
    assert "II/plant (8 seeds)" in out["evidence"] and "ratio 6" in out["evidence"]
    assert "converged fits 1 (Mt-form) and 8 (A-form)" in out["evidence"]


def test_conclusion_1_fails_when_the_shared_coefficients_scatter_alike():
    drift = {"II/plant": drift_of(), "II/linear": drift_of(shared_mt=0.09)}  # 1.8×
    out = conclusions([], VALID, drift)["1"]
    assert out["holds"] is False and "fails" in out["evidence"]


def test_conclusion_1_fails_when_the_conditions_are_alike():
    drift = {"II/linear": drift_of(condition_mt=3e8, condition_a=4e7)}  # ratio 7.5
    assert conclusions([], VALID, drift)["1"]["holds"] is False


def test_conclusion_1_ignores_invalid_references_single_seeds_and_missing_scatter():
    # Scenario I on the plant (fit 42 %): its deviations are model error, not drift
    drift = {"I/plant": drift_of(shared_mt=0.05), "II/linear": drift_of(seeds=1)}
    drift["II/plant"] = {k: v for k, v in drift_of().items() if k != "shared_scatter_a"}
    assert conclusions([], VALID, drift)["1"]["holds"] is None
    drift["II/plant"] = drift_of()
    assert conclusions([], VALID, drift)["1"]["holds"] is True


# -- conclusion 2: Nelder-Mead acceptable, Newton-Raphson unsatisfactory ---------------------------


def methods_rows(nm=9, nr=2):
    return [
        *arm_cells("II", "linear", "ml-nm-paper", nm),
        *arm_cells("II", "linear", "ml-nr", nr),
        # Scenario I on the plant, whose reference is not valid: never counted
        *arm_cells("I", "plant", "ml-nm-paper", 0),
        *arm_cells("I", "plant", "ml-nr", 10),
        # the analytic start (spread 0) is not a realistic one: never counted
        *arm_cells("II", "linear", "ml-nm-paper", 0, spreads=(0.0,)),
    ]


def test_conclusion_2_holds_when_nm_succeeds_and_nr_does_not():
    out = conclusions(methods_rows(), VALID, {})["2"]
    assert out["holds"] is True
    assert "spread 0.2: ml-nm-paper 9/10 (90 %" in out["evidence"]
    assert "ml-nr 2/10 (20 %" in out["evidence"] and "I/plant" not in out["evidence"]
    assert "median relative error 2.0 %" in out["evidence"]
    assert "ml-nm-paper within the likelihood region of the optimum in 18/20 cells" in out["evidence"]


def test_conclusion_2_fails_when_nm_succeeds_in_fewer_than_80_percent():
    assert conclusions(methods_rows(nm=7), VALID, {})["2"]["holds"] is False


def test_conclusion_2_fails_when_nr_succeeds_in_half():
    assert conclusions(methods_rows(nr=5), VALID, {})["2"]["holds"] is False


def test_conclusion_2_fails_at_one_spread():
    rows = methods_rows() + arm_cells("II", "linear", "ml-nm-paper", 5, spreads=(0.7,))
    rows += arm_cells("II", "linear", "ml-nr", 0, spreads=(0.7,))
    assert conclusions(rows, VALID, {})["2"]["holds"] is False


def test_conclusion_2_undecided_without_a_valid_data_set():
    rows = arm_cells("I", "plant", "ml-nm-paper", 0) + arm_cells("I", "plant", "ml-nr", 10)
    assert conclusions(rows, VALID, {})["2"]["holds"] is None


# -- conclusion 3: Nelder-Mead satisfactory with PRBS inputs ---------------------------------------


def factorial_rows(prbs_success=20, prbs_std=0.03, square_std=0.03, other_std=0.05):
    """ml-nm-paper on the PRBS (Scenario II), `prbs_success` of 20 cells at spread 0.4 reaching
    the optimum; ml-gn on every input reaching it in its 20 cells, σ relative; the optimum 1 %
    off the analytic model."""
    rows = arm_cells(
        rules.FACTORIAL[0], "plant", "ml-nm-paper", prbs_success, n=20, spreads=(0.4,), optimum=0.01
    )
    for s in rules.FACTORIAL:
        std = prbs_std if s == rules.FACTORIAL[0] else square_std if s == "inputs-square" else other_std
        rows += arm_cells(s, "plant", "ml-gn", 20, n=20, spreads=(0.4,), error=0.01, std=std, optimum=0.01)
    return rows


def test_conclusion_3_holds_when_prbs_succeeds_and_informs_as_much():
    out = conclusions(factorial_rows(), FACTORIAL_REGIME, {})["3"]
    assert out["holds"] is True
    json.dumps(out)
    assert "spread 0.4 20/20" in out["evidence"]
    assert "inputs-3211 median relative σ 5.0 %" in out["evidence"]  # σ 0.05 i over the optimum 1.01 i
    # within 1.25×: σ 0.037 against the square wave's 0.03 (1.23×)
    assert conclusions(factorial_rows(prbs_std=0.037), FACTORIAL_REGIME, {})["3"]["holds"] is True


def test_conclusion_3_takes_information_only_from_fits_that_reached_the_optimum():
    # the square wave's ml-gn cells all stopped elsewhere, with a σ that would beat PRBS's
    rows = [
        r for r in factorial_rows(prbs_std=0.039) if r["scenario"] != "inputs-square" or r["arm"] != "ml-gn"
    ]
    rows += arm_cells("inputs-square", "plant", "ml-gn", 0, n=20, spreads=(0.4,), std=0.01, optimum=0.01)
    out = conclusions(rows, FACTORIAL_REGIME, {})["3"]
    assert out["holds"] is True and "the best other input: inputs-square" not in out["evidence"]


def test_conclusion_3_fails_when_prbs_succeeds_in_fewer_than_80_percent():
    assert conclusions(factorial_rows(prbs_success=15), FACTORIAL_REGIME, {})["3"]["holds"] is False


def test_conclusion_3_fails_when_another_input_informs_more():
    # PRBS's σ 0.039, the square wave's 0.03: 1.3×
    out = conclusions(factorial_rows(prbs_std=0.039), FACTORIAL_REGIME, {})["3"]
    assert out["holds"] is False and "the best other input: inputs-square" in out["evidence"]


def test_conclusion_3_counts_only_valid_data_sets():
    regime = {**FACTORIAL_REGIME, "inputs-square/plant": {"lowest_truth_fit": 97.9}}
    # the square wave (the only input more informative than PRBS) is outside the linear regime
    out = conclusions(factorial_rows(prbs_std=0.039), regime, {})["3"]
    assert out["holds"] is True and "inputs-square" not in out["evidence"]
    rows = [r for r in factorial_rows() if r["scenario"] == rules.FACTORIAL[0]]
    assert conclusions(rows, FACTORIAL_REGIME, {})["3"]["holds"] is None  # nothing to compare with


def test_conclusion_3_without_a_finite_sigma_decides_only_a_failure():
    rows = factorial_rows(prbs_std=math.inf)
    assert conclusions(rows, FACTORIAL_REGIME, {})["3"]["holds"] is None
    rows = factorial_rows(prbs_success=15, prbs_std=math.inf)
    assert conclusions(rows, FACTORIAL_REGIME, {})["3"]["holds"] is False


# -- the MEKF: similar results on both scenarios ---------------------------------------------------


def mekf_rows(error_i, error_ii, arm="mekf-paper", optimum=0.0):
    return [
        *arm_cells("I", "linear", arm, 10, n=5, error=error_i, optimum=optimum),
        *arm_cells("II", "linear", arm, 10, n=5, error=error_ii, optimum=optimum),
        # not the exact reference: never counted
        *arm_cells("I", "plant", arm, 10, n=5, error=0.24, optimum=optimum),
    ]


def test_mekf_holds_when_similar_and_acceptable_on_both():
    rows = mekf_rows(0.05, 0.03) + mekf_rows(0.3, 0.02, arm="mekf")
    out = conclusions(rows, VALID, {})["mekf"]
    assert out["holds"] is True
    assert (
        "mekf-paper: median relative distance from the optimum 5.0 % on I/linear, 3.0 % on II/linear"
        in (out["evidence"])
    )
    assert "mekf: median relative distance from the optimum 30.0 % on I/linear" in out["evidence"]


def test_mekf_is_measured_from_the_optimum_not_the_analytic_model():
    # the optimum 10 % off the analytic model: 15.5 % and 13.3 % off it is 5 % and 3 % from the optimum
    out = conclusions(mekf_rows(0.155, 0.133, optimum=0.1), VALID, {})["mekf"]
    assert out["holds"] is True
    assert "optimum 5.0 % on I/linear, 3.0 % on II/linear" in out["evidence"]  # 1.155/1.1, 1.133/1.1
    assert "error against the analytic model 15.5 % on I/linear, 13.3 % on II/linear" in out["evidence"]
    # on target against the analytic model on I, 9.1 % from an optimum 10 % off it: 5× II's 1.8 %
    assert conclusions(mekf_rows(0.0, 0.08, optimum=0.1), VALID, {})["mekf"]["holds"] is False


def test_mekf_fails_when_one_scenario_is_twice_as_far():
    assert conclusions(mekf_rows(0.07, 0.03), VALID, {})["mekf"]["holds"] is False


def test_mekf_tiny_distances_are_similar_within_one_percent_whatever_their_ratio():
    assert conclusions(mekf_rows(0.002, 0.010), VALID, {})["mekf"]["holds"] is True  # 5×, 0.8 % apart
    assert conclusions(mekf_rows(0.005, 0.020), VALID, {})["mekf"]["holds"] is False  # 4×, 1.5 % apart


def test_mekf_fails_when_both_are_similar_but_far():
    assert conclusions(mekf_rows(0.3, 0.25), VALID, {})["mekf"]["holds"] is False


def test_mekf_fails_when_it_diverges():
    rows = mekf_rows(0.05, 0.03)
    for r in rows:
        if r["scenario"] == "I":
            r["estimate"] = math.nan
    out = conclusions(rows, VALID, {})["mekf"]
    assert out["holds"] is False and "∞" in out["evidence"]


def test_mekf_undecided_without_both_linear_scenarios_or_their_optimum():
    rows = [r for r in mekf_rows(0.05, 0.03) if r["scenario"] == "II"]
    assert conclusions(rows, VALID, {})["mekf"]["holds"] is None
    assert conclusions(mekf_rows(0.05, 0.03, optimum=None), VALID, {})["mekf"]["holds"] is None
