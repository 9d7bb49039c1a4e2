"""The manoeuvre metrics of flown experiments: the turning circle of a rudder step, the zigzag
of a zigzag signal (on ψ by the rudder, on θ by the elevators), chosen by what the experiment's
scenario flies.

`run_metrics(run)` reads a run directory: its `scenario.toml` says which experiments are
manoeuvres, and each one's record (the noise-free `.truth.csv` by default, or the measurement
CSV) gives the track (`track.record_track`). On measured data the peaks and the steady values
carry the sensor noise: an overshoot is the largest reading, biased up by the noise.
"""

from __future__ import annotations

import os
from pathlib import Path

from testbed.analysis.track import Track, record_track
from testbed.analysis.turning import TurningCircle, turning_circle
from testbed.analysis.zigzag import Zigzag, zigzag
from testbed.data import read_csv
from testbed.errors import InputError
from testbed.simulation.scenario import ExperimentSpec, read_scenario
from testbed.simulation.signals import Step, Zigzag as ZigzagSignal

__all__ = ["experiment_metrics", "manoeuvre", "run_metrics"]


def manoeuvre(spec: ExperimentSpec) -> str | None:
    """What the experiment `spec` flies: "turning circle" (a rudder step), "zigzag" (a zigzag
    signal on a fin channel), or None (another experiment)."""
    if isinstance(spec.fins.get("rudder"), Step):
        return "turning circle"
    if any(isinstance(signal, ZigzagSignal) for signal in spec.fins.values()):
        return "zigzag"
    return None


def experiment_metrics(
    spec: ExperimentSpec, track: Track, where: str = "the track"
) -> TurningCircle | Zigzag:
    """The metrics of the manoeuvre experiment `spec` flies (`manoeuvre`), read from its
    `track`: a turning circle, or a zigzag at the signal's nominal switching angle on ψ or θ;
    InputError naming `where` for an experiment that flies neither."""
    kind = manoeuvre(spec)
    if kind == "turning circle":
        return turning_circle(track, where)
    if kind is None:
        raise InputError(
            f"{where}: experiment {spec.name!r} flies no manoeuvre; expected a rudder step or a zigzag"
        )
    channel, signal = next((c, s) for c, s in spec.fins.items() if isinstance(s, ZigzagSignal))
    angle = track.psi if signal.on == "psi" else track.theta
    fin = track.rudder if channel == "rudder" else track.elevators
    return zigzag(track.t, angle, fin, signal.angle if signal.switch is None else signal.switch, where)


def run_metrics(run: str | Path, truth: bool = True) -> dict[str, TurningCircle | Zigzag]:
    """Experiment name → the metrics of each manoeuvre of a run directory (`experiment_metrics`),
    from its `.truth.csv` files (`truth`) or its measurement CSVs; InputError when the run
    flies none."""
    run = Path(run)
    if not os.path.lexists(run / "scenario.toml"):
        raise InputError(f"{run}: no scenario.toml; expected a run directory (testbed simulate)")
    s = read_scenario(run / "scenario.toml")
    out = {}
    for spec in (e for e in s.experiments if manoeuvre(e) is not None):
        path = run / f"{spec.name}{'.truth.csv' if truth else '.csv'}"
        if not os.path.lexists(path):
            raise InputError(f"{path}: missing; {run / 'scenario.toml'} flies experiment {spec.name!r}")
        out[spec.name] = experiment_metrics(spec, record_track(read_csv(path, spec.name)), str(path))
    if not out:
        raise InputError(
            f"{run}: experiments {', '.join(e.name for e in s.experiments)} fly no manoeuvre; "
            "expected a rudder step (turning circle) or a zigzag signal"
        )
    return out
