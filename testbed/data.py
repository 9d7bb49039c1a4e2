"""The files of SPEC §3: measurement CSVs, model-config TOML, run directories as data.

Readers validate everything a user can get wrong and raise `InputError` with a one-line message
naming the file and the field; writers go through `atomic_write_text`.
"""

from __future__ import annotations

import csv
import io
import json
import math
import tomllib
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Iterable, Mapping, Sequence

import numpy as np

from testbed.errors import InputError, atomic_write_text
from testbed.model import COEFFICIENTS, INPUTS, STATES, Vehicle

CSV_COLUMNS = ("t",) + STATES + INPUTS


@dataclass(frozen=True)
class Experiment:
    """One continuous record: uniform time `t`, measured states (absolute `u`), inputs (rad)."""

    name: str
    t: np.ndarray  # (N,)
    measured: tuple[str, ...]  # state names present, in STATES order
    y: np.ndarray  # (N, len(measured))
    inputs: np.ndarray  # (N, 3), INPUTS order
    source: str = ""

    @property
    def dt(self) -> float:
        return float(self.t[1] - self.t[0])

    def only(self, states: Sequence[str]) -> "Experiment":
        """The experiment with only the measured states among `states` (InputError if none)."""
        keep = [s for s in self.measured if s in states]
        if not keep:
            raise InputError(f"{self.source or self.name}: none of the fitted outputs "
                             f"({', '.join(states)}) is measured; it has {', '.join(self.measured)}")  # fmt: skip
        cols = [self.measured.index(s) for s in keep]
        return replace(self, measured=tuple(keep), y=self.y[:, cols])

    def column(self, state: str) -> np.ndarray:
        return self.y[:, self.measured.index(state)]


@dataclass(frozen=True)
class ModelConfig:
    """A model config (SPEC §3): the vehicle, all 35 coefficients, and the free ones."""

    vehicle: Vehicle
    coefficients: Mapping[str, float]  # every name in COEFFICIENTS
    free: tuple[str, ...] = ()
    source: str = ""
    outputs: tuple[str, ...] | None = None  # [identify] outputs: the states fitted (None: all measured)

    def fitted(self, experiments: Sequence[Experiment]) -> list[Experiment]:
        """The experiments reduced to the config's outputs (all of them without `outputs`)."""
        return list(experiments) if self.outputs is None else [e.only(self.outputs) for e in experiments]

    def with_coefficients(self, values: Mapping[str, float]) -> "ModelConfig":
        return replace(self, coefficients={**self.coefficients, **values})


def read_csv(path: str | Path, name: str | None = None) -> Experiment:
    """Read and validate one measurement CSV."""
    path = Path(path)
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read ({getattr(exc, 'strerror', None) or exc})") from None
    rows = list(csv.reader(io.StringIO(text)))
    if not rows or not any(c.strip() for c in rows[0]):
        raise InputError(f"{path}: empty file; expected a header row with {','.join(CSV_COLUMNS)}")
    header = [c.strip() for c in rows[0]]
    for required in ("t",) + INPUTS:
        if required not in header:
            raise InputError(f"{path}: column '{required}' missing; required: t,{','.join(INPUTS)}")
    dup = {c for c in header if header.count(c) > 1 and c in CSV_COLUMNS}
    if dup:
        raise InputError(f"{path}: column '{sorted(dup)[0]}' appears twice")
    measured = tuple(s for s in STATES if s in header)
    if not measured:
        raise InputError(f"{path}: no state column; expected at least one of {','.join(STATES)}")
    body = [r for r in rows[1:] if any(c.strip() for c in r)]
    if len(body) < 3:
        raise InputError(f"{path}: {len(body)} data rows; expected at least 3")
    wanted = [header.index(c) for c in ("t",) + measured + INPUTS]
    values = np.empty((len(body), len(wanted)))
    for k, row in enumerate(body, start=2):
        if len(row) != len(header):
            raise InputError(f"{path}: line {k} has {len(row)} fields; the header has {len(header)}")
        for j, col in enumerate(wanted):
            try:
                v = float(row[col])
            except ValueError:
                raise InputError(f"{path}: line {k}, column '{header[col]}': "
                                 f"{row[col]!r} is not a number") from None  # fmt: skip
            if not math.isfinite(v):
                raise InputError(f"{path}: line {k}, column '{header[col]}': "
                                 f"{row[col].strip()} (expected a finite number)")  # fmt: skip
            values[k - 2, j] = v
    t = values[:, 0]
    steps = np.diff(t)
    dt = float(np.median(steps))
    if dt <= 0 or np.any(np.abs(steps - dt) > 1e-6 * max(dt, 1e-12) + 1e-9):
        bad = int(np.argmax(np.abs(steps - dt))) + 3
        raise InputError(f"{path}: column 't' is not uniformly sampled (line {bad}); "
                         f"expected a constant step of {dt:g} s")  # fmt: skip
    n = len(measured)
    return Experiment(name or path.name.removesuffix(".csv"), t, measured, values[:, 1:1 + n],
                      values[:, 1 + n:], str(path))  # fmt: skip


def csv_text(t: np.ndarray, states: np.ndarray, inputs: np.ndarray,
             measured: Sequence[str] = STATES) -> str:  # fmt: skip
    """Measurement-CSV text: `states` (N, len(measured)) absolute, `inputs` (N, 3)."""
    out = io.StringIO()
    out.write(",".join(("t",) + tuple(measured) + INPUTS) + "\n")
    np.savetxt(out, np.column_stack([t, states, inputs]), delimiter=",", fmt="%.10g")
    return out.getvalue()


def write_csv(path: str | Path, t, states, inputs, measured: Sequence[str] = STATES) -> Path:
    return atomic_write_text(path, csv_text(t, states, inputs, measured))


def read_config(path: str | Path) -> ModelConfig:
    """Read and validate a model config TOML (SPEC §3)."""
    path = Path(path)
    try:
        doc = tomllib.loads(path.read_text())
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not valid TOML ({exc})") from None
    return parse_config(doc, str(path))


def parse_config(doc: Mapping, source: str = "<config>") -> ModelConfig:
    """Validate a parsed model-config document."""
    for table in ("vehicle", "coefficients"):
        if not isinstance(doc.get(table), dict):
            raise InputError(f"{source}: table [{table}] missing")
    veh = doc["vehicle"]
    values = {}
    for key in Vehicle.names():
        if key not in veh:
            raise InputError(f"{source}: [vehicle] {key} missing; expected a number (SI)")
        values[key] = _number(veh[key], f"{source}: [vehicle] {key}")
    for key in set(veh) - set(Vehicle.names()):
        raise InputError(f"{source}: [vehicle] {key} is not a vehicle constant; "
                         f"expected one of {', '.join(Vehicle.names())}")  # fmt: skip
    for key in ("mass", "Ix", "Iy", "Iz", "speed"):
        if values[key] <= 0:
            raise InputError(f"{source}: [vehicle] {key} = {values[key]:g}; expected > 0")
    coefficients = dict.fromkeys(COEFFICIENTS, 0.0)
    for key, v in doc["coefficients"].items():
        if key not in coefficients:
            raise InputError(f"{source}: [coefficients] {key} is not a coefficient name (SPEC §2)")
        coefficients[key] = _number(v, f"{source}: [coefficients] {key}")
    ident = doc.get("identify", {})
    free = ident.get("free", []) if isinstance(ident, dict) else None
    if not isinstance(free, list) or not all(isinstance(n, str) for n in free):
        raise InputError(f"{source}: [identify] free must be a list of coefficient names")
    for n in free:
        if n not in coefficients:
            raise InputError(f"{source}: [identify] free names {n!r}, not a coefficient (SPEC §2)")
    if len(set(free)) != len(free):
        raise InputError(f"{source}: [identify] free names a coefficient twice")
    outputs = ident.get("outputs") if isinstance(ident, dict) else None
    if outputs is not None:
        if not isinstance(outputs, list) or not outputs or any(s not in STATES for s in outputs):
            raise InputError(f"{source}: [identify] outputs = {outputs!r}; expected a non-empty list of "
                             f"states ({', '.join(STATES)})")  # fmt: skip
        outputs = tuple(s for s in STATES if s in outputs)
    return ModelConfig(Vehicle(**values), coefficients, tuple(free), source, outputs)


def _number(v, where: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise InputError(f"{where} = {v!r}; expected a finite number")
    return float(v)


def config_text(config: ModelConfig, comments: Mapping[str, str] | None = None) -> str:
    """TOML text of a model config; `comments` annotate vehicle constants or coefficients."""
    comments = comments or {}

    def line(key, value):
        note = f"  # {comments[key]}" if key in comments else ""
        return f"{key} = {float(value)!r}{note}"

    lines = ["[vehicle]"] + [line(k, getattr(config.vehicle, k)) for k in Vehicle.names()]
    lines += ["", "[coefficients]"] + [line(k, config.coefficients.get(k, 0.0)) for k in COEFFICIENTS]
    lines += ["", "[identify]", "free = [" + ", ".join(f'"{n}"' for n in config.free) + "]"]
    if config.outputs is not None:
        note = f"  # {comments['outputs']}" if "outputs" in comments else ""
        lines.append("outputs = [" + ", ".join(f'"{s}"' for s in config.outputs) + "]" + note)
    return "\n".join(lines + [""])


def write_config(path: str | Path, config: ModelConfig, comments=None) -> Path:
    return atomic_write_text(path, config_text(config, comments))


def run_csvs(run: Path) -> list[Path]:
    """The measurement CSVs of a run directory: the experiments its `manifest.json` lists, or
    without a manifest every `*.csv` but the `.truth.csv` and `.history.csv` files."""
    manifest = run / "manifest.json"
    if manifest.exists():
        try:
            names = json.loads(manifest.read_text())["experiments"]
            if not (isinstance(names, list) and all(isinstance(n, str) for n in names)):
                raise TypeError
        except (OSError, ValueError, KeyError, TypeError):
            raise InputError(f"{manifest}: expected JSON with an 'experiments' list of names") from None
        files = [run / f"{n}.csv" for n in names]
        for f in files:
            if not f.exists():
                raise InputError(f"{f}: missing; {manifest} lists experiment {f.stem!r}")
    else:
        files = sorted(f for f in run.glob("*.csv") if not f.name.endswith((".truth.csv", ".history.csv")))
    if not files:
        raise InputError(f"{run}: no measurement CSV in this directory")
    return files


def load_data(paths: Iterable[str | Path]) -> tuple[list[Experiment], ModelConfig | None]:
    """Experiments from run directories and/or CSVs, and the run's `model.toml` if there is one.

    A run directory contributes the experiments its `manifest.json` lists, or without a manifest
    every `<experiment>.csv` but the `.truth.csv` files (so outputs written beside them, such as
    filter histories, are not mistaken for experiments).
    """
    experiments: list[Experiment] = []
    config = None
    for p in map(Path, paths):
        if p.is_dir():
            experiments += [read_csv(f) for f in run_csvs(p)]
            if config is None and (p / "model.toml").exists():
                config = read_config(p / "model.toml")
        elif p.exists():
            experiments.append(read_csv(p))
        else:
            raise InputError(f"{p}: no such file or run directory")
    if not experiments:
        raise InputError("no data given; expected run directories or measurement CSVs")
    return experiments, config
