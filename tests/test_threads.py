"""sim.threads: the thread pools a worker sizes, OpenBLAS's included."""

from __future__ import annotations

import ctypes
import sys

import numpy as np
import pytest

from sim.threads import set_blas_threads

_GETTERS = ("scipy_openblas_get_num_threads64_", "scipy_openblas_get_num_threads",
            "openblas_get_num_threads64_", "openblas_get_num_threads")


def _numpy_openblas():
    """numpy's OpenBLAS (its thread-count getter), or None when numpy uses another BLAS."""
    with open("/proc/self/maps", encoding="utf-8", errors="replace") as maps:
        paths = sorted({ln.split()[-1] for ln in maps if "openblas" in ln.lower() and ".so" in ln})
    for path in paths:
        lib = ctypes.CDLL(path)
        getter = next((getattr(lib, g) for g in _GETTERS if hasattr(lib, g)), None)
        if getter is not None:
            return getter
    return None


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="memory map: Linux only")
def test_set_blas_threads_sizes_numpy_openblas_and_keeps_products():
    np.ones((2, 2)) @ np.ones((2, 2))            # numpy's BLAS is loaded
    getter = _numpy_openblas()
    if getter is None:
        pytest.skip("numpy is not linked to OpenBLAS")
    before = getter()
    rng = np.random.default_rng(3)
    a, x = rng.normal(size=(200_000, 3)), rng.normal(size=3)
    reference = a @ x
    try:
        assert set_blas_threads(1) >= 1
        assert getter() == 1
        assert (a @ x).tobytes() == reference.tobytes()   # row products: any thread count
    finally:
        set_blas_threads(before)
    assert getter() == before
