"""A scenario flown (`fly_scenario`): each experiment's command program (its fin signals and
autopilot loops, `program`), flown by the truth with its sensors and fin encoders logged.

A scenario flies on the MuJoCo plant or, as the linear-truth arm, on the analytic linear model
itself (`fly_scenario(..., truth="linear")`): the same autopilots, fin range and rate, signals
and noise streams, so only the plant differs. `runs.simulate` writes a run directory whole or
not at all, with the resolved scenario as `scenario.toml`, which `testbed simulate --scenario`
runs again.
"""

from __future__ import annotations
from dataclasses import dataclass, replace
from typing import Callable
import numpy as np
from testbed.simulation.autopilot import Autopilot
from testbed.errors import InputError
from testbed.simulation.measurements import check_seed, interval_means, measure, rng_for
from testbed.models.linear import IX, NX, continuous, structure, theta_vector, tilde
from testbed.models.sensors import Sensor, outputs
from testbed.simulation.imperfect import TrialFlight
from testbed.simulation.linear_plant import LinearPlant
from testbed.simulation.plant import Plant
from testbed.simulation.analytic import analytic_model
from testbed.simulation.vehicle import cruise_speed
from testbed.simulation.scenario import CHANNELS, ExperimentSpec, LOOPS, SAMPLES, Scenario, TRUTHS, scenario

__all__ = [
    "FIN_COMMANDS",
    "FinLog",
    "Flight",
    "CommandProgram",
    "check_fins",
    "check_flyable",
    "check_truth",
    "fly",
    "fly_scenario",
    "program",
]


CommandProgram = Callable[[float, np.ndarray], dict]  # (t, x) -> Autopilot.step keywords


def program(s: Scenario, e: ExperimentSpec, seed: int, index: int) -> CommandProgram:
    """The command program of experiment `e` (the `index`-th of `s`) for `seed`: at each control
    instant, the Autopilot keywords. Each signal has its own random stream (the PRBS phase)."""
    check_seed(seed)
    streams = {name: k + 1 for k, name in enumerate((*CHANNELS, *LOOPS, "hold"))}
    fins = {c: sig.program(rng_for(seed, index, streams[c])) for c, sig in e.fins.items()}
    loops = {k: sig.program(rng_for(seed, index, streams[k])) for k, sig in e.autopilot.items()}
    hold = e.hold_depth.program(rng_for(seed, index, streams["hold"])) if e.hold_depth else None
    depth0 = s.depth

    def commands(t, x):
        kw = {c: f(t, x) for c, f in fins.items()}
        for loop, f in loops.items():
            kw[loop] = f(t, x) + (depth0 if loop == "depth" else 0.0)
        if hold is not None:
            kw["hold_depth"] = depth0 + hold(t, x)
        return kw

    return commands


FIN_COMMANDS = ("fin_r", "fin_er", "fin_el")


@dataclass(frozen=True)
class Flight:
    """One experiment as flown: true and measured states at the sample times, and what drove them."""

    name: str
    t: np.ndarray  # (N,)
    truth: np.ndarray  # (N, 10) the model states, absolute u, psi unwrapped
    measured: np.ndarray  # (N, 10)
    fins: np.ndarray  # (N, 3) actual fin angles: each sample interval's mean (the last: the angle)
    fins_measured: np.ndarray  # (N, 3)
    position: np.ndarray  # (N, 3) NED, m
    # name -> (N,): the program's autopilot keywords (e.g. depth, yaw_rate, rudder, elevators;
    # NaN where absent), the autopilot's pitch command, the fin commands fin_r, fin_er, fin_el
    commands: dict
    specific_force: np.ndarray | None = None  # (N, 3) ax ay az where a sensor reads them
    fin_log: FinLog | None = None  # the fins logged faster than the samples (`Sensors.fin_rate`)


@dataclass(frozen=True)
class FinLog:
    """A flight at its fin log's instants (M = (N − 1)·fin_rate/rate + 1 of them): the true
    states (M, 10), the fins' true mean angle over each log interval (the last: the angle) and
    that angle as the encoders read it (M, 3)."""

    t: np.ndarray
    truth: np.ndarray
    fins: np.ndarray
    measured: np.ndarray


def fly(
    plant: Plant | LinearPlant,
    autopilot: Autopilot,
    name: str,
    program: CommandProgram,
    s: Scenario,
    duration: float,
    rng: np.random.Generator,
    progress: Callable[[float], None] | None = None,
    streams: Callable[[int], np.random.Generator] | None = None,
    weight: float = 0.0,
) -> Flight:
    """Fly one experiment of `duration` s from straight and level trim; sample, add sensor noise.
    An imperfect scenario (named sensors, a trial's imperfections) is flown one plant step at a
    time, the trajectory kept at every step for its sensors: `streams(k)` gives random stream k
    (the turbulence's, the named sensors' noise), `weight` the vehicle's weight (N)."""
    speed = s.speed if s.speed is not None else cruise_speed(plant.model)
    plant.reset(speed=speed, depth=s.depth)
    per_control = plant.timestep * s.control_rate
    steps = round(1.0 / per_control)
    if abs(1.0 / per_control - steps) > 1e-9:
        raise InputError(
            f"control rate {s.control_rate} Hz; expected it to divide the physics rate "
            f"{1 / plant.timestep:g} Hz"
        )
    # the fins logged `chunks` times a control interval: the plant stepped in as many parts
    chunks = 1 if s.sensors.fin_rate is None else round(s.sensors.fin_rate / s.control_rate)
    if steps % chunks:
        raise InputError(
            f"{s.where}: sensors.fin_rate = {s.sensors.fin_rate:g} Hz; expected it to divide the physics rate "
            f"{1 / plant.timestep:g} Hz"
        )
    t, at = s.stamps(duration)  # the samples' instants and control steps
    n_samples = len(t)
    logged = None if s.sensors.fin_rate is None else int(at[-1]) * chunks + 1
    fin_log, fine_truth = (None, None) if logged is None else (np.empty((logged, 3)), np.empty((logged, NX)))
    truth, fins, pos = np.empty((n_samples, NX)), np.empty((n_samples, 3)), np.empty((n_samples, 3))
    fin_cmds, pitch, keywords = np.empty((n_samples, 3)), np.empty(n_samples), []
    fin_integral = np.empty((n_samples, 3))
    autopilot.reset()
    control_dt = 1.0 / s.control_rate
    fine = None
    if not s.is_perfect:
        fine = TrialFlight(plant, s.trial, int(at[-1]) * steps + 1, streams, weight)
    # Read back by measured feedback: each state as the default sensor reads it (over the ground
    # in a current) plus its white noise, drawn at every control instant; the record's samples
    # are the readings at the sample instants (ψ unwrapped there). The fins are a function of the
    # record when every control instant is a sample and the record keeps every state read.
    std = noise = None
    if s.feedback == "measured":
        std, noise = s.sensors.std, np.empty((n_samples, NX))
    reader = Sensor() if any(s.trial.current) else None
    # The per-step work is Python around a ~0.15 ms plant step: keep it to what is needed.
    i = 0  # the next sample
    for k in range(int(at[-1]) + 1):
        x = plant.state()
        read = x
        if std is not None:
            drawn = rng.standard_normal(NX) * std
            read = (x if reader is None else outputs(reader, x, current=s.trial.current)) + drawn
        kw = program(k * control_dt, read)
        command, theta_cmd = autopilot.step(read, **kw)
        if k == at[i]:
            truth[i], fins[i], pos[i], fin_cmds[i] = x, plant.fin_angles(), plant.position(), command
            if noise is not None:
                noise[i] = drawn
            fin_integral[i] = plant.fin_integral()
            pitch[i] = np.nan if theta_cmd is None else theta_cmd
            keywords.append(kw)
            if progress and i % 50 == 0:
                progress(i / n_samples)
            if i == n_samples - 1:
                if fine is not None:
                    fine.record(x)
                break
            i += 1
        if fin_log is not None:
            for c in range(chunks):
                fine_truth[k * chunks + c], fin_log[k * chunks + c] = plant.state(), plant.fin_integral()
                plant.step(command, n=steps // chunks)
        elif fine is None:
            plant.step(command, n=steps)
        else:
            fine.advance(x, command, steps)
    truth[:, IX["psi"]] = np.unwrap(truth[:, IX["psi"]])
    # The input of sample k is held over [t_k, t_k+1) by the model (zero-order hold): record the
    # fin angle's mean over that interval (exact: the plant holds the fins over each physics
    # step), as an integrating encoder would; the last sample has no interval after it and
    # keeps the angle itself.
    fins[:-1] = interval_means(fin_integral, t, None if s.sensors.steps else s.sensors.rate)
    if fin_log is not None:
        fine_truth[-1], fin_log[-1] = truth[-1], fin_integral[-1]
        fine_truth[:, IX["psi"]] = np.unwrap(fine_truth[:, IX["psi"]])
        fin_log[:-1] = np.diff(fin_log, axis=0) * s.sensors.fin_rate
        fin_log[-1] = fins[-1]
    specific_force = None
    if fine is None:
        measured, fins_measured = measure(truth, fins, s.sensors, rng, noise)
    else:
        measured, fins_measured, specific_force = fine.measure(
            s.sensors, s.named_sensors, s.columns, t, truth, fins, rng, streams, noise
        )
        pos += np.outer(t, s.trial.current)
    commands = {
        key: np.array([kw.get(key, np.nan) for kw in keywords], float)
        for key in sorted({key for kw in keywords for key in kw})
    }
    commands.update(zip(FIN_COMMANDS, fin_cmds.T))
    if not np.isnan(pitch).all():
        commands["pitch"] = pitch
    if fin_log is not None:  # the encoders' noise at every logged angle
        read = fin_log + rng.standard_normal(fin_log.shape) * s.sensors.fin_std
        fin_log = FinLog(np.arange(len(read)) / s.sensors.fin_rate, fine_truth, fin_log, read)
    return Flight(name, t, truth, measured, fins, fins_measured, pos, commands, specific_force, fin_log)


def fly_scenario(
    s: Scenario | str,
    seed: int = 0,
    mjcf=None,
    progress: Callable[[str, float], None] | None = None,
    truth: str = "plant",
) -> tuple[list[Flight], object]:
    """Fly every experiment of a scenario (or built-in name, or file); returns the flights and
    the analytic linear model. `truth`: what flies — "plant", the MuJoCo plant, or "linear",
    the analytic linear model of the run's model.toml (`LinearPlant`, its fins rate-limited as
    the servos), with the same autopilots, programs and sensor noise streams."""
    check_truth(truth)
    s = scenario(s)
    check_seed(seed)
    plant = Plant(mjcf)
    speed = s.speed if s.speed is not None else cruise_speed(plant.model)
    lin = analytic_model(plant.model, speed)
    check_fins(s, lin.fins.angle, mjcf)
    try:
        autopilot = Autopilot.designed(lin.A_full, lin.B_full, speed, 1.0 / s.control_rate, lin.fins.angle)
    except InputError as exc:  # name where the speed and the rate came from
        named = s.described(speed=f"{speed:g} m/s", control_rate=f"{s.control_rate:g} Hz")
        raise InputError(f"{named}: {exc}") from None
    s = replace(s, speed=speed)
    if truth == "linear":
        st, theta = structure(lin.vehicle), theta_vector(lin.coefficients)
        A, B, S = continuous(st, theta)
        W = None
        if s.trial.has_loads:  # a wrench at the CG forces the six dynamic rows: Mt⁻¹ (wrench, 0)
            W = np.linalg.solve(tilde(st, theta)[0], np.eye(NX)[:, :6])
        plant = LinearPlant(A, B, S, 1.0 / s.control_rate, lin.fins.rate, W)
    flights = []
    for k, e in enumerate(s.experiments):
        report = (lambda f, name=e.name: progress(name, f)) if progress else None
        flights.append(
            fly(
                plant,
                autopilot,
                e.name,
                program(s, e, seed, k),
                s,
                s.duration_of(e),
                rng_for(seed, k, 0),
                report,
                lambda stream, k=k: rng_for(seed, k, stream),
                lin.vehicle.weight,
            )
        )
    return flights, lin


def check_truth(truth) -> None:
    """InputError unless `truth` names what a scenario can fly on (`TRUTHS`)."""
    if truth not in TRUTHS:
        raise InputError(f"truth={truth!r}; expected one of {', '.join(TRUTHS)}")


def check_fins(s: Scenario, limit: float, mjcf=None) -> None:
    """InputError unless every fin signal of `s` stays within the vehicle's fin range ±`limit`
    rad (its MJCF's servo range, `vehicle.fin_limits`)."""
    for e in s.experiments:
        for channel, signal in e.fins.items():
            if signal.peak() > limit:
                raise InputError(
                    f"{s.source or s.name}: experiment {e.name!r}: {channel} reaches {signal.peak():g} rad; "
                    f"expected at most the fin range of {mjcf or 'the bundled torpedo'}, {limit:g} rad"
                )


def check_flyable(s: Scenario) -> None:
    """Refuse up front what the tool could not use: a record with too few samples to fit, or
    too many to hold (~1 kB each in flight)."""
    rate, (low, high) = s.sensors.rate, SAMPLES
    for e in s.experiments:
        duration = s.duration_of(e)
        if not low <= s.sample_count(duration) <= high:
            where = (
                f"{s.where}: experiment {e.name!r}: duration = {duration!r}"
                if e.duration is not None
                else f"{s.described(duration=repr(duration))} (experiment {e.name!r})"
            )
            if s.sensors.steps is None:
                expected = f"{(low - 1) / rate:g} to {(high - 1) / rate:g} s ({low} to {high} samples at {rate:g} Hz)"
            else:
                expected = f"{low} to {high} samples at steps {list(s.sensors.steps)} s"
            raise InputError(f"{where}; expected {expected}")
