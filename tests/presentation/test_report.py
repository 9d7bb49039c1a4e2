"""Rerun recordings read back with rerun.chunk.RrdReader: entities, row counts, values, styles,
and the blueprint (views, what they show, on which timeline, the tracked entity)."""

import dataclasses
import os
import re
from collections import Counter, defaultdict

import numpy as np
import pyarrow as pa
import pytest
import rerun.chunk
from scipy.spatial.transform import Rotation

from testbed.analysis.comparison import compare
from testbed.data import Experiment, ModelConfig
from testbed.errors import InputError
from testbed.estimators import identify
from testbed.identification import likelihood, prediction
from testbed.identification.prediction import synthetic
from testbed.models.linear import INPUTS, STATES
from testbed.presentation import report
from testbed.simulation import recording
from testbed.simulation.analytic import analytic_config

FIN_NAMES = ("rudder", "elevator_right", "elevator_left")


def _rows(path) -> Counter:
    rows = Counter()
    for chunk in rerun.chunk.RrdReader(path).stream():
        rows[str(chunk.entity_path)] += chunk.num_rows
    return rows


def _data_columns(chunk) -> dict:
    """The index and component columns of a chunk (not its row ids), by name."""
    rb = chunk.to_record_batch()
    return {
        f.name: rb.column(i)
        for i, f in enumerate(rb.schema)
        if (f.metadata or {}).get(b"rerun:kind") in (b"data", b"index")
    }


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
    """(N, k): the entity's k series."""
    return np.array(_contents(path)[entity, "Scalars:scalars"].to_pylist(), float)


def _logged(path) -> dict:
    """entity -> {"timelines": the timelines of its temporal data, "components": all it has}."""
    out = defaultdict(lambda: {"timelines": set(), "components": set()})
    for chunk in rerun.chunk.RrdReader(path).stream():
        rb = chunk.to_record_batch()
        for f in rb.schema:
            kind = (f.metadata or {}).get(b"rerun:kind")
            key = "timelines" if kind == b"index" else "components" if kind == b"data" else None
            if key:
                out[str(chunk.entity_path)][key].add(f.name)
    return dict(out)


def _blueprint(path) -> dict:
    """Blueprint entity -> its properties (last value of each component), from the recording."""
    out = defaultdict(dict)
    for (entity, column), values in _contents(path, blueprint=True).items():
        if ":" not in column:  # an index (the blueprint's own timeline), not a component
            continue
        value = values.to_pylist()[-1]
        out[entity][column.split(":")[-1]] = (
            value[0] if isinstance(value, list) and len(value) == 1 else value
        )
    return dict(out)


def _views(bp) -> dict:
    """view entity -> kind, name, origin, query (list), and its properties (eye, axes, legend)."""
    views = {}
    for entity, props in bp.items():
        if "class_identifier" in props:
            query = bp.get(f"{entity}/ViewContents", {}).get("query")
            extra = {
                sub.removeprefix(entity + "/"): p for sub, p in bp.items() if sub.startswith(entity + "/")
            }
            views[entity] = {
                "kind": props["class_identifier"],
                "name": props.get("display_name"),
                "origin": props["space_origin"],
                "query": [query] if isinstance(query, str) else list(query),
                **extra,
            }
    return views


def _matches(view, logged) -> set:
    """The logged entities a view's query selects ("$origin", "/**" subtrees, "- " exclusions)."""
    chosen, dropped = set(), set()
    for expr in view["query"]:
        expr = expr.replace("$origin", view["origin"]).strip()
        target = dropped if expr.startswith("- ") else chosen
        expr = expr.removeprefix("- ").removeprefix("+ ").strip()
        if expr.endswith("/**"):
            base = expr[:-3]
            target.update(e for e in logged if e == base or e.startswith(base + "/"))
        else:
            target.update(e for e in logged if e == expr)
    return chosen - dropped


def _tabs(bp) -> dict:
    """The root Tabs container's tabs: display name -> blueprint entity, and the active one's."""
    root = bp["/viewport"]["root_container"]
    root = next(e for e in bp if e.startswith("/container/") and e.endswith(str(_uuid(root))))
    container = bp[root]
    assert container["container_kind"] == 1  # Tabs (ContainerKind)
    names = {bp["/" + c.lstrip("/")]["display_name"]: "/" + c.lstrip("/") for c in container["contents"]}
    return names, "/" + container["active_tab"].lstrip("/")


def _uuid(raw) -> str:
    import uuid

    return str(uuid.UUID(bytes=bytes(raw)))


def test_run_recording_has_the_replay_and_every_series(tmp_path, flights):
    path = recording.log_run(tmp_path / "recording.rrd", flights)
    assert path.exists() and os.listdir(tmp_path) == ["recording.rrd"]
    assert (path.stat().st_mode & 0o777) == 0o666 & ~_umask()
    rows = _rows(path)
    for f in flights:
        n = len(f.t)
        assert rows[f"/{f.name}/vehicle"] == n  # pose over time
        for fin in FIN_NAMES:
            assert rows[f"/{f.name}/vehicle/{fin}"] == n  # deflection over time
            assert rows[f"/{f.name}/vehicle/{fin}/blades"] == 1  # static shape
            assert rows[f"/{f.name}/vehicle/{fin}/pointer"] == 1 == rows[f"/{f.name}/vehicle/{fin}_neutral"]
        assert (
            rows[f"/{f.name}/vehicle/hull"]
            == 1
            == rows[f"/{f.name}/vehicle/ring"]
            == rows[f"/{f.name}/trail"]
        )
        for j, s in enumerate(STATES):  # one entity per state: measured and true, one row per sample
            assert rows[f"/{f.name}/states/{s}"] == n + 1  # + the static style
            both = np.column_stack([f.measured[:, j], f.truth[:, j]])
            assert np.array_equal(_scalars(path, f"/{f.name}/states/{s}"), both)
        for j, s in enumerate(INPUTS):
            both = np.column_stack([f.fins_measured[:, j], f.fins[:, j]])
            assert np.array_equal(_scalars(path, f"/{f.name}/fins/{s}"), both)
        for name in ("depth", "rudder", "fin_r", "mystery"):
            assert np.array_equal(_scalars(path, f"/{f.name}/commands/{name}")[:, 0], f.commands[name])
        assert f"/{f.name}/commands/roll" not in rows  # never given (NaN throughout): nothing to draw


def _umask() -> int:
    umask = os.umask(0)
    os.umask(umask)
    return umask


def test_attitude_quaternions_are_z_y_x_euler_angles():
    rng = np.random.default_rng(3)
    phi, theta, psi = rng.uniform(-3, 3, (3, 50))
    q = recording.euler_quaternions(phi, theta, psi)
    expected = Rotation.from_euler("ZYX", np.column_stack([psi, theta, phi])).as_quat()
    assert np.allclose(np.abs(np.sum(q * expected, axis=1)), 1.0, atol=1e-12)


@pytest.fixture(scope="module")
def run_rrd(tmp_path_factory, flights):
    return recording.log_run(tmp_path_factory.mktemp("run") / "recording.rrd", flights)


def test_world_view_tracks_an_entity_with_geometry_at_a_steady_distance(run_rrd, flights):
    bp, contents = _blueprint(run_rrd), _contents(run_rrd)
    views = _views(bp)
    for f in flights:
        (world,) = [
            v
            for v in views.values()
            if v["kind"] == "3D" and v["origin"] == "/" and f"/{f.name}/vehicle/**" in v["query"]
        ]
        eye = world["EyeControls3D"]
        tracked = eye["tracking_entity"]
        assert tracked.startswith(f"/{f.name}/vehicle/")  # moves with the vehicle's transform
        # it has geometry, so the viewer has a bounding box to follow: it orbits at 1.5 times the
        # radius of the sphere around that box, and starts where that puts it
        (strip,) = contents[tracked, "LineStrips3D:strips"].to_pylist()[0]
        ring = np.array(strip)
        distance = np.linalg.norm(np.subtract(eye["position"], eye["look_target"]))
        assert np.allclose(eye["look_target"], f.position[0])
        half_diagonal = np.linalg.norm(ring.max(0) - ring.min(0)) / 2
        assert 1.5 * half_diagonal == pytest.approx(distance, rel=0.01) and 4.0 < distance < 8.0
        for heading in np.linspace(0, np.pi, 7):  # its box, so the distance, is the same at any heading
            turned = ring @ Rotation.from_euler("z", heading).as_matrix().T
            assert np.linalg.norm(turned.max(0) - turned.min(0)) / 2 == pytest.approx(half_diagonal, rel=0.03)
        # the body-axes close-up: eye on the fins, ring left out
        (close,) = [v for v in views.values() if v["kind"] == "3D" and v["origin"] == f"/{f.name}/vehicle"]
        assert (
            f"- /{f.name}/vehicle/ring" in close["query"] and "tracking_entity" not in close["EyeControls3D"]
        )
        look, pos = close["EyeControls3D"]["look_target"], close["EyeControls3D"]["position"]
        assert np.linalg.norm(np.subtract(pos, look)) < 4.0 and look[0] < 0  # the stern, close


def test_every_view_shows_logged_entities_on_the_timeline_the_recording_opens_on(run_rrd):
    bp, logged = _blueprint(run_rrd), _logged(run_rrd)
    assert bp["/time_panel"]["timeline"] == "time"
    tabs, active = _tabs(bp)
    assert list(tabs) == ["horizontal", "horizontal: states", "vertical", "vertical: states"]
    assert active == tabs["horizontal"]
    views = _views(bp)
    for v in views.values():
        shown = _matches(v, logged)
        assert shown, f"{v['name']} shows nothing"
        if v["kind"] == "TimeSeries":
            assert all(
                "Scalars:scalars" in logged[e]["components"] and "time" in logged[e]["timelines"]
                for e in shown
            ), v["name"]
    # every view and container has exactly one parent (the viewer drops the layout otherwise)
    children = [c for e, p in bp.items() if e.startswith("/container/") for c in p["contents"]]
    assert (
        len(children) == len(set(children)) == len(views) + sum(e.startswith("/container/") for e in bp) - 1
    )


def test_series_have_one_fixed_style_per_role(tmp_path, run_rrd, yaw_fit):
    config, data, start = yaw_fit
    est = identify(data, start, method="ml-gn")
    fit = report.log_fit(tmp_path / "fit.rrd", data, start, est, [], compare(est, config))
    for path, roles in (
        (run_rrd, {"states": ("measured", "truth"), "fins": ("measured", "truth")}),
        (fit, {"outputs": ("measured", "model")}),
    ):
        contents = _contents(path)
        styled = {e for e, c in contents if c == "SeriesLines:colors"}
        for (entity, column), values in contents.items():
            if column != "Scalars:scalars":
                continue
            assert entity in styled, entity  # every series is styled, statically
            k = len(values.to_pylist()[0])
            colors = contents[entity, "SeriesLines:colors"].to_pylist()
            widths = contents[entity, "SeriesLines:widths"].to_pylist()
            assert len(colors) == 1 and len(colors[0]) == k == len(widths[0])  # one row: static
            assert len(contents[entity, "SeriesLines:names"].to_pylist()[0]) == k
            group = entity.split("/")[2] if entity.count("/") >= 3 else None
            if group in roles:
                expected = [recording.STYLE[r] for r in roles[group]]
                rgb = [((c >> 24) & 255, (c >> 16) & 255, (c >> 8) & 255) for c in colors[0]]
                assert rgb == [c for c, _ in expected] and widths[0] == pytest.approx(
                    [w for _, w in expected]
                )
    assert (
        recording.STYLE["measured"][1] < recording.STYLE["truth"][1] == recording.STYLE["model"][1]
    )  # thin vs bold


def test_commands_share_axes_only_with_what_they_command_with_units_and_no_legends(run_rrd):
    bp, logged = _blueprint(run_rrd), _logged(run_rrd)
    contents = _contents(run_rrd)
    where = defaultdict(set)  # command -> titles of the plots showing it
    for v in _views(bp).values():
        if v["kind"] != "TimeSeries":
            continue
        shown = _matches(v, logged)
        quantities = {e.split("/")[-1] for e in shown if "/commands/" not in e}
        assert len(quantities) <= 1, v["name"]  # one quantity per plot
        for e in shown:
            if "/commands/" in e:
                where[e.split("/")[-1]].add(v["name"])
        if quantities:
            (q,) = quantities
            assert v["name"] == recording.panel_title(q) and re.search(r"\((m|m/s|rad|rad/s)\)$", v["name"])
        assert v["PlotLegend"]["visible"] is False  # the key line says what the styles mean
        lo, hi = v["ScalarAxis"]["range"] if "ScalarAxis" in v else (-np.inf, np.inf)
        for e in shown:
            values = np.array(contents[e, "Scalars:scalars"].to_pylist(), float)
            assert lo <= np.nanmin(values) and np.nanmax(values) <= hi, (v["name"], e)
    assert where["depth"] == {"depth z (m)"}
    assert where["rudder"] == where["fin_r"] == {"rudder δr (rad)"}
    assert where["mystery"] == {"mystery"}  # a command with no quantity of its own: its own panel


@pytest.mark.parametrize("seed", range(20))
def test_axis_range_holds_the_data_and_ends_on_multiples_of_a_power_of_ten(seed):
    rng = np.random.default_rng(seed)
    scale = 10.0 ** rng.uniform(-4, 5)
    values = rng.normal(rng.uniform(-5, 5) * scale, scale, rng.integers(1, 300))
    for intervals in (4, 8):
        a, b = recording.axis_range(values, intervals)
        assert a <= values.min() and values.max() <= b
        inner_a, inner_b = a + (b - a) / 1.08 * 0.04, b - (b - a) / 1.08 * 0.04  # before the 4 % margins
        s = 10.0 ** np.floor(np.log10((inner_b - inner_a) / intervals) + 1e-9)
        s = s if (inner_b - inner_a) / s <= intervals + 1e-6 else 10 * s
        steps = (inner_b - inner_a) / s
        assert (
            1 - 1e-6 <= steps <= intervals + 1e-6 and abs(steps - round(steps)) < 1e-6
        )  # ends on multiples of s
        assert (
            values.max() - values.min() > (b - a) / 10 / 1.08 or len(set(values)) == 1
        )  # not needlessly wide


def test_axis_range_examples():
    assert recording.axis_range([-0.365, 0.365]) == pytest.approx((-0.432, 0.432))  # 8 steps of 0.1
    assert recording.axis_range([-0.092, 0.087]) == pytest.approx(
        (-0.108, 0.108)
    )  # 2 steps of 0.1, not 19 of 0.01
    assert recording.axis_range([93.7, 104.8]) == pytest.approx((89.2, 110.8))
    assert recording.axis_range([np.nan, 5.0, 5.0]) == pytest.approx((4.892, 5.108))
    assert recording.axis_range([]) == pytest.approx((-0.108, 0.108))


def test_same_run_same_recording(tmp_path, flights, make_flight):
    a = recording.log_run(tmp_path / "a.rrd", flights, title="testbed II seed 1")
    b = recording.log_run(tmp_path / "b.rrd", flights, title="testbed II seed 1")
    c = recording.log_run(tmp_path / "c.rrd", flights, title="testbed II seed 2")
    d = recording.log_run(
        tmp_path / "d.rrd", [make_flight("horizontal", seed=9), flights[1]], title="testbed II seed 1"
    )
    e = recording.log_run(tmp_path / "e.rrd", flights, title="testbed II seed 1", recording_id="mine")

    def rid(p):
        (store,) = rerun.chunk.RrdReader(p).recordings()
        return store.recording_id

    assert rid(a) == rid(b) and len({rid(a), rid(c), rid(d)}) == 3 and rid(e) == "mine"
    # Not byte-identical: Rerun stamps every chunk and row with a time-based id. The contents are.
    ca, cb = _contents(a), _contents(b)
    assert ca.keys() == cb.keys() and all(_same(ca[k], cb[k]) for k in ca)
    assert ("/__properties", "RecordingInfo:start_time") not in ca  # no wall-clock time
    assert ca["/__properties", "RecordingInfo:name"].to_pylist() == [["testbed II seed 1"]]


def test_an_exception_leaves_the_old_recording_and_no_temporary_file(tmp_path, monkeypatch, flights):
    path = tmp_path / "recording.rrd"
    path.write_bytes(b"old")
    calls = []

    def interrupted(*args):
        calls.append(args)
        if len(calls) == 5:
            raise KeyboardInterrupt

    monkeypatch.setattr(recording, "series", interrupted)
    with pytest.raises(InputError, match="recording.rrd: exists; expected a new file name, or force=True"):
        recording.log_run(path, flights)  # a recording there is replaced only when asked for
    assert calls == [] and os.listdir(tmp_path) == ["recording.rrd"] and path.read_bytes() == b"old"
    with pytest.raises(KeyboardInterrupt):
        recording.log_run(path, flights, force=True)
    assert os.listdir(tmp_path) == ["recording.rrd"] and path.read_bytes() == b"old"
    monkeypatch.undo()

    def failing_replace(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(recording.os, "replace", failing_replace)
    with pytest.raises(InputError, match="recording.rrd: cannot write .disk full"):  # one line, exit 2
        recording.log_run(path, flights, force=True)
    assert os.listdir(tmp_path) == ["recording.rrd"] and path.read_bytes() == b"old"
    monkeypatch.undo()
    with pytest.raises(InputError, match="does not exist"):
        recording.log_run(tmp_path / "no" / "recording.rrd", flights)


@pytest.fixture(scope="module")
def yaw_fit():
    config, _ = analytic_config(None, 20.0)
    config = ModelConfig(config.vehicle, config.coefficients, ("N_r", "N_dr"))
    t = np.arange(0, 10, 0.04)
    delta = np.column_stack([0.02 * np.sign(np.sin(1.3 * t)), np.zeros_like(t), np.zeros_like(t)])
    data = [
        synthetic(
            config,
            t,
            delta,
            rng=np.random.default_rng(0),
            measured=("v", "r", "psi"),
            noise_std={"v": 0.01, "r": 0.002, "psi": 0.002},
        )
    ]
    start = config.with_coefficients({"N_r": 0.8 * config.coefficients["N_r"]})
    return config, data, start


def test_ml_fit_opens_on_the_parameters_tab_on_the_iteration_timeline(tmp_path, yaw_fit):
    config, data, start = yaw_fit
    iterations = []
    est = identify(
        data,
        start,
        method="ml-gn",
        callback=lambda step: iterations.append((step.iteration, list(step.values), step.cost)),
    )
    comparison = compare(est, config, est)  # a truth fit (here the same fit) adds its line
    path = report.log_fit(tmp_path / "fit.rrd", data, start, est, iterations, comparison)
    assert os.listdir(tmp_path) == ["fit.rrd"]
    bp, logged, contents = _blueprint(path), _logged(path), _contents(path)
    values = np.array([v for _, v, _ in iterations])
    ks = [k for k, _, _ in iterations]
    for j, n in enumerate(est.free):  # estimate, ∓σ about the final one, analytic, truth fit
        got = _scalars(path, f"/parameters/{n}")
        constant = [
            est.values[j] - est.std[j],
            est.values[j] + est.std[j],
            config.coefficients[n],
            est.values[j],
        ]
        expected = np.column_stack([values[:, j], *[np.full(len(ks), c) for c in constant]])
        assert np.allclose(got, expected) and logged[f"/parameters/{n}"]["timelines"] == {"iteration"}
        assert contents[f"/parameters/{n}", "iteration"].to_pylist() == ks
    cost = np.array([c for _, _, c in iterations])
    above = _scalars(path, "/cost")[:, 0]
    least = cost == cost.min()  # with several starts the least is not always the last
    assert np.allclose(above[~least], np.log10(cost[~least] - cost.min())) and np.all(np.isnan(above[least]))
    assert bp["/time_panel"]["timeline"] == "iteration"
    tabs, active = _tabs(bp)
    assert list(tabs) == ["parameters", "comparison", f"{data[0].name}: outputs (time)"]
    assert active == tabs["parameters"]
    views = _views(bp)
    plots = {v["origin"]: v for v in views.values() if v["kind"] == "TimeSeries"}
    for j, n in enumerate(
        est.free
    ):  # one plot per coefficient, its data in range, x from first to last iteration
        v = plots[f"/parameters/{n}"]
        assert v["name"] == n and _matches(v, logged) == {f"/parameters/{n}"}
        lo, hi = v["ScalarAxis"]["range"]
        analytic = config.coefficients[n]
        assert lo <= min(values[:, j].min(), analytic) and hi >= max(values[:, j].max(), analytic)
        assert v["TimeAxis"]["view_range"] == {"start": ks[0], "end": ks[-1]}
    assert _matches(plots["/cost"], logged) == {"/cost"} and "log" in plots["/cost"]["name"]
    assert all(_matches(v, logged) for v in views.values())


def test_comparison_is_a_table_by_coefficient_name(tmp_path, yaw_fit):
    config, data, start = yaw_fit
    est = identify(data, start, method="ml-gn")
    comparison = compare(est, config, est)
    path = report.log_fit(tmp_path / "fit.rrd", data, start, est, [], comparison)
    ((text,),) = _contents(path)["/comparison/table", "TextDocument:text"].to_pylist()
    lines = [line for line in text.splitlines() if line.startswith("| ")]
    header = [c.strip() for c in lines[0].strip("|").split("|")]
    assert header == [
        "coefficient",
        "analytic",
        "identified",
        "± σ",
        "error (σ)",
        "error (%)",
        "truth fit",
        "model bias (%)",
        "noise (σ)",
    ]
    for row, r in zip(lines[1:], comparison.rows()):
        cells = [c.strip() for c in row.strip("|").split("|")]
        assert cells[0] == f"`{r['name']}`" and float(cells[1]) == pytest.approx(r["analytic"], rel=1e-3)
        assert float(cells[2]) == pytest.approx(r["identified"], rel=1e-3)
        assert float(cells[4].strip("*")) == pytest.approx(r["error_sigmas"], abs=0.05)
        assert cells[4].startswith("**") == (abs(r["error_sigmas"]) > 3)
    assert len(lines) == 1 + len(est.free)
    assert _contents(path)["/comparison/table", "TextDocument:media_type"].to_pylist() == [["text/markdown"]]


def test_validation_metrics_are_a_table_and_a_tab(tmp_path, yaw_fit):
    from testbed.analysis.validation import validate

    config, data, start = yaw_fit
    est = identify(data, start, method="ml-gn")
    validation = validate(data, start.with_coefficients(est.coefficients), config)
    path = report.log_fit(tmp_path / "fit.rrd", data, start, est, [], validation=validation)
    ((text,),) = _contents(path)["/validation/table", "TextDocument:text"].to_pylist()
    rows = [line for line in text.splitlines() if line.startswith("| ") and "---" not in line][1:]
    expected = validation.to_dict()
    assert len(rows) == sum(len(ch) for ch in expected.values())
    for row in rows:
        cells = [c.strip() for c in row.strip("|").split("|")]
        m = expected[cells[0]][cells[1]]
        assert float(cells[2]) == pytest.approx(m["fit_percent"], abs=0.01)
        assert float(cells[3]) == pytest.approx(m["fit_percent_analytic"], abs=0.01)
        assert (cells[-1] == "white") == m["whiteness"]["white"]


def test_fit_outputs_start_from_the_estimates_initial_states(tmp_path, yaw_fit, monkeypatch):
    _, data, start = yaw_fit
    est = identify(data, start, method="ml-gn")
    name = data[0].name
    x0 = est.initial_states[name]
    moved = dataclasses.replace(est, initial_states={name: {**x0, "psi": x0["psi"] + 1.0}})

    def no_fit(*args, **kwargs):
        raise AssertionError("the initial states were fitted again")

    monkeypatch.setattr(likelihood, "fit_initial_states", no_fit)
    path = report.log_fit(tmp_path / "fit.rrd", data, start, moved, [])
    psi = _scalars(path, f"/outputs/{name}/psi")[:, 1]  # (measured, model)
    assert psi[0] == pytest.approx(x0["psi"] + 1.0)
    assert _scalars(path, f"/outputs/{name}/r")[0, 1] == pytest.approx(x0["r"])
    monkeypatch.undo()
    # without them (or with some missing) the model outputs come from best-fitting ones
    partial = dataclasses.replace(est, initial_states={name: {"psi": x0["psi"] + 1.0}})
    for k, e in enumerate((dataclasses.replace(est, initial_states=None), partial)):
        path = report.log_fit(tmp_path / f"fit{k + 2}.rrd", data, start, e, [])
        expected = prediction.predict(data, start.with_coefficients(est.coefficients), e.initial_states)[0]
        assert np.allclose(_scalars(path, f"/outputs/{name}/psi")[:, 1], expected[:, 2])


def test_a_nonlinear_fit_is_recorded_with_the_nonlinear_models_outputs(tmp_path):
    """A nonlinear model config's `ml-gn` fit: each free term per iteration on the parameters tab,
    and the outputs of the nonlinear model flown from the estimate's initial state
    (`nonlinear_prediction.predict_nonlinear`), not the linear model's."""
    from testbed.captive.config import captive_config
    from testbed.identification.nonlinear_prediction import predict_nonlinear
    from testbed.models.nonlinear_flight import fly_nonlinear

    free = ("Y_uv", "N_uv")
    config = dataclasses.replace(captive_config(model="polynomial")[0], free=free, screen=False)
    model, theta = config.nonlinear()
    t = np.arange(151) * 0.02
    fins = np.zeros((len(t), 3))
    fins[(t > 0.4) & (t < 1.4), 0] = np.radians(3.0)
    x = fly_nonlinear(model, theta, t, np.r_[config.vehicle.speed, np.zeros(9)], fins)
    y = x + np.random.default_rng(2).normal(size=x.shape) * 1e-3
    data = [Experiment("turn", t, STATES, y, fins)]
    start = config.with_coefficients({n: 0.8 * config.terms[n] for n in free})
    iterations = []
    est = identify(
        data, start, "ml-gn", start="config",
        callback=lambda step: iterations.append((step.iteration, list(step.values), step.cost)),
    )  # fmt: skip
    path = report.log_fit(tmp_path / "fit.rrd", data, start, est, iterations)
    for j, n in enumerate(free):
        assert np.allclose(_scalars(path, f"/parameters/{n}")[:, 0], [v[j] for _, v, _ in iterations])
    expected = predict_nonlinear(data, start.with_coefficients(est.coefficients), est.initial_states)[0]
    for j, s in enumerate(STATES):
        got = _scalars(path, f"/outputs/turn/{s}")
        assert np.allclose(got[:, 0], y[:, j]) and np.allclose(
            got[:, 1], expected[:, j], rtol=1e-9, atol=1e-12
        ), s


def test_filter_recording_has_parameter_histories_with_sigma_bands_on_time(tmp_path, yaw_fit):
    _, data, start = yaw_fit
    est = identify(data, start, method="mekf")
    assert est.history_t is not None and est.initial_states is None
    path = report.log_fit(tmp_path / "fit.rrd", data, start, est, [])
    rows, bp, logged = _rows(path), _blueprint(path), _logged(path)
    n = len(est.history_t)
    assert n == len(data[0].t)
    for j, p in enumerate(est.free):
        mean, std = est.history[:, j], est.history_std[:, j]
        got = _scalars(path, f"/parameters/{p}")
        assert np.array_equal(got[:, 0], mean) and np.allclose(
            got[:, 1:], np.column_stack([mean - std, mean + std])
        )
        assert logged[f"/parameters/{p}"]["timelines"] == {"time"}
    assert rows["/cost"] == 0
    assert rows[f"/outputs/{data[0].name}/r"] == len(data[0].t) + 1  # fitted initial states; + the style
    assert bp["/time_panel"]["timeline"] == "time"
    tabs, active = _tabs(bp)
    assert active == tabs["parameters"]
    for v in _views(bp).values():  # the x axis ends where the data do
        if v["kind"] == "TimeSeries":
            t = est.history_t if v["origin"].startswith("/parameters/") else data[0].t
            assert v["TimeAxis"]["view_range"] == {"start": round(t[0] * 1e9), "end": round(t[-1] * 1e9)}


def test_replay(tmp_path, monkeypatch, capsys):
    with pytest.raises(InputError, match="no such recording"):
        report.replay(tmp_path)
    (tmp_path / "recording.rrd").write_bytes(b"")
    monkeypatch.setattr("sys.platform", "linux")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert "rerun " in report.replay(tmp_path)
