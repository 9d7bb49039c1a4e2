"""The campaign's report: PNG figures (matplotlib, Agg: no display needed), report.html beside
them, and report.rrd (the same results in Rerun).

Figures: `success-spread.png` (the probability of ending inside the data's optimum's likelihood region against the start
spread, per data set and arm, with Wilson intervals); named after the paper's,
`fig3-inputs-I.png` and `fig5-inputs-II.png` (the fin angles of the first seed's experiments),
`fig4-coefficients-I.png` and `fig6-coefficients-II.png` (each free coefficient's estimate over
the analytic value on the plant's data, per arm: the median over the seeds and the range);
`iterations-<scenario>.png` (the estimates of the first seed through the fit of the paper's
three methods).
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

from testbed.outputs import atomic_file, atomic_write_text
from testbed.models.linear import INPUTS
from testbed.simulation.recording import data_id, recording

RATIO_LIMITS = (0.0, 2.0)  # estimate / analytic shown; values beyond are drawn at the edge
HISTORY_ARMS = ("ml-nr", "ml-nm-paper", "mekf-paper")  # the paper's three methods, as it ran them
FIGURE_NUMBERS = {"I": 3, "II": 5}  # the paper's figures of each scenario's inputs (its coefficients: +1)
LISTED = 40  # cells that did not converge or failed, listed by name; the rest counted


TRUTH_NAMES = {"plant": "plant", "linear": "linear model"}


def _arm_colours(arms) -> dict[str, str]:
    """One colour per arm, in the order given (matplotlib's tab10, tab20 for more than ten)."""
    cmap = plt.get_cmap("tab10" if len(arms) <= 10 else "tab20")
    return {a: matplotlib.colors.to_hex(cmap(i % cmap.N)) for i, a in enumerate(arms)}


def _save(fig, path: Path) -> str:
    with atomic_file(path, force=True) as tmp:  # the campaign's own folder: its figures are redrawn
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


def coefficient_figure(out: Path, scenario: str, rows: list[dict], number: int, arms, palette) -> str:
    """Estimate / analytic per free coefficient and arm on the plant's data of `scenario` at its
    first spread: median over the seeds (marker; hollow where some seed's fit did not converge)
    and the range (bar)."""
    rows = [r for r in rows if r["scenario"] == scenario and r["truth"] == "plant" and r["coefficient"]]
    spread = min((r["spread"] for r in rows), default=0.0)
    rows = [r for r in rows if r["spread"] == spread]
    arms = [a for a in arms if any(r["arm"] == a for r in rows)]
    names = list(dict.fromkeys(r["coefficient"] for r in rows))
    fig, ax = plt.subplots(figsize=(8, 0.36 * max(len(names), 4) + 1.6), constrained_layout=True)
    lo, hi = RATIO_LIMITS
    for k, m in enumerate(arms):
        offset = (k - (len(arms) - 1) / 2) * min(0.8 / max(len(arms), 1), 0.18)
        for i, n in enumerate(names):
            rs = [r for r in rows if r["arm"] == m and r["coefficient"] == n]
            ratio = np.array([r["estimate"] / r["analytic"] if r["analytic"] else math.nan for r in rs])
            ratio = ratio[np.isfinite(ratio)]
            if not ratio.size:
                continue
            med, a, b = np.clip([np.median(ratio), ratio.min(), ratio.max()], lo, hi)
            all_conv = all(r["converged"] for r in rs)
            ax.plot([a, b], [i + offset] * 2, color=palette[m], lw=1.5)
            ax.plot(
                med, i + offset, "o", color=palette[m], mfc=palette[m] if all_conv else "white", ms=5, label=m
            )
    handles, labels = ax.get_legend_handles_labels()
    seen = dict(zip(labels, handles))  # one entry per arm
    ax.legend(seen.values(), seen.keys(), loc="lower right", fontsize=7)
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
    ax.set_title(f"Fig. {number}: identified against analytic, Scenario {scenario} (start spread {spread:g})")
    ax.grid(axis="x", alpha=0.3)
    return _save(fig, out / f"fig{number}-coefficients-{scenario}.png")


def success_figure(out: Path, summary: list[dict], arms, palette) -> str | None:
    """The probability of ending inside the data's optimum's likelihood region against the start spread, one panel per
    data set, one line per judged arm, with the Wilson 95 % interval of each proportion."""
    judged = [r for r in summary if r["judged"]]
    sets = list(dict.fromkeys((r["scenario"], r["truth"]) for r in judged))
    if not sets:
        return None
    cols = min(len(sets), 4)
    nrows = math.ceil(len(sets) / cols)
    fig, axes = plt.subplots(
        nrows,
        cols,
        figsize=(3.6 * cols + 1.4, 3.1 * nrows + 0.6),
        squeeze=False,
        sharey=True,
        constrained_layout=True,
    )
    shown = [a for a in arms if any(r["arm"] == a for r in judged)]
    for ax, (s, t) in zip(axes.flat, sets):
        here = [r for r in judged if (r["scenario"], r["truth"]) == (s, t)]
        spreads = sorted({r["spread"] for r in here})
        width = max(spreads) or 1.0
        for k, a in enumerate(shown):
            pts = sorted((r["spread"], r) for r in here if r["arm"] == a)
            if not pts:
                continue
            dx = (k - (len(shown) - 1) / 2) * 0.02 * width  # the arms' intervals side by side
            x = np.array([p[0] for p in pts]) + dx
            p = np.array([p[1]["success"] / p[1]["judged"] for p in pts])
            # the interval's ends, rounded a hair inside the point at 0 or 1, clipped to it
            lo = np.clip(p - np.array([q[1]["success_low"] for q in pts]), 0.0, None)
            hi = np.clip(np.array([q[1]["success_high"] for q in pts]) - p, 0.0, None)
            ax.errorbar(x, p, yerr=[lo, hi], marker="o", ms=4, lw=1.2, capsize=2, color=palette[a], label=a)
        ax.set_title(f"{s} on the {TRUTH_NAMES.get(t, t)}", fontsize=10)
        ax.set_xlabel("start spread s")
        ax.set_ylim(-0.05, 1.05)
        ax.set_xlim(min(spreads) - 0.15 * width, max(spreads) + 0.15 * width)
        ax.set_xticks(spreads)
        ax.grid(alpha=0.3)
    for ax in axes.flat[len(sets) :]:
        ax.axis("off")
    for ax in axes[:, 0]:
        ax.set_ylabel("P(inside the optimum's likelihood region)")
    handles, labels = axes.flat[0].get_legend_handles_labels()
    for ax in axes.flat[1 : len(sets)]:
        h, lab = ax.get_legend_handles_labels()
        handles += [x for x, y in zip(h, lab) if y not in labels]
        labels += [y for y in lab if y not in labels]
    fig.legend(handles, labels, loc="outside right upper", fontsize=8)
    fig.suptitle("Success against the start spread (bars: Wilson 95 % intervals)")
    return _save(fig, out / "success-spread.png")


def history_figure(out: Path, scenario: str, docs: list[dict]) -> str | None:
    """The first seed's estimates / analytic through the fit of the paper's three methods, on the
    plant's data of `scenario` at its first spread."""
    here = [d for d in docs if d["cell"]["scenario"] == scenario and d["cell"]["truth"] == "plant"]
    if not here:
        return None
    seed = min(d["cell"]["seed"] for d in here)
    spread = min(d["cell"]["spread"] for d in here)
    picked = {
        d["cell"]["arm"]: d
        for d in here
        if d["cell"]["seed"] == seed and d["cell"]["spread"] == spread and d.get("history")
    }
    arms = [m for m in HISTORY_ARMS if m in picked]
    if not arms:
        return None
    fig, axes = plt.subplots(
        1, len(arms), figsize=(4.8 * len(arms), 4.2), squeeze=False, constrained_layout=True
    )
    for ax, m in zip(axes[0], arms):
        d = picked[m]
        h = d["history"]
        ratio = np.array(h["ratio"], dtype=float)
        ax.plot(h["x"], np.clip(ratio, *RATIO_LIMITS), lw=0.9)
        ax.axhline(1.0, color="k", lw=0.8)
        ax.set_ylim(RATIO_LIMITS[0] - 0.05, RATIO_LIMITS[1] + 0.05)
        ax.set_xlabel(h["x_name"])
        ax.set_title(f"{m}: {d['status']}, {d['iterations']} iterations", fontsize=10)
        ax.grid(alpha=0.3)
    axes[0, 0].set_ylabel("estimate / analytic (one line per coefficient)")
    fig.suptitle(f"Iteration histories, Scenario {scenario} (seed {seed}, start spread {spread:g})")
    return _save(fig, out / f"iterations-{scenario}.png")


def write_report(
    out: Path,
    docs: list[dict],
    rows: list[dict],
    verdicts: dict,
    inputs: dict,
    summary: list[dict],
    regime: dict,
    drift: dict,
    arms,
    captive=None,
) -> Path:
    """The figures, report.html and report.rrd in `out`: `summary` per data set, spread and arm,
    `regime` and `drift` per data set, `arms` in the order the figures show them, `captive` per
    spread and coefficient of the nonlinear cells (`results.captive_table`)."""
    arms = [a for a in arms if any(d["cell"]["arm"] == a for d in docs)]
    palette = _arm_colours(arms)
    figures, missing = [], []
    name = success_figure(out, summary, arms, palette)
    if name:
        figures.append(
            ("Probability of ending inside the optimum's likelihood region against the start spread", name)
        )
    # the paper's order: each scenario's inputs, then its coefficients
    for s, number in FIGURE_NUMBERS.items():
        if s not in inputs:
            continue
        if inputs[s]:
            figures.append(
                (f"Fig. {number}: input histories, Scenario {s}", input_figure(out, s, inputs[s], number))
            )
        else:
            missing.append(f"Fig. {number} (inputs of Scenario {s}): its run could not be loaded")
        figures.append(
            (
                f"Fig. {number + 1}: identified against analytic, Scenario {s}",
                coefficient_figure(out, s, rows, number + 1, arms, palette),
            )
        )
    for s in FIGURE_NUMBERS:
        name = history_figure(out, s, docs)
        if name:
            figures.append((f"Iteration histories, Scenario {s}", name))
    atomic_write_text(
        out / "report.html",
        report_html(verdicts, summary, regime, drift, figures, missing, docs, captive),
        force=True,
    )
    write_rrd(out / "report.rrd", docs)
    return out / "report.html"


PAPER = {
    "1": "Linear equations of motion of a submerged body cannot have global identifiability and have a "
    "higher probability of simultaneous drift, due to the inertia matrix, than general state equations.",
    "2-nr": "The results of ML in combination with Newton-Raphson and steepest descent are unsatisfactory.",
    "2-nm": "ML with the Nelder-Mead simplex gives acceptable results.",
    "3": "ML with the Nelder-Mead simplex gives satisfactory results if the inputs are designed as "
    "pseudo-random binary sequences: Scenario II's data are better than Scenario I's for it.",
    "mekf": "The modified extended Kalman filter gives acceptable results, similar in both scenarios.",
}
VERDICT_CLASS = {True: "holds", False: "refuted", None: "undecided"}


def _pct(v: float) -> str:
    return f"{100 * v:.1f} %" if np.isfinite(v) else "–"


def _lowest(fits: dict, excited: dict) -> float | None:
    """The lowest fit % over the excited channels of every experiment (None if there is none)."""
    v = [fits[x][c] for x in excited for c in excited[x] if fits[x].get(c) is not None]
    return min(v) if v else None


def _fit(v) -> str:
    return f"{v:.2f} %" if v is not None and np.isfinite(v) else "–"


def report_html(
    verdicts: dict, summary: list[dict], regime: dict, drift: dict, figures, missing, docs, captive=None
) -> str:
    e = html.escape
    seeds = sorted({d["cell"]["seed"] for d in docs})
    spreads = sorted({d["cell"]["spread"] for d in docs})
    parts = [
        "<!doctype html><html lang='en'><head><meta charset='utf-8'><title>testbed reproduce: Kim &amp; Rhee</title>",
        "<style>body{font-family:sans-serif;max-width:1200px;margin:2em auto;padding:0 1em;color:#222}"
        "table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #ccc;padding:4px 8px;text-align:left}"
        "th{background:#f3f3f3}.holds{color:#1a7f37;font-weight:bold}.refuted{color:#b3261e;font-weight:bold}"
        ".undecided{color:#8a6d00;font-weight:bold}"
        "img{max-width:100%;border:1px solid #ddd;margin:0.5em 0}figure{margin:1.5em 0}</style></head><body>",
        "<h1>Kim &amp; Rhee reproduced</h1>",
        f"<p>{len(docs)} cells: data sets × seeds {e(', '.join(map(str, seeds)))} × start spreads "
        f"{e(', '.join(f'{s:g}' for s in spreads))} × arms. Every arm of a data set, seed and spread "
        "starts from the same a-priori model (log-normal errors per coefficient class, the screen run "
        "at it) and is judged against the data's best-likelihood optimum, the best of a multi-start "
        "search and every arm's end point: a success ends inside its likelihood region (ΔJ ≤ χ²₀.₉₅(p)/2). Files: <a href='results.csv'>results.csv</a>, <a href='summary.csv'>summary.csv</a>, "
        "<a href='conclusions.json'>conclusions.json</a>, <a href='regime.json'>regime.json</a>, "
        "<a href='drift.json'>drift.json</a>, <a href='report.rrd'>report.rrd</a> "
        "(open with <code>rerun report.rrd</code>).</p>",
        "<h2>The paper's conclusions</h2><table><tr><th>#</th><th>the paper</th><th>verdict</th>"
        "<th>rule</th><th>evidence</th></tr>",
    ]
    for k, v in verdicts.items():
        cls, word = VERDICT_CLASS[v["holds"]], v["verdict"]
        parts.append(
            f"<tr><td>{e(k)}</td><td>{e(PAPER.get(k, ''))}</td><td class='{cls}'>{word}</td>"
            f"<td>{e(v.get('rule', ''))}</td><td>{e(v['evidence'])}</td></tr>"
        )
    parts.append(
        "</table><h2>Where the linear reference holds</h2><p>The analytic linear model simulated open "
        "loop with each data set's recorded fin angles from its first noise-free truth sample: its fit "
        "% against the noise-free truth on every excited channel (the truth moving at least twice the "
        "sensor σ) and the lowest of them (the median over the seeds' runs; the channel and the rest "
        "from the first seed's), the lowest against the measured data, the speed loss and the peak "
        "pitch and pitch rate. Where the lowest fit to the truth is below 99 % the linear reference does not "
        "hold.</p><table>"
        "<tr><th>data set</th><th>lowest fit to the truth</th><th>fit to the truth per excited channel</th>"
        "<th>lowest fit to the data</th>"
        "<th>speed loss</th><th>peak pitch</th><th>peak pitch rate</th></tr>"
    )
    for key, r in regime.items():
        fits = "; ".join(
            f"{x}: "
            + ", ".join(
                f"{c} {r['truth'][x][c]:.1f}" for c in r["excited"][x] if r["truth"][x][c] is not None
            )
            for x in r["excited"]
        )
        lowest = r["lowest"]
        parts.append(
            f"<tr><td>{e(key)}</td><td>{_fit(r['lowest_fit_to_truth'])} ({e(str(lowest['channel']))}, "
            f"{e(str(lowest['experiment']))})</td><td>{e(fits)}</td><td>{_fit(_lowest(r['data'], r['excited']))}</td>"
            f"<td>{max(r['speed_loss'].values()):.2f} %</td><td>{max(r['peak_pitch'].values()):.1f}°</td>"
            f"<td>{max(r['peak_pitch_rate'].values()):.1f} °/s</td></tr>"
        )
    parts.append("</table>")
    if drift:
        parts.append(
            "<h2>Drift in practice</h2><table><tr><th>data set</th><th>cond. Mt-form</th>"
            "<th>cond. A-form</th><th>largest correlation, Mt-form</th><th>shared scatter Mt-form</th>"
            "<th>shared scatter A-form</th><th>null scatter Mt-form</th><th>null scatter A-form</th>"
            "<th>relative drift Mt-form</th><th>converged Mt / A</th><th>seeds</th></tr>"
        )
        for key, d in drift.items():
            a, b, rho = d["correlation_mt"]
            parts.append(
                f"<tr><td>{e(key)}</td><td>{d['condition_mt']:.3g}</td><td>{d['condition_a']:.3g}</td>"
                f"<td>{e(a)}–{e(b)} {rho:+.3f}</td><td>{d['shared_scatter_mt']:.3g}</td>"
                f"<td>{d['shared_scatter_a']:.3g}</td><td>{d['null_scatter_mt']:.3g}</td>"
                f"<td>{d['null_scatter_a']:.3g}</td><td>{_pct(d['relative_drift_mt'])}</td>"
                f"<td>{d.get('converged_mt', '–')} / {d.get('converged_a', '–')}</td><td>{d['seeds']}</td></tr>"
            )
        parts.append("</table>")
    parts.append(
        "<h2>Arms</h2><table><tr><th>data set</th><th>spread</th><th>arm</th><th>cells</th><th>success</th>"
        "<th>95 % interval</th><th>diverged</th><th>stalled</th><th>elsewhere</th><th>failed</th>"
        "<th>below the optimum search</th><th>accurate</th><th>median relative error</th>"
        "<th>median evaluations</th><th>median wall time (s)</th></tr>"
    )
    for r in summary:
        share = f"{r['success']}/{r['judged']}" if r["judged"] else "–"
        ci = f"{100 * r['success_low']:.0f}–{100 * r['success_high']:.0f} %" if r["judged"] else "–"
        parts.append(
            f"<tr><td>{e(r['scenario'])}/{e(r['truth'])}</td><td>{r['spread']:g}</td><td>{e(r['arm'])}</td>"
            f"<td>{r['cells']}</td><td>{share}</td><td>{ci}</td><td>{r['diverged']}</td><td>{r['stalled']}</td>"
            f"<td>{r['elsewhere']}</td><td>{r['failed']}</td><td>{r['beat_search'] if r['judged'] else '–'}</td>"
            f"<td>{r['accurate']}</td>"
            f"<td>{_pct(r['median_relative_error'])}</td><td>{r['median_evaluations']:.0f}</td>"
            f"<td>{r['median_wall_time_s']:.1f}</td></tr>"
        )
    parts.append("</table>")
    parts += captive_html(captive)
    failures = [d for d in docs if d["status"] != "converged"]
    if failures:
        parts.append(f"<h2>Cells that did not converge ({len(failures)})</h2><ul>")
        for d in failures[:LISTED]:
            c = d["cell"]
            parts.append(
                f"<li>{e(c['scenario'])}/{e(c['truth'])}, spread {c['spread']:g}, {e(c['arm'])}, seed {c['seed']}: "
                f"{e(d['status'])}{': ' + e(d['reason']) if d.get('reason') else ''}</li>"
            )
        if len(failures) > LISTED:
            parts.append(f"<li>… and {len(failures) - LISTED} more (results.csv, column reason)</li>")
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


def captive_html(captive: dict | None) -> list[str]:
    """The section "Scenario I against the captive reference" of the nonlinear cells (`captive`,
    `results.captive_table`): per arm, spread and coefficient, then per cell its fit and open-loop
    fit % per channel; nothing without nonlinear cells."""
    if not captive or not captive["cells"]:
        return []
    e = html.escape
    parts = [
        "<h2>Scenario I against the captive reference</h2><p>Each arm's method fitting the nonlinear "
        "model (the captive reference of the plant's body: <code>testbed captive</code>) with its terms "
        "that have a slope at trim free, from the captive values perturbed as the linear arms' "
        "a-priori model is (one start per seed and spread for every arm); each estimate against the "
        "captive value, in the data's Cramér-Rao σ (ml-gn-nonlinear's, corrected for coloured "
        "residuals) and in %. Within: the cells whose estimate is within max(3 σ, 10 %) of the "
        "captive value.</p><table><tr><th>arm</th><th>spread</th><th>coefficient</th>"
        "<th>captive</th><th>median estimate</th><th>median error (σ)</th><th>median error</th>"
        "<th>within</th></tr>"
    ]
    for r in captive["coefficients"]:
        parts.append(
            f"<tr><td>{e(r['arm'])}</td><td>{r['spread']:g}</td><td>{e(r['coefficient'])}</td><td>{r['captive']:.4g}</td>"
            f"<td>{r['median_estimate']:.4g}</td><td>{r['median_error_sigmas']:+.2f}</td>"
            f"<td>{r['median_error_percent']:+.2f} %</td><td>{r['within']}/{r['cells']}</td></tr>"
        )
    parts.append(
        "</table><table><tr><th>arm</th><th>seed</th><th>spread</th><th>status</th><th>iterations</th>"
        "<th>wall time (s)</th><th>open-loop fit per channel</th></tr>"
    )
    for d in captive["cells"]:
        fits = "; ".join(
            f"{x}: " + ", ".join(f"{ch} {_fit(v)}" for ch, v in ch_fits.items())
            for x, ch_fits in d["fit"].items()
        )
        parts.append(
            f"<tr><td>{e(d['arm'])}</td><td>{d['seed']}</td><td>{d['spread']:g}</td><td>{e(d['status'])}</td>"
            f"<td>{d['iterations']}</td><td>{d['wall_time_s']:.1f}</td><td>{e(fits or d['fit_note']) or '–'}</td></tr>"
        )
    parts.append("</table>")
    return parts


def write_rrd(path: Path, docs: list[dict]) -> Path:
    """report.rrd: per data set, spread, coefficient and arm the estimate / analytic (the
    nonlinear cells': / captive) over the seeds (timeline `seed`), and the first seed's histories
    (timelines `iteration` and `time`)."""
    title = "testbed reproduce"
    keys = sorted(d["key"] for d in docs)
    with recording(path, title, data_id(title, *keys), force=True) as rec:
        series: dict[str, list] = {}
        for d in docs:
            c = d["cell"]
            where = f"{c['scenario']}/{c['truth']}/s{c['spread']:g}"
            reference = d.get("captive") or d.get("analytic", {})
            for n, v in d.get("values", {}).items():
                a = reference[n]
                if a:
                    series.setdefault(f"coefficients/{where}/{n}/{c['arm']}", []).append((c["seed"], v / a))
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
                    f"histories/{c['scenario']}/{c['truth']}/s{c['spread']:g}/{c['arm']}/{n}",
                    indexes=[timeline],
                    columns=rr.Scalars.columns(scalars=ratio[:, j]),
                )
    return path
