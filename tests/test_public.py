"""The public surface: every module in testbed/ declares `__all__` and every name in it exists;
the package's modules, the tests, the studies, the benchmarks and the tools reach a testbed
module only through the names in its `__all__` (or its submodules), never through a private one.
"""

from __future__ import annotations

import ast
import importlib
import inspect
from pathlib import Path

import pytest

import testbed

ROOT = Path(testbed.__file__).parent
REPO = ROOT.parent
# Being split into smaller modules, which declare their own `__all__`.


def module_name(path: Path) -> str:
    parts = path.relative_to(REPO).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {module_name(p): p for p in sorted(ROOT.rglob("*.py"))}


def declared_all(path: Path) -> ast.expr | None:
    """The expression a module assigns to `__all__` at its top level, or None."""
    for node in ast.parse(path.read_text(encoding="utf-8")).body:
        targets = node.targets if isinstance(node, ast.Assign) else [getattr(node, "target", None)]
        if any(isinstance(t, ast.Name) and t.id == "__all__" for t in targets) and node.value is not None:
            return node.value
    return None


@pytest.mark.parametrize("name", sorted(MODULES))
def test_every_module_declares_all_and_every_name_in_it_exists(name):
    declared = declared_all(MODULES[name])
    assert declared is not None, f"{MODULES[name]}: no __all__"
    if name == "testbed.__main__":  # importing it runs the command line: it exports nothing
        assert ast.literal_eval(declared) == []
        return
    module = importlib.import_module(name)
    assert len(set(module.__all__)) == len(module.__all__), f"{name}: a name twice in __all__"
    missing = [n for n in module.__all__ if not hasattr(module, n)]
    assert missing == [], f"{name}: __all__ names {missing}, which it does not have"
    assert [n for n in module.__all__ if n.startswith("_")] == [], f"{name}: a private name in __all__"


def uses(path: Path):
    """(line, module, name) for every name a file takes from a testbed module: `from M import N`,
    and `A.N` or `getattr(A, "N")` where A is a testbed module bound by an import."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    bound: dict[str, str] = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module in MODULES:
            for a in node.names:
                sub = f"{node.module}.{a.name}"
                if sub in MODULES:
                    bound[a.asname or a.name] = sub
                else:
                    yield node.lineno, node.module, a.name
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.name in MODULES:
                    bound[a.asname or a.name.split(".")[0]] = a.name if a.asname else a.name.split(".")[0]
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "getattr" and len(node.args) >= 2:
            target, attr = node.args[0], node.args[1]
            if isinstance(target, ast.Name) and target.id in bound and isinstance(attr, ast.Constant):
                yield node.lineno, bound[target.id], attr.value
        if not isinstance(node, ast.Attribute):
            continue
        chain, x = [], node
        while isinstance(x, ast.Attribute):
            chain.append(x.attr)
            x = x.value
        if isinstance(x, ast.Name) and x.id in bound:
            module = bound[x.id]
            for attr in reversed(chain):  # testbed.simulation.scenario.BUILTIN: walk the submodules
                if f"{module}.{attr}" not in MODULES:
                    yield node.lineno, module, attr
                    break
                module = f"{module}.{attr}"


def files():
    for folder in ("testbed", "tests", "studies", "benchmarks", "tools"):
        yield from sorted((REPO / folder).rglob("*.py"))


def test_everything_uses_only_the_public_names():
    wrong = set()
    for path in files():
        if path.parent.name == "tests" and path.name == "test_public.py":
            continue
        own = module_name(path) if path.is_relative_to(ROOT) else None
        for line, module, name in uses(path):
            dunder = name.startswith("__") and name.endswith("__")  # __file__, __doc__, __version__
            if dunder or module == own:
                continue
            public = importlib.import_module(module).__all__
            if name not in public and not inspect.ismodule(
                getattr(importlib.import_module(module), name, None)
            ):
                wrong.add(f"{path.relative_to(REPO)}:{line}: {module}.{name}")
    assert not wrong, "\n".join(sorted(wrong))


def test_the_checks_find_a_private_name_and_a_name_outside_all(tmp_path):
    """The scan above sees each form of use."""
    probe = tmp_path / "probe.py"
    probe.write_text(
        "from testbed.simulation.recording import _quat_wxyz_to_xyzw\n"
        "from testbed.simulation import scenario as sc\n"
        "import testbed.data\n"
        "sc._TOP\n"
        "getattr(sc, '_EXPERIMENT')\n"
        "testbed.data.read_text\n"
    )
    found = {(m, n) for _, m, n in uses(probe)}
    assert found == {
        ("testbed.simulation.recording", "_quat_wxyz_to_xyzw"),
        ("testbed.simulation.scenario", "_TOP"),
        ("testbed.simulation.scenario", "_EXPERIMENT"),
        ("testbed.data", "read_text"),
    }
    assert "read_text" not in importlib.import_module("testbed.data").__all__


def _defined(path: Path) -> set[str]:
    """The names a module defines at its top level (functions, classes, assignments), not those it
    imports."""
    names = set()
    for node in ast.parse(path.read_text(encoding="utf-8")).body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            names |= {t.id for t in targets if isinstance(t, ast.Name)}
    return names


def test_each_public_name_is_defined_in_one_module():
    """A public name means one thing: no two modules define a name of the same spelling in their
    `__all__` (a package re-exporting a submodule's name defines nothing)."""
    where: dict[str, list[str]] = {}
    for name, path in MODULES.items():
        declared = declared_all(path)
        public = set(ast.literal_eval(declared)) if isinstance(declared, (ast.List, ast.Tuple)) else set()
        for n in sorted(public & _defined(path)):
            where.setdefault(n, []).append(name)
    assert {n: ms for n, ms in where.items() if len(ms) > 1} == {}
