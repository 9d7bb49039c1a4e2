"""The fluid forces of a vehicle's components: hull and fins, each an ellipsoid at its own flow.

A component is a part of the vehicle that the fluid loads at its own local velocity: the hull,
or one fin blade, which turns with its fin's angle about the fin's hinge. The forces of each
kind on it are those of an ellipsoid of its semi-axes r (x, y, z in its own axes) moving at the
local velocity v and rate ω of its centre, in its own axes, with density ρ (MuJoCo's ellipsoid
fluid model, the plant's; computation/fluid.rst of MuJoCo's documentation):

    blunt     f = −ρ A_p(v) ‖v‖ v                       A_p = π √(Σ b_i² v_i² / Σ b_i v_i²)
    slender   f = −ρ (A_max − A_p(v)) ‖v‖ v             b = ((r_y r_z)², (r_z r_x)², (r_x r_y)²)
    lift      f = ρ π √(Σ b_i v_i² / Σ b_i² v_i²) / ‖v‖ · ((b∘v) × v) × v      (Kutta lift)
    magnus    f = ρ V ω × v                              V = 4π r_x r_y r_z / 3
    angular   g = −ρ ‖κ∘ω‖ ω                            κ the component's swept moments
    munk      (f, g)(δ) − (f, g)(0),  f = (m_A∘v) × ω,  g = (m_A∘v) × v + (I_A∘ω) × ω

A_p is the ellipsoid's area projected along v, A_max = π r_max r_mid its largest. `munk` is how
a blade's added-mass velocity forces (its Munk moment among them; m_A, I_A its added masses and
inertias in its own axes) change as its fin turns: at δ = 0 they are part of the whole vehicle's
Kirchhoff forces, which the model's inertia M carries; the same coefficient scales the blade's
added mass turned in M (`component_kernels.turned_mass`). Each is a
force (f) or a torque (g) per unit coefficient, the coefficient being the component's drag, lift
or Magnus coefficient; the angular drag's moments κ (m⁵) carry MuJoCo's weighting of the swept
moments by the angular and slender coefficients, so its coefficient is 1 at the MJCF's values.
The vehicle feels the component's wrench about its CG in body axes: F = Q f, M = p × F + Q g,
(Q, p) the component's pose, Q(δ) = R(a, δ) Q₀ and p(δ) = h + R(a, δ) (p₀ − h) for a fin blade
turned by its fin's angle δ about the hinge line through h along a.

`component_kernels.wrenches` evaluates every kind on one component with its exact derivatives
with respect to the body velocities and the fin angles, compiled (numba) for real and complex
arguments (a complex step sees through it: the norms are principal square roots, analytic off
zero).
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass

import numpy as np

from testbed.errors import InputError

__all__ = [
    "FINS",
    "KINDS",
    "NAME",
    "Component",
    "check_component_name",
    "component_wrenches",
    "packed_components",
]

KINDS = ("blunt", "slender", "lift", "magnus", "angular", "munk")  # the forces of a component, in order
FINS = ("dr", "der", "del")  # the fin angles a blade can turn with, in δ's order
NAME = r"[A-Za-z][A-Za-z0-9_]*"  # a component's name: what `kind@name` and [components.name] take


@dataclass(frozen=True)
class Component:
    """One component: an ellipsoid of semi-axes `axes` (m) whose centre is at `centre` (m, body
    axes, from the CG) and whose axes are `frame`'s columns (body from component, a rotation)
    with every fin at 0; a blade turns with the fin `fin` (one of `FINS`, None on the hull)
    about the line through `hinge` along `hinge_axis`. `moments` (m⁵): the angular drag's κ;
    `density` (kg/m³): the fluid's; `added_mass`: m_A (kg) and I_A (kg m²) along and about its
    own axes."""

    name: str
    axes: tuple[float, float, float]
    centre: tuple[float, float, float]
    frame: tuple[tuple[float, float, float], ...]
    moments: tuple[float, float, float]
    density: float
    fin: str | None = None
    hinge: tuple[float, float, float] = (0.0, 0.0, 0.0)
    hinge_axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    added_mass: tuple[float, ...] = (0.0,) * 6

    def __post_init__(self):
        self._check()
        for field in ("axes", "centre", "moments", "hinge", "hinge_axis", "added_mass"):
            object.__setattr__(self, field, tuple(float(v) for v in getattr(self, field)))
        object.__setattr__(self, "frame", tuple(tuple(float(v) for v in row) for row in self.frame))
        object.__setattr__(self, "density", float(self.density))

    def _check(self) -> None:
        where = f"component {self.name!r}"
        check_component_name(self.name, "component")
        sizes = (
            ("axes", 3),
            ("centre", 3),
            ("moments", 3),
            ("hinge", 3),
            ("hinge_axis", 3),
            ("added_mass", 6),
        )
        for field, size in sizes:
            value = np.asarray(getattr(self, field), dtype=float) if _numbers(getattr(self, field)) else None
            if value is None or value.shape != (size,) or not np.all(np.isfinite(value)):
                raise InputError(f"{where}: {field} must be {size} finite numbers")
        if np.any(np.asarray(self.axes, float) <= 0) or np.any(np.asarray(self.moments, float) < 0):
            raise InputError(f"{where}: expected positive axes and non-negative moments")
        frame = np.asarray(self.frame, dtype=float) if _numbers(self.frame) else None
        if frame is None or frame.shape != (3, 3) or not np.allclose(frame @ frame.T, np.eye(3), atol=1e-9):
            raise InputError(f"{where}: frame must be a 3 × 3 rotation (rows of 3 numbers)")
        if (
            not _numbers(self.density)
            or np.ndim(self.density)
            or not np.isfinite(self.density)
            or self.density <= 0
        ):
            raise InputError(f"{where}: density {self.density!r}; expected a positive number (kg/m³)")
        if self.fin is not None and self.fin not in FINS:
            raise InputError(f"{where}: fin {self.fin!r}; expected one of {', '.join(FINS)} or none")
        if self.fin is not None and abs(np.linalg.norm(np.asarray(self.hinge_axis, float)) - 1) > 1e-9:
            raise InputError(f"{where}: hinge_axis must be a unit vector")


def check_component_name(name, where: str) -> str:
    """`name` if it is a component's name (`NAME`); else `InputError` naming `where` and it."""
    if not isinstance(name, str) or not re.fullmatch(NAME, name):
        raise InputError(f"{where} {json.dumps(name)}: expected a name of letters, digits and '_'")
    return name


def _numbers(value) -> bool:
    try:
        np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return False
    return True


def packed_components(components) -> tuple:
    """The components as the compiled `wrenches` takes them: (C, 31) floats per component
    (axes, centre, frame row by row, moments, density, hinge, hinge axis, added mass) and (C,)
    fin indices (−1: none)."""
    rows = [
        np.concatenate(
            [c.axes, c.centre, np.ravel(c.frame), c.moments, [c.density], c.hinge, c.hinge_axis, c.added_mass]
        )
        for c in components
    ]
    geometry = np.array(rows, dtype=float).reshape(len(rows), 31)
    fins = np.array([-1 if c.fin is None else FINS.index(c.fin) for c in components], dtype=np.int64)
    return geometry, fins


def component_wrenches(components, nu, delta) -> np.ndarray:
    """W (n, C, 6, 6): each component's wrench of each kind (`KINDS`) per unit coefficient at
    the body velocities ν (n, 6) and fin angles δ (n, 3), real or complex."""
    from testbed.models.component_kernels import SCRATCH, wrenches  # numba: only when evaluated

    nu, delta = np.atleast_2d(nu), np.atleast_2d(delta)
    dtype = complex if np.iscomplexobj(nu) or np.iscomplexobj(delta) else float
    z = np.ascontiguousarray(np.concatenate([nu, delta], axis=1), dtype=dtype)
    geometry, fins = packed_components(components)
    out = np.zeros((len(z), len(components), 6, 6), dtype=dtype)
    J, S = np.zeros((6, 6, 9), dtype=dtype), np.zeros(SCRATCH, dtype=dtype)
    every = np.ones(len(KINDS), dtype=bool)
    for n in range(len(z)):
        for c in range(len(components)):
            wrenches(geometry[c], fins[c], z[n], out[n, c], J, False, every, S)
    return out
