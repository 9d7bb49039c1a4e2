"""`testbed captive`: the captive reference written as a nonlinear model config, its fit table
printed; bad input refused in one line with status 2 and nothing written."""

from __future__ import annotations

import os
import time

import pytest

from test_bad_input import cli
from testbed.data import read_config
from testbed.models.nonlinear import INERTIA, TERMS
from testbed.captive.reference import Turns, reference_tests
from testbed.captive.fluid_components import component_terms, mjcf_components
from testbed.simulation.vehicle import default_mjcf, load_model


def test_captive_fits_the_component_model_to_the_mjcfs_own_coefficients(tmp_path, capsys):
    """The component terms have the plant's shapes: fitted to the captive tests, they come out as
    the MJCF's fluidcoef (1 for the angular drag and the blades' Munk terms), the inertia as
    the added mass read by the PMM tests plus the rigid body's I_xz."""
    out = tmp_path / "captive.toml"
    code, printed, err = cli(capsys, "captive", "--speed", "20", "--out", out)
    assert code == 0, err
    config = read_config(out)
    body = load_model()
    mjcf = component_terms(body)
    assert config.components == mjcf_components(body)
    assert set(mjcf) <= set(config.terms)
    for name, value in mjcf.items():
        assert config.terms[name] == pytest.approx(value, rel=1e-6), name
    others = set(config.terms) - set(mjcf)  # the Kirchhoff terms of the inertia M leaves out
    assert others == {"Y_qr", "Z_qq", "K_ur", "M_wq", "N_up", "N_vq"}
    assert config.free == tuple(mjcf) and config.screen  # the component terms the candidates
    assert printed.splitlines()[-1].split()[0] == "all"


def test_captive_writes_the_polynomial_reference_and_prints_every_surface(tmp_path, capsys):
    out = tmp_path / "captive.toml"
    start = time.process_time()
    code, printed, err = cli(capsys, "captive", "--speed", "20", "--model", "polynomial", "--out", out)
    took = time.process_time() - start
    assert code == 0, err
    config = read_config(out)
    assert list(config.terms) == list(TERMS) and config.vehicle.speed == 20.0
    assert {n for n, v in config.coefficients.items() if v} == set(INERTIA)
    assert config.free == tuple(TERMS) and config.screen  # the terms a candidate list
    lines = printed.splitlines()
    assert lines[0] == str(out)
    tests = reference_tests(20.0, turns=Turns(incidence=1.0, elevator=0.0, drift=-1.0, rudder=0.0))
    assert len(lines) == 1 + 2 + sum(len(t.speeds) for t in tests)  # path, header, surfaces, all
    assert lines[1].split() == ["test", "u", "m/s", "X", "Y", "Z", "K", "M", "N"]
    assert lines[-1].split()[0] == "all"
    assert took < 30  # the budget for a captive fit, on one core (the CLI runs single-threaded BLAS)


def test_captive_to_standard_output_keeps_the_table_on_stderr(capsys):
    code, printed, err = cli(capsys, "captive", "--out", "-")
    assert code == 0
    assert printed.startswith("[vehicle]") and "[terms]" in printed and "all" not in printed
    assert err.splitlines()[-1].split()[0] == "all"


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["--speed", "0"], ["--speed", "0 must be a finite number > 0"]),
        (["--speed", "1e300"], ["speed", "450"]),
        (["--mjcf", "missing.xml"], ["missing.xml"]),
        (["--model", "cubic"], ["--model", "cubic", "components"]),
        (["--out", "no/such/folder/c.toml"], ["no/such/folder"]),
    ],
)
def test_bad_input_is_one_line_and_writes_nothing(tmp_path, capsys, monkeypatch, argv, words):
    monkeypatch.chdir(tmp_path)
    argv = argv if "--out" in argv else argv + ["--out", "c.toml"]
    code, printed, err = cli(capsys, "captive", *argv)
    assert code == 2 and err.count("\n") == 1, err
    for w in words:
        assert w in err, err
    assert os.listdir(tmp_path) == []


def test_the_mjcf_read_is_not_an_output(tmp_path, capsys):
    mjcf = tmp_path / "body.xml"
    mjcf.write_bytes(default_mjcf().read_bytes())
    code, _, err = cli(capsys, "captive", "--mjcf", mjcf, "--out", mjcf)
    assert code == 2 and "is the input" in err and err.count("\n") == 1
    assert mjcf.read_bytes() == default_mjcf().read_bytes()
