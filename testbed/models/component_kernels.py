"""The components' forces per unit coefficient and their exact derivatives, compiled (numba) one
state and one component at a time, for real and complex arguments (the formulas: `components`).

Every intermediate lives in one scratch array the caller gives (`SCRATCH` entries of z's dtype),
at fixed places: a flight evaluates the components some forty thousand times, and allocating the
few dozen 3-vectors and 3 × 3 matrices of each evaluation would cost more than the arithmetic.
Their views (`_vec`, `_mat`) are inlined where they are taken, transposes are passed as views
(`A.T`), and constant flags and indices passed on are wrapped (`int(0)`): numba compiles a
callee anew for every literal argument value (`nonlinear_kernels`).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["SCRATCH", "turned_mass", "wrenches"]

SCRATCH = 1150  # the scratch entries `wrenches` and `turned_mass` need


@numba.njit(cache=True, inline="always")
def _vec(S, at):
    return S[at : at + 3]


@numba.njit(cache=True, inline="always")
def _mat(S, at):
    return S[at : at + 9].reshape((3, 3))


@numba.njit(cache=True)
def _cross(a, b, out):
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]


@numba.njit(cache=True)
def _mm(A, B, out):
    """out = A B (A (3, 3), B (3, k)); Aᵀ B with A.T given (a view)."""
    for i in range(3):
        for j in range(B.shape[1]):
            acc = 0.0 * B[0, 0]
            for k in range(3):
                acc += A[i, k] * B[k, j]
            out[i, j] = acc


@numba.njit(cache=True)
def _mv(A, x, out):
    """out = A x (A (3, 3), x (3,)); Aᵀ x with A.T given (a view)."""
    for i in range(3):
        acc = 0.0 * x[0]
        for k in range(3):
            acc += A[i, k] * x[k]
        out[i] = acc


@numba.njit(cache=True)
def _skew(a, out):
    """[a]× into out (3, 3): [a]× b = a × b."""
    out[0, 0], out[0, 1], out[0, 2] = 0.0, -a[2], a[1]
    out[1, 0], out[1, 1], out[1, 2] = a[2], 0.0, -a[0]
    out[2, 0], out[2, 1], out[2, 2] = -a[1], a[0], 0.0


@numba.njit(cache=True)
def _local(geometry, fin, z, S):
    """The component's pose at z = (ν, δ) into S: Q (body from component) at 0, p at 18, and
    their derivatives along its fin's angle dQ at 9, dp at 21 (zero off a fin)."""
    Q, dQ, p, dp = _mat(S, 0), _mat(S, 9), _vec(S, 18), _vec(S, 21)
    R, dR, K, K2 = _mat(S, 24), _mat(S, 33), _mat(S, 42), _mat(S, 51)
    a, h = geometry[22:25], geometry[19:22]
    d = z[6 + fin] if fin >= 0 else 0.0 * z[0]
    # R(a, δ) = I + sin δ [a]× + (1 − cos δ) [a]×², dR/dδ = cos δ [a]× + sin δ [a]×²
    _skew(a, K)
    _mm(K, K, K2)
    s, c = np.sin(d), np.cos(d)
    for i in range(3):
        for j in range(3):
            R[i, j] = (1.0 if i == j else 0.0) + s * K[i, j] + (1.0 - c) * K2[i, j]
            dR[i, j] = c * K[i, j] + s * K2[i, j]
    for i in range(3):
        p[i] = h[i]
        dp[i] = 0.0
        for j in range(3):
            p[i] += R[i, j] * (geometry[3 + j] - h[j])
            dp[i] += dR[i, j] * (geometry[3 + j] - h[j])
            Q[i, j] = 0.0
            dQ[i, j] = 0.0
            for k in range(3):
                Q[i, j] += R[i, k] * geometry[6 + 3 * k + j]
                dQ[i, j] += dR[i, k] * geometry[6 + 3 * k + j]
    if fin < 0:
        dQ[:, :] = 0.0
        dp[:] = 0.0


@numba.njit(cache=True)
def _kinds(r, kappa, rho, added, v, w, f, J, jacobian, used, first, S):
    """The wrench of each `used` kind from `first` on (f (6, 6): force, torque) in the
    component's axes at its local (v, ω), per unit coefficient, and with `jacobian` J (6, 6, 6):
    its derivatives along (v, ω) (0 for the others; without it J is left as it was); the last
    kind the whole added-mass velocity wrench (`wrenches` takes its change with the fin angle).
    Scratch from S[69:180]."""
    f[:, :] = 0.0
    if jacobian:
        J[:, :, :] = 0.0
    b, gA, n, nv, wl = _vec(S, 69), _vec(S, 72), _vec(S, 75), _vec(S, 78), _vec(S, 81)
    Sv, Sn, Snv, dw, tmp = _mat(S, 84), _mat(S, 93), _mat(S, 102), _mat(S, 111), _mat(S, 120)
    m, Sw, Sv2 = _vec(S, 129), _mat(S, 132), _mat(S, 141)
    P, H, t1, t2, SP, SH = _vec(S, 150), _vec(S, 153), _vec(S, 156), _vec(S, 159), _mat(S, 162), _mat(S, 171)
    b[0], b[1], b[2] = (r[1] * r[2]) ** 2, (r[2] * r[0]) ** 2, (r[0] * r[1]) ** 2
    N = b[0] * v[0] ** 2 + b[1] * v[1] ** 2 + b[2] * v[2] ** 2
    D = b[0] ** 2 * v[0] ** 2 + b[1] ** 2 * v[1] ** 2 + b[2] ** 2 * v[2] ** 2
    r_max = max(r[0], r[1], r[2])
    r_mid = r[0] + r[1] + r[2] - r_max - min(r[0], r[1], r[2])
    A_max = np.pi * r_max * r_mid
    if N.real > 0 and first <= 2 and (used[0] or used[1] or used[2]):
        speed = np.sqrt(v[0] ** 2 + v[1] ** 2 + v[2] ** 2)
        A_p = np.pi * np.sqrt(D / N)
        # drag −ρ a ‖v‖ v, a = A_p or A_max − A_p
        for kind, area in ((0, A_p), (1, A_max - A_p)):
            for i in range(3):
                f[kind, i] = -rho * area * speed * v[i]
        # Kutta lift σ w, σ = ρ π √(N/D)/‖v‖, w = (n × v) × v, n = b∘v
        for i in range(3):
            n[i] = b[i] * v[i]
        _cross(n, v, nv)
        _cross(nv, v, wl)
        sigma = rho * np.pi * np.sqrt(N / D) / speed
        for i in range(3):
            f[2, i] = sigma * wl[i]
        if jacobian:
            # ∇A_p = π²/A_p · v ∘ (b² N − b D) / N²
            for i in range(3):
                gA[i] = np.pi**2 / A_p * v[i] * (b[i] ** 2 * N - b[i] * D) / N**2
            # the drags' ∂/∂v = −ρ [a (‖v‖ I + v vᵀ/‖v‖) + ‖v‖ v ∇aᵀ]
            for kind, area, sign in ((0, A_p, 1.0), (1, A_max - A_p, -1.0)):
                for i in range(3):
                    for j in range(3):
                        J[kind, i, j] = -rho * (
                            area * ((speed if i == j else 0.0) + v[i] * v[j] / speed)
                            + speed * v[i] * sign * gA[j]
                        )
            # the lift's ∂/∂v = w ∇σᵀ + σ ([v]×[v]× diag(b) − [v]×[n]× + [n × v]×)
            _skew(v, Sv)
            _skew(n, Sn)
            _skew(nv, Snv)
            _mm(Sv, Sv, dw)
            _mm(Sv, Sn, tmp)
            for i in range(3):
                for j in range(3):
                    dw[i, j] = dw[i, j] * b[j] + Snv[i, j] - tmp[i, j]
            for j in range(3):
                g_sigma = sigma * (n[j] / N - b[j] * n[j] / D - v[j] / speed**2)
                for i in range(3):
                    J[2, i, j] = wl[i] * g_sigma + sigma * dw[i, j]
    # Magnus ρ V ω × v: ∂/∂v = ρ V [ω]×, ∂/∂ω = −ρ V [v]×
    V = 4.0 / 3.0 * np.pi * r[0] * r[1] * r[2]
    _cross(w, v, m)
    if jacobian:
        _skew(w, Sw)
        _skew(v, Sv2)
    if used[3] and first <= 3:
        for i in range(3):
            f[3, i] = rho * V * m[i]
            if not jacobian:
                continue
            for j in range(3):
                J[3, i, j] = rho * V * Sw[i, j]
                J[3, i, 3 + j] = -rho * V * Sv2[i, j]
    # angular drag −ρ ‖κ∘ω‖ ω: ∂/∂ω = −ρ (‖κ∘ω‖ I + ω (κ²∘ω)ᵀ / ‖κ∘ω‖)
    norm = np.sqrt((kappa[0] * w[0]) ** 2 + (kappa[1] * w[1]) ** 2 + (kappa[2] * w[2]) ** 2)
    if norm.real > 0 and used[4] and first <= 4:
        for i in range(3):
            f[4, 3 + i] = -rho * norm * w[i]
            if not jacobian:
                continue
            for j in range(3):
                J[4, 3 + i, 3 + j] = -rho * ((norm if i == j else 0.0) + w[i] * kappa[j] ** 2 * w[j] / norm)
    if not used[5]:
        return
    # added mass: f = P × ω, g = P × v + H × ω (P = m_A∘v, H = I_A∘ω);
    # ∂f/∂v = −[ω]× diag(m_A), ∂f/∂ω = [P]×, ∂g/∂v = [P]× − [v]× diag(m_A), ∂g/∂ω = [H]× − [ω]× diag(I_A)
    for i in range(3):
        P[i] = added[i] * v[i]
        H[i] = added[3 + i] * w[i]
    _cross(P, w, t1)
    for i in range(3):
        f[5, i] = t1[i]
    _cross(P, v, t1)
    _cross(H, w, t2)
    for i in range(3):
        f[5, 3 + i] = t1[i] + t2[i]
    if not jacobian:
        return
    _skew(P, SP)
    _skew(H, SH)
    for i in range(3):
        for j in range(3):
            J[5, i, j] = -Sw[i, j] * added[j]
            J[5, i, 3 + j] = SP[i, j]
            J[5, 3 + i, j] = SP[i, j] - Sv2[i, j] * added[j]
            J[5, 3 + i, 3 + j] = SH[i, j] - Sw[i, j] * added[3 + j]


@numba.njit(cache=True)
def wrenches(geometry, fin, z, W, JW, jacobian, used, S):
    """W (6, 6): each `used` kind's wrench on the vehicle (force, moment about the CG, body axes)
    per unit coefficient at z (9,) = (ν, δ) for one component (`packed_components`' row and fin),
    0 for the others; with `jacobian` JW (6, 6, 9) = ∂W/∂z. S: scratch (`SCRATCH`,) of z's dtype."""
    _posed(geometry, fin, z, W, JW, jacobian, used, int(0), S)
    if fin < 0 or not used[5]:
        W[5, :] = 0.0
        JW[5, :, :] = 0.0
        return
    W0 = S[678:714].reshape((6, 6))
    J0 = S[714:1038].reshape((6, 6, 9))
    # the blade at δ = 0: its added mass alone
    _posed(geometry, int(-1), z, W0, J0, jacobian, used, int(5), S)
    for i in range(6):
        W[5, i] -= W0[5, i]
        if jacobian:
            for j in range(9):
                JW[5, i, j] -= J0[5, i, j]


@numba.njit(cache=True)
def _posed(geometry, fin, z, W, JW, jacobian, used, first, S):
    """`wrenches`' kinds (the `used` ones from `first` on), the last the whole added-mass
    velocity wrench, the component posed at its fin's angle (at 0 for fin −1). Scratch from
    S[0:678]."""
    _local(geometry, fin, z, S)
    Q, dQ, p, dp = _mat(S, 0), _mat(S, 9), _vec(S, 18), _vec(S, 21)
    r, kappa, rho, added = geometry[0:3], geometry[15:18], geometry[18], geometry[25:31]
    nu_v, nu_w = z[0:3], z[3:6]
    vp, v, w = _vec(S, 180), _vec(S, 183), _vec(S, 186)
    f = S[189:225].reshape((6, 6))
    J = S[225:441].reshape((6, 6, 6))
    P, F, G, M = _mat(S, 441), _vec(S, 450), _vec(S, 453), _vec(S, 456)
    # the centre's velocity v + ω × p, in the component's axes with ω
    _cross(nu_w, p, vp)
    for i in range(3):
        vp[i] += nu_v[i]
    _mv(Q.T, vp, v)
    _mv(Q.T, nu_w, w)
    _kinds(r, kappa, rho, added, v, w, f, J, jacobian, used, first, S)
    _skew(p, P)
    W[:, :] = 0.0
    for k in range(6):
        if not used[k] or k < first:
            continue
        _mv(Q, f[k, :3], F)
        _mv(Q, f[k, 3:], G)
        _cross(p, F, M)
        for i in range(3):
            W[k, i] = F[i]
            W[k, 3 + i] = M[i] + G[i]
    if not jacobian:
        return
    L = S[459:513].reshape((6, 9))
    QtP, wdp, a, b = _mat(S, 513), _vec(S, 522), _vec(S, 525), _vec(S, 528)
    Jz = S[531:585].reshape((6, 9))
    dF, dG, dM = S[585:612].reshape((3, 9)), S[612:639].reshape((3, 9)), S[639:666].reshape((3, 9))
    dQf, dQg, t1, t2 = _vec(S, 666), _vec(S, 669), _vec(S, 672), _vec(S, 675)
    # ∂(v, ω)_local/∂ν: v = Qᵀ(v_b − [p]× ω_b), ω = Qᵀ ω_b
    L[:, :] = 0.0
    _mm(Q.T, P, QtP)
    for i in range(3):
        for j in range(3):
            L[i, j] = Q[j, i]
            L[i, 3 + j] = -QtP[i, j]
            L[3 + i, 3 + j] = Q[j, i]
    if fin >= 0:  # along δ: dQᵀ (v_b + ω_b × p) + Qᵀ (ω_b × dp), dQᵀ ω_b
        _cross(nu_w, dp, wdp)
        _mv(dQ.T, vp, a)
        _mv(Q.T, wdp, t1)
        _mv(dQ.T, nu_w, b)
        for i in range(3):
            L[i, 6 + fin] = a[i] + t1[i]
            L[3 + i, 6 + fin] = b[i]
    JW[:, :, :] = 0.0
    for k in range(6):
        if not used[k] or k < first:
            continue
        for i in range(6):  # ∂(f, g)_local/∂z
            for j in range(9):
                acc = 0.0 * z[0]
                for l in range(6):
                    acc += J[k, i, l] * L[l, j]
                Jz[i, j] = acc
        _mm(Q, Jz[:3], dF)
        _mm(Q, Jz[3:], dG)
        _mm(P, dF, dM)
        for i in range(3):
            for j in range(9):
                JW[k, i, j] = dF[i, j]
                JW[k, 3 + i, j] = dM[i, j] + dG[i, j]
        if fin >= 0:  # the pose's own turn: dQ f, dp × F + p × dQ f + dQ g
            _mv(Q, f[k, :3], F)
            _mv(dQ, f[k, :3], dQf)
            _mv(dQ, f[k, 3:], dQg)
            _cross(dp, F, t1)
            _cross(p, dQf, t2)
            for i in range(3):
                JW[k, i, 6 + fin] += dQf[i]
                JW[k, 3 + i, 6 + fin] += t1[i] + t2[i] + dQg[i]


@numba.njit(cache=True)
def _skewed(A, p, i, j):
    """(Aᵀ [p]×)_ij = Σ_k A_ki ([p]×)_kj, the j-th column of [p]× being (0, p₂, −p₁), (−p₂, 0, p₀)
    or (p₁, −p₀, 0)."""
    zero = 0.0 * p[0]
    col = (zero, p[2], -p[1]) if j == 0 else ((-p[2], zero, p[0]) if j == 1 else (p[1], -p[0], zero))
    return A[0, i] * col[0] + A[1, i] * col[1] + A[2, i] * col[2]


@numba.njit(cache=True)
def _transform(A, p, X):
    """X (6, 6) = [[Aᵀ, −Aᵀ [p]×], [0, Aᵀ]]: with A = Q the motion transform from the body's
    velocities to the component's own at its pose (Q, p)."""
    X[:, :] = 0.0
    for i in range(3):
        for j in range(3):
            X[i, j] = A[j, i]
            X[3 + i, 3 + j] = A[j, i]
            X[i, 3 + j] = -_skewed(A, p, i, j)


@numba.njit(cache=True)
def turned_mass(geometry, fin, z, DM, dDM, S):
    """DM (6, 6): how a blade's added mass about the CG in body axes, Xᵀ diag(m_A, I_A) X, changes
    as it turns with its fin from 0 to z's angle; dDM (6, 6) its derivative along that angle
    (X `_transform`, dX/dδ from the pose's). Scratch S[0:60] and S[1040:1148]."""
    added = geometry[25:31]
    X, dX, X0 = S[1040:1076].reshape((6, 6)), S[1076:1112].reshape((6, 6)), S[1112:1148].reshape((6, 6))
    _local(geometry, int(-1), z, S)
    _transform(_mat(S, 0), _vec(S, 18), X0)
    _local(geometry, fin, z, S)
    Q, dQ, p, dp = _mat(S, 0), _mat(S, 9), _vec(S, 18), _vec(S, 21)
    _transform(Q, p, X)
    # dX = [[dQᵀ, −dQᵀ [p]× − Qᵀ [dp]×], [0, dQᵀ]]
    _transform(dQ, p, dX)
    for i in range(3):
        for j in range(3):
            dX[i, 3 + j] -= _skewed(Q, dp, i, j)
    for i in range(6):
        for j in range(6):
            m, m0, dm = 0.0 * z[0], 0.0 * z[0], 0.0 * z[0]
            for k in range(6):
                m += X[k, i] * added[k] * X[k, j]
                m0 += X0[k, i] * added[k] * X0[k, j]
                dm += dX[k, i] * added[k] * X[k, j] + X[k, i] * added[k] * dX[k, j]
            DM[i, j] = m - m0
            dDM[i, j] = dm
