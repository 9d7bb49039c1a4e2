"""Rerun recordings read back with rerun.chunk.RrdReader: entities, row counts, values, blueprint."""

import dataclasses
import os
from collections import Counter, defaultdict

import numpy as np
import pyarrow as pa
import pytest
import rerun.chunk
from scipy.spatial.transform import Rotation

from testbed import report
from testbed.analysis import compare
from testbed.data import ModelConfig
from testbed.errors import InputError
from testbed.estimators import identify
from testbed.estimators import outputerror as oe
from testbed.estimators.outputerror import synthetic
from testbed.scenario import Flight
from testbed.truth import analytic_config

FIN_NAMES = ("rudder", "elevator_right", "elevator_left")


def _flight(name="horizontal", n=201, seed=0) -> Flight:
    """A flight with the shapes of `fly_scenario`'s (straight ahead at 20 m/s, wiggling fins)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.02
    truth = 0.05 * rng.standard_normal((n, 10))
    truth[:, 0] += 20.0
    fins = 0.1 * np.sin(np.outer(t, [1.0, 2.0, 3.0]))
    position = np.column_stack([20.0 * t, np.zeros(n), np.full(n, 100.0)])
    commands = {"depth": np.full(n, 100.0), "delta_r": fins[:, 0], "roll": np.full(n, np.nan)}
    return Flight(name, t, truth, truth + 0.01, fins, fins + 0.001, position, commands)


FLIGHTS = [_flight("horizontal", seed=1), _flight("vertical", n=151, seed=2)]


def _rows(path) -> Counter:
    rows = Counter()
    for chunk in rerun.chunk.RrdReader(path).stream():
        rows[str(chunk.entity_path)] += chunk.num_rows
    return rows


def _data_columns(chunk) -> dict:
    """The index and component columns of a chunk (not its row ids), by name."""
    rb = chunk.to_record_batch()
    return {f.name: rb.column(i) for i, f in enumerate(rb.schema)
            if (f.metadata or {}).get(b"rerun:kind") in (b"data", b"index")}  # fmt: skip


def _contents(path, blueprint=False) -> dict:
    """(entity, column) -> all its values in stream order, from the recording (or the blueprint)."""
    reader = rerun.chunk.RrdReader(path)
    store = reader.blueprints()[0] if blueprint else None
    out = defaultdict(list)
    for chunk in reader.stream(store=store):
        for name, col in _data_columns(chunk).items():
            out[str(chunk.entity_path), name].append(col)
    return {key: pa.concat_arrays(cols) for key, cols in out.items()}


def _same(x: pa.Array, y: pa.Array) -> bool:
    """Bitwise equal (NaN equals NaN, unlike `equals`)."""
    def raw(a):
        return [b.to_pybytes() if b is not None else None for b in a.buffers()]

    return x.type == y.type and raw(x) == raw(y)


def _scalars(path, entity) -> np.ndarray:
    return np.array([v for row in _contents(path)[entity, "Scalars:scalars"].to_pylist() for v in row])


def test_run_recording_has_the_replay_and_every_series(tmp_path):
    path = report.log_run(tmp_path / "recording.rrd", FLIGHTS)
    assert path.exists() and os.listdir(tmp_path) == ["recording.rrd"]
    assert (path.stat().st_mode & 0o777) == 0o666 & ~_umask()
    rows = _rows(path)
    for f in FLIGHTS:
        n = len(f.t)
        assert rows[f"/{f.name}/vehicle"] == n  # pose over time
        for fin in FIN_NAMES:
            assert rows[f"/{f.name}/vehicle/{fin}"] == n  # deflection over time
            assert rows[f"/{f.name}/vehicle/{fin}/blades"] == 1  # static shape
            assert rows[f"/{f.name}/vehicle/{fin}/pointer"] == 1 == rows[f"/{f.name}/vehicle/{fin}_neutral"]
        assert rows[f"/{f.name}/vehicle/hull"] == 1 and rows[f"/{f.name}/trail"] == 1
        for s in ("u", "v", "w", "p", "q", "r", "phi", "theta", "psi", "z"):
            assert rows[f"/{f.name}/states/{s}/truth"] == n == rows[f"/{f.name}/states/{s}/measured"]
        for fin in ("delta_r", "delta_er", "delta_el"):
            assert rows[f"/{f.name}/fins/{fin}/actual"] == n
        for name in f.commands:
            assert rows[f"/{f.name}/commands/{name}"] == n
    assert np.array_equal(_scalars(path, "/vertical/states/q/measured"), FLIGHTS[1].measured[:, 4])


def _umask() -> int:
    umask = os.umask(0)
    os.umask(umask)
    return umask


def test_attitude_quaternions_are_z_y_x_euler_angles():
    rng = np.random.default_rng(3)
    phi, theta, psi = rng.uniform(-3, 3, (3, 50))
    q = report._euler_quat(phi, theta, psi)
    expected = Rotation.from_euler("ZYX", np.column_stack([psi, theta, phi])).as_quat()
    assert np.allclose(np.abs(np.sum(q * expected, axis=1)), 1.0, atol=1e-12)


def test_blueprint_tracks_the_vehicle_and_has_a_body_axes_close_up(tmp_path):
    path = report.log_run(tmp_path / "recording.rrd", FLIGHTS)
    bp = _contents(path, blueprint=True)
    views = {entity: (bp[entity, "ViewBlueprint:class_identifier"].to_pylist()[0][0],
                      bp[entity, "ViewBlueprint:space_origin"].to_pylist()[0][0])
             for entity, name in bp if name == "ViewBlueprint:space_origin"}  # fmt: skip
    eyes = {entity.removesuffix("/EyeControls3D"): entity for entity, name in bp
            if name == "EyeControls3D:look_target"}  # fmt: skip
    for f in FLIGHTS:
        world = [v for v, (kind, origin) in views.items() if kind == "3D" and origin == "/"
                 and bp.get((eyes.get(v), "EyeControls3D:tracking_entity")) is not None
                 and bp[eyes[v], "EyeControls3D:tracking_entity"].to_pylist() == [[f"/{f.name}/vehicle"]]]  # fmt: skip
        assert len(world) == 1  # the world view's eye follows this flight's vehicle...
        look = bp[eyes[world[0]], "EyeControls3D:look_target"].to_pylist()[0][0]
        eye = bp[eyes[world[0]], "EyeControls3D:position"].to_pylist()[0][0]
        assert np.allclose(look, f.position[0])  # ...starting at it, from ~10 m, not the trail's size
        assert 5.0 < np.linalg.norm(np.subtract(eye, look)) < 20.0
        close = [v for v, (kind, origin) in views.items() if kind == "3D" and origin == f"/{f.name}/vehicle"]
        assert len(close) == 1 and close[0] in eyes  # the body-axes close-up, eye set on the fins
        look = bp[eyes[close[0]], "EyeControls3D:look_target"].to_pylist()[0][0]
        eye = bp[eyes[close[0]], "EyeControls3D:position"].to_pylist()[0][0]
        assert np.linalg.norm(np.subtract(eye, look)) < 4.0 and look[0] < 0  # the stern, close
        assert {(f"/{f.name}/states", "TimeSeries"), (f"/{f.name}", "TimeSeries")} <= {
            (origin, kind) for kind, origin in views.values()}


def test_same_run_same_recording(tmp_path):
    a = report.log_run(tmp_path / "a.rrd", FLIGHTS, title="testbed II seed 1")
    b = report.log_run(tmp_path / "b.rrd", FLIGHTS, title="testbed II seed 1")
    c = report.log_run(tmp_path / "c.rrd", FLIGHTS, title="testbed II seed 2")
    d = report.log_run(tmp_path / "d.rrd", [_flight("horizontal", seed=9), FLIGHTS[1]], title="testbed II seed 1")
    e = report.log_run(tmp_path / "e.rrd", FLIGHTS, title="testbed II seed 1", recording_id="mine")

    def rid(p):
        (store,) = rerun.chunk.RrdReader(p).recordings()
        return store.recording_id

    assert rid(a) == rid(b) and len({rid(a), rid(c), rid(d)}) == 3 and rid(e) == "mine"
    # Not byte-identical: Rerun stamps every chunk and row with a time-based id. The contents are.
    ca, cb = _contents(a), _contents(b)
    assert ca.keys() == cb.keys() and all(_same(ca[k], cb[k]) for k in ca)
    assert ("/__properties", "RecordingInfo:start_time") not in ca  # no wall-clock time
    assert ca["/__properties", "RecordingInfo:name"].to_pylist() == [["testbed II seed 1"]]


def test_an_exception_leaves_the_old_recording_and_no_temporary_file(tmp_path, monkeypatch):
    path = tmp_path / "recording.rrd"
    path.write_bytes(b"old")
    calls = []

    def interrupted(*args):
        calls.append(args)
        if len(calls) == 5:
            raise KeyboardInterrupt

    monkeypatch.setattr(report, "_scalars", interrupted)
    with pytest.raises(KeyboardInterrupt):
        report.log_run(path, FLIGHTS)
    assert os.listdir(tmp_path) == ["recording.rrd"] and path.read_bytes() == b"old"
    monkeypatch.undo()

    def failing_replace(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(report.os, "replace", failing_replace)
    with pytest.raises(InputError, match="recording.rrd: cannot write .disk full"):  # one line, exit 2
        report.log_run(path, FLIGHTS)
    assert os.listdir(tmp_path) == ["recording.rrd"] and path.read_bytes() == b"old"
    monkeypatch.undo()
    with pytest.raises(InputError, match="does not exist"):
        report.log_run(tmp_path / "no" / "recording.rrd", FLIGHTS)


@pytest.fixture(scope="module")
def yaw_fit():
    config, _ = analytic_config(None, 20.0)
    config = ModelConfig(config.vehicle, config.coefficients, ("N_r", "N_dr"))
    t = np.arange(0, 10, 0.04)
    delta = np.column_stack([0.02 * np.sign(np.sin(1.3 * t)), np.zeros_like(t), np.zeros_like(t)])
    data = [synthetic(config, t, delta, rng=np.random.default_rng(0), measured=("v", "r", "psi"),
                      noise_std={"v": 0.01, "r": 0.002, "psi": 0.002})]  # fmt: skip
    start = config.with_coefficients({"N_r": 0.8 * config.coefficients["N_r"]})
    return config, data, start


def test_fit_recording_has_outputs_iterations_and_comparison(tmp_path, yaw_fit):
    config, data, start = yaw_fit
    iterations = []
    est = identify(data, start, method="ml-gn",
                   callback=lambda k, values, cost: iterations.append((k, list(values), cost)))  # fmt: skip
    path = report.log_fit(tmp_path / "fit.rrd", data, start, est, iterations, compare(est, config))
    rows = _rows(path)
    name = data[0].name
    for s in ("v", "r", "psi"):
        assert rows[f"/outputs/{name}/{s}/measured"] == len(data[0].t) == rows[f"/outputs/{name}/{s}/model"]
    assert rows["/parameters/N_r"] == len(iterations) == rows["/cost"]
    assert rows["/comparison/table"] == 1 and rows["/comparison/error_sigmas"] == 1
    assert os.listdir(tmp_path) == ["fit.rrd"]


def test_fit_outputs_start_from_the_estimates_initial_states(tmp_path, yaw_fit, monkeypatch):
    _, data, start = yaw_fit
    est = identify(data, start, method="ml-gn")
    name = data[0].name
    x0 = est.extra["initial_states"][name]
    moved = dataclasses.replace(est, extra={**est.extra, "initial_states": {name: {**x0, "psi": x0["psi"] + 1.0}}})

    def no_fit(*args, **kwargs):
        raise AssertionError("the initial states were fitted again")

    monkeypatch.setattr(oe, "fit_initial_states", no_fit)
    path = report.log_fit(tmp_path / "fit.rrd", data, start, moved, [])
    psi = _scalars(path, f"/outputs/{name}/psi/model")
    assert psi[0] == pytest.approx(x0["psi"] + 1.0)
    assert _scalars(path, f"/outputs/{name}/r/model")[0] == pytest.approx(x0["r"])
    monkeypatch.undo()
    # without them (or with some missing) the model outputs come from best-fitting ones
    partial = dataclasses.replace(est, extra={**est.extra, "initial_states": {name: {"psi": x0["psi"] + 1.0}}})
    for e in (dataclasses.replace(est, extra={}), partial):
        path = report.log_fit(tmp_path / "fit2.rrd", data, start, e, [])
        expected = oe.predict(data, start.with_coefficients(est.coefficients), e.extra.get("initial_states"))[0]
        assert np.allclose(_scalars(path, f"/outputs/{name}/psi/model"), expected[:, 2])


def test_filter_recording_has_parameter_histories_with_sigma_bounds(tmp_path, yaw_fit):
    _, data, start = yaw_fit
    est = identify(data, start, method="mekf")
    assert est.history_t is not None and "initial_states" not in est.extra
    path = report.log_fit(tmp_path / "fit.rrd", data, start, est, [])
    rows = _rows(path)
    n = len(est.history_t)
    assert n == len(data[0].t)
    for j, p in enumerate(est.free):
        assert rows[f"/parameters/{p}/estimate"] == n == rows[f"/parameters/{p}/plus_sigma"]
        assert rows[f"/parameters/{p}/minus_sigma"] == n and rows[f"/parameters/{p}"] == 0
        mean, std = est.history[:, j], est.history_std[:, j]
        assert np.array_equal(_scalars(path, f"/parameters/{p}/estimate"), mean)
        assert np.allclose(_scalars(path, f"/parameters/{p}/plus_sigma"), mean + std)
        assert np.allclose(_scalars(path, f"/parameters/{p}/minus_sigma"), mean - std)
    assert rows["/cost"] == 0
    assert rows[f"/outputs/{data[0].name}/r/model"] == len(data[0].t)  # fitted initial states


def test_replay(tmp_path, monkeypatch, capsys):
    with pytest.raises(InputError, match="no such recording"):
        report.replay(tmp_path)
    (tmp_path / "recording.rrd").write_bytes(b"")
    monkeypatch.setattr("sys.platform", "linux")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert report.replay(tmp_path) == 0
    assert "rerun " in capsys.readouterr().out
