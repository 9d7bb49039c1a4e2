"""Output-error maximum likelihood for the SPEC §2 model: the numerical core of issue 4.

The model is the exact zero-order-hold discretisation `x[k+1] = Φ x[k] + Γ δ[k] + s`, written
`x[k+1] = E w[k]` with `E = [Φ Γ s]` and `w[k] = [x[k]; δ[k]; 1]`, simulated from each
experiment's initial state; the outputs are the measured states (`u` as the perturbation
u_abs − U). The parameter vector is

    p = (θ_free, x0 of experiment 1, x0 of experiment 2, ...)

where each experiment's initial state is estimated in its *measured* components only; the
unmeasured ones stay at trim (0). Measured components are pinned by the first samples, so they
are well conditioned, whereas unmeasured ones are either unobservable (ψ and z feed nothing
back) or only weakly observable, which would add near-null directions to the Fisher matrix.

Noise: `v ~ N(0, R)` with `R` diagonal, one variance per measured state (pooled over the
experiments). The paper's likelihood `J_M = 1/N Σ eᵀR⁻¹e` is minimised by relaxation: `R` is set
to the residual variance per channel, then held fixed while θ steps (Maine & Iliff).

Output sensitivities are exact: `∂E/∂θ_i` and `∂²E/∂θ_i∂θ_j` come from the exponential of
block-triangular augmented matrices (the discrete counterpart of the paper's Eq. 3), and the
sensitivities are propagated by the recursions obtained by differentiating `x[k+1] = E w[k]`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numba
import numpy as np
from scipy.linalg import expm
from scipy.signal import savgol_filter

from testbed.data import Experiment, ModelConfig
from testbed.errors import InputError
from testbed.model import (ITHETA, IX, NU, NX, STATES, Structure, continuous,
                           derivatives, discretize, structure, theta_vector, tilde)

NW = NX + NU + 1  # length of w = [x; δ; 1]
EXPLODE = 1e3  # a simulated output beyond EXPLODE·max|y| + 1 (SI) means the model diverged


@dataclass(frozen=True)
class Record:
    """One experiment as the model sees it."""

    name: str
    y: np.ndarray  # (N, k) measured states, u as the perturbation u_abs − U
    inputs: np.ndarray  # (N, 3)
    measured: np.ndarray  # (k,) indexes into STATES
    channels: np.ndarray  # (k,) indexes into Problem.channels
    dt: float
    offset: int  # where this experiment's initial state starts in p


@dataclass(frozen=True)
class Problem:
    """Experiments and model config, checked and converted once for the numerical core."""

    structure: Structure
    theta: np.ndarray  # (35,) the config's coefficients (free ones: the a-priori start)
    free: tuple[str, ...]
    index: np.ndarray  # (n_free,) positions of `free` in COEFFICIENTS
    records: tuple[Record, ...]
    channels: tuple[str, ...]  # the measured states of all experiments, STATES order
    speed: float
    source: str

    @property
    def n_free(self) -> int:
        return len(self.free)

    @property
    def n_params(self) -> int:
        return self.n_free + sum(len(r.measured) for r in self.records)

    @property
    def n_samples(self) -> int:
        return sum(len(r.y) for r in self.records)

    @property
    def start(self) -> np.ndarray:
        return self.theta[self.index].copy()

    def coefficients(self, values: np.ndarray) -> np.ndarray:
        """The full (35,) coefficient vector with the free ones set to `values`."""
        theta = self.theta.astype(np.result_type(self.theta, values))
        theta[self.index] = values
        return theta

    def columns(self, record: Record) -> np.ndarray:
        """Where the record's own parameters (the free coefficients, its x0) sit in p."""
        return np.r_[:self.n_free, record.offset:record.offset + len(record.measured)]

    def x0(self, record: Record, p: np.ndarray) -> np.ndarray:
        """The record's full initial state (10,) from the parameter vector."""
        x0 = np.zeros(NX, dtype=p.dtype)
        x0[record.measured] = p[record.offset:record.offset + len(record.measured)]
        return x0


def problem(experiments: Sequence[Experiment], config: ModelConfig) -> Problem:
    """Check the experiments and the config and set up the output-error problem."""
    where = config.source or "config"
    if not experiments:
        raise InputError("no experiments given; expected at least one measurement record")
    for n in config.free:
        if n not in ITHETA:
            raise InputError(f"{where}: [identify] free names {n!r}, not a coefficient (SPEC §2)")
    if len(set(config.free)) != len(config.free):
        raise InputError(f"{where}: [identify] free names a coefficient twice")
    try:
        theta = theta_vector(config.coefficients)
    except KeyError as exc:
        raise InputError(f"{where}: [coefficients] {exc.args[0]} (SPEC §2)") from None
    channels = tuple(s for s in STATES if any(s in e.measured for e in experiments))
    records, offset = [], len(config.free)
    for e in experiments:
        name = e.source or e.name
        y, inputs, t = (np.asarray(a, dtype=float) for a in (e.y, e.inputs, e.t))
        if len(t) < 3 or y.shape != (len(t), len(e.measured)) or inputs.shape != (len(t), NU):
            raise InputError(f"{name}: {len(t)} samples of {len(e.measured)} states and "
                             f"{inputs.shape[-1] if inputs.ndim == 2 else '?'} inputs; expected "
                             f"at least 3 samples, the states and {NU} inputs")  # fmt: skip
        for label, a in (("t", t), ("states", y), ("inputs", inputs)):
            if not np.all(np.isfinite(a)):
                raise InputError(f"{name}: {label} contain NaN or infinity; expected finite numbers")
        steps = np.diff(t)
        if steps[0] <= 0 or np.any(np.abs(steps - steps[0]) > 1e-6 * steps[0] + 1e-9):
            raise InputError(f"{name}: t is not uniformly increasing; expected a constant step")
        unknown = [s for s in e.measured if s not in IX]
        if unknown or not e.measured:
            raise InputError(f"{name}: measured states {list(e.measured)}; expected names from "
                             f"{', '.join(STATES)}")  # fmt: skip
        measured = np.array([IX[s] for s in e.measured])
        y = y.copy()
        if "u" in e.measured:
            y[:, e.measured.index("u")] -= config.vehicle.speed
        records.append(Record(e.name, y, inputs, measured,
                              np.array([channels.index(s) for s in e.measured]),
                              float(steps[0]), offset))  # fmt: skip
        offset += len(measured)
    index = np.array([ITHETA[n] for n in config.free], dtype=int)
    prob = Problem(structure(config.vehicle), theta, tuple(config.free), index, tuple(records),
                   channels, config.vehicle.speed, where)  # fmt: skip
    if abs(np.linalg.det(tilde(prob.structure, theta)[0])) < 1e-300:
        raise InputError(f"{where}: the inertia matrix Mt is singular at the given coefficients; "
                         "expected m − X_udot, Ix − K_pdot, ... to be nonzero")
    return prob


# --- the discrete model and its exact derivatives ---------------------------------------------


@dataclass(frozen=True)
class Discrete:
    """`E = [Φ Γ s]` (10, 14) and its derivatives w.r.t. the free coefficients."""

    E: np.ndarray
    dE: np.ndarray | None = None  # (n_free, 10, 14)
    d2E: np.ndarray | None = None  # (n_free, n_free, 10, 14)


def _augmented(A, B, S) -> np.ndarray:
    """`[[A, B, S], [0, 0, 0]]` (…, 14, 14): `w` obeys ẇ = F w under zero-order hold."""
    F = np.zeros(A.shape[:-2] + (NW, NW), dtype=np.result_type(A, B, S))
    F[..., :NX, :NX], F[..., :NX, NX:NX + NU], F[..., :NX, -1] = A, B, S
    return F


def discrete(prob: Problem, values: np.ndarray, dt: float, order: int = 0) -> Discrete:
    """The ZOH model at the free `values` and its first (`order` ≥ 1) and second derivatives.

    With `F(θ)` the augmented matrix, `E = exp(F Δ)`; then (Van Loan / Najfeld-Havel)
      exp([[F, F_i], [0, F]] Δ)                  has ∂E/∂θ_i in its top-right block,
      exp([[F, F_i, F_j, F_ij], [0, F, 0, F_j], [0, 0, F, F_i], [0, 0, 0, F]] Δ)
                                                 has ∂²E/∂θ_i∂θ_j in its top-right block,
    where `∂²A/∂θ_i∂θ_j = −Mt⁻¹(∂Mt_i ∂A_j + ∂Mt_j ∂A_i)` (Mt, At affine in θ), likewise B, S.
    """
    s, theta = prob.structure, prob.coefficients(values)
    A, B, S = continuous(s, theta)
    Phi, Gamma, sv = discretize(A, B, S, dt)
    E = np.column_stack([Phi, Gamma, sv])
    if order == 0 or prob.n_free == 0:
        return Discrete(E)
    n, nf = NW, prob.n_free
    F = _augmented(A, B, S)
    dA, dB, dS = derivatives(s, theta, A, B, S, prob.index)
    dF = _augmented(dA, dB, dS)
    big = np.zeros((nf, 2 * n, 2 * n), dtype=F.dtype)
    big[:, :n, :n] = big[:, n:, n:] = F
    big[:, :n, n:] = dF
    dE = expm(big * dt)[:, :NX, n:]
    if order == 1:
        return Discrete(E, dE)
    Mt = tilde(s, theta)[0]
    dMt = s.dMt[prob.index]
    dABS = dF[:, :NX, :]  # (nf, 10, 14)
    G = np.einsum("iab,jbc->ijac", dMt, dABS)
    d2F = np.zeros((nf, nf, n, n), dtype=F.dtype)
    d2F[:, :, :NX, :] = -np.linalg.solve(Mt[None, None], G + G.transpose(1, 0, 2, 3))
    iu, ju = np.triu_indices(nf)
    big = np.zeros((len(iu), 4 * n, 4 * n), dtype=F.dtype)
    for b in range(4):
        big[:, b * n:(b + 1) * n, b * n:(b + 1) * n] = F
    big[:, :n, n:2 * n], big[:, :n, 2 * n:3 * n] = dF[iu], dF[ju]
    big[:, :n, 3 * n:] = d2F[iu, ju]
    big[:, n:2 * n, 3 * n:], big[:, 2 * n:3 * n, 3 * n:] = dF[ju], dF[iu]
    block = expm(big * dt)[:, :NX, 3 * n:]
    d2E = np.zeros((nf, nf, NX, n), dtype=F.dtype)
    d2E[iu, ju] = block
    d2E[ju, iu] = block
    return Discrete(E, dE, d2E)


def _models(prob: Problem, values: np.ndarray, order: int) -> dict[float, Discrete]:
    return {dt: discrete(prob, values, dt, order) for dt in {r.dt for r in prob.records}}


# --- simulation and sensitivities -------------------------------------------------------------


def _propagate(Phi: np.ndarray, X0: np.ndarray, F: np.ndarray) -> np.ndarray:
    """`X[k+1] = Φ X[k] + F[k]` from `X[0] = X0`; returns (len(F) + 1,) + X0.shape."""
    dtype = np.result_type(Phi, X0, F)  # complex under the complex-step tests
    X = np.empty((len(F) + 1,) + X0.shape, dtype=dtype)
    X[0] = X0
    _recurse(np.ascontiguousarray(Phi, dtype), X.reshape(len(X), len(Phi), -1),
             np.ascontiguousarray(F, dtype).reshape(len(F), len(Phi), -1))
    return X


# Compiled: every simulation, sensitivity and simplex corner runs this recursion over all samples,
# and numpy's per-call overhead on a 10×10 product is ~50× the arithmetic.
@numba.njit(cache=True)
def _recurse(Phi, X, F):
    n, m = X.shape[1], X.shape[2]
    for k in range(F.shape[0]):
        for i in range(n):
            X[k + 1, i, :] = F[k, i, :]
            for l in range(n):  # the innermost loop runs along contiguous columns
                a = Phi[i, l]
                for j in range(m):
                    X[k + 1, i, j] += a * X[k, l, j]


def _states(record: Record, d: Discrete, x0: np.ndarray) -> np.ndarray:
    """State trajectory (N, 10) of one record from the full initial state `x0`."""
    forcing = record.inputs[:-1] @ d.E[:, NX:NX + NU].T + d.E[:, -1]
    return _propagate(d.E[:, :NX], x0[:, None], forcing[:, :, None])[:, :, 0]


def _w(x: np.ndarray, inputs: np.ndarray) -> np.ndarray:
    """`w[k] = [x[k]; δ[k]; 1]` (N, 14)."""
    return np.column_stack([x, inputs.astype(x.dtype), np.ones(len(x), dtype=x.dtype)])


def states(prob: Problem, p: np.ndarray) -> list[np.ndarray]:
    """Simulated states (N, 10) per experiment at the parameter vector `p` (u as a perturbation)."""
    models = _models(prob, p[:prob.n_free], 0)
    return [_states(r, models[r.dt], prob.x0(r, p)) for r in prob.records]


def outputs(prob: Problem, p: np.ndarray) -> list[np.ndarray]:
    """Model outputs (N, k) per experiment at the parameter vector `p` (u as a perturbation)."""
    return [x[:, r.measured] for r, x in zip(prob.records, states(prob, p))]


def residuals(prob: Problem, p: np.ndarray) -> list[np.ndarray]:
    """Measured minus model outputs (N, k) per experiment."""
    return [r.y - yhat for r, yhat in zip(prob.records, outputs(prob, p))]


def _first_order(prob: Problem, record: Record, d: Discrete, p: np.ndarray, x=None):
    """States (N, 10), w (N, 14) and state sensitivities (N, 10, n_free + k) of one record."""
    x = _states(record, d, prob.x0(record, p)) if x is None else x
    w = _w(x, record.inputs)
    nf, k = prob.n_free, len(record.measured)
    X0 = np.zeros((NX, nf + k), dtype=x.dtype)
    X0[record.measured, nf + np.arange(k)] = 1.0
    F = np.zeros((len(x) - 1, NX, nf + k), dtype=np.result_type(x, d.E))
    if nf:  # ∂E/∂θ_i w[k] for all i and k in one product
        F[:, :, :nf] = (w[:-1] @ d.dE.reshape(nf * NX, NW).T).reshape(-1, nf, NX).transpose(0, 2, 1)
    return x, w, _propagate(d.E[:, :NX], X0, F)


def sensitivities(prob: Problem, p: np.ndarray,
                  xs: Sequence[np.ndarray] | None = None) -> list[tuple[np.ndarray, np.ndarray]]:  # fmt: skip
    """Per experiment: model outputs (N, k) and output sensitivities (N, k, q) to the experiment's
    own parameters `p[prob.columns(record)]` (q = n_free + k; the others have no effect).

    ∂x[k+1]/∂θ_i = Φ ∂x[k]/∂θ_i + ∂E/∂θ_i w[k] (∂x[0]/∂θ = 0); ∂x[k]/∂x0 = Φᵏ.
    `xs`: the simulated states at `p` (`states(prob, p)`) if already known.
    """
    models = _models(prob, p[:prob.n_free], 1)
    out = []
    for i, r in enumerate(prob.records):
        x, _, X = _first_order(prob, r, models[r.dt], p, None if xs is None else xs[i])
        out.append((x[:, r.measured], X[:, r.measured]))
    return out


def curvature(prob: Problem, p: np.ndarray, weights: Sequence[np.ndarray]) -> np.ndarray:
    """`Σ_k Σ_c weights[k, c] ∂²y_c[k]/∂p∂p` (n_params, n_params), `weights` (N, k) per experiment.

    The second-order sensitivities of the paper's Eq. 3, discretised exactly, obey
      ∂²x[k+1]/∂p_i∂p_j = Φ ∂²x[k] + ∂Φ_i ∂x[k]/∂p_j + ∂Φ_j ∂x[k]/∂p_i + ∂²E_ij w[k],  ∂²x[0] = 0
    (only coefficients move Φ and E: the initial-state entries of ∂Φ, ∂²E are zero). Their
    weighted sum is taken by the adjoint recursion `μ[k] = Cᵀweights[k] + Φᵀ μ[k+1]`:
    `Σ_k aₖᵀ ∂²x[k] = Σ_k μ[k+1]ᵀ (forcing at k)`, exact, with no N·n_params² array. A one-hot
    weight gives the second-order sensitivity of one output sample.
    """
    models = _models(prob, p[:prob.n_free], 2)
    nf, H = prob.n_free, np.zeros((prob.n_params, prob.n_params), dtype=p.dtype)
    for r, wr in zip(prob.records, weights):
        d = models[r.dt]
        _, w, X = _first_order(prob, r, d, p)
        a = np.zeros((len(w), NX), dtype=np.result_type(wr, p))
        a[:, r.measured] = wr
        Phi = d.E[:, :NX]
        mu = _propagate(Phi.T, a[-1], a[-2::-1])[::-1]  # μ[k], k = 0 … N−1
        dPhi = np.zeros((X.shape[2], NX, NX), dtype=X.dtype)
        dPhi[:nf] = d.dE[:, :, :NX]
        H1 = np.einsum("jib,jbl->il", np.einsum("ja,iab->jib", mu[1:], dPhi), X[:-1])
        Hr = H1 + H1.T
        if nf:
            Hr[:nf, :nf] += np.einsum("ilab,ab->il", d.d2E, mu[1:].T @ w[:-1])
        cols = prob.columns(r)
        H[np.ix_(cols, cols)] += Hr
    return H


# --- likelihood ---------------------------------------------------------------------------------


def noise_variance(prob: Problem, res: Sequence[np.ndarray]) -> np.ndarray:
    """R: residual variance per channel (len(prob.channels),), pooled over the experiments.

    Floored far below any real sensor noise so that a noise-free fit stays finite.
    """
    ss, n, scale = np.zeros(len(prob.channels)), np.zeros(len(prob.channels)), np.zeros(len(prob.channels))
    for r, e in zip(prob.records, res):
        np.add.at(ss, r.channels, np.sum(e**2, axis=0))
        np.add.at(n, r.channels, len(e))
        np.add.at(scale, r.channels, np.sum(r.y**2, axis=0))
    return np.maximum(ss / n, 1e-14 * scale / n + 1e-30)


def weighted_cost(prob: Problem, res: Sequence[np.ndarray], R: np.ndarray) -> float:
    """`½ Σ_k eᵀ R⁻¹ e` over all experiments (R held fixed: the relaxation step)."""
    return 0.5 * sum(float(np.sum(e**2 / R[r.channels])) for r, e in zip(prob.records, res))


def negative_log_likelihood(prob: Problem, res: Sequence[np.ndarray]) -> float:
    """−ln p(Z|θ, R̂) with R̂ the ML noise variance: ½ Σ_c N_c (ln 2π R̂_c + 1)."""
    R = noise_variance(prob, res)
    n = np.zeros(len(prob.channels))
    for r in prob.records:
        np.add.at(n, r.channels, len(r.y))
    return float(0.5 * np.sum(n * (np.log(2 * np.pi * R) + 1)))


def exploded(prob: Problem, outs: Sequence[np.ndarray]) -> str | None:
    """Why the simulated outputs count as diverged (non-finite or ≫ the data), or None."""
    for r, yhat in zip(prob.records, outs):
        bound = EXPLODE * np.max(np.abs(r.y), axis=0) + 1.0
        bad = ~np.isfinite(yhat) | (np.abs(yhat) > bound)
        if bad.any():
            k, c = np.argwhere(bad)[0]
            return (f"experiment '{r.name}': simulated {STATES[r.measured[c]]} reaches "
                    f"{yhat[k, c]:.3g} at t = {k * r.dt:.3g} s")  # fmt: skip
    return None


def normal_equations(prob: Problem, sens, res, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`g = Σ Sᵀ R⁻¹ e` (minus the gradient of the weighted cost) and `M = Σ Sᵀ R⁻¹ S` (Fisher)."""
    g, M = np.zeros(prob.n_params), np.zeros((prob.n_params, prob.n_params))
    for r, (_, S), e in zip(prob.records, sens, res):
        W = (S / R[r.channels][None, :, None]).reshape(len(e) * len(r.measured), -1)
        S = S.reshape(len(W), -1)
        cols = prob.columns(r)
        g[cols] += W.T @ e.ravel()
        M[np.ix_(cols, cols)] += W.T @ S
    return g, M


def gauss_newton_terms(prob: Problem, p: np.ndarray, xs: Sequence[np.ndarray],
                       res: Sequence[np.ndarray], R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """`normal_equations(prob, sensitivities(prob, p, xs), res, R)`, without storing the (N, 10, q)
    sensitivities: they are propagated and accumulated sample by sample in one compiled pass, as
    one Gauss-Newton step needs only g and M (`xs`: the states at `p`)."""
    models = _models(prob, p[:prob.n_free], 1)
    g, M = np.zeros(prob.n_params), np.zeros((prob.n_params, prob.n_params))
    nf = prob.n_free
    for r, x, e in zip(prob.records, xs, res):
        d, k = models[r.dt], len(r.measured)
        X0 = np.zeros((NX, nf + k))
        X0[r.measured, nf + np.arange(k)] = 1.0
        gr, Mr = np.zeros(nf + k), np.zeros((nf + k, nf + k))
        forcing = _w(x, r.inputs)[:-1] @ d.dE.reshape(nf * NX, NW).T  # (N-1, nf·10): ∂E/∂θ_i w[k]
        _accumulate(np.ascontiguousarray(d.E[:, :NX]), forcing.reshape(-1, nf, NX), X0,
                    np.asarray(r.measured, np.int64), np.ascontiguousarray(e), 1.0 / R[r.channels], gr, Mr)  # fmt: skip
        cols = prob.columns(r)
        g[cols] += gr
        M[np.ix_(cols, cols)] += Mr
    return g, M


@numba.njit(cache=True)
def _accumulate(Phi, forcing, X, measured, e, rinv, g, M):
    """g += Σ Sᵀ R⁻¹ e, M += Σ Sᵀ R⁻¹ S with S[k] = X[k][measured], X[k+1] = Φ X[k] + (F[k], 0),
    F[k, i] = ∂E/∂θ_i w[k] given as `forcing` (N-1, nf, 10).

    Output sensitivities are gathered in blocks so that M grows by matrix products, not by
    per-sample rank-one updates."""
    n, m = X.shape
    nf, k, N = forcing.shape[1], len(measured), len(e)
    block = 64
    S = np.zeros((block * k, m))  # C-contiguous, as numba hands only those to BLAS
    SwT = np.zeros((m, block * k))
    eb = np.zeros(block * k)
    Xn = np.empty_like(X)
    filled = 0
    for t in range(N):
        for c in range(k):
            row = filled * k + c
            for j in range(m):
                S[row, j] = X[measured[c], j]
                SwT[j, row] = X[measured[c], j] * rinv[c]
            eb[row] = e[t, c]
        filled += 1
        if filled == block or t == N - 1:
            S[filled * k:] = 0.0  # a last, partial block: its stale rows must not count
            eb[filled * k:] = 0.0
            M += np.dot(SwT, S)
            g += np.dot(SwT, eb)
            filled = 0
        if t == N - 1:
            break
        for a in range(n):
            for j in range(m):
                Xn[a, j] = 0.0
            for l in range(n):
                phi = Phi[a, l]
                for j in range(m):
                    Xn[a, j] += phi * X[l, j]
            for i in range(nf):
                Xn[a, i] += forcing[t, i, a]
        X, Xn = Xn, X


def fit_initial_states(prob: Problem, values: np.ndarray,
                       R: np.ndarray | None = None) -> tuple[np.ndarray, list[np.ndarray]]:  # fmt: skip
    """The parameter vector at the free `values` with the best-fitting initial states, and the
    model outputs there.

    The outputs are linear in x0 (`y = y_forced + CΦᵏ x0`), so x0 is a weighted linear least-squares
    solution: R from the data's spread and then from the residuals when not given. A model whose
    responses are not finite gets the first measured samples.
    """
    models = _models(prob, values, 0)
    p = np.concatenate([values, np.zeros(prob.n_params - prob.n_free)])
    responses = []  # per record: forced (N, k) and free (N, k, k) output responses
    for r in prob.records:
        d, k = models[r.dt], len(r.measured)
        X0 = np.zeros((NX, 1 + k))
        X0[r.measured, 1 + np.arange(k)] = 1.0
        F = np.zeros((len(r.y) - 1, NX, 1 + k))
        F[:, :, 0] = r.inputs[:-1] @ d.E[:, NX:NX + NU].T + d.E[:, -1]
        Y = _propagate(d.E[:, :NX], X0, F)[:, r.measured]
        responses.append((Y[:, :, 0], Y[:, :, 1:]))

    def solve(R):
        outs = []
        for r, (yf, G) in zip(prob.records, responses):
            k = len(r.measured)
            if np.all(np.isfinite(yf)) and np.all(np.isfinite(G)):
                sd = np.sqrt(R[r.channels]) if R is not None else np.std(r.y, axis=0) + 1e-12
                A = (G / sd[None, :, None]).reshape(-1, k)
                # normal equations: k ≤ 10 unknowns pinned by the first samples, so squaring the
                # condition number is harmless, and it is 10× cheaper than an SVD of A
                x0 = np.linalg.lstsq(A.T @ A, A.T @ ((r.y - yf) / sd).ravel(), rcond=None)[0]
            else:
                x0 = r.y[0]
            p[r.offset:r.offset + k] = x0
            outs.append(yf + G @ x0)
        return outs

    if R is None:
        outs = solve(None)
        R = noise_variance(prob, [r.y - y for r, y in zip(prob.records, outs)])
    return p, solve(R)


def initial_states(prob: Problem, values: np.ndarray, R: np.ndarray | None = None) -> np.ndarray:
    """The parameter vector at the free `values` with the best-fitting initial states."""
    return fit_initial_states(prob, values, R)[0]


# --- uncertainty --------------------------------------------------------------------------------


def covariance(M: np.ndarray) -> np.ndarray:
    """`M⁻¹` through the eigenvalues of the diagonally scaled M.

    Eigenvalues below 1e-14 of the largest are numerically zero (a null direction): they are
    floored there, so the parameters along them get huge but finite standard errors.
    """
    D = np.sqrt(np.diag(M))
    D = np.where(D > 0, D, 1.0)
    lam, V = np.linalg.eigh(M / np.outer(D, D))
    lam = np.maximum(lam, 1e-14 * max(lam.max(initial=0.0), 1e-300))
    return (V / lam) @ V.T / np.outer(D, D)


def colored_middle(prob: Problem, sens, res, R: np.ndarray) -> np.ndarray:
    """Morelli & Klein's `Σ_i Σ_j S(i)ᵀR⁻¹ R_vv(i−j) R⁻¹S(j)`, R_vv the residual autocorrelation.

    With `R_vv(τ) = 1/N Σ_m v(m) v(m+τ)ᵀ` over all lags, the double sum equals
    `1/N Σ_τ P(τ) P(τ)ᵀ` with `P(τ) = Σ_m Σ_c v_c(m) (R⁻¹S)_c(m+τ)`: one FFT cross-correlation.
    """
    mid = np.zeros((prob.n_params, prob.n_params))
    for r, (_, S), e in zip(prob.records, sens, res):
        n = len(e)
        L = 2 * n
        W = S / R[r.channels][None, :, None]
        Pf = np.matmul(np.conj(np.fft.rfft(e, L, axis=0))[:, None, :], np.fft.rfft(W, L, axis=0))[:, 0]
        weight = np.full(len(Pf), 2.0)
        weight[0] = weight[-1] = 1.0  # DC and Nyquist appear once in the full spectrum
        cols = prob.columns(r)
        mid[np.ix_(cols, cols)] += np.real((np.conj(Pf) * weight[:, None]).T @ Pf) / (L * n)
    return mid


@dataclass(frozen=True)
class Information:
    """Cramér-Rao analysis of the free coefficients at `values` (initial states estimated)."""

    free: tuple[str, ...]
    values: np.ndarray  # (n_free,)
    fisher: np.ndarray  # (n_free, n_free), the initial states eliminated (Schur complement)
    crlb_std: np.ndarray  # (n_free,) Cramér-Rao standard errors
    correlation: np.ndarray  # (n_free, n_free)
    crlb_corrected_std: np.ndarray  # (n_free,) Morelli-Klein colored-residual bound
    noise_std: dict[str, float]  # per measured state: √R
    initial_states: dict[str, dict[str, float]]  # experiment → measured state → x0 (absolute u)
    cost: float  # negative log-likelihood (R at its ML value)
    p: np.ndarray  # (n_params,) the full parameter vector

    @property
    def relative_std(self) -> np.ndarray:
        return self.crlb_std / np.maximum(np.abs(self.values), 1e-300)


def assess(prob: Problem, p: np.ndarray) -> Information:
    """Fisher information, Cramér-Rao bounds and the colored-residual bound at `p`."""
    res = residuals(prob, p)
    R = noise_variance(prob, res)
    sens = sensitivities(prob, p)
    _, M = normal_equations(prob, sens, res, R)
    cov = covariance(M)
    corrected = cov @ colored_middle(prob, sens, res, R) @ cov
    nf = prob.n_free
    std = np.sqrt(np.diag(cov))
    fisher = M[:nf, :nf] - M[:nf, nf:] @ np.linalg.solve(M[nf:, nf:], M[nf:, :nf])
    fisher = (fisher + fisher.T) / 2
    x0 = {}
    for r in prob.records:
        xr = prob.x0(r, p) + np.eye(NX)[IX["u"]] * prob.speed
        x0[r.name] = {STATES[i]: float(xr[i]) for i in r.measured}
    return Information(prob.free, p[:nf].copy(), fisher, std[:nf],
                       cov[:nf, :nf] / np.outer(std[:nf], std[:nf]),
                       np.sqrt(np.maximum(np.diag(corrected)[:nf], 0.0)),
                       dict(zip(prob.channels, map(float, np.sqrt(R)))), x0,
                       negative_log_likelihood(prob, res), p.copy())  # fmt: skip


def _values(prob: Problem, values) -> np.ndarray:
    if values is None:
        return prob.start
    if isinstance(values, Mapping):
        unknown = set(values) - set(prob.free)
        if unknown:
            raise InputError(f"values: {sorted(unknown)[0]!r} is not a free coefficient; "
                             f"expected one of {', '.join(prob.free)}")  # fmt: skip
        return np.array([float(values.get(n, v)) for n, v in zip(prob.free, prob.start)])
    values = np.asarray(values, dtype=float)
    if values.shape != (prob.n_free,):
        raise InputError(f"values: {values.shape} values; expected {prob.n_free} (the free ones)")
    return values


def divergence(prob: Problem, p: np.ndarray) -> str | None:
    """Why the model at `p` diverges on the data (with its least stable eigenvalue), or None."""
    with np.errstate(over="ignore", invalid="ignore"):
        why = exploded(prob, outputs(prob, p))
    if why is None:
        return None
    A = continuous(prob.structure, prob.coefficients(p[:prob.n_free]))[0]
    ev = np.linalg.eigvals(A)
    worst = ev[np.argmax(ev.real)]
    return f"{why}; A's largest eigenvalue real part is {worst.real:.3g} 1/s"


def information(experiments: Sequence[Experiment], config: ModelConfig,
                values: Mapping[str, float] | np.ndarray | None = None) -> Information:
    """Cramér-Rao analysis of `config.free` at `values` (default: the config's coefficients).

    The initial states are fitted (linear least squares) and R is the residual variance there.
    A model that diverges on the data has no meaningful bound: InputError.
    """
    prob = problem(experiments, config)
    with np.errstate(over="ignore", invalid="ignore"):
        p = initial_states(prob, _values(prob, values))
    why = divergence(prob, p)
    if why is not None:
        raise InputError(f"{prob.source}: the model diverges at these coefficients ({why}); "
                         "expected coefficients giving a bounded response")  # fmt: skip
    return assess(prob, p)


def predict(experiments: Sequence[Experiment], config: ModelConfig,
            initial: Mapping[str, Mapping[str, float]] | None = None) -> list[np.ndarray]:
    """Model outputs (N, k) per experiment in its measured columns, absolute u, for plots.

    `initial`: experiment → state → x0 (absolute u, as in `Estimate.extra["initial_states"]`);
    the ones it does not give are the best-fitting initial states (no fit when it gives all).
    """
    prob = problem(experiments, config)
    given = initial or {}
    if all(STATES[i] in given.get(r.name, {}) for r in prob.records for i in r.measured):
        p = np.concatenate([prob.start, np.zeros(prob.n_params - prob.n_free)])
    else:
        p = initial_states(prob, prob.start)
    for r in prob.records:
        for j, i in enumerate(r.measured):
            if STATES[i] in given.get(r.name, {}):
                p[r.offset + j] = initial[r.name][STATES[i]] - (prob.speed if STATES[i] == "u" else 0)
    out = []
    for r, yhat in zip(prob.records, outputs(prob, p)):
        yhat = yhat.copy()
        yhat[:, r.measured == IX["u"]] += prob.speed
        out.append(yhat)
    return out


def synthetic(config: ModelConfig, t: np.ndarray, inputs: np.ndarray,
              noise_std: Mapping[str, float] | None = None, measured: Sequence[str] = STATES,
              rng: np.random.Generator | None = None, x0: np.ndarray | None = None,
              name: str = "synthetic") -> Experiment:  # fmt: skip
    """An experiment simulated from the linear model of `config` itself (ZOH inputs, absolute u).

    `x0`: initial perturbation state (10,), default trim; `noise_std`: white Gaussian noise per
    state (missing: none).
    """
    theta = theta_vector(config.coefficients)
    Phi, Gamma, sv = discretize(*continuous(structure(config.vehicle), theta), float(t[1] - t[0]))
    x0 = np.zeros(NX) if x0 is None else np.asarray(x0, dtype=float)
    x = _propagate(Phi, x0, np.asarray(inputs)[:-1] @ Gamma.T + sv)
    x[:, IX["u"]] += config.vehicle.speed
    measured = tuple(m for m in STATES if m in measured)
    cols = [IX[m] for m in measured]
    y = x[:, cols]
    if noise_std:
        rng = rng or np.random.default_rng()
        y = y + rng.normal(size=y.shape) * np.array([noise_std.get(m, 0.0) for m in measured])
    return Experiment(name, np.asarray(t, dtype=float), tuple(measured), y, np.asarray(inputs, dtype=float))


# --- equation error: a robust start -------------------------------------------------------------


def equation_error(experiments: Sequence[Experiment], config: ModelConfig,
                   window_s: float = 0.5) -> ModelConfig:
    """`config` with the free coefficients from a least-squares fit of the SPEC §2 rows.

    Each dynamics row `Mt ẋ = At x + Bt δ + St` is linear in its coefficients. The measured states
    are smoothed (Savitzky-Golay, cubic, `window_s` wide) and the row is averaged over each
    sample interval, where the input is held: ẋ ≈ Δx/Δt, x ≈ the interval's midpoint; the row's
    free coefficients are then a linear regression. A row is used only on experiments that measure every
    state it involves; the free coefficients of a row that no experiment supports, and directions
    the data do not excite, keep their a-priori values (minimum-norm correction).
    """
    prob = problem(experiments, config)
    s, theta = prob.structure, prob.theta
    fixed = theta.copy()
    fixed[prob.index] = 0.0
    Mf, Af, Bf, Sf = tilde(s, fixed)  # known part: constants and fixed coefficients
    values = prob.start
    for row in range(6):  # u v w p q r
        cols = [j for j, i in enumerate(prob.index)
                if s.dMt[i, row].any() or s.dAt[i, row].any() or s.dBt[i, row].any()]  # fmt: skip
        if not cols:
            continue
        idx = prob.index[cols]
        involved = (Mf[row] != 0) | (Af[row] != 0) | (s.dMt[idx, row] != 0).any(0) | \
            (s.dAt[idx, row] != 0).any(0)  # fmt: skip
        involved[row] = True
        X, Y = [], []
        for r in prob.records:
            if not set(np.flatnonzero(involved)) <= set(r.measured):
                continue
            n = len(r.y)
            win = min(max(5, int(round(window_s / r.dt)) | 1), n - (1 - n % 2))
            if win <= 3:
                continue
            xs = np.zeros((n, NX))
            xs[:, r.measured] = savgol_filter(r.y, win, 3, axis=0)
            us = savgol_filter(r.inputs, win, 3, axis=0)
            # over each sample interval the input is held: the row equation averaged over it
            # has ẋ = Δx/Δt, x at the midpoint and δ exactly, with no derivative across a step;
            # the same (linear) smoothing of states and inputs keeps that equation consistent
            keep = slice(win // 2, n - 1 - win // 2)  # the smoothed ends are extrapolated
            xdot = (np.diff(xs, axis=0) / r.dt)[keep]
            x = ((xs[1:] + xs[:-1]) / 2)[keep]
            u = us[:-1][keep]
            # Σ_free θ_i (∂Mt_i ẋ − ∂At_i x − ∂Bt_i δ)_row = (At_f x + Bt_f δ + St_f − Mt_f ẋ)_row
            X.append(xdot @ s.dMt[idx, row].T - x @ s.dAt[idx, row].T - u @ s.dBt[idx, row].T)
            Y.append(x @ Af[row] + u @ Bf[row] + Sf[row] - xdot @ Mf[row])
        if not X:
            continue
        X, Y = np.vstack(X), np.concatenate(Y)
        prior = values[cols]
        scale = np.linalg.norm(X, axis=0)
        scale = np.where(scale > 0, scale, 1.0)
        step = np.linalg.lstsq(X / scale, Y - X @ prior, rcond=1e-8)[0] / scale
        values[cols] = prior + step
    return config.with_coefficients(dict(zip(prob.free, map(float, values))))
