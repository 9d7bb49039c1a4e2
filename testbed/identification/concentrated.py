"""The output-error cost alone, for optimisers that need no derivatives (the simplex):
`J_M(θ) = 1/N Σ eᵀR⁻¹e` with R held and each experiment's initial state at its best for θ
(concentrated out), in three recursions over the samples per record and no sensitivities.

The outputs are linear in the measured components x0 of the initial state,
`y[k] = C x_f[k] + C Φᵏ x0` (x_f the response from trim to the inputs), so the best x0 solves
`A x0 = b` with W = R⁻¹ on the record's channels and

    A = Σ_k (CΦᵏ)ᵀ W CΦᵏ   the record's observability Gramian over its N samples, made by
                           doubling in about 2 log₂N steps (`kernels.gramian`),
    b = Σ_k (CΦᵏ)ᵀ W (y[k] − C x_f[k]) = λ[0],   λ[k] = Φᵀλ[k+1] + CᵀW (y[k] − C x_f[k]),

the adjoint recursion run backwards. A record with missing samples weights each sample by
W P[k], P[k] 1 for a channel's sample present and 0 for one missing: its Gramian is summed
sample by sample (`kernels.masked_gramian`), its adjoint and residuals take P[k] in.
A ≥ W (its k = 0 term): positive definite. The cost is
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
from testbed.models.linear import IBIAS, ICURRENT, IDELAY, NU, NX

__all__ = ["CONDITION", "Cost", "cost"]

# the Gramian's condition number (unit diagonal) up to which x0 comes from the normal equations:
# on the example vehicle the cost then agrees with the QR solve's to 4e-16 at 5e10, 1e-11 at 4e12
CONDITION = 1e10


class Cost:
    """`J_M(θ)` of `prob` at the free values with R held, prepared once (the records stacked per
    model they share, `Problem.key`; given output terms taken off and a given delay applied)
    for the thousands of calls of a simplex search; each call is one compiled pass per model
    (`kernels.concentrated_sse`)."""

    def __init__(self, prob: Problem):
        self.prob, self.groups = prob, []
        # what moves with the free values, done per call; what is given, once here
        self.moving_inputs = prob.delayed and bool(np.isin(prob.index, IDELAY).any())
        self.moving_terms = prob.biased and bool(np.isin(prob.index, np.r_[IBIAS, ICURRENT]).any())
        start = prob.start
        for key in dict.fromkeys(prob.key(r) for r in prob.records):
            records = [r for r in prob.records if prob.key(r) == key]
            starts = np.cumsum([0] + [len(r.y) for r in records])
            measured = np.zeros((len(records), NX), dtype=np.int64)
            y, present = np.zeros((starts[-1], NX)), np.ones((starts[-1], NX))
            for k, r in enumerate(records):
                measured[k, : len(r.measured)] = r.measured
                y[starts[k] : starts[k + 1], : len(r.measured)] = r.y
                if prob.biased and not self.moving_terms:
                    y[starts[k] : starts[k + 1], : len(r.measured)] -= prob.output_terms(r, start)
                if r.present is not None:
                    present[starts[k] : starts[k + 1], : len(r.measured)] = r.present
            y[present == 0] = 0.0  # a missing sample stays 0
            complete = np.array([r.present is None for r in records])
            inputs = np.ascontiguousarray(
                np.concatenate([prob.inputs(r, start) for r in records]), dtype=float
            )
            counts = np.array([len(r.measured) for r in records], dtype=np.int64)
            self.groups.append((key, records, starts, measured, counts, y, present, complete, inputs))

    def __call__(self, values: np.ndarray, R: np.ndarray) -> float:
        """`J_M = 1/N Σ eᵀR⁻¹e` at the free `values`; ∞ for an invalid model (singular Mt, or
        outputs that diverge: `likelihood.exploded`). Three sweeps over the records, each counted
        as a simulation (`recursions.simulated`): the outputs from x0 = 0, the adjoint that gives
        x0's normal equations, the outputs from x0 (its fallback `_by_qr` counts its own)."""
        from testbed.identification import kernels  # the compiler only where the simplex runs

        prob = self.prob
        if prob.mounted:  # outputs that mix the states: the compiled pass reads the states alone
            return _by_qr(prob, values, R)
        simulated(3 * prob.n_samples)
        total = 0.0
        try:
            with np.errstate(over="ignore", invalid="ignore"):  # a diverging model is an answer here
                models = discrete_models(prob, values, 0)
                for key, records, starts, measured, counts, y, present, complete, inputs in self.groups:
                    E = models[key].E
                    if self.moving_inputs:  # the fins' angles: the recorded ones advanced by the delay
                        inputs = np.ascontiguousarray(
                            np.concatenate([prob.inputs(r, values) for r in records])
                        )
                    if self.moving_terms:  # the measured states: the data less their output terms
                        y = y.copy()
                        for k, r in enumerate(records):
                            y[starts[k] : starts[k + 1], : len(r.measured)] -= prob.output_terms(r, values)
                        y[present == 0] = 0.0  # a missing sample stays 0
                    W = np.zeros((len(records), NX))
                    for k, r in enumerate(records):
                        W[k, : len(r.channels)] = 1.0 / R[r.channels]
                    sse = kernels.concentrated_sse(
                        np.ascontiguousarray(E[:, :NX]),
                        np.ascontiguousarray(E[:, NX : NX + NU]),
                        np.ascontiguousarray(E[:, -1]),
                        inputs,
                        y,
                        present,
                        complete,
                        starts,
                        measured,
                        counts,
                        W,
                        EXPLODE,
                        CONDITION,
                    )
                    if sse == -2.0:
                        return _by_qr(prob, values, R)
                    if not sse >= 0:  # the outputs diverged
                        return np.inf
                    total += sse
        except np.linalg.LinAlgError:
            return np.inf
        if not np.isfinite(total):
            return np.inf
        return total / prob.n_samples


def cost(prob: Problem, values: np.ndarray, R: np.ndarray) -> float:
    """`Cost(prob)(values, R)`: `J_M` once (a search prepares `Cost` once instead)."""
    return Cost(prob)(values, R)


def _by_qr(prob: Problem, values: np.ndarray, R: np.ndarray) -> float:
    """`cost` with the initial states from `likelihood.fit_initial_states` (QR factors)."""
    with np.errstate(over="ignore", invalid="ignore"):
        out = fit_initial_states(prob, values, R)[1]
    if exploded(prob, out) is not None:
        return np.inf
    return (
        sum(float(np.sum(r.residual(y) ** 2 / R[r.channels])) for r, y in zip(prob.records, out))
        / prob.n_samples
    )
