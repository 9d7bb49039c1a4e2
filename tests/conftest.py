"""Hypothesis profiles for the property-based tests, and the fixtures tests share.

`fast` (the default) keeps every property inside the suite's time budget; `slow` tries many more
examples. Select `slow` for every property with `HYPOTHESIS_PROFILE=slow` (or hypothesis' own
`--hypothesis-profile slow`); `-m slow` also runs each property once more under it.
"""

import os

from testbed.threads import one_blas_thread

one_blas_thread()  # before numpy loads: the workers share the cores (as the command line does)

import numpy as np  # noqa: E402
import pytest  # noqa: E402
from hypothesis import HealthCheck, settings  # noqa: E402

from testbed.simulation.flight import Flight  # noqa: E402

_COMMON = dict(
    deadline=None,
    suppress_health_check=[
        HealthCheck.function_scoped_fixture,
        HealthCheck.too_slow,
        HealthCheck.data_too_large,
    ],
)
settings.register_profile("fast", max_examples=20, **_COMMON)
settings.register_profile("slow", max_examples=400, **_COMMON)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "fast"))


def _flight(name="horizontal", n=201, seed=0) -> Flight:
    """A flight with the shapes of `fly_scenario`'s (straight ahead at 20 m/s, wiggling fins), its
    commands: a depth, a rudder program and the fin command, a roll never given, an unknown one."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.02
    truth = 0.05 * rng.standard_normal((n, 10))
    truth[:, 0] += 20.0
    truth[:, 9] += 100.0
    fins = 0.1 * np.sin(np.outer(t, [1.0, 2.0, 3.0]))
    position = np.column_stack([20.0 * t, np.zeros(n), np.full(n, 100.0)])
    commands = {
        "depth": np.full(n, 101.0),
        "rudder": np.sign(fins[:, 0]) * 0.1,
        "fin_r": fins[:, 0] + 0.01,
        "roll": np.full(n, np.nan),
        "mystery": np.linspace(0.0, 1.0, n),
    }
    return Flight(name, t, truth, truth + 0.01, fins, fins + 0.001, position, commands)


@pytest.fixture(scope="session")
def flights() -> list[Flight]:
    """Two flights of different lengths (the recording and report tests)."""
    return [_flight("horizontal", seed=1), _flight("vertical", n=151, seed=2)]


@pytest.fixture(scope="session")
def make_flight():
    """`make_flight(name, n, seed)`: a flight like those of `flights`, another realisation."""
    return _flight
