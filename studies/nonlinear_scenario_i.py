"""`ml-gn` with the nonlinear model on noisy Scenario I, against the captive reference, and the
identified model's prediction of held-out manoeuvres inside Scenario I's region.

The captive reference of the bundled torpedo (`captive_config`, `--model`: by default the
component model, 23 terms of the hull's and the four fin blades' forces at their own flow and the
six Kirchhoff terms of the inertia M leaves out; `polynomial`: the 102 polynomial terms; the
inertia from the PMM tests) is the reference, and each fit starts from its own a-priori values
about it (`priors.term_prior` at `--spread`, the campaign's rule: each free term moved by
exp(s_c z), z drawn per seed). The plant flies Scenario I for seeds 1..N (the same noise-free
truth every seed, the sensors' noise drawn per seed; `--rate 100`: its autopilots and record at
the plant's physics rate, where the fins are held over every sample interval; `--fin-rate 100`:
its fins logged at the physics rate, the servos' steps, its states still at 50 Hz, missing in
between); `ml-gn` fits each seed's record through the front door (`estimators.identify`, its
`auto` start, converged when every step is below 0.01 σ) with `--free` free, and the record's
noise-free truth too (`noise-free`: the noise σ given as the sensors', so its bounds are a noisy
record's) — where the fits would scatter about if the noise alone
moved them. Per coefficient: the estimate, its Cramér-Rao σ and coloured-residual σ, the error
in the coloured σ (the honest one for residuals that are not white) and in % of the captive
value, and whether it is within max(3 σ, 10 %) of it; per channel the residual rms over the
sensor's σ.

Default free list, on seed 1's record at the captive values: for the component model, what the
screen (`screening.screening` with `NONLINEAR`, as `testbed identify --config` runs it)
frees of its 23 component terms; for the polynomial terms, the 19 slope terms (`slope_terms`)
and the cross-flow terms whose bound with all 102 free is below `--level`.

Held-out manoeuvres inside Scenario I's region (±20 °/s of yaw rate, sway within ±0.5 m/s):
a turning circle, the rudder stepped to `--rudder` rad (default 0.015: an 18.9 °/s, 112 m turn)
after 2 s and held for 28 s, and a zigzag of ±`--rudder` switched at ±`--switch` degrees of
heading (default 15°, Scenario I's heading swing), depth and roll held by the autopilots. The
plant flies them (noise-free truth); each identified model, the captive model and the analytic
linear model fly open loop from the truth's first state with its fin angles
(`nonlinear_flight.fly_nonlinear`, `regime.open_loop`); the metrics (`experiment_metrics`: tactical
diameter, steady turn rate, first and second overshoots) are compared with the plant's.

Outputs in `--out`: one run directory per seed (`seed<k>`), `turn` and `zigzag` (the held-out
runs), `coefficients.csv`, `residuals.csv`, `manoeuvres.csv` and `summary.md` (`summary`: the
tables of docs/studies.md). An existing output is refused
unless `--force` (then only the study's own run directories and tables are replaced).

    python studies/nonlinear_scenario_i.py --seeds 5 --out runs/nonlinear-scenario-i
"""

from __future__ import annotations

import argparse
import csv
import io
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from testbed.analysis.manoeuvres import experiment_metrics
from testbed.analysis.screening import screening
from testbed.analysis.nonlinear_identifiability import NONLINEAR, nonlinear_identifiability
from testbed.analysis.regime import open_loop
from testbed.analysis.track import record_track
from testbed.data import Experiment, ModelConfig, load_data, read_csv
from testbed.outputs import atomic_write_text, check_output_directory, check_output_file
from testbed.errors import InputError
from testbed.estimators import Estimate, identify
from testbed.identification.nonlinear_prediction import predict_nonlinear
from testbed.models.linear import STATES
from testbed.models.nonlinear_flight import fly_nonlinear
from testbed.captive.config import MODELS, captive_config
from testbed.study.priors import term_prior
from testbed.captive.reference import slope_terms
from testbed.simulation.measurements import NOISE_STD
from testbed.simulation.runs import simulate
from testbed.simulation.scenario import read_scenario, scenario

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run as a script, too
from studies.trial import sigma  # noqa: E402  (the coloured-residual σ where the fit gives it)

RELATIVE = 0.10  # the bullet's relative band about the captive value
TOL = 0.01  # ml-gn converged when every step is below 0.01 of its Cramér-Rao σ
SIGMAS = 3.0
TABLES = ("coefficients.csv", "residuals.csv", "manoeuvres.csv", "summary.md")
HELD_OUT = ("turn", "zigzag")
METRICS = {
    "turn": ("tactical_diameter", "steady_turn_rate"),
    "zigzag": ("first_overshoot", "second_overshoot"),
}


def scenario_i(rate: float, fin_rate: float | None = None):
    """Scenario I with its autopilots and its record at `rate` Hz, its fins logged at `fin_rate`
    Hz (None: at `rate`)."""
    s = scenario("I")
    return replace(s, control_rate=rate, sensors=replace(s.sensors, rate=rate, fin_rate=fin_rate))


def check_out(out: Path, seeds: int, force: bool) -> None:
    """`InputError` unless every output can be written: new, or with `force` the study's own
    (run directories, its tables)."""
    for name in [f"seed{k}" for k in range(1, seeds + 1)] + list(HELD_OUT):
        check_output_directory(out / name, force=force)
    if out.is_dir():
        for name in TABLES + tuple(f"{h}.toml" for h in HELD_OUT):
            check_output_file(out / name, force=force)


def default_free(config: ModelConfig, record: Experiment, level: float) -> tuple[str, ...]:
    """The free list (module doc): for the component model, what the screen frees of its
    candidates on `record` at the config's values; for the polynomial terms, the slope terms and
    the other terms whose Cramér-Rao bound with all terms free, at the config's values on
    `record`, is below `level` × |value|."""
    terms = tuple(config.terms)
    if config.components:
        screen = screening([record], config, model=NONLINEAR)
        for n, why in screen.fixed.items():
            print(f"  screen fixes {n:24s} {why}", file=sys.stderr)
        return screen.config.free
    slopes = slope_terms(terms)
    idf = nonlinear_identifiability([record], replace(config, free=terms))
    relative = idf.crlb_std / np.abs(idf.values)
    ranked = sorted((r, n) for n, r in zip(idf.free, relative) if n not in slopes and r < level)
    for r, n in ranked:
        print(f"  {n:12s} relative Cramér-Rao bound {r:.3f}", file=sys.stderr)
    return slopes + tuple(n for _, n in ranked)


def scenario_files(out: Path, rudder: float, switch: float) -> dict[str, Path]:
    """The held-out manoeuvres' scenario files (module doc), written in the study's folder."""
    common = 'depth = 100.0\ncontrol_rate = 50.0\nduration = 30.0\n\n[[experiment]]\nname = "{0}"\n'
    held = "autopilot = {depth = 0.0, roll = 0.0}\n"
    texts = {
        "turn": f'name = "turn-{rudder:g}"\n'
        + common.format("turn")
        + f'rudder = {{signal = "step", amplitude = {-rudder!r}, start = 2.0}}\n'
        + held,
        "zigzag": f'name = "zigzag-{rudder:g}-{switch:g}"\n'
        + common.format("zigzag")
        + f'rudder = {{signal = "zigzag", angle = {rudder!r}, switch = {math.radians(switch)!r}, on = "psi"}}\n'
        + held,
    }
    files = {}
    for name, text in texts.items():
        files[name] = out / f"{name}.toml"
        atomic_write_text(files[name], text, force=True)  # the study's own folder (`check_out`)
    return files


def fitted(config: ModelConfig, est: Estimate) -> ModelConfig:
    return config.with_coefficients(dict(zip(est.free, est.values)))


def ratios(experiments, config: ModelConfig, initial=None) -> str:
    """The residual rms per state of `config`'s model on `experiments` (flown from `initial`,
    else the best-fitting initial states) over the sensor's noise σ, over the samples present,
    as CSV cells."""
    y = np.concatenate([e.y for e in experiments])
    yhat = np.concatenate(predict_nonlinear(experiments, config, initial))
    rms = np.sqrt(np.nanmean((y - yhat) ** 2, axis=0))
    by = dict(zip(experiments[0].measured, rms))
    return ",".join(f"{by[s] / NOISE_STD[s]:.3f}" if s in by else "" for s in STATES)


def flown(config: ModelConfig, truth: Experiment) -> Experiment:
    """The nonlinear model of `config` flown open loop on the truth's fins from its first state."""
    model, theta = config.nonlinear()
    x0 = np.array([truth.column(s)[0] for s in STATES])
    with np.errstate(all="ignore"):
        x = fly_nonlinear(model, theta, truth.t, x0, truth.inputs)
    return replace(truth, measured=STATES, y=x)


def metrics(spec, record: Experiment, where: str) -> dict[str, float]:
    """The manoeuvre's metrics of `record` (NaN where it flies none)."""
    kind = "turn" if spec.name == "turn" else "zigzag"
    try:
        m = experiment_metrics(spec, record_track(record), where)
    except (InputError, ValueError) as exc:
        print(f"  {where}: {exc}", file=sys.stderr)
        return {k: math.nan for k in METRICS[kind]}
    return {k: float(getattr(m, k)) for k in METRICS[kind]}


def study(
    seeds: int,
    out: Path,
    free: tuple[str, ...] | None,
    level: float,
    rudder: float,
    switch: float,
    force: bool,
    model: str = "components",
    spread: float = 0.4,
    rate: float = 50.0,
    fin_rate: float | None = None,
):
    out.mkdir(parents=True, exist_ok=True)
    captive, *_ = captive_config(model=model)
    runs = [
        simulate(scenario_i(rate, fin_rate), seed=k, out=out / f"seed{k}", force=force)
        for k in range(1, seeds + 1)
    ]
    truth = read_csv(runs[0] / "scenario-I.truth.csv", "scenario-I", keep_repeats=True)
    data = {f"seed {k}": load_data([run])[0] for k, run in enumerate(runs, 1)}
    if free is None:
        free = default_free(captive, data["seed 1"][0], level)
    print(f"free ({len(free)}): {' '.join(free)}", file=sys.stderr)
    # the truth with the noisy records' samples only (the states between them missing)
    truth = replace(truth, y=np.where(np.isnan(data["seed 1"][0].y), np.nan, truth.y))
    sensors = {s: NOISE_STD[s] for s in STATES}
    fits, experiments_of = {}, {"noise-free": [truth]} | data
    for k, (label, experiments) in enumerate(experiments_of.items()):
        # each seed's own a-priori start (the noise-free fit seed 1's), as a user's guess
        start = term_prior(replace(captive, free=free), free, spread, max(k, 1))
        config = start.with_noise_std(sensors) if label == "noise-free" else start
        t0 = time.perf_counter()
        fits[label] = identify(experiments, config, "ml-gn", options={"tol": TOL})
        est = fits[label]
        print(
            f"{label:10s} {est.status.name} from {est.start}, {est.iterations} it {time.perf_counter() - t0:.1f} s",
            file=sys.stderr,
        )

    coefficients = io.StringIO()
    coefficients.write(
        "fit,coefficient,estimate,crlb_sigma,coloured_sigma,captive,error_sigmas,error_percent,within\n"
    )
    residuals = io.StringIO()
    residuals.write("fit,status,iterations," + ",".join(f"{s}_rms_over_sensor" for s in STATES) + "\n")
    for label, est in fits.items():
        for n, v, s, sc in zip(est.free, est.values, est.std, sigma(est)):
            ref = captive.terms[n]
            # a fit that did not converge, or whose bound is infinite, tells nothing
            within = (
                est.converged and math.isfinite(sc) and abs(v - ref) <= max(SIGMAS * sc, RELATIVE * abs(ref))
            )
            coefficients.write(
                f"{label},{n},{v:.6g},{s:.3g},{sc:.3g},{ref:.6g},{(v - ref) / sc:+.2f},"
                f"{100 * (v - ref) / abs(ref):+.2f},{'yes' if within else 'no'}\n"
            )
        residuals.write(
            f"{label},{est.status.name},{est.iterations},{ratios(experiments_of[label], fitted(captive, est), est.initial_states)}\n"
        )
    for label in ("noise-free", "seed 1"):  # the captive model itself, from its best initial states
        residuals.write(f"captive on {label},,,{ratios(experiments_of[label], captive)}\n")

    manoeuvres = io.StringIO()
    manoeuvres.write("manoeuvre,metric,model,value,percent_from_plant\n")
    for name, file in scenario_files(out, rudder, switch).items():
        run = simulate(str(file), seed=1, out=out / name, force=force)
        spec = read_scenario(run / "scenario.toml").experiments[0]
        plant = read_csv(run / f"{name}.truth.csv", name, keep_repeats=True)
        linear = load_data([run])[1]
        models = {"plant": plant, "captive": flown(captive, plant)}
        models["linear"] = replace(plant, measured=STATES, y=open_loop([plant], linear)[0])
        models |= {label: flown(fitted(captive, est), plant) for label, est in fits.items()}
        values = {m: metrics(spec, record, f"{name} {m}") for m, record in models.items()}
        for metric in METRICS[name]:
            reference = values["plant"][metric]
            for m, v in values.items():
                pct = 100 * (v[metric] - reference) / abs(reference)
                manoeuvres.write(f"{name},{metric},{m},{v[metric]:.6g},{pct:+.2f}\n")
    tables = coefficients.getvalue(), residuals.getvalue(), manoeuvres.getvalue()
    return *tables, summary(tables[0], tables[2])


def _span(values, fmt: str) -> str:
    low, high = fmt.format(min(values)), fmt.format(max(values))
    return low if low == high else f"{low} to {high}"


def summary(coefficients: str, manoeuvres: str) -> str:
    """The study's two tables in Markdown (docs/studies.md): per coefficient the seeds' range of
    estimates and errors, how many are within, and the noise-free fit's error; per manoeuvre
    metric the plant's value and each model's % from it (the seeds as a range)."""
    rows = list(csv.DictReader(io.StringIO(coefficients)))
    seeds = [label for label in dict.fromkeys(r["fit"] for r in rows) if label.startswith("seed")]
    out = io.StringIO()
    n = len(seeds)
    out.write(
        f"| coefficient | captive | seeds 1–{n}: estimate | error % | error / σ | within | noise-free: error % |\n"
        "|---|---|---|---|---|---|---|\n"
    )
    for name in dict.fromkeys(r["coefficient"] for r in rows):
        of = {r["fit"]: r for r in rows if r["coefficient"] == name}
        cells = [
            _span([float(of[s][k]) for s in seeds], fmt)
            for k, fmt in (("estimate", "{:.4g}"), ("error_percent", "{:+.0f}"), ("error_sigmas", "{:+.1f}"))
        ]
        within = sum(of[s]["within"] == "yes" for s in seeds)
        out.write(
            f"| {name.replace('|', '&#124;')} | {float(of[seeds[0]]['captive']):.4g} | {' | '.join(cells)} | "
            f"{within}/{n} | {float(of['noise-free']['error_percent']):+.0f} |\n"
        )
    misses = [sum(r["within"] == "no" for r in rows if r["fit"] == s) for s in seeds]
    out.write(f"\nMisses per seed: {', '.join(map(str, misses))} of {len(rows) // (n + 1)}.\n\n")
    rows = list(csv.DictReader(io.StringIO(manoeuvres)))
    out.write(f"| metric | plant | identified (seeds 1–{n}) | noise-free fit | captive | analytic linear |\n")
    out.write("|---|---|---|---|---|---|\n")
    for key in dict.fromkeys((r["manoeuvre"], r["metric"]) for r in rows):
        of = {r["model"]: r for r in rows if (r["manoeuvre"], r["metric"]) == key}
        pct = {m: float(r["percent_from_plant"]) for m, r in of.items()}
        cells = [_span([pct[s] for s in seeds], "{:+.2f} %")] + [
            f"{pct[m]:+.2f} %" for m in ("noise-free", "captive", "linear")
        ]
        out.write(f"| {key[0]}: {key[1]} | {float(of['plant']['value']):.6g} | {' | '.join(cells)} |\n")
    return out.getvalue()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--out", type=Path, default=Path("runs/nonlinear-scenario-i"))
    ap.add_argument(
        "--free",
        default=None,
        help="comma-separated terms to free (default: the study's rule for the model, module doc)",
    )
    ap.add_argument(
        "--level",
        type=float,
        default=0.15,
        help="the polynomial model's default free list: the relative Cramér-Rao bound below which it "
        "takes a cross-flow term (module doc)",
    )
    ap.add_argument("--rudder", type=float, default=0.015, help="the held-out manoeuvres' rudder, rad")
    ap.add_argument("--switch", type=float, default=15.0, help="the zigzag's switching heading, degrees")
    ap.add_argument(
        "--spread",
        type=float,
        default=0.4,
        help="the start's spread about the captive values (the campaign's a-priori rule; 0: the captive values)",
    )
    ap.add_argument(
        "--rate",
        type=float,
        choices=(50.0, 100.0),
        default=50.0,
        help="Scenario I's control and sample rate, Hz: its own 50 (default), or 100, the plant's physics "
        "rate, where the fins are held over every sample interval",
    )
    ap.add_argument(
        "--fin-rate",
        type=float,
        default=None,
        help="Hz: Scenario I's fins logged this often (`[sensors] fin_rate`; 100: every step of the "
        "plant's servos), its states still at --rate (default: the fins at --rate)",
    )
    ap.add_argument("--force", action="store_true", help="replace the study's own outputs in --out")
    ap.add_argument(
        "--model",
        choices=MODELS,
        default="components",
        help="the captive reference's nonlinear model (default: components)",
    )
    a = ap.parse_args(argv)
    free = tuple(n.strip() for n in a.free.split(",") if n.strip()) if a.free else None
    try:
        if a.seeds < 1:
            raise InputError(f"--seeds {a.seeds}; expected 1 or more")
        check_out(a.out, a.seeds, a.force)
        scenario_i(a.rate, a.fin_rate)
        unknown = [n for n in free or () if n not in captive_config(model=a.model)[0].terms]
        if unknown:
            raise InputError(f"--free: {unknown[0]!r} is not a term of the captive model")
    except InputError as exc:
        print(f"nonlinear_scenario_i.py: {exc}", file=sys.stderr)
        return 2
    tables = study(
        a.seeds, a.out, free, a.level, a.rudder, a.switch, a.force, a.model, a.spread, a.rate, a.fin_rate
    )
    for name, text in zip(TABLES, tables):
        atomic_write_text(a.out / name, text, force=True)  # checked before the work (`check_out`)
        print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
