"""Fits from several starts: each start's `Fit`, the one kept (`best_fit`), and what every start
reached as the estimate records it (`starts_summary`, `starts_record`), and a global search's draws
(`latin`, ranked by `box_draws`), for the linear model's ML methods (`ml`) and the nonlinear
model's (`nonlinear`) alike, over the `Objective` protocol.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from testbed.estimators.base import Outcome, Status
from testbed.identification.bounds import crlb
from testbed.identification.likelihood import LEAST_SEGMENT, SEGMENTS, reduced
from testbed.identification.objective import Objective

__all__ = [
    "BOX_BOUNDS",
    "DELTA_J",
    "NOT_COMPUTED",
    "Fit",
    "best_fit",
    "box_draws",
    "latin",
    "starts_record",
    "starts_summary",
]

BOX_BOUNDS = 3.0  # a coefficient analysed at 0 is searched within ± this many Cramér-Rao bounds

DELTA_J = 1.0  # two fits whose negative log-likelihoods differ by less are at one optimum (½ χ²₁ at 84 %)


@dataclass(frozen=True)
class Fit:
    """One start's fit: where it began and where the optimiser stopped, with the cost there."""

    start: str
    outcome: Outcome
    cost: float  # the negative log-likelihood at outcome.p (inf where the model diverges)
    start_cost: float
    joined: str = ""  # the earlier start whose optimum's basin this one entered, ending there


def best_fit(fits: list[Fit]) -> Fit:
    """The fit of least cost; a converged fit within `DELTA_J` of it (the same optimum) before
    one that stopped otherwise."""
    least = min(f.cost for f in fits)
    converged = [f for f in fits if f.outcome.status is Status.CONVERGED and f.cost <= least + DELTA_J]
    return min(converged or fits, key=lambda f: f.cost)


NOT_COMPUTED = "not computed"  # a start's status in `starts` where it could not be computed


def starts_summary(fits: list[Fit], notes: dict[str, dict]) -> str:
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


def starts_record(fits: list[Fit], notes: dict[str, dict]) -> tuple[dict, ...]:
    """Every start's result as `Estimate.starts` holds it: its cost, status and iterations, the
    start whose path it joined, what it left at the a-priori values; a start that could not be
    computed with its reason (`notes`: start → "left" or "reason")."""
    return tuple(
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


def latin(
    theta0: np.ndarray, half: np.ndarray, count: int, spread: float, rng: np.random.Generator
) -> np.ndarray:
    """`count` vectors (count, len(θ0)) drawn by Latin hypercube in the box around `theta0`: each
    axis cut into `count` equal strata, one draw in each, the strata shuffled per axis;
    log-uniform within θ_i e^±`spread` for θ_i ≠ 0, uniform within ±`half`_i for θ_i = 0."""
    u = rng.permuted(np.tile(np.arange(count), (len(theta0), 1)), axis=1).T + rng.random((count, len(theta0)))
    u = 2.0 * u / count - 1.0  # (count, len(θ0)) in (−1, 1)
    return np.where(theta0 == 0, u * half, theta0 * np.exp(spread * u))


def box_draws(
    objective: Objective, options, box: tuple[np.ndarray, np.ndarray] | None = None
) -> list[np.ndarray]:
    """The best `options.polish` of `options.samples` free-value vectors drawn by Latin hypercube
    around the a-priori values `objective.start` (`latin` with `options.spread` and `options.seed`;
    a value at 0 within ±`BOX_BOUNDS` Cramér-Rao σ at the a-priori values, 0 where they cannot be
    flown), inside `box` (lower, upper) where given, ranked by their cost on the records cut into
    `SEGMENTS` segments, each with its own initial state: a draw's basin shows on short segments,
    where a model that drifts off over the whole record still flies."""
    theta0 = objective.start
    half = np.zeros(len(theta0))
    if np.any(theta0 == 0):
        at = objective.point(theta0)
        if at is not None:
            g, M = objective.terms(at)
            std = crlb(reduced(M, g, objective.n_free)[0]).std
            half = np.where(np.isfinite(std), BOX_BOUNDS * std, 0.0)
    draws = latin(theta0, half, options.samples, options.spread, np.random.default_rng(options.seed))
    if box is not None:
        draws = np.clip(draws, *box)
    stage = objective.segmented(SEGMENTS, LEAST_SEGMENT)
    points = [stage.point(d) for d in draws]
    costs = [np.inf if a is None else a.J for a in points]
    return [draws[i] for i in np.argsort(costs)[: options.polish] if np.isfinite(costs[i])]
