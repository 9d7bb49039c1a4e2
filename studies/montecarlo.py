"""Monte Carlo study of the ML output-error estimator.

Data simulated from the linear model itself (`studies.remus`: the REMUS-class example vehicle,
two Scenario-II-like experiments, rudder PRBS; elevator PRBS with a differential part for roll),
all ten states measured with white noise. For every noise seed the
free coefficients are fitted by `ml-gn` and by `mekf`; per coefficient the
table gives the mean error in Cramér-Rao sigmas (unbiased: |mean| < 0.5) and the empirical
standard deviation over the mean Cramér-Rao bound (efficient: 0.8–1.25), and against each
method's own reported σ (its mean over the seeds): the mean error (below 2) and the σ over the
empirical standard deviation (consistent: 0.7–1.5).

    python studies/montecarlo.py --seeds 50 --out runs/montecarlo.csv
"""

from __future__ import annotations

import argparse
import io
import sys
from pathlib import Path

import numpy as np

from testbed.outputs import atomic_write_text
from studies.remus import FREE, EXAMPLE_COEFFICIENTS, experiments, prior_config

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run as a script, too
from studies.seeds import counted, fit_seeds, scatter  # noqa: E402


def study(seeds: int, duration: float, methods: list[str]) -> str:
    """Run the study; return the table as CSV text (the bound: ml-gn's mean Cramér-Rao bound)."""
    simulated = np.array([EXAMPLE_COEFFICIENTS[n] for n in FREE])
    fits = fit_seeds(seeds, lambda seed: experiments(seed, duration), prior_config(), methods)
    spread = {m: scatter(fits[m], simulated) for m in methods}
    crlb, corrected = spread["ml-gn"].reported, spread["ml-gn"].corrected
    out = io.StringIO()
    head = ["coefficient", "simulated", "crlb_mean", "crlb_corrected_over_crlb"]
    for m in methods:
        head += [
            f"{m}_mean_err_sigma",
            f"{m}_std_over_crlb",
            f"{m}_bias",
            f"{m}_std",
            f"{m}_bias_over_own_sigma",
            f"{m}_own_sigma_over_std",
        ]
    out.write(",".join(head) + "\n")
    for i, name in enumerate(FREE):
        cells = [name, f"{simulated[i]:.6g}", f"{crlb[i]:.4g}", f"{corrected[i] / crlb[i]:.3f}"]
        for m in methods:
            sc = spread[m]
            cells += [
                f"{sc.bias[i] / crlb[i]:.3f}",
                f"{sc.std[i] / crlb[i]:.3f}",
                f"{sc.bias[i]:.4g}",
                f"{sc.std[i]:.4g}",
                f"{sc.bias[i] / sc.reported[i]:.3f}",
                f"{sc.reported[i] / sc.std[i]:.3f}",
            ]
        out.write(",".join(cells) + "\n")
    for m in methods:
        sc = spread[m]
        unbiased = int(np.sum(np.abs(sc.bias / crlb) < 0.5))
        efficient = int(np.sum((sc.std / crlb >= 0.8) & (sc.std / crlb <= 1.25)))
        own = sc.reported / sc.std
        within = int(np.sum(np.abs(sc.bias / sc.reported) < 2.0))
        consistent = int(np.sum((own >= 0.7) & (own <= 1.5)))
        out.write(
            f"# {m}: {sc.used} of {seeds} seeds {counted(m)}; "
            f"|mean error| < 0.5 sigma for {unbiased} of {len(FREE)} coefficients, "
            f"std/crlb in 0.8-1.25 for {efficient} of {len(FREE)}; "
            f"|mean error| < 2 own sigma for {within}, own sigma/std in 0.7-1.5 for "
            f"{consistent} of {len(FREE)}\n"
        )
    return out.getvalue()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=50)
    ap.add_argument("--duration", type=float, default=60.0, help="seconds per experiment")
    ap.add_argument("--out", default="runs/montecarlo.csv")
    args = ap.parse_args(argv)
    table = study(args.seeds, args.duration, ["ml-gn", "mekf"])
    atomic_write_text(args.out, table, force=True)  # the study's table, written again on every run
    print(table, end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
