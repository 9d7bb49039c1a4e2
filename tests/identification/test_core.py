"""Output-error core: exact sensitivities, exact discretisation, initial states, bounds, bad input."""

from dataclasses import replace

import numpy as np
import pytest
from references import assert_curvature_matches_complex_step, assert_sensitivities_match_complex_step

from testbed.errors import InputError
from testbed.estimators import equation_error, identify
from testbed.identification import bounds, likelihood, prediction, recursions, scan
from studies.remus import EXAMPLE_COEFFICIENTS, FREE, NOISE, example_config, experiments, inputs, prior_config
from testbed.identification.problem import problem
from testbed.models.linear import IX, NX, continuous

VERTICAL_SUBSET = ("u", "w", "q", "theta", "z", "p", "phi")


def _data(duration=3.0, noise=NOISE):
    """Two experiments; the second measures a subset, so measured sets differ per experiment."""
    h, v = experiments(seed=0, duration=duration, noise=noise)
    cols = [v.measured.index(s) for s in VERTICAL_SUBSET]
    return [h, replace(v, measured=VERTICAL_SUBSET, y=v.y[:, cols])]


def _problem(duration=3.0, free=FREE):
    prob = problem(_data(duration), example_config(free))
    return prob, likelihood.initial_states(prob, prob.start)


def test_first_order_sensitivities_match_complex_step():
    prob, p = _problem()
    assert_sensitivities_match_complex_step(prob, p)


def test_second_order_sensitivities_match_complex_step():
    prob, p = _problem(duration=2.0)
    rng = np.random.default_rng(3)
    random = [rng.normal(size=r.y.shape) for r in prob.records]
    one_hot = [np.zeros(r.y.shape) for r in prob.records]
    one_hot[1][25, VERTICAL_SUBSET.index("q")] = 1.0  # ∂²q[25]/∂p∂p of the second experiment
    for weights in (random, one_hot):
        assert_curvature_matches_complex_step(prob, p, weights)


def test_zero_order_hold_model_matches_fine_rk4_with_singular_A():
    prob, p = _problem(duration=4.0)
    A, B, S = continuous(prob.structure, prob.theta)
    assert np.linalg.matrix_rank(A) < NX  # ψ and z are pure integrators
    for r, yhat in zip(prob.records, recursions.simulated_outputs(prob, p)):
        x, h, sub = prob.x0(r, p).copy(), r.dt / 200, 200
        f = lambda x, u: A @ x + B @ u + S  # noqa: E731
        ref = [x[r.measured]]
        for k in range(len(r.y) - 1):
            for _ in range(sub):  # the input is held over the interval
                k1 = f(x, r.inputs[k])
                k2 = f(x + h / 2 * k1, r.inputs[k])
                k3 = f(x + h / 2 * k2, r.inputs[k])
                k4 = f(x + h * k3, r.inputs[k])
                x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            ref.append(x[r.measured])
        np.testing.assert_allclose(yhat, np.array(ref), rtol=1e-9, atol=1e-11)


def test_initial_states_are_recovered_exactly_from_noise_free_data():
    x0 = np.zeros(NX)
    x0[[IX["v"], IX["w"], IX["q"], IX["phi"], IX["z"]]] = 0.05, -0.03, 0.02, 0.04, 1.5
    cfg = example_config()
    t, u = np.arange(0, 5, 0.05), np.zeros((100, 3))
    exp = prediction.synthetic(cfg, t, u, x0=x0, name="release")
    prob = problem([exp], cfg)
    p, outs = likelihood.fit_initial_states(prob, prob.start)
    np.testing.assert_allclose(p[prob.n_free :], x0, atol=1e-9)
    np.testing.assert_allclose(outs[0], prob.records[0].y, atol=1e-9)
    # predict returns absolute u, as in the data
    np.testing.assert_allclose(prediction.predict([exp], cfg)[0], exp.y, atol=1e-9)


def _ar1(rng, shape, rho, std):
    """AR(1) noise of stationary standard deviation `std` (per column) and lag-one correlation rho."""
    w = rng.normal(size=shape) * std * np.sqrt(1 - rho**2)
    a = np.empty(shape)
    a[0] = rng.normal(size=shape[1:]) * std
    for i in range(1, len(a)):
        a[i] = rho * a[i - 1] + w[i]
    return a


def test_coloured_residual_bound_equals_the_morelli_klein_double_sum():
    prob, p = _problem(duration=6.0)
    rng = np.random.default_rng(5)
    res = [_ar1(rng, r.y.shape, 0.6, 0.01) for r in prob.records]  # coloured: K above the floor
    R = likelihood.noise_variance(prob, res)
    mid, lags = np.zeros((prob.n_params, prob.n_params)), []
    for r, S, v in zip(prob.records, recursions.sensitivities(prob, p), res):
        n, cols = len(v), prob.columns(r)
        W = S / R[r.channels][None, :, None]
        Rvv = np.array([v[: n - tau].T @ v[tau:] for tau in range(n)]) / n  # 1/N Σ_m v(m) v(m+τ)ᵀ
        rho = np.diagonal(Rvv, axis1=1, axis2=2)
        K = bounds.lag_window(rho[1 : n // 4 + 1] / rho[0], n)
        lags.append(K)
        for i in range(n):
            for j in range(max(i - K, 0), min(i + K + 1, n)):
                tau = j - i  # Bartlett window w(τ) = 1 − |τ|/(K+1)
                mid[np.ix_(cols, cols)] += (
                    (1 - abs(tau) / (K + 1)) * W[i].T @ (Rvv[tau] if tau >= 0 else Rvv[-tau].T) @ W[j]
                )
    assert all(bounds.MIN_LAGS < K <= 60 for K in lags), lags
    A = rng.normal(size=(prob.n_params, prob.n_params))
    cov = A @ A.T  # any symmetric matrix in place of M⁻¹: the sandwich is linear in each side
    ref = (cov @ mid @ cov)[: prob.n_free, : prob.n_free]
    got = bounds.coloured_covariance(prob, p, recursions.states(prob, p), res, R, cov)
    np.testing.assert_allclose(got, ref, rtol=1e-9, atol=1e-12 * np.abs(ref).max())


def test_lag_window_is_the_floor_for_white_residuals_and_spans_a_coloured_correlation():
    rng = np.random.default_rng(2)
    n = 4000

    def window(v):
        r = np.array([np.sum(v[: n - tau] * v[tau:], axis=0) for tau in range(n // 4 + 1)])
        return bounds.lag_window(r[1:] / r[0], n)

    assert window(rng.normal(size=(n, 10))) == bounds.MIN_LAGS
    # AR(1), ρ = 0.9: τ_int = (1+ρ)/(1−ρ) = 19, so six of them: about 114 lags
    assert 90 <= window(_ar1(rng, (n, 3), 0.9, 1.0)) <= 160
    # a slow oscillation (period 100 samples) in one channel: the window spans its
    # significant correlation (measured: 310 lags)
    v = rng.normal(size=(n, 3))
    v[:, 1] += 1.5 * np.sin(2 * np.pi * np.arange(n) / 100)
    assert 200 <= window(v) <= n // 2  # two periods or more


def _fits(noise, seeds):
    """ml-gn on the Monte Carlo study's experiments (60 s) with `noise(rng, shape, σ)` added."""
    fits = []
    for seed in range(seeds):
        rng = np.random.default_rng(700 + seed)
        data = [
            replace(e, y=e.y + noise(rng, e.y.shape, np.array([NOISE[m] for m in e.measured])))
            for e in experiments(seed, 60.0, noise=None)
        ]
        est = identify(data, prior_config(), method="ml-gn")
        assert est.converged
        fits.append(est)
    return fits


def test_coloured_residual_bound_equals_the_plain_one_for_white_residuals():
    # the fitted residuals of white-noise data: the corrected bound within a few % of the plain one
    # (measured 0.98-1.00 per coefficient over 12 seeds; all lags unwindowed read 0.80-1.01)
    fits = _fits(lambda rng, shape, std: rng.normal(size=shape) * std, 5)
    ratio = np.mean([e.crlb_corrected_std / e.std for e in fits], axis=0)
    assert 0.97 < np.mean(ratio) < 1.03, ratio
    assert np.all((ratio > 0.93) & (ratio < 1.07)), ratio


def test_coloured_residual_bound_grows_with_an_ar1_correlation_as_theory_says():
    # AR(1) noise, ρ = 0.7: the estimate's covariance is the sandwich C Sᵀ Σ⁻¹ T Σ⁻¹ S C with
    # T(i, j) = ρ^|i−j| (Σ the noise variances, C the white bound); for slowly varying
    # sensitivities it is (1+ρ)/(1−ρ) times the white bound
    rho = 0.7
    fits = _fits(lambda rng, shape, std: _ar1(rng, shape, rho, std), 4)
    ratio = np.mean([e.crlb_corrected_std / e.std for e in fits], axis=0)
    prob = problem(experiments(0, 60.0, noise=None), example_config())
    p = likelihood.initial_states(prob, prob.start)
    sigma = np.array([NOISE[c] for c in prob.channels])
    M, mid = np.zeros((prob.n_params, prob.n_params)), np.zeros((prob.n_params, prob.n_params))
    for r, S in zip(prob.records, recursions.sensitivities(prob, p)):
        cols, n = prob.columns(r), len(S)
        T = rho ** np.abs(np.subtract.outer(np.arange(n), np.arange(n)))
        for c, ch in enumerate(r.channels):
            W = S[:, c, :] / sigma[ch]  # Σ^-½ S of one channel (noises independent)
            M[np.ix_(cols, cols)] += W.T @ W
            mid[np.ix_(cols, cols)] += W.T @ T @ W
    C = np.linalg.inv(M)
    theory = np.sqrt(np.diag(C @ mid @ C) / np.diag(C))[: prob.n_free]
    lateral = [FREE.index(n) for n in ("Y_v", "Y_r", "Y_dr", "N_v", "N_r", "N_dr")]
    np.testing.assert_allclose(theory[lateral], np.sqrt((1 + rho) / (1 - rho)), rtol=0.03)
    # the residuals are fitted, which takes some of the coloured noise's low frequencies with it:
    # measured 0.89-0.94 of the sandwich per coefficient (all lags unwindowed: 0.65-0.94)
    assert np.all((ratio / theory > 0.82) & (ratio / theory < 1.05)), ratio / theory
    assert 0.88 < np.mean(ratio / theory) < 1.02, ratio / theory


def test_sensitivities_made_in_pieces_equal_the_whole_recursion():
    prob, p = _problem(duration=3.0)
    models, xs = recursions.discrete_models(prob, p[: prob.n_free], 1), recursions.states(prob, p)
    for r, x, S in zip(prob.records, xs, recursions.sensitivities(prob, p, xs)):
        scale = np.linspace(0.5, 2.0, len(r.measured))
        for size in (7, 8, len(x) - 1):  # odd and even pieces carry the recursion on
            got, parts = np.zeros_like(S), set()
            for channels, params, pieces in recursions.sensitivity_parts(
                prob, r, models[prob.key(r)], x, r.measured, scale, size, values=p[: prob.n_free]
            ):
                for samples, piece in pieces:
                    got[np.ix_(samples, channels, params)] = piece.transpose(1, 0, 2)
                parts.add(tuple(params))
            assert len(parts) == 2  # lateral and longitudinal: propagated apart
            np.testing.assert_allclose(got, S * scale[:, None], rtol=1e-12, atol=1e-13 * np.abs(S).max())


def test_compiled_recursions_equal_the_numpy_blocks():
    prob, p = _problem(duration=3.0)
    pc = p.astype(complex)
    pc[0] += 1e-30j  # complex steps run through both too

    def everything():
        xs, res = recursions.states(prob, p), recursions.residuals(prob, p)
        R = likelihood.noise_variance(prob, res)
        return (
            *xs,
            *recursions.sensitivities(prob, p, xs),
            *likelihood.gauss_newton_terms(prob, p, xs, res, R),
            likelihood.fit_initial_states(prob, prob.start)[0],
            *recursions.simulated_outputs(prob, pc),
        )

    blocks = everything()
    with scan.compiled():
        compiled = everything()
    for a, b in zip(blocks, compiled):  # g sums noise-sized residuals: to rounding of its largest entry
        np.testing.assert_allclose(a.real, b.real, rtol=1e-11, atol=1e-11 * np.abs(a.real).max())
        np.testing.assert_allclose(a.imag, b.imag, rtol=1e-11, atol=1e-11 * np.abs(a.imag).max() + 1e-300)


def test_uncoupled_parts_are_the_connected_states_and_parameters():
    coupled = np.zeros((4, 4), bool)
    coupled[1, 0] = True  # state 0 feeds 1, 2 and 3 are alone
    acts = np.zeros((4, 3), bool)
    acts[0, 0] = acts[2, 1] = acts[3, 2] = True  # parameter 2 acts on state 3 only
    parts = recursions.uncoupled(coupled, acts, np.array([1, 2, 3]))
    assert [[list(a) for a in part] for part in parts] == [
        [[0, 1], [0], [0]],
        [[2], [1], [1]],
        [[3], [2], [2]],
    ]
    acts[3, 1] = True  # parameter 1 now acts on 2 and 3 together: one part
    parts = recursions.uncoupled(coupled, acts, np.array([1, 2]))  # state 3 not asked for
    assert [[list(a) for a in part] for part in parts] == [[[0, 1], [0], [0]], [[2, 3], [1, 2], [1]]]


def test_information_is_consistent():
    data = _data(duration=30.0)
    info = bounds.information(data, example_config())
    F = info.fisher
    np.testing.assert_allclose(F, F.T, rtol=1e-12)
    np.testing.assert_allclose(bounds.fisher(data, example_config()), F, rtol=1e-12)
    # crlb of the coefficients with the initial states as nuisance = the Schur complement's inverse
    np.testing.assert_allclose(info.crlb_std, np.sqrt(np.diag(np.linalg.inv(F))), rtol=1e-6)
    np.testing.assert_allclose(np.diag(info.correlation), 1.0, rtol=1e-9)
    for (
        state,
        sd,
    ) in info.noise_std.items():  # residual std at the simulated coefficients ≈ the simulated noise
        assert abs(sd / NOISE[state] - 1) < 0.1, state
    # the bound ignoring colour and the corrected one agree for white residuals (within noise)
    ratio = info.crlb_corrected_std / info.crlb_std
    assert np.all((ratio > 0.6) & (ratio < 1.5)), ratio
    # values override the config: a 10 % change of one free coefficient raises the cost
    worse = bounds.information(data, example_config(), {"N_r": 0.9 * EXAMPLE_COEFFICIENTS["N_r"]})
    assert worse.cost > info.cost


def test_crlb_is_the_closed_form_inverse_and_infinite_along_null_directions():
    # regular: σ_i = √(F⁻¹)_ii and the correlations of F⁻¹
    J = np.random.default_rng(0).standard_normal((40, 4))
    F = J.T @ J
    inv = np.linalg.inv(F)
    cov, std, corr = bounds.crlb(F)
    np.testing.assert_allclose(cov, inv, rtol=1e-10)
    np.testing.assert_allclose(std, np.sqrt(np.diag(inv)), rtol=1e-10)
    np.testing.assert_allclose(corr, inv / np.outer(std, std), rtol=1e-10, atol=1e-14)
    # nearly singular 2×2, F = [[a, b], [b, c]]: σ₁ = √(c/(ac − b²)), ρ = −b/√(ac), exactly
    a, b, c = 1.0e6, 1.0e3 * (1.0 - 1e-7), 1.0  # ac − b² = 2e-7 ab: eigenvalue ratio 1e-7
    cov, std, corr = bounds.crlb(np.array([[a, b], [b, c]]))
    np.testing.assert_allclose(std, [np.sqrt(c / (a * c - b * b)), np.sqrt(a / (a * c - b * b))], rtol=1e-6)
    np.testing.assert_allclose(corr[0, 1], -b / np.sqrt(a * c), rtol=1e-12)
    # two coefficients that only act as their sum (null direction (1, −1)/√2, up to rounding)
    # and an unrelated one: the pair's bound is infinite, not the pseudo-inverse's finite value,
    # the third keeps its exact bound; scaling the parameters' units changes no decision
    F = np.array([[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 4.0]]) + 1e-17
    assert np.all(np.isfinite(np.sqrt(np.diag(np.linalg.pinv(F, rcond=1e-12, hermitian=True)))))
    for d in (np.ones(3), np.array([1e-4, 1e5, 1e3])):
        cov, std, corr = bounds.crlb(F / np.outer(d, d))
        np.testing.assert_allclose(std, [np.inf, np.inf, 0.5 * d[2]], rtol=1e-9)
        assert np.all(np.isnan(corr[:2])) and np.all(np.isnan(corr[:, :2])) and corr[2, 2] == 1.0
    # a coefficient with no information at all (zero row)
    F = np.diag([4.0, 1.0, 0.0])
    np.testing.assert_allclose(bounds.crlb(F).std, [0.5, 1.0, np.inf])


def test_equation_error_recovers_the_coefficients_from_noise_free_data():
    data = experiments(seed=0, duration=30.0, noise=None)
    prior = example_config().with_coefficients({n: 0.6 * EXAMPLE_COEFFICIENTS[n] for n in FREE})
    got, left = equation_error.regression(problem(data, prior))
    assert left == {}
    want = np.array([EXAMPLE_COEFFICIENTS[n] for n in FREE])
    np.testing.assert_allclose(got, want, rtol=0.01)


def test_equation_error_refuses_data_that_leave_a_row_out():
    t, u = inputs(duration=10.0)["horizontal"]
    config = prior_config(free=("N_r", "N_dr"))
    data = [prediction.synthetic(example_config(), t, u, measured=("r", "psi"), name="yaw")]
    got, left = equation_error.regression(problem(data, config))
    assert set(left) == {"N_r", "N_dr"} and "v" in left["N_r"] and "r" in left["N_r"]
    np.testing.assert_array_equal(got, [config.coefficients["N_r"], config.coefficients["N_dr"]])
    with pytest.raises(
        InputError, match=r"cannot estimate N_r, N_dr \(the row involves v, .*r; no experiment measures v"
    ):
        identify(data, config, method="equation-error")
    # the same data measuring sway too: the row is used
    data = [prediction.synthetic(example_config(), t, u, measured=("v", "p", "r", "phi", "psi"), name="yaw")]
    est = identify(data, config, method="equation-error")
    assert est.converged and est.iterations == 1
    np.testing.assert_allclose(
        est.values, [EXAMPLE_COEFFICIENTS["N_r"], EXAMPLE_COEFFICIENTS["N_dr"]], rtol=0.01
    )


def test_smoothing_is_savitzky_golay_within_the_record():
    from scipy.signal import savgol_filter

    y = np.random.default_rng(2).normal(size=(40, 3)).cumsum(axis=0)
    for win in (5, 11, 39):
        h = win // 2
        np.testing.assert_allclose(
            equation_error.smoothed(y, win),
            savgol_filter(y, win, 3, axis=0)[h : len(y) - h],
            rtol=1e-12,
            atol=1e-12 * np.abs(y).max(),
        )


def test_smoothing_with_missing_samples_fits_the_cubic_to_those_present():
    """A cubic is its own fit from any four samples: with samples missing, each window with half
    of those the channel's rate puts in it present (and at least five) gives the cubic's value at
    its centre; one with fewer gives NaN. All present marked: Savitzky-Golay itself."""
    t = np.linspace(-2, 3, 60)
    y = np.column_stack([1 + t - 0.5 * t**2 + 0.2 * t**3, 2 - t**3])
    present = np.random.default_rng(4).random(y.shape) > 0.3
    present[20:32, 1] = False  # a gap longer than half the window
    win, h = 11, 5
    out = equation_error.smoothed(np.where(present, y, 0.0), win, present)
    counts = np.array([present[k : k + win].sum(axis=0) for k in range(len(y) - 2 * h)])
    enough = counts >= np.maximum(present.mean(axis=0) * win / 2, 5)
    assert (~enough).any() and enough.any()
    np.testing.assert_allclose(out[enough], y[h:-h][enough], rtol=1e-9, atol=1e-9)
    assert np.isnan(out[~enough]).all()
    np.testing.assert_allclose(
        equation_error.smoothed(y, win, np.ones(y.shape, dtype=bool)), equation_error.smoothed(y, win)
    )


def test_bad_input():
    data = _data()
    with pytest.raises(InputError, match="Y_bogus"):
        problem(data, replace(example_config(), free=("Y_v", "Y_bogus")))
    y = data[0].y.copy()
    y[3, 1] = np.inf
    with pytest.raises(InputError, match="infinity"):
        problem([replace(data[0], y=y)], example_config())
    y[3, 1], y[:, 2] = np.nan, np.nan  # a missing sample is taken; a state with none is not
    with pytest.raises(InputError, match=f"{data[0].measured[2]} has no value"):
        problem([replace(data[0], y=y)], example_config())
    t = data[0].t.copy()
    t[5] += 0.01
    with pytest.raises(InputError, match="uniform"):
        problem([replace(data[0], t=t)], example_config())
    with pytest.raises(InputError, match="expected 15"):
        bounds.information(data, example_config(), np.zeros(3))


def test_unmeasured_initial_states_stay_at_trim():
    prob, p = _problem()
    r = prob.records[1]
    assert prob.n_params == len(FREE) + NX + len(VERTICAL_SUBSET)
    unmeasured = np.setdiff1d(np.arange(NX), r.measured)
    assert np.all(prob.x0(r, p)[unmeasured] == 0)


def test_gauss_newton_terms_are_the_weighted_sums_of_the_sensitivities():
    prob, p = _problem()  # two experiments measuring different subsets
    p = likelihood.initial_states(prob, prob.start * 1.1)
    xs, res = recursions.states(prob, p), recursions.residuals(prob, p)
    R = likelihood.noise_variance(prob, res)
    g, M = np.zeros(prob.n_params), np.zeros((prob.n_params, prob.n_params))
    for r, S, e in zip(prob.records, recursions.sensitivities(prob, p), res):
        cols, rinv = prob.columns(r), 1 / R[r.channels]
        g[cols] += np.einsum("nkp,k,nk->p", S, rinv, e)
        M[np.ix_(cols, cols)] += np.einsum("nkp,k,nkq->pq", S, rinv, S)
    g2, M2 = likelihood.gauss_newton_terms(prob, p, xs, res, R)
    np.testing.assert_allclose(g2, g, rtol=1e-10, atol=1e-12 * np.abs(g).max())
    np.testing.assert_allclose(M2, M, rtol=1e-10, atol=1e-12 * np.abs(M).max())


def test_fft_length_is_the_least_5_smooth_number_not_below_n():
    def smooth(m):
        for q in (2, 3, 5):
            while m % q == 0:
                m //= q
        return m == 1

    for n in [*range(1, 400), 6001, 7502, 12345]:
        L = bounds.fft_length(n)
        assert L >= n and smooth(L) and not any(smooth(m) for m in range(n, L)), (n, L)


def test_lag_window_of_a_record_too_short_to_test_is_its_half():
    assert bounds.lag_window(np.empty((0, 3)), 3) == 1
