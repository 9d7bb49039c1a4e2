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

The hull is integrated by classical RK4 (`_advance`, one compiled loop over the steps), each
of the four stages a completed forward evaluation with the fins at their held angles. MuJoCo's
own step would not do: its RK4 stages cannot be completed, and its first-order
steps are far from the continuous plant that the analytic model linearises (even at 4 ms, implicit
Euler moves the 23.7 rad/s sway-yaw and heave-pitch poles by 4 %, and `implicitfast` keeps only
the lower triangle of the strongly asymmetric fluid-force derivative): with `implicitfast` the
analytic model tracked the same response with 92–94 % fit (tests/test_plant.py measures the
agreement that RK4 and quasi-steady fins give).
"""

from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import NamedTuple

import llvmlite.binding
import mujoco
import numba
import numpy as np

from testbed.errors import InputError
from testbed.models.linear import Vehicle
from testbed.simulation.vehicle import (
    FINS,
    FLIP,
    check_model,
    constants,
    cruise_speed,
    fin_rate_limit,
    hydrostatics,
    load_model,
    motion_transform,
    rotation,
    skew,
)

__all__ = ["Plant", "step_cache"]


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
        self._fin_qadr = np.array([m.jnt_qposadr[m.joint(f).id] for f in FINS], np.intp)
        self._fin_act = np.array([m.actuator(f).id for f in FINS], np.intp)
        self._thruster = m.actuator("thruster").id
        self._fin_limit = m.actuator_ctrlrange[self._fin_act].copy()
        self._rate = fin_rate_limit(m)
        dofs = np.concatenate(
            [np.arange(self._vadr, self._vadr + 6), [m.jnt_dofadr[m.joint(f).id] for f in FINS]]
        ).astype(np.intp)
        # d.M's CSR entries as (row, col) of the 9×9 matrix over `dofs` (check_model: nv = 9).
        where = np.empty(m.nv, np.intp)
        where[dofs] = np.arange(len(dofs))
        rows = np.repeat(np.arange(m.nv), m.M_rownnz)
        P, M_hull, B, c = _added_mass_basis(m)
        self.thrust = 0.0
        self._addresses = (m._address, d._address)  # the C structs, for the compiled loop
        self._k = _Kernel(
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
            np.zeros(len(FINS)),
            np.zeros(len(FINS)),
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
        R = rotation(q)
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
        R = rotation(d.qpos[self._qadr + 3 : self._qadr + 7])
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
        velocities non-finite or beyond `_MAX_VELOCITY` (m/s, rad/s).
        """
        m, d, k = self.model, self.data, self._k
        cmd = np.asarray(fin_commands, float).reshape(len(FINS))  # _servo clips it to the range
        slew = self._rate * m.opt.timestep
        d.ctrl[self._thruster] = self.thrust
        t0 = d.time
        # The whole loop is compiled, calling MuJoCo's C API (Python around each step would
        # cost more than the step itself: benchmarks/bench_plant.py).
        advance = _advance if self.complete else _advance_plain
        done, cause = advance(*self._addresses, k, n, m.opt.timestep, cmd, slew)
        if self.complete:
            d.time = t0 + done * m.opt.timestep
        if cause >= 0:
            why = (
                f"velocities non-finite or beyond {_MAX_VELOCITY:g}"
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
        _wrench_applied(k.qfrc, k.xmat[k.hull], k.dofs, k.wrench)

    def _complete(self) -> None:
        """Add the added-mass inertia to d.M; the bias and buoyancy to qfrc_applied (the
        actuators' force is MuJoCo's own here: `mj_fwdActuation` follows)."""
        self._k.actuation[:] = 0.0
        _completion(self._k)

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


class _Kernel(NamedTuple):
    """What the compiled step reads and writes: views of MjData's arrays (valid while the data
    lives, so made once) and the plant's constants and mutable state."""

    xmat: np.ndarray
    qvel: np.ndarray
    qpos: np.ndarray
    qacc: np.ndarray
    M: np.ndarray  # d.M, the CSR mass matrix
    qfrc: np.ndarray  # d.qfrc_applied
    qfrc_passive: np.ndarray
    qfrc_actuator: np.ndarray
    qfrc_bias: np.ndarray
    ctrl: np.ndarray
    warnings: np.ndarray  # d.warning.number, MuJoCo's warning counters
    hull: int  # body id
    fin_qadr: np.ndarray
    fin_act: np.ndarray
    limits: np.ndarray  # fin servo ctrlrange, (fins, 2)
    dofs: np.ndarray  # hull's six dofs, then the fins'
    rows: np.ndarray  # d.M's entries as (row, col) over `dofs`
    cols: np.ndarray
    P: np.ndarray  # (fins, 3, 3, 9, 9), see _added_mass_basis
    M_hull: np.ndarray  # 9×9
    buoyancy: np.ndarray  # world force, N
    centre: np.ndarray  # of buoyancy, hull axes, m
    wrench: np.ndarray  # Plant.wrench, body axes (FRD)
    reference: np.ndarray  # Plant.reference
    integral: np.ndarray  # Plant.fin_integral
    actuation: np.ndarray  # the actuators' force on the hull over the step, hull axes (MuJoCo's)


# MuJoCo's C API for the compiled loop, from the library the Python bindings use. The mjModel*
# and mjData* go in as integer addresses (`_address`): the same calling convention as pointers.
llvmlite.binding.load_library_permanently(
    str(
        next(
            f
            for pattern in ("libmujoco.so*", "libmujoco*.dylib", "mujoco*.dll")
            for f in sorted(Path(mujoco.__file__).parent.glob(pattern))
        )
    )
)
_SIGNATURE = numba.types.void(numba.types.uintp, numba.types.uintp)
_mj_step = numba.types.ExternalFunction("mj_step", _SIGNATURE)
_mj_kinematics = numba.types.ExternalFunction("mj_kinematics", _SIGNATURE)
_mj_comPos = numba.types.ExternalFunction("mj_comPos", _SIGNATURE)
_mj_makeM = numba.types.ExternalFunction("mj_makeM", _SIGNATURE)
_mj_transmission = numba.types.ExternalFunction("mj_transmission", _SIGNATURE)
_mj_fwdVelocity = numba.types.ExternalFunction("mj_fwdVelocity", _SIGNATURE)
_mj_fwdActuation = numba.types.ExternalFunction("mj_fwdActuation", _SIGNATURE)
_mj_checkAcc = numba.types.ExternalFunction("mj_checkAcc", _SIGNATURE)
# void mj_integratePos(const mjModel* m, mjtNum* qpos, const mjtNum* qvel, mjtNum scale)
_mj_integratePos = numba.types.ExternalFunction(
    "mj_integratePos",
    numba.types.void(numba.types.uintp, numba.types.uintp, numba.types.uintp, numba.types.float64),
)
_MAX_VELOCITY = 1e4  # m/s or rad/s: no vehicle gets near; MuJoCo's own limit (1e10) is late


# The compiled step is written as scalar loops over small arrays, without numpy's library
# functions (cross, norm, slice assignment, reshape, min): each of those costs the compiler more
# than the whole step does, and a new install compiles it once (benchmarks/bench_cold.py). The
# helpers have no Python entry of their own (`_INNER`), the leaves take the arrays they use, not
# the whole `_Kernel`, and the step, its RK4 stages and their forward evaluation are written out
# in `_advance`, their one caller: a compiled function is optimised again in every caller it is linked into, and one
# inlined by numba copies its IR and the whole `_Kernel` (a reference count per array) at every
# call. Its scratch arrays are made once per call, not per step. The plain-MuJoCo loop and the
# completion called from Python are compiled apart, only when used.
_INNER = dict(no_cpython_wrapper=True, no_cfunc_wrapper=True)


@numba.njit(cache=True)
def _advance(model, data, k, n, h, cmd, slew):
    """`n` steps of `h` s of the completed plant; returns (steps taken, `_unstable`'s cause
    for the last one, -1 if none). RK4 leaves `data.time` to the caller.

    Each step moves the fin servos, holds the fins, and integrates by classical RK4, or by 2ʲ
    RK4 steps of h/2ʲ where the step's stiffness estimate puts h λ outside RK4's stability
    region (roll damping grows with the turn rate: −49 rad/s at trim, near −1000 rad/s turning
    at 1.4 rad/s with the fins at 0.15 rad). An RK4 step of `dt` on the hull's (qpos, qvel),
    positions on the quaternion manifold: x₁ = x₀ + dt (k₁ + 2k₂ + 2k₃ + k₄)/6, each kᵢ a
    completed forward evaluation (below, with the fins' added mass at their held angles and the
    actuators' force of the step's first stage). Its stiffness estimate is
    λ ≈ ‖a₃ − a₂‖ / ‖(dt/2)(a₂ − a₁)‖ (the accelerations' change between the second and third
    stages over their velocities' change, as in Hairer & Wanner's stiffness detection)."""
    qpos, qvel, qacc, reference = k.qpos, k.qvel, k.qacc, k.reference
    nv = qvel.shape[0]
    warned = k.warnings.copy()
    q_step, v_step = qpos.copy(), qvel.copy()  # the state at the step's start
    q0, v0 = qpos.copy(), qvel.copy()  # at the RK4 step's start
    vel_sum, acc_sum, vel = np.empty(nv), np.empty(nv), np.empty(nv)
    accs = np.empty((3, nv))
    H, rhs = np.empty((6, 6)), np.empty(6)
    rows, cols, M, dofs = k.rows, k.cols, k.M, k.dofs
    for i in range(n):
        _servo(reference, k.limits, k.ctrl, k.fin_act, cmd, slew)
        for f in range(reference.shape[0]):  # the fins, held over the step
            qpos[k.fin_qadr[f]] = reference[f]
            qvel[dofs[6 + f]] = 0.0
            k.integral[f] += h * reference[f]
        _copy(qpos, q_step)
        _copy(qvel, v_step)
        M9 = _added_mass(k.P, k.M_hull, k.qpos, k.fin_qadr)
        level = 0
        while True:  # level 0: one RK4 step; then, if it was too stiff, 2ʲ of them from the start
            steps = 1 << level
            dt = h / steps
            for _ in range(steps):
                _copy(qpos, q0)
                _copy(qvel, v0)
                for j in range(nv):
                    vel_sum[j] = acc_sum[j] = 0.0
                for stage in range(4):
                    # q̈ with the fins at rest relative to the hull: MuJoCo's forward stages,
                    # completed, and the hull's acceleration from the hull block of the complete
                    # mass matrix (the fins' accelerations are prescribed, zero in MuJoCo's
                    # coordinates). Only the stages this body needs: kinematics, mass matrix,
                    # velocity (fluid forces, bias); no factorisation, collision or constraints
                    # (`check_model`: none), and the actuators' force on the hull (`_actuation`)
                    # held over the step: read at its first stage, from that stage's kinematics.
                    _mj_kinematics(model, data)
                    _mj_comPos(model, data)
                    if level == 0 and stage == 0:
                        _actuation(model, data, k.xmat[k.hull], k.qfrc_actuator, dofs, k.actuation)
                    _mj_makeM(model, data)
                    _mj_fwdVelocity(model, data)
                    _complete(k, M9)
                    for row in range(6):
                        for col in range(6):
                            H[row, col] = 0.0
                    for e in range(rows.shape[0]):  # d.M holds the lower triangle
                        row, col = rows[e], cols[e]
                        if row < 6 and col < 6:
                            H[row, col] = H[col, row] = M[e]
                    for j in range(6):  # f = passive + applied (actuators included) − bias
                        d = dofs[j]
                        rhs[j] = k.qfrc_passive[d] + k.qfrc[d] - k.qfrc_bias[d]
                    a = _solve_spd(H, rhs)  # H q̈_hull = f_hull
                    for j in range(nv):
                        qacc[j] = 0.0
                    for j in range(6):
                        qacc[dofs[j]] = a[j]
                    _mj_checkAcc(model, data)  # a bad qacc is flagged in the warning counters
                    weight = _RK4_WEIGHTS[stage]
                    for j in range(nv):
                        vel_sum[j] += weight * qvel[j]
                        acc_sum[j] += weight * qacc[j]
                    if stage < 3:  # the next stage's point: x₀ + c dt kᵢ
                        c = _RK4_NODES[stage]
                        for j in range(nv):
                            accs[stage, j] = qacc[j]
                            vel[j] = qvel[j]
                        _copy(q0, qpos)
                        _mj_integratePos(model, qpos.ctypes.data, vel.ctypes.data, c * dt)
                        for j in range(nv):
                            qvel[j] = v0[j] + c * dt * accs[stage, j]
                for j in range(nv):
                    vel_sum[j] /= 6.0
                _copy(q0, qpos)
                _mj_integratePos(model, qpos.ctypes.data, vel_sum.ctypes.data, dt)
                for j in range(nv):
                    qvel[j] = v0[j] + dt / 6.0 * acc_sum[j]
            if level > 0:
                break
            dv, da = 0.0, 0.0  # squared norms
            for j in range(nv):
                d1, d2 = accs[1, j] - accs[0, j], accs[2, j] - accs[1, j]
                dv += d1 * d1
                da += d2 * d2
            dv = 0.5 * dt * math.sqrt(dv)
            lam = math.sqrt(da) / dv if dv > 0 else 0.0
            if h * lam <= _RK4_MAX_H_LAMBDA:
                break
            level = math.ceil(math.log2(h * lam / _RK4_SUB_H_LAMBDA))
            if level > _LEVELS:
                level = _LEVELS
            _copy(q_step, qpos)
            _copy(v_step, qvel)
        cause = _unstable(k.warnings, warned, qvel)
        if cause >= 0:
            return i + 1, cause
    return n, -1


@numba.njit(cache=True)
def _advance_plain(model, data, k, n, h, cmd, slew):
    """`_advance` for plain MuJoCo: `mj_step` with the external wrench applied (`h` is the
    model's own timestep)."""
    warned = k.warnings.copy()
    for i in range(n):
        _servo(k.reference, k.limits, k.ctrl, k.fin_act, cmd, slew)
        _apply_wrench(k.qfrc, k.xmat[k.hull], k.dofs, k.wrench)
        _mj_step(model, data)
        cause = _unstable(k.warnings, warned, k.qvel)
        if cause >= 0:
            return i + 1, cause
    return n, -1


@numba.njit(cache=True)
def _completion(k):
    """`_complete` with the added mass at the fins' current angles, from Python."""
    _complete(k, _added_mass(k.P, k.M_hull, k.qpos, k.fin_qadr))


@numba.njit(**_INNER)
def _actuation(model, data, R, f, dofs, actuation):
    """The actuators' generalized force on the hull, in hull axes, into `actuation` (R: the
    hull's `xmat` row, the kinematics current; f: MuJoCo's actuator force): the propulsor is fixed to the hull and its thrust held over the step,
    so it turns with the hull (`_complete` applies it at each stage); the fin servos act on the
    prescribed fins only."""
    _mj_transmission(model, data)
    _mj_fwdActuation(model, data)
    d = dofs
    actuation[0], actuation[1], actuation[2] = _turn_back(R, f[d[0]], f[d[1]], f[d[2]])
    for i in range(3, 6):  # the free joint's angular dofs are in hull axes already
        actuation[i] = f[d[i]]


# RK4's weights and the next stage's node, by stage. Its stability region reaches −2.79 on the
# real axis: past 2.0 a step is split into 2ʲ steps with h λ ≤ 1, up to 2^_LEVELS of them.
_RK4_WEIGHTS, _RK4_NODES = (1.0, 2.0, 2.0, 1.0), (0.5, 0.5, 1.0)
_RK4_MAX_H_LAMBDA, _RK4_SUB_H_LAMBDA, _LEVELS = 2.0, 1.0, 8


@numba.njit(**_INNER)
def _copy(src, dst):
    """dst[:] = src, elementwise."""
    for i in range(src.shape[0]):
        dst[i] = src[i]


@numba.njit(**_INNER)
def _unstable(warnings, warned, qvel):
    """The first MuJoCo warning counter that moved since `warned` (on bad qpos, qvel, qacc
    MuJoCo resets the state and goes on), len(warned) for velocities non-finite or beyond
    `_MAX_VELOCITY`, or -1 for neither."""
    for i in range(warned.shape[0]):
        if warnings[i] != warned[i]:
            return i
    for i in range(qvel.shape[0]):
        if not abs(qvel[i]) <= _MAX_VELOCITY:  # NaN too
            return warned.shape[0]
    return -1


@numba.njit(**_INNER)
def _servo(reference, limits, ctrl, fin_act, cmd, slew):
    """Move the servo reference toward `cmd`, clipped to the servo range (`limits`), by at most
    `slew`; the fins' actuators (`fin_act`) in MuJoCo's `ctrl` follow it."""
    for i in range(cmd.shape[0]):
        target = cmd[i]
        if target < limits[i, 0]:
            target = limits[i, 0]
        if target > limits[i, 1]:
            target = limits[i, 1]
        gap = target - reference[i]
        if abs(gap) <= slew:
            reference[i] = target
        else:
            reference[i] += slew if gap > 0 else -slew
        ctrl[fin_act[i]] = reference[i]


@numba.njit(**_INNER)
def _turn(R, x, y, z):
    """R (x, y, z), as a tuple, R a rotation matrix stored row by row (MuJoCo's `xmat` row)."""
    return (R[0] * x + R[1] * y + R[2] * z, R[3] * x + R[4] * y + R[5] * z, R[6] * x + R[7] * y + R[8] * z)


@numba.njit(**_INNER)
def _turn_back(R, x, y, z):
    """Rᵀ (x, y, z), as a tuple, R as in `_turn`."""
    return (R[0] * x + R[3] * y + R[6] * z, R[1] * x + R[4] * y + R[7] * z, R[2] * x + R[5] * y + R[8] * z)


@numba.njit(**_INNER)
def _cross(a0, a1, a2, b0, b1, b2):
    """a × b, as a tuple."""
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@numba.njit(cache=True)
def _wrench_applied(qfrc, R, dofs, w):
    """`_apply_wrench`, from Python."""
    _apply_wrench(qfrc, R, dofs, w)


@numba.njit(**_INNER)
def _apply_wrench(qfrc, R, dofs, w):
    """Plain MuJoCo's applied force `qfrc`: the external wrench `w` alone (body axes turned to
    MuJoCo's; R: the hull's `xmat` row)."""
    f = _turn(R, w[0], -w[1], -w[2])
    for i in range(qfrc.shape[0]):
        qfrc[i] = 0.0
    for i in range(3):
        qfrc[dofs[i]] = f[i]
        qfrc[dofs[3 + i]] = w[3 + i] if i == 0 else -w[3 + i]


@numba.njit(**_INNER)
def _added_mass(P, M_hull, qpos, fin_qadr):
    """M9 = M_hull + Σ_k Σ_ij b_i b_j P_kij in hull axes (X_k affine in b = (1, cos δ_k, sin δ_k),
    δ_k = qpos[fin_qadr[k]]): a function of the fin angles only, so once per step (the fins are
    held over it)."""
    M9 = M_hull.copy()
    for f in range(P.shape[0]):
        c, s = math.cos(qpos[fin_qadr[f]]), math.sin(qpos[fin_qadr[f]])
        b = (1.0, c, s)
        for i in range(3):
            for j in range(3):
                wm = b[i] * b[j]
                for r in range(9):
                    for col in range(9):
                        M9[r, col] += wm * P[f, i, j, r, col]
    return M9


@numba.njit(**_INNER)
def _complete(k, M9):
    """Add Tᵀ M9 T to the CSR mass matrix; write the generalized force
    F = −M9 γ + buoyancy + wrench + the actuators' force on the hull (`k.actuation`, hull axes),
    in MuJoCo's coordinates (fin rates are zero)."""
    R, q, dofs = k.xmat[k.hull], k.qvel, k.dofs
    M9 = M9.copy()
    nu = np.empty(9)  # ν = (v, ω, δ̇), v = Rᵀ q̇_lin in hull axes
    for i in range(9):
        nu[i] = q[dofs[i]]
    nu[0], nu[1], nu[2] = _turn_back(R, nu[0], nu[1], nu[2])
    cw = _cross(nu[3], nu[4], nu[5], nu[0], nu[1], nu[2])
    F = np.empty(9)
    for r in range(9):  # −M9 γ with γ = (−ω × v, 0, 0)
        F[r] = M9[r, 0] * cw[0] + M9[r, 1] * cw[1] + M9[r, 2] * cw[2]
    B, w, a, cb = k.buoyancy, k.wrench, k.actuation, k.centre
    Bh = _turn_back(R, B[0], B[1], B[2])
    torque = _cross(cb[0], cb[1], cb[2], Bh[0], Bh[1], Bh[2])
    F[3] += torque[0] + w[3] + a[3]
    F[4] += torque[1] - w[4] + a[4]
    F[5] += torque[2] - w[5] + a[5]
    F[0], F[1], F[2] = _turn(R, F[0] + w[0] + a[0], F[1] - w[1] + a[1], F[2] - w[2] + a[2])
    # MuJoCo's free-joint linear velocity is in world axes: ν = T q̇, T = diag(Rᵀ, I).
    for r in range(9):
        M9[r, 0], M9[r, 1], M9[r, 2] = _turn(R, M9[r, 0], M9[r, 1], M9[r, 2])  # M9 Rᵀ rows
    for col in range(9):
        M9[0, col], M9[1, col], M9[2, col] = _turn(R, M9[0, col], M9[1, col], M9[2, col])
    for e in range(k.rows.shape[0]):
        k.M[e] += M9[k.rows[e], k.cols[e]]
    for i in range(9):
        k.qfrc[dofs[i]] = F[i] + (B[i] if i < 3 else 0.0)


@numba.njit(**_INNER)
def _solve_spd(H, b):
    """x = H⁻¹ b for a small symmetric positive definite H, by Cholesky H = L Lᵀ (in place)."""
    n = b.shape[0]
    for j in range(n):
        s = H[j, j]
        for m in range(j):
            s -= H[j, m] * H[j, m]
        H[j, j] = np.sqrt(s)
        for i in range(j + 1, n):
            s = H[i, j]
            for m in range(j):
                s -= H[i, m] * H[j, m]
            H[i, j] = s / H[j, j]
    for i in range(n):  # L y = b
        s = b[i]
        for m in range(i):
            s -= H[i, m] * b[m]
        b[i] = s / H[i, i]
    for i in range(n - 1, -1, -1):  # Lᵀ x = y
        s = b[i]
        for m in range(i + 1, n):
            s -= H[m, i] * b[m]
        b[i] = s / H[i, i]
    return b


def _added_mass_basis(model: mujoco.MjModel):
    """Precompute the hull-axis added mass of hull and fins and the buoyancy.

    Returns P (fins, 3, 3, 9, 9) with X_k = Σ_i basis_i X_ki, basis = (1, cos δ_k, sin δ_k),
    P[k, i, j] = X_kiᵀ M_k X_kj; the hull's 9×9 added mass; the total displaced volume and its
    centre in hull axes. `check_model` has made sure that fins hinge about their body origin and
    that their displaced volume lies on the hinge axis (buoyancy does not move with δ).
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
        fin = next(f for f in FINS if model.joint(f).bodyid[0] == b)  # check_model: one exists
        k, j = FINS.index(fin), model.joint(fin).id
        a = model.jnt_axis[j] / np.linalg.norm(model.jnt_axis[j])
        Q0 = rotation(model.body_quat[b])  # hull from fin at δ = 0
        p = model.body_pos[b]
        A = skew(a)
        # Rot(a, δ) = I + sin δ [a]× + (1 − cos δ)[a]×², so the fin's axes Q0 Rot(δ) and with them
        # its motion transform are affine in (1, c, s): one transform per term.
        Xs = []
        for i, rot in enumerate([np.eye(3) + A @ A, -A @ A, A]):
            X = np.zeros((6, 9))
            X[:, :6] = motion_transform(Q0 @ rot, p)
            X[3:, 6 + k] = a if i == 0 else 0.0
            Xs.append(X)
        P[k] = [[Xi.T @ Mb @ Xj for Xj in Xs] for Xi in Xs]
        volume, moment = volume + V, moment + V * (p + Q0 @ cb)
    return P, M_hull, volume, moment / volume


def step_cache() -> tuple[str, int, int]:
    """Where the completed plant's compiled step is cached on disk, and how many times this
    process loaded it from there and compiled it (numba's dispatcher statistics)."""
    stats = _advance.stats
    return stats.cache_path, sum(stats.cache_hits.values()), sum(stats.cache_misses.values())
