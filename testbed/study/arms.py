"""The study's arms: each a registered method with the options that make it one of the variants
the paper compares, or one of its future work's.

An arm is fitted from the a-priori model of its cell (`testbed.study.priors.prior`), the screen
run at that prior, so every arm of a data set, seed and spread starts from the same model with
the same free coefficients. The drift arms fit two fixed parametrisations instead, unscreened,
for conclusion 1 (`testbed.analysis.drift`): the Mt-form with the inertia terms free
(normalised) and the A-form with them known.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

from testbed.errors import InputError
from testbed.estimators.filter_options import PAPER_OPTIONS

__all__ = [
    "ARMS",
    "Arm",
    "DEFAULT_ARMS",
    "DRIFT_ARMS",
    "FACTORIAL_ARMS",
    "NONLINEAR_ARM",
    "NONLINEAR_ARMS",
    "arm",
    "arms",
]


@dataclass(frozen=True)
class Arm:
    """A method with options: `name` in results.csv, `method` the registered estimator. The
    output-error arms start from the cell's a-priori model alone (`start="config"`) unless the
    arm is about another start: the paired start is the point of the comparison.

    `free`: "screened" (the screen's free set at the cell's prior, shared by the judged arms),
    "mt" (the candidates and the inertia terms, normalised), "a" (the candidates as written,
    the inertia known) or "terms" (a `NONLINEAR_ARMS` arm: the nonlinear model's slope terms, on
    Scenario I flown on the plant); only the screened arms are judged against the data's optimum.

    `budget`: the iteration limit in units of the method's own (`ml-nr` 100 iterations, `ml-nm`
    `SIMPLEX_ITERATIONS` per free coefficient): the paper states none for its methods, so the
    study runs them at the testbed's limit and at ten times it."""

    name: str
    method: str
    summary: str
    options: Mapping = field(default_factory=dict)
    free: str = "screened"
    budget: int = 1

    @property
    def judged(self) -> bool:
        return self.free == "screened"


ARMS: dict[str, Arm] = {
    a.name: a
    for a in (
        Arm(
            "ml-nr",
            "ml-nr",
            "the paper's Newton-Raphson (Eq. 10), λ in SI units",
            {"coordinates": "si", "start": "config"},
        ),
        Arm(
            "ml-nr-10x",
            "ml-nr",
            "the paper's Newton-Raphson with ten times the testbed's iteration limit",
            {"coordinates": "si", "start": "config"},
            budget=10,
        ),
        Arm(
            "ml-nr-scaled",
            "ml-nr",
            "Newton-Raphson in coordinates scaled by the start",
            {"coordinates": "scaled", "start": "config"},
        ),
        Arm(
            "ml-nm-paper",
            "ml-nm",
            "the paper's Nelder-Mead: coefficients (1, 2, ½, ½), one simplex",
            {"coefficients": "paper", "restarts": False, "start": "config", "coordinates": "scaled"},
        ),
        Arm(
            "ml-nm-paper-10x",
            "ml-nm",
            "the paper's Nelder-Mead with ten times the testbed's iteration limit",
            {"coefficients": "paper", "restarts": False, "start": "config", "coordinates": "scaled"},
            budget=10,
        ),
        Arm(
            "ml-nm-paper-restarts",
            "ml-nm",
            "Nelder-Mead, the paper's coefficients, with restarts and record-length continuation",
            {"coefficients": "paper", "restarts": True, "start": "config", "coordinates": "scaled"},
        ),
        Arm(
            "ml-nm-adaptive",
            "ml-nm",
            "Nelder-Mead with Gao & Han's adaptive coefficients, one simplex",
            {"coefficients": "adaptive", "restarts": False, "start": "config", "coordinates": "scaled"},
        ),
        Arm(
            "ml-nm-adaptive-restarts",
            "ml-nm",
            "Nelder-Mead, adaptive coefficients, restarts and continuation (ml-nm's default)",
            {"coefficients": "adaptive", "restarts": True, "start": "config"},
        ),
        Arm("mekf-paper", "mekf", "the paper's square-root modified EKF: fixed model noise", PAPER_OPTIONS),
        Arm("mekf", "mekf", "the modified EKF with covariance-matched model noise (the default)"),
        Arm(
            "mekf+ml-gn",
            "ml-gn",
            "on-line then off-line: ml-gn from the MEKF's estimate (the paper's future work 1)",
            {"start": "mekf"},
        ),
        Arm(
            "ml-gn",
            "ml-gn",
            "output error by trust-region Gauss-Newton (the modern reference)",
            {"start": "config"},
        ),
        Arm(
            "ml-gn-global",
            "ml-gn",
            "ml-gn from the best draws of the prior's box (the paper's future work 2)",
            {"start": "global"},
        ),
        Arm(
            "drift-mt",
            "ml-gn",
            "conclusion 1: the Mt-form, inertia terms free (normalised)",
            {"start": "config"},
            "mt",
        ),
        Arm("drift-a", "ml-gn", "conclusion 1: the A-form, the inertia known", {"start": "config"}, "a"),
    )
}
# The nonlinear model's methods on Scenario I flown on the plant, each from the captive values
# perturbed as the linear arms' a-priori model is and judged against the captive reference
# (`study.cells`); `NONLINEAR_ARM` runs wherever that data set does, the others where chosen.
# No `ml-nr` (the flight has no second-order sensitivities) and no `ml-nm` here: every corner of
# its simplex is a flight, about 20 minutes a cell on Scenario I's 60 s records.
NONLINEAR_ARMS: dict[str, Arm] = {
    a.name: a
    for a in (
        Arm(
            "ml-gn-nonlinear",
            "ml-gn",
            "ml-gn on the nonlinear model (its reference fit)",
            {"start": "config"},
            "terms",
        ),
        Arm(
            "ml-lm-nonlinear",
            "ml-lm",
            "Levenberg-Marquardt on the nonlinear model",
            {"start": "config"},
            "terms",
        ),
        Arm(
            "mekf-nonlinear",
            "mekf",
            "the paper's MEKF on the nonlinear model: fixed model noise",
            PAPER_OPTIONS,
            "terms",
        ),
        Arm(
            "equation-error-nonlinear", "equation-error", "the nonlinear model's rows regressed", {}, "terms"
        ),
    )
}
NONLINEAR_ARM = "ml-gn-nonlinear"  # the nonlinear cell every plan with Scenario I on the plant has
# The paper's three methods as it ran them, the modern reference, and the drift arms (the other
# nonlinear arms by name or with `all`: each compiles its own flight kernels, 15 s more of
# `reproduce --quick` from an empty compile cache for `mekf-nonlinear`).
DEFAULT_ARMS = ("ml-nr", "ml-nm-paper", "mekf-paper", "ml-gn", "drift-mt", "drift-a")
FACTORIAL_ARMS = ("ml-gn",)  # the arms the input factorial's other inputs are fitted with (II: every arm)
DRIFT_ARMS = ("drift-mt", "drift-a")


def arm(name: str) -> Arm:
    """The arm called `name` (of `ARMS` or `NONLINEAR_ARMS`); `InputError` if there is none."""
    if name not in ARMS and name not in NONLINEAR_ARMS:
        raise InputError(
            f"arm {name!r} is unknown; expected one of {', '.join([*ARMS, *NONLINEAR_ARMS])}, or all"
        )
    return ARMS.get(name) or NONLINEAR_ARMS[name]


def arms(names) -> tuple[str, ...]:
    """The arms `names` lists (`all`: every arm), checked, in `ARMS` then `NONLINEAR_ARMS` order."""
    names = tuple(names)
    if "all" in names:
        return (*ARMS, *NONLINEAR_ARMS)
    for n in names:
        arm(n)
    return tuple(n for n in (*ARMS, *NONLINEAR_ARMS) if n in names)
