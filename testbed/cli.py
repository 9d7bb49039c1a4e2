"""The command line (SPEC §4): a thin layer over the library.

Each sub-command parses its arguments, calls one library function and prints where its output
went. Bad input is an `InputError`: one line on stderr, exit status 2.
"""

from __future__ import annotations

import argparse
import contextlib
import signal
import sys
from pathlib import Path

from testbed.threads import one_blas_thread

one_blas_thread()  # before numpy loads

from testbed.errors import InputError, atomic_file  # noqa: E402

STDOUT = Path("-")  # `--out -`: standard output


def _positive(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not 0 < v < float("inf"):
        raise argparse.ArgumentTypeError(f"{text} must be a finite number > 0")
    return v


def _seed(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"{text} must be an integer >= 0")
    return v


def _outputs(inputs, outputs: dict) -> None:
    """Fail before the work, not after it, when an output cannot be written: `outputs` maps a
    label (the flag) to its path or None; `inputs` are the files read. No output may be an input
    (it would be clobbered) or another output, save devices and FIFOs (written into)."""
    import os

    from testbed.errors import check_output_file, is_stream

    seen = {}
    for label, path in outputs.items():
        if path is None:
            continue
        check_output_file(path, f"{label} {path}")
        if is_stream(path):
            continue
        key = os.path.realpath(path)  # links resolved: two names of one file are one file
        for source in inputs:
            if os.path.realpath(source) == key:
                raise InputError(f"{label} {path}: is the input {source}; expected a new file name")
        if key in seen:
            raise InputError(f"{label} {path}: is also the {seen[key]} output; expected another name")
        seen[key] = label


def _to_stdout(path: Path | None) -> Path | None:
    """None (standard output) for `--out -`, else the path."""
    return None if path == STDOUT else path


def _cmd_truth(args) -> int:
    from testbed.data import config_text
    from testbed.errors import atomic_write_text
    from testbed.truth import analytic_config

    args.out = _to_stdout(args.out)
    _outputs([args.mjcf] if args.mjcf else [], {"--out": args.out})
    config, comments = analytic_config(args.mjcf, args.speed)
    text = config_text(config, comments)
    if args.out:
        atomic_write_text(args.out, text)
        print(args.out)
    else:
        sys.stdout.write(text)
    return 0


def _quiet_mujoco() -> None:
    """The plant turns MuJoCo's warnings into one-line errors; don't print or log them twice."""
    import mujoco

    mujoco.set_mju_user_warning(lambda message: None)


def _cmd_simulate(args) -> int:
    from testbed.errors import check_output_directory
    from testbed.scenario import simulate

    _quiet_mujoco()
    if args.out == STDOUT:
        raise InputError("--out -: a run directory is a folder, not standard output; expected a folder name")
    if args.out is not None:
        check_output_directory(args.out, args.force, label=f"--out {args.out}")
    run = simulate(args.scenario, seed=args.seed, out=args.out, force=args.force,
                   duration=args.duration, speed=args.speed, mjcf=args.mjcf,
                   progress=not args.quiet)  # fmt: skip
    print(run)
    return 0


def _inputs(args):
    """The experiments, the model config to use, the run's analytic model (or None), and every
    file read (outputs must not clobber them)."""
    from testbed.data import load_data, read_config

    experiments, run_config = load_data(args.data)
    config = read_config(args.config) if args.config else run_config
    if config is None:
        raise InputError("no model config: give --config TOML (or a run directory with model.toml)")
    read = [Path(e.source) for e in experiments] + [Path(config.source)]
    read += [p / "manifest.json" for p in args.data if (p / "manifest.json").is_file()]
    return experiments, config, run_config, read


def _cmd_identify(args) -> int:
    import json

    from testbed.errors import is_stream
    from testbed.estimators import Status, estimator, identify
    from testbed.linear import check_fit

    args.out = _to_stdout(args.out)
    if args.rrd == STDOUT:
        raise InputError("--rrd -: a recording is a file; expected a file name (.rrd)")
    estimator(args.method)
    offline = args.method.startswith("ml-")
    if args.start is not None and not offline:
        raise InputError(f"--start {args.start}: only the ml-* methods take a start; "
                         f"{args.method} starts from the config")  # fmt: skip
    experiments, config, run_config, read = _inputs(args)
    truth = _truth_data(args.data) if run_config is not None else None
    read += [Path(e.source) for e in truth or ()]
    # the filters' estimate and ±σ histories go beside a file --out, not into a device or FIFO
    history = None
    if args.out and args.method in ("mekf", "ekf") and not is_stream(args.out):
        history = args.out.with_suffix(".history.csv")
    _outputs(read, {"--out": args.out, "the history beside --out": history, "--rrd": args.rrd})
    if args.perturb:
        config = _perturbed(config, args.perturb, args.seed)
    fixed = {}
    check_fit(experiments, config)  # what no analysis can mend, named, before the screening
    if not args.free_all:
        from testbed.analysis import screen

        config, fixed = screen(experiments, config)
        if not config.free:
            raise InputError(f"no coefficient of [identify] free is identifiable from "
                             f"{', '.join(map(str, args.data))} ({next(iter(fixed.values()))}); "
                             "expected data that excite them, or --free-all")  # fmt: skip
    live = sys.stderr.isatty()  # a progress line on long fits (ml-nm runs for minutes)
    options = {"start": args.start or "auto"} if offline else {}
    if args.max_iter is not None:
        options["max_iter"] = args.max_iter
    iterations = []  # (iteration, values, cost) of the off-line methods, for the Rerun log
    if offline:

        def callback(k, values, cost):
            iterations.append((k, list(values), cost))
            if live:
                print(f"\r{args.method}: iteration {k}, cost {cost:.6g}", end="", file=sys.stderr, flush=True)

        options["callback"] = callback
    estimate = identify(experiments, config, method=args.method, **options)
    if offline and live and iterations:
        print(file=sys.stderr)  # end the progress line
    if estimate.status is Status.DIVERGED:
        why = estimate.extra.get("diverged", {}).get("reason")
        raise InputError(f"--method {args.method}: {estimate.status.message}"
                         f"{f' ({why})' if why else ''} on {', '.join(map(str, args.data))}; "
                         f"no estimate written (try {'another --start or ' if offline else ''}"
                         "a better a-priori config)")  # fmt: skip
    if estimate.start != "config" and "start_reason" in estimate.extra:
        print(f"testbed identify: started from the {estimate.start} estimate: "
              f"{estimate.extra['start_reason']}", file=sys.stderr)  # fmt: skip
    doc = json.loads(estimate.to_json())
    if fixed:
        doc["fixed"] = {n: {"value": float(config.coefficients[n]), "reason": why} for n, why in fixed.items()}
    comparison = None
    if run_config is not None:
        comparison = _compare(estimate, run_config, truth)
        doc["comparison"] = {"analytic_model": run_config.source, **comparison.to_dict()}
        print(comparison.table(), file=sys.stderr)
    for n, why in fixed.items():
        print(f"{n:<12}fixed at {config.coefficients[n]:.4g}: {why}", file=sys.stderr)
    from testbed.validation import validate

    validation = validate(experiments, config.with_coefficients(estimate.coefficients), run_config)
    doc["validation"] = validation.to_dict()
    print(validation.table(), file=sys.stderr)
    text = json.dumps(doc, indent=2, allow_nan=False) + "\n"
    files = {args.out: text} if args.out else {}
    if history is not None:
        from testbed.estimators.mekf import history_csv_text

        files = {history: history_csv_text(estimate), **files}
    with contextlib.ExitStack() as outputs:  # every output, or none of them
        temporary = {path: outputs.enter_context(atomic_file(path)) for path in files}
        if args.rrd:
            from testbed.report import log_fit

            log_fit(args.rrd, experiments, config, estimate, iterations, comparison, validation=validation)
        for path, content in files.items():
            temporary[path].write_text(content)
    for path in files:
        print(path)
    if not args.out:
        sys.stdout.write(text)
    if args.rrd:
        print(args.rrd, file=sys.stderr)
    if not estimate.converged:
        print(f"testbed identify: not converged: {estimate.status.message}", file=sys.stderr)
        return 1
    return 0


def _perturbed(config, fraction: float, seed: int):
    """The config with every free coefficient's start moved by ±fraction (signs from `seed`)."""
    from dataclasses import replace

    import numpy as np

    signs = np.random.default_rng(seed).choice([-1.0, 1.0], size=len(config.free))
    moved = config.with_coefficients({n: config.coefficients[n] * (1 + s * fraction)
                                      for n, s in zip(config.free, signs)})  # fmt: skip
    return replace(moved, source=f"{config.source or 'config'} moved by --perturb {fraction:g}")


def _truth_data(paths):
    """The noise-free `<experiment>.truth.csv` of the run directories among `paths` (read and
    checked now, before any fit), or None when any is missing: the comparison then has no bias
    column."""
    from testbed.data import read_csv, run_csvs

    runs = [p for p in map(Path, paths) if (p / "manifest.json").exists()]
    truth = [f.with_suffix(".truth.csv") for p in runs for f in run_csvs(p)]
    if not truth or not all(f.exists() for f in truth):
        return None
    return [read_csv(f, f.name.removesuffix(".truth.csv")) for f in truth]


def _compare(estimate, analytic, truth):
    """The comparison with the analytic model, its bias split off by `ml-gn` on the noise-free
    `truth` from the analytic model, whatever method made the estimate (the bias belongs to the
    model, and a filter needs noise to work). A truth fit that cannot run is a note, not a
    failure: the estimate stands without it."""
    from dataclasses import replace

    from testbed.analysis import compare
    from testbed.estimators import identify

    if truth is None:
        return compare(estimate, analytic)
    try:
        fit = identify(truth, replace(analytic, free=tuple(estimate.free)), method="ml-gn", start="config")
    except InputError as exc:
        return replace(compare(estimate, analytic), note=f"no linear-model bias column: {exc}")
    return compare(estimate, analytic, fit)


def _cmd_analyze(args) -> int:
    from testbed.analysis import identifiability
    from testbed.errors import atomic_write_text

    args.out = _to_stdout(args.out)
    experiments, config, _, read = _inputs(args)
    _outputs(read, {"--out": args.out})
    if not config.free:
        raise InputError(f"{config.source or 'config'}: [identify] free is empty; nothing to analyse")
    result = identifiability(experiments, config)
    text = result.to_json()
    if args.out:
        atomic_write_text(args.out, text)
        print(args.out)
    else:
        sys.stdout.write(text)
    for line in result.summary:
        print(line, file=sys.stderr)
    return 0


def _cmd_validate(args) -> int:
    import json

    from testbed.data import read_estimates
    from testbed.errors import atomic_write_text
    from testbed.validation import validate

    args.out = _to_stdout(args.out)
    experiments, config, run_config, read = _inputs(args)
    _outputs(read + [args.estimates], {"--out": args.out})
    coefficients = read_estimates(args.estimates)[0]
    validation = validate(experiments, config.with_coefficients(coefficients), run_config)
    text = json.dumps({"estimates": str(args.estimates), "coefficients": coefficients,
                       "validation": validation.to_dict()}, indent=2, allow_nan=False) + "\n"  # fmt: skip
    if args.out:
        atomic_write_text(args.out, text)
        print(args.out)
    else:
        sys.stdout.write(text)
    print(validation.table(), file=sys.stderr)
    return 0


def _cmd_design(args) -> int:
    from testbed.design import design, read_estimates
    from testbed.errors import atomic_write_text

    if args.out == STDOUT:
        raise InputError("--out -: the design is a scenario file; expected a file name (.toml)")
    _outputs([args.start_from] if args.start_from else [], {"--out": args.out})
    _quiet_mujoco()
    estimates, noise = read_estimates(args.start_from) if args.start_from else (None, None)
    free = [n.strip() for n in args.free.split(",") if n.strip()] if args.free else None
    result = design(args.duration, args.criterion, free, args.mjcf, args.speed, estimates, noise)
    atomic_write_text(args.out, result.text())
    print(result.table(), file=sys.stderr)
    print(args.out)
    return 0


def _cmd_reproduce(args) -> int:
    from testbed.campaign import reproduce

    _quiet_mujoco()
    done = reproduce(args.out, seeds=args.seeds, scheduler=args.scheduler, quick=args.quick,
                     duration=args.duration)  # fmt: skip
    print(f"testbed reproduce: {done.computed} cells computed, {done.reused} reused, {done.failed} failed, "
          f"in {done.wall_time_s:.0f} s", file=sys.stderr)  # fmt: skip
    for k, v in done.conclusions.items():
        print(f"conclusion {k}: {'holds' if v['holds'] else 'refuted'}: {v['evidence']}", file=sys.stderr)
    print(done.out / "report.html")
    return 0


def _cmd_replay(args) -> int:
    from testbed.report import replay

    return replay(args.run)


class _Parser(argparse.ArgumentParser):
    """argparse with a one-line error (no usage block) and exit status 2."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


BUILTIN_SCENARIOS = ("I", "II", "turn", "zigzag", "zigzag-vertical")  # testbed/scenarios/*.toml


def parser() -> argparse.ArgumentParser:
    p = _Parser(prog="testbed", description="Simulate a submerged body and identify its "
                "manoeuvring coefficients (Kim & Rhee).")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND", parser_class=_Parser)

    s = sub.add_parser("truth", help="write the analytic linear model of an MJCF body (TOML)")
    s.add_argument("--mjcf", type=Path, default=None, help="MJCF file (default: the bundled torpedo)")
    s.add_argument("--speed", type=_positive, default=None, help="trim speed U, m/s (default: cruise)")
    s.add_argument("--out", type=Path, help="output TOML (default or -: stdout)")
    s.set_defaults(func=_cmd_truth)

    s = sub.add_parser("simulate", help="generate a scenario run directory")
    s.add_argument("--scenario", required=True,
                   help=f"a built-in scenario ({', '.join(BUILTIN_SCENARIOS)}) or a scenario file (.toml)")
    s.add_argument("--seed", type=_seed, default=0, help="noise and PRBS seed (default 0)")
    s.add_argument("--out", type=Path, help="run directory (default: runs/<scenario>-seed<N>)")
    s.add_argument("--force", action="store_true", help="replace an existing run directory")
    s.add_argument("--duration", type=_positive, help="seconds per experiment (default: the scenario's)")
    s.add_argument("--speed", type=_positive, help="cruise speed, m/s (default: the vehicle's)")
    s.add_argument("--mjcf", type=Path, default=None, help="MJCF file (default: the bundled torpedo)")
    s.add_argument("--quiet", action="store_true", help="no progress bar")
    s.set_defaults(func=_cmd_simulate)

    s = sub.add_parser("identify", help="estimate the free coefficients from data")
    s.add_argument("data", nargs="+", type=Path, help="run directories or measurement CSVs")
    s.add_argument("--method", default="ml-gn", help="ml-gn (default), ml-nr, ml-nm, mekf, ekf")
    s.add_argument("--config", type=Path, help="model config TOML (default: the run's model.toml)")
    s.add_argument("--out", type=Path, help="estimates JSON (default or -: stdout); mekf and ekf "
                   "also write the estimate and ±σ histories to OUT with suffix .history.csv when "
                   "OUT is a file")
    s.add_argument("--start", default=None,
                   help="ml-* only: auto (default: the a-priori values, or the equation-error "
                        "estimate if output error fails from them), config, equation-error or mekf")  # fmt: skip
    s.add_argument("--max-iter", type=int, default=None, help="iteration limit")
    s.add_argument("--perturb", type=_positive, default=None,
                   help="move every free coefficient's start by this fraction (e.g. 0.4), to test "
                        "convergence from a poor a-priori model")
    s.add_argument("--seed", type=_seed, default=0, help="signs of --perturb (default 0)")
    s.add_argument("--rrd", type=Path, help="also log the fit to this Rerun recording")
    s.add_argument("--free-all", action="store_true",
                   help="estimate every coefficient of [identify] free (default: those the data "
                        "identify; the others stay at their a-priori values, see `analyze`)")  # fmt: skip
    s.set_defaults(func=_cmd_identify)

    s = sub.add_parser("analyze", help="identifiability: Fisher information, CRLB, drift groups")
    s.add_argument("data", nargs="+", type=Path, help="run directories or measurement CSVs")
    s.add_argument("--config", type=Path, help="model config TOML (default: the run's model.toml)")
    s.add_argument("--out", type=Path, help="identifiability JSON (default or -: stdout)")
    s.set_defaults(func=_cmd_analyze)

    s = sub.add_parser("validate", help="fit %% and residual whiteness of identified coefficients on (held-out) data")
    s.add_argument("data", nargs="+", type=Path, help="run directories or measurement CSVs")
    s.add_argument("--estimates", type=Path, required=True, help="estimates JSON from `testbed identify`")
    s.add_argument("--config", type=Path, help="model config TOML (default: the run's model.toml)")
    s.add_argument("--out", type=Path, help="validation JSON (default: stdout)")
    s.set_defaults(func=_cmd_validate)

    s = sub.add_parser("design", help="design experiments from Fisher information (a scenario file)")
    s.add_argument("--duration", type=_positive, default=180.0, help="total flight time, s (default 180)")
    s.add_argument("--criterion", choices=("D", "A", "E"), default="A",
                   help="D: log det, A: sum of relative variances (default), E: worst direction")
    s.add_argument("--free", help="comma-separated coefficients to design for (default: the "
                   "analytic model's free list, or the estimate's)")
    s.add_argument("--mjcf", type=Path, default=None, help="MJCF file (default: the bundled torpedo)")
    s.add_argument("--speed", type=_positive, default=None, help="trim speed U, m/s (default: cruise)")
    s.add_argument("--from", dest="start_from", type=Path, default=None,
                   help="estimates JSON of the last fit: design at its coefficients and noise")
    s.add_argument("--out", type=Path, required=True, help="the scenario file to write (.toml)")
    s.set_defaults(func=_cmd_design)

    s = sub.add_parser("reproduce", help="the paper's study: Scenario I and II x 4 methods x seeds, on Dask")
    s.add_argument("--seeds", type=int, default=None, help="noise seeds 1..N (default 20; 1 with --quick)")
    s.add_argument("--out", type=Path, default=Path("runs/reproduce"),
                   help="output folder; finished cells in it are reused (default runs/reproduce)")
    s.add_argument("--scheduler", default=None, help="address of a running Dask scheduler, e.g. "
                   "tcp://host:8786, whose workers see --out (default: 2 local worker processes)")
    s.add_argument("--quick", action="store_true", help="30 s experiments, one seed unless --seeds: "
                   "a demonstration in under 3 minutes")
    s.add_argument("--duration", type=_positive, default=None, help="seconds per experiment "
                   "(default: the scenarios' own, 30 with --quick)")
    s.set_defaults(func=_cmd_reproduce)

    s = sub.add_parser("replay", help="open a run's recording.rrd in the Rerun viewer")
    s.add_argument("run", type=Path, help="run directory or .rrd file")
    s.set_defaults(func=_cmd_replay)
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
        print(f"testbed {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except MemoryError:
        print(f"testbed {args.command}: error: out of memory; expected less data or a shorter "
              "--duration", file=sys.stderr)  # fmt: skip
        return 2
    except KeyboardInterrupt:
        print(f"testbed {args.command}: interrupted; nothing was written", file=sys.stderr)
        return 130
    except BrokenPipeError:  # the reader of standard output went away (`testbed truth | head`)
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error at exit
        return 128 + signal.SIGPIPE
    except Exception:
        import traceback

        traceback.print_exc()
        print(f"testbed {args.command}: internal error (a bug in testbed, not in the input): "
              "please report it with the traceback above", file=sys.stderr)  # fmt: skip
        return INTERNAL_ERROR
    finally:
        signal.signal(signal.SIGTERM, previous)
