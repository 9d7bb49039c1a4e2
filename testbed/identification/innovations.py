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
`A P + P Aᵀ − (1/Δ) P Cᵀ 𝒮⁻¹ C P + F Fᵀ = 0` (`periodic_gain` with one phase). The measurement noise is what 𝒮
leaves, `R = 𝒮 − C P Cᵀ`; with that R, P is the ordinary Kalman filter's (`solve_discrete_are`).
From the prediction x̃[0] = x0, with the exact transition,

    ν[k] = y[k] − C x̃[k],   x̃[k+1] = Φ (x̃[k] + K ν[k]) + Γ δ[k] + s,

one linear recursion `x̃[k+1] = Φ(I − KC) x̃[k] + Φ K y[k] + Γ δ[k] + s` (`scan.propagate`).
The filter runs on the states the measured ones depend on (`observed`); the others feed no
output. With no process noise (F = 0) K = 0 and the innovations are the output-error residuals.

Sensors at their own rates: where a record's samples of each channel recur with a fixed period
of P samples (a 10 Hz DVL in a 50 Hz record: P = 5; `cycle`), the filter is the periodic steady
state, one gain per phase j of the cycle, on the channels that phase has (C_j): the innovations'
covariance 𝒮_j per phase, and P_j from the cycle of predictions

    P_{j+1} = Φ (P_j − P_j C_jᵀ 𝒮_j⁻¹ C_j P_j) Φᵀ + Q,   P_P = P_0,   K_j = P_j C_jᵀ 𝒮_j⁻¹,

solved by Newton's method on the cycle (`periodic_gain`); P = 1 is the steady state above.

Coloured process noise (a correlation time τ > 0): each noisy row's noise passes through a
first-order lag, `η̇ = −η/τ + ξ/τ` (`coloured`), η a state of the filter beside the vehicle's,
its spectral density f²/(1 + ω²τ²): the white noise's at low frequency, rolled off above 1/τ.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from testbed.identification import scan
from testbed.identification.problem import Problem, Record
from testbed.identification.recursions import discrete_models, simulated
from testbed.models.linear import BODY, IX, NU, NX, continuous

__all__ = [
    "BODY_ROWS",
    "FASTEST_LAG",
    "MAX_CYCLE",
    "Filter",
    "coloured",
    "cycle",
    "filters",
    "innovations",
    "observed",
    "periodic_gain",
    "process_covariance",
    "propagate_periodic",
    "initial_prediction",
]

BODY_ROWS = np.array([IX[s] for s in BODY])  # u v w p q r: the rows process noise enters
_REGULAR = 1e-10  # process noise on every state, relative, where the Riccati equation needs it
_NEWTON = 30  # Newton steps on the discrete Riccati equation, at most
_SETTLING = 200  # cycles of the recursion that make Newton's method's other start
_CLOSE = 0.1  # a first-order start whose cycle closes to this (relative) needs no other
_HALVINGS = 20  # halvings of a Newton step that does not reduce the equation's mismatch, at most
MAX_CYCLE = 100  # samples: the longest period of a record's sampling the periodic filter takes
FASTEST_LAG = 0.2  # of the sampling interval: a coloured noise's shortest correlation time


def cycle(present: np.ndarray | None, k: int) -> np.ndarray | None:
    """The channels each phase of a record's sampling cycle has, (P, k) bool, for the shortest
    period P (at most `MAX_CYCLE` samples) with `present[i] = phases[i mod P]` at every sample
    and more whole cycles than channels (each phase's innovations' covariance is estimated from
    its samples); None where there is none (dropouts, or a record too short for its cycle).
    `present` (N, k) or None (every sample there: P = 1)."""
    if present is None or present.all():
        return np.ones((1, k), dtype=bool)
    for P in range(1, min(MAX_CYCLE, len(present) // (k + 1)) + 1):
        phases = present[:P]
        if all((present[j::P] == phases[j]).all() for j in range(P)):
            return phases if phases.any(axis=0).all() else None
    return None


def _closure(taken: np.ndarray, links: np.ndarray) -> np.ndarray:
    """`taken` (n,) bool and, again and again, every state l that `links[a, l]` ties to a state a
    already taken, until none is added."""
    while True:
        wider = taken | links[taken].any(axis=0)
        if (wider == taken).all():
            return taken
        taken = wider


def observed(coupled: np.ndarray, measured: np.ndarray) -> np.ndarray:
    """The states the measured ones depend on (sorted indexes): the measured states and, again
    and again, every state that feeds one already taken (`coupled[a, l]`: state l feeds state a)."""
    taken = np.zeros(len(coupled), dtype=bool)
    taken[measured] = True
    return np.flatnonzero(_closure(taken, coupled))


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


def _covariance(P: np.ndarray) -> bool:
    """Whether P is finite, symmetric and positive semi-definite (to rounding)."""
    if not np.all(np.isfinite(P)):
        return False
    top = np.max(np.abs(P))
    return np.allclose(P, P.T, atol=1e-9 * top) and np.linalg.eigvalsh((P + P.T) / 2)[0] >= -1e-9 * top


def _reached(A: np.ndarray, W: np.ndarray) -> np.ndarray:
    """The states the process noise reaches (n,) bool: those with noise (W's nonzero rows) and
    every state that a reached one drives through A (A[i, j] ≠ 0), the least set A maps into
    itself (A is block triangular on it and the others: e^{AΔ} is too)."""
    return _closure(np.any(W != 0, axis=1), (A != 0).T)


def periodic_gain(A: np.ndarray, Phi: np.ndarray, Cs, W: np.ndarray, Ss, dt: float):
    """`(Ks, Ps)`: per phase j of the cycle, the gain K_j (n, k_j) and predicted covariance P_j of
    the filter in 𝒮_j (`Ss[j]`, (k_j, k_j)) with the phase's measurement matrix `Cs[j]` (k_j, n),
    for the continuous `A`, its transition `Phi` over `dt` and `W` = F Fᵀ; K = 0 where W = 0.

    P_0 solves the cycle `G(P_0) = f_{P−1}(… f_0(P_0)) − P_0 = 0`, f_j(P) = Φ(P − P C_jᵀ𝒮_j⁻¹C_j P)Φᵀ + Q
    (Q of `process_covariance`), by Newton's method: f_j's derivative is `dP ↦ Φ_c dP Φ_cᵀ −
    (ΦK_jC_j) dP (ΦK_jC_j)ᵀ`, Φ_c = Φ(I − K_jC_j), and the step solves the product of theirs over
    the cycle, less the identity, as one n² × n² linear system (least squares where a mode the
    noise does not reach leaves it singular), halved until it reduces the largest |G|. It starts
    from whichever is nearer closing the cycle: the solution of the first-order (continuous)
    form with the cycle's mean information, `A P + P Aᵀ − P (1/(PΔ) Σ C_jᵀ𝒮_j⁻¹C_j) P + W = 0`
    (scipy's `solve_continuous_are`; where scipy refuses it or returns no covariance, a mode on
    the imaginary axis that the process noise does not reach, every state with a process noise
    10⁻¹⁰ of the largest there), or, where that one's cycle misses by more than `_CLOSE` of P,
    `_SETTLING` cycles of the recursion itself from P = Q.
    On the states the noise does not reach (`_reached`) P is 0 and K's rows are 0 (the recursion
    from P = Q never leaves them); the equation is solved on the others alone (on all states
    Newton's steps, singular there, would leave P's part on those wherever its start put it, and
    the start depends on the values: the gain would jump between them). A mode of the reached
    states that the noise still does not excite keeps the least-squares step.
    `LinAlgError` where Newton's method does not settle: no solution with these 𝒮 (the process
    noise claims more than they hold)."""
    n = len(A)
    if not W.any():
        return [np.zeros((n, len(S))) for S in Ss], [np.zeros((n, n)) for _ in Ss]
    reached = _reached(A, W)
    if not reached.all():
        # P is 0 on the states the noise does not reach (P = Q starts there, and the recursion
        # keeps it there): the equation on the others alone
        on = np.flatnonzero(reached)
        Ks_on, Ps_on = periodic_gain(
            A[np.ix_(on, on)], Phi[np.ix_(on, on)], [C[:, on] for C in Cs], W[np.ix_(on, on)], Ss, dt
        )
        Ks, Ps = [np.zeros((n, len(S))) for S in Ss], [np.zeros((n, n)) for _ in Ss]
        for K, P, K_on, P_on in zip(Ks, Ps, Ks_on, Ps_on):
            K[on] = K_on
            P[np.ix_(on, on)] = P_on
        return Ks, Ps
    from scipy.linalg import block_diag, solve_continuous_are

    # the first-order form's b r⁻¹ bᵀ = (1/(PΔ)) Σ C_jᵀ 𝒮_j⁻¹ C_j
    Q = _full_covariance(A, W, dt)
    Sinv_C = [np.linalg.solve(S, C) for S, C in zip(Ss, Cs)]
    b, r = np.vstack(Cs).T, block_diag(*Ss) * dt * len(Cs)
    first = None
    for noise in (W, W + _REGULAR * np.max(W) * np.eye(n)):
        try:
            P = solve_continuous_are(A.T, b, noise, r)
        except (np.linalg.LinAlgError, ValueError):
            continue
        if _covariance(P):  # scipy may return a non-stabilising solution instead of refusing
            first = P
            break

    def around(P):
        """The cycle from P_0 = P: (K_j, P_j per phase, G(P), the cycle's derivative less I)."""
        Ks, Ps, L, Pj = [], [], np.eye(n * n), (P + P.T) / 2
        for C, SC in zip(Cs, Sinv_C):
            K = Pj @ SC.T
            Ks.append(K)
            Ps.append(Pj)
            Fc, H = Phi - Phi @ K @ C, Phi @ K @ C
            L = (np.kron(Fc, Fc) - np.kron(H, H)) @ L
            Pj = Phi @ (Pj - K @ C @ Pj) @ Phi.T + Q
        return Ks, Ps, Pj - Ps[0], L - np.eye(n * n)

    def mismatch(c) -> float:
        """The largest |G| of a cycle, relative to its P_0 (inf where not finite)."""
        return float(np.nan_to_num(np.max(np.abs(c[2])) / np.max(np.abs(c[1][0])), nan=np.inf))

    with np.errstate(over="ignore", invalid="ignore"):
        cycles = [] if first is None else [around(first)]
        if not cycles or mismatch(cycles[0]) > _CLOSE:
            P = Q  # the recursion itself from P = Q, as a filter started with no uncertainty
            for _ in range(_SETTLING):
                for C, SC in zip(Cs, Sinv_C):
                    P = Phi @ (P - P @ SC.T @ C @ P) @ Phi.T + Q
            cycles.append(around(P))
        Ks, Ps, G, L = min(cycles, key=mismatch)  # from the start whose cycle is nearer closing
        for _ in range(_NEWTON):
            size = np.max(np.abs(G))
            if not np.isfinite(size):
                break
            if size <= 1e-12 * np.max(np.abs(Ps[0])):
                return Ks, Ps
            try:
                step = np.linalg.solve(L, -G.ravel()).reshape(n, n)
            except np.linalg.LinAlgError:  # a mode the noise does not reach: its P stays put
                step = np.linalg.lstsq(L, -G.ravel(), rcond=None)[0].reshape(n, n)
            # the Newton step, halved while it does not reduce the cycle's mismatch
            for _ in range(_HALVINGS):
                trial = around(Ps[0] + step)
                if np.max(np.abs(trial[2])) < size:
                    break
                step = step / 2
            else:
                break
            Ks, Ps, G, L = trial
    raise np.linalg.LinAlgError("the Riccati equation in 𝒮 has no solution here")


@dataclass(frozen=True)
class Filter:
    """The periodic steady-state filter of one group of records (one Δ, one measured set, one
    sampling cycle), on the states `states` only: `x̃[i+1] = Phi_c[j] x̃[i] + PhiK[j] y[i] + Gamma δ[i]
    + s` at phase j = i mod P, the columns of PhiK[j] and K[j] zero where phase j has no sample."""

    states: (
        np.ndarray
    )  # indexes into the 10 states (the filter's first len(states); any after: coloured noise's)
    rows: np.ndarray  # the measured states' positions in `states`
    phases: np.ndarray  # (P, k) bool: the channels each phase has
    Phi_c: np.ndarray  # (P, n, n) Φ(I − K_j C_j)
    PhiK: np.ndarray  # (P, n, k) Φ K_j
    Gamma: np.ndarray  # (the filter's states, 3): the coloured noise's rows 0
    s: np.ndarray
    K: np.ndarray  # (P, n, k)
    P: np.ndarray  # (P, n, n): the predicted covariance at each phase

    @property
    def CPC(self) -> np.ndarray:
        """(P, k, k) C P_j Cᵀ: the part of the innovations' covariance the state's uncertainty makes."""
        return self.P[:, self.rows][:, :, self.rows]


def filters(
    prob: Problem, values: np.ndarray, q: np.ndarray, S: dict, states: dict, phases: dict, tau: float = 0.0
) -> dict:
    """The filter of each group of records, keyed as `S`: coefficients `values`, spectral
    densities `q` = f² (6,), `S[key]` the group's innovations' covariance per phase (over the
    phase's channels), `states[key]` the states it runs on (`observed`) and `phases[key]` its
    cycle (`cycle`); a key is (the records' model, `Problem.key`: Δ, or Δ and the record group
    where values are per record; measured states; cycle). With a correlation time `tau` > 0 the
    process noise is coloured (`coloured`). `LinAlgError` as `periodic_gain`."""
    models = discrete_models(prob, values, 0)
    W = np.zeros((NX, NX))
    W[BODY_ROWS, BODY_ROWS] = q
    out, As = {}, {}
    for key, o in states.items():
        model, measured = key[0], np.array(key[1])
        dt, group = model if isinstance(model, tuple) else (model, None)
        if group not in As:
            As[group] = continuous(prob.structure, prob.coefficients(values, group))[0]
        E = models[model].E[o]
        Phi, Ao, Wo = E[:, o], As[group][np.ix_(o, o)], W[np.ix_(o, o)]
        extra = 0
        if tau > 0:
            Ao, Wo, Phi = coloured(Ao, Wo, tau, dt)
            extra = len(Ao) - len(o)
        rows = np.searchsorted(o, measured)
        C = np.eye(len(Ao))[rows]
        on = phases[key]
        Cs = [C[m] for m in on]
        Ks, Ps = periodic_gain(Ao, Phi, Cs, Wo, S[key], dt)
        K = np.zeros((len(on), len(Ao), len(rows)))
        for j, m in enumerate(on):
            K[j][:, m] = Ks[j]
        PhiK = Phi @ K
        Phi_c = Phi - PhiK @ C
        Gamma = np.vstack([E[:, NX : NX + NU], np.zeros((extra, NU))])
        s = np.concatenate([E[:, -1], np.zeros(extra)])
        out[key] = Filter(o, rows, on, Phi_c, PhiK, Gamma, s, K, np.array(Ps))
    return out


def coloured(A: np.ndarray, W: np.ndarray, tau: float, dt: float):
    """`(A, W, Φ)` of the states with their process noise coloured: each row j with noise
    (W_jj > 0) driven by a state η_j through a first-order lag of time constant τ,

        ẋ_j = … + η_j,   η̇_j = −η_j/τ + ξ_j/τ,   ξ_j white of intensity W_jj,

    so that η_j's spectral density is W_jj/(1 + ω²τ²): W_jj at low frequency, as the white
    noise's, rolled off above 1/τ (a first-order Gauss-Markov disturbance of correlation time τ).
    The η_j follow the states; Φ = e^{AΔ} of the whole. A lag faster than `FASTEST_LAG` of the
    interval Δ rolls off beyond what the samples resolve, and its Q (Van Loan's, through e^{Δ/τ})
    would lose every digit: the noise is then the white one, `(A, W, e^{AΔ})`."""
    from scipy.linalg import expm

    if tau < FASTEST_LAG * dt:
        return A, W, expm(A * dt)
    noisy = np.flatnonzero(np.diag(W) > 0)
    n, m = len(A), len(noisy)
    Aa = np.zeros((n + m, n + m))
    Aa[:n, :n] = A
    Aa[noisy, n + np.arange(m)] = 1.0
    Aa[n:, n:] = -np.eye(m) / tau
    Wa = np.zeros((n + m, n + m))
    Wa[n:, n:] = np.diag(np.diag(W)[noisy]) / tau**2
    return Aa, Wa, expm(Aa * dt)


def propagate_periodic(Phi_c: np.ndarray, x0: np.ndarray, forcing: np.ndarray) -> np.ndarray:
    """`x[i+1] = Phi_c[i mod P] x[i] + forcing[i]` from x0 (n,); returns (len(forcing) + 1, n).
    With P > 1 as one recursion over whole cycles, `z[m+1] = T z[m] + g[m]` with T the cycle's
    product of transitions (`scan.propagate`), and each phase's states from the cycle's first."""
    P, n = len(Phi_c), len(x0)
    if P == 1:
        return scan.propagate(Phi_c[0], x0, forcing)
    N = len(forcing) + 1
    M = -(-len(forcing) // P)
    F = np.zeros((M * P, n), dtype=np.result_type(Phi_c, x0, forcing))
    F[: len(forcing)] = forcing
    F = F.reshape(M, P, n)
    U = [np.eye(n)]  # x[mP + j] = U_j z[m] + h[m, j]
    h = [np.zeros((M, n), dtype=F.dtype)]
    for j in range(P):
        U.append(Phi_c[j] @ U[j])
        h.append(h[j] @ Phi_c[j].T + F[:, j])
    z = scan.propagate(U[P], x0, h[P][:-1])
    x = np.stack([z @ U[j].T + h[j] for j in range(P)], axis=1).reshape(M * P, n)
    return np.vstack([x, z[-1:] @ U[P].T + h[P][-1:]])[:N]


def initial_prediction(f: Filter, x0: np.ndarray) -> np.ndarray:
    """The filter's initial prediction from the states' `x0` (10,): its states', and 0 for the
    coloured noise's (its mean)."""
    out = np.zeros(len(f.Phi_c[0]), dtype=x0.dtype)
    out[: len(f.states)] = x0[f.states]
    return out


def innovations(record: Record, f: Filter, x0: np.ndarray, y: np.ndarray, inputs: np.ndarray) -> np.ndarray:
    """ν (N, k) of one record from the predicted initial state `x0` (10,), its outputs `y` (its
    measured states, output terms taken off; 0 where missing) and `inputs`; 0 where missing."""
    simulated(len(y))
    P = len(f.phases)
    forcing = inputs[:-1] @ f.Gamma.T + f.s
    for j in range(P):
        forcing[j::P] += y[:-1][j::P] @ f.PhiK[j].T
    x = propagate_periodic(f.Phi_c, initial_prediction(f, x0), forcing)
    nu = y - x[:, f.rows]
    return nu if record.present is None else np.where(record.present, nu, 0.0)
