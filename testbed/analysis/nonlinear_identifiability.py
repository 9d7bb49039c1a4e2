"""Identifiability of a nonlinear model config's free coefficients: the Fisher information of the
output-error likelihood at the config's values, from the flight's exact sensitivities
(`nonlinear_sensitivities.flight`), with the Cramér-Rao bounds, correlations and practical drift
groups of the linear model's analysis (`identifiability.assessed`).

Each record is flown from its best-fitting initial state (`nonlinear_prediction.flights`); its
measured initial states are parameters of the likelihood as in the fit, eliminated from the
information (the Schur complement, `likelihood.reduced`). The noise is the config's
`noise_std` where it gives a channel, else the residuals' mean square there. The records must
measure the same states, every sample present, as for the fit. The structural part is only the free coefficients no measured state
depends on (their sensitivities are 0 along every record): the linear model's exact drift
analysis (a row operation on its equations) has no counterpart here, so `structural_drift_groups`
holds only those.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from testbed.analysis.identifiability import Identifiability, Structural, assessed
from testbed.data import Experiment, ModelConfig
from testbed.identification.likelihood import reduced
from testbed.identification.nonlinear_output_error import information, setup
from testbed.identification.nonlinear_prediction import flights
from testbed.models.linear import STATES

__all__ = ["nonlinear_identifiability"]


def nonlinear_identifiability(
    experiments: Sequence[Experiment], config: ModelConfig, substeps: int = 4
) -> Identifiability:
    """The identifiability of `config.free` (a nonlinear model config's) from `experiments` at
    the config's values (module doc)."""
    experiments = config.fitted(experiments)
    channels, recs, model, theta, idx = setup(experiments, config, "analyze on a nonlinear model config")
    free = tuple(config.free)
    ch = [STATES.index(c) for c in channels]
    flown = flights(experiments, config, substeps=substeps)
    res = np.concatenate([r.y - x[:, ch] for r, x in zip(recs, flown)])
    given = config.noise_std or {}
    R = np.array(
        [given[c] ** 2 if c in given else max(np.mean(res[:, k] ** 2), 1e-30) for k, c in enumerate(channels)]
    )
    H = information(model, theta, np.array([x[0] for x in flown]), recs, channels, free, R, substeps)[0]
    F = reduced(H, np.zeros(len(H)), len(free))[0]
    blind = tuple(n for k, n in enumerate(free) if H[k, k] == 0.0)
    struct = Structural(
        free, np.eye(len(free))[[free.index(n) for n in blind]], tuple((n,) for n in blind), blind
    )
    return assessed(free, theta[idx], F, struct)
