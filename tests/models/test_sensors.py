"""The measurement model (testbed.models.sensors): closed forms, complex-step derivatives, inverse."""

from __future__ import annotations

import math

import numpy as np
import pytest

from testbed.errors import InputError
from testbed.models.linear import IX, STATES
from testbed.models.sensors import GRAVITY, Sensor, linearize, outputs, recover

G = GRAVITY


def state(**values) -> np.ndarray:
    x = np.zeros(10)
    for k, v in values.items():
        x[IX[k]] = v
    return x


EVERYTHING = dict(
    position=(0.3, -0.05, 0.12),
    misalignment=(0.004, -0.003, 0.006),
    bias={"u": 0.01, "q": 2e-4, "psi": 0.003, "z": 0.1, "ax": 0.02},
    scale={"u": 0.003, "r": -0.001, "az": 0.002},
)
ALL = (*STATES, "ax", "ay", "az")


def complex_step(f, x, h=1e-30):
    """∂f/∂x by complex step (exact to rounding: no subtraction)."""
    cols = []
    for i in range(len(x)):
        xc = np.array(x, complex)
        xc[i] += 1j * h
        cols.append(f(xc).imag / h)
    return np.column_stack(cols)


@pytest.mark.parametrize("frame", ["body", "earth"])
def test_linearization_matches_complex_step(frame):
    outs = ALL if frame == "body" else STATES
    kept = {k: {o: v for o, v in EVERYTHING[k].items() if o in outs} for k in ("bias", "scale")}
    s = Sensor(name="imu", outputs=outs, frame=frame, **{**EVERYTHING, **kept})
    current = (0.2, -0.25, 0.01)
    x0 = state(u=19.5, v=0.0, psi=0.7, z=100.0)
    C, D, y0 = linearize(s, x0, current)
    xd0 = np.zeros(10)
    Cc = complex_step(lambda x: outputs(s, x, xd0, current), x0)
    Dc = complex_step(lambda xd: outputs(s, x0, xd, current), xd0)
    np.testing.assert_allclose(C, Cc, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(D, Dc, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(y0, outputs(s, x0, xd0, current), rtol=0, atol=0)


def test_complex_step_agrees_with_differences_away_from_trim():
    """The exact map is analytic: its complex-step Jacobian is the central differences' limit."""
    s = Sensor(name="imu", outputs=ALL, **EVERYTHING)
    rng = np.random.default_rng(3)
    x = state(u=19.0, v=0.3, w=-0.2, p=0.2, q=0.05, r=-0.1, phi=0.3, theta=-0.2, psi=2.5, z=80.0)
    xd = rng.normal(size=10)
    J = complex_step(lambda z: outputs(s, z, xd, (0.3, 0.1, 0.0)), x)
    h = 1e-6
    Jd = np.column_stack(
        [
            (outputs(s, x + h * e, xd, (0.3, 0.1, 0.0)) - outputs(s, x - h * e, xd, (0.3, 0.1, 0.0)))
            / (2 * h)
            for e in np.eye(10)
        ]
    )
    np.testing.assert_allclose(J, Jd, atol=1e-7)


def test_lever_arm_reads_the_points_velocity():
    r = (0.3, -0.05, 0.12)
    s = Sensor(name="dvl", outputs=("u", "v", "w"), position=r)
    u, v, w, p, q, rr = 19.0, 0.1, -0.05, 0.2, 0.03, -0.04
    y = outputs(s, state(u=u, v=v, w=w, p=p, q=q, r=rr))
    expected = [u + q * r[2] - rr * r[1], v + rr * r[0] - p * r[2], w + p * r[1] - q * r[0]]
    np.testing.assert_allclose(y, expected, rtol=1e-15)


def test_depth_at_a_point_forward_of_the_cg():
    s = Sensor(name="depth", outputs=("z",), position=(0.5, 0.0, 0.2))
    theta, phi = 0.1, 0.2
    y = outputs(s, state(z=50.0, theta=theta, phi=phi))
    # the point's depth: −x sin θ + z cos θ cos φ (earth z of C r)
    assert y[0] == pytest.approx(
        50.0 - 0.5 * math.sin(theta) + 0.2 * math.cos(theta) * math.cos(phi), abs=1e-14
    )


def test_earth_frame_velocity_turns_with_the_heading_and_adds_the_current():
    s = Sensor(name="ins", outputs=("u", "v", "w"), frame="earth")
    y = outputs(s, state(u=2.0, psi=math.pi / 2), current=(0.3, 0.0, 0.0))
    np.testing.assert_allclose(y, [0.3, 2.0, 0.0], atol=1e-15)
    body = Sensor(name="dvl", outputs=("u", "v", "w"))  # a DVL over the ground: Cᵀ c added
    np.testing.assert_allclose(
        outputs(body, state(u=2.0, psi=math.pi / 2), current=(0.3, 0.0, 0.0)), [2.0, -0.3, 0.0], atol=1e-15
    )


def test_accelerometer_at_rest_reads_minus_g_and_the_centripetal_acceleration():
    s = Sensor(name="acc", outputs=("ax", "ay", "az"))
    np.testing.assert_allclose(outputs(s, state(), np.zeros(10)), [0.0, 0.0, -G], atol=1e-15)
    theta = 0.3
    np.testing.assert_allclose(
        outputs(s, state(theta=theta), np.zeros(10)),
        [G * math.sin(theta), 0.0, -G * math.cos(theta)],
        atol=1e-14,
    )
    spun = Sensor(name="acc", outputs=("ax", "ay", "az"), position=(1.0, 0.0, 0.0))
    Omega = 0.5  # yawing in place: −Ω² r towards the centre
    np.testing.assert_allclose(
        outputs(spun, state(r=Omega), np.zeros(10)), [-(Omega**2), 0.0, -G], atol=1e-14
    )
    with pytest.raises(InputError, match="derivative"):
        outputs(s, state())


def test_bias_scale_and_misalignment():
    s = Sensor(
        name="gyro", outputs=("p", "q", "r"), bias={"q": 1e-3}, scale={"q": 0.01}, misalignment=(0, 0, 0.1)
    )
    p, q = 0.2, 0.05
    y = outputs(s, state(p=p, q=q))
    # axes yawed by a: the sensor's x axis is (cos a, sin a, 0) in body axes
    a = 0.1
    np.testing.assert_allclose(
        y,
        [math.cos(a) * p + math.sin(a) * q, 1.01 * (-math.sin(a) * p + math.cos(a) * q) + 1e-3, 0.0],
        atol=1e-15,
    )


def test_default_sensor_reads_the_states():
    x = 0.3 * np.random.default_rng(1).normal(size=(5, 10))
    np.testing.assert_array_equal(outputs(Sensor(), x), x)


def test_recover_inverts_the_outputs():
    rng = np.random.default_rng(7)
    n = 50
    x = np.zeros((n, 10))
    x[:, IX["u"]] = 19 + rng.normal(size=n)
    for k in ("v", "w", "p", "q", "r", "phi", "theta"):
        x[:, IX[k]] = 0.3 * rng.normal(size=n)
    x[:, IX["psi"]] = np.cumsum(rng.normal(size=n))  # unwrapped, many turns
    x[:, IX["z"]] = 100 + rng.normal(size=n)
    current = (0.25, -0.1, 0.0)
    rates, attitude = x[:, 3:6], x[:, 6:9]
    sensors = [
        Sensor(
            name="dvl",
            outputs=("u", "v", "w"),
            position=(0.3, 0.0, 0.1),
            misalignment=(0.01, -0.02, 0.03),
            bias={"v": 0.01},
            scale={"u": 0.002},
        ),
        Sensor(name="ins", outputs=("u", "v", "w"), frame="earth", position=(-0.5, 0.02, 0.0)),
        Sensor(
            name="ahrs",
            outputs=("p", "q", "r", "phi", "theta", "psi"),
            misalignment=(0.02, 0.01, -0.03),
            bias={"r": 1e-3},
        ),
        Sensor(name="depth", outputs=("z",), position=(1.0, 0.0, -0.1), bias={"z": 0.2}),
        Sensor(name="aligned", outputs=("v",), position=(0.3, 0.0, 0.0)),
    ]
    for s in sensors:
        got = recover(s, outputs(s, x, current=current), rates, attitude, current)
        assert set(got) == {o for o in s.outputs}
        for name, values in got.items():
            np.testing.assert_allclose(values, x[:, IX[name]], atol=1e-12, err_msg=f"{s.name} {name}")


@pytest.mark.parametrize(
    "kw, field",
    [
        (dict(outputs=("u", "x")), "outputs"),
        (dict(outputs=()), "outputs"),
        (dict(outputs=("u", "u")), "outputs"),
        (dict(position=(0, 0)), "position"),
        (dict(position=(0, 0, math.nan)), "position"),
        (dict(misalignment=(0, 0, 1.0)), "misalignment"),
        (dict(frame="ned"), "frame"),
        (dict(outputs=("ax", "ay", "az"), frame="earth"), "frame"),
        (dict(outputs=("u", "v"), frame="earth"), "outputs"),
        (dict(outputs=("u",), bias={"v": 1.0}), "bias.v"),
        (dict(outputs=("u",), bias={"u": math.inf}), "bias.u"),
        (dict(outputs=("u",), scale={"u": -1.0}), "scale.u"),
        (dict(outputs=("u",), noise_std={"u": -1.0}), "noise_std.u"),
        (dict(delay=-0.1), "delay"),
        (dict(rate=0.0), "rate"),
    ],
)
def test_bad_sensor_is_one_line_naming_the_field(kw, field):
    with pytest.raises(InputError) as err:
        Sensor(name="s", **kw)
    msg = str(err.value)
    assert field in msg and "sensor 's'" in msg and "\n" not in msg
