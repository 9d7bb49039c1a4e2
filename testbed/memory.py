"""Freed memory kept in the process for reuse, where a host set it to go back to the system.

glibc hands the top of its heap back to the system once more than M_TRIM_THRESHOLD bytes of it
are free, and serves blocks larger than M_MMAP_THRESHOLD by fresh mappings; either way the next
allocation of that size faults its pages in afresh. Dask's nanny starts workers with
`MALLOC_TRIM_THRESHOLD_=65536`, which also freezes glibc's adaptive thresholds: a simulation's
work arrays (a few hundred kB each, thousands of times per fit) then fault on every call, and on
a virtual machine the faults cost more than the arithmetic (a Scenario II simplex fit 3.6×
slower, two-thirds of its time in the kernel)."""

import ctypes
import ctypes.util

__all__ = ["MMAP_THRESHOLD", "TRIM_THRESHOLD", "keep_freed_memory"]

MMAP_THRESHOLD = 32 << 20  # bytes: blocks up to this come from the heap, not from fresh mappings
TRIM_THRESHOLD = 128 << 20  # bytes of free heap top kept before any is handed back


def keep_freed_memory() -> bool:
    """Raise glibc's mapping and trim thresholds (`mallopt`) for this process; False where the C
    library is not glibc (nothing done)."""
    name = ctypes.util.find_library("c")
    try:
        mallopt = ctypes.CDLL(name).mallopt
    except (OSError, AttributeError, TypeError):
        return False
    M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3  # <malloc.h>
    return bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD))
