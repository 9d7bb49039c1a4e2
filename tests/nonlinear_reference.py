"""How well a nonlinear model's term set can represent the plant: a least-squares fit of the
plant's own forces at sampled states.

At each sample (state x, fin angles δ: drawn uniformly in a box, or a flight's) the completed
plant gives its body accelerations ν̇ (`states.plant_rates`, fins held; `fit_plant`). The model says M ν̇ = F₀(x) +
R(x, δ) c, with F₀ the forces it knows exactly (Kirchhoff's velocity forces of M, weight and
buoyancy) and R the terms' regressors (`nonlinear.force_regressors`, the thrust's share
included), so each body row is a linear least-squares problem for its terms' coefficients c:
y = M ν̇ − F₀ = R c. What no choice of c explains is what the term set misses (and what the
model's constant M misses: the plant's added mass turns with the fins).

`FitQuality` per row: the fit of the forces, 100 (1 − ‖y − R c‖/‖y − ȳ‖), and of the
accelerations the fitted model predicts against the plant's, the same measure per row of ν̇.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from testbed.fit_percent import fit_percent
from testbed.models import nonlinear
from testbed.models.linear import NU, NX
from testbed.models.regressors import ROWS
from testbed.simulation.plant import Plant
from testbed.simulation.states import plant_rates

__all__ = ["Box", "FitQuality", "SCENARIO_I", "fit_plant", "fit_terms", "sample_box"]


@dataclass(frozen=True)
class Box:
    """Uniform sampling ranges: the speed from `speed[0]` to `speed[1]` (m/s), |v|, |w| ≤ `velocity`
    (m/s), |p|, |q|, |r| ≤ `rate` (rad/s), |φ|, |θ| ≤ `angle` (rad), each fin ≤ `fin` (rad)."""

    speed: tuple[float, float]
    velocity: float
    rate: float
    angle: float
    fin: float


# Scenario I's nominal ranges, every extreme at once (its flight stays well inside them)
SCENARIO_I = Box(speed=(16.0, 20.0), velocity=2.0, rate=1.7, angle=0.6, fin=0.4)


def sample_box(box: Box, n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(x (n, 10), δ (n, 3)) drawn uniformly in `box` (ψ and z at 0: nothing depends on them)."""
    rng = np.random.default_rng(seed)
    x = np.zeros((n, NX))
    x[:, 0] = rng.uniform(*box.speed, n)
    x[:, 1:3] = rng.uniform(-box.velocity, box.velocity, (n, 2))
    x[:, 3:6] = rng.uniform(-box.rate, box.rate, (n, 3))
    x[:, 6:8] = rng.uniform(-box.angle, box.angle, (n, 2))
    return x, rng.uniform(-box.fin, box.fin, (n, NU))


@dataclass(frozen=True)
class FitQuality:
    """The term set's least-squares fit of the plant, per body row (X Y Z K M N)."""

    coefficients: dict[str, float]  # the terms' fitted coefficients
    force_fit: dict[str, float]  # %, 100 (1 − ‖residual‖ / ‖y − ȳ‖) of the row's force
    acceleration_fit: dict[str, float]  # %, the same for the fitted model's ν̇ against the plant's
    force_rms: dict[str, float]  # N or N m: the residual's RMS
    samples: int


def fit_terms(model: nonlinear.NonlinearModel, inertia: dict[str, float], x, delta, nudot) -> FitQuality:
    """Fit `model`'s terms to the plant's accelerations `nudot` (n, 6) at `x`, `delta`, with the
    inertia coefficients (`nonlinear.INERTIA`) held at `inertia`."""
    theta0 = nonlinear.nonlinear_theta(model, inertia)
    M = model.inertia(theta0)
    y = nudot @ M.T - nonlinear.forces(model, theta0, x, delta)  # what the terms must give
    R = nonlinear.force_regressors(model, x, delta)
    c = nonlinear.row_least_squares(model, R, y)
    theta = theta0 + np.concatenate([np.zeros(len(nonlinear.INERTIA)), c])
    residual = y - np.einsum("nrk,k->nr", R, c)
    predicted = nonlinear.rates(model, theta, x, delta)[:, :6]
    return FitQuality(
        coefficients={t.name: float(v) for t, v in zip(model.terms, c)},
        force_fit={ROWS[r]: fit_percent(y[:, r], y[:, r] - residual[:, r]) for r in range(6)},
        acceleration_fit={ROWS[r]: fit_percent(nudot[:, r], predicted[:, r]) for r in range(6)},
        force_rms={ROWS[r]: float(np.sqrt(np.mean(residual[:, r] ** 2))) for r in range(6)},
        samples=len(x),
    )


def fit_plant(
    plant: Plant, model: nonlinear.NonlinearModel, inertia: dict[str, float], x, delta
) -> FitQuality:
    """`fit_terms` against `plant`'s own accelerations at `x`, `delta`, its propulsor set for the
    model's trim speed (`Plant.reset`, as after it)."""
    plant.reset(model.vehicle.speed)
    nudot = plant_rates(plant, x, delta)
    plant.reset(model.vehicle.speed)
    return fit_terms(model, inertia, x, delta, nudot)
