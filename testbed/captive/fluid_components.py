"""An MJCF body's fluid components and their terms: the component model of its fluid forces.

Each fluid geom (`fluidshape="ellipsoid"`) is a component: its equivalent ellipsoid, its pose in
body axes (FRD, from the CG) with the fins at 0, and for a blade its fin's hinge. Its terms are
the kinds of force its fluidcoef turns on (blunt and slender drag, Kutta lift, Magnus lift;
angular drag, whose moments κ carry the angular and slender coefficients), each with the MJCF's
coefficient; and each blade's `munk` term, the change of its added-mass velocity forces with its
fin angle. Together with the model's inertia and Kirchhoff
forces (the added mass at δ = 0) they are MuJoCo's fluid wrench.
"""

from __future__ import annotations

import mujoco
import numpy as np

from testbed.models import nonlinear
from testbed.models.components import FINS as FIN_INPUTS
from testbed.models.components import KINDS, Component
from testbed.models.mechanics import coriolis
from testbed.models.regressors import ROWS
from testbed.simulation.vehicle import (
    FLIP,
    added_mass,
    constants,
    fluid_frames,
    fluid_geoms,
    rigid_body_mass,
    semi_axes,
)

__all__ = ["component_terms", "inertia_terms", "mjcf_components", "rigid_inertia"]

_COEF = {"blunt": 0, "slender": 1, "lift": 3, "magnus": 4}  # the kind's fluidcoef entry


def _moments(r: np.ndarray, coef: np.ndarray) -> np.ndarray:
    """κ = C_ang I_D + C_slender (I_max − I_D): MuJoCo's angular-drag moments of an ellipsoid,
    I_D,i = 8π/15 r_i max(r_j, r_k)⁴ and I_max = 8π/15 r_mid r_max⁴."""
    swept = np.array([8 * np.pi / 15 * r[i] * max(r[(i + 1) % 3], r[(i + 2) % 3]) ** 4 for i in range(3)])
    s = np.sort(r)
    I_max = 8 * np.pi / 15 * s[1] * s[2] ** 4
    return coef[2] * swept + coef[1] * (I_max - swept)


def mjcf_components(model: mujoco.MjModel) -> tuple[Component, ...]:
    """The fluid geoms of `model` as components, in body axes (FRD) about the hull's origin (the
    CG), named by their geoms (or `geom<i>`)."""
    out = []
    for g, fin, Q, p, hinge, axis in fluid_frames(model):
        r = semi_axes(model, g)
        blade = (
            {}
            if fin is None
            else dict(fin=FIN_INPUTS[fin], hinge=tuple(FLIP @ hinge), hinge_axis=tuple(FLIP @ axis))
        )
        out.append(
            Component(
                name=model.geom(g).name or f"geom{g}",
                axes=tuple(r),
                centre=tuple(FLIP @ p),
                frame=tuple(map(tuple, FLIP @ Q)),
                moments=tuple(_moments(r, model.geom_fluid[g, 1:6])),
                density=float(model.opt.density),
                added_mass=tuple(model.opt.density * model.geom_fluid[g, 6:12]),
                **blade,
            )
        )
    return tuple(out)


def component_terms(model: mujoco.MjModel) -> dict[str, float]:
    """Each component's terms, named `kind@component`, with the MJCF's coefficients: the kinds
    its fluidcoef turns on, the angular drag where its moments are not 0, and a blade's Munk
    term where it has added mass (coefficient 1: the shapes carry the MJCF's values)."""
    terms = {}
    for part, g in zip(mjcf_components(model), fluid_geoms(model)):
        coef = model.geom_fluid[g, 1:6]
        for kind in KINDS:
            value = float(coef[_COEF[kind]]) if kind in _COEF else 1.0
            off = {"angular": not any(part.moments), "munk": part.fin is None or not any(part.added_mass)}
            if value != 0.0 and not off.get(kind, False):
                terms[f"{kind}@{part.name}"] = value
    return terms


def inertia_terms(model: mujoco.MjModel, speed: float, inertia: dict[str, float]) -> dict[str, float]:
    """The Kirchhoff forces of the inertia that the inertia coefficients `inertia` leave out of
    M (entries such as the surge-pitch coupling of a body whose added mass is not symmetric fore
    and aft, which no coefficient names) as quadratic terms `ROW_ij` (ν_i ν_j), exactly: −C(ν)ν
    is quadratic in ν. Their acceleration part stays out of the model."""
    vehicle = constants(model, speed)
    bare = nonlinear.nonlinear_model(vehicle, ())
    theta = nonlinear.nonlinear_theta(bare, {n: inertia[n] for n in nonlinear.INERTIA})
    dM = rigid_body_mass(model) + added_mass(model) - bare.inertia(theta)
    dM[np.abs(dM) < 1e-9 * np.abs(bare.inertia(theta)).max()] = 0.0
    E = np.eye(6)
    kirchhoff = lambda nu: coriolis(dM, nu)[0][0]  # noqa: E731
    terms = {}
    for i in range(6):
        for j in range(i, 6):
            F = kirchhoff(E[i] + E[j]) - kirchhoff(E[i]) - kirchhoff(E[j]) if i != j else kirchhoff(E[i])
            for row in range(6):
                if F[row] != 0.0:
                    terms[f"{ROWS[row]}_{'uvwpqr'[i]}{'uvwpqr'[j]}"] = float(F[row])
    return terms


def rigid_inertia(model: mujoco.MjModel, speed: float) -> dict[str, float]:
    """What the inertia coefficients must add to the added mass for M to be the whole vehicle's:
    the rigid body's entries that the vehicle constants leave out (its products of inertia such
    as I_xz, which the model's rigid-body matrix lacks), projected on the coefficients' entries
    of M (K_rdot and N_pdot hold −I_xz)."""
    bare = nonlinear.nonlinear_model(constants(model, speed), ())
    gap = rigid_body_mass(model) - bare.M_RB
    # M = M_RB + Σ θ_k ∂M/∂θ_k: the θ whose entries make up the gap, by least squares
    basis = bare.dM.reshape(len(nonlinear.INERTIA), 36).T
    theta = np.linalg.lstsq(basis, gap.ravel(), rcond=None)[0]
    return {n: float(v) for n, v in zip(nonlinear.INERTIA, theta) if abs(v) > 1e-12 * np.abs(gap).max()}
