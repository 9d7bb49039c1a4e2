"""Small symmetric positive definite systems solved inside compiled kernels, by Cholesky in scalar
loops: numpy's `linalg.solve` compiles LAPACK's wrapper and its shape checks' messages, which cost
a kernel's first compile more than the rest of it."""

import numba
import numpy as np

__all__ = ["solve_spd"]


@numba.njit(no_cpython_wrapper=True, no_cfunc_wrapper=True)  # only called from compiled code
def solve_spd(H, b):
    """x = H⁻¹ b for a small symmetric positive definite H, by Cholesky H = L Lᵀ (in place: H
    holds L, b holds x)."""
    n = b.shape[0]
    for j in range(n):
        s = H[j, j]
        for m in range(j):
            s -= H[j, m] * H[j, m]
        H[j, j] = np.sqrt(s)
        for i in range(j + 1, n):
            s = H[i, j]
            for m in range(j):
                s -= H[i, m] * H[j, m]
            H[i, j] = s / H[j, j]
    for i in range(n):  # L y = b
        s = b[i]
        for m in range(i):
            s -= H[i, m] * b[m]
        b[i] = s / H[i, i]
    for i in range(n - 1, -1, -1):  # Lᵀ x = y
        s = b[i]
        for m in range(i + 1, n):
            s -= H[m, i] * b[m]
        b[i] = s / H[i, i]
    return b
