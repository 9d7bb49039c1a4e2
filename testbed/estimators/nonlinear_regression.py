"""The nonlinear model's equation-error start: its dynamics rows fitted to the measured states'
difference quotients, with no flight, so no basin of attraction and no divergence along the record.

Every row of `M ν̇ = F(ν, η, δ; θ)` is linear in the terms' coefficients, and only M's inertia
coefficients and the Munk terms enter through M⁻¹. Over each sample interval, where the fin
angles are held, the measured states' difference quotient ν̇ ≈ Δν/Δt is compared with the
model's rates at the interval's midpoint x̄ (over a missing sample, the interval runs between
the samples present either side, with the fins' mean over it):

    e(θ) = Δν/Δt − f_ν(x̄, δ; θ)

and θ's free coefficients are taken by Gauss-Newton on Σ eᵀ W e, its Jacobian ∂f/∂θ the model's
exact sensitivities (`nonlinear.rate_sensitivities`), W the inverse of each row's mean-square error
at the current θ. The states are not smoothed, as the linear model's regression smooths them:
ν̇ jumps at every sample where the fins move, and a window spreads the jump over its neighbours
(on Scenario I's noise-free truth a 0.1 s window puts the fins' lift 1.4 % off, 0.5 s 25–35 %,
the raw quotient 0.1 %). White noise in the quotient is uncorrelated with the midpoint's (the
same samples, differenced and averaged), so it adds variance, not bias. Each step is the
least-squares solution of least norm in coordinates scaled by the Jacobian's columns, so
directions the data do not excite keep their a-priori values. Noise in the regressors biases the
estimate (errors in variables: on noisy Scenario I the lifts within 0.5 %, the blades' blunt drags
off by −155 to +211 %), so it is a start for output error, not an estimate of its own.

It needs every state the rows involve measured: u v w p q r and the attitude φ θ.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from testbed.errors import InputError
from testbed.estimators.intervals import between_present
from testbed.identification.nonlinear_output_error import FlightRecord
from testbed.models.linear import STATES
from testbed.models.nonlinear import NonlinearModel, rates, rate_sensitivities

__all__ = ["NEEDED", "equation_error"]

NEEDED = ("u", "v", "w", "p", "q", "r", "phi", "theta")  # the states the dynamics rows involve
_ROWS = 6  # ν̇'s rows of f
_STEPS = 8  # Gauss-Newton steps at most: M⁻¹ is the only nonlinearity in θ
STEP_TOL = 1e-6  # stop when every step is below this fraction of its coefficient


def _intervals(records: Sequence[FlightRecord], channels: Sequence[str]):
    """(ν̇, x̄, δ) over every record's intervals between consecutive samples where the rows'
    states are all present (`intervals.between_present`), the states the rows do not involve at 0."""
    to = [STATES.index(c) for c in NEEDED]
    source = [list(channels).index(c) for c in NEEDED]
    nudot, xbar, fins = [], [], []
    for r in records:
        quotient, mid, mean = between_present(r.t, r.y[:, source], r.fins)
        x = np.zeros((len(mid), len(STATES)))
        x[:, to] = mid
        nudot.append(quotient[:, :_ROWS])
        xbar.append(x)
        fins.append(mean)
    return np.concatenate(nudot), np.concatenate(xbar), np.concatenate(fins)


def equation_error(
    model: NonlinearModel,
    theta,
    records: Sequence[FlightRecord],
    channels: Sequence[str],
    free: Sequence[str],
) -> np.ndarray:
    """θ with its `free` coefficients (names from `model.names`) fitted to the records' difference
    quotients from `theta` (module doc); `InputError` naming the states the rows need that the
    records do not measure, or where no interval has them all present."""
    missing = [c for c in NEEDED if c not in channels]
    if missing:
        raise InputError(
            f"equation-error start: the records do not measure {', '.join(missing)}; the dynamics rows "
            f"involve {' '.join(NEEDED)}: expected records measuring them, or start config"
        )
    nudot, x, fins = _intervals(records, channels)
    if not len(nudot):
        raise InputError(
            "equation-error start: no interval between samples where every state the dynamics rows "
            f"involve ({' '.join(NEEDED)}) is present; expected records with rows measuring them all, "
            "or start config"
        )
    idx = np.array([model.names.index(n) for n in free])
    theta = np.array(theta, float)
    for _ in range(_STEPS):
        # e = Δν/Δt − f_ν(x̄, δ; θ), J = ∂f_ν/∂θ at the free coefficients
        e = nudot - rates(model, theta, x, fins)[:, :_ROWS]
        if not np.all(np.isfinite(e)):
            raise InputError("equation-error start: the model's rates are not finite at the records' states")
        # W = diag(1 / mean eᵢ²): each row weighted by its own error's scale
        W = 1.0 / np.maximum(np.mean(e**2, axis=0), np.finfo(float).tiny)
        J = rate_sensitivities(model, theta, x, fins)[:, :_ROWS, idx]
        A = (J * np.sqrt(W)[None, :, None]).reshape(-1, len(idx))
        b = (e * np.sqrt(W)).reshape(-1)
        scale = np.linalg.norm(A, axis=0)
        scale = np.where(scale > 0, scale, 1.0)
        step = np.linalg.lstsq(A / scale, b, rcond=1e-8)[0]
        theta[idx] += step / scale
        if np.all(np.abs(step / scale) <= STEP_TOL * np.abs(theta[idx])):
            break
    return theta
