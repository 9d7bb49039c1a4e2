"""The analytic linear model of the completed plant, and its numerical check.

Both linearize about straight, level trim at speed U, fins at zero, with the fin angles as inputs
(fin dynamics excluded), in the continuous form `Mt ẋ = At x + Bt δ + St` over the model states
`u v w p q r phi theta psi z` (u the perturbation).

Analytic (`analytic_model`), from the compiled MJCF alone. Each fluid geom g feels MuJoCo's
ellipsoid model (docs: computation/fluid.rst) at its local velocity ν_g = X_g ν, with
X_g = [[Qᵀ, −Qᵀ[p]×], [0, Qᵀ]] (Q, p its pose in hull axes), and pushes on the hull with the
wrench X_gᵀ φ_g(ν_g) about the CG. At trim ν₀ = (U e_x, 0), so

    ∂wrench/∂ν = X_gᵀ J_g X_g,    ∂wrench/∂δ = X_g'ᵀ φ_g(ν_g0) + X_gᵀ J_g X_g' ν₀,

with J_g = ∂φ_g/∂ν_g in closed form (`geom_terms`) and X_g' from the hinge (Q' = Q0 [a]× Q_l).
The rigid body adds m ω × v (the m U terms), MuJoCo's added-mass inertia M_A (plant.py puts it in
the mass matrix) joins M_RB on the left, weight and buoyancy give the restoring terms, and the
Euler-angle kinematics close the model. Terms quadratic in ω (angular drag, (I_A ω) × ω, ω × Iω)
have no linear part at ω = 0.

Numerical (`numerical_model`): central differences of `Plant.body_accelerations` (the completed
plant's own dynamics, fins held) and of the nonlinear Euler-angle kinematics.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from testbed.data import ModelConfig, config_text
from testbed.outputs import atomic_write_text, check_outputs
from testbed.models.linear import (
    COEFFICIENTS,
    INPUTS,
    IX,
    NU,
    NX,
    STATES,
    Vehicle,
    structure,
    theta_vector,
    tilde,
)
from testbed.models.mechanics import kinematics
from testbed.simulation.plant import Plant
from testbed.simulation.states import plant_rates
from testbed.simulation.vehicle import (
    FLIP,
    FinLimits,
    added_mass,
    buoyancy_centre,
    check_model,
    constants,
    cruise_speed,
    fin_limits,
    fluid_frames,
    fluid_geoms,
    load_model,
    motion_transform,
    rigid_body_mass,
    semi_axes,
    skew,
    trim_speed,
)

__all__ = [
    "FREE",
    "FORCE_ROWS",
    "MUJOCO_TERMS",
    "LinearModel",
    "OutsideTerm",
    "analytic",
    "analytic_config",
    "analytic_config_text",
    "analytic_model",
    "geom_terms",
    "model_config",
    "numerical_model",
]

MUJOCO_TERMS = ("drag", "lift", "magnus", "added_mass", "viscous")  # MuJoCo's ellipsoid-model forces
FORCE_ROWS = "XYZKMN"  # force/moment letter of the rows u v w p q r
_T6 = np.kron(np.eye(2), FLIP)  # MuJoCo hull axes (FLU) <-> body axes (FRD), for (lin, ang)
# The default [identify] free list: the damping and control derivatives but X_u. The added-mass
# (*dot) terms stay at their potential-flow values: with them free the rows of Mt can be rescaled
# without changing the outputs (exactly unidentifiable directions, testbed.analysis.structural.structural).
# X_u stays too: at constant thrust no scenario excites surge, and the speed lost in turns is
# second order.
FREE = tuple(n for n in COEFFICIENTS if not n.endswith("dot") and n != "X_u")


@dataclass(frozen=True)
class OutsideTerm:
    """An entry of the full linear model that the linear model's structure lacks (or gets differently).

    `value` is in coefficient convention (the Mt entry with a minus sign, like X_udot), and is
    the full model's entry minus what the projection onto the linear model puts there. `relative` compares it to
    the largest entry of the same row of the same matrix (St: to the trim drag, times the hull
    length for moment rows).
    """

    name: str  # e.g. X_q (At), X_qdot (Mt), Z_der (Bt), M_0 (St)
    matrix: str  # Mt, At, Bt or St
    value: float
    relative: float


@dataclass(frozen=True)
class LinearModel:
    """The linearized completed plant at one trim: full, and projected onto the linear model."""

    vehicle: Vehicle
    coefficients: dict[str, float]  # the linear model's 35 coefficients
    Mt: np.ndarray  # the projection: tilde(structure(vehicle), coefficients)
    At: np.ndarray
    Bt: np.ndarray
    St: np.ndarray
    Mt_full: np.ndarray  # the full linear model, same form and states
    At_full: np.ndarray
    Bt_full: np.ndarray
    St_full: np.ndarray
    A_full: np.ndarray  # Mt_full⁻¹ At_full
    B_full: np.ndarray  # Mt_full⁻¹ Bt_full
    outside: tuple[OutsideTerm, ...]  # largest |relative| first
    parts: dict[str, tuple[np.ndarray, np.ndarray]]  # per fluid term: its (At, Bt) rows u..r
    added_mass: np.ndarray  # M_A, 6×6 about the CG, body axes (FRD), fins at 0
    thrust: float  # N, the trim drag
    fins: FinLimits  # the servos' range and rate, from the MJCF


# -- one geom: MuJoCo's ellipsoid model and its Jacobian --------------------------------------


def geom_terms(r, coef, virtual, rho, beta, v) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Each ellipsoid-model term on one geom at local velocity `v` (≠ 0) and ω = 0.

    `r` semi-axes, `coef` fluidcoef (blunt, slender, angular, Kutta, Magnus), `virtual` the
    geom_fluid virtual masses and inertias per unit density (6,), `rho` density, `beta`
    viscosity. Returns term → (wrench (force, torque) in the geom's axes, its 6×6 Jacobian with
    respect to the local (v, ω)). MuJoCo's formulas (engine_passive.c, mj_viscousForces and
    mj_addedMassForces), differentiated by hand.
    """
    r, v = np.asarray(r, float), np.asarray(v, float)
    blunt, slender, _angular, kutta, magnus = coef
    speed = np.linalg.norm(v)
    I3, V = np.eye(3), 4.0 / 3.0 * np.pi * np.prod(r)
    b = np.array([r[1] * r[2], r[2] * r[0], r[0] * r[1]]) ** 2  # normal to the projected section: b ∘ v
    N, D = b @ v**2, (b * b) @ v**2
    out = {}

    def term(
        f=np.zeros(3),
        g=np.zeros(3),
        fv=np.zeros((3, 3)),
        fw=np.zeros((3, 3)),
        gv=np.zeros((3, 3)),
        gw=np.zeros((3, 3)),
    ):
        return np.concatenate([f, g]), np.block([[fv, fw], [gv, gw]])

    # Quadratic drag −ρ [C_b A_p + C_s (A_max − A_p)] |v| v, A_p = π √(D/N) the projected area;
    # A_p is homogeneous of degree 0, its gradient vanishes along an axis.
    A_p = np.pi * math.sqrt(D / N)
    grad_A = np.pi**2 / A_p * v * (b * b * N - b * D) / N**2
    srt = np.sort(r)
    c = (blunt - slender) * A_p + slender * np.pi * srt[2] * srt[1]
    out["drag"] = term(
        f=-rho * c * speed * v,
        fv=-rho
        * (c * (speed * I3 + np.outer(v, v) / speed) + speed * np.outer(v, (blunt - slender) * grad_A)),
    )

    # Kutta lift s(v) ((b∘v) × v) × v with s = C_K ρ π √(N/D) / |v| (degree −1).
    n = b * v
    w = np.cross(np.cross(n, v), v)
    s = kutta * rho * np.pi * math.sqrt(N / D) / speed
    grad_s = s * (n / N - b * n / D - v / speed**2)
    dw = skew(v) @ skew(v) @ np.diag(b) - skew(v) @ skew(n) + skew(np.cross(n, v))
    out["lift"] = term(f=s * w, fv=np.outer(w, grad_s) + s * dw)

    # Magnus C_M ρ V ω × v: linear in ω.
    out["magnus"] = term(fw=-magnus * rho * V * skew(v))

    # Added-mass velocity terms: f = (m_A∘v) × ω, g = (m_A∘v) × v + (I_A∘ω) × ω (Munk moment).
    mA = rho * np.asarray(virtual[:3], float)
    p = mA * v
    out["added_mass"] = term(g=np.cross(p, v), fw=skew(p), gv=skew(p) - skew(v) @ np.diag(mA))

    # Stokes drag on the equivalent sphere (diameter 2/3 Σ r).
    d = 2.0 / 3.0 * r.sum()
    out["viscous"] = term(
        f=-3 * np.pi * d * beta * v, fv=-3 * np.pi * d * beta * I3, gw=-np.pi * d**3 * beta * I3
    )
    return out


def _motion_rate(Q, p, dQ, dp) -> np.ndarray:
    """dX/dδ for a geom whose pose (Q, p) turns with δ at rate (dQ, dp)."""
    X = motion_transform(dQ, p)
    X[:3, 3:] -= Q.T @ skew(dp)
    return X


def _geom_frames(model: mujoco.MjModel):
    """Per fluid geom: (g, fin index or None, Q, p, Q', p') in MuJoCo hull axes at δ = 0
    (`vehicle.fluid_frames`); ' is d/dδ of its fin's hinge angle, [a]× Q and [a]× (p − h) for a
    turn about the hinge line through h along a (zero on the hull)."""
    frames = []
    for g, fin, Q, p, hinge, axis in fluid_frames(model):
        if fin is None:
            frames.append((g, None, Q, p, np.zeros((3, 3)), np.zeros(3)))
        else:
            A = skew(axis)
            frames.append((g, fin, Q, p, A @ Q, A @ (p - hinge)))
    return frames


# -- the analytic model -----------------------------------------------------------------------


def analytic_model(model: mujoco.MjModel, speed: float) -> LinearModel:
    """The closed-form linearization of the completed plant about trim at `speed` (m/s)."""
    check_model(model)  # the plant's own check: what one accepts, so does the other
    vehicle = constants(model, speed)  # InputError unless trim_speed(speed)
    U = vehicle.speed
    M_RB = rigid_body_mass(model)
    rho, beta = model.opt.density, model.opt.viscosity
    nu0 = np.array([U, 0.0, 0.0, 0.0, 0.0, 0.0])  # hull axes (FLU): x is forward in both
    wrench0 = np.zeros(6)
    parts = {t: (np.zeros((6, 6)), np.zeros((6, NU))) for t in MUJOCO_TERMS}
    for g, fin, Q, p, dQ, dp in _geom_frames(model):
        X = motion_transform(Q, p)
        terms = geom_terms(
            semi_axes(model, g), model.geom_fluid[g, 1:6], model.geom_fluid[g, 6:12], rho, beta, (X @ nu0)[:3]
        )
        for t, (phi, J) in terms.items():
            wrench0 += X.T @ phi
            parts[t][0][:] += _T6 @ X.T @ J @ X @ _T6
            if fin is not None:
                dX = _motion_rate(Q, p, dQ, dp)
                parts[t][1][:, fin] += _T6 @ (dX.T @ phi + X.T @ J @ dX @ nu0)
    wrench0 = _T6 @ wrench0
    thrust = max(0.0, -wrench0[0])  # the propulsor holds the trim speed (as plant.reset does)

    M_A = added_mass(model)
    Mt = np.eye(NX)
    Mt[:6, :6] = M_RB + M_A
    At, Bt, St = np.zeros((NX, NX)), np.zeros((NX, NU)), np.zeros(NX)
    for t in MUJOCO_TERMS:
        At[:6, :6] += parts[t][0]
        Bt[:6] += parts[t][1]
    # Rigid body about its CG: −(m ω × v, ω × Iω), linear part −m ω × U e_x.
    m, i = M_RB[0, 0], IX  # i: state index
    At[i["v"], i["r"]] -= m * U
    At[i["w"], i["q"]] += m * U
    # Weight at the CG, buoyancy at the CB: (W − B)(−θ, φ, 1) and r_B × (−B (−θ, φ, 1)).
    W, Bu, rB = vehicle.weight, vehicle.buoyancy, buoyancy_centre(model)
    down = {"phi": np.array([0.0, 1.0, 0.0]), "theta": np.array([-1.0, 0.0, 0.0])}
    for angle, e in down.items():
        At[:3, i[angle]] += (W - Bu) * e
        At[3:6, i[angle]] += np.cross(rB, -Bu * e)
    St[:6] = wrench0 + np.array([thrust, 0, 0, 0, 0, 0])
    St[:3] += (W - Bu) * np.array([0.0, 0.0, 1.0])
    St[3:6] += np.cross(rB, [0.0, 0.0, -Bu])
    # Euler-angle kinematics and depth rate, linearized: φ̇ = p, θ̇ = q, ψ̇ = r, ż = w − U θ.
    for angle, rate in (("phi", "p"), ("theta", "q"), ("psi", "r")):
        At[i[angle], i[rate]] = 1.0
    At[i["z"], i["w"]], At[i["z"], i["theta"]] = 1.0, -U

    coefficients = _project(Mt, At, Bt, vehicle)
    s = structure(vehicle)
    Mt_s, At_s, Bt_s, St_s = tilde(s, theta_vector(coefficients))
    sol = np.linalg.solve(Mt, np.column_stack([At, Bt]))
    outside = _outside(
        Mt - Mt_s,
        At - At_s,
        Bt - Bt_s,
        St - St_s,
        Mt,
        At,
        Bt,
        thrust,
        2 * semi_axes(model, _hull_geom(model)).max(),
    )
    return LinearModel(
        vehicle,
        coefficients,
        Mt_s,
        At_s,
        Bt_s,
        St_s,
        Mt,
        At,
        Bt,
        St,
        sol[:, :NX],
        sol[:, NX:],
        outside,
        parts,
        M_A,
        thrust,
        fins=fin_limits(model),
    )


def _hull_geom(model) -> int:
    hull = model.body("hull").id
    return int(next(g for g in fluid_geoms(model) if model.geom_bodyid[g] == hull))


def _project(Mt, At, Bt, vehicle: Vehicle) -> dict[str, float]:
    """The linear model's 35 coefficients read off the full model at the table's places.

    *dot terms: minus the off-rigid-body part of the mass matrix, i.e. −M_A, plus (K_rdot,
    N_pdot) the rigid body's product of inertia, which the linear model's known constants lack. The others
    are the total derivatives, less the m U the table writes out.
    """
    s = structure(vehicle)
    out = {}
    for k, name in enumerate(COEFFICIENTS):
        for matrix, D, D0 in (("Mt", s.dMt[k], s.Mt0), ("At", s.dAt[k], s.At0), ("Bt", s.dBt[k], s.Bt0)):
            if D.any():
                full = {"Mt": Mt, "At": At, "Bt": Bt}[matrix]
                # the coefficient's places (factor f): Σ f (full − constant part) / Σ f²
                out[name] = float(np.sum(D * (full - D0)) / np.sum(D * D))
    return out


def _outside(dMt, dAt, dBt, dSt, Mt, At, Bt, thrust, length) -> tuple[OutsideTerm, ...]:
    """The full model's entries beyond the projection onto the linear model, above rounding (relative 1e-10)."""
    short = {"delta_r": "dr", "delta_er": "der", "delta_el": "del"}
    terms = []
    for row in range(6):
        X = FORCE_ROWS[row]
        for col in range(NX):
            terms.append(
                OutsideTerm(
                    f"{X}_{STATES[col]}",
                    "At",
                    float(dAt[row, col]),
                    abs(dAt[row, col]) / np.abs(At[row]).max(),
                )
            )
        for col in range(6):
            terms.append(
                OutsideTerm(
                    f"{X}_{STATES[col]}dot",
                    "Mt",
                    float(-dMt[row, col]),
                    abs(dMt[row, col]) / np.abs(Mt[row]).max(),
                )
            )
        for col in range(NU):
            terms.append(
                OutsideTerm(
                    f"{X}_{short[INPUTS[col]]}",
                    "Bt",
                    float(dBt[row, col]),
                    abs(dBt[row, col]) / max(np.abs(Bt[row]).max(), 1e-300),
                )
            )
        scale = max(thrust, 1e-300) * (length if row >= 3 else 1.0)
        terms.append(OutsideTerm(f"{X}_0", "St", float(dSt[row]), abs(dSt[row]) / scale))
    return tuple(sorted((t for t in terms if t.relative > 1e-10), key=lambda t: -t.relative))


# -- the numerical model ----------------------------------------------------------------------


def numerical_model(plant_or_model, speed: float) -> tuple[np.ndarray, np.ndarray]:
    """`A, B` of the completed plant by central differences of its own dynamics at trim.

    `Plant.body_accelerations` (fins held at the perturbed angles, fin rates zero) gives the
    u..r rows; the nonlinear Euler-angle kinematics the φ θ ψ z rows. All ten states and the
    three fin angles are perturbed (ψ and z should have no effect). Resets the plant.
    """
    speed = trim_speed(speed)
    plant = plant_or_model if isinstance(plant_or_model, Plant) else Plant(model=plant_or_model)
    plant.reset(speed)
    m, U = plant.model, float(speed)
    depth = float(-plant.data.qpos[m.jnt_qposadr[m.joint("hull").id] + 2])
    trim = np.zeros(NX)
    trim[IX["u"]] = U

    def rates(x, delta):
        x = x + trim  # absolute u
        return np.concatenate([plant_rates(plant, x, delta, depth)[0], kinematics(x[None])[0][0]])

    # Angular drag is ρ κ |ω| ω: odd and not smooth at ω = 0, so a central difference errs by
    # κ h; the rate steps are small for that reason.
    h = np.array([1e-4 * U] * 3 + [1e-7] * 3 + [1e-4, 1e-4, 1e-4, 1e-3])
    x0, d0 = np.zeros(NX), np.zeros(NU)
    A = np.column_stack([(rates(x0 + e, d0) - rates(x0 - e, d0)) / (2 * e.sum()) for e in np.diag(h)])
    hd = 1e-4
    B = np.column_stack([(rates(x0, e) - rates(x0, -e)) / (2 * hd) for e in np.eye(NU) * hd])
    plant.reset(speed)
    return A, B


# -- the model config --------------------------------------------------------------------------


def analytic(mjcf: str | Path | None = None, speed: float | None = None) -> LinearModel:
    """The analytic model of `mjcf` (default: the bundled torpedo) at `speed` (default: its
    cruise speed)."""
    model = load_model(mjcf)
    return analytic_model(model, cruise_speed(model) if speed is None else trim_speed(speed))


def analytic_config(mjcf: str | Path | None = None, speed: float | None = None):
    """`(ModelConfig, comments)` of the analytic model of `mjcf` (default: the bundled torpedo)
    at `speed` (default: its cruise speed), for `testbed.data.config_text`.

    The comments give each coefficient's make-up and, on each row's damping coefficient, the
    full model's terms outside the linear model's structure.
    """
    return model_config(analytic(mjcf, speed), mjcf)


def analytic_config_text(
    mjcf: str | Path | None = None, speed: float | None = None, out=None, force: bool = False
) -> str:
    """The analytic model of `mjcf` at `speed` as a model config (TOML text, with each
    coefficient's make-up in comments), also written to `out` when given (an existing file
    there is refused unless `force`)."""
    check_outputs([mjcf] if mjcf else [], {"out": out}, force)
    text = config_text(*analytic_config(mjcf, speed))
    if out is not None:
        atomic_write_text(out, text, force)
    return text


def model_config(lin: LinearModel, mjcf=None):
    """`(ModelConfig, comments)` of an analytic model already computed (see `analytic_config`); its
    free list, `FREE`, is the candidates `identify` screens (`screen`), not a user's choice."""
    config = ModelConfig(lin.vehicle, dict(lin.coefficients), FREE, str(mjcf or ""), screen=True)
    return config, _comments(lin, mjcf)


def _comments(lin: LinearModel, mjcf) -> dict[str, str]:
    where = Path(mjcf).name if mjcf else "the bundled torpedo"
    notes = {"speed": f"U, trim speed; analytic model of {where}"}
    s = structure(lin.vehicle)
    for k, name in enumerate(COEFFICIENTS):
        if name.endswith("dot"):
            r, c = np.argwhere(s.dMt[k])[0]
            notes[name] = f"-M_A = {-lin.added_mass[r, c]:.6g}"
            rigid = lin.Mt_full[r, c] - lin.added_mass[r, c]  # off-diagonal: a product of inertia
            if r != c and abs(rigid) > 1e-4 * abs(lin.coefficients[name]):
                notes[name] += f", minus the rigid-body product of inertia {rigid:.6g}"
            continue
        matrix, D = (0, s.dAt[k]) if s.dAt[k].any() else (1, s.dBt[k])
        parts = []
        for t in MUJOCO_TERMS:
            block = lin.parts[t][matrix]
            value = float(np.sum(D[:6, : block.shape[1]] * block) / np.sum(D * D))
            if abs(value) > 1e-9 * max(1.0, abs(lin.coefficients[name])):
                parts.append(f"{t.replace('_', ' ')} {value:.4g}")
        notes[name] = ", ".join(parts) if parts else "no fluid term"
    for row, diag in enumerate(("X_u", "Y_v", "Z_w", "K_p", "M_q", "N_r")):
        extra = [t for t in lin.outside if t.name[0] == FORCE_ROWS[row]][:4]
        if extra:
            notes[diag] += "; outside the linear model: " + ", ".join(
                f"{t.name} = {t.value:.3g} ({100 * t.relative:.2g} % of row)" for t in extra
            )
    return notes
