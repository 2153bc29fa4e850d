"""The tracking process's own thread counts (BLAS/OpenMP, OpenCV, torch).

A tracking process runs one frame after another; its parallel kernels are
small, and on a machine where other processes (ROS, camera drivers, a second
tracker) hold cores, libraries that start one thread per core spend their
time waiting for each other. graphtrack therefore runs with ``n`` threads in
every pool, one by default (``--threads N``). Measurements: benchmarks/RESULTS.md
("busy core"). A program that uses graphtrack as a library keeps its own thread
counts: :func:`limit_threads` (n) runs it as the command line does.
"""
from __future__ import annotations

import os

from graphtrack.errors import is_whole

#: environment variables read by BLAS / OpenMP runtimes when they load (and by child processes)
THREAD_ENV = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "VECLIB_MAXIMUM_THREADS",
              "NUMEXPR_NUM_THREADS")
DEFAULT_THREADS = 1


def set_thread_environment(n: int = DEFAULT_THREADS) -> None:
    """Set the BLAS/OpenMP thread variables to ``n`` for libraries not yet loaded and child processes."""
    for var in THREAD_ENV:
        os.environ[var] = str(int(n))


def limit_threads(n: int = DEFAULT_THREADS) -> None:
    """Use ``n`` threads in every pool of this process: the environment (see
    :func:`set_thread_environment`), the BLAS libraries already loaded
    (threadpoolctl), OpenCV and torch (intra-op; inter-op too while torch has
    not started parallel work)."""
    # lazy: the CLI imports this module to set the thread environment BEFORE any numerical
    # library loads (set_thread_environment); only limit_threads needs them
    import cv2
    import torch
    from threadpoolctl import threadpool_limits

    if not is_whole(n) or n < 1:
        raise ValueError(f"limit_threads: n must be a whole number of at least 1, got {n!r}")
    n = int(n)
    set_thread_environment(n)
    threadpool_limits(n)
    cv2.setNumThreads(n)
    torch.set_num_threads(n)
    try:
        torch.set_num_interop_threads(n)
    except RuntimeError:  # torch allows this once, before its first parallel work
        pass
