"""Output-error maximum likelihood for the nonlinear model: chosen coefficients and each record's
initial state fitted to measured states by a damped Gauss-Newton (Levenberg-Marquardt) iteration.

The outputs are the measured states of the simulated trajectory (`nonlinear_sensitivities.flight`)
plus their output biases, `y = x + b + v` (an attitude sensor's mounting offset; `b` acts on its
own channel alone, `∂y/∂b = 1` there and 0 elsewhere, and not on the flight), the velocities as
a log mounted as g reads them (`log_mounting`: away from the CG, turned; 0 at the CG). The
fit's parameters are θ ⊕ b ⊕ g (`parameter_names`: θ's names, then `b_<state>` of each
measured channel, then the mounting), a bias or the mounting free like any coefficient; the noise `v ~ N(0, R)` with R diagonal, one variance per measured channel pooled over the
records. A missing sample (NaN: a sensor slower than the fins are logged, a dropout) is left
out of every sum, its residual NaN and its rows of J zero; the flight goes through it with the
fins of every row, so fins logged faster than the states move the model as they moved the body.
As for the linear model (`likelihood`), the likelihood is minimised by relaxation: R is set to
the residuals' mean square per channel (or held where `noise_std` gives it), then held
while the parameters step on `½ Σ eᵀ R⁻¹ e`. The step solves the Gauss-Newton normal equations
`(H + λ diag H) Δ = g`, `H = Σ Jᵀ R⁻¹ J`, `g = Σ Jᵀ R⁻¹ e`, J the outputs' exact sensitivities;
λ falls after a step that lowers the cost and grows until one does. The fit has converged when
every parameter's step is below `tolerance` × its Cramér-Rao σ. The bounds are those of the
Fisher information H at the last linearisation, with the initial states (when free) among the
parameters.

A record's initial state starts from its first sample in the measured channels and from straight
flight at the vehicle's speed in the others; free, only the measured channels' components move.
A continuation in record length (`continuation`) widens the basin, which output error's shrinks
as the record grows: the records' first halves are fitted first (recursively, down to `FIRST`
samples or more) and the whole records from that fit; it costs two to three times the direct
fit's time. Without it the first halves are fitted first only where the flight from the start
leaves every finite number (a start off the truth can make a nearly unstable vehicle diverge
within seconds of a large manoeuvre), halved again as needed down to `SHORTEST` samples. The
iterations reported count every stage's.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Callable, Mapping, Sequence

import numpy as np

from testbed.data import Experiment, ModelConfig, check_excited
from testbed.errors import InputError
from testbed.identification.bounds import coloured_term, crlb
from testbed.identification.nonlinear_sensitivities import flight
from testbed.identification.recursions import simulated
from testbed.models import log_mounting
from testbed.models.linear import MOUNTING, NU, NX, STATES
from testbed.models.nonlinear import NonlinearModel
from testbed.models.nonlinear_flight import fly

__all__ = [
    "DAMPING",
    "FIRST",
    "SHORTEST",
    "NonlinearFit",
    "Record",
    "coloured_bounds",
    "fit_output_error",
    "information",
    "neg_log_likelihood",
    "outputs",
    "parameter_names",
    "pooled_noise",
    "present_only",
    "records",
    "residuals",
    "setup",
    "start_states",
]

DAMPING = (1e-3, 10.0, 1e10)  # λ: its start, its factor down after a success and up after a failure, its cap
FIRST = 150  # samples: the continuation's first records are no shorter (module doc)
SHORTEST = 25  # samples: records the start's flight overflows are halved down to no shorter


@dataclass(frozen=True)
class Record:
    """One record: sample times (N,), fin angles (N, 3) held per sample, and the measured
    states (N, C) in the fit's channels' order, NaN where a sample is missing (a sensor slower
    than the fins are logged, a dropout)."""

    t: np.ndarray
    fins: np.ndarray
    y: np.ndarray


@dataclass(frozen=True)
class NonlinearFit:
    """The result of `fit_output_error`."""

    theta: np.ndarray  # all of θ ⊕ b ⊕ g in `parameter_names` order, the free ones fitted
    estimates: dict[str, float]  # the free coefficients
    std: dict[str, float]  # their Cramér-Rao σ
    initial_states: np.ndarray  # (records, 10)
    noise_std: dict[str, float]  # √R per channel
    cost: float  # −ln p(Z | θ, R): ½ Σ_c N_c ln 2π R_c + ½ Σ eᵀR⁻¹e
    iterations: int
    status: str  # "converged", "iteration limit" or "stalled" (no step lowers the cost)
    at_bounds: dict[str, float] = field(
        default_factory=dict
    )  # the free parameters it ends on a bound of, at it


def records(
    experiments: Sequence[Experiment], fit: str = "the nonlinear fit"
) -> tuple[tuple[str, ...], list[Record]]:
    """The measured channels (every record's, the same) and the `Record` of each experiment;
    `InputError` naming the record and the `fit` that needs them for records measuring different
    states."""
    channels = experiments[0].measured
    for e in experiments:
        where = e.source or e.name
        if e.measured != channels:
            raise InputError(
                f"{where}: measures {', '.join(e.measured)}, {experiments[0].source or experiments[0].name} "
                f"{', '.join(channels)}; {fit} takes records measuring the same states"
            )
    return channels, [Record(t=e.t, fins=e.inputs, y=e.y) for e in experiments]


def parameter_names(model: NonlinearModel, channels: Sequence[str]) -> tuple[str, ...]:
    """The names of the fit's parameters θ ⊕ b ⊕ g: θ's (`model.names`), the output bias
    `b_<state>` of each measured channel in `channels`, then the velocity log's mounting g
    (`MOUNTING`)."""
    return model.names + tuple(f"b_{c}" for c in channels) + MOUNTING


def outputs(states: np.ndarray, theta: np.ndarray, m: int, ch) -> np.ndarray:
    """The outputs (N, C) of the flown `states` (N, 10) in the state columns `ch` at θ ⊕ b ⊕ g
    (`theta`, θ's length `m`): the states as read (u, v, w by the log mounted as g,
    `log_mounting.read`) plus their biases."""
    return log_mounting.read(theta[m + len(ch) :], states, ch) + theta[m : m + len(ch)]


def setup(
    experiments: Sequence[Experiment], config: ModelConfig, fit: str
) -> tuple[tuple[str, ...], list[Record], NonlinearModel, np.ndarray, list[int]]:
    """`(channels, records, model, θ ⊕ b ⊕ g, free indices)` of a nonlinear model config's `free`
    (indices into `parameter_names`) on the experiments (`records`), b the config's output biases
    of the channels, g its velocity log's mounting; `InputError` naming the `fit` for what it cannot take: nothing free, values
    per record, a free output bias of a state no record measures, or records that do not move
    (`data.check_excited`)."""
    source = config.source or "config"
    if not config.free:
        raise InputError(f"{source}: [identify] free is empty; expected the coefficients {fit} is to take")
    if config.per_record:
        raise InputError(
            f"{source}: [identify] per_record {config.per_record[0]!r}; {fit} takes every value once "
            "for all records"
        )
    channels, recs = records(experiments, fit)
    check_excited(experiments)
    model, theta = config.nonlinear()
    names = parameter_names(model, channels)
    unmeasured = [n for n in config.free if n not in names]
    if unmeasured:
        raise InputError(
            f"{source}: [identify] free names {unmeasured[0]}, the output bias of a state the records do not "
            f"measure (they measure {', '.join(channels)}); expected the biases of measured states"
        )
    blind = [n for n in config.free if n in MOUNTING] if not {"u", "v", "w"} & set(channels) else []
    if blind:
        raise InputError(
            f"{source}: [identify] free names {blind[0]}, the velocity log's mounting, but the records "
            f"measure no velocity (they measure {', '.join(channels)}); expected u, v or w measured"
        )
    theta = np.concatenate([theta, config.output_biases(channels), config.mounting()])
    return channels, recs, model, theta, [names.index(n) for n in config.free]


def _check(model, records, channels, free, noise_std, tolerance, max_iterations):
    if not (isinstance(max_iterations, int) and max_iterations >= 1 and tolerance > 0):
        raise InputError(
            f"tolerance={tolerance!r}, max_iterations={max_iterations!r}; expected a tolerance > 0 "
            "and a whole number of iterations >= 1"
        )
    names = parameter_names(model, [c for c in channels if c in STATES])
    unknown = [n for n in free if n not in names]
    if unknown:
        raise InputError(f"free coefficient {unknown[0]!r} is not in the model; expected one of {names}")
    if len(set(free)) != len(free) or not free:
        raise InputError(f"free={tuple(free)!r}; expected one or more distinct coefficient names")
    bad = [c for c in channels if c not in STATES]
    if bad or len(set(channels)) != len(channels) or not channels:
        raise InputError(f"channels={tuple(channels)!r}; expected distinct states among {STATES}")
    extra = sorted(set(noise_std) - set(channels))
    if extra:
        raise InputError(f"noise_std names {extra[0]!r}; expected a measured channel {tuple(channels)}")
    if any(not (s > 0 and np.isfinite(s)) for s in noise_std.values()):
        raise InputError(f"noise_std={dict(noise_std)!r}; expected finite standard deviations > 0")
    if not records:
        raise InputError("records: none given; expected one or more")
    for i, r in enumerate(records):
        n = len(r.t)
        if r.fins.shape != (n, NU) or r.y.shape != (n, len(channels)) or np.any(np.isinf(r.y)):
            raise InputError(
                f"record {i}: fins {r.fins.shape}, y {r.y.shape}; expected ({n}, {NU}) and "
                f"({n}, {len(channels)}) finite measurements (NaN where missing)"
            )


def _simulate(model, theta, x0, records, ch, substeps):
    """Each record's flown states (N, 10) and residuals `e = y − ŷ` (N, C) (`outputs`), NaN
    where the sample is missing, at θ ⊕ b ⊕ g (`theta`; what it leaves out: 0); (None, None)
    where a flight does not stay finite. Tallied as simulated samples (`recursions.counting`)."""
    m = len(model.names)
    theta = _padded(theta, m, ch)
    flown, res = [], []
    with np.errstate(all="ignore"):
        for r, x in zip(records, x0):
            states = fly(model, theta[:m], r.t, x, r.fins, substeps)
            simulated(len(r.t))
            if not np.all(np.isfinite(states[:, ch])):
                return None, None
            flown.append(states)
            res.append(r.y - outputs(states, theta, m, ch))
    return flown, res


def _padded(theta, m: int, ch) -> np.ndarray:
    """θ ⊕ b ⊕ g from θ, θ ⊕ b or θ ⊕ b ⊕ g (what is left out: 0)."""
    theta = np.asarray(theta)
    full = m + len(ch) + len(MOUNTING)
    return theta if len(theta) == full else np.concatenate([theta, np.zeros(full - len(theta))])


def residuals(
    model: NonlinearModel, theta, x0: np.ndarray, records: Sequence[Record], ch, substeps: int | None = None
):
    """Each record's residuals (N, C) in the state columns `ch` (NaN where the sample is
    missing) at θ ⊕ b ⊕ g (`theta`; what it leaves out: 0), flown from its row of `x0` (records, 10); None
    where a flight does not stay finite. Tallied as `_simulate`'s."""
    return _simulate(model, theta, x0, records, ch, substeps)[1]


def start_states(model: NonlinearModel, records: Sequence[Record], ch) -> np.ndarray:
    """(records, 10): each record's first sample in its measured state columns `ch`, straight
    flight at the vehicle's speed in the others and where the first sample is missing."""
    x0 = np.zeros((len(records), NX))
    x0[:, 0] = model.vehicle.speed
    first = np.array([r.y[0] for r in records])
    x0[:, ch] = np.where(np.isnan(first), x0[:, ch], first)
    return x0


def pooled_noise(res: Sequence[np.ndarray], held: np.ndarray) -> np.ndarray:
    """R per channel: the residuals' mean square over every record's samples present, or `held`
    where it is not NaN (a given noise variance)."""
    R = sum(np.nansum(e**2, axis=0) for e in res) / np.maximum(_counts(res), 1)
    return np.where(np.isnan(held), np.maximum(R, 1e-30), held)


def _counts(res: Sequence[np.ndarray]) -> np.ndarray:
    """N_c: the samples present per channel over the records' residuals (NaN where missing)."""
    return sum(np.sum(~np.isnan(e), axis=0) for e in res)


def present_only(e: np.ndarray, S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Residuals `e` (N, C) and sensitivities `S` (N, C, p) with every missing sample's (NaN in
    `e`) set to 0: sums over them then take the samples present only."""
    missing = np.isnan(e)
    return np.where(missing, 0.0, e), np.where(missing[:, :, None], 0.0, S)


def neg_log_likelihood(res: Sequence[np.ndarray], R: np.ndarray) -> float:
    """−ln p(Z | θ, R) = ½ Σ_c N_c ln 2π R_c + ½ Σ eᵀR⁻¹e over the records' residuals present
    (NaN where missing)."""
    return 0.5 * float(np.sum(_counts(res) * np.log(2 * np.pi * R))) + 0.5 * sum(
        float(np.nansum(e**2 / R)) for e in res
    )


def _sensitivities(model, theta, x0, records, flown, ch, free, substeps):
    """Each record's output sensitivities to (θ ⊕ b ⊕ g)[free] (N, C, p) and to the measured
    channels' initial states (N, C, C), along its flown states; tallied
    (`recursions.counting`) as 1 + the free coefficients of θ columns a sample (the pass
    evaluates the model at every RK4 stage again)."""
    m, free = len(model.names), np.asarray(free, dtype=np.int64).reshape(-1)
    theta, ch = _padded(theta, m, ch), np.asarray(ch)
    own, bias, mounting = free < m, (free >= m) & (free < m + len(ch)), free >= m + len(ch)
    g = theta[m + len(ch) :]
    out = []
    for r, x, states in zip(records, x0, flown):
        f = flight(model, theta[:m], r.t, x, r.fins, free[own], substeps, states)
        simulated(len(r.t) * (1 + int(own.sum())))
        St = np.zeros((len(r.t), len(ch), len(free)))
        St[:, :, own] = log_mounting.read_derivatives(g, f.dx_dtheta, ch)
        # ∂(x + b)/∂b = 1 on the bias's own channel, 0 on the others
        St[:, free[bias] - m, np.flatnonzero(bias)] = 1.0
        if mounting.any():  # the log's reading moves with its mounting, on u, v, w
            dg = log_mounting.derivatives(g, states[:, :3], states[:, 3:6], np.zeros((len(states), 3)))
            velocity = ch < 3
            for j in np.flatnonzero(mounting):
                St[:, velocity, j] = dg[free[j] - m - len(ch)][:, ch[velocity]]
        out.append((St, log_mounting.read_derivatives(g, f.dx_dx0, ch)[:, :, ch]))
    return out


def fit_output_error(
    model: NonlinearModel,
    theta,
    records: Sequence[Record],
    channels: Sequence[str],
    free: Sequence[str],
    *,
    free_initial: bool = True,
    noise_std: Mapping[str, float] | None = None,
    substeps: int | None = None,
    tolerance: float = 0.01,
    max_iterations: int = 50,
    continuation: bool = False,
    callback: Callable[[np.ndarray, float], None] | None = None,
    bounds: tuple[np.ndarray, np.ndarray] | None = None,
) -> NonlinearFit:
    """Fit the `free` parameters of θ ⊕ b ⊕ g (names from `parameter_names`), started from
    `theta` (θ, θ ⊕ b or θ ⊕ b ⊕ g: the channels' biases and the mounting, 0 where left out), and each
    record's initial state (`free_initial`) to the `records`' measured `channels`, each record
    flown by RK4 with `substeps` steps per sample interval (module doc). `callback(values, cost)`
    after every step taken, any stage's: the free coefficients and the negative log-likelihood.
    `bounds`: `(low, high)` per free parameter (±inf: open), the box the fit keeps them in
    (a start outside it is moved onto it; `NonlinearFit.at_bounds` names those it ends on)."""
    channels, free, noise_std = tuple(channels), tuple(free), dict(noise_std or {})
    _check(model, records, channels, free, noise_std, tolerance, max_iterations)
    ch = [STATES.index(c) for c in channels]
    x0 = start_states(model, records, ch)
    held = np.array([noise_std.get(c, np.nan) ** 2 for c in channels])
    box = _box(bounds, len(free))
    settings = (channels, free, free_initial, held, substeps, tolerance, max_iterations, callback, box)
    options = dict(
        free_initial=free_initial,
        noise_std=noise_std,
        substeps=substeps,
        tolerance=tolerance,
        max_iterations=max_iterations,
        callback=callback,
        bounds=box,
    )
    n = min(len(r.t) for r in records)
    theta, stage = np.array(_padded(np.asarray(theta, float), len(model.names), ch), float), None
    if continuation and n >= 2 * FIRST:
        stage = fit_output_error(model, theta, _halves(records), channels, free, continuation=True, **options)
        theta, x0 = stage.theta, stage.initial_states
    fit = _fit(model, theta, x0, records, settings)
    if fit is None and stage is None and n >= 2 * SHORTEST:
        stage = fit_output_error(
            model, theta, _halves(records), channels, free, continuation=False, **options
        )
        fit = _fit(model, stage.theta, stage.initial_states, records, settings)
    if fit is None:
        raise InputError(
            f"the model's flight from the start values does not stay finite over the records ({n} samples "
            "or fewer); expected a start whose flight does"
        )
    return fit if stage is None else replace(fit, iterations=fit.iterations + stage.iterations)


def _box(bounds, p: int) -> tuple[np.ndarray, np.ndarray]:
    """`bounds` as (low, high) arrays of length `p` (None: unbounded); `InputError` unless
    low < high everywhere."""
    if bounds is None:
        return np.full(p, -np.inf), np.full(p, np.inf)
    low, high = (np.asarray(b, float).reshape(-1) for b in bounds)
    if low.shape != (p,) or high.shape != (p,) or not np.all(low < high):
        raise InputError(f"bounds {bounds!r}; expected (low, high), {p} each, low < high")
    return low, high


def _active(q: np.ndarray, g: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """The parameters held on their bound this iteration: on it with the likelihood's descent
    direction `g` (the normal equations' right side) pointing out of the box (the KKT condition
    of the bound: its multiplier has the right sign)."""
    return ((q <= low) & (g <= 0)) | ((q >= high) & (g >= 0))


def _halves(records):
    """The records' first halves."""
    return [
        Record(t=r.t[: len(r.t) // 2], fins=r.fins[: len(r.t) // 2], y=r.y[: len(r.t) // 2]) for r in records
    ]


def _fit(model, theta, x0, records, settings) -> NonlinearFit | None:
    """`fit_output_error` from θ and the initial states x0 (records, 10); None where the flight
    from them does not stay finite."""
    channels, free, free_initial, held, substeps, tolerance, max_iterations, callback, box = settings
    ch = [STATES.index(c) for c in channels]
    names = parameter_names(model, channels)
    idx = np.array([names.index(n) for n in free])
    p = len(idx)
    states = len(records) * len(ch) if free_initial else 0  # the initial states: unbounded
    low, high = np.r_[box[0], np.full(states, -np.inf)], np.r_[box[1], np.full(states, np.inf)]

    def bounds_of(H, moving):
        """The Cramér-Rao σ of the parameters off their bounds (those held: infinite)."""
        std = np.full(len(moving), np.inf)
        std[moving] = crlb(H[np.ix_(moving, moving)]).std
        return std

    def unpack(q):
        th, x = theta.copy(), x0.copy()
        th[idx] = q[:p]
        if free_initial:
            x[:, ch] = q[p:].reshape(len(records), len(ch))
        return th, x

    def weighted(res, R):
        return 0.5 * sum(float(np.nansum(e**2 / R)) for e in res)

    q = np.clip(np.concatenate([theta[idx], x0[:, ch].ravel() if free_initial else []]), low, high)
    flown, res = _simulate(model, *unpack(q), records, ch, substeps)
    if res is None:
        return None
    R = pooled_noise(res, held)
    lam, down, cap = DAMPING[0], DAMPING[1], DAMPING[2]
    status, iterations = "iteration limit", 0
    for iterations in range(1, max_iterations + 1):
        sens = _sensitivities(model, *unpack(q), records, flown, ch, idx, substeps)
        H, g = _normal_equations(res, sens, R, free_initial)
        # projected Levenberg-Marquardt: the parameters held on their bound stay out of the step,
        # the others' step is taken in the box (clipped onto it)
        moving = ~_active(q, g, low, high)
        std = bounds_of(H, moving)
        cost = weighted(res, R)
        while lam <= cap:
            D = np.diag(H)[moving]
            step = np.zeros(len(q))
            # (H_FF + λ diag H_FF) d_F = g_F
            step[moving] = np.linalg.solve(
                H[np.ix_(moving, moving)] + lam * np.diag(np.where(D > 0, D, 1.0)), g[moving]
            )
            step = np.clip(q + step, low, high) - q
            trial_flown, trial = _simulate(model, *unpack(q + step), records, ch, substeps)
            if trial is not None and weighted(trial, R) < cost:
                break
            lam *= down
        else:
            status = "stalled"
            break
        q, flown, res, lam = q + step, trial_flown, trial, lam / down
        R = pooled_noise(res, held)
        if callback is not None:
            callback(q[:p].copy(), neg_log_likelihood(res, R))
        if np.all(np.abs(step) <= tolerance * std):
            status = "converged"
            break
    std = bounds_of(_normal_equations(res, sens, R, free_initial)[0], moving)
    th, x = unpack(q)
    at = {free[k]: float(q[k]) for k in np.flatnonzero((q[:p] <= low[:p]) | (q[:p] >= high[:p]))}
    return NonlinearFit(
        theta=th,
        estimates={n: float(v) for n, v in zip(free, q[:p])},
        std={n: float(s) for n, s in zip(free, std[:p])},
        at_bounds=at,
        initial_states=x,
        noise_std={c: float(np.sqrt(v)) for c, v in zip(channels, R)},
        cost=neg_log_likelihood(res, R),
        iterations=iterations,
        status=status,
    )


def information(
    model: NonlinearModel,
    theta,
    x0: np.ndarray,
    records: Sequence[Record],
    channels: Sequence[str],
    free: Sequence[str],
    R: np.ndarray,
    substeps: int | None = None,
) -> tuple[np.ndarray, list[np.ndarray]]:
    """The Fisher information `Σ JᵀR⁻¹J` (the fit's bounds) over [the `free` parameters of θ ⊕ b ⊕ g
    (`theta`, `parameter_names`) | each record's measured initial states] with the noise variances `R` per channel, each record flown
    from its row of `x0` (records, 10), and the residuals along the flights."""
    res, sens = _linearisation(model, theta, x0, records, channels, free, substeps)
    return _normal_equations(res, sens, np.asarray(R, float), True)[0], res


def _linearisation(model, theta, x0, records, channels, free, substeps):
    """Each record's residuals along its flight from its row of `x0`, and its output
    sensitivities to θ's `free` coefficients and to its measured initial states."""
    ch = [STATES.index(c) for c in channels]
    names = parameter_names(model, channels)
    idx = np.array([names.index(n) for n in free], dtype=np.int64)
    flown, res = _simulate(model, theta, x0, records, ch, substeps)
    if res is None:
        raise InputError("the model's flight does not stay finite over the records; expected a bounded one")
    return res, _sensitivities(model, theta, x0, records, flown, ch, idx, substeps)


def _normal_equations(res, sens, R, free_initial):
    """H = Σ Jᵀ R⁻¹ J and g = Σ Jᵀ R⁻¹ e over the records' samples present, the columns
    [θ[free] | each record's measured initial states] (the latter only when free)."""
    P = _columns(res, sens, free_initial)
    H, g = np.zeros((P, P)), np.zeros(P)
    for i, (e, (St, Sx)) in enumerate(zip(res, sens)):
        e, J = present_only(e, _jacobian(i, St, Sx, P, free_initial))
        W = J / R[:, None]
        H += np.einsum("nci,ncj->ij", W, J)
        g += np.einsum("nci,nc->i", W, e)
    return H, g


def _columns(res, sens, free_initial) -> int:
    """The parameters: θ[free], and each record's measured initial states when free."""
    return sens[0][0].shape[2] + (len(res) * sens[0][1].shape[2] if free_initial else 0)


def _jacobian(i, St, Sx, P, free_initial) -> np.ndarray:
    """Record i's output sensitivities (N, C, P) to [θ[free] | each record's measured initial
    states] from its sensitivities to θ[free] `St` and to its own initial states `Sx`."""
    p, c = St.shape[2], Sx.shape[2]
    J = np.zeros(St.shape[:2] + (P,))
    J[:, :, :p] = St
    if free_initial:
        J[:, :, p + i * c : p + (i + 1) * c] = Sx
    return J


def coloured_bounds(
    model: NonlinearModel,
    theta,
    x0: np.ndarray,
    records: Sequence[Record],
    channels: Sequence[str],
    free: Sequence[str],
    R: np.ndarray,
    substeps: int | None = None,
) -> tuple[np.ndarray, np.ndarray, list[np.ndarray], np.ndarray]:
    """`(σ, σ_coloured, residuals, H)` at θ and the initial states `x0` (records, 10) with the noise
    variances `R`: the Cramér-Rao σ of the `free` parameters of θ ⊕ b ⊕ g (the initial states among the
    parameters, as the fit's), Morelli & Klein's σ for coloured residuals
    (`bounds.coloured_covariance`, its per-record sum `bounds.coloured_term`), the residuals and
    the Fisher information H they come from (`information`'s)."""
    res, sens = _linearisation(model, theta, x0, records, channels, free, substeps)
    R = np.asarray(R, float)
    H, _ = _normal_equations(res, sens, R, True)
    cov, std, _ = crlb(H)
    p, P, scale = len(free), len(H), np.sqrt(R)
    total = np.zeros((p, p))
    for i, (e, (St, Sx)) in enumerate(zip(res, sens)):
        # the rows with no sample (fins logged between the samples) left out: the residuals'
        # autocorrelation is over the samples, its lags counted in them
        rows = ~np.isnan(e).all(axis=1)
        missing = np.isnan(e[rows])
        e, J = present_only(e[rows], _jacobian(i, St[rows], Sx[rows], P, True))
        Z = (J / scale[:, None]) @ cov[:p].T
        total += coloured_term(Z, e / scale, ~missing if missing.any() else None)
    coloured = np.where(np.isinf(std[:p]), np.inf, np.sqrt(np.maximum(np.diag(total), 0.0)))
    return std[:p], coloured, res, H
