"""The input delay (`input_delay`): the fins' angle at t is the one recorded at t + τ."""

import numpy as np
import pytest
from references import assert_curvature_matches_complex_step, assert_sensitivities_match_complex_step, qr_cost
from identification.test_offsets import LATERAL, _start  # noqa: F401  (shared data)

from testbed.errors import InputError
from testbed.estimators import identify
from testbed.identification import concentrated, likelihood
from studies.remus import EXAMPLE_COEFFICIENTS, NOISE, VEHICLE
from testbed.identification.problem import problem, shifted
from testbed.models.linear import IX, NX, STATES, continuous, structure, theta_vector

DELAY = 0.075  # s: a logger 1.5 samples late at 20 Hz


def _late(duration=40.0, noise=True, delay=DELAY):
    """Rudder PRBS records flown with the fins' true angles, recorded `delay` late: the record's
    angle at t is the fin's at t − delay. Simulated on a grid 10× finer than the record's by
    scipy (its own zero-order hold), so the delay falls between the fine steps exactly."""
    from scipy import signal

    from testbed.data import Experiment
    from studies.remus import inputs

    rng = np.random.default_rng(11) if noise else None
    A, B, S = continuous(structure(VEHICLE), theta_vector(EXAMPLE_COEFFICIENTS))
    out = []
    for j in (1, 2):
        t, u = inputs(duration=duration, seed=j)["horizontal"]
        dt, fine = float(t[1] - t[0]), 10
        h = dt / fine
        Ad, Bd, *_ = signal.cont2discrete(
            (A, np.column_stack([B, S]), np.eye(NX), np.zeros((NX, 4))), h, "zoh"
        )
        n = len(t) * fine
        true = np.repeat(u, fine, axis=0)  # the fins' own angle, held over each fine step
        x = np.zeros((n, NX))
        for k in range(n - 1):
            x[k + 1] = Ad @ x[k] + Bd @ np.r_[true[k], 1.0]
        lag = int(round(delay / h))
        recorded = np.vstack([np.repeat(true[:1], lag, axis=0), true[:-lag]])  # late by `delay`
        # each record interval's mean angle, as the testbed records it
        u_rec = recorded.reshape(len(t), fine, 3).mean(axis=1)
        xs = x[::fine].copy()
        xs[:, IX["u"]] += VEHICLE.speed
        y = xs if rng is None else xs + rng.normal(size=xs.shape) * np.array([NOISE[s] for s in STATES])
        out.append(Experiment(f"late-{j}", t, STATES, y, u_rec))
    return out


def test_shifted_is_exact_on_quadratics_smooth_across_samples_and_held_at_the_ends():
    u = np.arange(8.0)[:, None] ** 2
    value, first, second = shifted(u, 1.25)
    s = np.arange(5) + 1.25  # where all four samples it convolves lie in the record
    np.testing.assert_allclose(value[:5, 0], s**2)  # cubic convolution reproduces quadratics
    np.testing.assert_allclose(first[:5, 0], 2 * s)
    np.testing.assert_allclose(second[:5, 0], 2.0)
    np.testing.assert_allclose(value[6:, 0], 49.0)  # beyond the end: the last sample, held
    np.testing.assert_allclose(first[6:, 0], 0.0)
    assert shifted(u, -0.5)[0][0, 0] == 0.0 and shifted(u, -0.5)[1][0, 0] == 0.0
    # C¹ in the shift across a whole sample (where linear interpolation has a kink)
    w = np.random.default_rng(5).normal(size=(50, 3))
    below, at = shifted(w, 3.0 - 1e-9), shifted(w, 3.0)
    np.testing.assert_allclose(below[0][:40], at[0][:40], atol=1e-8)
    np.testing.assert_allclose(below[1][:40], at[1][:40], atol=1e-7)
    np.testing.assert_allclose(at[0][:40], w[3:43])  # at a whole sample: the samples themselves
    # and at the ends, where the hold begins: the slope reaching the last sample is the hold's, 0
    np.testing.assert_allclose(shifted(w, 3.0 - 1e-9)[1][46], 0.0, atol=1e-6)
    np.testing.assert_allclose(shifted(w, -3.0 + 1e-9)[1][3], 0.0, atol=1e-6)


def test_sensitivities_to_the_delay_match_complex_step():
    data = _late(duration=3.0)
    prob = problem(data, _start(LATERAL + ("input_delay",)).with_coefficients({"input_delay": 0.03}))
    p = likelihood.initial_states(prob, prob.start)
    assert_sensitivities_match_complex_step(prob, p)


def test_second_order_sensitivities_with_a_delay_match_complex_step():
    data = _late(duration=2.0)
    prob = problem(data, _start(LATERAL + ("input_delay",)).with_coefficients({"input_delay": 0.03}))
    p = likelihood.initial_states(prob, prob.start)
    weights = [np.random.default_rng(3).normal(size=r.y.shape) for r in prob.records]
    assert_curvature_matches_complex_step(prob, p, weights)


def test_the_simplex_cost_with_a_delay_is_the_qr_likelihood():
    prob = problem(_late(duration=10.0), _start(LATERAL + ("input_delay",)))
    values = prob.start.copy()
    values[-1] = DELAY
    R = np.full(len(prob.channels), 1e-4)
    qr = qr_cost(prob, values, R)
    assert concentrated.Cost(prob)(values, R) == pytest.approx(qr, rel=1e-9)


def test_the_delay_is_recovered_where_a_model_without_it_is_biased():
    data = _late()
    truth = EXAMPLE_COEFFICIENTS | {"input_delay": DELAY}
    est = identify(data, _start(LATERAL + ("input_delay",)), method="ml-gn")
    assert est.converged
    sigmas = {n: (v - truth[n]) / s for n, v, s in zip(est.free, est.values, est.std)}
    assert max(abs(v) for v in sigmas.values()) < 3.0, sigmas
    plain = identify(data, _start(), method="ml-gn")
    worst = max(abs(v - truth[n]) / s for n, v, s in zip(plain.free, plain.values, plain.std))
    assert worst > 5.0


def test_the_kalman_filters_refuse_a_free_delay_and_ml_fem_fits_it():
    data = _late(duration=5.0)
    config = _start(LATERAL + ("input_delay",))
    for method in ("mekf", "ekf"):
        with pytest.raises(InputError, match="inputs' delay") as exc:
            identify(data, config, method=method)
        assert "\n" not in str(exc.value)
    truth = EXAMPLE_COEFFICIENTS | {"input_delay": DELAY}
    est = identify(_late(), config, method="ml-fem")
    assert est.converged, est.message
    sigmas = {n: (v - truth[n]) / s for n, v, s in zip(est.free, est.values, est.std)}
    assert max(abs(v) for v in sigmas.values()) < 3.0, sigmas


def test_the_screen_keeps_a_delay_the_data_determine():
    from testbed.analysis.screening import screening

    s = screening(_late(duration=20.0), _start(LATERAL + ("input_delay",)))
    assert "input_delay" not in s.fixed and "input_delay" in s.config.free


def test_the_likelihood_is_smooth_in_the_delay_across_whole_samples():
    """Fins that step at the record's instants, logged one sample late: the cost's slope in τ on
    either side of a whole sample is the same (with linear interpolation of the record it
    jumps there, a kink every estimator would have to step around)."""
    data = _late(duration=10.0, delay=0.05)
    dt = float(data[0].t[1] - data[0].t[0])
    prob = problem(data, _start(LATERAL + ("input_delay",)).with_coefficients(EXAMPLE_COEFFICIENTS))
    R = np.array([NOISE[STATES[c]] ** 2 for c in range(NX)])[: len(prob.channels)]
    cost = concentrated.Cost(prob)
    h = 1e-6 * dt
    for m in (1, 2, 3):
        at = prob.start.copy()
        slopes = []
        for side in (-1, 1):
            values = [at.copy(), at.copy()]
            values[0][-1], values[1][-1] = m * dt, m * dt + side * h
            slopes.append(side * (cost(values[1], R) - cost(values[0], R)) / h)
        assert abs(slopes[1] - slopes[0]) <= 1e-3 * abs(slopes[1]), (m, slopes)
