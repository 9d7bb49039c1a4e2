"""The paper's linear model (docs/model.md): `Mt ẋ = At x + Bt δ + St`.

Every matrix is affine in the 35 coefficients and the 6 constant offsets (`PARAMETERS`, which
also holds the outputs' 10 biases, the current, the velocity log's mounting and the inputs' delay), so the model is held as a constant part plus one derivative
matrix per parameter (`Structure`); `tilde` evaluates it, `continuous` gives
`A = Mt⁻¹At, B = Mt⁻¹Bt, S = Mt⁻¹St`, and `discretize` gives the exact zero-order-hold model
through the block-matrix exponential (valid for singular A: ψ and z are pure integrators);
`expm_pair` gives it with its exact first and second derivatives.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Mapping

import numpy as np

__all__ = [
    "COEFFICIENTS",
    "INPUTS",
    "BIASES",
    "BODY",
    "CURRENT",
    "DELAY",
    "IBIAS",
    "ICURRENT",
    "IDELAY",
    "IMOUNTING",
    "ITHETA",
    "IX",
    "MAX_SPEED",
    "MIN_SPEED",
    "MOUNTING",
    "NTHETA",
    "NU",
    "NX",
    "OFFSETS",
    "OUTPUT_TERMS",
    "OUTSIDE_EQUATIONS",
    "PARAMETERS",
    "STATES",
    "Structure",
    "Vehicle",
    "continuous",
    "derivatives",
    "discretize",
    "expm_pair",
    "inertia_defect",
    "pitch_dependents",
    "structure",
    "theta_vector",
    "tilde",
    "unobserved",
]

STATES = ("u", "v", "w", "p", "q", "r", "phi", "theta", "psi", "z")
INPUTS = ("delta_r", "delta_er", "delta_el")
COEFFICIENTS = (
    "X_udot",
    "X_u",
    "Y_vdot",
    "Y_pdot",
    "Y_rdot",
    "Y_v",
    "Y_p",
    "Y_r",
    "Y_dr",
    "Z_wdot",
    "Z_qdot",
    "Z_w",
    "Z_q",
    "Z_de",
    "K_vdot",
    "K_pdot",
    "K_rdot",
    "K_v",
    "K_p",
    "K_r",
    "K_dr",
    "K_der",
    "K_del",
    "M_wdot",
    "M_qdot",
    "M_w",
    "M_q",
    "M_de",
    "N_vdot",
    "N_pdot",
    "N_rdot",
    "N_v",
    "N_p",
    "N_r",
    "N_dr",
)
# Constant force and moment offsets per body row (N, N m): what a trial's imperfections add to
# the right side and no coefficient carries (a fin's zero error times its control derivative, a
# propeller's torque, a weight or centre-of-gravity error, a steady current's drag). They enter
# St; a config leaves them 0 and fixed unless it names them.
OFFSETS = ("X_0", "Y_0", "Z_0", "K_0", "M_0", "N_0")
# Output biases (SI, per state): a sensor's constant error, y = x + b. They act on the outputs,
# not on the motion: every derivative matrix is zero for them.
BIASES = tuple(f"b_{s}" for s in STATES)
# A steady current (m/s, north and east): the water's velocity over the ground. The states are
# the motion through the water; a velocity log tracking the bottom reads the motion over it.
CURRENT = ("c_N", "c_E")
# A velocity log's mounting: its axes turned from the body's about y and z (rad) and its position
# from the CG (m, body axes). It reads the velocity of its point in its axes, mixing the
# velocities and the rates (`testbed.models.log_mounting`); 0: at the CG, aligned.
MOUNTING = ("m_dvl_y", "m_dvl_z", "r_dvl_x", "r_dvl_y", "r_dvl_z")
OUTPUT_TERMS = BIASES + CURRENT + MOUNTING  # the parameters that act on the outputs alone
# The recorded fin angles' lag behind the fins (s): the fins' angle at t is the one recorded at
# t + input_delay (an encoder or a logger late by that much).
DELAY = "input_delay"
PARAMETERS = COEFFICIENTS + OFFSETS + OUTPUT_TERMS + (DELAY,)  # the model's parameter vector θ, in this order
OUTSIDE_EQUATIONS = OUTPUT_TERMS + (DELAY,)  # the parameters no matrix of the equations holds
NX, NU, NTHETA = len(STATES), len(INPUTS), len(PARAMETERS)
MIN_SPEED = 1e-3  # m/s: trim speeds below it are absurd (and near 1e-150 the fluid terms are 0/0)
# m/s: Mach 0.3 in water (sound: ~1500 m/s); beyond it no incompressible fluid model (MuJoCo's,
# the paper's) holds, and near 1e150 the fluid terms overflow
MAX_SPEED = 450.0
IX = {name: i for i, name in enumerate(STATES)}
ITHETA = {name: i for i, name in enumerate(PARAMETERS)}
IBIAS = np.array([ITHETA[b] for b in BIASES])  # θ[IBIAS]: the output biases in state order
ICURRENT = np.array([ITHETA[c] for c in CURRENT])  # θ[ICURRENT]: the current (north, east)
IDELAY = ITHETA[DELAY]
IMOUNTING = np.array([ITHETA[m] for m in MOUNTING])  # θ[IMOUNTING]: the velocity log's mounting

# Where each coefficient sits: (matrix, row, column, factor); Mt entries carry a minus sign.
_PLACES = {
    "X_udot": [("Mt", "u", "u", -1)],
    "X_u": [("At", "u", "u", 1)],
    "Y_vdot": [("Mt", "v", "v", -1)],
    "Y_pdot": [("Mt", "v", "p", -1)],
    "Y_rdot": [("Mt", "v", "r", -1)],
    "Y_v": [("At", "v", "v", 1)],
    "Y_p": [("At", "v", "p", 1)],
    "Y_r": [("At", "v", "r", 1)],
    "Y_dr": [("Bt", "v", 0, 1)],
    "Z_wdot": [("Mt", "w", "w", -1)],
    "Z_qdot": [("Mt", "w", "q", -1)],
    "Z_w": [("At", "w", "w", 1)],
    "Z_q": [("At", "w", "q", 1)],
    "Z_de": [("Bt", "w", 1, 0.5), ("Bt", "w", 2, 0.5)],
    "K_vdot": [("Mt", "p", "v", -1)],
    "K_pdot": [("Mt", "p", "p", -1)],
    "K_rdot": [("Mt", "p", "r", -1)],
    "K_v": [("At", "p", "v", 1)],
    "K_p": [("At", "p", "p", 1)],
    "K_r": [("At", "p", "r", 1)],
    "K_dr": [("Bt", "p", 0, 1)],
    "K_der": [("Bt", "p", 1, 1)],
    "K_del": [("Bt", "p", 2, -1)],
    "M_wdot": [("Mt", "q", "w", -1)],
    "M_qdot": [("Mt", "q", "q", -1)],
    "M_w": [("At", "q", "w", 1)],
    "M_q": [("At", "q", "q", 1)],
    "M_de": [("Bt", "q", 1, 0.5), ("Bt", "q", 2, 0.5)],
    "N_vdot": [("Mt", "r", "v", -1)],
    "N_pdot": [("Mt", "r", "p", -1)],
    "N_rdot": [("Mt", "r", "r", -1)],
    "N_v": [("At", "r", "v", 1)],
    "N_p": [("At", "r", "p", 1)],
    "N_r": [("At", "r", "r", 1)],
    "N_dr": [("Bt", "r", 0, 1)],
    **{name: [("St", row, None, 1)] for name, row in zip(OFFSETS, ("u", "v", "w", "p", "q", "r"))},
    **{name: [] for name in OUTPUT_TERMS + (DELAY,)},
}


@dataclass(frozen=True)
class Vehicle:
    """The linear model's known constants (SI; CB relative to the CG in body axes).

    `GM`, `GM_L`: a floating body's transverse and longitudinal metacentric heights; where given,
    the roll (pitch) restoring moment is −W GM φ (−W GM_L θ) instead of zB B φ (zB B θ). `Iy`, and
    `zB` where `GM` is given, serve only the pitch row: they may be None where no state the data
    give depends on that row (`pitch_dependents`); the model then holds stand-ins (`structure`)."""

    mass: float
    Ix: float
    Iy: float | None
    Iz: float
    weight: float
    buoyancy: float
    xB: float
    yB: float
    zB: float | None
    speed: float
    GM: float | None = None
    GM_L: float | None = None

    @classmethod
    def names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))

    def omitted(self) -> tuple[str, ...]:
        """The pitch row's constants left out (None): `Iy`, and `zB` where no `GM_L` replaces it."""
        needed = (("Iy", self.Iy), ("zB", self.zB if self.GM_L is None else self.GM_L))
        return tuple(n for n, v in needed if v is None)


@dataclass(frozen=True)
class Structure:
    """`Mt = Mt0 + Σ θ_i dMt[i]`, and likewise At, Bt, St, for one vehicle."""

    Mt0: np.ndarray
    At0: np.ndarray
    Bt0: np.ndarray
    St0: np.ndarray
    dMt: np.ndarray = field(repr=False)  # (NTHETA, 10, 10)
    dAt: np.ndarray = field(repr=False)  # (NTHETA, 10, 10)
    dBt: np.ndarray = field(repr=False)  # (NTHETA, 10, 3)
    dSt: np.ndarray = field(repr=False)  # (NTHETA, 10): the offsets; the restoring terms are known


def structure(vehicle: Vehicle) -> Structure:
    """The affine structure of the linear model's table (docs/model.md) for `vehicle`."""
    m, U, W, B = vehicle.mass, vehicle.speed, vehicle.weight, vehicle.buoyancy
    xB, yB, zB = vehicle.xB, vehicle.yB, vehicle.zB
    # the roll and pitch restoring stiffnesses: −W GM where a metacentric height is given, else
    # zB B; an omitted pitch constant (`Vehicle.omitted`) gets a stand-in, Iz for Iy and the roll
    # stiffness for the pitch one, which reaches no state the data give (`pitch_dependents`)
    roll = -W * vehicle.GM if vehicle.GM is not None else zB * B
    pitch = -W * vehicle.GM_L if vehicle.GM_L is not None else (zB * B if zB is not None else roll)
    Iy = vehicle.Iy if vehicle.Iy is not None else vehicle.Iz
    i = IX
    Mt0 = np.eye(NX)
    Mt0[i["u"], i["u"]] = Mt0[i["v"], i["v"]] = Mt0[i["w"], i["w"]] = m
    Mt0[i["p"], i["p"]], Mt0[i["q"], i["q"]], Mt0[i["r"], i["r"]] = vehicle.Ix, Iy, vehicle.Iz
    At0 = np.zeros((NX, NX))
    St0 = np.zeros(NX)
    At0[i["u"], i["theta"]] = -(W - B)
    At0[i["v"], i["r"]] = -m * U
    At0[i["v"], i["phi"]] = W - B
    At0[i["w"], i["q"]] = m * U
    St0[i["w"]] = W - B
    At0[i["p"], i["phi"]] = roll
    St0[i["p"]] = -yB * B
    At0[i["q"], i["theta"]] = pitch
    St0[i["q"]] = xB * B
    At0[i["r"], i["phi"]] = -xB * B
    At0[i["r"], i["theta"]] = -yB * B
    for angle, rate in (("phi", "p"), ("theta", "q"), ("psi", "r")):
        At0[i[angle], i[rate]] = 1.0
    At0[i["z"], i["w"]] = 1.0
    At0[i["z"], i["theta"]] = -U
    d = {
        "Mt": np.zeros((NTHETA, NX, NX)),
        "At": np.zeros((NTHETA, NX, NX)),
        "Bt": np.zeros((NTHETA, NX, NU)),
        "St": np.zeros((NTHETA, NX)),
    }
    for k, name in enumerate(PARAMETERS):
        for matrix, row, col, factor in _PLACES[name]:
            if col is None:
                d[matrix][k, i[row]] = factor
            else:
                d[matrix][k, i[row], col if isinstance(col, int) else i[col]] = factor
    return Structure(Mt0, At0, np.zeros((NX, NU)), St0, d["Mt"], d["At"], d["Bt"], d["St"])


def theta_vector(coefficients: Mapping[str, float]) -> np.ndarray:
    """θ: the 35 coefficients, the 6 offsets, the 10 output biases, the current and the input
    delay in `PARAMETERS` order; a missing name is 0."""
    unknown = set(coefficients) - set(PARAMETERS)
    if unknown:
        raise KeyError(f"unknown coefficient {sorted(unknown)[0]!r}")
    return np.array([float(coefficients.get(n, 0.0)) for n in PARAMETERS])


def tilde(s: Structure, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """`Mt, At, Bt, St` at the full parameter vector `theta` (NTHETA,)."""
    return (
        s.Mt0 + (theta @ s.dMt.reshape(len(s.dMt), -1)).reshape(s.Mt0.shape),
        s.At0 + (theta @ s.dAt.reshape(len(s.dAt), -1)).reshape(s.At0.shape),
        s.Bt0 + (theta @ s.dBt.reshape(len(s.dBt), -1)).reshape(s.Bt0.shape),
        s.St0 + theta @ s.dSt,
    )


def continuous(s: Structure, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`A, B, S` of `ẋ = A x + B δ + S`; raises `np.linalg.LinAlgError` if Mt is singular."""
    Mt, At, Bt, St = tilde(s, theta)
    sol = np.linalg.solve(Mt, np.column_stack([At, Bt, St]))
    return sol[:, :NX], sol[:, NX : NX + NU], sol[:, -1]


def discretize(A: np.ndarray, B: np.ndarray, S: np.ndarray, dt: float):
    """Exact zero-order-hold model `x[k+1] = Φ x[k] + Γ δ[k] + s`.

    One exponential of the block matrix [[A, B, S], [0, 0, 0]] Δ (`expm_pair`), so singular A
    is fine.
    """
    n, m = B.shape
    M = np.column_stack([A, B, S])
    E = expm_pair(M, np.zeros((n, 0, n + m + 1), dtype=M.dtype), dt)[0]
    return E[:, :n], E[:, n : n + m], E[:, -1]


def expm_pair(M: np.ndarray, dM: np.ndarray, dt: float, second=None):
    """`(E, dE)`: the top n rows of `expm(M̄ Δ)` and of its derivatives, where `M̄ = [[M], [0]]`
    is square (its last q − n rows zero) and `dM[:, i, :] = ∂M/∂θ_i` (n, p, q); `dE` is laid out
    like `dM`, so `dE @ ξ` is the (n, p) Jacobian `∂(E ξ)/∂θ` in one product.

    `second = (d2M, i, j)`: also the second derivatives `∂²E/∂θ_i∂θ_j` (P, n, q) for the pairs
    `(i[k], j[k])`, `d2M[k] = ∂²M/∂θ_i∂θ_j` (P, n, q); then `(E, dE, d2E)`.

    Van Loan: the upper-right block of `expm([[M̄, ∂M̄_i], [0, M̄]] Δ)` is `∂expm(M̄Δ)`, and that
    of the 4×4 block matrix with `∂M̄_i, ∂M̄_j, ∂²M̄_ij` above the diagonal is `∂²expm(M̄Δ)`.
    Computed for all i (and pairs) at once by scaling and squaring of the block-triangular
    matrices: Taylor at `h = Δ/2ˢ` with `‖A h‖₁ ≤ 1/2`, with `T_k = T_{k−1} X / k`,
      ∂T_k = (∂T_{k−1} X + T_{k−1} ∂X) / k,
      ∂²T_k = (∂²T_{k−1} X + ∂_iT_{k−1} ∂_jX + ∂_jT_{k−1} ∂_iX + T_{k−1} ∂²X) / k,
    then `E ← E²`, `∂E ← E ∂E + ∂E E`, `∂²E ← E ∂²E + ∂_iE ∂_jE + ∂_jE ∂_iE + ∂²E E` s times, top
    rows only. Only A (the first n columns) enters the powers, so the input columns (B, large
    for the fins) set neither s nor the number of terms: the k-th term of E and of ∂E is bounded
    by `‖Ah‖^(k−1)/(k−1)!` of the first (of ∂²E by `‖Ah‖^(k−2)/(k−2)!`: one term more), and the
    series stops where that bound is below 2⁻⁵³ (16 terms at ‖Ah‖ = 1/2). Equal to scipy's
    `expm` of the block matrices to rounding (tests: complex step), at a fraction of its cost:
    at 50 Hz, ‖AΔ‖₁ ≈ 1 for the torpedo's roll mode, s = 1.
    """
    n, p, q = dM.shape
    norm = float(np.abs(M[:, :n]).sum(0).max()) * dt
    s = max(0, math.ceil(math.log2(norm / 0.5))) if norm > 0 else 0
    h = dt / 2**s
    theta, bound, terms = norm / 2**s, 1.0, 1
    while bound > 2.0**-53 and terms < 40:  # bound of term k+1 relative to the first: θ^k/k!
        bound *= theta / terms
        terms += 1
    X = M * h
    dX = (dM * h).reshape(n, p * q)
    T, dT = X, dX.reshape(n, p, q)
    E, dE = X.copy(), dT.copy()
    if second is not None:
        d2M, i, j = second
        dXi, dXj = dX.reshape(n, p, q)[:, i].transpose(1, 0, 2), dX.reshape(n, p, q)[:, j].transpose(1, 0, 2)
        d2X = d2M * h
        d2T, d2E = d2X, d2X.copy()
        terms += 1
    for k in range(2, terms + 1):  # T_k from T_{k−1}: the recursions above
        if second is not None:
            dTi, dTj = dT[:, i, :n].transpose(1, 0, 2), dT[:, j, :n].transpose(1, 0, 2)
            d2T = (d2T[:, :, :n] @ X + dTi @ dXj + dTj @ dXi + T[:, :n] @ d2X) * (1.0 / k)
            d2E += d2T
        if p:  # (no derivatives asked: the model alone, thousands of times per simplex fit)
            dT = (
                (dT[:, :, :n].reshape(n * p, n) @ X).reshape(n, p, q) + (T[:, :n] @ dX).reshape(n, p, q)
            ) * (1.0 / k)
            dE += dT
        T = (T[:, :n] @ X) * (1.0 / k)
        E += T
    E[:, :n] += np.eye(n)
    for _ in range(s):  # (E, ∂E, ∂²E) ← (E², E ∂E + ∂E E, …), top rows only
        Ex = E[:, :n]
        if second is not None:
            dEi, dEj = dE[:, i].transpose(1, 0, 2), dE[:, j].transpose(1, 0, 2)
            d2E_new = Ex @ d2E + d2E[:, :, :n] @ E + dEi[:, :, :n] @ dEj + dEj[:, :, :n] @ dEi
            d2E_new[:, :, n:] += d2E[:, :, n:]
            d2E = d2E_new
        if p:
            dE_new = (Ex @ dE.reshape(n, p * q)).reshape(n, p, q)
            dE_new += (dE[:, :, :n].reshape(n * p, n) @ E).reshape(n, p, q)
            dE_new[:, :, n:] += dE[:, :, n:]
            dE = dE_new
        E_new = Ex @ E
        E_new[:, n:] += E[:, n:]
        E = E_new
    return (E, dE) if second is None else (E, dE, d2E)


def derivatives(
    s: Structure,
    theta: np.ndarray,
    A: np.ndarray,
    B: np.ndarray,
    S: np.ndarray,
    index: np.ndarray | None = None,
):
    """∂A/∂θ_i, ∂B/∂θ_i, ∂S/∂θ_i for the coefficients `index` (default all), stacked first.

    From `Mt A = At`: ∂A = Mt⁻¹(∂At − ∂Mt A); likewise for B and S.
    """
    index = np.arange(NTHETA) if index is None else np.asarray(index)
    Mt = s.Mt0 + np.tensordot(theta, s.dMt, 1)
    dMt = s.dMt[index]
    rhs = np.concatenate(
        [s.dAt[index] - dMt @ A, s.dBt[index] - dMt @ B, (s.dSt[index] - dMt @ S)[:, :, None]], axis=2
    )
    sol = np.linalg.solve(Mt[None], rhs)
    return sol[:, :, :NX], sol[:, :, NX : NX + NU], sol[:, :, -1]


# -- what a model config must satisfy before a fit -----------------------------------------------

BODY = ("u", "v", "w", "p", "q", "r")  # the body rows: the velocities and rates
# the diagonal of Mt's body block, as the linear model's table writes it
INERTIA_TERMS = {
    "u": "m − X_udot",
    "v": "m − Y_vdot",
    "w": "m − Z_wdot",
    "p": "Ix − K_pdot",
    "q": "Iy − M_qdot",
    "r": "Iz − N_rdot",
}


def inertia_defect(s: Structure, theta: np.ndarray) -> str | None:
    """Why `Mt` at `theta` is not the inertia of a body, or None.

    The body block of Mt (rigid body plus added mass) gives the kinetic energy ½ νᵀ Mt ν, which is
    positive for every motion ν: the block's symmetric part must be positive definite (which also
    makes Mt invertible). Names a diagonal term ≤ 0, else the least eigenvalue."""
    body = [IX[n] for n in BODY]
    M = tilde(s, theta)[0][np.ix_(body, body)]
    for n, d in zip(BODY, np.diag(M)):
        if not d > 0:
            return f"{INERTIA_TERMS[n]} = {d:.4g}; expected > 0"
    lam = np.linalg.eigvalsh((M + M.T) / 2)
    if lam[0] <= 1e-12 * lam[-1]:
        return (
            f"the symmetric part of its body block has the eigenvalue {lam[0]:.4g} "
            f"(largest {lam[-1]:.4g}); expected all > 0, a positive kinetic energy"
        )
    return None


def unobserved(s: Structure, theta: np.ndarray, free, measured) -> tuple[str, ...]:
    """The coefficients among `free` on which no `measured` state depends, whatever the free
    values (and the output biases of states not measured, the current without u or v, the
    velocity log's mounting without u, v or w): they
    cannot be identified from these measurements at all.

    A coefficient enters some rows of `Mt ẋ = At x + Bt δ`; Mt⁻¹ spreads a row to the rows
    coupled with it through Mt (either way: an over-estimate), and At carries a state into the
    rows that depend on it. The coefficient is observed if this reaches a measured state. Fixed
    coefficients count where they are nonzero, free ones wherever they sit."""
    idx = np.array([ITHETA[n] for n in free], dtype=int)
    reach = _reach(s, theta, free)
    seen = np.zeros(NX, dtype=bool)
    seen[[IX[n] for n in measured]] = True
    velocities = {"u", "v", "w"} & set(measured)
    if velocities and (np.any(theta[IMOUNTING]) or set(MOUNTING) & set(free)):
        seen[[IX[n] for n in ("p", "q", "r")]] = True  # a log away from the CG reads ω × r
    out = []
    for n, i in zip(free, idx):
        if n in MOUNTING:  # the velocity log's mounting: seen in its velocities
            if not velocities:
                out.append(n)
            continue
        if n in BIASES:  # a bias is seen in its own output alone
            if n[2:] not in measured:
                out.append(n)
            continue
        if n in CURRENT:  # the current in the velocities over the ground, u and v
            if not {"u", "v"} & set(measured):
                out.append(n)
            continue
        if n == DELAY:  # the inputs' timing: seen wherever they are
            continue
        if not (reach(s.dMt[i].any(1) | s.dAt[i].any(1) | s.dBt[i].any(1) | (s.dSt[i] != 0)) & seen).any():
            out.append(n)
    return tuple(out)


def _reach(s: Structure, theta: np.ndarray, free):
    """`reach(rows)`: the states that a change in the `rows` of `Mt ẋ = At x + Bt δ` can move
    (`unobserved`): Mt⁻¹ spreads a row to the rows coupled with it through Mt (either way: an
    over-estimate), and At carries a state into the rows that depend on it. Fixed coefficients
    count where they are nonzero, the `free` ones wherever they sit."""
    idx = np.array([ITHETA[n] for n in free], dtype=int)
    fixed = np.asarray(theta, dtype=float).copy()
    fixed[idx] = 0.0
    Mt, At = tilde(s, fixed)[:2]
    coupled = (Mt != 0) | s.dMt[idx].any(0)
    coupled = coupled | coupled.T | np.eye(NX, dtype=bool)
    for _ in range(NX):  # transitive closure: rows mixed by Mt⁻¹
        coupled = (coupled.astype(int) @ coupled.astype(int)) > 0
    drives = (At != 0) | s.dAt[idx].any(0)  # drives[r, k]: row r depends on x_k
    spread = (coupled.astype(int) @ drives.astype(int)) > 0  # spread[l, k]: ẋ_l depends on x_k

    def reach(rows: np.ndarray) -> np.ndarray:
        reached = coupled[:, rows].any(1)
        for _ in range(NX):
            reached = reached | spread[:, reached].any(1)
        return reached

    return reach


def pitch_dependents(s: Structure, theta: np.ndarray, free, measured) -> tuple[str, ...]:
    """The states among `measured` that the pitch row moves (Iy and the pitch restoring term sit
    in it alone): those that need the constants a 4-DOF config may leave out (`Vehicle.omitted`)."""
    rows = np.zeros(NX, dtype=bool)
    rows[IX["q"]] = True
    reached = _reach(s, theta, free)(rows)
    return tuple(n for n in STATES if n in measured and reached[IX[n]])
