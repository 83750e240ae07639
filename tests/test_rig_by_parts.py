"""A rig file by parts ([camera], [laser] plane, [turntable]) is the same rig as its Scheimpflug form.

Issue 35 item 1: the two forms of one instrument load into equal rigs (FabScan's calibration on
the command line, a synthetic distorted camera at a random pose in the library), project every
point to the same pixel, and bad input is refused with one typed error each.  Render-free.
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np
import pytest

from scheimpflug.errors import RigError
from scheimpflug.model.camera import project_points
from scheimpflug.model.instrument import Camera, Instrument, Sheet, Turntable, rig_file_text, rig_from_instrument
from scheimpflug.model.instrument_file import (
    CAMERA_KEYS,
    LASER_PART_KEYS,
    REPLACED_KEYS,
    TURNTABLE_KEYS,
    rig_parts_text,
)
from scheimpflug.model.rig import load_rig, rig_from_dict

ROOT = Path(__file__).resolve().parents[1]
FABSCAN = ROOT.parent / "shared" / "realdata" / "fabscan" / "dummy.config.json"
TOL_PX = 1e-9      # both forms give the same floats: the projections agree exactly, 1e-9 px leaves room

PARTS = {
    "camera": {"fx_px": 1000.0, "fy_px": 1002.0, "cx_px": 630.0, "cy_px": 470.0, "width_px": 1280,
               "height_px": 960, "distortion": [-0.12, 0.05, 0.001, -0.0005, 0.0], "pixel_pitch_um": 3.75,
               "f_number": 2.8},
    "laser": {"plane": {"normal": [0.8, 0.0, 0.6], "distance_mm": 228.0}, "wavelength_nm": 650.0},
}


def _rotation(rng) -> np.ndarray:
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


def _points(rig, rng, count=300) -> np.ndarray:
    """Rig-frame points near the sheet in front of the camera, 150–450 mm away."""
    x = rng.uniform(150.0, 450.0, count)
    y = rig.laser.scheimpflug_distance_mm - x * rig.laser.tan_phi + rng.normal(0.0, 5.0, count)
    return np.column_stack([x, y, rng.uniform(-0.3, 0.3, count) * x])


def _same_projection(a, b, rng) -> float:
    pts = _points(a, rng)
    pa, pb = project_points(a, pts).uv_px, project_points(b, pts).uv_px
    assert np.isfinite(pa).all()
    return float(np.abs(pa - pb).max())


def test_fabscan_rig_in_both_forms_is_one_rig(rng, tmp_path):
    from scheimpflug.app.cli import main

    paths = {}
    for form in ("scheimpflug", "parts"):
        paths[form] = tmp_path / f"{form}.toml"
        assert main(["rig", "from-calibration", str(FABSCAN), "--out", str(paths[form]), "--preset",
                     "rpi-v2-binned", "--form", form]) == 0
    text = paths["parts"].read_text()
    assert "[camera]" in text and "plane = { normal" in text and "[turntable]" in text
    assert "scheimpflug_distance_mm" not in text and "tan_phi" not in text and "# unknown" in text
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")        # FabScan's distortion folds inside the frame (test_instrument)
        a, b = load_rig(paths["scheimpflug"]), load_rig(paths["parts"])
    assert a == b                               # render-free: every key of every table equal
    assert _same_projection(a, b, rng) <= TOL_PX


def test_a_posed_distorted_camera_round_trips_through_its_parts(rng):
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = _rotation(rng), rng.uniform(-100.0, 100.0, 3)
    n_c = np.array([0.8, 0.1, 0.55]) / np.linalg.norm([0.8, 0.1, 0.55])
    n_i = pose[:3, :3] @ n_c
    cam = Camera(1000.0, 1001.0, 641.0, 480.5, 1280, 960, (-0.15, 0.04, 0.001, 0.0, 0.01), 3.75, 2.8,
                 focus_distance_mm=310.0, instrument_from_camera=pose)
    up = pose[:3, :3] @ np.array([0.0, -1.0, 0.0])          # the camera's −Y: up in its image
    axis_c = np.array([60.0, 0.0, 300.0])                   # a point of the plane, camera frame
    table = Turntable(pose[:3, :3] @ (axis_c + 40.0 * np.array([0.0, 1.0, 0.0])) + pose[:3, 3], up)
    inst = Instrument(cam, Sheet(n_i, 0.55 * 300.0 + 0.8 * 60.0 + n_i @ pose[:3, 3],
                                 emitter_mm=pose[:3, :3] @ np.array([-40.0, 0.0, 0.0]) + pose[:3, 3]), table)
    rig = rig_from_instrument(inst)
    data = _toml(rig_parts_text(rig, inst, "synthetic"))
    assert rig_from_dict(data) == rig
    assert rig_from_dict(_toml(rig_file_text(rig, inst, "synthetic"))) == rig
    assert _same_projection(rig, rig_from_dict(data), rng) <= TOL_PX


def _toml(text: str) -> dict:
    import tomllib

    return tomllib.loads(text)


def test_a_plane_by_a_point_is_the_plane_by_its_distance():
    by_point = {**PARTS, "laser": {"plane": {"normal": [0.8, 0.0, 0.6], "point_mm": [60.0, 5.0, 300.0]},
                                   "wavelength_nm": 650.0}}
    assert rig_from_dict(by_point) == rig_from_dict(PARTS)


def test_the_other_tables_keep_their_keys_and_preset_fills_the_camera():
    rig = rig_from_dict({**PARTS, "sensor": {"read_noise_e": 2.5, "exposure_ms": 4.0},
                         "environment": {"flood_irradiance_w_m2": 1.0}, "laser": {**PARTS["laser"], "power_mw": 7.0}})
    assert (rig.sensor.read_noise_e, rig.sensor.exposure_ms, rig.environment.flood_irradiance_w_m2,
            rig.laser.power_mw, rig.laser.wavelength_nm) == (2.5, 4.0, 1.0, 7.0, 650.0)
    assert rig.sensor.image_distance_mm == pytest.approx(1000.0 * 3.75e-3, rel=1e-12)
    cam = {k: v for k, v in PARTS["camera"].items() if k not in ("width_px", "height_px", "pixel_pitch_um",
                                                                  "f_number")}
    rig = rig_from_dict({**PARTS, "camera": {**cam, "preset": "rpi-v2-binned", "cx_px": 819.5, "cy_px": 615.5}})
    assert (rig.sensor.columns, rig.sensor.rows, rig.sensor.pixel_pitch_um, rig.lens.f_number) == (
        1640, 1232, 2.24, 2.0)


def test_design_of_an_ordinary_camera_by_parts():
    from scheimpflug.model.design import design_report

    rep = design_report(rig_from_dict(PARTS))
    assert rep["sensor_kind"] == "ordinary" and rep["C_mm"] is None and rep["depth_range_mm"] > 0


@pytest.mark.parametrize("table, key", [("lens", "focal_length_mm"), ("sensor", "hinge_column"),
                                        ("laser", "tan_phi"), ("stage", "axis_mm")])
def test_mixing_the_forms_names_both(table, key):
    data = {**PARTS, table: {**PARTS.get(table, {}), key: 1.0}}
    with pytest.raises(RigError, match=rf"\[{table}\] {key} and \[") as err:
        rig_from_dict(data)
    assert "by parts" in str(err.value)


def _with(table: str, **changes) -> dict:
    return {**PARTS, table: {**PARTS[table], **changes}}


@pytest.mark.parametrize("data, words", [
    (_with("camera", fx_px=0.0), "singular camera matrix"),
    (_with("laser", plane={"normal": [0.0, 0.0, 0.0], "distance_mm": 100.0}), "is zero"),
    (_with("laser", plane={"normal": [0.8, 0.0, 0.7], "distance_mm": 100.0}), "not 1"),
    (_with("laser", plane={"normal": [0.0, 0.0, 1.0], "distance_mm": -200.0}), "behind the camera"),
    (_with("laser", plane={"normal": [0.6, 0.0, -0.8], "distance_mm": 100.0}), "behind the camera or outside"),
    (_with("camera", preset="nope"), "unknown camera preset 'nope'"),
    (_with("camera", focus="far"), "focus"),
    (_with("camera", lens=1.0), "unknown key 'lens'"),
    (_with("laser", plane={"normal": [0.8, 0.0, 0.6]}), "one of distance_mm, point_mm"),
    ({"laser": PARTS["laser"]}, "needs a \\[camera\\]"),
    ({"camera": PARTS["camera"]}, "plane is missing"),
    ({**PARTS, "turntable": {"axis_point_mm": [0.0, 0.0, 300.0]}}, "axis_direction is missing"),
    ({**PARTS, "turntable": {"axis_point_mm": [0, 0, 300], "axis_direction": [0, 2, 0]}}, "not 1"),
])
def test_bad_input_by_parts_is_one_clear_error(data, words):
    with pytest.raises(RigError, match=words):
        rig_from_dict(data)


def test_the_reference_documents_every_key_by_parts():
    page = (ROOT / "docs" / "reference" / "rig-keys.md").read_text()
    section = page.split("## A rig file by parts", 1)[1]
    for key in (*CAMERA_KEYS, *TURNTABLE_KEYS, *LASER_PART_KEYS):
        assert re.search(rf"`{key}`", section), key
    for table, (keys, _) in REPLACED_KEYS.items():
        for key in keys:
            assert f"`{key}`" in section, (table, key)
    assert "by its parts" in (ROOT / "docs" / "reference" / "interface.md").read_text()
