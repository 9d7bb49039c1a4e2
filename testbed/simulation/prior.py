"""A scenario's a-priori model: the run's analytic model with some coefficients scaled.

A scenario file's `[prior]` table asks its runs for a second model config beside `model.toml`,
`prior.toml`: the a-priori model a user starts an identification from, as a published
coefficient set of a similar vehicle would be — the same vehicle and trim, each coefficient
`scale` names multiplied by its factor, and the names of `free` added to the candidates:

```toml
[prior]
scale = {N_v = 10.0, N_r = 0.25}        # coefficient = factor on its analytic value
free = ["b_phi", "b_theta", "b_psi"]    # estimated besides the analytic model's candidates
```
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Mapping

from testbed.data import ModelConfig, check_free, number
from testbed.errors import InputError, check_keys
from testbed.models.linear import COEFFICIENTS

__all__ = ["PRIOR_KEYS", "Prior", "parse_prior", "prior_config", "prior_table"]

PRIOR_KEYS = ("scale", "free")


@dataclass(frozen=True)
class Prior:
    """The a-priori model of a scenario's runs: coefficient → factor on its analytic value, and
    the names freed besides the analytic model's candidates."""

    scale: Mapping[str, float] = field(default_factory=dict)
    free: tuple[str, ...] = ()


def parse_prior(doc, where: str) -> Prior | None:
    """The `Prior` of a `[prior]` table (`where`: the file and table), None without one."""
    if doc is None:
        return None
    if not isinstance(doc, Mapping):
        raise InputError(f"{where}: expected a table")
    check_keys(doc, PRIOR_KEYS, where)
    scale = doc.get("scale", {})
    if not isinstance(scale, Mapping):
        raise InputError(f"{where}.scale: expected a table of coefficient = factor")
    for name in scale:
        if name not in COEFFICIENTS:
            raise InputError(
                f"{where}.scale.{name}: not a coefficient; expected names of {', '.join(COEFFICIENTS)}"
            )
    free = doc.get("free", [])
    if not isinstance(free, list) or not all(isinstance(n, str) for n in free):
        raise InputError(f"{where}.free = {free!r}; expected a list of names")
    return Prior(
        scale={k: number(v, f"{where}.scale.{k}") for k, v in scale.items()},
        free=check_free(free, f"{where}.free"),
    )


def prior_table(p: Prior) -> dict:
    """The `[prior]` table of `p` (`parse_prior` reads it back to an equal one)."""
    return {"scale": dict(p.scale), "free": list(p.free)}


def prior_config(config: ModelConfig, p: Prior) -> tuple[ModelConfig, dict[str, str]]:
    """The a-priori model from the run's analytic model `config`: its coefficients scaled, its
    free list extended; and a comment per scaled coefficient giving its analytic value."""
    coefficients = {**config.coefficients, **{k: f * config.coefficients[k] for k, f in p.scale.items()}}
    free = config.free + tuple(n for n in p.free if n not in config.free)
    comments = {
        k: f"the analytic {config.coefficients[k]:.6g} times {f:g} ([prior] scale)"
        for k, f in p.scale.items()
    }
    return replace(config, coefficients=coefficients, free=free), comments
