"""Structural identifiability of the paper's linear model.

The paper's simultaneous drift. Left-multiplying the rows of
`Mt ẋ = At x + Bt δ + St` by T = I + E, and changing state coordinates x → (I + F) x with
C F = 0 (only unmeasured states move), leave the measured outputs unchanged. A coefficient
direction dθ is exactly unidentifiable when some (E, F) reproduces it while every fixed entry of
the model stays put; to first order that is the null space of a linear map, computed here
(`structural`), with its drift groups.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from testbed.identification.problem import base_name
from testbed.models.linear import ITHETA, IX, NX, Structure, tilde, unobserved

__all__ = ["Structural", "copied", "drift_groups_of", "rref", "structural"]


@dataclass(frozen=True)
class Structural:
    """Exactly unidentifiable directions: `basis` (k × len(free)) in reduced row echelon form;
    `unobserved`: the free coefficients no measured state depends on (`model.unobserved`), each
    an unidentifiable direction of its own."""

    free: tuple[str, ...]
    basis: np.ndarray
    drift_groups: tuple[tuple[str, ...], ...]
    unobserved: tuple[str, ...] = ()

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
    G[:, 2 * NX * NX :] *= scale
    G /= np.maximum(np.linalg.norm(G, axis=1, keepdims=True), 1e-300)
    _, sv, vt = np.linalg.svd(G, full_matrices=len(G) < G.shape[1])  # the null space: right
    # singular vectors beyond the rank
    N = vt[np.sum(sv > tol * sv.max(initial=0.0)) :].T
    D = N[2 * NX * NX :]  # dθ components of the null vectors
    blind = unobserved(s, theta, free, measured)
    V = np.eye(k)[[free.index(n) for n in blind]]  # (scaled) directions of the unobserved ones
    if D.size:
        _, sv, vt = np.linalg.svd(D.T, full_matrices=False)
        V = np.vstack([vt[sv > 1e-6], V])
    if not len(V):
        return Structural(free, np.zeros((0, len(free))), ())
    _, sv, vt = np.linalg.svd(V, full_matrices=False)  # an orthonormal basis of their span
    # Back to coefficient units; the reduced basis is unique and sparse, so groups do not merge.
    basis = rref(vt[sv > 1e-6] * scale)
    return Structural(free, basis, drift_groups_of(free, basis), blind)


def rref(V: np.ndarray, tol: float = 1e-9) -> np.ndarray:
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


def drift_groups_of(names, basis, tol: float = 1e-6) -> tuple[tuple[str, ...], ...]:
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


def copied(struct: Structural, free: tuple[str, ...]) -> Structural:
    """`struct`, found for names of a config's free list, for its values `free` (a per-record
    name once per record; the names `struct` leaves out, outside every direction): a direction no
    data see moves every record's copy alike."""
    if free == struct.free:
        return struct
    basis = np.zeros((len(struct.basis), len(free)))
    for j, n in enumerate(free):
        if base_name(n) in struct.free:
            basis[:, j] = struct.basis[:, struct.free.index(base_name(n))]

    def copies(names):
        return tuple(n for n in free if base_name(n) in names)

    return Structural(free, basis, tuple(copies(g) for g in struct.drift_groups), copies(struct.unobserved))
