"""One contract, every method: the same tests run against each registered estimator (as scipy's
`least_squares` tests run one mixin against every solver)."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from testbed.errors import InputError
from testbed.estimators import (
    METHODS,
    Estimate,
    FilterEstimate,
    OptionError,
    Options,
    Progress,
    Status,
    identify,
    lookup,
)
from testbed.identification.prediction import synthetic
from testbed.simulation.measurements import NOISE_STD
from testbed.models.linear import INPUTS
from testbed.simulation.analytic import analytic_config

FREE = ("N_r", "N_dr")  # the yaw row's damping and rudder power: well excited by a rudder PRBS


@pytest.fixture(scope="module")
def problem():
    """Noisy sway-yaw data from the bundled torpedo's own linear model, and a start 20 % off."""
    config, _ = analytic_config()
    config = dataclasses.replace(config, free=FREE)
    rng = np.random.default_rng(7)
    t = np.arange(0.0, 40.0, 0.02)  # 50 Hz, the bundled scenarios' control rate
    inputs = np.zeros((len(t), len(INPUTS)))
    inputs[:, 0] = 0.02 * np.repeat(rng.choice([-1.0, 1.0], size=len(t) // 50 + 1), 50)[: len(t)]  # held 1 s
    # the yaw row involves sway, roll and roll rate too: measured, so that every method can use it
    measured = ("v", "p", "r", "phi", "psi")
    data = [synthetic(config, t, inputs, NOISE_STD, measured=measured, rng=rng, name="rudder")]
    start = config.with_coefficients({n: 0.8 * config.coefficients[n] for n in FREE})
    return data, config, start


@pytest.mark.parametrize("name", sorted(METHODS))
class TestEveryMethod:
    def test_capabilities_match_the_options(self, name):
        m = lookup(name)
        fields = {f.name for f in dataclasses.fields(m.options)}
        assert issubclass(m.options, Options) and m.options.__dataclass_params__.frozen
        assert m.iterative == ("max_iter" in fields) and m.starts == ("start" in fields)
        assert m.online == ("max_samples" in fields) and m.summary
        assert set(m.options.describe()) == fields

    def test_defaults_pass_their_checks_and_unknown_options_are_refused(self, name):
        m = lookup(name)
        m.options.build(name)
        with pytest.raises(OptionError, match=r"option no_such=1; expected one of the options") as info:
            m.options.build(name, {"no_such": 1})
        assert info.value.option == "no_such" and isinstance(info.value, (InputError, ValueError))

    def test_every_option_refuses_a_value_of_the_wrong_type(self, name):
        for f in dataclasses.fields(lookup(name).options):
            with pytest.raises(OptionError) as info:
                lookup(name).options.build(name, {f.name: object()})
            assert info.value.option == f.name and "\n" not in str(info.value)

    def test_fits_and_reports_through_one_contract(self, name, problem):
        data, config, start = problem
        m = lookup(name)
        seen = []
        est = identify(data, start, method=name, callback=seen.append)
        assert isinstance(est, Estimate) and est.method == name and est.free == FREE
        # Every method converges here: two coefficients of one row, both well excited by the
        # rudder PRBS, 20 % off, within its default limits (ml-nr, the slowest, in about 200
        # iterations). A converged fit is within 5 of its σ (or 3 %) of the coefficients that
        # simulated the data.
        assert est.status is Status.CONVERGED and est.converged, est.message
        assert isinstance(est, FilterEstimate) == m.online
        assert est.values.shape == est.std.shape == (len(FREE),) and np.all(est.std > 0)
        simulated = np.array([config.coefficients[n] for n in FREE])
        assert np.all(np.abs(est.values - simulated) <= np.maximum(5 * est.std, 0.03 * np.abs(simulated))), (
            est.values,
            simulated,
            est.std,
        )
        assert seen and all(isinstance(s, Progress) and s.values.shape == (len(FREE),) for s in seen)
        assert seen[-1].iteration == est.iterations
        doc = json.loads(est.to_json())
        assert set(doc["coefficients"]) == set(FREE) and doc["converged"] is est.converged

    def test_an_iteration_or_sample_limit_stops_it_unconverged(self, name, problem):
        data, _, start = problem
        m = lookup(name)
        if not (m.iterative or m.online):  # a direct method has no limit to set: both are refused
            for limit in ("max_iter", "max_samples"):
                with pytest.raises(OptionError, match=f"option {limit}=0"):
                    identify(data, start, method=name, options={limit: 0})
            return
        limit = {"max_iter": 0} if m.iterative else {"max_samples": 5}
        est = identify(data, start, method=name, options=limit)
        assert est.status is Status.MAX_ITERATIONS and not est.converged
        assert est.iterations == (0 if m.iterative else 5)

    def test_options_may_be_an_instance_a_mapping_or_keywords(self, name, problem):
        m = lookup(name)
        # a limit where the method has one, else its first option (a direct method's are > 0)
        key = (
            "max_iter"
            if m.iterative
            else "max_samples"
            if m.online
            else dataclasses.fields(m.options)[0].name
        )
        value = 3
        built = m.options.build(name, {key: value})
        assert m.options.build(name, built) == built == m.options.build(name, **{key: value})
        with pytest.raises(OptionError, match=f"{key}=-1"):
            identify(*problem[::2], method=name, **{key: -1})


@pytest.mark.parametrize("name", sorted(METHODS))
def test_fits_a_record_with_missing_samples(name, problem):
    """Each method takes a record with a tenth of every state's samples missing (NaN) and a
    heading sensor at a fifth of the rate: finite estimates and bounds, within 5 σ (or 5 %) of the
    coefficients that simulated the data."""
    data, config, start = problem
    rng = np.random.default_rng(11)
    e = data[0]
    y = e.y.copy()
    y[rng.random(y.shape) < 0.1] = np.nan
    slow = np.ones(len(y), dtype=bool)
    slow[::5] = False
    y[slow, e.measured.index("psi")] = np.nan
    if name == "ml-fem":  # its periodic steady-state filter needs samples that recur at a fixed period
        with pytest.raises(InputError, match=r"missing samples at no fixed period .* expected each channel"):
            identify([dataclasses.replace(e, y=y)], start, method=name)
        return
    est = identify([dataclasses.replace(e, y=y)], start, method=name)
    assert est.status is Status.CONVERGED, est.message
    assert np.all(np.isfinite(est.values)) and np.all(np.isfinite(est.std)) and np.all(est.std > 0)
    simulated = np.array([config.coefficients[n] for n in FREE])
    assert np.all(np.abs(est.values - simulated) <= np.maximum(5 * est.std, 0.05 * np.abs(simulated))), (
        est.values,
        simulated,
        est.std,
    )


@pytest.mark.parametrize("name", sorted(METHODS))
def test_evaluations_count_the_simulations_of_the_data_set(name, problem, monkeypatch):
    # Estimate.evaluations: simulations of the whole data set, a sensitivity pass counting
    # 1 + n_free. An iterative fit's grow with its iterations; a filter's are its passes times
    # the state and its parameter columns; equation error simulates nothing.
    from testbed.identification import concentrated

    data, _, start = problem
    m = lookup(name)
    if m.online:
        for passes in (1, 3):
            est = identify(data, start, method=name, passes=passes)
            assert est.evaluations == (est.passes or 1) * (1 + len(FREE)), (passes, est.passes)
        assert identify(data, start, method=name, max_samples=5).evaluations == 1  # a share, rounded up
    elif m.iterative:
        calls = []
        call = concentrated.Cost.__call__
        monkeypatch.setattr(concentrated.Cost, "__call__", lambda self, *a: calls.append(1) or call(self, *a))
        few, more = (identify(data, start, method=name, start="config", max_iter=k) for k in (1, 3))
        assert 0 < few.evaluations < more.evaluations, (few.evaluations, more.evaluations)
        if name == "ml-nm":  # its cost evaluations, and the few simulations of its noise updates
            calls.clear()
            full = identify(data, start, method=name, start="config")
            # besides: the start's initial states and cost, and per noise update (20 at most) the
            # initial states and residuals at the best corner
            assert 3 * len(calls) < full.evaluations <= 3 * len(calls) + 2 + 2 * 20, (
                len(calls),
                full.evaluations,
            )
    else:
        assert identify(data, start, method=name).evaluations == 0
    assert json.loads(identify(data, start, method=name).to_json())["evaluations"] >= 0
