"""Rotary-axis location: blocker frames and the cylinder cross-check, known truth."""

import json
import math

import numpy as np
import pytest
from synth_frames import (
    Camera,
    Geometry,
    PlateScene,
    plate_frame,
    rig_dict,
    write_folder,
)

from scheimpflug.app.cli import main
from scheimpflug.axis import axis_from_cylinder_scan, locate_axis, locate_axis_from_cylinder
from scheimpflug.calibration import Calibration
from scheimpflug.errors import CalibrationError

GEO = Geometry()
AXIS_MM = 179.45
SCENE = PlateScene(bottom_mm=-60.0, height_mm=100.0)


def _cal():
    return Calibration(hinge_u_px=GEO.hinge_u_px, hinge_v_px=GEO.hinge_v_px, F2_px_mm=GEO.F2_px_mm,
                       F2_sigma_px_mm=0.0, d0_mm=GEO.d0_mm, C_mm=GEO.C_mm, C_sigma_mm=0.0,
                       endpoint_fit_r2=(1.0, 1.0), method="refined", columns=GEO.columns,
                       rows=GEO.rows)


def _blocker_folder(path, thickness, angles=(0.0,), write_t=True):
    rng = np.random.default_rng(4)
    frames = []
    for a in angles:
        face = AXIS_MM - 0.5 * thickness / abs(math.cos(math.radians(a)))
        frames.append(plate_frame(GEO, face, SCENE, Camera(), rng)[0])
    params = {"blocker_thickness_mm": thickness} if write_t else {}
    return write_folder(path, frames, [{"angle_deg": a} for a in angles], scenario="blocker",
                        rig=rig_dict(GEO), scenario_params=params)


def test_blocker_axis_with_thickness_from_manifest(tmp_path):
    p = _blocker_folder(tmp_path / "b", 3.0, angles=(0.0, 180.0, 30.0))
    res = locate_axis(p, _cal())
    assert res.thickness_source == "manifest" and res.blocker_thickness_mm == 3.0
    assert abs(res.axis_mm - AXIS_MM) < 0.01
    assert all(abs(a - AXIS_MM) < 0.02 for a in res.per_frame_axis_mm)
    # the paper's column for 179.45 mm (Eq. 11 inverted), for the face
    u_face = GEO.hinge_u_px + GEO.F2_px_mm / (AXIS_MM - 1.5 - GEO.d0_mm)
    assert abs(res.column_px - u_face) < 0.02


def test_blocker_thickness_option_and_default(tmp_path):
    p = _blocker_folder(tmp_path / "b", 2.0, write_t=False)
    res = locate_axis(p, _cal())
    assert res.thickness_source == "default" and abs(res.axis_mm - AXIS_MM) < 0.01
    res4 = locate_axis(p, _cal(), blocker_thickness_mm=4.0)
    assert res4.thickness_source == "option" and abs(res4.axis_mm - (AXIS_MM + 1.0)) < 0.01


def test_axis_cli(tmp_path, capsys):
    p = _blocker_folder(tmp_path / "b", 2.0)
    _cal().save(tmp_path / "cal.json")
    assert main(["axis", str(p), "--calibration", str(tmp_path / "cal.json"), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert abs(d["axis_mm"] - AXIS_MM) < 0.01


def test_axis_cli_bad_inputs(tmp_path, capsys):
    _cal().save(tmp_path / "cal.json")
    (tmp_path / "empty").mkdir()
    assert main(["axis", str(tmp_path / "empty"), "--calibration", str(tmp_path / "cal.json")]) == 2
    assert "no manifest.json" in capsys.readouterr().err
    p = _blocker_folder(tmp_path / "b", 2.0)
    assert main(["axis", str(p), "--calibration", str(tmp_path / "nope.json")]) == 2
    assert "does not exist" in capsys.readouterr().err
    blank = write_folder(tmp_path / "blank", [np.full((GEO.rows, GEO.columns), 16, np.uint16)],
                         [{"angle_deg": 0.0}], scenario="blocker", rig=rig_dict(GEO))
    assert main(["axis", str(blank), "--calibration", str(tmp_path / "cal.json")]) == 2
    assert "no usable blocker frame" in capsys.readouterr().err


@pytest.mark.parametrize("ecc,phase", [(0.0, 0.0), (2.5, 40.0), (6.0, -120.0)])
def test_cylinder_fit_recovers_axis(ecc, phase, rng):
    R = 50.0
    th = np.arange(0.0, 360.0, 10.0)
    ph = np.radians(th + phase)
    near = AXIS_MM + ecc * np.cos(ph) - np.sqrt(R ** 2 - (ecc * np.sin(ph)) ** 2)
    fit = axis_from_cylinder_scan(th, near + rng.normal(0, 0.01, th.size), R)
    assert abs(fit.axis_mm - AXIS_MM) < 0.01
    assert abs(fit.eccentricity_mm - ecc) < 0.02


def test_cylinder_scan_frames(tmp_path):
    """Frames of an eccentric cylinder (its near side is a vertical stripe) → axis."""
    R, ecc, phase = 50.0, 3.0, 25.0
    th = np.arange(0.0, 360.0, 45.0)
    ph = np.radians(th + phase)
    near = AXIS_MM + ecc * np.cos(ph) - np.sqrt(R ** 2 - (ecc * np.sin(ph)) ** 2)
    rng = np.random.default_rng(8)
    frames = [plate_frame(GEO, s, SCENE, Camera(), rng)[0] for s in near]
    p = write_folder(tmp_path / "cyl", frames, [{"angle_deg": float(a)} for a in th],
                     scenario="rotary", rig=rig_dict(GEO))
    fit = locate_axis_from_cylinder(p, _cal(), R)
    assert abs(fit.axis_mm - AXIS_MM) < 0.02 and abs(fit.eccentricity_mm - ecc) < 0.05


def test_cylinder_fit_degenerate():
    with pytest.raises(CalibrationError):
        axis_from_cylinder_scan([0.0, 1.0], [1.0, 2.0], 50.0)
    with pytest.raises(ValueError):
        axis_from_cylinder_scan([0.0, 90.0, 180.0], [1.0, 2.0, 3.0], -1.0)
