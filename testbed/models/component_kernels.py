"""The components' forces per unit coefficient and their exact derivatives, compiled (numba) one
state and one component at a time, for real and complex arguments (the formulas: `components`).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["wrenches"]


@numba.njit(cache=True)
def _cross(a, b, out):
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]


@numba.njit(cache=True)
def _mm(A, B, transpose=False):
    """A B, or Aᵀ B with `transpose` (A (3, 3), B (3, k)), by loops: BLAS on 3 × 3 costs more
    than the arithmetic."""
    out = np.zeros((3, B.shape[1]), dtype=B.dtype)
    for i in range(3):
        for j in range(B.shape[1]):
            for k in range(3):
                out[i, j] += (A[k, i] if transpose else A[i, k]) * B[k, j]
    return out


@numba.njit(cache=True)
def _mv(A, x, transpose=False):
    """A x, or Aᵀ x with `transpose` (A (3, 3), x (3,))."""
    out = np.zeros(3, dtype=x.dtype)
    for i in range(3):
        for k in range(3):
            out[i] += (A[k, i] if transpose else A[i, k]) * x[k]
    return out


@numba.njit(cache=True)
def _skew(a, out):
    """[a]× into out (3, 3): [a]× b = a × b."""
    out[0, 0], out[0, 1], out[0, 2] = 0.0, -a[2], a[1]
    out[1, 0], out[1, 1], out[1, 2] = a[2], 0.0, -a[0]
    out[2, 0], out[2, 1], out[2, 2] = -a[1], a[0], 0.0


@numba.njit(cache=True)
def _local(geometry, fin, z):
    """The component's local flow and pose at z = (ν, δ): (v, ω) in its axes, Q (body from
    component), p, and their derivatives along its fin's angle (zero off a fin)."""
    a = geometry[22:25]
    h = geometry[19:22]
    Q0 = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            Q0[i, j] = geometry[6 + 3 * i + j]
    d = z[6 + fin] if fin >= 0 else 0.0 * z[0]
    # R(a, δ) = I + sin δ [a]× + (1 − cos δ) [a]×², dR/dδ = cos δ [a]× + sin δ [a]×²
    K = np.empty((3, 3))
    _skew(a, K)
    K2 = _mm(K, K)
    s, c = np.sin(d), np.cos(d)
    R = np.empty((3, 3), dtype=z.dtype)
    dR = np.empty((3, 3), dtype=z.dtype)
    for i in range(3):
        for j in range(3):
            R[i, j] = (1.0 if i == j else 0.0) + s * K[i, j] + (1.0 - c) * K2[i, j]
            dR[i, j] = c * K[i, j] + s * K2[i, j]
    Q = np.zeros((3, 3), dtype=z.dtype)
    dQ = np.zeros((3, 3), dtype=z.dtype)
    p = np.zeros(3, dtype=z.dtype)
    dp = np.zeros(3, dtype=z.dtype)
    for i in range(3):
        p[i] = h[i]
        for j in range(3):
            p[i] += R[i, j] * (geometry[3 + j] - h[j])
            dp[i] += dR[i, j] * (geometry[3 + j] - h[j])
            for k in range(3):
                Q[i, j] += R[i, k] * Q0[k, j]
                dQ[i, j] += dR[i, k] * Q0[k, j]
    if fin < 0:
        dQ[:, :] = 0.0
        dp[:] = 0.0
    return Q, p, dQ, dp


@numba.njit(cache=True)
def _kinds(r, kappa, rho, added, v, w, f, J, used):
    """Each `used` kind's wrench (f (6, 6): force, torque) in the component's axes at its local
    (v, ω), per unit coefficient, and J (6, 6, 6): its derivatives along (v, ω) (0 for the
    others); the last kind the whole added-mass velocity wrench (`wrenches` takes its change with
    the fin angle)."""
    f[:, :] = 0.0
    J[:, :, :] = 0.0
    b = np.empty(3)
    b[0], b[1], b[2] = (r[1] * r[2]) ** 2, (r[2] * r[0]) ** 2, (r[0] * r[1]) ** 2
    N = b[0] * v[0] ** 2 + b[1] * v[1] ** 2 + b[2] * v[2] ** 2
    D = b[0] ** 2 * v[0] ** 2 + b[1] ** 2 * v[1] ** 2 + b[2] ** 2 * v[2] ** 2
    rs = np.sort(r)
    A_max = np.pi * rs[2] * rs[1]
    if N.real > 0 and (used[0] or used[1] or used[2]):
        speed = np.sqrt(v[0] ** 2 + v[1] ** 2 + v[2] ** 2)
        A_p = np.pi * np.sqrt(D / N)
        # ∇A_p = π²/A_p · v ∘ (b² N − b D) / N²
        gA = np.empty(3, dtype=v.dtype)
        for i in range(3):
            gA[i] = np.pi**2 / A_p * v[i] * (b[i] ** 2 * N - b[i] * D) / N**2
        # drag −ρ a ‖v‖ v: ∂/∂v = −ρ [a (‖v‖ I + v vᵀ/‖v‖) + ‖v‖ v ∇aᵀ], a = A_p or A_max − A_p
        for kind, area, sign in ((0, A_p, 1.0), (1, A_max - A_p, -1.0)):
            for i in range(3):
                f[kind, i] = -rho * area * speed * v[i]
                for j in range(3):
                    J[kind, i, j] = -rho * (
                        area * ((speed if i == j else 0.0) + v[i] * v[j] / speed)
                        + speed * v[i] * sign * gA[j]
                    )
        # Kutta lift σ w, σ = ρ π √(N/D)/‖v‖, w = (n × v) × v, n = b∘v:
        # ∂/∂v = w ∇σᵀ + σ ([v]×[v]× diag(b) − [v]×[n]× + [n × v]×)
        n = np.empty(3, dtype=v.dtype)
        for i in range(3):
            n[i] = b[i] * v[i]
        nv = np.empty(3, dtype=v.dtype)
        _cross(n, v, nv)
        wl = np.empty(3, dtype=v.dtype)
        _cross(nv, v, wl)
        sigma = rho * np.pi * np.sqrt(N / D) / speed
        Sv = np.empty((3, 3), dtype=v.dtype)
        Sn = np.empty((3, 3), dtype=v.dtype)
        Snv = np.empty((3, 3), dtype=v.dtype)
        _skew(v, Sv)
        _skew(n, Sn)
        _skew(nv, Snv)
        dw = _mm(Sv, Sv)
        for j in range(3):
            for i in range(3):
                dw[i, j] *= b[j]
        dw += Snv - _mm(Sv, Sn)
        for i in range(3):
            f[2, i] = sigma * wl[i]
        for j in range(3):
            g_sigma = sigma * (n[j] / N - b[j] * n[j] / D - v[j] / speed**2)
            for i in range(3):
                J[2, i, j] = wl[i] * g_sigma + sigma * dw[i, j]
    # Magnus ρ V ω × v: ∂/∂v = ρ V [ω]×, ∂/∂ω = −ρ V [v]×
    V = 4.0 / 3.0 * np.pi * r[0] * r[1] * r[2]
    m = np.empty(3, dtype=v.dtype)
    _cross(w, v, m)
    Sw = np.empty((3, 3), dtype=v.dtype)
    Sv2 = np.empty((3, 3), dtype=v.dtype)
    _skew(w, Sw)
    _skew(v, Sv2)
    for i in range(3 if used[3] else 0):
        f[3, i] = rho * V * m[i]
        for j in range(3):
            J[3, i, j] = rho * V * Sw[i, j]
            J[3, i, 3 + j] = -rho * V * Sv2[i, j]
    # angular drag −ρ ‖κ∘ω‖ ω: ∂/∂ω = −ρ (‖κ∘ω‖ I + ω (κ²∘ω)ᵀ / ‖κ∘ω‖)
    norm = np.sqrt((kappa[0] * w[0]) ** 2 + (kappa[1] * w[1]) ** 2 + (kappa[2] * w[2]) ** 2)
    if norm.real > 0 and used[4]:
        for i in range(3):
            f[4, 3 + i] = -rho * norm * w[i]
            for j in range(3):
                J[4, 3 + i, 3 + j] = -rho * ((norm if i == j else 0.0) + w[i] * kappa[j] ** 2 * w[j] / norm)
    # added mass: f = P × ω, g = P × v + H × ω (P = m_A∘v, H = I_A∘ω);
    # ∂f/∂v = −[ω]× diag(m_A), ∂f/∂ω = [P]×, ∂g/∂v = [P]× − [v]× diag(m_A), ∂g/∂ω = [H]× − [ω]× diag(I_A)
    if not used[5]:
        return
    P = np.empty(3, dtype=v.dtype)
    H = np.empty(3, dtype=v.dtype)
    for i in range(3):
        P[i] = added[i] * v[i]
        H[i] = added[3 + i] * w[i]
    t1 = np.empty(3, dtype=v.dtype)
    t2 = np.empty(3, dtype=v.dtype)
    _cross(P, w, t1)
    f[5, :3] = t1
    _cross(P, v, t1)
    _cross(H, w, t2)
    for i in range(3):
        f[5, 3 + i] = t1[i] + t2[i]
    SP = np.empty((3, 3), dtype=v.dtype)
    SH = np.empty((3, 3), dtype=v.dtype)
    _skew(P, SP)
    _skew(H, SH)
    for i in range(3):
        for j in range(3):
            J[5, i, j] = -Sw[i, j] * added[j]
            J[5, i, 3 + j] = SP[i, j]
            J[5, 3 + i, j] = SP[i, j] - Sv2[i, j] * added[j]
            J[5, 3 + i, 3 + j] = SH[i, j] - Sw[i, j] * added[3 + j]


@numba.njit(cache=True)
def wrenches(geometry, fin, z, W, JW, jacobian, used):
    """W (6, 6): each `used` kind's wrench on the vehicle (force, moment about the CG, body axes)
    per unit coefficient at z (9,) = (ν, δ) for one component (`packed_components`' row and fin),
    0 for the others; with `jacobian` JW (6, 6, 9) = ∂W/∂z."""
    _posed(geometry, fin, z, W, JW, jacobian, used)
    if fin < 0 or not used[5]:
        W[5, :] = 0.0
        JW[5, :, :] = 0.0
        return
    W0 = np.empty((6, 6), dtype=z.dtype)
    J0 = np.zeros((6, 6, 9), dtype=z.dtype)
    munk = np.zeros(6, dtype=np.bool_)
    munk[5] = True
    _posed(geometry, -1, z, W0, J0, jacobian, munk)  # the blade at δ = 0: its added mass alone
    for i in range(6):
        W[5, i] -= W0[5, i]
        if jacobian:
            for j in range(9):
                JW[5, i, j] -= J0[5, i, j]


@numba.njit(cache=True)
def _posed(geometry, fin, z, W, JW, jacobian, used):
    """`wrenches`' kinds, the last the whole added-mass velocity wrench, the component posed at
    its fin's angle (at 0 for fin −1)."""
    Q, p, dQ, dp = _local(geometry, fin, z)
    r, kappa, rho, added = geometry[0:3], geometry[15:18], geometry[18], geometry[25:31]
    nu_v, nu_w = z[0:3], z[3:6]
    # the centre's velocity v + ω × p, in the component's axes with ω
    vp = np.empty(3, dtype=z.dtype)
    _cross(nu_w, p, vp)
    for i in range(3):
        vp[i] += nu_v[i]
    v = _mv(Q, vp, True)
    w = _mv(Q, nu_w, True)
    f = np.empty((6, 6), dtype=z.dtype)
    J = np.empty((6, 6, 6), dtype=z.dtype)
    _kinds(r, kappa, rho, added, v, w, f, J, used)
    P = np.empty((3, 3), dtype=z.dtype)
    _skew(p, P)
    W[:, :] = 0.0
    for k in range(6):
        if not used[k]:
            continue
        F = _mv(Q, f[k, :3])
        G = _mv(Q, f[k, 3:])
        M = np.empty(3, dtype=z.dtype)
        _cross(p, F, M)
        for i in range(3):
            W[k, i] = F[i]
            W[k, 3 + i] = M[i] + G[i]
    if not jacobian:
        return
    # ∂(v, ω)_local/∂ν: v = Qᵀ(v_b − [p]× ω_b), ω = Qᵀ ω_b
    L = np.zeros((6, 9), dtype=z.dtype)
    QtP = _mm(Q, P, True)
    for i in range(3):
        for j in range(3):
            L[i, j] = Q[j, i]
            L[i, 3 + j] = -QtP[i, j]
            L[3 + i, 3 + j] = Q[j, i]
    if fin >= 0:  # along δ: dQᵀ (v_b + ω_b × p) + Qᵀ (ω_b × dp), dQᵀ ω_b
        wdp = np.empty(3, dtype=z.dtype)
        _cross(nu_w, dp, wdp)
        a = _mv(dQ, vp, True) + _mv(Q, wdp, True)
        b = _mv(dQ, nu_w, True)
        for i in range(3):
            L[i, 6 + fin] = a[i]
            L[3 + i, 6 + fin] = b[i]
    JW[:, :, :] = 0.0
    for k in range(6):
        if not used[k]:
            continue
        Jz = np.zeros((6, 9), dtype=z.dtype)  # ∂(f, g)_local/∂z
        for i in range(6):
            for j in range(9):
                for l in range(6):
                    Jz[i, j] += J[k, i, l] * L[l, j]
        dF = _mm(Q, Jz[:3])
        dG = _mm(Q, Jz[3:])
        dM = _mm(P, dF)
        for i in range(3):
            for j in range(9):
                JW[k, i, j] = dF[i, j]
                JW[k, 3 + i, j] = dM[i, j] + dG[i, j]
        if fin >= 0:  # the pose's own turn: dQ f, dp × F + p × dQ f + dQ g
            F = _mv(Q, f[k, :3])
            dQf = _mv(dQ, f[k, :3])
            dQg = _mv(dQ, f[k, 3:])
            t1 = np.empty(3, dtype=z.dtype)
            t2 = np.empty(3, dtype=z.dtype)
            _cross(dp, F, t1)
            _cross(p, dQf, t2)
            for i in range(3):
                JW[k, i, 6 + fin] += dQf[i]
                JW[k, 3 + i, 6 + fin] += t1[i] + t2[i] + dQg[i]
