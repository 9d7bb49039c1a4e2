"""The nonlinear model flown open loop: its states from a first one, driven by recorded fin angles.

`fly_nonlinear` integrates ẋ = f(x, δ, θ) (`nonlinear.rates`) by the classical fourth-order Runge-Kutta
method, `substeps` steps per sample interval (by default steps of about 5 ms, `substeps_for`:
4 a 20 ms interval, 2 a 10 ms one), each sample's fin angles held until the next: a
run's records give at each sample the fins' mean over the interval that follows it, which held
over that interval moves the body as the fins did to first order (the linear model's predictions
take the inputs so too). The flight is compiled (`nonlinear_kernels.rk4_flight`), real or complex;
`fly_with_sensitivities` carries its exact sensitivities in the same pass.
"""

from __future__ import annotations

import numpy as np

from testbed.errors import InputError
from testbed.models.linear import NU, NX
from testbed.models.nonlinear import NonlinearModel, packed

__all__ = ["STEP", "STRETCH", "flown_rows", "fly_nonlinear", "fly_with_sensitivities", "substeps_for"]


STEP = 0.005  # s: the RK4 step a flight takes unless told (4 steps a 20 ms sample interval)
# a flight's intervals between the rows it needs are at most this many times their median
# (`flown_rows`): a dropout is flown in steps about as long as the record's own
STRETCH = 1.5


def substeps_for(t) -> int:
    """The RK4 steps per sample interval of the times `t` that make each about `STEP` s: the
    median interval over `STEP`, rounded, at least 1."""
    return max(1, int(round(float(np.median(np.diff(np.asarray(t, float)))) / STEP)))


def flown_rows(t: np.ndarray, y: np.ndarray, fins: np.ndarray) -> np.ndarray:
    """The rows (indices) a flight over the times `t` (N,) with the `fins` (N, 3) held from each
    row to the next must stop at to read the measurements `y` (N, k; NaN where missing): the
    first, the last, each with a sample and each where the fins change; and, where two of those
    lie further apart than `STRETCH` times their median interval (a dropout), as few rows between
    them as keep every interval within that. The flight from one of these rows to the next is the
    flight through the rows between, in fewer RK4 steps (`substeps_for` their median interval): a
    log read on its logger's millisecond clock holds about 20 ticks a row, all but one without a
    sample or a fin change. A record on its own step keeps every row."""
    n = len(t)
    needed = ~np.isnan(y).all(axis=1)
    needed[1:] |= np.any(fins[1:] != fins[:-1], axis=1)
    needed[[0, -1]] = True
    rows = np.flatnonzero(needed)
    if len(rows) == n:
        return rows
    steps = np.diff(t[rows])
    limit = STRETCH * float(np.median(steps))
    between = []
    for k in np.flatnonzero(steps > limit):
        last = t[rows[k]]
        for j in range(rows[k] + 1, rows[k + 1]):  # kept where leaving it out stretches the interval
            if t[j + 1] - last > limit:
                between.append(j)
                last = t[j]
    return np.union1d(rows, np.array(between, dtype=rows.dtype))


def _flown(
    model: NonlinearModel, theta, t, x0, fins, substeps, free, dfins=None
) -> tuple[np.ndarray, np.ndarray]:
    """The states (N, 10) and, for `free` (indices into `model.names`; None: none), their
    sensitivities S (N, 10, p + q + 10) to θ[free], to the q parameters that move the fins
    (`dfins` (N, 3, q): the fins' derivatives along them; None: none) and to x0 from
    S_0 = [0 0 I], in one compiled pass (`nonlinear_kernels.rk4_flight`); complex where
    `theta`, `x0` or the fins are."""
    from testbed.models import nonlinear_kernels  # numba: only when a model is flown

    dtype = complex if any(np.iscomplexobj(a) for a in (theta, x0, fins)) else float
    # contiguous times: a column or a strided slice would compile the flight a second time
    t, x0, fins = np.ascontiguousarray(t, float), np.asarray(x0, dtype), np.asarray(fins, dtype)
    substeps = substeps_for(t) if substeps is None and len(t) > 1 else substeps
    _check(t, x0, fins, substeps)
    columns = np.zeros(0, dtype=np.int64) if free is None else np.asarray(free, dtype=np.int64).reshape(-1)
    D = np.zeros((1, 3, 0), dtype) if dfins is None else np.ascontiguousarray(dfins, dtype)
    x = np.empty((len(t), NX), dtype)
    x[0] = x0
    if free is None:
        S = np.zeros((1, NX, 0), dtype)  # no sensitivities carried
    else:
        S = np.zeros((len(t), NX, len(columns) + D.shape[2] + NX), dtype)
        S[0, :, len(columns) + D.shape[2] :] = np.eye(NX)
    nonlinear_kernels.rk4_flight(
        packed(model, theta, dtype), t, x, np.ascontiguousarray(fins, dtype), columns, substeps, S, D
    )
    return x, S


def _check(t, x0, fins, substeps) -> None:
    """`InputError` unless `t` (N,) increases, x0 is (10,), the fins (N, 3) and `substeps` a whole number ≥ 1."""
    if t.ndim != 1 or len(t) < 2 or not np.all(np.diff(t) > 0):
        raise InputError(f"t: {t.shape} times; expected two or more increasing times")
    if x0.shape != (NX,) or fins.shape != (len(t), NU):
        raise InputError(f"x0 {x0.shape}, fins {fins.shape}; expected ({NX},) and ({len(t)}, {NU})")
    if not isinstance(substeps, int) or substeps < 1:
        raise InputError(f"substeps={substeps!r}; expected a whole number >= 1")


def fly_nonlinear(model: NonlinearModel, theta, t, x0, fins, substeps: int | None = None) -> np.ndarray:
    """The states (N, 10), absolute u, at the times `t` (N,) from `x0` (10,) at t[0], the fin
    angles `fins` (N, 3) (rad) given at the same times, each held until the next, `substeps` RK4
    steps an interval (None: `substeps_for(t)`); complex where
    `theta`, `x0` or the fins are (a complex-step derivative of the flight)."""
    return _flown(model, theta, t, x0, fins, substeps, None)[0]


def fly_with_sensitivities(
    model: NonlinearModel, theta, t, x0, fins, free, substeps: int | None = None, dfins=None
) -> tuple[np.ndarray, np.ndarray]:
    """`fly_nonlinear`'s states (N, 10) and, in the same pass, their sensitivities
    S (N, 10, p + q + 10): to θ[free] (p indices into `model.names`), to the q parameters whose
    derivatives of the fins `dfins` (N, 3, q) gives (held as the fins are; None: none) and to
    x0, each RK4 stage differentiated."""
    return _flown(model, theta, t, x0, fins, substeps, free, dfins)
