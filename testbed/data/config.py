"""Model configs (docs/files.md): `ModelConfig`, read from TOML and checked field by field."""

from __future__ import annotations

import json
import math
import numbers
import reprlib
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from testbed.data.experiment import MAX_DATA, Experiment
from testbed.data.files import check_name, read_toml
from testbed.errors import InputError, check_keys
from testbed.models.components import Component, check_component_name
from testbed.models.linear import (
    COEFFICIENTS,
    CURRENT,
    MAX_SPEED,
    MIN_SPEED,
    MOUNTING,
    OFFSETS,
    OUTSIDE_EQUATIONS,
    PARAMETERS,
    STATES,
    Vehicle,
)
from testbed.models.nonlinear import INERTIA, NonlinearModel, nonlinear_model, nonlinear_theta
from testbed.models.regressors import physical_bounds
from testbed.models.sensors import OUTPUTS, Sensor, needs, states_from

__all__ = [
    "BLADE_KEYS",
    "COMPONENT_KEYS",
    "CONFIG_SENSOR_KEYS",
    "IDENTIFY_KEYS",
    "MAX_CONSTANT",
    "MIN_NOISE_STD",
    "MOUNTING_LIMITS",
    "ModelConfig",
    "check_config",
    "check_free",
    "check_noise_std",
    "check_per_record",
    "number",
    "parse_config",
    "parse_sensor",
    "read_config",
    "undone",
]


# The largest magnitude of a vehicle constant or coefficient (SI): a supertanker's yaw inertia is
# ~1e13 kg m², its dimensional coefficients ~1e12. Products of a few such numbers stay finite.
MAX_CONSTANT = 1e15

# A velocity log's mounting (`MOUNTING`): misalignments within ±0.5 rad (a scenario sensor's
# limit: small angles), a position within 50 m of the CG
MOUNTING_LIMITS = {"m_dvl_y": 0.5, "m_dvl_z": 0.5, "r_dvl_x": 50.0, "r_dvl_y": 50.0, "r_dvl_z": 50.0}

# The least measurement-noise σ (SI): the floor that keeps a noise covariance R = σ² positive
# definite in double precision, far below any sensor's noise (1 nrad, 1 nm/s).
MIN_NOISE_STD = 1e-9

# What a model config's `[sensors.NAME]` says of a sensor: what it reads and its known errors
# (its rate and noise are the data's own)
CONFIG_SENSOR_KEYS = ("outputs", "position", "misalignment", "frame", "bias", "scale", "delay")


@dataclass(frozen=True)
class ModelConfig:
    """A model config: the vehicle, the model's parameters (the 35 coefficients, the offsets,
    the output biases, the current, the inputs' delay), and the free ones. With `terms` it is a
    nonlinear model config: the nonlinear model over the terms named (their coefficients), its
    inertia coefficients the `…dot` ones of `coefficients` and its output biases the `b_…` ones
    (the others 0)."""

    vehicle: Vehicle
    coefficients: Mapping[str, float]  # every name in PARAMETERS
    free: tuple[str, ...] = ()
    source: str = ""
    outputs: tuple[str, ...] | None = None  # [identify] outputs: the states fitted (None: all measured)
    # [identify] noise_std: state → the sensors' noise σ (SI), known; None: read off the data
    noise_std: Mapping[str, float] | None = None
    screen: bool = False  # [identify] screen: `free` is a candidate list that `identify` screens
    # [identify] per_record: free names estimated once per record (each experiment its own value)
    per_record: tuple[str, ...] = ()
    # experiment name → {name: value}: a record's own values, where they differ from `coefficients`
    # (an estimate's per-record values, `with_coefficients`)
    record_values: Mapping[str, Mapping[str, float]] = field(default_factory=dict)
    sensors: tuple[Sensor, ...] = ()  # [sensors.NAME]: the sensors whose geometry and errors are known
    terms: Mapping[str, float] | None = None  # [terms]: the nonlinear model's terms, in order; None: linear
    components: tuple[Component, ...] = ()  # [components.NAME]: what the component terms name
    # [identify] bounds: free name → (low, high), the box the fit keeps it in (±inf: open)
    bounds: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    # [identify] physical_bounds: each free term not in `bounds` on its physical side
    # (`regressors.physical_bounds`: a component's drags ≥ 0)
    physical_bounds: bool = True

    def __post_init__(self):  # a name a config leaves out is 0 (and fixed)
        object.__setattr__(self, "coefficients", dict.fromkeys(PARAMETERS, 0.0) | dict(self.coefficients))

    def record_coefficients(self, name: str) -> dict[str, float]:
        """The coefficients and offsets of the record (experiment) called `name`."""
        return {**self.coefficients, **self.record_values.get(name, {})}

    def readings(self, experiments: Sequence[Experiment]) -> list[Experiment]:
        """The experiments with each of the config's sensors undone (`models.sensors.states_from`):
        their readings turned into the CG's body-axis states, the rate and attitude sensors first
        (the others' lever arms and earth axes use them). Applied once to a record: a record
        keeps the names of the sensors already undone. `InputError` for a record without a
        sensor's outputs, or without the rates or attitude its correction needs."""
        order = sorted(
            self.sensors, key=lambda s: not set(s.outputs) & {"p", "q", "r", "phi", "theta", "psi"}
        )
        out = []
        for e in experiments:
            for sensor in (s for s in order if s.name not in e.sensors):
                e = undone(e, sensor, self.source or "config")
            out.append(e)
        return out

    def fitted(self, experiments: Sequence[Experiment]) -> list[Experiment]:
        """The experiments, the config's sensors undone (`readings`), reduced to the config's
        outputs (all of them without `outputs`). Each record keeps the outputs it measures;
        `InputError` for an output that no record measures, or a record that measures none."""
        experiments = self.readings(experiments)
        if self.outputs is None:
            return list(experiments)
        measured = {s for e in experiments for s in e.measured}
        missing = [s for s in self.outputs if s not in measured]
        if missing:
            raise InputError(
                f"{self.source or 'config'}: [identify] outputs names {', '.join(missing)}, which no "
                f"record measures (they measure {', '.join(s for s in STATES if s in measured)}); "
                "expected measured states, or no outputs to fit every measured state"
            )
        return [e.only(self.outputs) for e in experiments]

    def with_coefficients(self, values: Mapping[str, float]) -> "ModelConfig":
        """The config with `values` set: coefficients and offsets by name (a nonlinear model
        config's terms among them), and a record's own value as `name[experiment]` (an
        estimate's per-record values)."""
        terms = self.terms
        if terms is not None:
            terms = {n: values.get(n, v) for n, v in terms.items()}
            values = {n: v for n, v in values.items() if n not in terms}
        shared = {n: v for n, v in values.items() if not n.endswith("]")}
        records = {e: dict(v) for e, v in self.record_values.items()}
        for n, v in values.items():
            if n.endswith("]"):
                name, experiment = n[:-1].split("[", 1)
                records.setdefault(experiment, {})[name] = v
        return replace(self, coefficients={**self.coefficients, **shared}, record_values=records, terms=terms)

    @property
    def values(self) -> dict[str, float]:
        """Every parameter's value by name: the coefficients and offsets, and a nonlinear model
        config's terms."""
        return {**self.coefficients, **(self.terms or {})}

    def nonlinear(self) -> tuple[NonlinearModel, np.ndarray]:
        """A nonlinear model config's model and its θ (`models.nonlinear`: the inertia
        coefficients, then the terms)."""
        model = nonlinear_model(self.vehicle, tuple(self.terms), self.components)
        return model, nonlinear_theta(model, {**{n: self.coefficients[n] for n in INERTIA}, **self.terms})

    def box(self, names: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
        """`(low, high)` of each of `names`: its `bounds` entry, else (a nonlinear model config's
        term, with `physical_bounds`) its physical side, else unbounded (±inf)."""
        low, high = np.full(len(names), -math.inf), np.full(len(names), math.inf)
        for k, n in enumerate(names):
            if n in self.bounds:
                low[k], high[k] = self.bounds[n]
            elif self.physical_bounds and self.terms is not None and n in self.terms:
                low[k], high[k] = physical_bounds(n)
        return low, high

    def output_biases(self, states: Sequence[str]) -> np.ndarray:
        """The output biases `b_<state>` of `states`, in their order: y = x + b."""
        return np.array([self.coefficients[f"b_{s}"] for s in states], float)

    def mounting(self) -> np.ndarray:
        """The velocity log's mounting (5,), `MOUNTING` order: 0 at the CG, aligned."""
        return np.array([self.coefficients[n] for n in MOUNTING], float)

    def current(self) -> np.ndarray:
        """The steady current (c_N, c_E) (2,), m/s: 0 in still water."""
        return np.array([self.coefficients[n] for n in CURRENT], float)

    def with_noise_std(self, values: Mapping[str, float] | None, where: str = "noise_std") -> "ModelConfig":
        """The config with `values` (state → σ, checked as `where`) replacing its `noise_std`
        entry by entry; the states `values` leaves out keep the config's σ."""
        if not values:
            return self
        merged = {**(self.noise_std or {}), **check_noise_std(values, where)}
        return replace(self, noise_std={s: merged[s] for s in STATES if s in merged})


def undone(e: Experiment, sensor: Sensor, source: str) -> Experiment:
    """`e` with `sensor`'s readings turned into the states they measure (`ModelConfig.readings`)."""
    where = f"{e.source or e.name}: {source}'s sensors.{sensor.name}"
    missing = [o for o in sensor.outputs if o not in e.measured]
    if missing:
        raise InputError(f"{where} outputs {', '.join(missing)}, which the record has no column for")
    wants = needs(sensor)
    given = []
    for need, names in zip(wants, (("p", "q", "r"), ("phi", "theta", "psi"))):
        lacking = [n for n in names if n not in e.measured]
        if need and lacking:
            raise InputError(f"{where} needs {', '.join(names)} to be undone; the record has no {lacking[0]}")
        given.append(np.column_stack([e.column(n) for n in names]) if need else None)
    y = np.asarray(e.y, dtype=float).copy()
    cols = [e.measured.index(o) for o in sensor.outputs]
    states = states_from(sensor, np.asarray(e.t, float), y[:, cols], *given)
    for o, k in zip(sensor.outputs, cols):
        y[:, k] = states[o]
    return replace(e, y=y, sensors=e.sensors + (sensor.name,))


def read_config(path: str | Path) -> ModelConfig:
    """Read and validate a model config TOML."""
    return parse_config(read_toml(path, "a model config TOML file"), str(path))


# the vehicle constants every config gives; `Iy` may be left out where no state the data give
# depends on the pitch row (`problem.check_inputs`), `zB` where `GM` is given, and so may the
# metacentric heights `GM`, `GM_L` (docs/model.md#the-equations)
_REQUIRED = ("mass", "Ix", "Iz", "weight", "buoyancy", "xB", "yB", "speed")

# what each vehicle constant must be, beyond a finite number within ±MAX_CONSTANT
_VEHICLE_RANGES = {
    "mass": (0.0, "> 0 (kg)"),
    "Ix": (0.0, "> 0 (kg m²)"),
    "Iy": (0.0, "> 0 (kg m²)"),
    "Iz": (0.0, "> 0 (kg m²)"),
    "weight": (0.0, "> 0 (N)"),
    "buoyancy": (0.0, "> 0 (N)"),
    "speed": (MIN_SPEED, f"{MIN_SPEED:g} to {MAX_SPEED:g} (m/s, the trim speed)"),
}


def parse_config(doc: Mapping, source: str = "<config>") -> ModelConfig:
    """Validate a parsed model-config document."""
    for table in ("vehicle", "coefficients"):
        if not isinstance(doc.get(table), dict):
            raise InputError(f"{source}: table [{table}] missing")
    veh = doc["vehicle"]
    values = {}
    for key in Vehicle.names():
        if key in veh:
            values[key] = number(veh[key], f"{source}: [vehicle] {key}")
        elif key in _REQUIRED or (key == "zB" and "GM" not in veh):
            raise InputError(
                f"{source}: [vehicle] {key} missing; expected a number (SI)"
                + ("" if key in _REQUIRED else ", or GM (a floating body's metacentric height)")
            )
        else:
            values[key] = None
    for key in set(veh) - set(Vehicle.names()):
        raise InputError(
            f"{source}: [vehicle] {key} is not a vehicle constant; "
            f"expected one of {', '.join(Vehicle.names())}"
        )
    coefficients = dict.fromkeys(PARAMETERS, 0.0)
    for key, v in doc["coefficients"].items():
        if key not in coefficients:
            raise InputError(
                f"{source}: [coefficients] {key} is not a coefficient name; expected one of the linear model's 35 coefficients, 6 offsets, 10 output biases, the current, the velocity log's mounting or input_delay (docs/model.md)"
            )
        coefficients[key] = number(v, f"{source}: [coefficients] {key}")
    ident = doc.get("identify", {})
    free = ident.get("free", []) if isinstance(ident, dict) else None
    if not isinstance(free, list) or not all(isinstance(n, str) for n in free):
        raise InputError(f"{source}: [identify] free must be a list of coefficient names")
    outputs = ident.get("outputs") if isinstance(ident, dict) else None
    if outputs is not None:
        if not isinstance(outputs, list) or not all(isinstance(s, str) for s in outputs):
            raise InputError(f"{source}: [identify] outputs must be a list of state names")
        outputs = tuple(s for s in STATES if s in outputs) + tuple(s for s in outputs if s not in STATES)
    noise = ident.get("noise_std") if isinstance(ident, dict) else None
    if noise is not None:
        noise = check_noise_std(noise, f"{source}: [identify] noise_std") or None
    screen = ident.get("screen", False)
    if not isinstance(screen, bool):
        raise InputError(f"{source}: [identify] screen = {screen!r}; expected true or false")
    per_record = ident.get("per_record", []) if isinstance(ident, dict) else []
    if not isinstance(per_record, list) or not all(isinstance(n, str) for n in per_record):
        raise InputError(f"{source}: [identify] per_record must be a list of names from free")
    if isinstance(ident, dict):
        check_keys(ident, IDENTIFY_KEYS, f"{source}: [identify]")
    bounds = _bounds(
        ident.get("bounds", {}) if isinstance(ident, dict) else {}, f"{source}: [identify] bounds"
    )
    physical = ident.get("physical_bounds", True) if isinstance(ident, dict) else True
    if not isinstance(physical, bool):
        raise InputError(f"{source}: [identify] physical_bounds = {physical!r}; expected true or false")
    tables = doc.get("sensors", {})
    if not isinstance(tables, Mapping):
        raise InputError(f"{source}: [sensors] must hold [sensors.NAME] tables")
    sensors = tuple(parse_sensor(k, v, f"{source}: sensors.{k}") for k, v in tables.items())
    for sensor in sensors:
        if set(sensor.outputs) - set(STATES):
            raise InputError(
                f"{source}: sensors.{sensor.name}.outputs {list(sensor.outputs)}; expected states "
                f"({', '.join(STATES)}): the model has no specific force"
            )
    seen = [o for s_ in sensors for o in s_.outputs]
    twice = sorted({o for o in seen if seen.count(o) > 1})
    if twice:
        raise InputError(f"{source}: [sensors] read {twice[0]} twice; expected each state from one sensor")
    terms = doc.get("terms")
    if terms is not None:
        if not isinstance(terms, dict):
            raise InputError(f"{source}: [terms] must be a table of term names and their values")
        terms = {k: number(v, f"{source}: [terms] {json.dumps(k)}") for k, v in terms.items()}
    components = _components(doc.get("components"), terms, source)
    config = ModelConfig(
        Vehicle(**values),
        coefficients,
        tuple(free),
        source,
        outputs,
        noise,
        screen,
        tuple(per_record),
        sensors=sensors,
        terms=terms,
        components=components,
        bounds=bounds,
        physical_bounds=physical,
    )
    check_config(config)
    return config


def _bounds(table, where: str) -> dict[str, tuple[float, float]]:
    """`[identify] bounds` as name → (low, high): a table of names, each `[low, high]`, numbers
    with low < high (`-inf`, `inf`: open)."""
    if not isinstance(table, Mapping):
        raise InputError(f"{where} = {reprlib.repr(table)}; expected a table of names, each [low, high]")
    out = {}
    for name, pair in table.items():
        if not (isinstance(pair, list) and len(pair) == 2):
            raise InputError(f"{where}.{name} = {reprlib.repr(pair)}; expected [low, high]")
        low, high = (
            float(v) if isinstance(v, float) and math.isinf(v) else number(v, f"{where}.{name}") for v in pair
        )
        if not low < high:
            raise InputError(f"{where}.{name} = [{low:g}, {high:g}]; expected low < high")
        out[str(name)] = (low, high)
    return out


# the [identify] table's keys
IDENTIFY_KEYS = ("free", "outputs", "noise_std", "screen", "per_record", "bounds", "physical_bounds")
# a [components.NAME] table's keys: the required, then the optional (a fin blade's hinge)
COMPONENT_KEYS = ("axes", "centre", "frame", "moments", "density", "added_mass")

BLADE_KEYS = ("fin", "hinge", "hinge_axis")


def _components(tables, terms, source: str) -> tuple[Component, ...]:
    """The [components.NAME] tables as `Component`s; `InputError` naming the table and key."""
    if tables is None:
        return ()
    if terms is None:
        raise InputError(
            f"{source}: [components] in a linear model config; expected them only beside [terms] "
            "(the nonlinear model's component terms name them)"
        )
    if not isinstance(tables, Mapping) or not all(isinstance(t, Mapping) for t in tables.values()):
        raise InputError(f"{source}: [components] must hold [components.NAME] tables")
    out = []
    for name, table in tables.items():
        check_component_name(name, f"{source}: [components]")
        where = f"{source}: [components.{name}]"
        check_keys(table, COMPONENT_KEYS + BLADE_KEYS, where)
        missing = [k for k in COMPONENT_KEYS if k not in table]
        if missing:
            raise InputError(f"{where} {missing[0]} missing; expected {', '.join(COMPONENT_KEYS)}")
        stray = [k for k in BLADE_KEYS if k in table and "fin" not in table]
        if stray:
            raise InputError(
                f"{where} {stray[0]} without fin; expected a blade's hinge with its fin (dr, der, del)"
            )
        values = {k: table[k] for k in COMPONENT_KEYS + BLADE_KEYS if k in table}
        for k, v in values.items():
            if k == "fin":
                continue
            if k == "density":
                values[k] = number(v, f"{where} density")
            elif isinstance(v, list):
                rows = v if k == "frame" else [v]
                for row in rows:
                    if not isinstance(row, list):
                        raise InputError(f"{where} {k} = {v!r}; expected rows of numbers")
                    for x in row:
                        number(x, f"{where} {k}")
            else:
                raise InputError(f"{where} {k} = {v!r}; expected a list of numbers")
        try:
            out.append(Component(name=name, **values))
        except InputError as exc:
            raise InputError(f"{where}: {exc}") from None
    return tuple(out)


def check_config(config: ModelConfig) -> None:
    """`InputError` unless `config` holds a physical vehicle (`_VEHICLE_RANGES`), the model's
    parameters (`PARAMETERS`) as finite numbers within ±`MAX_CONSTANT`, and distinct free names."""
    source = config.source or "config"
    for key in Vehicle.names():
        if getattr(config.vehicle, key) is None and (
            key not in _REQUIRED + ("zB",) or config.vehicle.GM is not None
        ):
            continue  # an optional constant left out
        v = number(getattr(config.vehicle, key), f"{source}: [vehicle] {key}")
        low, expected = _VEHICLE_RANGES.get(key, (None, ""))
        high = MAX_SPEED if key == "speed" else math.inf
        if low is not None and not ((v > low if low == 0.0 else v >= low) and v <= high):
            raise InputError(f"{source}: [vehicle] {key} = {v:g}; expected {expected}")
    for key, v in config.coefficients.items():
        if key not in PARAMETERS:
            raise InputError(
                f"{source}: [coefficients] {key} is not a coefficient name; expected one of the linear model's 35 coefficients, 6 offsets, 10 output biases, the current, the velocity log's mounting or input_delay (docs/model.md)"
            )
        number(v, f"{source}: [coefficients] {key}")
        if key in MOUNTING and not abs(v) <= MOUNTING_LIMITS[key]:
            unit = "rad (a small misalignment)" if key.startswith("m_") else "m from the CG"
            raise InputError(
                f"{source}: [coefficients] {key} = {v:g}; expected within ±{MOUNTING_LIMITS[key]:g} {unit}"
            )
    if config.terms is not None:
        _check_terms(config, source)
    else:
        check_free(config.free, f"{source}: [identify] free")
    check_per_record(config.per_record, config.free, f"{source}: [identify] per_record")
    if config.outputs is not None and (not config.outputs or any(s not in STATES for s in config.outputs)):
        raise InputError(
            f"{source}: [identify] outputs = {list(config.outputs)!r}; expected a non-empty "
            f"list of states ({', '.join(STATES)})"
        )
    if config.noise_std is not None:
        check_noise_std(config.noise_std, f"{source}: [identify] noise_std")
    for n, (low, high) in config.bounds.items():
        where = f"{source}: [identify] bounds.{n}"
        if n not in config.free:
            raise InputError(f"{where}: not a free name; expected a name of [identify] free")
        value = config.values[n]
        if not low <= value <= high:
            raise InputError(
                f"{where} = [{low:g}, {high:g}]: its a-priori value {value:g} lies outside; expected a box holding it"
            )


def check_noise_std(noise, where: str) -> dict[str, float]:
    """`noise` as a dict state → σ in `STATES` order once it is a mapping of state names to
    numbers from `MIN_NOISE_STD` to `MAX_DATA` (SI); InputError naming `where` and the first
    entry that is not."""
    if not isinstance(noise, Mapping):
        shown = str(noise).lower() if isinstance(noise, bool) else repr(noise)[:40]
        raise InputError(
            f"{where} = {shown}; expected a table of state = σ (SI), e.g. {{r = 0.002, psi = 0.01}}"
        )
    for name, v in noise.items():
        if name not in STATES:
            raise InputError(f"{where} names {str(name)[:40]!r}, not a state (one of {', '.join(STATES)})")
        v = number(v, f"{where}: {name}")
        if not MIN_NOISE_STD <= v <= MAX_DATA:
            raise InputError(
                f"{where}: {name} = {v:g}; expected a σ from {MIN_NOISE_STD:g} to {MAX_DATA:g} (SI)"
            )
    return {s: float(noise[s]) for s in STATES if s in noise}


def parse_sensor(name: str, doc, where: str, keys: Sequence[str] = CONFIG_SENSOR_KEYS) -> Sensor:
    """The `Sensor` of a `[sensors.NAME]` table with the keys `keys` (`where`: the file and
    table, for messages)."""
    check_name(name, f"{where}: sensor name")
    if not isinstance(doc, Mapping):
        raise InputError(f"{where}: expected a table")
    check_keys(doc, keys, where)
    outs = doc.get("outputs")
    if not isinstance(outs, list) or not all(isinstance(o, str) for o in outs):
        raise InputError(f"{where}.outputs = {outs!r}; expected a list of {', '.join(OUTPUTS)}")
    kw = {"outputs": tuple(outs)}
    for key in ("position", "misalignment"):
        if key in doc:
            v = doc[key]
            if not isinstance(v, list) or len(v) != 3:
                raise InputError(f"{where}.{key} = {v!r}; expected a list of three numbers")
            kw[key] = tuple(number(a, f"{where}.{key}") for a in v)
    if "frame" in doc:
        kw["frame"] = doc["frame"]
    for key in ("delay", "rate"):
        if key in doc:
            kw[key] = number(doc[key], f"{where}.{key}")
    if "hold" in doc:
        kw["hold"] = doc["hold"]
    for key in ("bias", "scale", "noise_std", "resolution"):
        table = doc.get(key, {})
        if not isinstance(table, Mapping):
            raise InputError(f"{where}.{key}: expected a table of output = value")
        kw[key] = {o: number(v, f"{where}.{key}.{o}") for o, v in table.items()}
    try:
        return Sensor(name=name, **kw)
    except InputError as exc:
        raise InputError(f"{where.rsplit(': ', 1)[0]}: {exc}") from None


def check_free(free: Sequence[str], where: str) -> tuple[str, ...]:
    """`free` as a tuple once every entry is a coefficient or offset name (`PARAMETERS`) listed
    once; InputError naming `where` and the first entry that is not."""
    seen = set()
    for n in free:
        if n not in PARAMETERS:
            raise InputError(
                f"{where} names {n!r}, not a coefficient (one of {', '.join(COEFFICIENTS)}), "
                f"an offset (one of {', '.join(OFFSETS)}), an output bias (b_ and a state), the current (c_N, c_E), "
                f"the velocity log's mounting ({', '.join(MOUNTING)}) or input_delay"
            )
        if n in seen:
            raise InputError(f"{where} names a coefficient twice ({n})")
        seen.add(n)
    return tuple(free)


def check_per_record(per_record: Sequence[str], free: Sequence[str], where: str) -> tuple[str, ...]:
    """`per_record` as a tuple once every entry is a free name listed once; InputError naming
    `where` and the first entry that is not."""
    seen = set()
    for n in per_record:
        if n not in free:
            raise InputError(f"{where} names {n[:40]!r}, which free does not list; expected names from free")
        if n in seen:
            raise InputError(f"{where} names {n} twice")
        seen.add(n)
    return tuple(per_record)


def _check_terms(config: ModelConfig, source: str) -> None:
    """`InputError` unless a nonlinear model config's terms make a nonlinear model of its vehicle
    (`models.nonlinear.nonlinear_model`: term names, each once, a submerged body), with finite
    values, its linear parameters but the inertia coefficients and the output biases 0, and
    `free` among its names and the output biases."""
    names = [c.name for c in config.components]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise InputError(f"{source}: [components.{twice[0]}] given twice; expected each component once")
    try:
        model = nonlinear_model(config.vehicle, tuple(config.terms), config.components)
    except InputError as exc:
        raise InputError(f"{source}: [terms] {exc}") from None
    for key, v in config.terms.items():
        number(v, f"{source}: [terms] {json.dumps(key)}")
    extra = [k for k, v in config.coefficients.items() if v != 0.0 and k not in INERTIA + OUTSIDE_EQUATIONS]
    if extra:
        raise InputError(
            f"{source}: [coefficients] {extra[0]} in a nonlinear model config (one with [terms]); "
            f"expected only the inertia coefficients ({', '.join(INERTIA)}), the output biases "
            "(b_ and a state), the velocity log's mounting, the current and input_delay, the rest in [terms]"
        )
    seen = set()
    for n in config.free:
        if n not in model.names + OUTSIDE_EQUATIONS or n in seen:
            raise InputError(
                f"{source}: [identify] free names {n[:40]!r}"
                + (
                    " twice"
                    if n in seen
                    else ", not an inertia coefficient, an output bias, the velocity log's mounting, "
                    "the current, input_delay or one of [terms]"
                )
                + "; expected each of the model's names once"
            )
        seen.add(n)


def number(v, where: str) -> float:
    """`v` as a float; `InputError` unless it is a finite number within ±`MAX_CONSTANT`."""
    if isinstance(v, bool) or not isinstance(v, numbers.Real):
        shown = str(v).lower() if isinstance(v, bool) else repr(v)[:40]  # as TOML writes it
        raise InputError(f"{where} = {shown}; expected a finite number")
    if isinstance(v, numbers.Integral):  # an integer of any size: compared before it becomes a float
        value = float(v) if abs(v) <= MAX_CONSTANT else math.inf
        shown = str(v) if len(str(v)) <= 20 else f"an integer of {len(str(abs(v)))} digits"
    else:
        value, shown = float(v), str(v)
        if not math.isfinite(value):
            raise InputError(f"{where} = {v!r}; expected a finite number")
    if abs(value) > MAX_CONSTANT:
        raise InputError(f"{where} = {shown}; expected a magnitude of at most {MAX_CONSTANT:g} (SI)")
    return value
