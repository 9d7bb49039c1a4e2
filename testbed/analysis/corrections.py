"""A compatibility check's corrections applied to data (`identify --corrections`): read from a
check JSON, checked against their limits, and undone on the records.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
from scipy.interpolate import CubicSpline

from testbed.analysis.compatibility_checks import (
    LEVER_ARMS,
    ATTITUDE,
    CHECKS,
    MAX_OFFSET,
    MISALIGNMENTS,
    ATTITUDE_OFFSETS,
    SENSOR_PARAMETERS,
    limit_of,
)
from testbed.analysis.compatibility_records import channel_samples, misaligned
from testbed.data import MAX_DATA, Experiment, read_json
from testbed.errors import InputError

__all__ = ["check_corrections", "corrected", "read_corrections"]


def check_corrections(values, where: str) -> dict[str, float]:
    """`values` (sensor parameter → number) checked: known names, finite numbers, biases within
    ±`MAX_DATA`, attitude offsets within ±`MAX_OFFSET` rad, scale factors within ±`MAX_SCALE`,
    misalignments within ±`MAX_MISALIGNMENT` rad, lever arms within ±`MAX_ARM` m, delays within
    ±`MAX_DELAY` s (`limit_of`)."""
    if not isinstance(values, Mapping):
        raise InputError(f'{where}: expected an object of sensor parameters, e.g. {{"b_r": 0.002}}')
    out = {}
    for n, v in values.items():
        if n not in SENSOR_PARAMETERS:
            raise InputError(
                f"{where}: {str(n)[:40]!r} is not a sensor parameter; expected {', '.join(SENSOR_PARAMETERS)}"
            )
        limit = limit_of(n) or (MAX_OFFSET if n in ATTITUDE_OFFSETS else MAX_DATA)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not abs(v) <= limit:
            raise InputError(f"{where}: {n} = {repr(v)[:40]}; expected a number within ±{limit:g}")
        out[n] = float(v)
    return out


def read_corrections(path: str | Path) -> dict[str, float]:
    """The `corrections` of a check JSON (`testbed check --out`), checked."""
    doc = read_json(path, "a check JSON with corrections {name: value}")
    if not isinstance(doc, Mapping) or "corrections" not in doc:
        raise InputError(f"{path}: no 'corrections'; expected a check JSON (testbed check --out)")
    return check_corrections(doc["corrections"], f"{path}: corrections")


def corrected(experiments: Sequence[Experiment], corrections: Mapping[str, float]) -> list[Experiment]:
    """The experiments with each measured channel corrected by its sensor's parameters: a rate or
    velocity `(c(t + τ) − b_c) / (1 + k_c)`, c(t + τ) from the cubic spline through the
    channel's samples present (the end values held beyond them; a missing sample stays
    missing), an attitude channel less its offset `c − b_c`, the log's velocities misaligned back by
    its misalignment and moved from its point to the CG, v − ω × r (the rates measured: an
    `InputError` naming the record otherwise); parameters not given are 0, channels not measured
    are skipped."""
    corrections = check_corrections(corrections, "corrections")
    out = []
    for e in experiments:
        y = e.y.copy()
        for check in CHECKS:
            tau = corrections.get(check.delay, 0.0)
            for c in check.drives:
                if c not in e.measured:
                    continue
                j = e.measured.index(c)
                b, k = corrections.get(f"b_{c}", 0.0), corrections.get(f"k_{c}", 0.0)
                ts, ys = channel_samples(e, c)
                shifted = y[:, j]
                if tau and len(ts) > 1:
                    shifted = np.where(
                        np.isnan(y[:, j]), np.nan, CubicSpline(ts, ys)(np.clip(e.t + tau, ts[0], ts[-1]))
                    )
                y[:, j] = (shifted - b) / (1 + k)
            for c in check.uses:
                if c in e.measured:
                    y[:, e.measured.index(c)] -= corrections.get(f"b_{c}", 0.0)
            turns = [corrections.get(n, 0.0) for n in check.sensor if n in MISALIGNMENTS]
            if any(turns) and all(c in e.measured for c in check.drives):
                at = [e.measured.index(c) for c in check.drives]
                y[:, at] = misaligned(y[:, at], *turns)
            arm = np.array([corrections.get(n, 0.0) for n in check.sensor if n in LEVER_ARMS])
            if np.any(arm) and all(c in e.measured for c in check.drives):
                # the log's point moved to the CG: v = M y − ω × r, with the measured rates
                if not all(c in e.measured for c in ATTITUDE.drives):
                    named = ", ".join(f"{n} = {corrections[n]:g}" for n in LEVER_ARMS if corrections.get(n))
                    raise InputError(
                        f"corrections: {named}; record {e.name!r} has no p, q, r to move the log's "
                        "velocities to the CG with (v − ω × r): expected rate gyros, or the log's "
                        "position as the model config's r_dvl_x, r_dvl_y, r_dvl_z (identify reads the "
                        "velocities through it)"
                    )
                at = [e.measured.index(c) for c in check.drives]
                rates = np.column_stack([e.column(c) for c in ATTITUDE.drives])
                y[:, at] = y[:, at] - np.cross(rates, arm)
        out.append(replace(e, y=y))
    return out
