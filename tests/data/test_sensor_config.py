"""A model config's known sensors (`[sensors.NAME]`): their readings turned into the CG's
body-axis states before every method, once."""

import tomllib
from dataclasses import replace

import numpy as np
import pytest

from testbed.data import ModelConfig, config_text, parse_config, read_config, write_config
from testbed.errors import InputError
from testbed.estimators import identify
from studies.remus import EXAMPLE_COEFFICIENTS, FREE, example_config, experiments
from testbed.models.linear import STATES
from testbed.models.sensors import Sensor, outputs

# A DVL 0.4 m forward of the CG and 0.1 m below it, read in north-east-down axes (an INS's
# solution), with biases and a scale factor, two samples late; a depth cell 0.5 m forward.
DVL = Sensor(
    name="dvl",
    outputs=("u", "v", "w"),
    position=(0.4, 0.0, 0.1),
    frame="earth",
    bias={"u": 0.01, "v": -0.02},
    scale={"u": 0.003},
    delay=0.1,
)
DEPTH = Sensor(name="depth", outputs=("z",), position=(0.5, 0.0, -0.05), bias={"z": 0.05})
LATE = 2  # samples: DVL.delay at the example's 0.05 s


def _as_read(e, sensors=(DVL, DEPTH)):
    """`e` (absolute states at the CG) as the sensors read it: each sensor's outputs from the
    true states, read `delay` s late (here a whole number of samples)."""
    x = np.asarray(e.y, float)
    y = x.copy()
    for s in sensors:
        read = outputs(s, x)
        k = int(round(s.delay / e.dt))
        if k:
            read = np.vstack([np.repeat(read[:1], k, axis=0), read[:-k]])
        for j, o in enumerate(s.outputs):
            y[:, STATES.index(o)] = read[:, j]
    return replace(e, y=y)


def _config(sensors=(DVL, DEPTH), free=FREE) -> ModelConfig:
    return replace(example_config(free), sensors=tuple(sensors))


def test_a_config_s_sensors_round_trip(tmp_path):
    config = _config()
    back = read_config(write_config(tmp_path / "m.toml", config))
    assert back.sensors == config.sensors and back.coefficients == config.coefficients


def test_readings_are_turned_back_into_the_states_once():
    truth = experiments(seed=0, duration=10.0, noise=None)[0]
    read = _as_read(truth)
    assert np.abs(read.y - truth.y).max() > 0.05  # the sensors' readings are not the states
    config = _config()
    (once,) = config.readings([read])
    np.testing.assert_allclose(once.y[:-LATE], truth.y[:-LATE], atol=1e-10)
    assert np.isnan(once.y[-LATE:, :3]).all()  # the DVL's last readings are beyond the record
    assert once.sensors == ("dvl", "depth") or once.sensors == ("depth", "dvl")
    (twice,) = config.readings([once])
    np.testing.assert_array_equal(twice.y, once.y)  # applied once: a record keeps what was undone


def test_identify_fits_the_states_behind_the_readings():
    data = [_as_read(e) for e in experiments(seed=1, duration=30.0)]
    truth = np.array([EXAMPLE_COEFFICIENTS[n] for n in FREE])
    start = example_config().with_coefficients({n: 0.8 * EXAMPLE_COEFFICIENTS[n] for n in FREE})
    known = identify(data, replace(start, sensors=(DVL, DEPTH)), method="ml-gn")
    assert known.converged
    assert np.all(np.abs(known.values - truth) < 4 * known.std), (known.values - truth) / known.std
    unknown = identify(data, start, method="ml-gn")  # the same readings taken as the states
    assert np.max(np.abs(unknown.values - truth) / unknown.std) > 5


@pytest.mark.parametrize(
    "table, words",
    [
        ('outputs = ["u", "v", "w"]\nrate = 10.0', "unknown key 'rate'"),
        ('outputs = ["ax"]', r"outputs \['ax'\]; expected states"),
        ('outputs = ["u", "v"]\nframe = "earth"', "expected all of u, v, w"),
        ('outputs = ["u", "v", "w"]\nposition = [1, 2]', "position = .*expected a list of three numbers"),
        ('outputs = ["z"]\ndelay = -1.0', "delay -1.0; expected a finite number 0 to 10"),
        ('outputs = ["z"]\nbias = {w = 1.0}', "bias.w: not an output"),
    ],
)
def test_a_config_s_bad_sensor_is_one_line(table, words):
    text = config_text(example_config(())) + f"\n[sensors.s]\n{table}\n"
    with pytest.raises(InputError, match=words) as exc:
        parse_config(tomllib.loads(text), "m.toml")
    assert "\n" not in str(exc.value) and "m.toml" in str(exc.value)


def test_a_record_without_what_a_sensor_needs_is_refused():
    truth = experiments(seed=0, duration=5.0, noise=None)[0]
    for states, words in (
        (("p", "q", "r", "phi", "theta", "psi", "z"), "outputs u, v, w, which the record has no column for"),
        (("u", "v", "w", "phi", "theta", "psi", "z"), "needs p, q, r to be undone; the record has no p"),
    ):
        with pytest.raises(InputError, match=words) as exc:
            identify([truth.only(states)], _config(free=("N_r",)), method="ml-gn")
        assert "\n" not in str(exc.value)
    two = (DVL, replace(DEPTH, name="again", outputs=("w",), position=(0.0, 0.0, 0.0), bias={}))
    with pytest.raises(InputError, match="read w twice"):
        parse_config(tomllib.loads(config_text(_config(sensors=two))), "m.toml")


def test_validation_compares_the_states_behind_the_readings():
    from testbed.analysis.validation import validate

    truth = experiments(seed=2, duration=20.0, noise=None)
    read = [_as_read(e) for e in truth]
    config = _config()
    result = validate(read, config).to_dict()
    for e in truth:
        for state in ("u", "v", "w", "z"):
            assert result[e.name][state]["fit_percent"] > 99.9, (e.name, state)
    raw = validate(read, replace(config, sensors=())).to_dict()
    assert min(raw[e.name]["u"]["fit_percent"] for e in truth) < 99.0


def test_a_slower_sensor_keeps_its_own_samples():
    """A 10 Hz log in a 20 Hz record, 0.1 s late: put back on time, its samples move back by two
    rows and the rows between stay missing (never interpolated in)."""
    from testbed.models.sensors import late

    t = np.arange(0.0, 3.0, 0.05)
    y = np.sin(t)
    y[1::2] = np.nan  # a sample every other row
    back = late(t, y, 0.1)
    np.testing.assert_allclose(
        back[: len(t) - 2], np.where(np.isnan(y[2:]), np.nan, np.sin(t[2:])), equal_nan=True
    )
    assert np.isnan(back[-2:]).all()


def test_the_filters_take_the_states_behind_the_readings():
    from testbed.identification.problem import one_model

    truth = experiments(seed=0, duration=10.0, noise=None)[0]
    (states,), config = one_model([_as_read(truth)], _config(), "mekf")
    np.testing.assert_allclose(states.y[:-LATE], truth.y[:-LATE], atol=1e-10)
    assert config.sensors == (DVL, DEPTH)  # applied once: the record says so
