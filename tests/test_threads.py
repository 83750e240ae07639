"""sim.threads: the thread pools a worker sizes, the BLAS library's included."""

from __future__ import annotations

import os

import numpy as np
import pytest
from threadpoolctl import threadpool_info

from sim.threads import set_blas_threads


def _blas_threads() -> list[int]:
    return [lib["num_threads"] for lib in threadpool_info() if lib.get("user_api") == "blas"]


def test_set_blas_threads_sizes_numpy_blas_and_keeps_products(monkeypatch):
    for var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):   # set_blas_threads sets them: restored after
        old = os.environ.get(var)
        monkeypatch.setenv(var, old or "1")     # recorded, so teardown puts back the old value or none
        if old is None:
            monkeypatch.delenv(var)
    np.ones((2, 2)) @ np.ones((2, 2))            # numpy's BLAS is loaded
    before = _blas_threads()
    if not before:
        pytest.skip("no BLAS library that threadpoolctl knows")
    rng = np.random.default_rng(3)
    a, x = rng.normal(size=(200_000, 3)), rng.normal(size=3)
    reference = a @ x
    try:
        assert set_blas_threads(1) == len(before)
        assert _blas_threads() == [1] * len(before)
        # the same products with one thread — to rounding, not bit for bit: how BLAS splits the rows
        # between threads picks its kernels (an FMA or not), which may differ in the last bit
        np.testing.assert_allclose(a @ x, reference, rtol=0, atol=1e-12)
    finally:
        set_blas_threads(max(before))
    assert _blas_threads() == [max(before)] * len(before)
