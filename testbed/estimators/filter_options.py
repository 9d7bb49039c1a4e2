"""The filters' options (`FilterOptions`: `mekf`'s and `ekf`'s, each with its check and
meaning) and result (`FilterEstimate`: the estimate with its per-sample histories), with the
paper's own settings (`PAPER_OPTIONS`).
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from testbed.errors import is_number
from testbed.estimators.base import Estimate, Options, Status, count_option, is_count, option

__all__ = ["CONVENTIONAL_FLOOR", "FilterEstimate", "FilterOptions", "NONLINEAR_REFUSED", "PAPER_OPTIONS"]


CONVENTIONAL_FLOOR = 0.01  # the conventional EKF's default `state_noise` (module docstring)


# the options the filter on a nonlinear model config has no use for (module docstring)
NONLINEAR_REFUSED = ("passes", "pass_tol", "refresh_tol")


# The paper's MEKF (§5): its model of the data has measurement noise R alone (§4's likelihood),
# and its square-root algorithm propagates J_{k,k−1} from the model with no process-noise term:
# the model is taken as exact, so the measured states' model-noise covariance is fixed at zero —
# no covariance matching (`noise_window` 0) and no floor (`state_noise` 0). The coefficients'
# random walk (`param_noise`, 1e-6 of the prior σ) and the unmeasured states' process noise stay
# at their defaults, numerical allowances the paper's constant coefficients do not change.
PAPER_OPTIONS = {"noise_window": 0, "state_noise": 0.0}


def _sigmas(v) -> bool:
    """None, or a mapping of names to σ > 0."""
    return v is None or (
        isinstance(v, Mapping) and all(isinstance(k, str) and is_number(x) and x > 0 for k, x in v.items())
    )


def _at_least(low: float, doc: str, default: float):
    return option(default, lambda v: is_number(v) and v >= low, f"a finite number ≥ {low:g}", doc)


_SIGMAS = "a mapping of name to σ > 0, e.g. {'u': 0.01}"


@dataclass(frozen=True)
class FilterOptions(Options):
    """Options of `mekf` and `ekf` (the module docstring says what each choice means)."""

    max_samples: int | None = option(
        None,
        lambda v: v is None or (is_count(v) and v >= 1),
        "an integer ≥ 1 (samples)",
        "stop after this many samples; None: all",
    )
    noise_std: Mapping[str, float] | None = option(
        None,
        _sigmas,
        _SIGMAS,
        "measurement σ per measured state, over the config's; None: the config's or the data's",
    )
    prior_std: Mapping[str, float] | None = option(None, _sigmas, _SIGMAS, "a-priori σ per free coefficient")
    prior_frac: float = _at_least(0.0, "a-priori σ as a fraction of |value|", 0.5)
    prior_floor: float | None = option(
        None,
        lambda v: v is None or (is_number(v) and v > 0),
        "a number > 0",
        "least a-priori σ; None: 1e-3 × the largest |coefficient|",
    )
    param_noise: float = _at_least(
        0.0, "coefficients' random-walk σ per sample, fraction of the prior σ", 1e-6
    )
    state_noise: float | None = option(
        None,
        lambda v: v is None or (is_number(v) and v >= 0),
        "a finite number ≥ 0",
        "model-error σ floor per sample, fraction of R's σ; None: 0 for the "
        "square-root filters, 0.01 for the conventional one",
    )
    noise_window: int = count_option(
        50, 0, "samples averaged by the covariance matching; 0: model error at the floor"
    )
    noise_margin: float = _at_least(0.0, "standard errors of that average an excess must pass to count", 2.0)
    unmeasured_std: float = _at_least(0.0, "initial σ of an unmeasured state (SI)", 1.0)
    unmeasured_noise: float = _at_least(0.0, "process σ per sample of an unmeasured state (SI)", 1e-3)
    refresh_tol: float = _at_least(0.0, "recompute the exact model when a coefficient moved this many σ", 0.2)
    passes: int = count_option(
        1, 1, "passes over the data: 1 the on-line filter, more its fixed-interval iterations"
    )
    pass_tol: float = _at_least(
        0.0, "the iterations stop when no coefficient moved more than this many σ", 0.1
    )
    sqrt: str = option(
        "qr",
        lambda v: v in ("qr", "svd"),
        "'qr' or 'svd'",
        "time-update root: qr (one QR with the update) or svd (U Σ, the paper's)",
    )
    nis_window: int = count_option(200, 1, "samples over which the innovations are tested for divergence")
    nis_limit: float = _at_least(
        0.0, "mean normalised innovation squared per channel that means divergence", 25.0
    )
    explode: float = _at_least(
        0.0, "prior σ a coefficient may move before the filter counts as diverged", 100.0
    )


@dataclass(frozen=True)
class FilterEstimate(Estimate):
    """An `Estimate` with the filter's time histories (kept out of the JSON) and its diagnostics.

    Attributes (beyond `Estimate`'s):
        history: (N, p) θ̂ after each sample's update; `history_std` its σ; `history_t` the
            times, each experiment following the previous one.
        covariance: the final augmented covariance (states, then the free coefficients);
            `covariance_root` its lower-triangular root J, P = J Jᵀ (square-root filters only).
        filter: which filter ran ("square-root MEKF", "conventional EKF").
        nis_mean: mean normalised innovation squared per sample (about the number of measured
            channels for a consistent filter).
        sqrt: the time-update root ("qr" or "svd"; square-root filters only).
        max_covariance_asymmetry: the largest relative asymmetry the conventional covariance
            reached (conventional filter only).
        diverged_sample, diverged_t: where a diverged filter stopped.
        model_error_std: the model error found by covariance matching, per measured state: the
            RMS over the samples of its σ per sample.
        passes, last_step_std: with fixed-interval iterations, the passes made and the last
            pass's largest move in σ (None for the on-line filter).
    """

    history_t: np.ndarray | None = field(default=None, repr=False)
    history_std: np.ndarray | None = field(default=None, repr=False)
    covariance: np.ndarray | None = field(default=None, repr=False)
    covariance_root: np.ndarray | None = field(default=None, repr=False)
    filter: str = ""
    nis_mean: float = math.nan
    sqrt: str | None = None
    max_covariance_asymmetry: float | None = None
    diverged_sample: int | None = None
    diverged_t: float | None = None
    model_error_std: dict[str, float] | None = None
    passes: int | None = None
    last_step_std: float | None = None

    def json_fields(self) -> dict:
        doc = super().json_fields()
        doc |= {"filter": self.filter, "samples": int(self.iterations), "nis_mean": float(self.nis_mean)}
        if self.sqrt is not None:
            doc["sqrt"] = self.sqrt
        if self.max_covariance_asymmetry is not None:
            doc["max_covariance_asymmetry"] = float(self.max_covariance_asymmetry)
        if self.model_error_std is not None:
            doc["model_error_std"] = self.model_error_std
        if self.passes is not None:
            doc["passes"] = self.passes
            if self.last_step_std is not None:
                doc["last_step_std"] = float(self.last_step_std)
        if self.status is Status.DIVERGED:
            doc["diverged"] |= {"sample": self.diverged_sample, "t": self.diverged_t}
        return doc

    def history_csv(self) -> str:
        """CSV `t,<name>,<name>_std,...` of the estimate and ±σ histories."""
        cols = [self.history_t[:, None]]
        for j in range(len(self.free)):
            cols += [self.history[:, j : j + 1], self.history_std[:, j : j + 1]]
        buf = io.StringIO()
        buf.write(",".join(["t"] + [f"{n}{s}" for n in self.free for s in ("", "_std")]) + "\n")
        np.savetxt(buf, np.hstack(cols), delimiter=",", fmt="%.10g")
        return buf.getvalue()
