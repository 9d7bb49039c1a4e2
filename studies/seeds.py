"""What the noise studies share: fit every seed with every method, and summarise the scatter."""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Mapping, Sequence

import numpy as np

from testbed.data import Experiment, ModelConfig
from testbed.outputs import check_output_directory, check_output_file
from testbed.estimators import Estimate, Status, identify


def check_out(out: Path, seeds: int, files: Sequence[str]) -> None:
    """`InputError` unless a study of `seeds` seeds can write into `out` before it runs: each
    seed's run directory `seed<k>` new, or a run directory it replaces (never a folder of
    someone's files), and its own `files` (new, or the last run's, replaced: the study's folder
    is its own, run again in place)."""
    for k in range(1, seeds + 1):
        check_output_directory(out / f"seed{k}", force=True)
    if out.is_dir():
        for name in files:
            check_output_file(out / name, force=True)


def guess(config: ModelConfig, rng: np.random.Generator) -> ModelConfig:
    """Where a study's fit starts: the config's free coefficients × exp(0.3 N(0, 1)), drawn from
    `rng` in the order of `config.free` (a run's model is the linear truth's own, so starting from
    it would start from the answer)."""
    return config.with_coefficients(
        {n: config.coefficients[n] * float(np.exp(0.3 * rng.normal())) for n in config.free}
    )


def usable(est: Estimate) -> bool:
    """An ML fit counts when it converged; a filter, which has no iteration to converge, when it
    did not diverge."""
    return est.converged if est.method.startswith("ml-") else est.status is not Status.DIVERGED


def counted(method: str) -> str:
    """What `usable` asks of the method, for the table footers."""
    return "converged" if method.startswith("ml-") else "not diverged"


def fit_seeds(
    seeds: int,
    data: Callable[[int], Sequence[Experiment]],
    config: ModelConfig,
    methods: Sequence[str],
    options: Mapping[str, Mapping] | None = None,
) -> dict[str, list[Estimate]]:
    """Every method on the experiments `data(seed)` of every seed, from `config`, each with its
    `options` (by method name)."""
    fits = {m: [] for m in methods}
    for seed in range(seeds):
        experiments = data(seed)
        for m in methods:
            t0 = time.perf_counter()
            est = identify(experiments, config, method=m, **(options or {}).get(m, {}))
            fits[m].append(est)
            print(
                f"seed {seed:3d} {m:6s} {est.status.name:14s} {est.iterations:5d} it "
                f"{time.perf_counter() - t0:6.2f} s",
                file=sys.stderr,
            )
    return fits


@dataclass(frozen=True)
class Scatter:
    """One method's estimates over the usable seeds, per free coefficient."""

    used: int
    bias: np.ndarray  # mean error from the reference values
    std: np.ndarray  # empirical standard deviation (ddof 1)
    reported: np.ndarray  # mean of the method's own standard errors
    corrected: np.ndarray  # mean Morelli-Klein bound (NaN where the method gives none)


def scatter(fits: Sequence[Estimate], reference: np.ndarray) -> Scatter:
    good = [e for e in fits if usable(e)]
    if not good:  # nothing to take a mean of: every column NaN, as the table prints it
        none = np.full(len(reference), np.nan)
        return Scatter(0, none, none, none, none)
    values = np.array([e.values for e in good])
    corrected = [
        e.crlb_corrected_std if e.crlb_corrected_std is not None else np.full(len(e.free), np.nan)
        for e in good
    ]
    return Scatter(
        len(good),
        values.mean(0) - reference,
        values.std(0, ddof=1),
        np.mean([e.std for e in good], axis=0),
        np.mean(corrected, axis=0),
    )
