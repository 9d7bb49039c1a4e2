"""Identifiability of a nonlinear model config's free coefficients: the Fisher information of the
output-error likelihood at the config's values, from the flight's exact sensitivities
(`nonlinear_sensitivities.flight`), with the Cramér-Rao bounds, correlations and practical drift
groups of the linear model's analysis (`identifiability.assessed`).

Each record is flown from its best-fitting initial state (`nonlinear_prediction.flights`); its
measured initial states are parameters of the likelihood as in the fit, eliminated from the
information (the Schur complement, `likelihood.reduced`). The noise is the config's
`noise_std` where it gives a channel, else the residuals' mean square there. Missing samples
carry no information. The structural part is only the free coefficients no measured state
depends on (their sensitivities are 0 along every record): the linear model's exact drift
analysis (a row operation on its equations) has no counterpart here, so `structural_drift_groups`
holds only those.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from testbed.analysis.identifiability import Identifiability, Structural, assessed
from testbed.data import Experiment, ModelConfig
from testbed.errors import InputError
from testbed.identification.likelihood import reduced
from testbed.identification.nonlinear_prediction import flights
from testbed.identification.nonlinear_sensitivities import flight
from testbed.models.linear import STATES

__all__ = ["nonlinear_identifiability"]


def nonlinear_identifiability(
    experiments: Sequence[Experiment], config: ModelConfig, substeps: int = 4
) -> Identifiability:
    """The identifiability of `config.free` (a nonlinear model config's) from `experiments` at
    the config's values (module doc)."""
    source = config.source or "config"
    if not config.free:
        raise InputError(f"{source}: [identify] free is empty; nothing to analyse")
    if config.per_record:
        raise InputError(
            f"{source}: [identify] per_record {config.per_record[0]!r}; the nonlinear model's analysis "
            "takes every value once for all records"
        )
    experiments = config.fitted(experiments)
    model, theta = config.nonlinear()
    free = tuple(config.free)
    idx = [model.names.index(n) for n in free]
    flown = flights(experiments, config, substeps=substeps)
    parts = []  # per record: present mask, residual, J over [θ_free | measured x0]
    for e, x in zip(experiments, flown):
        ch = [STATES.index(c) for c in e.measured]
        f = flight(model, theta, e.t, x[0], e.inputs, idx, substeps, x)
        J = np.concatenate([f.dx_dtheta[:, ch], f.dx_dx0[:, ch][:, :, ch]], axis=2)
        present = np.isfinite(e.y)
        parts.append(
            (
                e.measured,
                present,
                np.where(present, e.y - x[:, ch], 0.0),
                np.where(present[:, :, None], J, 0.0),
            )
        )
    R = _noise(parts, config.noise_std or {})
    F = np.zeros((len(free), len(free)))
    for measured, _, _, J in parts:
        W = J / np.array([R[c] for c in measured])[:, None]
        M = np.einsum("nci,ncj->ij", W, J)
        F += reduced(M, np.zeros(len(M)), len(free))[0]
    blind = tuple(n for k, n in enumerate(free) if all(not np.any(J[:, :, k]) for _, _, _, J in parts))
    struct = Structural(
        free, np.eye(len(free))[[free.index(n) for n in blind]], tuple((n,) for n in blind), blind
    )
    return assessed(free, theta[idx], F, struct)


def _noise(parts, given) -> dict[str, float]:
    """R per measured channel: the given σ², else the residuals' mean square over the records."""
    total, count = {}, {}
    for measured, present, e, _ in parts:
        for k, c in enumerate(measured):
            total[c] = total.get(c, 0.0) + float(np.sum(e[:, k] ** 2))
            count[c] = count.get(c, 0) + int(np.sum(present[:, k]))
    return {c: given[c] ** 2 if c in given else max(total[c] / max(count[c], 1), 1e-30) for c in total}
