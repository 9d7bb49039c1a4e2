"""The default `ml-gn` optimiser: a scaled trust-region Gauss-Newton method on the likelihood,
written once over `objective.Objective`, so the linear model (`linear_objective`) and the
nonlinear one (`nonlinear_objective`) are fitted by the same code.

It minimises the negative log-likelihood with the noise variance at its ML value, the cost the
estimate is judged by, as a function of the free coefficients θ: the optimiser steps in θ and the
initial states follow (`objective.following`: the linear model's are fitted exactly at every θ,
its outputs being linear in them, variable projection, Golub & Pereyra; the nonlinear model's
take their Gauss-Newton step with θ's).

- The model: `m(d) = J − g_rᵀd + ½ dᵀF d − ½ g_xᵀM_xx⁻¹g_x`, with `F` and `g_r` the Gauss-Newton
  normal equations with the initial states solved for (`likelihood.reduced`), the last term the
  initial states' own step (0 where they are fitted exactly), R the residual variance at θ.
- Bounds (`box`): a value on its bound with the descent direction pointing out of the box is
  held there for the iteration (the KKT condition of the bound); the others take the step of the
  subproblem in their own subspace, clipped onto the box (a projected trust-region step).
- The step: the minimiser of `m` within `‖D d‖ ≤ Δ` (Moré's trust-region subproblem, solved
  exactly through the eigenvectors of `D⁻¹FD⁻¹`). `D = diag(1/s)` with `s_i` the largest of the
  coefficient's a-priori magnitude, its magnitude at the start and its Cramér-Rao bound there: a
  unit lets every coefficient move by its own size (or, a-priori 0, by one standard error),
  whatever its units. On the whole record the first region is `RADIUS` √n_free units, a tenth
  of each coefficient's size along every axis at once: a first step that far is still a small
  change of the model, inside the basin the start lies in, and the region doubles with each
  step the model predicts well, so a good prior on benign data converges in a handful of
  iterations, where a region of whole sizes let the first steps leap into another basin (on
  the REMUS-class records, 12 iterations lost there). On multiple shooting's segments, whose
  cost is nearer quadratic (a model's error does not grow along a whole record), the first
  region is `SEGMENT_RADIUS` √n_free: whole sizes, which carry a far start past the segments'
  shallow minima.
- Acceptance: `ρ = (W(θ) − W(θ + d)) / (m(0) − m(d))`, W the weighted cost `½ Σ eᵀR⁻¹e` with R
  held at its estimate at θ and the trial's initial states fitted with it; the step is taken
  when ρ > `ACCEPT`, and Δ shrinks (ρ < ¼) or grows (ρ > ¾ at the boundary) as in every
  trust-region method (Nocedal & Wright, Alg. 4.1). Then R is re-estimated at θ + d. Every step
  taken lowers the likelihood itself: W falls at the old R, and R̂ lowers it further. Where the
  initial states follow θ's step (the nonlinear model), their own step (`g_xᵀM_xx⁻¹` of it) has
  a region of its own, a share of the whole: a rejected step cuts it to a quarter first, down to
  `LEAST_REACH`, while it is at least `OWN_SHARE` of the decrease predicted, and the region after
  (the flight's dependence on its first state can be far from its quadratic model, a kink of an
  |v| term crossed, and no θ step mends that); a step the model predicts well doubles it, up to
  the whole.
- Multiple shooting, where the fit on the whole record fails: from a poor start the whole
  record's output error is far from quadratic (an unstable or wrong model's error grows along the
  record, and the heading integrates it), so the method fits the records cut into `segments`
  pieces, each with its own initial state (`likelihood.segmented`), then `SHRINK` times fewer stage
  by stage to the whole record, each stage from the one before; only the last decides
  convergence. Not first, unless the start's response grows beyond bound along the records (an
  unstable a-priori model, whose whole-record sensitivities are dominated by its growing mode):
  with the continuity between segments relaxed, a model that is not the data's (real data) has
  another optimum on segments than on the whole record, and the whole record's fit from there
  can end in another basin than from the start.
- Converged: the Gauss-Newton step of the values off their bounds and the initial states is
  shorter than `tol` Cramér-Rao σ (`√(g_rᵀF⁻¹g_r + g_xᵀM_xx⁻¹g_x)`), and the point passes the
  second-order check (`second_order`): where the objective has the Hessian of the cost
  (second-order sensitivities included, the initial states eliminated: the linear model's,
  `recursions.curvature`) it has no negative eigenvalue; a stationary point that fails is a
  saddle: the method steps along the direction of negative curvature and goes on, and one it
  cannot leave ends as `Status.SADDLE`. Where it has none (the nonlinear model), the cost is
  probed one Cramér-Rao σ either way along the least-determined directions of the information,
  and a probe that lowers it is a point the method goes on from.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from testbed.identification import bounds, likelihood
from testbed.identification.likelihood import SEGMENTS
from testbed.identification.linear_objective import as_objective
from testbed.identification.objective import Objective, Point, following
from testbed.identification.problem import Problem
from testbed.estimators.base import Outcome, Progress, Status
from testbed.estimators.box_bounds import held_on_bounds, into_box, start_in_box

__all__ = [
    "ACCEPT",
    "JOIN",
    "LEAST_REACH",
    "OWN_SHARE",
    "PROBES",
    "RADIUS",
    "SEGMENT_RADIUS",
    "SHRINK",
    "STAGE_TOL",
    "bounded_step",
    "second_order",
    "shooting_stages",
    "subproblem",
    "trust_region",
]

ACCEPT = 1e-4  # least ratio of actual to predicted decrease for a step to be taken
LEAST_REACH = 1.0 / 64  # the initial states' own step is cut to no less than this share before the region is
OWN_SHARE = 1e-3  # and only while that step's share of the decrease predicted is at least this
_NEAR = 1.0  # a Gauss-Newton step shorter than this (Cramér-Rao σ): near a stationary point
PACE = 3  # a descent closes in on its stationary point when its step halves over this many iterations
DIRECT = 12  # iterations on the whole record before multiple shooting is tried instead
STAGE_TOL = 0.1  # a shorter stage's convergence (Cramér-Rao σ): enough to start the next in its basin
SHRINK = 4  # each multiple-shooting stage has this many times fewer segments than the one before
JOIN = 2.0  # a fit within this many Cramér-Rao σ of an earlier optimum is in its basin (ΔJ ≈ 2 in the quadratic model)
RADIUS = 0.1  # the first trust region's radius over √n_free (scaled units) on the whole record
SEGMENT_RADIUS = 1.0  # … and on multiple shooting's segments
MIN_RADIUS = 1e-3  # the trust radius a stage hands on, at least (scaled units)
PROBES = 1  # directions the second-order check probes where the objective has no Hessian (`second_order`)
NEGATIVE = 1e-8  # an eigenvalue of the scaled Hessian below −NEGATIVE × its largest is negative curvature


def subproblem(F: np.ndarray, g: np.ndarray, s: np.ndarray, delta: float) -> tuple[np.ndarray, float]:
    """The step `d` minimising `−gᵀd + ½ dᵀF d` subject to `‖d/s‖ ≤ Δ` among the steps along
    the directions F determines: those not null by the Cramér-Rao rule (`bounds.crlb`: with
    `D F D = V Λ Vᵀ`, D = 1/√diag F, the eigenvectors whose eigenvalue is above `bounds.NULL` ×
    the largest), and its predicted decrease `gᵀd − ½ dᵀF d`. Inside the region the step is the
    Gauss-Newton step `C g`, C the Cramér-Rao covariance: the step whose length in Cramér-Rao σ
    decides convergence. A null direction is not stepped along: the data hold nothing to say how
    far, and a nearly null one's model is no guide.

    The directions are found in F's own scaling, not the region's: a coefficient whose scale `s`
    is far from its bound would make `S F S` singular to working precision along directions the
    data determine well. With B = D V₊ (Bᵀ F B = Λ₊), the step is `d = B Λ₊^-½ u`; in u the model
    is `−bᵀu + ½‖u‖²` (b = Λ₊^-½ Bᵀg) and the region `‖G u‖ ≤ Δ`, G = S⁻¹ B Λ₊^-½ = P Σ Wᵀ (SVD).
    With v = Wᵀu the minimiser is `v(μ) = Wᵀb / (1 + μ σ²)`: μ = 0 where that lies inside the
    region, else the μ > 0 with ‖Σ v(μ)‖ = Δ (the secular equation, decreasing in μ: bracketed
    on both sides and solved by bisection in log μ; Moré & Sorensen; Nocedal & Wright §4.3). No
    factor is inverted.
    """
    F = (F + F.T) / 2
    D = np.sqrt(np.maximum(np.diag(F), 0.0))
    D = 1.0 / np.where(D > 0, D, 1.0)
    lam, V = np.linalg.eigh(F * np.outer(D, D))
    keep = lam > bounds.NULL * max(lam.max(initial=0.0), 1e-300)
    if not keep.any():
        return np.zeros_like(g), 0.0
    root = np.sqrt(lam[keep])
    B = D[:, None] * V[:, keep] / root
    _, sigma, Wt = np.linalg.svd(B / s[:, None], full_matrices=False)
    b = Wt @ (B.T @ g)

    def region(mu: float) -> float:  # ‖Σ v(μ)‖
        return float(np.linalg.norm(sigma * b / (1.0 + mu * sigma**2)))

    mu = 0.0
    if region(0.0) > delta:
        hi = 1.0 / sigma.max() ** 2
        while region(hi) > delta:
            hi *= 4
        lo = hi / 4
        while lo > 0 and region(lo) <= delta:  # region(0) > Δ: a root lies below
            lo /= 4
        for _ in range(200):  # region(μ) > Δ at lo, ≤ Δ at hi
            mid = np.sqrt(lo * hi) if lo > 0 else hi / 4
            if region(mid) > delta:
                lo = mid
            else:
                hi = mid
            if hi - lo <= 1e-12 * hi:
                break
        mu = hi
    d = B @ (Wt.T @ (b / (1.0 + mu * sigma**2)))
    return d, float(g @ d - 0.5 * d @ F @ d)


def _scale(prior: np.ndarray, theta: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Each coefficient's scale: the largest of its a-priori magnitude, its magnitude at the
    start and its Cramér-Rao bound there (`bounds.crlb` of the reduced information `F`; 1 where
    none is finite and positive)."""
    std = bounds.crlb(F).std
    s = np.maximum(np.maximum(np.abs(prior), np.abs(theta)), np.where(np.isfinite(std), std, 0.0))
    return np.where(s > 0, s, 1.0)


def second_order(
    prob: Objective, at: Point, s: np.ndarray, M: np.ndarray | None = None, moving: np.ndarray | None = None
) -> tuple[list[np.ndarray], bool]:
    """The directions the second-order check of the stationary point `at` leaves along (unit
    length in the coordinates scaled by `s`, 0 on the values held on a bound: `moving` False):
    where the objective has the Hessian (`Objective.hessian`), its direction of most negative
    curvature, none where it has no negative eigenvalue; where it has none, the `PROBES`
    least-determined directions of the Gauss-Newton information (F's eigenvectors of least
    eigenvalue, scaled), along which a negative curvature of `M − Σ (e/R) ∂²y` lies first (M is
    positive semi-definite, the residuals' term small at a fit), each scaled to one Cramér-Rao
    σ: `_leave_saddle` keeps the first along which the cost falls. With them, whether they are
    probes (True), not a negative curvature found."""
    nf = prob.n_free
    moving = np.ones(nf, dtype=bool) if moving is None else moving
    if M is None:
        M = _terms(prob, at)[1]
    H = prob.hessian(at, M)
    if H is not None:
        H = H[np.ix_(moving, moving)] * np.outer(s[moving], s[moving])
        lam, V = np.linalg.eigh(H)
        if lam[0] >= -NEGATIVE * max(abs(lam[-1]), 1e-300):
            return [], False
        v = np.zeros(nf)
        v[moving] = s[moving] * V[:, 0]
        return [v], False
    F = likelihood.reduced(M, np.zeros(len(M)), nf)[0][np.ix_(moving, moving)]
    D = s[moving]
    lam, V = np.linalg.eigh(F * np.outer(D, D))
    out = []
    for k in np.flatnonzero(lam > bounds.NULL * max(lam.max(initial=0.0), 1e-300))[:PROBES]:
        v = np.zeros(nf)
        v[moving] = D * V[:, k] / np.sqrt(lam[k])  # one Cramér-Rao σ along it
        out.append(v)
    return out, True


def _terms(prob: Objective, x: Point) -> tuple[np.ndarray, np.ndarray] | None:
    """g and M at `x` (`Objective.terms`), None where they are not finite numbers: weights of a
    channel that holds one value (its R at the floor) times sensitivities of coefficients carried
    far off overflow."""
    with np.errstate(over="ignore", invalid="ignore"):  # overflow is checked for
        g, M = prob.terms(x)
    return (g, M) if np.all(np.isfinite(g)) and np.all(np.isfinite(M)) else None


def bounded_step(
    F: np.ndarray, g: np.ndarray, s: np.ndarray, delta: float, theta: np.ndarray, free: np.ndarray, box
) -> np.ndarray:
    """The trust-region step of the `free` values (the others held: 0) inside the `box`: the
    subproblem's step (`subproblem`); where it carries values across their bounds, those stop on
    them and the subproblem is solved again for the rest, with the region left and the model's
    gradient there (`g − F_·h d_h`), until no value crosses (an active-set step: clipping the
    whole step instead would turn it off the model's descent and stall the region)."""
    d = np.zeros(len(theta))
    if box is None:
        d[free] = subproblem(F[np.ix_(free, free)], g[free], s[free], delta)[0]
        return d
    low, high = box
    hit = np.zeros(len(theta), dtype=bool)
    for _ in range(len(theta)):
        m = free & ~hit
        left = delta**2 - float(np.sum((d[hit] / s[hit]) ** 2))
        if not m.any() or left <= 0:
            break
        d[m] = subproblem(F[np.ix_(m, m)], g[m] - F[np.ix_(m, hit)] @ d[hit], s[m], np.sqrt(left))[0]
        crossed = m & ((theta + d < low) | (theta + d > high))
        if not crossed.any():
            break
        d[crossed] = np.clip(theta + d, low, high)[crossed] - theta[crossed]
        hit |= crossed
    return into_box(theta + d, box) - theta


@dataclass(frozen=True)
class Descent:
    """Where a stage's descent stopped."""

    point: Point
    status: Status
    iterations: int
    delta: float
    fisher: np.ndarray | None  # M at the point (the full parameter vector's), with its R
    joined: int = -1  # the earlier optimum (of `follow`) whose basin it entered; -1: none
    step: float = np.inf  # the last Gauss-Newton step's length in Cramér-Rao σ
    earlier: float = np.inf  # its length `PACE` iterations before
    held: np.ndarray | None = None  # (n_free,) bool: the values held on a bound at the point


def _descend(
    prob: Objective,
    start: Point,
    s: np.ndarray,
    delta: float,
    tol: float,
    max_iter: int,
    report,
    follow: tuple = (),
    terms: tuple | None = None,
    box: tuple | None = None,
) -> Descent:
    """Trust-region steps on one stage's problem from `start` until the Gauss-Newton step is
    shorter than `tol` Cramér-Rao σ (CONVERGED), `max_iter` steps (MAX_ITERATIONS), the region
    shrinks to nothing (STALLED), or a step lands within `JOIN` Cramér-Rao σ of one of the
    optima `follow` ((θ, σ) of earlier fits on the same problem): inside its quadratic basin,
    bound for the same point. `terms`: `_terms` at `start`, if known. `box`: (low, high) of the
    free values (None: unbounded); a value on its bound with the descent pointing out is held
    there (`box_bounds.held_on_bounds`), the others step in the box (the step clipped onto it)."""
    nf, x, it, steps = prob.n_free, start, 0, []
    reach = 1.0  # the share of the initial states' own step taken: a region of its own
    while True:
        for i, (theta, std) in enumerate(follow):
            if np.all(np.abs(x.p[:nf] - theta) <= JOIN * std):
                return Descent(x, Status.CONVERGED, it, delta, None, joined=i)
        terms = _terms(prob, x) if terms is None else terms
        if terms is None:  # the coefficients ran off where the data hold nothing to stop them
            return Descent(x, Status.DIVERGED, it, delta, None)
        g, M = terms
        F, gr = likelihood.reduced(M, g, nf)
        held = held_on_bounds(x.p[:nf], gr, box)
        free = ~held
        # the initial states' own Gauss-Newton step and decrease (×2), none where they are fitted
        # at every θ
        alone, own = (None, 0.0) if prob.projected else following(M, g, nf, np.zeros(nf))
        Ff, gf = F[np.ix_(free, free)], gr[free]
        # the Gauss-Newton step in Cramér-Rao units, the initial states' included: √(g_rᵀ F⁻¹ g_r + g_xᵀ M_xx⁻¹ g_x)
        step = np.sqrt(max(gf @ bounds.crlb(Ff).covariance @ gf + own, 0.0))
        steps.append(step)
        if step < tol:
            return Descent(x, Status.CONVERGED, it, delta, M, step=step, held=held)
        if it >= max_iter:
            earlier = steps[-1 - PACE] if len(steps) > PACE else np.inf
            return Descent(x, Status.MAX_ITERATIONS, it, delta, M, step=step, earlier=earlier, held=held)
        while True:
            d = bounded_step(F, gr, s, delta, x.p[:nf], free, box)
            if prob.projected:
                whole = d
                # the decrease the quadratic model predicts, the initial states at their best: g_rᵀd − ½ dᵀF d
                predicted = float(gr @ d - 0.5 * d @ F @ d)
            else:  # the initial states follow θ's step, their own step cut to `reach` of it
                whole = following(M, g, nf, d)[0] - (1.0 - reach) * alone
                # gᵀΔp − ½ ΔpᵀMΔp; with the whole own step, g_rᵀd − ½ dᵀF d + ½ g_xᵀ M_xx⁻¹ g_x
                predicted = float(g @ whole - 0.5 * whole @ M @ whole)
            trial = prob.moved(x, whole)
            # ρ = actual / predicted decrease of the weighted cost with R held at its estimate at
            # x, the trial's initial states fitted with that R: a smooth function of the step
            # (the likelihood relaxed in R and x0 at every trial need not be: their alternation
            # can stall short of its fixed point). A decrease there is one of the likelihood
            # too, which the trial's own R̂ lowers further (½ Σ N_c ln R̂_c ≤ ½ Σ eᵀR⁻¹e + const)
            rho = (
                (prob.weighted_cost(x.res, x.R) - prob.weighted_cost(trial.res, x.R)) / predicted
                if trial is not None and predicted > 0
                else -np.inf
            )
            size = np.linalg.norm(d / s)
            # the initial states' own step's share of the decrease predicted: ½ g_xᵀM_xx⁻¹g_x c (2 − c)
            own_share = 0.5 * own * reach * (2.0 - reach)
            if not rho >= 0.25 and reach > LEAST_REACH and own_share > OWN_SHARE * predicted:
                # a poor model of the cost there, the initial states' own step a part of it: a
                # quarter of that step first, the region kept (the flight's dependence on its
                # first state can be far from quadratic, a kink of an |v| term crossed, and no θ
                # step mends that)
                reach *= 0.25
            elif not rho >= 0.25:  # a poor model of the cost there (or none: NaN): a smaller region
                # a quarter of the step, or of the region where the step came out longer (its
                # length in floating point off the model's, on coefficients scaled decades
                # apart): the region shrinks whatever the step
                delta = 0.25 * (size if size < delta else delta)
            elif rho > 0.75:
                reach = min(1.0, 2.0 * reach)
                if size > 0.99 * delta:
                    delta *= 2.0
            if rho > ACCEPT:
                break
            if delta < 1e-12 or predicted <= 0:
                return Descent(x, Status.STALLED, it, delta, M, step=step, held=held)
        x, it, terms = trial, it + 1, None
        report(x)


def trust_region(
    prob: Problem | Objective,
    p: np.ndarray,
    max_iter: int = 100,
    callback=None,
    tol: float = 1e-3,
    segments: int = SEGMENTS,
    radius: float = RADIUS,
    escapes: int = 3,
    follow: tuple = (),
    at: Point | None = None,
    box: tuple[np.ndarray, np.ndarray] | None = None,
) -> Outcome:
    """Minimise the negative log-likelihood of `prob` (a linear `Problem`, or any `Objective`:
    the nonlinear model's too) from the free coefficients of `p` (the initial states are fitted)
    by trust-region steps (`_descend`) from a region of `radius` × √n_free in the scaled
    coordinates (`SEGMENT_RADIUS` × √n_free where multiple shooting begins), with the
    second-order check at the end (leaving at most `escapes` saddles). From a start whose
    response grows beyond bound along the records (`Objective.shooting` cuts them into
    segments), multiple shooting from the first iteration, with all of `max_iter`: stages of that
    many pieces per record (of at least `likelihood.FEWEST_SEGMENT` samples), a quarter as many,
    …, then the whole record. Otherwise, where the whole record's fit does not converge in
    `DIRECT` iterations (`DIRECT` more if its Gauss-Newton step is then below `_NEAR` σ and has
    halved over the last `PACE`), or the model diverges over the whole record from `p`, multiple
    shooting from `p` again, with half the iterations left: stages of `segments`,
    `segments`/`SHRINK`, … pieces per record (of at least `likelihood.LEAST_SEGMENT` samples, or
    `likelihood.FEWEST_SEGMENT` where the model diverges from `p`: a sparse log's records may hold
    too few samples for the longer ones), then the whole record. Where that does not converge
    either, the whole record's fit goes on with the iterations left from the lower of the two
    points they reached. `max_iter` bounds the iterations of all of them together.

    `follow`: earlier fits' optima `(θ, σ)` on the same problem (`Outcome.optimum`); a fit that
    steps into one's basin stops there (`Outcome.joined`: which one). `at`: `prob.point(p[:n_free])`,
    if the caller has it. `box`: `(low, high)` of the free values (±inf: open), the box the fit
    keeps them in (a start outside it is moved onto it; `Outcome.held` marks those it ends on)."""
    prob = as_objective(prob)
    nf = prob.n_free
    p, box, at = start_in_box(p, nf, box, at)
    history: list[np.ndarray] = [p[:nf].copy()]

    def report(x: Point) -> None:
        history.append(x.p[:nf].copy())
        if callback is not None:
            callback(Progress(len(history) - 1, x.p[:nf].copy(), x.J))

    stages = shooting_stages(prob, segments, likelihood.LEAST_SEGMENT)

    def left() -> int:
        return max_iter - (len(history) - 1)

    def run(stages, p, budget, radius, at=None) -> Descent:
        return _stages(prob, stages, p, budget, tol, radius, escapes, follow, report, at, box)

    if at is not None and not prob.grows(p[:nf]):
        count = 1  # the start's response stays bounded over the whole record (`point` checked it)
    else:
        at = None
        with np.errstate(over="ignore", invalid="ignore"):  # a diverging start is an answer here
            count = prob.shooting(p[:nf], likelihood.FEWEST_SEGMENT)
    if segments > 1 and count > 1:  # the start's response grows beyond bound: segments first
        out = run(shooting_stages(prob, count, likelihood.FEWEST_SEGMENT), p, max_iter, SEGMENT_RADIUS)
        return _outcome(prob, p, out, history)
    direct = run([], p, min(max_iter, DIRECT) if stages else max_iter, radius, at)
    if direct.status is Status.MAX_ITERATIONS and direct.step < min(_NEAR, direct.earlier / 2) and stages:
        # near a stationary point, and closing in on it: as many iterations again before anything
        # else (a step that stays near one size is a slow crawl in a poor basin's valley)
        direct = run([], direct.point.p, min(left(), DIRECT), radius)
    if direct.point is None:  # the model diverges from `p`: segments as short as the records need
        stages = shooting_stages(prob, segments, likelihood.FEWEST_SEGMENT)
    out = direct
    if direct.status is not Status.CONVERGED and stages and left() // 2:
        # multiple shooting gets half of what is left; the rest goes on from the lower of the
        # points the two reached on the whole record (no budget is left unused)
        out = run(stages, p, left() // 2, SEGMENT_RADIUS)
        if out.status is not Status.CONVERGED:
            lower = min(
                (d for d in (direct, out) if d.point is not None), key=lambda d: d.point.J, default=None
            )
            if lower is not None:
                out = run([], lower.point.p, left(), radius) if left() else lower
    return _outcome(prob, p, out, history)


def _outcome(prob: Objective, p: np.ndarray, out: Descent, history: list) -> Outcome:
    """The fit's `Outcome` where its last descent `out` stopped (from `p`; `history`: θ after
    each iteration), with its optimum (θ and Cramér-Rao σ) where it converged."""
    nf = prob.n_free
    if out.point is None:
        return Outcome(p, Status.DIVERGED, len(history) - 1, np.array(history))
    optimum = ()
    if out.status is Status.CONVERGED and out.fisher is not None:
        optimum = (
            out.point.p[:nf].copy(),
            bounds.crlb(likelihood.reduced(out.fisher, np.zeros(len(out.fisher)), nf)[0]).std,
        )
    x = out.point
    held = out.held if out.held is not None and out.held.any() else None
    return Outcome(
        x.p,
        out.status,
        len(history) - 1,
        np.array(history),
        out.fisher,
        optimum,
        out.joined,
        x.J,
        (x.xs, x.res),
        held,
    )


def shooting_stages(prob: Objective, segments: int, least: int) -> list[Objective]:
    """The multiple-shooting stages: `segments`, `segments`/`SHRINK`, … pieces per record of at
    least `least` samples (`Objective.segmented`), each with fewer than the one before and more
    than the records themselves."""
    stages, n = [], segments
    while n > 1:
        stage = prob.segmented(n, least)
        if stage.pieces > prob.pieces and (not stages or stage.pieces < stages[-1].pieces):
            stages.append(stage)
        n //= SHRINK
    return stages


def _stages(prob, stages, p, max_iter, tol, radius, escapes, follow, report, at=None, box=None) -> Descent:
    """`_descend` on each of `stages` (multiple-shooting problems) in turn and then on `prob`,
    each from the one before's θ; the second-order check on `prob`'s optimum. The descent on
    `prob` (point None where the model diverges on it). `at`: the point at `p` on the first
    stage, if known."""
    nf = prob.n_free
    theta, s, delta, used = p[:nf].copy(), None, None, 0
    for stage in stages + [prob]:
        x = at if at is not None else stage.point(theta)
        at, terms = None, None
        if x is None:  # the model diverges on this stage from the last one's θ
            if stage is prob:
                return Descent(None, Status.DIVERGED, used, 0.0, None)
            continue
        if s is None:
            terms = _terms(stage, x)
            if terms is None:
                return Descent(x if stage is prob else None, Status.DIVERGED, used, 0.0, None)
            g, M = terms
            s, delta = _scale(prob.start, theta, likelihood.reduced(M, g, nf)[0]), radius * np.sqrt(nf)
        final = stage is prob
        tol_stage = tol if final else max(tol, STAGE_TOL)
        out = _descend(stage, x, s, delta, tol_stage, max_iter - used, report, follow, terms, box)
        used += out.iterations
        for k in range(escapes + 1 if final else 0):
            if out.status is not Status.CONVERGED or out.joined >= 0:
                break
            moving = ~out.held if out.held is not None else None
            directions, probed = second_order(stage, out.point, s, out.fisher, moving)
            if not directions:
                break
            sizes = (1.0,) if probed else out.delta * 0.5 ** np.arange(8)
            moved = (
                _leave_saddle(stage, out.point, directions, sizes, out.fisher, box) if k < escapes else None
            )
            if moved is None:
                if not probed:
                    out = replace(out, status=Status.SADDLE)
                break
            report(moved)
            out = _descend(stage, moved, s, out.delta, tol_stage, max_iter - used, report, follow, None, box)
            used += out.iterations
        theta, delta = out.point.p[:nf].copy(), max(out.delta, MIN_RADIUS)
    return out


def _leave_saddle(
    prob: Objective, x: Point, directions: list, sizes, M: np.ndarray, box: tuple | None
) -> Point | None:
    """A point of lower cost along ±v for v in `directions` (in turn), steps of each of `sizes`
    × v (the initial states following, `objective.following`; inside the `box`); None if there
    is none."""
    nf = prob.n_free
    for v in directions:
        for size in sizes:
            for sign in (1.0, -1.0):
                d = sign * size * v
                if box is not None:
                    d = into_box(x.p[:nf] + d, box) - x.p[:nf]
                trial = prob.moved(x, d if prob.projected else following(M, np.zeros(len(M)), nf, d)[0])
                if trial is not None and trial.J < x.J:
                    return trial
    return None
