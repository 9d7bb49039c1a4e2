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
