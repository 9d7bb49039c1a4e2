"""Step rate of the completed plant over raw `mj_step` of the same MJCF, measured in one run.

    python benchmarks/bench_plant.py [--seconds 20]

Both fly the bundled torpedo straight at cruise speed with the fins swept (so the servos and the
fluid forces work); the reference is a bare `mujoco.mj_step` loop, the plant is `Plant.step`
with the added-mass inertia and buoyancy completed every step. Goal: ratio >= 0.5.
"""

import argparse
import time

import mujoco
import numpy as np

from testbed.plant import Plant


def rate(run, steps):
    run(steps // 10)  # warm up
    t = time.perf_counter()
    run(steps)
    return steps / (time.perf_counter() - t)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="simulated seconds per measurement")
    args = ap.parse_args()
    plant = Plant()
    plant.reset()
    steps = int(args.seconds / plant.timestep)
    cmd = np.array([0.1, -0.05, -0.05])

    raw = Plant(complete=False)
    raw.reset()
    m, d = raw.model, raw.data
    d.ctrl[:3] = cmd

    def run_raw(n):
        for _ in range(n):
            mujoco.mj_step(m, d)

    def run_plant(n):
        for k in range(0, n, 10):  # a controller at 25 Hz commands the fins every 10 steps
            plant.step(cmd if (k // 500) % 2 else -cmd, n=10)

    rows = []
    for _ in range(3):  # interleave to share the machine's noise
        rows.append((rate(run_raw, steps), rate(run_plant, steps)))
    raw_rate, plant_rate = np.median(np.array(rows), axis=0)
    print(f"raw mj_step        : {raw_rate:10.0f} steps/s")
    print(f"completed plant    : {plant_rate:10.0f} steps/s  "
          f"({plant_rate * plant.timestep:.0f}x real time at dt={plant.timestep} s)")
    print(f"ratio plant / raw  : {plant_rate / raw_rate:10.2f}   (goal >= 0.5)")


if __name__ == "__main__":
    main()
