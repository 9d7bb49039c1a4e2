"""All-or-nothing writes: a user's file is never half-written nor replaced unasked.

Regular files and run directories are written to a temporary sibling and renamed, so nothing is
ever half-written. A user's file is never replaced unless asked for: an existing regular file (or
a symbolic link to one) named as an output is refused unless `force`, and an existing folder
unless `force` and it is a run directory or empty. A character device (the null device, a
terminal) or a FIFO named as an output is written into, never replaced: its content is built in a
private temporary file first and copied into it once complete. Block devices and sockets are
refused. Every refusal is an `InputError` naming the output.
"""

from __future__ import annotations
import contextlib
import os
import shutil
import stat
import tempfile
from pathlib import Path
from typing import Mapping, Sequence
from testbed.errors import InputError

__all__ = [
    "atomic_directory",
    "atomic_file",
    "atomic_write_bytes",
    "atomic_write_text",
    "check_output_directory",
    "check_output_file",
    "check_outputs",
    "is_stream",
]


def _umask() -> int:
    umask = os.umask(0)
    os.umask(umask)
    return umask


def _nearest(folder: Path) -> Path:
    """`folder` or the nearest of its ancestors that exists."""
    for ancestor in (folder, *folder.parents):
        if os.path.lexists(ancestor):
            return ancestor
    return Path(folder.anchor or ".")


def _not_a_folder(folder: Path) -> str | None:
    """Why no folder can be at `folder` or made there: it, or its nearest existing ancestor, is
    not a folder (None if it is one, or could be made)."""
    nearest = _nearest(folder)
    return None if nearest.is_dir() else f"{nearest} is a file, not a folder"


def _node(path: Path) -> os.stat_result | None:
    """`os.stat(path)` (symbolic links followed), or None if there is nothing there."""
    try:
        return os.stat(path)
    except (FileNotFoundError, NotADirectoryError):
        return None
    except OSError as exc:
        raise InputError(f"{path}: cannot reach ({exc.strerror or exc})") from None


def is_stream(path: str | os.PathLike) -> bool:
    """Whether `path` names a character device or a FIFO (written into, never replaced)."""
    st = _node(Path(path))
    return st is not None and (stat.S_ISCHR(st.st_mode) or stat.S_ISFIFO(st.st_mode))


def check_output_file(path: str | os.PathLike, label: str | None = None, force: bool = False) -> None:
    """`InputError` unless an output file can be written at `path`: a new regular file, an
    existing one (or a symbolic link to one) only with `force` (replaced), a character device or a
    FIFO (written into). `label` starts the message (default: the path)."""
    path = Path(path)
    label = label or str(path)
    st = _node(path)
    if st is None:
        why = _not_a_folder(path.parent)
        if why or not path.parent.is_dir():
            raise InputError(f"{label}: {why or f'folder {path.parent} does not exist'}")
    elif stat.S_ISDIR(st.st_mode):
        raise InputError(f"{label}: is a folder; expected a file name")
    elif stat.S_ISBLK(st.st_mode) or stat.S_ISSOCK(st.st_mode):
        kind = "a block device" if stat.S_ISBLK(st.st_mode) else "a socket"
        raise InputError(f"{label}: is {kind}; expected a regular file, a character device or a FIFO")
    elif stat.S_ISREG(st.st_mode) and not force:
        _refuse_existing(label)


def _refuse_existing(label: str) -> None:
    raise InputError(f"{label}: exists; expected a new file name, or force=True to replace it")


def check_output_directory(
    path: str | os.PathLike, force: bool = False, marker: str = "manifest.json", label: str | None = None
) -> None:
    """`InputError` unless a folder can be created at `path`, or (with `force`) replace the one
    there: only a folder that is empty or holds `marker` (a run directory) is ever replaced."""
    path = Path(path)
    label = label or str(path)
    st = _node(path)
    if st is None:
        why = _not_a_folder(path.parent)  # missing folders are made
        if why:
            raise InputError(f"{label}: {why}")
        return
    if not stat.S_ISDIR(st.st_mode):
        raise InputError(f"{label}: is a file, not a folder; expected a new run directory")
    if not force:
        raise InputError(f"{label}: already exists; expected a new folder, or force=True to replace it")
    try:
        replaceable = (path / marker).is_file() or not any(path.iterdir())
    except OSError as exc:
        raise InputError(f"{label}: cannot read ({exc.strerror or exc})") from None
    if not replaceable:
        raise InputError(
            f"{label}: is a folder without {marker}, not a run directory; force=True "
            "replaces only a run directory or an empty folder"
        )


def atomic_write_text(path: str | os.PathLike, text: str, force: bool = False) -> Path:
    """Write `text` to `path` through a temporary file in the same folder and a rename
    (`atomic_file`: an existing file is replaced only with `force`)."""
    return atomic_write_bytes(path, text.encode(), force)


def atomic_write_bytes(path: str | os.PathLike, data: bytes, force: bool = False) -> Path:
    """Write `data` to `path` through a temporary file in the same folder and a rename
    (`atomic_file`: an existing file is replaced only with `force`)."""
    with atomic_file(path, force) as tmp:
        tmp.write_bytes(data)
    return Path(path)


@contextlib.contextmanager
def atomic_file(path: str | os.PathLike, force: bool = False):
    """Yield a unique temporary file whose content becomes `path` only if the block finishes;
    on any exception (Ctrl-C included) it is removed and `path` is untouched.

    A new file is made by renaming a temporary sibling to it. An existing regular file (or the
    target of a symbolic link to one) is an `InputError` unless `force`, checked on entry and
    again before the rename (a file made meanwhile is not replaced either); with `force` the
    rename replaces it. A character device or a FIFO is written into at the end.
    """
    path = Path(path)
    check_output_file(path, force=force)
    if is_stream(path):
        with _private_temporary(path) as tmp:
            yield tmp
            _copy_into(tmp, path)
        return
    target = Path(os.path.realpath(path)) if path.is_symlink() else path
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    except OSError as exc:
        raise InputError(f"{path}: cannot write ({exc.strerror})") from None
    try:
        os.fchmod(fd, 0o666 & ~_umask())  # mkstemp makes it private; an output is not
        os.close(fd)
        yield Path(tmp)
        if not force and os.path.lexists(target):
            _refuse_existing(str(path))
        try:
            os.replace(tmp, target)
        except OSError as exc:
            raise InputError(f"{path}: cannot write ({exc.strerror or exc})") from None
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


@contextlib.contextmanager
def _private_temporary(path: Path):
    """A temporary file in the system's temporary folder, removed afterwards."""
    try:
        fd, tmp = tempfile.mkstemp(prefix="testbed-", suffix=".tmp")
    except OSError as exc:
        raise InputError(f"{path}: cannot stage the output ({exc.strerror})") from None
    os.close(fd)
    try:
        yield Path(tmp)
    finally:
        with contextlib.suppress(OSError):
            os.unlink(tmp)


def _copy_into(tmp: Path, path: Path) -> None:
    """Write the content of `tmp` into the device or FIFO `path` (opening a FIFO waits for its
    reader)."""
    try:
        with open(tmp, "rb") as src, open(path, "wb") as dst:
            shutil.copyfileobj(src, dst)
    except OSError as exc:
        raise InputError(f"{path}: cannot write ({exc.strerror or exc})") from None


@contextlib.contextmanager
def atomic_directory(path: str | os.PathLike, force: bool = False, marker: str = "manifest.json"):
    """Yield a temporary folder that becomes `path` only if the block finishes.

    An existing `path` is an error unless `force`, in which case it is replaced at the end if it
    is a folder that is empty or holds `marker` (a run directory: anything else is refused, so a
    mistyped `--out` never deletes a user's folder). Missing parent folders are made. On any
    exception (Ctrl-C included) the temporary folder and the parents made are removed and `path`
    is untouched.
    """
    path = Path(path)
    check_output_directory(path, force, marker)
    parent = path.parent
    made = [p for p in (parent, *parent.parents) if not os.path.lexists(p)]  # removed on failure
    try:
        parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".partial", dir=parent))
        tmp.chmod(0o777 & ~_umask())  # mkdtemp makes it private; a run directory is not
    except OSError as exc:
        raise InputError(f"{path}: cannot create ({exc.strerror})") from None
    try:
        yield tmp
        if path.exists():
            # a fresh empty name to move the old folder to (a rename over an empty folder)
            old = tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".old", dir=parent)
            os.replace(path, old)
            os.replace(tmp, path)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, path)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        for folder in made:  # innermost first; only if still empty
            with contextlib.suppress(OSError):
                folder.rmdir()
        raise


def check_outputs(
    read: Sequence[str | os.PathLike], outputs: Mapping[str, str | os.PathLike | None], force: bool = False
) -> None:
    """Fail before the work, not after it, when an output cannot be written: `outputs` maps a
    label (the parameter) to its path or None; `read` are the files read. No output may be an
    input (it would be clobbered) or another output, save devices and FIFOs (written into); an
    existing file is refused unless `force` (`check_output_file`)."""
    seen = {}
    for label, path in outputs.items():
        if path is None:
            continue
        named = f"{label}={str(path)!r}"
        check_output_file(path, named, force=True)  # its kind; whether it may be replaced comes last
        if is_stream(path):
            continue
        key = os.path.realpath(path)  # links resolved: two names of one file are one file
        for source in read:
            if os.path.realpath(source) == key:
                raise InputError(f"{named}: is the input {source}; expected a new file name")
        if key in seen:
            raise InputError(f"{named}: is also the {seen[key]} output; expected another name")
        seen[key] = label
        check_output_file(path, named, force)
