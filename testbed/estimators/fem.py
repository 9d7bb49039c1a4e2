"""`ml-fem`: maximum likelihood with a Kalman filter in the likelihood (the filter-error method of
Maine & Iliff 1981/1986 and Jategaonkar, Flight Vehicle System Identification, ch. 5), for data
with process noise (turbulence), where output error is biased.

The model and its steady-state filter are `identification.innovations`: process noise of
spectral density f_j² on each chosen body row j (Jategaonkar's diagonal distribution matrix F =
diag(f), continuous time, discretised exactly), measurement noise R diagonal. The negative
log-likelihood of the innovations ν, with 𝒮 their covariance,

    L = ½ Σ_k νᵀ 𝒮⁻¹ ν + (N/2) ln det 2π𝒮

(per group of records with one Δ, one measured set and one sampling cycle, and per phase j of the
cycle over the channels it has: Σ_j [½ Σ_{k in j} ν_kᵀ 𝒮_j⁻¹ ν_k + (N_j/2) ln det 2π𝒮_j];
`innovations`), is minimised by relaxation (Maine & Iliff), from output error's optimum (the same
iterations with F = 0: from a poor θ the filter would take the model's error for process noise;
from a start whose response does not stay bounded over the whole record, `ml-gn`'s fit with its
multiple shooting first), each iteration:

1. 𝒮 in closed form, `1/N Σ ν νᵀ` per group and phase;
2. one Gauss-Newton step (Levenberg-Marquardt damped, accepted only where ½Σνᵀ𝒮⁻¹ν falls) on
   p = (θ_free, each record's initial prediction in its measured states, f²) with 𝒮 and R fixed;
   the innovations' sensitivities by central differences in θ and f² (each a new filter: its
   gain from the Riccati equation), exact in the initial state (ν is linear in it);
3. R compatible with 𝒮 and the filter's P: `R = diag(𝒮 − C P Cᵀ)`. Where that would not be
   positive (beyond a floor of `R_FLOOR` 𝒮), R takes the floor and the process noise of the
   channel's own body row is scaled down by the ratio of the room left to C P Cᵀ, Jategaonkar's
   correction of F.

F is estimated through f² (the spectral densities), bounded below by 0: the likelihood is flat in
f at f = 0 (it depends on f²), so Gauss-Newton in f never reaches a row without process noise,
where in f² it stops on the bound (an active bound: held at 0 while the gradient points below).
f² = 0 is a local optimum of its own wherever a little process noise costs more than it explains
(the gain grows as a root of f²), so the rows that end there start again once from their first
guess, and the lower likelihood is kept.

Converged when the Gauss-Newton step is shorter than `tol` Cramér-Rao σ (over the parameters off
their bound) and the update of 𝒮 changed no variance by more than `r_tol` (relative). The Cramér-Rao
bounds are those of the information `Σ (∂ν/∂p)ᵀ 𝒮⁻¹ (∂ν/∂p)` at the estimate, the initial states
and f² eliminated as for output error.

With process noise R follows from 𝒮 (the config's `noise_std` is not used). With no process noise
(`process_noise="none"`) K = 0, ν are the output-error residuals and 𝒮 = R is the diagonal
residual variance (the config's `noise_std` where it gives a channel's): the fit is output error, and ends at `ml-gn`'s optimum.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np

from testbed.data import Experiment, ModelConfig
from testbed.errors import is_number
from testbed.estimators import starts, trust_region
from testbed.estimators.box_bounds import held_on_bounds, into_box, on_bounds
from testbed.estimators.fem_likelihood import Likelihood, noise_rows, sampling_cycles, start_noise
from testbed.estimators.base import (
    Callback,
    Estimate,
    Method,
    Options,
    Progress,
    bounds_message,
    Status,
    count_option,
    option,
    unphysical,
)
from testbed.identification import bounds, likelihood, recursions, scan
from testbed.identification.problem import base_name, check_one_model, one_model, problem
from testbed.models.linear import BODY, IX, NX, STATES

__all__ = ["FilterErrorOptions", "ML_FEM"]


def _noise_spec(v) -> bool:
    if not isinstance(v, str):
        return False
    if v in ("measured", "none"):
        return True
    names = [n.strip() for n in v.split(",")]
    return all(n in BODY for n in names) and len(set(names)) == len(names)


@dataclass(frozen=True)
class FilterErrorOptions(Options):
    """Options of `ml-fem`."""

    max_iter: int = count_option(50, 0, "iteration limit of each phase (output error, then the filter)")
    start: str = option(
        "config",
        lambda v: v in ("config", "equation-error"),
        "config or equation-error",
        "where the iterations begin: config (the a-priori values) or equation-error",
    )
    tol: float = option(
        1e-3,
        lambda v: is_number(v) and v > 0,
        "a number > 0",
        "converged when the Gauss-Newton step is shorter than tol Cramér-Rao σ",
    )
    r_tol: float = option(
        1e-3,
        lambda v: is_number(v) and v > 0,
        "a number > 0",
        "converged when an update of 𝒮 changes no variance by more than this (relative)",
    )
    process_noise: str = option(
        "measured",
        _noise_spec,
        "measured, none, or body states separated by commas (e.g. 'v,r')",
        "the body rows with process noise: measured (every measured body state), none (F = 0: output "
        "error), or a list of body states",
    )
    max_trials: int = count_option(30, 1, "damped steps tried per iteration before STALLED")
    correlation_time: float = option(
        0.0,
        lambda v: is_number(v) and 0 <= v <= 1e3,
        "a number of seconds from 0 to 1000",
        "the process noise's correlation time τ: 0, white; τ > 0, each row's noise through a "
        "first-order lag of time constant τ (turbulence of that correlation time), f² its "
        "low-frequency density; below a fifth of the sampling interval, white",
    )


def _fit(
    experiments: Sequence[Experiment],
    config: ModelConfig,
    opts: FilterErrorOptions,
    callback: Callback | None,
) -> Estimate:
    experiments, config = one_model(experiments, config, "ml-fem", terms=True)
    with recursions.counting() as tally, scan.compiled():
        t0 = time.perf_counter()
        prob = problem(experiments, config)
        cycles = sampling_cycles(prob)
        rows = noise_rows(prob, opts.process_noise)
        box = config.box([base_name(n) for n in prob.free]) if config.bounds else None
        theta0 = into_box(starts.named(prob, experiments, config, opts.start)[0], box)
        lik = Likelihood(prob, rows, theta0, cycles, opts.correlation_time)
        S, q0 = start_noise(lik)
        with np.errstate(over="ignore", invalid="ignore"):  # a diverging start is an answer here
            p = likelihood.initial_states(prob, theta0)
        diverges = likelihood.bounded(prob, theta0)[2] > 1
        scale = np.concatenate([np.where(theta0 != 0, np.abs(theta0), 1.0), np.ones(lik.nx), q0])
        done, history = 0, np.zeros((0, prob.n_free))

        def more(offset):
            if callback is None:
                return None
            return lambda step: callback(replace(step, iteration=offset + step.iteration))

        if diverges:
            # a start that diverges over the whole record (an unstable model, `likelihood.bounded`):
            # output error and the filter are no near-quadratic problem from there; `ml-gn`'s
            # multiple shooting takes it to output error's optimum first
            out = trust_region.trust_region(prob, p, max_iter=opts.max_iter, callback=callback, box=box)
            if out.status is not Status.DIVERGED:
                p, done, history = out.p, out.iterations, out.history[:-1]
        if lik.noisy:
            # output error first: from a poor θ the filter takes the model's error for process noise
            first = Likelihood(prob, rows[:0], theta0, cycles)
            out = _iterate(first, p, start_noise(first)[0], scale[: len(p)], opts, more(done), box)
            if out[2] is not Status.DIVERGED:
                p, done, history = out[0], done + out[3], np.vstack([history, out[4][:-1]])

        p, S, status, it, steps, why = _iterate(lik, np.concatenate([p, q0]), S, scale, opts, more(done), box)
        trail = [history, steps]
        zero = p[len(p) - len(q0) :] == 0
        if status is Status.CONVERGED and zero.any() and opts.max_iter > it:
            # f² = 0 is a local minimum of its own wherever a little process noise costs more
            # than it explains (the gain grows as a root of f²): the rows held there start again
            # from their first guess with the iterations left, and the lower likelihood is kept
            # (the estimate's history and iterations are the path to it; `evaluations` counts both)
            again = p.copy()
            again[len(p) - len(q0) :][zero] = q0[zero]
            other = _iterate(
                lik, again, S, scale, replace(opts, max_iter=opts.max_iter - it), more(done + it), box
            )
            if other[2] is Status.CONVERGED and _cost(lik, other) < _cost(lik, (p, S)):
                p, S, _, _, _, why = other
                it += other[3]
                trail.append(other[4][1:])
        est = _estimate(lik, p, S, status, done + it, np.vstack(trail), why, scale, box)
        # the simulations of the whole data set (`recursions.counting`), rounded up
        return replace(est, evaluations=-(-tally[0] // prob.n_samples), wall_time_s=time.perf_counter() - t0)


def _cost(lik: Likelihood, fit) -> float:
    """The negative log-likelihood at a fit's p (`fit[0]`) with its 𝒮 (`fit[1]`)."""
    return lik.negative_log_likelihood(lik.run(fit[0], fit[1])[1])


def _settle(lik: Likelihood, p: np.ndarray, S: dict, trials: int):
    """(p, the filter and innovations there) with 𝒮 = `S`, F reduced until the filter runs
    (halved where the gain overshoots: Φ(I − KC) unstable) and R = 𝒮 − C P Cᵀ is positive
    (`compatible`); None in place of the filter where that takes more than `trials` steps."""
    p = p.copy()
    for _ in range(trials):
        now = lik.run(p, S)
        if now is None and lik.noisy and p[lik.nf + lik.nx :].any():
            p[lik.nf + lik.nx :] /= 2
            continue
        if now is None or not lik.noisy:
            return p, now
        p, corrected = lik.compatible(S, now[0], p)[1:]
        if not corrected:
            return p, now
    return p, None


def _projected_step(p, M, g, bound, lam, low, high) -> np.ndarray:
    """p plus the damped Gauss-Newton step `(M + λ diag M) Δ = g` (solved with M scaled to a unit
    diagonal) over the parameters off their bound, each kept in [`low`, `high`] (the spectral
    densities f² ≥ 0, the coefficients in their box): one the step would take beyond its bound is
    set onto it and held there while the step is solved again for the others."""
    bound = bound.copy()
    while True:
        free = np.flatnonzero(~bound)
        Mf = M[np.ix_(free, free)]
        d = np.sqrt(np.maximum(np.diag(Mf), 1e-300))  # scaled to a unit diagonal: f²'s units are not θ's
        scaled = Mf / np.outer(d, d) + lam * np.eye(len(free))
        trial = p.copy()
        trial[free] += np.linalg.lstsq(scaled, g[free] / d, rcond=None)[0] / d
        beyond = (trial < low) | (trial > high)
        if not beyond.any():
            return trial
        bound |= beyond
        p = p.copy()
        p[beyond] = np.clip(trial, low, high)[beyond]


def _iterate(lik: Likelihood, p, S, scale, opts, callback, box=None):
    """The relaxation's iterations from p and 𝒮: (p, 𝒮, status, iterations, history, reason).
    `box`: `(low, high)` of the free coefficients (None: none), kept as `ml-gn` keeps them: one
    on its bound with the descent pointing out held there for the iteration, the others' step
    stopped on the box."""
    nf, nx = lik.nf, lik.nx
    # each parameter's range: the coefficients' box, the initial states free, f² ≥ 0
    low = np.r_[
        np.full(nf, -np.inf) if box is None else box[0], np.full(nx, -np.inf), np.zeros(len(p) - nf - nx)
    ]
    high = np.r_[np.full(nf, np.inf) if box is None else box[1], np.full(len(p) - nf, np.inf)]
    history = [p[:nf].copy()]
    p, now = _settle(lik, p, S, opts.max_trials)
    if now is None:
        return p, S, Status.DIVERGED, 0, np.array(history), "the filter diverges at the start"
    S = lik.covariances(now[1])
    p, now = _settle(lik, p, S, opts.max_trials)
    if now is None:
        return p, S, Status.DIVERGED, 0, np.array(history), "the filter diverges at the start"
    flt, nus = now
    changed, status, it, lam = np.inf, Status.MAX_ITERATIONS, 0, 1e-3
    for it in range(opts.max_iter + 1):
        try:
            g, M = lik.terms(p, flt, nus, S, scale)
        except np.linalg.LinAlgError as exc:
            return p, S, Status.DIVERGED, it, np.array(history), str(exc)
        q = p[nf + nx :]
        bound = np.zeros(len(p), dtype=bool)
        bound[nf + nx :] = (q <= 0) & (g[nf + nx :] <= 0)
        if box is not None:  # by θ's descent with the initial states and f² at their best
            bound[:nf] = held_on_bounds(p[:nf], likelihood.reduced(M, g, nf)[1], box)
        free = np.flatnonzero(~bound)
        Mf, gf = M[np.ix_(free, free)], g[free]
        cov = bounds.crlb(Mf).covariance
        if np.sqrt(max(gf @ cov @ gf, 0.0)) < opts.tol and changed < opts.r_tol:
            status = Status.CONVERGED
            break
        if it == opts.max_iter:
            break
        J0 = lik.weighted(nus, S)
        for _ in range(opts.max_trials):
            trial = _projected_step(p, M, g, bound, lam, low, high)
            new = lik.run(trial, S)
            if new is not None and lik.weighted(new[1], S) < J0:
                p, (flt, nus), lam = trial, new, max(lam / 10, 1e-9)
                break
            lam *= 10
        else:
            status = Status.STALLED
            break
        # the relaxation: 𝒮 in closed form, then F corrected where R = 𝒮 − CPCᵀ would not be positive
        S_new = lik.covariances(nus)
        changed = max(
            float(np.max(np.abs(np.diag(a) / np.diag(b) - 1), initial=0.0))
            for g in lik.groups
            for a, b in zip(S_new[g], S[g])
        )
        S = S_new
        q = p[nf + nx :].copy()
        p, now = _settle(lik, p, S, opts.max_trials)
        if now is None:
            return p, S, Status.DIVERGED, it + 1, np.array(history), "the filter diverged"
        flt, nus = now
        if np.any(p[nf + nx :] != q):
            changed = np.inf
        history.append(p[:nf].copy())
        if callback is not None:
            callback(Progress(it + 1, p[:nf].copy(), lik.negative_log_likelihood(nus)))
    return p, S, status, it, np.array(history), ""


def _estimate(lik: Likelihood, p, S, status, it, history, why, scale, box=None) -> Estimate:
    """The estimate at p with its Cramér-Rao bounds (a coefficient on a bound of the `box`: none,
    the others' with it held); DIVERGED (with the reason) where the fit failed, left the physical
    region or its bounds are not finite."""
    prob, nf, nx = lik.prob, lik.nf, lik.nx
    noise, process, std, cost = {}, {}, np.full(nf, np.nan), np.nan
    held = on_bounds(p[:nf], box)
    if status is not Status.DIVERGED:
        flt, nus = lik.run(p, S)
        try:
            M = lik.terms(p, flt, nus, S, scale)[1]
            F = likelihood.reduced(M, np.zeros(len(M)), nf)[0]
            std[~held] = bounds.crlb(F[np.ix_(~held, ~held)]).std
            full = bounds.crlb(M).std
        except np.linalg.LinAlgError as exc:
            status, why = Status.DIVERGED, f"the Cramér-Rao analysis at the estimate failed ({exc})"
        else:
            cost = lik.negative_log_likelihood(nus)
            variance = lik.compatible(S, flt, p)[0] if lik.noisy else likelihood.noise_variance(prob, nus)
            noise = dict(zip(prob.channels, map(float, np.sqrt(variance))))
            for k, j in enumerate(lik.rows):
                qk = p[nf + nx + k]
                process[BODY[j]] = {
                    "value": float(np.sqrt(qk)),
                    "std": float(full[nf + nx + k] / (2 * np.sqrt(qk))) if qk > 0 else float("inf"),
                }
            if not (np.isfinite(cost) and not np.any(np.isnan(std[~held]))):
                status, why = Status.DIVERGED, "the estimate or its Cramér-Rao bound is not finite"
    why = unphysical(prob.structure, prob.coefficients(p[:nf])) or why
    if why:
        status = Status.DIVERGED
    at_bounds = (
        {prob.free[k]: float(p[k]) for k in np.flatnonzero(held)} if status is not Status.DIVERGED else {}
    )
    x0 = {}
    for r in prob.records:
        xr = prob.x0(r, p) + np.eye(NX)[IX["u"]] * prob.speed
        x0[r.name] = {STATES[i]: float(xr[i]) for i in r.measured}
    return Estimate(
        method="ml-fem",
        status=status,
        free=prob.free,
        values=p[:nf].copy(),
        std=std if status is not Status.DIVERGED else np.full(nf, np.nan),
        cost=cost if status is not Status.DIVERGED else np.nan,
        iterations=it,
        wall_time_s=0.0,
        noise_std=noise if status is not Status.DIVERGED else {},
        history=history,
        initial_states=x0,
        process_noise_std=process if status is not Status.DIVERGED else None,
        at_bounds=at_bounds or None,
        message=why if status is Status.DIVERGED else bounds_message(at_bounds),
    )


def _refuses_data(experiments: Sequence[Experiment], config: ModelConfig) -> None:
    """`InputError` for records the periodic steady-state filter cannot run on
    (`fem_likelihood.sampling_cycles`), whatever is free: before the screen's fit, not after it."""
    sampling_cycles(problem(config.fitted(experiments), config))


ML_FEM = Method(
    name="ml-fem",
    fit=_fit,
    options=FilterErrorOptions,
    summary="maximum likelihood filter error: a steady-state Kalman filter in the likelihood, for data "
    "with process noise",
    refuses=lambda config: check_one_model(config, "ml-fem", terms=True),
    refuses_data=_refuses_data,
    bounds=True,
)
