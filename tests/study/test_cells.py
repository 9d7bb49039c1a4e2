"""The campaign's nonlinear cell: ml-gn fitting the nonlinear model to a short Scenario I on the
plant, from the captive values perturbed as the linear arms' prior is, judged against the captive
reference (`testbed captive`'s config, read here on its own), its rows in results.csv and the
summary, and its table in the report."""

from html import escape
import math

import numpy as np
import pytest

from testbed.presentation.figures import write_report
from testbed.captive.config import captive_config
from testbed.captive.reference import slope_terms
from testbed.study.arms import NONLINEAR_ARM, NONLINEAR_ARMS
from testbed.errors import Unflyable
from testbed.study import cells
from testbed.study.cells import Cell, Start, load_run, run_cell
from testbed.study.priors import SPREAD, term_class
from testbed.study.results import captive_table, read_results, results_csv, results_rows, summary_table

DURATION = 15.0  # s: a short Scenario I (its quick runs are 30 s)
SPREAD_S = 0.4


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    out = tmp_path_factory.mktemp("campaign")
    data = load_run(str(out), "I", "plant", 1, DURATION)
    c = Cell("I", NONLINEAR_ARM, 1, SPREAD_S, "plant", DURATION)
    doc = run_cell(c, data, Start(None, None, {}, ""))  # the linear start is not the nonlinear cell's
    return doc, data


def test_a_term_takes_its_linear_counterparts_class():
    assert [term_class(n) for n in ("X_uu", "Y_uv", "Y_up", "Z_uude", "K_uuda", "N_r|r|", "M_uq")] == [
        "damping",
        "damping",
        "cross-coupling",
        "control",
        "control",
        "damping",
        "damping",
    ]


def test_the_nonlinear_cell_is_judged_against_the_captive_values(cell):
    doc, data = cell
    assert doc["status"] != "failed", doc.get("traceback")
    captive, _, fit = captive_config(speed=data[1].vehicle.speed, model="polynomial")
    free = slope_terms(fit.terms)
    assert tuple(doc["free"]) == free and len(free) == 19
    assert doc["captive"] == {n: captive.terms[n] for n in free}
    # started from a guess: every term off the captive value by a log-normal factor of its class
    for n in free:
        ratio = doc["start"][n] / captive.terms[n]
        assert ratio != 1.0 and abs(math.log(ratio)) <= 5 * SPREAD[term_class(n)] * SPREAD_S, n
    for n in free:
        err = doc["values"][n] - captive.terms[n]
        assert doc["error_sigmas"][n] == pytest.approx(err / doc["std"][n], rel=1e-12)
        assert doc["error_percent"][n] == pytest.approx(100 * err / captive.terms[n], rel=1e-12)
        assert doc["std"][n] > 0
    # the open-loop fit of every measured channel of the record
    ((name, fits),) = doc["fit"].items()
    assert name == data[0][0].name and set(fits) == set(data[0][0].measured)
    assert all(v <= 100 for v in fits.values())
    assert doc["converged"] and doc["iterations"] >= 1 and doc["wall_time_s"] > 0


def test_its_rows_summary_and_report_table_carry_the_captive_judgement(cell, tmp_path):
    doc, data = cell
    (tmp_path / "results.csv").write_text(results_csv(results_rows([doc])))
    rows = read_results(tmp_path / "results.csv")
    assert {r["arm"] for r in rows} == {NONLINEAR_ARM} and {r["method"] for r in rows} == {"ml-gn"}
    captive = captive_config(speed=data[1].vehicle.speed, model="polynomial")[0].terms
    sigmas = {r["coefficient"]: (r["estimate"] - captive[r["coefficient"]]) / r["std"] for r in rows}
    assert {r["coefficient"]: r["analytic"] for r in rows} == pytest.approx(
        {n: captive[n] for n in sigmas}, rel=1e-9
    )
    assert rows[0]["sigmas"] == pytest.approx(max(map(abs, sigmas.values())), rel=1e-6)
    assert {r["outcome"] for r in rows} == {""}  # not judged against the linear optimum
    # within max(3 σ, 10 %) of the captive value, counted here
    within = {
        n: abs(s) <= 3 or abs(s) * r["std"] <= 0.1 * abs(captive[n])
        for (n, s), r in zip(sigmas.items(), rows)
    }
    (summary,) = summary_table(rows)
    assert summary["accurate"] == int(all(within.values())) and summary["judged"] == 0
    table = captive_table(rows, [doc])
    assert {r["coefficient"]: r["within"] for r in table["coefficients"]} == {
        n: int(w) for n, w in within.items()
    }
    assert {r["coefficient"]: r["median_error_sigmas"] for r in table["coefficients"]} == pytest.approx(
        sigmas, rel=1e-6
    )
    write_report(tmp_path, [doc], rows, {}, {}, [summary], {}, {}, (), table)
    html = (tmp_path / "report.html").read_text()
    assert "<h2>Scenario I against the captive reference</h2>" in html
    for n, s in sigmas.items():
        assert f"<td>{n}</td><td>{captive[n]:.4g}</td>" in html
        assert f"<td>{s:+.2f}</td>" in html
    assert f"u {doc['fit'][data[0][0].name]['u']:.2f} %" in html
    assert np.isfinite(list(sigmas.values())).all()


# mekf-nonlinear takes the same path with the nonlinear filter's kernels, which this module's
# worker would compile beside the others of the default run
@pytest.mark.parametrize(
    "arm",
    ["ml-lm-nonlinear", "equation-error-nonlinear", pytest.param("mekf-nonlinear", marks=pytest.mark.slow)],
)
def test_each_nonlinear_arm_starts_where_ml_gn_does_and_is_judged_in_its_sigma(cell, arm, tmp_path):
    """Another method on the nonlinear model: the same start as the `NONLINEAR_ARM` cell of its
    seed and spread, its own method's estimate, and its rows judged in the data's σ (that cell's,
    the nonlinear model's ML fit's), never its own."""
    reference, data = cell
    doc = run_cell(Cell("I", arm, 1, SPREAD_S, "plant", DURATION), data, Start(None, None, {}, ""))
    assert doc["status"] != "failed", doc.get("traceback")
    assert doc["start"] == reference["start"] and doc["captive"] == reference["captive"]
    assert doc["values"] != reference["values"]
    rows = results_rows([reference, doc])
    mine = [r for r in rows if r["arm"] == arm]
    assert {r["method"] for r in mine} == {NONLINEAR_ARMS[arm].method}
    assert {r["coefficient"]: r["optimum_std"] for r in mine} == reference["std"]
    errors = [abs(doc["values"][n] - doc["captive"][n]) / reference["std"][n] for n in doc["free"]]
    assert mine[0]["sigmas"] == pytest.approx(max(errors), rel=1e-9)
    table = captive_table(rows, [reference, doc])
    assert [c["arm"] for c in table["cells"]] == [NONLINEAR_ARM, arm]
    assert {r["arm"] for r in table["coefficients"]} == {NONLINEAR_ARM, arm}


def test_an_estimate_whose_open_loop_flight_diverges_is_a_result_without_a_fit(cell, monkeypatch, tmp_path):
    """A nonlinear arm's estimate whose open-loop flight leaves the finite numbers (a filter's
    last coefficients: `mekf-nonlinear` from a 0.5-spread start, Scenario I seed 4) is recorded,
    its values and σ judged as any other's, with no fit % and the reason in the report; the cell
    does not fail."""
    reference, data = cell
    why = "scenario-I.csv: the config's model flown from the record's first sample leaves the finite numbers at t = 2.3 s"

    def diverges(*args, **kwargs):
        raise Unflyable(why + "; expected a model whose flight stays bounded", why)

    monkeypatch.setattr(cells, "validate", diverges)
    arm = "equation-error-nonlinear"
    doc = run_cell(Cell("I", arm, 1, SPREAD_S, "plant", DURATION), data, Start(None, None, {}, ""))
    assert doc["status"] != "failed", doc.get("traceback")
    assert doc["fit"] == {} and why in doc["fit_note"]
    assert set(doc["values"]) == set(reference["values"]) and all(map(math.isfinite, doc["values"].values()))
    rows = results_rows([reference, doc])
    table = captive_table(rows, [reference, doc])
    assert [c["fit_note"] for c in table["cells"]] == ["", doc["fit_note"]]
    (summary, *_) = summary_table(rows)
    write_report(tmp_path, [reference, doc], rows, {}, {}, [summary], {}, {}, (), table)
    assert escape(why) in (tmp_path / "report.html").read_text(encoding="utf-8")
