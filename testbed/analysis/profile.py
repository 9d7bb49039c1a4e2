"""The profile likelihood of one coefficient: how far a value lies from the estimate by the
likelihood itself, not by its quadratic approximation.

The Cramér-Rao σ is the curvature of the negative log-likelihood J at the estimate θ̂: it measures
a distance well only where J is quadratic over it. A weakly excited coefficient is not: the data
may determine its logarithm or its reciprocal (a time constant) rather than the coefficient, and
the σ then grows and shrinks with the estimate (II-trial's Z_w: docs/studies.md). The
likelihood-ratio statistic at a value c of coefficient θ_i,

    Λ(c) = 2 (min_{θ: θ_i = c} J(θ) − J(θ̂)),

is the fit again with θ_i held at c (every other free value, the initial states and the noise
refitted: the profile), χ²₁-distributed where c is the truth (Wilks), whatever the
parametrisation. Its signed root `sign(c − θ̂_i) √Λ` is the distance in σ the likelihood gives;
where J is quadratic it is the Wald `(c − θ̂_i) / σ_i`, and |·| ≤ 3 is the 99.73 % region
(Venzon & Moolgavkar 1988; Raue et al. 2009 for identifiability).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Sequence

from testbed.data import Experiment, ModelConfig
from testbed.errors import InputError
from testbed.estimators import Estimate, identify, lookup
from testbed.identification.problem import base_name

__all__ = ["Profile", "profile"]


@dataclass(frozen=True)
class Profile:
    """The likelihood ratio of one coefficient at one value.

    Attributes:
        name: the coefficient.
        value: the value it was held at.
        statistic: Λ = 2 (J held − J at the estimate), χ²₁ where `value` is the truth (negative
            where the fit held at `value` found a lower cost than the estimate had: it was not
            at the optimum).
        sigmas: the signed root `sign(value − estimate) √max(Λ, 0)`: the distance in σ by the
            likelihood ratio.
        held: the fit with the coefficient held (its status says whether the profile's minimum
            was reached: a fit that stopped short gives a Λ too large).
    """

    name: str
    value: float
    statistic: float
    sigmas: float
    held: Estimate


def profile(
    experiments: Sequence[Experiment],
    config: ModelConfig,
    estimate: Estimate,
    name: str,
    value: float,
    **options,
) -> Profile:
    """The likelihood ratio of `estimate` (fitted to `experiments` with `config`) at `name` =
    `value`: the same method refitted from the estimate with `name` held at `value` (`options`:
    the method's, as for the estimate; `start` is the estimate where the method has starts)."""
    if base_name(name) in config.per_record:
        raise InputError(f"profile: {name!r} is fitted per record; expected a value shared by the records")
    if name not in estimate.free:
        raise InputError(
            f"profile: {name!r} is not a free value of the estimate; expected one of {', '.join(estimate.free)}"
        )
    if not math.isfinite(value):
        raise InputError(f"profile: {name} = {value!r}; expected a finite number")
    # the estimate's free values less `name` (a screened estimate's: the ones the screen kept)
    fitted = {base_name(n) for n in estimate.free}
    free = tuple(n for n in config.free if n != name and n in fitted)
    held_config = replace(
        config.with_coefficients(estimate.coefficients | {name: float(value)}), free=free, screen=False
    )
    if lookup(estimate.method).starts:
        options = {"start": "config"} | options
    held = identify(experiments, held_config, method=estimate.method, **options)
    statistic = 2.0 * (held.cost - estimate.cost)
    root = math.copysign(math.sqrt(max(statistic, 0.0)), value - estimate.coefficients[name])
    return Profile(name, float(value), float(statistic), float(root), held)
