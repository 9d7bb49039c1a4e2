"""`open_loop_fit`: the analytic model open loop against a run's data and noise-free truth."""

import json
import math

import numpy as np
import pytest

from testbed.analysis.regime import EXCITED_SNR, FIT_LIMIT, OpenLoopFit, open_loop_fit
from testbed.data import read_csv
from testbed.errors import InputError
from testbed.models.linear import STATES
from testbed.simulation import runs
from testbed.simulation.scenario import read_scenario


@pytest.fixture(scope="module")
def fits(tmp_path_factory):
    """Scenario II (seed 1, as the campaign evaluates it) on the plant and the linear model, and
    Scenario I (seed 3) on the plant, full length; their run directories and open-loop fits."""
    root = tmp_path_factory.mktemp("regime")
    out = {}
    for name, seed, truth in (("II", 1, "plant"), ("II", 1, "linear"), ("I", 3, "plant")):
        run = runs.simulate(name, seed=seed, out=root / f"{name}-{truth}", truth=truth)
        out[name, truth] = run, open_loop_fit(run)
    return out


def test_scenario_ii_is_in_the_linear_regime_on_the_plant(fits):
    run, f = fits["II", "plant"]
    assert f.lowest_fit_to_truth >= FIT_LIMIT, f.lowest
    sigma = read_scenario(run / "scenario.toml").sensors.noise_std
    for name in ("horizontal", "vertical", "roll"):
        truth = read_csv(run / f"{name}.truth.csv", keep_repeats=True)
        moved = {c for c in STATES if truth.column(c).std() >= EXCITED_SNR * sigma[c]}
        assert set(f.excited[name]) == moved and moved  # the documented rule, and each moves something
        for c in f.excited[name]:
            assert f.data[name][c] < f.truth[name][c]  # the noise lowers the fit to the data
    assert max(f.speed_loss.values()) < 0.1 and max(f.peak_pitch.values()) < 2.0  # %, deg


def test_the_linear_truth_is_fitted_to_rounding(fits):
    _, f = fits["II", "linear"]
    assert f.lowest_fit_to_truth > 99.99
    assert all(v == 0.0 for v in f.speed_loss.values())  # u is decoupled at trim in the linear model
    assert math.isnan(f.truth["horizontal"]["u"])  # a channel that does not vary has no fit %


def test_scenario_i_is_far_outside_it(fits):
    # The measurements of Scenario I, seed 3, 60 s (fit % of the noise-free truth, the
    # speed falling from 20 to 16.4 m/s, pitch 30°, pitch rate 95 °/s)
    _, f = fits["I", "plant"]
    truth = f.truth["scenario-I"]
    known = {"v": 83, "w": 87, "q": 81, "r": 82, "psi": 79, "theta": 42}
    assert {c: truth[c] for c in known} == pytest.approx(known, abs=2.0)
    assert f.speed * (1 - f.speed_loss["scenario-I"] / 100) == pytest.approx(16.4, abs=0.1)
    assert f.peak_pitch["scenario-I"] == pytest.approx(30.0, abs=1.0)
    assert f.peak_pitch_rate["scenario-I"] == pytest.approx(95.0, abs=2.0)
    assert f.lowest_fit_to_truth < known["theta"]  # the lowest is over every excited channel
    assert set(known) <= set(f.excited["scenario-I"])


def test_to_dict_is_json_and_round_trips(fits):
    for _, f in fits.values():
        d = json.loads(json.dumps(f.to_dict(), allow_nan=False))
        assert OpenLoopFit.from_dict(d).to_dict() == d
        assert d["lowest_fit_to_truth"] == pytest.approx(f.lowest_fit_to_truth)
        n, c = d["lowest"]["experiment"], d["lowest"]["channel"]
        assert d["truth"][n][c] == d["lowest_fit_to_truth"] and c in d["excited"][n]
        assert (
            min(d["truth"][n][c] for n in d["excited"] for c in d["excited"][n]) == d["lowest_fit_to_truth"]
        )


def test_a_run_without_its_full_truth_is_a_one_line_error(fits, tmp_path):
    run, _ = fits["II", "linear"]
    broken = tmp_path / "broken"
    broken.mkdir()
    for p in run.iterdir():
        (broken / p.name).write_bytes(p.read_bytes())
    (broken / "roll.truth.csv").unlink()
    with pytest.raises(InputError, match="roll.truth.csv") as exc:
        open_loop_fit(broken)
    assert "\n" not in str(exc.value)
    lines = (run / "roll.truth.csv").read_text().splitlines()
    keep = [i for i, c in enumerate(lines[0].split(",")) if c != "psi"]
    (broken / "roll.truth.csv").write_text(
        "\n".join(",".join(np.array(line.split(","))[keep]) for line in lines) + "\n"
    )
    with pytest.raises(InputError, match="expected every state"):
        open_loop_fit(broken)
