"""The paper's Newton-Raphson optimiser (`ml-nr`): the likelihood's Newton steps with the
second-order sensitivities, over records lengthened stage by stage from their first seconds.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from testbed.estimators.base import Callback, Outcome, Progress, Status
from testbed.identification import bounds, likelihood, recursions, scan
from testbed.identification.problem import Problem

__all__ = ["length_stages", "newton_raphson"]


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
        sim = _simulated_residuals(prob, p)
        if sim is None:  # the step into an invalid model does not count; report the one before
            return Outcome(last, Status.DIVERGED, it - 1, np.array(history[:it]))
        xs, res = sim
        if it:
            _report_iteration(callback, prob, it, p, res)
        R, g, M, converged = _normal_terms(prob, p, xs, res, tol)
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


def _normal_terms(prob: Problem, p: np.ndarray, xs, res, tol: float):
    """R, g and M at `p` (`likelihood.gauss_newton_terms`), and whether the Gauss-Newton step `M⁻¹g` is
    shorter than `tol` in Cramér-Rao units: converged."""
    R = likelihood.noise_variance(prob, res)
    g, M = likelihood.gauss_newton_terms(prob, p, xs, res, R)
    return R, g, M, np.sqrt(max(g @ bounds.crlb(M).covariance @ g, 0.0)) < tol


def _simulated_residuals(prob: Problem, p: np.ndarray):
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


def _report_iteration(callback: Callback | None, prob: Problem, it: int, p: np.ndarray, res) -> None:
    if callback is not None:
        callback(Progress(it, p[: prob.n_free].copy(), likelihood.negative_log_likelihood(prob, res)))


def length_stages(prob: Problem, first_length: float) -> list[Problem]:
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
