"""Rerun recordings of fits (parameters, comparison, validation, outputs) and the viewer.

A fit opens on its parameters tab, one plot per coefficient, on the timeline they are logged on:
`iteration` for the off-line fits, `time` for the filters. Styles, series and atomic writing
are the run recordings' (`testbed.simulation.recording`). `replay` finds a recording's viewer.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from testbed.errors import InputError
from testbed.estimators import FilterEstimate
from testbed.analysis.validation import predicted
from testbed.simulation.recording import (
    axis_range,
    data_id,
    panel_title,
    recording,
    series,
    time_column,
    x_range,
)

__all__ = ["log_fit", "replay"]

OUTPUTS_KEY = "thin grey: measured · bold red: the identified model's response to the measured fin angles"
PARAMETERS_KEY = {
    "iteration": (
        "bold blue: the estimate at each iteration · light blue: ± σ (Cramér-Rao) about the final "
        "estimate · orange: the analytic value · green: the fit to the noise-free truth (the linear "
        "model's best). The outputs are on the `time` timeline: choose it at the bottom left."
    ),
    "time": (
        "bold blue: the filter's estimate after each sample · light blue: its ± σ · orange: the analytic "
        "value · green: the fit to the noise-free truth (the linear model's best) · the experiments one "
        "after the other"
    ),
}


def _parameters(rec, estimate, iterations, comparison):
    """Log each free coefficient's history on one entity: the estimate, its ±σ band, and the
    analytic value and truth fit as constant lines. Returns the parameters tab (or None, with
    nothing to show) and the timeline it is on: `iteration` for the off-line methods (±σ: the
    Cramér-Rao bound about the final estimate), `time` for the filters (their σ at each sample)."""
    free = tuple(estimate.free)
    cost = None
    if isinstance(estimate, FilterEstimate):
        history_t = estimate.history_t
        timeline, x = "time", np.asarray(history_t, float)
        index = time_column(x)
        values, std = np.asarray(estimate.history, float), np.asarray(estimate.history_std, float)
        centre = values
        settled = len(x) // 20  # the prior's wide σ and first steps are left out of the y range
    else:
        if iterations:
            x = np.array([k for k, _, _ in iterations])
            values = np.array([v for _, v, _ in iterations], float)
            cost = np.array([c for _, _, c in iterations], float)
        elif estimate.history is not None:
            values = np.asarray(estimate.history, float)
            x = np.arange(len(values))
        else:
            return None, "time"
        timeline = "iteration"
        index = rr.TimeColumn("iteration", sequence=x)
        centre = np.broadcast_to(np.asarray(estimate.values, float), values.shape)
        std = np.broadcast_to(np.asarray(estimate.std, float), values.shape)
        settled = 0
    std = np.where(np.isfinite(std), std, np.nan)  # an unidentifiable coefficient has no band
    refs = []
    if comparison is not None:
        refs.append(("analytic", np.asarray(comparison.analytic, float)))
        if comparison.truth_fit is not None:
            refs.append(("truth fit", np.asarray(comparison.truth_fit, float)))
    axis_x = x_range(timeline, x[0], x[-1])
    views = {}
    for j, n in enumerate(free):
        columns = [values[:, j], centre[:, j] - std[:, j], centre[:, j] + std[:, j]]
        columns += [np.full(len(x), r[j]) for _, r in refs]
        series(
            rec,
            f"/parameters/{n}",
            index,
            np.column_stack(columns),
            ("estimate", "σ band", "σ band", *[role for role, _ in refs]),
            ("estimate", "-σ", "+σ", *[role for role, _ in refs]),
        )
        late = slice(max(settled, len(x) // 2), None)
        shown = np.concatenate(
            [values[settled:, j], columns[1][late], columns[2][late], *[r[j : j + 1] for _, r in refs]]
        )
        views[n] = rrb.TimeSeriesView(
            origin=f"/parameters/{n}",
            name=n,
            axis_x=axis_x,
            axis_y=rrb.ScalarAxis(range=axis_range(shown, 4)),
            plot_legend=rrb.PlotLegend(visible=False),
        )
    rows = {}  # one row per equation (X, Y, Z, K, M, N), in the order of `free`
    for n in free:
        rows.setdefault(n.split("_")[0], []).append(views[n])
    side = [rrb.TextDocumentView(origin="/key/parameters", name="key", titlebar=False)]
    rec.log(
        "/key/parameters",
        rr.TextDocument(PARAMETERS_KEY[timeline], media_type=rr.MediaType.MARKDOWN),
        static=True,
    )
    if cost is not None:
        # J is a negative log-likelihood (any sign): its distance to the least value reached (the
        # estimate's, also with several starts in turn), which shrinks geometrically as the fit
        # converges, on a log scale; the least itself is 0: not drawn
        above = np.log10(np.where(cost - cost.min() > 0, cost - cost.min(), np.nan))
        series(rec, "/cost", index, above, ("cost",), ("log10(J - J_final)",))
        side.insert(
            0,
            rrb.TimeSeriesView(
                origin="/cost",
                name="cost: log₁₀(J − J_final)",
                axis_x=axis_x,
                axis_y=rrb.ScalarAxis(range=axis_range(above, 4)),
                plot_legend=rrb.PlotLegend(visible=False),
            ),
        )
    tab = rrb.Horizontal(
        rrb.Vertical(*[rrb.Horizontal(*row) for row in rows.values()]),
        rrb.Vertical(*side),
        column_shares=[4, 1],
        name="parameters",
    )
    return tab, timeline


def _comparison_markdown(comparison) -> str:
    """The comparison as a Markdown table, with what its columns mean."""
    truth = comparison.truth_fit is not None

    def num(v, fmt=".4g"):
        return "–" if v is None else format(v, fmt)

    head = ["coefficient", "analytic", "identified", "± σ", "error (σ)", "error (%)"]
    if truth:
        head += ["truth fit", "model bias (%)", "noise (σ)"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in comparison.rows():
        sigmas = num(r["error_sigmas"], "+.1f")
        if r["error_sigmas"] is not None and abs(r["error_sigmas"]) > 3:
            sigmas = f"**{sigmas}**"
        cells = [
            f"`{r['name']}`",
            num(r["analytic"]),
            num(r["identified"]),
            num(r["std"], ".2g"),
            sigmas,
            num(None if r["relative_error"] is None else 100 * r["relative_error"], "+.1f"),
        ]
        if truth:
            bias = r["model_bias_relative"]
            cells += [
                num(r["truth_fit"]),
                num(None if bias is None else 100 * bias, "+.1f"),
                num(r["noise_sigmas"], "+.1f"),
            ]
        lines.append("| " + " | ".join(cells) + " |")
    text = [
        "## Identified versus analytic coefficients",
        "",
        "error = identified − analytic, in Cramér-Rao σ (bold beyond 3 σ) and in % of |analytic|.",
    ]
    if truth:
        text.append(
            "truth fit: `ml-gn` on the noise-free truth, the best the linear model can do; model bias = "
            "truth fit − analytic (% of |analytic|), noise = identified − truth fit (σ)."
        )
    if comparison.note:
        text.append(comparison.note)
    return "\n".join([*text, "", *lines])


def _validation_markdown(validation) -> str:
    """Fit % and residual whiteness per experiment and channel, as a Markdown table."""
    rows = [
        "Fit % of the model simulated open loop from its best initial state "
        "(100 (1 − ‖y − ŷ‖/‖y − ȳ‖)); the residual's largest autocorrelation over lags 1–25 "
        "against its 99 % bound, and the Ljung-Box p-value (white: p ≥ 0.01).",
        "",
        "| experiment | channel | fit % | analytic fit % | max \\|r_k\\| | bound | Ljung-Box p | residual |",
        "|---|---|---:|---:|---:|---:|---:|---|",
    ]
    for name, channels in validation.to_dict().items():
        for c, m in channels.items():
            w = m["whiteness"]
            fit = "–" if m["fit_percent"] is None else f"{m['fit_percent']:.2f}"
            base = m.get("fit_percent_analytic")
            base = "–" if base is None else f"{base:.2f}"
            rows.append(
                f"| {name} | {c} | {fit} | {base} | {w['max_autocorrelation']:.3f} | {w['bound']:.3f} | "
                f"{w['ljung_box_p']:.2g} | {'white' if w['white'] else '**coloured**'} |"
            )
    return "\n".join(rows)


def log_fit(
    path,
    experiments,
    config,
    estimate,
    iterations,
    comparison=None,
    recording_id: str | None = None,
    validation=None,
    force: bool = False,
) -> Path:
    """A recording of a fit: the parameters tab (each coefficient's estimate per iteration, or
    over time for the filters, with ±σ, the analytic value and the truth fit; the cost), the
    comparison table, the validation metrics (`testbed.analysis.validation.Validation`: fit % and
    residual whiteness per experiment and channel), and measured versus model outputs per
    experiment. It opens on the parameters tab and the timeline they are logged on.

    The model outputs (the linear model's, or a nonlinear model config's flown by
    `nonlinear_prediction`) start from the estimate's `initial_states` when it has them (the
    output-error methods), else from best-fitting initial states. `recording_id` defaults to one
    derived from the method, the data and the estimate. An existing file at `path` is an
    `InputError` unless `force` (then replaced).
    """
    title = f"testbed fit ({estimate.method})"
    history_t = estimate.history_t if isinstance(estimate, FilterEstimate) else None
    if recording_id is None:
        recording_id = data_id(
            title,
            *[part for e in experiments for part in (e.name, e.t, e.y, e.inputs)],
            tuple(estimate.free),
            np.asarray(estimate.values, float),
            history_t,
        )
    fitted = config.with_coefficients(estimate.coefficients)
    try:
        outputs = predicted(experiments, fitted, estimate.initial_states)
    except (InputError, np.linalg.LinAlgError, ValueError):
        outputs = [None] * len(experiments)  # a model that cannot be simulated: log the rest
    tabs = []
    with recording(path, title, recording_id, force) as rec:
        parameters, timeline = _parameters(rec, estimate, iterations, comparison)
        if parameters is not None:
            tabs.append(parameters)
        if comparison is not None:
            table = rr.TextDocument(_comparison_markdown(comparison), media_type=rr.MediaType.MARKDOWN)
            rec.log("/comparison/table", table, static=True)
            tabs.append(rrb.TextDocumentView(origin="/comparison/table", name="comparison"))
        if validation is not None:
            table = rr.TextDocument(_validation_markdown(validation), media_type=rr.MediaType.MARKDOWN)
            rec.log("/validation/table", table, static=True)
            tabs.append(rrb.TextDocumentView(origin="/validation/table", name="validation"))
        rec.log("/key/outputs", rr.TextDocument(OUTPUTS_KEY, media_type=rr.MediaType.MARKDOWN), static=True)
        for e, y in zip(experiments, outputs):
            t = time_column(e.t)
            panels = []
            for j, s in enumerate(e.measured):
                model = () if y is None else (y[:, j],)
                series(
                    rec,
                    f"/outputs/{e.name}/{s}",
                    t,
                    np.column_stack([e.y[:, j], *model]),
                    ("measured", "model")[: 1 + len(model)],
                )
                panels.append(
                    rrb.TimeSeriesView(
                        origin=f"/outputs/{e.name}/{s}",
                        name=panel_title(s),
                        axis_x=x_range("time", e.t[0], e.t[-1]),
                        axis_y=rrb.ScalarAxis(range=axis_range(np.concatenate([e.y[:, j], *model]))),
                        plot_legend=rrb.PlotLegend(visible=False),
                    )
                )
            key = rrb.TextDocumentView(origin="/key/outputs", name="key", titlebar=False)
            tabs.append(
                rrb.Vertical(
                    rrb.Grid(*panels, grid_columns=3),
                    key,
                    row_shares=[24, 1],
                    name=f"{e.name}: outputs (time)",
                )
            )
        rec.send_blueprint(
            rrb.Blueprint(
                rrb.Tabs(*tabs, active_tab=0),
                rrb.TimePanel(state="collapsed", timeline=timeline),
                collapse_panels=True,
            )
        )
    return Path(path)


def replay(run) -> str:
    """Open a run's `recording.rrd` (or an .rrd file) in the Rerun viewer; returns what was done,
    or, where there is no display, the command that would show it."""
    run = Path(run)
    path = run / "recording.rrd" if run.is_dir() else run
    if not path.is_file():
        raise InputError(f"{path}: no such recording; expected a run directory or an .rrd file")
    viewer = shutil.which("rerun") or str(Path(sys.executable).with_name("rerun"))
    headless = sys.platform.startswith("linux") and not (
        os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
    )
    if headless or not Path(viewer).exists():
        return (
            f"no display here: on a machine with one, run `rerun {path}`; or serve it to a "
            f"browser with `rerun --serve-web {path}`"
        )
    subprocess.Popen([viewer, str(path)], start_new_session=True)
    return f"opened {path} in the Rerun viewer"
