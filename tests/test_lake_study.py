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


def test_the_study_s_core_on_three_dives_fits_from_the_unstable_prior_and_holds_one_out(short_run):
    """Default `ml-gn` and `equation-error` on three dives from prior.toml: exits 0, 1 or 2 with
    one line each; the global search beside it; `ml-gn` on two dives validated on the third
    against the prior."""
    row = lake.seed_study(short_run, methods=("equation-error", "ml-gn"), fit_dives=2)
    for name, f in [*row["methods"].items(), ("global", row["global"])]:
        assert f["exit"] in (0, 1, 2), (name, f["reason"])
        assert f["reason"] and "\n" not in f["reason"]
        assert f["seconds"] > 0
    gn = row["methods"]["ml-gn"]
    assert gn["exit"] in (0, 1)
    assert row["delta_j"] >= 0
    assert row["delta_j"] == gn["estimate"]["cost"] - min(
        gn["estimate"]["cost"], row["global"]["estimate"]["cost"]
    )
    assert set(row["offsets"]) == {"b_phi", "b_theta", "b_psi"}
    b_phi = row["offsets"]["b_phi"]
    assert b_phi["estimated"] and b_phi["value"] == gn["estimate"]["coefficients"]["b_phi"]["value"]
    held = row["held_out"]
    assert held["fit_dives"] == ["dive-08", "dive-09"] and held["held_dives"] == ["dive-11"]
    assert set(held["median"]) == {"u", "v", "w", "phi", "theta", "psi"}
    # the prior reads the AHRS without its 7° roll offset: the fit, with b_phi, predicts φ better
    assert held["median"]["phi"]["fit"] > held["median"]["phi"]["prior"]
    text = lake.seed_table(1, row) + lake.summary({1: row})
    assert "### Seed 1" in text and "| ml-gn --start global |" in text
    json.dumps(row)


def test_the_study_refuses_a_folder_of_someone_s_notes_before_it_runs(tmp_path, capsys):
    notes = tmp_path / "notes"
    (notes / "seed1").mkdir(parents=True)
    (notes / "seed1" / "plan.txt").write_text("mine")
    assert lake.main(["--seeds", "1", "--out", str(notes)]) == 2
    assert "seed1: is a folder without manifest.json" in capsys.readouterr().err
    assert (notes / "seed1" / "plan.txt").read_text() == "mine"


@pytest.mark.slow
def test_the_lake_trial_s_ten_seeds_every_method_exits_with_a_reason(tmp_path, capsys):
    """The full study (about N minutes on one core): every method on every seed ends in exit 0,
    1 or 2 with its reason, never 70."""
    assert lake.main(["--out", str(tmp_path / "lake")]) == 0
    rows = json.loads((tmp_path / "lake" / "study.json").read_text())
    assert len(rows) == 10
    for seed, row in rows.items():
        assert set(row["methods"]) == set(METHODS)
        for m, f in row["methods"].items():
            assert f["exit"] in (0, 1, 2), (seed, m, f["reason"])
