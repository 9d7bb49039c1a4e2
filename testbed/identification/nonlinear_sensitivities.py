"""The nonlinear model's simulated trajectory and its exact sensitivities to the coefficients and
to the initial state.

The trajectory is `fly`'s: classical RK4, `substeps` steps per sample interval, each sample's fins
held. The sensitivities are those of that discrete map, not of the ODE: each RK4 stage
`k_i = f(X_i, δ, θ)` is differentiated, `∂k_i = A_i ∂X_i + F_θ,i` with `A_i = ∂f/∂x` and
`F_θ,i = ∂f/∂θ` at the stage's state X_i (`nonlinear.jacobians`, `nonlinear.sensitivities`), so
the gradient of any cost of the simulated outputs is exact.

Given the states at the samples, the stage states of every interval are computed at once
(vectorised over the intervals), and so are the interval's transition `Φ_k = ∂x_{k+1}/∂x_k` and
its input `Γ_k = ∂x_{k+1}/∂θ` at fixed x_k. The sensitivities then follow by the linear recursion
`S_{k+1} = Φ_k S_k + [Γ_k 0]`, `S_0 = [0 I]`, over the columns [free coefficients | x0].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from testbed.models.linear import NX
from testbed.models.nonlinear import NonlinearModel, jacobians, sensitivities
from testbed.models.nonlinear_flight import fly

__all__ = ["Flight", "flight"]


@dataclass(frozen=True)
class Flight:
    """A simulated record and its sensitivities at its samples."""

    x: np.ndarray  # (N, 10) states, absolute u
    dx_dtheta: np.ndarray  # (N, 10, p) ∂x/∂θ of the chosen coefficients
    dx_dx0: np.ndarray  # (N, 10, 10) ∂x/∂x0


def _interval_maps(model, theta, x, fins, h, substeps, free):
    """[Φ_k | Γ_k] (n, 10, 10 + p) of the n intervals starting at the states `x` (n, 10): the
    derivative of the RK4 map over one sample interval w.r.t. its start state and θ[free]."""
    n, p = len(x), len(free)
    T = np.zeros((n, NX, NX + p))
    T[:, :, :NX] = np.eye(NX)
    hh = h[:, None, None]
    for _ in range(substeps):
        ks, dks = [], []
        X, dX = x, T
        for a in (0.0, 0.5, 0.5, 1.0):
            if ks:
                X = x + (a * h)[:, None] * ks[-1]
                dX = T + a * hh * dks[-1]
            f, A, _ = jacobians(model, theta, X, fins)
            G = np.zeros((n, NX, NX + p))
            G[:, :, NX:] = sensitivities(model, theta, X, fins)[:, :, free]
            ks.append(f)
            dks.append(A @ dX + G)
        x = x + h[:, None] / 6 * (ks[0] + 2 * ks[1] + 2 * ks[2] + ks[3])
        T = T + hh / 6 * (dks[0] + 2 * dks[1] + 2 * dks[2] + dks[3])
    return T


def flight(model: NonlinearModel, theta, t, x0, fins, free=(), substeps: int = 4, states=None) -> Flight:
    """`fly`'s states at the times `t` (N,) from `x0` (10,) with the fins (N, 3) held per sample,
    and their exact sensitivities to θ[free] (indices into `model.names`) and to x0. `states`:
    the same call's `fly` states when already flown (not flown again)."""
    x = fly(model, theta, t, x0, fins, substeps) if states is None else np.asarray(states, float)
    free = np.asarray(free, dtype=int).reshape(-1)
    p = len(free)
    h = np.diff(np.asarray(t, float)) / substeps
    T = _interval_maps(
        model, np.asarray(theta, float), x[:-1], np.asarray(fins, float)[:-1], h, substeps, free
    )
    S = np.zeros((len(x), NX, p + NX))
    S[0, :, p:] = np.eye(NX)
    Phi, Gamma = T[:, :, :NX], T[:, :, NX:]
    for k in range(len(x) - 1):
        S[k + 1] = Phi[k] @ S[k]
        S[k + 1, :, :p] += Gamma[k]
    return Flight(x=x, dx_dtheta=S[:, :, :p], dx_dx0=S[:, :, p:])
