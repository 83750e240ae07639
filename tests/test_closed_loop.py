"""The closed loop at the paper's full resolution: twin frames → pipeline → truth.

Acceptance of the pipeline issue, on the twin's default paper-rig frames:
calibration recovers u_h and v_h within 0.5 px, F² and C within 0.05 %, d0
within 0.05 mm, endpoint R² ≥ 0.9998, and lands within 3 % of the paper's own
numbers; the cylinder's smooth part reconstructs within 0.05 mm RMS of the
mesh and its fitted diameter within 0.05 mm of 100 mm.  The cylinder is scanned
at 10° steps here (36 frames) to keep the suite short; every profile is a
full-resolution frame, so the per-point accuracy is the one of the 0.5° scan.
The truth values come from the rig's closed forms (docs/explanation/design-notes.md §3), not from
the pipeline.
"""

import math

import numpy as np
import pytest

from scheimpflug.app.cli import main
from scheimpflug.model.hinge import hinge_geometry
from scheimpflug.model.rig import load_preset

pytestmark = [pytest.mark.render, pytest.mark.slow]

PAPER = {"hinge_u_px": 3196.0, "F2_px_mm": -1.446e6, "d0_mm": -466.0, "C_mm": 145.91}


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    root = tmp_path_factory.mktemp("loop")
    opts = ["--preset", "paper", "--truth-pixels", "none", "--quiet"]
    assert main(["render", "calibration", "--out", str(root / "cal"), *opts]) == 0
    assert main(["render", "blocker", "--out", str(root / "blk"), *opts]) == 0
    assert main(["render", "rotary", "--part", "cylinder", "--step-deg", "10", "--out", str(root / "cyl"),
                 *opts]) == 0
    return root


@pytest.fixture(scope="module")
def calibration(folders):
    from scheimpflug.calibration import calibrate_folder

    return calibrate_folder(folders / "cal")


def test_calibration_recovers_the_rig_truth(calibration):
    g = hinge_geometry(load_preset("paper"))
    cal = calibration.best
    assert abs(cal.hinge_u_px - 3196.0) < 0.5
    assert abs(cal.hinge_v_px - 771.0) < 0.5
    assert abs(cal.F2_px_mm / g.F2_px_mm - 1) < 5e-4
    assert abs(cal.C_mm / g.C_mm - 1) < 5e-4
    assert abs(cal.d0_mm - (-466.0)) < 0.05
    assert min(calibration.paper.endpoint_fit_r2) >= 0.9998


def test_calibration_is_within_3_percent_of_the_paper(calibration):
    cal = calibration.best
    for key, paper in PAPER.items():
        assert abs(getattr(cal, key) / paper - 1) < 0.03, key


def test_paper_method_also_close(calibration):
    """The paper's own estimate (endpoint extrapolation) is looser but still sub-pixel here."""
    cal = calibration.paper
    assert abs(cal.hinge_u_px - 3196.0) < 2.0
    assert abs(cal.d0_mm + 466.0) < 0.5


def test_cylinder_scan_against_its_mesh(folders, calibration):
    import scenes
    from scheimpflug.axis import locate_axis
    from scheimpflug.fitting import fit_cylinder
    from scheimpflug.io.frames import open_frame_folder
    from scheimpflug.io.ply import read_mesh
    from scheimpflug.reconstruct import extract_folder, reconstruct_profiles
    from scheimpflug.scoring import PointToMesh

    cal = calibration.best
    axis_mm = locate_axis(folders / "blk", cal).axis_mm
    assert abs(axis_mm - 179.45) < 0.05
    ff = open_frame_folder(folders / "cyl")
    rows, us, _, _ = extract_folder(ff, "cog")
    cloud = reconstruct_profiles(rows, us, [r.angle_deg for r in ff.frames], cal, axis_mm)
    part = scenes.load_part("cylinder").parts[0]
    z_lo, z_hi = np.asarray(part.analytic["smooth_z_range_mm"]) + load_preset("paper").stage.rotary_table_z_mm
    xyz = cloud.xyz_mm[(cloud.xyz_mm[:, 2] > z_lo + 1) & (cloud.xyz_mm[:, 2] < z_hi - 1)]
    assert len(xyz) > 36 * 1000
    v, f, _ = read_mesh(folders / "cyl" / "truth" / "mesh.ply")
    d = PointToMesh(v, f).query(xyz).distance_mm
    assert math.sqrt(np.mean(d**2)) <= 0.05
    fit = fit_cylinder(xyz, axis_guess=np.array([0.0, 0.0, 1.0]))
    assert abs(fit.diameter_mm - 100.0) <= 0.05


@pytest.mark.parametrize("part", ["cylinder", "pile"])
def test_rotary_render_writes_the_paper_parts_as_truth_mesh(tmp_path, part):
    """scenes acceptance: truth/mesh.ply holds the paper's dimensions, the pile as three bodies."""
    from scheimpflug.io.ply import read_mesh

    out = tmp_path / part
    assert main(["render", "rotary", "--part", part, "--frames", "1", "--binning", "8", "--truth-pixels", "none",
                 "--out", str(out), "--quiet"]) == 0
    v, f, oid = read_mesh(out / "truth" / "mesh.ply")
    table = load_preset("paper").stage.rotary_table_z_mm

    def body(i):
        return v[np.unique(f[oid == i])]

    if part == "cylinder":
        p = body(1)
        r = np.hypot(p[:, 0], p[:, 1])
        assert r.max() == pytest.approx(50.0, abs=1e-6)          # Ø100 (knurl crests)
        assert p[:, 2].min() == pytest.approx(table, abs=1e-9)   # on the table
        assert np.ptp(p[:, 2]) == pytest.approx(108.0, abs=1e-9)
        return
    assert sorted(np.unique(oid)) == [1, 2, 3]
    ring, box, tape = body(1), body(2), body(3)
    ring_c = 0.5 * (ring[:, :2].max(0) + ring[:, :2].min(0))
    assert 2 * np.hypot(*(ring[:, :2] - ring_c).T).max() == pytest.approx(69.0, abs=1e-6)
    assert ring[:, 2].min() == pytest.approx(table, abs=1e-9)
    # the box: 252 × 165 × 62, lying flat on the ring; its footprint's edge lengths from the hull
    assert np.ptp(box[:, 2]) == pytest.approx(62.0, abs=1e-9)
    assert box[:, 2].min() == pytest.approx(ring[:, 2].max(), abs=1e-9)
    top = box[box[:, 2] > box[:, 2].max() - 1e-6][:, :2]
    d = np.linalg.norm(top[:, None] - top[None], axis=-1)
    assert sorted(np.unique(np.round(d, 6)))[-1] == pytest.approx(math.hypot(252.0, 165.0), abs=1e-6)
    tape_c = 0.5 * (tape[:, :2].max(0) + tape[:, :2].min(0))
    assert 2 * np.hypot(*(tape[:, :2] - tape_c).T).max() == pytest.approx(120.0, abs=1e-3)
    assert tape[:, 2].min() == pytest.approx(box[:, 2].max(), abs=1e-9)
