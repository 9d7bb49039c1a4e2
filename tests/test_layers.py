"""The package reads top-down: each module imports only modules of the layers below it.

The layers, in the order data flows (a module may import from any earlier layer, never from its
own or a later one): the errors and file safety; the linear model's equations; data files and
sensor noise; the MJCF vehicle, its plant and its analytic model; autopilots and input signals;
scenarios; recordings and run directories; the linear model's services; the estimators (their
contract, then the methods, then the front door); validation and identifiability analysis;
experiment design and fit reports; the headless jobs; the study's a-priori models and its judge
of success; the campaign's figures and the campaign; the command line; the public API.
"""

from __future__ import annotations

import ast
from pathlib import Path

import testbed

LAYERS = [
    (
        "testbed.errors",
        "testbed.memory",
        "testbed.threads",
        "testbed.fit_percent",
        "testbed.html_table",
        "testbed.html_figures",
    ),
    ("testbed.models", "testbed.models.linear"),
    ("testbed.models.sensors",),
    ("testbed.models.log_mounting",),
    ("testbed.models.component_kernels",),
    ("testbed.models.components",),
    ("testbed.models.regressors", "testbed.models.mechanics"),
    ("testbed.models.nonlinear_kernels",),
    ("testbed.models.nonlinear",),
    ("testbed.models.nonlinear_flight",),
    ("testbed.data",),
    ("testbed.simulation", "testbed.simulation.measurements"),
    ("testbed.simulation.vehicle",),
    ("testbed.simulation.plant", "testbed.simulation.linear_plant"),
    ("testbed.simulation.states",),
    ("testbed.simulation.nonlinear_reference",),
    ("testbed.simulation.analytic", "testbed.simulation.wrench", "testbed.simulation.fluid_components"),
    (
        "testbed.simulation.autopilot",
        "testbed.simulation.signals",
        "testbed.simulation.sensing",
        "testbed.simulation.trial",
        "testbed.simulation.prior",
        "testbed.simulation.captive",
    ),
    ("testbed.simulation.captive_fit",),
    ("testbed.simulation.captive_reference",),
    ("testbed.simulation.captive_config",),
    ("testbed.simulation.imperfect",),
    ("testbed.simulation.scenario",),
    ("testbed.simulation.recording",),
    ("testbed.simulation.runs",),
    ("testbed.identification", "testbed.identification.kernels"),
    ("testbed.identification.problem", "testbed.identification.scan"),
    ("testbed.identification.recursions",),
    ("testbed.identification.likelihood", "testbed.identification.nonlinear_sensitivities"),
    (
        "testbed.identification.bounds",
        "testbed.identification.prediction",
        "testbed.identification.nonlinear_prediction",
        "testbed.identification.nonlinear_transition",
        "testbed.identification.concentrated",
        "testbed.identification.innovations",
    ),
    ("testbed.identification.examples", "testbed.identification.nonlinear_output_error"),
    ("testbed.estimators.base", "testbed.estimators.simplex", "testbed.estimators.intervals"),
    (
        "testbed.estimators.mekf",
        "testbed.estimators.equation_error",
        "testbed.estimators.nonlinear_regression",
    ),
    ("testbed.estimators.nonlinear",),
    ("testbed.estimators.trust_region", "testbed.estimators.starts"),
    ("testbed.estimators.ml", "testbed.estimators.fem"),
    ("testbed.estimators",),
    (
        "testbed.analysis",
        "testbed.analysis.validation",
        "testbed.analysis.identifiability",
        "testbed.analysis.kinematics",
        "testbed.analysis.profile",
    ),
    (
        "testbed.analysis.regime",
        "testbed.analysis.compatibility",
        "testbed.analysis.nonlinear_identifiability",
    ),
    ("testbed.analysis.design",),
    ("testbed.analysis.drift",),
    ("testbed.analysis.instants", "testbed.analysis.track"),
    ("testbed.analysis.turning", "testbed.analysis.zigzag"),
    ("testbed.analysis.manoeuvres",),
    ("testbed.presentation", "testbed.presentation.report", "testbed.presentation.design_report"),
    ("testbed.presentation.captive_sweeps",),
    ("testbed.presentation.captive_figures", "testbed.presentation.captive_recording"),
    ("testbed.presentation.captive_report",),
    ("testbed.presentation.figures", "testbed.presentation.fit_figures"),
    ("testbed.presentation.fit_report",),
    ("testbed.jobs",),
    ("testbed.study.priors", "testbed.study.hashing"),
    ("testbed.study.rules",),
    ("testbed.study.arms",),
    ("testbed.study.cells",),
    ("testbed.study.results",),
    ("testbed.study", "testbed.study.campaign"),
    ("testbed.cli",),
    ("testbed.__main__",),
    ("testbed",),
]
PACKAGES = (
    "testbed.models",
    "testbed.simulation",
    "testbed.identification",
    "testbed.estimators",
    "testbed.analysis",
    "testbed.presentation",
    "testbed.study",
)
RANK = {name: k for k, names in enumerate(LAYERS) for name in names}
ROOT = Path(testbed.__file__).parent


def _module(path: Path) -> str:
    parts = ["testbed", *path.relative_to(ROOT).with_suffix("").parts]
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path) -> set[str]:
    """The testbed modules `path` imports, anywhere in it (function bodies included)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            submodules = {f"{node.module}.{a.name}" for a in node.names} & set(RANK)
            names = [a for a in node.names if f"{node.module}.{a.name}" not in RANK]
            found |= submodules | ({node.module} if names else set())
    return {m for m in found if m == "testbed" or m.startswith("testbed.")}


def test_every_module_has_a_layer():
    modules = {_module(p) for p in ROOT.rglob("*.py")}
    assert sorted(modules - set(RANK)) == []
    assert sorted(set(RANK) - modules) == []


def test_no_import_points_up_or_sideways():
    upward = []
    for path in sorted(ROOT.rglob("*.py")):
        me = _module(path)
        for target in _imports(path):
            owner = target if target in RANK else target.rsplit(".", 1)[0]
            if owner in RANK and RANK[owner] >= RANK[me] and owner != me:
                upward.append(f"{me} imports {target}")
    assert upward == []


def test_the_folders_follow_the_layers():
    """Each subpackage's modules come after every module of the subpackages before it."""
    spans = [[RANK[m] for m in RANK if m == package or m.startswith(package + ".")] for package in PACKAGES]
    assert [(max(a), min(b)) for a, b in zip(spans, spans[1:]) if max(a) > min(b)] == []


def test_the_check_sees_an_upward_import(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text("def f():\n    from testbed.cli import main\n")
    assert "testbed.cli" in _imports(bad)


def test_the_public_api_loads_on_demand_and_shadows_no_module():
    import subprocess
    import sys

    assert not {n for n in testbed.__all__ if f"testbed.{n}" in RANK}
    code = (
        "import sys, testbed; assert 'numpy' not in sys.modules; "
        "[getattr(testbed, n) for n in testbed.__all__]; print('mujoco' in sys.modules)"
    )
    assert (
        subprocess.run(
            [sys.executable, "-c", code], capture_output=True, text=True, check=True
        ).stdout.strip()
        == "True"
    )


def test_the_architecture_page_names_every_module_in_layer_order():
    text = (ROOT.parent / "docs" / "architecture.md").read_text(encoding="utf-8")
    names = [m.removeprefix("testbed.") for names in LAYERS[:-2] for m in names]
    positions = [text.find(f"`{n}`") for n in names]
    assert [n for n, p in zip(names, positions) if p < 0] == []
    assert positions == sorted(positions)


def test_fitting_a_csv_loads_neither_mujoco_nor_rerun_nor_a_compiler():
    import subprocess
    import sys

    code = (
        "import sys, testbed.cli, testbed.jobs, testbed.estimators; "
        "print(sorted({'mujoco', 'rerun', 'numba', 'scipy'} & set(sys.modules)))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "[]"
