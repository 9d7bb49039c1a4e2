"""Bounds on a nonlinear model config's free coefficients (`[identify] bounds`, and the physical
sides `regressors.physical_bounds` on by default): the config reads and writes them and refuses
what cannot be one; `ml-gn`, `ml-lm` and `ml-nm` keep every coefficient in its box, and where a bound holds one the
fit is the fit of the others with it fixed there (the bound's KKT point), its σ NaN, the bound
named; the methods that keep none refuse them."""

from __future__ import annotations

import math
import re
import tomllib
from dataclasses import replace

import numpy as np
import pytest
from analysis.test_nonlinear_identifiability import DETERMINED, truth  # noqa: F401  (the fixture: a doublet the captive model flew)

from testbed.data import config_text, parse_config
from testbed.errors import InputError
from testbed.estimators import METHODS, identify
from testbed.models.regressors import physical_bounds

KEEPERS = [
    "ml-gn",
    "ml-lm",
    "ml-nm",
    "ml-nr",
]  # the methods that keep bounds: every test of a box runs against each
# on the nonlinear model, ml-nm flies the records at every corner of its simplex: 20-25 s a test
NONLINEAR_KEEPERS = ["ml-gn", "ml-lm", pytest.param("ml-nm", marks=pytest.mark.slow)]
# how near its optimum each method's stopping rule leaves a fit, in Cramér-Rao σ: the Gauss-Newton
# step under `tol` = 1e-3 σ; the simplex's spread of N·J_M under `eps` = 1e-3, its corners within
# about √(2·1e-3) ≈ 0.045 σ of the minimum and its cost within 1e-3
STOPS = {"ml-gn": 1e-3, "ml-lm": 1e-3, "ml-nr": 1e-3, "ml-nm": 0.05}


def test_the_physical_sides_are_the_components_drags():
    assert physical_bounds("blunt@hull") == (0.0, math.inf)
    assert physical_bounds("slender@elevator_left") == (0.0, math.inf)
    assert physical_bounds("angular@rudder_upper") == (0.0, math.inf)
    for free in ("lift@rudder_upper", "munk@elevator_left", "N_r|r|", "Y_v|v|", "N_v|v|", "Y_uv", "X_uu"):
        assert physical_bounds(free) == (-math.inf, math.inf), free


def test_no_physical_side_contradicts_the_bundled_torpedos_captive_values():
    """The defaults a user's fit keeps are physics', so the plant's own captive fit (both models)
    lies inside them: a polynomial term's sign is shared with the other terms of its row (this
    fit's Y_v|v|, Z_w|w|, M_q|q| and N_r|r| are positive)."""
    from testbed.captive.config import captive_config

    for model in ("polynomial", "components"):
        terms = captive_config(model=model)[0].terms
        outside = {n: v for n, v in terms.items() if not physical_bounds(n)[0] <= v <= physical_bounds(n)[1]}
        assert outside == {}, (model, outside)


def test_the_config_reads_writes_and_checks_its_bounds(truth):  # noqa: F811
    config, _ = truth
    boxed = replace(config, free=DETERMINED, bounds={"Y_uv": (-math.inf, 0.0)}, physical_bounds=False)
    back = parse_config(tomllib.loads(config_text(boxed)), "back")
    assert back.bounds == {"Y_uv": (-math.inf, 0.0)} and back.physical_bounds is False
    low, high = replace(config, free=("Y_v|v|", "Y_uv"), bounds={"Y_v|v|": (-math.inf, 0.0)}).box(
        ("Y_v|v|", "Y_uv")
    )
    assert list(low) == [-math.inf, -math.inf] and list(high) == [0.0, math.inf]
    text = config_text(replace(config, free=DETERMINED))
    for bad, words in (
        ('bounds = {"Y_uv" = [1.0, 1.0]}', "low < high"),
        ('bounds = {"Y_uv" = [0.0]}', "expected [low, high]"),
        ('bounds = {"X_uu" = [-1e9, 1e9]}', "not a free name"),
        ('bounds = {"Y_uv" = [0.0, 1.0]}', "lies outside"),
        ("bound = {}", "unknown key 'bound'"),
        ("physical_bounds = 1", "expected true or false"),
    ):
        doc = tomllib.loads(text.replace("[identify]\n", f"[identify]\n{bad}\n"))
        with pytest.raises(InputError, match=re.escape(words)) as exc:
            parse_config(doc, "c.toml")
        assert "\n" not in str(exc.value) and "c.toml: [identify]" in str(exc.value)


@pytest.mark.parametrize("method", NONLINEAR_KEEPERS)
def test_a_bound_that_holds_gives_the_fit_of_the_others_with_it_fixed_there(truth, method):  # noqa: F811
    """`Y_uv` bounded below its value in the data: the fit ends on the bound, and the other
    coefficients are where the fit with `Y_uv` fixed at the bound puts them."""
    config, record = truth
    start = replace(config, free=DETERMINED, screen=False)
    free = identify([record], start, method, start="config")
    high = config.terms["Y_uv"] - 20 * free.std[0]  # far inside the region the data exclude
    boxed = identify(
        [record],
        replace(start, bounds={"Y_uv": (-math.inf, high)}).with_coefficients({"Y_uv": high}),
        method,
        start="config",
    )
    assert boxed.at_bounds == {"Y_uv": pytest.approx(high)} and boxed.converged
    assert boxed.values[0] == pytest.approx(high) and math.isnan(boxed.std[0])
    assert "on its bounds: Y_uv" in boxed.message and boxed.json_fields()["at_bounds"] == {
        "Y_uv": pytest.approx(high)
    }
    fixed = identify(
        [record],
        replace(start, free=DETERMINED[1:]).with_coefficients({"Y_uv": high}),
        method,
        start="config",
    )
    np.testing.assert_allclose(boxed.values[1:], fixed.values, rtol=0, atol=STOPS[method] * np.max(fixed.std))
    np.testing.assert_allclose(boxed.std[1:], fixed.std, rtol=max(STOPS[method], 1e-3))
    assert boxed.cost >= free.cost - 1e-9 and boxed.cost == pytest.approx(
        fixed.cost, abs=1e-6 if method != "ml-nm" else 1e-3
    )


@pytest.mark.parametrize("method", NONLINEAR_KEEPERS)
def test_a_start_on_the_wrong_side_of_a_bound_ends_on_its_side(truth, method):  # noqa: F811
    """A term bounded to ≤ 0 and started at 50 is moved onto its side, 0, and stays there or
    inside; unbounded, it ends where the data put it (69 in the captive model that flew them)."""
    config, record = truth
    start = replace(config, free=(*DETERMINED, "Y_v|v|"), screen=False).with_coefficients({"Y_v|v|": 50.0})
    est = identify([record], replace(start, bounds={"Y_v|v|": (-math.inf, 0.0)}), method, start="config")
    assert est.values[-1] <= 0.0
    free = identify([record], start, method, start="config")
    assert abs(free.values[-1] - config.terms["Y_v|v|"]) <= 3 * free.std[-1] and free.values[-1] > 0


@pytest.mark.parametrize("method", ["mekf", "ekf"])
def test_a_method_that_keeps_no_bounds_refuses_them(truth, method):  # noqa: F811
    config, record = truth
    boxed = replace(config, free=DETERMINED, screen=False, bounds={"Y_uv": (-math.inf, math.inf)})
    with pytest.raises(InputError, match=f"{method} does not keep bounds"):
        identify([record], boxed, method)


@pytest.mark.parametrize("method", ["mekf", "ekf"])
def test_a_linear_method_that_keeps_no_bounds_refuses_them(method):
    from estimators.test_trust_region import VERTICAL
    from studies.remus import example_config, experiments

    config = example_config(VERTICAL)
    boxed = replace(config, bounds={config.free[0]: (-math.inf, math.inf)})
    with pytest.raises(
        InputError,
        match=f"{method} does not keep bounds; expected ml-gn, ml-lm, ml-nr, ml-nm, ml-fem, equation-error, or no",
    ) as exc:
        identify(experiments(seed=2, duration=20.0)[1:], boxed, method)
    assert "\n" not in str(exc.value)


@pytest.mark.parametrize("method", [*KEEPERS, "equation-error", "ml-fem"])
def test_a_linear_fit_on_its_bound_is_the_fit_of_the_others_with_it_fixed_there(method):
    """The linear model's methods that keep `[identify] bounds`: a coefficient bounded 20 σ short
    of its estimate ends on the bound, its σ NaN, and the others where the fit with it fixed
    there puts them (equation error: its rows' bounded least squares, whose solution with the
    bound active is the one with the coefficient fixed there)."""
    from estimators.test_trust_region import VERTICAL
    from studies.remus import example_config, experiments

    data = experiments(seed=2, duration=20.0)[1:]
    config = example_config(VERTICAL)
    start = {"start": "config"} if METHODS[method].starts else {}
    free = identify(data, config, method, **start)
    name, value, std = config.free[0], free.values[0], free.std[0]
    bound = value - 20 * std * np.sign(value)  # toward 0: the box (bound, ∞) or (−∞, bound) excludes it
    box = (bound, math.inf) if bound > value else (-math.inf, bound)
    boxed = identify(
        data, replace(config, bounds={name: box}).with_coefficients({name: bound}), method, **start
    )
    assert boxed.at_bounds == {name: pytest.approx(bound)} and boxed.converged
    assert math.isnan(boxed.std[0]) and f"on its bounds: {name}" in boxed.message
    fixed = identify(
        data, replace(config, free=config.free[1:]).with_coefficients({name: bound}), method, **start
    )
    np.testing.assert_allclose(boxed.values[1:], fixed.values, rtol=0, atol=1e-2 * np.max(fixed.std))
    np.testing.assert_allclose(boxed.std[1:], fixed.std, rtol=1e-2)


@pytest.mark.slow  # Scenario I flown and every component term fitted: about a minute on one core
def test_free_all_on_the_component_model_keeps_every_drag_on_its_side_and_converges(tmp_path):
    """The plant's Scenario I (fins logged at 100 Hz), `testbed captive`'s component config with
    every term free (`--free-all`: near-copies the data cannot separate among them): the fit
    converges with every drag ≥ 0 and names the bounds it ends on."""
    from testbed.captive.config import captive_config
    from testbed.data import load_data
    from testbed.simulation.runs import simulate
    from testbed.simulation.scenario import scenario

    s = scenario("I")
    simulate(replace(s, sensors=replace(s.sensors, fin_rate=100.0)), seed=1, out=tmp_path / "I")
    experiments, _ = load_data([tmp_path / "I"])
    config = replace(captive_config(speed=20.0)[0], screen=False)
    est = identify(experiments, config, "ml-gn")
    assert est.converged, est.message
    drags = {n: v for n, v in zip(est.free, est.values) if n.split("@")[0] in ("blunt", "slender", "angular")}
    assert drags and min(drags.values()) >= 0.0
    assert est.at_bounds and all(drags[n] == 0.0 for n in est.at_bounds if n in drags)
    assert "on its bounds" in est.message


def test_a_simplex_stopped_by_its_limit_on_a_bound_reports_the_others_bounds():
    """`ml-nm` cut short by `max_iter` on a bound (an outcome that carries no information
    matrix) reports the others' σ from the estimate's information, that one's null: the bound at
    the a-priori value, on the side the data pull the coefficient to."""
    from estimators.test_trust_region import VERTICAL
    from studies.remus import example_config, experiments

    data = experiments(seed=2, duration=20.0)[1:]
    config = example_config(VERTICAL)
    name, prior = config.free[0], config.values[config.free[0]]
    pulled = identify(data, config, "ml-gn", start="config").values[0]
    box = (-math.inf, prior) if pulled > prior else (prior, math.inf)
    est = identify(data, replace(config, bounds={name: box}), "ml-nm", start="config", max_iter=30)
    assert est.status.name == "MAX_ITERATIONS" and est.at_bounds == {name: prior}
    assert math.isnan(est.std[0]) and np.all(np.isfinite(est.std[1:]))
