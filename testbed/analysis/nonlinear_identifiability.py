"""Identifiability of a nonlinear model config's free coefficients and output biases
(`nonlinear_output_error.parameter_names`): the Fisher information of the
output-error likelihood at the config's values, from the flight's exact sensitivities
(`nonlinear_sensitivities.flight`), with the Cramér-Rao bounds, correlations and practical drift
groups of the linear model's analysis (`identifiability.assessed`).

Each record is flown from its best-fitting initial state (`nonlinear_prediction.flights`), or,
where a flight leaves the finite numbers (an unstable a-priori model), the records are cut into
the fewest segments on which the flights from their first samples stay in the data's range, as
the linear model's analysis cuts them (`identifiability.on_segments` says so); its
measured initial states are parameters of the likelihood as in the fit, eliminated from the
information (the Schur complement, `bounds.eliminated`: a parameter left with only the rounding
of its information, such as a heading's output bias beside the initial heading, which ψ entering
no other state makes the same parameter, has none and an infinite bound). The noise is the config's
`noise_std` where it gives a channel, else the residuals' mean square there. The records must
measure the same states, as for the fit, a missing sample left out. The structural part is only
the free coefficients no measured state depends on (their sensitivities are 0 along every
record): the linear model's exact drift analysis (a row operation on its equations) has no
counterpart here, so `structural_drift_groups` holds only those. A direction along which the
information is numerically singular (an eigenvalue within its own rounding: `rank_tolerance`)
gives its coefficients infinite bounds.

The screen of a nonlinear model config (`NONLINEAR`, for `screening.screening`) takes its
stage 1 from this analysis at the a-priori values (`forward`) and its stage 2 from it at the
`ml-gn` estimate, each record flown from the fit's initial state. Stage 1 cannot fix every
candidate along a singular direction, as the linear model's fixes every member of a drift group:
a nonlinear term set comes with near-copies (one regressor twice; the two blades of a rudder,
each blade's blunt and slender drag), along which the information is singular or nearly so, and
fixing all of them would leave little to fit (of the captive component model's 23 candidates on
Scenario I, one). `forward` keeps one of each instead: it takes the candidates one at a time, the
most significant alone first, and keeps each while the information stays regular and every
candidate kept is significant at its a-priori value (|θ₀| ≥ 2 σ: `screening.SIGNIFICANT`),
the rule stage 2 applies at the estimate. A candidate 0 a priori is kept where its own bound is
finite and the others stay significant, so none is fixed for being 0.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Mapping, Sequence

import numpy as np

from testbed.analysis.identifiability import Identifiability, assessed, on_segments
from testbed.analysis.screening import SIGNIFICANT, ScreenModel
from testbed.analysis.structural import Structural
from testbed.data import Experiment, ModelConfig, split
from testbed.estimators import Estimate
from testbed.errors import Unflyable
from testbed.identification.bounds import NULL, crlb, eliminated
from testbed.identification.likelihood import FEWEST_SEGMENT, LEAST_SEGMENT
from testbed.identification.nonlinear_objective import NonlinearObjective
from testbed.identification.nonlinear_output_error import (
    flight_information,
    pooled_noise,
    read_outputs,
    setup,
)
from testbed.identification.nonlinear_prediction import first_samples, flights
from testbed.models.linear import STATES
from testbed.models.nonlinear_flight import substeps_for

__all__ = ["NONLINEAR", "forward", "nonlinear_identifiability", "rank_tolerance"]


def rank_tolerance(H: np.ndarray, F: np.ndarray, samples: int, channels: int, substeps: int) -> float:
    """The null tolerance of `bounds.crlb` for the information `F` (the coefficients' block of
    `H` with the initial states eliminated): the largest eigenvalue of the unit-diagonal F,
    relative to the largest, that lies within its own rounding (at least `bounds.NULL`).

    An entry of H is rounded by at most `γ √(H_ii H_jj)`, `γ = ε (N C + 2 K)`: the sum over the N
    samples' C channels of products of sensitivities rounds by at most N C ε of Σ|a b| ≤
    √(H_ii H_jj) (Cauchy-Schwarz), and each sensitivity, carried by a recursion through
    K = N × `substeps` RK4 steps, by at most K ε relative, twice in a product. Eliminating the
    initial states subtracts from H, so F's error stays on H's scale: on F's unit diagonal an
    entry's error is at most `γ k_i k_j`, `k_i = √(H_ii / F_ii)`. To first order an eigenvalue
    moves by `vᵀ E v` along its unit eigenvector v, at most `γ (Σ |v_i| k_i)²`: an eigenvalue no
    larger cannot be told from 0. (Weyl's bound for all directions at once, `γ Σ k_i²`, lets the
    worst-scaled coefficient blur every direction.) The eliminations' own rounding (about ε ×
    the initial states' block condition) is left out: a record's few initial states are well
    determined."""
    h, f = np.diag(H)[: len(F)], np.diag(F)
    informed = (h > 0) & (f > 0)
    k = np.sqrt(np.where(informed, h / np.where(informed, f, 1.0), 0.0))
    d = np.where(informed, np.sqrt(np.where(informed, f, 1.0)), 1.0)
    lam, V = np.linalg.eigh(F / np.outer(d, d))
    gamma = np.finfo(float).eps * samples * (channels + 2 * substeps)
    within = lam <= gamma * (np.abs(V).T @ k) ** 2
    top = max(lam.max(initial=0.0), 1e-300)
    return float(max(NULL, np.max(lam[within], initial=0.0) / top))


def nonlinear_identifiability(
    experiments: Sequence[Experiment],
    config: ModelConfig,
    substeps: int | None = None,
    initial: Mapping[str, Mapping[str, float]] | None = None,
    information: np.ndarray | None = None,
) -> Identifiability:
    """The identifiability of `config.free` (a nonlinear model config's) from `experiments` at
    the config's values (module doc); `initial`: each record's initial state by record name
    (an estimate's `initial_states`, held), else its best fit at the config's values;
    `information`: the Fisher information already computed there (an `Estimate.information`:
    the free coefficients, then each record's measured initial states), else computed. A record
    split at a dropout is its stretches (`data.split`)."""
    experiments = [p for e in config.fitted(experiments) for p in split(e)]
    channels, recs, model, theta, idx = setup(experiments, config, "analyze on a nonlinear model config")
    free = tuple(config.free)
    size = len(free) + len(recs) * len(channels)
    if information is not None and np.shape(information) != (size, size):
        raise ValueError(
            f"information of shape {np.shape(information)}; expected ({size}, {size}): the "
            f"{len(free)} free coefficients and {len(channels)} initial states in each of {len(recs)} records"
        )
    segments, why = 0, ""
    if information is None:
        information, segments, why = _information(
            experiments, config, (channels, recs, model, theta, idx), initial, substeps
        )
    H = information
    F = eliminated(H, len(free))
    blind = tuple(n for k, n in enumerate(free) if H[k, k] == 0.0)
    struct = Structural(
        free, np.eye(len(free))[[free.index(n) for n in blind]], tuple((n,) for n in blind), blind
    )
    steps = substeps_for(recs[0].t) if substeps is None else substeps
    null = rank_tolerance(H, F, sum(len(r.t) for r in recs), len(channels), steps)
    out = assessed(free, theta[idx], F, struct, null)
    return on_segments(out, segments, why) if segments else out


def forward(result: Identifiability) -> dict[str, str]:
    """Stage 1 of a nonlinear model config's screen, name → why (module doc): the candidates no
    measured state depends on, then those not kept by the forward selection over `result`'s
    information (regular at `result.null`, every kept candidate ≠ 0 at least `SIGNIFICANT` σ
    from 0 at its a-priori value), tried in order of |θ₀|/σ alone, those 0 a priori last."""
    F, values, free = result.fisher, np.asarray(result.values, float), result.free
    fixed = {n: "no fitted state depends on it" for n in result.structural.unobserved}
    alone = np.abs(values) * np.sqrt(np.maximum(np.diag(F), 0.0))  # |θ₀| / σ with it alone free
    order = sorted(
        (i for i, n in enumerate(free) if n not in fixed), key=lambda i: (values[i] == 0, -alone[i])
    )
    kept: list[int] = []
    for i in order:
        chosen = kept + [i]
        std = crlb(F[np.ix_(chosen, chosen)], result.null).std
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.where(np.isfinite(std), np.abs(values[chosen]) / std, 0.0)
        weak = [k for k, j in enumerate(chosen) if values[j] != 0 and z[k] < SIGNIFICANT]
        if np.all(np.isfinite(std)) and not weak:
            kept.append(i)
            continue
        if not np.all(np.isfinite(std)):
            with_it = [free[j] for j, sd in zip(kept, std) if not np.isfinite(sd)]
            along = f"it and {', '.join(with_it)}, kept before it" if with_it else "it"
            fixed[free[i]] = f"the Fisher information of these data is singular along {along}"
        elif weak[-1] == len(kept):
            fixed[free[i]] = (
                f"its a-priori value is {z[-1]:.2g} σ from 0 with the candidates kept before it "
                f"(below {SIGNIFICANT:g} σ)"
            )
        else:
            other = free[chosen[weak[0]]]
            fixed[free[i]] = (
                f"with it {other}, kept before it, would be {z[weak[0]]:.2g} σ from 0 at its a-priori "
                f"value (below {SIGNIFICANT:g} σ)"
            )
    return fixed


def _information(experiments, config: ModelConfig, problem: tuple, initial, substeps) -> tuple:
    """`(H, segments, why)`: the Fisher information of `config.free` and the records' measured
    initial states, each record flown from `initial` (else its best fit), with the config's noise
    (else the residuals' mean square); `problem`: `(channels, records, model, θ, free indices)`
    as `setup` gives them. Where a record's flight leaves the finite numbers (an unstable
    a-priori model), the information of the records cut into the fewest segments on which the
    flights stay in the data's range (`_on_segments`), their number and why."""
    channels, recs, model, theta, idx = problem
    ch = [STATES.index(c) for c in channels]
    given = config.noise_std or {}
    held = np.array([given.get(c, np.nan) ** 2 for c in channels])
    try:
        flown = flights(experiments, config, initial, substeps=substeps)
    except Unflyable as exc:
        objective = NonlinearObjective(model, theta, np.asarray(idx), tuple(recs), tuple(ch), held, substeps)
        H, segments = _on_segments(objective, channels, config.free, config.source or "the config")
        return H, segments, exc.reason
    m = len(model.names)  # the outputs: the states as read plus their biases
    # each record's rows are among its experiment's (`flown_rows`): the flight's states there
    flown = [x[np.searchsorted(e.t, r.t)] for e, r, x in zip(experiments, recs, flown)]
    R = pooled_noise([r.y - read_outputs(x, theta, m, ch) for r, x in zip(recs, flown)], held)
    x0 = np.array([x[0] for x in flown])
    return flight_information(model, theta, x0, recs, channels, config.free, R, substeps)[0], 0, ""


def _on_segments(objective: NonlinearObjective, channels, free, source: str) -> tuple[np.ndarray, int]:
    """The information of `objective`'s records cut into the fewest segments (1, 2, 4, …, each
    of at least `LEAST_SEGMENT` rows with a sample, or `FEWEST_SEGMENT` where that is not short
    enough) on which the model at its a-priori values, flown from each segment's first sample,
    stays in the data's range, and their number; `Unflyable` where even the shortest diverge."""
    theta = objective.start
    for least in (LEAST_SEGMENT, FEWEST_SEGMENT):
        stage = objective.segmented(objective.shooting(theta, least), least)
        at = stage.point(theta)
        if at is not None:
            H = flight_information(
                stage.model,
                stage.theta,
                stage.first_states(),
                stage.records,
                channels,
                free,
                at.R,
                stage.substeps,
            )[0]
            return H, stage.pieces
    raise Unflyable(
        f"{source}: the model diverges at these coefficients even on {stage.pieces} segments of the "
        "records; expected coefficients giving a response bounded over a few seconds"
    )


def _check(experiments: Sequence[Experiment], config: ModelConfig) -> None:
    """`InputError` for what the nonlinear fit cannot take (`nonlinear_output_error.setup`)."""
    setup(config.fitted(experiments), config, "the screen of a nonlinear model config")


def _assess(experiments, config: ModelConfig, noise_std: Mapping[str, float]) -> Identifiability:
    """Stage 1: the analysis at the config's values with the noise σ `noise_std`, each record
    flown from its first sample (`first_samples`): the information moves with the initial state
    only at second order, and the fit that follows fits it (where a mounted log's velocities are
    not the states', from the best fit)."""
    config = _noise(config, noise_std)
    parts = [p for e in config.fitted(experiments) for p in split(e)]  # the records it analyses
    initial = None if np.any(config.mounting()) else first_samples(parts, config)
    return nonlinear_identifiability(experiments, config, initial=initial)


def _at_estimate(experiments, candidates: ModelConfig, fit: Estimate) -> np.ndarray:
    """Stage 2: the information at the estimate `fit`, its noise and initial states (the fit's
    own, where it gives it)."""
    at = _noise(candidates.with_coefficients(fit.coefficients), fit.noise_std)
    return nonlinear_identifiability(
        experiments, at, initial=fit.initial_states, information=fit.information
    ).fisher


def _noise(config: ModelConfig, noise_std: Mapping[str, float]) -> ModelConfig:
    """`config` with the noise σ `noise_std` where positive (noise-free data read 0: their
    channels' variance is then the residuals' mean square)."""
    return replace(config, noise_std={c: s for c, s in noise_std.items() if s > 0})


NONLINEAR = ScreenModel(check=_check, assess=_assess, information=_at_estimate, unidentified=forward)
