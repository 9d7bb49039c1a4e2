"""Maximum-likelihood output-error methods: `ml-gn`, `ml-lm`, `ml-nr`, `ml-nm`.

All four minimise the paper's likelihood with the noise covariance estimated by relaxation
(R from the residuals, then held while θ steps), from the same start, with the same model and
initial-state parameters (`testbed.identification`), so they compare fairly:

- `ml-gn` (default): the scaled trust-region Gauss-Newton method of `trust_region`, with
  multiple shooting and a second-order check at the optimum, from the starts of `starts`.
- `ml-lm`: Gauss-Newton with Levenberg-Marquardt damping (Marquardt's diagonal scaling).
- `ml-nr`: the paper's modified Newton-Raphson, Eq. 10, exactly: the Hessian of J_M from the
  second-order sensitivities, `μ ∂J/∂θ + (∂²J/∂θ² + λI) Δθ = 0`, λ = max|∂J/∂θ|, μ = 0.5 if
  λ > 1 else 1/(λ+1); every step is taken (no line search), so its drift and divergence show;
  in SI units (the paper's) or, option `coordinates="scaled"`, in coordinates scaled by the start.
- `ml-nm`: the paper's eight-step Nelder-Mead simplex on J_M with its stopping rule; the
  initial states are fitted by linear least squares at every θ (outputs are linear in them:
  `concentrated.cost`, the cost alone, without sensitivities); with restarts and a
  record-length continuation (default) or, option `restarts=False`, the paper's one simplex.

From a start whose response does not stay bounded over the whole record (an unstable
a-priori model, `likelihood.bounded`), ml-lm, ml-nr and ml-nm run on segments first (`_shooting`,
the multiple shooting `ml-gn` has built in).

Convergence (ml-lm, ml-nr): the Gauss-Newton step measured in Cramér-Rao units,
`√(gᵀ M⁻¹ g)`, is below `tol` (default 1e-3): the estimate is within 0.001 σ of the optimum.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, fields, replace
from typing import Sequence

import numpy as np

from testbed.identification import bounds, concentrated, likelihood, recursions, scan
from testbed.identification.problem import Problem, problem
from testbed.data import Experiment, ModelConfig
from testbed.errors import InputError, is_number
from testbed.estimators import nonlinear, starts, trust_region
from testbed.estimators.simplex import STEPS, fresh_simplex, simplex_coefficients, simplex_run
from testbed.estimators.base import (
    Callback,
    Estimate,
    Method,
    Options,
    Outcome,
    Progress,
    Status,
    count_option,
    is_count,
    option,
    unphysical,
)

__all__ = [
    "DELTA_J",
    "Fit",
    "best_fit",
    "fresh_simplex",
    "GaussNewtonOptions",
    "ML_GN",
    "ML_LM",
    "ML_NM",
    "ML_NR",
    "NewtonRaphsonOptions",
    "SIMPLEX_ITERATIONS",
    "SimplexOptions",
    "TrustRegionOptions",
]


def _terms(prob: Problem, p: np.ndarray, xs, res, tol: float):
    """R, g and M at `p` (`likelihood.gauss_newton_terms`), and whether the Gauss-Newton step `M⁻¹g` is
    shorter than `tol` in Cramér-Rao units: converged."""
    R = likelihood.noise_variance(prob, res)
    g, M = likelihood.gauss_newton_terms(prob, p, xs, res, R)
    return R, g, M, np.sqrt(max(g @ bounds.crlb(M).covariance @ g, 0.0)) < tol


def _simulate(prob: Problem, p: np.ndarray):
    """States and residuals at `p`, or None where the model is invalid (singular Mt, diverging)."""
    try:
        with np.errstate(over="ignore", invalid="ignore"):  # a diverging model is an answer here
            xs = recursions.states(prob, p)
    except np.linalg.LinAlgError:
        return None
    out = [prob.outputs(r, x, p[: prob.n_free]) for r, x in zip(prob.records, xs)]
    if not np.all(np.isfinite(p)) or likelihood.exploded(prob, out) is not None:
        return None
    return xs, [r.residual(y) for r, y in zip(prob.records, out)]


def _report(callback: Callback | None, prob: Problem, it: int, p: np.ndarray, res) -> None:
    if callback is not None:
        callback(Progress(it, p[: prob.n_free].copy(), likelihood.negative_log_likelihood(prob, res)))


def gauss_newton(
    prob: Problem, p: np.ndarray, max_iter: int = 50, callback=None, tol: float = 1e-3
) -> Outcome:
    """Levenberg-Marquardt on `½ Σ eᵀR⁻¹e`, R re-estimated before every step."""
    history, lam = [p[: prob.n_free].copy()], 0.01
    xs, res = _simulate(prob, p)
    for it in range(max_iter + 1):
        R, g, M, converged = _terms(prob, p, xs, res, tol)
        if converged or it == max_iter:
            break
        J0, D = likelihood.weighted_cost(prob, res, R), np.diag(np.maximum(np.diag(M), 1e-300))
        while True:
            trial = p + np.linalg.solve(M + lam * D, g)
            sim = _simulate(prob, trial)
            if sim is not None and likelihood.weighted_cost(prob, sim[1], R) < J0:
                p, (xs, res), lam = trial, sim, max(lam / 10, 1e-12)
                break
            lam *= 10
            if lam > 1e12:
                return Outcome(p, Status.STALLED, it, np.array(history), M)
        history.append(p[: prob.n_free].copy())
        _report(callback, prob, it + 1, p, res)
    status = Status.CONVERGED if converged else Status.MAX_ITERATIONS
    return Outcome(p, status, it, np.array(history), M)


@scan.compiled()  # second-order sensitivities at every iteration: the compiler pays off
def newton_raphson(
    prob: Problem,
    p: np.ndarray,
    max_iter: int = 100,
    callback=None,
    tol: float = 1e-3,
    coordinates: str = "si",
) -> Outcome:
    """The paper's Eq. 10 on `J_M = 1/N Σ eᵀR⁻¹e`, R re-estimated before every step.

    `coordinates`: where the iteration runs, which sets λ = max|∂J_M/∂x| and μ: "si", the
    parameters in SI units (the paper's), or "scaled", the free coefficients scaled by the
    start, x_i = θ_i/|θ_i,start| (θ_i where θ_i,start = 0; the initial states stay in SI), with
    ∂J_M/∂x = S ∂J_M/∂p and ∂²J_M/∂x² = S ∂²J_M/∂p² S, S = diag(∂p/∂x), and the step S Δx.
    In SI units λ is the largest gradient entry of whichever coefficient has the largest units,
    and the damping λI then holds every step to about one SI unit; scaled, every coefficient
    moves in proportion to its size.
    """
    history, N = [p[: prob.n_free].copy()], prob.n_samples
    S = np.ones(len(p))
    if coordinates == "scaled":
        S[: prob.n_free] = np.where(p[: prob.n_free] != 0, np.abs(p[: prob.n_free]), 1.0)
    last = p
    for it in range(max_iter + 1):
        sim = _simulate(prob, p)
        if sim is None:  # the step into an invalid model does not count; report the one before
            return Outcome(last, Status.DIVERGED, it - 1, np.array(history[:it]))
        xs, res = sim
        if it:
            _report(callback, prob, it, p, res)
        R, g, M, converged = _terms(prob, p, xs, res, tol)
        if converged or it == max_iter:
            break
        grad = -2.0 / N * g * S  # ∂J_M/∂x
        weights = [e / R[r.channels] for r, e in zip(prob.records, res)]
        # ∂²J_M/∂x² (Eq. 3 sensitivities)
        hess = 2.0 / N * (M - recursions.curvature(prob, p, weights)) * np.outer(S, S)
        lam = float(np.max(np.abs(grad)))
        mu = 0.5 if lam > 1 else 1.0 / (lam + 1.0)
        try:
            step = S * np.linalg.solve(hess + lam * np.eye(len(p)), -mu * grad)
        except np.linalg.LinAlgError:
            return Outcome(p, Status.DIVERGED, it, np.array(history))
        last, p = p, p + step
        history.append(p[: prob.n_free].copy())
    status = Status.CONVERGED if converged else Status.MAX_ITERATIONS
    return Outcome(p, status, it, np.array(history), M)


def _stages(prob: Problem, first_length: float) -> list[Problem]:
    """The record-length continuation: each experiment's first T s for T = `first_length`,
    2·`first_length`, 4·`first_length`, … while shorter than 90 % of the longest record (a stage
    nearly as long as the record would only repeat it), then all of it."""
    longest = max(len(r.y) * r.dt for r in prob.records)
    lengths, T = [], first_length
    while T < 0.9 * longest:
        lengths.append(T)
        T *= 2
    return [
        replace(
            prob, records=tuple(r.rows(0, n) for r in prob.records for n in [max(int(round(T / r.dt)), 1)])
        )
        for T in lengths
    ] + [prob]


@scan.compiled()  # thousands of simulations: the compiler pays off
def nelder_mead(
    prob: Problem,
    p: np.ndarray,
    max_iter: int | None = None,
    callback=None,
    eps: float = 1e-3,
    step: float | None = None,
    restart_step: float | None = None,
    r_tol: float = 1e-3,
    max_relaxations: int = 20,
    coefficients: str = "adaptive",
    first_length: float = 60.0,
    stage_eps: float = 1.0,
    restarts: bool = True,
    coordinates: str | None = None,
    follow: tuple = (),
) -> Outcome:
    """The paper's eight-step simplex on J_M(θ) with R fixed; R relaxed between simplex runs.

    Stopping rule (step 3): `{1/(m+1) Σ (J_M(θ_i) − J_M(θ_b))²}^½ ≤ ε`, with ε = `eps`/N (J_M is
    a mean over N samples, so `eps` is in units of the χ² statistic N·J_M).

    Globalisation, for starts outside output error's local basin (from 40 % off, Gauss-Newton
    converges on the first 60 s or 120 s of the REMUS-class rudder PRBS but not on 300 s: the
    heading integrates the yaw-rate error, so the cost's nonconvexity grows with record length):

    - Coordinates (`coordinates`): by default each run's simplex moves in coordinates in which
      the Gauss-Newton information at its start is the identity (`_information_frame`): a unit
      step is one Cramér-Rao σ along each principal direction, so the cost's valleys, long and
      narrow in the coefficients' own units (the drift groups), are round, and the simplex
      needs about a third of the iterations. `scaled`: x_i = θ_i/|θ_i,start| (θ_i where
      θ_i,start = 0), every coefficient searched in proportion to its size. The first simplex
      spans `step` along each axis; every later run starts afresh from the best corner with
      `restart_step`.
    - Coefficients (`coefficients`): the paper's reflection 1, expansion 2, contraction ½ and
      shrink ½, or (default) Gao & Han's dimension-adaptive 1, 1 + 2/m, ¾ − 1/(2m), 1 − 1/m,
      which equal the paper's for m = 2 and make expansion less greedy and shrinking gentler as
      m grows, against the simplex's degeneration in many dimensions (Gao & Han 2012).
    - Restarts: a run that stops by its rule may have stagnated (the simplex degenerates); a fresh
      simplex at its best corner either moves on or confirms the minimum. A run that has not
      stopped after `RUN` iterations per free coefficient starts afresh from its best corner,
      in the frame there and as large as the simplex had become: the information's principal
      directions turn along a curved valley.
    - Joining (`follow`: earlier fits' optima (θ, σ) on the whole record): a fit whose best
      corner comes within `trust_region.JOIN` Cramér-Rao σ of one is in its basin and stops
      (`Outcome.joined`), as `ml-gn`'s starts do.
    - Record-length continuation (`first_length`): the simplex first fits each experiment's first
      `first_length` s, then twice that, and so on, and finally the whole record; each stage
      ends when a run stops by the rule with ε = `stage_eps`/N (corners within about a Cramér-Rao
      σ of each other for `stage_eps` = 1: enough to start the next stage inside its basin) and
      starts the next from its best corner with R relaxed.

    On the whole record, R is relaxed after each run and the next run starts afresh from the
    best corner. Converged when a run stops by its rule, improves J_M over its start by no more
    than ε, and the R update that follows changes no variance by more than `r_tol` (relative);
    STALLED if that takes more than `max_relaxations` runs.

    `restarts=False` is the paper's simplex without the globalisation's restarts and
    continuation (in `coordinates`, with `coefficients`): one simplex on the whole
    record from the first simplex at the start (`step` along each axis); when it stops by its
    rule, R is relaxed at its best corner and the same simplex goes on, its corners' J
    re-evaluated under the new R. Converged when it stops by its rule and that R update changes
    no variance by more than `r_tol`; STALLED after `max_relaxations` R updates.
    """
    nf = prob.n_free
    max_iter = SIMPLEX_ITERATIONS * nf if max_iter is None else max_iter
    coef = simplex_coefficients(coefficients, nf)
    coordinates = coordinates or "information"
    step = STEPS[coordinates][0] if step is None else step
    restart_step = STEPS[coordinates][1] if restart_step is None else restart_step
    scale = np.where(p[:nf] != 0, np.abs(p[:nf]), 1.0)
    theta = p[:nf].copy()
    history, it, joined, final = [theta.copy()], 0, [-1], [False]

    def report(i: int, best: np.ndarray, J: float) -> bool:
        """Record the best corner; True (stop) where it lies in an earlier optimum's basin."""
        theta = frame.theta(best)
        history.append(theta)
        if callback is not None:
            callback(Progress(i, theta, J))
        for k, (optimum, std) in enumerate(follow if final[0] else ()):
            if np.all(np.abs(theta - optimum) <= trust_region.JOIN * std):
                joined[0] = k
                return True
        return False

    def framed(stage: Problem, theta: np.ndarray, R: np.ndarray) -> _Frame:
        if coordinates == "scaled":
            return _Frame(np.zeros(nf), scale)
        return _information_frame(stage, theta, R, scale)

    if not restarts:
        R = likelihood.noise_variance(
            prob, recursions.residuals(prob, likelihood.initial_states(prob, theta))
        )
        frame = framed(prob, theta, R)
        return _one_simplex(
            prob, frame, R, coef, eps, step, r_tol, max_relaxations, max_iter, report, history
        )
    stages = _stages(prob, first_length)
    for stage in stages:
        final[0] = stage is prob
        size = step if stage is stages[0] else restart_step
        tol = (eps if stage is prob else stage_eps) / stage.n_samples
        q = likelihood.initial_states(stage, theta)
        R = likelihood.noise_variance(stage, recursions.residuals(stage, q))
        cost, relaxations = concentrated.Cost(stage), 0
        while True:
            frame = framed(stage, theta, R)

            def J(v: np.ndarray, cost=cost, R=R, frame=frame) -> float:
                return cost(frame.theta(v), R)

            x = frame.x(theta)
            J_start = J(x)
            corners, J_i, it, stopped = simplex_run(
                J, fresh_simplex(x, size), coef, tol, it, min(max_iter, it + RUN * nf), report
            )
            theta, J_best = frame.theta(corners[0]), J_i[0]
            if joined[0] >= 0:
                return Outcome(
                    likelihood.initial_states(prob, theta, R), Status.CONVERGED, it, np.array(history),
                    joined=joined[0],
                )  # fmt: skip
            if not stopped:
                if it >= max_iter:
                    return Outcome(
                        likelihood.initial_states(prob, theta, R),
                        Status.MAX_ITERATIONS,
                        it,
                        np.array(history),
                    )
                # a run cut short: afresh from its best corner in the frame there, as large as
                # the simplex had become (its corners' median distance from the best)
                size = float(np.median(np.linalg.norm(corners[1:] - corners[0], axis=1)))
                continue
            # R from the residuals at the best corner: the relaxation step
            q = likelihood.initial_states(stage, theta, R)
            R, R_old = likelihood.noise_variance(stage, recursions.residuals(stage, q)), R
            size, relaxations = restart_step, relaxations + 1
            if stage is not prob or (J_start - J_best <= tol and np.max(np.abs(R / R_old - 1)) < r_tol):
                break
            if relaxations >= max_relaxations:
                return Outcome(
                    likelihood.initial_states(prob, theta, R), Status.STALLED, it, np.array(history)
                )
    return _converged(prob, theta, R, it, history)


SIMPLEX_ITERATIONS = 500  # ml-nm's iteration limit per free coefficient, unless max_iter sets one
RUN = 20  # iterations per free coefficient after which a simplex run that has not stopped starts afresh


def _information(
    prob: Problem, theta: np.ndarray, R: np.ndarray, weigh: np.ndarray | None = None
) -> tuple[trust_region.Point, np.ndarray, np.ndarray] | None:
    """The point at θ (its initial states fitted with `R`), the Gauss-Newton information M of the
    full parameter vector there, weighed by `weigh` (None: the point's own residual variance), and
    M with the initial states solved for (F, θ's alone); None where the model diverges at θ."""
    x = trust_region.point(prob, theta, R)
    if x is None:
        return None
    with np.errstate(over="ignore", invalid="ignore"):
        g, M = likelihood.gauss_newton_terms(prob, x.p, x.xs, x.res, x.R if weigh is None else weigh)
    return x, M, likelihood.reduced(M, g, prob.n_free)[0]


def _converged(prob: Problem, theta: np.ndarray, R: np.ndarray, it: int, history: list) -> Outcome:
    """The CONVERGED outcome at θ (its initial states fitted with `R`), with its Fisher information
    (which spares `bounds.assess` a pass) and its optimum (θ, Cramér-Rao σ) for later starts to
    recognise (`Outcome.optimum`), where the information there is finite."""
    found = _information(prob, theta, R)
    if found is None:
        return Outcome(likelihood.initial_states(prob, theta, R), Status.CONVERGED, it, np.array(history))
    x, M, F = found
    std = bounds.crlb(F).std
    if not (np.all(np.isfinite(M)) and np.all(np.isfinite(std))):
        return Outcome(x.p, Status.CONVERGED, it, np.array(history))
    return Outcome(x.p, Status.CONVERGED, it, np.array(history), M, (theta.copy(), std))


@dataclass(frozen=True)
class _Frame:
    """The simplex's coordinates x: θ = origin + T x, T a matrix or (a vector) a diagonal."""

    origin: np.ndarray
    T: np.ndarray

    def theta(self, x: np.ndarray) -> np.ndarray:
        return self.origin + (self.T * x if self.T.ndim == 1 else self.T @ x)

    def x(self, theta: np.ndarray) -> np.ndarray:
        d = theta - self.origin
        return d / self.T if self.T.ndim == 1 else np.linalg.solve(self.T, d)


def _information_frame(prob: Problem, theta: np.ndarray, R: np.ndarray, scale: np.ndarray) -> _Frame:
    """Coordinates centred at θ in which the Gauss-Newton information there (initial states
    solved for, R held) is the identity: a unit step is one Cramér-Rao σ along each principal
    direction, so the cost's valleys are round for the simplex. With `D F D = V Λ Vᵀ`
    (D = 1/√diag F), `T = D V Λ^-½`; a direction the data hardly determine is searched no
    farther than its coefficients' own size (`scale`: T's column at most unit length in θ/scale).
    The coordinates scaled by `scale` where the information is not finite there (the model
    diverges)."""
    fallback = _Frame(np.zeros(prob.n_free), scale)
    found = _information(prob, theta, R, weigh=R)
    if found is None:
        return fallback
    F = found[2]
    if not np.all(np.isfinite(F)) or not np.all(np.diag(F) > 0):
        return fallback
    D = 1.0 / np.sqrt(np.diag(F))
    lam, V = np.linalg.eigh(F * np.outer(D, D))
    lam = np.maximum(lam, bounds.NULL * max(lam.max(), 1e-300))
    T = D[:, None] * V / np.sqrt(lam)
    # T = D V Λ^-½, each column at most as long as the coefficients' own size
    T /= np.maximum(np.linalg.norm(T / scale[:, None], axis=0), 1.0)
    return _Frame(theta.copy(), T)


def _one_simplex(
    prob: Problem, frame: _Frame, R, coef, eps, step, r_tol, max_relaxations, max_iter, report, history
) -> Outcome:
    """`nelder_mead` with `restarts=False`: one simplex from the start's first (in `frame`, R
    its first estimate), R relaxed whenever it stops by its rule, its corners re-evaluated under
    the new R."""
    tol = eps / prob.n_samples
    corners, it, cost = fresh_simplex(frame.x(history[0]), step), 0, concentrated.Cost(prob)
    for _ in range(max_relaxations):

        def J(v: np.ndarray, R=R) -> float:
            return cost(frame.theta(v), R)

        corners, _, it, stopped = simplex_run(J, corners, coef, tol, it, max_iter, report)
        if not stopped:
            status = Status.MAX_ITERATIONS
            break
        # R from the residuals at the best corner: the relaxation step
        q = likelihood.initial_states(prob, frame.theta(corners[0]), R)
        R, R_old = likelihood.noise_variance(prob, recursions.residuals(prob, q)), R
        if np.max(np.abs(R / R_old - 1)) < r_tol:
            status = Status.CONVERGED
            break
    else:
        status = Status.STALLED
    theta = frame.theta(corners[0])
    return Outcome(likelihood.initial_states(prob, theta, R), status, it, np.array(history))


def _estimate(
    name: str, prob: Problem, fit: Fit, t0: float, fits: list[Fit], evaluations: int, notes: dict[str, dict]
) -> Estimate:
    """The `Estimate` where the optimiser stopped from `fit`'s start, with its Cramér-Rao analysis
    and every start's result (`fits`; `notes`, start → the coefficients it left at their
    a-priori values, or why it was not computed) and the fit's `evaluations`; a DIVERGED one (the
    reason in its `message`) where that analysis breaks down or is not finite."""
    out, start, start_reason = fit.outcome, fit.start, _summary(fits, notes)
    tried = tuple(
        {
            "start": f.start,
            "cost": f.cost,
            "status": f.outcome.status.message,
            "iterations": f.outcome.iterations,
        }
        | ({"joined": f.joined} if f.joined else {})
        | notes.get(f.start, {})
        for f in fits
    ) + tuple(
        {"start": k, "cost": np.nan, "status": NOT_COMPUTED, "iterations": 0} | note
        for k, note in notes.items()
        if "reason" in note
    )
    why = None
    if out.status is Status.DIVERGED:  # where the model diverges there, no analysis to make
        with np.errstate(over="ignore", invalid="ignore"):
            diverges = likelihood.divergence(prob, out.p)
        if diverges is not None:
            why = f"the model diverges over the whole record where the fit stopped ({diverges})"
    if why is None:
        try:
            with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                info = bounds.assess(prob, out.p, out.fisher, simulated=out.simulated)
            # an infinite bound is an unidentifiable coefficient's (bounds.crlb); NaN is a failure
            why = (
                None
                if all(np.all(np.isfinite(a)) for a in (info.values, info.cost))
                and not np.any(np.isnan(info.crlb_std))
                else "the estimate or its Cramér-Rao bound is not finite"
            )
        except np.linalg.LinAlgError as exc:
            why = f"the Cramér-Rao analysis at the estimate failed ({exc})"
        why = unphysical(prob.structure, prob.coefficients(out.p[: prob.n_free])) or why
    if why is not None:
        nf = prob.n_free
        return Estimate(
            method=name,
            status=Status.DIVERGED,
            free=prob.free,
            values=out.p[:nf].copy(),
            std=np.full(nf, np.nan),
            cost=np.nan,
            iterations=sum(f.outcome.iterations for f in fits),
            wall_time_s=time.perf_counter() - t0,
            noise_std={},
            evaluations=evaluations,
            start=start,
            history=out.history,
            message=why,
            start_reason=start_reason,
            starts=tried,
        )
    return Estimate(
        method=name,
        status=out.status,
        free=prob.free,
        values=info.values,
        std=info.crlb_std,
        cost=info.cost,
        iterations=sum(f.outcome.iterations for f in fits),
        wall_time_s=time.perf_counter() - t0,
        noise_std=info.noise_std,
        evaluations=evaluations,
        start=start,
        history=out.history,
        start_reason=start_reason,
        starts=tried,
        crlb_corrected_std=np.asarray(info.crlb_corrected_std, float),
        initial_states=info.initial_states,
    )


DELTA_J = 1.0  # two fits whose negative log-likelihoods differ by less are at one optimum (½ χ²₁ at 84 %)


@dataclass(frozen=True)
class Fit:
    """One start's fit: where it began and where the optimiser stopped, with the cost there."""

    start: str
    outcome: Outcome
    cost: float  # the negative log-likelihood at outcome.p (inf where the model diverges)
    start_cost: float
    joined: str = ""  # the earlier start whose optimum's basin this one entered, ending there


def _cost(prob: Problem, p: np.ndarray) -> float:
    """The negative log-likelihood at `p`; inf where the model diverges there (`likelihood.exploded`)."""
    with np.errstate(over="ignore", invalid="ignore"):  # a diverging model is an answer here
        out = recursions.outputs(prob, p)
    if likelihood.exploded(prob, out) is not None:
        return np.inf
    return likelihood.negative_log_likelihood(prob, [r.residual(y) for r, y in zip(prob.records, out)])


def best_fit(fits: list[Fit]) -> Fit:
    """The fit of least cost; a converged fit within `DELTA_J` of it (the same optimum) before
    one that stopped otherwise."""
    least = min(f.cost for f in fits)
    converged = [f for f in fits if f.outcome.status is Status.CONVERGED and f.cost <= least + DELTA_J]
    return min(converged or fits, key=lambda f: f.cost)


NOT_COMPUTED = "not computed"  # a start's status in `starts` where it could not be computed


def _summary(fits: list[Fit], notes: dict[str, dict]) -> str:
    """What every start reached, or why it was not computed, for the estimate's `start_reason`."""
    parts = [
        f"{f.start}: cost {f.cost:.6g} ({f.outcome.status.message}"
        + (f", on the {f.joined} start's path" if f.joined else "")
        + (
            f"; {', '.join(notes[f.start]['left'])} left at their a-priori values"
            if "left" in notes.get(f.start, {})
            else ""
        )
        + ")"
        for f in fits
    ] + [f"{k}: {NOT_COMPUTED} ({note['reason']})" for k, note in notes.items() if "reason" in note]
    kept = f"the least cost of {len(fits)} starts" if len(fits) > 1 else "the only start computed"
    return f"{kept} ({'; '.join(parts)})" if len(parts) > 1 else ""


def _fit(
    name: str,
    optimiser,
    experiments: Sequence[Experiment],
    config: ModelConfig,
    options: Options,
    callback: Callback | None,
) -> Estimate:
    """Fit from the start(s) `options.start` names and keep the best (`best_fit`).

    `auto`: from the a-priori values and from the equation-error estimate, the better-fitting
    first; from the MEKF's estimate too when those two end apart (costs more than `DELTA_J`
    apart) or either fails; from the best box draw (as `global`'s) too where neither equation
    error (which leaves the rows the data cannot regress at their a-priori values) nor the MEKF
    gave a whole second start.
    `global`: from those two and from the best `polish` of `samples`
    coefficient vectors drawn in a box around the a-priori values (`starts.box`), ranked by
    their cost on the first multiple-shooting stage (records cut in 16: a poor model's error does
    not grow along the whole record there). Every start's result is recorded in the estimate,
    and the simulations of all of them counted (`Estimate.evaluations`).
    """
    with recursions.counting() as tally:
        return _fit_counted(name, optimiser, experiments, config, options, callback, tally)


def _evaluations(prob: Problem, tally: list[int]) -> int:
    """The samples simulated (`recursions.counting`) as simulations of the whole data set, rounded up."""
    return -(-tally[0] // prob.n_samples)


def _fit_counted(name, optimiser, experiments, config, options, callback, tally) -> Estimate:
    """`_fit`, the simulations tallied in `tally`."""
    t0 = time.perf_counter()
    prob = problem(experiments, config)
    start = options.start
    tuning = {f.name: getattr(options, f.name) for f in fields(options) if f.name not in START_OPTIONS}

    fits: list[Fit] = []

    def begin(theta: np.ndarray) -> tuple[np.ndarray, float, trust_region.Point | None]:
        """The parameter vector at θ with its best initial states, its cost, and for `ml-gn` the
        trust region's point there (None where the model diverges), which it starts from."""
        if optimiser is trust_region.trust_region:
            at = trust_region.point(prob, theta)
            if at is not None:
                return at.p, at.J, at
        with np.errstate(over="ignore", invalid="ignore"):  # a diverging start is reported below
            p0 = likelihood.initial_states(prob, theta)
        return p0, _cost(prob, p0), None

    def run(
        label: str, p0: np.ndarray, J0: float, at: trust_region.Point | None, earlier: Sequence[Fit] = ()
    ) -> Fit:
        more = {}
        if optimiser in (trust_region.trust_region, nelder_mead):
            more = {"follow": tuple(f.outcome.optimum for f in earlier if f.outcome.optimum)}
        if at is not None:
            more["at"] = at
        done = sum(f.outcome.iterations for f in fits)  # the iterations count on over the starts

        def report(step: Progress) -> None:
            callback(replace(step, iteration=done + step.iteration))

        first = (
            None if optimiser is trust_region.trust_region else likelihood.bounded(prob, p0[: prob.n_free])
        )
        if first is None or (first[2] == 1 and np.isfinite(J0)):
            out = optimiser(prob, p0, callback=report if callback else None, **tuning, **more)
        else:  # a start that diverges over the whole record: on segments first
            out = _shooting(optimiser, prob, first, tuning, report if callback else None)
        if out.joined >= 0:  # on an earlier fit's path: it ends where that one did
            twin = [f for f in earlier if f.outcome.optimum][out.joined]
            out = replace(twin.outcome, iterations=out.iterations, history=out.history, optimum=(), joined=-1)
            return Fit(label, out, twin.cost, J0, twin.start)
        J = _cost(prob, out.p) if out.cost is None else out.cost
        if J > J0 + 1e-9 * abs(J0) and out.status is not Status.DIVERGED:
            out = replace(out, status=Status.WORSE)
        return Fit(label, out, J, J0)

    notes: dict[str, dict] = {}  # start → what it left out ("left") or why it was not computed ("reason")

    def computed(label: str) -> np.ndarray | None:
        """The start `label`'s coefficients (`starts.named`), None where it cannot be computed."""
        try:
            theta, left = starts.named(prob, experiments, config, label)
        except InputError as exc:  # the filter refused the data or diverged; no row to regress
            notes[label] = {"reason": str(exc)}
            return None
        if left:
            notes[label] = {"left": left}
        return theta

    if start in ("config", "equation-error", "mekf"):
        theta, left = starts.named(prob, experiments, config, start)
        notes = {start: {"left": left}} if left else {}
        fit = run(start, *begin(theta))
        return _estimate(name, prob, fit, t0, [fit], _evaluations(prob, tally), notes)

    named = {"config": prob.start, "equation-error": computed("equation-error")}
    first = {k: begin(v) for k, v in named.items() if v is not None}
    for k in sorted(first, key=lambda k: (first[k][1], k != "config")):
        fits.append(run(k, *first[k], fits))
    if start == "global":
        for k, theta in enumerate(_polish_starts(prob, options)):
            fits.append(run(f"box-{k + 1}", *begin(theta), fits))
        return _estimate(name, prob, best_fit(fits), t0, fits, _evaluations(prob, tally), notes)
    if (
        len(fits) < 2
        or abs(fits[0].cost - fits[1].cost) > DELTA_J
        or any(f.outcome.status is not Status.CONVERGED for f in fits)
    ):
        theta = computed("mekf")
        if theta is not None:
            fits.append(run("mekf", *begin(theta), fits))
    whole = named["equation-error"] is not None and "left" not in notes.get("equation-error", {})
    if not whole and not any(f.start == "mekf" for f in fits):
        # no whole second start (equation error left rows at the a-priori values, no MEKF
        # fit): the best box draw is one
        for theta in _polish_starts(prob, replace(options, polish=1)):
            fits.append(run("box-1", *begin(theta), fits))
    return _estimate(name, prob, best_fit(fits), t0, fits, _evaluations(prob, tally), notes)


def _shooting(optimiser, prob: Problem, first: tuple, tuning: dict, callback) -> Outcome:
    """`optimiser` (`tuning`: its options) from a start that diverges over the whole record
    (`first`: `likelihood.bounded` there): multiple shooting, as `ml-gn`'s. First on the records
    cut into the fewest segments on which that model stays bounded, then on a quarter as many
    (`trust_region.SHRINK`), and so on, then on the whole record, each stage from the one
    before's coefficients with the iterations left of `max_iter` (all stages together); a stage
    on which they diverge is passed over. A stage before the last stops as `ml-gn`'s do, within
    `trust_region.STAGE_TOL` σ (`ml-nm`: by its rule with `stage_eps`): enough to start the next
    in its basin. DIVERGED where the whole record's model diverges from the last stage's
    coefficients."""
    first, p, count, _ = first
    theta = p[: prob.n_free]
    stages, count = [first], count // trust_region.SHRINK
    while count > 1:
        stages.append(likelihood.segmented(prob, count, likelihood.LEAST_SEGMENT))
        count //= trust_region.SHRINK
    stages.append(prob)
    budget, used, history = tuning.get("max_iter"), 0, [theta[None, :]]
    for stage in stages:
        with np.errstate(over="ignore", invalid="ignore"):
            p = likelihood.initial_states(stage, theta)
        if not np.isfinite(_cost(stage, p)):
            if stage is prob:
                return Outcome(p, Status.DIVERGED, used, np.concatenate(history))
            continue

        def report(step: Progress, used=used) -> None:
            callback(replace(step, iteration=used + step.iteration))

        left = {} if budget is None else {"max_iter": budget - used}
        if stage is not prob:  # a stage's looser convergence
            left |= {"tol": max(tuning["tol"], trust_region.STAGE_TOL)} if "tol" in tuning else {}
            left |= {"eps": tuning["stage_eps"]} if "stage_eps" in tuning else {}
        out = optimiser(stage, p, callback=report if callback else None, **(tuning | left))
        used += out.iterations
        history.append(out.history[1:])
        theta = out.p[: prob.n_free]
    return replace(out, iterations=used, history=np.concatenate(history))


def _polish_starts(prob: Problem, options: Options) -> list[np.ndarray]:
    """The best `options.polish` of `options.samples` box draws (`starts.box`), by their cost on
    the records cut into 16 segments, each with its own initial state."""
    rng = np.random.default_rng(options.seed)
    samples = starts.box(prob, options.samples, options.spread, rng)
    stage = likelihood.segmented(prob, trust_region.SEGMENTS, likelihood.LEAST_SEGMENT)
    costs = [_cost(stage, likelihood.initial_states(stage, theta)) for theta in samples]
    return [samples[i] for i in np.argsort(costs)[: options.polish] if np.isfinite(costs[i])]


STARTS = ("auto", "config", "equation-error", "mekf", "global")
START_OPTIONS = ("start", "samples", "spread", "polish", "seed")
_START = option(
    "auto",
    lambda v: v in STARTS,
    f"one of {', '.join(STARTS)}",
    "where the iterations begin: auto (the a-priori values and the equation-error estimate, "
    "and the MEKF's when those two end apart or fail, the best box draw where neither gave a whole second start; "
    "the least cost is kept), config (the "
    "a-priori values only), equation-error, mekf, or global (auto's first two and the best "
    "box draws, see samples, spread and polish)",
)
_SAMPLES = count_option(
    200, 1, "start global: coefficient vectors drawn in the box around the a-priori values"
)
_SPREAD = option(
    1.0,
    lambda v: is_number(v) and v > 0,
    "a number > 0",
    "start global: the box spans a-priori × e^±spread (coefficients analysed at 0: ±3 Cramér-Rao bounds)",
)
_POLISH = count_option(3, 1, "start global: the best box draws the optimiser is run from")
_SEED = count_option(0, 0, "start global: the seed of the box draws")
_TOL = option(
    1e-3,
    lambda v: is_number(v) and v > 0,
    "a number > 0",
    "converged when the Gauss-Newton step is shorter than tol Cramér-Rao σ",
)


def _max_iter(default: int | None):
    return option(
        default,
        lambda v: (v is None and default is None) or (is_count(v) and v >= 0),
        "an integer ≥ 0 (iterations)",
        "iteration limit" + (f"; None: {SIMPLEX_ITERATIONS} per free coefficient" if default is None else ""),
    )


@dataclass(frozen=True)
class TrustRegionOptions(Options):
    """Options of `ml-gn` (`trust_region.trust_region`: what each one means)."""

    max_iter: int = _max_iter(100)
    start: str = _START
    tol: float = _TOL
    segments: int = count_option(
        trust_region.SEGMENTS,
        1,
        "multiple shooting: each record is first fitted cut into this many pieces, a quarter as many per stage",
    )
    samples: int = _SAMPLES
    spread: float = _SPREAD
    polish: int = _POLISH
    seed: int = _SEED


@dataclass(frozen=True)
class GaussNewtonOptions(Options):
    """Options of `ml-lm`."""

    max_iter: int = _max_iter(50)
    start: str = _START
    tol: float = _TOL
    samples: int = _SAMPLES
    spread: float = _SPREAD
    polish: int = _POLISH
    seed: int = _SEED


@dataclass(frozen=True)
class NewtonRaphsonOptions(Options):
    """Options of `ml-nr`."""

    max_iter: int = _max_iter(100)
    start: str = _START
    tol: float = _TOL
    coordinates: str = option(
        "si",
        lambda v: v in ("si", "scaled"),
        "si or scaled",
        "where Eq. 10 runs, which sets λ = max|∂J/∂x| and μ: si (the paper's, SI units) or "
        "scaled (each free coefficient over its start's magnitude, x_i = θ_i/|θ_i,start|)",
    )
    samples: int = _SAMPLES
    spread: float = _SPREAD
    polish: int = _POLISH
    seed: int = _SEED


def _positive(doc: str, default: float):
    return option(default, lambda v: is_number(v) and v > 0, "a number > 0", doc)


def _step(doc: str):
    return option(None, lambda v: v is None or (is_number(v) and v > 0), "a number > 0 or None", doc)


@dataclass(frozen=True)
class SimplexOptions(Options):
    """Options of `ml-nm` (`nelder_mead`: what each one means)."""

    max_iter: int | None = _max_iter(None)
    start: str = _START
    eps: float = _positive(
        "stopping rule: the spread of J_M over the corners, in units of the χ² statistic N·J_M", 1e-3
    )
    step: float | None = _step(
        "first simplex: its edge along each axis, in Cramér-Rao σ (coordinates information) or "
        "as a fraction of each |θ_i,start| (scaled); None: 1 σ or 0.1"
    )
    restart_step: float | None = _step("later runs' fresh simplex, as step; None: 0.1 σ or 0.02")
    r_tol: float = _positive("converged when a noise update changes no variance by more than this", 1e-3)
    max_relaxations: int = count_option(
        20, 1, "simplex runs on the whole record (each after a noise update) before STALLED"
    )
    coefficients: str = option(
        "adaptive",
        lambda v: v in ("adaptive", "paper"),
        "adaptive or paper",
        "reflection, expansion, contraction and shrink: the paper's (1, 2, ½, "
        "½) or Gao & Han's dimension-adaptive (1, 1 + 2/m, ¾ − 1/(2m), 1 − 1/m)",
    )
    first_length: float = _positive(
        "record-length continuation: seconds of each experiment fitted "
        "first, doubled per stage up to the whole record",
        60.0,
    )
    stage_eps: float = _positive("stopping rule of the continuation's shorter stages (as eps)", 1.0)
    restarts: bool = option(
        True,
        lambda v: isinstance(v, bool),
        "True or False",
        "True: the record-length continuation and a fresh simplex after each noise update; False: "
        "the paper's one simplex on the whole record from the first, its corners re-evaluated "
        "after each noise update",
    )
    coordinates: str | None = option(
        None,
        lambda v: v in (None, "information", "scaled"),
        "information or scaled",
        "where the simplex moves: information (each run's start's Gauss-Newton information the "
        "identity: unit steps of one Cramér-Rao σ along its principal directions) or scaled "
        "(each free coefficient over its start's magnitude, x_i = θ_i/|θ_i,start|); None: "
        "information (a nonlinear model: scaled, the only one it has)",
    )
    samples: int = _SAMPLES
    spread: float = _SPREAD
    polish: int = _POLISH
    seed: int = _SEED


def _method(
    name: str, optimiser, options: type[Options], summary: str, on_nonlinear=None, refuses=None
) -> Method:
    def fit(experiments, config, opts, callback):
        return _fit(name, optimiser, experiments, config, opts, callback)

    return Method(
        name=name, fit=fit, options=options, summary=summary, nonlinear=on_nonlinear, refuses=refuses
    )


ML_GN = _method(
    "ml-gn",
    trust_region.trust_region,
    TrustRegionOptions,
    "maximum likelihood output error by scaled trust-region Gauss-Newton with multiple shooting",
    nonlinear.gauss_newton,
)
ML_LM = _method(
    "ml-lm",
    gauss_newton,
    GaussNewtonOptions,
    "maximum likelihood output error by Gauss-Newton with Levenberg-Marquardt damping",
)
ML_NR = _method(
    "ml-nr",
    newton_raphson,
    NewtonRaphsonOptions,
    "maximum likelihood output error by the paper's modified Newton-Raphson (Eq. 10)",
)
ML_NM = _method(
    "ml-nm",
    nelder_mead,
    SimplexOptions,
    "maximum likelihood output error by the paper's Nelder-Mead simplex",
    nonlinear.simplex,
)
