"""Scenario II noise study: ml-gn and the MEKF on the truth plant's data, beside the Cramér-Rao bound.

The torpedo flies Scenario II once (both modes); every seed then draws new sensor noise (states
and fin encoders, the run's documented noise) on the same flight, and the run's free coefficients
are identified by `ml-gn` and by `mekf`, both started from the analytic model as
`testbed identify RUN` does. Per coefficient the table gives the analytic value, the `ml-gn` fit
to the noise-free truth (the linear model's own bias: what any estimator converges to on these
manoeuvres), and per method the mean error from that truth fit in mean Cramér-Rao sigmas (bias
due to noise) and the empirical spread over the mean Cramér-Rao bound (efficiency), beside the
mean Morelli-Klein bound for coloured residuals and each method's own reported σ.

    python studies/scenario_ii.py --seeds 20 --out runs/scenario-ii-study.csv
"""

from __future__ import annotations

import argparse
import io
import sys
from dataclasses import replace
from pathlib import Path

from testbed.analysis.screening import screen
from testbed.data import Experiment
from testbed.outputs import atomic_write_text
from testbed.estimators import identify
from testbed.simulation.measurements import measure, rng_for
from testbed.models.linear import STATES
from testbed.simulation.flight import fly_scenario
from testbed.simulation.scenario import scenario
from testbed.simulation.analytic import model_config
from testbed.simulation.vehicle import default_mjcf

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run as a script, too
from studies.seeds import counted, fit_seeds, scatter  # noqa: E402

METHODS = ("ml-gn", "mekf")


def study(seeds: int, duration: float) -> str:
    """Run the study; return the table as CSV text."""
    settings = scenario("II").with_overrides(duration=duration)
    flights, lin = fly_scenario(settings, seed=0)
    # as a run's model.toml: depth measured but not fitted, the free set what the data identify
    config = replace(model_config(lin, default_mjcf())[0], outputs=tuple(s for s in STATES if s != "z"))

    def noisy(seed):  # new sensor noise on the same flight
        return [
            Experiment(
                f.name, f.t, STATES, *measure(f.truth, f.fins, settings.sensors, rng_for(seed + 1, k, 0))
            )
            for k, f in enumerate(flights)
        ]

    config = screen(noisy(0), config)[0]
    truth = [Experiment(f.name, f.t, STATES, f.truth, f.fins) for f in flights]
    reference = identify(truth, config, method="ml-gn", start="config")
    if not reference.converged:
        raise RuntimeError(f"the fit to the noise-free truth did not converge: {reference.status.message}")

    fits = fit_seeds(seeds, noisy, config, METHODS)
    spread = {m: scatter(fits[m], reference.values) for m in METHODS}
    crlb, corrected = spread["ml-gn"].reported, spread["ml-gn"].corrected
    out = io.StringIO()
    head = [
        "coefficient",
        "analytic",
        "truth_fit",
        "linear_model_bias",
        "crlb_mean",
        "crlb_corrected_over_crlb",
    ]
    for m in METHODS:
        head += [f"{m}_mean_err_sigma", f"{m}_std_over_crlb", f"{m}_mean_reported_std_over_crlb"]
    out.write(",".join(head) + "\n")
    for i, name in enumerate(config.free):
        a, ref = config.coefficients[name], reference.values[i]
        cells = [
            name,
            f"{a:.6g}",
            f"{ref:.6g}",
            f"{(ref - a) / abs(a):.3f}" if a else "",
            f"{crlb[i]:.4g}",
            f"{corrected[i] / crlb[i]:.3f}",
        ]
        for m in METHODS:
            sc = spread[m]
            cells += [
                f"{sc.bias[i] / crlb[i]:.3f}",
                f"{sc.std[i] / crlb[i]:.3f}",
                f"{sc.reported[i] / crlb[i]:.3f}",
            ]
        out.write(",".join(cells) + "\n")
    for m in METHODS:
        out.write(f"# {m}: {spread[m].used} of {seeds} seeds {counted(m)}\n")
    return out.getvalue()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--duration", type=float, default=scenario("II").duration, help="seconds per experiment")
    ap.add_argument("--out", default="runs/scenario-ii-study.csv")
    args = ap.parse_args(argv)
    table = study(args.seeds, args.duration)
    atomic_write_text(args.out, table, force=True)  # the study's table, written again on every run
    print(table, end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
