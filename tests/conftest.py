import os

import numpy as np
import pytest

os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture
def rng():
    """A seeded generator (mitsuba3's test style: one fixture, no re-seeding helpers)."""
    return np.random.default_rng(20261121)


@pytest.fixture
def paper_rig():
    from scheimpflug.model.rig import load_preset

    return load_preset("paper")
