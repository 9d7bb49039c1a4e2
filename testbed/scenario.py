"""The paper's scenarios and validation manoeuvres, flown by the truth plant, written as runs.

- `I` (the paper's sea-trial scenario): the depth command changes by 20 m every 5 s, the
  course-rate command switches between +20 and −20 deg/s every 1.5 s, the roll command is zero;
  all three autopilots fly it. One experiment, `scenario-I`.
- `II`: `horizontal` — depth and roll held by the elevator autopilots while the rudder follows a
  PRBS (±`prbs_rudder`); `vertical` — both elevators follow the same PRBS (±`prbs_elevators`)
  while the rudder is fixed at zero. The torpedo is nearly neutral in pitch (its only restoring
  moment is zB B), so an open-loop PRBS would let pitch and depth random-walk; the vertical
  mode adds the autopilot's slow hold (`testbed.autopilot`, poles at 0.2 rad/s = 0.03 Hz, on θ
  and depth only) to both elevators. Measured over seeds 0–19 at the defaults (60 s): the
  actual (equal) elevator deflection correlates with the PRBS at 0.93–0.94 (the commanded one
  at 0.986–0.996; the rest is the fin servo's lag), the correction carries 0.2–0.4 % of the
  PRBS's power above 0.1 Hz, |θ| stays under 0.19 rad and the depth within 12 m (tested with
  margins: ≥ 0.9, < 1 %, 0.3 rad, 20 m).
- `turn` (turning circle, rudder 0.2 rad, depth and roll held), `zigzag` (20/20: rudder ±20 deg,
  switched when the heading passes ∓20 deg from the initial one; depth and roll held) and
  `zigzag-vertical` (its counterpart in pitch: elevators together ±20 deg, switched at ∓20 deg
  of pitch, rudder at zero).

`EXPERIMENTS` is the one table of scenarios and their experiments.

The PRBS comes from a maximal-length linear feedback shift register (`prbs`). Its default clock
period (0.1 s) puts the −3 dB point of its spectrum at 4.4 Hz, above the vehicle's fastest
sway-yaw and heave-pitch poles (23.7 rad/s = 3.8 Hz), and its period (order 10: 1023 bits,
102 s) exceeds an experiment, so its lines (every 0.01 Hz) cover the whole band the data must
excite within 3 dB (`prbs_spectrum`; tested).

`simulate` writes a run directory (SPEC §3) whole or not at all.
"""

from __future__ import annotations

import datetime
import hashlib
import json
import math
import numbers
import shlex
import sys
import time
from dataclasses import asdict, dataclass, field, replace
from importlib import metadata
from pathlib import Path
from typing import Callable

import numpy as np

from testbed.autopilot import FIN_LIMIT, Autopilot, design
from testbed.data import MIN_ROWS, config_text, csv_text
from testbed.errors import InputError, atomic_directory
from testbed.measurements import Sensors, check_seed, measure, rng_for
from testbed.model import IX, NX, STATES
from testbed.plant import Plant
from testbed.vehicle import MAX_SPEED, MIN_SPEED, cruise_speed, default_mjcf

# Maximal-length feedback taps (1-indexed register stages) for orders 2..20.
TAPS = {2: (2, 1), 3: (3, 2), 4: (4, 3), 5: (5, 3), 6: (6, 5), 7: (7, 6), 8: (8, 6, 5, 4),
        9: (9, 5), 10: (10, 7), 11: (11, 9), 12: (12, 11, 10, 4), 13: (13, 12, 11, 8),
        14: (14, 13, 12, 2), 15: (15, 14), 16: (16, 15, 13, 4), 17: (17, 14), 18: (18, 11),
        19: (19, 18, 17, 14), 20: (20, 17)}  # fmt: skip


def _finite(v) -> bool:
    return isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(v)


def _positive(v) -> bool:
    return _finite(v) and v > 0


def _fin_angle(v) -> bool:
    return _finite(v) and 0 < abs(v) <= FIN_LIMIT


# Settings a user can get wrong: what each must be. The CLI exposes duration and speed.
_CHECKS = {
    "duration": (_positive, "a finite number > 0 (s)"),
    "speed": (lambda v: v is None or (_finite(v) and MIN_SPEED <= v <= MAX_SPEED), f"{MIN_SPEED} to {MAX_SPEED} (m/s)"),
    "depth": (_finite, "a finite number (m)"),
    "control_rate": (_positive, "a finite number > 0 (Hz)"),
    "depth_step": (_finite, "a finite number (m)"),
    "depth_period": (_positive, "a finite number > 0 (s)"),
    "yaw_rate": (_finite, "a finite number (rad/s)"),
    "yaw_period": (_positive, "a finite number > 0 (s)"),
    "prbs_order": (lambda v: isinstance(v, numbers.Integral) and v in TAPS, f"an integer in {min(TAPS)}..{max(TAPS)}"),
    "prbs_clock": (_positive, "a finite number > 0 (s)"),
    "prbs_rudder": (_fin_angle, f"0 < |angle| <= {FIN_LIMIT} rad"),
    "prbs_elevators": (_fin_angle, f"0 < |angle| <= {FIN_LIMIT} rad"),
    "turn_rudder": (_fin_angle, f"0 < |angle| <= {FIN_LIMIT} rad"),
    "zigzag_angle": (lambda v: _fin_angle(v) and v > 0, f"0 < angle <= {FIN_LIMIT} rad"),
}
SAMPLES = (MIN_ROWS, 10**6)  # the samples an experiment may have (MIN_ROWS: the fewest a fit takes)
CLI_SETTINGS = ("duration", "speed")  # the settings `testbed simulate` exposes (--duration, --speed)


@dataclass(frozen=True)
class Settings:
    """Everything that defines a run besides the scenario and the seed (defaults: the paper's)."""

    duration: float = 60.0  # s per experiment
    speed: float | None = None  # trim speed, m/s (None: the vehicle's cruise speed)
    depth: float = 100.0  # initial depth, m
    control_rate: float = 50.0  # Hz, autopilot
    sensors: Sensors = field(default_factory=Sensors)
    depth_step: float = 20.0  # Scenario I: m every depth_period
    depth_period: float = 5.0  # s
    yaw_rate: float = math.radians(20.0)  # Scenario I: ± rad/s every yaw_period
    yaw_period: float = 1.5  # s
    prbs_order: int = 10
    prbs_clock: float = 0.1  # s
    prbs_rudder: float = 0.02  # rad, horizontal mode
    # rad, vertical mode: the elevators together turn the pitch fast (θ̇ ≈ 24.5 δe at 20 m/s)
    # and pitch is held only below 0.03 Hz; 0.005 rad keeps |θ| under 0.2 rad over 60 s (0.02
    # tilts the torpedo by up to 0.75 rad, far outside the linear model)
    prbs_elevators: float = 0.005
    turn_rudder: float = 0.2  # rad
    zigzag_angle: float = math.radians(20.0)  # rad: fin angle and switching angle

    def __post_init__(self):
        for name, (ok, expected) in _CHECKS.items():
            value = getattr(self, name)
            if not ok(value):
                where = f"--{name}" if name in CLI_SETTINGS else f"setting {name}"
                raise InputError(f"{where} {value!r}; expected {expected}")
        # what a record can be: enough samples to fit, few enough to hold (~1 kB each in flight)
        rate, (low, high) = self.sensors.rate, SAMPLES
        if not low <= math.floor(self.duration * rate + 1e-9) + 1 <= high:
            raise InputError(f"--duration {self.duration!r}; expected {(low - 1) / rate:g} to "
                             f"{(high - 1) / rate:g} s ({low} to {high} samples at {rate:g} Hz)")


@dataclass(frozen=True)
class Flight:
    """One experiment as flown: true and measured states at the sample times, and what drove them."""

    name: str
    t: np.ndarray  # (N,)
    truth: np.ndarray  # (N, 10) SPEC states, absolute u, psi unwrapped
    measured: np.ndarray  # (N, 10)
    fins: np.ndarray  # (N, 3) actual fin angles
    fins_measured: np.ndarray  # (N, 3)
    position: np.ndarray  # (N, 3) NED, m
    # name -> (N,): the program's autopilot keywords (e.g. depth, yaw_rate, rudder, elevators;
    # NaN where absent), the autopilot's pitch command, the fin commands fin_r, fin_er, fin_el
    commands: dict


# -- input signals ---------------------------------------------------------------------------


def prbs(order: int, rng: np.random.Generator | None = None) -> np.ndarray:
    """One period (2^order − 1 bits, ±1) of the maximal-length LFSR sequence; `rng` picks the
    (non-zero) initial register, i.e. the phase."""
    if order not in TAPS:
        raise InputError(f"PRBS order {order}; expected one of {min(TAPS)}..{max(TAPS)}")
    state = [1] * order
    if rng is not None:
        while not any(state := list(rng.integers(0, 2, order))):
            pass
    out = np.empty(2**order - 1)
    for k in range(len(out)):
        out[k] = 1.0 if state[-1] else -1.0
        feedback = 0
        for tap in TAPS[order]:
            feedback ^= state[tap - 1]
        state = [feedback] + state[:-1]
    return out


def prbs_spectrum(order: int, clock: float, n: int = 4096) -> tuple[np.ndarray, np.ndarray]:
    """Power spectrum (frequency Hz, power per line) of the periodic PRBS with bit time `clock`.

    Lines at multiples of 1/((2^order − 1) clock) with envelope sinc²(f clock): the -3 dB point
    is at 0.44/clock, the first null at 1/clock.
    """
    bits = 2**order - 1
    f = np.arange(1, n + 1) / (bits * clock)
    return f, (bits + 1) / bits**2 * np.sinc(f * clock) ** 2


# -- the experiments: command programs -----------------------------------------------------------

Program = Callable[[float, np.ndarray], dict]  # (t, x) -> Autopilot.step keywords


def _held(s: Settings, **drive) -> dict:
    """Depth and roll held by the elevator autopilots while `drive` commands the rest."""
    return {"depth": s.depth, "roll": 0.0, **drive}


def _periods(t: float, period: float) -> int:
    """Whole periods elapsed at `t`; t = k Δt lands on a boundary as on it, not a rounding before."""
    return math.floor(t / period + 1e-9)


def _prbs_signal(s: Settings, seed: int, index: int, amplitude: float) -> Callable[[float], float]:
    bits = amplitude * prbs(s.prbs_order, rng_for(seed, index, 1))
    return lambda t: bits[_periods(t, s.prbs_clock) % len(bits)]


def _scenario_i(s: Settings, seed: int, index: int) -> Program:
    def program(t, x):
        depth = s.depth + s.depth_step * (_periods(t, s.depth_period) % 2)
        r = s.yaw_rate * (1 if _periods(t, s.yaw_period) % 2 == 0 else -1)
        return {"depth": depth, "yaw_rate": r, "roll": 0.0}

    return program


def _horizontal(s: Settings, seed: int, index: int) -> Program:
    value = _prbs_signal(s, seed, index, s.prbs_rudder)
    return lambda t, x: _held(s, rudder=value(t))


def _vertical(s: Settings, seed: int, index: int) -> Program:
    value = _prbs_signal(s, seed, index, s.prbs_elevators)
    return lambda t, x: {"elevators": value(t), "hold_depth": s.depth}


def _turn(s: Settings, seed: int, index: int) -> Program:
    return lambda t, x: _held(s, rudder=s.turn_rudder)


def _zigzag(state: str, drive: Callable[[float], dict]):
    """The zigzag on `state` (psi or theta): fins at ±zigzag_angle (keywords `drive(settings,
    angle)`), switched when `state` passes ∓zigzag_angle from its initial value."""

    def build(s: Settings, seed: int, index: int) -> Program:
        k, sign, start = IX[state], [1.0], []

        def program(t, x):
            if not start:
                start.append(x[k])
            # wrapped, so a heading near ±π does not jump by 2π
            angle = (x[k] - start[0] + math.pi) % (2 * math.pi) - math.pi
            # A positive fin turns the nose negative (rudder: to port; elevators: down).
            if sign[0] > 0 and angle <= -s.zigzag_angle:
                sign[0] = -1.0
            elif sign[0] < 0 and angle >= s.zigzag_angle:
                sign[0] = 1.0
            return drive(s, sign[0] * s.zigzag_angle)

        return program

    return build


# The single table of scenarios: scenario -> experiment name -> its program's builder
# (settings, seed, index of the experiment in the scenario).
EXPERIMENTS: dict[str, dict[str, Callable[[Settings, int, int], Program]]] = {
    "I": {"scenario-I": _scenario_i},
    "II": {"horizontal": _horizontal, "vertical": _vertical},
    "turn": {"turn": _turn},
    "zigzag": {"zigzag": _zigzag("psi", lambda s, d: _held(s, rudder=d))},
    "zigzag-vertical": {"zigzag-vertical": _zigzag("theta", lambda s, d: {"rudder": 0.0, "elevators": d})},
}


def experiments(scenario: str) -> dict[str, Callable[[Settings, int, int], Program]]:
    """The experiments of `scenario`; InputError if it is not one."""
    if scenario not in EXPERIMENTS:
        raise InputError(f"--scenario {scenario!r} is unknown; expected one of {', '.join(EXPERIMENTS)}")
    return EXPERIMENTS[scenario]


def programs(scenario: str, s: Settings, seed: int) -> dict[str, Program]:
    """The command programs of a scenario's experiments."""
    check_seed(seed)
    return {name: build(s, seed, k) for k, (name, build) in enumerate(experiments(scenario).items())}


# -- flying ------------------------------------------------------------------------------------

FIN_COMMANDS = ("fin_r", "fin_er", "fin_el")


def fly(plant: Plant, autopilot: Autopilot, name: str, program: Program, s: Settings,
        rng: np.random.Generator, progress: Callable[[float], None] | None = None) -> Flight:  # fmt: skip
    """Fly one experiment from straight and level trim; sample, and add sensor noise."""
    speed = s.speed if s.speed is not None else cruise_speed(plant.model)
    plant.reset(speed=speed, depth=s.depth)
    per_control = plant.timestep * s.control_rate
    steps = round(1.0 / per_control)
    controls_per_sample = round(s.control_rate / s.sensors.rate)
    if abs(1.0 / per_control - steps) > 1e-9 or abs(s.control_rate / s.sensors.rate - controls_per_sample) > 1e-9:
        raise InputError(f"control rate {s.control_rate} Hz and sample rate {s.sensors.rate} Hz must "
                         f"divide the physics rate {1 / plant.timestep:g} Hz and each other")  # fmt: skip
    n_samples = int(math.floor(s.duration * s.sensors.rate + 1e-9)) + 1
    truth, fins, pos = np.empty((n_samples, NX)), np.empty((n_samples, 3)), np.empty((n_samples, 3))
    fin_cmds, pitch, keywords = np.empty((n_samples, 3)), np.empty(n_samples), []
    autopilot.reset()
    control_dt = 1.0 / s.control_rate
    # The per-step work is Python around a ~0.15 ms plant step: keep it to what is needed.
    for k in range((n_samples - 1) * controls_per_sample + 1):
        x = plant.state()
        kw = program(k * control_dt, x)
        command, theta_cmd = autopilot.step(x, **kw)
        i, rest = divmod(k, controls_per_sample)
        if not rest:
            truth[i], fins[i], pos[i], fin_cmds[i] = x, plant.fin_angles(), plant.position(), command
            pitch[i] = np.nan if theta_cmd is None else theta_cmd
            keywords.append(kw)
            if progress and i % 50 == 0:
                progress(i / n_samples)
            if i == n_samples - 1:
                break
        plant.step(command, n=steps)
    truth[:, IX["psi"]] = np.unwrap(truth[:, IX["psi"]])
    # The input of sample k is held over [t_k, t_k+1) by the model (zero-order hold): record the
    # fin angle averaged over that interval (trapezoid), as an encoder with an anti-alias filter.
    fins[:-1] = 0.5 * (fins[:-1] + fins[1:])
    measured, fins_measured = measure(truth, fins, s.sensors, rng)
    commands = {key: np.array([kw.get(key, np.nan) for kw in keywords], float)
                for key in sorted({key for kw in keywords for key in kw})}  # fmt: skip
    commands.update(zip(FIN_COMMANDS, fin_cmds.T))
    if not np.isnan(pitch).all():
        commands["pitch"] = pitch
    t = np.arange(n_samples) / s.sensors.rate
    return Flight(name, t, truth, measured, fins, fins_measured, pos, commands)


def fly_scenario(scenario: str, seed: int = 0, settings: Settings = Settings(), mjcf=None,
                 progress: Callable[[str, float], None] | None = None) -> tuple[list[Flight], object]:  # fmt: skip
    """Fly every experiment of `scenario`; returns the flights and the analytic linear model."""
    from testbed.truth import analytic_model

    check_seed(seed)
    experiments(scenario)
    plant = Plant(mjcf)
    speed = settings.speed if settings.speed is not None else cruise_speed(plant.model)
    settings = replace(settings, speed=speed)
    lin = analytic_model(plant.model, speed)
    autopilot = Autopilot(design(lin.A_full, lin.B_full, speed), 1.0 / settings.control_rate)
    flights = []
    for k, (name, program) in enumerate(programs(scenario, settings, seed).items()):
        report = (lambda f, name=name: progress(name, f)) if progress else None
        flights.append(fly(plant, autopilot, name, program, settings, rng_for(seed, k, 0), report))
    return flights, lin


# -- run directories ---------------------------------------------------------------------------


def simulate(scenario: str, *, seed: int = 0, out=None, force: bool = False, duration=None,
             speed=None, mjcf=None, progress: bool = True, settings: Settings | None = None) -> Path:  # fmt: skip
    """Fly `scenario` and write its run directory (SPEC §3); returns its path."""
    from testbed.report import log_run
    from testbed.truth import model_config

    n_experiments = len(experiments(scenario))
    check_seed(seed)
    settings = settings or Settings()
    if duration is not None:
        settings = replace(settings, duration=float(duration))
    if speed is not None:
        settings = replace(settings, speed=float(speed))
    out = Path(out) if out is not None else Path("runs") / f"{scenario}-seed{seed}"
    mjcf_path = Path(mjcf) if mjcf is not None else default_mjcf()
    started = datetime.datetime.now(datetime.timezone.utc)
    bar = _ProgressBar(n_experiments) if progress else None
    with atomic_directory(out, force) as tmp:
        flights, lin = fly_scenario(scenario, seed, settings, mjcf_path, bar)
        for f in flights:
            (tmp / f"{f.name}.csv").write_text(csv_text(f.t, f.measured, f.fins_measured, STATES))
            (tmp / f"{f.name}.truth.csv").write_text(csv_text(f.t, f.truth, f.fins, STATES))
        config, comments = model_config(lin, mjcf_path)
        (tmp / "model.toml").write_text(config_text(config, comments))
        log_run(tmp / "recording.rrd", flights, mjcf_path, title=f"testbed {scenario} seed {seed}")
        settings = replace(settings, speed=lin.vehicle.speed)
        manifest = {
            "scenario": scenario,
            "seed": seed,
            "experiments": [f.name for f in flights],
            "settings": asdict(settings),
            "mjcf": str(mjcf_path.resolve()),
            "mjcf_sha256": hashlib.sha256(mjcf_path.read_bytes()).hexdigest(),
            "versions": _versions(),
            **_command(scenario, seed, settings, mjcf),
            "started": started.isoformat(),
            "finished": datetime.datetime.now(datetime.timezone.utc).isoformat(),
        }
        (tmp / "manifest.json").write_text(json.dumps(manifest, indent=2) + "\n")
        if bar:
            bar.done()
    return out


def _versions() -> dict[str, str]:
    """Versions of Python and the packages in play; a loaded module's own `__version__` (what
    ran, and ~10 ms faster each than reading the installed metadata)."""
    out = {"python": sys.version.split()[0]}
    for pkg, module in (("testbed", None), ("mujoco", "mujoco"), ("numpy", "numpy"), ("scipy", "scipy"),
                        ("numba", "numba"), ("rerun-sdk", "rerun"), ("filterpy", None)):  # fmt: skip
        version = getattr(sys.modules.get(module), "__version__", None)
        try:
            out[pkg] = version or metadata.version(pkg)
        except metadata.PackageNotFoundError:
            out[pkg] = "not installed"
    return out


def _command(scenario, seed, settings: Settings, mjcf) -> dict:
    """The manifest's `command` that regenerates the run (floats exact: repr round-trips), and
    which settings the command line cannot set: it reproduces the run only if those have their
    defaults (`command_reproduces_run`); otherwise `settings` has them."""
    parts = ["testbed", "simulate", "--scenario", scenario, "--seed", str(seed),
             "--duration", repr(float(settings.duration)), "--speed", repr(float(settings.speed))]  # fmt: skip
    if mjcf is not None:
        parts += ["--mjcf", str(Path(mjcf).resolve())]
    default, given = asdict(Settings()), asdict(settings)
    hidden = [name for name in given if name not in CLI_SETTINGS]
    return {"command": shlex.join(parts), "settings_not_on_command_line": hidden,
            "command_reproduces_run": all(given[n] == default[n] for n in hidden)}  # fmt: skip


class _ProgressBar:
    """A one-line text progress bar on stderr (only when stderr is a terminal)."""

    def __init__(self, experiments: int):
        self.experiments, self.index, self.name = experiments, -1, None
        self.live = sys.stderr.isatty()
        self.t0 = time.perf_counter()

    def __call__(self, name: str, fraction: float):
        if name != self.name:
            self.name, self.index = name, self.index + 1
        total = (self.index + fraction) / self.experiments
        if self.live:
            bar = "#" * int(30 * total)
            sys.stderr.write(f"\r[{bar:<30}] {100 * total:3.0f}% {name:<16}")
            sys.stderr.flush()

    def done(self):
        if self.live:
            sys.stderr.write(f"\r[{'#' * 30}] 100% done in {time.perf_counter() - self.t0:.1f} s\n")
