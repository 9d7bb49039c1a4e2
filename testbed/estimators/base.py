"""The contract every estimator keeps: its options, its result, its progress reports, its status.

`testbed.estimators` registers the methods and is the front door (`identify`).
"""

from __future__ import annotations

import enum
import json
import math
from dataclasses import dataclass, field, fields
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from testbed.data import Experiment, ModelConfig
from testbed.html_figures import svg_dots
from testbed.html_table import html_table
from testbed.errors import InputError
from testbed.models.linear import Structure, inertia_defect

__all__ = [
    "Callback",
    "Estimate",
    "Method",
    "OptionError",
    "Options",
    "Outcome",
    "Progress",
    "Status",
    "bounds_message",
    "bounds_text",
    "count_option",
    "is_count",
    "option",
    "unphysical",
]


class Status(enum.Enum):
    """How a fit ended; only CONVERGED is a success. The value is the message."""

    CONVERGED = "converged"
    MAX_ITERATIONS = "iteration limit reached before convergence"
    STALLED = "no step decreased the cost"
    DIVERGED = "the model or the filter diverged"
    SADDLE = "stopped at a stationary point that is not a minimum (the second-order check failed)"
    WORSE = "ended with a higher cost than its start"

    @property
    def message(self) -> str:
        return self.value


@dataclass(frozen=True)
class Estimate:
    """A fit: the free coefficients with their Cramér-Rao standard errors, and how it went.

    Attributes:
        method: the registered name of the method that made it.
        status: how the fit ended (`Status`); `converged` is `status is Status.CONVERGED`.
        free: the names of the estimated coefficients, in the order of `values` and `std`.
        values: (n_free,) the estimates.
        std: (n_free,) their Cramér-Rao standard errors at the estimate, with the estimated
            noise (NaN where the fit diverged).
        cost: the method's cost at the estimate (the negative log-likelihood for the
            output-error methods and the filters' innovations).
        iterations: iterations taken (`iterative` methods, over every start tried) or samples
            processed (`online`).
        wall_time_s: wall-clock time of the fit.
        evaluations: how many times the fit simulated the model over the whole data set, a
            sensitivity pass counting 1 + n_free (the states and their derivatives), as tallied
            where the simulations run (`recursions.counting`; shorter records count their share,
            rounded up in the total), the Cramér-Rao analysis at the estimate not included.
            ml-gn, ml-lm, ml-nr: cost evaluations and sensitivity passes (ml-nr's
            second-order pass counts 1 + n_free too), over every start tried (a start's own
            fit, the MEKF's, included); ml-fem: its filter passes over the data (a
            finite-difference column one, the initial-state columns one each); ml-nm: its cost evaluations (`concentrated.cost`: three sweeps each) and its
            noise updates' simulations; mekf, ekf: passes × (1 + n_free), the filter
            propagating the state and its parameter columns (a pass cut short by
            `max_samples` counts its share); equation-error: 0 (a regression, no simulation).
        noise_std: measurement noise σ per measured state, as estimated or used.
        start: where the fit started: "config" (the a-priori values), "equation-error", "mekf".
        history: (iterations + 1, n_free) values after each iteration (filters: each sample).
        message: what went wrong, where the status alone does not say (a divergence's reason).
        start_reason: why the fit started from `start` rather than the a-priori values.
        starts: every start tried (`start` auto or global): its name, the cost it reached, its
            status and iterations (and `left`: the coefficients it left at their a-priori
            values, name → why), then every start that could not be computed, with its
            `reason`; the estimate is the one of least cost.
        crlb_corrected_std: (n_free,) the bounds corrected for coloured residuals
            (output-error methods; None otherwise).
        initial_states: experiment → state → fitted initial value (absolute u), for the
            output-error methods, which estimate them (None otherwise).
        process_noise_std: body state → {"value", "std"}: the process noise's standard deviation
            f (continuous time, state unit/√s) and its Cramér-Rao bound, for `ml-fem`, which
            estimates it (None otherwise).
        information: the Fisher information at the estimate from which `std` comes, over the
            free coefficients and then each record's fitted initial states in its measured
            states (the nonlinear model's output-error fits; None otherwise): its analysis
            (`nonlinear_identifiability`) takes it rather than fly the sensitivities again.
        at_bounds: the free coefficients the fit ended on a bound of (`[identify] bounds` and the
            physical sides), name → the bound; each is held there, its σ NaN, the others' σ with
            it held (None: no bound reached, or a method that takes none).
    """

    method: str
    status: Status
    free: tuple[str, ...]
    values: np.ndarray
    std: np.ndarray
    cost: float
    iterations: int
    wall_time_s: float
    noise_std: dict[str, float]
    evaluations: int = 0
    start: str = "config"
    history: np.ndarray | None = field(default=None, repr=False)
    message: str = ""
    start_reason: str = ""
    starts: tuple[dict, ...] = ()
    crlb_corrected_std: np.ndarray | None = field(default=None, repr=False)
    initial_states: dict[str, dict[str, float]] | None = field(default=None, repr=False)
    process_noise_std: dict[str, dict[str, float]] | None = field(default=None, repr=False)
    information: np.ndarray | None = field(default=None, repr=False)
    at_bounds: dict[str, float] | None = None

    @property
    def converged(self) -> bool:
        return self.status is Status.CONVERGED

    @property
    def coefficients(self) -> dict[str, float]:
        return dict(zip(self.free, map(float, self.values)))

    def bounds_text(self) -> str:
        """The bounds the fit ended on, as `name = value` (empty where none)."""
        return bounds_text(self.at_bounds or {})

    def json_fields(self) -> dict[str, Any]:
        """The estimate as the estimates JSON's fields (a mapping of JSON values)."""
        doc = {
            "method": self.method,
            "converged": self.converged,
            "status": self.status.message,
            "iterations": int(self.iterations),
            "evaluations": int(self.evaluations),
            "cost": _finite(self.cost),
            "wall_time_s": float(self.wall_time_s),
            "start": self.start,
            "coefficients": {
                n: {"value": _finite(v), "std": _finite(s)}
                for n, v, s in zip(self.free, self.values, self.std)
            },
            "noise_std": {k: _finite(v) for k, v in self.noise_std.items()},
        }
        if self.crlb_corrected_std is not None:
            doc["crlb_corrected_std"] = {n: _finite(s) for n, s in zip(self.free, self.crlb_corrected_std)}
        if self.initial_states is not None:
            doc["initial_states"] = self.initial_states
        if self.process_noise_std is not None:
            doc["process_noise_std"] = {
                s: {k: _finite(v) for k, v in d.items()} for s, d in self.process_noise_std.items()
            }
        if self.start_reason:
            doc["start_reason"] = self.start_reason
        if self.starts:
            doc["starts"] = [{**t, "cost": _finite(t["cost"])} for t in self.starts]
        if self.status is Status.DIVERGED:
            doc["diverged"] = {"reason": self.message or self.status.message}
        if self.at_bounds:
            doc["at_bounds"] = {n: float(v) for n, v in self.at_bounds.items()}
        return doc

    def to_json(self) -> str:
        return json.dumps(self.json_fields(), indent=2, allow_nan=False) + "\n"

    def _repr_html_(self) -> str:
        """The estimate in a notebook: how the fit ended, each coefficient with its bounds (and a
        figure of each bound relative to its estimate), the noise σ."""
        coloured = self.crlb_corrected_std if self.crlb_corrected_std is not None else [None] * len(self.free)
        rows = [
            (n, f"{v:.6g}", f"{s:.3g}", "-" if c is None else f"{c:.3g}")
            for n, v, s, c in zip(self.free, self.values, self.std, coloured)
        ]
        head = ("coefficient", "estimate", "σ (Cramér-Rao)", "σ (coloured residuals)")
        summary = (
            f"{self.method}: {self.status.message}, {self.iterations} iterations, cost {self.cost:.6g}, "
            f"from the {self.start} start"
            + (f"; on its bounds: {self.bounds_text()}" if self.at_bounds else "")
        )
        noise = html_table(("state", "noise σ"), [(k, f"{v:.3g}") for k, v in self.noise_std.items()])
        with np.errstate(divide="ignore", invalid="ignore"):
            relative = 200 * np.asarray(self.std, float) / np.abs(np.asarray(self.values, float))
        figure = svg_dots(self.free, relative, "each estimate's ±2σ Cramér-Rao bound", "2σ / |estimate| (%)")
        return html_table(head, rows, summary) + figure + noise


def bounds_text(at_bounds: Mapping[str, float]) -> str:
    """Bounds reached, name → value, as `name = value, …`."""
    return ", ".join(f"{n} = {v:g}" for n, v in at_bounds.items())


def bounds_message(at_bounds: Mapping[str, float] | None) -> str:
    """An estimate's message for the bounds it ended on (`bounds_text`), empty where none."""
    return f"on its bounds: {bounds_text(at_bounds)}" if at_bounds else ""


def _finite(x) -> float | None:
    """`x` as a JSON number, or null where it is not finite (an unbounded standard error)."""
    x = float(x)
    return x if math.isfinite(x) else None


def unphysical(s: Structure, theta: np.ndarray) -> str | None:
    """Why coefficients a fit reached lie outside the physical region, as the reason of a
    DIVERGED result: no body has their inertia matrix (`inertia_defect`); None inside it."""
    defect = inertia_defect(s, theta)
    return (
        f"the fit left the physical region: the inertia matrix Mt is not a body's ({defect})"
        if defect
        else None
    )


@dataclass(frozen=True)
class Outcome:
    """Where an iterative optimiser stopped: the full parameter vector and how."""

    p: np.ndarray
    status: Status
    iterations: int
    history: np.ndarray  # (iterations + 1, n_free)
    fisher: np.ndarray | None = None  # M at p, when the optimiser has it (saves `assess` a pass)
    optimum: tuple = ()  # (θ, σ) where it converged, for later fits to recognise (`follow`)
    joined: int = -1  # which earlier optimum's basin it entered and stopped in (-1: none)
    cost: float | None = None  # the negative log-likelihood at p, when the optimiser has it
    simulated: tuple | None = None  # (states, residuals) per record at p, when the optimiser has them
    held: np.ndarray | None = None  # (n_free,) bool: the values it ends held on a bound of its box


@dataclass(frozen=True)
class Progress:
    """What a method reports to `callback` after each iteration (filters: each sample).

    Attributes:
        iteration: iterations done (filters: samples processed).
        values: (n_free,) the free coefficients now.
        cost: the method's cost now (NaN for the filters, whose cost is a sum over the samples).
        std: (n_free,) their σ now, for the filters; None otherwise.
    """

    iteration: int
    values: np.ndarray
    cost: float
    std: np.ndarray | None = None


Callback = Callable[[Progress], None]


class OptionError(InputError):
    """An option a method does not have, or a value it cannot take. `option` names it."""

    def __init__(self, method: str, option: str, value, expected: str):
        self.method, self.option, self.value, self.expected = method, option, value, expected
        super().__init__(f"{method}: option {option}={value!r}; expected {expected}")


def option(default, check: Callable[[Any], bool], expected: str, doc: str):
    """A typed option: its default, the test a value must pass, what that test expects (for
    the error), and what the option does."""
    return field(default=default, metadata={"check": check, "expected": expected, "doc": doc})


def is_count(v) -> bool:
    """An integer (not a bool)."""
    return isinstance(v, (int, np.integer)) and not isinstance(v, bool)


def count_option(default: int, least: int, doc: str):
    """An integer option of at least `least`."""
    return option(default, lambda v: is_count(v) and v >= least, f"an integer ≥ {least}", doc)


@dataclass(frozen=True)
class Options:
    """A method's options: frozen, built by keyword, every field an `option` with its check."""

    @classmethod
    def build(cls, method: str, given: Options | Mapping | None = None, **more) -> Options:
        """The options of `method` from an instance, a mapping and keywords (later ones win);
        `OptionError` for an unknown name or a value its check rejects."""
        values = {}
        if isinstance(given, Options):
            if not isinstance(given, cls):
                raise OptionError(method, "options", type(given).__name__, f"{cls.__name__}")
            values = {f.name: getattr(given, f.name) for f in fields(given)}
        elif given is not None:
            values = dict(given)
        values.update(more)
        names = [f.name for f in fields(cls)]
        for name in values:
            if name not in names:
                raise OptionError(
                    method, name, values[name], f"one of the options of {method}: {', '.join(names)}"
                )
        built = cls(**values)
        for f in fields(cls):
            v = getattr(built, f.name)
            if not f.metadata["check"](v):
                raise OptionError(method, f.name, v, f.metadata["expected"])
        return built

    @classmethod
    def describe(cls) -> dict[str, str]:
        """Option name → what it does and its default."""
        return {f.name: f"{f.metadata['doc']} (default {f.default!r})" for f in fields(cls)}


@dataclass(frozen=True)
class Method:
    """A registered method: what `identify` calls, with its options and capabilities.

    Attributes:
        name: the name users select it by.
        fit: `fit(experiments, config, options, callback) -> Estimate`, given checked inputs.
        options: its `Options` class.
        summary: one line saying what it is.
        iterative: iterates to an optimum; options have `max_iter`.
        starts: options have `start`.
        online: a one-pass recursive filter; options have `max_samples`; returns a
            `FilterEstimate`.
        nonlinear: `nonlinear(experiments, config, options, callback) -> Estimate` for a
            nonlinear model config (one with `terms`); None: the method fits the linear model only.
        refuses: `refuses(config)` raises `InputError` for what the method cannot take in a
            linear model config, whatever the data (a free output term, values per record): checked
            before any fit, the screen's included. None: it takes any.
        refuses_nonlinear: `refuses_nonlinear(config, options)`, the same for a nonlinear model
            config, and its `options` (built) the nonlinear fit cannot honour (`OptionError`).
        refuses_data: `refuses_data(experiments, config)` raises `InputError` for data the method
            cannot run on in a linear model config whatever is free (records whose samples recur
            at no fixed period, for a periodic filter): checked before any fit, the screen's
            included. None: any data `problem.check_fit` takes.
        bounds: keeps the free values in the box of `[identify] bounds` (and a nonlinear model
            config's physical bounds); a method that does not refuses a config with bounds.
    """

    name: str
    fit: Callable[[Sequence[Experiment], ModelConfig, Options, Callback | None], Estimate]
    options: type[Options]
    summary: str
    iterative: bool = True
    starts: bool = True
    online: bool = False
    nonlinear: Callable[[Sequence[Experiment], ModelConfig, Options, Callback | None], Estimate] | None = None
    refuses: Callable[[ModelConfig], None] | None = None
    refuses_nonlinear: Callable[[ModelConfig, Options], None] | None = None
    refuses_data: Callable[[Sequence[Experiment], ModelConfig], None] | None = None
    bounds: bool = False

    def __post_init__(self):
        names = {f.name for f in fields(self.options)}
        for flag, needs in (
            (self.iterative, "max_iter"),
            (self.starts, "start"),
            (self.online, "max_samples"),
        ):
            if flag and needs not in names:
                raise TypeError(f"method {self.name}: its capabilities need the option {needs}")
