"""The MEKF and the conventional EKF on a nonlinear model config: on the short record the captive
model flew (with the sensors' noise) from a start 20 % off, against the truth and the Cramér-Rao
bounds of the exact-sensitivity Fisher information; the per-sample transition's Jacobians against
complex steps of one RK4 interval of the compiled flight; the options it refuses; the command line."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from testbed.analysis.nonlinear_identifiability import nonlinear_identifiability
from testbed.errors import InputError
from testbed.estimators import FilterEstimate, OptionError, identify
from testbed.identification.nonlinear_transition import NonlinearTransition
from testbed.identification.problem import shifted
from testbed.models.linear import IX, STATES
from testbed.models.nonlinear_flight import fly_nonlinear

import estimators.test_nonlinear as shared
from estimators.test_nonlinear import FREE, SIGMA, _ok, _start

truth, files = shared.truth, shared.files  # the shared record and its files (fixtures)


@pytest.fixture(scope="module")
def bounds(truth):
    """The Cramér-Rao σ of FREE at the truth on the noise-free record, noise at the sensors' σ."""
    config, _, clean = truth
    return nonlinear_identifiability([clean], replace(config, noise_std=dict(zip(STATES, SIGMA)))).crlb_std


@pytest.mark.parametrize("method, name", [("mekf", "square-root MEKF"), ("ekf", "conventional EKF")])
def test_the_filters_converge_to_the_truth_with_the_cramer_rao_sigma(truth, bounds, method, name):
    config, noisy, _ = truth
    start = _start(config)
    steps = []
    est = identify([noisy], start, method, callback=steps.append)
    assert isinstance(est, FilterEstimate) and est.converged and est.filter == name and est.free == FREE
    assert est.iterations == len(noisy.t) == len(steps) and est.history.shape == (len(noisy.t), len(FREE))
    assert np.array_equal(est.history[-1], est.values) and np.allclose(
        est.history_std[-1], est.std, rtol=1e-10
    )
    truth_values = np.array([config.terms[n] for n in FREE])
    start_values = np.array([start.terms[n] for n in FREE])
    assert np.all(np.abs(est.values - truth_values) <= 3 * est.std), (est.values, truth_values, est.std)
    # the start was hundreds of σ off; the σ reached is the bound's (the filter's own model error
    # allowance, matched to the innovations, widens it a little)
    assert np.all(np.abs(start_values - truth_values) > 50 * est.std)
    assert np.all((est.std / bounds > 0.8) & (est.std / bounds < 1.4)), est.std / bounds
    # consistent innovations: about one per measured channel and sample
    assert 0.8 < est.nis_mean < 1.2


def test_the_transition_jacobians_are_complex_steps_of_one_rk4_interval(truth):
    """At a sample inside the rudder doublet, off trim in every state, with the free terms off
    the truth: Φ = ∂x⁺/∂x and D = ∂x⁺/∂θ[free] of one RK4 interval of the compiled flight, and
    the states it predicts (u as the perturbation from the vehicle's speed)."""
    config, noisy, _ = truth
    model, theta = _start(config).nonlinear()
    idx = [model.names.index(n) for n in FREE]
    step = NonlinearTransition(model, theta, idx)
    step.begin(noisy)
    k, U = 20, config.vehicle.speed
    xk = np.array([-0.4, 0.3, -0.2, 0.05, 0.04, -0.06, 0.1, -0.05, 0.3, 1.0])
    x = xk + 0.01
    Phi, D, xk1, x1 = step.step(k, theta[idx], None, xk, x)
    t, fins = noisy.t[k : k + 2], noisy.inputs[k : k + 2]
    trim = np.eye(10)[IX["u"]] * U
    h = 1e-30
    want_phi = np.column_stack(
        [
            fly_nonlinear(model, theta.astype(complex), t, xk + trim + 1j * h * e, fins)[1].imag / h
            for e in np.eye(10)
        ]
    )
    want_d = np.column_stack(
        [
            fly_nonlinear(model, theta + 1j * h * np.eye(len(theta))[i], t, xk + trim, fins)[1].imag / h
            for i in idx
        ]
    )
    assert np.allclose(Phi, want_phi, rtol=1e-10, atol=1e-13)
    assert np.allclose(D, want_d, rtol=1e-10, atol=1e-13 * np.abs(want_d).max())
    assert np.allclose(xk1, fly_nonlinear(model, theta, t, xk + trim, fins)[1] - trim, rtol=1e-14, atol=1e-14)
    assert np.allclose(x1, fly_nonlinear(model, theta, t, x + trim, fins)[1] - trim, rtol=1e-14, atol=1e-14)
    assert step.step(k, theta[idx], None, xk)[3] is None
    assert abs(noisy.inputs[k, 0]) > 0 and np.abs(Phi - np.eye(10)).max() > 1e-3  # a real interval


def test_what_the_filters_honour_and_refuse_on_a_nonlinear_config(truth):
    config, noisy, _ = truth
    for options in ({"passes": 2}, {"pass_tol": 0.5}, {"refresh_tol": 0.0}):
        with pytest.raises(OptionError) as e:
            identify([noisy], config, "mekf", options)
        assert e.value.option == next(iter(options)) and "\n" not in str(e.value)
    est = identify([noisy], _start(config), "ekf", max_samples=50, noise_std={"u": 0.05})
    assert est.iterations == 50 and est.status.name == "MAX_ITERATIONS" and est.noise_std["u"] == 0.05
    svd = identify([noisy], _start(config), "mekf", sqrt="svd", noise_window=0)
    qr = identify([noisy], _start(config), "mekf", noise_window=0)
    assert svd.sqrt == "svd" and np.allclose(svd.values, qr.values, rtol=1e-8)


def test_mekf_on_the_command_line(files, truth, capsys, tmp_path):
    config = truth[0]
    est = tmp_path / "e.json"
    argv = ["identify", files / "doublets.csv", "--config", files / "start.toml", "--method", "mekf"]
    _ok(capsys, argv + ["--out", est])
    doc = json.loads(est.read_text())
    assert doc["method"] == "mekf" and doc["converged"] and doc["filter"] == "square-root MEKF"
    assert list(doc["coefficients"]) == list(FREE)
    assert doc["nonlinear_model"] == {"config": str(files / "start.toml"), "terms": list(config.terms)}
    for n, c in doc["coefficients"].items():
        assert abs(c["value"] - config.terms[n]) <= 3 * c["std"], n
    # the estimate predicts the record as the config that flew it does, within the noise
    _ok(
        capsys,
        ["validate", files / "doublets.csv", "--config", files / "truth.toml", "--out", tmp_path / "v.json"],
    )
    flown = json.loads((tmp_path / "v.json").read_text())["validation"]["doublets"]
    for s in STATES:
        assert doc["validation"]["doublets"][s]["fit_percent"] == pytest.approx(
            flown[s]["fit_percent"], abs=0.5
        )
    history = est.with_suffix(".history.csv").read_text().splitlines()
    assert history[0] == "t," + ",".join(f"{n},{n}_std" for n in FREE) and len(history) == 202


def test_the_filter_takes_fixed_trial_parameters_off_the_data_and_refuses_free_ones(truth):
    """A record logged with attitude offsets, in a current, or with its fins logged late, and a
    config fixing those at their values: the filter's estimate is the one on the record without
    them. A free one is refused in one line."""
    config, noisy, _ = truth
    start = _start(config)
    late = replace(noisy, inputs=shifted(noisy.inputs, -1.5)[0])  # recorded 1.5 samples late
    on_time = replace(late, inputs=shifted(late.inputs, 1.5)[0])  # the fins a 30 ms delay flies
    for record, fixed, without in (
        (shared._offset(noisy), shared.OFFSETS, noisy),
        (shared._in_current(noisy, noisy), shared.CURRENT, noisy),
        (late, {"input_delay": 1.5 * (noisy.t[1] - noisy.t[0])}, on_time),
    ):
        est, plain = (
            identify([record], start.with_coefficients(fixed), "mekf"),
            identify([without], start, "mekf"),
        )
        assert np.allclose(est.values, plain.values, rtol=1e-6), fixed
        assert np.allclose(est.std, plain.std, rtol=1e-6), fixed
    for name in ("b_phi", "c_N", "input_delay"):
        with pytest.raises(InputError, match=rf"free names {name}; mekf on a nonlinear model config") as e:
            identify([noisy], replace(start, free=FREE + (name,)), "mekf")
        assert "\n" not in str(e.value)
