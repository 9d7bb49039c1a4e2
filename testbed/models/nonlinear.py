"""The nonlinear 6-DOF manoeuvring model (docs/model.md): `M ν̇ = F(ν, η, δ; θ)` and the
Euler-angle kinematics, over the states `u v w p q r phi theta psi z` with u the absolute speed.

    F = −C(ν) ν + g(η) + T e_x + Σ_k θ_k φ_k(ν, δ)

- M = M_RB + M_A: the vehicle's mass and inertias and the added mass the linear model holds (its
  `*dot` coefficients, `INERTIA`), the linear model's Mt body block (`linear.structure`).
- C(ν) ν: the Kirchhoff velocity forces of M (`mechanics.coriolis`): rigid-body Coriolis and
  centripetal forces, and the added mass's Coriolis and Munk terms, exact.
- g(η): weight and buoyancy at any attitude (`mechanics.restoring_state`).
- T: the propulsor's constant thrust, the drag of straight flight at the trim speed U (as the
  plant's propulsor is set): T = −Σ_{X terms} θ_k φ_k(U e_x, 0), so the model trims at U.
- Σ θ_k φ_k: the hydrodynamic terms (`regressors`), linear in their coefficients.

θ is `INERTIA` then the terms' coefficients (`NonlinearModel.names`). `rates` gives ẋ = f(x, δ, θ),
`jacobians` its exact ∂f/∂x and ∂f/∂δ, `sensitivities` ∂f/∂θ: M⁻¹ (φ_k + ∂T/∂θ_k e_x) for a term,
M⁻¹ (−C_k(ν) ν − ∂M/∂θ_k ν̇) for an inertia coefficient (C is linear in M). All take samples stacked
along the first axis (or one sample) and complex arrays, and evaluate the compiled model
(`nonlinear_kernels`, given the model at θ by `packed`; the compiler is loaded when the model is
first evaluated, not when a config naming it is read). `linearise` gives the linear model at
straight and level trim as the linear model's coefficients.
"""

from __future__ import annotations

import reprlib
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from testbed.errors import InputError
from testbed.models import linear
from testbed.models.components import KINDS, packed_components
from testbed.models.regressors import (
    PAIRS,
    ROWS,
    WEIGHTS,
    Term,
    factor_table,
    parse_term,
    term_components,
    term_wrenches,
)

__all__ = [
    "INERTIA",
    "TERMS",
    "Linearisation",
    "NonlinearModel",
    "OutsideEntry",
    "jacobians",
    "linearise",
    "nonlinear_model",
    "force_regressors",
    "forces",
    "packed",
    "rates",
    "row_least_squares",
    "rate_sensitivities",
    "nonlinear_theta",
    "thrust",
]

INERTIA = tuple(n for n in linear.COEFFICIENTS if n.endswith("dot"))  # M_A (and Ixz), as the linear model
# The default hydrodynamic terms: what MuJoCo's ellipsoid model gives the bundled torpedo in
# Scenario I's range (docs/model.md gives each term's reason).
TERMS = (
    "X_uu",
    "X_u|v|",
    "X_u|w|",
    "X_vv",
    "X_ww",
    "X_vv|v|",
    "X_ww|w|",
    "X_|v||w|",
    "X_vr",
    "X_wq",
    "X_rr",
    "X_qq",
    "X_uvdr",
    "X_urdr",
    "X_uwde",
    "X_uqde",
    "X_uudrdr",
    "X_uudede",
    "X_uudada",
    "X_u|vw|",
    "X_uu|vw|",
    "X_|vw||vw||vw|",
    "X_|vw|qq",
    "X_|vw|rr",
    "X_pp",
    "Y_uv",
    "Y_ur",
    "Y_up",
    "Y_v|v|",
    "Y_r|r|",
    "Y_uudr",
    "Y_uudrdrdr",
    "Y_uv|dr|",
    "Y_ur|dr|",
    "Y_v|vw|",
    "Z_uw",
    "Z_uq",
    "Z_w|w|",
    "Z_q|q|",
    "Z_uude",
    "Z_uudedede",
    "Z_uwdede",
    "Z_uqdede",
    "Z_uwdada",
    "Z_uqdada",
    "Z_uude|da|",
    "Z_w|vw|",
    "K_uv",
    "K_ur",
    "K_up",
    "K_p|p|",
    "K_p|q|",
    "K_p|r|",
    "K_uuda",
    "K_uqdr",
    "K_urde",
    "K_p|qr|",
    "K_pww",
    "K_pqq",
    "K_pwq",
    "K_pvv",
    "K_prr",
    "K_pvr",
    "K_daww",
    "K_daqq",
    "K_dawq",
    "K_dadede",
    "K_pdede",
    "K_pwde",
    "K_pqde",
    "K_prdr",
    "K_uvde",
    "K_uwdr",
    "K_uwda",
    "M_uw",
    "M_uq",
    "M_u|v|",
    "M_u|w|",
    "M_w|w|",
    "M_q|q|",
    "M_q|r|",
    "M_uude",
    "M_uudedede",
    "M_uwdede",
    "M_uqdede",
    "M_uwdada",
    "M_uqdada",
    "M_uude|da|",
    "M_w|vw|",
    "M_q|qr|",
    "N_uv",
    "N_ur",
    "N_up",
    "N_v|v|",
    "N_r|r|",
    "N_r|q|",
    "N_uudr",
    "N_uudrdrdr",
    "N_uv|dr|",
    "N_ur|dr|",
    "N_v|vw|",
    "N_r|qr|",
)
_BODY = slice(0, 6)


@dataclass(frozen=True)
class NonlinearModel:
    """One vehicle's nonlinear model over a term set (`nonlinear_model` builds and checks it)."""

    vehicle: linear.Vehicle
    terms: tuple[Term, ...]
    M_RB: np.ndarray  # 6 × 6: the vehicle's mass and inertias about its CG
    dM: np.ndarray  # (14, 6, 6): ∂M/∂θ_k of each INERTIA coefficient
    surge: np.ndarray  # over θ: the X terms' regressors at trim, −∂T/∂θ (0 elsewhere)

    @property
    def names(self) -> tuple[str, ...]:
        """θ's names in order: `INERTIA`, then the terms."""
        return INERTIA + tuple(t.name for t in self.terms)

    def inertia(self, theta) -> np.ndarray:
        """M = M_RB + M_A at θ (6 × 6)."""
        return self.M_RB + np.tensordot(np.asarray(theta)[: len(INERTIA)], self.dM, 1)


def nonlinear_model(vehicle: linear.Vehicle, terms=TERMS, components=()) -> NonlinearModel:
    """The model of `vehicle` (a submerged body: no GM, GM_L; Iy and zB given) over `terms`, whose
    component terms name `components` (`Component`s)."""
    if vehicle.GM is not None or vehicle.GM_L is not None or vehicle.omitted():
        raise InputError(
            "the nonlinear model is a submerged body's: expected Iy and zB given and no GM, GM_L "
            "(the restoring forces are those of weight at the CG and buoyancy at the CB)"
        )
    parsed = tuple(t if isinstance(t, Term) else parse_term(t, components) for t in terms)
    names = [t.name for t in parsed]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise InputError(f"term {twice[0]!r} is named twice; expected each term once")
    # a linear model's name means another thing here (Y_v: the linear terms scale with the speed),
    # but for the offsets, a constant force either way
    clash = sorted(set(names) & (set(linear.PARAMETERS) - set(linear.OFFSETS)))
    if clash:
        raise InputError(f"term {clash[0]!r} is a linear model's name; expected a nonlinear term")
    s = linear.structure(vehicle)
    dM = np.array([s.dMt[linear.ITHETA[n]][_BODY, _BODY] for n in INERTIA])
    with np.errstate(over="ignore", invalid="ignore"):  # a product of many factors: checked below
        trim = term_wrenches(parsed, np.array([[vehicle.speed, 0, 0, 0, 0, 0.0]]), np.zeros((1, linear.NU)))[
            0
        ]
    lost = [t for k, t in enumerate(parsed) if not np.all(np.isfinite(trim[:, k]))]
    if lost:
        raise InputError(
            f"term {reprlib.repr(lost[0].name)} ({len(lost[0].factors)} factors) is beyond the "
            f"floating-point range at the trim speed {vehicle.speed:g} m/s; expected a product of "
            "factors that stays finite"
        )
    surge = np.concatenate([np.zeros(len(INERTIA)), trim[0]])  # each term's surge force at trim
    return NonlinearModel(vehicle=vehicle, terms=parsed, M_RB=s.Mt0[_BODY, _BODY].copy(), dM=dM, surge=surge)


def nonlinear_theta(model: NonlinearModel, coefficients: Mapping[str, float]) -> np.ndarray:
    """θ in `model.names` order; a missing name is 0, an unknown one `InputError`."""
    unknown = sorted(set(coefficients) - set(model.names))
    if unknown:
        raise InputError(f"coefficient {unknown[0]!r} is not in the model; expected one of {model.names}")
    return np.array([float(coefficients.get(n, 0.0)) for n in model.names])


def thrust(model: NonlinearModel, theta) -> float:
    """T: the propulsor's thrust, which balances the X-row terms in straight flight at trim."""
    return -(model.surge @ np.asarray(theta))


def packed(model: NonlinearModel, theta, dtype=float) -> tuple:
    """The model at θ as the compiled kernels take it (`nonlinear_kernels`), its θ-dependent
    parts (coefficients, thrust, M and M⁻¹) of `dtype` (complex for a complex step in θ or in the
    state): (W, factor table, rows, c, T, M, M⁻¹, ∂M/∂θ_inertia, thrust shares, weight, buoyancy,
    r_B, pairs, each term's component (−1: none) and kind, the components' geometry and fins
    (`components.packed_components`) and the kinds the terms take of each)."""
    theta = np.asarray(theta).astype(dtype)
    M = model.inertia(theta)
    parts = term_components(model.terms)
    geometry, fins = packed_components(parts)
    used = np.zeros((len(parts), len(KINDS)), dtype=bool)  # the kinds the terms take of each
    for t in model.terms:
        if t.component is not None:
            used[parts.index(t.component), t.kind] = True
    v = model.vehicle
    return (
        WEIGHTS,
        factor_table(model.terms),
        np.array([t.row for t in model.terms], dtype=np.int64),
        np.ascontiguousarray(theta[len(INERTIA) :]),
        dtype(thrust(model, theta)),
        np.ascontiguousarray(M),
        np.ascontiguousarray(np.linalg.inv(M)),
        model.dM,
        np.ascontiguousarray(model.surge[len(INERTIA) :]),
        float(v.weight),
        float(v.buoyancy),
        np.array([v.xB, v.yB, v.zB], dtype=float),
        PAIRS,
        np.array(
            [-1 if t.component is None else parts.index(t.component) for t in model.terms], dtype=np.int64
        ),
        np.array([t.kind for t in model.terms], dtype=np.int64),
        geometry,
        fins,
        used,
    )


def _evaluate(model, theta, x, delta):
    """The compiled kernels, the model packed at θ and the samples x (n, 10), δ (n, 3), all of one
    dtype (complex where any is), and whether one sample was given."""
    from testbed.models import nonlinear_kernels  # numba: only when the model is evaluated

    x, delta = np.asarray(x), np.asarray(delta)
    single = x.ndim == 1
    dtype = complex if np.iscomplexobj(theta) or np.iscomplexobj(x) or np.iscomplexobj(delta) else float
    x = np.ascontiguousarray(np.atleast_2d(x), dtype)
    delta = np.ascontiguousarray(np.atleast_2d(delta), dtype)
    return nonlinear_kernels, packed(model, theta, dtype), x, delta, single


def _state_model(model, theta, x, delta, jacobian: bool, derivatives_in_theta: bool):
    """`nonlinear_kernels.state_model` at the samples: (F, ∂F/∂(x, δ), ẋ, ∂f/∂x, ∂f/∂δ, ∂f/∂θ),
    the derivatives not asked for one sample of scratch, and whether one sample was given."""
    kernels, m, x, delta, single = _evaluate(model, theta, x, delta)
    n, nx, nu = len(x), linear.NX, linear.NU
    J, P = (n if jacobian else 1), (n if derivatives_in_theta else 1)
    F, JF = np.zeros((n, 6), x.dtype), np.zeros((J, 6, nx + nu), x.dtype)
    f, A, B = np.empty((n, nx), x.dtype), np.empty((J, nx, nx), x.dtype), np.empty((J, nx, nu), x.dtype)
    G = np.empty((P, nx, len(model.names) if derivatives_in_theta else 0), x.dtype)
    kernels.state_model(m, x, delta, F, JF, f, A, B, G, jacobian, derivatives_in_theta)
    return F, JF, f, A, B, G, single


def _forces(model: NonlinearModel, theta, x, delta, derivatives: bool):
    """F (n, 6), and with `derivatives` also ∂F/∂x (n, 6, 10) and ∂F/∂δ (n, 6, 3)."""
    F, JF, *_ = _state_model(model, theta, x, delta, derivatives, False)
    return (F, JF[:, :, : linear.NX], JF[:, :, linear.NX :]) if derivatives else F


def forces(model: NonlinearModel, theta, x, delta) -> np.ndarray:
    """F (n, 6) at the states x (n, 10) and fin angles δ (n, 3): `M ν̇ = F`."""
    return _forces(model, theta, x, delta, False)


def force_regressors(model: NonlinearModel, x, delta) -> np.ndarray:
    """∂F/∂c (n, 6, K) for the terms' coefficients c: φ_k in term k's row (a component term's
    wrench in every row), and in surge the thrust's share −φ_k(U e_x, 0) of each term's surge
    force. F is affine in c: F = F|_{c=0} + (∂F/∂c) c."""
    x, delta = np.atleast_2d(x), np.atleast_2d(delta)
    out = term_wrenches(model.terms, x[:, _BODY], delta)
    out[:, 0, :] -= model.surge[len(INERTIA) :]
    return out


def row_least_squares(model: NonlinearModel, R, y, weights=None, held=()) -> np.ndarray:
    """The terms' coefficients c (K,) that minimise Σ_n w_n (y_nr − R_nr c)² in each body row r
    (R: `force_regressors` (n, 6, K), y (n, 6), w: `weights` (n,), default 1): each row's own
    terms fitted to it, the terms named in `held` left at 0. With component terms, which act in
    every row, all rows at once: Σ_r Σ_n w_n (y_nr − R_nr c)² / s_r², s_r the RMS of y's row r
    about its mean, so that forces and moments weigh alike."""
    w = np.ones(len(y)) if weights is None else np.sqrt(np.asarray(weights, float))
    c = np.zeros(len(model.terms))
    cols = [k for k, term in enumerate(model.terms) if term.name not in held]
    if any(model.terms[k].row < 0 for k in cols):
        spread = np.sqrt(np.mean((y - y.mean(axis=0)) ** 2, axis=0))
        scale = np.where(spread > 0, 1.0 / np.where(spread > 0, spread, 1.0), 0.0)
        A = (w[:, None, None] * scale[None, :, None] * R[:, :, cols]).reshape(-1, len(cols))
        c[cols] = np.linalg.lstsq(A, (w[:, None] * scale * y).ravel(), rcond=None)[0]
        return c
    for row in range(6):
        cols = [k for k, term in enumerate(model.terms) if term.row == row and term.name not in held]
        if cols:
            c[cols] = np.linalg.lstsq(w[:, None] * R[:, row, cols], w * y[:, row], rcond=None)[0]
    return c


def rates(model: NonlinearModel, theta, x, delta) -> np.ndarray:
    """ẋ = f(x, δ, θ) at the states x (n, 10) and fin angles δ (n, 3) (or one of each)."""
    *_, f, _, _, _, single = _state_model(model, theta, x, delta, False, False)
    return f[0] if single else f


def jacobians(model: NonlinearModel, theta, x, delta):
    """(ẋ, ∂f/∂x (n, 10, 10), ∂f/∂δ (n, 10, 3)), exact: M⁻¹ times the forces' Jacobians in the body
    rows, the kinematics' in the others."""
    _, _, f, A, B, _, single = _state_model(model, theta, x, delta, True, False)
    return (f[0], A[0], B[0]) if single else (f, A, B)


def rate_sensitivities(model: NonlinearModel, theta, x, delta) -> np.ndarray:
    """∂f/∂θ (n, 10, len(θ)): for a term M⁻¹ (φ_k e_row + ∂T/∂θ_k e_x), for an inertia
    coefficient M⁻¹ (−C_k(ν) ν − ∂M/∂θ_k ν̇) with C_k the Kirchhoff forces of ∂M/∂θ_k."""
    *_, G, single = _state_model(model, theta, x, delta, False, True)
    return G[0] if single else G


@dataclass(frozen=True)
class OutsideEntry:
    """An entry of the model's linearisation that the linear model's table has no place for."""

    name: str  # e.g. M_u (At), X_qdot (Mt), X_der (Bt)
    matrix: str  # Mt, At or Bt
    value: float


@dataclass(frozen=True)
class Linearisation:
    """The model linearised at straight and level trim at the vehicle's speed U, in the linear
    model's form `Mt ẋ = At x + Bt δ + St` (its states, u the perturbation u − U)."""

    coefficients: dict[str, float]  # the linear model's 35 coefficients and 6 offsets
    Mt: np.ndarray
    At: np.ndarray
    Bt: np.ndarray
    St: np.ndarray
    outside: tuple[OutsideEntry, ...]  # entries the linear table lacks (above rounding)


def linearise(model: NonlinearModel, theta) -> Linearisation:
    """The linear model at trim: the exact Jacobians of F and of the kinematics at (U e_x, 0),
    read off at the linear model's places (`linear.structure`): Y_v = U Y_uv, X_u = 2 U X_uu,
    Y_dr = U² Y_uudr, Y_r = U (Y_ur + X_udot), M_w = U (M_uw + X_udot − Z_wdot), … (docs/model.md).
    The offsets X_0 … N_0 take what F leaves at trim beyond the restoring terms."""
    theta = np.asarray(theta, float)
    x0, d0 = np.zeros((1, linear.NX)), np.zeros((1, linear.NU))
    x0[0, 0] = model.vehicle.speed
    F, Jx, Jd = (a[0] for a in _forces(model, theta, x0, d0, True))
    Mt, At, Bt = np.eye(linear.NX), np.zeros((linear.NX, linear.NX)), np.zeros((linear.NX, linear.NU))
    Mt[_BODY, _BODY], At[_BODY], Bt[_BODY] = model.inertia(theta), Jx, Jd
    At[6:] = jacobians(model, theta, x0[0], d0[0])[1][6:]
    St = np.concatenate([F, np.zeros(4)])
    s = linear.structure(model.vehicle)
    full = {"Mt": Mt, "At": At, "Bt": Bt, "St": St}
    out = {}
    for name in linear.COEFFICIENTS + linear.OFFSETS:
        k = linear.ITHETA[name]
        for matrix, D, D0 in (
            ("Mt", s.dMt[k], s.Mt0),
            ("At", s.dAt[k], s.At0),
            ("Bt", s.dBt[k], s.Bt0),
            ("St", s.dSt[k], s.St0),
        ):
            if D.any():  # the coefficient's places (factor f): Σ f (full − constant part) / Σ f²
                out[name] = float(np.sum(D * (full[matrix] - D0)) / np.sum(D * D))
    projected = dict(zip(("Mt", "At", "Bt"), linear.tilde(s, linear.theta_vector(out))[:3]))
    outside = []
    short = {"delta_r": "dr", "delta_er": "der", "delta_el": "del"}
    for matrix, cols in (
        ("Mt", [f"{c}dot" for c in linear.STATES]),
        ("At", linear.STATES),
        ("Bt", [short[i] for i in linear.INPUTS]),
    ):
        gap = full[matrix] - projected[matrix]
        scale = np.abs(full[matrix][_BODY]).max(axis=1)
        for r, c in zip(*np.nonzero(np.abs(gap[_BODY]) > 1e-10 * np.maximum(scale, 1e-300)[:, None])):
            value = float(-gap[r, c] if matrix == "Mt" else gap[r, c])
            outside.append(OutsideEntry(f"{ROWS[r]}_{cols[c]}", matrix, value))
    return Linearisation(out, Mt, At, Bt, St, tuple(outside))
