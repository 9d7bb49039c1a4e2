"""What a campaign's cell is keyed by besides its inputs: the package's code, hashed, so a cell
computed by other code is computed again."""

from __future__ import annotations

import functools
import hashlib
import os
from pathlib import Path

__all__ = ["CODE_FILES", "code_hash", "source_hash"]

CODE_FILES = ("*.py", "*.toml", "*.xml")  # what the package computes with: its modules and data


def source_hash(root: str | os.PathLike) -> str:
    """SHA-256 of the package's code under `root`: every file matching `CODE_FILES`, by its path
    relative to `root` and its bytes, in path order (compiled caches and other files ignored)."""
    root = Path(root)
    files = sorted({p for pattern in CODE_FILES for p in root.rglob(pattern) if "__pycache__" not in p.parts})
    h = hashlib.sha256()
    for p in files:
        data = p.read_bytes()
        h.update(f"{p.relative_to(root).as_posix()}\0{len(data)}\0".encode())
        h.update(data)
    return h.hexdigest()


@functools.lru_cache(maxsize=None)
def code_hash() -> str:
    """`source_hash` of this installation of testbed."""
    return source_hash(Path(__file__).resolve().parents[1])
