"""The campaign (`testbed reproduce`): cells on a real two-worker Dask LocalCluster, resumed after
a crash and surviving a worker killed mid-run; the plan, the keys, and the judge's bookkeeping
on cells built by hand."""

import contextlib
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

from testbed.errors import InputError
from testbed.study import campaign, cells, hashing
from testbed.study.arms import ARMS, DEFAULT_ARMS, FACTORIAL_ARMS
from testbed.study.campaign import plan
from testbed.study.arms import NONLINEAR_ARM, NONLINEAR_ARMS
from testbed.study.cells import OPTIMUM, Cell
from testbed.simulation.vehicle import vehicles
from testbed.study.results import (
    SUMMARY_COLUMNS,
    judgements,
    read_results,
    results_csv,
    results_rows,
    summary_table,
)

TINY = dict(
    scenarios=("II",),
    truths=("plant",),
    factorial=(),
    arms=("ml-gn", "mekf-paper"),
    spreads=(0.3,),
    duration=4.0,
)


def test_a_cell_key_follows_the_code(tmp_path, monkeypatch):
    """Editing any source or data file a cell computes with changes the hash and so every cell's
    key; editing a module that only reads finished cells does not, nor do compiled caches."""
    package, models = tmp_path / "testbed", tmp_path / "mjcf"
    shutil.copytree(
        Path(campaign.__file__).resolve().parents[1], package, ignore=shutil.ignore_patterns("*.pyc")
    )
    shutil.copytree(vehicles(), models)
    before = hashing.source_hash(package, models)
    assert hashing.source_hash(package) != before  # the vehicle models are among what is hashed
    (package / "__pycache__").mkdir(exist_ok=True)
    (package / "__pycache__" / "x.cpython-311.pyc").write_bytes(b"compiled")
    assert hashing.source_hash(package, models) == before
    for path in (
        package / "identification/likelihood.py",
        package / "simulation/scenarios/II.toml",
        models / "torpedo.xml",
    ):
        text = path.read_bytes()
        path.write_bytes(text + b"\n")
        assert hashing.source_hash(package, models) != before, path
        path.write_bytes(text)
    for edited in ("presentation/figures.py", "study/rules.py", "study/results.py", "cli.py"):
        path = package / edited  # read finished cells only: the same cells, rewritten outputs
        text = path.read_bytes()
        path.write_bytes(text + b"\n")
        assert hashing.source_hash(package, models) == before, edited
        path.write_bytes(text)
    assert hashing.source_hash(package, models) == before
    key = Cell("II", "ml-gn", 1).key
    monkeypatch.setattr(cells, "code_hash", lambda: "other code")
    assert Cell("II", "ml-gn", 1).key != key


def test_plan_pairs_every_arm_with_the_optimum_per_data_set_seed_and_spread():
    found = plan(2, spreads=(0.2, 0.4))
    main = [(s, t) for s in campaign.SCENARIOS for t in campaign.TRUTHS]
    factorial = [(s, "plant") for s in campaign.FACTORIAL]
    expected = {
        (s, t, sp, a, k)
        for s, t in main
        for sp in (0.2, 0.4)
        for a in (OPTIMUM, *(x for x in DEFAULT_ARMS if x in ARMS))
        for k in (1, 2)
    }
    # Scenario I on the plant: the nonlinear model, judged against the captive reference; on no
    # other data set
    expected |= {("I", "plant", sp, NONLINEAR_ARM, k) for sp in (0.2, 0.4) for k in (1, 2)}
    expected |= {
        (s, t, sp, a, k)
        for s, t in factorial
        for sp in (0.2, 0.4)
        for a in (OPTIMUM, *(x for x in DEFAULT_ARMS if x in FACTORIAL_ARMS))
        for k in (1, 2)
    }
    assert {(c.scenario, c.truth, c.spread, c.arm, c.seed) for c in found} == expected
    assert len(found) == len(expected)
    assert len({c.key for c in found}) == len(found)
    assert Cell("I", "ml-gn", 1).key != Cell("I", "ml-gn", 1, duration=30.0).key  # the data differ
    assert Cell("I", "ml-gn", 1).key != Cell("I", "ml-gn", 1, truth="linear").key
    assert Cell("I", "ml-gn", 1).key != Cell("I", "ml-gn", 1, spread=0.4).key
    assert all(c.duration == campaign.QUICK_DURATION for c in plan(1, quick=True))
    assert {c.arm for c in plan(1, arms=("all",))} == {OPTIMUM, *NONLINEAR_ARMS, *ARMS}
    assert not any(c.arm in NONLINEAR_ARMS for c in plan(1, scenarios=("II",), factorial=()))
    # a nonlinear arm alone: Scenario I on the plant's nonlinear cells, no optimum search
    only = plan(1, arms=("equation-error-nonlinear",), spreads=(0.4,))
    assert {(c.scenario, c.truth, c.arm) for c in only} == {
        ("I", "plant", NONLINEAR_ARM),
        ("I", "plant", "equation-error-nonlinear"),
    }
    # without Scenario II among the scenarios its PRBS level is still fitted by conclusion 3's arm
    alone = plan(1, scenarios=("I",), spreads=(0.4,))
    assert {c.arm for c in alone if c.scenario == "II"} == {OPTIMUM, "ml-nm-paper", "ml-gn"}
    assert {c.arm for c in alone if c.scenario == "inputs-square"} == {OPTIMUM, "ml-gn"}
    with pytest.raises(InputError, match="seeds=0"):
        plan(0)
    with pytest.raises(InputError, match="arm 'ml-xx' is unknown"):
        plan(1, arms=("ml-xx",))
    for bad in (-0.1, math.inf, math.nan, 4.0, True):
        with pytest.raises(InputError, match="start spread"):
            plan(1, spreads=(bad,))
    with pytest.raises(InputError, match="none given; expected at least one number from 0 to 3$"):
        plan(1, spreads=())
    with pytest.raises(InputError, match="truth 'wind'"):
        plan(1, truths=("wind",))


def test_the_cells_run_seed_by_seed_each_seeds_nonlinear_fits_first():
    cells = plan(2, spreads=(0.2, 0.4), arms=(*DEFAULT_ARMS, "mekf-nonlinear"))
    order = campaign.run_order(cells)
    assert sorted(c.key for c in order) == sorted(c.key for c in cells)
    assert [c.seed for c in order] == sorted(c.seed for c in cells)  # a stopped campaign has whole seeds
    for seed in (1, 2):
        arms = [c.arm for c in order if c.seed == seed]
        assert arms[:4] == [NONLINEAR_ARM, "mekf-nonlinear"] * 2 and not set(NONLINEAR_ARMS) & set(arms[4:])
        rest = [c.key for c in cells if c.seed == seed and c.arm not in NONLINEAR_ARMS]
        assert [c.key for c in order if c.seed == seed][4:] == rest  # the plan's order otherwise


def test_every_output_error_arm_starts_where_it_says_never_from_the_default_starts():
    """The default start (auto) would also try the equation-error and MEKF starts: an arm starts
    from the paired a-priori model unless it is about another start."""
    from testbed.estimators import lookup

    starts = {a.name: a.options.get("start") for a in ARMS.values() if lookup(a.method).starts}
    assert starts.pop("mekf+ml-gn") == "mekf" and starts.pop("ml-gn-global") == "global"
    assert set(starts.values()) == {"config"}, starts


def test_seeds_are_bounded_before_the_plan_is_built():
    one = dict(arms=("ml-gn",), scenarios=("II",), truths=("plant",), factorial=())
    assert len(plan(campaign.MAX_SEEDS, **one)) == 2 * campaign.MAX_SEEDS  # the optimum and the arm
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
    assert sorted(p.name for p in (tmp_path / "empty").iterdir()) == [campaign.CAMPAIGN_MARKER, "cells"]
    (tmp_path / "empty" / "results.csv").write_text("the campaign's\n")
    campaign.check_folder(tmp_path / "empty")  # a campaign's folder: resumed


def _doc(arm, seed, values, cost, status="converged", std=0.1, spread=0.4, truth="linear"):
    """A finished cell as run_cell writes it, of two coefficients with analytic values 1 and 2."""
    free = ["A", "B"]
    return {
        "key": f"{arm}-{seed}-{spread}",
        "cell": {
            "scenario": "II",
            "arm": arm,
            "seed": seed,
            "spread": spread,
            "truth": truth,
            "duration": None,
        },
        "status": status,
        "reason": "",
        "converged": status == "converged",
        "iterations": 5,
        "evaluations": 50,
        "wall_time_s": 1.0,
        "free": free,
        "analytic": {"A": 1.0, "B": 2.0},
        "values": dict(zip(free, values)),
        "std": {n: std for n in free},
        "cost": cost,
    }


def test_each_arm_is_judged_against_the_lowest_cost_found_on_its_data():
    docs = [
        _doc(OPTIMUM, 1, [1.0, 2.0], 100.0),
        _doc("ml-gn", 1, [1.001, 2.0], 100.0),  # at the optimum: 0.01 σ
        _doc("ml-nr", 1, [1.3, 2.0], 100.2, status="max iterations"),  # 3 σ off, inside the region
        _doc("ml-nr-scaled", 1, [1.3, 2.0], 103.1, status="max iterations"),  # outside: stalled
        _doc("ml-nm-paper", 1, [5.0, 2.0], 140.0),  # converged at another minimum
        _doc("mekf-paper", 1, [math.nan, 2.0], math.inf, status="diverged"),
        # seed 2: an arm found a lower cost than the optimum search: it is the optimum
        _doc(OPTIMUM, 2, [1.0, 2.0], 100.0),
        _doc("ml-gn", 2, [1.0, 2.0], 100.0),
        _doc("ml-nm-paper", 2, [0.5, 2.0], 80.0),
        _doc("drift-mt", 1, [1.0, 2.0], 100.0),
    ]
    got = {k: (v[0].outcome.name.lower() if v else None) for k, v in judgements(docs).items()}
    assert got == {
        "ml-gn-1-0.4": "success",
        "ml-nr-1-0.4": "success",
        "ml-nr-scaled-1-0.4": "stalled",
        "ml-nm-paper-1-0.4": "elsewhere",
        "mekf-paper-1-0.4": "diverged",
        "ml-gn-2-0.4": "elsewhere",
        "ml-nm-paper-2-0.4": "success",
    }
    rows = results_rows(docs)
    assert {r["arm"] for r in rows} == {
        "ml-gn",
        "ml-nr",
        "ml-nr-scaled",
        "ml-nm-paper",
        "mekf-paper",
        "drift-mt",
    }
    assert {r["outcome"] for r in rows if r["arm"] == "drift-mt"} == {""}  # not judged
    nm2 = [r for r in rows if r["arm"] == "ml-nm-paper" and r["seed"] == 2]
    assert [r["optimum"] for r in nm2] == [0.5, 2.0]
    # ... which the search missed: 20 below it, counted against the search
    assert {r["search_delta_cost"] for r in nm2} == {-20.0}
    assert [r["search_delta_cost"] for r in rows if r["arm"] == "ml-nr"] == [pytest.approx(0.2)] * 2
    # accuracy in the optimum's σ (0.1 here), whatever the cell's own
    assert {r["optimum_std"] for r in rows if r["arm"] == "ml-nr"} == {0.1}


def test_the_summary_counts_outcomes_with_wilson_intervals(tmp_path):
    docs = [_doc(OPTIMUM, k, [1.0, 2.0], 100.0) for k in range(1, 11)]
    docs += [
        _doc("ml-gn", k, [1.0 if k <= 7 else 9.0, 2.0], 100.0 if k <= 7 else 150.0) for k in range(1, 11)
    ]
    (tmp_path / "results.csv").write_text(results_csv(results_rows(docs)))
    (row,) = summary_table(read_results(tmp_path / "results.csv"))
    assert (row["cells"], row["success"], row["judged"], row["elsewhere"]) == (10, 7, 10, 3)
    # Wilson's interval for 7/10 at 95 %: (p + z²/2n ± z √(p(1−p)/n + z²/4n²)) / (1 + z²/n)
    z, n, p = 1.959963984540054, 10, 0.7
    centre, half = (
        (p + z**2 / (2 * n)) / (1 + z**2 / n),
        z * math.sqrt(p * (1 - p) / n + z**2 / (4 * n**2)) / (1 + z**2 / n),
    )
    assert row["success_low"] == pytest.approx(centre - half) and row["success_high"] == pytest.approx(
        centre + half
    )
    assert row["accurate"] == 7  # the other three are 800 % off with σ 0.1
    assert (row["beat_search"], row["min_search_delta_cost"]) == (0, 0.0)
    written = results_csv([row], SUMMARY_COLUMNS).splitlines()
    assert written[0] == ",".join(SUMMARY_COLUMNS)
    assert dict(zip(SUMMARY_COLUMNS, written[1].split(",")))["success"] == "7"


@contextlib.contextmanager
def _local_cluster(workers: int):
    """A Dask cluster of `workers` fresh worker processes on this machine, and its client."""
    import logging

    from dask.distributed import Client, LocalCluster

    with (
        LocalCluster(
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            silence_logs=logging.ERROR,
        ) as c,
        Client(c) as client,
    ):
        yield c, client


@pytest.fixture(scope="module")
def cluster():
    with _local_cluster(2) as c_client:
        yield c_client


def _check_outputs(out, planned):
    files = sorted(p.name for p in (out / "cells").glob("*.json"))
    assert files == sorted(f"{c.key}.json" for c in planned)  # every cell once, nothing else
    rows = read_results(out / "results.csv")
    keys = [(r["scenario"], r["truth"], r["spread"], r["arm"], r["seed"], r["coefficient"]) for r in rows]
    assert len(keys) == len(set(keys))  # no duplicates
    assert {(r["scenario"], r["arm"], r["seed"]) for r in rows} == {
        (c.scenario, c.arm, c.seed) for c in planned if c.arm != OPTIMUM
    }
    verdicts = json.loads((out / "conclusions.json").read_text())
    assert set(verdicts) == {"1", "2-nr", "2-nm", "3", "mekf"}
    assert all(v["holds"] in (True, False, None) for v in verdicts.values())
    html = (out / "report.html").read_text()
    for name in ("success-spread.png", "fig5-inputs-II.png", "fig6-coefficients-II.png", "iterations-II.png"):
        assert f"src='{name}'" in html and (out / name).read_bytes()[:4] == b"\x89PNG"
    assert (out / "report.rrd").stat().st_size > 0
    for name in ("summary.csv", "regime.json", "drift.json"):
        assert (out / name).is_file()
    return rows


def test_campaign_on_two_workers_survives_a_killed_worker_and_resumes(tmp_path, cluster):
    c, client = cluster
    out = tmp_path / "study"
    planned = plan(2, **{k: v for k, v in TINY.items()})
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
    assert done.computed == len(planned) and done.reused == 0
    rows = _check_outputs(out, planned)
    assert all(r["status"] != "failed" for r in rows), [r["reason"] for r in rows if r["status"] == "failed"]
    # the arms of a seed start from one a-priori model, another seed's is another
    docs = [json.loads(p.read_text()) for p in (out / "cells").glob("*.json")]
    starts = {}
    for d in docs:
        if d["cell"]["arm"] != OPTIMUM:
            starts.setdefault(d["cell"]["seed"], []).append(d["start"])
    assert all(len({json.dumps(x, sort_keys=True) for x in v}) == 1 for v in starts.values()), starts
    assert starts[1][0] != starts[2][0]
    assert {r["outcome"] for r in rows} <= {"success", "diverged", "stalled", "elsewhere"}
    assert all(r["evaluations"] > 0 for r in rows)

    # a crash after some cells: they are kept, only the missing one and one whose file was cut
    # short are computed again
    lost, cut = planned[1], planned[2]
    (out / "cells" / f"{lost.key}.json").unlink()
    path = out / "cells" / f"{cut.key}.json"
    path.write_bytes(path.read_bytes()[:100])
    kept = {p.name: p.stat().st_mtime_ns for p in (out / "cells").glob("*.json") if p != path}
    again = campaign.reproduce(out, seeds=2, scheduler=c.scheduler_address, **TINY)
    assert again.computed == 2 and again.reused == len(planned) - 2
    assert {p.name: p.stat().st_mtime_ns for p in (out / "cells").glob("*.json") if p.name in kept} == kept
    rows_again = _check_outputs(out, planned)
    before = {(r["arm"], r["seed"], r["coefficient"]): r["estimate"] for r in rows}
    after = {(r["arm"], r["seed"], r["coefficient"]): r["estimate"] for r in rows_again}
    assert before.keys() == after.keys()
    np.testing.assert_allclose([after[k] for k in before], [before[k] for k in before], rtol=1e-9)


def _plant_cache() -> tuple[str, int, int]:
    """Fly the plant one step; where its compiled step's cache is, and how many times this
    process loaded it from there or compiled it."""
    from testbed.simulation.plant import Plant
    from testbed.simulation.plant_step import step_cache

    Plant().step()
    return step_cache()


def test_workers_load_the_compiled_step_from_the_cache_this_process_fills():
    path, _, _ = _plant_cache()  # compiled here if the cache is empty, then on disk
    # workers started after it, nothing compiled in them: a cluster of their own (restarting the
    # shared one's workers races with its nannies still bringing back the one another test killed)
    with _local_cluster(1) as (_, client):
        for where, (their_path, hits, misses) in client.run(_plant_cache).items():
            assert (their_path, hits, misses) == (path, 1, 0), where


@pytest.mark.parametrize(
    "address, why",
    [("tcp://127.0.0.1:1", "ConnectionRefusedError"), ("not an address", "missing port number")],
)
def test_a_scheduler_that_does_not_answer_is_an_error_before_anything_is_written(tmp_path, address, why):
    """A port nothing listens on is refused by the first plain connection (Dask's client would
    retry it for `CONNECT_S`); a malformed address is Dask's own error."""
    with pytest.raises(InputError, match=f"scheduler={address}: cannot connect \\(.*{why}"):
        campaign.reproduce(tmp_path / "study", seeds=1, scheduler=address, **TINY)
    assert list(tmp_path.iterdir()) == []


def test_a_cell_whose_run_cannot_be_read_fails_with_the_files_reason(tmp_path, cluster):
    """A cached run whose measurement file was cut short: each cell on it is recorded as failed,
    its reason naming the file, and the results, verdicts and report are still written."""
    c, client = cluster
    out = tmp_path / "study"
    campaign.make_folder(out)
    broken = Path(cells.load_run(str(out), "II", "plant", 1, TINY["duration"])[0][0].source)
    broken.write_bytes(broken.read_bytes()[:200])  # mid-row: a short last row
    done = campaign.reproduce(out, seeds=1, scheduler=c.scheduler_address, **TINY)
    n = len(TINY["arms"]) + 1  # and the optimum
    assert done.failed == n and done.computed == n
    rows = read_results(out / "results.csv")
    assert {r["arm"] for r in rows} == set(TINY["arms"])
    for r in rows:
        assert r["status"] == "failed" and r["coefficient"] == "" and not r["converged"]
        assert r["reason"].startswith("InputError: ") and str(broken) in r["reason"], r["reason"]
    verdicts = json.loads((out / "conclusions.json").read_text())
    assert not any(v["holds"] for v in verdicts.values())
    assert (out / "report.html").is_file()


@pytest.mark.parametrize(
    "arm, limit",
    [("ml-nr", None), ("ml-nr-10x", 1000), ("ml-nm-paper", None), ("ml-nm-paper-10x", 5000 * 15)],
)
def test_an_arm_with_a_budget_fits_with_that_many_times_its_methods_limit(monkeypatch, arm, limit):
    """`ml-nr-10x` fits with 10 × ml-nr's 100 iterations, `ml-nm-paper-10x` with 10 × ml-nm's 500
    per free coefficient (the example's 15); the testbed's own arms leave the limit to the method."""
    from studies import remus as examples

    seen = {}

    def spy(experiments, config, method, options, callback):
        seen.update(options, free=len(config.free))
        raise RuntimeError("only the options are wanted")

    monkeypatch.setattr(cells, "identify", spy)
    data = (examples.experiments(1, duration=5.0), examples.example_config())
    begin = cells.Start(examples.prior_config(), examples.prior_config(), {}, "")
    doc = cells.run_cell(Cell("II", arm, 1, 0.3, "linear"), data, begin)
    assert doc["status"] == "failed" and seen["free"] == len(examples.FREE) == 15
    assert seen.get("max_iter") == limit
