"""`II-trial` fitted as `studies/trial.py` fits it: with the sensors' known geometry and the
trial's parameters free, what the scenario injected comes back, and the coefficients with it."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from studies.trial import MAX_ITER, TRIAL, beyond, guess, injected, known, main, misses
from testbed.analysis.profile import profile
from testbed.data import load_data
from testbed.estimators import identify
from testbed.models.linear import structure, theta_vector, tilde
from testbed.simulation.runs import simulate
from testbed.simulation.scenario import scenario


def test_the_injected_offsets_are_the_loads_less_the_fin_offsets_and_velocity_biases(tmp_path):
    """The K and N rows by hand: propeller torque, the weight's moment about the displaced CG,
    the recorded fins' offsets through the control derivatives (δ_true = δ_rec − offset), the
    DVL's biases through the velocity derivatives."""
    s = scenario("II-trial")
    run = simulate(s, seed=1, out=tmp_path / "run", truth="linear", duration=1.0)
    config = load_data([run])[1]
    c, trial, W = dict(config.coefficients), s.trial, config.vehicle.weight
    _, At, _, _ = tilde(structure(config.vehicle), theta_vector(config.coefficients))
    dvl = next(x for x in s.named_sensors if "v" in x.outputs)
    expected = (
        trial.roll_moment
        + trial.cg_offset[1] * (W + trial.weight_excess)
        - c["K_der"] * trial.offsets[1]
        + c["K_del"] * trial.offsets[2]
        - c.get("K_dr", 0.0) * trial.offsets[0]
        - c["K_v"] * dvl.bias["v"]
        - At[3, 2] * dvl.bias["w"]
    )
    got = injected(s, config, W)
    assert np.isclose(got["K_0"], expected, rtol=1e-12)
    assert np.isclose(
        got["N_0"],
        -c["N_dr"] * trial.offsets[0] - At[5, 1] * dvl.bias["v"] - At[5, 2] * dvl.bias["w"],
        rtol=1e-12,
    )
    assert got["input_delay"] == trial.fin_log_delay and got["c_N"] == trial.current[0]


@pytest.mark.slow
def test_ii_trial_gives_back_its_biases_offsets_current_and_delay(tmp_path):
    """`ml-gn` from a guess (the run's coefficients × exp(0.3 N(0, 1))); about 35 s."""
    s = scenario("II-trial")
    run = simulate(s, seed=1, out=tmp_path / "run", truth="linear")
    experiments, config = load_data([run])
    with_trial = replace(guess(config, 1), free=config.free + TRIAL, sensors=known(s), screen=False)
    est = identify(experiments, with_trial, method="ml-gn", max_iter=MAX_ITER)
    assert est.converged
    assert misses(est, injected(s, config, config.vehicle.weight), relative=0.0) == []
    assert misses(est, {n: config.coefficients[n] for n in config.free}) == []


@pytest.mark.slow
def test_ii_trial_by_the_filter_error_method_with_its_sensors_at_their_own_rates(tmp_path):
    """The same with `ml-fem`: its periodic filter (DVL and depth at 10 Hz in the IMU's 50 Hz),
    the turbulence's correlation time; about 30 s."""
    s = scenario("II-trial")
    run = simulate(s, seed=1, out=tmp_path / "run", truth="linear")
    experiments, config = load_data([run])
    with_trial = replace(guess(config, 1), free=config.free + TRIAL, sensors=known(s), screen=False)
    est = identify(
        experiments, with_trial, method="ml-fem", max_iter=MAX_ITER, correlation_time=s.trial.turbulence.time
    )
    assert est.converged, est.message
    assert misses(est, injected(s, config, config.vehicle.weight), relative=0.0) == []
    assert misses(est, {n: config.coefficients[n] for n in config.free}) == []


def test_the_study_refuses_a_folder_of_someone_s_notes_before_it_runs(tmp_path, capsys):
    notes = tmp_path / "notes"
    (notes / "seed1").mkdir(parents=True)
    (notes / "seed1" / "plan.txt").write_text("mine")
    assert main(["--seeds", "1", "--out", str(notes)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "seed1: is a folder without manifest.json" in err
    assert sorted(p.name for p in notes.rglob("*")) == ["plan.txt", "seed1"]
    assert (notes / "seed1" / "plan.txt").read_text() == "mine"


@pytest.mark.slow
def test_the_filter_error_fit_leaves_the_optimum_of_a_row_without_process_noise(tmp_path):
    """II-trial seed 2 with Z_w held at the analytic value, `ml-fem` from the analytic model: the
    yaw row's process noise reaches 0, a local optimum of its own (a little noise costs more than
    it explains), 28 above the one with it at 0.0065 rad/s/√s. Started again from its first guess
    it finds that one; the profile likelihood then puts the analytic Z_w 1.7 σ from the estimate,
    where the bound says 3.6 σ. About 60 s."""
    s = scenario("II-trial")
    run = simulate(s, seed=2, out=tmp_path / "run", truth="linear")
    experiments, config = load_data([run])
    with_trial = replace(guess(config, 2), free=config.free + TRIAL, sensors=known(s), screen=False)
    options = {"max_iter": MAX_ITER, "correlation_time": s.trial.turbulence.time}
    est = identify(experiments, with_trial, method="ml-fem", **options)
    truth = {n: config.coefficients[n] for n in config.free} | injected(s, config, config.vehicle.weight)
    held = replace(with_trial.with_coefficients(truth), free=tuple(n for n in with_trial.free if n != "Z_w"))
    from_truth = identify(experiments, held, method="ml-fem", **options)
    assert from_truth.converged and from_truth.process_noise_std["r"]["value"] > 0.005
    ratio = profile(experiments, with_trial, est, "Z_w", truth["Z_w"], **options)
    assert ratio.statistic == pytest.approx(2 * (from_truth.cost - est.cost), abs=0.1)
    assert abs(ratio.sigmas) < 3 < abs(beyond(est, truth)[0][1])
