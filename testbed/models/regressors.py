"""The nonlinear model's hydrodynamic terms: named products of the motion and the fin angles.

A term is a force or moment row and a product of factors, named as the submarine equations
name them: `Y_uv` is Y_uv·u·v in the sway row, `N_v|v|` is N_v|v|·v·|v| in the yaw row,
`Z_uude` is Z_uude·u²·δe. The letter before the underscore is the row (X Y Z K M N: surge, sway,
heave, roll, pitch, yaw); after it, the factors, each one of

    u v w p q r      the body velocities (u the absolute surge speed) and rates
    dr de da         the rudder δr, the elevators' mean δe = (δer + δel)/2 and half their
                     difference δa = (δer − δel)/2 (the ailerons' action in roll)
    |x|              the magnitude of any of those (x|x| is the usual cross-flow form)

The model is linear in the terms' coefficients: its forces are Σ θ_k φ_k(ν, δ) with the regressor
φ_k the term's product (`regressors`), whose gradient with respect to (ν, δ) (`gradients`) is
exact by the product rule. Both take complex arrays for complex-step derivatives: |x| is x or −x
by the sign of x's real part, so its derivative is sign(x), as for real x (taken as 0 at x = 0).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

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
ATOMS = tuple(_LINEAR) + tuple(f"|{a}|" for a in _LINEAR)
_TOKEN = re.compile(r"\|(?:d[rea]|[uvwpqr])\||d[rea]|[uvwpqr]")


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


def _atoms(nu, delta):
    """Each atom's value (n,) and gradient with respect to z = (ν, δ) (n, 9)."""
    z = np.concatenate([nu, delta], axis=1)
    out = {}
    for a, weights in _LINEAR.items():
        value = z @ weights
        out[a] = (value, np.broadcast_to(weights, z.shape))
        # |x|'s gradient sign(x), 0 at x = 0: the mean of its one-sided slopes, so that an even
        # term (u|v|) has no linear part at v = 0, as its central differences say
        sign = np.sign(np.real(value))
        out[f"|{a}|"] = (magnitude(value), sign[:, None] * weights)
    return out


def regressors(terms, nu, delta) -> np.ndarray:
    """φ (n, K): each term's product at the samples ν (n, 6) and δ (n, 3)."""
    atoms = _atoms(np.atleast_2d(nu), np.atleast_2d(delta))
    n = len(np.atleast_2d(nu))
    out = np.ones((n, len(terms)), dtype=np.result_type(nu, delta, float))
    for k, term in enumerate(terms):
        for a in term.factors:
            out[:, k] = out[:, k] * atoms[a][0]
    return out


def gradients(terms, nu, delta) -> np.ndarray:
    """∂φ/∂z (n, K, 9), z = (u v w p q r δr δer δel): the product rule over each term's factors."""
    atoms = _atoms(np.atleast_2d(nu), np.atleast_2d(delta))
    n = len(np.atleast_2d(nu))
    out = np.zeros((n, len(terms), 9), dtype=np.result_type(nu, delta, float))
    for k, term in enumerate(terms):
        for i, a in enumerate(term.factors):
            others = np.ones(n, dtype=out.dtype)
            for j, b in enumerate(term.factors):
                if j != i:
                    others = others * atoms[b][0]
            out[:, k] += others[:, None] * atoms[a][1]
    return out
