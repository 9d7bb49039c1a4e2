"""The completed plant: MuJoCo's rigid bodies and fluid forces, plus exactly what MuJoCo lacks.

MuJoCo's ellipsoid fluid model applies the velocity-dependent added-mass terms (Munk moment,
(m_A v) × ω, ...) but not the acceleration-dependent force −M_A ν̇, and no buoyancy. Applying
−M_A ν̇ from the previous step's acceleration (UUV Simulator, Gazebo) is unstable when added mass
is comparable to the body's, so here it goes where it belongs, into the generalized mass.
For each body b carrying fluid geoms, with ν_b = J_b q̇ its (linear, angular) velocity in its own
axes and M_b its 6×6 added mass:

    −M_b ν̇_b = −M_b J_b q̈ − M_b β_b,   β_b = (Rᵀ J̇_p q̇ − ω × v, Rᵀ J̇_r q̇)

(ν̇_b is the rate of change of the body-axis components, as in Kirchhoff's equations). After
`mj_step1` the plant adds Σ J_bᵀ M_b J_b to MuJoCo's mass matrix (CSR `d.M`; the tree sparsity
holds because J_b is non-zero only on b's ancestor dofs), refactors it, puts −Σ J_bᵀ M_b β_b and
the buoyancy of every fluid geom (−ρ V g at its centroid) in `qfrc_applied`, and lets
`mj_step2` finish: the integrator (Euler or implicitfast) sees the complete mass matrix, so the
scheme is as stable as MuJoCo's own rigid-body step. With MuJoCo's velocity terms this makes the
fluid part Kirchhoff's equations for a body in potential flow.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from testbed.errors import InputError
from testbed.model import Vehicle
from testbed.vehicle import FINS, FLIP, constants, cruise_speed, fin_rate_limit, hydrostatics, load_model


class Plant:
    """A stateful simulator of the completed plant (state lives in MuJoCo's `MjData`).

    `complete=False` runs plain MuJoCo (no added-mass inertia, no buoyancy), for comparison.
    """

    def __init__(self, mjcf=None, timestep: float | None = None, complete: bool = True,
                 model: mujoco.MjModel | None = None):  # fmt: skip
        self.model = model if model is not None else load_model(mjcf)
        if timestep is not None:
            if not timestep > 0:
                raise InputError(f"timestep={timestep}; expected > 0 s")
            self.model.opt.timestep = timestep
        self.data = mujoco.MjData(self.model)
        self.complete = complete
        m = self.model
        self.hull = m.body("hull").id
        self._qadr = m.jnt_qposadr[m.joint("hull").id]
        self._vadr = m.jnt_dofadr[m.joint("hull").id]
        self._fin_qadr = np.array([m.jnt_qposadr[m.joint(f).id] for f in FINS])
        self._fin_act = np.array([m.actuator(f).id for f in FINS])
        self._thruster = m.actuator("thruster").id
        self._fin_limit = m.actuator_ctrlrange[self._fin_act].copy()
        self._rate = fin_rate_limit(m)
        h = hydrostatics(m)
        self._bodies = h.bodies
        self._MA = h.added_mass
        self._buoyancy_force = -m.opt.density * h.volume[:, None] * m.opt.gravity[None, :]
        self._centroid = h.centroid
        nb, nv = len(h.bodies), m.nv
        self._Jp, self._Jr = np.zeros((nb, 3, nv)), np.zeros((nb, 3, nv))
        self._Jdp, self._Jdr = np.zeros((nb, 3, nv)), np.zeros((nb, 3, nv))
        self._rows = np.repeat(np.arange(nv), m.M_rownnz)
        self._cols = m.M_colind.copy()
        self.reference = np.zeros(3)  # rate-limited fin servo reference
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
        v_body = FLIP @ (R.T @ d.qvel[self._vadr:self._vadr + 3])
        w_body = FLIP @ d.qvel[self._vadr + 3:self._vadr + 6]
        Rn = FLIP @ R @ FLIP  # NED from FRD
        phi = math.atan2(Rn[2, 1], Rn[2, 2])
        theta = -math.asin(max(-1.0, min(1.0, Rn[2, 0])))
        psi = math.atan2(Rn[1, 0], Rn[0, 0])
        return np.concatenate([v_body, w_body, [phi, theta, psi, -d.qpos[self._qadr + 2]]])

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
        for _ in range(n):
            self.reference += np.clip(cmd - self.reference, -slew, slew)
            d.ctrl[self._fin_act] = self.reference
            d.ctrl[self._thruster] = self.thrust
            if self.complete:
                mujoco.mj_step1(m, d)
                self._complete()
                mujoco.mj_step2(m, d)
            else:
                mujoco.mj_step(m, d)
        if not np.all(np.isfinite(d.qvel)) or np.abs(d.qvel).max() > 1e4:
            raise InputError(f"simulation unstable at t={d.time:.3f} s (timestep "
                             f"{m.opt.timestep} s); expected a finite state — reduce the timestep")  # fmt: skip

    def _complete(self) -> None:
        """Add added-mass inertia to d.M and the added-mass bias and buoyancy to qfrc_applied."""
        m, d = self.model, self.data
        Jp, Jr, Jdp, Jdr = self._Jp, self._Jr, self._Jdp, self._Jdr
        for k, b in enumerate(self._bodies):
            mujoco.mj_jacBody(m, d, Jp[k], Jr[k], b)
            mujoco.mj_jacDot(m, d, Jdp[k], Jdr[k], d.xpos[b], b)
        R = d.xmat[self._bodies].reshape(-1, 3, 3)
        Rt = R.transpose(0, 2, 1)
        J = np.concatenate([Rt @ Jp, Rt @ Jr], axis=1)  # (nb, 6, nv): body-axis velocities
        qd = d.qvel
        nu = J @ qd
        v, w = nu[:, :3], nu[:, 3:]
        beta = np.concatenate([(Rt @ (Jdp @ qd)[..., None])[..., 0] - np.cross(w, v),
                               (Rt @ (Jdr @ qd)[..., None])[..., 0]], axis=1)  # fmt: skip
        MJ = self._MA @ J
        Madd = np.einsum("bik,bil->kl", J, MJ)
        d.M += Madd[self._rows, self._cols]
        mujoco.mj_factorM(m, d)
        # Buoyancy at each body's displaced-volume centroid (world force, world point).
        c = (R @ self._centroid[..., None])[..., 0]  # centroid offset from body origin, world
        f = self._buoyancy_force
        torque = np.cross(c, f)
        d.qfrc_applied[:] = (-np.einsum("bik,bi->k", J, (self._MA @ beta[..., None])[..., 0])
                             + np.einsum("bik,bi->k", Jp, f) + np.einsum("bik,bi->k", Jr, torque))  # fmt: skip

    def body_accelerations(self) -> np.ndarray:
        """(u̇ v̇ ẇ ṗ q̇ ṙ) in SPEC body axes at the current state, the fins held where they are.

        The fins are prescribed (fin dynamics excluded): the hull rows of `M q̈ = f` are solved
        with the fin accelerations set to zero. The state is not advanced.
        """
        m, d = self.model, self.data
        d.ctrl[self._thruster] = self.thrust
        mujoco.mj_fwdPosition(m, d)
        mujoco.mj_fwdVelocity(m, d)
        if self.complete:
            self._complete()
        else:
            d.qfrc_applied[:] = 0.0
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
        """½ q̇ᵀ (M_RB + M_A) q̇ at the current state (the conserved energy of potential flow)."""
        m, d = self.model, self.data
        mujoco.mj_forward(m, d)
        M = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(m, d, M)
        for k, b in enumerate(self._bodies):
            mujoco.mj_jacBody(m, d, self._Jp[k], self._Jr[k], b)
        Rt = d.xmat[self._bodies].reshape(-1, 3, 3).transpose(0, 2, 1)
        J = np.concatenate([Rt @ self._Jp, Rt @ self._Jr], axis=1)
        M = M + np.einsum("bik,bij,bjl->kl", J, self._MA, J)
        return 0.5 * float(d.qvel @ M @ d.qvel)
