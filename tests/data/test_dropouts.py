"""A logger's dropout: rows missing for longer than a few of the log's steps, over which the fins
moved as nothing recorded. The record is split there (`data.stretches`), each stretch with its
own initial state, instead of flown across with the fins held (docs/files.md#measurement-csv)."""

import numpy as np
import pytest

from testbed import identify
from testbed.analysis.validation import validate
from testbed.data import MAX_GAP, MIN_ROWS, read_csv, stretches, write_csv
from studies import remus as examples
from testbed.identification.prediction import synthetic
from testbed.models.linear import STATES

DT = 0.05


def _flight(seed: int, T: float = 40.0):
    """The example's first design flown for T s, its states with the example's noise."""
    t, u = next(iter(examples.inputs(T, DT, seed=seed).values()))
    e = synthetic(examples.example_config(), t, u)
    noise = np.array([examples.NOISE[s] for s in STATES])
    return t, e.y + np.random.default_rng(seed).normal(size=e.y.shape) * noise, u


def _csv(path, t, y, fins, rows):
    write_csv(path, t[rows], y[rows], fins[rows])
    return read_csv(path)


def test_a_complete_log_is_one_stretch(tmp_path):
    t, y, u = _flight(0, 10.0)
    e = _csv(tmp_path / "whole.csv", t, y, u, np.arange(len(t)))
    assert e.held is None and stretches(e) == [(0, len(t))]


def test_a_few_dropped_rows_are_bridged_a_long_dropout_splits_the_record(tmp_path):
    t, y, u = _flight(0, 20.0)
    n = len(t)
    short = np.r_[0:100, 100 + int(MAX_GAP) - 1 : n]  # a gap of MAX_GAP steps: bridged
    e = _csv(tmp_path / "short.csv", t, y, u, short)
    assert len(e.t) == n and e.held.sum() == MAX_GAP - 1 and stretches(e) == [(0, n)]
    long = np.r_[0:100, 100 + int(MAX_GAP) : n]  # one step more: split
    e = _csv(tmp_path / "long.csv", t, y, u, long)
    assert stretches(e) == [(0, 100), (100 + int(MAX_GAP), n)]


def test_rows_whose_fins_are_empty_count_as_a_dropout(tmp_path):
    """A row with its states but no fin angle: the fins there are held, not logged; a long run
    of such rows splits the record and its states are left out."""
    t, y, u = _flight(1, 20.0)
    fins = u.copy()
    fins[150:200] = np.nan
    write_csv(tmp_path / "fins.csv", t, y, fins)
    e = read_csv(tmp_path / "fins.csv")
    assert e.held.sum() == 50 and np.isfinite(e.inputs).all()
    assert stretches(e) == [(0, 150), (200, len(t))]


def test_a_dropout_at_the_end_ends_the_last_stretch_and_a_short_island_is_left_out(tmp_path):
    t, y, u = _flight(2, 20.0)
    n = len(t)
    rows = np.r_[0:200, 250 : 250 + MIN_ROWS - 1, 300:350, n - 1]
    e = _csv(tmp_path / "island.csv", t, y, u, rows)
    assert stretches(e) == [(0, 200), (300, 350)]


@pytest.fixture(scope="module")
def gapped(tmp_path_factory):
    """Two records of the example with a 4 s dropout each while the fins move, as one log per
    record and as its two stretches in separate logs."""
    tmp = tmp_path_factory.mktemp("gapped")
    logs, halves = [], []
    for seed, (a, b) in ((3, (200, 280)), (4, (450, 530))):
        t, y, u = _flight(seed)
        assert np.any(np.diff(u[a - 1 : b + 1], axis=0) != 0), "the fins must move in the gap"
        n = len(t)
        logs.append(_csv(tmp / f"rec{seed}.csv", t, y, u, np.r_[0:a, b:n]))
        halves += [
            _csv(tmp / f"rec{seed}_a.csv", t, y, u, np.arange(a)),
            _csv(tmp / f"rec{seed}_b.csv", t, y, u, np.arange(b, n)),
        ]
    return logs, halves


def test_a_log_with_a_dropout_fits_as_its_stretches_given_apart(gapped):
    """`ml-gn` (default options, from the a-priori values) on the logs with their dropouts lands
    where it lands on the same stretches given as four records (the same likelihood): within
    0.01 σ, and within 4 σ of the model that flew; each stretch has its initial state, named by
    its times."""
    logs, halves = gapped
    prior = examples.prior_config()
    fit, apart = identify(logs, prior, method="ml-gn"), identify(halves, prior, method="ml-gn")
    assert fit.converged and apart.converged
    assert np.all(np.abs(fit.values - apart.values) <= 0.01 * apart.std), (
        fit.values - apart.values
    ) / apart.std
    assert np.allclose(fit.std, apart.std, rtol=1e-3)
    truth = np.array([examples.EXAMPLE_COEFFICIENTS[n] for n in fit.free])
    assert np.all(np.abs(fit.values - truth) <= 4 * fit.std), (fit.values - truth) / fit.std
    assert sorted(fit.initial_states) == [
        "rec3 0–9.95 s",
        "rec3 14–39.95 s",
        "rec4 0–22.45 s",
        "rec4 26.5–39.95 s",
    ]


def test_validation_scores_the_stretches_the_model_is_flown_over(gapped):
    """The prediction is NaN inside the dropout, finite over the stretches, and the channels the
    rudder moves are scored over them."""
    logs, halves = gapped
    prior = examples.prior_config()
    fit = identify(logs, prior, method="ml-gn")
    config = prior.with_coefficients(fit.coefficients)
    v = validate(logs, config, initial=fit.initial_states)
    gap = logs[0].held
    assert np.isnan(v.predictions["rec3"].y[gap]).all() and np.isfinite(v.predictions["rec3"].y[~gap]).all()
    for channel in ("v", "r", "psi"):
        assert v.experiments["rec3"][channel].fit_percent > 50, channel


def test_a_nonlinear_model_config_fits_a_log_with_a_dropout_as_its_stretches(tmp_path):
    """The captive polynomial model flown through doublets, logged at 0.02 s with a 1 s dropout
    while the elevator moves: `ml-gn` on the log lands where it lands on its two stretches given
    apart, and `validate` flies the model over each stretch (NaN inside the dropout)."""
    from dataclasses import replace

    from testbed.models.nonlinear_flight import fly_nonlinear
    from testbed.captive.config import captive_config
    from testbed.simulation.measurements import NOISE_STD

    free = ("Y_uv", "N_uv", "Z_uw", "M_uw")
    config = replace(captive_config(model="polynomial")[0], free=free, screen=False)
    model, theta = config.nonlinear()
    t = 0.02 * np.arange(301)
    fins = np.zeros((len(t), 3))
    fins[(t >= 0.4) & (t < 1.6), 0], fins[(t >= 1.6) & (t < 2.8), 0] = 0.05, -0.05
    fins[(t >= 2.5) & (t < 3.3), 1:], fins[(t >= 3.3) & (t < 4.1), 1:] = 0.05, -0.05
    x0 = np.array([config.vehicle.speed, 0.1, -0.1, 0.01, 0.02, -0.01, 0.02, -0.01, 0.3, 1.0])
    x = fly_nonlinear(model, theta, t, x0, fins)
    y = x + np.random.default_rng(5).normal(size=x.shape) * np.array([NOISE_STD[s] for s in STATES])
    n = len(t)
    log = _csv(tmp_path / "gapped.csv", t, y, fins, np.r_[0:130, 180:n])
    halves = [
        _csv(tmp_path / "a.csv", t, y, fins, np.arange(130)),
        _csv(tmp_path / "b.csv", t, y, fins, np.arange(180, n)),
    ]
    start = config.with_coefficients(
        {n: config.terms[n] * (1.2 if k % 2 else 0.8) for k, n in enumerate(free)}
    )
    fit = identify([log], start, "ml-gn", start="config")
    apart = identify(halves, start, "ml-gn", start="config")
    assert fit.converged and apart.converged
    assert np.all(np.abs(fit.values - apart.values) <= 0.01 * apart.std), (
        fit.values - apart.values
    ) / apart.std
    v = validate([log], config.with_coefficients(fit.coefficients), initial=fit.initial_states)
    gap = log.held
    assert gap.sum() == 50 and np.isnan(v.predictions["gapped"].y[gap]).all()
    assert np.isfinite(v.predictions["gapped"].y[~gap]).all()
