"""The a-priori model a user would start from, and the judge of a fit against the data's optimum.

`prior` perturbs a model config's 35 coefficients the way a user's a-priori model is wrong: each
coefficient by a log-normal factor exp(s_c·z), z ~ N(0, 1), with s_c = `SPREAD[class] · s`, its
class's relative spread scaled by the start spread s; a coefficient analysed at 0 by an additive
error `ZERO_SIGMAS · s_c · σ · z` in its Cramér-Rao σ. Free and fixed coefficients alike; the
vehicle's constants (mass, inertia, weight, buoyancy, centre of buoyancy, speed) are known and
kept. The draws come from their own random stream of (seed, `PRIOR_STREAM`), one z per
coefficient in `COEFFICIENTS` order, so one scenario, seed and spread give one prior whatever
the method, the free set or the noise's streams (`testbed.simulation.measurements`).

`judge` says whether a fit reached the best-likelihood optimum of its data set — its cost
within the likelihood-ratio bound χ²_LEVEL(p)/2 of the optimum's, the region a likelihood-ratio
test cannot tell from it: what a stopping rule on the cost can deliver, and a filter too — and,
when it did not, how it failed (`Ending`). Its largest distance from the optimum in the
optimum's σ is measured beside it, never part of the verdict.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from testbed.data import ModelConfig
from testbed.errors import InputError, is_number
from testbed.estimators.base import Estimate, Status
from testbed.models.linear import COEFFICIENTS
from testbed.models.regressors import component_kind, parse_term
from testbed.simulation.measurements import check_seed

__all__ = [
    "MEMBERS",
    "CLASSES",
    "SPREAD",
    "ZERO_SIGMAS",
    "PRIOR_STREAM",
    "TERM_STREAM",
    "LEVEL",
    "prior",
    "term_class",
    "term_prior",
    "Ending",
    "Judgement",
    "cost_bound",
    "judge",
]

ADDED_MASS, DAMPING, CONTROL, CROSS = "added mass", "damping", "control", "cross-coupling"

# The classes and their coefficients: the …dot terms are added mass; the fins' derivatives are
# control; the roll–sway/yaw couplings of the hydrodynamic forces (small off-diagonal terms) are
# cross-coupling; the velocity and rate terms left are damping.
MEMBERS: dict[str, tuple[str, ...]] = {
    ADDED_MASS: tuple(n for n in COEFFICIENTS if n.endswith("dot")),
    DAMPING: ("X_u", "Y_v", "Y_r", "Z_w", "Z_q", "K_p", "M_w", "M_q", "N_v", "N_r"),
    CONTROL: ("Y_dr", "Z_de", "K_dr", "K_der", "K_del", "M_de", "N_dr"),
    CROSS: ("Y_p", "K_v", "K_r", "N_p"),
}
CLASSES: dict[str, str] = {n: c for c, names in MEMBERS.items() for n in names}  # coefficient → class

# A class's log-normal spread per unit start spread: added mass is predicted well by strip
# theory and the ellipsoid's formulas; fin derivatives by lifting-surface theory, less well;
# damping (viscous, with the hull's cross-flow) worse; the small cross-coupling terms worst.
SPREAD: dict[str, float] = {ADDED_MASS: 0.5, CONTROL: 0.75, DAMPING: 1.0, CROSS: 1.5}

# A coefficient analysed at 0 is off by ZERO_SIGMAS · s_c of its Cramér-Rao σ (sd): at s = 0.4
# a damping-class zero is 4 σ off, an error the likelihood sees but a local fit can recover.
ZERO_SIGMAS = 10.0

# The prior's stream: SeedSequence(seed, spawn_key=(PRIOR_STREAM,)), apart from the noise's
# streams (spawn keys (experiment, stream)) of the same seed.
PRIOR_STREAM = 0x7072696F
# A nonlinear model's terms draw from SeedSequence(seed, spawn_key=(PRIOR_STREAM, TERM_STREAM))
TERM_STREAM = 1

LEVEL = 0.95  # success: ΔJ ≤ χ²_LEVEL(p)/2, the likelihood-ratio confidence region at LEVEL


def prior(
    config: ModelConfig, spread: float, seed: int, std: Mapping[str, float] | None = None
) -> ModelConfig:
    """The a-priori model for start spread `spread` (s ≥ 0) and `seed`: `config` with every
    coefficient perturbed (module docstring); `std` maps each coefficient `config` has at 0 to
    its Cramér-Rao σ on the data set (`analyze`'s bounds). s = 0 returns `config` itself."""
    if not (is_number(spread) and spread >= 0):
        raise InputError(f"start spread {spread!r}: expected a finite number ≥ 0")
    seed = check_seed(seed)
    if spread == 0:
        return config
    std = std or {}
    zeros = [n for n in COEFFICIENTS if config.coefficients[n] == 0]
    bad = [n for n in zeros if not (n in std and math.isfinite(std[n]) and std[n] >= 0)]
    if bad:
        raise InputError(
            f"{config.source or 'config'}: {', '.join(bad)} analysed at 0 without a finite "
            "Cramér-Rao σ; expected σ ≥ 0 for every coefficient at 0 to size its additive error"
        )
    z = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(PRIOR_STREAM,))).standard_normal(
        len(COEFFICIENTS)
    )
    values = {}
    for n, zn in zip(COEFFICIENTS, z):
        theta, s_c = float(config.coefficients[n]), SPREAD[CLASSES[n]] * spread
        values[n] = theta * math.exp(s_c * zn) if theta != 0 else ZERO_SIGMAS * s_c * float(std[n]) * zn
    return config.with_coefficients(values)


def term_class(name: str) -> str:
    """The class of the nonlinear model's term `name`: its linear counterpart's, the term less its
    u factors (`Y_uv` → `Y_v`, `Z_uude` → `Z_de`, `X_uu` → `X_u`); without one (`K_uuda`, the
    fins' differential) control for a term of a fin, damping otherwise; a component term's
    control for a blade's lift or Munk term, damping otherwise."""
    kind = component_kind(name)
    if kind is not None:
        return CONTROL if kind in ("lift", "munk") else DAMPING
    rest = [a for a in parse_term(name).factors if a != "u"]
    counterpart = f"{name[0]}_{''.join(rest) or 'u'}"
    if counterpart in CLASSES:
        return CLASSES[counterpart]
    return CONTROL if any(a.strip("|").startswith("d") for a in rest) else DAMPING


def term_prior(config: ModelConfig, names, spread: float, seed: int) -> ModelConfig:
    """The a-priori values of a nonlinear model config's terms `names` (the rest kept): each term
    θ ≠ 0 by the log-normal factor exp(s_c·z) of `prior`, s_c = `SPREAD[term_class]` · `spread`,
    one z per name in order from the terms' own stream of `seed` (`TERM_STREAM`); a term at 0
    has no scale to be wrong by and stays 0. s = 0 returns `config` itself."""
    if not (is_number(spread) and spread >= 0):
        raise InputError(f"start spread {spread!r}: expected a finite number ≥ 0")
    seed = check_seed(seed)
    if spread == 0:
        return config
    names = tuple(names)
    stream = np.random.SeedSequence(seed, spawn_key=(PRIOR_STREAM, TERM_STREAM))
    z = np.random.default_rng(stream).standard_normal(len(names))
    return config.with_coefficients(
        {n: config.terms[n] * math.exp(SPREAD[term_class(n)] * spread * zn) for n, zn in zip(names, z)}
    )


class Ending(enum.Enum):
    """A fit judged against the data's optimum; the value is the message."""

    SUCCESS = "reached the best-likelihood optimum"
    DIVERGED = "diverged"
    STALLED = "stalled at the limit"
    ELSEWHERE = "converged elsewhere"


@dataclass(frozen=True)
class Judgement:
    """A fit against the optimum: its outcome, the largest |θ − θ̂|/σ over the free
    coefficients, ΔJ = J − Ĵ and the bound ΔJ had to meet."""

    outcome: Ending
    sigmas: float
    delta_cost: float
    bound: float

    @property
    def success(self) -> bool:
        return self.outcome is Ending.SUCCESS


def cost_bound(p: int, level: float = LEVEL) -> float:
    """χ²_level(p)/2, in the negative log-likelihood's units: by Wilks' theorem 2(J(θ) − Ĵ) is
    χ²(p) at the true θ for p free coefficients (the noise variances concentrated out), so the
    fits within it are those a likelihood-ratio test at `level` cannot tell from the optimum."""
    return float(chi2.ppf(level, p)) / 2


def judge(fit: Estimate, best: Estimate) -> Judgement:
    """`fit` against `best`, the best-likelihood fit of the same data and free set. Success iff
    its cost and coefficients are finite and ΔJ ≤ `cost_bound` (inside the optimum's likelihood
    region), whatever the fit's status: a filter's estimate, or an optimiser's stopped by a rule
    on the cost, can be as good as the data allow without sitting on the optimum. Otherwise:
    diverged (status diverged, or a non-finite value or cost), stalled at the limit (iteration
    limit or no decreasing step), or converged elsewhere (any other status: it stopped at a
    point the data tell from the optimum). `sigmas`, the largest |θ − θ̂|/σ over the free
    coefficients in `best`'s Cramér-Rao σ, is measured beside the verdict."""
    if set(fit.free) != set(best.free):
        raise InputError(
            f"fit of {', '.join(fit.free)} judged against an optimum of {', '.join(best.free)}; "
            "expected the same free coefficients"
        )
    theta, theta_hat, sigma = fit.coefficients, best.coefficients, dict(zip(best.free, map(float, best.std)))
    sigmas = max((_in_sigmas(theta[n] - theta_hat[n], sigma[n]) for n in best.free), default=0.0)
    delta, bound = float(fit.cost) - float(best.cost), cost_bound(len(best.free))
    finite = math.isfinite(fit.cost) and all(math.isfinite(v) for v in theta.values())
    if not finite:
        outcome = Ending.DIVERGED
    elif delta <= bound:
        outcome = Ending.SUCCESS
    elif fit.status is Status.DIVERGED:
        outcome = Ending.DIVERGED
    elif fit.status in (Status.MAX_ITERATIONS, Status.STALLED):
        outcome = Ending.STALLED
    else:
        outcome = Ending.ELSEWHERE
    return Judgement(outcome=outcome, sigmas=float(sigmas), delta_cost=delta, bound=bound)


def _in_sigmas(d: float, sigma: float) -> float:
    """|d| in units of σ: ∞ for a non-finite σ, or a non-zero d at σ = 0."""
    if not math.isfinite(sigma) or not math.isfinite(d):
        return math.inf
    if d == 0:
        return 0.0
    return abs(d) / sigma if sigma > 0 else math.inf
