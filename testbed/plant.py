"""The completed plant: MuJoCo's rigid bodies and fluid forces, plus exactly what MuJoCo lacks.

MuJoCo's ellipsoid fluid model applies the velocity-dependent added-mass terms (Munk moment,
(m_A v) × ω, ...) but not the acceleration-dependent force −M_A ν̇, and no buoyancy. Applying
−M_A ν̇ from the previous step's acceleration (UUV Simulator, Gazebo) is unstable when added mass
is comparable to the body's, so here it goes where it belongs, into the generalized mass.

In hull axes the vehicle's velocity is ν = (v, ω, δ̇) (hull linear and angular velocity, fin
rates). Fin k's velocity in its own axes is X_k(δ_k) ν, and with M_k its 6×6 added mass the
added mass of the whole vehicle is M9(δ) = M_hull + Σ X_kᵀ M_k X_k. The missing force is

    −Σ X_kᵀ M_k d/dt(X_k ν) = −M9 ν̇ − Σ δ̇_k X_kᵀ M_k ∂X_k/∂δ_k ν,

with ν̇ the rate of the hull-axis components (Kirchhoff's equations). X_k is affine in
(cos δ_k, sin δ_k), so both matrices are fixed combinations of nine precomputed 9×9 products
per fin. After `mj_step1` the plant maps M9 to MuJoCo's coordinates (free-joint linear velocity
is in world axes: v = Rᵀ q̇_lin, v̇ = Rᵀ q̈_lin − ω × v), adds it to MuJoCo's mass matrix (CSR
`d.M`, within the tree's sparsity), refactors it, puts the bias and the buoyancy of every fluid
geom (−ρ V g at its volume's centre) in `qfrc_applied`, and lets `mj_step2` finish. The
integrator (Euler or implicitfast) sees the complete mass matrix, so the step is as stable as
MuJoCo's own rigid-body step; with MuJoCo's velocity terms the fluid part is Kirchhoff's
equations for a body in potential flow.
"""

from __future__ import annotations

import math

import mujoco
import numba
import numpy as np

from testbed.errors import InputError
from testbed.model import Vehicle
from testbed.vehicle import (FINS, FLIP, constants, cruise_speed, fin_rate_limit, hydrostatics,
                             load_model, skew)


class Plant:
    """A stateful simulator of the completed plant (state lives in MuJoCo's `MjData`).

    `complete=False` runs plain MuJoCo (no added-mass inertia, no buoyancy), for comparison.
    `rk4=True` integrates the same dynamics with fourth-order Runge-Kutta (four evaluations a
    step, for accuracy studies) instead of the MJCF's integrator.
    """

    def __init__(self, mjcf=None, timestep: float | None = None, complete: bool = True,
                 model: mujoco.MjModel | None = None, rk4: bool = False):  # fmt: skip
        self.model = model if model is not None else load_model(mjcf)
        if timestep is not None:
            if not timestep > 0:
                raise InputError(f"timestep={timestep}; expected > 0 s")
            self.model.opt.timestep = timestep
        self.data = mujoco.MjData(self.model)
        self.complete = complete
        self.rk4 = rk4
        m = self.model
        self.hull = m.body("hull").id
        self._qadr = m.jnt_qposadr[m.joint("hull").id]
        self._vadr = m.jnt_dofadr[m.joint("hull").id]
        self._fin_qadr = np.array([m.jnt_qposadr[m.joint(f).id] for f in FINS])
        self._fin_act = np.array([m.actuator(f).id for f in FINS])
        self._thruster = m.actuator("thruster").id
        self._fin_limit = m.actuator_ctrlrange[self._fin_act].copy()
        self._rate = fin_rate_limit(m)
        self._dofs = np.concatenate([np.arange(self._vadr, self._vadr + 6),
                                     [m.jnt_dofadr[m.joint(f).id] for f in FINS]])  # fmt: skip
        P, self._M_hull, B, c = _added_mass_basis(m)
        self._P = P.transpose(0, 2, 1, 3, 4).reshape(-1, 81)  # rows (fin, j, i), as basis products
        self._buoyancy = -m.opt.density * B * m.opt.gravity  # world force, N
        self._buoyancy_centre = c  # hull axes, m
        # d.M's CSR entries as (row, col) of the 9×9 matrix over self._dofs (the tree's sparsity).
        where = np.full(m.nv, -1)
        where[self._dofs] = np.arange(len(self._dofs))
        rows, cols = np.repeat(np.arange(m.nv), m.M_rownnz), m.M_colind
        if (where[rows] < 0).any() or (where[cols] < 0).any():
            raise InputError("the MJCF has joints beyond the hull's free joint and the three fin "
                             "hinges; expected only those")  # fmt: skip
        self._csr = (where[rows], where[cols])
        self._F = np.zeros(len(self._dofs))
        self.reference = np.zeros(3)  # rate-limited fin servo reference
        self.wrench = np.zeros(6)  # external force and moment at the CG, SPEC body axes (N, N m)
        self.thrust = 0.0
        self.reset()

    # -- state -------------------------------------------------------------------------------

    @property
    def time(self) -> float:
        return float(self.data.time)

    @property
    def timestep(self) -> float:
        return float(self.model.opt.timestep)

    def vehicle_constants(self, speed: float | None = None) -> Vehicle:
        return constants(self.model, speed if speed is not None else cruise_speed(self.model))

    def reset(self, speed: float | None = None, depth: float = 50.0, heading: float = 0.0) -> None:
        """Straight and level at `speed` (default: cruise), fins at 0, thrust = drag at `speed`."""
        speed = cruise_speed(self.model) if speed is None else speed
        if not speed >= 0:
            raise InputError(f"speed={speed}; expected >= 0 m/s")
        m, d = self.model, self.data
        mujoco.mj_resetData(m, d)
        q = np.array([math.cos(heading / 2), 0.0, 0.0, -math.sin(heading / 2)])  # NED yaw = -z turn
        d.qpos[self._qadr:self._qadr + 3] = (0.0, 0.0, -depth)
        d.qpos[self._qadr + 3:self._qadr + 7] = q
        R = np.empty(9)
        mujoco.mju_quat2Mat(R, q)
        d.qvel[self._vadr:self._vadr + 3] = R.reshape(3, 3) @ np.array([speed, 0.0, 0.0])
        self.reference[:] = 0.0
        d.ctrl[:] = 0.0
        mujoco.mj_forward(m, d)
        # The propulsor balances the drag of straight flight at this speed.
        drag = R.reshape(3, 3).T @ d.qfrc_passive[self._vadr:self._vadr + 3]
        self.thrust = max(0.0, -float(drag[0]))
        d.ctrl[self._thruster] = self.thrust

    def set_state(self, qpos: np.ndarray, qvel: np.ndarray) -> None:
        """Set MuJoCo's generalized state (for tests and linearization)."""
        self.data.qpos[:] = qpos
        self.data.qvel[:] = qvel
        mujoco.mj_forward(self.model, self.data)

    def state(self) -> np.ndarray:
        """SPEC state `u v w p q r phi theta psi z` (absolute u; body FRD, earth NED, at the CG)."""
        d = self.data
        quat = d.qpos[self._qadr + 3:self._qadr + 7]
        R = np.empty(9)
        mujoco.mju_quat2Mat(R, quat)
        R = R.reshape(3, 3)
        v = R.T @ d.qvel[self._vadr:self._vadr + 3]
        w = d.qvel[self._vadr + 3:self._vadr + 6]
        # NED-from-FRD is FLIP R FLIP: entries (2,1), (2,2), (2,0), (1,0), (0,0) of it below.
        phi = math.atan2(R[2, 1], R[2, 2])
        theta = -math.asin(max(-1.0, min(1.0, -R[2, 0])))
        psi = math.atan2(-R[1, 0], R[0, 0])
        return np.array([v[0], -v[1], -v[2], w[0], -w[1], -w[2], phi, theta, psi,
                         -d.qpos[self._qadr + 2]])  # fmt: skip

    def position(self) -> np.ndarray:
        """CG position, NED (m)."""
        return FLIP @ self.data.qpos[self._qadr:self._qadr + 3]

    def fin_angles(self) -> np.ndarray:
        """Actual `delta_r, delta_er, delta_el` (rad)."""
        return self.data.qpos[self._fin_qadr].copy()

    # -- dynamics ----------------------------------------------------------------------------

    def step(self, fin_commands=(0.0, 0.0, 0.0), n: int = 1) -> None:
        """Advance `n` steps with the fin servos commanded to `fin_commands` (rad).

        Commands are clipped to the servo range and approached at the fin rate limit.
        """
        m, d = self.model, self.data
        cmd = np.clip(np.asarray(fin_commands, float), self._fin_limit[:, 0], self._fin_limit[:, 1])
        slew = self._rate * m.opt.timestep
        d.ctrl[self._thruster] = self.thrust
        settled = (cmd == self.reference).all()
        for _ in range(n):
            if not settled:
                gap = cmd - self.reference
                self.reference = np.where(np.abs(gap) <= slew, cmd, self.reference + np.sign(gap) * slew)
                d.ctrl[self._fin_act] = self.reference
                settled = (cmd == self.reference).all()
            if self.rk4:
                self._rk4_step()
            elif self.complete:
                mujoco.mj_step1(m, d)
                self._complete()
                mujoco.mj_step2(m, d)
            else:
                self._plain()
                mujoco.mj_step(m, d)
        if not np.all(np.isfinite(d.qvel)) or np.abs(d.qvel).max() > 1e4:
            raise InputError(f"simulation unstable at t={d.time:.3f} s (timestep "
                             f"{m.opt.timestep} s); expected a finite state — reduce the timestep")  # fmt: skip

    def _acceleration(self) -> np.ndarray:
        """q̈ at the current (qpos, qvel): MuJoCo's forward dynamics, completed."""
        m, d = self.model, self.data
        mujoco.mj_fwdPosition(m, d)
        mujoco.mj_fwdVelocity(m, d)
        self._complete() if self.complete else self._plain()
        mujoco.mj_fwdActuation(m, d)
        mujoco.mj_fwdAcceleration(m, d)
        mujoco.mj_fwdConstraint(m, d)
        return d.qacc.copy()

    def _rk4_step(self) -> None:
        """Classical RK4 on (qpos, qvel), positions integrated on the quaternion manifold."""
        m, d = self.model, self.data
        h = m.opt.timestep
        q0, v0 = d.qpos.copy(), d.qvel.copy()
        vels, accs = [v0], [self._acceleration()]
        for c in (0.5, 0.5, 1.0):
            d.qpos[:] = q0
            mujoco.mj_integratePos(m, d.qpos, vels[-1], c * h)
            d.qvel[:] = v0 + c * h * accs[-1]
            vels.append(d.qvel.copy())
            accs.append(self._acceleration())
        w = np.array([1.0, 2.0, 2.0, 1.0]) / 6.0
        d.qpos[:] = q0
        mujoco.mj_integratePos(m, d.qpos, w @ np.array(vels), h)
        d.qvel[:] = v0 + h * (w @ np.array(accs))
        d.time += h

    def _hull_wrench(self) -> np.ndarray:
        """`wrench` in MuJoCo's hull axes."""
        return self.wrench * _FLIP6

    def _plain(self) -> None:
        """Plain MuJoCo: only the external wrench is applied."""
        d = self.data
        f = self._hull_wrench()
        d.qfrc_applied[:] = 0.0
        d.qfrc_applied[self._dofs[:3]] = d.xmat[self.hull].reshape(3, 3) @ f[:3]
        d.qfrc_applied[self._dofs[3:6]] = f[3:]

    def _complete(self) -> None:
        """Add the added-mass inertia to d.M; the added-mass bias and buoyancy to qfrc_applied."""
        m, d = self.model, self.data
        _completion(d.xmat[self.hull], d.qpos[self._fin_qadr], d.qvel[self._dofs], self._P,
                    self._M_hull, self._buoyancy, self._buoyancy_centre, self._hull_wrench(),
                    self._csr[0], self._csr[1], d.M, self._F)  # fmt: skip
        mujoco.mj_factorM(m, d)
        d.qfrc_applied[self._dofs] = self._F

    def body_accelerations(self) -> np.ndarray:
        """(u̇ v̇ ẇ ṗ q̇ ṙ) in SPEC body axes at the current state, the fins held where they are.

        The fins are prescribed (fin dynamics excluded): the hull rows of `M q̈ = f` are solved
        with the fin accelerations set to zero. The state is not advanced.
        """
        m, d = self.model, self.data
        d.ctrl[self._thruster] = self.thrust
        mujoco.mj_fwdPosition(m, d)
        mujoco.mj_fwdVelocity(m, d)
        self._complete() if self.complete else self._plain()
        mujoco.mj_fwdActuation(m, d)
        mujoco.mj_fwdAcceleration(m, d)
        M = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(m, d, M)
        h = slice(self._vadr, self._vadr + 6)
        qacc = np.linalg.solve(M[h, h], d.qfrc_smooth[h])
        R = d.xmat[self.hull].reshape(3, 3)
        v_b = R.T @ d.qvel[self._vadr:self._vadr + 3]
        w_b = d.qvel[self._vadr + 3:self._vadr + 6]
        vdot = R.T @ qacc[:3] - np.cross(w_b, v_b)
        return np.concatenate([FLIP @ vdot, FLIP @ qacc[3:]])

    def kinetic_energy(self) -> float:
        """½ q̇ᵀ (M_RB + M_A) q̇ at the current state (the conserved energy of potential flow).

        Computed independently of the step: M_A = Σ J_bᵀ M_b J_b from MuJoCo's body Jacobians.
        """
        m, d = self.model, self.data
        mujoco.mj_forward(m, d)
        M = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(m, d, M)
        h = hydrostatics(m)
        jp, jr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
        for b, Mb in zip(h.bodies, h.added_mass):
            mujoco.mj_jacBody(m, d, jp, jr, b)
            Rt = d.xmat[b].reshape(3, 3).T
            J = np.vstack([Rt @ jp, Rt @ jr])
            M += J.T @ Mb @ J
        return 0.5 * float(d.qvel @ M @ d.qvel)


_FLIP6 = np.array([1.0, -1.0, -1.0, 1.0, -1.0, -1.0])


@numba.njit(cache=True)
def _cross(a, b):
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


# Compiled: run every physics step, where numpy's per-call overhead on 9×9 arrays would cost
# three times MuJoCo's own step (numba is a dependency for this loop alone).
@numba.njit(cache=True)
def _completion(xmat, delta, qd, P, M_hull, buoyancy, centre, wrench, rows, cols, M_csr, F):
    """Add Tᵀ M9 T to the CSR mass matrix `M_csr`; write the generalized force to `F`.

    M9 = M_hull + Σ basis_i basis_j P_ij (X_k affine in basis = (1, cos δ_k, sin δ_k)),
    F = −M9 γ − (Σ basis_i ḃasis_j P_ij) ν + buoyancy + wrench, in MuJoCo's coordinates.
    """
    R = xmat.reshape(3, 3)
    v = R.T @ qd[:3]
    w = qd[3:6]
    nfin = delta.shape[0]
    coef = np.zeros((2, nfin * 9))
    for k in range(nfin):
        c, s, rate = np.cos(delta[k]), np.sin(delta[k]), qd[6 + k]
        b = (1.0, c, s)
        bdot = (0.0, -s * rate, c * rate)
        for j in range(3):
            for i in range(3):
                coef[0, 9 * k + 3 * j + i] = b[i] * b[j]
                coef[1, 9 * k + 3 * j + i] = b[i] * bdot[j]
    MC = coef @ P
    M9 = M_hull + MC[0].reshape(9, 9)
    C9 = MC[1].reshape(9, 9)
    nu = np.concatenate((v, w, qd[6:]))
    cw = _cross(w, v)
    F[:] = -(C9 @ nu)  # and −M9 γ, with γ = (−ω × v, 0, 0):
    for i in range(9):
        F[i] += M9[i, 0] * cw[0] + M9[i, 1] * cw[1] + M9[i, 2] * cw[2]
    F[3:6] += _cross(centre, R.T @ buoyancy) + wrench[3:]
    F[:3] = R @ (F[:3] + wrench[:3]) + buoyancy
    # MuJoCo's free-joint linear velocity is in world axes: ν = T q̇, T = diag(Rᵀ, I).
    M9[:3] = R @ M9[:3]
    M9[:, :3] = (R @ np.ascontiguousarray(M9[:, :3].T)).T
    for e in range(rows.shape[0]):
        M_csr[e] += M9[rows[e], cols[e]]


def _added_mass_basis(model: mujoco.MjModel):
    """Precompute the hull-axis added mass of hull and fins and the buoyancy.

    Returns P (fins, 3, 3, 9, 9) with X_k = Σ_i basis_i X_ki, basis = (1, cos δ_k, sin δ_k),
    P[k, i, j] = X_kiᵀ M_k X_kj; the hull's 9×9 added mass; the total displaced volume and its
    centre in hull axes. Fins must hinge about their body origin, and their displaced volume must
    lie on their hinge axis (so buoyancy makes no hinge moment and does not move with δ).
    """
    h = hydrostatics(model)
    hull = model.body("hull").id
    P = np.zeros((len(FINS), 3, 3, 9, 9))
    M_hull = np.zeros((9, 9))
    volume, moment = 0.0, np.zeros(3)
    for b, Mb, V, cb in zip(h.bodies, h.added_mass, h.volume, h.centroid):
        if b == hull:
            M_hull[:6, :6] += Mb
            volume, moment = volume + V, moment + V * cb
            continue
        names = [f for f in FINS if model.joint(f).bodyid[0] == b]
        if model.body_parentid[b] != hull or not names:
            raise InputError(f"body {model.body(b).name!r} has fluid geoms but is not the hull "
                             "or a fin hinged to it; expected fluid geoms on those only")  # fmt: skip
        k, j = FINS.index(names[0]), model.joint(names[0]).id
        a = model.jnt_axis[j] / np.linalg.norm(model.jnt_axis[j])
        if np.linalg.norm(model.jnt_pos[j]) > 1e-9 or np.linalg.norm(np.cross(a, cb)) > 1e-9:
            raise InputError(f"fin {names[0]!r}: its hinge must pass through its body origin and "
                             "its fluid geoms' volume centre")  # fmt: skip
        Q0 = np.empty(9)
        mujoco.mju_quat2Mat(Q0, model.body_quat[b])
        Q0 = Q0.reshape(3, 3)  # hull from fin at δ = 0
        p = model.body_pos[b]
        A = skew(a)
        # Rot(a, δ) = I + sin δ [a]× + (1 − cos δ)[a]×², so Eᵀ = Rot(δ)ᵀ Q0ᵀ is affine in (1, c, s).
        Xs = []
        for i, rot in enumerate([(np.eye(3) + A @ A).T, (-A @ A).T, A.T]):
            Et = rot @ Q0.T
            X = np.zeros((6, 9))
            X[:3, :3] = Et
            X[:3, 3:6] = -Et @ skew(p)
            X[3:, 3:6] = Et
            X[3:, 6 + k] = a if i == 0 else 0.0
            Xs.append(X)
        P[k] = [[Xi.T @ Mb @ Xj for Xj in Xs] for Xi in Xs]
        volume, moment = volume + V, moment + V * (p + Q0 @ cb)
    return P, M_hull, volume, moment / volume
