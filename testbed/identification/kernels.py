"""The recursions of `testbed.identification.scan` compiled (numba), for optimisers that simulate
thousands of times: loading the compiler costs about 0.35 s once per process (its import and its compiled
code read back from the cache), which a simplex search wins back many times over and a single
Gauss-Newton fit of a measurement file does not (`scan.compiled`).

Each computes what `scan.Scan` computes, sample by sample: numpy's per-call overhead on a
10×10 product is ~50× the arithmetic, a compiled loop has none.
"""

import numba
import numpy as np

from testbed.models.cholesky import solve_spd

__all__ = [
    "adjoint_sum",
    "concentrated_sse",
    "gramian",
    "masked_gramian",
    "propagate_states",
    "recursion",
    "weighted_sse",
]


@numba.njit(cache=True, fastmath={"reassoc"})  # the sums reordered: 1.5× faster
def propagate_states(Phi, x, F):
    """`x[k+1] = Φ x[k] + F[k]` in place for k < len(F), from `x[0]`."""
    n = x.shape[1]
    for k in range(F.shape[0]):
        for i in range(n):
            acc = F[k, i]
            for l in range(n):
                acc += Phi[i, l] * x[k, l]
            x[k + 1, i] = acc


@numba.njit(cache=True, fastmath={"reassoc"})
def recursion(Phi, forcing, X, rows, S):
    """`S[c, t] = X[t][rows[c]]` for t < S.shape[1], with `X[t+1] = Φ X[t] + F[t]` from `X[0] = X`
    (n, m), F[t]'s first j columns `forcing[t]` (n, j) and the others zero; X is left at the
    state after the last forcing (the next piece's first)."""
    n, m = X.shape
    j = forcing.shape[2]
    x, xn = X, np.empty_like(X)
    for t in range(S.shape[1]):
        for c in range(len(rows)):
            for k in range(m):
                S[c, t, k] = x[rows[c], k]
        if t == forcing.shape[0]:  # the record's last sample: nothing to carry on
            break
        for a in range(n):
            for k in range(m):
                xn[a, k] = 0.0
            for l in range(n):  # the innermost loop runs along contiguous columns
                phi = Phi[a, l]
                if phi == 0:  # Φ is sparse even within a part (roll drives yaw, not back)
                    continue
                for k in range(m):
                    xn[a, k] += phi * x[l, k]
            for i in range(j):
                xn[a, i] += forcing[t, a, i]
        x, xn = xn, x
    if x is not X:  # element by element: an array assignment compiles its shape check's messages
        for a in range(n):
            for k in range(m):
                X[a, k] = x[a, k]


@numba.njit(cache=True, fastmath={"reassoc"})
def adjoint_sum(Phi, F, y, measured, W, P):
    """`b = λ[0][measured]` of the adjoint `λ[k] = Φᵀλ[k+1] + a[k]`, `a[k][measured] = W P[k] (y[k] −
    x[k][measured])` (P[k, j]: 1 where sample k of channel j is present, 0 where it is missing;
    None: every sample present, compiled apart without P), with `x[k+1] = Φ x[k] + F[k]` from
    x[0] = 0: the right-hand side of the initial state's normal equations
    (`testbed.identification.concentrated`)."""
    n, N, c = Phi.shape[0], y.shape[0], len(measured)
    x = np.empty((N, n))
    x[0] = 0.0
    propagate_states(Phi, x, F)
    a = np.zeros((N, n))  # a[N − 1 − k]: the adjoint runs backwards
    for k in range(N):
        for j in range(c):
            if P is None:
                a[N - 1 - k, measured[j]] = W[j] * (y[k, j] - x[k, measured[j]])
            else:
                a[N - 1 - k, measured[j]] = W[j] * P[k, j] * (y[k, j] - x[k, measured[j]])
    lam = x  # λ[N − 1 − k], in x's memory
    for i in range(n):
        lam[0, i] = a[0, i]
    propagate_states(np.ascontiguousarray(Phi.T), lam, a[1:])
    out = np.empty(c)
    for j in range(c):
        out[j] = lam[N - 1, measured[j]]
    return out


@numba.njit(cache=True, fastmath={"reassoc"})
def weighted_sse(Phi, x0, F, y, measured, W, P, explode):
    """`Σ_k Σ_j W_j P[k, j] (y[k, j] − x[k][measured[j]])²` (P as in `adjoint_sum`) along
    `x[k+1] = Φ x[k] + F[k]` from `x0`; −1 where an output is not finite or beyond
    `explode`·max|y_j| + 1 (the model diverged, `testbed.identification.likelihood.exploded`)."""
    N, c = y.shape[0], len(measured)
    bound = np.zeros(c)
    for k in range(N):
        for j in range(c):
            bound[j] = max(bound[j], abs(y[k, j]))
    bound = explode * bound + 1.0
    x = np.empty((N, Phi.shape[0]))
    for i in range(Phi.shape[0]):
        x[0, i] = x0[i]
    propagate_states(Phi, x, F)
    total = 0.0
    for k in range(N):
        for j in range(c):
            v = x[k, measured[j]]
            if not abs(v) <= bound[j]:  # NaN too
                return -1.0
            d = y[k, j] - v
            if P is None:
                total += W[j] * d * d
            else:
                total += W[j] * P[k, j] * d * d
    return total


@numba.njit(cache=True)
def _product(A, B, transpose_a):
    """`A B`, or `Aᵀ B` with `transpose_a`, of square matrices."""
    n = A.shape[0]
    C = np.zeros((n, n))
    for i in range(n):
        for l in range(n):
            a = A[l, i] if transpose_a else A[i, l]
            if a != 0:
                for j in range(n):
                    C[i, j] += a * B[l, j]
    return C


@numba.njit(cache=True)
def gramian(Phi, Q, N):
    """`Σ_{k<N} (Φᵏ)ᵀ Q Φᵏ` by doubling, from the most significant bit of N:
    `S_{2m} = S_m + (Φᵐ)ᵀ S_m Φᵐ` and `S_{m+1} = Q + Φᵀ S_m Φ` (about 2 log₂N steps of three
    products each)."""
    n = Phi.shape[0]
    S, P = np.zeros((n, n)), np.eye(n)  # S_m, Φᵐ for m = 0
    bits = 0
    while N >> bits:
        bits += 1
    for b in range(bits - 1, -1, -1):
        S = S + _product(P, _product(S, P, False), True)
        P = _product(P, P, False)
        if (N >> b) & 1:
            S = Q + _product(Phi, _product(S, Phi, False), True)
            P = _product(P, Phi, False)
    return S


@numba.njit(cache=True)
def masked_gramian(Phi, measured, W, P):
    """`Σ_k (C Φᵏ)ᵀ diag(W P[k]) C Φᵏ` restricted to the `measured` columns (c, c), C the rows
    `measured` of the identity, P as in `adjoint_sum`: a record's observability Gramian with its
    missing samples left out. Where fewer than half the samples are missing, the whole record's
    Gramian (`gramian`, by doubling) less the missing samples' terms, else the present samples'
    terms summed; either way the rows C Φᵏ are propagated sample by sample, Φ's zeros skipped
    (a torpedo's Φ is two uncoupled blocks), up to the last sample that has a term."""
    n, c, N = Phi.shape[0], len(measured), P.shape[0]
    missing, last_missing, last_present = 0, -1, -1
    for k in range(N):
        for l in range(c):
            if P[k, l] == 0:
                missing += 1
                last_missing = k
            else:
                last_present = k
    subtract = 2 * missing < N * c
    A = np.zeros((c, c))
    if subtract:
        Q = np.zeros((n, n))
        for j in range(c):
            Q[measured[j], measured[j]] = W[j]
        G = gramian(Phi, Q, N)
        for i in range(c):
            for j in range(c):
                A[i, j] = G[measured[i], measured[j]]
    last = last_missing if subtract else last_present
    R, Rn = np.zeros((c, n)), np.empty((c, n))  # C Φᵏ
    for j in range(c):
        R[j, measured[j]] = 1.0
    for k in range(last + 1):
        for l in range(c):
            if (P[k, l] == 0) != subtract or W[l] == 0:
                continue
            wl = -W[l] if subtract else W[l]
            for i in range(c):
                ri = wl * R[l, measured[i]]
                for j in range(i, c):
                    A[i, j] += ri * R[l, measured[j]]
        if k == last:
            break
        Rn[:, :] = 0.0
        for a in range(n):
            for b in range(n):
                phi = Phi[a, b]
                if phi == 0:
                    continue
                for j in range(c):
                    Rn[j, b] += R[j, a] * phi
        R, Rn = Rn, R
    for i in range(c):  # the terms went to the upper triangle: mirrored
        for j in range(i):
            A[i, j] = A[j, i]
    return A


@numba.njit(cache=True, fastmath={"reassoc"})
def concentrated_sse(Phi, Gamma, s, inputs, y, P, complete, starts, measured, counts, W, explode, condition):
    """`Σ_records Σ_k Σ_j W_rj P[k, j] (y[k, j] − x[k][measured[r, j]])²` with each record's
    initial state at its best (`testbed.identification.concentrated`): the records stacked in
    `inputs`, `y` and `P` (record r the rows `starts[r]:starts[r+1]`, its `counts[r]` measured
    states the first columns of y, `measured[r]`, their weights `W[r]`; P 1 where a sample is
    present, 0 where it is missing, `complete[r]` where record r misses none),
    `x[k+1] = Φ x[k] + Γ δ[k] + s`. Per record `adjoint_sum`, the Gramian (`gramian`, or
    `masked_gramian` for a record with missing samples) scaled to a unit diagonal, x0 from the
    normal equations and `weighted_sse`. −1 where the outputs diverge (`weighted_sse`), −2 where
    a scaled Gramian's condition number exceeds `condition` (x0 then wants a QR solve)."""
    n, total = Phi.shape[0], 0.0
    for r in range(len(starts) - 1):
        a, b, c = starts[r], starts[r + 1], counts[r]
        N, m, w = b - a, measured[r, :c], W[r, :c]
        yr, Pr = y[a:b, :c], P[a:b, :c]
        F = np.empty((N - 1, n))
        for k in range(N - 1):  # F[k] = Γ δ[k] + s
            for i in range(n):
                acc = s[i]
                for j in range(Gamma.shape[1]):
                    acc += Gamma[i, j] * inputs[a + k, j]
                F[k, i] = acc
        if complete[r]:
            rhs = adjoint_sum(Phi, F, yr, m, w, None)
            Q = np.zeros((n, n))
            for j in range(c):
                Q[m[j], m[j]] = w[j]
            G = gramian(Phi, Q, N)
            A = np.empty((c, c))
            for i in range(c):
                for j in range(c):
                    A[i, j] = G[m[i], m[j]]
        else:
            rhs = adjoint_sum(Phi, F, yr, m, w, Pr)
            A = masked_gramian(Phi, m, w, Pr)
        D = np.sqrt(np.diag(A).copy())  # unit diagonal: x0's units do not count
        for i in range(c):
            for j in range(c):
                A[i, j] /= D[i] * D[j]
        bounds = np.linalg.eigvalsh(A)
        if not bounds[0] * condition >= bounds[-1]:  # NaN too
            return -2.0
        x0m = solve_spd(A, rhs / D) / D  # A is positive definite (a Gramian, its condition checked)
        x0 = np.zeros(n)
        for j in range(c):
            x0[m[j]] = x0m[j]
        if complete[r]:
            sse = weighted_sse(Phi, x0, F, yr, m, w, None, explode)
        else:
            sse = weighted_sse(Phi, x0, F, yr, m, w, Pr, explode)
        if not sse >= 0:
            return -1.0
        total += sse
    return total
