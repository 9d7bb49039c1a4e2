"""What a campaign's cell is keyed by besides its inputs: the package's code, hashed, so a cell
computed by other code is computed again. The modules that only read finished cells (the
results, the rules, the report, the campaign's bookkeeping, the command line) are left out: a
change to them rewrites the outputs from the same cells."""

from __future__ import annotations

import functools
from fnmatch import fnmatch
import hashlib
import os
from pathlib import Path

from testbed.simulation.vehicle import vehicles

__all__ = ["CODE_FILES", "READERS", "code_hash", "source_hash"]

CODE_FILES = ("*.py", "*.toml", "*.xml")  # what the package computes with: its modules and data
# what reads finished cells only, relative to the package (no cell's fit runs through them)
READERS = (
    "presentation/*",
    "study/results.py",
    "study/rules.py",
    "study/campaign.py",
    "cli.py",
    "jobs/*",
    "arguments.py",
    "__main__.py",
)


def source_hash(root: str | os.PathLike, vehicles: str | os.PathLike | None = None) -> str:
    """SHA-256 of the package's code under `root` and the bundled vehicle models in `vehicles`:
    every file matching `CODE_FILES` but the `READERS`, by its path relative to `root` (a vehicle
    model's under `vehicles/`) and its bytes, in path order (compiled caches and other files
    ignored)."""
    root = Path(root)
    files = {
        p.relative_to(root).as_posix(): p
        for pattern in CODE_FILES
        for p in root.rglob(pattern)
        if "__pycache__" not in p.parts
        and not any(fnmatch(p.relative_to(root).as_posix(), r) for r in READERS)
    }
    if vehicles is not None:
        folder = Path(vehicles)
        files |= {f"vehicles/{p.relative_to(folder).as_posix()}": p for p in folder.rglob("*.xml")}
    h = hashlib.sha256()
    for name in sorted(files):
        data = files[name].read_bytes()
        h.update(f"{name}\0{len(data)}\0".encode())
        h.update(data)
    return h.hexdigest()


@functools.lru_cache(maxsize=None)
def code_hash() -> str:
    """`source_hash` of this installation of testbed and its bundled vehicle models."""
    return source_hash(Path(__file__).resolve().parents[1], vehicles())
