"""The file readers and writers: round trips and one-line errors on bad input."""

import numpy as np
import pytest

from testbed.data import (
    CSV_COLUMNS,
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
from testbed.errors import InputError, atomic_directory
from testbed.model import COEFFICIENTS, STATES, Vehicle

VEHICLE = Vehicle(30.51, 0.177, 3.45, 3.45, 299.0, 306.0, 0.0, 0.0, -0.0196, 1.54)


def _csv(tmp_path, text, name="e.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_csv_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    t = np.arange(20) * 0.05
    x, d = rng.normal(size=(20, 10)), rng.normal(size=(20, 3))
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
        ("t,u,delta_r,delta_er,delta_el\n0,1,0,0,0\n0.1,nan,0,0,0\n0.2,1,0,0,0\n", "line 3, column 'u'"),
        ("t,u,delta_r,delta_er,delta_el\n0,1,0,0,0\n0.1,x,0,0,0\n0.2,1,0,0,0\n", "'x' is not a number"),
        (
            "t,u,delta_r,delta_er,delta_el\n0,1,0,0,0\n0.1,1,0,0,0\n0.3,1,0,0,0\n0.4,1,0,0,0\n",
            "not uniformly sampled",
        ),
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
    assert back.coefficients == coeffs
    assert "# surge damping" in config_text(cfg, {"X_u": "surge damping"})


def _doc(**changes):
    doc = {
        "vehicle": {k: getattr(VEHICLE, k) for k in Vehicle.names()},
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
    ],
)
def test_config_bad_input(changes, words):
    with pytest.raises(InputError, match=words):
        parse_config(_doc(**changes), "m.toml")


def test_config_missing_name_is_zero_and_fixed():
    cfg = parse_config(_doc(), "m.toml")
    assert cfg.coefficients["Y_v"] == 0.0 and set(cfg.coefficients) == set(COEFFICIENTS)


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
