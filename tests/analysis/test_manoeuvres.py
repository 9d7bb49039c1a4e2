"""Manoeuvre metrics: turning circles and zigzags against closed-form trajectories, and on the
plant's own records."""

import math
import tomllib

import numpy as np
import pytest
from scipy.optimize import brentq

from testbed.analysis.instants import EXECUTE_FRACTION, crossing, executes, peak
from testbed.analysis.manoeuvres import experiment_metrics, manoeuvre, run_metrics
from testbed.analysis.track import Track, flight_track
from testbed.analysis.turning import STEADY_TOLERANCE, circle_fit, turning_circle
from testbed.analysis.zigzag import zigzag
from testbed.errors import InputError
from testbed.models.linear import IX
from testbed.simulation import runs
from testbed.simulation import flight as fl
from testbed.simulation import scenario as sc

# -- an analytic turning circle ------------------------------------------------------------------


def _circle(a, tau, U0, Us, psi_a, t_e, t):
    """A point on a straight approach at U0, heading psi_a, until t_e, then turning with
    r = a (1 − e^{−s/τ}) and speed Us + (U0 − Us) e^{−s/τ} (s = t − t_e), its velocity along its
    heading. With x = e^{−s/τ} the position N + iE after the execute is
    −τ e^{i(ψ_a − aτ)} ∫_1^x (Us + ΔU x') x'^{−iaτ−1} e^{iaτx'} dx', summed term by term
    (e^{iaτx'} as its power series): (position, heading, r, speed) at times t."""
    c, dU = a * tau, U0 - Us
    s = np.maximum(t - t_e, 0.0)
    x = np.exp(-s / tau)
    z = np.zeros_like(t, dtype=complex)
    for n in range(60):
        term = (1j * c) ** n / math.factorial(n)
        for weight, p in ((Us, 0), (dU, 1)):
            k = n + p - 1j * c
            z += weight * term * (x**k - 1.0) / k
    z *= -tau * np.exp(1j * (psi_a - c))
    z = np.where(t < t_e, U0 * (t - t_e) * np.exp(1j * psi_a), z)
    psi = psi_a + a * s - c * (1.0 - x)
    return z, psi, a * (1.0 - x), Us + dU * x


@pytest.mark.parametrize("a", [0.3, -0.3])  # starboard, port
def test_turning_circle_of_a_closed_form_trajectory(a):
    tau, U0, Us, psi_a, t_e, ramp = 2.0, 10.0, 7.0, math.radians(30), 10.0, 0.2
    t = np.arange(0.0, 150.0, 0.05)
    z, psi, r, speed = _circle(a, tau, U0, Us, psi_a, t_e, t)
    # the rudder ramps to its held angle, its EXECUTE_FRACTION passed at t_e exactly
    start = t_e - EXECUTE_FRACTION * ramp
    rudder = -0.3 * np.sign(a) * np.clip((t - start) / ramp, 0.0, 1.0)
    track = Track(t, z.real, z.imag, psi, np.zeros_like(t), r, speed, rudder, np.zeros_like(t))
    m = turning_circle(track)
    # reference: the instants of 90° and 180° by root finding on the closed-form heading
    turned = lambda s, target: abs(a) * (s - tau * (1 - math.exp(-s / tau))) - target  # noqa: E731
    s90, s180 = (brentq(turned, 0.0, 100.0, args=(g,), xtol=1e-14) for g in (math.pi / 2, math.pi))
    ref = {
        s: _circle(a, tau, U0, Us, psi_a, t_e, np.array([t_e + s]))[0][0] * np.exp(-1j * psi_a)
        for s in (s90, s180)
    }
    assert m.side == ("starboard" if a > 0 else "port")
    assert m.execute == pytest.approx(t_e, abs=1e-9)
    assert m.time_90 == pytest.approx(t_e + s90, abs=1e-4)
    assert m.time_180 == pytest.approx(t_e + s180, abs=1e-4)
    # linear interpolation between 0.05 s samples: the chord's error, U r² h²/8 ≈ 3e-4 m
    assert m.advance == pytest.approx(ref[s90].real, abs=1e-3)
    assert m.transfer == pytest.approx(np.sign(a) * ref[s90].imag, abs=1e-3)
    assert m.tactical_diameter == pytest.approx(np.sign(a) * ref[s180].imag, abs=1e-3)
    assert m.tactical_diameter > 2 * Us / abs(a)  # the build-up widens it beyond the steady circle
    # the steady turn: r within the band from s = τ ln(1/band), to the end
    assert m.steady_from == pytest.approx(t_e + tau * math.log(1 / STEADY_TOLERANCE), abs=0.05 + 1e-9)
    assert m.steady_turn_rate == pytest.approx(np.mean(r[t >= m.steady_from]), rel=1e-12)
    assert abs(a) * (1 - STEADY_TOLERANCE) < abs(m.steady_turn_rate) < abs(a)
    # the track's distance from the final circle after steady_from, U τ · 2 % · aτ, over R = Us/a
    # after steady_from the track lies within (Us |aτ| + ΔU) τ · band of the final circle (the
    # heading's lag aτ x and the speed's excess ΔU x, x ≤ band, integrated): its share of R
    bound = (Us * abs(a) * tau + (U0 - Us)) * tau * STEADY_TOLERANCE / (Us / abs(a))
    assert m.steady_diameter == pytest.approx(2 * Us / abs(a), rel=bound)
    assert m.approach_speed == pytest.approx(U0, rel=1e-12)
    assert m.steady_speed == pytest.approx(Us, rel=(U0 - Us) / Us * STEADY_TOLERANCE)
    assert m.speed_ratio == pytest.approx(Us / U0, rel=0.01)


def test_circle_fit_is_exact_on_a_circle_and_crossing_interpolates():
    angle = np.linspace(0.3, 2.0, 17)
    assert circle_fit(3 + 2.5 * np.cos(angle), -1 + 2.5 * np.sin(angle)) == pytest.approx((3, -1, 2.5))
    t = np.arange(5.0)
    y = np.array([0.0, 1.0, 3.0, 2.0, 0.0])
    assert crossing(t, y, 2.0) == 1.5 and crossing(t, y, 2.0, after=2.0) == 3.0
    assert crossing(t, y, 1.0) == 1.0 and crossing(t, y, 5.0) is None
    # the parabola through three samples of a parabola has its vertex
    tp = np.linspace(0.0, 1.0, 11)
    assert peak(tp, 2.0 - (tp - 0.437) ** 2, 0.0, 1.0) == pytest.approx((0.437, 2.0))
    # a fin going 0 → 1 → −1 → 1 in ramps: each execute where it has moved 5 %
    tf = np.linspace(0.0, 10.0, 1001)
    fin = np.interp(tf, [0, 1, 2, 4, 5, 7, 8], [0, 0, 1, 1, -1, -1, 1])
    assert executes(tf, fin, [0, 1, -1, 1, -1]) == pytest.approx([1.05, 4.05, 7.05])


# -- an analytic zigzag --------------------------------------------------------------------------


def _nomoto(psi0, r0, d0, rho, K, T):
    """Heading and yaw rate of T ṙ + r = K δ from (ψ0, r0) with δ = d0 + ρ s, in closed form."""
    C = r0 - K * d0 + K * rho * T

    def psi(s):
        return psi0 + K * d0 * s + K * rho * s**2 / 2 - K * rho * T * s + C * T * (1 - np.exp(-s / T))

    def r(s):
        return K * (d0 + rho * s) - K * rho * T + C * np.exp(-s / T)

    return psi, r


def _zigzag_reference(K, T, fin, switch, ramp, t_start, end):
    """A Nomoto ship's zigzag in closed form: rudder 0 until t_start, a ramp to +fin, then a
    reversal (`ramp` s from one side to the other) each time the heading passes the switching
    angle on the side it is swinging to. The pieces (start, ψ(s), r(s), δ(s)) and the instants
    the fin's moves start."""
    rate, pieces, state = 2 * fin / ramp, [], [0.0, 0.0, 0.0, 0.0]  # t0, ψ0, r0, δ0

    def add(rho, duration=None, side=None):  # a piece for `duration`, or until side·ψ = switch
        t0, psi0, r0, d0 = state
        psi, r = _nomoto(psi0, r0, d0, rho, K, T)
        if duration is None:
            duration = brentq(lambda s: side * psi(s) - switch, 0.0, 60.0, xtol=1e-14)
        pieces.append((t0, psi, r, lambda s: d0 + rho * s))
        state[:] = [t0 + duration, psi(duration), r(duration), d0 + rho * duration]
        return t0

    add(0.0, t_start)
    starts, side = [add(rate, fin / rate)], np.sign(K)
    while state[0] < end:
        add(0.0, side=side)
        starts.append(add(-np.sign(state[3]) * rate, 2 * fin / rate))
        side = -side
    add(0.0, 1e9)
    return pieces, starts


def _evaluate(pieces, t):
    starts = np.array([p[0] for p in pieces])
    k = np.searchsorted(starts, t, side="right") - 1
    out = np.empty((3, len(t)))
    for j, (t0, psi, r, d) in enumerate(pieces):
        on = k == j
        out[:, on] = psi(t[on] - t0), r(t[on] - t0), d(t[on] - t0)
    return out


@pytest.mark.parametrize("K", [0.5, -0.5])  # the first swing to starboard, to port
def test_zigzag_of_a_closed_form_heading(K):
    T, fin, switch, ramp, t_start = 1.5, 0.35, math.radians(20), 0.4, 1.0
    pieces, reversals = _zigzag_reference(K, T, fin, switch, ramp, t_start, 40.0)
    t = np.arange(0.0, 40.0, 0.01)
    psi, r, rudder = _evaluate(pieces, t)
    m = zigzag(t, psi, rudder, switch)
    # the executes: 5 % into each ramp (the first covers half the range)
    expected = [reversals[0] + EXECUTE_FRACTION * ramp / 2] + [
        s + EXECUTE_FRACTION * ramp for s in reversals[1:4]
    ]
    assert m.executes == pytest.approx(expected, abs=1e-9)
    assert m.initial_turning_time == pytest.approx(expected[1] - expected[0], abs=1e-9)
    assert m.period == pytest.approx(expected[3] - expected[1], abs=1e-9)
    # the overshoots: the heading where r = 0 (root of the closed-form r on its piece)
    peaks = []
    for begin, end in zip(reversals[1:3], reversals[2:4]):
        for (t0, psi_k, r_k, _), (t1, *_) in zip(pieces, pieces[1:]):
            lo, hi = max(begin, t0) - t0, min(end, t1) - t0
            if hi > lo and np.sign(r_k(lo)) != np.sign(r_k(hi)):
                s = brentq(r_k, lo, hi, xtol=1e-14)
                peaks.append((t0 + s, abs(psi_k(s))))
                break
    assert len(peaks) == 2
    assert m.peaks == pytest.approx([p[0] for p in peaks], abs=2e-3)  # the vertex of 3 samples
    # the parabola through three samples errs by up to |jump of ψ''| h²/8 where ψ'' = ṙ jumps,
    # by K ρ at a ramp's ends (elsewhere by ψ''' h³-sized amounts, under 1e-7 rad)
    kink = abs(K) * 2 * fin / ramp * 0.01**2 / 8
    assert m.first_overshoot == pytest.approx(peaks[0][1] - switch, abs=kink)
    assert m.second_overshoot == pytest.approx(peaks[1][1] - switch, abs=kink)
    assert m.first_overshoot > math.radians(1)  # a real overshoot, not a flat top
    assert m.reference == pytest.approx(_evaluate(pieces, np.array(expected[:1]))[0, 0], abs=1e-15)
    assert m.switch == switch and m.fin == pytest.approx(fin)
    measured = zigzag(t, psi, rudder)  # the switching angle read at the second execute
    at = _evaluate(pieces, np.array(expected[:2]))[0]  # ψ there, linearly interpolated: ± |ṙ| h²/8
    assert measured.switch == pytest.approx(
        abs(at[1] - at[0]), abs=np.abs(np.gradient(r, t)).max() * 0.01**2 / 8
    )


# -- on the plant --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "name, state, rate, channel",
    [("zigzag", "psi", "r", "rudder"), ("zigzag-vertical", "theta", "q", "elevators")],
)
def test_the_plants_zigzag_overshoots_are_its_records_peaks(name, state, rate, channel):
    """The overshoot is the record's largest excursion beyond the switching angle between the
    commanded reversals, to within the parabola's refinement of the sampled peak, and the
    peak instant is where the angle's rate changes sign."""
    s = sc.scenario(name).with_overrides(duration=6.0)
    (f,), _ = fl.fly_scenario(s)
    spec = s.experiments[0]
    m = experiment_metrics(spec, flight_track(f))
    angle, h = f.truth[:, IX[state]], f.t[1] - f.t[0]
    switch = spec.fins[channel].switch
    assert m.switch == switch and m.reference == angle[0]
    reversals = np.flatnonzero(np.diff(f.commands[channel])) + 1  # the commanded reversals
    sign = np.sign(angle[reversals[0]] - angle[0])
    accel = np.abs(np.gradient(f.truth[:, IX[rate]], h)).max()
    for k, overshoot in enumerate((m.first_overshoot, m.second_overshoot)):
        window = slice(reversals[k], reversals[k + 1])
        largest = (sign * (-1) ** k * (angle[window] - angle[0])).max()
        assert largest - switch <= overshoot <= largest - switch + accel * h**2 / 8
        i = np.searchsorted(f.t, m.peaks[k])
        rate_there = f.truth[i - 1 : i + 1, IX[rate]]
        assert rate_there[0] * rate_there[1] <= 0  # the rate changes sign within the sample
    assert f.t[reversals[0] - 1] <= m.executes[1] <= f.t[reversals[0]]  # within a sample of the order
    assert 0.5 * switch < m.first_overshoot + switch < 2 * switch


def test_the_plants_turning_circle_is_steady_symmetric_and_held():
    """The built-in turning circle flies: depth and roll held, nothing diverges; port mirrors
    starboard; the steady turn rate is the record's mean r over the steady part, within the
    band there; the circle fitted to the track has the kinematic diameter 2 U / |r|."""
    s = sc.scenario("turning-circle").with_overrides(duration=8.0)
    flights, _ = fl.fly_scenario(s)
    port, starboard = (experiment_metrics(e, flight_track(f)) for e, f in zip(s.experiments, flights))
    assert (port.side, starboard.side) == ("port", "starboard")
    for field in ("advance", "transfer", "tactical_diameter", "steady_diameter", "steady_speed"):
        assert getattr(port, field) == pytest.approx(getattr(starboard, field), rel=1e-6)
    assert port.steady_turn_rate == pytest.approx(-starboard.steady_turn_rate, rel=1e-6)
    for f, m in zip(flights, (port, starboard)):
        assert np.isfinite(f.truth).all()
        assert np.abs(f.truth[:, IX["z"]] - s.depth).max() < 1.0
        assert np.abs(f.truth[:, IX["phi"]]).max() < math.radians(3)
        r, steady = f.truth[:, IX["r"]], f.t >= m.steady_from
        assert m.steady_turn_rate == pytest.approx(r[steady].mean(), rel=1e-12)
        assert np.abs(r[steady] - m.steady_turn_rate).max() < 2 * STEADY_TOLERANCE * abs(m.steady_turn_rate)
        assert m.steady_diameter == pytest.approx(2 * m.steady_speed / abs(m.steady_turn_rate), rel=0.01)
        assert m.approach_speed == pytest.approx(s.speed or 20.0, rel=1e-6) and m.speed_ratio < 1
        assert m.execute == pytest.approx(s.experiments[0].fins["rudder"].start, abs=f.t[1])


def test_a_run_directory_gives_the_flights_metrics(tmp_path):
    """From the run's `.truth.csv` files (the track dead-reckoned from u, v, w and the attitude)
    the metrics of the flight itself (the plant's position), to the dead reckoning's error."""
    s = sc.scenario("turning-circle").with_overrides(duration=8.0)
    run = runs.simulate(s, out=tmp_path / "run")
    flights, _ = fl.fly_scenario(s)
    metrics = run_metrics(run)
    assert list(metrics) == ["port", "starboard"]
    for e, f in zip(s.experiments, flights):
        flown, read = experiment_metrics(e, flight_track(f)), metrics[e.name]
        assert read.execute == pytest.approx(
            flown.execute, abs=1e-9
        ) and read.steady_turn_rate == pytest.approx(flown.steady_turn_rate)
        for field in ("advance", "transfer", "tactical_diameter", "steady_diameter"):
            assert getattr(read, field) == pytest.approx(getattr(flown, field), abs=0.01)
    measured = run_metrics(run, truth=False)
    assert measured["port"].tactical_diameter == pytest.approx(metrics["port"].tactical_diameter, rel=0.05)


# -- data that hold no such manoeuvre ------------------------------------------------------------


def _track(t, rudder, r):
    zero = np.zeros_like(t)
    psi = np.concatenate([[0.0], np.cumsum(0.5 * (r[1:] + r[:-1]) * np.diff(t))])
    return Track(t, 10 * t, zero, psi, zero, r, zero + 10, rudder, zero)


T20, T80 = np.arange(0.0, 20.0, 0.1), np.arange(0.0, 80.0, 0.1)


@pytest.mark.parametrize(
    "track, message",
    [
        (_track(T20, np.zeros(200), np.full(200, 0.1)), "no execute inside the record"),
        (_track(T20, np.where(T20 > 1, 0.3, 0.0), np.full(200, 0.1)), "changes by 108.3°"),
        (  # turning at 0.1 ± 0.01 rad/s: never within 2 % for long
            _track(T80, np.where(T80 > 1, 0.3, 0.0), 0.1 + 0.01 * np.sin(T80)),
            "expected a steady turn of at least 180°",
        ),
    ],
)
def test_a_track_without_a_turning_circle_is_a_one_line_error(track, message):
    with pytest.raises(InputError, match=message) as err:
        turning_circle(track, "rec.csv")
    assert "\n" not in str(err.value) and str(err.value).startswith("rec.csv: ")


def test_a_record_without_a_zigzag_is_a_one_line_error():
    t = np.arange(0.0, 10.0, 0.1)
    fin = np.where(t > 2, 0.1, 0.0)
    with pytest.raises(InputError, match="2 fin executes .*; expected a zigzag's first four"):
        zigzag(t, 0.1 * t, fin, where="rec.csv")
    with pytest.raises(InputError, match="0 fin executes"):
        zigzag(t, 0.1 * t, np.zeros_like(t))


def test_a_run_without_manoeuvres_is_a_one_line_error(tmp_path):
    with pytest.raises(InputError, match="no scenario.toml; expected a run directory"):
        run_metrics(tmp_path)
    (tmp_path / "scenario.toml").write_text(sc.scenario_text(sc.scenario("II")))
    with pytest.raises(InputError, match="experiments horizontal, vertical, roll fly no manoeuvre"):
        run_metrics(tmp_path)
    assert [manoeuvre(e) for e in sc.scenario("II").experiments] == [None] * 3
    spec = sc.scenario("turning-circle")
    assert tomllib.loads(sc.scenario_text(spec))["name"] == "turning-circle"
    assert {manoeuvre(e) for e in spec.experiments} == {"turning circle"}
