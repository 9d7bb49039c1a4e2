"""A nonlinear model config ([terms]): written and read back, bad input refused in one line naming
the file and the key, and read by the commands."""

from __future__ import annotations

import tomllib

import pytest

from studies.fuzz import corpus, run_case, workspace
from testbed.data import ModelConfig, config_text, parse_config, read_config, write_config
from testbed.errors import InputError
from testbed.jobs.common import inputs
from testbed.models.nonlinear import INERTIA, TERMS
from testbed.simulation.analytic import analytic


@pytest.fixture(scope="module")
def config():
    lin = analytic()
    terms = {t: (-1) ** k * (k + 0.25) for k, t in enumerate(TERMS)}
    inertia = {n: lin.coefficients[n] for n in INERTIA}
    return ModelConfig(lin.vehicle, inertia, ("Y_uv", "N_v|v|", "X_udot"), terms=terms)


def test_a_nonlinear_config_round_trips(tmp_path, config):
    path = write_config(tmp_path / "n.toml", config, {"Y_uv": "sway from drift", "X_udot": "added mass"})
    back = read_config(path)
    assert back.terms == config.terms and list(back.terms) == list(TERMS)  # values and order
    assert back.coefficients == config.coefficients and back.free == config.free
    assert back.vehicle == config.vehicle
    text = path.read_text()
    assert '"N_v|v|" = ' in text and "# sway from drift" in text and "# added mass" in text
    assert "Y_v =" not in text  # the linear coefficients are not the model's
    assert config_text(back) == config_text(config)


def _doc(config):
    return tomllib.loads(config_text(config))


@pytest.mark.parametrize(
    ("changes", "words"),
    [
        ({"terms__Y_q_bar_": 1.0}, r"m.toml: \[terms\] term 'Y_q\|': expected a row letter"),
        ({"terms__Q_uv": 1.0}, r"m.toml: \[terms\] term 'Q_uv'"),
        ({"terms__Y_v": 1.0}, r"m.toml: \[terms\] term 'Y_v' is a linear model's name"),
        ({"terms__Y_uv": float("nan")}, r'm.toml: \[terms\] "Y_uv" = nan; expected a finite number'),
        ({"terms__Y_uv": "1"}, r"m.toml: \[terms\] \"Y_uv\" = '1'; expected a finite number"),
        ({"terms__Y_uv": 1e300}, r'm.toml: \[terms\] "Y_uv" = 1e\+300; expected a magnitude'),
        ({"coefficients__Y_v": -2.0}, r"m.toml: \[coefficients\] Y_v in a nonlinear model config"),
        ({"identify__free": ["N_uv|"]}, r"m.toml: \[identify\] free names 'N_uv\|', not an inertia"),
        ({"identify__free": ["Y_uv", "Y_uv"]}, r"m.toml: \[identify\] free names 'Y_uv' twice"),
        ({"vehicle__GM": 0.1}, r"m.toml: \[terms\] the nonlinear model is a submerged body's"),
    ],
)
def test_bad_nonlinear_config_is_one_line(config, changes, words):
    doc = _doc(config)
    for key, value in changes.items():
        table, _, name = key.partition("__")
        doc[table][name.replace("_bar_", "|")] = value
    with pytest.raises(InputError, match=words) as e:
        parse_config(doc, "m.toml")
    assert "\n" not in str(e.value)
    doc = _doc(config)
    doc["terms"] = 1.0
    with pytest.raises(InputError, match=r"\[terms\] must be a table"):
        parse_config(doc, "m.toml")


def test_the_commands_read_a_nonlinear_config(tmp_path, config):
    path = write_config(tmp_path / "n.toml", config)
    run = tmp_path / "h.csv"
    run.write_text("t,u,v,delta_r,delta_er,delta_el\n0,20,0,0,0,0\n0.1,20,0,0,0,0\n0.2,20,0,0,0,0\n")
    assert inputs([run], path)[1].terms == config.terms


def test_the_fuzz_corpus_terms_cases_end_in_one_line_errors(tmp_path):
    root = workspace(tmp_path)
    cases = [c for c in corpus(root) if c.label.startswith("config terms")]
    assert len(cases) == 14
    for case in cases:
        outcome = run_case(root, case)
        assert outcome.kind == "error" and not outcome.partial, (case.label, outcome.err)
        assert outcome.code == 2 and outcome.err.strip().count("\n") == 0, (case.label, outcome.err)


def test_a_term_beyond_the_floating_point_range_at_trim_is_refused(config):
    doc = _doc(config)
    doc["terms"]["N_" + "u" * 3000] = 0.0  # U³⁰⁰⁰ overflows, whatever its coefficient
    with pytest.raises(
        InputError, match=r"m.toml: \[terms\] term 'N_uu.*' \(3000 factors\) is beyond the float"
    ):
        parse_config(doc, "m.toml")
