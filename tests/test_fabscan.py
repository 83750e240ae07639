"""FabScan's calibration read as the sheet model of its frames as stored, and the stripe along the rows.

FabScanPi-Server turns every frame (transpose, left–right flip) before it measures
it; its calibration describes the turned frames.  The reader must give, for the
frames as the camera stored them, exactly the points FabScan's own formulae give
(re-implemented here from its source: ray ``K⁻¹·p'`` met with ``n·X = d``, the
platform ``Rᵀ(X − t)``, turned by ``R_z(angle)``), up to where the part frame's
origin and zero angle are.  No real data needed; the real frames are in
tests/test_real_frames.py.
"""

import json

import cv2
import numpy as np
import pytest
from fabscan_formulae import fabscan_points, rigid_rms

from scheimpflug.calibration import load_sheet_model
from scheimpflug.calibration.fabscan import fabscan_angles_deg, pixel_map, read_fabscan
from scheimpflug.errors import CalibrationError
from scheimpflug.reconstruct import reconstruct_profiles

W, H = 64, 48          # stored frames: 64 columns, 48 rows


def _rotation(rx, ry, rz):
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
    return (np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]]) @ np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
            @ np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]]))


def _config(tmp_path, rotate="True", hflip="True", vflip="False", dist=(0.1, -0.05, 0.002, -0.001, 0.0)):
    n = np.array([0.8, -0.03, 0.6])
    # the platform's z axis (up) along the turned image's −y, its x toward the camera: a turntable seen from the side
    r = _rotation(0.02, -0.01, 0.015) @ np.array([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]])
    cfg = {"camera": {"resolution": {"width": W, "height": H}, "rotate": rotate, "hflip": hflip, "vflip": vflip},
           "turntable": {"steps": 3200},
           "calibration": {"camera_matrix": [[90.0, 0, 25.0], [0, 92.0, 33.0], [0, 0, 1]],
                           "distortion_vector": list(dist),
                           "laser_planes": [{"normal": (n / np.linalg.norm(n)).tolist(), "distance": 80.0,
                                             "deviation": 0.05}],
                           "platform_rotation": r.tolist(), "platform_translation": [-3.0, 20.0, 120.0]}}
    p = tmp_path / "config.json"
    p.write_text(json.dumps(cfg))
    return p, cfg


@pytest.mark.parametrize("rotate, hflip, vflip", [(r, h, v) for r in (0, 1) for h in (0, 1) for v in (0, 1)])
def test_the_pixel_map_is_fabscans_turning_of_the_frame(rotate, hflip, vflip):
    img = np.zeros((H, W), np.uint8)
    img[7, 41] = 255                                       # row 7, column 41
    turned = img
    if rotate:
        turned = cv2.transpose(turned)
    if hflip:
        turned = cv2.flip(turned, 1)
    if vflip:
        turned = cv2.flip(turned, 0)
    a, b, size = pixel_map(W, H, bool(rotate), bool(hflip), bool(vflip))
    u2, v2 = a @ [41.0, 7.0] + b
    assert size == (turned.shape[1], turned.shape[0]) and turned[int(v2), int(u2)] == 255


@pytest.mark.parametrize("flags", [("True", "True", "False"), ("True", "False", "True"), ("False", "True", "False")])
def test_the_stored_frames_camera_projects_as_fabscans_camera_does(tmp_path, flags):
    path, cfg = _config(tmp_path, *flags)
    model = read_fabscan(path, distortion="apply")
    c = cfg["calibration"]
    a, b, _ = pixel_map(W, H, *(f == "True" for f in flags))
    m = np.eye(3)
    m[:2, :2] = a.T
    x = np.random.default_rng(0).uniform([-30, -30, 100], [30, 30, 200], (40, 3))
    p_fab, _ = cv2.projectPoints(x, np.zeros(3), np.zeros(3), np.array(c["camera_matrix"]),
                                 np.array(c["distortion_vector"]))
    stored = (a.T @ (p_fab[:, 0].T - b[:, None])).T          # the turned pixel back in the stored frame
    ours, _ = cv2.projectPoints((m @ x.T).T, np.zeros(3), np.zeros(3), model.camera.camera_matrix,
                                model.camera.dist_coeffs)
    np.testing.assert_allclose(ours[:, 0], stored, atol=1e-9)






def test_a_scan_reconstructs_to_fabscans_own_points(tmp_path):
    path, cfg = _config(tmp_path)
    model = load_sheet_model(path)                           # FabScan's config read as any calibration
    rng = np.random.default_rng(1)
    angles = fabscan_angles_deg(12, 3200, resolution=1)      # θ = −3.6 … −43.2°
    lines = [np.arange(5, W - 5) for _ in angles]            # one stripe point per column
    across = [rng.uniform(10, H - 10, W - 10) for _ in angles]
    ours = reconstruct_profiles(lines, across, angles, model, None, along="rows").xyz_mm
    theirs = fabscan_points(lines, across, angles, cfg)
    assert rigid_rms(ours, theirs) < 1e-9                    # the same points, up to the part frame's pose
    assert rigid_rms(ours, theirs, mirror=True) > 1.0        # … and not their mirror image
    assert model.axis["angle_to_sheet_deg"] < 5 and model.tilt["distortion"] == "as-fabscan"


def test_fabscans_angle_rule():
    # medium resolution, 6400 steps: int(1.8 / (360/6400)) = 32 steps per picture, 200 pictures, k·1.8°
    a = fabscan_angles_deg(201, 6400, resolution=2)
    assert a[0] == -1.8 and a[199] == pytest.approx(-360.0) and a[200] == pytest.approx(-361.8)
    assert fabscan_angles_deg(3, 3200, resolution=3)[0] == pytest.approx(-360 / (3200 // 7))


@pytest.mark.parametrize("edit, match", [
    (lambda c: c["calibration"].update(laser_planes=[]), "laser 0 has no plane"),
    (lambda c: c["calibration"]["laser_planes"][0].update(normal=[0.8, 0.0, 0.7]), "length"),
    (lambda c: c["calibration"].update(camera_matrix=[[0, 0, 1], [0, 90, 2], [0, 0, 1]]),
     "camera_matrix is singular.*fx = 0, fy = 90"),
    (lambda c: c["calibration"].update(platform_rotation=[[1, 0, 0], [0, 1, 0], [0, 0, 2]]), "rotation"),
    (lambda c: c["camera"].pop("resolution"), "resolution"),
])
def test_a_bad_fabscan_config_is_one_clear_error(tmp_path, edit, match):
    path, cfg = _config(tmp_path)
    edit(cfg)
    path.write_text(json.dumps(cfg))
    with pytest.raises(CalibrationError, match=match):
        load_sheet_model(path)


def test_the_second_laser_of_a_one_laser_config_is_refused(tmp_path):
    path, _ = _config(tmp_path)
    with pytest.raises(CalibrationError, match="laser 1 has no plane.*1 laser plane"):
        read_fabscan(path, laser=1)
