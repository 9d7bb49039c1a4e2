"""Data compatibility: the flight path reconstructed from the measured rates and velocities.

Before any fit of the dynamics, the kinematics the measurements must obey are checked (flight-
path reconstruction; Klein & Morelli ch. 10, Jategaonkar ch. 10). The attitude is integrated
from the rate gyros,

    φ̇ = p + (q sin φ + r cos φ) tan θ,   θ̇ = q cos φ − r sin φ,   ψ̇ = (q sin φ + r cos φ) / cos θ,

and the depth from the Doppler velocity log with the measured attitude,

    ż = −u sin θ + v cos θ sin φ + w cos θ cos φ,

each driving channel c corrected by its sensor's bias b_c, scale factor k_c and its group's
delay τ (the true value at time t is `(c_measured(t + τ) − b_c) / (1 + k_c)`; a sensor that
lags by τ has τ > 0), and the measured φ, θ the depth uses by their constant offsets `b_phi`,
`b_theta` (an AHRS mounted off its axes: the true angle is `c_measured − b_c`, the names of the
model's output biases). θ's offset turns the log's u into a sink rate −u sin θ, strongly seen
in depth over a dive; φ's through v and w, seen where v is. A heading offset enters neither
check's kinematics (ψ is the attitude check's output only, one more constant beside its initial
heading) and is not a check parameter; the attitude check integrates from its initial attitude,
which takes the φ and θ offsets in. The reconstruction is compared with the measured φ, θ, ψ
(the attitude check, `ATTITUDE`) and z (the depth check, `DEPTH`), and the initial attitude or
depth and the sensor parameters are fitted by the filter-error method (maximum likelihood of a
Kalman filter's innovations; Maine & Iliff, Jategaonkar): the noise of the rates and velocities
is integrated by the kinematics, so it is process noise, and output error would be biased and
its bounds 2–6 times too small. The noise is read off the data (robust third differences over
the samples present): the outputs' σ is the filter's measurement noise R, the driving channels'
(and, in ż, the attitude's times the velocities) its process noise, a random walk of h H σ² per
step h, H the interval between the channel's samples around it (h² σ² where every row is a
sample; a spline through samples H apart carries each sample's error over H). The attitude
filter is extended (linearised at each step), its gain held at each iteration's (Maine &
Iliff); the depth filter's process noise depends on the corrected velocities, so its gain and
the likelihood's ln det S follow the parameters. The fit is Gauss-Newton (trust region,
`scipy.optimize.least_squares`) on the residuals whose sum of squares is the negative
log-likelihood; its derivatives are exact: the complex step, the measured signals
interpolated by cubic splines (a fractional delay is a shift along the spline, so a 40 ms
delay at 50 Hz is as smooth a parameter as any other). The standard deviations are the
Cramér-Rao bounds, from the Fisher information of the innovations at the optimum.

What the delays mean: the gyros' τ is their lag behind the attitude channels, the log's τ its
lag behind the depth sensor. A delay common to every channel shifts the whole record in time
and cannot be told from the data; only these relative delays can.

The screen, like the coefficients' (docs/cli.md, the screen): a sensor parameter whose
regressor is mostly the noise of a measured channel in every record (`REGRESSORS`) or along
which the Fisher information of these data is singular is not identifiable (e.g. the log's v
bias when roll never leaves 0) and is held at 0; of the others, fitted, one at a time a
parameter within 2 σ of 0 is held at 0 (`HELD_FIRST`: scale factors, delays, then biases; the
others updated for it held there), and those left are fitted again until none is. The initial
states are always fitted.

The depth check's log may be misaligned from the body's axes by `m_dvl_y`, `m_dvl_z` (its reading
Mᵀ v, M = Rz(m_dvl_z) Ry(m_dvl_y), a scenario sensor's `misalignment`). A parameter correlated
beyond 0.99 with an attitude offset in these data is held, not separable (`_inseparable`): a
log's w bias makes the sink rate of a pitch offset wherever u is near constant, its
misalignment about y is one with it; the offset, the commoner error, is kept. About z the
misalignment turns u into v: seen through v sin φ where the vehicle rolls, and told from a v
bias only where the speed varies. Among the insignificant, the offsets are held last.

Missing samples: each channel's samples present are its data. The filter steps from row to row
of those where every output of the check is present (the others' outputs are left out); the
driving and used channels are cubic splines through their samples present, bridging a gap up
to `BRIDGED_GAP` (3) times the channel's median interval (a dropped sample or two, a slower
sensor's rate); across a longer gap the record is split, each stretch checked with its own
initial state and named `record a–b s`, the gap named unchecked. A record missing a channel a
check needs (not a column, or under 2 samples) is not checked for it: no gyros, no attitude
check; the depth check runs on the log and the measured attitude. The result names what it
could not check, wholly or over which stretch, and why (`Compatibility.unchecked`).

Each record is checked alone, and all records together (`pooled`: one set of sensor
parameters, each record or stretch its own initial states).
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from testbed.analysis.compatibility_checks import (
    ATTITUDE,
    CHECKS,
    BRIDGED_GAP,
    MAX_PITCH,
    MIN_CHECKED_ROWS,
    Check,
    Compatibility,
    Reconstruction,
)
from testbed.analysis.compatibility_fit import fitted_reconstruction
from testbed.analysis.compatibility_records import WHY_NEEDED, CheckRecord, channel_samples, missing_channels
from testbed.data import Experiment
from testbed.errors import InputError
from testbed.simulation.measurements import noise_from_data

__all__ = ["compatibility"]


def _stretches(e: Experiment, check: Check) -> tuple[list[tuple[float, float]], list[str]]:
    """The stretches of `e` that `check` can check: where every driving and used channel has
    samples on both sides, split at each gap of one longer than `BRIDGED_GAP` times its median
    interval, and holding at least `MIN_CHECKED_ROWS` rows with every output; and the parts left out,
    each with its reason."""
    rows = ~np.isnan(np.column_stack([e.column(c) for c in check.outputs])).any(axis=1)
    out_t = e.t[rows]
    if not len(out_t):
        return [], [f"no row has every one of {', '.join(check.outputs)}"]
    gaps: dict[tuple[float, float], list[str]] = {}  # (start, end) of a gap not bridged → channels
    limits = {}
    a, b = -math.inf, math.inf
    for c in check.drives + check.uses:
        ts, _ = channel_samples(e, c)
        a, b = max(a, ts[0]), min(b, ts[-1])
        d = np.diff(ts)
        limits[c] = BRIDGED_GAP * float(np.median(d))
        for i in np.flatnonzero(d > limits[c]):
            gaps.setdefault((float(ts[i]), float(ts[i + 1])), []).append(c)
    why = []
    channels = ", ".join(check.drives + check.uses)
    if out_t[0] < a:
        why.append(f"before {a:.4g} s, not every one of {channels} has a sample")
    for (g0, g1), cs in sorted(gaps.items()):
        limit = " or ".join(f"{v:.3g} s" for v in sorted({limits[c] for c in cs}))
        why.append(
            f"over {g0:.4g}–{g1:.4g} s, {', '.join(cs)} {'has' if len(cs) == 1 else 'have'} no sample "
            f"for {g1 - g0:.3g} s (a gap over {BRIDGED_GAP:g} times the channel's median interval, {limit}, "
            "is not bridged)"
        )
    if out_t[-1] > b:
        why.append(f"after {b:.4g} s, not every one of {channels} has a sample")
    merged: list[list[float]] = []  # the union of what is not checked, in time order
    for g0, g1 in sorted(list(gaps) + [(-math.inf, a), (b, math.inf)]):
        if merged and g0 <= merged[-1][1]:
            merged[-1][1] = max(merged[-1][1], g1)
        else:
            merged.append([g0, g1])
    stretches = []
    for (_, s0), (s1, _) in zip(merged[:-1], merged[1:]):
        n = int(np.sum((out_t >= s0) & (out_t <= s1)))
        if n == 0:
            continue
        if n < MIN_CHECKED_ROWS:
            why.append(
                f"over {s0:.4g}–{s1:.4g} s, between gaps, only {n} rows of the outputs (under {MIN_CHECKED_ROWS})"
            )
        else:
            stretches.append((float(s0), float(s1)))
    return stretches, why


def compatibility(experiments: Sequence[Experiment]) -> Compatibility:
    """The data-compatibility check of `experiments`: each record alone (its channels' noise read
    off it) and all pooled (the noise read off all), each check on the stretches of the records
    that measure its channels (`_stretches`); `InputError` when none has any."""
    unchecked: dict[str, dict[str, str]] = {e.name: {} for e in experiments}
    ready: dict[str, list[tuple[Experiment, list[tuple[float, float]]]]] = {}
    for check in CHECKS:
        for e in experiments:
            missing = missing_channels(e, check)
            steep = (
                float(np.nanmax(np.abs(e.column("theta"))))
                if "theta" in e.measured and not np.isnan(e.column("theta")).all()
                else 0.0
            )
            if missing:
                unchecked[e.name][check.name] = (
                    f"needs {', '.join(check.needs)} ({WHY_NEEDED[check.name]}); missing {', '.join(missing)}"
                )
                continue
            if check is ATTITUDE and steep > MAX_PITCH:
                unchecked[e.name][check.name] = (
                    f"theta reaches {steep:.4g} rad, beyond ±{MAX_PITCH:g}: the Euler angles' "
                    "kinematics are singular at ±π/2 (attitude in radians expected)"
                )
                continue
            stretches, why = _stretches(e, check)
            if why:
                unchecked[e.name][check.name] = "; ".join(why)
            if stretches:
                ready.setdefault(check.name, []).append((e, stretches))
    if not ready:
        why = "; ".join(
            f"{name}: {'; '.join(f'{c} check {w}' for c, w in v.items())}" for name, v in unchecked.items()
        )
        raise InputError(f"nothing to check: {why}")
    noise = {e.name: noise_from_data([e]) for e in experiments}
    records: dict[str, dict[str, Reconstruction]] = {e.name: {} for e in experiments}
    pooled = {}

    def pieces(check, e, stretches, noise):
        whole = len(stretches) == 1 and not unchecked[e.name].get(check.name)
        return [
            CheckRecord(e, check, noise, (a, b), e.name if whole else f"{e.name} {a:.4g}–{b:.4g} s")
            for a, b in stretches
        ]

    for check in CHECKS:
        some = ready.get(check.name, [])
        for e, stretches in some:
            records[e.name][check.name] = fitted_reconstruction(
                check, pieces(check, e, stretches, noise[e.name])
            )
        if len(some) == 1:
            pooled[check.name] = records[some[0][0].name][check.name]
        elif some:
            everyone = noise_from_data([e for e, _ in some])
            pooled[check.name] = fitted_reconstruction(
                check, [r for e, s in some for r in pieces(check, e, s, everyone)]
            )
    return Compatibility(records=records, pooled=pooled, unchecked=unchecked)
