"""What the linear model predicts: its outputs on measured experiments (for plots and
validation) and experiments simulated from it exactly (synthetic data).
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from testbed.data import Experiment, ModelConfig
from testbed.identification import scan
from testbed.identification.likelihood import initial_states
from testbed.identification.problem import problem
from testbed.identification.recursions import simulated_outputs
from testbed.models.linear import IX, NX, STATES, continuous, discretize, structure, theta_vector

__all__ = ["predict", "synthetic"]


def predict(
    experiments: Sequence[Experiment],
    config: ModelConfig,
    initial: Mapping[str, Mapping[str, float]] | None = None,
) -> list[np.ndarray]:
    """Model outputs (N, k) per experiment in its measured columns, absolute u, for plots; NaN
    at the samples the model is not flown over (a gap in the logged inputs, `data.stretches`).

    `initial`: record → state → x0 (absolute u, as in `Estimate.initial_states`: a record split
    at a gap names each stretch); the ones it does not give are the best-fitting initial states
    (no fit when it gives all).
    """
    prob = problem(experiments, config)
    given = initial or {}
    if all(STATES[i] in given.get(r.name, {}) for r in prob.records for i in r.measured):
        p = np.concatenate([prob.start, np.zeros(prob.n_params - prob.n_free)])
    else:
        p = initial_states(prob, prob.start)
    for r in prob.records:
        for j, i in enumerate(r.measured):
            if STATES[i] in given.get(r.name, {}):
                p[r.offset + j] = initial[r.name][STATES[i]] - (prob.speed if STATES[i] == "u" else 0)
    out = [np.full(np.shape(e.y), np.nan) for e in experiments]
    for r, yhat in zip(prob.records, simulated_outputs(prob, p)):
        yhat = yhat.copy()
        yhat[:, r.measured == IX["u"]] += prob.speed
        out[r.group][r.first : r.first + len(yhat)] = yhat
    return out


def synthetic(
    config: ModelConfig,
    t: np.ndarray,
    inputs: np.ndarray,
    noise_std: Mapping[str, float] | None = None,
    measured: Sequence[str] = STATES,
    rng: np.random.Generator | None = None,
    x0: np.ndarray | None = None,
    name: str = "synthetic",
) -> Experiment:
    """An experiment simulated from the linear model of `config` itself (ZOH inputs, absolute u).

    `x0`: initial perturbation state (10,), default trim; `noise_std`: white Gaussian noise per
    state (missing: none).
    """
    theta = theta_vector(config.coefficients)
    Phi, Gamma, sv = discretize(*continuous(structure(config.vehicle), theta), float(t[1] - t[0]))
    x0 = np.zeros(NX) if x0 is None else np.asarray(x0, dtype=float)
    x = scan.propagate(Phi, x0, np.asarray(inputs)[:-1] @ Gamma.T + sv)
    x[:, IX["u"]] += config.vehicle.speed
    measured = tuple(m for m in STATES if m in measured)
    cols = [IX[m] for m in measured]
    y = x[:, cols]
    if noise_std:
        rng = rng or np.random.default_rng()
        y = y + rng.normal(size=y.shape) * np.array([noise_std.get(m, 0.0) for m in measured])
    return Experiment(name, np.asarray(t, dtype=float), tuple(measured), y, np.asarray(inputs, dtype=float))
