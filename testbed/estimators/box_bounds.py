"""A box of bounds on the free values, `(low, high)` arrays (±inf: open; None: no box), as the
methods that keep `[identify] bounds` use it: a start moved into it, the values a bound holds at
an iteration (the KKT condition), a step solved in it by an active set, a least-squares
correction solved in it, and a point moved onto it.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "active_set_step",
    "held_on_bounds",
    "into_box",
    "least_squares_step",
    "on_bounds",
    "outcome_held",
    "start_in_box",
]


def held_on_bounds(theta: np.ndarray, g: np.ndarray, box: tuple | None) -> np.ndarray:
    """The free values held on their bound this iteration (bool, n_free): on it with the
    likelihood's descent direction `g` (the reduced normal equations' right side) pointing out of
    the box, the KKT condition of the bound (its multiplier has the right sign)."""
    if box is None:
        return np.zeros(len(theta), dtype=bool)
    low, high = box
    return ((theta <= low) & (g <= 0)) | ((theta >= high) & (g >= 0))


def active_set_step(solve, theta: np.ndarray, keep: np.ndarray, box: tuple | None) -> np.ndarray:
    """The step d of the parameters `keep` (bool; the others 0), its first len(θ) (the free
    values θ) inside the `box`: `solve(m, d, hit)` gives the step of the parameters `m` with those
    `hit` held at their entries of d; values it carries across a bound stop on it and the step is
    solved again for the rest, until none crosses (an active-set step: clipping the whole step
    would turn it off the descent and stall the damping)."""
    nf, d, hit = len(theta), np.zeros(len(keep)), np.zeros(len(keep), dtype=bool)
    for _ in range(nf + 1):
        m = keep & ~hit
        d[m] = solve(m, d, hit)
        if box is None:
            break
        crossed = np.zeros(len(keep), dtype=bool)
        crossed[:nf] = m[:nf] & ((theta + d[:nf] < box[0]) | (theta + d[:nf] > box[1]))
        if not crossed.any():
            break
        d[crossed] = (into_box(theta + d[:nf], box) - theta)[crossed[:nf]]
        hit |= crossed
    return d


def on_bounds(theta: np.ndarray, box: tuple | None) -> np.ndarray:
    """The free values that lie on a bound of the box, or beyond (bool, n_free; none without one)."""
    if box is None:
        return np.zeros(len(theta), dtype=bool)
    return (theta <= box[0]) | (theta >= box[1])


def outcome_held(held: np.ndarray) -> np.ndarray | None:
    """`Outcome.held` of the values `held` on a bound: None where none is."""
    return held if held.any() else None


def into_box(theta: np.ndarray, box: tuple | None) -> np.ndarray:
    """θ moved onto the box, where it lies outside."""
    return theta if box is None else np.clip(theta, box[0], box[1])


def start_in_box(
    p: np.ndarray, n_free: int, box: tuple | None, at=None
) -> tuple[np.ndarray, tuple | None, object]:
    """`(p, box, at)`: the start's parameter vector with its free values (the first `n_free`)
    moved into the box, the box as float arrays, and `at` (the point at `p`, if the caller has it)
    kept only where nothing moved."""
    if box is None:
        return p, None, at
    box = tuple(np.asarray(b, float) for b in box)
    inside = into_box(p[:n_free], box)
    if np.array_equal(inside, p[:n_free]):
        return p, box, at
    return np.concatenate([inside, p[n_free:]]), box, None


def least_squares_step(A: np.ndarray, b: np.ndarray, prior: np.ndarray, box: tuple | None) -> np.ndarray:
    """The correction d of `prior` that minimises ‖A d − b‖, A's columns scaled to unit length
    first (d's units do not count): the least-squares solution of least norm there, so directions
    the data do not excite keep their prior values; where prior + d leaves the `box` (prior inside
    it), the solution in the box instead (bounded least squares, `scipy.optimize.lsq_linear`)."""
    scale = np.linalg.norm(A, axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    d = np.linalg.lstsq(A / scale, b, rcond=1e-8)[0] / scale
    if box is not None and not np.all(into_box(prior + d, box) == prior + d):
        from scipy.optimize import lsq_linear  # only for a correction that leaves its box

        # min ‖(A/D) z − b‖ with prior + z/D inside the box (D the columns' norms)
        reach = ((box[0] - prior) * scale, (box[1] - prior) * scale)
        d = lsq_linear(A / scale, b, bounds=reach, method="bvls").x / scale
        d = into_box(prior + d, box) - prior
    return d
