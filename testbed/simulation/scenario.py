"""Scenarios: experiments defined in scenario files, read, checked and written back (`flight`
flies them, `runs` writes their run directories).

A scenario file (TOML; `testbed/simulation/scenarios/*.toml` are the built-in ones, in the same format)
sets the trim speed, initial depth, control and sample rates, the sensors and, per experiment,
its duration, the signal on each fin channel and which autopilot loops hold what:

```toml
name = "II"
description = "..."
duration = 60.0      # s, each experiment unless it sets its own
depth = 100.0        # m, initial depth
# speed = 20.0       # m/s, trim speed (default: the vehicle's cruise speed)
control_rate = 50.0  # Hz, autopilots and fin commands
feedback = "measured"  # the autopilots read the sensors (default "true": the true states)

[sensors]
rate = 50.0          # Hz; divides the control rate
# steps = [0.4, 0.6] # s, instead of rate: the rows' steps, repeated from t = 0 (a logger's stamps)
fin_std = 2e-5       # rad, fin encoders
# fin_rate = 100.0   # Hz; the fin angles logged this often: a multiple of the control rate
#                    # dividing the physics rate; the CSV rows between samples hold fins only
noise_std = {u = 0.05, v = 0.02, ...}   # per state, SI
measured = ["u", "v", ...]               # the state columns of the measurement CSVs

[sensors.dvl]        # named sensors: `testbed.simulation.sensing`
outputs = ["u", "v", "w"]
position = [0.3, 0.0, 0.15]

[trial]              # a trial's imperfections: `testbed.simulation.trial`
current = [0.25, 0.15, 0.0]

[prior]              # the runs' a-priori model, prior.toml: `testbed.simulation.prior`
scale = {N_r = 0.25}

[[experiment]]
name = "horizontal"
rudder = {signal = "prbs", amplitude = 0.001, order = 10, clock = 0.1}
autopilot = {depth = 0.0, roll = 0.0}
```

Fin channels: `rudder`, `elevators` (together, δe) and `differential` (δa: δer = δe + δa,
δel = δe − δa), each a signal (`testbed.simulation.signals`; a number is a hold). Autopilot loops
(`testbed.simulation.autopilot`): `depth` (m below the initial depth; 0 holds it), `yaw_rate` (rad/s),
`roll` (rad), each a number or a signal; a loop drives its fin channel, so a channel cannot be
both. `hold = {depth = ...}` is the slow pitch-depth hold that keeps an open-loop `elevators`
signal from letting the nearly neutral pitch random-walk (poles at 0.2 rad/s, far below a PRBS
band; `depth` again relative to the initial depth). A channel neither driven nor held is at 0.

The built-in scenarios: `I` (the paper's sea-trial scenario: depth steps of 20 m every 5 s,
course rate ±20 °/s every 1.5 s, roll held at zero), `II` (PRBS experiments in the linear
regime, see its file), `II-trial` (Scenario II with a real trial's imperfections: `testbed.simulation.trial`,
`testbed.simulation.sensing`), `lake` (a small vehicle's lake trial as its logger writes it:
rows at alternating steps, a slow DVL holding its value, no gyros, attitude offsets, short
closed-loop dives, and a course-unstable a-priori model), `turn`, `turning-circle`, `zigzag` and
`zigzag-vertical` (validation manoeuvres; `testbed.analysis.manoeuvres` measures them).

"""

from __future__ import annotations
import math
import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Mapping
import numpy as np
from testbed.data import MIN_ROWS, check_name, number, read_toml, sensor_table, toml_value
from testbed.errors import InputError, check_keys, is_number
from testbed.simulation.measurements import NOISE_STD, Sensors
from testbed.models.linear import STATES
from testbed.models.sensors import Sensor
from testbed.simulation.prior import Prior, parse_prior, prior_table
from testbed.simulation.sensing import check_sensors, columns, scenario_sensor
from testbed.simulation.trial import Trial, parse_trial, trial_table
from testbed.simulation.signals import Signal, parse_signal, signal_table
from testbed.simulation.vehicle import MAX_SPEED, MIN_SPEED

__all__ = [
    "BUILTIN",
    "CHANNELS",
    "ExperimentSpec",
    "FEEDBACKS",
    "LOOPS",
    "SAMPLES",
    "SCENARIO_DIR",
    "Scenario",
    "TRUTHS",
    "UNFITTED_DEPTH",
    "parse_scenario",
    "read_scenario",
    "scenario",
    "scenario_text",
]


# Why a run's model.toml fits every measured state but the depth (measured, and validated).
UNFITTED_DEPTH = (
    "depth is measured but not fitted: it integrates U θ, and the second-order drag "
    "moments of the real body (its drag grows with incidence, 2 cm above the CG: "
    "-119 N m per (m/s)^2 of heave or sway) rectify into a pitch drift that the "
    "linear model cannot follow"
)


CHANNELS = ("rudder", "elevators", "differential")  # fin channels a signal can drive


SAMPLES = (MIN_ROWS, 10**6)  # the samples an experiment may have (MIN_ROWS: the fewest a fit takes)


LOOPS = {"yaw_rate": "rudder", "depth": "elevators", "roll": "differential"}  # loop -> its channel


SCENARIO_DIR = Path(__file__).parent / "scenarios"


TRUTHS = ("plant", "linear")  # what a scenario can be flown on: the MuJoCo plant, the analytic model


# What the autopilots and the fin programs read: the true state, or the default sensors' readings
FEEDBACKS = ("true", "measured")


BUILTIN = tuple(sorted(p.stem for p in SCENARIO_DIR.glob("*.toml")))


def _positive(v) -> bool:
    return is_number(v) and v > 0


@dataclass(frozen=True)
class ExperimentSpec:
    """One experiment of a scenario: its fin signals and autopilot references."""

    name: str
    fins: Mapping[str, Signal] = field(default_factory=dict)  # channel -> signal
    autopilot: Mapping[str, Signal] = field(default_factory=dict)  # loop -> reference
    hold_depth: Signal | None = None  # the slow hold's depth reference, m below the initial depth
    duration: float | None = None  # s; None: the scenario's

    def __post_init__(self):
        where = f"experiment {self.name!r}"
        for loop, channel in LOOPS.items():
            if loop in self.autopilot and channel in self.fins:
                raise InputError(
                    f"{where}: {channel} is both a signal and driven by the {loop} "
                    "autopilot; expected one of them"
                )
        if self.hold_depth is not None and ("elevators" not in self.fins or "depth" in self.autopilot):
            raise InputError(
                f"{where}: hold needs an elevators signal and no depth autopilot; "
                "expected the hold to keep an open-loop elevator signal in bounds"
            )
        if self.duration is not None and not _positive(self.duration):
            raise InputError(f"{where}: duration {self.duration!r}; expected a finite number > 0 (s)")


@dataclass(frozen=True)
class Scenario:
    """A scenario: the vehicle's trim, the sensors and the experiments (a scenario file)."""

    name: str
    experiments: tuple[ExperimentSpec, ...]
    description: str = ""
    duration: float = 60.0  # s per experiment, unless it sets its own
    speed: float | None = None  # trim speed, m/s (None: the vehicle's cruise speed)
    depth: float = 100.0  # initial depth, m
    control_rate: float = 50.0  # Hz
    feedback: str = "true"  # what the autopilots read: FEEDBACKS
    sensors: Sensors = field(default_factory=Sensors)
    measured: tuple[str, ...] = STATES  # the states the default sensor reads (those no named sensor outputs)
    named_sensors: tuple[Sensor, ...] = ()  # the [sensors.NAME] tables
    trial: Trial = field(default_factory=Trial)  # the [trial] table
    prior: Prior | None = None  # the [prior] table: the runs' a-priori model (None: none written)
    source: str = ""  # the file it was read from, or "built-in"
    given: frozenset[str] = field(default=frozenset(), compare=False)  # fields set by `with_overrides`

    def __post_init__(self):
        checks = {
            "duration": (_positive, "a finite number > 0 (s)"),
            "speed": (
                lambda v: v is None or (_positive(v) and MIN_SPEED <= v <= MAX_SPEED),
                f"{MIN_SPEED} to {MAX_SPEED} (m/s)",
            ),
            "depth": (is_number, "a finite number (m)"),
            "control_rate": (_positive, "a finite number > 0 (Hz)"),
        }
        check_name(self.name, f"{self.where}: name")
        for name, (ok, expected) in checks.items():
            if not ok(getattr(self, name)):
                raise InputError(
                    f"{self.described(**{name: repr(getattr(self, name))})}; expected {expected}"
                )
        if self.feedback not in FEEDBACKS:
            raise InputError(
                f"{self.where}: feedback = {self.feedback!r}; expected one of "
                f"{', '.join(map(repr, FEEDBACKS))} (a string)"
            )
        if self.feedback == "measured" and self.named_sensors:
            raise InputError(
                f"{self.where}: feedback = 'measured' with named sensors "
                f"({', '.join(s.name for s in self.named_sensors)}); expected 'true': the autopilots "
                "read the default sensors only"
            )
        if not self.experiments:
            raise InputError(f"{self.where}: no [[experiment]]; expected at least one")
        names = [check_name(e.name, f"{self.where}: experiment name") for e in self.experiments]
        if len(set(names)) != len(names):
            raise InputError(f"{self.where}: experiment names {names}; expected distinct names")
        unknown = [s for s in self.measured if s not in STATES]
        if unknown or not self.measured:
            raise InputError(
                f"{self.where}: measured {list(self.measured)}; expected a "
                f"non-empty list of {', '.join(STATES)}"
            )
        steps = self.sensors.steps
        if steps is None:
            ratio = self.control_rate / self.sensors.rate
            if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
                raise InputError(
                    f"{self.where}: control rate {self.control_rate} Hz and sample "
                    f"rate {self.sensors.rate} Hz; expected the sample rate to divide the control rate"
                )
            check_sensors(self.named_sensors, self.sensors.rate, self.where)
        else:
            for d in steps:
                periods = d * self.control_rate
                if abs(periods - round(periods)) > 1e-9 or round(periods) < 1:
                    raise InputError(
                        f"{self.where}: sensors.steps = {list(steps)}: {d:g} s; expected whole "
                        f"numbers of control periods (1/{self.control_rate:g} s)"
                    )
            cycle = 1.0 / math.fsum(steps)
            check_sensors(self.named_sensors, cycle, self.where, "the rate the steps repeat at")
        if self.sensors.fin_rate is not None:
            ratio = self.sensors.fin_rate / self.control_rate
            if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
                raise InputError(
                    f"{self.where}: sensors.fin_rate = {self.sensors.fin_rate:g} Hz; expected a whole "
                    f"multiple of the control rate {self.control_rate:g} Hz"
                )
            if not self.is_perfect or steps is not None:
                raise InputError(
                    f"{self.where}: sensors.fin_rate with named sensors, a [trial] or steps; expected "
                    "the fins logged at the sample rate there (no fin_rate)"
                )
        for e in self.experiments:
            held = {"hold.depth": e.hold_depth} if e.hold_depth is not None else {}
            loops = {f"autopilot.{k}": v for k, v in e.autopilot.items()}
            for key, signal in {**e.fins, **loops, **held}.items():
                why = signal.undersampled(self.control_rate)
                if why is not None:
                    raise InputError(f"{self.source or 'scenario'}: experiment {e.name!r} {key}: {why}")

    @property
    def where(self) -> str:
        """The scenario as a message names it: its file, else its name."""
        if self.source == "built-in":
            return f"the built-in scenario {self.name}"
        return self.source or f"scenario {self.name!r}"

    def described(self, **values: str) -> str:
        """Fields (name → value as text) as a message names them, by where each came from: a
        caller's (`with_overrides`, the command line's flags) as `name=value`, the scenario
        file's as `<file>: name = value`, one left unset as `the default name value`."""
        given = [f"{k}={v}" for k, v in values.items() if k in self.given]
        unset = [
            f"the default {k} {v}"
            for k, v in values.items()
            if k not in self.given and getattr(self, k) is None
        ]
        read = [
            f"{k} = {v}" for k, v in values.items() if k not in self.given and getattr(self, k) is not None
        ]
        return ", ".join(given + ([f"{self.where}: {', '.join(read)}"] if read else []) + unset)

    def with_overrides(self, duration=None, speed=None) -> "Scenario":
        """The scenario with every experiment lasting `duration` and trimmed at `speed` (None:
        unchanged), as `testbed simulate --duration --speed` give them."""
        s = self
        if duration is not None:
            s = replace(
                s,
                duration=duration,
                experiments=tuple(replace(e, duration=None) for e in s.experiments),
                given=s.given | {"duration"},
            )
        if speed is not None:
            s = replace(s, speed=speed, given=s.given | {"speed"})
        return s

    @property
    def columns(self) -> tuple[str, ...]:
        """The measurement CSVs' output columns: the measured states and the named sensors' outputs."""
        return columns(self.measured, self.named_sensors)

    @property
    def is_perfect(self) -> bool:
        """Sensors at the CG, ideal but for their noise, and a perfect trial: today's flights."""
        return not self.named_sensors and self.trial.is_perfect

    def duration_of(self, e: ExperimentSpec) -> float:
        return e.duration if e.duration is not None else self.duration

    def sample_count(self, duration: float) -> int:
        """How many rows a record of `duration` s has: its stamps from 0 to `duration`."""
        steps = self.sensors.steps
        if steps is None:
            return int(math.floor(duration * self.sensors.rate + 1e-9)) + 1
        cycle, starts = math.fsum(steps), np.cumsum((0.0, *steps[:-1]))
        return sum(int(math.floor((duration - a) / cycle + 1e-9)) + 1 for a in starts if a <= duration + 1e-9)

    def stamps(self, duration: float) -> tuple[np.ndarray, np.ndarray]:
        """A record's stamps t (s) from 0 to `duration` and the control step each falls on: at
        the sample rate, or at `[sensors] steps` repeated from t = 0 (each stamp a whole number
        of control periods, t = that number / `control_rate`: 1.4, not 0.4 + 0.6 + 0.4)."""
        n = self.sample_count(duration)
        steps = self.sensors.steps
        if steps is None:
            return np.arange(n) / self.sensors.rate, np.arange(n) * round(
                self.control_rate / self.sensors.rate
            )
        periods = np.array([round(d * self.control_rate) for d in steps])
        starts = np.concatenate(([0], np.cumsum(periods)[:-1]))
        k = np.arange(n)
        at = (k // len(steps)) * int(periods.sum()) + starts[k % len(steps)]
        return at / self.control_rate, at


def scenario(name_or_path: str | Path | Scenario) -> Scenario:
    """A built-in scenario by name, or the scenario file at a path."""
    if isinstance(name_or_path, Scenario):
        return name_or_path
    if str(name_or_path) in BUILTIN:
        s = read_scenario(SCENARIO_DIR / f"{name_or_path}.toml")
        return replace(s, source="built-in")
    path = Path(name_or_path)
    if path.suffix != ".toml" and not path.exists():
        raise InputError(
            f"scenario={str(name_or_path)!r} is unknown; expected one of "
            f"{', '.join(BUILTIN)} or a scenario file (.toml)"
        )
    return read_scenario(path)


def read_scenario(path: str | Path) -> Scenario:
    """Read and check a scenario file; InputError naming the file and field otherwise."""
    return parse_scenario(read_toml(path, "a scenario file (.toml)"), str(path))


_TOP = (
    "name",
    "description",
    "duration",
    "speed",
    "depth",
    "control_rate",
    "feedback",
    "sensors",
    "trial",
    "prior",
    "experiment",
)


_SENSORS = ("rate", "steps", "fin_std", "fin_rate", "noise_std", "measured")


_EXPERIMENT = ("name", "duration", "autopilot", "hold", *CHANNELS)


def parse_scenario(doc: Mapping, source: str = "<scenario>") -> Scenario:
    """A `Scenario` from a parsed scenario file."""
    check_keys(doc, _TOP, source)
    top = lambda key, default: number(doc.get(key, default), f"{source}: {key}")  # noqa: E731
    experiments = doc.get("experiment", [])
    if not isinstance(experiments, list) or not all(isinstance(e, Mapping) for e in experiments):
        raise InputError(f"{source}: experiment must be an array of tables ([[experiment]])")
    return Scenario(
        name=str(doc.get("name", Path(source).stem)),
        description=str(doc.get("description", "")),
        duration=top("duration", 60.0),
        speed=None if doc.get("speed") is None else top("speed", None),
        depth=top("depth", 100.0),
        control_rate=top("control_rate", 50.0),
        feedback=doc.get("feedback", "true"),
        sensors=_sensors(doc.get("sensors", {}), f"{source}: sensors"),
        measured=_measured(doc.get("sensors", {}), f"{source}: sensors"),
        named_sensors=tuple(
            scenario_sensor(k, v, f"{source}: sensors.{k}")
            for k, v in doc.get("sensors", {}).items()
            if k not in _SENSORS
        ),
        trial=parse_trial(doc.get("trial", {}), f"{source}: trial"),
        prior=parse_prior(doc.get("prior"), f"{source}: prior"),
        experiments=tuple(_experiment(e, f"{source}: experiment {k + 1}") for k, e in enumerate(experiments)),
        source=source,
    )


def _sensors(doc, where: str) -> Sensors:
    if not isinstance(doc, Mapping):
        raise InputError(f"{where}: expected a table")
    unknown = sorted(k for k, v in doc.items() if k not in _SENSORS and not isinstance(v, Mapping))
    if unknown:
        raise InputError(
            f"{where}: unknown key {unknown[0]!r}; expected {', '.join(_SENSORS)} or a sensor's table"
        )
    noise = doc.get("noise_std", NOISE_STD)
    if not isinstance(noise, Mapping):
        raise InputError(f"{where}: noise_std must be a table of state = std")
    noise = {k: number(v, f"{where}: noise_std.{k}") for k, v in noise.items()}
    steps = doc.get("steps")
    if steps is not None:
        if "rate" in doc:
            raise InputError(f"{where}: rate and steps; expected one of them (steps: the rows' steps, s)")
        if not isinstance(steps, list) or not steps or len(steps) > 1000:
            raise InputError(f"{where}: steps = {steps!r}; expected a list of 1 to 1000 steps (s)")
        steps = tuple(float(number(d, f"{where}: steps")) for d in steps)
    try:
        return Sensors(
            rate=number(doc.get("rate", 50.0), f"{where}: rate"),
            noise_std={**NOISE_STD, **noise},
            fin_std=number(doc.get("fin_std", Sensors().fin_std), f"{where}: fin_std"),
            fin_rate=None if doc.get("fin_rate") is None else number(doc["fin_rate"], f"{where}: fin_rate"),
            steps=steps,
        )
    except InputError as exc:
        raise InputError(f"{where}: {exc}") from None


def _measured(doc, where: str) -> tuple[str, ...]:
    measured = doc.get("measured", list(STATES)) if isinstance(doc, Mapping) else list(STATES)
    if not isinstance(measured, list) or not all(isinstance(s, str) for s in measured):
        raise InputError(f"{where}: measured must be a list of state names")
    return tuple(s for s in STATES if s in measured) + tuple(s for s in measured if s not in STATES)


def _experiment(doc: Mapping, where: str) -> ExperimentSpec:
    name = doc.get("name")
    if not isinstance(name, str):
        raise InputError(f"{where}: name {name!r}; expected a string")
    where = f"{where.rsplit(': ', 1)[0]}: experiment {name!r}"
    check_keys(doc, _EXPERIMENT, where)
    autopilot, hold = doc.get("autopilot", {}), doc.get("hold", {})
    for key, table, allowed in (("autopilot", autopilot, tuple(LOOPS)), ("hold", hold, ("depth",))):
        if not isinstance(table, Mapping):
            raise InputError(f"{where}: {key} must be a table")
        bad = sorted(set(table) - set(allowed))
        if bad:
            raise InputError(f"{where}: unknown {key} loop {bad[0]!r}; expected {', '.join(allowed)}")
    duration = doc.get("duration")
    fins = {c: parse_signal(doc[c], f"{where} {c}") for c in CHANNELS if c in doc}
    loops = {k: parse_signal(v, f"{where} autopilot.{k}") for k, v in autopilot.items()}
    held = parse_signal(hold["depth"], f"{where} hold.depth") if "depth" in hold else None
    duration = None if duration is None else number(duration, f"{where}: duration")
    try:
        return ExperimentSpec(name=name, fins=fins, autopilot=loops, hold_depth=held, duration=duration)
    except InputError as exc:  # it names the experiment; add the file
        raise InputError(f"{where.rsplit(': ', 1)[0]}: {exc}") from None


def scenario_text(s: Scenario) -> str:
    """The scenario file of `s` (`parse_scenario` reads it back to an equal scenario)."""
    lines = [f"name = {toml_value(s.name)}"]
    if s.description:
        lines.append(f"description = {toml_value(s.description)}")
    lines += [f"duration = {toml_value(s.duration)}", f"depth = {toml_value(s.depth)}"]
    if s.speed is not None:
        lines.append(f"speed = {toml_value(s.speed)}")
    lines.append(f"control_rate = {toml_value(s.control_rate)}")
    if s.feedback != "true":
        lines.append(f"feedback = {toml_value(s.feedback)}")
    lines += [
        "",
        "[sensors]",
        (
            f"rate = {toml_value(s.sensors.rate)}"
            if s.sensors.steps is None
            else f"steps = {toml_value(list(s.sensors.steps))}"
        ),
        f"fin_std = {toml_value(s.sensors.fin_std)}",
        *([f"fin_rate = {toml_value(s.sensors.fin_rate)}"] if s.sensors.fin_rate is not None else []),
        f"noise_std = {toml_value(dict(s.sensors.noise_std))}",
        f"measured = {toml_value(list(s.measured))}",
    ]
    for sensor in s.named_sensors:
        key = sensor.name if re.fullmatch(r"[A-Za-z0-9_-]+", sensor.name) else toml_value(sensor.name)
        lines += ["", f"[sensors.{key}]"]
        lines += [f"{k} = {toml_value(v)}" for k, v in sensor_table(sensor).items()]
    if not s.trial.is_perfect:
        lines += ["", "[trial]", *[f"{k} = {toml_value(v)}" for k, v in trial_table(s.trial).items()]]
    if s.prior is not None:
        lines += ["", "[prior]", *[f"{k} = {toml_value(v)}" for k, v in prior_table(s.prior).items()]]
    for e in s.experiments:
        lines += ["", "[[experiment]]", f"name = {toml_value(e.name)}"]
        if e.duration is not None:
            lines.append(f"duration = {toml_value(e.duration)}")
        lines += [f"{c} = {toml_value(signal_table(sig))}" for c, sig in e.fins.items()]
        if e.autopilot:
            lines.append(f"autopilot = {toml_value({k: signal_table(v) for k, v in e.autopilot.items()})}")
        if e.hold_depth is not None:
            lines.append(f"hold = {toml_value({'depth': signal_table(e.hold_depth)})}")
    return "\n".join(lines) + "\n"
