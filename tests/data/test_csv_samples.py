"""What a measurement CSV's cells say of a sample: the NaN spellings loggers write (a missing
sample, a fin held) and the stale repeats of a sensor slower than its logger (missing)."""

import numpy as np
import pytest

from testbed.data import read_csv
from testbed.errors import InputError

SPELLINGS = ("nan", "NaN", "NAN", "-nan", "+nan", "-NaN", "nan(ind)", "-nan(ind)", "NaN(0x7ff8)", "nan(snan)")


def _csv(tmp_path, text, name="e.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


@pytest.mark.parametrize("spelling", SPELLINGS)
def test_every_nan_spelling_is_a_missing_state_and_a_held_fin(tmp_path, spelling):
    text = (
        "t,u,r,delta_r,delta_er,delta_el\n"
        "0,1.5,0.01,0.1,0,0\n"
        f"0.1, {spelling} ,0.02,0.2,0,0\n"
        f"0.2,1.7,0.03,{spelling},0,{spelling}\n"
        "0.3,1.8,0.04,0.4,0,0.5\n"
    )
    e = read_csv(_csv(tmp_path, text))
    np.testing.assert_array_equal(e.y[:, 0], [1.5, np.nan, 1.7, 1.8])
    np.testing.assert_array_equal(e.inputs[:, 0], [0.1, 0.2, 0.2, 0.4])
    np.testing.assert_array_equal(e.inputs[:, 2], [0.0, 0.0, 0.0, 0.5])


@pytest.mark.parametrize("cell", ("nan(", "nana", "-nan)", "nan(a b)", "--nan", "n an", "nan()x"))
def test_a_cell_that_only_looks_like_nan_is_refused_by_line_and_column(tmp_path, cell):
    text = f"t,u,delta_r,delta_er,delta_el\n0,1,0,0,0\n0.1,{cell},0,0,0\n0.2,1,0,0,0\n"
    with pytest.raises(InputError, match=r"line 3, column 'u': .* is not a number"):
        read_csv(_csv(tmp_path, text))


@pytest.mark.parametrize("spelling", ("-nan", "nan(ind)"))
def test_a_nan_time_is_refused(tmp_path, spelling):
    text = f"t,u,delta_r,delta_er,delta_el\n0,1,0,0,0\n{spelling},1,0,0,0\n0.2,1,0,0,0\n"
    with pytest.raises(InputError, match=r"line 3, column 't'"):
        read_csv(_csv(tmp_path, text))


def _log(tmp_path, t, columns, fins=None, name="log.csv"):
    """A measurement CSV of the named state columns (NaN: an empty cell) at times `t`."""
    fins = np.zeros((len(t), 3)) if fins is None else fins
    names = list(columns)
    lines = [",".join(["t", *names, "delta_r", "delta_er", "delta_el"])]
    for k in range(len(t)):
        cells = [repr(float(t[k]))] + [
            "" if np.isnan(columns[n][k]) else repr(float(columns[n][k])) for n in names
        ]
        lines.append(",".join(cells + [repr(float(f)) for f in fins[k]]))
    return _csv(tmp_path, "\n".join(lines) + "\n", name)


def _dvl_log(n=40, seed=3):
    """A logger's rows every 0.5 s: an AHRS fresh in every row (phi, psi with noise), a DVL (u, v)
    updating every other row and repeating its last value in between."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.5
    dvl = rng.normal(size=(n // 2, 2)) * 0.01 + [1.5, 0.0]
    u, v = np.repeat(dvl, 2, axis=0).T
    return t, {"u": u, "v": v, "phi": rng.normal(size=n) * 0.003, "psi": rng.normal(size=n) * 0.01}


def test_a_sensor_at_half_the_rows_rate_has_its_repeats_missing(tmp_path):
    t, columns = _dvl_log()
    e = read_csv(_log(tmp_path, t, columns))
    for s in ("u", "v"):
        np.testing.assert_array_equal(e.column(s)[::2], columns[s][::2])  # each fresh sample kept
        assert np.isnan(e.column(s)[1::2]).all()
    for s in ("phi", "psi"):
        np.testing.assert_array_equal(e.column(s), columns[s])
    kept = read_csv(_log(tmp_path, t, columns), keep_repeats=True)
    for s in columns:
        np.testing.assert_array_equal(kept.column(s), columns[s])


def test_a_repeat_is_judged_against_the_previous_value_present(tmp_path):
    t, columns = _dvl_log()
    columns["u"][1::4] = np.nan  # some of the DVL's repeats already empty
    columns["psi"][6] = np.nan  # the AHRS missing a sample
    e = read_csv(_log(tmp_path, t, columns))
    assert np.isnan(e.column("u")[1::2]).all() and not np.isnan(e.column("u")[::2]).any()


def test_stale_rows_constant_columns_and_occasional_repeats_are_samples(tmp_path):
    """Kept as logged: a row in which no state changes (the body still at its sensors'
    resolution), a state held at exactly 0 over the record, and a 3-digit heading standing still
    at the turns of a zigzag (repeats in fewer than a quarter of its rows)."""
    rng = np.random.default_rng(5)
    n = 60
    t = np.arange(n) * 0.1
    r = rng.normal(size=n) * 0.01
    r[20:24] = r[19]
    psi = np.round(np.sin(t), 2)  # repeats where the heading turns
    columns = {"r": r, "phi": np.zeros(n), "psi": psi}
    columns["psi"][20:24] = psi[19]  # rows 20–23 repeat every state: stale rows
    assert 0 < np.mean(np.diff(psi) == 0) < 0.25
    e = read_csv(_log(tmp_path, t, columns))
    for s in columns:
        np.testing.assert_array_equal(e.column(s), columns[s])


def test_the_testbeds_own_runs_read_the_same_with_and_without_repeats(tmp_path):
    """`testbed simulate`'s noisy CSVs, its fin-logged ones (rows with the states empty between
    samples) and its noise-free truth CSVs have no stale repeats to drop."""
    from testbed.data import run_csvs
    from testbed.simulation.runs import simulate
    from testbed.simulation.scenario import SCENARIO_DIR

    text = (SCENARIO_DIR / "I.toml").read_text()
    assert "[sensors]" not in text
    scenario = tmp_path / "fins.toml"
    scenario.write_text(
        text.replace(
            "control_rate = 50.0", "control_rate = 50.0\n\n[sensors]\nrate = 25.0\nfin_rate = 50.0", 1
        )
    )
    run = simulate(scenario, seed=2, duration=3.0, out=tmp_path / "run")
    files = run_csvs(run)
    files += [f.with_suffix(".truth.csv") for f in files]
    assert any(np.isnan(read_csv(f).y).all(axis=1).any() for f in files)  # the fins-only rows
    for f in files:
        a, b = read_csv(f), read_csv(f, keep_repeats=True)
        np.testing.assert_array_equal(a.y, b.y)


@pytest.mark.parametrize(
    "argv",
    [
        ("identify", "x.csv", "--config", "c.toml"),
        ("analyze", "x.csv", "--config", "c.toml"),
        ("validate", "x.csv", "--config", "c.toml"),
        ("check", "x.csv"),
    ],
)
def test_every_command_that_reads_data_takes_keep_repeats(argv, monkeypatch, capsys):
    import testbed.jobs.check
    import testbed.jobs.common
    from testbed.cli import main

    seen = []

    def load_data(paths, keep_repeats=False):
        seen.append(keep_repeats)
        raise InputError("x.csv: read")

    for reader in (testbed.jobs.common, testbed.jobs.check):  # every job's reading of data
        monkeypatch.setattr(reader, "load_data", load_data)
    assert main([*argv, "--keep-repeats"]) == 2 and main(list(argv)) == 2
    assert seen == [True, False]
