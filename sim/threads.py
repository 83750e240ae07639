"""How many cores this process may use, and sizing its thread pools to a share of them.

One place for what every worker process of the twin does first — the dataset's and
the study's Dask workers (:mod:`sim.dataset.engine`) and the render workers of
:func:`sim.writer.render_folder` — so that they all run alike:

* :func:`cores` — the cores this process may run on (its CPU affinity);
* :func:`configure_threads` — Dr.Jit's, numba's, Blosc's and OpenBLAS's thread pools
  sized to ``n`` cores, and glibc's allocator thresholds fixed (:func:`tune_malloc`).
"""

from __future__ import annotations

import contextlib
import os
import sys

__all__ = ["configure_threads", "cores", "drjit_threads", "set_blas_threads", "tune_malloc"]

_THREADS: dict = {}


def cores() -> int:
    """The number of cores this process may run on.

    Returns
    -------
    int
        Its CPU affinity's size on Linux, else ``os.cpu_count()`` (≥ 1).
    """
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


def configure_threads(n: int) -> None:
    """Size this process's thread pools (Dr.Jit, numba, Blosc, OpenBLAS) to ``n`` cores; tune malloc.

    Also fixes glibc's allocator thresholds (:func:`tune_malloc`): Dask's nanny starts
    workers with ``MALLOC_TRIM_THRESHOLD_=65536``, which turns off glibc's adaptive mmap
    threshold, so every frame-sized array was mapped, zero-filled and unmapped again —
    measured +25 % CPU per frame in a Dask worker.  Idempotent for the same ``n``.

    Parameters
    ----------
    n : int
        Cores this worker may use (≥ 1).
    """
    n = max(1, int(n))
    if _THREADS.get("n") == n:
        return
    tune_malloc()
    import numba

    numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))
    try:
        import numcodecs.blosc

        numcodecs.blosc.set_nthreads(n)
    except ImportError:  # pragma: no cover - zarr extra missing
        pass
    try:
        import drjit as dr

        dr.set_thread_count(n)
    except (ImportError, AttributeError):  # pragma: no cover - no Dr.Jit
        pass
    set_blas_threads(n)
    _THREADS["n"] = n


@contextlib.contextmanager
def drjit_threads(n: int):
    """Dr.Jit's thread pool sized to ``n`` within the block, its size before restored after.

    The pipelined frame loop (:func:`sim.writer.render_scenario`) runs with one pool
    thread: its two threads are the parallelism, and an idle pool thread spins after
    every kernel (nanothread), which took ≈ 15 ms of CPU per ideal frame from the
    other stage (``benchmarks/RESULTS.md``).  The results do not depend on it (every
    lane's value is its own; the fixed-point images are sums of integers).

    Parameters
    ----------
    n : int or None
        Pool threads (≥ 1); None leaves the pool as it is.

    Yields
    ------
    None
        Nothing: the pool is resized around the block (no-op without Dr.Jit).

    Notes
    -----
    The thread's queued kernels are waited for before each resize (``dr.sync_thread``):
    Dr.Jit's LLVM backend runs ahead of Python, and a pool resized under a launched
    kernel is a known way to crash nanothread (mitsuba-renderer/drjit#204).  The suite
    had an intermittent segmentation fault in the pipelined loop's noise kernel
    (twice in about six full runs, never alone); this is a precaution, the cause is
    not proven.
    """
    try:
        import drjit as dr
    except ImportError:  # pragma: no cover - no Dr.Jit
        dr = None
    if dr is None or n is None:
        yield
        return
    before = dr.thread_count()
    dr.sync_thread()         # no kernel of this thread in flight while the pool is resized (below)
    dr.set_thread_count(max(1, int(n)))
    try:
        yield
    finally:
        dr.sync_thread()
        dr.set_thread_count(before)


def set_blas_threads(n: int) -> int:
    """Size the thread pool of every BLAS library loaded in this process (numpy's, scipy's) to ``n``.

    Through threadpoolctl (OpenBLAS, MKL, BLIS; the limit stays set) for the libraries
    loaded now, numpy's among them, and ``OPENBLAS_NUM_THREADS``/``MKL_NUM_THREADS``
    for those loaded later.  A one-core worker needs it: after a large matrix
    product an idle OpenBLAS thread spins on the other core (≈ 95 ms of CPU per
    realistic frame, `benchmarks/RESULTS.md`).  A long dot product's sum may be split
    among the threads, so its last bits may depend on ``n``; the twin's frames and
    truth do not (checked bit for bit, one and two threads).

    Parameters
    ----------
    n : int
        Threads (≥ 1).

    Returns
    -------
    int
        The number of BLAS libraries set.
    """
    import numpy  # noqa: F401 - loads numpy's BLAS, so that the limit reaches it
    from threadpoolctl import threadpool_info, threadpool_limits

    n = max(1, int(n))
    for var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):   # BLAS libraries loaded later (scipy's)
        os.environ[var] = str(n)
    threadpool_limits(limits=n, user_api="blas")
    return sum(1 for lib in threadpool_info() if lib.get("user_api") == "blas")


def tune_malloc() -> None:
    """Serve arrays up to 32 MB from the heap and keep up to 256 MB of it (glibc only).

    Sets ``M_MMAP_THRESHOLD`` and ``M_TRIM_THRESHOLD`` with ``mallopt``; does nothing
    where the C library cannot be loaded or is not glibc's.
    """
    import ctypes
    import ctypes.util

    name = ctypes.util.find_library("c")
    if not name or not sys.platform.startswith("linux"):
        return
    try:
        libc = ctypes.CDLL(name)
        libc.mallopt(-3, 32 << 20)    # M_MMAP_THRESHOLD
        libc.mallopt(-1, 256 << 20)   # M_TRIM_THRESHOLD
    except (OSError, AttributeError):
        return
