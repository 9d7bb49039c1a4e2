"""Sparse records in the equation-error method and the ML methods' starts: missing samples,
channels at a fraction of the rows, states not measured. A start that cannot be computed is
skipped with its reason, and the others run."""

from __future__ import annotations

import csv
import json
from dataclasses import replace

import numpy as np
import pytest

from testbed import METHODS
from testbed.cli import main
from testbed.errors import InputError
from testbed.estimators import equation_error, identify
from testbed.estimators.intervals import between_present
from studies.remus import EXAMPLE_COEFFICIENTS, FREE, experiments, prior_config
from testbed.identification.problem import problem
from testbed.models.linear import STATES
from testbed.simulation.runs import simulate


def test_a_window_with_too_few_samples_present_is_missing_never_a_singular_cubic():
    """A cubic through three samples is not determined: over a 5-sample window with fewer than
    5 present the value is missing (NaN); with all 5 it is the cubic's own value."""
    t = np.arange(12.0)
    y = (1 + 0.5 * t - 0.1 * t**3)[:, None]
    present = np.ones((12, 1), bool)
    present[[3, 5], 0] = False  # the windows centred at 3, 4 and 5 hold 3 of their 5 samples
    out = equation_error.smoothed(np.where(present, y, np.nan), 5, present)[:, 0]
    full = np.array([present[k : k + 5].all() for k in range(8)])  # windows centred at 2 … 9
    assert np.isnan(out[~full]).all() and full.sum() == 2
    np.testing.assert_allclose(out[full], y[2:-2, 0][full])


def test_a_channel_at_half_the_rows_is_smoothed_over_its_own_samples():
    """Present every other row, a cubic channel is smoothed where the window holds half of the
    samples its rate gives (here 3 of 5 in 11 rows, at least 5): its own value."""
    t = np.linspace(0, 3, 41)
    y = (2 - t + 0.3 * t**3)[:, None]
    present = np.zeros((41, 1), bool)
    present[::2] = True
    out = equation_error.smoothed(np.where(present, y, np.nan), 11, present)[:, 0]
    assert np.isfinite(out).sum() >= len(out) // 2
    np.testing.assert_allclose(out[np.isfinite(out)], y[5:-5, 0][np.isfinite(out)], rtol=1e-9)


def test_the_intervals_run_between_present_samples_with_the_fins_mean_over_them():
    """x = t² sampled at uneven stamps with rows missing: the quotient over [a, b] is a + b, the
    midpoint (a² + b²)/2, and the fins held at each row average over the rows in between."""
    t = np.array([0.0, 0.5, 1.5, 2.0, 3.5, 4.0])
    x = np.column_stack([t**2, t])
    x[2, 0] = np.nan  # a missing sample: the interval runs from 0.5 to 2.0
    x[4, 1] = np.nan
    fins = np.column_stack([np.arange(6.0), -np.arange(6.0), np.zeros(6)])
    xdot, mid, mean = between_present(t, x, fins)
    a, b = np.array([0.0, 0.5, 2.0]), np.array([0.5, 2.0, 4.0])  # rows 0, 1, 3, 5
    np.testing.assert_allclose(xdot, np.column_stack([a + b, np.ones(3)]))
    np.testing.assert_allclose(mid, np.column_stack([(a**2 + b**2) / 2, (a + b) / 2]))
    held = [0.0, (1 * 1.0 + 2 * 0.5) / 1.5, (3 * 1.5 + 4 * 0.5) / 2.0]  # ∫ δ dt / span
    np.testing.assert_allclose(mean[:, 0], held)
    np.testing.assert_allclose(mean[:, 1], -np.array(held))


def _sparse(e, rng):
    """10 % of the rows missing, a run of sway samples and pitch at every other row."""
    y = e.y.copy()
    n = len(y)
    y[rng.choice(np.arange(1, n - 1), n // 10, replace=False)] = np.nan
    y[100:112, e.measured.index("v")] = np.nan
    y[1::2, e.measured.index("theta")] = np.nan
    return replace(e, y=y)


def test_equation_error_regresses_a_sparse_record_sampled_at_ten_hertz():
    """Noise-free data at 0.1 s (a 5-sample window) with rows, a run and every other pitch
    sample missing: every row regressed, each coefficient within 20 % of the truth (a start
    well inside output error's basin) from a prior 30 % off."""
    rng = np.random.default_rng(1)
    data = [_sparse(e, rng) for e in experiments(seed=0, duration=30.0, dt=0.1, noise=None)]
    got, left = equation_error.regression(problem(data, prior_config()))
    assert left == {}
    want = np.array([EXAMPLE_COEFFICIENTS[n] for n in FREE])
    np.testing.assert_allclose(got, want, rtol=0.2)


def test_a_start_that_cannot_be_computed_is_skipped_with_its_reason_and_the_others_run():
    """No rate gyro (p, q, r missing): every row involves a rate, so equation error supports no
    row; the fit runs from the other starts and `starts` names why equation error did not."""
    data = [
        e.only(("u", "v", "w", "phi", "theta", "psi")) for e in experiments(seed=0, duration=20.0, dt=0.1)
    ]
    config = prior_config()
    with pytest.raises(InputError, match="start='equation-error': no free coefficient's row"):
        identify(data, config, method="ml-gn", start="equation-error")
    est = identify(data, config, method="ml-gn")
    assert est.converged and est.start in ("config", "mekf")
    skipped = [s for s in est.starts if s["start"] == "equation-error"]
    assert len(skipped) == 1 and skipped[0]["status"] == "not computed"
    assert "no experiment measures r" in skipped[0]["reason"]
    assert "equation-error: not computed" in est.start_reason
    assert est.json_fields()["starts"][-1]["cost"] is None


def test_with_the_a_priori_start_alone_computable_the_best_box_draw_is_the_second():
    """No rate gyro and an attitude offset free: equation error regresses no row and the MEKF
    refuses the free offset, so `auto` would have one start; the best of `global`'s box draws is
    run as the second, both named in `starts`, the least cost kept."""
    data = [
        e.only(("u", "v", "w", "phi", "theta", "psi")) for e in experiments(seed=0, duration=20.0, dt=0.1)
    ]
    est = identify(data, replace(prior_config(), free=FREE + ("b_phi",)), method="ml-gn")
    tried = {s["start"]: s for s in est.starts}
    assert [s for s in tried if tried[s]["status"] != "not computed"] == ["config", "box-1"]
    assert {"equation-error", "mekf"} <= set(tried) and est.converged
    assert est.cost == min(tried[s]["cost"] for s in ("config", "box-1"))
    assert "least cost of 2 starts" in est.start_reason


def test_rows_left_at_their_a_priori_values_are_named_in_the_starts():
    """Roll rate missing: the rows that involve p keep their a-priori values in the
    equation-error start, named with the reason in its `starts` entry; a fit from a box draw
    or the MEKF's stands beside it."""
    data = [
        e.only(("u", "v", "w", "q", "r", "phi", "theta", "psi"))
        for e in experiments(seed=0, duration=20.0, dt=0.1)
    ]
    est = identify(data, prior_config(), method="ml-gn")
    entry = next(s for s in est.starts if s["start"] == "equation-error")
    assert "K_p" in entry["left"] and "no experiment measures p" in entry["left"]["K_p"]
    assert "Z_w" not in entry["left"]
    # not a whole second start: where no MEKF fit ran, the best box draw is one more
    ran = {s["start"] for s in est.starts if s["status"] != "not computed"}
    assert "box-1" in ran or "mekf" in ran


def _degraded_copy(src, dst, rng, course=0.0):
    """The CSV `src` as a logger gives it: 10 % of its rows dropped, 2 % of the state samples
    empty, the heading turned by `course` and wrapped into (−π, π]."""
    with open(src) as f:
        rows = list(csv.reader(f))
    head, data = rows[0], np.array(rows[1:], float)
    data = np.delete(data, rng.choice(np.arange(1, len(data) - 1), len(data) // 10, replace=False), axis=0)
    k = head.index("psi")
    data[:, k] = (data[:, k] + course + np.pi) % (2 * np.pi) - np.pi
    states = [i for i, c in enumerate(head) if c in STATES]
    gaps = rng.random((len(data), len(states))) < 0.02
    gaps[0] = False  # the first row keeps its states
    data[:, states] = np.where(gaps, np.nan, data[:, states])
    with open(dst, "w", newline="") as f:
        out = csv.writer(f)
        out.writerow(head)
        out.writerows([["" if np.isnan(x) else repr(float(x)) for x in row] for row in data])


@pytest.fixture(scope="module")
def degraded(tmp_path_factory):
    """A short Scenario II run's horizontal and vertical records degraded as a logger gives them."""
    run = simulate("II", seed=4, duration=12.0, out=tmp_path_factory.mktemp("r") / "II")
    rng = np.random.default_rng(5)
    for name in ("horizontal", "vertical"):
        _degraded_copy(run / f"{name}.csv", run.parent / f"{name}.csv", rng, course=np.radians(175))
    return run.parent, run / "model.toml"


@pytest.mark.parametrize("method", sorted(METHODS))
def test_every_method_runs_end_to_end_on_a_record_with_gaps(degraded, tmp_path, capsys, method):
    """Rows dropped, samples missing, the heading wrapped: every method fits (exit 0, or 1 where
    its iteration limit stops it), `ml-fem` refuses the dropouts with a one-line reason (its
    steady-state filter needs the samples at a fixed period); none exits 70."""
    folder, config = degraded
    out = tmp_path / "fit.json"
    limit = {"ml-nr": ["--max-iter", "3"], "ml-nm": ["--max-iter", "40"]}.get(method, [])
    argv = ["identify", folder / "horizontal.csv", folder / "vertical.csv", "--config", config]
    code = main([str(a) for a in argv + ["--method", method, "--out", out] + limit])
    err = capsys.readouterr().err
    if method == "ml-fem":
        assert code == 2 and "dropouts" in err.splitlines()[-1]
        return
    assert code in (0, 1), err
    doc = json.loads(out.read_text())
    assert doc["coefficients"] and all(np.isfinite(c["value"]) for c in doc["coefficients"].values())
