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
from testbed.analysis.regime import SEED, Limits, Linearity, linearity, peaks
from testbed.analysis.screening import unidentified
from testbed.data import Experiment, check_free
from testbed.errors import InputError
from testbed.identification.bounds import crlb
from testbed.models.linear import COEFFICIENTS, PARAMETERS
from testbed.simulation.analytic import analytic, model_config
from testbed.simulation.scenario import Scenario
from testbed.analysis.design_model import (
    CRITERIA,
    MAX_EXPERIMENT,
    Model,
    criterion,
    experiment,
    design_fisher,
    fly_model,
    model,
    regime_limits,
    scales,
    scenario_flights,
    scenario_information,
)
from testbed.analysis.design_signals import (
    CHECK_SEEDS,
    Candidate,
    MAX_SHRINKS,
    AMPLITUDE_SHRINK,
    TEMPLATES,
    best_signals,
    scaled,
)

__all__ = ["MIN_EXPERIMENT", "SPLIT_STEP", "Design", "design", "identified", "time_split"]


SPLIT_STEP = 10.0  # s, the grid of the time split


MIN_EXPERIMENT = 20.0  # s, the shortest experiment of a split


def time_split(cands: Mapping[str, Candidate], total: float, s: np.ndarray, kind: str) -> dict[str, float]:
    """Durations per experiment type (SPLIT_STEP grid, 0 or ≥ MIN_EXPERIMENT, summing to `total`)
    maximising the criterion of Σ (T_k / T_ref) F_k."""
    names = list(cands)
    rate = [cands[n].fisher / cands[n].duration for n in names]
    steps = int(round(total / SPLIT_STEP))
    best, best_value = None, -math.inf

    def walk(i, left, chosen):
        nonlocal best, best_value
        if i == len(names) - 1:
            durations = chosen + [left * SPLIT_STEP]
            if any(0 < d < MIN_EXPERIMENT for d in durations):
                return
            F = sum(d * r for d, r in zip(durations, rate))
            v = criterion(F, s, kind)
            if v > best_value:
                best, best_value = durations, v
            return
        for k in range(left + 1):
            walk(i + 1, left - k, chosen + [k * SPLIT_STEP])

    walk(0, steps, [])
    if best is None:
        raise InputError(
            f"duration={total:g} s: no split of it identifies every free coefficient; "
            "expected a longer flight or fewer free coefficients"
        )
    return {n: d for n, d in zip(names, best) if d > 0}


def identified(m: Model, total: float) -> dict[str, str]:
    """The free coefficients that Scenario II flown for `total` s leaves undetermined, by the
    rule `identify` screens with (`analysis.unidentified`: its data are the design model's own,
    so its estimates are the model's coefficients), with the reason. The design leaves them out
    by default: they would dominate any criterion, and the regime's amplitudes cannot bring them
    within reach."""
    return unidentified(scenario_flights(m, total), m.config, m.noise_std)


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
    durations = time_split(cands, duration, s, criterion_)
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
                            c: scaled(sig, float(f"{sig.amplitude * AMPLITUDE_SHRINK:.3g}"))
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
        F = F + design_fisher(m, t, xs, f, e.name)
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
