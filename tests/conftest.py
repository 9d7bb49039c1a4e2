"""Hypothesis profiles for the property-based tests.

`fast` (the default) keeps every property inside the suite's time budget; `slow` tries many more
examples. Select `slow` for every property with `HYPOTHESIS_PROFILE=slow` (or hypothesis' own
`--hypothesis-profile slow`); `-m slow` also runs each property once more under it.
"""

import os

from hypothesis import HealthCheck, settings

_COMMON = dict(deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                     HealthCheck.too_slow, HealthCheck.data_too_large])  # fmt: skip
settings.register_profile("fast", max_examples=20, **_COMMON)
settings.register_profile("slow", max_examples=400, **_COMMON)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "fast"))
