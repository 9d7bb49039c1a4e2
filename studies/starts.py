"""Scenario II from realistic starts: does the ML optimiser reach the optimum from where a user starts?

The torpedo flies Scenario II once (a run directory, reused when it exists). The 17 coefficients
Scenario II identifies (`FREE`) are fitted with every screen off, as `identify --free-all` does,
from `--starts` seeded starts near the analytic model, as a user's a-priori values would be: every
free coefficient times a log-normal factor exp(s·N(0,1)) (s = `--spread`, 0.5: a factor in
0.37–2.7 for 95 % of them); a free coefficient that is 0 a-priori, which no factor moves, moved by
3 of its Cramér-Rao bounds at the analytic model, of random sign. The fixed ones stay at their
analytic values.

The reference optimum is the fit of lowest negative log-likelihood among every fit of every
method and start and one more started at the analytic model (`ml-gn`, start `config`). A fit
reaches it when it converged, its cost is within ΔJ = 1 of the reference's and every coefficient
is within 0.1 of the reference's Cramér-Rao σ of the reference's. The table lists each fit; the
footer counts those reaching the optimum per method.

    python studies/starts.py --starts 20 --methods ml-gn ml-gn:config --out runs/starts.csv
    python studies/starts.py --starts 5 --methods ml-nm --jobs 2

A method is given as `METHOD` or `METHOD:START`, the latter with option start=START (`ml-gn:config`).
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import multiprocessing
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Sequence

import numpy as np

from testbed.identification.bounds import information
from testbed.data import Experiment, ModelConfig, load_data
from testbed.outputs import atomic_write_text
from testbed.errors import InputError
from testbed.estimators import identify, lookup
from testbed.simulation.runs import simulate

# What `testbed identify` frees on Scenario II (seed 1, 60 s) with its screen: the analytic
# model's free list less Y_p, K_r and K_dr (estimates 1.2, 0.6 and 0.5 σ from 0). Written out so
# the study fits exactly these, whatever a screen would say.
FREE = (
    "Y_v",
    "Y_r",
    "Y_dr",
    "Z_w",
    "Z_q",
    "Z_de",
    "K_v",
    "K_p",
    "K_der",
    "K_del",
    "M_w",
    "M_q",
    "M_de",
    "N_v",
    "N_p",
    "N_r",
    "N_dr",
)
SPREAD = 0.5  # σ of the log of the start's factor
ZERO_SIGMAS = 3.0  # how far a coefficient that is 0 a-priori is moved, in its Cramér-Rao bounds
# J is a negative log-likelihood: 2ΔJ is the likelihood-ratio statistic, χ²₁ for one parameter,
# whose 95 % quantile, 3.84, is ΔJ = 1.92. ΔJ = 1 is tighter than that — a fit this much worse is
# a distinct point the data can tell apart, not the optimum — and far above what convergence
# leaves (a step of 1e-3 σ changes J by ~1e-6). The coefficient test below is the sharp one:
# 0.1 σ along one direction is ΔJ = 0.005.
DELTA_J = 1.0
SIGMA_TOLERANCE = 0.1  # a coefficient of a fit at the optimum is within this many σ of the reference's
REFERENCE = ("analytic", "ml-gn", "config")  # the extra fit: start, method, start option


@dataclass(frozen=True)
class Fit:
    """One fit of the study: where it started, how it ended, what it found."""

    start: str  # the start's number, or "analytic"
    method: str  # the method as given (`ml-gn`, `ml-gn:config`)
    status: str  # the `Status` name, or REFUSED when `identify` refused the start
    cost: float  # negative log-likelihood (NaN without an estimate)
    values: np.ndarray  # (n_free,) the estimate (NaN without one)
    std: np.ndarray  # (n_free,) its Cramér-Rao σ
    iterations: int
    wall_time_s: float
    started_from: str = ""  # where the fit's iterations began (`Estimate.start`)
    message: str = ""

    @property
    def converged(self) -> bool:
        return self.status == "CONVERGED"


REFUSED = "REFUSED"


def parse_method(spec: str) -> tuple[str, dict]:
    """`METHOD` or `METHOD:START` → (method, options); InputError for an unknown method or an
    option the method does not take (checked before any fit)."""
    name, _, start = spec.partition(":")
    options = {"start": start} if start else {}
    lookup(name).options.build(name, options)
    return name, options


def scenario_run(run: Path, seed: int, duration: float | None) -> Path:
    """The run directory of Scenario II at `seed` (and `duration`): `run` if it is one, else flown
    and written there."""
    manifest = run / "manifest.json"
    if manifest.exists():
        flown = json.loads(manifest.read_text())
        wanted = duration if duration is not None else flown["settings"]["duration"]
        if flown["scenario"] != "II" or flown["seed"] != seed or flown["settings"]["duration"] != wanted:
            raise InputError(
                f"{run}: a run of scenario {flown['scenario']} seed {flown['seed']}, "
                f"{flown['settings']['duration']} s; expected Scenario II seed {seed}"
                + (f", {duration} s" if duration is not None else "")
                + " (another --run, or remove it)"
            )
        return run
    return simulate("II", seed=seed, out=run, duration=duration)


def bounds(experiments: Sequence[Experiment], config: ModelConfig) -> np.ndarray:
    """Cramér-Rao σ of `config.free` at the config's coefficients (noise: the residual there)."""
    return information(config.fitted(experiments), config).crlb_std


def perturbed_starts(
    config: ModelConfig, std: np.ndarray, n: int, spread: float = SPREAD, seed: int = 0
) -> list[dict[str, float]]:
    """`n` starts: each free coefficient × exp(`spread`·N(0,1)); one that is 0 moved by
    ZERO_SIGMAS of its bound `std`, of random sign. Start k draws the same numbers whatever `n`."""
    rng = np.random.default_rng(seed)
    a = np.array([config.coefficients[c] for c in config.free])
    out = []
    for _ in range(n):
        factor = np.exp(spread * rng.standard_normal(len(a)))
        sign = rng.choice([-1.0, 1.0], size=len(a))
        values = np.where(a != 0, a * factor, sign * ZERO_SIGMAS * std)
        out.append(dict(zip(config.free, map(float, values))))
    return out


def fit(experiments: Sequence[Experiment], config: ModelConfig, start: str, spec: str) -> Fit:
    """`identify` with the method `spec` from the config's coefficients (no screen)."""
    method, options = parse_method(spec)
    nf = len(config.free)
    t0 = time.perf_counter()
    try:
        est = identify(experiments, config, method=method, options=options)
    except InputError as exc:  # a start `identify` will not fit from (say, a diverging model)
        nan = np.full(nf, np.nan)
        return Fit(start, spec, REFUSED, np.nan, nan, nan, 0, time.perf_counter() - t0, message=str(exc))
    return Fit(
        start,
        spec,
        est.status.name,
        float(est.cost),
        np.asarray(est.values, float),
        np.asarray(est.std, float),
        int(est.iterations),
        time.perf_counter() - t0,
        est.start,
        est.message,
    )


def _task(args) -> Fit:
    return fit(*args)


def reference(fits: Sequence[Fit]) -> Fit:
    """The fit of lowest cost (the reference optimum)."""
    scored = [f for f in fits if np.isfinite(f.cost)]
    if not scored:
        raise RuntimeError("no fit has a finite cost: there is no reference optimum")
    return min(scored, key=lambda f: f.cost)


def distance(f: Fit, best: Fit) -> float:
    """max |θ − θ_best| / σ_best over the coefficients (NaN without an estimate); a coefficient
    whose σ_best is not finite counts as infinitely far unless it is equal."""
    d = np.abs(f.values - best.values)
    with np.errstate(invalid="ignore"):
        far = np.where(d == 0, 0.0, np.where(np.isfinite(best.std), d / best.std, np.inf))
    return float(np.max(np.where(np.isnan(d), np.nan, far)))


def reaches(f: Fit, best: Fit, delta_j: float = DELTA_J, tolerance: float = SIGMA_TOLERANCE) -> bool:
    """Converged, within `delta_j` of the best cost and `tolerance` σ of its coefficients."""
    return f.converged and f.cost - best.cost <= delta_j and distance(f, best) <= tolerance


@dataclass(frozen=True)
class Study:
    """Every fit, the reference optimum, and per method the count reaching it."""

    free: tuple[str, ...]
    fits: tuple[Fit, ...]  # the starts' fits, then the reference fit from the analytic model
    best: Fit
    reached: dict[str, int]  # method → starts from which it reached the optimum
    starts: int

    def table(self) -> str:
        lines = [
            f"{'start':>8}  {'method':<14}{'status':<16}{'from':<16}{'cost − best':>12}"
            f"{'max|Δθ|/σ':>11}{'iter':>6}{'wall s':>8}  optimum"
        ]
        for f in self.fits:
            lines.append(
                f"{f.start:>8}  {f.method:<14}{f.status:<16}{f.started_from:<16}"
                f"{f.cost - self.best.cost:>12.4g}{distance(f, self.best):>11.3g}{f.iterations:>6}"
                f"{f.wall_time_s:>8.2f}  {'yes' if reaches(f, self.best) else 'no'}"
            )
        lines.append(
            f"reference optimum: start {self.best.start}, {self.best.method}, cost {self.best.cost:.8g}"
        )
        lines += [
            f"{m}: reaches the optimum from {k} of {self.starts} starts" for m, k in self.reached.items()
        ]
        return "\n".join(lines) + "\n"

    def csv_text(self) -> str:
        out = io.StringIO()
        writer = csv.writer(out, lineterminator="\n")
        head = [
            "start",
            "method",
            "status",
            "started_from",
            "cost",
            "cost_minus_best",
            "max_dtheta_over_sigma",
            "iterations",
            "wall_time_s",
            "reaches_optimum",
            "message",
            *self.free,
        ]
        writer.writerow(head)
        for f in self.fits:
            cells = [
                f.start,
                f.method,
                f.status,
                f.started_from,
                f"{f.cost:.10g}",
                f"{f.cost - self.best.cost:.6g}",
                f"{distance(f, self.best):.6g}",
                str(f.iterations),
                f"{f.wall_time_s:.3f}",
                str(reaches(f, self.best)).lower(),
                f.message,
                *(f"{v:.8g}" for v in f.values),
            ]
            writer.writerow(cells)
        return out.getvalue()


def study(
    experiments: Sequence[Experiment],
    analytic: ModelConfig,
    methods: Sequence[str] = ("ml-gn",),
    starts: int = 20,
    spread: float = SPREAD,
    seed: int = 0,
    free: Sequence[str] = FREE,
    jobs: int = 1,
) -> Study:
    """Fit `free` with every method from every start (and once from the analytic model)."""
    for spec in methods:
        parse_method(spec)
    config = replace(analytic, free=tuple(free))
    std = bounds(experiments, config)
    tasks = [
        (experiments, config.with_coefficients(values), str(k), spec)
        for k, values in enumerate(perturbed_starts(config, std, starts, spread, seed))
        for spec in methods
    ]
    tasks.append((experiments, config, REFERENCE[0], f"{REFERENCE[1]}:{REFERENCE[2]}"))
    if jobs > 1:
        with ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
            fits = tuple(pool.map(_task, tasks))
    else:
        fits = tuple(map(_task, tasks))
    best = reference(fits)
    reached = {m: sum(reaches(f, best) for f in fits[:-1] if f.method == m) for m in methods}
    return Study(tuple(free), fits, best, reached, starts)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--starts", type=int, default=20, help="number of seeded starts")
    ap.add_argument("--spread", type=float, default=SPREAD, help="σ of the log of each start's factor")
    ap.add_argument("--start-seed", type=int, default=0, help="seed of the starts")
    ap.add_argument(
        "--methods", nargs="+", default=["ml-gn"], help="METHOD or METHOD:START, e.g. ml-gn:config"
    )
    ap.add_argument("--seed", type=int, default=1, help="the noise seed of the Scenario II run")
    ap.add_argument("--duration", type=float, default=None, help="seconds per experiment (the scenario's)")
    ap.add_argument("--run", type=Path, default=None, help="the run directory (default runs/II-seed<SEED>)")
    ap.add_argument("--jobs", type=int, default=1, help="worker processes")
    ap.add_argument("--out", default=None, help="also write the table as CSV")
    args = ap.parse_args(argv)
    if args.starts < 1 or args.jobs < 1 or not args.spread > 0:
        ap.error("--starts and --jobs must be at least 1 and --spread above 0")
    try:
        for spec in args.methods:
            parse_method(spec)
        run = args.run or Path("runs") / f"II-seed{args.seed}"
        experiments, analytic = load_data([scenario_run(run, args.seed, args.duration)])
    except InputError as exc:
        ap.error(str(exc))
    result = study(
        experiments, analytic, args.methods, args.starts, args.spread, args.start_seed, FREE, args.jobs
    )
    if args.out:
        atomic_write_text(args.out, result.csv_text(), force=True)  # the study's table, written again
    print(result.table(), end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
