"""`equation-error` on a nonlinear model config (`nonlinear_regression.equation_error_estimate`): the dynamics rows
regressed on the measured states' difference quotients, with the output-error analysis at the
estimate, in the config's box; what it cannot regress refused in one line."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from estimators.test_nonlinear import FREE, _start, truth  # noqa: F401  (the fixture: doublets the captive model flew)

from testbed.errors import InputError
from testbed.estimators import OptionError, identify
from testbed.estimators.nonlinear_regression import regressed
from testbed.identification.nonlinear_output_error import setup


def test_the_method_is_the_regression_with_the_likelihood_and_bounds_of_output_error_there(truth):  # noqa: F811
    """From 20 % off on the noisy doublets: the values are the equation-error start's; the cost is
    the negative log-likelihood of output error there, so `ml-gn` started from them lowers it
    (errors in variables move the regression off the optimum) and reaches the optimum it reaches
    from the config; the Cramér-Rao σ are those of the output-error information at a point within
    5 % of that optimum (the regression's accuracy on these data), so within a quarter of its σ."""
    config, noisy, _ = truth
    start = _start(config)
    est = identify([noisy], start, "equation-error")
    channels, recs, model, theta, idx = setup([noisy], start, "the test")
    values = regressed(model, theta, recs, channels, FREE)[0][idx]
    assert est.converged and est.method == "equation-error" and 1 <= est.iterations <= 8
    np.testing.assert_array_equal(est.values, values)
    assert np.all(np.abs(est.values / [config.terms[n] for n in FREE] - 1) < 0.05)
    assert set(est.initial_states) == {noisy.name} and set(est.noise_std) == set(channels)
    optimum = identify([noisy], start, "ml-gn", start="config")
    polished = identify(
        [noisy], start.with_coefficients(dict(zip(FREE, est.values))), "ml-gn", start="config"
    )
    assert optimum.converged and polished.converged
    assert optimum.cost < est.cost and polished.cost == pytest.approx(optimum.cost, abs=1e-6)
    np.testing.assert_allclose(est.std, optimum.std, rtol=0.25)
    assert np.all(np.isfinite(est.crlb_corrected_std)) and np.all(est.crlb_corrected_std > 0)


def test_a_bound_that_holds_gives_the_regression_of_the_others_with_it_fixed_there(truth):  # noqa: F811
    """`Y_uv` bounded below its regressed value: it ends on the bound with no σ, the bound named,
    and the others are the regression with `Y_uv` fixed there (the bounded least squares' KKT
    point: the Gauss-Newton steps stop at 1e-6 of each value)."""
    config, noisy, _ = truth
    start = _start(config)
    free = identify([noisy], start, "equation-error")
    high = free.values[0] - 0.1 * abs(free.values[0])
    boxed = identify(
        [noisy],
        replace(start, bounds={"Y_uv": (-math.inf, high)}).with_coefficients({"Y_uv": high}),
        "equation-error",
    )
    assert boxed.at_bounds == {"Y_uv": pytest.approx(high)} and boxed.converged
    assert boxed.values[0] == pytest.approx(high) and math.isnan(boxed.std[0])
    assert "on its bounds: Y_uv" in boxed.message
    fixed = identify(
        [noisy], replace(start, free=FREE[1:]).with_coefficients({"Y_uv": high}), "equation-error"
    )
    np.testing.assert_allclose(boxed.values[1:], fixed.values, rtol=1e-5)
    assert boxed.cost == pytest.approx(fixed.cost, rel=1e-9, abs=1e-6)


def test_what_the_regression_cannot_take_is_refused_in_one_line(truth):  # noqa: F811
    config, noisy, _ = truth
    biased = replace(config, free=(*FREE, "b_phi"))
    cases = [
        (biased, {}, InputError, r"free lists b_phi; equation-error regresses the dynamics rows"),
        (config, {"window_s": 1.0}, OptionError, r"window_s"),
    ]
    for cfg, options, error, words in cases:
        with pytest.raises(error, match=words) as e:
            identify([noisy], cfg, "equation-error", options)
        assert "\n" not in str(e.value)
    keep = [k for k, s in enumerate(noisy.measured) if s != "phi"]
    partial = replace(noisy, measured=tuple(noisy.measured[k] for k in keep), y=noisy.y[:, keep])
    with pytest.raises(InputError, match=r"^equation-error: the records do not measure phi.*or ml-gn$"):
        identify([partial], config, "equation-error")
