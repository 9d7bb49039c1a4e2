"""The output-error methods on a nonlinear model config (one with `[terms]`): `ml-gn` by
`nonlinear_output_error.fit_output_error` (damped Gauss-Newton with the flight's exact
sensitivities, R estimated by relaxation, each record's measured initial states free), behind
the same contract and `Estimate` as the linear model's methods.

What a linear method's option means here:

- `max_iter`: the iteration limit (every stage of the fit's record-length halving counted);
- `tol`: converged when every parameter's step is below `tol` × its Cramér-Rao σ;
- `start`: `config` (the config's values); `auto` is `config` too, the only start the nonlinear
  model has (no equation-error or MEKF start for it);
- any other option (`segments`, the global start's `samples` …) has no meaning for it: given a
  value other than its default, an `OptionError` names it.

The records must measure the same states with every sample present (`nonlinear_output_error.records`);
no value is estimated per record.
"""

from __future__ import annotations

import time
from dataclasses import fields
from typing import Sequence

import numpy as np

from testbed.data import Experiment, ModelConfig
from testbed.errors import InputError
from testbed.estimators.base import Callback, Estimate, OptionError, Options, Progress, Status
from testbed.identification.nonlinear_output_error import fit_output_error, records
from testbed.identification.recursions import counting
from testbed.models.linear import STATES

__all__ = ["STARTS", "gauss_newton"]

STARTS = ("auto", "config")  # the starts a nonlinear model has: its config's values
_MEANT = ("max_iter", "tol", "start")  # the options the nonlinear fit honours
_STATUS = {"converged": Status.CONVERGED, "iteration limit": Status.MAX_ITERATIONS, "stalled": Status.STALLED}


def _settings(method: str, options: Options) -> dict:
    """The fit's settings from the method's options; `OptionError` for one it cannot honour."""
    for f in fields(options):
        value = getattr(options, f.name)
        if f.name not in _MEANT and value != f.default:
            raise OptionError(
                method, f.name, value, "its default: the nonlinear model's fit has no such option"
            )
    if options.start not in STARTS:
        raise OptionError(method, "start", options.start, "auto or config for a nonlinear model config")
    if options.max_iter < 1:
        raise OptionError(method, "max_iter", options.max_iter, "an integer ≥ 1 for a nonlinear model config")
    return dict(tolerance=float(options.tol), max_iterations=int(options.max_iter))


def gauss_newton(
    experiments: Sequence[Experiment], config: ModelConfig, options: Options, callback: Callback | None
) -> Estimate:
    """`ml-gn` on a nonlinear model config (module doc)."""
    t0 = time.perf_counter()
    name = "ml-gn"
    settings = _settings(name, options)
    source = config.source or "config"
    if not config.free:
        raise InputError(f"{source}: [identify] free is empty; expected the coefficients to estimate")
    if config.per_record:
        raise InputError(
            f"{source}: [identify] per_record {config.per_record[0]!r}; the nonlinear model's fit "
            "estimates every value once for all records"
        )
    channels, recs = records(experiments, f"{name} on a nonlinear model config")
    model, theta = config.nonlinear()
    noise = {c: s for c, s in (config.noise_std or {}).items() if c in channels}
    history = [theta[[model.names.index(n) for n in config.free]]]

    def step(values: np.ndarray, cost: float) -> None:
        history.append(values)
        if callback is not None:
            callback(Progress(len(history) - 1, values.copy(), cost))

    with counting() as tally:
        fit = fit_output_error(
            model, theta, recs, channels, config.free, noise_std=noise, callback=step, **settings
        )
    return Estimate(
        method=name,
        status=_STATUS[fit.status],
        free=tuple(config.free),
        values=np.array([fit.estimates[n] for n in config.free]),
        std=np.array([fit.std[n] for n in config.free]),
        cost=fit.cost,
        iterations=fit.iterations,
        wall_time_s=time.perf_counter() - t0,
        noise_std=dict(fit.noise_std),
        evaluations=-(-tally[0] // sum(len(r.t) for r in recs)),
        history=np.array(history),
        initial_states={
            e.name: {c: float(x[STATES.index(c)]) for c in channels}
            for e, x in zip(experiments, fit.initial_states)
        },
    )
