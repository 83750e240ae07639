"""Real frames from real scanners through the pipeline, against their makers' results (issue 24 item 4).

The frames are in ``../shared/realdata/`` (not in the project: licences in its
README).  Every test here skips, saying so, when that folder is absent.  The
full figures (all frames, both FabScan scans) come from
``benchmarks/bench_real_frames.py`` and are in benchmarks/RESULTS.md.
"""

import glob
import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from fabscan_formulae import fabscan_points, rigid_rms

from scheimpflug.app.cli import main
from scheimpflug.calibration.fabscan import read_fabscan
from scheimpflug.fixed_lines import fixed_line, line_inliers
from scheimpflug.io.frames import open_frame_folder
from scheimpflug.reconstruct import extract_folder_stripes, reconstruct_profiles
from scheimpflug.stripe import image_pixels

REAL = Path(__file__).resolve().parents[2] / "shared" / "realdata"
needs_real = pytest.mark.skipif(not REAL.is_dir(), reason=f"real frames absent ({REAL}): see its README")


@needs_real
def test_fabscan_frames_reconstruct_to_fabscans_own_points(fabscan_scan, tmp_path, capsys):
    config = REAL / "fabscan" / "dummy.config.json"
    capsys.readouterr()
    assert main(["reconstruct", str(fabscan_scan), "--calibration", str(config), "--out", str(tmp_path / "c.ply"),
                 "--keep-saturated", "--no-quality-filter", "--keep-housing", "--json", "--quiet"]) == 0
    summary = json.loads(capsys.readouterr().out)      # every stripe point, the walls' too (--keep-housing)
    assert summary["n_points"] > 20 * 1000 and "measured in 3-D" in summary["axis_source"]
    ff = open_frame_folder(fabscan_scan)
    st = extract_folder_stripes(ff, "cog", keep_saturated=True)
    angles = [r.angle_deg for r in ff.frames]
    ours = reconstruct_profiles(st.rows, st.u, angles, read_fabscan(config), None, along=st.along).xyz_mm
    theirs = fabscan_points(st.rows, st.u, angles, json.loads(config.read_text()))
    assert len(ours) == summary["n_points"] == len(theirs)
    assert rigid_rms(ours, theirs) < 1e-6                    # FabScan's points, in our part frame
    assert rigid_rms(ours, theirs, mirror=True) > 10.0       # not mirrored (a bust: 48 mm)


@needs_real
def test_fabscans_back_walls_stand_still_and_straight(fabscan_scan):
    config = REAL / "fabscan" / "dummy.config.json"
    ff = open_frame_folder(fabscan_scan)
    st = extract_folder_stripes(ff, "cog", keep_saturated=True)
    u, v = image_pixels(np.concatenate(st.rows), np.concatenate(st.u), st.along)
    frame = np.concatenate([np.full(len(r), i) for i, r in enumerate(st.rows)])
    figures = {}
    for wall, (c0, c1) in {"left": (0, 190), "right": (1310, 1460)}.items():
        sel = (u >= c0) & (u <= c1)
        keep = line_inliers(u[sel], v[sel])
        assert keep.sum() > 0.7 * sel.sum()                  # most of the range is the wall
        for use in ("as-fabscan", "apply"):
            s, h = read_fabscan(config, distortion=use).stage_from_pixel(u[sel][keep], v[sel][keep])
            figures[wall, use] = fixed_line(s, h, frame[sel][keep])
    for wall in ("left", "right"):
        f = figures[wall, "as-fabscan"]
        assert f.n_frames == 20 and f.length_mm > 30
        # all 200 frames (benchmarks/RESULTS.md): 0.095 mm; a laser stripe of ~0.6 px on 0.17 mm pixels
        assert f.rms_mm < 0.15
        # FabScan's distortion bends both straight walls (their bow grows): its k3 = −1.15 over-corrects
        assert abs(figures[wall, "apply"].bow_mm) > 3 * abs(f.bow_mm)
    assert figures["left", "as-fabscan"].stillness_mm < 0.03


@needs_real
def test_3dscanscience_intrinsics_against_the_notebooks(tmp_path, capsys):
    # The notebook (4.2. Camera calibration) printed, in frames it turned (transpose, flip): fx 1430.39,
    # fy 1429.66, cx 636.40, cy 478.03.  The frames are stored unturned: our fx, fy, cx, cy are its
    # fy, fx, cy and 1279 − cx.
    expect = {"fx": 1429.66307, "fy": 1430.39147, "cx": 478.032706, "cy": 1279 - 636.403930}
    files = sorted(glob.glob(str(REAL / "3dscanscience" / "camera-calibration" / "frame*.jpg")))
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.001)
    objp = np.zeros((66, 3), np.float32)
    objp[:, :2] = np.mgrid[0:11, 0:6].T.reshape(-1, 2)
    img = []
    for f in files:                                          # the notebook's own recipe, on the stored frames
        g = cv2.cvtColor(cv2.imread(f), cv2.COLOR_BGR2GRAY)
        ok, c = cv2.findChessboardCorners(g, (11, 6), None)
        assert ok
        img.append(cv2.cornerSubPix(g, c, (11, 11), (-1, -1), crit))
    _, k, _, _, _ = cv2.calibrateCamera([objp] * len(img), img, g.shape[::-1], None, None)
    np.testing.assert_allclose([k[0, 0], k[1, 1], k[0, 2], k[1, 2]], [expect[q] for q in ("fx", "fy", "cx", "cy")],
                               atol=0.01)                    # the frames and the relation are the notebook's
    folder = tmp_path / "dss"
    assert main(["import", str(REAL / "3dscanscience" / "camera-calibration"), "--scenario", "target",
                 "--channel", "gray", "--out", str(folder)]) == 0
    capsys.readouterr()
    assert main(["calibrate", str(folder), "--method", "target", "--pattern", "chessboard:11x6:10",
                 "--distortion", "opencv5", "--json", "--quiet"]) == 0
    d = json.loads(capsys.readouterr().out)
    km, se = d["camera_matrix"], d["stderr"]
    got = {"fx": km[0][0], "fy": km[1][1], "cx": km[0][2], "cy": km[1][2]}
    assert len(d["poses_used"]) == 16 and d["laser_plane"] is None      # a camera calibration only
    for q in got:   # this pipeline's corners (a blurred corner's model fitted) against cornerSubPix's: 2 σ
        assert abs(got[q] - expect[q]) < 2 * se[q], (q, got[q], expect[q], se[q])
        assert 0.2 < se[q] < 1.0
