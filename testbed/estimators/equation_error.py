"""The equation-error method `equation-error`: the linear model's rows regressed on smoothed
derivatives of the measured states. No simulation, so no basin of attraction and no divergence
along the record, but biased by the noise and by the smoothing; the ML methods start from it
(`estimators.starts`). A nonlinear model config is regressed by `nonlinear_regression.equation_error_estimate`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from testbed.data import Experiment, ModelConfig
from testbed.errors import InputError, is_number
from testbed.estimators.base import (
    Callback,
    Estimate,
    Method,
    Options,
    Progress,
    Status,
    bounds_message,
    option,
)
from testbed.estimators.box_bounds import least_squares_step, on_bounds
from testbed.estimators.intervals import between_present
from testbed.estimators import nonlinear_regression
from testbed.identification.bounds import assess, held_bounds
from testbed.identification.likelihood import divergence, initial_states
from testbed.identification.problem import Problem, base_name, check_mounting, problem
from testbed.models.linear import NX, OUTSIDE_EQUATIONS, STATES, tilde

__all__ = ["EQUATION_ERROR", "SMOOTHABLE", "WINDOW_S", "EquationErrorOptions", "regression", "smoothed"]

WINDOW_S = 0.5  # the smoothing window's default width, seconds
SMOOTHABLE = 5  # the shortest window a cubic is smoothed over: a record needs as many samples


def regression(
    prob: Problem, window_s: float = WINDOW_S, box: tuple | None = None
) -> tuple[np.ndarray, dict[str, str]]:
    """The free coefficients (n_free,) from a least-squares fit of the linear model's rows, and
    those left at their a-priori values for want of data: name → why.

    Each dynamics row `Mt ẋ = At x + Bt δ + St` is linear in its coefficients. The measured states
    are smoothed (Savitzky-Golay, cubic, `window_s` wide and at least `SMOOTHABLE` samples) and
    the row is averaged over each interval between consecutive smoothed samples of the states it
    involves (`intervals.between_present`), where the input is held: ẋ ≈ Δx/Δt, x ≈ the
    interval's midpoint, δ its mean over the interval; the row's free coefficients are then a
    linear regression. Missing samples: the cubic of each window is fitted to the samples present
    (`smoothed`), a window with too few of them gives no smoothed sample, and the interval runs
    on to the next one there is. A row is used only on experiments that measure every state it
    involves; the free coefficients of a row that no experiment supports (none measures those
    states, or none has enough of their samples present to smooth), and directions the data do
    not excite, keep their a-priori values (minimum-norm correction). `box`: `(low, high)` of the
    free values (±inf: open; the a-priori values inside it): a row whose least-squares solution
    leaves the box is solved in it instead (bounded least squares, `scipy.optimize.lsq_linear`).
    """
    s = prob.structure
    # each record's known part: constants and fixed coefficients (a record may have its own)
    known = [tilde(s, prob.coefficients(np.zeros(prob.n_free), r.group)) for r in prob.records]
    values, left = prob.start, {}
    records = []  # per record: (t, smoothed states (NaN: none), inputs), or None if too short
    for r in prob.records:
        n = len(r.y)
        odd = n - (1 - n % 2)  # the longest window within the record
        win = min(max(SMOOTHABLE, int(round(window_s / r.dt)) | 1), odd)
        if win < SMOOTHABLE:
            records.append(None)
            continue
        # only samples whose smoothing window lies within the record: the ends would be
        # extrapolated
        xs = np.full((n, NX), np.nan)
        # the measured states: the data less their output terms (at the a-priori values)
        y = r.y - prob.output_terms(r, prob.start)
        present = np.ones(y.shape, bool) if r.present is None else r.present
        # a channel sampled at a fraction f of the rows: a window wide enough to hold SMOOTHABLE
        # of its samples
        f = present.mean(axis=0)
        wide = [min(max(win, int(np.ceil(SMOOTHABLE / fc)) | 1), odd) if fc else 0 for fc in f]
        for w in set(wide) - {0}:  # the channels of one window width smoothed together
            c = [k for k, wk in enumerate(wide) if wk == w]
            xs[w // 2 : n - w // 2, r.measured[c]] = smoothed(y[:, c], w, present[:, c])
        # the inputs (the a-priori input delay) smoothed as the states of every sample are
        us = prob.inputs(r, prob.start).copy()
        us[win // 2 : n - win // 2] = smoothed(us, win)
        records.append((r.dt * np.arange(n), xs, us))
    for row in range(6):  # u v w p q r
        cols = [
            j
            for j, i in enumerate(prob.index)
            if s.dMt[i, row].any() or s.dAt[i, row].any() or s.dBt[i, row].any() or s.dSt[i, row]
        ]
        if not cols:
            continue
        idx = prob.index[cols]
        involved = np.any([(Mf[row] != 0) | (Af[row] != 0) for Mf, Af, _, _ in known], axis=0)
        involved |= (s.dMt[idx, row] != 0).any(0) | (s.dAt[idx, row] != 0).any(0)
        involved[row] = True
        at = np.flatnonzero(involved)  # the states the row involves: the others may be missing
        X, Y, measuring = [], [], 0
        for r, record, (Mf, Af, Bf, Sf) in zip(prob.records, records, known):
            if not set(at) <= set(r.measured):
                continue
            measuring += 1
            if record is None:
                continue
            # over each interval between smoothed samples of every state the row involves
            t, xs, us = record
            xdot, x, u = between_present(t, xs[:, at], us)
            # Σ_free θ_i (∂Mt_i ẋ − ∂At_i x − ∂Bt_i δ − ∂St_i)_row = (At_f x + Bt_f δ + St_f − Mt_f ẋ)_row,
            # each record's own values (per record) acting on its rows alone
            Xr = (
                xdot @ s.dMt[idx, row][:, at].T
                - x @ s.dAt[idx, row][:, at].T
                - u @ s.dBt[idx, row].T
                - s.dSt[idx, row]
            ) * prob.acting(r.group)[cols]
            Yr = x @ Af[row, at] + u @ Bf[row] + Sf[row] - xdot @ Mf[row, at]
            keep = np.isfinite(Yr) & np.isfinite(Xr).all(axis=1)
            X.append(Xr[keep])
            Y.append(Yr[keep])
        if not sum(map(len, Y)):
            needs = ", ".join(STATES[i] for i in at)
            if measuring:
                why = (
                    f"the row involves {needs}; no experiment has enough of their samples present to "
                    f"smooth (a cubic over {window_s:g} s and at least {SMOOTHABLE} samples, half of "
                    "them present)"
                )
            else:
                unmeasured = [STATES[i] for i in at if not any(i in r.measured for r in prob.records)]
                why = f"the row involves {needs}; no experiment measures " + (
                    ", ".join(unmeasured) if unmeasured else "them all"
                )
            left |= {prob.free[j]: why for j in cols}
            continue
        X, Y = np.vstack(X), np.concatenate(Y)
        prior = values[cols]
        step = least_squares_step(
            X, Y - X @ prior, prior, None if box is None else (box[0][cols], box[1][cols])
        )
        values[cols] = prior + step
    return values, left


def smoothed(y: np.ndarray, win: int, present: np.ndarray | None = None) -> np.ndarray:
    """Savitzky-Golay smoothing of `y` (N, k), cubic, over `win` (odd) samples: at each sample
    whose window lies within the record (N − win + 1 of them), the value there of the cubic
    fitted to the window by least squares, a fixed weighted sum of the window. With `present`
    (N, k; None: every sample) the cubic is fitted to the samples present in the window alone,
    and the value is NaN where fewer than half of the samples the channel's rate puts in the
    window (its fraction present over the record times `win`), or fewer than `SMOOTHABLE`, are
    present: a gap is not bridged, and a cubic's four coefficients are fitted to at least five
    distinct samples, never a singular system."""
    h = win // 2
    if present is None or present.all():
        # the fitted cubic's value at the window's centre: the first row of the Vandermonde
        # pseudo-inverse
        c = np.linalg.pinv(np.vander(np.arange(-h, h + 1.0), 4, increasing=True))[0]
        return sliding_window_view(y, win, axis=0) @ c
    # per window and channel the normal equations of the cubic in s = o − h, weighted by presence:
    # Σ P s^(a+b) (a, b ≤ 3) and Σ P s^a y, summed over the window's offsets o: each a product of
    # the windows (n, k, win) with the powers of s (win, ·)
    w = present.astype(float)
    y = np.where(present, y, 0.0)
    s = (np.arange(win) - h) / max(h, 1)  # scaled to [−1, 1]: the 4 × 4 systems stay conditioned
    powers = s[:, None] ** np.arange(7)  # (win, 7)
    A = sliding_window_view(w, win, axis=0) @ powers  # (n, k, 7)
    b = sliding_window_view(y * w, win, axis=0) @ powers[:, :4]  # (n, k, 4)
    normal = A[:, :, np.add.outer(np.arange(4), np.arange(4))]  # (n, k, 4, 4) Hankel
    enough = A[:, :, 0] >= np.maximum(w.mean(axis=0) * win / 2, SMOOTHABLE)
    normal[~enough] = np.eye(4)
    out = np.linalg.solve(normal, b[..., None])[..., 0, 0]
    return np.where(enough, out, np.nan)


@dataclass(frozen=True)
class EquationErrorOptions(Options):
    """Options of `equation-error`."""

    window_s: float = option(
        WINDOW_S,
        lambda v: is_number(v) and v > 0,
        "a number > 0 (seconds)",
        "the width of the cubic Savitzky-Golay window that smooths the measured states and inputs",
    )


def _fit(
    experiments: Sequence[Experiment],
    config: ModelConfig,
    options: EquationErrorOptions,
    callback: Callback | None,
) -> Estimate:
    """The regression's coefficients, with the output-error analysis at them (`bounds.assess`): the
    Cramér-Rao bounds, the noise and the initial states that fit best, the negative
    log-likelihood as the cost, so that it compares with the other methods' estimates. One
    iteration: the regression is solved once. DIVERGED where the linear model at the estimate
    diverges on the data (the bounds are then meaningless), the reason named; InputError where the
    data leave a free coefficient out of the regression (`regression`)."""
    _refuses(config)
    t0 = time.perf_counter()
    prob = problem(experiments, config)
    box = config.box([base_name(n) for n in prob.free]) if config.bounds else None
    values, left = regression(prob, options.window_s, box)
    if left:
        rows = {why: [n for n in left if left[n] == why] for why in left.values()}
        raise InputError(
            f"{prob.source}: method='equation-error' cannot estimate "
            + "; ".join(f"{', '.join(names)} ({why})" for why, names in rows.items())
            + ": expected experiments that measure those states, or another method"
        )
    history = np.vstack([prob.start, values])
    why = None if np.all(np.isfinite(values)) else "the regression's estimate is not finite"
    if why is None:
        with np.errstate(over="ignore", invalid="ignore"):
            p = initial_states(prob, values)
        why = divergence(prob, p)
    if why is not None:
        return Estimate(
            method=EQUATION_ERROR.name,
            status=Status.DIVERGED,
            free=prob.free,
            values=values,
            std=np.full(prob.n_free, np.nan),
            cost=np.nan,
            iterations=1,
            evaluations=0,
            wall_time_s=time.perf_counter() - t0,
            noise_std={},
            history=history,
            message=why,
        )
    info = assess(prob, p)
    if callback is not None:
        callback(Progress(1, info.values.copy(), info.cost))
    # the values on a bound: no σ, the others' with them held
    held = on_bounds(values, box)
    std, coloured = held_bounds(info, held)
    at_bounds = {prob.free[k]: float(values[k]) for k in np.flatnonzero(held)}
    return Estimate(
        method=EQUATION_ERROR.name,
        status=Status.CONVERGED,
        free=prob.free,
        values=info.values,
        std=std,
        cost=info.cost,
        iterations=1,
        evaluations=0,
        wall_time_s=time.perf_counter() - t0,
        noise_std=info.noise_std,
        history=history,
        crlb_corrected_std=coloured,
        initial_states=info.initial_states,
        at_bounds=at_bounds or None,
        message=bounds_message(at_bounds),
    )


def _refuses(config: ModelConfig) -> None:
    """`InputError` for what the regression cannot take: a velocity log's mounting, a free
    output term or delay (they are in no row of the equations)."""
    check_mounting(config, "equation-error")
    terms = [n for n in config.free if n in OUTSIDE_EQUATIONS]
    if terms:
        raise InputError(
            f"{config.source or 'config'}: [identify] free lists {terms[0]}; equation-error "
            "regresses the equations' rows, which the outputs' biases, the current and the "
            "inputs' delay are not in: expected them fixed (their given values are applied), or an "
            "output-error method (ml-gn, ml-lm, ml-nr, ml-nm)"
        )


EQUATION_ERROR = Method(
    name="equation-error",
    fit=_fit,
    options=EquationErrorOptions,
    summary="equation error: the model's rows regressed on derivatives of the measured states (the linear "
    "model's smoothed)",
    iterative=False,
    starts=False,
    nonlinear=nonlinear_regression.equation_error_estimate,
    refuses=_refuses,
    refuses_nonlinear=nonlinear_regression.refuses,
    bounds=True,
)
