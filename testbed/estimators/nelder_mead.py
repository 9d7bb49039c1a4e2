"""The paper's Nelder-Mead optimiser (`ml-nm`): the simplex on the concentrated likelihood (the
initial states solved for), in coordinates scaled by the Fisher information, restarted afresh
until a run ends where it began, with the noise re-estimated between runs.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from testbed.estimators import trust_region
from testbed.estimators.base import Outcome, Progress, Status
from testbed.estimators.box_bounds import on_bounds, outcome_held, start_in_box
from testbed.estimators.newton_raphson import length_stages
from testbed.estimators import simplex
from testbed.estimators.simplex import STEPS, Frame, run_frame, simplex_coefficients, simplex_run
from testbed.identification import bounds, concentrated, likelihood, recursions, scan
from testbed.identification.problem import Problem
from testbed.identification.linear_objective import point
from testbed.identification.objective import Point

__all__ = ["RUN", "SIMPLEX_ITERATIONS", "nelder_mead"]


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
    box: tuple | None = None,
) -> Outcome:
    """The paper's eight-step simplex on J_M(θ) with R fixed; R relaxed between simplex runs.

    Stopping rule (step 3): `{1/(m+1) Σ (J_M(θ_i) − J_M(θ_b))²}^½ ≤ ε`, with ε = `eps`/N (J_M is
    a mean over N samples, so `eps` is in units of the χ² statistic N·J_M).

    Globalisation, for starts outside output error's local basin (from 40 % off, Gauss-Newton
    converges on the first 60 s or 120 s of the REMUS-class rudder PRBS but not on 300 s: the
    heading integrates the yaw-rate error, so the cost's nonconvexity grows with record length):

    - Coordinates (`coordinates`): by default each run's simplex moves in coordinates in which
      the Gauss-Newton information at its start is the identity (`simplex.run_frame`): a unit
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

    `box`: `(low, high)` of the free values (±inf: open), the box the fit keeps them in: a start
    outside it is moved onto it, and a corner whose θ lies outside costs J_M at θ moved onto the
    box plus its squared distance from there in the simplex's coordinates over N (`Frame`), so
    the simplex searches the box and comes back to it; `Outcome.held` marks the values that end
    on a bound.
    """
    p, box, _ = start_in_box(p, prob.n_free, box)
    out = _simplex(
        prob, p, max_iter, callback, eps, step, restart_step, r_tol, max_relaxations, coefficients,
        first_length, stage_eps, restarts, coordinates, follow, box,
    )  # fmt: skip
    return replace(out, held=outcome_held(on_bounds(out.p[: prob.n_free], box)))


def _simplex(
    prob, p, max_iter, callback, eps, step, restart_step, r_tol, max_relaxations, coefficients,
    first_length, stage_eps, restarts, coordinates, follow, box,
) -> Outcome:  # fmt: skip
    """`nelder_mead` in the box `box` (None: none)."""
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

    def framed(stage: Problem, theta: np.ndarray, R: np.ndarray) -> Frame:
        return run_frame(coordinates, theta, scale, box, lambda: _reduced_information(stage, theta, R))

    if not restarts:
        R = likelihood.noise_variance(
            prob, recursions.residuals(prob, likelihood.initial_states(prob, theta))
        )
        frame = framed(prob, theta, R)
        return _one_simplex(
            prob, frame, R, coef, eps, step, r_tol, max_relaxations, max_iter, report, history
        )
    stages = length_stages(prob, first_length)
    for stage in stages:
        final[0] = stage is prob
        size = step if stage is stages[0] else restart_step
        tol = (eps if stage is prob else stage_eps) / stage.n_samples
        q = likelihood.initial_states(stage, theta)
        R = likelihood.noise_variance(stage, recursions.residuals(stage, q))
        cost, relaxations = concentrated.Cost(stage), 0
        while True:
            frame = framed(stage, theta, R)

            def J(v: np.ndarray, cost=cost, R=R, frame=frame, n=stage.n_samples) -> float:
                return cost(frame.theta(v), R) + frame.outside(v) / n

            x = frame.x(theta)
            J_start = J(x)
            corners, J_i, it, stopped = simplex_run(
                J, simplex.fresh_simplex(x, size), coef, tol, it, min(max_iter, it + RUN * nf), report
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
) -> tuple[Point, np.ndarray, np.ndarray] | None:
    """The point at θ (its initial states fitted with `R`), the Gauss-Newton information M of the
    full parameter vector there, weighed by `weigh` (None: the point's own residual variance), and
    M with the initial states solved for (F, θ's alone); None where the model diverges at θ."""
    x = point(prob, theta, R)
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


def _reduced_information(prob: Problem, theta: np.ndarray, R: np.ndarray) -> np.ndarray | None:
    """The Gauss-Newton information of θ there, the initial states solved for and R held; None
    where the model diverges there."""
    found = _information(prob, theta, R, weigh=R)
    return None if found is None else found[2]


def _one_simplex(
    prob: Problem, frame: Frame, R, coef, eps, step, r_tol, max_relaxations, max_iter, report, history
) -> Outcome:
    """`nelder_mead` with `restarts=False`: one simplex from the start's first (in `frame`, R
    its first estimate), R relaxed whenever it stops by its rule, its corners re-evaluated under
    the new R."""
    tol = eps / prob.n_samples
    corners, it, cost = simplex.fresh_simplex(frame.x(history[0]), step), 0, concentrated.Cost(prob)
    for _ in range(max_relaxations):

        def J(v: np.ndarray, R=R) -> float:
            return cost(frame.theta(v), R) + frame.outside(v) / prob.n_samples

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
