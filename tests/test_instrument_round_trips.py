"""Issue 35's two round trips: the twin of an instrument given by its calibration, measured again.

A. A target calibration of a distorted camera (k1 = −0.22, k2 = 0.09) → ``rig from-calibration``
   → ``render target`` (a ChArUco pattern set: flood-lit and laser frames per pose) →
   ``calibrate --method target``.  The references are the calibration the rig was built from
   (K, distortion, plane — independent of the renderer) and OpenCV's own ``undistortPoints`` /
   ``projectPoints`` for the distortion mapping, compared on a grid of pixels over the frame.
B. On the command line as a user would: ``rig from-calibration dummy.config.json`` (FabScanPi's
   own calibration, ``--chain raspberry_pi_v2``) → ``render rotary --part MESH.stl --step-deg 12``
   (RGB JPEG, 1640 × 1232 as FabScan stores them) → ``import`` of those JPEG files as real
   frames → ``reconstruct --calibration dummy.config.json`` → ``evaluate --z-range`` from 1 mm
   above the part's foot (the turntable's disc shows its own line: the table's points, not the
   part's) against the twin's ``truth/mesh.ply``.  Skipped, saying so, where ``../shared/realdata`` is absent.

Measured figures (and the full-resolution commands) are in benchmarks/RESULTS.md, "Instrument
twin round trips (issue 35)".
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from scheimpflug.app.cli import main

pytestmark = pytest.mark.render

# ------------------------------------------------------------------ A: a target calibration

#: the issue's tolerances (issue 35, "Acceptance", round trips) — never loosened
FX_REL = 1e-3            # fx within 0.1 %
DISTORTION_PX = 0.05     # the distortion mapping within 0.05 px over the frame
PLANE_DEG = 0.05         # the plane's normal within 0.05°
PLANE_MM = 0.05          # the plane's distance within 0.05 mm

W, H = 800, 600
K_IN = np.array([[900.0, 0.0, 401.3], [0.0, 900.0, 297.6], [0.0, 0.0, 1.0]])
D_IN = np.array([-0.22, 0.09, 0.0, 0.0, 0.0])                  # |k1| ≥ 0.1
N_IN = np.array([0.5, 0.05, 0.86]) / np.linalg.norm([0.5, 0.05, 0.86])
D_MM = 180.0                                                   # the sheet n·X = 180 mm, camera frame
PATTERN = "charuco:12x9:10:7:DICT_4X4_100"                     # partly seen boards count: the frame's edges
POSES = 10


def _target_calibration(path: Path) -> None:
    """The calibration the instrument is built from, as ``calibrate --method target`` saves one."""
    from scheimpflug.calibration.camera import OpenCVCamera
    from scheimpflug.calibration.model import sheet_frame_from_plane
    from scheimpflug.calibration.target import TargetCalibration

    plane = np.array([*N_IN, -D_MM])
    origin, e_s, e_h = sheet_frame_from_plane(plane)
    TargetCalibration(camera=OpenCVCamera(K_IN, D_IN), homography=np.column_stack([e_s, e_h, origin]),
                      columns=W, rows=H, n_frames=0, laser_plane=plane, pattern="chessboard:9x6:10").save(path)


def _pixel_grid(step_px: float = 20.0) -> np.ndarray:
    """(n, 2) pixels over the whole frame, its edges and corners included."""
    u = np.linspace(0.0, W - 1.0, int(round((W - 1) / step_px)) + 1)
    v = np.linspace(0.0, H - 1.0, int(round((H - 1) / step_px)) + 1)
    uu, vv = np.meshgrid(u, v)
    return np.column_stack([uu.ravel(), vv.ravel()])


def distortion_mapping_px(k_ref, d_ref, d_other) -> tuple[float, float]:
    """Largest and RMS difference [px] of two distortions over the frame (OpenCV alone).

    Each pixel of a grid over the frame is undistorted with the reference camera
    (``cv2.undistortPoints``) to its ray; the ray is projected with the reference camera
    matrix and either distortion (``cv2.projectPoints``): the difference is the distortion's
    alone, in pixels of this camera, apart from the camera matrices' own differences.
    """
    p = _pixel_grid()
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    x = cv2.undistortPoints(p.reshape(-1, 1, 2), k_ref, d_ref, criteria=crit).reshape(-1, 2)
    rays = np.column_stack([x, np.ones(len(x))])
    ref = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), k_ref, d_ref)[0].reshape(-1, 2)
    assert np.abs(ref - p).max() < 1e-6                   # OpenCV's own round trip closes
    got = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), k_ref, d_other)[0].reshape(-1, 2)
    err = np.linalg.norm(got - ref, axis=1)
    return float(err.max()), float(np.sqrt(np.mean(err ** 2)))


def plane_differences(plane_ref, plane_other) -> tuple[float, float]:
    """Angle between the normals [deg] and the signed difference of the distances [mm]."""
    a, b = (np.asarray(q, float) / np.linalg.norm(np.asarray(q, float)[:3]) for q in (plane_ref, plane_other))
    b = b if a[:3] @ b[:3] > 0 else -b
    angle = math.degrees(math.atan2(np.linalg.norm(np.cross(a[:3], b[:3])), a[:3] @ b[:3]))
    return angle, float(-b[3] - -a[3])


def test_distortion_mapping_of_a_camera_with_itself_is_zero_and_sees_a_change():
    """The comparison's own degenerate case, and a known change: k2 + 0.001, largest at the farthest corner."""
    assert distortion_mapping_px(K_IN, D_IN, D_IN)[0] < 1e-9
    other = D_IN + np.array([0.0, 1e-3, 0.0, 0.0, 0.0])
    corners = np.array([[[0.0, 0.0]], [[W - 1.0, 0.0]], [[0.0, H - 1.0]], [[W - 1.0, H - 1.0]]])
    x = cv2.undistortPoints(corners, K_IN, D_IN, criteria=(
        cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)).reshape(-1, 2)
    r2 = (x ** 2).sum(axis=1).max()
    # closed form at the frame's farthest corner: Δ = fx · 1e-3 · r⁵ along the radius (fx = fy)
    assert distortion_mapping_px(K_IN, D_IN, other)[0] == pytest.approx(900.0 * 1e-3 * r2 ** 2.5, rel=1e-9)
    assert plane_differences([0, 0, 1, -100], [0, 0, -2, 201]) == pytest.approx((0.0, 0.5), abs=1e-12)


#: The lens's f-number (the calibration does not give it: ``rig from-calibration`` writes 2.0 and lists
#: it as unknown): f/8 keeps the poses' defocus blur ≤ 0.2 px, f/2 blurs their far edges by ≈ 0.7 px.
F_NUMBERS = (8.0, 2.0)


@pytest.fixture(scope="module", params=F_NUMBERS, ids=lambda n: f"f{n:g}")
def round_trip_a(request, tmp_path_factory, variant):
    """Round trip A once per f-number: its figures (measured 2026-12-07 with seed 0, see RESULTS.md)."""
    tmp = tmp_path_factory.mktemp("round_trip_a")
    _target_calibration(tmp / "target.json")
    rig = tmp / "rig.toml"
    assert main(["rig", "from-calibration", str(tmp / "target.json"), "--out", str(rig)]) == 0
    rig.write_text(re.sub(r"^f_number = .*$", f"f_number = {request.param!r}", rig.read_text(), flags=re.M))
    assert main(["render", "target", "--rig", str(rig), "--pattern", PATTERN, "--poses", str(POSES),
                 "--seed", "0", "--out", str(tmp / "tgt"), "--quiet"]) == 0
    assert main(["calibrate", str(tmp / "tgt"), "--method", "target", "--pattern", PATTERN,
                 "--distortion", "k1k2", "--out", str(tmp / "cal.json"), "--quiet"]) == 0
    got = json.loads((tmp / "cal.json").read_text())
    k, d = np.array(got["camera_matrix"]), np.array(got["dist_coeffs"])
    dist_max, dist_rms = distortion_mapping_px(K_IN, D_IN, d)
    angle, dd = plane_differences([*N_IN, -D_MM], got["laser_plane"])
    figures = {"f_number": request.param, "fx_rel": k[0, 0] / K_IN[0, 0] - 1.0, "fy_rel": k[1, 1] / K_IN[1, 1] - 1.0,
               "distortion_max_px": dist_max, "distortion_rms_px": dist_rms, "plane_deg": angle,
               "plane_mm": dd, "poses_used": len(got["poses_used"])}
    print("round trip A:", figures)
    return figures


@pytest.mark.slow
def test_round_trip_a_camera(round_trip_a):
    """fx within 0.1 %; the distortion within 0.05 px over the frame.

    Measured (seed 0): f/8 +0.009 %, 0.033 px; f/2 −0.038 %, 0.014 px.
    """
    f = round_trip_a
    assert f["poses_used"] >= 8
    assert abs(f["fx_rel"]) < FX_REL and abs(f["fy_rel"]) < FX_REL, f
    assert f["distortion_max_px"] < DISTORTION_PX, f


@pytest.mark.slow
def test_round_trip_a_plane_direction(round_trip_a):
    """The laser plane's normal within 0.05°.  Measured (seed 0): f/8 0.014°, f/2 0.015°."""
    assert round_trip_a["plane_deg"] < PLANE_DEG, round_trip_a


@pytest.mark.slow
def test_round_trip_a_plane_distance(request, round_trip_a):
    """The laser plane's distance within 0.05 mm.  Measured (seed 0): f/8 +0.016 mm; f/2 −0.067 mm —
    missed at f/2 (strict xfail, the reason below)."""
    f = round_trip_a
    if f["f_number"] < 4.0:
        request.applymarker(pytest.mark.xfail(strict=True, reason=(
            "f/2: measured −0.067 mm (seeds 0, 1, 2: −0.067, −0.052, −0.067 mm).  The calibration's fx comes "
            "out −0.035 … −0.047 % low on the twin's defocused frames (2 σ of its own standard error in every "
            "seed; the same without distortion, −0.048 %; calibrated on the exact corner truth it is exact; "
            "at f/8 +0.009 %), and the poses' depths, the plane's distance with them, scale with fx: "
            "−0.04 % of 180 mm.  A bias of blurred corners (the corner model or the twin's blur), open.")))
    assert abs(f["plane_mm"]) < PLANE_MM, f


# ------------------------------------------------------------------ B: FabScan on the command line

REAL = Path(__file__).resolve().parents[2] / "shared" / "realdata"
CONFIG = REAL / "fabscan" / "dummy.config.json"
needs_config = pytest.mark.skipif(not CONFIG.is_file(), reason=f"FabScan's config absent ({CONFIG}): "
                                  "see the README of the real-data folder")
RMS_MM = 0.05            # issue 35: ≤ 0.05 mm RMS with an ideal chain

#: The ideal chain: the keys of ``rig from-calibration --chain raspberry_pi_v2``'s file a user edits.
#: Still JPEG files of the Bayer camera, but lossless-like (quality 100, no chroma subsampling), no
#: veiling glare, a linear tone curve, equal laser responses of R, G and B (the mosaic neutral), no read
#: noise; blooming is off in the preset.  The photons' shot noise stays (no key turns it off).
IDEAL = {"chain": {"jpeg_quality": "100", "jpeg_subsampling": '"4:4:4"', "glare_fraction": "0.0",
                   "tone_curve": '"gamma"', "gamma": "1.0", "laser_qe_r": "0.45", "laser_qe_g": "0.45",
                   "laser_qe_b": "0.45", "bloom_spill_fraction": "0.0"},
         "sensor": {"read_noise_e": "0.0"}}


def _edit(rig_file: Path, tables: dict) -> None:
    """Set keys of a rig file's tables in place, line by line, as a user edits it."""
    text, table = [], None
    for line in rig_file.read_text().splitlines():
        m = re.match(r"\[(\w+)\]", line)
        table = m.group(1) if m else table
        key = line.split("=")[0].strip()
        if table in tables and key in tables[table]:
            line = f"{key} = {tables[table][key]}"
        text.append(line)
    rig_file.write_text("\n".join(text) + "\n")


#: the lowest height scored [mm]: above the table's own points (the stripe on the disc, ±its width)
Z_MIN_MM = 1.0


def _part(path: Path) -> Path:
    """A Ø60 × 80 mm cylinder standing on z = 0, as a user's STL."""
    import trimesh

    mesh = trimesh.creation.cylinder(radius=30.0, height=80.0, sections=256)
    mesh.apply_translation([0.0, 0.0, 40.0])
    mesh.export(path)
    return path


def _fabscan_round_trip(tmp: Path, capsys, edits: dict | None) -> dict:
    rig = tmp / "fabscan.toml"
    assert main(["rig", "from-calibration", str(CONFIG), "--preset", "rpi-v2-binned", "--chain",
                 "raspberry_pi_v2", "--fabscan-distortion", "as-fabscan", "--out", str(rig)]) == 0
    if edits:
        _edit(rig, edits)
    twin = tmp / "twin"
    assert main(["render", "rotary", "--rig", str(rig), "--part", str(_part(tmp / "part.stl")), "--step-deg", "12",
                 "--truth-pixels", "none", "--out", str(twin), "--quiet"]) == 0
    man = json.loads((twin / "manifest.json").read_text())
    files = [twin / f["file"] for f in man["frames"]]
    angles = [f["angle_deg"] for f in man["frames"]]
    assert angles == pytest.approx([12.0 * k for k in range(len(files))], abs=1e-12)
    from PIL import Image

    with Image.open(files[0]) as im:                     # the Raspberry Pi camera's files, FabScan's size
        assert (im.format, im.mode, im.size) == ("JPEG", "RGB", (1640, 1232))
    imported = tmp / "imported"
    assert main(["import", *map(str, files), "--channel", "r", f"--angles-deg={','.join(map(str, angles))}",
                 "--out", str(imported), "--quiet"]) == 0
    assert json.loads((imported / "manifest.json").read_text())["stripe_along"] == "rows"   # as FabScan's
    cloud = tmp / "cloud.ply"
    assert main(["reconstruct", str(imported), "--calibration", str(CONFIG), "--out", str(cloud), "--quiet"]) == 0
    capsys.readouterr()
    # the turntable's disc (FabScan's 70 mm, from its config) shows its own line: those points are
    # the table's, not the part's — the part is scored from Z_MIN_MM above its foot, as a user scores
    # a part standing on a table (the part frame's z = 0 is the rig's meridian height, not the table)
    import trimesh

    z_foot, z_top = trimesh.load(twin / "truth" / "mesh.ply").bounds[:, 2]
    assert main(["evaluate", str(cloud), "--mesh", str(twin / "truth" / "mesh.ply"), "--z-range",
                 str(z_foot + Z_MIN_MM), str(z_top + Z_MIN_MM), "--json"]) == 0
    return json.loads(capsys.readouterr().out)


@needs_config
@pytest.mark.slow
def test_round_trip_b_fabscan_ideal_chain(tmp_path, capsys, variant):
    """≤ 0.05 mm RMS with the ideal chain (:data:`IDEAL`), one whole turn at 12° (measured 0.017 mm).

    The twin's lens is FabScan's own model (``--fabscan-distortion as-fabscan``): ``reconstruct
    --calibration config.json`` reads the file as FabScan does, the camera matrix alone.  With the
    calibrated distortion as the lens (``apply``) the same path gives 0.27 mm RMS, mean
    +0.22 mm: the distortion FabScan's reconstruction leaves out (benchmarks/RESULTS.md).
    """
    got = _fabscan_round_trip(tmp_path, capsys, IDEAL)
    print("round trip B, ideal chain:", got)
    assert got["n_points"] > 20_000
    assert got["rms_mm"] <= RMS_MM, got


@needs_config
@pytest.mark.slow
def test_round_trip_b_fabscan_preset_chain_is_reported(tmp_path, capsys, variant):
    """The preset's chain as it is (noise, bt709, glare, JPEG 95 4:2:0): reported, only its sanity asserted.

    One whole turn at 12°: measured 0.016 mm RMS (benchmarks/RESULTS.md).
    """
    got = _fabscan_round_trip(tmp_path, capsys, None)
    print("round trip B, raspberry_pi_v2 chain:", got)
    assert got["n_points"] > 20_000 and got["rms_mm"] < 0.5, got
