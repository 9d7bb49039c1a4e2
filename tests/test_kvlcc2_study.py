"""The KVLCC2 study's conversion (studies/kvlcc2.py) on small synthetic records in the SIMMAN
formats: a steady turn with a known drift, its heading through ±180°, a rudder ramp."""

from __future__ import annotations

import math

import numpy as np
import pytest

from studies import kvlcc2
from testbed.identification import recursions
from testbed.identification.problem import problem
from testbed.data import read_config, read_csv

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
    r = recursions.outputs(prob, np.r_[prob.start, 0.0])[0][:, 0]
    assert r[-1] < 0  # positive δ steers to port (SIMMAN), as on testbed's torpedo (N_dr < 0)
