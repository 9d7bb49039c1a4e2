"""One BLAS thread for the numerical core, which works on small dense matrices: there one thread
is fastest, and numpy's and scipy's OpenBLAS pools contend on small machines."""

import os

__all__ = ["one_blas_thread"]


def one_blas_thread() -> None:
    """Ask numpy's and scipy's BLAS for one thread, unless the user chose (only before numpy loads)."""
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")
