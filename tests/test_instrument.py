"""An instrument given by its calibration → the rig the twin renders, checked against OpenCV itself.

The reference is ``cv2.projectPoints`` with the calibration's K and distortion (independent of
:mod:`scheimpflug.model.camera`); the sheet is compared with the calibration's plane by angle and
distance.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from scheimpflug.errors import RigError
from scheimpflug.model.camera import project_points, sensor_pose, sheet_point_from_pixel
from scheimpflug.model.distortion import distort_tangents, is_radial, undistort_tangents
from scheimpflug.model.instrument import (
    Camera,
    Instrument,
    Sheet,
    Turntable,
    camera_preset,
    rig_frame,
    rig_from_instrument,
)
from scheimpflug.model.rig import Lens, load_preset, load_rig

FABSCAN = Path(__file__).resolve().parents[2] / "shared" / "realdata" / "fabscan" / "dummy.config.json"
TOL_PX = 0.01          # the brief's bound; the measured agreement is ≈ 1e-9 px
K_SYN = np.array([[1510.0, 0.0, 655.3], [0.0, 1498.2, 470.9], [0.0, 0.0, 1.0]])
D_SYN = (-0.31, 0.12, 8e-4, -6e-4, -0.03)          # |k1| ≥ 0.1, all five terms


def _rotation(rng) -> np.ndarray:
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


def _synthetic(rng) -> tuple[Instrument, np.ndarray, float]:
    """A distorted 1280 × 960 camera at a random pose; a sheet crossing its view 200–400 mm away."""
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = _rotation(rng), rng.uniform(-100, 100, 3)
    n_c = np.array([0.8, 0.1, 0.55])
    n_c /= np.linalg.norm(n_c)
    d_c = 0.55 * 300.0 + 0.8 * 60.0                      # through (60, 0, 300) mm of the camera frame
    n_i = pose[:3, :3] @ n_c                             # the plane in the instrument frame
    cam = Camera(K_SYN[0, 0], K_SYN[1, 1], K_SYN[0, 2], K_SYN[1, 2], 1280, 960, D_SYN, 3.75, 2.8,
                 instrument_from_camera=pose)
    return Instrument(cam, Sheet(n_i, d_c + n_i @ pose[:3, 3])), n_c, d_c


def _plane_points(k, dist, n_c, d_c, size, rng, count=400) -> np.ndarray:
    """Camera-frame points of the plane n·X = d seen by random pixels (OpenCV's own undistortion)."""
    uv = rng.uniform([0, 0], [size[0] - 1, size[1] - 1], (count, 2))
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    m = cv2.undistortPoints(uv.reshape(-1, 1, 2), k, np.asarray(dist), criteria=crit).reshape(-1, 2)
    w = np.column_stack([m, np.ones(len(m))])
    lam = d_c / (w @ n_c)
    return (lam[:, None] * w)[lam > 0]


def _agreement_px(rig, rig_from_camera, k, dist, points_c) -> float:
    ref, _ = cv2.projectPoints(points_c.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), k, np.asarray(dist))
    got = project_points(rig, points_c @ rig_from_camera[:3, :3].T + rig_from_camera[:3, 3]).uv_px
    return float(np.abs(got - ref.reshape(-1, 2)).max())


def _sheet_matches(rig, frame, n_c, d_c) -> None:
    """The rig's sheet y = d − x·tan φ is the calibration's plane: angle and distance to 1e-9."""
    n_rig = np.array([rig.laser.tan_phi, 1.0, 0.0]) / math.hypot(rig.laser.tan_phi, 1.0)
    n_back = frame.rig_from_camera[:3, :3].T @ n_rig
    assert n_back @ n_c > 0
    assert math.degrees(math.asin(min(1.0, float(np.linalg.norm(np.cross(n_back, n_c)))))) < 1e-9
    assert rig.laser.scheimpflug_distance_mm / math.hypot(rig.laser.tan_phi, 1.0) == pytest.approx(d_c, abs=1e-9)


def test_projection_of_a_distorted_camera_is_opencvs(rng):
    inst, n_c, d_c = _synthetic(rng)
    rig, frame = rig_from_instrument(inst), rig_frame(inst)
    pts = _plane_points(K_SYN, D_SYN, n_c, d_c, (1280, 960), rng)
    assert len(pts) > 300
    assert _agreement_px(rig, frame.rig_from_camera, K_SYN, D_SYN, pts) < TOL_PX
    # the instrument frame's own points, through rig_from_instrument
    pose = inst.camera.instrument_from_camera
    pts_i = pts @ pose[:3, :3].T + pose[:3, 3]
    got = project_points(rig, pts_i @ frame.rig_from_instrument[:3, :3].T + frame.rig_from_instrument[:3, 3]).uv_px
    ref = cv2.projectPoints(pts.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K_SYN, np.asarray(D_SYN))[0]
    assert np.abs(got - ref.reshape(-1, 2)).max() < TOL_PX
    _sheet_matches(rig, frame, n_c, d_c)


def test_pixel_to_sheet_round_trip_through_opencv(rng):
    """sheet_point_from_pixel (inverse distortion) lands on the plane where OpenCV projects it back."""
    inst, n_c, d_c = _synthetic(rng)
    rig, frame = rig_from_instrument(inst), rig_frame(inst)
    uv = rng.uniform([0, 0], [1279, 959], (200, 2))
    p_rig = sheet_point_from_pixel(rig, uv)
    ok = np.all(np.isfinite(p_rig), axis=1)
    assert ok.mean() > 0.5
    p_c = p_rig[ok] @ frame.rig_from_camera[:3, :3]              # rotation only: the lens is the camera centre
    assert np.abs(p_c @ n_c - d_c).max() < 1e-9
    back = cv2.projectPoints(p_c.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K_SYN, np.asarray(D_SYN))[0]
    assert np.abs(back.reshape(-1, 2) - uv[ok]).max() < 1e-6


@pytest.mark.skipif(not FABSCAN.is_file(), reason="../shared/realdata/fabscan/dummy.config.json is absent")
def test_fabscan_config_gives_the_rig_opencv_projects_with(rng, tmp_path):
    from scheimpflug.app.cli import main
    from scheimpflug.calibration.fabscan import read_fabscan

    out = tmp_path / "fabscan.toml"
    assert main(["rig", "from-calibration", str(FABSCAN), "--out", str(out), "--preset", "rpi-v2-binned",
                 "--no-turntable", "--fabscan-distortion", "apply"]) == 0
    rig = load_rig(out)                                # the file, as a user would load it
    cal = read_fabscan(FABSCAN, distortion="apply")    # the stored frames' camera (FabScan turns its own)
    k, dist = cal.camera.camera_matrix, cal.camera.dist_coeffs[:5]
    plane = cal.laser_plane
    n_c, d_c = plane[:3], -plane[3]                    # a·X + d = 0 with d < 0 → n·X = D > 0
    pts = _plane_points(k, dist, n_c, d_c, (cal.columns, cal.rows), rng)
    assert len(pts) > 300
    from scheimpflug.calibration.instrument import instrument_from_calibration
    frame = rig_frame(instrument_from_calibration(FABSCAN, "rpi-v2-binned", turntable=False,
                                                  fabscan_distortion="apply"))
    assert _agreement_px(rig, frame.rig_from_camera, k, dist, pts) < TOL_PX
    _sheet_matches(rig, frame, n_c, d_c)
    assert (rig.sensor.columns, rig.sensor.rows, rig.sensor.pixel_pitch_um) == (1640, 1232, 2.24)
    assert "unknown" in out.read_text()


def test_opencv_file_on_the_command_line(rng, tmp_path):
    from scheimpflug.app.cli import main

    n_c = np.array([0.8, 0.1, 0.55]) / np.linalg.norm([0.8, 0.1, 0.55])
    d_c = 0.55 * 300.0 + 0.8 * 60.0
    f = tmp_path / "cam.json"
    f.write_text(json.dumps({"camera_matrix": K_SYN.tolist(), "dist_coeffs": list(D_SYN),
                             "laser_plane": [*n_c, -d_c], "image_size": [1280, 960]}))
    out = tmp_path / "rig.toml"
    assert main(["rig", "from-calibration", str(f), "--out", str(out)]) == 0
    rig = load_rig(out)
    pts = _plane_points(K_SYN, D_SYN, n_c, d_c, (1280, 960), rng)
    from scheimpflug.calibration.instrument import instrument_from_calibration
    frame = rig_frame(instrument_from_calibration(f))
    assert _agreement_px(rig, frame.rig_from_camera, K_SYN, D_SYN, pts) < TOL_PX
    assert main(["rig", "from-calibration", str(f), "--out", str(out)]) == 2          # exists: --force
    assert main(["rig", "from-calibration", str(f), "--out", str(out), "--preset", "nope", "--force"]) == 2
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"camera_matrix": [[0, 0, 640], [0, 0, 480], [0, 0, 1]], "dist_coeffs": [0] * 5,
                               "laser_plane": [*n_c, -d_c], "image_size": [1280, 960]}))
    assert main(["rig", "from-calibration", str(bad), "--out", str(tmp_path / "x.toml")]) == 2
    assert not (tmp_path / "x.toml").exists() and not list(tmp_path.glob("*.tmp*"))


def test_distortion_round_trip_and_radial_special_case(rng):
    lens = Lens(k1=-0.31, k2=0.12, k3=-0.03, p1=8e-4, p2=-6e-4, aspect_ratio=0.992)
    a = rng.uniform(-0.4, 0.4, (500, 2))
    for roll in (0.0, 37.0, -178.1):
        assert np.abs(undistort_tangents(lens, roll, distort_tangents(lens, roll, a)) - a).max() < 1e-13
    radial = Lens(k1=-0.31, k2=0.12)
    t2 = (a ** 2).sum(axis=1, keepdims=True)
    assert np.allclose(distort_tangents(radial, 23.0, a), a * (1 - 0.31 * t2 + 0.12 * t2 ** 2), rtol=0, atol=1e-15)
    assert is_radial(radial) and not is_radial(lens) and is_radial(load_preset("paper").lens)


def test_paper_rig_keeps_its_hinge_sensor():
    rig = load_preset("paper")
    assert rig.sensor.image_distance_mm == 0.0
    pose = sensor_pose(rig)
    assert abs(pose.u_dir[0]) > 0.3                     # tilted by the hinge rule (β ≈ 21.6°)


def _bad(**changes):
    cam = Camera(1000.0, 1000.0, 639.5, 479.5, 1280, 960)
    sheet = Sheet(np.array([0.8, 0.0, 0.6]), 150.0)
    cam_changes = {k: v for k, v in changes.items() if k in Camera.__dataclass_fields__}
    sheet_changes = {k: v for k, v in changes.items() if k in Sheet.__dataclass_fields__}
    import dataclasses

    return Instrument(dataclasses.replace(cam, **cam_changes), dataclasses.replace(sheet, **sheet_changes))


@pytest.mark.parametrize("changes, words", [
    ({"fx_px": 0.0}, "singular camera matrix"),
    ({"normal": np.zeros(3)}, "is zero"),
    ({"normal": np.array([0.8, 0.0, 0.7])}, "not 1"),
    ({"normal": np.array([0.0, 0.0, 1.0]), "distance_mm": -200.0}, "behind the camera or outside its view"),
    ({"normal": np.array([0.0, 0.0, 1.0]), "distance_mm": 200.0}, "perpendicular to the optical axis"),
    ({"distance_mm": 0.0}, "edge-on"),
    ({"distortion": (0.1, 0.0, 0.0, 0.0, 0.0, 0.2, 0.0, 0.0)}, "k4"),
    ({"distortion": (0.1, 0.0, 0.0)}, "0, 4, 5, 8, 12 or 14"),
])
def test_bad_instruments_are_refused_with_the_reason(changes, words):
    with pytest.raises(RigError, match=words):
        rig_from_instrument(_bad(**changes))


def test_unknown_preset_and_upside_down_table():
    with pytest.raises(RigError, match="unknown camera preset 'nope'"):
        camera_preset("nope")
    inst = _bad()
    frame = rig_frame(inst)
    down = frame.rig_from_camera[:3, :3].T @ np.array([0.0, 0.0, -1.0])    # the rig's −z, camera frame
    table = Turntable(np.array([0.0, 0.0, 250.0]), down)     # a table up the rig's −z: held, tilt 180°
    assert rig_from_instrument(Instrument(inst.camera, inst.sheet, table)).stage.axis_tilt_deg == pytest.approx(
        180.0, abs=1e-9)
    up = Turntable(np.array([0.0, 0.0, 250.0]), -down)
    rig = rig_from_instrument(Instrument(inst.camera, inst.sheet, up))
    assert rig.stage.axis_tilt_deg == pytest.approx(0.0, abs=1e-9)
    side = frame.rig_from_camera[:3, :3].T @ np.array([0.0, 1.0, 1.0]) / math.sqrt(2.0)     # leaning 45°
    with pytest.raises(RigError, match="leans 45"):
        rig_from_instrument(Instrument(inst.camera, inst.sheet, Turntable(np.array([0.0, 0.0, 250.0]), side)))


def test_dr_jit_distortion_is_numpys(variant, rng):
    import drjit as dr
    import mitsuba as mi

    from sim.lens import distort_tangents_dr, undistort_tangents_dr

    rig = rig_from_instrument(_synthetic(rng)[0])
    a = rng.uniform(-0.35, 0.35, (256, 2))
    ref = distort_tangents(rig.lens, rig.sensor.roll_deg, a)
    got = distort_tangents_dr(rig, mi.Float(a[:, 0]), mi.Float(a[:, 1]))
    assert np.abs(np.column_stack([np.array(g) for g in got]) - ref).max() < 1e-6       # float32
    back = undistort_tangents_dr(rig, mi.Float(ref[:, 0]), mi.Float(ref[:, 1]))
    dr.eval(back)
    assert np.abs(np.column_stack([np.array(g) for g in back]) - a).max() < 1e-6


def test_binned_ordinary_camera_keeps_the_geometry(rng):
    from scheimpflug.model.binning import binned_rig

    inst, n_c, d_c = _synthetic(rng)
    inst = Instrument(Camera(K_SYN[0, 0], K_SYN[1, 1], K_SYN[0, 2], K_SYN[1, 2], 1281, 961, D_SYN), inst.sheet)
    frame = rig_frame(inst)
    rig = rig_from_instrument(inst)
    pts = _plane_points(K_SYN, D_SYN, n_c, d_c, (1281, 961), rng) @ frame.rig_from_camera[:3, :3].T
    for k in (2, 3):
        uv = project_points(binned_rig(rig, k), pts).uv_px
        assert np.abs(uv - (project_points(rig, pts).uv_px - (k - 1) / 2) / k).max() < 1e-9


def test_rig_truth_gives_the_calibrated_opencv_camera_back(rng):
    """What a rendered folder records as its camera (truth/rig_truth.json) is the calibration's K and distortion."""
    from sim.truth import opencv_camera, rig_truth

    inst, _, _ = _synthetic(rng)
    rig, frame = rig_from_instrument(inst), rig_frame(inst)
    cv = rig_truth(rig)["opencv"]
    assert np.allclose(cv["camera_matrix"], K_SYN, rtol=0, atol=1e-9)
    assert np.allclose(cv["dist_coeffs"][:5], D_SYN, rtol=0, atol=1e-12) and not np.any(cv["dist_coeffs"][5:])
    _, camera_from_rig = opencv_camera(rig)
    assert np.allclose(camera_from_rig @ frame.rig_from_camera, np.eye(4), rtol=0, atol=1e-12)


def test_design_of_an_ordinary_camera_has_no_hinge_figures(rng):
    """The hinge rule's figures are null; the rest: tests/test_design_ordinary_camera.py."""
    from scheimpflug.model.design import design_report

    rep = design_report(rig_from_instrument(_synthetic(rng)[0]))
    assert rep["sensor_kind"] == "ordinary" and rep["tilt_deg"] is None and rep["F2_px_mm"] is None
    assert "ordinary camera" in rep["notes"][0]


def test_target_calibration_file_gives_the_same_camera(rng, tmp_path):
    """This project's target calibration (as ``calibrate --method target`` saves it) → rig → OpenCV's pixels."""
    from scheimpflug.app.cli import main
    from scheimpflug.calibration.camera import OpenCVCamera
    from scheimpflug.calibration.model import sheet_frame_from_plane
    from scheimpflug.calibration.target import TargetCalibration

    n_c = np.array([0.8, 0.1, 0.55]) / np.linalg.norm([0.8, 0.1, 0.55])
    d_c = 213.0
    plane = np.array([*n_c, -d_c])
    origin, e_s, e_h = sheet_frame_from_plane(plane)
    cal = TargetCalibration(camera=OpenCVCamera(K_SYN, np.asarray(D_SYN)),
                            homography=np.column_stack([e_s, e_h, origin]), columns=1280, rows=960, n_frames=0,
                            laser_plane=plane, pattern="chessboard:9x6:10")
    f = tmp_path / "target.json"
    cal.save(f)
    out = tmp_path / "rig.toml"
    assert main(["rig", "from-calibration", str(f), "--out", str(out)]) == 0
    from scheimpflug.calibration.instrument import instrument_from_calibration
    frame = rig_frame(instrument_from_calibration(f))
    pts = _plane_points(K_SYN, D_SYN, n_c, d_c, (1280, 960), rng)
    assert _agreement_px(load_rig(out), frame.rig_from_camera, K_SYN, D_SYN, pts) < TOL_PX


def test_fold_of_the_distortion_is_found_and_warned():
    from scheimpflug.model.distortion import fold_radius

    assert fold_radius(Lens(k1=0.145, k2=0.154, k3=-1.15)) == pytest.approx(0.69437, abs=1e-4)  # FabScan's
    assert fold_radius(Lens(k1=-0.31, k2=0.12, k3=-0.03)) > 0.0 and fold_radius(Lens()) == math.inf
    lens = Lens(k1=0.145, k2=0.154, k3=-1.15)
    r = np.linspace(0.0, 1.0, 100001)
    rd = r * (1 + 0.145 * r**2 + 0.154 * r**4 - 1.15 * r**6)
    assert fold_radius(lens) == pytest.approx(rd.max(), abs=1e-8)           # the fold is the distorted radius's peak
    cam = Camera(1000.0, 1000.0, 639.5, 479.5, 1280, 960, (0.145, 0.154, 0.0, 0.0, -1.15))
    with pytest.warns(UserWarning, match="folds back"):
        rig_from_instrument(Instrument(cam, Sheet(np.array([0.8, 0.0, 0.6]), 150.0)))
