"""The vehicle: load and check an MJCF submerged body, and read its constants.

An MJCF body is usable by testbed when it has a body `hull` with a free joint `hull` whose frame
origin is the CG of the whole vehicle (x forward, y port, z up: MuJoCo is z-up), hinge joints
`rudder`, `elevator_right`, `elevator_left` (no other joints), each through the origin of a
child body of `hull`, driven by position servos of the same names, a motor `thruster`, and
`fluidshape="ellipsoid"` geoms on the hull and the fins (which carry its hydrodynamics and,
here, its displaced volume; a fin's on its hinge axis). `check_model` names what is missing.
The body axes (FRD: x forward, y starboard, z down) are the MuJoCo hull axes turned half a turn
about x: `FLIP = diag(1, -1, -1)`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from testbed.errors import InputError
from testbed.models.linear import MAX_SPEED, MIN_SPEED, Vehicle

__all__ = [
    "FIN_JOINTS",
    "FLIP",
    "MAX_SPEED",
    "MIN_SPEED",
    "FinLimits",
    "Hydrostatics",
    "added_mass",
    "buoyancy_centre",
    "check_model",
    "constants",
    "cruise_speed",
    "default_mjcf",
    "fin_limits",
    "fin_rate_limit",
    "fluid_frames",
    "fluid_geoms",
    "hydrostatics",
    "load_model",
    "motion_transform",
    "rigid_body_mass",
    "quaternion_matrix",
    "semi_axes",
    "skew",
    "trim_speed",
    "vehicles",
    "volume",
]

FIN_JOINTS = ("rudder", "elevator_right", "elevator_left")
FLIP = np.diag([1.0, -1.0, -1.0])  # MuJoCo hull axes (FLU) <-> body axes (FRD); also ENU-ish world <-> NED


def vehicles() -> Path:
    """The folder of the bundled vehicle models: the source tree's `assets/mjcf/`, which the
    build ships in the wheel as `testbed/vehicles/` (pyproject.toml's package-dir)."""
    package = Path(__file__).resolve().parents[1]
    shipped = package / "vehicles"
    return shipped if shipped.is_dir() else package.parent / "assets" / "mjcf"


def default_mjcf() -> Path:
    """The bundled torpedo."""
    return vehicles() / "torpedo.xml"


def load_model(path: str | Path | None = None) -> mujoco.MjModel:
    """Compile `path` (default: the bundled torpedo) and check it has what the plant needs."""
    path = Path(path) if path is not None else default_mjcf()
    if path.is_dir():
        raise InputError(f"{path}: is a folder; expected an MJCF file")
    if not path.is_file():
        raise InputError(
            f"{path}: is not a regular file; expected an MJCF file"
            if path.exists()
            else f"{path}: no such MJCF file"
        )
    try:
        model = mujoco.MjModel.from_xml_path(str(path))
    except ValueError as exc:
        first = " ".join(str(exc).split())[:200]
        raise InputError(f"{path}: not a valid MJCF ({first})") from None
    check_model(model, str(path))
    return model


def check_model(model: mujoco.MjModel, source: str = "MJCF") -> None:
    """Raise `InputError` naming the first missing or wrong element the plant relies on.

    The one check for the plant and the analytic model alike: `load_model` runs it, and so do
    `Plant` and `analytic.analytic_model` on a model passed in (it may have been changed).
    """

    def need(kind, name, what):
        if mujoco.mj_name2id(model, kind, name) < 0:
            raise InputError(f"{source}: no {what} named {name!r}; expected {_NEEDS}")

    need(mujoco.mjtObj.mjOBJ_BODY, "hull", "body")
    need(mujoco.mjtObj.mjOBJ_JOINT, "hull", "joint")
    hull, body = model.joint("hull"), model.body("hull").id
    if mujoco.mjtJoint(int(hull.type[0])) != mujoco.mjtJoint.mjJNT_FREE or hull.bodyid[0] != body:
        raise InputError(f"{source}: joint 'hull' must be the free joint of body 'hull'")
    fin_bodies = []
    for fin in FIN_JOINTS:
        need(mujoco.mjtObj.mjOBJ_JOINT, fin, "hinge joint")
        j = model.joint(fin)
        if mujoco.mjtJoint(int(j.type[0])) != mujoco.mjtJoint.mjJNT_HINGE:
            raise InputError(f"{source}: joint {fin!r} must be a hinge")
        b = int(j.bodyid[0])
        if model.body_parentid[b] != body or b in fin_bodies:
            raise InputError(
                f"{source}: joint {fin!r} is on body {model.body(b).name!r}; expected a "
                "body of its own, a child of 'hull'"
            )
        if np.abs(j.pos).max() > 1e-9:
            raise InputError(
                f'{source}: joint {fin!r} pos="{" ".join(f"{x:g}" for x in j.pos)}"; '
                "expected 0 0 0, the hinge through its body's origin"
            )
        fin_bodies.append(b)
        need(mujoco.mjtObj.mjOBJ_ACTUATOR, fin, "position actuator")
        a = model.actuator(fin)
        if a.trnid[0] != j.id or mujoco.mjtTrn(int(a.trntype[0])) != mujoco.mjtTrn.mjTRN_JOINT:
            raise InputError(f"{source}: actuator {fin!r} must drive joint {fin!r}")
        kp = float(a.gainprm[0])
        if (
            mujoco.mjtGain(int(a.gaintype[0])) != mujoco.mjtGain.mjGAIN_FIXED
            or mujoco.mjtBias(int(a.biastype[0])) != mujoco.mjtBias.mjBIAS_AFFINE
            or mujoco.mjtDyn(int(a.dyntype[0])) == mujoco.mjtDyn.mjDYN_INTEGRATOR
            or not kp > 0
            or a.biasprm[0] != 0
            or a.biasprm[1] != -kp
        ):
            raise InputError(
                f"{source}: actuator {fin!r} is not a position servo (gainprm[0]={kp:g}, "
                f"biasprm[:2]=({a.biasprm[0]:g}, {a.biasprm[1]:g})); expected a "
                "<position> actuator: gainprm[0] = kp > 0, biasprm[:2] = (0, -kp)"
            )
    if model.njnt != 1 + len(FIN_JOINTS):
        raise InputError(
            f"{source}: {model.njnt} joints; expected only the free joint 'hull' and "
            f"the hinges {', '.join(map(repr, FIN_JOINTS))}"
        )
    need(mujoco.mjtObj.mjOBJ_ACTUATOR, "thruster", "motor actuator")
    thruster = model.actuator("thruster")
    if (
        mujoco.mjtGain(int(thruster.gaintype[0])) != mujoco.mjtGain.mjGAIN_FIXED
        or mujoco.mjtBias(int(thruster.biastype[0])) != mujoco.mjtBias.mjBIAS_NONE
    ):
        raise InputError(
            f"{source}: actuator 'thruster' has a gain or bias of its own; expected a <motor> (force = ctrl)"
        )
    if model.opt.density <= 0:
        raise InputError(f"{source}: option density={model.opt.density}; expected > 0 (a fluid)")
    if not np.intersect1d(fluid_geoms(model), _geom_on(model, "hull")).size:
        raise InputError(f"{source}: body 'hull' has no geom with fluidshape=\"ellipsoid\"")
    h = hydrostatics(model)
    for b, centre in zip(h.bodies, h.centroid):
        if b != body and b not in fin_bodies:
            raise InputError(
                f"{source}: body {model.body(b).name!r} has fluid geoms; expected "
                "fluid geoms on the hull and the fins only"
            )
        if b != body:
            fin = FIN_JOINTS[fin_bodies.index(b)]
            axis = model.joint(fin).axis / np.linalg.norm(model.joint(fin).axis)
            if np.linalg.norm(np.cross(axis, centre)) > 1e-9:
                raise InputError(
                    f"{source}: fin {fin!r}: its fluid geoms' volume centre "
                    f"({' '.join(f'{x:g}' for x in centre)}) is off its hinge axis; "
                    "expected on it"
                )
    M = rigid_body_mass(model)
    if np.abs(M[:3, 3:]).max() > 1e-6 * M[0, 0]:
        raise InputError(
            f"{source}: body 'hull': its frame origin is not the vehicle's CG; "
            "expected the CG of the whole vehicle, fins included"
        )


_NEEDS = (
    "a body 'hull' with free joint 'hull', hinge joints and position actuators 'rudder', "
    "'elevator_right', 'elevator_left', a motor 'thruster', ellipsoid fluid geoms"
)


def trim_speed(speed) -> float:
    """`speed` as a trim speed (m/s): from `MIN_SPEED` to `MAX_SPEED`, else `InputError`."""
    try:
        value = float(speed)
    except (TypeError, ValueError):
        raise InputError(f"speed={speed!r}; expected a number (m/s)") from None
    if not MIN_SPEED <= value <= MAX_SPEED:
        raise InputError(f"speed={speed}; expected a trim speed of {MIN_SPEED:g} to {MAX_SPEED:g} m/s")
    return value


def _geom_on(model, body):
    return np.flatnonzero(model.geom_bodyid == model.body(body).id)


def fluid_geoms(model: mujoco.MjModel) -> np.ndarray:
    """Indices of the geoms with `fluidshape="ellipsoid"` (geom_fluid[:, 0] is its switch)."""
    return np.flatnonzero(model.geom_fluid[:, 0] > 0)


def fluid_frames(model: mujoco.MjModel) -> list[tuple]:
    """Per fluid geom, in MuJoCo hull axes with the fins at 0: (g, fin index or None, Q, p,
    hinge point, hinge axis (unit)), Q hull-from-geom and p the geom's centre; the hinge the line
    its fin's joint turns it about (None, None on the hull). Fluid geoms are on the hull or a fin
    (`check_model`)."""
    hull = model.body("hull").id
    fin_of = {int(model.joint(f).bodyid[0]): k for k, f in enumerate(FIN_JOINTS)}
    out = []
    for g in fluid_geoms(model):
        b = int(model.geom_bodyid[g])
        Ql, pl = quaternion_matrix(model.geom_quat[g]), model.geom_pos[g]
        if b == hull:
            out.append((g, None, Ql, pl, None, None))
            continue
        j = model.joint(FIN_JOINTS[fin_of[b]]).id
        Q0 = quaternion_matrix(model.body_quat[b])
        axis = Q0 @ (model.jnt_axis[j] / np.linalg.norm(model.jnt_axis[j]))
        hinge = model.body_pos[b] + Q0 @ model.jnt_pos[j]  # the joint turns the fin about its anchor
        out.append((g, fin_of[b], Q0 @ Ql, model.body_pos[b] + Q0 @ pl, hinge, axis))
    return out


def semi_axes(model: mujoco.MjModel, g: int) -> np.ndarray:
    """The equivalent ellipsoid MuJoCo's fluid model uses for geom `g` (its semi-axes, m)."""
    size, kind = model.geom_size[g], mujoco.mjtGeom(int(model.geom_type[g]))
    if kind == mujoco.mjtGeom.mjGEOM_SPHERE:
        return np.full(3, size[0])
    if kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
        return np.array([size[0], size[0], size[1] + size[0]])
    if kind == mujoco.mjtGeom.mjGEOM_CYLINDER:
        return np.array([size[0], size[0], size[1]])
    if kind in (mujoco.mjtGeom.mjGEOM_ELLIPSOID, mujoco.mjtGeom.mjGEOM_BOX):
        return np.array(size[:3])
    raise InputError(
        f"geom {model.geom(g).name!r}: fluid geom type {kind} is not supported; "
        "expected sphere, capsule, cylinder, ellipsoid or box"
    )


def volume(model: mujoco.MjModel, g: int) -> float:
    """Displaced volume of fluid geom `g`: its equivalent ellipsoid's."""
    return float(4.0 / 3.0 * np.pi * np.prod(semi_axes(model, g)))


@dataclass(frozen=True)
class Hydrostatics:
    """Per body of the tree: its fluid geoms' added mass and displaced volume, in its own frame."""

    bodies: np.ndarray  # (nb,) body ids that carry fluid geoms
    added_mass: np.ndarray  # (nb, 6, 6) about the body origin, body axes, order (lin, ang)
    volume: np.ndarray  # (nb,) m^3
    centroid: np.ndarray  # (nb, 3) centre of the displaced volume, body frame


def hydrostatics(model: mujoco.MjModel) -> Hydrostatics:
    """Group the fluid geoms by body: added mass (from `geom_fluid`, times density) and volume.

    Geom g's added mass is diagonal in its own frame at its centre; seen from its body's origin
    it is `Xᵀ diag(m_A, I_A) X` with X the motion transform from body to geom velocities.
    """
    rho = model.opt.density
    geoms = fluid_geoms(model)
    bodies = np.unique(model.geom_bodyid[geoms])
    M = np.zeros((len(bodies), 6, 6))
    V = np.zeros(len(bodies))
    C = np.zeros((len(bodies), 3))
    for g in geoms:
        k = int(np.searchsorted(bodies, model.geom_bodyid[g]))
        p = model.geom_pos[g]
        X = motion_transform(quaternion_matrix(model.geom_quat[g]), p)
        M[k] += X.T @ np.diag(rho * model.geom_fluid[g, 6:12]) @ X
        v = volume(model, g)
        C[k] += v * p
        V[k] += v
    return Hydrostatics(bodies, M, V, C / V[:, None])


def skew(a: np.ndarray) -> np.ndarray:
    """[a]× so that skew(a) @ b = a × b."""
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def quaternion_matrix(quat) -> np.ndarray:
    """The 3×3 rotation matrix of a unit quaternion (w, x, y, z), MuJoCo's convention."""
    R = np.empty(9)
    mujoco.mju_quat2Mat(R, np.asarray(quat, float))
    return R.reshape(3, 3)


def motion_transform(Q: np.ndarray, p: np.ndarray) -> np.ndarray:
    """X = [[Qᵀ, −Qᵀ[p]×], [0, Qᵀ]]: a frame's velocity (v, ω) from its parent's, in its own axes.

    The frame sits at `p` with axes `Q` (parent-from-frame), both in the parent's axes: a rigid
    point at p moves with v + ω × p. A 6×6 mass matrix M of the frame seen from the parent is
    `Xᵀ M X` (the same kinetic energy ½ νᵀ Xᵀ M X ν).
    """
    X = np.zeros((6, 6))
    X[:3, :3] = X[3:, 3:] = Q.T
    X[:3, 3:] = -Q.T @ skew(p)
    return X


def cruise_speed(model: mujoco.MjModel) -> float:
    """The vehicle's cruise speed (custom numeric `cruise_speed`, else 1 body length per second)."""
    i = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_NUMERIC, "cruise_speed")
    if i >= 0:
        return float(model.numeric_data[model.numeric_adr[i]])
    return float(2 * semi_axes(model, int(_geom_on(model, "hull")[0])).max())


def fin_rate_limit(model: mujoco.MjModel) -> float:
    """Fin slew-rate limit, rad/s (custom numeric `fin_rate_limit`, else unlimited)."""
    i = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_NUMERIC, "fin_rate_limit")
    return float(model.numeric_data[model.numeric_adr[i]]) if i >= 0 else np.inf


@dataclass(frozen=True)
class FinLimits:
    """What the fins' servos allow, read from the MJCF (`fin_limits`)."""

    angle: float  # rad: the fins' stop nearest to 0, which the autopilots clip their commands to (±)
    rate: float  # rad/s: the slew-rate limit (inf: none)


def fin_limits(model: mujoco.MjModel) -> FinLimits:
    """The fins' limits as the plant applies them: the servos' control ranges (`ctrlrange` of the
    actuators `rudder`, `elevator_right`, `elevator_left`; the smallest |bound| of the three, as
    the autopilots clip symmetrically; inf where none is limited) and `fin_rate_limit`."""
    ids = [model.actuator(f).id for f in FIN_JOINTS]
    bounds = [np.abs(model.actuator_ctrlrange[i]).min() for i in ids if model.actuator_ctrllimited[i]]
    return FinLimits(angle=float(min(bounds, default=np.inf)), rate=fin_rate_limit(model))


def rigid_body_mass(model: mujoco.MjModel) -> np.ndarray:
    """6×6 rigid-body mass matrix of the whole vehicle about its CG, body axes (FRD), fins at 0."""
    M = _spatial_sum(model, lambda d, b: _body_rigid(model, d, b))
    return M


def added_mass(model: mujoco.MjModel) -> np.ndarray:
    """6×6 added-mass matrix (M_A, positive) of all fluid geoms about the CG, body axes (FRD)."""
    h = hydrostatics(model)
    lookup = {int(b): h.added_mass[k] for k, b in enumerate(h.bodies)}
    return _spatial_sum(model, lambda d, b: lookup.get(b))


def _body_rigid(model, data, b):
    """Body b's rigid-body 6×6 about its own origin, its own axes: diag(m, I_c) at its CoM c,
    moved to the origin (`[[m, −m[c]×], [m[c]×, I_c − m[c]×²]]`)."""
    R = quaternion_matrix(model.body_iquat[b])
    I = R @ np.diag(model.body_inertia[b]) @ R.T  # about the body's CoM, body axes
    X = motion_transform(np.eye(3), model.body_ipos[b])
    return X.T @ np.block([[model.body_mass[b] * np.eye(3), np.zeros((3, 3))], [np.zeros((3, 3)), I]]) @ X


def _spatial_sum(model, per_body):
    """Σ over the hull's subtree of per-body 6×6 matrices moved to the hull frame, FRD axes.

    Uses the zero pose (fins at 0); the hull frame origin is the CG by construction.
    """
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    hull = model.body("hull").id
    Rh, ph = data.xmat[hull].reshape(3, 3), data.xpos[hull]
    total = np.zeros((6, 6))
    for b in range(model.nbody):
        if b != hull and model.body_rootid[b] != hull:
            continue
        Mb = per_body(data, b)
        if Mb is None:
            continue
        R = Rh.T @ data.xmat[b].reshape(3, 3)  # hull from body
        X = motion_transform(R, Rh.T @ (data.xpos[b] - ph))  # body velocity from hull velocity
        total += X.T @ Mb @ X
    F = np.kron(np.eye(2), FLIP)
    return F @ total @ F


def constants(model: mujoco.MjModel, speed: float) -> Vehicle:
    """The linear model's known constants: mass, inertias about the CG, W, B, centre of buoyancy, U."""
    speed = trim_speed(speed)
    M = rigid_body_mass(model)
    g = float(np.linalg.norm(model.opt.gravity))
    xb = buoyancy_centre(model)
    V = hydrostatics(model).volume.sum()
    return Vehicle(
        mass=float(M[0, 0]),
        Ix=float(M[3, 3]),
        Iy=float(M[4, 4]),
        Iz=float(M[5, 5]),
        weight=float(M[0, 0]) * g,
        buoyancy=float(model.opt.density * V * g),
        xB=float(xb[0]),
        yB=float(xb[1]),
        zB=float(xb[2]),
        speed=float(speed),
    )


def buoyancy_centre(model: mujoco.MjModel) -> np.ndarray:
    """Centre of the displaced volume relative to the CG, body axes (FRD), fins at 0."""
    h = hydrostatics(model)
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    hull = model.body("hull").id
    Rh, ph = data.xmat[hull].reshape(3, 3), data.xpos[hull]
    c = np.zeros(3)
    for b, v, cb in zip(h.bodies, h.volume, h.centroid):
        c += v * (Rh.T @ (data.xpos[b] + data.xmat[b].reshape(3, 3) @ cb - ph))
    return FLIP @ (c / h.volume.sum())
