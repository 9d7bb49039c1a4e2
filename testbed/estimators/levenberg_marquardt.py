"""The plain Gauss-Newton optimiser of the output-error likelihood with Levenberg-Marquardt
damping (`ml-lm`), and the normal equations and progress reports the optimisers share.
"""

from __future__ import annotations

import numpy as np

from testbed.estimators.base import Callback, Outcome, Progress, Status
from testbed.identification import bounds, likelihood, recursions
from testbed.identification.problem import Problem

__all__ = ["levenberg_marquardt", "normal_terms", "report_iteration", "simulated_residuals"]


def normal_terms(prob: Problem, p: np.ndarray, xs, res, tol: float):
    """R, g and M at `p` (`likelihood.gauss_newton_terms`), and whether the Gauss-Newton step `M⁻¹g` is
    shorter than `tol` in Cramér-Rao units: converged."""
    R = likelihood.noise_variance(prob, res)
    g, M = likelihood.gauss_newton_terms(prob, p, xs, res, R)
    return R, g, M, np.sqrt(max(g @ bounds.crlb(M).covariance @ g, 0.0)) < tol


def simulated_residuals(prob: Problem, p: np.ndarray):
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


def report_iteration(callback: Callback | None, prob: Problem, it: int, p: np.ndarray, res) -> None:
    if callback is not None:
        callback(Progress(it, p[: prob.n_free].copy(), likelihood.negative_log_likelihood(prob, res)))


def levenberg_marquardt(
    prob: Problem, p: np.ndarray, max_iter: int = 50, callback=None, tol: float = 1e-3
) -> Outcome:
    """Levenberg-Marquardt on `½ Σ eᵀR⁻¹e`, R re-estimated before every step."""
    history, lam = [p[: prob.n_free].copy()], 0.01
    xs, res = simulated_residuals(prob, p)
    for it in range(max_iter + 1):
        R, g, M, converged = normal_terms(prob, p, xs, res, tol)
        if converged or it == max_iter:
            break
        J0, D = likelihood.weighted_cost(prob, res, R), np.diag(np.maximum(np.diag(M), 1e-300))
        while True:
            trial = p + np.linalg.solve(M + lam * D, g)
            sim = simulated_residuals(prob, trial)
            if sim is not None and likelihood.weighted_cost(prob, sim[1], R) < J0:
                p, (xs, res), lam = trial, sim, max(lam / 10, 1e-12)
                break
            lam *= 10
            if lam > 1e12:
                return Outcome(p, Status.STALLED, it, np.array(history), M)
        history.append(p[: prob.n_free].copy())
        report_iteration(callback, prob, it + 1, p, res)
    status = Status.CONVERGED if converged else Status.MAX_ITERATIONS
    return Outcome(p, status, it, np.array(history), M)
