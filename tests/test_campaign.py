"""The campaign (`testbed reproduce`): cells on a real two-worker Dask LocalCluster, resumed after
a crash and surviving a worker killed mid-run; the conclusions' rules on results built by hand."""

import json
import math
import os
import shutil
import signal
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from testbed.study import campaign
from testbed.study.campaign import Cell, conclusions, plan, read_results, results_csv, results_rows
from testbed.errors import InputError

TINY = dict(scenarios=("II",), methods=("ml-gn", "mekf"), duration=4.0)


def test_a_cell_key_follows_the_code(tmp_path, monkeypatch):
    """Editing any source or data file of the package changes the hash and so every cell's key;
    Python's compiled caches do not."""
    package = tmp_path / "testbed"
    shutil.copytree(
        Path(campaign.__file__).resolve().parents[1], package, ignore=shutil.ignore_patterns("*.pyc")
    )
    before = campaign.source_hash(package)
    (package / "__pycache__").mkdir(exist_ok=True)
    (package / "__pycache__" / "x.cpython-311.pyc").write_bytes(b"compiled")
    assert campaign.source_hash(package) == before
    for edited in (
        "identification/likelihood.py",
        "simulation/scenarios/II.toml",
        "simulation/mjcf/torpedo.xml",
    ):
        path = package / edited
        text = path.read_bytes()
        path.write_bytes(text + b"\n")
        assert campaign.source_hash(package) != before, edited
        path.write_bytes(text)
    assert campaign.source_hash(package) == before
    cell = Cell("II", "ml-gn", 1)
    key = cell.key
    monkeypatch.setattr(campaign, "code_hash", lambda: "other code")
    assert Cell("II", "ml-gn", 1).key != key


def test_plan_covers_scenarios_methods_and_seeds_with_distinct_keys():
    cells = plan(2)
    assert len(cells) == 2 * 4 * 2
    assert {(c.scenario, c.method, c.seed) for c in cells} == {
        (s, m, k) for s in ("I", "II") for m in ("ml-nr", "ml-nm", "mekf", "ml-gn") for k in (1, 2)
    }
    assert len({c.key for c in cells}) == len(cells)
    assert Cell("I", "ml-nm", 1).key != Cell("I", "ml-nm", 1, duration=30.0).key  # the data differ
    assert all(c.duration == campaign.QUICK_DURATION for c in plan(1, quick=True))
    with pytest.raises(InputError, match="seeds=0"):
        plan(0)


def test_seeds_are_bounded_before_the_plan_is_built():
    assert len(plan(campaign.MAX_SEEDS, methods=("ml-gn",), scenarios=("II",))) == campaign.MAX_SEEDS
    t0 = time.perf_counter()
    for seeds in (campaign.MAX_SEEDS + 1, 10**9, True, 2.0):
        with pytest.raises(InputError, match=f"seeds={seeds!r}; expected an integer from 1 to 1000"):
            plan(seeds)
    assert time.perf_counter() - t0 < 1.0  # 10⁹ seeds' cells would take a minute and 6 GB to build


def test_the_campaign_folder_is_new_empty_or_a_campaigns(tmp_path):
    campaign.check_folder(tmp_path / "new" / "study")  # made when the campaign starts
    (tmp_path / "empty").mkdir()
    campaign.check_folder(tmp_path / "empty")
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "results.csv").write_text("my results\n")
    (mine / "notes.txt").write_text("notes\n")
    with pytest.raises(InputError, match=f"out={mine}: holds files that are not a campaign's"):
        campaign.check_folder(mine)
    with pytest.raises(InputError, match="is a file"):
        campaign.check_folder(mine / "notes.txt")
    with pytest.raises(InputError, match="notes.txt is a file, not a folder"):
        campaign.check_folder(mine / "notes.txt" / "study")
    campaign.make_folder(tmp_path / "empty")
    assert sorted(p.name for p in (tmp_path / "empty").iterdir()) == [campaign.MARKER, "cells"]
    (tmp_path / "empty" / "results.csv").write_text("the campaign's\n")
    campaign.check_folder(tmp_path / "empty")  # a campaign's folder: resumed


def _doc(scenario, method, seed, ratios, converged=True, std=1e-6):
    rows = [
        {"coefficient": f"C{i}", "analytic": -10.0, "estimate": -10.0 * x, "std": std}
        for i, x in enumerate(ratios)
    ]
    return {
        "cell": {"scenario": scenario, "method": method, "seed": seed, "duration": None},
        "status": "converged" if converged else "max iterations",
        "reason": "",
        "converged": converged,
        "iterations": 5,
        "wall_time_s": 1.0,
        "rows": rows,
    }


DRIFT = {"null_directions": 2, "drift_groups": [["X_udot", "X_u"]], "null_directions_inertia_known": 0}


def test_a_coefficient_passes_within_ten_percent_or_three_finite_sigmas():
    def ok(estimate, std):
        return campaign.coefficient_ok({"analytic": 100.0, "estimate": estimate, "std": std})

    assert ok(109.0, 0.1) and not ok(111.0, 0.1)  # the 10 % clause, both ways
    assert ok(130.0, 10.1) and not ok(131.0, 10.0)  # the 3 σ clause, both ways
    assert not ok(150.0, math.inf) and ok(105.0, math.inf)  # an infinite σ bounds nothing
    assert not ok(150.0, math.nan) and not ok(math.nan, 1.0)


def test_conclusion_rules_decide_from_results_csv(tmp_path):
    good, bad = [1.0, 1.05, 0.95, 1.02, 0.98], [1.0, 1.5, 0.5, 2.0, 1.0]
    docs = [_doc("I", "ml-nm", k, [1.0, 1.3, 0.7, 1.2, 0.98]) for k in (1, 2)]  # 40 % within 10 %
    docs += [_doc("II", "ml-nm", k, good) for k in (1, 2)]
    docs += [_doc(s, "ml-nr", k, bad, converged=k == 1) for s in ("I", "II") for k in (1, 2)]
    (tmp_path / "results.csv").write_text(results_csv(results_rows(docs)))
    rows = read_results(tmp_path / "results.csv")
    v = conclusions(rows, {"I": DRIFT, "II": DRIFT})
    assert v["1"]["holds"] and "2 exactly unidentifiable" in v["1"]["evidence"]
    # ml-nm acceptable in 2/4 cells (< 80 %): conclusion 2 refuted although ml-nr fails everywhere
    assert not v["2"]["holds"] and "2/4" in v["2"]["evidence"] and "0/4" in v["2"]["evidence"]
    # on Scenario II ml-nm is acceptable in 2/2 and better than on I
    assert v["3"]["holds"] and "2/2" in v["3"]["evidence"]
    # a scenario with drift that the known inertia matrix does not remove refutes conclusion 1
    v = conclusions(rows, {"I": DRIFT, "II": {**DRIFT, "null_directions_inertia_known": 1}})
    assert not v["1"]["holds"]
    # within 3 σ counts as acceptable too
    docs = [_doc(s, "ml-nm", 1, bad, std=5.0) for s in ("I", "II")] + [
        _doc(s, "ml-nr", 1, bad) for s in ("I", "II")
    ]
    v = conclusions(read_back(tmp_path, docs), {"I": DRIFT})
    assert v["2"]["holds"]


def read_back(tmp_path, docs):
    (tmp_path / "r.csv").write_text(results_csv(results_rows(docs)))
    return read_results(tmp_path / "r.csv")


@pytest.fixture(scope="module")
def cluster():
    import logging

    from dask.distributed import Client, LocalCluster

    with (
        LocalCluster(
            n_workers=2,
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            silence_logs=logging.ERROR,
        ) as c,
        Client(c) as client,
    ):
        yield c, client


def _check_outputs(out, cells):
    files = sorted(p.name for p in (out / "cells").glob("*.json"))
    assert files == sorted(f"{c.key}.json" for c in cells)  # every cell once, nothing else
    rows = read_results(out / "results.csv")
    keys = [(r["scenario"], r["method"], r["seed"], r["coefficient"]) for r in rows]
    assert len(keys) == len(set(keys))  # no duplicates
    assert {(r["scenario"], r["method"], r["seed"]) for r in rows} == {
        (c.scenario, c.method, c.seed) for c in cells
    }
    verdicts = json.loads((out / "conclusions.json").read_text())
    assert list(verdicts) == ["1", "2", "3"] and all(isinstance(v["holds"], bool) for v in verdicts.values())
    html = (out / "report.html").read_text()
    for name in ("fig5-inputs-II.png", "fig6-coefficients-II.png", "iterations-II.png"):
        assert f"src='{name}'" in html and (out / name).read_bytes()[:4] == b"\x89PNG"
    assert (out / "report.rrd").stat().st_size > 0
    return rows


def test_campaign_on_two_workers_survives_a_killed_worker_and_resumes(tmp_path, cluster):
    c, client = cluster
    out = tmp_path / "study"
    cells = plan(2, methods=TINY["methods"], scenarios=TINY["scenarios"], duration=TINY["duration"])
    killed = []

    def kill_a_worker():  # as soon as the first cell is written, SIGKILL a worker process mid-campaign
        deadline = time.time() + 120
        while time.time() < deadline and not list((out / "cells").glob("*.json")):
            time.sleep(0.05)
        pids = client.run(os.getpid)
        pid = next(iter(pids.values()))
        os.kill(pid, signal.SIGKILL)
        killed.append(pid)

    killer = threading.Thread(target=kill_a_worker)
    killer.start()
    done = campaign.reproduce(out, seeds=2, scheduler=c.scheduler_address, **TINY)
    killer.join()
    assert killed
    assert done.computed == len(cells) and done.reused == 0
    rows = _check_outputs(out, cells)
    assert all(r["status"] != "failed" for r in rows), [r["reason"] for r in rows if r["status"] == "failed"]

    # a crash after some cells: they are kept, only the missing one and one whose file was cut
    # short are computed again
    lost, cut = cells[1], cells[2]
    (out / "cells" / f"{lost.key}.json").unlink()
    path = out / "cells" / f"{cut.key}.json"
    path.write_bytes(path.read_bytes()[:100])
    kept = {p.name: p.stat().st_mtime_ns for p in (out / "cells").glob("*.json") if p != path}
    again = campaign.reproduce(out, seeds=2, scheduler=c.scheduler_address, **TINY)
    assert again.computed == 2 and again.reused == len(cells) - 2
    assert {p.name: p.stat().st_mtime_ns for p in (out / "cells").glob("*.json") if p.name in kept} == kept
    rows_again = _check_outputs(out, cells)
    before = {(r["method"], r["seed"], r["coefficient"]): r["estimate"] for r in rows}
    after = {(r["method"], r["seed"], r["coefficient"]): r["estimate"] for r in rows_again}
    assert before.keys() == after.keys()
    np.testing.assert_allclose([after[k] for k in before], [before[k] for k in before], rtol=1e-9)


def _plant_cache() -> tuple[str, int, int]:
    """Fly the plant one step; where its compiled step's cache is, and how many times this
    process loaded it from there or compiled it."""
    from testbed.simulation import plant

    plant.Plant().step()
    return plant.step_cache()


def test_workers_load_the_compiled_step_from_the_cache_this_process_fills(cluster):
    c, client = cluster
    path, _, _ = _plant_cache()  # compiled here if the cache is empty, then on disk
    client.restart()  # new worker processes, nothing compiled in them
    for where, (their_path, hits, misses) in client.run(_plant_cache).items():
        assert (their_path, hits, misses) == (path, 1, 0), where


@pytest.mark.parametrize("address", ["tcp://127.0.0.1:1", "not an address"])
def test_a_scheduler_that_does_not_answer_is_an_error_before_anything_is_written(tmp_path, address):
    with pytest.raises(InputError, match=f"scheduler={address}: cannot connect"):
        campaign.reproduce(tmp_path / "study", seeds=1, scheduler=address, **TINY)
    assert list(tmp_path.iterdir()) == []


def test_a_cell_whose_run_cannot_be_read_fails_with_the_files_reason(tmp_path, cluster):
    """A cached run whose measurement file was cut short: each cell on it is recorded as failed,
    its reason naming the file, and the results, verdicts and report are still written."""
    c, client = cluster
    out = tmp_path / "study"
    campaign.make_folder(out)
    broken = Path(campaign.load_run(str(out), "II", 1, TINY["duration"])[0][0].source)
    broken.write_bytes(broken.read_bytes()[:200])  # mid-row: a short last row
    done = campaign.reproduce(out, seeds=1, scheduler=c.scheduler_address, **TINY)
    assert done.failed == len(TINY["methods"]) and done.computed == len(TINY["methods"])
    rows = read_results(out / "results.csv")
    assert {r["method"] for r in rows} == set(TINY["methods"])
    for r in rows:
        assert r["status"] == "failed" and r["coefficient"] == "" and not r["converged"]
        assert r["reason"].startswith("InputError: ") and str(broken) in r["reason"], r["reason"]
    verdicts = json.loads((out / "conclusions.json").read_text())
    assert not any(v["holds"] for v in verdicts.values())
    assert (out / "report.html").is_file()
