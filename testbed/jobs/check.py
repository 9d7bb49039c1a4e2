"""`testbed check` as a library function: the data-compatibility check of records, written as
JSON (and an HTML report).
"""

from __future__ import annotations
import os
from pathlib import Path
from typing import Sequence
from testbed.data import load_data
from testbed.outputs import check_outputs
from testbed.jobs.common import write_text, check_report

__all__ = ["check_data"]


def check_data(
    data: Sequence[str | os.PathLike],
    *,
    out: str | os.PathLike | None = None,
    keep_repeats: bool = False,
    force: bool = False,
    report: str | os.PathLike | None = None,
):
    """The data-compatibility check of `data` (run directories or measurement CSVs): the
    kinematics reconstructed, the sensor biases, scale factors and delays estimated with their
    bounds, written as JSON to `out` (`keep_repeats` and `force` as for `identify_data`); the
    `analysis.compatibility_checks.Compatibility`; `report`: a new or empty folder for its HTML page
    (`presentation.fit_report.check_report_html`)."""
    from testbed.analysis.compatibility import compatibility  # numba and scipy: only here

    experiments, _ = load_data(data, keep_repeats)
    read = [Path(e.source) for e in experiments]
    read += [Path(p) / "manifest.json" for p in data if (Path(p) / "manifest.json").is_file()]
    check_outputs(read, {"out": out}, force)
    check_report(report, force)
    result = compatibility(experiments)
    write_text(out, result.to_json(), force)
    if report is not None:  # last: a folder made only once everything else is written
        from testbed.presentation.fit_report import check_report_html, write_fit_report

        write_fit_report(
            report, check_report_html(result, f"testbed check: {', '.join(map(str, data))}"), force
        )
    return result
