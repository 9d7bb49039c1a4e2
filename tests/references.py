"""Independent references the output-error tests share: complex-step sensitivities and the
likelihood with the initial states from QR factors."""

import numpy as np

from testbed.identification import likelihood, recursions


def assert_sensitivities_match_complex_step(prob, p: np.ndarray) -> list[np.ndarray]:
    """`recursions.sensitivities(prob, p)` against the complex-step derivatives of the outputs,
    column by column (another record's own parameters move nothing); the sensitivities."""
    sens = recursions.sensitivities(prob, p)
    h = 1e-30
    for j in range(prob.n_params):
        pc = p.astype(complex)
        pc[j] += 1j * h
        for r, S, yc in zip(prob.records, sens, recursions.simulated_outputs(prob, pc)):
            ref, cols = yc.imag / h, list(prob.columns(r))
            if j not in cols:  # another experiment's initial state
                assert not ref.any()
                continue
            np.testing.assert_allclose(S[:, :, cols.index(j)], ref, rtol=1e-9, atol=1e-12 * np.abs(ref).max())
    return sens


def assert_curvature_matches_complex_step(prob, p: np.ndarray, weights) -> None:
    """`recursions.curvature(prob, p, weights)` against the complex-step derivatives of the
    weighted first-order sensitivities, and symmetric."""
    H = recursions.curvature(prob, p, weights)
    ref = np.zeros_like(H)
    h = 1e-30
    for j in range(prob.n_params):
        pc = p.astype(complex)
        pc[j] += 1j * h
        for r, w, S in zip(prob.records, weights, recursions.sensitivities(prob, pc)):
            ref[prob.columns(r), j] += np.einsum("nk,nkp->p", w, S.imag / h)
    np.testing.assert_allclose(H, ref, rtol=1e-9, atol=1e-11 * np.abs(ref).max())
    np.testing.assert_allclose(H, H.T, atol=1e-12 * np.abs(H).max())


def qr_cost(prob, values: np.ndarray, R: np.ndarray) -> float:
    """J_M at the free `values` with R held, the initial states from `likelihood.fit_initial_states`
    (QR factors): what the simplex's concentrated cost must equal."""
    out = likelihood.fit_initial_states(prob, values, R)[1]
    return (
        sum(float(np.sum(r.residual(y) ** 2 / R[r.channels])) for r, y in zip(prob.records, out))
        / prob.n_samples
    )
