"""Virtual captive tests: the vehicle held in prescribed motion, the water's force on it read.

A towing tank holds a model in a prescribed motion and measures the forces; here the motion is
set on the completed plant and the force read by `hydrodynamic_wrench` (body axes FRD, about the
CG; weight, buoyancy, rigid-body inertia and thrust not in it). Every test holds the surge speed
u at each of its `speeds` and varies the rest:

- a static test (`Sweep`) holds each point of a grid of body velocities and fin angles, at zero
  acceleration: static drift (v), incidence (w), the rotating arm (p, q, r), combined drift and
  yaw (v × r) or incidence and pitch (w × q), fin sweeps (rudder, elevators together or
  differential) and any other grid of the `VARIABLES`; a grid may follow a line (`follow`), a
  variable offset by a ratio times another: a turn, the drift and the rudder of a steady turn at
  each rate and the grid around them, as a rotating arm with drift angles bracketing the turn's;
- an oscillatory test (`Oscillation`, a planar motion mechanism) varies one body velocity as
  a sin(ω t) over one period in body axes (pure sway v, heave w, roll p, yaw r, pitch q: the
  others held, u included; pure surge: u about the held speed), sampled at `samples` instants;
  `pmm_coefficients` splits the force into its in-phase and quadrature parts.

The plant's fluid model has no memory (its forces depend on the instantaneous ν, ν̇, δ), so an
oscillatory test reads the same forces a static one would at those states, plus −M_A ν̇.
`captive_tests` runs a set and returns one `Measurement` per test and speed: the prescribed
ν, ν̇, δ and the wrench, row by row, ready for a least-squares fit of a force model.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np

from testbed.errors import InputError
from testbed.models.linear import INPUTS
from testbed.captive.wrench import hydrodynamic_wrench

__all__ = [
    "DEFAULT_TESTS",
    "OSCILLATIONS",
    "SPEEDS",
    "SWEEPS",
    "VARIABLES",
    "Measurement",
    "Oscillation",
    "Sweep",
    "captive_tests",
    "pmm_coefficients",
]

# What a test can vary: a body velocity (its index in ν = u v w p q r), or a fin direction over
# (delta_r, delta_er, delta_el): a fin alone, the elevators together (delta_e: δer = δel, pitch)
# or differentially (delta_d: δer = −δel, roll).
_RATES = {"v": 1, "w": 2, "p": 3, "q": 4, "r": 5}
_OSCILLATING = {"u": 0, **_RATES}  # an oscillation may also vary the surge speed about the held one
_FINS = {
    "delta_r": (1.0, 0.0, 0.0),
    "delta_er": (0.0, 1.0, 0.0),
    "delta_el": (0.0, 0.0, 1.0),
    "delta_e": (0.0, 1.0, 1.0),
    "delta_d": (0.0, 1.0, -1.0),
}
VARIABLES = tuple(_RATES) + tuple(_FINS)
_ROWS = "XYZKMN"  # the wrench's rows: force X Y Z, moment K M N

# Scenario I flies the torpedo at 16.4-20 m/s with |v|, |w| up to about 2 m/s, |p|, |q|, |r| up
# to 1.7 rad/s and fins to their 0.40 rad stops: the defaults cover that with a margin.
SPEEDS = (15.0, 17.5, 20.0)


def _check_speeds(name: str, speeds) -> tuple[float, ...]:
    out = tuple(float(s) for s in speeds)
    if not out or not all(0 <= s < math.inf for s in out):
        raise InputError(f"{name}: speeds={speeds!r}; expected one or more finite speeds >= 0 m/s")
    return out


@dataclass(frozen=True, kw_only=True)
class Sweep:
    """A static captive test: the grid of `vary` (names from `VARIABLES`), each from −extent to
    +extent in `points` steps (m/s, rad/s or rad as the variable), at each of `speeds` (u, m/s),
    the rest of ν and the fins at 0, ν̇ = 0. `follow` offsets the grid along lines: each
    (variable, leader, ratio), both in `vary`, adds ratio × the leader's value to the variable's
    (a turn: `("v", "r", -1.4)` holds v = −1.4 r + the grid's v)."""

    name: str
    vary: tuple[str, ...]
    extent: tuple[float, ...]
    points: tuple[int, ...]
    speeds: tuple[float, ...] = SPEEDS
    follow: tuple[tuple[str, str, float], ...] = ()

    def __post_init__(self):
        where = f"captive test {self.name!r}"
        if not self.vary or len(set(self.vary)) != len(self.vary):
            raise InputError(
                f"{where}: vary={self.vary!r}; expected distinct names from {', '.join(VARIABLES)}"
            )
        for v in self.vary:
            if v not in VARIABLES:
                raise InputError(f"{where}: vary {v!r}; expected one of {', '.join(VARIABLES)}")
        if not len(self.extent) == len(self.points) == len(self.vary):
            raise InputError(f"{where}: {len(self.vary)} variables; expected an extent and points for each")
        if not all(0 <= e < math.inf for e in self.extent):
            raise InputError(f"{where}: extent={self.extent!r}; expected finite extents >= 0")
        if not all(isinstance(n, int) and n >= 1 for n in self.points):
            raise InputError(f"{where}: points={self.points!r}; expected whole numbers >= 1")
        object.__setattr__(self, "speeds", _check_speeds(where, self.speeds))
        follow = tuple((str(a), str(b), float(k)) for a, b, k in self.follow)
        for a, b, k in follow:
            if a not in self.vary or b not in self.vary or a == b or not math.isfinite(k):
                raise InputError(
                    f"{where}: follow ({a!r}, {b!r}, {k!r}); expected two different varied names "
                    "and a finite ratio"
                )
        if len({a for a, _, _ in follow}) != len(follow) or {a for a, _, _ in follow} & {
            b for _, b, _ in follow
        }:
            raise InputError(
                f"{where}: follow={follow!r}; expected each variable to follow one leader that follows none"
            )
        object.__setattr__(self, "follow", follow)

    def axes(self) -> tuple[np.ndarray, ...]:
        """Each variable's values on the grid, from −extent to +extent (0 alone for one point)."""
        return tuple(
            np.linspace(-e, e, n) if n > 1 else np.zeros(1) for e, n in zip(self.extent, self.points)
        )

    def states(self, speed: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(ν, ν̇, δ) of every grid point at `speed`, row by row (the last variable fastest)."""
        grid = np.array(list(itertools.product(*self.axes()))).reshape(-1, len(self.vary))
        lead = grid.copy()
        for a, b, k in self.follow:
            grid[:, self.vary.index(a)] += k * lead[:, self.vary.index(b)]
        nu, fins = np.zeros((len(grid), 6)), np.zeros((len(grid), len(INPUTS)))
        nu[:, 0] = speed
        for k, v in enumerate(self.vary):
            if v in _RATES:
                nu[:, _RATES[v]] = grid[:, k]
            else:
                fins += np.outer(grid[:, k], _FINS[v])
        return nu, np.zeros_like(nu), fins


@dataclass(frozen=True, kw_only=True)
class Oscillation:
    """An oscillatory (PMM) test: ν_k = `amplitude` sin(ω t), ω = 2π/`period`, for `variable`
    (one of v w p q r; m/s or rad/s), sampled at t = i·period/`samples`, i = 0 … samples − 1,
    the rest of ν and the fins at 0, u held at each of `speeds`; for `variable` u (pure surge)
    u = speed + `amplitude` sin(ω t)."""

    name: str
    variable: str
    amplitude: float
    period: float = 4.0
    samples: int = 32
    speeds: tuple[float, ...] = SPEEDS

    def __post_init__(self):
        where = f"captive test {self.name!r}"
        if self.variable not in _OSCILLATING:
            raise InputError(
                f"{where}: variable {self.variable!r}; expected one of {', '.join(_OSCILLATING)}"
            )
        if not 0 < self.amplitude < math.inf:
            raise InputError(f"{where}: amplitude={self.amplitude!r}; expected a finite amplitude > 0")
        if not 0 < self.period < math.inf:
            raise InputError(f"{where}: period={self.period!r}; expected a finite period > 0 s")
        if not isinstance(self.samples, int) or self.samples < 4:
            raise InputError(f"{where}: samples={self.samples!r}; expected a whole number >= 4")
        object.__setattr__(self, "speeds", _check_speeds(where, self.speeds))

    @property
    def omega(self) -> float:
        """ω, rad/s."""
        return 2 * math.pi / self.period

    def times(self) -> np.ndarray:
        """The sample instants t (s) over one period."""
        return self.period * np.arange(self.samples) / self.samples

    def states(self, speed: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(ν, ν̇, δ) at the sample instants at `speed`."""
        phase = self.omega * self.times()
        nu, nu_dot = np.zeros((self.samples, 6)), np.zeros((self.samples, 6))
        nu[:, 0] = speed
        k = _OSCILLATING[self.variable]
        nu[:, k] += self.amplitude * np.sin(phase)
        nu_dot[:, k] = self.amplitude * self.omega * np.cos(phase)
        return nu, nu_dot, np.zeros((self.samples, len(INPUTS)))


@dataclass(frozen=True)
class Measurement:
    """One test at one speed: the prescribed states and the wrench read, one row per point.
    Body axes FRD about the CG; u absolute."""

    test: str  # the test's name
    speed: float  # u held, m/s
    nu: np.ndarray = field(repr=False)  # (n, 6) u v w p q r, m/s and rad/s
    nu_dot: np.ndarray = field(repr=False)  # (n, 6) their rates, m/s² and rad/s²
    fins: np.ndarray = field(repr=False)  # (n, 3) delta_r delta_er delta_el, rad
    wrench: np.ndarray = field(repr=False)  # (n, 6) X Y Z K M N, N and N m


SWEEPS = (
    Sweep(name="drift", vary=("v",), extent=(3.0,), points=(25,)),
    Sweep(name="incidence", vary=("w",), extent=(3.0,), points=(25,)),
    Sweep(name="roll_rate", vary=("p",), extent=(2.0,), points=(21,)),
    Sweep(name="pitch_rate", vary=("q",), extent=(2.0,), points=(21,)),
    Sweep(name="yaw_rate", vary=("r",), extent=(2.0,), points=(21,)),
    Sweep(name="drift_yaw", vary=("v", "r"), extent=(3.0, 2.0), points=(13, 11)),
    Sweep(name="incidence_pitch", vary=("w", "q"), extent=(3.0, 2.0), points=(13, 11)),
    Sweep(name="rudder", vary=("delta_r",), extent=(0.4,), points=(17,)),
    Sweep(name="elevator", vary=("delta_e",), extent=(0.4,), points=(17,)),
    Sweep(name="differential", vary=("delta_d",), extent=(0.4,), points=(17,)),
    Sweep(name="drift_rudder", vary=("v", "delta_r"), extent=(3.0, 0.4), points=(13, 9)),
    Sweep(name="incidence_elevator", vary=("w", "delta_e"), extent=(3.0, 0.4), points=(13, 9)),
)
OSCILLATIONS = (
    Oscillation(name="pure_surge", variable="u", amplitude=2.0),
    Oscillation(name="pure_sway", variable="v", amplitude=2.0),
    Oscillation(name="pure_heave", variable="w", amplitude=2.0),
    Oscillation(name="pure_roll", variable="p", amplitude=1.5),
    Oscillation(name="pure_pitch", variable="q", amplitude=1.5),
    Oscillation(name="pure_yaw", variable="r", amplitude=1.5),
)
DEFAULT_TESTS = SWEEPS + OSCILLATIONS


def captive_tests(vehicle, tests=DEFAULT_TESTS) -> tuple[Measurement, ...]:
    """Run `tests` (`Sweep`s and `Oscillation`s) on `vehicle` (a `Plant` or an `MjModel`, as
    `hydrodynamic_wrench` takes it; its fins are the bundled torpedo's three): one `Measurement`
    per test and speed, in that order."""
    names = [t.name for t in tests]
    if len(set(names)) != len(names):
        raise InputError(f"captive tests: names {names}; expected each name once")
    out = []
    for test in tests:
        if not isinstance(test, (Sweep, Oscillation)):
            raise InputError(f"captive tests: {test!r}; expected a Sweep or an Oscillation")
        for speed in test.speeds:
            nu, nu_dot, fins = test.states(speed)
            wrench = hydrodynamic_wrench(vehicle, nu, fins, nu_dot)
            out.append(Measurement(test.name, speed, nu, nu_dot, fins, wrench))
    return tuple(out)


def pmm_coefficients(test: Oscillation, measurement: Measurement) -> dict[str, float]:
    """The first harmonic of each wrench row of an oscillatory test, as derivatives.

    With x = a sin ωt the variable and F a row: the in-phase part (2/N) Σ F sin ωt over a
    period, divided by a, is the velocity derivative at this amplitude (`Y_v` for pure sway: the
    exact slope at a → 0, an amplitude-weighted one where F is nonlinear in x); the quadrature
    part (2/N) Σ F cos ωt, divided by a ω, the acceleration derivative (`Y_vdot` = −M_A entry).
    Any function of x alone has no quadrature part, so the latter is exact at any amplitude.
    """
    x = test.variable
    k = _OSCILLATING[x]
    if measurement.test != test.name or len(measurement.nu) != test.samples:
        raise InputError(f"measurement of {measurement.test!r}; expected one of test {test.name!r}")
    a, n = test.amplitude, test.samples
    sin = (measurement.nu[:, k] - (measurement.speed if k == 0 else 0.0)) / a
    cos = measurement.nu_dot[:, k] / (a * test.omega)
    out = {}
    for row, F in zip(_ROWS, measurement.wrench.T):
        out[f"{row}_{x}"] = float(2 / n * F @ sin / a)
        out[f"{row}_{x}dot"] = float(2 / n * F @ cos / (a * test.omega))
    return out
