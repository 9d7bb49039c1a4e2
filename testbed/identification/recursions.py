"""The linear model as the output-error fit simulates it: the exact zero-order-hold
discretisation `x[k+1] = Φ x[k] + Γ δ[k] + s`, written `x[k+1] = E w[k]` with `E = [Φ Γ s]` and
`w[k] = [x[k]; δ[k]; 1]`, its states from each experiment's initial state, and their exact
sensitivities.

`∂E/∂θ_i` and `∂²E/∂θ_i∂θ_j` come from the exponential of block-triangular augmented matrices
(the discrete counterpart of the paper's Eq. 3), and the sensitivities are propagated by the
recursions obtained by differentiating `x[k+1] = E w[k]` (`testbed.identification.scan`),
separately for each part of the model that evolves on its own (`uncoupled`: a torpedo's lateral
and longitudinal motions are uncoupled in the linear model, a quarter of the arithmetic).
"""

from __future__ import annotations

import contextlib
import contextvars
from dataclasses import dataclass
from typing import Iterator, Sequence

import numpy as np

from testbed.identification import scan
from testbed.identification.problem import Problem, Record
from testbed.models import log_mounting
from testbed.models.linear import (
    IBIAS,
    ICURRENT,
    IDELAY,
    IMOUNTING,
    IX,
    NU,
    NX,
    continuous,
    derivatives,
    discretize,
    expm_pair,
    tilde,
)

__all__ = [
    "NW",
    "Discrete",
    "channel_weights",
    "counting",
    "curvature",
    "discrete",
    "discrete_models",
    "simulated_outputs",
    "residuals",
    "sensitivities",
    "sensitivity_parts",
    "simulated",
    "states",
    "trajectory",
    "uncoupled",
]

NW = NX + NU + 1  # length of w = [x; δ; 1]

_COUNTERS = contextvars.ContextVar("counters", default=())  # the open `counting` blocks' tallies


@contextlib.contextmanager
def counting() -> Iterator[list[int]]:
    """Within this context the model's simulations are tallied: yields a one-item list that
    holds the samples simulated so far, a sample of a state trajectory counting 1 and one of a
    sensitivity pass 1 + n_free (the states and their derivative columns). An estimator's
    evaluations are that tally over its data's samples. Blocks nest: each counts everything
    simulated inside it."""
    tally = [0]
    token = _COUNTERS.set(_COUNTERS.get() + (tally,))
    try:
        yield tally
    finally:
        _COUNTERS.reset(token)


def simulated(samples: int) -> None:
    """Add `samples` simulated samples (trajectory samples × columns) to every open `counting` block."""
    for tally in _COUNTERS.get():
        tally[0] += samples


@dataclass(frozen=True)
class Discrete:
    """`E = [Φ Γ s]` (10, 14) and its derivatives w.r.t. the free coefficients."""

    E: np.ndarray
    dE: np.ndarray | None = None  # (n_free, 10, 14)
    d2E: np.ndarray | None = None  # (n_free, n_free, 10, 14)


def discrete(
    prob: Problem, values: np.ndarray, dt: float, order: int = 0, group: int | None = None
) -> Discrete:
    """The ZOH model at the free `values` and its first (`order` ≥ 1) and second derivatives,
    for the records of `group` (their own per-record values; the others' derivatives are zero).

    With `F(θ)` the augmented matrix [[A, B, S], [0, 0, 0]], `E = exp(F Δ)`; its derivatives are
    the top-right blocks of the exponentials of block-triangular matrices (Van Loan /
    Najfeld-Havel, `expm_pair`), all at once, with
    `∂²[A B S]/∂θ_i∂θ_j = −Mt⁻¹(∂Mt_i ∂[A B S]_j + ∂Mt_j ∂[A B S]_i)` (Mt, At affine in θ).
    """
    s, theta = prob.structure, prob.coefficients(values, group)
    A, B, S = continuous(s, theta)
    if order == 0 or prob.n_free == 0:
        return Discrete(np.column_stack(discretize(A, B, S, dt)))
    nf, acting = prob.n_free, prob.acting(-1 if group is None else group)
    dA, dB, dS = derivatives(s, theta, A, B, S, prob.index)
    dABS = np.concatenate([dA, dB, dS[:, :, None]], axis=2)  # (nf, 10, 14)
    dABS[~acting] = 0.0  # another record's own values do not move this one's model
    ABS = np.column_stack([A, B, S])
    if order == 1:
        E, dE = expm_pair(ABS, dABS.transpose(1, 0, 2), dt)
        return Discrete(E, dE.transpose(1, 0, 2))
    Mt = tilde(s, theta)[0]
    G = np.einsum("iab,jbc->ijac", s.dMt[prob.index] * acting[:, None, None], dABS)
    iu, ju = np.triu_indices(nf)
    d2ABS = -np.linalg.solve(Mt[None], (G + G.transpose(1, 0, 2, 3))[iu, ju])  # (pairs, 10, 14)
    E, dE, block = expm_pair(ABS, dABS.transpose(1, 0, 2), dt, (d2ABS, iu, ju))
    d2E = np.zeros((nf, nf, NX, NW), dtype=E.dtype)
    d2E[iu, ju] = block
    d2E[ju, iu] = block
    return Discrete(E, dE.transpose(1, 0, 2), d2E)


def discrete_models(prob: Problem, values: np.ndarray, order: int) -> dict:
    """`discrete` at the free `values` for each model the records need (`Problem.key`: each
    sampling interval, and each record group where some free values are per record)."""
    keys = {prob.key(r): r for r in prob.records}
    return {key: discrete(prob, values, r.dt, order, r.group) for key, r in keys.items()}


def trajectory(d: Discrete, x0: np.ndarray, inputs: np.ndarray) -> np.ndarray:
    """State trajectory (N, 10) of one record from the full initial state `x0` driven by its
    `inputs` (N, 3) (`Problem.inputs`)."""
    return scan.propagate(d.E[:, :NX], x0, inputs[:-1] @ d.E[:, NX : NX + NU].T + d.E[:, -1])


def _w(x: np.ndarray, inputs: np.ndarray) -> np.ndarray:
    """`w[k] = [x[k]; δ[k]; 1]` (N, 14)."""
    return np.column_stack([x, inputs.astype(x.dtype), np.ones(len(x), dtype=x.dtype)])


def states(prob: Problem, p: np.ndarray) -> list[np.ndarray]:
    """Simulated states (N, 10) per experiment at the parameter vector `p` (u as a perturbation)."""
    models = discrete_models(prob, p[: prob.n_free], 0)
    simulated(prob.n_samples)
    values = p[: prob.n_free]
    return [trajectory(models[prob.key(r)], prob.x0(r, p), prob.inputs(r, values)) for r in prob.records]


def simulated_outputs(prob: Problem, p: np.ndarray) -> list[np.ndarray]:
    """Model outputs (N, k) per experiment at the parameter vector `p` (u as a perturbation)."""
    return [prob.outputs(r, x, p[: prob.n_free]) for r, x in zip(prob.records, states(prob, p))]


def residuals(prob: Problem, p: np.ndarray) -> list[np.ndarray]:
    """Measured minus model outputs (N, k) per experiment."""
    return [r.residual(yhat) for r, yhat in zip(prob.records, simulated_outputs(prob, p))]


def sensitivity_parts(
    prob: Problem,
    record: Record,
    d: Discrete,
    x: np.ndarray,
    rows,
    scale: np.ndarray,
    size: int,
    present: np.ndarray | None = None,
    *,
    values: np.ndarray,
    biases: bool = True,
) -> Iterator[tuple[np.ndarray, np.ndarray, Iterator]]:
    """`scale[c] ∂y_rows[c][k]/∂p` of one record, p its own parameters (q = n_free + k), from its
    states `x` (N, 10), for each `uncoupled` part of the model: (channels, params, pieces), the
    pieces as in `scan.pieces` with (len(channels), T, len(params)) arrays; `channels` index `rows`,
    `params` p. Sensitivities across the parts are zero and not given; `present` (N, len(rows)):
    the samples there are, the others' sensitivities given as 0 (they are left out of the fit).
    `y` is the state plus its output terms where `biases`, else the state itself; `values`: the
    free values (the inputs' delay among them).

    ∂x[k+1]/∂θ_i = Φ ∂x[k]/∂θ_i + ∂E/∂θ_i w[k] (∂x[0]/∂θ = 0); ∂x[k]/∂x0 = Φᵏ; ∂y_c/∂b_c = 1;
    for the input delay τ the forcing is Γ ∂δ[k]/∂τ. A `mounted` velocity log's outputs mix the
    states: `_read_parts`.
    """
    nf, rows = prob.n_free, np.asarray(rows)
    if biases and prob.mounted and np.any(rows < 3):
        yield from _read_parts(prob, record, d, x, rows, scale, size, present, values)
        return
    dtype = np.result_type(x, d.E)  # complex under the complex-step tests
    w, Phi = _w(x, prob.inputs(record, values)), d.E[:, :NX]
    dE = d.dE if nf else np.zeros((0, NX, NW), dtype=dtype)
    delay = np.flatnonzero((prob.index == IDELAY) & prob.acting(record.group))
    if len(delay):
        # ∂x[k+1]/∂τ = Φ ∂x[k]/∂τ + Γ ∂δ[k]/∂τ: w carries ∂δ/∂τ, the delay's ∂E row picks it by Γ
        w = np.column_stack([w, prob.input_rates(record, values).astype(w.dtype)])
        dE = np.concatenate([dE, np.zeros((nf, NX, NU), dtype=dE.dtype)], axis=2)
        dE[delay[0], :, NW:] = d.E[:, NX : NX + NU]
    # the free output terms acting on this record (`Problem.output_terms`), each on its outputs:
    # free value i → {state: its regressor, the output's derivative}
    terms = _output_terms(prob, record) if biases else {}
    acts = np.column_stack([dE.any(axis=2).T, np.eye(NX, dtype=bool)[:, record.measured]])
    for i, regressors in terms.items():
        acts[list(regressors), i] = True
    for states, params, channels in uncoupled(Phi != 0, acts, rows):
        at = np.full(NX, -1)
        at[states] = np.arange(len(states))
        theta, x0 = params[params < nf], params[params >= nf]
        X = np.zeros((len(states), len(params)), dtype=dtype)  # the θ columns first
        X[at[record.measured[x0 - nf]], len(theta) + np.arange(len(x0))] = 1.0
        D = dE[theta][:, states, :].transpose(1, 0, 2).reshape(-1, w.shape[1])  # rows: (state, θ)
        pieces = scan.pieces(Phi[np.ix_(states, states)], D, w, X, at[rows[channels]], scale[channels], size)
        # the output terms: no dynamics (their columns of X stay zero), their regressor on their outputs
        direct = [
            (c, j, terms[i][rows[channels][c]])
            for j, i in enumerate(theta)
            if i in terms
            for c in range(len(channels))
            if rows[channels][c] in terms[i]
        ]
        if direct:
            pieces = _direct(pieces, direct, scale[channels])
        yield channels, params, pieces if present is None else _masked(pieces, present[:, channels])


def _read_parts(prob, record, d, x, rows, scale, size, present, values) -> Iterator:
    """`sensitivity_parts` of a record whose velocity log is `mounted`, as one part: the
    states' sensitivities (every state, `_sensitivities`) read through the log,
    ∂y/∂p = C ∂(v; ω)/∂p for u, v, w (`log_mounting.matrix`), the others the states'; and the
    output terms' own, ∂y/∂(mounting) (`log_mounting.mounting_derivatives`), ∂y/∂c = Mᵀ ∂c_b/∂c, ∂y_c/∂b_c = 1."""
    N = len(x)
    S = _sensitivities(prob, record, d, x, np.arange(NX), np.ones(NX), values, biases=False)
    theta = prob.coefficients(values, record.group)
    mounting = theta[IMOUNTING]
    S[:, :3] = np.einsum("cs,nsq->ncq", log_mounting.matrix(mounting), S[:, :6])
    acting = prob.acting(record.group)
    speed = np.array([prob.speed, 0.0, 0.0])
    if np.isin(prob.index[acting], IMOUNTING).any():
        dg = log_mounting.mounting_derivatives(
            mounting, x[:, :3] + speed, x[:, 3:6], prob.current(record, theta)
        )
    for i, k in enumerate(prob.index):
        if not acting[i]:
            continue
        if k in IBIAS:
            S[:, k - IBIAS[0], i] = 1.0
        elif k in IMOUNTING:
            S[:, :3, i] = dg[int(np.flatnonzero(IMOUNTING == k)[0])]
        elif k in ICURRENT:
            unit = np.zeros_like(theta)
            unit[k] = 1.0
            S[:, :3, i] = prob.current(record, unit) @ log_mounting.turned(mounting)
    S = S[:, rows] * np.asarray(scale)[None, :, None]
    if present is not None:
        S = S * present[:, :, None]
    pieces = ((np.arange(a, min(a + size, N)), S[a : a + size].transpose(1, 0, 2)) for a in range(0, N, size))
    yield np.arange(len(rows)), np.arange(S.shape[2]), pieces


def _output_terms(prob: Problem, record: Record) -> dict[int, dict[int, np.ndarray]]:
    """The free output terms acting on `record`, free index → {state: ∂y_state/∂value (N,) or
    a scalar}: a bias 1 on its own output; the current's (c_N, c_E) cos ψ, sin ψ on u and
    −sin ψ, cos ψ on v (`Problem.output_terms`), for the states the record measures."""
    acting, out = prob.acting(record.group), {}
    psi = np.zeros(len(record.y)) if record.heading is None else record.heading
    along = {k: (d[:, 0], d[:, 1]) for k, d in zip(ICURRENT, log_mounting.body_current_derivatives(psi))}
    for i, k in enumerate(prob.index):
        if not acting[i]:
            continue
        if k in IBIAS:
            regressors = {int(k - IBIAS[0]): 1.0}
        elif k in along:
            regressors = dict(zip((IX["u"], IX["v"]), along[k]))
        else:
            continue
        seen = {s: v for s, v in regressors.items() if s in record.measured}
        if seen:
            out[i] = seen
    return out


def _direct(pieces, direct, scale):
    """`pieces` with `S[c, :, j] = scale[c] · regressor` for each (c, j, regressor) in `direct`:
    an output term's sensitivity (its columns of the state's are zero)."""
    for samples, S in pieces:
        for c, j, regressor in direct:
            S[c, :, j] = scale[c] * (regressor[samples] if np.ndim(regressor) else regressor)
        yield samples, S


def _masked(pieces: Iterator, present: np.ndarray) -> Iterator:
    """`pieces` (samples, (channels, T, q) array) with the missing samples' rows zeroed."""
    for samples, S in pieces:
        yield samples, S * present[samples].T[:, :, None]


def uncoupled(coupled: np.ndarray, acts: np.ndarray, rows: np.ndarray):
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


def _sensitivities(
    prob: Problem,
    record: Record,
    d: Discrete,
    x: np.ndarray,
    rows,
    scale: np.ndarray,
    values: np.ndarray,
    biases: bool = True,
) -> np.ndarray:
    """All of `sensitivity_parts` at once: (N, len(rows), q)."""
    S = np.zeros((len(x), len(rows), prob.n_free + len(record.measured)), dtype=np.result_type(x, d.E))
    for channels, params, pieces in sensitivity_parts(
        prob, record, d, x, rows, scale, len(x), biases=biases, values=values
    ):
        for samples, piece in pieces:
            S[np.ix_(samples, channels, params)] = piece.transpose(1, 0, 2)
    return S


def sensitivities(prob: Problem, p: np.ndarray, xs: Sequence[np.ndarray] | None = None) -> list[np.ndarray]:
    """Per experiment: output sensitivities (N, k, q) to the experiment's own parameters
    `p[prob.columns(record)]` (q = n_free + k; the others have no effect). `xs`: the states at
    `p` (`states(prob, p)`) if already known. (The estimators take them in pieces instead.)
    """
    models = discrete_models(prob, p[: prob.n_free], 1)
    xs = states(prob, p) if xs is None else xs
    simulated(prob.n_samples * prob.n_free)
    return [
        _sensitivities(
            prob, r, models[prob.key(r)], x, r.measured, np.ones(len(r.measured)), p[: prob.n_free]
        )
        for r, x in zip(prob.records, xs)
    ]


def channel_weights(record: Record, R: np.ndarray) -> np.ndarray:
    """Per measured channel: 1/√R, which weights the sensitivities."""
    return R[record.channels] ** -0.5


def curvature(prob: Problem, p: np.ndarray, weights: Sequence[np.ndarray]) -> np.ndarray:
    """`Σ_k Σ_c weights[k, c] ∂²y_c[k]/∂p∂p` (n_params, n_params), `weights` (N, k) per experiment.

    The second-order sensitivities of the paper's Eq. 3, discretised exactly, obey
      ∂²x[k+1]/∂p_i∂p_j = Φ ∂²x[k] + ∂Φ_i ∂x[k]/∂p_j + ∂Φ_j ∂x[k]/∂p_i + ∂²E_ij w[k],  ∂²x[0] = 0
    (only coefficients move Φ and E: the initial-state entries of ∂Φ, ∂²E are zero; the input
    delay's forcing Γ ∂δ/∂τ adds ∂Γ_i ∂δ/∂τ to its pairs with θ_i, and Γ ∂²δ/∂τ² to its own). Their
    weighted sum is taken by the adjoint recursion `μ[k] = Cᵀweights[k] + Φᵀ μ[k+1]`:
    `Σ_k aₖᵀ ∂²x[k] = Σ_k μ[k+1]ᵀ (forcing at k)`, exact, with no N·n_params² array. A one-hot
    weight gives the second-order sensitivity of one output sample.
    """
    models = discrete_models(prob, p[: prob.n_free], 2)
    nf, H = prob.n_free, np.zeros((prob.n_params, prob.n_params), dtype=p.dtype)
    simulated(prob.n_samples * (1 + nf))  # the states and their sensitivities, for the adjoint
    for r, wr in zip(prob.records, weights):
        d = models[prob.key(r)]
        inputs = prob.inputs(r, p[:nf])
        x = trajectory(d, prob.x0(r, p), inputs)
        w, q = _w(x, inputs), nf + len(r.measured)
        a = wr @ prob.read_matrix(r, p[:nf])  # the weights on the states: Cᵀ w, C = ∂y/∂x
        Phi = d.E[:, :NX]
        mu = scan.propagate(Phi.T, a[-1], a[-2::-1])[::-1]  # μ[k], k = 0 … N−1
        # H1[i, l] = Σ_k μ[k+1]ᵀ ∂Φ_i ∂x[k]/∂p_l = Σ_ab ∂Φ_i[a, b] W[a, b, l] with
        # W[a, b, l] = Σ_k μ[k+1]_a ∂x_b[k]/∂p_l; only the coefficients move Φ (the rows of H1
        # past n_free are 0)
        mixed = prob.mounted and bool(np.any(r.measured < 3))
        if mixed:  # the reading's own curvature needs the states' sensitivities whole
            X = _sensitivities(prob, r, d, x, np.arange(NX), np.ones(NX), p[:nf], biases=False)
            W = (mu[1:].T @ X[:-1].reshape(len(X) - 1, NX * q)).reshape(NX, NX, q)
        else:
            W = _adjoint_products(prob, r, d, x, mu, p[:nf])
        H1 = np.zeros((q, q), dtype=W.dtype)
        H1[:nf] = d.dE[:, :, :NX].reshape(nf, NX * NX) @ W.reshape(NX * NX, q)
        Hr = H1 + H1.T
        if nf:
            Hr[:nf, :nf] += np.tensordot(d.d2E, mu[1:].T @ w[:-1], axes=([2, 3], [0, 1]))
        for j in np.flatnonzero((prob.index == IDELAY) & prob.acting(r.group)):
            # the delay's forcing Γ ∂δ[k]/∂τ moves with θ_i by ∂Γ_i ∂δ[k]/∂τ, and with τ by Γ ∂²δ[k]/∂τ²
            rates = prob.input_rates(r, p[:nf])
            cross = np.tensordot(d.dE[:, :, NX : NX + NU], mu[1:].T @ rates[:-1], axes=([1, 2], [0, 1]))
            Hr[:nf, j] += cross
            Hr[j, :nf] += cross
            Hr[j, j] += np.sum(d.E[:, NX : NX + NU] * (mu[1:].T @ prob.input_curvatures(r, p[:nf])[:-1]))
        if mixed:
            Hr += _read_curvature(prob, r, x, X, wr, p[:nf])
        cols = prob.columns(r)
        H[np.ix_(cols, cols)] += Hr
    return H


def _adjoint_products(
    prob: Problem, r: Record, d: Discrete, x: np.ndarray, mu: np.ndarray, values
) -> np.ndarray:
    """`W[a, b, l] = Σ_k μ[k+1]_a ∂x_b[k]/∂p_l` (10, 10, q) over k < N − 1, record r's states'
    sensitivities to its own parameters taken a piece at a time (`sensitivity_parts`), never
    held whole: per part and piece one product over its samples, (10, P) (P, channels·params)."""
    q, last = prob.n_free + len(r.measured), len(x) - 1
    W = np.zeros((NX, NX, q), dtype=np.result_type(x, d.E, mu))
    for channels, params, pieces in sensitivity_parts(
        prob, r, d, x, np.arange(NX), np.ones(NX), scan.PIECE, values=values, biases=False
    ):
        at = (slice(None), channels[:, None], params)
        for samples, piece in pieces:
            keep = samples < last  # μ[k+1] exists for k < N − 1
            S = piece[:, keep].transpose(1, 0, 2).reshape(np.count_nonzero(keep), -1)
            W[at] += (mu[samples[keep] + 1].T @ S).reshape(NX, len(channels), len(params))
    return W


def _read_curvature(
    prob: Problem, r: Record, x: np.ndarray, X: np.ndarray, wr: np.ndarray, values
) -> np.ndarray:
    """What a `mounted` velocity log adds to record r's `curvature` (q, q): Σ w ∂²y/∂p∂p of its
    reading y = C(g) (v; ω) + Mᵀ c_b beyond C ∂²x, over the record's own parameters (q = n_free
    + its x0): the mounting g with the states' sensitivities X (N, 10, q), Σ w (∂C/∂g_i) ∂x/∂p_j
    both ways, with itself and with the current (`log_mounting.second_derivatives`,
    `log_mounting.matrix_derivatives`)."""
    theta = prob.coefficients(values, r.group)
    g, acting = theta[IMOUNTING], prob.acting(r.group)
    velocity = r.measured < 3
    wv, read = wr[:, velocity], r.measured[velocity]  # the log's channels and their weights
    speed = np.array([prob.speed, 0.0, 0.0])
    current = prob.current(r, theta)
    H = np.zeros((X.shape[2], X.shape[2]))

    def free(among: np.ndarray) -> list[tuple[int, int]]:
        """(free index, position in `among`) of the free values among `among` acting here."""
        return [
            (i, int(np.flatnonzero(among == k)[0]))
            for i, k in enumerate(prob.index)
            if k in among and acting[i]
        ]

    mounting, currents = free(IMOUNTING), free(ICURRENT)
    dC = log_mounting.matrix_derivatives(g)[:, read]  # (5, channels, 6)
    d2 = log_mounting.second_derivatives(g, x[:, :3] + speed, x[:, 3:6], current)[:, :, :, read]
    dM = log_mounting.turned_derivatives(g)
    for i, s in mounting:
        cross = np.einsum("nc,cs,nsq->q", wv, dC[s], X[:, :6])  # Σ w (∂C/∂g_s) ∂x/∂p
        H[i] += cross
        H[:, i] += cross
        for j, t in mounting:
            H[i, j] += np.sum(wv * d2[s, t])
        if s < 2:  # a turn moves the current's reading: ∂²(Mᵀ c_b)/∂m ∂c = (∂c_b/∂c) ∂M/∂m
            for j, c in currents:
                unit = np.zeros_like(theta)
                unit[ICURRENT[c]] = 1.0
                term = np.sum(wv * (prob.current(r, unit) @ dM[s])[:, read])
                H[i, j] += term
                H[j, i] += term
    return H
