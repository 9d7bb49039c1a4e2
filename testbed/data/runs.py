"""Run directories and estimates as data: the CSVs a run lists, its `model.toml`, an estimates
JSON's values."""

from __future__ import annotations

import math
import os
from dataclasses import replace
from pathlib import Path
from typing import Iterable, Mapping, Sequence

from testbed.data.config import ModelConfig, number, read_config
from testbed.data.experiment import Experiment
from testbed.data.files import check_name, read_json
from testbed.data.measurement_csv import read_csv
from testbed.errors import InputError
from testbed.models.linear import PARAMETERS, STATES

__all__ = ["load_data", "read_estimates", "run_csvs"]


def read_estimates(
    path: str | Path, names: Sequence[str] | None = None
) -> tuple[dict[str, float], dict[str, float] | None]:
    """The coefficients and offsets (name → value) of an estimates JSON, the candidates its screen
    fixed among them at the values the fit held them at, without the values estimated per
    record, and its `noise_std` (state → σ) when it has one of positive numbers,
    else None; InputError naming the file. `names`: a nonlinear model's names (its inertia
    coefficients, terms and output biases), which its coefficients must be among instead of the linear model's."""
    expected = "an estimates JSON with coefficients {name: {value: ...}}"
    doc = read_json(path, expected)
    try:
        values = {n: c["value"] for n, c in doc["coefficients"].items()}
        # the candidates the screen fixed, at the values the fit held them at (a moved start's)
        values = {n: c["value"] for n, c in doc.get("fixed", {}).items()} | values
    except (KeyError, TypeError, AttributeError):
        raise InputError(f"{path}: expected {expected}") from None
    # a value estimated per record (`name[experiment]`) belongs to that record, not to the vehicle
    values = {n: v for n, v in values.items() if not (n.endswith("]") and n.split("[")[0] in PARAMETERS)}
    for n, v in values.items():
        if names is not None and n not in names:
            raise InputError(
                f"{path}: coefficient {n[:40]!r} is not one of the nonlinear model config's names; "
                "expected its inertia coefficients, [terms] or output biases"
            )
        if names is None and n not in PARAMETERS:
            raise InputError(
                f"{path}: coefficient {n[:40]!r} is not a coefficient name; expected one of the linear model's 35 coefficients, 6 offsets, 10 output biases, the current or input_delay (docs/model.md)"
            )
        values[n] = number(v, f"{path}: coefficient {n}")
    noise = doc.get("noise_std")
    if not (
        isinstance(noise, Mapping)
        and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and 0 < v < math.inf
            for v in noise.values()
        )
    ):
        noise = None
    else:
        noise = {k: float(v) for k, v in noise.items() if k in STATES}
    return {n: float(v) for n, v in values.items()}, noise


def run_csvs(run: Path) -> list[Path]:
    """The measurement CSVs of a run directory: the experiments its `manifest.json` lists, or
    without a manifest every `*.csv` but the `.truth.csv` and `.history.csv` files."""
    manifest = run / "manifest.json"
    if os.path.lexists(manifest):
        names = _manifest_experiments(manifest)
        files = [run / f"{n}.csv" for n in names]
        for f in files:
            if not f.is_file():
                raise InputError(f"{f}: missing; {manifest} lists experiment {f.name.removesuffix('.csv')!r}")
    else:
        files = sorted(f for f in run.glob("*.csv") if not f.name.endswith((".truth.csv", ".history.csv")))
    if not files:
        raise InputError(f"{run}: no measurement CSV in this directory")
    return files


def _manifest_experiments(manifest: Path) -> list[str]:
    """The experiment names a run's manifest lists: distinct file names (no folder part)."""
    expected = f"{manifest}: expected JSON with an 'experiments' list of names"
    try:
        names = read_json(manifest, "a run manifest (JSON) with an 'experiments' list")["experiments"]
    except (KeyError, TypeError, IndexError):
        raise InputError(expected) from None
    if not (isinstance(names, list) and all(isinstance(n, str) for n in names)):
        raise InputError(expected)
    for n in names:
        check_name(n, f"{manifest}: experiment")
    if len(set(names)) != len(names):
        raise InputError(
            f"{manifest}: experiment {sorted(n for n in names if names.count(n) > 1)[0]!r} is listed twice"
        )
    return names


def load_data(
    paths: Iterable[str | Path], keep_repeats: bool = False
) -> tuple[list[Experiment], ModelConfig | None]:
    """Experiments from run directories and/or CSVs, and the run's `model.toml` if there is one;
    `keep_repeats` as for `read_csv`.

    A run directory contributes the experiments its `manifest.json` lists, or without a manifest
    every `<experiment>.csv` but the `.truth.csv` files (so outputs written beside them, such as
    filter histories, are not mistaken for experiments). A file given twice is an error; two
    experiments of one name (say `horizontal` of two runs) are told apart by their folders.
    """
    experiments: list[Experiment] = []
    config = None
    for p in map(Path, paths):
        if p.is_dir():
            experiments += [read_csv(f, keep_repeats=keep_repeats) for f in run_csvs(p)]
            if config is None and os.path.lexists(p / "model.toml"):
                config = read_config(p / "model.toml")
        elif os.path.lexists(p):
            experiments.append(read_csv(p, keep_repeats=keep_repeats))
        else:
            raise InputError(f"{p}: no such file or run directory")
    if not experiments:
        raise InputError("no data given; expected run directories or measurement CSVs")
    files = [os.path.realpath(e.source) for e in experiments]
    for e, f in zip(experiments, files):
        if files.count(f) > 1:
            raise InputError(f"{e.source}: given twice; expected each experiment once")
    names = [e.name for e in experiments]
    return [
        replace(e, name=str(Path(e.source).with_suffix(""))) if names.count(e.name) > 1 else e
        for e in experiments
    ], config
