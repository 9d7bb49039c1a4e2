"""The command line: a thin layer over the library.

Each sub-command parses its arguments, calls one library function and prints where its output
went. Bad input is an `InputError`: one line on stderr, exit status 2.
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import sys
import time
import traceback
from pathlib import Path

from testbed.threads import one_blas_thread

__all__ = ["BUILTIN_SCENARIOS", "INTERNAL_ERROR", "main", "parser"]

one_blas_thread()  # before numpy loads

from testbed.errors import InputError  # noqa: E402

STDOUT = Path("-")  # `--out -`: standard output


def _number(text: str, zero: bool) -> float:
    """`text` as a finite number > 0, or ≥ 0 where `zero` is allowed; argparse's error otherwise."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (0 <= v if zero else 0 < v) or v == float("inf"):
        raise argparse.ArgumentTypeError(f"{text} must be a finite number {'>=' if zero else '>'} 0")
    return v


def _positive(text: str) -> float:
    return _number(text, zero=False)


def _non_negative(text: str) -> float:
    return _number(text, zero=True)


def _seed(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"{text} must be an integer >= 0")
    return v


def _noise_std(text: str) -> dict[str, float]:
    """`--noise-std r=0.002,psi=0.01`: state → σ (SI), checked (`data.check_noise_std`)."""
    from testbed.data import check_noise_std

    values = {}
    for pair in filter(None, (p.strip() for p in text.split(","))):
        name, eq, value = (part.strip() for part in pair.partition("="))
        if not eq:
            raise argparse.ArgumentTypeError(f"{pair!r}: expected state=σ pairs, e.g. r=0.002,psi=0.01")
        if name in values:
            raise argparse.ArgumentTypeError(f"{text!r} gives {name} twice")
        try:
            values[name] = float(value)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{pair!r}: {value!r} is not a number") from None
    if not values:
        raise argparse.ArgumentTypeError(f"{text!r}: expected state=σ pairs, e.g. r=0.002,psi=0.01")
    try:
        return check_noise_std(values, repr(text))
    except InputError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _to_stdout(path: Path | None) -> Path | None:
    """None (standard output) for `--out -`, else the path."""
    return None if path == STDOUT else path


def _check_recording(path: Path | None) -> None:
    """A Rerun recording is written to a file, never to standard output (`--rrd -`)."""
    if path == STDOUT:
        raise InputError("--rrd -: a recording is a file; expected a file name (.rrd)")


def _emit(out: Path | None, text: str) -> None:
    """Say where the output went, or print it when it went nowhere else."""
    if out is None:
        sys.stdout.write(text)
    else:
        print(out)


class ProgressBar:
    """`bar(fraction, label)`: a one-line progress bar on stderr, drawn only on a terminal."""

    def __init__(self, enabled: bool = True):
        self.live = enabled and sys.stderr.isatty()
        self.t0 = time.perf_counter()

    def __call__(self, fraction: float, label: str) -> None:
        if self.live:
            sys.stderr.write(f"\r[{'#' * int(30 * fraction):<30}] {100 * fraction:3.0f}% {label:<40}")
            sys.stderr.flush()

    def close(self) -> None:
        if self.live:
            sys.stderr.write(f"\r[{'#' * 30}] 100% done in {time.perf_counter() - self.t0:.1f} s{' ' * 40}\n")


def _quiet_mujoco() -> None:
    """The plant turns MuJoCo's warnings into one-line errors; don't print or log them twice."""
    import mujoco

    mujoco.set_mju_user_warning(lambda message: None)


def _cmd_analytic(args) -> int:
    from testbed.simulation.analytic import analytic_config_text

    _quiet_mujoco()
    out = _to_stdout(args.out)
    _emit(out, analytic_config_text(args.mjcf, args.speed, out, args.force))
    return 0


def _cmd_captive(args) -> int:
    _quiet_mujoco()
    out = _to_stdout(args.out)
    _check_recording(args.rrd)
    written = []
    if args.figures is None and args.rrd is None:  # no figures: matplotlib and Rerun not loaded
        from testbed.captive.config import captive_config_text

        text, fit = captive_config_text(args.mjcf, args.speed, out, args.force, args.model)
    else:
        from testbed.presentation.captive_report import write_captive

        text, fit, written = write_captive(
            args.mjcf, args.speed, out, args.figures, args.rrd, args.force, args.model
        )
    _emit(out, text)
    stream = sys.stderr if out is None else sys.stdout  # standard output may carry the TOML
    print(fit.table(), file=stream)
    for path in written:
        print(path, file=stream)
    return 0


def _cmd_simulate(args) -> int:
    from testbed.simulation.runs import simulate
    from testbed.simulation.scenario import TRUTHS

    if args.out == STDOUT:
        raise InputError("--out -: a run directory is a folder, not standard output; expected a folder name")
    if args.truth not in TRUTHS:
        raise InputError(f"--truth {args.truth}; expected one of {', '.join(TRUTHS)}")
    _quiet_mujoco()
    bar = ProgressBar(not args.quiet)
    run = simulate(
        args.scenario,
        seed=args.seed,
        out=args.out,
        force=args.force,
        duration=args.duration,
        speed=args.speed,
        mjcf=args.mjcf,
        progress=bar,
        truth=args.truth,
    )
    bar.close()
    print(run)
    return 0


def _cmd_identify(args) -> int:
    from testbed.estimators import lookup
    from testbed.jobs import identify_data

    out = _to_stdout(args.out)
    _check_recording(args.rrd)
    given = {
        "start": args.start,
        "max_iter": args.max_iter,
        "max_samples": args.max_samples,
        "process_noise": args.process_noise,
        "correlation_time": args.correlation_time,
    }
    options = {k: v for k, v in given.items() if v is not None}
    live = sys.stderr.isatty() and lookup(args.method).iterative  # a progress line (ml-nm runs for minutes)

    def progress(step):
        print(
            f"\r{args.method}: iteration {step.iteration}, cost {step.cost:.6g}",
            end="",
            file=sys.stderr,
            flush=True,
        )

    done = identify_data(
        args.data,
        method=args.method,
        config=args.config,
        out=out,
        rrd=args.rrd,
        options=options,
        perturb=args.perturb,
        perturb_spread=args.perturb_spread,
        report=args.report,
        seed=args.seed,
        screen=args.screen,
        noise_std=args.noise_std,
        progress=progress if live else None,
        corrections=args.corrections,
        keep_repeats=args.keep_repeats,
        force=args.force,
        reference=args.reference,
    )
    estimate = done.estimate
    if live and estimate.iterations:
        print(file=sys.stderr)  # end the progress line
    if estimate.start_reason:
        print(
            f"testbed identify: kept the fit from the {estimate.start} start, {estimate.start_reason}",
            file=sys.stderr,
        )
    if "screen_skipped" in done.document:
        print(
            "testbed identify: the screen fixed nothing for these data at the a-priori values: "
            + done.document["screen_skipped"],
            file=sys.stderr,
        )
    if done.comparison is not None:
        print(done.comparison.table(), file=sys.stderr)
    width = max([11, *map(len, done.fixed)])
    for n, why in done.fixed.items():
        print(f"{n:<{width}} fixed at {done.config.values[n]:.4g}: {why}", file=sys.stderr)
    if done.screen and not done.fixed:
        print(
            f"testbed identify: estimated as listed; the screen would fix {', '.join(done.screen)} "
            '(the estimates JSON\'s "screen" says why; --screen applies it)',
            file=sys.stderr,
        )
    print(done.validation.table(), file=sys.stderr)
    for path in done.written:
        print(path, file=sys.stderr if path == args.rrd else sys.stdout)
    if out is None:
        sys.stdout.write(done.text)
    if not estimate.converged:
        print(f"testbed identify: not converged: {estimate.status.message}", file=sys.stderr)
        return 1
    return 0


def _cmd_analyze(args) -> int:
    from testbed.jobs import analyze_data

    out = _to_stdout(args.out)
    result = analyze_data(
        args.data,
        config=args.config,
        out=out,
        noise_std=args.noise_std,
        keep_repeats=args.keep_repeats,
        force=args.force,
        report=args.report,
    )
    _emit(out, result.to_json())
    for line in result.summary:
        print(line, file=sys.stderr)
    return 0


def _cmd_check(args) -> int:
    from testbed.jobs import check_data

    out = _to_stdout(args.out)
    result = check_data(
        args.data, out=out, keep_repeats=args.keep_repeats, force=args.force, report=args.report
    )
    if args.out == STDOUT:
        sys.stdout.write(result.to_json())
        print(result.table(), end="", file=sys.stderr)
        return 0
    sys.stdout.write(result.table())
    if out is not None:
        print(out)
    return 0


def _cmd_validate(args) -> int:
    from testbed.analysis.manoeuvres import compared_table
    from testbed.jobs import validate_data

    out = _to_stdout(args.out)
    validation, text, manoeuvres = validate_data(
        args.data,
        args.estimates,
        config=args.config,
        out=out,
        keep_repeats=args.keep_repeats,
        force=args.force,
        report=args.report,
    )
    _emit(out, text)
    print(validation.table(), file=sys.stderr)
    if manoeuvres:
        print(compared_table(manoeuvres), file=sys.stderr)
    return 0


def _cmd_design(args) -> int:
    from testbed.presentation.design_report import table, write_design

    if args.out == STDOUT:
        raise InputError("--out -: the design is a scenario file; expected a file name (.toml)")
    _check_recording(args.rrd)
    _quiet_mujoco()
    free = [n.strip() for n in args.free.split(",") if n.strip()] if args.free else None
    result = write_design(
        args.out,
        args.duration,
        args.criterion,
        free,
        args.mjcf,
        args.speed,
        args.start_from,
        args.rrd,
        args.force,
    )
    print(table(result), file=sys.stderr)
    print(args.out)
    if args.rrd is not None:
        print(args.rrd, file=sys.stderr)
    return 0


def _cmd_reproduce(args) -> int:
    from testbed.study.campaign import reproduce

    _quiet_mujoco()
    bar = ProgressBar()
    done = reproduce(
        args.out,
        seeds=args.seeds,
        scheduler=args.scheduler,
        quick=args.quick,
        duration=args.duration,
        progress=bar,
        spreads=args.start_spread,
        arms=args.arms,
        truths=args.truth,
    )
    bar.close()
    print(
        f"testbed reproduce: {done.computed} cells computed, {done.reused} reused, {done.failed} failed, "
        f"in {done.wall_time_s:.0f} s",
        file=sys.stderr,
    )
    for k, v in done.conclusions.items():
        print(f"conclusion {k}: {v['verdict']}: {v['evidence']}", file=sys.stderr)
    print(done.out / "report.html")
    return 0


def _cmd_replay(args) -> int:
    from testbed.presentation.report import replay

    print(replay(args.run))
    return 0


def _flags(parser: argparse.ArgumentParser) -> list[tuple[str, str, bool | None, object]]:
    """(parameter name, the flag that sets it, the value it sets if a switch, else None, its
    default)."""
    return [
        (a.dest, max(a.option_strings, key=len), a.const if isinstance(a.const, bool) else None, a.default)
        for a in parser._actions
        if a.option_strings and a.dest != "help"
    ]


def in_flags(message: str, flags: list[tuple[str, str, bool | None, object]], args=None) -> str:
    """A library message names parameters as Python does (`max_iter=-1`, `force=True`,
    `screen=False`); the user typed flags (`--max-iter -1`, `--force`, `--free-all`). A parameter
    whose flag `args` leaves at its default is named as that default (`the default --out
    runs/reproduce`): the user typed no such flag."""
    for dest, flag, switch, default in flags:
        if switch is None:
            typed = args is None or getattr(args, dest, default) != default
            message = re.sub(rf"(?<![\w.-]){dest}=", f"{flag} " if typed else f"the default {flag} ", message)
        else:
            message = message.replace(f"{dest}={switch}", flag)
    return message


class _Parser(argparse.ArgumentParser):
    """argparse with a one-line error (no usage block) and exit status 2."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


KEEP_REPEATS_HELP = (
    "read a state that repeats its previous value while other states change as a sample "
    "(default: a slower sensor's stale repeat, missing; docs/files.md#measurement-csv)"
)
NOISE_STD_HELP = (
    "the sensors' noise σ per state, SI, e.g. r=0.002,psi=0.01 (for data whose noise cannot be "
    "read off them: low-pass filtered); replaces the config's [identify] noise_std entry by entry"
)
WRITES_FILES = ("analytic", "captive", "identify", "analyze", "check", "validate", "design")
FORCE_HELP = "replace an existing file at an output path (default: refused, exit 2)"
BUILTIN_SCENARIOS = (
    "I",
    "II",
    "II-trial",
    "inputs-3211",
    "inputs-multisine",
    "inputs-square",
    "lake",
    "turn",
    "turning-circle",
    "zigzag",
    "zigzag-vertical",
)  # testbed/simulation/scenarios/*.toml


def parser() -> argparse.ArgumentParser:
    p = _Parser(
        prog="testbed",
        description="Simulate a submerged body and identify its manoeuvring coefficients (Kim & Rhee).",
    )
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND", parser_class=_Parser)

    s = sub.add_parser("analytic", help="write the analytic linear model of an MJCF body (TOML)")
    s.add_argument("--mjcf", type=Path, default=None, help="MJCF file (default: the bundled torpedo)")
    s.add_argument("--speed", type=_positive, default=None, help="trim speed U, m/s (default: cruise)")
    s.add_argument("--out", type=Path, help="output TOML (default or -: stdout)")
    s.set_defaults(func=_cmd_analytic)

    s = sub.add_parser(
        "captive", help="fit the nonlinear model to virtual captive tests of an MJCF body (TOML)"
    )
    s.add_argument("--mjcf", type=Path, default=None, help="MJCF file (default: the bundled torpedo)")
    s.add_argument("--speed", type=_positive, default=None, help="trim speed U, m/s (default: cruise)")
    s.add_argument("--out", type=Path, help="output TOML (default or -: stdout; the fit table on stderr)")
    s.add_argument("--figures", type=Path, help="also draw each test's figure as a PNG in this new folder")
    s.add_argument("--rrd", type=Path, help="also log each test's figure to this Rerun recording")
    s.add_argument(
        "--model",
        choices=("components", "polynomial"),
        default="components",
        help="the nonlinear model fitted: the fluid forces of the hull and each fin blade at its own "
        "flow (default), or the polynomial Gertler-Hagen-style terms",
    )
    s.set_defaults(func=_cmd_captive)

    s = sub.add_parser("simulate", help="generate a scenario run directory")
    s.add_argument(
        "--scenario",
        required=True,
        help=f"a built-in scenario ({', '.join(BUILTIN_SCENARIOS)}) or a scenario file (.toml)",
    )
    s.add_argument("--seed", type=_seed, default=0, help="noise and PRBS seed (default 0)")
    s.add_argument("--out", type=Path, help="run directory (default: runs/<scenario>-seed<N>)")
    s.add_argument("--force", action="store_true", help="replace an existing run directory")
    s.add_argument("--duration", type=_positive, help="seconds per experiment (default: the scenario's)")
    s.add_argument("--speed", type=_positive, help="cruise speed, m/s (default: the vehicle's)")
    s.add_argument("--mjcf", type=Path, default=None, help="MJCF file (default: the bundled torpedo)")
    s.add_argument(
        "--truth",
        default="plant",
        help="what flies: plant (the MuJoCo plant, default) or linear (the run's analytic linear model)",
    )
    s.add_argument("--quiet", action="store_true", help="no progress bar")
    s.set_defaults(func=_cmd_simulate)

    s = sub.add_parser("identify", help="estimate the free coefficients from data")
    s.add_argument("data", nargs="+", type=Path, help="run directories or measurement CSVs")
    s.add_argument(
        "--method",
        default="ml-gn",
        help="ml-gn (default), ml-lm, ml-nr, ml-nm, ml-fem, mekf, ekf, equation-error; a nonlinear "
        "model config ([terms]): ml-gn, ml-nm, mekf or ekf",
    )
    s.add_argument(
        "--config", type=Path, help="model config TOML, linear or nonlinear (default: the run's model.toml)"
    )
    s.add_argument(
        "--out",
        type=Path,
        help="estimates JSON (default or -: stdout); mekf and ekf "
        "also write the estimate and ±σ histories to OUT with suffix .history.csv when "
        "OUT is a file",
    )
    s.add_argument(
        "--start",
        default=None,
        help="ml-* only: auto (default: from the a-priori values and the equation-error "
        "estimate, and the MEKF's if those end apart; the least cost is kept), config, "
        "equation-error, mekf, or global (auto's starts and the best of many drawn around "
        "the a-priori values)",
    )
    s.add_argument("--max-iter", type=int, default=None, help="iteration limit (ml-* methods)")
    s.add_argument("--max-samples", type=int, default=None, help="stop after this many samples (mekf, ekf)")
    s.add_argument(
        "--process-noise",
        default=None,
        metavar="ROWS",
        help="ml-fem only: the body rows with process noise: measured (default), none (output "
        "error), or body states such as v,r",
    )
    s.add_argument(
        "--correlation-time",
        type=float,
        default=None,
        metavar="S",
        help="ml-fem only: the process noise's correlation time (s; default 0, white), e.g. the "
        "turbulence's eddy length over the speed",
    )
    moved = s.add_mutually_exclusive_group()
    moved.add_argument(
        "--perturb",
        type=_positive,
        default=None,
        help="move every free coefficient's start by this fraction (e.g. 0.4), to test "
        "convergence from a poor a-priori model",
    )
    moved.add_argument(
        "--perturb-spread",
        type=_positive,
        default=None,
        metavar="S",
        help="multiply every free coefficient's start by exp(S·N(0,1)) (e.g. 0.3): the log-normal "
        "errors of an a-priori model, as the study draws them",
    )
    s.add_argument(
        "--seed", type=_seed, default=0, help="signs of --perturb, draws of --perturb-spread (default 0)"
    )
    s.add_argument("--rrd", type=Path, help="also log the fit to this Rerun recording")
    s.add_argument(
        "--report",
        type=Path,
        metavar="DIR",
        help="also write the fit's report to DIR/report.html (a new or empty folder): outputs against "
        "the model, residuals, coefficients with their bounds, correlations, convergence",
    )
    s.add_argument(
        "--reference",
        type=Path,
        metavar="CONFIG",
        help="a model config the report shows beside the estimates, e.g. the captive config a "
        "perturbed start came from (default: the run's model.toml for a linear fit, the config as "
        "written with --perturb or --perturb-spread)",
    )
    listed = s.add_mutually_exclusive_group()
    listed.add_argument(
        "--screen",
        action="store_true",
        default=None,
        help="estimate only the coefficients of [identify] free that the data determine, the "
        "others at their a-priori values (default where the config says screen = true, as a "
        "run's model.toml does)",
    )
    listed.add_argument(
        "--free-all",
        dest="screen",
        action="store_false",
        help="estimate every coefficient of [identify] free as listed, even a candidate list "
        "(screen = true); the screen is only reported (default for a config without it)",
    )
    s.add_argument("--noise-std", type=_noise_std, metavar="STATE=SIGMA,...", help=NOISE_STD_HELP)
    s.add_argument(
        "--corrections",
        type=Path,
        metavar="CHECK.json",
        help="a JSON of `testbed check`: correct the rates and velocities by its sensor biases, "
        "scale factors and delays before the fit",
    )
    s.add_argument("--keep-repeats", action="store_true", help=KEEP_REPEATS_HELP)
    s.set_defaults(func=_cmd_identify)

    s = sub.add_parser("analyze", help="identifiability: Fisher information, CRLB, drift groups")
    s.add_argument("data", nargs="+", type=Path, help="run directories or measurement CSVs")
    s.add_argument("--config", type=Path, help="model config TOML (default: the run's model.toml)")
    s.add_argument("--out", type=Path, help="identifiability JSON (default or -: stdout)")
    s.add_argument(
        "--report",
        type=Path,
        metavar="DIR",
        help="also write the analysis' report to DIR/report.html (a new or empty folder): the bounds, "
        "the correlation matrix and the drift groups",
    )
    s.add_argument("--noise-std", type=_noise_std, metavar="STATE=SIGMA,...", help=NOISE_STD_HELP)
    s.add_argument("--keep-repeats", action="store_true", help=KEEP_REPEATS_HELP)
    s.set_defaults(func=_cmd_analyze)

    s = sub.add_parser(
        "check", help="data compatibility: the kinematics reconstructed, sensor biases, scale factors, delays"
    )
    s.add_argument("data", nargs="+", type=Path, help="run directories or measurement CSVs")
    s.add_argument("--out", type=Path, help="check JSON (default: none, the table only; -: stdout)")
    s.add_argument(
        "--report",
        type=Path,
        metavar="DIR",
        help="also write the check's report to DIR/report.html (a new or empty folder): the corrections, "
        "each check's parameters pooled and per record, the reconstructions' fit",
    )
    s.add_argument("--keep-repeats", action="store_true", help=KEEP_REPEATS_HELP)
    s.set_defaults(func=_cmd_check)

    s = sub.add_parser(
        "validate",
        help="fit %% and residual whiteness of identified coefficients or a model config on (held-out) data",
    )
    s.add_argument("data", nargs="+", type=Path, help="run directories or measurement CSVs")
    s.add_argument(
        "--estimates",
        type=Path,
        help="estimates JSON from `testbed identify`, applied to the config (without it: the config as it stands)",
    )
    s.add_argument(
        "--config",
        type=Path,
        help="model config TOML, linear or nonlinear (default: the run's model.toml, or the "
        "config a nonlinear fit's estimates name)",
    )
    s.add_argument("--out", type=Path, help="validation JSON (default: stdout)")
    s.add_argument(
        "--report",
        type=Path,
        metavar="DIR",
        help="also write the validation's report to DIR/report.html (a new or empty folder): each "
        "record's outputs against the model, the residuals and their whiteness",
    )
    s.add_argument("--keep-repeats", action="store_true", help=KEEP_REPEATS_HELP)
    s.set_defaults(func=_cmd_validate)

    s = sub.add_parser("design", help="design experiments from Fisher information (a scenario file)")
    s.add_argument("--duration", type=_positive, default=180.0, help="total flight time, s (default 180)")
    s.add_argument(
        "--criterion",
        choices=("D", "A", "E"),
        default="A",
        help="D: log det, A: sum of relative variances (default), E: worst direction",
    )
    s.add_argument(
        "--free",
        help="comma-separated coefficients to design for (default: the "
        "analytic model's free list, or the estimate's)",
    )
    s.add_argument("--mjcf", type=Path, default=None, help="MJCF file (default: the bundled torpedo)")
    s.add_argument("--speed", type=_positive, default=None, help="trim speed U, m/s (default: cruise)")
    s.add_argument(
        "--from",
        dest="start_from",
        type=Path,
        default=None,
        help="estimates JSON of the last fit: design at its coefficients and noise",
    )
    s.add_argument("--out", type=Path, required=True, help="the scenario file to write (.toml)")
    s.add_argument(
        "--rrd", type=Path, help="also log the comparison with Scenario II to this Rerun recording"
    )
    s.set_defaults(func=_cmd_design)

    s = sub.add_parser(
        "reproduce", help="the paper's study: data sets x seeds x start spreads x arms, on Dask"
    )
    s.add_argument("--seeds", type=int, default=None, help="noise seeds 1..N (default 20; 1 with --quick)")
    s.add_argument(
        "--out",
        type=Path,
        default=Path("runs/reproduce"),
        help="output folder; finished cells in it are reused (default runs/reproduce)",
    )
    s.add_argument(
        "--scheduler",
        default=None,
        help="address of a running Dask scheduler, e.g. "
        "tcp://host:8786, whose workers see --out (default: 2 local worker processes)",
    )
    s.add_argument(
        "--quick",
        action="store_true",
        help="30 s experiments, one seed unless --seeds: a demonstration in under 3 minutes",
    )
    s.add_argument(
        "--duration",
        type=_positive,
        default=None,
        help="seconds per experiment (default: the scenarios' own, 30 with --quick)",
    )
    s.add_argument(
        "--start-spread",
        type=_non_negative,
        nargs="+",
        default=None,
        metavar="S",
        help="start spreads: the a-priori model's errors, log-normal per coefficient class "
        "(0: the analytic model; default: the study's, docs/studies.md)",
    )
    s.add_argument(
        "--arms",
        nargs="+",
        default=None,
        metavar="ARM",
        help="the arms fitted, or all (default: the paper's methods, ml-gn and the drift arms; "
        "docs/studies.md lists them)",
    )
    s.add_argument(
        "--truth",
        nargs="+",
        default=None,
        metavar="TRUTH",
        help="what Scenario I and II are flown on: plant (MuJoCo), linear (the analytic model) (default both)",
    )
    s.set_defaults(func=_cmd_reproduce)

    s = sub.add_parser("replay", help="open a run's recording.rrd in the Rerun viewer")
    s.add_argument("run", type=Path, help="run directory or .rrd file")
    s.set_defaults(func=_cmd_replay)
    for name, command in sub.choices.items():
        if name in WRITES_FILES:
            command.add_argument("--force", action="store_true", help=FORCE_HELP)
        command.set_defaults(flags=_flags(command))
    return p


def _terminate(signum, frame):
    raise KeyboardInterrupt  # `kill` cleans up like Ctrl-C: temporary outputs are removed


INTERNAL_ERROR = 70  # a bug (sysexits' EX_SOFTWARE): not 1, which means "did not converge"


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    previous = signal.signal(signal.SIGTERM, _terminate)
    try:
        return args.func(args)
    except InputError as exc:
        print(f"testbed {args.command}: error: {in_flags(str(exc), args.flags, args)}", file=sys.stderr)
        return 2
    except MemoryError:
        print(
            f"testbed {args.command}: error: out of memory; expected less data or a shorter --duration",
            file=sys.stderr,
        )
        return 2
    except KeyboardInterrupt:
        print(f"testbed {args.command}: interrupted; nothing was written", file=sys.stderr)
        return 130
    except BrokenPipeError:  # the reader of standard output went away (`testbed analytic | head`)
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error at exit
        return 128 + signal.SIGPIPE
    except Exception:
        traceback.print_exc()
        print(
            f"testbed {args.command}: internal error (a bug in testbed, not in the input): "
            "please report it with the traceback above",
            file=sys.stderr,
        )
        return INTERNAL_ERROR
    finally:
        signal.signal(signal.SIGTERM, previous)
