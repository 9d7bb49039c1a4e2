"""An estimate compared with the analytic model (`compare`): per coefficient the relative error
and the error in σ, and with a fit to the noise-free data the linear model's own bias apart
from the noise's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from testbed.html_figures import svg_dots
from testbed.html_table import html_table
from testbed.identification.problem import base_name

__all__ = ["Comparison", "compare"]


@dataclass(frozen=True)
class Comparison:
    """Identified versus analytic coefficients; `truth_fit` (fit to noise-free data) splits the
    error into the linear model's bias (truth_fit − analytic) and noise (identified − truth_fit)."""

    names: tuple[str, ...]
    analytic: np.ndarray
    identified: np.ndarray
    std: np.ndarray
    truth_fit: np.ndarray | None = None
    note: str = ""  # why the truth fit is missing, when it failed

    def rows(self) -> list[dict]:
        out = []
        for k, n in enumerate(self.names):
            a, x, s = self.analytic[k], self.identified[k], self.std[k]
            row = {
                "name": n,
                "analytic": float(a),
                "identified": float(x),
                "std": float(s),
                "relative_error": float((x - a) / abs(a)) if a else None,
                "error_sigmas": float((x - a) / s) if 0 < s < np.inf else None,
            }
            if self.truth_fit is not None:
                t = self.truth_fit[k]
                row["truth_fit"] = float(t)
                row["model_bias_relative"] = float((t - a) / abs(a)) if a else None
                row["noise_sigmas"] = float((x - t) / s) if 0 < s < np.inf else None
            out.append(row)
        return out

    def to_dict(self) -> dict:
        """The rows as JSON values: a value that is not finite (the unbounded std of a direction
        the data do not determine) is null."""
        rows = [
            {k: None if isinstance(v, float) and not np.isfinite(v) else v for k, v in r.items()}
            for r in self.rows()
        ]
        return {"rows": rows, **({"note": self.note} if self.note else {})}

    def cells(self) -> tuple[list[str], list[list[str]]]:
        """The column names and each coefficient's row as text ("-" where a value is undefined)."""
        head = ["coefficient", "analytic", "identified", "std", "rel.err", "sigmas"]
        if self.truth_fit is not None:
            head += ["truth fit", "lin.bias", "noise σ"]

        def f(v, fmt):
            return format(v, fmt) if v is not None else "-"

        rows = []
        for r in self.rows():
            row = [
                r["name"],
                f"{r['analytic']:.4g}",
                f"{r['identified']:.4g}",
                f"{r['std']:.2g}",
                f(r["relative_error"], ".1%"),
                f(r["error_sigmas"], ".1f"),
            ]
            if self.truth_fit is not None:
                row += [
                    f"{r['truth_fit']:.4g}",
                    f(r["model_bias_relative"], ".1%"),
                    f(r["noise_sigmas"], ".1f"),
                ]
            rows.append(row)
        return head, rows

    def table(self) -> str:
        head, rows = self.cells()
        widths = [12, 12, 12, 10, 9, 8, 12, 9, 8]
        lines = [
            "".join(v.ljust(w) if k == 0 else v.rjust(w) for k, (v, w) in enumerate(zip(row, widths)))
            for row in [head, *rows]
        ]
        if self.note:
            lines.append(self.note)
        return "\n".join(lines)

    def _repr_html_(self) -> str:
        """The comparison in a notebook: one row per coefficient, as `table`, and a figure of each
        error in its σ with the ±2σ band."""
        rows = self.rows()
        errors = [np.nan if r["error_sigmas"] is None else r["error_sigmas"] for r in rows]
        figure = svg_dots(
            [r["name"] for r in rows],
            errors,
            "identified − analytic, in the estimate's σ",
            "(identified − analytic) / σ",
            band=(-2.0, 2.0),
            reference=0.0,
        )
        return html_table(*self.cells(), self.note or "identified against the analytic coefficients") + figure


def compare(estimate, analytic_config, truth_estimate=None) -> Comparison:
    """Compare an `Estimate` with a model config's coefficients (and a fit to noise-free data,
    used only if it converged)."""
    names = tuple(estimate.free)
    analytic = np.array([analytic_config.coefficients[base_name(n)] for n in names])
    truth, note = None, ""
    if truth_estimate is not None and truth_estimate.converged:
        t = truth_estimate.coefficients
        truth = np.array([t[n] for n in names])
    elif truth_estimate is not None:
        note = (
            f"no linear-model bias column: the {truth_estimate.method} fit to the noise-free "
            f"truth did not converge ({truth_estimate.status.message})"
        )
    return Comparison(names, analytic, np.asarray(estimate.values), np.asarray(estimate.std), truth, note)
