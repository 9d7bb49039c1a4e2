"""Rerun recordings read back with rerun.chunk.RrdReader: entities and row counts."""

from collections import Counter

import numpy as np
import pytest
import rerun.chunk

from testbed import report
from testbed.analysis import compare
from testbed.data import ModelConfig
from testbed.errors import InputError
from testbed.estimators import identify
from testbed.estimators.outputerror import synthetic
from testbed.scenario import Settings, fly_scenario
from testbed.truth import analytic_config


def _rows(path) -> Counter:
    rows = Counter()
    for chunk in rerun.chunk.RrdReader(path).stream():
        rows[str(chunk.entity_path)] += chunk.num_rows
    return rows


def test_run_recording_has_the_replay_and_every_series(tmp_path):
    flights, _ = fly_scenario("II", seed=1, settings=Settings(duration=4.0))
    path = report.log_run(tmp_path / "recording.rrd", flights)
    assert path.exists() and not list(tmp_path.glob("*.tmp"))
    rows = _rows(path)
    for f in flights:
        n = len(f.t)
        assert rows[f"/{f.name}/vehicle"] == n  # pose over time
        for fin in ("rudder", "elevator_right", "elevator_left"):
            assert rows[f"/{f.name}/vehicle/{fin}"] == n  # deflection over time
            assert rows[f"/{f.name}/vehicle/{fin}/blades"] == 1  # static shape
        assert rows[f"/{f.name}/vehicle/hull"] == 1 and rows[f"/{f.name}/trail"] == 1
        for s in ("u", "v", "w", "p", "q", "r", "phi", "theta", "psi", "z"):
            assert rows[f"/{f.name}/states/{s}/truth"] == n == rows[f"/{f.name}/states/{s}/measured"]
        for fin in ("delta_r", "delta_er", "delta_el"):
            assert rows[f"/{f.name}/fins/{fin}/actual"] == n
        for name in f.commands:
            assert rows[f"/{f.name}/commands/{name}"] == n


def test_fit_recording_has_outputs_iterations_and_comparison(tmp_path):
    config, _ = analytic_config(None, 20.0)
    config = ModelConfig(config.vehicle, config.coefficients, ("N_r", "N_dr"))
    t = np.arange(0, 10, 0.04)
    delta = np.column_stack([0.02 * np.sign(np.sin(1.3 * t)), np.zeros_like(t), np.zeros_like(t)])
    data = [synthetic(config, t, delta, rng=np.random.default_rng(0), measured=("v", "r", "psi"))]
    start = config.with_coefficients({"N_r": 0.8 * config.coefficients["N_r"]})
    iterations = []
    est = identify(data, start, method="ml-gn",
                   callback=lambda k, values, cost: iterations.append((k, list(values), cost)))  # fmt: skip
    path = report.log_fit(tmp_path / "fit.rrd", data, start, est, iterations, compare(est, config))
    rows = _rows(path)
    name = data[0].name
    for s in ("v", "r", "psi"):
        assert rows[f"/outputs/{name}/{s}/measured"] == len(t) == rows[f"/outputs/{name}/{s}/model"]
    assert rows["/parameters/N_r"] == len(iterations) == rows["/cost"]
    assert rows["/comparison/table"] == 1 and rows["/comparison/error_sigmas"] == 1


def test_replay(tmp_path, monkeypatch, capsys):
    with pytest.raises(InputError, match="no such recording"):
        report.replay(tmp_path)
    (tmp_path / "recording.rrd").write_bytes(b"")
    monkeypatch.setattr("sys.platform", "linux")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert report.replay(tmp_path) == 0
    assert "rerun " in capsys.readouterr().out
