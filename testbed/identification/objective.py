"""The output-error likelihood as an optimiser sees it, whatever the model (`Objective`): the
cost at a point, the Gauss-Newton normal equations there, a step taken, the records cut into
segments. `linear_objective` implements it for the linear model, `nonlinear_objective` for the
nonlinear one; `estimators.trust_region` (`ml-gn`) is written once over it.

The parameter vector is `p = (θ_free, x0 of record 1, x0 of record 2, …)`, each record's initial
state in its measured components: the optimiser moves θ and the initial states follow it (exactly
where the outputs are linear in them, by their Gauss-Newton step where they are not).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from testbed.identification.likelihood import eliminate

__all__ = ["Objective", "Point", "following"]


@dataclass(frozen=True)
class Point:
    """A point of the parameter space: the full parameter vector p, each record's states along
    its flight, the residuals (0 or NaN where a sample is missing), the noise variance R per
    channel estimated from them (or given) and the negative log-likelihood J there."""

    p: np.ndarray
    xs: list
    res: list
    R: np.ndarray
    J: float


@runtime_checkable
class Objective(Protocol):
    """An output-error problem as the optimisers see it.

    - `n_free`: the free values θ, the first entries of p; `start`: their a-priori values (the
      scale a step is measured in); `pieces`: the records (segments count as records);
      `projected`: whether every point's initial states are the best for its θ (the optimiser
      then steps in θ alone; else the initial states take their Gauss-Newton step with θ's);
    - `point(θ, R)`: the point at θ with its initial states (fitted, or from the records' first
      samples), R held at `R` or estimated; None where the model diverges there;
    - `moved(at, step)`: the point at `at.p + step` (`step` over the whole of p: θ's step and the
      initial states' Gauss-Newton step that follows it, `following`), R held at `at.R` while the
      initial states are fitted, then estimated; None where the model diverges there;
    - `terms(at)`: `(g, M)`, `g = Σ Sᵀ R⁻¹ e` and `M = Σ Sᵀ R⁻¹ S` over the whole of p, S the
      outputs' exact sensitivities, R the point's;
    - `weighted_cost(res, R)`: `½ Σ eᵀR⁻¹e` over the samples present;
    - `hessian(at, M)`: the Hessian of the weighted cost in θ with the initial states
      eliminated (second-order sensitivities included), or None where the model has none (the
      second-order check then probes the cost);
    - `segmented(count, least)`: the records cut into `count` segments of at least `least`
      samples, each with its own initial state (multiple shooting);
    - `shooting(θ, least)`: the fewest segments per record (1, 2, 4, …) on which the model at θ
      stays bounded, 1 where the whole record does;
    - `grows(θ)`: whether the model at θ has a mode that grows beyond bound over the records even
      where its point there is finite (its sensitivities then dominated by that mode).
    """

    @property
    def n_free(self) -> int: ...

    @property
    def start(self) -> np.ndarray: ...

    @property
    def pieces(self) -> int: ...

    @property
    def projected(self) -> bool: ...

    def point(self, theta: np.ndarray, R: np.ndarray | None = None) -> Point | None: ...

    def moved(self, at: Point, step: np.ndarray) -> Point | None: ...

    def terms(self, at: Point) -> tuple[np.ndarray, np.ndarray]: ...

    def weighted_cost(self, res: list, R: np.ndarray) -> float: ...

    def hessian(self, at: Point, M: np.ndarray) -> np.ndarray | None: ...

    def segmented(self, count: int, least: int) -> "Objective": ...

    def shooting(self, theta: np.ndarray, least: int) -> int: ...

    def grows(self, theta: np.ndarray) -> bool: ...


def following(M: np.ndarray, g: np.ndarray, nf: int, d: np.ndarray) -> tuple[np.ndarray, float]:
    """The whole step of p for θ's step `d`: the initial states' Gauss-Newton step with θ moved by
    d, `Δx = M_xx⁻¹ (g_x − M_xθ d)`, and `g_xᵀ M_xx⁻¹ g_x`, twice the decrease of the cost the
    initial states' own step predicts (0 where they are at their best for θ already)."""
    if len(M) == nf:
        return d, 0.0
    K = eliminate(M, nf, np.column_stack([g[nf:], M[nf:, :nf] @ d]))
    own = float(g[nf:] @ K[:, 0])
    return np.concatenate([d, K[:, 0] - K[:, 1]]), max(own, 0.0)
