"""The completed plant: MuJoCo's rigid bodies and fluid forces, plus exactly what MuJoCo lacks.

MuJoCo's ellipsoid fluid model applies the velocity-dependent added-mass terms (Munk moment,
(m_A v) × ω, ...) but not the acceleration-dependent force −M_A ν̇, and no buoyancy. Applying
−M_A ν̇ from the previous step's acceleration (UUV Simulator, Gazebo) is unstable when added mass
is comparable to the body's, so here it goes where it belongs, into the generalized mass.

In hull axes the vehicle's velocity is ν = (v, ω, δ̇) (hull linear and angular velocity, fin
rates). Fin k's velocity in its own axes is X_k(δ_k) ν, and with M_k its 6×6 added mass the
added mass of the whole vehicle is M9(δ) = M_hull + Σ X_kᵀ M_k X_k. The missing force, with
the fins at rest relative to the hull (below), is

    −Σ X_kᵀ M_k d/dt(X_k ν) = −M9 ν̇,

with ν̇ the rate of the hull-axis components (Kirchhoff's equations). X_k is affine in
(cos δ_k, sin δ_k), so M9 is a fixed combination of nine precomputed 9×9 products per fin. After MuJoCo's position and velocity stages the plant maps M9 to MuJoCo's coordinates
(free-joint linear velocity is in world axes: v = Rᵀ q̇_lin, v̇ = Rᵀ q̈_lin − ω × v), adds it to
MuJoCo's mass matrix (CSR `d.M`, within the tree's sparsity) and puts the bias and the
buoyancy of every fluid geom (−ρ V g at its volume's centre) in `qfrc_applied`; the hull's
acceleration is then solved from the hull block of the complete mass matrix (the fins'
accelerations are prescribed), so the step is as stable as a rigid body's; with MuJoCo's
velocity terms the fluid part is Kirchhoff's equations for a body in potential flow.

The fins are prescribed, quasi-steady control surfaces, as the linear model takes them (the
fin angle is an input). Each is a digital servo: at every physics step its angle moves toward
the command by at most the fin rate limit times the step and is held until the next, so it
settles within one 10 ms step for any change below 20 mrad, and RK4 integrates exactly the
staircase that is recorded (a continuous servo faster than the step would not be resolved by
the stages; one slower than the 50 Hz sample interval spreads each command change over the
next interval, which a zero-order hold of the interval's mean angle does not represent: with
MuJoCo's 30 Hz position servo the noise-free fit's N row is 1–3 % off). The fluid and the hull
see each fin at its angle, at rest relative to the hull: a fin turning in the flow would add a
force linear in its rate (the non-circulatory lift of its added mass, −δ̇ X_kᵀ M_k ∂X_k/∂δ ν,
and MuJoCo's −ω × m_A v for the fin body), measured on the torpedo with dynamic fins at 1.9 ms ×
the fin's force per radian (B₁ ≈ 0.0019 s · B): an input lead that the linear model has no place
for (with it, the analytic model tracks an open-loop PRBS response to only 96–98 % fit).

The hull is integrated by classical RK4 (`plant_step.advance`, one compiled loop over the steps), each
of the four stages a completed forward evaluation with the fins at their held angles. MuJoCo's
own step would not do: its RK4 stages cannot be completed, and its first-order
steps are far from the continuous plant that the analytic model linearises (even at 4 ms, implicit
Euler moves the 23.7 rad/s sway-yaw and heave-pitch poles by 4 %, and `implicitfast` keeps only
the lower triangle of the strongly asymmetric fluid-force derivative): with `implicitfast` the
analytic model tracked the same response with 92–94 % fit (tests/simulation/test_plant.py measures the
agreement that RK4 and quasi-steady fins give).
"""

from __future__ import annotations
import copy
import math
import mujoco
import numpy as np
from testbed.errors import InputError
from testbed.models.linear import Vehicle
from testbed.simulation.vehicle import (
    FIN_JOINTS,
    FLIP,
    check_model,
    constants,
    cruise_speed,
    fin_rate_limit,
    hydrostatics,
    load_model,
    quaternion_matrix,
)
from testbed.simulation.plant_step import (
    Kernel,
    MAX_VELOCITY,
    added_mass_basis,
    advance,
    advance_plain,
    completion,
    wrench_applied,
)

__all__ = ["Plant"]


class Plant:
    """A stateful simulator of the completed plant (state lives in MuJoCo's `MjData`).

    The completed plant integrates with RK4 at the MJCF's timestep. `complete=False` runs plain
    MuJoCo instead (`mj_step` with the MJCF's integrator, fins driven by MuJoCo's own servos,
    no added-mass inertia, no buoyancy), for comparison. A `model` passed in is used as it is
    (later changes to it reach the plant), except with `timestep`: then the plant works on a
    copy, and the caller's model keeps its own timestep.
    """

    def __init__(
        self,
        mjcf=None,
        timestep: float | None = None,
        complete: bool = True,
        model: mujoco.MjModel | None = None,
    ):
        if model is None:
            model = load_model(mjcf)
        else:
            check_model(model)
            if timestep is not None:
                model = copy.copy(model)
        if timestep is not None:
            if not 0 < timestep < math.inf:
                raise InputError(f"timestep={timestep}; expected a finite timestep > 0 s")
            model.opt.timestep = timestep
        self.model = model
        self.data = mujoco.MjData(self.model)
        self.complete = complete
        m, d = self.model, self.data
        self.hull = m.body("hull").id
        self._qadr = m.jnt_qposadr[m.joint("hull").id]
        self._vadr = m.jnt_dofadr[m.joint("hull").id]
        self._fin_qadr = np.array([m.jnt_qposadr[m.joint(f).id] for f in FIN_JOINTS], np.intp)
        self._fin_act = np.array([m.actuator(f).id for f in FIN_JOINTS], np.intp)
        self._thruster = m.actuator("thruster").id
        self._fin_limit = m.actuator_ctrlrange[self._fin_act].copy()
        self._rate = fin_rate_limit(m)
        dofs = np.concatenate(
            [np.arange(self._vadr, self._vadr + 6), [m.jnt_dofadr[m.joint(f).id] for f in FIN_JOINTS]]
        ).astype(np.intp)
        # d.M's CSR entries as (row, col) of the 9×9 matrix over `dofs` (check_model: nv = 9).
        where = np.empty(m.nv, np.intp)
        where[dofs] = np.arange(len(dofs))
        rows = np.repeat(np.arange(m.nv), m.M_rownnz)
        P, M_hull, B, c = added_mass_basis(m)
        self.thrust = 0.0
        self._addresses = (m._address, d._address)  # the C structs, for the compiled loop
        self._k = Kernel(
            d.xmat,
            d.qvel,
            d.qpos,
            d.qacc,
            d.M,
            d.qfrc_applied,
            d.qfrc_passive,
            d.qfrc_actuator,
            d.qfrc_bias,
            d.ctrl,
            d.warning.number,
            self.hull,
            self._fin_qadr,
            self._fin_act,
            self._fin_limit,
            dofs,
            where[rows],
            where[m.M_colind].astype(np.intp),
            P,
            M_hull,
            -m.opt.density * B * m.opt.gravity,
            c,
            np.zeros(6),
            np.zeros(len(FIN_JOINTS)),
            np.zeros(len(FIN_JOINTS)),
            np.zeros(6),
        )
        self.reset()

    @property
    def wrench(self) -> np.ndarray:
        """External force and moment at the CG, body axes (FRD) (N, N m); set it in place or whole."""
        return self._k.wrench

    @wrench.setter
    def wrench(self, value) -> None:
        self._k.wrench[:] = value

    @property
    def reference(self) -> np.ndarray:
        """The fin servos' rate-limited reference (rad): the completed plant's fin angles."""
        return self._k.reference

    def fin_integral(self) -> np.ndarray:
        """∫ δ dt of each fin since the last reset (rad s), exact: its difference over a sample
        interval, divided by the interval, is the fin's mean angle over it."""
        return self._k.integral.copy()

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
        if not 0 <= speed < math.inf:
            raise InputError(f"speed={speed}; expected a finite speed >= 0 m/s")
        m, d = self.model, self.data
        mujoco.mj_resetData(m, d)
        q = np.array([math.cos(heading / 2), 0.0, 0.0, -math.sin(heading / 2)])  # NED yaw = -z turn
        d.qpos[self._qadr : self._qadr + 3] = (0.0, 0.0, -depth)
        d.qpos[self._qadr + 3 : self._qadr + 7] = q
        R = quaternion_matrix(q)
        d.qvel[self._vadr : self._vadr + 3] = R @ np.array([speed, 0.0, 0.0])
        self.reference[:] = 0.0
        self._k.integral[:] = 0.0
        d.ctrl[:] = 0.0
        mujoco.mj_forward(m, d)
        # The propulsor balances the drag of straight flight at this speed.
        drag = R.T @ d.qfrc_passive[self._vadr : self._vadr + 3]
        self.thrust = max(0.0, -float(drag[0]))
        d.ctrl[self._thruster] = self.thrust

    def set_state(self, qpos: np.ndarray, qvel: np.ndarray) -> None:
        """Set MuJoCo's generalized state (for tests and linearization); the fin servos start
        from the fin angles in it."""
        self.data.qpos[:] = qpos
        self.data.qvel[:] = qvel
        self.reference[:] = qpos[self._fin_qadr]
        mujoco.mj_forward(self.model, self.data)

    def state(self) -> np.ndarray:
        """The state `u v w p q r phi theta psi z` (absolute u; body FRD, earth NED, at the CG)."""
        d = self.data
        R = quaternion_matrix(d.qpos[self._qadr + 3 : self._qadr + 7])
        v = R.T @ d.qvel[self._vadr : self._vadr + 3]
        w = d.qvel[self._vadr + 3 : self._vadr + 6]
        # NED-from-FRD is FLIP R FLIP: entries (2,1), (2,2), (2,0), (1,0), (0,0) of it below.
        phi = math.atan2(R[2, 1], R[2, 2])
        theta = -math.asin(max(-1.0, min(1.0, -R[2, 0])))
        psi = math.atan2(-R[1, 0], R[0, 0])
        return np.array([v[0], -v[1], -v[2], w[0], -w[1], -w[2], phi, theta, psi, -d.qpos[self._qadr + 2]])

    def position(self) -> np.ndarray:
        """CG position, NED (m)."""
        return FLIP @ self.data.qpos[self._qadr : self._qadr + 3]

    def fin_angles(self) -> np.ndarray:
        """Actual `delta_r, delta_er, delta_el` (rad)."""
        return self.data.qpos[self._fin_qadr].copy()

    # -- dynamics ----------------------------------------------------------------------------

    def step(self, fin_commands=(0.0, 0.0, 0.0), n: int = 1) -> None:
        """Advance `n` steps with the fin servos commanded to `fin_commands` (rad).

        Commands are clipped to the servo range and approached at the fin rate limit, the fins
        held over each step (plain MuJoCo: its servos follow). Raises `InputError` at the first
        step that MuJoCo flags (it would reset the state and go on) or that leaves the
        velocities non-finite or beyond `MAX_VELOCITY` (m/s, rad/s).
        """
        m, d, k = self.model, self.data, self._k
        cmd = np.asarray(fin_commands, float).reshape(len(FIN_JOINTS))  # _servo clips it to the range
        slew = self._rate * m.opt.timestep
        d.ctrl[self._thruster] = self.thrust
        t0 = d.time
        # The whole loop is compiled, calling MuJoCo's C API (Python around each step would
        # cost more than the step itself: benchmarks/bench_plant.py).
        stepped = advance if self.complete else advance_plain
        done, cause = stepped(*self._addresses, k, n, m.opt.timestep, cmd, slew)
        if self.complete:
            d.time = t0 + done * m.opt.timestep
        if cause >= 0:
            why = (
                f"velocities non-finite or beyond {MAX_VELOCITY:g}"
                if cause == len(k.warnings)
                else "MuJoCo: " + mujoco.mju_warningText(cause, int(d.warning.lastinfo[cause])).split(". ")[0]
            )
            raise InputError(
                f"simulation unstable at t={t0 + done * m.opt.timestep:.4g} s ({why}); "
                "expected a bounded state: lower the speed or the timestep, or fix the MJCF"
            )

    def _plain(self) -> None:
        """Plain MuJoCo: only the external wrench is applied."""
        k = self._k
        wrench_applied(k.qfrc, k.xmat[k.hull], k.dofs, k.wrench)

    def _complete(self) -> None:
        """Add the added-mass inertia to d.M; the bias and buoyancy to qfrc_applied (the
        actuators' force is MuJoCo's own here: `mj_fwdActuation` follows)."""
        self._k.actuation[:] = 0.0
        completion(self._k)

    def body_accelerations(self) -> np.ndarray:
        """(u̇ v̇ ẇ ṗ q̇ ṙ) in body axes (FRD) at the current state, the fins held where they are.

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
        v_b = R.T @ d.qvel[self._vadr : self._vadr + 3]
        w_b = d.qvel[self._vadr + 3 : self._vadr + 6]
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
