"""Measurement CSVs (docs/files.md): read onto one uniform clock (stamps as loggers write them,
stale repeats, missing samples, unwrapped angles), and written."""

from __future__ import annotations

import csv
import io
import math
import re
from pathlib import Path
from typing import Sequence

import numpy as np

from testbed.data.experiment import MIN_ROWS, TOO_LARGE, Experiment, median, too_large, uniform_step
from testbed.data.files import read_text
from testbed.outputs import atomic_write_text
from testbed.errors import InputError
from testbed.models.linear import INPUTS, STATES

__all__ = [
    "CLOCK_DIVISIONS",
    "CLOCK_POINTS",
    "CSV_COLUMNS",
    "MAX_SAMPLES",
    "SLOWER",
    "WRAPPING",
    "clock",
    "csv_text",
    "read_csv",
    "stale",
    "write_csv",
]


CSV_COLUMNS = ("t",) + STATES + INPUTS

MAX_SAMPLES = 10**6  # the most samples a record's time grid may have

# A log's clock (`clock`): the most grid points per row a clock that holds every stamp may put
# on a record (a 50 Hz log jittered ±20 % and stamped in milliseconds: 20), and the points per
# median step of the grid that stamps with no such clock go to
CLOCK_POINTS = 32

CLOCK_DIVISIONS = 8

# Rows per stamp that may lie off the clock of the median step, each read at its nearest tick
# (`clock`): a logger's glitch, not a clock of its own
OFF_CLOCK = 1000

# The least share of a state column's values, in rows with a fresh sample, that repeat its
# previous one for the column to be read as a sensor slower than the log (`stale`)
SLOWER = 0.25

# Angles that wrap at ±π in a log (`read_csv` unwraps them): roll and heading. Pitch stays
# within ±π/2.
WRAPPING = ("phi", "psi")

# A NaN as loggers write it, any case: `nan`, C's printf `-nan` and `+nan`, C99's `nan(chars)`
# and MSVC's `-nan(ind)`, `NaN(0x7ff8)`: a missing sample
_NAN = re.compile(r"[+-]?nan(\([0-9a-z_]*\))?", re.IGNORECASE)


def read_csv(path: str | Path, name: str | None = None, keep_repeats: bool = False) -> Experiment:
    """Read and validate one measurement CSV.

    A plain table of numbers (what the testbed and spreadsheets write) is parsed in one pass
    (numpy's reader, which gives the same floats as Python's); anything it does not take, or any
    value that fails a check, is read again row by row, which names the line and column at
    fault. A state's stale repeats are missing samples (`stale`) unless `keep_repeats`."""
    path = Path(path)
    text = read_text(path, "a measurement CSV file")
    # newline="": lines end at \n, \r\n or a lone \r (old spreadsheet exports), as csv expects
    lines = io.StringIO(text, newline="")
    reader = csv.reader(lines)
    try:
        first = next(reader, [])
    except csv.Error as exc:
        raise InputError(f"{path}: line {reader.line_num}: {exc}; expected comma-separated numbers") from None
    if not any(c.strip() for c in first):
        raise InputError(f"{path}: empty file; expected a header row with {','.join(CSV_COLUMNS)}")
    header = [c.strip() for c in first]
    for required in ("t",) + INPUTS:
        if required not in header:
            raise InputError(f"{path}: column '{required}' missing; required: t,{','.join(INPUTS)}")
    dup = {c for c in header if header.count(c) > 1 and c in CSV_COLUMNS}
    if dup:
        raise InputError(f"{path}: column '{sorted(dup)[0]}' appears twice")
    measured = tuple(s for s in STATES if s in header)
    if not measured:
        raise InputError(f"{path}: no state column; expected at least one of {','.join(STATES)}")
    wanted = [header.index(c) for c in ("t",) + measured + INPUTS]
    values = _plain_table(text[lines.tell() :], len(header))
    if values is not None:
        values = values[:, wanted]
    if values is None or len(values) < MIN_ROWS or too_large(values[:, 1:]):
        values = _rows(path, header, wanted, reader)
    n = len(measured)
    if not keep_repeats:
        values[:, 1 : 1 + n][stale(values[:, 1 : 1 + n])] = math.nan
    unlogged = np.isnan(values[:, 1 + n :]).any(axis=1)  # a row with a fin field empty
    values, rows = _on_grid(path, _held(path, values, n))
    held = (rows < 0) | unlogged[np.maximum(rows, 0)]
    for j, state in enumerate(measured):
        if np.isnan(values[:, 1 + j]).all():
            raise InputError(f"{path}: column '{state}' has no value; expected at least one sample of it")
    return Experiment(
        name or path.name.removesuffix(".csv"),
        values[:, 0],
        measured,
        _unwrapped(path, values[:, 1 : 1 + n], measured),
        values[:, 1 + n :],
        str(path),
        held=held if held.any() else None,
    )


def stale(states: np.ndarray) -> np.ndarray:
    """Which of the `states` (rows as logged, a column per state, NaN where missing) are stale
    repeats, a sensor slower than its logger's rows writing its last sample again: a value equal
    to its column's previous value present, in a row where some state's value differs from its
    own column's previous one (the row has a fresh sample), in a column where such repeats are
    at least `SLOWER` of its values in those rows (a sensor at most 3/4 of the rows' rate: at
    half of it, every other value is a repeat). Not stale: the repeats of a row in which no state
    changes (no sensor shows an update, and it cannot be told from a body holding still at its
    sensors' resolution), a column's occasional repeats (a quantised reading standing still at a
    turn of the signal: 3-digit headings repeat in a tenth of the rows of a zigzag), and a column
    that holds one value over the whole record (a state held exactly: its repeats are its
    samples)."""
    states = np.asarray(states, dtype=float)
    present = ~np.isnan(states)
    repeat = np.zeros(states.shape, dtype=bool)
    for j, column in enumerate(states.T):
        at = np.flatnonzero(present[:, j])
        repeat[at[1:], j] = column[at[1:]] == column[at[:-1]]
    fresh = np.any(present & ~repeat, axis=1)  # a row with a state that changed
    first = present & (np.cumsum(present, axis=0) == 1)  # each column's first value: no repeat
    counted = present & fresh[:, None] & ~first
    candidates = repeat & fresh[:, None]
    share = candidates.sum(axis=0) / np.maximum(counted.sum(axis=0), 1)
    changes = (present & ~repeat & ~first).any(axis=0)  # a column that holds one value: never stale
    return candidates & ((share >= SLOWER) & changes)[None, :]


def _held(path: Path, values: np.ndarray, n: int) -> np.ndarray:
    """`values` (rows: t, `n` states, the inputs) with each missing input (NaN) held at its last
    recorded value, the zero-order hold the model applies to the fins; `InputError` naming the
    column where the first row has none to hold."""
    fins = values[:, 1 + n :]
    missing = np.isnan(fins)
    if not missing.any():
        return values
    if missing[0].any():
        raise InputError(
            f"{path}: data row 1, column '{INPUTS[int(np.argmax(missing[0]))]}' is empty; expected "
            "the fin angle at the first row (a later gap holds the last recorded value)"
        )
    last = np.where(missing, 0, np.arange(len(fins))[:, None])
    np.maximum.accumulate(last, axis=0, out=last)
    values = values.copy()
    values[:, 1 + n :] = np.take_along_axis(fins, last, axis=0)
    return values


def _on_grid(path: Path, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rows of `values` (t first, then the states, then the inputs) on the record's clock,
    the rule for logs as they come (docs/files.md#measurement-csv): uniform times are kept as
    they are; otherwise the rows go to the points of the grid t0 + jh that `clock` finds (every
    stamp on its own point where the stamps share a clock; a row logged twice counts once; a row
    on the point of the row before it takes the point a median step later where the next row is
    more than 1.5 median steps away: a stale stamp), rows still on one point are merged (each state the mean of the values present, the
    inputs of the last row), and a point without a row has every state missing (NaN) and the
    inputs held from the row before it. With the rows of `values` each point takes its inputs
    from (−1: none, held). `InputError` naming the data row where the time decreases, and for a
    grid longer than `MAX_SAMPLES`."""
    t = values[:, 0]
    dt, off = uniform_step(t)
    if off is None:
        return values, np.arange(len(values))
    with np.errstate(over="ignore", invalid="ignore"):
        back = np.flatnonzero(~(np.diff(t) >= 0))
        if back.size:
            k = int(back[0]) + 1
            raise InputError(
                f"{path}: data row {k + 1}: t = {t[k]:.10g} s after {t[k - 1]:.10g} s; expected "
                "times that never decrease"
            )
        same = (values[1:] == values[:-1]) | (np.isnan(values[1:]) & np.isnan(values[:-1]))
        distinct = np.flatnonzero(np.r_[True, ~same.all(axis=1)])
        values = values[distinct]  # a row logged twice is one row
        t = values[:, 0]
        steps = np.diff(t)
        positive = steps[steps > 0]
        dt = median(positive) if positive.size else math.nan
        if not dt > 0:
            raise InputError(f"{path}: t never increases; expected times in seconds")
        if not (t[-1] - t[0]) / dt < MAX_SAMPLES:  # the coarsest clock the stamps can have
            raise InputError(
                f"{path}: t spans {t[-1] - t[0]:.10g} s at a median step of {dt:.10g} s, more than "
                f"{MAX_SAMPLES} samples; expected at most {MAX_SAMPLES}"
            )
    start, h, j = clock(t, dt)
    if j[-1] + 1 > MAX_SAMPLES:
        raise InputError(
            f"{path}: t spans {t[-1] - t[0]:.10g} s on a clock of {h:.10g} s, a grid of "
            f"{int(j[-1]) + 1} samples; expected at most {MAX_SAMPLES}"
        )
    per = max(1, int(round(dt / h)))  # grid points per median step
    for k in np.flatnonzero(np.diff(j) == 0) + 1:  # a row on the point of the row before it
        if j[k] == j[k - 1] and (k + 1 == len(j) or j[k + 1] - j[k] > 1.5 * per):
            j[k] += per  # a stale stamp: the sample a step later, where no row has its own
    n = int(j[-1]) + 1
    grid = np.full((n, values.shape[1]), np.nan)
    grid[:, 0] = start + np.arange(n) * h
    states = values[:, 1 : values.shape[1] - len(INPUTS)]
    present = ~np.isnan(states)
    sums, counts = np.zeros((n, states.shape[1])), np.zeros((n, states.shape[1]))
    np.add.at(sums, j, np.where(present, states, 0.0))
    np.add.at(counts, j, present)
    with np.errstate(invalid="ignore", divide="ignore"):
        grid[:, 1 : 1 + states.shape[1]] = np.where(counts > 0, sums / counts, np.nan)
    last = np.flatnonzero(np.r_[j[1:] != j[:-1], True])  # the last row on each occupied point
    held = np.zeros(n, dtype=np.int64)
    held[j[last]] = last
    occupied = np.zeros(n, dtype=bool)
    occupied[j[last]] = True
    held = np.maximum.accumulate(np.where(occupied, held, 0))
    grid[:, -len(INPUTS) :] = values[held, -len(INPUTS) :]
    if len(last) < MIN_ROWS:
        raise InputError(f"{path}: {len(last)} distinct stamps; expected at least {MIN_ROWS}")
    return grid, np.where(occupied, distinct[held], -1)


def clock(t: np.ndarray, dt: float) -> tuple[float, float, np.ndarray]:
    """The clock of the stamps `t` (never decreasing, `dt` their median positive step): the grid
    `t0 + j h` and each stamp's point `j` (int, from 0), as `(t0, h, j)`.

    A logger stamps from a clock that ticks every h, and its rows are a whole number of ticks
    apart (0.4 s and 0.6 s alternately: h = 0.2 s; a jittered 50 Hz log stamped in
    milliseconds: h = 1 ms). Where all but a few stamps (at most one per `OFF_CLOCK` rows) lie
    on the clock of the median step, that is the clock and those few go to their nearest ticks
    (`_glitched`). Otherwise h is the coarsest of (least positive step)/k, k = 1, 2, …, on
    which every stamp lies within the rounding of a printed stamp (`uniform_step`'s tolerance),
    and (t0, h) the least-squares line through the stamps at their points: the grid holds every
    stamp exactly, and the record is the same as its stamps. The search stops where the grid
    would hold more than `CLOCK_POINTS` points per row; stamps with no such clock (jittered
    floats) go to the nearest point of the grid at `dt / CLOCK_DIVISIONS` on the least-squares
    line (a timing error of at most `dt / (2 CLOCK_DIVISIONS)`)."""
    t = np.asarray(t, dtype=float)
    steps = np.diff(t)
    least = float(np.min(steps[steps > 0]))
    tol = 1e-6 * least + 1e-9 * float(np.max(np.abs(t)))
    glitched = _glitched(t, dt, tol)
    if glitched is not None:
        return glitched
    most = CLOCK_POINTS * len(t)
    k = 1
    while (t[-1] - t[0]) * k / least < most:
        start, h, j = _line(t, least / k)
        if np.max(np.abs(t - start - j * h)) <= tol:
            return float(t[0]), h, j  # the first stamp as logged: the line's start is within tol of it
        k += 1
    return _line(t, dt / CLOCK_DIVISIONS)


def _glitched(t: np.ndarray, dt: float, tol: float) -> tuple[float, float, np.ndarray] | None:
    """`(t0, h, j)` of the clock of the median step `dt` where every stamp but a few (at least
    one, at most one per `OFF_CLOCK` rows) lies on it, each of those few at its nearest tick (a
    timing error of at most half a step on that row): a logger's glitch, which would otherwise
    make the clock a common divisor of it and the step (one stamp 7 ms early in a 50 Hz log: a
    1 ms clock, 20 ticks a row). None where the stamps are all on it, or more are off it."""
    j = np.concatenate([[0.0], np.cumsum(np.rint(np.diff(t) / dt))])
    r = t - j * dt
    on = np.abs(r - np.median(r)) <= max(tol, 1e-3 * dt)  # on the clock up to its printing
    if not 0 < np.count_nonzero(~on) <= max(1, len(t) // OFF_CLOCK) or np.ptp(j[on]) == 0:
        return None
    start, h, j = _line(t, dt, on)  # the line through the stamps on it, which must hold each of them
    return (start, h, j) if np.max(np.abs(t[on] - start - j[on] * h)) <= tol else None


def _line(t: np.ndarray, h: float, on=slice(None)) -> tuple[float, float, np.ndarray]:
    """`(t0, h', j)`: each step of `t` in whole steps of h (rounded), the least-squares line
    `t0 + j h'` through the stamps `on` (every one by default) at those points (a step's own
    error does not accumulate along the record: the median of ±20 % jittered steps is 0.4 % off,
    12 samples by the end of 3000 rows), and each stamp's nearest point of it, the first at 0."""
    j = np.concatenate([[0.0], np.cumsum(np.rint(np.diff(t) / h))])
    if j[-1] == 0:
        return float(t[0]), h, j.astype(np.int64)
    jc, tc = j[on] - j[on].mean(), t[on] - t[on].mean()
    h = float(jc @ tc / (jc @ jc))
    start = float(t[on].mean() - h * j[on].mean())
    j = np.rint((t - start) / h).astype(np.int64)
    return start + int(j[0]) * h, h, j - j[0]


def _unwrapped(path: Path, y: np.ndarray, measured: Sequence[str]) -> np.ndarray:
    """`y` with each angle that wraps at ±π in logs (`WRAPPING`) made continuous: a column that
    jumps by more than π between two of its values (missing samples skipped) is unwrapped
    (`np.unwrap`: each such jump is taken as a wrap, and whole turns are added from there on), so
    the angle starts at its first value and never jumps by more than π. A column without such a
    jump is left as it is, bit for bit."""
    for j, name in enumerate(measured):
        at = np.flatnonzero(~np.isnan(y[:, j]))
        if name in WRAPPING and np.any(np.abs(np.diff(y[at, j])) > np.pi):
            y[at, j] = np.unwrap(y[at, j])
            large = too_large(y[:, j : j + 1])
            if large:
                raise InputError(
                    f"{path}: column '{name}' unwrapped (it jumps by more than π) reaches "
                    f"{y[large[0], j]:.10g} at data row {large[0] + 1}, {TOO_LARGE}"
                )
    return y


def _plain_table(body: str, columns: int) -> np.ndarray | None:
    """The rows of `body` as a (rows, `columns`) array if every line is `columns` finite numbers
    separated by commas (blank lines aside), else None."""
    if not body.strip():
        return None
    try:
        values = np.loadtxt(io.StringIO(body), delimiter=",", comments=None, ndmin=2)
    except ValueError:
        return None
    return values if values.shape[1] == columns and np.all(np.isfinite(values)) else None


def _rows(path: Path, header: list[str], wanted: list[int], reader) -> np.ndarray:
    """The columns `wanted` (t first) of the data rows still in `reader`, checked value by value:
    `InputError` naming the line and column of the first that is not a finite number within
    ±`MAX_DATA`. A state or input may be missing (an empty field or a NaN, `_NAN`): NaN."""
    rows = []
    try:
        rows.extend(reader)
    except csv.Error as exc:
        raise InputError(f"{path}: line {reader.line_num}: {exc}; expected comma-separated numbers") from None
    body = [(k, r) for k, r in enumerate(rows, start=2) if any(c.strip() for c in r)]
    if len(body) < MIN_ROWS:
        raise InputError(f"{path}: {len(body)} data rows; expected at least {MIN_ROWS}")
    values = np.empty((len(body), len(wanted)))
    for i, (k, row) in enumerate(body):
        if len(row) != len(header):
            raise InputError(f"{path}: line {k} has {len(row)} fields; the header has {len(header)}")
        for j, col in enumerate(wanted):
            field = row[col].strip()
            if j and (not field or _NAN.fullmatch(field)):  # a missing sample
                values[i, j] = math.nan
                continue
            try:
                v = float(field)
            except ValueError:
                raise InputError(
                    f"{path}: line {k}, column '{header[col]}': {row[col][:40]!r} is not a number"
                ) from None
            if not math.isfinite(v):
                raise InputError(
                    f"{path}: line {k}, column '{header[col]}': {field} (expected a finite number"
                    + (")" if j == 0 else ", or empty or NaN for a missing sample)")
                )
            values[i, j] = v
    large = too_large(values[:, 1:])
    if large:
        (i, j), col = large, wanted[large[1] + 1]
        raise InputError(
            f"{path}: line {body[i][0]}, column '{header[col]}': {body[i][1][col].strip()} is {TOO_LARGE}"
        )
    return values


def csv_text(t: np.ndarray, states: np.ndarray, inputs: np.ndarray, measured: Sequence[str] = STATES) -> str:
    """Measurement-CSV text: `states` (N, len(measured)) absolute, `inputs` (N, 3)."""
    out = io.StringIO()
    out.write(",".join(("t",) + tuple(measured) + INPUTS) + "\n")
    np.savetxt(out, np.column_stack([t, states, inputs]), delimiter=",", fmt="%.10g")
    return out.getvalue()


def write_csv(
    path: str | Path, t, states, inputs, measured: Sequence[str] = STATES, force: bool = False
) -> Path:
    """A measurement CSV at `path` (`csv_text`); an existing file is refused unless `force`."""
    return atomic_write_text(path, csv_text(t, states, inputs, measured), force)
