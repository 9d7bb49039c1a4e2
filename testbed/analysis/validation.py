"""Validation metrics of a model on data, as MATLAB's `compare` and `resid` and SIDPAC give them.

Per experiment and measured channel:

- **fit %** `100 (1 − ‖y − ŷ‖ / ‖y − ȳ‖)`: the model simulated open loop with the recorded
  inputs from its best-fitting initial state (linear least squares, as `compare` does), against
  the data; 100 is perfect, 0 is no better than the channel's mean (it can be negative);
- **residual whiteness** of `e = y − ŷ`: the normalised autocorrelation `r_k = Σ e_t e_{t+k} /
  Σ e_t²` at lags 1..`LAGS`, its 99 % confidence bound `2.576/√N` for white noise, how many lags
  fall outside it, and the Ljung-Box statistic `Q = N (N + 2) Σ r_k² / (N − k)` with its p-value
  against χ²(`LAGS`); the residual is called white when p ≥ 0.01. Coloured residuals mean model
  error (or coloured noise): the plain Cramér-Rao bound is then optimistic.

`validate` computes both for a model config (e.g. identified coefficients applied to the
a-priori config) and, when given, for the analytic model on the same data.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Mapping, Sequence

import numpy as np

from testbed.data import Experiment, ModelConfig, stretches
from testbed.errors import InputError
from testbed.fit_percent import fit_percent
from testbed.html_figures import svg_dots
from testbed.html_table import html_table
from testbed.identification import nonlinear_prediction
from testbed.identification.bounds import chi2_sf
from testbed.identification.prediction import predict

__all__ = [
    "CONFIDENCE",
    "LAGS",
    "ChannelMetrics",
    "Validation",
    "Whiteness",
    "autocorrelation",
    "predicted",
    "validate",
    "whiteness",
]

LAGS = 25  # autocorrelation lags tested (0.5 s at 50 Hz: beyond the torpedo's fast modes)
CONFIDENCE = 2.576  # 99 % two-sided normal quantile
WHITE_P = 0.01  # Ljung-Box p-value at or above which a residual counts as white


@dataclass(frozen=True)
class Whiteness:
    """The residual autocorrelation test of one channel."""

    max_autocorrelation: float  # max |r_k| over lags 1..LAGS
    bound: float  # 2.576/√N: the 99 % band of white noise
    lags_outside: int  # lags with |r_k| above the bound (about LAGS/100 for white noise)
    ljung_box_q: float
    ljung_box_p: float
    white: bool  # p ≥ WHITE_P

    def to_dict(self) -> dict:
        return {
            "max_autocorrelation": self.max_autocorrelation,
            "bound": self.bound,
            "lags_outside": self.lags_outside,
            "ljung_box_q": self.ljung_box_q,
            "ljung_box_p": self.ljung_box_p,
            "white": self.white,
        }


def autocorrelation(e: np.ndarray, lags: int = LAGS) -> np.ndarray:
    """The sample autocorrelation r_1 … r_lags of a residual sequence `e` (N,), its mean taken
    off (fewer lags where the sequence is shorter; none where it holds one value)."""
    e = np.asarray(e, float) - np.mean(e)
    n = len(e)
    lags = min(lags, n - 1)
    energy = float(e @ e)
    if energy == 0.0 or lags < 1:
        return np.zeros(0)
    spectrum = np.fft.rfft(e, 2 * n)  # r_k for every lag at once, no circular wrap
    return np.fft.irfft(spectrum * np.conj(spectrum), 2 * n)[1 : lags + 1] / energy


def whiteness(e: np.ndarray, lags: int = LAGS) -> Whiteness:
    """The autocorrelation test of a residual sequence `e` (N,)."""
    n = len(e)
    r = autocorrelation(e, lags)
    lags = len(r)
    if lags == 0:
        return Whiteness(0.0, CONFIDENCE / np.sqrt(n), 0, 0.0, 1.0, True)
    bound = CONFIDENCE / np.sqrt(n)
    q = float(n * (n + 2) * np.sum(r**2 / (n - np.arange(1, lags + 1))))
    p = chi2_sf(q, lags)
    return Whiteness(float(np.abs(r).max()), float(bound), int(np.sum(np.abs(r) > bound)), q, p, p >= WHITE_P)


@dataclass(frozen=True)
class ChannelMetrics:
    fit_percent: float  # of the validated model
    whiteness: Whiteness  # of its residual
    fit_percent_analytic: float | None = None  # of the analytic model, when given

    def to_dict(self) -> dict:
        doc = {"fit_percent": _finite(self.fit_percent), "whiteness": self.whiteness.to_dict()}
        if self.fit_percent_analytic is not None:
            doc["fit_percent_analytic"] = _finite(self.fit_percent_analytic)
        return doc


def _finite(v: float) -> float | None:
    return float(v) if np.isfinite(v) else None


@dataclass(frozen=True)
class Validation:
    """experiment → channel → metrics; `predictions`: experiment → the validated model's
    open-loop prediction as a record (the experiment with ŷ in its measured channels)."""

    experiments: Mapping[str, Mapping[str, ChannelMetrics]]
    predictions: Mapping[str, Experiment] = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {e: {c: m.to_dict() for c, m in ch.items()} for e, ch in self.experiments.items()}

    def rows(self) -> tuple[tuple[str, ...], list[tuple[str, ...]]]:
        """The metrics' column names and one row of text per experiment and channel (the analytic
        model's fit % only where some channel has it)."""
        analytic = any(
            m.fit_percent_analytic is not None for ch in self.experiments.values() for m in ch.values()
        )
        head = ("experiment", "channel", "fit %") + (("analytic",) if analytic else ())
        head += ("max |r_k|", "bound", "Ljung-Box p", "residual")
        rows = []
        for e, ch in self.experiments.items():
            for c, m in ch.items():
                w = m.whiteness
                row = (e, c, _pct(m.fit_percent)) + ((_pct(m.fit_percent_analytic),) if analytic else ())
                rows.append(
                    row
                    + (f"{w.max_autocorrelation:.3f}", f"{w.bound:.3f}", f"{w.ljung_box_p:.2g}")
                    + ("white" if w.white else "coloured",)
                )
        return head, rows

    def table(self) -> str:
        """The metrics as a plain table, one row per experiment and channel."""
        head, rows = self.rows()
        widths = (16, 8, 8) + ((10,) if "analytic" in head else ()) + (11, 8, 13)
        return "\n".join(
            "".join(f"{v:<{w}}" if k < 2 else f"{v:>{w}}" for k, (v, w) in enumerate(zip(row, widths)))
            + f"  {row[-1]}"
            for row in [head, *rows]
        )

    def _repr_html_(self) -> str:
        """The metrics in a notebook: one row per experiment and channel, and a figure of the fit
        % of each (a coloured residual marked)."""
        names, fits = [], []
        for e, ch in self.experiments.items():
            for c, m in ch.items():
                names.append(f"{e} {c}{'' if m.whiteness.white else ' (coloured)'}")
                fits.append(m.fit_percent)
        figure = svg_dots(
            names, fits, "the model's fit per channel", "fit % (100: every sample)", reference=100.0
        )
        return html_table(*self.rows(), "the model's fit % and residual whiteness per channel") + figure


def _pct(v) -> str:
    return "-" if v is None or not np.isfinite(v) else f"{v:.2f}"


def predicted(
    experiments: Sequence[Experiment],
    config: ModelConfig,
    initial: Mapping[str, Mapping[str, float]] | None = None,
) -> list[np.ndarray]:
    """`config`'s model outputs per experiment (NaN where it is not flown): the linear model's
    (`prediction.predict`), or a nonlinear model config's flown open loop
    (`nonlinear_prediction.predict_nonlinear`); `initial` as they take it."""
    flown = predict if config.terms is None else nonlinear_prediction.predict_nonlinear
    return flown(experiments, config, initial)


def validate(
    experiments: Sequence[Experiment],
    config: ModelConfig,
    analytic: ModelConfig | None = None,
    initial: Mapping[str, Mapping[str, float]] | None = None,
) -> Validation:
    """Fit % and residual whiteness of `config`'s model (linear, or nonlinear flown by
    `nonlinear_prediction`) on every measured channel of the experiments (its initial states
    fitted, or taken from `initial`: experiment → state → x0),
    and the fit % of `analytic`'s model on the same data (initial states fitted). A
    channel's metrics are over its samples present, its residuals taken in sequence (a missing
    sample skipped, a slower sensor's at its own rate)."""
    experiments = config.readings(experiments)  # compared in the states, the config's sensors undone
    with np.errstate(over="ignore", invalid="ignore"):  # an overflowing prediction is refused below
        yhat = predicted(experiments, config, initial)
    flown = [np.zeros(len(e.t), dtype=bool) for e in experiments]  # the model's stretches of each
    for e, f in zip(experiments, flown):
        for a, b in stretches(e):
            f[a:b] = True
    for e, y_model, f in zip(experiments, yhat, flown):
        if not np.all(np.isfinite(y_model[f])):  # an unstable model's response overflowed: no score
            raise InputError(
                f"{config.source or 'config'}: the model's prediction of {e.source or e.name} leaves the "
                "finite numbers (its response grows beyond them along the record); expected coefficients "
                "whose response stays finite over it"
            )
    base = predict(experiments, analytic) if analytic is not None else [None] * len(experiments)
    out, predictions = {}, {}
    for e, y_model, y_base, f in zip(experiments, yhat, base, flown):
        predictions[e.name] = replace(e, y=y_model, source=f"the model's prediction of {e.source or e.name}")
        out[e.name] = {}
        for k, c in enumerate(e.measured):
            at = f & ~np.isnan(e.y[:, k])  # the samples present and flown; their residuals in sequence
            y = e.y[at, k]
            out[e.name][c] = ChannelMetrics(
                fit_percent(y, y_model[at, k]),
                whiteness(y - y_model[at, k]),
                None if y_base is None else fit_percent(y, y_base[at, k]),
            )
    return Validation(experiments=out, predictions=predictions)
