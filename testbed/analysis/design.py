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
(`estimates`) checks the rule on the same plant (`mjcf`), its stand-in for the vehicle. The fins'
range and slew rate are the MJCF's (`vehicle.fin_limits`), for the flights and the bounds alike.

The regime's peaks and the check on the truth plant are `testbed.analysis.regime`; the design's
text, scenario file and Rerun recording are `testbed.presentation.design_report`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Mapping, Sequence

import numpy as np

from testbed.analysis.regime import FITTED, SEED, Limits, Linearity, linearity, peaks
from testbed.analysis.screening import unidentified
from testbed.data import Experiment, ModelConfig, check_free
from testbed.errors import InputError
from testbed.identification import bounds
from testbed.identification.bounds import crlb
from testbed.models.linear import (
    COEFFICIENTS,
    IX,
    NX,
    PARAMETERS,
    STATES,
    continuous,
    derivatives,
    inertia_defect,
    structure,
    theta_vector,
)
from testbed.simulation.analytic import analytic, model_config
from testbed.simulation.autopilot import Autopilot, fly_linear
from testbed.simulation.measurements import NOISE_STD
from testbed.simulation.flight import program
from testbed.simulation.scenario import ExperimentSpec, Scenario, scenario
from testbed.simulation.signals import TAPS, Hold, Multisine, Prbs, Signal, Square
from testbed.simulation.vehicle import FinLimits

__all__ = [
    "CHECK_SEEDS",
    "CRITERIA",
    "GROWTH",
    "GROWTH_BISECTIONS",
    "GROWING",
    "GROWTH_MARGIN",
    "HOLD_STEPS",
    "MAX_EXPERIMENT",
    "MAX_SHRINKS",
    "MIN_EXPERIMENT",
    "MULTISINE_BANDS",
    "MULTISINE_LINES",
    "PRBS_CLOCKS",
    "REFERENCE",
    "SCENARIO_HOLD",
    "SHRINK",
    "STEP",
    "TEMPLATES",
    "Candidate",
    "Design",
    "Model",
    "band",
    "best_signals",
    "candidates",
    "criterion",
    "design",
    "evaluate",
    "experiment",
    "fisher",
    "fly_model",
    "grow",
    "hold_signal",
    "identified",
    "information",
    "instability",
    "largest",
    "model",
    "regime_limits",
    "scaled",
    "scales",
    "scenario_flights",
    "scenario_information",
    "spec",
    "split",
]

CRITERIA = ("D", "A", "E")
GROWING = 1e-6  # 1/s: a mode whose real part exceeds it grows (the design model must be stable)
STEP = 10.0  # s, the grid of the time split
MIN_EXPERIMENT = 20.0  # s, the shortest experiment of a split
# s, the longest record: the depth integrates the second-order pitch drift (it grows as the cube
# of the time), and Scenario II's regime was measured on 60 s records; more time for a type is
# flown as several records (each its own initial state and PRBS phase)
MAX_EXPERIMENT = 60.0
CHECK_SEEDS = (0, 1, 2)  # the PRBS phases the flown design is checked with (simulate's default: 0)
GROWTH_MARGIN = 0.7  # the rule's tolerances an amplitude is grown to: a margin for other phases
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


# -- the model the design is made at ---------------------------------------------------------------


@dataclass(frozen=True)
class Model:
    """The linear model and its autopilots: what the design simulates and differentiates."""

    config: ModelConfig  # coefficients; `free` the ones designed for; outputs: every state but z
    A: np.ndarray
    B: np.ndarray
    autopilot: Autopilot
    fins: FinLimits  # the vehicle's fin range and slew rate (its MJCF's)
    noise_std: Mapping[str, float]
    control_rate: float = 50.0
    depth: float = 100.0

    @property
    def speed(self) -> float:
        return self.config.vehicle.speed


def model(
    config: ModelConfig,
    fins: FinLimits,
    noise_std: Mapping[str, float] | None = None,
    control_rate: float = 50.0,
) -> Model:
    """The design model of `config` (its coefficients, its free list), autopilots designed on it,
    with the vehicle's fins `fins`."""
    why = instability(config)
    if why is not None:
        raise InputError(
            f"{config.source or 'model'}: {why}; expected the coefficients of a stable vehicle to design at"
        )
    A, B, _ = continuous(structure(config.vehicle), theta_vector(config.coefficients))
    speed = config.vehicle.speed
    ap = Autopilot.designed(A, B, speed, 1.0 / control_rate, fins.angle)
    config = replace(config, outputs=FITTED)
    return Model(config, A, B, ap, fins, dict(noise_std or NOISE_STD), control_rate)


def instability(config: ModelConfig) -> str | None:
    """Why the linear model of `config` is no vehicle to design at, or None: its Mt is not a
    body's, or it is not finite, or its least stable mode grows. A growing mode is named by its
    largest states (the eigenvector's components) and by the coefficients its growth rate
    depends on most: those of largest |Re ∂λ/∂θ_i · θ_i| (the change of the rate per relative
    change of θ_i, ∂λ/∂θ_i = wᴴ ∂A/∂θ_i v with w, v its left and right eigenvectors, wᴴv = 1)."""
    s, theta = structure(config.vehicle), theta_vector(config.coefficients)
    defect = inertia_defect(s, theta)
    if defect:
        return f"the inertia matrix Mt is not a body's: {defect}"
    A, B, S = continuous(s, theta)
    if not np.all(np.isfinite(A)):
        return "the linear model is not finite"
    lam, V = np.linalg.eig(A)
    k = int(np.argmax(lam.real))
    if lam[k].real <= GROWING:
        return None
    v = np.abs(V[:, k])
    states = [STATES[i] for i in np.argsort(-v)[:3] if v[i] >= 0.1 * v.max()]
    dA = derivatives(s, theta, A, B, S)[0]
    effect = np.abs((np.linalg.inv(V)[k] @ dA @ V[:, k]).real * theta)
    top = [i for i in np.argsort(-effect)[:3] if effect[i] > 0]
    oscillating = (
        f", oscillating at {abs(lam[k].imag) / (2 * np.pi):.3g} Hz" if abs(lam[k].imag) > GROWING else ""
    )
    return (
        f"the linear model is unstable: a mode in {', '.join(states)} grows at {lam[k].real:.3g} 1/s"
        f"{oscillating}; its growth depends most on "
        + ", ".join(f"{COEFFICIENTS[i]} = {theta[i]:.4g}" for i in top)
    )


def fly_model(m: Model, e: ExperimentSpec, duration: float, seed: int = SEED, index: int = 0):
    """Experiment `e` flown by the linear model with its autopilots: (t, states, fin angles)."""
    s = Scenario(name="design", experiments=(e,), speed=m.speed, depth=m.depth, control_rate=m.control_rate)
    x0 = np.zeros(NX)
    x0[IX["z"]] = m.depth
    m.autopilot.reset()
    return fly_linear(m.A, m.B, m.autopilot, program(s, e, seed, index), duration, x0, rate_limit=m.fins.rate)


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
        **{
            k: worst[k] for k in ("yaw_rate", "pitch_rate", "roll_rate", "sideslip", "heave", "pitch", "roll")
        },
        fin=m.fins.angle,
        fin_rate=m.fins.rate,
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


def still(m: Model, kind: str, fins: Mapping[str, Signal], duration: float):
    """The experiment of `kind` flown with its signals `fins` at zero: `fly_model`'s flight, the
    same for every signal of those channels."""
    return fly_model(m, spec(kind, {c: scaled(s, 0.0) for c, s in fins.items()}, duration), duration)


def largest(
    m: Model, kind: str, fins: Mapping[str, Signal], limits: Limits, duration: float, zero=None
) -> float:
    """The largest factor c such that the experiment with the fin amplitudes times c stays
    within `limits` (the model and autopilots are linear: the response is the part with the
    signals at zero plus c times the signals' part). `zero`: `still`'s flight, if flown."""
    dt = 1.0 / m.control_rate
    _, x0s, f0s = still(m, kind, fins, duration) if zero is None else zero
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


def evaluate(
    m: Model, kind: str, fins: Mapping[str, Signal], limits: Limits, duration: float, zero=None
) -> Candidate:
    """The experiment scaled to the regime's peak bounds and its Fisher information (`zero`:
    `still`'s flight, if flown)."""
    c = largest(m, kind, fins, limits, duration, zero)
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
        signals = candidates(duration)
        zero = still(m, kind, {channel: signals[0]}, duration)  # the same for every signal
        tried = [evaluate(m, kind, {channel: sig}, limits, duration, zero) for sig in signals]
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


def design(
    duration: float = 180.0,
    criterion_: str = "A",
    free: Sequence[str] | None = None,
    mjcf=None,
    speed: float | None = None,
    estimates: Mapping[str, float] | None = None,
    noise_std: Mapping[str, float] | None = None,
    check: bool = True,
    estimates_source: str = "estimates",
) -> Design:
    """Design a scenario of `duration` s in total for the criterion (`D`, `A`, `E`) of the
    Fisher information of `free` (default: the analytic model's free list) at the analytic
    model of `mjcf` at `speed`, or at `estimates` (coefficient -> value, e.g. the last fit's:
    the sequential design; `estimates_source`: where they were read, for the errors). `check`:
    fly it on the truth plant and scale down any experiment that leaves the linear regime.
    InputError where the model designed at is no stable vehicle (`instability`)."""
    if criterion_ not in CRITERIA:
        raise InputError(f"criterion={criterion_!r}; expected one of {', '.join(CRITERIA)}")
    if not (
        isinstance(duration, (int, float)) and math.isfinite(duration) and duration >= 2 * MIN_EXPERIMENT
    ):
        raise InputError(f"duration={duration!r}; expected at least {2 * MIN_EXPERIMENT:g} s")
    lin = analytic(mjcf, speed)
    config = model_config(lin, mjcf)[0]
    source = "analytic model"
    if estimates:
        unknown = sorted(set(estimates) - set(PARAMETERS))
        if unknown:
            raise InputError(
                f"{estimates_source}: {unknown[0]!r} is not a coefficient name; expected one of the linear model's 35 (docs/model.md)"
            )
        # a trial's offsets, biases, current and delay describe its records, not the vehicle flown
        estimates = {n: v for n, v in estimates.items() if n in COEFFICIENTS}
        config = replace(config.with_coefficients(dict(estimates)), source=estimates_source)
        source = "estimate"
        free = free if free is not None else tuple(n for n in COEFFICIENTS if n in estimates)
    if free is not None:
        if not free:
            raise InputError("free is empty; expected coefficient names, e.g. Y_v,N_r")
        free = check_free(free, "free")
        config = replace(config, free=tuple(n for n in COEFFICIENTS if n in free))
    m = model(config, lin.fins, noise_std)
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
