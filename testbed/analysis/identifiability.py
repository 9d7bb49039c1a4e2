"""Identifiability of the paper's linear model from data: the Fisher information at the
config's values, the Cramér-Rao bounds, correlations and practical drift groups beside the
structural ones (`structural`), and the summary a user reads.
"""

from __future__ import annotations

import html
import json
from dataclasses import dataclass, replace

import numpy as np

from testbed.analysis.structural import Structural, copied, drift_groups_of, rref, structural
from testbed.data import check_excited
from testbed.html_figures import svg_heatmap
from testbed.html_table import html_table
from testbed.identification.bounds import NULL, analysed, crlb, fisher_at
from testbed.identification.problem import base_name, expanded
from testbed.models.linear import ITHETA, IX, OUTSIDE_EQUATIONS, structure, theta_vector

__all__ = [
    "CORRELATED",
    "Identifiability",
    "UNCERTAIN",
    "assessed",
    "direction_text",
    "identifiability",
    "on_segments",
    "singular",
]


CORRELATED = 0.95  # |correlation| above which two coefficients drift together in practice


UNCERTAIN = 0.5  # relative Cramér-Rao bound above which a coefficient is practically unknown


@dataclass(frozen=True)
class Identifiability:
    """What the data can tell about the free coefficients of a config (the analyze JSON)."""

    free: tuple[str, ...]
    values: np.ndarray  # the coefficients analysed (the config's)
    fisher: np.ndarray
    crlb_std: np.ndarray  # inf where unidentifiable (`bounds.crlb`, and every structural drift group)
    correlation: np.ndarray  # NaN in an unidentifiable coefficient's row and column
    structural: Structural
    practical_groups: tuple[tuple[str, ...], ...]
    uncertain: tuple[str, ...]  # relative bound > UNCERTAIN
    summary: tuple[str, ...]
    null: float = NULL  # the eigenvalue of the scaled information, relative to the largest, taken as 0
    segments: int = (
        0  # the information of the records cut into this many segments (0: whole; `bounds.analysed`)
    )

    @property
    def singular(self) -> np.ndarray:
        """The directions along which these data's Fisher information is singular beyond the
        structure's (`singular`), k × len(free) in coefficient units: each coefficient with
        an infinite bound for want of information (`bounds.crlb`) lies on one."""
        return singular(self.fisher, self.structural.basis, self.null)

    @property
    def singular_groups(self) -> tuple[tuple[str, ...], ...]:
        """The coefficients sharing a direction of `singular`."""
        return drift_groups_of(self.free, self.singular)

    @property
    def null_directions(self) -> int:
        """The unidentifiable directions: the structure's and these data's (`singular`)."""
        return self.structural.null_directions + len(self.singular)

    @property
    def drift_groups(self) -> tuple[tuple[str, ...], ...]:
        """Structural groups first, then those of the data's singular directions, then the
        practical ones not already inside one."""
        groups = self.structural.drift_groups + self.singular_groups
        seen = [set(g) for g in groups]
        extra = tuple(g for g in self.practical_groups if not any(set(g) <= s for s in seen))
        return groups + extra

    def bounds(self) -> tuple[tuple[str, ...], list[tuple[str, ...]]]:
        """The column names and each coefficient's row as text: the value analysed, its Cramér-Rao
        bound (∞ where the data do not determine it) and that bound relative to the value."""
        rows = [
            (
                n,
                f"{v:.6g}",
                "∞" if not np.isfinite(sd) else f"{sd:.3g}",
                "-" if not (v and np.isfinite(sd)) else f"{abs(sd / v):.1%}",
            )  # fmt: skip
            for n, v, sd in zip(self.free, self.values, self.crlb_std)
        ]
        return ("coefficient", "value analysed", "Cramér-Rao σ", "relative"), rows

    def _repr_html_(self) -> str:
        """The analysis in a notebook: each coefficient's value and Cramér-Rao bound, the
        correlation matrix as a heat map, the drift groups, and the summary."""
        groups = html_table(("drift group",), [(", ".join(g),) for g in self.drift_groups])
        summary = "".join(f"<p>{html.escape(line)}</p>" for line in self.summary)
        heat = svg_heatmap(self.free, self.correlation, "the coefficients' correlation matrix")
        return html_table(*self.bounds(), "identifiability") + heat + groups + summary

    def to_json(self) -> str:

        def num(x):
            return float(x) if np.isfinite(x) else None

        doc = {
            "free": list(self.free),
            "crlb_std": {n: num(s) for n, s in zip(self.free, self.crlb_std)},
            "correlation": [[num(round(float(c), 6)) for c in row] for row in self.correlation],
            "null_directions": self.null_directions,
            "drift_groups": [list(g) for g in self.drift_groups],
            "structural_drift_groups": [list(g) for g in self.structural.drift_groups],
            "singular_drift_groups": [list(g) for g in self.singular_groups],
            "practical_drift_groups": [list(g) for g in self.practical_groups],
            "null_basis": [
                [float(v) for v in row] for row in np.vstack([self.structural.basis, self.singular])
            ],
            "unobserved": list(self.structural.unobserved),
            "relative_crlb": {
                n: num(s / abs(v)) if v else None for n, s, v in zip(self.free, self.crlb_std, self.values)
            },
            "practically_unidentifiable": list(self.uncertain),
            "fisher_condition": num(np.linalg.cond(self.fisher)),
            "segments": self.segments or None,
            "summary": list(self.summary),
        }
        return json.dumps(doc, indent=2, allow_nan=False) + "\n"


def identifiability(experiments, config, noise_std=None) -> Identifiability:
    """Fisher information, Cramér-Rao bounds, correlations, structural and practical drift groups
    of `config.free` at the config's coefficients, for the given experiments. `noise_std`: the
    measurement noise per channel (default: the residual at the config's coefficients).
    `InputError` for records that do not move (`data.check_excited`)."""
    experiments = config.fitted(experiments)
    check_excited(experiments)
    at = analysed(experiments, config, noise_std=noise_std)
    F = fisher_at(at)
    free = expanded(config, [e.name for e in experiments])[0]
    theta = theta_vector(config.coefficients)
    measured = sorted({m for e in experiments for m in e.measured}, key=list(IX).index)
    # the output terms and the inputs' delay are no part of the equations' structure: no row
    # operation moves them
    dynamic = tuple(n for n in config.free if n not in OUTSIDE_EQUATIONS)
    struct = copied(structural(structure(config.vehicle), theta, dynamic, measured), free)
    out = assessed(free, theta[[ITHETA[base_name(n)] for n in free]], F, struct)
    return on_segments(out, at.segments, at.why) if at.segments else out


def on_segments(result: Identifiability, segments: int, why: str) -> Identifiability:
    """`result`, computed on `segments` segments of the records because the model diverges over
    the whole record (`why`), saying so first in its summary."""
    cut = (
        f"Computed on {segments} segments of the records, each with its own initial state: the "
        f"model diverges over the whole record at these coefficients ({why})."
    )
    return replace(result, summary=(cut, *result.summary), segments=segments)


def assessed(
    free: tuple[str, ...], values: np.ndarray, F: np.ndarray, struct: Structural, null: float = NULL
) -> Identifiability:
    """The identifiability of the coefficients `free` at `values` from their Fisher information
    `F` and their exactly unidentifiable directions `struct`: the bounds (infinite in a drift
    group, or along a direction of F whose eigenvalue is at most `null` of the largest:
    `bounds.crlb`), correlations, practical drift groups, the practically unknown, the summary."""
    bounds = crlb(F, null)
    std, corr = bounds.std.copy(), bounds.correlation.copy()
    # a structural drift group has no information at all: infinite bounds, undefined correlations
    drifting = np.array([n in {m for g in struct.drift_groups for m in g} for n in free])
    std[drifting] = np.inf
    corr[drifting, :] = corr[:, drifting] = np.nan
    pairs = np.argwhere(np.triu(np.abs(corr) > CORRELATED, 1))
    practical = (
        drift_groups_of(free, np.array([np.eye(len(free))[i] + np.eye(len(free))[j] for i, j in pairs]))
        if len(pairs)
        else ()
    )
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.where(values != 0, std / np.abs(values), np.inf)
    uncertain = tuple(
        n for n, r, s in zip(free, rel, std) if np.isfinite(s) and np.isfinite(r) and r > UNCERTAIN
    )
    summary = _summary(free, struct, practical, uncertain, corr, rel, std, singular(F, struct.basis, null))
    return Identifiability(free, values, F, std, corr, struct, practical, uncertain, summary, null)


def singular(F: np.ndarray, basis: np.ndarray, null: float = NULL) -> np.ndarray:
    """The directions along which the Fisher information `F` is singular (an eigenvalue of the
    scaled information at most `null` of the largest, as `bounds.crlb` takes them) that the
    exactly unidentifiable `basis` (k × n, coefficient units) does not span, in reduced row
    echelon form in coefficient units. A coefficient's component is kept only where `crlb`
    gives it an infinite bound (above √null along the null directions, or no information), so
    the directions name exactly the coefficients the data leave unbounded."""
    M = (F + F.T) / 2
    D = np.sqrt(np.maximum(np.diag(M), 0.0))
    D = np.where(D > 0, D, 1.0)
    lam, V = np.linalg.eigh(M / np.outer(D, D))
    zero = lam <= null * max(lam.max(initial=0.0), 1e-300)
    N = V[:, zero]  # the null directions, scaled coordinates D dθ
    unbounded = (np.linalg.norm(N, axis=1) > np.sqrt(null)) | (np.diag(M) <= 0)
    N[~unbounded] = 0.0
    if len(basis):  # less the structure's directions (null directions of F too)
        Q = np.linalg.qr((basis * D).T)[0]
        N -= Q @ (Q.T @ N)
        N[~unbounded] = 0.0
    if not N.size:
        return np.zeros((0, len(F)))
    u, sv, _ = np.linalg.svd(N, full_matrices=False)
    directions = u[:, sv > 1e-6].T / D  # coefficient units
    if not len(directions):
        return np.zeros((0, len(F)))
    return rref(directions / np.abs(directions).max(axis=1, keepdims=True))


def _summary(free, struct, practical, uncertain, corr, rel, std, directions) -> tuple[str, ...]:
    """Plain sentences: what cannot be identified, and what to fix or measure."""
    lines = []
    if struct.unobserved:
        lines.append(
            f"Not identifiable: {', '.join(struct.unobserved)}; the measured states do not "
            "depend on them in the model; measure the states they drive or fix them."
        )
    for g in struct.drift_groups:
        if set(g) <= set(struct.unobserved):
            continue
        lines.append(
            f"Exactly unidentifiable: {', '.join(g)} can drift together without changing "
            "the outputs (rows of Mt ẋ = At x + Bt δ scale together); fix one of them "
            "(e.g. an added-mass term from theory) or free fewer coefficients."
        )
    index = {n: i for i, n in enumerate(free)}
    structural_ = set(struct.unobserved) | {n for g in struct.drift_groups for n in g}
    singular = [n for n in free if np.isinf(std[index[n]]) and n not in structural_]
    if singular:
        k = len(directions)
        lines.append(
            f"Unidentifiable in these data: {', '.join(singular)} (the Fisher information is "
            f"singular along {k} direction{'s' if k > 1 else ''} of them, "
            f"{'; '.join(direction_text(free, d) for d in directions)}: infinite Cramér-Rao bounds); "
            "add a manoeuvre that excites them or fix them."
        )
    for g in practical:
        worst = max(abs(corr[index[a], index[b]]) for a in g for b in g if a != b)
        lines.append(
            f"Practically inseparable in these data: {', '.join(g)} (|correlation| up to "
            f"{worst:.3f}); add a manoeuvre that excites them differently (PRBS input, "
            "other mode) or fix one."
        )
    for n in uncertain:
        lines.append(
            f"Poorly determined: {n} (Cramér-Rao bound {100 * rel[index[n]]:.0f} % of its "
            "value); the data hardly excite it."
        )
    for n in free:
        if not np.isfinite(rel[index[n]]) and np.isfinite(std[index[n]]):
            lines.append(
                f"{n} is analysed at 0, so it has no relative bound: its Cramér-Rao bound "
                f"is {std[index[n]]:.3g}; compare that with the values you expect."
            )
    if not lines:
        lines.append(
            "All free coefficients are identifiable from these data; the largest relative "
            f"bound is {100 * np.nanmax(rel):.2g} %."
        )
    return tuple(lines)


def direction_text(free, d: np.ndarray) -> str:
    """A null direction in words, its coefficients' components: `dN_v + 0.25 dN_r`."""
    terms = [
        f"{'-' if v < 0 else '+'} {'' if abs(v) == 1 else f'{abs(v):.3g} '}d{n}" for n, v in zip(free, d) if v
    ]
    return " ".join(terms).removeprefix("+ ")
