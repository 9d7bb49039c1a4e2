"""The nonlinear model against independent references: complex-step derivatives, finite
differences, the linear model's own matrices, hand-derived linearisations, closed-form restoring
forces, rotation matrices, Newton-Euler; and the term-set fit on data it must reproduce."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
from nonlinear_reference import SCENARIO_I, fit_terms, sample_box

from testbed.errors import InputError
from testbed.models import linear, nonlinear_kernels
from testbed.models.mechanics import coriolis, kinematics
from testbed.models.nonlinear import (
    INERTIA,
    TERMS,
    forces,
    jacobians,
    linearise,
    nonlinear_model,
    packed,
    rates,
    rate_sensitivities,
    nonlinear_theta,
    thrust,
)
from testbed.models.regressors import WEIGHTS, parse_term, regressors

# A torpedo-like body (SI): CB 2 cm above the CG, slightly heavy, off-diagonal added mass.
VEHICLE = linear.Vehicle(
    mass=170.0,
    Ix=2.2,
    Iy=67.0,
    Iz=67.5,
    weight=1700.0,
    buoyancy=1675.0,
    xB=0.01,
    yB=0.002,
    zB=-0.02,
    speed=20.0,
)
DOTS = {
    "X_udot": -8.0,
    "Y_vdot": -158.0,
    "Y_pdot": -3.0,
    "Y_rdot": -2.3,
    "Z_wdot": -159.0,
    "Z_qdot": 2.4,
    "K_vdot": -3.0,
    "K_pdot": -0.4,
    "K_rdot": -0.4,
    "M_wdot": 2.4,
    "M_qdot": -55.0,
    "N_vdot": -2.3,
    "N_pdot": -0.4,
    "N_rdot": -56.0,
}


def model_and_theta(seed=0):
    model = nonlinear_model(VEHICLE)
    rng = np.random.default_rng(seed)
    coefficients = dict(DOTS)
    coefficients.update({t.name: rng.normal() * 50.0 for t in model.terms})
    return model, nonlinear_theta(model, coefficients), coefficients


def samples(n=6, seed=1):
    """States at large angles and rates (not at any kink of |x|), fins beyond Scenario I's."""
    rng = np.random.default_rng(seed)
    x = np.column_stack(
        [
            rng.uniform(5, 25, n),
            rng.uniform(-3, 3, (n, 2)),
            rng.uniform(-2, 2, (n, 3)),
            rng.uniform(-1.3, 1.3, (n, 2)),
            rng.uniform(-3, 3, n),
            rng.uniform(0, 100, n),
        ]
    )
    return x, rng.uniform(-0.5, 0.5, (n, 3))


def complex_step(f, z, h=1e-30):
    """∂f/∂z by complex step (exact to rounding): columns stacked last."""
    return np.stack([f(z + 1j * h * e).imag / h for e in np.eye(z.shape[-1])], axis=-1)


def close(a, b, rtol):
    """Agreement relative to the larger array's magnitude."""
    return np.abs(a - b).max() <= rtol * max(np.abs(a).max(), np.abs(b).max())


def test_jacobians_match_complex_step():
    model, theta, _ = model_and_theta()
    x, delta = samples()
    f, A, B = jacobians(model, theta, x, delta)
    assert close(f, rates(model, theta, x, delta), 1e-14)
    assert close(A, complex_step(lambda z: rates(model, theta, z, delta), x.astype(complex)), 1e-13)
    assert close(B, complex_step(lambda z: rates(model, theta, x, z), delta.astype(complex)), 1e-13)
    one = jacobians(model, theta, x[0], delta[0])  # one sample: unstacked
    assert one[1].shape == (10, 10) and np.allclose(one[1], A[0], rtol=0, atol=0)


def test_rates_are_the_equation_assembled_from_independent_parts():
    """ẋ against M⁻¹ (−C(ν)ν + g(η) + T e_x + Σ c_k φ_k) built here from np.cross, the rotation
    matrix and the regressors' named products, and the Euler rates from the rotation's."""
    model, theta, c = model_and_theta()
    x, delta = samples()
    M = model.inertia(theta)
    rB = np.array([VEHICLE.xB, VEHICLE.yB, VEHICLE.zB])
    phi = regressors(model.terms, x[:, :6], delta)
    got = rates(model, theta, x, delta)
    for n in range(len(x)):
        nu, h = x[n, :6], M @ x[n, :6]
        F = -np.concatenate([np.cross(nu[3:], h[:3]), np.cross(nu[3:], h[3:]) + np.cross(nu[:3], h[:3])])
        down = rotation(*x[n, 6:9]).T @ np.array([0, 0, 1.0])
        F += np.concatenate(
            [(VEHICLE.weight - VEHICLE.buoyancy) * down, np.cross(rB, -VEHICLE.buoyancy * down)]
        )
        F[0] += thrust(model, theta)
        for k, term in enumerate(model.terms):
            F[term.row] += c[term.name] * phi[n, k]
        sf, cf, tt = math.sin(x[n, 6]), math.cos(x[n, 6]), math.tan(x[n, 7])
        p, q, r = nu[3:]
        euler = [p + (q * sf + r * cf) * tt, q * cf - r * sf, (q * sf + r * cf) / math.cos(x[n, 7])]
        depth = (rotation(*x[n, 6:9]) @ nu[:3])[2]
        assert close(got[n], np.concatenate([np.linalg.solve(M, F), euler, [depth]]), 1e-14)


def test_any_term_set_is_evaluated_from_its_factor_table():
    """Terms of up to six factors over every atom and magnitude: the named products, and the
    Jacobians and sensitivities by complex step of the same compiled code."""
    names = ("X_uvwpqr", "Y_|u||v||w||p||q||r|", "Z_drdedada", "K_|dr||de||da|", "M_u|de|", "N_vdr|r|")
    model = nonlinear_model(VEHICLE, names)
    rng = np.random.default_rng(3)
    theta = nonlinear_theta(model, {**DOTS, **{n: rng.normal() * 10 for n in names}})
    x, delta = samples(seed=9)
    u, v, w, p, q, r = x[:, :6].T
    dr, de, da = delta[:, 0], (delta[:, 1] + delta[:, 2]) / 2, (delta[:, 1] - delta[:, 2]) / 2
    want = np.column_stack(
        [
            u * v * w * p * q * r,
            abs(u * v * w * p * q * r),
            dr * de * da * da,
            abs(dr * de * da),
            u * abs(de),
            v * dr * abs(r),
        ]
    )
    F = forces(model, theta, x, delta)
    F0 = forces(model, nonlinear_theta(model, DOTS), x, delta)
    # one term per row, X..N; X_uvwpqr is 0 in straight flight, so the thrust holds none of it
    assert close(F - F0, want * theta[len(INERTIA) :], 1e-14)
    f, A, B = jacobians(model, theta, x, delta)
    assert close(A, complex_step(lambda z: rates(model, theta, z, delta), x.astype(complex)), 1e-13)
    assert close(B, complex_step(lambda z: rates(model, theta, x, z), delta.astype(complex)), 1e-13)
    S = rate_sensitivities(model, theta, x, delta)
    assert close(S, complex_step(lambda t: rates(model, t, x, delta), theta.astype(complex)), 1e-13)


def test_a_rows_offset_is_a_constant_force_and_the_linear_models_offset():
    """`Y_0` … `N_0` (a term of no factor): the forces move by the offsets exactly, wherever the
    state; the linearisation's offsets are theirs; the derivatives by complex step of the same
    code; `X_0`, which the thrust would cancel at trim, is refused with the reason."""
    offsets = {"Y_0": 40.0, "Z_0": -25.0, "K_0": 3.0, "M_0": 60.0, "N_0": -45.0}
    model = nonlinear_model(VEHICLE, ("Y_uv", "N_ur", *offsets))
    assert [parse_term(n).factors for n in offsets] == [()] * 5
    base = {**DOTS, "Y_uv": -30.0, "N_ur": -15.0}
    theta, still = nonlinear_theta(model, {**base, **offsets}), nonlinear_theta(model, base)
    x, delta = samples(seed=5)
    assert close(
        forces(model, theta, x, delta) - forces(model, still, x, delta),
        np.tile([0.0, *offsets.values()], (len(x), 1)),
        1e-14,
    )
    moved = linearise(model, theta).coefficients
    assert all(
        moved[n] - linearise(model, still).coefficients[n] == pytest.approx(v, abs=1e-9)
        for n, v in offsets.items()
    )
    f, A, B = jacobians(model, theta, x, delta)
    assert close(A, complex_step(lambda z: rates(model, theta, z, delta), x.astype(complex)), 1e-13)
    S = rate_sensitivities(model, theta, x, delta)
    assert close(S, complex_step(lambda t: rates(model, t, x, delta), theta.astype(complex)), 1e-13)
    with pytest.raises(InputError, match="'X_0': the thrust balances the surge row"):
        nonlinear_model(VEHICLE, ("X_0",))


def test_a_pair_magnitude_atom_is_evaluated_with_its_exact_gradient():
    """Atoms √(z_i² + z_j²) of pairs of z = (ν, δ) (`regressors.PAIRS`' form), given to the compiled
    model directly: the terms' forces against the formula, the Jacobians against complex steps of
    the same compiled rates, and no slope at a pair's zero (the mean of its one-sided slopes)."""
    model = nonlinear_model(VEHICLE, ())
    L = WEIGHTS.shape[1]
    c = np.array([3.0, -2.0, 5.0])

    def kernel_model(dtype, coefficients):
        m = list(packed(model, nonlinear_theta(model, DOTS), dtype))
        m[1] = np.array([[1, 2 * L], [2 * L + 1, 2 * L + 1], [2 * L, L]])  # v|vw|, |qδr|², |vw|·|u|
        m[2], m[3], m[8] = np.array([1, 5, 2]), coefficients.astype(dtype), np.zeros(3)
        m[12] = np.array([[1, 2], [4, 6]])
        m[13], m[14] = np.full(3, -1), np.full(3, -1)  # no component terms
        return tuple(m)

    def evaluated(coefficients, x, d, jacobian=False):
        """(F, f, A, B) of the compiled model at the samples (A, B one sample of scratch unless
        `jacobian`)."""
        n, J = len(x), len(x) if jacobian else 1
        F, JF, f = np.empty((n, 6), x.dtype), np.empty((J, 6, 13), x.dtype), np.empty((n, 10), x.dtype)
        A, B, G = np.empty((J, 10, 10), x.dtype), np.empty((J, 10, 3), x.dtype), np.empty((1, 10, 0), x.dtype)
        nonlinear_kernels.state_model(
            kernel_model(x.dtype.type, coefficients), x, d, F, JF, f, A, B, G, jacobian, False
        )
        return F, f, A, B

    def rates_of(x, d, coefficients=c):
        return evaluated(coefficients, x, d)[1]

    x, delta = samples(seed=11)
    F, F0 = evaluated(c, x, delta)[0], evaluated(0 * c, x, delta)[0]
    u, v, w, q = x[:, 0], x[:, 1], x[:, 2], x[:, 4]
    want = np.zeros((len(x), 6))
    want[:, 1] = c[0] * v * np.hypot(v, w)
    want[:, 5] = c[1] * (q**2 + delta[:, 0] ** 2)
    want[:, 2] = c[2] * np.hypot(v, w) * np.abs(u)
    assert close(F - F0, want, 1e-14)
    _, f, A, B = evaluated(c, x, delta, jacobian=True)
    assert close(f, rates_of(x, delta), 0)
    assert close(A, complex_step(lambda z: rates_of(z, delta.astype(complex)), x.astype(complex)), 1e-13)
    assert close(B, complex_step(lambda z: rates_of(x.astype(complex), z), delta.astype(complex)), 1e-13)
    x[:, 1:3] = 0.0  # v = w = 0: |vw| has no slope there, and |vw|·|u| none along u
    A0 = evaluated(np.zeros(3), x, delta, jacobian=True)[2]
    A = evaluated(np.array([0.0, 0.0, 1.0]), x, delta, jacobian=True)[2]
    assert np.array_equal(A, A0)


def test_sensitivities_match_complex_step():
    model, theta, _ = model_and_theta()
    x, delta = samples()
    S = rate_sensitivities(model, theta, x, delta)
    reference = complex_step(lambda t: rates(model, t, x, delta), theta.astype(complex))
    assert S.shape == (len(x), 10, len(INERTIA) + len(TERMS))
    assert close(S, reference, 1e-13)


def test_linearisation_matches_finite_differences_of_f():
    model, theta, _ = model_and_theta()
    lin = linearise(model, theta)
    A = np.linalg.solve(lin.Mt, lin.At)
    B = np.linalg.solve(lin.Mt, lin.Bt)
    x0, d0 = np.zeros(10), np.zeros(3)
    x0[0] = VEHICLE.speed
    hx = np.array([1e-4] + [1e-7] * 9)
    hd = 1e-6
    Afd = np.column_stack(
        [
            (rates(model, theta, x0 + e, d0) - rates(model, theta, x0 - e, d0)) / (2 * e.sum())
            for e in np.diag(hx)
        ]
    )
    Bfd = np.column_stack(
        [(rates(model, theta, x0, e) - rates(model, theta, x0, -e)) / (2 * hd) for e in np.eye(3) * hd]
    )
    # central differences: error O(h²) times third derivatives, O(h) times the coefficient for the
    # x|x| terms (their second derivative jumps at 0): far below 1e-6 of the entries at these steps
    assert close(A, Afd, 1e-6) and close(B, Bfd, 1e-6)
    # the thrust holds the speed; what is left at trim is the restoring (this body is heavy, its CB off)
    assert rates(model, theta, x0, d0) == pytest.approx(np.linalg.solve(lin.Mt, lin.St), rel=1e-12, abs=1e-15)
    assert rates(model, theta, x0, d0)[0] == 0.0


def test_linearisation_is_the_linear_model_with_its_coefficients():
    model, theta, c = model_and_theta()
    lin = linearise(model, theta)
    assert lin.outside == ()  # the default terms give nothing the linear table lacks
    s = linear.structure(VEHICLE)
    full = linear.theta_vector(lin.coefficients)
    Mt, At, Bt, St = linear.tilde(s, full)
    scale = np.abs(lin.At).max()
    assert close(Mt, lin.Mt, 1e-14) and np.abs(At - lin.At).max() < 1e-13 * scale and close(Bt, lin.Bt, 1e-14)
    A, B, _ = linear.continuous(s, full)
    assert close(A, np.linalg.solve(lin.Mt, lin.At), 1e-12) and close(
        B, np.linalg.solve(lin.Mt, lin.Bt), 1e-12
    )
    # the mapping by hand: regressor slopes at (U, 0) and Kirchhoff's linear part (docs/model.md)
    U, k = VEHICLE.speed, lin.coefficients
    expected = {
        "X_u": 2 * U * c["X_uu"],
        "Y_v": U * c["Y_uv"],
        "Y_p": U * c["Y_up"],
        "Y_r": U * (c["Y_ur"] + c["X_udot"]),
        "Y_dr": U**2 * c["Y_uudr"],
        "Z_w": U * c["Z_uw"],
        "Z_q": U * (c["Z_uq"] - c["X_udot"]),
        "Z_de": U**2 * c["Z_uude"],
        "K_v": U * c["K_uv"],
        "K_p": U * c["K_up"],
        "K_r": U * c["K_ur"],
        "K_der": U**2 * c["K_uuda"] / 2,
        "K_del": U**2 * c["K_uuda"] / 2,
        "M_w": U * (c["M_uw"] + c["X_udot"] - c["Z_wdot"]),
        "M_q": U * (c["M_uq"] - c["Z_qdot"]),
        "M_de": U**2 * c["M_uude"],
        "N_v": U * (c["N_uv"] + c["Y_vdot"] - c["X_udot"]),
        "N_p": U * (c["N_up"] + c["Y_pdot"]),
        "N_r": U * (c["N_ur"] + c["Y_rdot"]),
        "N_dr": U**2 * c["N_uudr"],
        "K_dr": 0.0,
        **{n: c[n] for n in INERTIA},
        **{n: 0.0 for n in linear.OFFSETS},
    }
    assert set(expected) == set(k)
    for name, value in expected.items():
        assert k[name] == pytest.approx(value, rel=1e-12, abs=1e-9), name


def test_a_term_outside_the_linear_table_is_named():
    model = nonlinear_model(VEHICLE, ("X_uu", "M_uu", "Z_uw", "X_uw"))
    theta = nonlinear_theta(model, {**DOTS, "X_uu": -6.0, "M_uu": 0.5, "Z_uw": -60.0, "X_uw": 3.0})
    lin = linearise(model, theta)
    U = VEHICLE.speed
    assert {(e.name, e.matrix): e.value for e in lin.outside} == pytest.approx(
        {("M_u", "At"): 2 * U * 0.5, ("X_w", "At"): U * 3.0}
    )
    assert lin.coefficients["M_0"] == pytest.approx(0.5 * U**2)  # a constant moment at trim
    assert thrust(model, theta) == pytest.approx(6.0 * U**2)


def rotation(phi, theta, psi):
    """NED from body, built from elementary rotations: Rz(ψ) Ry(θ) Rx(φ)."""
    c, s = np.cos([phi, theta, psi]), np.sin([phi, theta, psi])
    Rx = np.array([[1, 0, 0], [0, c[0], -s[0]], [0, s[0], c[0]]])
    Ry = np.array([[c[1], 0, s[1]], [0, 1, 0], [-s[1], 0, c[1]]])
    Rz = np.array([[c[2], -s[2], 0], [s[2], c[2], 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def angles(R):
    return np.array([math.atan2(R[2, 1], R[2, 2]), -math.asin(R[2, 0]), math.atan2(R[1, 0], R[0, 0])])


def test_restoring_at_sixty_degrees_of_roll_is_the_closed_form():
    """CB h above the CG, W = B, at rest at φ = 60°: the roll moment −B h sin φ, nothing else."""
    h, B = 0.05, 2000.0
    body = linear.Vehicle(
        mass=B / 9.81, Ix=3.0, Iy=50.0, Iz=50.0, weight=B, buoyancy=B, xB=0, yB=0, zB=-h, speed=10.0
    )
    model = nonlinear_model(body, ())
    theta = nonlinear_theta(model, {})
    x = np.zeros(10)
    x[6] = math.radians(60)
    F = forces(model, theta, x, np.zeros(3))[0]
    assert F == pytest.approx([0, 0, 0, -B * h * math.sin(math.radians(60)), 0, 0], abs=1e-9)
    assert rates(model, theta, x, np.zeros(3))[3] == pytest.approx(-B * h * math.sqrt(3) / 2 / 3.0)


def test_restoring_at_any_attitude_is_weight_and_buoyancy_turned_by_the_rotation():
    model, _, _ = model_and_theta()
    theta = nonlinear_theta(model, DOTS)  # no hydrodynamic terms: at rest only the restoring is left
    rB = np.array([VEHICLE.xB, VEHICLE.yB, VEHICLE.zB])
    for phi, th, psi in ((1.0, -0.9, 2.0), (-2.5, 1.2, -0.3), (math.pi / 2, 0.4, 1.0)):
        x = np.array([0, 0, 0, 0, 0, 0, phi, th, psi, 7.0])
        down = rotation(phi, th, psi).T @ np.array([0, 0, 1.0])  # gravity in body axes
        expected = np.concatenate(
            [(VEHICLE.weight - VEHICLE.buoyancy) * down, np.cross(rB, -VEHICLE.buoyancy * down)]
        )
        F = forces(model, theta, x, np.zeros(3))[0]
        # at rest the Kirchhoff forces vanish; the thrust is the trim drag (0: no terms)
        assert F == pytest.approx(expected, abs=1e-9)


def test_kinematics_at_large_angles_follow_the_rotation_matrix():
    """Euler rates and ż against R(t + h) = R(t) exp([ω]× h), angles read back from R."""
    rng = np.random.default_rng(4)
    for phi, th, psi in ((1.2, 1.1, -2.8), (-2.9, -1.3, 0.5), (0.3, 0.2, 3.0)):
        nu = rng.uniform(-2, 2, 6)
        R = rotation(phi, th, psi)
        w, h = nu[3:], 1e-6
        W = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
        a = np.linalg.norm(w)

        def turned(t):
            K = W / a
            return R @ (np.eye(3) + math.sin(a * t) * K + (1 - math.cos(a * t)) * K @ K)  # Rodrigues

        d = (angles(turned(h)) - angles(turned(-h))) / (2 * h)
        d[2] = (d[2] + math.pi / h) % (2 * math.pi / h) - math.pi / h  # ψ across ±π
        x = np.concatenate([nu, [phi, th, psi, 3.0]])
        f = kinematics(x[None])[0][0]
        assert f[:3] == pytest.approx(d, rel=1e-7, abs=1e-7)
        assert f[3] == pytest.approx((R @ nu[:3])[2], rel=1e-13, abs=1e-13)


def test_coriolis_is_newton_euler_for_a_rigid_body_and_does_no_work():
    rng = np.random.default_rng(5)
    m, I = 150.0, np.diag([2.0, 60.0, 61.0])
    M = np.zeros((6, 6))
    M[:3, :3], M[3:, 3:] = m * np.eye(3), I
    nu = rng.normal(size=(4, 6))
    F, _ = coriolis(M, nu)
    v, w = nu[:, :3], nu[:, 3:]
    assert np.allclose(F[:, :3], -m * np.cross(w, v), rtol=1e-14, atol=1e-12)
    assert np.allclose(F[:, 3:], -np.cross(w, w @ I), rtol=1e-14, atol=1e-12)
    model, theta, _ = model_and_theta()
    Mfull = model.inertia(theta)
    F = coriolis((Mfull + Mfull.T) / 2, nu)[0]
    assert np.abs(np.einsum("ni,ni->n", F, nu)).max() < 1e-12 * np.abs(F).max() * np.abs(nu).max()


def test_regressors_are_the_named_products():
    u, v, w, p, q, r = 18.0, -1.5, 0.7, 0.2, -0.4, 0.9
    dr, der, del_ = 0.3, -0.1, 0.25
    de, da = (der + del_) / 2, (der - del_) / 2
    names = ("Y_v|v|", "K_uuda", "Z_uude|da|", "X_|v||w|", "N_ur|dr|", "K_p|q|", "M_uwdede", "X_uu")
    names += ("Y_v|vw|", "K_p|qr|", "K_dawq")
    expected = [
        v * abs(v),
        u * u * da,
        u * u * de * abs(da),
        abs(v) * abs(w),
        u * r * abs(dr),
        p * abs(q),
        u * w * de**2,
        u * u,
        v * math.hypot(v, w),
        p * math.hypot(q, r),
        da * w * q,
    ]
    got = regressors(
        tuple(parse_term(n) for n in names), np.array([[u, v, w, p, q, r]]), np.array([[dr, der, del_]])
    )
    assert got[0] == pytest.approx(expected, rel=1e-15)


def test_the_cross_flow_magnitudes_are_their_closed_forms_with_no_slope_where_their_pair_is_zero():
    """√(v² + w²) and √(q² + r²) in products: the regressors are the closed forms, and where the
    pair is 0 the model's Jacobian has no part from them (the mean of the one-sided slopes, as for
    |x|). Elsewhere `test_jacobians_match_complex_step` checks their slopes: the default terms hold
    both."""
    names = ("X_u|vw|", "Y_v|vw|", "K_p|qr|", "N_r|qr|", "M_|vw||qr|")
    z = np.array([[18.0, -1.5, 0.7, 0.2, -0.4, 0.9, 0.1, -0.2, 0.05]])
    vw, qr = math.hypot(-1.5, 0.7), math.hypot(-0.4, 0.9)
    got = regressors(tuple(parse_term(n) for n in names), z[:, :6], z[:, 6:])[0]
    assert got == pytest.approx([18.0 * vw, -1.5 * vw, 0.2 * qr, 0.9 * qr, vw * qr], rel=1e-15)
    model, theta, _ = model_and_theta()
    pairs = [k for k, n in enumerate(model.names) if "|vw|" in n or "|qr|" in n]
    assert len(pairs) >= 5
    held = theta.copy()
    held[pairs] = 0.0
    x, delta = np.array([18.0, 0, 0, 0.2, 0, 0, 0.1, 0.2, 0.3, 50.0]), np.array([0.1, -0.05, 0.02])
    assert close(jacobians(model, theta, x, delta)[1], jacobians(model, held, x, delta)[1], 1e-14)
    x[1] = 0.3  # off the kink the pair terms do act
    assert not close(jacobians(model, theta, x, delta)[1], jacobians(model, held, x, delta)[1], 1e-3)


def test_terms_are_parsed_by_their_names_and_bad_ones_refused():
    t = parse_term("N_v|v|")
    assert (t.row, t.factors) == (5, ("v", "|v|"))
    assert parse_term("K_uuda").factors == ("u", "u", "da")
    assert parse_term("K_p|qr|").factors == ("p", "|qr|")
    for bad in ("Q_uv", "Y_", "Y_uvx", "Yuv", "Y_|uv|", "Y_|vr|", "Y_|vw"):
        with pytest.raises(InputError):
            parse_term(bad)
    with pytest.raises(InputError, match="twice"):
        nonlinear_model(VEHICLE, ("Y_uv", "Y_uv"))
    with pytest.raises(InputError, match="linear model"):
        nonlinear_model(VEHICLE, ("Y_v",))
    with pytest.raises(InputError, match="GM"):
        nonlinear_model(linear.Vehicle(**{**VEHICLE.__dict__, "GM": 0.1}))


def test_the_fit_recovers_the_coefficients_of_data_the_model_made():
    model, theta, coefficients = model_and_theta(seed=7)
    x, delta = sample_box(SCENARIO_I, 800, seed=2)
    nudot = rates(model, theta, x, delta)[:, :6]
    quality = fit_terms(model, DOTS, x, delta, nudot)
    fitted = np.array([quality.coefficients[t.name] for t in model.terms])
    truth = np.array([coefficients[t.name] for t in model.terms])
    assert np.abs(fitted - truth).max() < 1e-8 * np.abs(truth).max()
    assert min(quality.force_fit.values()) > 100 - 1e-8
    assert min(quality.acceleration_fit.values()) > 100 - 1e-8


def test_the_model_page_lists_the_default_terms_in_order():
    text = (Path(__file__).resolve().parents[2] / "docs" / "model.md").read_text(encoding="utf-8")
    nonlinear = text[text.index("# The nonlinear model") :]
    listed = re.search(r"```\n(X_uu .*?)```", nonlinear, re.S).group(1).split()
    assert listed == list(TERMS)
    assert f"default set, {len(TERMS)} terms" in nonlinear
