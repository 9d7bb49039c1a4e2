"""Study: simultaneous drift measured on flown data (the paper's conclusion 1).

Flies a scenario with several seeds on the MuJoCo plant, fits every seed with ml-gn from the
analytic model in the Mt-form (`drift.normalised`: the inertia terms free, each row's diagonal
fixed) and in the A-form (the inertia known), and prints `drift.evidence` at the analytic model
with the first seed's information.

    PYTHONPATH=$PWD python studies/drift.py --scenario II --seeds 1 2 3 4 [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

from testbed.analysis.drift import evidence, forms
from testbed.data import load_data
from testbed.estimators import identify


def flown(scenario: str, seed: int, out: Path) -> Path:
    """The run directory of `scenario` flown with `seed` (simulated once)."""
    run = out / f"drift-{scenario}-{seed}"
    if not run.exists():
        cmd = [sys.executable, "-m", "testbed", "simulate", "--scenario", scenario, "--seed", str(seed)]
        subprocess.run([*cmd, "--out", str(run)], check=True, capture_output=True)
    return run


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="II")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4])
    ap.add_argument("--out", type=Path, default=Path(tempfile.gettempdir()))
    args = ap.parse_args(argv)
    first = None
    fits, status = {"mt": [], "a": []}, {"mt": [], "a": []}
    for seed in args.seeds:
        experiments, config = load_data([flown(args.scenario, seed, args.out)])
        config = replace(config, screen=False)
        f = forms(experiments, config)
        first = first or f
        for key, cfg in (("mt", f.mt), ("a", f.a)):
            est = identify(experiments, replace(config, free=cfg.free), "ml-gn", {"start": "config"})
            print(f"seed {seed} {key}: {est.status.value}, {est.iterations} iterations", file=sys.stderr)
            fits[key].append(dict(zip(est.free, map(float, est.values))))
            status[key].append(est.status.value)
    doc = evidence(first, fits["mt"], fits["a"]) | {"status_mt": status["mt"], "status_a": status["a"]}
    print(json.dumps(doc, indent=2))


if __name__ == "__main__":
    main()
