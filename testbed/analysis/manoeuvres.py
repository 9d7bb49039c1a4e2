"""The manoeuvre metrics of flown experiments: the turning circle of a rudder step, the zigzag
of a zigzag signal (on ψ by the rudder, on θ by the elevators), chosen by what the experiment's
scenario flies.

`run_metrics(run)` reads a run directory: its `scenario.toml` says which experiments are
manoeuvres, and each one's record (the noise-free `.truth.csv` by default, or the measurement
CSV) gives the track (`track.record_track`). On measured data the peaks and the steady values
carry the sensor noise: an overshoot is the largest reading, biased up by the noise.

`compared(run, predictions)` sets the metrics of a model's open-loop prediction of each
manoeuvre beside the record's: the prediction (the model's outputs in the measured channels)
makes a track as a record does, and each metric's difference is `100 (model − record) /
|record|`.
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Mapping

from testbed.analysis.track import Track, record_track
from testbed.analysis.turning import TurningCircle, turning_circle
from testbed.analysis.zigzag import Zigzag, zigzag
from testbed.data import Experiment, read_csv
from testbed.errors import InputError
from testbed.simulation.scenario import ExperimentSpec, read_scenario
from testbed.simulation.signals import Step
from testbed.simulation.signals import ZigzagSignal

__all__ = [
    "TABLE_METRICS",
    "Compared",
    "compared",
    "compared_table",
    "experiment_metrics",
    "manoeuvre",
    "metric_values",
    "run_metrics",
]

# the metrics the table shows, per manoeuvre (the JSON has every one)
TABLE_METRICS = {
    "turning circle": (
        "advance",
        "transfer",
        "tactical_diameter",
        "steady_diameter",
        "steady_turn_rate",
        "speed_ratio",
    ),
    "zigzag": ("first_overshoot", "second_overshoot", "initial_turning_time", "period"),
}


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
        out[spec.name] = _record_metrics(spec, path)
    if not out:
        raise InputError(
            f"{run}: experiments {', '.join(e.name for e in s.experiments)} fly no manoeuvre; "
            "expected a rudder step (turning circle) or a zigzag signal"
        )
    return out


def _record_metrics(spec: ExperimentSpec, path: Path) -> TurningCircle | Zigzag:
    # a noise-free truth holds a steady turn's speed exactly: its repeats are samples
    record = read_csv(path, spec.name, keep_repeats=path.name.endswith(".truth.csv"))
    return experiment_metrics(spec, record_track(record), str(path))


def metric_values(m: TurningCircle | Zigzag) -> dict:
    """The metrics as a dict: the dataclass's fields (tuples as lists), and a turning circle's
    speed loss `speed_ratio`."""
    values = {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(m).items()}
    return values | ({"speed_ratio": m.speed_ratio} if isinstance(m, TurningCircle) else {})


@dataclass(frozen=True)
class Compared:
    """A manoeuvre's metrics from its record and from a model's open-loop prediction; a side
    whose metrics cannot be read (a state the prediction lacks, no manoeuvre in the track) is
    None with the reason in `note`."""

    manoeuvre: str  # "turning circle" or "zigzag"
    source: str  # the record read
    record: TurningCircle | Zigzag | None
    model: TurningCircle | Zigzag | None
    note: str = ""

    def differences(self) -> dict[str, float | None]:
        """metric → `100 (model − record) / |record|` for each scalar number (None where the
        record's is 0); empty when a side is missing."""
        if self.record is None or self.model is None:
            return {}
        rec, mod = metric_values(self.record), metric_values(self.model)
        return {
            k: (100.0 * (mod[k] - v) / abs(v) if v != 0 else None)
            for k, v in rec.items()
            if isinstance(v, float)
        }

    def to_dict(self) -> dict:
        doc = {
            "manoeuvre": self.manoeuvre,
            "source": self.source,
            "record": None if self.record is None else metric_values(self.record),
            "model": None if self.model is None else metric_values(self.model),
            "difference_percent": self.differences(),
        }
        return doc | ({"note": self.note} if self.note else {})


def compared(run: str | Path, predictions: Mapping[str, Experiment]) -> dict[str, Compared]:
    """Experiment name → the metrics of each manoeuvre the run directory `run` flies (its
    `scenario.toml`) from its record (the noise-free `.truth.csv` where present, else the
    measurement CSV) and from `predictions[name]` (a model's prediction as a record, its
    track by `record_track`), for the experiments among `predictions`; empty when the run
    flies none."""
    run = Path(run)
    out = {}
    for spec in read_scenario(run / "scenario.toml").experiments:
        kind = manoeuvre(spec)
        if kind is None or spec.name not in predictions:
            continue
        path = run / f"{spec.name}.truth.csv"
        path = path if os.path.lexists(path) else run / f"{spec.name}.csv"
        record, model, notes = None, None, []
        try:
            record = _record_metrics(spec, path)
        except InputError as err:
            notes.append(f"no record metrics: {err}")
        try:
            model = experiment_metrics(
                spec, record_track(predictions[spec.name]), predictions[spec.name].source
            )
        except InputError as err:
            notes.append(f"no model metrics: {err}")
        out[spec.name] = Compared(
            manoeuvre=kind, source=str(path), record=record, model=model, note="; ".join(notes)
        )
    return out


def compared_table(comparisons: Mapping[str, Compared]) -> str:
    """The `TABLE_METRICS` of each manoeuvre, record against model, as a plain table."""
    lines = [f"{'manoeuvre':<16}{'metric':<22}{'record':>12}{'model':>12}{'diff %':>9}"]
    for name, c in comparisons.items():
        if c.note:
            lines.append(f"{name:<16}{c.note}")
        if c.record is None or c.model is None:
            continue
        rec, mod, diff = metric_values(c.record), metric_values(c.model), c.differences()
        for k in TABLE_METRICS[c.manoeuvre]:
            d = diff[k]
            lines.append(
                f"{name:<16}{k:<22}{rec[k]:>12.4g}{mod[k]:>12.4g}{'-' if d is None else f'{d:.2f}':>9}"
            )
    return "\n".join(lines)
