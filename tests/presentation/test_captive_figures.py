"""The captive tests' figures: the points drawn are the plant's wrench at the test's states, the
curves the fitted model's (against the fit's own route to it: its regressors and added mass), the
fit % in each title the fit of those curves to those points; the PNGs and the Rerun recording hold
them; `testbed captive --figures/--rrd` writes both, and refuses bad outputs in one line with
nothing written."""

from __future__ import annotations

import itertools
import math
import os
from collections import defaultdict

import matplotlib.image
import numpy as np
import pytest
import rerun.chunk

from presentation.test_report import _blueprint, _logged, _matches, _tabs, _views  # noqa: F401  (the recording's readers)
from test_bad_input import cli
from testbed.models import linear, nonlinear
from testbed.models.mechanics import coriolis
from testbed.models.regressors import ROWS
from testbed.presentation.captive_figures import figure_name, sweep_figure
from testbed.presentation.captive_recording import TIMELINE, log_captive, milli, sweep_entity
from testbed.presentation.captive_report import MARKER
from testbed.presentation.captive_sweeps import DENSE, sweep_panels
from testbed.captive.rig import Oscillation
from testbed.captive.config import captive_config_text
from testbed.captive.reference import region_tests
from testbed.simulation.vehicle import constants, load_model
from testbed.captive.wrench import hydrodynamic_wrench

SPEED = 20.0
_RATES = {"v": 1, "w": 2, "p": 3, "q": 4, "r": 5}
# each fin variable's (delta_r, delta_er, delta_el) per unit, as docs/captive.md defines them
_FINS = {"delta_r": (1, 0, 0), "delta_e": (0, 1, 1), "delta_d": (0, 1, -1)}


@pytest.fixture(scope="module")
def captive():
    """(MjModel, TOML text, fit, panels) of the bundled torpedo at 20 m/s."""
    model = load_model(None)
    text, fit = captive_config_text(None, SPEED, model="polynomial")
    return model, text, fit, sweep_panels(model, fit)


def _states(speed, values: dict, n: int):
    """(ν, δ) with u = speed and each named variable (v w p q r or a fin direction) its values."""
    nu, fins = np.zeros((n, 6)), np.zeros((n, 3))
    nu[:, 0] = speed
    for name, x in values.items():
        if name in _RATES:
            nu[:, _RATES[name]] = x
        else:
            fins += np.outer(np.broadcast_to(x, n), _FINS[name])
    return nu, fins


@pytest.fixture(scope="module")
def fitted(captive):
    """The fitted model's wrench at (ν, δ, ν̇) by the fit's own route: the terms' regressors
    (surge relative to trim) times their coefficients, with the added mass's Kirchhoff forces
    −C_A(ν) ν (`coriolis`; M_A the inertia coefficients' less the rigid body's share), less M_A ν̇
    and the plant's thrust."""
    vehicle, _, fit, _ = captive
    model = nonlinear.nonlinear_model(constants(vehicle, fit.speed), fit.terms)
    theta = nonlinear.nonlinear_theta(model, fit.coefficients)
    M_A = model.inertia(theta) - model.inertia(nonlinear.nonlinear_theta(model, fit.rigid))  # the water's
    c = theta[len(nonlinear.INERTIA) :]

    def wrench(nu, fins, nu_dot):
        x = np.concatenate([nu, np.zeros((len(nu), linear.NX - 6))], axis=1)
        tau = nonlinear.force_regressors(model, x, fins) @ c + coriolis(M_A, nu)[0] - nu_dot @ M_A.T
        tau[:, 0] -= fit.thrust
        return tau

    return wrench


def _oscillating(test: Oscillation, speed: float, t):
    """(ν, ν̇) of the oscillation at the instants t: its variable a sin ωt about 0 (u: about speed)."""
    a, w, k = test.amplitude, test.omega, "uvwpqr".index(test.variable)
    nu, nu_dot = np.zeros((len(t), 6)), np.zeros((len(t), 6))
    nu[:, 0] = speed
    nu[:, k] += a * np.sin(w * t)
    nu_dot[:, k] = a * w * np.cos(w * t)
    return nu, nu_dot


def _fit(y, model) -> float:
    return 100 * (1 - np.linalg.norm(y - model) / np.linalg.norm(y - y.mean()))


def test_a_sweeps_points_are_the_plants_wrench_and_its_curves_the_fitted_models(captive, fitted):
    model, _, fit, panels = captive
    tests = {t.name: t for t in region_tests(model, SPEED)}
    by = defaultdict(list)
    for p in panels:
        if isinstance(tests[p.test], Oscillation):
            continue
        by[p.test, p.speed].append(p)
    for (name, speed), own in by.items():
        test = tests[name]
        # a slice per value of the other variables (their grid's points), the first swept along
        rest = list(
            itertools.product(*(np.linspace(-e, e, n) for e, n in zip(test.extent[1:], test.points[1:])))
        )
        first = np.linspace(-test.extent[0], test.extent[0], test.points[0])
        dense = np.linspace(-test.extent[0], test.extent[0], DENSE)
        points, curves = [], []  # per slice: (ν, δ) of its points and of its curve
        for value in rest:
            for along, out in ((first, points), (dense, curves)):
                lead = {test.vary[0]: along, **dict(zip(test.vary[1:], value))}
                values = dict(lead)
                for a, b, k in test.follow:  # a variable on a line: offset by a ratio times its leader
                    values[a] = values[a] + k * np.asarray(lead[b])
                out.append(_states(speed, values, len(along)))
        plant = [hydrodynamic_wrench(model, nu, fins) for nu, fins in points]
        at_points = [fitted(nu, fins, np.zeros_like(nu)) for nu, fins in points]
        curve = [fitted(nu, fins, np.zeros_like(nu)) for nu, fins in curves]
        for p in own:
            r = ROWS.index(p.row)
            assert len(p.plant) == len(p.model) == len(rest)
            for k in range(len(rest)):
                assert np.allclose(p.plant[k].x, first, rtol=0) and np.allclose(p.model[k].x, dense, rtol=0)
                assert np.allclose(p.plant[k].y, plant[k][:, r], rtol=1e-12, atol=0)
                scale = np.abs(curve[k][:, r]).max()
                assert np.allclose(p.model[k].y, curve[k][:, r], rtol=1e-9, atol=1e-9 * scale)
            # the title's fit % is the fit of the model to these points
            y, m = (np.concatenate([w[:, r] for w in ws]) for ws in (plant, at_points))
            assert p.fit == pytest.approx(_fit(y, m), abs=1e-6)
    assert len(by) == 3 * sum(not isinstance(t, Oscillation) for t in tests.values())


def test_an_oscillations_panels_hold_its_harmonics_of_what_they_draw(captive, fitted):
    model, _, fit, panels = captive
    tests = {t.name: t for t in region_tests(model, SPEED)}
    seen = set()
    for p in panels:
        test = tests[p.test]
        if not isinstance(test, Oscillation):
            continue
        (plant,), (curve,) = p.plant, p.model
        assert np.allclose(plant.x, test.period * np.arange(test.samples) / test.samples, rtol=0)
        a, w = test.amplitude, test.omega
        nu, nu_dot = _oscillating(test, p.speed, plant.x)
        r = ROWS.index(p.row)
        fins = np.zeros((len(nu), 3))
        assert np.allclose(plant.y, hydrodynamic_wrench(model, nu, fins, nu_dot)[:, r], rtol=1e-12, atol=0)
        m = fitted(nu, fins, nu_dot)[:, r]
        # the curve: the model along the oscillation at DENSE instants of the period
        assert np.allclose(curve.x, test.period * np.arange(DENSE) / DENSE, rtol=0)
        nu_c, nu_dot_c = _oscillating(test, p.speed, curve.x)
        expected = fitted(nu_c, np.zeros((DENSE, 3)), nu_dot_c)[:, r]
        assert np.allclose(curve.y, expected, rtol=1e-9, atol=1e-9 * np.abs(expected).max())
        assert p.fit == pytest.approx(_fit(plant.y, m), abs=1e-6)
        # the parts: the first harmonic of the drawn points, and of the model at the same instants
        n = len(plant.x)
        for name, (of_plant, of_model) in p.parts.items():
            basis = np.cos(w * plant.x) / (a * w) if name.endswith("dot") else np.sin(w * plant.x) / a
            assert of_plant == pytest.approx(2 / n * plant.y @ basis, rel=1e-12, abs=1e-9)
            assert of_model == pytest.approx(2 / n * m @ basis, rel=1e-9, abs=1e-9)
            seen.add(name)
    # the inertia coefficients are the quadrature parts: each of the model's is drawn somewhere
    assert {"Y_vdot", "Z_wdot", "K_pdot", "M_qdot", "N_rdot", "X_udot", "N_vdot", "Y_rdot"} <= seen
    assert "X_v" not in seen  # X is even in v: no in-phase part worth drawing


def test_every_row_a_test_varies_is_drawn_and_no_other(captive):
    _, _, fit, panels = captive
    drawn = {(p.test, p.speed, p.row) for p in panels}
    rated = {(s.test, s.speed, s.row) for s in fit.surfaces if not math.isnan(s.fit)}
    assert drawn == rated
    assert {"v", "v_r", "pure_q", "delta_e"} <= {t for t, _, _ in drawn}


def test_a_figure_is_a_png_with_a_panel_per_speed_and_row(tmp_path, captive):
    *_, panels = captive
    for test in ("v_r", "pure_v"):
        own = [p for p in panels if p.test == test]
        path = sweep_figure(tmp_path / figure_name(test), own)
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        height, width, _ = matplotlib.image.imread(path).shape
        rows = len({p.row for p in own})
        assert width > 250 * rows and height > 200 * len({p.speed for p in own})


def _recorded(path) -> dict:
    """entity -> (sweep index, scalars (N, k)) of the recording's temporal series."""
    out = defaultdict(lambda: ([], []))
    for chunk in rerun.chunk.RrdReader(path).stream():
        rb = chunk.to_record_batch()
        names = rb.schema.names
        if TIMELINE in names and "Scalars:scalars" in names:
            x, y = out[str(chunk.entity_path)]
            x += rb.column(TIMELINE).to_pylist()
            y += rb.column("Scalars:scalars").to_pylist()
    return {e: (np.array(x), np.array(y, float)) for e, (x, y) in out.items()}


def test_the_recording_holds_every_panels_points_and_curves(tmp_path, captive):
    _, text, fit, panels = captive
    path = log_captive(tmp_path / "captive.rrd", panels, fit.table(), text)
    assert os.listdir(tmp_path) == ["captive.rrd"]
    series = _recorded(path)
    assert len(series) == 2 * len(panels)
    for p in panels:
        for kind, drawn in (("plant", p.plant), ("model", p.model)):
            x, y = series[f"{sweep_entity(p)}/{kind}"]
            assert np.array_equal(x, milli(drawn[0].x))  # distinct thousandths at these extents
            assert np.array_equal(y, np.column_stack([s.y for s in drawn]))
    # a tab per test after the fit's, opening on the first test and on the `sweep` timeline; a
    # plot per panel, showing its plant and model, named with its fit %
    bp = _blueprint(path)
    tabs, active = _tabs(bp)
    assert list(tabs) == ["fit"] + list(dict.fromkeys(p.test for p in panels)) and active == tabs["v"]
    assert bp["/time_panel"]["timeline"] == TIMELINE
    plots = {v["origin"]: v for v in _views(bp).values() if v["kind"] == "TimeSeries"}
    assert len(plots) == len(panels)
    logged = _logged(path)
    for p in panels:
        view = plots[sweep_entity(p)]
        assert _matches(view, logged) == {f"{sweep_entity(p)}/plant", f"{sweep_entity(p)}/model"}
        assert view["name"].endswith(f"fit {p.fit:.2f} %")


def test_captive_writes_the_recording_beside_the_config(tmp_path, capsys):
    out, rrd = tmp_path / "c.toml", tmp_path / "c.rrd"
    code, printed, err = cli(capsys, "captive", "--speed", SPEED, "--out", out, "--rrd", rrd)
    assert code == 0, err
    lines = printed.splitlines()
    assert lines[0] == str(out) and lines[-1] == str(rrd) and lines[-2].split()[0] == "all"
    assert sorted(os.listdir(tmp_path)) == ["c.rrd", "c.toml"]
    assert any(e.startswith("/captive/pure_q/") for e in _recorded(rrd))


@pytest.mark.slow  # about 50 s on one core: two folders of 42 figures
def test_captive_writes_a_folder_of_figures_and_force_replaces_only_its_own(tmp_path, capsys):
    figures, out = tmp_path / "figures", tmp_path / "c.toml"
    code, printed, err = cli(capsys, "captive", "--speed", SPEED, "--out", out, "--figures", figures)
    assert code == 0, err
    assert printed.splitlines()[-1] == str(figures)
    names = sorted(os.listdir(figures))
    assert names == sorted([MARKER] + [figure_name(t.name) for t in region_tests(load_model(None), SPEED)])
    assert "all" in (figures / MARKER).read_text()
    # again: refused without --force; with it the folder is replaced (it holds the marker)
    code, _, err = cli(capsys, "captive", "--out", tmp_path / "d.toml", "--figures", figures)
    assert code == 2 and "already exists" in err and "--force" in err and err.count("\n") == 1
    (figures / "v.png").write_bytes(b"old")
    code, _, err = cli(capsys, "captive", "--out", tmp_path / "d.toml", "--figures", figures, "--force")
    assert code == 0, err
    assert (figures / "v.png").read_bytes()[:4] == b"\x89PNG"
    assert sorted(os.listdir(tmp_path)) == ["c.toml", "d.toml", "figures"]


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["--figures", "mine"], ["--figures 'mine'", "already exists"]),
        (["--figures", "mine", "--force"], ["--figures 'mine'", "without captive-fit.txt"]),
        (["--figures", "file.txt"], ["--figures 'file.txt'", "is a file"]),
        (["--figures", "-"], ["--figures '-'", "folder name"]),
        (["--figures", "new", "--out", "new/c.toml"], ["--out 'new/c.toml'", "folder new does not exist"]),
        (
            ["--figures", "ours", "--force", "--out", "ours/c.toml"],
            ["--figures 'ours'", "holds the out ours/c.toml"],
        ),
        (
            ["--figures", "ours", "--force", "--rrd", "ours/c.rrd"],
            ["--figures 'ours'", "holds the rrd ours/c.rrd"],
        ),
        (["--figures", "c.toml", "--out", "c.toml"], ["--figures 'c.toml'", "holds the out"]),
        (["--figures", "file.txt/sub"], ["file.txt is a file"]),
        (["--rrd", "-"], ["--rrd -", "expected a file name"]),
        (["--rrd", "no/such/c.rrd"], ["--rrd 'no/such/c.rrd'", "no/such"]),
        (["--rrd", "c.toml", "--out", "c.toml"], ["c.toml", "is also the"]),
        (["--rrd", "mine"], ["--rrd 'mine'", "is a folder"]),
    ],
)
def test_bad_outputs_are_one_line_and_write_nothing(tmp_path, capsys, monkeypatch, argv, words):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("a user's")
    (tmp_path / "file.txt").write_text("a user's")
    (tmp_path / "ours").mkdir()
    (tmp_path / "ours" / MARKER).write_text("figures testbed wrote")
    before = sorted(os.listdir(tmp_path))
    argv = argv if "--out" in argv else argv + ["--out", "c.toml"]
    code, printed, err = cli(capsys, "captive", *argv)
    assert code == 2 and err.count("\n") == 1, err
    for w in words:
        assert w in err, err
    assert sorted(os.listdir(tmp_path)) == before and os.listdir(tmp_path / "mine") == ["notes.txt"]
    assert (tmp_path / "file.txt").read_text() == "a user's"
