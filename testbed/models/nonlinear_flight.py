"""The nonlinear model flown open loop: its states from a first one, driven by recorded fin angles.

`fly` integrates ẋ = f(x, δ, θ) (`nonlinear.rates`) by the classical fourth-order Runge-Kutta
method, `substeps` steps per sample interval, each sample's fin angles held until the next: a
run's records give at each sample the fins' mean over the interval that follows it, which held
over that interval moves the body as the fins did to first order (the linear model's predictions
take the inputs so too).
"""

from __future__ import annotations

import numpy as np

from testbed.errors import InputError
from testbed.models.linear import NU, NX
from testbed.models.nonlinear import NonlinearModel, rates

__all__ = ["fly"]


def fly(model: NonlinearModel, theta, t, x0, fins, substeps: int = 4) -> np.ndarray:
    """The states (N, 10), absolute u, at the times `t` (N,) from `x0` (10,) at t[0], the fin
    angles `fins` (N, 3) (rad) given at the same times, each held until the next; complex where
    `theta` or `x0` is (a complex-step derivative of the flight)."""
    dtype = np.result_type(np.asarray(theta), np.asarray(x0), float)
    t, x0, fins = np.asarray(t, float), np.asarray(x0, dtype), np.asarray(fins, float)
    if t.ndim != 1 or len(t) < 2 or not np.all(np.diff(t) > 0):
        raise InputError(f"t: {t.shape} times; expected two or more increasing times")
    if x0.shape != (NX,) or fins.shape != (len(t), NU):
        raise InputError(f"x0 {x0.shape}, fins {fins.shape}; expected ({NX},) and ({len(t)}, {NU})")
    if not isinstance(substeps, int) or substeps < 1:
        raise InputError(f"substeps={substeps!r}; expected a whole number >= 1")
    out = np.empty((len(t), NX), dtype)
    out[0] = x = x0
    for k in range(len(t) - 1):
        h, d = (t[k + 1] - t[k]) / substeps, fins[k]
        for _ in range(substeps):
            k1 = rates(model, theta, x, d)
            k2 = rates(model, theta, x + h / 2 * k1, d)
            k3 = rates(model, theta, x + h / 2 * k2, d)
            k4 = rates(model, theta, x + h * k3, d)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        out[k + 1] = x
    return out
