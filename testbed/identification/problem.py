"""The output-error problem: experiments and a model config checked and converted once for the
numerical core (`Problem`, one `Record` per experiment, or per stretch of one split at a gap in
its logged inputs: `data.stretches`).

The parameter vector of the output-error fit is

    p = (θ_free, x0 of record 1, x0 of record 2, ...)

where each experiment's initial state is estimated in its *measured* components only; the
unmeasured ones stay at trim (0). Measured components are pinned by the first samples, so they
are well conditioned, whereas unmeasured ones are either unobservable (ψ and z feed nothing
back) or only weakly observable, which would add near-null directions to the Fisher matrix.
The outputs are the measured states, `u` as the perturbation u_abs − U.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace
from typing import Mapping, Sequence

import numpy as np

from testbed.data import (
    Experiment,
    ModelConfig,
    check_config,
    check_excited,
    check_experiment,
    stretch_name,
    stretches,
)
from testbed.errors import InputError
from testbed.models import log_mounting
from testbed.models.linear import (
    CURRENT,
    OUTSIDE_EQUATIONS,
    IBIAS,
    ICURRENT,
    IDELAY,
    IMOUNTING,
    ITHETA,
    MOUNTING,
    IX,
    NX,
    STATES,
    Structure,
    inertia_defect,
    pitch_dependents,
    structure,
    theta_vector,
    unobserved,
)

__all__ = [
    "Problem",
    "Record",
    "base_name",
    "check_fit",
    "check_heading",
    "check_inputs",
    "check_mounting",
    "check_one_model",
    "expanded",
    "free_values",
    "measured_heading",
    "one_model",
    "problem",
    "shifted",
]


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
    group: int = 0  # which experiment it is (its segments share it): the owner of per-record values
    heading: np.ndarray | None = None  # (N,) the measured ψ (None: not measured, the trim's 0)
    present: np.ndarray | None = None  # (N, k) bool, the samples there are; None: all of them
    first: int = 0  # its first sample in the experiment (a stretch of one split at a gap)

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
        heading = None if self.heading is None else self.heading[a:b]
        return replace(
            self,
            y=self.y[a:b],
            inputs=self.inputs[a:b],
            present=present,
            heading=heading,
            first=self.first + a,
        )


@dataclass(frozen=True)
class Problem:
    """Experiments and model config, checked and converted once for the numerical core."""

    structure: Structure
    theta: np.ndarray  # (NTHETA,) the config's parameters (free ones: the a-priori start)
    free: tuple[str, ...]  # a per-record value is named `name[experiment]`
    index: np.ndarray  # (n_free,) positions of `free` in PARAMETERS
    records: tuple[Record, ...]
    channels: tuple[str, ...]  # the measured states of all experiments, STATES order
    speed: float
    source: str
    known: np.ndarray | None = None  # (len(channels),) R where [identify] noise_std gives it, else NaN
    # (n_free,) the record group owning each free value (`[identify] per_record`), −1 where shared
    owner: np.ndarray | None = None
    # (n_groups, NTHETA) each record group's own θ where the config gives some records their own
    # values (`ModelConfig.record_values`), else None: every record has `theta`
    thetas: np.ndarray | None = None

    @functools.cached_property
    def pooled(self) -> tuple[np.ndarray, np.ndarray]:
        """Per channel, over the records: the samples present (at least 1: a channel may have
        none, a stage too short for it) and Σ y², what the noise variance is pooled over."""
        n, scale = np.zeros(len(self.channels)), np.zeros(len(self.channels))
        for r in self.records:  # a record's channels are distinct
            n[r.channels] += r.counts
            scale[r.channels] += np.sum(r.y**2, axis=0)
        return np.maximum(n, 1), scale

    @functools.cached_property
    def per_record(self) -> bool:
        """Whether the records' models differ: some free values, or fixed values, are a
        record's own."""
        return self.thetas is not None or (self.owner is not None and bool(np.any(self.owner >= 0)))

    def key(self, record: Record):
        """Which discrete model `record` is simulated with: one per sampling interval, and per
        record group where the records' models differ."""
        return (record.dt, record.group) if self.per_record else record.dt

    def acting(self, group: int) -> np.ndarray:
        """(n_free,) bool: the free values that act on the records of `group`."""
        if self.owner is None:
            return np.ones(self.n_free, dtype=bool)
        return (self.owner < 0) | (self.owner == group)

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
        """The free values' a-priori values: a per-record one its record's."""
        if self.thetas is None or self.owner is None:
            return self.theta[self.index].copy()
        return np.where(self.owner < 0, self.theta[self.index], self.thetas[self.owner, self.index])

    def coefficients(self, values: np.ndarray, group: int | None = None) -> np.ndarray:
        """The full (NTHETA,) parameter vector θ with the free ones set to `values`: the shared ones,
        and the per-record ones of record group `group` (None: the shared ones only)."""
        own = self.theta if group is None or self.thetas is None else self.thetas[group]
        theta = own.astype(np.result_type(own, values))
        acting = self.acting(-1 if group is None else group)
        theta[self.index[acting]] = np.asarray(values)[acting]
        return theta

    def columns(self, record: Record) -> np.ndarray:
        """Where the record's own parameters (the free coefficients, its x0) sit in p."""
        return np.r_[: self.n_free, record.offset : record.offset + len(record.measured)]

    @functools.cached_property
    def biased(self) -> bool:
        """Whether some output term (a bias, the current) is free or nonzero: the outputs are then
        not the states."""
        thetas = self.theta[None] if self.thetas is None else self.thetas
        terms = np.r_[IBIAS, ICURRENT]
        return bool(np.any(thetas[:, terms]) or np.isin(self.index, terms).any())

    def output_terms(self, record: Record, values: np.ndarray) -> np.ndarray:
        """What the outputs add to the measured states at the free `values`, (N, k) or (1, k):
        each output's bias, and the current in the velocities over the ground,
        u + c_N cos ψ + c_E sin ψ and v − c_N sin ψ + c_E cos ψ (ψ the record's measured heading),
        where the velocity log is not `mounted` (a mounted one reads the current in its own axes:
        `outputs`)."""
        theta = self.coefficients(values, record.group)
        bias = theta[IBIAS[record.measured]]
        if self.mounted or not (np.any(theta[ICURRENT]) or np.isin(self.index, ICURRENT).any()):
            return bias[None, :]
        current = self.current(record, theta)
        out = np.zeros((len(current), len(bias)), dtype=current.dtype) + bias
        for k in range(2):
            out[:, record.measured == k] += current[:, k : k + 1]
        return out

    def current(self, record: Record, theta: np.ndarray) -> np.ndarray:
        """The current (c_N, c_E of the full parameter vector `theta`) in body axes along the
        record's measured heading ψ, (N, 3): (c_N cos ψ + c_E sin ψ, c_E cos ψ − c_N sin ψ, 0)."""
        psi = np.zeros(len(record.y)) if record.heading is None else record.heading
        return log_mounting.body_current(theta[ICURRENT], psi)

    @functools.cached_property
    def mounted(self) -> bool:
        """Whether the velocity log's mounting (`MOUNTING`) is free or nonzero: its u, v, w
        outputs then mix the velocities and rates (`testbed.models.log_mounting`)."""
        thetas = self.theta[None] if self.thetas is None else self.thetas
        return bool(np.any(thetas[:, IMOUNTING]) or np.isin(self.index, IMOUNTING).any())

    def readings(self, record: Record, x: np.ndarray, values: np.ndarray) -> np.ndarray:
        """What a `mounted` velocity log reads from the states `x` (N, 10) at the free `values`,
        (N, 3), u as its perturbation from the trim speed (`log_mounting.reading`, the current
        in it)."""
        theta = self.coefficients(values, record.group)
        trim = np.array([self.speed, 0.0, 0.0])
        read = log_mounting.reading(theta[IMOUNTING], x[:, :3] + trim, x[:, 3:6], self.current(record, theta))
        return read - trim

    @functools.cached_property
    def delayed(self) -> bool:
        """Whether the input delay is free or nonzero: the inputs are then not the recorded ones."""
        thetas = self.theta[None] if self.thetas is None else self.thetas
        return bool(np.any(thetas[:, IDELAY]) or np.isin(self.index, IDELAY).any())

    def inputs(self, record: Record, values: np.ndarray) -> np.ndarray:
        """The fins' angles (N, 3) at the free `values`: the recorded ones advanced by the input
        delay τ, δ(t_k) = δ_rec(t_k + τ), between samples by cubic convolution and held beyond
        the record's ends (`shifted`)."""
        if not self.delayed:
            return record.inputs
        return self._shifted(record, values)[0]

    def input_rates(self, record: Record, values: np.ndarray) -> np.ndarray:
        """∂δ/∂τ (N, 3) of `inputs`."""
        return self._shifted(record, values)[1] / record.dt

    def input_curvatures(self, record: Record, values: np.ndarray) -> np.ndarray:
        """∂²δ/∂τ² (N, 3) of `inputs`."""
        return self._shifted(record, values)[2] / record.dt**2

    def _shifted(self, record: Record, values: np.ndarray):
        return shifted(record.inputs, self.coefficients(values, record.group)[IDELAY] / record.dt)

    def read_matrix(self, record: Record, values: np.ndarray) -> np.ndarray:
        """∂y/∂x (k, 10): the outputs' derivative w.r.t. the state, the state's own but for the
        u, v, w of a `mounted` velocity log, `log_mounting.matrix` on (u, v, w, p, q, r)."""
        return log_mounting.read_matrix(self.coefficients(values, record.group)[IMOUNTING], record.measured)

    def outputs(self, record: Record, x: np.ndarray, values: np.ndarray) -> np.ndarray:
        """The record's model outputs (N, k) from its states `x` (N, 10) at the free `values`:
        the measured states, u, v, w as a `mounted` velocity log reads them (`readings`), plus
        their output terms (`output_terms`)."""
        if self.mounted and np.any(record.measured < 3):
            x = np.concatenate([self.readings(record, x, values), x[:, 3:]], axis=1)
        y = x[:, record.measured]
        return y + self.output_terms(record, values) if self.biased else y

    def x0(self, record: Record, p: np.ndarray) -> np.ndarray:
        """The record's full initial state (10,) from the parameter vector."""
        x0 = np.zeros(NX, dtype=p.dtype)
        x0[record.measured] = p[record.offset : record.offset + len(record.measured)]
        return x0


def check_heading(experiments: Sequence[Experiment], current: bool) -> None:
    """`InputError` naming the first record that fits u or v without ψ where the model has a
    `current` (free or not 0): the current turns with the heading into the body's axes."""
    for e in experiments:
        if current and "psi" not in e.measured and {"u", "v"} & set(e.measured):
            raise InputError(
                f"{e.source or e.name}: the current (c_N, c_E) turns with the heading, and this "
                "record fits u or v without psi: expected a psi column (and psi among [identify] "
                "outputs), or the current 0 and fixed"
            )


def measured_heading(e: Experiment) -> np.ndarray | None:
    """The record's measured ψ (N,), its missing samples interpolated (a regressor of the
    current, not a sample of the likelihood: docs/model.md), or None where it has no ψ column."""
    if "psi" not in e.measured:
        return None
    psi, k = np.asarray(e.column("psi"), dtype=float), np.arange(len(e.t))
    there = np.isfinite(psi)
    return psi if there.all() else np.interp(k, k[there], psi[there])


def shifted(u: np.ndarray, steps) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`u` (N, m) advanced by `steps` samples (real, or complex under a complex step),
    u(k + steps), with its first and second derivatives in `steps`: between samples the cubic
    convolution of Keys (a = −½, Catmull-Rom), which passes through the samples and is C¹ in the
    shift across them (linear interpolation would put a kink in the likelihood at every whole
    sample of delay), the first and last samples held beyond the ends. On s = m + f,
    f ∈ [0, 1]:

        u(s) = w₋₁(f) u[m−1] + w₀(f) u[m] + w₁(f) u[m+1] + w₂(f) u[m+2],
        w = ½ (−f³ + 2f² − f,  3f³ − 5f² + 2,  −3f³ + 4f² + f,  f³ − f²),

    the samples beyond the ends mirrored about the end ones (u[−1] = u[1], u[N] = u[N−2]), so
    the interpolant's slope is 0 at the ends, as the hold's beyond them: C¹ there too."""
    n = len(u)
    pos = np.arange(n) + steps
    inside = (np.real(pos) >= 0) & (np.real(pos) <= n - 1)
    pos = np.where(inside, pos, np.clip(np.real(pos), 0, n - 1))
    m = np.minimum(np.floor(np.real(pos)).astype(int), max(n - 2, 0))
    f = (pos - m)[:, None]
    mirrored = [np.abs(m + j) for j in (-1, 0, 1, 2)]  # about the first sample,
    at = [u[np.clip(n - 1 - np.abs(n - 1 - i), 0, n - 1)] for i in mirrored]  # and about the last
    w = (-(f**3) + 2 * f**2 - f, 3 * f**3 - 5 * f**2 + 2, -3 * f**3 + 4 * f**2 + f, f**3 - f**2)
    dw = (-3 * f**2 + 4 * f - 1, 9 * f**2 - 10 * f, -9 * f**2 + 8 * f + 1, 3 * f**2 - 2 * f)
    d2w = (-6 * f + 4, 18 * f - 10, -18 * f + 8, 6 * f - 2)
    value, first, second = (0.5 * sum(c * a for c, a in zip(ws, at)) for ws in (w, dw, d2w))
    held = ~inside[:, None]  # beyond the ends the shift moves nothing
    return value, np.where(held, 0.0, first), np.where(held, 0.0, second)


def check_fit(experiments: Sequence[Experiment], config: ModelConfig) -> None:
    """`InputError` unless `config.free` can be fitted to the experiments' fitted outputs: the
    inputs check out (`check_inputs`), the records move (`data.check_excited`) and every free
    coefficient is seen in the measured states (`model.unobserved`)."""
    if not config.free:
        raise InputError(f"{config.source or 'config'}: [identify] free is empty; nothing to estimate")
    experiments = config.fitted(experiments)
    check_inputs(experiments, config)
    check_excited(experiments)
    measured = {s for e in experiments for s in e.measured}
    blind = unobserved(structure(config.vehicle), theta_vector(config.coefficients), config.free, measured)
    if blind:
        raise InputError(
            f"{config.source or 'config'}: [identify] free {', '.join(blind)}: not "
            f"identifiable, the measured states ({', '.join(s for s in STATES if s in measured)}) "
            "do not depend on them in the model; measure the states they drive or fix them"
        )


def check_inputs(experiments: Sequence[Experiment], config: ModelConfig) -> None:
    """`InputError` unless the experiments and the config can be fitted together, before any work:

    - each record is usable (`data.check_experiment`) and the config valid (`data.check_config`);
    - a 4-DOF config's omitted pitch constants (`Vehicle.omitted`) reach no measured state
      (`model.pitch_dependents`): the model's stand-ins for them then move nothing the data give;
    - the config's Mt is the inertia of a body (`model.inertia_defect`): a singular or indefinite
      one makes every model built on it blow up, the fault of the config, not of the data.

    The sampling interval is not checked against the model's modes: the zero-order hold is
    discretised exactly at any step, a stable mode faster than the step has decayed within it
    (the data are only blind to it) and an unstable one is a divergence, which the fit and the
    analysis handle as such (on segments).
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


def problem(experiments: Sequence[Experiment], config: ModelConfig) -> Problem:
    """Check the experiments and the config (`check_inputs`) and set up the output-error problem."""
    check_inputs(experiments, config)
    experiments = config.readings(experiments)  # the config's known sensors undone (once)
    where = config.source or "config"
    theta = theta_vector(config.coefficients)
    channels = tuple(s for s in STATES if any(s in e.measured for e in experiments))
    free, owner = expanded(config, [e.name for e in experiments])
    own = [theta_vector(config.record_coefficients(e.name)) for e in experiments]  # each record's θ
    current = any(base_name(n) in CURRENT for n in free) or any(theta[ICURRENT].any() for theta in own)
    check_heading(experiments, current)
    records, offset = [], len(free)
    for j, e in enumerate(experiments):
        y, inputs, t = (np.asarray(a, dtype=float) for a in (e.y, e.inputs, e.t))
        measured = np.array([IX[s] for s in e.measured])
        y = y.copy()
        if "u" in e.measured:
            y[:, e.measured.index("u")] -= config.vehicle.speed
        present = ~np.isnan(y)
        y[~present] = 0.0
        whole = Record(
            e.name,
            y,
            inputs,
            measured,
            np.array([channels.index(s) for s in e.measured]),
            float(t[1] - t[0]),
            offset,
            j,
            measured_heading(e),
            None if present.all() else present,
        )
        for a, b in stretches(e):  # a record split at its gaps: each stretch its own initial state
            r = whole.rows(a, b)
            if r.present is not None and r.present.all():
                r = replace(r, present=None)
            records.append(replace(r, name=stretch_name(e, a, b), offset=offset))
            offset += len(measured)
    index = np.array([ITHETA[base_name(n)] for n in free], dtype=int)
    thetas = np.array(own) if any(e.name in config.record_values for e in experiments) else None
    return Problem(
        structure(config.vehicle),
        theta,
        free,
        index,
        tuple(records),
        channels,
        config.vehicle.speed,
        where,
        np.array([(config.noise_std or {}).get(c, np.nan) ** 2 for c in channels]),
        owner,
        thetas,
    )


def check_mounting(config: ModelConfig, method: str) -> None:
    """`InputError` where the config's velocity log is mounted (a `MOUNTING` value free or not
    0) for `method`, which reads the velocities at the CG in the body's axes."""
    values = [config.coefficients, *config.record_values.values()]
    named = [n for n in MOUNTING if n in config.free or any(v.get(n, 0.0) for v in values)]
    if named:
        raise InputError(
            f"{config.source or 'config'}: {named[0]} is free or not 0; {method} reads the velocities at "
            "the CG in the body's axes: expected the velocity log's mounting 0 and fixed (with rate "
            "gyros, a known one as [sensors.NAME] position and misalignment), or an output-error method (ml-gn, ml-lm, ml-nr, ml-nm)"
        )


def check_one_model(config: ModelConfig, method: str, terms: bool = False) -> None:
    """`InputError` for what a filter (`method`) cannot take in `config` (`one_model`), before
    any data are read."""
    source = config.source or "config"
    if config.per_record and not terms:
        raise InputError(
            f"{source}: [identify] per_record lists {', '.join(config.per_record)}; {method} runs "
            "one model over every record: expected no per_record, or an output-error method "
            "(ml-gn, ml-lm, ml-nr, ml-nm) or equation-error"
        )
    check_mounting(config, method)
    free = [n for n in config.free if n in OUTSIDE_EQUATIONS]
    if free and not terms:
        raise InputError(
            f"{source}: [identify] free lists {free[0]}; {method} takes the outputs' biases, the "
            "current and the inputs' delay as the config gives them: expected them fixed, or "
            "ml-fem or an output-error method (ml-gn, ml-lm, ml-nr, ml-nm)"
        )


def one_model(
    experiments: Sequence[Experiment], config: ModelConfig, method: str, terms: bool = False
) -> tuple[list[Experiment], ModelConfig]:
    """For a filter: the experiments with the config's sensors undone (`ModelConfig.readings`),
    its given output terms (biases, the current) taken off their measured states and its given
    input delay applied to their inputs (each record's own), and the config without them.
    `InputError` for what a filter that runs one model over every record (`method`: mekf, ekf)
    cannot take: values per record, a record's own coefficient or offset, a free output term or
    delay; `terms` (ml-fem, a filter per record group) takes them all."""
    source = config.source or "config"
    check_one_model(config, method, terms)
    free = [n for n in config.free if n in OUTSIDE_EQUATIONS]
    experiments = config.readings(experiments)
    unfree = dict.fromkeys(free, 0.0)  # a free one is fitted, not taken off the data
    given = replace(
        config,
        coefficients={**config.coefficients, **unfree},
        record_values={name: {**values, **unfree} for name, values in config.record_values.items()},
        free=(),
        per_record=(),
        bounds={},  # nothing free, nothing bounded: this problem only reads the given terms
    )
    prob = problem(experiments, given)
    out, none = [], np.zeros(0)
    for e, r in zip(experiments, prob.records):
        taken = prob.output_terms(r, none)
        if np.any(taken):
            e = replace(e, y=np.asarray(e.y, dtype=float) - taken)
        out.append(replace(e, inputs=prob.inputs(r, none)) if prob.delayed else e)
    zero = {n: 0.0 for n in OUTSIDE_EQUATIONS if n not in free}
    records = {name: {**values, **zero} for name, values in config.record_values.items()}
    config = replace(config, coefficients={**config.coefficients, **zero}, record_values=records)
    own = {e: n for e, values in config.record_values.items() for n, v in values.items() if v}
    if own and not terms:
        record, name = next(iter(own.items()))
        raise InputError(
            f"{source}: record {record!r} has its own {name}; {method} runs one model over every "
            "record: expected shared values, or an output-error method"
        )
    return out, config


def expanded(config: ModelConfig, names: Sequence[str]) -> tuple[tuple[str, ...], np.ndarray]:
    """The free values of a problem of `config` on records named `names`, in the order of p: the
    shared names of `config.free`, then each `[identify] per_record` name once per record
    (`name[record]`); and each one's owner, the record's index (−1 where shared)."""
    shared = tuple(n for n in config.free if n not in config.per_record)
    free = shared + tuple(f"{n}[{name}]" for n in config.per_record for name in names)
    owner = [-1] * len(shared) + [j for _ in config.per_record for j in range(len(names))]
    return free, np.array(owner, dtype=int)


def base_name(name: str) -> str:
    """The coefficient or offset a free value is of: `N_0` for `N_0[zigzag-port]`."""
    return name.split("[", 1)[0]


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
