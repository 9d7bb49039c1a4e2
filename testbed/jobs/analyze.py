"""`testbed analyze` as a library function: the identifiability of a config's free
coefficients from data, written as JSON (and an HTML report).
"""

from __future__ import annotations
import os
from typing import Mapping, Sequence
from testbed.analysis.identifiability import Identifiability, identifiability
from testbed.analysis.nonlinear_identifiability import nonlinear_identifiability
from testbed.outputs import check_outputs
from testbed.errors import InputError
from testbed.jobs.common import write_text, inputs, check_report

__all__ = ["analyze_data"]


def analyze_data(
    data: Sequence[str | os.PathLike],
    *,
    config: str | os.PathLike | None = None,
    out: str | os.PathLike | None = None,
    noise_std: Mapping[str, float] | None = None,
    keep_repeats: bool = False,
    force: bool = False,
    report: str | os.PathLike | None = None,
) -> Identifiability:
    """Identifiability of the config's free coefficients from `data` (Fisher information,
    Cramér-Rao bounds, correlations, drift groups; a nonlinear model config's by
    `analysis.nonlinear_identifiability`), written as JSON to `out`; `noise_std`, `keep_repeats`
    and `force` as for `identify_data`; `report`: a new or empty folder for the analysis' HTML page
    (`presentation.fit_report.analysis_report_html`)."""
    experiments, cfg, _, read = inputs(data, config, keep_repeats)
    cfg = cfg.with_noise_std(noise_std)
    check_outputs(read, {"out": out}, force)
    check_report(report, force)
    if not cfg.free:
        raise InputError(f"{cfg.source or 'config'}: [identify] free is empty; nothing to analyse")
    if cfg.terms is not None:
        result = nonlinear_identifiability(experiments, cfg)
    else:
        result = identifiability(experiments, cfg)
    write_text(out, result.to_json(), force)
    if report is not None:  # last: a folder made only once everything else is written
        from testbed.presentation.fit_report import analysis_report_html, write_fit_report

        title = f"testbed analyze: {', '.join(map(str, data))}"
        write_fit_report(report, analysis_report_html(experiments, cfg, result, title), force)
    return result
