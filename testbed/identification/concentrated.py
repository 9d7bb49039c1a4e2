"""The output-error cost alone, for optimisers that need no derivatives (the simplex):
`J_M(θ) = 1/N Σ eᵀR⁻¹e` with R held and each experiment's initial state at its best for θ
(concentrated out), in three recursions over the samples per record and no sensitivities.

The outputs are linear in the measured components x0 of the initial state,
`y[k] = C x_f[k] + C Φᵏ x0` (x_f the response from trim to the inputs), so the best x0 solves
`A x0 = b` with W = R⁻¹ on the record's channels and

    A = Σ_k (CΦᵏ)ᵀ W CΦᵏ   the record's observability Gramian over its N samples, made by
                           doubling in about 2 log₂N steps (`kernels.gramian`),
    b = Σ_k (CΦᵏ)ᵀ W (y[k] − C x_f[k]) = λ[0],   λ[k] = Φᵀλ[k+1] + CᵀW (y[k] − C x_f[k]),

the adjoint recursion run backwards. A ≥ W (its k = 0 term): positive definite. The cost is
then summed from the residuals of the trajectory simulated from that x0, never from
`vᵀWv − bᵀx0`, whose cancellation would cost digits: x0's rounding error (the normal
equations square the condition number) enters the cost only to second order. This is the
minimum `likelihood.fit_initial_states` finds with R given, by a third of its arithmetic. Where
the Gramian scaled to a unit diagonal is conditioned worse than `CONDITION` (a strongly
unstable model: its free response grows by decades along the record), the cost is computed
from that QR solve instead, which does not square the condition number.
"""

from __future__ import annotations

import numpy as np

from testbed.identification.likelihood import EXPLODE, exploded, fit_initial_states
from testbed.identification.problem import Problem
from testbed.identification.recursions import discrete_models, simulated
from testbed.models.linear import NU, NX

__all__ = ["CONDITION", "cost"]

# the Gramian's condition number (unit diagonal) up to which x0 comes from the normal equations:
# on the example vehicle the cost then agrees with the QR solve's to 4e-16 at 5e10, 1e-11 at 4e12
CONDITION = 1e10


def cost(prob: Problem, values: np.ndarray, R: np.ndarray) -> float:
    """`J_M = 1/N Σ eᵀR⁻¹e` at the free `values` with R held and the initial states at their
    best; ∞ for an invalid model (singular Mt, or outputs that diverge: `likelihood.exploded`).
    Three compiled sweeps over the records (`kernels.adjoint_sum`, `kernels.weighted_sse`), each
    counted as a simulation (`recursions.simulated`): the outputs from x0 = 0, the adjoint that
    gives x0's normal equations, the outputs from x0 (its fallback `_by_qr` counts its own)."""
    from testbed.identification import kernels  # the compiler only where the simplex runs

    simulated(3 * prob.n_samples)
    try:
        with np.errstate(over="ignore", invalid="ignore"):  # a diverging model is an answer here
            models = discrete_models(prob, values, 0)
            total, grams = 0.0, {}
            for r in prob.records:
                E, m, N = models[r.dt].E, r.measured, len(r.y)
                Phi = np.ascontiguousarray(E[:, :NX])
                F = r.inputs[:-1] @ E[:, NX : NX + NU].T + E[:, -1]
                W = 1.0 / R[r.channels]
                b = kernels.adjoint_sum(Phi, F, r.y, m, W)
                key = (r.dt, N, tuple(m), tuple(W))
                if key not in grams:
                    Q = np.zeros((NX, NX))
                    Q[m, m] = W
                    A = kernels.gramian(Phi, Q, N)[np.ix_(m, m)]
                    D = np.sqrt(np.diag(A))  # unit diagonal: x0's units do not count
                    A = A / np.outer(D, D)
                    bounds = np.linalg.eigvalsh(A)[[0, -1]]
                    if not bounds[0] * CONDITION >= bounds[1]:  # NaN too
                        return _by_qr(prob, values, R)
                    grams[key] = A, D
                A, D = grams[key]
                x0 = np.zeros(NX)
                x0[m] = np.linalg.solve(A, b / D) / D
                sse = kernels.weighted_sse(Phi, x0, F, r.y, m, W, EXPLODE)
                if not sse >= 0:  # the outputs diverged
                    return np.inf
                total += sse
    except np.linalg.LinAlgError:
        return np.inf
    if not np.isfinite(total):
        return np.inf
    return total / prob.n_samples


def _by_qr(prob: Problem, values: np.ndarray, R: np.ndarray) -> float:
    """`cost` with the initial states from `likelihood.fit_initial_states` (QR factors)."""
    with np.errstate(over="ignore", invalid="ignore"):
        out = fit_initial_states(prob, values, R)[1]
    if exploded(prob, out) is not None:
        return np.inf
    return (
        sum(float(np.sum((r.y - y) ** 2 / R[r.channels])) for r, y in zip(prob.records, out)) / prob.n_samples
    )
