"""`testbed captive` with its figures: the captive reference's model config, and each test's
figure as a PNG in a new folder (`captive_figures`) and in a Rerun recording
(`captive_recording`). Every output is checked before the tests run and written whole or not at
all; the figures' folder holds `MARKER` (the fit table), which marks it as one `force` may replace.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

from testbed.outputs import atomic_directory, atomic_write_text, check_output_directory, check_outputs
from testbed.errors import InputError
from testbed.presentation.captive_figures import figure_name, sweep_figure
from testbed.presentation.captive_recording import log_captive
from testbed.presentation.captive_sweeps import by_test, sweep_panels
from testbed.captive.config import captive_config_text
from testbed.captive.fit import CaptiveFit
from testbed.simulation.vehicle import load_model

__all__ = ["MARKER", "write_captive"]

MARKER = "captive-fit.txt"  # the fit of every force surface, in every figures folder


def _inside(path, folder) -> bool:
    path, folder = os.path.realpath(path), os.path.realpath(folder)
    return path == folder or path.startswith(folder.rstrip(os.sep) + os.sep)


def _check_figures(figures, force: bool, others: dict) -> None:
    label = f"figures={str(figures)!r}"
    if str(figures) == "-":
        raise InputError(f"{label}: figures are files in a folder; expected a folder name")
    check_output_directory(figures, force, MARKER, label)
    for name, path in others.items():
        if path is not None and _inside(path, figures):
            raise InputError(f"{label}: holds the {name} {path}; expected a folder apart from it")


def write_captive(
    mjcf: str | Path | None = None,
    speed: float | None = None,
    out: str | Path | None = None,
    figures: str | Path | None = None,
    rrd: str | Path | None = None,
    force: bool = False,
    model: str = "components",
) -> tuple[str, CaptiveFit, list[Path]]:
    """`(TOML text, fit, the figures written)`: the captive reference of `mjcf` at `speed` with
    the nonlinear `model` (`captive_config_text`), its text written to `out` when given, each test's figure to the new
    folder `figures` (one PNG per test, and `MARKER`) and to the Rerun recording `rrd`, when
    given. An existing file at `out` or `rrd` is refused unless `force`, and an existing folder at
    `figures` unless `force` and it holds `MARKER` or nothing."""
    check_outputs([mjcf] if mjcf else [], {"out": out, "rrd": rrd}, force)
    if figures is not None:
        _check_figures(figures, force, {"out": out, "rrd": rrd, "mjcf": mjcf})
    text, fit = captive_config_text(mjcf, speed, model=model)
    panels = sweep_panels(load_model(mjcf), fit)
    written = []
    with contextlib.ExitStack() as stack:  # the figures' folder appears last, when all is done
        if figures is not None:
            tmp = stack.enter_context(atomic_directory(figures, force, MARKER))
            for test, own in by_test(panels).items():
                sweep_figure(tmp / figure_name(test), own)
            (tmp / MARKER).write_text(f"testbed captive: the fit of every force surface (%)\n{fit.table()}\n")
            written.append(Path(figures))
        if rrd is not None:
            written.append(log_captive(rrd, panels, fit.table(), text, force))
        if out is not None:
            atomic_write_text(out, text, force)
    return text, fit, written
