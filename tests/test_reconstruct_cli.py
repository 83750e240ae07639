"""`scheimpflug reconstruct` and `scheimpflug evaluate` end to end on synthetic rotary frames.

The frames are drawn from the closed forms (a Gaussian stripe at the column of
the near side of a cylinder centred on the rotary axis), independent of the
renderer; the reconstructed cloud must lie on that cylinder.
"""

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import trimesh

from scheimpflug.app.cli import main
from scheimpflug.calibration import Calibration
from scheimpflug.io.ply import read_point_cloud

ROWS, COLS = 200, 300
U_H, V_H, F2, D0, C = 800.0, 100.0, -1.0e5, -100.0, 100.0
AXIS, RADIUS, HALF_H = 80.0, 20.0, 10.0


def _stripe_frame(rng, u_c, v_rows, peak=2000.0, sigma=1.5, background=100.0, noise=2.0):
    cols = np.arange(COLS)
    img = np.full((ROWS, COLS), background) + rng.normal(0, noise, (ROWS, COLS))
    img[v_rows] += peak * np.exp(-0.5 * ((cols - u_c) / sigma) ** 2)
    return np.clip(np.round(img), 0, 65535).astype(np.uint16)


def _write_scan(path: Path, frames, angles, rig=True):
    (path / "frames").mkdir(parents=True, exist_ok=True)
    entries = []
    for i, (f, a) in enumerate(zip(frames, angles)):
        name = f"frames/{i:05d}.png"
        cv2.imwrite(str(path / name), f)
        entry = {"file": name, "exposure_ms": 5.0, "seed": i}
        if a is not None:
            entry["angle_deg"] = float(a)
        entries.append(entry)
    manifest = {"scenario": "rotary", "frames": entries}
    if rig:
        manifest["rig"] = {"sensor": {"rows": ROWS, "columns": COLS, "adc_bits": 16}}
    (path / "manifest.json").write_text(json.dumps(manifest))
    return path


@pytest.fixture
def cal_file(tmp_path):
    cal = Calibration(hinge_u_px=U_H, hinge_v_px=V_H, F2_px_mm=F2, F2_sigma_px_mm=0.0, d0_mm=D0,
                      C_mm=C, C_sigma_mm=0.0, endpoint_fit_r2=(1.0, 1.0), method="paper",
                      columns=COLS, rows=ROWS)
    cal.save(tmp_path / "cal.json")
    return tmp_path / "cal.json"


def _cylinder_scan(tmp_path, rng, n_frames=24):
    # near side of the cylinder: stage = AXIS - RADIUS; column from Eq. 11 inverted
    u_c = U_H + F2 / (AXIS - RADIUS - D0)
    # rows whose height C (v - v_h)/(u - u_h) is within the cylinder's ±HALF_H
    v = np.arange(ROWS)
    lit = np.abs(C * (v - V_H) / (u_c - U_H)) <= HALF_H - 0.2
    angles = np.arange(n_frames) * 360.0 / n_frames
    frames = [_stripe_frame(rng, u_c, v[lit]) for _ in angles]
    return _write_scan(tmp_path / "scan", frames, angles), int(lit.sum())


def test_reconstruct_and_evaluate_cylinder(tmp_path, rng, cal_file, capsys):
    scan, n_lit = _cylinder_scan(tmp_path, rng)
    out = tmp_path / "cloud.ply"
    assert main(["reconstruct", str(scan), "--calibration", str(cal_file), "--axis-mm", str(AXIS),
                 "--out", str(out), "--json", "--quiet", "--min-snr", "12"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["n_frames"] == 24
    cloud = read_point_cloud(out)
    # every lit row of every frame is found; the stripe detector may add a few false detections
    # in dark rows (noise), which are not reconstruction's business: bounded here, excluded below
    on_part = np.abs(C * (cloud.row - V_H) / (U_H + F2 / (AXIS - RADIUS - D0) - U_H)) <= HALF_H
    assert on_part.sum() == 24 * n_lit
    assert summary["n_points"] - on_part.sum() <= 0.01 * summary["n_points"]
    xyz = cloud.xyz_mm[on_part]
    r = np.hypot(xyz[:, 0], xyz[:, 1])
    # 0.256 mm/px at this column; noise 2 DN on a 2000 DN stripe → centre error ≪ 0.05 px
    assert np.abs(r - RADIUS).max() < 0.01
    assert np.abs(xyz[:, 2]).max() <= HALF_H
    # each frame's points lie on the sheet line at its angle: (r cos θ, −r sin θ) with r = −RADIUS
    th = np.radians(cloud.angle_deg[on_part])
    np.testing.assert_allclose(xyz[:, 0], -RADIUS * np.cos(th), atol=0.01)
    np.testing.assert_allclose(xyz[:, 1], RADIUS * np.sin(th), atol=0.01)
    mesh = trimesh.creation.cylinder(radius=RADIUS, height=2 * HALF_H, sections=720)
    mesh.export(tmp_path / "truth.stl")
    assert main(["evaluate", str(out), "--mesh", str(tmp_path / "truth.stl"), "--json",
                 "--fit", "cylinder", "--fit", "circle", "--z-range", str(-HALF_H), str(HALF_H)]) == 0
    res = json.loads(capsys.readouterr().out)
    for key in ("n_points", "rms_mm", "mean_abs_mm", "p95_mm", "max_mm"):
        assert key in res
    assert res["n_points"] == on_part.sum()
    assert res["distance_kind"] == "signed"
    assert res["rms_mm"] < 0.01
    assert res["fits"]["cylinder"]["diameter_mm"] == pytest.approx(2 * RADIUS, abs=0.01)
    assert res["fits"]["circle"]["diameter_mm"] == pytest.approx(2 * RADIUS, abs=0.01)
    # human-readable output works too
    assert main(["evaluate", str(out), "--mesh", str(tmp_path / "truth.stl"), "--fit", "plane",
                 "--z-range", "-10", "10"]) == 0
    assert "RMS" in capsys.readouterr().out


def _run_fail(args, capsys, match):
    assert main(args) == 2
    err = capsys.readouterr().err
    assert match in err and len(err.strip().splitlines()) == 1, err


def test_reconstruct_bad_inputs(tmp_path, rng, cal_file, capsys):
    base = ["--calibration", str(cal_file), "--axis-mm", "80", "--out", str(tmp_path / "o.ply"),
            "--quiet"]
    # missing manifest
    (tmp_path / "empty").mkdir()
    _run_fail(["reconstruct", str(tmp_path / "empty")] + base, capsys, "manifest")
    # wrong-size frames
    scan = _write_scan(tmp_path / "wrong", [np.zeros((ROWS + 1, COLS), np.uint16)], [0.0])
    _run_fail(["reconstruct", str(scan)] + base, capsys, "expected")
    # unreadable frame
    scan = _write_scan(tmp_path / "corrupt", [np.zeros((ROWS, COLS), np.uint16)], [0.0])
    (scan / "frames/00000.png").write_bytes(b"not a png")
    _run_fail(["reconstruct", str(scan)] + base, capsys, "corrupt")
    # blank frames: no stripe anywhere
    scan = _write_scan(tmp_path / "blank", [np.full((ROWS, COLS), 100, np.uint16)] * 3, [0, 1, 2])
    _run_fail(["reconstruct", str(scan)] + base, capsys, "no stripe")
    # saturated frames: every stripe row is clipped, its edges hard (full scale next to the background), so
    # each edge lies somewhere within a pixel: centred on them (the default) every point is less certain
    # than the SNR filter allows and is dropped; --saturated drop drops them before
    sat = [np.full((ROWS, COLS), 100, np.uint16) for _ in range(2)]
    for i, f in enumerate(sat):
        f[:, 150 + i:154 + i] = 65535
    scan = _write_scan(tmp_path / "sat", sat, [0, 1])
    assert main(["reconstruct", str(scan)] + base) == 2     # (this calibration gives no incidence: a warning first)
    assert "400 saturated with a centre less certain" in capsys.readouterr().err.strip().splitlines()[-1]
    _run_fail(["reconstruct", str(scan), "--saturated", "drop"] + base, capsys, "saturated rows dropped")
    # not a rotary scan
    scan = _write_scan(tmp_path / "noangle", [np.zeros((ROWS, COLS), np.uint16)], [None])
    _run_fail(["reconstruct", str(scan)] + base, capsys, "angle_deg")
    # calibration for another sensor size
    good, _ = _cylinder_scan(tmp_path, rng, n_frames=2)
    other = json.loads(cal_file.read_text())
    other["columns"] = COLS * 2
    (tmp_path / "other.json").write_text(json.dumps(other))
    _run_fail(["reconstruct", str(good), "--calibration", str(tmp_path / "other.json"),
               "--axis-mm", "80", "--out", str(tmp_path / "o.ply"), "--quiet"], capsys, "calibration")
    # missing calibration file
    _run_fail(["reconstruct", str(good), "--calibration", str(tmp_path / "nope.json"),
               "--axis-mm", "80", "--out", str(tmp_path / "o.ply"), "--quiet"], capsys, "does not exist")
    assert not (tmp_path / "o.ply").exists()


def test_evaluate_bad_inputs(tmp_path, capsys):
    mesh = trimesh.creation.box(extents=[1, 1, 1])
    mesh.export(tmp_path / "box.stl")
    m = ["--mesh", str(tmp_path / "box.stl")]
    _run_fail(["evaluate", str(tmp_path / "none.ply")] + m, capsys, "does not exist")
    (tmp_path / "corrupt.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 5\n"
                                           b"property float x\nproperty float y\nproperty float z\n"
                                           b"end_header\n\x00\x01")
    _run_fail(["evaluate", str(tmp_path / "corrupt.ply")] + m, capsys, "truncated")
    (tmp_path / "empty.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 0\n"
                                         b"property float x\nproperty float y\nproperty float z\n"
                                         b"end_header\n")
    _run_fail(["evaluate", str(tmp_path / "empty.ply")] + m, capsys, "empty")
    # a point cloud given as the mesh
    (tmp_path / "pts.ply").write_bytes(b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n"
                                       b"property float y\nproperty float z\nend_header\n0 0 0\n1 0 0\n"
                                       b"0 1 0\n")
    _run_fail(["evaluate", str(tmp_path / "pts.ply"), "--mesh", str(tmp_path / "pts.ply")], capsys,
              "not a mesh")
    _run_fail(["evaluate", str(tmp_path / "pts.ply"), "--mesh", str(tmp_path / "nomesh.stl")], capsys,
              "does not exist")
    _run_fail(["evaluate", str(tmp_path / "pts.ply"), "--mesh", str(tmp_path / "box.stl"),
               "--region", "5"], capsys, "region")


def test_evaluate_regions_from_object_ids(tmp_path, capsys):
    from scheimpflug.io.ply import write_point_cloud
    from scheimpflug.reconstruct import PointCloud

    a = trimesh.creation.box(extents=[10, 10, 10])
    b = trimesh.creation.box(extents=[10, 10, 10])
    b.apply_translation([30, 0, 0])
    both = trimesh.util.concatenate([a, b])
    ids = np.r_[np.full(len(a.faces), 3), np.full(len(b.faces), 4)]
    header = ("ply\nformat binary_little_endian 1.0\n"
              f"element vertex {len(both.vertices)}\nproperty double x\nproperty double y\n"
              f"property double z\nelement face {len(both.faces)}\n"
              "property list uchar int vertex_indices\nproperty int object_id\nend_header\n")
    faces = np.empty(len(both.faces), dtype=[("n", "u1"), ("v", "<i4", (3,)), ("id", "<i4")])
    faces["n"], faces["v"], faces["id"] = 3, both.faces, ids
    (tmp_path / "mesh.ply").write_bytes(header.encode() + np.asarray(both.vertices, "<f8").tobytes()
                                        + faces.tobytes())
    # 0.25 mm outside box 3 (x = 5.25), 0.5 mm inside box 4 (x = 25.5)
    xyz = np.array([[5.25, 0, 0], [5.25, 1, 1], [25.5, 0, 0.0]])
    write_point_cloud(tmp_path / "c.ply", PointCloud(xyz, np.zeros(3), np.zeros(3, int), np.zeros(3)))
    assert main(["evaluate", str(tmp_path / "c.ply"), "--mesh", str(tmp_path / "mesh.ply"), "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["region_key"] == "object_id"
    assert res["regions"]["3"]["n_points"] == 2
    assert res["regions"]["3"]["mean_signed_mm"] == pytest.approx(0.25, abs=1e-6)
    assert res["regions"]["4"]["mean_signed_mm"] == pytest.approx(-0.5, abs=1e-6)
    assert main(["evaluate", str(tmp_path / "c.ply"), "--mesh", str(tmp_path / "mesh.ply"), "--json",
                 "--region", "4"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["n_points"] == 1 and res["max_mm"] == pytest.approx(0.5, abs=1e-6)


class _Turned:
    """A calibration of frames turned by 90° (transpose, then flip left–right): pixel (u', v') is (v', ROWS−1−u')."""

    def __init__(self, cal):
        self.cal = cal

    def stage_from_pixel(self, u, v):
        return self.cal.stage_from_pixel(np.asarray(v, float), ROWS - 1 - np.asarray(u, float))


def test_a_stripe_along_the_rows_gives_the_cloud_of_the_same_frames_unturned(tmp_path, rng, cal_file):
    from scheimpflug.calibration import load_calibration
    from scheimpflug.io.frames import open_frame_folder
    from scheimpflug.reconstruct import extract_folder_stripes, reconstruct_profiles

    scan, _ = _cylinder_scan(tmp_path, rng, n_frames=6)
    turned = tmp_path / "turned"
    (turned / "frames").mkdir(parents=True)
    manifest = json.loads((scan / "manifest.json").read_text())
    for e in manifest["frames"]:
        img = cv2.imread(str(scan / e["file"]), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(turned / e["file"]), cv2.flip(cv2.transpose(img), 1))     # a camera turned by 90°
    manifest.pop("rig")
    manifest["stripe_along"] = "rows"
    (turned / "manifest.json").write_text(json.dumps(manifest))
    cal = load_calibration(cal_file)
    clouds = []
    for folder, model in ((scan, cal), (turned, _Turned(cal))):
        ff = open_frame_folder(folder)
        st = extract_folder_stripes(ff, "gaussian3", min_snr=12)
        clouds.append(reconstruct_profiles(st.rows, st.u, [r.angle_deg for r in ff.frames], model, AXIS,
                                           along=st.along))
    assert len(clouds[0]) == len(clouds[1]) > 6 * 50
    # the turned frames' lines are their columns: the unturned rows, upside down
    lines = np.sort(ROWS - 1 - np.unique(clouds[0].row))
    np.testing.assert_array_equal(np.unique(clouds[1].row), lines)                  # exact: integers
    order = [np.lexsort((c.xyz_mm[:, 2], c.frame)) for c in clouds]
    np.testing.assert_allclose(clouds[1].xyz_mm[order[1]], clouds[0].xyz_mm[order[0]], atol=1e-9)
