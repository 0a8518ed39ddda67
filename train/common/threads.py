"""One BLAS/OpenMP thread per process: the parallelism is across episodes and runs.

Imports nothing but :mod:`os`, so an entry point can call :func:`one_thread_defaults`
before numpy loads (BLAS reads the variables once, when it loads).
"""

from __future__ import annotations

import os

#: The thread-count variables of OpenMP, OpenBLAS and MKL.
ONE_THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def one_thread_defaults() -> None:
    """Set each of :data:`ONE_THREAD_VARS` to 1 in this process's environment unless the
    user set it: BLAS loaded afterwards here, and every worker process started from here,
    runs one thread."""
    for name in ONE_THREAD_VARS:
        os.environ.setdefault(name, "1")
