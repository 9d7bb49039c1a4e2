"""The paper's Newton-Raphson optimiser (`ml-nr`): the likelihood's Newton steps with the
second-order sensitivities, over records lengthened stage by stage from their first seconds.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from testbed.estimators.base import Callback, Outcome, Progress, Status
from testbed.estimators.box_bounds import active_set_step, held_on_bounds, outcome_held, start_in_box
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
    box: tuple | None = None,
) -> Outcome:
    """The paper's Eq. 10 on `J_M = 1/N Σ eᵀR⁻¹e`, R re-estimated before every step.

    `coordinates`: where the iteration runs, which sets λ = max|∂J_M/∂x| and μ: "si", the
    parameters in SI units (the paper's), or "scaled", the free coefficients scaled by the
    start, x_i = θ_i/|θ_i,start| (θ_i where θ_i,start = 0; the initial states stay in SI), with
    ∂J_M/∂x = S ∂J_M/∂p and ∂²J_M/∂x² = S ∂²J_M/∂p² S, S = diag(∂p/∂x), and the step S Δx.
    In SI units λ is the largest gradient entry of whichever coefficient has the largest units,
    and the damping λI then holds every step to about one SI unit; scaled, every coefficient
    moves in proportion to its size.

    `box`: `(low, high)` of the free values (±inf: open), the box the fit keeps them in: a start
    outside it is moved onto it, a value on its bound with the descent pointing out is held there
    for the iteration (the bound's KKT condition, `box_bounds.held_on_bounds`: left out of the
    step and of the convergence test), the others' step is an active-set step in the box
    (`box_bounds.active_set_step`), and `Outcome.held` marks those it ends held on.
    """
    nf = prob.n_free
    p, box, _ = start_in_box(p, nf, box)
    history, N = [p[:nf].copy()], prob.n_samples
    S = np.ones(len(p))
    if coordinates == "scaled":
        S[: prob.n_free] = np.where(p[: prob.n_free] != 0, np.abs(p[: prob.n_free]), 1.0)
    last, held = p, np.zeros(nf, dtype=bool)
    for it in range(max_iter + 1):
        sim = _simulated_residuals(prob, p)
        if sim is None:  # the step into an invalid model does not count; report the one before
            return Outcome(last, Status.DIVERGED, it - 1, np.array(history[:it]), held=outcome_held(held))
        xs, res = sim
        if it:
            _report_iteration(callback, prob, it, p, res)
        R, g, M = _normal_terms(prob, p, xs, res)
        # the values a bound holds: by θ's descent with the initial states at their best
        held = held_on_bounds(p[:nf], likelihood.reduced(M, g, nf)[1], box) if box is not None else held
        keep = np.r_[~held, np.ones(len(p) - nf, dtype=bool)]
        converged = _converged(g[keep], M[np.ix_(keep, keep)], tol)
        if converged or it == max_iter:
            break
        grad = -2.0 / N * g * S  # ∂J_M/∂x
        weights = [e / R[r.channels] for r, e in zip(prob.records, res)]
        # ∂²J_M/∂x² (Eq. 3 sensitivities)
        hess = 2.0 / N * (M - recursions.curvature(prob, p, weights)) * np.outer(S, S)
        lam = float(np.max(np.abs(grad[keep])))
        mu = 0.5 if lam > 1 else 1.0 / (lam + 1.0)

        def solve(m, d, hit, hess=hess, lam=lam, mu=mu, grad=grad):
            # (∂²J/∂x² + λI) Δx = −μ ∂J/∂x over the parameters m, those hit held at d (Δx = d/S)
            rhs = -mu * grad[m] - hess[np.ix_(m, hit)] @ (d[hit] / S[hit])
            return S[m] * np.linalg.solve(hess[np.ix_(m, m)] + lam * np.eye(m.sum()), rhs)

        try:  # θ kept in the box by an active set
            step = active_set_step(solve, p[:nf], keep, box)
        except np.linalg.LinAlgError:
            return Outcome(p, Status.DIVERGED, it, np.array(history), held=outcome_held(held))
        last, p = p, p + step
        history.append(p[:nf].copy())
    status = Status.CONVERGED if converged else Status.MAX_ITERATIONS
    return Outcome(p, status, it, np.array(history), M, held=outcome_held(held))


def _normal_terms(prob: Problem, p: np.ndarray, xs, res):
    """R, g and M at `p` (`likelihood.gauss_newton_terms`)."""
    R = likelihood.noise_variance(prob, res)
    g, M = likelihood.gauss_newton_terms(prob, p, xs, res, R)
    return R, g, M


def _converged(g: np.ndarray, M: np.ndarray, tol: float) -> bool:
    """Whether the Gauss-Newton step `M⁻¹g` is shorter than `tol` in Cramér-Rao units."""
    return bool(np.sqrt(max(g @ bounds.crlb(M).covariance @ g, 0.0)) < tol)


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
