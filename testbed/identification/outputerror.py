"""Output-error maximum likelihood for the linear model (docs/model.md): its numerical core.

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

Speed: the estimators never hold the N·k·q sensitivities of an experiment whole. They are made a
thousand samples at a time and summed into the normal equations as they come (fresh memory
pages, whose first writes fault, cost more than the arithmetic), and separately for each part of
the model that evolves on its own (a torpedo's lateral and longitudinal motions are uncoupled in
the linear model: a quarter of the arithmetic). Every recursion over the samples runs in numpy,
in blocks of samples (`_Scan`), and this module imports nothing but numpy: a command that fits a
CSV starts without loading a compiler or scipy. Optimisers that simulate thousands of times run
them compiled instead (`compiled`).
"""

from __future__ import annotations

import contextlib
import contextvars
import math
from dataclasses import dataclass, replace
from statistics import NormalDist
from typing import Iterator, Mapping, NamedTuple, Sequence

import numpy as np

from testbed.data import Experiment, ModelConfig, check_config, check_experiment
from testbed.errors import InputError
from testbed.models.linear import (
    ITHETA,
    IX,
    NU,
    NX,
    STATES,
    Structure,
    continuous,
    derivatives,
    discretize,
    expm_pair,
    fastest_rate,
    inertia_defect,
    structure,
    theta_vector,
    tilde,
    unobserved,
)

NW = NX + NU + 1  # length of w = [x; δ; 1]
EXPLODE = 1e3  # a simulated output beyond EXPLODE·max|y| + 1 (SI) means the model diverged
RELAXATIONS = 20  # noise updates of `fit_initial_states` at most (each a k × k solve per record)
PIECE = 1024  # samples per piece of sensitivities (`_pieces`): a piece's work arrays stay in the CPU's cache


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
    known: np.ndarray | None = None  # (len(channels),) R where [identify] noise_std gives it, else NaN

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
        return np.r_[: self.n_free, record.offset : record.offset + len(record.measured)]

    def x0(self, record: Record, p: np.ndarray) -> np.ndarray:
        """The record's full initial state (10,) from the parameter vector."""
        x0 = np.zeros(NX, dtype=p.dtype)
        x0[record.measured] = p[record.offset : record.offset + len(record.measured)]
        return x0


COARSEST = math.log(2.0**53)  # ρΔ beyond which the fastest mode decays below rounding in one step


def check_fit(experiments: Sequence[Experiment], config: ModelConfig) -> None:
    """`InputError` unless `config.free` can be fitted to the experiments' fitted outputs: the
    inputs check out (`check_inputs`) and every free coefficient is seen in the measured states
    (`model.unobserved`)."""
    if not config.free:
        raise InputError(f"{config.source or 'config'}: [identify] free is empty; nothing to estimate")
    experiments = config.fitted(experiments)
    check_inputs(experiments, config)
    measured = {s for e in experiments for s in e.measured}
    blind = unobserved(structure(config.vehicle), theta_vector(config.coefficients), config.free, measured)
    if blind:
        raise InputError(
            f"{config.source or 'config'}: [identify] free {', '.join(blind)}: not "
            f"identifiable, the measured states ({', '.join(s for s in STATES if s in measured)}) "
            "do not depend on them in the model; measure the states they drive or fix them"
        )


def check_inputs(experiments: Sequence[Experiment], config: ModelConfig) -> None:
    """`InputError` unless the experiments and the config can be fitted together, before any work:

    - each record is usable (`data.check_experiment`) and the config valid (`data.check_config`);
    - the config's Mt is the inertia of a body (`model.inertia_defect`): a singular or indefinite
      one makes every model built on it blow up, the fault of the config, not of the data;
    - each record's sampling interval Δ resolves the model: over one step the fastest mode
      (rate ρ) decays by e^(−ρΔ), and beyond ρΔ = ln 2⁵³ that is below double-precision
      rounding, so the record shows none of it. Such a step is the data's fault (t in ms, say).
    """
    if not experiments:
        raise InputError("no experiments given; expected at least one measurement record")
    for e in experiments:
        check_experiment(e)
    check_config(config)
    source = config.source or "config"
    s, theta = structure(config.vehicle), theta_vector(config.coefficients)
    defect = inertia_defect(s, theta)
    if defect:
        raise InputError(f"{source}: the inertia matrix Mt is not a body's: {defect}")
    rate = fastest_rate(s, theta)
    for e in experiments:
        dt = float(e.t[1] - e.t[0])
        if rate * dt > COARSEST:
            raise InputError(
                f"{e.source or e.name}: t steps {dt:g} s; the model of {source} has a "
                f"mode at {rate:.3g} 1/s, which such a step cannot show: expected a step "
                f"below {COARSEST / rate:.3g} s (t in seconds)"
            )


def problem(experiments: Sequence[Experiment], config: ModelConfig) -> Problem:
    """Check the experiments and the config (`check_inputs`) and set up the output-error problem."""
    check_inputs(experiments, config)
    where = config.source or "config"
    theta = theta_vector(config.coefficients)
    channels = tuple(s for s in STATES if any(s in e.measured for e in experiments))
    records, offset = [], len(config.free)
    for e in experiments:
        y, inputs, t = (np.asarray(a, dtype=float) for a in (e.y, e.inputs, e.t))
        measured = np.array([IX[s] for s in e.measured])
        y = y.copy()
        if "u" in e.measured:
            y[:, e.measured.index("u")] -= config.vehicle.speed
        records.append(
            Record(
                e.name,
                y,
                inputs,
                measured,
                np.array([channels.index(s) for s in e.measured]),
                float(t[1] - t[0]),
                offset,
            )
        )
        offset += len(measured)
    index = np.array([ITHETA[n] for n in config.free], dtype=int)
    return Problem(
        structure(config.vehicle),
        theta,
        tuple(config.free),
        index,
        tuple(records),
        channels,
        config.vehicle.speed,
        where,
        np.array([(config.noise_std or {}).get(c, np.nan) ** 2 for c in channels]),
    )


# --- the discrete model and its exact derivatives ---------------------------------------------


@dataclass(frozen=True)
class Discrete:
    """`E = [Φ Γ s]` (10, 14) and its derivatives w.r.t. the free coefficients."""

    E: np.ndarray
    dE: np.ndarray | None = None  # (n_free, 10, 14)
    d2E: np.ndarray | None = None  # (n_free, n_free, 10, 14)


def discrete(prob: Problem, values: np.ndarray, dt: float, order: int = 0) -> Discrete:
    """The ZOH model at the free `values` and its first (`order` ≥ 1) and second derivatives.

    With `F(θ)` the augmented matrix [[A, B, S], [0, 0, 0]], `E = exp(F Δ)`; its derivatives are
    the top-right blocks of the exponentials of block-triangular matrices (Van Loan /
    Najfeld-Havel, `expm_pair`), all at once, with
    `∂²[A B S]/∂θ_i∂θ_j = −Mt⁻¹(∂Mt_i ∂[A B S]_j + ∂Mt_j ∂[A B S]_i)` (Mt, At affine in θ).
    """
    s, theta = prob.structure, prob.coefficients(values)
    A, B, S = continuous(s, theta)
    if order == 0 or prob.n_free == 0:
        return Discrete(np.column_stack(discretize(A, B, S, dt)))
    nf = prob.n_free
    dA, dB, dS = derivatives(s, theta, A, B, S, prob.index)
    dABS = np.concatenate([dA, dB, dS[:, :, None]], axis=2)  # (nf, 10, 14)
    ABS = np.column_stack([A, B, S])
    if order == 1:
        E, dE = expm_pair(ABS, dABS.transpose(1, 0, 2), dt)
        return Discrete(E, dE.transpose(1, 0, 2))
    Mt = tilde(s, theta)[0]
    G = np.einsum("iab,jbc->ijac", s.dMt[prob.index], dABS)
    iu, ju = np.triu_indices(nf)
    d2ABS = -np.linalg.solve(Mt[None], (G + G.transpose(1, 0, 2, 3))[iu, ju])  # (pairs, 10, 14)
    E, dE, block = expm_pair(ABS, dABS.transpose(1, 0, 2), dt, (d2ABS, iu, ju))
    d2E = np.zeros((nf, nf, NX, NW), dtype=E.dtype)
    d2E[iu, ju] = block
    d2E[ju, iu] = block
    return Discrete(E, dE.transpose(1, 0, 2), d2E)


def _models(prob: Problem, values: np.ndarray, order: int) -> dict[float, Discrete]:
    return {dt: discrete(prob, values, dt, order) for dt in {r.dt for r in prob.records}}


# --- simulation and sensitivities -------------------------------------------------------------


_KERNELS = contextvars.ContextVar(
    "kernels", default=None
)  # testbed.identification.kernels within `compiled()`


@contextlib.contextmanager
def compiled():
    """Within this context the recursions over the samples run compiled (`testbed.identification.kernels`), for
    optimisers that simulate thousands of times; outside it, in numpy blocks (`_Scan`), which
    need no compiler loaded: a process that fits one file is done before numba would be."""
    from testbed.identification import kernels

    token = _KERNELS.set(kernels)
    try:
        yield
    finally:
        _KERNELS.reset(token)


def _propagate(Phi: np.ndarray, x0: np.ndarray, F: np.ndarray) -> np.ndarray:
    """`x[k+1] = Φ x[k] + F[k]` from `x[0] = x0` (n,); returns (len(F) + 1, n)."""
    dtype = np.result_type(Phi, x0, F)  # complex under the complex-step tests
    n, N = len(x0), len(F) + 1
    x = np.empty((N, n), dtype=dtype)
    kernels = _KERNELS.get()
    if kernels is not None:
        x[0] = x0
        kernels.propagate(np.ascontiguousarray(Phi, dtype), x, np.ascontiguousarray(F, dtype))
        return x
    order, Y, _ = _Scan(np.asarray(Phi, dtype), 1, 1, np.arange(n), N)(
        np.asarray(x0, dtype)[:, None], np.asarray(F, dtype)[:, :, None], N
    )
    x[order] = Y[:, :, 0].T
    return x


class _Scan:
    """`X[t+1] = Φ X[t] + F[t]` over pieces of at most `size` samples, X[t] (n, m) with only the
    first j columns of F[t] nonzero. A call `(X0, f, P)` takes the piece's first state `X0`
    (n, m) and its forcings `f[t]` (the first j columns of F[t]; P − 1 or P of them, (·, n, j))
    and gives `(order, Y, carry)`: `Y[c, k] = X[order[k]][rows[c]]` for the P samples of the
    piece in the order `order` (len(rows), P, m; valid until the next call), and X[P] if f has P
    forcings (else None).

    In chunks of L ≈ √size samples, t = bL + i. All chunks advance together from a zero state,
    one product per step for all of them: `Z_i = Φ Z_{i−1} + F` (Z_i[b]: the response at bL + i
    to chunk b's own forcing, zero in the unforced columns, which are left out), as
    `[Φ I] [Z_{i−1}; F]`. The chunks' first states then follow one from the other,
    `X[(b+1)L] = Φᴸ X[bL] + Z_L[b]`, and `X[bL + i] = Φⁱ X[bL] + Z_i[b]` is one product for all
    samples, ordered by i, then b. That is about twice the arithmetic of stepping sample by
    sample, in 2√P products of n × B·m blocks instead of P products of n × m blocks, whose
    per-call overhead in numpy would be ~50× the arithmetic. The powers of Φ and the work arrays
    are made once, for every call.
    """

    def __init__(self, Phi: np.ndarray, j: int, m: int, rows: np.ndarray, size: int):
        n, c, dtype = len(Phi), len(rows), Phi.dtype
        self.Phi, self.j, self.m, self.rows = Phi, j, m, rows
        self.L = L = max(1, math.isqrt(size))
        B = -(-size // L)
        self.power = np.empty((L + 1, n, n), dtype=dtype)  # Φⁱ
        self.power[0] = np.eye(n)
        for i in range(1, L + 1):
            self.power[i] = Phi @ self.power[i - 1]
        self.step = np.hstack([Phi, np.eye(n, dtype=dtype)])  # [Φ I]
        self.rows_power = self.power[:L][:, rows].transpose(1, 0, 2).reshape(c * L, n)  # Φⁱ[rows[c]]
        self.W = np.empty((L + 1, 2 * n, B * j), dtype=dtype)  # W[i] = [Z_i; F at bL + i]: one operand
        self.start = np.empty((B + 1, n, m), dtype=dtype)  # X[bL]
        self.Y = np.empty((c * L, B * m), dtype=dtype)
        self.order = (np.arange(L)[:, None] + L * np.arange(B)).ravel()

    def __call__(self, X0: np.ndarray, f: np.ndarray, P: int):
        L, j, m, n, c = self.L, self.j, self.m, len(self.Phi), len(self.rows)
        B, T = -(-P // L), len(f)
        W = self.W[:, :, : B * j]
        forcing = W[:L, n:].reshape(L, n, B, j)  # [i, a, b] = F[bL + i][a]
        full, rest = divmod(T, L)
        forcing[:, :, :full] = f[: full * L].reshape(full, L, n, j).transpose(1, 2, 0, 3)
        if full < B:
            forcing[:rest, :, full] = f[full * L :]
            forcing[rest:, :, full] = 0.0
            forcing[:, :, full + 1 :] = 0.0
        W[0, :n] = 0.0
        for i in range(1, L + 1):
            np.matmul(self.step, W[i - 1], out=W[i, :n])
        Z = W[:, :n].reshape(L + 1, n, B, j)
        start = self.start[: B + 1]
        start[0] = X0
        for b in range(B):
            np.matmul(self.power[L], start[b], out=start[b + 1])
            start[b + 1, :, :j] += Z[L, :, b]
        # Y[c, i, b] = Φⁱ[rows[c]] X[bL] + Z_i[b][rows[c]]
        Y = np.matmul(self.rows_power, start[:B].transpose(1, 0, 2).reshape(n, B * m), out=self.Y[:, : B * m])
        Y = Y.reshape(c, L, B, m)
        Y[..., :j] += Z[:L, self.rows].transpose(1, 0, 2, 3)
        order = self.order.reshape(L, -1)[:, :B]
        if B * L == P:
            Y, order = Y.reshape(c, L * B, m), order.ravel()
        else:  # the piece's own samples only
            keep = order < P
            Y, order = Y[:, keep], order[keep]
        carry = None
        if T >= P:
            b, i = divmod(P, L)
            carry = self.power[i] @ start[b]
            if i:
                carry[:, :j] += Z[i, :, b]
        return order, Y, carry


def _states(record: Record, d: Discrete, x0: np.ndarray) -> np.ndarray:
    """State trajectory (N, 10) of one record from the full initial state `x0`."""
    return _propagate(d.E[:, :NX], x0, record.inputs[:-1] @ d.E[:, NX : NX + NU].T + d.E[:, -1])


def _w(x: np.ndarray, inputs: np.ndarray) -> np.ndarray:
    """`w[k] = [x[k]; δ[k]; 1]` (N, 14)."""
    return np.column_stack([x, inputs.astype(x.dtype), np.ones(len(x), dtype=x.dtype)])


def states(prob: Problem, p: np.ndarray) -> list[np.ndarray]:
    """Simulated states (N, 10) per experiment at the parameter vector `p` (u as a perturbation)."""
    models = _models(prob, p[: prob.n_free], 0)
    return [_states(r, models[r.dt], prob.x0(r, p)) for r in prob.records]


def outputs(prob: Problem, p: np.ndarray) -> list[np.ndarray]:
    """Model outputs (N, k) per experiment at the parameter vector `p` (u as a perturbation)."""
    return [x[:, r.measured] for r, x in zip(prob.records, states(prob, p))]


def residuals(prob: Problem, p: np.ndarray) -> list[np.ndarray]:
    """Measured minus model outputs (N, k) per experiment."""
    return [r.y - yhat for r, yhat in zip(prob.records, outputs(prob, p))]


def _sensitivity_parts(
    prob: Problem, record: Record, d: Discrete, x: np.ndarray, rows, scale: np.ndarray, size: int
) -> Iterator[tuple[np.ndarray, np.ndarray, Iterator]]:
    """`scale[c] ∂x_rows[c][k]/∂p` of one record, p its own parameters (q = n_free + k), from its
    states `x` (N, 10), for each `_uncoupled` part of the model: (channels, params, pieces), the
    pieces as in `_pieces` with (T, len(channels), len(params)) arrays; `channels` index `rows`,
    `params` p. Sensitivities across the parts are zero and not given.

    ∂x[k+1]/∂θ_i = Φ ∂x[k]/∂θ_i + ∂E/∂θ_i w[k] (∂x[0]/∂θ = 0); ∂x[k]/∂x0 = Φᵏ.
    """
    nf, rows = prob.n_free, np.asarray(rows)
    dtype = np.result_type(x, d.E)  # complex under the complex-step tests
    w, Phi = _w(x, record.inputs), d.E[:, :NX]
    dE = d.dE if nf else np.zeros((0, NX, NW), dtype=dtype)
    acts = np.column_stack([dE.any(axis=2).T, np.eye(NX, dtype=bool)[:, record.measured]])
    for states, params, channels in _uncoupled(Phi != 0, acts, rows):
        at = np.full(NX, -1)
        at[states] = np.arange(len(states))
        theta, x0 = params[params < nf], params[params >= nf]
        X = np.zeros((len(states), len(params)), dtype=dtype)  # the θ columns first
        X[at[record.measured[x0 - nf]], len(theta) + np.arange(len(x0))] = 1.0
        D = dE[theta][:, states, :].transpose(1, 0, 2).reshape(-1, NW)  # rows: (state, θ)
        yield (
            channels,
            params,
            _pieces(Phi[np.ix_(states, states)], D, w, X, at[rows[channels]], scale[channels], size),
        )


def _uncoupled(coupled: np.ndarray, acts: np.ndarray, rows: np.ndarray):
    """The parts of the model that evolve independently: (states, params, channels) for each.

    `coupled[a, l]`: state l feeds state a (Φ's pattern); `acts[:, j]`: the states parameter j
    acts on; `rows`: the states asked for. A torpedo's lateral and longitudinal motions are
    uncoupled in the linear model, so each part propagates only its own states and parameters
    (a quarter of the arithmetic); a fully coupled model is one part.
    """
    shared = acts.astype(int) @ acts.T.astype(int) > 0  # states one parameter acts on together
    reach = coupled | coupled.T | shared | np.eye(len(coupled), dtype=bool)
    while True:  # transitive closure by squaring: ⌈log₂ n⌉ products at most
        wider = reach.astype(int) @ reach.astype(int) > 0
        if (wider == reach).all():
            break
        reach = wider
    label = reach.argmax(axis=1)  # a part's label: its first state
    out = []
    for part in sorted(set(label.tolist())):  # (np.unique would import numpy.ma: 50 ms)
        params = np.flatnonzero(acts[label == part].any(axis=0))
        channels = np.flatnonzero(label[rows] == part)
        if len(params) and len(channels):
            out.append((np.flatnonzero(label == part), params, channels))
    return out


def _pieces(
    Phi: np.ndarray, D: np.ndarray, w: np.ndarray, X: np.ndarray, rows, scale: np.ndarray, size: int
) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Rows `rows` of X[t], times `scale`, for `X[t+1] = Φ X[t] + F[t]` from `X[0] = X` (n, m),
    where F[t]'s first j columns are `(D w[t])` reshaped (n, j) (D: (n·j, len(w[t]))) and the
    others zero: in consecutive pieces of at most `size` samples, `(samples, S)` with
    `S[c, k] = scale[c] X[samples[k]][rows[c]]` (len(rows), len(samples), m; valid until the
    next piece), made by `_Scan` (`kernels.recursion` within `compiled()`) from the last state of
    the piece before. Made and used a piece
    at a time (F too), in arrays reused from piece to piece, neither is ever allocated for all N
    samples: fresh memory pages cost more here than the arithmetic, as their first writes
    fault."""
    N, dtype, n = len(w), X.dtype, len(Phi)
    rows, scale = np.asarray(rows, np.int64), np.asarray(scale, float)[:, None, None]
    DT, j = np.asarray(D.T, dtype), len(D) // n
    size = -(-N // -(-N // size))  # pieces of equal length, none longer than `size`
    kernels = _KERNELS.get()
    if kernels is None:
        scan = _Scan(np.asarray(Phi, dtype), j, X.shape[1], rows, size)
    else:
        Phi, X = np.ascontiguousarray(Phi, dtype), X.astype(dtype)  # X carried on in place
        work = np.empty(len(rows) * size * X.shape[1], dtype=dtype)
    for t0 in range(0, N, size):
        t1 = min(t0 + size, N)
        f = w[t0 : min(t1, N - 1)] @ DT  # the last piece has no forcing after the record's end
        f = f.reshape(len(f), n, j)
        if kernels is None:
            order, S, X = scan(X, f, t1 - t0)
        else:  # the first len(rows)·P·m entries of `work`: contiguous for any P
            order = np.arange(t1 - t0)
            S = work[: len(rows) * len(order) * X.shape[1]].reshape(len(rows), len(order), -1)
            kernels.recursion(Phi, f, X, rows, S)
        S *= scale
        yield t0 + order, S


def _sensitivities(
    prob: Problem, record: Record, d: Discrete, x: np.ndarray, rows, scale: np.ndarray
) -> np.ndarray:
    """All of `_sensitivity_parts` at once: (N, len(rows), q)."""
    S = np.zeros((len(x), len(rows), prob.n_free + len(record.measured)), dtype=np.result_type(x, d.E))
    for channels, params, pieces in _sensitivity_parts(prob, record, d, x, rows, scale, len(x)):
        for samples, piece in pieces:
            S[np.ix_(samples, channels, params)] = piece.transpose(1, 0, 2)
    return S


def sensitivities(prob: Problem, p: np.ndarray, xs: Sequence[np.ndarray] | None = None) -> list[np.ndarray]:
    """Per experiment: output sensitivities (N, k, q) to the experiment's own parameters
    `p[prob.columns(record)]` (q = n_free + k; the others have no effect). `xs`: the states at
    `p` (`states(prob, p)`) if already known. (The estimators take them in pieces instead.)
    """
    models = _models(prob, p[: prob.n_free], 1)
    xs = states(prob, p) if xs is None else xs
    return [
        _sensitivities(prob, r, models[r.dt], x, r.measured, np.ones(len(r.measured)))
        for r, x in zip(prob.records, xs)
    ]


def _scale(record: Record, R: np.ndarray) -> np.ndarray:
    """Per measured channel: 1/√R, which weights the sensitivities."""
    return R[record.channels] ** -0.5


def curvature(prob: Problem, p: np.ndarray, weights: Sequence[np.ndarray]) -> np.ndarray:
    """`Σ_k Σ_c weights[k, c] ∂²y_c[k]/∂p∂p` (n_params, n_params), `weights` (N, k) per experiment.

    The second-order sensitivities of the paper's Eq. 3, discretised exactly, obey
      ∂²x[k+1]/∂p_i∂p_j = Φ ∂²x[k] + ∂Φ_i ∂x[k]/∂p_j + ∂Φ_j ∂x[k]/∂p_i + ∂²E_ij w[k],  ∂²x[0] = 0
    (only coefficients move Φ and E: the initial-state entries of ∂Φ, ∂²E are zero). Their
    weighted sum is taken by the adjoint recursion `μ[k] = Cᵀweights[k] + Φᵀ μ[k+1]`:
    `Σ_k aₖᵀ ∂²x[k] = Σ_k μ[k+1]ᵀ (forcing at k)`, exact, with no N·n_params² array. A one-hot
    weight gives the second-order sensitivity of one output sample.
    """
    models = _models(prob, p[: prob.n_free], 2)
    nf, H = prob.n_free, np.zeros((prob.n_params, prob.n_params), dtype=p.dtype)
    for r, wr in zip(prob.records, weights):
        d = models[r.dt]
        x = _states(r, d, prob.x0(r, p))
        w, X = _w(x, r.inputs), _sensitivities(prob, r, d, x, np.arange(NX), np.ones(NX))
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
    """R: residual variance per channel (len(prob.channels),), pooled over the experiments."""
    return _pooled_variance(prob, [np.sum(e**2, axis=0) for e in res])


def _pooled_variance(prob: Problem, sums: Sequence[np.ndarray]) -> np.ndarray:
    """R from each experiment's residual sums of squares per measured channel (`noise_variance`).

    Floored far below any real sensor noise so that a noise-free fit stays finite; the channels
    whose noise the config gives (`[identify] noise_std`) keep it.
    """
    ss, n, scale = np.zeros(len(prob.channels)), np.zeros(len(prob.channels)), np.zeros(len(prob.channels))
    for r, e2 in zip(prob.records, sums):  # a record's channels are distinct
        ss[r.channels] += e2
        n[r.channels] += len(r.y)
        scale[r.channels] += np.sum(r.y**2, axis=0)
    R = np.maximum(ss / n, 1e-14 * scale / n + 1e-30)
    return R if prob.known is None else np.where(np.isnan(prob.known), R, prob.known)


def weighted_cost(prob: Problem, res: Sequence[np.ndarray], R: np.ndarray) -> float:
    """`½ Σ_k eᵀ R⁻¹ e` over all experiments (R held fixed: the relaxation step)."""
    return 0.5 * sum(float(np.sum(e**2 / R[r.channels])) for r, e in zip(prob.records, res))


def negative_log_likelihood(prob: Problem, res: Sequence[np.ndarray]) -> float:
    """−ln p(Z|θ, R) = ½ Σ_c (N_c ln 2π R_c + S_c/R_c), S_c channel c's residual sum of squares,
    R_c the ML noise variance S_c/N_c (then ½ Σ_c N_c (ln 2π R_c + 1)) or the config's."""
    R = noise_variance(prob, res)
    n, S = np.zeros(len(prob.channels)), np.zeros(len(prob.channels))
    for r, e in zip(prob.records, res):
        n[r.channels] += len(r.y)
        S[r.channels] += np.sum(e**2, axis=0)
    return float(0.5 * np.sum(n * np.log(2 * np.pi * R) + S / R))


def exploded(prob: Problem, outs: Sequence[np.ndarray]) -> str | None:
    """Why the simulated outputs count as diverged (non-finite or ≫ the data), or None."""
    for r, yhat in zip(prob.records, outs):
        bound = EXPLODE * np.max(np.abs(r.y), axis=0) + 1.0
        bad = ~np.isfinite(yhat) | (np.abs(yhat) > bound)
        if bad.any():
            k, c = np.argwhere(bad)[0]
            return (
                f"experiment '{r.name}': simulated {STATES[r.measured[c]]} reaches "
                f"{yhat[k, c]:.3g} at t = {k * r.dt:.3g} s"
            )
    return None


def gauss_newton_terms(
    prob: Problem, p: np.ndarray, xs: Sequence[np.ndarray], res: Sequence[np.ndarray], R: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """`g = Σ Sᵀ R⁻¹ e` (minus the gradient of the weighted cost) and `M = Σ Sᵀ R⁻¹ S` (Fisher) at
    `p` (`xs`: the states there, `res`: the residuals), S the output sensitivities, made and summed
    a piece at a time (`_pieces`)."""
    models = _models(prob, p[: prob.n_free], 1)
    g, M = np.zeros(prob.n_params), np.zeros((prob.n_params, prob.n_params))
    for r, x, e in zip(prob.records, xs, res):
        e, cols = e / np.sqrt(R[r.channels]), prob.columns(r)
        gr, Mr = np.zeros(len(cols)), np.zeros((len(cols), len(cols)))
        for channels, params, pieces in _sensitivity_parts(
            prob, r, models[r.dt], x, r.measured, _scale(r, R), PIECE
        ):
            ep, gp, Mp = e[:, channels], np.zeros(len(params)), np.zeros((len(params), len(params)))
            for samples, S in pieces:
                S = S.reshape(-1, len(params))  # weighted: R^-½ S, channel by channel
                gp += S.T @ ep[samples].T.ravel()
                Mp += S.T @ S  # numpy's matmul takes Sᵀ S as one symmetric update
            gr[params] += gp
            Mr[np.ix_(params, params)] += Mp
        g[cols] += gr
        M[np.ix_(cols, cols)] += Mr
    return g, M


def segmented(prob: Problem, count: int, least: int) -> Problem:
    """`prob` with each record cut into `count` consecutive segments of (nearly) equal length,
    each a record of its own with its own initial state: output error on segments, the multiple
    shooting of boundary-value problems with the continuity between segments relaxed.

    A segment has at least `least` samples (a shorter record keeps fewer segments, at least one).
    Over a segment of length T a model's error grows by at most e^(aT) for its least stable
    rate a, where over the whole record it grows by e^(a·T_record): short segments keep the cost
    of an unstable or poor model's error bounded. The unmeasured components of each segment's
    initial state stay at trim, as for a whole record.
    """
    records, offset = [], prob.n_free
    for r in prob.records:
        n = len(r.y)
        pieces = max(1, min(count, n // max(least, 1)))
        edges = np.linspace(0, n, pieces + 1).round().astype(int)
        for j, (a, b) in enumerate(zip(edges[:-1], edges[1:])):
            name = r.name if pieces == 1 else f"{r.name}[{j}]"
            records.append(Record(name, r.y[a:b], r.inputs[a:b], r.measured, r.channels, r.dt, offset))
            offset += len(r.measured)
    return replace(prob, records=tuple(records))


def _eliminate(M: np.ndarray, nf: int, rhs: np.ndarray) -> np.ndarray:
    """`M_xx⁻¹ rhs`, x the parameters after the first `nf` (the initial states), with M_xx
    scaled to a unit diagonal first: an unstable model's initial-state sensitivities grow along
    the record, so M_xx spans many decades."""
    Mxx = M[nf:, nf:]
    D = np.sqrt(np.maximum(np.diag(Mxx), 0.0))
    D = np.where(D > 0, D, 1.0)
    return np.linalg.lstsq(Mxx / np.outer(D, D), rhs / D[:, None], rcond=None)[0] / D[:, None]


def reduced(M: np.ndarray, g: np.ndarray, nf: int) -> tuple[np.ndarray, np.ndarray]:
    """The normal equations of the first `nf` parameters with the others (the initial states)
    solved for: the Schur complement `F = M_θθ − M_θx M_xx⁻¹ M_xθ` and `g_θ − M_θx M_xx⁻¹ g_x`,
    the Gauss-Newton model of the cost as a function of θ alone (variable projection)."""
    if len(M) > nf:
        K = _eliminate(M, nf, np.column_stack([M[nf:, :nf], g[nf:]]))
        F, gr = M[:nf, :nf] - M[:nf, nf:] @ K[:, :nf], g[:nf] - M[:nf, nf:] @ K[:, nf]
    else:
        F, gr = M[:nf, :nf].copy(), g[:nf].copy()
    return (F + F.T) / 2, gr


def fit_initial_states(
    prob: Problem, values: np.ndarray, R: np.ndarray | None = None, full: bool = False
) -> tuple[np.ndarray, list[np.ndarray]]:
    """The parameter vector at the free `values` with the best-fitting initial states, and the
    model outputs there (`full`: the whole states, (N, 10) per record).

    The outputs are linear in x0 (`y = y_forced + G x0`, G = CΦᵏ), so x0 is a weighted linear
    least-squares solution; when R is not given, R from the data's spread, then R and x0 in turn
    towards their joint fixed point, where x0 and R maximise the likelihood for these
    coefficients. Each channel c is reduced once, in one pass, to the triangular factor of
    `[G_c  y_c − y_c,forced]` (QR, a piece at a time): for any weights the least-squares problem
    is then k small triangular blocks, solved without squaring its condition number, which an
    unstable model's G makes large (its free response grows along the record). A model whose
    responses are not finite gets the first measured samples. Real values only: this solve is
    not complex-step safe.
    """
    models = _models(prob, values, 0)
    p = np.concatenate([values, np.zeros(prob.n_params - prob.n_free)])
    factors = []  # per record: (k, k + 1, k + 1) upper-triangular factors of [G_c v_c], channel c
    for r in prob.records:
        d, k = models[r.dt], len(r.measured)
        T = np.zeros((k, k + 1, k + 1))
        u1 = np.column_stack([r.inputs, np.ones(len(r.y))])  # [δ; 1]: [Γ s] u1 forces column 0
        Phi, forcing = d.E[:, :NX], d.E[:, NX:]
        # columns: 0 the forced response, 1 + i the response to x0's i-th measured component;
        # each part of the model that evolves on its own (`_uncoupled`) is propagated alone
        acts = np.column_stack([forcing.any(axis=1), np.eye(NX, dtype=bool)[:, r.measured]])
        finite = True
        for states, params, channels in _uncoupled(Phi != 0, acts, r.measured):
            params = np.union1d([0], params)  # a part the inputs do not force has a zero column 0
            at = np.full(NX, -1)
            at[states] = np.arange(len(states))
            x0 = params[1:] - 1  # the x0 components of this part, indexes into r.measured
            X = np.zeros((len(states), len(params)))
            X[at[r.measured[x0]], 1 + np.arange(len(x0))] = 1.0
            rows = at[r.measured[channels]]
            cols = np.r_[x0, k]  # where [G v] of this part's channels sit in [G_c v_c]
            for samples, Y in _pieces(
                Phi[np.ix_(states, states)], forcing[states], u1, X, rows, np.ones(len(rows)), PIECE
            ):
                block = np.zeros((len(channels), len(samples) + k + 1, k + 1))
                block[:, : k + 1] = T[channels]
                with np.errstate(over="ignore", invalid="ignore"):
                    block[:, k + 1 :, cols] = np.concatenate(
                        [Y[:, :, 1:], (r.y[np.ix_(samples, channels)].T - Y[:, :, 0])[:, :, None]], axis=2
                    )
                if not np.all(np.isfinite(block)):
                    finite = False
                    break
                T[channels] = np.linalg.qr(block, mode="r")[:, : k + 1]
            if not finite:
                break
        factors.append(T if finite else None)

    def solve(variance) -> list[np.ndarray]:
        """x0 per record for channel variances `variance(record)` (stored in `p`), and the
        residual sums of squares there: min Σ_c ‖(G_c x − v_c)‖²/R_c = Σ_c ‖U_c x − z_c‖²/R_c + ρ_c²/R_c
        with [U_c z_c; 0 ρ_c] channel c's factor."""
        sums = []
        for r, T in zip(prob.records, factors):
            k = len(r.measured)
            if T is None:
                p[r.offset : r.offset + k] = r.y[0]
                sums.append(np.full(k, np.inf))
                continue
            w = variance(r) ** -0.5
            A, z = (T[:, :k, :k] * w[:, None, None]).reshape(-1, k), (T[:, :k, k] * w[:, None]).ravel()
            D = np.linalg.norm(A, axis=0)  # columns scaled to unit length: x0's units do not count
            D = np.where(D > 0, D, 1.0)
            x0 = np.linalg.lstsq(A / D, z, rcond=None)[0] / D
            p[r.offset : r.offset + k] = x0
            sums.append(np.sum((T[:, :k, :k] @ x0 - T[:, :k, k]) ** 2, axis=1) + T[:, k, k] ** 2)
        return sums

    if R is None:
        R = _pooled_variance(prob, solve(lambda r: (np.std(r.y, axis=0) + 1e-12) ** 2))
        for _ in range(RELAXATIONS):
            new = _pooled_variance(prob, solve(lambda r: R[r.channels]))
            settled = np.all(np.abs(new - R) <= 1e-12 * R)
            R = new
            if settled:
                break
    else:
        solve(lambda r: R[r.channels])
    xs = [_states(r, models[r.dt], prob.x0(r, p)) for r in prob.records]
    return p, xs if full else [x[:, r.measured] for r, x in zip(prob.records, xs)]


def initial_states(prob: Problem, values: np.ndarray, R: np.ndarray | None = None) -> np.ndarray:
    """The parameter vector at the free `values` with the best-fitting initial states."""
    return fit_initial_states(prob, values, R)[0]


# --- uncertainty --------------------------------------------------------------------------------


class Bounds(NamedTuple):
    """The Cramér-Rao bounds of a Fisher information matrix (see `crlb`)."""

    covariance: np.ndarray  # (n, n) a generalised inverse of M: M⁻¹ where M is regular
    std: np.ndarray  # (n,) √(M⁻¹)_ii; inf for an unidentifiable parameter
    correlation: np.ndarray  # (n, n) cov_ij / (σ_i σ_j); NaN in an unidentifiable one's row and column


NULL = 1e-12  # eigenvalue of the scaled Fisher matrix, relative to its largest, that counts as 0


def crlb(M: np.ndarray) -> Bounds:
    """Cramér-Rao bounds of the Fisher information `M`: covariance, standard deviations and
    correlations, with one rule for a singular or nearly singular M.

    M is scaled to unit diagonal (`Mₛ = D⁻¹ M D⁻¹`, D = √diag M, so the rule does not depend on
    the parameters' units) and Mₛ = V Λ Vᵀ; eigenvalues at or below `NULL` × the largest are null
    directions. `covariance = D⁻¹ V₊ Λ₊⁻¹ V₊ᵀ D⁻¹` over the other eigenvalues, a generalised
    inverse of M. A parameter whose unit vector lies in the range of M has the bound
    `σ_i² = (M⁻)_ii`, the same for every generalised inverse; one with a component above √NULL
    along the null directions (or no information at all, M_ii = 0) is unidentifiable: no unbiased
    estimator has a finite variance, so σ_i = inf (a truncated pseudo-inverse would report a
    small, wrong bound) and its correlations are NaN.
    """
    M = (M + M.T) / 2
    D = np.sqrt(np.maximum(np.diag(M), 0.0))
    informed = D > 0
    D = np.where(informed, D, 1.0)
    lam, V = np.linalg.eigh(M / np.outer(D, D))
    null = lam <= NULL * max(lam.max(initial=0.0), 1e-300)
    cov = (V[:, ~null] / lam[~null]) @ V[:, ~null].T / np.outer(D, D)
    unidentifiable = ~informed | (np.linalg.norm(V[:, null], axis=1) > np.sqrt(NULL))
    std = np.where(unidentifiable, np.inf, np.sqrt(np.maximum(np.diag(cov), 0.0)))
    s = np.where(unidentifiable, np.nan, std)
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(s, s)
    corr[np.diag_indices_from(corr)] = np.where(unidentifiable, np.nan, 1.0)
    return Bounds(cov, std, corr)


MIN_LAGS = 10  # the lag window's floor (`_lag_window`), samples
INTEGRATED_TIMES = 6  # the lag window's length in integrated autocorrelation times (`_lag_window`)


def _fft_length(n: int) -> int:
    """The least 2^a 3^b 5^c ≥ n: an FFT length numpy's pocketfft transforms fast."""
    best = 1 << max(n - 1, 0).bit_length()
    p5 = 1
    while p5 < best:
        p35 = p5
        while p35 < best:
            m = p35 * (1 << max((n - 1) // p35, 0).bit_length()) if p35 < n else p35
            best = min(best, m)
            p35 *= 3
        p5 *= 5
    return best


def _lag_window(rho: np.ndarray, n: int) -> int:
    """K, the lags the residual autocorrelation is kept to in `colored_covariance`.

    `rho`: (lags 1 … n/4, k) each channel's residual autocorrelation coefficient ρ(τ) =
    r_cc(τ)/r_cc(0), `n` the record's samples. K covers, in every channel, both
    - twice the last lag at which ρ is significant, so that the Bartlett taper still weighs it by
      ½ or more: outside ±z·√((1 + 2 Σ_j<τ ρ(j)²)/n), Bartlett's band for a correlation that has
      ended before τ, z for 99 % over all those lags and channels at once (Bonferroni) — an
      oscillating or late correlation;
    - c = `INTEGRATED_TIMES` integrated autocorrelation times, the first M ≥ c (1 + 2 Σ_τ≤M ρ(τ))
      (Sokal's automatic window) — a slowly decaying correlation, whose tail stays inside the
      band but adds up (AR(1): τ_int = (1+ρ)/(1−ρ));
    at least `MIN_LAGS`, at most n/2. White residuals keep the floor: K/N small, so the window
    adds little sampling noise to the bound.
    """
    if not rho.size:  # a record of under 4 samples: no lag to test
        return min(MIN_LAGS, n // 2)
    # Bartlett's variance of ρ(τ) beyond the correlation: (1 + 2 Σ_j<τ ρ(j)²)/n
    var = (1.0 + 2.0 * (np.cumsum(rho**2, axis=0) - rho**2)) / n
    z = NormalDist().inv_cdf(1.0 - 0.005 / rho.size)
    outside = np.flatnonzero(np.any(rho**2 > z**2 * var, axis=1))
    last = outside[-1] + 1 if len(outside) else 0
    # M ≥ c τ_int(M), τ_int(M) = 1 + 2 Σ_τ≤M ρ(τ): the first such M in the slowest channel (none: n)
    reached = np.arange(1, len(rho) + 1)[:, None] >= INTEGRATED_TIMES * (1.0 + 2.0 * np.cumsum(rho, axis=0))
    sokal = np.max(np.argmax(reached, axis=0)) + 1 if np.all(np.any(reached, axis=0)) else n
    return int(min(max(2 * last, sokal, MIN_LAGS), n // 2))


def colored_covariance(
    prob: Problem,
    p: np.ndarray,
    xs: Sequence[np.ndarray],
    res: Sequence[np.ndarray],
    R: np.ndarray,
    cov: np.ndarray,
) -> np.ndarray:
    """Morelli & Klein's covariance of the free coefficients for colored residuals,

        C (Σ_i Σ_j S(i)ᵀR⁻¹ R_vv(i−j) R⁻¹S(j)) Cᵀ,   R_vv(τ) = w(τ) 1/N Σ_m v(m) v(m+τ)ᵀ,

    per experiment, with C = `cov[:n_free]` (cov = M⁻¹, the bound for white residuals), S the
    output sensitivities, v the residuals (`xs`: the states at `p`, `res`: the residuals) and
    w(τ) = 1 − |τ|/(K+1) for |τ| ≤ K, 0 beyond: the Bartlett lag window, K from `_lag_window`.

    The window is what makes the bound agree with M⁻¹ for white residuals. Over all lags the
    sample autocorrelation's spectrum is the periodogram |V(f)|²/N, and the fit's normal equations
    `Σ_m S(m)ᵀR⁻¹v(m) = Σ_f S(f)ᴴR⁻¹V(f) = 0` leave it with holes exactly where the sensitivities'
    spectra lie, so the all-lag sum reads low (down to 0.8 of M⁻¹'s σ on 60 s records); the long-lag
    estimates carry only that bias and sampling noise. The Bartlett window smooths the periodogram
    over a band ~1/K wide (a convolution with the Fejér kernel), filling the holes from the
    neighbouring frequencies, and keeps the estimate positive semidefinite. Its lag-0 term alone
    is M; white residuals add lag terms of relative size √(K/N).

    Computed per frequency of an L-point DFT grid, L ≥ N + K (no wrap-around): with
    Φ(f) = Σ_|τ|≤K R_vv(τ) e^{+iωτ} (K lags summed directly) and Z = R^-½ S Cᵀ (the sensitivities
    already projected by C: n_free columns, not n_params) the double sum is
    `1/L Σ_f Z(f)ᴴ Φ(f) Z(f)`.
    """
    models, nf = _models(prob, p[: prob.n_free], 1), prob.n_free
    out = np.zeros((nf, nf))
    # R^-½ S Cᵀ, time first; one buffer for all records (fresh pages are dear)
    Z = np.empty((max(len(r.y) for r in prob.records), max(len(r.measured) for r in prob.records), nf))
    for r, x, e in zip(prob.records, xs, res):
        n, k, C = len(e), len(r.measured), cov[:nf, prob.columns(r)].T
        Zr = Z[:n, :k]
        Zr[...] = 0.0
        for channels, params, pieces in _sensitivity_parts(
            prob, r, models[r.dt], x, r.measured, _scale(r, R), PIECE
        ):
            for samples, S in pieces:
                Zr[np.ix_(np.arange(n)[samples], channels)] = (S @ C[params]).transpose(1, 0, 2)
        v = e / np.sqrt(R[r.channels])  # R^-½ v
        # per channel Σ_m v(m) v(m+τ), τ = 0 … n/4 (an FFT grid with no wrap-around at those lags)
        V = np.fft.rfft(v, _fft_length(n + n // 4 + 2), axis=0)
        auto = np.fft.irfft(V.real**2 + V.imag**2, axis=0)[: n // 4 + 2]
        K = _lag_window(auto[1 : n // 4 + 1] / np.maximum(auto[0], 1e-300), n)
        L = _fft_length(n + K + 1)  # lags up to K without wrap-around
        # G(τ) = w(τ) R_vv(τ), 0 < τ ≤ K
        G = np.empty((K, k * k))
        for tau in range(1, K + 1):
            G[tau - 1] = ((1.0 - tau / (K + 1)) / n * (v[: n - tau].T @ v[tau:])).ravel()
        # Φ(f) = R_vv(0) + Σ_τ>0 (G(τ) e^{+iωτ} + G(τ)ᵀ e^{−iωτ}) (as R_vv(−τ) = R_vv(τ)ᵀ)
        #      = R_vv(0) + Gc + Gcᵀ + i (Gs − Gsᵀ), Gc = Σ_τ G(τ) cos ωτ, Gs = Σ_τ G(τ) sin ωτ
        omega_tau = 2 * np.pi / L * np.outer(np.arange(L // 2 + 1), np.arange(1, K + 1))
        Gc, Gs = (np.cos(omega_tau) @ G).reshape(-1, k, k), (np.sin(omega_tau) @ G).reshape(-1, k, k)
        Phi = np.empty(Gc.shape, complex)
        np.add(Gc, Gc.transpose(0, 2, 1), out=Phi.real)
        Phi.real += v.T @ v / n
        np.subtract(Gs, Gs.transpose(0, 2, 1), out=Phi.imag)
        Zf = np.fft.rfft(Zr, L, axis=0)  # (frequencies, k, n_free)
        PhiZ = Phi @ Zf
        Zf[0] *= 0.5  # DC and Nyquist appear once in the full spectrum, the others twice
        if L % 2 == 0:
            Zf[-1] *= 0.5
        # 1/L Σ_f Z(f)ᴴ Φ(f) Z(f), real part: Re(aᴴb) = aᵣᵀbᵣ + aᵢᵀbᵢ, one real product of the
        # arrays viewed as (re, im) pairs
        RI = np.ascontiguousarray(Zf).reshape(-1, nf).view(float).T @ PhiZ.reshape(-1, nf).view(float)
        out += (RI[0::2, 0::2] + RI[1::2, 1::2]) * (2.0 / L)
    return out


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


def assess(
    prob: Problem, p: np.ndarray, M: np.ndarray | None = None, R: np.ndarray | None = None
) -> Information:
    """Fisher information, Cramér-Rao bounds and the colored-residual bound at `p`.

    `M`: `gauss_newton_terms(prob, p, …, R)[1]` with R the residual variance at `p`, if an
    optimiser already has it (not checked: the caller vouches that it belongs to `p`). `R`: the
    noise variance per channel to use instead of the residual variance at `p`.
    """
    xs = states(prob, p)
    res = [r.y - x[:, r.measured] for r, x in zip(prob.records, xs)]
    R = noise_variance(prob, res) if R is None else R
    if M is None:
        M = gauss_newton_terms(prob, p, xs, res, R)[1]
    nf = prob.n_free
    # the bounds of θ from its information with the initial states eliminated, which stays well
    # conditioned where M itself does not (an unstable model's); the colored bound needs the θ
    # rows of M⁻¹ too: [F⁻¹, −F⁻¹ M_θx M_xx⁻¹] (the inverse of a 2 × 2 block matrix)
    F = reduced(M, np.zeros(len(M)), nf)[0]
    cov, std, corr = crlb(F)
    rows = np.hstack([cov, -cov @ _eliminate(M, nf, M[nf:, :nf]).T]) if len(M) > nf else cov
    corrected = colored_covariance(prob, p, xs, res, R, rows)
    x0 = {}
    for r in prob.records:
        xr = prob.x0(r, p) + np.eye(NX)[IX["u"]] * prob.speed
        x0[r.name] = {STATES[i]: float(xr[i]) for i in r.measured}
    return Information(
        prob.free,
        p[:nf].copy(),
        F,
        std,
        corr,
        np.where(np.isinf(std), np.inf, np.sqrt(np.maximum(np.diag(corrected), 0.0))),
        dict(zip(prob.channels, map(float, np.sqrt(R)))),
        x0,
        negative_log_likelihood(prob, res),
        p.copy(),
    )


def _values(prob: Problem, values) -> np.ndarray:
    if values is None:
        return prob.start
    if isinstance(values, Mapping):
        unknown = set(values) - set(prob.free)
        if unknown:
            raise InputError(
                f"values: {sorted(unknown)[0]!r} is not a free coefficient; "
                f"expected one of {', '.join(prob.free)}"
            )
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
    A = continuous(prob.structure, prob.coefficients(p[: prob.n_free]))[0]
    ev = np.linalg.eigvals(A)
    worst = ev[np.argmax(ev.real)]
    return f"{why}; A's largest eigenvalue real part is {worst.real:.3g} 1/s"


def information(
    experiments: Sequence[Experiment],
    config: ModelConfig,
    values: Mapping[str, float] | np.ndarray | None = None,
    noise_std: Mapping[str, float] | None = None,
) -> Information:
    """Cramér-Rao analysis of `config.free` at `values` (default: the config's coefficients).

    The initial states are fitted (linear least squares); R is `noise_std`² where given (per
    channel), else the residual variance there, which also holds the model's error at `values`.
    A model that diverges on the data has no meaningful bound: InputError.
    """
    prob, p, R = _analysed(experiments, config, values, noise_std)
    return assess(prob, p, R=R)


def fisher(
    experiments: Sequence[Experiment],
    config: ModelConfig,
    values: Mapping[str, float] | np.ndarray | None = None,
    noise_std: Mapping[str, float] | None = None,
) -> np.ndarray:
    """`information(...).fisher` alone: the Fisher information of `config.free` (n_free, n_free),
    the initial states eliminated, without the bounds (no colored-residual analysis)."""
    prob, p, R = _analysed(experiments, config, values, noise_std)
    xs = states(prob, p)
    res = [r.y - x[:, r.measured] for r, x in zip(prob.records, xs)]
    M = gauss_newton_terms(prob, p, xs, res, noise_variance(prob, res) if R is None else R)[1]
    return reduced(M, np.zeros(len(M)), prob.n_free)[0]


def _analysed(experiments, config, values, noise_std) -> tuple[Problem, np.ndarray, np.ndarray | None]:
    """The problem, the parameter vector at `values` with the best-fitting initial states and R
    from `noise_std` (None without) for `information` and `fisher`; InputError where the model
    diverges on the data: it has no meaningful bound."""
    prob = problem(experiments, config)
    with np.errstate(over="ignore", invalid="ignore"):
        p = initial_states(prob, _values(prob, values))
    why = divergence(prob, p)
    if why is not None:
        raise InputError(
            f"{prob.source}: the model diverges at these coefficients ({why}); "
            "expected coefficients giving a bounded response"
        )
    return prob, p, None if noise_std is None else np.array([noise_std[c] ** 2 for c in prob.channels])


def predict(
    experiments: Sequence[Experiment],
    config: ModelConfig,
    initial: Mapping[str, Mapping[str, float]] | None = None,
) -> list[np.ndarray]:
    """Model outputs (N, k) per experiment in its measured columns, absolute u, for plots.

    `initial`: experiment → state → x0 (absolute u, as in `Estimate.initial_states`);
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


def synthetic(
    config: ModelConfig,
    t: np.ndarray,
    inputs: np.ndarray,
    noise_std: Mapping[str, float] | None = None,
    measured: Sequence[str] = STATES,
    rng: np.random.Generator | None = None,
    x0: np.ndarray | None = None,
    name: str = "synthetic",
) -> Experiment:
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


def equation_error(
    experiments: Sequence[Experiment], config: ModelConfig, window_s: float = 0.5
) -> ModelConfig:
    """`config` with the free coefficients from a least-squares fit of the linear model's rows.

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
    intervals = []  # per record: (ẋ, x, δ) over its sample intervals, or None if too short to smooth
    for r in prob.records:
        n = len(r.y)
        win = min(max(5, int(round(window_s / r.dt)) | 1), n - (1 - n % 2))
        if win <= 3:
            intervals.append(None)
            continue
        # only intervals whose smoothing window lies within the record: the ends would be
        # extrapolated
        xs = np.zeros((n - win + 1, NX))
        xs[:, r.measured] = _smoothed(r.y, win)
        us = _smoothed(r.inputs, win)
        # over each sample interval the input is held: the row equation averaged over it
        # has ẋ = Δx/Δt, x at the midpoint and δ exactly, with no derivative across a step;
        # the same (linear) smoothing of states and inputs keeps that equation consistent
        intervals.append((np.diff(xs, axis=0) / r.dt, (xs[1:] + xs[:-1]) / 2, us[:-1]))
    for row in range(6):  # u v w p q r
        cols = [
            j
            for j, i in enumerate(prob.index)
            if s.dMt[i, row].any() or s.dAt[i, row].any() or s.dBt[i, row].any()
        ]
        if not cols:
            continue
        idx = prob.index[cols]
        involved = (
            (Mf[row] != 0) | (Af[row] != 0) | (s.dMt[idx, row] != 0).any(0) | (s.dAt[idx, row] != 0).any(0)
        )
        involved[row] = True
        X, Y = [], []
        for r, record in zip(prob.records, intervals):
            if record is None or not set(np.flatnonzero(involved)) <= set(r.measured):
                continue
            xdot, x, u = record
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


def _smoothed(y: np.ndarray, win: int) -> np.ndarray:
    """Savitzky-Golay smoothing of `y` (N, k), cubic, over `win` (odd) samples: at each sample
    whose window lies within the record (N − win + 1 of them), the value there of the cubic
    fitted to the window by least squares, a fixed weighted sum of the window."""
    h = win // 2
    # the fitted cubic's value at the window's centre: the first row of the Vandermonde pseudo-inverse
    c = np.linalg.pinv(np.vander(np.arange(-h, h + 1.0), 4, increasing=True))[0]
    n = len(y) - 2 * h
    return sum(c[o] * y[o : o + n] for o in range(win))
