"""The nonlinear model's output-error fit (`fit_output_error`: the linear model's trust-region
optimiser over the nonlinear objective) on data the model itself flew, with the testbed's sensor
noise, against the truth and the Cramér-Rao bounds."""

from __future__ import annotations

import numpy as np
import pytest

from testbed.errors import InputError
from testbed.estimators import Status
from testbed.estimators.nonlinear_fit import fit_output_error
from testbed.models.linear import STATES
from testbed.models.nonlinear_flight import fly_nonlinear
from identification.test_nonlinear_output_error import FREE, SIGMA, captive_truth, noisy


@pytest.fixture(scope="module")
def truth():
    return captive_truth()


def test_a_fit_from_a_perturbed_start_returns_the_truth_within_three_sigma(truth):
    model, theta = truth
    record, start = noisy(model, theta, seed=1)
    fit = fit_output_error(model, start, [record], STATES, FREE)
    assert fit.status is Status.CONVERGED
    for n in FREE:
        true = theta[model.names.index(n)]
        assert abs(fit.estimates[n] - true) <= 3 * fit.std[n], (n, fit.estimates[n], true, fit.std[n])
        assert fit.theta[model.names.index(n)] == fit.estimates[n]
    held = [n for n in model.names if n not in FREE]
    assert np.array_equal(
        fit.theta[[model.names.index(n) for n in held]], theta[[model.names.index(n) for n in held]]
    )
    # the noise estimated is the noise added (1000 samples: its standard deviation to ~2 %)
    assert np.allclose([fit.noise_std[s] for s in STATES], SIGMA, rtol=0.08)
    assert np.all(np.abs(fit.initial_states - record.y[0]) <= 3 * SIGMA)


def test_a_start_whose_flight_overflows_is_fitted_by_multiple_shooting(truth):
    model, theta = truth
    record, start = noisy(model, theta, seed=5, seconds=3.0)
    with np.errstate(all="ignore"):
        assert not np.all(np.isfinite(fly_nonlinear(model, start, record.t, record.y[0], record.fins)))
    fit = fit_output_error(model, start, [record], STATES, FREE)
    assert fit.status is Status.CONVERGED
    for n in FREE:
        assert abs(fit.estimates[n] - theta[model.names.index(n)]) <= 3 * fit.std[n], n


def test_held_noise_and_held_initial_states_are_kept(truth):
    model, theta = truth
    record, start = noisy(model, theta, seed=2, seconds=2.0)
    given = {"q": 0.004, "r": 0.001}
    fit = fit_output_error(model, start, [record], STATES, FREE[:2], free_initial=False, noise_std=given)
    assert fit.noise_std["q"] == 0.004 and fit.noise_std["r"] == 0.001
    assert np.array_equal(fit.initial_states[0], record.y[0])


def test_bad_names_are_one_line_input_errors(truth):
    model, theta = truth
    record, _ = noisy(model, theta, seed=3, seconds=0.2)
    cases = [
        dict(channels=STATES, free=("Y_nope",)),
        dict(channels=STATES, free=()),
        dict(channels=("u", "yaw"), free=FREE),
        dict(channels=STATES, free=FREE, noise_std={"x": 1.0}),
        dict(channels=STATES, free=FREE, noise_std={"u": -1.0}),
        dict(channels=STATES[:3], free=FREE),  # y has 10 columns
        dict(channels=STATES, free=FREE, max_iterations=0),
    ]
    for kwargs in cases:
        with pytest.raises(InputError) as err:
            fit_output_error(model, theta, [record], **kwargs)
        assert "\n" not in str(err.value)


@pytest.mark.slow  # Monte Carlo over noise seeds, about 5 s on one core
def test_the_cramer_rao_bounds_match_the_scatter_over_seeds(truth):
    """Over 8 noise seeds the errors normalised by their σ have mean square ≈ 1 (80 of them:
    χ²₈₀/80 lies in [0.5, 1.6] with probability > 0.999). Starts that fly the manoeuvre to
    overflow are among them (one of the eight)."""
    model, theta = truth
    z, diverged = [], 0
    for seed in range(10, 18):
        record, start = noisy(model, theta, seed=seed, seconds=6.0)
        with np.errstate(all="ignore"):
            diverged += not np.all(
                np.isfinite(fly_nonlinear(model, start, record.t, record.y[0], record.fins))
            )
        fit = fit_output_error(model, start, [record], STATES, FREE)
        assert fit.status is Status.CONVERGED
        z += [(fit.estimates[n] - theta[model.names.index(n)]) / fit.std[n] for n in FREE]
    assert diverged >= 1
    assert 0.5 <= np.mean(np.square(z)) <= 1.6, np.round(z, 2)


def test_the_linear_and_the_nonlinear_fit_run_through_one_optimiser(truth, monkeypatch):
    """`ml-gn` on either model runs the same `trust_region`, given each model's objective: its
    second-order check at each optimum sees the linear and then the nonlinear objective."""
    from studies.remus import example_config, experiments

    from testbed.estimators import identify, trust_region
    from testbed.identification.linear_objective import LinearObjective
    from testbed.identification.nonlinear_objective import NonlinearObjective

    seen = []
    real = trust_region.second_order

    def second_order(prob, *args, **kwargs):
        seen.append(type(prob))
        return real(prob, *args, **kwargs)

    monkeypatch.setattr(trust_region, "second_order", second_order)
    identify(experiments(seed=2, duration=20.0)[1:], example_config(), "ml-gn", start="config")
    assert set(seen) == {LinearObjective}
    model, theta = truth
    record, start = noisy(model, theta, seed=1, seconds=4.0)
    fit_output_error(model, start, [record], STATES, FREE)
    assert set(seen) == {LinearObjective, NonlinearObjective}


def test_the_second_order_probes_lie_one_cramer_rao_sigma_out(truth):
    """At the nonlinear fit's optimum, the probes of the second-order check (the flight has no
    second-order sensitivities) lie one Cramér-Rao σ out along the least-determined directions:
    the weighted cost rises by ½ there (its quadratic model; within 20 %), and none lowers it."""
    from testbed.estimators import trust_region
    from testbed.estimators.nonlinear_fit import nonlinear_problem
    from testbed.identification.nonlinear_output_error import neg_log_likelihood, pooled_noise
    from testbed.identification.objective import Point, following

    model, theta = truth
    record, start = noisy(model, theta, seed=1, seconds=6.0)
    fit = fit_output_error(model, start, [record], STATES, FREE)
    prob = nonlinear_problem(model, start, [record], STATES, FREE)  # the fit's own
    xs, res = fit.outcome.simulated
    R = pooled_noise(res, prob.held)
    at = Point(fit.outcome.p, xs, res, R, neg_log_likelihood(res, R))
    g, M = prob.terms(at)
    directions, probed = trust_region.second_order(prob, at, np.abs(prob.start), M)
    assert probed and len(directions) == trust_region.PROBES
    base = prob.weighted_cost(at.res, at.R)
    for v in directions:
        for sign in (1.0, -1.0):
            moved = prob.moved(at, following(M, np.zeros(len(M)), prob.n_free, sign * v)[0])
            rise = prob.weighted_cost(moved.res, at.R) - base
            assert 0.4 <= rise <= 0.6, rise


def test_the_nonlinear_objectives_gradient_is_the_cost_differentiated(truth):
    """`NonlinearObjective.terms`' g is minus the gradient of the weighted cost `½ Σ eᵀR⁻¹e` in
    the whole parameter vector (coefficients and initial states), R held: against central
    differences of the cost the objective itself evaluates (`moved`)."""
    from testbed.estimators.nonlinear_fit import nonlinear_problem

    model, theta = truth
    record, start = noisy(model, theta, seed=3, seconds=2.0)
    prob = nonlinear_problem(model, start, [record], STATES, FREE)
    at = prob.point(prob.start)
    g, M = prob.terms(at)
    assert M.shape == (len(g), len(g)) == (prob.n_free + len(STATES),) * 2
    seen = np.diag(M) > 0  # a term the 2 s do not excite has no information and no gradient
    assert np.all(g[~seen] == 0) and seen.sum() >= len(g) - 2
    scale = np.sqrt(1.0 / np.where(seen, np.diag(M), 1.0))  # one Cramér-Rao-like unit per parameter
    for k in np.flatnonzero(seen):
        e = np.zeros(len(g))
        e[k] = 1e-3 * scale[k]
        up, down = prob.moved(at, e), prob.moved(at, -e)
        slope = (prob.weighted_cost(up.res, at.R) - prob.weighted_cost(down.res, at.R)) / (2 * e[k])
        assert slope == pytest.approx(-g[k], rel=1e-4, abs=1e-6 / scale[k]), k


def test_the_initial_states_step_minimises_the_quadratic_model_given_thetas():
    """`objective.following`: with θ moved by d, the initial states' step `M_xx⁻¹ (g_x − M_xθ d)`
    minimises `−gᵀp + ½ pᵀM p` over them, and `g_xᵀ M_xx⁻¹ g_x` is twice the decrease of their
    own step; against numpy's least squares on a random positive definite model."""
    from testbed.identification.objective import following

    rng = np.random.default_rng(5)
    nf, n = 3, 7
    A = rng.normal(size=(20, n))
    M, g = A.T @ A, rng.normal(size=n)
    d = rng.normal(size=nf)
    step, own = following(M, g, nf, d)
    np.testing.assert_array_equal(step[:nf], d)
    # the model's minimiser over x given θ's step d: M_xx x = g_x − M_xθ d
    x = np.linalg.lstsq(M[nf:, nf:], g[nf:] - M[nf:, :nf] @ d, rcond=None)[0]
    np.testing.assert_allclose(step[nf:], x, rtol=1e-10)
    alone = np.linalg.solve(M[nf:, nf:], g[nf:])
    assert own == pytest.approx(g[nf:] @ alone, rel=1e-10)
    assert following(M[:nf, :nf], g[:nf], nf, d) == (d, 0.0) or np.array_equal(
        following(M[:nf, :nf], g[:nf], nf, d)[0], d
    )
