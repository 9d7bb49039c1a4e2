"""Simultaneous drift measured in practice: the inertia terms free against the inertia known.

The coefficients of `Mt ẋ = At x + Bt δ + St` are not globally identifiable: with Mt unknown a
row can be scaled, or combined with the rows its inertia couples it to, and the outputs stay the
same (`structural.structural` finds these exact null directions). The practical question
is whether, once the rows are normalised so that no exact null direction is left, the fit with
the inertia terms free (the Mt-form) still drifts more than the fit of the same data with the
inertia known (the A-form: `ẋ = Mt⁻¹At x + Mt⁻¹Bt δ`, only At and Bt coefficients free).

Both forms are compared through their Fisher information in relative coordinates (θ_i / s_i,
`design.scales`): its condition number, its largest correlation, and its near-null directions
(the eigenvectors of the scaled information with the smallest eigenvalues). Along a near-null
direction v with eigenvalue λ the Cramér-Rao σ is 1/√λ; the seeds' estimates projected on v
scatter with that σ if the drift is the noise the bounds predict (`evidence`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Mapping, Sequence

import numpy as np

from testbed.analysis.design_model import scales
from testbed.analysis.structural import structural
from testbed.data import Experiment, ModelConfig
from testbed.errors import InputError
from testbed.identification.bounds import crlb, fisher
from testbed.models.linear import COEFFICIENTS, ITHETA, IX, STATES, structure, theta_vector
from testbed.simulation.measurements import noise_from_data

__all__ = [
    "ADDED_MASS",
    "DIAGONAL",
    "Form",
    "Forms",
    "NAMED",
    "NEAR_NULL",
    "evidence",
    "form",
    "forms",
    "normalised",
]

ADDED_MASS = tuple(n for n in COEFFICIENTS if n.endswith("dot"))  # the coefficients of Mt
# each row's diagonal inertia term (m − X_udot, …, Iz − N_rdot): the row's scale
DIAGONAL = ("X_udot", "Y_vdot", "Z_wdot", "K_pdot", "M_qdot", "N_rdot")
NEAR_NULL = 3  # the near-null directions compared: the smallest eigenvalues of the scaled Fisher
NAMED = 6  # components of the worst direction reported, the largest first


def normalised(config: ModelConfig) -> ModelConfig:
    """The Mt-form free set: `config.free` and the off-diagonal added-mass terms, normalised so
    that no exact null direction is left.

    Each row's diagonal inertia term (`DIAGONAL`) stays at its a-priori value, which pins the
    row's scale. One diagonal per row is not enough where Mt couples three rows: the torpedo's
    lateral rows v, p, r (Y_pdot, Y_rdot, K_vdot, K_rdot, N_vdot, N_pdot) keep one exact null
    direction each, a row plus a multiple of another that leaves its diagonal unchanged (the
    vertical rows w, q are pinned through the restoring moment z_B B in q's row, which w's row
    does not have; weakly, so M_wdot drifts in practice: docs/studies.md). So, while `structural` finds a null direction with every state measured, the
    added-mass term with the largest relative component (|v_i| / s_i) along one is fixed too
    (on the Scenario II torpedo: Y_rdot, K_rdot, N_vdot, leaving Y_pdot, Z_qdot, K_vdot,
    M_wdot, N_pdot free). The result has 0 exact null directions when every state is measured:
    with the inertia known and every state measured nothing drifts (`structural`: E Mt = 0
    forces E = 0), so at the latest the loop ends when every inertia term is fixed.
    """
    s, theta = structure(config.vehicle), theta_vector(config.coefficients)
    free = [*config.free, *(n for n in ADDED_MASS if n not in config.free and n not in DIAGONAL)]
    free = [n for n in free if n not in DIAGONAL]
    while True:
        null = structural(s, theta, free, STATES)
        if not null.null_directions:
            return replace(config, free=tuple(free))
        rel = null.basis / scales(replace(config, free=tuple(free)))
        rel /= np.linalg.norm(rel, axis=1, keepdims=True)
        inertia = [i for i, n in enumerate(free) if n in ADDED_MASS]
        free.pop(inertia[int(np.argmax(np.abs(rel[:, inertia]).max(0)))])


@dataclass(frozen=True)
class Form:
    """The Fisher information of one free set at `values`, in relative coordinates θ_i / s_i.

    `eigenvalues` ascending and `eigenvectors` (columns) of `S F S`, S = diag(`scales`): along
    column j the relative Cramér-Rao σ is 1/√eigenvalues[j]. `correlation`: the pair of largest
    |ρ| (Cramér-Rao correlation), as (name, name, ρ)."""

    free: tuple[str, ...]
    values: np.ndarray
    scales: np.ndarray
    fisher: np.ndarray
    eigenvalues: np.ndarray
    eigenvectors: np.ndarray
    correlation: tuple[str, str, float]

    @property
    def condition(self) -> float:
        """λ_max / λ_min of the scaled information (inf where it is singular)."""
        return float(self.eigenvalues[-1] / self.eigenvalues[0]) if self.eigenvalues[0] > 0 else np.inf


def form(F: np.ndarray, config: ModelConfig) -> Form:
    """The `Form` of the information `F` of `config.free` at the config's coefficients."""
    s = scales(config)
    lam, V = np.linalg.eigh(F * np.outer(s, s))
    largest = V[np.argmax(np.abs(V), 0), np.arange(len(V))]
    V *= np.where(largest < 0, -1.0, 1.0)  # each direction's sign: its largest component positive
    corr = crlb(F).correlation
    rho = np.abs(np.nan_to_num(corr))
    np.fill_diagonal(rho, -1.0)
    i, j = sorted(np.unravel_index(np.argmax(rho), rho.shape))
    return Form(
        free=tuple(config.free),
        values=theta_vector(config.coefficients)[[ITHETA[n] for n in config.free]],
        scales=s,
        fisher=F,
        eigenvalues=lam,
        eigenvectors=V,
        correlation=(config.free[i], config.free[j], float(corr[i, j])),
    )


@dataclass(frozen=True)
class Forms:
    """The Mt-form (`mt`: `normalised(config)`) and the A-form (`a`: the config's free set with the
    inertia known) of the same data; `null_directions_mt`: the Mt-form's exact null directions
    with the data's measured states (0 where every state is measured)."""

    mt: Form
    a: Form
    null_directions_mt: int
    noise_std: Mapping[str, float]


def forms(
    experiments: Sequence[Experiment], config: ModelConfig, noise_std: Mapping[str, float] | None = None
) -> Forms:
    """The Fisher information of both forms at the config's coefficients (`bounds.fisher`, the
    initial states eliminated). `noise_std`: the measurement noise per channel, default the
    config's, else read off the data (`noise_from_data`) — not the residual at the config's
    coefficients, which holds the a-priori model's error too."""
    data = config.fitted(experiments)
    noise = dict(noise_std) if noise_std is not None else noise_from_data(data, config.noise_std)
    mt = normalised(config)
    a = replace(config, free=tuple(n for n in config.free if n not in ADDED_MASS))
    measured = sorted({m for e in data for m in e.measured}, key=list(IX).index)
    null = structural(structure(config.vehicle), theta_vector(config.coefficients), mt.free, measured)
    return Forms(
        mt=form(fisher(data, mt, noise_std=noise), mt),
        a=form(fisher(data, a, noise_std=noise), a),
        null_directions_mt=null.null_directions,
        noise_std=noise,
    )


def _projections(f: Form, estimates: Sequence[Mapping[str, float]], k: int, what: str) -> np.ndarray:
    """The estimates' relative deviations from `f.values` along the k worst directions, (seeds, k)."""
    if len(estimates) < 2:
        raise InputError(f"{what}: {len(estimates)} estimate(s); expected at least 2 seeds for a scatter")
    for e in estimates:
        missing = [n for n in f.free if n not in e]
        if missing:
            raise InputError(
                f"{what}: an estimate has no {missing[0]}; expected every one of {', '.join(f.free)}"
            )
    theta = np.array([[float(e[n]) for n in f.free] for e in estimates])
    if not np.isfinite(theta).all():
        seed, i = np.argwhere(~np.isfinite(theta))[0]
        raise InputError(f"{what}[{seed}]: {f.free[i]} = {theta[seed, i]}; expected finite estimates")
    Z = (theta - f.values) / f.scales
    return Z @ f.eigenvectors[:, :k]


def _scatter(f: Form, P: np.ndarray) -> np.ndarray:
    """Per direction: the seeds' sample σ along it over its Cramér-Rao σ."""
    return P.std(0, ddof=1) * np.sqrt(f.eigenvalues[: P.shape[1]])


def _shared_scatter(f: Form, estimates: Sequence[Mapping[str, float]], names: Sequence[str]) -> float:
    """The rms over `names` (a subset of `f.free`) of the seeds' sample σ of the estimate over s_i."""
    i = [f.free.index(n) for n in names]
    theta = np.array([[float(e[n]) for n in names] for e in estimates])
    return float(np.sqrt(np.mean((theta.std(0, ddof=1) / f.scales[i]) ** 2)))


def evidence(
    forms: Forms,
    estimates_mt: Sequence[Mapping[str, float]],
    estimates_a: Sequence[Mapping[str, float]],
    k: int = NEAR_NULL,
) -> dict:
    """What the seeds' estimates say about drift, JSON-able.

    `estimates_mt`, `estimates_a`: one {name: value} per seed (at least 2, finite: the caller
    chooses which fits count), fitted in the Mt-form and in the A-form. Each form's estimates
    are projected on its own k worst directions (relative coordinates); `null_scatter_*` is the
    rms over those directions of (the seeds' sample σ along the direction) / (its Cramér-Rao σ):
    ≈ 1 where the drift is the noise the bounds predict (with n seeds, within the sampling error
    of a σ from n − 1 degrees of freedom), ≫ 1 where it is more. Keys:
      condition_mt, condition_a: condition numbers of the scaled Fisher informations;
      correlation_mt, correlation_a: [name, name, ρ], the pair of largest |ρ|;
      null_scatter_mt, null_scatter_a (and per direction, worst first: *_directions);
      null_direction_mt: the Mt-form's worst direction, its `NAMED` largest components by name;
      relative_drift_mt: the rms over the seeds of the relative deviation along that direction
          from the coefficients the information was evaluated at (a bias there counts too);
      relative_scatter_mt: the seeds' sample σ along it (relative);
      relative_drift_a: the same as relative_drift_mt along the A-form's own worst direction;
      shared_scatter_mt, shared_scatter_a: on the coefficients both forms estimate (the A-form's
          free set, which the Mt-form frees too), the rms over them of (the seeds' sample σ of
          the estimate) / s_i (|θ_i| at the information's coefficients, `design.scales`): the
          like-for-like scatter of the At, Bt coefficients with the inertia free and known;
      eigenvalue_mt, eigenvalue_a: the smallest eigenvalues (1/σ² in relative units);
      inertia_free_mt: the added-mass terms free in the Mt-form; null_directions_mt: its exact
          null directions with the data's measured states; near_null: k; seeds.
    """
    mt, a = forms.mt, forms.a
    k_mt, k_a = min(k, len(mt.free)), min(k, len(a.free))
    P_mt = _projections(mt, estimates_mt, k_mt, "estimates_mt")
    P_a = _projections(a, estimates_a, k_a, "estimates_a")
    r_mt, r_a = _scatter(mt, P_mt), _scatter(a, P_a)
    worst = mt.eigenvectors[:, 0]
    shared_mt, shared_a = (_shared_scatter(f, e, a.free) for f, e in ((mt, estimates_mt), (a, estimates_a)))
    top = np.argsort(-np.abs(worst))[:NAMED]
    return {
        "condition_mt": mt.condition,
        "condition_a": a.condition,
        "correlation_mt": list(mt.correlation),
        "correlation_a": list(a.correlation),
        "null_scatter_mt": float(np.sqrt(np.mean(r_mt**2))),
        "null_scatter_a": float(np.sqrt(np.mean(r_a**2))),
        "null_scatter_mt_directions": [float(r) for r in r_mt],
        "null_scatter_a_directions": [float(r) for r in r_a],
        "null_direction_mt": {mt.free[i]: float(worst[i]) for i in top},
        "relative_drift_mt": float(np.sqrt(np.mean(P_mt[:, 0] ** 2))),
        "relative_scatter_mt": float(P_mt[:, 0].std(ddof=1)),
        "relative_drift_a": float(np.sqrt(np.mean(P_a[:, 0] ** 2))),
        "shared_scatter_mt": shared_mt,
        "shared_scatter_a": shared_a,
        "eigenvalue_mt": float(mt.eigenvalues[0]),
        "eigenvalue_a": float(a.eigenvalues[0]),
        "inertia_free_mt": [n for n in mt.free if n in ADDED_MASS],
        "null_directions_mt": forms.null_directions_mt,
        "near_null": k,
        "seeds": len(estimates_mt),
    }
