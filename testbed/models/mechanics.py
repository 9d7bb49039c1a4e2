"""The nonlinear model's exact mechanics: Coriolis forces, weight and buoyancy, kinematics.

Body axes at the CG (x forward, y starboard, z down), earth axes north-east-down, ν = (v, ω) =
(u v w p q r) with u the absolute surge speed, Euler angles η = (φ, θ, ψ) and depth z. Each part
is compiled (numba) for one state, writing its value and its exact Jacobian into given arrays,
real or complex alike (complex-step derivatives): the nonlinear model's compiled state
derivative (`nonlinear_kernels`) is made of them. `coriolis` and `kinematics` apply them to
samples stacked along the first axis.

- Kirchhoff forces (`kirchhoff`, `coriolis_state`): for a body of constant inertia M (rigid body
  plus added mass, 6 × 6, symmetric), Kirchhoff's equations give the velocity forces
  −(ω × h_v, ω × h_ω + v × h_v) with the momentum h = M ν. For the rigid body about its CG they
  are Newton-Euler's −(m ω × v, ω × I ω); for the added mass they are the Coriolis and Munk
  terms of potential flow, which MuJoCo's ellipsoid model applies per fluid geom (their sum is
  the same expression for the summed M_A: the form is frame-invariant).
- Restoring (`restoring_state`): weight W at the CG and buoyancy B at the CB r_B, down being
  g = (−sin θ, cos θ sin φ, cos θ cos φ) in body axes: force (W − B) g, moment r_B × (−B g).
- Kinematics (`kinematics_state`): φ̇ = p + (q sin φ + r cos φ) tan θ, θ̇ = q cos φ − r sin φ,
  ψ̇ = (q sin φ + r cos φ)/cos θ, ż = −u sin θ + (v sin φ + w cos φ) cos θ.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["coriolis", "coriolis_state", "kinematics", "kinematics_state", "kirchhoff", "restoring_state"]


@numba.njit(cache=True)
def _cross(a0, a1, a2, b0, b1, b2):
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@numba.njit(cache=True)
def kirchhoff(h, nu, F):
    """F (6,) += −(ω × h_v, ω × h_ω + v × h_v): the velocity forces of the momentum h (6,) at ν."""
    c = _cross(nu[3], nu[4], nu[5], h[0], h[1], h[2])
    d = _cross(nu[3], nu[4], nu[5], h[3], h[4], h[5])
    e = _cross(nu[0], nu[1], nu[2], h[0], h[1], h[2])
    for i in range(3):
        F[i] -= c[i]
        F[3 + i] -= d[i] + e[i]


@numba.njit(cache=True)
def coriolis_state(M, nu, F, J, jacobian):
    """F (6,) += the Kirchhoff velocity forces of inertia M (6 × 6) at ν (6,), and with
    `jacobian` J (6, ≥ 6) += their derivative with respect to ν in its first six columns:
    d(a × b) = a × db − b × da, with dh = M dν."""
    h = np.zeros(6, dtype=F.dtype)
    for i in range(6):
        for j in range(6):
            h[i] += M[i, j] * nu[j]
    kirchhoff(h, nu, F)
    if not jacobian:
        return
    for j in range(6):  # the momentum's part: −(ω × M_v e_j, ω × M_ω e_j + v × M_v e_j)
        c = _cross(nu[3], nu[4], nu[5], M[0, j], M[1, j], M[2, j])
        d = _cross(nu[3], nu[4], nu[5], M[3, j], M[4, j], M[5, j])
        e = _cross(nu[0], nu[1], nu[2], M[0, j], M[1, j], M[2, j])
        for i in range(3):
            J[i, j] -= c[i]
            J[3 + i, j] -= d[i] + e[i]
    for k in range(3):  # the velocity's part: dω × h_v, dω × h_ω, dv × h_v
        a = _cross(1.0 if k == 0 else 0.0, 1.0 if k == 1 else 0.0, 1.0 if k == 2 else 0.0, h[0], h[1], h[2])
        b = _cross(1.0 if k == 0 else 0.0, 1.0 if k == 1 else 0.0, 1.0 if k == 2 else 0.0, h[3], h[4], h[5])
        for i in range(3):
            J[i, 3 + k] -= a[i]
            J[3 + i, 3 + k] -= b[i]
            J[3 + i, k] -= a[i]


@numba.njit(cache=True)
def restoring_state(weight, buoyancy, rB, phi, theta, F, J, jacobian):
    """F (6,) += weight at the CG and buoyancy at `rB` (CB − CG, body axes) at roll `phi` and pitch
    `theta`; with `jacobian` J (6, 2) += their derivative with respect to (φ, θ)."""
    sf, cf, st, ct = np.sin(phi), np.cos(phi), np.sin(theta), np.cos(theta)
    g = (-st, ct * sf, ct * cf)
    m = _cross(rB[0], rB[1], rB[2], g[0], g[1], g[2])
    for i in range(3):
        F[i] += (weight - buoyancy) * g[i]
        F[3 + i] -= buoyancy * m[i]
    if not jacobian:
        return
    for k, dg in enumerate(((0.0 * ct, ct * cf, -ct * sf), (-ct, -st * sf, -st * cf))):  # ∂g/∂φ, ∂g/∂θ
        dm = _cross(rB[0], rB[1], rB[2], dg[0], dg[1], dg[2])
        for i in range(3):
            J[i, k] += (weight - buoyancy) * dg[i]
            J[3 + i, k] -= buoyancy * dm[i]


@numba.njit(cache=True)
def kinematics_state(x, f, J, jacobian):
    """f (4,) = (φ̇, θ̇, ψ̇, ż) at the state x (10,) = (u v w p q r φ θ ψ z); with `jacobian` J
    (4, 10) = its derivative with respect to x."""
    u, v, w, p, q, r, phi, theta = x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7]
    sf, cf, st, ct = np.sin(phi), np.cos(phi), np.sin(theta), np.cos(theta)
    tt, sec = st / ct, 1.0 / ct
    a = q * sf + r * cf  # the body rates' part about the earth's vertical, in the yz plane
    side = v * sf + w * cf
    f[0], f[1], f[2], f[3] = p + a * tt, q * cf - r * sf, a * sec, -u * st + side * ct
    if not jacobian:
        return
    da_phi = q * cf - r * sf
    J[:, :] = 0.0
    J[0, 3] = 1.0
    J[0, 4], J[0, 5] = sf * tt, cf * tt
    J[0, 6] = da_phi * tt
    J[0, 7] = a * sec**2
    J[1, 4], J[1, 5], J[1, 6] = cf, -sf, -a
    J[2, 4], J[2, 5] = sf * sec, cf * sec
    J[2, 6], J[2, 7] = da_phi * sec, a * sec * tt
    J[3, 0], J[3, 1], J[3, 2] = -st, sf * ct, cf * ct
    J[3, 6] = (v * cf - w * sf) * ct
    J[3, 7] = -u * ct - side * st


@numba.njit(cache=True)
def _coriolis(M, nu, F, J):
    for n in range(nu.shape[0]):
        coriolis_state(M, nu[n], F[n], J[n], bool(True))  # bool(): no literal specialisation


@numba.njit(cache=True)
def _kinematics(x, f, J):
    for n in range(x.shape[0]):
        kinematics_state(x[n], f[n], J[n], bool(True))


def _common(*arrays):
    dtype = np.result_type(*arrays, float)
    return [np.ascontiguousarray(a, dtype) for a in arrays]


def coriolis(M, nu):
    """(F (n, 6), ∂F/∂ν (n, 6, 6)): the Kirchhoff velocity forces of inertia M at ν (n, 6)."""
    M, nu = _common(M, np.atleast_2d(nu))
    F, J = np.zeros(nu.shape, nu.dtype), np.zeros(nu.shape[:1] + (6, 6), nu.dtype)
    _coriolis(M, nu, F, J)
    return F, J


def kinematics(x):
    """((φ̇, θ̇, ψ̇, ż) (n, 4), their Jacobian with respect to x (n, 4, 10)) at the states x
    (n, 10) = (u v w p q r φ θ ψ z)."""
    (x,) = _common(np.atleast_2d(x))
    f, J = np.zeros((len(x), 4), x.dtype), np.zeros((len(x), 4, 10), x.dtype)
    _kinematics(x, f, J)
    return f, J
