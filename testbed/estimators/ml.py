"""Maximum-likelihood output-error methods: `ml-gn`, `ml-lm`, `ml-nr`, `ml-nm`.

All four minimise the paper's likelihood with the noise covariance estimated by relaxation
(R from the residuals, then held while θ steps), from the same start, with the same model and
initial-state parameters (`testbed.identification`), so they compare fairly:

- `ml-gn` (default): the scaled trust-region Gauss-Newton method of `trust_region`, with
  multiple shooting and a second-order check at the optimum, from the starts of `starts`.
- `ml-lm`: Gauss-Newton with Levenberg-Marquardt damping (Marquardt's diagonal scaling) over the
  objective protocol, the initial states fitted at every θ (`levenberg_marquardt`).
- `ml-nr`: the paper's modified Newton-Raphson, Eq. 10, exactly: the Hessian of J_M from the
  second-order sensitivities, `μ ∂J/∂θ + (∂²J/∂θ² + λI) Δθ = 0`, λ = max|∂J/∂θ|, μ = 0.5 if
  λ > 1 else 1/(λ+1); every step is taken (no line search), so its drift and divergence show;
  in SI units (the paper's) or, option `coordinates="scaled"`, in coordinates scaled by the start.
- `ml-nm`: the paper's eight-step Nelder-Mead simplex on J_M with its stopping rule; the
  initial states are fitted by linear least squares at every θ (outputs are linear in them:
  `concentrated.cost`, the cost alone, without sensitivities); with restarts and a
  record-length continuation (default) or, option `restarts=False`, the paper's one simplex.

From a start whose response does not stay bounded over the whole record (an unstable
a-priori model, `likelihood.bounded`), ml-lm, ml-nr and ml-nm run on segments first (`_shooting`,
the multiple shooting `ml-gn` has built in).

Convergence (ml-lm, ml-nr): the Gauss-Newton step measured in Cramér-Rao units,
`√(gᵀ M⁻¹ g)`, is below `tol` (default 1e-3): the estimate is within 0.001 σ of the optimum.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, fields, replace
from typing import Sequence

import numpy as np

from testbed.data import Experiment, ModelConfig
from testbed.errors import InputError, is_number
from testbed.estimators import nonlinear, starts, trust_region
from testbed.estimators.base import (
    Callback,
    Estimate,
    Method,
    Options,
    Outcome,
    Progress,
    Status,
    bounds_message,
    count_option,
    is_count,
    option,
    unphysical,
)
from testbed.estimators.levenberg_marquardt import levenberg_marquardt
from testbed.estimators.multistart import DELTA_J, Fit, best_fit, box_draws, starts_record, starts_summary
from testbed.estimators.nelder_mead import SIMPLEX_ITERATIONS, nelder_mead
from testbed.estimators.newton_raphson import newton_raphson
from testbed.identification import bounds, likelihood, recursions
from testbed.identification.linear_objective import as_objective, point
from testbed.identification.objective import Point
from testbed.identification.problem import Problem, base_name, problem

__all__ = [
    "GaussNewtonOptions",
    "ML_GN",
    "ML_LM",
    "ML_NM",
    "ML_NR",
    "NewtonRaphsonOptions",
    "SimplexOptions",
    "TrustRegionOptions",
]


def _estimate(
    name: str, prob: Problem, fit: Fit, t0: float, fits: list[Fit], evaluations: int, notes: dict[str, dict]
) -> Estimate:
    """The `Estimate` where the optimiser stopped from `fit`'s start, with its Cramér-Rao analysis
    and every start's result (`fits`; `notes`, start → the coefficients it left at their
    a-priori values, or why it was not computed) and the fit's `evaluations`; a DIVERGED one (the
    reason in its `message`) where that analysis breaks down or is not finite."""
    out, start, start_reason, tried = (
        fit.outcome,
        fit.start,
        starts_summary(fits, notes),
        starts_record(fits, notes),
    )
    why = None
    if out.status is Status.DIVERGED:  # where the model diverges there, no analysis to make
        with np.errstate(over="ignore", invalid="ignore"):
            diverges = likelihood.divergence(prob, out.p)
        if diverges is not None:
            why = f"the model diverges over the whole record where the fit stopped ({diverges})"
    if why is None:
        try:
            with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                info = bounds.assess(prob, out.p, out.fisher, simulated=out.simulated)
            # an infinite bound is an unidentifiable coefficient's (bounds.crlb); NaN is a failure
            why = (
                None
                if all(np.all(np.isfinite(a)) for a in (info.values, info.cost))
                and not np.any(np.isnan(info.crlb_std))
                else "the estimate or its Cramér-Rao bound is not finite"
            )
        except np.linalg.LinAlgError as exc:
            why = f"the Cramér-Rao analysis at the estimate failed ({exc})"
        why = unphysical(prob.structure, prob.coefficients(out.p[: prob.n_free])) or why
    if why is not None:
        nf = prob.n_free
        return Estimate(
            method=name,
            status=Status.DIVERGED,
            free=prob.free,
            values=out.p[:nf].copy(),
            std=np.full(nf, np.nan),
            cost=np.nan,
            iterations=sum(f.outcome.iterations for f in fits),
            wall_time_s=time.perf_counter() - t0,
            noise_std={},
            evaluations=evaluations,
            start=start,
            history=out.history,
            message=why,
            start_reason=start_reason,
            starts=tried,
        )
    # the values held on a bound: no σ, the others' with them held
    std, coloured = bounds.held_bounds(info, out.held)
    at_bounds = (
        {} if out.held is None else {prob.free[k]: float(info.values[k]) for k in np.flatnonzero(out.held)}
    )
    return Estimate(
        method=name,
        status=out.status,
        free=prob.free,
        values=info.values,
        std=std,
        cost=info.cost,
        iterations=sum(f.outcome.iterations for f in fits),
        wall_time_s=time.perf_counter() - t0,
        noise_std=info.noise_std,
        evaluations=evaluations,
        start=start,
        history=out.history,
        start_reason=start_reason,
        starts=tried,
        crlb_corrected_std=coloured,
        initial_states=info.initial_states,
        at_bounds=at_bounds or None,
        message=bounds_message(at_bounds),
    )


def _cost(prob: Problem, p: np.ndarray) -> float:
    """The negative log-likelihood at `p`; inf where the model diverges there (`likelihood.exploded`)."""
    with np.errstate(over="ignore", invalid="ignore"):  # a diverging model is an answer here
        out = recursions.simulated_outputs(prob, p)
    if likelihood.exploded(prob, out) is not None:
        return np.inf
    return likelihood.negative_log_likelihood(prob, [r.residual(y) for r, y in zip(prob.records, out)])


def _fit(
    name: str,
    optimiser,
    experiments: Sequence[Experiment],
    config: ModelConfig,
    options: Options,
    callback: Callback | None,
) -> Estimate:
    """Fit from the start(s) `options.start` names and keep the best (`best_fit`).

    `auto`: from the a-priori values and from the equation-error estimate, the better-fitting
    first; from the MEKF's estimate too when those two end apart (costs more than `DELTA_J`
    apart) or either fails; from the best box draw (as `global`'s) too where neither equation
    error (which leaves the rows the data cannot regress at their a-priori values) nor the MEKF
    gave a whole second start.
    `global`: from those two and from the best `polish` of `samples`
    coefficient vectors drawn in a box around the a-priori values (`multistart.box_draws`, inside
    the bounds where given), ranked by
    their cost on the first multiple-shooting stage (records cut in 16: a poor model's error does
    not grow along the whole record there). Every start's result is recorded in the estimate,
    and the simulations of all of them counted (`Estimate.evaluations`).
    """
    with recursions.counting() as tally:
        return _fit_counted(name, optimiser, experiments, config, options, callback, tally)


def _evaluations(prob: Problem, tally: list[int]) -> int:
    """The samples simulated (`recursions.counting`) as simulations of the whole data set, rounded up."""
    return -(-tally[0] // prob.n_samples)


def _fit_counted(name, optimiser, experiments, config, options, callback, tally) -> Estimate:
    """`_fit`, the simulations tallied in `tally`."""
    t0 = time.perf_counter()
    prob = problem(experiments, config)
    start = options.start
    tuning = {f.name: getattr(options, f.name) for f in fields(options) if f.name not in START_OPTIONS}

    fits: list[Fit] = []
    # the bounds the ML optimisers keep (the other methods refuse them: `Method.bounds`), and the
    # box draws' too
    box = config.box([base_name(n) for n in prob.free]) if config.bounds else None

    def begin(theta: np.ndarray) -> tuple[np.ndarray, float, Point | None]:
        """The parameter vector at θ with its best initial states, its cost, and for `ml-gn` the
        trust region's point there (None where the model diverges), which it starts from."""
        if optimiser is trust_region.trust_region:
            at = point(prob, theta)
            if at is not None:
                return at.p, at.J, at
        with np.errstate(over="ignore", invalid="ignore"):  # a diverging start is reported below
            p0 = likelihood.initial_states(prob, theta)
        return p0, _cost(prob, p0), None

    def run(label: str, p0: np.ndarray, J0: float, at: Point | None, earlier: Sequence[Fit] = ()) -> Fit:
        more = {}
        if optimiser in (trust_region.trust_region, nelder_mead):
            more = {"follow": tuple(f.outcome.optimum for f in earlier if f.outcome.optimum)}
        if at is not None:
            more["at"] = at
        kept = {"box": box} if box is not None else {}  # the optimisers that keep bounds take the box
        more |= kept
        done = sum(f.outcome.iterations for f in fits)  # the iterations count on over the starts

        def report(step: Progress) -> None:
            callback(replace(step, iteration=done + step.iteration))

        first = (
            None if optimiser is trust_region.trust_region else likelihood.bounded(prob, p0[: prob.n_free])
        )
        if first is None or (first[2] == 1 and np.isfinite(J0)):
            out = optimiser(prob, p0, callback=report if callback else None, **tuning, **more)
        else:  # a start that diverges over the whole record: on segments first
            out = _shooting(optimiser, prob, first, tuning | kept, report if callback else None)
        if out.joined >= 0:  # on an earlier fit's path: it ends where that one did
            twin = [f for f in earlier if f.outcome.optimum][out.joined]
            out = replace(twin.outcome, iterations=out.iterations, history=out.history, optimum=(), joined=-1)
            return Fit(label, out, twin.cost, J0, twin.start)
        J = _cost(prob, out.p) if out.cost is None else out.cost
        if J > J0 + 1e-9 * abs(J0) and out.status is not Status.DIVERGED:
            out = replace(out, status=Status.WORSE)
        return Fit(label, out, J, J0)

    notes: dict[str, dict] = {}  # start → what it left out ("left") or why it was not computed ("reason")

    def computed(label: str) -> np.ndarray | None:
        """The start `label`'s coefficients (`starts.named`), None where it cannot be computed."""
        try:
            theta, left = starts.named(prob, experiments, config, label)
        except InputError as exc:  # the filter refused the data or diverged; no row to regress
            notes[label] = {"reason": str(exc)}
            return None
        if left:
            notes[label] = {"left": left}
        return theta

    if start in ("config", "equation-error", "mekf"):
        theta, left = starts.named(prob, experiments, config, start)
        notes = {start: {"left": left}} if left else {}
        fit = run(start, *begin(theta))
        return _estimate(name, prob, fit, t0, [fit], _evaluations(prob, tally), notes)

    named = {"config": prob.start, "equation-error": computed("equation-error")}
    first = {k: begin(v) for k, v in named.items() if v is not None}
    for k in sorted(first, key=lambda k: (first[k][1], k != "config")):
        fits.append(run(k, *first[k], fits))
    if start == "global":
        for k, theta in enumerate(box_draws(as_objective(prob), options, box)):
            fits.append(run(f"box-{k + 1}", *begin(theta), fits))
        return _estimate(name, prob, best_fit(fits), t0, fits, _evaluations(prob, tally), notes)
    if (
        len(fits) < 2
        or abs(fits[0].cost - fits[1].cost) > DELTA_J
        or any(f.outcome.status is not Status.CONVERGED for f in fits)
    ):
        theta = computed("mekf")
        if theta is not None:
            fits.append(run("mekf", *begin(theta), fits))
    whole = named["equation-error"] is not None and "left" not in notes.get("equation-error", {})
    if not whole and not any(f.start == "mekf" for f in fits):
        # no whole second start (equation error left rows at the a-priori values, no MEKF
        # fit): the best box draw is one
        for theta in box_draws(as_objective(prob), replace(options, polish=1), box):
            fits.append(run("box-1", *begin(theta), fits))
    return _estimate(name, prob, best_fit(fits), t0, fits, _evaluations(prob, tally), notes)


def _shooting(optimiser, prob: Problem, first: tuple, tuning: dict, callback) -> Outcome:
    """`optimiser` (`tuning`: its options) from a start that diverges over the whole record
    (`first`: `likelihood.bounded` there): multiple shooting, as `ml-gn`'s. First on the records
    cut into the fewest segments on which that model stays bounded, then on a quarter as many
    (`trust_region.SHRINK`), and so on, then on the whole record, each stage from the one
    before's coefficients with the iterations left of `max_iter` (all stages together); a stage
    on which they diverge is passed over. A stage before the last stops as `ml-gn`'s do, within
    `trust_region.STAGE_TOL` σ (`ml-nm`: by its rule with `stage_eps`): enough to start the next
    in its basin. DIVERGED where the whole record's model diverges from the last stage's
    coefficients."""
    first, p, count, _ = first
    theta = p[: prob.n_free]
    stages, count = [first], count // trust_region.SHRINK
    while count > 1:
        stages.append(likelihood.segmented(prob, count, likelihood.LEAST_SEGMENT))
        count //= trust_region.SHRINK
    stages.append(prob)
    budget, used, history = tuning.get("max_iter"), 0, [theta[None, :]]
    for stage in stages:
        with np.errstate(over="ignore", invalid="ignore"):
            p = likelihood.initial_states(stage, theta)
        if not np.isfinite(_cost(stage, p)):
            if stage is prob:
                return Outcome(p, Status.DIVERGED, used, np.concatenate(history))
            continue

        def report(step: Progress, used=used) -> None:
            callback(replace(step, iteration=used + step.iteration))

        left = {} if budget is None else {"max_iter": budget - used}
        if stage is not prob:  # a stage's looser convergence
            left |= {"tol": max(tuning["tol"], trust_region.STAGE_TOL)} if "tol" in tuning else {}
            left |= {"eps": tuning["stage_eps"]} if "stage_eps" in tuning else {}
        out = optimiser(stage, p, callback=report if callback else None, **(tuning | left))
        used += out.iterations
        history.append(out.history[1:])
        theta = out.p[: prob.n_free]
    return replace(out, iterations=used, history=np.concatenate(history))


_STARTS = ("auto", "config", "equation-error", "mekf", "global")


START_OPTIONS = ("start", "samples", "spread", "polish", "seed")


_START = option(
    "auto",
    lambda v: v in _STARTS,
    f"one of {', '.join(_STARTS)}",
    "where the iterations begin: auto (the a-priori values and the equation-error estimate, "
    "and the MEKF's when those two end apart or fail, the best box draw where neither gave a whole second start; "
    "the least cost is kept), config (the "
    "a-priori values only), equation-error, mekf, or global (auto's first two and the best "
    "box draws, see samples, spread and polish)",
)


_SAMPLES = count_option(
    200, 1, "start global: coefficient vectors drawn in the box around the a-priori values"
)


_SPREAD = option(
    1.0,
    lambda v: is_number(v) and v > 0,
    "a number > 0",
    "start global: the box spans a-priori × e^±spread (coefficients analysed at 0: ±3 Cramér-Rao bounds)",
)


_POLISH = count_option(3, 1, "start global: the best box draws the optimiser is run from")


_SEED = count_option(0, 0, "start global: the seed of the box draws")


_TOL = option(
    1e-3,
    lambda v: is_number(v) and v > 0,
    "a number > 0",
    "converged when the Gauss-Newton step is shorter than tol Cramér-Rao σ",
)


def _max_iter(default: int | None):
    return option(
        default,
        lambda v: (v is None and default is None) or (is_count(v) and v >= 0),
        "an integer ≥ 0 (iterations)",
        "iteration limit" + (f"; None: {SIMPLEX_ITERATIONS} per free coefficient" if default is None else ""),
    )


@dataclass(frozen=True)
class TrustRegionOptions(Options):
    """Options of `ml-gn` (`trust_region.trust_region`: what each one means)."""

    max_iter: int = _max_iter(100)
    start: str = _START
    tol: float = _TOL
    segments: int = count_option(
        likelihood.SEGMENTS,
        1,
        "multiple shooting: each record is first fitted cut into this many pieces, a quarter as many per stage",
    )
    samples: int = _SAMPLES
    spread: float = _SPREAD
    polish: int = _POLISH
    seed: int = _SEED


@dataclass(frozen=True)
class GaussNewtonOptions(Options):
    """Options of `ml-lm`."""

    max_iter: int = _max_iter(50)
    start: str = _START
    tol: float = _TOL
    samples: int = _SAMPLES
    spread: float = _SPREAD
    polish: int = _POLISH
    seed: int = _SEED


@dataclass(frozen=True)
class NewtonRaphsonOptions(Options):
    """Options of `ml-nr`."""

    max_iter: int = _max_iter(100)
    start: str = _START
    tol: float = _TOL
    coordinates: str = option(
        "si",
        lambda v: v in ("si", "scaled"),
        "si or scaled",
        "where Eq. 10 runs, which sets λ = max|∂J/∂x| and μ: si (the paper's, SI units) or "
        "scaled (each free coefficient over its start's magnitude, x_i = θ_i/|θ_i,start|)",
    )
    samples: int = _SAMPLES
    spread: float = _SPREAD
    polish: int = _POLISH
    seed: int = _SEED


def _positive(doc: str, default: float):
    return option(default, lambda v: is_number(v) and v > 0, "a number > 0", doc)


def _step(doc: str):
    return option(None, lambda v: v is None or (is_number(v) and v > 0), "a number > 0 or None", doc)


@dataclass(frozen=True)
class SimplexOptions(Options):
    """Options of `ml-nm` (`nelder_mead`: what each one means)."""

    max_iter: int | None = _max_iter(None)
    start: str = _START
    eps: float = _positive(
        "stopping rule: the spread of J_M over the corners, in units of the χ² statistic N·J_M", 1e-3
    )
    step: float | None = _step(
        "first simplex: its edge along each axis, in Cramér-Rao σ (coordinates information) or "
        "as a fraction of each |θ_i,start| (scaled); None: 1 σ or 0.1"
    )
    restart_step: float | None = _step("later runs' fresh simplex, as step; None: 0.1 σ or 0.02")
    r_tol: float = _positive("converged when a noise update changes no variance by more than this", 1e-3)
    max_relaxations: int = count_option(
        20, 1, "simplex runs on the whole record (each after a noise update) before STALLED"
    )
    coefficients: str = option(
        "adaptive",
        lambda v: v in ("adaptive", "paper"),
        "adaptive or paper",
        "reflection, expansion, contraction and shrink: the paper's (1, 2, ½, "
        "½) or Gao & Han's dimension-adaptive (1, 1 + 2/m, ¾ − 1/(2m), 1 − 1/m)",
    )
    first_length: float = _positive(
        "record-length continuation: seconds of each experiment fitted "
        "first, doubled per stage up to the whole record",
        60.0,
    )
    stage_eps: float = _positive("stopping rule of the continuation's shorter stages (as eps)", 1.0)
    restarts: bool = option(
        True,
        lambda v: isinstance(v, bool),
        "True or False",
        "True: the record-length continuation and a fresh simplex after each noise update; False: "
        "the paper's one simplex on the whole record from the first, its corners re-evaluated "
        "after each noise update",
    )
    coordinates: str | None = option(
        None,
        lambda v: v in (None, "information", "scaled"),
        "information or scaled",
        "where the simplex moves: information (each run's start's Gauss-Newton information the "
        "identity: unit steps of one Cramér-Rao σ along its principal directions) or scaled "
        "(each free coefficient over its start's magnitude, x_i = θ_i/|θ_i,start|); None: "
        "information (a nonlinear model: scaled, the only one it has)",
    )
    samples: int = _SAMPLES
    spread: float = _SPREAD
    polish: int = _POLISH
    seed: int = _SEED


def _method(
    name: str, optimiser, options: type[Options], summary: str, on_nonlinear=None, refuses=None, bounds=False
) -> Method:
    """The method `name` by `optimiser` (`on_nonlinear`: its fit of a nonlinear model config, whose
    options `nonlinear.refused_options` checks)."""

    def fit(experiments, config, opts, callback):
        return _fit(name, optimiser, experiments, config, opts, callback)

    return Method(
        name=name,
        fit=fit,
        options=options,
        summary=summary,
        nonlinear=on_nonlinear,
        refuses=refuses,
        refuses_nonlinear=(lambda config, opts: nonlinear.refused_options(name, opts))
        if on_nonlinear
        else None,
        bounds=bounds,
    )


ML_GN = _method(
    "ml-gn",
    trust_region.trust_region,
    TrustRegionOptions,
    "maximum likelihood output error by scaled trust-region Gauss-Newton with multiple shooting",
    nonlinear.gauss_newton,
    bounds=True,
)


ML_LM = _method(
    "ml-lm",
    levenberg_marquardt,
    GaussNewtonOptions,
    "maximum likelihood output error by Gauss-Newton with Levenberg-Marquardt damping",
    nonlinear.damped_gauss_newton,
    bounds=True,
)


ML_NR = _method(
    "ml-nr",
    newton_raphson,
    NewtonRaphsonOptions,
    "maximum likelihood output error by the paper's modified Newton-Raphson (Eq. 10)",
    bounds=True,
)


ML_NM = _method(
    "ml-nm",
    nelder_mead,
    SimplexOptions,
    "maximum likelihood output error by the paper's Nelder-Mead simplex",
    nonlinear.simplex,
    bounds=True,
)
