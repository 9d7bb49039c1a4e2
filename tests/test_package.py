"""What a wheel of the project ships, read from pyproject.toml against the source tree: every
folder of modules under testbed/ is a package the build lists, the bundled vehicle models live
once in assets/mjcf/ and ship as testbed/vehicles/, every other file under testbed/ (the
scenarios) is package data the code reads from inside the package; and a wheel built from the
tree holds all of it. (.ci/run builds the wheel itself and runs `testbed reproduce --quick` from
it, installed.)"""

import fnmatch
import shutil
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

from testbed.simulation.scenario import SCENARIO_DIR
from testbed.simulation.vehicle import default_mjcf, vehicles

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "testbed"
ASSETS = ROOT / "assets" / "mjcf"
CONFIG = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]


def _files(folder: Path):
    return [p for p in folder.rglob("*") if p.is_file() and "__pycache__" not in p.parts]


def _folder(package: str) -> Path:
    """Where the build reads `package` from (pyproject's package-dir, else its dotted path)."""
    mapped = CONFIG.get("package-dir", {}).get(package)
    return ROOT / mapped if mapped else ROOT.joinpath(*package.split("."))


def _shipped_data() -> set[Path]:
    """The files that pyproject's package-data patterns select."""
    shipped = set()
    for package, patterns in CONFIG["package-data"].items():
        folder = _folder(package)
        for f in _files(folder):
            if any(fnmatch.fnmatch(f.relative_to(folder).as_posix(), p) for p in patterns):
                shipped.add(f)
    return shipped


def test_every_folder_of_modules_is_a_package_the_build_lists():
    listed = set(CONFIG["packages"])
    folders = {f.parent for f in _files(PACKAGE) if f.suffix == ".py"}
    assert {PACKAGE, PACKAGE / "simulation", PACKAGE / "study"} <= folders  # the walk sees the tree
    for folder in folders:
        name = ".".join(folder.relative_to(ROOT).parts)
        assert (folder / "__init__.py").is_file(), f"{name}: a folder of modules without __init__.py"
        assert name in listed, f"{name}: not in pyproject's packages"
    assert listed - {".".join(f.relative_to(ROOT).parts) for f in folders} == {"testbed.vehicles"}


def test_the_vehicle_models_live_once_in_assets_and_ship_as_package_data():
    assert _folder("testbed.vehicles") == ASSETS and default_mjcf() == ASSETS / "torpedo.xml"
    assert vehicles() == ASSETS  # in the tree; installed from a wheel, testbed/vehicles/
    assert not [f for f in _files(PACKAGE) if f.suffix == ".xml"]  # no second copy in the package
    data = {f for f in _files(PACKAGE) if f.suffix != ".py"} | set(_files(ASSETS))
    assert set(SCENARIO_DIR.glob("*.toml")) <= data and len(list(SCENARIO_DIR.glob("*.toml"))) >= 2
    assert data == _shipped_data(), sorted(str(f.relative_to(ROOT)) for f in data ^ _shipped_data())


def test_the_code_reads_its_scenarios_from_inside_the_package():
    assert SCENARIO_DIR.resolve().is_relative_to(PACKAGE)


def test_a_wheel_built_from_the_tree_holds_every_module_and_the_torpedo(tmp_path):
    """The build itself (pip, an isolated build environment): every module and data file where
    the installed package reads it, the MJCF as testbed/vehicles/torpedo.xml. Built from a copy
    of what the build reads, so nothing is left in the tree."""
    source = tmp_path / "source"
    for name in ("pyproject.toml", "README.md"):
        source.mkdir(exist_ok=True)
        (source / name).write_bytes((ROOT / name).read_bytes())
    for folder in (PACKAGE, ASSETS):
        copied = source / folder.relative_to(ROOT)
        shutil.copytree(folder, copied, ignore=shutil.ignore_patterns("__pycache__"))
    build = [
        sys.executable,
        "-m",
        "pip",
        "wheel",
        "-q",
        "--no-deps",
        "-w",
        str(tmp_path / "dist"),
        str(source),
    ]
    done = subprocess.run(build, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    (wheel,) = (tmp_path / "dist").glob("testbed-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    expected = {f.relative_to(ROOT).as_posix() for f in _files(PACKAGE) if f.suffix in (".py", ".toml")}
    expected |= {f"testbed/vehicles/{f.relative_to(ASSETS).as_posix()}" for f in _files(ASSETS)}
    assert "testbed/vehicles/torpedo.xml" in expected
    assert expected <= names, sorted(expected - names)
