"""Output biases (`b_u` … `b_z`): y = x + b, known or estimated, shared or per record."""

import numpy as np
import pytest
from references import assert_sensitivities_match_complex_step, qr_cost
from identification.test_offsets import FIN_OFFSET, LATERAL, _lsim, _start, _turns  # noqa: F401  (shared data)

from testbed.errors import InputError
from testbed.estimators import identify
from testbed.identification import concentrated, likelihood
from studies.remus import EXAMPLE_COEFFICIENTS
from testbed.identification.problem import problem
from testbed.models.linear import IX

GYRO = 0.004  # rad/s: a yaw-rate gyro's bias, 1.3× the example's gyro noise
DVL = 0.03  # m/s: a velocity log's sway bias


def _biased(data, biases):
    """`data` with each record's outputs biased by its own `biases` (state → value)."""
    out = []
    for e, b in zip(data, biases):
        y = e.y.copy()
        for state, v in b.items():
            y[:, e.measured.index(state)] += v
        out.append(type(e)(e.name, e.t, e.measured, y, e.inputs))
    return out


BIASES = ({"r": GYRO, "v": DVL}, {"r": -GYRO, "v": DVL})  # the gyro re-zeroed between the records


def test_sensitivities_to_biases_match_complex_step():
    data = _biased(_turns((FIN_OFFSET, -FIN_OFFSET), duration=3.0), BIASES)
    prob = problem(data, _start(LATERAL + ("b_v", "b_r", "N_0"), ("b_r",)))
    p = likelihood.initial_states(prob, prob.start)
    p[prob.free.index("b_v")] = 0.01
    sens = assert_sensitivities_match_complex_step(prob, p)
    # a bias moves its own output by exactly 1 and nothing else
    first = prob.records[0]
    S = sens[0][:, :, list(prob.columns(first)).index(prob.free.index("b_r[turn-0]"))]
    assert np.all(S[:, list(first.measured).index(IX["r"])] == 1.0) and np.count_nonzero(S) == len(S)


def test_the_simplex_cost_with_biases_is_the_qr_likelihood():
    data = _biased(_turns((FIN_OFFSET, -FIN_OFFSET), duration=10.0), BIASES)
    prob = problem(data, _start(LATERAL + ("b_v", "b_r"), ("b_r",)))
    values = prob.start.copy()
    values[prob.free.index("b_v")], values[prob.free.index("b_r[turn-1]")] = 0.02, -0.003
    R = np.full(len(prob.channels), 1e-4)
    qr = qr_cost(prob, values, R)
    assert concentrated.Cost(prob)(values, R) == pytest.approx(qr, rel=1e-9)


def test_each_record_s_biases_are_recovered_where_a_model_without_them_is_biased():
    offsets = (FIN_OFFSET, -FIN_OFFSET)
    data = _biased(_turns(offsets), BIASES)
    truth = EXAMPLE_COEFFICIENTS | {
        f"{n}[turn-{j}]": EXAMPLE_COEFFICIENTS[c] * d0
        for n, c in (("Y_0", "Y_dr"), ("N_0", "N_dr"))
        for j, d0 in enumerate(offsets)
    }
    truth |= {"b_v": DVL, "b_r[turn-0]": GYRO, "b_r[turn-1]": -GYRO}
    per_record = ("Y_0", "N_0", "b_r")
    for method in ("ml-gn", "ml-fem"):  # ml-fem: a filter per record
        est = identify(data, _start(LATERAL + per_record + ("b_v",), per_record), method=method)
        assert est.converged, (method, est.message)
        sigmas = {n: (v - truth[n]) / s for n, v, s in zip(est.free, est.values, est.std)}
        assert max(abs(v) for v in sigmas.values()) < 3.0, (method, sigmas)
    plain = identify(data, _start(LATERAL + ("Y_0", "N_0"), ("Y_0", "N_0")), method="ml-gn")
    worst = max(abs(v - truth[n]) / s for n, v, s in zip(plain.free, plain.values, plain.std))
    assert worst > 5.0  # the same data with the biases left out of the model


def test_a_bias_the_config_gives_is_taken_off_the_data():
    data = _biased(_turns((FIN_OFFSET, FIN_OFFSET), duration=20.0, noise=False), ({"r": GYRO}, {"r": GYRO}))
    known = _start(LATERAL + ("Y_0", "N_0")).with_coefficients({"b_r": GYRO})
    truth = EXAMPLE_COEFFICIENTS | {"Y_0": EXAMPLE_COEFFICIENTS["Y_dr"] * FIN_OFFSET}
    truth["N_0"] = EXAMPLE_COEFFICIENTS["N_dr"] * FIN_OFFSET
    for method in ("ml-gn", "equation-error"):
        est = identify(data, known, method=method)
        np.testing.assert_allclose(est.values, [truth[n] for n in est.free], rtol=0.02, err_msg=method)


def test_the_kalman_filters_refuse_a_free_bias_ml_fem_fits_it_and_the_screen_fixes_a_heading_bias():
    from testbed.analysis.screening import screening

    data = _biased(_turns((FIN_OFFSET, -FIN_OFFSET), duration=20.0), BIASES)
    for method in ("mekf", "ekf"):
        with pytest.raises(InputError, match=r"free lists b_r; .* expected them fixed") as exc:
            identify(data, _start(LATERAL + ("b_r",)), method=method)
        assert "\n" not in str(exc.value)
    # one gyro bias and one fin offset over both records: ml-fem fits them with the coefficients
    data = _biased(_turns((FIN_OFFSET, FIN_OFFSET)), ({"r": GYRO}, {"r": GYRO}))
    truth = EXAMPLE_COEFFICIENTS | {"b_r": GYRO}
    truth |= {
        "Y_0": EXAMPLE_COEFFICIENTS["Y_dr"] * FIN_OFFSET,
        "N_0": EXAMPLE_COEFFICIENTS["N_dr"] * FIN_OFFSET,
    }
    est = identify(data, _start(LATERAL + ("Y_0", "N_0", "b_r")), method="ml-fem")
    assert est.converged, est.message
    sigmas = {n: (v - truth[n]) / s for n, v, s in zip(est.free, est.values, est.std)}
    assert max(abs(v) for v in sigmas.values()) < 3.0, sigmas
    s = screening(data, _start(LATERAL + ("b_psi",)))
    assert "b_psi" in s.fixed and "singular" in s.fixed["b_psi"]  # the same as another initial heading


def test_the_coloured_residual_bound_is_not_shrunk_by_missing_samples():
    """White residuals (the right model): the coloured bound is about the white one, with or
    without half the samples missing (each lag's sum over the pairs there are)."""
    from dataclasses import replace

    data = _turns((FIN_OFFSET, -FIN_OFFSET), duration=20.0)
    config = _start(LATERAL + ("Y_0", "N_0"), ("Y_0", "N_0"))
    ratios = []
    for drop in (0.0, 0.5):
        rng = np.random.default_rng(4)
        gappy = []
        for e in data:
            y = e.y.copy()
            y[rng.random(y.shape) < drop] = np.nan
            gappy.append(replace(e, y=y))
        est = identify(gappy, config, method="ml-gn")
        ratios.append(np.median(est.crlb_corrected_std / est.std))
    assert abs(ratios[1] - ratios[0]) < 0.1, ratios


def test_a_velocity_bias_and_the_offsets_that_hold_that_velocity_trade_exactly():
    """Y_0 and N_0 can hold a steady sway with no yaw rate; from an initial state at that sway it
    reads as b_v: with all three free the Fisher information is singular along that direction,
    with two of them it is not."""
    from testbed.analysis.identifiability import identifiability

    data = _biased(_turns((FIN_OFFSET, -FIN_OFFSET), duration=20.0), BIASES)
    all_three = identifiability(data, _start(LATERAL + ("Y_0", "N_0", "b_v")))
    assert not np.isfinite(all_three.crlb_std[-3:]).any()
    two = identifiability(data, _start(LATERAL + ("Y_0", "N_0")))
    assert np.isfinite(two.crlb_std).all()


def test_the_simplex_cost_with_given_biases_current_and_delay_is_the_qr_likelihood():
    data = _biased(_turns((FIN_OFFSET, -FIN_OFFSET), duration=10.0), BIASES)
    given = {"b_r": 0.002, "b_v": 0.01, "c_N": 0.05, "input_delay": 0.03}
    prob = problem(data, _start(LATERAL).with_coefficients(given))
    R = np.full(len(prob.channels), 1e-4)
    assert concentrated.Cost(prob)(prob.start, R) == pytest.approx(qr_cost(prob, prob.start, R), rel=1e-9)
