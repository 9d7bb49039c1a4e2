"""Results as HTML tables, for a notebook's display (`_repr_html_`): every cell escaped."""

from __future__ import annotations

import html
from typing import Iterable, Sequence

__all__ = ["html_table"]


def html_table(head: Sequence[str], rows: Iterable[Sequence], caption: str = "") -> str:
    """A `<table>` with the column names `head`, one `<tr>` per row of `rows` (each cell `str`ed),
    and `caption` above it; numbers right-aligned."""
    parts = ["<table>"]
    if caption:
        parts.append(f"<caption>{html.escape(caption)}</caption>")
    parts.append("<thead><tr>" + "".join(f"<th>{html.escape(str(h))}</th>" for h in head) + "</tr></thead>")
    parts.append("<tbody>")
    for row in rows:
        cells = []
        for v in row:
            align = ' style="text-align:right"' if isinstance(v, (int, float)) or _numeric(v) else ""
            cells.append(f"<td{align}>{html.escape(str(v))}</td>")
        parts.append("<tr>" + "".join(cells) + "</tr>")
    parts.append("</tbody></table>")
    return "".join(parts)


def _numeric(v) -> bool:
    try:
        float(str(v).rstrip("%"))
    except ValueError:
        return False
    return True
