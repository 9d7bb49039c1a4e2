"""One interface for every estimator, like `scipy.optimize.minimize(method=...)`.

`identify(experiments, config, method=...)` fits the free coefficients of `config` to the
experiments and returns an `Estimate`; methods register themselves by SPEC name, so they are
swapped by name and compared on the same data, start and free set.
"""

from __future__ import annotations

import enum
import json
import math
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from testbed.data import Experiment, ModelConfig
from testbed.model import STATES


class Status(enum.Enum):
    """How a fit ended; only CONVERGED is a success."""

    CONVERGED = "converged"
    MAX_ITERATIONS = "iteration limit reached before convergence"
    STALLED = "no step decreased the cost"
    DIVERGED = "the model or the filter diverged"

    @property
    def message(self) -> str:
        return self.value


@dataclass(frozen=True)
class Estimate:
    """A fit: the free coefficients with Cramér-Rao standard errors, and how it went."""

    method: str
    status: Status
    free: tuple[str, ...]
    values: np.ndarray  # (n_free,)
    std: np.ndarray  # (n_free,) Cramér-Rao standard errors at the estimate
    cost: float
    iterations: int
    wall_time_s: float
    noise_std: dict[str, float]  # per measured state
    start: str = "config"  # where the fit started: config, equation-error, mekf, ...
    history: np.ndarray = field(default=None, repr=False)  # (iterations+1, n_free) values
    extra: dict = field(default_factory=dict, repr=False)  # method-specific JSON-able results

    @property
    def converged(self) -> bool:
        return self.status is Status.CONVERGED

    @property
    def coefficients(self) -> dict[str, float]:
        return dict(zip(self.free, map(float, self.values)))

    def to_json(self) -> str:
        doc = {
            "method": self.method,
            "converged": self.converged,
            "status": self.status.message,
            "iterations": int(self.iterations),
            "cost": _finite(self.cost),
            "wall_time_s": float(self.wall_time_s),
            "start": self.start,
            "coefficients": {n: {"value": _finite(v), "std": _finite(s)}
                             for n, v, s in zip(self.free, self.values, self.std)},
            "noise_std": {k: _finite(v) for k, v in self.noise_std.items()},
            **self.extra,
        }  # fmt: skip
        return json.dumps(doc, indent=2, allow_nan=False) + "\n"


def _finite(x) -> float | None:
    """`x` as a JSON number, or null where it is not finite (an unbounded standard error)."""
    x = float(x)
    return x if math.isfinite(x) else None


Method = Callable[..., Estimate]
METHODS: dict[str, Method] = {}


def register(name: str):
    """Decorator: make `fn(experiments, config, **options) -> Estimate` available by name."""

    def deco(fn: Method) -> Method:
        METHODS[name] = fn
        return fn

    return deco


COARSEST = math.log(2.0**53)  # ρΔ beyond which the fastest mode decays below rounding in one step


def estimator(name: str) -> Method:
    """The estimator registered as `name`; `InputError` if there is none."""
    _load_methods()
    from testbed.errors import InputError

    if name not in METHODS:
        raise InputError(f"--method {name!r} is unknown; expected one of {', '.join(sorted(METHODS))}")
    return METHODS[name]


def identify(experiments: Sequence[Experiment], config: ModelConfig, method: str = "ml-gn",
             **options) -> Estimate:  # fmt: skip
    """Estimate `config.free` from `experiments` with the named method.

    Everything is checked before the fit starts (`check_fit`)."""
    fn = estimator(method)
    experiments = config.fitted(experiments)
    check_fit(experiments, config)
    return fn(experiments, config, **options)


def check_fit(experiments: Sequence[Experiment], config: ModelConfig) -> None:
    """`InputError` unless `config.free` can be fitted to the experiments' fitted outputs: the
    inputs check out (`check_inputs`) and every free coefficient is seen in the measured states
    (`model.unobserved`)."""
    from testbed.errors import InputError
    from testbed.model import structure, theta_vector, unobserved

    if not config.free:
        raise InputError(f"{config.source or 'config'}: [identify] free is empty; nothing to estimate")
    experiments = config.fitted(experiments)
    check_inputs(experiments, config)
    measured = {s for e in experiments for s in e.measured}
    blind = unobserved(structure(config.vehicle), theta_vector(config.coefficients), config.free, measured)
    if blind:
        raise InputError(f"{config.source or 'config'}: [identify] free {', '.join(blind)}: not "
                         f"identifiable, the measured states ({', '.join(s for s in STATES if s in measured)}) "
                         "do not depend on them in the model; measure the states they drive or fix them")  # fmt: skip


def check_inputs(experiments: Sequence[Experiment], config: ModelConfig) -> None:
    """`InputError` unless the experiments and the config can be fitted together, before any work:

    - each record is usable (`data.check_experiment`) and the config valid (`data.check_config`);
    - the config's Mt is the inertia of a body (`model.inertia_defect`): a singular or indefinite
      one makes every model built on it blow up, the fault of the config, not of the data;
    - each record's sampling interval Δ resolves the model: over one step the fastest mode
      (rate ρ) decays by e^(−ρΔ), and beyond ρΔ = ln 2⁵³ that is below double-precision
      rounding, so the record shows none of it. Such a step is the data's fault (t in ms, say).
    """
    from testbed.data import check_config, check_experiment
    from testbed.errors import InputError
    from testbed.model import fastest_rate, inertia_defect, structure, theta_vector

    if not experiments:
        raise InputError("no experiments given; expected at least one measurement record")
    for e in experiments:
        check_experiment(e)
    check_config(config)
    source = config.source or "config"
    s, theta = structure(config.vehicle), theta_vector(config.coefficients)
    defect = inertia_defect(s, theta)
    if defect:
        raise InputError(f"{source}: the inertia matrix Mt is not a body's: {defect}")
    rate = fastest_rate(s, theta)
    for e in experiments:
        dt = float(e.t[1] - e.t[0])
        if rate * dt > COARSEST:
            raise InputError(f"{e.source or e.name}: t steps {dt:g} s; the model of {source} has a "
                             f"mode at {rate:.3g} 1/s, which such a step cannot show: expected a step "
                             f"below {COARSEST / rate:.3g} s (t in seconds)")  # fmt: skip


def _load_methods() -> None:
    """Import the modules that register methods (kept lazy: the CLI starts fast)."""
    import importlib

    for mod in ("testbed.estimators.ml", "testbed.estimators.mekf"):
        try:
            importlib.import_module(mod)
        except ModuleNotFoundError as exc:
            if exc.name != mod:
                raise
