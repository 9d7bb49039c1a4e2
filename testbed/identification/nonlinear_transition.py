"""The nonlinear model's one-sample transition for a Kalman filter: the state one sample interval
on and its exact Jacobians with respect to the state and the free coefficients.

The transition from sample k is `fly_nonlinear`'s RK4 flight over [t_k, t_{k+1}] with the fins held at
sample k's (`substeps` steps), and its Jacobians are that discrete map's own
(`nonlinear_sensitivities.flight` over the one interval: ∂x⁺/∂x and ∂x⁺/∂θ[free], each RK4
stage differentiated), so the filter linearises exactly the model it predicts with. The filter's
state carries u as the perturbation u − U from the vehicle's speed U (as the linear model's
does); the flight's absolute u is that plus U, which the Jacobians do not see.
"""

from __future__ import annotations

import numpy as np

from testbed.data import Experiment
from testbed.identification.nonlinear_sensitivities import flight
from testbed.models.linear import IX
from testbed.models.nonlinear import NonlinearModel
from testbed.models.nonlinear_flight import fly_nonlinear

__all__ = ["NonlinearTransition"]


class NonlinearTransition:
    """The nonlinear model at θ (all of it, `model.names` order) with the coefficients `idx` free,
    stepped one sample at a time over an experiment (`begin`, then `step`)."""

    def __init__(self, model: NonlinearModel, theta: np.ndarray, idx, substeps: int | None = None):
        self.model, self.theta, self.idx = model, np.asarray(theta, float).copy(), np.asarray(idx)
        self.substeps = substeps
        self.trim = np.zeros(len(IX))
        self.trim[IX["u"]] = model.vehicle.speed

    def begin(self, e: Experiment, refresh_tol: float = 0.0) -> None:
        """A new experiment: its times and fin angles (`refresh_tol` is the linear model's: every
        step here is exact)."""
        self.t, self.fins = np.asarray(e.t, float), np.asarray(e.inputs, float)

    def step(self, k: int, th: np.ndarray, var, xk: np.ndarray, x: np.ndarray | None = None):
        """`(Φ, D, xk⁺, x⁺)` of the interval from sample k at the free coefficients `th`: Φ = ∂x⁺/∂x
        (10, 10) and D = ∂x⁺/∂θ[free] (10, p) at `xk`, and the states one interval on from `xk`
        and (if given) from `x` (None otherwise); `var` (the coefficients' variances) is unused."""
        theta = self.theta.copy()
        theta[self.idx] = th
        t, fins = self.t[k : k + 2], self.fins[k : k + 2]
        f = flight(self.model, theta, t, xk + self.trim, fins, self.idx, self.substeps)
        ahead = (
            None
            if x is None
            else fly_nonlinear(self.model, theta, t, x + self.trim, fins, self.substeps)[1] - self.trim
        )
        return f.dx_dx0[1], f.dx_dtheta[1], f.x[1] - self.trim, ahead
