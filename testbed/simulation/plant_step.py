"""The completed plant's step, compiled (numba): MuJoCo's own passes called from the compiled
loop through its C API, the fins' servos, the hull's and fins' added mass in the mass matrix and
the buoyancy, integrated by RK4 (`plant` module doc). `Kernel` holds the views of MjData's
arrays and the plant's constants the step reads and writes; `advance` runs it, `advance_plain`
runs plain MuJoCo, `completion` evaluates the completed accelerations once.
"""

from __future__ import annotations
import math
from pathlib import Path
from typing import NamedTuple
import llvmlite.binding
import mujoco
import numba
import numpy as np
from testbed.models.cholesky import solve_spd
from testbed.simulation.vehicle import FIN_JOINTS, hydrostatics, motion_transform, quaternion_matrix, skew

__all__ = [
    "Kernel",
    "MAX_VELOCITY",
    "added_mass_basis",
    "advance",
    "advance_plain",
    "completion",
    "step_cache",
    "wrench_applied",
]


class Kernel(NamedTuple):
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
    P: np.ndarray  # (fins, 3, 3, 9, 9), see added_mass_basis
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


MAX_VELOCITY = 1e4  # m/s or rad/s: no vehicle gets near; MuJoCo's own limit (1e10) is late


# The compiled step is written as scalar loops over small arrays, without numpy's library
# functions (cross, norm, slice assignment, reshape, min): each of those costs the compiler more
# than the whole step does, and a new install compiles it once (benchmarks/bench_cold.py). The
# helpers have no Python entry of their own (`_INNER`), the leaves take the arrays they use, not
# the whole `Kernel`, and the step, its RK4 stages and their forward evaluation are written out
# in `advance`, their one caller: a compiled function is optimised again in every caller it is linked into, and one
# inlined by numba copies its IR and the whole `Kernel` (a reference count per array) at every
# call. Its scratch arrays are made once per call, not per step. The plain-MuJoCo loop and the
# completion called from Python are compiled apart, only when used.
_INNER = dict(no_cpython_wrapper=True, no_cfunc_wrapper=True)


@numba.njit(cache=True)
def advance(model, data, k, n, h, cmd, slew):
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
                    a = solve_spd(H, rhs)  # H q̈_hull = f_hull
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
def advance_plain(model, data, k, n, h, cmd, slew):
    """`advance` for plain MuJoCo: `mj_step` with the external wrench applied (`h` is the
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
def completion(k):
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
    `MAX_VELOCITY`, or -1 for neither."""
    for i in range(warned.shape[0]):
        if warnings[i] != warned[i]:
            return i
    for i in range(qvel.shape[0]):
        if not abs(qvel[i]) <= MAX_VELOCITY:  # NaN too
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
def wrench_applied(qfrc, R, dofs, w):
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


def added_mass_basis(model: mujoco.MjModel):
    """Precompute the hull-axis added mass of hull and fins and the buoyancy.

    Returns P (fins, 3, 3, 9, 9) with X_k = Σ_i basis_i X_ki, basis = (1, cos δ_k, sin δ_k),
    P[k, i, j] = X_kiᵀ M_k X_kj; the hull's 9×9 added mass; the total displaced volume and its
    centre in hull axes. `check_model` has made sure that fins hinge about their body origin and
    that their displaced volume lies on the hinge axis (buoyancy does not move with δ).
    """
    h = hydrostatics(model)
    hull = model.body("hull").id
    P = np.zeros((len(FIN_JOINTS), 3, 3, 9, 9))
    M_hull = np.zeros((9, 9))
    volume, moment = 0.0, np.zeros(3)
    for b, Mb, V, cb in zip(h.bodies, h.added_mass, h.volume, h.centroid):
        if b == hull:
            M_hull[:6, :6] += Mb
            volume, moment = volume + V, moment + V * cb
            continue
        fin = next(f for f in FIN_JOINTS if model.joint(f).bodyid[0] == b)  # check_model: one exists
        k, j = FIN_JOINTS.index(fin), model.joint(fin).id
        a = model.jnt_axis[j] / np.linalg.norm(model.jnt_axis[j])
        Q0 = quaternion_matrix(model.body_quat[b])  # hull from fin at δ = 0
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
    stats = advance.stats
    return stats.cache_path, sum(stats.cache_hits.values()), sum(stats.cache_misses.values())
