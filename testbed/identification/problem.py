"""The output-error problem: experiments and a model config checked and converted once for the
numerical core (`Problem`, one `Record` per experiment).

The parameter vector of the output-error fit is

    p = (θ_free, x0 of experiment 1, x0 of experiment 2, ...)

where each experiment's initial state is estimated in its *measured* components only; the
unmeasured ones stay at trim (0). Measured components are pinned by the first samples, so they
are well conditioned, whereas unmeasured ones are either unobservable (ψ and z feed nothing
back) or only weakly observable, which would add near-null directions to the Fisher matrix.
The outputs are the measured states, `u` as the perturbation u_abs − U.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Mapping, Sequence

import numpy as np

from testbed.data import Experiment, ModelConfig, check_config, check_experiment
from testbed.errors import InputError
from testbed.models.linear import (
    ITHETA,
    IX,
    NX,
    STATES,
    Structure,
    fastest_rate,
    inertia_defect,
    pitch_dependents,
    structure,
    theta_vector,
    unobserved,
)

__all__ = ["COARSEST", "Problem", "Record", "check_fit", "check_inputs", "free_values", "problem"]


@dataclass(frozen=True)
class Record:
    """One experiment as the model sees it. A missing sample (NaN in the experiment) is left out
    of the likelihood: `present` marks the samples there are, and `y` is 0 where there is none,
    so that the arithmetic on it stays finite; every residual is taken through `residual`."""

    name: str
    y: np.ndarray  # (N, k) measured states, u as the perturbation u_abs − U; 0 where missing
    inputs: np.ndarray  # (N, 3)
    measured: np.ndarray  # (k,) indexes into STATES
    channels: np.ndarray  # (k,) indexes into Problem.channels
    dt: float
    offset: int  # where this experiment's initial state starts in p
    present: np.ndarray | None = None  # (N, k) bool, the samples there are; None: all of them

    @property
    def counts(self) -> np.ndarray:
        """The samples present per channel (k,)."""
        return np.full(len(self.measured), len(self.y)) if self.present is None else self.present.sum(axis=0)

    def residual(self, yhat: np.ndarray) -> np.ndarray:
        """`y − yhat` (N, k), 0 at the missing samples."""
        e = self.y - yhat
        return e if self.present is None else np.where(self.present, e, 0)

    def rows(self, a: int, b: int) -> "Record":
        """The record's samples a … b − 1 (its own initial state still at `offset`)."""
        present = None if self.present is None else self.present[a:b]
        return replace(self, y=self.y[a:b], inputs=self.inputs[a:b], present=present)


@dataclass(frozen=True)
class Problem:
    """Experiments and model config, checked and converted once for the numerical core."""

    structure: Structure
    theta: np.ndarray  # (35,) the config's coefficients (free ones: the a-priori start)
    free: tuple[str, ...]
    index: np.ndarray  # (n_free,) positions of `free` in COEFFICIENTS
    records: tuple[Record, ...]
    channels: tuple[str, ...]  # the measured states of all experiments, STATES order
    speed: float
    source: str
    known: np.ndarray | None = None  # (len(channels),) R where [identify] noise_std gives it, else NaN

    @property
    def n_free(self) -> int:
        return len(self.free)

    @property
    def n_params(self) -> int:
        return self.n_free + sum(len(r.measured) for r in self.records)

    @property
    def n_samples(self) -> int:
        return sum(len(r.y) for r in self.records)

    @property
    def start(self) -> np.ndarray:
        return self.theta[self.index].copy()

    def coefficients(self, values: np.ndarray) -> np.ndarray:
        """The full (35,) coefficient vector with the free ones set to `values`."""
        theta = self.theta.astype(np.result_type(self.theta, values))
        theta[self.index] = values
        return theta

    def columns(self, record: Record) -> np.ndarray:
        """Where the record's own parameters (the free coefficients, its x0) sit in p."""
        return np.r_[: self.n_free, record.offset : record.offset + len(record.measured)]

    def x0(self, record: Record, p: np.ndarray) -> np.ndarray:
        """The record's full initial state (10,) from the parameter vector."""
        x0 = np.zeros(NX, dtype=p.dtype)
        x0[record.measured] = p[record.offset : record.offset + len(record.measured)]
        return x0


COARSEST = math.log(2.0**53)  # ρΔ beyond which the fastest mode decays below rounding in one step


def check_fit(experiments: Sequence[Experiment], config: ModelConfig) -> None:
    """`InputError` unless `config.free` can be fitted to the experiments' fitted outputs: the
    inputs check out (`check_inputs`) and every free coefficient is seen in the measured states
    (`model.unobserved`)."""
    if not config.free:
        raise InputError(f"{config.source or 'config'}: [identify] free is empty; nothing to estimate")
    experiments = config.fitted(experiments)
    check_inputs(experiments, config)
    measured = {s for e in experiments for s in e.measured}
    blind = unobserved(structure(config.vehicle), theta_vector(config.coefficients), config.free, measured)
    if blind:
        raise InputError(
            f"{config.source or 'config'}: [identify] free {', '.join(blind)}: not "
            f"identifiable, the measured states ({', '.join(s for s in STATES if s in measured)}) "
            "do not depend on them in the model; measure the states they drive or fix them"
        )


def check_inputs(experiments: Sequence[Experiment], config: ModelConfig, resolve: bool = True) -> None:
    """`InputError` unless the experiments and the config can be fitted together, before any work:

    - each record is usable (`data.check_experiment`) and the config valid (`data.check_config`);
    - a 4-DOF config's omitted pitch constants (`Vehicle.omitted`) reach no measured state
      (`model.pitch_dependents`): the model's stand-ins for them then move nothing the data give;
    - the config's Mt is the inertia of a body (`model.inertia_defect`): a singular or indefinite
      one makes every model built on it blow up, the fault of the config, not of the data;
    - each record's sampling interval Δ resolves the model: over one step the fastest mode
      (rate ρ) decays by e^(−ρΔ), and beyond ρΔ = ln 2⁵³ that is below double-precision
      rounding, so the record shows none of it. Such a step is the data's fault (t in ms, say).
      Checked where `resolve`: for a user's model against a user's data. A model a fit reached
      from these data (`resolve=False`) may have such a mode: the simulation is exact at any
      step, and the data are only blind to that mode.
    """
    if not experiments:
        raise InputError("no experiments given; expected at least one measurement record")
    for e in experiments:
        check_experiment(e)
    check_config(config)
    source = config.source or "config"
    s, theta = structure(config.vehicle), theta_vector(config.coefficients)
    omitted = config.vehicle.omitted()
    if omitted:
        measured = {n for e in experiments for n in e.measured}
        needs = pitch_dependents(s, theta, config.free, measured)
        if needs:
            raise InputError(
                f"{source}: [vehicle] {', '.join(omitted)} missing; the pitch row needs "
                f"{'it' if len(omitted) == 1 else 'them'}, and the measured {', '.join(needs)} "
                f"depend{'s' if len(needs) == 1 else ''} on it; expected a number (SI), or data "
                "without the states the pitch row moves"
            )
    defect = inertia_defect(s, theta)
    if defect:
        raise InputError(f"{source}: the inertia matrix Mt is not a body's: {defect}")
    rate = fastest_rate(s, theta) if resolve else 0.0
    for e in experiments:
        dt = float(e.t[1] - e.t[0])
        if rate * dt > COARSEST:
            raise InputError(
                f"{e.source or e.name}: t steps {dt:g} s; the model of {source} has a "
                f"mode at {rate:.3g} 1/s, which such a step cannot show: expected a step "
                f"below {COARSEST / rate:.3g} s (t in seconds)"
            )


def problem(experiments: Sequence[Experiment], config: ModelConfig, resolve: bool = True) -> Problem:
    """Check the experiments and the config (`check_inputs`, `resolve` as there) and set up the
    output-error problem."""
    check_inputs(experiments, config, resolve)
    where = config.source or "config"
    theta = theta_vector(config.coefficients)
    channels = tuple(s for s in STATES if any(s in e.measured for e in experiments))
    records, offset = [], len(config.free)
    for e in experiments:
        y, inputs, t = (np.asarray(a, dtype=float) for a in (e.y, e.inputs, e.t))
        measured = np.array([IX[s] for s in e.measured])
        y = y.copy()
        if "u" in e.measured:
            y[:, e.measured.index("u")] -= config.vehicle.speed
        present = ~np.isnan(y)
        y[~present] = 0.0
        records.append(
            Record(
                e.name,
                y,
                inputs,
                measured,
                np.array([channels.index(s) for s in e.measured]),
                float(t[1] - t[0]),
                offset,
                None if present.all() else present,
            )
        )
        offset += len(measured)
    index = np.array([ITHETA[n] for n in config.free], dtype=int)
    return Problem(
        structure(config.vehicle),
        theta,
        tuple(config.free),
        index,
        tuple(records),
        channels,
        config.vehicle.speed,
        where,
        np.array([(config.noise_std or {}).get(c, np.nan) ** 2 for c in channels]),
    )


def free_values(prob: Problem, values: Mapping[str, float] | np.ndarray | None) -> np.ndarray:
    """The free coefficients (n_free,) from a mapping of some of them (the others at the config's
    values), an array of all of them, or None (the config's); InputError for a name that is not
    free or an array of another length."""
    if values is None:
        return prob.start
    if isinstance(values, Mapping):
        unknown = set(values) - set(prob.free)
        if unknown:
            raise InputError(
                f"values: {sorted(unknown)[0]!r} is not a free coefficient; "
                f"expected one of {', '.join(prob.free)}"
            )
        return np.array([float(values.get(n, v)) for n, v in zip(prob.free, prob.start)])
    values = np.asarray(values, dtype=float)
    if values.shape != (prob.n_free,):
        raise InputError(f"values: {values.shape} values; expected {prob.n_free} (the free ones)")
    return values
