"""The nonlinear model's output-error likelihood as an `objective.Objective`, the one
`estimators.trust_region` fits the linear model's by.

The parameters are θ ⊕ b ⊕ g ⊕ c ⊕ τ's free ones (`nonlinear_output_error.parameter_names`) and, when
`free_initial`, each record's initial state in its measured channels; the unmeasured components
of an initial state stay at straight flight at the vehicle's speed
(`nonlinear_output_error.start_states`). The outputs are not linear in the initial states: a
point's initial states are the records' first samples where it starts, and then take their
Gauss-Newton step with θ's at every step (`objective.following`). The noise variance R is the
residuals' mean square per channel over the samples present (or `held` where given). The
output_sensitivities are the flight's exact ones (`nonlinear_sensitivities`); the model has no
second-order ones, so `hessian` is None and the optimiser's second-order check probes the cost.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
import numpy as np

from testbed.identification.likelihood import EXPLODE
from testbed.identification.nonlinear_output_error import (
    FlightRecord,
    neg_log_likelihood,
    normal_equations,
    pooled_noise,
    output_sensitivities,
    fly_records,
    start_states,
)
from testbed.identification.objective import Point
from testbed.models.nonlinear import NonlinearModel

__all__ = ["NonlinearObjective"]


@dataclass(frozen=True)
class NonlinearObjective:
    """The nonlinear output-error problem: `model`, its parameters θ ⊕ b ⊕ g ⊕ c ⊕ τ `theta` (the free
    ones, indices `free` into it, at their a-priori values), the `records` and their measured
    state columns `ch`, R held where `held` is not NaN (per channel), RK4 `substeps`, each
    record's measured initial state free (`free_initial`) or held at its first sample."""

    model: NonlinearModel
    theta: np.ndarray
    free: np.ndarray
    records: tuple[FlightRecord, ...]
    ch: tuple[int, ...]
    held: np.ndarray
    substeps: int | None = None
    free_initial: bool = True
    x0: np.ndarray | None = None  # (records, 10) the initial states a point starts from; None: `start_states`
    # the last point's parameter vector and output sensitivities (`terms`), for the bounds at a fit's end
    last: dict = field(default_factory=dict, compare=False, repr=False)

    @property
    def n_free(self) -> int:
        return len(self.free)

    @property
    def start(self) -> np.ndarray:
        return self.theta[self.free].copy()

    @property
    def pieces(self) -> int:
        return len(self.records)

    @property
    def projected(self) -> bool:
        """False: the initial states step with θ (module doc)."""
        return False

    def first_states(self) -> np.ndarray:
        """(records, 10): the initial states a point starts from."""
        return start_states(self.model, self.records, self.ch) if self.x0 is None else self.x0

    def unpack(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """θ ⊕ b ⊕ g ⊕ c ⊕ τ and the initial states (records, 10) of the parameter vector `p`."""
        theta, x0 = self.theta.copy(), self.first_states().copy()
        theta[self.free] = p[: self.n_free]
        if self.free_initial:
            x0[:, list(self.ch)] = p[self.n_free :].reshape(len(self.records), len(self.ch))
        return theta, x0

    def _at(self, p: np.ndarray, R: np.ndarray | None) -> Point | None:
        """The point at `p`, R estimated from its residuals (J at that R), or None where a flight
        leaves the finite numbers or the data's range by `likelihood.EXPLODE`."""
        if not np.all(np.isfinite(p)):
            return None
        flown, res = fly_records(self.model, *self.unpack(p), self.records, list(self.ch), self.substeps)
        # a flight whose outputs leave the data's range EXPLODE-fold has diverged (NaN: missing)
        with np.errstate(invalid="ignore"):
            if res is None or any(
                np.any(np.abs(r.y - e) > EXPLODE * np.nanmax(np.abs(r.y), axis=0) + 1.0)
                for r, e in zip(self.records, res)
            ):
                return None
        R = pooled_noise(res, self.held)
        return Point(p, flown, res, R, neg_log_likelihood(res, R))

    def point(self, theta: np.ndarray, R: np.ndarray | None = None) -> Point | None:
        """The point at the free values `theta`, each record's initial state its first sample."""
        x0 = self.first_states()[:, list(self.ch)].ravel() if self.free_initial else []
        return self._at(np.concatenate([theta, x0]), R)

    def moved(self, at: Point, step: np.ndarray) -> Point | None:
        return self._at(at.p + step, at.R)

    def terms(self, at: Point) -> tuple[np.ndarray, np.ndarray]:
        theta, x0 = self.unpack(at.p)
        sens = output_sensitivities(
            self.model, theta, x0, self.records, at.xs, list(self.ch), self.free, self.substeps
        )
        M, g = normal_equations(at.res, sens, at.R, self.free_initial)
        self.last.update(p=at.p.copy(), sensitivities=sens)
        return g, M

    def sensitivities_at(self, p: np.ndarray) -> list | None:
        """The output sensitivities `terms` took at the parameter vector `p`, if it was the last
        one it took; else None."""
        same = "p" in self.last and np.array_equal(self.last["p"], p)
        return self.last["sensitivities"] if same else None

    def weighted_cost(self, res: list, R: np.ndarray) -> float:
        """`½ Σ eᵀR⁻¹e` over the samples present."""
        return 0.5 * sum(float(np.nansum(e**2 / R)) for e in res)

    def hessian(self, at: Point, M: np.ndarray | None = None) -> None:
        """None: the flight has no second-order output_sensitivities (module doc)."""
        return None

    def segmented(self, count: int, least: int) -> "NonlinearObjective":
        """The records cut into `count` consecutive segments of (nearly) equal length, each of at
        least `least` rows with a sample and starting at one, each its own record with its own
        initial state (its first sample's measured states)."""
        records = []
        for r in self.records:
            rows = np.flatnonzero(~np.isnan(r.y).all(axis=1))
            pieces = max(1, min(count, len(rows) // max(least, 1)))
            at = np.linspace(0, len(rows), pieces + 1).round().astype(int)[1:-1]
            edges = np.r_[0, rows[at], len(r.t)]
            records += [r.rows(a, b) for a, b in zip(edges[:-1], edges[1:])]
        return replace(self, records=tuple(records), x0=None, last={})

    def shooting(self, theta: np.ndarray, least: int) -> int:
        """The fewest segments per record (1, 2, 4, …; each of at least `least` rows with a
        sample) on whose records the flight at the free values `theta` stays bounded."""
        count, pieces = 1, 0
        while True:
            stage = self if count == 1 else self.segmented(count, least)
            if stage.point(theta) is not None or stage.pieces == pieces:
                return count
            count, pieces = 2 * count, stage.pieces

    def grows(self, theta: np.ndarray) -> bool:
        """False: a flight that leaves the data's range is no point (`point`: None), and one
        that stays in it is fitted on the whole record."""
        return False
