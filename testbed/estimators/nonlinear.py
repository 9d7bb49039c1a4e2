"""The output-error methods on a nonlinear model config (one with `[terms]`), behind the same
contract and `Estimate` as the linear model's methods:

- `ml-gn`: the linear model's optimiser, `trust_region` (scaled trust-region Gauss-Newton with
  multiple shooting, bounds and the second-order check), on the nonlinear likelihood
  (`nonlinear_fit.fit_output_error` over `nonlinear_objective.NonlinearObjective`), the
  flight's exact sensitivities, each record's measured initial states free, from the starts
  below, kept as the linear model's are (`multistart.best_fit`);
- `ml-lm`: the linear model's `levenberg_marquardt` on the same objective, the initial states
  stepping with θ, from `config`, `equation-error` or `auto` (both run to their end, the least
  cost kept), in the same box as `ml-gn` (`box_bounds`); multiple shooting only from a start
  whose flight diverges over the whole record (as the linear model's `ml-lm`);
- `ml-nm`: the paper's Nelder-Mead simplex (`simplex`) on the same likelihood,
  `J_M = 1/N Σ eᵀR⁻¹e` over the free coefficients, each run in the coordinates at its start
  (`coordinates`, as the linear model's: by default whitened by the flight's Gauss-Newton
  information there, the initial states solved for, `simplex.run_frame`; or scaled by
  the start, θᵢ/|θᵢ,start|). Each record's initial state is concentrated out at every θ to first order:
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

- `max_iter`: the iteration limit (`ml-gn`: every stage of multiple shooting and every start
  counted as the linear model's; `ml-nm`: simplex iterations, default 500 per free coefficient);
- `tol`, `segments` (`ml-gn`): as for the linear model;
- `eps`, `step`, `restart_step`, `r_tol`, `max_relaxations`, `coefficients`, `coordinates` (`ml-nm`): as for
  the linear model;
- `start`: `config` (the config's values), `equation-error` (the dynamics rows fitted to the
  measured states' difference quotients from the config's values, `nonlinear_regression`: no
  flight, so no basin; it needs u v w p q r φ θ measured), or `auto` (the default): `ml-gn`
  fits from both, the better-flying first (the likelihood with R the residuals' mean square,
  the measured first samples as initial states), the second stopping where it steps into the
  first's basin, and keeps the least cost; `ml-nm` takes the better-flying one. `config` alone
  where the records cannot give the second. `global` (`ml-gn`): auto's two and the best
  `polish` of `samples` draws in the box a-priori × e^±`spread` (a value at 0: ±3 Cramér-Rao
  σ there; inside the bounds), ranked by their cost on the records cut into 16 segments, as the
  linear model's. `Estimate.start` names the start kept, `Estimate.starts` every start's end.
  No MEKF start;
- any other option (`ml-nm`'s `restarts`, `first_length` …) has no meaning here: given a value
  other than its default, an `OptionError` names it.

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
from testbed.estimators.base import Callback, Estimate, OptionError, Options, Progress, Status, bounds_message
from testbed.estimators.box_bounds import into_box, on_bounds
from testbed.estimators.multistart import Fit, best_fit, box_draws, starts_record, starts_summary
from testbed.estimators.nonlinear_fit import fit as fit_from
from testbed.estimators.nonlinear_fit import NonlinearFit, estimate_of, nonlinear_problem
from testbed.estimators.nonlinear_regression import regressed
from testbed.estimators.simplex import STEPS, fresh_simplex, run_frame, simplex_coefficients, simplex_run
from testbed.identification.likelihood import reduced
from testbed.identification.nonlinear_output_error import (
    coloured_bounds,
    coloured_bounds_held,
    sensitivity_bounds,
    neg_log_likelihood,
    pooled_noise,
    present_only,
    flight_information,
    flight_residuals,
    fitted_initial_states,
    setup,
    start_states,
)
from testbed.identification.recursions import counting
from testbed.models.linear import STATES

__all__ = ["GN_STARTS", "STARTS", "damped_gauss_newton", "gauss_newton", "refused_options", "simplex"]

STARTS = ("auto", "config", "equation-error")  # the starts a nonlinear model has (module doc)
GN_STARTS = STARTS + ("global",)  # … and `ml-gn`'s global search
_GN = (
    "max_iter",
    "tol",
    "start",
    "segments",
    "samples",
    "spread",
    "polish",
    "seed",
)  # the options each method honours
_LM = ("max_iter", "tol", "start")
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


def refused_options(method: str, options: Options) -> None:
    """`OptionError` for an option `method` (`ml-gn`, `ml-lm`, `ml-nm`) cannot honour on a
    nonlinear model config (module doc), a start it does not have, or an iteration limit below 1
    (`ml-gn`, `ml-lm`): checked before any fit, the command's screen's included."""
    meant, starts = {"ml-gn": (_GN, GN_STARTS), "ml-lm": (_LM, STARTS), "ml-nm": (_NM, STARTS)}[method]
    _checked(method, options, meant, starts)
    if method != "ml-nm" and options.max_iter < 1:
        raise OptionError(method, "max_iter", options.max_iter, "an integer ≥ 1 for a nonlinear model config")


def _checked(method: str, options: Options, meant: Sequence[str], starts: Sequence[str] = STARTS) -> None:
    """`OptionError` for an option the nonlinear fit cannot honour (module doc), or a start not
    among `starts`."""
    for f in fields(options):
        value = getattr(options, f.name)
        if f.name not in meant and value != f.default:
            raise OptionError(
                method, f.name, value, "its default: the nonlinear model's fit has no such option"
            )
    if options.start not in starts:
        raise OptionError(method, "start", options.start, f"{', '.join(starts)} for a nonlinear model config")


def _regressed(start: str, model, theta, recs, channels, free) -> np.ndarray | None:
    """The equation-error start (`nonlinear_regression.regressed`); None where the records cannot
    give it, `InputError` if `start` names it."""
    try:
        return regressed(model, theta, recs, channels, free)[0]
    except InputError:
        if start == "equation-error":
            raise
        return None


def _starts(options: Options, model, theta, recs, channels, free, prob, box, notes):
    """The starts `options.start` names as (label, θ ⊕ b ⊕ g ⊕ c ⊕ τ, its point where computed), in the
    order they are run (module doc): `auto` and `global` the better-flying of the a-priori and equation-error starts first,
    `global` then the best `polish` box draws (`multistart.box_draws`)."""
    if options.start == "config":
        yield "config", theta, None
        return
    regressed = _regressed(options.start, model, theta, recs, channels, free)
    if options.start == "equation-error":
        yield "equation-error", regressed, None
        return
    named = {"config": theta}
    if regressed is None:
        notes["equation-error"] = {"reason": "the records cannot give it (module doc)"}
    else:
        named["equation-error"] = regressed
    idx = prob.free
    at = {k: prob.point(v[idx]) for k, v in named.items()}
    cost = {k: np.inf if a is None else a.J for k, a in at.items()}
    for k in sorted(named, key=lambda k: (cost[k], k != "config")):
        yield k, named[k], at[k]
    if options.start == "global":
        for k, values in enumerate(box_draws(prob, options, box)):
            start = theta.copy()
            start[idx] = values
            yield f"box-{k + 1}", start, None


def gauss_newton(
    experiments: Sequence[Experiment], config: ModelConfig, options: Options, callback: Callback | None
) -> Estimate:
    """`ml-gn` on a nonlinear model config (module doc)."""
    return _output_error("ml-gn", experiments, config, options, callback)


def damped_gauss_newton(
    experiments: Sequence[Experiment], config: ModelConfig, options: Options, callback: Callback | None
) -> Estimate:
    """`ml-lm` on a nonlinear model config (module doc)."""
    return _output_error("ml-lm", experiments, config, options, callback)


def _output_error(
    name: str, experiments: Sequence[Experiment], config: ModelConfig, options: Options, callback
) -> Estimate:
    """`ml-gn` or `ml-lm` (`name`) on a nonlinear model config (module doc): each start's fit
    (`nonlinear_fit.fit` by that optimiser), the best kept."""
    t0 = time.perf_counter()
    gn = name == "ml-gn"
    refused_options(name, options)
    channels, recs, model, theta, idx = setup(experiments, config, f"{name} on a nonlinear model config")
    noise = {c: s for c, s in (config.noise_std or {}).items() if c in channels}
    box = config.box(config.free)
    trust = {"bounds": box} | ({"segments": int(options.segments)} if gn else {"optimiser": name})
    fits: list[Fit] = []
    notes: dict[str, dict] = {}
    with counting() as tally:
        prob = nonlinear_problem(model, theta, recs, channels, config.free, noise_std=noise)

        def run(label: str, start: np.ndarray, at) -> tuple[Fit, NonlinearFit] | None:
            """The fit from θ ⊕ b ⊕ g ⊕ c ⊕ τ `start` (stopping in an earlier fit's basin, then that
            one's), None where it cannot be computed (the reason in `notes`)."""
            done = sum(f.outcome.iterations for f in fits)

            def report(values: np.ndarray, cost: float) -> None:
                history.append(values.copy())
                if callback is not None:
                    callback(Progress(done + len(history), values.copy(), cost))

            history: list[np.ndarray] = []
            earlier = [f for f in fits if f.outcome.optimum]
            at = prob.point(start[idx]) if at is None else at
            J0 = np.inf if at is None else at.J
            try:
                fit = fit_from(
                    prob, start[idx], callback=report, tolerance=float(options.tol),
                    max_iterations=int(options.max_iter), at=at,
                    follow=tuple(f.outcome.optimum for f in earlier), **trust,
                )  # fmt: skip
            except InputError as exc:
                notes[label] = {"reason": str(exc)}
                return None
            out = replace(fit.outcome, history=np.vstack([start[idx], *history]))
            if out.joined >= 0:  # on an earlier fit's path: it ends where that one did
                twin = earlier[out.joined]
                out = replace(
                    twin.outcome, iterations=out.iterations, history=out.history, optimum=(), joined=-1
                )
                return Fit(label, out, twin.cost, J0, twin.start), kept[twin.start]
            return Fit(label, out, fit.cost, J0), fit

        kept: dict[str, NonlinearFit] = {}
        for label, start, at in _starts(options, model, theta, recs, channels, config.free, prob, box, notes):
            done = run(label, start, at)
            if done is not None:
                fits.append(done[0])
                kept[label] = done[1]
        if not fits:
            raise InputError(next(iter(notes.values()))["reason"])
        best = best_fit(fits)
        fit = kept[best.start if not best.joined else best.joined]
    R = np.array([fit.noise_std[c] ** 2 for c in channels])
    # the bounds reached held: the others' σ with them held, theirs NaN (a bound is no estimate's σ)
    moving = [n for n in config.free if n not in fit.at_bounds]
    std, coloured, H = np.full(len(config.free), np.nan), np.full(len(config.free), np.nan), None
    if moving:
        at = [config.free.index(n) for n in moving]
        if fit.sensitivities is not None:  # the fit's own at its estimate, those of the values held left out
            sens = [(St[:, :, at], Sx) for St, Sx in fit.sensitivities]
            std[at], coloured[at], _, H = sensitivity_bounds(fit.outcome.simulated[1], sens, R)
        else:
            std[at], coloured[at], _, H = coloured_bounds(
                model, fit.theta, fit.initial_states, recs, channels, moving, R
            )
    return estimate_of(
        config,
        experiments,
        recs,
        channels,
        fit.initial_states,
        t0,
        tally[0],
        method=name,
        status=best.outcome.status,
        values=np.array([fit.estimates[n] for n in config.free]),
        std=std,
        cost=fit.cost,
        iterations=sum(f.outcome.iterations for f in fits),
        noise_std=dict(fit.noise_std),
        start=best.start,
        history=best.outcome.history,
        start_reason=starts_summary(fits, notes),
        starts=starts_record(fits, notes),
        crlb_corrected_std=coloured,
        information=H if not fit.at_bounds else None,
        at_bounds=dict(fit.at_bounds) or None,
        message=bounds_message(fit.at_bounds),
    )


def simplex(
    experiments: Sequence[Experiment], config: ModelConfig, options: Options, callback: Callback | None
) -> Estimate:
    """`ml-nm` on a nonlinear model config (module doc)."""
    t0, name = time.perf_counter(), "ml-nm"
    refused_options(name, options)
    coordinates = options.coordinates or "information"
    channels, recs, model, theta, idx = setup(experiments, config, f"{name} on a nonlinear model config")
    ch = [STATES.index(c) for c in channels]
    given = config.noise_std or {}
    held = np.array([given.get(c, np.nan) ** 2 for c in channels])
    with counting() as ranked:  # the starts' flights, counted with the fit's
        prob = nonlinear_problem(model, theta, recs, channels, config.free, noise_std=given)
        # the better-flying start (`_starts`' first)
        label, theta, _ = next(_starts(options, model, theta, recs, channels, config.free, prob, None, {}))
    nf, N = len(idx), int(sum(np.sum(~np.isnan(r.y).all(axis=1)) for r in recs))  # the samples
    max_iter = 500 * nf if options.max_iter is None else options.max_iter
    box = config.box(config.free)
    theta = theta.copy()
    theta[idx] = into_box(theta[idx], box)  # a start outside the box moved onto it
    scale = np.where(theta[idx] != 0, np.abs(theta[idx]), 1.0)  # the start's size
    history = [theta[idx].copy()]

    def information(th, x0, R) -> np.ndarray | None:
        """The flight's information of the free values at θ ⊕ b ⊕ g ⊕ c ⊕ τ `th`, the initial
        states `x0` solved for, R held; None where the flight does not stay finite there."""
        try:
            H = flight_information(model, th, x0, recs, channels, config.free, R)[0]
        except InputError:
            return None
        return reduced(H, np.zeros(len(H)), nf)[0]

    def coefficients(x):
        """θ ⊕ b ⊕ g ⊕ c ⊕ τ at the simplex's x in the run's `frame`, its free values moved onto
        the box."""
        th = theta.copy()
        th[idx] = frame.theta(x)
        return th

    def flown(th, x0):
        return flight_residuals(model, th, x0, recs, ch)

    with counting() as tally:
        x0 = start_states(model, recs, ch)
        if flown(theta, x0) is None:
            raise InputError(
                f"{config.source or 'config'}: the model's flight from the start values does not stay "
                "finite over the records; expected a start whose flight does (or ml-gn, which halves them)"
            )
        x0, sens = fitted_initial_states(model, theta, recs, ch, x0, None)
        R = pooled_noise(flown(theta, x0), held)

        def J(v: np.ndarray) -> float:
            """J_M at θ(v), each record's initial state concentrated out to first order: the
            residual less its weighted least-squares fit by the initial-state sensitivities; a
            corner outside the box costs J_M at θ on the box plus its squared distance from
            there over N, so the simplex comes back to the box."""
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
            return (total + frame.outside(v)) / N

        def report(i: int, best: np.ndarray, cost: float) -> None:
            history.append(coefficients(best)[idx])
            if callback is not None:
                callback(Progress(i, history[-1].copy(), cost))

        coef = simplex_coefficients(options.coefficients, nf)
        tol = options.eps / N
        steps = [
            d if v is None else v for v, d in zip((options.step, options.restart_step), STEPS[coordinates])
        ]
        th, size, it, status = theta, steps[0], 0, Status.STALLED
        for _ in range(options.max_relaxations):
            # each run in the coordinates at its start
            frame = run_frame(coordinates, th[idx], scale, box, lambda: information(th, x0, R))
            x = frame.x(th[idx])
            J_start = J(x)
            corners, J_i, it, stopped = simplex_run(
                J, fresh_simplex(x, size), coef, tol, it, max_iter, report
            )
            th, J_best, size = coefficients(corners[0]), J_i[0], steps[1]
            if not stopped:
                status = Status.MAX_ITERATIONS
                break
            # the relaxation at the best corner: the initial states and their sensitivities, then R
            x0, sens = fitted_initial_states(model, th, recs, ch, x0, R)
            R, R_old = pooled_noise(flown(th, x0), held), R
            if J_start - J_best <= tol and np.max(np.abs(R / R_old - 1)) < options.r_tol:
                status = Status.CONVERGED
                break
    # the values on a bound held: the others' σ with them held, theirs NaN (a bound is no estimate's σ)
    held_on = on_bounds(th[idx], box)
    on = {config.free[k]: float(th[idx][k]) for k in np.flatnonzero(held_on)}
    std, coloured, res, H = coloured_bounds_held(model, th, x0, recs, channels, config.free, R, held_on)
    return estimate_of(
        config,
        experiments,
        recs,
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
        at_bounds=on or None,
        message=bounds_message(on),
    )
