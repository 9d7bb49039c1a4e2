"""The filters' discrete model `E = [Φ Γ s]` and its derivative `∂E/∂θ` at the free coefficients
(`DiscreteModel`), for the augmented state of the MEKF and EKF (`mekf`).
"""

from __future__ import annotations

import numpy as np

from testbed.data import Experiment
from testbed.models.linear import continuous, derivatives, expm_pair

__all__ = ["DiscreteModel"]


class DiscreteModel:
    """The discrete model `E = [Φ Γ s]` and `∂E/∂θ` (n, p, q) at the free coefficients `th`.

    When no free coefficient enters the mass matrix Mt (no free *dot term: Scenario II's default
    list), `M = Mt⁻¹[At Bt St]` is affine in θ and its derivatives are constant: both come from
    one solve at the start and `M(θ)` is one product. Otherwise `continuous`/`derivatives` are
    evaluated at every refresh.

    The filters take the model through `linearised` (module docstring, "Speed"): exact when a
    coefficient moved more than `refresh_tol` of its σ since the last exact one (and at the
    first sample of each experiment: `restart`), carried to first order in between."""

    def __init__(self, s, theta: np.ndarray, idx: np.ndarray):
        self.s, self.theta, self.idx = s, theta.copy(), idx
        self.th0 = theta[idx].copy()
        self.affine = not np.any(s.dMt[idx])
        if self.affine:
            self.M0, self.dM = self._continuous(self.theta)  # LinAlgError: singular Mt
            self.dMq = np.ascontiguousarray(self.dM.transpose(0, 2, 1))  # (n, q, p)
        self.restart(0.0, 0.0)

    def _continuous(self, theta):
        A, B, S = continuous(self.s, theta)
        dA, dB, dS = derivatives(self.s, theta, A, B, S, self.idx)
        M = np.hstack([A, B, S[:, None]])
        dM = np.concatenate([dA, dB, dS[:, :, None]], axis=2).transpose(1, 0, 2)
        return M, np.ascontiguousarray(dM)

    def exact(self, th: np.ndarray, dt: float):
        """`(E, dE)` at `th`: `E = [Φ Γ s]` (n, q) and `dE[:, i, :] = ∂E/∂θ_i` (n, p, q), exact
        (`expm_pair`)."""
        if self.affine:
            M, dM = self.M0 + self.dMq @ (th - self.th0), self.dM
        else:
            theta = self.theta.copy()
            theta[self.idx] = th
            M, dM = self._continuous(theta)
        return expm_pair(M, dM, dt)

    def restart(self, dt: float, refresh_tol: float) -> None:
        """A new experiment (sample interval `dt`): its first `linearised` is exact."""
        self.dt, self.tol2, self.th_model = dt, refresh_tol**2, None

    def begin(self, e: Experiment, refresh_tol: float) -> None:
        """A new experiment `e` (`restart`): its inputs, each with the 1 of the constant term."""
        self.restart(e.dt, refresh_tol)
        self.inputs = np.hstack([e.inputs, np.ones((len(e.t), 1))])

    def step(self, k: int, th: np.ndarray, var: np.ndarray, xk: np.ndarray, x: np.ndarray | None = None):
        """`(Φ, D, xk⁺, x⁺)` of the time update from sample k at `th` (`linearised`, centred on
        `xk`): the states one sample on from `xk` and (if given) from `x` (None otherwise)."""
        xi = np.concatenate((xk, self.inputs[k]))
        E, D = self.linearised(th, var, xi)
        ahead = None if x is None else E @ np.concatenate((x, self.inputs[k]))
        return E[:, : len(E)], D, E @ xi, ahead

    def linearised(self, th: np.ndarray, var: np.ndarray, xi: np.ndarray):
        """`(E, D)` for the time update at `th` (coefficient variances `var`): `E = [Φ Γ s]` and
        `D = ∂(E ξ)/∂θ` (n, p) at `xi = [x; δ; 1]` (the linearisation centre). E is exact if a
        coefficient moved more than `refresh_tol` σ since the last exact model θₘ, else
        `E(θₘ) + ∂E·(th − θₘ)`; ∂E is always θₘ's."""
        if self.th_model is None or ((th - self.th_model) ** 2 > self.tol2 * var).any():
            self.th_model = th.copy()
            self.E0, dE = self.exact(th, self.dt)
            n, p, q = dE.shape
            self.dEx = dE.reshape(n * p, q)  # (dEx @ ξ).reshape(n, p) is ∂(Eξ)/∂θ
            self.dEt = np.ascontiguousarray(dE.transpose(0, 2, 1)).reshape(n * q, p)
            E = self.E0
        else:  # E to first order in the move since the last exact model
            E = self.E0 + (self.dEt @ (th - self.th_model)).reshape(len(self.E0), -1)
        return E, (self.dEx @ xi).reshape(len(E), -1)
