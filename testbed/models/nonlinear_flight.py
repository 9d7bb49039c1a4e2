"""The nonlinear model flown open loop: its states from a first one, driven by recorded fin angles.

`fly` integrates ẋ = f(x, δ, θ) (`nonlinear.rates`) by the classical fourth-order Runge-Kutta
method, `substeps` steps per sample interval, the fin angles interpolated linearly between their
samples (the fins are servo-driven: they move continuously between the samples that record them).
"""

from __future__ import annotations

import numpy as np

from testbed.errors import InputError
from testbed.models.linear import NU, NX
from testbed.models.nonlinear import NonlinearModel, rates

__all__ = ["fly"]


def fly(model: NonlinearModel, theta, t, x0, fins, substeps: int = 4) -> np.ndarray:
    """The states (N, 10), absolute u, at the times `t` (N,) from `x0` (10,) at t[0], the fin
    angles `fins` (N, 3) (rad) given at the same times."""
    t, x0, fins = np.asarray(t, float), np.asarray(x0, float), np.asarray(fins, float)
    if t.ndim != 1 or len(t) < 2 or not np.all(np.diff(t) > 0):
        raise InputError(f"t: {t.shape} times; expected two or more increasing times")
    if x0.shape != (NX,) or fins.shape != (len(t), NU):
        raise InputError(f"x0 {x0.shape}, fins {fins.shape}; expected ({NX},) and ({len(t)}, {NU})")
    if not isinstance(substeps, int) or substeps < 1:
        raise InputError(f"substeps={substeps!r}; expected a whole number >= 1")
    out = np.empty((len(t), NX))
    out[0] = x = x0
    for k in range(len(t) - 1):
        h = (t[k + 1] - t[k]) / substeps
        slope = (fins[k + 1] - fins[k]) / (t[k + 1] - t[k])
        for s in range(substeps):
            d0 = fins[k] + slope * (s * h)
            dm, d1 = d0 + slope * (h / 2), d0 + slope * h
            k1 = rates(model, theta, x, d0)
            k2 = rates(model, theta, x + h / 2 * k1, dm)
            k3 = rates(model, theta, x + h / 2 * k2, dm)
            k4 = rates(model, theta, x + h * k3, d1)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        out[k + 1] = x
    return out
