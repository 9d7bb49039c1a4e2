"""Reports: one self-contained HTML page (its figures embedded as PNG, no network) of what an
identification engineer looks at (MATLAB's `compare` and `resid`, SIDPAC's plots). A fit's page
(`identify --report`, `fit_report_html`, `SECTIONS`):

- **summary**: the method, how the fit ended, its cost, every start with the cost it reached,
  what the screen fixed and why, the records and the stretches the model is flown over;
- **outputs**: per record, each channel measured against the fitted model and the a-priori one,
  fit % in the panel's title;
- **residuals**: per record, the residuals over time, their autocorrelation with the whiteness
  test's 99 % band and their spectrum; which channels are coloured;
- **coefficients**: each estimate and a-priori value with ±2σ (Cramér-Rao and coloured-residual)
  over its reference (the analytic model of a run, a captive config, where known), and the table;
- **trial**: the trial's parameters, free or set (`trial_parameters`): the offsets `X_0` … `N_0`,
  the output biases, the current, the velocity log's mounting and the inputs' delay, each with
  its unit, estimate, bounds and a-priori value;
- **correlation**: the estimates' correlation matrix, the drift groups and the analysis' summary
  at the estimate (`analyze`);
- **convergence**: the cost per iteration.

A validation's page has its summary, outputs and residuals (`validation_report_html`); an
analysis' its records, bounds and correlation (`analysis_report_html`); a data-compatibility
check's its corrections and each check's parameters (`check_report_html`). `write_fit_report`
writes a page to `FOLDER/report.html`; a folder holding anything else is refused.
"""

from __future__ import annotations

import base64
import html
import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from testbed.analysis.identifiability import identifiability
from testbed.analysis.nonlinear_identifiability import nonlinear_identifiability
from testbed.analysis.validation import Validation, predicted, validate
from testbed.data import Experiment, ModelConfig, stretch_name, stretches
from testbed.outputs import atomic_write_text, check_output_directory
from testbed.errors import InputError
from testbed.html_table import html_table
from testbed.identification.problem import base_name
from testbed.models.linear import CURRENT, DELAY, MOUNTING, OFFSETS, STATES
from testbed.presentation import fit_figures

__all__ = [
    "ANALYSIS_SECTIONS",
    "REPORT",
    "SECTIONS",
    "TRIAL_UNITS",
    "VALIDATION_SECTIONS",
    "analysis_report_html",
    "check_report_folder",
    "check_report_html",
    "fit_report_html",
    "report",
    "trial_parameters",
    "validation_report_html",
    "write_fit_report",
]

REPORT = "report.html"
SECTIONS = ("summary", "outputs", "residuals", "coefficients", "trial", "correlation", "convergence")
VALIDATION_SECTIONS = ("summary", "outputs", "residuals")  # a validation has no fit to show
ANALYSIS_SECTIONS = ("summary", "bounds", "correlation")
_STYLE = (
    "body{font-family:sans-serif;max-width:1250px;margin:2em auto;padding:0 1em;color:#222}"
    "table{border-collapse:collapse;margin:0.8em 0}td,th{border:1px solid #ccc;padding:3px 8px}"
    "th{background:#f3f3f3}caption{text-align:left;font-weight:bold;padding:4px 0;white-space:nowrap}"
    "img{max-width:100%;border:1px solid #ddd;margin:0.4em 0}nav a{margin-right:1em}"
)


# each trial parameter's unit (docs/model.md): the offsets' forces and moments, the output biases'
# in their state's unit, the current's velocity, the mounting's angles and lever arm, the delay
TRIAL_UNITS = {
    **{n: "N" if n[0] in "XYZ" else "N m" for n in OFFSETS},
    **{f"b_{x}": fit_figures.UNITS[x] for x in STATES},
    **dict.fromkeys(CURRENT, "m/s"),
    **{n: "rad" if n.startswith("m_") else "m" for n in MOUNTING},
    DELAY: "s",
}


def check_report_folder(folder: str | os.PathLike, force: bool = False) -> Path:
    """`InputError` unless `folder` can take the report: a new folder, an empty one, or (with
    `force`) one holding only a report. A folder of anything else is a user's: never written to."""
    folder = Path(folder)
    if not os.path.lexists(folder):
        check_output_directory(folder, label=f"--report {folder}")
        return folder
    if not folder.is_dir():
        raise InputError(f"--report {folder}: is a file; expected a new or empty folder for the report")
    held = sorted(p.name for p in folder.iterdir())
    if held and not (force and held == [REPORT]):
        raise InputError(
            f"--report {folder}: holds {held[0]}{' and more' if len(held) > 1 else ''}; expected a new or "
            f"empty folder (or one holding only {REPORT}, with --force)"
        )
    return folder


def _img(png: bytes, alt: str) -> str:
    return f"<img alt='{html.escape(alt)}' src='data:image/png;base64,{base64.b64encode(png).decode()}'>"


def _predicted(experiments, config: ModelConfig, initial) -> list[np.ndarray]:
    with np.errstate(all="ignore"):  # a diverging model's outputs are drawn as they come
        return predicted(experiments, config, initial)


def _drawn(tasks: Sequence[tuple]) -> list[bytes]:
    """Each `(figure, arguments)` drawn, in order: in worker processes, one per core, where there
    are several of both (matplotlib draws on one core; each figure takes a fraction of a second),
    else here."""
    workers = min(len(tasks), len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else 1)
    if workers < 2:
        return [f(*args) for f, args in tasks]
    with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("fork")) as pool:
        return list(pool.map(_draw, tasks))


def _draw(task: tuple) -> bytes:
    figure, args = task
    return figure(*args)


def _page(title: str, sections: Sequence[tuple[str, str, str]]) -> str:
    """The page: `title`, a navigation bar, and each `(id, heading, body)` as a `<section>`."""
    e = html.escape
    parts = [
        "<!doctype html><html lang='en'><head><meta charset='utf-8'>",
        f"<title>{e(title)}</title><style>{_STYLE}</style></head><body>",
        f"<h1>{e(title)}</h1><nav>",
        *(f"<a href='#{k}'>{k}</a>" for k, _, _ in sections),
        "</nav>",
    ]
    parts += [f"<section id='{k}'><h2>{e(heading)}</h2>\n{body}\n</section>" for k, heading, body in sections]
    return "\n".join(parts + ["</body></html>"])


def _records(experiments: Sequence[Experiment]) -> str:
    """The records: their samples, duration, channels and the stretches the model is flown over."""
    rows = [
        (
            r.name,
            len(r.t),
            f"{r.t[-1] - r.t[0]:.4g}",
            ", ".join(r.measured),
            "; ".join(stretch_name(r, a, b) for a, b in stretches(r)),
        )  # fmt: skip
        for r in experiments
    ]
    head = ("record", "samples", "duration (s)", "channels", "flown over")
    return html_table(head, rows, "the records (one split at a dropout in its fins: its stretches)")


def _outputs_and_residuals(experiments, model, before, validation: Validation) -> tuple[str, str]:
    """The outputs section's body (per record, measured against `model` and the a-priori
    `before`, fit % from `validation`) and the residuals section's (per record over time, their
    autocorrelation and spectrum, which channels are coloured; the metrics table)."""
    e = html.escape
    metrics = validation.experiments
    tasks = []  # (figure, its arguments) per record: drawn side by side (`_drawn`)
    for r, yhat, y0 in zip(experiments, model, before or [None] * len(experiments)):
        m = metrics.get(r.name, {})
        fits = [m[c].fit_percent if c in m else None for c in r.measured]
        res = r.y - yhat
        bounds = [m[c].whiteness.bound if c in m else 0.0 for c in r.measured]
        white = [m[c].whiteness.white if c in m else True for c in r.measured]
        tasks += [
            (fit_figures.outputs_figure, (r.name, r.t, r.measured, r.y, yhat, fits, y0)),
            (fit_figures.residuals_figure, (r.name, r.t, r.measured, res)),
            (fit_figures.autocorrelation_figure, (r.name, r.measured, res, bounds, white)),
            (fit_figures.spectrum_figure, (r.name, r.dt, r.measured, res)),
        ]
    drawn = iter(_drawn(tasks))
    outputs, residuals = [], []
    for r in experiments:
        m = metrics.get(r.name, {})
        coloured = [c for c in r.measured if c in m and not m[c].whiteness.white]
        outputs.append(_img(next(drawn), f"{r.name} outputs"))
        residuals.append(f"<h3>{e(r.name)}</h3><p>coloured: {e(', '.join(coloured) or 'none')}</p>")
        residuals += [
            _img(next(drawn), f"{r.name} {what}") for what in ("residuals", "autocorrelation", "spectrum")
        ]
    residuals.append(html_table(*validation.rows(), "fit % and residual whiteness per channel"))
    return "\n".join(outputs), "\n".join(residuals)


def _validated(experiments, validation: Validation) -> list[np.ndarray] | None:
    """The model's outputs the validation scored (the fit % shown beside them), where it holds
    every record with its channels; else None."""
    out = []
    for r in experiments:
        p = validation.predictions.get(r.name)
        if p is None or tuple(p.measured) != tuple(r.measured):
            return None
        out.append(np.asarray(p.y, float))
    return out


def _a_priori(experiments, prior: ModelConfig | None, initial=None):
    """The a-priori model's predictions, or None (no prior, or one that cannot be flown here): a
    nonlinear model flown from the fit's initial states `initial` (its own best-fitting ones cost
    a Gauss-Newton fit per record), the linear model from its best-fitting ones (least squares)."""
    if prior is None:
        return None
    try:
        return _predicted(experiments, prior, initial if prior.terms is not None else None)
    except (InputError, np.linalg.LinAlgError, ValueError):
        return None


def _summary(estimate, recording: str | None, fixed: Mapping[str, str] | None, experiments) -> str:
    """How the fit ended, every start, the recording, what the screen fixed, the records."""
    e = html.escape
    parts = [
        f"<p><b>{e(estimate.method)}</b>: {e(estimate.status.message)}; {estimate.iterations} iterations, "
        f"{estimate.evaluations} simulations, cost (negative log-likelihood) {estimate.cost:.6g}, from the "
        f"{e(estimate.start)} start{e(f' ({estimate.start_reason})' if estimate.start_reason else '')}.</p>"
    ]
    if recording is not None:
        parts.append(
            f"<p>The fit's Rerun recording: <a href='{e(recording)}'>{e(recording)}</a> "
            f"(open it with <code>rerun {e(recording)}</code>).</p>"
        )
    if estimate.starts:
        rows = [
            (
                t.get("start"),
                f"{t.get('cost', float('nan')):.6g}",
                t.get("status", t.get("reason", "")),
                t.get("iterations", ""),
            )  # fmt: skip
            for t in estimate.starts
        ]
        parts.append(html_table(("start", "cost", "status", "iterations"), rows, "every start tried"))
    if fixed:
        parts.append(
            html_table(("coefficient", "fixed because"), sorted(fixed.items()), "what the screen fixed")
        )
    parts.append(_records(experiments))
    return "\n".join(parts)


def trial_parameters(names) -> list[str]:
    """The trial's parameters among `names` (a per-record one by its base name): the offsets, the
    output biases, the current, the velocity log's mounting and the inputs' delay, which a real
    trial adds to the model's coefficients."""
    return [n for n in names if base_name(n) in TRIAL_UNITS]


def _value(config: ModelConfig, name: str) -> float:
    """`config`'s value of an estimate's name: a per-record one (`N_0[zigzag]`) the record's own,
    else the config's; NaN where the config has none."""
    if name.endswith("]"):
        base, record = name[:-1].split("[", 1)
        return config.record_coefficients(record).get(base, np.nan)
    return config.values.get(name, np.nan)


def _coefficients(estimate, start: ModelConfig, reference: ModelConfig | None, label: str) -> str:
    """The estimates of the model's coefficients (the trial's parameters have their own section)
    against the a-priori values of `start` and the `reference`'s (`label` its column): the figure
    and the table."""
    trial = set(trial_parameters(estimate.free))
    keep = [k for k, n in enumerate(estimate.free) if n not in trial]
    if not keep:
        return "<p>No coefficient of the model is free: only the trial's parameters (below).</p>"
    return _estimates(estimate, keep, start, reference, label, "coefficients")


def _estimates(
    estimate, keep, start: ModelConfig, reference, label: str, title: str, shifts: bool = False
) -> str:
    """The figure and the table of the estimates `keep` (indices into `estimate.free`): each over
    its reference (`fit_figures.coefficients_figure`) or, `shifts`, its distance from the a-priori
    value in σ (`fit_figures.shifts_figure`: parameters of several units, most 0 a priori)."""
    names = [estimate.free[k] for k in keep]
    values, std = np.asarray(estimate.values, float)[keep], np.asarray(estimate.std, float)[keep]
    coloured = None
    if estimate.crlb_corrected_std is not None:
        coloured = np.asarray(estimate.crlb_corrected_std, float)[keep]
    a_priori = np.array([_value(start, n) for n in names], float)
    ref = None
    if reference is not None:
        ref = np.array([_value(reference, n) for n in names], float)
        ref = ref if np.all(np.isfinite(ref)) else None
    if shifts:
        figure = fit_figures.shifts_figure(names, values, std, coloured, a_priori)
    else:
        figure = fit_figures.coefficients_figure(names, values, std, coloured, a_priori, ref, label)
    units = [TRIAL_UNITS.get(base_name(n)) for n in names]
    rows = [
        (n,)
        + (() if not any(units) else (units[k] or "-",))
        + (f"{v:.6g}", f"{s:.3g}", "-" if coloured is None else f"{coloured[k]:.3g}", f"{a_priori[k]:.6g}")
        + (() if ref is None else (f"{ref[k]:.6g}",))
        for k, (n, v, s) in enumerate(zip(names, values, std))
    ]
    head = (
        ("parameter" if any(units) else "coefficient",)
        + (("unit",) if any(units) else ())
        + ("estimate", "σ Cramér-Rao", "σ coloured", "a-priori")
        + (() if ref is None else (label,))
    )
    return _img(figure, title) + html_table(head, rows, f"the estimates of the {title}")


def _trial(estimate, start: ModelConfig) -> str:
    """The trial's parameters: the free ones estimated (figure and table), the others as set."""
    free = trial_parameters(estimate.free)
    estimated = {base_name(n) for n in free}
    parts = []
    if free:
        keep = [estimate.free.index(n) for n in free]
        parts.append(_estimates(estimate, keep, start, None, "", "trial's parameters", shifts=True))
    held = [
        (n, TRIAL_UNITS[n], f"{v:.6g}")
        for n, v in start.values.items()
        if n in TRIAL_UNITS and n not in estimated and v != 0
    ]
    if held:
        parts.append(
            html_table(("parameter", "unit", "value"), held, "the trial's parameters set in the config")
        )
    if not parts:
        parts.append(
            "<p>None free or set: the config fixes every offset, output bias, current, mounting and "
            "delay at 0. A trial's imperfections are freed in <code>[identify] free</code> "
            "(docs/model.md).</p>"
        )
    return "\n".join(parts)


def _correlation(experiments, fitted: ModelConfig, estimate) -> str:
    """The analysis at the estimate: the correlation matrix, the drift groups, its summary."""
    try:
        if fitted.terms is None:
            analysis = identifiability(experiments, fitted, noise_std=estimate.noise_std)
        else:
            analysis = nonlinear_identifiability(
                experiments, fitted, initial=estimate.initial_states, information=estimate.information
            )
    except (InputError, np.linalg.LinAlgError, ValueError) as exc:
        return f"<p>No analysis at the estimate: {html.escape(str(exc))}</p>"
    return _analysis(analysis)


def _analysis(analysis) -> str:
    """An identifiability analysis (`analyze`'s): the correlation matrix, the drift groups and its
    summary."""
    groups = [(", ".join(g),) for g in analysis.drift_groups] or [("none",)]
    return "\n".join(
        [
            _img(fit_figures.correlation_figure(analysis.free, analysis.correlation), "correlation"),
            html_table(("drift group",), groups, "coefficients the data cannot tell apart"),
            *(f"<p>{html.escape(line)}</p>" for line in analysis.summary),
        ]
    )


def _convergence(iterations: Sequence[tuple]) -> str:
    costs = [(k, c) for k, _, c in iterations if c is not None and np.isfinite(c)]
    if len(costs) > 1:
        return _img(fit_figures.convergence_figure(costs), "convergence")
    return "<p>No cost per iteration to show (a filter, or a fit of one iteration).</p>"


def fit_report_html(
    experiments: Sequence[Experiment],
    config: ModelConfig,
    estimate,
    validation: Validation,
    prior: ModelConfig | None = None,
    iterations: Sequence[tuple] = (),
    reference: ModelConfig | None = None,
    fixed: Mapping[str, str] | None = None,
    title: str = "",
    recording: str | None = None,
    reference_label: str = "analytic",
) -> str:
    """The report's page: `config` the model config fitted (its free coefficients the estimate's),
    `validation` of the fitted model, `prior` the a-priori config (its predictions beside the fit's),
    `iterations` (iteration, values, cost) as the fit reported them, `reference` a model config
    whose coefficients are the reference (a run's analytic model, a captive config) and
    `reference_label` its name in the table, `fixed` what the screen fixed (name → why),
    `recording` the fit's Rerun recording as the page links it (a path relative to the page's
    folder)."""
    fitted = config.with_coefficients(estimate.coefficients)
    experiments = fitted.fitted(experiments)
    model = _validated(experiments, validation) or _predicted(experiments, fitted, estimate.initial_states)
    before = _a_priori(experiments, prior, estimate.initial_states)
    outputs, residuals = _outputs_and_residuals(experiments, model, before, validation)
    start = prior if prior is not None else config
    sections = [
        ("summary", "Summary", _summary(estimate, recording, fixed, experiments)),
        ("outputs", "Outputs", outputs),
        ("residuals", "Residuals", residuals),
        ("coefficients", "Coefficients", _coefficients(estimate, start, reference, reference_label)),
        ("trial", "Trial parameters", _trial(estimate, start)),
        ("correlation", "Correlation and drift", _correlation(experiments, fitted, estimate)),
        ("convergence", "Convergence", _convergence(iterations)),
    ]
    return _page(title or "testbed fit report", sections)


def analysis_report_html(
    experiments: Sequence[Experiment], config: ModelConfig, analysis, title: str = ""
) -> str:
    """An identifiability analysis' page (`analyze --report`): the records and the coefficients
    analysed with their Cramér-Rao bounds, and the correlation matrix with the drift groups."""
    bounds = html_table(*analysis.bounds(), "the bounds")
    summary = f"<p>{html.escape(config.source or 'the config')} analysed on:</p>" + _records(
        config.fitted(experiments)
    )
    sections = [
        ("summary", "Summary", summary),
        ("bounds", "Cramér-Rao bounds", bounds),
        ("correlation", "Correlation and drift", _analysis(analysis)),
    ]
    return _page(title or "testbed identifiability report", sections)


def check_report_html(result, title: str = "") -> str:
    """A data-compatibility check's page (`check --report`): the corrections it found, per check
    the sensor parameters of the pooled fit and of each record alone (figure and table) and each
    output's fit, and what was not checked."""
    e = html.escape
    head = ("parameter", "value", "σ", "identifiable", "why held")
    corrections = [
        (
            n,
            f"{p.value:.4g}",
            "∞" if not np.isfinite(p.std) else f"{p.std:.2g}",
            "yes" if p.estimated else "no",
            p.reason,
        )
        for pooled in result.pooled.values()
        for n, p in pooled.parameters.items()
    ]
    sections = [("corrections", "Corrections", html_table(head, corrections, "the pooled sensor parameters"))]
    for check, pooled in result.pooled.items():
        names = list(pooled.parameters)
        fits = [("pooled", pooled)] + [(r, c[check]) for r, c in result.records.items() if check in c]
        estimates = [
            (
                label,
                np.array([f.parameters[n].value for n in names]),
                np.array([f.parameters[n].std if f.parameters[n].estimated else 0.0 for n in names]),
            )  # fmt: skip
            for label, f in fits
        ]
        rows = [
            (
                o,
                "-" if v["fit_percent"] is None else f"{v['fit_percent']:.2f}",
                f"{v['residual_std']:.3g}",
                f"{v['noise_std']:.3g}",
                f"{v['innovation_rms']:.3g}",
            )  # fmt: skip
            for o, v in pooled.fit.items()
        ]
        body = "\n".join(
            [
                f"<p>Fitted on {e(', '.join(pooled.records))}; {pooled.iterations} evaluations.</p>",
                _img(fit_figures.corrections_figure(check, names, estimates), f"{check} parameters"),
                html_table(
                    ("output", "fit %", "residual σ", "noise σ", "innovation rms"), rows, "the reconstruction"
                ),
            ]
        )
        sections.append((check, f"The {check} check", body))
    unchecked = [
        (name, check, why) for name, checks in result.unchecked.items() for check, why in checks.items()
    ]
    sections.append(
        (
            "unchecked",
            "Not checked",
            html_table(("record", "check", "why"), unchecked or [("-", "-", "every record checked")]),
        )
    )
    return _page(title or "testbed check report", sections)


def validation_report_html(
    experiments: Sequence[Experiment],
    config: ModelConfig,
    validation: Validation,
    prior: ModelConfig | None = None,
    title: str = "",
    note: str = "",
) -> str:
    """A validation's page: the model of `config` flown on the records (held out from its fit, as
    a rule) against what they measured, beside `prior`'s where given, with the residuals and their
    whiteness; `note` says what model and coefficients were validated."""
    experiments = config.fitted(experiments)
    model = _validated(experiments, validation) or _predicted(experiments, config, None)
    outputs, residuals = _outputs_and_residuals(experiments, model, _a_priori(experiments, prior), validation)
    summary = (f"<p>{html.escape(note)}</p>" if note else "") + _records(experiments)
    sections = [
        ("summary", "Summary", summary),
        ("outputs", "Outputs", outputs),
        ("residuals", "Residuals", residuals),
    ]
    return _page(title or "testbed validation report", sections)


def write_fit_report(folder: str | os.PathLike, page: str, force: bool = False) -> Path:
    """`page` written to `folder/report.html` (`check_report_folder`: a new or empty folder)."""
    folder = check_report_folder(folder, force)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / REPORT
    atomic_write_text(path, page, force=True)
    return path


def report(
    folder: str | os.PathLike,
    experiments: Sequence[Experiment],
    config: ModelConfig,
    estimate,
    prior: ModelConfig | None = None,
    iterations: Sequence[tuple] = (),
    reference: ModelConfig | None = None,
    force: bool = False,
    reference_label: str = "analytic",
) -> Path:
    """The report of `estimate` (fitted to `experiments` with `config`) written to
    `folder/report.html`, the fitted model validated on the same records: `testbed identify
    --report` from Python. `prior`, `iterations`, `reference` and `reference_label` as for
    `fit_report_html`."""
    check_report_folder(folder, force)
    fitted = config.with_coefficients(estimate.coefficients)
    initial = estimate.initial_states if config.terms is not None else None
    validation = validate(experiments, fitted, reference if config.terms is None else None, initial)
    page = fit_report_html(
        experiments,
        config,
        estimate,
        validation,
        prior,
        iterations,
        reference,
        reference_label=reference_label,
    )
    return write_fit_report(folder, page, force)
