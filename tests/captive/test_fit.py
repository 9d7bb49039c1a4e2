"""The nonlinear model fitted to captive tests: a round trip through captive tests of the model
itself, the reference's linearisation against the analytic linear model, and the reference flown
against Scenario I's noise-free truth."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from testbed.fit_percent import fit_percent
from testbed.data import read_csv
from testbed.errors import InputError
from testbed.models.nonlinear import (
    INERTIA,
    TERMS,
    forces,
    linearise,
    nonlinear_model,
    rates,
    nonlinear_theta,
    thrust,
)
from testbed.models.nonlinear_flight import fly_nonlinear
from testbed.simulation import runs
from testbed.simulation.analytic import analytic_model
from testbed.captive.rig import DEFAULT_TESTS, Measurement, captive_tests
from testbed.captive.fit import fit_captive, pmm_inertia
from testbed.captive.reference import (
    Turns,
    captive_reference,
    couplings,
    reference_tests,
    slope_terms,
    steady_turns,
)
from testbed.simulation.vehicle import added_mass, constants, load_model

# The damping and control derivatives the linearisation is judged on
CHECKED = (
    "Y_v Y_r Y_p Y_dr Z_w Z_q Z_de K_v K_p K_r K_dr K_der K_del M_w M_q M_de N_v N_p N_r N_dr X_u".split()
)


def model_wrench(model, theta, tests):
    """What captive tests of the nonlinear model itself read: its forces without weight,
    buoyancy, rigid-body inertia (the forces of the same model with no added mass and no terms)
    and thrust, less its added mass's inertia −M_A ν̇."""
    rigid = np.zeros(len(theta))  # M = M_RB, no terms, no thrust
    M_A = model.inertia(theta) - model.M_RB
    out = []
    for test in tests:
        for speed in test.speeds:
            nu, nu_dot, fins = test.states(speed)
            x = np.concatenate([nu, np.zeros((len(nu), 4))], axis=1)
            wrench = forces(model, theta, x, fins) - forces(model, rigid, x, fins) - nu_dot @ M_A.T
            wrench[:, 0] -= thrust(model, theta)
            out.append(Measurement(test.name, speed, nu, nu_dot, fins, wrench))
    return tuple(out)


def made_up_theta(model, seed=1):
    """The analytic model's inertia coefficients and term coefficients of random sign and size
    (each row's scale its analytic linear terms' one)."""
    rng = np.random.default_rng(seed)
    lin = analytic_model(load_model(), 20.0).coefficients
    scale = {"X": 10.0, "Y": 100.0, "Z": 100.0, "K": 5.0, "M": 100.0, "N": 100.0}
    values = {n: lin[n] for n in INERTIA}
    values.update({t: scale[t[0]] * rng.uniform(0.5, 2.0) * rng.choice([-1, 1]) for t in TERMS})
    return nonlinear_theta(model, values)


def test_a_captive_test_of_the_model_fits_back_to_its_coefficients():
    """Round trip: the wrenches a captive test of the nonlinear model itself would read, at the
    reference's test states, are fitted back to the model's inertia and term coefficients."""
    mjcf = load_model()
    model = nonlinear_model(constants(mjcf, 20.0))
    theta = made_up_theta(model)
    tests = reference_tests(20.0)
    measured = model_wrench(model, theta, tests)
    fit = fit_captive(model.vehicle, tests, measured, thrust(model, theta))
    got = nonlinear_theta(model, fit.coefficients)
    assert np.abs(got - theta).max() <= 1e-8 * np.abs(theta).max()
    for name, value in zip(model.names, theta):
        assert fit.coefficients[name] == pytest.approx(value, rel=1e-7, abs=1e-9 * abs(value) + 1e-9), name
    assert min(fit.rows.values()) > 100 - 1e-6
    assert all(math.isnan(s.fit) or s.fit > 100 - 1e-5 for s in fit.surfaces)
    # held terms stay where they are held, the rest fit around them
    held = {"Y_uv": 1.5 * theta[model.names.index("Y_uv")]}
    other = fit_captive(model.vehicle, tests, measured, thrust(model, theta), fixed=held)
    assert other.coefficients["Y_uv"] == held["Y_uv"]
    assert other.rows["Y"] < 99.9 and other.rows["N"] > 100 - 1e-6


def test_the_plain_default_tests_leave_couplings_unidentified():
    """The default captive tests vary at most two of v w r and the fins together, never p with
    q: a term such as K_p|q| has a zero regressor there, and the round trip misses it."""
    mjcf = load_model()
    model = nonlinear_model(constants(mjcf, 20.0))
    theta = made_up_theta(model)
    measured = model_wrench(model, theta, DEFAULT_TESTS)
    fit = fit_captive(model.vehicle, DEFAULT_TESTS, measured, thrust(model, theta))
    assert fit.coefficients["K_p|q|"] == 0.0 and theta[model.names.index("K_p|q|")] != 0


def test_the_pmm_inertia_is_the_vehicles_added_mass():
    """The oscillatory tests' quadrature parts (u v w p q r) are the vehicle's added mass at fins 0,
    as the linear model's `…dot` coefficients: −M_A's entries."""
    mjcf = load_model()
    tests = reference_tests(20.0)
    inertia = pmm_inertia(tests, captive_tests(mjcf, tests))
    M_A = added_mass(mjcf)
    where = {n: ("XYZKMN".index(n[0]), "uvwpqr".index(n[2])) for n in INERTIA}
    for name, (i, j) in where.items():
        assert inertia[name] == pytest.approx(-M_A[i, j], rel=1e-9, abs=1e-9 * np.abs(M_A).max()), name


@pytest.fixture(scope="module")
def reference():
    return captive_reference(load_model(), 20.0)


def test_the_reference_linearises_to_the_analytic_model(reference):
    """The acceptance: the captive model's linearisation at 20 m/s within 1 % of the analytic
    linear model on every damping and control derivative; K_dr, 0 in both, within 1 % of K_der
    (the roll row's control derivative, same units)."""
    mjcf = load_model()
    model = nonlinear_model(constants(mjcf, 20.0))
    got = linearise(model, nonlinear_theta(model, reference.coefficients)).coefficients
    want = analytic_model(mjcf, 20.0).coefficients
    for name in CHECKED:
        scale = abs(want[name]) if want[name] else abs(want["K_der"])
        assert abs(got[name] - want[name]) <= 0.01 * scale, (name, got[name], want[name])


def test_the_reference_fits_its_surfaces_and_reports_each(reference):
    """Every test, speed and row has its fit in the table; the lateral rows fit the plant's
    forces over the region closely (the fit of the whole row, every surface together), the
    vertical ones less closely: along the pitch turns the fin's moment nearly balances the
    hull's, and the polynomial terms share their error between the turns and the box."""
    tests = reference_tests(20.0, turns=Turns(incidence=1.0, elevator=0.0, drift=-1.0, rudder=0.0))
    assert len(reference.surfaces) == 6 * sum(len(t.speeds) for t in tests)
    assert {s.test for s in reference.surfaces} == {t.name for t in tests}
    assert set(reference.coefficients) == set(INERTIA) | set(TERMS)
    assert min(reference.rows[r] for r in "YN") > 98.0 and min(reference.rows[r] for r in "ZM") > 95.0
    table = reference.table().splitlines()
    assert len(table) == 2 + sum(len(t.speeds) for t in tests)
    assert reference.thrust > 0 and reference.speed == 20.0


def test_the_reference_turns_as_the_analytic_model_turns(reference):
    """The turn tests follow the steady turns of the reference linearised at trim: the same as
    the analytic linear model's (its heave-pitch and sway-yaw rows solved for the incidence and
    elevator at a unit pitch rate, the drift and rudder at a unit yaw rate), within 1 %."""
    mjcf = load_model()
    model = nonlinear_model(constants(mjcf, 20.0))
    got = steady_turns(model, nonlinear_theta(model, reference.coefficients))
    lin = analytic_model(mjcf, 20.0)
    A, B = lin.At_full, lin.Bt_full
    de = B[:, 1] + B[:, 2]
    w, e = np.linalg.solve([[A[2, 2], de[2]], [A[4, 2], de[4]]], [-A[2, 4], -A[4, 4]])
    v, r = np.linalg.solve([[A[1, 1], B[1, 0]], [A[5, 1], B[5, 0]]], [-A[1, 5], -A[5, 5]])
    assert (got.incidence, got.elevator, got.drift, got.rudder) == pytest.approx((w, e, v, r), rel=0.01)
    assert got.incidence > 0 and got.drift < 0  # the cross flow vanishes ahead of the CG
    names = {t.name for t in reference_tests(20.0, turns=got)} - {t.name for t in reference_tests(20.0)}
    assert names == {"turn_pitch", "turn_yaw", "turn_both"} <= {s.test for s in reference.surfaces}


def test_couplings_are_the_variables_a_term_multiplies_together():
    """A grid of three or more variables is run for each term that multiplies them: `K_pwq`
    needs p, w and q at once, `X_|vw|dr` the cross flow with the rudder; a pair needs none."""
    terms = ("Y_uv", "K_pwq", "Z_uwdada", "X_|vw|dr", "K_p|qr|", "K_pqw")
    assert couplings(terms) == (("v", "w", "delta_r"), ("w", "p", "q"), ("p", "q", "r"))
    assert {("w", "p", "q"), ("p", "q", "r")} <= set(couplings())  # the default terms' K_pwq, K_p|qr|


def test_slope_terms_are_those_with_a_slope_at_trim():
    """A term has a slope at trim iff every factor but one is u and that one no magnitude: the
    linearisation of each alone (coefficient 1) has a nonzero entry exactly for those."""
    mjcf = load_model()
    vehicle = constants(mjcf, 20.0)
    found = []
    for name in TERMS:
        model = nonlinear_model(vehicle, (name,))
        lin = linearise(model, nonlinear_theta(model, {name: 1.0}))
        free = linearise(model, nonlinear_theta(model, {name: 0.0}))
        if np.abs(lin.At - free.At).max() > 0 or np.abs(lin.Bt - free.Bt).max() > 0:
            found.append(name)
    assert tuple(found) == slope_terms(TERMS)


def test_fly_is_the_ode_solution():
    """`fly_nonlinear` against an adaptive high-order solver of the same equations, interval by interval
    with each sample's fins held, over 2 s of a turning, pitching flight: it converges to it as
    the steps shrink (RK4's h⁴ where the forces are smooth; the magnitudes' kinks slow it)."""
    mjcf = load_model()
    model = nonlinear_model(constants(mjcf, 20.0))
    theta = nonlinear_theta(model, captive_reference(mjcf, 20.0).coefficients)
    t = np.arange(0, 2.0001, 0.02)
    fins = np.stack([0.05 * np.sin(2 * t), 0.1 * np.cos(3 * t), 0.08 * np.cos(3 * t)], axis=1)
    x0 = np.array([20.0, 0.1, 0.2, 0.05, 0.1, 0.05, 0.02, 0.05, 0.0, 50.0])
    ref = [x0]
    for k in range(len(t) - 1):
        step = solve_ivp(
            lambda s, x: rates(model, theta, x, fins[k]),
            (t[k], t[k + 1]),
            ref[-1],
            method="DOP853",
            rtol=1e-12,
            atol=1e-12,
        )
        ref.append(step.y[:, -1])
    ref = np.array(ref)
    error = [np.abs(fly_nonlinear(model, theta, t, x0, fins, substeps=n) - ref).max() for n in (4, 16)]
    assert error[1] < 1e-7 * np.abs(ref).max() and error[1] < error[0] / 10
    with pytest.raises(InputError, match="increasing"):
        fly_nonlinear(model, theta, t[::-1], x0, fins)


def test_the_reference_flies_scenario_i_better_than_the_linear_model(tmp_path, reference):
    """Scenario I (seed 3) flown open loop from its first noise-free truth sample with its
    recorded fin angles: the captive reference beats the analytic linear model's fits measured
    there (v 83, w 87, q 81, r 82, ψ 79, θ 42 %) on each of those channels."""
    run = runs.simulate("I", seed=3, out=tmp_path / "I")
    truth = read_csv(run / "scenario-I.truth.csv", keep_repeats=True)
    mjcf = load_model()
    model = nonlinear_model(constants(mjcf, 20.0))
    flown = fly_nonlinear(
        model, nonlinear_theta(model, reference.coefficients), truth.t, truth.y[0], truth.inputs
    )
    linear = {"v": 83, "w": 87, "q": 81, "r": 82, "psi": 79, "theta": 42}
    index = {c: i for i, c in enumerate(truth.measured)}
    for c, fit in linear.items():
        assert fit_percent(truth.column(c), flown[:, index[c]]) > fit, c


def test_bad_input_is_one_line():
    mjcf = load_model()
    vehicle = constants(mjcf, 20.0)
    tests = reference_tests(20.0)
    measured = captive_tests(mjcf, tests[:3])
    for call, match in (
        (lambda: fit_captive(vehicle, tests[:3], measured, 100.0), "no oscillation of u"),
        (lambda: fit_captive(vehicle, tests, measured, 100.0, weights={"nope": 1.0}), "weight for 'nope'"),
        (lambda: fit_captive(vehicle, tests, measured, math.nan), "thrust"),
        (lambda: reference_tests(-1.0), "speed"),
    ):
        with pytest.raises(InputError, match=match) as e:
            call()
        assert "\n" not in str(e.value)
