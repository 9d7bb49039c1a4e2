"""The profile likelihood against the Cramér-Rao bound where the likelihood is quadratic (the
example's vertical plane over a 60 s record: Λ(θ̂ + kσ) = k², the profile's curvature at θ̂
being the Schur complement of the information)."""

from dataclasses import replace

import numpy as np
import pytest

from testbed.analysis.profile import profile
from testbed.errors import InputError
from testbed.estimators import identify
from studies.remus import experiments, prior_config

VERTICAL = ("Z_w", "Z_q", "Z_de", "M_w", "M_q", "M_de")


@pytest.fixture(scope="module")
def fit():
    data = experiments(seed=3, duration=60.0)
    config = prior_config(VERTICAL, error=0.2)
    return data, config, identify(data, config, method="ml-gn", start="config")


@pytest.mark.parametrize("name", ["M_q", "Z_de"])
@pytest.mark.parametrize("k", [-3.0, 1.0, 3.0])
def test_the_likelihood_ratio_is_the_wald_statistic_where_the_likelihood_is_quadratic(fit, name, k):
    data, config, est = fit
    assert est.converged
    i = est.free.index(name)
    value = est.values[i] + k * est.std[i]
    p = profile(data, config, est, name, value)
    assert p.held.converged and name not in p.held.free
    assert p.sigmas == pytest.approx(k, rel=0.02)
    assert p.statistic == pytest.approx(k * k, rel=0.04)


def test_at_the_estimate_the_ratio_is_zero(fit):
    data, config, est = fit
    p = profile(data, config, est, "M_w", float(est.coefficients["M_w"]))
    assert abs(p.statistic) < 1e-3


def test_what_cannot_be_profiled_is_refused_in_one_line(fit):
    data, config, est = fit
    for name, value, match in (("N_r", 1.0, "'N_r' is not a free value"), ("M_q", np.nan, "M_q = nan")):
        with pytest.raises(InputError, match=match) as e:
            profile(data, config, est, name, value)
        assert "\n" not in str(e.value)


def test_a_value_per_record_is_refused_and_the_others_keep_theirs(fit):
    data, config, _ = fit
    config = replace(config, per_record=("M_de",))
    est = identify(data, config, method="ml-gn", start="config")
    each = [n for n in est.free if n.startswith("M_de[")]
    assert len(each) == len(data)
    with pytest.raises(InputError, match="fitted per record") as e:
        profile(data, config, est, each[0], est.coefficients[each[0]])
    assert "\n" not in str(e.value)
    p = profile(data, config, est, "M_q", float(est.coefficients["M_q"]))
    assert sorted(p.held.free) == sorted(n for n in est.free if n != "M_q") and abs(p.statistic) < 1e-3
