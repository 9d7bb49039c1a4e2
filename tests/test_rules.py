"""The rules that decide the paper's conclusions: each made to hold and to fail on hand-made rows."""

from __future__ import annotations

import json
import math

import pytest
from scipy.stats import binomtest

from testbed.study import rules
from testbed.study.rules import accurate, coefficient_ok, conclusions, relative_error, valid_reference, wilson

VALID = {"II/plant": {"lowest_truth_fit": 99.4}, "I/plant": {"lowest_truth_fit": 42.0}}
FACTORIAL_REGIME = {f"{s}/plant": {"lowest_truth_fit": 99.3} for s in rules.FACTORIAL}


def cell(scenario, truth, spread, arm, seed, outcome="success", error=0.02, coefficients=4, std=math.inf):
    """One cell's rows: `coefficients` coefficients at 1, 2, …, each estimated `error` off
    (relative), with σ `std` (relative); an empty coefficient for a failed cell."""
    base = {
        "scenario": scenario,
        "truth": truth,
        "spread": spread,
        "arm": arm,
        "seed": seed,
        "outcome": outcome,
    }
    if outcome == "failed":
        return [{**base, "coefficient": "", "analytic": math.nan, "estimate": math.nan, "std": math.nan}]
    return [
        {**base, "coefficient": f"c{i}", "analytic": float(i), "estimate": i * (1 + error), "std": i * std}
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


def test_valid_reference_is_the_linear_truth_or_a_fit_of_99_percent():
    assert valid_reference("I/linear", {})
    assert valid_reference("II/plant", VALID)
    assert not valid_reference("I/plant", VALID)
    assert not valid_reference("inputs-prbs/plant", VALID)  # no regime measured: not known valid


def test_no_rows_leave_every_conclusion_undecided():
    out = conclusions([], {}, {})
    assert set(out) == {"1", "2", "3", "mekf"}
    for v in out.values():
        assert v["holds"] is None and v["rule"] and v["evidence"]
    json.dumps(out)


# -- conclusion 1: drift is more probable with Mt free ---------------------------------------------


def drift_of(condition_mt=2e14, condition_a=4e7, relative_drift_mt=660.0, seeds=8):
    return {
        "condition_mt": condition_mt,
        "condition_a": condition_a,
        "correlation_mt": ["M_de", "M_wdot", 0.9999998],
        "correlation_a": ["K_v", "K_r", 0.955],
        "null_scatter_mt": 3.4,
        "null_scatter_a": 1.5,
        "relative_drift_mt": relative_drift_mt,
        "seeds": seeds,
    }


def test_conclusion_1_holds_when_mt_form_is_ill_conditioned_and_drifts():
    drift = {"II/plant": drift_of(), "II/linear": drift_of(relative_drift_mt=0.3)}
    out = conclusions([], VALID, drift)["1"]
    assert out["holds"] is True
    assert "II/plant (8 seeds)" in out["evidence"] and "660" in out["evidence"]


def test_conclusion_1_fails_when_the_mt_form_does_not_drift():
    drift = {"II/plant": drift_of(), "II/linear": drift_of(relative_drift_mt=0.05)}
    out = conclusions([], VALID, drift)["1"]
    assert out["holds"] is False and "fails" in out["evidence"]


def test_conclusion_1_fails_when_the_conditions_are_alike():
    drift = {"II/linear": drift_of(condition_mt=3e8, condition_a=4e7)}  # ratio 7.5
    assert conclusions([], VALID, drift)["1"]["holds"] is False


def test_conclusion_1_ignores_invalid_references_and_single_seeds():
    # Scenario I on the plant (fit 42 %): its deviations are model error, not drift
    drift = {"I/plant": drift_of(relative_drift_mt=0.01), "II/linear": drift_of(seeds=1)}
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


def factorial_rows(prbs_success=20, prbs_error=0.02, square_error=0.02):
    rows = []
    for s in rules.FACTORIAL:
        success = prbs_success if s == "inputs-prbs" else 20
        error = prbs_error if s == "inputs-prbs" else square_error if s == "inputs-square" else 0.2
        rows += arm_cells(s, "plant", "ml-nm-paper", success, n=20, spreads=(0.4,), error=error)
    return rows


def test_conclusion_3_holds_when_prbs_succeeds_and_is_as_accurate():
    out = conclusions(factorial_rows(), FACTORIAL_REGIME, {})["3"]
    assert out["holds"] is True
    json.dumps(out)
    assert "spread 0.4 20/20" in out["evidence"] and "inputs-3211 0/20" in out["evidence"]


def test_conclusion_3_fails_when_prbs_succeeds_in_fewer_than_80_percent():
    assert conclusions(factorial_rows(prbs_success=15), FACTORIAL_REGIME, {})["3"]["holds"] is False


def test_conclusion_3_fails_when_another_input_is_more_accurate():
    # PRBS 11 % off on every coefficient (σ infinite: none acceptable), the square wave 2 %
    out = conclusions(factorial_rows(prbs_error=0.11), FACTORIAL_REGIME, {})["3"]
    assert out["holds"] is False and "the best other input: inputs-square" in out["evidence"]


def test_conclusion_3_counts_only_valid_data_sets():
    regime = {**FACTORIAL_REGIME, "inputs-square/plant": {"lowest_truth_fit": 97.9}}
    # the square wave (the only input more accurate than PRBS) is outside the linear regime
    out = conclusions(factorial_rows(prbs_error=0.11), regime, {})["3"]
    assert out["holds"] is True and "inputs-square" not in out["evidence"]
    rows = [r for r in factorial_rows() if r["scenario"] == "inputs-prbs"]
    assert conclusions(rows, FACTORIAL_REGIME, {})["3"]["holds"] is None  # nothing to compare with


# -- the MEKF: similar results on both scenarios ---------------------------------------------------


def mekf_rows(error_i, error_ii, arm="mekf-paper"):
    return [
        *arm_cells("I", "linear", arm, 10, n=5, error=error_i),
        *arm_cells("II", "linear", arm, 10, n=5, error=error_ii),
        *arm_cells("I", "plant", arm, 10, n=5, error=0.24),  # not the exact reference: never counted
    ]


def test_mekf_holds_when_similar_and_acceptable_on_both():
    rows = mekf_rows(0.05, 0.03) + mekf_rows(0.3, 0.02, arm="mekf")
    out = conclusions(rows, VALID, {})["mekf"]
    assert out["holds"] is True
    assert "mekf-paper: median relative error 5.0 % on I/linear, 3.0 % on II/linear" in out["evidence"]
    assert "mekf: median relative error 30.0 % on I/linear" in out["evidence"]  # reported, not decisive


def test_mekf_fails_when_one_scenario_is_twice_as_wrong():
    assert conclusions(mekf_rows(0.07, 0.03), VALID, {})["mekf"]["holds"] is False


def test_mekf_fails_when_both_are_similar_but_inaccurate():
    assert conclusions(mekf_rows(0.3, 0.25), VALID, {})["mekf"]["holds"] is False


def test_mekf_fails_when_it_diverges():
    rows = mekf_rows(0.05, 0.03)
    for r in rows:
        if r["scenario"] == "I":
            r["estimate"] = math.nan
    out = conclusions(rows, VALID, {})["mekf"]
    assert out["holds"] is False and "∞" in out["evidence"]


def test_mekf_undecided_without_both_linear_scenarios():
    rows = [r for r in mekf_rows(0.05, 0.03) if r["scenario"] == "II"]
    assert conclusions(rows, VALID, {})["mekf"]["holds"] is None
