"""A velocity log's mounting (`m_dvl_y`, `m_dvl_z`, `r_dvl_x` … `r_dvl_z`): its u, v, w read the
velocity of its point in its own axes, y = Mᵀ (v + ω × r + c_b) − U e_x, known or estimated."""

from dataclasses import replace

import numpy as np
import pytest
from scipy import optimize

from testbed.errors import InputError
from testbed.estimators import identify
from testbed.identification import likelihood, recursions
from testbed.identification.problem import problem
from testbed.models import log_mounting
from testbed.models.linear import IX, MOUNTING, STATES
from testbed.models.sensors import Sensor, outputs
from references import assert_curvature_matches_complex_step, assert_sensitivities_match_complex_step

from identification.test_current import _data as _current_data
from identification.test_offsets import (
    FIN_OFFSET,
    LATERAL,
    _start,
    _turns,
    assert_recovered_beside_the_offsets,
)

MOUNT = {"m_dvl_y": 0.0, "m_dvl_z": 0.03, "r_dvl_x": 0.6, "r_dvl_y": 0.0, "r_dvl_z": 0.25}


def test_the_reading_is_the_sensor_model_s_and_its_derivatives_the_complex_step_s():
    """Against `models.sensors`' map of a body-frame velocity sensor at r, misaligned by
    (0, m_y, m_z), and its derivatives against the complex step of the reading."""
    rng = np.random.default_rng(0)
    g = np.array([0.02, -0.04, 0.7, -0.1, 0.3])
    x = rng.normal(size=(6, len(STATES))) * 0.1
    x[:, IX["u"]] += 2.0
    current = np.column_stack([rng.normal(size=(6, 2)) * 0.1, np.zeros(6)])
    sensor = Sensor(
        name="dvl", outputs=("u", "v", "w"), position=tuple(g[2:]), misalignment=(0.0, g[0], g[1])
    )
    # the sensors' map takes the current in earth axes: level attitude, heading 0 (C = I)
    x[:, [IX["phi"], IX["theta"], IX["psi"]]] = 0.0
    want = outputs(sensor, x, current=current)
    got = log_mounting.reading(g, x[:, :3], x[:, 3:6], current)
    np.testing.assert_allclose(got, want, rtol=1e-13, atol=1e-15)
    dg = log_mounting.mounting_derivatives(g, x[:, :3], x[:, 3:6], current)
    for i in range(5):
        gc = g.astype(complex)
        gc[i] += 1e-30j
        ref = log_mounting.reading(gc, x[:, :3], x[:, 3:6], current).imag / 1e-30
        np.testing.assert_allclose(dg[i], ref, rtol=1e-12, atol=1e-15)
    # linear in the state: C (v; ω) plus the reading of the current alone
    C = log_mounting.matrix(g)
    alone = log_mounting.reading(g, np.zeros((6, 3)), np.zeros((6, 3)), current)
    np.testing.assert_allclose(got, x[:, :6] @ C.T + alone, rtol=1e-12, atol=1e-15)


def _mounted(data, clean, mounting, current=(0.0, 0.0)):
    """`data` whose u, v, w a log mounted as `mounting` reads (from the noise-free states of
    `clean`, with a current over the ground turned by the true heading), its own noise kept."""
    g = np.array([mounting[n] for n in MOUNTING])
    out = []
    for e, c in zip(data, clean):
        x = np.column_stack([c.column(s) for s in STATES])
        psi = x[:, IX["psi"]]
        cb = np.column_stack(
            [
                current[0] * np.cos(psi) + current[1] * np.sin(psi),
                current[1] * np.cos(psi) - current[0] * np.sin(psi),
                np.zeros(len(psi)),
            ]
        )
        read = log_mounting.reading(g, x[:, :3], x[:, 3:6], cb)
        y = e.y.copy()
        for k, s in enumerate(("u", "v", "w")):
            y[:, e.measured.index(s)] += read[:, k] - x[:, IX[s]]
        out.append(replace(e, y=y))
    return out


def test_sensitivities_to_the_mounting_match_complex_step():
    """With the mounting, the current and a velocity bias free, per record and shared."""
    data = _current_data(duration=3.0)
    prob = problem(data, _start(LATERAL + MOUNTING + ("c_N", "b_v"), ("r_dvl_x",)))
    p = likelihood.initial_states(prob, prob.start)
    for n, v in (("m_dvl_y", 0.02), ("m_dvl_z", -0.03), ("r_dvl_z", 0.3), ("c_N", 0.1), ("b_v", 0.01)):
        p[prob.free.index(n)] = v
    assert prob.mounted
    assert_sensitivities_match_complex_step(prob, p)


def test_the_curvature_of_a_mounted_log_matches_complex_step():
    """ml-nr's second derivatives with the mounting, the current and a bias free: against the
    complex step of the first-order sensitivities."""
    data = _current_data(duration=2.0)
    prob = problem(data, _start(LATERAL + MOUNTING + ("c_N", "c_E", "b_v"), ("r_dvl_x",)))
    p = likelihood.initial_states(prob, prob.start)
    for n, v in (("m_dvl_y", 0.02), ("m_dvl_z", -0.03), ("r_dvl_z", 0.3), ("r_dvl_y", -0.1), ("c_N", 0.1)):
        p[prob.free.index(n)] = v
    rng = np.random.default_rng(2)
    weights = [rng.normal(size=r.y.shape) for r in prob.records]
    assert_curvature_matches_complex_step(prob, p, weights)


def test_the_initial_states_minimise_the_cost_as_scipy_finds():
    """The best-fitting initial states of a mounted log's records: scipy's least squares over
    them, with the same R, finds no lower cost."""
    data = _mounted(
        _turns((FIN_OFFSET, -FIN_OFFSET), 10.0), _turns((FIN_OFFSET, -FIN_OFFSET), 10.0, noise=False), MOUNT
    )
    prob = problem(data, _start(LATERAL + MOUNTING))
    values = prob.start.copy()
    for n, v in MOUNT.items():
        values[prob.free.index(n)] = v
    R = np.full(len(prob.channels), 1e-4)
    p, out = likelihood.fit_initial_states(prob, values, R)

    def weighted(x0):
        q = np.r_[values, x0]
        return np.concatenate(
            [
                (r.residual(y) / np.sqrt(R[r.channels])).ravel()
                for r, y in zip(prob.records, recursions.simulated_outputs(prob, q))
            ]
        )

    ref = optimize.least_squares(weighted, p[prob.n_free :] + 0.01, method="lm", xtol=1e-14, ftol=1e-14)
    ours = float(np.sum(weighted(p[prob.n_free :]) ** 2))
    assert ours <= 2 * ref.cost * (1 + 1e-9)
    np.testing.assert_allclose(p[prob.n_free :], ref.x, rtol=1e-6, atol=1e-9)


def test_a_mounted_log_is_recovered_where_a_model_at_the_cg_is_biased():
    """A log 0.6 m forward and 0.25 m below the CG, turned 0.03 rad in yaw: from the example's
    a-priori values, `ml-gn` puts the mounting and the coefficients within 3 σ; the same data
    read as at the CG bias the coefficients beyond."""
    offsets = (FIN_OFFSET, -FIN_OFFSET)
    data = _mounted(_turns(offsets), _turns(offsets, noise=False), MOUNT)
    assert_recovered_beside_the_offsets(data, ("m_dvl_z", "r_dvl_x", "r_dvl_z"), MOUNT)


def test_a_given_mounting_is_read_by_the_output_error_methods_and_refused_by_the_others():
    """A known mounting in the config: `ml-gn`, `ml-lm` and `ml-nr` fit the mounted data as well as the
    same records read at the CG; the methods that read the velocities at the CG refuse it, free
    or given."""
    offsets = (FIN_OFFSET, -FIN_OFFSET)
    clean = _turns(offsets, 20.0, noise=False)
    data = _mounted(_turns(offsets, 20.0), clean, MOUNT)
    config = _start(LATERAL + ("Y_0", "N_0"), ("Y_0", "N_0"))
    given = config.with_coefficients(MOUNT)
    # ml-nr in scaled coordinates: in SI (the paper's), λ = max|∂J/∂x| mixes the mounting's
    # sizes (0.03 rad, 0.6 m) with the coefficients' (hundreds) and it stops at its limit
    for method, more in (("ml-gn", {}), ("ml-lm", {}), ("ml-nr", {"coordinates": "scaled"})):
        at_cg = identify(_turns(offsets, 20.0), config, method=method, **more)
        mounted = identify(data, given, method=method, **more)
        assert mounted.converged and mounted.cost == pytest.approx(at_cg.cost, abs=1.0)
    shared = _start(LATERAL)
    for method in ("mekf", "ekf", "equation-error", "ml-fem"):
        for config in (shared.with_coefficients(MOUNT), replace(shared, free=LATERAL + ("m_dvl_z",))):
            with pytest.raises(
                InputError, match=rf"m_dvl_z is free or not 0; {method} reads the velocities"
            ) as exc:
                identify(data, config, method=method)
            assert "\n" not in str(exc.value)


def test_a_mounting_beyond_its_range_is_refused():
    with pytest.raises(InputError, match=r"m_dvl_y = 0.7; expected within ±0.5 rad"):
        identify(_turns((FIN_OFFSET, -FIN_OFFSET), 5.0), _start(LATERAL).with_coefficients({"m_dvl_y": 0.7}))
