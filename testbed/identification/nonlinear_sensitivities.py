"""The nonlinear model's simulated trajectory and its exact sensitivities to the coefficients and
to the initial state.

The trajectory is `fly_nonlinear`'s: classical RK4, `substeps` steps per sample interval, each sample's fins
held. The sensitivities are those of that discrete map, not of the ODE: each RK4 stage
`k_i = f(X_i, δ, θ)` is differentiated, `∂k_i = A_i ∂X_i + F_θ,i` with `A_i = ∂f/∂x` and
`F_θ,i = ∂f/∂θ` at the stage's state X_i (the model's exact Jacobians), so the gradient of any
cost of the simulated outputs is exact. One compiled forward pass (`nonlinear_flight.fly_with_sensitivities`)
flies the record and carries the sensitivity matrix S = ∂x/∂[θ[free] | the fins' parameters | x0]
(10 × (p + q + 10)) through every stage from S_0 = [0 0 I]; a parameter that moves the fins (the
inputs' delay τ, the fins δ(t + τ)) forces its column by `B_i ∂δ/∂τ`, `B_i = ∂f/∂δ` at the stage.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from testbed.models.nonlinear import NonlinearModel
from testbed.models.nonlinear_flight import fly_with_sensitivities

__all__ = ["FlightSensitivities", "flight"]


@dataclass(frozen=True)
class FlightSensitivities:
    """A simulated record and its sensitivities at its samples."""

    x: np.ndarray  # (N, 10) states, absolute u
    dx_dtheta: np.ndarray  # (N, 10, p) ∂x/∂θ of the chosen coefficients
    dx_dx0: np.ndarray  # (N, 10, 10) ∂x/∂x0
    dx_dinputs: np.ndarray  # (N, 10, q) ∂x/∂ the parameters that move the fins (the inputs' delay)


def flight(
    model: NonlinearModel, theta, t, x0, fins, free=(), substeps: int | None = None, dfins=None
) -> FlightSensitivities:
    """`fly_nonlinear`'s states at the times `t` (N,) from `x0` (10,) with the fins (N, 3) held per sample,
    and their exact sensitivities to θ[free] (indices into `model.names`), to the parameters whose
    derivatives of the fins `dfins` (N, 3, q) gives (None: none) and to x0, in one pass."""
    free = np.asarray(free, dtype=np.int64).reshape(-1)
    x, S = fly_with_sensitivities(
        model, np.asarray(theta, float), t, np.asarray(x0, float), fins, free, substeps, dfins
    )
    p, q = len(free), 0 if dfins is None else np.shape(dfins)[2]
    return FlightSensitivities(
        x=x, dx_dtheta=S[:, :, :p], dx_dx0=S[:, :, p + q :], dx_dinputs=S[:, :, p : p + q]
    )
