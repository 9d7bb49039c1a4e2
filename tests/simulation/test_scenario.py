"""Scenarios: scenario files, the paper's command definitions, autopilots, PRBS, run directories."""

import hashlib
import json
import math
import os
import shlex
import shutil
import signal
import tomllib
from dataclasses import replace

import numpy as np
import pytest

from testbed.simulation import runs
from testbed.simulation import flight as fl
from testbed.simulation import scenario as sc
from testbed.simulation import signals as sig
from testbed.arguments import BUILTIN_SCENARIOS
from testbed.cli import main
from testbed.data import load_data
from testbed.errors import InputError
from testbed.simulation.measurements import rng_for
from testbed.models.linear import IX
from testbed.simulation.analytic import analytic_model
from testbed.simulation.autopilot import Autopilot
from testbed.simulation.trial import parse_trial
from testbed.simulation.vehicle import fin_limits, fin_rate_limit, load_model


def _short(name, duration):
    return sc.scenario(name).with_overrides(duration=duration)


def test_scenario_i_commands_are_the_papers():
    s = sc.scenario("I")
    program = fl.program(s, s.experiments[0], seed=0, index=0)
    x = np.zeros(10)
    for k in range(1500):  # the control instants k / 50 Hz
        c = program(k * 0.02, x)
        assert c["depth"] == 100.0 + 20.0 * (k // 250 % 2)  # 20 m every 5 s
        assert c["yaw_rate"] == pytest.approx(math.radians(20) * (1 if k // 75 % 2 == 0 else -1))  # 1.5 s
        assert c["roll"] == 0.0


def test_scenario_i_is_flown_not_toned_down():
    (flight,), _ = fl.fly_scenario(_short("I", 12.0))
    r, z = flight.truth[:, IX["r"]], flight.truth[:, IX["z"]]
    assert r.max() > 0.85 * math.radians(20) and r.min() < -0.85 * math.radians(20)
    assert z.max() - z.min() > 15.0


@pytest.mark.parametrize("order", range(3, 13))
def test_prbs_is_maximal_length_and_balanced(order):
    bits = sig.prbs(order, np.random.default_rng(order))
    n = 2**order - 1
    assert len(bits) == n and bits.sum() == 1  # one more +1 than −1
    twice = np.concatenate([bits, bits])
    # the periodic autocorrelation of an m-sequence is n at lag 0 and −1 elsewhere
    corr = np.array([twice[k : k + n] @ bits for k in range(n)])
    assert corr[0] == n and np.all(corr[1:] == -1)


def test_prbs_spectrum_covers_the_vehicle_bandwidth():
    s = sc.scenario("II")
    prbs = [e.fins[c] for e in s.experiments for c in e.fins if isinstance(e.fins[c], sig.Prbs)]
    assert len(prbs) == 3 and len({(p.order, p.clock) for p in prbs}) == 1
    A = analytic_model(load_model(), 20.0).A_full
    poles = [abs(np.linalg.eigvals(A[np.ix_(i, i)])) for i in ([1, 5], [2, 4, 7])]  # v,r; w,q,θ
    fastest, slowest = max(p.max() for p in poles) / (2 * np.pi), min(p.min() for p in poles) / (2 * np.pi)
    f, power = sig.prbs_spectrum(prbs[0].order, prbs[0].clock)
    flat = f[power >= 0.5 * power[0]]  # within 3 dB of the lowest line
    assert flat.max() > fastest  # covers the fastest sway-yaw and heave-pitch poles
    assert f[0] < 0.1 * fastest and slowest > 0
    assert (2 ** prbs[0].order - 1) * prbs[0].clock >= s.duration  # no repeat within an experiment


def test_scenario_ii_horizontal_holds_depth_while_the_rudder_follows_the_prbs():
    s = _short("II", 20.0)
    horizontal, _, _ = fl.fly_scenario(s, seed=3)[0]
    z = horizontal.truth[:, IX["z"]]
    assert np.abs(z - 100.0).max() < 0.2  # depth held while the rudder is excited
    rudder = s.experiments[0].fins["rudder"]
    bits = sig.prbs(rudder.order, rng_for(3, 0, 1))[np.arange(len(horizontal.t)) // 5]  # 5 samples a bit
    assert np.array_equal(horizontal.commands["rudder"], rudder.amplitude * bits)
    assert np.array_equal(horizontal.commands["fin_r"], horizontal.commands["rudder"])


def _power_above(signal, dt, f_min):
    f = np.fft.rfftfreq(len(signal), dt)
    return (np.abs(np.fft.rfft(signal - signal.mean())) ** 2)[f > f_min].sum()


@pytest.mark.parametrize("seed", [0, 9])  # two PRBS phases
def test_scenario_ii_vertical_elevators_follow_the_prbs(seed):
    """Both elevators follow the PRBS, the slow hold adding only what keeps pitch and depth
    bounded and steps the depth by 3 m every 15 s: the PRBS dominates the elevators above
    0.1 Hz."""
    s = sc.scenario("II")
    _, f, _ = fl.fly_scenario(s, seed=seed)[0]
    dt, e = 1.0 / s.sensors.rate, s.experiments[1].fins["elevators"]
    prbs = e.amplitude * sig.prbs(e.order, rng_for(seed, 1, 2))[np.arange(len(f.t)) // 5]
    assert np.array_equal(f.commands["elevators"], prbs)
    assert np.array_equal(f.commands["fin_er"], f.commands["fin_el"])  # equal commands
    assert np.abs(f.fins[:, 1] - f.fins[:, 2]).max() < 1e-12  # equal deflections
    assert np.abs(f.commands["fin_r"]).max() == 0.0 and np.abs(f.fins[:, 0]).max() == 0.0  # rudder fixed
    elevator, correction = f.fins[:, 1], f.commands["fin_er"] - prbs
    assert np.corrcoef(elevator, prbs)[0, 1] >= 0.9
    # the hold's depth steps put their edges above 0.1 Hz too: 1.8 % of the PRBS there (seeds 0, 9)
    assert _power_above(correction, dt, 0.1) < 0.03 * _power_above(prbs, dt, 0.1)
    assert np.abs(f.truth[:, IX["theta"]]).max() < 0.05  # rad: small pitch ...
    z = f.truth[:, IX["z"]] - s.depth
    assert np.abs(z).max() < 5.0 and z.max() > 2.0  # ... and depth, which does step


def test_scenario_ii_roll_moves_the_elevators_differentially_only():
    """The roll experiment's PRBS on the elevators' difference, depth held by their sum, rudder
    fixed: an input for the roll row that no autopilot correlates with the states."""
    s = _short("II", 20.0)
    _, _, f = fl.fly_scenario(s, seed=2)[0]
    a = s.experiments[2].fins["differential"]
    prbs = a.amplitude * sig.prbs(a.order, rng_for(2, 2, 3))[np.arange(len(f.t)) // 5]
    assert np.array_equal(f.commands["differential"], prbs)
    difference = 0.5 * (f.commands["fin_er"] - f.commands["fin_el"])
    assert np.allclose(difference, prbs, atol=1e-12)
    assert np.abs(f.fins[:, 0]).max() == 0.0
    assert np.abs(f.truth[:, IX["p"]]).max() > 0.02 and np.abs(f.truth[:, IX["phi"]]).max() < 0.2
    assert np.abs(f.truth[:, IX["z"]] - s.depth).max() < 0.2


def test_turning_circle_reaches_a_steady_yaw_rate_at_the_commanded_rudder():
    s = _short("turn", 8.0)
    (f,), _ = fl.fly_scenario(s)
    rudder = s.experiments[0].fins["rudder"].value
    steady = f.t >= 5.0
    r = f.truth[steady, IX["r"]]
    assert r.mean() < -0.04  # a positive rudder turns to port (2.8 deg/s on 0.11 deg)
    assert np.ptp(r) < 0.01 * abs(r.mean())  # steady
    assert np.all(f.commands["rudder"] == rudder) and np.all(f.commands["fin_r"] == rudder)
    assert np.allclose(f.fins[steady, 0], rudder, rtol=0, atol=1e-12)  # the servo holds it
    assert np.abs(f.truth[:, IX["z"]] - s.depth).max() < 0.5  # depth held
    assert np.abs(f.truth[:, IX["phi"]]).max() < 0.05  # roll held


def _zigzag_commands(angle, fin, switch):
    """The zigzag rule replayed on the flown `angle` (from its initial value): +fin first, to
    −fin when the angle reaches −switch, back to +fin when it reaches +switch."""
    out, sign = [], 1.0
    for a in angle - angle[0]:
        if sign > 0 and a <= -switch:
            sign = -1.0
        elif sign < 0 and a >= switch:
            sign = 1.0
        out.append(sign * fin)
    return np.array(out)


@pytest.mark.parametrize(
    "scenario, state, fin, keyword",
    [("zigzag", "psi", 0, "rudder"), ("zigzag-vertical", "theta", 1, "elevators")],
)
def test_zigzag_switches_the_fins_when_the_angle_passes_the_switching_angle(scenario, state, fin, keyword):
    s = _short(scenario, 12.0)
    (f,), _ = fl.fly_scenario(s)
    limit, switch = s.experiments[0].fins[keyword].angle, s.experiments[0].fins[keyword].switch
    angle = f.truth[:, IX[state]]
    command = f.commands[keyword]
    assert np.array_equal(command, _zigzag_commands(angle, limit, switch))  # switched on time
    switches = np.flatnonzero(np.diff(command))
    assert len(switches) >= 3  # a real zigzag, not one turn
    assert command[0] == limit  # first to negative heading / nose down
    # between switches the fin reaches the commanded angle
    for a, b in zip(switches[:-1], switches[1:]):
        assert np.abs(f.fins[a + 1 : b + 1, fin] - command[a + 1]).min() < 1e-12
    if scenario == "zigzag":
        assert np.abs(f.truth[:, IX["z"]] - s.depth).max() < 0.5  # depth held
    else:
        assert np.abs(f.fins[:, 0]).max() < 1e-9 and np.abs(f.fins[:, 1] - f.fins[:, 2]).max() < 1e-9


def _files(run):
    return {p.name: p.read_bytes() for p in run.iterdir() if p.suffix in (".csv", ".toml")}


def test_run_directory_is_complete_and_its_command_regenerates_it(tmp_path, capsys):
    a = runs.simulate("II", seed=5, out=tmp_path / "a", duration=6.0)
    c = runs.simulate("II", seed=6, out=tmp_path / "c", duration=6.0)
    names = {f"{e}{s}" for e in ("horizontal", "vertical", "roll") for s in (".csv", ".truth.csv")}
    assert {p.name for p in a.iterdir()} == names | {
        "model.toml",
        "scenario.toml",
        "recording.rrd",
        "manifest.json",
    }
    manifest = json.loads((a / "manifest.json").read_text())
    argv = shlex.split(manifest["command"])
    assert (
        argv[:2] == ["testbed", "simulate"]
        and "--scenario" in argv
        and argv[argv.index("--scenario") + 1] == "II"
    )
    assert main(argv[1:] + ["--quiet", "--out", str(tmp_path / "b")]) == 0
    assert _files(a) == _files(tmp_path / "b")  # the recorded command: identical bytes
    assert _files(a)["horizontal.csv"] != _files(c)["horizontal.csv"]  # other seed: other noise
    assert manifest["mjcf_sha256"] == hashlib.sha256(open(manifest["mjcf"], "rb").read()).hexdigest()
    assert manifest["settings"] == tomllib.loads((a / "scenario.toml").read_text())
    assert manifest["settings"]["duration"] == 6.0 and manifest["settings"]["speed"] == 20.0
    assert manifest["seed"] == 5 and manifest["scenario"] == "II"
    assert {"mujoco", "numpy", "rerun-sdk"} <= set(manifest["versions"])
    experiments, config = load_data([a])
    assert [e.name for e in experiments] == ["horizontal", "vertical", "roll"]
    assert config.vehicle.speed == pytest.approx(20.0) and len(experiments[0].t) == 301  # 6 s at 50 Hz
    assert config.outputs == ("u", "v", "w", "p", "q", "r", "phi", "theta", "psi")  # depth: validated only
    assert "depth is measured but not fitted" in (a / "model.toml").read_text()


def test_a_scenario_file_written_by_hand_drives_a_run(tmp_path):
    """Every signal kind, autopilot loops and sensors from a hand-written file; the run's
    scenario.toml, given back to simulate, flies the same run."""
    path = tmp_path / "mine.toml"
    path.write_text("""
name = "mine"
description = "a hand-written test"
duration = 4.0
depth = 60.0
speed = 15.0
control_rate = 50.0

[sensors]
rate = 25.0
fin_std = 0.0
noise_std = {u = 0.0, z = 0.1}
measured = ["v", "r", "psi", "z"]

[[experiment]]
name = "doublet-and-3211"
rudder = {signal = "doublet", amplitude = 0.01, width = 0.5, start = 0.5}
differential = {signal = "3211", amplitude = 0.002, unit = 0.2, start = 1.0}
autopilot = {depth = {signal = "step", amplitude = 2.0, start = 2.0}}

[[experiment]]
name = "multisine"
duration = 3.0
elevators = {signal = "multisine", amplitude = 0.003, frequencies = [0.2, 0.5, 1.1]}
hold = {depth = 0.0}
autopilot = {yaw_rate = {signal = "square", amplitude = 0.05, half_period = 1.0}, roll = 0.0}
""")
    run = runs.simulate(path, seed=1, out=tmp_path / "run")
    experiments, config = load_data([run])
    first, second = experiments
    assert first.measured == ("v", "r", "psi", "z") and len(first.t) == 101 and len(second.t) == 76
    assert config.vehicle.speed == 15.0
    truth = np.loadtxt(run / "doublet-and-3211.truth.csv", delimiter=",", skiprows=1)
    t, rudder = truth[:, 0], truth[:, 11]
    assert rudder[(t > 0.6) & (t < 0.95)].min() > 0.009 and rudder[(t > 1.1) & (t < 1.45)].max() < -0.009
    assert np.abs(rudder[t > 1.6]).max() < 1e-12
    manifest = json.loads((run / "manifest.json").read_text())
    argv = shlex.split(manifest["command"])
    assert argv[argv.index("--scenario") + 1] == str((run / "scenario.toml").resolve())
    again = runs.simulate(run / "scenario.toml", seed=1, out=tmp_path / "again")
    assert _files(run) == _files(again) | {"scenario.toml": _files(run)["scenario.toml"]}


def test_min_crest_phases_lower_the_peak_of_schroeders_and_keep_the_amplitude():
    """Independent reference: the peak of Σ cos(2π f_k t + φ_k) evaluated on its own grid; the
    crest factor (peak / rms, rms √(K/2) for K lines) of the designed multisines falls by a
    fifth or more from Schroeder's phases, and the signal still peaks at its amplitude."""
    from testbed.simulation.signals import Multisine, min_crest_phases, schroeder_phases

    f = np.array([k / 60.0 for k in (1, 2, 3, 5, 8, 12, 18, 27, 40, 60, 90, 135, 180)])
    t = np.linspace(0.0, 60.0, 120001)  # one common period of these harmonics, finely

    def crest(phi):
        return np.abs(np.cos(2 * np.pi * np.outer(t, f) + phi).sum(1)).max() / np.sqrt(len(f) / 2)

    minimal = np.array(min_crest_phases(tuple(f)))
    assert crest(minimal) < 0.8 * crest(schroeder_phases(len(f)))
    assert min_crest_phases(tuple(f)) == min_crest_phases(tuple(float(v) for v in f))  # deterministic
    program = Multisine(amplitude=0.002, frequencies=tuple(f), phases="min-crest").program(None)
    x = np.array([program(ti, None) for ti in t[::10]])
    assert np.abs(x).max() == pytest.approx(0.002, rel=2e-3)
    assert Multisine().phases == "schroeder"  # the default is unchanged


def test_built_in_scenarios_are_files_that_round_trip():
    assert set(sc.BUILTIN) == set(BUILTIN_SCENARIOS)
    for name in sc.BUILTIN:
        s = sc.scenario(name)
        assert sc.parse_scenario(tomllib.loads(sc.scenario_text(s)), s.source) == s
        assert (sc.SCENARIO_DIR / f"{name}.toml").exists()


FACTORIAL = {
    "II": sig.Prbs,
    "inputs-square": sig.Square,
    "inputs-3211": sig.Input3211,
    "inputs-multisine": sig.Multisine,
}
HALVED = {("inputs-square", "vertical"), ("inputs-3211", "roll")}  # where Scenario II's peak is not linear


@pytest.mark.parametrize("name", sorted(FACTORIAL))
def test_input_factorial_is_scenario_ii_with_another_signal(name):
    """Scenario II's layout, loops, hold and duration; its peaks (halved where documented); the
    power over the record: the peak squared, a multisine's K/2 times its scale squared."""
    ii, s = sc.scenario("II"), sc.scenario(name)
    assert name in sc.BUILTIN
    assert replace(s, name="II", description="", source="", experiments=ii.experiments) == replace(
        ii, description="", source=""
    )
    assert [e.name for e in s.experiments] == [e.name for e in ii.experiments]
    for e, e2 in zip(s.experiments, ii.experiments):
        assert (e.autopilot, e.hold_depth, e.duration) == (e2.autopilot, e2.hold_depth, e2.duration)
        assert e.fins.keys() == e2.fins.keys()
        for channel, u in e.fins.items():
            if isinstance(e2.fins[channel], sig.Hold):
                assert u == e2.fins[channel]
                continue
            assert type(u) is FACTORIAL[name]
            peak = e2.fins[channel].peak() / (2 if (name, e.name) in HALVED else 1)
            assert u.peak() == pytest.approx(peak, rel=1e-12)
            t = np.arange(round(s.duration * s.control_rate)) / s.control_rate
            program = u.program(np.random.default_rng(1))
            x = np.array([program(ti, None) for ti in t])
            if isinstance(u, sig.Multisine):
                f = np.asarray(u.frequencies)
                # sampled at the control rate: below the peak by at most the top line's half-step
                assert peak * np.cos(np.pi * f.max() / s.control_rate) <= np.abs(x).max() <= peak * (1 + 1e-9)
                scale = peak / sig.multisine_peak(f, np.array(sig.min_crest_phases(u.frequencies)))
                assert np.mean(x**2) == pytest.approx(len(f) / 2 * scale**2, rel=1e-6)  # whole periods
                assert np.mean(x**2) / peak**2 == pytest.approx(0.45, abs=0.01)  # as documented
            else:
                assert np.abs(x).max() == peak
                assert np.mean(x**2) == pytest.approx(peak**2, rel=1e-12)


@pytest.mark.parametrize(
    "text, message",
    [
        ("duration = -1.0\n[[experiment]]\nname = 'x'", "duration = -1.0; expected a finite number > 0"),
        ("[[experiment]]\nname = 'x'\nrudder = {signal = 'prbs', amplitude = 0.5}", "rudder reaches 0.5 rad"),
        ("[[experiment]]\nname = 'x'\nrudder = {signal = 'chirp'}", "signal 'chirp'; expected one of"),
        (
            "[[experiment]]\nname = 'x'\nrudder = {signal = 'prbs', order = 31}",
            "order = 31; expected an integer",
        ),
        ("[[experiment]]\nname = 'x'\nrudder = {signal = 'prbs', amp = 0.1}", "unknown prbs parameter 'amp'"),
        (
            "[[experiment]]\nname = 'x'\nrudder = {signal = 'multisine', amplitude = 0.001, phases = 'best'}",
            "expected 'schroeder' or 'min-crest'",
        ),
        (
            "[[experiment]]\nname = 'x'\nrudder = 0.1\nautopilot = {yaw_rate = 0.1}",
            "both a signal and driven",
        ),
        ("[[experiment]]\nname = 'x'\nautopilot = {pitch = 0.1}", "unknown autopilot loop 'pitch'"),
        ("[[experiment]]\nname = 'x'\nhold = {depth = 0.0}", "hold needs an elevators signal"),
        ("[[experiment]]\nname = 'x'\n[[experiment]]\nname = 'x'", "expected distinct names"),
        ("wind = 3\n[[experiment]]\nname = 'x'", "unknown key 'wind'"),
        ("feedback = 'sensors'\n[[experiment]]\nname = 'x'", "feedback = 'sensors'; expected one of"),
        ("feedback = 1\n[[experiment]]\nname = 'x'", "feedback = 1; expected one of"),
        (
            "feedback = 'measured'\n[sensors.dvl]\noutputs = ['u']\n[[experiment]]\nname = 'x'",
            "feedback = 'measured' with named sensors (dvl)",
        ),
        ("[sensors]\nrate = 30.0\n[[experiment]]\nname = 'x'", "expected the sample rate to divide"),
        ("[sensors]\nmeasured = ['depth']\n[[experiment]]\nname = 'x'", "measured ['depth']"),
        ("name = ", "not valid TOML"),
        ("name = 'none'", "no [[experiment]]"),
    ],
)
def test_bad_scenario_files_are_one_line_errors(tmp_path, capsys, text, message):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    assert main(["simulate", "--scenario", str(path), "--quiet", "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err and "bad.toml" in err, err
    assert not (tmp_path / "run").exists()


TRIALS = {
    "perfect": {},
    "current and turbulence": {
        "current": [0.3, -0.2, 0.0],
        "turbulence": {"force_std": [1.0, 10.0, 10.0], "moment_std": [0.1, 3.0, 3.0], "time": 0.5},
    },
}


@pytest.mark.parametrize("trial", sorted(TRIALS))
@pytest.mark.parametrize("feedback", sc.FEEDBACKS)
def test_the_autopilots_read_the_true_states_or_the_records_readings(feedback, trial):
    """Replayed on the record's rows (the true states, or the measured ones for measured
    feedback: over the ground in a current), the same autopilots and programs give the fin
    commands flown, and the measured states keep the documented noise either way."""
    s = replace(_short("II", 6.0), feedback=feedback, trial=parse_trial(TRIALS[trial], "trial"))
    flights, lin = fl.fly_scenario(s, seed=3, truth="linear")
    for k, (e, f) in enumerate(zip(s.experiments, flights)):
        autopilot = Autopilot.designed(
            lin.A_full, lin.B_full, lin.vehicle.speed, 1 / s.control_rate, lin.fins.angle
        )
        program = fl.program(s, e, seed=3, index=k)
        rows = f.truth if feedback == "true" else f.measured
        flown = np.column_stack([f.commands[c] for c in fl.FIN_COMMANDS])
        replayed = np.array([autopilot.step(x, **program(t, x))[0] for t, x in zip(f.t, rows)])
        assert np.abs(replayed - flown).max() < 1e-12, e.name
        other = f.measured if feedback == "true" else f.truth
        autopilot.reset()
        replayed = np.array([autopilot.step(x, **program(t, x))[0] for t, x in zip(f.t, other)])
        assert np.abs(replayed - flown).max() > 1e-4, e.name  # the autopilots did read `rows`
        if trial == "perfect":
            for name, std in s.sensors.noise_std.items():
                assert np.std(f.measured[:, IX[name]] - f.truth[:, IX[name]]) == pytest.approx(std, rel=0.15)


@pytest.mark.parametrize("truth", sc.TRUTHS)
def test_with_two_control_steps_a_sample_the_record_holds_every_other_reading(truth, monkeypatch):
    """At a control rate twice the sample rate the autopilots read at every control instant and
    the record keeps the readings at the sample instants (ψ unwrapped there), on both truths, and
    a scenario with measured feedback round-trips through its file."""
    read = []
    step = Autopilot.step

    def logged(self, x, **kw):
        read.append(np.array(x))
        return step(self, x, **kw)

    monkeypatch.setattr(Autopilot, "step", logged)
    s = replace(_short("II", 2.0), feedback="measured", control_rate=100.0)
    assert sc.parse_scenario(tomllib.loads(sc.scenario_text(s)), s.source) == s
    flights, _ = fl.fly_scenario(s, seed=5, truth=truth)
    for f in flights:
        readings, read[:] = np.array(read[: 2 * len(f.t) - 1]), read[2 * len(f.t) - 1 :]
        at_samples = readings[::2]
        assert len(at_samples) == len(f.t)
        assert np.array_equal(np.delete(at_samples, IX["psi"], 1), np.delete(f.measured, IX["psi"], 1))
        assert np.allclose(np.unwrap(at_samples[:, IX["psi"]]), f.measured[:, IX["psi"]], atol=0.1)
        between = readings[1::2] - f.truth[:-1]  # the readings no sample keeps: noisy all the same
        assert np.std(between[:, IX["q"]]) > 0.5 * s.sensors.noise_std["q"]
    assert not read


def test_noise_is_the_documented_noise(tmp_path):
    s = _short("I", 20.0)
    f = fl.fly_scenario(s, seed=2)[0][0]
    for name, std in s.sensors.noise_std.items():
        k = IX[name]
        assert np.std(f.measured[:, k] - f.truth[:, k]) == pytest.approx(std, rel=0.1)
    assert np.std(f.fins_measured - f.fins) == pytest.approx(s.sensors.fin_std, rel=0.1)


def test_bad_input_leaves_nothing(tmp_path, capsys, monkeypatch):
    def one_line_exit_2(argv):
        code = main(argv)
        err = capsys.readouterr().err
        assert code == 2 and err.count("\n") == 1, err
        return err

    assert "unknown" in one_line_exit_2(["simulate", "--scenario", "III", "--out", str(tmp_path / "x")])
    with pytest.raises(SystemExit) as e:
        main(["simulate", "--scenario", "I", "--duration", "-3"])
    assert e.value.code == 2 and "--duration" in capsys.readouterr().err
    (tmp_path / "exists").mkdir()
    assert "already exists" in one_line_exit_2(
        ["simulate", "--scenario", "I", "--out", str(tmp_path / "exists")]
    )
    blocker = tmp_path / "file"
    blocker.write_text("")
    blocked = ["simulate", "--scenario", "I", "--out", str(blocker / "run")]
    assert "file is a file, not a folder" in one_line_exit_2(blocked)

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(fl, "fly", interrupted)
    assert main(["simulate", "--scenario", "I", "--quiet", "--out", str(tmp_path / "cut")]) == 130
    assert sorted(p.name for p in tmp_path.iterdir()) == ["exists", "file"]  # no run, no temp dir
    with pytest.raises(InputError, match="duration"):
        fl.fly_scenario(replace(sc.scenario("I"), duration=-1.0))


@pytest.mark.parametrize(
    "option, value", [("--duration", "inf"), ("--duration", "nan"), ("--seed", "-1"), ("--speed", "inf")]
)
def test_bad_numbers_are_one_line_errors(option, value, tmp_path, capsys):
    try:
        code = main(
            ["simulate", "--scenario", "II", "--quiet", "--out", str(tmp_path / "run"), option, value]
        )
    except SystemExit as exc:  # the option parser may catch it before the library
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and option.strip("-") in err and value in err, err
    assert list(tmp_path.iterdir()) == []


def test_library_checks_its_inputs(tmp_path):
    for kwargs in ({"duration": math.inf}, {"speed": math.nan}, {"seed": -1}):
        # a value the caller gave is named as its parameter (`duration=inf`), as Python writes it
        with pytest.raises(InputError, match=f"{next(iter(kwargs))}[= ].*; expected"):
            runs.simulate("II", out=tmp_path / "run", **kwargs)
    assert list(tmp_path.iterdir()) == []
    for bad in (math.inf, math.nan, 0.0, -1.0, "60"):
        with pytest.raises(InputError, match="duration"):
            sc.scenario("II").with_overrides(duration=bad)
    with pytest.raises(InputError, match="amplitude"):
        sc.ExperimentSpec("x", fins={"rudder": sig.Prbs(amplitude=math.nan)})
    # beyond the fin range of the vehicle flown (the torpedo's 0.4 rad): refused before flying
    wide = sc.ExperimentSpec("x", fins={"rudder": sig.Prbs(amplitude=0.5)})
    with pytest.raises(
        InputError, match="experiment 'x': rudder reaches 0.5 rad; expected at most the fin range"
    ):
        runs.simulate(sc.Scenario(name="wide", experiments=(wide,), duration=1.0), out=tmp_path / "run")
    assert list(tmp_path.iterdir()) == []
    for bad in (-1, 1.5, True, "3"):
        with pytest.raises(InputError, match="seed .*non-negative integer"):
            rng_for(bad, 0)
        with pytest.raises(InputError, match="seed"):
            fl.fly_scenario(_short("I", 1.0), seed=bad)
    assert rng_for(np.int64(3), 0).integers(1 << 30) == rng_for(3, 0).integers(1 << 30)
    with pytest.raises(
        InputError,
        match="unknown; expected one of I, II, II-trial, inputs-3211, inputs-multisine, inputs-square, lake, turn, turning-circle, zigzag, zigzag-vertical",
    ):
        sc.scenario("III")


def test_kill_leaves_nothing(tmp_path, monkeypatch):
    def killed(*args, **kwargs):
        os.kill(os.getpid(), signal.SIGTERM)  # as `kill PID` would, mid-flight
        raise AssertionError("SIGTERM did not stop the run")

    monkeypatch.setattr(fl, "fly", killed)
    assert main(["simulate", "--scenario", "II", "--quiet", "--out", str(tmp_path / "run")]) == 130
    assert list(tmp_path.iterdir()) == []  # no run directory, no temporary one


def test_a_second_kill_while_cleaning_up_is_ignored(tmp_path, monkeypatch):
    """`kill` twice: the second SIGTERM arrives while the temporary run directory is being
    removed, and the removal still runs to its end."""
    rmtree = shutil.rmtree

    def killed(*args, **kwargs):
        os.kill(os.getpid(), signal.SIGTERM)
        raise AssertionError("SIGTERM did not stop the run")

    def removed_under_fire(path, *args, **kwargs):
        os.kill(os.getpid(), signal.SIGTERM)
        rmtree(path, *args, **kwargs)

    monkeypatch.setattr(fl, "fly", killed)
    monkeypatch.setattr(shutil, "rmtree", removed_under_fire)
    before = signal.getsignal(signal.SIGTERM)
    assert main(["simulate", "--scenario", "II", "--quiet", "--out", str(tmp_path / "run")]) == 130
    assert list(tmp_path.iterdir()) == []
    assert signal.getsignal(signal.SIGTERM) is before  # the handler restored


def test_fins_logged_at_the_physics_rate_are_the_servos_steps_between_the_samples(tmp_path):
    """Scenario I with `[sensors] fin_rate = 100`: the same flight and sensor noise as at its
    50 Hz; the truth's fins at every 10 ms the servo's staircase replayed from the autopilots'
    commands (each physics step toward the clipped command by at most the rate limit × 10 ms),
    each pair's mean the 50 Hz record's interval mean; the run's CSV a row every 10 ms, the
    states empty between the samples, read back as missing."""
    s = _short("I", 3.0)
    fine = replace(s, sensors=replace(s.sensors, fin_rate=100.0))
    assert sc.parse_scenario(tomllib.loads(sc.scenario_text(fine)), fine.source) == fine
    (f,), _ = fl.fly_scenario(s, seed=3)
    (g,), _ = fl.fly_scenario(fine, seed=3)
    assert f.fin_log is None and np.array_equal(g.measured, f.measured) and np.array_equal(g.truth, f.truth)
    log = g.fin_log
    assert len(log.t) == 2 * len(f.t) - 1 and np.allclose(log.t[::2], f.t)
    np.testing.assert_allclose(log.truth[::2], f.truth, atol=1e-9)
    np.testing.assert_allclose(0.5 * (log.fins[:-1:2] + log.fins[1::2]), f.fins[:-1], atol=1e-12)
    model = load_model()
    limits, slew = fin_limits(model).angle, fin_rate_limit(model) * model.opt.timestep
    commands = np.column_stack([g.commands[k] for k in fl.FIN_COMMANDS])
    reference, replayed = np.zeros(3), []
    for command in commands[:-1]:
        for _ in range(2):
            gap = np.clip(command, -limits, limits) - reference
            reference = reference + np.clip(gap, -slew, slew)
            replayed.append(reference)
    np.testing.assert_allclose(log.fins[:-1], replayed, atol=1e-12)
    assert np.abs(log.fins[1:-1:2] - log.fins[:-1:2]).max() > 0.5 * slew  # the servo slewed within samples
    run = runs.simulate(fine, seed=3, out=tmp_path / "run")
    (e,), _ = load_data([run])
    assert np.allclose(e.t, log.t)
    np.testing.assert_allclose(e.inputs, log.measured, rtol=1e-9, atol=1e-15)
    assert np.isnan(e.y[1::2]).all() and not np.isnan(e.y[::2]).any()
    truth = np.loadtxt(run / "scenario-I.truth.csv", delimiter=",", skiprows=1)
    assert len(truth) == len(log.t) and not np.isnan(truth).any()


@pytest.mark.parametrize(
    "sensors, words",
    [
        ({"fin_rate": 75.0}, "sensors.fin_rate = 75 Hz; expected a whole multiple of the control rate 50 Hz"),
        ({"fin_rate": 150.0}, "sensors.fin_rate = 150 Hz; expected it to divide the physics rate 100 Hz"),
        ({"fin_rate": -1.0}, "fin_rate -1.0; expected a finite number > 0 (Hz)"),
    ],
)
def test_a_fin_rate_the_plant_cannot_log_is_a_one_line_error(tmp_path, capsys, sensors, words):
    path = tmp_path / "bad.toml"
    path.write_text(
        "[sensors]\n" + "".join(f"{k} = {v}\n" for k, v in sensors.items()) + "[[experiment]]\nname = 'x'\n"
    )
    assert main(["simulate", "--scenario", str(path), "--quiet", "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and words in err and "bad.toml" in err, err
    assert not (tmp_path / "run").exists()


def test_a_fin_rate_with_a_trial_is_refused():
    with pytest.raises(InputError, match=r"sensors.fin_rate with named sensors, a \[trial\] or steps") as e:
        sc.parse_scenario(
            tomllib.loads(
                "[sensors]\nfin_rate = 100.0\n[trial]\ncurrent = [0.1, 0.0, 0.0]\n[[experiment]]\nname = 'x'\n"
            ),
            "t.toml",
        )
    assert "\n" not in str(e.value)
