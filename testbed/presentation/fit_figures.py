"""The figures of a fit's report (`fit_report`), as PNG bytes: matplotlib, Agg (no display).

Each is titled, its axes labelled with units: measured against predicted outputs per record,
the residuals over time, their autocorrelation with its 99 % band and their spectrum, the
coefficients with their bounds, the trial parameters' distance from their a-priori values in σ,
the correlation matrix, and the cost per iteration.
"""

from __future__ import annotations

import functools
import io
import math
from typing import Sequence

import matplotlib
import numpy as np

matplotlib.use("Agg")  # headless: figures are bytes
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.ticker import LogLocator, MaxNLocator, NullLocator  # noqa: E402

from testbed.analysis.validation import LAGS, autocorrelation  # noqa: E402

__all__ = [
    "UNITS",
    "autocorrelation_figure",
    "coefficients_figure",
    "convergence_figure",
    "corrections_figure",
    "correlation_figure",
    "outputs_figure",
    "residuals_figure",
    "shifts_figure",
    "spectrum_figure",
]

UNITS = {
    "u": "m/s",
    "v": "m/s",
    "w": "m/s",
    "p": "rad/s",
    "q": "rad/s",
    "r": "rad/s",
    "phi": "rad",
    "theta": "rad",
    "psi": "rad",
    "z": "m",
}
_COLUMNS = 3  # subplots per row of a channel grid
_DPI = 80
MEASURED, MODEL, PRIOR = "#8a8a8a", "#c0392b", "#2e86c1"


_STYLE = {  # set once for every figure: per-axis settings re-create its ticks (most of the time)
    "axes.titlesize": 10,
    "axes.titley": 1.02,  # a title at a fixed height: placing it above the tick labels measures them
    "axes.labelsize": 8,
    "xtick.labelsize": 7,
    "ytick.labelsize": 7,
    "legend.fontsize": 7,
    "xtick.minor.visible": False,
    "ytick.minor.visible": False,
}


def _styled(draw):
    """`draw` run under `_STYLE` (its name kept: a worker process finds it by name)."""

    @functools.wraps(draw)
    def styled(*args, **kwargs):
        with plt.rc_context(_STYLE):
            return draw(*args, **kwargs)

    return styled


def _png(fig) -> bytes:
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=_DPI)
    plt.close(fig)
    return buffer.getvalue()


def _bottom(axes, n: int, xlabel: str) -> None:
    """`xlabel` under the lowest panel of each column of a `_grid` of `n` panels (the panels of a
    column share the x quantity; the channel and its unit are in each panel's title)."""
    for k in range(max(0, n - _COLUMNS), n):
        axes[k].set_xlabel(xlabel)


def _grid(n: int, title: str, height: float = 2.1):
    """A grid of `n` panels, `_COLUMNS` a row, each row `height` inches, with room for the titles
    and labels fixed in inches (a constrained layout measures every tick label: seconds a page)."""
    rows = max(1, math.ceil(n / _COLUMNS))
    total = height * rows + 0.8
    fig, axes = plt.subplots(rows, _COLUMNS, figsize=(12, total), squeeze=False)
    fig.subplots_adjust(
        left=0.07, right=0.99, top=1 - 0.8 / total, bottom=0.5 / total, hspace=0.6 * 2.1 / height, wspace=0.32
    )
    fig.suptitle(title)
    for ax in axes.flat[n:]:
        ax.set_visible(False)
    return fig, axes.flat


@_styled
def outputs_figure(
    name: str,
    t: np.ndarray,
    measured: Sequence[str],
    y: np.ndarray,
    model: np.ndarray,
    fits: Sequence[float | None],
    prior: np.ndarray | None = None,
) -> bytes:
    """Each channel of record `name`: measured (grey) against the model (red) and the a-priori
    model (blue, dashed) where given; the fit % in the panel's title."""
    fig, axes = _grid(len(measured), f"{name}: measured and predicted outputs")
    for j, (ax, s) in enumerate(zip(axes, measured)):
        ax.plot(t, y[:, j], ".", color=MEASURED, ms=1.5, label="measured")
        if prior is not None:  # beneath the fit's line
            ax.plot(t, prior[:, j], "--", color=PRIOR, lw=0.9, label="a-priori")
        ax.plot(t, model[:, j], color=MODEL, lw=1.1, label="fit")
        fit = fits[j]
        label = f"{s} ({UNITS.get(s, '')})"
        ax.set_title(f"{label}: fit {fit:.1f} %" if fit is not None and np.isfinite(fit) else label)
    axes[0].legend(loc="best")
    _bottom(axes, len(measured), "t (s)")
    return _png(fig)


@_styled
def residuals_figure(name: str, t: np.ndarray, measured: Sequence[str], residuals: np.ndarray) -> bytes:
    """Each channel's residual (measured − model) over time."""
    fig, axes = _grid(len(measured), f"{name}: residuals (measured − model)", height=1.8)
    for j, (ax, s) in enumerate(zip(axes, measured)):
        ax.plot(t, residuals[:, j], color=MODEL, lw=0.6)
        ax.axhline(0.0, color="black", lw=0.5)
        ax.set_title(f"{s} ({UNITS.get(s, '')})")
    _bottom(axes, len(measured), "t (s)")
    return _png(fig)


@_styled
def autocorrelation_figure(
    name: str, measured: Sequence[str], residuals: np.ndarray, bounds: Sequence[float], white: Sequence[bool]
) -> bytes:
    """Each channel's residual autocorrelation at lags 1 … `validation.LAGS` with the whiteness
    test's 99 % band (±`bounds`); a coloured channel's title says so (its Ljung-Box test)."""
    fig, axes = _grid(
        len(measured), f"{name}: residual autocorrelation, 99 % band of white noise", height=1.8
    )
    for j, (ax, s) in enumerate(zip(axes, measured)):
        e = residuals[:, j]
        r = autocorrelation(e[np.isfinite(e)], LAGS)  # the validation's test, over the samples present
        ax.vlines(np.arange(1, len(r) + 1), 0, r, color=MODEL if not white[j] else "#34495e", lw=1.2)
        ax.axhspan(-bounds[j], bounds[j], color="#d6eaf8")
        ax.axhline(0.0, color="black", lw=0.5)
        ax.set_ylim(-(top := min(1.0, max(2.5 * bounds[j], 1.1 * np.abs(r).max(initial=0.0)))), top)
        ax.set_title(f"{s}: {'white' if white[j] else 'coloured'}")
    _bottom(axes, len(measured), "lag (samples)")
    return _png(fig)


def _binned(f: np.ndarray, psd: np.ndarray, bins: int = 80) -> tuple[np.ndarray, np.ndarray]:
    """The periodogram averaged in `bins` logarithmically spaced frequency bands (the empty ones
    left out): a smoother estimate of the spectrum, and few points to draw."""
    edges = np.geomspace(f[0], f[-1] * (1 + 1e-12), bins + 1)
    which = np.minimum(np.searchsorted(edges, f, side="right") - 1, bins - 1)
    counts = np.bincount(which, minlength=bins)
    there = counts > 0
    return (np.bincount(which, weights=f, minlength=bins)[there] / counts[there],
            np.bincount(which, weights=psd, minlength=bins)[there] / counts[there])  # fmt: skip


@_styled
def spectrum_figure(name: str, dt: float, measured: Sequence[str], residuals: np.ndarray) -> bytes:
    """Each channel's residual power spectral density (periodogram, one-sided): flat for white
    noise, a hump where the model misses a mode."""
    fig, axes = _grid(len(measured), f"{name}: residual spectrum", height=1.8)
    for j, (ax, s) in enumerate(zip(axes, measured)):
        e = residuals[:, j]
        e = e[np.isfinite(e)]
        e = e - e.mean() if len(e) else e
        if len(e) > 1:
            f, psd = _binned(
                np.fft.rfftfreq(len(e), dt)[1:], (2 * dt / len(e)) * np.abs(np.fft.rfft(e))[1:] ** 2
            )
            keep = psd > 0  # a channel held exactly (no noise) has none to show
            if keep.any():
                ax.loglog(f[keep], psd[keep], color="#34495e", lw=0.8)
                ax.xaxis.set_major_locator(LogLocator(numticks=4))
                ax.yaxis.set_major_locator(LogLocator(numticks=4))
                ax.xaxis.set_minor_locator(NullLocator())
                ax.yaxis.set_minor_locator(NullLocator())
        ax.set_title(f"{s} (({UNITS.get(s, '')})²/Hz)")
    _bottom(axes, len(measured), "frequency (Hz)")
    return _png(fig)


@_styled
def shifts_figure(
    names: Sequence[str], values: np.ndarray, std: np.ndarray, coloured: np.ndarray | None, prior: np.ndarray
) -> bytes:
    """Each estimate's distance from its a-priori value in its own σ (Cramér-Rao, dots; coloured-
    residual, crosses), on a symmetric-log axis with the band within 2σ shaded: parameters of
    different units and a-priori values of 0 (a trial's offsets, biases, current, delay) on one
    axis, what the data moved away from the a-priori model beyond its bounds standing out."""
    n = len(names)
    fig, ax = plt.subplots(figsize=(8, 0.32 * n + 1.6), layout="constrained")
    k = np.arange(n)[::-1]
    shift = np.asarray(values, float) - np.asarray(prior, float)
    ax.axvspan(-2, 2, color="#eeeeee", label="within 2σ of the a-priori value")
    if coloured is not None:
        ax.plot(shift / coloured, k, "x", color="#f5b041", label="/ σ coloured residuals")
    ax.plot(shift / std, k, "o", color=MODEL, ms=4, label="/ σ Cramér-Rao")
    ax.axvline(0.0, color="black", lw=0.6)
    ax.set_xscale("symlog", linthresh=2.0)
    ax.margins(x=0.06)
    ax.set_yticks(k, names, fontsize=8)
    ax.set_xlabel("(estimate − a-priori) / σ (symmetric log beyond ±2)")
    ax.set_title("trial's parameters: the estimates' distance from the a-priori values")
    ax.legend(loc="best")
    return _png(fig)


@_styled
def coefficients_figure(
    names: Sequence[str],
    values: np.ndarray,
    std: np.ndarray,
    coloured: np.ndarray | None,
    prior: np.ndarray,
    reference: np.ndarray | None,
    reference_label: str,
) -> bytes:
    """Each coefficient over its reference (the analytic or captive value where known, else its
    a-priori value; its Cramér-Rao σ where that is 0): the estimate with ±2σ (Cramér-Rao, thick;
    coloured-residual, thin) and the a-priori value, the reference at 1."""
    base = reference if reference is not None else prior
    zero = base == 0
    base = np.where(zero, np.where(np.isfinite(std) & (std > 0), std, 1.0), base)
    scale = np.abs(base)
    n = len(names)
    fig, ax = plt.subplots(figsize=(8, 0.32 * n + 1.6), layout="constrained")
    k = np.arange(n)[::-1]
    if coloured is not None:
        ax.errorbar(values / base, k, xerr=2 * np.where(np.isfinite(coloured), coloured, 0) / scale, fmt="none",
                    ecolor="#f5b041", lw=1, capsize=2, label="±2σ coloured residuals")  # fmt: skip
    ax.errorbar(values / base, k, xerr=2 * np.where(np.isfinite(std), std, 0) / scale, fmt="o", color=MODEL,
                ms=4, lw=2.2, label="estimate ±2σ Cramér-Rao")  # fmt: skip
    ax.plot(prior / base, k, "x", color=PRIOR, label="a-priori")
    ax.axvline(
        1.0, color="black", lw=0.6, label=reference_label if reference is not None else "a-priori value"
    )
    ax.set_yticks(k, names, fontsize=8)
    over = reference_label if reference is not None else "a-priori value"
    ax.set_xlabel(f"value / {over}" + (f" (/ σ where the {over} is 0)" if zero.any() else ""))
    ax.set_title("coefficients")
    ax.legend(loc="best")
    return _png(fig)


@_styled
def correlation_figure(names: Sequence[str], correlation: np.ndarray) -> bytes:
    """The estimates' correlation matrix (Cramér-Rao) as a heat map, −1 … 1."""
    n = len(names)
    size = min(12, 2.5 + 0.32 * n)
    fig, ax = plt.subplots(figsize=(size, size * 0.85), layout="constrained")
    image = ax.imshow(np.where(np.isfinite(correlation), correlation, 0.0), cmap="RdBu_r", vmin=-1, vmax=1)
    ax.set_xticks(range(n), names, rotation=90, fontsize=7)
    ax.set_yticks(range(n), names, fontsize=7)
    ax.set_title("correlation of the estimates")
    fig.colorbar(image, ax=ax, label="correlation", shrink=0.8)
    return _png(fig)


@_styled
def convergence_figure(costs: Sequence[tuple[int, float]]) -> bytes:
    """J − J_least (negative log-likelihood) per iteration, on a log scale: (iteration, cost)
    pairs in the order reported (several starts one after the other)."""
    fig, ax = plt.subplots(figsize=(8, 3.2), layout="constrained")
    c = np.array([j for _, j in costs], float)
    above = c - np.nanmin(c)
    ax.semilogy(np.arange(1, len(c) + 1), np.where(above > 0, above, np.nan), "o-", color=MODEL, ms=3)
    ax.yaxis.set_major_locator(LogLocator(numticks=6))
    ax.yaxis.set_minor_locator(NullLocator())
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel("iteration (every start's, in the order run)")
    ax.set_ylabel("J − J least")
    ax.set_title("cost per iteration")
    return _png(fig)


@_styled
def corrections_figure(
    check: str, names: Sequence[str], estimates: Sequence[tuple[str, np.ndarray, np.ndarray]]
) -> bytes:
    """One panel per sensor parameter of `check`: each fit's estimate with ±2σ, `estimates` as
    (label, values, σ) over `names` (the pooled fit first, then each record alone); a parameter
    held at 0 has σ 0, one the data do not determine an infinite σ (no bar)."""
    fig, axes = _grid(len(names), f"{check} check: the sensor parameters, pooled and per record", height=2.0)
    k = np.arange(len(estimates))
    for j, (ax, n) in enumerate(zip(axes, names)):
        values = np.array([v[j] for _, v, _ in estimates], float)
        std = np.array([s[j] for _, _, s in estimates], float)
        ax.errorbar(
            k, values, yerr=2 * np.where(np.isfinite(std), std, 0.0), fmt="o", color=MODEL, ms=4, capsize=3
        )
        ax.axhline(0.0, color="black", lw=0.5)
        ax.set_xticks(k, [label[-14:] for label, _, _ in estimates], rotation=30, ha="right")
        ax.set_title(f"{n} ({_sensor_unit(n)})")
    return _png(fig)


def _sensor_unit(name: str) -> str:
    """The unit of a data-compatibility check's sensor parameter: a bias in its channel's unit,
    a scale factor none, a delay s, a misalignment rad, a lever arm m."""
    kind, _, channel = name.partition("_")
    if kind == "b":
        return UNITS.get(channel, "")
    return {"k": "–", "tau": "s", "m": "rad", "r": "m"}.get(kind, "")
