"""The experiment design as the user sees it: its table of bounds, the scenario file with the
design's account in its header, its Rerun recording, and the command's files
(`testbed design`). The design itself is `testbed.analysis.design`.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Sequence

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from testbed.analysis.design import Design, design
from testbed.analysis.design_signals import GROWTH_MARGIN
from testbed.analysis.regime import Limits
from testbed.data import read_estimates as data_read_estimates
from testbed.outputs import atomic_write_text, check_outputs
from testbed.models.linear import INPUTS, STATES
from testbed.simulation.measurements import NOISE_STD
from testbed.simulation.recording import (
    STYLE,
    axis_range,
    data_id,
    panel_title,
    recording,
    series,
    time_column,
    x_range,
)
from testbed.simulation.scenario import scenario_text

__all__ = [
    "BOUNDS_KEY",
    "DESIGN_COLUMNS",
    "FLIGHTS_KEY",
    "MOVED",
    "limits_text",
    "log_design",
    "design_estimates",
    "rows",
    "summary",
    "table",
    "text",
    "write_design",
]


def limits_text(limits: Limits) -> str:
    """The bounds of the regime in one line."""
    deg = math.degrees
    return (
        f"yaw rate {deg(limits.yaw_rate):.2f} deg/s, pitch rate {deg(limits.pitch_rate):.2f} deg/s, "
        f"roll rate {deg(limits.roll_rate):.2f} deg/s, sideslip {deg(limits.sideslip):.3f} deg, "
        f"heave {limits.heave:.4f} m/s, pitch {deg(limits.pitch):.2f} deg, roll {deg(limits.roll):.2f} deg, "
        f"fin {limits.fin:g} rad, fin rate {limits.fin_rate:g} rad/s"
    )


DESIGN_COLUMNS = ("coefficient", "value", "design σ", "design %", "II σ", "II %", "II/design")


def rows(d: Design) -> list[tuple[str, ...]]:
    """Per coefficient, formatted (`DESIGN_COLUMNS`): value, predicted bound and relative bound (%)
    of the design and of Scenario II at the same flight time, and their ratio."""
    rel = 100 * d.relative(d.crlb), 100 * d.relative(d.crlb_base)
    return [
        (
            n,
            f"{v:.4g}",
            f"{a:.3g}",
            f"{ra:.3g}" if v else "-",
            f"{b:.3g}",
            f"{rb:.3g}" if v else "-",
            f"{b / a:.2f}",
        )
        for n, v, a, b, ra, rb in zip(d.free, d.values, d.crlb, d.crlb_base, *rel)
    ]


def summary(d: Design) -> str:
    """The worst relative bounds of the design and of Scenario II."""
    (n1, w1), (n2, w2) = d.worst()
    return (
        f"worst relative bound: design {100 * w1:.3g} % ({n1}), Scenario II {100 * w2:.3g} % ({n2}), "
        f"{d.duration:g} s each"
    )


def table(d: Design) -> str:
    """`rows` under `DESIGN_COLUMNS`, fixed width, then the worst relative bounds."""
    widths = (12, 12, 11, 10, 11, 10, 10)

    def line(cells):  # the name left-aligned, the numbers right-aligned
        return "".join(f"{c:<{w}}" if k == 0 else f"{c:>{w}}" for k, (c, w) in enumerate(zip(cells, widths)))

    return "\n".join([line(DESIGN_COLUMNS), *map(line, rows(d)), summary(d)])


def text(d: Design) -> str:
    """The scenario file, its header comments giving how it was designed and the bounds."""
    deg = math.degrees
    head = [
        f"Designed experiment ({d.criterion}-optimal Fisher information of {len(d.free)} free "
        f"coefficients at the {d.source}), {d.duration:g} s of flight."
    ]
    if d.left_out:
        head += ["Left out (Scenario II at this flight time does not identify them; --free to choose):"]
        head += [f"  {n}: {why}" for n, why in d.left_out.items()]
    head += [
        "Signal shapes ranked with their peaks at Scenario II's on the same model:",
        "  " + limits_text(d.limits),
    ]
    if d.growth:
        head += [
            "then grown on the truth plant to the largest amplitude that keeps the linear "
            f"regime's rule with its tolerances x{GROWTH_MARGIN:g}: "
            + ", ".join(
                f"{k} x{g:.2f}" + ("" if h is None else f" (its hold steps the depth {h:g} m at mid-record)")
                for k, (g, h) in d.growth.items()
            )
        ]
    head += ["Peaks on the design model:"]
    head += [
        f"  {n}: yaw rate {deg(p['yaw_rate']):.2f} deg/s, pitch rate {deg(p['pitch_rate']):.2f} deg/s, "
        f"roll rate {deg(p['roll_rate']):.2f} deg/s, sideslip {deg(p['sideslip']):.3f} deg, "
        f"pitch {deg(p['pitch']):.2f} deg, roll {deg(p['roll']):.2f} deg, fin {deg(p['fin']):.3f} deg"
        for n, p in d.peaks.items()
    ]
    if d.linearity is not None:
        head += [
            "Flown noise-free on the truth plant with the PRBS phases of seeds "
            f"{', '.join(map(str, d.linearity.seeds))}, the worst (the rule: fit >= 99 % on "
            "excited channels, second-order residual < 0.2 of the noise on fitted channels):"
        ]
        head += ["  " + line for line in d.linearity.table().splitlines()]
    head += [
        "Predicted Cramér-Rao bounds (sensor noise of the scenario's sensors), against the "
        "paper's Scenario II at the same flight time:"
    ]
    head += ["  " + line for line in table(d).splitlines()]
    return "".join(f"# {line}\n" for line in head) + "\n" + scenario_text(d.scenario)


BOUNDS_KEY = (
    "relative Cramér-Rao bound (%) of each free coefficient, in the order of the table: "
    "bold blue, the design; grey, Scenario II at the same flight time"
)
MOVED = 1e-9  # a flight's channel spanning less than this (rad, m/s, m) is not drawn
FLIGHTS_KEY = "the designed experiment as the design model flies it (the linear model with its autopilots)"


def log_design(path: str | Path, d: Design, force: bool = False) -> Path:
    """A Rerun recording of a design: the `bounds` tab (per free coefficient the predicted
    relative Cramér-Rao bound of the design beside Scenario II's at the same flight time, as
    paired bars, with the table), then per designed experiment its fin angles and states as
    the design model flies it. An existing file at `path` is an `InputError` unless `force`."""
    title = "testbed design"
    rel = {"design": d.relative(d.crlb), "scenario_II": d.relative(d.crlb_base)}
    k = np.arange(len(d.free), dtype=float)
    tabs = []
    with recording(path, title, data_id(title, text(d)), force) as rec:
        for (label, r), offset, role in zip(rel.items(), (-0.2, 0.2), ("estimate", "measured")):
            bars = rr.BarChart(
                np.nan_to_num(100 * r), color=STYLE[role][0], abscissa=k + offset, widths=np.full(len(k), 0.4)
            )
            rec.log(f"/bounds/{label}", bars, static=True)
        table = "\n".join(
            [f"| # | {' | '.join(DESIGN_COLUMNS)} |", "|---" * (len(DESIGN_COLUMNS) + 1) + "|"]
            + [f"| {i} | {' | '.join(row)} |" for i, row in enumerate(rows(d))]
            + ["", summary(d)]
        )
        rec.log("/bounds/table", rr.TextDocument(table, media_type=rr.MediaType.MARKDOWN), static=True)
        rec.log("/key/bounds", rr.TextDocument(BOUNDS_KEY, media_type=rr.MediaType.MARKDOWN), static=True)
        tabs.append(
            rrb.Horizontal(
                rrb.Vertical(
                    rrb.BarChartView(
                        origin="/bounds", contents=[f"/bounds/{n}" for n in rel], name="relative bounds (%)"
                    ),
                    rrb.TextDocumentView(origin="/key/bounds", name="key", titlebar=False),
                    row_shares=[12, 1],
                ),
                rrb.TextDocumentView(origin="/bounds/table", name="table"),
                column_shares=[3, 2],
                name="bounds",
            )
        )
        rec.log("/key/flights", rr.TextDocument(FLIGHTS_KEY, media_type=rr.MediaType.MARKDOWN), static=True)
        for e in d.flights:
            name, t = e.name, e.t
            columns = {
                **{c: e.inputs[:, j] for j, c in enumerate(INPUTS)},
                **{c: e.column(c) for c in STATES},
            }
            panels = []
            for c, v in columns.items():
                if np.ptp(v) < MOVED:
                    continue  # a channel this experiment does not move (its roundoff is not drawn)
                series(rec, f"/flights/{name}/{c}", time_column(t), v, ("model",), (c,))
                panels.append(
                    rrb.TimeSeriesView(
                        origin=f"/flights/{name}/{c}",
                        name=panel_title(c),
                        axis_x=x_range("time", t[0], t[-1]),
                        axis_y=rrb.ScalarAxis(range=axis_range(v)),
                        plot_legend=rrb.PlotLegend(visible=False),
                    )
                )
            key = rrb.TextDocumentView(origin="/key/flights", name="key", titlebar=False)
            tabs.append(rrb.Vertical(rrb.Grid(*panels, grid_columns=4), key, row_shares=[24, 1], name=name))
        rec.send_blueprint(
            rrb.Blueprint(
                rrb.Tabs(*tabs, active_tab=0), rrb.TimePanel(state="collapsed"), collapse_panels=True
            )
        )
    return Path(path)


def design_estimates(path: str | Path) -> tuple[dict[str, float], dict[str, float] | None]:
    """The coefficients and the noise of an estimates JSON (`data.read_estimates`), the noise
    completed with the sensors' defaults (`measurements.NOISE_STD`) for the states it lacks."""
    values, noise = data_read_estimates(path)
    return values, None if noise is None else {**NOISE_STD, **noise}


def write_design(
    out: str | Path,
    duration: float = 180.0,
    criterion_: str = "A",
    free: Sequence[str] | None = None,
    mjcf=None,
    speed: float | None = None,
    start_from: str | Path | None = None,
    rrd: str | Path | None = None,
    force: bool = False,
) -> Design:
    """`design` at the analytic model of `mjcf`, or at the estimates JSON `start_from` (its
    coefficients and noise: the sequential design), written as a scenario file to `out`, and
    with `rrd` logged to that Rerun recording (`log_design`). Existing files at `out` and `rrd`
    are refused before the work (`InputError`) unless `force` (then replaced)."""
    check_outputs([start_from] if start_from else [], {"out": out, "rrd": rrd}, force)
    estimates, noise = design_estimates(start_from) if start_from else (None, None)
    result = design(
        duration,
        criterion_,
        free,
        mjcf,
        speed,
        estimates,
        noise,
        estimates_source=str(start_from or "estimates"),
    )
    atomic_write_text(out, text(result), force)
    if rrd is not None:
        log_design(rrd, result, force)
    return result
