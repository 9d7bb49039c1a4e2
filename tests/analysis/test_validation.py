"""Validation metrics: fit % and residual whiteness against closed forms, and `testbed validate`."""

import json
from dataclasses import replace

import numpy as np
import pytest

from testbed.cli import main
from testbed.analysis.manoeuvres import compared, experiment_metrics, metric_values, run_metrics
from testbed.analysis.track import record_track
from testbed.analysis.validation import CONFIDENCE, whiteness
from testbed.identification.bounds import chi2_sf
from testbed.fit_percent import fit_percent
from testbed.data import load_data
from testbed.identification.prediction import predict
from testbed.simulation import runs
from testbed.simulation.scenario import read_scenario


def test_fit_percent_is_one_minus_the_relative_error_norm():
    y = np.sin(np.linspace(0, 10, 500))
    assert fit_percent(y, y) == 100.0
    assert fit_percent(y, np.full_like(y, y.mean())) == pytest.approx(0.0)
    assert fit_percent(y, y + 0.1 * (y - y.mean())) == pytest.approx(90.0)
    assert np.isnan(fit_percent(np.ones(5), np.zeros(5)))


def test_white_noise_is_white_and_a_coloured_residual_is_not():
    rng = np.random.default_rng(0)
    n = 3000
    e = rng.standard_normal(n)
    w = whiteness(e)
    assert w.white and w.bound == pytest.approx(CONFIDENCE / np.sqrt(n)) and w.lags_outside <= 2
    ar = np.empty(n)  # AR(1), r_k = 0.5^k
    ar[0] = e[0]
    for k in range(1, n):
        ar[k] = 0.5 * ar[k - 1] + e[k]
    c = whiteness(ar)
    assert not c.white and c.max_autocorrelation == pytest.approx(0.5, abs=0.05) and c.ljung_box_p < 1e-10


def test_chi2_survival_matches_scipy():
    from scipy.stats import chi2

    for k in (1, 2, 3, 10, 25, 26, 101):
        for q in (0.0, 1e-6, 0.5, k, 3.0 * k + 7, 200.0, 1200.0):
            assert chi2_sf(q, k) == pytest.approx(chi2.sf(q, k), rel=1e-12, abs=1e-300)


def test_ljung_box_rejects_white_noise_at_its_level():
    """Over many white sequences the test calls about 1 % coloured (p < 0.01)."""
    rng = np.random.default_rng(1)
    rejected = sum(not whiteness(rng.standard_normal(1000)).white for _ in range(400))
    assert rejected <= 12  # 4 expected; 12 is far in the binomial tail


def test_validate_on_a_held_out_run(tmp_path, capsys):
    """Fit on a short Scenario II run, predict a held-out turn: the JSON gives every channel's
    fit % (identified and analytic) and whiteness; the turn's heading is predicted."""
    for scenario, out in (("II", "ii"), ("turn", "turn")):
        assert (
            main(
                [
                    "simulate",
                    "--scenario",
                    scenario,
                    "--seed",
                    "1",
                    "--duration",
                    "20",
                    "--quiet",
                    "--out",
                    str(tmp_path / out),
                ]
            )
            == 0
        )
    est = tmp_path / "est.json"
    assert main(["identify", str(tmp_path / "ii"), "--out", str(est)]) in (0, 1)
    doc = json.loads(est.read_text())
    assert set(doc["validation"]) == {"horizontal", "vertical", "roll"}
    assert doc["validation"]["roll"]["p"]["fit_percent"] > 90.0
    capsys.readouterr()
    out = tmp_path / "val.json"
    assert main(["validate", str(tmp_path / "turn"), "--estimates", str(est), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    val = json.loads(out.read_text())["validation"]["turn"]
    assert set(val) == {"u", "v", "w", "p", "q", "r", "phi", "theta", "psi", "z"}
    assert val["psi"]["fit_percent"] > 95.0 and val["psi"]["fit_percent_analytic"] > 95.0
    assert {"max_autocorrelation", "bound", "lags_outside", "ljung_box_p", "white"} <= set(
        val["r"]["whiteness"]
    )
    # without estimates the run's own model.toml (the analytic model) is validated as it stands:
    # its fit % is the analytic column's
    own = tmp_path / "val-config.json"
    assert main(["validate", str(tmp_path / "turn"), "--out", str(own)]) == 0
    doc = json.loads(own.read_text())
    assert "estimates" not in doc and doc["config"].endswith("model.toml")
    for c, m in doc["validation"]["turn"].items():
        assert m["fit_percent"] == pytest.approx(m["fit_percent_analytic"], abs=1e-9), c
    assert "manoeuvres" not in doc  # the turn's rudder is held from the start: no manoeuvre
    assert "Ljung-Box" in err and "turn" in err


SMALL_TURN = """name = "small-turn"
duration = 30.0
depth = 100.0
control_rate = 50.0

[[experiment]]
name = "circle"
rudder = {signal = "step", amplitude = 0.01, start = 1.0}
autopilot = {depth = 0.0, roll = 0.0}
"""


def test_validate_compares_the_manoeuvre_of_record_and_model(tmp_path, capsys):
    """A run flying a turning circle on a 0.01 rad rudder step: the record's metrics are the
    run's own (its .truth.csv), the model's are those of the track its open-loop prediction makes
    (built here from the analytic model's prediction), and each difference is 100 (model −
    record) / |record|."""
    (tmp_path / "small-turn.toml").write_text(SMALL_TURN)
    spec = read_scenario(tmp_path / "small-turn.toml")
    run = runs.simulate(spec, out=tmp_path / "run")
    out = tmp_path / "val.json"
    capsys.readouterr()
    assert main(["validate", str(run), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    doc = json.loads(out.read_text())["manoeuvres"]["circle"]
    assert doc["manoeuvre"] == "turning circle" and doc["source"] == str(run / "circle.truth.csv")
    assert doc["record"] == metric_values(run_metrics(run)["circle"])
    experiments, config = load_data([run])
    (yhat,) = predict(experiments, config)
    track = record_track(replace(experiments[0], y=yhat))
    model = metric_values(experiment_metrics(spec.experiments[0], track))
    numbers = {k for k, v in model.items() if not isinstance(v, str)}  # the turn's side: a word
    assert {k: doc["model"][k] for k in numbers} == pytest.approx({k: model[k] for k in numbers}, rel=1e-12)
    assert {k: doc["model"][k] for k in model.keys() - numbers} == {
        k: model[k] for k in model.keys() - numbers
    }
    assert doc["model"].keys() == model.keys()
    # the prediction's circle is kinematic: the steady diameter is 2 U / |r| over the steady turn
    assert model["steady_diameter"] == pytest.approx(
        2 * model["steady_speed"] / abs(model["steady_turn_rate"]), rel=0.01
    )
    for k, v in doc["record"].items():
        if isinstance(v, float):
            assert doc["difference_percent"][k] == pytest.approx(100 * (model[k] - v) / abs(v), rel=1e-9), k
    assert set(doc["difference_percent"]) >= {
        "advance",
        "transfer",
        "tactical_diameter",
        "steady_turn_rate",
        "speed_ratio",
    }
    assert "tactical_diameter" in err and "diff %" in err
    # a prediction without u has no track: the model's side is left out, the reason given
    partial = {"circle": replace(experiments[0], y=yhat).only(["v", "w", "r", "phi", "theta", "psi"])}
    (c,) = compared(run, partial).values()
    assert c.model is None and c.differences() == {} and c.record == run_metrics(run)["circle"]
    assert c.note.startswith("no model metrics: ") and "u not measured" in c.note


@pytest.mark.parametrize(
    "text, message",
    [
        ("{", "expected an estimates JSON"),
        ('{"coefficients": {"N_x": {"value": 1}}}', "'N_x' is not a coefficient"),
        ('{"coefficients": {"N_r": {"value": "a"}}}', "expected a finite number"),
    ],
)
def test_validate_rejects_a_bad_estimates_file(tmp_path, capsys, text, message):
    assert (
        main(["simulate", "--scenario", "turn", "--duration", "2", "--quiet", "--out", str(tmp_path / "t")])
        == 0
    )
    bad = tmp_path / "bad.json"
    bad.write_text(text)
    capsys.readouterr()
    assert (
        main(["validate", str(tmp_path / "t"), "--estimates", str(bad), "--out", str(tmp_path / "v.json")])
        == 2
    )
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err and "bad.json" in err, err
    assert not (tmp_path / "v.json").exists()
