"""Data compatibility: the flight path reconstructed from the measured rates and velocities.

Before any fit of the dynamics, the kinematics the measurements must obey are checked (flight-
path reconstruction; Klein & Morelli ch. 10, Jategaonkar ch. 10). The attitude is integrated
from the rate gyros,

    φ̇ = p + (q sin φ + r cos φ) tan θ,   θ̇ = q cos φ − r sin φ,   ψ̇ = (q sin φ + r cos φ) / cos θ,

and the depth from the Doppler velocity log with the measured attitude,

    ż = −u sin θ + v cos θ sin φ + w cos θ cos φ,

each driving channel c corrected by its sensor's bias b_c, scale factor k_c and its group's
delay τ (the true value at time t is `(c_measured(t + τ) − b_c) / (1 + k_c)`; a sensor that
lags by τ has τ > 0), and the measured φ, θ the depth uses by their constant offsets `b_phi`,
`b_theta` (an AHRS mounted off its axes: the true angle is `c_measured − b_c`, the names of the
model's output biases). θ's offset turns the log's u into a sink rate −u sin θ, strongly seen
in depth over a dive; φ's through v and w, seen where v is. A heading offset enters neither
check's kinematics (ψ is the attitude check's output only, one more constant beside its initial
heading) and is not a check parameter; the attitude check integrates from its initial attitude,
which takes the φ and θ offsets in. The reconstruction is compared with the measured φ, θ, ψ
(the attitude check, `ATTITUDE`) and z (the depth check, `DEPTH`), and the initial attitude or
depth and the sensor parameters are fitted by the filter-error method (maximum likelihood of a
Kalman filter's innovations; Maine & Iliff, Jategaonkar): the noise of the rates and velocities
is integrated by the kinematics, so it is process noise, and output error would be biased and
its bounds 2–6 times too small. The noise is read off the data (robust third differences over
the samples present): the outputs' σ is the filter's measurement noise R, the driving channels'
(and, in ż, the attitude's times the velocities) its process noise, a random walk of h H σ² per
step h, H the interval between the channel's samples around it (h² σ² where every row is a
sample; a spline through samples H apart carries each sample's error over H). The attitude
filter is extended (linearised at each step), its gain held at each iteration's (Maine &
Iliff); the depth filter's process noise depends on the corrected velocities, so its gain and
the likelihood's ln det S follow the parameters. The fit is Gauss-Newton (trust region,
`scipy.optimize.least_squares`) on the residuals whose sum of squares is the negative
log-likelihood; its derivatives are exact: the complex step, the measured signals
interpolated by cubic splines (a fractional delay is a shift along the spline, so a 40 ms
delay at 50 Hz is as smooth a parameter as any other). The standard deviations are the
Cramér-Rao bounds, from the Fisher information of the innovations at the optimum.

What the delays mean: the gyros' τ is their lag behind the attitude channels, the log's τ its
lag behind the depth sensor. A delay common to every channel shifts the whole record in time
and cannot be told from the data; only these relative delays can.

The screen, like the coefficients' (docs/cli.md, the screen): a sensor parameter whose
regressor is mostly the noise of a measured channel in every record (`REGRESSORS`) or along
which the Fisher information of these data is singular is not identifiable (e.g. the log's v
bias when roll never leaves 0) and is held at 0; of the others, fitted, one at a time a
parameter within 2 σ of 0 is held at 0 (`HELD_FIRST`: scale factors, delays, then biases; the
others updated for it held there), and those left are fitted again until none is. The initial
states are always fitted.

The depth check's log may be turned from the body's axes by `m_dvl_y`, `m_dvl_z` (its reading
Mᵀ v, M = Rz(m_dvl_z) Ry(m_dvl_y), a scenario sensor's `misalignment`). A parameter correlated
beyond 0.99 with an attitude offset in these data is held, not separable (`_inseparable`): a
log's w bias makes the sink rate of a pitch offset wherever u is near constant, its
misalignment about y is one with it; the offset, the commoner error, is kept. About z the
misalignment turns u into v: seen through v sin φ where the vehicle rolls, and told from a v
bias only where the speed varies. Among the insignificant, the offsets are held last.

Missing samples: each channel's samples present are its data. The filter steps from row to row
of those where every output of the check is present (the others' outputs are left out); the
driving and used channels are cubic splines through their samples present, bridging a gap up
to `MAX_GAP` (3) times the channel's median interval (a dropped sample or two, a slower
sensor's rate); across a longer gap the record is split, each stretch checked with its own
initial state and named `record a–b s`, the gap named unchecked. A record missing a channel a
check needs (not a column, or under 2 samples) is not checked for it: no gyros, no attitude
check; the depth check runs on the log and the measured attitude. The result names what it
could not check, wholly or over which stretch, and why (`Compatibility.unchecked`).

Each record is checked alone, and all records together (`pooled`: one set of sensor
parameters, each record or stretch its own initial states).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.optimize import least_squares

from testbed.analysis.kinematics import attitude_filter, attitudes, depth_filter
from testbed.data import MAX_DATA, Experiment, read_json
from testbed.errors import InputError
from testbed.fit_percent import fit_percent
from testbed.simulation.measurements import noise_from_data

__all__ = [
    "ATTITUDE",
    "CHECKS",
    "DEPTH",
    "MAX_DELAY",
    "MAX_GAP",
    "MAX_MISALIGNMENT",
    "MAX_OFFSET",
    "MAX_SCALE",
    "MISALIGNMENTS",
    "OFFSETS",
    "SENSOR_PARAMETERS",
    "Check",
    "Compatibility",
    "Parameter",
    "Reconstruction",
    "check_corrections",
    "compatibility",
    "corrected",
    "read_corrections",
    "reconstruct",
]

MAX_DELAY = 1.0  # s: the largest sensor delay fitted or applied, either sign
MAX_SCALE = 0.5  # the largest |k| of a scale factor fitted or applied (1 + k within 0.5-1.5)
MAX_MISALIGNMENT = 0.5  # rad: the largest misalignment fitted or applied (a scenario's limit)
SIGNIFICANCE = 2.0  # a parameter within this many σ of 0 is held at 0 (the coefficients' screen)
SINGULAR = 1e-10  # an eigenvalue of the scaled Fisher information below this × the largest: singular
# Of the parameters within SIGNIFICANCE σ of 0, scale factors are held first, then
# misalignments, delays, then biases: a constant velocity makes its bias and scale factor (or a
# misalignment turning it into another channel) nearly one parameter (u ≈ 20 m/s), and a bias
# is the commoner error, present whether the channel varies or not.
# The attitude offsets come last (`_rank`): with u near constant the log's w bias makes nearly
# the sink rate of a pitch offset, and an AHRS mounted off its axes is the commoner error.
HELD_FIRST = ("k_", "m_", "r_", "tau_", "b_")
MAX_ARM = 50.0  # m: the largest |r| of a lever arm fitted or applied
STEP = 1e-30  # the complex step: exact derivatives (no difference is taken)
# A scale factor multiplies its channel, a delay its channel's rate of change, the log's u and v
# biases sin θ and sin φ: a parameter whose regressor is mostly the noise of a measured channel
# would be fitted to that noise (errors in variables: on a level run, where θ is its noise, the
# depth follows no −u sin θ and b_u goes to u). Such a parameter is held, not identifiable,
# unless some record has, for one of its alternatives, every channel's signal (the standard
# deviation of the channel less its noise) at least `MIN_SIGNAL` times its noise.
REGRESSORS = {
    "k_p": (("p",),),
    "k_q": (("q",),),
    "k_r": (("r",),),
    "tau_gyro": (("p",), ("q",), ("r",)),
    "b_u": (("theta",),),
    "k_u": (("theta",),),
    "b_v": (("phi",),),
    "k_v": (("v", "phi"),),
    "k_w": (("w",),),
    "tau_dvl": (("w",), ("u", "theta"), ("v", "phi")),
    "b_phi": (("v",), ("w",)),
    "m_dvl_z": (("phi",),),
    "r_dvl_x": (("theta",),),
    "r_dvl_y": (("phi",),),
    "r_dvl_z": (("phi",), ("theta",)),
}
MIN_SIGNAL = 3.0
MAX_PITCH = 1.5  # rad (86°): beyond, the attitude check is not run (tan θ, 1 / cos θ near ±π/2)
# A sensor parameter correlated with an attitude offset beyond this is held (`_inseparable`).
MAX_CORRELATION = 0.99
MAX_OFFSET = math.pi  # rad: the largest |b| of an attitude offset applied
# A driving or used channel's gap (between two samples present) is bridged by its cubic spline
# when it is at most MAX_GAP times the channel's median interval in the record: a sensor's
# dropped sample or two; a longer gap splits the record, the stretch across it left unchecked.
MAX_GAP = 3.0
MIN_ROWS = 4  # a stretch between gaps is checked when its outputs have at least this many rows


@dataclass(frozen=True)
class Check:
    """One kinematic check: the channels that drive it (corrected by their sensors' parameters),
    the measured channels it uses (corrected by their offsets), the outputs it reconstructs and
    the parameters."""

    name: str
    drives: tuple[str, ...]
    uses: tuple[str, ...]
    outputs: tuple[str, ...]
    initial: tuple[str, ...]
    delay: str
    axes: tuple[str, ...] = ()  # the body axes about which the driving sensor may be turned
    arm: bool = False  # the driving sensor's position (its lever arm) among the parameters

    @property
    def sensor(self) -> tuple[str, ...]:
        """The sensor parameters: each driving channel's bias and scale factor, the delay, each
        used channel's offset, the driving sensor's misalignment about each of `axes`, its
        position along x, y, z where it has an `arm`."""
        group = self.delay.removeprefix("tau_")
        return (
            tuple(f"b_{c}" for c in self.drives)
            + tuple(f"k_{c}" for c in self.drives)
            + (self.delay,)
            + tuple(f"b_{c}" for c in self.uses)
            + tuple(f"m_{group}_{a}" for a in self.axes)
            + (tuple(f"r_{group}_{a}" for a in "xyz") if self.arm else ())
        )

    @property
    def needs(self) -> tuple[str, ...]:
        return self.drives + self.uses + self.outputs


ATTITUDE = Check(
    name="attitude",
    drives=("p", "q", "r"),
    uses=(),
    outputs=("phi", "theta", "psi"),
    initial=("phi0", "theta0", "psi0"),
    delay="tau_gyro",
)
DEPTH = Check(
    name="depth",
    drives=("u", "v", "w"),
    uses=("phi", "theta"),
    outputs=("z",),
    initial=("z0",),
    delay="tau_dvl",
    axes=("y", "z"),
    arm=True,
)
CHECKS = (ATTITUDE, DEPTH)
SENSOR_PARAMETERS = ATTITUDE.sensor + DEPTH.sensor
OFFSETS = tuple(f"b_{c}" for check in CHECKS for c in check.uses)  # the attitude offsets
MISALIGNMENTS = tuple(n for check in CHECKS for n in check.sensor if n.startswith("m_"))
ARMS = tuple(n for check in CHECKS for n in check.sensor if n.startswith("r_"))  # lever arms, m


@dataclass(frozen=True)
class Parameter:
    """An estimate: its value, its Cramér-Rao σ (inf where the data cannot determine it), and
    whether it was fitted; a parameter the screen held at 0 has `estimated` False and `reason`."""

    value: float
    std: float
    estimated: bool = True
    reason: str = ""

    def to_dict(self) -> dict:
        d = {
            "value": self.value,
            "std": self.std if math.isfinite(self.std) else None,
            "identifiable": self.estimated,
        }
        return d | ({"reason": self.reason} if self.reason else {})


@dataclass(frozen=True)
class Reconstruction:
    """One check fitted on one or more records.

    Attributes:
        check: the check's name (`attitude`, `depth`).
        records: the records fitted (one set of sensor parameters for all).
        parameters: sensor parameter → estimate (held at 0 where the screen says so).
        initial: record → initial state → estimate.
        fit: output → {`noise_std`: its measurement noise (read off the data), `residual_std`
            and `fit_percent`: the RMS of y − ŷ and 100 (1 − ‖y − ŷ‖ / ‖y − ȳ‖) of the
            reconstruction run open loop at the estimate (None for a constant channel),
            `innovation_rms`: the RMS of the filter's whitened innovations (≈ 1)}.
        iterations: the Gauss-Newton function evaluations over every fit of the screen.
    """

    check: str
    records: tuple[str, ...]
    parameters: Mapping[str, Parameter]
    initial: Mapping[str, Mapping[str, Parameter]]
    fit: Mapping[str, Mapping[str, float | None]]
    iterations: int

    def to_dict(self) -> dict:
        return {
            "records": list(self.records),
            "parameters": {n: p.to_dict() for n, p in self.parameters.items()},
            "initial": {r: {n: p.to_dict() for n, p in v.items()} for r, v in self.initial.items()},
            "fit": {c: dict(v) for c, v in self.fit.items()},
            "iterations": self.iterations,
        }


@dataclass(frozen=True)
class Compatibility:
    """The checks of a set of records: each record alone and all pooled.

    Attributes:
        records: record → check name → its reconstruction.
        pooled: check name → the reconstruction of every record that has the check's channels.
        unchecked: record → check name → why it was not checked, wholly (missing channels)
            or over the stretches it names (gaps too long to bridge, rows past a channel's
            last sample).
    """

    records: Mapping[str, Mapping[str, Reconstruction]]
    pooled: Mapping[str, Reconstruction]
    unchecked: Mapping[str, Mapping[str, str]]

    @property
    def corrections(self) -> dict[str, float]:
        """The pooled sensor parameters (0 where held), what `corrected` applies."""
        return {n: p.value for r in self.pooled.values() for n, p in r.parameters.items()}

    def to_dict(self) -> dict:
        return {
            "corrections": self.corrections,
            "pooled": {c: r.to_dict() for c, r in self.pooled.items()},
            "records": {
                name: {c: r.to_dict() for c, r in checks.items()} for name, checks in self.records.items()
            },
            "unchecked": {name: dict(why) for name, why in self.unchecked.items() if why},
        }

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2, allow_nan=False) + "\n"

    def table(self) -> str:
        """The pooled sensor parameters, per record beside them, and each output's fit."""
        names = list(self.records)
        lines = []
        for check, pooled in self.pooled.items():
            lines.append(f"{check} check ({', '.join(pooled.records)}):")
            head = f"  {'parameter':<10}{'pooled':>24}" + "".join(f"{n[-22:]:>24}" for n in names)
            lines.append(head)
            for n, p in pooled.parameters.items():
                row = f"  {n:<10}{_cell(p):>24}"
                for name in names:
                    r = self.records[name].get(check)
                    row += f"{_cell(r.parameters[n]) if r else '—':>24}"
                lines.append(row)
            for c, f in pooled.fit.items():
                fit = "—" if f["fit_percent"] is None else f"{f['fit_percent']:.2f} %"
                lines.append(
                    f"  {c:<10}fit {fit}, residual σ {f['residual_std']:.3g} (noise σ {f['noise_std']:.3g})"
                )
        for name, why in self.unchecked.items():
            for check, reason in why.items():
                lines.append(f"{name}: {check} not checked: {reason}")
        return "\n".join(lines) + "\n"


def _cell(p: Parameter) -> str:
    if not p.estimated:
        return "0 (held)"
    return f"{p.value:.4g} ± {p.std:.2g}"


def _turned(v: np.ndarray, ay, az) -> np.ndarray:
    """The velocities `v` (..., 3) in a sensor's axes turned into the body's: Rz(az) Ry(ay) v,
    a sensor misaligned by ay about y and az about z (its reading Mᵀ v, as a scenario's
    `misalignment`)."""
    cy, sy, cz, sz = np.cos(ay), np.sin(ay), np.cos(az), np.sin(az)
    u1, w1 = cy * v[..., 0] + sy * v[..., 2], -sy * v[..., 0] + cy * v[..., 2]
    return np.stack([cz * u1 - sz * v[..., 1], sz * u1 + cz * v[..., 1], w1], axis=-1)


def _samples(e: Experiment, c: str) -> tuple[np.ndarray, np.ndarray]:
    """Channel `c`'s samples present in `e`: their times and values."""
    y = e.column(c)
    present = ~np.isnan(y)
    return e.t[present], y[present]


class _Record:
    """One record, or one stretch of it between two unbridged gaps, ready for a check: the rows
    where every output is present (`t`, the filter's steps between them), the fine grid
    (those rows and the midpoints between them), the cubic splines through each driving and
    used channel's samples present, the outputs, and the noise of the channels (`noise`:
    channel → σ).

    The noise of a driving or used channel is integrated as a random walk: each step h of the
    filter adds h H σ² of it, H the interval between the channel's samples around the step
    (h² σ² where every row is a sample; a spline through samples H apart carries each sample's
    error over H, (H σ)² in all)."""

    def __init__(
        self,
        e: Experiment,
        check: Check,
        noise: Mapping[str, float],
        window: tuple[float, float] | None = None,
        name: str | None = None,
        every_row: bool = False,
    ):
        self.name = name or e.name
        a, b = window or (e.t[0], e.t[-1])
        y = np.column_stack([e.column(c) for c in check.outputs])
        rows = (e.t >= a) & (e.t <= b) & (every_row | ~np.isnan(y).any(axis=1))
        self.window = (float(a), float(b))
        self.t = np.asarray(e.t[rows], dtype=float)
        self.h = np.diff(self.t)
        fine = np.empty(2 * len(self.t) - 1)
        fine[0::2], fine[1::2] = self.t, self.t[:-1] + self.h / 2
        self.fine = fine
        self.check = check
        self.splines, interval, self.signal = {}, {}, {}
        for c in check.drives + check.uses:
            ts, ys = _samples(e, c)
            # the samples within the window and the nearest one beyond each end
            lo, hi = max(np.searchsorted(ts, a, "right") - 1, 0), np.searchsorted(ts, b, "left") + 1
            ts, ys = ts[lo:hi], ys[lo:hi]
            self.splines[c] = CubicSpline(ts, ys)
            at = np.clip(np.searchsorted(ts, fine[1::2]), 1, len(ts) - 1)
            interval[c] = ts[at] - ts[at - 1]  # H: the interval between samples around each step
        self.used = {c: self.splines[c](fine) for c in check.uses}
        self.y = y[rows]
        self.R = np.array([noise[c] ** 2 for c in check.outputs])
        self.noise = dict(noise)
        self.interval = interval
        # the drives' process noise per step over h²: σ² H / h (h H σ² in all)
        self.Sw = np.column_stack([self.noise[c] ** 2 * interval[c] / self.h for c in check.drives])
        for c in check.needs:  # channel → the standard deviation of its signal over its noise's
            ts, ys = _samples(e, c)
            ys = ys[(ts >= a) & (ts <= b)]
            var = float(np.var(ys)) if len(ys) else 0.0
            self.signal[c] = math.sqrt(max(var - noise[c] ** 2, 0.0)) / noise[c]

    def _depth_noise(self, x: np.ndarray, w: np.ndarray, phi: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """The depth filter's process noise per step (B, N − 1): the variance of ż from the noise
        of the velocities (scaled as they are corrected) and of the attitude (times the
        corrected velocities), at each step's start, integrated as a random walk (h H var)."""
        n = len(self.check.drives)
        k = x[:, len(self.check.initial) + n : len(self.check.initial) + 2 * n]
        u, v, w = (w[:, 0:-1:2, i] for i in range(3))
        phi, theta = phi[:, 0:-1:2], theta[:, 0:-1:2]
        s, c, st, ct = np.sin(phi), np.cos(phi), np.sin(theta), np.cos(theta)
        su, sv, sw = (self.noise[ch] / (1 + k[:, [i]]) for i, ch in enumerate(self.check.drives))
        H = self.interval
        var = (
            (su * st) ** 2 * H["u"]
            + (sv * ct * s) ** 2 * H["v"]
            + (sw * ct * c) ** 2 * H["w"]
            + (self.noise["theta"] * (u * ct + (v * s + w * c) * st)) ** 2 * H["theta"]
            + (self.noise["phi"] * ct * (v * c - w * s)) ** 2 * H["phi"]
        )
        return self.h * var

    def drives(self, tau: np.ndarray) -> np.ndarray:
        """The driving channels at `fine + tau` (B,) complex, (B, 2N − 1, channels): the spline
        at the real shift plus i Im(τ) times its slope (the complex step's first order, exact for
        the derivative); beyond the window's ends the end values are held."""
        a, b = self.window
        s = self.fine + tau[0].real
        inside = (s >= a) & (s <= b)
        s = np.clip(s, a, b)
        out = np.empty((len(tau), len(s), len(self.check.drives)), dtype=complex)
        for j, c in enumerate(self.check.drives):
            spline = self.splines[c]
            slope = np.where(inside, spline(s, 1), 0.0)
            out[:, :, j] = spline(s)[None, :] + 1j * tau.imag[:, None] * slope[None, :]
        return out

    def _corrected(self, x: np.ndarray):
        """The initial states (B, initial), the corrected driving channels (B, 2N − 1, channels),
        the used channels less their offsets (channel → (B, 2N − 1)) and the driving sensor's
        lever arm (B, 3, or (B, 0) without one) of the parameter rows `x` (B, initial + sensor),
        complex."""
        check, n = self.check, len(self.check.drives)
        x0 = x[:, : len(check.initial)]
        sensor = x[:, len(check.initial) :]
        b, k, tau = sensor[:, :n], sensor[:, n : 2 * n], sensor[:, 2 * n]
        offsets = sensor[:, 2 * n + 1 : 2 * n + 1 + len(check.uses)]
        at = 2 * n + 1 + len(check.uses)
        turns, arm = sensor[:, at : at + len(check.axes)], sensor[:, at + len(check.axes) :]
        used = {c: self.used[c][None, :] - offsets[:, [i]] for i, c in enumerate(check.uses)}
        w = (self.drives(tau) - b[:, None, :]) / (1 + k[:, None, :])
        if check.axes:
            w = _turned(w, turns[:, 0, None], turns[:, 1, None])
        return np.ascontiguousarray(x0), w, used, arm

    def _depth_steps(self, w: np.ndarray, phi: np.ndarray, theta: np.ndarray, arm: np.ndarray) -> np.ndarray:
        """The depth's change over each step (B, N − 1): Simpson's rule on ż of the log's point,
        less the change of that point's depth below the CG's (the log at r reads v + ω × r, whose
        ż is the CG's plus d(C r)₃/dt: its integral is (C r)₃ at the step's ends,
        (C r)₃ = −r_x sin θ + (r_y sin φ + r_z cos φ) cos θ)."""
        zdot = -w[:, :, 0] * np.sin(theta) + (w[:, :, 1] * np.sin(phi) + w[:, :, 2] * np.cos(phi)) * np.cos(
            theta
        )
        steps = self.h / 6 * (zdot[:, 0:-1:2] + 4 * zdot[:, 1::2] + zdot[:, 2::2])
        if arm.shape[1]:
            r = arm[:, :, None]
            s, c = np.sin(phi[:, 0::2]), np.cos(phi[:, 0::2])
            point = -r[:, 0] * np.sin(theta[:, 0::2]) + (r[:, 1] * s + r[:, 2] * c) * np.cos(theta[:, 0::2])
            steps = steps - np.diff(point, axis=1)
        return steps

    def outputs(self, x: np.ndarray) -> np.ndarray:
        """The outputs reconstructed open loop (B, N, outputs) at the parameter rows `x`."""
        x0, w, used, arm = self._corrected(x)
        if self.check is ATTITUDE:
            out = np.empty((len(x), len(self.t), 3), dtype=complex)
            attitudes(self.h, np.ascontiguousarray(w), x0, out)
            return out
        steps = self._depth_steps(w, used["phi"], used["theta"], arm)
        return (np.concatenate([np.zeros((len(x), 1)), np.cumsum(steps, axis=1)], axis=1) + x0)[:, :, None]

    def innovations(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """The filter's whitened innovations (B, N, outputs) at the parameter rows `x`, and the
        log-ratios ln(S / R) of their variances to the noise's where these depend on the
        parameters (the depth check; None for the attitude, whose gain is held)."""
        x0, w, used, arm = self._corrected(x)
        if self.check is ATTITUDE:
            out = np.empty((len(x), len(self.t), 3), dtype=complex)
            attitude_filter(self.h, np.ascontiguousarray(w), x0, self.y, self.R, self.Sw, out)
            return out, None
        out, logs = (np.empty((len(x), len(self.t)), dtype=complex) for _ in range(2))
        phi, theta = used["phi"], used["theta"]
        steps, q = self._depth_steps(w, phi, theta, arm), self._depth_noise(x, w, phi, theta)
        depth_filter(
            np.ascontiguousarray(steps),
            np.ascontiguousarray(q),
            x0[:, 0].copy(),
            self.y[:, 0],
            self.R[0],
            out,
            logs,
        )
        return out[:, :, None], logs[:, :, None]

    def start(self) -> np.ndarray:
        """The initial states: the mean of each output's first five samples."""
        return np.array([np.mean(y[~np.isnan(y)][:5]) for y in self.y.T])

    def evaluate(self, x: np.ndarray, jac: bool):
        """At `x` (real): the whitened innovations e and the log-ratios g (N, outputs; g None
        for the attitude) and, with `jac`, their derivatives (N, outputs, parameters) by the
        complex step (else None)."""
        rows = x[None, :] + 1j * STEP * np.eye(len(x)) if jac else x[None, :].astype(complex)
        e, g = self.innovations(rows)

        def split(a):
            return a[0].real, (np.moveaxis(a.imag / STEP, 0, -1) if jac else None)

        return split(e) + (split(g) if g is not None else (None, None))


def reconstruct(
    e: Experiment, check: Check, values: Mapping[str, float] | None = None
) -> dict[str, np.ndarray]:
    """The outputs of `check` reconstructed from record `e`: output name → (N,) array, at the
    parameters `values` (initial states and sensor parameters by name; an initial state left
    out starts at the mean of the output's first five samples, a sensor parameter at 0); the
    driving and used channels are the splines through their samples present."""
    _need(e, check)
    record = _Record(e, check, {c: 1.0 for c in e.measured}, every_row=True)
    values = dict(values or {})
    unknown = set(values) - set(check.initial) - set(check.sensor)
    if unknown:
        raise InputError(
            f"{check.name} check: {', '.join(sorted(unknown))}: not its parameters; expected "
            f"{', '.join(check.initial + check.sensor)}"
        )
    x0 = record.start()
    x = np.array(
        [values.get(n, x0[i]) for i, n in enumerate(check.initial)]
        + [values.get(n, 0.0) for n in check.sensor]
    )
    y = record.outputs(x[None, :].astype(complex))[0].real
    return {c: y[:, i] for i, c in enumerate(check.outputs)}


def _need(e: Experiment, check: Check) -> None:
    missing = _missing(e, check)
    if missing:
        raise InputError(
            f"{e.source or e.name}: the {check.name} check needs {', '.join(check.needs)}; "
            f"missing {', '.join(missing)}"
        )


class _Fit:
    """The filter-error problem of one check on records: the free sensor parameters (shared),
    then each record's initial states; the other sensor parameters held at 0."""

    def __init__(self, records: Sequence[_Record], check: Check):
        self.records, self.check = records, check
        self.ni = len(check.initial)

    def local(self, x: np.ndarray, free: Sequence[str], r: int) -> np.ndarray:
        """Record r's parameter row (initial + sensor) from the free vector `x`."""
        sensor = dict(zip(free, x[: len(free)]))
        start = len(free) + r * self.ni
        return np.concatenate([x[start : start + self.ni], [sensor.get(n, 0.0) for n in self.check.sensor]])

    def _parts(self, x, free, jac: bool):
        """Per record (e, de, g, dg) as `_Record.evaluate`, the derivatives over the free vector."""
        cols = [self.check.sensor.index(n) + self.ni for n in free]
        for r, rec in enumerate(self.records):
            parts = rec.evaluate(self.local(x, free, r), jac)
            if jac:
                at = slice(len(free) + r * self.ni, len(free) + (r + 1) * self.ni)
                for i in (1, 3):
                    d = parts[i]
                    if d is not None:
                        J = np.zeros(d.shape[:2] + (len(x),))
                        J[:, :, : len(free)], J[:, :, at] = d[:, :, cols], d[:, :, : self.ni]
                        parts = parts[:i] + (J,) + parts[i + 1 :]
            yield parts

    def residuals(self, x, free, jac: bool):
        """The residuals whose sum of squares is the negative log-likelihood (up to a constant):
        the whitened innovations, and where their variance S depends on the parameters
        √(1 + ln(S / R)), stacked over records; and their Jacobian."""
        res, rows = [], []
        for e, de, g, dg in self._parts(x, free, jac):
            res.append(e.ravel())
            rows += [de.reshape(-1, len(x))] if jac else []
            if g is not None:
                root = np.sqrt(1 + g)
                res.append(root.ravel())
                rows += [(dg / (2 * root[:, :, None])).reshape(-1, len(x))] if jac else []
        return np.concatenate(res), (np.concatenate(rows) if jac else None)

    def fisher(self, x, free) -> np.ndarray:
        """The Fisher information of the innovations ν ~ N(0, S): Σ ∂νᵀ S⁻¹ ∂ν + ½ (∂ ln S)ᵀ ∂ ln S,
        with S⁻¹ᐟ² ∂ν = ∂e + e ∂g / 2 (e = ν / √S, g = ln S / R)."""
        M = np.zeros((len(x), len(x)))
        for e, de, g, dg in self._parts(x, free, jac=True):
            if g is not None:
                de = de + e[:, :, None] * dg / 2
                M += 0.5 * np.einsum("nci,ncj->ij", dg, dg)
            M += np.einsum("nci,ncj->ij", de, de)
        return M

    def start(self, free) -> np.ndarray:
        return np.concatenate([np.zeros(len(free))] + [rec.start() for rec in self.records])

    def bounds(self, free):
        limit = [_limit(n) or np.inf for n in free]
        hi = np.array(limit + [np.inf] * self.ni * len(self.records))
        return -hi, hi

    def solve(self, x, free):
        """Gauss-Newton (trust region) from `x`; (x, evaluations)."""
        cache = {}

        def both(z):
            key = z.tobytes()
            if key not in cache:
                cache.clear()
                cache[key] = self.residuals(z, free, jac=True)
            return cache[key]

        lo, hi = self.bounds(free)
        sol = least_squares(
            lambda z: both(z)[0],
            np.clip(x, 0.999 * lo, 0.999 * hi),
            jac=lambda z: both(z)[1],
            bounds=(lo, hi),
            x_scale="jac",
            method="trf",
        )
        return sol.x, int(sol.nfev)

    def covariance(self, x, free) -> np.ndarray:
        """The inverse Fisher information (pseudo-inverse): the Cramér-Rao bounds."""
        return np.linalg.pinv(self.fisher(x, free), rcond=1e-15, hermitian=True)


def _singular(M: np.ndarray, names: Sequence[str]) -> list[str]:
    """The parameters (of the first len(names) rows) to hold so that the Fisher information M is
    regular, greedily: the one that weighs most in the least determined direction of the
    information scaled to unit diagonal, while that direction is singular."""
    d = np.sqrt(np.diag(M))
    held = [n for i, n in enumerate(names) if d[i] == 0]
    keep = [i for i in range(len(M)) if i >= len(names) or names[i] not in held]
    while True:
        Ms = M[np.ix_(keep, keep)] / np.outer(d[keep], d[keep])
        lam, V = np.linalg.eigh(Ms)
        if lam[0] > SINGULAR * lam[-1]:
            return held
        sensor = [j for j, i in enumerate(keep) if i < len(names)]
        if not sensor:
            return held
        j = max(sensor, key=lambda j: abs(V[j, 0]))
        held.append(names[keep[j]])
        del keep[j]


def _inseparable(M: np.ndarray, names: Sequence[str], held: Mapping[str, str]) -> dict[str, str]:
    """The sensor parameters (of the first len(names) rows of the Fisher information M, those of
    `held` aside) correlated with an attitude offset beyond `MAX_CORRELATION`, with the reason,
    held one at a time, the most correlated first, the correlations computed again without it:
    the data tell them from the offset by little more than their noise (a log's w bias makes
    the sink rate −u sin θ of a pitch offset wherever u is near constant; its misalignment about
    y turns its u into the same); the offset, the commoner error, is kept."""
    out: dict[str, str] = {}
    while True:
        keep = [i for i in range(len(M)) if i >= len(names) or (names[i] not in held and names[i] not in out)]
        d = np.sqrt(np.diag(M)[keep])
        P = np.linalg.pinv(M[np.ix_(keep, keep)] / np.outer(d, d), hermitian=True)
        s = np.sqrt(np.abs(np.diag(P)))
        index = {names[i]: j for j, i in enumerate(keep) if i < len(names)}
        pairs = [
            (abs(P[j, index[o]]) / (s[j] * s[index[o]]), n, o)
            for o in OFFSETS
            if o in index
            for n, j in index.items()
            if n not in OFFSETS
        ]
        rho, n, o = max(pairs, default=(0.0, "", ""))
        if rho <= MAX_CORRELATION:
            return out
        out[n] = (
            f"not separable from {o}: correlated {rho:.4f} with it in these data (the offset, the "
            "commoner error, is kept)"
        )


def _conditional(x: np.ndarray, P: np.ndarray, i) -> np.ndarray:
    """The estimate `x` (covariance P) with parameter(s) i held at 0: the others moved as the
    cost's quadratic model says (the Gaussian conditioned on x[i] = 0)."""
    i = np.atleast_1d(i)
    if not len(i):
        return x
    return x - P[:, i] @ np.linalg.solve(P[np.ix_(i, i)], x[i])


def _rank(name: str) -> int:
    """Where `name` comes in the order parameters are held (`HELD_FIRST`, the offsets last)."""
    if name in OFFSETS:
        return len(HELD_FIRST)
    return next(i for i, prefix in enumerate(HELD_FIRST) if name.startswith(prefix))


def _insignificant(x, P, free, stds, reasons) -> list[str]:
    """The parameters of `free` held at 0 one at a time (`HELD_FIRST` order, then the least
    significant) while one is within SIGNIFICANCE σ of 0, the others updated for each held;
    their σ and reasons recorded in `stds` and `reasons`."""
    held = []
    while True:
        z = {
            i: abs(x[i]) / math.sqrt(P[i, i]) for i in range(len(free)) if free[i] not in held and P[i, i] > 0
        }
        z = {i: v for i, v in z.items() if v < SIGNIFICANCE}  # P[i, i] ≤ 0: determined by those held
        if not z:
            return held
        i = min(z, key=lambda i: (_rank(free[i]), z[i]))
        stds[free[i]] = math.sqrt(P[i, i])
        reasons[free[i]] = (
            f"not significant: {x[i]:.3g} ± {stds[free[i]]:.2g} is within {SIGNIFICANCE:g} σ of 0"
        )
        held.append(free[i])
        x = _conditional(x, P, i)
        P = P - np.outer(P[:, i], P[i, :]) / P[i, i]


def _noise_regressors(records: Sequence[_Record], names: Sequence[str]) -> dict[str, str]:
    """The parameters of `names` whose regressor is mostly noise in every record (`REGRESSORS`),
    with the reason."""
    out = {}
    for n in names:
        alternatives = REGRESSORS.get(n, ())
        best = max(
            (min(rec.signal[c] for c in channels) for rec in records for channels in alternatives),
            default=math.inf,
        )
        if best < MIN_SIGNAL:
            what = " or ".join("·".join(channels) for channels in alternatives)
            out[n] = (
                f"not identifiable: its regressor ({what}) is mostly measurement noise here "
                f"(signal {best:.2g} × the noise, below {MIN_SIGNAL:g})"
            )
    return out


def _reconstruction(check: Check, records: Sequence[_Record]) -> Reconstruction:
    """Fit `check` on `records`: the screen, the fit, the bounds, the reconstruction's fit."""
    fit = _Fit(records, check)
    names = list(check.sensor)
    reasons = _noise_regressors(records, names)
    names_left = [n for n in names if n not in reasons]
    M = fit.fisher(fit.start(names_left), names_left)
    reasons |= {
        n: "not identifiable: the Fisher information of these data is singular along it"
        for n in _singular(M, names_left)
    }
    reasons |= _inseparable(M, names_left, reasons)
    stds = {n: math.inf for n in reasons}
    free = [n for n in names if n not in reasons]
    x, iterations = fit.solve(fit.start(free), free)
    P = fit.covariance(x, free)
    while True:  # screened, fitted again, until the fit leaves none within SIGNIFICANCE σ of 0
        held = _insignificant(x, P, free, stds, reasons)
        if not held:
            break
        keep = [i for i, n in enumerate(free) if n not in held] + list(range(len(free), len(x)))
        free = [n for n in free if n not in held]
        x, more = fit.solve(_conditional(x, P, [i for i in range(len(x)) if i not in keep])[keep], free)
        iterations += more
        P = fit.covariance(x, free)
    std = np.sqrt(np.diag(P))
    parameters = {}
    for n in names:
        if n in free:
            parameters[n] = Parameter(value=float(x[free.index(n)]), std=float(std[free.index(n)]))
        else:
            parameters[n] = Parameter(value=0.0, std=stds[n], estimated=False, reason=reasons[n])
    initial, y, yhat = {}, [], []
    for r, rec in enumerate(records):
        at = len(free) + r * fit.ni
        initial[rec.name] = {
            n: Parameter(value=float(x[at + j]), std=float(std[at + j])) for j, n in enumerate(check.initial)
        }
        y.append(rec.y)
        yhat.append(rec.outputs(fit.local(x, free, r)[None, :].astype(complex))[0].real)
    y, yhat = np.concatenate(y), np.concatenate(yhat)
    innovations = np.concatenate([e for e, *_ in fit._parts(x, free, jac=False)])
    quality = {}
    for j, c in enumerate(check.outputs):
        error = np.linalg.norm(y[:, j] - yhat[:, j])
        quality[c] = {
            "noise_std": float(math.sqrt(records[0].R[j])),
            "residual_std": float(error / math.sqrt(len(y))),
            "fit_percent": None if math.isnan(fit := fit_percent(y[:, j], yhat[:, j])) else fit,
            "innovation_rms": float(np.sqrt(np.mean(innovations[:, j] ** 2))),
        }
    return Reconstruction(
        check=check.name,
        records=tuple(rec.name for rec in records),
        parameters=parameters,
        initial=initial,
        fit=quality,
        iterations=iterations,
    )


def _fitted(check: Check, records: Sequence[_Record]) -> Reconstruction:
    """`_reconstruction`, a fit the data drive to non-finite values an `InputError` naming them."""
    with np.errstate(all="ignore"):
        try:
            done = _reconstruction(check, records)
            finite = all(math.isfinite(p.value) for p in done.parameters.values()) and all(
                math.isfinite(p.value) for v in done.initial.values() for p in v.values()
            )
        except (ValueError, np.linalg.LinAlgError) as exc:
            finite, why = False, f" ({exc})"
        else:
            why = ""
    if not finite:
        raise InputError(
            f"{', '.join(r.name for r in records)}: the {check.name} check reached no finite "
            f"estimate{why}; expected channels in SI units (rad, rad/s, m/s, m)"
        )
    return done


# What each missing channel prevents, by check.
WHY_NEEDED = {
    "attitude": "the attitude is integrated from the rate gyros and compared with the measured attitude",
    "depth": "the depth is integrated from the log's velocities turned by the measured attitude",
}


def _missing(e: Experiment, check: Check) -> list[str]:
    """The channels `check` needs that `e` does not measure, or of which it has under 2 samples."""
    return [c for c in check.needs if c not in e.measured or np.sum(~np.isnan(e.column(c))) < 2]


def _stretches(e: Experiment, check: Check) -> tuple[list[tuple[float, float]], list[str]]:
    """The stretches of `e` that `check` can check: where every driving and used channel has
    samples on both sides, split at each gap of one longer than `MAX_GAP` times its median
    interval, and holding at least `MIN_ROWS` rows with every output; and the parts left out,
    each with its reason."""
    rows = ~np.isnan(np.column_stack([e.column(c) for c in check.outputs])).any(axis=1)
    out_t = e.t[rows]
    if not len(out_t):
        return [], [f"no row has every one of {', '.join(check.outputs)}"]
    gaps: dict[tuple[float, float], list[str]] = {}  # (start, end) of a gap not bridged → channels
    limits = {}
    a, b = -math.inf, math.inf
    for c in check.drives + check.uses:
        ts, _ = _samples(e, c)
        a, b = max(a, ts[0]), min(b, ts[-1])
        d = np.diff(ts)
        limits[c] = MAX_GAP * float(np.median(d))
        for i in np.flatnonzero(d > limits[c]):
            gaps.setdefault((float(ts[i]), float(ts[i + 1])), []).append(c)
    why = []
    channels = ", ".join(check.drives + check.uses)
    if out_t[0] < a:
        why.append(f"before {a:.4g} s, not every one of {channels} has a sample")
    for (g0, g1), cs in sorted(gaps.items()):
        limit = " or ".join(f"{v:.3g} s" for v in sorted({limits[c] for c in cs}))
        why.append(
            f"over {g0:.4g}–{g1:.4g} s, {', '.join(cs)} {'has' if len(cs) == 1 else 'have'} no sample "
            f"for {g1 - g0:.3g} s (a gap over {MAX_GAP:g} times the channel's median interval, {limit}, "
            "is not bridged)"
        )
    if out_t[-1] > b:
        why.append(f"after {b:.4g} s, not every one of {channels} has a sample")
    merged: list[list[float]] = []  # the union of what is not checked, in time order
    for g0, g1 in sorted(list(gaps) + [(-math.inf, a), (b, math.inf)]):
        if merged and g0 <= merged[-1][1]:
            merged[-1][1] = max(merged[-1][1], g1)
        else:
            merged.append([g0, g1])
    stretches = []
    for (_, s0), (s1, _) in zip(merged[:-1], merged[1:]):
        n = int(np.sum((out_t >= s0) & (out_t <= s1)))
        if n == 0:
            continue
        if n < MIN_ROWS:
            why.append(
                f"over {s0:.4g}–{s1:.4g} s, between gaps, only {n} rows of the outputs (under {MIN_ROWS})"
            )
        else:
            stretches.append((float(s0), float(s1)))
    return stretches, why


def compatibility(experiments: Sequence[Experiment]) -> Compatibility:
    """The data-compatibility check of `experiments`: each record alone (its channels' noise read
    off it) and all pooled (the noise read off all), each check on the stretches of the records
    that measure its channels (`_stretches`); `InputError` when none has any."""
    unchecked: dict[str, dict[str, str]] = {e.name: {} for e in experiments}
    ready: dict[str, list[tuple[Experiment, list[tuple[float, float]]]]] = {}
    for check in CHECKS:
        for e in experiments:
            missing = _missing(e, check)
            steep = (
                float(np.nanmax(np.abs(e.column("theta"))))
                if "theta" in e.measured and not np.isnan(e.column("theta")).all()
                else 0.0
            )
            if missing:
                unchecked[e.name][check.name] = (
                    f"needs {', '.join(check.needs)} ({WHY_NEEDED[check.name]}); missing {', '.join(missing)}"
                )
                continue
            if check is ATTITUDE and steep > MAX_PITCH:
                unchecked[e.name][check.name] = (
                    f"theta reaches {steep:.4g} rad, beyond ±{MAX_PITCH:g}: the Euler angles' "
                    "kinematics are singular at ±π/2 (attitude in radians expected)"
                )
                continue
            stretches, why = _stretches(e, check)
            if why:
                unchecked[e.name][check.name] = "; ".join(why)
            if stretches:
                ready.setdefault(check.name, []).append((e, stretches))
    if not ready:
        why = "; ".join(
            f"{name}: {'; '.join(f'{c} check {w}' for c, w in v.items())}" for name, v in unchecked.items()
        )
        raise InputError(f"nothing to check: {why}")
    noise = {e.name: noise_from_data([e]) for e in experiments}
    records: dict[str, dict[str, Reconstruction]] = {e.name: {} for e in experiments}
    pooled = {}

    def pieces(check, e, stretches, noise):
        whole = len(stretches) == 1 and not unchecked[e.name].get(check.name)
        return [
            _Record(e, check, noise, (a, b), e.name if whole else f"{e.name} {a:.4g}–{b:.4g} s")
            for a, b in stretches
        ]

    for check in CHECKS:
        some = ready.get(check.name, [])
        for e, stretches in some:
            records[e.name][check.name] = _fitted(check, pieces(check, e, stretches, noise[e.name]))
        if len(some) == 1:
            pooled[check.name] = records[some[0][0].name][check.name]
        elif some:
            everyone = noise_from_data([e for e, _ in some])
            pooled[check.name] = _fitted(check, [r for e, s in some for r in pieces(check, e, s, everyone)])
    return Compatibility(records=records, pooled=pooled, unchecked=unchecked)


def _limit(name: str) -> float | None:
    """The largest |value| of a sensor parameter fitted or applied: a delay `MAX_DELAY` s, a
    scale factor `MAX_SCALE`, a misalignment `MAX_MISALIGNMENT` rad, a lever arm `MAX_ARM` m;
    None for a bias or an attitude offset."""
    if name.startswith("tau_"):
        return MAX_DELAY
    if name.startswith("k_"):
        return MAX_SCALE
    if name in MISALIGNMENTS:
        return MAX_MISALIGNMENT
    return MAX_ARM if name in ARMS else None


def check_corrections(values, where: str) -> dict[str, float]:
    """`values` (sensor parameter → number) checked: known names, finite numbers, biases within
    ±`MAX_DATA`, attitude offsets within ±`MAX_OFFSET` rad, scale factors within ±`MAX_SCALE`,
    misalignments within ±`MAX_MISALIGNMENT` rad, lever arms within ±`MAX_ARM` m, delays within
    ±`MAX_DELAY` s (`_limit`)."""
    if not isinstance(values, Mapping):
        raise InputError(f'{where}: expected an object of sensor parameters, e.g. {{"b_r": 0.002}}')
    out = {}
    for n, v in values.items():
        if n not in SENSOR_PARAMETERS:
            raise InputError(
                f"{where}: {str(n)[:40]!r} is not a sensor parameter; expected {', '.join(SENSOR_PARAMETERS)}"
            )
        limit = _limit(n) or (MAX_OFFSET if n in OFFSETS else MAX_DATA)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not abs(v) <= limit:
            raise InputError(f"{where}: {n} = {repr(v)[:40]}; expected a number within ±{limit:g}")
        out[n] = float(v)
    return out


def read_corrections(path: str | Path) -> dict[str, float]:
    """The `corrections` of a check JSON (`testbed check --out`), checked."""
    doc = read_json(path, "a check JSON with corrections {name: value}")
    if not isinstance(doc, Mapping) or "corrections" not in doc:
        raise InputError(f"{path}: no 'corrections'; expected a check JSON (testbed check --out)")
    return check_corrections(doc["corrections"], f"{path}: corrections")


def corrected(experiments: Sequence[Experiment], corrections: Mapping[str, float]) -> list[Experiment]:
    """The experiments with each measured channel corrected by its sensor's parameters: a rate or
    velocity `(c(t + τ) − b_c) / (1 + k_c)`, c(t + τ) from the cubic spline through the
    channel's samples present (the end values held beyond them; a missing sample stays
    missing), an attitude channel less its offset `c − b_c`, the log's velocities turned back by
    its misalignment and moved from its point to the CG, v − ω × r (the rates measured: an
    `InputError` naming the record otherwise); parameters not given are 0, channels not measured
    are skipped."""
    corrections = check_corrections(corrections, "corrections")
    out = []
    for e in experiments:
        y = e.y.copy()
        for check in CHECKS:
            tau = corrections.get(check.delay, 0.0)
            for c in check.drives:
                if c not in e.measured:
                    continue
                j = e.measured.index(c)
                b, k = corrections.get(f"b_{c}", 0.0), corrections.get(f"k_{c}", 0.0)
                ts, ys = _samples(e, c)
                shifted = y[:, j]
                if tau and len(ts) > 1:
                    shifted = np.where(
                        np.isnan(y[:, j]), np.nan, CubicSpline(ts, ys)(np.clip(e.t + tau, ts[0], ts[-1]))
                    )
                y[:, j] = (shifted - b) / (1 + k)
            for c in check.uses:
                if c in e.measured:
                    y[:, e.measured.index(c)] -= corrections.get(f"b_{c}", 0.0)
            turns = [corrections.get(n, 0.0) for n in check.sensor if n in MISALIGNMENTS]
            if any(turns) and all(c in e.measured for c in check.drives):
                at = [e.measured.index(c) for c in check.drives]
                y[:, at] = _turned(y[:, at], *turns)
            arm = np.array([corrections.get(n, 0.0) for n in check.sensor if n in ARMS])
            if np.any(arm) and all(c in e.measured for c in check.drives):
                # the log's point moved to the CG: v = M y − ω × r, with the measured rates
                if not all(c in e.measured for c in ATTITUDE.drives):
                    named = ", ".join(f"{n} = {corrections[n]:g}" for n in ARMS if corrections.get(n))
                    raise InputError(
                        f"corrections: {named}; record {e.name!r} has no p, q, r to move the log's "
                        "velocities to the CG with (v − ω × r): expected rate gyros, or the log's "
                        "position as the model config's r_dvl_x, r_dvl_y, r_dvl_z (identify reads the "
                        "velocities through it)"
                    )
                at = [e.measured.index(c) for c in check.drives]
                rates = np.column_stack([e.column(c) for c in ATTITUDE.drives])
                y[:, at] = y[:, at] - np.cross(rates, arm)
        out.append(replace(e, y=y))
    return out
