"""What a nonlinear model config predicts on measured experiments: its model flown open loop
(`nonlinear_flight.fly_nonlinear`) with each record's fin angles, for validation.

The outputs are the flown states plus the config's output biases (`y = x + b`, `b_<state>`), the
velocities as the config's velocity log reads them where it is mounted and over the ground where
the config has a current, turned by the record's measured heading (`log_mounting.read`); the
fins flown are the recorded ones advanced by the config's inputs' delay (`delayed_inputs`).
Each record is flown from its initial state: the given one (an estimate's `initial_states`) where
given, else the best-fitting one, as the linear model's predictions take it. The best fit starts
from the record's first sample in its measured states (straight flight at the vehicle's speed in
the others and where the first sample is missing) and moves the measured states' components by
damped Gauss-Newton on the output-error likelihood of the record less its biases, with the noise relaxed (R the residuals' mean
square per channel, then held for the step), the flight's exact sensitivities to its initial
state (`nonlinear_sensitivities.flight`), until the undamped Gauss-Newton step is below
`TOLERANCE` of its Cramér-Rao σ in every component or `ITERATIONS` have run. Missing samples are
left out of the fit.
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from testbed.data import Experiment, ModelConfig, split, stretches
from testbed.errors import InputError, Unflyable
from testbed.identification.nonlinear_sensitivities import flight
from testbed.identification.problem import measured_heading, shifted
from testbed.identification.recursions import simulated
from testbed.models import log_mounting
from testbed.models.linear import DELAY, MOUNTING, NX, STATES
from testbed.models.nonlinear import NonlinearModel
from testbed.models.nonlinear_flight import flown_rows, fly_nonlinear

__all__ = [
    "ITERATIONS",
    "TOLERANCE",
    "check_constant_interval",
    "delayed_inputs",
    "first_samples",
    "flights",
    "initial_state",
    "predict_nonlinear",
    "unread",
]

ITERATIONS = 20  # Gauss-Newton steps of an initial state's fit, at most
TOLERANCE = 0.01  # converged when every component's step is below this many of its Cramér-Rao σ


def predict_nonlinear(
    experiments: Sequence[Experiment],
    config: ModelConfig,
    initial: Mapping[str, Mapping[str, float]] | None = None,
    substeps: int | None = None,
) -> list[np.ndarray]:
    """The nonlinear model's outputs (N, k) per experiment in its measured columns (the flown
    states plus the config's output biases), absolute u,
    flown by RK4 with `substeps` steps per sample interval from the initial states `initial`
    (record → state → x0: a record split at a dropout names each stretch, `data.split`) gives and
    the best-fitting ones it does not (module doc), over each stretch, NaN between them;
    `Unflyable` (an `InputError`) naming the record where a flight leaves the finite numbers."""
    pieces = [split(e) for e in experiments]
    flown = iter(flights([p for ps in pieces for p in ps], config, initial, substeps))
    out = []
    for e, ps in zip(experiments, pieces):
        y = np.full(np.shape(e.y), np.nan)
        for (a, b), p in zip(stretches(e), ps):
            x = next(flown)
            ch = [STATES.index(c) for c in p.measured]
            y[a:b] = log_mounting.read(config.mounting(), x, ch, _current(p, config))
            y[a:b] += config.output_biases(p.measured)
        out.append(y)
    return out


def _current(e: Experiment, config: ModelConfig) -> np.ndarray | None:
    """The config's current in body axes along the record's measured heading
    (`log_mounting.current_along`), None where the config has none."""
    return log_mounting.current_along(config.current(), measured_heading(e), len(e.t))


def check_constant_interval(experiments: Sequence[Experiment], what: str) -> None:
    """`InputError` naming the first record whose samples are not at one constant interval (to
    1e-6 of it), which `what` (the inputs' delay: a shift in samples) needs."""
    for e in experiments:
        dt = np.diff(np.asarray(e.t, float))
        if len(dt) and np.any(np.abs(dt - dt[0]) > 1e-6 * dt[0]):
            raise InputError(
                f"{e.source or e.name}: its samples are {dt.min():g} to {dt.max():g} s apart; {what} "
                "shifts the fins by a fraction of one interval: expected a constant sample interval"
            )


def delayed_inputs(e: Experiment, config: ModelConfig) -> np.ndarray:
    """The fins (N, 3) the config's model flies on record `e`: the recorded ones advanced by its
    inputs' delay τ, δ_rec(t_k + τ) (`problem.shifted` on the record's sample interval, which a
    delay needs constant: `check_constant_interval`)."""
    tau = config.coefficients[DELAY]
    if tau == 0 or len(e.t) < 2:
        return e.inputs
    check_constant_interval([e], f"{DELAY} (free or not 0)")
    return shifted(np.asarray(e.inputs, float), tau / (e.t[1] - e.t[0]))[0]


def unread(e: Experiment, config: ModelConfig) -> np.ndarray:
    """The record's readings (N, k) less the config's output biases and, on u and v, its current
    (`_current`): the states as a log at the CG reads them through the water (a mounted log's
    reading is not undone)."""
    y = e.y - config.output_biases(e.measured)
    current = _current(e, config)
    if current is not None:
        for j, c in enumerate(e.measured):
            if c in ("u", "v"):
                y[:, j] -= current[:, STATES.index(c)]
    return y


def first_samples(experiments: Sequence[Experiment], config: ModelConfig) -> dict[str, dict[str, float]]:
    """Each record's initial state as its first sample less the config's output terms (`unread`),
    record name → state → value (a state whose first sample is missing left out: fitted)."""
    out = {}
    for e in experiments:
        first = unread(e, config)[0]
        out[e.name] = {c: float(v) for c, v in zip(e.measured, first) if np.isfinite(v)}
    return out


def flights(
    experiments: Sequence[Experiment],
    config: ModelConfig,
    initial: Mapping[str, Mapping[str, float]] | None = None,
    substeps: int | None = None,
) -> list[np.ndarray]:
    """`predict_nonlinear`'s flights: every state (N, 10) of each experiment, absolute u (no output
    bias). The initial state is fitted on the rows the flight must stop at (`flown_rows`), then
    flown through every row."""
    model, theta = config.nonlinear()
    out = []
    for e in experiments:
        ch = [STATES.index(c) for c in e.measured]
        given = (initial or {}).get(e.name, {})
        y = e.y - config.output_biases(e.measured)  # y − b: the states as read
        x0 = np.zeros(NX)
        x0[0] = model.vehicle.speed
        for c, v in {**first_samples([e], config)[e.name], **given}.items():
            x0[STATES.index(c)] = v
        moved = [j for j, c in enumerate(e.measured) if c not in given]
        fins, current = delayed_inputs(e, config), _current(e, config)
        rows = flown_rows(e.t, y, fins)
        t = e.t[rows]
        with np.errstate(all="ignore"):
            states = _finite(e, config, t, fly_nonlinear(model, theta, t, x0, fins[rows], substeps))
            x0, states = initial_state(
                model,
                theta,
                t,
                fins[rows],
                y[rows],
                ch,
                moved,
                x0,
                None,
                substeps,
                states,
                config.mounting(),
                None if current is None else current[rows],
            )
            if len(rows) < len(e.t):
                states = fly_nonlinear(model, theta, e.t, x0, fins, substeps)
                states = _finite(e, config, e.t, states, "from its fitted initial state")
        out.append(states)
    return out


def _finite(
    e: Experiment,
    config: ModelConfig,
    t: np.ndarray,
    states: np.ndarray,
    start: str = "from the record's first sample",
) -> np.ndarray:
    """`states` flown `start` at the times `t` of record `e`; `Unflyable` naming the record and
    the config where they leave the finite numbers."""
    bad = np.argwhere(~np.isfinite(states))
    if len(bad):
        why = (
            f"{config.source or 'the config'}'s model flown {start} leaves the finite numbers at "
            f"t = {t[bad[0][0]]:g} s"
        )
        raise Unflyable(f"{e.source or e.name}: {why}; expected a model whose flight stays bounded", why)
    return states


def initial_state(
    model: NonlinearModel,
    theta,
    t: np.ndarray,
    fins: np.ndarray,
    y: np.ndarray,
    ch: Sequence[int],
    moved: Sequence[int],
    x0: np.ndarray,
    R: np.ndarray | None = None,
    substeps: int | None = None,
    states: np.ndarray | None = None,
    mounting: np.ndarray | None = None,
    current: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """`(x0, states)`: the best-fitting initial state (module doc) of a record with times `t`,
    fins and measurements `y` (N, k) of the states `ch` as read (NaN where missing; u, v, w by a
    velocity log mounted as `mounting`, None: at the CG, over the ground where the `current` in
    body axes (N, 3) is given), started from `x0`, its components
    `moved` (indices into `ch`) fitted, and the flight from it; the noise variances `R` (k,) held
    where given, else relaxed. The flight from `x0` (`states` where already flown) must stay
    finite. Its flights count 1 a sample and its sensitivity passes 1 + the components moved
    (`recursions.counting`)."""
    y = np.asarray(y, float)
    present = np.isfinite(y)
    cols = [ch[j] for j in moved]
    mounting = np.zeros(len(MOUNTING)) if mounting is None else np.asarray(mounting, float)

    def residual(x):
        return np.where(present, y - log_mounting.read(mounting, x, ch, current), 0.0)

    if states is None:
        states = fly_nonlinear(model, theta, t, x0, fins, substeps)
        simulated(len(t))
    res, lam = residual(states), 1e-3
    for _ in range(ITERATIONS if moved else 0):
        V = np.maximum(np.sum(res**2, axis=0) / np.maximum(present.sum(axis=0), 1), 1e-30) if R is None else R
        dx0 = flight(model, theta, t, x0, fins, (), substeps).dx_dx0
        J = log_mounting.read_derivatives(mounting, dx0, ch)[:, :, cols]
        simulated(len(t) * (1 + len(cols)))
        J = np.where(present[:, :, None], J, 0.0)
        W = J / V[:, None]
        H = np.einsum("nci,ncj->ij", W, J)
        g = np.einsum("nci,nc->i", W, res)
        cost = float(np.sum(res**2 / V))
        if np.all(
            np.abs(np.linalg.lstsq(H, g, rcond=None)[0])
            <= TOLERANCE * np.sqrt(np.abs(np.diag(np.linalg.pinv(H))))
        ):
            break  # the Gauss-Newton step is within the tolerance: converged
        while lam <= 1e10:
            step = np.linalg.solve(H + lam * np.diag(np.where(np.diag(H) > 0, np.diag(H), 1.0)), g)
            trial_x0 = x0.copy()
            trial_x0[cols] += step
            trial = fly_nonlinear(model, theta, t, trial_x0, fins, substeps)
            simulated(len(t))
            if np.all(np.isfinite(trial)) and float(np.sum(residual(trial) ** 2 / V)) < cost:
                break
            lam *= 10
        else:
            break
        x0, states, res, lam = trial_x0, trial, residual(trial), lam / 10
    return x0, states
