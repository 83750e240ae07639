"""Hostile inputs of axis, reconstruct, evaluate, design and render (issue 12 items 3, 4, 8, 10,
the option/path/file/write tracebacks, limits and messages), and the CLI's last-resort handler.

Synthetic frames from the closed forms (``synth_frames``, ``test_reconstruct_cli``); nothing here
renders except the one test marked ``render``.
"""

import json
import os
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
import trimesh
from synth_frames import PlateScene, calibration_folder, plate_frame, rig_dict, write_folder
from test_hostile_calibration import GEO, STAGES
from test_reconstruct_cli import AXIS, COLS, ROWS, _cylinder_scan, _write_scan
from test_reconstruct_cli import D0 as D0_MM
from test_reconstruct_cli import F2 as F2_PX_MM
from test_reconstruct_cli import U_H as U_H_PX
from test_reconstruct_cli import V_H as V_H_PX
from test_reconstruct_cli import C as C_MM

from scheimpflug.app import cli
from scheimpflug.app.cli import main
from scheimpflug.axis import locate_axis
from scheimpflug.calibration import Calibration, calibrate_folder
from scheimpflug.errors import CalibrationError
from scheimpflug.io.ply import read_point_cloud, write_point_cloud
from scheimpflug.reconstruct import PointCloud

ROOT = Path(__file__).resolve().parents[1]


def _fails(args, capsys, *needles, status=2):
    """The command fails with one error line (warnings before it are fine) and no traceback."""
    capsys.readouterr()
    assert main(args) == status
    err = capsys.readouterr().err.strip()
    lines = [line for line in err.splitlines() if not line.startswith(("warning", "note"))]
    assert len(lines) == 1 and "Traceback" not in err, err
    for n in needles:
        assert n in err, err
    return err


@pytest.fixture(scope="module")
def plate(tmp_path_factory):
    """A binned calibration folder and its calibration file."""
    root = tmp_path_factory.mktemp("plate")
    path, _ = calibration_folder(root / "cal", GEO, stages=STAGES, seed=3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        calibrate_folder(path).best.save(root / "cal.json")
    return path, root / "cal.json"


def _blocker(path, face_mm=150.0, scenario="blocker", frames=2, entry=None, slope=0.0):
    """Blocker frames: a vertical face at stage ``face_mm`` (the plate's stripe, taller)."""
    rng = np.random.default_rng(7)
    imgs = [plate_frame(GEO, face_mm, PlateScene(bottom_mm=-70.0, height_mm=140.0), _cam(), rng)[0]
            for _ in range(frames)]
    if slope:
        imgs = [_shear(img, slope) for img in imgs]
    return write_folder(path, imgs, [dict(entry or {"angle_deg": 0.0}) for _ in imgs], scenario=scenario,
                        rig=rig_dict(GEO), scenario_params={"blocker_thickness_mm": 2.0})


def _cam():
    from synth_frames import Camera

    return Camera()


def _shear(img, slope):
    """Shift row v by slope·(v − v_mid) columns: a stripe that is not vertical."""
    out = np.empty_like(img)
    for v in range(img.shape[0]):
        out[v] = np.roll(img[v], int(round(slope * (v - img.shape[0] / 2))))
    return out


# ------------------------------------------------------------------ item 4: axis


def test_a_calibration_folder_is_not_a_blocker(plate, capsys):
    """Item 4: was accepted (axis 121 mm instead of 179.45, cloud RMS 29 mm)."""
    folder, cal = plate
    _fails(["axis", str(folder), "--calibration", str(cal)], capsys,
           "holds a 'calibration' scenario", "not blocker frames")
    blk = _blocker(folder.parent / "blk-as-scan")
    _fails(["reconstruct", str(blk), "--calibration", str(cal), "--axis-from", str(folder),
            "--out", str(folder.parent / "x.ply")], capsys, "not blocker frames")


def test_real_frames_without_a_scenario_are_checked_for_plausibility(plate, tmp_path, capsys):
    folder, cal = plate
    calibration = Calibration.load(cal)
    anon = tmp_path / "anon"                   # the calibration frames, but the manifest says nothing
    shutil.copytree(folder, anon)
    m = json.loads((anon / "manifest.json").read_text())
    del m["scenario"]
    (anon / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(CalibrationError, match="translation stage positions"):
        locate_axis(anon, calibration)
    for f in m["frames"]:
        del f["stage_mm"]
    (anon / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(CalibrationError, match="mm apart.*not one blocker at one place"):
        locate_axis(anon, calibration)
    # true blocker frames without a scenario: accepted, with a warning
    blk = _blocker(tmp_path / "blk", scenario=None)
    res = locate_axis(blk, calibration)
    assert abs(res.axis_mm - 151.0) < 0.3 and any("names no scenario" in w for w in res.warnings)
    assert main(["axis", str(blk), "--calibration", str(cal)]) == 0
    assert "names no scenario" in capsys.readouterr().err


def test_a_slanted_stripe_is_not_a_blocker_face(plate, tmp_path):
    _, cal = plate
    res = locate_axis(_blocker(tmp_path / "slant", slope=0.2), Calibration.load(cal))
    assert any("not vertical" in w for w in res.warnings)
    clean = locate_axis(_blocker(tmp_path / "ok"), Calibration.load(cal))
    assert clean.warnings == ()


@pytest.mark.parametrize("value", ["0", "-5", "nan", "inf"])
def test_cylinder_radius_option_is_validated(plate, tmp_path, capsys, value):
    _, cal = plate
    _fails(["axis", str(_blocker(tmp_path / "b")), "--calibration", str(cal), "--cylinder-scan", "x",
            "--cylinder-radius-mm", value], capsys, "argument --cylinder-radius-mm")


# ------------------------------------------------------------------ reconstruct


@pytest.fixture
def scan(tmp_path, rng):
    cal = Calibration(hinge_u_px=U_H_PX, hinge_v_px=V_H_PX, F2_px_mm=F2_PX_MM, F2_sigma_px_mm=0.0,
                      d0_mm=D0_MM, C_mm=C_MM, C_sigma_mm=0.0, endpoint_fit_r2=(1.0, 1.0), method="paper",
                      columns=COLS, rows=ROWS)
    cal.save(tmp_path / "cal.json")
    folder, _ = _cylinder_scan(tmp_path, rng, n_frames=6)
    return folder, tmp_path / "cal.json"


@pytest.mark.parametrize("value, needle", [
    ("1e308", "argument --axis-mm: 1e308: must be a finite number in [-1e+06, 1e+06]"),  # was a cloud of inf
    ("nan", "argument --axis-mm: nan"),                                               # was "no stripe found"
    ("inf", "argument --axis-mm"),
])
def test_axis_mm_option_is_validated(scan, tmp_path, capsys, value, needle):
    """Item 8: numbers on the command line are finite and plausible, with the option named."""
    folder, cal = scan
    out = tmp_path / "c.ply"
    _fails(["reconstruct", str(folder), "--calibration", str(cal), "--axis-mm", value, "--out", str(out)],
           capsys, needle)
    assert not out.exists()


def test_axis_outside_the_depth_range_is_refused(scan, tmp_path, capsys):
    """Issue 25: an axis outside the calibrated depth range was a warning and a cloud far away."""
    folder, cal = scan
    _fails(["reconstruct", str(folder), "--calibration", str(cal), "--axis-mm", "5000", "--quiet",
            "--out", str(tmp_path / "c.ply")], capsys, "outside the depth range")
    assert not (tmp_path / "c.ply").exists()


@pytest.mark.parametrize("value", ["0", "-5", "nan"])
def test_min_snr_option_is_validated(scan, tmp_path, capsys, value):
    folder, cal = scan
    _fails(["reconstruct", str(folder), "--calibration", str(cal), "--axis-mm", str(AXIS),
            "--min-snr", value, "--out", str(tmp_path / "c.ply")], capsys, "argument --min-snr")


def test_reconstruct_outputs_that_are_inputs_are_refused(scan, tmp_path, capsys):
    """Item 3: `reconstruct --out DIR/frames/00000.png` overwrote its own input."""
    folder, cal = scan
    frame = folder / "frames" / "00000.png"
    before = frame.read_bytes()
    base = ["reconstruct", str(folder), "--calibration", str(cal), "--axis-mm", str(AXIS), "--quiet"]
    _fails(base + ["--out", str(frame)], capsys, "input frame folder", "(frames)")
    _fails(base + ["--out", str(cal)], capsys, "is an input of this command")
    _fails(base + ["--out", str(folder)], capsys, "is a folder")
    assert frame.read_bytes() == before  # exact: copy
    out = tmp_path / "c.ply"
    assert main(base + ["--out", str(out)]) == 0
    _fails(base + ["--out", str(out)], capsys, "already exists: pass --force")
    assert main(base + ["--out", str(out), "--force"]) == 0


def test_all_saturated_scan_says_saturated(tmp_path, capsys, scan):
    _, cal = scan
    frames = [np.full((ROWS, COLS), 65535, np.uint16) for _ in range(3)]
    sat = _write_scan(tmp_path / "sat", frames, [0.0, 10.0, 20.0])
    _fails(["reconstruct", str(sat), "--calibration", str(cal), "--axis-mm", str(AXIS), "--quiet",
            "--out", str(tmp_path / "c.ply")], capsys, "3 of them saturated", "lower the exposure")


def test_non_ascii_folder_and_file_names_work_end_to_end(tmp_path, rng, scan, capsys):
    """Was UnicodeEncodeError in the PLY writer, after all the work."""
    folder, cal = scan
    odd = tmp_path / "scän dir – pièce 1"
    shutil.copytree(folder, odd)
    out = odd / "nuage ü.ply"
    assert main(["reconstruct", str(odd), "--calibration", str(cal), "--axis-mm", str(AXIS), "--quiet",
                 "--out", str(out)]) == 0
    head = out.read_bytes()[:400]
    assert b"sc\\xe4n dir" in head                      # the header stays ASCII
    cloud = read_point_cloud(out)
    assert len(cloud) > 0
    mesh = trimesh.creation.cylinder(radius=20.0, height=20.0, sections=90)
    mesh.export(odd / "vérité.stl")
    assert main(["evaluate", str(out), "--mesh", str(odd / "vérité.stl"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["n_points"] == len(cloud)


# ------------------------------------------------------------------ evaluate and files


@pytest.fixture
def cloud_and_mesh(tmp_path, rng):
    mesh = trimesh.creation.box(extents=(40.0, 40.0, 40.0))
    mesh.export(tmp_path / "box.ply")
    xyz = rng.uniform(-20, 20, (500, 3))
    xyz[:, 0] = 20.0
    return tmp_path / "box.ply", xyz


def test_evaluate_counts_the_points_it_drops(tmp_path, capsys, cloud_and_mesh):
    """Item 10: 500 → 450 points without a word."""
    mesh, xyz = cloud_and_mesh
    xyz[:40] = np.nan
    xyz[40:50, 2] = np.inf
    n = len(xyz)
    write_point_cloud(tmp_path / "c.ply", PointCloud(xyz, np.zeros(n), np.zeros(n, np.int64), np.zeros(n)))
    assert main(["evaluate", str(tmp_path / "c.ply"), "--mesh", str(mesh), "--json"]) == 0
    cap = capsys.readouterr()
    d = json.loads(cap.out)
    assert d["n_points"] == 450 and d["n_dropped"] == 50 and d["n_points_read"] == 500
    assert "50 of 500 points" in cap.err and d["max_mm"] < 1e-4
    # finite, but beyond ±1e12 mm (their squares overflow near 1e154): dropped and counted too
    lines = [f"{x!r} {y!r} {z!r}" for x, y, z in np.nan_to_num(xyz[50:], nan=0.0)[:100].tolist()]
    lines += ["1e154 0 0", "0 -1e13 0", "0 0 20"]
    (tmp_path / "far.ply").write_text("ply\nformat ascii 1.0\nelement vertex 103\nproperty double x\n"
                                      "property double y\nproperty double z\nend_header\n"
                                      + "\n".join(lines) + "\n")
    assert main(["evaluate", str(tmp_path / "far.ply"), "--mesh", str(mesh), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["n_dropped"] == 2 and d["n_points"] == 101 and d["max_mm"] < 1e-4


@pytest.mark.parametrize("body, needle", [
    ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
     "end_header\n", "announces 3 vertex but only 0 bytes"),                    # empty ASCII PLY
    ("ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\nproperty float x\n"
     "property float y\nproperty float z\nend_header\n", "announces 4000000000 vertex"),  # MemoryError
    ("ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\nproperty float z\n"
     "end_header\n", "is empty"),
    ("", "not a PLY file"),
])
def test_bad_clouds_are_one_line(tmp_path, capsys, cloud_and_mesh, body, needle):
    mesh, _ = cloud_and_mesh
    (tmp_path / "bad.ply").write_text(body)
    _fails(["evaluate", str(tmp_path / "bad.ply"), "--mesh", str(mesh)], capsys, needle)


def test_bad_meshes_are_one_line(tmp_path, capsys, cloud_and_mesh):
    _, xyz = cloud_and_mesh
    n = len(xyz)
    write_point_cloud(tmp_path / "c.ply", PointCloud(xyz, np.zeros(n), np.zeros(n, np.int64), np.zeros(n)))
    cloud = str(tmp_path / "c.ply")
    _fails(["evaluate", cloud, "--mesh", str(tmp_path)], capsys, "is a folder, not a file")
    (tmp_path / "idx.ply").write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n"
                                      "property float y\nproperty float z\nelement face 1\n"
                                      "property list uchar int vertex_indices\nend_header\n"
                                      "0 0 0\n1 0 0\n0 1 0\n3 0 1 99\n")
    _fails(["evaluate", cloud, "--mesh", str(tmp_path / "idx.ply")], capsys, "idx.ply")
    _fails(["evaluate", cloud, "--mesh", str(tmp_path / "none.stl")], capsys, "does not exist")


# ------------------------------------------------------------------ design, writes


def test_tan_phi_nan_names_the_option(capsys):
    _fails(["design", "--near-mm", "500", "--far-mm", "850", "--tan-phi", "nan"], capsys,
           "argument --tan-phi: nan")


def test_unwritable_destinations_are_one_line(tmp_path, capsys, monkeypatch, plate):
    """A read-only destination for --out, --write-rig, --plot (simulated: this may run as root)."""
    import tempfile

    def denied(*args, dir=None, **kwargs):
        raise PermissionError(13, "Permission denied", str(dir))

    folder, _ = plate
    monkeypatch.setattr(tempfile, "mkstemp", denied)
    _fails(["calibrate", str(folder), "--quiet", "--out", str(tmp_path / "c.json")], capsys,
           "Permission denied", str(tmp_path))
    _fails(["design", "--near-mm", "500", "--far-mm", "850", "--write-rig", str(tmp_path / "r.toml")],
           capsys, "Permission denied")
    _fails(["design", "--plot", str(tmp_path / "d.png")], capsys, "Permission denied")


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_read_only_folder_is_refused_before_work(tmp_path, capsys, plate):
    folder, _ = plate
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    _fails(["calibrate", str(folder), "--quiet", "--out", str(ro / "c.json")], capsys, "permission denied")


# ------------------------------------------------------------------ render limits


@pytest.mark.parametrize("args, needle", [
    (["calibration", "--steps", "1000000000"], "1,000,000,000 frames"),          # hung silently
    (["rotary", "--step-deg", "1e-6"], "360,000,000 frames"),                    # MemoryError
    (["rotary", "--step-deg", "0.01", "--binning", "8"], "pass --yes"),
    (["blocker", "--binning", "8", "--seed", "-1"], "argument --seed"),
    (["rotary", "--step-deg", "nan"], "argument --step-deg"),
    (["calibration", "--plate-height-mm", "inf"], "argument --plate-height-mm"),
])
def test_render_sizes_the_job_before_starting(tmp_path, capsys, args, needle):
    out = tmp_path / "o"
    _fails(["render", *args, "--out", str(out)], capsys, needle)
    assert not out.exists()


def test_render_refuses_a_job_that_cannot_fit_in_memory(tmp_path, capsys):
    """columns = 10^7 failed in OpenCV after creating the folder; the largest valid sensor is sized."""
    rig = tmp_path / "wide.toml"
    rig.write_text("[sensor]\ncolumns = 65535\nrows = 65535\nhinge_column = 70000\n")
    out = tmp_path / "o"
    _fails(["render", "blocker", "--rig", str(rig), "--out", str(out)], capsys, "GB of memory", "--binning")
    assert not out.exists()


@pytest.mark.render
def test_render_a_part_file_with_a_non_ascii_name(tmp_path, capsys):
    """`render --part "pièce 1.stl"` crashed and left a folder that crashed again on rerun."""
    part = tmp_path / "pièce 1.stl"
    trimesh.creation.box(extents=(60.0, 60.0, 60.0)).apply_translation((0, 0, 30.0)).export(part)
    out = tmp_path / "scan é"
    args = ["render", "rotary", "--part", str(part), "--binning", "8", "--step-deg", "90", "--frames", "1",
            "--truth-pixels", "none", "--quiet", "--out", str(out)]
    assert main(args) == 0
    head = (out / "truth" / "mesh.ply").read_bytes()
    assert "scene pi\\xe8ce 1;" in head[:head.index(b"end_header")].decode("ascii")
    assert main(args) == 0                                           # rerun: complete, nothing to do
    assert json.loads((out / "manifest.json").read_text())["complete"] is True


# ------------------------------------------------------------------ the last resort


def test_an_unexpected_exception_is_one_line_asking_for_a_report(monkeypatch, capsys):
    from scheimpflug.app.commands import design

    def boom(args):
        raise KeyError("oops")

    monkeypatch.setattr(design, "run", boom)
    monkeypatch.delenv("SCHEIMPFLUG_DEBUG", raising=False)
    err = _fails(["design"], capsys, "internal error: KeyError", "please report", status=cli.EXIT_BUG)
    assert "--debug" in err
    with pytest.raises(KeyError):
        main(["--debug", "design"])
    monkeypatch.setenv("SCHEIMPFLUG_DEBUG", "1")
    with pytest.raises(KeyError):
        main(["design"])


def test_degenerate_triangles_score_a_distance_not_nan(tmp_path, capsys):
    """Found by the fuzz suite: a zero-length edge made the closest point 0/0 (rms null)."""
    from scheimpflug.scoring import PointToMesh

    tri = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]])      # a ≡ b: a segment
    for faces in ([[0, 1, 2]], [[0, 2, 1]], [[2, 0, 1]]):
        d = PointToMesh(tri, np.array(faces)).query(np.array([[3.0, 4.0, 0.5], [0.0, 0.0, -2.0]]))
        np.testing.assert_allclose(np.abs(d.distance_mm), [5.0, 2.0], atol=1e-12)
    fuzz = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])     # the example found
    trimesh.Trimesh(fuzz, np.array([[0, 0, 1]]), process=False).export(tmp_path / "m.ply")
    write_point_cloud(tmp_path / "c.ply", PointCloud(np.zeros((1, 3)), np.zeros(1), np.zeros(1, np.int64),
                                                     np.zeros(1)))
    assert main(["evaluate", str(tmp_path / "c.ply"), "--mesh", str(tmp_path / "m.ply"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["rms_mm"] == 0.0
