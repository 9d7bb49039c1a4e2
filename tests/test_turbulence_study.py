"""The turbulence study: its open-loop flight against the model's own prediction, and its
acceptance (the filter-error method unbiased with honest bounds where output error is biased)."""

from __future__ import annotations

import numpy as np
import pytest

from studies.turbulence import flown_open_loop, study
from testbed.data import load_data
from testbed.identification.prediction import predict
from testbed.models.linear import STATES
from testbed.simulation.measurements import NOISE_STD
from testbed.simulation.runs import simulate
from testbed.simulation.scenario import scenario


def test_without_turbulence_the_open_loop_flight_is_the_model_s_response_plus_the_sensor_noise(tmp_path):
    run = simulate(scenario("II"), seed=1, out=tmp_path / "run", truth="linear", duration=20.0)
    experiments, config = load_data([run])
    flown = flown_open_loop(experiments, config, 0.0, 0.5, np.random.default_rng(3))
    for e, y in zip(flown, predict(flown, config)):
        assert e.measured == STATES and np.array_equal(
            e.inputs, next(x for x in experiments if x.name == e.name).inputs
        )
        residual = e.y - y
        np.testing.assert_allclose(residual.std(axis=0), [NOISE_STD[s] for s in STATES], rtol=0.1)
        assert np.all(
            np.abs(residual.mean(axis=0)) < 4 * np.array([NOISE_STD[s] for s in STATES]) / np.sqrt(len(e.t))
        )


@pytest.mark.slow
def test_with_autopilots_reading_the_sensors_the_filter_error_method_is_unbiased_where_output_error_is_not(
    tmp_path,
):
    """Scenario II with II-trial's turbulence, 20 seeds: every coefficient of `ml-fem` within
    0.5 σ on average with σ/scatter in 0.7–1.4; `ml-gn` on the same data more than 1 σ off."""
    text = study(20, 0.1, 0.5, tmp_path)
    lines = text.splitlines()
    assert "ml-gn 20/20 converged, ml-fem 20/20 converged" in lines[-1], lines[-1]
    rows = np.array([[float(c) for c in line.split(",")[2:]] for line in lines[1:-1]])
    gn_bias, fem_bias, fem_ratio = rows[:, 0], rows[:, 2], rows[:, 3]
    assert np.abs(fem_bias).max() < 0.5, fem_bias
    assert np.all((0.7 < fem_ratio) & (fem_ratio < 1.4)), fem_ratio
    assert np.abs(gn_bias).max() > 1.0, gn_bias
