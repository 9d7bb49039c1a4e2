"""The screen of a nonlinear model config: on a short record the captive model flew (the sensors'
noise added) with the elevator moving as the rudder and the ailerons held, the screen fixes a term
whose factor never moves, one of a pair of terms whose factors are one and the same (the other
kept: it is the pair's one determined combination) and a term whose true value is 0, and the rest
are recovered from a perturbed start; through the library and on the command line."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from testbed.analysis.identifiability import assessed
from testbed.analysis.nonlinear_identifiability import (
    NONLINEAR,
    forward,
    nonlinear_identifiability,
    rank_tolerance,
)
from testbed.analysis.screening import screening
from testbed.jobs.identify import identify_screened
from testbed.analysis.structural import Structural
from testbed.captive.config import captive_config
from testbed.cli import main
from testbed.data import Experiment, read_config, read_csv, write_config, write_csv
from testbed.estimators import identify
from testbed.errors import Unflyable
from testbed.identification.nonlinear_prediction import first_samples, flights
from testbed.models.linear import STATES
from testbed.models.nonlinear_flight import fly_nonlinear
from testbed.simulation import runs
from testbed.simulation.measurements import NOISE_STD

DETERMINED = ("Y_uv", "N_uv", "Z_uw", "M_uw")  # moved 20 % off in the start
BLIND = "K_uuda"  # u²δa: the ailerons held at 0, its regressor is 0 along the record
TWINS = ("X_uudrdr", "X_uudede")  # u²δr², u²δe²: δe = δr, one regressor for both
ZERO = "Y_uv|dr|"  # 0 in the truth and a priori
CANDIDATES = (*DETERMINED, BLIND, *TWINS, ZERO)
SIGMA = np.array([NOISE_STD[s] for s in STATES])


@pytest.fixture(scope="module")
def truth():
    """The captive model (ZERO set to 0) with the CANDIDATES as a candidate list, and a 4 s
    record it flew from near straight flight at 20 m/s through a 3° doublet of rudder and
    both elevators together (δe = δr, δa = 0), the sensors' noise added."""
    base = captive_config(model="polynomial")[0]
    config = replace(base, free=CANDIDATES, screen=True).with_coefficients({ZERO: 0.0})
    model, theta = config.nonlinear()
    t = np.arange(201) * 0.02
    d = np.radians(3.0) * (((t >= 0.2) & (t < 1.0)) * 1.0 - ((t >= 1.0) & (t < 1.8)))
    fins = np.column_stack([d, d, d])  # δr, δer, δel: δe = δr, δa = 0
    x0 = np.array([config.vehicle.speed, 0.1, -0.1, 0.01, 0.02, -0.01, 0.02, -0.01, 0.3, 1.0])
    x = fly_nonlinear(model, theta, t, x0, fins)
    noisy = x + np.random.default_rng(1).normal(size=x.shape) * SIGMA
    return config, Experiment("doublet", t, STATES, noisy, fins)


def _twins(config):
    """(fixed, kept): of the twins, one regressor for both, the one more significant a priori
    (the larger |value|) is kept and the other fixed."""
    kept = max(TWINS, key=lambda n: abs(config.terms[n]))
    return next(n for n in TWINS if n != kept), kept


def _start(config):
    """The a-priori config: the DETERMINED terms 20 % off (signs mixed), the others as in the truth."""
    return config.with_coefficients(
        {n: config.terms[n] * (1.2 if k % 2 else 0.8) for k, n in enumerate(DETERMINED)}
    )


def test_the_rank_tolerance_separates_one_regressor_twice_from_a_distinct_one(truth):
    """At the truth the twins' scaled information has an eigenvalue within the rounding of 0 (two
    equal columns), below the tolerance; without one of them the smallest is far above it."""
    config, record = truth
    twins = nonlinear_identifiability([record], replace(config, free=(*DETERMINED, *TWINS)))
    apart = nonlinear_identifiability([record], replace(config, free=(*DETERMINED, TWINS[0])))
    for result, singular in ((twins, True), (apart, False)):
        F = result.fisher
        d = np.sqrt(np.diag(F))
        lam = np.linalg.eigvalsh(F / np.outer(d, d))
        tol = rank_tolerance(F, F, len(record.t), len(STATES), 4)  # κ = 1: no initial state eliminated
        assert (lam[0] <= tol * lam[-1]) == singular, (lam, tol)
    assert np.all(np.isinf(twins.crlb_std[-2:])) and np.all(np.isfinite(apart.crlb_std))


def test_forward_keeps_one_of_a_copy_and_what_stays_significant_a_priori():
    """Sensitivities with unit noise: A strong, B and its copy B2 (a smaller value, so tried
    later), C moderate, W whose value is 0.5 of its bound (below 2 σ), Z blind. Closed form:
    with A, B, C kept each stays far above 2 σ; B2 makes the information singular with B."""
    rng = np.random.default_rng(2)
    a, b, c, w = rng.normal(size=(4, 400))
    J = np.column_stack([a, b, b, c, w, np.zeros(400)])
    free = ("A", "B", "B2", "C", "W", "Z")
    values = np.array([1.0, 0.5, 0.2, 0.3, 0.5 / np.linalg.norm(w), 1.0])
    struct = Structural(free, np.eye(6)[[5]], (("Z",),), ("Z",))
    fixed = forward(assessed(free, values, J.T @ J, struct))
    assert list(fixed) == ["Z", "B2", "W"], fixed
    assert "singular along it and B, kept before it" in fixed["B2"]
    assert "its a-priori value is 0.5 σ from 0" in fixed["W"]


def test_the_screen_fixes_the_blind_one_twin_and_the_zero_and_recovers_the_rest(truth):
    config, record = truth
    fixed_twin, kept_twin = _twins(config)
    s = screening([record], _start(config), model=NONLINEAR)
    assert list(s.fixed) == [BLIND, fixed_twin, ZERO], s.fixed
    assert "no fitted state depends on it" in s.fixed[BLIND]
    assert f"singular along it and {kept_twin}" in s.fixed[fixed_twin]
    assert "σ from 0" in s.fixed[ZERO]
    assert s.config.free == (*DETERMINED, kept_twin) and s.fit.converged
    # the a-priori values stay, the fixed ones at the truth
    assert all(s.config.terms[n] == config.terms[n] for n in (BLIND, fixed_twin, ZERO))
    # the rest recovered within 3 σ: the kept twin its own value, the other held at its truth
    for n, v, sd in zip(s.fit.free, s.fit.values, s.fit.std):
        assert abs(v - config.terms[n]) <= 3 * sd, (n, v, config.terms[n], sd)


def test_stage_1_keeps_a_candidate_0_a_priori_that_is_determined(truth):
    """Nothing is fixed for being 0: a determined term whose a-priori value is 0 (the elevators'
    heave force, δe moving) passes the first stage and is freed at its estimate, near its truth."""
    config, record = truth
    candidates = replace(_start(config), free=(*DETERMINED, "Z_uude")).with_coefficients({"Z_uude": 0.0})
    s = screening([record], candidates, model=NONLINEAR)
    assert s.fixed == {} and s.fit.free == (*DETERMINED, "Z_uude")
    assert abs(s.fit.values[-1] - config.terms["Z_uude"]) <= 3 * s.fit.std[-1]


@pytest.mark.parametrize("method", ["ml-gn", "ml-nm"])
def test_the_fits_information_is_the_analysis_at_the_estimate(truth, method):
    """An estimate carries the Fisher information its bounds come from; the analysis at the
    estimate (the screen's stage 2, a report's correlation) takes it, and gets what flying the
    sensitivities again at the estimate gives."""
    config, record = truth
    fit = identify([record], replace(_start(config), free=DETERMINED), method=method)
    at = replace(config.with_coefficients(fit.coefficients), free=DETERMINED, noise_std=fit.noise_std)
    flown = nonlinear_identifiability([record], at, initial=fit.initial_states)
    given = nonlinear_identifiability([record], at, initial=fit.initial_states, information=fit.information)
    np.testing.assert_allclose(given.fisher, flown.fisher, rtol=1e-6)
    np.testing.assert_allclose(given.correlation, flown.correlation, atol=1e-8)
    np.testing.assert_allclose(np.sqrt(np.diag(np.linalg.inv(given.fisher))), fit.std, rtol=1e-6)
    with pytest.raises(ValueError, match="expected"):
        nonlinear_identifiability([record], at, information=fit.information[1:, 1:])


def test_identify_screened_fits_the_screened_list(truth):
    config, record = truth
    fixed_twin, kept_twin = _twins(config)
    screened = identify_screened([record], _start(config), model=NONLINEAR)
    assert screened.applied and screened.estimate.free == (*DETERMINED, kept_twin)
    assert set(screened.fixed) == {BLIND, fixed_twin, ZERO}
    for n, v, sd in zip(screened.estimate.free, screened.estimate.values, screened.estimate.std):
        assert abs(v - config.terms[n]) <= 3 * sd, (n, v, config.terms[n], sd)


@pytest.mark.parametrize("flag", ["--screen", None])
def test_screen_on_the_command_line(truth, tmp_path, capsys, flag):
    """A candidate list (screen = true) is screened by default and with --screen; the JSON's
    `fixed` gives the a-priori value and the reason, `coefficients` what the data determine."""
    config, record = truth
    write_csv(tmp_path / "doublet.csv", record.t, record.y, record.inputs)
    write_config(tmp_path / "start.toml", _start(config))
    assert read_config(tmp_path / "start.toml").screen
    out = tmp_path / "est.json"
    argv = ["identify", tmp_path / "doublet.csv", "--config", tmp_path / "start.toml", "--out", out]
    code = main([str(a) for a in argv] + ([flag] if flag else []))
    err = capsys.readouterr().err
    assert code == 0, err
    doc = json.loads(out.read_text())
    fixed_twin, kept_twin = _twins(config)
    assert list(doc["coefficients"]) == [*DETERMINED, kept_twin] and "screen" not in doc
    assert list(doc["fixed"]) == [BLIND, fixed_twin, ZERO]
    for n, f in doc["fixed"].items():
        assert f["value"] == config.terms[n] and f["reason"].startswith("not determined by these data")
    for n, c in doc["coefficients"].items():
        assert abs(c["value"] - config.terms[n]) <= 3 * c["std"], n


def test_free_all_fits_the_list_as_written_and_reports_the_screen(truth, tmp_path, capsys):
    config, record = truth
    free = replace(config, free=(*DETERMINED, ZERO))
    write_csv(tmp_path / "doublet.csv", record.t, record.y, record.inputs)
    write_config(tmp_path / "start.toml", _start(free))
    out = tmp_path / "est.json"
    argv = ["identify", tmp_path / "doublet.csv", "--config", tmp_path / "start.toml", "--out", out]
    assert main([str(a) for a in argv] + ["--free-all"]) == 0, capsys.readouterr().err
    doc = json.loads(out.read_text())
    assert list(doc["coefficients"]) == [*DETERMINED, ZERO] and "fixed" not in doc
    assert list(doc["screen"]) == [ZERO]


def _unstable(config, factor):
    """The config with N_uv (the yaw moment of sideslip) `factor` times its value: at −1 the
    flight from the record's first sample leaves the finite numbers within its 4 s, at −3 the
    flights from every sample do within a fifth of a second."""
    return config.with_coefficients({"N_uv": factor * config.terms["N_uv"]})


def test_an_unstable_a_priori_model_is_analysed_on_the_segments_it_can_be_flown_on(truth):
    """The information of a model whose flight over the whole record diverges is that of the
    records cut where it stays bounded, each piece with its own initial state: the same as the
    pieces analysed as records of their own, and the summary says so first."""
    config, record = truth
    prior = replace(_unstable(config, -1.0), free=DETERMINED, screen=False)
    with pytest.raises(Unflyable):
        flights([record], prior, first_samples([record], prior))
    cut = nonlinear_identifiability([record], prior)
    assert cut.segments > 1 and cut.summary[0].startswith(f"Computed on {cut.segments} segments")
    assert "leaves the finite numbers" in cut.summary[0] and np.all(np.isfinite(cut.crlb_std))
    # the pieces (nearly) equal, as many rows each, each flown from its first sample
    edges = np.linspace(0, len(record.t), cut.segments + 1).round().astype(int)
    pieces = [
        Experiment(f"piece {k}", record.t[a:b], STATES, record.y[a:b], record.inputs[a:b])
        for k, (a, b) in enumerate(zip(edges[:-1], edges[1:]))
    ]
    alone = nonlinear_identifiability(pieces, prior, initial=first_samples(pieces, prior))
    assert alone.segments == 0
    np.testing.assert_allclose(cut.fisher, alone.fisher, rtol=1e-9)


@pytest.mark.parametrize("factor, skipped", [(-1.0, False), (-3.0, True)])
def test_the_screen_starts_from_an_unstable_a_priori_model(truth, factor, skipped):
    """An unstable prior is no refusal: its stage 1 reads the information on segments (−1), or,
    where even the shortest diverge (−3), is skipped with the reason; the fit from the starts
    that fly recovers every candidate within 3 σ."""
    config, record = truth
    s = screening([record], replace(_unstable(config, factor), free=DETERMINED), model=NONLINEAR)
    assert bool(s.skipped) is skipped and ("even on" in s.skipped) is skipped, s.skipped
    assert s.fit.converged and s.fit.free == DETERMINED
    for n, v, sd in zip(s.fit.free, s.fit.values, s.fit.std):
        assert abs(v - config.terms[n]) <= 3 * sd, (n, v, config.terms[n], sd)


@pytest.mark.slow
def test_on_scenario_i_flown_by_the_captive_model_every_freed_term_is_within_3_sigma(tmp_path):
    """Scenario I's fin angles (seed 1) flown by the captive model from the plant's first
    noise-free sample, the sensors' noise added, screened from `testbed captive`'s candidate
    list (every term) at the captive values: the estimate of each term the screen frees is within
    3 Cramér-Rao σ of the value that flew the record, and the screen frees some and fixes some
    (60 s of a large manoeuvre do not determine all 102 terms)."""
    config = captive_config(model="polynomial")[0]
    run = runs.simulate("I", seed=1, out=tmp_path / "I")
    truth = read_csv(run / "scenario-I.truth.csv", keep_repeats=True)
    model, theta = config.nonlinear()
    x = fly_nonlinear(model, theta, truth.t, np.array([truth.column(s)[0] for s in STATES]), truth.inputs)
    noisy = x + np.random.default_rng(1).normal(size=x.shape) * SIGMA
    screened = identify_screened(
        [Experiment("I", truth.t, STATES, noisy, truth.inputs)], config, model=NONLINEAR
    )
    est = screened.estimate
    assert screened.applied and est.converged and 0 < len(est.free) < len(config.terms)
    assert set(est.free) | set(screened.fixed) == set(config.terms)
    for n, v, sd in zip(est.free, est.values, est.std):
        assert abs(v - config.terms[n]) <= 3 * sd, (n, v, config.terms[n], sd)
