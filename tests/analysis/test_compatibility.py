"""The data-compatibility check (`testbed check`, `analysis.compatibility`): the kinematics
against closed forms and an independent integrator, sensor errors injected into a real
simulated run's noise-free truth recovered within 3 σ, the σ against the scatter over noise
seeds, the screen, missing channels, `corrected` and `identify --corrections`, the command's
outputs and errors."""

import json
import math
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.integrate import solve_ivp

from testbed.analysis.compatibility import compatibility
from testbed.analysis.compatibility_checks import ATTITUDE, DEPTH, SENSOR_PARAMETERS
from testbed.analysis.compatibility_records import reconstruct
from testbed.analysis.corrections import check_corrections, corrected
from testbed.cli import main
from testbed.data import Experiment, read_csv, write_csv
from testbed.errors import InputError
from testbed.models.linear import INPUTS, STATES
from testbed.simulation.measurements import NOISE_STD
from testbed.simulation.runs import simulate

# Injected: gyro biases of 0.002 rad/s (0.11 deg/s, a tactical-grade gyro's), the log's bias of
# 0.1 m/s along track, an AHRS reading 0.0025 rad (0.14 deg) of pitch at rest, and the rates 40 ms
# (two samples at 50 Hz) late. (A log's w bias makes the sink rate a pitch offset makes at the
# speed: at 16-20 m/s the depth check takes it as the offset; see the lake trial's tests.)
INJECTED = {"b_p": 0.002, "b_q": -0.002, "b_r": 0.002, "tau_gyro": 0.04, "b_u": 0.1, "b_theta": -0.0025}
RATES = ("p", "q", "r")


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """Scenario I (the sea trial: pitch to ±30°, the depth and heading changing), 30 s."""
    return simulate("I", seed=1, duration=30.0, out=tmp_path_factory.mktemp("r") / "I")


@pytest.fixture(scope="module")
def truth(run):
    return read_csv(run / "scenario-I.truth.csv", "scenario-I", keep_repeats=True)


def sensed(truth: Experiment, seed: int, injected=INJECTED, noise=1.0) -> Experiment:
    """What sensors with the `injected` errors would record of the noise-free `truth`: the rates
    late by tau_gyro (linear interpolation, the first sample held), the biases added, white
    noise of the scenario's default σ (times `noise`) on every channel."""
    rng = np.random.default_rng(seed)
    y = truth.y.copy()
    for j, c in enumerate(truth.measured):
        if c in RATES:
            y[:, j] = np.interp(truth.t - injected.get("tau_gyro", 0.0), truth.t, y[:, j])
        y[:, j] += injected.get(f"b_{c}", 0.0) + noise * rng.normal(0.0, NOISE_STD[c], len(truth.t))
    return replace(truth, y=y, name=f"seed{seed}", source="")


def record(t, **channels) -> Experiment:
    """A record of the given channels (arrays or constants) at times `t`, fins at 0."""
    measured = tuple(s for s in STATES if s in channels)
    y = np.column_stack([np.broadcast_to(np.asarray(channels[s], float), t.shape) for s in measured])
    return Experiment("synthetic", t, measured, y, np.zeros((len(t), len(INPUTS))))


# -- the kinematics ---------------------------------------------------------------------------


def test_a_coordinated_turn_in_closed_form():
    # banked at φ0 and turning at Ω: q = Ω sin φ0, r = Ω cos φ0 keep φ and θ = 0 and turn ψ at Ω
    t = np.arange(0, 20.0, 0.02)
    phi0, omega, psi0 = 0.3, 0.1, 1.0
    e = record(t, p=0.0, q=omega * math.sin(phi0), r=omega * math.cos(phi0), phi=phi0, theta=0.0, psi=psi0)
    out = reconstruct(e, ATTITUDE, {"phi0": phi0, "theta0": 0.0, "psi0": psi0})
    np.testing.assert_allclose(out["psi"], psi0 + omega * t, atol=1e-12)
    np.testing.assert_allclose(out["phi"], phi0, atol=1e-12)
    np.testing.assert_allclose(out["theta"], 0.0, atol=1e-12)
    # a gyro with bias b and scale factor k reads (1 + k) r + b: corrected, the same turn
    b, k = 0.01, 0.05
    biased = record(
        t,
        p=0.0,
        q=omega * math.sin(phi0),
        r=(1 + k) * omega * math.cos(phi0) + b,
        phi=phi0,
        theta=0.0,
        psi=psi0,
    )
    out = reconstruct(biased, ATTITUDE, {"phi0": phi0, "theta0": 0.0, "psi0": psi0, "b_r": b, "k_r": k})
    np.testing.assert_allclose(out["psi"], psi0 + omega * t, atol=1e-12)


def test_depth_at_a_constant_pitch_in_closed_form():
    # ż = −u sin θ + w cos θ at φ = 0: w = a sin(ωt) integrates to a (1 − cos ωt) / ω
    t = np.arange(0, 20.0, 0.02)
    theta, u, a, w0 = 0.2, 20.0, 0.3, 1.5
    e = record(t, u=u, v=0.0, w=a * np.sin(w0 * t), phi=0.0, theta=theta, z=50.0)
    z = reconstruct(e, DEPTH, {"z0": 50.0})["z"]
    exact = 50.0 - u * math.sin(theta) * t + math.cos(theta) * a * (1 - np.cos(w0 * t)) / w0
    np.testing.assert_allclose(z, exact, atol=1e-6)  # Simpson on the spline: O(h⁴)


def test_the_attitude_against_an_independent_integrator():
    # rates varying on every axis at once, large angles: scipy's DOP853 at 1e-12 on the exact
    # rates against RK4 on the spline through their 50 Hz samples
    def rates(t):
        return np.array([0.3 * np.sin(0.7 * t), 0.2 * np.cos(0.5 * t), 0.25 * np.sin(0.3 * t + 1)])

    def f(t, x):
        p, q, r = rates(t)
        s, c = math.sin(x[0]), math.cos(x[0])
        return [p + (q * s + r * c) * math.tan(x[1]), q * c - r * s, (q * s + r * c) / math.cos(x[1])]

    t = np.arange(0, 30.0, 0.02)
    x0 = [0.1, -0.2, 0.5]
    ref = solve_ivp(f, (0, t[-1]), x0, t_eval=t, method="DOP853", rtol=1e-12, atol=1e-12).y
    p, q, r = rates(t)
    e = record(t, p=p, q=q, r=r, phi=ref[0], theta=ref[1], psi=ref[2])
    out = reconstruct(e, ATTITUDE, dict(zip(ATTITUDE.initial, x0)))
    for i, c in enumerate(ATTITUDE.outputs):
        np.testing.assert_allclose(out[c], ref[i], atol=1e-7)
    # the rates read 40 ms late: corrected by tau_gyro, the same attitude
    late = record(t, p=np.interp(t - 0.04, t, p), q=np.interp(t - 0.04, t, q), r=np.interp(t - 0.04, t, r))
    e = replace(e, y=np.column_stack([late.y, e.y[:, 3:]]))
    out = reconstruct(e, ATTITUDE, dict(zip(ATTITUDE.initial, x0)) | {"tau_gyro": 0.04})
    inside = t < t[-1] - 0.04  # beyond, the late record has no sample of the rates
    for i, c in enumerate(ATTITUDE.outputs):
        np.testing.assert_allclose(out[c][inside], ref[i][inside], atol=2e-5)  # linear interpolation's error


def test_sensors_without_errors_give_no_delay_on_a_synthetic_roll():
    # rolling only, p a 0.3 s lag of a ±0.1 rad/s PRBS switching every 0.1 s, integrated exactly
    # at 1 ms and sampled at 50 Hz: kinks between samples, no sensor error
    rng = np.random.default_rng(0)
    fine = np.arange(0, 60.0005, 0.001)
    switches = np.repeat(rng.choice([-0.1, 0.1], size=601), 100)[: len(fine)]
    p = np.zeros_like(fine)
    for k in range(1, len(fine)):
        p[k] = p[k - 1] + 0.001 / 0.3 * (switches[k - 1] - p[k - 1])
    phi = np.concatenate([[0.0], np.cumsum((p[1:] + p[:-1]) / 2 * 0.001)])
    t, p, phi = fine[::20], p[::20], phi[::20]
    zero = np.zeros_like(t)
    clean = record(t, p=p, q=zero, r=zero, phi=phi, theta=zero, psi=zero)
    noisy = clean.y + rng.normal(0.0, 1.0, clean.y.shape) * [NOISE_STD[c] for c in clean.measured]
    # noise-free: what the spline misses of the kinks between samples is a twentieth of a
    # sample's delay at most, and a scale error below 0.1 %
    exact = compatibility([replace(clean, y=clean.y + 1e-7 * rng.normal(size=clean.y.shape))]).pooled
    assert abs(exact["attitude"].parameters["tau_gyro"].value) < 0.02 / 20
    assert all(abs(p.value) < 1e-3 for p in exact["attitude"].parameters.values())
    for n, p in compatibility([replace(clean, y=noisy)]).pooled["attitude"].parameters.items():
        assert not p.estimated or abs(p.value) < 3 * p.std, (n, p)  # with noise: nothing found


# -- recovery -----------------------------------------------------------------------------------


def test_injected_biases_and_delay_recovered_within_3_sigma(truth):
    result = compatibility([sensed(truth, seed=1)])
    assert result.unchecked == {"seed1": {}}
    fitted = {n: p for r in result.pooled.values() for n, p in r.parameters.items()}
    assert set(fitted) == set(SENSOR_PARAMETERS)
    for n, value in INJECTED.items():
        p = fitted[n]
        assert p.estimated, (n, p)
        assert abs(p.value - value) < 3 * p.std, (n, p)
        assert p.std < abs(value) / 5, (n, p)  # and determined: not within 3 σ by a large σ
    for n, p in fitted.items():  # the others are 0 in truth: held, or estimated within 3 σ of it
        if n not in INJECTED:
            assert not p.estimated or abs(p.value) < 3 * p.std, (n, p)
    for r in result.pooled.values():  # the filter's innovations are as white as its noise says
        for c, fit in r.fit.items():
            assert 0.8 < fit["innovation_rms"] < 1.25, (c, fit)


@pytest.mark.slow  # Monte Carlo over noise seeds, about 8 s on one core
def test_the_bounds_match_the_scatter_over_noise_seeds(truth):
    # 12 seeds: the scatter's sampling error is 1/√(2 × 11) = 21 %; the bounds must match it
    # within 3 of that, and the mean error be within 3 standard errors of 0
    seeds = range(12)
    always = ("b_p", "b_q", "b_r", "tau_gyro", "b_theta")
    fits = [compatibility([sensed(truth, seed)]).pooled for seed in seeds]
    for n in always:
        check = "attitude" if n in ATTITUDE.sensor else "depth"
        est = [f[check].parameters[n] for f in fits]
        assert all(p.estimated for p in est), n
        values, std = np.array([p.value for p in est]), np.mean([p.std for p in est])
        ratio = np.std(values, ddof=1) / std
        assert abs(ratio - 1) < 3 / math.sqrt(2 * (len(seeds) - 1)), (n, ratio)
        assert abs(values.mean() - INJECTED[n]) < 3 * std / math.sqrt(len(seeds)), (n, values.mean())


def test_pooled_records_share_the_sensor_parameters(truth):
    a, b = sensed(truth, seed=3), sensed(truth, seed=4)
    result = compatibility([a, b])
    pooled = result.pooled["attitude"]
    assert pooled.records == ("seed3", "seed4") and set(pooled.initial) == {"seed3", "seed4"}
    for n in ("b_p", "b_q", "b_r", "tau_gyro"):
        alone = [result.records[r]["attitude"].parameters[n].std for r in ("seed3", "seed4")]
        # twice the data: σ / √2 (within the records' differences)
        assert 0.6 < pooled.parameters[n].std / (np.mean(alone) / math.sqrt(2)) < 1.4, n
        assert abs(pooled.parameters[n].value - INJECTED[n]) < 3 * pooled.parameters[n].std


# -- the screen and missing channels --------------------------------------------------------


def test_roll_never_varying_leaves_the_v_bias_and_scale_not_identifiable(truth):
    e = sensed(truth, seed=2)
    y = e.y.copy()
    y[:, e.measured.index("phi")] = 0.0  # the body never rolls: v has no part in ż
    depth = compatibility([replace(e, y=y)]).pooled["depth"]
    for n in ("b_v", "k_v"):
        p = depth.parameters[n]
        assert not p.estimated and p.value == 0 and p.std == math.inf and "not identifiable" in p.reason
        assert p.to_dict()["std"] is None and p.to_dict()["identifiable"] is False


def test_a_level_run_holds_what_only_noise_would_determine(tmp_path):
    # Scenario II's horizontal record holds depth and pitch: θ is its sensor's noise, and fitted
    # to it b_u would go to u (the depth follows no −u sin θ); the screen holds b_u and k_u
    run = simulate("II", seed=2, duration=5.0, out=tmp_path / "II")
    level = read_csv(run / "horizontal.csv")
    depth = compatibility([level]).pooled["depth"]
    for n in ("b_u", "k_u"):
        p = depth.parameters[n]
        assert not p.estimated and "mostly measurement noise" in p.reason, (n, p)


def test_a_record_without_depth_or_rates_is_checked_for_what_it_has(truth):
    e = sensed(truth, seed=5)
    no_z = e.only([s for s in STATES if s != "z"])
    no_r = replace(e.only([s for s in STATES if s != "r"]), name="no-r")
    result = compatibility([no_z, no_r])
    assert result.unchecked["seed5"]["depth"].startswith("needs u, v, w, phi, theta, z (")
    assert result.unchecked["seed5"]["depth"].endswith("); missing z")
    assert result.unchecked["no-r"]["attitude"].endswith("); missing r")
    assert result.pooled["attitude"].records == ("seed5",) and result.pooled["depth"].records == ("no-r",)
    assert "seed5: depth not checked: needs u, v, w, phi, theta, z (the depth is integrated" in result.table()
    with pytest.raises(InputError, match="nothing to check"):
        compatibility([e.only(["u", "psi"])])


def test_an_attitude_in_degrees_is_not_checked_and_wild_rates_are_an_error(truth):
    e = sensed(truth, seed=8)
    y = e.y.copy()
    for c in ("phi", "theta", "psi"):
        y[:, e.measured.index(c)] *= 180 / math.pi
    result = compatibility([replace(e, y=y)])
    assert "theta reaches 30" in result.unchecked["seed8"]["attitude"] and "attitude" not in result.pooled
    y = e.y.copy()
    y[:, e.measured.index("p")] = 1e6 * np.sign(np.sin(7 * e.t))  # ±1e6 rad/s: tan θ blows up
    with pytest.raises(InputError, match="the attitude check reached no finite estimate") as exc:
        compatibility([replace(e, y=y)])
    assert "\n" not in str(exc.value)


# -- corrections ------------------------------------------------------------------------------


def test_corrected_undoes_the_injected_errors(truth):
    late = sensed(truth, seed=0, noise=0.0)
    back = corrected([late], INJECTED)[0]
    inside = slice(2, -2)  # the first two samples were held by the delay, the last two by its undoing
    for c in ("p", "q", "r", "u", "w", "v", "phi", "theta", "z"):
        np.testing.assert_allclose(back.column(c)[inside], truth.column(c)[inside], atol=1e-12, err_msg=c)
    scaled = corrected([truth], {"k_r": 0.1, "b_r": 0.01})[0]
    np.testing.assert_allclose(scaled.column("r"), (truth.column("r") - 0.01) / 1.1, atol=1e-15)


@pytest.mark.parametrize(
    "values, message",
    [
        ({"b_x": 1.0}, "'b_x' is not a sensor parameter"),
        ({"tau_gyro": 1.5}, "tau_gyro = 1.5; expected a number within ±1"),
        ({"k_p": -0.9}, "k_p = -0.9; expected a number within ±0.5"),
        ({"b_p": "0.1"}, "b_p = '0.1'; expected a number"),
        ({"b_p": "0\n1"}, "b_p = '0\\\\n1'; expected a number"),  # a value's newline stays escaped: one line
        ({"b_p": True}, "b_p = True; expected a number"),
        ({"b_p": math.nan}, "b_p = nan"),
        ({"b_p": math.inf}, "b_p = inf"),
        ([1, 2], "expected an object of sensor parameters"),
    ],
)
def test_check_corrections_names_the_bad_value(values, message):
    with pytest.raises(InputError, match=message.replace("(", r"\(")) as exc:
        check_corrections(values, "f.json: corrections")
    assert "\n" not in str(exc.value) and str(exc.value).startswith("f.json: corrections")


@given(
    st.dictionaries(
        st.sampled_from(SENSOR_PARAMETERS + ("x", "")),
        st.one_of(st.floats(), st.integers(), st.text(max_size=3), st.none(), st.booleans()),
    )
)
def test_check_corrections_takes_or_refuses_in_one_line(values):
    try:
        out = check_corrections(values, "w")
    except InputError as exc:
        assert "\n" not in str(exc)
        return
    assert set(out) <= set(SENSOR_PARAMETERS) and all(math.isfinite(v) for v in out.values())


def test_identify_applies_the_corrections_before_the_fit(run, truth, tmp_path, capsys):
    bad = tmp_path / "bad"
    shutil.copytree(run, bad)
    e = sensed(truth, seed=6)
    write_csv(bad / "scenario-I.csv", e.t, e.y, e.inputs, e.measured, force=True)
    good = tmp_path / "good"
    shutil.copytree(run, good)
    for folder in (bad, good):  # no truth comparison: an ml-gn fit each, beside the point here
        (folder / "scenario-I.truth.csv").unlink()
    fixed = corrected([read_csv(bad / "scenario-I.csv")], INJECTED)[0]
    write_csv(good / "scenario-I.csv", fixed.t, fixed.y, fixed.inputs, fixed.measured, force=True)
    corrections = tmp_path / "corrections.json"
    corrections.write_text(json.dumps({"corrections": INJECTED}))

    def fit(data, *extra):
        out = tmp_path / f"{data.name}{len(extra)}.json"
        assert (
            main(
                ["identify", str(data), "--method", "equation-error", "--free-all", "--out", str(out), *extra]
            )
            == 0
        )
        return json.loads(out.read_text())

    applied = fit(bad, "--corrections", str(corrections))
    assert applied["corrections"] == {"file": str(corrections), "values": INJECTED}
    direct, raw = fit(good), fit(bad)
    for n, c in direct["coefficients"].items():
        assert applied["coefficients"][n]["value"] == pytest.approx(c["value"], rel=1e-6), (
            n
        )  # the CSV's 10 digits
    moved = [
        n
        for n, c in raw["coefficients"].items()
        if abs(c["value"] - direct["coefficients"][n]["value"]) > c["std"]
    ]
    assert moved  # the uncorrected data fit otherwise: the corrections made the difference


# -- the command ------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def trial(run, tmp_path_factory):
    """The Scenario I run with sensors that have the injected errors."""
    folder = tmp_path_factory.mktemp("t") / "trial"
    shutil.copytree(run, folder)
    e = sensed(read_csv(run / "scenario-I.truth.csv", "scenario-I", keep_repeats=True), seed=7)
    write_csv(folder / "scenario-I.csv", e.t, e.y, e.inputs, e.measured, force=True)
    return folder


def test_check_writes_the_json_and_prints_the_table(trial, tmp_path, capsys):
    out = tmp_path / "check.json"
    assert main(["check", str(trial), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert printed.splitlines()[-1] == str(out) and "tau_gyro" in printed and "attitude check" in printed
    doc = json.loads(out.read_text())
    assert set(doc) == {"corrections", "pooled", "records", "unchecked"}
    assert set(doc["corrections"]) == set(SENSOR_PARAMETERS) and doc["unchecked"] == {}
    tau = doc["pooled"]["attitude"]["parameters"]["tau_gyro"]
    assert tau["identifiable"] and abs(tau["value"] - 0.04) < 3 * tau["std"]
    assert set(doc["records"]["scenario-I"]) == {"attitude", "depth"}
    assert set(doc["pooled"]["depth"]["fit"]["z"]) == {
        "noise_std",
        "residual_std",
        "fit_percent",
        "innovation_rms",
    }
    documented = (Path(__file__).parents[2] / "docs" / "files.md").read_text().split("## Check JSON")[1]
    documented = documented.split("\n## ")[0]
    fit = doc["pooled"]["attitude"]
    keys = set(doc) | set(fit) | set(fit["fit"]["phi"]) | {k for p in fit["parameters"].values() for k in p}
    assert len(keys) > 10 and [k for k in sorted(keys) if f"`{k}`" not in documented] == []
    assert main(["check", str(trial), "--out", "-"]) == 0
    std = capsys.readouterr()
    assert json.loads(std.out)["corrections"] == doc["corrections"] and "attitude check" in std.err


def test_check_report_shows_the_corrections_and_each_checks_parameters(trial, tmp_path, capsys):
    """`check --report DIR`: the pooled corrections as the JSON gives them, one figure of each
    check's parameters (pooled and per record) with its reconstruction's fit, nothing unchecked."""
    import base64
    import re

    from testbed.presentation.fit_report import REPORT

    out, folder = tmp_path / "check.json", tmp_path / "report"
    assert main(["check", str(trial), "--out", str(out), "--report", str(folder)]) == 0, (
        capsys.readouterr().err
    )
    page = (folder / REPORT).read_text(encoding="utf-8")
    ids = re.findall(r"<section id='([a-z]+)'>", page)
    assert ids == ["corrections", "attitude", "depth", "unchecked"]
    doc = json.loads(out.read_text())
    tau = doc["corrections"]["tau_gyro"]
    assert f">{tau:.4g}</td>" in page and "every record checked" in page
    images = [base64.b64decode(b) for b in re.findall(r"base64,([A-Za-z0-9+/=]+)'", page)]
    assert len(images) == 2 and all(png.startswith(b"\x89PNG") for png in images)
    fit = doc["pooled"]["depth"]["fit"]["z"]["fit_percent"]
    assert f">{fit:.2f}</td>" in page


def test_check_bad_input_one_line_status_2_nothing_written(trial, tmp_path, capsys):
    csv = trial / "scenario-I.csv"
    before = csv.read_bytes()
    no_channels = tmp_path / "thin.csv"
    no_channels.write_text(
        "t,u,delta_r,delta_er,delta_el\n0,1,0,0,0\n0.02,1,0,0,0\n0.04,1,0,0,0\n0.06,1,0,0,0\n"
    )
    cases = [
        (["check", str(csv), "--out", str(csv)], "is the input"),
        (["check", str(trial), "--out", str(tmp_path)], "is a folder"),
        (["check", str(trial), "--out", str(tmp_path / "no" / "c.json")], "does not exist"),
        (["check", str(tmp_path / "missing.csv")], "no such file"),
        (["check", str(no_channels), "--out", str(tmp_path / "c.json")], "nothing to check"),
    ]
    for argv, message in cases:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err and err.startswith("testbed check: error:"), err
    assert csv.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["thin.csv"]


@pytest.mark.parametrize(
    "content, message",
    [
        ("not json", "not valid JSON"),
        ("[]", "no 'corrections'"),
        ("{}", "no 'corrections'"),
        ('{"corrections": []}', "expected an object of sensor parameters"),
        ('{"corrections": {"b_s": 1}}', "'b_s' is not a sensor parameter"),
        ('{"corrections": {"tau_dvl": -2}}', "tau_dvl = -2"),
        ('{"corrections": {"k_u": 1e400}}', "k_u = inf"),
        ('{"corrections": {"b_q": null}}', "b_q = None"),
        ("[" * 100000 + "]" * 100000, "nested too deeply"),
    ],
)
def test_identify_refuses_a_bad_corrections_file(trial, tmp_path, capsys, content, message):
    bad = tmp_path / "c.json"
    bad.write_text(content)
    out = tmp_path / "est.json"
    argv = [
        "identify",
        str(trial),
        "--method",
        "equation-error",
        "--corrections",
        str(bad),
        "--out",
        str(out),
    ]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err and str(bad) in err, err
    assert not out.exists()


def test_identify_refuses_a_missing_or_folder_corrections(trial, tmp_path, capsys):
    for path, message in ((tmp_path / "none.json", "cannot read"), (tmp_path, "is a folder")):
        assert main(["identify", str(trial), "--method", "equation-error", "--corrections", str(path)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err, err


def test_a_record_with_heading_dropouts_is_checked_on_the_rows_it_has():
    t = np.arange(0.0, 20.0, 0.02)
    rng = np.random.default_rng(0)
    y = np.zeros((len(t), 10))
    y[:, 0] = 20.0
    y[:, 5] = 0.05  # a steady turn: r constant, ψ its integral
    y[:, 8] = 0.05 * t
    y[:, 7] = 0.02 * np.sin(0.5 * t)  # pitch varies: the depth check has something to see
    y[:, 4] = 0.01 * np.cos(0.5 * t)
    y[:, 9] = np.cumsum(-20.0 * y[:, 7]) * 0.02
    y += rng.normal(size=y.shape) * 1e-3
    y[::7, 8] = np.nan  # heading dropouts
    result = compatibility([Experiment("gappy", t, STATES, y, np.zeros((len(t), 3)))])
    assert result.unchecked["gappy"] == {}
    assert result.pooled["attitude"].records == ("gappy",) and result.pooled["depth"].records == ("gappy",)


# -- a logger's records: missing samples and channels, attitude offsets (the lake trial) --------

LAKE_DIVES = (0, 3, 6, 9)  # dive-01, -04, -07, -10: depth steps and doublets, turns
DVL = ("u", "v", "w")


@pytest.fixture(scope="module")
def lake(tmp_path_factory):
    """Seed → the run directory of four of the lake trial's dives (each 20-26 s)."""
    from testbed.simulation.scenario import scenario

    s = scenario("lake")
    s = replace(s, experiments=tuple(s.experiments[i] for i in LAKE_DIVES))
    runs = {}

    def get(seed):
        if seed not in runs:
            runs[seed] = simulate(s, seed=seed, out=tmp_path_factory.mktemp("lake") / f"seed{seed}")
        return runs[seed]

    return get


def as_stamped(path: Path, tick: float = 0.2) -> Experiment:
    """A logged CSV as a reader keeping the stamps gives it: each row at its exact stamp on a
    `tick` clock, the ticks between with every state missing (the fins held), and a DVL channel
    that repeats its last value bit for bit missing (the logger's held ping)."""
    lines = path.read_text().splitlines()
    head, rows = lines[0].split(","), np.array([[float(v) for v in line.split(",")] for line in lines[1:]])
    measured = tuple(c for c in STATES if c in head)
    y = np.column_stack([rows[:, head.index(c)] for c in measured])
    for c in DVL:
        j = measured.index(c)
        y[1:, j] = np.where(y[1:, j] == y[:-1, j], np.nan, y[1:, j])
    at = np.rint(rows[:, 0] / tick).astype(int)
    t = np.arange(at[-1] + 1) * tick
    Y = np.full((len(t), len(measured)), np.nan)
    Y[at] = y
    held = np.searchsorted(at, np.arange(len(t)), "right") - 1  # each tick's latest row
    fins = np.column_stack([rows[:, head.index(c)] for c in INPUTS])[held]
    return Experiment(path.stem, t, measured, Y, fins)


def _offsets(run: Path) -> dict[str, float]:
    import tomllib

    scenario = tomllib.loads((run / "scenario.toml").read_text())
    return {f"b_{c}": v for c, v in scenario["sensors"]["ahrs"]["bias"].items()}


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_the_lake_trials_attitude_offsets_within_3_sigma(lake, seed):
    run = lake(seed)
    records = [as_stamped(p) for p in sorted(run.glob("dive-??.csv"))]
    assert all(np.isnan(e.y).all(axis=1).any() for e in records)  # rows with every state missing
    result = compatibility(records)
    depth = result.pooled["depth"]
    # every dive checked (a stretch of it where its last ping equals the one before to 1 mm/s)
    assert [r.split(" ")[0] for r in depth.records] == [e.name for e in records]
    truth = _offsets(run) | {f"b_{c}": 0.0 for c in DVL}  # the trial's DVL has no bias
    assert truth["b_theta"] == pytest.approx(-0.02618) and truth["b_phi"] == pytest.approx(0.12217)
    theta = depth.parameters["b_theta"]
    assert theta.estimated and theta.std < abs(truth["b_theta"]) / 10, theta  # determined
    for n, value in truth.items():
        if n in depth.parameters:  # b_psi: no check uses the heading
            p = depth.parameters[n]
            assert math.isfinite(p.std) or not p.estimated, (n, p)
            assert abs(p.value - value) < 3 * p.std, (n, p)
    for e in records:
        assert "missing p, q, r" in result.unchecked[e.name]["attitude"]
        assert "rate gyros" in result.unchecked[e.name]["attitude"]


def test_check_on_the_lake_trial_exits_0_naming_what_it_could_not_check(lake, tmp_path, capsys):
    run = lake(1)
    assert main(["check", str(run), "--out", str(tmp_path / "check.json")]) == 0
    out = capsys.readouterr().out
    assert "b_theta" in out and "b_phi" in out
    assert "dive-01: attitude not checked: needs p, q, r, phi, theta, psi" in out
    doc = json.loads((tmp_path / "check.json").read_text())
    assert {"b_phi", "b_theta"} <= set(doc["corrections"])
    assert set(doc["unchecked"]) == {"dive-01", "dive-04", "dive-07", "dive-10"}


def test_no_gyros_and_a_dvl_every_other_row_is_checked_for_depth(lake):
    e = as_stamped(lake(1) / "dive-07.csv")
    u = e.column("u")
    assert 0.3 < np.mean(~np.isnan(u[~np.isnan(e.column("z"))])) < 0.7  # the DVL in every other row
    result = compatibility([e])
    assert set(result.pooled) == {"depth"} and result.pooled["depth"].records == ("dive-07",)
    assert set(result.unchecked["dive-07"]) == {"attitude"}
    assert "attitude not checked" in result.table() and "missing p, q, r" in result.table()
    # a DVL dropout of 5 s splits the dive: the stretch across it is named, either side checked
    y = e.y.copy()
    y[(e.t > 8.5) & (e.t < 13.5), : len(DVL)] = np.nan
    result = compatibility([replace(e, y=y)])
    why = result.unchecked["dive-07"]["depth"]
    assert "over 8–14 s, u, v, w have no sample for 6 s" in why and "is not bridged" in why, why
    assert result.pooled["depth"].records == ("dive-07 0–8 s", "dive-07 14–23 s")
    # gaps of different channels overlapping: nothing inside their union is checked, nor a
    # stretch between gaps with under 4 rows
    y[(e.t > 3.5) & (e.t < 6.5), 1] = np.nan  # v: 3-7 s
    y[(e.t > 16.5) & (e.t < 19.5), 2] = np.nan  # w: 16-20 s
    y[(e.t > 3.5) & (e.t < 5.9), 3] = np.nan  # phi: 3.4-6 s, within v's gap
    result = compatibility([replace(e, y=y)])
    assert result.pooled["depth"].records == ("dive-07 0–3 s", "dive-07 14–16 s", "dive-07 20–23 s")
    why = result.unchecked["dive-07"]["depth"]
    assert "over 7–8 s, between gaps, only 3 rows of the outputs (under 4)" in why, why
    assert "over 3–7 s, v has no sample for 4 s" in why and "over 16–20 s, w has no sample" in why, why
    assert "over 3.4–6 s, phi has no sample for 2.6 s" in why, why


def test_corrected_takes_the_attitude_offsets_off_the_attitude():
    t = np.arange(0.0, 2.0, 0.5)
    e = record(t, u=2.0, phi=0.2, theta=np.array([0.1, np.nan, 0.3, 0.0]))
    back = corrected([e], {"b_phi": 0.12, "b_theta": -0.02})[0]
    np.testing.assert_allclose(back.column("phi"), 0.08)
    np.testing.assert_allclose(back.column("theta"), [0.12, np.nan, 0.32, 0.02])
    np.testing.assert_allclose(back.column("u"), 2.0)
    with pytest.raises(InputError, match="b_theta = 4; expected a number within ±3.14159"):
        check_corrections({"b_theta": 4}, "f.json: corrections")


def test_a_dvls_misalignment_about_z_recovered_where_the_vehicle_rolls_and_about_y_held():
    # the speed 1.2-2.8 m/s, rolling ±0.3 rad and pitching ±0.1: the DVL, misaligned by 0.05 rad
    # about z, reads Rz(−0.05) v; ż integrated independently (solve_ivp). Turned about z it puts
    # az u into v, seen through v sin φ: at a constant speed it would be a v bias; the speed
    # varying tells them apart. Turned about y it is a pitch offset: held for b_theta.
    t = np.arange(0.0, 60.0, 0.1)
    rng = np.random.default_rng(3)

    def body(s):
        phi, theta = 0.3 * np.sin(0.3 * s), 0.1 * np.sin(0.2 * s + 1)
        return (
            np.array([2.0 + 0.8 * np.sin(0.15 * s), 0.05 * np.sin(0.5 * s), 0.02 * np.cos(0.4 * s)]),
            phi,
            theta,
        )

    def zdot(s, z):
        (u, v, w), phi, theta = body(s)
        return -u * np.sin(theta) + (v * np.sin(phi) + w * np.cos(phi)) * np.cos(theta)

    z = solve_ivp(zdot, (0, t[-1]), [5.0], t_eval=t, rtol=1e-10, atol=1e-12).y[0]
    (u, v, w), phi, theta = body(t)
    az = 0.05
    read = np.column_stack([np.cos(az) * u + np.sin(az) * v, -np.sin(az) * u + np.cos(az) * v, w])
    noise = {"u": 0.005, "v": 0.005, "w": 0.005, "phi": 0.003, "theta": 0.003, "z": 0.02}
    channels = dict(zip(DVL, read.T)) | {"phi": phi, "theta": theta, "z": z}
    e = record(t, **{c: y + rng.normal(0.0, noise[c], len(t)) for c, y in channels.items()})
    depth = compatibility([e]).pooled["depth"]
    p = depth.parameters["m_dvl_z"]
    assert p.estimated and abs(p.value - az) < 3 * p.std and p.std < az / 5, p
    assert depth.parameters["m_dvl_y"].reason.startswith("not separable from b_theta"), depth.parameters
    back = corrected([e], {"m_dvl_z": az})[0]  # the reading misaligned back into the body's axes
    np.testing.assert_allclose(back.column("v"), v, atol=0.03)
    np.testing.assert_allclose(back.column("u"), u, atol=0.03)


def test_a_dvls_lever_arm_recovered_from_the_depth_without_gyros():
    # the log 0.8 m forward of the depth sensor (at the CG) and 0.3 m below: it reads v + ω × r,
    # ω from the attitude's rates (ψ constant), ż of the CG integrated independently (solve_ivp).
    # Its point's depth changes by −r_x sin θ + … as the vehicle pitches: what the depth check
    # sees of the lever arm, without rate gyros; the check gives r_dvl_x within 3 σ.
    t = np.arange(0.0, 60.0, 0.1)
    rng = np.random.default_rng(4)
    arm = np.array([0.8, 0.0, 0.3])

    def body(s):
        phi, theta = 0.3 * np.sin(0.3 * s), 0.1 * np.sin(0.2 * s + 1)
        dphi, dtheta = 0.09 * np.cos(0.3 * s), 0.02 * np.cos(0.2 * s + 1)
        rates = np.array([dphi, dtheta * np.cos(phi), -dtheta * np.sin(phi)])
        return (
            np.array([2.0 + 0.8 * np.sin(0.15 * s), 0.05 * np.sin(0.5 * s), 0.02 * np.cos(0.4 * s)]),
            rates,
            phi,
            theta,
        )

    def zdot(s, z):
        (u, v, w), _, phi, theta = body(s)
        return -u * np.sin(theta) + (v * np.sin(phi) + w * np.cos(phi)) * np.cos(theta)

    z = solve_ivp(zdot, (0, t[-1]), [5.0], t_eval=t, rtol=1e-10, atol=1e-12).y[0]
    vel, rates, phi, theta = body(t)
    read = vel.T + np.cross(rates.T, arm)
    noise = {"u": 0.005, "v": 0.005, "w": 0.005, "phi": 0.003, "theta": 0.003, "z": 0.02}
    channels = dict(zip(DVL, read.T)) | {"phi": phi, "theta": theta, "z": z}
    e = record(t, **{c: y + rng.normal(0.0, noise[c], len(t)) for c, y in channels.items()})
    depth = compatibility([e]).pooled["depth"]
    p = depth.parameters["r_dvl_x"]
    assert p.estimated and abs(p.value - arm[0]) < 3 * p.std and p.std < arm[0] / 5, p
    assert "r_dvl_y" in depth.parameters and "r_dvl_z" in depth.parameters
    # the correction needs the rates: refused in one line without them, applied with them
    with pytest.raises(InputError, match=r"r_dvl_x = 0.8; record .* has no p, q, r") as exc:
        corrected([e], {"r_dvl_x": 0.8})
    assert "\n" not in str(exc.value)
    gyros = (
        dict(zip(("p", "q", "r"), rates)) | {c: y for c, y in zip(DVL, read.T)} | {"phi": phi, "theta": theta}
    )
    back = corrected([record(t, **gyros)], {"r_dvl_x": 0.8, "r_dvl_z": 0.3})[0]
    for c, want in zip(DVL, vel):
        np.testing.assert_allclose(back.column(c), want, atol=1e-12)
