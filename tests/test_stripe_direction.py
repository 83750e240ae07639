"""A frame folder's stripe_along checked against the calibration (issue 34 item 3, the reconstruct half).

A part turning about the vertical axis is cut by the sheet along the sheet's height axis: the
calibration says which way that runs in the image.  Synthetic calibrations (the paper form; the
same turned by 90° and by 45°) and FabScan's own config (skipped, saying so, without
``../shared/realdata``).
"""

import glob
import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from scheimpflug.app.cli import main
from scheimpflug.calibration import Calibration, load_calibration
from scheimpflug.calibration.direction import (
    height_direction_px,
    stripe_along_from_calibration,
    stripe_direction_problem,
)

ROWS, COLS = 200, 300
U_H, V_H, F2, D0, C = 800.0, 100.0, -1.0e5, -100.0, 100.0
AXIS, RADIUS = 80.0, 20.0
REAL = Path(__file__).resolve().parents[2] / "shared" / "realdata"
CAL = Calibration(hinge_u_px=U_H, hinge_v_px=V_H, F2_px_mm=F2, F2_sigma_px_mm=0.0, d0_mm=D0, C_mm=C,
                  C_sigma_mm=0.0, endpoint_fit_r2=(1.0, 1.0), method="paper", columns=COLS, rows=ROWS)


class _Turned:
    """The calibration of frames turned about the image centre by ``deg`` (90: a camera on its side)."""

    def __init__(self, cal, deg):
        self.cal, self.t = cal, math.radians(deg)
        self.c = np.array([(COLS - 1) / 2, (ROWS - 1) / 2])

    def _rot(self, u, v, sign):
        du, dv = np.asarray(u, float) - self.c[0], np.asarray(v, float) - self.c[1]
        cs, sn = math.cos(self.t), sign * math.sin(self.t)
        return self.c[0] + cs * du - sn * dv, self.c[1] + sn * du + cs * dv

    def stage_from_pixel(self, u, v):
        return self.cal.stage_from_pixel(*self._rot(u, v, -1))

    def pixel_from_stage(self, s, h):
        return self._rot(*self.cal.pixel_from_stage(s, h), 1)


def test_the_paper_form_images_the_height_down_the_columns():
    d = height_direction_px(CAL, COLS, ROWS)
    # Eq. 12 at fixed u: h ∝ (v − v_h), so a height step moves along v only, toward smaller v here (C·/(u − u_h) < 0)
    np.testing.assert_allclose(d, [0.0, -1.0], atol=1e-9)
    assert stripe_along_from_calibration(CAL, COLS, ROWS) == "columns"
    assert stripe_direction_problem(CAL, COLS, ROWS, "columns") is None


@pytest.mark.parametrize(("deg", "expected"), [(90, "rows"), (-90, "rows"), (180, "columns"), (20, "columns"),
                                               (70, "rows"), (45, None)])
def test_a_turned_camera_turns_the_stripe(deg, expected):
    model = _Turned(CAL, deg)
    d = height_direction_px(model, COLS, ROWS)
    np.testing.assert_allclose(abs(d[0]), abs(math.sin(math.radians(deg))), atol=1e-6)
    assert stripe_along_from_calibration(model, COLS, ROWS) == expected
    if expected is None:                                       # oblique: nothing decided, nothing refused
        assert stripe_direction_problem(model, COLS, ROWS, "rows") is None
        assert stripe_direction_problem(model, COLS, ROWS, "columns") is None


def test_the_contradiction_names_both_directions_and_the_fix():
    msg = stripe_direction_problem(_Turned(CAL, 90), COLS, ROWS, "columns")
    assert "stripe_along = 'columns'" in msg and "along the rows" in msg and "--stripe-along rows" in msg
    msg = stripe_direction_problem(CAL, COLS, ROWS, "rows")
    assert "stripe_along = 'rows'" in msg and "--stripe-along columns" in msg
    with pytest.raises(ValueError, match="along"):
        stripe_direction_problem(CAL, COLS, ROWS, "diagonal")
    with pytest.raises(ValueError, match="frame size"):
        stripe_direction_problem(CAL, 0, ROWS, "rows")


class _Nowhere:
    def stage_from_pixel(self, u, v):
        return np.full(np.shape(u), np.nan), np.full(np.shape(u), np.nan)


def test_a_calibration_that_maps_nothing_decides_nothing():
    assert height_direction_px(_Nowhere(), COLS, ROWS) is None
    assert stripe_direction_problem(_Nowhere(), COLS, ROWS, "rows") is None


def _scan(tmp_path, rng, along):
    """A cylinder's stripe, down the columns (one column), the manifest saying ``along``."""
    u_c = U_H + F2 / (AXIS - RADIUS - D0)
    cols = np.arange(COLS)
    (tmp_path / "scan" / "frames").mkdir(parents=True)
    entries = []
    for i in range(4):
        img = 100.0 + 2000.0 * np.exp(-0.5 * ((cols - u_c) / 1.5) ** 2)[None, :] + rng.normal(0, 2.0, (ROWS, COLS))
        cv2.imwrite(str(tmp_path / "scan" / f"frames/{i:05d}.png"), np.clip(np.rint(img), 0, 65535).astype(np.uint16))
        entries.append({"file": f"frames/{i:05d}.png", "angle_deg": 90.0 * i})
    (tmp_path / "scan" / "manifest.json").write_text(json.dumps({"scenario": "rotary", "stripe_along": along,
                                                                 "frames": entries}))
    return tmp_path / "scan"


def test_reconstruct_and_axis_refuse_a_folder_read_across_its_stripe(tmp_path, rng, capsys):
    """A folder saying "rows" whose calibration images the height down the columns: refused, exit 2.

    (Read along the rows, every line lies along the stripe or beside it, with no peak across it:
    before, the error said "no stripe found"; FabScan's frames gave a cloud of scattered points
    with exit 0, test below and benchmarks/bench_saturated_stripes.py.)"""
    CAL.save(tmp_path / "cal.json")
    scan = _scan(tmp_path, rng, "rows")
    assert main(["reconstruct", str(scan), "--calibration", str(tmp_path / "cal.json"), "--axis-mm", str(AXIS),
                 "--out", str(tmp_path / "c.ply"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--stripe-along columns" in err[0] and "stripe_along = 'rows'" in err[0]
    assert not (tmp_path / "c.ply").exists()
    assert main(["reconstruct", str(scan), "--calibration", str(tmp_path / "cal.json"), "--axis-from", str(scan),
                 "--out", str(tmp_path / "c.ply"), "--quiet"]) == 2
    assert "--stripe-along columns" in capsys.readouterr().err
    assert main(["axis", str(scan), "--calibration", str(tmp_path / "cal.json")]) == 2
    assert "--stripe-along columns" in capsys.readouterr().err
    manifest = json.loads((scan / "manifest.json").read_text())
    (scan / "manifest.json").write_text(json.dumps({**manifest, "stripe_along": "columns"}))
    assert main(["reconstruct", str(scan), "--calibration", str(tmp_path / "cal.json"), "--axis-mm", str(AXIS),
                 "--out", str(tmp_path / "c.ply"), "--quiet", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["n_points"] > 4 * 50


needs_real = pytest.mark.skipif(not REAL.is_dir(), reason=f"real frames absent ({REAL}): see its README")


@needs_real
def test_fabscans_config_says_rows_and_refuses_columns(tmp_path, capsys):
    """FabScan's camera is turned: its config images the turntable's axis across the stored frames."""
    config = REAL / "fabscan" / "dummy.config.json"
    cal = load_calibration(config)
    assert stripe_along_from_calibration(cal, 1640, 1232) == "rows"
    files = sorted(glob.glob(str(REAL / "fabscan" / "scan-2_1" / "*.jpg")))[:200:50]
    out = tmp_path / "scan"
    assert main(["import", *files, "--channel", "r", "--stripe-along", "rows", "--quiet",
                 "--angles-deg=-1.8:-90", "--out", str(out)]) == 0
    manifest = json.loads((out / "manifest.json").read_text())       # a folder that says otherwise (an
    (out / "manifest.json").write_text(json.dumps({**manifest, "stripe_along": "columns"}))   # older import's)
    capsys.readouterr()
    assert main(["reconstruct", str(out), "--calibration", str(config), "--out", str(tmp_path / "c.ply"),
                 "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--stripe-along rows" in err[0], err
