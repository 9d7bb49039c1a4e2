"""Sensors: what each of a vehicle's sensors outputs, as a function of the state and its derivative.

A sensor (`Sensor`) outputs some of the states `u v w p q r phi theta psi z` and the specific
force `ax ay az`. Where it sits and how it is mounted changes what it reads (body axes FRD,
earth axes NED, r its `position` from the CG, M = Rz(a₃) Ry(a₂) Rx(a₁) the rotation from its
axes to the body's for its `misalignment` a, C the body-to-earth rotation Rz(ψ) Ry(θ) Rx(φ),
c the water's velocity over the ground, earth axes):

| outputs | what the sensor reads |
|---|---|
| u v w, frame "body" | Mᵀ (v + Cᵀ c + ω × r): the ground velocity of its point, in its axes (a DVL) |
| u v w, frame "earth" | C (v + ω × r) + c: the same in earth axes, north-east-down (an INS) |
| p q r | Mᵀ ω (gyros) |
| phi theta psi | the Euler angles of C M: its own axes' attitude (an AHRS) |
| z | z + (C r)₃: the depth of its point (a pressure sensor) |
| ax ay az | Mᵀ (v̇ + ω × v + ω̇ × r + ω × (ω × r) − Cᵀ (0, 0, g)): the specific force at its point |

v and ω are the body-axis velocity through the water and angular velocity at the CG (the
model's states); the accelerometers need v̇ and ω̇ (a steady current adds nothing to them: the
ground velocity's inertial rate is v̇ + ω × v either way). Each output is then
`(1 + scale) · reading + bias`. A sensor's `delay` (its output at t is the reading at t − delay),
`rate`, `noise_std`, `resolution` (its outputs' quantisation step) and `hold` (its last sample
repeated in the rows between its own samples) say how it is sampled and logged, which is the
simulation's business (`testbed.simulation.sensing`). The default sensor reads every state at the CG, unbiased: the
sensors of a run without imperfections.

`outputs` is the exact map, analytic in the state (so complex-step differentiable);
`linearize` its Jacobians at a straight and level trim (y ≈ y₀ + C (x − x₀) + D ẋ); `recover`
its inverse for known sensor parameters: the CG's body-axis states from the outputs, given the
body rates and attitude (a real log's DVL away from the CG, or an INS's earth-frame velocity).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from testbed.errors import InputError, is_number
from testbed.models.linear import IX, STATES

__all__ = [
    "ACCELERATIONS",
    "FRAMES",
    "GRAVITY",
    "OUTPUTS",
    "Sensor",
    "euler",
    "late",
    "linearize",
    "needs",
    "outputs",
    "recover",
    "rotation",
    "states_from",
]

ACCELERATIONS = ("ax", "ay", "az")  # specific force, body (sensor) axes, m/s²
OUTPUTS = (*STATES, *ACCELERATIONS)
FRAMES = ("body", "earth")  # what a velocity sensor's u v w are resolved in
GRAVITY = 9.81  # m/s², the bundled MJCF's
_GROUPS = {
    "velocity": ("u", "v", "w"),
    "rate": ("p", "q", "r"),
    "attitude": ("phi", "theta", "psi"),
    "depth": ("z",),
    "specific force": ACCELERATIONS,
}
_ZERO3 = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Sensor:
    """One sensor: its outputs, where it sits, how it is mounted, its errors and its sampling."""

    name: str = "sensors"
    outputs: tuple[str, ...] = STATES
    position: tuple[float, float, float] = _ZERO3  # from the CG, body axes, m
    misalignment: tuple[float, float, float] = _ZERO3  # its axes' rotation from the body's, rad
    frame: str = "body"  # u v w in body ("body") or north-east-down ("earth") axes
    bias: Mapping[str, float] = field(default_factory=dict)  # per output, its unit
    scale: Mapping[str, float] = field(default_factory=dict)  # per output, scale-factor error (fraction)
    delay: float = 0.0  # s
    rate: float | None = None  # Hz; None: the record's sample rate
    noise_std: Mapping[str, float] = field(default_factory=dict)  # per output, white, its unit
    resolution: Mapping[str, float] = field(default_factory=dict)  # per output, its quantisation step
    hold: bool = False  # its last sample logged again in the rows between its own samples

    def __post_init__(self):
        where = f"sensor {self.name!r}"
        outs = self.outputs
        if not isinstance(outs, tuple) or not outs or any(o not in OUTPUTS for o in outs):
            raise InputError(
                f"{where}: outputs {list(outs)!r}; expected a non-empty list of {', '.join(OUTPUTS)}"
            )
        if len(set(outs)) != len(outs):
            raise InputError(f"{where}: outputs {list(outs)}; expected each output once")
        for key in ("position", "misalignment"):
            v = getattr(self, key)
            if not isinstance(v, tuple) or len(v) != 3 or not all(is_number(a) for a in v):
                raise InputError(f"{where}: {key} {v!r}; expected three finite numbers")
        if any(abs(a) > 0.5 for a in self.misalignment):
            raise InputError(
                f"{where}: misalignment {list(self.misalignment)}; expected small angles, |a| <= 0.5 rad"
            )
        if self.frame not in FRAMES:
            raise InputError(f"{where}: frame {self.frame!r}; expected one of {', '.join(FRAMES)}")
        if self.frame == "earth" and any(o in outs for o in ACCELERATIONS):
            raise InputError(
                f"{where}: frame 'earth' with specific force outputs; expected body axes for ax ay az"
            )
        rotated = self.frame == "earth" or any(self.misalignment)
        for group, names in _GROUPS.items():
            held = [o for o in names if o in outs]
            if rotated and held and len(held) != len(names) and group != "depth":
                raise InputError(
                    f"{where}: outputs {held} of the {group}; expected all of {', '.join(names)} "
                    "for a misaligned or earth-frame sensor (it turns the whole vector)"
                )
        checks = {
            "bias": (is_number, "a finite number"),
            "scale": (lambda s: is_number(s) and s > -1, "a finite number > -1 (fraction)"),
            "noise_std": (lambda s: is_number(s) and s >= 0, "a finite number >= 0"),
            "resolution": (lambda s: is_number(s) and s > 0, "a finite number > 0 (its unit)"),
        }
        for key, (ok, expected) in checks.items():
            table = getattr(self, key)
            if not isinstance(table, Mapping):
                raise InputError(f"{where}: {key} {table!r}; expected a table of output = value")
            for o, s in table.items():
                if o not in outs:
                    raise InputError(f"{where}: {key}.{o}: not an output; expected one of {', '.join(outs)}")
                if not ok(s):
                    raise InputError(f"{where}: {key}.{o} = {s!r}; expected {expected}")
        if not (is_number(self.delay) and 0 <= self.delay <= 10.0):
            raise InputError(f"{where}: delay {self.delay!r}; expected a finite number 0 to 10 (s)")
        if self.rate is not None and not (is_number(self.rate) and self.rate > 0):
            raise InputError(f"{where}: rate {self.rate!r}; expected a finite number > 0 (Hz)")
        if not isinstance(self.hold, bool):
            raise InputError(f"{where}: hold {self.hold!r}; expected true or false")


# -- rotations -----------------------------------------------------------------------------------


def rotation(phi, theta, psi) -> np.ndarray:
    """Rz(ψ) Ry(θ) Rx(φ), (..., 3, 3): body to earth for Euler angles (complex too)."""
    cf, sf, ct, st, cp, sp = np.cos(phi), np.sin(phi), np.cos(theta), np.sin(theta), np.cos(psi), np.sin(psi)
    rows = [
        [ct * cp, sf * st * cp - cf * sp, cf * st * cp + sf * sp],
        [ct * sp, sf * st * sp + cf * cp, cf * st * sp - sf * cp],
        [-st, sf * ct, cf * ct],
    ]
    return np.stack([np.stack(np.broadcast_arrays(*row), -1) for row in rows], -2)


def _atan2(y, x):
    """atan2, analytic for complex arguments (its imaginary part: the complex step's)."""
    if np.iscomplexobj(y) or np.iscomplexobj(x):
        return np.arctan2(y.real, x.real) + 1j * np.arctan(y / x).imag
    return np.arctan2(y, x)


def euler(R: np.ndarray) -> np.ndarray:
    """(φ, θ, ψ), (..., 3), of rotations R = Rz(ψ) Ry(θ) Rx(φ) (..., 3, 3); ψ in (−π, π]."""
    return np.stack(
        [_atan2(R[..., 2, 1], R[..., 2, 2]), -np.arcsin(R[..., 2, 0]), _atan2(R[..., 1, 0], R[..., 0, 0])], -1
    )


def _turns(angle):
    """The whole turns (multiples of 2π) nearest `angle`."""
    return 2 * math.pi * np.round(angle / (2 * math.pi))


def _apply(R, v):
    return np.einsum("...ij,...j->...i", R, v)


def _apply_t(R, v):
    return np.einsum("...ji,...j->...i", R, v)


# -- the map and its inverse ---------------------------------------------------------------------


def _vector(x, names):
    return np.stack([x[..., IX[n]] for n in names], -1)


def _readings(sensor: Sensor, x, xdot=None, current=_ZERO3, gravity: float = GRAVITY) -> dict:
    """Every quantity the sensor's outputs are taken from, before its scale and bias: output -> (...)."""
    x = np.asarray(x)
    r = np.asarray(sensor.position, float)
    M = rotation(*sensor.misalignment)
    v, w = _vector(x, ("u", "v", "w")), _vector(x, ("p", "q", "r"))
    C = rotation(x[..., IX["phi"]], x[..., IX["theta"]], x[..., IX["psi"]])
    out = {}
    wanted = set(sensor.outputs)
    if wanted & {"u", "v", "w"}:
        point = v + np.cross(w, np.broadcast_to(r, w.shape))
        if sensor.frame == "earth":
            vel = _apply(C, point) + np.asarray(current, float)
        else:
            vel = _apply_t(M, point + _apply_t(C, np.broadcast_to(np.asarray(current, float), v.shape)))
        out.update(zip(("u", "v", "w"), np.moveaxis(vel, -1, 0)))
    if wanted & {"p", "q", "r"}:
        out.update(zip(("p", "q", "r"), np.moveaxis(_apply_t(M, w), -1, 0)))
    if wanted & {"phi", "theta", "psi"} and not any(sensor.misalignment):
        out.update((n, x[..., IX[n]]) for n in ("phi", "theta", "psi"))
    elif wanted & {"phi", "theta", "psi"}:
        angles = euler(np.einsum("...ij,jk->...ik", C, M))
        angles[..., 2] -= _turns(angles[..., 2].real - x[..., IX["psi"]].real)  # next to the unwrapped ψ
        out.update(zip(("phi", "theta", "psi"), np.moveaxis(angles, -1, 0)))
    if "z" in wanted:
        out["z"] = x[..., IX["z"]] + _apply(C, np.broadcast_to(r, v.shape))[..., 2]
    if wanted & set(ACCELERATIONS):
        if xdot is None:
            raise InputError(f"sensor {sensor.name!r}: specific force needs the state derivative")
        xdot = np.asarray(xdot)
        vd, wd = _vector(xdot, ("u", "v", "w")), _vector(xdot, ("p", "q", "r"))
        rr = np.broadcast_to(r, w.shape)
        a = vd + np.cross(w, v) + np.cross(wd, rr) + np.cross(w, np.cross(w, rr))
        g = _apply_t(C, np.broadcast_to(np.array([0.0, 0.0, gravity]), v.shape))
        out.update(zip(ACCELERATIONS, np.moveaxis(_apply_t(M, a - g), -1, 0)))
    return {o: out[o] for o in sensor.outputs}


def outputs(sensor: Sensor, x, xdot=None, current=_ZERO3, gravity: float = GRAVITY) -> np.ndarray:
    """The sensor's outputs (..., len(outputs)), noise-free and undelayed, at the states x
    (..., 10; absolute u) and their derivatives xdot (needed for ax ay az only); `current`: the
    water's velocity over the ground, NED, m/s."""
    read = _readings(sensor, x, xdot, current, gravity)
    return np.stack(
        [(1.0 + sensor.scale.get(o, 0.0)) * read[o] + sensor.bias.get(o, 0.0) for o in sensor.outputs], -1
    )


def recover(sensor: Sensor, y, rates, attitude, current=_ZERO3) -> dict:
    """The CG's body-axis states that the sensor's outputs y (..., len(outputs)) measure, for
    its known parameters: bias and scale undone, then its axes, the earth frame, the current
    and the lever arm (ω × r with the given body `rates` (..., 3) and the body `attitude` φ θ ψ
    (..., 3)). Velocities need all three of u v w unless the sensor is at the CG and aligned."""
    y = np.asarray(y, float)
    if any(o in ACCELERATIONS for o in sensor.outputs):
        raise InputError(f"sensor {sensor.name!r}: specific force has no state to recover")
    read = {
        o: (y[..., k] - sensor.bias.get(o, 0.0)) / (1.0 + sensor.scale.get(o, 0.0))
        for k, o in enumerate(sensor.outputs)
    }
    rates, attitude = np.asarray(rates, float), np.asarray(attitude, float)
    M = rotation(*sensor.misalignment)
    C = rotation(attitude[..., 0], attitude[..., 1], attitude[..., 2])
    r = np.broadcast_to(np.asarray(sensor.position, float), rates.shape)
    c = np.broadcast_to(np.asarray(current, float), rates.shape)
    out = {}
    if "p" in read:
        w = _apply(M, np.stack([read.get(n, np.zeros(y.shape[:-1])) for n in ("p", "q", "r")], -1))
        out.update({n: w[..., i] for i, n in enumerate(("p", "q", "r")) if n in read})
    if "phi" in read:
        body = euler(np.einsum("...ij,kj->...ik", rotation(read["phi"], read["theta"], read["psi"]), M))
        body[..., 2] -= _turns(body[..., 2] - read["psi"])
        out.update(zip(("phi", "theta", "psi"), np.moveaxis(body, -1, 0)))
    held = [n for n in ("u", "v", "w") if n in read]
    if held:
        vec = np.stack([read.get(n, np.zeros(y.shape[:-1])) for n in ("u", "v", "w")], -1)
        if sensor.frame == "earth":
            point = _apply_t(C, vec - c)
        else:
            point = _apply(M, vec) - _apply_t(C, c)
        v = point - np.cross(rates, r)
        out.update({n: v[..., i] for i, n in enumerate(("u", "v", "w")) if n in read})
    if "z" in read:
        out["z"] = read["z"] - _apply(C, r)[..., 2]
    return {s: out[s] for s in STATES if s in out}


def late(t: np.ndarray, y: np.ndarray, delay: float) -> np.ndarray:
    """A channel read `delay` s late put back on time: y(t + delay) on the uniform grid `t`,
    linearly interpolated between its samples present (finite), and present only where the
    sample nearest t + delay is (a slower sensor keeps its own samples, moved back by the
    delay, never filled in); missing where t + delay passes its last one."""
    there = np.isfinite(y)
    if not delay or not there.any():
        return y
    s = t + delay
    out = np.interp(s, t[there], y[there])
    nearest = np.clip(np.rint((s - t[0]) / (t[1] - t[0])).astype(int), 0, len(t) - 1)
    out[~there[nearest] | (s > t[there][-1])] = np.nan
    return out


def needs(sensor: Sensor) -> tuple[bool, bool]:
    """Whether undoing `sensor` needs the body rates (a velocity sensor away from the CG) and
    the attitude (a velocity sensor in earth axes, a depth sensor away from the CG)."""
    moved = any(sensor.position)
    velocity = bool({"u", "v", "w"} & set(sensor.outputs))
    return velocity and moved, (velocity and sensor.frame == "earth") or ("z" in sensor.outputs and moved)


def states_from(sensor: Sensor, t: np.ndarray, readings: np.ndarray, rates=None, attitude=None) -> dict:
    """The CG's body-axis states (state -> (N,)) that a sensor's `readings` (N, len(outputs)),
    sampled at `t` and read `delay` s late, measure for its known parameters (`recover`, after
    `late`); `rates` and `attitude` (N, 3) where `needs` says so (else zeros). A sample whose
    correction needs a missing one is missing."""
    y = np.column_stack([late(t, readings[:, k], sensor.delay) for k in range(readings.shape[1])])
    zeros = np.zeros((len(t), 3))
    rates = zeros if rates is None else np.asarray(rates, float)
    attitude = zeros if attitude is None else np.asarray(attitude, float)
    return recover(sensor, y, rates, attitude)


# -- the linearisation at trim -------------------------------------------------------------------


def _skew(a) -> np.ndarray:
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def linearize(sensor: Sensor, x0, current=_ZERO3, gravity: float = GRAVITY):
    """(C, D, y₀) with y ≈ y₀ + C (x − x₀) + D ẋ near a straight and level trim x₀ (10,: φ = θ = 0
    and no rates; any speed, heading and depth) with ẋ₀ = 0. Closed forms: at level trim a small
    attitude change δ = (δφ, δθ, δψ) turns C into C₀ (I + [δ]×), and an Euler-angle change of the
    sensor's axes is W⁻¹ of its body-axis rotation (W: Euler rates to body rates)."""
    x0 = np.asarray(x0, float)
    if any(abs(x0[IX[n]]) > 1e-12 for n in ("p", "q", "r", "phi", "theta")):
        raise InputError(f"sensor {sensor.name!r}: linearize needs a straight and level trim (p q r φ θ = 0)")
    M = rotation(*sensor.misalignment)
    C0 = rotation(0.0, 0.0, x0[IX["psi"]])
    r, c = np.asarray(sensor.position, float), np.asarray(current, float)
    v0 = np.array([x0[IX["u"]], x0[IX["v"]], x0[IX["w"]]])
    cb = C0.T @ c
    E = np.eye(3)
    iv, iw, ia, iz = 0, 3, 6, 9  # the first columns of v, ω, the attitude and z
    rows_C, rows_D = {}, {}

    def put(names, Cblock, Dblock=None):
        for i, n in enumerate(names):
            row_c, row_d = np.zeros(10), np.zeros(10)
            for start, block in Cblock.items():
                row_c[start : start + 3] = block[i]
            for start, block in (Dblock or {}).items():
                row_d[start : start + 3] = block[i]
            rows_C[n], rows_D[n] = row_c, row_d

    if sensor.frame == "earth":
        dvel = np.column_stack([C0 @ np.cross(E[i], v0) for i in range(3)])
        put(("u", "v", "w"), {iv: C0, iw: -C0 @ _skew(r), ia: dvel})
    else:
        dvel = np.column_stack([M.T @ np.cross(cb, E[i]) for i in range(3)])
        put(("u", "v", "w"), {iv: M.T, iw: -M.T @ _skew(r), ia: dvel})
    put(("p", "q", "r"), {iw: M.T})
    phi_s, theta_s, _ = euler(C0 @ M)
    W = np.array(
        [
            [1.0, 0.0, -math.sin(theta_s)],
            [0.0, math.cos(phi_s), math.cos(theta_s) * math.sin(phi_s)],
            [0.0, -math.sin(phi_s), math.cos(theta_s) * math.cos(phi_s)],
        ]
    )
    put(("phi", "theta", "psi"), {ia: np.linalg.solve(W, M.T)})
    dz = np.zeros((1, 10))
    dz[0, iz], dz[0, ia : ia + 3] = 1.0, np.cross(r, E[2])
    rows_C["z"], rows_D["z"] = dz[0], np.zeros(10)
    put(
        ACCELERATIONS,
        {iw: -M.T @ _skew(v0), ia: -gravity * M.T @ _skew(E[2])},
        {iv: M.T, iw: -M.T @ _skew(r)},
    )
    gain = np.array([1.0 + sensor.scale.get(o, 0.0) for o in sensor.outputs])
    Cm = gain[:, None] * np.array([rows_C[o] for o in sensor.outputs])
    Dm = gain[:, None] * np.array([rows_D[o] for o in sensor.outputs])
    y0 = outputs(sensor, x0, np.zeros(10), current, gravity)
    return Cm, Dm, y0
