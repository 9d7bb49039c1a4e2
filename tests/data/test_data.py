"""The file readers and writers: round trips and one-line errors on bad input."""

import tomllib
from dataclasses import replace

import numpy as np
import pytest

from testbed.data import (
    CSV_COLUMNS,
    Experiment,
    ModelConfig,
    config_text,
    load_data,
    median,
    parse_config,
    read_config,
    read_csv,
    write_config,
    write_csv,
)
from testbed.outputs import atomic_directory
from testbed.errors import InputError
from testbed.models.linear import COEFFICIENTS, INPUTS, PARAMETERS, STATES, Vehicle

VEHICLE = Vehicle(30.51, 0.177, 3.45, 3.45, 299.0, 306.0, 0.0, 0.0, -0.0196, 1.54)


def _csv(tmp_path, text, name="e.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_csv_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    t = np.arange(20) * 0.05
    # within ±1: no angle jumps by more than π between rows, so none is unwrapped
    x, d = rng.uniform(-1.0, 1.0, size=(20, 10)), rng.normal(size=(20, 3))
    path = write_csv(tmp_path / "run.csv", t, x, d)
    e = read_csv(path)
    assert e.name == "run" and e.measured == STATES
    np.testing.assert_allclose(e.y, x, rtol=1e-9)
    np.testing.assert_allclose(e.inputs, d, rtol=1e-9)
    assert e.dt == pytest.approx(0.05)


def test_csv_read_in_one_pass_equals_row_by_row(tmp_path):
    """A plain table is parsed in one pass; the same values in forms only the row-by-row reader
    takes (a quoted cell, lone-CR line ends, a text column) read to the same floats, bit for bit."""
    rng = np.random.default_rng(1)
    t = np.arange(50) * 0.05
    x = rng.normal(size=(50, 10)) * 10.0 ** rng.integers(-8, 4, size=(50, 10))
    plain = read_csv(write_csv(tmp_path / "plain.csv", t, x, rng.normal(size=(50, 3))))
    text = (tmp_path / "plain.csv").read_text()
    head, first, rest = text.split("\n", 2)
    cells = first.split(",")
    cells[1] = f'"{cells[1]}"'
    variants = {
        "quoted.csv": "\n".join([head, ",".join(cells), rest]),
        "cr.csv": text.replace("\n", "\r"),
        "text.csv": "".join(
            line + (",note\n" if k else ",remark\n") for k, line in enumerate(text.splitlines())
        ),
    }
    for name, variant in variants.items():
        e = read_csv(_csv(tmp_path, variant, name))
        for a, b in ((e.t, plain.t), (e.y, plain.y), (e.inputs, plain.inputs)):
            np.testing.assert_array_equal(a, b)


def test_median_is_numpys():
    rng = np.random.default_rng(4)
    for a in (
        rng.normal(size=7),
        rng.normal(size=8),
        np.array([1.0, np.inf, -np.inf, 2.0]),
        np.array([3.0, np.nan, 1.0]),
        np.array([-np.inf, np.inf]),
        rng.integers(0, 3, size=10),
    ):
        with np.errstate(invalid="ignore"):  # -inf + inf
            np.testing.assert_array_equal(median(a), np.median(a))


def test_csv_subset_and_extra_columns(tmp_path):
    p = _csv(
        tmp_path, "t,extra,r,delta_r,delta_er,delta_el,v\n0,9,1,0,0,0,2\n0.1,9,1,0,0,0,2\n0.2,9,1,0,0,0,2\n"
    )
    e = read_csv(p)
    assert e.measured == ("v", "r")
    np.testing.assert_array_equal(e.column("r"), [1, 1, 1])


@pytest.mark.parametrize(
    "text, words",
    [
        ("", "empty file"),
        ("t,u,delta_r,delta_er\n0,1,0,0\n", "'delta_el' missing"),
        ("t,delta_r,delta_er,delta_el\n0,0,0,0\n1,0,0,0\n2,0,0,0\n", "no state column"),
        ("t,u,delta_r,delta_er,delta_el\n0,1,0,0,0\n0.1,inf,0,0,0\n0.2,1,0,0,0\n", "line 3, column 'u'"),
        ("t,u,delta_r,delta_er,delta_el\n0,1,0,0,0\nnan,1,0,0,0\n0.2,1,0,0,0\n", "line 3, column 't'"),
        ("t,u,delta_r,delta_er,delta_el\n0,1,0,0,0\n,1,0,0,0\n0.2,1,0,0,0\n", "line 3, column 't'"),
        ("t,u,delta_r,delta_er,delta_el\n0,,0,0,0\n0.1,nan,0,0,0\n0.2,,0,0,0\n", "column 'u' has no value"),
        ("t,u,delta_r,delta_er,delta_el\n0,1,,0,0\n0.1,1,0,0,0\n0.2,1,0,0,0\n", "row 1, column 'delta_r'"),
        ("t,u,delta_r,delta_er,delta_el\n0,1,0,0,0\n0.2,1,0,0,0\n0.1,1,0,0,0\n", "data row 3: t = 0.1"),
        ("t,u,delta_r,delta_er,delta_el\n0,1,0,0,0\n0,1,0,0,0\n0,1,0,0,0\n", "t never increases"),
        (
            "t,u,delta_r,delta_er,delta_el\n0,1,0,0,0\n1e-6,1,0,0,0\n2e-6,1,0,0,0\n3e-6,1,0,0,0\n10,1,0,0,0\n",
            "t spans 10 s at a median step of 1e-06 s, more than 1000000 samples",
        ),
        (
            "t,u,delta_r,delta_er,delta_el\n0,1,0,0,0\n0.1,1,0,0,0\n0.2,1,0,0,0\n1e300,1,0,0,0\n",
            "t spans 1e\\+300 s at a median step of 0.1 s, more than 1000000 samples",
        ),
        ("t,u,delta_r,delta_er,delta_el\n0,1,0,0,0\n0.1,x,0,0,0\n0.2,1,0,0,0\n", "'x' is not a number"),
        ("t,u,delta_r,delta_er,delta_el\n0,1,0,0,0\n0.1,1,0,0\n0.2,1,0,0,0\n", "line 3 has 4 fields"),
    ],
)
def test_csv_bad_input(tmp_path, text, words):
    with pytest.raises(InputError, match=words) as exc:
        read_csv(_csv(tmp_path, text))
    assert "\n" not in str(exc.value) and "e.csv" in str(exc.value)


def test_config_round_trip(tmp_path):
    coeffs = {n: float(i) - 17.5 for i, n in enumerate(COEFFICIENTS)}
    cfg = ModelConfig(VEHICLE, coeffs, ("X_u", "N_r"))
    path = write_config(tmp_path / "m.toml", cfg, {"X_u": "surge damping"})
    back = read_config(path)
    assert back.vehicle == VEHICLE and back.free == ("X_u", "N_r")
    assert back.coefficients == dict.fromkeys(PARAMETERS, 0.0) | coeffs
    assert "# surge damping" in config_text(cfg, {"X_u": "surge damping"})
    assert "K_0" not in config_text(cfg)  # offsets appear only where a config sets or frees them


def test_config_round_trip_with_offsets_per_record(tmp_path):
    coeffs = {n: float(i) - 17.5 for i, n in enumerate(COEFFICIENTS)} | {"K_0": -0.25}
    cfg = ModelConfig(VEHICLE, coeffs, ("X_u", "N_0", "K_0"), per_record=("N_0",))
    back = read_config(write_config(tmp_path / "m.toml", cfg))
    assert back.coefficients == dict.fromkeys(PARAMETERS, 0.0) | coeffs
    assert back.free == ("X_u", "N_0", "K_0") and back.per_record == ("N_0",)


@pytest.mark.parametrize(
    "per_record, words",
    [
        ('["N_r"]', "names 'N_r', which free does not list"),
        ('["N_0", "N_0"]', "names N_0 twice"),
        ("3", "must be a list"),
    ],
)
def test_config_per_record_bad_input(tmp_path, per_record, words):
    text = config_text(ModelConfig(VEHICLE, {}, ("N_0",))).replace(
        'free = ["N_0"]', f'free = ["N_0"]\nper_record = {per_record}'
    )
    path = tmp_path / "m.toml"
    path.write_text(text)
    with pytest.raises(InputError, match=words) as exc:
        read_config(path)
    assert "\n" not in str(exc.value) and "per_record" in str(exc.value)


def _doc(**changes):
    doc = {
        "vehicle": {k: getattr(VEHICLE, k) for k in Vehicle.names() if getattr(VEHICLE, k) is not None},
        "coefficients": {"X_u": -1.0},
        "identify": {"free": ["X_u"]},
    }
    for key, value in changes.items():
        table, _, field = key.partition("__")
        if value is None:
            doc[table].pop(field)
        else:
            doc[table][field] = value
    return doc


@pytest.mark.parametrize(
    "changes, words",
    [
        ({"vehicle__zB": None}, r"\[vehicle\] zB missing"),
        ({"vehicle__mass": "heavy"}, r"\[vehicle\] mass = 'heavy'; expected a finite number"),
        ({"vehicle__speed": 0.0}, r"\[vehicle\] speed = 0; expected 0.001 to 450"),
        ({"vehicle__speed": 1e-6}, r"\[vehicle\] speed = 1e-06; expected 0.001 to 450"),
        ({"vehicle__weight": -299.0}, r"\[vehicle\] weight = -299; expected > 0"),
        ({"vehicle__buoyancy": 0}, r"\[vehicle\] buoyancy = 0; expected > 0"),
        (
            {"coefficients__Y_v": 1e300},
            r"\[coefficients\] Y_v = 1e\+300; expected a magnitude of at most 1e\+15",
        ),
        ({"vehicle__colour": 1.0}, r"\[vehicle\] colour is not a vehicle constant"),
        ({"coefficients__Y_vv": 1.0}, r"\[coefficients\] Y_vv is not a coefficient"),
        ({"identify__free": ["X_u", "Y_foo"]}, r"free names 'Y_foo'"),
        ({"identify__free": ["X_u", "X_u"]}, r"names a coefficient twice"),
        ({"identify__noise_std": 0.01}, r"\[identify\] noise_std = 0.01; expected a table of state = σ"),
        ({"identify__noise_std": {"yaw": 0.01}}, r"\[identify\] noise_std names 'yaw', not a state"),
        ({"identify__noise_std": {"r": 0.0}}, r"\[identify\] noise_std: r = 0; expected a σ from 1e-09"),
        ({"identify__noise_std": {"r": -0.002}}, r"\[identify\] noise_std: r = -0.002; expected a σ"),
        ({"identify__noise_std": {"psi": 1e7}}, r"\[identify\] noise_std: psi = 1e\+07; expected a σ"),
        ({"identify__noise_std": {"r": "0.002"}}, r"\[identify\] noise_std: r = '0.002'; expected a finite"),
        ({"identify__noise_std": {"r": True}}, r"\[identify\] noise_std: r = true; expected a finite"),
        ({"identify__noise_std": {"r": float("inf")}}, r"\[identify\] noise_std: r = inf; expected a finite"),
    ],
)
def test_config_bad_input(changes, words):
    with pytest.raises(InputError, match=words):
        parse_config(_doc(**changes), "m.toml")


def test_config_noise_std_round_trip_and_merge(tmp_path):
    cfg = parse_config(_doc(identify__noise_std={"psi": 0.002, "r": 1}), "m.toml")
    assert cfg.noise_std == {"r": 1.0, "psi": 0.002}  # in state order, as floats
    assert "noise_std = {r = 1.0, psi = 0.002}" in config_text(cfg)
    assert read_config(write_config(tmp_path / "m.toml", cfg)).noise_std == cfg.noise_std
    assert parse_config(_doc(), "m.toml").noise_std is None
    assert "noise_std" not in config_text(parse_config(_doc(), "m.toml"))
    # given values replace the config's entry by entry; the others stay
    assert cfg.with_noise_std({"r": 0.003, "u": 0.05}).noise_std == {"u": 0.05, "r": 0.003, "psi": 0.002}
    assert cfg.with_noise_std(None) is cfg
    with pytest.raises(InputError, match=r"^noise_std: r = -1; expected a σ"):
        cfg.with_noise_std({"r": -1})


def test_config_missing_name_is_zero_and_fixed():
    cfg = parse_config(_doc(), "m.toml")
    assert cfg.coefficients["Y_v"] == 0.0 and set(cfg.coefficients) == set(PARAMETERS)


def test_malformed_toml(tmp_path):
    p = tmp_path / "bad.toml"
    p.write_text("[vehicle\nmass = 1")
    with pytest.raises(InputError, match="bad.toml: not valid TOML"):
        read_config(p)


def test_load_run_directory(tmp_path):
    t = np.arange(5) * 0.1
    write_csv(tmp_path / "horizontal.csv", t, np.zeros((5, 10)), np.zeros((5, 3)))
    write_csv(tmp_path / "horizontal.truth.csv", t, np.zeros((5, 10)), np.zeros((5, 3)))
    write_config(tmp_path / "model.toml", ModelConfig(VEHICLE, dict.fromkeys(COEFFICIENTS, 0.0)))
    experiments, cfg = load_data([tmp_path])
    assert [e.name for e in experiments] == ["horizontal"] and cfg.vehicle == VEHICLE
    with pytest.raises(InputError, match="no such file"):
        load_data([tmp_path / "missing"])


def test_atomic_directory_leaves_nothing_on_error(tmp_path):
    target = tmp_path / "run"
    with pytest.raises(KeyboardInterrupt):
        with atomic_directory(target) as tmp:
            (tmp / "half.csv").write_text("x")
            raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []
    with atomic_directory(target) as tmp:
        (tmp / "whole.csv").write_text("x")
    assert (target / "whole.csv").exists()
    with pytest.raises(InputError, match="already exists"):
        with atomic_directory(target):
            pass


def test_csv_columns_are_the_spec_columns():
    assert ",".join(CSV_COLUMNS) == "t,u,v,w,p,q,r,phi,theta,psi,z,delta_r,delta_er,delta_el"


def test_outputs_must_be_measured_by_some_record():
    """Each `[identify] outputs` entry is measured by at least one record; a record keeps the
    outputs it measures; one measuring none of them is refused."""
    t = np.arange(5) * 0.1
    rv = Experiment("rv", t, ("v", "r"), np.zeros((5, 2)), np.zeros((5, 3)), "rv.csv")
    vp = Experiment("vp", t, ("v", "psi"), np.zeros((5, 2)), np.zeros((5, 3)), "vp.csv")
    cfg = ModelConfig(VEHICLE, dict.fromkeys(COEFFICIENTS, 0.0), ("Y_v",), "m.toml", ("r", "psi"))
    assert [e.measured for e in cfg.fitted([rv, vp])] == [("r",), ("psi",)]
    missing = replace(cfg, outputs=("r", "z", "q"))
    with pytest.raises(InputError) as exc:
        missing.fitted([rv, vp])
    message = str(exc.value)
    assert message == (
        "m.toml: [identify] outputs names z, q, which no record measures (they measure v, r, psi); "
        "expected measured states, or no outputs to fit every measured state"
    )
    with pytest.raises(InputError, match="rv.csv: none of the fitted outputs"):
        replace(cfg, outputs=("psi",)).fitted([rv, vp])


def test_a_wrapped_angle_is_unwrapped_on_reading(tmp_path):
    """A heading (and a roll) logged within ±π reads as the continuous angle: each jump of more
    than π between rows is a wrap. The continuous record is the reference."""
    t = np.arange(400) * 0.05
    psi = 3.0 + 0.9 * t + 0.3 * np.sin(2.0 * t)  # through +π, then two more turns
    phi = -2.5 - 0.4 * t  # a slow roll through −π
    x = np.zeros((len(t), 10))
    x[:, STATES.index("psi")], x[:, STATES.index("phi")] = psi, phi
    wrapped = x.copy()
    for j in (STATES.index("psi"), STATES.index("phi")):
        wrapped[:, j] = np.angle(np.exp(1j * x[:, j]))  # (−π, π], as an AHRS logs it
    assert np.abs(np.diff(wrapped, axis=0)).max() > 6.0  # it does wrap
    e = read_csv(write_csv(tmp_path / "wrapped.csv", t, wrapped, np.zeros((len(t), 3))))
    np.testing.assert_allclose(e.y, x, rtol=0, atol=1e-8)  # the CSV's 10 digits
    theta = x.copy()
    theta[:, STATES.index("theta")] = wrapped[:, STATES.index("psi")]  # pitch is never unwrapped
    e = read_csv(write_csv(tmp_path / "theta.csv", t, theta, np.zeros((len(t), 3))))
    np.testing.assert_allclose(e.column("theta"), theta[:, STATES.index("theta")], rtol=0, atol=1e-8)


def test_an_angle_unwrapped_beyond_the_data_limit_is_refused(tmp_path):
    p = _csv(
        tmp_path, "t,psi,delta_r,delta_er,delta_el\n0,999999,0,0,0\n0.1,999995,0,0,0\n0.2,999995,0,0,0\n"
    )
    with pytest.raises(InputError) as exc:
        read_csv(p)
    assert str(exc.value) == (
        f"{p}: column 'psi' unwrapped (it jumps by more than π) reaches 1000001.283 at data row 2, "
        "beyond ±1e+06; expected a plausible SI value (m, m/s, rad, rad/s)"
    )


def _log(tmp_path, t, y, d, measured=("u", "r")):
    """A measurement CSV written row by row: NaN in `y` or `d` as an empty field."""

    def field(v):
        return "" if np.isnan(v) else repr(float(v))

    rows = [",".join(("t",) + tuple(measured) + INPUTS)]
    rows += [",".join(map(field, (tk, *yk, *dk))) for tk, yk, dk in zip(t, y, d)]
    return _csv(tmp_path, "\n".join(rows) + "\n")


def test_missing_state_samples_stay_missing_and_fins_are_held(tmp_path):
    t = np.arange(8) * 0.1
    y = np.column_stack([1.0 + t, -t])
    y[[2, 5], 0] = np.nan
    y[1::2, 1] = np.nan  # r at half the rate
    d = np.tile([0.1, 0.2, 0.3], (8, 1))
    d[3:5, 0] = np.nan
    d[6, 2] = np.nan
    e = read_csv(_log(tmp_path, t, y, d))
    np.testing.assert_array_equal(e.t, t)
    np.testing.assert_array_equal(np.isnan(e.y), np.isnan(y))
    np.testing.assert_array_equal(e.y[~np.isnan(y)], y[~np.isnan(y)])
    np.testing.assert_array_equal(e.inputs, np.tile([0.1, 0.2, 0.3], (8, 1)))  # held: the same


def test_nan_as_text_is_a_missing_sample(tmp_path):
    e = read_csv(_csv(tmp_path, "t,u,delta_r,delta_er,delta_el\n0,1,0,0,0\n0.1,NaN,0,0,0\n0.2,nan,0,0,0\n"))
    np.testing.assert_array_equal(np.isnan(e.y[:, 0]), [False, True, True])


def test_uniform_times_are_read_bit_for_bit(tmp_path):
    t = 0.02 * np.arange(50) + 1e-9 * np.random.default_rng(0).normal(size=50)  # within 1e-6 of Δ
    y, d = np.random.default_rng(1).normal(size=(50, 2)), np.zeros((50, 3))
    e = read_csv(_log(tmp_path, t, y, d))
    np.testing.assert_array_equal(e.t, t)
    np.testing.assert_array_equal(e.y, y)


def _rows_at(e, t):
    """The index of each stamp of `t` among the record's times (each within 1e-9 s of one)."""
    k = np.searchsorted(e.t, t - 1e-9)
    np.testing.assert_allclose(e.t[k], t, rtol=0, atol=1e-9)
    return k


def test_stamps_on_a_millisecond_clock_are_kept_exactly(tmp_path):
    """A 50 Hz log stamped in milliseconds with ±20 % jitter: the record's clock is 1 ms, every
    row sits at its own stamp, the other points have every state missing and the inputs of the
    row before them held; a repeated stamp's rows are merged (the mean of each state present,
    the last row's inputs)."""
    dt, n = 0.02, 40
    rng = np.random.default_rng(3)
    t = np.round(5.0 + dt * np.arange(n) + rng.uniform(-0.2, 0.2, n) * dt, 3)
    t[0] = 5.0
    y = np.column_stack([np.arange(n, dtype=float), 10.0 + np.arange(n)])
    d = np.column_stack([np.arange(n) * 0.01, np.zeros(n), np.zeros(n)])
    keep = np.ones(n, dtype=bool)
    keep[[7, 8, 20]] = False  # dropped rows
    rows_t, rows_y, rows_d = list(t[keep]), list(y[keep]), list(d[keep])
    at = list(np.flatnonzero(keep)).index(12)
    rows_t.insert(at + 1, rows_t[at])  # a repeated stamp: a second sample of row 12's instant
    rows_y.insert(at + 1, np.array([np.nan, 30.0]))
    rows_d.insert(at + 1, np.array([0.5, 0.0, 0.0]))
    e = read_csv(_log(tmp_path, np.array(rows_t), np.array(rows_y), np.array(rows_d)))
    np.testing.assert_allclose(np.diff(e.t), 0.001, rtol=0, atol=1e-12)
    assert abs(e.t[0] - 5.0) < 1e-9
    k = _rows_at(e, t[keep])
    want = y[keep]
    want[list(np.flatnonzero(keep)).index(12)] = [12.0, (22.0 + 30.0) / 2]
    np.testing.assert_array_equal(e.y[k], want)
    between = np.ones(len(e.t), dtype=bool)
    between[k] = False
    assert np.isnan(e.y[between]).all()
    fins = d[keep].copy()
    fins[list(np.flatnonzero(keep)).index(12), 0] = 0.5
    held = np.searchsorted(k, np.arange(len(e.t)), side="right") - 1  # the row each point holds
    np.testing.assert_array_equal(e.inputs, fins[held])


def test_alternating_stamps_keep_their_instants(tmp_path):
    """Rows 0.4 s and 0.6 s apart alternately are ticks of a 0.2 s clock: each row at its own
    stamp, a point without a row between them, never a row moved."""
    steps = np.tile([0.4, 0.6], 15)
    t = 2.0 + np.r_[0.0, np.cumsum(steps)]
    y = np.random.default_rng(2).normal(size=(len(t), 2))
    d = np.random.default_rng(3).normal(size=(len(t), 3)) * 0.1
    e = read_csv(_log(tmp_path, t, y, d))
    np.testing.assert_allclose(np.diff(e.t), 0.2, rtol=0, atol=1e-12)
    k = _rows_at(e, t)
    np.testing.assert_array_equal(e.y[k], y)
    assert np.isnan(np.delete(e.y, k, axis=0)).all()
    np.testing.assert_array_equal(e.inputs[k], d)
    np.testing.assert_array_equal(e.inputs[k[:-1] + 1], d[:-1])  # held until the next row


def test_stamps_with_no_clock_go_to_the_nearest_eighth_of_a_step(tmp_path):
    """Stamps jittered as floats share no clock: each row goes to the nearest point of the grid
    at an eighth of the median step (at most a sixteenth of a step from its stamp), a point of
    its own (the grid is the least-squares line through the stamps, which the median step alone
    would drift from by several samples over 3000 rows)."""
    n, dt = 3000, 0.02
    rng = np.random.default_rng(5)
    t = dt * np.arange(n) + rng.uniform(-0.2, 0.2, n) * dt
    y = rng.normal(size=(n, 2))
    e = read_csv(_log(tmp_path, t, y, np.zeros((n, 3))))
    present = np.flatnonzero(~np.isnan(e.y[:, 0]))
    assert len(present) == n
    np.testing.assert_array_equal(e.y[present], y)
    assert np.max(np.abs(e.t[present] - t)) <= dt / 16 * 1.01
    assert abs(np.median(np.diff(e.t)) - dt / 8) < 1e-3 * dt


@pytest.mark.parametrize("glitches", [2, 4])
def test_a_few_stamps_off_the_step_s_clock_go_to_its_nearest_ticks(tmp_path, glitches):
    """A 50 Hz log of 3000 rows stamped in milliseconds, rows dropped, `glitches` stamps a few
    ms off: up to one in a thousand rows (3) is a logger's glitch, read at its nearest tick of
    the 20 ms clock, every other row at its own stamp; more, and the clock is the 1 ms one that
    holds every stamp exactly, as for a jittered log."""
    n, dt = 3000, 0.02
    rng = np.random.default_rng(7)
    t = np.round(10.0 + dt * np.arange(n), 3)
    y = rng.normal(size=(n, 2))
    d = np.zeros((n, 3))
    odd = rng.choice(np.arange(100, n - 100), glitches, replace=False)
    stamps = t.copy()
    stamps[odd] += rng.choice([-0.007, 0.006], glitches)
    keep = np.ones(n, dtype=bool)
    keep[1000:1030] = False  # a dropout
    e = read_csv(_log(tmp_path, stamps[keep], y[keep], d[keep]))
    if glitches <= n // 1000:
        np.testing.assert_allclose(np.diff(e.t), dt, rtol=0, atol=1e-9)
        assert len(e.t) == n
        k = _rows_at(e, t[keep])  # the glitched rows at their true ticks, the others at their stamps
    else:
        np.testing.assert_allclose(np.diff(e.t), 0.001, rtol=0, atol=1e-9)
        k = _rows_at(e, stamps[keep])
    np.testing.assert_array_equal(e.y[k], y[keep])
    assert np.isnan(np.delete(e.y, k, axis=0)).all()


def test_a_stale_stamp_takes_the_free_point_after_it_and_a_row_logged_twice_counts_once(tmp_path):
    """A row stamped like the row before it, where the next grid point has no row, is that
    point's sample (the logger repeated a stale stamp); a row repeated whole is one row."""
    t = 0.1 * np.arange(10)
    y = np.column_stack([np.arange(10.0), 100 + np.arange(10.0)])
    d = np.zeros((10, 3))
    stamps = t.copy()
    stamps[4] = stamps[3]  # stale: the sample of t = 0.4 stamped 0.3
    rows = np.column_stack([stamps, y, d])
    rows = np.insert(rows, 7, rows[6], axis=0)  # row 6 logged twice
    e = read_csv(_log(tmp_path, rows[:, 0], rows[:, 1:3], rows[:, 3:]))
    assert len(e.t) == 10
    np.testing.assert_array_equal(e.y, y)
    assert abs(e.t[1] - e.t[0] - 0.1) < 1e-3


def test_a_4_dof_config_may_leave_out_the_pitch_constants(tmp_path):
    doc = _doc()
    del doc["vehicle"]["Iy"]
    config = parse_config(doc, "m.toml")
    assert config.vehicle.Iy is None and config.vehicle.omitted() == ("Iy",)
    assert "Iy" not in config_text(config)
    assert parse_config(tomllib.loads(config_text(config)), "again").vehicle == config.vehicle
    doc["vehicle"] |= {"GM": 0.05}
    del doc["vehicle"]["zB"]
    assert parse_config(doc, "m.toml").vehicle.omitted() == ("Iy", "zB")
    doc["vehicle"] |= {"GM_L": 1.5}
    assert parse_config(doc, "m.toml").vehicle.omitted() == ("Iy",)
    del doc["vehicle"]["GM"]
    with pytest.raises(InputError, match=r"m.toml: \[vehicle\] zB missing; expected a number \(SI\), or GM"):
        parse_config(doc, "m.toml")
    doc["vehicle"] |= {"zB": 0.0, "GM": float("nan")}
    with pytest.raises(InputError, match=r"\[vehicle\] GM = nan; expected a finite number"):
        parse_config(doc, "m.toml")


def test_an_estimates_json_gives_the_fixed_candidates_at_the_values_the_fit_held(tmp_path):
    """A screened fit's `fixed` candidates stayed at their a-priori values, which `--perturb`
    moves: the model an estimates JSON describes has them there, not at the config's values."""
    import json

    from testbed.data import read_estimates

    path = tmp_path / "e.json"
    doc = {
        "coefficients": {"Y_v": {"value": -2000.0, "std": 10.0}},
        "fixed": {"K_r": {"value": 3.1, "reason": "not determined"}, "Y_v": {"value": 7.0, "reason": "-"}},
    }
    path.write_text(json.dumps(doc))
    values, _ = read_estimates(path)
    assert values == {"K_r": 3.1, "Y_v": -2000.0}
    path.write_text(json.dumps(doc | {"fixed": {"K_r": {"reason": "no value"}}}))
    with pytest.raises(InputError, match="e.json"):
        read_estimates(path)
