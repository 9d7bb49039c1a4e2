"""The plain Gauss-Newton optimiser of the output-error likelihood with Levenberg-Marquardt
damping (`ml-lm`), written once over the `objective.Objective` protocol: the linear model's and
the nonlinear model's likelihood alike.
"""

from __future__ import annotations

import numpy as np

from testbed.estimators.base import Outcome, Progress, Status
from testbed.estimators.box_bounds import active_set_step, held_on_bounds, outcome_held, start_in_box
from testbed.identification import bounds, likelihood, linear_objective
from testbed.identification.objective import Objective, Point
from testbed.identification.problem import Problem

__all__ = ["levenberg_marquardt"]


def levenberg_marquardt(
    prob: Problem | Objective,
    p: np.ndarray,
    max_iter: int = 50,
    callback=None,
    tol: float = 1e-3,
    at: Point | None = None,
    box: tuple | None = None,
) -> Outcome:
    """Levenberg-Marquardt on the weighted cost `½ Σ eᵀR⁻¹e` of `prob` (a linear `Problem`, or
    any `Objective`) from the free values of `p`, R re-estimated at every point taken.

    The step solves the Gauss-Newton normal equations damped by Marquardt's diagonal,
    `(F + λ diag F) d = g`: where the objective fits the initial states at every θ (`projected`,
    the linear model) on θ's reduced equations (`likelihood.reduced`, the initial states
    eliminated), else on the whole parameter vector, the initial states stepping with θ. A step
    that lowers the cost (R held at the point's) is taken and λ falls tenfold; else λ rises
    tenfold, STALLED beyond 1e12. Converged when the Gauss-Newton step is shorter than `tol`
    Cramér-Rao σ. `at`: `prob.point(p[:n_free])`, if the caller has it. `box`: `(low, high)` of
    the free values (±inf: open), the box the fit keeps them in: a start outside it is moved onto
    it, a value on its bound with the descent pointing out is held there for the iteration (the
    bound's KKT condition, `box_bounds.held_on_bounds`: left out of the step and of the
    convergence test), the others' step is an active-set step in the box (`_damped_step`), and
    `Outcome.held` marks those it ends held on."""
    obj = linear_objective.as_objective(prob)
    nf = obj.n_free
    p, box, at = start_in_box(p, nf, box, at)
    x = obj.point(p[:nf]) if at is None else at
    if x is None:
        return Outcome(p, Status.DIVERGED, 0, np.array([p[:nf]]))
    history, lam = [x.p[:nf].copy()], 0.01
    status = Status.MAX_ITERATIONS
    for it in range(max_iter + 1):
        g, M = obj.terms(x)
        # F d = g: θ's reduced equations where the initial states are fitted at every θ
        F, gr = likelihood.reduced(M, g, nf) if obj.projected else (M, g)
        # the values a bound holds: by θ's descent with the initial states at their best
        descent = gr[:nf] if obj.projected or box is None else likelihood.reduced(M, g, nf)[1]
        held = held_on_bounds(x.p[:nf], descent, box)
        keep = np.r_[~held, np.ones(len(F) - nf, dtype=bool)]
        Fk, gk = F[np.ix_(keep, keep)], gr[keep]
        # the Gauss-Newton step of the values not held, in Cramér-Rao units: √(gᵀ F⁻¹ g)
        if np.sqrt(max(gk @ bounds.crlb(Fk).covariance @ gk, 0.0)) < tol:
            status = Status.CONVERGED
            break
        if it == max_iter:
            break
        W0 = obj.weighted_cost(x.res, x.R)
        while True:
            try:
                d = _damped_step(F, gr, lam, keep, x.p[:nf], box)
            except np.linalg.LinAlgError:  # singular even damped: a larger λ
                trial = None
            else:  # projected: θ's step, the initial states fitted again there
                trial = obj.moved(x, np.concatenate([d, np.zeros(len(x.p) - nf)]) if obj.projected else d)
            if trial is not None and obj.weighted_cost(trial.res, x.R) < W0:
                x, lam = trial, max(lam / 10, 1e-12)
                break
            lam *= 10
            if lam > 1e12:
                return _outcome(x, Status.STALLED, it, history, M, held)
        history.append(x.p[:nf].copy())
        if callback is not None:
            callback(Progress(it + 1, x.p[:nf].copy(), x.J))
    return _outcome(x, status, it, history, M, held)


def _damped_step(F, g, lam: float, keep: np.ndarray, theta: np.ndarray, box) -> np.ndarray:
    """The Levenberg-Marquardt step `(F + λ diag F) d = g` of the parameters `keep` (the others
    0), the values θ kept in the `box` by an active set (`box_bounds.active_set_step`): those
    stopped on a bound held there, the rest solved with the model's gradient there, `g − F_·h d_h`."""

    def solve(m, d, hit):
        Fm = F[np.ix_(m, m)]
        # (F + λ diag F) d = g − F_·h d_h
        return np.linalg.solve(
            Fm + lam * np.diag(np.maximum(np.diag(Fm), 1e-300)), g[m] - F[np.ix_(m, hit)] @ d[hit]
        )

    return active_set_step(solve, theta, keep, box)


def _outcome(x: Point, status: Status, it: int, history: list, M, held: np.ndarray) -> Outcome:
    """Where it stopped: the point `x`, with M there and its states and residuals, and the values
    `held` on a bound."""
    return Outcome(
        x.p, status, it, np.array(history), M, cost=x.J, simulated=(x.xs, x.res), held=outcome_held(held)
    )
