"""The force and moment the water exerts on a vehicle held in a prescribed motion.

The completed plant's hydrodynamics at a body velocity ν = (u v w p q r), fin angles δ and body
acceleration ν̇ (the rate of the body-axis components), read from the plant itself:

    τ_H = τ_MuJoCo(ν, δ) − M_A(δ) ν̇.

τ_MuJoCo is MuJoCo's ellipsoid fluid model on every fluid geom of the body and of its children
(`qfrc_fluid` on the free joint's six dofs: a free joint's generalized force is the total force
of its subtree and its moment about the joint's origin, so the fins' forces are in it; their
hinges' own entries, the hinge moments, are internal to the vehicle and left out). With the
vehicle turned to MuJoCo's world axes, its linear dofs are the hull axes too. M_A(δ) is the added
mass of hull and fins at their angles, the fins at rest relative to the hull, Σ J_bᵀ M_b J_b
over the bodies with fluid geoms (M_b from MuJoCo's virtual masses, J_b the body's Jacobian): the
inertial force that `Plant` completes MuJoCo with (MuJoCo applies the velocity-dependent
added-mass terms, Munk moment included, itself).

Not in τ_H: weight and buoyancy, the rigid body's inertia M_RB ν̇ + C_RB(ν) ν, the propulsor's
thrust. The completed plant's equations are M_RB ν̇ + C_RB(ν) ν = τ_H + restoring + thrust.
"""

from __future__ import annotations

import mujoco
import numpy as np

from testbed.errors import InputError
from testbed.simulation.plant import Plant
from testbed.simulation.vehicle import FIN_JOINTS, FLIP, hydrostatics

__all__ = ["hydrodynamic_wrench"]

_T6 = np.kron(np.eye(2), FLIP)  # MuJoCo hull axes (FLU) <-> body axes (FRD), for (lin, ang)


def hydrodynamic_wrench(vehicle, nu, fins=None, nu_dot=None) -> np.ndarray:
    """(X Y Z K M N) the water exerts on the vehicle (N, N m), body axes FRD, about the origin of
    the free body (a testbed vehicle's CG), at body velocity `nu` = (u v w p q r) (m/s, rad/s,
    FRD, u absolute), fin angles `fins` (rad; default 0) and body acceleration `nu_dot`
    (default 0). Weight, buoyancy, rigid-body inertia and thrust are not in it (module doc).

    `vehicle` is a `Plant` or an `MjModel` with one free joint (the joint `hull` where there are
    several); `fins` are (delta_r, delta_er, delta_el), the angles of its hinges `rudder`,
    `elevator_right`, `elevator_left` (a body without one of them takes 0 for it). Each argument
    is one row or rows of them (n, ·); rows broadcast; the result has the rows' shape (6,) or
    (n, 6). A plant's own state is left as it is.
    """
    model = vehicle.model if isinstance(vehicle, Plant) else vehicle
    if not isinstance(model, mujoco.MjModel):
        raise InputError(f"vehicle: {type(vehicle).__name__}; expected a Plant or a mujoco.MjModel")
    rig = _Rig(model)
    one = all(a is None or np.ndim(a) == 1 for a in (nu, fins, nu_dot))
    nu = _rows("nu", nu, 6)
    fins = _rows("fins", np.zeros(len(FIN_JOINTS)) if fins is None else fins, len(FIN_JOINTS))
    missing = [FIN_JOINTS[k] for k in np.flatnonzero((rig.fins < 0) & fins.any(0))]
    if missing:
        raise InputError(f"fins: {missing[0]} deflected; expected 0, the MJCF has no hinge {missing[0]!r}")
    nu_dot = _rows("nu_dot", np.zeros(6) if nu_dot is None else nu_dot, 6)
    lengths = {len(a) for a in (nu, fins, nu_dot)} - {1}
    if len(lengths) > 1:
        raise InputError(f"nu, fins, nu_dot: {sorted(lengths)} rows; expected one row or the same number")
    n = lengths.pop() if lengths else 1
    nu, fins, nu_dot = (np.broadcast_to(a, (n, a.shape[1])) for a in (nu, fins, nu_dot))
    out = np.empty((n, 6))
    for i in range(n):
        out[i] = rig.fluid(nu[i], fins[i])
        if nu_dot[i].any():
            out[i] -= rig.added_mass(fins[i]) @ nu_dot[i]
    return out[0] if one else out


def _rows(name: str, value, width: int) -> np.ndarray:
    """`value` as finite rows of `width` numbers, else `InputError`."""
    try:
        a = np.array(value, float)
    except (TypeError, ValueError):
        raise InputError(f"{name}={value!r}; expected numbers") from None
    if a.ndim == 1:
        a = a[None]
    if a.ndim != 2 or a.shape[1] != width or not len(a):
        raise InputError(
            f"{name}: shape {np.shape(value)}; expected {width} values or rows (n, {width}) of them"
        )
    if not np.isfinite(a).all():
        raise InputError(f"{name}: a value is not finite; expected finite numbers")
    return a


class _Rig:
    """The vehicle turned to MuJoCo's world axes (identity attitude), its state set directly."""

    def __init__(self, model: mujoco.MjModel):
        free = [j for j in range(model.njnt) if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE]
        named = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, "hull")
        if named in free:
            free = [named]
        if len(free) != 1:
            raise InputError(
                f"MJCF: {len(free)} free joints; expected one (the vehicle's), or one named 'hull'"
            )
        j = free[0]
        self.model, self.data = model, mujoco.MjData(model)
        self.qadr, self.vadr = int(model.jnt_qposadr[j]), int(model.jnt_dofadr[j])
        self.fins = np.full(len(FIN_JOINTS), -1, np.intp)  # qpos address of each fin's hinge, -1: none
        for i, f in enumerate(FIN_JOINTS):
            k = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, f)
            if k >= 0 and model.jnt_type[k] == mujoco.mjtJoint.mjJNT_HINGE:
                self.fins[i] = model.jnt_qposadr[k]
        self.hydrostatics = hydrostatics(model)
        self._added = {}

    def _pose(self, fins: np.ndarray) -> None:
        d = self.data
        d.qpos[:] = self.model.qpos0
        d.qpos[self.qadr + 3 : self.qadr + 7] = (1.0, 0.0, 0.0, 0.0)
        d.qpos[self.fins[self.fins >= 0]] = fins[self.fins >= 0]
        d.qvel[:] = 0.0

    def fluid(self, nu: np.ndarray, fins: np.ndarray) -> np.ndarray:
        """MuJoCo's fluid force on the free joint, FRD."""
        m, d = self.model, self.data
        self._pose(fins)
        d.qvel[self.vadr : self.vadr + 6] = _T6 @ nu
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_fwdVelocity(m, d)
        return _T6 @ d.qfrc_fluid[self.vadr : self.vadr + 6]

    def added_mass(self, fins: np.ndarray) -> np.ndarray:
        """M_A(δ), 6×6 about the free body's origin, FRD (kept per fin angles)."""
        key = tuple(fins)
        if key not in self._added:
            m, d, h = self.model, self.data, self.hydrostatics
            self._pose(fins)
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            jp, jr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
            M = np.zeros((6, 6))
            dofs = slice(self.vadr, self.vadr + 6)
            for b, Mb in zip(h.bodies, h.added_mass):
                mujoco.mj_jacBody(m, d, jp, jr, b)
                Rt = d.xmat[b].reshape(3, 3).T
                J = np.vstack([Rt @ jp[:, dofs], Rt @ jr[:, dofs]])  # body b's own axes
                M += J.T @ Mb @ J
            self._added[key] = _T6 @ M @ _T6
        return self._added[key]
