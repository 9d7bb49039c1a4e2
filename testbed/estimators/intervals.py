"""The intervals between present samples, the equation-error methods' unit of data: over each
interval between consecutive rows where every state a dynamics row involves is present, the
states' difference quotient, their midpoint and the fins' mean over the interval.

With the fins held at each row, the row equation `M ẋ = f(x, δ)` integrated over the interval
[t_a, t_b] gives M (x_b − x_a)/(t_b − t_a) = the mean of f over it; the states' mean is taken at
the midpoint (x_a + x_b)/2 and the fins' mean is exact, ∫ δ dt/(t_b − t_a), over every row held
in between (a row whose states are missing still holds its fins).
"""

from __future__ import annotations

import numpy as np

__all__ = ["between_present"]


def between_present(t: np.ndarray, x: np.ndarray, fins: np.ndarray) -> tuple[np.ndarray, ...]:
    """`(ẋ, x̄, δ̄)` over the intervals between consecutive rows of `x` (N, k) with every column
    present (not NaN): the difference quotient Δx/Δt and the midpoint (m, k) and the mean of
    `fins` (N, f), held from each stamp `t` (N,) to the next, over each interval (m, f)."""
    rows = np.flatnonzero(~np.isnan(x).any(axis=1))
    span = np.diff(t[rows])[:, None]
    # ∫ δ dt from the first row to each row: the held fins times the rows' steps
    integral = np.concatenate(
        [np.zeros((1, fins.shape[1])), np.cumsum(fins[:-1] * np.diff(t)[:, None], axis=0)]
    )
    xs = x[rows]
    return np.diff(xs, axis=0) / span, 0.5 * (xs[1:] + xs[:-1]), np.diff(integral[rows], axis=0) / span
