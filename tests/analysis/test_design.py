"""Experiment design: criteria, bounds, amplitude scaling, time split, the command line."""

import json
import math
import tomllib
from dataclasses import replace

import numpy as np
import pytest

from testbed.analysis import design as D
from testbed.analysis import design_model as DM
from testbed.analysis import design_signals as DS
from testbed.analysis import regime
from testbed.presentation import design_report
from testbed.errors import InputError
from testbed.simulation.scenario import parse_scenario
from testbed.simulation.signals import Multisine, Prbs


@pytest.fixture(scope="module")
def model():
    from testbed.simulation.analytic import analytic, model_config

    lin = analytic()
    config = model_config(lin)[0]
    return DM.model(replace(config, free=("Y_v", "N_r", "N_dr", "K_p", "K_der", "M_q", "M_de")), lin.fins)


def test_criteria_on_relative_coefficients():
    F = np.diag([4.0, 100.0])
    s = np.array([1.0, 0.1])  # relative information: diag(4, 1)
    assert DM.criterion(F, s, "D") == pytest.approx(math.log(4.0))
    assert DM.criterion(F, s, "A") == pytest.approx(-(0.25 + 1.0))
    assert DM.criterion(F, s, "E") == pytest.approx(1.0)
    assert DM.criterion(np.diag([1.0, 0.0]), np.ones(2), "A") == -math.inf
    with pytest.raises(InputError, match="criterion"):
        DM.criterion(F, s, "X")


def test_band_is_harmonics_of_the_record():
    f = np.array(DS.band(60.0, 0.0, 1.0))
    assert f.min() == pytest.approx(1 / 60) and f.max() <= 1.0 + 1e-9 and len(f) <= DS.MULTISINE_LINES
    assert np.allclose(f * 60, np.round(f * 60))
    assert len(DS.band(60.0, 0.0, 100.0)) == DS.MULTISINE_LINES


def test_split_puts_time_where_the_criterion_needs_it():
    # two experiment types, each informing one coefficient at 1 per second; the second
    # coefficient is 4x larger so it needs 4x the information for the same relative bound
    cands = {
        "a": DS.Candidate("a", {}, 60.0, np.diag([60.0, 0.0])),
        "b": DS.Candidate("b", {}, 60.0, np.diag([0.0, 60.0])),
    }
    s = np.array([1.0, 0.5])
    d = D.time_split(cands, 100.0, s, "E")
    assert d == {"a": 20.0, "b": 80.0} or d == {"a": 30.0, "b": 70.0}  # λ = max min(Ta, Tb/4)
    assert D.time_split(cands, 100.0, s, "D") == {"a": 50.0, "b": 50.0}
    with pytest.raises(InputError, match="duration"):
        D.time_split({"a": cands["a"]}, 100.0, s, "A")  # b's coefficient never informed


def test_largest_amplitude_meets_a_bound_exactly(model):
    limits = DM.regime_limits(model)
    # Scenario II's own experiments define the bounds: its rudder PRBS sits on the yaw-rate bound
    sig = Prbs(amplitude=1e-3, order=10, clock=0.1)
    c = DS.largest(model, "horizontal", {"rudder": sig}, limits, 60.0)
    t, xs, fins = DM.fly_model(model, DS.spec("horizontal", {"rudder": DS.scaled(sig, 1e-3 * c)}), 60.0)
    ratios = limits.ratios(regime.peaks(xs, fins, model.speed, 0.02))
    assert max(ratios.values()) == pytest.approx(1.0, abs=1e-6)
    assert max(ratios, key=ratios.get) in ("yaw_rate", "sideslip")
    # a multisine gets the amplitude that reaches its own binding peak
    ms = Multisine(amplitude=1e-3, frequencies=DS.band(60.0, 0.0, 1.0))
    c2 = DS.largest(model, "roll", {"differential": ms}, limits, 60.0)
    t, xs, fins = DM.fly_model(model, DS.spec("roll", {"differential": DS.scaled(ms, 1e-3 * c2)}), 60.0)
    assert max(limits.ratios(regime.peaks(xs, fins, model.speed, 0.02)).values()) == pytest.approx(
        1.0, abs=1e-6
    )


def test_fisher_matches_finite_differences_of_the_outputs(model):
    """Independent reference: F = Σ Sᵀ R⁻¹ S with S the central differences of the simulated
    outputs (initial states at trim are known here and the experiment starts at trim)."""
    from testbed.identification.prediction import synthetic

    e = DS.spec("horizontal", {"rudder": Prbs(amplitude=1e-3, order=8, clock=0.2)})
    t, xs, fins = DM.fly_model(model, e, 20.0)
    F = DM.design_fisher(model, t, xs, fins)
    cfg = model.config
    chans = [c for c in regime.FITTED]
    w = np.array([1.0 / model.noise_std[c] ** 2 for c in chans])

    def out(cfg_):
        y = synthetic(cfg_, t, fins)
        return np.column_stack([y.column(c) for c in chans])

    S = []
    for n in cfg.free:
        h = 1e-4 * abs(cfg.coefficients[n])
        up = out(cfg.with_coefficients({n: cfg.coefficients[n] + h}))
        dn = out(cfg.with_coefficients({n: cfg.coefficients[n] - h}))
        S.append(((up - dn) / (2 * h)).ravel())
    S = np.array(S).T
    F_fd = S.T @ (S * np.tile(w, len(t))[:, None])
    # The estimated initial state removes a little information; the lateral coefficients the
    # rudder excites agree closely
    i = [cfg.free.index(n) for n in ("Y_v", "N_r", "N_dr")]
    assert np.allclose(np.diag(F)[i], np.diag(F_fd)[i], rtol=0.05)
    assert np.all(np.diag(F)[i] <= np.diag(F_fd)[i] * (1 + 1e-6))


def test_read_estimates(tmp_path):
    p = tmp_path / "est.json"
    p.write_text(
        json.dumps({"coefficients": {"Y_v": {"value": -2000.0, "std": 10.0}}, "noise_std": {"v": 0.03}})
    )
    values, noise = design_report.design_estimates(p)
    assert values == {"Y_v": -2000.0} and noise["v"] == 0.03 and noise["r"] == 0.002
    p.write_text(json.dumps({"coefficients": {"Y_q": {"value": 1.0}}}))
    with pytest.raises(InputError, match="Y_q"):
        design_report.design_estimates(p)
    p.write_text("{")
    with pytest.raises(InputError, match="estimates JSON"):
        design_report.design_estimates(p)


def test_design_refuses_bad_arguments():
    with pytest.raises(InputError, match="criterion"):
        D.design(180.0, "B")
    with pytest.raises(InputError, match="duration"):
        D.design(10.0, "A")
    with pytest.raises(InputError, match="free"):
        D.design(180.0, "A", free=["Y_x"])


def test_cli_design_errors(tmp_path, capsys):
    from testbed.cli import main

    assert main(["design", "--criterion", "A", "--free", "Y_x", "--out", str(tmp_path / "d.toml")]) == 2
    assert "Y_x" in capsys.readouterr().err and not (tmp_path / "d.toml").exists()
    assert main(["design", "--out", str(tmp_path / "no" / "d.toml")]) == 2


def test_the_design_recording_holds_the_comparison_and_the_flights(tmp_path):
    """Read back: the paired bars are the relative bounds of the design and of Scenario II, the
    table names every free coefficient, and each designed experiment has its moved channels."""
    import rerun.chunk

    free = ("Y_v", "N_r", "N_dr", "K_p", "K_der", "M_q", "M_de")
    d = D.design(60.0, "A", free=free, check=False)
    path = design_report.log_design(tmp_path / "design.rrd", d)
    bars, entities, table = {}, set(), ""
    for chunk in rerun.chunk.RrdReader(str(path)).stream():
        entities.add(str(chunk.entity_path))
        rb = chunk.to_record_batch()
        names = [f.name for f in rb.schema]
        if "BarChart:values" in names:
            bars[str(chunk.entity_path)] = np.array(
                rb.column(names.index("BarChart:values"))[0].as_py()[0]["buffer"]
            )
        if "TextDocument:text" in names and str(chunk.entity_path) == "/bounds/table":
            table = rb.column(names.index("TextDocument:text"))[0].as_py()[0]
    assert np.allclose(bars["/bounds/design"], 100 * d.relative(d.crlb))
    assert np.allclose(bars["/bounds/scenario_II"], 100 * d.relative(d.crlb_base))
    assert all(f"| {n} |" in table for n in free)
    for e in d.scenario.experiments:
        assert f"/flights/{e.name}/delta_r" in entities or f"/flights/{e.name}/delta_er" in entities
        assert f"/flights/{e.name}/u" not in entities  # not moved by the linear model: not drawn


def _free(run_estimates):
    return set(json.loads(run_estimates.read_text())["coefficients"])


def _analyze(main, run, free, tmp_path):
    """`testbed analyze RUN` with the run's model.toml, `free` made its free list: the relative bounds."""
    text = (run / "model.toml").read_text()
    line = next(l for l in text.splitlines() if l.startswith("free = "))
    config = tmp_path / f"{run.name}.toml"
    config.write_text(text.replace(line, "free = " + json.dumps(sorted(free))))
    out = tmp_path / f"{run.name}.analysis.json"
    assert main(["analyze", str(run), "--config", str(config), "--out", str(out)]) == 0
    return json.loads(out.read_text())["relative_crlb"]


@pytest.mark.slow  # the design's study through six commands (design, two simulate, identify, analyze), about 20 s
def test_designed_run_halves_scenario_ii_worst_bound_stays_linear_and_is_identified(tmp_path):
    """The acceptance of `testbed design`, through the command line as a user runs it: the
    default design and Scenario II flown (default seed, same flight time), each identified by
    `ml-gn` (which frees what its data identify), then `testbed analyze` on both runs over the
    coefficients both free (the roll row's K_v, K_p, K_der, K_del among them)."""
    from testbed.cli import main
    from testbed.data import load_data, read_config
    from testbed.identification.prediction import predict
    from testbed.models.linear import STATES
    from testbed.fit_percent import fit_percent

    designed = tmp_path / "designed.toml"
    assert main(["design", "--out", str(designed), "--rrd", str(tmp_path / "design.rrd")]) == 0
    assert (tmp_path / "design.rrd").stat().st_size > 0
    runs = {"designed": tmp_path / "designed", "II": tmp_path / "II"}
    assert main(["simulate", "--scenario", str(designed), "--out", str(runs["designed"])]) == 0
    assert main(["simulate", "--scenario", "II", "--out", str(runs["II"])]) == 0
    flight = {k: sum(e.t[-1] - e.t[0] for e in load_data([r])[0]) for k, r in runs.items()}
    assert flight["designed"] <= flight["II"] + 1e-6  # no more flight time
    for k, r in runs.items():
        assert main(["identify", str(r), "--out", str(tmp_path / f"{k}.json")]) == 0
    both = _free(tmp_path / "designed.json") & _free(tmp_path / "II.json")
    assert {"K_v", "K_p", "K_der", "K_del"} <= both
    rel = {k: _analyze(main, r, both, tmp_path) for k, r in runs.items()}
    worst = {k: max(rel[k][n] for n in both) for k in runs}
    assert worst["designed"] <= 0.5 * worst["II"], worst

    # linear: the analytic model open loop from the first noise-free sample, the flown inputs
    config = read_config(runs["designed"] / "model.toml")
    truth, _ = load_data(sorted(runs["designed"].glob("*.truth.csv")), keep_repeats=True)
    start = {e.name: dict(zip(STATES, e.y[0])) for e in truth}
    for e, yhat in zip(truth, predict(truth, config, start)):
        excited = DS.TEMPLATES[e.name.split("-")[0].split(".")[0]]["excited"]
        for c in excited:
            assert fit_percent(e.column(c), yhat[:, STATES.index(c)]) >= 99.0, (e.name, c)

    # ml-gn on the designed run: within max(3 coloured-residual σ, 3 %) of the analytic model
    est = json.loads((tmp_path / "designed.json").read_text())
    analytic = {row["name"]: row["analytic"] for row in est["comparison"]["rows"]}
    for n, c in est["coefficients"].items():
        tol = max(3 * est["crlb_corrected_std"][n], 0.03 * abs(analytic[n]))
        assert abs(c["value"] - analytic[n]) <= tol, (n, c["value"], analytic[n])


def test_sequential_design_is_made_at_the_estimate_and_its_noise(tmp_path):
    """`--from EST.json`: the design model takes the estimate's coefficients (its free set)
    and noise; the information scales as 1/σ², so doubling every noise σ doubles every bound
    of the same design exactly."""
    from testbed.simulation.analytic import analytic_config

    analytic = analytic_config()[0].coefficients
    free = ("Y_v", "Y_r", "Y_dr", "N_v", "N_r", "N_dr", "K_p", "K_der", "K_del")
    estimate = {n: 1.2 * analytic[n] for n in free}
    path = tmp_path / "est.json"
    path.write_text(
        json.dumps({"coefficients": {n: {"value": v} for n, v in estimate.items()}, "noise_std": {"v": 0.03}})
    )
    values, noise = design_report.design_estimates(path)
    d1 = D.design(60.0, "A", estimates=values, noise_std=noise, check=False)
    assert d1.source == "estimate" and set(d1.free) == set(free)
    assert np.allclose(d1.values, [estimate[n] for n in d1.free])
    d2 = D.design(60.0, "A", estimates=values, noise_std={k: 2 * v for k, v in noise.items()}, check=False)
    assert d2.scenario == d1.scenario and np.allclose(d2.crlb, 2 * d1.crlb)
    d0 = D.design(60.0, "A", free=free, check=False)  # at the analytic model
    assert not np.allclose(d0.crlb_base, d1.crlb_base)


@pytest.mark.slow  # a design grown on the truth plant, about 20 s on one core
def test_design_from_an_estimates_file_writes_a_scenario_made_at_it(tmp_path):
    """`testbed design --from EST.json`: the scenario file says it was made at the estimate and
    lists its free set, and reads back as a scenario."""
    from testbed.cli import main
    from testbed.simulation.analytic import analytic_config

    analytic = analytic_config()[0].coefficients
    free = ("Y_v", "Y_r", "Y_dr", "N_v", "N_r", "N_dr", "K_p", "K_der", "K_del")
    path = tmp_path / "est.json"
    path.write_text(
        json.dumps(
            {"coefficients": {n: {"value": 1.2 * analytic[n]} for n in free}, "noise_std": {"v": 0.03}}
        )
    )
    out = tmp_path / "next.toml"
    assert main(["design", "--from", str(path), "--duration", "120", "--out", str(out)]) == 0
    text = out.read_text()
    assert "at the estimate" in text and all(f"#   {n} " in text for n in free)
    assert parse_scenario(tomllib.loads(text), str(out)).experiments


def test_design_from_an_unstable_estimate_names_the_file_the_mode_and_the_coefficient(tmp_path, capsys):
    """The yaw damping's sign flipped: refused (exit 2, nothing written) naming the estimates
    file, the growing mode (its rate: A's eigenvalue of largest real part) and N_r."""
    from testbed.cli import main
    from testbed.models.linear import continuous, structure, theta_vector
    from testbed.simulation.analytic import analytic_config

    config = analytic_config()[0]
    flipped = config.with_coefficients({"N_r": -config.coefficients["N_r"]})
    A = continuous(structure(flipped.vehicle), theta_vector(flipped.coefficients))[0]
    rate = np.linalg.eigvals(A).real.max()
    assert rate > 1.0  # premise: the flipped model diverges
    path = tmp_path / "est.json"
    path.write_text(json.dumps({"coefficients": {"N_r": {"value": flipped.coefficients["N_r"]}}}))
    out = tmp_path / "next.toml"
    assert main(["design", "--from", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"{path}: the linear model is unstable: a mode in r" in err, err
    assert f"grows at {rate:.3g} 1/s" in err and "depends most on N_r = " in err
    assert "\n" not in err.strip() and not out.exists()


def test_a_multisine_above_half_the_control_rate_is_refused_naming_the_field(tmp_path, capsys):
    """A line at or above the Nyquist frequency of the control rate is sampled as another one
    (at 1e308 Hz its phase overflows): refused up front, the field and the bound named."""
    import warnings

    from testbed.cli import main

    def doc(frequencies, rate=50.0):
        rudder = {"signal": "multisine", "amplitude": 0.01, "frequencies": frequencies}
        return {"control_rate": rate, "experiment": [{"name": "a", "rudder": rudder}]}

    expected = (
        r"s.toml: experiment 'a' rudder: multisine frequencies up to {} Hz; expected frequencies below {} Hz"
    )
    with pytest.raises(
        InputError, match=expected.format(r"1e\+308", "25") + r", half the control_rate \(50 Hz\)"
    ):
        parse_scenario(doc([0.1, 1e308]), "s.toml")
    with pytest.raises(InputError, match=expected.format("50", "50")):
        parse_scenario(doc([0.1, 50.0], rate=100.0), "s.toml")
    assert parse_scenario(doc([0.1, 49.9], rate=100.0), "s.toml").experiments
    path = tmp_path / "s.toml"
    path.write_text(
        '[[experiment]]\nname = "a"\nrudder = {signal = "multisine", amplitude = 0.01, frequencies = [0.1, 1e308]}\n'
    )
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert main(["simulate", "--scenario", str(path), "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert "frequencies up to 1e+308 Hz" in err and "speed" not in err and not (tmp_path / "run").exists()
