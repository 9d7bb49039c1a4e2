"""The captive tests' figures as PNGs (matplotlib, Agg: no display needed), one per test
(`testbed captive --figures DIR`): a grid of panels, a row per speed and a column per wrench row
the test excites, each with the plant's wrench as points, the fitted model's as a line and the
fit % in its title (`captive_sweeps`). A one-variable sweep and an oscillation are drawn in the
recordings' colours (the plant blue, the model red); a grid's slices each in a colour of their
own, named in the legend. An oscillation's panels also give each row's in-phase and quadrature
parts, the plant's and the model's.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import matplotlib

matplotlib.use("Agg")  # headless: figures are files
import matplotlib.pyplot as plt  # noqa: E402

from testbed.models.regressors import ROWS  # noqa: E402
from testbed.presentation.captive_sweeps import SWEEP_UNITS, SweepPanel, series_colours  # noqa: E402

__all__ = ["DPI", "figure_name", "sweep_figure"]

DPI = 100


def figure_name(test: str) -> str:
    """The PNG of a test."""
    return f"{test}.png"


def _rgb(colour) -> tuple[float, float, float]:
    return tuple(c / 255 for c in colour)


def _title(p: SweepPanel) -> str:
    lines = [f"{p.row} ({SWEEP_UNITS[p.row]}) at {p.speed:g} m/s: fit {p.fit:.2f} %"]
    lines += [f"{n}: plant {a:.4g}, model {b:.4g}" for n, (a, b) in p.parts.items()]
    return "\n".join(lines)


def sweep_figure(path: Path, panels: Sequence[SweepPanel]) -> Path:
    """Draw the panels of one test (every speed and row of it) to the PNG `path`."""
    test = panels[0].test
    speeds = list(dict.fromkeys(p.speed for p in panels))
    rows = [r for r in ROWS if any(p.row == r for p in panels)]
    at = {(p.speed, p.row): p for p in panels}
    # fixed margins in inches (a layout engine would take most of the drawing time)
    title = 0.14 * (1 + max(len(p.parts) for p in panels))  # each panel's title lines
    width, height, gap, side = 2.9, 2.0, 0.75, 0.75  # a panel, the space between, the left margin
    legend = 1.8 if len(panels[0].plant) > 1 else 1.0
    top, bottom = 0.45 + title, 0.5
    W = side + len(rows) * width + (len(rows) - 1) * gap + legend
    H = top + len(speeds) * height + (len(speeds) - 1) * (title + 0.35) + bottom
    fig, axes = plt.subplots(len(speeds), len(rows), figsize=(W, H), squeeze=False, sharex=True)
    axes[0, 0].xaxis.set_major_locator(matplotlib.ticker.MaxNLocator(5))
    fig.subplots_adjust(
        left=side / W,
        right=1 - legend / W,
        bottom=bottom / H,
        top=1 - top / H,
        wspace=gap / width,
        hspace=(title + 0.35) / height,
    )
    colours = [(_rgb(a), _rgb(b)) for a, b in series_colours(len(panels[0].plant))]
    for i, speed in enumerate(speeds):
        for j, row in enumerate(rows):
            ax = axes[i, j]
            p = at.get((speed, row))
            if p is None:
                ax.axis("off")  # this row does not vary at this speed
                continue
            for plant, model, (dots, line) in zip(p.plant, p.model, colours):
                ax.plot(model.x, model.y, color=line, lw=1.3)
                ax.plot(plant.x, plant.y, "o", color=dots, ms=3.2)
            ax.set_title(_title(p), fontsize=8, loc="left", y=1.0, pad=3)  # placed, not fitted: faster
            ax.tick_params(labelsize=7)
            ax.yaxis.set_major_locator(matplotlib.ticker.MaxNLocator(5))  # few ticks: each costs time
            ax.grid(alpha=0.3)
            if i == len(speeds) - 1:
                ax.set_xlabel(f"{p.x} ({SWEEP_UNITS[p.x]})", fontsize=8)
    first = panels[0]
    if len(first.plant) > 1:
        handles = [
            matplotlib.lines.Line2D([], [], color=c, marker="o", ms=3.2, lw=1.3, label=s.label)
            for s, (c, _) in zip(first.plant, colours)
        ]
        key = "points: the plant's wrench, lines: the fitted model's, one colour per slice"
    else:
        handles = [
            matplotlib.lines.Line2D([], [], color=colours[0][0], marker="o", ms=3.2, lw=0, label="plant"),
            matplotlib.lines.Line2D([], [], color=colours[0][1], lw=1.3, label="model"),
        ]
        key = "points: the plant's wrench, line: the fitted model's"
    fig.legend(
        handles=handles,
        loc="center left",
        bbox_to_anchor=(1 - (legend - 0.15) / W, 0.5),
        fontsize=7,
        frameon=False,
    )
    what = "oscillation" if first.x == "t" else "sweep"
    fig.suptitle(f"Captive {what} {test}: {key}", fontsize=10)
    fig.savefig(path, format="png", dpi=DPI)
    plt.close(fig)
    return path
