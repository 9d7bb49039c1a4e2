"""Autopilots designed from the analytic linear model: depth, course rate and roll.

Each channel is a linear-quadratic regulator with integral action, designed on its block of the
analytic model (`testbed.truth.analytic_model`) with Bryson's rule (Q = diag(1/x_max²),
R = 1/δ_max²):

- course rate: rudder on (v, r, ∫(r − r_cmd)), with the steady-state rudder as feedforward;
- pitch: elevators together, δe = (δer + δel)/2, on (w, q, θ, ∫(θ − θ_cmd)); depth is an outer
  loop commanding the pitch that gives a depth rate k_z (z_cmd − z), limited to ±`max_pitch`;
- roll: elevators differentially, δa = (δer − δel)/2, on (p, φ, ∫(φ − φ_cmd)).

Commands are clipped to the fin range; an integrator stops integrating while its fin saturates
in the direction that would wind it up (conditional integration, no wind-up). The fin rate
limit is the plant's (`Plant.step`). `Autopilot.step` is the only state: the three integrators.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import solve_continuous_are

from testbed.model import IX

FIN_LIMIT = 0.40  # rad, the torpedo's servo range


@dataclass(frozen=True)
class Channel:
    """One LQR-with-integrator loop: δ = δ_ff − K_x (x − x_ref) − K_i ∫e."""

    states: tuple[str, ...]  # the states it feeds back
    tracked: str  # the state whose error is integrated
    Kx: np.ndarray  # (len(states),)
    Ki: float
    ff: np.ndarray  # steady state (x, δ) per unit of command: x_ss / ref, δ_ss / ref


def design_channel(A, B, states, tracked, x_max, delta_max) -> Channel:
    """LQR with integral action on the block `states` of (A, B); B is one input column."""
    i = [IX[s] for s in states]
    a = A[np.ix_(i, i)]
    b = B[i][:, None]
    n = len(i)
    aa = np.zeros((n + 1, n + 1))
    aa[:n, :n] = a
    aa[n, states.index(tracked)] = 1.0
    bb = np.vstack([b, [[0.0]]])
    Q = np.diag(1.0 / np.asarray(x_max, float) ** 2)
    P = solve_continuous_are(aa, bb, Q, np.array([[1.0 / delta_max**2]]))
    K = (bb.T @ P) * delta_max**2
    # Steady state for a unit command of the tracked state: [a b; e_tracked 0] [x; δ] = [0; 1]
    M = np.zeros((n + 1, n + 1))
    M[:n, :n], M[:n, n] = a, b[:, 0]
    M[n, states.index(tracked)] = 1.0
    rhs = np.zeros(n + 1)
    rhs[n] = 1.0
    ff = np.linalg.lstsq(M, rhs, rcond=None)[0]
    return Channel(tuple(states), tracked, K[0, :n], float(K[0, n]), ff)


@dataclass(frozen=True)
class Design:
    """The three channels and the depth outer loop."""

    yaw_rate: Channel
    pitch: Channel
    roll: Channel
    speed: float
    k_depth: float = 0.6  # 1/s: commanded depth rate per metre of depth error
    max_pitch: float = 0.45  # rad


def design(A: np.ndarray, B: np.ndarray, speed: float) -> Design:
    """Design the autopilots on the continuous linear model (A, B) at trim `speed` (SPEC order)."""
    rudder = B[:, 0]
    together = B[:, 1] + B[:, 2]  # δer = δel = δe
    differential = B[:, 1] - B[:, 2]  # δer = −δel = δa
    return Design(
        # The fins are strong (20 deg/s of turn takes under 1 deg of rudder at 20 m/s): small
        # δ_max keeps the loops from banging between the stops at the 2 rad/s rate limit.
        yaw_rate=design_channel(A, rudder, ("v", "r"), "r", [2.0, 0.3, 0.3], 0.02),
        pitch=design_channel(A, together, ("w", "q", "theta"), "theta", [2.0, 0.3, 0.1, 0.1], 0.05),
        roll=design_channel(A, differential, ("p", "phi"), "phi", [1.0, 0.05, 0.05], 0.01),
        speed=speed,
    )


@dataclass
class Autopilot:
    """The autopilots with their integrators (the only state). Modes switch channels on or off."""

    design: Design
    dt: float  # control period, s
    integrators: np.ndarray = field(default_factory=lambda: np.zeros(3))  # yaw rate, pitch, roll

    def step(self, x: np.ndarray, *, depth=None, yaw_rate=None, roll=None, rudder=None,
             elevators=None, elevator_excitation=0.0) -> tuple[np.ndarray, dict]:  # fmt: skip
        """Fin commands (δr, δer, δel) for state `x` (SPEC order, absolute u).

        Give `depth` (m) to hold or change depth, `yaw_rate` (rad/s), `roll` (rad); or `rudder`
        / `elevators` (rad) to drive those fins directly (open loop, e.g. a PRBS);
        `elevator_excitation` is added to both elevators on top of the depth loop. Returns the
        commands and the inner references used ({"pitch": θ_cmd} when depth is controlled).
        """
        d, refs = self.design, {}
        if rudder is not None:
            dr = rudder
        elif yaw_rate is not None:
            dr = self._loop(0, d.yaw_rate, x, yaw_rate)
        else:
            dr = 0.0
        if elevators is not None:
            de, da = elevators, 0.0
        else:
            de = 0.0
            if depth is not None:
                zdot = d.k_depth * (depth - x[IX["z"]])
                theta_cmd = _clip(-zdot / d.speed, d.max_pitch)
                refs["pitch"] = theta_cmd
                de = self._loop(1, d.pitch, x, theta_cmd)
            de += elevator_excitation
            da = self._loop(2, d.roll, x, roll) if roll is not None else 0.0
        cmd = np.array([_clip(dr), _clip(de + da), _clip(de - da)])
        return cmd, refs

    def _loop(self, k: int, ch: Channel, x: np.ndarray, ref: float) -> float:
        error = x[IX[ch.tracked]] - ref
        u = ch.ff[-1] * ref - ch.Ki * self.integrators[k]
        for s, gain, x_ss in zip(ch.states, ch.Kx, ch.ff):
            u -= gain * (x[IX[s]] - x_ss * ref)
        # Conditional integration: stop where the fin is saturated and the error would wind up.
        saturated = abs(u) >= FIN_LIMIT and (-ch.Ki * error > 0) == (u > 0)
        if not saturated:
            self.integrators[k] += error * self.dt
        return _clip(u)


def _clip(value: float, limit: float = FIN_LIMIT) -> float:
    return float(min(max(value, -limit), limit))
