"""A user's file is never replaced unless asked for: an existing file at any output path of any
command that writes one is refused before the work, in one line with status 2, and left byte for
byte as it was; `--force` replaces it, through a temporary sibling and a rename."""

from __future__ import annotations

import json
import os
import tomllib

import pytest

from test_bad_input import cli
from testbed.data import read_config, write_config, write_csv
from testbed.outputs import atomic_file, atomic_write_text
from testbed.errors import InputError
from testbed.jobs.analyze import analyze_data
from testbed.jobs.check import check_data
from testbed.jobs.identify import identify_data
from testbed.jobs.validate import validate_data
from testbed.simulation.runs import simulate

OLD = b"a user's file\n"
REFUSED = "exists; expected a new file name, or --force to replace it"


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    return simulate("II", seed=4, duration=6.0, out=tmp_path_factory.mktemp("r") / "II")


@pytest.fixture(scope="module")
def estimates(run, tmp_path_factory):
    path = tmp_path_factory.mktemp("e") / "estimates.json"
    identify_data([run], out=path, options={"max_iter": 1})
    return path


def _listing(folder):
    return sorted(os.listdir(folder))


def _rrd(path):
    return path.read_bytes()[:4] == b"RRF2"  # a Rerun recording's header


def _json(path):
    return isinstance(json.loads(path.read_text()), dict)


def _toml(path):
    return bool(tomllib.loads(path.read_text()))


# (command line with {user} the existing file and {new} a fresh name, the flag refused, the
# function whose call is the command's work, what a replaced file must read as)
CASES = {
    "analytic --out": (
        ["analytic", "--out", "{user}"],
        "--out",
        "testbed.simulation.analytic.analytic_config",
        _toml,
    ),
    "captive --out": (
        ["captive", "--out", "{user}"],
        "--out",
        "testbed.captive.config.captive_config",
        _toml,
    ),
    "captive --rrd": (
        ["captive", "--out", "{new}", "--rrd", "{user}"],
        "--rrd",
        "testbed.captive.config.captive_config",
        _rrd,
    ),
    "identify --out": (
        ["identify", "{run}", "--max-iter", "1", "--out", "{user}"],
        "--out",
        "testbed.jobs.identify.identify_screened",
        _json,
    ),
    "identify --rrd": (
        ["identify", "{run}", "--max-iter", "1", "--out", "{new}.json", "--rrd", "{user}"],
        "--rrd",
        "testbed.jobs.identify.identify_screened",
        _rrd,
    ),
    "identify history": (
        ["identify", "{run}", "--method", "mekf", "--out", "{user_stem}.json"],
        ".history.csv",
        "testbed.jobs.identify.identify_screened",
        lambda path: path.read_text().startswith("t,"),
    ),
    "analyze --out": (
        ["analyze", "{run}", "--out", "{user}"],
        "--out",
        "testbed.jobs.analyze.identifiability",
        _json,
    ),
    "check --out": (
        ["check", "{run}", "--out", "{user}"],
        "--out",
        "testbed.analysis.compatibility.compatibility",
        _json,
    ),
    "validate --out": (
        ["validate", "{run}", "--estimates", "{estimates}", "--out", "{user}"],
        "--out",
        "testbed.jobs.validate.validate",
        _json,
    ),
    "design --out": (
        ["design", "--duration", "40", "--free", "Y_v,N_r", "--out", "{user}"],
        "--out",
        "testbed.presentation.design_report.design",
        _toml,
    ),
    "design --rrd": (
        ["design", "--duration", "40", "--free", "Y_v,N_r", "--out", "{new}.toml", "--rrd", "{user}"],
        "--rrd",
        "testbed.presentation.design_report.design",
        _rrd,
    ),
}
# a design takes ~12 s of one core, the captive reference with its recording ~10 s
FAST = [k for k in CASES if not k.startswith("design") and k != "captive --rrd"]


def _argv(case, run, estimates, folder):
    """The case's command line, and the user's file it names (made, holding OLD)."""
    user = folder / ("mine.history.csv" if case == "identify history" else "mine")
    user.write_bytes(OLD)
    names = {
        "user": user,
        "user_stem": folder / "mine",
        "new": folder / "new",
        "run": run,
        "estimates": estimates,
    }
    return [a.format(**{k: str(v) for k, v in names.items()}) for a in CASES[case][0]], user


def _no_work(monkeypatch, target):
    def started(*args, **kwargs):
        raise AssertionError(f"{target} ran: the output was checked after the work started")

    monkeypatch.setattr(target, started)


@pytest.mark.parametrize("case", list(CASES))
def test_an_existing_file_is_refused_before_the_work_and_left_as_it_was(
    case, run, estimates, tmp_path, capsys, monkeypatch
):
    argv, user = _argv(case, run, estimates, tmp_path)
    _no_work(monkeypatch, CASES[case][2])
    code, out, err = cli(capsys, *argv)
    assert code == 2 and err.count("\n") == 1 and out == "", err
    assert f"{CASES[case][1]} '{user}': {REFUSED}" in err or (
        case == "identify history" and f"'{user}': {REFUSED}" in err
    ), err
    assert user.read_bytes() == OLD and _listing(tmp_path) == [user.name]  # nothing else written


def test_a_symbolic_link_to_a_file_is_refused_like_the_file(tmp_path, capsys, monkeypatch):
    target = tmp_path / "mine.toml"
    target.write_bytes(OLD)
    link = tmp_path / "link.toml"
    link.symlink_to(target.name)
    _no_work(monkeypatch, CASES["analytic --out"][2])
    code, _, err = cli(capsys, "analytic", "--out", link)
    assert code == 2 and err.count("\n") == 1 and f"--out '{link}': {REFUSED}" in err, err
    assert (
        link.is_symlink() and target.read_bytes() == OLD and _listing(tmp_path) == ["link.toml", "mine.toml"]
    )


def _replaced(case, run, estimates, tmp_path, capsys):
    argv, user = _argv(case, run, estimates, tmp_path)
    code, _, err = cli(capsys, *argv, "--force")
    assert code in (0, 1), err
    assert user.read_bytes() != OLD and CASES[case][3](user)
    assert not [n for n in _listing(tmp_path) if n.startswith(".")]  # no temporary left


@pytest.mark.parametrize("case", FAST)
def test_force_replaces_an_existing_file(case, run, estimates, tmp_path, capsys):
    _replaced(case, run, estimates, tmp_path, capsys)


@pytest.mark.slow
@pytest.mark.parametrize("case", [k for k in CASES if k not in FAST])
def test_slow_commands_force_replaces_an_existing_file(case, run, estimates, tmp_path, capsys):
    _replaced(case, run, estimates, tmp_path, capsys)


def test_force_through_a_symbolic_link_replaces_its_target(tmp_path, capsys):
    target = tmp_path / "mine.toml"
    target.write_bytes(OLD)
    link = tmp_path / "link.toml"
    link.symlink_to(target.name)
    code, _, err = cli(capsys, "analytic", "--out", link, "--force")
    assert code == 0, err
    assert link.is_symlink() and _toml(target) and _listing(tmp_path) == ["link.toml", "mine.toml"]


def test_force_does_not_make_an_input_an_output(run, tmp_path, capsys):
    before = (run / "model.toml").read_bytes()
    code, _, err = cli(capsys, "analyze", run, "--out", run / "model.toml", "--force")
    assert code == 2 and err.count("\n") == 1 and "is the input" in err, err
    assert (run / "model.toml").read_bytes() == before


def test_an_input_named_as_the_output_is_blamed_as_the_input_first(run, capsys):
    code, _, err = cli(capsys, "analyze", run, "--out", run / "model.toml")
    assert code == 2 and "is the input" in err and "exists" not in err, err


# -- the library ---------------------------------------------------------------------------------


def test_library_writers_refuse_an_existing_file_unless_force(run, estimates, tmp_path):
    user = tmp_path / "mine"
    user.write_bytes(OLD)
    config = read_config(run / "model.toml")
    writers = {
        "atomic_write_text": lambda **k: atomic_write_text(user, "new\n", **k),
        "write_config": lambda **k: write_config(user, config, **k),
        "write_csv": lambda **k: write_csv(user, [0.0, 0.1], [[0.0] * 10] * 2, [[0.0] * 3] * 2, **k),
        "analyze_data": lambda **k: analyze_data([run], out=user, **k),
        "check_data": lambda **k: check_data([run], out=user, **k),
        "validate_data": lambda **k: validate_data([run], estimates, out=user, **k),
    }
    for name, write in writers.items():
        with pytest.raises(InputError, match="exists; expected a new file name, or force=True") as exc:
            write()
        assert "\n" not in str(exc.value), name
        assert user.read_bytes() == OLD and _listing(tmp_path) == ["mine"], name
        write(force=True)
        assert user.read_bytes() != OLD, name
        user.write_bytes(OLD)


def test_a_file_made_while_the_output_was_written_is_not_replaced(tmp_path):
    path = tmp_path / "out.json"
    with pytest.raises(InputError, match="out.json: exists"):
        with atomic_file(path) as tmp:
            tmp.write_text("new\n")
            path.write_bytes(OLD)  # another process took the name meanwhile
    assert path.read_bytes() == OLD and _listing(tmp_path) == ["out.json"]
