"""A nonlinear model config behind `identify`, `validate` and `analyze`: the library's front door
and the command line, on short records the captive model itself flew (with the testbed's sensor
noise), against the truth, finite-difference Fisher information and one-line refusals."""

from __future__ import annotations

import json
import re
from dataclasses import replace

import numpy as np
import pytest

from testbed.analysis.nonlinear_identifiability import forward, nonlinear_identifiability
from testbed.cli import main
from testbed.data import Experiment, read_config, write_config, write_csv
from testbed.errors import InputError, Unflyable
from testbed.estimators import OptionError, identify
from testbed.estimators.nonlinear_fit import fit_output_error
from testbed.estimators.nonlinear_regression import regressed
from testbed.identification.likelihood import reduced
from testbed.identification.nonlinear_output_error import coloured_bounds, flight_information, records, setup
from testbed.identification import nonlinear_output_error, nonlinear_prediction
from testbed.identification.nonlinear_sensitivities import flight
from testbed.identification.problem import shifted
from testbed.identification.recursions import counting
from testbed.jobs.common import perturbed
from testbed.models import log_mounting
from testbed.models.linear import STATES
from testbed.models.nonlinear_flight import fly_nonlinear
from testbed.captive.config import captive_config
from testbed.simulation.measurements import NOISE_STD

FREE = ("Y_uv", "N_uv", "Z_uw", "M_uw")
SIGMA = np.array([NOISE_STD[s] for s in STATES])


def doublet(t, start, half, amplitude):
    return amplitude * (
        ((t >= start) & (t < start + half)) * 1.0 - ((t >= start + half) & (t < start + 2 * half))
    )


@pytest.fixture(scope="module")
def truth():
    """The captive model with FREE free (as written: no screen), and a 4 s record it flew from near straight flight at
    20 m/s (off the |·| terms' kinks at 0) through rudder, elevator and aileron doublets:
    noise-free and with the sensors' noise."""
    config = replace(captive_config(model="polynomial")[0], free=FREE, screen=False)
    model, theta = config.nonlinear()
    t = np.arange(201) * 0.02
    a = np.radians(3.0)
    fins = np.column_stack(
        [doublet(t, 0.2, 0.8, a), doublet(t, 1.5, 0.8, a), doublet(t, 3.0, 0.4, np.radians(0.3))]
    )
    x0 = np.array([config.vehicle.speed, 0.1, -0.1, 0.01, 0.02, -0.01, 0.02, -0.01, 0.3, 1.0])
    x = fly_nonlinear(model, theta, t, x0, fins)
    noisy = x + np.random.default_rng(1).normal(size=x.shape) * SIGMA
    return config, Experiment("doublets", t, STATES, noisy, fins), Experiment("clean", t, STATES, x, fins)


def _start(config):
    """The config with the free terms moved 20 % off (signs mixed): a start that is not the truth."""
    return config.with_coefficients(
        {n: config.terms[n] * (1.2 if k % 2 else 0.8) for k, n in enumerate(FREE)}
    )


@pytest.fixture(scope="module")
def files(truth, tmp_path_factory):
    config, noisy, clean = truth
    root = tmp_path_factory.mktemp("nl")
    write_csv(root / "doublets.csv", noisy.t, noisy.y, noisy.inputs)
    write_csv(root / "clean.csv", clean.t, clean.y, clean.inputs)
    write_config(root / "truth.toml", config)
    write_config(root / "start.toml", _start(config))
    return root


def test_ml_gn_returns_the_truth_within_three_sigma_from_a_perturbed_start(truth):
    config, noisy, _ = truth
    steps = []
    est = identify([noisy], _start(config), "ml-gn", callback=steps.append, start="config")
    assert est.converged and est.method == "ml-gn" and est.free == FREE
    for n, v, s in zip(est.free, est.values, est.std):
        assert abs(v - config.terms[n]) <= 3 * s, (n, v, config.terms[n], s)
    # the noise estimated is the noise added (201 samples: its σ to ~10 %)
    assert np.allclose([est.noise_std[s] for s in STATES], SIGMA, rtol=0.25)
    assert set(est.initial_states) == {"doublets"} and set(est.initial_states["doublets"]) == set(STATES)
    assert [p.iteration for p in steps] == list(range(1, len(steps) + 1)) and len(steps) >= 2
    assert est.history.shape == (len(steps) + 1, len(FREE))
    assert np.array_equal(est.history[-1], est.values)
    assert steps[-1].cost == pytest.approx(est.cost)
    # white residuals: the coloured-residual bound near the plain one, within the lag-window
    # estimate's sampling error on one 201-sample record, about √(K/N) for K ≥ 10 lags (≥ 0.22)
    assert np.all(np.abs(est.crlb_corrected_std / est.std - 1) < 0.35), est.crlb_corrected_std / est.std


def test_the_coloured_residual_bound_follows_the_sandwich_covariance_of_ar1_noise(truth):
    """AR(1) sensor noise (ρ = 0.8, the sensors' σ): the estimate's covariance is the sandwich
    C Jᵀ Σ⁻¹ T Σ⁻¹ J C, T(i, j) = ρ^|i−j| per channel, C the white bound, J the sensitivities at
    the truth (free terms and initial state); the coloured bound read off the residuals of one
    record follows its ratio to the plain bound."""
    config, _, clean = truth
    rng = np.random.default_rng(5)
    rho, n = 0.8, len(clean.t)
    w = rng.normal(size=(n, 10)) * SIGMA * np.sqrt(1 - rho**2)
    noise = np.zeros_like(w)
    noise[0] = rng.normal(size=10) * SIGMA
    for k in range(1, n):
        noise[k] = rho * noise[k - 1] + w[k]
    est = identify([replace(clean, y=clean.y + noise)], _start(config), "ml-gn")
    assert est.converged
    model, theta = config.nonlinear()
    f = flight(model, theta, clean.t, clean.y[0], clean.inputs, [model.names.index(m) for m in FREE])
    J = np.concatenate([f.dx_dtheta, f.dx_dx0], axis=2)  # (n, 10, 14)
    W = J / SIGMA[:, None] ** 2
    C = np.linalg.inv(np.einsum("nci,ncj->ij", W, J))
    T = rho ** np.abs(np.subtract.outer(np.arange(n), np.arange(n)))
    middle = np.einsum("nci,nm,mcj,c->ij", W, T, W, SIGMA**2)
    sandwich = np.sqrt(np.diag(C @ middle @ C)[: len(FREE)])
    white = np.sqrt(np.diag(C)[: len(FREE)])
    want, got = sandwich / white, est.crlb_corrected_std / est.std
    assert np.all(want > 1.5), want
    # one record's lag-window estimate: its sampling error about √(K/N), K the lags kept
    assert np.all(np.abs(got / want - 1) < 0.35), (got, want)


def test_evaluations_count_the_flights_and_sensitivity_passes(truth):
    """One iteration: the start's flight (1), a sensitivity pass (1 + n_free), the trial
    flights of the trust-region step (at least one) and the sensitivity pass at the point it
    stops, which judges its convergence (1 + n_free)."""
    config, noisy, _ = truth
    est = identify([noisy], _start(config), "ml-gn", max_iter=1, start="config")
    assert est.iterations == 1 and 4 + 2 * len(FREE) <= est.evaluations <= 4 + 2 * len(FREE) + 4


def test_the_options_the_nonlinear_fit_cannot_honour_are_refused(truth):
    config, noisy, _ = truth
    for options, name in (({"start": "mekf"}, "start"), ({"max_iter": 0}, "max_iter")):
        with pytest.raises(OptionError) as e:
            identify([noisy], config, "ml-gn", options)
        assert e.value.option == name and "\n" not in str(e.value)
    # the limit holds per start, as the linear model's; the estimate counts every start's
    limited = identify([noisy], _start(config), "ml-gn", max_iter=1)
    assert [s["iterations"] for s in limited.starts] == [1, 1] and limited.iterations == 2
    assert not limited.converged


@pytest.mark.parametrize("method", ["ml-nr", "ml-fem"])
def test_the_linear_methods_refuse_a_nonlinear_config(truth, method):
    config, noisy, _ = truth
    with pytest.raises(
        InputError,
        match=rf"method='{method}' fits the linear model only.*ml-gn, ml-lm, ml-nm, mekf, ekf, equation-error for \[terms\]",
    ) as e:
        identify([noisy], config, method)
    assert "\n" not in str(e.value)


def _first(experiment, n):
    return replace(experiment, t=experiment.t[:n], y=experiment.y[:n], inputs=experiment.inputs[:n])


def test_ml_nm_reports_through_the_contract_and_refuses_what_it_cannot_honour(truth):
    config, noisy, _ = truth
    start = replace(_start(config), free=FREE[:2])
    steps = []
    est = identify([_first(noisy, 40)], start, "ml-nm", max_iter=3, callback=steps.append)
    assert est.method == "ml-nm" and est.status.name == "MAX_ITERATIONS" and est.iterations == 3
    assert [p.iteration for p in steps] == [1, 2, 3] and est.history.shape == (4, 2)
    assert np.all(np.isfinite(est.std)) and np.all(est.std > 0) and est.evaluations > 3
    assert set(est.initial_states["doublets"]) == set(STATES)
    refused = (({"restarts": False}, "restarts"), ({"first_length": 1.0}, "first_length"))
    for options, name in refused:
        with pytest.raises(OptionError) as e:
            identify([noisy], start, "ml-nm", options)
        assert e.value.option == name


@pytest.mark.slow
@pytest.mark.parametrize("coordinates", ["information", "scaled"])
def test_ml_nm_ends_at_ml_gns_optimum(truth, coordinates):
    """The simplex on the same likelihood, one free term, the first second of the record, in
    either coordinates (about 2 minutes: every cost evaluation is a flight)."""
    config, noisy, _ = truth
    start = replace(config.with_coefficients({"Y_uv": 0.8 * config.terms["Y_uv"]}), free=("Y_uv",))
    data = [_first(noisy, 50)]
    nm, gn = identify(data, start, "ml-nm", coordinates=coordinates), identify(data, start, "ml-gn")
    assert nm.converged and gn.converged
    assert abs(nm.values[0] - gn.values[0]) <= 0.05 * gn.std[0], (nm.values, gn.values, gn.std)
    assert nm.std[0] == pytest.approx(gn.std[0], rel=0.01) and nm.cost == pytest.approx(gn.cost, abs=0.01)
    assert abs(nm.values[0] - config.terms["Y_uv"]) <= 3 * nm.std[0]


def test_records_the_fit_cannot_take_are_refused(truth):
    config, noisy, _ = truth
    fewer = noisy.only(STATES[:6])
    with pytest.raises(InputError, match="takes records measuring the same states") as e:
        identify([noisy, replace(fewer, name="other")], config, "ml-gn")
    assert "\n" not in str(e.value)
    with pytest.raises(InputError, match="per_record"):
        identify([noisy], replace(config, per_record=("Y_uv",)), "ml-gn")


def _halved(record):
    """`record` on a grid twice as fine: every row's fins held over both of its halves, the states
    at the new rows missing."""
    n = len(record.t)
    t = np.arange(2 * n - 1) * record.dt / 2
    y = np.full((len(t), record.y.shape[1]), np.nan)
    y[::2] = record.y
    return replace(record, t=t, y=y, inputs=np.repeat(record.inputs, 2, axis=0)[:-1])


def test_rows_without_states_are_left_out_of_every_sum(truth):
    """The record with a row of fins and no states inserted in every interval (the fins held as
    before), flown with half the RK4 steps per row (the same steps), fits as the record itself:
    the same estimates, bounds, coloured bounds, noise, likelihood and Fisher information; through
    the front door (5 ms steps at any rate) `ml-gn` and `ml-nm` take the same steps."""
    config, noisy, _ = truth
    model, start = _start(config).nonlinear()
    (channels, whole), (_, halved) = records([noisy]), records([_halved(noisy)])
    fits = [
        fit_output_error(model, start, r, channels, FREE, substeps=n, tolerance=1e-6)
        for r, n in ((whole, 4), (halved, 2))
    ]
    a, b = fits
    for n in FREE:
        assert abs(b.estimates[n] - a.estimates[n]) < 1e-6 * a.std[n], n
        assert b.std[n] == pytest.approx(a.std[n], rel=1e-6)
    assert b.cost == pytest.approx(a.cost, abs=1e-6)
    for c in channels:
        assert b.noise_std[c] == pytest.approx(a.noise_std[c], rel=1e-8)
    R = np.array([a.noise_std[c] ** 2 for c in channels])
    got = [
        coloured_bounds(model, a.theta, f.initial_states, r, channels, FREE, R, n)
        for f, r, n in ((a, whole, 4), (b, halved, 2))
    ]
    np.testing.assert_allclose(got[1][0], got[0][0], rtol=1e-6)
    np.testing.assert_allclose(got[1][1], got[0][1], rtol=1e-6)
    H = [
        flight_information(model, a.theta, a.initial_states, r, channels, FREE, R, n)[0]
        for r, n in ((whole, 4), (halved, 2))
    ]
    np.testing.assert_allclose(H[1], H[0], rtol=1e-8)
    for method, options in (("ml-gn", {}), ("ml-nm", {"max_iter": 60})):  # the front door, 5 ms steps both
        a, b = (
            identify([r], _start(config), method, start="config", **options) for r in (noisy, _halved(noisy))
        )
        assert b.iterations == a.iterations and np.all(np.abs(b.values - a.values) < 1e-9 * a.std), method
        np.testing.assert_allclose(b.std, a.std, rtol=1e-9)
        assert b.cost == pytest.approx(a.cost, abs=1e-8)


def test_a_log_on_its_logger_s_millisecond_clock_fits_as_flown_through_every_tick(truth, monkeypatch):
    """The captive model flown on a 1 ms grid through the doublets as a 50 Hz logger samples
    them (each held until the next stamp, the stamps 20 ms ± 4 ms apart), its states read at the
    stamps with the sensors' noise and missing at the other ticks: `ml-gn` from 20 % off flies
    only from stamp to stamp (5 ms RK4 steps) and ends within 3 σ of the model that flew, and
    within 0.1 σ of the same fit flown through every tick in 1 ms steps; `analyze`'s Fisher
    information and the prediction `validate` scores are those flown through every tick, to
    RK4's error."""
    config = truth[0]
    model, theta = config.nonlinear()
    rng = np.random.default_rng(3)
    stamps = np.cumsum(np.r_[0, rng.integers(16, 25, size=250)])
    stamps = stamps[stamps <= 4000]
    t = np.arange(stamps[-1] + 1) * 0.001
    a = np.radians(3.0)
    s = t[stamps]
    logged = np.column_stack(
        [doublet(s, 0.2, 0.8, a), doublet(s, 1.5, 0.8, a), doublet(s, 3.0, 0.4, np.radians(0.3))]
    )
    fins = logged[np.searchsorted(stamps, np.arange(len(t)), side="right") - 1]
    x0 = np.array([config.vehicle.speed, 0.1, -0.1, 0.01, 0.02, -0.01, 0.02, -0.01, 0.3, 1.0])
    states = fly_nonlinear(model, theta, t, x0, fins, substeps=4)
    y = np.full_like(states, np.nan)
    y[stamps] = states[stamps] + rng.normal(size=(len(stamps), 10)) * SIGMA
    log = Experiment("millisecond-clock", t, STATES, y, fins)
    with counting() as tally:
        est = identify([log], _start(config), "ml-gn", start="config")
    assert est.converged
    assert tally[0] <= est.evaluations * len(stamps)  # samples simulated: a flight's are the stamps
    for n, v, s in zip(est.free, est.values, est.std):
        assert abs(v - config.terms[n]) <= 3 * s, (n, v, config.terms[n], s)
    model, start = _start(config).nonlinear()
    channels, ticks = records([log])
    every = fit_output_error(model, start, ticks, channels, FREE, substeps=1, tolerance=1e-6)
    for n, v, s in zip(est.free, est.values, est.std):
        assert abs(v - every.estimates[n]) <= 0.1 * s, (n, v, every.estimates[n], s)
    stamped = nonlinear_identifiability([log], config).fisher
    predicted = nonlinear_prediction.predict_nonlinear([log], config)[0]
    for module in (nonlinear_output_error, nonlinear_prediction):  # every tick flown
        monkeypatch.setattr(module, "flown_rows", lambda t, y, fins: np.arange(len(t)))
    ticked = nonlinear_identifiability([log], config).fisher
    # the prediction at every tick, its initial state fitted to 0.01 σ (`nonlinear_prediction`)
    every = nonlinear_prediction.predict_nonlinear([log], config)[0]
    assert predicted.shape == every.shape == (len(t), 10)
    assert np.all(np.abs(predicted - every) <= 0.01 * SIGMA)
    scale = np.sqrt(np.outer(np.diag(ticked), np.diag(ticked)))  # each entry's: 0.1 % of it
    assert np.all(np.abs(stamped - ticked) <= 1e-3 * scale)


def _regressed(config, clean, noisy):
    """The equation-error start from 20 % off, on the noise-free record within 1 % of `config`'s
    terms, on the noisy one within 5 % (a quarter of the start's error)."""
    for record, within in ((clean, 0.01), (noisy, 0.05)):
        channels, recs, model, start, _ = setup([record], _start(config), "the test")
        theta = regressed(model, start, recs, channels, FREE)[0]
        for n in FREE:
            assert abs(theta[model.names.index(n)] / config.terms[n] - 1) < within, (record.name, n)


@pytest.fixture(scope="module")
def fine(truth):
    """The captive model flown on a 10 ms grid by doublets that switch mid-interval of the 20 ms
    one, its states read every 20 ms (missing in between), noise-free and with the sensors'
    noise."""
    config = truth[0]
    model, theta = config.nonlinear()
    t = np.arange(401) * 0.01
    a = np.radians(3.0)
    fins = np.column_stack(
        [doublet(t, 0.21, 0.79, a), doublet(t, 1.51, 0.79, a), doublet(t, 3.01, 0.39, np.radians(0.3))]
    )
    x = fly_nonlinear(
        model,
        theta,
        t,
        np.array([config.vehicle.speed, 0.1, -0.1, 0.01, 0.02, -0.01, 0.02, -0.01, 0.3, 1.0]),
        fins,
    )
    noisy = x + np.random.default_rng(2).normal(size=x.shape) * SIGMA
    x[1::2] = noisy[1::2] = np.nan
    return Experiment("fine", t, STATES, noisy, fins), Experiment("fine-clean", t, STATES, x, fins)


def test_fins_logged_faster_than_the_states_identify_the_model_that_flew(truth, fine):
    """From 20 % off, on states read at half the fins' rate: ml-gn within 3 σ of the model that
    flew, the equation-error start on the noise-free record within the midpoint rule's error over
    the 20 ms between states (1 %) and on the noisy one within a quarter of the start's error."""
    config = truth[0]
    noisy, clean = fine
    est = identify([noisy], _start(config), "ml-gn", start="config")
    assert est.converged
    for n, v, s in zip(est.free, est.values, est.std):
        assert abs(v - config.terms[n]) <= 3 * s, (n, v, config.terms[n], s)
    _regressed(config, clean, noisy)


def test_the_bounds_of_analyze_are_those_of_the_complex_step_fisher_information(truth):
    """The Cramér-Rao bounds at the truth from complex-step derivatives of the flight (over the
    free terms and the initial state), the initial state eliminated, with the noise held at the
    sensors' σ, against the analysis from the exact sensitivities, on the record's first 1.6 s."""
    config, _, clean = truth
    n = 80
    clean = replace(clean, t=clean.t[:n], y=clean.y[:n], inputs=clean.inputs[:n])
    config = replace(config, noise_std=dict(zip(STATES, SIGMA)))
    got = nonlinear_identifiability([clean], config)
    model, theta = config.nonlinear()
    x0 = clean.y[0].astype(complex)
    columns = []
    for name in FREE:
        d = np.zeros(len(theta), complex)
        d[model.names.index(name)] = 1e-30j
        columns.append(fly_nonlinear(model, theta + d, clean.t, x0, clean.inputs).imag.ravel() / 1e-30)
    for i in range(10):
        d = np.zeros(10, complex)
        d[i] = 1e-30j
        columns.append(
            fly_nonlinear(model, theta.astype(complex), clean.t, x0 + d, clean.inputs).imag.ravel() / 1e-30
        )
    J = np.column_stack(columns)
    W = np.tile(1 / SIGMA**2, n)
    F = reduced(J.T @ (W[:, None] * J), np.zeros(len(FREE) + 10), len(FREE))[0]
    want = np.sqrt(np.diag(np.linalg.inv(F)))
    assert np.allclose(got.crlb_std, want, rtol=1e-8), (got.crlb_std, want)
    assert got.free == FREE and not got.structural.unobserved


def _ok(capsys, argv):
    code = main([str(a) for a in argv])
    printed = capsys.readouterr()
    assert code == 0, printed.err
    return printed


def test_identify_then_validate_on_the_command_line(files, truth, capsys, tmp_path):
    config = truth[0]
    est = tmp_path / "est.json"
    _ok(capsys, ["identify", files / "doublets.csv", "--config", files / "start.toml", "--out", est])
    doc = json.loads(est.read_text())
    assert doc["method"] == "ml-gn" and doc["converged"] and list(doc["coefficients"]) == list(FREE)
    assert doc["nonlinear_model"] == {"config": str(files / "start.toml"), "terms": list(config.terms)}
    for n, c in doc["coefficients"].items():
        assert abs(c["value"] - config.terms[n]) <= 3 * c["std"], n
    assert set(doc["validation"]["doublets"]) == set(STATES)
    # validate rebuilds the model from the config the estimates name, the estimates applied
    out = tmp_path / "v.json"
    _ok(capsys, ["validate", files / "doublets.csv", "--estimates", est, "--out", out])
    v = json.loads(out.read_text())
    assert v["coefficients"] == {n: c["value"] for n, c in doc["coefficients"].items()}
    assert v["config"] == str(files / "start.toml")
    for s in STATES:  # its initial state fitted, not the fit's: the same model within noise
        assert v["validation"]["doublets"][s]["fit_percent"] == pytest.approx(
            doc["validation"]["doublets"][s]["fit_percent"], abs=0.5
        )


def test_validate_the_config_that_flew_the_data_fits_them_exactly(files, capsys, tmp_path):
    out = tmp_path / "v.json"
    printed = _ok(capsys, ["validate", files / "clean.csv", "--config", files / "truth.toml", "--out", out])
    doc = json.loads(out.read_text())
    assert "estimates" not in doc and doc["config"] == str(files / "truth.toml")
    fits = {s: m["fit_percent"] for s, m in doc["validation"]["clean"].items()}
    assert set(fits) == set(STATES) and min(fits.values()) > 99.99, fits
    assert "fit %" in printed.err
    # the start, 20 % off on four terms, flies visibly worse on the channels they drive
    _ok(
        capsys,
        ["validate", files / "clean.csv", "--config", files / "start.toml", "--out", tmp_path / "s.json"],
    )
    off = json.loads((tmp_path / "s.json").read_text())["validation"]["clean"]
    assert min(off[s]["fit_percent"] for s in ("v", "w", "r", "q")) < 99.0


def test_analyze_on_the_command_line(files, capsys, tmp_path):
    out = tmp_path / "a.json"
    _ok(capsys, ["analyze", files / "doublets.csv", "--config", files / "truth.toml", "--out", out])
    doc = json.loads(out.read_text())
    assert doc["free"] == list(FREE) and all(doc["crlb_std"][n] > 0 for n in FREE)
    assert np.shape(doc["correlation"]) == (4, 4) and doc["null_directions"] == 0


@pytest.mark.parametrize(
    "extra, words",
    [
        (["--method", "ml-fem"], "--method 'ml-fem' fits the linear model only"),
        (
            ["--start", "mekf"],
            "option --start 'mekf'; expected auto, config, equation-error, global for a nonlinear model config",
        ),
        (["--max-iter", "0"], "option --max-iter 0; expected an integer ≥ 1"),
    ],
)
def test_identify_refusals_are_one_line_and_write_nothing(files, capsys, tmp_path, extra, words):
    out = tmp_path / "est.json"
    argv = ["identify", files / "doublets.csv", "--config", files / "start.toml", "--out", out]
    code = main([str(a) for a in argv] + [a.format(tmp=tmp_path) for a in extra])
    err = capsys.readouterr().err
    assert code == 2 and words in err and err.strip().count("\n") == 0, err
    assert not any(tmp_path.iterdir())


def test_identify_records_the_nonlinear_fit_to_rerun(files, capsys, tmp_path):
    """`--rrd` for a nonlinear model config writes the recording beside the estimates
    (its contents: tests/presentation/test_report.py)."""
    rrd, out = tmp_path / "fit.rrd", tmp_path / "est.json"
    argv = ["identify", files / "doublets.csv", "--config", files / "start.toml", "--out", out, "--rrd", rrd]
    assert main([str(a) for a in argv]) == 0, capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["est.json", "fit.rrd"] and rrd.stat().st_size > 0


def test_validate_refuses_estimates_of_another_model(files, capsys, tmp_path):
    linear = tmp_path / "linear.json"
    linear.write_text(json.dumps({"coefficients": {"Y_v": {"value": -40.0}}}))
    nonlinear = tmp_path / "nonlinear.json"
    nonlinear.write_text(
        json.dumps(
            {
                "coefficients": {"Y_uv": {"value": -100.0}},
                "nonlinear_model": {"config": str(files / "start.toml"), "terms": ["Y_uv"]},
            }
        )
    )
    bad_name = tmp_path / "bad.json"
    bad_name.write_text(
        json.dumps(
            {
                "coefficients": {"Y_v": {"value": -40.0}},
                "nonlinear_model": {
                    "config": str(files / "start.toml"),
                    "terms": list(read_config(files / "start.toml").terms),
                },
            }
        )
    )
    for estimates, words in (
        (linear, "a linear model's fit; .*start.toml is a nonlinear model config"),
        (nonlinear, "fitted the nonlinear model over .*start.toml's terms; .* has other terms"),
        (bad_name, "coefficient 'Y_v' is not one of the nonlinear model config's names"),
    ):
        out = tmp_path / "v.json"
        code = main(
            [
                "validate",
                str(files / "clean.csv"),
                "--config",
                str(files / "start.toml"),
                "--estimates",
                str(estimates),
                "--out",
                str(out),
            ]
        )
        err = capsys.readouterr().err
        assert code == 2 and err.strip().count("\n") == 0 and not out.exists(), err
        assert re.search(words, err), err


def test_perturb_moves_the_free_terms(truth):
    config = truth[0]
    moved = perturbed(config, 0.1, seed=3)
    for n in FREE:
        assert moved.terms[n] == pytest.approx(config.terms[n] * 1.1) or moved.terms[n] == pytest.approx(
            config.terms[n] * 0.9
        )
    assert {n: v for n, v in moved.terms.items() if n not in FREE} == {
        n: v for n, v in config.terms.items() if n not in FREE
    }
    assert moved.coefficients == config.coefficients


@pytest.mark.parametrize("command", ["identify", "analyze"])
def test_a_record_with_a_gap_is_taken_on_the_command_line(files, capsys, tmp_path, command):
    lines = (files / "doublets.csv").read_text().splitlines()
    cells = lines[30].split(",")
    cells[4] = ""  # p missing at one sample
    lines[30] = ",".join(cells)
    gap = tmp_path / "gap.csv"
    gap.write_text("\n".join(lines) + "\n")
    out = tmp_path / "out.json"
    code = main([command, str(gap), "--config", str(files / "truth.toml"), "--out", str(out)])
    assert code == 0, capsys.readouterr().err
    assert out.exists()


def test_the_equation_error_start_regresses_the_model_that_flew_the_data(truth):
    """From 20 % off, the rows fitted to the records' difference quotients: on the noise-free
    record within the midpoint rule's O(Δt²) error (well under 1 %), on the noisy one within a
    quarter of the start's error."""
    config, noisy, clean = truth
    _regressed(config, clean, noisy)


def test_auto_starts_from_the_better_flying_start_and_ends_at_the_same_optimum(truth):
    config, noisy, _ = truth
    far = config.with_coefficients(
        {n: config.terms[n] * (3.0 if k % 2 else 1 / 3) for k, n in enumerate(FREE)}
    )
    from_config = identify([noisy], far, "ml-gn", start="config")
    auto = identify([noisy], far, "ml-gn")
    assert from_config.start == "config" and auto.start == "equation-error"
    assert from_config.converged and auto.converged and auto.iterations < from_config.iterations
    assert np.all(np.abs(auto.values - from_config.values) < 0.1 * auto.std)
    # at the values that flew the data the config's flight fits better than the regression's
    assert identify([noisy], config, "ml-gn").start == "config"
    assert identify([noisy], far, "ml-nm", max_iter=1).start == "equation-error"


def test_the_equation_error_start_needs_the_states_the_rows_involve(truth):
    config, noisy, _ = truth
    keep = [STATES.index(s) for s in STATES if s != "phi"]
    partial = replace(noisy, measured=tuple(STATES[k] for k in keep), y=noisy.y[:, keep])
    with pytest.raises(InputError, match=r"equation-error start: the records do not measure phi") as e:
        identify([partial], config, "ml-gn", start="equation-error")
    assert "\n" not in str(e.value)
    assert identify([partial], config, "ml-gn", max_iter=1).start == "config"


def test_the_equation_error_start_needs_an_interval_with_every_state_present(truth):
    """Roll and pitch logged on alternate rows: no interval has every state the rows involve, so
    the start cannot be computed (a one-line reason) and auto flies from the config's values."""
    config, noisy, _ = truth
    y = noisy.y.copy()
    y[::2, STATES.index("phi")] = np.nan
    y[1::2, STATES.index("theta")] = np.nan
    alternate = replace(noisy, y=y)
    with pytest.raises(InputError, match=r"equation-error start: no interval between samples") as e:
        identify([alternate], config, "ml-gn", start="equation-error")
    assert "\n" not in str(e.value)
    assert identify([alternate], config, "ml-gn", max_iter=1).start == "config"


OFFSETS = {"b_phi": np.radians(7.0), "b_theta": np.radians(-1.5), "b_psi": np.radians(3.0)}


def _offset(e: Experiment) -> Experiment:
    """The record as an attitude sensor mounted askew logs it: φ, θ, ψ plus `OFFSETS`."""
    y = e.y.copy()
    for name, b in OFFSETS.items():
        y[:, STATES.index(name[2:])] += b
    return replace(e, y=y)


def test_ml_gn_recovers_the_attitude_offsets_with_the_terms_and_leaves_the_heading_offset_unbounded(truth):
    """From 20 % off and the offsets at 0: φ's and θ's offsets and the terms within 3 σ. ψ enters
    no other state, so its offset and the initial heading move the outputs alike: b_psi's bound
    is infinite, in the fit and in `analyze`, and its screen names the singular information."""
    config, noisy, _ = truth
    biased = _offset(noisy)
    start = replace(_start(config), free=FREE + tuple(OFFSETS))
    est = identify([biased], start, "ml-gn", start="config")
    assert est.converged and est.free == FREE + tuple(OFFSETS)
    got = dict(zip(est.free, zip(est.values, est.std)))
    for n in FREE:
        assert abs(got[n][0] - config.terms[n]) <= 3 * got[n][1], (n, got[n], config.terms[n])
    for n in ("b_phi", "b_theta"):
        assert np.isfinite(got[n][1]) and abs(got[n][0] - OFFSETS[n]) <= 3 * got[n][1], (n, got[n])
    assert got["b_psi"][1] == np.inf
    # the offsets explain the attitude channels: their noise is the sensors' again
    assert np.allclose([est.noise_std[s] for s in ("phi", "theta")], SIGMA[[6, 7]], rtol=0.25)
    analysed = nonlinear_identifiability([biased], start.with_coefficients(OFFSETS))
    bound = dict(zip(analysed.free, analysed.crlb_std))
    assert bound["b_psi"] == np.inf and np.isfinite(bound["b_phi"]) and np.isfinite(bound["b_theta"])
    # the screen's first stage fixes it for that reason, alone or beside the others
    assert forward(analysed)["b_psi"] == "the Fisher information of these data is singular along it"


def test_ml_nm_recovers_the_attitude_offsets(truth):
    """`ml-nm` with φ's and θ's offsets free from 0 (the terms at their values) on the record's
    first 1.6 s: within 3 σ of the offsets and at `ml-gn`'s optimum (0.1 σ)."""
    config, noisy, _ = truth
    data = [_first(_offset(noisy), 80)]
    start = replace(config, free=("b_phi", "b_theta"))
    nm, gn = identify(data, start, "ml-nm", start="config"), identify(data, start, "ml-gn", start="config")
    assert nm.converged and gn.converged
    for n, v, s, g in zip(nm.free, nm.values, nm.std, gn.values):
        assert abs(v - OFFSETS[n]) <= 3 * s and abs(v - g) <= 0.1 * s, (n, v, g, OFFSETS[n], s)


def test_the_bias_columns_of_analyze_are_those_of_the_complex_step_fisher_information(truth):
    """The Cramér-Rao bounds at the truth over the free terms and φ's and θ's offsets, from
    complex-step derivatives of the outputs y = x(θ, x0) + b (the initial state eliminated, the
    noise held at the sensors' σ), against the analysis from the exact sensitivities."""
    config, _, clean = truth
    n, biases = 80, ("b_phi", "b_theta")
    clean = _offset(replace(clean, t=clean.t[:n], y=clean.y[:n], inputs=clean.inputs[:n]))
    at = replace(config, free=FREE + biases, noise_std=dict(zip(STATES, SIGMA))).with_coefficients(OFFSETS)
    got = nonlinear_identifiability([clean], at)
    model, theta = config.nonlinear()
    b = np.array([OFFSETS.get(f"b_{s}", 0.0) for s in STATES])
    x0 = clean.y[0] - b

    def outputs(th, x, bias):
        return (fly_nonlinear(model, th, clean.t, x, clean.inputs) + bias).imag.ravel() / 1e-30

    columns, h = [], 1e-30j
    for name in FREE:
        columns.append(outputs(theta + h * np.eye(len(theta))[model.names.index(name)], x0, b))
    for name in biases:
        columns.append(outputs(theta.astype(complex), x0, b + h * np.eye(10)[STATES.index(name[2:])]))
    for i in range(10):
        columns.append(outputs(theta.astype(complex), x0 + h * np.eye(10)[i], b))
    want = _complex_step_bounds(columns, n, len(FREE) + len(biases))
    assert got.free == FREE + biases
    assert np.allclose(got.crlb_std, want, rtol=1e-8), (got.crlb_std, want)


def test_identify_on_the_command_line_writes_the_output_biases(files, truth, capsys, tmp_path):
    """A nonlinear config freeing φ's and θ's offsets and fixing ψ's: `identify` writes them
    with the terms, and `validate` predicts the attitude as the fit did (the biases added)."""
    config, noisy, _ = truth
    biased = _offset(noisy)
    write_csv(tmp_path / "biased.csv", biased.t, biased.y, biased.inputs)
    cfg = replace(_start(config), free=FREE + ("b_phi", "b_theta")).with_coefficients(
        {"b_psi": OFFSETS["b_psi"]}
    )
    write_config(tmp_path / "c.toml", cfg)
    assert read_config(tmp_path / "c.toml").coefficients["b_psi"] == OFFSETS["b_psi"]
    est = tmp_path / "est.json"
    _ok(capsys, ["identify", tmp_path / "biased.csv", "--config", tmp_path / "c.toml", "--out", est])
    doc = json.loads(est.read_text())
    assert list(doc["coefficients"]) == list(FREE) + ["b_phi", "b_theta"]
    for n in ("b_phi", "b_theta"):
        c = doc["coefficients"][n]
        assert abs(c["value"] - OFFSETS[n]) <= 3 * c["std"], (n, c)
    out = tmp_path / "v.json"
    _ok(capsys, ["validate", tmp_path / "biased.csv", "--estimates", est, "--out", out])
    v = json.loads(out.read_text())["validation"]["biased"]
    for s in ("phi", "theta", "psi"):
        assert v[s]["fit_percent"] == pytest.approx(doc["validation"]["biased"][s]["fit_percent"], abs=0.5)
        assert v[s]["fit_percent"] > 90, (s, v[s])


def test_ml_gn_and_ml_nm_recover_the_rows_offsets_with_the_terms(truth):
    """Constant pitch and yaw moments (a trim or buoyancy error: `M_0`, `N_0` among the terms):
    the record flown with them and the sensors' noise, fitted from the terms 20 % off and the
    offsets at 0: `ml-gn` puts every free value within 3 σ of what flew it, and `ml-nm` (the
    terms at their values) ends at `ml-gn`'s optimum; the fit without them is rejected by the
    likelihood-ratio test (ΔJ beyond χ²₂(0.999)/2)."""
    config, _, clean = truth
    offsets = {"M_0": 4.0, "N_0": -3.0}
    at_zero = replace(config, terms={**config.terms, **dict.fromkeys(offsets, 0.0)})
    model, theta = at_zero.with_coefficients(offsets).nonlinear()
    x = fly_nonlinear(model, theta, clean.t, clean.y[0], clean.inputs)
    y = x + np.random.default_rng(2).normal(size=x.shape) * SIGMA
    data = [Experiment("offsets", clean.t, STATES, y, clean.inputs)]
    est = _recovered(at_zero, data, offsets)[0]
    without = identify(data, replace(_start(at_zero), free=FREE), "ml-gn", start="config")
    assert without.cost - est.cost > 13.8 / 2, (without.cost, est.cost)


def _delayed(config, clean: Experiment, tau: float, noise: int | None = None) -> Experiment:
    """The record `clean`'s fins logged `tau` s late: the model flown with them advanced by tau
    (δ_rec(t + τ), `problem.shifted`), its states as data (with the sensors' noise of seed
    `noise`, None: none), the fins as recorded."""
    model, theta = config.nonlinear()
    fins = shifted(clean.inputs, tau / (clean.t[1] - clean.t[0]))[0]
    x = fly_nonlinear(model, theta, clean.t, clean.y[0], fins)
    if noise is not None:
        x = x + np.random.default_rng(noise).normal(size=x.shape) * SIGMA
    return Experiment("delayed", clean.t, STATES, x, clean.inputs)


def test_ml_gn_and_ml_nm_recover_the_inputs_delay_with_the_terms(truth):
    """Fins logged 30 ms late (1.5 samples): from the terms 20 % off and no delay, `ml-gn` puts
    the terms and τ within 3 σ; `ml-nm` (τ alone free) ends at `ml-gn`'s optimum; the fit without
    τ is rejected by the likelihood-ratio test (ΔJ beyond χ²₁(0.999)/2)."""
    config, _, clean = truth
    data = [_delayed(config, clean, 0.03, noise=1)]
    est = _recovered(config, data, {"input_delay": 0.03})[0]
    without = identify(data, replace(_start(config), free=FREE), "ml-gn", start="config")
    assert without.cost - est.cost > 10.8 / 2, (without.cost, est.cost)


def test_the_delay_column_of_analyze_is_that_of_the_complex_step_fisher_information(truth):
    """The Cramér-Rao bounds over the free terms and the inputs' delay, from complex-step
    derivatives of the flight with its fins shifted (`problem.shifted`, complex in the shift),
    against the analysis's exact sensitivities, the flight's sensitivity to τ forced by ∂f/∂δ ∂δ/∂τ."""
    config, _, clean = truth
    n, tau = 80, 0.013
    clean = _first(clean, n)
    data = _delayed(config, clean, tau)
    at = replace(config, free=FREE + ("input_delay",), noise_std=dict(zip(STATES, SIGMA)))
    got = nonlinear_identifiability([data], at.with_coefficients({"input_delay": tau}))
    model, theta = config.nonlinear()
    dt, x0 = clean.t[1] - clean.t[0], clean.y[0]

    def outputs(th, x, shift):
        fins = shifted(clean.inputs, shift / dt)[0]
        return fly_nonlinear(model, th, clean.t, x, fins).imag.ravel() / 1e-30

    columns, h, real = [], 1e-30j, theta.astype(complex)
    for name in FREE:
        columns.append(outputs(theta + h * np.eye(len(theta))[model.names.index(name)], x0, tau))
    columns.append(outputs(real, x0, tau + h))
    for i in range(10):
        columns.append(outputs(real, x0 + h * np.eye(10)[i], tau))
    assert got.free == FREE + ("input_delay",)
    assert np.allclose(got.crlb_std, _complex_step_bounds(columns, n, len(FREE) + 1), rtol=1e-8)


def test_a_delay_on_records_without_a_constant_interval_is_refused(truth):
    """By the fits (free or given) and by the prediction `validate` makes (given), in one line."""
    config, noisy, _ = truth
    t = noisy.t.copy()
    t[50:] += 0.005  # one interval 25 ms, the others 20 ms
    uneven = replace(noisy, t=t)
    given = replace(config, free=FREE).with_coefficients({"input_delay": 0.02})
    for run in (
        lambda: identify([uneven], replace(config, free=FREE + ("input_delay",)), "ml-gn"),
        lambda: identify([uneven], given, "ml-gn"),
        lambda: nonlinear_prediction.predict_nonlinear([uneven], given),
    ):
        with pytest.raises(
            InputError, match=r"input_delay \(free or not 0\) shifts the fins .* constant sample interval"
        ) as e:
            run()
        assert "\n" not in str(e.value)


def test_ml_lm_fits_the_nonlinear_model_through_the_linear_models_optimiser(truth, monkeypatch):
    """`ml-lm` on either model runs the same `levenberg_marquardt`, given each model's objective;
    on the nonlinear record from the terms 20 % off it converges at `ml-gn`'s optimum (0.01 σ),
    and refuses the trust region's options and the global start."""
    from studies.remus import example_config, experiments

    from testbed.identification import linear_objective
    from testbed.identification.linear_objective import LinearObjective
    from testbed.identification.nonlinear_objective import NonlinearObjective

    seen, real = [], linear_objective.as_objective
    monkeypatch.setattr(
        linear_objective, "as_objective", lambda prob: seen.append(type(real(prob))) or real(prob)
    )
    assert identify(
        experiments(seed=2, duration=20.0)[1:], example_config(), "ml-lm", start="config"
    ).converged
    assert set(seen) == {LinearObjective}
    config, noisy, _ = truth
    est = identify([noisy], _start(config), "ml-lm", start="config")
    gn = identify([noisy], _start(config), "ml-gn", start="config")
    assert set(seen) == {LinearObjective, NonlinearObjective}
    assert est.method == "ml-lm" and est.converged and gn.converged
    assert np.all(np.abs(est.values - gn.values) <= 0.01 * gn.std), (est.values - gn.values) / gn.std
    with pytest.raises(OptionError, match="start"):
        identify([noisy], _start(config), "ml-lm", start="global")


def test_a_free_output_bias_of_a_state_not_measured_is_refused(truth):
    config, noisy, _ = truth
    start = replace(config, free=FREE + ("b_psi",))
    for method in ("ml-gn", "ml-nm"):
        with pytest.raises(
            InputError, match=r"free names b_psi, the output bias of a state the records do not"
        ) as e:
            identify([noisy.only(STATES[:8])], start, method)
        assert "\n" not in str(e.value)
    with pytest.raises(InputError, match=r"free names b_psi, the output bias"):
        nonlinear_identifiability([noisy.only(STATES[:8])], start)


MOUNTED = {"m_dvl_y": 0.0, "m_dvl_z": 0.02, "r_dvl_x": 0.8, "r_dvl_y": 0.0, "r_dvl_z": 0.2}


def _mounted(e: Experiment, clean: Experiment) -> Experiment:
    """The record's u, v, w as a log mounted as `MOUNTED` reads them (from the clean flight), its
    noise kept."""
    g = np.array(list(MOUNTED.values()))
    x = clean.y
    y = e.y.copy()
    y[:, :3] += log_mounting.reading(g, x[:, :3], x[:, 3:6], np.zeros((len(x), 3))) - x[:, :3]
    return replace(e, y=y)


def _recovered(config, data, values: dict):
    """`ml-gn` on `data` from the terms 20 % off and the parameters `values` at the config's
    (0): the terms and those within 3 σ of what flew and read the record; `ml-nm` with those
    alone free (the terms at their values) at `ml-gn`'s optimum on the first 80 samples (0.1 σ).
    The estimate, the prediction of `data` with its values and with the config's."""
    est = identify(data, replace(_start(config), free=FREE + tuple(values)), "ml-gn", start="config")
    assert est.converged
    for n, v, s in zip(est.free, est.values, est.std):
        want = values[n] if n in values else config.terms[n]
        assert abs(v - want) <= 3 * s, (n, v, want, s)
    short = [_first(data[0], 80)]
    at = replace(config, free=tuple(values))
    nm, gn = identify(short, at, "ml-nm", start="config"), identify(short, at, "ml-gn", start="config")
    assert nm.converged and gn.converged
    for v, s, g in zip(nm.values, nm.std, gn.values):
        assert abs(v - g) <= 0.1 * s
    fitted = config.with_coefficients(dict(zip(est.free, est.values)))
    predict = nonlinear_prediction.predict_nonlinear
    return est, predict(data, fitted)[0], predict(data, config)[0]


def test_ml_gn_and_ml_nm_recover_a_mounted_log_with_the_terms(truth):
    """A log 0.8 m forward, 0.2 m below the CG, turned 0.02 rad in yaw: from the terms 20 % off
    and the mounting at 0, `ml-gn` puts the terms and the mounting within 3 σ; `ml-nm` (the terms
    at their values) ends at its optimum; `validate` reads the velocities as the fit did."""
    config, noisy, clean = truth
    data = [_mounted(noisy, clean)]
    _, yhat, plain = _recovered(config, data, {n: MOUNTED[n] for n in ("m_dvl_z", "r_dvl_x", "r_dvl_z")})
    for c in range(3):  # the mounted reading fits u, v, w far better than the CG's velocities
        assert np.std(data[0].y[:, c] - yhat[:, c]) < np.std(data[0].y[:, c] - plain[:, c])


def test_the_mounting_columns_of_analyze_are_those_of_the_complex_step_fisher_information(truth):
    """As for the biases: the Cramér-Rao bounds over the free terms and the mounting, from
    complex-step derivatives of the read outputs, against the analysis's exact sensitivities."""
    config, _, clean = truth
    n, names = 80, ("m_dvl_z", "r_dvl_x", "r_dvl_z")
    clean = _mounted(_first(clean, n), _first(clean, n))
    at = replace(config, free=FREE + names, noise_std=dict(zip(STATES, SIGMA))).with_coefficients(MOUNTED)
    got = nonlinear_identifiability([clean], at)
    model, theta = config.nonlinear()
    g0 = np.array(list(MOUNTED.values()))
    x0 = truth[2].y[0]

    def outputs(th, x, g):
        return (
            log_mounting.read(g, fly_nonlinear(model, th, clean.t, x, clean.inputs), range(10)).imag.ravel()
            / 1e-30
        )

    columns, h = [], 1e-30j
    for name in FREE:
        columns.append(outputs(theta + h * np.eye(len(theta))[model.names.index(name)], x0, g0))
    for name in names:
        columns.append(outputs(theta.astype(complex), x0, g0 + h * np.eye(5)[list(MOUNTED).index(name)]))
    for i in range(10):
        columns.append(outputs(theta.astype(complex), x0 + h * np.eye(10)[i], g0))
    assert got.free == FREE + names
    assert np.allclose(got.crlb_std, _complex_step_bounds(columns, n, len(FREE) + len(names)), rtol=1e-8)


CURRENT = {"c_N": 0.3, "c_E": -0.2}


def _in_current(e: Experiment, clean: Experiment, mounting=None) -> Experiment:
    """The record's u, v, w as a log (mounted as `mounting`, None: at the CG) reads them over the
    ground in the steady `CURRENT`, turned into the body's axes by the record's own measured
    heading (the regressor the model takes), from the clean flight; its noise kept."""
    g = np.zeros(5) if mounting is None else np.asarray(mounting, float)
    c = log_mounting.body_current(np.array(list(CURRENT.values())), e.y[:, STATES.index("psi")])
    x, y = clean.y, e.y.copy()
    y[:, :3] += log_mounting.reading(g, x[:, :3], x[:, 3:6], c) - x[:, :3]
    return replace(e, y=y)


def test_ml_gn_and_ml_nm_recover_a_current_with_the_terms(truth):
    """A current of 0.36 m/s under a log at the CG: from the terms 20 % off and the current at
    0, `ml-gn` puts the terms and (c_N, c_E) within 3 σ; `ml-nm` (the terms at their values)
    ends at `ml-gn`'s optimum; the prediction with the fitted current reads u and v over the
    ground, where the model without it is off by the current."""
    config, noisy, clean = truth
    data = [_in_current(noisy, clean)]
    _, yhat, still = _recovered(config, data, CURRENT)
    for c in range(2):  # RMS: the current is a slowly turning offset, which a spread would miss
        fit, off = (np.sqrt(np.mean((data[0].y[:, c] - y[:, c]) ** 2)) for y in (yhat, still))
        assert fit < 2 * SIGMA[c] < off, (STATES[c], fit, off)


def test_the_current_columns_of_analyze_are_those_of_the_complex_step_fisher_information(truth):
    """As for the mounting: the Cramér-Rao bounds over the free terms, the mounting and the
    current under a mounted log, from complex-step derivatives of the read outputs, against the
    analysis's exact sensitivities."""
    config, _, clean = truth
    n, names = 80, ("m_dvl_z", "r_dvl_x", "c_N", "c_E")
    g0, c0 = np.array(list(MOUNTED.values())), np.array(list(CURRENT.values()))
    clean = _in_current(_first(clean, n), _first(clean, n), g0)
    at = replace(config, free=FREE + names, noise_std=dict(zip(STATES, SIGMA)))
    got = nonlinear_identifiability([clean], at.with_coefficients({**MOUNTED, **CURRENT}))
    model, theta = config.nonlinear()
    psi, x0 = clean.y[:, STATES.index("psi")], truth[2].y[0]

    def outputs(th, x, g, c):
        states = fly_nonlinear(model, th, clean.t, x, clean.inputs)
        return log_mounting.read(g, states, range(10), log_mounting.body_current(c, psi)).imag.ravel() / 1e-30

    columns, h, real = [], 1e-30j, theta.astype(complex)
    for name in FREE:
        columns.append(outputs(theta + h * np.eye(len(theta))[model.names.index(name)], x0, g0, c0))
    for name in names[:2]:
        columns.append(outputs(real, x0, g0 + h * np.eye(5)[list(MOUNTED).index(name)], c0))
    for name in names[2:]:
        columns.append(outputs(real, x0, g0, c0 + h * np.eye(2)[list(CURRENT).index(name)]))
    for i in range(10):
        columns.append(outputs(real, x0 + h * np.eye(10)[i], g0, c0))
    assert got.free == FREE + names
    assert np.allclose(got.crlb_std, _complex_step_bounds(columns, n, len(FREE) + len(names)), rtol=1e-8)


@pytest.mark.parametrize("kind", ["current", "delay"])
def test_identify_and_validate_on_the_command_line_take_a_trials_parameters(kind, truth, capsys, tmp_path):
    """A nonlinear config freeing the current (the velocities read over the ground) or the
    inputs' delay (the fins logged 30 ms late), a start value given: the config written back
    keeps it, `identify` writes the parameters with the terms, within 3 σ, and `validate`
    predicts every channel as the fit did."""
    config, noisy, clean = truth
    if kind == "current":
        data, values, given = _in_current(noisy, clean), CURRENT, {"c_N": 0.1}
    else:
        data, values, given = (
            _delayed(config, clean, 0.03, noise=1),
            {"input_delay": 0.03},
            {"input_delay": 0.01},
        )
    write_csv(tmp_path / "trial.csv", data.t, data.y, data.inputs)
    write_config(
        tmp_path / "c.toml", replace(_start(config), free=FREE + tuple(values)).with_coefficients(given)
    )
    assert all(read_config(tmp_path / "c.toml").coefficients[n] == v for n, v in given.items())
    est = tmp_path / "est.json"
    _ok(capsys, ["identify", tmp_path / "trial.csv", "--config", tmp_path / "c.toml", "--out", est])
    doc = json.loads(est.read_text())
    for n, want in values.items():
        c = doc["coefficients"][n]
        assert abs(c["value"] - want) <= 3 * c["std"], (n, c)
    out = tmp_path / "v.json"
    _ok(capsys, ["validate", tmp_path / "trial.csv", "--estimates", est, "--out", out])
    v = json.loads(out.read_text())["validation"]["trial"]
    for s in STATES:
        assert v[s]["fit_percent"] == pytest.approx(doc["validation"]["trial"][s]["fit_percent"], abs=0.5), s


def test_a_current_without_the_heading_or_the_velocities_is_refused(truth):
    """The current turns with the heading: a record fitting u or v without ψ is refused where
    the current is free or not 0, and a free current where no velocity is measured, each in one
    line naming what is missing, for the fits and the analysis alike."""
    config, noisy, _ = truth
    no_psi = noisy.only(tuple(s for s in STATES if s != "psi"))
    for cfg in (replace(config, free=FREE + ("c_N",)), replace(config, free=FREE).with_coefficients(CURRENT)):
        for method in ("ml-gn", "ml-nm", "mekf"):
            # the filter estimates no current at all: said first, from the config alone
            words = (
                "free names c_N; mekf" if method == "mekf" and "c_N" in cfg.free else "turns with the heading"
            )
            with pytest.raises(InputError, match=words) as e:
                identify([no_psi], cfg, method)
            assert "\n" not in str(e.value)
    with pytest.raises(InputError, match=r"free names c_E, the current, but the records measure no velocity"):
        nonlinear_identifiability([noisy.only(STATES[3:])], replace(config, free=FREE + ("c_E",)))


def _complex_step_bounds(columns, n: int, p: int) -> np.ndarray:
    """The Cramér-Rao σ of the first `p` of the outputs' complex-step derivative `columns` over
    `n` samples of the 10 states, the last 10 columns (the initial state's) eliminated, the
    noise at the sensors' σ."""
    J = np.column_stack(columns)
    W = np.tile(1 / SIGMA**2, n)
    F = reduced(J.T @ (W[:, None] * J), np.zeros(p + 10), p)[0]
    return np.sqrt(np.diag(np.linalg.inv(F)))


def test_ml_lm_takes_a_start_whose_flight_diverges_on_segments_first(truth):
    """With N_uv (the yaw moment of sideslip) of the wrong sign the a-priori model's flight from
    the record's first sample leaves the finite numbers within its 4 s: `ml-lm` fits the record
    cut into segments first, as `ml-gn` does, and ends at `ml-gn`'s optimum (within 0.01 σ), every
    coefficient within 3 σ of the model that flew."""
    config, noisy, _ = truth
    prior = config.with_coefficients({"N_uv": -config.terms["N_uv"]})
    with pytest.raises(Unflyable):
        nonlinear_prediction.flights([noisy], prior, nonlinear_prediction.first_samples([noisy], prior))
    lm, gn = (identify([noisy], prior, m, start="config") for m in ("ml-lm", "ml-gn"))
    assert lm.converged and gn.converged
    assert np.all(np.abs(lm.values - gn.values) <= 0.01 * gn.std)
    for n, v, s in zip(lm.free, lm.values, lm.std):
        assert abs(v - config.terms[n]) <= 3 * s, (n, v, config.terms[n], s)
