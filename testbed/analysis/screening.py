"""The screen of a candidate list: which of a config's free coefficients these data determine.

Stage 1 fixes what the analysis at the a-priori values cannot determine (the linear model's
structurally unidentified candidates, `structurally_unidentified`); stage 2 fits the rest and
fixes, by backward elimination, those the estimate does not make significant (`insignificant`,
checked by the likelihood ratio). `screening` runs both for the linear model (`LINEAR`) or
another (`ScreenModel`); `jobs.identify.identify_screened` fits the screened list with the
method asked for.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable, Mapping, Sequence

import numpy as np

from testbed.analysis.identifiability import UNCERTAIN, Identifiability, direction_text, identifiability
from testbed.data import Experiment, ModelConfig
from testbed.estimators import Estimate, Status, identify
from testbed.errors import Unflyable
from testbed.identification.bounds import crlb, fisher
from testbed.identification.problem import base_name, check_fit, expanded
from testbed.simulation.measurements import noise_from_data

__all__ = [
    "LINEAR",
    "SIGNIFICANT",
    "Screen",
    "ScreenModel",
    "LIKELIHOOD_RATIO",
    "insignificant",
    "screen",
    "screening",
    "structurally_unidentified",
    "unidentified",
    "without",
]


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
                f"the Fisher information of these data is singular along {direction_text(result.free, d)} "
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
    candidates = without(config, fixed)
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
    return Screen(without(config, fixed), fixed, fit, skipped)


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


def without(config: ModelConfig, fixed) -> ModelConfig:
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


def unidentified(experiments, config, noise_std=None) -> dict[str, str]:
    """The screen's rule where the data would come from the config's own model (the design's
    default free set), name → why: stage 1, then stage 2 at the config's coefficients, which a fit
    of such data estimates (on average), with the Fisher information there; no fit needed."""
    result = identifiability(experiments, config, noise_std)
    fixed = _by_name(result.free, structurally_unidentified(result))
    rest = without(config, fixed)
    if rest.free:
        fitted = rest.fitted(experiments)
        names = expanded(rest, [e.name for e in fitted])[0]
        values = [config.coefficients[base_name(n)] for n in names]
        information = fisher(fitted, rest, noise_std=noise_std)
        fixed.update(_by_name(names, insignificant(names, values, information, values)))
    return fixed
