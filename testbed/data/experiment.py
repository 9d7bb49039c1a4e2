"""A record as the estimators take it (`Experiment`): its checks, and the stretches a dropout in
its fins splits it into."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np

from testbed.errors import InputError
from testbed.models.linear import INPUTS, STATES

__all__ = [
    "Experiment",
    "MAX_DATA",
    "MAX_GAP",
    "MIN_ROWS",
    "TOO_LARGE",
    "check_excited",
    "check_experiment",
    "median",
    "split",
    "stretch_name",
    "stretches",
    "too_large",
    "uniform_step",
]


MIN_ROWS = 3  # the fewest samples a record can have: the estimators difference and fit x0 on them

# The longest gap in a record's logged inputs, in their median intervals, across which the model
# holds the fins (`stretches`): a few rows dropped, where holding them costs less than a new
# initial state (a tenth of the rows dropped at random and the record split at every pair: bounds
# 1.5–1.9× wider); a longer dropout splits the record (a 2.4 s one held in a Scenario II log:
# coefficients 60 σ off and `ml-gn` at its iteration limit)
MAX_GAP = 10.0

# The largest magnitude a measured state or input may have, in SI units (m, m/s, rad, rad/s):
# 1000 km of depth, 1000 km/s, 10⁶ rad. Beyond it a value is a unit or export error, and its
# square, summed over a record, would leave the range of double precision long before 1e300.
MAX_DATA = 1e6


@dataclass(frozen=True)
class Experiment:
    """One record: uniform time `t`, measured states (absolute `u`; NaN where a sample is
    missing), inputs (rad), and where no row logged the inputs (`held`: held from the row
    before; the model is flown across a short gap so, and split at a long one, `stretches`)."""

    name: str
    t: np.ndarray  # (N,)
    measured: tuple[str, ...]  # state names present, in STATES order
    y: np.ndarray  # (N, len(measured))
    inputs: np.ndarray  # (N, 3), INPUTS order
    source: str = ""
    sensors: tuple[
        str, ...
    ] = ()  # the config sensors whose readings are already undone (`ModelConfig.readings`)
    held: np.ndarray | None = None  # (N,) True where no row logged the inputs; None: none

    @property
    def dt(self) -> float:
        return float(self.t[1] - self.t[0])

    def only(self, states: Sequence[str]) -> "Experiment":
        """The experiment with only the measured states among `states` (InputError if none)."""
        keep = [s for s in self.measured if s in states]
        if not keep:
            raise InputError(
                f"{self.source or self.name}: none of the fitted outputs "
                f"({', '.join(states)}) is measured; it has {', '.join(self.measured)}"
            )
        cols = [self.measured.index(s) for s in keep]
        return replace(self, measured=tuple(keep), y=self.y[:, cols])

    def column(self, state: str) -> np.ndarray:
        return self.y[:, self.measured.index(state)]


def median(a: np.ndarray) -> float:
    """`np.median` of the values of `a` (NaN if one is NaN), by partition: `np.median` imports
    `numpy.ma` on its first call, 50 ms, a tenth of a command that fits a CSV."""
    a = np.asarray(a, dtype=float).ravel()
    if not a.size or np.isnan(a).any():
        return math.nan
    k = a.size // 2
    if a.size % 2:
        return float(np.partition(a, k)[k])
    part = np.partition(a, [k - 1, k])
    return float((part[k - 1] + part[k]) / 2)


def uniform_step(t: np.ndarray) -> tuple[float, int | None]:
    """The sampling interval of the times `t` (their median step) and the index of the first
    step off it, or None if every step is within 1e-6 of it (plus the rounding of t's values as
    printed with 10 digits). A step ≤ 0, or one beyond the floating-point range, is always off."""
    with np.errstate(over="ignore", invalid="ignore"):  # t near ±1.8e308: its steps overflow
        steps = np.diff(t)
        dt = median(steps)
        tol = 1e-6 * abs(dt) + 1e-9 * float(np.max(np.abs(t)))
        off = ~np.isfinite(steps) | (steps <= 0) | ~(np.abs(steps - dt) <= tol)
    return dt, (int(np.argmax(off)) if off.any() else None)


def too_large(values: np.ndarray) -> tuple[int, int] | None:
    """(row, column) of the first value beyond ±`MAX_DATA`, or None."""
    bad = np.abs(values) > MAX_DATA
    return tuple(map(int, np.argwhere(bad)[0])) if bad.any() else None


TOO_LARGE = f"beyond ±{MAX_DATA:g}; expected a plausible SI value (m, m/s, rad, rad/s)"


def stretches(e: Experiment) -> list[tuple[int, int]]:
    """The sample ranges `[a, b)` of `e` the model is flown over: the whole record, split at each
    gap in its inputs longer than `MAX_GAP` times their median interval (a stretch of samples
    `held` from the last row that logged them: a logger's dropout, over which the fins moved as
    nothing recorded), each stretch from the row after the gap; the samples inside a gap, and a
    stretch with fewer than `MIN_ROWS` rows that logged the inputs, are left out. Across a
    shorter gap (a row dropped or two, a clock whose ticks outnumber the rows) the fins are
    held, the model's own zero-order hold."""
    n = len(e.t)
    if e.held is None or not e.held.any():
        return [(0, n)]
    held = np.asarray(e.held, dtype=bool)
    logged = np.flatnonzero(~held)
    if len(logged) < 2:
        return [(0, n)]
    # the gaps: after logged[i], where the next logged row (or the record's end) is far
    last = len(logged) - 1
    gaps = np.flatnonzero(np.diff(np.r_[logged, n]) > MAX_GAP * median(np.diff(logged)))
    starts = np.r_[logged[0], logged[gaps[gaps < last] + 1]]
    ends = np.r_[logged[gaps] + 1, [n] if last not in gaps else []].astype(int)
    keep = [(int(a), int(b)) for a, b in zip(starts, ends) if np.count_nonzero(~held[a:b]) >= MIN_ROWS]
    return keep or [(0, n)]


def stretch_name(e: Experiment, a: int, b: int) -> str:
    """The name of `e`'s samples `[a, b)` (`stretches`): its own for the whole record, else
    `NAME a–b s` with the stretch's first and last times."""
    return e.name if (a, b) == (0, len(e.t)) else f"{e.name} {e.t[a]:.4g}–{e.t[b - 1]:.4g} s"


def split(e: Experiment) -> list[Experiment]:
    """`e` as the records of its `stretches`, each named by `stretch_name`."""
    return [
        replace(
            e,
            name=stretch_name(e, a, b),
            t=e.t[a:b],
            y=e.y[a:b],
            inputs=e.inputs[a:b],
            held=None if e.held is None or not e.held[a:b].any() else e.held[a:b],
        )
        for a, b in stretches(e)
    ]


def check_experiment(e: Experiment) -> None:
    """`InputError` unless `e` is a record the estimators can use (what `read_csv` ensures of a
    file, for records made in Python): at least `MIN_ROWS` samples of its distinct measured
    states and the three inputs, finite values within ±`MAX_DATA` (a state may be missing, NaN,
    at some samples, not at all of them), uniformly increasing times."""
    name = e.source or e.name
    unknown = [s for s in e.measured if s not in STATES]
    if unknown or not e.measured or len(set(e.measured)) != len(e.measured):
        raise InputError(
            f"{name}: measured states {list(e.measured)}; expected distinct names from {', '.join(STATES)}"
        )
    try:
        y, inputs, t = (np.asarray(a, dtype=float) for a in (e.y, e.inputs, e.t))
    except (TypeError, ValueError):
        raise InputError(f"{name}: t, states and inputs must be arrays of numbers") from None
    n = len(t) if t.ndim == 1 else -1
    if n < MIN_ROWS or y.shape != (n, len(e.measured)) or inputs.shape != (n, len(INPUTS)):
        raise InputError(
            f"{name}: t {t.shape}, states {y.shape}, inputs {inputs.shape}; expected "
            f"N ≥ {MIN_ROWS} samples: (N,), (N, {len(e.measured)}), (N, {len(INPUTS)})"
        )
    for label, a in (("t", t), ("inputs", inputs)):
        if not np.all(np.isfinite(a)):
            raise InputError(f"{name}: {label} contain NaN or infinity; expected finite numbers")
    if np.isinf(y).any():
        raise InputError(f"{name}: states contain infinity; expected finite numbers (NaN: a missing sample)")
    empty = np.isnan(y).all(axis=0)
    if empty.any():
        raise InputError(
            f"{name}: {e.measured[int(np.argmax(empty))]} has no value (all NaN); expected at least one sample"
        )
    for label, a, columns in (("states", y, e.measured), ("inputs", inputs, INPUTS)):
        large = too_large(a)
        if large:
            k, j = large
            raise InputError(f"{name}: {columns[j]} = {a[k, j]:g} at t = {t[k]:g} s is {TOO_LARGE}")
    dt, off = uniform_step(t)
    if off is not None:
        raise InputError(
            f"{name}: t is not uniformly sampled (at t = {t[off + 1]:g} s); expected a constant step"
        )


def check_excited(experiments: Sequence[Experiment]) -> None:
    """`InputError` unless some record moves: a state that takes two values over its samples
    present, or a fin two angles. Records in which every state and fin holds one value show the
    vehicle at rest (or at trim) and no noise: no coefficient changes what they show, and no
    noise can be read off them, so there is nothing to identify."""
    for e in experiments:
        y, inputs = np.asarray(e.y, dtype=float), np.asarray(e.inputs, dtype=float)
        first = np.array([column[~np.isnan(column)][:1] for column in y.T]).ravel()
        if np.any((y != first) & ~np.isnan(y)) or np.any(inputs != inputs[:1]):
            return
    names = [e.source or e.name for e in experiments]
    where = names[0] if len(names) == 1 else f"{names[0]} and the {len(names) - 1} other records"
    raise InputError(
        f"{where}: no excitation: every state and fin holds one value throughout (the vehicle at "
        "rest or at trim, no noise), so no coefficient changes what the data show; nothing to "
        "identify; expected records in which the fins or the states move"
    )
