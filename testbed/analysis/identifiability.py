"""Identifiability of the paper's linear model.

Structural part: the paper's simultaneous drift. Left-multiplying the rows of
`Mt ẋ = At x + Bt δ + St` by T = I + E, and changing state coordinates x → (I + F) x with
C F = 0 (only unmeasured states move), leave the measured outputs unchanged. A coefficient
direction dθ is exactly unidentifiable when some (E, F) reproduces it while every fixed entry of
the model stays put; to first order that is the null space of a linear map, computed here.
"""

from __future__ import annotations

import html
import json
from dataclasses import dataclass, replace
from typing import Callable, Mapping, Sequence

import numpy as np

from testbed.data import Experiment, ModelConfig, check_excited
from testbed.errors import InputError
from testbed.html_figures import svg_dots, svg_heatmap
from testbed.html_table import html_table
from testbed.estimators import Estimate, Status, check_method, identify, lookup
from testbed.identification.problem import base_name, check_fit, expanded
from testbed.identification.bounds import NULL, Unflyable, analysed, chi2_sf, crlb, fisher, fisher_at
from testbed.simulation.measurements import noise_from_data
from testbed.models.linear import (
    OUTSIDE_EQUATIONS,
    ITHETA,
    IX,
    NX,
    Structure,
    structure,
    theta_vector,
    tilde,
    unobserved,
)

__all__ = [
    "Comparison",
    "Identifiability",
    "LINEAR",
    "SIGNIFICANT",
    "Screen",
    "ScreenModel",
    "Screened",
    "assessed",
    "Structural",
    "UNCERTAIN",
    "compare",
    "identifiability",
    "identify_screened",
    "insignificant",
    "screen",
    "screening",
    "singular",
    "structural",
    "structurally_unidentified",
    "unidentified",
]


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
    basis = _rref(vt[sv > 1e-6] * scale)
    return Structural(free, basis, _groups(free, basis), blind)


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


def _copied(struct: Structural, free: tuple[str, ...]) -> Structural:
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


# -- practical identifiability and the identifiability report ------------------------------------

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
        return _groups(self.free, self.singular)

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
    struct = _copied(structural(structure(config.vehicle), theta, dynamic, measured), free)
    out = assessed(free, theta[[ITHETA[base_name(n)] for n in free]], F, struct)
    if not at.segments:
        return out
    cut = (
        f"Computed on {at.segments} segments of the records, each with its own initial state: the "
        f"model diverges over the whole record at these coefficients ({at.why})."
    )
    return replace(out, summary=(cut, *out.summary), segments=at.segments)


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
        _groups(free, np.array([np.eye(len(free))[i] + np.eye(len(free))[j] for i, j in pairs]))
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
    return _rref(directions / np.abs(directions).max(axis=1, keepdims=True))


# -- the screen ------------------------------------------------------------------------------------

LIKELIHOOD_RATIO = 0.95  # the likelihood-ratio test's level for the significance stage's fixes
SIGNIFICANT = 1 / UNCERTAIN  # |estimate| / σ below which these data cannot tell a coefficient from 0


@dataclass(frozen=True)
class Screen:
    """What the screen made of a candidate list (`screening`).

    Attributes:
        config: the config with only the candidates these data determine left free.
        fixed: the other candidates, name → why, in the order they were fixed.
        fit: the `ml-gn` fit of the candidates the structural stage left (None when it left
            none), whose estimate the significance stage tested.
        skipped: why the structural stage was not taken (the a-priori model cannot be flown
            on the records, even in segments), "" where it was.
    """

    config: ModelConfig
    fixed: dict[str, str]
    fit: Estimate | None
    skipped: str = ""


@dataclass(frozen=True)
class Screened:
    """A fit behind the screen (`identify_screened`): `config` fitted, its `estimate`, `screen`
    (name → why) what the screen fixes, whether it was `applied` (else only reported), and why
    its structural stage was `skipped` ("" where it was taken: `Screen.skipped`)."""

    config: ModelConfig
    estimate: Estimate
    screen: dict[str, str]
    applied: bool
    skipped: str = ""

    @property
    def fixed(self) -> dict[str, str]:
        """The candidates left at their a-priori values, name → why."""
        return self.screen if self.applied else {}


def structurally_unidentified(result: Identifiability) -> dict[str, str]:
    """The screen's first stage, name → why, whatever the coefficients' values: the free
    coefficients in an exactly unidentifiable drift group (`structural`) and those on a
    direction along which the Fisher information of these data is singular (an infinite
    Cramér-Rao bound: `Identifiability.singular`, the direction named)."""
    fixed = {}
    for group in result.structural.drift_groups:
        for n in group:
            fixed[n] = (
                "no fitted state depends on it"
                if n in result.structural.unobserved
                else f"in the exactly unidentifiable drift group {', '.join(group)}"
            )
    for d in result.singular:
        for n in np.asarray(result.free)[d != 0]:
            fixed.setdefault(
                str(n),
                f"the Fisher information of these data is singular along {_direction(result.free, d)} "
                "(an infinite bound)",
            )
    for n, std in zip(result.free, result.crlb_std):
        if n not in fixed and not np.isfinite(std):
            fixed[n] = "the Fisher information of these data is singular along it (an infinite bound)"
    return fixed


def insignificant(free, estimate, information: np.ndarray, prior) -> dict[str, str]:
    """The screen's second stage, name → why in the order fixed: backward elimination at an
    estimate of `free` (`estimate`, with the Fisher `information` there).

    Each round takes the least significant coefficient, |θ̂|/σ below `SIGNIFICANT` (its
    Cramér-Rao bound above `UNCERTAIN` of the estimate: the data cannot tell it from 0), whose
    a-priori value the data do not contradict either (|θ̂ − prior| ≤ `SIGNIFICANT` σ, so fixing
    it there costs the fit little), and fixes it at `prior`. The others are then re-estimated
    with the cost's quadratic model, θ̂_r − F_rr⁻¹ F_rs (prior_s − θ̂_s) with σ from F_rr, and
    the next round tests them: a coefficient that drifts with another (say K_v with K_r) is
    insignificant while both are free and determined once the other is fixed, so fixing all
    insignificant ones at once would lose both.
    """
    free, theta, prior = list(free), np.asarray(estimate, float), np.asarray(prior, float)
    fixed: dict[str, str] = {}
    while len(fixed) < len(free):
        rest = [i for i, n in enumerate(free) if n not in fixed]
        held = [i for i, n in enumerate(free) if n in fixed]
        bounds = crlb(information[np.ix_(rest, rest)])
        shift = information[np.ix_(rest, held)] @ (prior[held] - theta[held])
        value = theta[rest] - bounds.covariance @ shift
        std = bounds.std
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.where(np.isfinite(std), np.abs(value) / std, 0.0)
            off = np.where(np.isfinite(std), np.abs(value - prior[rest]) / std, 0.0)
        eligible = np.flatnonzero((z < SIGNIFICANT) & (off <= SIGNIFICANT))
        if not len(eligible):
            break
        k = eligible[np.argmin(z[eligible])]
        fixed[free[rest[k]]] = (
            f"estimate {value[k]:.4g} ± {std[k]:.2g}, {z[k]:.1f} σ from 0 (below {SIGNIFICANT:g} σ)"
        )
    return fixed


@dataclass(frozen=True)
class ScreenModel:
    """What the screen needs of a model; the rest (`screening`) is the same mathematics for every
    model: an information matrix and an estimate.

    Attributes:
        check: `(experiments, config)` → None; `InputError` for what no screen can mend.
        assess: `(experiments, config, noise_std)` → the `Identifiability` of `config.free` at
            the config's values with the measurement noise σ per state `noise_std` (stage 1).
        information: `(experiments, candidates, fit)` → the Fisher information of
            `candidates.free` at the `ml-gn` estimate `fit` (stage 2).
        unidentified: `assess`'s result → the candidates stage 1 fixes, name → why
            (default `structurally_unidentified`).
    """

    check: Callable[[Sequence[Experiment], ModelConfig], None]
    assess: Callable[[Sequence[Experiment], ModelConfig, Mapping[str, float]], Identifiability]
    information: Callable[[Sequence[Experiment], ModelConfig, Estimate], np.ndarray]
    unidentified: Callable[[Identifiability], dict[str, str]] = structurally_unidentified


def _information(experiments, candidates: ModelConfig, fit: Estimate) -> np.ndarray:
    """The linear model's information at the estimate, the problem checked against the a-priori
    candidates: the step check (`problem.check_inputs`) is about the user's model, not a model the
    fit reached (the simulation is exact at any step; a mode too fast for it only makes the data
    blind to it)."""
    return fisher(
        candidates.fitted(experiments), candidates, values=fit.coefficients, noise_std=fit.noise_std
    )


LINEAR = ScreenModel(check=check_fit, assess=identifiability, information=_information)


def screening(experiments, config, options=None, callback=None, model: ScreenModel = LINEAR) -> Screen:
    """The screen of the candidate list `config.free`: which candidates these data determine.

    Nothing is fixed for being 0. Stage 1, at the a-priori coefficients with the measurement noise
    read off the data (third differences, `noise_from_data`) where the config's `noise_std` does
    not give it: `model.unidentified` of `model.assess` fixes what these data cannot determine
    (the linear model's: the structurally unidentifiable candidates, `structurally_unidentified`,
    whatever their magnitude). Stage 2:
    the rest are fitted with `ml-gn` (`options`, its options; `callback`, its progress), and
    those the estimate does not make significant are fixed by backward elimination
    (`insignificant`, with `model.information` at the estimate). A fixed candidate stays at its
    a-priori value. Where the a-priori model cannot be flown on the records even in segments,
    stage 1 is skipped (`Screen.skipped` says why) and the fit starts as it can. When the
    `ml-gn` fit diverges, or reaches a model that cannot be flown on the records even in
    segments (a diverged fit too), stage 2 fixes nothing. What no screen can mend
    (bad data, a candidate no fitted state depends on) is an `InputError` first (`model.check`).
    `model`: the linear model's (`LINEAR`) or another's (`ScreenModel`).
    """
    model.check(experiments, config)
    noise = noise_from_data(config.fitted(experiments), config.noise_std)
    fixed, skipped = {}, ""
    try:
        result = model.assess(experiments, config, noise)
    except Unflyable as exc:  # no information at the a-priori values: the fit's starts may fly
        skipped = str(exc)
    else:
        fixed = {
            n: f"not determined by these data: {why}"
            for n, why in _by_name(result.free, model.unidentified(result)).items()
        }
    candidates = _without(config, fixed)
    if not candidates.free:
        return Screen(candidates, fixed, None)
    fit = identify(experiments, candidates, method="ml-gn", options=options, callback=callback)
    if fit.status is Status.DIVERGED:
        return Screen(candidates, fixed, fit, skipped)
    try:
        information = model.information(experiments, candidates, fit)
    except Unflyable:  # the model the fit reached cannot be flown on the records: it diverged
        why = "the model it reached diverges on the records even in segments"
        return Screen(candidates, fixed, replace(fit, status=Status.DIVERGED, message=why), skipped)
    prior = [config.values[base_name(n)] for n in fit.free]
    for n, why in _by_name(fit.free, insignificant(fit.free, fit.values, information, prior)).items():
        fixed[n] = f"not determined by these data: {why}"
    return Screen(_without(config, fixed), fixed, fit, skipped)


def _by_name(values: tuple[str, ...], fixed: dict[str, str]) -> dict[str, str]:
    """The names of a config's free list whose every value (`values`: a per-record name once per
    record) is in `fixed`, name → why, in the order fixed: a per-record name stays free for every
    record while the data determine it in one."""
    out = {}
    for v, why in fixed.items():
        n = base_name(v)
        copies = [m for m in values if base_name(m) == n]
        if n not in out and all(m in fixed for m in copies):
            out[n] = why if copies == [n] else f"{why} (in every record: {', '.join(copies)})"
    return out


def _without(config: ModelConfig, fixed) -> ModelConfig:
    """`config` with the names in `fixed` no longer free (nor per record)."""
    return replace(
        config,
        free=tuple(n for n in config.free if n not in fixed),
        per_record=tuple(n for n in config.per_record if n not in fixed),
    )


def screen(experiments, config):
    """`(config, fixed)`: the config with only the candidates of `config.free` these data
    determine left free, and `fixed` (name → why) for the others, which stay at their a-priori
    values (`screening`)."""
    s = screening(experiments, config)
    return s.config, s.fixed


def identify_screened(
    experiments,
    config,
    method: str = "ml-gn",
    options=None,
    callback=None,
    apply: bool | None = None,
    model: ScreenModel = LINEAR,
) -> Screened:
    """Screen `config.free` (`screening`, for `model`) and fit with `method` (`options`,
    `callback` as for `identify`).

    `apply`: fit only the candidates the screen leaves free (default: `config.screen`, the
    config's `[identify] screen`); otherwise fit `config.free` as written, the screen only
    reported. The screen's `ml-gn` fit is the fit itself when `method` is `ml-gn` and the free set
    is the same (then `callback` gets its steps when it ends); otherwise `method` fits anew
    (`ml-gn`: one start, where the screen's fit ended, that fit having run the starts asked for;
    the estimate's time and simulations count that fit in; its fixes tested as a likelihood
    ratio and undone where they fail it; `callback` gets the steps of the fit returned, when it
    ends).
    `InputError` when the screen applied leaves nothing free.
    """
    apply = config.screen if apply is None else apply
    m = lookup(method)
    built = m.options.build(m.name, options)  # what the method refuses, before the screen's fit
    check_method(m.name, config)
    same = m.name == "ml-gn"
    steps = []
    s = screening(experiments, config, options if same else None, steps.append if same else None, model)
    fitted = s.config if apply else config
    if not fitted.free:
        first = next(iter(s.fixed))
        raise InputError(
            f"{config.source or 'config'}: no candidate of [identify] free is determined by these "
            f"data ({first} {s.fixed[first]}); expected data that excite them, or the list "
            "estimated as written (screen=False)"
        )
    if same and s.fit is not None and s.fit.free == fitted.free:
        for step in steps if callback is not None else ():
            callback(step)
        estimate = s.fit
    elif same and apply and s.fit is not None and s.fit.status is not Status.DIVERGED:
        # the screened set from where the screen's fit ended, the fixed candidates at their
        # a-priori values: its basin, not the a-priori model's again
        kept = {n: v for n, v in zip(s.fit.free, s.fit.values) if base_name(n) in fitted.free}
        start, rest = fitted.with_coefficients(kept), []
        dropped = [n for n in dict.fromkeys(map(base_name, s.fit.free)) if n not in fitted.free]
        # one start: the screen's fit ran the starts asked for, and its optimum is this one's
        local = replace(built, start="config")
        estimate = identify(experiments, start, method=method, options=local, callback=rest.append)
        reason = f"then from its optimum with {', '.join(dropped)} fixed"
        estimate = replace(
            estimate,
            start=s.fit.start,
            start_reason=f"{s.fit.start_reason}; {reason}" if s.fit.start_reason else reason,
            wall_time_s=s.fit.wall_time_s + estimate.wall_time_s,  # what the estimate cost
            evaluations=s.fit.evaluations + estimate.evaluations,
        )
        # the likelihood-ratio test of the significance stage's fixes: fixing k coefficients the
        # data do not contradict raises the cost by at most χ²₀.₉₅(k)/2; more, and the quadratic
        # model that chose them did not hold (a model far from linear in them): their fit stands
        rise = estimate.cost - s.fit.cost  # NaN where the fit of the rest diverged
        if not (rise <= 0 or (np.isfinite(rise) and chi2_sf(2 * rise, len(dropped)) >= 1 - LIKELIHOOD_RATIO)):
            why = (
                f"fixing {', '.join(dropped)} raised the cost by {rise:.4g}, more than the χ² "
                f"test allows (p = {chi2_sf(2 * rise, len(dropped)):.2g})"
                if np.isfinite(rise)
                else f"the fit with {', '.join(dropped)} fixed diverged"
            )
            structural = {n: w for n, w in s.fixed.items() if n not in dropped}
            fitted = _without(config, structural)
            s = replace(s, config=fitted, fixed=structural)
            estimate, rest = (
                replace(s.fit, start_reason=f"{s.fit.start_reason}; the screen kept them: {why}"),
                steps,
            )
        for step in rest if callback is not None else ():  # the steps of the fit returned
            callback(step)
    else:
        estimate = identify(experiments, fitted, method=method, options=options, callback=callback)
    return Screened(fitted, estimate, s.fixed, apply, s.skipped)


def unidentified(experiments, config, noise_std=None) -> dict[str, str]:
    """The screen's rule where the data would come from the config's own model (the design's
    default free set), name → why: stage 1, then stage 2 at the config's coefficients, which a fit
    of such data estimates (on average), with the Fisher information there; no fit needed."""
    result = identifiability(experiments, config, noise_std)
    fixed = _by_name(result.free, structurally_unidentified(result))
    rest = _without(config, fixed)
    if rest.free:
        fitted = rest.fitted(experiments)
        names = expanded(rest, [e.name for e in fitted])[0]
        values = [config.coefficients[base_name(n)] for n in names]
        information = fisher(fitted, rest, noise_std=noise_std)
        fixed.update(_by_name(names, insignificant(names, values, information, values)))
    return fixed


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
            f"{'; '.join(_direction(free, d) for d in directions)}: infinite Cramér-Rao bounds); "
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


def _direction(free, d: np.ndarray) -> str:
    """A null direction in words, its coefficients' components: `dN_v + 0.25 dN_r`."""
    terms = [
        f"{'-' if v < 0 else '+'} {'' if abs(v) == 1 else f'{abs(v):.3g} '}d{n}" for n, v in zip(free, d) if v
    ]
    return " ".join(terms).removeprefix("+ ")


# -- comparison with the analytic model -----------------------------------------------------------


@dataclass(frozen=True)
class Comparison:
    """Identified versus analytic coefficients; `truth_fit` (fit to noise-free data) splits the
    error into the linear model's bias (truth_fit − analytic) and noise (identified − truth_fit)."""

    names: tuple[str, ...]
    analytic: np.ndarray
    identified: np.ndarray
    std: np.ndarray
    truth_fit: np.ndarray | None = None
    note: str = ""  # why the truth fit is missing, when it failed

    def rows(self) -> list[dict]:
        out = []
        for k, n in enumerate(self.names):
            a, x, s = self.analytic[k], self.identified[k], self.std[k]
            row = {
                "name": n,
                "analytic": float(a),
                "identified": float(x),
                "std": float(s),
                "relative_error": float((x - a) / abs(a)) if a else None,
                "error_sigmas": float((x - a) / s) if 0 < s < np.inf else None,
            }
            if self.truth_fit is not None:
                t = self.truth_fit[k]
                row["truth_fit"] = float(t)
                row["model_bias_relative"] = float((t - a) / abs(a)) if a else None
                row["noise_sigmas"] = float((x - t) / s) if 0 < s < np.inf else None
            out.append(row)
        return out

    def to_dict(self) -> dict:
        """The rows as JSON values: a value that is not finite (the unbounded std of a direction
        the data do not determine) is null."""
        rows = [
            {k: None if isinstance(v, float) and not np.isfinite(v) else v for k, v in r.items()}
            for r in self.rows()
        ]
        return {"rows": rows, **({"note": self.note} if self.note else {})}

    def cells(self) -> tuple[list[str], list[list[str]]]:
        """The column names and each coefficient's row as text ("-" where a value is undefined)."""
        head = ["coefficient", "analytic", "identified", "std", "rel.err", "sigmas"]
        if self.truth_fit is not None:
            head += ["truth fit", "lin.bias", "noise σ"]

        def f(v, fmt):
            return format(v, fmt) if v is not None else "-"

        rows = []
        for r in self.rows():
            row = [
                r["name"],
                f"{r['analytic']:.4g}",
                f"{r['identified']:.4g}",
                f"{r['std']:.2g}",
                f(r["relative_error"], ".1%"),
                f(r["error_sigmas"], ".1f"),
            ]
            if self.truth_fit is not None:
                row += [
                    f"{r['truth_fit']:.4g}",
                    f(r["model_bias_relative"], ".1%"),
                    f(r["noise_sigmas"], ".1f"),
                ]
            rows.append(row)
        return head, rows

    def table(self) -> str:
        head, rows = self.cells()
        widths = [12, 12, 12, 10, 9, 8, 12, 9, 8]
        lines = [
            "".join(v.ljust(w) if k == 0 else v.rjust(w) for k, (v, w) in enumerate(zip(row, widths)))
            for row in [head, *rows]
        ]
        if self.note:
            lines.append(self.note)
        return "\n".join(lines)

    def _repr_html_(self) -> str:
        """The comparison in a notebook: one row per coefficient, as `table`, and a figure of each
        error in its σ with the ±2σ band."""
        rows = self.rows()
        errors = [np.nan if r["error_sigmas"] is None else r["error_sigmas"] for r in rows]
        figure = svg_dots(
            [r["name"] for r in rows],
            errors,
            "identified − analytic, in the estimate's σ",
            "(identified − analytic) / σ",
            band=(-2.0, 2.0),
            reference=0.0,
        )
        return html_table(*self.cells(), self.note or "identified against the analytic coefficients") + figure


def compare(estimate, analytic_config, truth_estimate=None) -> Comparison:
    """Compare an `Estimate` with a model config's coefficients (and a fit to noise-free data,
    used only if it converged)."""
    names = tuple(estimate.free)
    analytic = np.array([analytic_config.coefficients[base_name(n)] for n in names])
    truth, note = None, ""
    if truth_estimate is not None and truth_estimate.converged:
        t = truth_estimate.coefficients
        truth = np.array([t[n] for n in names])
    elif truth_estimate is not None:
        note = (
            f"no linear-model bias column: the {truth_estimate.method} fit to the noise-free "
            f"truth did not converge ({truth_estimate.status.message})"
        )
    return Comparison(names, analytic, np.asarray(estimate.values), np.asarray(estimate.std), truth, note)
