"""The captive reference of an MJCF body as a nonlinear model config (`testbed captive`)."""

from __future__ import annotations

from pathlib import Path

from testbed.data import ModelConfig, config_text
from testbed.outputs import atomic_write_text, check_outputs
from testbed.errors import InputError
from testbed.models.regressors import component_kind
from testbed.captive.fit import CaptiveFit
from testbed.captive.reference import captive_reference, component_reference, slope_terms
from testbed.simulation.vehicle import constants, cruise_speed, load_model, trim_speed

__all__ = ["MODELS", "captive_config", "captive_config_text"]

# The nonlinear models a captive reference is fitted with: the component model (the fluid forces
# of the hull and each fin blade at its own flow) or the polynomial terms (`nonlinear.TERMS`)
MODELS = ("components", "polynomial")


def captive_config(
    mjcf: str | Path | None = None, speed: float | None = None, model: str = "components"
) -> tuple[ModelConfig, dict[str, str], CaptiveFit]:
    """`(ModelConfig, comments, fit)`: the captive reference of `mjcf` (default: the bundled
    torpedo) at trim speed `speed` (default: its cruise speed) with the nonlinear `model` (one of
    `MODELS`), a nonlinear model config with the inertia coefficients and every term (and the
    components the component terms name), the terms a candidate list for the screen
    (`[identify] screen = true`); the comments say where each came from.

    The inertia coefficients are no candidates: the PMM tests measure them directly, while in a
    free-running record they share regressors with terms (the added mass's Munk moment and
    Coriolis forces, (Z_wdot − X_udot)·u·w in the pitch row beside M_uw, …), so that with them
    free the information is singular along directions that hold most terms. Nor, for the
    component model, are the Kirchhoff terms of the inertia M leaves out (`Y_qr`, …): they are
    the same added mass's."""
    if model not in MODELS:
        raise InputError(f"model {model!r}; expected one of {', '.join(MODELS)}")
    body = load_model(mjcf)
    U = cruise_speed(body) if speed is None else trim_speed(speed)
    fit = component_reference(body, U) if model == "components" else captive_reference(body, U)
    inertia = {n: v for n, v in fit.coefficients.items() if n not in fit.terms}
    terms = {n: fit.coefficients[n] for n in fit.terms}
    vehicle = constants(body, U)
    # the candidates: the terms, but for the component model the Kirchhoff terms of the inertia
    # M leaves out, which the PMM tests measure as they measure the inertia coefficients
    free = tuple(n for n in terms if model == "polynomial" or component_kind(n))
    config = ModelConfig(
        vehicle, inertia, free, str(mjcf or ""), screen=True, terms=terms, components=fit.components
    )
    where = Path(mjcf).name if mjcf else "the bundled torpedo"
    comments = {"speed": f"U, trim speed; captive reference of {where} ({model} model)"}
    comments |= {n: "the PMM tests' quadrature part and the rigid body's I_xz" for n in inertia}
    if model == "components":
        comments |= {n: "over the manoeuvre" if component_kind(n) else "inertia M leaves out" for n in terms}
    else:
        at_trim = set(slope_terms(fit.terms))
        comments |= {n: "slope at trim" if n in at_trim else "over the manoeuvre" for n in terms}
    return config, comments, fit


def captive_config_text(
    mjcf: str | Path | None = None,
    speed: float | None = None,
    out=None,
    force: bool = False,
    model: str = "components",
) -> tuple[str, CaptiveFit]:
    """`(TOML text, fit)` of `captive_config`, the text also written to `out` when given (an
    existing file there is refused unless `force`)."""
    check_outputs([mjcf] if mjcf else [], {"out": out}, force)
    config, comments, fit = captive_config(mjcf, speed, model)
    text = config_text(config, comments)
    if out is not None:
        atomic_write_text(out, text, force)
    return text, fit
