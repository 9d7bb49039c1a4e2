"""Property-based tests (hypothesis) of every reader and of the command line.

Generated measurement CSVs, model-config TOMLs and run manifests: valid ones with random values,
and malformed ones (a valid one broken by one to three mutations). The properties:

- a reader returns exactly what a valid file holds (a roll or heading that wraps at ±π made
  continuous; a file it wrote reads back the same), or raises `InputError` with one line
  naming the file; no other exception, ever;
- the command line, given such files and random arguments, exits 0, 1 or 2 and never prints a
  traceback; on 2 it prints exactly one stderr line naming a file, flag or value and writes
  nothing; it never changes an input.

The `fast` profile (tests/conftest.py) bounds the examples; `-m slow` runs each property again
with many more, as does `HYPOTHESIS_PROFILE=slow` for the whole run.
"""

import copy
import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from studies.fuzz import (
    CSV_MUTATIONS,
    TOML_BAD_VALUES,
    Case,
    apply_csv_mutation,
    run_case,
    toml_text,
    workspace,
)

from testbed.data import (
    CSV_COLUMNS,
    MAX_DATA,
    MIN_NOISE_STD,
    WRAPPING,
    ModelConfig,
    check_experiment,
    csv_text,
    parse_config,
    read_config,
    read_csv,
    run_csvs,
    write_config,
)
from testbed.errors import InputError
from testbed.estimators import METHODS
from testbed.models.linear import COEFFICIENTS, INPUTS, STATES, Vehicle

pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")  # a numpy warning is a failure
PROFILES = ["suite", pytest.param("slow", marks=pytest.mark.slow)]


def run_property(make, profile):
    """Build the @given test with `make()` and run it under the loaded profile, or `slow`."""
    test = make()
    if profile == "slow":
        test = settings(settings.get_profile("slow"))(test)
    test()


def one_line(exc: InputError, name: str):
    text = str(exc)
    assert "\n" not in text and name in text, text


# -- measurement CSV -----------------------------------------------------------------------------

FINITE = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)
LARGE = st.one_of(FINITE, st.floats(-MAX_DATA, MAX_DATA), st.sampled_from([MAX_DATA, -MAX_DATA, 5e-324, 0.0]))
CELL = st.text(
    st.characters(codec="utf-8", exclude_characters=',"\r\n', exclude_categories=("Cc", "Cs")), max_size=8
)
EXTRA = CELL.filter(lambda c: c.strip() not in CSV_COLUMNS)


@st.composite
def measurement(draw, values=FINITE):
    """(CSV bytes, t, measured, y, inputs): a valid measurement CSV and what it holds."""
    chosen = draw(st.sets(st.sampled_from(STATES), min_size=1))
    measured = tuple(s for s in STATES if s in chosen)
    n = draw(st.integers(3, 25))
    dt = draw(st.sampled_from([0.01, 0.02, 0.05, 0.1, 1.0]))
    t = draw(st.floats(0, 1e3)) + dt * np.arange(n)
    y = np.array(
        draw(
            st.lists(st.lists(values, min_size=len(measured), max_size=len(measured)), min_size=n, max_size=n)
        )
    )
    u = np.array(draw(st.lists(st.lists(values, min_size=3, max_size=3), min_size=n, max_size=n)))
    extras = draw(st.lists(EXTRA, max_size=2))
    header = draw(st.permutations(["t", *measured, *INPUTS, *(f"\x00{k}" for k in range(len(extras)))]))
    cells = {"t": t, **dict(zip(measured, y.T)), **dict(zip(INPUTS, u.T))}
    lines = [",".join(extras[int(h[1:])] if h[0] == "\x00" else h for h in header)]
    for k in range(n):
        lines.append(",".join(draw(CELL) if h[0] == "\x00" else repr(float(cells[h][k])) for h in header))
    end = draw(st.sampled_from(["\n", "\r\n"]))
    text = draw(st.sampled_from(["", "\ufeff"])) + end.join(lines) + end * draw(st.integers(0, 2))
    return text.encode(), t, measured, y, u


def _file(folder: Path, name: str, data: bytes) -> Path:
    path = folder / name
    path.write_bytes(data)
    return path


MUTATIONS = sorted(CSV_MUTATIONS)


@st.composite
def csv_mutations(draw):
    """One to three (mutation, position) pairs of `studies.fuzz.CSV_MUTATIONS`."""
    return tuple(
        draw(st.tuples(st.sampled_from(MUTATIONS), st.integers(0, 2**20)))
        for _ in range(draw(st.integers(1, 3)))
    )


def mutate_csv(data: bytes, mutations, junk: bytes = b"", at: int = 0) -> bytes:
    for name, where in mutations:
        data = apply_csv_mutation(data, name, where)
    k = at % (len(data) + 1)
    return data[:k] + junk + data[k:]


def assert_unwrapped(read: np.ndarray, raw: np.ndarray):
    """`read` is the angle `raw` made continuous: the same first value, whole turns added, no
    jump of more than π left (up to the rounding of the sums)."""
    ulp = 1e-12 * max(1.0, float(np.abs(read).max()))
    turns = (read - raw) / (2 * np.pi)
    assert read[0] == raw[0] and np.all(np.abs(turns - np.round(turns)) < ulp)
    assert np.all(np.abs(np.diff(read)) <= np.pi + ulp)


@pytest.mark.parametrize("profile", PROFILES)
def test_a_valid_csv_reads_back_exactly_and_round_trips(tmp_path, profile):
    def make():
        @given(measurement())
        def check(case):
            data, t, measured, y, u = case
            path = _file(tmp_path, "e.csv", data)
            e = read_csv(path, keep_repeats=True)  # drawn values repeat: read as written, not as stale
            assert e.measured == measured and e.name == "e"
            np.testing.assert_array_equal(e.t, t)
            np.testing.assert_array_equal(e.inputs, u)
            for j, name in enumerate(measured):
                if name in WRAPPING and np.any(np.abs(np.diff(y[:, j])) > np.pi):
                    assert_unwrapped(e.y[:, j], y[:, j])
                else:  # every other column exactly as written
                    np.testing.assert_array_equal(e.y[:, j], y[:, j])
            again = read_csv(
                _file(tmp_path, "w.csv", csv_text(e.t, e.y, e.inputs, e.measured).encode()), keep_repeats=True
            )
            assert again.measured == measured
            np.testing.assert_allclose(again.y, e.y, rtol=1e-9, atol=1e-300)
            assert path.read_bytes() == data  # the reader leaves its input alone

        return check

    run_property(make, profile)


@pytest.mark.parametrize("profile", PROFILES)
def test_a_malformed_csv_is_read_or_refused_in_one_line(tmp_path, profile):
    def make():
        @given(measurement(), csv_mutations(), st.binary(max_size=12), st.integers(0, 2**20))
        def check(case, mutations, junk, at):
            text = mutate_csv(case[0], mutations, junk, at)
            path = _file(tmp_path, "bad.csv", text)
            try:
                e = read_csv(path)
            except InputError as exc:
                one_line(exc, "bad.csv")
            else:  # what was read is a usable record
                check_experiment(e)  # a missing sample (NaN) is allowed; none beyond MAX_DATA
                assert not np.any(np.abs(e.y) > MAX_DATA) and e.inputs.shape == (len(e.t), 3)
            assert path.read_bytes() == text

        return check

    run_property(make, profile)


# -- model config --------------------------------------------------------------------------------

POSITIVE = st.floats(1e-2, 1e5)
NOISE = st.one_of(st.floats(MIN_NOISE_STD, MAX_DATA), st.sampled_from([MIN_NOISE_STD, MAX_DATA, 1]))


@st.composite
def config_doc(draw):
    """A valid model-config document (ints and floats as TOML would give them)."""
    number = lambda s: st.one_of(s, s.map(round).filter(lambda v: v != 0))  # noqa: E731
    vehicle = {k: draw(number(POSITIVE)) for k in ("mass", "Ix", "Iy", "Iz", "weight", "buoyancy")}
    vehicle |= {k: draw(number(st.floats(-10, 10))) for k in ("xB", "yB", "zB")}
    vehicle["speed"] = draw(st.floats(1e-3, 100))
    coefficients = draw(st.dictionaries(st.sampled_from(COEFFICIENTS), number(st.floats(-1e6, 1e6))))
    doc = {"vehicle": vehicle, "coefficients": coefficients}
    if draw(st.booleans()):
        doc["identify"] = {"free": draw(st.lists(st.sampled_from(COEFFICIENTS), unique=True))}
        if draw(st.booleans()):
            doc["identify"]["noise_std"] = draw(st.dictionaries(st.sampled_from(STATES), NOISE))
    return doc


@st.composite
def bad_config_doc(draw):
    """A valid document broken by one to three mutations of its tables, keys or values."""
    doc = json.loads(json.dumps(draw(config_doc())))
    doc.setdefault("identify", {"free": []})
    for _ in range(draw(st.integers(1, 3))):
        table = draw(st.sampled_from(["vehicle", "coefficients", "identify", None]))
        if table is None:
            doc[draw(st.sampled_from(["vehicle", "coefficients", "identify", "extra"]))] = copy.deepcopy(
                draw(st.sampled_from(TOML_BAD_VALUES))
            )  # a fresh {} each time: mutated below
            continue
        if not isinstance(doc.get(table), dict):
            continue
        keys = list(doc[table]) + ["colour", "X_uu", "free", "mass", "noise_std"]
        key = draw(st.sampled_from(keys))
        if draw(st.booleans()) and key in doc[table]:
            del doc[table][key]
        else:
            bad = [["X_u", "X_u"], ["Y_nope"], [1], {"r": -1.0}, {"yaw": 0.1}, {"psi": "0.1"}]
            doc[table][key] = copy.deepcopy(draw(st.sampled_from(TOML_BAD_VALUES + bad)))
    return doc


def _expected(doc) -> ModelConfig:
    noise = doc.get("identify", {}).get("noise_std")
    return ModelConfig(
        Vehicle(**{k: float(v) for k, v in doc["vehicle"].items()}),
        {n: float(doc["coefficients"].get(n, 0.0)) for n in COEFFICIENTS},
        tuple(doc.get("identify", {}).get("free", ())),
        noise_std={s: float(noise[s]) for s in STATES if s in noise} if noise else None,
    )


@pytest.mark.parametrize("profile", PROFILES)
def test_a_valid_config_reads_back_exactly_and_round_trips(tmp_path, profile):
    def make():
        @given(config_doc())
        def check(doc):
            text = toml_text(doc).encode()
            path = _file(tmp_path, "m.toml", text)
            cfg = read_config(path)
            want = _expected(doc)
            assert (cfg.vehicle, dict(cfg.coefficients), cfg.free, cfg.noise_std) == (
                want.vehicle,
                want.coefficients,
                want.free,
                want.noise_std,
            )
            back = read_config(
                write_config(tmp_path / "w.toml", cfg, force=True)
            )  # the last example's replaced
            assert (back.vehicle, dict(back.coefficients), back.free, back.noise_std) == (
                cfg.vehicle,
                dict(cfg.coefficients),
                cfg.free,
                cfg.noise_std,
            )
            assert path.read_bytes() == text

        return check

    run_property(make, profile)


@pytest.mark.parametrize("profile", PROFILES)
def test_a_malformed_config_is_read_or_refused_in_one_line(tmp_path, profile):
    def make():
        @given(bad_config_doc(), st.data())
        def check(doc, data):
            text = toml_text(doc).encode()
            if data.draw(st.booleans()):  # and sometimes the text itself broken
                cut = data.draw(st.integers(0, len(text)))
                junk = [b"", b"\xff\xfe", b"[", b"= =", b"\x00", b"a = [" * 3000, b"\n[vehicle]\n"]
                text = text[:cut] + data.draw(st.sampled_from(junk)) + text[cut:]
            path = _file(tmp_path, "bad.toml", text)
            try:
                cfg = read_config(path)
            except InputError as exc:
                one_line(exc, "bad.toml")
            else:
                assert all(math.isfinite(v) for v in cfg.coefficients.values())
                assert cfg.vehicle.speed >= 1e-3 and cfg.vehicle.mass > 0
                noise = cfg.noise_std or {}
                assert set(noise) <= set(STATES) and all(
                    MIN_NOISE_STD <= v <= MAX_DATA for v in noise.values()
                )
            assert path.read_bytes() == text

        return check

    run_property(make, profile)


def test_parse_config_refuses_python_values_in_one_line():
    for bad in TOML_BAD_VALUES:
        doc = {"vehicle": {"mass": bad}, "coefficients": {}}
        with pytest.raises(InputError) as exc:
            parse_config(doc, "m.toml")
        one_line(exc.value, "m.toml")


# -- run manifest --------------------------------------------------------------------------------

MANIFEST_VALUES = st.one_of(
    st.lists(st.sampled_from(["horizontal", "vertical"]), min_size=1, max_size=2, unique=True),
    st.lists(
        st.sampled_from(
            [
                "horizontal",
                "vertical",
                "",
                ".",
                "..",
                "../x",
                "a/b",
                "a\\b",
                "n\x00l",
                "missing",
                "horizontal.truth",
            ]
        ),
        max_size=3,
    ),
    st.sampled_from(TOML_BAD_VALUES),
    st.integers(),
    st.text(max_size=5),
    st.none(),
)


@st.composite
def manifest_text(draw):
    """The bytes of a manifest.json: valid or broken JSON, an experiments list or anything."""
    shape = draw(st.sampled_from(["doc", "list", "no key", "text", "deep"]))
    if shape == "text":
        return draw(st.binary(max_size=30))
    if shape == "deep":
        return b"[" * draw(st.integers(1, 100_000)) + b"]"
    value = draw(MANIFEST_VALUES)
    doc = {"doc": {"scenario": "II", "experiments": value}, "list": [value], "no key": {"seed": value}}[shape]
    return json.dumps(doc, allow_nan=True).encode()


@pytest.mark.parametrize("profile", PROFILES)
def test_a_manifest_lists_the_run_or_is_refused_in_one_line(tmp_path, profile):
    run = tmp_path / "run"
    run.mkdir()
    rows = "t,u,delta_r,delta_er,delta_el\n0,1,0,0,0\n0.1,1,0,0,0\n0.2,1,0,0,0\n"
    for name in ("horizontal", "vertical", "horizontal.truth"):
        (run / f"{name}.csv").write_text(rows)
    (tmp_path / "x.csv").write_text(rows)

    def make():
        @given(manifest_text())
        def check(text):
            (run / "manifest.json").write_bytes(text)
            try:
                files = run_csvs(run)
            except InputError as exc:
                one_line(exc, "run")
            else:
                assert files and all(f.parent == run and f.is_file() for f in files)
                assert len(set(files)) == len(files)

        return check

    run_property(make, profile)


# -- the command line ----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def ws(tmp_path_factory):
    """A workspace of valid inputs (`studies.fuzz.workspace`), made once."""
    return workspace(tmp_path_factory.mktemp("ws"))


NUMBERS = st.sampled_from(["0", "-1", "1e400", "nan", "inf", "-inf", "x", "", "1e-300", "0.5", "2", "1e300"])
OUTS = st.sampled_from(
    [
        "out/e.json",
        "out/e.json",
        "-",
        "out",
        "out/no/e.json",
        "data/h.csv",
        "cfg.toml",
        "keep.txt/e.json",
        "keep.txt",
        "link.txt",
        "run/model.toml",
        "run/e.json",
        "null",
    ]
)


NOISE_FLAGS = ["r=0.002", "u=0.05,psi=1e-9", "psi=1e6", "r=-1", "yaw=1", "r", "", "r=nan", "r=1,r=2", ","]


@st.composite
def command_line(draw) -> Case:
    """One `testbed` command over the workspace (`studies.fuzz.workspace`), valid or not, with
    the files it may name: bad.csv (a workspace CSV mutated), random.csv (a valid CSV of random
    values), bad.toml, run's manifest."""
    command = draw(st.sampled_from(["identify", "identify", "identify", "analyze", "analytic", "simulate"]))
    maybe = lambda flag, values: [flag, draw(values)] if draw(st.booleans()) else []  # noqa: E731
    files = []
    if command in ("identify", "analyze"):
        data = draw(
            st.lists(
                st.sampled_from(
                    [
                        "run",
                        "data/h.csv",
                        "data/v.csv",
                        "bad.csv",
                        "random.csv",
                        "missing.csv",
                        "data",
                        "/dev/null",
                        "cfg.toml",
                    ]
                ),
                min_size=1,
                max_size=2,
            )
        )
        argv = [command, *data]
        argv += maybe(
            "--config", st.sampled_from(["cfg.toml", "cfg.toml", "bad.toml", "missing.toml", "data"])
        )
        argv += maybe("--out", OUTS)
        argv += maybe("--noise-std", st.sampled_from(NOISE_FLAGS))
        if command == "identify":
            method = draw(st.sampled_from(["ml-gn", "ml-gn", "mekf", "ml-nr", "ml-nm", "ekf", "nope"]))
            argv += ["--method", method]
            iters = st.one_of(st.integers(-2, 3).map(str), NUMBERS)
            argv += (
                ["--max-iter", draw(iters)] if method in ("ml-nr", "ml-nm") else maybe("--max-iter", iters)
            )
            argv += maybe("--start", st.sampled_from(["auto", "config", "equation-error", "mekf", "nope"]))
            argv += maybe("--perturb", st.one_of(NUMBERS, st.sampled_from(["0.1", "0.3"])))
            argv += maybe("--seed", st.one_of(NUMBERS, st.integers(-3, 2**70).map(str)))
            argv += maybe("--rrd", st.sampled_from(["out/f.rrd", "out", "-", "out/e.json", "data/h.csv"]))
        if "random.csv" in data:  # valid, with values anywhere in the plausible range
            files.append(("random.csv", draw(measurement(LARGE))[0]))
        if "bad.csv" in data:
            files.append(
                ("bad.csv", (draw(st.sampled_from(["data/h.csv", "data/v.csv"])), draw(csv_mutations())))
            )
        if "run" in data and draw(st.booleans()):
            files.append(("run/manifest.json", draw(manifest_text())))
        if "bad.toml" in argv:
            files.append(("bad.toml", toml_text(draw(bad_config_doc())).encode()))
    elif command == "analytic":
        argv = [
            "analytic",
            *maybe("--mjcf", st.sampled_from(["data", "missing.xml", "cfg.toml", "/dev/null"])),
        ]
        argv += maybe("--speed", st.one_of(NUMBERS, st.sampled_from(["20", "0.0005", "451"])))
        argv += maybe("--out", OUTS)
    else:
        argv = ["simulate", "--quiet", "--scenario", draw(st.sampled_from(["I", "II", "turn", "nope"]))]
        argv += ["--duration", draw(st.sampled_from(["0.06", "0.001", "0.02", "-1", "nan", "1e300", "x"]))]
        argv += maybe("--seed", st.one_of(NUMBERS, st.integers(-3, 5).map(str)))
        argv += maybe("--speed", st.one_of(NUMBERS, st.sampled_from(["20", "0.0005", "451"])))
        argv += maybe("--mjcf", st.sampled_from(["data", "missing.xml", "cfg.toml"]))
        argv += [
            "--out",
            draw(
                st.sampled_from(["out/run", "out/a/b", "out", "keep.txt", "keep.txt/run", "-", "data", "run"])
            ),
        ]
    argv += ["--force"] if draw(st.booleans()) else []  # a file or run directory there replaced
    return Case(" ".join(argv), tuple(argv), tuple(files))


def commands_behave(ws, cases, profile, reaches_the_fit=False):
    """Run each command line drawn from `cases` on a fresh copy of the workspace
    (`studies.fuzz.run_case`: fd-level capture, numpy warnings as errors) and require no crash
    (a traceback, a status other than 0, 1 or 2, or a status 2 without exactly one stderr line
    naming a file, flag or value) and no partial output (anything written on failure, or an
    input changed). `reaches_the_fit`: the options drawn are the method's own, so none is
    refused as an option the method does not have."""

    def make():
        @given(cases)
        def check(case):
            o = run_case(ws, case)
            assert o.kind != "crash", (case.argv, o.code, o.err[-2000:])
            assert not o.partial, (case.argv, o.code, o.partial, o.err[-500:])
            if reaches_the_fit:
                assert "expected one of the options of" not in o.err, (case.argv, o.err)

        return check

    run_property(make, profile)


@pytest.mark.parametrize("profile", PROFILES)
def test_the_command_line_exits_0_1_or_2_in_one_line_and_writes_nothing_on_failure(ws, profile):
    commands_behave(ws, command_line(), profile)


@st.composite
def fit_on_random_data(draw) -> Case:
    """identify (every registered method) or analyze on a valid CSV of random values (anywhere
    in the plausible range, at any sampling step), alone or beside a workspace experiment, with
    the workspace config. Each method is given only the options its capabilities say it has:
    an iterative method at most 3 iterations; a filter, sometimes, a sample limit."""
    method = draw(st.sampled_from([*sorted(METHODS), None]))
    data = ["random.csv"] + draw(st.sampled_from([[], ["data/h.csv"]]))
    if method is None:
        argv = ["analyze", *data]
    else:
        argv = ["identify", *data, "--method", method]
        if METHODS[method].iterative:
            argv += ["--max-iter", "3"]
        if METHODS[method].online and draw(st.booleans()):
            argv += ["--max-samples", str(draw(st.integers(1, 30)))]
    argv += ["--config", "cfg.toml", "--out", "out/e.json"]
    return Case(" ".join(argv), tuple(argv), (("random.csv", draw(measurement(LARGE))[0]),))


@pytest.mark.parametrize("profile", PROFILES)
def test_fits_on_random_valid_data_end_in_0_1_or_2(ws, profile):
    commands_behave(ws, fit_on_random_data(), profile, reaches_the_fit=True)


def test_every_method_takes_the_options_it_is_drawn_with():
    """The draws above name only options a method has: its options accept them."""
    for name, method in METHODS.items():
        given = {"max_iter": 3} if method.iterative else {}
        given |= {"max_samples": 30} if method.online else {}
        options = method.options.build(name, {}, **given)
        assert all(getattr(options, k) == v for k, v in given.items()), name
