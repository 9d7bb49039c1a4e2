"""Instants read off sampled records, between the samples: where a signal crosses a level
(linear interpolation), where it peaks (the parabola through the highest sample and its
neighbours), and where a fin begins each move of a manoeuvre (its execute).

A fin's execute is the instant it has covered `EXECUTE_FRACTION` of a move from one held
angle to the next: within a sample of the instant it started, and not set off by encoder noise
(the bundled torpedo's fins slew at 2 rad/s, so 5 % of a 20° step is 9 ms after its start).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

__all__ = ["EXECUTE_FRACTION", "crossing", "executes", "peak"]

EXECUTE_FRACTION = 0.05  # of a fin's move from one held angle to the next


def crossing(t: np.ndarray, y: np.ndarray, level: float, after: float | None = None) -> float | None:
    """The first instant at or after `after` (default: the first sample) where `y` reaches
    `level`, linearly interpolated between the samples; None if it never does."""
    d = np.asarray(y, float) - level
    at = np.flatnonzero(d == 0.0)
    across = np.flatnonzero(d[:-1] * d[1:] < 0.0)
    instants = np.concatenate(
        [t[at], t[across] + (t[across + 1] - t[across]) * d[across] / (d[across] - d[across + 1])]
    )
    if after is not None:
        instants = instants[instants >= after]
    return float(instants.min()) if instants.size else None


def peak(t: np.ndarray, y: np.ndarray, begin: float, end: float) -> tuple[float, float]:
    """(instant, value) of the largest `y` on [begin, end]: the vertex of the parabola through
    the highest sample and its two neighbours, where it lies between them."""
    inside = np.flatnonzero((t >= begin) & (t <= end))
    k = int(inside[np.argmax(y[inside])])
    if k == 0 or k == len(t) - 1:
        return float(t[k]), float(y[k])
    (t0, t1, t2), (y0, y1, y2) = t[k - 1 : k + 2], y[k - 1 : k + 2]
    a = ((y2 - y1) / (t2 - t1) - (y1 - y0) / (t1 - t0)) / (t2 - t0)  # the parabola's curvature
    if a >= 0.0:
        return float(t1), float(y1)
    slope = (y1 - y0) / (t1 - t0) + a * (t1 - t0)  # its slope at t1
    shift = float(np.clip(-slope / (2.0 * a), t0 - t1, t2 - t1))
    return float(t1 + shift), float(y1 + slope * shift + a * shift**2)


def executes(t: np.ndarray, fin: np.ndarray, held: Sequence[float]) -> list[float]:
    """The execute instants of a fin that moves through the held angles `held` in turn (from
    held[0] to held[1], then to held[2], …): each where the fin has covered `EXECUTE_FRACTION`
    of its move, once it has arrived within half that of the previous held angle (the
    record's first instant where the fin is already past it there). As many as the record
    holds."""
    out: list[float] = []
    arrived = None
    for a, b in zip(held[:-1], held[1:]):
        # its execute level, and the arrival: within half that fraction of the held angle (so
        # the next move's level lies beyond it)
        level, near = a + EXECUTE_FRACTION * (b - a), b - 0.5 * EXECUTE_FRACTION * (b - a)
        if not out and (fin[0] - level) * (b - a) >= 0.0:
            instant = float(t[0])
        else:
            instant = crossing(t, fin, level, arrived)
            if instant is None:
                break
        out.append(instant)
        there = np.flatnonzero((t >= instant) & ((fin - near) * (b - a) >= 0.0))
        if not there.size:
            break
        arrived = float(t[there[0]])
    return out
