"""Shared by the jobs: the data and configs a job reads (`inputs`), the a-priori model moved
from its values (`perturbed`, `spread`), the noise-free records of a run and the comparison with
the analytic model, a report folder checked, and text written to a file or standard output.
"""

from __future__ import annotations
import os
from dataclasses import replace
from pathlib import Path
from typing import Sequence
import numpy as np
from testbed.analysis.comparison import Comparison, compare
from testbed.data import MAX_CONSTANT, Experiment, ModelConfig, load_data, read_config, read_csv, run_csvs
from testbed.outputs import atomic_write_text
from testbed.errors import InputError
from testbed.estimators import Estimate, identify
from testbed.identification.problem import base_name

__all__ = ["check_report", "inputs", "perturbed", "spread", "truth_comparison", "truth_data", "write_text"]


def write_text(out: str | os.PathLike | None, text: str, force: bool = False) -> None:
    """Write `text` to `out` atomically (nothing when `out` is None; an existing file only with
    `force`)."""
    if out is not None:
        atomic_write_text(out, text, force)


def inputs(
    data: Sequence[str | os.PathLike], config: str | os.PathLike | None = None, keep_repeats: bool = False
):
    """`(experiments, config, run_config, read)`: the experiments of `data` (run directories or
    measurement CSVs; a state's stale repeats read as missing unless `keep_repeats`,
    `data.stale`), the model config to use (`config`, else the run's model.toml), the run's
    analytic model (None for CSVs) and every file read (outputs must not clobber them)."""
    experiments, run_config = load_data(data, keep_repeats)
    used = read_config(config) if config else run_config
    if used is None:
        raise InputError("no model config: expected config=TOML, or a run directory with model.toml")
    read = [Path(e.source) for e in experiments] + [Path(used.source)]
    read += [Path(p) / "manifest.json" for p in data if (Path(p) / "manifest.json").is_file()]
    return experiments, used, run_config, read


def perturbed(config: ModelConfig, fraction: float, seed: int) -> ModelConfig:
    """The config with every free coefficient's start moved by ±fraction (signs from `seed`)."""
    signs = np.random.default_rng(seed).choice([-1.0, 1.0], size=len(config.free))
    values = config.values
    moved = config.with_coefficients({n: values[n] * (1 + s * fraction) for n, s in zip(config.free, signs)})
    return replace(moved, source=f"{config.source or 'config'} with its start moved by perturb={fraction:g}")


def spread(config: ModelConfig, s: float, seed: int) -> ModelConfig:
    """The config with every free coefficient's start multiplied by exp(s·z), z standard normal
    per coefficient drawn from `seed`: log-normal errors, as an a-priori model's are (a start
    keeps its sign; one at 0 stays there)."""
    z = np.random.default_rng(seed).standard_normal(len(config.free))
    values = config.values
    with np.errstate(over="ignore", invalid="ignore"):  # checked below
        starts = {n: float(values[n] * np.exp(s * zn)) for n, zn in zip(config.free, z)}
    far = [n for n, v in starts.items() if not abs(v) <= MAX_CONSTANT]
    if far:
        raise InputError(
            f"--perturb-spread {s:g}: {far[0]}'s start {values[far[0]]:g} × exp({s:g}·{z[config.free.index(far[0])]:.3g}) "
            f"is beyond ±{MAX_CONSTANT:g}; expected a spread of a few tenths (0.3: errors of about 30 %)"
        )
    moved = config.with_coefficients(starts)
    return replace(moved, source=f"{config.source or 'config'} with its start spread by perturb-spread={s:g}")


def check_report(report, force: bool) -> None:
    """`InputError` unless the `--report` folder can take a report (`check_report_folder`); the
    report's module (matplotlib) loads only when one is asked for."""
    if report is not None:
        from testbed.presentation.fit_report import check_report_folder

        check_report_folder(report, force)


def truth_data(paths: Sequence[str | os.PathLike]) -> list[Experiment] | None:
    """The noise-free `<experiment>.truth.csv` of the run directories among `paths` (read and
    checked now, before any fit), or None when any is missing: the comparison then has no bias
    column."""
    runs = [p for p in map(Path, paths) if (p / "manifest.json").exists()]
    truth = [f.with_suffix(".truth.csv") for p in runs for f in run_csvs(p)]
    if not truth or not all(f.exists() for f in truth):
        return None
    return [read_csv(f, f.name.removesuffix(".truth.csv"), keep_repeats=True) for f in truth]


def truth_comparison(estimate: Estimate, analytic: ModelConfig, truth: list[Experiment] | None) -> Comparison:
    """The comparison with the analytic model, its bias split off by `ml-gn` on the noise-free
    `truth` from the analytic model, whatever method made the estimate (the bias belongs to the
    model, and a filter needs noise to work). The truth fit takes the channels the estimate
    weighed, by its noise σ, held: it is the optimum the estimate's own weighting aims at, where
    noise-free residuals would weigh each channel by its model error alone (and take as many
    Gauss-Newton iterations as that weighting takes to settle). A truth fit that cannot run is
    a note, not a failure: the estimate stands without it."""
    if truth is None:
        return compare(estimate, analytic)
    try:
        names = tuple(dict.fromkeys(base_name(n) for n in estimate.free))
        per_record = tuple(dict.fromkeys(base_name(n) for n in estimate.free if n != base_name(n)))
        noise = {**(analytic.noise_std or {}), **estimate.noise_std}
        config = replace(analytic, free=names, per_record=per_record, noise_std=noise or None)
        weighed = tuple(estimate.noise_std)
        fit = identify(
            [e.only(weighed) for e in truth] if weighed else truth, config, method="ml-gn", start="config"
        )
    except InputError as exc:
        return replace(compare(estimate, analytic), note=f"no linear-model bias column: {exc}")
    return compare(estimate, analytic, fit)
