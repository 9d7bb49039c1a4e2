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

import io
import math
import time
from functools import lru_cache
from dataclasses import dataclass, field, fields, replace
from typing import Callable, Mapping, Sequence

import numpy as np

from testbed.data import Experiment, ModelConfig, split
from testbed.errors import InputError, is_number
from testbed.estimators.base import (
    Estimate,
    Method,
    OptionError,
    Options,
    Progress,
    Status,
    count_option,
    is_count,
    option,
    unphysical,
)
from testbed.identification.nonlinear_output_error import setup
from testbed.identification.nonlinear_transition import NonlinearTransition
from testbed.identification.problem import check_mounting, check_one_model, one_model
from testbed.identification.recursions import simulated
from testbed.simulation.measurements import NOISE_STD, noise_free_channels, noise_from_data
from testbed.models.linear import (
    IX,
    ITHETA,
    NX,
    STATES,
    continuous,
    derivatives,
    expm_pair,
    structure,
    theta_vector,
)

__all__ = [
    "EKF",
    "DiscreteModel",
    "FilterEstimate",
    "FilterOptions",
    "MEKF",
    "NONLINEAR_REFUSED",
    "PAPER_OPTIONS",
    "run_filter",
    "sqrt_update",
    "svd_root",
    "tria",
]


# ---------------------------------------------------------------- square-root kernels (pure)


def tria(X: np.ndarray) -> np.ndarray:
    """Lower-triangular L with a non-negative diagonal and `L Lᵀ = X Xᵀ`; X is (n, k ≥ n)."""
    L = np.linalg.qr(X.T, mode="r").T
    return L * np.where(np.diag(L) < 0, -1.0, 1.0)


@lru_cache(maxsize=None)
def _tri(n: int) -> np.ndarray:
    """The (n, n) lower-triangular mask (cached: the filter takes triangles every sample)."""
    return np.tri(n)


def sqrt_update(pre: np.ndarray, m: int, nu: np.ndarray):
    """The array-form measurement update, the filter's own kernel (module docstring).

    `pre` is the pre-array `[[Rh, C J⁻], [0, J⁻]]` ((m + n, m + k), zero-padded on the right
    is fine): `Cov v = Rh Rhᵀ` for `y = C x + v`, `J⁻` (n, k ≥ n) any root of the prior (the
    rectangular `[F J, Q½]` straight from the time update, or a triangular one). One QR gives
    `[[L, 0], [K̄, J⁺]]`; `nu` is the innovation ν (m,), or (m, j) columns of them.

    Returns `(K ν, L⁻¹ ν, L, J⁺)`: the state correction (`K = K̄ L⁻¹`; `nu = I` gives K), the
    whitened innovation, the innovation root (`L Lᵀ = C P⁻ Cᵀ + R`) and the lower-triangular
    posterior root (`J⁺J⁺ᵀ = P⁻ − K C P⁻`); the diagonals' signs are as the QR left them.
    """
    r = pre.shape[0]
    h = np.linalg.qr(pre.T, mode="raw")[0]  # its lower triangle: [[L, 0], [K̄, J⁺]]
    L = h[:m, :m] * _tri(m)
    w = np.linalg.solve(L, nu)
    return h[m:, :m] @ w, w, L, h[m:, m:r] * _tri(r - m)


def svd_root(X: np.ndarray) -> np.ndarray:
    """`U Σ` from the SVD of X (n, k ≥ n): an (n, n) root of `X Xᵀ` (option `sqrt="svd"`)."""
    U, sv = np.linalg.svd(X, full_matrices=False)[:2]
    return U * sv


# ---------------------------------------------------------------- the model and its Jacobian


class DiscreteModel:
    """The discrete model `E = [Φ Γ s]` and `∂E/∂θ` (n, p, q) at the free coefficients `th`.

    When no free coefficient enters the mass matrix Mt (no free *dot term: Scenario II's default
    list), `M = Mt⁻¹[At Bt St]` is affine in θ and its derivatives are constant: both come from
    one solve at the start and `M(θ)` is one product. Otherwise `continuous`/`derivatives` are
    evaluated at every refresh.

    The filters take the model through `linearised` (module docstring, "Speed"): exact when a
    coefficient moved more than `refresh_tol` of its σ since the last exact one (and at the
    first sample of each experiment: `restart`), carried to first order in between."""

    def __init__(self, s, theta: np.ndarray, idx: np.ndarray):
        self.s, self.theta, self.idx = s, theta.copy(), idx
        self.th0 = theta[idx].copy()
        self.affine = not np.any(s.dMt[idx])
        if self.affine:
            self.M0, self.dM = self._continuous(self.theta)  # LinAlgError: singular Mt
            self.dMq = np.ascontiguousarray(self.dM.transpose(0, 2, 1))  # (n, q, p)
        self.restart(0.0, 0.0)

    def _continuous(self, theta):
        A, B, S = continuous(self.s, theta)
        dA, dB, dS = derivatives(self.s, theta, A, B, S, self.idx)
        M = np.hstack([A, B, S[:, None]])
        dM = np.concatenate([dA, dB, dS[:, :, None]], axis=2).transpose(1, 0, 2)
        return M, np.ascontiguousarray(dM)

    def exact(self, th: np.ndarray, dt: float):
        """`(E, dE)` at `th`: `E = [Φ Γ s]` (n, q) and `dE[:, i, :] = ∂E/∂θ_i` (n, p, q), exact
        (`expm_pair`)."""
        if self.affine:
            M, dM = self.M0 + self.dMq @ (th - self.th0), self.dM
        else:
            theta = self.theta.copy()
            theta[self.idx] = th
            M, dM = self._continuous(theta)
        return expm_pair(M, dM, dt)

    def restart(self, dt: float, refresh_tol: float) -> None:
        """A new experiment (sample interval `dt`): its first `linearised` is exact."""
        self.dt, self.tol2, self.th_model = dt, refresh_tol**2, None

    def begin(self, e: Experiment, refresh_tol: float) -> None:
        """A new experiment `e` (`restart`): its inputs, each with the 1 of the constant term."""
        self.restart(e.dt, refresh_tol)
        self.inputs = np.hstack([e.inputs, np.ones((len(e.t), 1))])

    def step(self, k: int, th: np.ndarray, var: np.ndarray, xk: np.ndarray, x: np.ndarray | None = None):
        """`(Φ, D, xk⁺, x⁺)` of the time update from sample k at `th` (`linearised`, centred on
        `xk`): the states one sample on from `xk` and (if given) from `x` (None otherwise)."""
        xi = np.concatenate((xk, self.inputs[k]))
        E, D = self.linearised(th, var, xi)
        ahead = None if x is None else E @ np.concatenate((x, self.inputs[k]))
        return E[:, : len(E)], D, E @ xi, ahead

    def linearised(self, th: np.ndarray, var: np.ndarray, xi: np.ndarray):
        """`(E, D)` for the time update at `th` (coefficient variances `var`): `E = [Φ Γ s]` and
        `D = ∂(E ξ)/∂θ` (n, p) at `xi = [x; δ; 1]` (the linearisation centre). E is exact if a
        coefficient moved more than `refresh_tol` σ since the last exact model θₘ, else
        `E(θₘ) + ∂E·(th − θₘ)`; ∂E is always θₘ's."""
        if self.th_model is None or ((th - self.th_model) ** 2 > self.tol2 * var).any():
            self.th_model = th.copy()
            self.E0, dE = self.exact(th, self.dt)
            n, p, q = dE.shape
            self.dEx = dE.reshape(n * p, q)  # (dEx @ ξ).reshape(n, p) is ∂(Eξ)/∂θ
            self.dEt = np.ascontiguousarray(dE.transpose(0, 2, 1)).reshape(n * q, p)
            E = self.E0
        else:  # E to first order in the move since the last exact model
            E = self.E0 + (self.dEt @ (th - self.th_model)).reshape(len(self.E0), -1)
        return E, (self.dEx @ xi).reshape(len(E), -1)


# ---------------------------------------------------------------- options and result

CONVENTIONAL_FLOOR = 0.01  # the conventional EKF's default `state_noise` (module docstring)
# the options the filter on a nonlinear model config has no use for (module docstring)
NONLINEAR_REFUSED = ("passes", "pass_tol", "refresh_tol")

# The paper's MEKF (§5): its model of the data has measurement noise R alone (§4's likelihood),
# and its square-root algorithm propagates J_{k,k−1} from the model with no process-noise term:
# the model is taken as exact, so the measured states' model-noise covariance is fixed at zero —
# no covariance matching (`noise_window` 0) and no floor (`state_noise` 0). The coefficients'
# random walk (`param_noise`, 1e-6 of the prior σ) and the unmeasured states' process noise stay
# at their defaults, numerical allowances the paper's constant coefficients do not change.
PAPER_OPTIONS = {"noise_window": 0, "state_noise": 0.0}


def _sigmas(v) -> bool:
    """None, or a mapping of names to σ > 0."""
    return v is None or (
        isinstance(v, Mapping) and all(isinstance(k, str) and is_number(x) and x > 0 for k, x in v.items())
    )


def _at_least(low: float, doc: str, default: float):
    return option(default, lambda v: is_number(v) and v >= low, f"a finite number ≥ {low:g}", doc)


_SIGMAS = "a mapping of name to σ > 0, e.g. {'u': 0.01}"


@dataclass(frozen=True)
class FilterOptions(Options):
    """Options of `mekf` and `ekf` (the module docstring says what each choice means)."""

    max_samples: int | None = option(
        None,
        lambda v: v is None or (is_count(v) and v >= 1),
        "an integer ≥ 1 (samples)",
        "stop after this many samples; None: all",
    )
    noise_std: Mapping[str, float] | None = option(
        None,
        _sigmas,
        _SIGMAS,
        "measurement σ per measured state, over the config's; None: the config's or the data's",
    )
    prior_std: Mapping[str, float] | None = option(None, _sigmas, _SIGMAS, "a-priori σ per free coefficient")
    prior_frac: float = _at_least(0.0, "a-priori σ as a fraction of |value|", 0.5)
    prior_floor: float | None = option(
        None,
        lambda v: v is None or (is_number(v) and v > 0),
        "a number > 0",
        "least a-priori σ; None: 1e-3 × the largest |coefficient|",
    )
    param_noise: float = _at_least(
        0.0, "coefficients' random-walk σ per sample, fraction of the prior σ", 1e-6
    )
    state_noise: float | None = option(
        None,
        lambda v: v is None or (is_number(v) and v >= 0),
        "a finite number ≥ 0",
        "model-error σ floor per sample, fraction of R's σ; None: 0 for the "
        "square-root filters, 0.01 for the conventional one",
    )
    noise_window: int = count_option(
        50, 0, "samples averaged by the covariance matching; 0: model error at the floor"
    )
    noise_margin: float = _at_least(0.0, "standard errors of that average an excess must pass to count", 2.0)
    unmeasured_std: float = _at_least(0.0, "initial σ of an unmeasured state (SI)", 1.0)
    unmeasured_noise: float = _at_least(0.0, "process σ per sample of an unmeasured state (SI)", 1e-3)
    refresh_tol: float = _at_least(0.0, "recompute the exact model when a coefficient moved this many σ", 0.2)
    passes: int = count_option(
        1, 1, "passes over the data: 1 the on-line filter, more its fixed-interval iterations"
    )
    pass_tol: float = _at_least(
        0.0, "the iterations stop when no coefficient moved more than this many σ", 0.1
    )
    sqrt: str = option(
        "qr",
        lambda v: v in ("qr", "svd"),
        "'qr' or 'svd'",
        "time-update root: qr (one QR with the update) or svd (U Σ, the paper's)",
    )
    nis_window: int = count_option(200, 1, "samples over which the innovations are tested for divergence")
    nis_limit: float = _at_least(
        0.0, "mean normalised innovation squared per channel that means divergence", 25.0
    )
    explode: float = _at_least(
        0.0, "prior σ a coefficient may move before the filter counts as diverged", 100.0
    )


@dataclass(frozen=True)
class FilterEstimate(Estimate):
    """An `Estimate` with the filter's time histories (kept out of the JSON) and its diagnostics.

    Attributes (beyond `Estimate`'s):
        history: (N, p) θ̂ after each sample's update; `history_std` its σ; `history_t` the
            times, each experiment following the previous one.
        covariance: the final augmented covariance (states, then the free coefficients);
            `covariance_root` its lower-triangular root J, P = J Jᵀ (square-root filters only).
        filter: which filter ran ("square-root MEKF", "conventional EKF").
        nis_mean: mean normalised innovation squared per sample (about the number of measured
            channels for a consistent filter).
        sqrt: the time-update root ("qr" or "svd"; square-root filters only).
        max_covariance_asymmetry: the largest relative asymmetry the conventional covariance
            reached (conventional filter only).
        diverged_sample, diverged_t: where a diverged filter stopped.
        model_error_std: the model error found by covariance matching, per measured state: the
            RMS over the samples of its σ per sample.
        passes, last_step_std: with fixed-interval iterations, the passes made and the last
            pass's largest move in σ (None for the on-line filter).
    """

    history_t: np.ndarray | None = field(default=None, repr=False)
    history_std: np.ndarray | None = field(default=None, repr=False)
    covariance: np.ndarray | None = field(default=None, repr=False)
    covariance_root: np.ndarray | None = field(default=None, repr=False)
    filter: str = ""
    nis_mean: float = math.nan
    sqrt: str | None = None
    max_covariance_asymmetry: float | None = None
    diverged_sample: int | None = None
    diverged_t: float | None = None
    model_error_std: dict[str, float] | None = None
    passes: int | None = None
    last_step_std: float | None = None

    def json_fields(self) -> dict:
        doc = super().json_fields()
        doc |= {"filter": self.filter, "samples": int(self.iterations), "nis_mean": float(self.nis_mean)}
        if self.sqrt is not None:
            doc["sqrt"] = self.sqrt
        if self.max_covariance_asymmetry is not None:
            doc["max_covariance_asymmetry"] = float(self.max_covariance_asymmetry)
        if self.model_error_std is not None:
            doc["model_error_std"] = self.model_error_std
        if self.passes is not None:
            doc["passes"] = self.passes
            if self.last_step_std is not None:
                doc["last_step_std"] = float(self.last_step_std)
        if self.status is Status.DIVERGED:
            doc["diverged"] |= {"sample": self.diverged_sample, "t": self.diverged_t}
        return doc

    def history_csv(self) -> str:
        """CSV `t,<name>,<name>_std,...` of the estimate and ±σ histories."""
        cols = [self.history_t[:, None]]
        for j in range(len(self.free)):
            cols += [self.history[:, j : j + 1], self.history_std[:, j : j + 1]]
        buf = io.StringIO()
        buf.write(",".join(["t"] + [f"{n}{s}" for n in self.free for s in ("", "_std")]) + "\n")
        np.savetxt(buf, np.hstack(cols), delimiter=",", fmt="%.10g")
        return buf.getvalue()


# ---------------------------------------------------------------- the filters


class _Diverged(Exception):
    """The filter left its domain; the message says how."""


@dataclass
class _State:
    """What one pass over the experiments carries from sample to sample and experiment to
    experiment: the free coefficients (updated in place), the root of their covariance, the
    histories and the totals."""

    th: np.ndarray
    Jth: np.ndarray
    qth: np.ndarray
    th0: np.ndarray
    sig0: np.ndarray
    names: tuple[str, ...]
    hist: np.ndarray
    hist_var: np.ndarray
    hist_t: np.ndarray
    ldiag: np.ndarray  # |diagonal| of the innovation root per sample (for ln det Σν)
    total: int
    count: int = 0
    cost: float = 0.0  # ½ Σ νᵀ Σν⁻¹ ν; the ln det part is added from ldiag at the end
    nis_sum: float = 0.0
    t_offset: float = 0.0
    t_now: float = 0.0
    matched: frozenset = frozenset()  # measured states whose model error is matched to the data
    q2_sum: np.ndarray = field(default_factory=lambda: np.zeros(NX))  # Σ q² of the matched states
    q_samples: np.ndarray = field(default_factory=lambda: np.zeros(NX))  # and their sample counts
    asym: float = 0.0
    J: np.ndarray | None = None  # the last augmented root (square root) or covariance
    ref: np.ndarray | None = None  # the coefficients the pass is linearised about (None: θ̂)


def _experiment(e: Experiment, sigma_r: Mapping[str, float], U: float, o: FilterOptions):
    """Measured rows, measurements (u as the perturbation; 0 where missing), the samples present
    (N, k), R's σ, the initial state and its σ, and the states' process σ for one experiment. A
    state missing at the first sample starts at trim with the unmeasured states' σ."""
    rows = np.array([IX[name] for name in e.measured])
    y = e.y.copy()
    if "u" in e.measured:
        y[:, e.measured.index("u")] -= U
    present = ~np.isnan(y)
    y[~present] = 0.0
    sr = np.array([sigma_r[name] for name in e.measured])
    x = np.zeros(NX)
    x[rows] = y[0]
    sx0 = np.full(NX, o.unmeasured_std)
    sx0[rows] = np.where(present[0], sr, o.unmeasured_std)
    qx = np.full(NX, o.unmeasured_noise)
    qx[rows] = o.state_noise * sr
    return rows, y, present, sr, x, sx0, qx


class _ModelError:
    """The states' process σ per sample `q` (Q = diag q²) over one experiment, the measured
    states' part matched to the innovations (module docstring, "Model error").

    `q` starts at `_experiment`'s (the floors); `update` after each measurement update sets it
    for the next time update. `rows` are the matched states, `cols` their places among the
    measured channels."""

    def __init__(
        self,
        q: np.ndarray,
        measured: Sequence[str],
        rows: np.ndarray,
        y: np.ndarray,
        present: np.ndarray,
        st: _State,
        o: FilterOptions,
    ):
        self.q = q.copy()
        self.cols = np.array([j for j, name in enumerate(measured) if name in st.matched], dtype=int)
        self.rows = rows[self.cols]
        self.floor2 = self.q[self.rows] ** 2
        var = [y[present[:, j], j].var() if present[:, j].any() else 0.0 for j in self.cols]
        self.cap2 = np.maximum(np.array(var), self.floor2)
        self.alpha = 1.0 / o.noise_window if o.noise_window and len(self.rows) else 0.0
        # the standard error of an exponential average of ν² − S̃ where the model is right (q = 0:
        # Var ν² = 2 S̃²) is S̃ √(2α/(2−α))
        self.margin = o.noise_margin * math.sqrt(2.0 * self.alpha / (2.0 - self.alpha))
        self.q2_bar = np.zeros(len(self.rows))
        self.s0_bar = None
        self.st = st

    def update(self, nu: np.ndarray, s: np.ndarray, present: np.ndarray) -> bool:
        """Innovations `nu` (m,) and the diagonal `s` (m,) of their predicted covariance S, from
        the measurement update after a time update with `q`, of the channels `present` (m,)
        (a missing sample's channel keeps its averages); False if nothing is matched."""
        if not self.alpha:
            return False
        seen = present[self.cols]
        a = self.alpha * seen
        s0 = s[self.cols] - self.q[self.rows] ** 2  # S̃ = S − q²: what the model and R predict
        q2_hat = nu[self.cols] ** 2 - s0  # q̂² = ν² − S̃: the innovation's excess over it
        self.q2_bar += a * (q2_hat - self.q2_bar)  # exponential averages over 1/α samples
        self.s0_bar = s0 * seen if self.s0_bar is None else self.s0_bar + a * (s0 - self.s0_bar)
        # q² = q̄² − margin · se₀ (only what the average resolves), within [floor², Var y]
        q2 = np.clip(self.q2_bar - self.margin * self.s0_bar, self.floor2, self.cap2)
        self.q[self.rows] = np.sqrt(q2)
        self.st.q2_sum[self.rows] += q2 * seen
        self.st.q_samples[self.rows] += seen
        return True


class _Books:
    """What both filters do after each sample's measurement update: record it in `st`
    (histories, cost, count), check for divergence (module docstring) and call the callback.
    `signed`: the variances can turn negative (a formed P; a root's are sums of squares)."""

    def __init__(self, st: _State, o: FilterOptions, m: int, callback: Callable | None, signed: bool = False):
        self.st, self.o, self.m, self.callback, self.signed = st, o, m, callback, signed
        self.ring, self.ring_sum = np.zeros(o.nis_window), 0.0  # NIS per channel, last window
        self.lim = o.explode * st.sig0

    def sample(self, k: int, x, th, var, nis: float, ldiag, m: int | None = None) -> None:
        """Sample `k` of the experiment: states `x`, coefficients `th`, their variances `var`,
        the innovations' NIS and |diagonal| of their root `ldiag` (for ln det Σν; 1 for a
        channel missing there), `m` the channels present (all of them: None)."""
        st, ring = self.st, self.ring
        m = self.m if m is None else max(m, 1)
        c = st.count
        st.hist[c], st.hist_var[c], st.hist_t[c] = th, var, st.t_now
        st.ldiag[c, : len(ldiag)] = ldiag
        st.cost += 0.5 * nis
        st.nis_sum += nis / m
        if not math.isfinite(nis + x.sum() + th.sum() + var.sum()):
            raise _Diverged("a state, coefficient or covariance is not finite")
        if self.signed and (var < 0).any():
            raise _Diverged("a coefficient variance became negative")
        window = len(ring)
        slot = k % window
        self.ring_sum += nis / m - ring[slot]
        ring[slot] = nis / m
        if slot == window - 1:
            self.ring_sum = float(ring.sum())  # no drift of the running sum
        if k + 1 >= window and self.ring_sum > self.o.nis_limit * window:
            raise _Diverged(
                f"innovations {math.sqrt(self.ring_sum / window):.3g}× their "
                f"predicted σ over {window} samples"
            )
        if (np.abs(th - st.th0) > self.lim).any():
            raise _Diverged(_far(st, self.o))
        st.count = c + 1
        if self.callback is not None:
            self.callback(Progress(c + 1, th.copy(), math.nan, np.sqrt(var)))


def _sqrt_pass(
    e: Experiment,
    st: _State,
    model: DiscreteModel | NonlinearTransition,
    o: FilterOptions,
    sigma_r,
    U: float,
    modified: bool,
    callback: Callable | None,
) -> None:
    """One experiment through the square-root filter(s) (module docstring, "Square root")."""
    n, p = NX, len(st.th)
    N = n + p
    rows, y, present, sr, x, sx0, qx = _experiment(e, sigma_r, U, o)
    m = len(rows)
    svd = o.sqrt == "svd"
    # Pre-arrays [[R½, C J⁻], [0, J⁻]], J⁻ the predicted root: [F J, Q½] (augmented filter) and
    # [Φ Jx, D Jθ, Qx½] (the MEKF's Kalman filter); on the first sample the initial root.
    wa, wk = 2 * N, 2 * n + N
    if svd:  # J⁻ = U Σ from the SVD of that array, then the same QR
        pre_a, pre_k = np.zeros((m + N, m + N)), np.zeros((m + n, m + n))
        ja, jk = np.zeros((N, wa)), np.zeros((n, wk))
    else:
        pre_a, pre_k = np.zeros((m + N, m + wa)), np.zeros((m + n, m + wk))
        ja, jk = pre_a[m:, m:], pre_k[m:, m:]  # views: the time update writes into the arrays
    pre_a[:m, :m] = pre_k[:m, :m] = np.diag(sr)
    ja[:n, :n] = jk[:, :n] = np.diag(sx0)
    ja[n:, n:N] = st.Jth
    sel = m + rows  # rows of C J⁻ within the arrays
    Ftop = np.zeros((n, N))  # [Φ D], the top rows of F = [[Φ, D], [0, I]]
    xk = x.copy()  # the Kalman filter's estimate: the MEKF's linearisation centre
    th, ref = st.th, st.ref
    books = _Books(st, o, m, callback)
    error = _ModelError(qx, e.measured, rows, y, present, st, o)
    qa, qk = N + error.rows, n + N + error.rows  # the matched σ's columns in the roots' Q½ blocks
    model.begin(e, o.refresh_tol)
    t0, last, Ja = e.t[0] - st.t_offset, len(e.t) - 1, None
    try:
        for k in range(len(e.t)):
            if st.count >= st.total:
                break
            st.t_now = e.t[k] - t0
            # --- measurement update, augmented filter: one QR of the pre-array
            if svd:
                pre_a[m:, m:] = svd_root(ja)
            pre_a[:m, m:] = pre_a[sel, m:]
            ok = present[k]
            full = ok.all()
            nu = y[k] - x[rows]
            if not full:  # a missing channel: its row decoupled (C J⁻ = 0, ν = 0), no update
                pre_a[:m, m:][~ok] = 0.0
                nu[~ok] = 0.0
            dx, w, L, Ja = sqrt_update(pre_a, m, nu)
            x += dx[:n]
            th += dx[n:]
            if modified:  # --- the Kalman filter
                if svd:
                    pre_k[m:, m:] = svd_root(jk)
                pre_k[:m, m:] = pre_k[sel, m:]
                nuk = y[k] - xk[rows]
                if not full:
                    pre_k[:m, m:][~ok] = 0.0
                    nuk[~ok] = 0.0
                dxk, _, _, Jx = sqrt_update(pre_k, m, nuk)
                xk += dxk
            else:
                xk = x
            if k > 0 and error.update(nu, np.einsum("ij,ij->i", L, L), ok):  # diag S = diag L Lᵀ
                ja[error.rows, qa] = jk[error.rows, qk] = error.q[error.rows]
            var = np.einsum("ij,ij->i", Ja[n:], Ja[n:])
            if full:
                books.sample(k, xk, th, var, float(w @ w), L.diagonal())
            else:
                books.sample(k, xk, th, var, float(w @ w), np.where(ok, L.diagonal(), 1.0), int(ok.sum()))
            if k == last:
                break
            if k == 0:  # process noise from the first time update on
                ja[:, N:] = np.diag(np.concatenate([error.q, st.qth]))
                jk[:, n + N :] = np.diag(error.q)
            # --- time update, linearised at the KF's estimate (and the reference θ_r, if any)
            Phi, D, xk, ahead = model.step(k, th if ref is None else ref, var, xk, x if modified else None)
            Ftop[:, :n], Ftop[:, n:] = Phi, D
            if modified:
                x = ahead
                jk[:, :n] = Phi @ Jx
                if ref is None:  # θ̂'s uncertainty enters the KF as noise; θ_r is given
                    jk[:, n : N + n] = D @ Ja[n:]
            else:
                x = xk
            if ref is not None:  # x⁻ = Φ_r x + Γ_r δ + s_r + D (θ̂ − θ_r): linear in [x; θ]
                x = x + D @ (th - ref)
            ja[:n, :N] = Ftop @ Ja
            ja[n:, :N] = Ja[n:]
    finally:
        st.J = Ja
    if Ja is not None:
        st.Jth = tria(Ja[n:])
    st.t_offset = st.t_now + e.dt


def _conventional_pass(
    e: Experiment,
    st: _State,
    model: DiscreteModel | NonlinearTransition,
    o: FilterOptions,
    sigma_r,
    U: float,
    callback: Callable | None,
) -> None:
    """One experiment through the textbook EKF: `P = F P Fᵀ + Q`, `P = P − K C P`."""
    n, p = NX, len(st.th)
    rows, y, present, sr, x, sx0, qx = _experiment(e, sigma_r, U, o)
    m, R = len(rows), np.diag(sr**2)
    Q = np.diag(np.concatenate([qx, st.qth]) ** 2)
    P = np.zeros((n + p, n + p))
    P[:n, :n] = np.diag(sx0**2)
    P[n:, n:] = st.Jth @ st.Jth.T
    F = np.eye(n + p)
    th, ref = st.th, st.ref
    books = _Books(st, o, m, callback, signed=True)
    error = _ModelError(qx, e.measured, rows, y, present, st, o)
    model.begin(e, o.refresh_tol)
    t0, last = e.t[0] - st.t_offset, len(e.t) - 1
    try:
        for k in range(len(e.t)):
            if st.count >= st.total:
                break
            st.t_now = e.t[k] - t0
            ok = present[k]  # the channels present: the update takes only those
            nu = np.where(ok, y[k] - x[rows], 0.0)
            Sv = P[np.ix_(rows, rows)] + R
            s = np.diag(Sv).copy()
            if not ok.all():
                Sv, at = Sv[np.ix_(ok, ok)], rows[ok]
            else:
                at = rows
            Linv = np.linalg.inv(np.linalg.cholesky(Sv))  # LinAlgError: not definite
            K = np.linalg.solve(Sv, P[at]).T
            P = P - K @ P[at]
            st.asym = max(st.asym, np.abs(P - P.T).max() / np.abs(P).max())
            try:
                np.linalg.cholesky(P)
            except np.linalg.LinAlgError:
                raise _Diverged("the covariance lost positive definiteness") from None
            dx = K @ nu[ok]
            x, th[:] = x + dx[:n], th + dx[n:]
            if k > 0 and error.update(nu, s, ok):
                Q[error.rows, error.rows] = error.q[error.rows] ** 2
            w = Linv @ nu[ok]
            var = np.diag(P)[n:].copy()
            ldiag = np.ones(m)
            ldiag[ok] = 1.0 / np.diag(Linv)
            books.sample(k, x, th, var, float(w @ w), ldiag, int(ok.sum()))
            if k == last:
                break
            Phi, D, x, _ = model.step(k, th if ref is None else ref, var, x)  # at its own estimate
            F[:n, :n], F[:n, n:] = Phi, D
            if ref is not None:  # x⁻ = Φ_r x + Γ_r δ + s_r + D (θ̂ − θ_r)
                x = x + D @ (th - ref)
            P = F @ P @ F.T + Q
    finally:
        st.J = P
    st.Jth = np.linalg.cholesky(P[n:, n:])
    st.t_offset = st.t_now + e.dt


def _pass(
    experiments: Sequence[Experiment],
    st: _State,
    transition: Callable[[], DiscreteModel | NonlinearTransition],
    o: FilterOptions,
    sigma_r,
    U: float,
    modified: bool,
    square_root: bool,
    callback: Callable | None,
) -> dict | None:
    """One pass of the filter over the experiments in sequence, into `st`; its divergence
    (reason, sample, time) or None."""
    diverged = None
    try:
        # an overflow or 0/0 makes a state, coefficient or variance non-finite, which `_Books`
        # reports as the divergence it is (numpy's warnings would only repeat it)
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            model = transition()
            for e in experiments:
                if st.count >= st.total:
                    break
                if square_root:
                    _sqrt_pass(e, st, model, o, sigma_r, U, modified, callback)
                else:
                    _conventional_pass(e, st, model, o, sigma_r, U, callback)
    except _Diverged as exc:
        diverged = str(exc)
    except np.linalg.LinAlgError as exc:
        diverged = f"linear algebra failed ({exc}): a singular Mt or a covariance not positive definite"
    if diverged is None:
        return None
    with np.errstate(over="ignore", invalid="ignore"):
        hint = _hint(st, diverged, experiments)
    return {"reason": diverged + hint, "sample": st.count, "t": float(st.t_now)}


def _covariance(st: _State, square_root: bool):
    """The final augmented covariance P and its lower-triangular root (square root only; None
    where the pass ended before a sample)."""
    if st.J is None:
        return None, None
    if not square_root:
        return st.J, None
    Ja = st.J * np.where(np.diag(st.J) < 0, -1.0, 1.0)  # a Cholesky-like root
    return Ja @ Ja.T, Ja


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


def _nonlinear(experiments: Sequence[Experiment], config: ModelConfig, method: str, options: FilterOptions):
    """`_linear` for a nonlinear model config: its θ (`model.names` order), its transition the
    model's RK4 flight (`NonlinearTransition`), nothing unphysical; `OptionError` for an option
    it has no use for (`NONLINEAR_REFUSED`) given a value other than its default."""
    defaults = {f.name: f.default for f in fields(FilterOptions)}
    for name in NONLINEAR_REFUSED:
        value = getattr(options, name)
        if value != defaults[name]:
            raise OptionError(
                method, name, value, "its default: the filter on a nonlinear model config has no such option"
            )
    check_mounting(config, f"{method} on a nonlinear model config")
    model, theta, idx = setup(experiments, config, f"{method} on a nonlinear model config")[2:]
    m = len(model.names)
    biased = [n for n, i in zip(config.free, idx) if i >= m]
    if biased:
        raise InputError(
            f"{config.source or 'config'}: [identify] free names {biased[0]}; {method} on a nonlinear model "
            "config takes the fixed output biases off the data and estimates none: expected ml-gn or ml-nm"
        )
    theta, idx = theta[:m], np.array(idx)
    # y − b: the fixed output biases taken off the measured states
    experiments = [replace(e, y=e.y - config.output_biases(e.measured)) for e in experiments]
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
        st = _State(
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
        diverged = _pass(experiments, st, transition, options, sigma_r, U, modified, square_root, callback)
        processed += st.count
        simulated(st.count * (1 + p))  # the state and its p parameter columns propagated
        P, Ja = _covariance(st, square_root)
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


def _far(st: _State, o: FilterOptions) -> str:
    moved = np.abs(st.th - st.th0) / st.sig0
    j = int(np.argmax(moved))
    return f"coefficient {st.names[j]} moved {moved[j]:.3g} prior σ (limit {o.explode:g})"


def _hint(st: _State, reason: str, experiments: Sequence[Experiment]) -> str:
    """Why the filter diverged, where the data tell: innovations far beyond their predicted σ;
    measured states without noise (`noise_free_channels`) whose σ was not given, and what to
    give."""
    nis = st.nis_sum / max(st.count, 1)
    if nis <= 10.0:
        return ""
    out = (
        ""
        if "innovations" in reason
        else (f"; the innovations were {math.sqrt(nis):.3g}× their predicted σ on average")
    )
    measured = {name for e in experiments for name in e.measured}
    quiet = [name for name in STATES if name in measured and name not in st.matched]
    if quiet:
        table = ", ".join(f"{name} = {NOISE_STD[name]:g}" for name in quiet)
        flag = ",".join(f"{name}={NOISE_STD[name]:g}" for name in quiet)
        out += (
            f"; the data look noise-free or low-pass filtered ({', '.join(quiet)}): the filter "
            "weighs the model against the measurement noise, which cannot be read off such data, "
            "so any model error diverges it; give the sensors' noise σ (SI, before any low-pass filter) as "
            f"[identify] noise_std in the model config, e.g. noise_std = {{{table}}}, or on the "
            f"command line --noise-std {flag}"
        )
    return out


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
