"""The nonlinear model's equation error, as output error's start (`regressed`) and as the method
`equation-error` on a nonlinear model config (`equation_error_estimate`): its dynamics rows fitted to the measured
states' difference quotients, with no flight, so no basin of attraction and no divergence along
the record.

Every row of `M ν̇ = F(ν, η, δ; θ)` is linear in the terms' coefficients, and only M's inertia
coefficients and the Munk terms enter through M⁻¹. Over each sample interval, where the fin
angles are held, the measured states' difference quotient ν̇ ≈ Δν/Δt is compared with the
model's rates at the interval's midpoint x̄ (over a missing sample, the interval runs between
the samples present either side, with the fins' mean over it):

    e(θ) = Δν/Δt − f_ν(x̄, δ; θ)

and θ's free coefficients are taken by Gauss-Newton on Σ eᵀ W e, its Jacobian ∂f/∂θ the model's
exact sensitivities (`nonlinear.rate_sensitivities`), W the inverse of each row's mean-square error
at the current θ. The states are not smoothed, as the linear model's regression smooths them:
ν̇ jumps at every sample where the fins move, and a window spreads the jump over its neighbours
(on Scenario I's noise-free truth a 0.1 s window puts the fins' lift 1.4 % off, 0.5 s 25–35 %,
the raw quotient 0.1 %). White noise in the quotient is uncorrelated with the midpoint's (the
same samples, differenced and averaged), so it adds variance, not bias. Each step is the
least-squares solution of least norm in coordinates scaled by the Jacobian's columns, so
directions the data do not excite keep their a-priori values. Noise in the regressors biases the
estimate (errors in variables: on noisy Scenario I the lifts within 0.5 %, the blades' blunt drags
off by −155 to +211 %): as the linear model's regression, it is a start for output error, and as
a method an estimate of that bias's size.

It needs every state the rows involve measured: u v w p q r and the attitude φ θ.
"""

from __future__ import annotations

import time
from dataclasses import fields, replace
from typing import Sequence

import numpy as np

from testbed.data import Experiment, ModelConfig
from testbed.errors import InputError
from testbed.estimators.base import Callback, Estimate, OptionError, Options, Progress, Status, bounds_message
from testbed.estimators.box_bounds import least_squares_step, on_bounds
from testbed.estimators.nonlinear_fit import estimate_of
from testbed.estimators.intervals import between_present
from testbed.identification.nonlinear_output_error import (
    FlightRecord,
    coloured_bounds_held,
    fitted_initial_states,
    flight_residuals,
    neg_log_likelihood,
    pooled_noise,
    read_outputs,
    record_fins,
    setup,
    start_states,
)
from testbed.identification.problem import check_mounting
from testbed.identification.recursions import counting
from testbed.models.linear import NX, STATES
from testbed.models.nonlinear import NonlinearModel, rates, rate_sensitivities

__all__ = ["NEEDED", "equation_error_estimate", "regressed", "refuses"]

NEEDED = ("u", "v", "w", "p", "q", "r", "phi", "theta")  # the states the dynamics rows involve
_ROWS = 6  # ν̇'s rows of f
_STEPS = 8  # Gauss-Newton steps at most: M⁻¹ is the only nonlinearity in θ
STEP_TOL = 1e-6  # stop when every step is below this fraction of its coefficient


def _intervals(records: Sequence[FlightRecord], channels: Sequence[str]):
    """(ν̇, x̄, δ) over every record's intervals between consecutive samples where the rows'
    states are all present (`intervals.between_present`), the states the rows do not involve at 0."""
    to = [STATES.index(c) for c in NEEDED]
    source = [list(channels).index(c) for c in NEEDED]
    nudot, xbar, fins = [], [], []
    for r in records:
        quotient, mid, mean = between_present(r.t, r.y[:, source], r.fins)
        x = np.zeros((len(mid), len(STATES)))
        x[:, to] = mid
        nudot.append(quotient[:, :_ROWS])
        xbar.append(x)
        fins.append(mean)
    return np.concatenate(nudot), np.concatenate(xbar), np.concatenate(fins)


def regressed(
    model: NonlinearModel,
    theta: np.ndarray,
    records: Sequence[FlightRecord],
    channels: Sequence[str],
    free: Sequence[str],
    box: tuple | None = None,
    role: str = "start",
) -> tuple[np.ndarray, int]:
    """θ ⊕ b ⊕ g ⊕ c ⊕ τ (`theta`) with θ's `free` coefficients (names from `model.names`; the
    others of `free` held) fitted to the records' difference quotients (module doc), and the
    Gauss-Newton steps taken. The records are taken less what their outputs add to a body at rest
    (the biases b, the current c), their fins advanced by the delay τ; b, g, c and τ are held, and a
    mounted log's velocities taken as the CG's. `box`: `(low, high)` of θ's free coefficients (None:
    none), each step's least-squares correction solved in it (`box_bounds.least_squares_step`).
    `InputError` naming the states the rows need that the records do not measure, or where no
    interval has them all present, for the regression as output error's start (`role` "start")
    or as the method (`role` "method")."""
    name, instead = (
        ("equation-error start", "start config") if role == "start" else ("equation-error", "ml-gn")
    )
    missing = [c for c in NEEDED if c not in channels]
    if missing:
        raise InputError(
            f"{name}: the records do not measure {', '.join(missing)}; the dynamics rows "
            f"involve {' '.join(NEEDED)}: expected records measuring them, or {instead}"
        )
    m, ch = len(model.names), [STATES.index(c) for c in channels]
    unbiased = [
        replace(
            r,
            y=r.y - read_outputs(np.zeros((len(r.t), NX)), theta, m, ch, r.heading),
            fins=record_fins(r, theta, m, ch)[0],
        )
        for r in records
    ]
    nudot, x, fins = _intervals(unbiased, channels)
    if not len(nudot):
        raise InputError(
            f"{name}: no interval between samples where every state the dynamics rows "
            f"involve ({' '.join(NEEDED)}) is present; expected records with rows measuring them all, "
            f"or {instead}"
        )
    idx = np.array([model.names.index(n) for n in free if n in model.names])
    theta = np.array(theta, float)
    rows = theta[:m]  # a view: the dynamics rows' coefficients, stepped in place
    for steps in range(1, _STEPS + 1):
        # e = Δν/Δt − f_ν(x̄, δ; θ), J = ∂f_ν/∂θ at the free coefficients
        e = nudot - rates(model, rows, x, fins)[:, :_ROWS]
        if not np.all(np.isfinite(e)):
            raise InputError(f"{name}: the model's rates are not finite at the records' states")
        # W = diag(1 / mean eᵢ²): each row weighted by its own error's scale
        W = 1.0 / np.maximum(np.mean(e**2, axis=0), np.finfo(float).tiny)
        J = rate_sensitivities(model, rows, x, fins)[:, :_ROWS, idx]
        A = (J * np.sqrt(W)[None, :, None]).reshape(-1, len(idx))
        b = (e * np.sqrt(W)).reshape(-1)
        step = least_squares_step(A, b, rows[idx], box)
        rows[idx] += step
        if np.all(np.abs(step) <= STEP_TOL * np.abs(rows[idx])):
            break
    return theta, steps


def refuses(config: ModelConfig, options: Options) -> None:
    """What `equation-error` cannot take in a nonlinear model config, whatever the data: an option
    other than its default (`OptionError`: the linear regression's smoothing window; the quotients
    are not smoothed); a mounted velocity log, a free parameter beside the terms (an output bias,
    the current, the delay: in no dynamics row) (`InputError`)."""
    for f in fields(options):
        if getattr(options, f.name) != f.default:
            raise OptionError(
                "equation-error", f.name, getattr(options, f.name),
                "its default: equation-error on a nonlinear model config has no such option",
            )  # fmt: skip
    check_mounting(config, "equation-error on a nonlinear model config")
    outside = [n for n in config.free if n not in config.nonlinear()[0].names]
    if outside:
        raise InputError(
            f"{config.source or 'config'}: [identify] free lists {outside[0]}; equation-error regresses "
            "the dynamics rows, which the outputs' biases, the current and the inputs' delay are not in: "
            "expected them fixed (their given values are applied), or an output-error method (ml-gn, ml-lm, ml-nm)"
        )


def equation_error_estimate(
    experiments: Sequence[Experiment], config: ModelConfig, options: Options, callback: Callback | None
) -> Estimate:
    """`equation-error` on a nonlinear model config: the dynamics rows' free coefficients
    regressed from the config's values (`regressed`, in the config's box: its `[identify] bounds`
    and physical sides), then the output-error analysis at them, as the linear method's: each
    record's initial state fitted by Gauss-Newton on its flight, R the residuals' mean square (or
    the config's `noise_std` where given), the Cramér-Rao and coloured-residual bounds with the
    initial states among the parameters (a coefficient on a bound: none, the others' with it held)
    and the negative log-likelihood as the cost, so that the estimate compares with the other
    methods'. `iterations`: the regression's Gauss-Newton steps. DIVERGED, the reason named,
    where the model's flight at the estimate does not stay finite over the records; `InputError`
    for a free output term or delay (in no dynamics row), a mounted velocity log, records without
    the states the rows involve; `OptionError` for an option other than its default (the linear
    regression's smoothing window: the quotients are not smoothed)."""
    t0, name = time.perf_counter(), "equation-error"
    where = f"{name} on a nonlinear model config"
    refuses(config, options)
    channels, recs, model, theta, idx = setup(experiments, config, where)
    ch = [STATES.index(c) for c in channels]
    given = config.noise_std or {}
    held = np.array([given.get(c, np.nan) ** 2 for c in channels])
    box = config.box(config.free)
    with counting() as tally:
        th, steps = regressed(model, theta, recs, channels, config.free, box, role="method")
        values = th[idx]
        history = np.vstack([theta[idx], values])
        x0 = start_states(model, recs, ch)
        flown = flight_residuals(model, th, x0, recs, ch) if np.all(np.isfinite(values)) else None
        if flown is None:
            return estimate_of(
                config, experiments, recs, channels, x0, t0, tally[0], method=name, status=Status.DIVERGED,
                values=values, std=np.full(len(idx), np.nan), cost=np.nan, iterations=steps,
                noise_std={}, history=history,
                message="the model's flight at the regression's estimate does not stay finite over the records",
            )  # fmt: skip
        x0 = fitted_initial_states(model, th, recs, ch, x0, None, sensitivities=False)[0]
        R = pooled_noise(flight_residuals(model, th, x0, recs, ch), held)
        # the values on a bound: no σ, the others' with them held
        held_on = on_bounds(values, box)
        on = {config.free[k]: float(values[k]) for k in np.flatnonzero(held_on)}
        std, coloured, res, H = coloured_bounds_held(model, th, x0, recs, channels, config.free, R, held_on)
    cost = neg_log_likelihood(res, R)
    if callback is not None:
        callback(Progress(1, values.copy(), cost))
    return estimate_of(
        config, experiments, recs, channels, x0, t0, tally[0], method=name, status=Status.CONVERGED,
        values=values, std=std, cost=cost, iterations=steps,
        noise_std={c: float(np.sqrt(v)) for c, v in zip(channels, R)}, history=history,
        crlb_corrected_std=coloured, information=H, at_bounds=on or None,
        message=bounds_message(on),
    )  # fmt: skip
