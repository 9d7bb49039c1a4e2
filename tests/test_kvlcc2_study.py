"""The KVLCC2 study's conversion (studies/kvlcc2.py) on small synthetic records in the SIMMAN
formats: a steady turn with a known drift, its heading through ±180°, a rudder ramp."""

from __future__ import annotations

import csv
import json
import math
import os
from pathlib import Path

import numpy as np
import pytest

from studies import kvlcc2
from testbed import METHODS
from testbed.cli import main
from testbed.identification import recursions
from testbed.identification.prediction import synthetic
from testbed.identification.problem import problem
from testbed.data import read_config, read_csv, write_config, write_csv

SHIP = """# model scale, as in the repository
T: 0.46
L: 7.0
CB: 0.810
B: 1.27
rho: 1000
x_G: 0.25  # CG forward of midship
m: 3270
I_z: 10014.375
volume: 3.27
scale_factor: 45.7
x_r: -3.5 # rudder
A_R: 0.0539
H_R: 0.345
"""
U, BETA, R_DEG, DT = 8.0, math.radians(5.0), 0.5, 0.13526  # full-scale steady turn, raw step (s)


def turn(n: int, dt: float, lam: float):
    """A steady turn sampled every dt: the raw columns (deg, deg/s, earth velocities) and the
    body velocities at the midship origin, at the scale of the data (λ = 45.7: full scale; 1: the
    model's: U / √45.7 and r √45.7)."""
    t = dt * np.arange(n)
    speed, r = U * math.sqrt(lam / 45.7), R_DEG * math.sqrt(45.7 / lam)
    psi = 170.0 + r * t  # through 180°: printed wrapped to (−180, 180]
    u, v = speed * math.cos(BETA), -speed * math.sin(BETA)
    rad = np.radians(psi)
    raw = {
        "t": t,
        "x0": speed * t,
        "y0": 0 * t,
        "phi": 0.2 + 0.01 * t,
        "psi": (psi + 180) % 360 - 180,
        "dx0": u * np.cos(rad) - v * np.sin(rad),
        "dy0": u * np.sin(rad) + v * np.cos(rad),
        "p": 0.01 + 0 * t,
        "r": r + 0 * t,
        "delta": -5.0 + 0.1 * t,  # a ramp: its interval mean is its midpoint value
        "n": 90 + 0 * t,
        "thrust": 40 + 0 * t,
        "torque": 1 + 0 * t,
    }
    return raw, u, v, r


def write_dat(folder, kind: str, n: int, dt: float, drop: int | None = None):
    lam = kvlcc2.SCALE[kind]
    raw, u, v, r = turn(n, dt, lam)
    keep = np.arange(n) != drop
    lines = {
        "MARIN": ["MARIN(Maritime Research Institute Netherlands)", "Zig-zag for KVLCC2 : 10 / -10", ""],
        "HSVA": [" HSVA, experimental data CPMC", " KVLCC2", " Z10\xb0/5\xb0", " Time series of motions"],
    }[kind]
    for k in np.flatnonzero(keep):
        time = f"{raw['t'][k]:.2E}" if kind == "MARIN" else f"{raw['t'][k]:.9f}"  # MARIN: 3 digits
        lines.append("\t".join([time] + [f"{raw[c][k]:.8E}" for c in kvlcc2.LAYOUTS[kind][1:]]))
    lines += ["\t\t\t", "\t\t\t"]
    name = {"MARIN": "MARIN_FREE_KVLCC2_zz_10_m.dat", "HSVA": "HSVA_CPMC_KVLCC2_Z_10_05.dat"}[kind]
    (folder / name).write_bytes("\n".join(lines).encode("latin-1"))
    (folder / "ship_data.yml").write_text(SHIP)
    return raw, u, v, r, lam


@pytest.mark.parametrize("kind", ["MARIN", "HSVA"])
def test_convert_gives_body_states_at_the_cg_on_a_uniform_grid(tmp_path, kind):
    dt = DT if kind == "MARIN" else 0.05
    raw, u, v, r, lam = write_dat(tmp_path, kind, 3000, dt)
    (name,) = kvlcc2.convert(tmp_path, tmp_path / "out")
    e = read_csv(tmp_path / "out" / f"{name}.csv")
    step = kvlcc2.STEP[kind]
    assert e.dt == pytest.approx(step)
    assert e.t[-1] == pytest.approx(raw["t"][-1], abs=step)
    x_g = 0.25 * lam
    r_rad = math.radians(r)
    np.testing.assert_allclose(e.column("u"), u, rtol=1e-6)
    np.testing.assert_allclose(e.column("v"), v + x_g * r_rad, rtol=1e-5)  # the CG's sway
    np.testing.assert_allclose(e.column("r"), r_rad, rtol=1e-6)
    # the ramps to within their rate times the rebuilt clock's error (ms from 3-digit stamps)
    clock = 5e-3 if kind == "MARIN" else 1e-8
    np.testing.assert_allclose(e.column("psi"), np.radians(170 + r * e.t), atol=r_rad * clock)  # unwrapped
    np.testing.assert_allclose(e.column("phi"), np.radians(0.2 + 0.01 * e.t), atol=math.radians(0.01) * clock)
    assert ("p" in e.measured) == (kind == "MARIN")
    mid = np.radians(-5.0 + 0.1 * (e.t[:-1] + step / 2))  # each interval's mean rudder angle
    np.testing.assert_allclose(e.inputs[:-1, 0], mid, atol=math.radians(0.1) * clock + 1e-12)
    assert not e.inputs[:, 1:].any()
    config = read_config(tmp_path / "out" / f"{name}.toml")
    assert config.vehicle.speed == pytest.approx(u, rel=1e-6)
    assert config.vehicle.mass == pytest.approx(kvlcc2.RHO[kind] * 3.27 * lam**3)
    assert config.free == kvlcc2.SWAY_YAW_FREE and config.outputs == ("v", "r", "psi")
    roll = read_config(tmp_path / "out" / f"{name}-roll.toml")
    assert "phi" in roll.outputs and set(kvlcc2.ROLL_FREE) <= set(roll.free)


def test_printed_stamps_rebuild_one_clock_unless_a_sample_is_missing(tmp_path):
    raw = write_dat(tmp_path, "MARIN", 5000, DT)[0]
    cols, ulp = kvlcc2.read_dat(tmp_path / "MARIN_FREE_KVLCC2_zz_10_m.dat")
    assert len(np.unique(cols["t"])) < 0.3 * cols["t"].size  # stamps repeat beyond 10 s
    t = kvlcc2.uniform_time(cols["t"], ulp)
    np.testing.assert_allclose(t, raw["t"], atol=2e-3)
    write_dat(tmp_path, "MARIN", 5000, DT, drop=4000)  # a gap of one step at 541 s
    cols, ulp = kvlcc2.read_dat(tmp_path / "MARIN_FREE_KVLCC2_zz_10_m.dat")
    assert kvlcc2.uniform_time(cols["t"], ulp) is None
    stamps, merged = kvlcc2.merged(cols["t"], cols)
    assert np.all(np.diff(stamps) > 0)
    np.testing.assert_allclose(merged["r"], R_DEG)


def test_a_priori_derivatives_at_the_cg_give_the_midship_forces_moved():
    """The same motion seen from midship and from the CG: the sway force is the same and the
    yaw moment about the CG is the midship one less x_G times the force."""
    s = {"L": 320.0, "B": 58.0, "T": 20.8, "CB": 0.81, "rho": 1025.0}
    at_midship = kvlcc2.clarke({**s, "x_G": 0.0}, 8.0)
    at_cg = kvlcc2.clarke({**s, "x_G": 11.1}, 8.0)
    v_g, r = 0.3, 0.004
    v_o = v_g - 11.1 * r
    for kind in ("", "dot"):
        Y_o = at_midship[f"Y_v{kind}"] * v_o + at_midship[f"Y_r{kind}"] * r
        N_o = at_midship[f"N_v{kind}"] * v_o + at_midship[f"N_r{kind}"] * r
        assert at_cg[f"Y_v{kind}"] * v_g + at_cg[f"Y_r{kind}"] * r == pytest.approx(Y_o, rel=1e-12)
        assert at_cg[f"N_v{kind}"] * v_g + at_cg[f"N_r{kind}"] * r == pytest.approx(
            N_o - 11.1 * Y_o, rel=1e-12
        )
    assert at_midship["Y_v"] < 0 and at_midship["N_r"] < 0 and at_midship["Y_r"] > 0


def test_a_positive_rudder_turns_the_written_model_to_port_as_the_data_do(tmp_path):
    write_dat(tmp_path, "MARIN", 200, DT)
    (name,) = kvlcc2.convert(tmp_path, tmp_path / "out")
    config = read_config(tmp_path / "out" / f"{name}.toml")
    e = read_csv(tmp_path / "out" / f"{name}.csv")
    step = e.__class__(e.name, e.t, ("r",), np.zeros((e.t.size, 1)), np.tile([0.1, 0, 0], (e.t.size, 1)))
    prob = problem([step], config)
    r = recursions.simulated_outputs(prob, np.r_[prob.start, 0.0])[0][:, 0]
    assert r[-1] < 0  # positive δ steers to port (SIMMAN), as on testbed's torpedo (N_dr < 0)


def degraded(src: Path, dst: Path, rng: np.random.Generator, course_deg: float = 175.0) -> None:
    """The converted CSV `src` as a logger gives it, written to `dst`: 10 % of its rows (not the
    ends) dropped at random and the heading, turned by `course_deg`, wrapped into (−180°, 180°]."""
    with open(src) as f:
        rows = list(csv.reader(f))
    head, data = rows[0], np.array(rows[1:], float)
    data = np.delete(data, rng.choice(np.arange(1, len(data) - 1), len(data) // 10, replace=False), axis=0)
    k = head.index("psi")
    data[:, k] = (data[:, k] + math.radians(course_deg) + math.pi) % (2 * math.pi) - math.pi
    with open(dst, "w", newline="") as f:
        csv.writer(f).writerows([head, *([repr(float(x)) for x in row] for row in data)])


def every_method(csv_path: Path, toml: Path, out: Path, capsys) -> dict[str, tuple[int, str]]:
    """`testbed identify` with every method on one record: method → (exit status, last line)."""
    done = {}
    for method in sorted(METHODS):
        limit = {"ml-nr": ["--max-iter", "5"], "ml-nm": ["--max-iter", "60"]}.get(method, [])
        fit = out / f"{method}.json"
        argv = [str(csv_path), "--config", str(toml), "--method", method, "--out", str(fit), *limit]
        code = main(["identify", *argv])
        err = capsys.readouterr().err.strip().splitlines()
        done[method] = (code, err[-1] if err else "")
        if code in (0, 1):
            doc = json.loads(fit.read_text())
            assert set(doc["coefficients"]) == set(kvlcc2.SWAY_YAW_FREE), method
            assert all(np.isfinite(c["value"]) for c in doc["coefficients"].values()), method
    return done


def test_a_zigzag_record_with_rows_dropped_runs_end_to_end_with_every_method(tmp_path, capsys):
    """The sway-yaw model of the full-scale tanker flown through rudder steps every 30 s, logged
    at 1 s as the converted MARIN records are, 10 % of its rows dropped and the heading wrapped:
    every method fits (exit 0, or 1 where its iteration limit stops it) but `ml-fem`, whose
    steady-state filter refuses dropouts with a one-line reason. None exits 70 (the smoothing
    window of 5 samples at 1 s holds too few samples present at a gap: no singular cubic)."""
    (tmp_path / "ship_data.yml").write_text(SHIP)
    config = kvlcc2.model_config(kvlcc2.ship(tmp_path, "MARIN"), 8.0, roll=False)
    t = np.arange(0.0, 600.0, 1.0)
    rudder = np.radians(10.0) * np.where((t // 30) % 2 == 0, 1.0, -1.0)
    inputs = np.column_stack([rudder, np.zeros_like(t), np.zeros_like(t)])
    noise = {"v": 0.01, "r": 2e-4, "psi": 1e-3}
    record = synthetic(config, t, inputs, noise, ("v", "r", "psi"), np.random.default_rng(1), name="zz")
    write_csv(tmp_path / "clean.csv", record.t, record.y, record.inputs, record.measured)
    toml = write_config(tmp_path / "zz.toml", config)
    degraded(tmp_path / "clean.csv", tmp_path / "zz.csv", np.random.default_rng(2))
    done = every_method(tmp_path / "zz.csv", toml, tmp_path, capsys)
    assert all(code in (0, 1) for m, (code, _) in done.items() if m != "ml-fem"), done
    assert done["ml-fem"][0] == 2 and "dropouts" in done["ml-fem"][1]


MARIN = os.environ.get("TESTBED_KVLCC2_RAW", "")  # a folder with the MARIN .dat records and ship_data.yml


@pytest.mark.skipif(not MARIN, reason="TESTBED_KVLCC2_RAW names no folder of the MARIN records")
@pytest.mark.parametrize("name", ["zz_10", "zz_-10", "zz_20", "zz_-20"])
def test_the_marin_zigzags_with_rows_dropped_run_end_to_end_with_every_method(tmp_path, capsys, name):
    """The public MARIN zigzags (SIMMAN 2008, the KVLCC2 at full scale), converted, with 10 % of
    their rows dropped and the heading wrapped: every method fits (exit 0, or 1 where its
    iteration limit stops it) but `ml-fem`, which refuses the dropouts with a one-line reason."""
    names = kvlcc2.convert(Path(MARIN), tmp_path / "data")
    assert name in names
    degraded(tmp_path / "data" / f"{name}.csv", tmp_path / f"{name}.csv", np.random.default_rng(1))
    done = every_method(tmp_path / f"{name}.csv", tmp_path / "data" / f"{name}.toml", tmp_path, capsys)
    assert all(code in (0, 1) for m, (code, _) in done.items() if m != "ml-fem"), done
    assert done["ml-fem"][0] == 2 and "dropouts" in done["ml-fem"][1]
