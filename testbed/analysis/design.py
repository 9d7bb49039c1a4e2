"""Experiment design: the scenario whose data bound the free coefficients best, before flying it.

The Fisher information of the free coefficients θ of an experiment is computed at a model
(the analytic model, or the estimate of the last fit) from the experiment as that model would
fly it: the linear model with the autopilots closing the loops they hold (`fly_linear`), every
state measured but the depth (which a run does not fit), white sensor noise of
`testbed.simulation.measurements.NOISE_STD`, each experiment's initial state estimated:

    F = Σ_experiments Σ_k (∂ŷ_k/∂θ)ᵀ R⁻¹ (∂ŷ_k/∂θ)      (initial states eliminated)

and the Cramér-Rao bound of θ_i is √(F⁻¹)_ii. Information adds over experiments, so the design
has two levels:

1. per experiment type (`TEMPLATES`: which fin channels a signal drives, which autopilot loops
   hold the others), the signal of each channel — a PRBS (its clock) or a multisine of
   minimal crest factor (its band) — chosen for the criterion on its own; for the elevators'
   experiment also the step of the slow hold's depth reference (`HOLD_STEPS`), whose slow
   heave-pitch motion carries most of the information on the heave row;
2. the split of the flight time between the types (10 s steps, each flown type ≥ 20 s), chosen
   for the criterion of the summed information.

Criteria, on the information of the relative coefficients θ_i/s_i (s_i = |θ_i|; a coefficient
at 0 is measured against the largest |value| of its row): `D` maximises log det F, `A` minimises
trace F⁻¹ (the sum of the relative variances), `E` maximises the smallest eigenvalue of F (the
worst-determined direction).

The amplitudes. The linear regime is the rule that sized Scenario II, measured on the truth
plant (`linearity`): flown noise-free, the analytic model simulated open loop with the flown
inputs tracks it with fit ≥ 99 % on every channel the experiment excites, depth included, and
the second-order residual (the plant minus the analytic model) stays below a fifth of the sensor
noise on every fitted channel. What breaks it is the plant's second-order response (the angular
drag, the drag's growth with incidence, which the depth integrates), and how far a signal can go
before it does depends on its spectrum and on the record's length, so Scenario II's peaks do not
carry over to another signal. The shapes are ranked with their peaks at Scenario II's on the
design model (`Limits`, `largest`: linear, no flight); the chosen one is then grown on the truth
plant to the largest amplitude the rule allows (`grow`), and the flown design is checked again
(an experiment that breaks the rule is scaled down until it holds). The sequential design
(`estimates`) checks the rule on the same plant (`mjcf`), its stand-in for the vehicle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from testbed.analysis.identifiability import unidentified
from testbed.simulation.autopilot import FIN_LIMIT, Autopilot, fly_linear
from testbed.data import Experiment, ModelConfig, check_free, read_estimates as data_read_estimates
from testbed.errors import InputError, atomic_write_text, check_outputs
from testbed.identification import bounds
from testbed.identification.bounds import crlb
from testbed.identification.prediction import predict
from testbed.simulation.measurements import NOISE_STD
from testbed.simulation.recording import (
    STYLE,
    axis_range,
    data_id,
    panel_title,
    recording,
    series,
    time_column,
    x_range,
)
from testbed.models.linear import COEFFICIENTS, INPUTS, IX, NX, STATES, continuous, structure, theta_vector
from testbed.simulation.scenario import (
    ExperimentSpec,
    Scenario,
    fly_scenario,
    program,
    scenario,
    scenario_text,
)
from testbed.simulation.signals import TAPS, Hold, Multisine, Prbs, Signal, Square
from testbed.simulation.analytic import analytic_config, model_config
from testbed.analysis.validation import fit_percent

CRITERIA = ("D", "A", "E")
FIN_RATE = 2.0  # rad/s, the servos' slew rate (the plant's and fly_linear's)
STEP = 10.0  # s, the grid of the time split
MIN_EXPERIMENT = 20.0  # s, the shortest experiment of a split
# s, the longest record: the depth integrates the second-order pitch drift (it grows as the cube
# of the time), and Scenario II's regime was measured on 60 s records; more time for a type is
# flown as several records (each its own initial state and PRBS phase)
MAX_EXPERIMENT = 60.0
SEED = 1  # the PRBS phases and noise streams the design is evaluated and flown with
CHECK_SEEDS = (0, 1, 2)  # the PRBS phases the flown design is checked with (simulate's default: 0)
GROWTH_MARGIN = 0.7  # the rule's tolerances an amplitude is grown to: a margin for other phases
FITTED = tuple(s for s in STATES if s != "z")  # a run's model.toml fits every state but depth
RESIDUAL_LIMIT = 0.2  # second-order residual / sensor noise on fitted channels (Scenario II's rule)
FIT_LIMIT = 99.0  # % fit of the analytic model on every excited channel, depth included
SHRINK = 0.8  # amplitude factor per failed linearity check
MAX_SHRINKS = 6

# Experiment types: the channels a designed signal drives, the loops that hold the others, and
# the channels each excites (the ones the linearity check holds to the fit rule). The rudder and
# the differential elevator are not driven together: the roll-yaw coupling of the real body is
# second order, and with both at half of their single-channel amplitudes the truth's roll rate
# already departs from the linear model by 0.23 of the gyro noise (fit of p 98.2 %).
TEMPLATES = {
    "horizontal": dict(
        channels=("rudder",), autopilot={"depth": 0.0, "roll": 0.0}, hold=False, excited=("v", "r", "psi")
    ),
    "vertical": dict(channels=("elevators",), autopilot={}, hold=True, excited=("w", "q", "theta", "z")),
    "roll": dict(channels=("differential",), autopilot={"depth": 0.0}, hold=False, excited=("p", "phi")),
}
# The elevators' experiment: its slow hold's depth reference steps once, at the middle of the
# record, by one of these (m; Scenario II's steps 3 m every 15 s).
HOLD_STEPS = (3.0, 6.0, 9.0, 12.0)
SCENARIO_HOLD = 3.0  # m, the hold step the shapes are ranked with
GROWTH = 16.0  # the largest factor an amplitude is grown by on the truth plant
GROWTH_BISECTIONS = 4  # after the doubling: the factor found to within 2^(1/16), 4.4 %
PRBS_CLOCKS = (0.1, 0.2, 0.5, 1.0, 2.0)  # s
MULTISINE_BANDS = ((0.0, 0.3), (0.0, 1.0), (0.0, 3.0))  # Hz; 0: from the record's fundamental
MULTISINE_LINES = 24  # at most, log-spaced harmonics of the record's fundamental
REFERENCE = 1e-3  # rad, the amplitude a shape is simulated at before it is scaled to the bounds


@dataclass(frozen=True)
class Limits:
    """Peak bounds of the linear regime: rates rad/s, angles rad, velocities m/s."""

    yaw_rate: float
    pitch_rate: float
    roll_rate: float
    sideslip: float  # |v|/U, rad
    heave: float  # |w|, m/s
    pitch: float
    roll: float
    fin: float = FIN_LIMIT
    fin_rate: float = FIN_RATE

    def ratios(self, peaks: Mapping[str, float]) -> dict[str, float]:
        """Each peak over its bound (≤ 1 inside the regime)."""
        return {k: peaks[k] / getattr(self, k) for k in peaks}

    def table(self) -> str:
        deg = math.degrees
        return (
            f"yaw rate {deg(self.yaw_rate):.2f} deg/s, pitch rate {deg(self.pitch_rate):.2f} deg/s, "
            f"roll rate {deg(self.roll_rate):.2f} deg/s, sideslip {deg(self.sideslip):.3f} deg, "
            f"heave {self.heave:.4f} m/s, pitch {deg(self.pitch):.2f} deg, roll {deg(self.roll):.2f} deg, "
            f"fin {self.fin:g} rad, fin rate {self.fin_rate:g} rad/s"
        )


def peaks(xs: np.ndarray, fins: np.ndarray, speed: float, dt: float) -> dict[str, float]:
    """The limited quantities' peaks over a flight (states (N, 10), fin angles (N, 3))."""
    i = IX
    return {
        "yaw_rate": float(np.abs(xs[:, i["r"]]).max()),
        "pitch_rate": float(np.abs(xs[:, i["q"]]).max()),
        "roll_rate": float(np.abs(xs[:, i["p"]]).max()),
        "sideslip": float(np.abs(xs[:, i["v"]]).max() / speed),
        "heave": float(np.abs(xs[:, i["w"]]).max()),
        "pitch": float(np.abs(xs[:, i["theta"]]).max()),
        "roll": float(np.abs(xs[:, i["phi"]]).max()),
        "fin": float(np.abs(fins).max()),
        "fin_rate": float(np.abs(np.diff(fins, axis=0)).max() / dt),
    }


# -- the model the design is made at ---------------------------------------------------------------


@dataclass(frozen=True)
class Model:
    """The linear model and its autopilots: what the design simulates and differentiates."""

    config: ModelConfig  # coefficients; `free` the ones designed for; outputs: every state but z
    A: np.ndarray
    B: np.ndarray
    autopilot: Autopilot
    noise_std: Mapping[str, float]
    control_rate: float = 50.0
    depth: float = 100.0

    @property
    def speed(self) -> float:
        return self.config.vehicle.speed


def model(
    config: ModelConfig, noise_std: Mapping[str, float] | None = None, control_rate: float = 50.0
) -> Model:
    """The design model of `config` (its coefficients, its free list), autopilots designed on it."""
    A, B, _ = continuous(structure(config.vehicle), theta_vector(config.coefficients))
    if not np.all(np.isfinite(A)) or np.linalg.eigvals(A).real.max() > 1e-6:
        raise InputError(
            f"{config.source or 'model'}: the linear model is unstable or not finite; "
            "expected coefficients of a stable vehicle to design at"
        )
    speed = config.vehicle.speed
    ap = Autopilot.designed(A, B, speed, 1.0 / control_rate)
    config = replace(config, outputs=FITTED)
    return Model(config, A, B, ap, dict(noise_std or NOISE_STD), control_rate)


def fly_model(m: Model, e: ExperimentSpec, duration: float, seed: int = SEED, index: int = 0):
    """Experiment `e` flown by the linear model with its autopilots: (t, states, fin angles)."""
    s = Scenario(name="design", experiments=(e,), speed=m.speed, depth=m.depth, control_rate=m.control_rate)
    x0 = np.zeros(NX)
    x0[IX["z"]] = m.depth
    m.autopilot.reset()
    return fly_linear(m.A, m.B, m.autopilot, program(s, e, seed, index), duration, x0, FIN_RATE)


def experiment(m: Model, t: np.ndarray, xs: np.ndarray, fins: np.ndarray, name: str = "design") -> Experiment:
    """A flight of `fly_model` as noise-free data: every state (u absolute) and the fin angles."""
    y = xs.copy()
    y[:, IX["u"]] += m.speed
    return Experiment(name, t, STATES, y, fins)


def fisher(m: Model, t: np.ndarray, xs: np.ndarray, fins: np.ndarray, name: str = "design") -> np.ndarray:
    """Fisher information of `m.config.free` from one noise-free experiment (initial states
    eliminated), with the sensor noise `m.noise_std`."""
    e = experiment(m, t, xs, fins, name)
    return bounds.fisher(m.config.fitted([e]), m.config, noise_std=m.noise_std)


# -- criteria ----------------------------------------------------------------------------------------


def scales(config: ModelConfig) -> np.ndarray:
    """s_i of the relative coefficients: |θ_i|, or for a coefficient at 0 the largest |value| of
    its row's coefficients."""
    out = []
    for n in config.free:
        v = abs(config.coefficients.get(n, 0.0))
        if v == 0:
            row = [abs(config.coefficients.get(c, 0.0)) for c in COEFFICIENTS if c[0] == n[0]]
            v = max(row) if max(row) > 0 else 1.0
        out.append(v)
    return np.array(out)


def criterion(F: np.ndarray, s: np.ndarray, kind: str) -> float:
    """The design criterion of information `F` (free coefficients) at scales `s`; larger is better."""
    Fr = F * np.outer(s, s)
    w = np.linalg.eigvalsh((Fr + Fr.T) / 2)
    if w.min() <= 1e-12 * max(w.max(), 1e-300):
        return -math.inf
    if kind == "D":
        return float(np.sum(np.log(w)))
    if kind == "A":
        return -float(np.sum(1.0 / w))
    if kind == "E":
        return float(w.min())
    raise InputError(f"criterion={kind!r}; expected one of {', '.join(CRITERIA)}")


# -- the linear regime ---------------------------------------------------------------------------------


def regime_limits(m: Model, base: Scenario | str = "II") -> Limits:
    """The peaks Scenario II's experiments reach on the design model (at 60 s each): the
    largest of each quantity over its experiments, each its own experiment type's bound."""
    base = scenario(base)
    worst: dict[str, float] = {}
    for k, e in enumerate(base.experiments):
        t, xs, fins = fly_model(m, e, base.duration_of(e), SEED, k)
        for key, v in peaks(xs, fins, m.speed, 1.0 / m.control_rate).items():
            worst[key] = max(worst.get(key, 0.0), v)
    return Limits(
        **{k: worst[k] for k in ("yaw_rate", "pitch_rate", "roll_rate", "sideslip", "heave", "pitch", "roll")}
    )


# -- signals ---------------------------------------------------------------------------------------------


def candidates(duration: float) -> list[Signal]:
    """The signal shapes (amplitude REFERENCE) tried on each channel: PRBS at each clock (its order
    the shortest whose period covers the record), multisines over each band with the phases of
    the smallest crest factor found (`signals.min_crest_phases`: the most power for the peak)."""
    out: list[Signal] = []
    for clock in PRBS_CLOCKS:
        order = next((n for n in sorted(TAPS) if (2**n - 1) * clock >= duration), max(TAPS))
        out.append(Prbs(amplitude=REFERENCE, order=max(order, 5), clock=clock))
    for lo, hi in MULTISINE_BANDS:
        out.append(Multisine(amplitude=REFERENCE, frequencies=band(duration, lo, hi), phases="min-crest"))
    return out


def band(duration: float, lo: float, hi: float, lines: int = MULTISINE_LINES) -> tuple:
    """Harmonics of the record's fundamental 1/duration in [lo, hi] Hz, at most `lines` of them
    log-spaced (a flat-amplitude multisine then puts its power where the vehicle responds)."""
    f0 = 1.0 / duration
    k_lo, k_hi = max(1, math.ceil(lo / f0 - 1e-9)), max(2, math.floor(hi / f0 + 1e-9))
    ks = np.unique(np.round(np.geomspace(k_lo, k_hi, 4 * lines)).astype(int))
    if len(ks) > lines:
        ks = ks[np.unique(np.round(np.linspace(0, len(ks) - 1, lines)).astype(int))]
    return tuple(round(float(k * f0), 9) for k in ks)


def scaled(sig: Signal, amplitude: float) -> Signal:
    return replace(sig, amplitude=float(amplitude))


def hold_signal(step: float, duration: float) -> Square:
    """The slow hold's depth reference: the initial depth, then `step` m deeper from the
    middle of the record."""
    return Square(amplitude=step / 2, half_period=duration / 2, offset=step / 2, first=-1)


def spec(
    kind: str,
    fins: Mapping[str, Signal],
    duration: float | None = None,
    name: str | None = None,
    hold: float | None = None,
) -> ExperimentSpec:
    """The experiment of type `kind` with these fin signals (`hold`: the hold's depth step, m,
    of a type whose slow hold moves the depth; `duration` its record, default 60 s)."""
    tpl = TEMPLATES[kind]
    fixed = {"rudder": Hold(0.0)} if kind in ("vertical", "roll") else {}  # the rudder held at 0
    step = SCENARIO_HOLD if hold is None else hold
    return ExperimentSpec(
        name=name or kind,
        fins={**fins, **fixed},
        autopilot={k: Hold(float(v)) for k, v in tpl["autopilot"].items()},
        hold_depth=hold_signal(step, duration or MAX_EXPERIMENT) if tpl["hold"] else None,
        duration=duration,
    )


def largest(m: Model, kind: str, fins: Mapping[str, Signal], limits: Limits, duration: float) -> float:
    """The largest factor c such that the experiment with the fin amplitudes times c stays
    within `limits` (the model and autopilots are linear: the response is the part with the
    signals at zero plus c times the signals' part)."""
    dt = 1.0 / m.control_rate
    zero = {c: scaled(s, 0.0) for c, s in fins.items()}
    _, x0s, f0s = fly_model(m, spec(kind, zero, duration), duration)
    _, x1s, f1s = fly_model(m, spec(kind, fins, duration), duration)
    dx, df = x1s - x0s, f1s - f0s

    def ok(c):
        return max(limits.ratios(peaks(x0s + c * dx, f0s + c * df, m.speed, dt)).values()) <= 1.0

    if not ok(0.0):
        raise InputError(f"the {kind} experiment leaves the linear regime with its signals at zero")
    hi = 1.0
    while ok(hi) and hi < 1e6:
        hi *= 2.0
    lo = 0.0 if not ok(hi / 2) else hi / 2
    for _ in range(30):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if ok(mid) else (lo, mid)
    return lo


@dataclass(frozen=True)
class Candidate:
    """One experiment type with its signals (and hold step) and its information over `duration`."""

    kind: str
    fins: Mapping[str, Signal]
    duration: float
    fisher: np.ndarray
    hold: float | None = None  # the slow hold's depth step, m (types whose hold moves the depth)
    growth: float = 1.0  # the factor the truth plant allowed over Scenario II's peaks

    def spec(self, duration: float | None = None, name: str | None = None) -> ExperimentSpec:
        return spec(self.kind, self.fins, duration, name, self.hold)


def information(
    m: Model,
    kind: str,
    fins: Mapping[str, Signal],
    duration: float,
    hold: float | None = None,
    growth: float = 1.0,
) -> Candidate:
    """The candidate of these signals: its information flown on the design model."""
    t, xs, f = fly_model(m, spec(kind, fins, duration, hold=hold), duration)
    return Candidate(kind, fins, duration, fisher(m, t, xs, f, kind), hold, growth)


def evaluate(m: Model, kind: str, fins: Mapping[str, Signal], limits: Limits, duration: float) -> Candidate:
    """The experiment scaled to the regime's peak bounds and its Fisher information."""
    c = largest(m, kind, fins, limits, duration)
    return information(
        m, kind, {ch: scaled(s, float(f"{s.amplitude * c:.3g}")) for ch, s in fins.items()}, duration
    )


def grow(m: Model, cand: Candidate, mjcf=None) -> Candidate:
    """`cand` with its fin amplitudes times the largest factor g ≤ GROWTH at which its
    experiment, flown noise-free on the truth plant, keeps the rule of the linear regime
    (`linearity`); g < 1 when the candidate breaks it as it is. The factor is doubled until
    the rule breaks, then bisected (GROWTH_BISECTIONS times, in log2)."""
    excited = {cand.kind: TEMPLATES[cand.kind]["excited"]}

    def fins(g):
        return {ch: scaled(s, float(f"{s.amplitude * g:.3g}")) for ch, s in cand.fins.items()}

    def passes(g):
        e = spec(cand.kind, fins(g), cand.duration, cand.kind, cand.hold)
        s = Scenario(name="growth", experiments=(e,), duration=cand.duration)
        return linearity(s, excited, mjcf).passed(cand.kind, GROWTH_MARGIN)

    lo, hi = (1.0, 2.0) if passes(1.0) else (SHRINK**MAX_SHRINKS, 1.0)
    if lo == 1.0:
        while hi <= GROWTH and passes(hi):
            lo, hi = hi, 2 * hi
    elif not passes(lo):
        raise InputError(
            f"the {cand.kind} experiment breaks the linear regime even at {lo:.2g} of its amplitude"
        )
    for _ in range(GROWTH_BISECTIONS):
        mid = math.sqrt(lo * hi)
        lo, hi = (mid, hi) if passes(mid) else (lo, mid)
    return information(m, cand.kind, fins(lo), cand.duration, cand.hold, lo)


def best_signals(
    m: Model, limits: Limits, kind_: str, duration: float = MAX_EXPERIMENT, mjcf=None, check: bool = True
) -> dict[str, Candidate]:
    """Per single-channel experiment type, the best signal for criterion `kind_`, each
    experiment completed by Scenario II's information (a type is judged by what it adds):
    the shapes ranked at Scenario II's peaks, the best grown on the truth plant (`check`),
    for the elevators' experiment with each hold step of HOLD_STEPS."""
    base = scenario_information(m, 3 * duration)
    s = scales(m.config)

    def value(c: Candidate) -> float:
        return criterion(base + c.fisher, s, kind_)

    out = {}
    for kind in ("horizontal", "vertical", "roll"):
        (channel,) = TEMPLATES[kind]["channels"]
        tried = [evaluate(m, kind, {channel: sig}, limits, duration) for sig in candidates(duration)]
        best = max(tried, key=value)
        if not check:
            out[kind] = best
            continue
        holds = HOLD_STEPS if TEMPLATES[kind]["hold"] else (None,)
        grown = [grow(m, replace(best, hold=h), mjcf) for h in holds]
        out[kind] = max(grown, key=value)
    return out


# -- the time split ---------------------------------------------------------------------------------------


def split(cands: Mapping[str, Candidate], total: float, s: np.ndarray, kind: str) -> dict[str, float]:
    """Durations per experiment type (STEP grid, 0 or ≥ MIN_EXPERIMENT, summing to `total`)
    maximising the criterion of Σ (T_k / T_ref) F_k."""
    names = list(cands)
    rate = [cands[n].fisher / cands[n].duration for n in names]
    steps = int(round(total / STEP))
    best, best_value = None, -math.inf

    def walk(i, left, chosen):
        nonlocal best, best_value
        if i == len(names) - 1:
            durations = chosen + [left * STEP]
            if any(0 < d < MIN_EXPERIMENT for d in durations):
                return
            F = sum(d * r for d, r in zip(durations, rate))
            v = criterion(F, s, kind)
            if v > best_value:
                best, best_value = durations, v
            return
        for k in range(left + 1):
            walk(i + 1, left - k, chosen + [k * STEP])

    walk(0, steps, [])
    if best is None:
        raise InputError(
            f"duration={total:g} s: no split of it identifies every free coefficient; "
            "expected a longer flight or fewer free coefficients"
        )
    return {n: d for n, d in zip(names, best) if d > 0}


def scenario_flights(m: Model, total: float, base: Scenario | str = "II") -> list[Experiment]:
    """Scenario II flown by the design model for `total` s (split evenly, as it is)."""
    base = scenario(base)
    each = total / len(base.experiments)
    return [experiment(m, *fly_model(m, e, each, SEED, k), e.name) for k, e in enumerate(base.experiments)]


def scenario_information(m: Model, total: float, base: Scenario | str = "II") -> np.ndarray:
    """Fisher information of Scenario II flown for `total` s."""
    F = 0.0
    for e in scenario_flights(m, total, base):
        F = F + bounds.fisher(m.config.fitted([e]), m.config, noise_std=m.noise_std)
    return F


def identified(m: Model, total: float) -> dict[str, str]:
    """The free coefficients that Scenario II flown for `total` s leaves undetermined, by the
    rule `identify` screens with (`analysis.unidentified`: its data are the design model's own,
    so its estimates are the model's coefficients), with the reason. The design leaves them out
    by default: they would dominate any criterion, and the regime's amplitudes cannot bring them
    within reach."""
    return unidentified(scenario_flights(m, total), m.config, m.noise_std)


# -- the check on the truth plant --------------------------------------------------------------------------


@dataclass(frozen=True)
class Linearity:
    """Per experiment, the worst over the seeds flown: the lowest fit of the analytic model on
    its excited channels, and the largest second-order residual over the sensor noise on the
    fitted channels."""

    fit: Mapping[str, tuple[str, float]]  # experiment -> (channel, fit %)
    residual: Mapping[str, tuple[str, float]]  # experiment -> (channel, rms residual / noise)
    speed_loss: Mapping[str, float]  # experiment -> peak speed loss, fraction of U
    seeds: tuple[int, ...] = (SEED,)

    def passed(self, name: str, margin: float = 1.0) -> bool:
        """The rule, its two tolerances (100 % − fit, residual) times `margin` (≤ 1: stricter)."""
        return (
            self.fit[name][1] >= 100.0 - margin * (100.0 - FIT_LIMIT)
            and self.residual[name][1] < margin * RESIDUAL_LIMIT
        )

    def table(self) -> str:
        return "\n".join(
            f"{n}: lowest fit {c} {f:.2f} %, largest second-order residual "
            f"{self.residual[n][0]} {self.residual[n][1]:.3f} of the noise, speed loss "
            f"{100 * self.speed_loss[n]:.3f} %"
            for n, (c, f) in self.fit.items()
        )


def linearity(
    s: Scenario, excited: Mapping[str, Sequence[str]], mjcf=None, seeds: Sequence[int] = (SEED,)
) -> Linearity:
    """Fly `s` noise-free on the truth plant with each seed's PRBS phases; compare with the
    analytic model simulated open loop with the flown inputs from the first sample (`excited`:
    experiment -> its channels). The worst over the seeds."""
    fit, residual, loss = {}, {}, {}
    for seed in seeds:
        flights, lin = fly_scenario(s, seed=seed, mjcf=mjcf)
        config = model_config(lin)[0]
        truth = [Experiment(f.name, f.t, STATES, f.truth, f.fins) for f in flights]
        start = {e.name: dict(zip(STATES, e.y[0])) for e in truth}
        U = lin.vehicle.speed
        for e, yhat in zip(truth, predict(truth, config, start)):
            fits = {c: fit_percent(e.column(c), yhat[:, IX[c]]) for c in excited[e.name]}
            res = {c: float(np.std(e.column(c) - yhat[:, IX[c]])) / s.sensors.noise_std[c] for c in FITTED}
            c1, c2 = min(fits, key=fits.get), max(res, key=res.get)
            if e.name not in fit or fits[c1] < fit[e.name][1]:
                fit[e.name] = (c1, fits[c1])
            if e.name not in residual or res[c2] > residual[e.name][1]:
                residual[e.name] = (c2, res[c2])
            loss[e.name] = max(loss.get(e.name, 0.0), float((U - e.column("u").min()) / U))
    return Linearity(fit, residual, loss, tuple(seeds))


# -- the design ------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Design:
    """A designed scenario with its predicted bounds, and Scenario II's at the same flight time."""

    scenario: Scenario
    criterion: str
    free: tuple[str, ...]
    values: np.ndarray  # the coefficients designed at
    crlb: np.ndarray  # predicted Cramér-Rao std of the design
    crlb_base: np.ndarray  # of Scenario II at the same flight time
    limits: Limits
    linearity: Linearity | None
    shrinks: Mapping[str, int] = field(default_factory=dict)  # experiment -> amplitude reductions
    source: str = "analytic model"
    # type -> (factor grown over Scenario II's peaks, the hold's depth step in m or None)
    growth: Mapping[str, tuple[float, float | None]] = field(default_factory=dict)
    peaks: Mapping[str, Mapping[str, float]] = field(default_factory=dict)  # experiment -> `peaks`
    left_out: Mapping[str, str] = field(default_factory=dict)  # free coefficients not designed for, and why
    flights: tuple[Experiment, ...] = ()  # the designed experiments as the design model flies them

    @property
    def duration(self) -> float:
        return sum(self.scenario.duration_of(e) for e in self.scenario.experiments)

    def relative(self, std: np.ndarray) -> np.ndarray:
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(self.values != 0, std / np.abs(self.values), np.nan)

    def worst(self) -> tuple[tuple[str, float], tuple[str, float]]:
        """The largest relative bound of the design and of Scenario II (name, value)."""
        out = []
        for std in (self.crlb, self.crlb_base):
            r = self.relative(std)
            k = int(np.nanargmax(r))
            out.append((self.free[k], float(r[k])))
        return tuple(out)

    COLUMNS = ("coefficient", "value", "design σ", "design %", "II σ", "II %", "II/design")

    def rows(self) -> list[tuple[str, ...]]:
        """Per coefficient, formatted (`COLUMNS`): value, predicted bound and relative bound (%)
        of the design and of Scenario II at the same flight time, and their ratio."""
        rel = 100 * self.relative(self.crlb), 100 * self.relative(self.crlb_base)
        return [
            (
                n,
                f"{v:.4g}",
                f"{a:.3g}",
                f"{ra:.3g}" if v else "-",
                f"{b:.3g}",
                f"{rb:.3g}" if v else "-",
                f"{b / a:.2f}",
            )
            for n, v, a, b, ra, rb in zip(self.free, self.values, self.crlb, self.crlb_base, *rel)
        ]

    def summary(self) -> str:
        (n1, w1), (n2, w2) = self.worst()
        return (
            f"worst relative bound: design {100 * w1:.3g} % ({n1}), Scenario II {100 * w2:.3g} % ({n2}), "
            f"{self.duration:g} s each"
        )

    def table(self) -> str:
        """`rows` under `COLUMNS`, fixed width, then the worst relative bounds."""
        widths = (12, 12, 11, 10, 11, 10, 10)

        def line(cells):  # the name left-aligned, the numbers right-aligned
            return "".join(
                f"{c:<{w}}" if k == 0 else f"{c:>{w}}" for k, (c, w) in enumerate(zip(cells, widths))
            )

        return "\n".join([line(self.COLUMNS), *map(line, self.rows()), self.summary()])

    def text(self) -> str:
        """The scenario file, its header comments giving how it was designed and the bounds."""
        deg = math.degrees
        head = [
            f"Designed experiment ({self.criterion}-optimal Fisher information of {len(self.free)} free "
            f"coefficients at the {self.source}), {self.duration:g} s of flight."
        ]
        if self.left_out:
            head += ["Left out (Scenario II at this flight time does not identify them; --free to choose):"]
            head += [f"  {n}: {why}" for n, why in self.left_out.items()]
        head += [
            "Signal shapes ranked with their peaks at Scenario II's on the same model:",
            "  " + self.limits.table(),
        ]
        if self.growth:
            head += [
                "then grown on the truth plant to the largest amplitude that keeps the linear "
                f"regime's rule with its tolerances x{GROWTH_MARGIN:g}: "
                + ", ".join(
                    f"{k} x{g:.2f}"
                    + ("" if h is None else f" (its hold steps the depth {h:g} m at mid-record)")
                    for k, (g, h) in self.growth.items()
                )
            ]
        head += ["Peaks on the design model:"]
        head += [
            f"  {n}: yaw rate {deg(p['yaw_rate']):.2f} deg/s, pitch rate {deg(p['pitch_rate']):.2f} deg/s, "
            f"roll rate {deg(p['roll_rate']):.2f} deg/s, sideslip {deg(p['sideslip']):.3f} deg, "
            f"pitch {deg(p['pitch']):.2f} deg, roll {deg(p['roll']):.2f} deg, fin {deg(p['fin']):.3f} deg"
            for n, p in self.peaks.items()
        ]
        if self.linearity is not None:
            head += [
                "Flown noise-free on the truth plant with the PRBS phases of seeds "
                f"{', '.join(map(str, self.linearity.seeds))}, the worst (the rule: fit >= 99 % on "
                "excited channels, second-order residual < 0.2 of the noise on fitted channels):"
            ]
            head += ["  " + line for line in self.linearity.table().splitlines()]
        head += [
            "Predicted Cramér-Rao bounds (sensor noise of the scenario's sensors), against the "
            "paper's Scenario II at the same flight time:"
        ]
        head += ["  " + line for line in self.table().splitlines()]
        return "".join(f"# {line}\n" for line in head) + "\n" + scenario_text(self.scenario)


def design(
    duration: float = 180.0,
    criterion_: str = "A",
    free: Sequence[str] | None = None,
    mjcf=None,
    speed: float | None = None,
    estimates: Mapping[str, float] | None = None,
    noise_std: Mapping[str, float] | None = None,
    check: bool = True,
) -> Design:
    """Design a scenario of `duration` s in total for the criterion (`D`, `A`, `E`) of the
    Fisher information of `free` (default: the analytic model's free list) at the analytic
    model of `mjcf` at `speed`, or at `estimates` (coefficient -> value, e.g. the last fit's:
    the sequential design). `check`: fly it on the truth plant and scale down any experiment
    that leaves the linear regime."""
    if criterion_ not in CRITERIA:
        raise InputError(f"criterion={criterion_!r}; expected one of {', '.join(CRITERIA)}")
    if not (
        isinstance(duration, (int, float)) and math.isfinite(duration) and duration >= 2 * MIN_EXPERIMENT
    ):
        raise InputError(f"duration={duration!r}; expected at least {2 * MIN_EXPERIMENT:g} s")
    config = analytic_config(mjcf, speed)[0]
    source = "analytic model"
    if estimates:
        unknown = sorted(set(estimates) - set(COEFFICIENTS))
        if unknown:
            raise InputError(
                f"estimates: {unknown[0]!r} is not a coefficient name; expected one of the linear model's 35 (docs/model.md)"
            )
        config = config.with_coefficients(dict(estimates))
        source = "estimate"
        free = free if free is not None else tuple(n for n in COEFFICIENTS if n in estimates)
    if free is not None:
        if not free:
            raise InputError("free is empty; expected coefficient names, e.g. Y_v,N_r")
        free = check_free(free, "free")
        config = replace(config, free=tuple(n for n in COEFFICIENTS if n in free))
    m = model(config, noise_std)
    left_out = {} if free is not None else identified(m, duration)
    if left_out:
        m = replace(m, config=replace(m.config, free=tuple(n for n in m.config.free if n not in left_out)))
    limits = regime_limits(m)
    s = scales(m.config)
    cands = best_signals(m, limits, criterion_, mjcf=mjcf, check=check)
    durations = split(cands, duration, s, criterion_)
    records = {}  # experiment name -> (type, duration)
    for k, d in durations.items():
        n = math.ceil(d / MAX_EXPERIMENT - 1e-9)
        for i in range(n):
            records[k if i == 0 else f"{k}-{i + 1}"] = (k, d / n)
    kinds = {name: k for name, (k, _) in records.items()}
    experiments = tuple(cands[k].spec(d, name) for name, (k, d) in records.items())
    scn = Scenario(
        name="designed",
        experiments=experiments,
        duration=max(d for _, d in records.values()),
        description=f"{criterion_}-optimal experiments for {len(m.config.free)} coefficients "
        f"within Scenario II's linear regime, {duration:g} s",
    )
    check_result, shrinks = None, {e.name: 0 for e in experiments}
    if check:
        excited = {name: TEMPLATES[k]["excited"] for name, k in kinds.items()}
        for _ in range(MAX_SHRINKS + 1):
            check_result = linearity(scn, excited, mjcf, CHECK_SEEDS)
            failed = [e for e in scn.experiments if not check_result.passed(e.name)]
            if not failed or max(shrinks.values()) >= MAX_SHRINKS:
                break
            for e in failed:
                shrinks[e.name] += 1
            scn = replace(
                scn,
                experiments=tuple(
                    replace(
                        e,
                        fins={
                            c: scaled(sig, float(f"{sig.amplitude * SHRINK:.3g}"))
                            if e in failed and c in TEMPLATES[kinds[e.name]]["channels"]
                            else sig
                            for c, sig in e.fins.items()
                        },
                    )
                    for e in scn.experiments
                ),
            )
        if any(not check_result.passed(e.name) for e in scn.experiments):
            raise InputError(f"no design inside the linear regime: {check_result.table()}")
    F, flown_peaks, flights = 0.0, {}, []
    for k, e in enumerate(scn.experiments):
        t, xs, f = fly_model(m, e, scn.duration_of(e), SEED, k)
        F = F + fisher(m, t, xs, f, e.name)
        flown_peaks[e.name] = peaks(xs, f, m.speed, 1.0 / m.control_rate)
        flights.append(experiment(m, t, xs, f, e.name))
    base = scenario_information(m, duration)
    return Design(
        scenario=scn,
        criterion=criterion_,
        free=m.config.free,
        values=np.array([m.config.coefficients[n] for n in m.config.free]),
        crlb=crlb(F).std,
        crlb_base=crlb(base).std,
        limits=limits,
        linearity=check_result,
        shrinks=shrinks,
        source=source,
        growth={k: (c.growth, c.hold) for k, c in cands.items() if k in durations},
        peaks=flown_peaks,
        left_out=left_out,
        flights=tuple(flights),
    )


BOUNDS_KEY = (
    "relative Cramér-Rao bound (%) of each free coefficient, in the order of the table: "
    "bold blue, the design; grey, Scenario II at the same flight time"
)
MOVED = 1e-9  # a flight's channel spanning less than this (rad, m/s, m) is not drawn
FLIGHTS_KEY = "the designed experiment as the design model flies it (the linear model with its autopilots)"


def log_design(path: str | Path, d: Design) -> Path:
    """A Rerun recording of a design: the `bounds` tab (per free coefficient the predicted
    relative Cramér-Rao bound of the design beside Scenario II's at the same flight time, as
    paired bars, with the table), then per designed experiment its fin angles and states as
    the design model flies it."""
    title = "testbed design"
    rel = {"design": d.relative(d.crlb), "scenario_II": d.relative(d.crlb_base)}
    k = np.arange(len(d.free), dtype=float)
    tabs = []
    with recording(path, title, data_id(title, d.text())) as rec:
        for (label, r), offset, role in zip(rel.items(), (-0.2, 0.2), ("estimate", "measured")):
            bars = rr.BarChart(
                np.nan_to_num(100 * r), color=STYLE[role][0], abscissa=k + offset, widths=np.full(len(k), 0.4)
            )
            rec.log(f"/bounds/{label}", bars, static=True)
        table = "\n".join(
            [f"| # | {' | '.join(d.COLUMNS)} |", "|---" * (len(d.COLUMNS) + 1) + "|"]
            + [f"| {i} | {' | '.join(row)} |" for i, row in enumerate(d.rows())]
            + ["", d.summary()]
        )
        rec.log("/bounds/table", rr.TextDocument(table, media_type=rr.MediaType.MARKDOWN), static=True)
        rec.log("/key/bounds", rr.TextDocument(BOUNDS_KEY, media_type=rr.MediaType.MARKDOWN), static=True)
        tabs.append(
            rrb.Horizontal(
                rrb.Vertical(
                    rrb.BarChartView(
                        origin="/bounds", contents=[f"/bounds/{n}" for n in rel], name="relative bounds (%)"
                    ),
                    rrb.TextDocumentView(origin="/key/bounds", name="key", titlebar=False),
                    row_shares=[12, 1],
                ),
                rrb.TextDocumentView(origin="/bounds/table", name="table"),
                column_shares=[3, 2],
                name="bounds",
            )
        )
        rec.log("/key/flights", rr.TextDocument(FLIGHTS_KEY, media_type=rr.MediaType.MARKDOWN), static=True)
        for e in d.flights:
            name, t = e.name, e.t
            columns = {
                **{c: e.inputs[:, j] for j, c in enumerate(INPUTS)},
                **{c: e.column(c) for c in STATES},
            }
            panels = []
            for c, v in columns.items():
                if np.ptp(v) < MOVED:
                    continue  # a channel this experiment does not move (its roundoff is not drawn)
                series(rec, f"/flights/{name}/{c}", time_column(t), v, ("model",), (c,))
                panels.append(
                    rrb.TimeSeriesView(
                        origin=f"/flights/{name}/{c}",
                        name=panel_title(c),
                        axis_x=x_range("time", t[0], t[-1]),
                        axis_y=rrb.ScalarAxis(range=axis_range(v)),
                        plot_legend=rrb.PlotLegend(visible=False),
                    )
                )
            key = rrb.TextDocumentView(origin="/key/flights", name="key", titlebar=False)
            tabs.append(rrb.Vertical(rrb.Grid(*panels, grid_columns=4), key, row_shares=[24, 1], name=name))
        rec.send_blueprint(
            rrb.Blueprint(
                rrb.Tabs(*tabs, active_tab=0), rrb.TimePanel(state="collapsed"), collapse_panels=True
            )
        )
    return Path(path)


def read_estimates(path: str | Path) -> tuple[dict[str, float], dict[str, float] | None]:
    """The coefficients and the noise of an estimates JSON (`data.read_estimates`), the noise
    completed with the sensors' defaults (`measurements.NOISE_STD`) for the states it lacks."""
    values, noise = data_read_estimates(path)
    return values, None if noise is None else {**NOISE_STD, **noise}


def write_design(
    out: str | Path,
    duration: float = 180.0,
    criterion_: str = "A",
    free: Sequence[str] | None = None,
    mjcf=None,
    speed: float | None = None,
    start_from: str | Path | None = None,
    rrd: str | Path | None = None,
) -> Design:
    """`design` at the analytic model of `mjcf`, or at the estimates JSON `start_from` (its
    coefficients and noise: the sequential design), written as a scenario file to `out`, and
    with `rrd` logged to that Rerun recording (`log_design`)."""
    check_outputs([start_from] if start_from else [], {"out": out, "rrd": rrd})
    estimates, noise = read_estimates(start_from) if start_from else (None, None)
    result = design(duration, criterion_, free, mjcf, speed, estimates, noise)
    atomic_write_text(out, result.text())
    if rrd is not None:
        log_design(rrd, result)
    return result
