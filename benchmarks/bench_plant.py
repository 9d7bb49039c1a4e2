"""Step rate of the completed plant over raw `mj_step` of the same MJCF, measured in one run.

    python benchmarks/bench_plant.py [--seconds 4] [--rounds 15]

Both fly the bundled torpedo at cruise speed with the fins deflected (so the servos and the
fluid forces work); the reference is a bare `mujoco.mj_step` loop called from Python, as a user
of plain MuJoCo would, and the plant is `Plant.step` (its n-step loop compiled) with the
added-mass inertia and buoyancy completed every step. The two are measured alternately in short
rounds, and each side's best round counts: on a shared machine other work only ever slows a
round down, so the best is the least disturbed. Goal: ratio >= 0.5.
"""

import argparse
import time

import mujoco
import numpy as np

from testbed.simulation.plant import Plant


def rate(run, steps):
    t = time.perf_counter()
    run(steps)
    return steps / (time.perf_counter() - t)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=4.0, help="simulated seconds per round")
    ap.add_argument("--rounds", type=int, default=15, help="rounds per side")
    args = ap.parse_args()
    plant = Plant()
    plant.reset()
    steps = round(args.seconds / plant.timestep / 10) * 10
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

    run_raw(steps // 10)  # warm up (and compile, if the cache is cold)
    run_plant(steps // 10)
    rows = np.array([(rate(run_raw, steps), rate(run_plant, steps)) for _ in range(args.rounds)])
    raw_rate, plant_rate = rows.max(axis=0)
    ratios = rows[:, 1] / rows[:, 0]
    print(f"raw mj_step        : {raw_rate:10.0f} steps/s  (best of {args.rounds} rounds)")
    print(
        f"completed plant    : {plant_rate:10.0f} steps/s  "
        f"({plant_rate * plant.timestep:.0f}x real time at dt={plant.timestep} s)"
    )
    print(
        f"ratio plant / raw  : {plant_rate / raw_rate:10.2f}   (goal >= 0.5; round by round "
        f"{np.percentile(ratios, 25):.2f}-{np.percentile(ratios, 75):.2f}, middle half)"
    )


if __name__ == "__main__":
    main()
