"""On-line identification (the paper's §5 and Fig. 2): the modified extended Kalman filter (MEKF)
with a square-root covariance, and the conventional augmented EKF as its baseline.

The augmented state is the 10 SPEC states (`u` as the perturbation u_abs − U) followed by the free
coefficients θ, which are constant up to a small random walk. The states follow the exact
zero-order-hold model `x[k+1] = Φ(θ) x[k] + Γ(θ) δ[k] + s(θ)` of `testbed.model`; its Jacobian
wrt θ, `D = ∂Φ/∂θ x + ∂Γ/∂θ δ + ∂s/∂θ`, is exact as well: with `M = [[A, B, S], [0, 0, 0]]`,
Van Loan's block exponential `expm([[M, ∂M], [0, M]] Δ)` holds `∂expm(MΔ)` in its upper-right
block, so there is no series truncation and singular A (ψ, z integrators) is fine.

MEKF (Fig. 2). An optimal Kalman filter (KF) for the states, run with the model at the current
θ̂, in parallel with an EKF for the augmented state [x; θ]; both start from the same estimate.
The EKF is the usual one (its own prediction `Φ(θ̂)x̂ + Γ(θ̂)δ + s(θ̂)`, its own innovation and
gain, which update x̂ and θ̂) except for the centre of each Taylor expansion: the Jacobian
`F = [[Φ, D], [0, I]]` is evaluated at the KF's state estimate, which given θ̂ is the optimal one,
instead of at the EKF's own, which the parameter error contaminates. The KF is optimal for the
states given θ̂; while θ̂ is uncertain its process noise includes the prediction error that
uncertainty causes, `D P_θθ Dᵀ` (otherwise it trusts a wrong model over the measurements), so it
becomes the optimal KF at θ̂ as the coefficients converge. (Updating the states with the KF's
gain instead was tried: the augmented covariance then no longer describes the state error, and
at high signal-to-noise the innovations outgrow it.)

Square root (the paper's algorithm, in array form): every covariance is held as a lower-triangular
`J` with `P = J Jᵀ`, so it is symmetric and positive semi-definite by construction and its
condition number is the square root of P's. Time update: `J⁺ = tria([F J, Q½])`; measurement
update: one QR of `[[R½, C J], [0, J]]` gives the innovation root `L` (the paper's `L_k`), the
gain `K = K̄ L⁻¹` (one triangular solve) and the updated root — algebraically the paper's
`J_{k,k}` formula without forming `C P Cᵀ`.

filterpy 2.0's `SquareRootKalmanFilter` is used nowhere in the filter, because it (1) is linear
only: its `predict` is `x = F x + B u`, while the augmented prediction is the nonlinear
`Φ(θ)x + Γ(θ)δ + s(θ)` with a new F every step; (2) inverts the innovation root with `pinv` (an
SVD per sample) instead of a triangular solve; (3) returns neither the innovation likelihood
nor the NIS needed for the cost and the divergence test (and its `P_post` returns the prior).
The kernels below are the same array algorithm; the tests check them against filterpy's
`SquareRootKalmanFilter` and against its Joseph-form `KalmanFilter`.

The conventional EKF (`ekf`) is the textbook filter on the same augmented model: linearised
about its own estimate, `P = F P Fᵀ + Q`, `P = P − K C P` (no symmetrisation, no Joseph form),
so rounding shows up as asymmetry and lost definiteness; both are checked every sample.

Choices (all options of `mekf`/`ekf`, see `FilterOptions`):
- R: measurement noise σ per measured state from `noise_std`, else from the data: the third
  difference of a smooth signal sampled fast is almost pure noise, `Var(Δ³e) = 20 σ²`; a median
  absolute deviation makes it robust to the kinks at input steps. States that move fast against
  the sample rate (roll and yaw rate at 20 Hz) leak into it: it is then an upper bound (up to
  ~1.5× in the tests), which errs on the safe side (wider σ); give `noise_std` when known.
- Initial covariance: measured states start at their first sample with σ = R's; unmeasured ones
  at trim (0) with σ `unmeasured_std`. Free coefficients start at the config's a-priori values with
  σ = `prior_frac`·|value| (default 50 %), at least `prior_floor` (default 1e-3 × the largest
  |coefficient|), or `prior_std[name]`.
- Q: states `state_noise` × R's σ per sample (model error; unmeasured: `unmeasured_noise`);
  coefficients a random walk of `param_noise` × prior σ per sample (default 1e-6: constant up to
  a numerical allowance).
- Several experiments run in sequence; the coefficients and their covariance carry over, the
  states restart from each experiment's first sample.
- Divergence (→ `Status.DIVERGED`, reason in `extra["diverged"]`): a non-finite state or
  covariance, a singular `Mt`, the conventional covariance no longer positive definite, the mean
  normalised innovation squared per measured channel over `nis_window` samples above `nis_limit`,
  or a coefficient more than `explode` prior σ from its start.
- `refresh_tol`: the discrete model and its Jacobian (one batched exponential, most of the cost
  of a sample) are recomputed only when some coefficient moved more than `refresh_tol` of its
  current σ since the last computation (default 0.1; 0 recomputes every sample). The prediction
  then uses coefficients within σ/10 of the estimate, an error a tenth of the coefficient
  uncertainty the filter already carries; it triples the throughput.
- `cost` is the negative log-likelihood of the innovations, `½ Σ (νᵀ Σν⁻¹ ν + ln det Σν)`
  (without the 2π constant), Σν the augmented filter's innovation covariance.
- Status CONVERGED when every sample was processed and, over the last 10 % of them, no estimate
  strayed more than 3 final σ from its final value (MAX_ITERATIONS otherwise).
"""

from __future__ import annotations

import io
import math
import time
from dataclasses import dataclass, field, fields
from typing import Callable, Mapping, Sequence

import numpy as np

from testbed.data import Experiment, ModelConfig
from testbed.errors import InputError
from testbed.estimators import Estimate, Status, register
from testbed.model import IX, ITHETA, NX, STATES, continuous, derivatives, structure, theta_vector


# ---------------------------------------------------------------- square-root kernels (pure)


def tria(X: np.ndarray) -> np.ndarray:
    """Lower-triangular L with a non-negative diagonal and `L Lᵀ = X Xᵀ`; X is (n, k ≥ n)."""
    L = np.linalg.qr(X.T, mode="r").T
    return L * np.where(np.diag(L) < 0, -1.0, 1.0)


def sqrt_predict(F: np.ndarray, J: np.ndarray, Qh: np.ndarray) -> np.ndarray:
    """Root of `F J Jᵀ Fᵀ + Qh Qhᵀ`."""
    return tria(np.hstack([F @ J, Qh]))


def sqrt_update(J: np.ndarray, C: np.ndarray, Rh: np.ndarray):
    """Array-form measurement update of the root `J` with `y = C x + v`, `Cov v = Rh Rhᵀ`.

    Returns `(K, L⁻¹, J⁺)`: the gain, the inverse innovation root (`L Lᵀ = C P Cᵀ + R`, so the
    whitened innovation is `L⁻¹ν`) and the posterior root (`J⁺J⁺ᵀ = P − K C P`), from one QR of
    `[[Rh, C J], [0, J]]` → `[[L, 0], [K̄, J⁺]]`, `K = K̄ L⁻¹`.
    """
    m, n = C.shape
    pre = np.zeros((m + n, m + n))
    pre[:m, :m], pre[:m, m:], pre[m:, m:] = Rh, C @ J, J
    post = tria(pre)
    # L is at most 10 × 10: its inverse costs less than two triangular solves, and numpy's
    # LAPACK alone keeps one BLAS thread pool (scipy's second pool stalled under load).
    Linv = np.linalg.inv(post[:m, :m])
    return post[m:, :m] @ Linv, Linv, post[m:, m:]


# ---------------------------------------------------------------- the model and its Jacobian


def discrete_jacobian(A, B, S, dA, dB, dS, dt: float):
    """Exact ZOH model and its derivatives: `(E, dE)` with `E = [Φ Γ s]` (10, 14) and
    `dE[i] = ∂[Φ Γ s]/∂θ_i` (p, 10, 14).

    Van Loan: the upper-right block of `expm([[M, ∂M_i], [0, M]] Δ)` is `∂expm(MΔ)`. Computed
    for all i at once by scaling and squaring of the block-triangular pair (E, ∂E) — Taylor at
    ‖MΔ‖₁/2ˢ ≤ 1/4 until a term is below 1e-17 of the sum, then `∂E ← E ∂E + ∂E E`, `E ← E²`
    s times — keeping only the top n rows, as M's last m+1 rows are zero. Equal to scipy's
    `expm` of the block matrix to rounding, at a fraction of its cost. A truncated series
    (first-order term) is no cheaper shortcut here: the roll mode has ‖AΔ‖ ≈ 2.5 at 20 Hz.
    """
    n, p = A.shape[0], len(dA)
    a = np.hstack([A, B, S[:, None]])  # top rows of M
    q = a.shape[1]
    norm = np.abs(a).sum(0).max() * dt
    s = max(0, math.ceil(math.log2(norm / 0.25))) if norm > 0 else 0
    h = dt / 2**s
    X = a * h
    dX = np.concatenate([dA, dB, dS[:, :, None]], axis=2) * h
    dXcols = dX.transpose(1, 0, 2).reshape(n, p * q)  # [dX_1 ... dX_p] side by side

    # G[0] = the Taylor term of E − I, G[1:] = that of ∂E (top rows): g_k = (g_{k−1} M + ...)/k
    G = np.concatenate([X[None], dX])
    total = G.copy()
    for k in range(2, 20):
        G_new = (G[:, :, :n].reshape(-1, n) @ X).reshape(p + 1, n, q)
        G_new[1:] += (G[0, :, :n] @ dXcols).reshape(n, p, q).transpose(1, 0, 2)
        G = G_new / k
        total += G
        if np.abs(G).max() <= 1e-17 * np.abs(total).max():
            break
    E, dE = total[0], total[1:]
    E[:, :n] += np.eye(n)
    for _ in range(s):  # (E, ∂E) ← (E², E ∂E + ∂E E), top rows only
        Ex = E[:, :n]
        dE_new = (Ex @ dE.transpose(1, 0, 2).reshape(n, p * q)).reshape(n, p, q).transpose(1, 0, 2)
        dE_new += (dE[:, :, :n].reshape(p * n, n) @ E).reshape(p, n, q)
        dE_new[:, :, n:] += dE[:, :, n:]
        E_new = Ex @ E
        E_new[:, n:] += E[:, n:]
        E, dE = E_new, dE_new
    return E, dE


def noise_from_data(experiments: Sequence[Experiment]) -> dict[str, float]:
    """Measurement noise σ per measured state, pooled over the experiments: robust third
    differences, `Var(Δ³e) = 20 σ²` (an upper bound where the signal is fast; module docstring)."""
    pooled: dict[str, list[np.ndarray]] = {}
    for e in experiments:
        for j, name in enumerate(e.measured):
            pooled.setdefault(name, []).append(np.diff(e.y[:, j], 3))
    out = {}
    for name in (s for s in STATES if s in pooled):
        d = np.concatenate(pooled[name])
        mad = 1.4826 * np.median(np.abs(d - np.median(d)))
        out[name] = max(mad / math.sqrt(20.0), 1e-9)  # floor: R must stay positive definite
    return out


# ---------------------------------------------------------------- options and result


@dataclass(frozen=True)
class FilterOptions:
    """Tuning of `mekf` and `ekf` (module docstring: what each choice means)."""

    noise_std: Mapping[str, float] | None = None  # measurement σ per measured state; None: data
    prior_std: Mapping[str, float] | None = None  # a-priori σ per free coefficient
    prior_frac: float = 0.5
    prior_floor: float | None = None  # None: 1e-3 × the largest |coefficient| of the config
    param_noise: float = 1e-6  # random-walk σ per sample, fraction of the prior σ
    state_noise: float = 0.1  # model-error σ per sample, fraction of the measurement σ
    unmeasured_std: float = 1.0  # initial σ of an unmeasured state (SI)
    unmeasured_noise: float = 1e-3  # process σ per sample of an unmeasured state (SI)
    refresh_tol: float = 0.1
    nis_window: int = 200
    nis_limit: float = 25.0
    explode: float = 100.0

    @classmethod
    def from_options(cls, opts: Mapping) -> "FilterOptions":
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(opts) - names)
        if unknown:
            raise InputError(f"option {unknown[0]!r} is unknown to the filter; expected one of "
                             f"{', '.join(sorted(names))}")  # fmt: skip
        o = cls(**opts)
        for name in ("prior_frac", "param_noise", "state_noise", "unmeasured_std",
                     "unmeasured_noise", "refresh_tol", "nis_limit", "explode"):  # fmt: skip
            v = getattr(o, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise InputError(f"option {name}={v!r}; expected a finite number ≥ 0")
        if o.prior_floor is not None and not o.prior_floor > 0:
            raise InputError(f"option prior_floor={o.prior_floor!r}; expected a number > 0")
        if not (isinstance(o.nis_window, int) and o.nis_window >= 1):
            raise InputError(f"option nis_window={o.nis_window!r}; expected an integer ≥ 1")
        for name, d in (("noise_std", o.noise_std), ("prior_std", o.prior_std)):
            for k, v in (d or {}).items():
                if not (math.isfinite(v) and v > 0):
                    raise InputError(f"option {name}[{k!r}]={v!r}; expected a number > 0")
        return o


@dataclass(frozen=True)
class FilterEstimate(Estimate):
    """An `Estimate` with the filter's time histories, kept out of the JSON (`to_json`).

    `history` (N, p) is θ̂ after each sample's update, `history_std` its σ, `history_t` the times,
    each experiment following the previous one; `covariance` is the final augmented covariance
    (states then free coefficients) and `covariance_root` its lower-triangular root J (P = J Jᵀ;
    square-root filters only).
    """

    history_t: np.ndarray = field(default=None, repr=False)
    history_std: np.ndarray = field(default=None, repr=False)
    covariance: np.ndarray = field(default=None, repr=False)
    covariance_root: np.ndarray = field(default=None, repr=False)


def history_csv_text(est: FilterEstimate) -> str:
    """CSV `t,<name>,<name>_std,...` of the estimate and ±σ histories."""
    cols = [est.history_t[:, None]]
    for j in range(len(est.free)):
        cols += [est.history[:, j:j + 1], est.history_std[:, j:j + 1]]
    buf = io.StringIO()
    buf.write(",".join(["t"] + [f"{n}{s}" for n in est.free for s in ("", "_std")]) + "\n")
    np.savetxt(buf, np.hstack(cols), delimiter=",", fmt="%.10g")
    return buf.getvalue()


# ---------------------------------------------------------------- the filters


class _Diverged(Exception):
    """The filter left its domain; the message says how."""


def _run(experiments: Sequence[Experiment], config: ModelConfig, *, method: str,
         modified: bool, square_root: bool, options: FilterOptions, max_samples: int | None,
         callback: Callable | None) -> FilterEstimate:  # fmt: skip
    """One pass over the experiments in sequence; see the module docstring. `modified`: centre
    the Jacobian on a parallel KF (square-root only); otherwise on the filter's own estimate."""
    t_start = time.perf_counter()
    s = structure(config.vehicle)
    U = config.vehicle.speed
    theta = theta_vector(config.coefficients)
    idx = np.array([ITHETA[n] for n in config.free])
    p, n = len(idx), NX
    th0 = theta[idx].copy()
    floor = options.prior_floor or 1e-3 * (np.abs(theta).max() or 1.0)
    sig0 = np.maximum(options.prior_frac * np.abs(th0), floor)
    for name, v in (options.prior_std or {}).items():
        if name not in config.free:
            raise InputError(f"option prior_std[{name!r}]: not a free coefficient; free: "
                             f"{', '.join(config.free)}")  # fmt: skip
        sig0[config.free.index(name)] = float(v)
    sigma_r = noise_from_data(experiments)
    for name, v in (options.noise_std or {}).items():
        if name not in sigma_r:
            raise InputError(f"option noise_std[{name!r}]: not a measured state; measured: "
                             f"{', '.join(sigma_r)}")  # fmt: skip
        sigma_r[name] = float(v)

    Jth = np.diag(sig0)  # root of the coefficients' covariance, carried between experiments
    Qth = options.param_noise * sig0
    total = sum(len(e.t) for e in experiments)
    if max_samples is not None:
        total = min(total, max_samples)
    hist = np.full((total, p), np.nan)
    hist_std = np.full((total, p), np.nan)
    hist_t = np.full(total, np.nan)
    cost, nis_sum, count, t_offset, t_now = 0.0, 0.0, 0, 0.0, 0.0
    diverged, asym = None, 0.0
    Ja = P = None

    try:
        for e in experiments:
            if count >= total:
                break
            rows = [IX[m] for m in e.measured]
            m = len(rows)
            C = np.eye(n)[rows]
            Ca = np.hstack([C, np.zeros((m, p))])
            y = e.y.copy()
            if "u" in e.measured:
                y[:, e.measured.index("u")] -= U
            sr = np.array([sigma_r[name] for name in e.measured])
            Rh, R = np.diag(sr), np.diag(sr**2)
            x = np.zeros(n)  # the augmented filter's state estimate
            x[rows] = y[0]
            xk = x.copy()  # the Kalman filter's: the MEKF's linearisation centre
            sx0 = np.full(n, options.unmeasured_std)
            sx0[rows] = sr
            qx = np.full(n, options.unmeasured_noise)
            qx[rows] = options.state_noise * sr
            Qh_x, Qh_a = np.diag(qx), np.diag(np.concatenate([qx, Qth]))
            Jx = np.diag(sx0)
            Ja = np.zeros((n + p, n + p))
            Ja[:n, :n], Ja[n:, n:] = Jx, Jth
            if not square_root:
                P = Ja @ Ja.T
            dt = e.dt
            F = np.eye(n + p)
            th_model = None
            nis_ring = np.zeros(options.nis_window)
            for k in range(len(e.t)):
                if count >= total:
                    break
                t_now = t_offset + e.t[k] - e.t[0]
                # --- measurement update
                nu = y[k] - C @ x
                if square_root:
                    Ka, Linv, Ja = sqrt_update(Ja, Ca, Rh)
                else:
                    Sv = P[np.ix_(rows, rows)] + R
                    Linv = np.linalg.inv(np.linalg.cholesky(Sv))  # LinAlgError: not definite
                    Ka = np.linalg.solve(Sv, P[rows]).T
                    P = P - Ka @ P[rows]
                    asym = max(asym, np.abs(P - P.T).max() / np.abs(P).max())
                    try:
                        np.linalg.cholesky(P)
                    except np.linalg.LinAlgError:
                        raise _Diverged("the covariance lost positive definiteness") from None
                x = x + Ka[:n] @ nu
                theta[idx] += Ka[n:] @ nu
                if modified:
                    Kx, _, Jx = sqrt_update(Jx, C, Rh)
                    xk = xk + Kx @ (y[k] - C @ xk)
                w = Linv @ nu
                nis = float(w @ w)
                cost += 0.5 * nis - float(np.log(np.abs(np.diag(Linv))).sum())
                nis_sum += nis / m
                var_th = (Ja[n:] ** 2).sum(1) if square_root else np.diag(P)[n:]
                hist[count], hist_std[count] = theta[idx], np.sqrt(np.maximum(var_th, 0.0))
                hist_t[count] = t_now
                _check(xk if modified else x, theta[idx], var_th, nis, nis_ring, k, m, th0, sig0,
                       options)  # fmt: skip
                count += 1
                if callback is not None:
                    callback(count - 1, theta[idx].copy(), hist_std[count - 1].copy())
                if k == len(e.t) - 1:
                    break
                # --- time update
                std_now = hist_std[count - 1]
                if th_model is None or np.any(np.abs(theta[idx] - th_model)
                                              > options.refresh_tol * std_now):  # fmt: skip
                    th_model = theta[idx].copy()
                    A, B, S = continuous(s, theta)
                    E, dE = discrete_jacobian(A, B, S, *derivatives(s, theta, A, B, S, idx), dt)
                    Phi = E[:, :n]
                xi = np.concatenate([x, e.inputs[k], [1.0]])
                if modified:
                    xik = np.concatenate([xk, e.inputs[k], [1.0]])
                    D = (dE @ xik).T  # (n, p): ∂(Φx + Γδ + s)/∂θ at the KF's estimate
                    xk = E @ xik
                else:
                    D = (dE @ xi).T  # at the EKF's own estimate
                x = E @ xi
                F[:n, :n], F[:n, n:] = Phi, D
                if square_root:
                    if modified:  # the coefficients' uncertainty enters the KF as noise
                        Jx = sqrt_predict(Phi, Jx, np.hstack([D @ Ja[n:], Qh_x]))
                    Ja = sqrt_predict(F, Ja, Qh_a)
                else:
                    P = F @ P @ F.T + Qh_a**2
            t_offset = hist_t[count - 1] + e.dt
            Jth = tria(Ja[n:]) if square_root else np.linalg.cholesky(P[n:, n:])
    except _Diverged as exc:
        diverged = str(exc)
    except np.linalg.LinAlgError as exc:
        diverged = f"linear algebra failed ({exc}): a singular Mt or a covariance not positive definite"
    if diverged is not None:
        diverged = {"reason": diverged, "sample": count, "t": float(t_now)}

    values = theta[idx].copy()
    cov = (Ja @ Ja.T) if square_root else P
    std = np.sqrt(np.maximum(np.diag(cov)[n:], 0.0)) if cov is not None else sig0
    if diverged:
        status = Status.DIVERGED
    elif count < sum(len(e.t) for e in experiments):
        status = Status.MAX_ITERATIONS
    else:
        tail = hist[int(0.9 * count):]
        settled = np.all(np.abs(tail - values) <= 3.0 * std)
        status = Status.CONVERGED if settled else Status.MAX_ITERATIONS
    extra = {"filter": f"{'square-root' if square_root else 'conventional'} "
                       f"{'MEKF' if modified else 'EKF'}",
             "samples": count, "nis_mean": nis_sum / max(count, 1)}  # fmt: skip
    if not square_root:
        extra["max_covariance_asymmetry"] = float(asym)
    if diverged:
        extra["diverged"] = diverged
    return FilterEstimate(
        method=method, status=status, free=tuple(config.free), values=values, std=std,
        cost=cost, iterations=count, wall_time_s=time.perf_counter() - t_start,
        noise_std=sigma_r, start="config", history=hist[:count], extra=extra,
        history_t=hist_t[:count], history_std=hist_std[:count], covariance=cov,
        covariance_root=Ja if square_root else None,
    )  # fmt: skip


def _check(x, th, var_th, nis, ring, k, m, th0, sig0, o: FilterOptions) -> None:
    """Raise `_Diverged` if the filter left its domain (module docstring)."""
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(th)) and np.all(np.isfinite(var_th))
            and math.isfinite(nis)):  # fmt: skip
        raise _Diverged("a state, coefficient or covariance is not finite")
    if np.any(var_th < 0):
        raise _Diverged("a coefficient variance became negative")
    ring[k % len(ring)] = nis / m
    if k + 1 >= len(ring) and ring.mean() > o.nis_limit:
        raise _Diverged(f"innovations {math.sqrt(ring.mean()):.3g}× their predicted σ over "
                        f"{len(ring)} samples")  # fmt: skip
    far = np.abs(th - th0) > o.explode * sig0
    if np.any(far):
        raise _Diverged(f"coefficient {int(np.argmax(far))} moved > {o.explode:g} prior σ")


def _entry(method: str, modified: bool, square_root: bool):
    def fn(experiments: Sequence[Experiment], config: ModelConfig, *, max_iter: int | None = None,
           start: str = "config", callback: Callable | None = None, **opts) -> FilterEstimate:  # fmt: skip
        if start not in ("config", "auto"):
            raise InputError(f"--start {start!r}: the {method} filter starts from the config's "
                             "a-priori values; expected config")  # fmt: skip
        if max_iter is not None and max_iter < 1:
            raise InputError(f"--max-iter {max_iter}; expected ≥ 1 (samples to process)")
        if not config.free:
            raise InputError(f"{config.source or 'config'}: [identify] free is empty; nothing to estimate")
        return _run(experiments, config, method=method, modified=modified,
                    square_root=square_root, options=FilterOptions.from_options(opts),
                    max_samples=max_iter, callback=callback)  # fmt: skip

    fn.__name__ = method
    fn.__doc__ = (f"`{method}`: fit `config.free` on-line, one pass over `experiments` in sequence "
                  "(`max_iter` caps the samples; options: `FilterOptions`). Returns a "
                  "`FilterEstimate` (final values, filter σ, histories).")  # fmt: skip
    return fn


mekf = register("mekf")(_entry("mekf", modified=True, square_root=True))
ekf = register("ekf")(_entry("ekf", modified=False, square_root=False))
