"""`identify --report DIR`: one self-contained HTML page of the fit (figures embedded), for the
linear model and a nonlinear model config; a user's folder is never written to; the page opened
in headless Chromium shows every section with its figures and logs no error."""

from __future__ import annotations

import base64
import re
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from testbed.cli import main
from testbed.data import write_config, write_csv
from studies import remus as examples
from testbed.presentation.fit_report import ANALYSIS_SECTIONS, REPORT, SECTIONS, VALIDATION_SECTIONS

PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def linear(tmp_path_factory):
    """Two records of the example (one with a dropout) and its a-priori config."""
    root = tmp_path_factory.mktemp("linear")
    paths = []
    for e in examples.experiments(4, duration=30.0):
        rows = np.arange(len(e.t)) if e.name == "horizontal" else np.r_[0:200, 260 : len(e.t)]
        paths.append(root / f"{e.name}.csv")
        write_csv(paths[-1], e.t[rows], e.y[rows], e.inputs[rows])
    write_config(root / "prior.toml", examples.prior_config())
    return root, paths


@pytest.fixture(scope="module")
def nonlinear(tmp_path_factory):
    """A 3 s doublet record of the captive polynomial model and a start 20 % off on two terms."""
    from testbed.models.linear import STATES
    from testbed.models.nonlinear_flight import fly_nonlinear
    from testbed.captive.config import captive_config

    free = ("Y_uv", "N_uv")
    config = replace(captive_config(model="polynomial")[0], free=free, screen=False)
    model, theta = config.nonlinear()
    t = np.arange(151) * 0.02
    fins = np.zeros((len(t), 3))
    fins[(t > 0.4) & (t < 1.4), 0] = np.radians(3.0)
    fins[(t >= 1.4) & (t < 2.4), 0] = -np.radians(3.0)
    x = fly_nonlinear(model, theta, t, np.r_[config.vehicle.speed, np.zeros(9)], fins)
    y = x + np.random.default_rng(3).normal(size=x.shape) * 1e-3
    root = tmp_path_factory.mktemp("nonlinear")
    write_csv(root / "doublet.csv", t, y, fins, STATES)
    write_config(root / "start.toml", config.with_coefficients({n: 0.8 * config.terms[n] for n in free}))
    return root


def _report(capsys, data, config, folder, *extra) -> str:
    argv = ["identify", *map(str, data), "--config", str(config), "--report", str(folder), *extra]
    code = main(argv + ["--out", str(folder.parent / f"{folder.name}.json")])
    assert code == 0, capsys.readouterr().err if capsys else code
    return (folder / REPORT).read_text(encoding="utf-8")


@pytest.fixture(scope="module")
def linear_report(linear, tmp_path_factory):
    """The linear records' report with default options, its folder (`report`) beside the fit's
    JSON (`report.json`): drawn once for the tests that only read it."""
    root, paths = linear
    folder = tmp_path_factory.mktemp("linear_report") / "report"
    _report(None, paths, root / "prior.toml", folder)
    return folder


@pytest.fixture(scope="module")
def nonlinear_report(nonlinear, tmp_path_factory):
    """The nonlinear record's report from its start, drawn once (as `linear_report`)."""
    folder = tmp_path_factory.mktemp("nonlinear_report") / "report"
    _report(None, [nonlinear / "doublet.csv"], nonlinear / "start.toml", folder)
    return folder


def _sections(page: str) -> dict[str, str]:
    parts = re.split(r"<section id='([a-z]+)'>", page)
    return {parts[k]: parts[k + 1] for k in range(1, len(parts) - 1, 2)}


def _images(html: str) -> list[bytes]:
    return [base64.b64decode(b) for b in re.findall(r"src='data:image/png;base64,([A-Za-z0-9+/=]+)'", html)]


def test_a_linear_fit_report_has_every_section_with_its_figures(linear_report):
    page = (linear_report / REPORT).read_text(encoding="utf-8")
    assert list(linear_report.iterdir()) == [linear_report / REPORT]
    sections = _sections(page)
    assert list(sections) == list(SECTIONS)
    figures = {name: _images(body) for name, body in sections.items()}
    assert all(png.startswith(PNG) and len(png) > 5_000 for pngs in figures.values() for png in pngs)
    # per record: outputs; residuals over time, autocorrelation, spectrum
    assert len(figures["outputs"]) == 2 and len(figures["residuals"]) == 6
    assert len(figures["coefficients"]) == len(figures["correlation"]) == len(figures["convergence"]) == 1
    assert "No analysis" not in sections["correlation"]
    assert "http" not in page.replace("http-equiv", "")  # nothing fetched: self-contained
    for name in examples.FREE:
        assert f"<td>{name}</td>" in sections["coefficients"], name
    assert "<td>vertical 0–9.95 s; vertical 13–29.95 s</td>" in sections["summary"]
    assert "<td>horizontal</td><td" in sections["summary"]
    assert "every start tried" in sections["summary"] and "drift group" in sections["correlation"]


def test_a_validation_report_shows_the_held_out_records_against_the_model(
    linear, linear_report, capsys, tmp_path
):
    """Fitted on seed 4's records, validated on seed 5's: the page's outputs and residuals of the
    held-out records, the config as written beside the estimate's model, fit % as the JSON's."""
    import json

    root, paths = linear
    held_out = []
    for e in examples.experiments(5, duration=20.0):
        held_out.append(tmp_path / f"held_{e.name}.csv")
        write_csv(held_out[-1], e.t, e.y, e.inputs)
    argv = ["validate", *map(str, held_out), "--config", str(root / "prior.toml"), "--estimates"]
    argv += [str(linear_report.parent / "report.json"), "--out", str(tmp_path / "v.json")]
    argv += ["--report", str(tmp_path / "v")]
    assert main(argv) == 0, capsys.readouterr().err
    page = (tmp_path / "v" / REPORT).read_text(encoding="utf-8")
    sections = _sections(page)
    assert list(sections) == list(VALIDATION_SECTIONS)
    assert len(_images(sections["outputs"])) == 2 and len(_images(sections["residuals"])) == 6
    doc = json.loads((tmp_path / "v.json").read_text())
    fit = doc["validation"]["held_horizontal"]["r"]["fit_percent"]
    assert f">{fit:.2f}</td>" in sections["residuals"] and "with the coefficients of" in sections["summary"]


def test_an_analysis_report_shows_the_bounds_correlation_and_drift(linear, nonlinear, capsys, tmp_path):
    """`analyze --report`: the bounds as the JSON gives them, the correlation heat map and the
    drift groups, for the linear model and a nonlinear model config."""
    import json

    root, paths = linear
    for name, data, config in (
        ("linear", paths, root / "prior.toml"),
        ("nonlinear", [nonlinear / "doublet.csv"], nonlinear / "start.toml"),
    ):
        argv = ["analyze", *map(str, data), "--config", str(config), "--out", str(tmp_path / f"{name}.json")]
        assert main(argv + ["--report", str(tmp_path / name)]) == 0, capsys.readouterr().err
        sections = _sections((tmp_path / name / REPORT).read_text(encoding="utf-8"))
        assert list(sections) == list(ANALYSIS_SECTIONS), name
        doc = json.loads((tmp_path / f"{name}.json").read_text())
        for coefficient, sd in doc["crlb_std"].items():
            assert f"<td>{coefficient}</td>" in sections["bounds"], (name, coefficient)
            assert sd is None or f">{sd:.3g}</td>" in sections["bounds"], (name, coefficient)
        assert len(_images(sections["correlation"])) == 1 and "drift group" in sections["correlation"]


def test_the_report_links_the_fits_recording(linear, capsys, tmp_path):
    root, paths = linear
    page = _report(
        capsys, paths, root / "prior.toml", tmp_path / "report", "--rrd", str(tmp_path / "fit.rrd")
    )
    assert "<a href='../fit.rrd'>../fit.rrd</a>" in page and (tmp_path / "fit.rrd").is_file()


def test_a_nonlinear_fit_report_flies_the_nonlinear_model(nonlinear_report):
    page = (nonlinear_report / REPORT).read_text(encoding="utf-8")
    sections = _sections(page)
    assert list(sections) == list(SECTIONS)
    assert len(_images(sections["outputs"])) == 1 and len(_images(sections["residuals"])) == 3
    assert "<td>Y_uv</td>" in sections["coefficients"] and "<td>N_uv</td>" in sections["coefficients"]
    assert len(_images(sections["correlation"])) == 1 and "No analysis" not in sections["correlation"]


def test_the_trials_parameters_have_their_own_section_with_their_units(
    linear, linear_report, capsys, tmp_path
):
    """A yaw offset and a rate gyro's bias freed and a compass bias set: the trial section gives
    each with its unit (the free ones with their bounds), the coefficients section none of them."""
    root, paths = linear
    prior = examples.prior_config()
    config = replace(prior, free=(*prior.free, "N_0", "b_r"), per_record=("N_0",))
    write_config(tmp_path / "trial.toml", config.with_coefficients({"b_psi": 0.01}))
    sections = _sections(_report(capsys, paths, tmp_path / "trial.toml", tmp_path / "report"))
    trial = sections["trial"]
    for name, unit in (
        ("N_0[horizontal]", "N m"),
        ("N_0[vertical]", "N m"),
        ("b_r", "rad/s"),
        ("b_psi", "rad"),
    ):
        assert f"<td>{name}</td><td>{unit}</td>" in trial, name
        assert f"<td>{name}</td>" not in sections["coefficients"], name
    assert len(_images(trial)) == 1 and "set in the config" in trial
    assert "nan" not in trial  # a per-record name's a-priori value is its record's
    assert "<td>N_0</td>" not in trial  # estimated per record, so not among those set
    assert "<td>Y_v</td>" in sections["coefficients"] and "Y_v" not in trial
    plain = _sections((linear_report / REPORT).read_text(encoding="utf-8"))
    assert "None free or set" in plain["trial"] and not _images(plain["trial"])


def test_a_nonlinear_report_shows_its_reference_beside_a_perturbed_start(linear, nonlinear, capsys, tmp_path):
    """From a perturbed start the config as written is the reference; `--reference` names another
    (here the captive config itself); `--reference` without a report, or of the other model, is
    refused before the fit."""
    data, start = [nonlinear / "doublet.csv"], nonlinear / "start.toml"
    page = _report(capsys, data, start, tmp_path / "moved", "--perturb-spread", "0.2", "--seed", "3")
    assert "<th>config as written</th>" in _sections(page)["coefficients"]
    page = _report(capsys, data, start, tmp_path / "given", "--reference", str(start))
    assert "<th>start</th>" in _sections(page)["coefficients"]
    argv = ["identify", *map(str, data), "--config", str(start), "--out", str(tmp_path / "x.json")]
    capsys.readouterr()
    for extra, message in (
        (["--reference", str(start)], "expected --report"),
        (
            ["--reference", str(linear[0] / "prior.toml"), "--report", str(tmp_path / "r")],
            "expected a nonlinear one",
        ),
    ):
        assert main(argv + extra) == 2
        err = capsys.readouterr().err
        assert message in err and err.strip().count("\n") == 0, err
    assert not (tmp_path / "x.json").exists()


@pytest.mark.parametrize("held", ["file", "folder"])
def test_a_users_file_or_folder_is_never_written_to(linear, capsys, tmp_path, held):
    root, paths = linear
    target = tmp_path / "mine"
    if held == "file":
        target.write_text("my notes")
    else:
        target.mkdir()
        (target / "notes.txt").write_text("my notes")
    argv = ["identify", *map(str, paths), "--config", str(root / "prior.toml"), "--report", str(target)]
    code = main(argv + ["--out", str(tmp_path / "e.json"), "--force"])
    err = capsys.readouterr().err
    assert code == 2 and "--report" in err and err.strip().count("\n") == 0, err
    assert not (tmp_path / "e.json").exists()  # refused before the fit: nothing written
    if held == "file":
        assert target.read_text() == "my notes"
    else:
        assert [p.name for p in target.iterdir()] == ["notes.txt"]


def test_a_report_folder_is_replaced_only_with_force(linear, capsys, tmp_path):
    root, paths = linear
    folder = tmp_path / "r"
    folder.mkdir()
    (folder / REPORT).write_text("an old report")
    argv = ["identify", *map(str, paths), "--config", str(root / "prior.toml"), "--report", str(folder)]
    assert main(argv + ["--out", str(tmp_path / "a.json")]) == 2
    assert (folder / REPORT).read_text() == "an old report"
    capsys.readouterr()
    assert main(argv + ["--out", str(tmp_path / "b.json"), "--force"]) == 0
    assert (folder / REPORT).read_text(encoding="utf-8").startswith("<!doctype html>")


@pytest.mark.parametrize("model", ["linear", "nonlinear"])
def test_the_page_opens_in_chromium_with_every_section_and_no_console_error(request, model):
    playwright = pytest.importorskip("playwright.sync_api", reason="playwright is not installed")
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        pytest.skip("no Chromium on this machine (Debian's chromium package)")
    folder = request.getfixturevalue(f"{model}_report")
    flags = ["--no-sandbox", "--disable-gpu", "--no-first-run", "--disable-background-networking"]
    errors = []
    with playwright.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium, args=flags)
        page = browser.new_page()
        page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
        page.on("pageerror", lambda exc: errors.append(str(exc)))
        page.goto(Path(folder / REPORT).as_uri())
        for section in SECTIONS:
            assert page.locator(f"section#{section} h2").count() == 1, section
        widths = page.eval_on_selector_all("img", "imgs => imgs.map(i => i.naturalWidth)")
        browser.close()
    assert widths and all(w > 100 for w in widths), widths
    assert errors == []


def test_the_same_page_from_python(tmp_path):
    """`testbed.report` writes the page of a fit made in Python, the prior's predictions beside it."""
    import testbed

    experiments = examples.experiments(6, duration=20.0)
    prior = examples.prior_config()
    iterations = []
    est = testbed.identify(
        experiments, prior, "ml-gn", callback=lambda s: iterations.append((s.iteration, s.values, s.cost))
    )
    path = testbed.report(
        tmp_path / "r", experiments, prior, est, prior, iterations, examples.example_config()
    )
    page = path.read_text(encoding="utf-8")
    sections = _sections(page)
    assert path == tmp_path / "r" / REPORT and list(sections) == list(SECTIONS)
    assert "<th>analytic</th>" in sections["coefficients"] and len(_images(sections["convergence"])) == 1
    with pytest.raises(testbed.InputError, match="--report"):
        testbed.report(tmp_path / "r", experiments, prior, est)
