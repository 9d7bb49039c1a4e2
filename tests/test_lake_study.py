"""The lake trial's acceptance study (studies/lake.py): its core on a few dives of one seed, and
the full study of ten seeds (slow)."""

from __future__ import annotations

import json
from dataclasses import replace

import pytest

from studies import lake
from testbed import METHODS
from testbed.simulation.runs import simulate
from testbed.simulation.scenario import scenario

LAKE = scenario("lake")
AHRS = next(s for s in LAKE.named_sensors if s.name == "ahrs")


@pytest.fixture(scope="module")
def short_run(tmp_path_factory):
    """Seed 1's dive-08 (depth and course squares), dive-09 (rudder zigzag) and dive-11 (a
    depth step in a course square) of the lake trial, as its run directory."""
    dives = tuple(e for e in LAKE.experiments if e.name in ("dive-08", "dive-09", "dive-11"))
    return simulate(replace(LAKE, experiments=dives), seed=1, out=tmp_path_factory.mktemp("lake") / "seed1")


def test_the_offsets_compared_are_the_ahrs_bias_the_scenario_injected(short_run):
    assert lake.true_offsets(short_run) == {
        "b_phi": AHRS.bias["phi"],
        "b_theta": AHRS.bias["theta"],
        "b_psi": AHRS.bias["psi"],
    }


@pytest.fixture(scope="module")
def short_row(short_run):
    """The study's core on the three dives: default `ml-gn` and `equation-error`, the global
    search, `ml-gn` on two dives validated on the third."""
    return lake.seed_study(short_run, methods=("equation-error", "ml-gn"), fit_dives=2)


def test_the_study_s_core_records_every_fit_s_exit_reason_and_time(short_row):
    """Each fit from prior.toml ends in exit 0, 1 or 2 with one line; the row holds every part
    of the study and renders as its tables."""
    row = short_row
    for name, f in [
        *row["methods"].items(),
        ("global", row["global"]),
        ("fit dives", row["held_out"]["fit"]),
    ]:
        assert f["exit"] in (0, 1, 2), (name, f["reason"])
        assert f["reason"] and "\n" not in f["reason"]
        assert f["seconds"] > 0
    held = row["held_out"]
    assert held["fit_dives"] == ["dive-08", "dive-09"] and held["held_dives"] == ["dive-11"]
    # the attitude offsets of the kinematic check: the pitch offset within 3 σ of the AHRS's
    assert row["check"]["exit"] == 0, row["check"]["reason"]
    b_theta = row["check"]["offsets"]["b_theta"]
    assert b_theta["estimated"] and abs(b_theta["sigmas"]) <= lake.SIGMAS, b_theta
    text = lake.seed_table(1, row) + lake.summary({1: row})
    assert "### Seed 1" in text and "| ml-gn --start global |" in text
    json.dumps(row)


def test_default_ml_gn_fits_from_the_unstable_prior_to_the_global_search_s_optimum(short_row):
    """The acceptance's core on three dives: default `ml-gn` fits from prior.toml (course-unstable
    at +0.80 1/s) to the optimum of the global search within ΔJ 1, with the AHRS's roll offset
    estimated within 3 σ. (The held-out comparison needs more dives than two to fit: the full study.)"""
    row = short_row
    gn = row["methods"]["ml-gn"]
    assert gn["exit"] == 0, gn["reason"]
    assert row["delta_j"] == gn["estimate"]["cost"] - min(
        gn["estimate"]["cost"], row["global"]["estimate"]["cost"]
    )
    assert row["delta_j"] <= lake.DELTA_J
    b_phi = row["offsets"]["b_phi"]
    assert b_phi["estimated"] and abs(b_phi["sigmas"]) <= lake.SIGMAS, b_phi


def test_the_study_refuses_a_folder_of_someone_s_notes_before_it_runs(tmp_path, capsys):
    notes = tmp_path / "notes"
    (notes / "seed1").mkdir(parents=True)
    (notes / "seed1" / "plan.txt").write_text("mine")
    assert lake.main(["--seeds", "1", "--out", str(notes)]) == 2
    assert "seed1: is a folder without manifest.json" in capsys.readouterr().err
    assert (notes / "seed1" / "plan.txt").read_text() == "mine"


@pytest.mark.slow
def test_the_lake_trial_s_ten_seeds_every_method_exits_with_a_reason(tmp_path, capsys):
    """The full study (about 40 minutes with --jobs 2 on two shared cores): every method on every seed ends in exit 0,
    1 or 2 with its reason, never 70."""
    assert lake.main(["--out", str(tmp_path / "lake")]) == 0
    rows = json.loads((tmp_path / "lake" / "study.json").read_text())
    assert len(rows) == 10
    for seed, row in rows.items():
        assert set(row["methods"]) == set(METHODS)
        for m, f in row["methods"].items():
            assert f["exit"] in (0, 1, 2), (seed, m, f["reason"])
