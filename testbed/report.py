"""Rerun recordings: runs (3D replay, trails, time series) and fits (outputs, iterations, comparison).

Everything is logged in bulk with `send_columns` on a `time` timeline (s). Each flight's tab has
a world view (north-east-down, with the trail) whose eye follows the vehicle, and a close-up in
body axes where the vehicle stands still and the fins turn, each with a pointer along its chord
beside a grey neutral one, so a 1 deg deflection moves the pointer's tip 1 cm.

Files are written to a unique temporary name and renamed, so a recording is whole or absent. The
recording id is derived from the title and the data (same run, same id); the file is not
byte-identical between runs, because Rerun stamps every chunk and row with a time-based id, but
its decoded contents are. `replay` opens one in the Rerun viewer, or says how when there is no
display.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import shutil
import subprocess
import sys
import uuid
from pathlib import Path

import mujoco
import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from testbed.errors import InputError, atomic_file
from testbed.model import IX, STATES
from testbed.vehicle import FINS, FLIP, load_model

UNITS = {"u": "m/s", "v": "m/s", "w": "m/s", "p": "rad/s", "q": "rad/s", "r": "rad/s",
         "phi": "rad", "theta": "rad", "psi": "rad", "z": "m"}  # fmt: skip
PANELS = {"velocity": ("u", "v", "w"), "rates": ("p", "q", "r"), "attitude": ("phi", "theta", "psi"),
          "depth": ("z",)}  # fmt: skip


def _recording_id(title: str, *parts) -> str:
    """A recording id (UUID) from the title and the logged data: the same run gives the same id,
    and two different runs never share one (the viewer would merge them)."""
    h = hashlib.sha256(title.encode())
    for part in parts:
        if isinstance(part, np.ndarray):
            a = np.ascontiguousarray(part)
            h.update(f"{a.dtype.str}{a.shape}".encode())
            h.update(a.data)
        else:
            h.update(repr(part).encode())
    return str(uuid.UUID(bytes=h.digest()[:16], version=5))


@contextlib.contextmanager
def _recording(path: str | os.PathLike, title: str, recording_id: str):
    """Yield a recording stream saving to a unique temporary sibling of `path` (send the
    blueprint last, inside the block), renamed to `path` when the block finishes; on any
    exception (Ctrl-C included) the temporary file is removed, so a recording is whole or absent
    (`testbed.errors.atomic_file`; the file sink writes while we log).

    No wall-clock start time is sent: the same data give the same decoded contents.
    """
    with atomic_file(path) as tmp:
        rec = rr.RecordingStream("testbed", recording_id=recording_id, send_properties=False)
        try:
            rec.save(str(tmp))
            rec.send_recording_name(title)
            yield rec
            rec.flush()
        finally:
            rec.disconnect()


def _scalars(rec, entity: str, index, values: np.ndarray) -> None:
    """One scalar series; `index` a `TimeColumn` (shared by every series of a flight)."""
    rec.send_columns(entity, indexes=[index], columns=rr.Scalars.columns(scalars=np.asarray(values, float)))


def _time(t: np.ndarray) -> rr.TimeColumn:
    return rr.TimeColumn("time", duration=np.asarray(t, float))


def _quat_wxyz_to_xyzw(q: np.ndarray) -> np.ndarray:
    return np.array([q[1], q[2], q[3], q[0]])


def _euler_quat(phi: np.ndarray, theta: np.ndarray, psi: np.ndarray) -> np.ndarray:
    """Quaternions (N, 4; x, y, z, w) of the body-to-NED rotation Rz(ψ) Ry(θ) Rx(φ)."""
    cr, sr = np.cos(phi / 2), np.sin(phi / 2)
    cp, sp = np.cos(theta / 2), np.sin(theta / 2)
    cy, sy = np.cos(psi / 2), np.sin(psi / 2)
    return np.column_stack([sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
                            cr * cp * sy - sr * sp * cy, cr * cp * cy + sr * sp * sy])  # fmt: skip


def _geometry(mjcf):
    """Hull and fin blades in SPEC body axes: the hull's [(centre, half sizes, quaternion)], and
    per fin its origin, hinge axis and blades [(centre, half sizes, quaternion)] in its frame."""
    model = load_model(mjcf)
    hull_body = model.body("hull").id

    def geoms_of(body):
        out = []
        for g in np.flatnonzero(model.geom_bodyid == body):
            R = np.empty(9)
            mujoco.mju_quat2Mat(R, model.geom_quat[g])
            q = np.empty(4)
            mujoco.mju_mat2Quat(q, (FLIP @ R.reshape(3, 3) @ FLIP).ravel())
            out.append((FLIP @ model.geom_pos[g], model.geom_size[g].copy(), _quat_wxyz_to_xyzw(q)))
        return out

    hull = geoms_of(hull_body)
    fins = {}
    for f in FINS:
        j = model.joint(f).id
        body = model.jnt_bodyid[j]
        fins[f] = (FLIP @ model.body_pos[body], FLIP @ model.jnt_axis[j], geoms_of(body))
    return hull, fins


POINTER = 0.6  # m: the fin pointers, long enough that 1 deg moves their tip 1 cm


def _ellipsoids(geoms, color) -> rr.Ellipsoids3D:
    return rr.Ellipsoids3D(centers=[c for c, _, _ in geoms], half_sizes=[s for _, s, _ in geoms],
                           quaternions=[q for _, _, q in geoms], colors=[color], fill_mode="solid")  # fmt: skip


def _run_views(root: str, name: str, start: np.ndarray, heading: float) -> rrb.Horizontal:
    """A flight's tab: the world view (trail; the eye follows the vehicle), the close-up in body
    axes (the vehicle at rest, the fins and their pointers turning), and the time series."""
    c, s = np.cos(heading), np.sin(heading)
    behind = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ np.array([-9.0, -5.0, -3.5])
    world = rrb.Spatial3DView(
        origin="/", contents=[f"{root}/vehicle/**", f"{root}/trail"], name=f"{name}: world (NED)",
        eye_controls=rrb.EyeControls3D(position=start + behind, look_target=start, eye_up=(0.0, 0.0, -1.0),
                                       tracking_entity=f"{root}/vehicle"))  # fmt: skip
    body = rrb.Spatial3DView(
        origin=f"{root}/vehicle", contents=[f"{root}/vehicle/**"], name=f"{name}: fins (body axes)",
        eye_controls=rrb.EyeControls3D(position=(-3.4, 1.6, -1.1), look_target=(-1.0, 0.0, 0.0),
                                       eye_up=(0.0, 0.0, -1.0)))  # fmt: skip
    series = [rrb.TimeSeriesView(origin=f"{root}/states", contents=[f"{root}/states/{s}/**" for s in group],
                                 name=f"{name}: {panel}") for panel, group in PANELS.items()]  # fmt: skip
    series.append(rrb.TimeSeriesView(origin=root, contents=[f"{root}/fins/**", f"{root}/commands/**"],
                                     name=f"{name}: fins and commands"))  # fmt: skip
    return rrb.Horizontal(rrb.Vertical(world, body), rrb.Vertical(*series), column_shares=[3, 2], name=name)


def _flight_parts(f) -> list:
    parts = [f.name, f.t, f.truth, f.measured, f.fins, f.fins_measured, f.position]
    for k in sorted(f.commands):
        parts += [k, np.asarray(f.commands[k])]
    return parts


def log_run(path, flights, mjcf=None, title: str = "testbed run", recording_id: str | None = None) -> Path:
    """A recording of the flights of a run: 3D replay with fin deflections, trails, time series.

    `recording_id` defaults to one derived from the title and the flights, so the same run
    always gets the same id (see `_recording_id`).
    """
    if recording_id is None:
        recording_id = _recording_id(title, *[part for f in flights for part in _flight_parts(f)])
    hull, fins = _geometry(mjcf)
    tabs = []
    with _recording(path, title, recording_id) as rec:
        rec.log("/", rr.ViewCoordinates.RIGHT_HAND_Z_DOWN, static=True)  # north, east, down
        for flight in flights:
            root = f"/{flight.name}"
            t = _time(flight.t)
            x = flight.truth
            quats = _euler_quat(x[:, IX["phi"]], x[:, IX["theta"]], x[:, IX["psi"]])
            rec.send_columns(f"{root}/vehicle", indexes=[t],
                             columns=rr.Transform3D.columns(translation=flight.position, quaternion=quats))  # fmt: skip
            rec.log(f"{root}/vehicle/hull", _ellipsoids(hull, (160, 165, 170)), static=True)
            for k, (name, (origin, axis, blades)) in enumerate(fins.items()):
                angle = flight.fins[:, k]
                q = np.column_stack([np.outer(np.sin(angle / 2), axis), np.cos(angle / 2)])
                rec.send_columns(f"{root}/vehicle/{name}", indexes=[t], columns=rr.Transform3D.columns(
                    translation=np.tile(origin, (len(angle), 1)), quaternion=q))  # fmt: skip
                rec.log(f"{root}/vehicle/{name}/blades", _ellipsoids(blades, (220, 90, 25)), static=True)
                # a pointer along each blade's chord, aft: it turns with the fin; its neutral
                # position is drawn in the body frame, so the deflection is the angle between them
                aft = np.array([-POINTER, 0.0, 0.0])
                rec.log(f"{root}/vehicle/{name}/pointer", rr.LineStrips3D(
                    [[c, c + aft] for c, _, _ in blades], colors=[(220, 90, 25)], radii=0.008), static=True)  # fmt: skip
                rec.log(f"{root}/vehicle/{name}_neutral", rr.LineStrips3D(
                    [[origin + c, origin + c + aft] for c, _, _ in blades], colors=[(120, 120, 120)],
                    radii=0.004), static=True)  # fmt: skip
            rec.log(f"{root}/trail", rr.LineStrips3D([flight.position], colors=[(60, 160, 230)]), static=True)
            for j, s in enumerate(STATES):
                _scalars(rec, f"{root}/states/{s}/truth", t, flight.truth[:, j])
                _scalars(rec, f"{root}/states/{s}/measured", t, flight.measured[:, j])
            for j, s in enumerate(("delta_r", "delta_er", "delta_el")):
                _scalars(rec, f"{root}/fins/{s}/actual", t, flight.fins[:, j])
                _scalars(rec, f"{root}/fins/{s}/measured", t, flight.fins_measured[:, j])
            for name, values in flight.commands.items():
                _scalars(rec, f"{root}/commands/{name}", t, values)
            tabs.append(_run_views(root, flight.name, flight.position[0], float(x[0, IX["psi"]])))
        rec.send_blueprint(rrb.Blueprint(rrb.Tabs(*tabs), collapse_panels=True))
    return Path(path)


def log_fit(path, experiments, config, estimate, iterations, comparison=None,
            recording_id: str | None = None) -> Path:  # fmt: skip
    """A recording of a fit: measured vs model outputs, parameters per iteration (or over time for
    the filters), cost, and the comparison with the analytic model.

    The model outputs start from the estimate's `extra["initial_states"]` when it has them (the
    output-error methods), else from best-fitting initial states. `recording_id` defaults to one
    derived from the method, the data and the estimate.
    """
    title = f"testbed fit ({estimate.method})"
    history_t = getattr(estimate, "history_t", None)
    if recording_id is None:
        recording_id = _recording_id(title, *[part for e in experiments for part in (e.name, e.t, e.y, e.inputs)],
                                     tuple(estimate.free), np.asarray(estimate.values, float), history_t)  # fmt: skip
    from testbed.estimators.outputerror import predict

    fitted = config.with_coefficients(estimate.coefficients)
    try:
        outputs = predict(experiments, fitted, estimate.extra.get("initial_states"))
    except (InputError, np.linalg.LinAlgError, ValueError):
        outputs = [None] * len(experiments)  # a model that cannot be simulated: log the rest
    views = []
    with _recording(path, title, recording_id) as rec:
        for e, y in zip(experiments, outputs):
            t = _time(e.t)
            for j, s in enumerate(e.measured):
                _scalars(rec, f"/outputs/{e.name}/{s}/measured", t, e.y[:, j])
                if y is not None:
                    _scalars(rec, f"/outputs/{e.name}/{s}/model", t, y[:, j])
            views.append(rrb.Vertical(*[rrb.TimeSeriesView(origin=f"/outputs/{e.name}/{s}", name=f"{e.name}: {s}")
                                        for s in e.measured], name=e.name))  # fmt: skip
        if history_t is not None:
            t = _time(history_t)
            for j, n in enumerate(estimate.free):
                mean, std = estimate.history[:, j], estimate.history_std[:, j]
                _scalars(rec, f"/parameters/{n}/estimate", t, mean)
                _scalars(rec, f"/parameters/{n}/plus_sigma", t, mean + std)
                _scalars(rec, f"/parameters/{n}/minus_sigma", t, mean - std)
        elif iterations:
            k = rr.TimeColumn("iteration", sequence=np.array([i for i, _, _ in iterations]))
            values = np.array([v for _, v, _ in iterations])
            for j, n in enumerate(estimate.free):
                _scalars(rec, f"/parameters/{n}", k, values[:, j])
            _scalars(rec, "/cost", k, [c for _, _, c in iterations])
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
        rec.send_blueprint(rrb.Blueprint(rrb.Tabs(*views), collapse_panels=True))
    return Path(path)


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
