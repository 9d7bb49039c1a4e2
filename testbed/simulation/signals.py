"""Input signals of the scenario files: what a fin or an autopilot reference does over time.

Each signal is a frozen dataclass built by keyword from its TOML table (`parse_signal`) and
written back by `signal_table`; `Signal.program(rng)` gives the function `(t, x) → value` that
the experiment calls at every control step (`x` the state the autopilots read, in `STATES` order:
the true one or the sensors' reading, the scenario's `feedback`; only `zigzag` reads it). The signals:

| signal | parameters | value |
|---|---|---|
| `hold` | `value` | constant |
| `step` | `amplitude`, `start`, `initial` | `initial` before `start`, then `amplitude` |
| `square` | `amplitude`, `half_period`, `offset`, `first` | `offset ± amplitude`, switched every `half_period`, `first` (±1) the first sign |
| `prbs` | `amplitude`, `order`, `clock` | ±`amplitude`, a maximal-length LFSR sequence, one bit per `clock` s, phase from the run's seed |
| `doublet` | `amplitude`, `width`, `start` | +a for `width`, −a for `width`, then 0 |
| `3211` | `amplitude`, `unit`, `start` | +a, −a, +a, −a for 3, 2, 1, 1 `unit`s, then 0 |
| `multisine` | `amplitude`, `frequencies`, `start`, `phases` | Σ cos(2π f_k t + φ_k), scaled to peak `amplitude`; `phases` `schroeder` (φ_k = −π k(k−1)/K, low crest factor) or `min-crest` (the smallest crest factor found from them, `min_crest_phases`) |
| `zigzag` | `angle`, `on`, `switch` | ±`angle`, switched when `on` (`psi` or `theta`) passes ∓`switch` (default `angle`) from its initial value |

A positive fin turns the nose negative (rudder: to port; elevators: down), so the zigzag
starts at +angle and switches when the angle has gone to −angle.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, fields
from typing import Callable, ClassVar, Mapping

import numpy as np

from testbed.errors import InputError, is_number
from testbed.models.linear import IX

__all__ = [
    "CLIP",
    "CLIP_ITERATIONS",
    "PEAK_SAMPLES",
    "PHASES",
    "SIGNALS",
    "TAPS",
    "Doublet",
    "Hold",
    "Input3211",
    "Multisine",
    "Prbs",
    "SignalProgram",
    "Signal",
    "Square",
    "Step",
    "ZigzagSignal",
    "min_crest_phases",
    "multisine_peak",
    "parse_signal",
    "peak_span",
    "peak_window",
    "periods",
    "prbs",
    "prbs_spectrum",
    "schroeder_phases",
    "signal_table",
]

SignalProgram = Callable[[float, np.ndarray], float]

# Maximal-length feedback taps (1-indexed register stages) for orders 2..20.
TAPS = {
    2: (2, 1),
    3: (3, 2),
    4: (4, 3),
    5: (5, 3),
    6: (6, 5),
    7: (7, 6),
    8: (8, 6, 5, 4),
    9: (9, 5),
    10: (10, 7),
    11: (11, 9),
    12: (12, 11, 10, 4),
    13: (13, 12, 11, 8),
    14: (14, 13, 12, 2),
    15: (15, 14),
    16: (16, 15, 13, 4),
    17: (17, 14),
    18: (18, 11),
    19: (19, 18, 17, 14),
    20: (20, 17),
}


def prbs(order: int, rng: np.random.Generator | None = None) -> np.ndarray:
    """One period (2^order − 1 bits, ±1) of the maximal-length LFSR sequence; `rng` picks the
    (non-zero) initial register, i.e. the phase."""
    if order not in TAPS:
        raise InputError(f"PRBS order {order}; expected one of {min(TAPS)}..{max(TAPS)}")
    state = [1] * order
    if rng is not None:
        while not any(state := list(rng.integers(0, 2, order))):
            pass
    out = np.empty(2**order - 1)
    for k in range(len(out)):
        out[k] = 1.0 if state[-1] else -1.0
        feedback = 0
        for tap in TAPS[order]:
            feedback ^= state[tap - 1]
        state = [feedback] + state[:-1]
    return out


def prbs_spectrum(order: int, clock: float, n: int = 4096) -> tuple[np.ndarray, np.ndarray]:
    """Power spectrum (frequency Hz, power per line) of the periodic PRBS with bit time `clock`.

    Lines at multiples of 1/((2^order − 1) clock) with envelope sinc²(f clock): the -3 dB point
    is at 0.44/clock, the first null at 1/clock.
    """
    bits = 2**order - 1
    f = np.arange(1, n + 1) / (bits * clock)
    return f, (bits + 1) / bits**2 * np.sinc(f * clock) ** 2


def periods(t: float, period: float) -> int:
    """Whole periods elapsed at `t`; t = k Δt lands on a boundary as on it, not a rounding before."""
    return math.floor(t / period + 1e-9)


def schroeder_phases(k: int) -> np.ndarray:
    """Schroeder's phases φ_i = −π i(i−1)/K, i = 1..K, for a flat-spectrum multisine of low
    crest factor."""
    i = np.arange(1, k + 1)
    return -np.pi * i * (i - 1) / k


PEAK_SAMPLES = 40001  # the grid a multisine's peak is measured on
CLIP_ITERATIONS = 200  # of the crest-factor minimisation
CLIP = 0.9  # the level it clips at, as a fraction of the current peak


def peak_span(frequencies: np.ndarray) -> float:
    """How long a multisine's peak is measured over: 20 periods of its lowest frequency, at
    most 200 s."""
    return min(20.0 / frequencies.min(), 200.0)


def peak_window(frequencies: np.ndarray) -> np.ndarray:
    """The times a multisine's peak is measured at: `peak_span` on a fine grid."""
    return np.linspace(0.0, peak_span(frequencies), PEAK_SAMPLES)


def multisine_peak(frequencies: np.ndarray, phases: np.ndarray) -> float:
    """max |Σ cos(2π f_k t + φ_k)| over `peak_window`."""
    t = peak_window(frequencies)
    return float(np.abs(np.cos(2 * np.pi * np.outer(t, frequencies) + phases).sum(1)).max())


@functools.lru_cache(maxsize=64)
def min_crest_phases(frequencies: tuple) -> tuple:
    """Phases of the flat-spectrum multisine Σ cos(2π f_k t + φ_k) with the smallest peak found
    (its rms is fixed, √(K/2), so the smallest crest factor): from Schroeder's phases, the
    time-frequency swapping of Van der Ouderaa, Schoukens and Renneboog (1988) — clip the signal
    at a level below its peak, give each line the phase of the clipped signal's least-squares
    component on it, restore the flat amplitudes — keeping the best phases seen. Deterministic."""
    f = np.asarray(frequencies, float)
    if len(f) == 1:
        return (0.0,)
    # the search grid: 16 samples per period of the highest line over the peak window
    span = peak_span(f)
    t = np.linspace(0.0, span, int(min(PEAK_SAMPLES, 16 * f.max() * span + 1)))
    arg = 2 * np.pi * np.outer(t, f)
    cos, sin = np.cos(arg), np.sin(arg)
    # Σ a_k cos(arg_k + φ_k) = Σ (a_k cos φ_k) cos arg_k − (a_k sin φ_k) sin arg_k
    project = np.linalg.pinv(np.hstack([cos, -sin]))

    def signal(phi: np.ndarray) -> np.ndarray:  # Σ cos(arg_k + φ_k), one product per term
        return cos @ np.cos(phi) - sin @ np.sin(phi)

    phi = schroeder_phases(len(f))
    x = signal(phi)
    best, best_peak = phi, np.abs(x).max()
    for _ in range(CLIP_ITERATIONS):
        level = CLIP * np.abs(x).max()
        c = project @ np.clip(x, -level, level)
        phi = np.arctan2(c[len(f) :], c[: len(f)])
        x = signal(phi)
        peak = np.abs(x).max()
        if peak < best_peak:
            best, best_peak = phi, peak
    return tuple(float(v) for v in best)


PHASES = {
    "schroeder": lambda f: schroeder_phases(len(f)),
    "min-crest": lambda f: np.array(min_crest_phases(f)),
}


# -- the signals ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class Signal:
    """Base of the signals; `kind` is the TOML `signal` name."""

    kind: ClassVar[str] = ""
    # field -> (check, what it must be), for the one-line error on a bad value
    checks: ClassVar[dict] = {}

    def __post_init__(self):
        for name, (ok, expected) in self.checks.items():
            if not ok(getattr(self, name)):
                raise InputError(f"{self.kind} {name} = {getattr(self, name)!r}; expected {expected}")

    def program(self, rng: np.random.Generator) -> SignalProgram:
        raise NotImplementedError

    def peak(self) -> float:
        """The largest |value| the signal takes (for the fin-range check)."""
        raise NotImplementedError

    def undersampled(self, rate: float) -> str | None:
        """Why the signal cannot be sampled `rate` times a second (the control rate, at which
        the autopilots read it), or None."""
        return None


_FINITE = (is_number, "a finite number")
_POSITIVE = (lambda v: is_number(v) and v > 0, "a finite number > 0")
_TIME = (lambda v: is_number(v) and v >= 0, "a finite time >= 0 s")


@dataclass(frozen=True)
class Hold(Signal):
    kind: ClassVar[str] = "hold"
    checks: ClassVar[dict] = {"value": _FINITE}
    value: float = 0.0

    def program(self, rng):
        value = self.value
        return lambda t, x: value

    def peak(self):
        return abs(self.value)


@dataclass(frozen=True)
class Step(Signal):
    kind: ClassVar[str] = "step"
    checks: ClassVar[dict] = {"amplitude": _FINITE, "start": _TIME, "initial": _FINITE}
    amplitude: float = 0.0
    start: float = 1.0
    initial: float = 0.0

    def program(self, rng):
        a, start, initial = self.amplitude, self.start, self.initial
        return lambda t, x: a if t >= start - 1e-9 else initial

    def peak(self):
        return max(abs(self.amplitude), abs(self.initial))


@dataclass(frozen=True)
class Square(Signal):
    kind: ClassVar[str] = "square"
    checks: ClassVar[dict] = {
        "amplitude": _FINITE,
        "half_period": _POSITIVE,
        "offset": _FINITE,
        "first": (lambda v: v in (1, -1) and not isinstance(v, bool), "1 or -1"),
    }
    amplitude: float = 0.0
    half_period: float = 1.0
    offset: float = 0.0
    first: int = 1

    def program(self, rng):
        a, h, offset, first = self.amplitude, self.half_period, self.offset, self.first
        return lambda t, x: offset + first * a * (1 if periods(t, h) % 2 == 0 else -1)

    def peak(self):
        return abs(self.offset) + abs(self.amplitude)


@dataclass(frozen=True)
class Prbs(Signal):
    kind: ClassVar[str] = "prbs"
    checks: ClassVar[dict] = {
        "amplitude": _FINITE,
        "clock": _POSITIVE,
        "order": (
            lambda v: isinstance(v, int) and not isinstance(v, bool) and v in TAPS,
            f"an integer in {min(TAPS)}..{max(TAPS)}",
        ),
    }
    amplitude: float = 0.0
    order: int = 10
    clock: float = 0.1

    def program(self, rng):
        bits, clock = self.amplitude * prbs(self.order, rng), self.clock
        return lambda t, x: bits[periods(t, clock) % len(bits)]

    def peak(self):
        return abs(self.amplitude)


@dataclass(frozen=True)
class _Pulses(Signal):
    """±amplitude over consecutive slots of `slot` s from `start` (signs per slot), then 0."""

    signs: ClassVar[tuple] = ()

    @property
    def slot(self) -> float:
        raise NotImplementedError

    def program(self, rng):
        return _pulses(self.amplitude, self.start, self.slot, self.signs)

    def peak(self):
        return abs(self.amplitude)


@dataclass(frozen=True)
class Doublet(_Pulses):
    kind: ClassVar[str] = "doublet"
    checks: ClassVar[dict] = {"amplitude": _FINITE, "width": _POSITIVE, "start": _TIME}
    signs: ClassVar[tuple] = (1, -1)
    amplitude: float = 0.0
    width: float = 1.0
    start: float = 1.0

    @property
    def slot(self) -> float:
        return self.width


@dataclass(frozen=True)
class Input3211(_Pulses):
    kind: ClassVar[str] = "3211"
    checks: ClassVar[dict] = {"amplitude": _FINITE, "unit": _POSITIVE, "start": _TIME}
    signs: ClassVar[tuple] = (1, 1, 1, -1, -1, 1, -1)  # 3 units +, 2 −, 1 +, 1 −
    amplitude: float = 0.0
    unit: float = 0.5
    start: float = 1.0

    @property
    def slot(self) -> float:
        return self.unit


def _pulses(amplitude: float, start: float, width: float, signs: tuple) -> SignalProgram:
    """±amplitude over consecutive slots of `width` s from `start`, then 0."""

    def program(t, x):
        k = periods(t - start, width) if t >= start - 1e-9 else -1
        return amplitude * signs[k] if 0 <= k < len(signs) else 0.0

    return program


@dataclass(frozen=True)
class Multisine(Signal):
    kind: ClassVar[str] = "multisine"
    checks: ClassVar[dict] = {
        "amplitude": _FINITE,
        "start": _TIME,
        "frequencies": (
            lambda v: isinstance(v, tuple) and len(v) > 0 and all(is_number(f) and f > 0 for f in v),
            "a non-empty list of frequencies > 0 Hz",
        ),
        "phases": (lambda v: v in PHASES, " or ".join(repr(k) for k in PHASES)),
    }
    amplitude: float = 0.0
    frequencies: tuple = (0.1, 0.2, 0.3)
    start: float = 0.0
    phases: str = "schroeder"

    def program(self, rng):
        f = np.asarray(self.frequencies, float)
        phi = PHASES[self.phases](self.frequencies)
        scale, start = self.amplitude / multisine_peak(f, phi), self.start

        def program(t, x):
            if t < start - 1e-9:
                return 0.0
            return scale * float(np.cos(2 * np.pi * f * (t - start) + phi).sum())

        return program

    def peak(self):
        return abs(self.amplitude)

    def undersampled(self, rate):
        """A line at or above half the sampling rate (Nyquist) is sampled as a lower one (at
        exactly half, as a constant times ±1): the flown signal would not be this multisine."""
        highest = max(self.frequencies)
        if highest < rate / 2:
            return None
        return (
            f"multisine frequencies up to {highest:g} Hz; expected frequencies below {rate / 2:g} Hz, "
            f"half the control_rate ({rate:g} Hz) at which the signal is sampled"
        )


@dataclass(frozen=True)
class ZigzagSignal(Signal):
    kind: ClassVar[str] = "zigzag"
    checks: ClassVar[dict] = {
        "angle": (lambda v: is_number(v) and v > 0, "a finite angle > 0 rad"),
        "switch": (lambda v: v is None or (is_number(v) and v > 0), "a finite angle > 0 rad"),
        "on": (lambda v: v in ("psi", "theta"), "'psi' or 'theta'"),
    }
    angle: float = math.radians(20.0)
    on: str = "psi"
    switch: float | None = None  # the switching angle of `on`, rad (default: `angle`)

    def program(self, rng):
        k, sign, start = IX[self.on], [1.0], []
        angle, switch = self.angle, self.angle if self.switch is None else self.switch

        def program(t, x):
            if not start:
                start.append(x[k])
            # wrapped, so a heading near ±π does not jump by 2π
            turned = (x[k] - start[0] + math.pi) % (2 * math.pi) - math.pi
            if sign[0] > 0 and turned <= -switch:
                sign[0] = -1.0
            elif sign[0] < 0 and turned >= switch:
                sign[0] = 1.0
            return sign[0] * angle

        return program

    def peak(self):
        return abs(self.angle)


SIGNALS: dict[str, type[Signal]] = {
    s.kind: s for s in (Hold, Step, Square, Prbs, Doublet, Input3211, Multisine, ZigzagSignal)
}


def parse_signal(value, where: str) -> Signal:
    """A signal from its TOML form: a number (a `hold`) or a table with `signal` and its
    parameters. InputError naming `where` (e.g. `file: experiment 'x' rudder`) otherwise."""
    if is_number(value):
        return Hold(value=float(value))
    if not isinstance(value, Mapping):
        raise InputError(f"{where}: {value!r}; expected a number or a table with 'signal'")
    kind = value.get("signal")
    if kind not in SIGNALS:
        raise InputError(f"{where}: signal {kind!r}; expected one of {', '.join(SIGNALS)}")
    cls = SIGNALS[kind]
    names = {f.name for f in fields(cls)}
    unknown = sorted(set(value) - names - {"signal"})
    if unknown:
        raise InputError(
            f"{where}: unknown {kind} parameter {unknown[0]!r}; expected {', '.join(sorted(names))}"
        )
    kwargs = {}
    for name, v in value.items():
        if name == "signal":
            continue
        if name == "frequencies":
            v = tuple(v) if isinstance(v, list) else v
        elif isinstance(v, int) and not isinstance(v, bool) and name not in ("order", "first"):
            v = float(v)
        kwargs[name] = v
    try:
        return cls(**kwargs)
    except InputError as exc:
        raise InputError(f"{where}: {exc}") from None


def signal_table(s: Signal) -> dict:
    """The TOML table of a signal (`parse_signal` reads it back to an equal signal)."""
    return {"signal": s.kind, **{f.name: getattr(s, f.name) for f in fields(s)}}
