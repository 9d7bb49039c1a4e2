"""The kinematics of the data-compatibility check, compiled (numba): the attitude integrated
from the body rates (RK4 on the sample grid, the rates at each step's start, middle and end),
its extended Kalman filter, and the depth's Kalman filter. They run in complex arithmetic, so
that `analysis.compatibility` differentiates them by the complex step, one row per parameter.
"""

import numba
import numpy as np

__all__ = ["attitude_filter", "attitudes", "depth_filter"]


@numba.njit(cache=True)
def attitudes(h, rates, x0, out):
    """RK4 of the attitude kinematics on the sample grid: `rates` (B, 2N − 1, 3) at the samples
    and the midpoints between them, `h` the N − 1 steps, `x0` (B, 3); `out` (B, N, 3)."""
    for b in range(rates.shape[0]):
        x = x0[b].copy()
        out[b, 0] = x
        for k in range(h.shape[0]):
            x = _rk4(x, rates[b, 2 * k], rates[b, 2 * k + 1], rates[b, 2 * k + 2], h[k])
            out[b, k + 1] = x


@numba.njit(cache=True)
def _rk4(x, w0, wm, w1, h):
    """One RK4 step of the attitude kinematics, the rates at the step's start, middle and end."""
    k1 = _euler_rates(x, w0)
    k2 = _euler_rates(x + 0.5 * h * k1, wm)
    k3 = _euler_rates(x + 0.5 * h * k2, wm)
    k4 = _euler_rates(x + h * k3, w1)
    return x + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


@numba.njit(cache=True)
def _euler_rates(x, w):
    """(φ̇, θ̇, ψ̇) at attitude `x` and body rates `w` = (p, q, r)."""
    s, c = np.sin(x[0]), np.cos(x[0])
    qr = w[1] * s + w[2] * c
    d = np.empty_like(x)
    d[0] = w[0] + qr * np.tan(x[1])
    d[1] = w[1] * c - w[2] * s
    d[2] = qr / np.cos(x[1])
    return d


@numba.njit(cache=True)
def _linearised(x, w):
    """A = ∂(φ̇, θ̇, ψ̇)/∂(φ, θ, ψ) and G = ∂(φ̇, θ̇, ψ̇)/∂(p, q, r) at attitude `x`, rates `w`."""
    s, c, t, ct = np.sin(x[0]), np.cos(x[0]), np.tan(x[1]), np.cos(x[1])
    qr, dqr = w[1] * s + w[2] * c, w[1] * c - w[2] * s
    A = np.zeros((3, 3))
    A[0, 0], A[0, 1] = dqr * t, qr / ct**2
    A[1, 0] = -qr
    A[2, 0], A[2, 1] = dqr / ct, qr * t / ct
    G = np.array([[1.0, s * t, c * t], [0.0, c, -s], [0.0, s / ct, c / ct]])
    return A, G


@numba.njit(cache=True)
def attitude_filter(h, rates, x0, y, R, Sw, out):
    """The whitened innovations `out` (B, N, 3) of the extended Kalman filter of the attitude:
    the state predicted by `_rk4` from the corrected rates, the measured φ, θ, ψ `y` (N, 3) with
    noise variances `R`; the rates' noise is the process noise, Q = h² G diag(Sw[k]) Gᵀ on step
    k (a random walk of the integrated noise; `Sw` (N − 1, 3) each step's variances). The gain
    and the whitening are computed on the first row's real part and held for every row: the
    complex step then differentiates the innovations at a fixed gain (Maine & Iliff)."""
    B, N = rates.shape[0], y.shape[0]
    K = np.zeros((N, 3, 3))
    W = np.zeros((N, 3, 3))  # the inverse Cholesky factor of the innovations' covariance
    for i in range(3):
        W[0, i, i] = 1.0 / np.sqrt(R[i])
    for b in range(B):
        x = x0[b].copy()
        P = np.zeros((3, 3))  # the initial state is a parameter, known exactly
        for i in range(3):
            out[b, 0, i] = (y[0, i] - x[i]) * W[0, i, i]
        for k in range(N - 1):
            xp = _rk4(x, rates[b, 2 * k], rates[b, 2 * k + 1], rates[b, 2 * k + 2], h[k])
            if b == 0:
                A, G = _linearised(x.real, rates[0, 2 * k].real)
                F = np.eye(3) + h[k] * A
                Gd = h[k] * G
                Pp = F @ P @ F.T + Gd @ np.diag(Sw[k]) @ Gd.T
                S = Pp + np.diag(R)
                W[k + 1] = np.linalg.inv(np.linalg.cholesky(S))
                K[k + 1] = Pp @ np.linalg.inv(S)
                P = (np.eye(3) - K[k + 1]) @ Pp
                P = 0.5 * (P + P.T)
            nu = np.empty(3, dtype=np.complex128)
            for i in range(3):
                nu[i] = y[k + 1, i] - xp[i]
            for i in range(3):
                acc, upd = 0j, 0j
                for j in range(3):
                    acc += W[k + 1, i, j] * nu[j]
                    upd += K[k + 1, i, j] * nu[j]
                out[b, k + 1, i] = acc
                x[i] = xp[i] + upd


@numba.njit(cache=True)
def depth_filter(steps, q, x0, y, R, out, logs):
    """The depth's Kalman filter: z predicted by the integrated ż `steps` (B, N − 1), process
    noise `q` (B, N − 1) per step, measured `y` (N,) with noise variance `R`; its whitened
    innovations ν / √S to `out` and ln(S / R) to `logs` (B, N), in the rows' complex arithmetic
    (gain included: the process noise depends on the parameters through the corrected
    velocities, so the likelihood's ln det S does too)."""
    for b in range(steps.shape[0]):
        x = x0[b]
        P = 0.0j  # the initial depth is a parameter, known exactly
        out[b, 0], logs[b, 0] = (y[0] - x) / np.sqrt(R), 0.0
        for k in range(steps.shape[1]):
            xp = x + steps[b, k]
            Pp = P + q[b, k]
            S = Pp + R
            nu = y[k + 1] - xp
            out[b, k + 1], logs[b, k + 1] = nu / np.sqrt(S), np.log(S / R)
            K = Pp / S
            x = xp + K * nu
            P = (1 - K) * Pp
