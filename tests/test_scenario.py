"""Scenarios: the paper's command definitions, autopilot performance, PRBS, run directories."""

import hashlib
import json
import math
import os
import shlex
import signal
from dataclasses import asdict, fields

import numpy as np
import pytest

from testbed import scenario as sc
from testbed.cli import main
from testbed.data import load_data
from testbed.errors import InputError
from testbed.measurements import rng_for
from testbed.model import IX
from testbed.truth import analytic_model
from testbed.vehicle import load_model

SHORT = sc.Settings(duration=6.0)


def test_scenario_i_commands_are_the_papers():
    program = sc.programs("I", sc.Settings(), seed=0)["scenario-I"]
    x = np.zeros(10)
    for k in range(1500):  # the control instants k / 50 Hz
        c = program(k * 0.02, x)
        assert c["depth"] == 100.0 + 20.0 * (k // 250 % 2)  # 20 m every 5 s
        assert c["yaw_rate"] == pytest.approx(math.radians(20) * (1 if k // 75 % 2 == 0 else -1))  # 1.5 s
        assert c["roll"] == 0.0


def test_scenario_i_is_flown_not_toned_down():
    (flight,), _ = sc.fly_scenario("I", settings=sc.Settings(duration=12.0))
    r, z = flight.truth[:, IX["r"]], flight.truth[:, IX["z"]]
    assert r.max() > 0.85 * math.radians(20) and r.min() < -0.85 * math.radians(20)
    assert z.max() - z.min() > 15.0


@pytest.mark.parametrize("order", range(3, 13))
def test_prbs_is_maximal_length_and_balanced(order):
    bits = sc.prbs(order, np.random.default_rng(order))
    n = 2**order - 1
    assert len(bits) == n and bits.sum() == 1  # one more +1 than −1
    twice = np.concatenate([bits, bits])
    # the periodic autocorrelation of an m-sequence is n at lag 0 and −1 elsewhere
    corr = np.array([twice[k:k + n] @ bits for k in range(n)])
    assert corr[0] == n and np.all(corr[1:] == -1)


def test_prbs_spectrum_covers_the_vehicle_bandwidth():
    s = sc.Settings()
    A = analytic_model(load_model(), 20.0).A_full
    poles = [abs(np.linalg.eigvals(A[np.ix_(i, i)])) for i in ([1, 5], [2, 4, 7])]  # v,r; w,q,θ
    fastest, slowest = max(p.max() for p in poles) / (2 * np.pi), min(p.min() for p in poles) / (2 * np.pi)
    f, power = sc.prbs_spectrum(s.prbs_order, s.prbs_clock)
    flat = f[power >= 0.5 * power[0]]  # within 3 dB of the lowest line
    assert flat.max() > fastest  # covers the fastest sway-yaw and heave-pitch poles
    assert f[0] < 0.1 * fastest and slowest > 0
    assert (2**s.prbs_order - 1) * s.prbs_clock >= s.duration  # no repeat within an experiment


def test_scenario_ii_horizontal_holds_depth_while_the_rudder_follows_the_prbs():
    s = sc.Settings(duration=20.0)
    (horizontal, _), _ = sc.fly_scenario("II", seed=3, settings=s)
    z = horizontal.truth[:, IX["z"]]
    assert np.abs(z - 100.0).max() < 1.0  # depth held within 1 m while the rudder is excited
    bits = sc.prbs(s.prbs_order, rng_for(3, 0, 1))[np.arange(len(horizontal.t)) // 5]  # 5 samples a bit
    assert np.array_equal(horizontal.commands["rudder"], s.prbs_rudder * bits)
    assert np.array_equal(horizontal.commands["fin_r"], horizontal.commands["rudder"])


def _power_above(signal, dt, f_min):
    f = np.fft.rfftfreq(len(signal), dt)
    return (np.abs(np.fft.rfft(signal - signal.mean())) ** 2)[f > f_min].sum()


@pytest.mark.parametrize("seed", [0, 9])  # two PRBS phases
def test_scenario_ii_vertical_elevators_follow_the_prbs(seed):
    """Both elevators follow the PRBS, the slow hold adding only what keeps pitch and depth
    bounded over the default 60 s: the PRBS dominates the elevators above 0.1 Hz."""
    s = sc.Settings()
    (_, vertical), _ = sc.fly_scenario("II", seed=seed, settings=s)
    f, dt = vertical, 1.0 / s.sensors.rate
    prbs = s.prbs_elevators * sc.prbs(s.prbs_order, rng_for(seed, 1, 1))[np.arange(len(f.t)) // 5]
    assert np.array_equal(f.commands["elevators"], prbs)
    assert np.array_equal(f.commands["fin_er"], f.commands["fin_el"])  # equal commands
    assert np.abs(f.fins[:, 1] - f.fins[:, 2]).max() < 1e-9  # equal deflections
    assert np.abs(f.commands["fin_r"]).max() == 0.0 and np.abs(f.fins[:, 0]).max() < 1e-9  # rudder fixed
    elevator, correction = f.fins[:, 1], f.commands["fin_er"] - prbs
    assert np.corrcoef(elevator, prbs)[0, 1] >= 0.9  # the deflection, servo lag included
    assert np.corrcoef(f.commands["fin_er"], prbs)[0, 1] >= 0.98
    assert _power_above(correction, dt, 0.1) < 0.01 * _power_above(prbs, dt, 0.1)
    assert 0.8 < _power_above(elevator, dt, 0.1) / _power_above(prbs, dt, 0.1) < 1.1
    assert np.abs(f.truth[:, IX["theta"]]).max() < 0.3  # rad: bounded pitch ...
    assert np.abs(f.truth[:, IX["z"]] - s.depth).max() < 20.0  # ... and depth


def test_turning_circle_reaches_a_steady_yaw_rate_at_the_commanded_rudder():
    s = sc.Settings(duration=8.0)
    (f,), _ = sc.fly_scenario("turn", settings=s)
    steady = f.t >= 5.0
    r = f.truth[steady, IX["r"]]
    assert r.mean() < -0.5  # a positive rudder turns to port, hard
    assert np.ptp(r) < 0.01 * abs(r.mean())  # steady
    assert np.all(f.commands["rudder"] == s.turn_rudder) and np.all(f.commands["fin_r"] == s.turn_rudder)
    assert np.abs(f.fins[steady, 0] - s.turn_rudder).max() < 0.01  # the servo holds it (hinge moment)
    assert np.abs(f.truth[:, IX["z"]] - s.depth).max() < 0.5  # depth held
    assert np.abs(f.truth[:, IX["phi"]]).max() < 0.05  # roll held


def _zigzag_commands(angle, limit):
    """The 20/20 rule replayed on the flown `angle` (from its initial value): +limit first, to
    −limit when the angle reaches −limit, back to +limit when it reaches +limit."""
    out, sign = [], 1.0
    for a in angle - angle[0]:
        if sign > 0 and a <= -limit:
            sign = -1.0
        elif sign < 0 and a >= limit:
            sign = 1.0
        out.append(sign * limit)
    return np.array(out)


@pytest.mark.parametrize("scenario, state, fin, keyword",
                         [("zigzag", "psi", 0, "rudder"), ("zigzag-vertical", "theta", 1, "elevators")])  # fmt: skip
def test_zigzag_switches_the_fins_when_the_angle_passes_the_switching_angle(scenario, state, fin, keyword):
    s = sc.Settings(duration=6.0)
    (f,), _ = sc.fly_scenario(scenario, settings=s)
    angle = f.truth[:, IX[state]]
    command = f.commands[keyword]
    assert np.array_equal(command, _zigzag_commands(angle, s.zigzag_angle))  # switched on time
    switches = np.flatnonzero(np.diff(command))
    assert len(switches) >= 3  # a real zigzag, not one turn
    assert command[0] == s.zigzag_angle  # first to negative heading / nose down
    # between switches the fin reaches the commanded angle
    for a, b in zip(switches[:-1], switches[1:]):
        assert np.abs(f.fins[a + 1:b + 1, fin] - command[a + 1]).min() < 0.02
    if scenario == "zigzag":
        assert np.abs(f.truth[:, IX["z"]] - s.depth).max() < 0.5  # depth held
    else:
        assert np.abs(f.fins[:, 0]).max() < 1e-9 and np.abs(f.fins[:, 1] - f.fins[:, 2]).max() < 1e-9


def _files(run):
    return {p.name: p.read_bytes() for p in run.iterdir() if p.suffix in (".csv", ".toml")}


def test_run_directory_is_complete_and_its_command_regenerates_it(tmp_path, capsys):
    a = sc.simulate("II", seed=5, out=tmp_path / "a", settings=SHORT, progress=False)
    c = sc.simulate("II", seed=6, out=tmp_path / "c", settings=SHORT, progress=False)
    names = {"horizontal.csv", "vertical.csv", "horizontal.truth.csv", "vertical.truth.csv",
             "model.toml", "recording.rrd", "manifest.json"}  # fmt: skip
    assert {p.name for p in a.iterdir()} == names
    manifest = json.loads((a / "manifest.json").read_text())
    argv = shlex.split(manifest["command"])
    assert argv[0] == "testbed" and manifest["command_reproduces_run"]
    assert main(argv[1:] + ["--quiet", "--out", str(tmp_path / "b")]) == 0
    assert _files(a) == _files(tmp_path / "b")  # the recorded command: identical bytes
    assert _files(a)["horizontal.csv"] != _files(c)["horizontal.csv"]  # other seed: other noise
    assert manifest["mjcf_sha256"] == hashlib.sha256(open(manifest["mjcf"], "rb").read()).hexdigest()
    assert manifest["settings"] == json.loads(json.dumps(asdict(sc.Settings(duration=6.0, speed=20.0))))
    assert manifest["seed"] == 5
    assert {"mujoco", "numpy", "rerun-sdk"} <= set(manifest["versions"])
    experiments, config = load_data([a])
    assert [e.name for e in experiments] == ["horizontal", "vertical"]
    assert config.vehicle.speed == pytest.approx(20.0) and len(experiments[0].t) == 301  # 6 s at 50 Hz


def test_manifest_says_when_the_command_cannot_reproduce_the_run(tmp_path):
    s = sc.Settings(duration=0.2, depth=50.0, prbs_clock=0.05)
    run = sc.simulate("II", out=tmp_path / "r", settings=s, progress=False)
    manifest = json.loads((run / "manifest.json").read_text())
    assert not manifest["command_reproduces_run"]
    hidden = set(manifest["settings_not_on_command_line"])
    assert hidden == {f.name for f in fields(sc.Settings)} - {"duration", "speed"}
    assert manifest["settings"]["depth"] == 50.0 and manifest["settings"]["prbs_clock"] == 0.05
    assert "--duration 0.2 " in manifest["command"]  # exact, not rounded


def test_noise_is_the_documented_noise(tmp_path):
    flights, _ = sc.fly_scenario("I", seed=2, settings=sc.Settings(duration=20.0))
    f = flights[0]
    for name, std in sc.Settings().sensors.noise_std.items():
        k = IX[name]
        assert np.std(f.measured[:, k] - f.truth[:, k]) == pytest.approx(std, rel=0.1)


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
    assert "already exists" in one_line_exit_2(["simulate", "--scenario", "I", "--out", str(tmp_path / "exists")])
    blocker = tmp_path / "file"
    blocker.write_text("")
    blocked = ["simulate", "--scenario", "I", "--out", str(blocker / "run")]
    assert "file is a file, not a folder" in one_line_exit_2(blocked)

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(sc, "fly", interrupted)
    assert main(["simulate", "--scenario", "I", "--quiet", "--out", str(tmp_path / "cut")]) == 130
    assert sorted(p.name for p in tmp_path.iterdir()) == ["exists", "file"]  # no run, no temp dir
    with pytest.raises(InputError, match="duration"):
        sc.fly_scenario("I", settings=sc.Settings(duration=-1.0))


@pytest.mark.parametrize("option, value", [("--duration", "inf"), ("--duration", "nan"), ("--seed", "-1"),
                                           ("--speed", "inf")])  # fmt: skip
def test_bad_numbers_are_one_line_errors(option, value, tmp_path, capsys):
    try:
        code = main(["simulate", "--scenario", "II", "--quiet", "--out", str(tmp_path / "run"), option, value])
    except SystemExit as exc:  # the option parser may catch it before the library
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and option.strip("-") in err and value in err, err
    assert list(tmp_path.iterdir()) == []


def test_library_checks_its_inputs(tmp_path):
    for kwargs in ({"duration": math.inf}, {"speed": math.nan}, {"seed": -1}):
        with pytest.raises(InputError, match=f"{next(iter(kwargs))} .*; expected"):
            sc.simulate("II", out=tmp_path / "run", progress=False, **kwargs)
    assert list(tmp_path.iterdir()) == []
    for bad in (math.inf, math.nan, 0.0, -1.0, "60"):
        with pytest.raises(InputError, match="duration"):
            sc.Settings(duration=bad)
    for bad in (0.0, 0.5, math.nan):
        with pytest.raises(InputError, match="prbs_elevators"):
            sc.Settings(prbs_elevators=bad)
    for bad in (-1, 1.5, True, "3"):
        with pytest.raises(InputError, match="seed .*non-negative integer"):
            rng_for(bad, 0)
        with pytest.raises(InputError, match="seed"):
            sc.fly_scenario("I", seed=bad, settings=SHORT)
    assert rng_for(np.int64(3), 0).integers(1 << 30) == rng_for(3, 0).integers(1 << 30)
    with pytest.raises(InputError, match="unknown; expected one of I, II, turn, zigzag, zigzag-vertical"):
        sc.programs("III", SHORT, 0)


def test_kill_leaves_nothing(tmp_path, monkeypatch):
    def killed(*args, **kwargs):
        os.kill(os.getpid(), signal.SIGTERM)  # as `kill PID` would, mid-flight
        raise AssertionError("SIGTERM did not stop the run")

    monkeypatch.setattr(sc, "fly", killed)
    assert main(["simulate", "--scenario", "II", "--quiet", "--out", str(tmp_path / "run")]) == 130
    assert list(tmp_path.iterdir()) == []  # no run directory, no temporary one
