"""One record as a compatibility check reconstructs it (`CheckRecord`): its driving channels
splined, the reconstruction of its outputs with the sensor parameters and their exact
derivatives (complex step), and `reconstruct`, the outputs a record's channels give.
"""

from __future__ import annotations

import math
from typing import Mapping

import numpy as np
from scipy.interpolate import CubicSpline

from testbed.analysis.compatibility_checks import ATTITUDE, COMPLEX_STEP, Check
from testbed.analysis.kinematics import attitude_filter, attitudes, depth_filter
from testbed.data import Experiment
from testbed.errors import InputError

__all__ = [
    "CheckRecord",
    "WHY_NEEDED",
    "channel_samples",
    "check_needs",
    "missing_channels",
    "reconstruct",
    "misaligned",
]


def misaligned(v: np.ndarray, ay, az) -> np.ndarray:
    """The velocities `v` (..., 3) in a sensor's axes misaligned into the body's: Rz(az) Ry(ay) v,
    a sensor misaligned by ay about y and az about z (its reading Mᵀ v, as a scenario's
    `misalignment`)."""
    cy, sy, cz, sz = np.cos(ay), np.sin(ay), np.cos(az), np.sin(az)
    u1, w1 = cy * v[..., 0] + sy * v[..., 2], -sy * v[..., 0] + cy * v[..., 2]
    return np.stack([cz * u1 - sz * v[..., 1], sz * u1 + cz * v[..., 1], w1], axis=-1)


def channel_samples(e: Experiment, c: str) -> tuple[np.ndarray, np.ndarray]:
    """Channel `c`'s samples present in `e`: their times and values."""
    y = e.column(c)
    present = ~np.isnan(y)
    return e.t[present], y[present]


class CheckRecord:
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
            ts, ys = channel_samples(e, c)
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
            ts, ys = channel_samples(e, c)
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
            w = misaligned(w, turns[:, 0, None], turns[:, 1, None])
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
        rows = x[None, :] + 1j * COMPLEX_STEP * np.eye(len(x)) if jac else x[None, :].astype(complex)
        e, g = self.innovations(rows)

        def split(a):
            return a[0].real, (np.moveaxis(a.imag / COMPLEX_STEP, 0, -1) if jac else None)

        return split(e) + (split(g) if g is not None else (None, None))


def reconstruct(
    e: Experiment, check: Check, values: Mapping[str, float] | None = None
) -> dict[str, np.ndarray]:
    """The outputs of `check` reconstructed from record `e`: output name → (N,) array, at the
    parameters `values` (initial states and sensor parameters by name; an initial state left
    out starts at the mean of the output's first five samples, a sensor parameter at 0); the
    driving and used channels are the splines through their samples present."""
    check_needs(e, check)
    record = CheckRecord(e, check, {c: 1.0 for c in e.measured}, every_row=True)
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


def check_needs(e: Experiment, check: Check) -> None:
    missing = missing_channels(e, check)
    if missing:
        raise InputError(
            f"{e.source or e.name}: the {check.name} check needs {', '.join(check.needs)}; "
            f"missing {', '.join(missing)}"
        )


# What each missing channel prevents, by check.
WHY_NEEDED = {
    "attitude": "the attitude is integrated from the rate gyros and compared with the measured attitude",
    "depth": "the depth is integrated from the log's velocities misaligned by the measured attitude",
}


def missing_channels(e: Experiment, check: Check) -> list[str]:
    """The channels `check` needs that `e` does not measure, or of which it has under 2 samples."""
    return [c for c in check.needs if c not in e.measured or np.sum(~np.isnan(e.column(c))) < 2]
