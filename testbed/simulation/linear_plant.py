"""The linear model flown as a plant: `ẋ = A x + B δ + S (+ W w)` with the fin servos' rate limit.

`LinearPlant` steps the model exactly (zero-order hold at its timestep, the control period) with
the fins slewing towards their commands at the servos' rate limit, each step holding the fin's
mean angle over it (the fin ramps for |move| / (rate Δ) of the step, then holds). It offers the
truth plant's interface (`reset`, `state`, `step`, `fin_angles`, `fin_integral`, `position`,
`timestep`), so a scenario flies it as it flies the MuJoCo plant (`testbed.simulation.scenario`),
and `testbed.simulation.autopilot.fly_linear` flies the design's closed loops on it. With `W`
(10 × 6: the state derivative per unit body-axis force and moment at the CG, Mt⁻¹ (I, 0)) it
takes an external `wrench`, held over each step, as the MuJoCo plant does. The fin
range is the autopilot's: it clips every command to the servos' range before the plant sees it.
"""

from __future__ import annotations

import math

import numpy as np

from testbed.models.linear import IX, NX, discretize

__all__ = ["LinearPlant"]

_U, _V, _PSI = IX["u"], IX["v"], IX["psi"]


class LinearPlant:
    """The linear model (A, B, S) stepped every `timestep` s, fins slewing at `rate_limit` rad/s."""

    def __init__(
        self,
        A: np.ndarray,
        B: np.ndarray,
        S: np.ndarray,
        timestep: float,
        rate_limit: float,
        W: np.ndarray | None = None,
    ):
        self.Phi, self.Gamma, self.s = discretize(A, B if W is None else np.hstack([B, W]), S, timestep)
        self.Gamma, self.Gamma_w = self.Gamma[:, : B.shape[1]], self.Gamma[:, B.shape[1] :]
        self.wrench = np.zeros(self.Gamma_w.shape[1])  # the external wrench's input, held over each step
        self.timestep = float(timestep)
        self.rate_limit = float(rate_limit)
        self.reset()

    def reset(self, speed: float = 0.0, depth: float = 0.0, x0: np.ndarray | None = None) -> None:
        """Trim at `speed` (m/s), fins at 0, from the perturbation state `x0` (default: trim at
        `depth` m)."""
        self.speed = float(speed)
        self.x = np.zeros(NX) if x0 is None else np.array(x0, float)
        if x0 is None:
            self.x[IX["z"]] = depth
        self.fin = np.zeros(3)
        self.integral = np.zeros(3)
        self.track = np.zeros(2)  # north, east (m)

    def state(self) -> np.ndarray:
        """The state `u v w p q r phi theta psi z` (absolute u, as the truth plant's)."""
        x = self.x.copy()
        x[IX["u"]] += self.speed
        return x

    def fin_angles(self) -> np.ndarray:
        return self.fin.copy()

    def fin_integral(self) -> np.ndarray:
        """∫ δ dt of each fin since the last reset (rad s): its difference over a step, divided
        by the step, is the angle the step held."""
        return self.integral.copy()

    def position(self) -> np.ndarray:
        """NED position (m): the depth state, and the horizontal track integrated from the
        horizontal velocity turned by the heading (the model has no north and east states)."""
        return np.array([*self.track, self.x[IX["z"]]])

    def step(self, fin_commands, n: int = 1) -> None:
        """Advance `n` steps with the fins commanded to `fin_commands` (rad)."""
        dt, reach = self.timestep, self.rate_limit * self.timestep
        commands = np.asarray(fin_commands, float)
        for _ in range(n):
            # the fins' move, clipped to ±reach (numpy's clip costs more than its arithmetic here)
            move = np.minimum(np.maximum(commands - self.fin, -reach), reach)
            held = self.fin + move * (1.0 - 0.5 * np.abs(move) / reach)
            x = self.x.tolist()
            u, v, psi = self.speed + x[_U], x[_V], x[_PSI]
            c, s = math.cos(psi), math.sin(psi)
            self.track[0] += dt * (u * c - v * s)
            self.track[1] += dt * (u * s + v * c)
            self.x = self.Phi @ self.x + self.Gamma @ held + self.s
            if self.wrench.size:
                self.x += self.Gamma_w @ self.wrench
            self.fin = self.fin + move
            self.integral += held * dt
