"""Validation metrics: fit % and residual whiteness against closed forms, and `testbed validate`."""

import json

import numpy as np
import pytest

from testbed.cli import main
from testbed.analysis.validation import CONFIDENCE, chi2_sf, fit_percent, whiteness


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
    assert "Ljung-Box" in err and "turn" in err


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
