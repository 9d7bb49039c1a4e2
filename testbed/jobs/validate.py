"""`testbed validate` as a library function: fit % and residual whiteness of a model on
(held-out) data, with the manoeuvres a run flies measured against the model's.
"""

from __future__ import annotations
import json
import os
from pathlib import Path
from typing import Sequence
from testbed.analysis.validation import Validation, validate
from testbed.data import read_estimates, read_json
from testbed.outputs import check_outputs
from testbed.errors import InputError
from testbed.identification.problem import check_inputs
from testbed.models.linear import OUTSIDE_EQUATIONS
from testbed.jobs.common import write_text, inputs, check_report

__all__ = ["validate_data"]


def validate_data(
    data: Sequence[str | os.PathLike],
    estimates: str | os.PathLike | None = None,
    *,
    config: str | os.PathLike | None = None,
    out: str | os.PathLike | None = None,
    keep_repeats: bool = False,
    force: bool = False,
    report: str | os.PathLike | None = None,
) -> tuple[Validation, str, dict]:
    """Fit % and residual whiteness on `data` of a model config (`config`, default: the run's
    model.toml, or a nonlinear fit's config named in `estimates`) with the coefficients of the
    `estimates` JSON applied, or as it stands without `estimates`; the validation JSON (also
    written to `out`; `keep_repeats` and `force` as for `identify_data`) with them, and
    experiment name → the
    manoeuvre metrics of the record and of the model's open-loop prediction for each manoeuvre a
    run directory of `data` flies (`analysis.manoeuvres.compared`: `Compared`). A nonlinear model config is flown open loop
    (`analysis.validate`). `report`: a new or empty folder for the validation's HTML page
    (`presentation.fit_report.validation_report_html`: the model against the records, the config
    as written beside it where `estimates` changed it)."""
    model = _nonlinear_estimates(estimates) if estimates is not None else None
    if config is None and model is not None:
        config = model["config"]
    experiments, cfg, run_config, read = inputs(data, config, keep_repeats)
    runs = [Path(p) for p in data if (Path(p) / "scenario.toml").is_file()]  # their manoeuvres compared
    read += [f for run in runs for f in (run / "scenario.toml", *run.glob("*.truth.csv"))]
    check_outputs(read + ([estimates] if estimates is not None else []), {"out": out}, force)
    check_report(report, force)
    coefficients = {}
    if cfg.terms is None:
        if model is not None:
            raise InputError(
                f"{estimates}: a nonlinear model's fit ([terms] of {model['config']}); {cfg.source} is a "
                "linear model config; expected the config the estimates were fitted with"
            )
        check_inputs(experiments, cfg)  # the user's data against the user's model (validate checks no step)
        if estimates is not None:
            coefficients = read_estimates(estimates)[0]
    elif estimates is not None:
        if model is None:
            raise InputError(
                f"{estimates}: a linear model's fit; {cfg.source} is a nonlinear model config ([terms]); "
                "expected the config the estimates were fitted with"
            )
        if model["terms"] != list(cfg.terms):
            raise InputError(
                f"{estimates}: fitted the nonlinear model over {model['config']}'s terms; {cfg.source} has "
                "other terms; expected the config the estimates were fitted with"
            )
        coefficients = read_estimates(estimates, cfg.nonlinear()[0].names + OUTSIDE_EQUATIONS)[0]
    validation = validate(experiments, cfg.with_coefficients(coefficients), run_config)
    manoeuvres = {}
    if runs:
        from testbed.analysis.manoeuvres import compared  # mujoco (the scenarios): only for runs

        manoeuvres = {name: c for run in runs for name, c in compared(run, validation.predictions).items()}
    given = estimates is not None
    text = (
        json.dumps(
            {
                "config": cfg.source,
                **({"estimates": str(estimates), "coefficients": coefficients} if given else {}),
                "validation": validation.to_dict(),
                **({"manoeuvres": {n: c.to_dict() for n, c in manoeuvres.items()}} if manoeuvres else {}),
            },
            indent=2,
            allow_nan=False,
        )
        + "\n"
    )
    page = None
    if report is not None:
        from testbed.presentation.fit_report import validation_report_html

        what = f"{cfg.source} with the coefficients of {estimates}" if given else f"{cfg.source} as written"
        page = validation_report_html(
            experiments,
            cfg.with_coefficients(coefficients),
            validation,
            cfg if given else None,
            f"testbed validate: {', '.join(map(str, data))}",
            f"The model validated: {what}; its outputs flown open loop from the best-fitting initial "
            "states" + (", the config as written beside them (a-priori)." if given else "."),
        )
    write_text(out, text, force)
    if page is not None:  # last: a folder made only once everything else is written
        from testbed.presentation.fit_report import write_fit_report

        write_fit_report(report, page, force)
    return validation, text, manoeuvres


def _nonlinear_estimates(path) -> dict | None:
    """An estimates JSON's `nonlinear_model` (`config`, `terms`) when it is a nonlinear fit's."""
    doc = read_json(path, "an estimates JSON")
    model = doc.get("nonlinear_model") if isinstance(doc, dict) else None
    if model is None:
        return None
    if not (
        isinstance(model, dict)
        and isinstance(model.get("config"), str)
        and isinstance(model.get("terms"), list)
        and all(isinstance(t, str) for t in model["terms"])
    ):
        raise InputError(f"{path}: nonlinear_model; expected {{config: a path, terms: a list of term names}}")
    return model
