"""The campaign's unit of work: one data set, noise seed and start spread, fitted by one arm.

A data set is a scenario flown on a truth: the MuJoCo plant, or the analytic linear model flown
as the plant (`testbed.simulation.runs.simulate`, `truth="linear"`), where the linear reference
is exact. Its run directory is shared by every cell of the scenario, truth and seed.

Per data set, seed and spread one start (`start`): the a-priori model (`priors.prior`) and the
screen run at it, shared by every arm. One more fit per start, the `OPTIMUM` cell, searches for
the data's best-likelihood optimum from that prior, as a user could, never from the answer:
`ml-gn` from several starts (`REFERENCE_SEARCH`: the a-priori values, the equation-error
estimate and the best box draws around the prior, `ml-gn`'s `global` start); the reference a
cell is judged against is the lowest cost of that search and every arm's end point
(`testbed.study.results`). Every cell records the output-error
negative log-likelihood at its estimate (`likelihood_at`), one measure for every method, which
the judge compares (`testbed.study.results`).

On Scenario I flown on the plant the nonlinear cells (`arms.NONLINEAR_ARMS`: `NONLINEAR_ARM`,
`ml-gn`, in every plan, the others where chosen): each method fitting the nonlinear model of the
captive reference (`captive_config`, the plant's body at the run's trim speed) with its terms
that have a slope at trim free (`captive.reference.slope_terms`), started from the captive values
perturbed as the linear arms' a-priori model is (`priors.term_prior`), the same start for every
such arm of a seed and spread. Each is judged against the captive values: per coefficient the
error in % of the captive value and in the Cramér-Rao σ of the data (the `NONLINEAR_ARM` cell's,
corrected for coloured residuals: `testbed.study.results`), with the fitted model's open-loop fit
% per measured channel (`validation.validate`, its fitted initial states where it has them).
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
import time
import traceback
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import mujoco
import numpy as np

from testbed.analysis.drift import normalised
from testbed.analysis.screening import screening
from testbed.analysis.validation import validate
from testbed.captive.config import captive_config
from testbed.captive.reference import slope_terms
from testbed.data import load_data
from testbed.errors import InputError, Unflyable, one_line
from testbed.estimators import FilterEstimate, identify, lookup
from testbed.estimators.nelder_mead import SIMPLEX_ITERATIONS
from testbed.identification import likelihood, recursions, scan
from testbed.identification.bounds import fisher
from testbed.identification.problem import problem
from testbed.models.linear import COEFFICIENTS
from testbed.simulation.measurements import noise_from_data
from testbed.simulation.runs import simulate
from testbed.simulation.scenario import scenario, scenario_text
from testbed.study.arms import ARMS, NONLINEAR_ARMS, arm
from testbed.study.hashing import code_hash
from testbed.study.priors import prior, term_prior

__all__ = [
    "Cell",
    "FORMAT",
    "HISTORY_POINTS",
    "OPTIMUM",
    "REFERENCE_SEARCH",
    "Start",
    "captive_start",
    "likelihood_at",
    "load_run",
    "run_cell",
    "start",
    "zero_sigmas",
]

FORMAT = 3  # version of the cell file: part of every key, so a new format recomputes
OPTIMUM = "optimum"  # the cell that looks for the data's best-likelihood optimum (not an arm)
# the OPTIMUM cell's search: ml-gn's global start (the a-priori values, the equation-error
# estimate, the best `polish` of `samples` draws of the box a-priori × e^±1), the draws seeded
# by the cell's seed
REFERENCE_SEARCH = {"start": "global", "samples": 50, "polish": 2}
HISTORY_POINTS = 400  # the MEKF's per-sample history, thinned to this many points per cell


@dataclass(frozen=True)
class Cell:
    """One identification: `scenario` flown on `truth` with noise `seed`, fitted by `arm` from
    the a-priori model of start spread `spread` (`OPTIMUM`: the search for the optimum)."""

    scenario: str
    arm: str
    seed: int
    spread: float = 0.0
    truth: str = "plant"
    duration: float | None = None  # s per experiment (None: the scenario's own)

    @property
    def run_name(self) -> str:
        """The cached run directory's name, shared by the cells of a scenario, truth and seed."""
        return f"{self.scenario}-{self.truth}-seed{self.seed}" + (
            f"-{self.duration:g}s" if self.duration else ""
        )

    @property
    def method(self) -> str:
        return "ml-gn" if self.arm == OPTIMUM else arm(self.arm).method

    @functools.cached_property  # reads the scenario file: once per cell
    def key(self) -> str:
        """`<scenario>-<truth>-s<spread>-<arm>-seed<N>-<hash>`: the hash of every input the
        result depends on, the package's code among them."""
        flown = scenario(self.scenario).with_overrides(duration=self.duration)
        a = None if self.arm == OPTIMUM else arm(self.arm)
        doc = {
            "format": FORMAT,
            "scenario": scenario_text(replace(flown, source="")),
            "truth": self.truth,
            "spread": self.spread,
            "arm": self.arm,
            "method": self.method,
            "options": dict(a.options) if a else {},
            "free": a.free if a else "screened",
            "budget": a.budget if a else 1,
            "seed": self.seed,
            "code": code_hash(),
        }
        h = hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:12]
        return f"{self.scenario}-{self.truth}-s{self.spread:g}-{self.arm}-seed{self.seed}-{h}"


def load_run(out: str, scenario: str, truth: str, seed: int, duration: float | None):
    """The experiments and analytic model config of a run, flying it into `out/runs/` first
    unless it is there (several workers may fly the same run at once: the first rename wins)."""
    mujoco.set_mju_user_warning(lambda message: None)  # the plant raises its warnings as errors
    run = Path(out) / "runs" / Cell(scenario, "", seed, truth=truth, duration=duration).run_name
    if not (run / "manifest.json").exists():
        run.parent.mkdir(parents=True, exist_ok=True)
        try:
            simulate(scenario, seed=seed, out=run, duration=duration, truth=truth)
        except (InputError, OSError):
            if not (run / "manifest.json").exists():  # not a lost race with another worker
                raise
    return load_data([run])


def zero_sigmas(experiments, config) -> dict[str, float]:
    """The Cramér-Rao σ of each coefficient `config` has at 0, each alone (1/√F_ii, the others
    known) at the analytic model with the noise read off the data: what sizes the prior's
    additive errors. 0 where the data do not depend on it (its value changes nothing)."""
    zeros = tuple(n for n in COEFFICIENTS if config.coefficients[n] == 0)
    if not zeros:
        return {}
    at = replace(config, free=zeros)
    fitted = at.fitted(experiments)
    F = np.diag(fisher(fitted, at, noise_std=noise_from_data(fitted, config.noise_std)))
    return {n: float(1.0 / math.sqrt(f)) if f > 0 else 0.0 for n, f in zip(zeros, F)}


@dataclass(frozen=True)
class Start:
    """Where the arms of a data set, seed and spread begin: the a-priori model (`prior`, the
    candidates free), it with the screen's free set (`config`), what the screen fixed (name →
    why), and how the screen went."""

    prior: object  # ModelConfig
    config: object  # ModelConfig
    fixed: dict
    note: str = ""


@scan.compiled()  # a campaign's worker fits thousands of times: the compiler pays off
def start(data, spread: float, seed: int) -> Start:
    """The a-priori model of `spread` and `seed` for the run `data`, screened at itself; where the
    screen fails (its fit diverges on a poor prior) the candidates are fitted as written."""
    experiments, analytic = data
    a_priori = prior(analytic, spread, seed, zero_sigmas(experiments, analytic))
    try:
        s = screening(experiments, a_priori)
        if not s.config.free:
            return Start(
                a_priori, a_priori, {}, "the screen left nothing free: the candidates fitted as written"
            )
        return Start(a_priori, s.config, dict(s.fixed), "")
    except (InputError, np.linalg.LinAlgError) as exc:
        note = f"the screen failed ({one_line(exc)}): the candidates fitted as written"
        return Start(a_priori, a_priori, {}, note)


def likelihood_at(experiments, config) -> float:
    """−ln p(Z|θ) of output error at `config`'s coefficients: the initial states fitted, the
    noise variances concentrated out (`likelihood.negative_log_likelihood`); ∞ where the model
    diverges on the data. The same measure whichever method made the coefficients."""
    try:
        prob = problem(config.fitted(experiments), config)
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            p = likelihood.initial_states(prob, prob.start)
            if likelihood.divergence(prob, p) is not None:
                return math.inf
            cost = likelihood.negative_log_likelihood(prob, recursions.residuals(prob, p))
    except (InputError, np.linalg.LinAlgError, FloatingPointError):
        return math.inf
    return float(cost) if math.isfinite(cost) else math.inf


def _fitted_config(cell: Cell, data, begin: Start):
    """The model config the cell fits: the start's (screened) for a judged arm and the optimum's
    search. The drift arms compare two parametrisations of the same model, so everything they
    do not estimate is the analytic model's (the inertia known means known) and only what they
    estimate starts from the prior: the candidates as written for the A-form, with the inertia
    terms normalised (the analytic model's normalisation, the one `drift.forms` analyses) for the
    Mt-form."""
    if cell.arm == OPTIMUM or ARMS[cell.arm].free == "screened":
        return begin.config
    analytic = data[1]
    free = normalised(analytic).free if ARMS[cell.arm].free == "mt" else analytic.free
    return replace(analytic, free=free).with_coefficients({n: begin.prior.coefficients[n] for n in free})


@functools.lru_cache(maxsize=4)  # one per trim speed and worker: every seed's cell shares it
def _captive(speed: float):
    config, _, fit = captive_config(speed=speed, model="polynomial")
    return config, slope_terms(fit.terms)


def captive_start(speed: float, spread: float, seed: int):
    """(the captive reference at trim speed `speed` with its slope terms free, it started from
    their a-priori values of `spread` and `seed`): what the nonlinear cells are judged against,
    and where it starts."""
    captive, free = _captive(float(speed))
    captive = replace(captive, free=free)
    return captive, term_prior(captive, free, spread, seed)


def _nonlinear_fit(doc: dict, cell: Cell, experiments, speed: float) -> None:
    """A `NONLINEAR_ARMS` cell's fit and its errors against the captive values, into `doc`, with
    its open-loop fit % per record and channel (`fit`; none where the estimate's flight leaves
    the finite numbers, `fit_note` says where)."""
    captive, config = captive_start(speed, cell.spread, cell.seed)
    costs = []
    est = identify(
        experiments,
        config,
        method=cell.method,
        options=dict(NONLINEAR_ARMS[cell.arm].options),
        callback=lambda step: costs.append(float(step.cost)),
    )
    std = est.crlb_corrected_std if est.crlb_corrected_std is not None else est.std
    reference = {n: float(captive.terms[n]) for n in est.free}
    values = {n: float(v) for n, v in zip(est.free, est.values)}
    sigma = {n: _number(s) for n, s in zip(est.free, std)}
    fit, note = {}, ""
    try:
        fits = validate(experiments, config.with_coefficients(values), initial=est.initial_states or None)
    except Unflyable as exc:  # the estimate flown open loop diverges: a result, with no fit %
        note = one_line(exc)
    else:
        fit = {x: {c: _number(m.fit_percent) for c, m in ch.items()} for x, ch in fits.experiments.items()}
    doc.update(
        _status(est),
        free=list(est.free),
        start={n: float(config.terms[n]) for n in est.free},
        captive=reference,
        values=values,
        std=sigma,
        error_sigmas={
            n: _number((values[n] - reference[n]) / sigma[n]) if sigma[n] else None for n in values
        },
        error_percent={n: 100 * (values[n] - reference[n]) / reference[n] for n in values},
        fit=fit,
        fit_note=note,
        history=_history(est, np.array([reference[n] for n in est.free]), costs),
    )


def _status(est) -> dict:
    return dict(
        status=est.status.name.lower().replace("_", " "),
        reason=_reason(est),
        converged=bool(est.converged),
        iterations=int(est.iterations),
        evaluations=int(est.evaluations),
        wall_time_s=float(est.wall_time_s),
    )


@scan.compiled()
def run_cell(cell: Cell, data, begin: Start) -> dict:
    """Fit one cell and measure it; never raises: a failure is returned as a result with
    `status` "failed" and its reason."""
    t0 = time.perf_counter()
    doc = {"key": cell.key, "cell": asdict(cell), "start_note": begin.note}
    try:
        if cell.arm in NONLINEAR_ARMS:
            _nonlinear_fit(doc, cell, data[0], data[1].vehicle.speed)
            return doc
        experiments, analytic = data
        config = _fitted_config(cell, data, begin)
        method = lookup(cell.method)
        options = dict(ARMS[cell.arm].options) if cell.arm in ARMS else REFERENCE_SEARCH | {"seed": cell.seed}
        budget = ARMS[cell.arm].budget if cell.arm in ARMS else 1
        if budget != 1:  # the method's own iteration limit, `budget` times
            limit = method.options.build(method.name, options).max_iter
            options["max_iter"] = budget * (SIMPLEX_ITERATIONS * len(config.free) if limit is None else limit)
        costs = []
        callback = (lambda step: costs.append(float(step.cost))) if method.iterative else None
        est = identify(experiments, config, method=cell.method, options=options, callback=callback)
        values = est.coefficients
        std = est.crlb_corrected_std if est.crlb_corrected_std is not None else est.std
        doc.update(
            _status(est),
            free=list(est.free),
            fixed={
                n: {"value": float(config.coefficients[n]), "reason": why} for n, why in begin.fixed.items()
            },
            start={n: float(config.coefficients[n]) for n in est.free},
            analytic={n: float(analytic.coefficients[n]) for n in est.free},
            values={n: float(values[n]) for n in est.free},
            std={n: _number(s) for n, s in zip(est.free, std)},
            cost=likelihood_at(experiments, config.with_coefficients(values)),
            history=_history(est, np.array([analytic.coefficients[n] for n in est.free]), costs),
        )
    except Exception as exc:  # a failed cell is a result too
        doc.update(
            status="failed",
            reason=one_line(exc),
            converged=False,
            iterations=0,
            evaluations=0,
            wall_time_s=time.perf_counter() - t0,
            free=[],
            values={},
            traceback=traceback.format_exc(),
        )
    return doc


def _number(v) -> float | None:
    """A σ for JSON: inf stays (Python's json writes and reads it as Infinity), NaN becomes None."""
    v = float(v)
    return None if math.isnan(v) else v


def _reason(est) -> str:
    if est.converged:
        return ""
    return est.status.message + (f" ({est.message})" if est.message else "")


def _history(est, analytic: np.ndarray, costs: list[float]) -> dict:
    """The estimates over the fit, divided by the analytic values: per iteration for the off-line
    methods (with J_M), per sample (thinned to `HISTORY_POINTS`, with the time) for the filters."""
    h = est.history
    if h is None:
        return {}
    h = np.asarray(h, float)
    scale = np.where(analytic != 0, analytic, 1.0)
    out = {}
    if isinstance(est, FilterEstimate):
        t = est.history_t
        pick = np.unique(np.linspace(0, len(h) - 1, min(len(h), HISTORY_POINTS)).round().astype(int))
        h, out["x"], out["x_name"] = h[pick], np.asarray(t, float)[pick].tolist(), "time (s)"
    else:
        out["x"], out["x_name"] = list(range(len(h))), "iteration"
        out["cost"] = costs
    out["ratio"] = np.where(np.isfinite(h / scale), h / scale, None).tolist()
    return out
