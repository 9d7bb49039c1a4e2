"""The paper's scenarios and validation manoeuvres, flown by the truth plant, written as runs.

- `I` (the paper's sea-trial scenario): the depth command changes by 20 m every 5 s, the
  course-rate command switches between +20 and −20 deg/s every 1.5 s, the roll command is zero;
  all three autopilots fly it. One experiment, `scenario-I`.
- `II`: `horizontal` — depth and roll held by the elevator autopilots while the rudder follows a
  PRBS; `vertical` — both elevators follow the same PRBS while the rudder is fixed at zero. The
  torpedo's pitch is nearly neutral (its only restoring moment is zB B), so an open-loop PRBS
  would let pitch random-walk to vertical within a minute; the depth autopilot therefore stays
  on in vertical mode, adding the same slow correction to both elevators (equal deflections,
  the PRBS dominating above 0.1 Hz).
- `turn` (turning circle, rudder 0.2 rad, depth and roll held), `zigzag` (20/20: rudder ±20 deg,
  switched when the heading passes ∓20 deg from the initial one) and `zigzag-vertical` (its
  counterpart in pitch: elevators together ±20 deg, switched at ∓20 deg of pitch).

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
import sys
import time
from dataclasses import asdict, dataclass, field, replace
from importlib import metadata
from pathlib import Path
from typing import Callable

import numpy as np

from testbed.autopilot import Autopilot, design
from testbed.data import config_text, csv_text
from testbed.errors import InputError, atomic_directory
from testbed.measurements import Sensors, measure, rng_for
from testbed.model import IX, STATES
from testbed.plant import Plant
from testbed.vehicle import cruise_speed, default_mjcf

# Maximal-length feedback taps (1-indexed register stages) for orders 2..20.
TAPS = {2: (2, 1), 3: (3, 2), 4: (4, 3), 5: (5, 3), 6: (6, 5), 7: (7, 6), 8: (8, 6, 5, 4),
        9: (9, 5), 10: (10, 7), 11: (11, 9), 12: (12, 11, 10, 4), 13: (13, 12, 11, 8),
        14: (14, 13, 12, 2), 15: (15, 14), 16: (16, 15, 13, 4), 17: (17, 14), 18: (18, 11),
        19: (19, 18, 17, 14), 20: (20, 17)}  # fmt: skip

EXPERIMENTS = {"I": ("scenario-I",), "II": ("horizontal", "vertical"), "turn": ("turn",),
               "zigzag": ("zigzag",), "zigzag-vertical": ("zigzag-vertical",)}  # fmt: skip


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
    prbs_amplitude: float = 0.02  # rad (rudder in horizontal, elevators in vertical)
    turn_rudder: float = 0.2  # rad
    zigzag_angle: float = math.radians(20.0)  # rad: fin angle and switching angle


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
    commands: dict  # name -> (N,) command signal


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


# -- flying ------------------------------------------------------------------------------------


Program = Callable[[float, np.ndarray], tuple[dict, dict]]  # (t, x) -> (autopilot kwargs, commands)


def programs(scenario: str, s: Settings, seed: int) -> dict[str, Program]:
    """The command programs of a scenario's experiments."""
    z0 = s.depth

    def scenario_i(t, x):
        depth = z0 + s.depth_step * (int(t // s.depth_period) % 2)
        r = s.yaw_rate * (1 if int(t // s.yaw_period) % 2 == 0 else -1)
        return {"depth": depth, "yaw_rate": r, "roll": 0.0}, {"depth": depth, "yaw_rate": r, "roll": 0.0}

    def prbs_program(k):
        bits = prbs(s.prbs_order, rng_for(seed, k, 1))

        def value(t):
            return s.prbs_amplitude * bits[int(t // s.prbs_clock) % len(bits)]

        return value

    def horizontal(value):
        def program(t, x):
            d = value(t)
            return {"depth": z0, "roll": 0.0, "rudder": d}, {"depth": z0, "roll": 0.0, "delta_r": d}

        return program

    def vertical(value):
        def program(t, x):
            d = value(t)
            return {"depth": z0, "elevator_excitation": d}, {"depth": z0, "delta_e_prbs": d}

        return program

    def turn(t, x):
        return ({"depth": z0, "roll": 0.0, "rudder": s.turn_rudder},
                {"depth": z0, "roll": 0.0, "delta_r": s.turn_rudder})  # fmt: skip

    def zigzag(kind):
        k = IX["psi"] if kind == "rudder" else IX["theta"]
        sign = [1.0]
        start = []

        def program(t, x):
            if not start:
                start.append(x[k])
            angle = x[k] - start[0]
            # A positive fin turns the nose negative (rudder: to port; elevators: down).
            if sign[0] > 0 and angle <= -s.zigzag_angle:
                sign[0] = -1.0
            elif sign[0] < 0 and angle >= s.zigzag_angle:
                sign[0] = 1.0
            d = sign[0] * s.zigzag_angle
            if kind == "rudder":
                return {"depth": z0, "roll": 0.0, "rudder": d}, {"depth": z0, "roll": 0.0, "delta_r": d}
            return {"elevators": d}, {"delta_r": 0.0, "delta_er": d, "delta_el": d}

        return program

    table = {
        "I": lambda: {"scenario-I": scenario_i},
        "II": lambda: {"horizontal": horizontal(prbs_program(0)), "vertical": vertical(prbs_program(1))},
        "turn": lambda: {"turn": turn},
        "zigzag": lambda: {"zigzag": zigzag("rudder")},
        "zigzag-vertical": lambda: {"zigzag-vertical": zigzag("elevators")},
    }
    if scenario not in table:
        raise InputError(f"--scenario {scenario!r} is unknown; expected one of {', '.join(table)}")
    return table[scenario]()


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
    rows, fins, pos, cmds = [], [], [], []
    autopilot.integrators[:] = 0.0
    control_dt = 1.0 / s.control_rate
    for k in range((n_samples - 1) * controls_per_sample + 1):
        t = k * control_dt
        x = plant.state()
        kwargs, record = program(t, x)
        command, refs = autopilot.step(x, **kwargs)
        if k % controls_per_sample == 0:
            rows.append(x)
            fins.append(plant.fin_angles())
            pos.append(plant.position())
            cmds.append({**record, **refs, **dict(zip(("fin_r", "fin_er", "fin_el"), command))})
            if progress and len(rows) % 50 == 0:
                progress(len(rows) / n_samples)
        if len(rows) == n_samples:
            break
        plant.step(command, n=steps)
    truth = np.array(rows)
    truth[:, IX["psi"]] = np.unwrap(truth[:, IX["psi"]])
    # The input of sample k is held over [t_k, t_k+1) by the model (zero-order hold): record the
    # fin angle averaged over that interval (trapezoid), as an encoder with an anti-alias filter.
    fins = np.array(fins)
    fins[:-1] = 0.5 * (fins[:-1] + fins[1:])
    measured, fins_measured = measure(truth, fins, s.sensors, rng)
    names = sorted({key for c in cmds for key in c})
    commands = {key: np.array([c.get(key, np.nan) for c in cmds]) for key in names}
    t = np.arange(n_samples) / s.sensors.rate
    return Flight(name, t, truth, measured, fins, fins_measured, np.array(pos), commands)


def fly_scenario(scenario: str, seed: int = 0, settings: Settings = Settings(), mjcf=None,
                 progress: Callable[[str, float], None] | None = None) -> tuple[list[Flight], object]:  # fmt: skip
    """Fly every experiment of `scenario`; returns the flights and the analytic linear model."""
    from testbed.truth import analytic_model

    if not settings.duration > 0:
        raise InputError(f"--duration {settings.duration}; expected > 0 s")
    plant = Plant(mjcf)
    speed = settings.speed if settings.speed is not None else cruise_speed(plant.model)
    if not speed > 0:
        raise InputError(f"--speed {speed}; expected > 0 m/s")
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

    if scenario not in EXPERIMENTS:
        raise InputError(f"--scenario {scenario!r} is unknown; expected one of {', '.join(EXPERIMENTS)}")
    settings = settings or Settings()
    if duration is not None:
        settings = replace(settings, duration=float(duration))
    if speed is not None:
        settings = replace(settings, speed=float(speed))
    out = Path(out) if out is not None else Path("runs") / f"{scenario}-seed{seed}"
    mjcf_path = Path(mjcf) if mjcf is not None else default_mjcf()
    started = datetime.datetime.now(datetime.timezone.utc)
    bar = _ProgressBar(len(EXPERIMENTS[scenario])) if progress else None
    with atomic_directory(out, force) as tmp:
        flights, lin = fly_scenario(scenario, seed, settings, mjcf_path, bar)
        for f in flights:
            (tmp / f"{f.name}.csv").write_text(csv_text(f.t, f.measured, f.fins_measured, STATES))
            (tmp / f"{f.name}.truth.csv").write_text(csv_text(f.t, f.truth, f.fins, STATES))
        config, comments = model_config(lin, mjcf_path)
        (tmp / "model.toml").write_text(config_text(config, comments))
        log_run(tmp / "recording.rrd", flights, mjcf_path, title=f"testbed {scenario} seed {seed}")
        manifest = {
            "scenario": scenario,
            "seed": seed,
            "experiments": [f.name for f in flights],
            "settings": asdict(replace(settings, speed=lin.vehicle.speed)),
            "mjcf": str(mjcf_path.resolve()),
            "mjcf_sha256": hashlib.sha256(mjcf_path.read_bytes()).hexdigest(),
            "versions": _versions(),
            "command": _command(scenario, seed, settings, mjcf),
            "started": started.isoformat(),
            "finished": datetime.datetime.now(datetime.timezone.utc).isoformat(),
        }
        (tmp / "manifest.json").write_text(json.dumps(manifest, indent=2) + "\n")
        if bar:
            bar.done()
    return out


def _versions() -> dict[str, str]:
    out = {"python": sys.version.split()[0]}
    for pkg in ("testbed", "mujoco", "numpy", "scipy", "numba", "rerun-sdk", "filterpy"):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            out[pkg] = "not installed"
    return out


def _command(scenario, seed, settings: Settings, mjcf) -> str:
    """The command line that regenerates this run (settings the CLI does not expose are in
    the manifest's `settings`)."""
    parts = ["testbed", "simulate", "--scenario", scenario, "--seed", str(seed),
             "--duration", f"{settings.duration:g}"]  # fmt: skip
    if settings.speed is not None:
        parts += ["--speed", f"{settings.speed:g}"]
    if mjcf is not None:
        parts += ["--mjcf", str(mjcf)]
    return " ".join(parts)


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
