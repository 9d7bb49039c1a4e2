"""The campaign's report: PNG figures (matplotlib, Agg: no display needed), report.html beside
them, and report.rrd (the same results in Rerun).

Figures, named after the paper's: `fig3-inputs-I.png` and `fig5-inputs-II.png` (the fin angles
of the first seed's experiments), `fig4-coefficients-I.png` and `fig6-coefficients-II.png` (each
free coefficient's estimate over the analytic value, per method: the median over the seeds and
the range), `iterations-<scenario>.png` (the estimates of the first seed through the fit of
ml-nr, ml-nm and the MEKF).
"""

from __future__ import annotations

import html
import math
from pathlib import Path

import matplotlib
import numpy as np
import rerun as rr

__all__ = ["write_report"]

matplotlib.use("Agg")  # headless: figures are files
import matplotlib.pyplot as plt  # noqa: E402

from testbed.errors import atomic_file, atomic_write_text
from testbed.models.linear import INPUTS
from testbed.simulation.recording import data_id, recording

COLORS = {"ml-nr": "#d62728", "ml-nm": "#1f77b4", "mekf": "#2ca02c", "ml-gn": "#7f7f7f"}
RATIO_LIMITS = (0.0, 2.0)  # estimate / analytic shown; values beyond are drawn at the edge
HISTORY_METHODS = ("ml-nr", "ml-nm", "mekf")


def _save(fig, path: Path) -> str:
    with atomic_file(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110)
    plt.close(fig)
    return path.name


def input_figure(out: Path, scenario: str, experiments, number: int) -> str:
    """The fin angles (deg) of each experiment: the paper's Fig. 3 (Scenario I) or 5 (II)."""
    labels = {"delta_r": "rudder δr", "delta_er": "right elevator δer", "delta_el": "left elevator δel"}
    fig, axes = plt.subplots(
        3,
        len(experiments),
        figsize=(4.2 * len(experiments) + 1, 6.5),
        squeeze=False,
        sharex="col",
        constrained_layout=True,
    )
    for j, e in enumerate(experiments):
        for i, name in enumerate(INPUTS):
            ax = axes[i, j]
            ax.plot(e.t, np.degrees(e.inputs[:, i]), lw=0.8, color="#1f77b4")
            ax.set_ylabel(f"{labels[name]} (deg)" if j == 0 else "")
            ax.grid(alpha=0.3)
        axes[0, j].set_title(e.name)
        axes[-1, j].set_xlabel("time (s)")
    fig.suptitle(f"Fig. {number}: input histories, Scenario {scenario} (seed 1)")
    return _save(fig, out / f"fig{number}-inputs-{scenario}.png")


def coefficient_figure(out: Path, scenario: str, rows: list[dict], number: int, methods) -> str:
    """Estimate / analytic per free coefficient and method: median over the seeds (marker;
    hollow where some seed's fit did not converge) and the range (bar)."""
    rows = [r for r in rows if r["scenario"] == scenario and r["coefficient"]]
    names = list(dict.fromkeys(r["coefficient"] for r in rows))
    fig, ax = plt.subplots(figsize=(8, 0.36 * max(len(names), 4) + 1.6), constrained_layout=True)
    lo, hi = RATIO_LIMITS
    for k, m in enumerate(methods):
        offset = (k - (len(methods) - 1) / 2) * 0.18
        for i, n in enumerate(names):
            rs = [r for r in rows if r["method"] == m and r["coefficient"] == n]
            if not rs:
                continue
            ratio = np.array([r["estimate"] / r["analytic"] if r["analytic"] else math.nan for r in rs])
            ratio = ratio[np.isfinite(ratio)]
            if not ratio.size:
                continue
            med, a, b = np.clip([np.median(ratio), ratio.min(), ratio.max()], lo, hi)
            all_conv = all(r["converged"] for r in rs)
            ax.plot([a, b], [i + offset] * 2, color=COLORS[m], lw=1.5)
            ax.plot(
                med, i + offset, "o", color=COLORS[m], mfc=COLORS[m] if all_conv else "white", ms=5, label=m
            )
    handles, labels = ax.get_legend_handles_labels()
    seen = dict(zip(labels, handles))  # one entry per method
    ax.legend(seen.values(), seen.keys(), loc="lower right", fontsize=8)
    ax.axvline(1.0, color="k", lw=0.8)
    ax.axvspan(0.9, 1.1, color="k", alpha=0.06)
    ax.set_yticks(range(len(names)), names)
    ax.invert_yaxis()
    ax.set_xlim(lo - 0.05, hi + 0.05)
    ax.set_xlabel(
        "identified / analytic (median over seeds, bar: range; hollow: some fit not converged; "
        "clipped to [0, 2]; grey band ±10 %)",
        fontsize=8,
    )
    ax.set_title(f"Fig. {number}: identified against analytic coefficients, Scenario {scenario}")
    ax.grid(axis="x", alpha=0.3)
    return _save(fig, out / f"fig{number}-coefficients-{scenario}.png")


def history_figure(out: Path, scenario: str, docs: list[dict]) -> str | None:
    """The first seed's estimates / analytic through the fit of ml-nr, ml-nm and the MEKF."""
    picked = {
        d["cell"]["method"]: d
        for d in docs
        if d["cell"]["scenario"] == scenario
        and d["cell"]["seed"] == min(x["cell"]["seed"] for x in docs)
        and d.get("history")
    }
    methods = [m for m in HISTORY_METHODS if m in picked]
    if not methods:
        return None
    fig, axes = plt.subplots(
        1, len(methods), figsize=(4.8 * len(methods), 4.2), squeeze=False, constrained_layout=True
    )
    for ax, m in zip(axes[0], methods):
        d = picked[m]
        h = d["history"]
        ratio = np.array(h["ratio"], dtype=float)
        ax.plot(h["x"], np.clip(ratio, *RATIO_LIMITS), lw=0.9)
        ax.axhline(1.0, color="k", lw=0.8)
        ax.set_ylim(RATIO_LIMITS[0] - 0.05, RATIO_LIMITS[1] + 0.05)
        ax.set_xlabel(h["x_name"])
        ax.set_title(
            f"{m}: {d['status']}, {d['iterations']} iterations" if m != "mekf" else f"{m}: {d['status']}",
            fontsize=10,
        )
        ax.grid(alpha=0.3)
    axes[0, 0].set_ylabel("estimate / analytic (one line per coefficient)")
    fig.suptitle(f"Iteration histories, Scenario {scenario} (seed {min(x['cell']['seed'] for x in docs)})")
    return _save(fig, out / f"iterations-{scenario}.png")


def write_report(
    out: Path,
    docs: list[dict],
    rows: list[dict],
    verdicts: dict,
    inputs: dict,
    summary: list[dict],
    methods,
    scenarios,
) -> Path:
    """The figures, report.html and report.rrd in `out`: `summary` per scenario and method,
    `methods` and `scenarios` in the order the figures show them."""
    methods = [m for m in methods if any(d["cell"]["method"] == m for d in docs)]
    scenarios = [s for s in scenarios if any(d["cell"]["scenario"] == s for d in docs)]
    figures, missing = [], []
    for s in scenarios:  # the paper's order: each scenario's inputs, then its coefficients
        number = {"I": 3, "II": 5}[s]
        if inputs.get(s):
            figures.append(
                (f"Fig. {number}: input histories, Scenario {s}", input_figure(out, s, inputs[s], number))
            )
        else:
            missing.append(f"Fig. {number} (inputs of Scenario {s}): its run could not be loaded")
        figures.append(
            (
                f"Fig. {number + 1}: identified against analytic, Scenario {s}",
                coefficient_figure(out, s, rows, number + 1, methods),
            )
        )
    for s in scenarios:
        name = history_figure(out, s, docs)
        if name:
            figures.append((f"Iteration histories, Scenario {s}", name))
        else:
            missing.append(f"iteration histories of Scenario {s}: no cell has a history")
    atomic_write_text(out / "report.html", report_html(verdicts, summary, figures, missing, docs))
    write_rrd(out / "report.rrd", docs)
    return out / "report.html"


PAPER = {
    "1": "Linear equations of motion of a submerged body cannot have global identifiability and have a "
    "higher probability of simultaneous drift, due to the inertia matrix, than general state equations.",
    "2": "ML with the Nelder-Mead simplex gives acceptable results; ML with Newton-Raphson and steepest "
    "descent is unsatisfactory.",
    "3": "ML with the Nelder-Mead simplex gives satisfactory results when the inputs are designed as "
    "pseudo-random binary sequences.",
}


def report_html(verdicts: dict, summary: list[dict], figures, missing, docs) -> str:
    e = html.escape
    seeds = sorted({d["cell"]["seed"] for d in docs})
    parts = [
        "<!doctype html><html lang='en'><head><meta charset='utf-8'><title>testbed reproduce: Kim &amp; Rhee</title>",
        "<style>body{font-family:sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;color:#222}"
        "table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #ccc;padding:4px 8px;text-align:left}"
        "th{background:#f3f3f3}.holds{color:#1a7f37;font-weight:bold}.refuted{color:#b3261e;font-weight:bold}"
        "img{max-width:100%;border:1px solid #ddd;margin:0.5em 0}figure{margin:1.5em 0}</style></head><body>",
        "<h1>Kim &amp; Rhee reproduced</h1>",
        f"<p>{len(docs)} cells: Scenario I and II × {{ml-nr, ml-nm, mekf, ml-gn}} × seeds "
        f"{e(', '.join(map(str, seeds)))}. Each cell identifies the coefficients its data identify "
        "(screened free set) starting from the analytic model, and compares with it. Files: "
        "<a href='results.csv'>results.csv</a>, <a href='conclusions.json'>conclusions.json</a>, "
        "<a href='report.rrd'>report.rrd</a> (open with <code>rerun report.rrd</code>).</p>",
        "<h2>The paper's conclusions</h2><table><tr><th>#</th><th>conclusion</th><th>verdict</th><th>evidence</th></tr>",
    ]
    for k in ("1", "2", "3"):
        v = verdicts[k]
        cls, word = ("holds", "holds") if v["holds"] else ("refuted", "refuted")
        parts.append(
            f"<tr><td>{k}</td><td>{e(PAPER[k])}</td><td class='{cls}'>{word}</td><td>{e(v['evidence'])}</td></tr>"
        )
    parts.append(
        "</table><h2>Cells</h2><table><tr><th>scenario</th><th>method</th><th>cells</th><th>converged</th>"
        "<th>acceptable</th><th>failed</th><th>median relative error</th><th>median wall time (s)</th></tr>"
    )
    for r in summary:
        rel = f"{100 * r['median_relative_error']:.1f} %" if np.isfinite(r["median_relative_error"]) else "–"
        parts.append(
            f"<tr><td>{e(r['scenario'])}</td><td>{e(r['method'])}</td><td>{r['cells']}</td>"
            f"<td>{r['converged']}</td><td>{r['acceptable']}</td><td>{r['failed']}</td><td>{rel}</td>"
            f"<td>{r['median_wall_time_s']:.1f}</td></tr>"
        )
    parts.append("</table>")
    failures = [d for d in docs if d["status"] != "converged"]
    if failures:
        parts.append("<h2>Cells that did not converge</h2><ul>")
        for d in failures:
            c = d["cell"]
            parts.append(
                f"<li>Scenario {e(c['scenario'])}, {e(c['method'])}, seed {c['seed']}: "
                f"{e(d['status'])}{': ' + e(d['reason']) if d.get('reason') else ''}</li>"
            )
        parts.append("</ul>")
    parts.append("<h2>Figures</h2>")
    for caption, name in figures:
        parts.append(
            f"<figure><img src='{e(name)}' alt='{e(caption)}'><figcaption>{e(caption)}</figcaption></figure>"
        )
    for m in missing:
        parts.append(f"<p>Missing: {e(m)}</p>")
    parts.append("</body></html>\n")
    return "\n".join(parts)


def write_rrd(path: Path, docs: list[dict]) -> Path:
    """report.rrd: per scenario, method and coefficient the estimate / analytic over the seeds
    (timeline `seed`), and the first seed's histories (timelines `iteration` and `time`)."""
    title = "testbed reproduce"
    keys = sorted(d["key"] for d in docs)
    with recording(path, title, data_id(title, *keys)) as rec:
        series: dict[str, list] = {}
        for d in docs:
            c = d["cell"]
            for r in d["rows"]:
                if r["analytic"]:
                    series.setdefault(
                        f"coefficients/{c['scenario']}/{r['coefficient']}/{c['method']}", []
                    ).append((c["seed"], r["estimate"] / r["analytic"]))
        for entity, points in series.items():
            points.sort()
            rec.send_columns(
                entity,
                indexes=[rr.TimeColumn("seed", sequence=[p[0] for p in points])],
                columns=rr.Scalars.columns(scalars=np.array([p[1] for p in points], float)),
            )
        first = min((d["cell"]["seed"] for d in docs), default=1)
        for d in docs:
            c, h = d["cell"], d.get("history")
            if c["seed"] != first or not h:
                continue
            ratio = np.array(h["ratio"], dtype=float)
            timeline = (
                rr.TimeColumn("iteration", sequence=h["x"])
                if h["x_name"] == "iteration"
                else rr.TimeColumn("time", duration=np.asarray(h["x"], float))
            )
            for j, n in enumerate(d.get("free", [])):
                rec.send_columns(
                    f"histories/{c['scenario']}/{c['method']}/{n}",
                    indexes=[timeline],
                    columns=rr.Scalars.columns(scalars=ratio[:, j]),
                )
    return path
