"""One pass of the filters over the experiments (`mekf` module doc): what a pass carries from
sample to sample (`FilterState`), one experiment's arrays, the measured states' model error
matched to the innovations (`ModelError`), the histories (`Books`), and the square-root and
conventional passes themselves.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Mapping, Sequence

import numpy as np

from testbed.data import Experiment
from testbed.estimators.base import Progress
from testbed.estimators.filter_model import DiscreteModel
from testbed.estimators.filter_options import FilterOptions
from testbed.estimators.square_root import sqrt_update, svd_root, tria
from testbed.identification.nonlinear_transition import NonlinearTransition
from testbed.models.linear import IX, NX, STATES
from testbed.simulation.measurements import NOISE_STD

__all__ = [
    "Books",
    "Diverged",
    "FilterState",
    "ModelError",
    "conventional_pass",
    "divergence_hint",
    "experiment_arrays",
    "filter_pass",
    "final_covariance",
    "moved_furthest",
    "sqrt_pass",
]


class Diverged(Exception):
    """The filter left its domain; the message says how."""


@dataclass
class FilterState:
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


def experiment_arrays(e: Experiment, sigma_r: Mapping[str, float], U: float, o: FilterOptions):
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


class ModelError:
    """The states' process σ per sample `q` (Q = diag q²) over one experiment, the measured
    states' part matched to the innovations (module docstring, "Model error").

    `q` starts at `experiment_arrays`'s (the floors); `update` after each measurement update sets it
    for the next time update. `rows` are the matched states, `cols` their places among the
    measured channels."""

    def __init__(
        self,
        q: np.ndarray,
        measured: Sequence[str],
        rows: np.ndarray,
        y: np.ndarray,
        present: np.ndarray,
        st: FilterState,
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


class Books:
    """What both filters do after each sample's measurement update: record it in `st`
    (histories, cost, count), check for divergence (module docstring) and call the callback.
    `signed`: the variances can turn negative (a formed P; a root's are sums of squares)."""

    def __init__(
        self, st: FilterState, o: FilterOptions, m: int, callback: Callable | None, signed: bool = False
    ):
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
            raise Diverged("a state, coefficient or covariance is not finite")
        if self.signed and (var < 0).any():
            raise Diverged("a coefficient variance became negative")
        window = len(ring)
        slot = k % window
        self.ring_sum += nis / m - ring[slot]
        ring[slot] = nis / m
        if slot == window - 1:
            self.ring_sum = float(ring.sum())  # no drift of the running sum
        if k + 1 >= window and self.ring_sum > self.o.nis_limit * window:
            raise Diverged(
                f"innovations {math.sqrt(self.ring_sum / window):.3g}× their "
                f"predicted σ over {window} samples"
            )
        if (np.abs(th - st.th0) > self.lim).any():
            raise Diverged(moved_furthest(st, self.o))
        st.count = c + 1
        if self.callback is not None:
            self.callback(Progress(c + 1, th.copy(), math.nan, np.sqrt(var)))


def sqrt_pass(
    e: Experiment,
    st: FilterState,
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
    rows, y, present, sr, x, sx0, qx = experiment_arrays(e, sigma_r, U, o)
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
    books = Books(st, o, m, callback)
    error = ModelError(qx, e.measured, rows, y, present, st, o)
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


def conventional_pass(
    e: Experiment,
    st: FilterState,
    model: DiscreteModel | NonlinearTransition,
    o: FilterOptions,
    sigma_r,
    U: float,
    callback: Callable | None,
) -> None:
    """One experiment through the textbook EKF: `P = F P Fᵀ + Q`, `P = P − K C P`."""
    n, p = NX, len(st.th)
    rows, y, present, sr, x, sx0, qx = experiment_arrays(e, sigma_r, U, o)
    m, R = len(rows), np.diag(sr**2)
    Q = np.diag(np.concatenate([qx, st.qth]) ** 2)
    P = np.zeros((n + p, n + p))
    P[:n, :n] = np.diag(sx0**2)
    P[n:, n:] = st.Jth @ st.Jth.T
    F = np.eye(n + p)
    th, ref = st.th, st.ref
    books = Books(st, o, m, callback, signed=True)
    error = ModelError(qx, e.measured, rows, y, present, st, o)
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
                raise Diverged("the covariance lost positive definiteness") from None
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


def filter_pass(
    experiments: Sequence[Experiment],
    st: FilterState,
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
        # an overflow or 0/0 makes a state, coefficient or variance non-finite, which `Books`
        # reports as the divergence it is (numpy's warnings would only repeat it)
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            model = transition()
            for e in experiments:
                if st.count >= st.total:
                    break
                if square_root:
                    sqrt_pass(e, st, model, o, sigma_r, U, modified, callback)
                else:
                    conventional_pass(e, st, model, o, sigma_r, U, callback)
    except Diverged as exc:
        diverged = str(exc)
    except np.linalg.LinAlgError as exc:
        diverged = f"linear algebra failed ({exc}): a singular Mt or a covariance not positive definite"
    if diverged is None:
        return None
    with np.errstate(over="ignore", invalid="ignore"):
        hint = divergence_hint(st, diverged, experiments)
    return {"reason": diverged + hint, "sample": st.count, "t": float(st.t_now)}


def final_covariance(st: FilterState, square_root: bool):
    """The final augmented covariance P and its lower-triangular root (square root only; None
    where the pass ended before a sample)."""
    if st.J is None:
        return None, None
    if not square_root:
        return st.J, None
    Ja = st.J * np.where(np.diag(st.J) < 0, -1.0, 1.0)  # a Cholesky-like root
    return Ja @ Ja.T, Ja


def moved_furthest(st: FilterState, o: FilterOptions) -> str:
    moved = np.abs(st.th - st.th0) / st.sig0
    j = int(np.argmax(moved))
    return f"coefficient {st.names[j]} moved {moved[j]:.3g} prior σ (limit {o.explode:g})"


def divergence_hint(st: FilterState, reason: str, experiments: Sequence[Experiment]) -> str:
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
