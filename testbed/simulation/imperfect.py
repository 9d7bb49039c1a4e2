"""An imperfect trial's flight: the plant stepped one step at a time, its trajectory kept.

A scenario with named sensors or a trial's imperfections (`testbed.simulation.sensing`,
`testbed.simulation.trial`) is flown one plant step at a time: each fin's command reaches its
servo `actuator_delay` late (whole plant steps), less its encoder's zero error, through the
servo's dead band; the trial's loads are the plant's wrench, held over the step; the state and
the fins' integral are kept at every step, for the sensors to sample (their delays and rates)
and the fin record to lag. With none of that, the same plant steps fly the same trajectory as
whole control periods do.
"""

from __future__ import annotations

import collections
import math
from typing import Sequence

import numpy as np

from testbed.models.linear import IX, NX, STATES
from testbed.models.sensors import Sensor, outputs
from testbed.simulation.measurements import Sensors, interval_means, measure
from testbed.simulation.sensing import SENSOR_STREAM, sample
from testbed.simulation.trial import TURBULENCE_STREAM, Backlash, Trial, gauss_markov

__all__ = ["TrialFlight"]


class TrialFlight:
    """An imperfect flight's plant steps: the fins' command late, through the servo's dead band
    and the encoder's zero error, the trial's loads as the plant's wrench; the trajectory and the
    fins' integral kept at every step."""

    def __init__(self, plant, trial: Trial, n: int, streams, weight: float):
        self.plant, self.trial, self.weight, self.h = plant, trial, weight, plant.timestep
        self.x, self.integral = np.empty((n, NX)), np.empty((n, 3))
        self.j = 0
        lag = round(trial.actuator_delay / self.h)
        held = -trial.offsets  # before the start the fins were commanded to 0: their true angles
        self.queue = collections.deque([held] * lag)  # the commands on their way, one per step
        self.backlash = Backlash(trial.backlash, held)
        std = trial.turbulence.std
        self.gusts = None
        if std.any():
            self.gusts = gauss_markov(std, trial.turbulence.time, self.h, n, streams(TURBULENCE_STREAM))

    def record(self, x: np.ndarray) -> None:
        self.x[self.j], self.integral[self.j] = x, self.plant.fin_integral()

    def advance(self, x: np.ndarray, command: np.ndarray, steps: int) -> None:
        plant, trial = self.plant, self.trial
        for n in range(steps):
            if n:
                x = plant.state()
            self.record(x)
            self.queue.append(np.asarray(command, float) - trial.offsets)
            fin = self.backlash(self.queue.popleft())
            if trial.has_loads:
                wrench = trial.loads(x, self.weight)
                plant.wrench = wrench if self.gusts is None else wrench + self.gusts[self.j]
            plant.step(fin, n=1)
            self.j += 1
        if trial.has_loads and self.j == len(self.x) - 1:
            plant.wrench = np.zeros(6)  # the plant is reused: no load carries into the next flight

    def fin_means(self, t: np.ndarray, rate: float | None, fins: np.ndarray) -> np.ndarray:
        """The recorded fins: each sample interval's mean angle `fin_log_delay` s earlier (the
        integral is piecewise linear: interpolation is exact; before the start the fins were at 0);
        `rate`: the record's uniform sample rate, None for stamps at unequal steps."""
        d = self.trial.fin_log_delay
        if not d:
            return fins
        fine_t = np.arange(len(self.x)) * self.h
        integral = np.column_stack(
            [np.interp(t - d, fine_t, self.integral[:, j], left=0.0) for j in range(3)]
        )
        out = fins.copy()
        out[:-1] = interval_means(integral, t, rate)
        step = min(int(math.floor((t[-1] - d) / self.h + 1e-9)), len(self.x) - 2)  # the last: the angle then
        out[-1] = (self.integral[step + 1] - self.integral[step]) / self.h if step >= 0 else 0.0
        return out

    def measure(
        self, sensors: Sensors, named: Sequence[Sensor], columns, t, truth, fins, rng, streams, noise=None
    ):
        """The measured states (N, 10; NaN where no sensor samples), recorded fins (N, 3) and
        specific force (N, 3, or None): the default sensor's noise (`noise`, where the flight drew
        it already) and the encoders' from `rng` (as a perfect flight's), named sensor k's from
        random stream SENSOR_STREAM + k; `columns`: the record's outputs."""
        current = self.trial.current
        fine_t = np.arange(len(self.x)) * self.h
        fine_x = self.x.copy()
        fine_x[:, IX["psi"]] = np.unwrap(fine_x[:, IX["psi"]])
        at_cg = outputs(Sensor(), truth, current=current) if any(current) else truth
        rate = None if sensors.steps else sensors.rate
        measured, fins_measured = measure(at_cg, self.fin_means(t, rate, fins), sensors, rng, noise)
        fins_measured = fins_measured + self.trial.offsets
        measured[:, [IX[n] for n in STATES if n not in columns]] = np.nan
        specific_force = None
        for k, sensor in enumerate(named):
            y = sample(sensor, t, fine_t, fine_x, current, streams(SENSOR_STREAM + k))
            for j, o in enumerate(sensor.outputs):
                if o in IX:
                    measured[:, IX[o]] = y[:, j]
                else:
                    if specific_force is None:
                        specific_force = np.full((len(t), 3), np.nan)
                    specific_force[:, "xyz".index(o[1])] = y[:, j]
        return measured, fins_measured, specific_force
