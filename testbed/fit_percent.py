"""The fit of a model's output to a measured signal, in percent: the normalised root-mean-square
error's complement, 100 at a perfect fit, 0 for the signal's mean, negative for worse."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["fit_percent"]


def fit_percent(y: np.ndarray, yhat: np.ndarray, floor: float = 0.0) -> float:
    """`100 (1 − ‖y − ŷ‖ / ‖y − ȳ‖)`; NaN where ‖y − ȳ‖ is not above `floor` (a signal that does
    not vary, or by no more than rounding)."""
    spread = float(np.linalg.norm(y - np.mean(y)))
    return 100.0 * (1.0 - float(np.linalg.norm(y - yhat)) / spread) if spread > floor else math.nan
