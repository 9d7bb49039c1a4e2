"""`II-trial`: output error with today's model against the trial's parameters, by output error
and by the filter-error method.

The built-in `II-trial` (Scenario II flown as a real trial: named sensors away from the CG,
biased, misaligned, delayed and at their own rates; fin offsets, delays and a dead band; a
current, turbulence, propeller torque and an imperfect trim) is flown on the linear truth (the
analytic model of the bundled torpedo, so the coefficients the data come from are known exactly)
for each seed and fitted from a guess, the run's free coefficients × exp(0.3 N(0, 1)) (`guess`):

- **today's model**: `ml-gn` on the run's config as written (no sensors, no trial parameters);
- **with the trial's parameters**: `ml-gn` and `ml-fem` with the config stating what a
  calibrated installation knows of its sensors (`[sensors.NAME]`: positions, misalignments,
  scale factors, delays; not the biases), and the offsets `Y_0` … `N_0`, the biases `b_u`,
  `b_p`, `b_q`, `b_r`, the current and the inputs' delay free (`b_v`, `b_w` trade exactly with
  the offsets: docs/model.md); `ml-fem` models the process noise with the turbulence's
  correlation time (as a user would take eddy length over speed).

Every error is in the fit's own σ: the Morelli-Klein bound for coloured residuals where the fit
gives it, else the Cramér-Rao σ. A coefficient passes within max(3 σ, 3 %) of the analytic
model; a trial parameter within 3 σ (alone) of what the scenario injected. One that does not is
measured by the likelihood ratio as well (`analysis.profile`: the fit again with it held at the
reference), the distance that does not depend on how the parameter is written where the
likelihood is not quadratic over the error (`ml-gn`'s takes its residuals as white, so for it
the ratio is the stricter); `off_by_likelihood` lists those beyond 3 σ by that too. What each
trial parameter should come to (`injected`): the sensors'
biases, the current, the fin log's delay, and per equation row the constant load of the
propeller torque, weight excess and CG offset, less the fin offsets through the control
derivatives (the recorded fins read the true ones plus their offsets) and the DVL's v and w
biases through the velocity derivatives (a biased velocity is a shifted state).

    python studies/trial.py --seeds 5 --out runs/trial
"""

from __future__ import annotations

import argparse
import io
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from testbed.analysis.profile import profile
from testbed.data import ModelConfig, load_data
from testbed.outputs import atomic_write_text
from testbed.errors import InputError
from testbed.estimators import Estimate, identify
from testbed.models.linear import IX, OFFSETS, STATES, structure, theta_vector, tilde
from testbed.models.sensors import Sensor
from testbed.simulation.runs import simulate
from testbed.simulation.scenario import Scenario, scenario

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run as a script, too
from studies import seeds  # noqa: E402
from studies.seeds import check_out  # noqa: E402

TRIAL = ("Y_0", "Z_0", "K_0", "M_0", "N_0", "b_u", "b_p", "b_q", "b_r", "c_N", "c_E", "input_delay")
SPECIFIC_FORCE = ("ax", "ay", "az")  # outputs the linear model does not fit
MAX_ITER = 1000  # iterations per start (ml-fem: per phase): 32 values beyond the initial states, from a guess, need 150-350
METHODS = ("ml-gn", "ml-fem")


def known(s: Scenario) -> tuple[Sensor, ...]:
    """The scenario's named sensors as a calibrated installation knows them: outputs the model
    fits, geometry, scale factors and delays; the biases, noise and rates left to the data."""
    out = []
    for sensor in s.named_sensors:
        outputs = tuple(o for o in sensor.outputs if o not in SPECIFIC_FORCE)
        scale = {o: v for o, v in sensor.scale.items() if o in outputs}
        out.append(replace(sensor, outputs=outputs, scale=scale, bias={}, rate=None, noise_std={}))
    return tuple(out)


def injected(s: Scenario, config: ModelConfig, weight: float) -> dict[str, float]:
    """What each trial parameter should come to on the scenario's data (the module's docstring)."""
    bias = {o: v for sensor in s.named_sensors for o, v in sensor.bias.items()}
    st = structure(config.vehicle)
    _, At, Bt, _ = tilde(st, theta_vector(config.coefficients))
    trial = s.trial
    load = trial.loads(np.zeros(len(STATES)), weight)
    rows = load - Bt[:6] @ np.asarray(trial.offsets, float)
    rows = rows - At[:6, IX["v"]] * bias.get("v", 0.0) - At[:6, IX["w"]] * bias.get("w", 0.0)
    out = {name: float(rows[IX[state]]) for name, state in zip(OFFSETS, STATES[:6])}
    out |= {f"b_{o}": float(bias.get(o, 0.0)) for o in ("u", "p", "q", "r")}
    out |= {"c_N": float(trial.current[0]), "c_E": float(trial.current[1])}
    out["input_delay"] = float(trial.fin_log_delay)
    return out


def guess(config: ModelConfig, seed: int) -> ModelConfig:
    """Where seed `seed`'s fits start (`seeds.guess`, its own draw)."""
    return seeds.guess(config, np.random.default_rng(1000 + seed))


def sigma(est: Estimate) -> np.ndarray:
    """The fit's σ: the coloured-residual bound where it gives one, else the Cramér-Rao σ."""
    return est.std if est.crlb_corrected_std is None else est.crlb_corrected_std


def beyond(est: Estimate, reference: dict[str, float], relative: float = 0.03) -> list[tuple[str, float]]:
    """The free names beyond max(3 σ, `relative` × |reference|) of `reference`, with their error
    (estimate − reference) in σ."""
    out = []
    for name, v, sd in zip(est.free, est.values, sigma(est)):
        if name not in reference:
            continue
        a = reference[name]
        if not abs(v - a) <= max(3 * sd, relative * abs(a)):  # a σ that is not finite bounds nothing
            out.append((name, (v - a) / sd))
    return out


def misses(est: Estimate, reference: dict[str, float], relative: float = 0.03) -> list[str]:
    """`beyond`, as text."""
    return [f"{name} {z:+.1f}σ" for name, z in beyond(est, reference, relative)]


def by_likelihood(
    experiments, config: ModelConfig, est: Estimate, reference, relative, options
) -> tuple[str, list[str]]:
    """Each of `beyond`'s names with its distance by the likelihood ratio too (`profile`: the fit
    again with it held at the reference, estimate − reference in σ), as text; and those beyond
    3 σ by it as well, or not measured by it: a held fit that did not converge, or one below the
    estimate (which was then short of its optimum)."""
    text, still = [], []
    for name, z in beyond(est, reference, relative):
        p = profile(experiments, config, est, name, reference[name], max_iter=MAX_ITER, **options)
        if not p.held.converged or p.statistic < 0:
            why = "did not converge" if not p.held.converged else f"{-p.statistic:.2g} below the estimate"
            text.append(f"{name} {z:+.1f}σ (the fit held at the reference {why})")
            still.append(name)
            continue
        text.append(f"{name} {z:+.1f}σ (likelihood ratio {-p.sigmas:+.1f}σ)")
        if abs(p.sigmas) > 3:
            still.append(name)
    return " ".join(text) or "-", still


def study(seeds: int, out: Path) -> str:
    """Run the study; return the table as CSV text."""
    out.mkdir(parents=True, exist_ok=True)
    s = scenario("II-trial")
    table = io.StringIO()
    table.write("seed,method,status,seconds,coefficients_off,trial_off,trial_worst_sigma,off_by_likelihood\n")
    for seed in range(1, seeds + 1):
        run = simulate(s, seed=seed, out=out / f"seed{seed}", force=True, truth="linear")
        experiments, config = load_data([run])
        analytic = dict(config.coefficients)
        coefficients = {n: analytic[n] for n in config.free}
        start = guess(config, seed)
        today = identify(experiments, start, method="ml-gn")
        worst = max(abs(v - analytic[n]) / sd for n, v, sd in zip(today.free, today.values, sigma(today)))
        table.write(f"{seed},today's model,{today.status.name},,worst {worst:.0f}σ,,,\n")
        with_trial = replace(start, free=config.free + TRIAL, sensors=known(s), screen=False)
        truth = injected(s, config, config.vehicle.weight)
        options = {"ml-fem": {"correlation_time": s.trial.turbulence.time}}
        for method in METHODS:
            t0 = time.perf_counter()
            opts = options.get(method, {})
            est = identify(experiments, with_trial, method=method, max_iter=MAX_ITER, **opts)
            seconds = time.perf_counter() - t0
            errors = [(v - truth[n]) / sd for n, v, sd in zip(est.free, est.values, sigma(est)) if n in truth]
            off, still = by_likelihood(experiments, with_trial, est, coefficients, 0.03, opts)
            trial_off, trial_still = by_likelihood(experiments, with_trial, est, truth, 0.0, opts)
            table.write(
                f"{seed},{method},{est.status.name},{seconds:.0f},{off},{trial_off},"
                f"{max(map(abs, errors)):.1f},{' '.join(still + trial_still) or '-'}\n"
            )
            for n, v, sd in zip(est.free, est.values, sigma(est)):
                if n in truth:
                    print(
                        f"    {method} {n:12s} {v: .5g} ± {sd:.2g}  injected {truth[n]: .5g}", file=sys.stderr
                    )
        print(table.getvalue().splitlines()[-3:], file=sys.stderr)
    return table.getvalue()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--out", type=Path, default=Path("runs/trial"))
    a = ap.parse_args(argv)
    try:
        check_out(a.out, a.seeds, ("trial.csv",))
    except InputError as exc:
        print(f"trial.py: {exc}", file=sys.stderr)
        return 2
    text = study(a.seeds, a.out)
    atomic_write_text(a.out / "trial.csv", text, force=True)  # the study's own folder (`check_out`)
    print(text, end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
