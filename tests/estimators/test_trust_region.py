"""The default ML optimiser's parts against independent references: its trust-region step
against scipy's constrained minimiser, its Hessian against finite differences of the cost, its
multiple-shooting segments against the whole record."""

import numpy as np
import pytest
from scipy.optimize import NonlinearConstraint, minimize

from testbed.estimators import Status, identify, trust_region
from testbed.identification import likelihood
from studies.remus import example_config, experiments
from testbed.identification.problem import problem
from testbed.identification.linear_objective import LinearObjective, point
from testbed.identification.objective import Point

VERTICAL = ("Z_w", "Z_q", "Z_de", "M_w", "M_q", "M_de")


def _model(rng, n, rank=None):
    A = rng.normal(size=(n, rank or n))
    return A @ A.T, rng.normal(size=n), np.exp(rng.normal(size=n))


@pytest.mark.parametrize("delta", [0.05, 0.5, 50.0])
@pytest.mark.parametrize("rank", [None, 3])
def test_step_solves_the_trust_region_subproblem_as_scipy_does(delta, rank):
    """Against scipy's constrained minimiser of the model in the region; for a singular F, over
    the steps along the directions F determines (D V₊, the eigenvectors of F scaled to unit
    diagonal with nonzero eigenvalues, D = 1/√diag F: the span of the Cramér-Rao covariance)."""
    rng = np.random.default_rng(7)
    F, g, s = _model(rng, 5, rank)
    basis = np.eye(5)
    if rank:  # a singular F: keep g in its range, as Gauss-Newton's is (g = Sᵀ R⁻¹ e, F = Sᵀ R⁻¹ S)
        g = F @ rng.normal(size=5)
        D = 1 / np.sqrt(np.diag(F))
        lam, V = np.linalg.eigh(F * np.outer(D, D))
        basis = D[:, None] * V[:, lam > 1e-9 * lam.max()]
    d, predicted = trust_region.subproblem(F, g, s, delta)

    def model(x):
        return -g @ x + 0.5 * x @ F @ x

    k = basis.shape[1]
    inside = NonlinearConstraint(lambda y: np.sum((basis @ y / s) ** 2), 0.0, delta**2)
    best = min(
        (minimize(lambda y: model(basis @ y), y0, constraints=[inside], method="trust-constr",
                  options={"gtol": 1e-12, "xtol": 1e-12})
         for y0 in (np.zeros(k), np.linalg.lstsq(basis, 0.5 * delta * s * rng.normal(size=5) / np.sqrt(5), rcond=None)[0])),
        key=lambda r: r.fun,
    )  # fmt: skip
    assert np.linalg.norm(d / s) <= delta * (1 + 1e-9)
    assert model(d) <= best.fun + 1e-7 * max(1.0, abs(best.fun))
    assert predicted == pytest.approx(-model(d), rel=1e-12)


def _badly_scaled(rng, n=6):
    """F = D⁻¹ C D⁻¹: a correlation matrix C of condition ~1e5 between coefficients whose bounds
    D span six decades, as a model's information has when one coefficient is known to 1e-3 and
    another to 1e3; the region's scales s = 1 know nothing of it (S F S's condition ~1e17)."""
    Q = np.linalg.qr(rng.normal(size=(n, n)))[0]
    C = Q @ np.diag(np.logspace(0, -5, n)) @ Q.T
    C /= np.sqrt(np.outer(np.diag(C), np.diag(C)))
    D = np.logspace(-3, 3, n)
    return C / np.outer(D, D), rng.normal(size=n) / D, np.ones(n)


def test_a_badly_scaled_region_keeps_every_direction_the_data_determine():
    """Inside the region the step is F⁻¹g whatever the region's scales: none of F's directions
    is dropped for being small in the region's coordinates."""
    F, g, s = _badly_scaled(np.random.default_rng(3))
    full = np.linalg.solve(F, g)
    d, predicted = trust_region.subproblem(F, g, s, 10 * np.linalg.norm(full / s))
    assert d == pytest.approx(full, rel=1e-6, abs=1e-6 * np.abs(full).max())
    assert predicted == pytest.approx(0.5 * g @ full, rel=1e-8)


@pytest.mark.parametrize("fraction", [0.9, 0.3, 1e-3])
def test_a_step_on_the_boundary_satisfies_the_optimality_conditions(fraction):
    """On the boundary the step is the global minimiser of the model in the region (Moré &
    Sorensen): ‖d/s‖ = Δ and (F + μ S⁻²) d = g for some μ ≥ 0 (F positive definite here), for a
    region just inside the full step's and one far inside it, where the multiplier's root lies
    well below the bracket's first guess ‖c‖/Δ."""
    F, g, s = _badly_scaled(np.random.default_rng(5))
    delta = fraction * np.linalg.norm(np.linalg.solve(F, g) / s)
    d, _ = trust_region.subproblem(F, g, s, delta)
    assert np.linalg.norm(d / s) == pytest.approx(delta, rel=1e-9)
    r, n = g - F @ d, d / s**2
    mu = n @ r / (n @ n)
    assert mu >= 0
    assert np.linalg.norm(r - mu * n) <= 1e-6 * np.linalg.norm(g)


def test_hessian_is_the_second_derivative_of_the_cost_with_the_initial_states_fitted():
    data = experiments(seed=2, duration=20.0)[1:]
    config = example_config(VERTICAL)
    prob = problem(data, config)
    theta = prob.start * 1.05  # off the optimum, where the second-order terms count
    R = point(prob, prob.start).R

    def cost(th):
        p, out = likelihood.fit_initial_states(prob, th, R)
        return likelihood.weighted_cost(prob, [r.y - y for r, y in zip(prob.records, out)], R)

    p, xs = likelihood.fit_initial_states(prob, theta, R, full=True)
    res = [r.y - x[:, r.measured] for r, x in zip(prob.records, xs)]
    at = Point(p, xs, res, R, likelihood.negative_log_likelihood(prob, res))
    H = LinearObjective(prob).hessian(at)
    h = 1e-4 * np.abs(theta)
    fd = np.empty_like(H)
    for i in range(len(theta)):
        for j in range(len(theta)):
            ei, ej = np.eye(len(theta))[i] * h[i], np.eye(len(theta))[j] * h[j]
            fd[i, j] = (
                cost(theta + ei + ej) - cost(theta + ei - ej) - cost(theta - ei + ej) + cost(theta - ei - ej)
            ) / (4 * h[i] * h[j])
    scale = np.sqrt(np.outer(np.diag(H), np.diag(H)))
    np.testing.assert_allclose(H / scale, fd / scale, atol=2e-4)


def test_segments_cover_the_record_each_with_its_own_initial_state():
    data = experiments(seed=1, duration=60.0, noise=None)  # noise-free
    prob = problem(data, example_config())
    seg = likelihood.segmented(prob, 16, likelihood.LEAST_SEGMENT)
    per_record = len(seg.records) // len(prob.records)
    assert per_record == min(16, len(prob.records[0].y) // likelihood.LEAST_SEGMENT)
    for k, r in enumerate(prob.records):
        pieces = seg.records[k * per_record : (k + 1) * per_record]
        np.testing.assert_array_equal(np.vstack([q.y for q in pieces]), r.y)
        np.testing.assert_array_equal(np.vstack([q.inputs for q in pieces]), r.inputs)
    assert seg.n_params == prob.n_free + sum(len(r.measured) for r in seg.records)
    # noise-free data at the simulated coefficients: every segment's initial state is fitted exactly
    for e in point(seg, prob.start).res:
        assert np.max(np.abs(e)) < 1e-8


def test_a_stationary_point_is_checked_for_a_minimum():
    data = experiments(seed=2, duration=20.0)[1:]
    config = example_config(VERTICAL)
    est = identify(data, config, method="ml-gn", start="config")
    assert est.converged
    prob = problem(data, config)
    at = point(prob, est.values)
    assert trust_region.second_order(LinearObjective(prob), at, np.abs(est.values)) == ([], False)
    H = LinearObjective(prob).hessian(at)
    assert np.all(np.linalg.eigvalsh(H) > 0)


def test_a_fit_that_stops_at_its_limit_has_used_the_whole_limit_and_kept_its_best_point():
    # from these guesses the whole record's fit does not converge within its first iterations,
    # and multiple shooting stops at its share below the point it had reached: the rest of the
    # limit goes on from there (seed 2 then converges within 24; seed 10 needs more than 5). With
    # a limit the first attempt uses up, the point it reached is the answer, not the start
    data = experiments(seed=1, duration=60.0)
    config = example_config()
    for seed, limit, converges in ((2, 24, True), (10, 5, False)):
        rng = np.random.default_rng(seed)
        guess = config.with_coefficients(
            {n: config.coefficients[n] * np.exp(0.7 * rng.normal()) for n in config.free}
        )
        prob = problem(data, guess)
        nf = prob.n_free
        out = trust_region.trust_region(prob, prob.start.copy(), max_iter=limit)
        assert (out.status is Status.CONVERGED) is converges
        assert out.status is Status.CONVERGED or out.iterations == limit
        start = point(prob, prob.start).J
        for limit in (3, 24):
            whole = trust_region.trust_region(prob, prob.start.copy(), max_iter=limit, segments=1)
            out = trust_region.trust_region(prob, prob.start.copy(), max_iter=limit)
            J = point(prob, out.p[:nf]).J
            assert J <= point(prob, whole.p[:nf]).J + 1e-9 * abs(start) and J < start


def test_a_step_longer_than_its_region_still_shrinks_the_region(monkeypatch):
    """On coefficients scaled decades apart (a fit of random numbers ran them to 7e13) the step's
    length in floating point can come out above the region's radius it was solved for. Every
    step that fails must still shrink the region, so that a fit whose steps all fail stalls
    rather than trying the same step forever: here every step is 4 × the region long and
    uphill."""
    data = experiments(seed=2, duration=20.0)[1:]
    prob = problem(data, example_config(VERTICAL))
    solved = []

    def uphill(F, g, s, delta):
        solved.append(delta)
        assert len(solved) < 1000, f"the same step tried over and over: Δ = {solved[-5:]}"
        return -4.0 * delta * s * g / np.linalg.norm(g), 1.0

    monkeypatch.setattr(trust_region, "subproblem", uphill)
    out = trust_region.trust_region(prob, prob.start.copy(), segments=1)
    assert out.status is Status.STALLED and out.iterations == 0
    assert len(solved) < 100 and all(b < a for a, b in zip(solved, solved[1:]))


def test_a_step_in_a_box_stops_the_values_that_cross_and_solves_for_the_rest_as_scipy_does():
    """The bounded step (`trust_region.bounded_step` through the public optimiser's box): with the
    region wide open, the values the Gauss-Newton step carries across their bounds stop on them
    and the rest minimise the quadratic model given that: on a nearly diagonal convex model the
    bound-constrained minimiser, which scipy's L-BFGS-B finds independently."""
    from scipy.optimize import minimize

    rng = np.random.default_rng(3)
    n = 6
    A = np.eye(n) + 0.05 * rng.normal(size=(n, n))
    F = A.T @ A
    g = rng.normal(size=n)
    theta = np.zeros(n)
    full = np.linalg.solve(F, g)
    low, high = np.full(n, -np.inf), np.full(n, np.inf)
    for k in np.argsort(-np.abs(full))[:2]:  # the two largest moves cross a bound at half their length
        (high if full[k] > 0 else low)[k] = full[k] / 2
    d = trust_region.bounded_step(F, g, np.ones(n), 1e6, theta, np.ones(n, dtype=bool), (low, high))
    ref = minimize(
        lambda x: -g @ x + 0.5 * x @ F @ x, np.zeros(n), jac=lambda x: F @ x - g,
        bounds=list(zip(low, high)), method="L-BFGS-B", options={"ftol": 1e-15, "gtol": 1e-12},
    )  # fmt: skip
    np.testing.assert_allclose(d, ref.x, atol=1e-6)
    assert np.all(d >= low) and np.all(d <= high)


class _MisModelledInitialState:
    """W(θ, x) = ½ (θ − 1)² + 10 x², one θ and one initial state that follows it (not projected),
    whose Gauss-Newton curvature is reported as 1 where the cost's is 20: the initial state's own
    step overshoots twentyfold, as a flight far from its quadratic model in its first state does."""

    n_free, pieces, projected = 1, 1, False
    start = np.array([0.0])

    def _at(self, p):
        res = [np.array([[1.0 - p[0], -np.sqrt(20.0) * p[1]]])]
        R = np.ones(2)
        return Point(p, [None], res, R, self.weighted_cost(res, R))

    def point(self, theta, R=None):
        return self._at(np.array([theta[0], 1.0]))

    def moved(self, at, step):
        return self._at(at.p + step)

    def terms(self, at):
        e = at.res[0][0]
        return np.array([e[0], np.sqrt(20.0) * e[1]]), np.eye(2)

    def weighted_cost(self, res, R):
        return 0.5 * float(np.sum(res[0] ** 2 / R))

    def hessian(self, at, M=None):
        return None  # the second-order check probes the cost instead

    def segmented(self, count, least):
        return self

    def shooting(self, theta, least):
        return 1

    def grows(self, theta):
        return False


def test_a_rejected_step_cuts_the_initial_states_own_step_too():
    prob = _MisModelledInitialState()
    out = trust_region.trust_region(prob, np.array([0.0, 1.0]), max_iter=200)
    assert out.status is Status.CONVERGED
    assert abs(out.p[0] - 1.0) < 1e-3 and abs(out.p[1]) < 1e-3 / np.sqrt(20.0)
