"""testbed: simulate a submerged body in MuJoCo and identify its manoeuvring coefficients.

The public API (each name is loaded on first use, so `import testbed` stays light):

- data: `load_data`, `read_csv`, `read_config`, `Experiment`, `ModelConfig`;
- the simulation: `analytic_config` (the analytic linear model of an MJCF body);
- runs: `simulate` (fly a scenario, built-in or a file, and write its run directory);
- identification: `identify` (one front door for every method), `Estimate`, `Status`, `METHODS`;
- analysis: `analyze` (identifiability: Fisher information, Cramér-Rao bounds, drift groups),
  `screen` (the candidates the data determine), `compare` (against the analytic model),
  `validate` (fit % and residual whiteness);
- reports: `report` (a fit's self-contained HTML page: outputs, residuals, coefficients,
  correlations, convergence);
- the study: `reproduce` (the paper's study as a campaign, with its report);
- errors: `InputError` (a `ValueError`: bad input, named), `OptionError`.

The layers, each importing only those before it, are listed in docs/architecture.md.
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

_API = {
    "load_data": "testbed.data",
    "read_csv": "testbed.data",
    "read_config": "testbed.data",
    "Experiment": "testbed.data",
    "ModelConfig": "testbed.data",
    "analytic_config": "testbed.simulation.analytic",
    "simulate": "testbed.simulation.runs",
    "identify": "testbed.estimators",
    "Estimate": "testbed.estimators",
    "Status": "testbed.estimators",
    "METHODS": "testbed.estimators",
    "OptionError": "testbed.estimators",
    "analyze": ("testbed.analysis.identifiability", "identifiability"),
    "screen": "testbed.analysis.screening",
    "compare": "testbed.analysis.comparison",
    "validate": "testbed.analysis.validation",
    "report": "testbed.presentation.fit_report",
    "reproduce": "testbed.study.campaign",
    "InputError": "testbed.errors",
}

__all__ = sorted(_API)  # no name of a submodule: `from testbed import design` is the module


def __getattr__(name: str):
    if name not in _API:
        raise AttributeError(f"module 'testbed' has no attribute {name!r}")
    module, attribute = _API[name] if isinstance(_API[name], tuple) else (_API[name], name)
    value = getattr(importlib.import_module(module), attribute)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_API))
