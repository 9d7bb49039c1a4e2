"""Benchmark: `testbed captive`'s fit (the captive reference of the bundled torpedo at 20 m/s)
against the analytic linear model of the same MJCF, both from the compiled model.

The captive reference flies its virtual captive tests (the tests near trim, then the manoeuvres'
region) and fits the nonlinear model's terms to them in two stages; the analytic model derives
the linear coefficients in closed form. Each is timed as the best of three runs, the two
alternating, with single-threaded BLAS. Prints both times, their ratio and the worst relative
error of the captive model's linearisation against the analytic model (the issue's check:
within 1 %).

    python3 benchmarks/bench_captive.py
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from testbed.threads import one_blas_thread

one_blas_thread()  # as the command line does, before numpy loads

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from testbed.models import nonlinear  # noqa: E402
from testbed.simulation.analytic import analytic_model  # noqa: E402
from testbed.captive.reference import captive_reference  # noqa: E402
from testbed.simulation.vehicle import constants, load_model  # noqa: E402

SPEED = 20.0
DERIVATIVES = ("Y_v", "Y_r", "Z_w", "Z_q", "K_p", "M_w", "M_q", "N_v", "N_r", "Y_dr", "Z_de", "M_de", "N_dr")


def main() -> int:
    model = load_model()
    best = {"captive": float("inf"), "analytic": float("inf")}
    for _ in range(3):
        t0 = time.perf_counter()
        fit = captive_reference(model, SPEED)
        best["captive"] = min(best["captive"], time.perf_counter() - t0)
        t0 = time.perf_counter()
        lin = analytic_model(model, SPEED)
        best["analytic"] = min(best["analytic"], time.perf_counter() - t0)
    nl = nonlinear.nonlinear_model(constants(model, SPEED), fit.terms)
    theta = nonlinear.nonlinear_theta(nl, fit.coefficients)
    linear = nonlinear.linearise(nl, theta).coefficients
    worst = max(abs(linear[n] / lin.coefficients[n] - 1.0) for n in DERIVATIVES)
    print(f"captive reference: {best['captive']:.3f} s (best of 3; goal <= 30 s)")
    print(f"analytic model:    {best['analytic']:.3f} s")
    print(f"ratio captive / analytic: {best['captive'] / best['analytic']:.1f}")
    print(f"worst linearisation error against the analytic model: {100 * worst:.4f} % (goal <= 1 %)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
