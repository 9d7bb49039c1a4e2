"""The captive tests in a Rerun recording (`testbed captive --rrd FILE`): a tab with the fit of
every force surface, then a tab per test with a plot per speed and wrench row the test excites,
the plant's wrench as points and the fitted model's as a line (`captive_sweeps`), the fit % in the
plot's name; an oscillation's tab also has its in-phase and quadrature parts.

A plot's abscissa is a timeline, so every test shares one: `sweep`, a sequence, the swept
variable in thousandths of its unit (mm/s, mrad/s, mrad) and an oscillation's time in ms. A
value is rounded to it; of the model's curve's values that round to one already logged the first
alone is kept (only for extents under 0.04 of their unit).
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from testbed.presentation.captive_sweeps import SWEEP_UNITS, Series, SweepPanel, by_test, series_colours
from testbed.simulation.recording import axis_range, data_id, recording

__all__ = ["KEY", "MILLI", "TIMELINE", "log_captive", "milli", "sweep_entity"]

TIMELINE = "sweep"
KEY = (
    "points: the plant's wrench read in the captive test · line: the fitted model's (blue and red; "
    "a grid of two variables: one colour per value of the other, named on hover) · x: timeline "
    "`sweep`, the swept variable in thousandths of its unit (mm/s, mrad/s, mrad), an oscillation's "
    "time in ms"
)


MILLI = {"m/s": "mm/s", "rad/s": "mrad/s", "rad": "mrad", "s": "ms"}  # the abscissa's unit on `sweep`


def milli(x) -> np.ndarray:
    """A value on the `sweep` timeline: x (SI) in thousandths, rounded."""
    return np.rint(1000.0 * np.asarray(x, float)).astype(np.int64)


def sweep_entity(p: SweepPanel) -> str:
    """The entity of a panel: its series are `plant` and `model`, a column per slice."""
    return f"/captive/{p.test}/{p.speed:g}/{p.row}"


def _log(rec, entity: str, series: Sequence[Series], style) -> None:
    """The slices of a panel's plant or model on one entity, a column each (they share x)."""
    x, first = np.unique(milli(series[0].x), return_index=True)
    rec.log(entity, style, static=True)
    rec.send_columns(
        entity,
        indexes=[rr.TimeColumn(TIMELINE, sequence=x)],
        columns=rr.Scalars.columns(scalars=np.column_stack([s.y[first] for s in series])),
    )


def _view(p: SweepPanel) -> rrb.TimeSeriesView:
    x = np.concatenate([milli(s.x) for s in p.plant + p.model])
    y = np.concatenate([s.y for s in p.plant + p.model])
    at = rrb.TimeRangeBoundary.absolute
    return rrb.TimeSeriesView(
        origin=sweep_entity(p),
        name=f"{p.row} ({SWEEP_UNITS[p.row]}) against {p.x} ({MILLI[SWEEP_UNITS[p.x]]}) at {p.speed:g} m/s: fit {p.fit:.2f} %",
        axis_x=rrb.TimeAxis(view_range=rr.TimeRange(start=at(seq=int(x.min())), end=at(seq=int(x.max())))),
        axis_y=rrb.ScalarAxis(range=axis_range(y, 6)),
        plot_legend=rrb.PlotLegend(visible=False),
    )


def _parts_table(panels: Sequence[SweepPanel]) -> str:
    lines = ["| u m/s | part | plant | model |", "|---|---|---|---|"]
    for p in panels:
        lines += [f"| {p.speed:g} | {n} | {a:.5g} | {b:.5g} |" for n, (a, b) in p.parts.items()]
    return "\n".join(lines)


def log_captive(
    path: str | Path, panels: Sequence[SweepPanel], table: str, text: str, force: bool = False
) -> Path:
    """Write the recording of `panels` to `path`: `table` the fit of every force surface (`CaptiveFit.table`),
    `text` the model config written (the recording's id is derived from it)."""
    title = "testbed captive"
    with recording(path, title, data_id(title, text), force) as rec:
        rec.log("/key", rr.TextDocument(KEY, media_type=rr.MediaType.MARKDOWN), static=True)
        rec.log("/fit", rr.TextDocument(f"```\n{table}\n```", media_type=rr.MediaType.MARKDOWN), static=True)
        tabs = [rrb.TextDocumentView(origin="/fit", name="fit")]
        for test, own in by_test(panels).items():
            for p in own:
                dots, lines = zip(*series_colours(len(p.plant)))
                points = rr.SeriesPoints(
                    colors=dots,
                    names=[s.label or "plant" for s in p.plant],
                    markers=["circle"] * len(dots),
                    marker_sizes=[3.0] * len(dots),
                )
                _log(rec, f"{sweep_entity(p)}/plant", p.plant, points)
                curve = rr.SeriesLines(colors=lines, names=[s.label or "model" for s in p.model])
                _log(rec, f"{sweep_entity(p)}/model", p.model, curve)
            body = rrb.Grid(*map(_view, own), grid_columns=len({p.row for p in own}))
            if any(p.parts for p in own):  # an oscillation: its in-phase and quadrature parts beside
                table_md = rr.TextDocument(_parts_table(own), media_type=rr.MediaType.MARKDOWN)
                rec.log(f"/parts/{test}", table_md, static=True)
                body = rrb.Horizontal(
                    body, rrb.TextDocumentView(origin=f"/parts/{test}"), column_shares=[5, 1]
                )
            key = rrb.TextDocumentView(origin="/key", name="key", titlebar=False)  # a view has one parent
            tabs.append(rrb.Vertical(body, key, row_shares=[24, 1], name=test))
        rec.send_blueprint(
            rrb.Blueprint(
                rrb.Tabs(*tabs, active_tab=1),
                rrb.TimePanel(timeline=TIMELINE, state="collapsed"),
                collapse_panels=True,
            )
        )
    return Path(path)
