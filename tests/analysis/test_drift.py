"""Drift in practice: the normalised Mt-form, the two forms' Fisher information and the seeds'
scatter along the near-null directions, each against an independent reference."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from testbed.analysis import drift
from testbed.analysis.structural import structural
from testbed.errors import InputError
from testbed.identification.bounds import crlb, eliminated, fisher
from studies.remus import NOISE, example_config, inputs
from testbed.identification.prediction import synthetic
from testbed.models.linear import ITHETA, NX, STATES, structure, theta_vector
from testbed.simulation.analytic import analytic_config


def _null(config, free) -> int:
    s = structure(config.vehicle)
    return structural(s, theta_vector(config.coefficients), free, STATES).null_directions


@pytest.mark.parametrize("which", ["torpedo", "example"])
def test_normalised_leaves_no_exact_null_direction_and_no_inertia_term_more_could_be_free(which):
    config = analytic_config()[0] if which == "torpedo" else example_config()
    mt = drift.normalised(config)
    assert set(config.free) <= set(mt.free)
    assert not set(drift.DIAGONAL) & set(mt.free)
    assert _null(config, mt.free) == 0
    # it fixes more than the diagonals exactly where the diagonals alone leave null directions
    # (the torpedo, neutrally buoyant, yes; the example, 7 N buoyant, whose W − B pins v's row, no)
    diagonal_only = [*mt.free, *(n for n in drift.ADDED_MASS if n not in mt.free and n not in drift.DIAGONAL)]
    assert (_null(config, diagonal_only) > 0) == (len(diagonal_only) > len(mt.free)) == (which == "torpedo")
    for n in drift.ADDED_MASS:  # each off-diagonal term it fixed would bring a null direction back
        if n not in mt.free and n not in drift.DIAGONAL:
            assert _null(config, [*mt.free, n]) == 1, n


def test_normalised_on_the_torpedo_frees_the_couplings_the_restoring_moments_pin():
    mt = drift.normalised(analytic_config()[0])
    assert [n for n in mt.free if n in drift.ADDED_MASS] == ["Y_pdot", "Z_qdot", "K_vdot", "M_wdot", "N_pdot"]


def test_fisher_is_the_finite_difference_jacobian_with_the_initial_states_eliminated():
    config = drift.normalised(replace(example_config(), free=("Y_v", "N_r", "N_dr", "M_q", "M_de")))
    assert "M_wdot" in config.free and "Z_qdot" in config.free
    t, u = inputs(duration=6.0, dt=0.05)["vertical"]
    u = u + inputs(duration=6.0, dt=0.05)["horizontal"][1]
    free = config.free

    def outputs(q):  # q = (θ_free, x0): the noise-free outputs, all states, stacked and whitened
        values = dict(zip(free, q[: len(free)]))
        e = synthetic(config.with_coefficients(values), t, u, x0=q[len(free) :])
        return (e.y / np.array([NOISE[m] for m in e.measured])).ravel()

    q = np.concatenate([theta_vector(config.coefficients)[[ITHETA[n] for n in free]], np.zeros(NX)])
    h = 1e-5 * np.maximum(np.abs(q), 1.0)
    J = np.column_stack(
        [(outputs(q + h[i] * e) - outputs(q - h[i] * e)) / (2 * h[i]) for i, e in enumerate(np.eye(len(q)))]
    )
    M, k = J.T @ J, len(free)
    reference = M[:k, :k] - M[:k, k:] @ np.linalg.solve(M[k:, k:], M[k:, :k])
    data = [synthetic(config, t, u)]
    F = fisher(data, config, noise_std=NOISE)
    np.testing.assert_allclose(F, reference, rtol=1e-5, atol=1e-7 * np.abs(reference).max())


def _hand_form(values, relative_information):
    """A Form of the example config with `values` free and the relative information given."""
    config = example_config(tuple(values))
    s = np.abs(np.array([config.coefficients[n] for n in values]))
    return drift.form(relative_information / np.outer(s, s), config)


def test_a_copy_of_an_initial_state_keeps_no_information_and_an_infinite_bound():
    """Sensitivities J = [a, b, c, c]: the third parameter is the initial state (the last column)
    again. Eliminated, its information is rounding, zeroed; the others' bounds are those of the
    closed form with the initial state alone beside them."""
    rng = np.random.default_rng(3)
    a, b, c = rng.normal(size=(3, 500)) * [[1.0], [1e3], [1e-2]]
    J = np.column_stack([a, b, c, c])
    F = eliminated(J.T @ J, 3)
    assert np.all(F[2] == 0.0) and np.all(F[:, 2] == 0.0)
    bounds = crlb(F)
    assert np.isinf(bounds.std[2])
    K = np.column_stack([a, b, c])
    exact = np.sqrt(np.diag(np.linalg.inv(K.T @ K))[:2])
    np.testing.assert_allclose(bounds.std[:2], exact, rtol=1e-9)


def test_condition_correlation_and_worst_direction_of_a_hand_built_ill_conditioned_case():
    Q = np.array([[1.0, 1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 0.0, np.sqrt(2.0)]]) / np.sqrt(2.0)
    f = _hand_form(("Y_v", "Y_r", "N_r"), Q @ np.diag([1e-5, 1.0, 3.0]) @ Q.T)
    assert f.condition == pytest.approx(3e5, rel=1e-8)
    a, b, rho = f.correlation
    assert (a, b) == ("Y_v", "Y_r")
    assert rho == pytest.approx((1e5 - 1) / (1e5 + 1), rel=1e-9)  # cov = Q diag(1e5, 1, 1/3) Qᵀ
    np.testing.assert_allclose(f.eigenvectors[:, 0], [2**-0.5, 2**-0.5, 0.0], atol=1e-9)
    np.testing.assert_allclose(f.eigenvalues, [1e-5, 1.0, 3.0], rtol=1e-8)


@pytest.fixture(scope="module")
def hand_forms():
    rng = np.random.default_rng(5)
    G = rng.normal(size=(5, 5))
    Q = np.linalg.qr(G)[0]
    mt = _hand_form(("Y_v", "Y_r", "N_v", "N_r", "Y_rdot"), Q @ np.diag([1e-6, 1e-4, 1e-2, 1.0, 5.0]) @ Q.T)
    a = _hand_form(("Y_v", "Y_r", "N_v", "N_r"), np.diag([0.5, 2.0, 4.0, 8.0]))
    return drift.Forms(mt=mt, a=a, null_directions_mt=0, noise_std={})


def _draws(f, n, rng, drift_sigmas=0.0):
    cov = np.linalg.inv(f.fisher)
    theta = rng.multivariate_normal(f.values, cov, size=n)
    if drift_sigmas:  # a drift along the worst direction, drift_sigmas of its Cramér-Rao σ
        sigma = 1.0 / np.sqrt(f.eigenvalues[0])
        theta += np.outer(rng.normal(size=n) * drift_sigmas * sigma, f.eigenvectors[:, 0] * f.scales)
    return [dict(zip(f.free, row)) for row in theta]


def test_evidence_scatter_is_one_for_estimates_drawn_from_the_bounds(hand_forms):
    rng, n = np.random.default_rng(11), 400
    ev = drift.evidence(hand_forms, _draws(hand_forms.mt, n, rng), _draws(hand_forms.a, n, rng))
    json.dumps(ev, allow_nan=False)
    se = 1.0 / np.sqrt(2 * (n - 1))  # relative standard error of a sample σ
    for r in ev["null_scatter_mt_directions"] + ev["null_scatter_a_directions"]:
        assert abs(r - 1.0) < 4 * se
    assert abs(ev["null_scatter_mt"] - 1.0) < 4 * se and abs(ev["null_scatter_a"] - 1.0) < 4 * se
    assert ev["condition_mt"] == pytest.approx(5e6, rel=1e-6) and ev["condition_a"] == pytest.approx(16.0)
    assert ev["seeds"] == n and ev["near_null"] == drift.NEAR_NULL
    assert set(ev["null_direction_mt"]) <= set(hand_forms.mt.free)
    # the relative drift along the worst direction is its relative Cramér-Rao σ, 1/√1e-6
    assert ev["relative_drift_mt"] == pytest.approx(1e3, rel=4 * se)


def test_evidence_scatter_grows_with_a_drift_along_the_null_direction(hand_forms):
    rng, n = np.random.default_rng(12), 400
    ev = drift.evidence(hand_forms, _draws(hand_forms.mt, n, rng, 10.0), _draws(hand_forms.a, n, rng))
    assert ev["null_scatter_mt_directions"][0] == pytest.approx(np.sqrt(101.0), rel=0.15)
    assert ev["null_scatter_mt"] > 5.0
    assert abs(ev["null_scatter_a"] - 1.0) < 0.2


def test_evidence_needs_two_seeds_and_every_coefficient(hand_forms):
    rng = np.random.default_rng(0)
    one = _draws(hand_forms.mt, 1, rng)
    with pytest.raises(InputError, match="at least 2 seeds"):
        drift.evidence(hand_forms, one, _draws(hand_forms.a, 3, rng))
    partial = [{k: v for k, v in e.items() if k != "N_r"} for e in _draws(hand_forms.mt, 3, rng)]
    with pytest.raises(InputError, match="no N_r"):
        drift.evidence(hand_forms, partial, _draws(hand_forms.a, 3, rng))
    nan = _draws(hand_forms.mt, 3, rng)
    nan[1]["Y_v"] = float("nan")
    with pytest.raises(InputError, match=r"estimates_mt\[1\]: Y_v = nan"):
        drift.evidence(hand_forms, nan, _draws(hand_forms.a, 3, rng))


def test_forms_of_the_example_data():
    config = example_config()
    data = [
        synthetic(config, t, u, NOISE, rng=np.random.default_rng(1), name=k) for k, (t, u) in inputs().items()
    ]
    f = drift.forms(data, config)
    assert f.a.free == config.free and f.mt.free == drift.normalised(config).free
    assert f.null_directions_mt == 0
    for which, cfg in ((f.mt, drift.normalised(config)), (f.a, config)):
        np.testing.assert_allclose(which.fisher, fisher(data, cfg, noise_std=f.noise_std), rtol=1e-12)
    # the A-form's scaled information is a principal submatrix of the Mt-form's (same scales):
    # its eigenvalues interlace, so its condition number is no larger
    assert f.mt.condition > f.a.condition


def test_evidence_shared_scatter_compares_the_coefficients_both_forms_estimate(hand_forms):
    mt, a = hand_forms.mt, hand_forms.a
    rng = np.random.default_rng(3)
    base = rng.normal(size=(6, len(a.free)))  # the same relative deviations in both forms
    est_a = [dict(zip(a.free, a.values * (1 + 0.01 * z))) for z in base]
    est_mt = [
        {**e, "Y_rdot": mt.values[mt.free.index("Y_rdot")] * (1 + 0.5 * w)} for e, w in zip(est_a, base[:, 0])
    ]
    ev = drift.evidence(hand_forms, est_mt, est_a)
    # the reference: rms over Y_v, Y_r, N_v, N_r of the sample σ of θ/|θ|, by hand
    expected = np.sqrt(np.mean((0.01 * base.std(0, ddof=1)) ** 2))
    assert ev["shared_scatter_mt"] == pytest.approx(expected, rel=1e-9)
    assert ev["shared_scatter_a"] == pytest.approx(expected, rel=1e-9)  # Y_rdot is not shared
    loose = [{**e, "N_v": e["N_v"] * (1 + 0.2 * w)} for e, w in zip(est_mt, rng.normal(size=6))]
    ev = drift.evidence(hand_forms, loose, est_a)
    assert ev["shared_scatter_mt"] > 3 * ev["shared_scatter_a"]
    # the A-form's relative information is diag(0.5, 2, 4, 8): its worst direction is Y_v alone
    assert ev["relative_drift_a"] == pytest.approx(np.sqrt(np.mean((0.01 * base[:, 0]) ** 2)), rel=1e-9)
    json.dumps(ev, allow_nan=False)
