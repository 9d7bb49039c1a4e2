"""The filter-error method's likelihood (`ml-fem`): for p = (θ_free, each record's initial
prediction in its measured states, f² of the rows with process noise), each record's steady-state
Kalman filter (`identification.innovations`) and innovations ν, their covariances 𝒮 per group of
records and phase of the sampling cycle, the negative log-likelihood

    L = Σ_groups Σ_j [½ Σ_{k in j} ν_kᵀ 𝒮_j⁻¹ ν_k + (N_j/2) ln det 2π𝒮_j],

its Gauss-Newton terms (the innovations' sensitivities by central differences in θ and f², exact
in the initial state), and R compatible with 𝒮 (Jategaonkar's correction of F where it would not
be positive). `estimators.fem` iterates on it.
"""

from __future__ import annotations

import numpy as np

from testbed.errors import InputError
from testbed.identification import innovations, likelihood, recursions
from testbed.identification.problem import Problem
from testbed.models.linear import BODY, IX, NX

__all__ = ["Likelihood", "R_FLOOR", "R_ROOM", "START_SHARE", "noise_rows", "sampling_cycles", "start_noise"]

START_SHARE = 0.05  # f²Δ to start from, as a share of the channel's first differences' variance
R_FLOOR = 1e-3  # R is kept above this fraction of the innovations' variance per channel
R_ROOM = 0.05  # where it is not, F is scaled down to leave R about this fraction
_STEP = 1e-5  # central-difference step, relative to the parameter (or its start's size)


def noise_rows(prob: Problem, spec: str) -> np.ndarray:
    """Indexes into BODY of the rows with process noise; `InputError` for a row whose state no
    record measures (its noise could not be told from the others')."""
    measured = {int(i) for r in prob.records for i in r.measured}
    if spec == "none":
        return np.zeros(0, dtype=int)
    if spec == "measured":
        return np.array([j for j, s in enumerate(BODY) if IX[s] in measured], dtype=int)
    names = [n.strip() for n in spec.split(",")]
    blind = [n for n in names if IX[n] not in measured]
    if blind:
        raise InputError(
            f"ml-fem: option process_noise={spec!r}: {', '.join(blind)} not measured; expected "
            "body states the data measure"
        )
    return np.array([BODY.index(n) for n in names], dtype=int)


def _key(prob: Problem, r, phases: np.ndarray) -> tuple:
    """The group of a record: its model (`Problem.key`: its sampling interval, and its record
    group where values are per record), measured states and sampling cycle `phases`, which set
    its filter."""
    return (prob.key(r), tuple(r.measured), phases.tobytes(), phases.shape)


def _by_phase(v: np.ndarray, on: np.ndarray):
    """(j, phase j's samples of `v` (·, k, …) over the channels it has) for each phase of `on` (P, k)."""
    P = len(on)
    for j, m in enumerate(on):
        yield j, v[j::P][:, m]


class Likelihood:
    """The innovations, their covariances and sensitivities of one problem, p = (θ, x0s, f²)."""

    def __init__(self, prob: Problem, rows: np.ndarray, theta0: np.ndarray, cycles, tau: float = 0.0):
        """`cycles`: each record's sampling cycle (`sampling_cycles`)."""
        self.prob, self.rows, self.nf, self.tau = prob, rows, prob.n_free, tau
        self.nx = prob.n_params - prob.n_free
        self.noisy = len(rows) > 0
        self.keys = [_key(prob, r, on) for r, on in zip(prob.records, cycles)]
        self.states, self.phases = {}, {}
        for r, key, on in zip(prob.records, self.keys, cycles):
            d = recursions.discrete(prob, theta0, r.dt, order=1)
            coupled = d.E[:, :NX] != 0
            if d.dE is not None:
                coupled = coupled | (d.dE[:, :, :NX] != 0).any(axis=0)
            self.states[key] = innovations.observed(coupled, r.measured)
            self.phases[key] = on
        self.groups = sorted(self.states)

    def q(self, p: np.ndarray) -> np.ndarray:
        """The spectral densities f² of the six body rows from p (0 on the rows without noise)."""
        q = np.zeros(len(BODY))
        q[self.rows] = p[self.nf + self.nx :]
        return q

    def outputs(self, p: np.ndarray) -> list[np.ndarray]:
        """Each record's measured states with the output terms at p taken off (0 where missing)."""
        prob, values = self.prob, p[: self.nf]
        if not prob.biased:
            return [r.y for r in prob.records]
        return [r.residual(prob.output_terms(r, values)) for r in prob.records]

    def run(self, p: np.ndarray, S: dict):
        """(filters, innovations per record) at p with the innovations' covariances `S` (per
        group and phase), or None where the filter cannot be built or its innovations are not
        finite."""
        prob, values = self.prob, p[: self.nf]
        ys = self.outputs(p)
        try:
            with np.errstate(over="ignore", invalid="ignore"):
                flt = innovations.filters(prob, values, self.q(p), S, self.states, self.phases, self.tau)
                nus = [
                    innovations.innovations(r, flt[key], prob.x0(r, p), y, prob.inputs(r, values))
                    for r, key, y in zip(prob.records, self.keys, ys)
                ]
        except np.linalg.LinAlgError:
            return None
        if not all(np.all(np.isfinite(v)) for v in nus) or likelihood.exploded(
            prob, [y - v for y, v in zip(ys, nus)]
        ):
            return None
        return flt, nus

    def covariances(self, nus) -> dict:
        """𝒮 per group and phase in closed form, 1/N Σ ννᵀ over the phase's samples and
        channels; with no process noise the pooled diagonal residual variance of output error
        (`likelihood.noise_variance`)."""
        if not self.noisy:
            R = likelihood.noise_variance(self.prob, nus)
            return {g: [np.diag(R[self.channels(g)][m]) for m in self.phases[g]] for g in self.groups}
        sums = {g: [0.0] * len(self.phases[g]) for g in self.groups}
        counts = {g: [0] * len(self.phases[g]) for g in self.groups}
        for key, v in zip(self.keys, nus):
            for j, vj in _by_phase(v, self.phases[key]):
                sums[key][j] = sums[key][j] + vj.T @ vj
                counts[key][j] += len(vj)
        return {g: [a / n for a, n in zip(sums[g], counts[g])] for g in self.groups}

    def channels(self, key) -> np.ndarray:
        """The channels (indexes into `prob.channels`) of a group's records."""
        return next(r.channels for r, k in zip(self.prob.records, self.keys) if k == key)

    def weighted(self, nus, S) -> float:
        """½ Σ νᵀ 𝒮⁻¹ ν (𝒮 held: the relaxation's cost)."""
        return 0.5 * sum(
            float(np.sum(vj * np.linalg.solve(S[key][j], vj.T).T))
            for key, v in zip(self.keys, nus)
            for j, vj in _by_phase(v, self.phases[key])
        )

    def negative_log_likelihood(self, nus) -> float:
        """L with 𝒮 in closed form: Σ over groups and phases (N_j/2)(k_j + ln det 2π𝒮_j) (output
        error's with none)."""
        if not self.noisy:
            return likelihood.negative_log_likelihood(self.prob, nus)
        S = self.covariances(nus)
        n = {g: np.zeros(len(self.phases[g])) for g in self.groups}
        for r, key in zip(self.prob.records, self.keys):
            P = len(self.phases[key])
            n[key] += [len(r.y[j::P]) for j in range(P)]
        return float(
            sum(
                0.5 * n[g][j] * (len(Sj) + np.linalg.slogdet(2 * np.pi * Sj)[1])
                for g in self.groups
                for j, Sj in enumerate(S[g])
            )
        )

    def terms(self, p, flt, nus, S, scale):
        """g = Σ Jᵀ𝒮⁻¹ν and M = Σ Jᵀ𝒮⁻¹J at p, J = ∂ν/∂p (central differences in θ and f²,
        exact in x0). `scale`: each parameter's typical size (the step's reference)."""
        prob, nf, n = self.prob, self.nf, len(p)
        cols = list(range(nf)) + list(range(nf + self.nx, n))
        plus, minus, steps = {}, {}, {}
        for i in cols:
            h = _STEP * max(abs(p[i]), scale[i])
            up, down = p.copy(), p.copy()
            up[i] += h
            down[i] -= h
            h2 = 2 * h
            if i >= nf + self.nx and down[i] < 0:  # f² at its bound: a forward difference
                down, h2 = p, h
            a, b = self.run(up, S), self.run(down, S)
            if a is None or b is None:
                raise np.linalg.LinAlgError("the filter fails next to the estimate")
            plus[i], minus[i], steps[i] = a[1], b[1], h2
        g, M = np.zeros(n), np.zeros((n, n))
        for k, (r, key, v) in enumerate(zip(prob.records, self.keys, nus)):
            own = cols + list(range(r.offset, r.offset + len(r.measured)))
            J = np.zeros((len(v), len(r.measured), len(own)))
            for c, i in enumerate(cols):
                J[:, :, c] = (plus[i][k] - minus[i][k]) / steps[i]
            f = flt[key]
            for c, m in enumerate(r.measured):
                e = np.zeros(len(f.Phi_c[0]))  # the filter's states, the coloured noise's after them
                e[np.searchsorted(f.states, m)] = 1.0
                recursions.simulated(len(v))
                x = innovations.propagate_periodic(f.Phi_c, e, np.zeros((len(v) - 1, len(e))))
                J[:, :, len(cols) + c] = -x[:, f.rows]
            if r.present is not None:
                J[~r.present] = 0.0
            for (j, Jj), (_, vj) in zip(_by_phase(J, self.phases[key]), _by_phase(v, self.phases[key])):
                W = np.linalg.inv(np.linalg.cholesky(S[key][j]))  # whitening: W ν has unit covariance
                Jw = np.einsum("ab,nbq->naq", W, Jj).reshape(-1, len(own))
                vw = (vj @ W.T).ravel()
                g[own] -= Jw.T @ vw  # −∂(½Σνᵀ𝒮⁻¹ν)/∂p
                M[np.ix_(own, own)] += Jw.T @ Jw
        return g, M

    def compatible(self, S, flt, p):
        """R = diag(𝒮 − C P Cᵀ) pooled per channel over the groups and phases that have it,
        floored at `R_FLOOR` 𝒮, and p with f² scaled down where the floor binds (Jategaonkar's
        correction of F: every row by the square of the least ratio of (1 − R_ROOM) 𝒮 to C P Cᵀ,
        P growing about as √f²), with whether it was."""
        prob = self.prob
        nc = len(prob.channels)
        room, cpc, n = np.zeros(nc), np.zeros(nc), np.zeros(nc)
        for r, key in zip(prob.records, self.keys):
            on, CPC = self.phases[key], flt[key].CPC
            for j, m in enumerate(on):
                count = len(r.y[j :: len(on)])
                room[r.channels[m]] += count * np.diag(S[key][j])
                cpc[r.channels[m]] += count * np.diag(CPC[j])[m]
                n[r.channels[m]] += count
        room, cpc = room / n, cpc / n
        R = np.maximum(room - cpc, R_FLOOR * room)
        binding = room - cpc < R_FLOOR * room
        p = p.copy()
        if binding.any():
            p[self.nf + self.nx :] *= np.min((1 - R_ROOM) * room[binding] / cpc[binding]) ** 2
        return R, p, bool(binding.any())


def start_noise(lik: Likelihood) -> tuple[dict, np.ndarray]:
    """𝒮 and f² to start from, from each channel's first differences (between the samples it
    has), whose variance is about 2R + f²Δ (+ the motion's, small at the sampling rates of the
    data): 𝒮 half of it, f²Δ `START_SHARE` of it on the rows with process noise (a small gain:
    the Riccati equation's first-order form holds for gains small per step)."""
    prob = lik.prob
    ss, n, q = np.zeros(len(prob.channels)), np.zeros(len(prob.channels)), np.zeros(len(lik.rows))
    for r in prob.records:
        for c, channel in enumerate(r.channels):
            y = r.y[:, c] if r.present is None else r.y[r.present[:, c], c]
            ss[channel] += np.sum(np.diff(y) ** 2)
            n[channel] += len(y) - 1
    d2 = np.maximum(ss / np.maximum(n, 1), 1e-30)
    dt = min(r.dt for r in prob.records)
    for k, j in enumerate(lik.rows):
        q[k] = START_SHARE * d2[prob.channels.index(BODY[j])] / dt
    return {g: [np.diag(d2[lik.channels(g)][m] / 2) for m in lik.phases[g]] for g in lik.groups}, q


def sampling_cycles(prob: Problem) -> list[np.ndarray]:
    """Each record's sampling cycle (`innovations.cycle`); `InputError` for a record whose missing
    samples recur at no fixed period."""
    out = []
    for r in prob.records:
        out.append(innovations.cycle(r.present, len(r.measured)))
        if out[-1] is None:
            raise InputError(
                f"experiment {r.name!r}: missing samples at no fixed period (dropouts); ml-fem runs the "
                f"periodic steady-state filter: expected each channel's samples to recur every at most "
                f"{innovations.MAX_CYCLE} samples (a sensor at its own rate) over more cycles than the "
                "record has channels, or an output-error method (ml-gn, ml-lm, ml-nr, ml-nm)"
            )
    return out
