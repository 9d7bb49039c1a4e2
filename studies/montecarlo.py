"""Monte Carlo study of the ML output-error estimator.

Data simulated from the linear model itself (a small AUV: the SPEC example vehicle with
REMUS-like coefficients), two Scenario-II-like experiments (rudder PRBS; elevator PRBS with a
differential part for roll), all ten states measured with white noise. For every noise seed the
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

from testbed.data import Experiment, ModelConfig
from testbed.errors import atomic_write_text
from testbed.linear import synthetic
from testbed.model import COEFFICIENTS, Vehicle

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run as a script, too
from studies.seeds import counted, fit_seeds, scatter  # noqa: E402

VEHICLE = Vehicle(mass=30.51, Ix=0.177, Iy=3.45, Iz=3.45, weight=299.0, buoyancy=306.0,
                  xB=0.0, yB=0.0, zB=-0.0196, speed=1.54)  # fmt: skip
_U = VEHICLE.speed
# REMUS-like linear coefficients (Prestero 2001, linearised at U), with the Munk moments and the
# rate damping adjusted so that the linear model is stable in both planes.
TRUTH = dict.fromkeys(COEFFICIENTS, 0.0) | dict(
    X_udot=-0.93, X_u=-2 * 1.62 * _U,
    Y_vdot=-35.5, Y_rdot=1.93, Y_v=-28.6 * _U, Y_r=5.22 * _U, Y_dr=9.64 * _U**2,
    Z_wdot=-35.5, Z_qdot=-1.93, Z_w=-28.6 * _U, Z_q=-5.22 * _U, Z_de=-9.64 * _U**2,
    K_pdot=-0.0141, K_p=-0.3, K_der=0.5, K_del=0.5,
    M_wdot=-1.93, M_qdot=-4.88, M_w=6.0, M_q=-8.0, M_de=-6.15 * _U**2,
    N_vdot=1.93, N_rdot=-4.88, N_v=-6.0, N_r=-8.0, N_dr=-6.15 * _U**2,
)  # fmt: skip
# Well posed (no structural null direction): damping and control terms, added-mass terms fixed.
FREE = ("Y_v", "Y_r", "Y_dr", "N_v", "N_r", "N_dr", "Z_w", "Z_q", "Z_de", "M_w", "M_q", "M_de",
        "K_p", "K_der", "K_del")  # fmt: skip
NOISE = dict(u=0.01, v=0.01, w=0.01, p=0.003, q=0.003, r=0.003, phi=0.002, theta=0.002,
             psi=0.002, z=0.02)  # fmt: skip


def truth_config(free=FREE) -> ModelConfig:
    return ModelConfig(VEHICLE, dict(TRUTH), tuple(free), "truth")


def prior_config(free=FREE, error: float = 0.3) -> ModelConfig:
    """A-priori values `error` off the truth, alternating sign (a stable starting model)."""
    off = {n: TRUTH[n] * (1 + error if i % 3 == 0 else 1 - error) for i, n in enumerate(free)}
    return truth_config(free).with_coefficients(off)


def _prbs(rng: np.random.Generator, n: int, hold: int, amplitude: float) -> np.ndarray:
    levels = rng.integers(0, 2, size=n // hold + 1) * 2.0 - 1.0
    return np.repeat(levels, hold)[:n] * amplitude


def inputs(duration: float = 60.0, dt: float = 0.05, seed: int = 0) -> dict[str, tuple]:
    """Scenario-II-like designs: name → (t, inputs (N, 3))."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration, dt)
    n = len(t)
    horizontal = np.zeros((n, 3))
    horizontal[:, 0] = _prbs(rng, n, int(1.5 / dt), 0.1)
    vertical = np.zeros((n, 3))
    common, differential = _prbs(rng, n, int(1.5 / dt), 0.1), _prbs(rng, n, int(0.85 / dt), 0.05)
    vertical[:, 1], vertical[:, 2] = common + differential, common - differential
    return {"horizontal": (t, horizontal), "vertical": (t, vertical)}


def experiments(seed: int, duration: float = 60.0, dt: float = 0.05,
                noise: dict | None = NOISE) -> list[Experiment]:  # fmt: skip
    """The two experiments with noise realisation `seed` (the input design is fixed)."""
    rng = np.random.default_rng(10_000 + seed)
    return [synthetic(truth_config(), t, u, noise, rng=rng, name=name)
            for name, (t, u) in inputs(duration, dt).items()]  # fmt: skip


def study(seeds: int, duration: float, methods: list[str]) -> str:
    """Run the study; return the table as CSV text (the bound: ml-gn's mean Cramér-Rao bound)."""
    truth = np.array([TRUTH[n] for n in FREE])
    fits = fit_seeds(seeds, lambda seed: experiments(seed, duration), prior_config(), methods)
    spread = {m: scatter(fits[m], truth) for m in methods}
    crlb, corrected = spread["ml-gn"].reported, spread["ml-gn"].corrected
    out = io.StringIO()
    head = ["coefficient", "truth", "crlb_mean", "crlb_corrected_over_crlb"]
    for m in methods:
        head += [f"{m}_mean_err_sigma", f"{m}_std_over_crlb", f"{m}_bias", f"{m}_std",
                 f"{m}_bias_over_own_sigma", f"{m}_own_sigma_over_std"]  # fmt: skip
    out.write(",".join(head) + "\n")
    for i, name in enumerate(FREE):
        cells = [name, f"{truth[i]:.6g}", f"{crlb[i]:.4g}", f"{corrected[i] / crlb[i]:.3f}"]
        for m in methods:
            sc = spread[m]
            cells += [f"{sc.bias[i] / crlb[i]:.3f}", f"{sc.std[i] / crlb[i]:.3f}", f"{sc.bias[i]:.4g}",
                      f"{sc.std[i]:.4g}", f"{sc.bias[i] / sc.reported[i]:.3f}",
                      f"{sc.reported[i] / sc.std[i]:.3f}"]  # fmt: skip
        out.write(",".join(cells) + "\n")
    for m in methods:
        sc = spread[m]
        unbiased = int(np.sum(np.abs(sc.bias / crlb) < 0.5))
        efficient = int(np.sum((sc.std / crlb >= 0.8) & (sc.std / crlb <= 1.25)))
        own = sc.reported / sc.std
        within = int(np.sum(np.abs(sc.bias / sc.reported) < 2.0))
        consistent = int(np.sum((own >= 0.7) & (own <= 1.5)))
        out.write(f"# {m}: {sc.used} of {seeds} seeds {counted(m)}; "
                  f"|mean error| < 0.5 sigma for {unbiased} of {len(FREE)} coefficients, "
                  f"std/crlb in 0.8-1.25 for {efficient} of {len(FREE)}; "
                  f"|mean error| < 2 own sigma for {within}, own sigma/std in 0.7-1.5 for "
                  f"{consistent} of {len(FREE)}\n")  # fmt: skip
    return out.getvalue()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=50)
    ap.add_argument("--duration", type=float, default=60.0, help="seconds per experiment")
    ap.add_argument("--out", default="runs/montecarlo.csv")
    args = ap.parse_args(argv)
    table = study(args.seeds, args.duration, ["ml-gn", "mekf"])
    atomic_write_text(args.out, table)
    print(table, end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
