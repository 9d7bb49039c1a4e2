"""The command line's arguments: each sub-command's parser (`parser`) with its options' types
(finite numbers, seeds, noise σ per state), help and defaults, and the options a message names
(`in_flags`: an error about `max_iter` reads `--max-iter`).
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

from testbed.errors import InputError

__all__ = ["BUILTIN_SCENARIOS", "in_flags", "parser"]


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

    s = sub.add_parser("identify", help="estimate the free coefficients from data")
    s.add_argument("data", nargs="+", type=Path, help="run directories or measurement CSVs")
    s.add_argument(
        "--method",
        default="ml-gn",
        help="ml-gn (default), ml-lm, ml-nr, ml-nm, ml-fem, mekf, ekf, equation-error; a nonlinear "
        "model config ([terms]): ml-gn, ml-lm, ml-nm, mekf, ekf or equation-error",
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

    s = sub.add_parser("replay", help="open a run's recording.rrd in the Rerun viewer")
    s.add_argument("run", type=Path, help="run directory or .rrd file")
    for name, command in sub.choices.items():
        if name in WRITES_FILES:
            command.add_argument("--force", action="store_true", help=FORCE_HELP)
        command.set_defaults(flags=_flags(command))
    return p
