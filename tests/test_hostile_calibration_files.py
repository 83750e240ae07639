"""Calibration files probed as a hostile user would (issue 34 items 1, 6, 13, 14).

Every calibration file carries the frame size it was made for and every reader
checks it: the paper form, the general model, the target calibration, the
OpenCV export (JSON and YAML, whatever model made it) and FabScan's
``config.json`` (its ``camera.resolution``).  Before, the export of a target
calibration was read as a target file without ``columns``/``rows`` — 0 × 0, the
check skipped — and a 4 × 4-binned calibration reconstructed a 2 × 2-binned scan
with exit status 0 (heights −287 … 43 mm instead of −70 … 38).  A file of an
earlier version without a size still loads and warns when applied.  FabScan
configs are validated field by field, each defect named (not "needs --axis-mm").
No renderer: synthetic calibrations and tiny frame folders.
"""

import json
import math
import re
import warnings

import numpy as np
import pytest
from synth_frames import write_folder

from scheimpflug.app.cli import main
from scheimpflug.calibration import applicability_problem, load_sheet_model
from scheimpflug.calibration.camera import OpenCVCamera
from scheimpflug.calibration.fabscan import read_fabscan
from scheimpflug.calibration.model import check_laser_plane
from scheimpflug.calibration.opencv import as_general, write_opencv
from scheimpflug.calibration.paper import Calibration
from scheimpflug.errors import CalibrationError
from scheimpflug.io.frames import FrameFolder

W, H = 64, 48          # the calibrations' frames: 64 columns, 48 rows


def _fabscan_config(tmp_path, name="config.json", edit=None):
    """A FabScan config of 64 × 48 stored frames (camera turned: rotate, hflip), a turntable seen from the side."""
    n = np.array([0.8, -0.03, 0.6])
    r = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]])
    cfg = {"camera": {"resolution": {"width": W, "height": H}, "rotate": "True", "hflip": "True", "vflip": "False"},
           "turntable": {"steps": 3200},
           "calibration": {"camera_matrix": [[90.0, 0, 25.0], [0, 92.0, 33.0], [0, 0, 1]],
                           "distortion_vector": [0.1, -0.05, 0.002, -0.001, 0.0],
                           "laser_planes": [{"normal": (n / np.linalg.norm(n)).tolist(), "distance": 80.0,
                                             "deviation": 0.05}],
                           "platform_rotation": r.tolist(), "platform_translation": [-3.0, 20.0, 120.0]}}
    if edit is not None:
        edit(cfg)
    p = tmp_path / name
    p.write_text(json.dumps(cfg))
    return p


def _paper(columns=W, rows=H) -> Calibration:
    return Calibration(hinge_u_px=800.0, hinge_v_px=20.0, F2_px_mm=-1e6, F2_sigma_px_mm=0.0, d0_mm=-100.0,
                       C_mm=100.0, C_sigma_mm=0.0, endpoint_fit_r2=(1.0, 1.0), method="paper", columns=columns,
                       rows=rows)


def _files(tmp_path) -> dict:
    """One file of every calibration kind, all made for 64 × 48 frames."""
    target = read_fabscan(_fabscan_config(tmp_path))
    files = {"fabscan": tmp_path / "config.json", "paper": tmp_path / "paper.json",
             "general": tmp_path / "general.json", "target": tmp_path / "target.json",
             "opencv-of-target": tmp_path / "cv-target.json", "opencv-of-paper": tmp_path / "cv-paper.json",
             "opencv-yaml": tmp_path / "cv-target.yml"}
    _paper().save(files["paper"])
    as_general(_paper()).save(files["general"])
    files["target"].write_text(json.dumps(target.to_json_dict()))
    write_opencv(files["opencv-of-target"], target)
    write_opencv(files["opencv-of-paper"], _paper())
    write_opencv(files["opencv-yaml"], target)
    return files


def _frames(rows, columns) -> FrameFolder:
    return FrameFolder(path=None, rig=None, scenario="rotary", scenario_params={}, frames=(), rows=rows,
                       columns=columns)


KINDS = ["fabscan", "paper", "general", "target", "opencv-of-target", "opencv-of-paper", "opencv-yaml"]


# ------------------------------------------------------------------ item 1: the frame size in every file


@pytest.mark.parametrize("kind", KINDS)
def test_every_calibration_file_carries_its_frame_size_and_refuses_other_frames(tmp_path, kind):
    """Before: the OpenCV export of a target calibration read back as 0 × 0 and fitted any frames."""
    model = load_sheet_model(_files(tmp_path)[kind])
    assert (model.columns, model.rows) == (W, H)
    with warnings.catch_warnings():
        warnings.simplefilter("error")                     # a size known: no warning
        assert applicability_problem(model, _frames(H, W)) is None
    problem = applicability_problem(model, _frames(H // 2, W // 2))    # a 2 × 2-binned scan
    assert problem and "made for 48 × 64 frames" in problem and "0.5 × this binning" in problem
    assert model.problem(W // 2, H // 2) == problem


def test_the_opencv_export_of_another_binning_is_refused_by_reconstruct(tmp_path, capsys):
    """The issue's case end to end: cv.json of a calibration of 64 × 48 frames, a scan of 32 × 24."""
    cv = _files(tmp_path)["opencv-of-target"]
    assert json.loads(cv.read_text())["model"] == "target"      # what sent it down the target reader
    frames = [np.full((H // 2, W // 2), 10, np.uint8) for _ in range(3)]
    scan = write_folder(tmp_path / "scan", frames, [{"angle_deg": 10.0 * i} for i in range(3)], scenario="rotary")
    capsys.readouterr()
    status = main(["reconstruct", str(scan), "--calibration", str(cv), "--axis-mm", "150", "--quiet",
                   "--out", str(tmp_path / "c.ply")])
    err = capsys.readouterr().err
    assert status == 2 and "made for 48 × 64 frames, the frames are 24 × 32" in err, err
    assert not (tmp_path / "c.ply").exists()


@pytest.mark.parametrize("kind, keys", [("paper", ("columns", "rows")), ("general", ("columns", "rows")),
                                        ("target", ("columns", "rows", "image_size")),
                                        ("opencv-of-paper", ("image_size",))])
def test_an_old_file_without_a_size_loads_and_warns_when_applied(tmp_path, kind, keys):
    path = _files(tmp_path)[kind]
    d = json.loads(path.read_text())
    for k in keys:
        d.pop(k, None)
    path.write_text(json.dumps(d))
    model = load_sheet_model(path)
    assert (model.columns, model.rows) == (0, 0)
    with pytest.warns(UserWarning, match=r"records no frame size.*these 24 × 32 frames .*cannot be checked"):
        assert applicability_problem(model, _frames(24, 32)) is None


def test_a_target_file_with_only_image_size_has_that_size(tmp_path):
    path = _files(tmp_path)["target"]
    d = json.loads(path.read_text())
    d.pop("columns"), d.pop("rows")
    path.write_text(json.dumps(d))
    assert (load_sheet_model(path).columns, load_sheet_model(path).rows) == (W, H)


@pytest.mark.parametrize("edit, needle", [
    ({"columns": 64}, "gives columns but not rows"),
    ({"columns": 64, "rows": 48, "image_size": [64, 40]}, r"image_size \[64, 40\] and columns × rows 64 × 48 disagree"),
    ({"image_size": [0, 48]}, "two sides > 0"),
    ({"image_size": [64]}, r"image_size must be \[columns, rows\]"),
    ({"columns": 64.5, "rows": 48}, "columns = 64.5 must be a whole number"),
    ({"columns": True, "rows": 48}, "columns = True must be a whole number"),
    ({"columns": 0, "rows": 48}, "both sides > 0"),
])
def test_a_malformed_frame_size_is_refused_by_name(edit, needle):
    from scheimpflug.calibration.model import frame_size_from_json

    with pytest.raises(CalibrationError, match=needle):
        frame_size_from_json(edit)


@pytest.mark.parametrize("kind", ["paper", "general", "target"])
def test_a_malformed_size_in_a_file_is_refused_naming_the_file(tmp_path, kind):
    path = _files(tmp_path)[kind]
    d = json.loads(path.read_text())
    d.pop("rows")
    path.write_text(json.dumps(d))
    with pytest.raises(CalibrationError, match=rf"{path.name}.*gives columns but not rows"):
        load_sheet_model(path)


def test_an_export_of_a_calibration_without_a_size_is_refused(tmp_path):
    with pytest.raises(CalibrationError, match="records no frame size.*image_size"):
        write_opencv(tmp_path / "cv.json", _paper(0, 0))
    assert not (tmp_path / "cv.json").exists()


# ------------------------------------------------------------------ item 6: a plane behind the camera


def test_a_negative_fabscan_laser_distance_is_refused(tmp_path):
    """Before: accepted, the axis then 155.76 mm from the sheet (the plane mirrored through the camera)."""
    path = _fabscan_config(tmp_path, edit=lambda c: c["calibration"]["laser_planes"][0].update(distance=-80.0))
    with pytest.raises(CalibrationError, match=r"laser_planes\[0\].*distance -80 mm.*behind the camera.*sign"):
        load_sheet_model(path)


def test_a_foreign_opencv_plane_behind_the_camera_is_refused(tmp_path):
    cv = {"camera_matrix": [[900.0, 0, 320], [0, 900.0, 240], [0, 0, 1]], "dist_coeffs": [0.0] * 5,
          "image_size": [640, 480], "laser_plane": [0.0, -0.6, -0.8, -100.0]}    # meets the optical axis at Z = −125
    (tmp_path / "cv.json").write_text(json.dumps(cv))
    with pytest.raises(CalibrationError, match=r"behind the camera \(at Z = -125 mm\)"):
        load_sheet_model(tmp_path / "cv.json")


# ------------------------------------------------------------------ item 13: every FabScan defect by name


def _plane(c):
    return c["calibration"]["laser_planes"][0]


FABSCAN_DEFECTS = [
    (lambda c: _plane(c).update(normal=[0.8, 0.6]), r"laser_planes\[0\]\.normal must be 3 numbers, got 2"),
    (lambda c: _plane(c).update(normal=[0.0, 0.0, 0.0]), r"laser_planes\[0\]\.normal = \[0, 0, 0\] has length 0"),
    (lambda c: _plane(c).update(normal=[1.6, 0.0, 1.2]), r"normal = \[1.6, 0, 1.2\] has length 2, not 1"),
    (lambda c: _plane(c).update(normal=[math.nan, 0.6, 0.8]), r"normal = \[nan, 0.6, 0.8\] holds a value that is not"),
    (lambda c: _plane(c).pop("distance"), r"laser_planes\[0\]\.distance is missing"),
    (lambda c: c["calibration"].update(camera_matrix=[[0, 0, 1], [0, 90, 2], [0, 0, 1]]), "singular"),
    (lambda c: c["calibration"].pop("camera_matrix"), r"calibration\.camera_matrix is missing"),
    (lambda c: c["calibration"].update(camera_matrix=[[90.0, 0, 25.0], [0, 92.0, 33.0]]),
     r"camera_matrix must be a 3 × 3 matrix, got 6"),
    (lambda c: c["calibration"].update(laser_planes=[]), "laser 0 has no plane"),
    (lambda c: c["calibration"].update(laser_planes=None), "laser_planes must be a list"),
    (lambda c: c["calibration"].update(platform_rotation=[[1, 0, 0], [0, 1, 0], [0, 0, 2]]),
     "not a rotation: RᵀR differs"),
    (lambda c: c["calibration"].update(platform_rotation=[[0, 1, 0], [0, 0, -1], [1, 0, 0]]),
     "not a rotation: its determinant is −1"),
    (lambda c: c["calibration"].pop("platform_translation"), r"platform_translation is missing"),
    (lambda c: c["calibration"].update(platform_translation=[0.0, 20.0, -120.0]), "turntable at Z = -120 mm"),
    (lambda c: c["calibration"].update(distortion_vector=[0.1, math.nan, 0, 0, 0]),
     r"distortion_vector = \[0.1, nan, 0, 0, 0\] holds a value"),
    (lambda c: c["camera"].update(resolution={"width": 64}), "camera.resolution needs"),
]


@pytest.mark.parametrize("edit, needle", FABSCAN_DEFECTS)
def test_every_fabscan_defect_is_named(tmp_path, edit, needle):
    path = _fabscan_config(tmp_path, edit=edit)
    with pytest.raises(CalibrationError, match=needle) as info:
        load_sheet_model(path)
    assert "config.json" in str(info.value) and "np.float64" not in str(info.value)


@pytest.mark.parametrize("edit, needle", FABSCAN_DEFECTS[:3])
def test_reconstruct_with_an_axis_names_the_fabscan_defect(tmp_path, capsys, edit, needle):
    path = _fabscan_config(tmp_path, edit=edit)
    scan = write_folder(tmp_path / "scan", [np.zeros((H, W), np.uint8)] * 3,
                        [{"angle_deg": 10.0 * i} for i in range(3)], scenario="rotary")
    capsys.readouterr()
    assert main(["reconstruct", str(scan), "--calibration", str(path), "--axis-mm", "150", "--quiet",
                 "--out", str(tmp_path / "c.ply")]) == 2
    err = capsys.readouterr().err
    assert "needs --axis-mm" not in err and len(err.strip().splitlines()) == 1
    assert re.search(needle, err), err


def test_reconstruct_without_an_axis_names_the_fabscan_defect_not_the_axis(tmp_path, capsys):
    path = _fabscan_config(tmp_path, edit=FABSCAN_DEFECTS[0][0])
    scan = write_folder(tmp_path / "scan", [np.zeros((H, W), np.uint8)] * 3,
                        [{"angle_deg": 10.0 * i} for i in range(3)], scenario="rotary")
    capsys.readouterr()
    assert main(["reconstruct", str(scan), "--calibration", str(path), "--quiet", "--out",
                 str(tmp_path / "c.ply")]) == 2
    err = capsys.readouterr().err
    assert "normal must be 3 numbers" in err and "needs --axis-mm" not in err, err


def test_fabscans_own_config_reads_without_a_word():
    from pathlib import Path

    real = Path(__file__).resolve().parents[2] / "shared" / "realdata" / "fabscan" / "dummy.config.json"
    if not real.is_file():
        pytest.skip(f"real FabScan config absent ({real}): see its README")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        model = read_fabscan(real)
    assert (model.columns, model.rows) == (1640, 1232) and abs(model.axis["distance_to_sheet_mm"]) < 2.0


def test_a_principal_point_outside_fabscans_frame_warns(tmp_path):
    """A camera matrix of another resolution (here the full sensor's, twice camera.resolution)."""
    path = _fabscan_config(tmp_path, edit=lambda c: c["calibration"].update(
        camera_matrix=[[180.0, 0, 70.0], [0, 184.0, 100.0], [0, 0, 1]]))
    with pytest.warns(UserWarning, match=r"principal point \(70, 100\) px lies outside its turned 48 × 64 frame"):
        read_fabscan(path)


# ------------------------------------------------------------------ item 14: wording


@pytest.mark.parametrize("k, dist, needle, not_needle", [
    ([[math.nan, 0, 1], [0, 90, 2], [0, 0, 1]], [0.0] * 14, r"camera_matrix\[0\]\[0\] = nan is not a finite number",
     "got shape"),
    ([[90, 0, 1], [0, 90, 2], [0, 0, 1]], [0.0] * 3 + [math.nan] + [0.0] * 10,
     r"dist_coeffs\[3\] = nan is not a finite number", "got 14"),
    ([[90, 0, 1], [0, 90, 2], [0, 0, 1]], [0.0] * 6, "dist_coeffs must be 4, 5, 8, 12 or 14 numbers.*got 6", "finite"),
])
def test_camera_messages_say_what_is_wrong(k, dist, needle, not_needle):
    with pytest.raises(CalibrationError, match=needle) as info:
        OpenCVCamera(np.array(k, float), np.array(dist, float))
    assert not_needle not in str(info.value)


@pytest.mark.parametrize("drop, needle", [(("laser_plane",), "the key laser_plane is missing"),
                                          (("camera_matrix", "dist_coeffs"),
                                           "the keys camera_matrix, dist_coeffs are missing")])
def test_a_missing_opencv_key_is_named_in_words(tmp_path, drop, needle):
    """Before: a missing laser_plane was reported as just 'laser_plane' (a KeyError's text)."""
    path = _files(tmp_path)["opencv-of-paper"]
    d = json.loads(path.read_text())
    for k in drop:
        d.pop(k)
    path.write_text(json.dumps(d))
    with pytest.raises(CalibrationError, match=needle):
        load_sheet_model(path)


def test_numbers_in_messages_are_numbers_not_numpy_reprs():
    with pytest.raises(CalibrationError) as info:
        check_laser_plane([np.float64(math.nan), np.float64(0.6), np.float64(0.8), np.float64(-10.0)])
    assert "np.float64" not in str(info.value) and "[nan, 0.6, 0.8, -10]" in str(info.value)


def test_a_library_warning_is_one_line_on_the_command_line(tmp_path, capsys):
    """A warning the command does not print itself (here: an old file's unknown frame size) is one line
    naming the command, without Python's file, line number and source line (scheimpflug.app.cli)."""
    path = _files(tmp_path)["paper"]
    d = json.loads(path.read_text())
    del d["columns"], d["rows"]
    path.write_text(json.dumps(d))
    scan = write_folder(tmp_path / "scan", [np.zeros((H, W), np.uint8)] * 3,
                        [{"angle_deg": 10.0 * i} for i in range(3)], scenario="rotary")
    capsys.readouterr()
    main(["reconstruct", str(scan), "--calibration", str(path), "--axis-mm", "150", "--quiet",
          "--out", str(tmp_path / "c.ply")])
    lines = capsys.readouterr().err.strip().splitlines()
    warned = [x for x in lines if "records no frame size" in x]
    assert len(warned) == 1 and warned[0].startswith("scheimpflug reconstruct: warning: "), lines
    assert not any("UserWarning" in x or ".py:" in x for x in lines), lines
