"""The nonlinear model's hydrodynamic terms: named products of the motion and the fin angles.

A term is a force or moment row and a product of factors, named as the submarine equations
name them: `Y_uv` is Y_uv·u·v in the sway row, `N_v|v|` is N_v|v|·v·|v| in the yaw row,
`Z_uude` is Z_uude·u²·δe, and `M_0` the pitch row's offset, a constant moment (the linear model's
`M_0`; a trial's trim or buoyancy error). The letter before the underscore is the row (X Y Z K M N:
surge, sway, heave, roll, pitch, yaw; no `X_0`: the thrust balances the surge row at trim, so a
constant surge force is the thrust's); after it, `0` or the factors, each one of

    u v w p q r      the body velocities (u the absolute surge speed) and rates
    dr de da         the rudder δr, the elevators' mean δe = (δer + δel)/2 and half their
                     difference δa = (δer − δel)/2 (the ailerons' action in roll)
    |x|              the magnitude of any of those (x|x| is the usual cross-flow form)
    |vw| |qr|        the magnitudes of the cross flow, √(v² + w²), and of the cross-flow turn
                     rate, √(q² + r²): a body of revolution's drag acts along the whole cross
                     flow, so its sway force is v·√(v² + w²), not v·|v| + v·|w|

A component term names a force of one of the vehicle's components instead of a product:
`lift@rudder_upper` is the Kutta lift on the component `rudder_upper` per unit lift coefficient,
its force and its moment about the CG in every body row at once, `blunt@hull` the hull's blunt
drag (`components`: the kinds, the components' geometry); one coefficient scales the whole
wrench, as the fluid's own coefficient does.

The model is linear in the terms' coefficients: its forces are Σ θ_k φ_k(ν, δ) with the regressor
φ_k the term's product (`regressors`, over stacked samples, for least-squares fits of the
coefficients). The atoms are data: `WEIGHTS` gives each linear atom from z = (ν, δ) and
`factor_table` each term's factors as indices into (linear atoms, their magnitudes, 1), from which
the compiled model (`nonlinear_kernels`) evaluates any term set and its gradients. Complex arrays
are taken for complex-step derivatives: |x| is x or −x by the sign of x's real part, so its
derivative is sign(x), as for real x (taken as 0 at x = 0); √(a² + b²) is the principal square
root, analytic off a = b = 0, its derivative (a, b)/√(a² + b²) (taken as 0 at a = b = 0).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from testbed.errors import InputError
from testbed.models.components import KINDS, NAME, Component, component_wrenches

__all__ = [
    "ATOMS",
    "PAIRS",
    "ROWS",
    "WEIGHTS",
    "Term",
    "component_kind",
    "factor_table",
    "magnitude",
    "parse_term",
    "physical_bounds",
    "regressors",
    "term_components",
    "term_wrenches",
]

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
_COMPONENT = re.compile(r"(" + "|".join(KINDS) + r")@(" + NAME + ")")
_TOKEN = re.compile(r"\|(?:vw|qr|d[rea]|[uvwpqr])\||d[rea]|[uvwpqr]")


@dataclass(frozen=True)
class Term:
    """One hydrodynamic term: its name, its body row (0..5: X..N) and its factors (`ATOMS`), or
    for a component term row −1 (every row), no factors, its component and the index of its kind
    in `KINDS`."""

    name: str
    row: int
    factors: tuple[str, ...]
    component: Component | None = None
    kind: int = -1


def component_kind(name: str) -> str | None:
    """The kind (one of `KINDS`) a component term's name `kind@component` names; None for any
    other name."""
    match = _COMPONENT.fullmatch(str(name))
    return match.group(1) if match else None


# The terms whose sign physics fixes: a component's drags (`blunt`, `slender`, `angular`:
# f = −c ρ A ‖v‖ v, dissipative for c ≥ 0), each the coefficient of a drag law. A polynomial
# term's sign is not physics': a row's damping in its own velocity is shared by every term of
# the set even in it (the bundled torpedo's captive polynomial fit has Y_v|v|, Z_w|w|, M_q|q|
# and N_r|r| positive, its cross-flow terms carrying the damping), so none is bounded unasked
DRAGS = ("blunt", "slender", "angular")


def physical_bounds(name: str) -> tuple[float, float]:
    """`(low, high)` of the term `name` on its dissipative side: `(0, ∞)` for a component's drag,
    else `(−∞, ∞)`."""
    if component_kind(name) in DRAGS:
        return 0.0, math.inf
    return -math.inf, math.inf


def parse_term(name: str, components=()) -> Term:
    """The term named `name` (e.g. `Y_uv`, `N_v|v|`, `M_uude`, `lift@rudder_upper` of one of
    `components`); `InputError` if it is not one."""
    match = _COMPONENT.fullmatch(str(name))
    if match:
        kind, which = match.groups()
        named = {c.name: c for c in components}
        if which not in named:
            raise InputError(
                f"term {name!r}: no component {which!r}; expected one of [components]: "
                f"{', '.join(named) or 'none given'}"
            )
        return Term(str(name), -1, (), named[which], KINDS.index(kind))
    row, _, rest = str(name).partition("_")
    if rest == "0" and row in ROWS[1:]:  # the row's offset: a constant force or moment, φ = 1
        return Term(name=str(name), row=ROWS.index(row), factors=())
    if str(name) == "X_0":
        raise InputError(
            "term 'X_0': the thrust balances the surge row in straight flight at trim, so a constant "
            "surge force is the thrust's and moves nothing; expected the offset of another row (Y_0 … N_0)"
        )
    tokens = _TOKEN.findall(rest)
    if len(row) != 1 or row not in ROWS or not tokens or "".join(tokens) != rest:
        raise InputError(
            f"term {name!r}: expected a row letter ({' '.join(ROWS)}), '_' and a product of "
            f"factors among {' '.join(ATOMS)} (e.g. Y_uv, N_v|v|, Z_uude), or a kind "
            f"({' '.join(KINDS)}) '@' a component (e.g. lift@rudder_upper)"
        )
    return Term(name=str(name), row=ROWS.index(row), factors=tuple(tokens))


def magnitude(x):
    """|x| that complex steps see through: x or −x by the sign of x's real part."""
    return np.where(np.real(x) >= 0, x, -x)


WEIGHTS = np.array(list(_LINEAR.values())).T  # (9, L): z = (u v w p q r δr δer δel) ↦ the linear atoms
# (P, 2): the entries of z whose magnitude √(z_i² + z_j²) is an atom, after the linear atoms'
# magnitudes in `ATOMS` (a pair's atom for the compiled model and `regressors`)
PAIRS = np.array(list(_PAIRS.values()), dtype=np.int64).reshape(-1, 2)


@lru_cache(maxsize=64)
def factor_table(terms: tuple[Term, ...]) -> np.ndarray:
    """(K, F): each term's factors as indices into `ATOMS` (the L linear atoms, their magnitudes,
    the pairs' magnitudes), padded with len(ATOMS), the constant 1."""
    width = max((len(t.factors) for t in terms), default=1)
    table = np.full((len(terms), width), len(ATOMS), dtype=np.int64)
    for k, t in enumerate(terms):
        table[k, : len(t.factors)] = [ATOMS.index(a) for a in t.factors]
    return table


def term_components(terms) -> tuple[Component, ...]:
    """The distinct components of `terms`' component terms, in order of first use."""
    return tuple(dict.fromkeys(t.component for t in terms if t.component is not None))


def regressors(terms, nu, delta) -> np.ndarray:
    """φ (n, K): each term's product at the samples ν (n, 6) and δ (n, 3) (1 for a component term,
    whose regressor is its wrench: `term_wrenches`)."""
    z = np.concatenate([np.atleast_2d(nu), np.atleast_2d(delta)], axis=1)
    value = z @ WEIGHTS
    pairs = np.sqrt(z[:, PAIRS[:, 0]] ** 2 + z[:, PAIRS[:, 1]] ** 2)
    atoms = np.concatenate([value, magnitude(value), pairs, np.ones((len(z), 1), dtype=value.dtype)], axis=1)
    return np.prod(atoms[:, factor_table(tuple(terms))], axis=2)


def term_wrenches(terms, nu, delta) -> np.ndarray:
    """(n, 6, K): each term's force and moment per unit coefficient in the body rows at the
    samples ν (n, 6) and δ (n, 3): a product term's φ in its row, a component term's wrench."""
    terms = tuple(terms)
    phi = regressors(terms, nu, delta)
    out = np.zeros((len(phi), 6, len(terms)), dtype=phi.dtype)
    rows = [k for k, t in enumerate(terms) if t.component is None]
    out[:, [terms[k].row for k in rows], rows] = phi[:, rows]
    parts = term_components(terms)
    if parts:
        W = component_wrenches(parts, nu, delta)
        for k, t in enumerate(terms):
            if t.component is not None:
                out[:, :, k] = W[:, parts.index(t.component), t.kind]
    return out
