"""The nonlinear model's state derivative, its exact derivatives and its RK4 flight, compiled
(numba) one state at a time: numpy's per-call overhead on one state's 6 × 6 and 10 × 10
products is tens of times the arithmetic, and a flight evaluates the model four times per RK4
step, thousands of steps per record.

Every function takes the model as the tuple `nonlinear.packed` makes (its term table and
constant matrices at one θ) and real or complex arrays alike: numba compiles a complex128
specialisation beside the float64 one, so a complex step differentiates this code itself.

The terms are data: each term's factors are indices into the atoms, the atoms' values being
z W (z = (ν, δ), W the linear atoms' weights, `regressors.WEIGHTS`), their magnitudes, the
magnitudes √(z_i² + z_j²) of pairs of z's entries (`regressors.PAIRS`) and the constant 1
(`regressors.factor_table`), so any term set the names describe is evaluated here,
with the gradient of each product by the product rule (summed per force row and atom, then
taken through W once).

With `jacobian`, a state's evaluation writes ∂F/∂(x, δ) (6 × 13) beside F; `rk4_flight` carries
the sensitivities S = ∂x/∂(θ[free], the fins' parameters, x0) (10 × (p + q + 10)) through each
RK4 stage, ∂k_i = A_i ∂X_i + [F_θ,i  B_i ∂δ  0], so they are exact for the flight (module doc of
`identification.nonlinear_sensitivities`).

A flag passed as a constant is wrapped (`bool(False)`): numba compiles a callee anew for every
literal value it is called with, but once per type for a value it only knows at run time, and
compiling these kernels, once per installation, is most of the first nonlinear fit's time.
"""

from __future__ import annotations

import numba
import numpy as np

from testbed.models.component_kernels import SCRATCH, turned_mass, wrenches
from testbed.models.mechanics import coriolis_state, kinematics_state, kirchhoff, restoring_state

__all__ = ["rk4_flight", "state_model"]


@numba.njit(cache=True)
def _atoms(weights, pairs, z, atoms, signs, scales):
    """The atoms' values at z (9,) = (ν, δ) into atoms (2L + P + 1,): z W (W (9, L) the linear
    atoms' weights), their magnitudes, the pairs' magnitudes √(z_i² + z_j²) (`pairs` (P, 2)),
    and 1. The gradients: a linear atom's or magnitude's is its sign (`signs`) times its weights,
    a pair's (z_i, z_j) times its `scales` entry 1/√(z_i² + z_j²) (both 0 where the atom has none:
    the constant, a magnitude or a pair at 0, the mean of its one-sided slopes, so that an even
    term such as u|v| has no linear part at v = 0)."""
    L = weights.shape[1]
    for a in range(L):
        value = 0.0 * z[0]
        for i in range(z.shape[0]):
            value += z[i] * weights[i, a]
        atoms[a] = value
        signs[a] = 1.0
        # |x| as x or −x by the sign of x's real part (a complex step sees through it)
        atoms[L + a] = value if value.real >= 0 else -value
        signs[L + a] = np.sign(value.real)
    for k in range(pairs.shape[0]):
        norm = np.sqrt(z[pairs[k, 0]] ** 2 + z[pairs[k, 1]] ** 2)  # the principal root
        atoms[2 * L + k] = norm
        signs[2 * L + k] = 0.0 if norm.real == 0 else 1.0
        scales[k] = 0.0 if norm.real == 0 else 1.0 / norm
    atoms[2 * L + pairs.shape[0]] = 1.0
    signs[2 * L + pairs.shape[0]] = 0.0


@numba.njit(cache=True)
def _forces(m, x, d, work, jacobian):
    """F (6,) = −C(ν)ν + g(η) + T e_x + Σ c_k φ_k e_row(k) at the state x (10,) and fins δ (3,),
    φ (K,) the terms' products of atoms (the factor table); with `jacobian` JF (6, 13) =
    ∂F/∂(x, δ), the terms' part by the product rule summed per row and atom first. F, JF and φ
    are the first three of the `work` arrays."""
    weights, table, rows, c, thrust, M = m[0], m[1], m[2], m[3], m[4], m[5]
    weight, buoyancy, rB, pairs = m[9], m[10], m[11], m[12]
    part, kind, geometry, fins, used = m[13], m[14], m[15], m[16], m[17]
    F, JF, phi, z, atoms, signs, slopes, scales, CW, CJ, CS, CM, CdM = work[:13]
    L = weights.shape[1]
    z[:6] = x[:6]
    z[6:] = d
    _atoms(weights, pairs, z, atoms, signs, scales)
    F[:] = 0.0
    if jacobian:
        JF[:, :] = 0.0
        slopes[:, :] = 0.0  # ∂F_row/∂atom
    coriolis_state(M, x[:6], F, JF, jacobian)
    restoring_state(weight, buoyancy, rB, x[6], x[7], F, JF[:, 6:8], jacobian)
    F[0] += thrust
    # the blades' added mass turned with their fins (`_inertia`) depends on δ alone, which a flight
    # holds over each sample interval: evaluated when δ changes (work[14] the last δ, work[15][0]
    # 1 until M⁻¹ follows it)
    last, stale = work[14], work[15]
    turned = not (d[0] == last[0] and d[1] == last[1] and d[2] == last[2])
    for p in range(geometry.shape[0]):  # each component's wrenches per unit coefficient
        wrenches(geometry[p], fins[p], z, CW[p], CJ[p], jacobian, used[p], CS)
        if turned and used[p, 5] and fins[p] >= 0:
            turned_mass(geometry[p], fins[p], z, CM[p], CdM[p], CS)
    if turned:
        last[:] = d
        stale[0] = 1.0
    width = table.shape[1]
    for k in range(len(rows)):
        if part[k] >= 0:  # a component term: its component's wrench of its kind, in every row
            phi[k] = 1.0
            for r in range(6):
                F[r] += c[k] * CW[part[k], kind[k], r]
                if jacobian:
                    for i in range(9):
                        JF[r, i if i < 6 else i + 4] += c[k] * CJ[part[k], kind[k], r, i]
            continue
        product = atoms[table[k, 0]]
        for f in range(1, width):
            product *= atoms[table[k, f]]
        phi[k] = product
        F[rows[k]] += c[k] * product
        if not jacobian:
            continue
        for f in range(width):
            atom = table[k, f]
            if signs[atom] == 0.0:
                continue
            others = c[k] * signs[atom]
            for g in range(width):
                if g != f:
                    others *= atoms[table[k, g]]
            slopes[rows[k], atom] += others
    if not jacobian:
        return
    for r in range(6):
        for atom in range(2 * L):
            slope = slopes[r, atom]
            if slope == 0:
                continue
            for i in range(9):
                w = weights[i, atom % L]
                if w != 0:
                    JF[r, i if i < 6 else i + 4] += slope * w
        for k in range(pairs.shape[0]):
            slope = slopes[r, 2 * L + k] * scales[k]
            for i in pairs[k]:
                JF[r, i if i < 6 else i + 4] += slope * z[i]


@numba.njit(cache=True)
def _inertia(m, work):
    """M⁻¹ at the state `_forces` last evaluated, into work[13]: the model's, or with `munk` terms
    M + Σ c_k ΔM_b(δ), each blade's added mass turned with its fin scaled by its Munk term's
    coefficient (the blade's added mass is one quantity, in its Kirchhoff forces and in M). An
    M that has no inverse (not finite: the state has left the finite numbers, or singular: Munk
    coefficients cancelling the mass) gives NaN, rates that a flight's caller reports as its
    leaving the finite numbers."""
    c, M, part, kind = m[3], m[5], m[13], m[14]
    CM, MI, stale = work[11], work[13], work[15]
    if stale[0] == 0.0:
        return
    stale[0] = 0.0
    Mt, turned = M.copy(), False
    for k in range(len(part)):
        if part[k] >= 0 and kind[k] == 5:
            Mt += c[k] * CM[part[k]]
            turned = True
    if not turned:
        MI[:, :] = m[6]
        return
    try:
        MI[:, :] = np.linalg.inv(Mt)
    except Exception:  # numba's LinAlgError: a matrix not finite or singular
        MI[:, :] = np.nan


@numba.njit(cache=True)
def _state(m, x, d, f, A, B, work, jacobian):
    """f (10,) = ẋ at x (10,), δ (3,); with `jacobian` A (10, 10) = ∂f/∂x and B (10, 3) = ∂f/∂δ:
    M⁻¹ times the forces' in the body rows (M with the blades' added mass turned, `_inertia`;
    its turn's −M⁻¹ ∂M/∂δ ν̇ in B), the kinematics' in the others."""
    F, JF, Minv = work[0], work[1], work[13]
    _forces(m, x, d, work, jacobian)
    _inertia(m, work)
    for i in range(6):
        acc = 0.0 * F[0]
        for j in range(6):
            acc += Minv[i, j] * F[j]
        f[i] = acc
    kinematics_state(x, f[6:], A[6:], jacobian)
    if not jacobian:
        return
    for i in range(6):
        for j in range(13):
            acc = 0.0 * F[0]
            for l in range(6):
                acc += Minv[i, l] * JF[l, j]
            if j < 10:
                A[i, j] = acc
            else:
                B[i, j - 10] = acc
    B[6:, :] = 0.0
    c, part, kind, fins, CdM = m[3], m[13], m[14], m[16], work[12]
    for k in range(len(part)):
        if part[k] >= 0 and kind[k] == 5 and fins[part[k]] >= 0:
            for i in range(6):
                acc = 0.0 * F[0]
                for l in range(6):
                    for n in range(6):
                        acc += Minv[i, l] * CdM[part[k], l, n] * f[n]
                B[i, fins[part[k]]] -= c[k] * acc


@numba.njit(cache=True)
def _theta_columns(m, x, f, work, columns, G):
    """G[:, j] (10,) = ∂f/∂θ_columns[j] at the state x whose ẋ is f, the terms' φ and the
    components' wrenches in `work` (`_forces`' at x): for a term M⁻¹ (φ_k e_row − s_k e_x) (s_k
    the thrust's share; a component term's wrench in place of φ_k e_row), for an inertia
    coefficient M⁻¹ (−C_k(ν) ν − ∂M/∂θ_k ν̇), C_k the Kirchhoff forces of ∂M/∂θ_k (C is linear
    in M)."""
    rows, dM, surge, part, kind = m[2], m[7], m[8], m[13], m[14]
    phi, CW, CM, Minv = work[2], work[8], work[11], work[13]
    inertia = dM.shape[0]  # the inertia coefficients lead θ (`nonlinear.INERTIA`)
    g = np.empty(6, dtype=f.dtype)
    h = np.empty(6, dtype=f.dtype)
    G[6:, :] = 0.0
    for j in range(len(columns)):
        col = columns[j]
        if col < inertia:
            for i in range(6):
                h[i] = 0.0
                g[i] = 0.0
                for l in range(6):
                    h[i] += dM[col, i, l] * x[l]
                    g[i] -= dM[col, i, l] * f[l]
            kirchhoff(h, x[:6], g)
            for i in range(6):
                acc = 0.0 * g[0]
                for l in range(6):
                    acc += Minv[i, l] * g[l]
                G[i, j] = acc
        else:
            k = col - inertia
            for i in range(6):
                if part[k] >= 0:
                    acc = -Minv[i, 0] * surge[k]
                    for r in range(6):
                        acc += Minv[i, r] * CW[part[k], kind[k], r]
                        if kind[k] == 5:  # its turned added mass in M: −M⁻¹ ΔM_b ν̇
                            for n in range(6):
                                acc -= Minv[i, r] * CM[part[k], r, n] * f[n]
                    G[i, j] = acc
                else:
                    G[i, j] = Minv[i, rows[k]] * phi[k] - Minv[i, 0] * surge[k]


@numba.njit(cache=True)
def _work(m, like):
    """Scratch arrays of `like`'s dtype for `_forces`: F, JF, φ, z, the atoms, their signs, the
    rows' slopes along the atoms, the pairs' scales, the components' wrenches per kind and
    their gradients along z, the components' scratch, the blades' turned added mass and its
    derivative along their fins, M⁻¹ at the state, the δ they were evaluated at and whether M⁻¹
    is to follow."""
    K, atoms, C = len(m[2]), 2 * m[0].shape[1] + m[12].shape[0] + 1, m[15].shape[0]
    dtype = like.dtype
    return (
        np.zeros(6, dtype=dtype),
        np.zeros((6, 13), dtype=dtype),
        np.zeros(K, dtype=dtype),
        np.zeros(9, dtype=dtype),
        np.zeros(atoms, dtype=dtype),
        np.zeros(atoms),
        np.zeros((6, atoms), dtype=dtype),
        np.zeros(m[12].shape[0], dtype=dtype),
        np.zeros((C, 6, 6), dtype=dtype),
        np.zeros((C, 6, 6, 9), dtype=dtype),
        np.zeros(SCRATCH, dtype=dtype),
        np.zeros((C, 6, 6), dtype=dtype),
        np.zeros((C, 6, 6), dtype=dtype),
        np.zeros((6, 6), dtype=dtype),
        np.full(3, np.nan, dtype=dtype),
        np.ones(1),
    )


@numba.njit(cache=True)
def state_model(m, x, d, F, JF, f, A, B, G, jacobian, theta):
    """At the states x (n, 10) and fins d (n, 3): the forces F (n, 6) and f (n, 10) = ẋ; with
    `jacobian` JF (n, 6, 13) = ∂F/∂(x, δ), A (n, 10, 10) = ∂f/∂x and B (n, 10, 3) = ∂f/∂δ; with
    `theta` G (n, 10, P) = ∂f/∂θ, every coefficient. An array a flag leaves out may have one
    sample: it is scratch. One kernel for all of them: each compiled kernel takes the whole
    model's tree anew, and compiling it is most of a first nonlinear fit's time."""
    work = _work(m, x)
    columns = np.arange(G.shape[2])
    for n in range(x.shape[0]):
        k = n if jacobian else 0
        _state(m, x[n], d[n], f[n], A[k], B[k], work, jacobian)
        for r in range(6):
            F[n, r] = work[0][r]
            if jacobian:
                for i in range(13):
                    JF[n, r, i] = work[1][r, i]
        if theta:
            _theta_columns(m, x[n], f[n], work, columns, G[n])


@numba.njit(cache=True)
def rk4_flight(m, t, x, fins, columns, substeps, S, D):
    """x[k + 1] (10,) from x[k] for k < N − 1 in place (x (N, 10), x[0] given): classical RK4,
    `substeps` steps per interval [t[k], t[k + 1]], the fins (N, 3) held at fins[k]; and S[k + 1]
    (10, p + q + 10) from S[k] (S[0] given): the states' sensitivities to θ[columns] (p), to q
    parameters that move the fins (D (N, 3, q): ∂fins[k]/∂ each, held with them) and to x[0],
    carried through every RK4 stage. S with no columns (1, 10, 0): the flight alone, the model
    evaluated without its derivatives."""
    work = _work(m, x)
    p, q, width = len(columns), D.shape[2], S.shape[2]
    carried = width > 0  # a run-time flag: `_state` compiled once for both
    A, B = np.empty((10, 10), dtype=x.dtype), np.empty((10, 3), dtype=x.dtype)
    G = np.empty((10, p), dtype=x.dtype)
    ks = np.empty((4, 10), dtype=x.dtype)
    dks = np.empty((4, 10, width), dtype=x.dtype)
    X = np.empty(10, dtype=x.dtype)
    dX = np.empty((10, width), dtype=x.dtype)
    xs = np.empty(10, dtype=x.dtype)
    T = np.empty((10, width), dtype=x.dtype)
    for k in range(x.shape[0] - 1):
        h = (t[k + 1] - t[k]) / substeps
        for j in range(10):
            xs[j] = x[k, j]
            for c in range(width):
                T[j, c] = S[k, j, c]
        for _ in range(substeps):
            for i, a in enumerate((0.0, 0.5, 0.5, 1.0)):
                for j in range(10):
                    X[j] = xs[j] if i == 0 else xs[j] + a * h * ks[i - 1, j]
                    for c in range(width):
                        dX[j, c] = T[j, c] if i == 0 else T[j, c] + a * h * dks[i - 1, j, c]
                _state(m, X, fins[k], ks[i], A, B, work, carried)
                if not carried:
                    continue
                _theta_columns(m, X, ks[i], work, columns, G)
                for j in range(10):  # ∂k_i = A_i ∂X_i + [G_i  B_i D_k  0]
                    for c in range(width):
                        dks[i, j, c] = G[j, c] if c < p else 0.0
                    for c in range(q):
                        for l in range(3):
                            dks[i, j, p + c] += B[j, l] * D[k, l, c]
                    for l in range(10):
                        a_jl = A[j, l]
                        if a_jl != 0:
                            for c in range(width):
                                dks[i, j, c] += a_jl * dX[l, c]
            for j in range(10):
                xs[j] = xs[j] + h / 6 * (ks[0, j] + 2 * ks[1, j] + 2 * ks[2, j] + ks[3, j])
                for c in range(width):
                    T[j, c] = T[j, c] + h / 6 * (
                        dks[0, j, c] + 2 * dks[1, j, c] + 2 * dks[2, j, c] + dks[3, j, c]
                    )
        for j in range(10):
            x[k + 1, j] = xs[j]
            for c in range(width):
                S[k + 1, j, c] = T[j, c]
