"""The twin of FabScanPi from its own calibration (issue 35 items 1, 3, 5): turntable, orientation, housing.

References, each independent of the renderer: FabScan's ``config.json`` as
:func:`scheimpflug.calibration.fabscan.read_fabscan` reads it (its platform pose turned
into the stored frames' camera frame), ``cv2.projectPoints`` with its camera matrix and
distortion, the rendered image's own column centroids, and the real frames of
``../shared/realdata/fabscan/scan-2_1`` (skipped, saying so, where that folder is absent).
"""

from __future__ import annotations

import glob
import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from scheimpflug.app.cli import main
from scheimpflug.errors import RigError

REAL = Path(__file__).resolve().parents[2] / "shared" / "realdata"
CONFIG = REAL / "fabscan" / "dummy.config.json"
needs_config = pytest.mark.skipif(not CONFIG.is_file(), reason=f"FabScan's config absent ({CONFIG})")
needs_real = pytest.mark.skipif(not (REAL / "fabscan" / "scan-2_1").is_dir(),
                                reason=f"real frames absent ({REAL}/fabscan/scan-2_1): see its README")
WALLS = ((0, 190), (1310, 1460))      # the two still lines' columns in scan-2_1 (tests/test_real_frames.py)


def _rig_file(tmp_path, distortion: str = "apply", disc: bool = False) -> Path:
    """FabScan's rig file; without ``disc`` its table's disc (FabScan's radius, 70 mm) taken out."""
    out = tmp_path / f"fabscan-{distortion}{'-disc' if disc else ''}.toml"
    assert main(["rig", "from-calibration", str(CONFIG), "--preset", "rpi-v2-binned", "--out", str(out),
                 "--fabscan-distortion", distortion]) == 0
    text = out.read_text()
    assert "table_radius_mm = 70.0" in text                      # FabScan's config gives its table's radius
    if not disc:
        out.write_text(text.replace("table_radius_mm = 70.0", "table_radius_mm = 0.0"))
    return out


@needs_config
def test_fabscan_rig_holds_its_turntable(tmp_path):
    """The rig's rotary axis, in the camera frame, is FabScan's platform axis within 1e-9."""
    from scheimpflug.calibration.fabscan import read_fabscan
    from scheimpflug.calibration.instrument import instrument_from_calibration
    from scheimpflug.model.instrument import rig_frame
    from scheimpflug.model.rig import load_rig
    from sim.stages import rig_from_stage, stage_from_part

    rig = load_rig(_rig_file(tmp_path))
    assert rig.stage.axis_tilt_deg > 170.0                      # the table's up is the rig's −z
    cam_from_rig = np.linalg.inv(rig_frame(instrument_from_calibration(CONFIG, "rpi-v2-binned")).rig_from_camera)
    table = cam_from_rig @ rig_from_stage(rig) @ stage_from_part(rig, 0.0)
    # the reference: FabScan's platform (R, t) in the stored frames' camera frame, by hand
    d = json.loads(CONFIG.read_text())["calibration"]
    m = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])   # rotate, hflip: X = Y_fab, Y = −X_fab
    r, t = np.asarray(d["platform_rotation"]), np.asarray(d["platform_translation"])
    assert np.abs(table[:3, 3] - m @ t).max() < 1e-9
    assert np.abs(table[:3, 2] - m @ r[:, 2]).max() < 1e-9
    axis = read_fabscan(CONFIG).axis                           # and the reader agrees
    assert np.abs(table[:3, 2] - np.asarray(axis["direction"])).max() < 1e-9
    assert rig.stage.axis_offset_mm == pytest.approx(0.4917, abs=1e-3)    # FabScan's axis misses its plane


def test_stage_axis_upside_down_and_off_the_sheet(paper_rig):
    from sim.stages import stage_from_part

    rig = paper_rig.replace(stage={"axis_tilt_deg": 180.0, "axis_offset_mm": 2.5})
    m = stage_from_part(rig, 30.0)
    assert np.allclose(m[:3, 2], [0.0, 0.0, -1.0], rtol=0, atol=1e-15)     # the part's up is the stage's −z
    assert np.allclose(m[:3, 3], [0.0, 2.5, paper_rig.stage.rotary_table_z_mm], rtol=0, atol=1e-12)
    # exact: same run — an explicit offset 0 is the default's pose, bit for bit (the paper rig unchanged)
    assert np.array_equal(stage_from_part(paper_rig, 30.0), stage_from_part(paper_rig.replace(
        stage={"axis_offset_mm": 0.0}), 30.0))
    for bad in (10.0, 90.0, 170.0, 180.5):
        with pytest.raises(RigError, match="axis_tilt_deg"):
            paper_rig.replace(stage={"axis_tilt_deg": bad})


@needs_config
@pytest.mark.render
def test_render_rotary_of_the_fabscan_rig(tmp_path, variant):
    """``render rotary`` of the FabScan rig: the files' size and orientation, the stripe along the rows,
    the exact per-column truth where the image and OpenCV put it."""
    from scheimpflug.model.binning import binned_rig
    from scheimpflug.model.rig import load_rig
    from sim.stages import ref_from_stage, rig_from_stage
    from sim.truth import opencv_camera

    rig_path = _rig_file(tmp_path)
    out = tmp_path / "scan"
    assert main(["render", "rotary", "--rig", str(rig_path), "--part", "sphere", "--step-deg", "90",
                 "--binning", "4", "--out", str(out), "--quiet"]) == 0
    man = json.loads((out / "manifest.json").read_text())
    assert man["stripe_along"] == "rows" and len(man["frames"]) == 4
    assert [f["angle_deg"] for f in man["frames"]] == [0.0, 90.0, 180.0, 270.0]
    image = cv2.imread(str(out / "frames" / "00000.png"), cv2.IMREAD_UNCHANGED).astype(np.float64)
    assert image.shape == (308, 410)                           # FabScan's stored 1640 × 1232, binned by 4
    truth = np.load(out / "truth" / "00000.npz")
    v_true = truth["stripe_u"]
    assert v_true.shape == (410,)                              # one stripe point per column
    cols = np.flatnonzero(np.isfinite(v_true) & (truth["stripe_count"] == 1))
    assert len(cols) > 60
    # the image's own column centroids (above 10 % of the column's peak) find the stripe where the truth says
    w = np.clip(image[:, cols] - 0.1 * image[:, cols].max(axis=0), 0.0, None)
    centroid = (w * np.arange(308)[:, None]).sum(axis=0) / w.sum(axis=0)
    assert np.median(np.abs(centroid - v_true[cols])) < 0.1
    # OpenCV projects the truth points onto (column, stripe row): K binned by 4 from FabScan's own K
    rig = binned_rig(load_rig(rig_path), 4)
    from scheimpflug.calibration.fabscan import read_fabscan

    cal = read_fabscan(CONFIG, distortion="apply")
    k = cal.camera.camera_matrix.copy()
    k[:2] /= 4.0
    k[:2, 2] -= 1.5 / 4.0                                      # pixel centres of a 4 × 4 bin
    _, cam_from_rig = opencv_camera(rig)
    cam_from_ref = cam_from_rig @ rig_from_stage(rig) @ np.linalg.inv(ref_from_stage(rig))   # truth: the upright frame
    p = truth["stripe_point_mm"][cols] @ cam_from_ref[:3, :3].T + cam_from_ref[:3, 3]
    uv = cv2.projectPoints(p.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), k, cal.camera.dist_coeffs[:5])[0]
    uv = uv.reshape(-1, 2)
    assert np.abs(uv[:, 0] - cols).max() < 1e-6 and np.abs(uv[:, 1] - v_true[cols]).max() < 1e-6


@pytest.mark.render
def test_housing_boards_found_again_from_the_twins_frames(tmp_path, variant):
    """A housing file → render (its walls' lines in the frames) → ``rig housing`` finds the same 3-D lines."""
    from scheimpflug.calibration.camera import OpenCVCamera
    from scheimpflug.calibration.model import sheet_frame_from_plane
    from scheimpflug.calibration.target import TargetCalibration
    from scheimpflug.model.housing import Board, housing_to_toml, load_housing

    k = np.array([[330.0, 0.0, 204.2], [0.0, 330.0, 153.1], [0.0, 0.0, 1.0]])
    n_c = np.array([-0.026, 0.788, 0.615])
    n_c /= np.linalg.norm(n_c)
    plane = np.array([*n_c, -77.5])
    origin, e_s, e_h = sheet_frame_from_plane(plane)
    cal = TargetCalibration(camera=OpenCVCamera(k, np.zeros(5)), homography=np.column_stack([e_s, e_h, origin]),
                            columns=410, rows=308, n_frames=0, laser_plane=plane, pattern="chessboard:9x6:10")
    cal_path = tmp_path / "cal.json"
    cal.save(cal_path)
    rig_path = tmp_path / "rig.toml"
    assert main(["rig", "from-calibration", str(cal_path), "--out", str(rig_path)]) == 0
    # two boards across the sheet, crossing it in lines at X = ∓60 mm (the sheet's height ends)
    boards = []
    for name, x in (("low", -60.0), ("high", 60.0)):
        along = np.cross(n_c, [1.0, 0.0, 0.0])
        along *= np.sign(along[2]) / np.linalg.norm(along)        # in the sheet, away from the camera
        centre = np.array([x, 0.0, 0.0]) + (77.5 - n_c @ [x, 0.0, 0.0]) * n_c + 130.0 * along
        normal = np.cross(n_c, along)
        normal = normal if normal @ centre < 0 else -normal
        boards.append(Board(name, centre, normal, along, 60.0, 40.0))
    housing = tmp_path / "housing.toml"
    housing.write_text(housing_to_toml(boards, "two test boards"))
    assert [b.name for b in load_housing(housing)] == ["low", "high"]
    out = tmp_path / "scan"
    assert main(["render", "rotary", "--rig", str(rig_path), "--part", "sphere", "--step-deg", "180",
                 "--housing", str(housing), "--truth-pixels", "none", "--out", str(out), "--quiet"]) == 0
    man = json.loads((out / "manifest.json").read_text())
    assert man["stripe_along"] == "rows" and len(man["scenario_params"]["housing"]["boards"]) == 2
    ids = np.load(out / "truth" / "00000.npz")["stripe_object_id"]      # per column: what the sheet lights
    cols = []
    for board_id, board in zip((101, 102), boards):
        face_u, _ = cal.pixel_from_camera(board.centre_mm + np.outer([-30.0, 30.0], board.length_dir))
        c = np.flatnonzero(ids == board_id)                             # lit and seen …
        c = c[(c >= face_u.min()) & (c <= face_u.max())]                # … on the face, not its end
        assert len(c) > 8
        cols.append(f"{c.min() + 1}:{c.max() - 1}")
    found = tmp_path / "found.toml"
    assert main(["rig", "housing", str(out), "--calibration", str(cal_path), "--walls", ",".join(cols),
                 "--out", str(found)]) == 0
    for b, f in zip(boards, load_housing(found)):
        assert abs(abs(f.length_dir @ b.length_dir) - 1.0) < 1e-5          # the same line …
        off = f.centre_mm - b.centre_mm
        assert np.linalg.norm(off - (off @ b.length_dir) * b.length_dir) < 0.05     # … within 0.05 mm


# ---------------------------------------------------------------- the real frames


@pytest.fixture(scope="module")
def scan200(tmp_path_factory):
    """All 200 frames of one turn of ``scan-2_1``, imported as a user would."""
    if not (REAL / "fabscan" / "scan-2_1").is_dir():
        pytest.skip(f"real frames absent ({REAL})")
    from scheimpflug.calibration.fabscan import fabscan_angles_deg

    files = sorted(glob.glob(str(REAL / "fabscan" / "scan-2_1" / "*.jpg")))[:200]
    angles = fabscan_angles_deg(200, 6400, resolution=2)
    out = tmp_path_factory.mktemp("fabscan200") / "scan"
    assert main(["import", *files, "--channel", "r", "--stripe-along", "rows", "--quiet",
                 f"--angles-deg={','.join(f'{a:g}' for a in angles)}", "--out", str(out)]) == 0
    return out


def _wall_points(folder):
    from scheimpflug.fixed_lines import line_inliers
    from scheimpflug.io.frames import open_frame_folder
    from scheimpflug.reconstruct import extract_folder_stripes
    from scheimpflug.stripe import image_pixels

    st = extract_folder_stripes(open_frame_folder(folder), "cog", keep_saturated=True)
    u, v = image_pixels(np.concatenate(st.rows), np.concatenate(st.u), st.along)
    frame = np.concatenate([np.full(len(r), i) for i, r in enumerate(st.rows)])
    out = []
    for c0, c1 in WALLS:
        sel = np.flatnonzero((u >= c0) & (u <= c1))
        sel = sel[line_inliers(u[sel], v[sel])]
        out.append((u[sel], v[sel], frame[sel]))
    return out


def _per_column(real, twin) -> tuple[np.ndarray, np.ndarray]:
    """Per column seen in both: RMS over the real frames of (real − twin) [px], and its mean (the bias)."""
    (ru, rv, _), (tu, tv, _) = real, twin
    rc, tc = np.round(ru).astype(int), np.round(tu).astype(int)
    cols = np.intersect1d(rc, tc)
    rms, bias = [], []
    for c in cols:
        d = rv[rc == c] - tv[tc == c].mean()
        rms.append(math.sqrt(float(np.mean(d ** 2))))
        bias.append(float(d.mean()))
    return np.array(rms), np.array(bias)


@needs_real
@pytest.mark.slow
@pytest.mark.render
def test_twins_wall_lines_fall_on_the_real_ones(scan200, tmp_path, variant):
    """Issue 35's first acceptance test, on all 200 frames of scan-2_1 (module docstring; measured
    figures in the report of the session and below).

    The housing is found from the real frames (``rig housing``) with FabScan's own camera model
    (``--fabscan-distortion as-fabscan``: its calibrated k3 = −1.15 folds back inside the frame and
    bends the straight lines, tests/test_real_frames.py), the twin renders it (full frames, 2
    angles: the boards stand still), both folders go through the same detector.

    Measured (2026-12-07): line 1 (columns 0–190) 0.98 px RMS per column over all columns and
    frames, its per-column bias 0.79 px RMS; line 2 (1310–1460) 2.84 px RMS, bias 0.76 px RMS —
    line 2 is the turntable's top, not a still wall: it lies at the table's height within its
    radius and moves once per turn by 3.7 px (a tilted disc), which no fixed board can follow.
    With the calibrated distortion (``apply``): 1.36 and 3.35 px.

    With the twin's table disc where FabScan's calibration puts the platform (70 mm, still), line 2 was
    19.38 px RMS per column (RESULTS); the table's top found from the frames, a disc that wobbles:
    :func:`test_twins_table_line_falls_on_the_real_one`.
    """
    rig_path = _rig_file(tmp_path, "as-fabscan")
    housing = tmp_path / "housing.toml"
    assert main(["rig", "housing", str(scan200), "--calibration", str(CONFIG), "--walls",
                 ",".join(f"{a}:{b}" for a, b in WALLS), "--fabscan-distortion", "as-fabscan",
                 "--out", str(housing)]) == 0
    out = tmp_path / "twin"
    assert main(["render", "rotary", "--rig", str(rig_path), "--part", "sphere", "--step-deg", "90",
                 "--frames", "2", "--housing", str(housing), "--truth-pixels", "none", "--out", str(out),
                 "--quiet"]) == 0
    real, twin = _wall_points(scan200), _wall_points(out)
    rms1, bias1 = _per_column(real[0], twin[0])
    rms2, bias2 = _per_column(real[1], twin[1])
    assert len(rms1) > 150 and len(rms2) > 120
    assert math.sqrt(np.mean(rms1 ** 2)) < 1.0                 # the still wall: within 1 px RMS per column
    assert math.sqrt(np.mean(bias1 ** 2)) < 1.0 and math.sqrt(np.mean(bias2 ** 2)) < 1.0
    assert 2.0 < math.sqrt(np.mean(rms2 ** 2)) < 4.0           # the turning disc: its wobble, not the twin
    print(f"line 1 {math.sqrt(np.mean(rms1 ** 2)):.3f} px RMS (bias {math.sqrt(np.mean(bias1 ** 2)):.3f}) over "
          f"{len(rms1)} columns; line 2 without the disc {math.sqrt(np.mean(rms2 ** 2)):.3f} px RMS (bias "
          f"{math.sqrt(np.mean(bias2 ** 2)):.3f}) over {len(rms2)} columns")


@needs_real
@pytest.mark.slow
@pytest.mark.render
def test_twins_table_line_falls_on_the_real_one(scan200, tmp_path, variant):
    """Issue 35's acceptance on the table: the top found from the real frames (h, its lean, the tilt that
    makes it wobble: :mod:`scheimpflug.turntable_top`, fitted, not tuned), the twin's turning disc rendered
    at 8 of the real frames' angles, each compared per column with the real frame AT THE SAME ANGLE.

    The fit uses every 4th frame of the turn (50 frames, to keep the test short); both lines by the same
    detector, per frame the inliers of a RANSAC line over columns 1310–1460
    (:func:`scheimpflug.turntable_top.table_line_points`); the columns seen at 6 of the 8 angles at least.
    FabScan's own camera model (``as-fabscan``), as for the walls.

    Measured (2026-12-07): h +0.129 mm, lean 0.723° toward 160.5°, tilt 0.213° toward 169.6° (fit
    residual 1.515 px RMS); the table line 1.619 px RMS per column (RMS over the 8 angles, then over 142
    columns), its per-column bias 0.869 px RMS; per angle the mean −1.40 px at 0°, within ±0.6 px at the
    others.  The fit from all 200 frames: 1.609 px.  For comparison (the same pairing, a hidden part,
    every column seen at any angle): the still disc at the calibrated table plane 20.2 px, the fitted h
    and lean without the wobble 4.24 px, with it 1.754 px.  The target, 1 px, is not met: the real
    line is bent by ±1 px along its length where FabScan's camera model (K alone) makes every line of
    the sheet straight (the per-column bias), the real top's line departs from a tilted plane's
    once-per-turn wobble by 0.62 px RMS per frame (−1.4 px at 0°, the scan's first frame), and each
    single frame's line has its stripe noise (the twin's cardboard: 0.75–0.9 px per column against its
    exact line at full resolution).
    """
    import dataclasses

    from scheimpflug.calibration.instrument import calibration_sheet_model
    from scheimpflug.io.frames import open_frame_folder
    from scheimpflug.model.rig import load_rig
    from scheimpflug.model.rigfile import with_stage_keys
    from scheimpflug.turntable_top import table_line_points, table_top_of_folder
    from sim.backgrounds import camera_from_table

    columns = WALLS[1]
    real = open_frame_folder(scan200)
    rig_path = _rig_file(tmp_path, "as-fabscan", disc=True)
    cal = calibration_sheet_model(CONFIG, "as-fabscan")
    top = table_top_of_folder(dataclasses.replace(real, frames=real.frames[::4]), cal, columns,
                              camera_from_table(load_rig(rig_path)))
    assert top.n_frames == 50 and top.n_points > 5000
    rig_path.write_text(with_stage_keys(rig_path.read_text(), top.rig_keys(), "fitted from scan-2_1"))
    out = tmp_path / "twin-table"
    assert main(["render", "rotary", "--rig", str(rig_path), "--part", "sphere", "--step-deg", "45", "--frames", "8",
                 "--truth-pixels", "none", "--out", str(out), "--quiet"]) == 0
    twin = open_frame_folder(out)
    pick = [next(i for i, r in enumerate(real.frames) if abs((r.angle_deg - t.angle_deg + 180.0) % 360.0 - 180.0)
                 < 1e-6) for t in twin.frames]                   # the real frame at each twin angle
    ru, rv, rf = table_line_points(dataclasses.replace(real, frames=tuple(real.frames[i] for i in pick)), columns)
    tu, tv, tf = table_line_points(twin, columns)
    rc, tc = np.round(ru).astype(int), np.round(tu).astype(int)
    d = np.full((len(pick), columns[1] - columns[0] + 1), np.nan)
    for k in range(len(pick)):
        for c in np.intersect1d(rc[rf == k], tc[tf == k]):
            d[k, c - columns[0]] = rv[(rf == k) & (rc == c)].mean() - tv[(tf == k) & (tc == c)].mean()
    seen = np.isfinite(d).sum(axis=0) >= 6                       # columns seen at 6 of the 8 angles at least
    per_column = np.sqrt(np.nanmean(d[:, seen] ** 2, axis=0))
    bias = np.nanmean(d[:, seen], axis=0)
    rms = math.sqrt(float(np.mean(per_column ** 2)))
    print(f"table top: h {top.offset_mm:+.4f} ± {top.offset_se_mm:.4f} mm, lean {top.lean_deg:.4f}° toward "
          f"{top.lean_azimuth_deg:.2f}°, tilt {top.tilt_deg:.4f} ± {top.tilt_se_deg:.4f}° toward "
          f"{top.azimuth_deg:.2f} ± {top.azimuth_se_deg:.2f}°, fit residual {top.rms_px:.3f} px; table line "
          f"{rms:.3f} px RMS per column over {seen.sum()} columns and 8 angles (bias "
          f"{math.sqrt(float(np.mean(bias ** 2))):.3f} px RMS); per angle "
          + ", ".join(f"{t.angle_deg:g}°: {np.nanmean(r):+.2f}" for t, r in zip(twin.frames, d)))
    assert seen.sum() > 120
    assert rms < 2.0                # measured 1.619 px (docstring): the target, 1 px, is not met


@pytest.mark.parametrize("change, words", [
    ({"normal": [0.0, 0.0, 2.0]}, "not 1"),
    ({"length_dir": [0.0, 0.6, 0.8]}, "not perpendicular"),
    ({"width_mm": 0.0}, "width_mm"),
    ({"centre_mm": [0.0, float("nan"), 1.0]}, "finite"),
    ({"colour": "red"}, "unknown key"),
])
def test_bad_housing_boards_are_refused_with_the_reason(tmp_path, change, words):
    from scheimpflug.model.housing import housing_from_dict, load_housing

    good = {"name": "w", "centre_mm": [0.0, 0.0, 100.0], "normal": [0.0, 0.0, -1.0], "length_dir": [1.0, 0.0, 0.0],
            "length_mm": 50.0, "width_mm": 20.0}
    assert len(housing_from_dict({"board": [good]})) == 1
    with pytest.raises(RigError, match=words):
        housing_from_dict({"board": [{**good, **change}]})
    with pytest.raises(RigError, match="at least one"):
        housing_from_dict({})
    (tmp_path / "h.toml").write_text("[[board]]\nname = 1\n")
    with pytest.raises(RigError, match="h.toml"):
        load_housing(tmp_path / "h.toml")


def test_wall_board_is_the_line_of_its_points(rng):
    """Points of a known 3-D line in a sheet, seen by a pinhole camera → the board holds that line."""
    from scheimpflug.calibration.camera import OpenCVCamera
    from scheimpflug.calibration.model import sheet_frame_from_plane
    from scheimpflug.calibration.target import TargetCalibration
    from scheimpflug.fixed_lines import wall_board

    k = np.array([[800.0, 0.0, 320.0], [0.0, 800.0, 240.0], [0.0, 0.0, 1.0]])
    n = np.array([0.7, 0.1, 0.5])
    n /= np.linalg.norm(n)
    plane = np.array([*n, -120.0])
    origin, e_s, e_h = sheet_frame_from_plane(plane)
    cal = TargetCalibration(camera=OpenCVCamera(k, np.zeros(5)), homography=np.column_stack([e_s, e_h, origin]),
                            columns=640, rows=480, n_frames=0, laser_plane=plane, pattern="chessboard:9x6:10")
    d = np.cross(n, [0.0, 1.0, 0.0])
    d /= np.linalg.norm(d)
    p0 = origin + 15.0 * np.cross(n, d)
    pts = p0 + np.outer(rng.uniform(-20.0, 20.0, 300), d)
    u, v = cal.pixel_from_camera(pts)
    b = wall_board(cal, u, v, "w", margin_mm=5.0)
    assert abs(abs(b.length_dir @ d) - 1.0) < 1e-12
    off = b.centre_mm - p0
    assert np.linalg.norm(off - (off @ d) * d) < 1e-9                       # the face holds the line
    assert abs(b.normal @ n) < 1e-12 and b.normal @ b.centre_mm < 0         # ⟂ the sheet, facing the camera
    t = (pts - p0) @ d
    assert b.length_mm == pytest.approx(np.ptp(t) + 10.0, abs=1e-9)


@needs_config
def test_background_walls_stand_on_an_upside_down_table(tmp_path):
    """``--background walls`` of a rig whose table is up its −z: the walls rise from the table toward −z."""
    from scheimpflug.model.rig import load_rig
    from sim.backgrounds import scan_background

    rig = load_rig(_rig_file(tmp_path, "as-fabscan"))
    z_table = rig.stage.rotary_table_z_mm
    for part in scan_background(rig, "walls", height_mm=120.0):
        z = np.asarray(part.mesh.vertices)[:, 2]
        assert z.max() == pytest.approx(z_table, abs=1e-9) and z.min() == pytest.approx(z_table - 120.0, abs=1e-9)


@needs_config
@pytest.mark.slow
@pytest.mark.render
def test_twin_scan_reconstructs_with_fabscans_own_calibration(tmp_path, capsys, variant):
    """``rig from-calibration`` → ``render rotary`` (the stored frames' size and orientation, the stripe along
    the rows, FabScan's angle rule) → ``reconstruct --calibration config.json`` → ``evaluate`` against the
    twin's truth mesh (the turntable's frame, :func:`sim.stages.ref_from_stage`).

    The twin's lens is FabScan's own model (``as-fabscan``: K alone), as its reconstruction assumes; 16-bit
    frames with the rig's default noise.  Measured (2026-12-07): 0.0517 mm RMS, mean signed −0.0001 mm over
    42 275 points — the pipeline holds the axis in the sheet, FabScan's misses it by 0.49 mm at 0.35°.
    """
    rig_path = _rig_file(tmp_path, "as-fabscan")
    out = tmp_path / "scan"
    assert main(["render", "rotary", "--rig", str(rig_path), "--part", "cylinder", "--step-deg", "12",
                 "--truth-pixels", "none", "--out", str(out), "--quiet"]) == 0
    cloud = tmp_path / "cloud.ply"
    assert main(["reconstruct", str(out), "--calibration", str(CONFIG), "--out", str(cloud), "--quiet"]) == 0
    capsys.readouterr()
    assert main(["evaluate", str(cloud), "--mesh", str(out / "truth" / "mesh.ply"), "--json"]) == 0
    got = json.loads(capsys.readouterr().out)
    assert got["n_points"] > 30_000
    assert got["rms_mm"] < 0.06 and abs(got["mean_signed_mm"]) < 0.01
