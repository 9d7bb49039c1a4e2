"""Scenario II generation speed: simulated seconds per wall second (goal >= 50x real time).

    python benchmarks/bench_scenario.py [--repeat N]

Flies both modes at the default durations (2 x 60 s) through the completed plant and the
autopilots, with sensor noise, as `testbed simulate --scenario II` does; then writes the whole
run directory (CSVs, model.toml, manifest, recording.rrd) and times that too. The reference
measured in the same process is the bare plant stepped at the control rate with constant fins
(no autopilot, no sampling, no files) over the same simulated time.

Once per process, before any of that, come the imports and the plant's compiled-code load
(numba cache): timed and printed on their own, since a fresh `testbed simulate` pays them once
and the simulated-time ratio would otherwise depend on how long the run is. The best of
`--repeat` runs is reported (the machine's other load only ever slows a run down).
"""

import argparse
import tempfile
import time
from pathlib import Path

from testbed.threads import one_blas_thread

one_blas_thread()  # as the command line does, before numpy loads

GOAL = 50.0  # x real time, the whole run directory


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=3, help="runs of each measurement (best kept)")
    args = ap.parse_args(argv)

    t0 = time.perf_counter()
    import testbed.presentation.report  # noqa: F401  (the recording's imports, as simulate pays them)
    from testbed.simulation.plant import Plant
    from testbed.simulation.runs import simulate
    from testbed.simulation.flight import fly_scenario
    from testbed.simulation.scenario import scenario

    Plant().step((0.0, 0.0, 0.0))  # loads the compiled completion
    startup = time.perf_counter() - t0

    s = scenario("II")
    simulated = sum(s.duration_of(e) for e in s.experiments)
    plant = Plant()
    steps = round(1.0 / (s.control_rate * plant.timestep))

    def bare():
        plant.reset()
        for _ in range(round(simulated * s.control_rate)):
            plant.step((0.02, 0.0, 0.0), n=steps)

    def flying():
        fly_scenario(s, seed=0)

    def whole():
        with tempfile.TemporaryDirectory() as tmp:
            simulate("II", seed=0, out=Path(tmp) / "run")

    def best(job):
        times = []
        for _ in range(args.repeat):
            t = time.perf_counter()
            job()
            times.append(time.perf_counter() - t)
        return min(times)

    t_bare, t_fly, t_whole = best(bare), best(flying), best(whole)
    print(f"simulated time        : {simulated:.0f} s (Scenario II, every experiment, best of {args.repeat})")
    print(f"start-up (once)       : {startup:6.2f} s  imports and compiled-code load")
    print(f"bare plant            : {simulated / t_bare:6.0f}x real time  ({t_bare:.2f} s)")
    print(
        f"flying, autopilots    : {simulated / t_fly:6.0f}x real time  ({t_fly:.2f} s, "
        f"{t_fly / t_bare:.2f}x the bare plant's time)"
    )
    print(f"files (CSV, TOML, rrd): {t_whole - t_fly:6.2f} s")
    ratio = simulated / t_whole
    verdict = "meets" if ratio >= GOAL else "MISSES"
    print(
        f"whole run directory   : {ratio:6.0f}x real time  ({t_whole:.2f} s)  {verdict} the goal >= {GOAL:.0f}x"
    )
    fresh = simulated / (t_whole + startup)
    print(f"  with the start-up   : {fresh:6.0f}x real time  (a fresh `testbed simulate --scenario II`)")


if __name__ == "__main__":
    main()
