"""A user's files: text, TOML and JSON read with one-line errors naming the file and what was
expected, and the names that become file names checked."""

from __future__ import annotations

import codecs
import json
import os
import reprlib
import stat
import tomllib
from pathlib import Path

from testbed.errors import InputError

__all__ = ["MAX_NAME", "check_name", "read_json", "read_text", "read_toml"]


def read_text(path: str | Path, expected: str) -> str:
    """The text of a regular file or a pipe: UTF-8 (or UTF-16 after its byte-order mark, as
    spreadsheets export "Unicode text"), a byte-order mark dropped, undecodable bytes replaced
    (they can only be in names or cells that are then reported or ignored). Anything else (a
    folder, a device that never ends such as /dev/zero) is an `InputError`."""
    path = Path(path)
    try:
        mode = os.stat(path).st_mode
        if stat.S_ISDIR(mode):
            raise InputError(f"{path}: is a folder; expected {expected}")
        if not (stat.S_ISREG(mode) or stat.S_ISFIFO(mode)):
            raise InputError(f"{path}: is not a regular file; expected {expected}")
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror or exc})") from None
    utf16 = data.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE))
    return data.decode("utf-16" if utf16 else "utf-8-sig", errors="replace")


def read_toml(path: str | Path, expected: str) -> dict:
    """The document of the TOML file at `path` (`read_text`); `InputError` naming the file where
    it is not valid TOML, nested too deeply to read included (a recursive parser's stack)."""
    try:
        return tomllib.loads(read_text(path, expected))
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{path}: not valid TOML ({exc}); expected {expected}") from None
    except RecursionError:
        raise InputError(f"{path}: not valid TOML (nested too deeply); expected {expected}") from None


def read_json(path: str | Path, expected: str):
    """The document of the JSON file at `path` (`read_text`); `InputError` naming the file where
    it is not valid JSON, nested too deeply to read included."""
    try:
        return json.loads(read_text(path, expected))
    except RecursionError:
        raise InputError(f"{path}: not valid JSON (nested too deeply); expected {expected}") from None
    except ValueError as exc:
        raise InputError(f"{path}: not valid JSON ({exc}); expected {expected}") from None


MAX_NAME = 100  # bytes (UTF-8) of a name that becomes a file name, with room for suffixes in 255


def check_name(name: str, where: str) -> str:
    """`name` if it can be a file or folder name by itself (an experiment's CSV, a scenario's run
    directory): a string of 1 to `MAX_NAME` bytes in UTF-8, without a folder separator (/ or \\)
    or a control character (NUL included), not starting with a dot (a hidden file, `.` and `..`);
    `InputError` naming `where` otherwise."""
    if not isinstance(name, str):
        raise InputError(f"{where} {reprlib.repr(name)}; expected a string")
    size = len(name.encode("utf-8", errors="replace"))
    if not 0 < size <= MAX_NAME or name.startswith(".") or any(c in "/\\" or c < " " for c in name):
        raise InputError(
            f"{where} {reprlib.repr(name)}{f' ({size} bytes)' if size > MAX_NAME else ''}; "
            f"expected a file name of 1 to {MAX_NAME} bytes, without / or \\, "
            "control characters or a leading dot"
        )
    return name
