"""`testbed identify` as a library function (`identify_data`), and the screened fit it runs
(`identify_screened`: the candidates the data determine, fitted by the method asked for).
"""

from __future__ import annotations
import contextlib
import json
import os
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable, Mapping, Sequence
import numpy as np
from testbed.analysis.comparison import Comparison
from testbed.analysis.nonlinear_identifiability import NONLINEAR
from testbed.analysis.screening import LINEAR
from testbed.analysis.validation import Validation, validate
from testbed.data import MAX_CONSTANT, ModelConfig, read_config
from testbed.outputs import atomic_file, check_outputs, is_stream
from testbed.errors import InputError
from testbed.estimators import Estimate, Progress, Status, check_method, identify, lookup
from testbed.identification.problem import base_name
from testbed.jobs.common import inputs, perturbed, spread, check_report, truth_data, truth_comparison
from testbed.analysis.screening import LIKELIHOOD_RATIO, ScreenModel, screening, without
from testbed.identification.bounds import chi2_sf

__all__ = ["Identified", "Screened", "identify_data", "identify_screened"]


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
    check_report(report, force)
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


@dataclass(frozen=True)
class Screened:
    """A fit behind the screen (`identify_screened`): `config` fitted, its `estimate`, `screen`
    (name → why) what the screen fixes, whether it was `applied` (else only reported), and why
    its structural stage was `skipped` ("" where it was taken: `Screen.skipped`)."""

    config: ModelConfig
    estimate: Estimate
    screen: dict[str, str]
    applied: bool
    skipped: str = ""

    @property
    def fixed(self) -> dict[str, str]:
        """The candidates left at their a-priori values, name → why."""
        return self.screen if self.applied else {}


def identify_screened(
    experiments,
    config,
    method: str = "ml-gn",
    options=None,
    callback=None,
    apply: bool | None = None,
    model: ScreenModel = LINEAR,
) -> Screened:
    """Screen `config.free` (`screening`, for `model`) and fit with `method` (`options`,
    `callback` as for `identify`).

    `apply`: fit only the candidates the screen leaves free (default: `config.screen`, the
    config's `[identify] screen`); otherwise fit `config.free` as written, the screen only
    reported. The screen's `ml-gn` fit is the fit itself when `method` is `ml-gn` and the free set
    is the same (then `callback` gets its steps when it ends); otherwise `method` fits anew
    (`ml-gn`: one start, where the screen's fit ended, that fit having run the starts asked for;
    the estimate's time and simulations count that fit in; its fixes tested as a likelihood
    ratio and undone where they fail it; `callback` gets the steps of the fit returned, when it
    ends).
    `InputError` when the screen applied leaves nothing free.
    """
    apply = config.screen if apply is None else apply
    m = lookup(method)
    built = m.options.build(m.name, options)  # what the method refuses, before the screen's fit
    check_method(m.name, config, built)
    if config.terms is None and m.refuses_data is not None:
        m.refuses_data(experiments, config)
    same = m.name == "ml-gn"
    steps = []
    s = screening(experiments, config, options if same else None, steps.append if same else None, model)
    fitted = s.config if apply else config
    if not fitted.free:
        first = next(iter(s.fixed))
        raise InputError(
            f"{config.source or 'config'}: no candidate of [identify] free is determined by these "
            f"data ({first} {s.fixed[first]}); expected data that excite them, or the list "
            "estimated as written (screen=False)"
        )
    if same and s.fit is not None and s.fit.free == fitted.free:
        for step in steps if callback is not None else ():
            callback(step)
        estimate = s.fit
    elif same and apply and s.fit is not None and s.fit.status is not Status.DIVERGED:
        # the screened set from where the screen's fit ended, the fixed candidates at their
        # a-priori values: its basin, not the a-priori model's again
        kept = {n: v for n, v in zip(s.fit.free, s.fit.values) if base_name(n) in fitted.free}
        start, rest = fitted.with_coefficients(kept), []
        dropped = [n for n in dict.fromkeys(map(base_name, s.fit.free)) if n not in fitted.free]
        # one start: the screen's fit ran the starts asked for, and its optimum is this one's
        local = replace(built, start="config")
        estimate = identify(experiments, start, method=method, options=local, callback=rest.append)
        reason = f"then from its optimum with {', '.join(dropped)} fixed"
        estimate = replace(
            estimate,
            start=s.fit.start,
            start_reason=f"{s.fit.start_reason}; {reason}" if s.fit.start_reason else reason,
            wall_time_s=s.fit.wall_time_s + estimate.wall_time_s,  # what the estimate cost
            evaluations=s.fit.evaluations + estimate.evaluations,
        )
        # the likelihood-ratio test of the significance stage's fixes: fixing k coefficients the
        # data do not contradict raises the cost by at most χ²₀.₉₅(k)/2; more, and the quadratic
        # model that chose them did not hold (a model far from linear in them): their fit stands
        rise = estimate.cost - s.fit.cost  # NaN where the fit of the rest diverged
        if not (rise <= 0 or (np.isfinite(rise) and chi2_sf(2 * rise, len(dropped)) >= 1 - LIKELIHOOD_RATIO)):
            why = (
                f"fixing {', '.join(dropped)} raised the cost by {rise:.4g}, more than the χ² "
                f"test allows (p = {chi2_sf(2 * rise, len(dropped)):.2g})"
                if np.isfinite(rise)
                else f"the fit with {', '.join(dropped)} fixed diverged"
            )
            structural = {n: w for n, w in s.fixed.items() if n not in dropped}
            fitted = without(config, structural)
            s = replace(s, config=fitted, fixed=structural)
            estimate, rest = (
                replace(s.fit, start_reason=f"{s.fit.start_reason}; the screen kept them: {why}"),
                steps,
            )
        for step in rest if callback is not None else ():  # the steps of the fit returned
            callback(step)
    else:
        estimate = identify(experiments, fitted, method=method, options=options, callback=callback)
    return Screened(fitted, estimate, s.fixed, apply, s.skipped)
