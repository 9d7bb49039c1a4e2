"""Output error and the filter-error method on data with process noise (turbulence).

Scenario II flown on the linear truth (the analytic model of the bundled torpedo, so the
coefficients the data come from are known exactly) with the truth's turbulence, body-axis force
and moment disturbances as first-order Gauss-Markov processes ([trial.turbulence],
docs/files.md), at `--scale` times the loads of a 0.01 m/s velocity fluctuation (`II-trial`'s
at scale 0.1) and correlation time `--time`, its autopilots reading the sensors
(`feedback = "measured"`; `--feedback true`: the true states, and then in the horizontal and roll
records the elevators move only against the turbulence). Every seed's run is fitted by `ml-gn`
and `ml-fem` from the same guess, the run's free coefficients × exp(0.3 N(0, 1)); `ml-fem` models
the process noise as coloured with the turbulence's correlation time (`--fem-time`: another; 0,
white). `--open-loop` fits each seed's records flown again without their autopilots, driven by
their recorded fins through the same dynamics and turbulence (`flown_open_loop`). Per coefficient
the table gives each method's mean error over its mean σ (unbiased: |·| < 0.5) and its mean σ
over the scatter of its estimates (honest bounds: 0.7–1.4).

    python studies/turbulence.py --seeds 20 --out runs/turbulence
"""

from __future__ import annotations

import argparse
import io
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from testbed.data import Experiment, load_data
from testbed.models.linear import IX, NX, STATES, continuous, discretize, structure, theta_vector, tilde
from testbed.simulation.measurements import NOISE_STD
from testbed.simulation.trial import gauss_markov
from testbed.outputs import atomic_write_text
from testbed.errors import InputError
from testbed.simulation.runs import simulate
from testbed.simulation.scenario import FEEDBACKS, scenario, scenario_text

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run as a script, too
from studies.seeds import check_out, fit_seeds, guess, scatter  # noqa: E402

METHODS = ("ml-gn", "ml-fem")
FORCE_STD = (2.7, 21.0, 21.0)  # N: a 0.01 m/s fluctuation's loads, ten times II-trial's
MOMENT_STD = (0.3, 6.3, 6.3)  # N m


def scenario_file(out: Path, scale: float, time: float, duration: float | None, feedback: str) -> Path:
    """Scenario II with the turbulence at `scale` of a 0.01 m/s fluctuation's, correlation `time`
    s, its autopilots reading `feedback` (FEEDBACKS)."""
    text = scenario_text(replace(scenario("II"), feedback=feedback))
    force = ", ".join(f"{scale * f:g}" for f in FORCE_STD)
    moment = ", ".join(f"{scale * m:g}" for m in MOMENT_STD)
    table = f"[trial.turbulence]\nforce_std = [{force}]\nmoment_std = [{moment}]\ntime = {time:g}\n\n"
    first = text.index("[[experiment]]")
    text = text[:first] + table + text[first:]
    text = text.replace('name = "II"', 'name = "II-turbulence"', 1)
    if duration is not None:
        text = text.replace("duration = 60.0", f"duration = {duration:g}", 1)
    path = out / "II-turbulence.toml"
    atomic_write_text(path, text, force=True)  # the study's own folder (`check_out`)
    return path


def flown_open_loop(experiments, config, scale: float, time: float, rng) -> list[Experiment]:
    """The records flown again without their autopilots: the linear truth (the analytic model,
    exact zero-order hold at the record's step) driven by the recorded fins, with turbulence of the
    same spectrum (body-axis loads through Mt⁻¹, each a Gauss-Markov process held over the step,
    as the truth's) and the same sensor noise, drawn from `rng`."""
    st, theta = structure(config.vehicle), theta_vector(config.coefficients)
    Mt = tilde(st, theta)[0]
    A, B, S = continuous(st, theta)
    W = np.linalg.solve(Mt, np.eye(NX)[:, :6])  # the state derivative per unit load
    std = scale * np.array(FORCE_STD + MOMENT_STD)
    noise = np.array([NOISE_STD[s] for s in STATES])
    out = []
    for e in experiments:
        dt = float(e.t[1] - e.t[0])
        Phi, Gamma, s = discretize(A, np.hstack([B, W]), S, dt)
        loads = gauss_markov(std, time, dt, len(e.t), rng)
        x = np.zeros((len(e.t), NX))
        for k in range(len(e.t) - 1):
            x[k + 1] = Phi @ x[k] + Gamma @ np.r_[e.inputs[k], loads[k]] + s
        x[:, IX["u"]] += config.vehicle.speed
        out.append(replace(e, measured=STATES, y=x + rng.normal(size=x.shape) * noise))
    return out


def study(
    seeds: int,
    scale: float,
    time: float,
    out: Path,
    duration: float | None = None,
    fem_time: float | None = None,
    open_loop: bool = False,
    feedback: str = "measured",
) -> str:
    """Run the study; return the table as CSV text. `fem_time`: the correlation time `ml-fem`
    models the process noise with (None: the turbulence's, `time`; 0: white); `open_loop`: each
    seed's records flown again open loop with their recorded fins (`flown_open_loop`);
    `feedback`: what the autopilots read (FEEDBACKS)."""
    out.mkdir(parents=True, exist_ok=True)
    file = scenario_file(out, scale, time, duration, feedback)
    runs = [
        simulate(str(file), seed=s + 1, out=out / f"seed{s + 1}", force=True, truth="linear")
        for s in range(seeds)
    ]
    config = replace(load_data([runs[0]])[1], screen=False)
    truth = np.array([config.coefficients[n] for n in config.free])

    def data(seed: int):
        experiments = load_data([runs[seed]])[0]
        if not open_loop:
            return experiments
        return flown_open_loop(experiments, config, scale, time, np.random.default_rng(10_000 + seed))

    start = guess(config, np.random.default_rng(1000))
    fem_time = time if fem_time is None else fem_time
    fits = fit_seeds(seeds, data, start, METHODS, {"ml-fem": {"correlation_time": fem_time}})
    spread = {m: scatter(fits[m], truth) for m in METHODS}
    table = io.StringIO()
    table.write(
        "coefficient,analytic," + ",".join(f"{m}_bias_sigmas,{m}_sigma_over_scatter" for m in METHODS) + "\n"
    )
    for i, n in enumerate(config.free):
        cells = [
            f"{spread[m].bias[i] / spread[m].reported[i]:.3f},{spread[m].reported[i] / spread[m].std[i]:.3f}"
            for m in METHODS
        ]
        table.write(f"{n},{truth[i]:.6g}," + ",".join(cells) + "\n")
    used = ", ".join(f"{m} {spread[m].used}/{seeds} converged" for m in METHODS)
    read = "true states" if feedback == "true" else "sensors"
    again = ", flown again open loop" if open_loop else ""
    table.write(
        f"# {used}; turbulence {scale:g} × a 0.01 m/s fluctuation's, correlation {time:g} s; "
        f"ml-fem's process noise correlation {fem_time:g} s; autopilots reading the {read}{again}\n"
    )
    return table.getvalue()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument(
        "--scale",
        type=float,
        default=0.1,
        help="the turbulence's size, × a 0.01 m/s fluctuation's loads (II-trial: 0.1)",
    )
    ap.add_argument("--time", type=float, default=0.5, help="its correlation time, s")
    ap.add_argument("--duration", type=float, default=None, help="s per experiment (default: II's)")
    ap.add_argument(
        "--fem-time",
        type=float,
        default=None,
        help="the correlation time ml-fem models the process noise with, s (default: --time; 0: white)",
    )
    ap.add_argument(
        "--open-loop",
        action="store_true",
        help="fit each seed's records flown again open loop, driven by their recorded fins",
    )
    ap.add_argument(
        "--feedback",
        choices=FEEDBACKS,
        default="measured",
        help="what the autopilots read: the sensors (measured, default) or the true states",
    )
    ap.add_argument("--out", type=Path, default=Path("runs/turbulence"))
    args = ap.parse_args(argv)
    try:
        check_out(args.out, args.seeds, ("turbulence.csv", "II-turbulence.toml"))
    except InputError as exc:
        print(f"turbulence.py: {exc}", file=sys.stderr)
        return 2
    text = study(
        args.seeds,
        args.scale,
        args.time,
        args.out,
        args.duration,
        args.fem_time,
        args.open_loop,
        args.feedback,
    )
    atomic_write_text(args.out / "turbulence.csv", text, force=True)
    print(text, end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
