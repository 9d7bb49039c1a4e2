"""The linear model (docs/model.md): the affine structure against the table written out by hand."""

import numpy as np

from testbed.models.linear import (
    COEFFICIENTS,
    NTHETA,
    Vehicle,
    continuous,
    derivatives,
    discretize,
    structure,
    theta_vector,
    tilde,
)

from studies.remus import EXAMPLE_COEFFICIENTS, VEHICLE  # noqa: E402


def test_matrices_match_the_spec_table():
    veh = Vehicle(30.51, 0.177, 3.45, 3.6, 299.0, 306.0, 0.01, 0.002, -0.0196, 1.54)
    c = dict(zip(COEFFICIENTS, np.random.default_rng(1).normal(size=35)))
    m, U, W, B = veh.mass, veh.speed, veh.weight, veh.buoyancy
    Mt, At, Bt, St = tilde(structure(veh), theta_vector(c))
    M, A, Bm, S = np.eye(10), np.zeros((10, 10)), np.zeros((10, 3)), np.zeros(10)
    u, v, w, p, q, r, phi, th, psi, z = range(10)
    M[u, u] = m - c["X_udot"]
    A[u, u] = c["X_u"]
    A[u, th] = -(W - B)
    M[v, v] = m - c["Y_vdot"]
    M[v, p] = -c["Y_pdot"]
    M[v, r] = -c["Y_rdot"]
    A[v, v], A[v, p], A[v, r], A[v, phi] = c["Y_v"], c["Y_p"], c["Y_r"] - m * U, W - B
    Bm[v, 0] = c["Y_dr"]
    M[w, w] = m - c["Z_wdot"]
    M[w, q] = -c["Z_qdot"]
    A[w, w], A[w, q], S[w] = c["Z_w"], c["Z_q"] + m * U, W - B
    Bm[w, 1] = Bm[w, 2] = c["Z_de"] / 2
    M[p, v], M[p, p], M[p, r] = -c["K_vdot"], veh.Ix - c["K_pdot"], -c["K_rdot"]
    A[p, v], A[p, p], A[p, r], A[p, phi], S[p] = c["K_v"], c["K_p"], c["K_r"], veh.zB * B, -veh.yB * B
    Bm[p] = c["K_dr"], c["K_der"], -c["K_del"]
    M[q, w], M[q, q] = -c["M_wdot"], veh.Iy - c["M_qdot"]
    A[q, w], A[q, q], A[q, th], S[q] = c["M_w"], c["M_q"], veh.zB * B, veh.xB * B
    Bm[q, 1] = Bm[q, 2] = c["M_de"] / 2
    M[r, v], M[r, p], M[r, r] = -c["N_vdot"], -c["N_pdot"], veh.Iz - c["N_rdot"]
    A[r, v], A[r, p], A[r, r], A[r, phi], A[r, th] = c["N_v"], c["N_p"], c["N_r"], -veh.xB * B, -veh.yB * B
    Bm[r, 0] = c["N_dr"]
    A[phi, p] = A[th, q] = A[psi, r] = 1
    A[z, w], A[z, th] = 1, -U
    for got, want in ((Mt, M), (At, A), (Bt, Bm), (St, S)):
        np.testing.assert_array_equal(got, want)


def test_derivatives_against_central_differences():
    veh = Vehicle(30.51, 0.177, 3.45, 3.45, 299.0, 306.0, 0.0, 0.0, -0.0196, 1.54)
    s = structure(veh)
    theta = np.random.default_rng(2).normal(size=NTHETA) * 0.2  # the offsets as well
    A, B, S = continuous(s, theta)
    dA, dB, dS = derivatives(s, theta, A, B, S)
    h = 1e-6
    for i in range(NTHETA):
        e = np.zeros(NTHETA)
        e[i] = h
        (Ap, Bp, Sp), (Am, Bmn, Sm) = continuous(s, theta + e), continuous(s, theta - e)
        np.testing.assert_allclose(dA[i], (Ap - Am) / (2 * h), atol=1e-7)
        np.testing.assert_allclose(dB[i], (Bp - Bmn) / (2 * h), atol=1e-7)
        np.testing.assert_allclose(dS[i], (Sp - Sm) / (2 * h), atol=1e-7)


def test_discretize_handles_pure_integrators():
    # ẋ1 = x2, ẋ2 = u + s: A singular; closed form for a double integrator.
    A = np.array([[0.0, 1.0], [0.0, 0.0]])
    B = np.array([[0.0], [1.0]])
    S = np.array([0.0, 0.5])
    dt = 0.3
    Phi, Gamma, s = discretize(A, B, S, dt)
    np.testing.assert_allclose(Phi, [[1, dt], [0, 1]])
    np.testing.assert_allclose(Gamma[:, 0], [dt**2 / 2, dt])
    np.testing.assert_allclose(s, [0.5 * dt**2 / 2, 0.5 * dt])


def test_discretize_equals_scipy_expm_from_fine_to_coarse_steps():
    """The series with scaling and squaring against scipy's Padé `expm` of the block matrix,
    from steps far below the fastest mode to steps that square many times."""
    from scipy.linalg import expm

    A, B, S = continuous(structure(VEHICLE), theta_vector(EXAMPLE_COEFFICIENTS))
    big = np.zeros((14, 14))
    big[:10] = np.column_stack([A, B, S])
    for dt in (1e-4, 0.02, 0.5, 5.0, 60.0):
        ref = expm(big * dt)[:10]
        got = np.column_stack(discretize(A, B, S, dt))
        assert np.abs(got - ref).max() < 1e-12 * np.abs(ref).max()


def test_metacentric_heights_set_the_roll_and_pitch_stiffness_in_closed_form():
    """With GM and GM_L, and W = B (no restoring force in surge or sway), the roll and pitch
    rows alone are `(Ix − K_pdot) φ̈ = K_p φ̇ − W GM φ` and `(Iy − M_qdot) θ̈ = M_q θ̇ − W GM_L θ`:
    their roots `(K_p ± √(K_p² − 4 (Ix − K_pdot) W GM)) / (2 (Ix − K_pdot))` are A's eigenvalues;
    zB no longer enters either."""
    W, GM, GM_L = 300.0, 0.05, 1.2
    c = dict.fromkeys(COEFFICIENTS, 0.0) | {"K_p": -2.0, "K_pdot": -0.1, "M_q": -30.0, "M_qdot": -1.0}
    theta = theta_vector(c)
    eigs = []
    for zB in (-0.02, 0.3):
        veh = Vehicle(
            mass=30.0,
            Ix=0.2,
            Iy=3.0,
            Iz=3.2,
            weight=W,
            buoyancy=W,
            xB=0.0,
            yB=0.0,
            zB=zB,
            speed=1.5,
            GM=GM,
            GM_L=GM_L,
        )
        eigs.append(np.sort_complex(np.linalg.eigvals(continuous(structure(veh), theta)[0])))
    np.testing.assert_allclose(eigs[0], eigs[1])
    for inertia, damping, stiffness in ((0.2 + 0.1, -2.0, W * GM), (3.0 + 1.0, -30.0, W * GM_L)):
        for sign in (1, -1):
            root = (damping + sign * np.sqrt(complex(damping**2 - 4 * inertia * stiffness))) / (2 * inertia)
            assert np.min(np.abs(eigs[0] - root)) < 1e-9 * abs(root), (root, eigs[0])
    # without them, the zB B terms: roll stiffness −zB B
    veh = Vehicle(
        mass=30.0, Ix=0.2, Iy=3.0, Iz=3.2, weight=W, buoyancy=W, xB=0.0, yB=0.0, zB=-0.02, speed=1.5
    )
    At = tilde(structure(veh), theta)[1]
    assert At[3, 6] == -0.02 * W and At[4, 7] == -0.02 * W
