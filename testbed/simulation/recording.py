"""Rerun recordings of runs, and what every recording shares.

A run has two tabs per flight: the replay — a world view (north-east-down, with the trail) whose
eye follows the vehicle, a close-up in body axes where the vehicle stands still and the fins
turn, each with a pointer along its chord beside a grey neutral one (a 1 deg deflection moves the
pointer's tip 1 cm), and the fin angles and depth with their commands — and the other states.
Everything is logged in bulk with `send_columns` on a `time` timeline (s). Every series has a
fixed style per role (`STYLE`), the same in every tab of every recording; each plot shows one
quantity, with its unit in the title and its commands on the same axes; a key line replaces the
legends, which would cover the data.

Files are written to a unique temporary name and renamed, so a recording is whole or absent. The
recording id is derived from the title and the data (same run, same id); the file is not
byte-identical between runs, because Rerun stamps every chunk and row with a time-based id, but
its decoded contents are.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import uuid
from pathlib import Path

import mujoco
import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from testbed.outputs import atomic_file
from testbed.models.linear import INPUTS, IX, STATES
from testbed.simulation.flight import FIN_COMMANDS
from testbed.simulation.vehicle import FIN_JOINTS, FLIP, load_model, quaternion_matrix

__all__ = [
    "STYLE",
    "axis_range",
    "data_id",
    "euler_quaternions",
    "log_run",
    "panel_title",
    "recording",
    "series",
    "time_column",
    "x_range",
]

# Every series keeps one style per role, in every tab of every recording: measured values thin
# and light, the truth (or the fitted model) bold, commands as steps. Role -> (RGB, width in UI points).
STYLE = {
    "measured": ((150, 160, 175), 1.0),
    "truth": ((25, 90, 200), 1.75),
    "model": ((205, 45, 45), 1.75),
    "command": ((240, 140, 20), 1.5),
    "fin command": ((140, 70, 190), 1.5),
    "estimate": ((25, 90, 200), 2.5),
    "σ band": ((140, 175, 225), 1.0),
    "analytic": ((240, 140, 20), 1.5),
    "truth fit": ((40, 160, 80), 1.5),
    "cost": ((25, 90, 200), 2.5),
}
# The plotted quantities (the model states and fin angles): title and unit.
QUANTITIES = {
    "u": ("surge speed u", "m/s"),
    "v": ("sway speed v", "m/s"),
    "w": ("heave speed w", "m/s"),
    "p": ("roll rate p", "rad/s"),
    "q": ("pitch rate q", "rad/s"),
    "r": ("yaw rate r", "rad/s"),
    "phi": ("roll φ", "rad"),
    "theta": ("pitch θ", "rad"),
    "psi": ("heading ψ", "rad"),
    "z": ("depth z", "m"),
    "delta_r": ("rudder δr", "rad"),
    "delta_er": ("right elevator δer", "rad"),
    "delta_el": ("left elevator δel", "rad"),
}
# A flight's panels: beside the 3D views the fins and the depth (what its commands drive), and
# in a tab of their own the other states, three to a row. The plots label an axis step only
# where it is some 20 px tall: at 1600 x 900 those beside the 3D views have room for about six
# steps, those of the states tab for eight (`axis_range`).
REPLAY_PANELS = ("delta_r", "delta_er", "delta_el", "z")
STATE_PANELS = ("u", "v", "w", "p", "q", "r", "phi", "theta", "psi")
# Each command is drawn on the axes of the quantity it commands (same unit); others get a panel.
COMMAND_PANELS = {
    "depth": ("z",),
    "hold_depth": ("z",),
    "roll": ("phi",),
    "pitch": ("theta",),
    "yaw_rate": ("r",),
    "rudder": ("delta_r",),
    "elevators": ("delta_er", "delta_el"),
    "fin_r": ("delta_r",),
    "fin_er": ("delta_er",),
    "fin_el": ("delta_el",),
}
# Commands with no quantity of their own to share axes with: their panel's title.
OTHER_COMMANDS = {"differential": "differential elevator command δa = (δer − δel)/2 (rad)"}
# The key lines under the plots, which say what the styles mean.
RUN_KEY = (
    "thin grey: measured · bold blue: true · orange: the experiment's commands · "
    "purple: fin commands (autopilot)"
)


def axis_range(values, intervals: int = 8) -> tuple[float, float]:
    """A y range for the finite `values`: the narrowest [a, b] around them whose ends are multiples
    of one power of ten s at most `intervals` steps of s apart, widened by 4 % on each side. The
    plots label the multiples of a power of ten only, and only where they are far enough apart:
    data from -0.35 to 0.35 in a panel with room for four labelled steps would show a single
    label (0), and three (-1, 0, 1) with `axis_range(values, 4)`."""
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    lo, hi = (float(v.min()), float(v.max())) if v.size else (0.0, 0.0)
    span = hi - lo if hi > lo else max(abs(hi), 1.0)
    s = 10.0 ** (np.floor(np.log10(span)) - 1)
    while True:
        a, b = np.floor(lo / s + 1e-9) * s, np.ceil(hi / s - 1e-9) * s
        if b - a < s / 2:  # a constant on a multiple of s
            a, b = a - s, b + s
        if (b - a) / s <= intervals + 1e-9:
            pad = 0.04 * (b - a)  # labels at the very ends would be clipped
            return float(f"{a - pad:.12g}"), float(f"{b + pad:.12g}")
        s *= 10.0


def panel_title(key: str) -> str:
    title, unit = QUANTITIES[key]
    return f"{title} ({unit})"


def data_id(title: str, *parts) -> str:
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
def recording(path: str | os.PathLike, title: str, recording_id: str, force: bool = False):
    """Yield a recording stream saving to a unique temporary sibling of `path` (send the
    blueprint last, inside the block), renamed to `path` when the block finishes; on any
    exception (Ctrl-C included) the temporary file is removed, so a recording is whole or absent
    (`testbed.outputs.atomic_file`; the file sink writes while we log). An existing file at `path`
    is an `InputError` unless `force` (then replaced).

    No wall-clock start time is sent: the same data give the same decoded contents.
    """
    with atomic_file(path, force) as tmp:
        rec = rr.RecordingStream("testbed", recording_id=recording_id, send_properties=False)
        try:
            rec.save(str(tmp))
            rec.send_recording_name(title)
            yield rec
            rec.flush()
        finally:
            rec.disconnect()


def series(rec, entity: str, index, values, roles, names=None, step: bool = False) -> None:
    """Scalar series on one entity, one column of `values` (N, k) per role, with their style
    (static: it holds at every time, on every timeline); `index` a `TimeColumn`."""
    values = np.asarray(values, float).reshape(len(values), -1)
    # where several samples share a pixel, their minimum and maximum are drawn: the noise's true envelope
    rec.log(
        entity,
        rr.SeriesLines(
            colors=[STYLE[r][0] for r in roles],
            widths=[STYLE[r][1] for r in roles],
            names=list(names or roles),
            aggregation_policy="MinMax",
            interpolation_mode="StepAfter" if step else None,
        ),
        static=True,
    )
    rec.send_columns(entity, indexes=[index], columns=rr.Scalars.columns(scalars=values))


def time_column(t: np.ndarray) -> rr.TimeColumn:
    return rr.TimeColumn("time", duration=np.asarray(t, float))


def _quat_wxyz_to_xyzw(q: np.ndarray) -> np.ndarray:
    return np.array([q[1], q[2], q[3], q[0]])


def euler_quaternions(phi: np.ndarray, theta: np.ndarray, psi: np.ndarray) -> np.ndarray:
    """Quaternions (N, 4; x, y, z, w) of the body-to-NED rotation Rz(ψ) Ry(θ) Rx(φ)."""
    cr, sr = np.cos(phi / 2), np.sin(phi / 2)
    cp, sp = np.cos(theta / 2), np.sin(theta / 2)
    cy, sy = np.cos(psi / 2), np.sin(psi / 2)
    return np.column_stack(
        [
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
            cr * cp * cy + sr * sp * sy,
        ]
    )


def _geometry(mjcf):
    """Hull and fin blades in body axes (FRD): the hull's [(centre, half sizes, quaternion)], and
    per fin its origin, hinge axis and blades [(centre, half sizes, quaternion)] in its frame."""
    model = load_model(mjcf)
    hull_body = model.body("hull").id

    def geoms_of(body):
        out = []
        for g in np.flatnonzero(model.geom_bodyid == body):
            q = np.empty(4)
            mujoco.mju_mat2Quat(q, (FLIP @ quaternion_matrix(model.geom_quat[g]) @ FLIP).ravel())
            out.append((FLIP @ model.geom_pos[g], model.geom_size[g].copy(), _quat_wxyz_to_xyzw(q)))
        return out

    hull = geoms_of(hull_body)
    fins = {}
    for f in FIN_JOINTS:
        j = model.joint(f).id
        body = model.jnt_bodyid[j]
        fins[f] = (FLIP @ model.body_pos[body], FLIP @ model.jnt_axis[j], geoms_of(body))
    return hull, fins


POINTER = 0.6  # m: the fin pointers, long enough that 1 deg moves their tip 1 cm


def _ellipsoids(geoms, color) -> rr.Ellipsoids3D:
    return rr.Ellipsoids3D(
        centers=[c for c, _, _ in geoms],
        half_sizes=[s for _, s, _ in geoms],
        quaternions=[q for _, _, q in geoms],
        colors=[color],
        fill_mode="solid",
    )


# The world view's eye orbits the tracked entity at 1.5 times the radius of the sphere around its
# bounding box (the Rerun viewer's rule), so the eye follows a ring of radius RING in the body's
# x-y plane: its box is nearly the same at any heading, the eye stays ≈ 2.1 RING (5.3 m) away,
# and the ring tilts with pitch and roll (roll of the round hull shows only through it and the fins).
RING = 2.5  # m
# The eye's starting offset, in body axes: behind, to port and above, at that same distance, so the
# view is the same whether the viewer keeps this offset or takes the ring's box.
EYE = np.array([-3.0, -2.0, -1.5]) / np.linalg.norm([-3.0, -2.0, -1.5]) * 1.5 * np.sqrt(2.0) * RING


def _key() -> rrb.TextDocumentView:
    """The line saying what the styles mean (a view has one parent: one per container)."""
    return rrb.TextDocumentView(origin="/key", name="key", titlebar=False)


def _run_views(root: str, name: str, start: np.ndarray, heading: float, commands, ranges) -> list:
    """A flight's two tabs. `name`: the world view (its eye follows the vehicle's ring; the trail), the
    close-up in body axes (the vehicle at rest, the fins and their pointers turning), the fin
    angles and the depth with their commands; `name: states`: the other states. `ranges`: each
    panel's y range."""
    c, s = np.cos(heading), np.sin(heading)
    behind = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ EYE
    world = rrb.Spatial3DView(
        origin="/",
        contents=[f"{root}/vehicle/**", f"{root}/trail"],
        name=f"{name}: world (NED)",
        eye_controls=rrb.EyeControls3D(
            position=start + behind,
            look_target=start,
            eye_up=(0.0, 0.0, -1.0),
            tracking_entity=f"{root}/vehicle/ring",
        ),
    )
    body = rrb.Spatial3DView(
        origin=f"{root}/vehicle",
        contents=[f"{root}/vehicle/**", f"- {root}/vehicle/ring"],
        name=f"{name}: fins (body axes)",
        eye_controls=rrb.EyeControls3D(
            position=(-3.4, 1.6, -1.1), look_target=(-1.0, 0.0, 0.0), eye_up=(0.0, 0.0, -1.0)
        ),
    )

    def panel(key):
        group = "fins" if key in INPUTS else "states"
        given = [f"{root}/commands/{c}" for c in commands if key in COMMAND_PANELS.get(c, ())]
        return rrb.TimeSeriesView(
            origin=root,
            contents=[f"{root}/{group}/{key}", *given],
            name=panel_title(key),
            axis_y=rrb.ScalarAxis(range=ranges[key]),
            plot_legend=rrb.PlotLegend(visible=False),
        )

    plots = [panel(k) for k in REPLAY_PANELS]
    if others := [c for c in commands if c not in COMMAND_PANELS]:
        plots.append(
            rrb.TimeSeriesView(
                origin=root,
                contents=[f"{root}/commands/{c}" for c in others],
                name=" · ".join(OTHER_COMMANDS.get(c, c) for c in others),
                plot_legend=rrb.PlotLegend(visible=False),
            )
        )
    replay = rrb.Horizontal(
        rrb.Vertical(world, body, row_shares=[3, 2]),
        rrb.Vertical(*plots, _key(), row_shares=[6] * len(plots) + [1]),
        column_shares=[5, 4],
        name=name,
    )
    states = rrb.Vertical(
        rrb.Grid(*[panel(k) for k in STATE_PANELS], grid_columns=3),
        _key(),
        row_shares=[24, 1],
        name=f"{name}: states",
    )
    return [replay, states]


def _flight_parts(f) -> list:
    parts = [f.name, f.t, f.truth, f.measured, f.fins, f.fins_measured, f.position]
    for k in sorted(f.commands):
        parts += [k, np.asarray(f.commands[k])]
    return parts


def _held(a: np.ndarray) -> np.ndarray:
    """Each NaN (a sample a slower sensor did not take) replaced by the last value above it: a
    sensor's samples drawn held until its next (a column of NaN stays NaN)."""
    a = np.asarray(a, float)
    rows = np.where(np.isnan(a), 0, np.arange(len(a))[:, None])
    np.maximum.accumulate(rows, axis=0, out=rows)
    return a[rows, np.arange(a.shape[1])]


def log_run(
    path, flights, mjcf=None, title: str = "testbed run", recording_id: str | None = None, force: bool = False
) -> Path:
    """A recording of the flights of a run: 3D replay with fin deflections, trails, time series;
    an existing file at `path` is an `InputError` unless `force` (then replaced).

    `recording_id` defaults to one derived from the title and the flights, so the same run
    always gets the same id (see `data_id`).
    """
    if recording_id is None:
        recording_id = data_id(title, *[part for f in flights for part in _flight_parts(f)])
    hull, fins = _geometry(mjcf)
    tabs = []
    with recording(path, title, recording_id, force) as rec:
        rec.log("/", rr.ViewCoordinates.RIGHT_HAND_Z_DOWN, static=True)  # north, east, down
        rec.log("/key", rr.TextDocument(RUN_KEY, media_type=rr.MediaType.MARKDOWN), static=True)
        for flight in flights:
            root = f"/{flight.name}"
            t = time_column(flight.t)
            x = flight.truth
            quats = euler_quaternions(x[:, IX["phi"]], x[:, IX["theta"]], x[:, IX["psi"]])
            rec.send_columns(
                f"{root}/vehicle",
                indexes=[t],
                columns=rr.Transform3D.columns(translation=flight.position, quaternion=quats),
            )
            rec.log(f"{root}/vehicle/hull", _ellipsoids(hull, (160, 165, 170)), static=True)
            a = np.linspace(0.0, 2 * np.pi, 73)
            ring = np.column_stack([RING * np.cos(a), RING * np.sin(a), np.zeros_like(a)])
            rec.log(
                f"{root}/vehicle/ring",
                rr.LineStrips3D([ring], colors=[(120, 150, 190)], radii=0.01),
                static=True,
            )
            for k, (name, (origin, axis, blades)) in enumerate(fins.items()):
                angle = flight.fins[:, k]
                q = np.column_stack([np.outer(np.sin(angle / 2), axis), np.cos(angle / 2)])
                rec.send_columns(
                    f"{root}/vehicle/{name}",
                    indexes=[t],
                    columns=rr.Transform3D.columns(
                        translation=np.tile(origin, (len(angle), 1)), quaternion=q
                    ),
                )
                rec.log(f"{root}/vehicle/{name}/blades", _ellipsoids(blades, (220, 90, 25)), static=True)
                # a pointer along each blade's chord, aft: it turns with the fin; its neutral
                # position is drawn in the body frame, so the deflection is the angle between them
                aft = np.array([-POINTER, 0.0, 0.0])
                rec.log(
                    f"{root}/vehicle/{name}/pointer",
                    rr.LineStrips3D(
                        [[c, c + aft] for c, _, _ in blades], colors=[(220, 90, 25)], radii=0.008
                    ),
                    static=True,
                )
                rec.log(
                    f"{root}/vehicle/{name}_neutral",
                    rr.LineStrips3D(
                        [[origin + c, origin + c + aft] for c, _, _ in blades],
                        colors=[(120, 120, 120)],
                        radii=0.004,
                    ),
                    static=True,
                )
            rec.log(f"{root}/trail", rr.LineStrips3D([flight.position], colors=[(60, 160, 230)]), static=True)
            measured = _held(flight.measured)
            for j, s in enumerate(STATES):
                series(
                    rec,
                    f"{root}/states/{s}",
                    t,
                    np.column_stack([measured[:, j], flight.truth[:, j]]),
                    ("measured", "truth"),
                )
            for j, s in enumerate(INPUTS):
                series(
                    rec,
                    f"{root}/fins/{s}",
                    t,
                    np.column_stack([flight.fins_measured[:, j], flight.fins[:, j]]),
                    ("measured", "truth"),
                    ("measured", "actual"),
                )
            commands = [k for k in sorted(flight.commands) if not np.isnan(flight.commands[k]).all()]
            for k in commands:  # a command never given (NaN throughout) draws nothing: not logged
                series(
                    rec,
                    f"{root}/commands/{k}",
                    t,
                    flight.commands[k],
                    ("fin command" if k in FIN_COMMANDS else "command",),
                    (f"{k} command",),
                    step=True,
                )
            plotted = {
                **{s: (measured[:, j], x[:, j]) for j, s in enumerate(STATES)},
                **{s: (flight.fins_measured[:, j], flight.fins[:, j]) for j, s in enumerate(INPUTS)},
            }
            ranges = {
                key: axis_range(
                    np.concatenate(
                        [*values, *[flight.commands[c] for c in commands if key in COMMAND_PANELS.get(c, ())]]
                    ),
                    6 if key in REPLAY_PANELS else 8,
                )
                for key, values in plotted.items()
            }
            tabs += _run_views(
                root, flight.name, flight.position[0], float(x[0, IX["psi"]]), commands, ranges
            )
        rec.send_blueprint(
            rrb.Blueprint(
                rrb.Tabs(*tabs, active_tab=0),
                rrb.TimePanel(state="collapsed", timeline="time"),
                collapse_panels=True,
            )
        )
    return Path(path)


def x_range(index: str, first, last) -> rrb.TimeAxis:
    """The x axis of a plot from `first` to `last` on timeline `index` (seconds, or iterations),
    not the whole timeline: other data on it (another experiment's) run longer."""
    at = rrb.TimeRangeBoundary.absolute
    if index == "iteration":
        start, end = at(seq=int(first)), at(seq=int(last))
    else:
        start, end = at(seconds=float(first)), at(seconds=float(last))
    return rrb.TimeAxis(view_range=rr.TimeRange(start=start, end=end))
