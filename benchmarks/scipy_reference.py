"""The references the ML benchmarks measure `ml-gn` against: scipy output-error fits.

`scipy.optimize.least_squares` with its defaults (trf, 2-point finite-difference Jacobian) on
testbed's own simulator (`recursions.residuals`: the strong reference), or, with `--plain`, on a
simulator written with scipy alone as a user without testbed would write it (the exact
zero-order hold by `scipy.linalg.expm` of the block matrix, the outputs by `scipy.signal.dlsim`);
the free coefficients and each
experiment's measured initial states as parameters, from the a-priori values with the
best-fitting initial states; the noise covariance relaxed as `ml-gn` relaxes it (R from the
residuals, refit, until R settles). As a whole command it reads the measurement CSVs and the
model config with testbed's readers and writes the estimate as JSON:

    python benchmarks/scipy_reference.py A.csv B.csv --config cfg.toml --out ref.json [--plain]
        [--free NAME,NAME,...]

It fits the config's `[identify] free` as written (a candidate list is not screened). `--free`
fits those names instead, a subset of the config's list, the others fixed at their a-priori
values: the free set `testbed identify` kept after its screen (its estimate's `coefficients`, the
rest under `fixed`), so that both fit the same model.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace

from testbed.threads import one_blas_thread

one_blas_thread()  # as the command line does, before numpy loads

import numpy as np  # noqa: E402
from scipy.linalg import expm  # noqa: E402
from scipy.optimize import least_squares  # noqa: E402
from scipy.signal import dlsim  # noqa: E402

from testbed.identification import likelihood, recursions  # noqa: E402
from testbed.identification.problem import Problem, problem  # noqa: E402
from testbed.data import read_config, read_csv  # noqa: E402
from testbed.models.linear import NU, NX, continuous  # noqa: E402


def plain_residuals(prob: Problem, q: np.ndarray) -> list[np.ndarray]:
    """The residuals at `q` simulated with scipy alone: `expm([[A, B, S], [0, 0, 0]] Δ)` gives
    Φ and Γ = [B S]'s zero-order hold, `dlsim` the outputs from each experiment's x0."""
    A, B, S = continuous(prob.structure, prob.coefficients(q[: prob.n_free]))
    block = np.zeros((NX + NU + 1, NX + NU + 1))
    block[:NX, :NX], block[:NX, NX : NX + NU], block[:NX, -1] = A, B, S
    out = []
    for r in prob.records:
        E = expm(block * r.dt)
        C = np.eye(NX)[r.measured]
        u = np.column_stack([r.inputs, np.ones(len(r.inputs))])
        _, y, _ = dlsim((E[:NX, :NX], E[:NX, NX:], C, np.zeros((len(C), NU + 1)), r.dt), u, x0=prob.x0(r, q))
        out.append(r.y - y)
    return out


def scipy_fit(data, config, plain: bool = False) -> tuple[np.ndarray, int, int]:
    """Output error by least_squares (2-point Jacobian), R relaxed between fits: the free values,
    the model evaluations and the relaxation rounds. `plain`: on `plain_residuals`."""
    prob = problem(data, config)
    residuals = (lambda q: plain_residuals(prob, q)) if plain else (lambda q: recursions.residuals(prob, q))
    p = likelihood.initial_states(prob, prob.start)
    R = likelihood.noise_variance(prob, residuals(p))
    nfev = rounds = 0
    for rounds in range(1, 11):

        def weighted(q):
            res = residuals(q)
            out = np.concatenate([(e / np.sqrt(R[r.channels])).ravel() for r, e in zip(prob.records, res)])
            return np.where(np.isfinite(out), out, 1e10)

        sol = least_squares(weighted, p, jac="2-point", method="trf")  # scipy's defaults
        p, nfev = sol.x, nfev + sol.nfev + sol.njev * len(p)
        R, R_old = likelihood.noise_variance(prob, residuals(p)), R
        if np.max(np.abs(R / R_old - 1)) < 1e-3:
            break
    return p[: prob.n_free], nfev, rounds


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", nargs="+", help="measurement CSVs")
    ap.add_argument("--config", required=True, help="model config TOML")
    ap.add_argument("--out", required=True, help="estimate JSON")
    ap.add_argument("--plain", action="store_true", help="simulate with scipy alone (expm, dlsim)")
    ap.add_argument("--free", help="comma-separated names to fit, a subset of the config's free list")
    args = ap.parse_args(argv)
    data, config = [read_csv(f) for f in args.data], read_config(args.config)
    if args.free is not None:
        free = tuple(n.strip() for n in args.free.split(",") if n.strip())
        other = [n for n in free if n not in config.free]
        if not free or other or len(set(free)) < len(free):
            ap.error(
                f"--free {args.free}: expected distinct names of {args.config}'s free list {config.free}"
            )
        config = replace(config, free=free)
    t0 = time.perf_counter()
    values, nfev, rounds = scipy_fit(config.fitted(data), config, args.plain)
    doc = {
        "coefficients": dict(zip(config.free, map(float, values))),
        "model_evaluations": nfev,
        "rounds": rounds,
        "fit_time_s": time.perf_counter() - t0,
    }
    with open(args.out, "w") as f:
        json.dump(doc, f, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
