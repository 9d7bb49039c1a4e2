"""The built-in lake trial: a small AUV's logger, tested on the CSV text it writes.

Each property is checked against an independent replay: the stamps against the alternating
steps written out, every named sensor's column against the truth at its own sample stamps with
its noise drawn again from its documented random stream (`sensing.SENSOR_STREAM` + its index),
the truth and the fins against the same dives flown and logged uniformly at 10 Hz.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from testbed.cli import main
from testbed.data import read_config
from testbed.errors import InputError
from testbed.models.linear import STATES, continuous, structure, theta_vector
from testbed.simulation.measurements import rng_for
from testbed.simulation.runs import simulate
from testbed.simulation.flight import fly_scenario
from testbed.simulation.scenario import scenario
from testbed.simulation.sensing import SENSOR_STREAM

SEED = 3
LAKE = scenario("lake")
SENSORS = {s.name: s for s in LAKE.named_sensors}
COLUMNS = ["t", "u", "v", "w", "phi", "theta", "psi", "z", "delta_r", "delta_er", "delta_el"]


def _short(s=LAKE):
    """Two of the dives (a course-rate step; a depth step during a turn), as the test's scenario."""
    return replace(s, experiments=(s.experiments[1], s.experiments[6]))


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    return simulate(_short(), seed=SEED, out=tmp_path_factory.mktemp("lake") / "run"), _short()


def _table(path):
    lines = path.read_text().splitlines()
    return lines[0].split(","), [line.split(",") for line in lines[1:]]


def _values(rows, header, names):
    return np.array([[float(r[header.index(n)]) for n in names] for r in rows])


def test_rows_fall_exactly_on_the_alternating_stamps_in_both_csvs(run):
    out, s = run
    for e in s.experiments:
        header, rows = _table(out / f"{e.name}.csv")
        truth_header, truth_rows = _table(out / f"{e.name}.truth.csv")
        assert header == COLUMNS  # no p, q, r: no rate gyros
        assert truth_header == ["t", *STATES, "delta_r", "delta_er", "delta_el"]
        # t = 0, 0.4, 1, 1.4, 2, ... up to the dive's duration, as the logger writes them
        n = 2 * math.floor(e.duration) + 1 + (e.duration % 1 >= 0.4)
        expected = [f"{i // 2}" if i % 2 == 0 else f"{i // 2}.4" for i in range(n)]
        assert [r[0] for r in rows] == expected
        assert [r[0] for r in truth_rows] == expected


def test_the_dvl_holds_its_ping_between_rows_quantised_to_its_resolution(run):
    out, s = run
    dvl = SENSORS["dvl"]
    assert dvl.rate == 1.0 and dvl.hold and set(dvl.resolution.values()) == {0.001}
    k_dvl = [x.name for x in s.named_sensors].index("dvl")
    for k, e in enumerate(s.experiments):
        header, rows = _table(out / f"{e.name}.csv")
        truth_header, truth_rows = _table(out / f"{e.name}.truth.csv")
        pings = np.arange(0, len(rows), 2)  # the rows at whole seconds
        truth = _values(truth_rows, truth_header, ["u", "v", "w"])[pings]
        noise = rng_for(SEED, k, SENSOR_STREAM + k_dvl).standard_normal(truth.shape) * 0.005
        expected = np.round((truth + noise) / 0.001) * 0.001
        logged = _values(rows, header, ["u", "v", "w"])
        np.testing.assert_allclose(logged[pings], expected, rtol=0, atol=1e-12)
        np.testing.assert_allclose(logged * 1000, np.round(logged * 1000), rtol=0, atol=1e-9)
        for i in range(1, len(rows), 2):  # the row between repeats the ping's text, bit for bit
            assert rows[i][1:4] == rows[i - 1][1:4]
        # while the other channels change at every row
        assert all(rows[i][4:8] != rows[i - 1][4:8] for i in range(1, len(rows)))


def test_attitude_reads_the_truth_plus_its_offsets_and_depth_the_truth(run):
    out, s = run
    names = [x.name for x in s.named_sensors]
    ahrs = SENSORS["ahrs"]
    offsets = np.array([ahrs.bias[a] for a in ("phi", "theta", "psi")])
    assert offsets[0] == pytest.approx(math.radians(7.0), abs=1e-4)  # 7 deg of roll at rest
    for k, e in enumerate(s.experiments):
        header, rows = _table(out / f"{e.name}.csv")
        truth_header, truth_rows = _table(out / f"{e.name}.truth.csv")
        attitude = _values(truth_rows, truth_header, ["phi", "theta", "psi"])
        noise = rng_for(SEED, k, SENSOR_STREAM + names.index("ahrs")).standard_normal(attitude.shape)
        expected = attitude + offsets + noise * [0.003, 0.003, 0.01]
        logged = _values(rows, header, ["phi", "theta", "psi"])
        np.testing.assert_allclose(logged, expected, rtol=0, atol=1e-9)
        depth = _values(truth_rows, truth_header, ["z"])
        noise = rng_for(SEED, k, SENSOR_STREAM + names.index("depth")).standard_normal(depth.shape)
        np.testing.assert_allclose(_values(rows, header, ["z"]), depth + 0.02 * noise, rtol=0, atol=1e-8)


def test_truth_and_fins_are_those_of_the_same_dives_logged_uniformly(run):
    """The same dives flown and logged at 10 Hz (the control rate): the lake log's truth is the
    uniform log's at its stamps, and each row's fin angle the mean of the uniform log's interval
    means over its own 0.4 or 0.6 s (the last row: the angle then)."""
    out, s = run
    uniform = replace(s, sensors=replace(s.sensors, steps=None, rate=10.0))
    flights, _ = fly_scenario(uniform, SEED)
    for e, f in zip(s.experiments, flights):
        header, rows = _table(out / f"{e.name}.truth.csv")
        t = _values(rows, header, ["t"])[:, 0]
        at = np.round(t * 10).astype(int)
        np.testing.assert_allclose(_values(rows, header, STATES), f.truth[at], rtol=1e-9, atol=1e-12)
        fins = _values(rows, header, ["delta_r", "delta_er", "delta_el"])
        means = [f.fins[a:b].mean(axis=0) for a, b in zip(at[:-1], at[1:])] + [f.fins[-1]]
        np.testing.assert_allclose(fins, means, rtol=1e-9, atol=1e-12)
        logged_header, logged = _table(out / f"{e.name}.csv")
        encoder = _values(logged, logged_header, ["delta_r", "delta_er", "delta_el"]) - fins
        assert np.abs(encoder).max() < 5 * s.sensors.fin_std  # the fins read with their encoders' noise


def test_the_prior_beside_the_run_is_course_unstable_at_0_8(run):
    out, _ = run
    model, prior = read_config(out / "model.toml"), read_config(out / "prior.toml")

    def largest(config):
        A, _, _ = continuous(structure(config.vehicle), theta_vector(config.coefficients))
        return np.linalg.eigvals(A).real.max()

    assert largest(model) <= 1e-9  # the analytic model: stable but for its integrators
    assert largest(prior) == pytest.approx(0.80, abs=0.02)
    scaled = {k for k in model.coefficients if prior.coefficients[k] != model.coefficients[k]}
    assert scaled == set(LAKE.prior.scale) == {"Y_v", "N_v", "N_r", "Z_w", "M_q"}
    for k, factor in LAKE.prior.scale.items():
        assert prior.coefficients[k] == pytest.approx(factor * model.coefficients[k], rel=1e-12)
    assert prior.free == model.free + ("X_u", "b_phi", "b_theta", "b_psi") and prior.screen
    assert prior.vehicle == model.vehicle and prior.outputs == model.outputs == (
        "u",
        "v",
        "w",
        "phi",
        "theta",
        "psi",
    )
    assert (out / "prior.toml").read_text().startswith("# The a-priori model of this run")


BASE = """name = "s"
duration = 3.0
control_rate = 10.0
[sensors]
{sensors}
[[experiment]]
name = "x"
autopilot = {{depth = 0.0}}
"""


@pytest.mark.parametrize(
    "sensors, words",
    [
        ("rate = 5.0\nsteps = [0.4, 0.6]", ["sensors: rate and steps"]),
        ("steps = []", ["sensors: steps"]),
        ("steps = 0.5", ["sensors: steps"]),
        ("steps = [0.4, -0.6]", ["sensors: steps"]),
        ('steps = [0.4, "a"]', ["sensors: steps"]),
        ("steps = [0.4, 0.65]", ["sensors.steps = [0.4, 0.65]: 0.65 s", "control periods"]),
        ("steps = [0.4, 0.6]\nfin_rate = 20.0", ["sensors.fin_rate"]),
        ('steps = [0.4, 0.6]\n[sensors.dvl]\noutputs = ["u"]\nrate = 2.5', ["sensors.dvl.rate = 2.5"]),
        ('[sensors.dvl]\noutputs = ["u"]\nhold = 1', ["sensor 'dvl': hold 1"]),
        ('[sensors.dvl]\noutputs = ["u"]\nresolution = {u = 0.0}', ["resolution.u"]),
        ('[sensors.dvl]\noutputs = ["u"]\nresolution = {v = 0.001}', ["resolution.v"]),
        ('[sensors.dvl]\noutputs = ["u"]\nresolution = 0.001', ["sensors.dvl.resolution"]),
        ("[prior]\nscale = {N_x = 2.0}", ["prior.scale.N_x"]),
        ('[prior]\nscale = {N_r = "a"}', ["prior.scale.N_r"]),
        ("[prior]\nscale = 2.0", ["prior.scale"]),
        ('[prior]\nfree = ["b_q", "b_q"]', ["prior.free"]),
        ('[prior]\nfree = ["X_y"]', ["prior.free names 'X_y'"]),
        ("[prior]\nmodel = 1", ["prior: unknown key 'model'"]),
    ],
)
def test_every_logger_field_is_refused_in_one_line_naming_it(tmp_path, capsys, sensors, words):
    path = tmp_path / "s.toml"
    path.write_text(BASE.format(sensors=sensors))  # a [prior] table follows an empty [sensors]
    code = main(["simulate", "--scenario", str(path), "--out", str(tmp_path / "run"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1, err
    assert "s.toml" in err
    for w in words:
        assert w in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.toml"]


def test_a_record_at_steps_counts_its_stamps_before_flying():
    s = replace(LAKE, experiments=LAKE.experiments[:1])
    assert [s.sample_count(d) for d in (0.0, 0.39, 0.4, 0.99, 1.0, 1.4, 20.0)] == [1, 1, 2, 2, 3, 4, 41]
    t, at = s.stamps(20.0)
    assert at.tolist()[:6] == [0, 4, 10, 14, 20, 24] and t[-1] == 20.0 and len(t) == 41
    short = replace(s, duration=0.4, experiments=(replace(s.experiments[0], duration=None),))
    with pytest.raises(
        InputError, match=r"duration = 0.4 .*expected 3 to 1000000 samples at steps \[0.4, 0.6\] s"
    ):
        simulate(short, out="/nonexistent/x")


@pytest.mark.slow
def test_the_full_lake_trial(tmp_path):
    """The 16 dives as built: one record each, 20-26 s, and the prior beside them."""
    out = simulate("lake", seed=1, out=tmp_path / "lake1")
    csvs = sorted(p.name for p in out.glob("dive-*.csv") if not p.name.endswith(".truth.csv"))
    assert csvs == [f"dive-{k:02d}.csv" for k in range(1, 17)]
    for e in LAKE.experiments:
        header, rows = _table(out / f"{e.name}.csv")
        assert 20.0 <= e.duration <= 26.0 and header == COLUMNS
        assert float(rows[-1][0]) <= e.duration < float(rows[-1][0]) + 0.6
    assert (out / "prior.toml").exists()
    # regenerated by name: the built-in as it is (its dives keep their own durations)
    assert json.loads((out / "manifest.json").read_text())["command"] == (
        "testbed simulate --seed 1 --scenario lake --speed 2.0"
    )


STEPPED = """name = "stepped"
duration = 6.0
speed = 2.0
control_rate = 10.0
[sensors]
steps = [0.4, 0.6]
fin_std = 0.0
{trial}
[[experiment]]
name = "x"
autopilot = {{depth = 0.0, roll = 0.0, yaw_rate = {{signal = "square", amplitude = 0.03, half_period = 1.3}}}}
"""


@pytest.mark.parametrize("trial, delay", [("", 0), ("[trial]\nfin_log_delay = 0.1", 1)])
def test_stepped_fins_are_each_rows_interval_mean_logged_late_by_the_trials_delay(trial, delay):
    """Without named sensors (the default sensor's path) and with a [trial]'s fin log delay of one
    control period: row i's recorded fin is the fins' mean over [t_i − d, t_i+1 − d), from the
    same flight logged uniformly at 10 Hz (before the start the fins were at 0)."""
    import tomllib

    from testbed.simulation.scenario import parse_scenario

    s = parse_scenario(tomllib.loads(STEPPED.format(trial=trial)), "stepped.toml")
    (f,), _ = fly_scenario(s, 2, truth="linear")
    (g,), _ = fly_scenario(replace(s, sensors=replace(s.sensors, steps=None, rate=10.0)), 2, truth="linear")
    at = np.round(f.t * 10).astype(int)
    assert at.tolist()[:5] == [0, 4, 10, 14, 20] and f.t[-1] == 6.0
    np.testing.assert_array_equal(f.truth, g.truth[at])
    late = np.vstack([np.zeros((delay, 3)), g.fins])  # the uniform log's interval means, d late
    means = [late[a:b].mean(axis=0) for a, b in zip(at[:-1], at[1:])]
    np.testing.assert_allclose(f.fins_measured[:-1], means, rtol=1e-9, atol=1e-15)
    assert np.abs(f.fins_measured[:-1]).max() > 1e-3  # the rudder moved
