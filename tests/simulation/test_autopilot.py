"""Autopilots on the analytic linear model: stability, step responses, saturation, no wind-up."""

import re

import numpy as np
import pytest

from testbed.simulation import autopilot as ap
from testbed.errors import InputError
from testbed.models.linear import IX, NX, discretize
from testbed.simulation.analytic import analytic_model
from testbed.simulation.vehicle import load_model

DT = 0.02  # 50 Hz, the scenarios' control rate


@pytest.fixture(scope="module")
def lin():
    return analytic_model(load_model(), 20.0)


@pytest.fixture(scope="module")
def design(lin):
    return ap.design_autopilots(lin.A_full, lin.B_full, 20.0)


def _closed_loop(lin, d):
    return ap.closed_loop(lin.A_full, lin.B_full, d, DT)


def test_closed_loop_is_stable_and_is_what_step_computes(lin, design):
    M = _closed_loop(lin, design)
    radius = np.sort(np.abs(np.linalg.eigvals(M)))
    assert radius[-1] == pytest.approx(1.0) and radius[-2] < 0.999  # only the heading ψ is free
    # Autopilot.step in its linear range is that closed loop, step for step
    autopilot = ap.Autopilot(design, DT, lin.fins.angle)
    xi = np.zeros(NX + 3)
    xi[[IX["v"], IX["q"], IX["phi"], IX["z"]]] = (0.05, 0.01, 0.02, 0.5)
    Phi, Gamma, _ = discretize(lin.A_full, lin.B_full, np.zeros(NX), DT)
    for _ in range(300):
        fins, _ = autopilot.step(xi[:NX], depth=0.0, yaw_rate=0.0, roll=0.0)
        assert max(map(abs, fins)) < lin.fins.angle  # unsaturated
        following = M @ xi
        assert Phi @ xi[:NX] + Gamma @ np.array(fins) == pytest.approx(following[:NX], abs=1e-12)
        assert autopilot.integrators == pytest.approx(following[NX:], abs=1e-12)
        xi = following
    assert np.abs(xi[:NX]).max() < 0.05 * 0.5  # and it returns towards trim


def _documented_table():
    rows = re.findall(
        r"^\| (course rate|depth|roll) \| .*? \| ([\d.]+) s \| ([\d.]+) % \| ([\d.]+) s \|$", ap.__doc__, re.M
    )
    return {name: tuple(map(float, values)) for name, *values in rows}


@pytest.mark.parametrize("loop", list(ap.STEP_RESPONSES))
def test_step_responses_reach_the_command_as_documented(lin, design, loop):
    t, y, fins, m = ap.step_response(lin.A_full, lin.B_full, design, loop, lin.fins)
    state, keyword, start, end = ap.STEP_RESPONSES[loop]
    assert m.final == pytest.approx(end, abs=0.02 * abs(end - start))  # reaches the command
    assert np.abs(fins).max() <= lin.fins.angle
    rise, overshoot, settling = _documented_table()[loop]
    assert (round(m.rise, 2), round(100 * m.overshoot, 1), round(m.settling, 2)) == (
        rise,
        overshoot,
        settling,
    )


def test_step_metrics_of_a_second_order_system():
    """Against the closed forms for ω²/(s² + 2ζω s + ω²): overshoot exp(−πζ/√(1−ζ²)), and the
    rise time of ζ = 0.5 (1.64/ω, tabulated)."""
    zeta, w = 0.5, 2.0
    t = np.arange(0.0, 20.0, 1e-4)
    wd = w * np.sqrt(1 - zeta**2)
    y = 1 - np.exp(-zeta * w * t) * (np.cos(wd * t) + zeta / np.sqrt(1 - zeta**2) * np.sin(wd * t))
    m = ap.step_metrics(t, 3.0 + 2.0 * y, 3.0, 5.0)
    assert m.overshoot == pytest.approx(np.exp(-np.pi * zeta / np.sqrt(1 - zeta**2)), abs=1e-4)
    assert m.rise == pytest.approx(1.64 / w, abs=0.01)
    assert 3.5 / (zeta * w) < m.settling < 4.5 / (zeta * w)  # the ±2 % envelope bound 3.9/(ζω)
    assert m.final == pytest.approx(5.0)


def test_fins_stay_within_the_stops(lin, design):
    autopilot = ap.Autopilot(design, DT, lin.fins.angle)
    t, xs, fins = ap.fly_linear(
        lin.A_full,
        lin.B_full,
        autopilot,
        lambda t, x: {"yaw_rate": 10.0, "depth": 300.0, "roll": 1.0},
        10.0,
        rate_limit=lin.fins.rate,
    )
    rng = np.random.default_rng(1)
    commands = [
        autopilot.step(x, yaw_rate=4.0, depth=300.0, roll=1.0)[0] for x in rng.normal(0, 3, (200, NX))
    ]
    assert np.abs(fins).max() <= lin.fins.angle and np.abs(commands).max() <= lin.fins.angle
    assert np.abs(fins[:, 0]).max() == pytest.approx(lin.fins.angle)  # it did saturate


class _Naive(ap.Autopilot):
    """Integrates whatever the stops do (wind-up)."""

    def integrate(self, k, x, ref, demanded, realised):
        self.integrators[k] += (x[IX[self.loops[k].tracked]] - ref) * self.dt


class _Clamped(ap.Autopilot):
    """The reference: the integrator held still whenever its fin is cut by a stop."""

    def integrate(self, k, x, ref, demanded, realised):
        if abs(demanded - realised) < 1e-12:
            super().integrate(k, x, ref, demanded, realised)


def _recovery(lin, design, kind):
    """Course rate commanded far beyond reach (30 rad/s; the linear model makes 9.8 at the
    rudder's stop) for 10 s, then 20 deg/s: the excursion past the new command (fraction of
    the step) and the settling time."""
    target = np.radians(20.0)
    autopilot = kind(design, DT, lin.fins.angle)
    t, xs, _ = ap.fly_linear(
        lin.A_full,
        lin.B_full,
        autopilot,
        lambda t, x: {"yaw_rate": 30.0 if t < 10.0 else target, "depth": 0.0, "roll": 0.0},
        20.0,
        rate_limit=lin.fins.rate,
    )
    after = t >= 10.0
    r = xs[after, IX["r"]]
    m = ap.step_metrics(t[after] - 10.0, r, r[0], target)
    return m.overshoot, m.settling


def test_no_wind_up_after_a_long_saturated_command(lin, design):
    overshoot, settling = _recovery(lin, design, ap.Autopilot)
    clamped_overshoot, clamped_settling = _recovery(lin, design, _Clamped)
    naive_overshoot, naive_settling = _recovery(lin, design, _Naive)
    assert overshoot == pytest.approx(clamped_overshoot, abs=0.01) and overshoot < 0.15
    assert settling <= clamped_settling + 0.1 and settling < 3.0
    assert naive_settling > settling + 2.0  # the test can fail: wind-up is visible


def _demands(design, de, da):
    """A state where the pitch loop asks δe = de and the roll loop δa = da (commands zero)."""
    x = np.zeros(NX)
    x[IX["z"]] = 50.0  # = the depth command: θ_cmd = 0
    x[IX["theta"]] = -de / design.pitch.K[IX["theta"]]
    x[IX["phi"]] = -da / design.roll.K[IX["phi"]]
    return x


def test_elevator_mix_past_the_stop_does_not_wind_up_the_integrators(lin, design):
    autopilot = ap.Autopilot(design, DT, lin.fins.angle)
    x = _demands(design, 0.3, 0.2)  # each within the stop, the right elevator (0.5) not
    errors = np.array([x[IX["theta"]], x[IX["phi"]]])
    # premise: both integrators would push their demand further into the stop
    assert np.all(-np.array([design.pitch.Ki, design.roll.Ki]) * errors > 0)
    fins, _ = autopilot.step(x, depth=50.0, roll=0.0)
    assert fins[1:] == pytest.approx((lin.fins.angle, 0.1))
    assert np.all(autopilot.integrators[1:] == 0.0)  # no wind-up
    # within the stops both integrate; and past them an integrator still unwinds
    fins, _ = autopilot.step(_demands(design, 0.1, 0.1), depth=50.0, roll=0.0)
    assert fins[1:] == pytest.approx((0.2, 0.0), abs=1e-12) and np.all(autopilot.integrators[1:] != 0.0)
    autopilot.reset()
    autopilot.integrators[1] = -0.5 / design.pitch.Ki  # the pitch integrator alone asks +0.5
    x = _demands(design, -0.01, 0.2)  # its error now pulls back from the stop
    fins, _ = autopilot.step(x, depth=50.0, roll=0.0)
    assert fins[1] == lin.fins.angle
    assert autopilot.integrators[1] == pytest.approx(-0.5 / design.pitch.Ki + x[IX["theta"]] * DT)


def test_vertical_hold_is_slow_and_leaves_the_elevators_equal(lin, design):
    """The slow hold on the full model: poles at 0.2 rad/s (damping 0.71), far below the PRBS
    band; everything else as fast as before or untouched."""
    together = lin.B_full[:, 1] + lin.B_full[:, 2]
    K = np.zeros(NX)
    K[IX["theta"]], K[IX["z"]] = design.hold
    poles = np.linalg.eigvals(lin.A_full - np.outer(together, K))
    assert np.sum(np.abs(poles) < 1e-9) == 1 and np.all(poles.real < 1e-9)  # ψ free, the rest stable
    slow = poles[(np.abs(poles) > 1e-9) & (np.abs(poles) < 0.22)]
    assert len(slow) == 2 and np.abs(slow) == pytest.approx([ap.HOLD_BANDWIDTH] * 2, rel=0.05)
    assert -slow[0].real / abs(slow[0]) == pytest.approx(np.sqrt(0.5), abs=0.02)
    autopilot = ap.Autopilot(design, DT, lin.fins.angle)
    x = np.zeros(NX)
    x[IX["theta"]], x[IX["z"]] = 0.1, 103.0
    fins, theta_cmd = autopilot.step(x, elevators=0.004, hold_depth=100.0)
    expected = 0.004 - design.hold[0] * 0.1 - design.hold[1] * 3.0
    assert fins == pytest.approx((0.0, expected, expected), abs=1e-15) and theta_cmd is None


def test_autopilots_unstable_when_sampled_are_refused():
    """Above about 27 m/s the pitch loop, designed in continuous time, has a sampled mode at
    25 Hz (the Nyquist frequency at 50 Hz) outside the unit circle: refused with the speed and
    the rate named; at 200 Hz the same loops are stable."""
    lin = analytic_model(load_model(), 30.0)
    with pytest.raises(InputError, match=r"sampled at 50 Hz at a trim speed of 30 m/s.*25\.0 Hz"):
        ap.Autopilot.designed(lin.A_full, lin.B_full, 30.0, DT, lin.fins.angle)
    assert ap.Autopilot.designed(lin.A_full, lin.B_full, 30.0, 0.005, lin.fins.angle).dt == 0.005
    d = ap.design_autopilots(lin.A_full, lin.B_full, 30.0)
    assert np.abs(np.linalg.eigvals(ap.closed_loop(lin.A_full, lin.B_full, d, DT))).max() > 1.2


def test_cli_refuses_a_speed_its_autopilots_cannot_fly(tmp_path, capsys):
    from testbed.cli import main

    assert main(["simulate", "--scenario", "II", "--speed", "30", "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--speed 30 m/s" in err and "scenario II: control_rate = 50 Hz" in err, (
        err
    )
    assert not (tmp_path / "run").exists()
