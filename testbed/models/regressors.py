"""The nonlinear model's hydrodynamic terms: named products of the motion and the fin angles.

A term is a force or moment row and a product of factors, named as the submarine equations
name them: `Y_uv` is Y_uv·u·v in the sway row, `N_v|v|` is N_v|v|·v·|v| in the yaw row,
`Z_uude` is Z_uude·u²·δe. The letter before the underscore is the row (X Y Z K M N: surge, sway,
heave, roll, pitch, yaw); after it, the factors, each one of

    u v w p q r      the body velocities (u the absolute surge speed) and rates
    dr de da         the rudder δr, the elevators' mean δe = (δer + δel)/2 and half their
                     difference δa = (δer − δel)/2 (the ailerons' action in roll)
    |x|              the magnitude of any of those (x|x| is the usual cross-flow form)
    |vw| |qr|        the magnitudes of the cross flow, √(v² + w²), and of the cross-flow turn
                     rate, √(q² + r²): a body of revolution's drag acts along the whole cross
                     flow, so its sway force is v·√(v² + w²), not v·|v| + v·|w|

The model is linear in the terms' coefficients: its forces are Σ θ_k φ_k(ν, δ) with the regressor
φ_k the term's product (`regressors`), whose gradient with respect to (ν, δ) (`gradients`) is
exact by the product rule. Both take complex arrays for complex-step derivatives: |x| is x or −x
by the sign of x's real part, so its derivative is sign(x), as for real x (taken as 0 at x = 0);
√(a² + b²) is the principal square root, analytic off a = b = 0, its derivative (a, b)/√(a² + b²)
(taken as 0 at a = b = 0).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from testbed.errors import InputError

__all__ = ["ATOMS", "ROWS", "Term", "gradients", "magnitude", "parse_term", "regressors"]

ROWS = "XYZKMN"  # force/moment letter of the body rows u v w p q r
# The factors a term multiplies, each a linear combination of z = (u v w p q r δr δer δel), or
# the magnitude of one: its weights on z.
_LINEAR = {
    **{s: np.eye(9)[i] for i, s in enumerate("uvwpqr")},
    "dr": np.eye(9)[6],
    "de": 0.5 * (np.eye(9)[7] + np.eye(9)[8]),
    "da": 0.5 * (np.eye(9)[7] - np.eye(9)[8]),
}
# The magnitudes of pairs of body velocities: the atom and the indices of its pair in z
_PAIRS = {"|vw|": (1, 2), "|qr|": (4, 5)}
ATOMS = tuple(_LINEAR) + tuple(f"|{a}|" for a in _LINEAR) + tuple(_PAIRS)
_TOKEN = re.compile(r"\|(?:vw|qr|d[rea]|[uvwpqr])\||d[rea]|[uvwpqr]")


@dataclass(frozen=True)
class Term:
    """One hydrodynamic term: its name, its body row (0..5: X..N) and its factors (`ATOMS`)."""

    name: str
    row: int
    factors: tuple[str, ...]


def parse_term(name: str) -> Term:
    """The term named `name` (e.g. `Y_uv`, `N_v|v|`, `M_uude`); `InputError` if it is not one."""
    row, _, rest = str(name).partition("_")
    tokens = _TOKEN.findall(rest)
    if len(row) != 1 or row not in ROWS or not tokens or "".join(tokens) != rest:
        raise InputError(
            f"term {name!r}: expected a row letter ({' '.join(ROWS)}), '_' and a product of "
            f"factors among {' '.join(ATOMS)} (e.g. Y_uv, N_v|v|, Z_uude)"
        )
    return Term(name=str(name), row=ROWS.index(row), factors=tuple(tokens))


def magnitude(x):
    """|x| that complex steps see through: x or −x by the sign of x's real part."""
    return np.where(np.real(x) >= 0, x, -x)


_WEIGHTS = np.array(list(_LINEAR.values())).T  # (9, 9): z ↦ the linear atoms' values


@lru_cache(maxsize=64)
def _table(terms: tuple[Term, ...]) -> np.ndarray:
    """(K, F): each term's factors as indices into `ATOMS`, padded with len(ATOMS), the constant 1."""
    width = max((len(t.factors) for t in terms), default=1)
    table = np.full((len(terms), width), len(ATOMS), dtype=int)
    for k, t in enumerate(terms):
        table[k, : len(t.factors)] = [ATOMS.index(a) for a in t.factors]
    return table


def _atoms(nu, delta):
    """Each atom's value (n, A + 1), the last atom being the constant 1, and its gradient with
    respect to z = (ν, δ) (n, A + 1, 9)."""
    z = np.concatenate([np.atleast_2d(nu), np.atleast_2d(delta)], axis=1)
    n = len(z)
    value = z @ _WEIGHTS
    # |x|'s gradient sign(x), 0 at x = 0: the mean of its one-sided slopes, so that an even
    # term (u|v|) has no linear part at v = 0, as its central differences say
    sign = np.sign(np.real(value))
    pairs = [np.sqrt(z[:, i] ** 2 + z[:, j] ** 2) for i, j in _PAIRS.values()]
    one = np.ones((n, 1), dtype=value.dtype)
    values = np.concatenate([value, magnitude(value), np.stack(pairs, axis=1).reshape(n, -1), one], axis=1)
    grads = np.zeros((n, len(ATOMS) + 1, 9), dtype=values.dtype)
    grads[:, : len(_LINEAR)] = _WEIGHTS.T
    grads[:, len(_LINEAR) : 2 * len(_LINEAR)] = sign[:, :, None] * _WEIGHTS.T
    for k, ((i, j), norm) in enumerate(zip(_PAIRS.values(), pairs)):
        zero = np.real(norm) == 0
        scale = np.where(zero, 0.0, 1.0 / np.where(zero, 1.0, norm))
        grads[:, 2 * len(_LINEAR) + k, i] = z[:, i] * scale
        grads[:, 2 * len(_LINEAR) + k, j] = z[:, j] * scale
    return values, grads


def regressors(terms, nu, delta) -> np.ndarray:
    """φ (n, K): each term's product at the samples ν (n, 6) and δ (n, 3)."""
    values = _atoms(nu, delta)[0]
    return np.prod(values[:, _table(tuple(terms))], axis=2)


def gradients(terms, nu, delta) -> np.ndarray:
    """∂φ/∂z (n, K, 9), z = (u v w p q r δr δer δel): the product rule over each term's factors."""
    values, grads = _atoms(nu, delta)
    table = _table(tuple(terms))
    factors = values[:, table]  # (n, K, F)
    out = np.zeros(factors.shape[:2] + (9,), dtype=factors.dtype)
    for i in range(table.shape[1]):
        others = np.prod(np.delete(factors, i, axis=2), axis=2)
        out += others[:, :, None] * grads[:, table[:, i]]
    return out
