"""The linear model's output-error likelihood as an `objective.Objective`: its outputs are linear
in the initial states, so at every θ each record's initial state is the weighted least-squares one
(`likelihood.fit_initial_states`) and the optimiser moves in θ alone, the initial states
following exactly (variable projection, Golub & Pereyra); the Hessian is exact, from the
second-order sensitivities (`recursions.curvature`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from testbed.identification import likelihood, recursions
from testbed.identification.objective import Objective, Point
from testbed.identification.problem import Problem

__all__ = ["LinearObjective", "as_objective", "point"]


def point(prob: Problem, theta: np.ndarray, R: np.ndarray | None = None) -> Point | None:
    """The point at θ: the initial states fitted with the noise variance `R` (None: R and they
    at their maximum likelihood, `likelihood.fit_initial_states`), R re-estimated from the residuals;
    None where the model is invalid there (singular Mt, diverging)."""
    if not np.all(np.isfinite(theta)):
        return None
    try:
        with np.errstate(over="ignore", invalid="ignore"):  # a diverging model is an answer here
            p, xs = likelihood.fit_initial_states(prob, theta, R, full=True)
    except np.linalg.LinAlgError:
        return None
    out = [prob.outputs(r, x, theta) for r, x in zip(prob.records, xs)]
    if likelihood.exploded(prob, out) is not None:
        return None
    res = [r.residual(y) for r, y in zip(prob.records, out)]
    return Point(
        p, xs, res, likelihood.noise_variance(prob, res), likelihood.negative_log_likelihood(prob, res)
    )


@dataclass(frozen=True)
class LinearObjective:
    """The linear output-error `prob` as an `Objective` (module doc)."""

    prob: Problem

    @property
    def n_free(self) -> int:
        return self.prob.n_free

    @property
    def start(self) -> np.ndarray:
        return self.prob.start

    @property
    def pieces(self) -> int:
        return len(self.prob.records)

    @property
    def projected(self) -> bool:
        """True: the initial states are fitted exactly at every θ (`point`)."""
        return True

    def point(self, theta: np.ndarray, R: np.ndarray | None = None) -> Point | None:
        return point(self.prob, theta, R)

    def moved(self, at: Point, step: np.ndarray) -> Point | None:
        """The point at θ + step's θ part, its initial states fitted exactly with `at.R`."""
        return point(self.prob, at.p[: self.n_free] + step[: self.n_free], at.R)

    def terms(self, at: Point) -> tuple[np.ndarray, np.ndarray]:
        return likelihood.gauss_newton_terms(self.prob, at.p, at.xs, at.res, at.R)

    def weighted_cost(self, res: list, R: np.ndarray) -> float:
        return likelihood.weighted_cost(self.prob, res, R)

    def hessian(self, at: Point, M: np.ndarray | None = None) -> np.ndarray:
        """The Hessian in θ of the weighted cost `½ Σ eᵀR⁻¹e` (R held at `at`'s) with each
        record's initial state at its least-squares value: `H = M − Σ (e/R) ∂²y` (first- and
        second-order sensitivities) with the initial states eliminated (Schur complement), the
        curvature of the cost as the optimiser sees it. `M`: the Gauss-Newton information there,
        if known."""
        prob = self.prob
        weights = [e / at.R[r.channels] for r, e in zip(prob.records, at.res)]
        if M is None:
            M = self.terms(at)[1]
        H = M - recursions.curvature(prob, at.p, weights)
        return likelihood.reduced(H, np.zeros(len(M)), prob.n_free)[0]

    def segmented(self, count: int, least: int) -> "LinearObjective":
        return LinearObjective(likelihood.segmented(self.prob, count, least))

    def shooting(self, theta: np.ndarray, least: int) -> int:
        with np.errstate(over="ignore", invalid="ignore"):  # a diverging start is an answer here
            return likelihood.bounded(self.prob, theta, least)[2]

    def grows(self, theta: np.ndarray) -> bool:
        """Whether the model's least stable mode grows beyond bound over the longest record."""
        return likelihood.grows(self.prob, theta)


def as_objective(prob: Problem | Objective) -> Objective:
    """`prob` as an `Objective`: a linear `Problem` wrapped (`LinearObjective`), an objective as
    it is."""
    return LinearObjective(prob) if isinstance(prob, Problem) else prob
