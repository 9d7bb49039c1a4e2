"""The a-priori model (`testbed.study.priors.prior`) and the judge of a fit against the optimum.

The statistical checks use 2 000 seeds and a χ² test on the standardised errors of each
coefficient; each check's false-alarm rate (the chance a correct draw fails it) is 1e-3 over all
the coefficients it tests together (Bonferroni, two-sided). The seeds are fixed, so the outcome
is reproducible.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import chi2

from testbed.errors import InputError
from testbed.estimators.base import Estimate, Status
from testbed.models.linear import COEFFICIENTS
from testbed.simulation.analytic import analytic_config
from testbed.simulation.measurements import rng_for
from testbed.study.priors import (
    CLASSES,
    MEMBERS,
    SPREAD,
    PRIOR_STREAM,
    ZERO_SIGMAS,
    Ending,
    cost_bound,
    judge,
    prior,
)

DRAWS = 2000
ALPHA = 1e-3


@pytest.fixture(scope="module")
def config():
    return analytic_config()[0]


def variance_test(z: np.ndarray, alpha: float) -> bool:
    """Whether the columns of `z` (draws × tests) pass as N(0, 1): Σz² within the two-sided
    χ²(n) interval at `alpha` over all the columns together."""
    n, k = z.shape
    lo, hi = chi2.ppf(alpha / (2 * k), n), chi2.ppf(1 - alpha / (2 * k), n)
    stat = np.sum(z**2, axis=0)
    return bool(np.all((stat > lo) & (stat < hi)))


def test_every_coefficient_has_exactly_one_class():
    listed = [n for names in MEMBERS.values() for n in names]
    assert sorted(listed) == sorted(COEFFICIENTS)  # each once: no duplicates, none missing
    assert len(listed) == len(set(listed))
    assert set(CLASSES) == set(COEFFICIENTS) and set(SPREAD) == set(MEMBERS)
    assert all(CLASSES[n] == "added mass" for n in COEFFICIENTS if n.endswith("dot"))


def test_spread_zero_is_the_analytic_config(config):
    assert prior(config, 0.0, 7) is config
    assert prior(config, 0, 7, {"K_dr": 1.0}) is config


def test_every_coefficient_is_perturbed_and_the_vehicle_kept(config):
    p = prior(config, 0.4, 3, {"K_dr": 5.0})
    assert p.vehicle == config.vehicle and p.free == config.free
    assert all(p.coefficients[n] != config.coefficients[n] for n in COEFFICIENTS)
    # log-normal factors keep each sign
    assert all(
        np.sign(p.coefficients[n]) == np.sign(config.coefficients[n]) for n in COEFFICIENTS if n != "K_dr"
    )


def draws(config, spread, std):
    return np.array(
        [[prior(config, spread, seed, std).coefficients[n] for n in COEFFICIENTS] for seed in range(DRAWS)]
    )


def test_log_spread_matches_each_class(config):
    spread, std = 0.3, {"K_dr": 2.0}
    theta = np.array([config.coefficients[n] for n in COEFFICIENTS])
    x = draws(config, spread, std)
    nonzero = theta != 0
    s_c = np.array([SPREAD[CLASSES[n]] * spread for n in COEFFICIENTS])
    z = np.log(x[:, nonzero] / theta[nonzero]) / s_c[nonzero]
    assert variance_test(z, ALPHA)
    # the test has power: a spread 10 % off in every class fails it
    assert not variance_test(z / 1.1, ALPHA) and not variance_test(z * 1.1, ALPHA)


def test_zeros_get_additive_errors_in_cramer_rao_units(config):
    spread = 0.4
    zeroed = replace(config, coefficients={**config.coefficients, "Y_p": 0.0, "M_qdot": 0.0})
    std = {"K_dr": 2.0, "Y_p": 0.05, "M_qdot": 30.0}
    x = draws(zeroed, spread, std)
    cols = [COEFFICIENTS.index(n) for n in std]
    scale = np.array([ZERO_SIGMAS * SPREAD[CLASSES[n]] * spread * std[n] for n in std])
    z = x[:, cols] / scale
    assert variance_test(z, ALPHA)
    assert not variance_test(z / 1.1, ALPHA)


def test_a_zero_without_a_finite_sigma_is_refused(config):
    with pytest.raises(InputError, match="K_dr"):
        prior(config, 0.2, 1)
    with pytest.raises(InputError, match="K_dr"):
        prior(config, 0.2, 1, {"K_dr": math.inf})


@pytest.mark.parametrize("spread", [-0.1, math.nan, math.inf, "0.2", True])
def test_a_bad_spread_is_refused(config, spread):
    with pytest.raises(InputError, match="start spread"):
        prior(config, spread, 1, {"K_dr": 1.0})


@pytest.mark.parametrize("seed", [-1, 1.5, None])
def test_a_bad_seed_is_refused(config, seed):
    with pytest.raises(InputError, match="seed"):
        prior(config, 0.2, seed, {"K_dr": 1.0})


def test_same_seed_and_spread_same_prior_different_seeds_differ(config):
    std = {"K_dr": 1.0}
    a, b, c = prior(config, 0.4, 5, std), prior(config, 0.4, 5, std), prior(config, 0.4, 6, std)
    assert a.coefficients == b.coefficients
    assert all(a.coefficients[n] != c.coefficients[n] for n in COEFFICIENTS)
    # one draw per coefficient, scaled by the spread: two spreads share the direction
    d = prior(config, 0.2, 5, std)
    for n in COEFFICIENTS:
        if config.coefficients[n] != 0:
            ratio = math.log(a.coefficients[n] / config.coefficients[n])
            assert ratio == pytest.approx(2 * math.log(d.coefficients[n] / config.coefficients[n]))


def test_the_prior_is_paired_across_methods(config):
    """What a method changes about the config — its free set, the screen, the bounds of the
    coefficients that are not at 0 — does not change the prior."""
    std = {"K_dr": 1.0}
    base = prior(config, 0.4, 9, std)
    for variant in (
        replace(config, free=("Y_v", "N_r")),
        replace(config, free=(), screen=False),
        replace(config, outputs=("v", "r")),
    ):
        assert prior(variant, 0.4, 9, std).coefficients == base.coefficients
    assert prior(config, 0.4, 9, {**std, "Y_v": 3.0, "N_r": 1e9}).coefficients == base.coefficients


def test_the_prior_stream_is_not_the_noise_stream(config):
    """The prior's draws are not the noise's streams of the same seed, nor a plain generator's."""
    seed, std = 4, {"K_dr": 1.0}
    p = prior(config, 1.0, seed, std)
    z = np.array(
        [
            math.log(p.coefficients[n] / config.coefficients[n]) / SPREAD[CLASSES[n]]
            if config.coefficients[n] != 0
            else p.coefficients[n] / (ZERO_SIGMAS * SPREAD[CLASSES[n]] * std[n])
            for n in COEFFICIENTS
        ]
    )
    assert np.allclose(
        z,
        np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(PRIOR_STREAM,))).standard_normal(
            len(z)
        ),
    )
    others = [np.random.default_rng(seed)] + [rng_for(seed, e, s) for e in range(3) for s in range(2)]
    assert all(np.max(np.abs(z - g.standard_normal(len(z)))) > 0.1 for g in others)


FREE = ("Y_v", "N_r")


def estimate(values, cost, status=Status.CONVERGED, std=(1.0, 2.0), free=FREE):
    return Estimate(
        method="test",
        status=status,
        free=free,
        values=np.array(values, float),
        std=np.array(std, float),
        cost=float(cost),
        iterations=10,
        wall_time_s=0.0,
        noise_std={},
    )


BEST = estimate([10.0, -20.0], 100.0)


def test_the_cost_bound_is_the_likelihood_ratio_region():
    # χ²(2) has the closed-form quantile −2 ln(1 − level)
    assert cost_bound(2) == pytest.approx(-math.log(0.05))
    assert cost_bound(1) == pytest.approx(1.959964**2 / 2, rel=1e-6)


def test_success_is_inside_the_likelihood_region():
    j = judge(estimate([10.0 + 0.09, -20.0 - 0.19], 100.0 + 2.9), BEST)
    assert j.success and j.outcome is Ending.SUCCESS
    assert j.sigmas == pytest.approx(0.095) and j.delta_cost == pytest.approx(2.9)
    # a lower cost than the reference optimum is within the bound too
    assert judge(estimate([10.0, -20.0], 99.0), BEST).success


def test_a_fit_far_in_sigma_inside_the_region_succeeds_and_its_distance_is_measured():
    # 3 σ away on a coefficient, ΔJ 2.9 < χ²₀.₉₅(2)/2 = 3.0: the data cannot tell it from the optimum
    j = judge(estimate([10.0, -20.0 - 3.0], 100.0 + 2.9), BEST)
    assert j.success and j.sigmas == pytest.approx(1.5)


def test_a_cost_outside_the_bound_fails():
    j = judge(estimate([10.0, -20.0], 100.0 + 3.1), BEST)
    assert not j.success and j.outcome is Ending.ELSEWHERE and j.bound == pytest.approx(-math.log(0.05))


def test_an_infinite_sigma_is_an_infinite_distance_not_a_verdict():
    best = estimate([10.0, -20.0], 100.0, std=(1.0, math.inf))
    j = judge(estimate([10.0, -20.1], 100.0), best)
    assert j.success and j.sigmas == math.inf


@pytest.mark.parametrize("status", [Status.MAX_ITERATIONS, Status.STALLED])
def test_stalled_at_the_limit(status):
    assert judge(estimate([12.0, -20.0], 150.0, status), BEST).outcome is Ending.STALLED
    # a fit that stopped at its limit but inside the region is a success
    assert judge(estimate([10.0, -20.0], 100.0, status), BEST).success


def test_diverged():
    assert judge(estimate([10.0, -20.0], 150.0, Status.DIVERGED), BEST).outcome is Ending.DIVERGED
    assert judge(estimate([10.0, -20.0], math.nan), BEST).outcome is Ending.DIVERGED
    assert judge(estimate([math.inf, -20.0], 100.0), BEST).outcome is Ending.DIVERGED
    # a filter flagged diverged whose finite estimate the data cannot tell from the optimum
    assert judge(estimate([10.0, -20.0], 101.0, Status.DIVERGED), BEST).success


@pytest.mark.parametrize("status", [Status.CONVERGED, Status.SADDLE, Status.WORSE])
def test_converged_elsewhere(status):
    assert judge(estimate([5.0, -25.0], 140.0, status), BEST).outcome is Ending.ELSEWHERE


def test_free_coefficients_are_matched_by_name():
    swapped = estimate([-20.0, 10.0], 100.0, free=("N_r", "Y_v"), std=(2.0, 1.0))
    assert judge(swapped, BEST).success
    with pytest.raises(InputError, match="same free coefficients"):
        judge(estimate([10.0], 100.0, free=("Y_v",), std=(1.0,)), BEST)


def test_the_classes_are_documented_as_in_the_code():
    """docs/studies.md's table of classes lists each class's coefficients and spread as the code."""
    text = (Path(__file__).resolve().parents[2] / "docs" / "studies.md").read_text(encoding="utf-8")
    rows = {}
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip("|").split("|")]
        if len(cells) == 4 and cells[0] in MEMBERS:
            rows[cells[0]] = (cells[1], float(cells[2]))
    assert set(rows) == set(MEMBERS)
    for c, (names, spread) in rows.items():
        listed = MEMBERS[c] if c != "added mass" else ("the …dot terms",)
        assert names == ", ".join(listed) and spread == SPREAD[c]
