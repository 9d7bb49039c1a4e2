"""The ML optimiser judged from where a user starts: a course-unstable vehicle from 40 % off, and
Scenario II from paired realistic starts (`studies/starts.py`; the 20-start acceptance is slow)."""

import csv
from dataclasses import replace

import numpy as np
import pytest
from scipy.optimize import brentq

from studies import starts
from testbed.analysis.screening import screen
from testbed.data import load_data
from testbed.errors import InputError
from testbed.estimators import OptionError, identify
from testbed.identification import bounds, prediction
from testbed.models.linear import IX, continuous, discretize, structure, theta_vector
from testbed.simulation.analytic import analytic_config
from testbed.simulation.measurements import NOISE_STD
from testbed.simulation.signals import Prbs

# -- a course-unstable vehicle ---------------------------------------------------------------------

POLE = 0.02  # 1/s: the unstable yaw-sway root; e^(0.02·300) = 403 over the record
DURATION, DT = 300.0, 0.05
SWAY_YAW = ("Y_v", "Y_r", "Y_dr", "N_v", "N_r", "N_dr")
LATERAL = ("v", "p", "r", "phi", "psi")
# the heading autopilot, δ_r = PRBS + k_ψ ψ + k_r r (a positive rudder turns to port: ψ falls):
# closed-loop poles −0.39 ± 0.34j 1/s and the fast ones; the unstable root is held
K_PSI, K_R = 0.001, 0.003
PRBS = Prbs(amplitude=0.0005, order=10, clock=0.1)  # Scenario II's rudder PRBS at half its amplitude


def _largest_pole(config) -> float:
    A = continuous(structure(config.vehicle), theta_vector(config.coefficients))[0]
    return float(np.linalg.eigvals(A).real.max())


@pytest.fixture(scope="module")
def unstable():
    """The analytic torpedo with its Munk moment N_v scaled until the yaw-sway root is at +POLE
    (×7.9: the straight-line stability margin reversed), flown 300 s with the autopilot holding
    its heading against a rudder PRBS (course-unstable ships are tested under an autopilot or in
    zigzags: open loop the heading runs away), its lateral states measured with the run's sensor
    noise. The autopilot reads the noise-free states (as a filtered estimate would); the data
    are the linear model's own response to the rudder it recorded (`prediction.synthetic`)."""
    config = analytic_config()[0]
    nv = config.coefficients["N_v"]

    def pole(f):
        return _largest_pole(config.with_coefficients({"N_v": f * nv})) - POLE

    simulated = replace(
        config.with_coefficients({"N_v": brentq(pole, 1.0, 30.0) * nv}), free=SWAY_YAW, outputs=LATERAL
    )
    A, B, S = continuous(structure(simulated.vehicle), theta_vector(simulated.coefficients))
    Phi, Gamma, s = discretize(A, B, S, DT)
    t = np.arange(0.0, DURATION, DT)
    program = PRBS.program(np.random.default_rng(3))
    x, inputs = np.zeros(len(A)), np.zeros((len(t), 3))
    for k, tk in enumerate(t):
        inputs[k, 0] = program(tk, x) + K_PSI * x[IX["psi"]] + K_R * x[IX["r"]]
        x = Phi @ x + Gamma @ inputs[k] + s
    noise = {c: NOISE_STD[c] for c in LATERAL}
    experiment = prediction.synthetic(
        simulated, t, inputs, noise, LATERAL, np.random.default_rng(1), name="autopilot"
    )
    # the bounds at the simulated coefficients with the noise known, the initial states eliminated (Schur
    # complement): independent of any fit
    sigma = np.sqrt(
        np.diag(np.linalg.inv(bounds.information([experiment], simulated, noise_std=noise).fisher))
    )
    return simulated, experiment, sigma


@pytest.fixture(scope="module")
def optimum(unstable):
    """The reference: ml-gn started at the truth."""
    simulated, e, _ = unstable
    return identify([e], simulated, method="ml-gn", start="config")


def test_the_course_unstable_vehicle_is_unstable_and_held(unstable):
    # its own check, apart from the fit: the scaled Munk moment puts one real root at +POLE, and
    # the autopilot keeps the flight in the linear regime (yaw rate below 10 °/s, heading 30°)
    # where open loop the root grows 403-fold
    config = analytic_config()[0]
    assert _largest_pole(config) <= 0.0  # the analytic torpedo is straight-line stable
    simulated, e, _ = unstable
    A = continuous(structure(simulated.vehicle), theta_vector(simulated.coefficients))[0]
    ev = np.linalg.eigvals(A)
    root = ev[np.argmax(ev.real)]
    assert 0.02 - 1e-9 <= root.real <= 0.05 and root.imag == 0.0, root
    assert np.abs(e.column("r")).max() < np.radians(10.0)
    assert np.abs(e.column("psi")).max() < np.radians(30.0)


DELTA_J = starts.DELTA_J


@pytest.mark.parametrize("seed", [0, 2])  # the start's model: course-stable; diverging at +1.3 1/s
def test_default_ml_gn_reaches_the_optimum_of_a_course_unstable_vehicle(unstable, optimum, seed):
    simulated, e, sigma = unstable
    signs = np.random.default_rng(seed).choice([-1.0, 1.0], size=len(SWAY_YAW))
    start = simulated.with_coefficients(
        {n: simulated.coefficients[n] * (1 + 0.4 * s) for n, s in zip(SWAY_YAW, signs)}
    )
    fit = identify([e], start, method="ml-gn")
    assert fit.converged and optimum.converged, (fit.status, optimum.status)
    assert fit.cost <= optimum.cost + DELTA_J, fit.cost - optimum.cost
    off = np.abs(fit.values - optimum.values) / sigma
    assert np.all(off <= starts.SIGMA_TOLERANCE), off


# -- Scenario II from realistic starts ------------------------------------------------------------


def test_starts_move_each_coefficient_by_a_log_normal_factor_and_a_zero_by_its_bounds():
    config = replace(analytic_config()[0], free=starts.FREE + ("K_dr",))  # K_dr is 0 a-priori
    assert config.coefficients["K_dr"] == 0.0
    std = np.arange(1.0, len(config.free) + 1)
    drawn = starts.perturbed_starts(config, std, 400, spread=0.5, seed=7)
    a = np.array([config.coefficients[n] for n in starts.FREE])
    logs = np.log(np.array([[s[n] for n in starts.FREE] for s in drawn]) / a)
    # 400 × 17 draws of 0.5·N(0,1): the mean within 4 standard errors of 0, the spread within 5 %
    assert abs(logs.mean()) < 4 * 0.5 / np.sqrt(logs.size)
    assert 0.475 < logs.std() < 0.525
    zero = np.array([s["K_dr"] for s in drawn])
    assert np.all(np.abs(zero) == 3.0 * std[-1]) and 0.4 < np.mean(zero > 0) < 0.6
    # start k is the same whatever the number of starts (a 5-start study shares the 20's first 5)
    assert starts.perturbed_starts(config, std, 3, spread=0.5, seed=7) == drawn[:3]


def _fit(cost, values, converged=True):
    status = "CONVERGED" if converged else "MAX_ITERATIONS"
    return starts.Fit("0", "ml-gn", status, cost, np.asarray(values, float), np.ones(2), 5, 0.1)


def test_a_fit_reaches_the_optimum_within_delta_j_and_a_tenth_of_sigma():
    best = replace(_fit(-100.0, [1.0, 2.0]), std=np.array([0.5, 2.0]))
    assert starts.reaches(_fit(-99.5, [1.04, 1.81]), best)  # 0.08 σ and 0.095 σ
    assert not starts.reaches(_fit(-99.5, [1.06, 2.0]), best)  # 0.12 σ
    assert not starts.reaches(_fit(-98.5, [1.0, 2.0]), best)  # ΔJ = 1.5
    assert not starts.reaches(_fit(-100.0, [1.0, 2.0], converged=False), best)
    # an unbounded σ at the reference judges nothing near it: only the reference itself is there
    unbounded = replace(best, std=np.array([0.5, np.inf]))
    assert starts.reaches(best, unbounded) and not starts.reaches(_fit(-100.0, [1.0, 2.001]), unbounded)
    assert starts.reference([_fit(np.nan, [0, 0]), _fit(-3.0, [1, 1]), _fit(-5.0, [2, 2])]).cost == -5.0


def test_methods_and_their_starts_are_checked_before_any_fit():
    assert starts.parse_method("ml-gn:config") == ("ml-gn", {"start": "config"})
    assert starts.parse_method("ml-nm") == ("ml-nm", {})
    with pytest.raises(OptionError, match="start"):
        starts.parse_method("ml-gn:nowhere")
    with pytest.raises(InputError, match="unknown"):
        starts.parse_method("ml-xx")


@pytest.fixture(scope="module")
def short_run(tmp_path_factory):
    """Scenario II, 20 s per experiment, seed 1."""
    return starts.scenario_run(tmp_path_factory.mktemp("starts") / "II-20", seed=1, duration=20.0)


def test_short_start_study_reaches_the_optimum_from_every_start(short_run, tmp_path, capsys):
    # the study on a 20 s Scenario II: default ml-gn from 3 starts in 2 processes, the table and the CSV
    out = tmp_path / "starts.csv"
    argv = ["--starts", "3", "--duration", "20", "--run", str(short_run), "--out", str(out), "--jobs", "2"]
    assert starts.main(argv) == 0
    table = capsys.readouterr().out
    assert "ml-gn: reaches the optimum from 3 of 3 starts" in table
    rows = list(csv.reader(out.open()))
    head, rows = rows[0], rows[1:]
    assert head[-len(starts.FREE) :] == list(starts.FREE)
    assert [r[0] for r in rows] == ["0", "1", "2", "analytic"]
    column = dict(zip(head, zip(*rows)))
    assert min(map(float, column["cost_minus_best"])) == 0.0
    assert all(r == "true" for r in column["reaches_optimum"])


def test_a_run_of_another_seed_or_length_is_refused(short_run):
    with pytest.raises(InputError, match="seed 1, 20.0 s; expected Scenario II seed 2"):
        starts.scenario_run(short_run, seed=2, duration=20.0)
    with pytest.raises(InputError, match="expected Scenario II seed 1, 60.0 s"):
        starts.scenario_run(short_run, seed=1, duration=60.0)


@pytest.fixture(scope="module")
def scenario_ii(tmp_path_factory):
    """Scenario II as the study flies it (60 s, seed 1): its experiments and analytic model."""
    return load_data([starts.scenario_run(tmp_path_factory.mktemp("starts") / "II-seed1", 1, None)])


@pytest.mark.slow
def test_the_free_list_is_what_scenario_ii_identifies(scenario_ii):
    experiments, config = scenario_ii
    assert screen(experiments, config)[0].free == starts.FREE


@pytest.mark.slow
def test_default_ml_gn_reaches_the_optimum_from_19_of_20_starts(scenario_ii):
    result = starts.study(*scenario_ii, methods=["ml-gn"], starts=20)
    print(result.table())
    assert result.reached["ml-gn"] >= 19


@pytest.mark.slow
def test_global_start_reaches_the_optimum_from_every_start(scenario_ii):
    result = starts.study(*scenario_ii, methods=["ml-gn:global"], starts=20)
    print(result.table())
    assert result.reached["ml-gn:global"] == 20


def _logged(run, dst, rng, jitter):
    """The 50 Hz record a logger writes of the fin-logged run `run` (states every 20 ms, fins
    and truth every 10 ms), into `dst`: each sample taken at its stamp, the 20 ms instant
    jittered by up to ±`jitter` of the step (the run's noise-free states there, a cubic spline
    through its 100 Hz truth, plus the run's own noise of the row), each fin the mean of the
    servo's 10 ms steps over the row's own interval (held to the next row). With `jitter` > 0 a
    tenth of each state's samples are dropped (empty fields) at random, one stamp in a hundred
    is a stale copy of the one before (its sample taken at its own instant), and the depth is
    logged at 10 Hz only (a fifth of the rows)."""
    import shutil

    from scipy.interpolate import CubicSpline

    shutil.copytree(run, dst, ignore=shutil.ignore_patterns("*.rrd", "*.csv"))
    for f in run.glob("*.csv"):
        if f.name.endswith(".truth.csv"):
            continue
        header = f.read_text().splitlines()[0].split(",")
        fine = np.loadtxt(f.with_suffix(".truth.csv"), delimiter=",", skiprows=1)
        rows = np.genfromtxt(f, delimiter=",", skip_header=1)
        a = rows[~np.isnan(rows[:, 1])]  # the rows with states: every 20 ms
        states = [j for j, c in enumerate(header) if c not in ("t", "delta_r", "delta_er", "delta_el")]
        fins = [header.index(c) for c in ("delta_r", "delta_er", "delta_el")]
        dt = a[1, 0] - a[0, 0]
        stamps = a[:, 0] + rng.uniform(-jitter, jitter, len(a)) * dt
        stamps[[0, -1]] = a[[0, -1], 0]
        noise = a[:, states] - fine[np.searchsorted(fine[:, 0], a[:, 0] - 1e-9)][:, states]
        a[:, states] = CubicSpline(fine[:, 0], fine[:, states])(stamps) + noise
        step = fine[1, 0] - fine[0, 0]
        knots = np.r_[fine[:, 0], fine[-1, 0] + step]
        for j in fins:  # ∫δ dt at the servo's steps; each row's fin its mean to the next stamp
            at = np.interp(stamps, knots, np.r_[0.0, np.cumsum(fine[:, j] * step)])
            a[:-1, j] = np.diff(at) / np.diff(stamps)
        a[:, 0] = stamps
        if jitter:
            for j in states:
                a[rng.random(len(a)) < 0.1, j] = np.nan
            slow = np.ones(len(a), dtype=bool)
            slow[::5] = False
            a[slow, header.index("z")] = np.nan
            stale = np.flatnonzero(rng.random(len(a)) < 0.01)
            stale = stale[stale > 0]
            a[stale, 0] = a[stale - 1, 0]
        lines = [",".join(header)] + [",".join("" if np.isnan(v) else f"{v:.10g}" for v in r) for r in a]
        (dst / f.name).write_text("\n".join(lines) + "\n")


def test_a_scenario_ii_log_as_it_comes_keeps_its_information(tmp_path):
    """Scenario II (seed 1, its fins and truth also at the servos' 100 Hz) logged at 50 Hz with
    dropouts, stamps jittered by ±20 % of the step, stale stamps and a 10 Hz depth sensor, each
    sample taken at its stamp (two realisations), against the same flight logged at its 20 ms
    instants: read at its stamps, each log keeps its information. A tenth of the samples missing
    costs 1/√0.9 = 1.054 of σ: at the clean log's estimate, with the sensors' noise, each
    coefficient's Cramér-Rao σ is within 1.2× of the clean log's, and `ml-gn` with the run's
    model.toml converges on each. (Its estimate is not the clean log's: the servos move every
    10 ms, and the fins held from stamp to jittered stamp are another approximation of their
    course than the 20 ms intervals' means; a log whose fins change at its own stamps identifies
    the model as its even twin does, tests/data/test_time_as_logged.py.)"""
    from importlib.resources import files

    from testbed.jobs.identify import identify_screened
    from testbed.identification.bounds import information
    from testbed.simulation.runs import simulate

    scenario = tmp_path / "II-fins.toml"
    text = (files("testbed.simulation") / "scenarios" / "II.toml").read_text()
    scenario.write_text(text + "\n[sensors]\nfin_rate = 100.0\n")
    simulate(str(scenario), seed=1, out=tmp_path / "run")
    _logged(tmp_path / "run", tmp_path / "clean", np.random.default_rng(0), 0.0)
    clean, config = load_data([tmp_path / "clean"])
    a = identify_screened(clean, config).estimate
    fitted = replace(config, free=a.free).with_noise_std(NOISE_STD)
    at_clean = information(fitted.fitted(clean), fitted, a.values).crlb_std
    for seed in range(2):
        _logged(tmp_path / "run", tmp_path / f"logged{seed}", np.random.default_rng(seed), 0.2)
        logged, _ = load_data([tmp_path / f"logged{seed}"])
        assert all(np.isnan(e.y).any() for e in logged)
        same = information(fitted.fitted(logged), fitted, a.values).crlb_std / at_clean
        assert np.all(same <= 1.2) and np.all(same >= 1.0), {
            n: round(float(v), 3) for n, v in zip(a.free, same)
        }
    b = identify(logged, replace(config, free=a.free), "ml-gn")
    assert a.converged and b.converged


def test_the_screened_list_is_fitted_from_where_the_screen_s_fit_ended():
    """When the screen fixes a candidate, `ml-gn` fits the rest from the screen's own estimate
    (the fixed one at its a-priori value), not from the a-priori model again: in the screen fit's
    basin, which a poor a-priori model may not lead back to."""
    from testbed.analysis.screening import screening
    from testbed.jobs.identify import identify_screened
    from studies.remus import example_config, experiments

    config = example_config()
    prior = config.with_coefficients({n: 0.6 * config.coefficients[n] for n in config.free})
    candidates = replace(prior, free=config.free + ("K_dr",), screen=True)
    screened = identify_screened(experiments(seed=1, duration=60.0), candidates, options={"start": "config"})
    assert list(screened.fixed) == ["K_dr"]
    estimate = screened.estimate
    screen = screening(experiments(seed=1, duration=60.0), candidates, options={"start": "config"}).fit
    start = dict(zip(screen.free, screen.values))
    assert estimate.history[0] == pytest.approx([start[n] for n in estimate.free], rel=1e-12)
    assert estimate.converged and estimate.iterations < screen.iterations


def test_a_fix_that_costs_more_than_the_likelihood_ratio_test_allows_is_undone(monkeypatch):
    """The significance stage chooses its fixes by the cost's quadratic model; where fixing them
    raises the cost by more than χ²₀.₉₅(k)/2 (here N_r held at half its value, forced through the
    stage), the screen's fit of every candidate stands, the reason in its start_reason."""
    from testbed.analysis import screening
    from studies.remus import example_config, experiments
    from testbed.jobs.identify import identify_screened

    config = example_config()
    prior = replace(config.with_coefficients({"N_r": 0.5 * config.coefficients["N_r"]}), screen=True)
    data = experiments(seed=1, duration=60.0)
    monkeypatch.setattr(screening, "insignificant", lambda *a: {"N_r": "forced"})
    screened = identify_screened(data, prior, options={"start": "config"})
    assert screened.fixed == {} and "N_r" in screened.estimate.free
    assert "the screen kept them: fixing N_r raised the cost by" in screened.estimate.start_reason
    monkeypatch.undo()
    whole = identify_screened(data, replace(prior, screen=False), options={"start": "config"})
    assert screened.estimate.cost == pytest.approx(whole.estimate.cost, abs=1e-6)
