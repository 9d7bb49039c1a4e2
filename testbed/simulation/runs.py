"""Run directories: a flown scenario written as the files users fit, replay and regenerate.

`simulate` flies a scenario (on the MuJoCo plant, or with `truth="linear"` on the analytic
linear model itself) and writes `runs/<scenario>-seed<N>/`: one measurement CSV and one
noise-free `.truth.csv` per experiment (both at the fin log's rate where the scenario logs the
fins faster than its samples, `[sensors] fin_rate`: the measurement CSV's states then missing
between the samples, the truth's present at every row), `model.toml` (the analytic linear model
at the run's trim, with every coefficient), with a `[prior]` in the scenario `prior.toml` (its a-priori
model: `testbed.simulation.prior`), `scenario.toml` (the scenario as flown), `recording.rrd` (Rerun)
and `manifest.json` (scenario, seed, truth, settings, the MJCF file and its SHA-256, package versions,
the command that regenerates the run, start and end times). The directory is built under a
temporary name and renamed: it appears whole or not at all.
"""

from __future__ import annotations

import datetime
import hashlib
import json
import shlex
import sys
import tomllib
from dataclasses import replace
from importlib import metadata
from pathlib import Path
from typing import Callable

import numpy as np

from testbed.data import config_text, csv_text
from testbed.outputs import atomic_directory
from testbed.simulation.measurements import check_seed
from testbed.models.linear import STATES
from testbed.models.sensors import ACCELERATIONS
from testbed.simulation.recording import log_run
from testbed.simulation.sensing import gapped_csv_text
from testbed.simulation.flight import check_flyable, check_truth, fly_scenario
from testbed.simulation.scenario import UNFITTED_DEPTH, Scenario, scenario, scenario_text
from testbed.simulation.analytic import model_config
from testbed.simulation.prior import prior_config
from testbed.simulation.vehicle import default_mjcf

__all__ = ["PRIOR_NOTE", "simulate"]

# The head of a run's prior.toml: what it is, and what it is not.
PRIOR_NOTE = (
    "# The a-priori model of this run (its scenario's [prior]): model.toml, the analytic model of\n"
    "# the body flown, with the coefficients commented below scaled, as a published coefficient set\n"
    "# of a similar vehicle would differ from it; a start for identify, not the truth.\n"
)


def simulate(
    s: Scenario | str,
    *,
    seed: int = 0,
    out=None,
    force: bool = False,
    duration=None,
    speed=None,
    mjcf=None,
    progress: Callable[[float, str], None] | None = None,
    truth: str = "plant",
) -> Path:
    """Fly a scenario (object, built-in name or file) and write its run directory. `truth`:
    "plant" flies the MuJoCo plant, "linear" the run's analytic linear model (`fly_scenario`)."""
    check_truth(truth)
    s = scenario(s).with_overrides(duration=duration, speed=speed)
    check_seed(seed)
    check_flyable(s)
    out = Path(out) if out is not None else Path("runs") / f"{s.name}-seed{seed}"
    mjcf_path = Path(mjcf) if mjcf is not None else default_mjcf()
    started = datetime.datetime.now(datetime.timezone.utc)
    names = [e.name for e in s.experiments]
    report = (lambda name, f: progress((names.index(name) + f) / len(names), name)) if progress else None
    with atomic_directory(out, force) as tmp:
        flights, lin = fly_scenario(s, seed, mjcf_path, report, truth)
        for f in flights:
            (tmp / f"{f.name}.csv").write_text(gapped_csv_text(*_logged(f, s.columns), s.columns))
            fine = f if f.fin_log is None else f.fin_log  # the truth at every logged fin angle's instant
            (tmp / f"{f.name}.truth.csv").write_text(csv_text(fine.t, fine.truth, fine.fins, STATES))
        config, comments = model_config(lin, mjcf_path)
        config = replace(config, outputs=tuple(c for c in s.columns if c in STATES and c != "z"))
        comments["outputs"] = UNFITTED_DEPTH
        (tmp / "model.toml").write_text(config_text(config, comments))
        if s.prior is not None:
            prior, notes = prior_config(config, s.prior)
            (tmp / "prior.toml").write_text(PRIOR_NOTE + config_text(prior, {**comments, **notes}))
        flown = replace(s, speed=lin.vehicle.speed, source="")
        (tmp / "scenario.toml").write_text(scenario_text(flown))
        title = f"testbed {s.name} seed {seed}" + (f" ({truth} truth)" if truth != "plant" else "")
        log_run(tmp / "recording.rrd", flights, mjcf_path, title=title)
        manifest = {
            "scenario": s.name,
            "scenario_source": s.source,
            "seed": seed,
            "truth": truth,
            "experiments": [f.name for f in flights],
            "settings": _settings(flown),
            "mjcf": str(mjcf_path.resolve()),
            "mjcf_sha256": hashlib.sha256(mjcf_path.read_bytes()).hexdigest(),
            "versions": _versions(),
            "command": _command(s, seed, flown, mjcf, out, truth),
            "started": started.isoformat(),
            "finished": datetime.datetime.now(datetime.timezone.utc).isoformat(),
        }
        (tmp / "manifest.json").write_text(json.dumps(manifest, indent=2) + "\n")
    return out


def _logged(f, names) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A flight's measurement CSV as (t, outputs, fins): at the sample rate, or at the fin log's
    rate with the outputs at the sample instants and missing (NaN) between."""
    if f.fin_log is None:
        return f.t, _outputs(f, names), f.fins_measured
    every = (len(f.fin_log.t) - 1) // (len(f.t) - 1)
    outputs = np.full((len(f.fin_log.t), len(names)), np.nan)
    outputs[::every] = _outputs(f, names)
    return f.fin_log.t, outputs, f.fin_log.measured


def _outputs(f, names) -> np.ndarray:
    """A flight's measured outputs `names` (N, len(names)): states and specific force."""
    by_name = {n: f.measured[:, j] for j, n in enumerate(STATES)}
    if f.specific_force is not None:
        by_name.update(zip(ACCELERATIONS, f.specific_force.T))
    return np.column_stack([by_name[n] for n in names])


def _settings(s: Scenario) -> dict:
    """The flown scenario as JSON: the same content as its scenario.toml."""
    return tomllib.loads(scenario_text(s))


def _versions() -> dict[str, str]:
    """Versions of Python and the packages in play; a loaded module's own `__version__` (what
    ran, and ~10 ms faster each than reading the installed metadata)."""
    out = {"python": sys.version.split()[0]}
    for pkg, module in (
        ("testbed", None),
        ("mujoco", "mujoco"),
        ("numpy", "numpy"),
        ("scipy", "scipy"),
        ("numba", "numba"),
        ("rerun-sdk", "rerun"),
        ("filterpy", None),
    ):
        version = getattr(sys.modules.get(module), "__version__", None)
        try:
            out[pkg] = version or metadata.version(pkg)
        except metadata.PackageNotFoundError:
            out[pkg] = "not installed"
    return out


def _command(s: Scenario, seed: int, flown: Scenario, mjcf, out: Path, truth: str) -> str:
    """The command that regenerates the run: the built-in scenario by name where the run flew it
    as built but for the command line's --duration (left out where the built-in's experiments
    keep their own durations) and --speed, else the run's scenario.toml."""
    parts = ["testbed", "simulate", "--seed", str(seed)]
    built = scenario(s.name) if s.source == "built-in" else None
    speed = ["--speed", repr(float(flown.speed))]
    if built is not None and _same(built.with_overrides(flown.duration, flown.speed), flown):
        parts += ["--scenario", s.name, "--duration", repr(float(flown.duration)), *speed]
    elif built is not None and _same(built.with_overrides(None, flown.speed), flown):
        parts += ["--scenario", s.name, *speed]
    else:
        parts += ["--scenario", str(out.resolve() / "scenario.toml")]
    if mjcf is not None:
        parts += ["--mjcf", str(Path(mjcf).resolve())]
    if truth != "plant":
        parts += ["--truth", truth]
    return shlex.join(parts)


def _same(a: Scenario, b: Scenario) -> bool:
    """Whether two scenarios fly the same: the same scenario file but for where it was read."""
    return scenario_text(replace(a, source="")) == scenario_text(replace(b, source=""))
