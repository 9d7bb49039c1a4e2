"""Scenarios: the paper's command definitions, autopilot performance, PRBS, run directories."""

import hashlib
import json
import math

import numpy as np
import pytest

from testbed import scenario as sc
from testbed.cli import main
from testbed.data import load_data
from testbed.errors import InputError
from testbed.model import IX
from testbed.truth import analytic_model
from testbed.vehicle import load_model

SHORT = sc.Settings(duration=6.0)


def test_scenario_i_commands_are_the_papers():
    program = sc.programs("I", sc.Settings(), seed=0)["scenario-I"]
    x = np.zeros(10)
    for t in np.arange(0.0, 30.0, 0.05):
        _, c = program(t, x)
        assert c["depth"] == 100.0 + 20.0 * (int(t // 5.0) % 2)  # 20 m every 5 s
        assert c["yaw_rate"] == pytest.approx(math.radians(20) * (1 if int(t // 1.5) % 2 == 0 else -1))
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


def test_scenario_ii_holds_depth_and_drives_fins_as_the_paper_says():
    flights, _ = sc.fly_scenario("II", seed=3, settings=sc.Settings(duration=20.0))
    horizontal, vertical = flights
    z = horizontal.truth[:, IX["z"]]
    assert np.abs(z - 100.0).max() < 1.0  # depth held within 1 m while the rudder is excited
    assert np.unique(np.round(horizontal.commands["delta_r"], 9)).size == 2  # binary
    assert np.array_equal(vertical.commands["fin_er"], vertical.commands["fin_el"])
    assert np.abs(vertical.fins[:, 1] - vertical.fins[:, 2]).max() < 1e-3
    assert np.abs(vertical.fins[:, 0]).max() < 1e-6  # rudder fixed
    assert np.abs(vertical.commands["fin_r"]).max() == 0.0


def _files(run):
    return {p.name: p.read_bytes() for p in run.iterdir() if p.suffix in (".csv", ".toml")}


def test_run_directory_is_complete_and_reproducible(tmp_path):
    a = sc.simulate("II", seed=5, out=tmp_path / "a", settings=SHORT, progress=False)
    b = sc.simulate("II", seed=5, out=tmp_path / "b", settings=SHORT, progress=False)
    c = sc.simulate("II", seed=6, out=tmp_path / "c", settings=SHORT, progress=False)
    names = {"horizontal.csv", "vertical.csv", "horizontal.truth.csv", "vertical.truth.csv",
             "model.toml", "recording.rrd", "manifest.json"}  # fmt: skip
    assert {p.name for p in a.iterdir()} == names
    assert _files(a) == _files(b)  # same seed: identical bytes
    assert _files(a)["horizontal.csv"] != _files(c)["horizontal.csv"]  # other seed: other noise
    manifest = json.loads((a / "manifest.json").read_text())
    assert manifest["mjcf_sha256"] == hashlib.sha256(open(manifest["mjcf"], "rb").read()).hexdigest()
    assert manifest["settings"]["duration"] == 6.0 and manifest["seed"] == 5
    assert {"mujoco", "numpy", "rerun-sdk"} <= set(manifest["versions"])
    experiments, config = load_data([a])
    assert [e.name for e in experiments] == ["horizontal", "vertical"]
    assert config.vehicle.speed == pytest.approx(20.0) and len(experiments[0].t) == 301  # 6 s at 50 Hz


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
    assert "cannot create" in one_line_exit_2(["simulate", "--scenario", "I", "--out", str(blocker / "run")])

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(sc, "fly", interrupted)
    assert main(["simulate", "--scenario", "I", "--quiet", "--out", str(tmp_path / "cut")]) == 130
    assert sorted(p.name for p in tmp_path.iterdir()) == ["exists", "file"]  # no run, no temp dir
    with pytest.raises(InputError, match="duration"):
        sc.fly_scenario("I", settings=sc.Settings(duration=-1.0))
