"""The nonlinear model's output-error likelihood against independent references: the trajectory's
sensitivities against complex steps of an RK4 flight written here. Its fits are
`tests/estimators/test_nonlinear_fit.py`'s."""

from __future__ import annotations

import numpy as np
import pytest

from testbed.identification.nonlinear_output_error import FlightRecord
from testbed.identification.nonlinear_sensitivities import flight
from testbed.models.linear import STATES
from testbed.models.nonlinear import INERTIA, nonlinear_model, nonlinear_theta
from testbed.models.nonlinear_flight import fly_nonlinear
from testbed.captive.reference import captive_reference
from testbed.simulation.measurements import NOISE_STD
from testbed.simulation.vehicle import constants, load_model

FREE = ("Y_uv", "Y_ur", "Y_uudr", "Z_uw", "Z_uq", "Z_uude", "M_uw", "M_uq", "M_uude", "N_uv")
SIGMA = np.array([NOISE_STD[s] for s in STATES])


@pytest.fixture(scope="module")
def truth():
    return captive_truth()


def captive_truth():
    """The torpedo's nonlinear model at 20 m/s and its captive reference's θ."""
    mjcf = load_model()
    model = nonlinear_model(constants(mjcf, 20.0))
    return model, nonlinear_theta(model, captive_reference(mjcf, 20.0).coefficients)


def doublet(t, start, half, amplitude):
    return amplitude * (
        ((t >= start) & (t < start + half)) * 1.0 - ((t >= start + half) & (t < start + 2 * half))
    )


def manoeuvre(seconds=10.0):
    """Rudder, elevator and aileron doublets of 3° (0.3° differential) at 50 Hz from 20 m/s."""
    t = np.arange(round(seconds * 50) + 1) * 0.02
    a = np.radians(3.0)
    fins = np.column_stack(
        [
            doublet(t, 0.5, 1.0, a) + doublet(t, 6.0, 0.7, -a),
            doublet(t, 2.5, 1.0, a) + doublet(t, 7.5, 0.6, a),
            doublet(t, 4.5, 0.5, np.radians(0.3)),
        ]
    )
    x0 = np.zeros(10)
    x0[0] = 20.0
    return t, fins, x0


def test_the_trajectory_sensitivities_are_the_complex_step_derivatives_of_the_flight(truth):
    """The compiled sensitivity pass against complex steps of the compiled flight (its complex128
    specialisation): every inertia coefficient, terms with magnitudes and fins, every x0."""
    model, theta = truth
    t, fins, x0 = manoeuvre(2.0)
    x0 = x0 + np.array([0, 0.1, -0.1, 0.05, 0.02, -0.03, 0.1, -0.05, 0.3, 10.0])
    names = INERTIA + ("Y_uv", "M_q|q|", "N_uudr", "K_p|p|", "X_uudada", "Z_uude|da|", "Y_uv|dr|")
    free = [model.names.index(n) for n in names]
    got = flight(model, theta, t, x0, fins, free)
    assert np.array_equal(got.x, fly_nonlinear(model, theta, t, x0, fins))
    for j, i in enumerate(free):
        step = 1e-30 * abs(theta[i])
        tc = theta.astype(complex)
        tc[i] += 1j * step
        want = fly_nonlinear(model, tc, t, x0, fins).imag / step
        assert np.abs(got.dx_dtheta[:, :, j] - want).max() <= 1e-12 * np.abs(want).max(), names[j]
    for i in range(10):
        xc = x0.astype(complex)
        xc[i] += 1e-30j
        want = fly_nonlinear(model, theta, t, xc, fins).imag / 1e-30
        assert np.abs(got.dx_dx0[:, :, i] - want).max() <= 1e-12 * np.abs(want).max(), STATES[i]


def test_the_default_flight_takes_5_ms_steps_at_any_sample_rate(truth):
    """Flown by default, the record at 50 Hz and the same fins on a 10 ms grid reach the same
    states at the common instants (4 and 2 RK4 steps a row: the same 5 ms steps), as flights
    with those steps given; 10 ms steps would leave them apart by RK4's error."""
    model, theta = truth
    t, fins, x0 = manoeuvre(2.0)
    fine_t = np.arange(2 * len(t) - 1) * 0.01
    fine_fins = np.repeat(fins, 2, axis=0)[:-1]
    coarse, fine = (
        fly_nonlinear(model, theta, t, x0, fins),
        fly_nonlinear(model, theta, fine_t, x0, fine_fins),
    )
    assert np.array_equal(coarse, fly_nonlinear(model, theta, t, x0, fins, substeps=4))
    assert np.array_equal(fine, fly_nonlinear(model, theta, fine_t, x0, fine_fins, substeps=2))
    scale = np.abs(coarse).max(axis=0) + 1e-3
    assert np.max(np.abs(fine[::2] - coarse) / scale) < 1e-12
    coarser = fly_nonlinear(model, theta, fine_t, x0, fine_fins, substeps=1)[::2]
    assert np.max(np.abs(coarser - coarse) / scale) > 1e-9


def noisy(model, theta, seed, seconds=10.0):
    t, fins, x0 = manoeuvre(seconds)
    rng = np.random.default_rng(seed)
    y = fly_nonlinear(model, theta, t, x0, fins) + rng.normal(size=(len(t), 10)) * SIGMA
    start = theta.copy()
    for n in FREE:
        start[model.names.index(n)] *= np.exp(0.2 * rng.normal())
    return FlightRecord(t=t, fins=fins, y=y), start


@pytest.mark.parametrize("free_initial", [True, False])
def test_the_normal_equations_are_those_of_the_whole_jacobian_stacked(free_initial):
    """`normal_equations` of several records with samples missing, against JᵀR⁻¹J and JᵀR⁻¹e of
    the whole Jacobian written out here: every record's rows stacked, its initial states' columns
    its own and zero in the others' rows, the missing samples' rows left out."""
    from testbed.identification.nonlinear_output_error import normal_equations

    rng = np.random.default_rng(3)
    p, C, lengths = 4, 3, (40, 25, 31)
    R = rng.uniform(0.5, 2.0, C)
    res, sens = [], []
    for n in lengths:
        e = rng.standard_normal((n, C))
        e[rng.random((n, C)) < 0.2] = np.nan
        res.append(e)
        sens.append((rng.standard_normal((n, C, p)), rng.standard_normal((n, C, C))))
    P = p + (len(lengths) * C if free_initial else 0)
    rows, values = [], []
    for i, (e, (St, Sx)) in enumerate(zip(res, sens)):
        for k in range(len(e)):
            for c in range(C):
                if np.isnan(e[k, c]):
                    continue
                row = np.zeros(P)
                row[:p] = St[k, c]
                if free_initial:
                    row[p + i * C : p + (i + 1) * C] = Sx[k, c]
                rows.append(row / np.sqrt(R[c]))
                values.append(e[k, c] / np.sqrt(R[c]))
    J, e = np.array(rows), np.array(values)
    H, g = normal_equations(res, sens, R, free_initial)
    np.testing.assert_allclose(H, J.T @ J, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(g, J.T @ e, rtol=1e-12, atol=1e-12)
