"""Constant force and moment offsets (`X_0` … `N_0`): in the model, estimated shared or per record."""

import numpy as np
import pytest
from references import assert_sensitivities_match_complex_step
from scipy import signal

from testbed.data import Experiment
from testbed.errors import InputError
from testbed.estimators import identify
from testbed.identification import likelihood
from studies.remus import EXAMPLE_COEFFICIENTS, NOISE, VEHICLE, example_config, inputs
from testbed.identification.problem import problem
from testbed.models.linear import IX, NX, OFFSETS, STATES, continuous, structure, theta_vector, tilde

LATERAL = ("Y_v", "Y_r", "Y_dr", "N_v", "N_r", "N_dr")  # a rudder alone leaves roll unexcited
FIN_OFFSET = 0.0087  # rad: a rudder whose zero is 0.5° off


def test_offsets_are_constant_forces_and_moments_in_st():
    s = structure(VEHICLE)
    values = dict(zip(OFFSETS, (1.0, -2.0, 3.0, -0.25, 0.5, -0.75)))
    base = tilde(s, theta_vector(EXAMPLE_COEFFICIENTS))
    with_offsets = tilde(s, theta_vector(EXAMPLE_COEFFICIENTS | values))
    for a, b in zip(base[:3], with_offsets[:3]):  # Mt, At, Bt do not move
        np.testing.assert_array_equal(a, b)
    expected = base[3].copy()
    expected[[IX[n] for n in ("u", "v", "w", "p", "q", "r")]] += list(values.values())
    np.testing.assert_array_equal(with_offsets[3], expected)


def _lsim(coefficients: dict, t: np.ndarray, u: np.ndarray, rng, name: str) -> Experiment:
    """An experiment simulated by scipy (its own zero-order hold of ẋ = A x + B δ + S, S as an
    input held at 1), with the example's noise (`rng` None: none): data the testbed's
    recursions did not make."""
    A, B, S = continuous(structure(VEHICLE), theta_vector(coefficients))
    dt = float(t[1] - t[0])
    Ad, Bd, *_ = signal.cont2discrete((A, np.column_stack([B, S]), np.eye(NX), np.zeros((NX, 4))), dt, "zoh")
    x = np.zeros((len(t), NX))
    for k in range(len(t) - 1):
        x[k + 1] = Ad @ x[k] + Bd @ np.r_[u[k], 1.0]
    x[:, IX["u"]] += VEHICLE.speed
    y = x if rng is None else x + rng.normal(size=x.shape) * np.array([NOISE[s] for s in STATES])
    return Experiment(name, t, STATES, y, u)


def _turns(offsets: tuple[float, float], duration: float = 40.0, noise: bool = True) -> list[Experiment]:
    """Two rudder PRBS records whose rudder zeros are off by `offsets` (rad): each wants its own
    sway force and yaw moment offsets, Y_dr δ₀ and N_dr δ₀."""
    rng = np.random.default_rng(5) if noise else None
    out = []
    for j, d0 in enumerate(offsets):
        t, u = inputs(duration=duration, seed=j + 1)["horizontal"]
        truth = EXAMPLE_COEFFICIENTS | {
            "Y_0": EXAMPLE_COEFFICIENTS["Y_dr"] * d0,
            "N_0": EXAMPLE_COEFFICIENTS["N_dr"] * d0,
        }
        out.append(_lsim(truth, t, u, rng, f"turn-{j}"))
    return out


def test_per_record_sensitivities_match_complex_step():
    data = _turns((FIN_OFFSET, -FIN_OFFSET), duration=3.0)
    prob = problem(data, _start(LATERAL + ("Y_0", "N_0", "K_0"), ("N_0", "Y_0")))
    assert prob.free == LATERAL + ("K_0", "N_0[turn-0]", "N_0[turn-1]", "Y_0[turn-0]", "Y_0[turn-1]")
    p = likelihood.initial_states(prob, prob.start)
    p[prob.n_free - 4 : prob.n_free] = [0.1, -0.2, 0.3, -0.4]
    sens = assert_sensitivities_match_complex_step(prob, p)
    for r, S in zip(prob.records, sens):  # another record's own offsets do not move this one
        others = [j for j, n in enumerate(prob.free) if "[" in n and not n.endswith(f"[{r.name}]")]
        assert not S[:, :, others].any()


def _sigmas(est, truth: dict) -> dict[str, float]:
    return {n: (v - truth[n]) / s for n, v, s in zip(est.free, est.values, est.std)}


def _truth(offsets: tuple[float, float]) -> dict[str, float]:
    return EXAMPLE_COEFFICIENTS | {
        f"{n}[turn-{j}]": EXAMPLE_COEFFICIENTS[c] * d0
        for n, c in (("Y_0", "Y_dr"), ("N_0", "N_dr"))
        for j, d0 in enumerate(offsets)
    }


def assert_recovered_beside_the_offsets(data, extra: tuple[str, ...], truth: dict[str, float]) -> None:
    """`ml-gn` from `_start` with `extra` free beside the lateral coefficients and each record's
    Y_0, N_0 puts every value within 3 σ of `truth` (the example's coefficients and the records'
    offsets added); the same data fitted without `extra` are biased beyond 5 σ."""
    truth = _truth((FIN_OFFSET, -FIN_OFFSET)) | truth
    est = identify(data, _start(LATERAL + ("Y_0", "N_0") + extra, ("Y_0", "N_0")), method="ml-gn")
    assert est.converged
    sigmas = _sigmas(est, truth)
    assert max(abs(v) for v in sigmas.values()) < 3.0, sigmas
    plain = identify(data, _start(LATERAL + ("Y_0", "N_0"), ("Y_0", "N_0")), method="ml-gn")
    assert max(abs(v) for v in _sigmas(plain, truth).values()) > 5.0


def _start(free=LATERAL, per_record=()):
    from dataclasses import replace

    start = example_config(LATERAL).with_coefficients({n: 0.7 * EXAMPLE_COEFFICIENTS[n] for n in LATERAL})
    return replace(start, free=free, per_record=per_record)


def test_each_record_s_offsets_are_recovered_where_one_model_without_them_is_biased():
    offsets = (FIN_OFFSET, -FIN_OFFSET)
    data, truth = _turns(offsets), _truth(offsets)
    est = identify(data, _start(LATERAL + ("Y_0", "N_0"), ("Y_0", "N_0")), method="ml-gn")
    assert est.converged and len(est.free) == len(LATERAL) + 4
    sigmas = _sigmas(est, truth)
    assert max(abs(v) for v in sigmas.values()) < 3.0, sigmas
    plain = identify(data, _start(), method="ml-gn")  # the same data, no offsets in the model
    assert max(abs(v) for v in _sigmas(plain, truth).values()) > 5.0


def test_equation_error_regresses_each_record_s_offsets():
    offsets = (FIN_OFFSET, -FIN_OFFSET)
    data, truth = _turns(offsets, noise=False), _truth(offsets)
    est = identify(data, _start(LATERAL + ("Y_0", "N_0"), ("Y_0", "N_0")), method="equation-error")
    assert est.converged
    np.testing.assert_allclose(est.values, [truth[n] for n in est.free], rtol=0.02)


def test_filters_refuse_per_record_values():
    data = _turns((FIN_OFFSET, -FIN_OFFSET), duration=3.0)
    config = _start(LATERAL + ("N_0",), ("N_0",))
    for method in ("mekf", "ekf"):
        with pytest.raises(InputError, match=r"per_record lists N_0; .* expected no per_record") as exc:
            identify(data, config, method=method)
        assert "\n" not in str(exc.value)


def test_the_screen_fixes_a_per_record_name_only_where_no_record_determines_it():
    from testbed.analysis.screening import screening

    offsets = (FIN_OFFSET, -FIN_OFFSET)
    data = _turns(offsets)
    per_record = ("Y_0", "N_0", "X_0")  # no record has a surge offset
    s = screening(data, _start(LATERAL + per_record, per_record))
    assert list(s.fixed) == ["X_0"] and "in every record: X_0[turn-0], X_0[turn-1]" in s.fixed["X_0"]
    assert s.config.free == LATERAL + ("Y_0", "N_0") and s.config.per_record == ("Y_0", "N_0")


def test_a_free_offset_unpins_its_row():
    """W ≠ B pins the heave row: scaling it by 1 + ε would scale the known W − B in St, which no
    coefficient takes up. A free Z_0 takes it up (Z_0 → (1 + ε)(W − B + Z_0) − (W − B)): the
    heave row's coefficients and Z_0 then drift together."""
    from testbed.analysis.structural import structural

    heave = ("Z_wdot", "Z_qdot", "Z_w", "Z_q", "Z_de")
    s, theta = structure(VEHICLE), theta_vector(EXAMPLE_COEFFICIENTS)
    assert VEHICLE.weight != VEHICLE.buoyancy
    assert structural(s, theta, heave, STATES).null_directions == 0
    free = structural(s, theta, heave + ("Z_0",), STATES)
    assert free.null_directions == 1 and set(free.drift_groups[0]) == {
        "Z_wdot",
        "Z_qdot",
        "Z_w",
        "Z_q",
        "Z_de",
        "Z_0",
    }


def test_identify_command_reports_and_validates_each_record_with_its_own_offsets(tmp_path):
    import json

    from testbed.cli import main
    from testbed.data import write_config, write_csv

    offsets = (FIN_OFFSET, -FIN_OFFSET)
    data, truth = _turns(offsets), _truth(offsets)
    for e in data:
        write_csv(tmp_path / f"{e.name}.csv", e.t, e.y, e.inputs)
    write_config(tmp_path / "model.toml", _start(LATERAL + ("Y_0", "N_0"), ("Y_0", "N_0")))
    out = tmp_path / "est.json"
    args = ["identify", str(tmp_path / "turn-0.csv"), str(tmp_path / "turn-1.csv")]
    assert main(args + ["--config", str(tmp_path / "model.toml"), "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    for j in (0, 1):
        got = doc["coefficients"][f"N_0[turn-{j}]"]
        assert abs(got["value"] - truth[f"N_0[turn-{j}]"]) < 4 * got["std"]
        # each record is validated with its own offset: a shared one would leave ψ drifting
        assert doc["validation"][f"turn-{j}"]["psi"]["fit_percent"] > 99.0
    config = _start().with_coefficients({n: v["value"] for n, v in doc["coefficients"].items()})
    assert config.record_values == {
        f"turn-{j}": {n: doc["coefficients"][f"{n}[turn-{j}]"]["value"] for n in ("Y_0", "N_0")}
        for j in (0, 1)
    }
    assert config.record_coefficients("turn-1")["N_0"] == doc["coefficients"]["N_0[turn-1]"]["value"]
    assert config.record_coefficients("other")["N_0"] == 0.0


def test_per_record_estimates_keep_the_truth_fit_and_the_one_model_filter_refuses_their_values():
    from testbed.jobs.common import truth_comparison

    offsets = (FIN_OFFSET, -FIN_OFFSET)
    data, clean = _turns(offsets), _turns(offsets, noise=False)
    start = _start(LATERAL + ("Y_0", "N_0"), ("Y_0", "N_0"))
    est = identify(data, start, method="ml-gn")
    comparison = truth_comparison(est, example_config(LATERAL), clean)
    assert comparison.note == "" and comparison.truth_fit is not None
    own = _start().with_coefficients(dict(zip(est.free, est.values)))
    with pytest.raises(InputError, match=r"record 'turn-0' has its own [YN]_0; .* expected shared values"):
        identify(data, own, method="mekf")
