"""The linear-truth plant: a scenario flown by the run's analytic linear model itself."""

import json
import shlex

import numpy as np
import pytest
from scipy.linalg import expm

from testbed.cli import main
from testbed.data import read_config, read_csv
from testbed.errors import InputError
from testbed.models.linear import IX, NU, NX, STATES, continuous, structure, theta_vector
from testbed.simulation import runs
from testbed.simulation.scenario import read_scenario
from testbed.simulation.vehicle import fin_limits, load_model

DURATION = 10.0  # s per experiment
SEED = 2


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    """Scenario II flown with one seed on the MuJoCo plant and on the linear model."""
    root = tmp_path_factory.mktemp("truths")
    return {
        truth: runs.simulate("II", seed=SEED, out=root / truth, duration=DURATION, truth=truth)
        for truth in ("plant", "linear")
    }


def _open_loop(run, name):
    """The run's model.toml simulated open loop from the first truth sample with the recorded
    fin angles, by its own exact zero-order hold (scipy's expm of the augmented matrix)."""
    config = read_config(run / "model.toml")
    truth = read_csv(run / f"{name}.truth.csv", keep_repeats=True)
    A, B, S = continuous(structure(config.vehicle), theta_vector(config.coefficients))
    M = np.zeros((NX + NU + 1, NX + NU + 1))
    M[:NX, :NX], M[:NX, NX : NX + NU], M[:NX, -1] = A, B, S
    E = expm(M * truth.dt)
    x = truth.y[0].copy()
    x[IX["u"]] -= config.vehicle.speed
    xs = [x]
    for u in truth.inputs[:-1]:
        x = E[:NX, :NX] @ x + E[:NX, NX : NX + NU] @ u + E[:NX, -1]
        xs.append(x)
    xs = np.array(xs)
    xs[:, IX["u"]] += config.vehicle.speed
    return truth, xs


def _fits(run, name, sigma):
    """Fit % of the open-loop model on each channel the flight moves (std above 1e-3 σ)."""
    truth, xs = _open_loop(run, name)
    out = {}
    for c in STATES:
        y = truth.column(c)
        if y.std() > 1e-3 * sigma[c]:
            out[c] = 100 * (1 - np.linalg.norm(y - xs[:, IX[c]]) / np.linalg.norm(y - y.mean()))
    return out


def test_the_analytic_model_reproduces_the_linear_truth_and_not_the_plants(pair):
    sigma = read_scenario(pair["linear"] / "scenario.toml").sensors.noise_std
    for name in ("horizontal", "vertical", "roll"):
        linear, plant = _fits(pair["linear"], name, sigma), _fits(pair["plant"], name, sigma)
        assert len(linear) >= 3 and min(linear.values()) > 99.99, (name, linear)
        assert min(plant.values()) < 99.99, (name, plant)  # the check can fail: it does on the plant
        truth, xs = _open_loop(pair["linear"], name)
        scale = np.array([sigma[c] for c in STATES])
        assert np.max(np.abs(truth.y - xs) / scale) < 1e-6  # to rounding, in noise units


def test_linear_truth_has_the_plants_sensors_noise_and_files(pair):
    plant, linear = pair["plant"], pair["linear"]
    assert {p.name for p in plant.iterdir()} == {p.name for p in linear.iterdir()}
    m_plant, m_linear = (json.loads((r / "manifest.json").read_text()) for r in (plant, linear))
    assert m_plant["truth"] == "plant" and m_linear["truth"] == "linear"
    assert m_plant["settings"] == m_linear["settings"]
    sensors = read_scenario(linear / "scenario.toml").sensors
    sigma, fin_std = sensors.noise_std, sensors.fin_std
    assert (plant / "model.toml").read_text() == (linear / "model.toml").read_text()
    for name in m_linear["experiments"]:
        a, b = read_csv(plant / f"{name}.csv"), read_csv(linear / f"{name}.csv")
        assert a.measured == b.measured and a.y.shape == b.y.shape
        ta, tb = (read_csv(r / f"{name}.truth.csv", keep_repeats=True) for r in (plant, linear))
        assert not np.allclose(ta.y, tb.y)  # another plant flew
        cols = [ta.measured.index(c) for c in a.measured]
        # the same noise streams: measured minus truth is the same draw on both plants (to the
        # CSVs' rounding, in noise units)
        scale = np.array([sigma[c] for c in a.measured])
        assert (np.abs((a.y - ta.y[:, cols]) - (b.y - tb.y[:, cols])).max(axis=0) < 1e-4 * scale).all()
        assert np.abs((a.inputs - ta.inputs) - (b.inputs - tb.inputs)).max() < 1e-4 * fin_std
        assert np.std(b.y - tb.y[:, cols], axis=0) == pytest.approx(scale, rel=0.15)  # the documented noise


def test_linear_truths_fins_keep_the_servos_range_and_rate(tmp_path):
    # Scenario I drives the fins hard: on the linear plant too they stop at the range and slew
    # at the servos' rate (each sample holds the mean angle of its interval)
    run = runs.simulate("I", seed=SEED, out=tmp_path / "I", duration=DURATION, truth="linear")
    limits = fin_limits(load_model())
    fins = read_csv(run / "scenario-I.truth.csv", keep_repeats=True).inputs
    assert np.abs(fins).max() <= limits.angle + 1e-12
    assert np.abs(np.diff(fins, axis=0)).max() <= limits.rate * 0.02 * (1 + 1e-9)
    assert np.abs(np.diff(fins, axis=0)).max() > 0.9 * limits.rate * 0.02  # it does reach the rate


def test_linear_truths_command_regenerates_it(pair, tmp_path):
    argv = shlex.split(json.loads((pair["linear"] / "manifest.json").read_text())["command"])
    assert argv[argv.index("--truth") + 1] == "linear"
    assert main(argv[1:] + ["--quiet", "--out", str(tmp_path / "again")]) == 0
    for name in ("horizontal", "vertical", "roll"):
        for suffix in (".csv", ".truth.csv"):
            f = f"{name}{suffix}"
            assert (tmp_path / "again" / f).read_bytes() == (pair["linear"] / f).read_bytes()


def test_a_bad_truth_is_a_one_line_error(tmp_path, capsys):
    code = main(
        ["simulate", "--scenario", "II", "--quiet", "--out", str(tmp_path / "run"), "--truth", "mujoco"]
    )
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "--truth mujoco" in err and "linear" in err, err
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(InputError, match="truth='nonlinear'; expected one of plant, linear"):
        runs.simulate("II", out=tmp_path / "lib", duration=1.0, truth="nonlinear")
    assert list(tmp_path.iterdir()) == []
