"""The turbulence study's open-loop flight against the model's own prediction."""

from __future__ import annotations

import numpy as np

from studies.turbulence import flown_open_loop
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
    for e, y in zip(flown, predict(flown, config, resolve=False)):
        assert e.measured == STATES and np.array_equal(
            e.inputs, next(x for x in experiments if x.name == e.name).inputs
        )
        residual = e.y - y
        np.testing.assert_allclose(residual.std(axis=0), [NOISE_STD[s] for s in STATES], rtol=0.1)
        assert np.all(
            np.abs(residual.mean(axis=0)) < 4 * np.array([NOISE_STD[s] for s in STATES]) / np.sqrt(len(e.t))
        )
