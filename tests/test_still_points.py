"""The housing told from the part by what stands still (issue 36 item 1): :mod:`scheimpflug.still_points`.

Synthetic stripes with known truth: a still wall (a straight line with ±0.2 px uniform noise, hidden
in half the frames over part of its length), a part whose stripe moves with the angle by
tens of pixels, a turning table whose line wobbles once per turn (±2, ±4 or ±12 px); a calibration
stub mapping pixel (u, v) to the camera point (u/2, v/2, 100) mm with the turntable's axis
along y through (100, 0, 100) mm, so that a pixel's distance from the axis is |u/2 − 100| mm
and its height v/2 mm — the closed forms the table and FabScan's radius rule are checked
against.  One slow test on FabScan's real frames (skipped, saying so, without them).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from scheimpflug.reconstruct import FolderStripes
from scheimpflug.still_points import (
    beyond_turntable,
    separate_housing,
    still_mask,
    still_regions,
    turntable_radius_mm,
)

N_FRAMES = 40
WALL = np.arange(0, 100)            # still wall's lines (columns: the stripe along the rows)
PART = np.arange(100, 260)          # the part's
TABLE = np.arange(260, 320)         # the table's (wobbles)
HIDDEN = np.arange(80, 100)         # wall lines the part hides in frames 0 … 19


def _scan(seed: int = 0, table_wobble_px: float = 2.0) -> tuple[FolderStripes, list]:
    """Stripes of N_FRAMES frames; and per frame the truth label of each point (w, p, t)."""
    rng = np.random.default_rng(seed)
    rows, u, labels = [], [], []
    for f in range(N_FRAMES):
        theta = 2 * np.pi * f / N_FRAMES
        wall = WALL if f >= 20 else np.setdiff1d(WALL, HIDDEN)
        v_wall = 200.0 + 0.3 * wall + rng.uniform(-0.2, 0.2, wall.size)      # two frames: within 0.4 px
        v_part = 100.0 + 30.0 * np.sin(theta + PART / 20.0) + rng.normal(0, 0.2, PART.size)
        v_table = 8.0 + table_wobble_px * np.sin(theta) + rng.normal(0, 0.2, TABLE.size)
        rows.append(np.concatenate([wall, PART, TABLE]))
        u.append(np.concatenate([v_wall, v_part, v_table]))
        labels.append(np.array(["w"] * wall.size + ["p"] * PART.size + ["t"] * TABLE.size))
    ones = [np.ones(len(r)) for r in rows]
    return FolderStripes(rows, u, ones, ones, ones, {}, "rows", [np.zeros(len(r), bool) for r in rows], ones), labels


class _Cal:
    """Pixel (u, v) → camera (u/2, v/2, 100) mm; the turntable's axis along y through (100, 0, 100), r = 70 mm."""

    axis = {"direction": [0.0, 1.0, 0.0], "point_mm": [100.0, 0.0, 100.0]}
    tilt = {"turntable": {"radius": 70}}

    def sheet_frame(self):
        return np.zeros(3), np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])

    def camera_from_pixel(self, u, v):
        u, v = np.asarray(u, np.float64), np.asarray(v, np.float64)
        return np.stack([0.5 * u, 0.5 * v, np.full(u.shape, 100.0)], axis=-1)


def _flat(st):
    line = np.concatenate(st.rows)
    frame = np.concatenate([np.full(len(r), i) for i, r in enumerate(st.rows)])
    return line.astype(np.float64), np.concatenate(st.u), frame


def test_still_mask_is_the_wall_exactly():
    # a table wobbling by ±4 px: a point within 1 px of another frame's in at most a third of the turn
    # (4·sin θ within 2 px of its peak: θ within ±30° of it), not "most frames"
    st, labels = _scan(table_wobble_px=4.0)
    u, v, frame = _flat(st)                       # stripe along the rows: u the column (the line)
    got = still_mask(u, v, frame)
    truth = np.concatenate(labels) == "w"         # the wall, even where the part hid it half the time
    assert np.array_equal(got, truth)           # exact: integers (boolean masks)
    assert np.array_equal(still_mask(u, v, frame, along="rows"), got)   # exact: integers (masks); along told


def test_still_mask_bounds():
    st, labels = _scan(table_wobble_px=4.0)
    u, v, frame = _flat(st)
    wall = np.concatenate(labels) == "w"
    # every wall point has every frame that shows its line within 1 px (0.4 px at most): 40, or 20 on the hidden lines
    hidden = wall & np.isin(u, HIDDEN)
    assert still_mask(u, v, frame, min_frames=20)[hidden].all()
    assert not still_mask(u, v, frame, min_frames=21)[hidden].any()
    assert still_mask(u, v, frame, min_frames=40)[wall & ~hidden].all()
    # a tolerance below the noise (0.2 px): few points find the others
    assert still_mask(u, v, frame, tol_px=0.01)[wall].mean() < 0.2
    # a stripe along the columns: the same with u and v swapped
    assert np.array_equal(still_mask(v, u, frame, along="columns"), still_mask(u, v, frame))  # exact: integers


def test_still_mask_refuses():
    with pytest.raises(ValueError, match="tol_px"):
        still_mask([1.0], [2.0], [0], tol_px=0.0)
    with pytest.raises(ValueError, match="along-stripe coordinate"):
        still_mask([1.0, 2.0], [3.0, 4.0], [0, 1])           # both whole pixels: say which
    with pytest.raises(ValueError, match="frame has 1 entries for 2 points"):
        still_mask([1.0, 2.0], [3.5, 4.5], [0])
    assert still_mask([], [], []).shape == (0,)


def test_still_regions_without_and_with_a_calibration():
    st, _ = _scan()
    assert still_regions(st) == {"wall_left": (0.0, 99.0), "wall_right": (260.0, 319.0), "part": (100.0, 259.0)}
    # with the calibration: lines 260–319 map 30–50 mm from the axis (≤ 70) at 3–5 mm height: the table;
    # the wall's lines 0–99 are 50–100 mm away at 50–65 mm height: a wall
    assert still_regions(st, _Cal()) == {"wall_left": (0.0, 99.0), "table": (260.0, 319.0), "part": (100.0, 259.0)}
    # a wobble beyond the regions' tolerance: ±12 px is within 6 px of its median a third of the turn
    wobbly, _ = _scan(table_wobble_px=12.0)
    assert still_regions(wobbly) == {"wall_left": (0.0, 99.0), "part": (100.0, 319.0)}


def test_fabscan_rule_and_radius():
    cal = _Cal()
    assert turntable_radius_mm(cal) == 70.0
    u = np.array([0.0, 59.0, 60.0, 200.0, 340.0, 341.0])
    # distance |u/2 − 100|: beyond 70 mm for u < 60 and u > 340
    assert beyond_turntable(cal, u, np.zeros(6)).tolist() == [True, True, False, False, False, True]

    class NoRadius(_Cal):
        tilt = {"turntable": {"radius": None}}

    assert turntable_radius_mm(NoRadius()) is None and beyond_turntable(NoRadius(), u, u) is None


def test_separate_housing_drops_the_wall_keeps_part_and_table():
    st, labels = _scan()
    lab = np.concatenate(labels)
    split = separate_housing(st, _Cal())
    keep = np.concatenate(split.keep)
    # still wall points dropped (all of them: the whole wall is still); lines < 60 are beyond 70 mm
    # too, counted once, as still
    assert np.array_equal(keep, lab != "w")       # exact: integers (boolean masks)
    assert split.still == int((lab == "w").sum()) and split.beyond_turntable == 0
    assert split.to_json_dict()["dropped"] == split.still
    kept = st.select(split.keep)
    assert sum(len(r) for r in kept.rows) == int((lab != "w").sum())
    assert np.array_equal(np.concatenate(kept.u), np.concatenate(st.u)[lab != "w"])   # exact: copy


def test_separate_housing_when_nothing_moves():
    """A part of revolution on the axis stands still everywhere: nothing is dropped as still, and it says so."""
    st, _ = _scan()
    still_only = st.select([np.isin(r, np.concatenate([WALL, TABLE])) for r in st.rows])
    split = separate_housing(still_only)
    assert split.still == 0 and "moves on no line" in split.note
    assert all(k.all() for k in split.keep)


def test_select_refuses_a_wrong_mask():
    st, _ = _scan()
    with pytest.raises(ValueError, match="one boolean mask per frame"):
        st.select([np.ones(3, bool)])


# ------------------------------------------------------------------ the real frames

REAL = Path(__file__).resolve().parents[2] / "shared" / "realdata"
CONFIG = REAL / "fabscan" / "dummy.config.json"
SCAN = REAL / "fabscan" / "scan-2_1"
#: scan-2_1's columns (tests/test_real_frames.py, tests/test_fabscan_twin.py): the left back wall, the
#: turntable's top (a still line with a once-per-turn wobble)
LEFT_WALL, TABLE_TOP = (0, 190), (1310, 1460)


@pytest.mark.slow
@pytest.mark.skipif(not SCAN.is_dir() or not CONFIG.is_file(), reason=f"real frames absent ({SCAN}): see its README")
def test_fabscan_scan_regions_and_reconstruct_default(fabscan_scan, tmp_path, capsys):
    """scan-2_1, every 10th of its 200 frames (conftest's ``fabscan_scan``): the regions where a person
    put them, and ``reconstruct`` dropping the wall's points by default (the housing block of its JSON),
    keeping them on request."""
    from scheimpflug.app.cli import main

    scan = fabscan_scan
    capsys.readouterr()
    got = {}
    for keep in (False, True):
        assert main(["reconstruct", str(scan), "--calibration", str(CONFIG), "--out", str(tmp_path / f"{keep}.ply"),
                     "--json", "--quiet", *(["--keep-housing"] if keep else [])]) == 0
        got[keep] = json.loads(capsys.readouterr().out)
    h = got[False]["housing"]
    assert h["applied"] is True and h["reason"] == "a real scan (written by 'import')"
    regions = h["regions"]
    assert regions["wall_left"][0] <= LEFT_WALL[0] and regions["wall_left"][1] >= LEFT_WALL[1]
    assert regions["table"][0] <= TABLE_TOP[0] and regions["table"][1] >= TABLE_TOP[1]
    assert LEFT_WALL[1] < regions["part"][0] and regions["part"][1] < TABLE_TOP[0]
    assert h["turntable_radius_mm"] == 70.0
    # the left wall's columns hold 0–190 × 20 frames = 3 820 stripe points: most of them dropped
    assert 0.9 * 191 * 20 < h["still"] <= h["dropped"]
    assert got[True]["housing"] == {"applied": False, "reason": "--keep-housing"}
    assert got[True]["quality_filter"]["n_points"] - got[False]["quality_filter"]["n_points"] == h["dropped"]
