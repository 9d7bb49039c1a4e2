"""A manoeuvre's track: what the turning-circle and zigzag metrics read from a record.

From a flight (`testbed.simulation.scenario.Flight`) the plant's own NED position; from a
record (an `Experiment`: a run's CSV or `.truth.csv`, any measurement CSV) the horizontal
position dead-reckoned from the body velocities and the attitude, `(ṅ, ė, ḋ) = R(φ, θ, ψ)
(u, v, w)`, by the trapezoidal rule from (0, 0). Dead-reckoned, the position is relative to
the water: in a current it is the track a turning-circle trial reports after its correction
for drift.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from testbed.data import Experiment
from testbed.errors import InputError
from testbed.models.linear import INPUTS, IX
from testbed.models.sensors import rotation

__all__ = ["TRACK_STATES", "Track", "flight_track", "record_track"]

TRACK_STATES = ("u", "v", "w", "r", "phi", "theta", "psi")  # what a record needs for a track


@dataclass(frozen=True)
class Track:
    """A manoeuvre's track on uniform or non-uniform time `t` (s): the NED position `north`,
    `east` (m), the heading `psi` (rad, unwrapped) and pitch `theta` (rad), the yaw rate `r`
    (rad/s), the speed through the water `speed` = |(u, v, w)| (m/s), the rudder `rudder` and
    the elevators together `elevators` ((δer + δel)/2, rad)."""

    t: np.ndarray
    north: np.ndarray
    east: np.ndarray
    psi: np.ndarray
    theta: np.ndarray
    r: np.ndarray
    speed: np.ndarray
    rudder: np.ndarray
    elevators: np.ndarray


def flight_track(flight) -> Track:
    """The track of a flown experiment (a `Flight`): its true states, NED position and fin angles."""
    x = flight.truth
    return Track(
        t=flight.t,
        north=flight.position[:, 0],
        east=flight.position[:, 1],
        psi=x[:, IX["psi"]],
        theta=x[:, IX["theta"]],
        r=x[:, IX["r"]],
        speed=np.linalg.norm(x[:, [IX["u"], IX["v"], IX["w"]]], axis=1),
        rudder=flight.fins[:, 0],
        elevators=flight.fins[:, 1:].mean(axis=1),
    )


def record_track(e: Experiment) -> Track:
    """The track of a record: its position dead-reckoned from u, v, w, φ, θ, ψ; InputError
    naming the record when one of `TRACK_STATES` is not measured or has a gap."""
    where = e.source or e.name
    missing = [s for s in TRACK_STATES if s not in e.measured]
    if missing:
        raise InputError(
            f"{where}: {', '.join(missing)} not measured; expected {', '.join(TRACK_STATES)} for a track"
        )
    x = {s: e.column(s) for s in TRACK_STATES}
    gaps = [s for s in TRACK_STATES if not np.isfinite(x[s]).all()]
    if gaps:
        raise InputError(f"{where}: {', '.join(gaps)} has missing samples; expected a complete record")
    body = np.stack([x["u"], x["v"], x["w"]], axis=1)
    ned = np.einsum("nij,nj->ni", rotation(x["phi"], x["theta"], x["psi"]), body)
    steps = np.diff(e.t)[:, None] * 0.5 * (ned[1:, :2] + ned[:-1, :2])
    position = np.vstack([np.zeros(2), np.cumsum(steps, axis=0)])
    fins = {name: e.inputs[:, k] for k, name in enumerate(INPUTS)}
    return Track(
        t=e.t,
        north=position[:, 0],
        east=position[:, 1],
        psi=x["psi"],
        theta=x["theta"],
        r=x["r"],
        speed=np.linalg.norm(body, axis=1),
        rudder=fins["delta_r"],
        elevators=0.5 * (fins["delta_er"] + fins["delta_el"]),
    )
