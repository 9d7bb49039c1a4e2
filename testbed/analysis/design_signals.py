"""The candidate inputs of an experiment design (`design` module doc): the experiment types and
their templates, the signal shapes (PRBS clocks, multisine bands, square holds) scaled to the
largest amplitude the linear regime allows, each evaluated by its information, grown on the
truth plant while the linearity check holds, and the best per type.
"""

from __future__ import annotations
import math
from dataclasses import dataclass, replace
from typing import Mapping
import numpy as np
from testbed.analysis.regime import Limits, linearity, peaks
from testbed.errors import InputError
from testbed.simulation.scenario import ExperimentSpec, Scenario
from testbed.simulation.signals import TAPS, Hold, Multisine, Prbs, Signal, Square
from testbed.analysis.design_model import (
    MAX_EXPERIMENT,
    Model,
    criterion,
    design_fisher,
    fly_model,
    scales,
    scenario_information,
)

__all__ = [
    "CHECK_SEEDS",
    "Candidate",
    "GROWTH",
    "GROWTH_BISECTIONS",
    "GROWTH_MARGIN",
    "HOLD_STEPS",
    "MAX_SHRINKS",
    "MULTISINE_BANDS",
    "MULTISINE_LINES",
    "PRBS_CLOCKS",
    "REFERENCE",
    "SCENARIO_HOLD",
    "AMPLITUDE_SHRINK",
    "TEMPLATES",
    "band",
    "best_signals",
    "candidates",
    "evaluate",
    "grow",
    "hold_signal",
    "candidate_information",
    "largest",
    "scaled",
    "spec",
    "still",
]


CHECK_SEEDS = (0, 1, 2)  # the PRBS phases the flown design is checked with (simulate's default: 0)


GROWTH_MARGIN = 0.7  # the rule's tolerances an amplitude is grown to: a margin for other phases


AMPLITUDE_SHRINK = 0.8  # amplitude factor per failed linearity check


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


def candidate_information(
    m: Model,
    kind: str,
    fins: Mapping[str, Signal],
    duration: float,
    hold: float | None = None,
    growth: float = 1.0,
) -> Candidate:
    """The candidate of these signals: its information flown on the design model."""
    t, xs, f = fly_model(m, spec(kind, fins, duration, hold=hold), duration)
    return Candidate(kind, fins, duration, design_fisher(m, t, xs, f, kind), hold, growth)


def evaluate(
    m: Model, kind: str, fins: Mapping[str, Signal], limits: Limits, duration: float, zero=None
) -> Candidate:
    """The experiment scaled to the regime's peak bounds and its Fisher information (`zero`:
    `still`'s flight, if flown)."""
    c = largest(m, kind, fins, limits, duration, zero)
    return candidate_information(
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

    lo, hi = (1.0, 2.0) if passes(1.0) else (AMPLITUDE_SHRINK**MAX_SHRINKS, 1.0)
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
    return candidate_information(m, cand.kind, fins(lo), cand.duration, cand.hold, lo)


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
