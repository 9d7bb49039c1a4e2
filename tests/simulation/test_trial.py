"""A trial's imperfections in the truth and the named sensors of scenario files
(testbed.simulation.trial, testbed.simulation.sensing): each against its stated definition."""

from __future__ import annotations

import csv
import io
import math
import tomllib

import numpy as np
import pytest

from testbed.cli import main
from testbed.models.linear import INPUTS, IX, STATES
from testbed.models.sensors import rotation
from testbed.simulation.flight import fly_scenario
from testbed.simulation.scenario import SCENARIO_DIR, parse_scenario, scenario, scenario_text
from testbed.simulation.trial import Backlash, Trial, gauss_markov

BASE = """
name = "t"
duration = {duration}
depth = 100.0
control_rate = 50.0

[sensors]
rate = 50.0
fin_std = 0.0
noise_std = {{u = 0.0, v = 0.0, w = 0.0, p = 0.0, q = 0.0, r = 0.0, phi = 0.0, theta = 0.0, psi = 0.0, z = 0.0}}
{extra}

[[experiment]]
name = "e"
rudder = {{signal = "prbs", amplitude = 0.001, order = 10, clock = 0.1}}
elevators = {{signal = "prbs", amplitude = 0.0003, order = 9, clock = 0.1}}
differential = {{signal = "prbs", amplitude = 0.0015, order = 8, clock = 0.1}}
"""


def scen(extra: str = "", duration: float = 6.0):
    return parse_scenario(tomllib.loads(BASE.format(extra=extra, duration=duration)), "t.toml")


def flight(extra: str = "", truth: str = "linear", duration: float = 6.0, seed: int = 1):
    flights, _ = fly_scenario(scen(extra, duration), seed, truth=truth)
    return flights[0]


# -- turbulence: the stated process --------------------------------------------------------------


def test_gauss_markov_has_the_stated_variance_correlation_and_spectrum():
    """σ², the autocorrelation σ² e^{−|t|/τ} and S(ω) = 2σ²τ/(1 + ω²τ²), by Monte Carlo over
    independent records, each within 4 of its own standard errors."""
    sigma, tau, dt, n, m = 3.0, 0.5, 0.01, 2048, 400
    rng = np.random.default_rng(11)
    w = np.stack([gauss_markov(np.array([sigma]), tau, dt, n, rng)[:, 0] for _ in range(m)])
    # variance: the records' first samples are independent N(0, σ²) (stationary start)
    first = w[:, 0]
    assert abs(first.var() - sigma**2) < 4 * sigma**2 * math.sqrt(2 / m)
    # autocorrelation at lags 0.1 and 0.5 s from sample k0 to k0 + lag across records
    for lag in (10, 50):
        prod = w[:, 100] * w[:, 100 + lag]
        assert abs(prod.mean() - sigma**2 * math.exp(-lag * dt / tau)) < 4 * prod.std() / math.sqrt(m)
    # spectrum: the averaged periodogram (two-sided, per rad/s) at low frequencies (ω dt << 1,
    # where the sampled process's spectrum is the continuous one's to 0.1 %)
    f = np.fft.rfft(w, axis=1)
    periodogram = (np.abs(f) ** 2 * dt / n).mean(axis=0)
    omega = 2 * np.pi * np.fft.rfftfreq(n, dt)
    for k in (5, 20, 60):
        S = 2 * sigma**2 * tau / (1 + (omega[k] * tau) ** 2)
        # each ordinate is S χ²₂/2 (relative spread 1): the mean of m has relative error 1/√m;
        # the record's finite length leaks (1/(n dt τ) ~ 0.1 %)
        assert abs(periodogram[k] / S - 1) < 4 / math.sqrt(m) + 0.01


def test_turbulence_forces_both_truths_as_stated():
    """The body-axis sway force's response: the linear truth's and the MuJoCo plant's yaw rate
    under the same turbulence agree (the wrench on the plant, Mt⁻¹ (wrench, 0) in the linear
    model), and without the fins' signals turbulence alone moves the vehicle."""
    extra = "[trial.turbulence]\nforce_std = [0.0, 40.0, 0.0]\nmoment_std = [0.0, 0.0, 12.0]\ntime = 0.5"
    quiet = flight("", "linear")
    lin = flight(extra, "linear")
    r = IX["r"]
    assert np.std(lin.truth[:, r] - quiet.truth[:, r]) > 1e-3  # rad/s: the gusts turn it
    plant_quiet, plant = flight("", "plant"), flight(extra, "plant")
    d_lin = lin.truth[:, r] - quiet.truth[:, r]
    d_plant = plant.truth[:, r] - plant_quiet.truth[:, r]
    # the gust sequences differ (one per plant step: 10 ms against 20 ms), so compare their size
    assert 0.5 < np.std(d_plant) / np.std(d_lin) < 2.0


# -- the current -------------------------------------------------------------------------------


def test_the_vehicle_drifts_with_a_steady_current_and_the_sensors_read_over_ground():
    c = np.array([0.3, -0.2, 0.0])
    still = flight("", "plant", duration=4.0)
    drift = flight("[trial]\ncurrent = [0.3, -0.2, 0.0]", "plant", duration=4.0)
    np.testing.assert_array_equal(drift.truth, still.truth)  # through the water: unchanged
    np.testing.assert_allclose(drift.position - still.position, np.outer(drift.t, c), atol=1e-12)
    # ground velocity = water-relative + current: the track's rate is C v + c
    dt = drift.t[1] - drift.t[0]
    ground = np.diff(drift.position, axis=0) / dt
    x = drift.truth
    C = rotation(x[:, IX["phi"]], x[:, IX["theta"]], x[:, IX["psi"]])
    water = np.einsum("nij,nj->ni", C, x[:, :3])
    np.testing.assert_allclose(ground, 0.5 * (water[1:] + water[:-1]) + c, atol=2e-3)
    # a noise-free sensor at the CG reads the ground velocity in body axes: v + Cᵀ c
    np.testing.assert_allclose(drift.measured[:, :3], x[:, :3] + np.einsum("nji,j->ni", C, c), atol=1e-12)


# -- the fins --------------------------------------------------------------------------------------


def test_fin_offset_is_in_the_record_and_not_in_the_fin():
    offset = {"delta_r": 0.004, "delta_er": -0.002, "delta_el": 0.001}
    base = flight("")
    f = flight("[trial]\nfin_offset = " + "{" + ", ".join(f"{k} = {v}" for k, v in offset.items()) + "}")
    off = np.array([offset[k] for k in INPUTS])
    np.testing.assert_allclose(f.fins_measured - f.fins, np.tile(off, (len(f.t), 1)), atol=1e-15)
    # the servo holds its encoder at the command: the true fin is the command less the offset
    # (the open-loop signals: the commands are the base flight's)
    np.testing.assert_allclose(f.fins[5:], base.fins[5:] - off, atol=1e-12)


def test_fin_log_delay_shifts_the_record():
    """A 20 ms logging delay on the linear truth (20 ms steps): sample k records the fins' mean
    over the interval before (the first: the fins at rest)."""
    f = flight("[trial]\nfin_log_delay = 0.02")
    np.testing.assert_allclose(f.fins_measured[1:-1], f.fins[:-2], atol=1e-15)
    np.testing.assert_array_equal(f.fins_measured[0], np.zeros(3))


def test_actuator_delay_shifts_the_fins():
    base = flight("")
    f = flight("[trial]\nactuator_delay = 0.04")
    np.testing.assert_allclose(f.fins[2:], base.fins[:-2], atol=1e-15)
    assert np.abs(f.fins[2:] - base.fins[2:]).max() > 1e-4


def test_backlash_is_a_dead_band():
    b = Backlash(0.2, np.zeros(1))
    cmd = np.concatenate([np.linspace(0, 1, 11), np.linspace(1, -1, 21)])
    out = np.array([b(np.array([c]))[0] for c in cmd])
    # rising: 0.1 behind once past the half band; after the reversal it holds until the command
    # is 0.2 below its peak, then follows 0.1 above it
    np.testing.assert_allclose(out[:11], np.maximum(cmd[:11] - 0.1, 0.0), atol=1e-15)
    np.testing.assert_allclose(out[11:], np.minimum(cmd[11:] + 0.1, 0.9), atol=1e-15)


# -- the loads -----------------------------------------------------------------------------------


def test_loads_of_the_weight_excess_cg_offset_and_propeller_torque():
    t = Trial(weight_excess=5.0, cg_offset=(0.01, 0.002, 0.0), roll_moment=3.0)
    W = 1000.0
    level = np.zeros(10)
    # level: the weight's excess straight down; the CG forward pitches the nose down (M < 0), to
    # starboard rolls to starboard (K > 0)
    np.testing.assert_allclose(
        t.loads(level, W), [0, 0, 5.0, 3.0 + 0.002 * 1005.0, -0.01 * 1005.0, 0], atol=1e-12
    )
    pitched = np.zeros(10)
    pitched[IX["theta"]] = 0.3  # nose up: down is (−sin θ, 0, cos θ) in body axes
    down = np.array([-math.sin(0.3), 0.0, math.cos(0.3)])
    np.testing.assert_allclose(
        t.loads(pitched, W),
        [*(5.0 * down), *(np.cross([0.01, 0.002, 0.0], 1005.0 * down) + [3.0, 0, 0])],
        atol=1e-12,
    )


def test_propeller_torque_rolls_both_truths_alike():
    """A constant roll moment with no roll autopilot: the MuJoCo plant (its wrench) and the linear
    truth (Mt⁻¹ forcing) roll to the same angle; the hydrostatic restoring moment W·BG sets it."""
    lin = flight("[trial]\nroll_moment = 2.0", "linear", duration=10.0)
    plant = flight("[trial]\nroll_moment = 2.0", "plant", duration=10.0)
    base_lin, base_plant = flight("", "linear", duration=10.0), flight("", "plant", duration=10.0)
    phi = IX["phi"]
    d_lin = lin.truth[-50:, phi] - base_lin.truth[-50:, phi]
    d_plant = plant.truth[-50:, phi] - base_plant.truth[-50:, phi]
    assert d_lin.mean() > 0.02  # rad: it rolls to starboard
    assert abs(d_plant.mean() / d_lin.mean() - 1) < 0.1


# -- the named sensors -----------------------------------------------------------------------------


def test_sensor_delay_and_rate_sample_the_truth_at_their_times():
    """A depth sensor 30 ms late (between two 20 ms steps of the linear truth) at 10 Hz: its
    samples, every fifth row, are the truth's depth interpolated 30 ms earlier; the CSV leaves the
    other rows empty."""
    extra = '[sensors.depth]\noutputs = ["z"]\ndelay = 0.03\nrate = 10.0\nnoise_std = {z = 0.0}'
    f = flight(extra)
    z = f.measured[:, IX["z"]]
    rows = np.arange(0, len(f.t), 5)
    assert np.isnan(np.delete(z, rows)).all()
    expected = np.interp(f.t[rows] - 0.03, f.t, f.truth[:, IX["z"]])
    np.testing.assert_allclose(z[rows], expected, atol=1e-12)
    assert np.abs(expected - f.truth[rows, IX["z"]]).max() > 1e-5  # the delay shows


def test_run_csv_leaves_the_slow_sensors_fields_empty(tmp_path):
    path = tmp_path / "s.toml"
    extra = '[sensors.dvl]\noutputs = ["u", "v", "w"]\nposition = [0.3, 0.0, 0.1]\nrate = 10.0\n'
    extra += '[sensors.acc]\noutputs = ["ax", "ay", "az"]\n'
    path.write_text(BASE.format(extra=extra, duration=1.0))
    out = tmp_path / "run"
    assert (
        main(
            [
                "simulate",
                "--scenario",
                str(path),
                "--seed",
                "2",
                "--out",
                str(out),
                "--truth",
                "linear",
                "--quiet",
            ]
        )
        == 0
    )
    rows = list(csv.reader(io.StringIO((out / "e.csv").read_text())))
    header = rows[0]
    assert header == ["t", *STATES, "ax", "ay", "az", *INPUTS]
    for k, row in enumerate(rows[1:]):
        for name in ("u", "v", "w"):
            assert (row[header.index(name)] == "") == (k % 5 != 0), (k, name)
        assert all(row[header.index(n)] != "" for n in ("p", "z", "ax", "delta_r"))
    truth = list(csv.reader(io.StringIO((out / "e.truth.csv").read_text())))
    assert truth[0] == ["t", *STATES, *INPUTS] and all("" not in r for r in truth)
    # the accelerometers read v̇ + ω × v − Cᵀ g at the CG (v̇ from the truth's differences)
    x = np.array(truth[1:], float)[:, 1:11]
    acc = np.array([[float(r[header.index(n)]) for n in ("ax", "ay", "az")] for r in rows[1:]])
    vdot = np.gradient(x[:, :3], 0.02, axis=0)
    C = rotation(x[:, IX["phi"]], x[:, IX["theta"]], x[:, IX["psi"]])
    f = vdot + np.cross(x[:, 3:6], x[:, :3]) - 9.81 * C[:, 2, :]
    residual = (acc - f)[2:-2]  # the ends: one-sided differences
    assert np.abs(residual.mean(axis=0)).max() < 4 * 0.01 / math.sqrt(len(residual)) + 2e-3
    assert 0.007 < residual.std() < 0.013  # the accelerometers' noise, 0.01 m/s²


def test_an_ideal_named_sensor_flies_the_same_truth():
    """The imperfect path (one plant step at a time) flies exactly the perfect path's truth."""
    a = flight("", "plant", duration=3.0)
    b = flight('[sensors.dvl]\noutputs = ["u"]', "plant", duration=3.0)
    np.testing.assert_array_equal(a.truth, b.truth)
    np.testing.assert_array_equal(a.fins, b.fins)
    np.testing.assert_array_equal(np.delete(a.measured, 0, 1), np.delete(b.measured, 0, 1))


def test_ii_trial_round_trips_through_its_scenario_text():
    s = scenario("II-trial")
    from dataclasses import replace

    flown = replace(s, source="")
    assert parse_scenario(tomllib.loads(scenario_text(flown)), "") == flown
    assert not s.is_perfect and s.columns[-3:] == ("ax", "ay", "az")
    dotted = replace(flown, named_sensors=(replace(flown.named_sensors[0], name="dvl 2.b"),))
    assert parse_scenario(tomllib.loads(scenario_text(dotted)), "") == dotted
    # every other built-in but the lake trial's logger stays perfect: its scenario.toml has no new table
    for p in SCENARIO_DIR.glob("*.toml"):
        if p.stem not in ("II-trial", "lake"):
            other = scenario(p.stem)
            assert other.is_perfect and "[trial]" not in scenario_text(other)


# -- bad input -------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "extra, words",
    [
        ("[sensors.dvl]\nposition = [0, 0, 0]", ["sensors.dvl.outputs"]),
        ('[sensors.dvl]\noutputs = ["u", "speed"]', ["sensor 'dvl'", "outputs"]),
        ('[sensors.dvl]\noutputs = ["u"]\nposition = [0, 0]', ["sensors.dvl.position"]),
        ('[sensors.dvl]\noutputs = ["u"]\nposition = [0, 0, "a"]', ["sensors.dvl.position"]),
        ('[sensors.dvl]\noutputs = ["u"]\nmisalignment = [0, 0, 2]', ["misalignment"]),
        ('[sensors.dvl]\noutputs = ["u", "v", "w"]\nframe = "ned"', ["frame"]),
        ('[sensors.dvl]\noutputs = ["u"]\nbias = {v = 1.0}', ["bias.v"]),
        ('[sensors.dvl]\noutputs = ["u"]\nbias = 3', ["sensors.dvl.bias"]),
        ('[sensors.dvl]\noutputs = ["u"]\nscale = {u = -2.0}', ["scale.u"]),
        ('[sensors.dvl]\noutputs = ["u"]\ndelay = -1.0', ["delay"]),
        ('[sensors.dvl]\noutputs = ["u"]\nrate = 7.0', ["sensors.dvl.rate"]),
        ('[sensors.dvl]\noutputs = ["u"]\nrate = 0.0', ["rate"]),
        ('[sensors.dvl]\noutputs = ["u"]\nnoise_std = {u = -1.0}', ["noise_std.u"]),
        ('[sensors.dvl]\noutputs = ["u"]\ncolour = 1', ["unknown key 'colour'"]),
        ('[sensors.a]\noutputs = ["u"]\n[sensors.b]\noutputs = ["u"]', ["sensors.b outputs u"]),
        ('[sensors."a/b"]\noutputs = ["u"]', ["sensor name"]),
        ("[trial]\nfin_offset = {delta_x = 0.001}", ["trial.fin_offset.delta_x"]),
        ("[trial]\nfin_offset = {delta_r = 1.0}", ["trial.fin_offset.delta_r"]),
        ("[trial]\nfin_offset = 0.001", ["trial.fin_offset"]),
        ("[trial]\nfin_log_delay = -0.1", ["trial.fin_log_delay"]),
        ("[trial]\nactuator_delay = 5.0", ["trial.actuator_delay"]),
        ("[trial]\nbacklash = true", ["trial.backlash"]),
        ("[trial]\ncurrent = [0.3, 0.0]", ["trial.current"]),
        ("[trial]\ncurrent = [30.0, 0.0, 0.0]", ["trial.current"]),
        ('[trial]\nroll_moment = "big"', ["trial.roll_moment"]),
        ("[trial]\nweight_excess = nan", ["trial.weight_excess"]),
        ("[trial]\ncg_offset = [1.0, 0.0, 0.0]", ["trial.cg_offset"]),
        ("[trial]\nwaves = 1.0", ["unknown key 'waves'"]),
        ("[trial]\nturbulence = 1.0", ["trial.turbulence"]),
        ("[trial.turbulence]\nforce_std = [1.0, -1.0, 0.0]", ["trial.turbulence.force_std"]),
        ("[trial.turbulence]\nmoment_std = [1.0]", ["trial.turbulence.moment_std"]),
        ("[trial.turbulence]\ntime = 0.0", ["trial.turbulence.time"]),
        ("[trial.turbulence]\nspectrum = 1", ["unknown key 'spectrum'"]),
        ("trial = 3", ["trial"]),
    ],
)
def test_every_new_scenario_field_is_refused_in_one_line_naming_it(tmp_path, capsys, extra, words):
    path = tmp_path / "s.toml"
    text = BASE.format(extra=extra, duration=1.0)
    if extra.startswith("trial ="):  # a top-level key: before any table
        text = extra + "\n" + BASE.format(extra="", duration=1.0)
    path.write_text(text)
    code = main(["simulate", "--scenario", str(path), "--out", str(tmp_path / "run"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1, err
    assert "s.toml" in err
    for w in words:
        assert w in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.toml"]
