"""The captive reference: the nonlinear model fitted to captive tests of the plant, in two stages.

1. **At trim**: the terms with a slope at trim (`slope_terms`: every factor u but one, which is
   no magnitude, and X_uu; they alone make the linearisation, docs/model.md) are fitted to the
   same tests at 1/1000 of their extents, at the trim speed U alone: there the other terms'
   share of the forces is a millionth of theirs, so these coefficients are the plant's slopes at
   trim, as a towing tank reads linear derivatives from small-amplitude tests.
2. **Over the manoeuvre**: the other terms, those held, fitted to the tests over the region a
   manoeuvre flies (`reference_tests`).

The region is Scenario I's (the torpedo at 20 m/s flies |v| ≤ 0.5 m/s, |w| ≤ 1.5 m/s,
|p|, |r| ≤ 0.36 rad/s, |q| ≤ 1.65 rad/s, δr ≤ 0.04, δe ≤ 0.15 rad, down to 16.4 m/s) with a
margin (`ENVELOPE`), scaled to another trim speed U by U/20 (velocities and rates; fin angles as
they are): at 0.8 U, 0.9 U and U, a sweep of each variable to its extent, a 7 × 7 grid of every
pair of variables to half their extents (the pairs carry the couplings, the flight's states lie
mostly well inside the envelope) and an oscillation of each velocity (u by 0.1 U) for the
inertia coefficients. Fitted over the plain default captive tests (extents ±3 m/s, ±2 rad/s, fins
±0.4 rad) the polynomial terms bend to extremes the manoeuvre never reaches (docs/captive.md).
"""

from __future__ import annotations

import dataclasses
import itertools
from dataclasses import dataclass

import mujoco
import numpy as np

from testbed.errors import InputError
from testbed.models.nonlinear import TERMS, NonlinearModel, linearise, nonlinear_model, nonlinear_theta
from testbed.models.regressors import component_kind, parse_term
from testbed.captive.rig import Oscillation, Sweep, captive_tests
from testbed.captive.fit import CaptiveFit, fit_captive, pmm_inertia
from testbed.captive.fluid_components import component_terms, inertia_terms, mjcf_components, rigid_inertia
from testbed.simulation.vehicle import constants
from testbed.captive.wrench import hydrodynamic_wrench

__all__ = [
    "BAND",
    "ENVELOPE",
    "NEAR",
    "Turns",
    "captive_reference",
    "component_reference",
    "couplings",
    "near_tests",
    "reference_tests",
    "region_tests",
    "slope_terms",
    "steady_turns",
    "turn_tests",
]

# The extents at 20 m/s: m/s for v w, rad/s for p q r, rad for the fins (delta_d differential)
ENVELOPE = {"v": 0.75, "w": 1.6, "p": 0.5, "q": 1.7, "r": 0.5, "delta_r": 0.1, "delta_e": 0.2, "delta_d": 0.1}
# The turn tests' band about a steady turn at 20 m/s: m/s for v w, rad for the fins
BAND = {"w": 0.3, "v": 0.2, "delta_e": 0.03, "delta_r": 0.02}
NEAR = 1e-3  # the trim stage's tests, as a fraction of the extents
_FINS = ("delta_r", "delta_e", "delta_d")


# Each term factor's captive-test variable (u is held at each speed; |vw| and |qr| vary a pair)
_VARIABLE = {
    **{k: (k,) for k in "vwpqr"},
    **{f"|{k}|": (k,) for k in "vwpqr"},
    "dr": ("delta_r",),
    "de": ("delta_e",),
    "da": ("delta_d",),
    **{f"|d{k}|": (f"delta_{n}",) for k, n in (("r", "r"), ("e", "e"), ("a", "d"))},
    "|vw|": ("v", "w"),
    "|qr|": ("q", "r"),
    "u": (),
}


def couplings(terms=TERMS) -> tuple[tuple[str, ...], ...]:
    """The sets of three or more test variables that a term multiplies together (`K_pwq`: p, w,
    q), in `ENVELOPE`'s order: a grid of them is the only test that moves such a term."""
    order = list(ENVELOPE)
    found = set()
    for name in terms:
        varied = {v for a in parse_term(name).factors for v in _VARIABLE[a]}
        if len(varied) >= 3:
            found.add(tuple(sorted(varied, key=order.index)))
    return tuple(sorted(found, key=lambda c: [order.index(v) for v in c]))


@dataclass(frozen=True)
class Turns:
    """A steady turn's drift and fin per unit turn rate (the model's at trim): in pitch
    w = `incidence` q and δe = `elevator` q, in yaw v = `drift` r and δr = `rudder` r."""

    incidence: float  # m per rad (w/q)
    elevator: float  # s (δe/q)
    drift: float  # m per rad (v/r)
    rudder: float  # s (δr/r)


def steady_turns(model: NonlinearModel, theta) -> Turns:
    """The steady turns of `model` at `theta` linearised at trim: the heave and pitch rows with
    ẇ = q̇ = 0 solved for w and δe at q = 1 rad/s (weight and buoyancy left out: a rotating arm
    holds the attitude), the sway and yaw rows for v and δr at r = 1 rad/s."""
    lin = linearise(model, theta)
    A, B = lin.At, lin.Bt
    de = B[:, 1] + B[:, 2]
    w, e = np.linalg.solve([[A[2, 2], de[2]], [A[4, 2], de[4]]], [-A[2, 4], -A[4, 4]])
    v, r = np.linalg.solve([[A[1, 1], B[1, 0]], [A[5, 1], B[5, 0]]], [-A[1, 5], -A[5, 5]])
    return Turns(incidence=float(w), elevator=float(e), drift=float(v), rudder=float(r))


def turn_tests(speed: float, turns: Turns) -> tuple:
    """Rotating-arm tests along the steady turns at 0.8 U, 0.9 U and U: the pitch rate over
    its extent (13 points), the incidence and the elevators about the turn's by ±`BAND` (3 × 3);
    the same in yaw; and both turns at once (7 × 7 rates)."""
    scale = speed / 20.0
    speeds = (0.8 * speed, 0.9 * speed, speed)
    q, r = ENVELOPE["q"] * scale, ENVELOPE["r"] * scale
    band = {k: e if k in _FINS else e * scale for k, e in BAND.items()}
    pitch = (("w", "q", turns.incidence), ("delta_e", "q", turns.elevator))
    yaw = (("v", "r", turns.drift), ("delta_r", "r", turns.rudder))
    return (
        Sweep(
            name="turn_pitch",
            vary=("q", "w", "delta_e"),
            extent=(q, band["w"], band["delta_e"]),
            points=(13, 3, 3),
            speeds=speeds,
            follow=pitch,
        ),
        Sweep(
            name="turn_yaw",
            vary=("r", "v", "delta_r"),
            extent=(r, band["v"], band["delta_r"]),
            points=(13, 3, 3),
            speeds=speeds,
            follow=yaw,
        ),
        Sweep(
            name="turn_both",
            vary=("q", "r", "w", "v", "delta_e", "delta_r"),
            extent=(q, r, 0.0, 0.0, 0.0, 0.0),
            points=(7, 7, 1, 1, 1, 1),
            speeds=speeds,
            follow=pitch + yaw,
        ),
    )


def reference_tests(speed: float, terms=TERMS, turns: Turns | None = None) -> tuple:
    """The captive tests over the manoeuvre's region at trim speed `speed` (module doc), with a
    grid of each set of variables that one of `terms` couples (`couplings`), and with `turns`
    the rotating-arm tests along them (`turn_tests`)."""
    if not 0 < speed < np.inf:
        raise InputError(f"speed={speed!r}; expected a finite trim speed > 0 m/s")
    scale = speed / 20.0
    extent = {k: e if k in _FINS else e * scale for k, e in ENVELOPE.items()}
    speeds = (0.8 * speed, 0.9 * speed, speed)
    sweeps = tuple(
        Sweep(name=k, vary=(k,), extent=(e,), points=(13,), speeds=speeds) for k, e in extent.items()
    )
    pairs = tuple(
        Sweep(
            name=f"{a}_{b}", vary=(a, b), extent=(extent[a] / 2, extent[b] / 2), points=(7, 7), speeds=speeds
        )
        for a, b in itertools.combinations(extent, 2)
    )
    combined = tuple(
        Sweep(
            name="_".join(c),
            vary=c,
            extent=tuple(extent[k] / 2 for k in c),
            points=(5,) * len(c),
            speeds=speeds,
        )
        for c in couplings(terms)
    )
    amplitude = {"u": 0.1 * speed, **{k: extent[k] for k in "vwpqr"}}
    oscillations = tuple(
        Oscillation(name=f"pure_{k}", variable=k, amplitude=a, speeds=speeds) for k, a in amplitude.items()
    )
    return sweeps + pairs + combined + oscillations + (turn_tests(speed, turns) if turns else ())


def near_tests(tests, speed: float, fraction: float = NEAR) -> tuple:
    """`tests` at `fraction` of their extents and amplitudes, at `speed` alone."""
    out = []
    for t in tests:
        if isinstance(t, Sweep):
            out.append(dataclasses.replace(t, extent=tuple(e * fraction for e in t.extent), speeds=(speed,)))
        else:
            out.append(dataclasses.replace(t, amplitude=t.amplitude * fraction, speeds=(speed,)))
    return tuple(out)


def slope_terms(terms=TERMS) -> tuple[str, ...]:
    """The terms with a slope at trim: each factor u but one, not a magnitude (`Y_uv`,
    `Z_uude`), and the pure-u terms (`X_uu`)."""
    out = []
    for name in terms:
        rest = [a for a in parse_term(name).factors if a != "u"]
        if not rest or (len(rest) == 1 and not rest[0].startswith("|")):
            out.append(name)
    return tuple(out)


def _design(terms) -> tuple[str, ...]:
    """The terms the tests are designed for: `terms`, or for a component model (any term of a
    component) the default `TERMS`, whose region and couplings the component terms share."""
    return TERMS if any(component_kind(t) for t in terms) else tuple(terms)


def _trim_stage(model: mujoco.MjModel, speed: float, terms):
    """(vehicle, thrust, the trim stage's fit of the slope terms) at trim speed `speed`."""
    terms = _design(terms)
    vehicle = constants(model, speed)
    thrust = -float(hydrodynamic_wrench(model, [speed, 0, 0, 0, 0, 0])[0])  # the drag at trim
    near = near_tests(reference_tests(speed, terms), speed)
    first = fit_captive(vehicle, near, captive_tests(model, near), thrust, terms=slope_terms(terms))
    return vehicle, thrust, first


def _region_tests(speed: float, terms, vehicle, first) -> tuple:
    """The second stage's tests: the region's, with rotating-arm tests along the steady turns of
    the trim stage's model."""
    terms = _design(terms)
    linear = nonlinear_model(vehicle, slope_terms(terms))
    return reference_tests(speed, terms, steady_turns(linear, nonlinear_theta(linear, first.coefficients)))


def region_tests(model: mujoco.MjModel, speed: float, terms=TERMS) -> tuple:
    """The tests `captive_reference` fits its second stage to (the ones its fit table lists), and
    `component_reference` its one stage (`terms` naming a component)."""
    vehicle, _, first = _trim_stage(model, speed, terms)
    return _region_tests(speed, terms, vehicle, first)


def captive_reference(model: mujoco.MjModel, speed: float, terms=TERMS) -> CaptiveFit:
    """The captive reference of the vehicle `model` at trim speed `speed` (module doc)."""
    vehicle, thrust, first = _trim_stage(model, speed, terms)
    held = {n: first.coefficients[n] for n in slope_terms(terms)}
    tests = _region_tests(speed, terms, vehicle, first)
    fit = fit_captive(vehicle, tests, captive_tests(model, tests), thrust, terms=terms, fixed=held)
    return _with_rigid(fit, rigid_inertia(model, speed))


def component_reference(model: mujoco.MjModel, speed: float) -> CaptiveFit:
    """The captive reference of the vehicle `model` at trim speed `speed` with the component
    model (docs/model.md, "Component terms"): the terms of its fluid components
    (`fluid_components.component_terms`, their names; their values fitted) and the Kirchhoff
    terms of the inertia the PMM-measured coefficients leave out, fitted in one stage to the
    region's tests with the rotating-arm tests along the steady turns of the trim stage's
    model: the component terms have the plant's own shapes, so no stage must keep the slopes."""
    vehicle, thrust, first = _trim_stage(model, speed, TERMS)
    tests = _region_tests(speed, TERMS, vehicle, first)
    measured = captive_tests(model, tests)
    rigid = rigid_inertia(model, speed)
    inertia = {n: v + rigid.get(n, 0.0) for n, v in pmm_inertia(tests, measured).items()}
    terms = tuple(component_terms(model)) + tuple(inertia_terms(model, speed, inertia))
    fit = fit_captive(vehicle, tests, measured, thrust, terms=terms, components=mjcf_components(model))
    return _with_rigid(fit, rigid)


def _with_rigid(fit: CaptiveFit, rigid: dict[str, float]) -> CaptiveFit:
    """`fit` with the rigid body's share of the inertia coefficients added to the PMM tests'
    added mass (`fluid_components.rigid_inertia`): the model's M is the whole vehicle's."""
    coefficients = {n: v + rigid.get(n, 0.0) for n, v in fit.coefficients.items()}
    return dataclasses.replace(fit, coefficients=coefficients, rigid=dict(rigid))
