"""Benchmark: one nonlinear output-error fit of Scenario I (goal ≤ 30 s on one core).

    python benchmarks/bench_nonlinear_fit.py [--seed 1] [--rounds 3] [--fin-rate 100]

The data: `testbed simulate --scenario I --seed 1` (the plant's noisy record: 60 s at 50 Hz, 3001
samples, every state measured) in a temporary folder; `--fin-rate 100`: the same flight with its
fins logged every 10 ms (`[sensors] fin_rate`: 6001 rows, the states at 3001 of them), flown
with 2 RK4 steps a row (the same 5 ms steps). The fit: the nonlinear model over the
captive reference's terms (`testbed captive`'s at 20 m/s), its 19 terms with a slope at trim and
`N_r|r|` free (20 coefficients), started from the captive values, every record's initial state
free (`estimators.nonlinear_fit.fit_output_error`: `ml-gn`'s trust-region optimiser, RK4 steps of 5 ms).
The component model (`testbed captive`'s default: the hull's and fin blades' forces at their own
flow) is fitted the same way, 14 of its terms free (the stricter list of docs/studies.md, whose
relative Cramér-Rao bounds stay below 15 %: the four blades' lift and blunt drag, the hull's
blunt, slender and angular drag, three blades' Munk terms), from the captive values each moved by exp(±0.2) (alternating), with
`fit_output_error`'s default tolerance. The reference measured in the same run is `ml-gn`
fitting the linear model to the same record from the analytic model (the run's model.toml, its
default free set). Each is timed as the best
of `--rounds` calls, alternating, with single-threaded BLAS and numba, in wall and CPU time (the
machine may be shared). The model's compiled code is loaded from numba's cache before the clock
starts; the first call's time in this process (the cache read) and a compilation from an empty
cache (in a fresh process) are printed apart.

The commands beside the two nonlinear cells, each the same fit as a user types it: the captive
configs written by `testbed captive --model polynomial --speed 20 --out polynomial.toml` and
`testbed captive --speed 20 --out components.toml` (the component model, the default) in the
temporary folder (untimed), each config's `[identify]` candidate list replaced by the cell's
explicit free list (`screen` off; the component config's 14 values moved as the cell's start,
`read_config` then `write_config`), then `testbed identify run --config polynomial.toml --out
est.json` and `testbed identify run --config components.toml --out est.json` on the run above
with default options, as processes from their start to their exit (the console script beside
this interpreter; one untimed run of the first, so Python's byte code is cached as for any user;
then best of `--rounds`, the two alternating): start-up, reading, the screen (only reported for
an explicit list, but run: the Fisher information from the flight's sensitivities at the start
and at the estimate, and its `ml-gn` fit, which is the fit itself where the screen's first stage
fixes nothing, else a second fit of the list as written follows), the fit from the default
`auto` starts (the config's values and the equation-error regression, the better-flying first,
the other stopping where it joins the first's basin; converged at steps below `ml-gn`'s `tol`,
0.001 σ, as the cells), its Cramér-Rao and coloured-residual bounds, validation
(the fitted model flown open loop) and writing. Printed: each command's time, the ratio command
/ cell, the fit its estimates JSON reports (`wall_time_s`, `iterations`, `start`), and where the
two differ by more than 3× a line saying why, measured stage by stage in one more run of the
command (`workload.why`); all also in units of a fixed numpy workload timed in the same run
(`workload.machine`), against the goal in those units (30 s at the workload's reference time).
"""

from __future__ import annotations

import argparse
import inspect
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

from testbed.threads import one_blas_thread

one_blas_thread()  # as the command line does, before numpy loads
os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from testbed.data import load_data, read_config, write_config  # noqa: E402
from testbed.estimators import identify, lookup  # noqa: E402
from testbed.estimators import nonlinear_fit  # noqa: E402
from testbed.estimators.nonlinear_fit import fit_output_error  # noqa: E402
from testbed.identification.nonlinear_output_error import FlightRecord  # noqa: E402
from testbed.identification.nonlinear_sensitivities import flight  # noqa: E402
from testbed.models.linear import STATES  # noqa: E402
from testbed.models.nonlinear import nonlinear_model, nonlinear_theta  # noqa: E402
from testbed.models.nonlinear_flight import fly_nonlinear  # noqa: E402
from testbed.captive.reference import captive_reference, component_reference, slope_terms  # noqa: E402
from testbed.simulation.runs import simulate  # noqa: E402
from testbed.simulation.scenario import scenario  # noqa: E402
from testbed.simulation.vehicle import constants, load_model  # noqa: E402
from workload import REFERENCE_S, command, console, fit_summary, machine, why  # noqa: E402

GOAL = 30.0  # s, one fit on one core
SPEED = 20.0
EXTRA = ("N_r|r|",)  # freed beside the slope terms: 20 coefficients
# 14 of the component model's terms, each determined on Scenario I within 15 % (docs/studies.md)
COMPONENT_FREE = tuple(
    f"{kind}@{part}"
    for kind, parts in (
        ("lift", ("rudder_upper", "rudder_lower", "elevator_right", "elevator_left")),
        ("blunt", ("rudder_upper", "rudder_lower", "elevator_right", "elevator_left", "hull")),
        ("slender", ("hull",)),
        ("angular", ("hull",)),
        ("munk", ("elevator_right", "elevator_left", "rudder_upper")),
    )
    for part in parts
)
# a fresh process compiling the model's flight and its sensitivities from an empty cache
COLD = """
import time, numpy as np
t0 = time.perf_counter()
from testbed.models.nonlinear import TERMS, nonlinear_model
from testbed.models.nonlinear_flight import fly_nonlinear
from testbed.identification.nonlinear_sensitivities import flight
from testbed.simulation.vehicle import constants, load_model
model = nonlinear_model(constants(load_model(), 20.0), TERMS)
theta = np.zeros(len(model.names))
x0 = np.zeros(10); x0[0] = 20.0
t0 = time.perf_counter()
flight(model, theta, np.array([0.0, 0.02]), x0, np.zeros((2, 3)), [20])
print(time.perf_counter() - t0)
"""


def _best(runs, rounds):
    """Per run: the shortest wall time and the shortest CPU time of `rounds` calls, and the last
    call's result; the runs alternate, so a slow spell of a shared machine hits both alike."""
    wall, cpu, out = [[] for _ in runs], [[] for _ in runs], [None] * len(runs)
    for _ in range(rounds):
        for i, run in enumerate(runs):
            t0, c0 = time.perf_counter(), time.process_time()
            out[i] = run()
            wall[i].append(time.perf_counter() - t0)
            cpu[i].append(time.process_time() - c0)
    return [(min(w), min(c), o) for w, c, o in zip(wall, cpu, out)]


def _explicit(path: Path, free, values) -> None:
    """`testbed captive`'s config at `path` with `free` its explicit free list (no screen) and
    `values` (name → value) set, as a user edits it for the fit."""
    config = read_config(path).with_coefficients(values)
    write_config(path, replace(config, free=tuple(free), screen=False), force=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seed", type=int, default=1, help="the run's noise seed")
    ap.add_argument("--rounds", type=int, default=3, help="timed calls of each fit and command (best taken)")
    ap.add_argument("--fin-rate", type=float, default=None, help="Hz: Scenario I's fins logged this often")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:  # the run and the commands' inputs, to the end
        return _bench(args, Path(tmp))


def _bench(args, tmp: Path) -> int:
    s = scenario("I")
    s = replace(s, sensors=replace(s.sensors, fin_rate=args.fin_rate))
    run = tmp / "run"
    simulate(s, seed=args.seed, out=run)
    experiments, analytic = load_data([run])
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp / "cache"))
    cold = float(
        subprocess.run(
            [sys.executable, "-c", COLD], env=env, check=True, capture_output=True, text=True
        ).stdout
    )
    mjcf = load_model()
    reference = captive_reference(mjcf, SPEED)
    model = nonlinear_model(constants(mjcf, SPEED), reference.terms)
    theta = nonlinear_theta(model, reference.coefficients)
    free = slope_terms(reference.terms) + EXTRA
    channels = tuple(s for s in experiments[0].measured if s in STATES)
    records = [
        FlightRecord(t=e.t, fins=e.inputs, y=e.y[:, [e.measured.index(c) for c in channels]])
        for e in experiments
    ]
    r = records[0]
    x0 = np.zeros(10)
    x0[0] = SPEED
    x0[[STATES.index(c) for c in channels]] = r.y[0]
    idx = [model.names.index(n) for n in free]

    t0 = time.perf_counter()
    flight(model, theta, r.t[:2], x0, r.fins[:2], idx)  # the compiled code, read from numba's cache
    first = time.perf_counter() - t0
    (t_fly, _, _), (t_flight, _, _) = _best(
        [
            lambda: fly_nonlinear(model, theta, r.t, x0, r.fins),
            lambda: flight(model, theta, r.t, x0, r.fins, idx),
        ],
        args.rounds,
    )
    components = component_reference(mjcf, SPEED)
    cmodel = nonlinear_model(constants(mjcf, SPEED), components.terms, components.components)
    ctheta = nonlinear_theta(cmodel, components.coefficients)
    cstart = ctheta.copy()
    for k, n in enumerate(COMPONENT_FREE):
        cstart[cmodel.names.index(n)] *= np.exp(0.2 if k % 2 == 0 else -0.2)
    fit_output_error(
        cmodel, cstart, [FlightRecord(t=r.t[:3], fins=r.fins[:3], y=r.y[:3])], channels, COMPONENT_FREE[:1]
    )
    (t_nl, c_nl, fit), (t_cm, c_cm, cfit), (t_lin, c_lin, lin) = _best(
        [
            lambda: fit_output_error(model, theta, records, channels, free),
            lambda: fit_output_error(cmodel, cstart, records, channels, COMPONENT_FREE),
            lambda: identify(experiments, analytic, method="ml-gn", start="config"),
        ],
        args.rounds,
    )
    samples = int(sum(np.sum(~np.isnan(x.y).all(axis=1)) for x in records))
    rows = sum(len(x.t) for x in records)
    z = [(fit.estimates[n] - reference.coefficients[n]) / fit.std[n] for n in free]
    print(
        f"BLAS threads: {os.environ['OPENBLAS_NUM_THREADS']}, numba threads: {os.environ['NUMBA_NUM_THREADS']}; "
        f"data: Scenario I seed {args.seed}, {len(records)} record, {samples} samples in {rows} rows, channels {' '.join(channels)}; "
        f"{len(free)} coefficients free from the captive values, best of {args.rounds}"
    )
    print(
        f"compiled code: first call in this process {first:.2f} s (read from numba's cache; compiled if stale), "
        f"compiling from an empty cache {cold:.1f} s (a fresh process)"
    )
    print(
        f"one flight (RK4, 5 ms steps): {1e3 * t_fly:.1f} ms; flight and sensitivities: {1e3 * t_flight:.1f} ms"
    )
    print(
        f"nonlinear ml-gn: {t_nl:7.2f} s ({c_nl:.2f} s CPU), {fit.status.message}, {fit.iterations} iterations"
    )
    print(
        f"linear ml-gn   : {t_lin:7.2f} s ({c_lin:.2f} s CPU), {lin.status.name}, {lin.iterations} iterations (analytic start, {len(analytic.free)} free)"
    )
    print(
        f"nonlinear / goal ({GOAL:g} s): {t_nl / GOAL:.3f}; nonlinear / linear: {t_nl / t_lin:.1f}x; "
        f"estimates from the captive values: max {np.max(np.abs(z)):.1f} σ ({free[int(np.argmax(np.abs(z)))]})"
    )
    zc = [(cfit.estimates[n] - components.coefficients[n]) / cfit.std[n] for n in COMPONENT_FREE]
    print(
        f"component ml-gn: {t_cm:7.2f} s ({c_cm:.2f} s CPU), {cfit.status.message}, {cfit.iterations} iterations, "
        f"{len(COMPONENT_FREE)} free from the captive values × exp(±0.2)"
    )
    print(
        f"component / goal ({GOAL:g} s): {t_cm / GOAL:.3f}; component / linear: {t_cm / t_lin:.1f}x; "
        f"estimates from the captive values: max {np.max(np.abs(zc)):.1f} σ "
        f"({COMPONENT_FREE[int(np.argmax(np.abs(zc)))]})"
    )
    testbed = console()
    command([testbed, "captive", "--model", "polynomial", "--speed", SPEED, "--out", "polynomial.toml"], tmp)
    command([testbed, "captive", "--speed", SPEED, "--out", "components.toml"], tmp)
    _explicit(tmp / "polynomial.toml", free, {})
    _explicit(
        tmp / "components.toml", COMPONENT_FREE, {n: cstart[cmodel.names.index(n)] for n in COMPONENT_FREE}
    )

    def user(config, out):  # the command as a user types it, default options
        return [testbed, "identify", run.name, "--config", config, "--out", out]

    commands = {
        "polynomial": (t_nl, fit, free, "the captive values"),
        "components": (t_cm, cfit, COMPONENT_FREE, "the captive values × exp(±0.2)"),
    }
    command(user("polynomial.toml", "est0.json"), tmp)  # byte code cached, as for any user
    times = {name: [] for name in commands}
    for k in range(1, args.rounds + 1):
        for name in commands:
            times[name].append(command(user(f"{name}.toml", f"{name}{k}.json"), tmp))
    work, goal = machine(), GOAL / REFERENCE_S
    # the step tolerances in Cramér-Rao σ: the cell's (`nonlinear_fit.fit`'s default), the command's (ml-gn's)
    tolerance = inspect.signature(nonlinear_fit.fit).parameters["tolerance"].default
    tol = lookup("ml-gn").options.build("ml-gn", {}).tol
    for name, (t_cell, cell, names, start) in commands.items():
        t_cmd = min(times[name])
        what = (
            f"fit_output_error from {start}, {cell.iterations} iterations, {len(names)} free, "
            f"converged at steps below {tolerance:g} σ (the command's ml-gn: {tol:g} σ)"
        )
        reason = why(user(f"{name}.toml", f"{name}-why.json"), tmp, t_cell, t_cmd, what)
        print(
            f"command `testbed identify run --config {name}.toml --out est.json`: {t_cmd:.2f} s "
            f"(best of {args.rounds}); its fit (estimates JSON): {fit_summary(tmp / f'{name}1.json')}"
        )
        print(f"{name} cell {t_cell:.2f} s, command {t_cmd:.2f} s: command / cell {t_cmd / t_cell:.1f}x")
        if reason:
            print(reason)
        print(
            f"workload {work:.3f} s (reference {REFERENCE_S:.3f} s): {name} cell {t_cell / work:.1f}, "
            f"command {t_cmd / work:.1f} workloads; goal {goal:.1f} ({GOAL:g} s at the reference): "
            f"cell {t_cell / work / goal:.2f}, command {t_cmd / work / goal:.2f} of the goal"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
