"""The MEKF and the conventional EKF: kernels against filterpy and complex steps, estimates
against the coefficients that simulated the data, numerical soundness, divergence detection."""

import json
from dataclasses import replace

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter, SquareRootKalmanFilter
from scipy.signal import butter, filtfilt

from testbed.cli import main
from testbed.data import Experiment, ModelConfig, load_data, write_config, write_csv
from testbed.errors import InputError
from testbed.estimators import Status, identify
from testbed.estimators.filter_model import DiscreteModel
from testbed.estimators.filter_options import FilterOptions
from testbed.estimators.mekf import run_filter
from testbed.estimators.square_root import sqrt_update, svd_root, tria
from studies import remus as examples
from testbed.identification.bounds import information
from testbed.models.linear import (
    COEFFICIENTS,
    ITHETA,
    IX,
    STATES,
    Vehicle,
    continuous,
    discretize,
    structure,
    theta_vector,
)
from testbed.simulation.measurements import noise_free_channels, noise_from_data
from testbed.simulation.runs import simulate

# A torpedo like the bundled one at 20 m/s (SI units); CB slightly off the CG so S ≠ 0.
VEHICLE = Vehicle(170.75, 2.16, 67.25, 67.24, 1675.1, 1675.1, 0.0, 0.0, -0.0179, 20.0)
SIMULATED = {
    "X_udot": -8.11,
    "X_u": -265.6,
    "Y_vdot": -158.6,
    "Y_pdot": -2.99,
    "Y_rdot": -2.35,
    "Y_v": -2135.1,
    "Y_p": -4.30,
    "Y_r": 2217.8,
    "Y_dr": 42505.7,
    "Z_wdot": -158.6,
    "Z_qdot": 2.35,
    "Z_w": -2135.1,
    "Z_q": -2217.8,
    "Z_de": -42505.7,
    "K_vdot": -2.99,
    "K_pdot": -0.395,
    "K_rdot": -0.426,
    "K_v": -4.30,
    "K_p": -124.8,
    "K_r": 2.48,
    "K_dr": 0.0,
    "K_der": -3613.0,
    "K_del": -3613.0,
    "M_wdot": 2.35,
    "M_qdot": -55.76,
    "M_w": 630.6,
    "M_q": -2791.2,
    "M_de": -47273.4,
    "N_vdot": -2.35,
    "N_pdot": -0.426,
    "N_rdot": -55.76,
    "N_v": -630.6,
    "N_p": -55.41,
    "N_r": -2791.1,
    "N_dr": -47273.4,
}
SWAY_YAW = ("Y_v", "Y_r", "Y_dr", "N_v", "N_r", "N_dr")  # *dot terms fixed: well posed
NOISE = np.array([0.01, 0.01, 0.01, 0.002, 0.002, 0.002, 0.002, 0.002, 0.002, 0.01])


def _prbs(rng, n, dt, amp, hold):
    k = max(1, round(hold / dt))
    return np.repeat(rng.choice([-amp, amp], size=n // k + 1), k)[:n]


def _simulate(coefficients, inputs, dt, noise, seed, name="run", process=0.0):
    """Exact ZOH simulation of the linear model from trim; all ten states measured. `process`:
    σ per sample of a white process noise on the states."""
    A, B, S = continuous(structure(VEHICLE), theta_vector(coefficients))
    Phi, Gamma, s = discretize(A, B, S, dt)
    w = np.random.default_rng(seed + 1).normal(size=(len(inputs), 10)) * process
    x, X = np.zeros(10), np.zeros((len(inputs), 10))
    for k, d in enumerate(inputs):
        X[k], x = x, Phi @ x + Gamma @ d + s + w[k]
    Y = X + np.random.default_rng(seed).normal(size=X.shape) * noise
    Y[:, 0] += VEHICLE.speed
    return Experiment(name, np.arange(len(inputs)) * dt, STATES, Y, inputs)


def _horizontal(seed, T=30.0, dt=0.05, noise=NOISE):
    rng = np.random.default_rng(seed)
    n = round(T / dt)
    inputs = np.zeros((n, 3))
    inputs[:, 0] = _prbs(rng, n, dt, np.deg2rad(2.0), 0.5)
    return _simulate(SIMULATED, inputs, dt, noise, seed + 1000, "horizontal")


def _start(free, seed=3, spread=0.3):
    rng = np.random.default_rng(seed)
    start = {n: SIMULATED[n] * (1 + spread * rng.choice([-1, 1])) for n in free}
    return ModelConfig(VEHICLE, dict(SIMULATED), tuple(free)).with_coefficients(start)


def _spd(rng, n):
    G = rng.normal(size=(n, n))
    return G @ G.T + n * np.eye(n)


def _pre_array(Rh, C, Jm):
    """The filter's pre-array `[[Rh, C J⁻], [0, J⁻]]`, J⁻ (n, k) any root of the prior."""
    m, (n, k) = len(Rh), Jm.shape
    pre = np.zeros((m + n, m + k))
    pre[:m, :m], pre[:m, m:], pre[m:, m:] = Rh, C @ Jm, Jm
    return pre


def test_square_root_kernels_match_joseph_form_and_filterpy():
    # sqrt_update is the filter's own update: fed, as the filter feeds it, the rectangular
    # predicted root [F J, Q½] (or its SVD root), it does filterpy's predict and update at once.
    rng = np.random.default_rng(0)
    n, m = 8, 3
    P, Q, R = _spd(rng, n), _spd(rng, n) * 0.1, _spd(rng, m)
    F, H = rng.normal(size=(n, n)) * 0.5, rng.normal(size=(m, n))
    x, z = rng.normal(size=n), rng.normal(size=m)

    kf = KalmanFilter(dim_x=n, dim_z=m)  # filterpy's update is the Joseph form
    kf.x, kf.P, kf.F, kf.Q, kf.H, kf.R = x.copy(), P.copy(), F, Q, H, R
    kf.predict()
    kf.update(z)

    Jm = np.hstack([F @ np.linalg.cholesky(P), np.linalg.cholesky(Q)])
    np.testing.assert_allclose(Jm @ Jm.T, F @ P @ F.T + Q, rtol=1e-12, atol=1e-12)
    scale = np.abs(kf.P).max()
    for root in (Jm, svd_root(Jm)):
        assert root.shape == (n, 2 * n if root is Jm else n)
        pre = _pre_array(np.linalg.cholesky(R), H, root)
        dx, w, L, J_post = sqrt_update(pre, m, z - H @ F @ x)
        K = sqrt_update(pre, m, np.eye(m))[0]  # ν = I: the gain itself
        assert np.abs(J_post @ J_post.T - kf.P).max() < 1e-10 * scale
        np.testing.assert_allclose(K, kf.K, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(F @ x + dx, kf.x, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(L @ L.T, kf.S, rtol=1e-10)
        np.testing.assert_allclose(w @ w, kf.y @ np.linalg.solve(kf.S, kf.y), rtol=1e-10)
        # Roots are lower triangular: up to column signs the Cholesky factors.
        assert np.array_equal(J_post, np.tril(J_post)) and np.array_equal(L, np.tril(L))
        signs = np.where(np.diag(J_post) < 0, -1.0, 1.0)
        np.testing.assert_allclose(J_post * signs, np.linalg.cholesky(kf.P), rtol=1e-8, atol=1e-10)
    # A square triangular prior root (no time update) is the plain array update.
    pre = _pre_array(np.linalg.cholesky(R), H, np.linalg.cholesky(P))
    J_post = sqrt_update(pre, m, np.zeros(m))[3]
    K = np.linalg.solve(H @ P @ H.T + R, H @ P).T
    np.testing.assert_allclose(J_post @ J_post.T, P - K @ H @ P, rtol=1e-10, atol=1e-10)

    sr = SquareRootKalmanFilter(dim_x=n, dim_z=m)  # the same array algorithm, linear only
    sr.x, sr.P, sr.F, sr.Q, sr.H, sr.R = x[:, None].copy(), P, F, Q, H, R
    sr.predict()
    sr.update(z[:, None])
    np.testing.assert_allclose(sr.P, kf.P, rtol=1e-9)
    np.testing.assert_allclose(sr.x[:, 0], kf.x, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(
        tria(np.hstack([F, F])) @ tria(np.hstack([F, F])).T, 2 * F @ F.T, rtol=1e-12, atol=1e-12
    )


def _zoh(A, B, S, dt):
    """[Φ Γ s] from scipy's expm of the block matrix [[A, B, S], [0, 0, 0]] Δ: the reference."""
    from scipy.linalg import expm

    n = len(A)
    big = np.zeros((n + B.shape[1] + 1,) * 2, dtype=np.result_type(A, B, S))
    big[:n] = np.column_stack([A, B, S])
    return expm(big * dt)[:n]


def test_model_matches_complex_step():
    # DiscreteModel.exact (expm_pair) against scipy's expm and its complex steps, on both paths: free
    # *dot terms (continuous/derivatives at every call) and none (affine in θ).
    vehicle = Vehicle(30.51, 0.177, 3.45, 3.45, 299.0, 306.0, 0.01, 0.002, -0.0196, 1.54)
    s = structure(vehicle)
    theta = theta_vector({n: v / 40 for n, v in SIMULATED.items()}) + 0.1  # K_dr ≠ 0 too
    for free in (
        ("Y_vdot", "Y_r", "Z_de", "K_pdot", "K_del", "N_rdot"),
        ("Y_v", "Y_r", "Z_de", "K_p", "K_del", "N_r"),
    ):
        idx = np.array([ITHETA[n] for n in free])
        model = DiscreteModel(s, theta, idx)
        assert model.affine == (free[0] == "Y_v")
        th = theta[idx] * 1.1  # away from the start: the affine path's M(θ) is moved
        at = theta.copy()
        at[idx] = th
        for dt in (0.02, 0.5):  # ‖AΔ‖ below and far above the scaling threshold
            E, dE = model.exact(th, dt)
            ref = _zoh(*continuous(s, at), dt)
            assert np.abs(E - ref).max() < 1e-12 * np.abs(ref).max()
            h = 1e-30
            for j, i in enumerate(idx):
                tc = at.astype(complex)
                tc[i] += 1j * h
                ref = _zoh(*continuous(s, tc), dt).imag / h
                assert np.abs(dE[:, j, :] - ref).max() < 1e-11 * np.abs(ref).max()


def test_model_refresh_policy_carries_E_to_first_order():
    s = structure(VEHICLE)
    theta = theta_vector(SIMULATED)
    idx = np.array([ITHETA[n] for n in SWAY_YAW])
    model = DiscreteModel(s, theta, idx)
    dt, th0 = 0.05, theta[idx].copy()
    var = (0.1 * np.abs(th0)) ** 2
    xi = np.concatenate([np.random.default_rng(13).normal(size=10), [0.01, -0.02, 0.0, 1.0]])
    model.restart(dt, 0.2)
    E0, D0 = model.linearised(th0, var, xi)
    Ex, dE = model.exact(th0, dt)
    np.testing.assert_array_equal(E0, Ex)
    np.testing.assert_allclose(D0, np.einsum("ipq,q->ip", dE, xi), rtol=1e-12, atol=1e-12)
    # Within refresh_tol σ: E(θₘ) + ∂E·Δθ (second-order error), D still θₘ's.
    step = 0.15 * np.sqrt(var)
    E1, D1 = model.linearised(th0 + step, var, xi)
    np.testing.assert_allclose(E1, E0 + np.einsum("ipq,p->iq", dE, step), rtol=1e-12, atol=1e-14)
    np.testing.assert_array_equal(D1, D0)
    exact1 = model.exact(th0 + step, dt)[0]
    assert np.abs(E1 - exact1).max() < 0.05 * np.abs(exact1 - E0).max()
    # Beyond it, or after a restart: the exact model at the new θ.
    E2, D2 = model.linearised(th0 + 2 * step, var, xi)
    np.testing.assert_array_equal(E2, model.exact(th0 + 2 * step, dt)[0])
    model.restart(dt, 0.2)
    np.testing.assert_array_equal(model.linearised(th0 + step, var, xi)[0], exact1)
    # refresh_tol = 0: exact at every call.
    model.restart(dt, 0.0)
    model.linearised(th0, var, xi)
    np.testing.assert_array_equal(
        model.linearised(th0 + 1e-9 * step, var, xi)[0], model.exact(th0 + 1e-9 * step, dt)[0]
    )


def test_noise_from_data_recovers_the_measurement_noise():
    # Slow signals: the third difference is noise alone.
    t = np.arange(2000) * 0.05
    rng = np.random.default_rng(1)
    slow = np.sin(0.3 * t)[:, None] * np.arange(1, 11) + rng.normal(size=(2000, 10)) * NOISE
    sigma = noise_from_data([Experiment("slow", t, STATES, slow, np.zeros((2000, 3)))])
    np.testing.assert_allclose([sigma[n] for n in STATES], NOISE, rtol=0.08)
    # A manoeuvre: fast roll and yaw rates leak in, never below the noise, at most 1.6×.
    sigma = noise_from_data([_horizontal(seed=1, T=60.0)])
    ratio = np.array([sigma[n] for n in STATES]) / NOISE
    assert np.all(ratio > 0.9) and np.all(ratio < 1.6), ratio


def test_mekf_estimates_lie_within_a_few_sigma_of_the_simulated_coefficients():
    e = _horizontal(seed=2)
    config = _start(SWAY_YAW)
    simulated = np.array([SIMULATED[n] for n in SWAY_YAW])
    seen = []
    for method in ("mekf", "ekf"):
        est = identify([e], config, method, callback=lambda step: seen.append(step.iteration))
        assert est.status is Status.CONVERGED, est.message
        assert np.all(np.abs(est.values - simulated) < 4 * est.std), (est.values - simulated) / est.std
        assert np.all(est.std < 0.05 * np.abs(simulated))  # far tighter than the 50 % prior
        assert est.iterations == len(e.t) and est.history.shape == (len(e.t), len(SWAY_YAW))
        np.testing.assert_array_equal(est.history[-1], est.values)
        np.testing.assert_allclose(est.history_std[-1], est.std)
        assert est.history_std[0, 0] > 10 * est.history_std[-1, 0]
    assert seen == list(range(1, len(e.t) + 1)) * 2
    doc = json.loads(est.to_json())  # histories stay out of the JSON
    assert set(doc["coefficients"]) == set(SWAY_YAW) and len(json.dumps(doc)) < 2000
    csv = np.loadtxt(est.history_csv().splitlines()[1:], delimiter=",")
    np.testing.assert_allclose(csv[:, 1], est.history[:, 0], rtol=1e-9)


def test_experiments_in_sequence_carry_the_coefficients_and_their_covariance():
    e1, e2 = _horizontal(seed=4, T=15.0), _horizontal(seed=5, T=15.0)
    config = _start(SWAY_YAW)
    noise = dict(zip(STATES, NOISE))
    one = identify([e1], config, "mekf", noise_std=noise)
    both = identify([e1, e2], config, "mekf", noise_std=noise)
    assert both.iterations == len(e1.t) + len(e2.t)
    np.testing.assert_array_equal(both.history[: len(e1.t)], one.history)
    assert np.all(both.std < 0.9 * one.std)
    assert np.all(np.diff(both.history_t) > 0)


def test_samples_missing_leave_the_filters_predicting():
    """Every state missing over the last 100 samples: the filters only predict there, and θ̂,
    which the time update carries unchanged, ends where it ends on the record cut short; a
    tenth of each state's samples and a few whole rows missing: finite, close to the
    coefficients that simulated the data."""
    e = _horizontal(seed=6, T=20.0)
    config = _start(SWAY_YAW)
    noise = dict(zip(STATES, NOISE))
    y = e.y.copy()
    y[-100:] = np.nan
    cut = replace(e, t=e.t[:-100], y=e.y[:-100], inputs=e.inputs[:-100])
    rng = np.random.default_rng(1)
    holes = e.y.copy()
    holes[rng.random(holes.shape) < 0.1] = np.nan
    holes[[50, 51, 200]] = np.nan
    simulated = np.array([SIMULATED[n] for n in SWAY_YAW])
    for method in ("mekf", "ekf"):
        masked = identify([replace(e, y=y)], config, method, noise_std=noise)
        short = identify([cut], config, method, noise_std=noise)
        np.testing.assert_allclose(masked.values, short.values, rtol=1e-10)
        np.testing.assert_allclose(masked.history[: len(cut.t)], short.history, rtol=1e-10)
        est = identify([replace(e, y=holes)], config, method, noise_std=noise)
        assert est.status is Status.CONVERGED, est.message
        assert np.all(np.abs(est.values - simulated) < 4 * est.std), (est.values - simulated) / est.std


def test_poorly_scaled_problem_breaks_the_conventional_covariance_only():
    # Coefficients from 2.5 to 47 000 with 50 % a-priori σ, measurements to a micro-unit: the
    # covariance's condition number passes 1/eps within a few samples. The conventional
    # P − K C P cancels ~10 orders of magnitude and loses symmetry and definiteness; the square
    # root never forms P and keeps it. (The start is within 1 %: from farther, at this
    # signal-to-noise, any EKF's linearisation error outgrows its covariance.)
    free = tuple(n for n in COEFFICIENTS if not n.endswith("dot") and n != "K_dr")
    rng = np.random.default_rng(6)
    n = 200
    inputs = np.column_stack(
        [_prbs(rng, n, 0.05, 0.03, 0.5), _prbs(rng, n, 0.05, 0.03, 0.4), _prbs(rng, n, 0.05, 0.03, 0.7)]
    )
    e = _simulate(SIMULATED, inputs, 0.05, 1e-6, seed=7)
    config = _start(free, spread=0.01)
    opts = dict(noise_std={s: 1e-6 for s in STATES}, refresh_tol=0.0)
    ekf = identify([e], config, "ekf", **opts)
    assert ekf.status is Status.DIVERGED and ekf.iterations < 20
    assert "positive definite" in ekf.message
    eps = np.finfo(float).eps
    P = ekf.covariance
    # Asymmetry: one symmetric update rounds at ~eps; this is ~10⁸ eps, accumulated in 4 steps.
    assert np.abs(P - P.T).max() / np.abs(P).max() > 1e5 * eps
    assert ekf.max_covariance_asymmetry > 1e5 * eps

    # The same EKF (same centre, same model) in square-root form, stopped at the same sample.
    sq = run_filter(
        [e],
        config,
        method="ekf-sqrt",
        modified=False,
        square_root=True,
        options=FilterOptions.build("ekf-sqrt", opts, max_samples=ekf.iterations + 1),
        callback=None,
    )
    J = sq.covariance_root
    assert np.allclose(J, np.tril(J)) and np.all(np.diag(J) > 0)  # P = J Jᵀ definite
    sv = np.linalg.svd(J, compute_uv=False)
    assert sv[-1] / sv[0] < 1e-8  # cond(P) = cond(J)² > 1e16 > 1/eps: no formed P holds it
    # The same filter: P agrees with J Jᵀ to rounding in its large entries; its small
    # directions are below P's rounding (eps ‖P‖), where Cholesky found it indefinite.
    assert np.abs(J @ J.T - P).max() < 1e-6 * np.abs(P).max()

    mekf = identify([e], config, "mekf", **opts)
    assert mekf.status is Status.CONVERGED, mekf.message
    J = mekf.covariance_root
    assert np.all(np.isfinite(J)) and np.allclose(J, np.tril(J)) and np.all(np.diag(J) > 0)
    Pm = mekf.covariance
    assert np.abs(Pm - Pm.T).max() <= 4 * eps * np.abs(Pm).max()  # symmetric to rounding
    sv = np.linalg.svd(J, compute_uv=False)
    assert sv[-1] / sv[0] < 1e-8 and sv[-1] > 0
    simulated = np.array([SIMULATED[n] for n in free])
    assert np.all(np.abs(mekf.values - simulated) < 4 * mekf.std)


def test_a_wildly_wrong_model_is_reported_as_diverged():
    e = _horizontal(seed=8, T=20.0)
    wrong = {**SIMULATED, "K_p": 10 * abs(SIMULATED["K_p"]), "N_r": -0.1 * SIMULATED["N_r"]}  # unstable
    config = ModelConfig(VEHICLE, wrong, ("Y_dr",))
    for method in ("mekf", "ekf"):
        est = identify([e], config, method)
        assert est.status is Status.DIVERGED and not est.converged
        assert est.iterations < len(e.t)
        assert est.message and est.diverged_sample is not None
        assert "diverged" in est.json_fields()


def test_bad_options_are_input_errors():
    e = _horizontal(seed=9, T=2.0)
    config = _start(SWAY_YAW)
    for bad in (
        {"no_such_option": 1},
        {"prior_frac": -1.0},
        {"noise_std": {"u": 0.0}},
        {"noise_std": {"nope": 1.0}},
        {"start": "equation-error"},
        {"max_iter": 0},
        {"noise_std": {"u": "a"}},
        {"noise_std": [0.01] * 10},
        {"noise_std": 0.01},
        {"prior_std": {"Y_v": None}},
        {"prior_std": ["Y_v"]},
        {"sqrt": "cholesky"},
        {"refresh_tol": True},
        {"prior_frac": False},
        {"nis_limit": True},
        {"prior_floor": True},
        {"prior_floor": "a"},
        {"nis_window": True},
        {"noise_std": {"u": True}},
        {"prior_std": {"Y_v": True}},
        {"noise_window": -1},
        {"noise_window": 2.5},
        {"noise_margin": -1.0},
        {"state_noise": "a"},
        {"passes": 0},
        {"passes": 2.0},
        {"pass_tol": -0.1},
    ):
        with pytest.raises(InputError) as info:
            identify([e], config, "mekf", **bad)
        assert "\n" not in str(info.value)  # one line


def test_fixed_interval_iterations_reach_the_maximum_likelihood_estimate():
    # Every pass after the first is the filter of the model linearised about the previous pass's
    # estimate, its prior re-centred there: a Levenberg-Marquardt step of the likelihood. Their
    # fixed point is the ML estimate with its Cramér-Rao bound: that of ml-gn (Gauss-Newton on
    # the output error, with the same noise), which one pass misses by up to a σ.
    e = _horizontal(seed=2)
    config = _start(SWAY_YAW)
    ml = identify([e], config, "ml-gn")
    assert ml.converged
    one = identify([e], config, "mekf", noise_std=ml.noise_std)
    assert np.max(np.abs(one.values - ml.values) / ml.std) > 0.5
    for method, tol in (("mekf", 0.02), ("ekf", 0.05)):  # the EKF's model-error floor: 0.01 σ
        it = identify([e], config, method, noise_std=ml.noise_std, passes=8, pass_tol=0.01)
        assert it.status is Status.CONVERGED and 2 <= it.passes < 8, it.message
        assert it.last_step_std <= 0.01
        assert np.max(np.abs(it.values - ml.values) / ml.std) < tol, (it.values - ml.values) / ml.std
        np.testing.assert_allclose(it.std, ml.std, rtol=0.01)
        assert it.history.shape == (len(e.t), len(SWAY_YAW))  # the last pass's
        np.testing.assert_array_equal(it.history[-1], it.values)
    # Out of passes before the step is small: not converged.
    short = identify([e], config, "mekf", noise_std=ml.noise_std, passes=2, pass_tol=1e-6)
    assert short.status is Status.MAX_ITERATIONS and short.passes == 2


def test_refresh_policy_and_svd_option_match_the_exact_filter():
    # Between exact refreshes the model is carried to first order: the default's estimates stay
    # within a small fraction of σ of the filter that recomputes the exact model every sample;
    # the SVD time-update root is the same filter to rounding.
    e = _horizontal(seed=10, T=20.0)
    config = _start(SWAY_YAW)
    exact = identify([e], config, "mekf", refresh_tol=0.0)
    default = identify([e], config, "mekf")
    svd = identify([e], config, "mekf", sqrt="svd")
    assert exact.status is default.status is svd.status is Status.CONVERGED
    assert np.max(np.abs(default.values - exact.values) / exact.std) < 0.05
    assert np.max(np.abs(default.history - exact.history) / exact.history_std) < 0.2
    np.testing.assert_allclose(svd.values, default.values, rtol=1e-8)
    np.testing.assert_allclose(svd.std, default.std, rtol=1e-8)
    assert svd.sqrt == "svd" and default.sqrt == "qr"
    # The likelihood: ½ Σ (νᵀ Σν⁻¹ ν + ln det Σν), finite and the same for both roots.
    assert np.isfinite(default.cost) and abs(svd.cost - default.cost) < 1e-6 * abs(default.cost)


def test_noise_free_data_diverge_with_the_reason():
    # The model differs from the data's (N_r 10 % off, fixed); without measurement noise the
    # filter has nothing to set that error against: DIVERGED, saying why.
    n = 400
    inputs = np.zeros((n, 3))
    inputs[:, 0] = _prbs(np.random.default_rng(11), n, 0.05, np.deg2rad(2.0), 0.5)
    e = _simulate({**SIMULATED, "N_r": 1.1 * SIMULATED["N_r"]}, inputs, 0.05, 0.0, seed=12)
    assert noise_free_channels([e]) == list(STATES)
    assert noise_free_channels([_horizontal(seed=12, T=20.0)]) == []
    config = ModelConfig(VEHICLE, dict(SIMULATED), ("Y_v", "N_v", "Y_dr"))
    est = identify([e], config, "mekf")
    assert est.status is Status.DIVERGED
    reason = est.message
    assert "predicted σ" in reason and "noise-free" in reason and "noise_std" in reason
    assert "\n" not in reason
    # Given the sensor noise, the same data fit: the model error is then small against it.
    noisy = identify([e], config, "mekf", noise_std=dict(zip(STATES, NOISE)))
    assert noisy.status is not Status.DIVERGED, noisy.message


def test_low_pass_filtered_data_fit_given_the_sensors_noise_in_the_config(tmp_path, capsys):
    # A log whose every channel the sensors low-pass filtered (a 2nd-order Butterworth at 3 Hz
    # on 20 Hz data, forward and backward: no lag): its noise cannot be read off it, and with R
    # from the data the filter's own smoothing is a many-σ model error. Refused, naming what to
    # give. Given the sensors' σ (before the low-pass filter: the noise density in the band it
    # passes, where the sway-yaw response is), the filter converges near the simulated coefficients: within 4
    # Cramér-Rao bounds of the raw data with that noise (filtering only loses information).
    free = ("Y_v", "Y_r", "Y_dr", "N_v", "N_r", "N_dr")
    raw = examples.experiments(seed=1)[0]  # horizontal: a rudder PRBS, 60 s at 20 Hz
    b, a = butter(2, 3.0, fs=1.0 / raw.dt)
    filtered = replace(raw, y=filtfilt(b, a, raw.y, axis=0))
    assert noise_free_channels([filtered]) == list(STATES)
    simulated = np.array([examples.EXAMPLE_COEFFICIENTS[n] for n in free])
    bound = information([raw], examples.example_config(free), noise_std=examples.NOISE).crlb_std
    prior = examples.prior_config(free)  # 30 % off
    given = replace(prior, noise_std=examples.NOISE)

    refused = identify([filtered], prior, "mekf")
    assert refused.status is Status.DIVERGED
    for words in ("look noise-free or low-pass filtered", "[identify] noise_std", "--noise-std"):
        assert words in refused.message, refused.message
    est = identify([filtered], given, "mekf")
    assert est.status is Status.CONVERGED, est.message
    assert np.all(np.abs(est.values - simulated) < 4 * bound), (est.values - simulated) / bound
    assert est.noise_std == examples.NOISE

    # The same through the command line: the noise in the config file, or the flag.
    data = write_csv(tmp_path / "filtered.csv", filtered.t, filtered.y, filtered.inputs)
    bare, noted = write_config(tmp_path / "bare.toml", prior), write_config(tmp_path / "c.toml", given)
    flag = ",".join(f"{k}={v!r}" for k, v in examples.NOISE.items())

    def cli(config, *more):
        out = tmp_path / "e.json"
        code = main(
            [str(a) for a in ("identify", data, "--config", config, "--method", "mekf", "--out", out)]
            + list(more)
        )
        err = capsys.readouterr().err
        doc = json.loads(out.read_text()) if out.exists() else None
        for written in (out, out.with_suffix(".history.csv")):  # each call a fresh fit's outputs
            written.unlink(missing_ok=True)
        return code, err, doc

    code, err, doc = cli(bare)
    assert code == 2 and err.count("\n") == 1 and doc is None, err
    assert "low-pass filtered" in err and "[identify] noise_std" in err and "--noise-std" in err
    code, err, doc = cli(noted)
    assert code == 0, err
    values = np.array([doc["coefficients"][n]["value"] for n in free])
    assert np.all(np.abs(values - simulated) < 4 * bound), (values - simulated) / bound
    assert doc["noise_std"] == examples.NOISE
    code, err, by_flag = cli(bare, "--noise-std", flag)
    assert code == 0 and by_flag["coefficients"] == doc["coefficients"], err
    # the flag's entries replace the config's one by one
    code, err, merged = cli(noted, "--noise-std", "r=0.006")
    assert code == 0 and merged["noise_std"] == examples.NOISE | {"r": 0.006}, err


@pytest.fixture(scope="module")
def scenario_i(tmp_path_factory):
    """The first 12 s of Scenario I: a turn each way and the first 20 m depth step (at 5 s)."""
    return simulate("I", seed=1, duration=12.0, out=tmp_path_factory.mktemp("r") / "I")


def test_filters_started_at_the_analytic_model_follow_scenario_i(scenario_i):
    # Scenario I flies beyond the linear regime: the analytic model's one-sample error is many
    # measurement σ in the rates. With the model error fixed at a linear-regime size (none, or
    # 0.1 σ per sample) the innovations are 5-8x their σ by the end of the first depth step and
    # the filter is declared diverged; with it matched to the innovations both filters run
    # through, their innovations near their σ.
    experiments, config = load_data([scenario_i])
    n = len(experiments[0].t)
    for method in ("mekf", "ekf"):
        for fixed in ({"noise_window": 0}, {"noise_window": 0, "state_noise": 0.1}):
            est = identify(experiments, config, method, **fixed)
            assert est.status is Status.DIVERGED, (method, fixed)
            assert "predicted σ" in est.message
            assert est.diverged_t < 8.0
        est = identify(experiments, config, method)
        assert est.status is not Status.DIVERGED, est.message
        assert est.iterations == n and np.all(np.isfinite(est.values)) and np.all(est.std > 0)
        assert est.nis_mean < 2.0, est.nis_mean  # per channel: 1 where consistent


def test_model_error_matches_a_known_process_noise():
    # Data from the model itself driven by a white process noise of 3 measurement σ per sample
    # on v, p and r: covariance matching finds it (its RMS over the run, the first
    # `noise_window` samples ramping up from 0, within 10 %) and nothing on the other states;
    # the innovations are then as large as predicted. The default margin keeps the unforced
    # states at 0 and takes little off the forced ones.
    n = 2400
    inputs = np.zeros((n, 3))
    inputs[:, 0] = _prbs(np.random.default_rng(14), n, 0.05, np.deg2rad(2.0), 0.5)
    forced = [IX["v"], IX["p"], IX["r"]]
    process = np.zeros(10)
    process[forced] = 3.0 * NOISE[forced]
    e = _simulate(SIMULATED, inputs, 0.05, NOISE, seed=15, process=process)
    config = ModelConfig(VEHICLE, dict(SIMULATED), ("Y_dr",))
    noise = dict(zip(STATES, NOISE))
    found = {}
    for margin in (0.0, 2.0):
        est = identify(
            [e], config, "mekf", noise_std=noise, prior_frac=1e-6, noise_window=100, noise_margin=margin
        )
        assert est.status is Status.CONVERGED, est.message
        found[margin] = np.array([est.model_error_std[name] for name in STATES]) / NOISE
        assert abs(est.nis_mean - 1.0) < 0.05, est.nis_mean
    rest = np.setdiff1d(np.arange(10), forced)
    assert np.all(np.abs(found[0.0][forced] - 3.0) < 0.3), found
    assert np.all(found[0.0][rest] < 0.3), found
    assert np.all((found[2.0][forced] > 2.7) & (found[2.0][forced] <= found[0.0][forced])), found
    assert np.all(found[2.0][rest] < 0.1), found
    # Without it the same filter's innovations outgrow their σ.
    fixed = identify([e], config, "mekf", noise_std=noise, prior_frac=1e-6, noise_window=0)
    assert fixed.nis_mean > 3.0, fixed.nis_mean


def test_the_papers_mekf_has_a_fixed_zero_model_noise_and_fits_an_exact_model():
    # PAPER_OPTIONS: no covariance matching, no floor; on data from the linear model itself (the
    # model exact, where Q = 0 is the truth) the filter converges within its σ of the simulated
    # coefficients and reports no model error, where the default matches some.
    from testbed.estimators.filter_options import PAPER_OPTIONS

    assert FilterOptions.build("mekf", PAPER_OPTIONS) == FilterOptions(noise_window=0, state_noise=0.0)
    data = examples.experiments(seed=4, duration=60.0)
    prior = examples.prior_config(error=0.2)
    paper = identify(data, prior, "mekf", PAPER_OPTIONS)
    assert paper.converged and paper.model_error_std is None
    want = np.array([examples.EXAMPLE_COEFFICIENTS[n] for n in examples.FREE])
    z = np.abs(paper.values - want) / paper.std
    assert np.all(z < 4), dict(zip(examples.FREE, z.round(2)))
    assert identify(data, prior, "mekf").model_error_std is not None
