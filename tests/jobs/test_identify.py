"""The command's screened fit (`jobs.identify.identify_screened`): what the method cannot take is
refused before the screen fits."""

from __future__ import annotations

from dataclasses import replace

import pytest
from estimators.test_nonlinear import FREE, truth  # noqa: F401  (the fixture: doublets the captive model flew)

from testbed.errors import InputError
from testbed.estimators import OptionError


@pytest.mark.parametrize(
    "method, free, options, error, words",
    [
        ("equation-error", ("b_phi",), None, InputError, r"free lists b_phi"),
        ("mekf", ("b_phi",), None, InputError, r"free names b_phi"),
        ("ml-nm", (), {"start": "global"}, OptionError, r"option start='global'; expected auto"),
        ("ml-lm", (), {"start": "global"}, OptionError, r"option start='global'; expected auto"),
        ("ekf", (), {"passes": 2}, OptionError, r"option passes=2"),
    ],
)
def test_what_a_nonlinear_config_cannot_take_is_refused_before_the_screen_fits(
    truth,  # noqa: F811
    method,
    free,
    options,
    error,
    words,
    monkeypatch,
):
    """What a method cannot take in a nonlinear model config whatever the data (a free output bias,
    in no dynamics row and estimated by no filter; an option its nonlinear fit has no use for) is
    refused before the command's screen fits (a minute and more on a 60 s record), not after it."""
    from testbed.jobs import identify as job

    config, noisy, _ = truth

    def screened(*args, **kwargs):
        raise AssertionError("the screen ran")

    monkeypatch.setattr(job, "screening", screened)
    with pytest.raises(error, match=words) as e:
        job.identify_screened([noisy], replace(config, free=(*FREE, *free), screen=True), method, options)
    assert "\n" not in str(e.value)
