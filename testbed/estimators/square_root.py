"""The square-root filter's algebra (the paper's §5), pure numpy: triangularisation `tria`
(`L Lᵀ = X Xᵀ`), the joint measurement update of a root `sqrt_update`, and the SVD root.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

__all__ = ["sqrt_update", "svd_root", "tria"]


def tria(X: np.ndarray) -> np.ndarray:
    """Lower-triangular L with a non-negative diagonal and `L Lᵀ = X Xᵀ`; X is (n, k ≥ n)."""
    L = np.linalg.qr(X.T, mode="r").T
    return L * np.where(np.diag(L) < 0, -1.0, 1.0)


@lru_cache(maxsize=None)
def _tri(n: int) -> np.ndarray:
    """The (n, n) lower-triangular mask (cached: the filter takes triangles every sample)."""
    return np.tri(n)


def sqrt_update(pre: np.ndarray, m: int, nu: np.ndarray):
    """The array-form measurement update, the filter's own kernel (module docstring).

    `pre` is the pre-array `[[Rh, C J⁻], [0, J⁻]]` ((m + n, m + k), zero-padded on the right
    is fine): `Cov v = Rh Rhᵀ` for `y = C x + v`, `J⁻` (n, k ≥ n) any root of the prior (the
    rectangular `[F J, Q½]` straight from the time update, or a triangular one). One QR gives
    `[[L, 0], [K̄, J⁺]]`; `nu` is the innovation ν (m,), or (m, j) columns of them.

    Returns `(K ν, L⁻¹ ν, L, J⁺)`: the state correction (`K = K̄ L⁻¹`; `nu = I` gives K), the
    whitened innovation, the innovation root (`L Lᵀ = C P⁻ Cᵀ + R`) and the lower-triangular
    posterior root (`J⁺J⁺ᵀ = P⁻ − K C P⁻`); the diagonals' signs are as the QR left them.
    """
    r = pre.shape[0]
    h = np.linalg.qr(pre.T, mode="raw")[0]  # its lower triangle: [[L, 0], [K̄, J⁺]]
    L = h[:m, :m] * _tri(m)
    w = np.linalg.solve(L, nu)
    return h[m:, :m] @ w, w, L, h[m:, m:r] * _tri(r - m)


def svd_root(X: np.ndarray) -> np.ndarray:
    """`U Σ` from the SVD of X (n, k ≥ n): an (n, n) root of `X Xᵀ` (option `sqrt="svd"`)."""
    U, sv = np.linalg.svd(X, full_matrices=False)[:2]
    return U * sv
