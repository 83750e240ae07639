"""`reconstruct --model` and `evaluate --model` end to end: rendered scans scored against their truth meshes.

The scans are rendered by the twin on a 4 × 4 binned sensor (row pitch
≈ 0.25 mm) and reconstructed with the rig's true constants (the calibration is
tested elsewhere); the acceptance volumes are computed here independently of
the model and of the truth mesh: closed forms, and for the knurled band a fine
numerical integral of its analytic radius.  Bad input: one clear error each,
nothing written.
"""

import json
import math

import numpy as np
import pytest

from scheimpflug.app.cli import main
from scheimpflug.calibration import Calibration
from scheimpflug.io.ply import read_triangle_mesh, write_point_cloud
from scheimpflug.reconstruct import PointCloud
from scheimpflug.scoring import is_closed_mesh

BIN = "4"


def _truth_calibration(scan, path):
    t = json.loads((scan / "truth" / "rig_truth.json").read_text())
    sensor = json.loads((scan / "manifest.json").read_text())["rig"]["sensor"]
    Calibration(hinge_u_px=t["hinge_u_px"], hinge_v_px=t["hinge_v_px"], F2_px_mm=t["F2_px_mm"], F2_sigma_px_mm=0.0,
                d0_mm=t["d0_mm"], C_mm=t["C_mm"], C_sigma_mm=0.0, endpoint_fit_r2=(1.0, 1.0), method="paper",
                columns=sensor["columns"], rows=sensor["rows"]).save(path)
    return t["axis_mm"]


def _scan_and_model(tmp, part, step, capsys):
    scan = tmp / "scan"
    assert main(["render", "rotary", "--part", str(part), "--step-deg", str(step), "--binning", BIN,
                 "--truth-pixels", "none", "--out", str(scan), "--quiet"]) == 0
    axis = _truth_calibration(scan, tmp / "cal.json")
    capsys.readouterr()
    assert main(["reconstruct", str(scan), "--calibration", str(tmp / "cal.json"), "--axis-mm", str(axis),
                 "--out", str(tmp / "cloud.ply"), "--model", str(tmp / "model.ply"), "--json", "--quiet"]) == 0
    rec = json.loads(capsys.readouterr().out)
    assert main(["evaluate", str(tmp / "cloud.ply"), "--mesh", str(scan / "truth" / "mesh.ply"),
                 "--model", str(tmp / "model.ply"), "--samples", "100000", "--json"]) == 0
    return rec, json.loads(capsys.readouterr().out)


def _closed_by_body(path) -> bool:
    m = read_triangle_mesh(path)
    body = m.face_properties["body"]
    return all(is_closed_mesh(m.faces[body == b]) for b in np.unique(body))


@pytest.mark.render
@pytest.mark.slow
def test_paper_cylinder_at_half_degree(tmp_path, capsys):
    """Acceptance: watertight, volume within 0.2 % of π·50²·108 minus the grooves, symmetric mean ≤ 2 × RMS."""
    import scenes
    from scenes import knurl_radius_mm

    rec, ev = _scan_and_model(tmp_path, "cylinder", 0.5, capsys)
    spec = scenes.load_part("cylinder").parts[0].analytic["knurl"]
    th = (np.arange(8000) + 0.5) * 2 * np.pi / 8000
    zb = (np.arange(800) + 0.5) * 20.0 / 800
    band = np.sum(0.5 * knurl_radius_mm(th[:, None], zb[None, :], spec) ** 2) * (2 * np.pi / 8000) * (20.0 / 800)
    grooves = math.pi * 50.0**2 * 20.0 - band
    truth = math.pi * 50.0**2 * 108.0 - grooves
    assert rec["watertight"] and rec["n_bodies"] == 1 and _closed_by_body(tmp_path / "model.ply")
    assert abs(rec["volume_mm3"] / truth - 1) < 2e-3
    assert abs(rec["volume_from_sections_mm3"] / truth - 1) < 2e-3
    assert ev["mean_mm"] <= 2 * ev["rms_mm"]
    assert ev["volume_error_mm3"] == pytest.approx(rec["volume_mm3"] - ev["true_volume_mm3"])
    assert ev["coverage"] > 0.7 and 0 < ev["hausdorff_mm"] < 5.0
    mid = [s for s in rec["sections"] if -40 < s["z_mm"] < 20]
    assert mid and all(abs(s["diameter_mm"] - 100.0) < 0.05 for s in mid)


def _revolved_stl(path, rows):
    from scenes.revolve import revolved_mesh

    theta = 2 * np.pi * np.arange(720) / 720
    z = np.array([r[0] for r in rows], float)
    r = np.array([[r[1]] * len(theta) for r in rows], float)
    revolved_mesh(theta, z, r).export(str(path))
    return path


@pytest.mark.render
@pytest.mark.slow
def test_stepped_part_analytic_volume(tmp_path, capsys):
    """Base Ø80 × 30, shoulder, wall Ø50 to 60, cone to Ø30 at 80, flat top: within 0.5 % of the closed form."""
    part = _revolved_stl(tmp_path / "stepped.stl", [(0, 0), (0, 40), (30, 40), (30, 25), (60, 25), (80, 15), (80, 0)])
    rec, ev = _scan_and_model(tmp_path, part, 2.0, capsys)
    truth = math.pi * (40**2 * 30 + 25**2 * 30 + 20.0 / 3 * (25**2 + 25 * 15 + 15**2))
    assert rec["watertight"] and _closed_by_body(tmp_path / "model.ply")
    assert abs(rec["volume_mm3"] / truth - 1) < 5e-3
    assert abs(ev["volume_error_mm3"]) < 5e-3 * truth


@pytest.mark.render
@pytest.mark.slow
def test_overhang_is_closed_marked_and_its_volume_error_reported(tmp_path, capsys):
    """A mushroom (stem Ø20 × 30, head Ø60 × 15): the head's underside is never lit from above."""
    part = _revolved_stl(tmp_path / "mushroom.stl", [(0, 0), (0, 10), (30, 10), (30, 30), (45, 30), (45, 0)])
    rec, ev = _scan_and_model(tmp_path, part, 4.0, capsys)
    assert rec["watertight"] and _closed_by_body(tmp_path / "model.ply")
    assert rec["faces_by_fill"]["cap"] > 0 and rec["measured_area_share"] < 0.8
    m = read_triangle_mesh(tmp_path / "model.ply")
    filled = m.faces[m.face_properties["fill"] != 0]
    # the underside (z = −40 in the part frame, r from 10 to 30 mm) is closed by filled faces
    near = np.abs(m.vertices[filled][:, :, 2] + 40.0).max(axis=1) < 2.0
    r = np.hypot(*m.vertices[filled[near]][:, :, :2].reshape(-1, 2).T)
    assert near.any() and r.max() > 28.0
    # the wall under the head is hidden over ≈ 1.5 mm: head and stem are closed apart, by caps
    assert rec["n_bodies"] == 2
    truth = math.pi * (10**2 * 30 + 30**2 * 15)
    assert ev["true_volume_mm3"] == pytest.approx(truth, rel=1e-4)
    assert ev["volume_error_mm3"] == pytest.approx(ev["volume_mm3"] - truth, rel=1e-3, abs=1.0)
    assert abs(ev["volume_error_mm3"]) < 0.05 * truth


# ------------------------------------------------------------------ bad input


def _dark_scan(path, n=5):
    import cv2

    (path / "frames").mkdir(parents=True)
    frames = []
    for i in range(n):
        cv2.imwrite(str(path / f"frames/{i:05d}.png"), np.full((40, 60), 100, np.uint16))
        frames.append({"file": f"frames/{i:05d}.png", "angle_deg": 72.0 * i})
    (path / "manifest.json").write_text(json.dumps({"frames": frames}))
    Calibration(hinge_u_px=800.0, hinge_v_px=20.0, F2_px_mm=-1e5, F2_sigma_px_mm=0, d0_mm=-100.0, C_mm=100.0,
                C_sigma_mm=0, endpoint_fit_r2=(1, 1), method="paper", columns=60, rows=40).save(path / "cal.json")
    return path


def test_scan_without_usable_frames_is_one_error_and_writes_nothing(tmp_path, capsys):
    scan = _dark_scan(tmp_path / "dark")
    status = main(["reconstruct", str(scan), "--calibration", str(scan / "cal.json"), "--axis-mm", "30",
                   "--out", str(tmp_path / "c.ply"), "--model", str(tmp_path / "m.stl"), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1 and "no usable frame" in err[0]
    assert not (tmp_path / "c.ply").exists() and not (tmp_path / "m.stl").exists()


def test_non_rotary_cloud_to_model_is_one_error(tmp_path, capsys):
    rng = np.random.default_rng(3)
    n = 500
    write_point_cloud(tmp_path / "c.ply", PointCloud(rng.normal(size=(n, 3)), np.full(n, np.nan), np.full(n, -1),
                                                     np.zeros(n)))
    status = main(["reconstruct", str(tmp_path / "c.ply"), "--model", str(tmp_path / "m.stl")])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1 and "not a rotary scan" in err[0] and "poisson" in err[0]
    assert not (tmp_path / "m.stl").exists()
    assert not list(tmp_path.glob(".m*"))


@pytest.mark.parametrize("name", ["blocked/m.stl", "m.obj"])
def test_unwritable_model_path_fails_before_any_work(tmp_path, capsys, name):
    scan = _dark_scan(tmp_path / "scan")
    (tmp_path / "blocked").write_text("a file where a folder should be")
    status = main(["reconstruct", str(scan), "--calibration", str(scan / "cal.json"), "--axis-mm", "80",
                   "--out", str(tmp_path / "c.ply"), "--model", str(tmp_path / name), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1 and "model file" in err[0]
    assert not (tmp_path / "c.ply").exists()


def test_poisson_without_open3d_is_one_clear_error(tmp_path, capsys, monkeypatch):
    import builtins

    real_import = builtins.__import__

    def no_open3d(name, *a, **k):
        if name == "open3d":
            raise ImportError("No module named 'open3d'")
        return real_import(name, *a, **k)

    monkeypatch.setattr(builtins, "__import__", no_open3d)
    from tests.test_meshing import synthetic_scan

    write_point_cloud(tmp_path / "c.ply", synthetic_scan(lambda p, z: 30.0 + 0 * z, 10.0, n_frames=36))
    status = main(["reconstruct", str(tmp_path / "c.ply"), "--model", str(tmp_path / "m.ply"),
                   "--model-method", "poisson"])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1 and "scheimpflug[poisson]" in err[0]
    assert not (tmp_path / "m.ply").exists()


def test_model_from_a_saved_cloud_with_sections(tmp_path, capsys):
    from tests.test_meshing import synthetic_scan

    write_point_cloud(tmp_path / "c.ply", synthetic_scan(lambda p, z: 30.0 + 0 * z, 20.0, n_frames=180))
    assert main(["reconstruct", str(tmp_path / "c.ply"), "--model", str(tmp_path / "m.stl"), "--table-z-mm", "-70",
                 "--section-z", "-60", "--sections-plot", str(tmp_path / "s.png"), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["watertight"] and out["volume_mm3"] == pytest.approx(math.pi * 900 * 19.95, rel=1e-3)
    assert out["sections"][0]["area_mm2"] == pytest.approx(math.pi * 900, rel=1e-3)
    assert out["volume_from_sections_mm3"] == pytest.approx(out["volume_mm3"], rel=1e-3)
    m = read_triangle_mesh(tmp_path / "m.stl")                # STL: welded back into a closed mesh
    assert is_closed_mesh(m.faces) and (tmp_path / "s.png").stat().st_size > 10_000


def test_meshing_error_leaves_no_file(tmp_path, capsys):
    """Stripes in only two frames: a cloud, but no model (3 angles needed); neither file is written."""
    import cv2

    scan = _dark_scan(tmp_path / "two")
    u_c = 30.0                                                 # a surface ≈ 20 mm before the axis
    for i in (0, 1):
        img = np.full((40, 60), 100.0 + i)                     # two frames, not one listed twice
        img[5:35] += 3000.0 * np.exp(-0.5 * ((np.arange(60) - u_c) / 1.5) ** 2)
        cv2.imwrite(str(scan / f"frames/{i:05d}.png"), img.astype(np.uint16))
    status = main(["reconstruct", str(scan), "--calibration", str(scan / "cal.json"), "--axis-mm", "50",
                   "--out", str(tmp_path / "c.ply"), "--model", str(tmp_path / "m.ply"), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and "at least 3 rotary angles" in err[-1]
    assert not (tmp_path / "c.ply").exists() and not (tmp_path / "m.ply").exists()
