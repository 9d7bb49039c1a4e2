"""Identifiability of the paper's linear model (issue 4, items 5 and 8).

Structural part: the paper's simultaneous drift. Left-multiplying the rows of
`Mt ẋ = At x + Bt δ + St` by T = I + E, and changing state coordinates x → (I + F) x with
C F = 0 (only unmeasured states move), leave the measured outputs unchanged. A coefficient
direction dθ is exactly unidentifiable when some (E, F) reproduces it while every fixed entry of
the model stays put; to first order that is the null space of a linear map, computed here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import null_space

from testbed.model import COEFFICIENTS, ITHETA, IX, NX, Structure, tilde


@dataclass(frozen=True)
class Structural:
    """Exactly unidentifiable directions: `basis` (k × len(free)), orthonormal rows."""

    free: tuple[str, ...]
    basis: np.ndarray
    drift_groups: tuple[tuple[str, ...], ...]

    @property
    def null_directions(self) -> int:
        return len(self.basis)


def structural(s: Structure, theta: np.ndarray, free, measured, tol: float = 1e-9) -> Structural:
    """Null directions of the coefficients `free` at `theta` (35,) when `measured` states are output.

    Unknowns (vec E, vec F, dθ_free); constraints: E Mt + Mt F = Σ dθ_i ∂Mt/∂θ_i, likewise At,
    E Bt = Σ dθ_i ∂Bt/∂θ_i, E St = 0 (restoring terms known), C F = 0. dθ is scaled by the
    coefficient magnitudes so the tolerance is relative.
    """
    free = tuple(free)
    idx = np.array([ITHETA[n] for n in free], dtype=int)
    Mt, At, Bt, St = tilde(s, theta)
    scale = np.maximum(np.abs(theta[idx]), 1e-3 * max(np.abs(theta).max(), 1.0))
    I, k = np.eye(NX), len(idx)
    C = I[[IX[n] for n in measured]]
    # Row-major vec: vec(E X) = (I ⊗ Xᵀ) vec E, vec(X F) = (X ⊗ I) vec F.
    blocks = [  # (E part, F part, dθ part) for each group of model entries
        (np.kron(I, Mt.T), np.kron(Mt, I), -s.dMt[idx].reshape(k, -1).T),
        (np.kron(I, At.T), np.kron(At, I), -s.dAt[idx].reshape(k, -1).T),
        (np.kron(I, Bt.T), np.zeros((Bt.size, NX * NX)), -s.dBt[idx].reshape(k, -1).T),
        (np.kron(I, St[None, :]), np.zeros((NX, NX * NX)), -s.dSt[idx].reshape(k, -1).T),
        (np.zeros((len(C) * NX, NX * NX)), np.kron(C, I), np.zeros((len(C) * NX, k))),
    ]
    G = np.hstack([np.vstack([b[j] for b in blocks]) for j in range(3)])
    G[:, 2 * NX * NX:] *= scale
    G /= np.maximum(np.linalg.norm(G, axis=1, keepdims=True), 1e-300)
    N = null_space(G, rcond=tol)
    D = N[2 * NX * NX:]  # dθ components of the null vectors
    if D.size == 0:
        return Structural(free, np.zeros((0, len(free))), ())
    _, sv, vt = np.linalg.svd(D.T, full_matrices=False)
    # Back to coefficient units; the reduced basis is unique and sparse, so groups do not merge.
    basis = _rref(vt[sv > 1e-6] * scale)
    return Structural(free, basis, _groups(free, basis))


def _rref(V: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    """Reduced row echelon form of the full-row-rank `V` (unique for its row space)."""
    R = V.copy()
    row = 0
    for col in range(R.shape[1]):
        if row == len(R):
            break
        piv = row + np.argmax(np.abs(R[row:, col]))
        if abs(R[piv, col]) < tol:
            continue
        R[[row, piv]] = R[[piv, row]]
        R[row] /= R[row, col]
        others = np.arange(len(R)) != row
        R[others] -= np.outer(R[others, col], R[row])
        row += 1
    R[np.abs(R) < tol] = 0.0
    return R


def _groups(names, basis, tol: float = 1e-6) -> tuple[tuple[str, ...], ...]:
    """Connected components of the coefficients sharing a null vector."""
    parent = list(range(len(names)))

    def find(i):
        while parent[i] != i:
            i = parent[i]
        return i

    involved = set()
    for v in basis:
        nz = np.flatnonzero(np.abs(v) > tol)
        involved.update(nz.tolist())
        for j in nz[1:]:
            parent[find(j)] = find(nz[0])
    groups = {}
    for i in sorted(involved):
        groups.setdefault(find(i), []).append(names[i])
    return tuple(tuple(g) for g in groups.values())
