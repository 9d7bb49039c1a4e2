"""Headless jobs: each command of the command line as one library function.

A job reads its inputs (run directories, measurement CSVs, model configs, estimates), checks
every output it will write before doing any work (none may be an input or another output),
does the work, and writes its outputs atomically: all of them or none. It returns what it
computed; it prints nothing. Parameters are named as in Python (`max_iter`); `testbed.cli`
maps them to its flags.
"""

from __future__ import annotations

import contextlib
import json
import os
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable, Mapping, Sequence

import numpy as np

from testbed.analysis.comparison import Comparison, compare
from testbed.analysis.identifiability import Identifiability, identifiability
from testbed.analysis.nonlinear_identifiability import NONLINEAR, nonlinear_identifiability
from testbed.analysis.screening import LINEAR, identify_screened
from testbed.analysis.validation import Validation, validate
from testbed.data import (
    MAX_CONSTANT,
    Experiment,
    ModelConfig,
    load_data,
    read_config,
    read_csv,
    read_estimates,
    read_json,
    run_csvs,
)
from testbed.errors import InputError, atomic_file, atomic_write_text, check_outputs, is_stream
from testbed.estimators import Estimate, Progress, Status, check_method, identify, lookup
from testbed.identification.problem import base_name, check_inputs
from testbed.models.linear import BIASES, MOUNTING

__all__ = [
    "Identified",
    "analyze_data",
    "check_data",
    "identify_data",
    "inputs",
    "perturbed",
    "spread",
    "truth_comparison",
    "truth_data",
    "validate_data",
    "write_text",
]


def write_text(out: str | os.PathLike | None, text: str, force: bool = False) -> None:
    """Write `text` to `out` atomically (nothing when `out` is None; an existing file only with
    `force`)."""
    if out is not None:
        atomic_write_text(out, text, force)


def inputs(
    data: Sequence[str | os.PathLike], config: str | os.PathLike | None = None, keep_repeats: bool = False
):
    """`(experiments, config, run_config, read)`: the experiments of `data` (run directories or
    measurement CSVs; a state's stale repeats read as missing unless `keep_repeats`,
    `data.stale`), the model config to use (`config`, else the run's model.toml), the run's
    analytic model (None for CSVs) and every file read (outputs must not clobber them)."""
    experiments, run_config = load_data(data, keep_repeats)
    used = read_config(config) if config else run_config
    if used is None:
        raise InputError("no model config: expected config=TOML, or a run directory with model.toml")
    read = [Path(e.source) for e in experiments] + [Path(used.source)]
    read += [Path(p) / "manifest.json" for p in data if (Path(p) / "manifest.json").is_file()]
    return experiments, used, run_config, read


def perturbed(config: ModelConfig, fraction: float, seed: int) -> ModelConfig:
    """The config with every free coefficient's start moved by ±fraction (signs from `seed`)."""
    signs = np.random.default_rng(seed).choice([-1.0, 1.0], size=len(config.free))
    values = config.values
    moved = config.with_coefficients({n: values[n] * (1 + s * fraction) for n, s in zip(config.free, signs)})
    return replace(moved, source=f"{config.source or 'config'} with its start moved by perturb={fraction:g}")


def spread(config: ModelConfig, s: float, seed: int) -> ModelConfig:
    """The config with every free coefficient's start multiplied by exp(s·z), z standard normal
    per coefficient drawn from `seed`: log-normal errors, as an a-priori model's are (a start
    keeps its sign; one at 0 stays there)."""
    z = np.random.default_rng(seed).standard_normal(len(config.free))
    values = config.values
    with np.errstate(over="ignore", invalid="ignore"):  # checked below
        starts = {n: float(values[n] * np.exp(s * zn)) for n, zn in zip(config.free, z)}
    far = [n for n, v in starts.items() if not abs(v) <= MAX_CONSTANT]
    if far:
        raise InputError(
            f"--perturb-spread {s:g}: {far[0]}'s start {values[far[0]]:g} × exp({s:g}·{z[config.free.index(far[0])]:.3g}) "
            f"is beyond ±{MAX_CONSTANT:g}; expected a spread of a few tenths (0.3: errors of about 30 %)"
        )
    moved = config.with_coefficients(starts)
    return replace(moved, source=f"{config.source or 'config'} with its start spread by perturb-spread={s:g}")


def _check_report(report, force: bool) -> None:
    """`InputError` unless the `--report` folder can take a report (`check_report_folder`); the
    report's module (matplotlib) loads only when one is asked for."""
    if report is not None:
        from testbed.presentation.fit_report import check_report_folder

        check_report_folder(report, force)


def truth_data(paths: Sequence[str | os.PathLike]) -> list[Experiment] | None:
    """The noise-free `<experiment>.truth.csv` of the run directories among `paths` (read and
    checked now, before any fit), or None when any is missing: the comparison then has no bias
    column."""
    runs = [p for p in map(Path, paths) if (p / "manifest.json").exists()]
    truth = [f.with_suffix(".truth.csv") for p in runs for f in run_csvs(p)]
    if not truth or not all(f.exists() for f in truth):
        return None
    return [read_csv(f, f.name.removesuffix(".truth.csv"), keep_repeats=True) for f in truth]


def truth_comparison(estimate: Estimate, analytic: ModelConfig, truth: list[Experiment] | None) -> Comparison:
    """The comparison with the analytic model, its bias split off by `ml-gn` on the noise-free
    `truth` from the analytic model, whatever method made the estimate (the bias belongs to the
    model, and a filter needs noise to work). The truth fit takes the channels the estimate
    weighed, by its noise σ, held: it is the optimum the estimate's own weighting aims at, where
    noise-free residuals would weigh each channel by its model error alone (and take as many
    Gauss-Newton iterations as that weighting takes to settle). A truth fit that cannot run is
    a note, not a failure: the estimate stands without it."""
    if truth is None:
        return compare(estimate, analytic)
    try:
        names = tuple(dict.fromkeys(base_name(n) for n in estimate.free))
        per_record = tuple(dict.fromkeys(base_name(n) for n in estimate.free if n != base_name(n)))
        noise = {**(analytic.noise_std or {}), **estimate.noise_std}
        config = replace(analytic, free=names, per_record=per_record, noise_std=noise or None)
        weighed = tuple(estimate.noise_std)
        fit = identify(
            [e.only(weighed) for e in truth] if weighed else truth, config, method="ml-gn", start="config"
        )
    except InputError as exc:
        return replace(compare(estimate, analytic), note=f"no linear-model bias column: {exc}")
    return compare(estimate, analytic, fit)


@dataclass(frozen=True)
class Identified:
    """What `identify_data` did.

    Attributes:
        estimate: the fit.
        config: the model config fitted (the screen applied: the candidates the data determine).
        fixed: coefficient → why the screen applied left it at its a-priori value.
        screen: coefficient → why the screen fixes it, or where it was not applied would fix it.
        comparison: against the run's analytic model (None for data without one).
        validation: fit % and residual whiteness of the fitted model on the data.
        document: the estimates JSON as a mapping; `text` as written.
        written: the files written (the estimates, a filter's history CSV, the recording).
    """

    estimate: Estimate
    config: ModelConfig
    fixed: dict[str, str]
    screen: dict[str, str]
    comparison: Comparison | None
    validation: Validation
    document: dict
    text: str
    written: tuple[Path, ...]


def _reference(
    reference, report, config: ModelConfig, run_config: ModelConfig | None, moved: bool
) -> tuple[ModelConfig | None, str]:
    """The report's reference and its label (`identify_data`'s `reference`); `InputError` for a
    reference with no report to show it, or of the other model."""
    if reference is None:
        if config.terms is None and run_config is not None:
            return run_config, "analytic"
        return (config, "config as written") if moved else (None, "")
    if report is None:
        raise InputError(
            f"--reference {reference}: shown only in a fit report; expected --report DIR beside it"
        )
    given = read_config(reference)
    if (given.terms is None) != (config.terms is None):
        kind = "linear" if config.terms is None else "nonlinear"
        raise InputError(
            f"{reference}: a {'non' if kind == 'linear' else ''}linear model config; expected a {kind} one as the fitted config"
        )
    return given, Path(reference).stem


def identify_data(
    data: Sequence[str | os.PathLike],
    *,
    method: str = "ml-gn",
    config: str | os.PathLike | None = None,
    out: str | os.PathLike | None = None,
    rrd: str | os.PathLike | None = None,
    options: Mapping | None = None,
    perturb: float | None = None,
    seed: int = 0,
    screen: bool | None = None,
    perturb_spread: float | None = None,
    report: str | os.PathLike | None = None,
    noise_std: Mapping[str, float] | None = None,
    progress: Callable[[Progress], None] | None = None,
    corrections: str | os.PathLike | None = None,
    keep_repeats: bool = False,
    force: bool = False,
    reference: str | os.PathLike | None = None,
) -> Identified:
    """Identify the coefficients of `data` (run directories or CSVs) and write the estimates JSON
    to `out`, a filter's estimate and ±σ histories beside it (`.history.csv`), and a Rerun
    recording of the fit to `rrd`.

    `config`: the model config (default: the run's model.toml); `options`: the method's
    options; `perturb`: move every free start by this fraction (signs from `seed`);
    `perturb_spread`: multiply every free start by exp(S·N(0, 1)) instead (drawn from `seed`);
    `report`: a new or empty folder for the fit's HTML report (`presentation.fit_report`);
    `reference`: a model config whose values the report shows beside the estimates, named by its
    file's stem (e.g. the captive config a perturbed start came from; default: the run's analytic
    model for a linear fit, else the config as written where `perturb` or `perturb_spread` moved
    the start);
    `screen`: fit only the candidates of the config's free list that the data determine
    (`analysis.identify_screened`), or (False) the list as written, the screen only reported in
    the JSON's `screen`; default: as the config's `[identify] screen` says; `noise_std`: the
    sensors' noise σ per state, replacing the config's `[identify] noise_std` entry by entry;
    `corrections`: a check JSON (`check_data`) whose sensor corrections are applied to the data
    before the fit (`analysis.corrections.corrected`); `keep_repeats`: read a state's stale
    repeats as samples (`data.stale`: missing by default). A diverged fit is an `InputError` and writes nothing; a fit that ran but did not converge is
    written (`Identified.estimate.converged` says so). An existing file at `out`, its history
    CSV or `rrd` is refused before the fit (`InputError`) unless `force` (then replaced).
    """
    m = lookup(method)
    opts = m.options.build(m.name, options or {})
    experiments, cfg, run_config, read = inputs(data, config, keep_repeats)
    cfg = cfg.with_noise_std(noise_std)
    applied = None
    if corrections is not None:  # the check's module loads numba and scipy: only when asked for
        from testbed.analysis.corrections import corrected, read_corrections

        applied = read_corrections(corrections)
        experiments = corrected(experiments, applied)
        read.append(Path(corrections))
    truth = truth_data(data) if run_config is not None and cfg.terms is None else None
    read += [Path(e.source) for e in truth or ()]
    history = (
        Path(out).with_suffix(".history.csv") if out is not None and m.online and not is_stream(out) else None
    )
    shown = _reference(reference, report, cfg, run_config, perturb is not None or perturb_spread is not None)
    read += [Path(reference)] if reference is not None else []
    check_outputs(read, {"out": out, "history": history, "rrd": rrd}, force)
    _check_report(report, force)
    check_method(m.name, cfg)  # before the screen's fit
    if perturb is not None:
        cfg = perturbed(cfg, perturb, seed)
    if perturb_spread is not None:
        cfg = spread(cfg, perturb_spread, seed)
    a_priori = cfg  # the start, for the report's a-priori predictions
    iterations = []  # (iteration, values, cost) of the iterative methods, for the recording

    def callback(step: Progress) -> None:
        if m.iterative:
            iterations.append((step.iteration, list(step.values), step.cost))
        if progress is not None:
            progress(step)

    model = LINEAR if cfg.terms is None else NONLINEAR
    screened = identify_screened(experiments, cfg, m.name, opts, callback, apply=screen, model=model)
    cfg, estimate = screened.config, screened.estimate
    if estimate.status is Status.DIVERGED:
        expected = f" (expected {'another start or ' if m.starts else ''}a better a-priori config)"
        if "; give " in estimate.message:  # the reason says what to give (a filter's noise-free data)
            expected = ""
        raise InputError(
            f"method={m.name!r}: {estimate.status.message}"
            f"{f' ({estimate.message})' if estimate.message else ''} on "
            f"{', '.join(map(str, data))}; no estimate written{expected}"
        )
    # a value the fit carried beyond what a config may hold is the fit's, not the config's: the
    # model validated below would be refused as a config
    beyond = [(n, v) for n, v in zip(estimate.free, estimate.values) if not abs(v) <= MAX_CONSTANT]
    if beyond:
        raise InputError(
            f"method={m.name!r}: the fit carried {beyond[0][0]} to {beyond[0][1]:.3g}, beyond "
            f"±{MAX_CONSTANT:g} (SI) on {', '.join(map(str, data))}: these data do not determine it; "
            "no estimate written (expected data that excite it, or it fixed)"
        )
    doc = estimate.json_fields()
    if applied is not None:
        doc["corrections"] = {"file": str(corrections), "values": applied}
    if screened.fixed:
        doc["fixed"] = {
            n: {"value": float(cfg.values[n]), "reason": why} for n, why in screened.fixed.items()
        }
    if not screened.applied:
        doc["screen"] = dict(screened.screen)
    if screened.skipped:
        doc["screen_skipped"] = screened.skipped
    comparison = None
    if cfg.terms is not None:
        doc["nonlinear_model"] = {"config": str(config), "terms": list(cfg.terms)}
    elif run_config is not None:
        comparison = truth_comparison(estimate, run_config, truth)
        doc["comparison"] = {"analytic_model": run_config.source, **comparison.to_dict()}
    validation = validate(
        experiments,
        cfg.with_coefficients(estimate.coefficients),
        run_config,
        estimate.initial_states if cfg.terms is not None else None,
    )
    doc["validation"] = validation.to_dict()
    text = json.dumps(doc, indent=2, allow_nan=False) + "\n"
    page = None
    if report is not None:
        from testbed.presentation.fit_report import fit_report_html, write_fit_report

        page = fit_report_html(
            experiments,
            cfg,
            estimate,
            validation,
            a_priori,
            iterations,
            shown[0],
            screened.fixed,
            f"testbed identify: {m.name} on {', '.join(map(str, data))}",
            None if rrd is None else os.path.relpath(Path(rrd).resolve(), Path(report).resolve()),
            shown[1],
        )
    files = {Path(out): text} if out is not None else {}
    if history is not None:
        files = {history: estimate.history_csv(), **files}
    with contextlib.ExitStack() as stack:  # every output, or none of them
        temporary = {path: stack.enter_context(atomic_file(path, force)) for path in files}
        if rrd is not None:
            from testbed.presentation.report import log_fit  # Rerun and MuJoCo load only for a recording

            log_fit(
                rrd, experiments, cfg, estimate, iterations, comparison, validation=validation, force=force
            )
        for path, content in files.items():
            temporary[path].write_text(content)
        if page is not None:  # last: a folder made only once everything else is ready
            write_fit_report(report, page, force)
    written = (
        tuple(files)
        + ((Path(rrd),) if rrd is not None else ())
        + ((Path(report),) if report is not None else ())
    )
    return Identified(
        estimate, cfg, screened.fixed, screened.screen, comparison, validation, doc, text, written
    )


def analyze_data(
    data: Sequence[str | os.PathLike],
    *,
    config: str | os.PathLike | None = None,
    out: str | os.PathLike | None = None,
    noise_std: Mapping[str, float] | None = None,
    keep_repeats: bool = False,
    force: bool = False,
    report: str | os.PathLike | None = None,
) -> Identifiability:
    """Identifiability of the config's free coefficients from `data` (Fisher information,
    Cramér-Rao bounds, correlations, drift groups; a nonlinear model config's by
    `analysis.nonlinear_identifiability`), written as JSON to `out`; `noise_std`, `keep_repeats`
    and `force` as for `identify_data`; `report`: a new or empty folder for the analysis' HTML page
    (`presentation.fit_report.analysis_report_html`)."""
    experiments, cfg, _, read = inputs(data, config, keep_repeats)
    cfg = cfg.with_noise_std(noise_std)
    check_outputs(read, {"out": out}, force)
    _check_report(report, force)
    if not cfg.free:
        raise InputError(f"{cfg.source or 'config'}: [identify] free is empty; nothing to analyse")
    if cfg.terms is not None:
        result = nonlinear_identifiability(experiments, cfg)
    else:
        result = identifiability(experiments, cfg)
    write_text(out, result.to_json(), force)
    if report is not None:  # last: a folder made only once everything else is written
        from testbed.presentation.fit_report import analysis_report_html, write_fit_report

        title = f"testbed analyze: {', '.join(map(str, data))}"
        write_fit_report(report, analysis_report_html(experiments, cfg, result, title), force)
    return result


def check_data(
    data: Sequence[str | os.PathLike],
    *,
    out: str | os.PathLike | None = None,
    keep_repeats: bool = False,
    force: bool = False,
    report: str | os.PathLike | None = None,
):
    """The data-compatibility check of `data` (run directories or measurement CSVs): the
    kinematics reconstructed, the sensor biases, scale factors and delays estimated with their
    bounds, written as JSON to `out` (`keep_repeats` and `force` as for `identify_data`); the
    `analysis.compatibility_checks.Compatibility`; `report`: a new or empty folder for its HTML page
    (`presentation.fit_report.check_report_html`)."""
    from testbed.analysis.compatibility import compatibility  # numba and scipy: only here

    experiments, _ = load_data(data, keep_repeats)
    read = [Path(e.source) for e in experiments]
    read += [Path(p) / "manifest.json" for p in data if (Path(p) / "manifest.json").is_file()]
    check_outputs(read, {"out": out}, force)
    _check_report(report, force)
    result = compatibility(experiments)
    write_text(out, result.to_json(), force)
    if report is not None:  # last: a folder made only once everything else is written
        from testbed.presentation.fit_report import check_report_html, write_fit_report

        write_fit_report(
            report, check_report_html(result, f"testbed check: {', '.join(map(str, data))}"), force
        )
    return result


def validate_data(
    data: Sequence[str | os.PathLike],
    estimates: str | os.PathLike | None = None,
    *,
    config: str | os.PathLike | None = None,
    out: str | os.PathLike | None = None,
    keep_repeats: bool = False,
    force: bool = False,
    report: str | os.PathLike | None = None,
) -> tuple[Validation, str, dict]:
    """Fit % and residual whiteness on `data` of a model config (`config`, default: the run's
    model.toml, or a nonlinear fit's config named in `estimates`) with the coefficients of the
    `estimates` JSON applied, or as it stands without `estimates`; the validation JSON (also
    written to `out`; `keep_repeats` and `force` as for `identify_data`) with them, and
    experiment name → the
    manoeuvre metrics of the record and of the model's open-loop prediction for each manoeuvre a
    run directory of `data` flies (`analysis.manoeuvres.compared`: `Compared`). A nonlinear model config is flown open loop
    (`analysis.validate`). `report`: a new or empty folder for the validation's HTML page
    (`presentation.fit_report.validation_report_html`: the model against the records, the config
    as written beside it where `estimates` changed it)."""
    model = _nonlinear_estimates(estimates) if estimates is not None else None
    if config is None and model is not None:
        config = model["config"]
    experiments, cfg, run_config, read = inputs(data, config, keep_repeats)
    runs = [Path(p) for p in data if (Path(p) / "scenario.toml").is_file()]  # their manoeuvres compared
    read += [f for run in runs for f in (run / "scenario.toml", *run.glob("*.truth.csv"))]
    check_outputs(read + ([estimates] if estimates is not None else []), {"out": out}, force)
    _check_report(report, force)
    coefficients = {}
    if cfg.terms is None:
        if model is not None:
            raise InputError(
                f"{estimates}: a nonlinear model's fit ([terms] of {model['config']}); {cfg.source} is a "
                "linear model config; expected the config the estimates were fitted with"
            )
        check_inputs(experiments, cfg)  # the user's data against the user's model (validate checks no step)
        if estimates is not None:
            coefficients = read_estimates(estimates)[0]
    elif estimates is not None:
        if model is None:
            raise InputError(
                f"{estimates}: a linear model's fit; {cfg.source} is a nonlinear model config ([terms]); "
                "expected the config the estimates were fitted with"
            )
        if model["terms"] != list(cfg.terms):
            raise InputError(
                f"{estimates}: fitted the nonlinear model over {model['config']}'s terms; {cfg.source} has "
                "other terms; expected the config the estimates were fitted with"
            )
        coefficients = read_estimates(estimates, cfg.nonlinear()[0].names + BIASES + MOUNTING)[0]
    validation = validate(experiments, cfg.with_coefficients(coefficients), run_config)
    manoeuvres = {}
    if runs:
        from testbed.analysis.manoeuvres import compared  # mujoco (the scenarios): only for runs

        manoeuvres = {name: c for run in runs for name, c in compared(run, validation.predictions).items()}
    given = estimates is not None
    text = (
        json.dumps(
            {
                "config": cfg.source,
                **({"estimates": str(estimates), "coefficients": coefficients} if given else {}),
                "validation": validation.to_dict(),
                **({"manoeuvres": {n: c.to_dict() for n, c in manoeuvres.items()}} if manoeuvres else {}),
            },
            indent=2,
            allow_nan=False,
        )
        + "\n"
    )
    page = None
    if report is not None:
        from testbed.presentation.fit_report import validation_report_html

        what = f"{cfg.source} with the coefficients of {estimates}" if given else f"{cfg.source} as written"
        page = validation_report_html(
            experiments,
            cfg.with_coefficients(coefficients),
            validation,
            cfg if given else None,
            f"testbed validate: {', '.join(map(str, data))}",
            f"The model validated: {what}; its outputs flown open loop from the best-fitting initial "
            "states" + (", the config as written beside them (a-priori)." if given else "."),
        )
    write_text(out, text, force)
    if page is not None:  # last: a folder made only once everything else is written
        from testbed.presentation.fit_report import write_fit_report

        write_fit_report(report, page, force)
    return validation, text, manoeuvres


def _nonlinear_estimates(path) -> dict | None:
    """An estimates JSON's `nonlinear_model` (`config`, `terms`) when it is a nonlinear fit's."""
    doc = read_json(path, "an estimates JSON")
    model = doc.get("nonlinear_model") if isinstance(doc, dict) else None
    if model is None:
        return None
    if not (
        isinstance(model, dict)
        and isinstance(model.get("config"), str)
        and isinstance(model.get("terms"), list)
        and all(isinstance(t, str) for t in model["terms"])
    ):
        raise InputError(f"{path}: nonlinear_model; expected {{config: a path, terms: a list of term names}}")
    return model
