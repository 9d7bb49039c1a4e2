"""The uncertainty of the output-error estimate: the Fisher information (initial states
eliminated), Cramér-Rao bounds with one rule for a singular matrix, and Morelli & Klein's bound
for coloured residuals.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from statistics import NormalDist
from typing import Mapping, NamedTuple, Sequence

import numpy as np

from testbed.data import Experiment, ModelConfig
from testbed.errors import InputError, Unflyable
from testbed.identification.likelihood import (
    bounded,
    divergence,
    eliminate,
    gauss_newton_terms,
    initial_states,
    negative_log_likelihood,
    noise_variance,
    reduced,
)
from testbed.identification.problem import Problem, free_values, problem
from testbed.identification.recursions import channel_weights, discrete_models, sensitivity_parts, states
from testbed.identification.scan import PIECE
from testbed.models.linear import IX, NX, STATES, continuous

__all__ = [
    "chi2_sf",
    "COARSEST",
    "INTEGRATED_TIMES",
    "MIN_LAGS",
    "NULL",
    "Analysed",
    "Bounds",
    "Information",
    "analysed",
    "assess",
    "coloured_covariance",
    "lagged",
    "coloured_term",
    "crlb",
    "eliminated",
    "fft_length",
    "fisher",
    "fisher_at",
    "held_bounds",
    "information",
    "lag_window",
]


class Bounds(NamedTuple):
    """The Cramér-Rao bounds of a Fisher information matrix (see `crlb`)."""

    covariance: np.ndarray  # (n, n) a generalised inverse of M: M⁻¹ where M is regular
    std: np.ndarray  # (n,) √(M⁻¹)_ii; inf for an unidentifiable parameter
    correlation: np.ndarray  # (n, n) cov_ij / (σ_i σ_j); NaN in an unidentifiable one's row and column


NULL = 1e-12  # eigenvalue of the scaled Fisher matrix, relative to its largest, that counts as 0


def crlb(M: np.ndarray, null: float = NULL) -> Bounds:
    """Cramér-Rao bounds of the Fisher information `M`: covariance, standard deviations and
    correlations, with one rule for a singular or nearly singular M.

    M is scaled to unit diagonal (`Mₛ = D⁻¹ M D⁻¹`, D = √diag M, so the rule does not depend on
    the parameters' units) and Mₛ = V Λ Vᵀ; eigenvalues at or below `null` (default `NULL`) × the
    largest are null directions. `covariance = D⁻¹ V₊ Λ₊⁻¹ V₊ᵀ D⁻¹` over the other eigenvalues, a generalised
    inverse of M. A parameter whose unit vector lies in the range of M has the bound
    `σ_i² = (M⁻)_ii`, the same for every generalised inverse; one with a component above √null
    along the null directions (or no information at all, M_ii = 0) is unidentifiable: no unbiased
    estimator has a finite variance, so σ_i = inf (a truncated pseudo-inverse would report a
    small, wrong bound) and its correlations are NaN.
    """
    M = (M + M.T) / 2
    D = np.sqrt(np.maximum(np.diag(M), 0.0))
    informed = D > 0
    D = np.where(informed, D, 1.0)
    lam, V = np.linalg.eigh(M / np.outer(D, D))
    zero = lam <= null * max(lam.max(initial=0.0), 1e-300)
    cov = (V[:, ~zero] / lam[~zero]) @ V[:, ~zero].T / np.outer(D, D)
    unidentifiable = ~informed | (np.linalg.norm(V[:, zero], axis=1) > np.sqrt(null))
    std = np.where(unidentifiable, np.inf, np.sqrt(np.maximum(np.diag(cov), 0.0)))
    s = np.where(unidentifiable, np.nan, std)
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(s, s)
    corr[np.diag_indices_from(corr)] = np.where(unidentifiable, np.nan, 1.0)
    return Bounds(cov, std, corr)


def chi2_sf(q: float, k: int) -> float:
    """`P(χ²_k > q)`, the survival function of the χ² law with `k` (a positive integer) degrees
    of freedom, in closed form: with x = q/2,
      k even: e^(−x) Σ_{j<k/2} x^j / j!,
      k odd:  erfc(√x) + e^(−x) Σ_{j=1}^{(k−1)/2} x^(j−½) / Γ(j + ½),
    each term taken through its logarithm, so that neither e^(−x) nor x^j leaves the range of
    double precision before their product does."""
    x = q / 2.0
    if x <= 0.0:
        return 1.0
    if k % 2 == 0:
        return min(1.0, sum(math.exp(j * math.log(x) - x - math.lgamma(j + 1)) for j in range(k // 2)))
    return min(
        1.0,
        math.erfc(math.sqrt(x))
        + sum(math.exp((j - 0.5) * math.log(x) - x - math.lgamma(j + 0.5)) for j in range(1, (k + 1) // 2)),
    )


MIN_LAGS = 10  # the lag window's floor (`lag_window`), samples
INTEGRATED_TIMES = 6  # the lag window's length in integrated autocorrelation times (`lag_window`)


def fft_length(n: int) -> int:
    """The least 2^a 3^b 5^c ≥ n: an FFT length numpy's pocketfft transforms fast."""
    best = 1 << max(n - 1, 0).bit_length()
    p5 = 1
    while p5 < best:
        p35 = p5
        while p35 < best:
            m = p35 * (1 << max((n - 1) // p35, 0).bit_length()) if p35 < n else p35
            best = min(best, m)
            p35 *= 3
        p5 *= 5
    return best


def lag_window(rho: np.ndarray, n: int) -> int:
    """K, the lags the residual autocorrelation is kept to in `coloured_covariance`.

    `rho`: (lags 1 … n/4, k) each channel's residual autocorrelation coefficient ρ(τ) =
    r_cc(τ)/r_cc(0), `n` the record's samples. K covers, in every channel, both
    - twice the last lag at which ρ is significant, so that the Bartlett taper still weighs it by
      ½ or more: outside ±z·√((1 + 2 Σ_j<τ ρ(j)²)/n), Bartlett's band for a correlation that has
      ended before τ, z for 99 % over all those lags and channels at once (Bonferroni) — an
      oscillating or late correlation;
    - c = `INTEGRATED_TIMES` integrated autocorrelation times, the first M ≥ c (1 + 2 Σ_τ≤M ρ(τ))
      (Sokal's automatic window) — a slowly decaying correlation, whose tail stays inside the
      band but adds up (AR(1): τ_int = (1+ρ)/(1−ρ));
    at least `MIN_LAGS`, at most n/2. White residuals keep the floor: K/N small, so the window
    adds little sampling noise to the bound.
    """
    if not rho.size:  # a record of under 4 samples: no lag to test
        return min(MIN_LAGS, n // 2)
    # Bartlett's variance of ρ(τ) beyond the correlation: (1 + 2 Σ_j<τ ρ(j)²)/n
    var = (1.0 + 2.0 * (np.cumsum(rho**2, axis=0) - rho**2)) / n
    z = NormalDist().inv_cdf(1.0 - 0.005 / rho.size)
    outside = np.flatnonzero(np.any(rho**2 > z**2 * var, axis=1))
    last = outside[-1] + 1 if len(outside) else 0
    # M ≥ c τ_int(M), τ_int(M) = 1 + 2 Σ_τ≤M ρ(τ): the first such M in the slowest channel (none: n)
    reached = np.arange(1, len(rho) + 1)[:, None] >= INTEGRATED_TIMES * (1.0 + 2.0 * np.cumsum(rho, axis=0))
    sokal = np.max(np.argmax(reached, axis=0)) + 1 if np.all(np.any(reached, axis=0)) else n
    return int(min(max(2 * last, sokal, MIN_LAGS), n // 2))


def coloured_covariance(
    prob: Problem,
    p: np.ndarray,
    xs: Sequence[np.ndarray],
    res: Sequence[np.ndarray],
    R: np.ndarray,
    cov: np.ndarray,
) -> np.ndarray:
    """Morelli & Klein's covariance of the free coefficients for coloured residuals,

        C (Σ_i Σ_j S(i)ᵀR⁻¹ R_vv(i−j) R⁻¹S(j)) Cᵀ,   R_vv(τ) = w(τ) 1/N Σ_m v(m) v(m+τ)ᵀ,

    per experiment, with C = `cov[:n_free]` (cov = M⁻¹, the bound for white residuals), S the
    output sensitivities, v the residuals (`xs`: the states at `p`, `res`: the residuals) and
    w(τ) = 1 − |τ|/(K+1) for |τ| ≤ K, 0 beyond: the Bartlett lag window, K from `lag_window`.

    The window is what makes the bound agree with M⁻¹ for white residuals. Over all lags the
    sample autocorrelation's spectrum is the periodogram |V(f)|²/N, and the fit's normal equations
    `Σ_m S(m)ᵀR⁻¹v(m) = Σ_f S(f)ᴴR⁻¹V(f) = 0` leave it with holes exactly where the sensitivities'
    spectra lie, so the all-lag sum reads low (down to 0.8 of M⁻¹'s σ on 60 s records); the long-lag
    estimates carry only that bias and sampling noise. The Bartlett window smooths the periodogram
    over a band ~1/K wide (a convolution with the Fejér kernel), filling the holes from the
    neighbouring frequencies, and keeps the estimate positive semidefinite. Its lag-0 term alone
    is M; white residuals add lag terms of relative size √(K/N).

    Computed per frequency of an L-point DFT grid, L ≥ N + K (no wrap-around): with
    Φ(f) = Σ_|τ|≤K R_vv(τ) e^{+iωτ} (K lags summed directly) and Z = R^-½ S Cᵀ (the sensitivities
    already projected by C: n_free columns, not n_params) the double sum is
    `1/L Σ_f Z(f)ᴴ Φ(f) Z(f)`.
    """
    models, nf = discrete_models(prob, p[: prob.n_free], 1), prob.n_free
    out = np.zeros((nf, nf))
    # R^-½ S Cᵀ, time first; one buffer for all records (fresh pages are dear)
    Z = np.empty((max(len(r.y) for r in prob.records), max(len(r.measured) for r in prob.records), nf))
    for r, x, e in zip(prob.records, xs, res):
        n, k, C = len(e), len(r.measured), cov[:nf, prob.columns(r)].T
        Zr = Z[:n, :k]
        Zr[...] = 0.0
        for channels, params, pieces in sensitivity_parts(
            prob,
            r,
            models[prob.key(r)],
            x,
            r.measured,
            channel_weights(r, R),
            PIECE,
            r.present,
            values=p[:nf],
        ):
            for samples, S in pieces:
                Zr[np.ix_(np.arange(n)[samples], channels)] = (S @ C[params]).transpose(1, 0, 2)
        out += coloured_term(Zr, e / np.sqrt(R[r.channels]), r.present)
    return out


def coloured_term(Z: np.ndarray, v: np.ndarray, present: np.ndarray | None = None) -> np.ndarray:
    """One record's `1/L Σ_f Z(f)ᴴ Φ(f) Z(f)` of `coloured_covariance`: `Z` (N, k, n_free) its
    sensitivities R^-½ S Cᵀ, `v` (N, k) its residuals R^-½ v (0 where missing), `present` (N, k)
    where the samples are (None: all)."""
    n, k, nf = Z.shape
    # per channel Σ_m v(m) v(m+τ), τ = 0 … n/4 (an FFT grid with no wrap-around at those lags)
    V = np.fft.rfft(v, fft_length(n + n // 4 + 2), axis=0)
    auto = np.fft.irfft(V.real**2 + V.imag**2, axis=0)[: n // 4 + 2]
    K = lag_window(auto[1 : n // 4 + 1] / np.maximum(auto[0], 1e-300), n)
    L = fft_length(n + K + 1)  # lags up to K without wrap-around
    # G(τ) = w(τ) R_vv(τ), 0 < τ ≤ K, from the lagged products Σ_m v(m) v(m+τ)ᵀ of every channel
    # pair (`lagged`); with missing samples (v = 0 there) each lag's sum has fewer pairs: scaled
    # by (n − τ)/pairs, which leaves a complete record's estimate as it is
    P = None if present is None else present.astype(float)
    tau = np.arange(1, K + 1)[:, None, None]
    G = (1.0 - tau / (K + 1)) / n * lagged(v, K, L)[1:]
    if P is not None:
        G *= (n - tau) / np.maximum(lagged(P, K, L)[1:], 1.0)
    # Φ(f) = R_vv(0) + Σ_τ>0 (G(τ) e^{+iωτ} + G(τ)ᵀ e^{−iωτ}) (as R_vv(−τ) = R_vv(τ)ᵀ)
    #      = R_vv(0) + conj(F(f)) + F(f)ᵀ, F(f) = Σ_τ G(τ) e^{−iωτ}: the DFT of G over the lags
    F = np.fft.rfft(np.concatenate([np.zeros((1, k, k)), G]), L, axis=0)
    Phi = F.conj() + F.transpose(0, 2, 1)
    Phi.real += v.T @ v / (n if P is None else np.maximum(P.T @ P, 1.0))
    Zf = np.fft.rfft(Z, L, axis=0)  # (frequencies, k, n_free)
    PhiZ = Phi @ Zf
    Zf[0] *= 0.5  # DC and Nyquist appear once in the full spectrum, the others twice
    if L % 2 == 0:
        Zf[-1] *= 0.5
    # 1/L Σ_f Z(f)ᴴ Φ(f) Z(f), real part: Re(aᴴb) = aᵣᵀbᵣ + aᵢᵀbᵢ, one real product of the
    # arrays viewed as (re, im) pairs
    RI = np.ascontiguousarray(Zf).reshape(-1, nf).view(float).T @ PhiZ.reshape(-1, nf).view(float)
    return (RI[0::2, 0::2] + RI[1::2, 1::2]) * (2.0 / L)


def lagged(x: np.ndarray, K: int, L: int) -> np.ndarray:
    """`Σ_m x(m) x(m+τ)ᵀ` for τ = 0 … K (K + 1, k, k), `x` (n, k), from the cross-spectra on
    an L-point DFT grid (L ≥ n + K: no wrap-around at those lags)."""
    X = np.fft.rfft(x, L, axis=0)
    return np.fft.irfft(X.conj()[:, :, None] * X[:, None, :], L, axis=0)[: K + 1]


@dataclass(frozen=True)
class Information:
    """Cramér-Rao analysis of the free coefficients at `values` (initial states estimated)."""

    free: tuple[str, ...]
    values: np.ndarray  # (n_free,)
    fisher: np.ndarray  # (n_free, n_free), the initial states eliminated (Schur complement)
    crlb_std: np.ndarray  # (n_free,) Cramér-Rao standard errors
    correlation: np.ndarray  # (n_free, n_free)
    crlb_corrected_std: np.ndarray  # (n_free,) Morelli-Klein coloured-residual bound
    noise_std: dict[str, float]  # per measured state: √R
    initial_states: dict[str, dict[str, float]]  # experiment → measured state → x0 (absolute u)
    cost: float  # negative log-likelihood (R at its ML value)
    p: np.ndarray  # (n_params,) the full parameter vector
    segments: int = 0  # the records were analysed cut into this many segments in all (0: whole)

    @property
    def relative_std(self) -> np.ndarray:
        return self.crlb_std / np.maximum(np.abs(self.values), 1e-300)


def held_bounds(info: "Information", held: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """The Cramér-Rao and coloured-residual bounds of `info`'s free values where those `held`
    (bool, n_free; None: none) end on a bound of a box: theirs NaN (a bound is no estimate's σ),
    the others' Cramér-Rao bounds from the information with them held."""
    std, coloured = info.crlb_std, np.asarray(info.crlb_corrected_std, float)
    if held is None or not held.any():
        return std, coloured
    moving = ~held
    std = np.full(len(held), np.nan)
    std[moving] = crlb(info.fisher[np.ix_(moving, moving)]).std
    return std, np.where(moving, coloured, np.nan)


def assess(
    prob: Problem,
    p: np.ndarray,
    M: np.ndarray | None = None,
    R: np.ndarray | None = None,
    simulated: tuple | None = None,
) -> Information:
    """Fisher information, Cramér-Rao bounds and the coloured-residual bound at `p`.

    `M`: `gauss_newton_terms(prob, p, …, R)[1]` with R the residual variance at `p`, and `simulated`:
    the states and residuals per record there `(xs, res)`, if an optimiser already has them (not
    checked: the caller vouches that they belong to `p`). `R`: the noise variance per channel to
    use instead of the residual variance at `p`.
    """
    if simulated is None:
        xs = states(prob, p)
        res = [r.residual(prob.outputs(r, x, p[: prob.n_free])) for r, x in zip(prob.records, xs)]
    else:
        xs, res = simulated
    R = noise_variance(prob, res) if R is None else R
    if M is None:
        M = gauss_newton_terms(prob, p, xs, res, R)[1]
    nf = prob.n_free
    # the bounds of θ from its information with the initial states eliminated, which stays well
    # conditioned where M itself does not (an unstable model's); the coloured bound needs the θ
    # rows of M⁻¹ too: [F⁻¹, −F⁻¹ M_θx M_xx⁻¹] (the inverse of a 2 × 2 block matrix)
    F = eliminated(M, nf)
    cov, std, corr = crlb(F)
    rows = np.hstack([cov, -cov @ eliminate(M, nf, M[nf:, :nf]).T]) if len(M) > nf else cov
    corrected = coloured_covariance(prob, p, xs, res, R, rows)
    x0 = {}
    for r in prob.records:
        xr = prob.x0(r, p) + np.eye(NX)[IX["u"]] * prob.speed
        x0[r.name] = {STATES[i]: float(xr[i]) for i in r.measured}
    return Information(
        prob.free,
        p[:nf].copy(),
        F,
        std,
        corr,
        np.where(np.isinf(std), np.inf, np.sqrt(np.maximum(np.diag(corrected), 0.0))),
        dict(zip(prob.channels, map(float, np.sqrt(R)))),
        x0,
        negative_log_likelihood(prob, res),
        p.copy(),
    )


class Analysed(NamedTuple):
    """What `information` and `fisher` analyse: the problem, the parameter vector at the values
    analysed with the best-fitting initial states, and R from the config's noise σ (None: the
    residuals'). `segments`: where the model diverges over the whole record, the records are cut
    into this many segments in all, each with its own initial state (`likelihood.bounded`);
    0 where they are analysed whole."""

    prob: Problem
    p: np.ndarray
    R: np.ndarray | None
    segments: int
    why: str = ""  # why the whole record is not analysed, where the records are cut


def analysed(
    experiments: Sequence[Experiment],
    config: ModelConfig,
    values: Mapping[str, float] | np.ndarray | None = None,
    noise_std: Mapping[str, float] | None = None,
) -> Analysed:
    """The problem of `config.free` on the experiments at `values` (default: the config's
    coefficients) for `information` and `fisher`. Where the model diverges over the whole record
    (an unstable model's response grows along it), the records are cut into the fewest segments
    on which it stays bounded, each with its own initial state (`likelihood.bounded`): the
    information of the multiple-shooting problem, which the fit starts from. `Unflyable` where it
    diverges even on the shortest segments."""
    prob = problem(experiments, config)
    theta = free_values(prob, values)
    stage, p, _, why = bounded(prob, theta)
    if why is not None:
        coarse = _coarse_step(experiments, prob, theta)
        if coarse is not None:  # the data's clock, not the model, is at fault (t in ms, say)
            raise InputError(coarse)
        cut = (
            f" even on {len(stage.records)} segments of the records"
            if len(stage.records) > len(prob.records)
            else ""
        )
        raise Unflyable(
            f"{prob.source}: the model diverges at these coefficients{cut} ({why}); expected "
            "coefficients giving a response bounded over a few seconds"
        )
    R = None if noise_std is None else np.array([noise_std[c] ** 2 for c in prob.channels])
    if stage is prob:
        return Analysed(prob, p, R, 0)
    with np.errstate(over="ignore", invalid="ignore"):
        whole = divergence(prob, initial_states(prob, theta))
    if whole is None:  # bounded, but growing more than EXPLODE-fold along a record
        ev = np.linalg.eigvals(continuous(prob.structure, prob.coefficients(theta))[0])
        whole = f"A's largest eigenvalue real part is {np.max(ev.real):.3g} 1/s"
    return Analysed(stage, p, R, len(stage.records), whole)


def information(
    experiments: Sequence[Experiment],
    config: ModelConfig,
    values: Mapping[str, float] | np.ndarray | None = None,
    noise_std: Mapping[str, float] | None = None,
) -> Information:
    """Cramér-Rao analysis of `config.free` at `values` (default: the config's coefficients).

    The initial states are fitted (linear least squares); R is `noise_std`² where given (per
    channel), else the residual variance there, which also holds the model's error at `values`.
    Where the model diverges over the whole record, on segments (`analysed`; its `segments`).
    """
    a = analysed(experiments, config, values, noise_std)
    return replace(assess(a.prob, a.p, R=a.R), segments=a.segments)


def fisher(
    experiments: Sequence[Experiment],
    config: ModelConfig,
    values: Mapping[str, float] | np.ndarray | None = None,
    noise_std: Mapping[str, float] | None = None,
) -> np.ndarray:
    """`information(...).fisher` alone: the Fisher information of `config.free` (n_free, n_free),
    the initial states eliminated, without the bounds (no coloured-residual analysis)."""
    return fisher_at(analysed(experiments, config, values, noise_std))


def fisher_at(a: Analysed) -> np.ndarray:
    """`fisher` of what `analysed` gives."""
    prob, p = a.prob, a.p
    xs = states(prob, p)
    res = [r.residual(prob.outputs(r, x, p[: prob.n_free])) for r, x in zip(prob.records, xs)]
    M = gauss_newton_terms(prob, p, xs, res, noise_variance(prob, res) if a.R is None else a.R)[1]
    return eliminated(M, prob.n_free)


def eliminated(M: np.ndarray, nf: int) -> np.ndarray:
    """The information of the first `nf` parameters of `M` with the others (the initial states)
    eliminated (`likelihood.reduced`). A parameter left with at most `NULL` of its own
    information M_ii (a copy of an initial state, such as a heading bias beside the initial
    heading: the Schur complement leaves rounding, 4e-15 of M_ii, which scaled to unit diagonal
    looks like an independent parameter with a finite bound) has none: its row and column are 0,
    so `crlb` bounds it infinite."""
    F = reduced(M, np.zeros(len(M)), nf)[0]
    lost = np.diag(F) <= NULL * np.diag(M)[:nf]
    F[lost, :] = 0.0
    F[:, lost] = 0.0
    return F


COARSEST = math.log(2.0**53)  # ρΔ beyond which a mode decays below double-precision rounding in one step


def _coarse_step(experiments: Sequence[Experiment], prob: Problem, theta: np.ndarray) -> str | None:
    """Where a model cannot be simulated on the records even in segments, the likelier fault
    where a record's step Δ (its median) is so coarse that the model's fastest mode (rate ρ)
    decays below rounding within it (ρΔ > ln 2⁵³: t in ms, say): that record and step named,
    else None. A step so coarse is no fault by itself (the zero-order hold is exact at any step,
    and a model that stays bounded is analysed and fitted at it)."""
    rate = float(np.max(np.abs(np.linalg.eigvals(continuous(prob.structure, prob.coefficients(theta))[0]))))
    for e in experiments:
        dt = float(np.median(np.diff(e.t)))
        if rate * dt > COARSEST:
            return (
                f"{e.source or e.name}: t steps {dt:g} s; the model of {prob.source} has a mode at "
                f"{rate:.3g} 1/s, which such a step cannot show, and its response at this step is "
                f"unbounded on the records: expected a step below {COARSEST / rate:.3g} s (t in seconds)"
            )
    return None
