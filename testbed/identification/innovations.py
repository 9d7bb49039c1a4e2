"""The linear model with process noise and its steady-state Kalman filter: the innovations whose
likelihood the filter-error method maximises.

Model (each record, sampling interval Δ, u as the perturbation):

    x[k+1] = Φ x[k] + Γ δ[k] + s + w[k],   w ~ N(0, Q)
    y[k]   = C x[k] + v[k],                 v ~ N(0, R), R diagonal

`[Φ Γ s]` is the exact zero-order hold of `Mt ẋ = At x + Bt δ + St` (`recursions.discrete`). The
process noise enters the six body rows: in continuous time `ẋ = A x + B δ + S + F η`, η white
of unit intensity, F = diag(f) over the body rows u v w p q r (zero on the kinematic rows), so
f_j is row j's process-noise standard deviation in (state unit)/√s, Jategaonkar's distribution
matrix. Its exact discretisation (Van Loan; what a simulation of the model draws w from) is

    Q = ∫₀^Δ e^{Aτ} F Fᵀ e^{Aᵀτ} dτ:   exp([[−A, FFᵀ], [0, Aᵀ]] Δ) = [[·, G₁₂], [0, Φᵀ]],  Q = Φ G₁₂.

The filter is the steady-state (time-invariant) Kalman filter, valid for a stationary process
and a record long against the filter's settling. In the filter-error method the innovations'
covariance 𝒮 is estimated (in closed form) and held while θ and F step, so the gain is written
in 𝒮 (Maine & Iliff; Jategaonkar ch. 5): `K = P Cᵀ 𝒮⁻¹`, P the predicted covariance, from the
discrete algebraic Riccati equation with 𝒮 held,

    P = Φ (P − P Cᵀ 𝒮⁻¹ C P) Φᵀ + Q,

which has no standard form (scipy's `solve_discrete_are` holds R, not 𝒮): it is solved by
Newton's method from its first-order (continuous) form, Jategaonkar's
`A P + P Aᵀ − (1/Δ) P Cᵀ 𝒮⁻¹ C P + F Fᵀ = 0` (`steady_gain`). The measurement noise is what 𝒮
leaves, `R = 𝒮 − C P Cᵀ`; with that R, P is the ordinary Kalman filter's (`solve_discrete_are`).
From the prediction x̃[0] = x0, with the exact transition,

    ν[k] = y[k] − C x̃[k],   x̃[k+1] = Φ (x̃[k] + K ν[k]) + Γ δ[k] + s,

one linear recursion `x̃[k+1] = Φ(I − KC) x̃[k] + Φ K y[k] + Γ δ[k] + s` (`scan.propagate`).
The filter runs on the states the measured ones depend on (`observed`); the others feed no
output. With no process noise (F = 0) K = 0 and the innovations are the output-error residuals.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from testbed.identification import scan
from testbed.identification.problem import Problem, Record
from testbed.identification.recursions import discrete_models, simulated
from testbed.models.linear import IX, NU, NX, STATES, continuous

__all__ = [
    "BODY",
    "BODY_ROWS",
    "Filter",
    "filters",
    "innovations",
    "observed",
    "process_covariance",
    "steady_gain",
]

BODY = STATES[:6]  # u v w p q r: the rows process noise enters
BODY_ROWS = np.array([IX[s] for s in BODY])
_REGULAR = 1e-10  # process noise on every state, relative, where the Riccati equation needs it
_NEWTON = 30  # Newton steps on the discrete Riccati equation, at most


def observed(coupled: np.ndarray, measured: np.ndarray) -> np.ndarray:
    """The states the measured ones depend on (sorted indexes): the measured states and, again
    and again, every state that feeds one already taken (`coupled[a, l]`: state l feeds state a)."""
    taken = np.zeros(len(coupled), dtype=bool)
    taken[measured] = True
    while True:
        wider = taken | coupled[taken].any(axis=0)
        if (wider == taken).all():
            return np.flatnonzero(taken)
        taken = wider


def process_covariance(A: np.ndarray, q: np.ndarray, dt: float) -> np.ndarray:
    """Q (10, 10) of the continuous process noise with spectral densities `q` = f² (6,) on the
    body rows, over one interval `dt` (Van Loan)."""
    W = np.zeros((len(A), len(A)))
    W[BODY_ROWS, BODY_ROWS] = q
    return _full_covariance(A, W, dt)


def _full_covariance(A: np.ndarray, W: np.ndarray, dt: float) -> np.ndarray:
    """∫₀^Δ e^{Aτ} W e^{Aᵀτ} dτ (Van Loan)."""
    from scipy.linalg import expm

    n = len(A)
    G = expm(np.block([[-A, W], [np.zeros((n, n)), A.T]]) * dt)
    Q = G[n:, n:].T @ G[:n, n:]
    return (Q + Q.T) / 2


def steady_gain(A: np.ndarray, Phi: np.ndarray, C: np.ndarray, W: np.ndarray, S: np.ndarray, dt: float):
    """`(K, P)`: the steady-state gain and predicted covariance of the filter in 𝒮 (`S`, (k, k))
    for the continuous `A`, its transition `Phi` over `dt`, `C` (k, n) and `W` = F Fᵀ; K = 0
    where W = 0.

    P solves the discrete Riccati equation with 𝒮 held, `G(P) = Φ(P − P Cᵀ𝒮⁻¹C P)Φᵀ + Q − P = 0`
    (Q of `process_covariance`), by Newton's method from the solution of its first-order
    (continuous) form `A P + P Aᵀ − (1/Δ) P Cᵀ 𝒮⁻¹ C P + W = 0` (scipy's `solve_continuous_are`):
    the step solves `Φ_c dP Φ_cᵀ − (ΦKC) dP (ΦKC)ᵀ − dP = −G(P)`, Φ_c = Φ(I − KC), as one
    n² × n² linear system. Where scipy refuses the first-order form (a mode on the imaginary axis
    that the process noise does not reach: an integrator), every state gets a process noise
    10⁻¹⁰ of the largest there. `LinAlgError` where Newton's method does not settle: no
    solution with this 𝒮 (the process noise claims more than 𝒮 holds)."""
    n, k = len(A), len(S)
    if not W.any():
        return np.zeros((n, k)), np.zeros((n, n))
    from scipy.linalg import solve_continuous_are

    try:
        P = solve_continuous_are(A.T, C.T, W, S * dt)
    except (np.linalg.LinAlgError, ValueError):
        try:
            P = solve_continuous_are(A.T, C.T, W + _REGULAR * np.max(W) * np.eye(n), S * dt)
        except ValueError as exc:
            raise np.linalg.LinAlgError(str(exc)) from exc
    Q = _full_covariance(A, W, dt)
    Sinv_C = np.linalg.solve(S, C)
    for _ in range(_NEWTON):
        P = (P + P.T) / 2
        K = P @ Sinv_C.T
        G = Phi @ (P - K @ C @ P) @ Phi.T + Q - P
        if not np.all(np.isfinite(G)):
            break
        if np.max(np.abs(G)) <= 1e-12 * np.max(np.abs(P)):
            return K, P
        Fc, H = Phi - Phi @ K @ C, Phi @ K @ C
        L = np.kron(Fc, Fc) - np.kron(H, H) - np.eye(n * n)
        P = P + np.linalg.solve(L, -G.ravel()).reshape(n, n)
    raise np.linalg.LinAlgError("the Riccati equation in 𝒮 has no solution here")


@dataclass(frozen=True)
class Filter:
    """The steady-state filter of one group of records (one Δ, one measured set), on the states
    `states` only: `x̃[k+1] = Phi_c x̃[k] + (Phi K) y[k] + Gamma δ[k] + s`."""

    states: np.ndarray  # indexes into the 10 states
    rows: np.ndarray  # the measured states' positions in `states`
    Phi_c: np.ndarray  # Φ(I − KC)
    PhiK: np.ndarray  # Φ K
    Gamma: np.ndarray  # (len(states), 3)
    s: np.ndarray
    K: np.ndarray
    P: np.ndarray  # the predicted covariance (len(states), len(states))

    @property
    def CPC(self) -> np.ndarray:
        """C P Cᵀ: the part of the innovations' covariance the state's uncertainty makes."""
        return self.P[np.ix_(self.rows, self.rows)]


def filters(prob: Problem, values: np.ndarray, q: np.ndarray, S: dict, states: dict) -> dict:
    """The filter of each group of records, keyed by (Δ, measured states): coefficients
    `values`, spectral densities `q` = f² (6,), `S[key]` the group's innovations' covariance and
    `states[key]` the states it runs on (`observed`). `LinAlgError` as `steady_gain`."""
    models = discrete_models(prob, values, 0)
    A = continuous(prob.structure, prob.coefficients(values))[0]
    W = np.zeros((NX, NX))
    W[BODY_ROWS, BODY_ROWS] = q
    out = {}
    for r in prob.records:
        key = (r.dt, tuple(r.measured))
        if key in out:
            continue
        o = states[key]
        E = models[r.dt].E[o]
        Phi = E[:, o]
        rows = np.searchsorted(o, r.measured)
        C = np.eye(len(o))[rows]
        K, P = steady_gain(A[np.ix_(o, o)], Phi, C, W[np.ix_(o, o)], S[key], r.dt)
        out[key] = Filter(o, rows, Phi - Phi @ K @ C, Phi @ K, E[:, NX : NX + NU], E[:, -1], K, P)
    return out


def innovations(record: Record, f: Filter, x0: np.ndarray) -> np.ndarray:
    """ν (N, k) of one record from the predicted initial state `x0` (10,)."""
    simulated(len(record.y))
    forcing = record.y[:-1] @ f.PhiK.T + record.inputs[:-1] @ f.Gamma.T + f.s
    x = scan.propagate(f.Phi_c, x0[f.states], forcing)
    return record.y - x[:, f.rows]
