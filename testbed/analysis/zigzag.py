"""The zigzag metrics of a record (IMO's and ITTC's definitions), in the horizontal plane on the
heading ψ with the rudder, or in the vertical plane on the pitch θ with the elevators.

The fin's executes are found from its record (`instants.executes`): the fin leaves its neutral
angle (the middle of its range) for one extreme (first execute), then reverses between the
extremes (second, third, fourth execute). With a_0 the angle at the first execute and s the
sign of the first swing (that of a − a_0 at the second execute):

- **switching angle**: the nominal one when given (20° in a 20/20 zigzag), else the change
  |a − a_0| at the second execute;
- **first overshoot**: the largest s (a − a_0) between the second and third executes, less the
  switching angle; **second overshoot**: the largest −s (a − a_0) between the third and fourth,
  less it (each peak at the vertex of the parabola through its highest sample and neighbours);
- **initial turning time**: from the first execute to the second (the time to reach the
  switching angle); **period**: from the second execute to the fourth, one full cycle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from testbed.analysis.instants import executes, peak
from testbed.errors import InputError

__all__ = ["Zigzag", "zigzag"]


@dataclass(frozen=True)
class Zigzag:
    """A zigzag's metrics: angles in rad, times in s (the record's clock)."""

    fin: float  # the fin's angle: half its range
    switch: float  # the switching angle
    reference: float  # a_0: the angle at the first execute
    first_overshoot: float
    second_overshoot: float
    initial_turning_time: float  # first execute to second
    period: float  # second execute to fourth
    executes: tuple[float, float, float, float]
    peaks: tuple[float, float]  # the instants of the first and second overshoots


def zigzag(
    t: np.ndarray, angle: np.ndarray, fin: np.ndarray, switch: float | None = None, where: str = "the record"
) -> Zigzag:
    """The zigzag metrics of `angle` (ψ or θ, unwrapped, rad) driven by `fin` (rad) on time
    `t`; `switch` the nominal switching angle (rad; None: measured at the second execute).
    A one-line InputError naming `where` when the record holds no zigzag (a fin that does not
    reverse three times, an angle that does not move)."""
    top, bottom = float(fin.max()), float(fin.min())
    neutral, half = 0.5 * (top + bottom), 0.5 * (top - bottom)
    leaving = np.flatnonzero(np.abs(fin - neutral) >= 0.5 * half) if half > 0 else []
    held = [neutral]
    if len(leaving):
        ends = (top, bottom) if fin[leaving[0]] > neutral else (bottom, top)
        held += [ends[k % 2] for k in range(4)]
    found = executes(t, fin, held) if len(held) > 1 else []
    if len(found) < 4:
        raise InputError(
            f"{where}: {len(found)} fin executes (moves from neutral or between the fin's extremes); "
            "expected a zigzag's first four: the fin leaving neutral, then reversing three times"
        )
    e1, e2, e3, e4 = found[:4]
    reference = float(np.interp(e1, t, angle))
    swing = float(np.interp(e2, t, angle)) - reference
    if swing == 0.0:
        raise InputError(f"{where}: the angle has not moved at the second execute; expected a zigzag")
    s = float(np.sign(swing))
    nominal = abs(swing) if switch is None else float(switch)
    first_at, first = peak(t, s * (angle - reference), e2, e3)
    second_at, second = peak(t, -s * (angle - reference), e3, e4)
    return Zigzag(
        fin=half,
        switch=nominal,
        reference=reference,
        first_overshoot=first - nominal,
        second_overshoot=second - nominal,
        initial_turning_time=e2 - e1,
        period=e4 - e2,
        executes=(e1, e2, e3, e4),
        peaks=(first_at, second_at),
    )
