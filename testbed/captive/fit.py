"""The nonlinear model fitted to virtual captive tests (docs/captive.md, the fit).

A captive test of the nonlinear model (docs/model.md) would read its hydrodynamic wrench

    τ_H = −C_A(ν) ν − M_A ν̇ + Σ_k c_k φ_k(ν, δ)

(the added mass M_A's Kirchhoff forces and inertia, and the terms; not the rigid body, weight,
buoyancy or thrust). The inertia coefficients (`nonlinear.INERTIA`, M_A's entries) are read from
the oscillatory tests' quadrature parts (`pmm_inertia`: a column of −M_A per oscillated velocity,
exact at any amplitude), averaged over the speeds. With M_A known, each wrench row is linear in
its row's term coefficients: y = τ_H + C_A(ν) ν + M_A ν̇ = R c, fitted by least squares per row.

The model's thrust is the drag its terms give in straight flight at the trim speed U, so a
term's surge regressor is φ_k − φ_k(U e_x, 0) (`nonlinear.force_regressors`) and the surge row
is fitted as τ_X + T with T the plant's own thrust, the drag it measures at U: the fitted model
then trims at U exactly where the plant does, and its surge force at any other state is fitted
relative to trim, as the plant's propulsor sees it.

`weights` scale a test's rows in the least squares (its points count `weight` times; default 1).
Fit quality per test, speed and row (`SurfaceFit`): 100 (1 − ‖residual‖/‖τ − τ̄‖) and the
residual's RMS, the fit being undefined (nan) where the measured row does not vary.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from testbed.errors import InputError
from testbed.fit_percent import fit_percent
from testbed.models import linear, nonlinear
from testbed.models.mechanics import coriolis
from testbed.models.regressors import ROWS
from testbed.captive.rig import Measurement, Oscillation, pmm_coefficients

__all__ = ["CaptiveFit", "SurfaceFit", "fit_captive", "fitted_wrench", "pmm_inertia"]


@dataclass(frozen=True)
class SurfaceFit:
    """How well the fitted model reproduces one wrench row of one test at one speed."""

    test: str
    speed: float  # m/s
    row: str  # X Y Z K M N
    fit: float  # %, 100 (1 − ‖residual‖/‖τ − τ̄‖); nan where τ does not vary
    rms: float  # N or N m: the residual's RMS
    points: int


@dataclass(frozen=True)
class CaptiveFit:
    """The nonlinear model's coefficients fitted to captive measurements, and the fit's quality."""

    coefficients: dict[str, float]  # `nonlinear.INERTIA` (from the PMM tests), then the terms
    terms: tuple[str, ...]
    speed: float  # U, m/s: the trim speed the thrust is the drag at
    thrust: float  # N: the plant's drag at U, the surge row is fitted against
    surfaces: tuple[SurfaceFit, ...]  # per test, speed and row, in the measurements' order
    rows: dict[str, float]  # % per row over every measurement
    components: tuple = ()  # the `Component`s the component terms name
    # the rigid body's share of the inertia coefficients (its products of inertia, which the
    # vehicle constants lack), in `coefficients` but not in the water's wrench
    rigid: dict[str, float] = dataclasses.field(default_factory=dict)

    def table(self) -> str:
        """The fit of every force surface: one line per test and speed, % per row (RMS residual
        where the row does not vary, in brackets)."""
        head = f"{'test':<20} {'u m/s':>6} " + " ".join(f"{r:>9}" for r in ROWS)
        lines = [head]
        by = {}
        for s in self.surfaces:
            by.setdefault((s.test, s.speed), {})[s.row] = s
        for (test, speed), rows in by.items():
            cells = [_cell(rows[r]) for r in ROWS]
            lines.append(f"{test:<20} {speed:>6.1f} " + " ".join(f"{c:>9}" for c in cells))
        lines.append(f"{'all':<20} {'':>6} " + " ".join(f"{self.rows[r]:>9.2f}" for r in ROWS))
        return "\n".join(lines)


def _cell(s: SurfaceFit) -> str:
    return f"({s.rms:.2g})" if math.isnan(s.fit) else f"{s.fit:.2f}"


def pmm_inertia(tests: Sequence, measurements: Sequence[Measurement]) -> dict[str, float]:
    """`nonlinear.INERTIA` from the oscillatory tests' quadrature parts: `R_xdot` is row R's
    quadrature part of the oscillation of x, averaged over the speeds it was run at."""
    found: dict[str, list[float]] = {}
    by_name = {t.name: t for t in tests if isinstance(t, Oscillation)}
    for m in measurements:
        if m.test in by_name:
            for name, value in pmm_coefficients(by_name[m.test], m).items():
                found.setdefault(name, []).append(value)
    missing = [n for n in nonlinear.INERTIA if n not in found]
    if missing:
        raise InputError(
            f"captive tests: no oscillation of {missing[0].split('_')[1][0]} for {missing[0]}; "
            f"expected an oscillatory test of each of u v w p q r"
        )
    return {n: float(np.mean(found[n])) for n in nonlinear.INERTIA}


def fit_captive(
    vehicle: linear.Vehicle,
    tests: Sequence,
    measurements: Sequence[Measurement],
    thrust: float,
    terms: Sequence[str] = nonlinear.TERMS,
    weights: Mapping[str, float] | None = None,
    fixed: Mapping[str, float] | None = None,
    components=(),
) -> CaptiveFit:
    """Fit `terms` of `vehicle`'s nonlinear model (trim speed `vehicle.speed`) to `measurements`
    of `tests` (`captive.captive_tests`), the plant's thrust at trim being `thrust` (N); the
    terms in `fixed` are held at their values there, the rest fitted; the component terms name
    `components`."""
    weights, fixed = dict(weights or {}), dict(fixed or {})
    unknown = sorted(set(weights) - {m.test for m in measurements})
    if unknown:
        raise InputError(f"captive fit: weight for {unknown[0]!r}; expected a measured test's name")
    bad = [k for k, w in weights.items() if not 0 <= w < math.inf]
    if bad:
        raise InputError(f"captive fit: weight {bad[0]}={weights[bad[0]]!r}; expected a finite weight >= 0")
    if not math.isfinite(thrust):
        raise InputError(f"captive fit: thrust={thrust!r}; expected a finite force (N)")
    model = nonlinear.nonlinear_model(vehicle, terms, components)
    names = [t.name for t in model.terms]
    stray = sorted(set(fixed) - set(names))
    if stray:
        raise InputError(f"captive fit: held term {stray[0]!r}; expected one of the fitted terms")
    inertia = pmm_inertia(tests, measurements)
    M_A = model.inertia(nonlinear.nonlinear_theta(model, inertia)) - model.M_RB
    nu = np.concatenate([m.nu for m in measurements])
    x = np.concatenate([nu, np.zeros((len(nu), linear.NX - 6))], axis=1)
    R = nonlinear.force_regressors(model, x, np.concatenate([m.fins for m in measurements]))
    held = np.array([fixed.get(n, 0.0) for n in names], float)
    # what the free terms must give: the wrench with the added mass's forces and the held terms
    # taken out, and in surge the thrust added (the terms' surge regressors are relative to trim)
    y = np.concatenate([m.wrench for m in measurements]) - coriolis(M_A, nu)[0]
    y += np.concatenate([m.nu_dot for m in measurements]) @ M_A.T
    y[:, 0] += thrust
    y -= np.einsum("nrk,k->nr", R, held)
    w = np.concatenate([np.full(len(m.nu), weights.get(m.test, 1.0)) for m in measurements])
    c = nonlinear.row_least_squares(model, R, y, w, held=fixed)
    residual = y - np.einsum("nrk,k->nr", R, c)
    tau = np.concatenate([m.wrench for m in measurements])
    return CaptiveFit(
        coefficients={**inertia, **dict(zip(names, (held + c).tolist()))},
        terms=tuple(names),
        speed=vehicle.speed,
        thrust=float(thrust),
        surfaces=_surfaces(measurements, residual, np.abs(tau).max(axis=0)),
        rows={ROWS[r]: _fit(tau[:, r], residual[:, r], np.abs(tau[:, r]).max()) for r in range(6)},
        components=tuple(components),
    )


def fitted_wrench(vehicle: linear.Vehicle, fit: CaptiveFit, nu, fins, nu_dot) -> np.ndarray:
    """The wrench (n, 6) a captive test of the fitted model reads at the states ν (n, 6), fins δ
    (n, 3) and rates ν̇ (n, 6), as the fit compares it with the plant's: the model's forces less
    the rigid body's (what the equation of motion adds to the water's), less M_A ν̇, and in surge
    the model's thrust exchanged for the plant's (`fit.thrust`). `vehicle` is the one fitted."""
    if vehicle.speed != fit.speed:
        raise InputError(
            f"vehicle at speed={vehicle.speed!r} m/s; expected the fit's trim speed {fit.speed!r}"
        )
    model = nonlinear.nonlinear_model(vehicle, fit.terms, fit.components)
    theta = nonlinear.nonlinear_theta(model, fit.coefficients)
    body = nonlinear.nonlinear_theta(model, fit.rigid)  # the rigid body's share alone
    nu, nu_dot = np.atleast_2d(nu), np.atleast_2d(nu_dot)
    x = np.concatenate([nu, np.zeros((len(nu), linear.NX - 6))], axis=1)
    rigid = nonlinear.forces(model, body, x, fins)  # −C_RB ν and the restoring forces
    M_A = model.inertia(theta) - model.inertia(body)
    tau = nonlinear.forces(model, theta, x, fins) - rigid - nu_dot @ M_A.T
    tau[:, 0] -= fit.thrust
    return tau


def _surfaces(measurements, residual, scale) -> tuple[SurfaceFit, ...]:
    """Each measurement's fit per row, its rows being the next ones of `residual`."""
    out, start = [], 0
    for m in measurements:
        part = residual[start : start + len(m.nu)]
        start += len(m.nu)
        for r in range(6):
            out.append(
                SurfaceFit(
                    test=m.test,
                    speed=m.speed,
                    row=ROWS[r],
                    fit=_fit(m.wrench[:, r], part[:, r], scale[r]),
                    rms=float(np.sqrt(np.mean(part[:, r] ** 2))),
                    points=len(m.nu),
                )
            )
    return tuple(out)


def _fit(y, residual, scale: float) -> float:
    """`fit_percent` of y and y − residual; NaN where y varies by no more than rounding of `scale`."""
    return fit_percent(y, y - residual, 1e-9 * scale * math.sqrt(len(y)))
