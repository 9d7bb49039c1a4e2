"""The fins' range and rate come from the MJCF: a vehicle whose servos stop at ±0.2 rad (the
bundled torpedo's copy with its ranges edited) is flown, checked and designed for with ±0.2."""

from dataclasses import replace

import numpy as np
import pytest

from testbed.analysis import design_model as DM
from testbed.analysis import design_signals as DS
from testbed.errors import InputError
from testbed.simulation.analytic import analytic, model_config
from testbed.simulation.flight import fly_scenario
from testbed.simulation.scenario import ExperimentSpec, Scenario
from testbed.simulation.signals import Hold, Prbs
from testbed.simulation.vehicle import default_mjcf, fin_limits, load_model

NARROW = 0.2  # rad, the edited vehicle's fin range (the bundled torpedo's: 0.4)


@pytest.fixture(scope="module")
def narrow(tmp_path_factory):
    text = default_mjcf().read_text(encoding="utf-8")
    assert text.count('range="-0.40 0.40"') == 2  # the fins' joint range and the servos' ctrlrange
    path = tmp_path_factory.mktemp("mjcf") / "narrow.xml"
    path.write_text(text.replace('range="-0.40 0.40"', f'range="-{NARROW} {NARROW}"'), encoding="utf-8")
    return path


def test_the_limits_are_read_from_the_mjcf(narrow):
    bundled, edited = fin_limits(load_model()), fin_limits(load_model(narrow))
    assert (bundled.angle, bundled.rate) == (0.4, 2.0)
    assert (edited.angle, edited.rate) == (NARROW, 2.0)
    assert analytic(narrow).fins == edited


def _turn(rudder=None):
    """2 s at a course rate far beyond reach (the rudder saturates), or the rudder driven open loop."""
    fins = {} if rudder is None else {"rudder": rudder}
    loops = {"depth": Hold(0.0), "roll": Hold(0.0)} | ({} if rudder else {"yaw_rate": Hold(10.0)})
    e = ExperimentSpec(name="turn", fins=fins, autopilot=loops)
    return Scenario(name="turn", experiments=(e,), duration=2.0, source="turn.toml")


def test_the_autopilot_saturates_at_the_vehicles_range(narrow):
    (bundled,), _ = fly_scenario(_turn())
    (edited,), _ = fly_scenario(_turn(), mjcf=narrow)
    assert np.abs(bundled.commands["fin_r"]).max() == pytest.approx(0.4)
    assert np.abs(edited.commands["fin_r"]).max() == pytest.approx(NARROW)
    assert np.abs(edited.fins[:, 0]).max() <= NARROW + 1e-9


def test_a_signal_beyond_the_vehicles_range_is_refused(narrow):
    wide = _turn(Prbs(amplitude=0.3, order=5, clock=0.2))
    with pytest.raises(
        InputError, match=rf"turn.toml: experiment 'turn': rudder reaches 0.3 rad; .*{narrow.name}, 0.2 rad"
    ):
        fly_scenario(wide, mjcf=narrow)
    (flight,), _ = fly_scenario(wide)  # the torpedo's range holds it
    assert np.abs(flight.commands["fin_r"]).max() == pytest.approx(0.3)


def test_the_design_bounds_and_flies_the_vehicles_fins(narrow):
    lin = analytic(narrow)
    m = DM.model(replace(model_config(lin, narrow)[0], free=("Y_v", "N_r", "N_dr")), lin.fins)
    limits = DM.regime_limits(m)
    assert (limits.fin, limits.fin_rate) == (NARROW, 2.0)
    spec = DS.spec("horizontal", {"rudder": Prbs(amplitude=0.3, order=5, clock=0.5)})
    _, _, fins = DM.fly_model(m, spec, 10.0)
    assert np.abs(fins[:, 0]).max() == pytest.approx(NARROW)
    assert np.abs(np.diff(fins[:, 0])).max() <= 2.0 / m.control_rate + 1e-12  # the MJCF's rate
