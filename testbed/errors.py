"""Bad input: every user-facing failure is an `InputError` (a `ValueError`) whose message is one
line naming the file, field or value and what was expected; the command line turns it into exit
status 2. With the checks every reader shares: a table's keys, a number.
"""

from __future__ import annotations
import math
import numbers
import unicodedata
from typing import Mapping, Sequence

__all__ = ["InputError", "Unflyable", "check_keys", "is_number", "one_line", "printable"]


def printable(text: str) -> str:
    """`text` with each control character and line or paragraph separator escaped as a Python
    string literal writes it (`\\n`, `\\x00`, `\\u2028`): a file name or a cell holding a line
    break stays on the line of the message that names it."""
    return "".join(
        c.encode("unicode_escape").decode("ascii") if unicodedata.category(c) in ("Cc", "Zl", "Zp") else c
        for c in text
    )


class InputError(ValueError):
    """Bad input from a user: the message is one line, fit to print as it is (`printable`: a
    name holding a line break is escaped where any message names it)."""

    def __init__(self, message: str = ""):
        super().__init__(printable(str(message)))


class Unflyable(InputError):
    """The model cannot be flown on the records at these coefficients: it has no information
    there (an `InputError`: exit 2 where the user's config is at fault; an analysis that can
    cut the records into segments tries them first). `reason`: how it diverges, without the file
    or the expectation the message adds (the message where none is given)."""

    def __init__(self, message: str = "", reason: str = ""):
        super().__init__(message)
        self.reason = printable(reason) if reason else str(self)


def one_line(exc: BaseException) -> str:
    """`Type: message` of an exception on one line, for a result that records why it failed."""
    return f"{type(exc).__name__}: {' '.join(str(exc).split())}"


def check_keys(table: Mapping, keys: Sequence[str], where: str) -> None:
    """`InputError` naming the first (sorted) key of a file's `table` that is not one of `keys`."""
    unknown = sorted(set(table) - set(keys))
    if unknown:
        raise InputError(f"{where}: unknown key {unknown[0]!r}; expected {', '.join(keys)}")


def is_number(v) -> bool:
    """A finite real number (Python's or NumPy's); a bool is not one (`true` is no quantity)."""
    if isinstance(v, bool) or not isinstance(v, numbers.Real):
        return False
    return isinstance(v, numbers.Integral) or math.isfinite(v)  # an integer of any size is finite
