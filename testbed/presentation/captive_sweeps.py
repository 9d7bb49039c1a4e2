"""What the captive tests' figures show (`testbed captive --figures/--rrd`): per test, speed and
wrench row the test excites, the plant's wrench at the test's points and the fitted model's along
the swept variable, with the fit % that `testbed captive` prints (docs/captive.md).

- A sweep's abscissa is its first variable. A grid of more variables is drawn as slices: one
  series per value of the others (a 7 × 7 pair grid: 7 slices), each at its own points for the
  plant and along `DENSE` values of the first variable for the model.
- An oscillation (PMM) is drawn against time over its period, and carries each row's first
  harmonic (`captive.pmm_coefficients`) of the plant's wrench and of the model's at the same
  instants: the in-phase part (`Y_v`) and the quadrature part (`Y_vdot`).

A row is drawn where the fit rates it (its `SurfaceFit` is a number): where the plant's row
varies over the test at that speed.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from dataclasses import dataclass, field

import mujoco
import numpy as np

from testbed.models.regressors import ROWS
from testbed.captive.rig import Measurement, Oscillation, captive_tests, pmm_coefficients
from testbed.captive.fit import CaptiveFit, fitted_wrench
from testbed.captive.reference import region_tests
from testbed.simulation.recording import STYLE
from testbed.simulation.vehicle import constants

__all__ = [
    "DENSE",
    "NEGLIGIBLE",
    "SWEEP_UNITS",
    "Series",
    "SweepPanel",
    "by_test",
    "series_colours",
    "sweep_panels",
]

NEGLIGIBLE = 1e-6  # a PMM part whose harmonic is below this share of its row's range is not shown
DENSE = 81  # the model's curve: values of the swept variable from −extent to +extent, or instants a period
# The unit of each swept variable, of time, and of each wrench row.
SWEEP_UNITS = {
    **dict.fromkeys("uvw", "m/s"),
    **dict.fromkeys("pqr", "rad/s"),
    **dict.fromkeys(("delta_r", "delta_er", "delta_el", "delta_e", "delta_d"), "rad"),
    "t": "s",
    **dict.fromkeys("XYZ", "N"),
    **dict.fromkeys("KMN", "N m"),
}

# viridis at 0, 1/4, 1/2, 3/4 and 1 (RGB): the slices' colours, dark to light
_VIRIDIS = np.array([(68, 1, 84), (59, 82, 139), (33, 145, 140), (94, 201, 98), (253, 231, 37)], float)


def series_colours(n: int) -> list[tuple[tuple[int, int, int], tuple[int, int, int]]]:
    """Per slice of a panel, the colours (RGB, 0-255) of the plant's points and the model's line:
    the recordings' (`STYLE`: the truth blue, the model red) for one, else one viridis colour
    per slice for both, from its dark end to 0.9 of it."""
    if n == 1:
        return [(STYLE["truth"][0], STYLE["model"][0])]
    grid = np.linspace(0.0, 1.0, len(_VIRIDIS))
    out = []
    for a in np.linspace(0.0, 0.9, n):
        c = tuple(int(round(np.interp(a, grid, _VIRIDIS[:, k]))) for k in range(3))
        out.append((c, c))
    return out


@dataclass(frozen=True)
class Series:
    """One curve or set of points: `y` against `x`; `label` names the slice ("" for none)."""

    label: str
    x: np.ndarray = field(repr=False)
    y: np.ndarray = field(repr=False)


@dataclass(frozen=True)
class SweepPanel:
    """One wrench row of one test at one speed: the plant's points and the model's curve."""

    test: str
    speed: float  # u held, m/s
    row: str  # X Y Z K M N
    x: str  # the abscissa: the swept variable, or "t" for an oscillation
    fit: float  # %, the fit's `SurfaceFit` of this test, speed and row
    plant: tuple[Series, ...]  # the wrench read from the plant, one series per slice
    model: tuple[Series, ...]  # the fitted model's, in the same slices
    parts: dict[str, tuple[float, float]]  # an oscillation's first harmonic: name -> (plant, model)


def sweep_panels(model: mujoco.MjModel, fit: CaptiveFit) -> tuple[SweepPanel, ...]:
    """The panels of `fit`, the captive reference of the vehicle `model` (`captive_reference`):
    its second stage's tests (`region_tests` at the fit's trim speed) run on the plant again, and the model
    evaluated with `captive.fit.fitted_wrench`, in the fit's order of tests, speeds and rows."""
    vehicle = constants(model, fit.speed)
    tests = {t.name: t for t in region_tests(model, fit.speed, fit.terms)}
    measurements = captive_tests(model, tuple(tests.values()))
    rated = {(s.test, s.speed, s.row): s.fit for s in fit.surfaces}
    if [(m.test, m.speed) for m in measurements] != list(dict.fromkeys(k[:2] for k in rated)):
        raise RuntimeError(
            "the captive fit's surfaces are not those of region_tests: their figures would lie"
        )
    out = []
    for m in measurements:
        draw = [r for r in range(6) if not math.isnan(rated[(m.test, m.speed, ROWS[r])])]
        if draw:
            out += _panels(vehicle, fit, tests[m.test], m, draw, rated)
    return tuple(out)


def _panels(vehicle, fit, test, m: Measurement, rows, rated) -> list[SweepPanel]:
    def model_at(states):  # states: (ν, ν̇, δ) as a test gives them
        nu, nu_dot, fins = states
        return fitted_wrench(vehicle, fit, nu, fins, nu_dot)

    if isinstance(test, Oscillation):
        t = test.times()
        dense = dataclasses.replace(test, samples=DENSE)
        at_points = Measurement(m.test, m.speed, m.nu, m.nu_dot, m.fins, model_at((m.nu, m.nu_dot, m.fins)))
        plant_parts, model_parts = pmm_coefficients(test, m), pmm_coefficients(test, at_points)
        curve = model_at(dense.states(m.speed))
        return [
            SweepPanel(
                test=m.test,
                speed=m.speed,
                row=ROWS[r],
                x="t",
                fit=rated[(m.test, m.speed, ROWS[r])],
                plant=(Series("", t, m.wrench[:, r]),),
                model=(Series("", dense.times(), curve[:, r]),),
                parts=_parts(test, m.wrench[:, r], ROWS[r], plant_parts, model_parts),
            )
            for r in rows
        ]
    axes = test.axes()
    dense = dataclasses.replace(test, points=(DENSE,) + test.points[1:], speeds=(m.speed,))
    curve = model_at(dense.states(m.speed))
    slices = list(itertools.product(*axes[1:]))
    labels = [", ".join(f"{v} = {x:.3g} {SWEEP_UNITS[v]}" for v, x in zip(test.vary[1:], s)) for s in slices]
    # the grid runs with the first variable slowest: slice k is every len(slices)-th point from k
    n = len(slices)
    return [
        SweepPanel(
            test=m.test,
            speed=m.speed,
            row=ROWS[r],
            x=test.vary[0],
            fit=rated[(m.test, m.speed, ROWS[r])],
            plant=tuple(Series(labels[k], axes[0], m.wrench[k::n, r]) for k in range(n)),
            model=tuple(Series(labels[k], dense.axes()[0], curve[k::n, r]) for k in range(n)),
            parts={},
        )
        for r in rows
    ]


def _parts(test: Oscillation, F, row: str, plant: dict, model: dict) -> dict[str, tuple[float, float]]:
    """Row `row`'s in-phase and quadrature parts (plant, model) that carry a force: those whose
    harmonic (the part times a, or a ω) is above `NEGLIGIBLE` of the row's range F (a row even
    in the variable, X in pure sway, has none)."""
    scale = {"": test.amplitude, "dot": test.amplitude * test.omega}
    out = {}
    for kind, a in scale.items():
        n = f"{row}_{test.variable}{kind}"
        if max(abs(plant[n]), abs(model[n])) * a > NEGLIGIBLE * np.ptp(F):
            out[n] = (plant[n], model[n])
    return out


def by_test(panels) -> dict[str, list[SweepPanel]]:
    """The panels grouped by test, in their order."""
    out: dict[str, list[SweepPanel]] = {}
    for p in panels:
        out.setdefault(p.test, []).append(p)
    return out
