"""The data-compatibility checks and their results (`compatibility` module doc): the attitude
and depth checks (`Check`: the channels that drive each, the outputs it reconstructs, its sensor
parameters), a fitted parameter, a reconstruction and the whole result (`Compatibility`), with
the limits every fitted or applied parameter keeps.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Mapping

__all__ = [
    "LEVER_ARMS",
    "ATTITUDE",
    "CHECKS",
    "Check",
    "Compatibility",
    "DEPTH",
    "HELD_FIRST",
    "MAX_ARM",
    "MAX_CORRELATION",
    "MAX_DELAY",
    "BRIDGED_GAP",
    "MAX_MISALIGNMENT",
    "MAX_OFFSET",
    "MAX_PITCH",
    "MAX_SCALE",
    "MIN_CHECKED_ROWS",
    "MIN_SIGNAL",
    "MISALIGNMENTS",
    "ATTITUDE_OFFSETS",
    "Parameter",
    "REGRESSORS",
    "Reconstruction",
    "SENSOR_PARAMETERS",
    "SIGNIFICANCE",
    "SINGULAR",
    "COMPLEX_STEP",
    "limit_of",
    "parameter_cell",
]


MAX_DELAY = 1.0  # s: the largest sensor delay fitted or applied, either sign


MAX_SCALE = 0.5  # the largest |k| of a scale factor fitted or applied (1 + k within 0.5-1.5)


MAX_MISALIGNMENT = 0.5  # rad: the largest misalignment fitted or applied (a scenario's limit)


SIGNIFICANCE = 2.0  # a parameter within this many σ of 0 is held at 0 (the coefficients' screen)


SINGULAR = 1e-10  # an eigenvalue of the scaled Fisher information below this × the largest: singular


# Of the parameters within SIGNIFICANCE σ of 0, scale factors are held first, then
# misalignments, delays, then biases: a constant velocity makes its bias and scale factor (or a
# misalignment turning it into another channel) nearly one parameter (u ≈ 20 m/s), and a bias
# is the commoner error, present whether the channel varies or not.
# The attitude offsets come last (`_rank`): with u near constant the log's w bias makes nearly
# the sink rate of a pitch offset, and an AHRS mounted off its axes is the commoner error.
HELD_FIRST = ("k_", "m_", "r_", "tau_", "b_")


MAX_ARM = 50.0  # m: the largest |r| of a lever arm fitted or applied


COMPLEX_STEP = 1e-30  # the complex step: exact derivatives (no difference is taken)


# A scale factor multiplies its channel, a delay its channel's rate of change, the log's u and v
# biases sin θ and sin φ: a parameter whose regressor is mostly the noise of a measured channel
# would be fitted to that noise (errors in variables: on a level run, where θ is its noise, the
# depth follows no −u sin θ and b_u goes to u). Such a parameter is held, not identifiable,
# unless some record has, for one of its alternatives, every channel's signal (the standard
# deviation of the channel less its noise) at least `MIN_SIGNAL` times its noise.
REGRESSORS = {
    "k_p": (("p",),),
    "k_q": (("q",),),
    "k_r": (("r",),),
    "tau_gyro": (("p",), ("q",), ("r",)),
    "b_u": (("theta",),),
    "k_u": (("theta",),),
    "b_v": (("phi",),),
    "k_v": (("v", "phi"),),
    "k_w": (("w",),),
    "tau_dvl": (("w",), ("u", "theta"), ("v", "phi")),
    "b_phi": (("v",), ("w",)),
    "m_dvl_z": (("phi",),),
    "r_dvl_x": (("theta",),),
    "r_dvl_y": (("phi",),),
    "r_dvl_z": (("phi",), ("theta",)),
}


MIN_SIGNAL = 3.0


MAX_PITCH = 1.5  # rad (86°): beyond, the attitude check is not run (tan θ, 1 / cos θ near ±π/2)


# A sensor parameter correlated with an attitude offset beyond this is held (`_inseparable`).
MAX_CORRELATION = 0.99


MAX_OFFSET = math.pi  # rad: the largest |b| of an attitude offset applied


# A driving or used channel's gap (between two samples present) is bridged by its cubic spline
# when it is at most BRIDGED_GAP times the channel's median interval in the record: a sensor's
# dropped sample or two; a longer gap splits the record, the stretch across it left unchecked.
BRIDGED_GAP = 3.0


MIN_CHECKED_ROWS = 4  # a stretch between gaps is checked when its outputs have at least this many rows


@dataclass(frozen=True)
class Check:
    """One kinematic check: the channels that drive it (corrected by their sensors' parameters),
    the measured channels it uses (corrected by their offsets), the outputs it reconstructs and
    the parameters."""

    name: str
    drives: tuple[str, ...]
    uses: tuple[str, ...]
    outputs: tuple[str, ...]
    initial: tuple[str, ...]
    delay: str
    axes: tuple[str, ...] = ()  # the body axes about which the driving sensor may be misaligned
    arm: bool = False  # the driving sensor's position (its lever arm) among the parameters

    @property
    def sensor(self) -> tuple[str, ...]:
        """The sensor parameters: each driving channel's bias and scale factor, the delay, each
        used channel's offset, the driving sensor's misalignment about each of `axes`, its
        position along x, y, z where it has an `arm`."""
        group = self.delay.removeprefix("tau_")
        return (
            tuple(f"b_{c}" for c in self.drives)
            + tuple(f"k_{c}" for c in self.drives)
            + (self.delay,)
            + tuple(f"b_{c}" for c in self.uses)
            + tuple(f"m_{group}_{a}" for a in self.axes)
            + (tuple(f"r_{group}_{a}" for a in "xyz") if self.arm else ())
        )

    @property
    def needs(self) -> tuple[str, ...]:
        return self.drives + self.uses + self.outputs


ATTITUDE = Check(
    name="attitude",
    drives=("p", "q", "r"),
    uses=(),
    outputs=("phi", "theta", "psi"),
    initial=("phi0", "theta0", "psi0"),
    delay="tau_gyro",
)


DEPTH = Check(
    name="depth",
    drives=("u", "v", "w"),
    uses=("phi", "theta"),
    outputs=("z",),
    initial=("z0",),
    delay="tau_dvl",
    axes=("y", "z"),
    arm=True,
)


CHECKS = (ATTITUDE, DEPTH)


SENSOR_PARAMETERS = ATTITUDE.sensor + DEPTH.sensor


ATTITUDE_OFFSETS = tuple(f"b_{c}" for check in CHECKS for c in check.uses)  # the attitude offsets


MISALIGNMENTS = tuple(n for check in CHECKS for n in check.sensor if n.startswith("m_"))


LEVER_ARMS = tuple(n for check in CHECKS for n in check.sensor if n.startswith("r_"))  # lever arms, m


@dataclass(frozen=True)
class Parameter:
    """An estimate: its value, its Cramér-Rao σ (inf where the data cannot determine it), and
    whether it was fitted; a parameter the screen held at 0 has `estimated` False and `reason`."""

    value: float
    std: float
    estimated: bool = True
    reason: str = ""

    def to_dict(self) -> dict:
        d = {
            "value": self.value,
            "std": self.std if math.isfinite(self.std) else None,
            "identifiable": self.estimated,
        }
        return d | ({"reason": self.reason} if self.reason else {})


@dataclass(frozen=True)
class Reconstruction:
    """One check fitted on one or more records.

    Attributes:
        check: the check's name (`attitude`, `depth`).
        records: the records fitted (one set of sensor parameters for all).
        parameters: sensor parameter → estimate (held at 0 where the screen says so).
        initial: record → initial state → estimate.
        fit: output → {`noise_std`: its measurement noise (read off the data), `residual_std`
            and `fit_percent`: the RMS of y − ŷ and 100 (1 − ‖y − ŷ‖ / ‖y − ȳ‖) of the
            reconstruction run open loop at the estimate (None for a constant channel),
            `innovation_rms`: the RMS of the filter's whitened innovations (≈ 1)}.
        iterations: the Gauss-Newton function evaluations over every fit of the screen.
    """

    check: str
    records: tuple[str, ...]
    parameters: Mapping[str, Parameter]
    initial: Mapping[str, Mapping[str, Parameter]]
    fit: Mapping[str, Mapping[str, float | None]]
    iterations: int

    def to_dict(self) -> dict:
        return {
            "records": list(self.records),
            "parameters": {n: p.to_dict() for n, p in self.parameters.items()},
            "initial": {r: {n: p.to_dict() for n, p in v.items()} for r, v in self.initial.items()},
            "fit": {c: dict(v) for c, v in self.fit.items()},
            "iterations": self.iterations,
        }


@dataclass(frozen=True)
class Compatibility:
    """The checks of a set of records: each record alone and all pooled.

    Attributes:
        records: record → check name → its reconstruction.
        pooled: check name → the reconstruction of every record that has the check's channels.
        unchecked: record → check name → why it was not checked, wholly (missing channels)
            or over the stretches it names (gaps too long to bridge, rows past a channel's
            last sample).
    """

    records: Mapping[str, Mapping[str, Reconstruction]]
    pooled: Mapping[str, Reconstruction]
    unchecked: Mapping[str, Mapping[str, str]]

    @property
    def corrections(self) -> dict[str, float]:
        """The pooled sensor parameters (0 where held), what `corrected` applies."""
        return {n: p.value for r in self.pooled.values() for n, p in r.parameters.items()}

    def to_dict(self) -> dict:
        return {
            "corrections": self.corrections,
            "pooled": {c: r.to_dict() for c, r in self.pooled.items()},
            "records": {
                name: {c: r.to_dict() for c, r in checks.items()} for name, checks in self.records.items()
            },
            "unchecked": {name: dict(why) for name, why in self.unchecked.items() if why},
        }

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2, allow_nan=False) + "\n"

    def table(self) -> str:
        """The pooled sensor parameters, per record beside them, and each output's fit."""
        names = list(self.records)
        lines = []
        for check, pooled in self.pooled.items():
            lines.append(f"{check} check ({', '.join(pooled.records)}):")
            head = f"  {'parameter':<10}{'pooled':>24}" + "".join(f"{n[-22:]:>24}" for n in names)
            lines.append(head)
            for n, p in pooled.parameters.items():
                row = f"  {n:<10}{parameter_cell(p):>24}"
                for name in names:
                    r = self.records[name].get(check)
                    row += f"{parameter_cell(r.parameters[n]) if r else '—':>24}"
                lines.append(row)
            for c, f in pooled.fit.items():
                fit = "—" if f["fit_percent"] is None else f"{f['fit_percent']:.2f} %"
                lines.append(
                    f"  {c:<10}fit {fit}, residual σ {f['residual_std']:.3g} (noise σ {f['noise_std']:.3g})"
                )
        for name, why in self.unchecked.items():
            for check, reason in why.items():
                lines.append(f"{name}: {check} not checked: {reason}")
        return "\n".join(lines) + "\n"


def parameter_cell(p: Parameter) -> str:
    if not p.estimated:
        return "0 (held)"
    return f"{p.value:.4g} ± {p.std:.2g}"


def limit_of(name: str) -> float | None:
    """The largest |value| of a sensor parameter fitted or applied: a delay `MAX_DELAY` s, a
    scale factor `MAX_SCALE`, a misalignment `MAX_MISALIGNMENT` rad, a lever arm `MAX_ARM` m;
    None for a bias or an attitude offset."""
    if name.startswith("tau_"):
        return MAX_DELAY
    if name.startswith("k_"):
        return MAX_SCALE
    if name in MISALIGNMENTS:
        return MAX_MISALIGNMENT
    return MAX_ARM if name in LEVER_ARMS else None
