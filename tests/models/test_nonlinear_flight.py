"""The nonlinear model's compiled flight (`models.nonlinear_flight`)."""

from __future__ import annotations

import numpy as np

from testbed.models import linear, nonlinear_kernels
from testbed.models.nonlinear import nonlinear_model, nonlinear_theta
from testbed.models.nonlinear_flight import fly_nonlinear

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
