"""The paper's eight-step Nelder-Mead simplex (`simplex_run`), its coefficients, a fresh
simplex and the coordinates a run moves in (`run_frame`: scaled by the start, or whitened by the
information): the search `ml-nm` runs on the linear model's likelihood and on the nonlinear
model's."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from testbed.estimators.box_bounds import into_box
from testbed.identification.bounds import NULL

__all__ = ["Frame", "STEPS", "fresh_simplex", "run_frame", "simplex_coefficients", "simplex_run"]

# the first simplex's edge and a later run's, per coordinates: Cramér-Rao σ (information) or
# fractions of |θ_i,start| (scaled)
STEPS = {"information": (1.0, 0.1), "scaled": (0.1, 0.02)}


def simplex_coefficients(kind: str, m: int) -> tuple[float, float, float, float]:
    """Reflection, expansion, contraction and shrink coefficients in m dimensions: the paper's
    (1, 2, ½, ½), or Gao & Han's dimension-adaptive (1, 1 + 2/m, ¾ − 1/(2m), 1 − 1/m), which
    equal the paper's for m = 2."""
    if kind == "paper" or m < 2:
        return 1.0, 2.0, 0.5, 0.5
    return 1.0, 1.0 + 2.0 / m, 0.75 - 0.5 / m, 1.0 - 1.0 / m


def fresh_simplex(x: np.ndarray, size: float) -> np.ndarray:
    """A fresh simplex (m + 1, m): `x` and `x + size·e_i` for each axis i."""
    return np.vstack([x, x + size * np.eye(len(x))])


def simplex_run(
    J, simplex: np.ndarray, coefficients, tol: float, it: int, max_iter: int, report
) -> tuple[np.ndarray, np.ndarray, int, bool]:
    """One run of the paper's eight steps from the corners `simplex` (m + 1, m), their J
    evaluated first.

    `report(it, best corner, its J)` after each iteration; a true return stops the run there.
    Returns the corners where it stopped (the lowest first), their J, the iteration count
    (continued from `it`) and whether the stopping rule (step 3, spread ≤ `tol`) stopped it
    rather than `max_iter` or `report`.
    """
    alpha, gamma, beta, delta = coefficients
    m = simplex.shape[1]
    simplex = simplex.copy()
    J_i = np.array([J(v) for v in simplex])
    stopped = False
    while it < max_iter:
        # 1. the highest and lowest corners
        hi, lo = int(np.argmax(J_i)), int(np.argmin(J_i))
        # 2. the centroid of all corners but the highest
        b = (simplex.sum(0) - simplex[hi]) / m
        # 3. stopping rule: {1/(m+1) Σ (J_i − J_b)²}^½ ≤ ε (a diverged corner, J = ∞, makes it
        #    ∞ or NaN: not stopped). The spread is at least the corners' own standard deviation
        #    (its minimum over J_b, at their mean): J_b is computed only where that does not
        #    already decide, which leaves the rule as it is at one simulation less per iteration
        with np.errstate(over="ignore", invalid="ignore"):
            if np.std(J_i) <= tol and np.sqrt(np.mean((J_i - J(b)) ** 2)) <= tol:
                stopped = True
                break
        it += 1
        # 4. reflection: θ_r = θ_b + α(θ_b − θ_h)
        r = b + alpha * (b - simplex[hi])
        J_r = J(r)
        if J_r < J_i[lo]:
            # 5. expansion: θ_e = θ_b + γ(θ_r − θ_b)
            e = b + gamma * (r - b)
            J_e = J(e)
            simplex[hi], J_i[hi] = (e, J_e) if J_e < J_i[lo] else (r, J_r)
        elif not np.all(J_r >= np.delete(J_i, hi)):
            # 6. better than some corner other than the highest
            simplex[hi], J_i[hi] = r, J_r
        else:
            # 7. contraction, on the reflected side if it beats the highest:
            #    θ_c = θ_b + β(θ_r − θ_b), else θ_c = θ_b + β(θ_h − θ_b)
            c = b + beta * ((r if J_r < J_i[hi] else simplex[hi]) - b)
            J_c = J(c)
            if J_c < J_i[hi]:
                # 8. accept the contraction ...
                simplex[hi], J_i[hi] = c, J_c
            else:
                # ... or shrink towards the lowest corner: θ_i = θ_l + δ(θ_i − θ_l)
                simplex = simplex[lo] + delta * (simplex - simplex[lo])
                J_i = np.array([J_i[lo] if i == lo else J(v) for i, v in enumerate(simplex)])
        lo = int(np.argmin(J_i))
        if report(it, simplex[lo], float(J_i[lo])):  # the caller's own reason to stop here
            break
    order = np.argsort(J_i, kind="stable")
    return simplex[order], J_i[order], it, stopped


@dataclass(frozen=True)
class Frame:
    """The simplex's coordinates x: θ = origin + T x, T a matrix or (a vector) a diagonal,
    moved onto the `box` (None: none) where it lies outside."""

    origin: np.ndarray
    T: np.ndarray
    box: tuple | None = None

    def _raw(self, x: np.ndarray) -> np.ndarray:
        return self.origin + (self.T * x if self.T.ndim == 1 else self.T @ x)

    def theta(self, x: np.ndarray) -> np.ndarray:
        return into_box(self._raw(x), self.box)

    def x(self, theta: np.ndarray) -> np.ndarray:
        d = theta - self.origin
        return d / self.T if self.T.ndim == 1 else np.linalg.solve(self.T, d)

    def outside(self, x: np.ndarray) -> float:
        """‖x − x(θ on the box)‖²: how far outside the box the corner x lies, in the simplex's
        units (Cramér-Rao σ in the information's frame), 0 inside."""
        raw = self._raw(x)
        inside = into_box(raw, self.box)
        return 0.0 if np.array_equal(inside, raw) else float(np.sum((x - self.x(inside)) ** 2))


def run_frame(
    coordinates: str,
    theta: np.ndarray,
    scale: np.ndarray,
    box: tuple | None,
    information: Callable[[], np.ndarray | None],
) -> Frame:
    """The coordinates of a simplex run from θ, moved onto `box`: "scaled", x = θ/`scale`; or
    "information", whitened by `information()`, the information of θ there (the initial states
    solved for; None where it cannot be computed), asked for only then (`_whitened`)."""
    if coordinates == "scaled":
        return Frame(np.zeros(len(theta)), scale, box)
    return replace(_whitened(information(), theta, scale), box=box)


def _whitened(F: np.ndarray | None, theta: np.ndarray, scale: np.ndarray) -> Frame:
    """Coordinates centred at θ in which the information `F` there (θ's, the initial states
    solved for) is the identity: a unit step is one Cramér-Rao σ along each principal direction,
    so the cost's valleys are round for the simplex. With `D F D = V Λ Vᵀ` (D = 1/√diag F),
    `T = D V Λ^-½`; a direction the data hardly determine is searched no farther than its
    coefficients' own size (`scale`: T's column at most unit length in θ/scale). The coordinates
    scaled by `scale` (origin 0) where F is None or not finite with a positive diagonal."""
    if F is None or not np.all(np.isfinite(F)) or not np.all(np.diag(F) > 0):
        return Frame(np.zeros(len(theta)), scale)
    D = 1.0 / np.sqrt(np.diag(F))
    lam, V = np.linalg.eigh(F * np.outer(D, D))
    lam = np.maximum(lam, NULL * max(lam.max(), 1e-300))
    T = D[:, None] * V / np.sqrt(lam)
    # T = D V Λ^-½, each column at most as long as the coefficients' own size
    T /= np.maximum(np.linalg.norm(T / scale[:, None], axis=0), 1.0)
    return Frame(theta.copy(), T)
