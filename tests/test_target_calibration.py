"""Calibration without a stage (issue 24 item 2): ``calibrate --method target`` against the twin's truth.

References, none from the calibration's own code: the twin's exact camera (``truth/rig_truth.json``,
OpenCV's tilted model of the rig: ``cv2.projectPoints`` reproduces its corners to 1e-13 px), the
rig's sheet plane and rotary axis (``scheimpflug.model.hinge``, ``sim.stages``), the exact stripe
points of the laser frames (``truth/*.npz``: ``stripe_point_mm``), closed forms (the lens equation,
a plane turned about a line) and a midpoint-rule integral of the light cone for the blur centroid.
Binned (2 × 2) frames keep it fast; the full-resolution figures are benchmarks/RESULTS.md's.
"""

from __future__ import annotations

import json
import math
import shutil

import cv2
import numpy as np
import pytest

from scheimpflug.app.cli import main
from scheimpflug.calibration import TargetCalibration, load_sheet_model
from scheimpflug.calibration.camera import OpenCVCamera
from scheimpflug.calibration.target import (
    _centred,
    _rot_tilt,
    blur_centroid_offsets,
    fit_laser_plane,
    focus_axis,
    rotary_axis_from_planes,
)
from scheimpflug.errors import CalibrationError

PATTERN = "charuco:9x6:15:11"
BIN = ["--binning", "2", "--quiet"]


def _render(out, *args):
    assert main(["render", "target", "--preset", "paper", "--pattern", PATTERN, *BIN, "--out", str(out), *args]) == 0
    return out


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    root = tmp_path_factory.mktemp("target")
    hand = _render(root / "hand", "--poses", "8", "--depth-range-mm", "520:650", "--height-range-mm=-15:15")
    table = _render(root / "table", "--on-table", "--step-deg", "30", "--lights", "flood")
    return root, hand, table


@pytest.fixture(scope="module")
def calibrated(frames):
    root, hand, table = frames
    out = root / "cal.json"
    assert main(["calibrate", str(hand), "--method", "target", "--pattern", PATTERN, "--distortion", "none",
                 "--on-table", str(table), "--out", str(out), "--quiet"]) == 0
    return out, json.loads(out.read_text())


def _truth(folder):
    from scheimpflug.model.hinge import hinge_geometry
    from scheimpflug.model.rig import rig_from_dict
    from sim.stages import rig_from_stage

    m = json.loads((folder / "manifest.json").read_text())
    cam = json.loads((folder / "truth" / "rig_truth.json").read_text())["opencv"]
    rig = rig_from_dict(m["rig"])
    c = np.array(cam["camera_from_rig"])
    g = hinge_geometry(rig)
    n = c[:3, :3] @ g.sheet_normal
    p = c[:3, :3] @ g.rig_from_sheet(600.0, 0.0) + c[:3, 3]
    plane = np.array([*n, -n @ p]) if n @ p > 0 else -np.array([*n, -n @ p])
    rs = rig_from_stage(rig)
    return cam, plane, c[:3, :3] @ rs[:3, 3] + c[:3, 3], c[:3, :3] @ rs[:3, 2], c


@pytest.mark.render
def test_target_calibration_finds_the_twins_camera_and_laser_plane(frames, calibrated, variant):
    _, d = calibrated
    cam, plane, _, _, _ = _truth(frames[1])
    for key in ("camera_matrix", "dist_coeffs", "reprojection_rms_px", "poses_used", "poses_skipped",
                "laser_plane", "laser_plane_rms_mm", "axis"):                     # docs/reference/interface.md
        assert key in d, key
    k, k0 = np.array(d["camera_matrix"]), np.array(cam["camera_matrix"])
    dist, dist0 = np.array(d["dist_coeffs"]), np.array(cam["dist_coeffs"])
    se = d["stderr"]
    assert len(dist) == 14 and d["tilt"]["mode"] == "focus" and len(d["poses_used"]) >= 5
    assert abs(k[0, 0] / k0[0, 0] - 1) < 3e-3                                  # binned: 0.3 %
    assert abs(math.degrees(dist[13] - dist0[13])) < max(0.15, 3 * se["tau_y_deg"])
    assert abs(math.degrees(dist[12] - dist0[12])) < max(0.15, 3 * se["tau_x_deg"])
    assert d["tilt"]["lens_focal_length_mm"] == pytest.approx(55.0, rel=5e-3)  # the rig's lens
    pl = np.array(d["laser_plane"])
    normal_deg = math.degrees(math.acos(min(1.0, pl[:3] @ plane[:3])))
    assert normal_deg < 3 * se["laser_plane_normal_deg"] + 0.02                 # the stated σ covers it
    assert abs(pl[3] - plane[3]) < 3 * se["laser_plane_distance_mm"] + 0.02
    assert d["reprojection_rms_px"] < 0.15 and d["laser_plane_rms_mm"] < 0.1


def _stripe_alignment(hand, model):
    """Our and the true camera-frame points of the laser frames' exact stripe, and the rigid motion between."""
    from scheimpflug.model.rig import rig_from_dict
    from sim.stages import rig_from_stage

    *_, camera_from_rig = _truth(hand)
    rig = rig_from_dict(json.loads((hand / "manifest.json").read_text())["rig"])
    camera_from_stage = camera_from_rig @ rig_from_stage(rig)                  # truth points: the stage frame
    ours, true = [], []
    for f in json.loads((hand / "manifest.json").read_text())["frames"]:
        if f["light"] != "laser":
            continue
        z = np.load(hand / f["truth"])
        rows = np.flatnonzero(np.isfinite(z["stripe_u"]))[::4]
        if rows.size:
            ours.append(model.camera_from_pixel(z["stripe_u"][rows], rows.astype(float)))
            true.append(z["stripe_point_mm"][rows] @ camera_from_stage[:3, :3].T + camera_from_stage[:3, 3])
    a, b = np.concatenate(ours), np.concatenate(true)
    u, _, vt = np.linalg.svd((a - a.mean(0)).T @ (b - b.mean(0)))             # Kabsch: b ≈ R a + t
    r = vt.T @ np.diag([1, 1, np.linalg.det(vt.T @ u.T)]) @ u.T
    return a, b, r, b.mean(0) - a.mean(0) @ r.T


@pytest.mark.render
def test_the_target_sheet_model_puts_the_stripe_where_it_is(frames, calibrated, variant):
    """The exact stripe points of the laser frames, mapped through the calibration, are the true ones
    up to a rigid motion (the camera frame's own estimate): the metric mapping is what reconstructs."""
    path, _ = calibrated
    model = load_sheet_model(path)
    assert isinstance(model, TargetCalibration)
    a, b, r, t = _stripe_alignment(frames[1], model)
    resid = np.linalg.norm(b - (a @ r.T + t), axis=1)
    assert len(a) > 200 and np.sqrt(np.mean(resid ** 2)) < 0.1                 # [mm], binned twin
    assert np.degrees(np.arccos(min(1.0, (np.trace(r) - 1) / 2))) < 0.5         # the frame itself within 0.5°


@pytest.mark.render
def test_table_poses_give_the_rotary_axis(frames, calibrated, variant):
    path, d = calibrated
    _, _, q_true, w_true, _ = _truth(frames[1])
    axis = d["axis"]
    assert axis["poses"] >= 4
    # our camera frame is an estimate (turned by ≈ δc/f about the lens: 690 mm away, millimetres): the
    # stripe's points align it with the true frame, and there the axis is the rig's
    _, _, r, t = _stripe_alignment(frames[1], load_sheet_model(path))
    q, w = r @ np.array(axis["point_mm"]) + t, r @ np.array(axis["direction"])
    assert math.degrees(math.acos(min(1.0, abs(w @ w_true)))) < 0.3
    assert np.linalg.norm(np.cross(q - q_true, w_true)) < 0.5                  # [mm]
    assert abs(axis["distance_to_sheet_mm"]) < 0.5 and axis["angle_to_sheet_deg"] < 0.3


@pytest.mark.render
def test_pattern_frames_without_laser_frames_calibrate_the_camera_alone(frames, tmp_path, capsys, variant):
    root, hand, _ = frames
    only = tmp_path / "flood"
    shutil.copytree(hand, only)
    m = json.loads((only / "manifest.json").read_text())
    m["frames"] = [f for f in m["frames"] if f["light"] == "flood"]
    (only / "manifest.json").write_text(json.dumps(m))
    capsys.readouterr()
    assert main(["calibrate", str(only), "--method", "target", "--pattern", PATTERN, "--json", "--quiet",
                 "--out", str(tmp_path / "cam.json")]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["laser_plane"] is None and d["reprojection_rms_px"] < 0.15 and "sheet_frame" not in d
    scan = tmp_path / "scan"
    shutil.copytree(hand, scan)
    m = json.loads((scan / "manifest.json").read_text())
    m["frames"] = [dict(f, angle_deg=float(i)) for i, f in enumerate(m["frames"]) if f["light"] == "laser"]
    m["scenario"] = "rotary"
    (scan / "manifest.json").write_text(json.dumps(m))
    assert main(["reconstruct", str(scan), "--calibration", str(tmp_path / "cam.json"), "--axis-mm", "0",
                 "--out", str(tmp_path / "c.ply"), "--quiet"]) != 0
    err = capsys.readouterr().err.strip()
    assert "no laser plane" in err and "\n" not in err and not (tmp_path / "c.ply").exists()


def _subset(src, dst, keep):
    shutil.copytree(src, dst)
    m = json.loads((dst / "manifest.json").read_text())
    m["frames"] = [f for f in m["frames"] if keep(f)]
    (dst / "manifest.json").write_text(json.dumps(m))
    return dst


@pytest.mark.render
@pytest.mark.parametrize("case, words", [
    ("spec", "found in 0 of 8 flood-lit frames; 15 DICT_4X4_50 markers seen with ids up to 24, a 8 × 5 board holds 20"),
    ("two", "only 2 usable pose(s)"),
    ("laser-only", "without their flood-lit pose frame"),
])
def test_bad_target_input_is_one_line_and_writes_nothing(frames, tmp_path, capsys, case, words, variant):
    _, hand, _ = frames
    pattern = PATTERN
    folder = hand
    if case == "spec":
        pattern = "charuco:8x5:15:11"
    elif case == "two":
        folder = _subset(hand, tmp_path / "two", lambda f: f["pose"] in (1, 2))
    else:
        folder = _subset(hand, tmp_path / "laser", lambda f: f["light"] == "laser")
    out = tmp_path / "cal.json"
    capsys.readouterr()
    assert main(["calibrate", str(folder), "--method", "target", "--pattern", pattern, "--out", str(out),
                 "--quiet"]) != 0
    err = capsys.readouterr().err.strip()
    assert words in err and "\n" not in err and "Traceback" not in err, err
    assert not out.exists()


@pytest.mark.render
def test_parallel_poses_are_named_degenerate(tmp_path, capsys, variant):
    flat = tmp_path / "flat"
    assert main(["render", "target", "--preset", "paper", "--pattern", "chessboard:6x5:12", "--binning", "4",
                 "--quiet", "--poses", "4", "--tilt-deg", "0", "--roll-deg", "0", "--off-sheet-mm", "0",
                 "--lights", "flood", "--depth-range-mm", "560:600", "--height-range-mm=-5:5",
                 "--out", str(flat)]) == 0
    capsys.readouterr()
    assert main(["calibrate", str(flat), "--method", "target", "--pattern", "chessboard:6x5:12", "--quiet"]) != 0
    err = capsys.readouterr().err.strip()
    assert "degenerate poses: all 4 poses of the pattern are parallel" in err and "\n" not in err
    assert main(["calibrate", str(flat), "--method", "target", "--pattern", "chessboard:5x4:12", "--quiet"]) != 0
    err = capsys.readouterr().err.strip()                                      # 5 × 4 given for a 6 × 5 board
    assert "found in 0 of 4 flood-lit frames; is the pattern 6 × 5 (inner corners)?" in err and "\n" not in err


# ---------------------------------------------------------------- closed forms


def test_the_focus_condition_is_the_lens_equation_for_an_untilted_camera():
    cam = OpenCVCamera(np.array([[2000.0, 0, 640], [0, 2000.0, 480], [0, 0, 1]]), np.zeros(14))
    pitch_um, distance = 3.0, 400.0
    axis, f = focus_axis(cam, [0.0, 0.0, 1.0, -distance], pitch_um)
    d_s = 2000.0 * pitch_um * 1e-3
    assert f == pytest.approx(1.0 / (1.0 / d_s + 1.0 / distance), rel=1e-12)
    np.testing.assert_allclose(axis, [0.0, 0.0, 1.0], atol=1e-15)


def test_the_focus_condition_gives_the_twin_rigs_lens_and_axis():
    import sim.truth
    from scheimpflug.model.hinge import hinge_geometry
    from scheimpflug.model.rig import load_preset

    rig = load_preset("paper")
    cam, c = sim.truth.opencv_camera(rig)
    camera = OpenCVCamera(cam.camera_matrix, cam.dist_coeffs)
    g = hinge_geometry(rig)
    n = c[:3, :3] @ g.sheet_normal
    p = c[:3, :3] @ g.rig_from_sheet(600.0, 0.0) + c[:3, 3]
    plane = np.array([*n, -n @ p]) if n @ p > 0 else -np.array([*n, -n @ p])
    axis, f = focus_axis(camera, plane, rig.sensor.pixel_pitch_um)
    assert f == pytest.approx(rig.lens.focal_length_mm, rel=1e-9)
    np.testing.assert_allclose(axis, [0.0, 0.0, 1.0], atol=1e-9)                # the camera's z is the lens axis
    gauge = _centred(camera, (rig.sensor.columns, rig.sensor.rows))             # τ is a gauge without distortion
    pts = np.random.default_rng(0).uniform(-40, 40, (50, 3)) + [0.0, 0.0, 650.0]
    a, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), camera.camera_matrix, camera.dist_coeffs)
    turned = pts @ (_rot_tilt(gauge).T @ _rot_tilt(camera)).T
    b, _ = cv2.projectPoints(turned, np.zeros(3), np.zeros(3), gauge.camera_matrix, gauge.dist_coeffs)
    assert np.abs(a - b).max() < 1e-9 and abs(math.degrees(gauge.tau_y_rad) - 21.646) > 2.0


def test_planes_turned_about_a_line_give_that_line():
    rng = np.random.default_rng(4)
    w = np.array([0.05, -1.0, 0.02])
    w /= np.linalg.norm(w)
    q = np.array([10.0, 5.0, 700.0])
    n0 = np.cross(w, [1.0, 0.0, 0.0])
    n0 /= np.linalg.norm(n0)
    planes = []
    for theta in np.radians([0, 25, 50, 80, 110, 150]):
        rot = cv2.Rodrigues(w * theta)[0]
        n = rot @ n0
        planes.append([*n, -(n @ q) + 3.0 + rng.normal(0, 1e-4)])              # the face 3 mm off the axis
    qq, ww, rms = rotary_axis_from_planes(planes)
    assert math.degrees(math.acos(abs(ww @ w))) < 1e-3 and np.linalg.norm(np.cross(qq - q, w)) < 1e-2
    with pytest.raises(CalibrationError, match="do not turn"):
        rotary_axis_from_planes([planes[0]] * 3)


def test_the_laser_plane_fit_drops_outliers():
    rng = np.random.default_rng(2)
    n = np.array([0.9, 0.1, 0.3])
    n /= np.linalg.norm(n)
    e1 = np.cross(n, [0.0, 0.0, 1.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    pts = 150.0 * n + rng.uniform(-40, 40, (2000, 1)) * e1 + rng.uniform(-40, 40, (2000, 1)) * e2
    pts += rng.normal(0, 0.02, (2000, 1)) * n
    pts[:100] += 5.0 * n                                                        # a reflection's points
    plane, keep = fit_laser_plane(pts)
    assert not keep[:100].any() and keep[100:].mean() > 0.99
    assert math.degrees(math.acos(plane[:3] @ n)) < 0.01 and abs(plane[3] + 150.0) < 0.01


def test_the_blur_centroid_is_the_light_cones_on_the_tilted_sensor():
    """Against a midpoint-rule integral over the aperture written here (rays to the conjugate point)."""
    import sim.truth
    from scheimpflug.model.rig import load_preset

    rig = load_preset("paper")
    cam, _ = sim.truth.opencv_camera(rig)
    camera = OpenCVCamera(cam.camera_matrix, cam.dist_coeffs)
    f, n_f = rig.lens.focal_length_mm, rig.lens.f_number
    x = np.array([[-30.0, 20.0, 640.0], [25.0, -15.0, 600.0]])                 # off the sheet: defocused
    ours = blur_centroid_offsets(camera, x, f, n_f, rig.sensor.pixel_pitch_um)
    rr, pp = np.meshgrid((np.arange(500) + 0.5) / 500, (np.arange(1000) + 0.5) / 1000 * 2 * math.pi)
    r = 0.5 * f / n_f * np.sqrt(rr.ravel())                                   # midpoint rule, equal areas
    ap = np.c_[r * np.cos(pp.ravel()), r * np.sin(pp.ravel()), np.zeros(r.size)]
    k, t = camera.camera_matrix, camera.tilt
    n_s = _rot_tilt(camera).T @ [0.0, 0.0, 1.0]                                # OpenCV's tilted sensor normal
    plane_pt = -np.array([0.0, 0.0, camera.focal_px * rig.sensor.pixel_pitch_um * 1e-3])   # the real sensor

    def to_px(q):                                                              # a sensor point's pixel (pinhole)
        h = (k @ t @ np.c_[q[:, 0] / q[:, 2], q[:, 1] / q[:, 2], np.ones(len(q))].T).T
        return h[:, :2] / h[:, 2:]

    for i, p in enumerate(x):
        img = -f * p / (p[2] - f)                                              # thin lens: the conjugate point
        w = img - ap
        lam = ((plane_pt - ap) @ n_s) / (w @ n_s)
        q = ap + lam[:, None] * w
        d = ap - q
        wt = np.abs(d[:, 2]) * np.abs(d @ n_s) / (d ** 2).sum(1) ** 2
        centroid = (to_px(q) * wt[:, None]).sum(0) / wt.sum()
        chief = to_px(img[None])[0]
        assert np.abs(centroid - chief - ours[i]).max() < 1e-3, (centroid - chief, ours[i])
        assert np.abs(ours[i]).max() > 0.02                                    # a shift worth correcting
