"""The command line: a thin layer over the library.

Each sub-command parses its arguments, calls one library function and prints where its output
went. Bad input is an `InputError`: one line on stderr, exit status 2.
"""

from __future__ import annotations

import os
import signal
import sys
import time
import traceback
from pathlib import Path

from testbed.threads import one_blas_thread

__all__ = ["COMMANDS", "INTERNAL_ERROR", "main"]

one_blas_thread()  # before numpy loads

from testbed.arguments import in_flags, parser  # noqa: E402
from testbed.errors import InputError  # noqa: E402

STDOUT = Path("-")  # `--out -`: standard output


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
    from testbed.jobs.identify import identify_data

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
    if estimate.at_bounds:
        print(f"testbed identify: ended on its bounds: {estimate.bounds_text()}", file=sys.stderr)
    for path in done.written:
        print(path, file=sys.stderr if path == args.rrd else sys.stdout)
    if out is None:
        sys.stdout.write(done.text)
    if not estimate.converged:
        print(f"testbed identify: not converged: {estimate.status.message}", file=sys.stderr)
        return 1
    return 0


def _cmd_analyze(args) -> int:
    from testbed.jobs.analyze import analyze_data

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
    from testbed.jobs.check import check_data

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
    from testbed.jobs.validate import validate_data

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


def _terminate(signum, frame):
    # `kill` cleans up like Ctrl-C: temporary outputs are removed; a second `kill` while they are
    # is ignored, so that the cleanup runs to its end (Ctrl-C pressed again still stops it)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    raise KeyboardInterrupt


INTERNAL_ERROR = 70  # a bug (sysexits' EX_SOFTWARE): not 1, which means "did not converge"


# each command's handler, by the name the parser gives it (`args.command`)
COMMANDS = {
    "analytic": _cmd_analytic,
    "captive": _cmd_captive,
    "simulate": _cmd_simulate,
    "identify": _cmd_identify,
    "analyze": _cmd_analyze,
    "check": _cmd_check,
    "validate": _cmd_validate,
    "design": _cmd_design,
    "reproduce": _cmd_reproduce,
    "replay": _cmd_replay,
}


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    previous = signal.signal(signal.SIGTERM, _terminate)
    try:
        return COMMANDS[args.command](args)
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
