import glob
import os
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("MPLBACKEND", "Agg")

#: Real frames of real scanners (not in the project: licences in its README); tests using them skip without.
REAL = Path(__file__).resolve().parents[2] / "shared" / "realdata"


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


@pytest.fixture(scope="session")
def fabscan_scan(tmp_path_factory):
    """20 frames of one turn of FabScan's ``scan-2_1`` imported (read only by the tests that share it)."""
    if not REAL.is_dir():
        pytest.skip(f"real frames absent ({REAL})")
    from scheimpflug.app.cli import main
    from scheimpflug.calibration.fabscan import fabscan_angles_deg

    files = sorted(glob.glob(str(REAL / "fabscan" / "scan-2_1" / "*.jpg")))[:200:10]   # 20 of one turn
    angles = fabscan_angles_deg(200, 6400, resolution=2)[:200:10]
    out = tmp_path_factory.mktemp("fabscan") / "scan"
    assert main(["import", *files, "--channel", "r", "--stripe-along", "rows", "--quiet",
                 f"--angles-deg={','.join(f'{a:g}' for a in angles)}", "--out", str(out)]) == 0
    return out
