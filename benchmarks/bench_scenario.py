"""Scenario II generation speed: simulated seconds per wall second (goal >= 50x real time).

    python benchmarks/bench_scenario.py

Flies both modes at the default durations (2 x 60 s) through the completed plant and the
autopilots, with sensor noise, as `testbed simulate --scenario II` does; then writes the whole
run directory (CSVs, model.toml, recording.rrd) and times that too. The reference measured in
the same run is the bare plant (no autopilot, no recording) over the same simulated time.
"""

import tempfile
import time
from pathlib import Path

from testbed.plant import Plant
from testbed.scenario import EXPERIMENTS, Settings, fly_scenario, simulate


def main():
    s = Settings()
    simulated = s.duration * len(EXPERIMENTS["II"])
    plant = Plant()
    plant.reset()
    t = time.perf_counter()
    plant.step((0.02, 0.0, 0.0), n=round(simulated / plant.timestep))
    bare = time.perf_counter() - t
    t = time.perf_counter()
    fly_scenario("II", seed=0, settings=s)
    flying = time.perf_counter() - t
    with tempfile.TemporaryDirectory() as tmp:
        t = time.perf_counter()
        simulate("II", seed=0, out=Path(tmp) / "run", progress=False)
        whole = time.perf_counter() - t
    print(f"simulated time           : {simulated:.0f} s (Scenario II, both modes)")
    print(f"bare plant (reference)   : {simulated / bare:6.0f}x real time")
    print(f"flying with autopilots   : {simulated / flying:6.0f}x real time ({flying / bare:.2f}x the bare plant's time)")
    print(f"whole run directory      : {simulated / whole:6.0f}x real time   (goal >= 50x)")


if __name__ == "__main__":
    main()
