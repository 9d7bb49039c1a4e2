"""The screen: a candidate list loses only what the data do not determine, an explicit list is
fitted as written. Data from a "foreign" torpedo (the bundled one's linear model with coefficients
changed, as another simulator would give), fitted from a user's a-priori config that has some of
them at 0 or tiny. The whole 20-coefficient list from such a config takes ml-gn a while (slow);
a short list of the same kind runs by default."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from testbed.analysis.identifiability import UNCERTAIN, identifiability
from testbed.analysis.screening import SIGNIFICANT, insignificant, screening
from testbed.cli import main
from testbed.data import config_text, read_config, write_csv
from testbed.errors import InputError
from testbed.estimators import identify
from testbed.identification.prediction import synthetic
from testbed.jobs.identify import identify_data
from testbed.simulation.analytic import analytic_config, analytic_config_text
from testbed.simulation.measurements import NOISE_STD, noise_from_data
from testbed.simulation.signals import Prbs

MEASURED = ("u", "v", "w", "p", "q", "r", "phi", "theta", "psi")
ZERO = ("Z_q", "M_w", "N_v", "N_p")  # 0 in the user's a-priori config, not in the foreign body
# fin channels (delta_r, delta_er, delta_el) of each experiment and its PRBS amplitude, rad
EXPERIMENTS = {"rudder": ((1, 0, 0), 0.001), "elevators": ((0, 1, 1), 0.001), "roll": ((0, 1, -1), 0.001)}


def flights(simulated, seed=3):
    """Scenario II's three PRBS experiments (60 s at 20 Hz, open loop) flown by the linear model
    `simulated`, with the testbed's sensor noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 60.0, 0.05)
    out = []
    for name, (signs, amplitude) in EXPERIMENTS.items():
        program = Prbs(amplitude=amplitude, order=10, clock=0.1).program(rng)
        fins = np.outer([program(ti, None) for ti in t], signs)
        out.append(synthetic(simulated, t, fins, NOISE_STD, measured=MEASURED, rng=rng, name=name))
    return out


def write(tmp, data, configs):
    """The experiments as measurement CSVs and each of `configs` (name → config) as a TOML file
    in `tmp`."""
    csvs = [write_csv(tmp / f"{e.name}.csv", e.t, e.y, e.inputs, e.measured) for e in data]
    paths = [tmp / f"{name}.toml" for name in configs]
    for path, config in zip(paths, configs.values()):
        path.write_text(config_text(config))
    return csvs, *paths


@pytest.fixture(scope="module")
def foreign(tmp_path_factory):
    """The foreign torpedo's data, the model they were simulated from, and the user's a-priori config (ZERO at 0) as a
    candidate list and as an explicit list, written as files."""
    analytic = analytic_config()[0]
    c = analytic.coefficients
    simulated = analytic.with_coefficients(
        {"Y_v": 1.3 * c["Y_v"], "N_r": 0.8 * c["N_r"], "M_q": 1.2 * c["M_q"]} | {n: 1.5 * c[n] for n in ZERO}
    )
    prior = analytic.with_coefficients(dict.fromkeys(ZERO, 0.0))
    tmp = tmp_path_factory.mktemp("foreign")
    data = flights(simulated)
    lists = {"candidates": replace(prior, screen=True), "explicit": replace(prior, screen=False)}
    csvs, candidates, explicit = write(tmp, data, lists)
    return data, simulated, csvs, candidates, explicit


@pytest.fixture(scope="module")
def candidate_run(foreign, tmp_path_factory):
    """`identify` (ml-gn) on the foreign data from the candidate list: the screen applied."""
    csvs, candidates = foreign[2], foreign[3]
    out = tmp_path_factory.mktemp("candidates") / "e.json"
    return identify_data(csvs, config=candidates, out=out), json.loads(out.read_text())


@pytest.fixture(scope="module")
def explicit_run(foreign, tmp_path_factory):
    """`identify` (ml-gn) on the foreign data from the explicit list: the screen only reported."""
    csvs, explicit = foreign[2], foreign[4]
    out = tmp_path_factory.mktemp("explicit") / "e.json"
    return identify_data(csvs, config=explicit, out=out), json.loads(out.read_text())


def test_a_priori_zeros_the_data_determine_are_freed_from_a_short_candidate_list(foreign, tmp_path):
    """ZERO and K_dr as candidates, the rest at the foreign body's values: ZERO is estimated (4
    to 100 σ from 0, where the foreign body has them), K_dr (0 in both bodies) is fixed."""
    _, simulated, csvs, _, _ = foreign
    path = tmp_path / "short.toml"
    prior = simulated.with_coefficients(dict.fromkeys(ZERO, 0.0))
    path.write_text(config_text(replace(prior, free=ZERO + ("K_dr",), screen=True)))
    done = identify_data(csvs, config=path)
    assert done.estimate.free == ZERO and list(done.fixed) == ["K_dr"]
    for n, value, std in zip(done.estimate.free, done.estimate.values, done.estimate.std):
        assert abs(value) > 4 * std and abs(value - simulated.coefficients[n]) < 4 * std, (n, value, std)


@pytest.mark.slow
def test_a_candidate_list_frees_what_the_data_determine_even_at_an_a_priori_zero(foreign, candidate_run):
    _, simulated, _, candidates, _ = foreign
    config = read_config(candidates)
    assert config.screen and all(config.coefficients[n] == 0.0 for n in ZERO)
    done, doc = candidate_run
    est = dict(zip(done.estimate.free, zip(done.estimate.values, done.estimate.std)))
    for n in ZERO:  # determined at > 4 σ, and where the foreign body has them
        value, std = est[n]
        assert abs(value) > 4 * std and abs(value - simulated.coefficients[n]) < 4 * std, (n, value, std)
    # what the data cannot tell from 0 is fixed at its a-priori value (K_dr is 0 in both bodies),
    # with its reason; the rest of the list is estimated, and nothing is only reported
    assert "K_dr" in doc["fixed"] and set(doc["fixed"]) == set(done.fixed) and "screen" not in doc
    assert set(doc["fixed"]) | set(doc["coefficients"]) == set(config.free)
    assert all("σ from 0" in f["reason"] for f in doc["fixed"].values())


@pytest.mark.slow
def test_an_explicit_list_is_fitted_as_written_and_the_screen_only_reported(
    foreign, explicit_run, candidate_run
):
    config = read_config(foreign[4])
    done, doc = explicit_run
    assert not config.screen and not done.fixed
    assert list(doc["coefficients"]) == list(config.free) and "fixed" not in doc
    # the same screen as on the candidate list, reported only
    fixed = candidate_run[1]["fixed"]
    assert doc["screen"] == {n: f["reason"] for n, f in fixed.items()} == done.screen


@pytest.mark.slow
def test_what_the_screen_fixes_costs_the_fit_little_and_leaves_the_rest_significant(
    explicit_run, candidate_run
):
    """The backward elimination works on the cost's quadratic model. Refitted with ml-gn (the
    candidate run), every candidate left free is significant, and the cost has risen from the
    fit of the whole list (the explicit run, the screen's own fit) by at most SIGNIFICANT²/2
    per coefficient fixed (each was within SIGNIFICANT σ of its a-priori value)."""
    whole, refit = explicit_run[0].estimate, candidate_run[0].estimate
    assert whole.converged and refit.converged
    assert np.all(np.abs(refit.values) >= SIGNIFICANT * refit.std), dict(
        zip(refit.free, refit.values / refit.std)
    )
    assert 0 <= refit.cost - whole.cost <= SIGNIFICANT**2 / 2 * len(candidate_run[0].fixed)


def test_a_tiny_a_priori_value_the_data_determine_is_not_fixed():
    """K_v of a body with a large roll moment of sway (a sail high above the CG), a-priori a
    thousandth of it: the bound at the a-priori value is far above 50 % of that value (the old
    rule fixed it), but the estimate is many σ from 0."""
    analytic = analytic_config()[0]
    simulated = analytic.with_coefficients({"K_v": 15 * analytic.coefficients["K_v"]})
    prior = replace(simulated.with_coefficients({"K_v": simulated.coefficients["K_v"] / 1000}), screen=True)
    data = flights(simulated, seed=5)
    at_prior = identifiability(data, prior, noise_from_data(prior.fitted(data)))
    k = at_prior.free.index("K_v")
    assert at_prior.crlb_std[k] > UNCERTAIN * abs(at_prior.values[k])
    s = screening(data, prior)
    assert "K_v" in s.config.free
    value, std = dict(zip(s.fit.free, zip(s.fit.values, s.fit.std)))["K_v"]
    assert abs(value) > 4 * std and abs(value - simulated.coefficients["K_v"]) < 4 * std


def test_backward_elimination_keeps_the_partner_of_a_drifting_pair():
    """Two estimates 0.99 correlated, each alone within 2 σ of 0: fixing the less significant
    at its a-priori 0 leaves the other at 1.9 − 0.99 · 0.5 = 1.405 with σ √(1 − 0.99²) = 0.141,
    10 σ from 0 (Gaussian conditioning): it stays free. A third, within 2 σ of 0 but 9.5 σ from
    its a-priori value, stays free: fixing it there would contradict the data."""
    covariance = np.array([[1.0, 0.99, 0.0], [0.99, 1.0, 0.0], [0.0, 0.0, 1.0]])
    fixed = insignificant(("a", "b", "c"), [0.5, 1.9, 0.5], np.linalg.inv(covariance), [0.0, 0.0, 10.0])
    assert list(fixed) == ["a"]
    # the same pair uncorrelated: both are fixed, the less significant first
    fixed = insignificant(("a", "b"), [0.5, 1.9], np.eye(2), [0.0, 0.0])
    assert list(fixed) == ["a", "b"] and "1.9 σ from 0" in fixed["b"]


def test_the_candidate_marker_is_written_read_and_checked(tmp_path):
    text = analytic_config_text()
    assert "\nscreen = true\n" in text and "# screen = true: free is a candidate list" in text
    path = tmp_path / "c.toml"
    path.write_text(text)
    assert read_config(path).screen
    path.write_text(text.replace("screen = true", 'screen = "yes"'))
    with pytest.raises(InputError, match=r"c\.toml: \[identify\] screen = 'yes'; expected true or false"):
        read_config(path)
    path.write_text(text.replace("screen = true\n", ""))
    assert not read_config(path).screen


def test_the_flags_override_the_config_and_an_empty_screen_is_a_one_line_error(foreign, tmp_path, capsys):
    """K_dr alone free, the others at the foreign body's values (K_dr is 0 there). Listed
    explicitly, it is fitted and the screen, which would fix it, reported in one line; with
    --screen the screen leaves nothing to estimate: a one-line error, nothing written. As a
    candidate list the other way round, --free-all fitting it."""
    _, simulated, csvs, _, _ = foreign
    out = tmp_path / "e.json"

    def identify(path, *flags):
        code = main(["identify", *map(str, csvs), "--config", str(path), "--out", str(out), *flags])
        err = capsys.readouterr().err
        if code == 2:
            assert err.count("\n") == 1 and "no candidate of [identify] free is determined" in err
            assert "K_dr" in err and not out.exists()
            return
        assert code == 0
        (line,) = [x for x in err.splitlines() if "the screen would fix" in x]
        assert "K_dr" in line and "--screen" in line
        doc = json.loads(out.read_text())
        assert list(doc["coefficients"]) == ["K_dr"] and list(doc["screen"]) == ["K_dr"]
        out.unlink()
        return doc

    for screen, flag in ((False, "--screen"), (True, "--free-all")):
        path = tmp_path / f"only-{screen}.toml"
        path.write_text(config_text(replace(simulated, free=("K_dr",), screen=screen)))
        assert (identify(path) is None) is screen
        assert (identify(path, flag) is None) is not screen


def test_the_screen_takes_the_information_at_an_estimate_with_a_mode_faster_than_the_step():
    # Data from a vehicle whose roll mode (K_p = −200: 1.05e3 1/s) decays below rounding within
    # one 0.05 s step (e^−ρΔ < 2⁻⁵³), fitted from an a-priori model whose fastest mode (5.2e2 1/s)
    # the step still resolves, and the fit reaches the data's fast roll mode. The screen completes
    # and keeps K_p, which the data determine (the quasi-static roll rate p = K_δ δ / −K_p); the
    # estimate given back as a start is no error (the exact zero-order hold shows the fast stable
    # mode as decayed within the step) and ends where it began.
    from testbed.analysis.validation import validate
    from studies import remus as examples
    from testbed.identification.bounds import COARSEST
    from testbed.models.linear import continuous, structure, theta_vector

    roll = dict(K_der=100.0, K_del=100.0)
    truth = examples.example_config().with_coefficients(roll | dict(K_p=-200.0))
    prior = examples.example_config().with_coefficients(roll | dict(K_p=-100.0))
    rng = np.random.default_rng(3)
    data = [
        synthetic(truth, t, u, examples.NOISE, rng=rng, name=n) for n, (t, u) in examples.inputs().items()
    ]
    dt = float(data[0].t[1] - data[0].t[0])

    def rate(c):
        return np.max(
            np.abs(np.linalg.eigvals(continuous(structure(c.vehicle), theta_vector(c.coefficients))[0]))
        )

    assert rate(prior) * dt < COARSEST < rate(truth) * dt
    s = screening(data, prior, {"start": "config"})
    assert s.fit.converged
    assert rate(prior.with_coefficients(s.fit.coefficients)) * dt > COARSEST  # the fit found the fast mode
    assert "K_p" in s.config.free and "K_p" not in s.fixed
    assert abs(s.fit.coefficients["K_p"] + 200.0) < 3 * s.fit.std[s.fit.free.index("K_p")]
    # the fitted model is validated on the same data too: with its fast roll mode it follows the
    # roll the differential elevator drives (the rudder experiment's p is noise)
    fit = validate(data, prior.with_coefficients(s.fit.coefficients))
    assert fit.experiments["vertical"]["p"].fit_percent > 80
    again = identify(data, prior.with_coefficients(s.fit.coefficients), method="ml-gn", start="config")
    assert again.converged and abs(again.cost - s.fit.cost) < 1.0  # ΔJ: the same optimum


@pytest.mark.parametrize(
    "method, free, words",
    [
        ("mekf", ("b_v",), "free lists b_v; mekf takes the outputs' biases"),
        ("ekf", ("m_dvl_z",), "m_dvl_z is free or not 0; ekf reads the velocities"),
        ("equation-error", ("c_N",), "free lists c_N; equation-error regresses"),
        ("ml-fem", ("m_dvl_y",), "m_dvl_y is free or not 0; ml-fem reads the velocities"),
    ],
)
def test_what_a_method_refuses_in_the_config_is_refused_before_the_screen_s_fit(
    monkeypatch, method, free, words
):
    """A config the method cannot take, whatever the data: the one-line refusal, and no screen
    (its `ml-gn` fit can take minutes on a real log)."""
    from studies.remus import FREE, experiments, prior_config
    from testbed.jobs import identify

    def screened(*args, **kwargs):
        raise AssertionError("the screen ran before the method's refusal")

    monkeypatch.setattr(identify, "screening", screened)
    config = replace(prior_config(), free=FREE + free, screen=True)
    with pytest.raises(InputError, match=words) as exc:
        identify.identify_screened(experiments(seed=0, duration=5.0), config, method)
    assert "\n" not in str(exc.value)
