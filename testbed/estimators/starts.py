"""Where the output-error iterations begin: the starts a user has, and a global search's.

- `config`: the a-priori values of the model config.
- `equation-error`: the linear model's rows fitted by least squares to smoothed derivatives
  (`equation_error.regression`, the method `equation-error`): no simulation, so no basin, but
  biased by noise and filtering.
- `mekf`: the modified EKF's estimate after one pass (`mekf.MEKF`), which follows the states
  with the data, so a poor model cannot drift away from them.
- `global`'s box draws (`multistart.box_draws`): coefficients drawn in a box around the a-priori
  values (Latin hypercube): a coefficient θ_i ≠ 0 between θ_i e^−b and θ_i e^b, one analysed at
  0 within ±3 of its Cramér-Rao bounds there, for a multi-start search (the paper's future work
  2, global optimisation).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from testbed.data import Experiment, ModelConfig
from testbed.errors import InputError
from testbed.estimators import equation_error, mekf
from testbed.estimators.base import Status
from testbed.estimators.filter_options import FilterOptions
from testbed.identification.problem import Problem

__all__ = ["named"]


def named(
    prob: Problem, experiments: Sequence[Experiment], config: ModelConfig, start: str
) -> tuple[np.ndarray, dict[str, str]]:
    """The free coefficients of the start `start` (config, equation-error or mekf), and those it
    leaves at their a-priori values, name → why (equation error's rows that no experiment
    supports: `equation_error.regression`). InputError where the start cannot be computed, the
    reason named: the MEKF diverges or refuses the data, or equation error supports no row (or
    none that moves a value from its a-priori one: the a-priori start again)."""
    if start == "config":
        return prob.start, {}
    if start == "equation-error":
        values, left = equation_error.regression(prob)
        if len(left) == prob.n_free or (left and np.array_equal(values, prob.start)):
            why = "; ".join(dict.fromkeys(left.values()))
            raise InputError(
                f"{prob.source}: start='equation-error': no free coefficient's row can be regressed on "
                f"these data ({why}); expected records measuring those states, or start config or mekf"
            )
        return values, left
    est = mekf.MEKF.fit(experiments, config, FilterOptions(), None)
    if est.status is Status.DIVERGED:
        raise InputError(
            f"{prob.source}: start='mekf': the MEKF diverged ({est.message}); expected "
            "a filter that converges, or start auto or equation-error"
        )
    return np.array([est.coefficients[n] for n in prob.free]), {}
