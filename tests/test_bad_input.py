"""Bad input never crashes, never clobbers, never wastes the user's time.

Each case is a file or an argument a user can give: the command line must answer with exit
status 0, 1 or 2, and on 2 with exactly one stderr line naming the file, field or value, having
written nothing, before any long work. Numpy's warnings are errors here, so one that would reach
the user as an extra stderr line fails the test (as an internal error, exit status 70).
"""

import csv
import json
import os
import shutil
import stat
import threading
import time
from dataclasses import replace

import numpy as np
import pytest

import testbed.estimators
from testbed.analysis.identifiability import identifiability
from testbed.analysis.screening import structurally_unidentified
from testbed.cli import main
from testbed.data import ModelConfig, config_text, csv_text, load_data, read_config, read_csv, write_config
from testbed.outputs import atomic_file
from testbed.errors import InputError
from testbed.estimators import Estimate, Status, identify
from testbed.models.linear import COEFFICIENTS
from testbed.simulation.measurements import noise_from_data
from testbed.simulation.runs import simulate
from testbed.simulation.scenario import SCENARIO_DIR

pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")  # numpy's floating-point warnings


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    return simulate("II", seed=4, duration=6.0, out=tmp_path_factory.mktemp("r") / "II")


def cli(capsys, *argv):
    """(exit status, stdout, stderr) of `testbed argv` run in this process."""
    try:
        code = main([str(a) for a in argv])
    except SystemExit as exc:  # argparse's own errors
        code = exc.code
    out = capsys.readouterr()
    return code, out.out, out.err


def refused(capsys, *argv, words=()):
    """Run `testbed argv`, which must fail with one line naming each of `words`; returns it."""
    code, _, err = cli(capsys, *argv)
    assert code == 2 and err.count("\n") == 1, err
    for w in words:
        assert str(w) in err, err
    return err


def _rows(run, name="horizontal.csv"):
    with (run / name).open() as f:
        return list(csv.reader(f))


def _write(path, rows, encoding="utf-8"):
    path.write_bytes(("\n".join(",".join(r) for r in rows) + "\n").encode(encoding))
    return path


def _listing(folder):
    return sorted(p.name for p in folder.iterdir())


def _config(run, tmp_path, name="c.toml", free=None, **changes):
    cfg = read_config(run / "model.toml")
    text = config_text(replace(cfg, free=tuple(free)) if free is not None else cfg)
    for old, new in changes.items():
        text = text.replace(old, new)
    path = tmp_path / name
    path.write_text(text)
    return path


# -- the measurement CSV -------------------------------------------------------------------------


def test_a_cell_beyond_the_csv_field_limit_is_one_line(run, tmp_path, capsys):
    rows = _rows(run)
    rows[5][1] = "1" * 140_000
    data = _write(tmp_path / "long.csv", rows)
    with pytest.raises(InputError, match=r"long.csv: line 6: field larger than field limit"):
        read_csv(data)
    refused(
        capsys,
        "identify",
        data,
        "--config",
        run / "model.toml",
        "--out",
        tmp_path / "e.json",
        words=["long.csv", "line 6"],
    )
    assert _listing(tmp_path) == ["long.csv"]


@pytest.mark.parametrize(
    "command", [["identify", "--method", "ml-gn"], ["identify", "--method", "mekf"], ["analyze"]]
)
def test_a_cell_of_1e300_is_blamed_on_its_line_and_column(run, tmp_path, capsys, command):
    rows = _rows(run)
    rows[7][rows[0].index("q")] = "1e300"
    data = _write(tmp_path / "big.csv", rows)
    refused(
        capsys,
        command[0],
        data,
        *command[1:],
        "--config",
        run / "model.toml",
        "--out",
        tmp_path / "e.json",
        words=["big.csv", "line 8", "column 'q'", "1e300"],
    )
    assert _listing(tmp_path) == ["big.csv"]


def test_every_state_times_1e300_is_blamed_on_the_data(run, tmp_path, capsys):
    rows = _rows(run)
    for row in rows[1:]:
        for j in range(1, 11):
            row[j] = repr(float(row[j]) * 1e300)
    data = _write(tmp_path / "huge.csv", rows)
    refused(
        capsys,
        "identify",
        data,
        "--config",
        run / "model.toml",
        "--out",
        tmp_path / "e.json",
        words=["huge.csv", "line 2", "column 'u'"],
    )
    # the same records made in Python: the library refuses them too, before any fit
    e = read_csv(run / "horizontal.csv")
    with pytest.raises(InputError, match="beyond"):
        identify([replace(e, y=e.y * 1e300)], read_config(run / "model.toml"))


def test_inputs_of_1e300_and_a_200_s_step_blame_the_data_not_the_config(run, tmp_path, capsys):
    rows = _rows(run)
    rows[4][rows[0].index("delta_r")] = "1e300"
    data = _write(tmp_path / "fins.csv", rows)
    err = refused(
        capsys,
        "identify",
        data,
        "--config",
        run / "model.toml",
        "--start",
        "config",
        words=["fins.csv", "line 5", "column 'delta_r'"],
    )
    assert "model.toml" not in err
    rows = _rows(run)
    for k, row in enumerate(rows[1:]):
        row[0] = str(200 * k)
    data = _write(tmp_path / "slow.csv", rows)
    for argv in (["identify", "--start", "config"], ["identify", "--method", "mekf"], ["analyze"]):
        err = refused(
            capsys,
            argv[0],
            data,
            *argv[1:],
            "--config",
            run / "model.toml",
            words=["slow.csv", "t steps 200 s", "(t in seconds)"],
        )
        assert "diverge" not in err


def test_a_utf8_byte_order_mark_is_read(run, tmp_path):
    rows = _rows(run)
    rows[0][0] = "\ufeff" + rows[0][0]
    e = read_csv(_write(tmp_path / "bom.csv", rows))
    ref = read_csv(run / "horizontal.csv")
    np.testing.assert_array_equal(e.t, ref.t)
    np.testing.assert_array_equal(e.y, ref.y)


def test_a_latin1_name_of_an_extra_column_is_ignored(run, tmp_path):
    rows = [r + ["1"] for r in _rows(run)]
    rows[0][-1] = "température"
    e = read_csv(_write(tmp_path / "latin1.csv", rows, encoding="latin-1"))
    np.testing.assert_array_equal(e.y, read_csv(run / "horizontal.csv").y)


def test_a_device_or_folder_as_data_is_refused_without_reading_it(tmp_path, capsys):
    refused(
        capsys,
        "identify",
        "/dev/zero",
        "--config",
        tmp_path / "c.toml",
        words=["/dev/zero", "not a regular file"],
    )
    with pytest.raises(InputError, match="is a folder; expected a model config"):
        read_config(tmp_path)


# -- the model config ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    "line, new, words",
    [
        ("speed = 20.0", "speed = 1e-6", "speed = 1e-06; expected 0.001 to 450"),
        ("speed = 20.0", "speed = 1e6", "speed = 1e+06; expected 0.001 to 450"),
        ("weight = ", "weight = -", "weight = -1675.09; expected > 0"),
    ],
)
def test_an_impossible_vehicle_is_refused(run, tmp_path, capsys, line, new, words):
    config = _config(run, tmp_path, **{line: new})
    for argv in (["identify", run], ["analyze", run]):
        refused(capsys, *argv, "--config", config, words=["c.toml", "[vehicle]", words])


@pytest.mark.parametrize(
    "noise, words",
    [
        ("0.01", "[identify] noise_std = 0.01; expected a table of state = σ (SI)"),
        ("{yaw = 0.01}", "[identify] noise_std names 'yaw', not a state (one of u, v, w,"),
        ("{r = 0}", "[identify] noise_std: r = 0; expected a σ from 1e-09 to 1e+06 (SI)"),
        ("{r = -0.002}", "[identify] noise_std: r = -0.002; expected a σ from 1e-09"),
        ("{psi = nan}", "[identify] noise_std: psi = nan; expected a finite number"),
        ('{r = "0.002"}', "[identify] noise_std: r = '0.002'; expected a finite number"),
    ],
)
def test_a_bad_noise_std_in_the_config_is_refused(run, tmp_path, capsys, noise, words):
    config = _config(run, tmp_path, **{"free = [": f"noise_std = {noise}\nfree = ["})
    for argv in (["identify", run, "--method", "mekf"], ["identify", run], ["analyze", run]):
        refused(capsys, *argv, "--config", config, "--out", tmp_path / "e.json", words=["c.toml", words])
    assert not (tmp_path / "e.json").exists()


@pytest.mark.parametrize(
    "value, words",
    [
        ("r=-1", "'r=-1': r = -1; expected a σ from 1e-09 to 1e+06 (SI)"),
        ("r=0.002,yaw=1", "names 'yaw', not a state"),
        ("r=inf", "'r=inf': r = inf; expected a finite number"),
        ("r", "'r': expected state=σ pairs, e.g. r=0.002,psi=0.01"),
        ("", "expected state=σ pairs"),
        ("r=x", "'r=x': 'x' is not a number"),
        ("r=1,r=2", "gives r twice"),
    ],
)
def test_a_bad_noise_std_flag_is_refused_naming_it(run, tmp_path, capsys, value, words):
    for command in ("identify", "analyze"):
        refused(
            capsys,
            command,
            run,
            "--noise-std",
            value,
            "--out",
            tmp_path / "e.json",
            words=["--noise-std", words],
        )
    assert not (tmp_path / "e.json").exists()


def test_an_output_no_record_measures_is_refused(run, tmp_path, capsys):
    # the run's model.toml fits every measured state but z, r among them; this log has no r
    k = _rows(run)[0].index("r")
    data = _write(tmp_path / "no-r.csv", [r[:k] + r[k + 1 :] for r in _rows(run)])
    words = [
        "model.toml: [identify] outputs names r, which no record measures",
        "(they measure u, v, w, p, q, phi, theta, psi, z)",
    ]
    for argv in (["identify", "--method", "mekf"], ["identify"], ["analyze"]):
        refused(
            capsys, *argv, data, "--config", run / "model.toml", "--out", tmp_path / "e.json", words=words
        )
    assert not (tmp_path / "e.json").exists()


@pytest.mark.parametrize("method", ["mekf", "ml-gn"])
def test_an_inertia_that_is_not_a_bodys_is_refused_before_the_fit(run, tmp_path, capsys, method):
    iz = read_config(run / "model.toml").vehicle.Iz
    config = _config(run, tmp_path, free=("N_r", "N_rdot"))
    text = config.read_text().splitlines()
    config.write_text("\n".join(f"N_rdot = {iz!r}" if ln.startswith("N_rdot =") else ln for ln in text))
    refused(
        capsys,
        "identify",
        run,
        "--config",
        config,
        "--method",
        method,
        "--out",
        tmp_path / "e.json",
        words=["c.toml", "Iz − N_rdot = 0"],
    )
    assert not (tmp_path / "e.json").exists()


def test_only_u_measured_with_lateral_coefficients_free_is_not_identifiable(run, tmp_path, capsys):
    rows = [[r[0], r[1]] + r[11:] for r in _rows(run)]
    data = _write(tmp_path / "u.csv", rows)
    config = tmp_path / "c.toml"  # every measured state fitted (the run's outputs are not measured)
    write_config(config, replace(read_config(run / "model.toml"), free=("Y_v", "N_r", "Y_dr"), outputs=None))
    for method in ("ml-gn", "mekf"):
        refused(
            capsys,
            "identify",
            data,
            "--config",
            config,
            "--method",
            method,
            "--out",
            tmp_path / "e.json",
            words=["Y_v, N_r, Y_dr", "not identifiable", "(u)"],
        )
    assert not (tmp_path / "e.json").exists()
    code, out, err = cli(capsys, "analyze", data, "--config", config)
    doc = json.loads(out)
    assert code == 0 and "Not identifiable: Y_v, N_r, Y_dr" in err
    assert doc["crlb_std"] == {"Y_v": None, "N_r": None, "Y_dr": None}
    assert doc["null_directions"] == 3 and doc["unobserved"] == ["Y_v", "N_r", "Y_dr"]
    assert "All free coefficients are identifiable" not in err


# -- arguments -----------------------------------------------------------------------------------


def test_identify_refuses_a_negative_seed(run, capsys):
    refused(capsys, "identify", run, "--perturb", "0.2", "--seed", "-1", words=["--seed", "-1"])


def test_identify_refuses_both_perturbations_and_a_spread_beyond_any_start(run, capsys, tmp_path):
    refused(capsys, "identify", run, "--perturb", "0.2", "--perturb-spread", "0.3", words=["--perturb"])
    for bad in ("0", "-0.3", "nan", "inf"):
        refused(capsys, "identify", run, "--perturb-spread", bad, words=["--perturb-spread", bad])
    out = tmp_path / "e.json"
    refused(
        capsys,
        "identify",
        run,
        "--perturb-spread",
        "1e300",
        "--out",
        out,
        words=["--perturb-spread", "1e+15"],
    )
    assert not out.exists()


@pytest.mark.parametrize("duration", ["0.001", "0.02", "1e300"])
def test_simulate_refuses_a_duration_it_could_not_use_up_front(tmp_path, capsys, monkeypatch, duration):
    import testbed.simulation.runs

    monkeypatch.setattr(testbed.simulation.runs, "fly_scenario", lambda *a, **k: pytest.fail("flew"))
    refused(
        capsys,
        "simulate",
        "--scenario",
        "I",
        "--duration",
        duration,
        "--out",
        tmp_path / "r",
        words=[f"--duration {float(duration)!r}", "samples"],
    )
    assert _listing(tmp_path) == []


def test_misleading_path_messages_name_the_file_in_the_way(run, tmp_path, capsys):
    file = tmp_path / "x.csv"
    file.write_text("not a folder\n")
    refused(capsys, "identify", run, "--out", file / "est.json", words=[f"{file} is a file, not a folder"])
    refused(capsys, "analyze", run, "--out", file / "a.json", words=[f"{file} is a file, not a folder"])
    refused(
        capsys,
        "simulate",
        "--scenario",
        "I",
        "--out",
        file / "run",
        words=[f"{file} is a file, not a folder"],
    )
    refused(capsys, "analytic", "--mjcf", tmp_path, words=[f"{tmp_path}: is a folder; expected an MJCF file"])
    assert _listing(tmp_path) == ["x.csv"] and file.read_text() == "not a folder\n"


# -- outputs -------------------------------------------------------------------------------------


def test_simulate_force_never_replaces_a_file_or_a_users_folder(tmp_path, capsys):
    file = tmp_path / "FILE"
    file.write_text("keep me\n")
    refused(capsys, "simulate", "--scenario", "I", "--force", "--out", file, words=["FILE", "is a file"])
    folder = tmp_path / "mine"
    folder.mkdir()
    (folder / "thesis.tex").write_text("keep me too\n")
    refused(
        capsys,
        "simulate",
        "--scenario",
        "I",
        "--force",
        "--out",
        folder,
        words=["mine", "not a run directory"],
    )
    assert _listing(tmp_path) == ["FILE", "mine"] and file.read_text() == "keep me\n"
    assert _listing(folder) == ["thesis.tex"]


def test_an_output_may_not_be_an_input(run, tmp_path, capsys):
    before = (run / "horizontal.csv").read_bytes()
    refused(
        capsys,
        "identify",
        run / "horizontal.csv",
        "--config",
        run / "model.toml",
        "--out",
        run / "horizontal.csv",
        words=["is the input"],
    )
    refused(capsys, "analyze", run, "--out", run / "model.toml", words=["is the input"])
    refused(capsys, "identify", run, "--out", tmp_path / "a.rrd", "--rrd", tmp_path / "a.rrd", words=["also"])
    assert (run / "horizontal.csv").read_bytes() == before


def _null_device(tmp_path):
    """A character device like /dev/null (the real one must never be risked in a test)."""
    node = tmp_path / "null"
    try:
        os.mknod(node, stat.S_IFCHR | 0o666, os.makedev(1, 3))
    except (PermissionError, OSError):
        pytest.skip("cannot make a device node here")
    return node


@pytest.mark.parametrize(
    "command",
    [
        ["analytic"],
        ["identify", "--method", "ml-gn", "--max-iter", "1"],
        ["identify", "--method", "mekf"],
        ["analyze"],
    ],
)
def test_a_character_device_as_out_is_written_into_not_replaced(run, tmp_path, capsys, command):
    node = _null_device(tmp_path)
    rdev = os.stat(node).st_rdev
    data = [] if command[0] == "analytic" else [run]
    code, _, err = cli(capsys, command[0], *data, *command[1:], "--out", node)
    assert code in (0, 1), err
    st = os.stat(node)
    assert stat.S_ISCHR(st.st_mode) and st.st_rdev == rdev
    assert _listing(tmp_path) == ["null"]  # no history file beside a device, no temporary


def test_a_fifo_as_out_receives_the_whole_output(run, tmp_path, capsys):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    got = []
    reader = threading.Thread(target=lambda: got.append(fifo.read_bytes()))
    reader.start()
    code, _, err = cli(capsys, "analyze", run, "--out", fifo)
    reader.join(timeout=30)
    if reader.is_alive():  # nothing opened the FIFO: unblock the reader, then fail
        with open(fifo, "wb"):
            pass
        pytest.fail("the FIFO was not written")
    assert code == 0, err
    assert json.loads(got[0])["free"] == list(read_config(run / "model.toml").free)
    assert stat.S_ISFIFO(os.stat(fifo).st_mode) and _listing(tmp_path) == ["pipe"]


def test_dash_is_standard_output(run, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, out, err = cli(capsys, "analyze", run, "--out", "-")
    assert code == 0 and json.loads(out)["free"]
    code, out, err = cli(capsys, "analytic", "--out", "-")
    assert code == 0 and out.startswith("[vehicle]")
    refused(capsys, "simulate", "--scenario", "I", "--out", "-", words=["--out -"])
    refused(capsys, "identify", run, "--rrd", "-", words=["--rrd -"])
    assert _listing(tmp_path) == []


def test_atomic_file_writes_into_a_device_through_a_private_temporary(tmp_path):
    node = _null_device(tmp_path)
    with atomic_file(node) as tmp:
        assert tmp.parent != tmp_path
        tmp.write_text("x")
    assert stat.S_ISCHR(os.stat(node).st_mode) and not tmp.exists()


# -- run directories -----------------------------------------------------------------------------


def test_a_broken_truth_file_is_found_before_the_fit(run, tmp_path, capsys, monkeypatch):
    import shutil

    copy = tmp_path / "run"
    shutil.copytree(run, copy)
    (copy / "horizontal.truth.csv").write_text("t,u\n")
    monkeypatch.setattr(testbed.estimators, "identify", lambda *a, **k: pytest.fail("the fit ran"))
    refused(
        capsys,
        "identify",
        copy,
        "--out",
        tmp_path / "e.json",
        words=["horizontal.truth.csv", "column 'delta_r' missing"],
    )
    assert not (tmp_path / "e.json").exists()


@pytest.mark.parametrize(
    "experiments, words",
    [
        (["../outside"], "expected a file name of 1 to 100 bytes, without / or"),
        (["horizontal", "horizontal"], "listed twice"),
        ("horizontal", "'experiments' list of names"),
    ],
)
def test_a_manifest_names_only_its_own_distinct_files(run, tmp_path, capsys, experiments, words):
    import shutil

    copy = tmp_path / "run"
    shutil.copytree(run, copy)
    (tmp_path / "outside.csv").write_bytes((run / "horizontal.csv").read_bytes())
    doc = json.loads((copy / "manifest.json").read_text())
    (copy / "manifest.json").write_text(json.dumps({**doc, "experiments": experiments}))
    refused(capsys, "analyze", copy, words=["manifest.json", words])


def test_the_same_file_twice_is_refused_and_namesakes_are_told_apart(run, tmp_path, capsys):
    import shutil

    refused(
        capsys,
        "analyze",
        run / "horizontal.csv",
        run / "horizontal.csv",
        "--config",
        run / "model.toml",
        words=["given twice"],
    )
    other = tmp_path / "II"
    shutil.copytree(run, other)
    code, out, err = cli(capsys, "identify", run, other, "--max-iter", "1", "--out", tmp_path / "e.json")
    assert code in (0, 1), err
    assert len(json.loads((tmp_path / "e.json").read_text())["initial_states"]) == 6  # 2 runs × 3 experiments


# -- nesting, names and where a value came from ---------------------------------------------------

DEEP = {"toml": "a = " + "[" * 100_000 + "\n", "json": '{"coefficients": ' + "[" * 100_000 + "}"}


def _scenario(tmp_path, name="s.toml", **replace_text):
    """The built-in Scenario II as a user's file of 2 s experiments, with `replace_text` applied."""
    text = (SCENARIO_DIR / "II.toml").read_text().replace("duration = 60.0", "duration = 2.0")
    for old, new in replace_text.items():
        assert old in text
        text = text.replace(old, new)
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.mark.parametrize(
    "reader", ["config", "scenario", "estimates (validate)", "estimates (design)", "manifest"]
)
def test_every_reader_refuses_deep_nesting_in_one_line(run, tmp_path, capsys, reader):
    kind = "json" if reader.startswith(("estimates", "manifest")) else "toml"
    bad = tmp_path / f"deep.{kind}"
    bad.write_text(DEEP[kind])
    out = tmp_path / "out"
    argv = {
        "config": ("identify", run, "--config", bad, "--out", out),
        "scenario": ("simulate", "--scenario", bad, "--out", out),
        "estimates (validate)": ("validate", run, "--estimates", bad, "--out", out),
        "estimates (design)": ("design", "--from", bad, "--out", out),
        "manifest": ("identify", tmp_path / "run", "--out", out),
    }[reader]
    if reader == "manifest":
        shutil.copytree(run, tmp_path / "run")
        bad = tmp_path / "run" / "manifest.json"
        bad.write_text(DEEP[kind])
    refused(capsys, *argv, words=[bad, "nested too deeply"])
    assert not out.exists()


@pytest.mark.parametrize(
    "old, new, words",
    [
        ('name = "II"', 'name = "../escaped"', ["s.toml: name '../escaped'"]),
        ('name = "II"', 'name = ".."', ["s.toml: name '..'"]),
        ('name = "II"', 'name = "a\\u0000b"', ["s.toml: name 'a\\x00b'"]),
        ('name = "II"', f'name = "{"n" * 300}"', ["s.toml: name", "(300 bytes)"]),
        ('name = "horizontal"', 'name = "hor\\u0000izontal"', ["experiment name 'hor\\x00izontal'"]),
        ('name = "horizontal"', f'name = "{"h" * 300}"', ["experiment name", "(300 bytes)"]),
        ('name = "horizontal"', 'name = "a\\\\b"', ["experiment name 'a\\\\b'"]),
    ],
)
def test_scenario_and_experiment_names_are_file_names(tmp_path, capsys, monkeypatch, old, new, words):
    """A name becomes a file or folder name (runs/<scenario>-seed<N>, <experiment>.csv): one
    with a separator, `..`, a NUL or 300 bytes is refused before the flight, and nothing is
    written anywhere (a run named ../escaped once landed outside runs/)."""
    monkeypatch.chdir(tmp_path)
    path = _scenario(tmp_path, **{old: new})
    refused(capsys, "simulate", "--scenario", path, "--quiet", words=words + ["expected a file name"])
    assert _listing(tmp_path) == ["s.toml"]


def test_a_manifest_experiment_with_a_nul_byte_is_refused(run, tmp_path, capsys):
    shutil.copytree(run, tmp_path / "run")
    (tmp_path / "run" / "manifest.json").write_text(json.dumps({"experiments": ["a\x00b"]}))
    refused(capsys, "identify", tmp_path / "run", words=["manifest.json: experiment 'a\\x00b'"])


def test_values_from_a_scenario_file_are_blamed_on_its_fields_not_on_flags(tmp_path, capsys):
    """A value the user did not type is named by the file and field it came from."""
    fast = _scenario(tmp_path, "fast.toml", **{"duration = 2.0": "duration = 2.0\nspeed = 30.0"})
    err = refused(
        capsys, "simulate", "--scenario", fast, "--out", tmp_path / "r", words=["fast.toml: speed = 30 m/s"]
    )
    assert "--speed" not in err and "control_rate = 50 Hz" in err and "unstable" in err
    long = _scenario(tmp_path, "long.toml", **{"duration = 2.0": "duration = 10000000.0"})
    err = refused(
        capsys,
        "simulate",
        "--scenario",
        long,
        "--out",
        tmp_path / "r",
        words=["long.toml: duration = 10000000.0 (experiment"],
    )
    assert "--duration" not in err
    one = _scenario(tmp_path, "one.toml", **{'name = "roll"': 'name = "roll"\nduration = 1e7'})
    refused(
        capsys,
        "simulate",
        "--scenario",
        one,
        "--out",
        tmp_path / "r",
        words=["one.toml: experiment 'roll': duration = 10000000.0"],
    )
    # the flags, when typed, are named as flags
    refused(
        capsys,
        "simulate",
        "--scenario",
        long,
        "--duration",
        "1e-6",
        "--out",
        tmp_path / "r",
        words=["--duration 1e-06"],
    )
    refused(
        capsys,
        "simulate",
        "--scenario",
        fast,
        "--speed",
        "1e-6",
        "--out",
        tmp_path / "r",
        words=["--speed 1e-06"],
    )
    assert not (tmp_path / "r").exists()


@pytest.fixture(scope="module")
def fuzz_workspace(tmp_path_factory):
    """The fuzz study's workspace (a 2 s synthetic run at 20 Hz) with every coefficient free."""
    from studies.fuzz import workspace

    root = workspace(tmp_path_factory.mktemp("ws"))
    cfg = read_config(root / "run" / "model.toml")
    write_config(root / "all.toml", replace(cfg, free=COEFFICIENTS, source=""))
    return root


def test_a_fit_that_leaves_the_physical_region_has_diverged(fuzz_workspace):
    """On the fuzz workspace's run the screen's fit of the 16 candidates it keeps (of all 35)
    converges in cost where Mt is no body's: a diverged fit (not bad input), with the reason."""
    experiments, _ = load_data([fuzz_workspace / "run"])
    cfg = read_config(fuzz_workspace / "all.toml")
    noise = noise_from_data(cfg.fitted(experiments), cfg.noise_std)
    fixed = structurally_unidentified(identifiability(experiments, cfg, noise))
    candidates = replace(cfg, free=tuple(n for n in cfg.free if n not in fixed))
    est = identify(experiments, candidates, method="ml-gn")
    assert est.status is Status.DIVERGED and "left the physical region" in est.message
    assert "inertia matrix Mt is not a body's" in est.message
    assert (
        identify(experiments, candidates, method="ml-gn", options={"max_iter": 0}).status
        is Status.MAX_ITERATIONS
    )


def test_identify_free_all_never_blames_a_sound_config_for_the_fit(fuzz_workspace, tmp_path, capsys):
    """`--free-all` with all 35 free: the screen's fit leaves the physical region; that fit has
    diverged (the screen fixes nothing), the config is not at fault."""
    out = tmp_path / "e.json"
    code, _, err = cli(
        capsys,
        "identify",
        fuzz_workspace / "run",
        "--config",
        fuzz_workspace / "all.toml",
        "--free-all",
        "--out",
        out,
    )
    assert "not a body's" not in err or "diverged" in err, err
    assert code in (0, 1) and json.loads(out.read_text())["method"] == "ml-gn", err


# -- reproduce -----------------------------------------------------------------------------------


def test_reproduce_never_writes_into_a_users_folder(tmp_path, capsys):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "results.csv").write_text("my results\n")
    (mine / "notes.txt").write_text("my notes\n")
    before = {p.name: p.read_bytes() for p in mine.iterdir()}
    refused(capsys, "reproduce", "--quick", "--out", mine, words=[f"--out {mine}", ".testbed-campaign"])
    assert {p.name: p.read_bytes() for p in mine.iterdir()} == before


def test_a_flag_left_at_its_default_is_named_as_the_default(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "runs" / "reproduce").mkdir(parents=True)
    (tmp_path / "runs" / "reproduce" / "results.csv").write_text("my results\n")
    refused(capsys, "reproduce", "--quick", words=["error: the default --out runs/reproduce: holds"])
    assert (tmp_path / "runs" / "reproduce" / "results.csv").read_text() == "my results\n"


def test_reproduce_bounds_seeds_before_building_the_plan(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    t0 = time.perf_counter()
    refused(capsys, "reproduce", "--seeds", "1000000000", words=["--seeds 1000000000", "1 to 1000"])
    assert time.perf_counter() - t0 < 5.0 and _listing(tmp_path) == []


def test_reproduce_with_a_malformed_scheduler_address_writes_nothing(tmp_path, capsys):
    refused(
        capsys,
        "reproduce",
        "--scheduler",
        "not an address",
        "--out",
        tmp_path / "study",
        words=["--scheduler not an address"],
    )
    assert _listing(tmp_path) == []


# -- the library ---------------------------------------------------------------------------------


def test_input_error_is_a_value_error():
    assert issubclass(InputError, ValueError)


def test_an_estimate_that_is_not_finite_still_writes_json():
    est = Estimate(
        "ml-gn",
        Status.DIVERGED,
        ("Y_v",),
        np.array([np.inf]),
        np.array([np.nan]),
        np.nan,
        0,
        0.0,
        {"v": np.inf},
    )
    doc = json.loads(est.to_json())
    assert doc["coefficients"]["Y_v"] == {"value": None, "std": None} and doc["noise_std"] == {"v": None}


def test_a_config_made_in_python_is_checked_like_a_file(run):
    e = read_csv(run / "horizontal.csv")
    cfg = read_config(run / "model.toml")
    bad = ModelConfig(replace(cfg.vehicle, speed=1e-9), cfg.coefficients, cfg.free, "mine")
    with pytest.raises(InputError, match=r"mine: \[vehicle\] speed = 1e-09"):
        identify([e], bad)


def test_a_file_name_holding_a_line_break_is_named_on_one_line(tmp_path, capsys, run):
    """Every message naming a file escapes its control characters: a CSV, a config, a missing
    input and an output whose names hold a line break are each refused on one line."""
    broken = tmp_path / "two\nlines.csv"
    broken.write_text("t,u\n0,1\n")
    config = tmp_path / "model\r\n.toml"
    config.write_text("[vehicle]\n")
    taken = tmp_path / "taken\n.json"
    taken.write_text("a user's file\n")
    for argv, shown in (
        (("analyze", broken, "--config", run / "model.toml"), "two\\nlines.csv: column 'delta_r' missing"),
        (("identify", tmp_path / "no\u2028such.csv", "--config", run / "model.toml"), "no\\u2028such.csv"),
        (("validate", run, "--config", config), "model\\r\\n.toml: table [coefficients] missing"),
        (("identify", run, "--max-iter", "1", "--out", taken), "taken\\n.json"),
    ):
        refused(capsys, *argv, words=(shown,))


def test_data_without_excitation_are_refused_for_what_they_are(run, capsys, tmp_path):
    """States at trim and fins at 0 throughout: no coefficient changes what the record shows, and
    the refusal says so of the data, not of the config whose values a fit would have carried off."""
    config = read_config(run / "model.toml")
    e = read_csv(run / "horizontal.csv")
    y = np.zeros_like(e.y)
    y[:, 0] = config.vehicle.speed
    y[:, -1] = e.y[0, -1]  # z: the depth held
    flat = tmp_path / "flat.csv"
    flat.write_text(csv_text(e.t, y, np.zeros_like(e.inputs)))
    for argv in (
        ("identify", flat, "--config", run / "model.toml"),
        ("identify", flat, "--config", run / "model.toml", "--method", "mekf"),
        ("identify", flat, "--config", run / "model.toml", "--start", "config"),
        ("analyze", flat, "--config", run / "model.toml"),
    ):
        err = refused(capsys, *argv, words=("flat.csv: no excitation", "nothing to identify"))
        assert "model.toml" not in err, err
    # a moving record beside a flat one is data to fit
    assert identify([e, replace(e, y=y, inputs=0 * e.inputs, name="flat")], config, max_iter=1).free


def test_a_record_whose_only_motion_is_a_channels_rounding_is_refused(run, capsys, tmp_path):
    """States at trim but v, which carries 1e-6 of noise, and the fins at 0: the noise is all a fit
    can follow and the still channels' variances sit at their floor. The default start's screen
    finds no candidate the data determine; from the a-priori start the coefficients run off until
    the normal equations overflow and the fit ends as diverged. Either way one line, exit 2,
    nothing written."""
    config = read_config(run / "model.toml")
    e = read_csv(run / "horizontal.csv")
    y = np.zeros_like(e.y)
    y[:, 0] = config.vehicle.speed
    y[:, -1] = e.y[0, -1]
    y[:, e.measured.index("v")] = 1e-6 * np.random.default_rng(0).normal(size=len(y))
    still = tmp_path / "still.csv"
    still.write_text(csv_text(e.t, y, np.zeros_like(e.inputs)))
    for more, words in (((), ("no candidate", "not determined")), (("--start", "config"), ("diverged",))):
        out = tmp_path / "e.json"
        refused(capsys, "identify", still, "--config", run / "model.toml", "--out", out, *more, words=words)
        assert not out.exists()


def test_a_value_the_fit_carried_off_is_reported_as_the_fits(run, capsys, monkeypatch, tmp_path):
    """A fit that ends with a coefficient beyond what a config may hold (±1e15) is refused as
    the fit's outcome on the data, never as a value of the config the fit started from."""
    from testbed.jobs.identify import identify_screened as real

    def carried_off(*args, **kwargs):
        done = real(*args, **kwargs)
        values = done.estimate.values.copy()
        values[0] = -1e18
        return replace(done, estimate=replace(done.estimate, values=values))

    monkeypatch.setattr("testbed.jobs.identify.identify_screened", carried_off)
    out = tmp_path / "e.json"
    err = refused(
        capsys,
        "identify",
        run,
        "--max-iter",
        "1",
        "--out",
        out,
        words=("--method 'ml-gn': the fit carried Y_v to -1e+18",),
    )
    assert "-1e+18" in err and "model.toml" not in err and not out.exists(), err
