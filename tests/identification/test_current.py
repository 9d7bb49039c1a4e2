"""A steady current (`c_N`, `c_E`) in the velocities over the ground: y_u = u + c_N cos ψ + c_E sin ψ,
y_v = v − c_N sin ψ + c_E cos ψ, ψ the measured heading."""

import numpy as np
import pytest

from testbed.estimators import identify
from testbed.identification import concentrated, likelihood
from testbed.identification.problem import problem
from references import assert_sensitivities_match_complex_step, qr_cost

from identification.test_offsets import (
    FIN_OFFSET,
    LATERAL,
    _start,
    _turns,
    assert_recovered_beside_the_offsets,
)  # noqa: F401

CURRENT = (0.12, -0.08)  # m/s north, east: a 0.14 m/s tidal current, a tenth of the example's speed


def _with_current(data, truth_data, current):
    """`data` whose u and v are read over the ground: the current turned by the true heading
    (from `truth_data`, the same records without noise)."""
    out = []
    for e, clean in zip(data, truth_data):
        psi = clean.column("psi")
        y = e.y.copy()
        y[:, e.measured.index("u")] += current[0] * np.cos(psi) + current[1] * np.sin(psi)
        y[:, e.measured.index("v")] += current[1] * np.cos(psi) - current[0] * np.sin(psi)
        out.append(type(e)(e.name, e.t, e.measured, y, e.inputs))
    return out


def _data(duration=40.0):
    offsets = (FIN_OFFSET, -FIN_OFFSET)
    return _with_current(_turns(offsets, duration), _turns(offsets, duration, noise=False), CURRENT)


def test_the_heading_turns_in_these_records():
    span = [np.ptp(e.column("psi")) for e in _turns((FIN_OFFSET, -FIN_OFFSET), noise=False)]
    assert min(span) > 0.5  # rad: the current is told from a bias only as the heading turns


def test_sensitivities_to_the_current_match_complex_step():
    data = _data(duration=3.0)
    prob = problem(data, _start(LATERAL + ("c_N", "c_E", "b_v"), ("c_E",)))
    p = likelihood.initial_states(prob, prob.start)
    p[prob.free.index("c_N")] = 0.1
    assert_sensitivities_match_complex_step(prob, p)


def test_the_simplex_cost_with_a_current_is_the_qr_likelihood():
    prob = problem(_data(duration=10.0), _start(LATERAL + ("c_N", "c_E")))
    values = prob.start.copy()
    values[-2:] = CURRENT
    R = np.full(len(prob.channels), 1e-4)
    qr = qr_cost(prob, values, R)
    assert concentrated.Cost(prob)(values, R) == pytest.approx(qr, rel=1e-9)


def test_the_current_is_recovered_beside_the_velocity_biases():
    truth = {"c_N": CURRENT[0], "c_E": CURRENT[1], "b_u": 0.0, "b_v": 0.0}
    assert_recovered_beside_the_offsets(_data(), ("c_N", "c_E", "b_u", "b_v"), truth)


def test_a_current_without_the_heading_is_refused():
    from testbed.errors import InputError

    config = _start(LATERAL + ("c_N", "c_E"))
    for data, outputs in (
        (_data(duration=5.0), ("u", "v", "r")),
        ([e.only(("u", "v", "r")) for e in _data(5.0)], None),
    ):
        with pytest.raises(InputError, match=r"the current \(c_N, c_E\) turns with the heading") as exc:
            identify(
                data,
                config if outputs is None else config.__class__(**{**config.__dict__, "outputs": outputs}),
            )
        assert "\n" not in str(exc.value)


def test_equation_error_refuses_free_output_terms_and_delay():
    from testbed.errors import InputError

    for name in ("c_N", "b_v", "input_delay"):
        with pytest.raises(InputError, match=rf"free lists {name}; equation-error"):
            identify(_data(duration=5.0), _start(LATERAL + (name,)), method="equation-error")
