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
from testbed.linear import check_fit


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


def _load_methods() -> None:
    """Import the modules that register methods (kept lazy: the CLI starts fast)."""
    import importlib

    for mod in ("testbed.estimators.ml", "testbed.estimators.mekf"):
        try:
            importlib.import_module(mod)
        except ModuleNotFoundError as exc:
            if exc.name != mod:
                raise
