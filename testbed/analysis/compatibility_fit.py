"""The fit of a check's sensor parameters to its records (`compatibility` module doc): the
Gauss-Newton fit (`CheckFit`), what the data cannot separate or do not make significant held
at 0 with its reason, and the reconstruction of the fit.
"""

from __future__ import annotations

import math
from typing import Mapping, Sequence

import numpy as np
from scipy.optimize import least_squares

from testbed.analysis.compatibility_checks import (
    HELD_FIRST,
    MAX_CORRELATION,
    MIN_SIGNAL,
    ATTITUDE_OFFSETS,
    REGRESSORS,
    SIGNIFICANCE,
    SINGULAR,
    Check,
    Parameter,
    Reconstruction,
    limit_of,
)
from testbed.analysis.compatibility_records import CheckRecord
from testbed.errors import InputError
from testbed.fit_percent import fit_percent

__all__ = ["CheckFit", "fitted_reconstruction", "reconstruction"]


class CheckFit:
    """The filter-error problem of one check on records: the free sensor parameters (shared),
    then each record's initial states; the other sensor parameters held at 0."""

    def __init__(self, records: Sequence[CheckRecord], check: Check):
        self.records, self.check = records, check
        self.ni = len(check.initial)

    def local(self, x: np.ndarray, free: Sequence[str], r: int) -> np.ndarray:
        """Record r's parameter row (initial + sensor) from the free vector `x`."""
        sensor = dict(zip(free, x[: len(free)]))
        start = len(free) + r * self.ni
        return np.concatenate([x[start : start + self.ni], [sensor.get(n, 0.0) for n in self.check.sensor]])

    def _parts(self, x, free, jac: bool):
        """Per record (e, de, g, dg) as `CheckRecord.evaluate`, the derivatives over the free vector."""
        cols = [self.check.sensor.index(n) + self.ni for n in free]
        for r, rec in enumerate(self.records):
            parts = rec.evaluate(self.local(x, free, r), jac)
            if jac:
                at = slice(len(free) + r * self.ni, len(free) + (r + 1) * self.ni)
                for i in (1, 3):
                    d = parts[i]
                    if d is not None:
                        J = np.zeros(d.shape[:2] + (len(x),))
                        J[:, :, : len(free)], J[:, :, at] = d[:, :, cols], d[:, :, : self.ni]
                        parts = parts[:i] + (J,) + parts[i + 1 :]
            yield parts

    def residuals(self, x, free, jac: bool):
        """The residuals whose sum of squares is the negative log-likelihood (up to a constant):
        the whitened innovations, and where their variance S depends on the parameters
        √(1 + ln(S / R)), stacked over records; and their Jacobian."""
        res, rows = [], []
        for e, de, g, dg in self._parts(x, free, jac):
            res.append(e.ravel())
            rows += [de.reshape(-1, len(x))] if jac else []
            if g is not None:
                root = np.sqrt(1 + g)
                res.append(root.ravel())
                rows += [(dg / (2 * root[:, :, None])).reshape(-1, len(x))] if jac else []
        return np.concatenate(res), (np.concatenate(rows) if jac else None)

    def fisher(self, x, free) -> np.ndarray:
        """The Fisher information of the innovations ν ~ N(0, S): Σ ∂νᵀ S⁻¹ ∂ν + ½ (∂ ln S)ᵀ ∂ ln S,
        with S⁻¹ᐟ² ∂ν = ∂e + e ∂g / 2 (e = ν / √S, g = ln S / R)."""
        M = np.zeros((len(x), len(x)))
        for e, de, g, dg in self._parts(x, free, jac=True):
            if g is not None:
                de = de + e[:, :, None] * dg / 2
                M += 0.5 * np.einsum("nci,ncj->ij", dg, dg)
            M += np.einsum("nci,ncj->ij", de, de)
        return M

    def start(self, free) -> np.ndarray:
        return np.concatenate([np.zeros(len(free))] + [rec.start() for rec in self.records])

    def bounds(self, free):
        limit = [limit_of(n) or np.inf for n in free]
        hi = np.array(limit + [np.inf] * self.ni * len(self.records))
        return -hi, hi

    def solve(self, x, free):
        """Gauss-Newton (trust region) from `x`; (x, evaluations)."""
        cache = {}

        def both(z):
            key = z.tobytes()
            if key not in cache:
                cache.clear()
                cache[key] = self.residuals(z, free, jac=True)
            return cache[key]

        lo, hi = self.bounds(free)
        sol = least_squares(
            lambda z: both(z)[0],
            np.clip(x, 0.999 * lo, 0.999 * hi),
            jac=lambda z: both(z)[1],
            bounds=(lo, hi),
            x_scale="jac",
            method="trf",
        )
        return sol.x, int(sol.nfev)

    def covariance(self, x, free) -> np.ndarray:
        """The inverse Fisher information (pseudo-inverse): the Cramér-Rao bounds."""
        return np.linalg.pinv(self.fisher(x, free), rcond=1e-15, hermitian=True)


def _singular(M: np.ndarray, names: Sequence[str]) -> list[str]:
    """The parameters (of the first len(names) rows) to hold so that the Fisher information M is
    regular, greedily: the one that weighs most in the least determined direction of the
    information scaled to unit diagonal, while that direction is singular."""
    d = np.sqrt(np.diag(M))
    held = [n for i, n in enumerate(names) if d[i] == 0]
    keep = [i for i in range(len(M)) if i >= len(names) or names[i] not in held]
    while True:
        Ms = M[np.ix_(keep, keep)] / np.outer(d[keep], d[keep])
        lam, V = np.linalg.eigh(Ms)
        if lam[0] > SINGULAR * lam[-1]:
            return held
        sensor = [j for j, i in enumerate(keep) if i < len(names)]
        if not sensor:
            return held
        j = max(sensor, key=lambda j: abs(V[j, 0]))
        held.append(names[keep[j]])
        del keep[j]


def _inseparable(M: np.ndarray, names: Sequence[str], held: Mapping[str, str]) -> dict[str, str]:
    """The sensor parameters (of the first len(names) rows of the Fisher information M, those of
    `held` aside) correlated with an attitude offset beyond `MAX_CORRELATION`, with the reason,
    held one at a time, the most correlated first, the correlations computed again without it:
    the data tell them from the offset by little more than their noise (a log's w bias makes
    the sink rate −u sin θ of a pitch offset wherever u is near constant; its misalignment about
    y turns its u into the same); the offset, the commoner error, is kept."""
    out: dict[str, str] = {}
    while True:
        keep = [i for i in range(len(M)) if i >= len(names) or (names[i] not in held and names[i] not in out)]
        d = np.sqrt(np.diag(M)[keep])
        P = np.linalg.pinv(M[np.ix_(keep, keep)] / np.outer(d, d), hermitian=True)
        s = np.sqrt(np.abs(np.diag(P)))
        index = {names[i]: j for j, i in enumerate(keep) if i < len(names)}
        pairs = [
            (abs(P[j, index[o]]) / (s[j] * s[index[o]]), n, o)
            for o in ATTITUDE_OFFSETS
            if o in index
            for n, j in index.items()
            if n not in ATTITUDE_OFFSETS
        ]
        rho, n, o = max(pairs, default=(0.0, "", ""))
        if rho <= MAX_CORRELATION:
            return out
        out[n] = (
            f"not separable from {o}: correlated {rho:.4f} with it in these data (the offset, the "
            "commoner error, is kept)"
        )


def _conditional(x: np.ndarray, P: np.ndarray, i) -> np.ndarray:
    """The estimate `x` (covariance P) with parameter(s) i held at 0: the others moved as the
    cost's quadratic model says (the Gaussian conditioned on x[i] = 0)."""
    i = np.atleast_1d(i)
    if not len(i):
        return x
    return x - P[:, i] @ np.linalg.solve(P[np.ix_(i, i)], x[i])


def _rank(name: str) -> int:
    """Where `name` comes in the order parameters are held (`HELD_FIRST`, the offsets last)."""
    if name in ATTITUDE_OFFSETS:
        return len(HELD_FIRST)
    return next(i for i, prefix in enumerate(HELD_FIRST) if name.startswith(prefix))


def _insignificant(x, P, free, stds, reasons) -> list[str]:
    """The parameters of `free` held at 0 one at a time (`HELD_FIRST` order, then the least
    significant) while one is within SIGNIFICANCE σ of 0, the others updated for each held;
    their σ and reasons recorded in `stds` and `reasons`."""
    held = []
    while True:
        z = {
            i: abs(x[i]) / math.sqrt(P[i, i]) for i in range(len(free)) if free[i] not in held and P[i, i] > 0
        }
        z = {i: v for i, v in z.items() if v < SIGNIFICANCE}  # P[i, i] ≤ 0: determined by those held
        if not z:
            return held
        i = min(z, key=lambda i: (_rank(free[i]), z[i]))
        stds[free[i]] = math.sqrt(P[i, i])
        reasons[free[i]] = (
            f"not significant: {x[i]:.3g} ± {stds[free[i]]:.2g} is within {SIGNIFICANCE:g} σ of 0"
        )
        held.append(free[i])
        x = _conditional(x, P, i)
        P = P - np.outer(P[:, i], P[i, :]) / P[i, i]


def _noise_regressors(records: Sequence[CheckRecord], names: Sequence[str]) -> dict[str, str]:
    """The parameters of `names` whose regressor is mostly noise in every record (`REGRESSORS`),
    with the reason."""
    out = {}
    for n in names:
        alternatives = REGRESSORS.get(n, ())
        best = max(
            (min(rec.signal[c] for c in channels) for rec in records for channels in alternatives),
            default=math.inf,
        )
        if best < MIN_SIGNAL:
            what = " or ".join("·".join(channels) for channels in alternatives)
            out[n] = (
                f"not identifiable: its regressor ({what}) is mostly measurement noise here "
                f"(signal {best:.2g} × the noise, below {MIN_SIGNAL:g})"
            )
    return out


def reconstruction(check: Check, records: Sequence[CheckRecord]) -> Reconstruction:
    """Fit `check` on `records`: the screen, the fit, the bounds, the reconstruction's fit."""
    fit = CheckFit(records, check)
    names = list(check.sensor)
    reasons = _noise_regressors(records, names)
    names_left = [n for n in names if n not in reasons]
    M = fit.fisher(fit.start(names_left), names_left)
    reasons |= {
        n: "not identifiable: the Fisher information of these data is singular along it"
        for n in _singular(M, names_left)
    }
    reasons |= _inseparable(M, names_left, reasons)
    stds = {n: math.inf for n in reasons}
    free = [n for n in names if n not in reasons]
    x, iterations = fit.solve(fit.start(free), free)
    P = fit.covariance(x, free)
    while True:  # screened, fitted again, until the fit leaves none within SIGNIFICANCE σ of 0
        held = _insignificant(x, P, free, stds, reasons)
        if not held:
            break
        keep = [i for i, n in enumerate(free) if n not in held] + list(range(len(free), len(x)))
        free = [n for n in free if n not in held]
        x, more = fit.solve(_conditional(x, P, [i for i in range(len(x)) if i not in keep])[keep], free)
        iterations += more
        P = fit.covariance(x, free)
    std = np.sqrt(np.diag(P))
    parameters = {}
    for n in names:
        if n in free:
            parameters[n] = Parameter(value=float(x[free.index(n)]), std=float(std[free.index(n)]))
        else:
            parameters[n] = Parameter(value=0.0, std=stds[n], estimated=False, reason=reasons[n])
    initial, y, yhat = {}, [], []
    for r, rec in enumerate(records):
        at = len(free) + r * fit.ni
        initial[rec.name] = {
            n: Parameter(value=float(x[at + j]), std=float(std[at + j])) for j, n in enumerate(check.initial)
        }
        y.append(rec.y)
        yhat.append(rec.outputs(fit.local(x, free, r)[None, :].astype(complex))[0].real)
    y, yhat = np.concatenate(y), np.concatenate(yhat)
    innovations = np.concatenate([e for e, *_ in fit._parts(x, free, jac=False)])
    quality = {}
    for j, c in enumerate(check.outputs):
        error = np.linalg.norm(y[:, j] - yhat[:, j])
        quality[c] = {
            "noise_std": float(math.sqrt(records[0].R[j])),
            "residual_std": float(error / math.sqrt(len(y))),
            "fit_percent": None if math.isnan(fit := fit_percent(y[:, j], yhat[:, j])) else fit,
            "innovation_rms": float(np.sqrt(np.mean(innovations[:, j] ** 2))),
        }
    return Reconstruction(
        check=check.name,
        records=tuple(rec.name for rec in records),
        parameters=parameters,
        initial=initial,
        fit=quality,
        iterations=iterations,
    )


def fitted_reconstruction(check: Check, records: Sequence[CheckRecord]) -> Reconstruction:
    """`reconstruction`, a fit the data drive to non-finite values an `InputError` naming them."""
    with np.errstate(all="ignore"):
        try:
            done = reconstruction(check, records)
            finite = all(math.isfinite(p.value) for p in done.parameters.values()) and all(
                math.isfinite(p.value) for v in done.initial.values() for p in v.values()
            )
        except (ValueError, np.linalg.LinAlgError) as exc:
            finite, why = False, f" ({exc})"
        else:
            why = ""
    if not finite:
        raise InputError(
            f"{', '.join(r.name for r in records)}: the {check.name} check reached no finite "
            f"estimate{why}; expected channels in SI units (rad, rad/s, m/s, m)"
        )
    return done
