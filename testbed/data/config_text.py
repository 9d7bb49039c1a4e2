"""A model config written back as TOML: its values, its sensors and comments."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Mapping

from testbed.data.config import BLADE_KEYS, COMPONENT_KEYS, ModelConfig
from testbed.outputs import atomic_write_text
from testbed.models.linear import COEFFICIENTS, DELAY, OFFSETS, OUTPUT_TERMS, OUTSIDE_EQUATIONS, Vehicle
from testbed.models.nonlinear import INERTIA
from testbed.models.sensors import Sensor

__all__ = ["config_text", "sensor_table", "toml_value", "write_config"]


def sensor_table(s: Sensor) -> dict:
    """The `[sensors.NAME]` table of a sensor (`parse_sensor` reads it back to an equal one)."""
    out = {
        "outputs": list(s.outputs),
        "position": list(s.position),
        "misalignment": list(s.misalignment),
        "frame": s.frame,
        "bias": dict(s.bias),
        "scale": dict(s.scale),
        "delay": s.delay,
    }
    if s.rate is not None:
        out["rate"] = s.rate
    if s.noise_std:
        out["noise_std"] = dict(s.noise_std)
    if s.resolution:
        out["resolution"] = dict(s.resolution)
    if s.hold:
        out["hold"] = True
    return out


_SCREEN_NOTE = (
    "screen = true: free is a candidate list; identify fixes the candidates these data do not "
    "determine (docs/cli.md#the-screen); without it free is estimated as written"
)


def config_text(config: ModelConfig, comments: Mapping[str, str] | None = None) -> str:
    """TOML text of a model config; `comments` annotate vehicle constants or coefficients."""
    comments = comments or {}

    def line(key, value):
        note = f"  # {comments[key]}" if key in comments else ""
        return f"{key} = {float(value)!r}{note}"

    lines = ["[vehicle]"] + [
        line(k, getattr(config.vehicle, k)) for k in Vehicle.names() if getattr(config.vehicle, k) is not None
    ]
    if config.terms is None:
        lines += ["", "[coefficients]"] + [line(k, config.coefficients.get(k, 0.0)) for k in COEFFICIENTS]
        lines += [
            line(k, config.coefficients.get(k, 0.0))
            for k in OFFSETS + OUTPUT_TERMS + (DELAY,)
            if config.coefficients.get(k, 0.0) != 0.0 or k in config.free
        ]
    else:  # a nonlinear model config: its inertia coefficients, then its terms (names quoted: `|`)
        lines += ["", "[coefficients]"] + [line(k, config.coefficients.get(k, 0.0)) for k in INERTIA]
        lines += [
            line(k, config.coefficients[k])
            for k in OUTSIDE_EQUATIONS
            if config.coefficients[k] != 0.0 or k in config.free
        ]
        lines += ["", "[terms]"] + [
            f"{json.dumps(k)} = {float(v)!r}" + (f"  # {comments[k]}" if k in comments else "")
            for k, v in config.terms.items()
        ]
    lines += ["", "[identify]"]
    if config.screen:
        lines += [f"# {_SCREEN_NOTE}", "screen = true"]
    lines += ["free = [" + ", ".join(f'"{n}"' for n in config.free) + "]"]
    if config.per_record:
        lines += ["per_record = [" + ", ".join(f'"{n}"' for n in config.per_record) + "]"]
    if config.outputs is not None:
        note = f"  # {comments['outputs']}" if "outputs" in comments else ""
        lines.append("outputs = [" + ", ".join(f'"{s}"' for s in config.outputs) + "]" + note)
    if config.noise_std:
        note = f"  # {comments['noise_std']}" if "noise_std" in comments else ""
        pairs = ", ".join(f"{s} = {float(v)!r}" for s, v in config.noise_std.items())
        lines.append(f"noise_std = {{{pairs}}}{note}")
    if config.bounds:
        pairs = ", ".join(
            f"{json.dumps(n)} = {toml_value([float(x) for x in b])}" for n, b in config.bounds.items()
        )
        lines.append(f"bounds = {{{pairs}}}")
    if not config.physical_bounds:
        lines.append("physical_bounds = false")
    for sensor in config.sensors:
        lines += ["", f"[sensors.{json.dumps(sensor.name)}]"]
        lines += [f"{k} = {toml_value(v)}" for k, v in sensor_table(sensor).items()]
    for c in config.components:
        lines += ["", f"[components.{c.name}]"]
        lines += [f"{k} = {toml_value(getattr(c, k))}" for k in COMPONENT_KEYS]
        if c.fin is not None:
            lines += [f"{k} = {toml_value(getattr(c, k))}" for k in BLADE_KEYS]
    return "\n".join(lines + [""])


def toml_value(v) -> str:
    """A TOML value: strings, exact floats (repr round-trips), ints, lists and inline tables."""
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return repr(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, Mapping):
        return "{" + ", ".join(f"{k} = {toml_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(f"no TOML form for {v!r}")


def write_config(path: str | Path, config: ModelConfig, comments=None, force: bool = False) -> Path:
    """A model config at `path` (`config_text`); an existing file is refused unless `force`."""
    return atomic_write_text(path, config_text(config, comments), force)
