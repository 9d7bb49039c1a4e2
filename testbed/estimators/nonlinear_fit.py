"""Output-error maximum likelihood for the nonlinear model as a library call: chosen parameters of
θ ⊕ b ⊕ g ⊕ c ⊕ τ and each record's measured initial state fitted to measured states by the same scaled
trust-region Gauss-Newton method as the linear model's `ml-gn` (`trust_region`, over
`nonlinear_objective.NonlinearObjective`): multiple shooting where the flight from the start
leaves the data's range or the whole record's fit does not converge, the projected step inside
bounds, the second-order check at the end (the cost probed along the least-determined
directions: the flight has no second-order sensitivities).

The bounds reported are the Cramér-Rao ones of the Fisher information at the estimate with the
initial states (when free) among the parameters; a parameter the fit ends held on a bound has
none (NaN), the others' are those with it held.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Callable, Mapping, Sequence

import numpy as np

from testbed.errors import InputError
from testbed.estimators.base import Estimate, Outcome, Status
from testbed.estimators.levenberg_marquardt import levenberg_marquardt
from testbed.estimators.trust_region import STAGE_TOL, shooting_stages, trust_region
from testbed.identification.bounds import crlb
from testbed.identification.likelihood import FEWEST_SEGMENT, SEGMENTS
from testbed.identification.nonlinear_objective import NonlinearObjective
from testbed.identification.nonlinear_output_error import (
    FlightRecord,
    check_records,
    neg_log_likelihood,
    parameter_names,
    pooled_noise,
)
from testbed.identification.objective import Point
from testbed.models.linear import STATES
from testbed.models.nonlinear import NonlinearModel

__all__ = ["NonlinearFit", "estimate_of", "fit", "fit_output_error", "nonlinear_problem", "result"]


@dataclass(frozen=True)
class NonlinearFit:
    """The result of `fit_output_error`."""

    theta: np.ndarray  # all of θ ⊕ b ⊕ g ⊕ c ⊕ τ in `parameter_names` order, the free ones fitted
    estimates: dict[str, float]  # the free parameters
    std: dict[str, float]  # their Cramér-Rao σ (NaN: held on a bound)
    initial_states: np.ndarray  # (records, 10)
    noise_std: dict[str, float]  # √R per channel
    cost: float  # −ln p(Z | θ, R): ½ Σ_c N_c ln 2π R_c + ½ Σ eᵀR⁻¹e
    iterations: int
    status: Status
    at_bounds: dict[str, float] = field(default_factory=dict)  # the free parameters held on a bound, at it
    outcome: Outcome | None = None  # the optimiser's own result (its optimum, for later starts to join)
    # the output sensitivities at the estimate (`nonlinear_output_error.output_sensitivities`)
    sensitivities: list | None = field(default=None, repr=False)


def nonlinear_problem(
    model: NonlinearModel,
    theta,
    records: Sequence[FlightRecord],
    channels: Sequence[str],
    free: Sequence[str],
    *,
    free_initial: bool = True,
    noise_std: Mapping[str, float] | None = None,
    substeps: int | None = None,
) -> NonlinearObjective:
    """The `NonlinearObjective` of the `free` parameters of θ ⊕ b ⊕ g ⊕ c ⊕ τ (names from
    `parameter_names`; `theta`: θ or θ ⊕ b ⊕ g ⊕ c ⊕ τ cut after any part, what it leaves out 0) on the `records`'
    measured `channels`, R held where `noise_std` gives it."""
    noise_std = dict(noise_std or {})
    check_records(model, records, tuple(channels), tuple(free), noise_std, 1.0, 1)
    ch = tuple(STATES.index(c) for c in channels)
    names = parameter_names(model, channels)
    theta = np.asarray(theta, float)
    full = np.zeros(len(names))
    full[: len(theta)] = theta
    return NonlinearObjective(
        model=model,
        theta=full,
        free=np.array([names.index(n) for n in free], dtype=np.int64),
        records=tuple(records),
        ch=ch,
        held=np.array([noise_std.get(c, np.nan) ** 2 for c in channels]),
        substeps=substeps,
        free_initial=free_initial,
    )


def result(prob: NonlinearObjective, out: Outcome) -> NonlinearFit:
    """The `NonlinearFit` of the optimiser's outcome `out` on `prob`, where it stopped at a point
    whose flight is finite."""
    nf = prob.n_free
    names = parameter_names(prob.model, [STATES[c] for c in prob.ch])
    free, channels = [names[i] for i in prob.free], [STATES[c] for c in prob.ch]
    theta, x0 = prob.unpack(out.p)
    xs, res = out.simulated
    R = pooled_noise(res, prob.held)
    M = out.fisher
    if M is None and out.joined < 0:  # the information at the point, where the fit has none
        M = prob.terms(Point(out.p, xs, res, R, neg_log_likelihood(res, R)))[1]
    held = np.zeros(nf, dtype=bool) if out.held is None else out.held
    std = np.full(nf, np.nan)
    # the values held on a bound left out: no σ, the others' with them held; none where the fit
    # stopped in an earlier fit's basin (`follow`: that fit's are its caller's)
    if M is not None and (~held).any():
        keep = np.r_[np.flatnonzero(~held), nf : len(M)]
        std[~held] = crlb(M[np.ix_(keep, keep)]).std[: int((~held).sum())]
    return NonlinearFit(
        theta=theta,
        estimates={n: float(v) for n, v in zip(free, out.p[:nf])},
        std={n: float(s) for n, s in zip(free, std)},
        initial_states=x0,
        noise_std={c: float(np.sqrt(v)) for c, v in zip(channels, R)},
        cost=neg_log_likelihood(res, R),
        iterations=out.iterations,
        status=out.status,
        at_bounds={free[k]: float(out.p[k]) for k in np.flatnonzero(held)},
        outcome=out,
        sensitivities=prob.sensitivities_at(out.p),
    )


def fit_output_error(
    model: NonlinearModel, theta, records: Sequence[FlightRecord], channels, free, **keywords
) -> NonlinearFit:
    """Fit the `free` parameters of θ ⊕ b ⊕ g ⊕ c ⊕ τ (names from `parameter_names`), started from
    `theta` (θ or θ ⊕ b ⊕ g ⊕ c ⊕ τ cut after any part: the channels' biases, the mounting, the current and the delay, 0 where left out), and
    each record's initial state to the `records`' measured `channels` by `trust_region` (module
    doc). `keywords`: `nonlinear_problem`'s (`free_initial`, `noise_std`, `substeps`) and `fit`'s."""
    problem = {k: keywords.pop(k) for k in ("free_initial", "noise_std", "substeps") if k in keywords}
    prob = nonlinear_problem(model, theta, records, channels, free, **problem)
    return fit(prob, prob.start, **keywords)


def fit(
    prob: NonlinearObjective,
    values: np.ndarray,
    *,
    tolerance: float = 1e-3,
    max_iterations: int = 100,
    callback: Callable[[np.ndarray, float], None] | None = None,
    bounds: tuple[np.ndarray, np.ndarray] | None = None,
    follow: tuple = (),
    segments: int = SEGMENTS,
    at: Point | None = None,
    optimiser: str = "ml-gn",
) -> NonlinearFit:
    """The fit of the objective `prob` from its free `values` (`at`: `prob.point` there, if the
    caller has it) until the Gauss-Newton step is shorter than `tolerance` Cramér-Rao σ or
    `max_iterations`. `callback(values, cost)` after every step taken, any stage's: the free
    parameters and the negative log-likelihood. `bounds`: `(low, high)` per free parameter
    (±inf: open), the box the fit keeps them in (a start outside it is moved onto it;
    `NonlinearFit.at_bounds` names those it ends on). `follow`: earlier fits' optima (θ, σ) on
    the same problem (`Outcome.optimum`): a fit that steps into one's basin stops there
    (`Outcome.joined`), its σ NaN (the earlier fit's are the caller's).
    `segments`: multiple shooting's first stage, pieces per record (1: none). `optimiser`:
    `ml-gn` (`trust_region`, all of the above) or `ml-lm` (`levenberg_marquardt`: the bounds,
    multiple shooting only from a start whose flight diverges, `_levenberg_marquardt`; `follow`
    is then unused)."""
    if not (isinstance(max_iterations, int) and max_iterations >= 1 and tolerance > 0):
        raise InputError(
            f"tolerance={tolerance!r}, max_iterations={max_iterations!r}; expected a tolerance > 0 "
            "and a whole number of iterations >= 1"
        )
    box = _box(bounds, prob.n_free)
    report = None if callback is None else (lambda step: callback(step.values, step.cost))
    x0 = prob.first_states()[:, list(prob.ch)].ravel() if prob.free_initial else []
    at = prob.point(values) if at is None else at
    if optimiser == "ml-lm":
        out = _levenberg_marquardt(prob, values, at, max_iterations, tolerance, report, box)
    else:
        out = trust_region(
            prob, np.concatenate([values, x0]), max_iter=max_iterations, tol=tolerance, callback=report,
            follow=follow, at=at, box=box, segments=segments,
        )  # fmt: skip
    if out.status is Status.DIVERGED and out.simulated is None:
        raise InputError(
            "the model's flight from the start values does not stay finite over the records, even on "
            "the shortest segments; expected a start whose flight does"
        )
    return result(prob, out)


def _levenberg_marquardt(
    prob: NonlinearObjective, values, at, max_iterations, tolerance, report, box
) -> Outcome:
    """`levenberg_marquardt` from the free `values` (`at`: `prob.point` there, None where the
    flight leaves the finite numbers over the whole record); from such a start multiple shooting
    first, as `ml-gn`'s: on the records cut into the fewest segments on which the flight stays
    bounded (`NonlinearObjective.shooting`), then on a quarter as many, …, then on the whole
    record, each stage from the one before's values (each segment's initial state its first
    sample) and, before the last, converged within `STAGE_TOL` σ; `max_iterations` for all of
    them together."""
    stages, nf = [], prob.n_free
    if at is None:
        with np.errstate(over="ignore", invalid="ignore"):  # a diverging start is an answer here
            count = prob.shooting(values, FEWEST_SEGMENT)
        stages = shooting_stages(prob, count, FEWEST_SEGMENT)
    used, history = 0, [np.asarray(values, float)[None, :]]
    for stage in [*stages, prob]:
        x0 = stage.first_states()[:, list(stage.ch)].ravel() if stage.free_initial else []

        def stepped(step, used=used):
            report(replace(step, iteration=used + step.iteration))

        out = levenberg_marquardt(
            stage, np.concatenate([values, x0]), max_iter=max(max_iterations - used, 1),
            tol=tolerance if stage is prob else max(tolerance, STAGE_TOL),
            callback=stepped if report is not None else None, at=at if stage is prob else None, box=box,
        )  # fmt: skip
        used += out.iterations
        history.append(out.history[1:])
        if stage is not prob and out.status is Status.DIVERGED:
            continue  # a stage the values diverge on is passed over
        values = out.p[:nf]
    return replace(out, iterations=used, history=np.concatenate(history))


def _box(bounds, p: int) -> tuple[np.ndarray, np.ndarray] | None:
    """`bounds` as (low, high) arrays of length `p` (None: unbounded); `InputError` unless
    low < high everywhere."""
    if bounds is None:
        return None
    low, high = (np.asarray(b, float).reshape(-1) for b in bounds)
    if low.shape != (p,) or high.shape != (p,) or not np.all(low < high):
        raise InputError(f"bounds {bounds!r}; expected (low, high), {p} each, low < high")
    return low, high


def estimate_of(config, experiments, records, channels, x0, t0: float, tally: int, **fields) -> Estimate:
    """The `Estimate` of a fit of `config.free` to `experiments` (its other `fields` given), with
    its wall time from `t0`, its evaluations from the samples simulated `tally` (flights of the
    experiments' `records`) and each record's fitted initial state `x0` (records, 10) in the
    measured `channels`."""
    return Estimate(
        free=tuple(config.free),
        wall_time_s=time.perf_counter() - t0,
        evaluations=-(-tally // sum(len(r.t) for r in records)),
        initial_states={
            e.name: {c: float(x[STATES.index(c)]) for c in channels} for e, x in zip(experiments, x0)
        },
        **fields,
    )
