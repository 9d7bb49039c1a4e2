"""The linear recursion `X[t+1] = Φ X[t] + F[t]` over the samples of a record, the engine under
every simulation and sensitivity of the output-error fit.

Every recursion runs in numpy, in blocks of samples (`Scan`), and this module imports nothing
but numpy: a command that fits a CSV starts without loading a compiler or scipy. Optimisers that
simulate thousands of times run them compiled instead (`compiled`, `testbed.identification.kernels`).
Sensitivities are made a thousand samples at a time (`pieces`) and never held whole: fresh memory
pages, whose first writes fault, cost more than the arithmetic.
"""

from __future__ import annotations

import contextlib
import contextvars
import math
from typing import Iterator

import numpy as np

__all__ = ["PIECE", "Scan", "compiled", "pieces", "propagate"]

PIECE = 1024  # samples per piece of sensitivities (`pieces`): a piece's work arrays stay in the CPU's cache

_KERNELS = contextvars.ContextVar(
    "kernels", default=None
)  # testbed.identification.kernels within `compiled()`


@contextlib.contextmanager
def compiled():
    """Within this context the recursions over the samples run compiled (`testbed.identification.kernels`), for
    optimisers that simulate thousands of times; outside it, in numpy blocks (`Scan`), which
    need no compiler loaded: a process that fits one file is done before numba would be."""
    from testbed.identification import kernels

    token = _KERNELS.set(kernels)
    try:
        yield
    finally:
        _KERNELS.reset(token)


def propagate(Phi: np.ndarray, x0: np.ndarray, F: np.ndarray) -> np.ndarray:
    """`x[k+1] = Φ x[k] + F[k]` from `x[0] = x0` (n,); returns (len(F) + 1, n)."""
    dtype = np.result_type(Phi, x0, F)  # complex under the complex-step tests
    n, N = len(x0), len(F) + 1
    x = np.empty((N, n), dtype=dtype)
    kernels = _KERNELS.get()
    if kernels is not None:
        x[0] = x0
        kernels.propagate_states(np.ascontiguousarray(Phi, dtype), x, np.ascontiguousarray(F, dtype))
        return x
    order, Y, _ = Scan(np.asarray(Phi, dtype), 1, 1, np.arange(n), N)(
        np.asarray(x0, dtype)[:, None], np.asarray(F, dtype)[:, :, None], N
    )
    x[order] = Y[:, :, 0].T
    return x


class Scan:
    """`X[t+1] = Φ X[t] + F[t]` over pieces of at most `size` samples, X[t] (n, m) with only the
    first j columns of F[t] nonzero. A call `(X0, f, P)` takes the piece's first state `X0`
    (n, m) and its forcings `f[t]` (the first j columns of F[t]; P − 1 or P of them, (·, n, j))
    and gives `(order, Y, carry)`: `Y[c, k] = X[order[k]][rows[c]]` for the P samples of the
    piece in the order `order` (len(rows), P, m; valid until the next call), and X[P] if f has P
    forcings (else None).

    In chunks of L ≈ √size samples, t = bL + i. All chunks advance together from a zero state,
    one product per step for all of them: `Z_i = Φ Z_{i−1} + F` (Z_i[b]: the response at bL + i
    to chunk b's own forcing, zero in the unforced columns, which are left out), as
    `[Φ I] [Z_{i−1}; F]`. The chunks' first states then follow one from the other,
    `X[(b+1)L] = Φᴸ X[bL] + Z_L[b]`, and `X[bL + i] = Φⁱ X[bL] + Z_i[b]` is one product for all
    samples, ordered by i, then b. That is about twice the arithmetic of stepping sample by
    sample, in 2√P products of n × B·m blocks instead of P products of n × m blocks, whose
    per-call overhead in numpy would be ~50× the arithmetic. The powers of Φ and the work arrays
    are made once, for every call.
    """

    def __init__(self, Phi: np.ndarray, j: int, m: int, rows: np.ndarray, size: int):
        n, c, dtype = len(Phi), len(rows), Phi.dtype
        self.Phi, self.j, self.m, self.rows = Phi, j, m, rows
        self.L = L = max(1, math.isqrt(size))
        B = -(-size // L)
        self.power = np.empty((L + 1, n, n), dtype=dtype)  # Φⁱ
        self.power[0] = np.eye(n)
        for i in range(1, L + 1):
            self.power[i] = Phi @ self.power[i - 1]
        self.step = np.hstack([Phi, np.eye(n, dtype=dtype)])  # [Φ I]
        self.rows_power = self.power[:L][:, rows].transpose(1, 0, 2).reshape(c * L, n)  # Φⁱ[rows[c]]
        self.W = np.empty((L + 1, 2 * n, B * j), dtype=dtype)  # W[i] = [Z_i; F at bL + i]: one operand
        self.start = np.empty((B + 1, n, m), dtype=dtype)  # X[bL]
        self.Y = np.empty((c * L, B * m), dtype=dtype)
        self.order = (np.arange(L)[:, None] + L * np.arange(B)).ravel()

    def __call__(self, X0: np.ndarray, f: np.ndarray, P: int):
        L, j, m, n, c = self.L, self.j, self.m, len(self.Phi), len(self.rows)
        B, T = -(-P // L), len(f)
        W = self.W[:, :, : B * j]
        forcing = W[:L, n:].reshape(L, n, B, j)  # [i, a, b] = F[bL + i][a]
        full, rest = divmod(T, L)
        forcing[:, :, :full] = f[: full * L].reshape(full, L, n, j).transpose(1, 2, 0, 3)
        if full < B:
            forcing[:rest, :, full] = f[full * L :]
            forcing[rest:, :, full] = 0.0
            forcing[:, :, full + 1 :] = 0.0
        W[0, :n] = 0.0
        for i in range(1, L + 1):
            np.matmul(self.step, W[i - 1], out=W[i, :n])
        Z = W[:, :n].reshape(L + 1, n, B, j)
        start = self.start[: B + 1]
        start[0] = X0
        for b in range(B):
            np.matmul(self.power[L], start[b], out=start[b + 1])
            start[b + 1, :, :j] += Z[L, :, b]
        # Y[c, i, b] = Φⁱ[rows[c]] X[bL] + Z_i[b][rows[c]]
        Y = np.matmul(self.rows_power, start[:B].transpose(1, 0, 2).reshape(n, B * m), out=self.Y[:, : B * m])
        Y = Y.reshape(c, L, B, m)
        Y[..., :j] += Z[:L, self.rows].transpose(1, 0, 2, 3)
        order = self.order.reshape(L, -1)[:, :B]
        if B * L == P:
            Y, order = Y.reshape(c, L * B, m), order.ravel()
        else:  # the piece's own samples only
            keep = order < P
            Y, order = Y[:, keep], order[keep]
        carry = None
        if T >= P:
            b, i = divmod(P, L)
            carry = self.power[i] @ start[b]
            if i:
                carry[:, :j] += Z[i, :, b]
        return order, Y, carry


def pieces(
    Phi: np.ndarray, D: np.ndarray, w: np.ndarray, X: np.ndarray, rows, scale: np.ndarray, size: int
) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Rows `rows` of X[t], times `scale`, for `X[t+1] = Φ X[t] + F[t]` from `X[0] = X` (n, m),
    where F[t]'s first j columns are `(D w[t])` reshaped (n, j) (D: (n·j, len(w[t]))) and the
    others zero: in consecutive pieces of at most `size` samples, `(samples, S)` with
    `S[c, k] = scale[c] X[samples[k]][rows[c]]` (len(rows), len(samples), m; valid until the
    next piece), made by `Scan` (`kernels.recursion` within `compiled()`) from the last state of
    the piece before. Made and used a piece
    at a time (F too), in arrays reused from piece to piece, neither is ever allocated for all N
    samples: fresh memory pages cost more here than the arithmetic, as their first writes
    fault."""
    N, dtype, n = len(w), X.dtype, len(Phi)
    rows, scale = np.asarray(rows, np.int64), np.asarray(scale, float)[:, None, None]
    DT, j = np.asarray(D.T, dtype), len(D) // n
    size = -(-N // -(-N // size))  # pieces of equal length, none longer than `size`
    kernels = _KERNELS.get()
    if kernels is None:
        scan = Scan(np.asarray(Phi, dtype), j, X.shape[1], rows, size)
    else:
        Phi, X = np.ascontiguousarray(Phi, dtype), X.astype(dtype)  # X carried on in place
        work = np.empty(len(rows) * size * X.shape[1], dtype=dtype)
    for t0 in range(0, N, size):
        t1 = min(t0 + size, N)
        f = w[t0 : min(t1, N - 1)] @ DT  # the last piece has no forcing after the record's end
        f = f.reshape(len(f), n, j)
        if kernels is None:
            order, S, X = scan(X, f, t1 - t0)
        else:  # the first len(rows)·P·m entries of `work`: contiguous for any P
            order = np.arange(t1 - t0)
            S = work[: len(rows) * len(order) * X.shape[1]].reshape(len(rows), len(order), -1)
            kernels.recursion(Phi, f, X, rows, S)
        S *= scale
        yield t0 + order, S
