"""Records read at their stamps: a log whose rows are not evenly spaced identifies the model as
the same flight logged evenly does (docs/files.md#measurement-csv: time as logged)."""

import numpy as np

from testbed import identify
from testbed.data import read_csv, write_csv
from studies import remus as examples
from testbed.identification.prediction import synthetic
from testbed.models.linear import STATES

TICK = 0.01  # s: the flights' clock, on which every stamp below lies


def _logged(tmp_path, name, stamps, levels, seed, degrade=None):
    """The REMUS-class example flown on the 0.01 s clock with `levels[k]` (3,) held from
    `stamps[k]` to the next stamp, its states sampled at the stamps with the example's noise,
    written as a measurement CSV and read back. `degrade` (a random generator): a tenth of the
    rows left out, none where a fin moves (the loop that moved it logged it), and one stamp in
    fifty a stale copy of the one before (its sample still taken at its own instant)."""
    n = int(round(stamps[-1] / TICK)) + 1
    at = np.rint(np.asarray(stamps) / TICK).astype(int)
    u = np.zeros((n, 3))
    for k, a in enumerate(at):
        u[a:] = levels[k]
    flight = synthetic(examples.example_config(), TICK * np.arange(n), u)
    noise = np.array([examples.NOISE[s] for s in STATES])
    y = flight.y[at] + np.random.default_rng(seed).normal(size=(len(at), len(STATES))) * noise
    t, fins = np.array(stamps, dtype=float), u[at]
    if degrade is not None:
        moved = np.r_[True, np.any(np.diff(fins, axis=0) != 0, axis=1)]
        keep = moved | (degrade.random(len(t)) >= 0.1)
        stale = np.flatnonzero(degrade.random(len(t)) < 0.02)
        t[stale[stale > 0]] = t[stale[stale > 0] - 1]
        t, y, fins = t[keep], y[keep], fins[keep]
    path = tmp_path / f"{name}.csv"
    write_csv(path, t, y, fins)
    return read_csv(path)


def _fits(tmp_path, label, stamps):
    """`ml-gn` (default options) from the example's a-priori values on the two designs flown
    with the fins switching on the 0.1 s instants every log below stamps."""
    records = []
    for seed, (name, (t, u)) in enumerate(examples.inputs(stamps[-1] + 1, 0.1).items()):
        levels = u[np.floor(np.asarray(stamps) / 0.1 + 1e-9).astype(int)]
        records.append(_logged(tmp_path, f"{label}_{name}", stamps, levels, 100 + seed))
    return identify(records, examples.prior_config(), method="ml-gn")


def test_alternating_stamps_identify_the_model_as_even_ones_do(tmp_path):
    """Rows 0.04 s and 0.06 s apart alternately (a 0.02 s clock, each row at its stamp): every
    coefficient within 4 σ of the model that flew, and every bound within 1.1× of the same
    flight's logged every 0.05 s (as many rows)."""
    T = 40.0
    alternating = np.r_[0.0, np.cumsum(np.tile([0.04, 0.06], int(round(T / 0.1))))]
    even = 0.05 * np.arange(int(round(T / 0.05)) + 1)
    fit, reference = _fits(tmp_path, "alternating", alternating), _fits(tmp_path, "even", even)
    assert fit.converged and reference.converged
    truth = np.array([examples.EXAMPLE_COEFFICIENTS[n] for n in fit.free])
    errors = (fit.values - truth) / fit.std
    assert np.all(np.abs(errors) < 4), dict(zip(fit.free, errors.round(2)))
    ratio = fit.std / reference.std
    assert np.all(ratio < 1.1) and np.all(ratio > 1 / 1.1), dict(zip(fit.free, ratio.round(3)))


def test_the_nonlinear_model_on_alternating_stamps_matches_its_even_sub_log(tmp_path):
    """The captive polynomial model flown on a 0.01 s clock through rudder, elevator and aileron
    doublets that switch on 0.05 s instants, logged at 0.02 s and 0.03 s alternately (each row at
    its stamp, the flight stepping to each): `ml-gn` from 20 % off lands within 1 σ of its fit to
    every other row, the log's even 0.05 s sub-log, and within 3 σ of the model that flew."""
    from dataclasses import replace

    from testbed.models.nonlinear_flight import fly_nonlinear
    from testbed.captive.config import captive_config
    from testbed.simulation.measurements import NOISE_STD

    free = ("Y_uv", "N_uv", "Z_uw", "M_uw")
    config = replace(captive_config(model="polynomial")[0], free=free, screen=False)
    model, theta = config.nonlinear()
    t = TICK * np.arange(401)

    def doublet(start, half, amplitude):
        return amplitude * (
            ((t >= start) & (t < start + half)) * 1.0 - ((t >= start + half) & (t < start + 2 * half))
        )

    a = np.radians(3.0)
    fins = np.column_stack([doublet(0.2, 0.8, a), doublet(1.5, 0.8, a), doublet(3.0, 0.4, np.radians(0.3))])
    x0 = np.array([config.vehicle.speed, 0.1, -0.1, 0.01, 0.02, -0.01, 0.02, -0.01, 0.3, 1.0])
    x = fly_nonlinear(model, theta, t, x0, fins)
    stamps = np.r_[0.0, np.cumsum(np.tile([0.02, 0.03], 80))]
    at = np.rint(stamps / TICK).astype(int)
    sigma = np.array([NOISE_STD[s] for s in STATES])
    y = x[at] + np.random.default_rng(4).normal(size=(len(at), len(STATES))) * sigma
    write_csv(tmp_path / "alternating.csv", stamps, y, fins[at])
    write_csv(tmp_path / "even.csv", stamps[::2], y[::2], fins[at][::2])
    alternating, even = read_csv(tmp_path / "alternating.csv"), read_csv(tmp_path / "even.csv")
    assert len(alternating.t) == 401 and np.allclose(np.diff(even.t), 0.05)
    start = config.with_coefficients(
        {n: config.terms[n] * (1.2 if k % 2 else 0.8) for k, n in enumerate(free)}
    )
    fit = identify([alternating], start, "ml-gn", start="config")
    sub = identify([even], start, "ml-gn", start="config")
    assert fit.converged and sub.converged
    truth = np.array([config.terms[n] for n in free])
    assert np.all(np.abs(fit.values - sub.values) <= sub.std), (fit.values - sub.values) / sub.std
    assert np.all(np.abs(fit.values - truth) <= 3 * fit.std), (fit.values - truth) / fit.std


def test_a_log_with_late_dropped_and_stale_rows_identifies_the_model_as_its_even_twin(tmp_path):
    """The example flown by a 20 Hz loop that runs up to ±20 % of its step early or late on a
    10 ms clock, the fins switching at its own stamps, logged with a tenth of the rows dropped and
    one stamp in fifty a stale copy of the one before: `ml-gn` (default options) from the
    a-priori values within 4 σ of the model that flew on every coefficient, and every bound
    within 1.2× of the same design flown and logged every 0.05 s (a tenth of the samples missing
    costs 1/√0.9 = 1.054 of σ)."""
    T, step = 30.0, 0.05
    k = np.arange(int(round(T / step)) + 1)
    rng = np.random.default_rng(11)
    late = np.round((step * k + rng.uniform(-0.2, 0.2, len(k)) * step) / TICK) * TICK
    late[0] = 0.0
    fits = {}
    for label, stamps, degrade in (("even", step * k, None), ("late", late, np.random.default_rng(12))):
        records = [
            _logged(tmp_path, f"{label}_{name}", stamps, u[k], 100 + seed, degrade)
            for seed, (name, (t, u)) in enumerate(examples.inputs(T + 1, step).items())
        ]
        fits[label] = identify(records, examples.prior_config(), method="ml-gn")
    fit, reference = fits["late"], fits["even"]
    assert fit.converged and reference.converged
    truth = np.array([examples.EXAMPLE_COEFFICIENTS[n] for n in fit.free])
    errors = (fit.values - truth) / fit.std
    assert np.all(np.abs(errors) < 4), dict(zip(fit.free, errors.round(2)))
    ratio = fit.std / reference.std
    assert np.all(ratio < 1.2), dict(zip(fit.free, ratio.round(3)))
