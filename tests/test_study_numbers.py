"""The README's and docs/studies.md's numbers of the paper's study are the committed campaign's:
`tools/study_numbers.py` renders its blocks from docs/figures/ and the pages hold them as rendered."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def numbers():
    spec = importlib.util.spec_from_file_location("study_numbers", ROOT / "tools" / "study_numbers.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_pages_hold_the_blocks_rendered_from_the_committed_campaign(numbers):
    for page, (name, block) in numbers.blocks().items():
        text = page.read_text(encoding="utf-8")
        assert f"{numbers.begin(name)}\n{block}\n{numbers.end(name)}" in text, (
            f"{page.name}: run tools/study_numbers.py"
        )


def test_the_committed_campaign_is_whole(numbers):
    measured = json.loads((numbers.ASSETS / "measured.json").read_text(encoding="utf-8"))
    assert set(measured) == {"commit", "command", "date", "cells", "wall_time_s", "valid"}
    summary, conclusions, drift, _ = numbers.load()
    assert set(conclusions) == set(numbers.CLAIMS)
    assert all(v["verdict"] in ("reproduced", "not reproduced", "not decided") for v in conclusions.values())
    assert summary and drift
    for figure in numbers.FIGURES:
        assert (numbers.ASSETS / figure).stat().st_size > 10_000, figure


def test_a_number_changed_by_hand_is_caught(numbers, tmp_path):
    """The check reads the numbers, not just the markers: a summary that says otherwise renders
    another block."""
    import shutil

    assets = tmp_path / "reproduce"
    shutil.copytree(numbers.ASSETS, assets)
    rows = (assets / "summary.csv").read_text(encoding="utf-8").splitlines()
    head = rows[0].split(",")
    i, j = head.index("success"), head.index("median_evaluations")
    cells = rows[1].split(",")
    cells[i], cells[j] = str(int(cells[i]) + 1), str(float(cells[j]) + 7)
    rows[1] = ",".join(cells)
    (assets / "summary.csv").write_text("\n".join(rows) + "\n", encoding="utf-8")
    assert numbers.blocks(assets) != numbers.blocks()


def test_a_claim_decided_with_ten_times_the_iteration_limit_is_shown_beside_it(numbers):
    summary, conclusions, drift, measured = numbers.load()
    longer = dict(conclusions)
    longer["2-nr"] = conclusions["2-nr"] | {
        "longer": {
            "arm": "ml-nr-10x",
            "verdict": "not reproduced",
            "holds": False,
            "evidence": "II/linear 9/10",
        }
    }
    readme = numbers.readme_block(summary, longer, drift, measured)
    assert "With ten times the iteration limit (`ml-nr-10x`): **not reproduced**." in readme
    plain = {k: {f: v for f, v in c.items() if f != "longer"} for k, c in conclusions.items()}
    assert "ml-nr-10x" not in numbers.readme_block(summary, plain, drift, measured)
    studies = numbers.studies_block(summary, longer, drift, measured)
    assert "(`ml-nr-10x`): **not reproduced**: II/linear 9/10." in studies
