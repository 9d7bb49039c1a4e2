"""Rerun recordings: runs (3D replay, trails, time series) and fits (outputs, iterations, comparison).

Everything is logged in bulk with `send_columns` on a `time` timeline (s); the world view is
north-east-down. Files are written to a temporary name and renamed, so a recording is whole or
absent. `replay` opens one in the Rerun viewer, or says how when there is no display.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np
import rerun as rr
import rerun.blueprint as rrb
from scipy.spatial.transform import Rotation

from testbed.errors import InputError
from testbed.model import STATES
from testbed.vehicle import FINS, FLIP, load_model

UNITS = {"u": "m/s", "v": "m/s", "w": "m/s", "p": "rad/s", "q": "rad/s", "r": "rad/s",
         "phi": "rad", "theta": "rad", "psi": "rad", "z": "m"}  # fmt: skip
PANELS = {"velocity": ("u", "v", "w"), "rates": ("p", "q", "r"), "attitude": ("phi", "theta", "psi"),
          "depth": ("z",)}  # fmt: skip


def _save(rec: rr.RecordingStream, path: Path, blueprint) -> Path:
    """Flush `rec` (saving to a temporary file) and rename it to `path`."""
    rec.send_blueprint(blueprint)
    rec.flush()
    rec.disconnect()
    os.replace(path.with_name(path.name + ".tmp"), path)
    return path


def _open(path: str | os.PathLike, title: str) -> tuple[rr.RecordingStream, Path]:
    path = Path(path)
    if not path.parent.is_dir():
        raise InputError(f"{path}: folder {path.parent} does not exist")
    rec = rr.RecordingStream("testbed")
    rec.save(str(path.with_name(path.name + ".tmp")))
    rec.send_recording_name(title)
    return rec, path


def _scalars(rec, entity: str, t: np.ndarray, values: np.ndarray, timeline="time") -> None:
    index = rr.TimeColumn(timeline, duration=t) if timeline == "time" else rr.TimeColumn(timeline, sequence=t)
    rec.send_columns(entity, indexes=[index], columns=rr.Scalars.columns(scalars=np.asarray(values, float)))


def _quat(R: np.ndarray) -> np.ndarray:
    return Rotation.from_matrix(R).as_quat()  # x, y, z, w


def _geometry(mjcf):
    """Hull and fin blades in SPEC body axes: (hull centre, half sizes), and per fin its origin,
    hinge axis and blades [(centre, half sizes, quaternion)]."""
    model = load_model(mjcf)
    hull_body = model.body("hull").id

    def geoms_of(body):
        out = []
        for g in np.flatnonzero(model.geom_bodyid == body):
            R = np.empty(9)
            mujoco.mju_quat2Mat(R, model.geom_quat[g])
            out.append((FLIP @ model.geom_pos[g], model.geom_size[g].copy(),
                        _quat(FLIP @ R.reshape(3, 3) @ FLIP)))  # fmt: skip
        return out

    hull = geoms_of(hull_body)
    fins = {}
    for f in FINS:
        j = model.joint(f).id
        body = model.jnt_bodyid[j]
        fins[f] = (FLIP @ model.body_pos[body], FLIP @ model.jnt_axis[j], geoms_of(body))
    return hull, fins


def log_run(path, flights, mjcf=None, title: str = "testbed run") -> Path:
    """A recording of the flights of a run: 3D replay with fin deflections, trails, time series."""
    rec, path = _open(path, title)
    rec.log("/", rr.ViewCoordinates.RIGHT_HAND_Z_DOWN, static=True)  # north, east, down
    hull, fins = _geometry(mjcf)
    tabs = []
    for flight in flights:
        root = f"/{flight.name}"
        t = rr.TimeColumn("time", duration=flight.t)
        phi, theta, psi = flight.truth[:, 6], flight.truth[:, 7], flight.truth[:, 8]
        quats = Rotation.from_euler("ZYX", np.column_stack([psi, theta, phi])).as_quat()
        rec.send_columns(f"{root}/vehicle", indexes=[t],
                         columns=rr.Transform3D.columns(translation=flight.position, quaternion=quats))  # fmt: skip
        rec.log(f"{root}/vehicle/hull", rr.Ellipsoids3D(
            centers=[c for c, _, _ in hull], half_sizes=[s for _, s, _ in hull],
            quaternions=[q for _, _, q in hull], colors=[(160, 165, 170)], fill_mode="solid"), static=True)  # fmt: skip
        for k, (name, (origin, axis, blades)) in enumerate(fins.items()):
            angle = flight.fins[:, k]
            q = np.column_stack([np.outer(np.sin(angle / 2), axis), np.cos(angle / 2)])
            rec.send_columns(f"{root}/vehicle/{name}", indexes=[t], columns=rr.Transform3D.columns(
                translation=np.tile(origin, (len(angle), 1)), quaternion=q))  # fmt: skip
            rec.log(f"{root}/vehicle/{name}/blades", rr.Ellipsoids3D(
                centers=[c for c, _, _ in blades], half_sizes=[s for _, s, _ in blades],
                quaternions=[q for _, _, q in blades], colors=[(220, 90, 25)], fill_mode="solid"), static=True)  # fmt: skip
        rec.log(f"{root}/trail", rr.LineStrips3D([flight.position], colors=[(60, 160, 230)]), static=True)
        for j, s in enumerate(STATES):
            _scalars(rec, f"{root}/states/{s}/truth", flight.t, flight.truth[:, j])
            _scalars(rec, f"{root}/states/{s}/measured", flight.t, flight.measured[:, j])
        for j, s in enumerate(("delta_r", "delta_er", "delta_el")):
            _scalars(rec, f"{root}/fins/{s}/actual", flight.t, flight.fins[:, j])
            _scalars(rec, f"{root}/fins/{s}/measured", flight.t, flight.fins_measured[:, j])
        for name, values in flight.commands.items():
            _scalars(rec, f"{root}/commands/{name}", flight.t, values)
        tabs.append(rrb.Horizontal(
            rrb.Spatial3DView(origin="/", contents=[f"{root}/**"], name=f"{flight.name} 3D"),
            rrb.Vertical(*[rrb.TimeSeriesView(origin=f"{root}/states", contents=[f"{root}/states/{s}/**" for s in group],
                                              name=f"{flight.name}: {panel}")
                           for panel, group in PANELS.items()],
                         rrb.TimeSeriesView(origin=root, contents=[f"{root}/fins/**", f"{root}/commands/**"],
                                            name=f"{flight.name}: fins and commands")),
            name=flight.name))  # fmt: skip
    return _save(rec, path, rrb.Blueprint(rrb.Tabs(*tabs), collapse_panels=True))


def log_fit(path, experiments, config, estimate, iterations, comparison=None) -> Path:
    """A recording of a fit: measured vs model outputs, parameters per iteration (or over time for
    the filters), cost, and the comparison with the analytic model."""
    from testbed.estimators.outputerror import predict

    rec, path = _open(path, f"testbed fit ({estimate.method})")
    views = []
    fitted = config.with_coefficients(estimate.coefficients)
    try:
        outputs = predict(experiments, fitted)
    except (InputError, np.linalg.LinAlgError, ValueError):
        outputs = [None] * len(experiments)  # a model that cannot be simulated: log the rest
    for e, y in zip(experiments, outputs):
        for j, s in enumerate(e.measured):
            _scalars(rec, f"/outputs/{e.name}/{s}/measured", e.t, e.y[:, j])
            if y is not None:
                _scalars(rec, f"/outputs/{e.name}/{s}/model", e.t, y[:, j])
        views.append(rrb.Vertical(*[rrb.TimeSeriesView(origin=f"/outputs/{e.name}/{s}", name=f"{e.name}: {s}")
                                    for s in e.measured], name=e.name))  # fmt: skip
    history_t = getattr(estimate, "history_t", None)
    if history_t is not None:
        for j, n in enumerate(estimate.free):
            mean, std = estimate.history[:, j], estimate.history_std[:, j]
            _scalars(rec, f"/parameters/{n}/estimate", history_t, mean)
            _scalars(rec, f"/parameters/{n}/plus_sigma", history_t, mean + std)
            _scalars(rec, f"/parameters/{n}/minus_sigma", history_t, mean - std)
    elif iterations:
        k = np.array([i for i, _, _ in iterations])
        values = np.array([v for _, v, _ in iterations])
        for j, n in enumerate(estimate.free):
            _scalars(rec, f"/parameters/{n}", k, values[:, j], timeline="iteration")
        _scalars(rec, "/cost", k, [c for _, _, c in iterations], timeline="iteration")
    views.append(rrb.TimeSeriesView(origin="/parameters", name="parameters"))
    if comparison is not None:
        rows = comparison.rows()
        rel = [r["relative_error"] if r["relative_error"] is not None else 0.0 for r in rows]
        sig = [r["error_sigmas"] if r["error_sigmas"] is not None else 0.0 for r in rows]
        rec.log("/comparison/relative_error", rr.BarChart(np.array(rel, float)), static=True)
        rec.log("/comparison/error_sigmas", rr.BarChart(np.array(sig, float)), static=True)
        rec.log("/comparison/table", rr.TextDocument("```\n" + comparison.table() + "\n```",
                                                     media_type=rr.MediaType.MARKDOWN), static=True)  # fmt: skip
        views.append(rrb.Vertical(rrb.BarChartView(origin="/comparison/relative_error"),
                                  rrb.BarChartView(origin="/comparison/error_sigmas"),
                                  rrb.TextDocumentView(origin="/comparison/table"), name="comparison"))  # fmt: skip
    return _save(rec, path, rrb.Blueprint(rrb.Tabs(*views), collapse_panels=True))


def replay(run) -> int:
    """Open a run's `recording.rrd` (or an .rrd file) in the Rerun viewer."""
    run = Path(run)
    path = run / "recording.rrd" if run.is_dir() else run
    if not path.is_file():
        raise InputError(f"{path}: no such recording; expected a run directory or an .rrd file")
    viewer = shutil.which("rerun") or str(Path(sys.executable).with_name("rerun"))
    headless = sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    if headless or not Path(viewer).exists():
        print(f"no display here: on a machine with one, run `rerun {path}`; or serve it to a "
              f"browser with `rerun --serve-web {path}`")  # fmt: skip
        return 0
    subprocess.Popen([viewer, str(path)], start_new_session=True)
    print(f"opened {path} in the Rerun viewer")
    return 0
