"""One front door for every estimator, like `scipy.optimize.minimize(method=...)`.

`identify(experiments, config, method=..., options=...)` fits the free coefficients of `config`
to the experiments and returns an `Estimate`. Every method is registered with the same contract
(`Method`): a name, the function that fits, its typed options (an `Options` dataclass: unknown
names and out-of-range values are an `OptionError` naming the option), and its capabilities, so
a caller never guesses them from the name:

- `iterative`: the method iterates towards an optimum; its options have `max_iter` and its
  `Estimate.iterations` counts those iterations;
- `starts`: its options have `start` (where the iterations begin);
- `online`: a recursive filter, one pass over the samples: its options have `max_samples`, its
  `Estimate.iterations` counts the samples processed, and it returns a `FilterEstimate` with the
  estimate and σ histories.

A method with none of them (`equation-error`) is solved at once, no limit: one iteration (on a
nonlinear model config, the few Gauss-Newton steps its rows' inertia terms take).

Every method reports its progress to `callback(Progress)` after each iteration (or sample).

The modules, in layer order: the contract (`base`), the equation-error methods' intervals
(`intervals`), the filters' algebra, model and options (`square_root`, `filter_model`,
`filter_options`), a box of bounds (`box_bounds`), fits from several starts (`multistart`), the
paper's simplex and its coordinates (`simplex`),
the default ML optimiser over either model's likelihood (`trust_region`), the filters' passes
(`filter_passes`), the nonlinear model's fit by it (`nonlinear_fit`), the nonlinear model's
equation error (`nonlinear_regression`: output error's start and the method), the filters as
methods (`mekf`), equation error (`equation_error`), the nonlinear model's output-error methods (`nonlinear`), the other
optimisers (`levenberg_marquardt`, `newton_raphson`, `nelder_mead`) and where the linear
model's fits start (`starts`), the ML methods (`ml`) and the filter-error method (`fem`, its likelihood `fem_likelihood`).
"""

from __future__ import annotations

from typing import Mapping, Sequence

from testbed.data import Experiment, ModelConfig, split
from testbed.errors import InputError
from testbed.estimators import equation_error, fem, mekf, ml
from testbed.estimators.base import Callback, Estimate, Method, OptionError, Options, Progress, Status
from testbed.estimators.filter_options import FilterEstimate, FilterOptions
from testbed.identification.problem import check_fit

__all__ = [
    "Callback",
    "Estimate",
    "FilterEstimate",
    "FilterOptions",
    "METHODS",
    "Method",
    "OptionError",
    "Options",
    "Progress",
    "Status",
    "check_method",
    "identify",
    "lookup",
    "register",
]

METHODS: dict[str, Method] = {
    m.name: m
    for m in (
        ml.ML_GN,
        ml.ML_LM,
        ml.ML_NR,
        ml.ML_NM,
        fem.ML_FEM,
        mekf.MEKF,
        mekf.EKF,
        equation_error.EQUATION_ERROR,
    )
}


def register(m: Method) -> Method:
    """Make `m` available to `identify` by its name (a method of the user's own)."""
    METHODS[m.name] = m
    return m


def lookup(name: str) -> Method:
    """The method registered as `name`; `InputError` if there is none."""
    if name not in METHODS:
        raise InputError(f"method={name!r} is unknown; expected one of {', '.join(sorted(METHODS))}")
    return METHODS[name]


def check_method(method: str, config: ModelConfig, options: Options | None = None) -> None:
    """`InputError` unless the named method fits the model of `config`: a method without a
    `nonlinear` fit refuses a nonlinear model config (`config.terms`), a linear one what it
    `refuses`, a nonlinear one what it `refuses_nonlinear` (with `options`, built; None: the
    defaults), and a method that keeps no bounds a config with `[identify] bounds`."""
    m = lookup(method)
    if config.terms is None and m.refuses is not None:
        m.refuses(config)
    if config.terms is not None and m.refuses_nonlinear is not None:
        m.refuses_nonlinear(config, m.options.build(m.name, None) if options is None else options)
    if config.terms is not None and m.nonlinear is None:
        takes = ", ".join(n for n, k in METHODS.items() if k.nonlinear is not None)
        raise InputError(
            f"method={m.name!r} fits the linear model only; {config.source or 'the config'} is a "
            f"nonlinear model config ([terms]); expected a linear model config, or {takes} for [terms]"
        )
    if config.bounds and not m.bounds:
        keeps = ", ".join(n for n, k in METHODS.items() if k.bounds)
        raise InputError(
            f"{config.source or 'config'}: [identify] bounds.{next(iter(config.bounds))}: {m.name} does not "
            f"keep bounds; expected {keeps}, or no [identify] bounds"
        )


def identify(
    experiments: Sequence[Experiment],
    config: ModelConfig,
    method: str = "ml-gn",
    options: Options | Mapping | None = None,
    callback: Callback | None = None,
    **more,
) -> Estimate:
    """Estimate `config.free` from `experiments` with the named method.

    `options`: the method's `Options` (or a mapping of them; keywords in `more` are added);
    `callback(Progress)` after every iteration or sample. Everything is checked before the fit
    starts: the options (`OptionError`), the data and the config (`problem.check_fit`). A
    nonlinear model config (`config.terms`) goes to the method's `nonlinear` fit; a method
    without one refuses it (`InputError`).
    """
    m = lookup(method)
    opts = m.options.build(m.name, options, **more)
    check_method(m.name, config, opts)
    if config.terms is not None:  # a record split at a dropout: its stretches (`data.split`)
        return m.nonlinear([p for e in config.fitted(experiments) for p in split(e)], config, opts, callback)
    experiments = config.fitted(experiments)
    check_fit(experiments, config)
    return m.fit(experiments, config, opts, callback)
