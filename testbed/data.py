"""The files: measurement CSVs, model-config TOML, run directories as data.

Readers validate everything a user can get wrong and raise `InputError` with a one-line message
naming the file and the field; writers go through `atomic_write_text`.
"""

from __future__ import annotations

import codecs
import csv
import io
import json
import math
import numbers
import os
import re
import reprlib
import stat
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Iterable, Mapping, Sequence

import numpy as np

from testbed.errors import InputError, atomic_write_text, check_keys
from testbed.models.linear import (
    BIASES,
    COEFFICIENTS,
    DELAY,
    INPUTS,
    MAX_SPEED,
    MIN_SPEED,
    MOUNTING,
    OFFSETS,
    OUTPUT_TERMS,
    PARAMETERS,
    STATES,
    Vehicle,
)
from testbed.models.components import Component, check_component_name
from testbed.models.nonlinear import INERTIA, NonlinearModel, nonlinear_model, theta_vector
from testbed.models.sensors import OUTPUTS, Sensor, needs, states_from

__all__ = [
    "CLOCK_DIVISIONS",
    "CLOCK_POINTS",
    "CONFIG_SENSOR_KEYS",
    "CSV_COLUMNS",
    "Experiment",
    "MAX_CONSTANT",
    "MAX_DATA",
    "MAX_GAP",
    "MAX_NAME",
    "MAX_SAMPLES",
    "MIN_NOISE_STD",
    "MIN_ROWS",
    "ModelConfig",
    "SLOWER",
    "WRAPPING",
    "check_config",
    "check_excited",
    "check_experiment",
    "check_free",
    "check_per_record",
    "check_name",
    "check_noise_std",
    "clock",
    "config_text",
    "csv_text",
    "load_data",
    "median",
    "number",
    "parse_config",
    "parse_sensor",
    "read_config",
    "read_csv",
    "read_estimates",
    "read_json",
    "read_toml",
    "run_csvs",
    "sensor_table",
    "split",
    "stale",
    "stretch_name",
    "stretches",
    "toml_value",
    "write_config",
    "write_csv",
]

CSV_COLUMNS = ("t",) + STATES + INPUTS
MAX_SAMPLES = 10**6  # the most samples a record's time grid may have
# A log's clock (`clock`): the most grid points per row a clock that holds every stamp may put
# on a record (a 50 Hz log jittered ±20 % and stamped in milliseconds: 20), and the points per
# median step of the grid that stamps with no such clock go to
CLOCK_POINTS = 32
CLOCK_DIVISIONS = 8
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
# The largest magnitude of a vehicle constant or coefficient (SI): a supertanker's yaw inertia is
# ~1e13 kg m², its dimensional coefficients ~1e12. Products of a few such numbers stay finite.
MAX_CONSTANT = 1e15
# A velocity log's mounting (`MOUNTING`): misalignments within ±0.5 rad (a scenario sensor's
# limit: small angles), a position within 50 m of the CG
MOUNTING_LIMITS = {"m_dvl_y": 0.5, "m_dvl_z": 0.5, "r_dvl_x": 50.0, "r_dvl_y": 50.0, "r_dvl_z": 50.0}
# The least measurement-noise σ (SI): the floor that keeps a noise covariance R = σ² positive
# definite in double precision, far below any sensor's noise (1 nrad, 1 nm/s).
MIN_NOISE_STD = 1e-9
# What a model config's `[sensors.NAME]` says of a sensor: what it reads and its known errors
# (its rate and noise are the data's own)
CONFIG_SENSOR_KEYS = ("outputs", "position", "misalignment", "frame", "bias", "scale", "delay")
# The least share of a state column's values, in rows with a fresh sample, that repeat its
# previous one for the column to be read as a sensor slower than the log (`stale`)
SLOWER = 0.25
# Angles that wrap at ±π in a log (`read_csv` unwraps them): roll and heading. Pitch stays
# within ±π/2.
WRAPPING = ("phi", "psi")


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


@dataclass(frozen=True)
class ModelConfig:
    """A model config: the vehicle, the model's parameters (the 35 coefficients, the offsets,
    the output biases, the current, the inputs' delay), and the free ones. With `terms` it is a
    nonlinear model config: the nonlinear model over the terms named (their coefficients), its
    inertia coefficients the `…dot` ones of `coefficients` and its output biases the `b_…` ones
    (the others 0)."""

    vehicle: Vehicle
    coefficients: Mapping[str, float]  # every name in PARAMETERS
    free: tuple[str, ...] = ()
    source: str = ""
    outputs: tuple[str, ...] | None = None  # [identify] outputs: the states fitted (None: all measured)
    # [identify] noise_std: state → the sensors' noise σ (SI), known; None: read off the data
    noise_std: Mapping[str, float] | None = None
    screen: bool = False  # [identify] screen: `free` is a candidate list that `identify` screens
    # [identify] per_record: free names estimated once per record (each experiment its own value)
    per_record: tuple[str, ...] = ()
    # experiment name → {name: value}: a record's own values, where they differ from `coefficients`
    # (an estimate's per-record values, `with_coefficients`)
    record_values: Mapping[str, Mapping[str, float]] = field(default_factory=dict)
    sensors: tuple[Sensor, ...] = ()  # [sensors.NAME]: the sensors whose geometry and errors are known
    terms: Mapping[str, float] | None = None  # [terms]: the nonlinear model's terms, in order; None: linear
    components: tuple[Component, ...] = ()  # [components.NAME]: what the component terms name

    def __post_init__(self):  # a name a config leaves out is 0 (and fixed)
        object.__setattr__(self, "coefficients", dict.fromkeys(PARAMETERS, 0.0) | dict(self.coefficients))

    def record_coefficients(self, name: str) -> dict[str, float]:
        """The coefficients and offsets of the record (experiment) called `name`."""
        return {**self.coefficients, **self.record_values.get(name, {})}

    def readings(self, experiments: Sequence[Experiment]) -> list[Experiment]:
        """The experiments with each of the config's sensors undone (`models.sensors.states_from`):
        their readings turned into the CG's body-axis states, the rate and attitude sensors first
        (the others' lever arms and earth axes use them). Applied once to a record: a record
        keeps the names of the sensors already undone. `InputError` for a record without a
        sensor's outputs, or without the rates or attitude its correction needs."""
        order = sorted(
            self.sensors, key=lambda s: not set(s.outputs) & {"p", "q", "r", "phi", "theta", "psi"}
        )
        out = []
        for e in experiments:
            for sensor in (s for s in order if s.name not in e.sensors):
                e = _undone(e, sensor, self.source or "config")
            out.append(e)
        return out

    def fitted(self, experiments: Sequence[Experiment]) -> list[Experiment]:
        """The experiments, the config's sensors undone (`readings`), reduced to the config's
        outputs (all of them without `outputs`). Each record keeps the outputs it measures;
        `InputError` for an output that no record measures, or a record that measures none."""
        experiments = self.readings(experiments)
        if self.outputs is None:
            return list(experiments)
        measured = {s for e in experiments for s in e.measured}
        missing = [s for s in self.outputs if s not in measured]
        if missing:
            raise InputError(
                f"{self.source or 'config'}: [identify] outputs names {', '.join(missing)}, which no "
                f"record measures (they measure {', '.join(s for s in STATES if s in measured)}); "
                "expected measured states, or no outputs to fit every measured state"
            )
        return [e.only(self.outputs) for e in experiments]

    def with_coefficients(self, values: Mapping[str, float]) -> "ModelConfig":
        """The config with `values` set: coefficients and offsets by name (a nonlinear model
        config's terms among them), and a record's own value as `name[experiment]` (an
        estimate's per-record values)."""
        terms = self.terms
        if terms is not None:
            terms = {n: values.get(n, v) for n, v in terms.items()}
            values = {n: v for n, v in values.items() if n not in terms}
        shared = {n: v for n, v in values.items() if not n.endswith("]")}
        records = {e: dict(v) for e, v in self.record_values.items()}
        for n, v in values.items():
            if n.endswith("]"):
                name, experiment = n[:-1].split("[", 1)
                records.setdefault(experiment, {})[name] = v
        return replace(self, coefficients={**self.coefficients, **shared}, record_values=records, terms=terms)

    @property
    def values(self) -> dict[str, float]:
        """Every parameter's value by name: the coefficients and offsets, and a nonlinear model
        config's terms."""
        return {**self.coefficients, **(self.terms or {})}

    def nonlinear(self) -> tuple[NonlinearModel, np.ndarray]:
        """A nonlinear model config's model and its θ (`models.nonlinear`: the inertia
        coefficients, then the terms)."""
        model = nonlinear_model(self.vehicle, tuple(self.terms), self.components)
        return model, theta_vector(model, {**{n: self.coefficients[n] for n in INERTIA}, **self.terms})

    def output_biases(self, states: Sequence[str]) -> np.ndarray:
        """The output biases `b_<state>` of `states`, in their order: y = x + b."""
        return np.array([self.coefficients[f"b_{s}"] for s in states], float)

    def mounting(self) -> np.ndarray:
        """The velocity log's mounting (5,), `MOUNTING` order: 0 at the CG, aligned."""
        return np.array([self.coefficients[n] for n in MOUNTING], float)

    def with_noise_std(self, values: Mapping[str, float] | None, where: str = "noise_std") -> "ModelConfig":
        """The config with `values` (state → σ, checked as `where`) replacing its `noise_std`
        entry by entry; the states `values` leaves out keep the config's σ."""
        if not values:
            return self
        merged = {**(self.noise_std or {}), **check_noise_std(values, where)}
        return replace(self, noise_std={s: merged[s] for s in STATES if s in merged})


def _undone(e: Experiment, sensor: Sensor, source: str) -> Experiment:
    """`e` with `sensor`'s readings turned into the states they measure (`ModelConfig.readings`)."""
    where = f"{e.source or e.name}: {source}'s sensors.{sensor.name}"
    missing = [o for o in sensor.outputs if o not in e.measured]
    if missing:
        raise InputError(f"{where} outputs {', '.join(missing)}, which the record has no column for")
    wants = needs(sensor)
    given = []
    for need, names in zip(wants, (("p", "q", "r"), ("phi", "theta", "psi"))):
        lacking = [n for n in names if n not in e.measured]
        if need and lacking:
            raise InputError(f"{where} needs {', '.join(names)} to be undone; the record has no {lacking[0]}")
        given.append(np.column_stack([e.column(n) for n in names]) if need else None)
    y = np.asarray(e.y, dtype=float).copy()
    cols = [e.measured.index(o) for o in sensor.outputs]
    states = states_from(sensor, np.asarray(e.t, float), y[:, cols], *given)
    for o, k in zip(sensor.outputs, cols):
        y[:, k] = states[o]
    return replace(e, y=y, sensors=e.sensors + (sensor.name,))


def read_text(path: str | Path, expected: str) -> str:
    """The text of a regular file or a pipe: UTF-8 (or UTF-16 after its byte-order mark, as
    spreadsheets export "Unicode text"), a byte-order mark dropped, undecodable bytes replaced
    (they can only be in names or cells that are then reported or ignored). Anything else (a
    folder, a device that never ends such as /dev/zero) is an `InputError`."""
    path = Path(path)
    try:
        mode = os.stat(path).st_mode
        if stat.S_ISDIR(mode):
            raise InputError(f"{path}: is a folder; expected {expected}")
        if not (stat.S_ISREG(mode) or stat.S_ISFIFO(mode)):
            raise InputError(f"{path}: is not a regular file; expected {expected}")
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror or exc})") from None
    utf16 = data.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE))
    return data.decode("utf-16" if utf16 else "utf-8-sig", errors="replace")


def read_toml(path: str | Path, expected: str) -> dict:
    """The document of the TOML file at `path` (`read_text`); `InputError` naming the file where
    it is not valid TOML, nested too deeply to read included (a recursive parser's stack)."""
    try:
        return tomllib.loads(read_text(path, expected))
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{path}: not valid TOML ({exc}); expected {expected}") from None
    except RecursionError:
        raise InputError(f"{path}: not valid TOML (nested too deeply); expected {expected}") from None


def read_json(path: str | Path, expected: str):
    """The document of the JSON file at `path` (`read_text`); `InputError` naming the file where
    it is not valid JSON, nested too deeply to read included."""
    try:
        return json.loads(read_text(path, expected))
    except RecursionError:
        raise InputError(f"{path}: not valid JSON (nested too deeply); expected {expected}") from None
    except ValueError as exc:
        raise InputError(f"{path}: not valid JSON ({exc}); expected {expected}") from None


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


def _too_large(values: np.ndarray) -> tuple[int, int] | None:
    """(row, column) of the first value beyond ±`MAX_DATA`, or None."""
    bad = np.abs(values) > MAX_DATA
    return tuple(map(int, np.argwhere(bad)[0])) if bad.any() else None


_TOO_LARGE = f"beyond ±{MAX_DATA:g}; expected a plausible SI value (m, m/s, rad, rad/s)"
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
    if values is None or len(values) < MIN_ROWS or _too_large(values[:, 1:]):
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
    milliseconds: h = 1 ms). h is the coarsest of (least positive step)/k, k = 1, 2, …, on
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
    most = CLOCK_POINTS * len(t)
    k = 1
    while (t[-1] - t[0]) * k / least < most:
        start, h, j = _line(t, least / k)
        if np.max(np.abs(t - start - j * h)) <= tol:
            return float(t[0]), h, j  # the first stamp as logged: the line's start is within tol of it
        k += 1
    return _line(t, dt / CLOCK_DIVISIONS)


def _line(t: np.ndarray, h: float) -> tuple[float, float, np.ndarray]:
    """`(t0, h', j)`: each step of `t` in whole steps of h (rounded), the least-squares line
    `t0 + j h'` through the stamps at those points (a step's own error does not accumulate
    along the record: the median of ±20 % jittered steps is 0.4 % off, 12 samples by the end of
    3000 rows), and each stamp's nearest point of it, the first at 0."""
    j = np.concatenate([[0.0], np.cumsum(np.rint(np.diff(t) / h))])
    if j[-1] == 0:
        return float(t[0]), h, j.astype(np.int64)
    jc, tc = j - j.mean(), t - t.mean()
    h = float(jc @ tc / (jc @ jc))
    start = float(t.mean() - h * j.mean())
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
            large = _too_large(y[:, j : j + 1])
            if large:
                raise InputError(
                    f"{path}: column '{name}' unwrapped (it jumps by more than π) reaches "
                    f"{y[large[0], j]:.10g} at data row {large[0] + 1}, {_TOO_LARGE}"
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
    large = _too_large(values[:, 1:])
    if large:
        (i, j), col = large, wanted[large[1] + 1]
        raise InputError(
            f"{path}: line {body[i][0]}, column '{header[col]}': {body[i][1][col].strip()} is {_TOO_LARGE}"
        )
    return values


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
        large = _too_large(a)
        if large:
            k, j = large
            raise InputError(f"{name}: {columns[j]} = {a[k, j]:g} at t = {t[k]:g} s is {_TOO_LARGE}")
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


def read_config(path: str | Path) -> ModelConfig:
    """Read and validate a model config TOML."""
    return parse_config(read_toml(path, "a model config TOML file"), str(path))


# the vehicle constants every config gives; `Iy` may be left out where no state the data give
# depends on the pitch row (`problem.check_inputs`), `zB` where `GM` is given, and so may the
# metacentric heights `GM`, `GM_L` (docs/model.md#the-equations)
_REQUIRED = ("mass", "Ix", "Iz", "weight", "buoyancy", "xB", "yB", "speed")
# what each vehicle constant must be, beyond a finite number within ±MAX_CONSTANT
_VEHICLE_RANGES = {
    "mass": (0.0, "> 0 (kg)"),
    "Ix": (0.0, "> 0 (kg m²)"),
    "Iy": (0.0, "> 0 (kg m²)"),
    "Iz": (0.0, "> 0 (kg m²)"),
    "weight": (0.0, "> 0 (N)"),
    "buoyancy": (0.0, "> 0 (N)"),
    "speed": (MIN_SPEED, f"{MIN_SPEED:g} to {MAX_SPEED:g} (m/s, the trim speed)"),
}


def parse_config(doc: Mapping, source: str = "<config>") -> ModelConfig:
    """Validate a parsed model-config document."""
    for table in ("vehicle", "coefficients"):
        if not isinstance(doc.get(table), dict):
            raise InputError(f"{source}: table [{table}] missing")
    veh = doc["vehicle"]
    values = {}
    for key in Vehicle.names():
        if key in veh:
            values[key] = number(veh[key], f"{source}: [vehicle] {key}")
        elif key in _REQUIRED or (key == "zB" and "GM" not in veh):
            raise InputError(
                f"{source}: [vehicle] {key} missing; expected a number (SI)"
                + ("" if key in _REQUIRED else ", or GM (a floating body's metacentric height)")
            )
        else:
            values[key] = None
    for key in set(veh) - set(Vehicle.names()):
        raise InputError(
            f"{source}: [vehicle] {key} is not a vehicle constant; "
            f"expected one of {', '.join(Vehicle.names())}"
        )
    coefficients = dict.fromkeys(PARAMETERS, 0.0)
    for key, v in doc["coefficients"].items():
        if key not in coefficients:
            raise InputError(
                f"{source}: [coefficients] {key} is not a coefficient name; expected one of the linear model's 35 coefficients, 6 offsets, 10 output biases, the current, the velocity log's mounting or input_delay (docs/model.md)"
            )
        coefficients[key] = number(v, f"{source}: [coefficients] {key}")
    ident = doc.get("identify", {})
    free = ident.get("free", []) if isinstance(ident, dict) else None
    if not isinstance(free, list) or not all(isinstance(n, str) for n in free):
        raise InputError(f"{source}: [identify] free must be a list of coefficient names")
    outputs = ident.get("outputs") if isinstance(ident, dict) else None
    if outputs is not None:
        if not isinstance(outputs, list) or not all(isinstance(s, str) for s in outputs):
            raise InputError(f"{source}: [identify] outputs must be a list of state names")
        outputs = tuple(s for s in STATES if s in outputs) + tuple(s for s in outputs if s not in STATES)
    noise = ident.get("noise_std") if isinstance(ident, dict) else None
    if noise is not None:
        noise = check_noise_std(noise, f"{source}: [identify] noise_std") or None
    screen = ident.get("screen", False)
    if not isinstance(screen, bool):
        raise InputError(f"{source}: [identify] screen = {screen!r}; expected true or false")
    per_record = ident.get("per_record", []) if isinstance(ident, dict) else []
    if not isinstance(per_record, list) or not all(isinstance(n, str) for n in per_record):
        raise InputError(f"{source}: [identify] per_record must be a list of names from free")
    tables = doc.get("sensors", {})
    if not isinstance(tables, Mapping):
        raise InputError(f"{source}: [sensors] must hold [sensors.NAME] tables")
    sensors = tuple(parse_sensor(k, v, f"{source}: sensors.{k}") for k, v in tables.items())
    for sensor in sensors:
        if set(sensor.outputs) - set(STATES):
            raise InputError(
                f"{source}: sensors.{sensor.name}.outputs {list(sensor.outputs)}; expected states "
                f"({', '.join(STATES)}): the model has no specific force"
            )
    seen = [o for s_ in sensors for o in s_.outputs]
    twice = sorted({o for o in seen if seen.count(o) > 1})
    if twice:
        raise InputError(f"{source}: [sensors] read {twice[0]} twice; expected each state from one sensor")
    terms = doc.get("terms")
    if terms is not None:
        if not isinstance(terms, dict):
            raise InputError(f"{source}: [terms] must be a table of term names and their values")
        terms = {k: number(v, f"{source}: [terms] {json.dumps(k)}") for k, v in terms.items()}
    components = _components(doc.get("components"), terms, source)
    config = ModelConfig(
        Vehicle(**values),
        coefficients,
        tuple(free),
        source,
        outputs,
        noise,
        screen,
        tuple(per_record),
        sensors=sensors,
        terms=terms,
        components=components,
    )
    check_config(config)
    return config


# a [components.NAME] table's keys: the required, then the optional (a fin blade's hinge)
_COMPONENT_KEYS = ("axes", "centre", "frame", "moments", "density", "added_mass")
_BLADE_KEYS = ("fin", "hinge", "hinge_axis")


def _components(tables, terms, source: str) -> tuple[Component, ...]:
    """The [components.NAME] tables as `Component`s; `InputError` naming the table and key."""
    if tables is None:
        return ()
    if terms is None:
        raise InputError(
            f"{source}: [components] in a linear model config; expected them only beside [terms] "
            "(the nonlinear model's component terms name them)"
        )
    if not isinstance(tables, Mapping) or not all(isinstance(t, Mapping) for t in tables.values()):
        raise InputError(f"{source}: [components] must hold [components.NAME] tables")
    out = []
    for name, table in tables.items():
        check_component_name(name, f"{source}: [components]")
        where = f"{source}: [components.{name}]"
        check_keys(table, _COMPONENT_KEYS + _BLADE_KEYS, where)
        missing = [k for k in _COMPONENT_KEYS if k not in table]
        if missing:
            raise InputError(f"{where} {missing[0]} missing; expected {', '.join(_COMPONENT_KEYS)}")
        stray = [k for k in _BLADE_KEYS if k in table and "fin" not in table]
        if stray:
            raise InputError(
                f"{where} {stray[0]} without fin; expected a blade's hinge with its fin (dr, der, del)"
            )
        values = {k: table[k] for k in _COMPONENT_KEYS + _BLADE_KEYS if k in table}
        for k, v in values.items():
            if k == "fin":
                continue
            if k == "density":
                values[k] = number(v, f"{where} density")
            elif isinstance(v, list):
                rows = v if k == "frame" else [v]
                for row in rows:
                    if not isinstance(row, list):
                        raise InputError(f"{where} {k} = {v!r}; expected rows of numbers")
                    for x in row:
                        number(x, f"{where} {k}")
            else:
                raise InputError(f"{where} {k} = {v!r}; expected a list of numbers")
        try:
            out.append(Component(name=name, **values))
        except InputError as exc:
            raise InputError(f"{where}: {exc}") from None
    return tuple(out)


def check_config(config: ModelConfig) -> None:
    """`InputError` unless `config` holds a physical vehicle (`_VEHICLE_RANGES`), the model's
    parameters (`PARAMETERS`) as finite numbers within ±`MAX_CONSTANT`, and distinct free names."""
    source = config.source or "config"
    for key in Vehicle.names():
        if getattr(config.vehicle, key) is None and (
            key not in _REQUIRED + ("zB",) or config.vehicle.GM is not None
        ):
            continue  # an optional constant left out
        v = number(getattr(config.vehicle, key), f"{source}: [vehicle] {key}")
        low, expected = _VEHICLE_RANGES.get(key, (None, ""))
        high = MAX_SPEED if key == "speed" else math.inf
        if low is not None and not ((v > low if low == 0.0 else v >= low) and v <= high):
            raise InputError(f"{source}: [vehicle] {key} = {v:g}; expected {expected}")
    for key, v in config.coefficients.items():
        if key not in PARAMETERS:
            raise InputError(
                f"{source}: [coefficients] {key} is not a coefficient name; expected one of the linear model's 35 coefficients, 6 offsets, 10 output biases, the current, the velocity log's mounting or input_delay (docs/model.md)"
            )
        number(v, f"{source}: [coefficients] {key}")
        if key in MOUNTING and not abs(v) <= MOUNTING_LIMITS[key]:
            unit = "rad (a small misalignment)" if key.startswith("m_") else "m from the CG"
            raise InputError(
                f"{source}: [coefficients] {key} = {v:g}; expected within ±{MOUNTING_LIMITS[key]:g} {unit}"
            )
    if config.terms is not None:
        _check_terms(config, source)
    else:
        check_free(config.free, f"{source}: [identify] free")
    check_per_record(config.per_record, config.free, f"{source}: [identify] per_record")
    if config.outputs is not None and (not config.outputs or any(s not in STATES for s in config.outputs)):
        raise InputError(
            f"{source}: [identify] outputs = {list(config.outputs)!r}; expected a non-empty "
            f"list of states ({', '.join(STATES)})"
        )
    if config.noise_std is not None:
        check_noise_std(config.noise_std, f"{source}: [identify] noise_std")


def check_noise_std(noise, where: str) -> dict[str, float]:
    """`noise` as a dict state → σ in `STATES` order once it is a mapping of state names to
    numbers from `MIN_NOISE_STD` to `MAX_DATA` (SI); InputError naming `where` and the first
    entry that is not."""
    if not isinstance(noise, Mapping):
        shown = str(noise).lower() if isinstance(noise, bool) else repr(noise)[:40]
        raise InputError(
            f"{where} = {shown}; expected a table of state = σ (SI), e.g. {{r = 0.002, psi = 0.01}}"
        )
    for name, v in noise.items():
        if name not in STATES:
            raise InputError(f"{where} names {str(name)[:40]!r}, not a state (one of {', '.join(STATES)})")
        v = number(v, f"{where}: {name}")
        if not MIN_NOISE_STD <= v <= MAX_DATA:
            raise InputError(
                f"{where}: {name} = {v:g}; expected a σ from {MIN_NOISE_STD:g} to {MAX_DATA:g} (SI)"
            )
    return {s: float(noise[s]) for s in STATES if s in noise}


def parse_sensor(name: str, doc, where: str, keys: Sequence[str] = CONFIG_SENSOR_KEYS) -> Sensor:
    """The `Sensor` of a `[sensors.NAME]` table with the keys `keys` (`where`: the file and
    table, for messages)."""
    check_name(name, f"{where}: sensor name")
    if not isinstance(doc, Mapping):
        raise InputError(f"{where}: expected a table")
    check_keys(doc, keys, where)
    outs = doc.get("outputs")
    if not isinstance(outs, list) or not all(isinstance(o, str) for o in outs):
        raise InputError(f"{where}.outputs = {outs!r}; expected a list of {', '.join(OUTPUTS)}")
    kw = {"outputs": tuple(outs)}
    for key in ("position", "misalignment"):
        if key in doc:
            v = doc[key]
            if not isinstance(v, list) or len(v) != 3:
                raise InputError(f"{where}.{key} = {v!r}; expected a list of three numbers")
            kw[key] = tuple(number(a, f"{where}.{key}") for a in v)
    if "frame" in doc:
        kw["frame"] = doc["frame"]
    for key in ("delay", "rate"):
        if key in doc:
            kw[key] = number(doc[key], f"{where}.{key}")
    if "hold" in doc:
        kw["hold"] = doc["hold"]
    for key in ("bias", "scale", "noise_std", "resolution"):
        table = doc.get(key, {})
        if not isinstance(table, Mapping):
            raise InputError(f"{where}.{key}: expected a table of output = value")
        kw[key] = {o: number(v, f"{where}.{key}.{o}") for o, v in table.items()}
    try:
        return Sensor(name=name, **kw)
    except InputError as exc:
        raise InputError(f"{where.rsplit(': ', 1)[0]}: {exc}") from None


def sensor_table(s: Sensor) -> dict:
    """The `[sensors.NAME]` table of a sensor (`parse_sensor` reads it back to an equal one)."""
    out = {
        "outputs": list(s.outputs),
        "position": list(s.position),
        "misalignment": list(s.misalignment),
        "frame": s.frame,
        "bias": dict(s.bias),
        "scale": dict(s.scale),
        "delay": s.delay,
    }
    if s.rate is not None:
        out["rate"] = s.rate
    if s.noise_std:
        out["noise_std"] = dict(s.noise_std)
    if s.resolution:
        out["resolution"] = dict(s.resolution)
    if s.hold:
        out["hold"] = True
    return out


def check_free(free: Sequence[str], where: str) -> tuple[str, ...]:
    """`free` as a tuple once every entry is a coefficient or offset name (`PARAMETERS`) listed
    once; InputError naming `where` and the first entry that is not."""
    seen = set()
    for n in free:
        if n not in PARAMETERS:
            raise InputError(
                f"{where} names {n!r}, not a coefficient (one of {', '.join(COEFFICIENTS)}), "
                f"an offset (one of {', '.join(OFFSETS)}), an output bias (b_ and a state), the current (c_N, c_E), "
                f"the velocity log's mounting ({', '.join(MOUNTING)}) or input_delay"
            )
        if n in seen:
            raise InputError(f"{where} names a coefficient twice ({n})")
        seen.add(n)
    return tuple(free)


def check_per_record(per_record: Sequence[str], free: Sequence[str], where: str) -> tuple[str, ...]:
    """`per_record` as a tuple once every entry is a free name listed once; InputError naming
    `where` and the first entry that is not."""
    seen = set()
    for n in per_record:
        if n not in free:
            raise InputError(f"{where} names {n[:40]!r}, which free does not list; expected names from free")
        if n in seen:
            raise InputError(f"{where} names {n} twice")
        seen.add(n)
    return tuple(per_record)


def _check_terms(config: ModelConfig, source: str) -> None:
    """`InputError` unless a nonlinear model config's terms make a nonlinear model of its vehicle
    (`models.nonlinear.nonlinear_model`: term names, each once, a submerged body), with finite
    values, its linear parameters but the inertia coefficients and the output biases 0, and
    `free` among its names and the output biases."""
    names = [c.name for c in config.components]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise InputError(f"{source}: [components.{twice[0]}] given twice; expected each component once")
    try:
        model = nonlinear_model(config.vehicle, tuple(config.terms), config.components)
    except InputError as exc:
        raise InputError(f"{source}: [terms] {exc}") from None
    for key, v in config.terms.items():
        number(v, f"{source}: [terms] {json.dumps(key)}")
    extra = [k for k, v in config.coefficients.items() if v != 0.0 and k not in INERTIA + BIASES + MOUNTING]
    if extra:
        raise InputError(
            f"{source}: [coefficients] {extra[0]} in a nonlinear model config (one with [terms]); "
            f"expected only the inertia coefficients ({', '.join(INERTIA)}), the output biases "
            "(b_ and a state) and the velocity log's mounting, the rest in [terms]"
        )
    seen = set()
    for n in config.free:
        if n not in model.names + BIASES + MOUNTING or n in seen:
            raise InputError(
                f"{source}: [identify] free names {n[:40]!r}"
                + (
                    " twice"
                    if n in seen
                    else ", not an inertia coefficient, an output bias, the velocity log's mounting or one of [terms]"
                )
                + "; expected each of the model's names once"
            )
        seen.add(n)


def number(v, where: str) -> float:
    """`v` as a float; `InputError` unless it is a finite number within ±`MAX_CONSTANT`."""
    if isinstance(v, bool) or not isinstance(v, numbers.Real):
        shown = str(v).lower() if isinstance(v, bool) else repr(v)[:40]  # as TOML writes it
        raise InputError(f"{where} = {shown}; expected a finite number")
    if isinstance(v, numbers.Integral):  # an integer of any size: compared before it becomes a float
        value = float(v) if abs(v) <= MAX_CONSTANT else math.inf
        shown = str(v) if len(str(v)) <= 20 else f"an integer of {len(str(abs(v)))} digits"
    else:
        value, shown = float(v), str(v)
        if not math.isfinite(value):
            raise InputError(f"{where} = {v!r}; expected a finite number")
    if abs(value) > MAX_CONSTANT:
        raise InputError(f"{where} = {shown}; expected a magnitude of at most {MAX_CONSTANT:g} (SI)")
    return value


_SCREEN_NOTE = (
    "screen = true: free is a candidate list; identify fixes the candidates these data do not "
    "determine (docs/cli.md#the-screen); without it free is estimated as written"
)


def config_text(config: ModelConfig, comments: Mapping[str, str] | None = None) -> str:
    """TOML text of a model config; `comments` annotate vehicle constants or coefficients."""
    comments = comments or {}

    def line(key, value):
        note = f"  # {comments[key]}" if key in comments else ""
        return f"{key} = {float(value)!r}{note}"

    lines = ["[vehicle]"] + [
        line(k, getattr(config.vehicle, k)) for k in Vehicle.names() if getattr(config.vehicle, k) is not None
    ]
    if config.terms is None:
        lines += ["", "[coefficients]"] + [line(k, config.coefficients.get(k, 0.0)) for k in COEFFICIENTS]
        lines += [
            line(k, config.coefficients.get(k, 0.0))
            for k in OFFSETS + OUTPUT_TERMS + (DELAY,)
            if config.coefficients.get(k, 0.0) != 0.0 or k in config.free
        ]
    else:  # a nonlinear model config: its inertia coefficients, then its terms (names quoted: `|`)
        lines += ["", "[coefficients]"] + [line(k, config.coefficients.get(k, 0.0)) for k in INERTIA]
        lines += [
            line(k, config.coefficients[k])
            for k in BIASES + MOUNTING
            if config.coefficients[k] != 0.0 or k in config.free
        ]
        lines += ["", "[terms]"] + [
            f"{json.dumps(k)} = {float(v)!r}" + (f"  # {comments[k]}" if k in comments else "")
            for k, v in config.terms.items()
        ]
    lines += ["", "[identify]"]
    if config.screen:
        lines += [f"# {_SCREEN_NOTE}", "screen = true"]
    lines += ["free = [" + ", ".join(f'"{n}"' for n in config.free) + "]"]
    if config.per_record:
        lines += ["per_record = [" + ", ".join(f'"{n}"' for n in config.per_record) + "]"]
    if config.outputs is not None:
        note = f"  # {comments['outputs']}" if "outputs" in comments else ""
        lines.append("outputs = [" + ", ".join(f'"{s}"' for s in config.outputs) + "]" + note)
    if config.noise_std:
        note = f"  # {comments['noise_std']}" if "noise_std" in comments else ""
        pairs = ", ".join(f"{s} = {float(v)!r}" for s, v in config.noise_std.items())
        lines.append(f"noise_std = {{{pairs}}}{note}")
    for sensor in config.sensors:
        lines += ["", f"[sensors.{json.dumps(sensor.name)}]"]
        lines += [f"{k} = {toml_value(v)}" for k, v in sensor_table(sensor).items()]
    for c in config.components:
        lines += ["", f"[components.{c.name}]"]
        lines += [f"{k} = {toml_value(getattr(c, k))}" for k in _COMPONENT_KEYS]
        if c.fin is not None:
            lines += [f"{k} = {toml_value(getattr(c, k))}" for k in _BLADE_KEYS]
    return "\n".join(lines + [""])


def toml_value(v) -> str:
    """A TOML value: strings, exact floats (repr round-trips), ints, lists and inline tables."""
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return repr(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, Mapping):
        return "{" + ", ".join(f"{k} = {toml_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(f"no TOML form for {v!r}")


def write_config(path: str | Path, config: ModelConfig, comments=None, force: bool = False) -> Path:
    """A model config at `path` (`config_text`); an existing file is refused unless `force`."""
    return atomic_write_text(path, config_text(config, comments), force)


def read_estimates(
    path: str | Path, names: Sequence[str] | None = None
) -> tuple[dict[str, float], dict[str, float] | None]:
    """The coefficients and offsets (name → value) of an estimates JSON, without the values
    estimated per record, and its `noise_std` (state → σ) when it has one of positive numbers,
    else None; InputError naming the file. `names`: a nonlinear model's names (its inertia
    coefficients, terms and output biases), which its coefficients must be among instead of the linear model's."""
    expected = "an estimates JSON with coefficients {name: {value: ...}}"
    doc = read_json(path, expected)
    try:
        values = {n: c["value"] for n, c in doc["coefficients"].items()}
    except (KeyError, TypeError, AttributeError):
        raise InputError(f"{path}: expected {expected}") from None
    # a value estimated per record (`name[experiment]`) belongs to that record, not to the vehicle
    values = {n: v for n, v in values.items() if not (n.endswith("]") and n.split("[")[0] in PARAMETERS)}
    for n, v in values.items():
        if names is not None and n not in names:
            raise InputError(
                f"{path}: coefficient {n[:40]!r} is not one of the nonlinear model config's names; "
                "expected its inertia coefficients, [terms] or output biases"
            )
        if names is None and n not in PARAMETERS:
            raise InputError(
                f"{path}: coefficient {n[:40]!r} is not a coefficient name; expected one of the linear model's 35 coefficients, 6 offsets, 10 output biases, the current or input_delay (docs/model.md)"
            )
        values[n] = number(v, f"{path}: coefficient {n}")
    noise = doc.get("noise_std")
    if not (
        isinstance(noise, Mapping)
        and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and 0 < v < math.inf
            for v in noise.values()
        )
    ):
        noise = None
    else:
        noise = {k: float(v) for k, v in noise.items() if k in STATES}
    return {n: float(v) for n, v in values.items()}, noise


def run_csvs(run: Path) -> list[Path]:
    """The measurement CSVs of a run directory: the experiments its `manifest.json` lists, or
    without a manifest every `*.csv` but the `.truth.csv` and `.history.csv` files."""
    manifest = run / "manifest.json"
    if os.path.lexists(manifest):
        names = _manifest_experiments(manifest)
        files = [run / f"{n}.csv" for n in names]
        for f in files:
            if not f.is_file():
                raise InputError(f"{f}: missing; {manifest} lists experiment {f.name.removesuffix('.csv')!r}")
    else:
        files = sorted(f for f in run.glob("*.csv") if not f.name.endswith((".truth.csv", ".history.csv")))
    if not files:
        raise InputError(f"{run}: no measurement CSV in this directory")
    return files


MAX_NAME = 100  # bytes (UTF-8) of a name that becomes a file name, with room for suffixes in 255


def check_name(name: str, where: str) -> str:
    """`name` if it can be a file or folder name by itself (an experiment's CSV, a scenario's run
    directory): a string of 1 to `MAX_NAME` bytes in UTF-8, without a folder separator (/ or \\)
    or a control character (NUL included), not starting with a dot (a hidden file, `.` and `..`);
    `InputError` naming `where` otherwise."""
    if not isinstance(name, str):
        raise InputError(f"{where} {reprlib.repr(name)}; expected a string")
    size = len(name.encode("utf-8", errors="replace"))
    if not 0 < size <= MAX_NAME or name.startswith(".") or any(c in "/\\" or c < " " for c in name):
        raise InputError(
            f"{where} {reprlib.repr(name)}{f' ({size} bytes)' if size > MAX_NAME else ''}; "
            f"expected a file name of 1 to {MAX_NAME} bytes, without / or \\, "
            "control characters or a leading dot"
        )
    return name


def _manifest_experiments(manifest: Path) -> list[str]:
    """The experiment names a run's manifest lists: distinct file names (no folder part)."""
    expected = f"{manifest}: expected JSON with an 'experiments' list of names"
    try:
        names = read_json(manifest, "a run manifest (JSON) with an 'experiments' list")["experiments"]
    except (KeyError, TypeError, IndexError):
        raise InputError(expected) from None
    if not (isinstance(names, list) and all(isinstance(n, str) for n in names)):
        raise InputError(expected)
    for n in names:
        check_name(n, f"{manifest}: experiment")
    if len(set(names)) != len(names):
        raise InputError(
            f"{manifest}: experiment {sorted(n for n in names if names.count(n) > 1)[0]!r} is listed twice"
        )
    return names


def load_data(
    paths: Iterable[str | Path], keep_repeats: bool = False
) -> tuple[list[Experiment], ModelConfig | None]:
    """Experiments from run directories and/or CSVs, and the run's `model.toml` if there is one;
    `keep_repeats` as for `read_csv`.

    A run directory contributes the experiments its `manifest.json` lists, or without a manifest
    every `<experiment>.csv` but the `.truth.csv` files (so outputs written beside them, such as
    filter histories, are not mistaken for experiments). A file given twice is an error; two
    experiments of one name (say `horizontal` of two runs) are told apart by their folders.
    """
    experiments: list[Experiment] = []
    config = None
    for p in map(Path, paths):
        if p.is_dir():
            experiments += [read_csv(f, keep_repeats=keep_repeats) for f in run_csvs(p)]
            if config is None and os.path.lexists(p / "model.toml"):
                config = read_config(p / "model.toml")
        elif os.path.lexists(p):
            experiments.append(read_csv(p, keep_repeats=keep_repeats))
        else:
            raise InputError(f"{p}: no such file or run directory")
    if not experiments:
        raise InputError("no data given; expected run directories or measurement CSVs")
    files = [os.path.realpath(e.source) for e in experiments]
    for e, f in zip(experiments, files):
        if files.count(f) > 1:
            raise InputError(f"{e.source}: given twice; expected each experiment once")
    names = [e.name for e in experiments]
    return [
        replace(e, name=str(Path(e.source).with_suffix(""))) if names.count(e.name) > 1 else e
        for e in experiments
    ], config
