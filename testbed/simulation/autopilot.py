"""Autopilots designed from the analytic linear model: course rate, depth, roll, and a slow hold.

Each loop is a linear-quadratic regulator with integral action, designed on its block of the
analytic model (`testbed.simulation.analytic.analytic_model`) with Bryson's rule (Q = diag(1/x_max²),
R = 1/δ_max²):

- course rate: rudder on (v, r, ∫(r − r_cmd)), with the steady-state rudder as feedforward;
- pitch: elevators together, δe = (δer + δel)/2, on (w, q, θ, ∫(θ − θ_cmd)); depth is an outer
  loop commanding the pitch that gives a depth rate k_z (z_cmd − z), limited to ±`max_pitch`;
- roll: elevators differentially, δa = (δer − δel)/2, on (p, φ, ∫(φ − φ_cmd)).

The fins are strong (20 deg/s of turn takes under 1 deg of rudder at 20 m/s), so δ_max is small
to keep the loops from banging between the stops at the torpedo's 2 rad/s fin rate limit.

Step responses on the analytic model at 20 m/s (`step_response`: the autopilot at 50 Hz on the
exact zero-order-hold model, fins rate-limited to 2 rad/s; Scenario I's step sizes; rise 10–90 %,
settling into ±2 % of the step; tested):

| loop | step | rise time | overshoot | settling |
|---|---|---|---|---|
| course rate | 0 → 20 deg/s | 0.06 s | 3.0 % | 1.10 s |
| depth | 100 → 120 m | 3.02 s | 0.0 % | 6.92 s |
| roll | 0 → 5 deg | 0.14 s | 7.8 % | 1.92 s |

Course rate and roll rise fast and then creep back from their overshoot with the integrator's
slow mode; depth is first order (k_z = 0.6/s, the pitch command at its 0.45 rad limit for the
first 0.8 s), so Scenario I's 5 s depth steps reach 95 % but not ±2 %.

Vertical excitation hold (`Autopilots.hold`): in Scenario II's vertical mode both elevators follow a
PRBS. The torpedo is nearly neutral in pitch (its only restoring moment is zB B: a pole at
−0.012 rad/s), so an open-loop PRBS random-walks pitch and depth. The hold is a state feedback
on (θ, z − z_cmd) only, designed on the quasi-steady model of the slow pitch-depth motion (w and
q eliminated by singular perturbation: θ̇ ≈ −24.5 δe at 20 m/s) with Butterworth poles at
`hold_bandwidth` = 0.2 rad/s (0.03 Hz) — deliberately far below the PRBS band, so the PRBS
dominates the elevators above ~0.1 Hz while depth and pitch stay bounded. It has no integrator
(nothing to wind up).

Fin commands are clipped to the vehicle's fin range, ±`fin_limit` (the MJCF's servo range,
`testbed.simulation.vehicle.fin_limits`). An integrator stops integrating while its fin command is
not realised (saturated, including where the pitch and roll mix on one elevator exceeds the stop)
and its error would push further into the stop (conditional integration: no wind-up).
`Autopilot.integrators` is its only state.

The loops are designed in continuous time and run at the scenario's control rate;
`Autopilot.designed` refuses a speed at which they are unstable when sampled (`check_sampled`:
the bundled torpedo at 50 Hz above about 27 m/s, where the pitch loop's gain, growing with the
fins' U² effectiveness, makes its mode at the Nyquist frequency diverge).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from scipy.linalg import solve_continuous_are

from testbed.errors import InputError
from testbed.models.linear import IX, NX, discretize
from testbed.simulation.linear_plant import LinearPlant
from testbed.simulation.vehicle import FinLimits

__all__ = [
    "HOLD_BANDWIDTH",
    "STEP_RESPONSES",
    "Autopilot",
    "Channel",
    "Autopilots",
    "StepMetrics",
    "check_sampled",
    "closed_loop",
    "design_autopilots",
    "design_channel",
    "design_hold",
    "fly_linear",
    "step_metrics",
    "step_response",
]

YAW, PITCH, ROLL = 0, 1, 2  # the integrators


@dataclass(frozen=True)
class Channel:
    """One LQR-with-integrator loop: δ = g_ref ref − K x − K_i ∫(x_tracked − ref)."""

    tracked: str  # the state whose error is integrated
    K: np.ndarray  # (NX,) full-state gain, zero outside the loop's states
    Ki: float
    g_ref: float  # feedforward: steady δ per unit ref plus K x_ss per unit ref


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
    k = (bb.T @ P)[0] * delta_max**2
    # Steady state for a unit command of the tracked state: [a b; e_tracked 0] [x; δ] = [0; 1]
    M = np.zeros((n + 1, n + 1))
    M[:n, :n], M[:n, n] = a, b[:, 0]
    M[n, states.index(tracked)] = 1.0
    rhs = np.zeros(n + 1)
    rhs[n] = 1.0
    ff = np.linalg.lstsq(M, rhs, rcond=None)[0]
    K = np.zeros(NX)
    K[i] = k[:n]
    return Channel(tracked, K, float(k[n]), float(ff[n] + k[:n] @ ff[:n]))


def design_hold(A, b, bandwidth: float) -> np.ndarray:
    """Gains (K_θ, K_z) of δe = −K_θ θ − K_z (z − z_cmd) placing the slow pitch-depth poles at
    `bandwidth` (rad/s, Butterworth), on the quasi-steady model with w and q eliminated."""
    f, s = [IX["w"], IX["q"]], [IX["theta"], IX["z"]]
    fast = np.linalg.solve(A[np.ix_(f, f)], np.column_stack([A[np.ix_(f, s)], b[f]]))
    a = A[np.ix_(s, s)] - A[np.ix_(s, f)] @ fast[:, :2]
    bs = b[s] - A[np.ix_(s, f)] @ fast[:, 2]
    # Ackermann: K = [0 1] C⁻¹ φ(a), φ the desired characteristic polynomial s² + √2 ω s + ω².
    C = np.column_stack([bs, a @ bs])
    phi = a @ a + np.sqrt(2.0) * bandwidth * a + bandwidth**2 * np.eye(2)
    return np.linalg.solve(C, np.eye(2))[1] @ phi


@dataclass(frozen=True)
class Autopilots:
    """The three loops, the depth outer loop and the slow hold of the vertical excitation mode."""

    yaw_rate: Channel
    pitch: Channel
    roll: Channel
    hold: np.ndarray  # (K_θ, K_z), see design_hold
    speed: float
    k_depth: float = 0.6  # 1/s: commanded depth rate per metre of depth error
    max_pitch: float = 0.45  # rad


HOLD_BANDWIDTH = 0.2  # rad/s: the vertical-mode hold, far below the PRBS band (0.01–4.4 Hz)


def design_autopilots(
    A: np.ndarray, B: np.ndarray, speed: float, hold_bandwidth: float = HOLD_BANDWIDTH
) -> Autopilots:
    """Autopilots the autopilots on the continuous linear model (A, B) at trim `speed` (`STATES` order)."""
    rudder = B[:, 0]
    together = B[:, 1] + B[:, 2]  # δer = δel = δe
    differential = B[:, 1] - B[:, 2]  # δer = −δel = δa
    return Autopilots(
        yaw_rate=design_channel(A, rudder, ("v", "r"), "r", [2.0, 0.3, 0.3], 0.02),
        pitch=design_channel(A, together, ("w", "q", "theta"), "theta", [2.0, 0.3, 0.1, 0.1], 0.05),
        roll=design_channel(A, differential, ("p", "phi"), "phi", [1.0, 0.05, 0.05], 0.01),
        hold=design_hold(A, together, hold_bandwidth),
        speed=speed,
    )


def _loop_gains(d: Autopilots) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(mix K, mix Ki, E) of all loops in their linear range, commands zero: the fins are
    −(mix K x + mix Ki ∫), and the integrators integrate E x."""
    mix = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 1.0], [0.0, 1.0, -1.0]])  # (δr, δe, δa) -> fins
    K = np.array([d.yaw_rate.K, d.pitch.K, d.roll.K])
    K[1, IX["z"]] -= d.pitch.g_ref * d.k_depth / d.speed  # θ_cmd = k_z (z − z_cmd) / U
    Ki = np.diag([d.yaw_rate.Ki, d.pitch.Ki, d.roll.Ki])
    E = np.zeros((3, NX))  # the integrated errors x_tracked − ref
    E[0, IX["r"]], E[2, IX["phi"]] = 1.0, 1.0
    E[1, IX["theta"]], E[1, IX["z"]] = 1.0, -d.k_depth / d.speed
    return mix @ K, mix @ Ki, E


def closed_loop(A: np.ndarray, B: np.ndarray, d: Autopilots, dt: float) -> np.ndarray:
    """The sampled closed loop of all loops in their linear range, from the design's gains:
    state (x, ∫yaw, ∫pitch, ∫roll), commands zero, the fins held over each control period dt
    (the exact zero-order-hold model of (A, B))."""
    Phi, Gamma, _ = discretize(A, B, np.zeros(NX), dt)
    K, Ki, E = _loop_gains(d)
    # x⁺ = Φ x − Γ (K x + Ki ∫),  ∫⁺ = ∫ + dt E x
    return np.block([[Phi - Gamma @ K, -Gamma @ Ki], [dt * E, np.eye(3)]])


def check_sampled(A: np.ndarray, B: np.ndarray, d: Autopilots, dt: float) -> None:
    """InputError when the loops, stable in continuous time, are unstable sampled every dt: the
    fins' effectiveness grows as U², and above some speed the pitch loop's gain makes its
    sampled mode at the Nyquist frequency grow (this torpedo at 50 Hz: above about 27 m/s). The
    heading, which no loop holds, is the one mode on the unit circle; a vehicle unstable in a
    mode no loop holds is left to the plant, which stops where its motion diverges."""
    K, Ki, E = _loop_gains(d)
    # ẋ = (A − B K) x − B Ki ∫,  d∫/dt = E x
    continuous = np.block([[A - B @ K, -B @ Ki], [E, np.zeros((3, 3))]])
    if np.linalg.eigvals(continuous).real.max() > 1e-9:
        return
    w = np.linalg.eigvals(closed_loop(A, B, d, dt))
    k = int(np.argmax(np.abs(w)))
    if abs(w[k]) > 1.0 + 1e-9:
        raise InputError(
            f"the autopilots are unstable when sampled at {1 / dt:g} Hz at a trim speed of {d.speed:g} m/s "
            f"(a mode at {abs(np.angle(w[k])) / (2 * np.pi * dt):.1f} Hz grows {abs(w[k]):.3g}x "
            "per step); expected a lower speed or a higher control rate"
        )


@dataclass
class Autopilot:
    """The autopilots with their integrators (the only state). Modes switch loops on or off."""

    design: Autopilots
    dt: float  # control period, s
    fin_limit: float  # rad: fin commands are clipped to ±fin_limit (the MJCF's servo range)
    integrators: np.ndarray = field(default_factory=lambda: np.zeros(3))  # YAW, PITCH, ROLL

    def __post_init__(self):
        d = self.design
        self.loops = (d.yaw_rate, d.pitch, d.roll)
        self._K = np.array([c.K for c in self.loops])  # one product per step for all loops

    @classmethod
    def designed(cls, A: np.ndarray, B: np.ndarray, speed: float, dt: float, fin_limit: float) -> "Autopilot":
        """The autopilots designed on (A, B) at trim `speed`, run every dt s (`check_sampled`),
        their fin commands clipped to ±`fin_limit` rad."""
        d = design_autopilots(A, B, speed)
        check_sampled(A, B, d, dt)
        return cls(d, dt, fin_limit)

    def reset(self) -> None:
        self.integrators[:] = 0.0

    def step(
        self,
        x: np.ndarray,
        *,
        depth=None,
        yaw_rate=None,
        roll=None,
        rudder=None,
        elevators=None,
        differential=None,
        hold_depth=None,
    ) -> tuple[tuple[float, float, float], float | None]:
        """Fin commands (δr, δer, δel) for state `x` (`STATES` order), and the pitch command
        (rad; None when depth is not controlled).

        Give `depth` (m) to hold or change depth, `yaw_rate` (rad/s), `roll` (rad); or `rudder`,
        `elevators` (together, δe) or `differential` (δa: δer = δe + δa, δel = δe − δa) in rad
        to drive those fins directly (open loop, e.g. a PRBS). With `elevators`, `hold_depth`
        (m) adds the slow hold's correction to both elevators.
        """
        if differential is not None and roll is not None:
            raise ValueError("differential and roll both drive the elevators' difference; give one")
        d, stop = self.design, self.fin_limit
        kx = (self._K @ x).tolist()
        if rudder is not None:
            dr = _clip(rudder, stop)
        elif yaw_rate is not None:
            u = self._output(YAW, yaw_rate, kx)
            dr = _clip(u, stop)
            self.integrate(YAW, x, yaw_rate, u, dr)
        else:
            dr = 0.0
        theta_cmd = None
        da = 0.0 if differential is None else differential
        if elevators is not None:
            de = elevators
            if hold_depth is not None:
                de -= d.hold[0] * x[IX["theta"]] + d.hold[1] * (x[IX["z"]] - hold_depth)
        else:
            de = 0.0
            if depth is not None:
                theta_cmd = _clip(-d.k_depth * (depth - x[IX["z"]]) / d.speed, d.max_pitch)
                de = self._output(PITCH, theta_cmd, kx)
            if roll is not None:
                da = self._output(ROLL, roll, kx)
        er, el = _clip(de + da, stop), _clip(de - da, stop)
        # What the elevators realise of each loop's demand, after the stops on their sum.
        if theta_cmd is not None:
            self.integrate(PITCH, x, theta_cmd, de, 0.5 * (er + el))
        if roll is not None and elevators is None:
            self.integrate(ROLL, x, roll, da, 0.5 * (er - el))
        return (dr, er, el), theta_cmd

    def _output(self, k: int, ref: float, kx: list) -> float:
        ch = self.loops[k]
        return ch.g_ref * ref - kx[k] - ch.Ki * self.integrators[k]

    def integrate(self, k: int, x: np.ndarray, ref: float, demanded: float, realised: float) -> None:
        """Conditional integration: not while the demand is cut by a stop and the error pushes
        it further in (the integrator's push on δ is −K_i error). A subclass may replace the
        rule (the tests compare it with plain and clamped integration)."""
        error = x[IX[self.loops[k].tracked]] - ref
        cut = demanded - realised  # rounding of the elevator mix is no cut
        if abs(cut) > 1e-12 and (-self.loops[k].Ki * error > 0) == (cut > 0):
            return
        self.integrators[k] += error * self.dt


def _clip(value: float, limit: float) -> float:
    return min(max(value, -limit), limit)


# -- the design on the analytic model: closed-loop responses -------------------------------------


def fly_linear(
    A: np.ndarray,
    B: np.ndarray,
    autopilot: Autopilot,
    commands: Callable[[float, np.ndarray], dict],
    duration: float,
    x0: np.ndarray | None = None,
    *,
    rate_limit: float,
):
    """Fly `autopilot` on the linear model ẋ = A x + B δ (a `LinearPlant`: exact zero-order hold
    at its period).

    `commands(t, x)` gives `Autopilot.step`'s keywords. The fins slew at `rate_limit` (rad/s;
    the vehicle's, `FinLimits.rate`) towards the commands, as the plant's servos; each period holds the fin's mean angle over it.
    Returns times (N,), states (N, NX) and fin angles (N, 3) at the control instants.
    """
    dt = autopilot.dt
    plant = LinearPlant(A, B, np.zeros(NX), dt, rate_limit)
    plant.reset(x0=x0)
    n = int(round(duration / dt)) + 1
    xs, fins = np.empty((n, NX)), np.empty((n, 3))
    for k in range(n):
        xs[k], fins[k] = plant.x, plant.fin
        cmd, _ = autopilot.step(plant.x, **commands(k * dt, plant.x))
        plant.step(cmd)
    return np.arange(n) * dt, xs, fins


@dataclass(frozen=True)
class StepMetrics:
    rise: float  # s, 10 % to 90 % of the step
    overshoot: float  # fraction of the step
    settling: float  # s, last exit from ±2 % of the step around the target
    final: float  # the response at the end


def step_metrics(t: np.ndarray, y: np.ndarray, start: float, target: float) -> StepMetrics:
    """Rise time, overshoot and settling time of the response `y` to a step start → target."""
    e = (y - start) / (target - start)  # 0 → 1
    rise = t[np.argmax(e >= 0.9)] - t[np.argmax(e >= 0.1)] if np.any(e >= 0.9) else np.inf
    outside = np.flatnonzero(np.abs(e - 1.0) > 0.02)
    if not len(outside):
        settling = 0.0
    elif outside[-1] == len(t) - 1:
        settling = np.inf  # not settled within the record
    else:
        settling = t[outside[-1] + 1]
    return StepMetrics(float(rise), float(max(0.0, e.max() - 1.0)), float(settling), float(y[-1]))


# The documented steps: Scenario I's sizes (course rate and depth), a 5 deg roll step.
STEP_RESPONSES = {
    "course rate": ("r", "yaw_rate", 0.0, np.radians(20.0)),
    "depth": ("z", "depth", 100.0, 120.0),
    "roll": ("phi", "roll", 0.0, np.radians(5.0)),
}


def step_response(
    A: np.ndarray,
    B: np.ndarray,
    design_: Autopilots,
    loop: str,
    fins: FinLimits,
    duration: float = 10.0,
    rate: float = 50.0,
    target: float | None = None,
):
    """The closed-loop response of `loop` (a key of STEP_RESPONSES) to its step, the other loops holding
    (course-rate steps hold depth and roll; depth and roll steps hold each other and zero course
    rate), with the vehicle's fin range and rate `fins`. Returns (t, y, fins, StepMetrics);
    `target` overrides the step's end value."""
    state, key, start, end = STEP_RESPONSES[loop]
    end = end if target is None else target
    hold = {"yaw_rate": 0.0, "depth": 100.0, "roll": 0.0}
    x0 = np.zeros(NX)
    x0[IX["z"]] = 100.0
    ap = Autopilot(design_, 1.0 / rate, fins.angle)
    t, xs, angles = fly_linear(A, B, ap, lambda t, x: {**hold, key: end}, duration, x0, rate_limit=fins.rate)
    y = xs[:, IX[state]]
    return t, y, angles, step_metrics(t, y, start, end)
