"""What a wheel of the project ships, read from pyproject.toml against the source tree: every
folder of modules under testbed/ is a package the build finds, and every other file under
testbed/ (the bundled MJCF, the scenarios) is package data the code reads from inside the package.
(.ci/run builds the wheel itself and runs `testbed reproduce --quick` from it, installed.)"""

import fnmatch
import tomllib
from pathlib import Path

import setuptools

from testbed.simulation.scenario import SCENARIO_DIR
from testbed.simulation.vehicle import default_mjcf

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "testbed"
CONFIG = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]


def _files(folder: Path):
    return [p for p in folder.rglob("*") if p.is_file() and "__pycache__" not in p.parts]


def _shipped_data() -> set[Path]:
    """The files under testbed/ that pyproject's package-data patterns select."""
    shipped = set()
    for package, patterns in CONFIG["package-data"].items():
        folder = ROOT.joinpath(*package.split("."))
        for f in _files(folder):
            if any(fnmatch.fnmatch(f.relative_to(folder).as_posix(), p) for p in patterns):
                shipped.add(f)
    return shipped


def test_every_folder_of_modules_is_a_package_the_build_finds():
    find = CONFIG["packages"]["find"]
    found = set(setuptools.find_packages(where=str(ROOT), include=find["include"]))
    folders = {f.parent for f in _files(PACKAGE) if f.suffix == ".py"}
    assert {PACKAGE, PACKAGE / "simulation", PACKAGE / "study"} <= folders  # the walk sees the tree
    for folder in folders:
        name = ".".join(folder.relative_to(ROOT).parts)
        assert (folder / "__init__.py").is_file(), f"{name}: a folder of modules without __init__.py"
        assert name in found, f"{name}: not found by pyproject's packages.find"
    assert all(name == "testbed" or name.startswith("testbed.") for name in found)


def test_every_data_file_under_the_package_is_shipped():
    data = {f for f in _files(PACKAGE) if f.suffix != ".py"}
    assert default_mjcf() in data and set(SCENARIO_DIR.glob("*.toml")) <= data
    assert len(list(SCENARIO_DIR.glob("*.toml"))) >= 2  # I and II at least
    assert data == _shipped_data(), sorted(str(f.relative_to(ROOT)) for f in data ^ _shipped_data())


def test_the_code_reads_its_data_from_inside_the_package():
    for path in (default_mjcf(), SCENARIO_DIR):
        assert path.resolve().is_relative_to(PACKAGE), path
