"""On-line identification (the paper's §5 and Fig. 2): the modified extended Kalman filter (MEKF)
with a square-root covariance, and the conventional augmented EKF as its baseline.

The augmented state is the 10 model states (`u` as the perturbation u_abs − U) followed by the free
coefficients θ, which are constant up to a small random walk. The states follow the exact
zero-order-hold model `x[k+1] = Φ(θ) x[k] + Γ(θ) δ[k] + s(θ)` of `testbed.models.linear`; its Jacobian
wrt θ, `D = ∂Φ/∂θ x + ∂Γ/∂θ δ + ∂s/∂θ`, is exact as well: with `M = [[A, B, S], [0, 0, 0]]`,
Van Loan's block exponential `expm([[M, ∂M], [0, M]] Δ)` holds `∂expm(MΔ)` in its upper-right
block, so there is no series truncation and singular A (ψ, z integrators) is fine (`expm_pair`:
all free coefficients at once, by scaling and squaring; `D = ∂E ξ` is then one product).

MEKF (Fig. 2). An optimal Kalman filter (KF) for the states, run with the model at the current
θ̂, in parallel with an EKF for the augmented state [x; θ]; both start from the same estimate.
The EKF is the usual one (its own prediction `Φ(θ̂)x̂ + Γ(θ̂)δ + s(θ̂)`, its own innovation and
gain, which update x̂ and θ̂) except for the centre of each Taylor expansion: the Jacobian
`F = [[Φ, D], [0, I]]` is evaluated at the KF's state estimate, which given θ̂ is the optimal one,
instead of at the EKF's own, which the parameter error contaminates. The KF is optimal for the
states given θ̂; while θ̂ is uncertain its process noise includes the prediction error that
uncertainty causes, `D P_θθ Dᵀ` (otherwise it trusts a wrong model over the measurements), so it
becomes the optimal KF at θ̂ as the coefficients converge. (Updating the states with the KF's
gain instead would leave the augmented covariance no longer describing the state error, and at
high signal-to-noise the innovations would outgrow it.)

Square root (the paper's algorithm, in array form): every covariance is held as a root `J` with
`P = J Jᵀ`, so it is symmetric and positive semi-definite by construction and its condition
number is the square root of P's. The measurement update is one QR of the pre-array
`[[R½, C J⁻], [0, J⁻]]` → `[[L, 0], [K̄, J⁺]]`: the innovation root `L` (the paper's `L_k`), the
gain `K = K̄ L⁻¹` (only `L⁻¹ν` is needed: one solve) and the lower-triangular posterior root —
algebraically the paper's `J_{k,k}` formula without forming `C P Cᵀ` (`sqrt_update`). The time
update's root need not be triangular, so it is not triangularised on its own (not
`J⁻ = tria([F J, Q½])`): the rectangular `J⁻ = [F J, Q½]` goes straight into the next
pre-array, and one QR per sample and filter does both updates (same result to rounding, half
the QR calls). The paper names the SVD as the numerically safer way to form `J_{k,k−1}`:
option `sqrt="svd"` takes `J⁻ = U Σ` from the SVD of `[F J, Q½]` (`svd_root`; orthogonal, like
the QR, so no better conditioned here; about twice the cost), then the same update. Both
filters of the MEKF run every update through `sqrt_update`, the kernel the tests compare with
filterpy.

filterpy 2.0 is not used in the filter (the tests check the kernels against it):
- `SquareRootKalmanFilter` is linear only: `predict` is `x = F x + B u` with a fixed F, while
  the augmented prediction is the nonlinear `Φ(θ)x + Γ(θ)δ + s(θ)` with a new F every sample;
  its `update(z, R2)` takes the square root of R (not R), inverts the innovation root with
  `pinv` (an SVD per sample) instead of a triangular solve, forms Q of every QR, returns neither
  the likelihood nor the NIS needed for the cost and the divergence test, and its `P_post`
  returns the prior.
- `ExtendedKalmanFilter` is the conventional form only (no square root); its `predict_update`
  evaluates H (the Jacobian) at the old posterior before predicting and stores that old
  posterior as `x_prior`/`P_prior`. Where the tests use filterpy, predict and update are called
  separately.

Speed (`benchmarks/bench_mekf.py`: a real Scenario II run, 50 Hz, 20 free coefficients, about
100× real time on one core, the goal being 20×): per sample two QRs and two small solves, a
few products; all else is kept off the per-sample path. When no free coefficient enters the
mass matrix (no free *dot term), `M(θ) = Mt⁻¹[At Bt St]` is affine in θ with constant
derivatives (one solve at the start). The exact pair (E, ∂E) costs about three samples; it is
recomputed only when a coefficient moved more than `refresh_tol` of its σ since the last one,
and in between E is carried to first order, `E(θ̂) ≈ E(θₘ) + ∂E·(θ̂ − θₘ)` (one product), so the
prediction's error is second order in that move; D is ∂E at θₘ.

The nonlinear model (a config with `[terms]`). The same filters with the
model's own one-sample transition (`NonlinearTransition`): the RK4 flight over the sample
interval with the fins held, Φ and D that map's exact sensitivities to the state and the free
coefficients at the KF's state, the EKF's prediction its own flight (the model's one interface
to the filters: `begin` an experiment, `step` one sample, `(Φ, D, xk⁺, x⁺)`). The states carry u
as the perturbation here too (the flight adds the vehicle's speed). One pass: the options
`NONLINEAR_REFUSED` (the fixed-interval iterations and the exponential's refresh, which the
exact flight has no use for) are an `OptionError` at any value but their default; the records as
`ml-gn` takes them (`nonlinear_output_error.setup`: complete, measuring the same states).

The conventional EKF (`ekf`) is the textbook filter on the same augmented model: linearised
about its own estimate, `P = F P Fᵀ + Q`, `P = P − K C P` (no symmetrisation, no Joseph form),
so rounding shows up as asymmetry and lost definiteness; both are checked every sample.

Choices (all options of `mekf`/`ekf`, see `FilterOptions`):
- R: measurement noise σ per measured state: the sensors' σ where it is known, from the option
  `noise_std`, else from the config's `noise_std` (`[identify] noise_std`, `--noise-std`; the
  option overrides it entry by entry), else from the data: the third difference of a smooth
  signal sampled fast is almost pure noise, `Var(Δ³e) = 20 σ²`; a median absolute deviation
  makes it robust to the kinks at input steps. States that move fast against the sample rate
  (roll and yaw rate at 20 Hz) leak into it: it is then an upper bound (up to ~1.5× in the
  tests), which errs on the safe side (wider σ); give `noise_std` when known. Process noise is
  sized from the data either way (below).
- Initial covariance: measured states start at their first sample with σ = R's; unmeasured ones
  at trim (0) with σ `unmeasured_std`. Free coefficients start at the config's a-priori values with
  σ = `prior_frac`·|value| (default 50 %), at least `prior_floor` (default 1e-3 × the largest
  |coefficient|), or `prior_std[name]`.
- Q: coefficients a random walk of `param_noise` × prior σ per sample (default 1e-6: constant
  up to a numerical allowance); unmeasured states `unmeasured_noise`; measured states the model
  error, sized from the innovations (next item).
- Model error (`_ModelError`). The linear model is exact only in its linear regime. Beyond it
  (Scenario I: ±20 m depth steps, ±20°/s turns, 30° of pitch) its one-sample prediction error on
  the noise-free truth is 9–40 measurement σ in p, q and r, about 1 σ in u and φ (surge loses
  up to 18 % of its speed in the turns, which the linear surge row cannot follow; φ̇ = p misses
  the tan θ · r of a turn at 30° of pitch, 0.6 σ of it), coloured (lag-one autocorrelation
  0.94–1.0) and changing with the manoeuvre; on Scenario II it is below 0.02 σ. No fixed Q fits both: one sized for the
  linear regime leaves Scenario I's innovations 5–20× their predicted σ (u from the first turn,
  p, r and φ at the first depth step), and one sized for Scenario I discards most of Scenario
  II's information. So the model-error σ q_i of each measured state is estimated on-line by
  covariance matching (Mehra 1972; Myers & Tapley 1976): the innovation's predicted variance is
  `S_ii = S̃_ii + q_i²`, `S̃ = C F P Fᵀ Cᵀ + R` (q_i that of the last time update), so
  `ν_i² − S̃_ii` is a one-sample estimate of q_i², averaged exponentially over `noise_window`
  samples (α = 1/`noise_window`). Where the model is right (q = 0, `Var ν² = 2 S̃²`) that average
  scatters by `S̃ √(2α/(2−α))`; only its part beyond `noise_margin` of those standard errors is
  taken, so that the scatter does not inflate Q on data the model fits, while a real model error
  is taken nearly whole. The floor is `state_noise` × R's σ: none for the square-root filters
  (where the model is exact Q = 0 is the truth, and a floor makes the reported σ conservative:
  1.4–1.9× the scatter in the Monte Carlo study at 0.01), 0.01 for the conventional EKF, whose
  formed `P − K C P` otherwise loses definiteness within a second on a well-scaled problem. The
  ceiling is the channel's variance over the experiment: a model error per sample as large as
  the whole signal is no model of it (a wrong model, left to the divergence test). The
  coefficients' random walk stays small: the model error goes to the states, where it is, not to
  a drift of the coefficients, which then fit what the linear model can follow of the manoeuvre
  (on Scenario I far from the analytic values), their σ the information left once the model
  error is allowed for. The filter's own linearisation error (early, while the coefficients are
  far off) is model error too and is absorbed the same way. Where the model is exact, the
  matching still lifts q off 0 now and then (RMS over a run 0–0.14 R's σ in the Monte Carlo
  study): the reported σ follows (0.8–1.1× the scatter there), but the slow heave-pitch
  coefficients, whose information accumulates over long stretches, scatter up to 1.7× the
  Cramér-Rao bound; `noise_window=0` when the model is known to be exact. The estimate's
  `model_error_std`: the RMS over the samples of the q found, per state.
- Several experiments run in sequence; the coefficients and their covariance carry over, the
  states restart from each experiment's first sample.
- Fixed-interval iterations (`passes` > 1; default 1, the on-line filter). One pass is not the
  maximum-likelihood estimate: early in it P_θθ is the wide prior, θ̂ swings, and the model
  linearised at the swinging estimate (`Φ(θ̂)` in the prediction and in F) has second-order
  errors its covariance does not hold. On weakly identified coefficients that leaves, in the
  Monte Carlo study, a bias of 0.4 σ and a scatter up to 1.4× the Cramér-Rao bound in the sway
  and yaw rows; a test case ends 0.9 σ from the ML estimate. Each further pass runs the filter
  of the model linearised about the previous pass's estimate θ_r, with the prior N(θ_r, P₀)
  re-centred on it: `x⁻ = Φ_r x + Γ_r δ + s_r + D (θ − θ_r)`, `F = [[Φ_r, D], [0, I]]`, D at the
  Kalman filter's state given θ_r. That model is linear in [x; θ], so the pass is the exact
  least-squares solution of the linearised problem: one Gauss-Newton step of the likelihood from
  θ_r, damped by P₀⁻¹ (Levenberg-Marquardt; the iterated Kalman smoother is Gauss-Newton, Bell
  1994). The passes stop when no coefficient moved more than `pass_tol` of its σ (status
  MAX_ITERATIONS if `passes` ran out first); at the fixed point the re-centred prior pulls
  nowhere, so it is the maximum of the likelihood (with the model error at 0, the output-error
  ML estimate) and P_θθ = (P₀⁻¹ + Fisher information)⁻¹, its Cramér-Rao bound up to the wide
  prior. In the Monte Carlo study (`passes=4`) the sway and yaw rows' bias falls to 0.17 σ at
  most; with `noise_window=0` as well every scatter is 0.9–1.2× the bound. Each pass costs about
  as much as the first. The histories, callback calls (every pass makes them) and cost are the
  last pass's; the estimate's `passes` says how many ran, `last_step_std` the last one's
  largest move.
- Divergence (→ `Status.DIVERGED`, reason in the estimate's `message`): a non-finite state or
  covariance, a singular `Mt`, the conventional covariance no longer positive definite, the mean
  normalised innovation squared per measured channel over `nis_window` samples above `nis_limit`,
  or a coefficient more than `explode` prior σ from its start.
- `refresh_tol` (default 0.2; 0: the exact model every sample): see Speed. On a Scenario II
  run the default's final estimates are within 0.1 σ of the every-sample filter's (20 free
  coefficients; 0.02 σ with the 18 that `identify` keeps) at about a fifth of the exponentials.
- Noise-free or low-pass filtered data (the runs' `*.truth.csv`; a log whose sensors or export
  smoothed it): the filter weighs the model against measurement noise; with none left to read
  (σ from the data down to the 1e-9 floor that keeps R definite, or the small remnant a
  low-pass filter leaves) any model error (MuJoCo's plant against the linear model; the
  low-pass filter's smoothing) is a many-σ innovation, and the filter diverges within a few
  samples. No floor on R makes such a fit meaningful: on Scenario II even 1 % of each signal's
  spread leaves innovations ~20× their σ. Covariance matching needs R to be the noise: in a
  channel that `noise_free_channels` finds without noise (and `noise_std` does not give), R
  from the data is the signal's own roughness, so its model error stays at the floor. It is
  reported as DIVERGED with the reason, the innovations' size, that the data look noise-free or
  low-pass filtered, and what to give: the sensors' σ before any low-pass filter, as the
  config's `noise_std`. That σ is the right weight for a low-pass filtered channel: in the band
  the filter passes, where the signal is, its noise has the sensor's spectral density (a
  2nd-order Butterworth at 3 Hz on 20 Hz data, forward and backward: estimates within 2.5
  Cramér-Rao bounds of the raw data's, their σ 0.6-1.1× those bounds).
- `cost` is the negative log-likelihood of the innovations, `½ Σ (νᵀ Σν⁻¹ ν + ln det Σν)`
  (without the 2π constant), Σν the augmented filter's innovation covariance.
- Status CONVERGED when every sample was processed and, over the last 10 % of them, no estimate
  strayed more than 3 final σ from its final value (MAX_ITERATIONS otherwise).
"""

from __future__ import annotations

import time
from dataclasses import fields, replace
from typing import Callable, Sequence

import numpy as np

from testbed.data import Experiment, ModelConfig, split
from testbed.errors import InputError
from testbed.estimators.base import Method, OptionError, Status, unphysical
from testbed.estimators.filter_model import DiscreteModel
from testbed.estimators.filter_options import (
    CONVENTIONAL_FLOOR,
    NONLINEAR_REFUSED,
    FilterEstimate,
    FilterOptions,
)
from testbed.estimators.filter_passes import FilterState, filter_pass, final_covariance
from testbed.identification.nonlinear_output_error import setup
from testbed.identification.nonlinear_prediction import delayed_inputs, unread
from testbed.identification.nonlinear_transition import NonlinearTransition
from testbed.identification.problem import check_mounting, check_one_model, one_model
from testbed.identification.recursions import simulated
from testbed.models.linear import ITHETA, IX, NX, structure, theta_vector
from testbed.simulation.measurements import noise_free_channels, noise_from_data

__all__ = ["EKF", "MEKF", "run_filter"]


def _linear(experiments: Sequence[Experiment], config: ModelConfig, method: str, options: FilterOptions):
    """`run_filter`'s linear model: the experiments and config as the filter takes them
    (`one_model`), θ (all 35) with `idx` free, the model's one-sample transition (a factory: one
    per pass) and why values reached for the free coefficients are unphysical (None if not)."""
    experiments, config = one_model(experiments, config, method)
    s = structure(config.vehicle)
    theta = theta_vector(config.coefficients)
    idx = np.array([ITHETA[n] for n in config.free])

    def why(values: np.ndarray) -> str | None:
        reached = theta.copy()
        reached[idx] = values
        return unphysical(s, reached)

    return experiments, config, theta, idx, lambda: DiscreteModel(s, theta, idx), why


def _refuses_nonlinear(config: ModelConfig, method: str, options: FilterOptions) -> None:
    """What the filter cannot take in a nonlinear model config, whatever the data: an option it has
    no use for (`NONLINEAR_REFUSED`) given a value other than its default (`OptionError`); a
    mounted velocity log, a free parameter beside the terms (an output bias, the current, the
    delay: taken off the data where given, estimated nowhere) (`InputError`)."""
    defaults = {f.name: f.default for f in fields(FilterOptions)}
    for name in NONLINEAR_REFUSED:
        value = getattr(options, name)
        if value != defaults[name]:
            raise OptionError(
                method, name, value, "its default: the filter on a nonlinear model config has no such option"
            )
    check_mounting(config, f"{method} on a nonlinear model config")
    names = config.nonlinear()[0].names
    biased = [n for n in config.free if n not in names]
    if biased:
        raise InputError(
            f"{config.source or 'config'}: [identify] free names {biased[0]}; {method} on a nonlinear model "
            "config takes the fixed output biases off the data and estimates none: expected ml-gn or ml-nm"
        )


def _nonlinear(experiments: Sequence[Experiment], config: ModelConfig, method: str, options: FilterOptions):
    """`_linear` for a nonlinear model config: its θ (`model.names` order), its transition the
    model's RK4 flight (`NonlinearTransition`), nothing unphysical; `OptionError` for an option
    it has no use for (`NONLINEAR_REFUSED`) given a value other than its default."""
    _refuses_nonlinear(config, method, options)
    model, theta, idx = setup(experiments, config, f"{method} on a nonlinear model config")[2:]
    theta, idx = theta[: len(model.names)], np.array(idx)
    # the fixed output biases and current taken off the measured states, the fins advanced by the
    # fixed delay
    experiments = [replace(e, y=unread(e, config), inputs=delayed_inputs(e, config)) for e in experiments]
    return (
        experiments,
        config,
        theta,
        idx,
        lambda: NonlinearTransition(model, theta, idx),
        lambda values: None,
    )


def run_filter(
    experiments: Sequence[Experiment],
    config: ModelConfig,
    *,
    method: str,
    modified: bool,
    square_root: bool,
    options: FilterOptions,
    callback: Callable | None,
) -> FilterEstimate:
    """The filter over the experiments in sequence, `options.passes` times at most (module
    docstring, "Fixed-interval iterations"). `modified`: centre the Jacobian on a parallel KF
    (square-root only); otherwise on the filter's own estimate. A nonlinear model config
    (`config.terms`) is filtered with its own transition (module docstring, "The nonlinear
    model"). A record split at a dropout in its logged inputs (`data.split`) is filtered as its
    stretches, the state started afresh on each."""
    t_start = time.perf_counter()
    experiments = [s for e in experiments for s in split(e)]
    prepare = _linear if config.terms is None else _nonlinear
    experiments, config, theta, idx, transition, unphysical_at = prepare(experiments, config, method, options)
    if options.state_noise is None:
        options = replace(options, state_noise=0.0 if square_root else CONVENTIONAL_FLOOR)
    U = config.vehicle.speed
    p, n = len(idx), NX
    th0 = theta[idx].copy()
    floor = options.prior_floor or 1e-3 * (np.abs(theta).max() or 1.0)
    sig0 = np.maximum(options.prior_frac * np.abs(th0), floor)
    for name, v in (options.prior_std or {}).items():
        if name not in config.free:
            raise InputError(
                f"option prior_std[{name!r}]: not a free coefficient; free: {', '.join(config.free)}"
            )
        sig0[config.free.index(name)] = float(v)
    given = {**(config.noise_std or {}), **(options.noise_std or {})}  # the option's entries first
    sigma_r = noise_from_data(experiments, given)
    for name in options.noise_std or ():
        if name not in sigma_r:
            raise InputError(
                f"option noise_std[{name!r}]: not a measured state; measured: {', '.join(sigma_r)}"
            )

    # covariance matching needs R to be the noise, which a channel without noise does not tell
    quiet = set(noise_free_channels(experiments)) - set(given)
    samples = sum(len(e.t) for e in experiments)
    total = samples if options.max_samples is None else min(samples, options.max_samples)
    ref = step = None  # the previous pass's estimate; the largest move from it, in final σ
    processed = 0  # samples filtered over the passes
    for done in range(1, options.passes + 1):
        start = th0 if ref is None else ref  # the prior N(start, diag σ₀²), re-centred
        st = FilterState(
            th=start.copy(),
            Jth=np.diag(sig0),
            qth=options.param_noise * sig0,
            th0=start.copy(),
            sig0=sig0,
            names=tuple(config.free),
            hist=np.full((total, p), np.nan),
            hist_var=np.full((total, p), np.nan),
            hist_t=np.full(total, np.nan),
            ldiag=np.ones((total, NX)),
            total=total,
            matched=frozenset(sigma_r) - quiet,
            ref=ref,
        )
        diverged = filter_pass(
            experiments, st, transition, options, sigma_r, U, modified, square_root, callback
        )
        processed += st.count
        simulated(st.count * (1 + p))  # the state and its p parameter columns propagated
        P, Ja = final_covariance(st, square_root)
        std = np.sqrt(np.maximum(np.diag(P)[n:], 0.0)) if P is not None else sig0
        if diverged or st.count < samples:
            break
        if ref is not None:
            step = float(np.max(np.abs(st.th - ref) / std))
            if step <= options.pass_tol:
                break
        ref = st.th.copy()

    count = st.count
    values = st.th.copy()
    hist, hist_std = st.hist[:count], np.sqrt(np.maximum(st.hist_var[:count], 0.0))
    cost = st.cost + float(np.log(np.abs(st.ldiag[:count])).sum())
    why = None if diverged else unphysical_at(values)
    if why:
        diverged = {"reason": why, "sample": None, "t": None}
    if diverged:
        status = Status.DIVERGED
    elif count < samples:
        status = Status.MAX_ITERATIONS
    else:
        tail = hist[int(0.9 * count) :]
        settled = np.all(np.abs(tail - values) <= 3.0 * std)
        iterated = options.passes == 1 or (step is not None and step <= options.pass_tol)
        status = Status.CONVERGED if settled and iterated else Status.MAX_ITERATIONS
    model_error = None
    if st.q_samples.any():  # the model error found: RMS over the samples of its σ per sample
        model_error = {
            name: float(np.sqrt(st.q2_sum[i] / st.q_samples[i])) for name, i in IX.items() if st.q_samples[i]
        }
    return FilterEstimate(
        method=method,
        status=status,
        free=tuple(config.free),
        values=values,
        std=std,
        cost=cost,
        iterations=count,
        wall_time_s=time.perf_counter() - t_start,
        noise_std=sigma_r,
        evaluations=-(-processed * (1 + p) // samples),
        start="config",
        history=hist,
        message=diverged["reason"] if diverged else "",
        history_t=st.hist_t[:count],
        history_std=hist_std,
        covariance=P,
        covariance_root=Ja,
        filter=f"{'square-root' if square_root else 'conventional'} {'MEKF' if modified else 'EKF'}",
        nis_mean=st.nis_sum / max(count, 1),
        sqrt=options.sqrt if square_root else None,
        max_covariance_asymmetry=None if square_root else float(st.asym),
        diverged_sample=diverged["sample"] if diverged else None,
        diverged_t=diverged["t"] if diverged else None,
        model_error_std=model_error,
        passes=done if options.passes > 1 else None,
        last_step_std=step if options.passes > 1 else None,
    )


def _method(name: str, modified: bool, square_root: bool, summary: str) -> Method:
    def fit(experiments, config, options, callback):
        return run_filter(
            experiments,
            config,
            method=name,
            modified=modified,
            square_root=square_root,
            options=options,
            callback=callback,
        )

    return Method(
        name=name,
        fit=fit,
        options=FilterOptions,
        summary=summary,
        iterative=False,
        starts=False,
        online=True,
        nonlinear=fit,
        refuses=lambda config: check_one_model(config, name),
        refuses_nonlinear=lambda config, options: _refuses_nonlinear(config, name, options),
    )


MEKF = _method(
    "mekf",
    modified=True,
    square_root=True,
    summary="the modified extended Kalman filter with a square-root covariance (on-line)",
)


EKF = _method(
    "ekf",
    modified=False,
    square_root=False,
    summary="the conventional augmented extended Kalman filter (on-line baseline)",
)
