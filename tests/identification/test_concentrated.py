"""The simplex's cost (`concentrated.cost`) against the likelihood with the initial states fitted
by `likelihood.fit_initial_states` (QR of the initial-state responses, an independent solve)."""

from dataclasses import replace

import numpy as np
import pytest

from testbed.identification import concentrated, kernels, likelihood, recursions
from studies.remus import EXAMPLE_COEFFICIENTS, FREE, experiments, prior_config
from testbed.identification.problem import problem


def _reference(prob, values, R) -> float:
    """`J_M = 1/N Σ eᵀR⁻¹e` with the initial states fitted by QR; ∞ where the model diverges."""
    with np.errstate(over="ignore", invalid="ignore"):
        p = likelihood.initial_states(prob, values, R)
        if likelihood.divergence(prob, p) is not None:
            return np.inf
        return 2.0 * likelihood.weighted_cost(prob, recursions.residuals(prob, p), R) / prob.n_samples


def _mixed_records():
    """Records of three lengths, two sampling intervals and two sets of measured states."""
    horizontal, vertical = experiments(seed=4, duration=40.0)
    coarse = replace(
        horizontal, t=horizontal.t[::2], y=horizontal.y[::2], inputs=horizontal.inputs[::2], name="coarse"
    )
    keep = ("w", "q", "theta")
    short = replace(
        vertical,
        measured=keep,
        y=vertical.y[:517, [vertical.measured.index(s) for s in keep]],
        t=vertical.t[:517],
        inputs=vertical.inputs[:517],
    )
    return [horizontal, coarse, short]


def test_cost_is_the_likelihood_at_the_best_initial_states():
    prob = problem(_mixed_records(), prior_config(error=0.3))
    rng = np.random.default_rng(0)
    R = np.exp(rng.normal(-9, 1, len(prob.channels)))  # any R held: not the residuals' own
    truth = np.array([EXAMPLE_COEFFICIENTS[n] for n in FREE])
    for values in (prob.start, truth, truth * np.exp(0.05 * rng.normal(size=len(truth)))):
        want = _reference(prob, values, R)
        assert np.isfinite(want)
        assert concentrated.cost(prob, values, R) == pytest.approx(want, rel=1e-10)


def test_cost_of_a_diverging_model_is_infinite():
    prob = problem(experiments(seed=1, duration=60.0), prior_config(error=0.3))
    values = prob.start.copy()
    values[FREE.index("M_q")] = 3 * abs(EXAMPLE_COEFFICIENTS["M_q"])  # pitch unstable
    R = np.full(len(prob.channels), 1e-4)
    assert _reference(prob, values, R) == np.inf
    assert concentrated.cost(prob, values, R) == np.inf


def test_cost_of_a_strongly_unstable_model_is_exact():
    # pitch unstable at 0.29 1/s over 60 s (growth e¹⁷, outputs still bounded): the Gramian's
    # condition number is ~1e18, where the normal equations would overstate the cost by 0.3 %
    prob = problem(experiments(seed=1, duration=60.0), prior_config(error=0.3))
    values = prob.start.copy()
    values[FREE.index("M_q")] = -0.4 * EXAMPLE_COEFFICIENTS["M_q"]
    R = np.full(len(prob.channels), 1e-4)
    want = _reference(prob, values, R)
    assert np.isfinite(want)
    assert concentrated.cost(prob, values, R) == pytest.approx(want, rel=1e-10)


@pytest.mark.parametrize("N", [1, 2, 3, 8, 13, 1000])
def test_gramian_is_the_sum_of_its_terms(N):
    rng = np.random.default_rng(N)
    Phi = rng.normal(size=(6, 6))
    Phi *= 0.98 / np.max(np.abs(np.linalg.eigvals(Phi)))  # stable, slowly decaying
    C = rng.normal(size=(6, 6))
    Q = C.T @ C
    want, P = np.zeros((6, 6)), np.eye(6)
    for _ in range(N):
        want += P.T @ Q @ P
        P = Phi @ P
    np.testing.assert_allclose(kernels.gramian(Phi, Q, N), want, rtol=1e-10, atol=1e-12 * np.abs(want).max())


def _missing(experiments_, fraction, seed):
    """The experiments with a `fraction` of each state's samples missing (NaN) at random, and a
    depth sensor at a fifth of the rate where depth is measured (its other samples missing)."""
    rng = np.random.default_rng(seed)
    out = []
    for e in experiments_:
        y = e.y.copy()
        y[rng.random(y.shape) < fraction] = np.nan
        if "z" in e.measured:
            slow = np.ones(len(y), dtype=bool)
            slow[::5] = False
            y[slow, e.measured.index("z")] = np.nan
        out.append(replace(e, y=y))
    return out


def test_cost_with_missing_samples_is_the_likelihood_of_the_samples_present():
    """Records with samples missing (one record complete): the compiled cost (masked Gramian,
    adjoint and residuals) against the QR solve of `fit_initial_states` on the masked blocks."""
    records = _mixed_records()
    prob = problem(_missing(records[:2], 0.1, 3) + records[2:], prior_config(error=0.3))
    assert [r.present is None for r in prob.records] == [False, False, True]
    rng = np.random.default_rng(1)
    R = np.exp(rng.normal(-9, 1, len(prob.channels)))
    truth = np.array([EXAMPLE_COEFFICIENTS[n] for n in FREE])
    for values in (prob.start, truth):
        want = _reference(prob, values, R)
        assert np.isfinite(want)
        assert concentrated.cost(prob, values, R) == pytest.approx(want, rel=1e-10)


@pytest.mark.parametrize("missing", [0.3, 0.8, 1.0])
def test_masked_gramian_is_the_sum_over_the_samples_present(missing):
    """Few samples missing (the whole Gramian less their terms), most of them (the present ones'
    terms summed), a channel without any: against the sum written out, Φ with zeros."""
    rng = np.random.default_rng(2)
    Phi = np.eye(6) + 0.05 * rng.normal(size=(6, 6))
    Phi[:3, 3:] = 0.0
    measured, W = np.array([0, 2, 5, 4]), np.array([1.0, 2.0, 0.5, 3.0])
    P = (rng.random((40, 4)) > missing).astype(float)
    P[:, 3] = 1.0 if missing < 1 else 0.0
    P[-5:] = 0.0
    want, Pk = np.zeros((4, 4)), np.eye(6)
    for k in range(40):
        C = Pk[measured][:, measured]
        want += C.T @ np.diag(W * P[k]) @ C
        Pk = Pk @ Phi
    got = kernels.masked_gramian(Phi, measured, W, P)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-13 * np.abs(want).max())
    np.testing.assert_array_equal(got, got.T)
