"""The output-error likelihood: residuals' noise, costs, the Gauss-Newton normal equations, the
best-fitting initial states, and the problem cut into segments (multiple shooting).

Noise: `v ~ N(0, R)` with `R` diagonal, one variance per measured state (pooled over the
experiments). A missing sample is left out of every sum (`Record.present`): the residuals are 0
there, and the variances count the samples present. The paper's likelihood `J_M = 1/N Σ eᵀR⁻¹e` is minimised by relaxation: `R` is set
to the residual variance per channel, then held fixed while θ steps (Maine & Iliff).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Sequence

import numpy as np

from testbed.identification import scan
from testbed.identification.problem import Problem
from testbed.identification.recursions import (
    channel_weights,
    discrete_models,
    sensitivity_parts,
    simulated_outputs,
    simulated,
    trajectory,
    uncoupled,
)
from testbed.models.linear import NX, STATES, continuous

__all__ = [
    "EXPLODE",
    "FEWEST_SEGMENT",
    "LEAST_SEGMENT",
    "RELAXATIONS",
    "SEGMENTS",
    "blocks",
    "bounded",
    "divergence",
    "eliminate",
    "exploded",
    "fit_initial_states",
    "gauss_newton_terms",
    "grows",
    "growth_rate",
    "initial_states",
    "negative_log_likelihood",
    "noise_variance",
    "reduced",
    "segmented",
    "weighted_cost",
]

EXPLODE = 1e3  # a simulated output beyond EXPLODE·max|y| + 1 (SI) means the model diverged
LEAST_SEGMENT = 50  # samples in a multiple-shooting segment, at least
SEGMENTS = 16  # multiple shooting's first stage, and a global search's ranking: segments per record
# the fewest samples of a segment where a record holds too few for `LEAST_SEGMENT`-sample ones
# (a small vehicle's 25 s dive logged at 2 Hz) and the model diverges over it: each segment's
# initial state still has several samples of every measured channel
FEWEST_SEGMENT = 10
RELAXATIONS = 20  # noise updates of `fit_initial_states` at most (each a k × k solve per record)


def noise_variance(prob: Problem, res: Sequence[np.ndarray]) -> np.ndarray:
    """R: residual variance per channel (len(prob.channels),), pooled over the experiments."""
    return _pooled_variance(prob, [np.sum(e**2, axis=0) for e in res])


def _pooled_variance(prob: Problem, sums: Sequence[np.ndarray]) -> np.ndarray:
    """R from each experiment's residual sums of squares per measured channel (`noise_variance`).

    Floored far below any real sensor noise so that a noise-free fit stays finite; the channels
    whose noise the config gives (`[identify] noise_std`) keep it.
    """
    ss = np.zeros(len(prob.channels))
    for r, e2 in zip(prob.records, sums):  # a record's channels are distinct
        ss[r.channels] += e2
    n, scale = prob.pooled
    R = np.maximum(ss / n, 1e-14 * scale / n + 1e-30)
    return R if prob.known is None else np.where(np.isnan(prob.known), R, prob.known)


def weighted_cost(prob: Problem, res: Sequence[np.ndarray], R: np.ndarray) -> float:
    """`½ Σ_k eᵀ R⁻¹ e` over all experiments (R held fixed: the relaxation step); `res` from
    `Record.residual`, 0 at the missing samples."""
    return 0.5 * sum(float(np.sum(e**2 / R[r.channels])) for r, e in zip(prob.records, res))


def negative_log_likelihood(prob: Problem, res: Sequence[np.ndarray]) -> float:
    """−ln p(Z|θ, R) = ½ Σ_c (N_c ln 2π R_c + S_c/R_c), S_c channel c's residual sum of squares,
    R_c the ML noise variance S_c/N_c (then ½ Σ_c N_c (ln 2π R_c + 1)) or the config's."""
    R = noise_variance(prob, res)
    n, S = np.zeros(len(prob.channels)), np.zeros(len(prob.channels))
    for r, e in zip(prob.records, res):
        n[r.channels] += r.counts
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
    a piece at a time (`scan.pieces`)."""
    models = discrete_models(prob, p[: prob.n_free], 1)
    simulated(prob.n_samples * prob.n_free)  # the sensitivities; the states `xs` are given
    g, M = np.zeros(prob.n_params), np.zeros((prob.n_params, prob.n_params))
    for r, x, e in zip(prob.records, xs, res):
        e, cols = e / np.sqrt(R[r.channels]), prob.columns(r)
        gr, Mr = np.zeros(len(cols)), np.zeros((len(cols), len(cols)))
        for channels, params, pieces in sensitivity_parts(
            prob,
            r,
            models[prob.key(r)],
            x,
            r.measured,
            channel_weights(r, R),
            scan.PIECE,
            r.present,
            values=p[: prob.n_free],
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

    A segment has at least `least` samples, counting the rows with a sample of some channel (a
    shorter record keeps fewer segments, at least one), and starts at one: the ticks of a log's
    clock between its rows carry none. Over a segment of length T a model's error grows by at
    most e^(aT) for its least stable rate a, where over the whole record it grows by
    e^(a·T_record): short segments keep the cost of an unstable or poor model's error bounded.
    The unmeasured components of each segment's initial state stay at trim, as for a whole record.
    """
    records, offset = [], prob.n_free
    for r in prob.records:
        n = len(r.y)
        rows = np.arange(n) if r.present is None else np.flatnonzero(r.present.any(axis=1))
        pieces = max(1, min(count, len(rows) // max(least, 1)))
        at = np.linspace(0, len(rows), pieces + 1).round().astype(int)[1:-1]
        edges = np.r_[0, rows[at], n]
        for j, (a, b) in enumerate(zip(edges[:-1], edges[1:])):
            name = r.name if pieces == 1 else f"{r.name}[{j}]"
            records.append(replace(r.rows(a, b), name=name, offset=offset))
            offset += len(r.measured)
    return replace(prob, records=tuple(records))


def growth_rate(prob: Problem, values: np.ndarray) -> float:
    """The rate of the model's least stable mode at the free `values` (A's eigenvalue of largest
    real part, 1/s), 0 where every mode decays."""
    A = continuous(prob.structure, prob.coefficients(values))[0]
    return max(float(np.max(np.linalg.eigvals(A).real)), 0.0)


def grows(prob: Problem, values: np.ndarray) -> bool:
    """Whether the model's least stable mode grows by more than `EXPLODE` over the longest record."""
    longest = max(len(r.y) * r.dt for r in prob.records)
    return growth_rate(prob, values) * longest > np.log(EXPLODE)


def bounded(
    prob: Problem, values: np.ndarray, least: int = LEAST_SEGMENT
) -> tuple[Problem, np.ndarray, int, str | None]:
    """`prob` cut into the fewest segments per record (`segmented`: 1, 2, 4, … each of at least
    `least` samples, or `FEWEST_SEGMENT` where the records are too short to be cut further at
    that length) on which the model at the free `values` stays bounded: its outputs do not
    explode (`exploded`) and its least stable mode (rate a > 0) grows by at most `EXPLODE`
    (a·T ≤ ln EXPLODE over T s; the fitted initial state can cancel a faster growth over the
    record, but the likelihood is then no longer near-quadratic in θ, and the information's
    elimination of that initial state cannot resolve it); the parameter vector there with the
    best-fitting initial states, the segments asked per record (1: `prob` itself), and None. Where
    even the shortest segments do not stay bounded, those, and why not."""
    rate = growth_rate(prob, values)
    count, pieces = 1, 0
    while True:
        stage = prob if count == 1 else segmented(prob, count, least)
        if count > 1 and len(stage.records) == pieces and least > FEWEST_SEGMENT:
            least = FEWEST_SEGMENT  # records too short for `least`-sample segments: shorter ones
            stage = segmented(prob, count, least)
        with np.errstate(over="ignore", invalid="ignore"):  # a diverging model is an answer here
            p = initial_states(stage, values)
            out = simulated_outputs(stage, p)
        longest = max(len(r.y) * r.dt for r in stage.records)
        why = exploded(stage, out)
        if why is None and rate * longest > np.log(EXPLODE):
            why = f"its response grows {np.exp(min(rate * longest, 700.0)):.3g}-fold over {longest:.3g} s"
        if why is None or len(stage.records) == pieces:
            if why is not None:
                why = f"{why}; A's largest eigenvalue real part is {rate:.3g} 1/s"
            return stage, p, count, why
        count, pieces = 2 * count, len(stage.records)


def eliminate(M: np.ndarray, nf: int, rhs: np.ndarray) -> np.ndarray:
    """`M_xx⁻¹ rhs`, x the parameters after the first `nf` (the initial states), with M_xx
    scaled to a unit diagonal first: an unstable model's initial-state sensitivities grow along
    the record, so M_xx spans many decades. Each record's initial state acts on its own
    samples alone, so M_xx is block diagonal (`blocks`) and is solved a block at a time: on
    multiple shooting's hundreds of segments that is hundreds of k × k solves, not one of their
    order cubed."""
    Mxx = M[nf:, nf:]
    D = np.sqrt(np.maximum(np.diag(Mxx), 0.0))
    D = np.where(D > 0, D, 1.0)
    A, b = Mxx / np.outer(D, D), rhs / D[:, None]
    out = np.empty(b.shape, dtype=np.result_type(A, b))
    for block in blocks(A):
        out[block] = np.linalg.lstsq(A[block, block], b[block], rcond=None)[0]
    return out / D[:, None]


def blocks(A: np.ndarray) -> list[slice]:
    """The diagonal blocks of the symmetric matrix `A`, as fine as its zeros allow: a block ends
    at the first index that no entry of the rows up to it reaches beyond."""
    n = len(A)
    nz = A != 0
    last = np.where(nz.any(axis=1), n - 1 - np.argmax(nz[:, ::-1], axis=1), 0)
    reach = np.maximum.accumulate(np.maximum(last, np.arange(n)))
    ends = np.flatnonzero(reach == np.arange(n))
    return [slice(int(a), int(b) + 1) for a, b in zip(np.r_[0, ends[:-1] + 1], ends)]


def reduced(M: np.ndarray, g: np.ndarray, nf: int) -> tuple[np.ndarray, np.ndarray]:
    """The normal equations of the first `nf` parameters with the others (the initial states)
    solved for: the Schur complement `F = M_θθ − M_θx M_xx⁻¹ M_xθ` and `g_θ − M_θx M_xx⁻¹ g_x`,
    the Gauss-Newton model of the cost as a function of θ alone (variable projection)."""
    if len(M) > nf:
        K = eliminate(M, nf, np.column_stack([M[nf:, :nf], g[nf:]]))
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
    models = discrete_models(prob, values, 0)
    simulated(prob.n_samples)  # one simulation: the responses to x0 are linear in it
    p = np.concatenate([values, np.zeros(prob.n_params - prob.n_free)])
    factors = []  # per record: (k, k + 1, k + 1) upper-triangular factors of [G_c v_c], channel c
    # the measured states: the data less their output terms (biases, the current); where a
    # mounted velocity log mixes the states, the data less the outputs at trim (affine in x)
    mixed = [prob.mounted and bool(np.any(r.measured < 3)) for r in prob.records]
    ys = [
        r.y - prob.outputs(r, np.zeros((len(r.y), NX)), values) if prob.biased or mix else r.y
        for r, mix in zip(prob.records, mixed)
    ]
    for r, y, mix in zip(prob.records, ys, mixed):
        d, k = models[prob.key(r)], len(r.measured)
        T = np.zeros((k, k + 1, k + 1))
        u1 = np.column_stack([prob.inputs(r, values), np.ones(len(r.y))])  # [δ; 1]: [Γ s] u1 forces column 0
        pieces = _read_responses(prob, r, d, u1, values) if mix else _responses(d, r, u1)
        finite = True
        for channels, cols, samples, Y in pieces:
            block = np.zeros((len(channels), len(samples) + k + 1, k + 1))
            block[:, : k + 1] = T[channels]
            with np.errstate(over="ignore", invalid="ignore"):
                block[:, k + 1 :, cols] = np.concatenate(
                    [Y[:, :, 1:], (y[np.ix_(samples, channels)].T - Y[:, :, 0])[:, :, None]], axis=2
                )
                if r.present is not None:  # a missing sample's row: zero, no equation
                    block[:, k + 1 :] *= r.present[np.ix_(samples, channels)].T[:, :, None]
            if not np.all(np.isfinite(block)):
                finite = False
                break
            T[channels] = np.linalg.qr(block, mode="r")[:, : k + 1]
        factors.append(T if finite else None)

    # the records by their number of measured states, each group's factors stacked: one batched
    # solve per group (a segmented problem has dozens of records of the same size)
    groups: dict[int, list[int]] = {}
    for i, (r, T) in enumerate(zip(prob.records, factors)):
        if T is not None:
            groups.setdefault(len(r.measured), []).append(i)
    stacked = {k: np.stack([factors[i] for i in idx]) for k, idx in groups.items()}

    def solve(variance) -> list[np.ndarray]:
        """x0 per record for channel variances `variance(record)` (stored in `p`), and the
        residual sums of squares there: min Σ_c ‖(G_c x − v_c)‖²/R_c = Σ_c ‖U_c x − z_c‖²/R_c + ρ_c²/R_c
        with [U_c z_c; 0 ρ_c] channel c's factor."""
        sums = [None] * len(prob.records)
        for k, idx in groups.items():
            T = stacked[k]
            w = np.stack([variance(prob.records[i]) for i in idx]) ** -0.5
            A = (T[:, :, :k, :k] * w[:, :, None, None]).reshape(len(idx), -1, k)
            z = (T[:, :, :k, k] * w[:, :, None]).reshape(len(idx), -1)
            x0 = np.full((len(idx), k), np.nan)
            finite = np.all(np.isfinite(A), axis=(1, 2)) & np.all(np.isfinite(z), axis=1)
            if finite.any():
                x0[finite] = _least_squares(A[finite], z[finite])
            # Σ_c ‖U_c x0 − z_c‖² + ρ_c², per record and channel
            r2 = np.sum((np.einsum("bcij,bj->bci", T[:, :, :k, :k], x0) - T[:, :, :k, k]) ** 2, axis=2)
            r2 += T[:, :, k, k] ** 2
            for j, i in enumerate(idx):
                r = prob.records[i]
                p[r.offset : r.offset + k] = x0[j] if finite[j] else ys[i][0]
                sums[i] = r2[j] if finite[j] else np.full(k, np.inf)
        for i, (r, y) in enumerate(zip(prob.records, ys)):
            if sums[i] is None:  # responses not finite: the first measured samples
                p[r.offset : r.offset + len(r.measured)] = y[0]
                sums[i] = np.full(len(r.measured), np.inf)
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
    xs = [trajectory(models[prob.key(r)], prob.x0(r, p), prob.inputs(r, values)) for r in prob.records]
    return p, xs if full else [prob.outputs(r, x, values) for r, x in zip(prob.records, xs)]


def _least_squares(A: np.ndarray, z: np.ndarray) -> np.ndarray:
    """The least-squares solutions x of the stacked problems `A[b] x ≈ z[b]` (B, m, k), each
    with its columns scaled to unit length first (x's units do not count): by one batched QR where
    every R is well conditioned, `np.linalg.lstsq` (its minimum-norm solution) where one is not."""
    with np.errstate(over="ignore"):
        D = np.linalg.norm(A, axis=1)
    if not np.all(np.isfinite(D)):  # a square overflowed: the norm over the largest entry
        top = np.max(np.abs(A), axis=1)
        D = top * np.linalg.norm(A / np.where(top > 0, top, 1.0)[:, None, :], axis=1)
    D = np.where(D > 0, D, 1.0)
    A = A / D[:, None, :]
    Q, U = np.linalg.qr(A)
    d = np.abs(np.diagonal(U, axis1=1, axis2=2))
    # lstsq's rank rule, on the triangular factor's diagonal: well above eps·max(m, k)·its largest
    good = np.all(d > 1e3 * np.finfo(float).eps * max(A.shape[1:]) * d.max(axis=1, keepdims=True), axis=1)
    x = np.empty(A.shape[::2])
    if good.any():
        x[good] = np.linalg.solve(U[good], np.einsum("bmk,bm->bk", Q[good], z[good])[:, :, None])[:, :, 0]
    for b in np.flatnonzero(~good):
        x[b] = np.linalg.lstsq(A[b], z[b], rcond=None)[0]
    return x / D


def _responses(d, r, u1: np.ndarray):
    """The record's outputs' responses, a piece at a time: (channels, cols, samples, Y), Y
    (len(channels), T, 1 + len(x0)) with column 0 the response forced by `u1` = [δ; 1] from
    trim and 1 + i the response to the i-th x0 component of this part (`cols`: where these sit
    in [G_c v_c]). Each part of the model that evolves on its own (`uncoupled`) is propagated
    alone."""
    k, Phi, forcing = len(r.measured), d.E[:, :NX], d.E[:, NX:]
    acts = np.column_stack([forcing.any(axis=1), np.eye(NX, dtype=bool)[:, r.measured]])
    for states, params, channels in uncoupled(Phi != 0, acts, r.measured):
        params = np.union1d([0], params)  # a part the inputs do not force has a zero column 0
        at = np.full(NX, -1)
        at[states] = np.arange(len(states))
        x0 = params[1:] - 1  # the x0 components of this part, indexes into r.measured
        X = np.zeros((len(states), len(params)))
        X[at[r.measured[x0]], 1 + np.arange(len(x0))] = 1.0
        rows = at[r.measured[channels]]
        cols = np.r_[x0, k]
        for samples, Y in scan.pieces(
            Phi[np.ix_(states, states)], forcing[states], u1, X, rows, np.ones(len(rows)), scan.PIECE
        ):
            yield channels, cols, samples, Y


def _read_responses(prob: Problem, r, d, u1: np.ndarray, values: np.ndarray):
    """`_responses` of a record whose `mounted` velocity log mixes the states: every state's
    response propagated, the outputs' the linear part of their reading, `Problem.read_matrix`."""
    k, Phi, forcing = len(r.measured), d.E[:, :NX], d.E[:, NX:]
    X = np.zeros((NX, 1 + k))
    X[r.measured, 1 + np.arange(k)] = 1.0
    C = prob.read_matrix(r, values)
    for samples, Y in scan.pieces(Phi, forcing, u1, X, np.arange(NX), np.ones(NX), scan.PIECE):
        yield np.arange(k), np.r_[: k + 1], samples, np.einsum("cs,stq->ctq", C, Y)


def initial_states(prob: Problem, values: np.ndarray, R: np.ndarray | None = None) -> np.ndarray:
    """The parameter vector at the free `values` with the best-fitting initial states."""
    return fit_initial_states(prob, values, R)[0]


def divergence(prob: Problem, p: np.ndarray) -> str | None:
    """Why the model at `p` diverges on the data (with its least stable eigenvalue), or None."""
    with np.errstate(over="ignore", invalid="ignore"):
        why = exploded(prob, simulated_outputs(prob, p))
    if why is None:
        return None
    A = continuous(prob.structure, prob.coefficients(p[: prob.n_free]))[0]
    ev = np.linalg.eigvals(A)
    worst = ev[np.argmax(ev.real)]
    return f"{why}; A's largest eigenvalue real part is {worst.real:.3g} 1/s"
