"""The output-error methods on a nonlinear model config (one with `[terms]`), behind the same
contract and `Estimate` as the linear model's methods:

- `ml-gn`: `nonlinear_output_error.fit_output_error`, damped Gauss-Newton with the flight's exact
  sensitivities, R estimated by relaxation, each record's measured initial states free;
- `ml-nm`: the paper's Nelder-Mead simplex (`simplex`) on the same likelihood,
  `J_M = 1/N Σ eᵀR⁻¹e` over the free coefficients in coordinates scaled by the start
  (θᵢ/|θᵢ,start|). Each record's initial state is concentrated out at every θ to first order:
  the residual less its weighted least-squares fit by the outputs' sensitivities to the measured
  initial states, taken at the run's reference state (the linear `ml-nm` concentrates it
  exactly, its outputs being linear in it). R and that reference are held during a simplex run
  and relaxed at its best corner between runs (the initial state by Gauss-Newton,
  `nonlinear_prediction.initial_state`, its sensitivities there; R the residuals' mean square);
  every later run a fresh simplex at the best corner (`restart_step`). Converged when a run stops by its
  rule, improves J_M by no more than ε = `eps`/N, and the relaxation that follows changes no
  variance by more than `r_tol`; stalled after `max_relaxations` runs. No record-length
  continuation.

Both report the Cramér-Rao bounds with the initial states among the parameters and the
coloured-residual bounds at the estimate (`nonlinear_output_error.coloured_bounds`; not counted
in `evaluations`, as for the linear model).

What a linear method's option means here:

- `max_iter`: the iteration limit (`ml-gn`: every stage of the fit's record-length halving
  counted, at least 1; `ml-nm`: simplex iterations, default 500 per free coefficient);
- `tol` (`ml-gn`): converged when every parameter's step is below `tol` × its Cramér-Rao σ;
- `eps`, `step`, `restart_step`, `r_tol`, `max_relaxations`, `coefficients`, `coordinates` (`ml-nm`; only `scaled`): as for
  the linear model;
- `start`: `config` (the config's values), `equation-error` (the dynamics rows fitted to the
  measured states' difference quotients from the config's values, `nonlinear_regression`: no
  flight, so no basin; it needs u v w p q r φ θ measured), or `auto` (the default): of those
  two the one whose flight fits the records better (the likelihood with R the residuals' mean
  square, the measured first samples as initial states; two flights, counted in
  `evaluations`), `config` where the records cannot give the second. `Estimate.start` names
  the start taken. No MEKF start;
- any other option (`segments`, the global start's `samples`, `ml-nm`'s `restarts`,
  `first_length` …) has no meaning here: given a value other than its default, an
  `OptionError` names it.

The records must measure the same states (`nonlinear_output_error.records`); a missing sample
is left out of every sum, the flight going through it; no value is estimated per record.
"""

from __future__ import annotations

import time
from dataclasses import fields, replace
from typing import Sequence

import numpy as np

from testbed.data import Experiment, ModelConfig
from testbed.errors import InputError
from testbed.estimators.base import Callback, Estimate, OptionError, Options, Progress, Status, bounds_text
from testbed.estimators.nonlinear_regression import equation_error
from testbed.estimators.simplex import STEPS, fresh_simplex, simplex_coefficients, simplex_run
from testbed.identification.nonlinear_output_error import (
    coloured_bounds,
    fit_output_error,
    neg_log_likelihood,
    pooled_noise,
    present_only,
    residuals,
    setup,
    start_states,
)
from testbed.identification.nonlinear_prediction import initial_state
from testbed.identification.nonlinear_sensitivities import flight
from testbed.identification.recursions import counting, simulated
from testbed.models import log_mounting
from testbed.models.linear import STATES

__all__ = ["STARTS", "damped_gauss_newton", "simplex"]

STARTS = ("auto", "config", "equation-error")  # the starts a nonlinear model has (module doc)
_STATUS = {"converged": Status.CONVERGED, "iteration limit": Status.MAX_ITERATIONS, "stalled": Status.STALLED}
_GN = ("max_iter", "tol", "start")  # the options each method honours on a nonlinear model config
_NM = (
    "max_iter",
    "start",
    "eps",
    "step",
    "restart_step",
    "r_tol",
    "max_relaxations",
    "coefficients",
    "coordinates",
)


def _checked(method: str, options: Options, meant: Sequence[str]) -> None:
    """`OptionError` for an option the nonlinear fit cannot honour (module doc)."""
    for f in fields(options):
        value = getattr(options, f.name)
        if f.name not in meant and value != f.default:
            raise OptionError(
                method, f.name, value, "its default: the nonlinear model's fit has no such option"
            )
    if options.start not in STARTS:
        raise OptionError(
            method, "start", options.start, "auto, config or equation-error for a nonlinear model config"
        )


def _estimate(config, experiments, channels, x0, t0: float, tally: int, **fields) -> Estimate:
    """The `Estimate` of a fit of `config.free` to `experiments` (its other `fields` given), with
    its wall time from `t0`, its evaluations from the samples simulated `tally` and each record's
    fitted initial state `x0` (records, 10) in the measured `channels`."""
    return Estimate(
        free=tuple(config.free),
        wall_time_s=time.perf_counter() - t0,
        evaluations=-(-tally // sum(len(e.t) for e in experiments)),
        initial_states={
            e.name: {c: float(x[STATES.index(c)]) for c in channels} for e, x in zip(experiments, x0)
        },
        **fields,
    )


def _start(start: str, model, theta, recs, channels, free, held) -> tuple[str, np.ndarray]:
    """The start `start` names as (name, θ ⊕ b ⊕ g), for `auto` the better-flying one (module doc):
    the equation-error start fits θ's free coefficients to the records less their biases b, which
    it holds; `InputError` where the equation-error start is named and the records cannot give it."""
    if start == "config":
        return "config", theta
    m, own = len(model.names), [n for n in free if n in model.names]
    # the records less their biases; a mounted log's velocities taken as the CG's (a start)
    unbiased = [replace(r, y=r.y - theta[m : m + len(channels)]) for r in recs]
    try:
        regressed = np.concatenate([equation_error(model, theta[:m], unbiased, channels, own), theta[m:]])
    except InputError:
        if start == "equation-error":
            raise
        return "config", theta
    if start == "equation-error":
        return "equation-error", regressed
    ch = [STATES.index(c) for c in channels]
    x0 = start_states(model, recs, ch)

    def cost(th):
        res = residuals(model, th, x0, recs, ch)
        return np.inf if res is None else neg_log_likelihood(res, pooled_noise(res, held))

    return min((("config", theta), ("equation-error", regressed)), key=lambda s: cost(s[1]))


def damped_gauss_newton(
    experiments: Sequence[Experiment], config: ModelConfig, options: Options, callback: Callback | None
) -> Estimate:
    """`ml-gn` on a nonlinear model config (module doc)."""
    t0, name = time.perf_counter(), "ml-gn"
    _checked(name, options, _GN)
    if options.max_iter < 1:
        raise OptionError(name, "max_iter", options.max_iter, "an integer ≥ 1 for a nonlinear model config")
    channels, recs, model, theta, idx = setup(experiments, config, f"{name} on a nonlinear model config")
    noise = {c: s for c, s in (config.noise_std or {}).items() if c in channels}
    held = np.array([noise.get(c, np.nan) ** 2 for c in channels])
    history = [theta[idx]]

    def step(values: np.ndarray, cost: float) -> None:
        history.append(values)
        if callback is not None:
            callback(Progress(len(history) - 1, values.copy(), cost))

    box = config.box(config.free)
    with counting() as tally:
        label, start = _start(options.start, model, theta, recs, channels, config.free, held)
        history[0] = start[idx]
        fit = fit_output_error(
            model,
            start,
            recs,
            channels,
            config.free,
            noise_std=noise,
            callback=step,
            tolerance=float(options.tol),
            max_iterations=int(options.max_iter),
            bounds=box,
        )
    R = np.array([fit.noise_std[c] ** 2 for c in channels])
    # the bounds reached held: the others' σ with them held, theirs NaN (a bound is no estimate's σ)
    moving = [n for n in config.free if n not in fit.at_bounds]
    std, coloured, H = np.full(len(config.free), np.nan), np.full(len(config.free), np.nan), None
    if moving:
        at = [config.free.index(n) for n in moving]
        std[at], coloured[at], _, H = coloured_bounds(
            model, fit.theta, fit.initial_states, recs, channels, moving, R
        )
    return _estimate(
        config,
        experiments,
        channels,
        fit.initial_states,
        t0,
        tally[0],
        method=name,
        status=_STATUS[fit.status],
        values=np.array([fit.estimates[n] for n in config.free]),
        std=std,
        cost=fit.cost,
        iterations=fit.iterations,
        noise_std=dict(fit.noise_std),
        start=label,
        history=np.array(history),
        crlb_corrected_std=coloured,
        information=H if not fit.at_bounds else None,
        at_bounds=dict(fit.at_bounds) or None,
        message=f"on its bounds: {bounds_text(fit.at_bounds)}" if fit.at_bounds else "",
    )


def _unbounded(name: str, config: ModelConfig) -> None:
    """`InputError` for `[identify] bounds` given to a method that does not keep them."""
    if config.bounds:
        first = next(iter(config.bounds))
        raise InputError(
            f"{config.source or 'config'}: [identify] bounds.{first}: {name} does not keep bounds; "
            "expected ml-gn, or no [identify] bounds"
        )


def simplex(
    experiments: Sequence[Experiment], config: ModelConfig, options: Options, callback: Callback | None
) -> Estimate:
    """`ml-nm` on a nonlinear model config (module doc)."""
    t0, name = time.perf_counter(), "ml-nm"
    _checked(name, options, _NM)
    _unbounded(name, config)
    if options.coordinates == "information":
        raise OptionError(
            name, "coordinates", options.coordinates, "scaled or None for a nonlinear model config"
        )
    channels, recs, model, theta, idx = setup(experiments, config, f"{name} on a nonlinear model config")
    ch = [STATES.index(c) for c in channels]
    given = config.noise_std or {}
    held = np.array([given.get(c, np.nan) ** 2 for c in channels])
    with counting() as ranked:  # the starts' flights, counted with the fit's
        label, theta = _start(options.start, model, theta, recs, channels, config.free, held)
    nf, N = len(idx), int(sum(np.sum(~np.isnan(r.y).all(axis=1)) for r in recs))  # the samples
    max_iter = 500 * nf if options.max_iter is None else options.max_iter
    scale = np.where(theta[idx] != 0, np.abs(theta[idx]), 1.0)  # θ[free] = scale·x
    history = [theta[idx].copy()]

    def coefficients(x):
        th = theta.copy()
        th[idx] = scale * x
        return th

    def flown(th, x0):
        return residuals(model, th, x0, recs, ch)

    def relaxed(th, x0, R):
        """Each record's initial state fitted at θ (R held where given) and its outputs'
        sensitivities to the measured initial states there (N, k, k)."""
        fitted, sens, m = [], [], len(model.names)
        for r, x in zip(recs, x0):
            # the flight fitted to the record less its output biases b, read by the log (θ ⊕ b ⊕ g = th)
            b, g = th[m : m + len(ch)], th[m + len(ch) :]
            x, states = initial_state(
                model, th[:m], r.t, r.fins, r.y - b, ch, range(len(ch)), x, R, None, None, g
            )
            fitted.append(x)
            dx0 = flight(model, th[:m], r.t, x, r.fins, (), None, states).dx_dx0
            sens.append(log_mounting.read_derivatives(g, dx0, ch)[:, :, ch])
            simulated(len(r.t) * (1 + len(ch)))
        return np.array(fitted), sens

    with counting() as tally:
        x0 = start_states(model, recs, ch)
        if flown(theta, x0) is None:
            raise InputError(
                f"{config.source or 'config'}: the model's flight from the start values does not stay "
                "finite over the records; expected a start whose flight does (or ml-gn, which halves them)"
            )
        x0, sens = relaxed(theta, x0, None)
        R = pooled_noise(flown(theta, x0), held)

        def J(v: np.ndarray) -> float:
            """J_M at θ(v), each record's initial state concentrated out to first order: the
            residual less its weighted least-squares fit by the initial-state sensitivities."""
            res = flown(coefficients(v), x0)
            if res is None:
                return np.inf
            total = 0.0
            for e, S in zip(res, sens):
                e, S = present_only(e, S)
                W = S / R[:, None]
                d = np.linalg.lstsq(np.einsum("nci,ncj->ij", W, S), np.einsum("nci,nc->i", W, e), rcond=None)[
                    0
                ]
                total += float(np.sum((e - S @ d) ** 2 / R))
            return total / N

        def report(i: int, best: np.ndarray, cost: float) -> None:
            history.append(scale * best)
            if callback is not None:
                callback(Progress(i, scale * best, cost))

        coef = simplex_coefficients(options.coefficients, nf)
        tol = options.eps / N
        steps = [d if v is None else v for v, d in zip((options.step, options.restart_step), STEPS["scaled"])]
        x, size, it, status = theta[idx] / scale, steps[0], 0, Status.STALLED
        for _ in range(options.max_relaxations):
            J_start = J(x)
            corners, J_i, it, stopped = simplex_run(
                J, fresh_simplex(x, size), coef, tol, it, max_iter, report
            )
            x, J_best, size = corners[0], J_i[0], steps[1]
            if not stopped:
                status = Status.MAX_ITERATIONS
                break
            # the relaxation at the best corner: the initial states and their sensitivities, then R
            x0, sens = relaxed(coefficients(x), x0, R)
            R, R_old = pooled_noise(flown(coefficients(x), x0), held), R
            if J_start - J_best <= tol and np.max(np.abs(R / R_old - 1)) < options.r_tol:
                status = Status.CONVERGED
                break
    th = coefficients(x)
    std, coloured, res, H = coloured_bounds(model, th, x0, recs, channels, config.free, R)
    return _estimate(
        config,
        experiments,
        channels,
        x0,
        t0,
        tally[0] + ranked[0],
        method=name,
        status=status,
        values=th[idx],
        std=std,
        cost=neg_log_likelihood(res, R),
        iterations=it,
        noise_std={c: float(np.sqrt(v)) for c, v in zip(channels, R)},
        start=label,
        history=np.array(history),
        crlb_corrected_std=coloured,
        information=H,
    )
