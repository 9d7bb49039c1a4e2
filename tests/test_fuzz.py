"""The bad-input corpus of `studies/fuzz.py`: no crash, no partial output, in this process and in
real `python -m testbed` processes (where a traceback or a C library's message would show)."""

import pytest

from studies.fuzz import corpus, run_case, run_subprocess, tally, time_cases, workspace


@pytest.fixture(scope="module")
def ws(tmp_path_factory):
    return workspace(tmp_path_factory.mktemp("ws"))


def _check(ws, cases, runner=None):
    outcomes = [run_case(ws, c, *([runner] if runner else [])) for c in cases]
    bad = [(o.label, o.code, o.partial, o.err[-400:]) for o in outcomes if o.kind == "crash" or o.partial]
    assert not bad, bad
    return tally(outcomes)


def test_every_fourth_case_of_the_corpus(ws):
    counts = _check(ws, corpus(ws)[::4])
    assert counts["errors"] > counts["ok"] > 0  # the corpus is mostly bad input, and some runs succeed


def test_an_output_through_a_link_replaces_its_file_only_with_force(ws):
    """`--out link.txt` (a link to keep.txt, a user's file): refused, nothing changed; with
    `--force` the file the link names is replaced and the link stays: the judge counts it as the
    output, and a change to any other file would still be partial."""
    from studies.fuzz import judge

    by_label = {c.label: c for c in corpus(ws)}
    refused = run_case(ws, by_label["analytic --out link.txt"])
    assert refused.code == 2 and refused.kind == "error" and not refused.partial
    forced = run_case(ws, by_label["analytic --out link.txt --force"])
    assert forced.code == 0 and not forced.partial
    argv = ("analytic", "--out", "link.txt", "--force")
    before = {"link.txt": "link:keep.txt", "keep.txt": "a", "data/h.csv": "b"}
    assert judge(argv, 0, "", "", before, {**before, "keep.txt": "c"})[1] == ""
    assert judge(argv, 0, "", "", before, {**before, "data/h.csv": "c"})[1] == "data/h.csv"


@pytest.mark.slow
def test_the_whole_corpus(ws):
    counts = _check(ws, corpus(ws))
    assert counts["cases"] > 400


def test_real_processes_print_one_line_and_no_traceback(ws):
    cases = [c for c in corpus(ws) if c.label.startswith("issue:")]
    cases += [
        c
        for c in corpus(ws)
        if c.label
        in ("csv long cell @0", "config N_rdot=3.45", "manifest deep", "identify --method mekf --out null")
    ]
    counts = _check(ws, cases, run_subprocess)
    assert counts["errors"] >= 8


def test_bad_time_gaps_and_priors_end_in_one_line_or_a_fit(ws):
    """Each time-and-gap mutation through `analyze`, and every prior case: decreasing, repeated and
    duplicated stamps, huge gaps, single-row segments, all-NaN channels, NaN spellings, stale
    repeats, a course-unstable linear prior and overflowing priors of both models."""
    cases = [c for c in time_cases(ws) if c.label.startswith("prior:") or c.label.endswith("(analyze)")]
    counts = _check(ws, cases)
    assert counts["errors"] > counts["ok"] > 0


@pytest.mark.slow
def test_every_time_and_prior_case_in_real_processes(ws):
    counts = _check(ws, time_cases(ws), run_subprocess)
    assert counts["cases"] > 50
