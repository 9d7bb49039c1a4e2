"""The nonlinear model's compiled flight (`models.nonlinear_flight`)."""

from __future__ import annotations

import numpy as np

from testbed.captive.reference import captive_reference
from testbed.models import linear, nonlinear_kernels
from testbed.models.nonlinear import nonlinear_model, nonlinear_theta
from testbed.models.nonlinear_flight import STRETCH, flown_rows, fly_nonlinear
from testbed.simulation.vehicle import constants, load_model

VEHICLE = linear.Vehicle(
    mass=170.0, Ix=2.2, Iy=67.0, Iz=67.5, weight=1700.0, buoyancy=1675.0, xB=0.0, yB=0.0, zB=-0.02, speed=20.0
)


def test_times_a_column_or_a_strided_slice_fly_through_the_one_compiled_flight():
    """Times read as a table's column are strided; the flight takes them as contiguous, so the
    kernel compiled for them is the one for every flight, and the states are the same."""
    model = nonlinear_model(VEHICLE)
    theta = nonlinear_theta(model, {"X_udot": -8.0, "Y_vdot": -158.0, "Z_wdot": -159.0, "M_qdot": -55.0})
    table = np.column_stack([np.arange(11) * 0.02, np.ones(11)])
    fins = np.zeros((11, 3))
    fins[3:, 1] = 0.05
    x0 = np.r_[20.0, np.zeros(9)]
    strided = fly_nonlinear(model, theta, table[:, 0], x0, fins)
    assert np.array_equal(strided, fly_nonlinear(model, theta, table[:, 0].copy(), x0, fins))
    layouts = {
        sig[1].layout for sig in nonlinear_kernels.rk4_flight.signatures if str(sig[2].dtype) == "float64"
    }
    assert layouts == {"C"}


def doublet(t, start, half, amplitude):
    return amplitude * (
        ((t >= start) & (t < start + half)) * 1.0 - ((t >= start + half) & (t < start + 2 * half))
    )


def test_a_flight_stops_at_the_rows_with_a_sample_or_a_fin_change():
    """A 50 Hz log read on its logger's 1 ms clock (19 ticks in 20 without a sample), with a fin
    change at a tick without states and a 0.2 s dropout: the flight keeps the first and the last
    tick, every tick with a sample or a fin change and, in the dropout, ticks no further apart
    than `STRETCH` times the median interval (20 ms), as few as that takes. Flown from kept tick
    to kept tick in 20 RK4 steps an interval, the first second's states are those of the flight
    through every tick in one step a tick. A record on its own step keeps every row, its
    dropout's too."""
    mjcf = load_model()
    model = nonlinear_model(constants(mjcf, 20.0))
    theta = nonlinear_theta(model, captive_reference(mjcf, 20.0).coefficients)
    t50 = np.arange(101) * 0.02
    a = np.radians(3.0)
    fins50 = np.column_stack(
        [doublet(t50, 0.5, 1.0, a), doublet(t50, 0.3, 0.6, a), doublet(t50, 1.2, 0.2, a / 10)]
    )
    x0 = np.r_[20.0, np.zeros(9)]
    t = np.arange(2001) * 0.001
    fins = fins50[np.arange(2001) // 20]  # each row's fins held over its 20 ticks
    fins[1010:1020] += 0.01  # logged at a tick without states
    states = fly_nonlinear(model, theta, t, x0, fins, substeps=1)
    y = np.full_like(states, np.nan)
    sampled = np.setdiff1d(np.arange(0, 2001, 20), np.arange(1420, 1600, 20))
    y[sampled] = states[sampled]
    rows = flown_rows(t, y, fins)
    assert set(sampled) | {1010} <= set(rows)
    # in the dropout: the rudder's and elevator's change at 1.5 s, and from 1.4 s and from it every 30 ms
    assert set(rows) - set(sampled) - {1010} == {1430, 1460, 1490, 1500, 1530, 1560, 1590}
    assert np.max(np.diff(t[rows])) <= STRETCH * 0.020 + 1e-12
    first = rows[rows <= 1000]
    np.testing.assert_allclose(
        fly_nonlinear(model, theta, t[first], x0, fins[first], substeps=20),
        states[rows[rows <= 1000]],
        rtol=0,
        atol=1e-12 * np.abs(states).max(),
    )
    dropout = np.where(np.isin(np.arange(101), [40, 41, 42])[:, None], np.nan, 0.0)
    assert np.array_equal(flown_rows(t50, dropout, fins50), np.arange(101))
