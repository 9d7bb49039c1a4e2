"""Benchmark: `testbed identify` as a whole command against a plain scipy fit as a whole command.

    python benchmarks/bench_command.py [--data {remus,II}] [--rounds 3] [--keep DIR]

Data (`--data remus`, the default): the Monte Carlo study's linear model (REMUS-class vehicle,
its coefficients and noise), two experiments of 300 s at 20 Hz (12 000 samples), all ten states
measured; 21 free coefficients: the study's 15 and the longitudinal added-mass and surge terms
(X_udot, X_u, Z_wdot, Z_qdot, M_wdot, M_qdot; the data identify each to within 6 % and none is in
a drift group), their a-priori values 30 % off the simulated coefficients. The two CSVs and the
model config are written to a temporary folder, then two processes are timed from their start to
their exit:

- the command: `testbed identify A.csv B.csv --config cfg.toml --out est.json` (the console
  script beside this interpreter), everything included: reading, screening, the `ml-gn` fit,
  its Cramér-Rao analysis, validation, writing;
- the plain scipy reference, the goal's: `python benchmarks/scipy_reference.py A.csv B.csv
  --config cfg.toml --out plain.json --plain`, a `least_squares` output-error fit (2-point
  Jacobian, R relaxed) on a simulator written with scipy alone (`expm` for the zero-order hold,
  `dlsim` for the outputs), as a user without testbed would fit the data;
- the strong reference: the same fit on testbed's own simulator (without `--plain`), which
  isolates what the optimiser and its exact sensitivities win.

`--data II`: the default Scenario II run directory, what a user gets from `testbed simulate
--scenario II --seed 1 --out II` (flown untimed into the folder: three experiments of 60 s at
50 Hz, horizontal, vertical and roll), fitted as the user fits it: the command is `testbed identify
II --out est.json`, its config the run's `model.toml` (the analytic model as the a-priori values,
the default candidates screened, z measured but not fitted) and its whole command includes the
comparison with the analytic model (the fit to the run's noise-free `.truth.csv` files). The
references fit the run's three measurement CSVs with that `model.toml` and `--free` the
coefficients the command estimated (its screen fixes some at their a-priori values, listed in its
estimate's `fixed`; the untimed run gives them), from the same a-priori values. The errors are
taken against the run's analytic model (`model.toml`), and against the command's own fit to the
noise-free data (its `comparison`'s `truth_fit`), which leaves out the linear model's bias.

After one untimed run of the command (Python's byte-code cache written, as for any user), the
two alternate for `--rounds` rounds and each one's best round counts (other work on a
shared machine only slows a process down). Printed: the times, their ratio against the goal
(the command ≥ 30× faster than the plain reference), each one's error against the simulated coefficients in the command's Cramér-Rao σ,
and how far apart the two estimates are (they must agree).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from studies.remus import FREE, EXAMPLE_COEFFICIENTS, experiments, prior_config  # noqa: E402

from testbed.data import read_config, run_csvs, write_config, write_csv  # noqa: E402

EXTRA = ("X_udot", "X_u", "Z_wdot", "Z_qdot", "M_wdot", "M_qdot")
RUN = "II"  # the Scenario II run directory, in the benchmark's folder
DURATION_S = 300.0
START_ERROR = 0.3
GOAL = 30.0


def write_inputs(folder: Path) -> tuple[list[Path], Path]:
    """The two experiments' CSVs and the a-priori model config, written into `folder` (the
    benchmark's own: a kept folder's are replaced)."""
    csvs = []
    for e in experiments(seed=0, duration=DURATION_S):
        csvs.append(write_csv(folder / f"{e.name}.csv", e.t, e.y, e.inputs, e.measured, force=True))
    config = write_config(folder / "cfg.toml", prior_config(FREE + EXTRA, error=START_ERROR), force=True)
    return csvs, config


def simulate_run(script: Path, folder: Path) -> tuple[list[Path], Path]:
    """The default Scenario II run directory `folder/II` (a kept folder's replaced), as a user
    flies it; its measurement CSVs and its `model.toml`."""
    wall([str(script), "simulate", "--scenario", "II", "--seed", "1", "--out", RUN, "--force"], folder)
    return run_csvs(folder / RUN), folder / RUN / "model.toml"


# Python caches compiled byte code beside the sources, as it does for any user; a shell that
# switched that off would time the compiler too.
ENV = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}


def wall(argv: list[str], cwd: Path) -> tuple[float, float]:
    """Wall time and CPU time (user + system) of one run of `argv` to its exit; it must succeed."""
    cpu0, t0 = _children_cpu(), time.perf_counter()
    done = subprocess.run(
        argv, cwd=cwd, env=ENV, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, check=False
    )
    elapsed, cpu = time.perf_counter() - t0, _children_cpu() - cpu0
    if done.returncode != 0:
        sys.exit(f"{' '.join(argv)} failed ({done.returncode}):\n{done.stderr}")
    return elapsed, cpu


def _children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--data", choices=("remus", "II"), default="remus", help="the REMUS-class set or the Scenario II run"
    )
    ap.add_argument("--rounds", type=int, default=3, help="runs of each command (the best counts)")
    ap.add_argument("--keep", type=Path, default=None, help="write the inputs and outputs here, kept")
    args = ap.parse_args()
    python = sys.executable
    script = Path(python).parent / "testbed"
    if not script.exists():
        sys.exit(f"no console script {script}: install the package into this interpreter (pip install -e .)")
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.keep or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        if args.data == "II":
            csvs, config = simulate_run(script, folder)
            identify = [str(script), "identify", RUN, "--out", "est.json", "--force"]
        else:
            csvs, config = write_inputs(folder)
            identify = [str(script), "identify", *map(str, csvs), "--config", str(config)]
            identify += ["--out", str(folder / "est.json"), "--force"]
        wall(identify, folder)  # byte code and files cached, as for a user
        # II: the references fit the free set the command kept after its screen
        kept = list(json.loads((folder / "est.json").read_text())["coefficients"])
        files = [str(f) for f in csvs] + ["--config", str(config)]
        files += ["--free", ",".join(kept)] if args.data == "II" else []
        commands = {
            "testbed identify": identify,
            "scipy reference": [
                python,
                str(ROOT / "benchmarks" / "scipy_reference.py"),
                *files,
                "--out",
                str(folder / "ref.json"),
            ],
            "plain scipy": [
                python,
                str(ROOT / "benchmarks" / "scipy_reference.py"),
                *files,
                "--out",
                str(folder / "plain.json"),
                "--plain",
            ],
        }
        times = {name: [] for name in commands}
        for _ in range(args.rounds):
            for name, argv in commands.items():
                times[name].append(wall(argv, folder))
        est = json.loads((folder / "est.json").read_text())
        ref = json.loads((folder / "ref.json").read_text())
        plain = json.loads((folder / "plain.json").read_text())
        n = sum(len(np.loadtxt(f, delimiter=",", skiprows=1, usecols=0)) for f in csvs)
        analytic = read_config(config).coefficients if args.data == "II" else None
    if args.data == "II":
        names = tuple(kept)
        simulated = np.array([analytic[n] for n in names])
        rows = {row["name"]: row for row in est["comparison"]["rows"]}
        if any(rows[n]["analytic"] != analytic[n] for n in names):
            sys.exit(f"the command compared with another analytic model than {RUN}/model.toml")
        truth_fit = np.array([rows[n]["truth_fit"] for n in names])
        data = (
            f"the Scenario II run (seed 1), {len(csvs)} experiments, {n} samples, {len(names)} free "
            f"coefficients ({len(est.get('fixed', {}))} fixed by the screening: "
            f"{', '.join(est.get('fixed', {}))}), start the run's model.toml (the analytic model)"
        )
    else:
        names = FREE + EXTRA
        simulated = np.array([EXAMPLE_COEFFICIENTS[n] for n in names])
        data = (
            f"{len(csvs)} experiments, {n} samples, {len(names)} free coefficients "
            f"({len(est.get('fixed', {}))} fixed by the screening), start {100 * START_ERROR:.0f} % off"
        )
    values = np.array([est["coefficients"][n]["value"] for n in names])
    std = np.array([est["coefficients"][n]["std"] for n in names])
    reference = np.array([ref["coefficients"][n] for n in names])
    z_cmd, z_ref = (values - simulated) / std, (reference - simulated) / std
    best = {name: min(w for w, _ in t) for name, t in times.items()}
    cpu = {name: min(c for _, c in t) for name, t in times.items()}
    print(f"interpreter: {python}; data: {data}")
    truth = "analytic" if args.data == "II" else "simulated"
    print(
        f"{'coefficient':12s} {truth:>10s} {'identify':>10s} {'scipy':>10s} {'cmd err/σ':>9s} {'ref err/σ':>9s}"
    )
    for name, t, a, b, za, zb in zip(names, simulated, values, reference, z_cmd, z_ref):
        print(f"{name:12s} {t:10.4g} {a:10.4g} {b:10.4g} {za:9.2f} {zb:9.2f}")
    print(
        f"testbed identify: {best['testbed identify']:7.3f} s whole command (best of {args.rounds}; "
        f"CPU {cpu['testbed identify']:.3f} s), "
        f"fit {est['wall_time_s']:.3f} s, {est['iterations']} iterations, {est['status']}, "
        f"rms error {np.sqrt(np.mean(z_cmd**2)):.3f} σ"
    )
    print(
        f"scipy reference : {best['scipy reference']:7.3f} s whole command (best of {args.rounds}; "
        f"CPU {cpu['scipy reference']:.3f} s), "
        f"fit {ref['fit_time_s']:.3f} s, {ref['model_evaluations']} model evaluations in "
        f"{ref['rounds']} R-relaxation rounds, rms error {np.sqrt(np.mean(z_ref**2)):.3f} σ"
    )
    plain_values = np.array([plain["coefficients"][n] for n in names])
    z_plain = (plain_values - simulated) / std
    print(
        f"plain scipy     : {best['plain scipy']:7.3f} s whole command (best of {args.rounds}; "
        f"CPU {cpu['plain scipy']:.3f} s), fit {plain['fit_time_s']:.3f} s, {plain['model_evaluations']} "
        f"model evaluations, rms error {np.sqrt(np.mean(z_plain**2)):.3f} σ"
    )
    print(
        f"speed ratio whole command against plain scipy: {best['plain scipy'] / best['testbed identify']:.1f}x "
        f"(CPU {cpu['plain scipy'] / cpu['testbed identify']:.1f}x) (goal >= {GOAL:g}x); "
        f"fit alone: {plain['fit_time_s'] / est['wall_time_s']:.1f}x"
    )
    print(
        f"speed ratio whole command against the strong reference: "
        f"{best['scipy reference'] / best['testbed identify']:.1f}x "
        f"(CPU {cpu['scipy reference'] / cpu['testbed identify']:.1f}x); fit alone: "
        f"{ref['fit_time_s'] / est['wall_time_s']:.1f}x; max |identify − scipy| = "
        f"{max(np.max(np.abs(z_cmd - z_ref)), np.max(np.abs(z_cmd - z_plain))):.3f} σ"
    )
    if args.data == "II":
        rms = [np.sqrt(np.mean(((v - truth_fit) / std) ** 2)) for v in (values, reference, plain_values)]
        print(
            "rms error against the command's fit to the noise-free .truth.csv (the linear model's "
            f"bias left out): identify {rms[0]:.3f} σ, scipy reference {rms[1]:.3f} σ, "
            f"plain scipy {rms[2]:.3f} σ"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
