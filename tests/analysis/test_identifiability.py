"""Structural identifiability: the null directions found against hand-derived row operations."""

import numpy as np

from testbed.analysis.structural import structural
from testbed.models.linear import COEFFICIENTS, ITHETA, NTHETA, STATES, Vehicle, continuous, structure, tilde

VEHICLE = Vehicle(30.51, 0.177, 3.45, 3.45, 299.0, 306.0, 0.0, 0.0, -0.0196, 1.54)
SWAY_YAW = (
    "Y_vdot",
    "Y_pdot",
    "Y_rdot",
    "Y_v",
    "Y_p",
    "Y_r",
    "Y_dr",
    "N_vdot",
    "N_pdot",
    "N_rdot",
    "N_v",
    "N_p",
    "N_r",
    "N_dr",
)


def _theta(seed=0):
    """Random coefficients, no offsets or biases."""
    return np.r_[
        np.random.default_rng(seed).normal(size=len(COEFFICIENTS)) * 5.0, np.zeros(NTHETA - len(COEFFICIENTS))
    ]


def _row_operation(s, theta, T):
    """θ' read back from T·[Mt At Bt] (each free coefficient's own entry); must reproduce T·model."""
    Mt, At, Bt = (T @ X for X in tilde(s, theta)[:3])
    new = theta.copy()
    for k, name in enumerate(COEFFICIENTS):
        for X, dX, X0 in ((Mt, s.dMt[k], s.Mt0), (At, s.dAt[k], s.At0), (Bt, s.dBt[k], s.Bt0)):
            hit = np.argwhere(dX != 0)
            if len(hit):
                i, j = hit[0]
                new[k] = (X[i, j] - X0[i, j]) / dX[i, j]
    return new


def test_sway_plus_yaw_and_yaw_scale_are_the_null_directions():
    # With xB = yB = 0 nothing known pins the yaw row (Iz − N_rdot is free as a whole), and the
    # yaw row has no φ, θ or δe terms, so "sway += e·yaw" and "yaw *= 1+e" leave A, B, S unchanged.
    s, theta = structure(VEHICLE), _theta()
    v, r = STATES.index("v"), STATES.index("r")
    free_idx = [ITHETA[n] for n in SWAY_YAW]
    directions = []
    for T in (
        np.eye(10) + 0.3 * np.eye(10)[:, [v]] @ np.eye(10)[[r]],
        np.eye(10) + 0.3 * np.eye(10)[:, [r]] @ np.eye(10)[[r]],
    ):
        new = _row_operation(s, theta, T)
        changed = np.flatnonzero(~np.isclose(new, theta))
        assert set(changed) <= set(free_idx)
        for a, b in zip(continuous(s, theta), continuous(s, new)):
            np.testing.assert_allclose(a, b, atol=1e-10)
        directions.append((new - theta)[free_idx])
    result = structural(s, theta, SWAY_YAW, STATES)
    assert result.null_directions == 2
    # The hand-derived directions lie in the reported null space, and span it.
    basis = result.basis
    for d in directions:
        residual = d - basis.T @ np.linalg.lstsq(basis.T, d, rcond=None)[0]
        assert np.linalg.norm(residual) < 1e-8 * np.linalg.norm(d)
    assert np.linalg.matrix_rank(np.array(directions)) == 2
    assert {frozenset(g) for g in result.drift_groups} == {frozenset(SWAY_YAW[:7]), frozenset(SWAY_YAW[7:])}


def test_offset_centre_of_buoyancy_pins_the_yaw_row():
    # yB ≠ 0 makes −yB B θ a known yaw term that no other row with a free Mt entry carries:
    # the yaw scale and sway += yaw both break (xB ≠ 0 would not: (W − B) φ in sway compensates).
    s = structure(Vehicle(30.51, 0.177, 3.45, 3.45, 299.0, 306.0, 0.0, 0.01, -0.0196, 1.54))
    assert structural(s, _theta(), SWAY_YAW, STATES).null_directions == 0


def test_well_posed_case_has_no_null_direction():
    free = ("X_u", "Y_v", "Y_r", "Y_dr", "Z_w", "Z_q", "K_p", "M_q", "M_de", "N_v", "N_r", "N_dr")
    assert structural(structure(VEHICLE), _theta(1), free, STATES).null_directions == 0


def test_a_singular_information_shows_as_named_null_directions():
    """F = JᵀJ with b's column twice a's (J (1, −½, 0, 0) = 0) and no information on d: two null
    directions beyond the structure's, named, exactly the coefficients with infinite bounds."""
    from testbed.analysis.identifiability import assessed
    from testbed.analysis.structural import Structural

    free = ("a", "b", "c", "d")
    rng = np.random.default_rng(3)
    col = rng.normal(size=(50, 2))
    J = np.column_stack([col[:, 0] * 1e3, 2e3 * col[:, 0], col[:, 1], np.zeros(50)])
    F = J.T @ J
    result = assessed(free, np.array([1.0, 2.0, 3.0, 4.0]), F, Structural(free, np.zeros((0, 4)), ()))
    assert result.null_directions == 2
    np.testing.assert_allclose(result.singular, [[1.0, -0.5, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]], atol=1e-9)
    np.testing.assert_allclose(J @ result.singular.T, 0.0, atol=1e-9 * np.abs(J).max())
    assert set(result.singular_groups) == {("a", "b"), ("d",)} and set(result.drift_groups) >= {
        ("a", "b"),
        ("d",),
    }
    assert [n for n, s in zip(free, result.crlb_std) if np.isinf(s)] == ["a", "b", "d"]
    doc = __import__("json").loads(result.to_json())
    assert doc["null_directions"] == 2 and len(doc["null_basis"]) == 2
    assert any("singular along 2 directions" in line and "da - 0.5 db" in line for line in result.summary)


def test_analyze_and_the_screen_name_an_unexcited_row_as_null_directions():
    """Dives with the rudder at 0 and sway fitted, no yaw rate: the rudder's yaw moment has no
    information. analyze reports it as a null direction (not 0 beside an infinite bound), and
    the screen's first stage fixes it naming the direction analyze lists."""
    from testbed.analysis.identifiability import identifiability
    from testbed.analysis.screening import structurally_unidentified
    from studies.remus import example_config, experiments

    vertical = experiments(seed=0, duration=20.0)[1].only(("v", "psi"))
    config = example_config(free=("N_v", "N_r", "N_dr"))
    result = identifiability([vertical], config)
    unbounded = {n for n, s in zip(result.free, result.crlb_std) if not np.isfinite(s)}
    assert unbounded == {"N_dr"}
    assert result.null_directions == 1 and {n for g in result.drift_groups for n in g} >= unbounded
    fixed = structurally_unidentified(result)
    assert set(fixed) == unbounded and "singular along dN_dr " in fixed["N_dr"]
