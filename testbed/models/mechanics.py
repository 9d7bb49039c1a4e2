"""The nonlinear model's exact mechanics: Coriolis forces, weight and buoyancy, kinematics.

Body axes at the CG (x forward, y starboard, z down), earth axes north-east-down, ν = (v, ω) =
(u v w p q r) with u the absolute surge speed, Euler angles η = (φ, θ, ψ) and depth z. Each
function takes samples stacked along the first axis, and complex arrays (complex-step
derivatives), and returns its value with its exact Jacobian.

- `coriolis`: for a body of constant inertia M (rigid body plus added mass, 6 × 6, symmetric),
  Kirchhoff's equations give the velocity forces −(ω × h_v, ω × h_ω + v × h_v) with the
  momentum h = M ν. For the rigid body about its CG they are Newton-Euler's −(m ω × v, ω × I ω);
  for the added mass they are the Coriolis and Munk terms of potential flow, which MuJoCo's
  ellipsoid model applies per fluid geom (their sum is the same expression for the summed M_A:
  the form is frame-invariant).
- `restoring`: weight W at the CG and buoyancy B at the CB r_B, down being
  g = (−sin θ, cos θ sin φ, cos θ cos φ) in body axes: force (W − B) g, moment r_B × (−B g).
- `kinematics`: φ̇ = p + (q sin φ + r cos φ) tan θ, θ̇ = q cos φ − r sin φ,
  ψ̇ = (q sin φ + r cos φ)/cos θ, ż = −u sin θ + (v sin φ + w cos φ) cos θ.
"""

from __future__ import annotations

import numpy as np

__all__ = ["coriolis", "cross", "kinematics", "kirchhoff", "restoring", "skew"]


def cross(a, b):
    """a × b over the last axis, for real or complex arrays."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def skew(a):
    """[a]× (…, 3, 3) with [a]× b = a × b."""
    z = np.zeros_like(a[..., 0])
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    return np.stack(
        [np.stack([z, -a2, a1], -1), np.stack([a2, z, -a0], -1), np.stack([-a1, a0, z], -1)], axis=-2
    )


def kirchhoff(h, nu):
    """−(ω × h_v, ω × h_ω + v × h_v) (…, 6): the velocity forces of the momentum h = M ν (…, 6)
    at ν (…, 6), stacked alike (or broadcast)."""
    v, w, hv, hw = nu[..., :3], nu[..., 3:], h[..., :3], h[..., 3:]
    return -np.concatenate([cross(w, hv), cross(w, hw) + cross(v, hv)], axis=-1)


def coriolis(M: np.ndarray, nu):
    """(F (n, 6), ∂F/∂ν (n, 6, 6)): the Kirchhoff velocity forces of inertia M at ν (n, 6)."""
    h = nu @ M.T
    v, w, hv, hw = nu[:, :3], nu[:, 3:], h[:, :3], h[:, 3:]
    F = kirchhoff(h, nu)
    # d(a × b) = [a]× db − [b]× da, with dh = M dν
    Sw, Sv, Shv, Shw = skew(w), skew(v), skew(hv), skew(hw)
    J = np.zeros(nu.shape[:1] + (6, 6), dtype=F.dtype)
    J[:, :3] = -(Sw @ M[:3])
    J[:, :3, 3:] += Shv
    J[:, 3:] = -(Sw @ M[3:] + Sv @ M[:3])
    J[:, 3:, 3:] += Shw
    J[:, 3:, :3] += Shv
    return F, J


def restoring(weight: float, buoyancy: float, centre, phi, theta):
    """(F (n, 6), ∂F/∂(φ, θ) (n, 6, 2)): weight at the CG, buoyancy at `centre` (CB − CG, body
    axes), at roll `phi` and pitch `theta` (n,)."""
    sf, cf, st, ct = np.sin(phi), np.cos(phi), np.sin(theta), np.cos(theta)
    g = np.stack([-st, ct * sf, ct * cf], axis=1)
    dg = np.stack(
        [
            np.stack([np.zeros_like(phi), ct * cf, -ct * sf], axis=1),  # ∂g/∂φ
            np.stack([-ct, -st * sf, -st * cf], axis=1),  # ∂g/∂θ
        ],
        axis=2,
    )
    rB = np.asarray(centre, float)
    F = np.concatenate([(weight - buoyancy) * g, -buoyancy * cross(rB, g)], axis=1)
    J = np.concatenate([(weight - buoyancy) * dg, -buoyancy * (skew(rB) @ dg)], axis=1)
    return F, J


def kinematics(x):
    """((φ̇, θ̇, ψ̇, ż) (n, 4), their Jacobian with respect to x (n, 4, 10)) at the states x
    (n, 10) = (u v w p q r φ θ ψ z)."""
    u, v, w, p, q, r, phi, theta = (x[:, i] for i in range(8))
    sf, cf, st, ct = np.sin(phi), np.cos(phi), np.sin(theta), np.cos(theta)
    tt, sec = st / ct, 1.0 / ct
    a = q * sf + r * cf  # the body rates' part about the earth's vertical, in the yz plane
    da_phi = q * cf - r * sf
    side = v * sf + w * cf
    f = np.stack([p + a * tt, q * cf - r * sf, a * sec, -u * st + side * ct], axis=1)
    J = np.zeros(x.shape[:1] + (4, 10), dtype=f.dtype)
    one = np.ones_like(u)
    J[:, 0, 3] = one
    J[:, 0, 4], J[:, 0, 5] = sf * tt, cf * tt
    J[:, 0, 6] = da_phi * tt
    J[:, 0, 7] = a * sec**2
    J[:, 1, 4], J[:, 1, 5], J[:, 1, 6] = cf, -sf, -a
    J[:, 2, 4], J[:, 2, 5] = sf * sec, cf * sec
    J[:, 2, 6], J[:, 2, 7] = da_phi * sec, a * sec * tt
    J[:, 3, 0], J[:, 3, 1], J[:, 3, 2] = -st, sf * ct, cf * ct
    J[:, 3, 6] = (v * cf - w * sf) * ct
    J[:, 3, 7] = -u * ct - side * st
    return f, J
