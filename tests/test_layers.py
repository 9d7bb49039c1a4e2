"""The package reads top-down: each module imports only modules of the layers above it, as the
layer map of docs/architecture.md declares them (one table row per layer, in the order data
flows; the folders' rows in the order of their folders)."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import testbed

ROOT = Path(testbed.__file__).parent
ARCHITECTURE = ROOT.parent / "docs" / "architecture.md"


def layer_map(text: str) -> list[tuple[str, ...]]:
    """The layers of the page's "The layer map" section: per table row, the modules its first
    cell names (`models.linear` is `testbed.models.linear`; `testbed` the package itself)."""
    section = text.split("## The layer map", 1)[1]
    section = re.split(r"^## ", section, maxsplit=1, flags=re.M)[0]
    layers = []
    for line in section.splitlines():
        if line.startswith("| `"):
            names = re.findall(r"`([\w.]+)`", line.split("|")[1])
            layers.append(tuple(n if n == "testbed" else f"testbed.{n}" for n in names))
    return layers


LAYERS = layer_map(ARCHITECTURE.read_text(encoding="utf-8"))
# the folders, in the order of their rows
PACKAGES = tuple(
    dict.fromkeys(
        ".".join(m.split(".")[:2])
        for names in LAYERS
        for m in names
        if m.count(".") >= 1 and (ROOT / m.split(".")[1]).is_dir()
    )
)
RANK = {name: k for k, names in enumerate(LAYERS) for name in names}


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


def test_the_layer_map_is_read_from_the_page():
    """The map has the folders in their order and a row per layer; a row the page adds is read."""
    assert PACKAGES[:4] == ("testbed.models", "testbed.data", "testbed.simulation", "testbed.captive")
    assert LAYERS[0][0] == "testbed.errors" and LAYERS[-1] == ("testbed",)
    extra = layer_map("## The layer map\n| `a`, `b.c` | x |\n| modules | y |\n## Next\n| `d` | z |\n")
    assert extra == [("testbed.a", "testbed.b.c")]


def test_each_subpackage_docstring_names_its_modules():
    """A folder's `__init__` docstring names every module in it, so it stays the folder's map."""
    missing = []
    for package in PACKAGES:
        folder = ROOT / package.split(".")[1]
        doc = ast.get_docstring(ast.parse((folder / "__init__.py").read_text(encoding="utf-8"))) or ""
        for module in sorted(p.stem for p in folder.glob("*.py") if p.stem != "__init__"):
            if f"`{module}`" not in doc:
                missing.append(f"{package}: {module}")
    assert missing == []
