"""The truth's sensors: named sensors of a scenario file, sampled from the flown trajectory.

A scenario file's `[sensors]` table may hold, besides `rate`, `fin_std`, `noise_std` and
`measured`, one sub-table per named sensor (`testbed.models.sensors.Sensor`):

```toml
[sensors.dvl]
outputs = ["u", "v", "w"]          # states, or ax ay az (specific force)
position = [0.3, 0.0, 0.1]         # m from the CG, body axes
misalignment = [0.0, 0.0, 0.0]     # rad, its axes' rotation from the body's (x, y, z)
frame = "body"                     # u v w in body axes, or "earth" (north-east-down)
bias = {u = 0.0}                   # per output, its unit
scale = {u = 0.0}                  # per output, scale-factor error (fraction)
delay = 0.0                        # s
rate = 5.0                         # Hz; divides the [sensors] rate (default: that rate)
noise_std = {u = 0.05}             # per output (default: the state's default noise)
resolution = {u = 0.001}           # per output, the logged value's quantisation step (default: none)
hold = false                       # true: its last sample logged again in the rows between its samples
```

A measured state that no named sensor outputs is read by the default sensor at the CG,
exactly, with the `[sensors] noise_std`. A sensor's sample k is taken at t_k = k / rate and
reads the truth at t_k − delay, linearly interpolated between the plant's steps (10 ms for the
bundled torpedo; before the start the vehicle was at its initial trim); the specific force's
state derivative is the central difference of the states over the plant's steps. Its noisy
output is rounded to the nearest multiple of its `resolution`. A sensor slower than the record
leaves its fields empty in the rows it has no sample for, or with `hold` repeats its last
sample there, bit for bit, as a logger that writes every channel's latest value at each row.
On a record logged at repeating `[sensors] steps`, a sensor's samples fall on the first row of
every m-th cycle of the steps (its rate 1 / (m · sum(steps))).
"""

from __future__ import annotations

import io
import math
from dataclasses import replace
from typing import Sequence

import numpy as np

from testbed.data import csv_text
from testbed.data import parse_sensor as data_parse_sensor
from testbed.errors import InputError
from testbed.models.linear import INPUTS
from testbed.models.sensors import ACCELERATIONS, OUTPUTS, Sensor, outputs
from testbed.simulation.measurements import NOISE_STD

__all__ = [
    "ACCELERATION_STD",
    "SENSOR_KEYS",
    "SENSOR_STREAM",
    "check_sensors",
    "columns",
    "gapped_csv_text",
    "scenario_sensor",
    "sample",
]

ACCELERATION_STD = 0.01  # m/s², a navigation-grade MEMS accelerometer's white noise at 50 Hz
SENSOR_STREAM = 16  # sensor i's noise: random stream SENSOR_STREAM + i of its experiment
SENSOR_KEYS = (
    "outputs",
    "position",
    "misalignment",
    "frame",
    "bias",
    "scale",
    "delay",
    "rate",
    "noise_std",
    "resolution",
    "hold",
)


def _default_std(output: str) -> float:
    return ACCELERATION_STD if output in ACCELERATIONS else NOISE_STD[output]


def scenario_sensor(name: str, doc, where: str) -> Sensor:
    """The `Sensor` of a scenario's `[sensors.NAME]` table (`where`: the file and table, for
    messages; `data.parse_sensor`), its outputs' noise defaulting to today's sensors'."""
    sensor = data_parse_sensor(name, doc, where, SENSOR_KEYS)
    noise = {**{o: _default_std(o) for o in sensor.outputs}, **sensor.noise_std}
    return replace(sensor, noise_std=noise)


def check_sensors(sensors: Sequence[Sensor], rate: float, where: str, what: str = "the sample rate") -> None:
    """InputError unless the named sensors' outputs are distinct and each rate divides `rate`
    (`what` names it: the record's sample rate, or the rate its repeating steps recur at)."""
    seen = {}
    for s in sensors:
        for o in s.outputs:
            if o in seen:
                raise InputError(
                    f"{where}: sensors.{s.name} outputs {o}, as sensors.{seen[o]} does; expected each output from one sensor"
                )
            seen[o] = s.name
        if s.rate is not None:
            ratio = rate / s.rate
            if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
                raise InputError(
                    f"{where}: sensors.{s.name}.rate = {s.rate!r}; expected {what} {rate:g} Hz "
                    "divided by a whole number"
                )


def columns(measured: Sequence[str], sensors: Sequence[Sensor]) -> tuple[str, ...]:
    """The measurement CSV's output columns: the measured states and every named sensor's outputs."""
    named = {o for s in sensors for o in s.outputs}
    return tuple(o for o in OUTPUTS if o in measured or o in named)


def _at(times: np.ndarray, fine_t: np.ndarray, fine: np.ndarray) -> np.ndarray:
    """Each column of `fine` (at `fine_t`) linearly interpolated at `times`; before the start, the first row."""
    return np.column_stack([np.interp(times, fine_t, fine[:, j]) for j in range(fine.shape[1])])


def sample(
    sensor: Sensor, t: np.ndarray, fine_t: np.ndarray, fine_x: np.ndarray, current, rng: np.random.Generator
) -> np.ndarray:
    """The sensor's noisy outputs (len(t), len(outputs)) on the record's clock t: at the rows
    whose stamp is a multiple of its period 1 / rate (every row without a rate), each reading the
    truth `delay` s earlier, interpolated in the physics-rate trajectory (fine_t, fine_x:
    absolute u, ψ unwrapped), with its noise, rounded to its `resolution`; in the other rows NaN,
    or with `hold` its last sample."""
    rows = np.arange(len(t))
    if sensor.rate is not None:
        cycles = t * sensor.rate
        rows = np.flatnonzero(np.abs(cycles - np.round(cycles)) < 1e-6)
    times = t[rows] - sensor.delay
    x = _at(times, fine_t, fine_x)
    xdot = None
    if any(o in ACCELERATIONS for o in sensor.outputs):
        xdot = _at(times, fine_t, np.gradient(fine_x, fine_t, axis=0))
    y = outputs(sensor, x, xdot, current)
    std = np.array([sensor.noise_std.get(o, 0.0) for o in sensor.outputs])
    y = y + rng.standard_normal(y.shape) * std
    for j, o in enumerate(sensor.outputs):
        if o in sensor.resolution:  # the nearest step the sensor reports
            y[:, j] = np.round(y[:, j] / sensor.resolution[o]) * sensor.resolution[o]
    if sensor.hold:  # each row the latest sample at or before it (the first row is a sample: t = 0)
        return y[np.searchsorted(rows, np.arange(len(t)), side="right") - 1]
    out = np.full((len(t), len(sensor.outputs)), np.nan)
    out[rows] = y
    return out


def gapped_csv_text(t: np.ndarray, values: np.ndarray, fins: np.ndarray, names: Sequence[str]) -> str:
    """Measurement-CSV text whose empty fields are the samples a sensor did not take (NaN in
    `values`); with none missing, `data.csv_text`'s."""
    if not np.isnan(values).any():
        return csv_text(t, values, fins, names)
    out = io.StringIO()
    out.write(",".join(("t", *names, *INPUTS)) + "\n")
    for row in np.column_stack([t, values, fins]):
        out.write(",".join("" if math.isnan(v) else "%.10g" % v for v in row) + "\n")
    return out.getvalue()
