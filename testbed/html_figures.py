"""Results as inline SVG figures, for a notebook's display (`_repr_html_`) beside their tables:
plain text, no plotting library, every label escaped.

- `svg_dots`: one row per name, a dot at its value with an optional ±interval bar, a shaded
  band and a reference line, titled, the axis labelled with its unit;
- `svg_heatmap`: a symmetric matrix in [−1, 1] (a correlation matrix) as coloured cells, blue
  negative, red positive, each cell's value in its tooltip.
"""

from __future__ import annotations

import html
import math
from typing import Sequence

import numpy as np

__all__ = ["svg_dots", "svg_heatmap"]

ROW = 16  # px per row
LABEL = 130  # px for the names
PLOT = 360  # px of plotting width
MARGIN = 14
DOT, BAR, BAND = "#c0392b", "#e6a19a", "#eeeeee"
FONT = "font-family='sans-serif' font-size='11'"


def _e(text) -> str:
    return html.escape(str(text), quote=True)


def _ticks(lo: float, hi: float) -> list[float]:
    """About five round values spanning [lo, hi]."""
    step = 10 ** math.floor(math.log10((hi - lo) / 4))
    step *= next(m for m in (1, 2, 5, 10) if (hi - lo) / (m * step) <= 6)
    return [k * step for k in range(math.ceil(lo / step), math.floor(hi / step) + 1)]


def svg_dots(
    names: Sequence[str],
    values: Sequence[float],
    title: str,
    xlabel: str,
    half_width: Sequence[float] | None = None,
    band: tuple[float, float] | None = None,
    reference: float | None = None,
) -> str:
    """An `<svg>`: each of `names` a row with a dot at its value (a non-finite one left out, its
    row marked "–") and, where `half_width` gives it, a bar value ± half_width; `band` shaded
    (e.g. ±2 σ), `reference` a vertical line; `title` above, `xlabel` below the axis."""
    v = np.asarray(values, float)
    w = np.zeros_like(v) if half_width is None else np.abs(np.asarray(half_width, float))
    w = np.where(np.isfinite(w), w, 0.0)
    shown = np.isfinite(v)
    extent = [
        *(v[shown] - w[shown]),
        *(v[shown] + w[shown]),
        *(band or ()),
        *(() if reference is None else (reference,)),
    ]
    lo, hi = (min(extent), max(extent)) if extent else (0.0, 1.0)
    if hi - lo <= 0:
        lo, hi = lo - 1.0, hi + 1.0
    pad = 0.05 * (hi - lo)
    lo, hi = lo - pad, hi + pad

    def x(value: float) -> float:
        return LABEL + PLOT * (value - lo) / (hi - lo)

    top, n = 22, len(names)
    height = top + ROW * n + 40
    parts = [
        f"<svg xmlns='http://www.w3.org/2000/svg' width='{LABEL + PLOT + MARGIN}' height='{height}' "
        f"role='img' {FONT}><title>{_e(title)}</title>",
        f"<text x='{LABEL + PLOT / 2}' y='14' text-anchor='middle' font-weight='bold'>{_e(title)}</text>",
    ]
    if band is not None:
        parts.append(
            f"<rect x='{x(band[0]):.1f}' y='{top}' width='{x(band[1]) - x(band[0]):.1f}' "
            f"height='{ROW * n}' fill='{BAND}'/>"
        )
    if reference is not None:
        parts.append(
            f"<line x1='{x(reference):.1f}' x2='{x(reference):.1f}' y1='{top}' y2='{top + ROW * n}' stroke='#000' stroke-width='0.7'/>"
        )
    for k, name in enumerate(names):
        y = top + ROW * k + ROW / 2
        parts.append(f"<text x='{LABEL - 6}' y='{y + 4:.1f}' text-anchor='end'>{_e(name)}</text>")
        if not shown[k]:
            parts.append(f"<text x='{LABEL + 4}' y='{y + 4:.1f}'>–</text>")
            continue
        if w[k] > 0:
            parts.append(
                f"<line x1='{x(v[k] - w[k]):.1f}' x2='{x(v[k] + w[k]):.1f}' y1='{y:.1f}' y2='{y:.1f}' "
                f"stroke='{BAR}' stroke-width='3'/>"
            )
        parts.append(
            f"<circle cx='{x(v[k]):.1f}' cy='{y:.1f}' r='3' fill='{DOT}'><title>{_e(name)}: {v[k]:.4g}</title></circle>"
        )
    axis = top + ROW * n
    parts.append(f"<line x1='{LABEL}' x2='{LABEL + PLOT}' y1='{axis}' y2='{axis}' stroke='#444'/>")
    for t in _ticks(lo, hi):
        parts.append(
            f"<line x1='{x(t):.1f}' x2='{x(t):.1f}' y1='{axis}' y2='{axis + 4}' stroke='#444'/>"
            f"<text x='{x(t):.1f}' y='{axis + 15}' text-anchor='middle'>{t:.4g}</text>"
        )
    parts.append(f"<text x='{LABEL + PLOT / 2}' y='{axis + 32}' text-anchor='middle'>{_e(xlabel)}</text>")
    return "".join(parts + ["</svg>"])


def svg_heatmap(names: Sequence[str], matrix: np.ndarray, title: str) -> str:
    """An `<svg>` of `matrix` (n × n, entries in [−1, 1]; a non-finite one grey): blue for −1,
    white for 0, red for +1, each cell's pair and value in its tooltip; `title` above."""
    n = len(names)
    M = np.asarray(matrix, float)
    cell = max(8, min(22, 360 // max(n, 1)))
    top, left = 22, LABEL
    size = cell * n
    parts = [
        f"<svg xmlns='http://www.w3.org/2000/svg' width='{left + size + MARGIN}' height='{top + size + LABEL}' "
        f"role='img' {FONT}><title>{_e(title)}</title>",
        f"<text x='{left + size / 2}' y='14' text-anchor='middle' font-weight='bold'>{_e(title)}</text>",
    ]
    for i, a in enumerate(names):
        parts.append(
            f"<text x='{left - 4}' y='{top + cell * i + cell / 2 + 4:.1f}' text-anchor='end'>{_e(a)}</text>"
        )
        bx, by = left + cell * i + cell / 2 + 4, top + size + 4
        parts.append(
            f"<text x='{bx:.1f}' y='{by}' text-anchor='end' transform='rotate(-90 {bx:.1f} {by})'>{_e(a)}</text>"
        )
        for j, b in enumerate(names):
            c = M[i, j]
            parts.append(
                f"<rect x='{left + cell * j}' y='{top + cell * i}' width='{cell}' height='{cell}' "
                f"fill='{_colour(c)}'><title>{_e(a)}, {_e(b)}: {c:.3f}</title></rect>"
            )
    return "".join(parts + ["</svg>"])


def _colour(c: float) -> str:
    """White at 0 towards red at +1 and blue at −1; grey where not finite."""
    if not np.isfinite(c):
        return "#bbbbbb"
    t = min(abs(c), 1.0)
    full = (192, 57, 43) if c > 0 else (41, 128, 185)
    r, g, b = (round(255 + (f - 255) * t) for f in full)
    return f"#{r:02x}{g:02x}{b:02x}"
