"""A global search's box draws (`multistart.box_draws`), the one search of both models' `global`
start, against the draws and segment costs computed independently of the `Objective` protocol."""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from testbed.estimators import identify, ml
from testbed.estimators.multistart import BOX_BOUNDS, box_draws, latin
from testbed.identification import bounds, likelihood, recursions
from testbed.identification.linear_objective import as_objective
from testbed.identification.problem import problem
from studies.remus import experiments, prior_config

OPTIONS = SimpleNamespace(samples=12, spread=0.5, polish=3, seed=4)


def _segment_cost(stage, theta: np.ndarray) -> float:
    """The negative log-likelihood on the segments with their least-squares initial states,
    simulated from them: the linear model's own path, not the objective's point."""
    with np.errstate(over="ignore", invalid="ignore"):
        p = likelihood.initial_states(stage, theta)
        out = recursions.simulated_outputs(stage, p)
    if likelihood.exploded(stage, out) is not None:
        return np.inf
    return likelihood.negative_log_likelihood(stage, [r.residual(y) for r, y in zip(stage.records, out)])


@pytest.fixture(scope="module")
def prob():
    config = prior_config(error=0.3)
    return problem(experiments(seed=0), config.with_coefficients({config.free[1]: 0.0}))  # Y_r at 0


def _expected(prob, draws: np.ndarray) -> list[np.ndarray]:
    stage = likelihood.segmented(prob, likelihood.SEGMENTS, likelihood.LEAST_SEGMENT)
    costs = np.array([_segment_cost(stage, d) for d in draws])
    return [draws[i] for i in np.argsort(costs)[: OPTIONS.polish] if np.isfinite(costs[i])]


def _draws(prob) -> tuple[np.ndarray, np.ndarray]:
    """The Latin hypercube draws around the a-priori values, a value at 0 within ±`BOX_BOUNDS` of
    its Cramér-Rao bound there, from the states simulated at the fitted initial states; with
    the bounds' σ."""
    theta0 = prob.start
    p = likelihood.initial_states(prob, theta0)
    xs = recursions.states(prob, p)
    res = [r.residual(prob.outputs(r, x, theta0)) for r, x in zip(prob.records, xs)]
    g, M = likelihood.gauss_newton_terms(prob, p, xs, res, likelihood.noise_variance(prob, res))
    std = bounds.crlb(likelihood.reduced(M, g, prob.n_free)[0]).std
    half = np.where(theta0 == 0, BOX_BOUNDS * std, 0.0)
    return latin(theta0, half, OPTIONS.samples, OPTIONS.spread, np.random.default_rng(OPTIONS.seed)), std


def test_the_best_box_draws_are_the_latin_draws_of_least_cost_on_the_segments(prob):
    assert prob.start[1] == 0  # a coefficient analysed at 0: its half-width from its Cramér-Rao bound
    draws, std = _draws(prob)
    assert np.isfinite(std[1]) and np.ptp(draws[:, 1]) > std[1]
    found = box_draws(as_objective(prob), OPTIONS)
    assert len(found) == OPTIONS.polish
    np.testing.assert_allclose(
        np.array(found), np.array(_expected(prob, draws)), rtol=1e-9, atol=1e-9 * std[1]
    )


def test_the_box_draws_stay_inside_the_bounds(prob):
    theta0 = prob.start
    width = np.abs(theta0) * 0.1 + 1e-3
    box = (theta0 - width, theta0 + width)  # narrower than e^±0.5
    found = box_draws(as_objective(prob), OPTIONS, box)
    assert found and all(np.all(d >= box[0]) and np.all(d <= box[1]) for d in found)
    draws, std = _draws(prob)
    assert np.any((draws < box[0]) | (draws > box[1]))  # the box cut some draws
    np.testing.assert_allclose(
        np.array(found), np.array(_expected(prob, np.clip(draws, *box))), rtol=1e-9, atol=1e-9 * std[1]
    )


def test_a_bounded_linear_global_fit_draws_its_starts_inside_its_bounds(monkeypatch):
    config = prior_config(error=0.3)
    bounds = {
        n: tuple(sorted((0.8 * config.coefficients[n], 1.2 * config.coefficients[n]))) for n in config.free
    }
    bounded = replace(config, bounds=bounds)
    seen = []

    def spy(objective, options, box=None):
        seen.append(box)
        return box_draws(objective, options, box)

    monkeypatch.setattr(ml, "box_draws", spy)
    est = identify(
        experiments(seed=0),
        bounded,
        method="ml-gn",
        options={"start": "global", "samples": 20, "spread": 1.0, "polish": 2},
    )
    assert len(seen) == 1
    np.testing.assert_array_equal(seen[0][0], [bounds[n][0] for n in config.free])
    np.testing.assert_array_equal(seen[0][1], [bounds[n][1] for n in config.free])
    assert [s["start"] for s in est.starts][-2:] == ["box-1", "box-2"]
    assert all(bounds[n][0] <= v <= bounds[n][1] for n, v in est.coefficients.items() if n in bounds)
