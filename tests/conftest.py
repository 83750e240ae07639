import os

import numpy as np
import pytest

os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture
def rng():
    """A seeded generator (mitsuba3's test style: one fixture, no re-seeding helpers)."""
    return np.random.default_rng(20261121)


@pytest.fixture(scope="module")
def variant():
    """The Mitsuba JIT variant the renderer needs; the test is skipped without a libLLVM ≥ 17."""
    from sim.variant import is_jit_variant, select_variant

    v = select_variant()
    if not is_jit_variant(v):
        pytest.skip("no usable libLLVM ≥ 17: the renderer needs a JIT variant")
    return v


@pytest.fixture
def paper_rig():
    from scheimpflug.model.rig import load_preset

    return load_preset("paper")
