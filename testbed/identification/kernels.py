"""The recursions of `testbed.identification.scan` compiled (numba), for optimisers that simulate
thousands of times: loading the compiler costs about 0.35 s once per process (its import and its compiled
code read back from the cache), which a simplex search wins back many times over and a single
Gauss-Newton fit of a measurement file does not (`scan.compiled`).

Each computes what `scan.Scan` computes, sample by sample: numpy's per-call overhead on a
10×10 product is ~50× the arithmetic, a compiled loop has none.
"""

import numba
import numpy as np

__all__ = ["propagate", "recursion"]


@numba.njit(cache=True)
def propagate(Phi, x, F):
    """`x[k+1] = Φ x[k] + F[k]` in place for k < len(F), from `x[0]`."""
    n = x.shape[1]
    for k in range(F.shape[0]):
        for i in range(n):
            acc = F[k, i]
            for l in range(n):
                acc += Phi[i, l] * x[k, l]
            x[k + 1, i] = acc


@numba.njit(cache=True)
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
    if x is not X:
        X[:, :] = x
