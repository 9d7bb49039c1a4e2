"""The nonlinear model's output-error likelihood: its records, parameters, flights, residuals,
noise, sensitivities and normal equations, and the Fisher information and bounds at a fit.
`nonlinear_objective` makes it an `objective.Objective`, which `estimators.trust_region` fits.

The outputs are the measured states of the simulated trajectory (`nonlinear_sensitivities.flight`)
plus their output biases, `y = x + b + v` (an attitude sensor's mounting offset; `b` acts on its
own channel alone, `∂y/∂b = 1` there and 0 elsewhere, and not on the flight), the velocities as
a log mounted as g reads them over the ground (`log_mounting`: away from the CG, turned; 0 at
the CG), a steady current c = (c_N, c_E) turned into the body's axes by the record's measured
heading (`log_mounting.body_current`), as the linear model's outputs take it. The fins the
model flies are the recorded ones advanced by the inputs' delay τ, δ(t_k) = δ_rec(t_k + τ)
(`problem.shifted`: cubic convolution between samples, on a record's constant sample interval),
the flight's sensitivity to τ forced by ∂f/∂δ ∂δ/∂τ (`nonlinear_sensitivities`). The fit's
parameters are θ ⊕ b ⊕ g ⊕ c ⊕ τ (`parameter_names`: θ's names, then `b_<state>` of each
measured channel, the mounting, the current, the delay), each free like any coefficient; the
noise `v ~ N(0, R)` with R diagonal, one variance per measured channel pooled over the
records. A missing sample (NaN: a sensor slower than the fins are logged, a dropout) is left
out of every sum, its residual NaN and its rows of J zero; the flight goes through it with the
fins of every row, so fins logged faster than the states move the model as they moved the body.
As for the linear model (`likelihood`), R is the residuals' mean square per channel (or held
where `noise_std` gives it); the normal equations are `H = Σ Jᵀ R⁻¹ J`, `g = Σ Jᵀ R⁻¹ e`, J the
outputs' exact sensitivities, the bounds those of H with the initial states among the
parameters.

A record's initial state starts from its first sample in the measured channels and from straight
flight at the vehicle's speed in the others; free, only the measured channels' components move.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from testbed.data import Experiment, ModelConfig, check_excited
from testbed.errors import InputError
from testbed.identification.bounds import coloured_term, crlb
from testbed.identification.nonlinear_prediction import check_constant_interval, initial_state
from testbed.identification.nonlinear_sensitivities import flight
from testbed.identification.problem import check_heading, measured_heading, shifted
from testbed.identification.recursions import simulated
from testbed.models import log_mounting
from testbed.models.linear import CURRENT, DELAY, MOUNTING, NU, NX, STATES
from testbed.models.nonlinear import NonlinearModel
from testbed.models.nonlinear_flight import flown_rows, fly_nonlinear

__all__ = [
    "FlightRecord",
    "check_records",
    "coloured_bounds",
    "coloured_bounds_held",
    "flight_information",
    "neg_log_likelihood",
    "normal_equations",
    "output_terms",
    "read_outputs",
    "record_fins",
    "sensitivity_bounds",
    "parameter_names",
    "pooled_noise",
    "present_only",
    "records",
    "flight_residuals",
    "fitted_initial_states",
    "output_sensitivities",
    "setup",
    "fly_records",
    "start_states",
]


@dataclass(frozen=True)
class FlightRecord:
    """One record: sample times (N,), fin angles (N, 3) held per sample, the measured
    states (N, C) in the fit's channels' order, NaN where a sample is missing (a sensor slower
    than the fins are logged, a dropout), and its measured heading ψ (N,) that turns the current
    into the body's axes (`problem.measured_heading`; None: not measured, taken as 0)."""

    t: np.ndarray
    fins: np.ndarray
    y: np.ndarray
    heading: np.ndarray | None = None

    def rows(self, a: int, b: int) -> "FlightRecord":
        """Its samples a to b (a segment)."""
        return self.at(slice(a, b))

    def at(self, rows) -> "FlightRecord":
        """Its samples at `rows` (a slice or increasing indices)."""
        heading = None if self.heading is None else self.heading[rows]
        return FlightRecord(t=self.t[rows], fins=self.fins[rows], y=self.y[rows], heading=heading)


def records(
    experiments: Sequence[Experiment], fit: str = "the nonlinear fit"
) -> tuple[tuple[str, ...], list[FlightRecord]]:
    """The measured channels (every record's, the same) and the `FlightRecord` of each experiment;
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
    return channels, [
        FlightRecord(t=e.t, fins=e.inputs, y=e.y, heading=measured_heading(e)) for e in experiments
    ]


def parameter_names(model: NonlinearModel, channels: Sequence[str]) -> tuple[str, ...]:
    """The names of the fit's parameters θ ⊕ b ⊕ g ⊕ c ⊕ τ: θ's (`model.names`), the output bias
    `b_<state>` of each measured channel in `channels`, the velocity log's mounting g
    (`MOUNTING`), the current c (`CURRENT`), then the inputs' delay τ (`DELAY`)."""
    return model.names + tuple(f"b_{c}" for c in channels) + MOUNTING + CURRENT + (DELAY,)


def output_terms(theta: np.ndarray, m: int, ch) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(b, g, c) of θ ⊕ b ⊕ g ⊕ c ⊕ τ (θ's length `m`, the channels `ch`)."""
    k = m + len(ch)
    g = k + len(MOUNTING)
    return theta[m:k], theta[k:g], theta[g : g + len(CURRENT)]


def _delay_at(m: int, ch) -> int:
    """Where τ sits in θ ⊕ b ⊕ g ⊕ c ⊕ τ: last."""
    return m + len(ch) + len(MOUNTING) + len(CURRENT)


def record_fins(
    record: FlightRecord, theta: np.ndarray, m: int, ch, along: bool = False
) -> tuple[np.ndarray, np.ndarray | None]:
    """The fins (N, 3) the model flies on `record` at θ ⊕ b ⊕ g ⊕ c ⊕ τ: the recorded ones
    advanced by τ, δ_rec(t_k + τ) (`problem.shifted` on the record's sample interval; at τ = 0
    the recorded ones), and with `along` their derivative along τ (N, 3, 1), else None."""
    tau = theta[_delay_at(m, ch)]
    if tau == 0 and not along:
        return record.fins, None
    dt = record.t[1] - record.t[0]
    value, first, _ = shifted(record.fins, tau / dt)
    return value, (first / dt)[:, :, None] if along else None


def read_outputs(
    states: np.ndarray, theta: np.ndarray, m: int, ch, heading: np.ndarray | None = None
) -> np.ndarray:
    """The outputs (N, C) of the flown `states` (N, 10) in the state columns `ch` at
    θ ⊕ b ⊕ g ⊕ c ⊕ τ (`theta`, θ's length `m`): the states as read (u, v, w by the log mounted as g over the
    ground, the current turned by the record's `heading`, `log_mounting.read`) plus their biases."""
    b, g, c = output_terms(theta, m, ch)
    return log_mounting.read(g, states, ch, log_mounting.current_along(c, heading, len(states))) + b


def setup(
    experiments: Sequence[Experiment], config: ModelConfig, fit: str
) -> tuple[tuple[str, ...], list[FlightRecord], NonlinearModel, np.ndarray, list[int]]:
    """`(channels, records, model, θ ⊕ b ⊕ g ⊕ c ⊕ τ, free indices)` of a nonlinear model config's `free`
    (indices into `parameter_names`) on the experiments (`records`, each on the rows its flight
    needs, `flown_rows`, unless the delay is free or not 0), b the config's output biases
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
    blind = [n for n in config.free if n in MOUNTING + CURRENT] if not {"u", "v", "w"} & set(channels) else []
    if blind:
        what = "the velocity log's mounting" if blind[0] in MOUNTING else "the current"
        raise InputError(
            f"{source}: [identify] free names {blind[0]}, {what}, but the records "
            f"measure no velocity (they measure {', '.join(channels)}); expected u, v or w measured"
        )
    current = np.any(config.current()) or any(n in CURRENT for n in config.free)
    check_heading(experiments, bool(current))
    delay = config.coefficients[DELAY]
    if delay != 0 or DELAY in config.free:
        check_constant_interval(experiments, f"{DELAY} (free or not 0)")
    else:  # the delayed fins are interpolated on the constant interval: every row kept there
        recs = [r.at(flown_rows(r.t, r.y, r.fins)) for r in recs]
    theta = np.concatenate(
        [theta, config.output_biases(channels), config.mounting(), config.current(), [delay]]
    )
    return channels, recs, model, theta, [names.index(n) for n in config.free]


def check_records(model, records, channels, free, noise_std, tolerance, max_iterations) -> None:
    """`InputError` for what a fit of the `free` parameters (names) to the `records`' measured
    `channels` cannot take: a tolerance ≤ 0, an iteration limit < 1, a name not in the model,
    channels not states, given noise of a channel not measured or not a positive number, records
    of the wrong shapes or with infinite samples."""
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


def fly_records(model, theta, x0, records, ch, substeps):
    """Each record's flown states (N, 10) and residuals `e = y − ŷ` (N, C) (`read_outputs`), NaN
    where the sample is missing, at θ ⊕ b ⊕ g ⊕ c ⊕ τ (`theta`; what it leaves out: 0); (None, None)
    where a flight does not stay finite. Tallied as simulated samples (`recursions.counting`)."""
    m = len(model.names)
    theta = _padded(theta, m, ch)
    flown, res = [], []
    with np.errstate(all="ignore"):
        for r, x in zip(records, x0):
            states = fly_nonlinear(model, theta[:m], r.t, x, record_fins(r, theta, m, ch)[0], substeps)
            simulated(len(r.t))
            if not np.all(np.isfinite(states[:, ch])):
                return None, None
            flown.append(states)
            res.append(r.y - read_outputs(states, theta, m, ch, r.heading))
    return flown, res


def _padded(theta, m: int, ch) -> np.ndarray:
    """θ ⊕ b ⊕ g ⊕ c ⊕ τ from θ or a part of it that leaves out its end (what is left out: 0)."""
    theta = np.asarray(theta)
    full = _delay_at(m, ch) + 1
    return theta if len(theta) == full else np.concatenate([theta, np.zeros(full - len(theta))])


def flight_residuals(
    model: NonlinearModel,
    theta,
    x0: np.ndarray,
    records: Sequence[FlightRecord],
    ch,
    substeps: int | None = None,
):
    """Each record's residuals (N, C) in the state columns `ch` (NaN where the sample is
    missing) at θ ⊕ b ⊕ g ⊕ c ⊕ τ (`theta`; what it leaves out: 0), flown from its row of `x0` (records, 10); None
    where a flight does not stay finite. Tallied as `_simulate`'s."""
    return fly_records(model, theta, x0, records, ch, substeps)[1]


def fitted_initial_states(
    model: NonlinearModel,
    theta: np.ndarray,
    records: Sequence[FlightRecord],
    ch,
    x0: np.ndarray,
    R: np.ndarray | None,
    sensitivities: bool = True,
) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """`(x0, S)`: each record's measured initial state fitted at θ ⊕ b ⊕ g ⊕ c ⊕ τ (`theta`) by
    Gauss-Newton from its row of `x0` (records, 10) (`nonlinear_prediction.initial_state`: the
    flight fitted to the record less its output biases b, read by the log mounted as g, the
    current c along the record's heading), the noise variances `R` (per channel of `ch`) held, or
    relaxed per record where None; with `sensitivities`, S per record: the outputs' sensitivities
    to the measured initial state there (N, k, k), else None."""
    fitted, sens, m = [], [], len(model.names)
    b, g, c = output_terms(theta, m, ch)
    for r, x in zip(records, x0):
        current, fins = log_mounting.current_along(c, r.heading, len(r.t)), record_fins(r, theta, m, ch)[0]
        x = initial_state(
            model, theta[:m], r.t, fins, r.y - b, ch, range(len(ch)), x, R, None, None, g, current
        )[0]
        fitted.append(x)
        if sensitivities:
            dx0 = flight(model, theta[:m], r.t, x, fins, (), None).dx_dx0
            sens.append(log_mounting.read_derivatives(g, dx0, ch)[:, :, ch])
            simulated(len(r.t) * (1 + len(ch)))
    return np.array(fitted), sens if sensitivities else None


def start_states(model: NonlinearModel, records: Sequence[FlightRecord], ch) -> np.ndarray:
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


def output_sensitivities(model, theta, x0, records, flown, ch, free, substeps):
    """Each record's output sensitivities to (θ ⊕ b ⊕ g ⊕ c ⊕ τ)[free] (N, C, p) and to the
    measured channels' initial states (N, C, C), along its flown states; tallied
    (`recursions.counting`) as 1 + the free coefficients of θ columns (and τ's) a sample (the
    pass evaluates the model at every RK4 stage again)."""
    m, free = len(model.names), np.asarray(free, dtype=np.int64).reshape(-1)
    theta, ch = _padded(theta, m, ch), np.asarray(ch)
    k, d = m + len(ch), _delay_at(m, ch)  # where the mounting starts (the current after it), τ
    own, bias = free < m, (free >= m) & (free < k)
    mounting, current, delay = (
        (free >= k) & (free < k + len(MOUNTING)),
        (free >= k + len(MOUNTING)) & (free < d),
        free == d,
    )
    _, g, c = output_terms(theta, m, ch)
    velocity = ch < 3
    out = []
    for r, x, states in zip(records, x0, flown):
        fins, dfins = record_fins(r, theta, m, ch, bool(delay.any()))
        f = flight(model, theta[:m], r.t, x, fins, free[own], substeps, dfins)
        simulated(len(r.t) * (1 + int(own.sum()) + int(delay.any())))
        St = np.zeros((len(r.t), len(ch), len(free)))
        St[:, :, _positions(own)] = log_mounting.read_derivatives(g, f.dx_dtheta, ch)
        if delay.any():  # the flight's own, through the fins it moves
            St[:, :, delay] = log_mounting.read_derivatives(g, f.dx_dinputs, ch)
        # ∂(x + b)/∂b = 1 on the bias's own channel, 0 on the others
        St[:, free[bias] - m, np.flatnonzero(bias)] = 1.0
        psi = np.zeros(len(r.t)) if r.heading is None else r.heading
        if mounting.any():  # the log's reading moves with its mounting, on u, v, w
            cb = log_mounting.body_current(c, psi)
            dg = log_mounting.mounting_derivatives(g, states[:, :3], states[:, 3:6], cb)
            for j in np.flatnonzero(mounting):
                St[:, velocity, j] = dg[free[j] - k][:, ch[velocity]]
        if current.any():  # the reading Mᵀ(v + ω × r + c_b): ∂y/∂c = Mᵀ ∂c_b/∂c on u, v, w
            dc = log_mounting.body_current_derivatives(psi) @ log_mounting.turned(g)
            for j in np.flatnonzero(current):
                St[:, velocity, j] = dc[free[j] - k - len(MOUNTING)][:, ch[velocity]]
        out.append((St, log_mounting.read_derivatives(g, f.dx_dx0, ch)[:, :, ch]))
    return out


def _positions(mask: np.ndarray):
    """Where `mask` is true: a slice where those places run on without a gap (numpy writes a
    slice's block several times faster than it scatters along a mask), else their indices."""
    at = np.flatnonzero(mask)
    if len(at) and at[-1] - at[0] + 1 == len(at):
        return slice(int(at[0]), int(at[-1]) + 1)
    return at


def flight_information(
    model: NonlinearModel,
    theta,
    x0: np.ndarray,
    records: Sequence[FlightRecord],
    channels: Sequence[str],
    free: Sequence[str],
    R: np.ndarray,
    substeps: int | None = None,
) -> tuple[np.ndarray, list[np.ndarray]]:
    """The Fisher information `Σ JᵀR⁻¹J` (the fit's bounds) over [the `free` parameters of θ ⊕ b ⊕ g ⊕ c ⊕ τ
    (`theta`, `parameter_names`) | each record's measured initial states] with the noise variances `R` per channel, each record flown
    from its row of `x0` (records, 10), and the residuals along the flights."""
    res, sens = _linearisation(model, theta, x0, records, channels, free, substeps)
    return normal_equations(res, sens, np.asarray(R, float), True)[0], res


def _linearisation(model, theta, x0, records, channels, free, substeps):
    """Each record's residuals along its flight from its row of `x0`, and its output
    sensitivities to θ's `free` coefficients and to its measured initial states."""
    ch = [STATES.index(c) for c in channels]
    names = parameter_names(model, channels)
    idx = np.array([names.index(n) for n in free], dtype=np.int64)
    flown, res = fly_records(model, theta, x0, records, ch, substeps)
    if res is None:
        raise InputError("the model's flight does not stay finite over the records; expected a bounded one")
    return res, output_sensitivities(model, theta, x0, records, flown, ch, idx, substeps)


def normal_equations(res, sens, R, free_initial):
    """H = Σ Jᵀ R⁻¹ J and g = Σ Jᵀ R⁻¹ e over the records' samples present, the columns
    [θ[free] | each record's measured initial states] (the latter only when free)."""
    P = _columns(res, sens, free_initial)
    H, g = np.zeros((P, P)), np.zeros(P)
    for i, (e, (St, Sx)) in enumerate(zip(res, sens)):
        cols = _record_columns(i, St, Sx, free_initial)
        # the rows (sample, channel) present, each a row of the record's own columns (θ[free] and
        # its initial states; zero in the others')
        present = ~np.isnan(e.ravel())
        J = _jacobian(St, Sx, free_initial).reshape(-1, len(cols))[present]
        W = J / np.broadcast_to(R, e.shape).ravel()[present, None]
        # H += Jᵢᵀ R⁻¹ Jᵢ, g += Jᵢᵀ R⁻¹ eᵢ
        H[np.ix_(cols, cols)] += W.T @ J
        g[cols] += W.T @ e.ravel()[present]
    return H, g


def _columns(res, sens, free_initial) -> int:
    """The parameters: θ[free], and each record's measured initial states when free."""
    return sens[0][0].shape[2] + (len(res) * sens[0][1].shape[2] if free_initial else 0)


def _record_columns(i, St, Sx, free_initial) -> np.ndarray:
    """Where record i's sensitivities (`_jacobian`) sit among the columns [θ[free] | each record's
    measured initial states]: θ[free]'s, and its own initial states' when free."""
    p, c = St.shape[2], Sx.shape[2]
    own = np.arange(p + i * c, p + (i + 1) * c) if free_initial else np.arange(0)
    return np.r_[np.arange(p), own]


def _jacobian(St, Sx, free_initial) -> np.ndarray:
    """A record's output sensitivities (N, C, ·) to θ[free] `St` and, when free, to its own
    initial states `Sx`: its columns of the Jacobian (`_record_columns`), the others' zero."""
    return np.concatenate([St, Sx], axis=2) if free_initial else St


def coloured_bounds(
    model: NonlinearModel,
    theta,
    x0: np.ndarray,
    records: Sequence[FlightRecord],
    channels: Sequence[str],
    free: Sequence[str],
    R: np.ndarray,
    substeps: int | None = None,
) -> tuple[np.ndarray, np.ndarray, list[np.ndarray], np.ndarray]:
    """`(σ, σ_coloured, residuals, H)` at θ and the initial states `x0` (records, 10) with the noise
    variances `R`: the Cramér-Rao σ of the `free` parameters of θ ⊕ b ⊕ g ⊕ c ⊕ τ (the initial states among the
    parameters, as the fit's), Morelli & Klein's σ for coloured residuals
    (`bounds.coloured_covariance`, its per-record sum `bounds.coloured_term`), the residuals and
    the Fisher information H they come from (`flight_information`'s)."""
    return sensitivity_bounds(*_linearisation(model, theta, x0, records, channels, free, substeps), R)


def coloured_bounds_held(
    model: NonlinearModel,
    theta,
    x0: np.ndarray,
    records: Sequence[FlightRecord],
    channels: Sequence[str],
    free: Sequence[str],
    R: np.ndarray,
    held: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, list[np.ndarray], np.ndarray | None]:
    """`coloured_bounds` of the `free` parameters where those `held` (bool per name) end on a
    bound of a box: theirs NaN (a bound is no estimate's σ), the others' with them held; the
    residuals, and H where none is held (None otherwise: the information of the others alone)."""
    std, coloured = np.full(len(free), np.nan), np.full(len(free), np.nan)
    at = np.flatnonzero(~held)
    if not len(at):
        return (
            std,
            coloured,
            flight_residuals(model, theta, x0, records, [STATES.index(c) for c in channels]),
            None,
        )
    moving = [free[k] for k in at]
    std[at], coloured[at], res, H = coloured_bounds(model, theta, x0, records, channels, moving, R)
    return std, coloured, res, None if held.any() else H


def sensitivity_bounds(res: Sequence[np.ndarray], sens: Sequence[tuple], R) -> tuple:
    """`coloured_bounds` from each record's residuals `res` and output sensitivities `sens` (as
    `output_sensitivities` gives them, its columns the free parameters), with the noise
    variances `R`."""
    R = np.asarray(R, float)
    H, _ = normal_equations(res, sens, R, True)
    cov, std, _ = crlb(H)
    p, scale = sens[0][0].shape[2], np.sqrt(R)
    total = np.zeros((p, p))
    for i, (e, (St, Sx)) in enumerate(zip(res, sens)):
        # the rows with no sample (fins logged between the samples) left out: the residuals'
        # autocorrelation is over the samples, its lags counted in them
        rows = ~np.isnan(e).all(axis=1)
        missing = np.isnan(e[rows])
        e, J = present_only(e[rows], _jacobian(St[rows], Sx[rows], True))
        Z = (J / scale[:, None]) @ cov[:p, _record_columns(i, St, Sx, True)].T
        total += coloured_term(Z, e / scale, ~missing if missing.any() else None)
    coloured = np.where(np.isinf(std[:p]), np.inf, np.sqrt(np.maximum(np.diag(total), 0.0)))
    return std[:p], coloured, res, H
