"""The turning-circle metrics of a track (ITTC's definitions), to port or to starboard.

The rudder's execute is found from its record (`instants.executes`: its move from the approach
angle, the first sample's, to the held angle, the last sample's). From there, with ψ_e the
heading and P_e the position at the execute:

- **advance**: the distance P − P_e along the approach heading ψ_e when the heading has changed
  by 90°; **transfer**: the distance across it, towards the turn, at that instant;
- **tactical diameter**: the distance across at 180° of heading change;
- **steady turning diameter**: the diameter of the circle fitted (least squares, Kåsa's
  algebraic fit) to the track over the steady turn; **steady turn rate**: the mean r there;
- **speed**: the approach speed at the execute, the steady speed the mean speed over the
  steady turn; their ratio is the speed loss.

The crossing instants are interpolated linearly between samples, and the positions and the
speed at them likewise.

**Steady turn**: the yaw rate counts as steady from the first sample after which every
sample's r lies within `STEADY_TOLERANCE` of the median r over the record's last half turn of
heading, to the end of the record; that stretch must turn the heading by at least
`STEADY_TURN`, or the record holds no steady turn (InputError).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from testbed.analysis.instants import crossing, executes
from testbed.analysis.track import Track
from testbed.errors import InputError

__all__ = ["STEADY_TOLERANCE", "STEADY_TURN", "TurningCircle", "circle_fit", "turning_circle"]

STEADY_TOLERANCE = 0.02  # relative band of r about its final value that counts as steady
STEADY_TURN = math.pi  # rad of heading change the steady turn must cover (half a circle)


@dataclass(frozen=True)
class TurningCircle:
    """A turning circle's metrics: lengths in m, times in s (the record's clock), rates in
    rad/s, speeds in m/s."""

    side: str  # "starboard" (heading increasing, r > 0) or "port"
    execute: float  # the rudder's execute instant
    rudder: float  # the held rudder angle, rad (the record's last)
    advance: float  # along the approach heading at 90° of heading change
    transfer: float  # across it, towards the turn, at 90°
    tactical_diameter: float  # across at 180°
    time_90: float  # the instants of 90° and 180° of heading change
    time_180: float
    steady_from: float  # the start of the steady turn (to the record's end)
    steady_diameter: float  # the circle fitted to the track over the steady turn
    steady_turn_rate: float  # mean r over the steady turn (signed: > 0 to starboard)
    approach_speed: float  # speed at the execute
    steady_speed: float  # mean speed over the steady turn

    @property
    def speed_ratio(self) -> float:
        """The speed loss: the steady speed over the approach speed."""
        return self.steady_speed / self.approach_speed


def circle_fit(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    """(x_c, y_c, radius) of the circle x² + y² + a x + b y + c = 0 fitted by least squares
    (Kåsa): exact for points on a circle."""
    A = np.stack([x, y, np.ones_like(x)], axis=1)
    (a, b, c), *_ = np.linalg.lstsq(A, -(x**2 + y**2), rcond=None)
    xc, yc = -a / 2.0, -b / 2.0
    return float(xc), float(yc), float(math.sqrt(max(xc**2 + yc**2 - c, 0.0)))


def turning_circle(track: Track, where: str = "the track") -> TurningCircle:
    """The turning-circle metrics of `track`; a one-line InputError naming `where` when it
    holds no turning circle (the rudder never moves, the heading never changes by 180°, no
    steady turn)."""
    t, psi, r = track.t, track.psi, track.r
    approach, held = float(track.rudder[0]), float(track.rudder[-1])
    found = executes(t, track.rudder, [approach, held]) if held != approach else []
    if not found or found[0] <= t[0]:
        raise InputError(
            f"{where}: the rudder goes from {approach:g} to {held:g} rad with no execute inside the "
            "record; expected a straight approach, then a rudder step held to the end"
        )
    t_e = found[0]
    psi_e = float(np.interp(t_e, t, psi))
    sign = 1.0 if psi[-1] >= psi_e else -1.0
    turned = sign * (psi - psi_e)
    t90, t180 = crossing(t, turned, math.pi / 2, t_e), crossing(t, turned, math.pi, t_e)
    if t180 is None:
        raise InputError(
            f"{where}: the heading changes by {math.degrees(turned.max()):.1f}° after the execute; "
            "expected at least 180° (a turning circle)"
        )
    along = np.array([math.cos(psi_e), math.sin(psi_e)])  # (north, east) unit vectors
    across = sign * np.array([-math.sin(psi_e), math.cos(psi_e)])  # towards the turn

    def at(instant):  # the position at an instant
        return np.array([np.interp(instant, t, track.north), np.interp(instant, t, track.east)])

    def moved(instant):
        return at(instant) - at(t_e)

    last = turned >= turned[-1] - STEADY_TURN
    r_final = float(np.median(r[last]))
    outside = np.flatnonzero(np.abs(r - r_final) > STEADY_TOLERANCE * abs(r_final))
    first = outside[-1] + 1 if outside.size else 0
    if first >= len(t) or turned[-1] - turned[first] < STEADY_TURN or sign * r_final <= 0:
        covered = 0.0 if first >= len(t) else math.degrees(turned[-1] - turned[first])
        raise InputError(
            f"{where}: the yaw rate is steady (within {STEADY_TOLERANCE:.0%} of its final value) over "
            f"{covered:.0f}° of heading; expected a steady turn of at least {math.degrees(STEADY_TURN):.0f}°"
        )
    steady = slice(first, None)
    *_, radius = circle_fit(track.north[steady], track.east[steady])
    return TurningCircle(
        side="starboard" if sign > 0 else "port",
        execute=t_e,
        rudder=held,
        advance=float(moved(t90) @ along),
        transfer=float(moved(t90) @ across),
        tactical_diameter=float(moved(t180) @ across),
        time_90=t90,
        time_180=t180,
        steady_from=float(t[first]),
        steady_diameter=2.0 * radius,
        steady_turn_rate=float(r[steady].mean()),
        approach_speed=float(np.interp(t_e, t, track.speed)),
        steady_speed=float(track.speed[steady].mean()),
    )
