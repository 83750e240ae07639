"""Error models through the renderer (issue 11): each shows up in the frames where its definition puts it.

4 × 4 binned paper rig, a few frames each, no ambient light and no sensor noise
(the renderer's expected electrons), stripe centres by a windowed centre of
gravity; measured − measured differences against the ideal rig cancel the
detector's own bias.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from scheimpflug.model.binning import binned_rig
from scheimpflug.model.hinge import hinge_geometry
from scheimpflug.model.rig import load_preset

pytestmark = pytest.mark.render

BIN = 4


def _rig(**tables):
    rig = load_preset("paper").replace(environment={"ambient_irradiance_w_m2": 0.0})
    return binned_rig(rig.replace(**tables) if tables else rig, BIN)


def _frames(rig, name, spp=64, seed=5, **options):
    """(scenario, [(expected electrons, StripeTruth)]) of a scenario, noise-free."""
    from sim.scenarios import build_scenario
    from sim.truth import SceneCaster, stripe_truth
    from sim.writer import MitsubaTwin

    sc = build_scenario(name, rig, seed=seed, **options)
    twin = MitsubaTwin(rig, sc.assembly, spp=spp)
    mesh = sc.assembly.combined_mesh()
    ids = sc.assembly.face_object_ids()
    out = []
    for f in sc.frames:
        img = twin.render(f)
        truth = stripe_truth(rig, np.asarray(mesh.vertices), np.asarray(mesh.faces), ids,
                             f.rig_from_part, f.ref_from_part, SceneCaster(twin.scene),
                             rig_from_laser=f.rig_from_laser)
        out.append((img, truth))
    return sc, out


def _cog(img, half=6):
    """Per-row windowed centre of gravity around the row maximum [px] and the row sums."""
    u0 = np.argmax(img, axis=1)
    cols = np.clip(u0[:, None] + np.arange(-half, half + 1), 0, img.shape[1] - 1)
    vals = np.take_along_axis(img, cols, 1).astype(np.float64)
    s = vals.sum(1)
    return (vals * cols).sum(1) / np.where(s > 0, s, 1.0), s


def _rows(truth, margin=3):
    rows = np.flatnonzero(np.isfinite(truth.stripe_u))
    return rows[margin:-margin]


# ------------------------------------------------------------------ translation stage
def test_stage_with_periodic_error_moves_the_plate_where_the_model_says(variant):
    """Lead 40 mm, 250 µm amplitude: at s = 10, 20, 30 mm the plate is +250, 0, −250 µm off."""
    opts = {"steps": 3, "start_mm": 10.0, "step_mm": 10.0}
    rig = _rig(stage={"translation_periodic_um": 250.0, "translation_lead_mm": 40.0})
    ideal = _rig()
    g = hinge_geometry(rig)
    sc, err = _frames(rig, "calibration", **opts)
    _, ref = _frames(ideal, "calibration", **opts)
    for f, (img, truth), (img0, truth0), expected_um in zip(sc.frames, err, ref, (250.0, 0.0, -250.0)):
        assert f.actual["stage"]["position_error_um"] == pytest.approx(expected_um, abs=1e-6)
        D0 = f.stage_mm - rig.stage.d0_mm
        shift = float(g.column_from_distance(D0 + 1e-3 * expected_um) - g.column_from_distance(D0))
        rows = _rows(truth0)
        measured = np.median(_cog(img)[0][rows] - _cog(img0)[0][rows])
        assert measured == pytest.approx(shift, abs=0.02), (expected_um, shift, measured)
        np.testing.assert_allclose(truth.stripe_u[rows] - truth0.stripe_u[rows], shift, atol=1e-6)
        # the truth's points lie on the face where the carriage really went (stage x = s_a − axis)
        x = truth.stripe_point_mm[rows, 0]
        np.testing.assert_allclose(x, f.actual["stage"]["stage_mm"] - rig.stage.axis_mm, atol=1e-6)
    if abs(shift) < 0.2:
        pytest.fail(f"the test's shift ({shift:.3f} px) is too small to tell")


# ------------------------------------------------------------------ calibration plate
def test_plate_tilt_shows_up_as_the_predicted_stripe_slope(variant):
    tilt = 3.0
    rig = _rig(stage={"plate_tilt_deg": tilt})
    g = hinge_geometry(rig)
    sc, [(img, truth)] = _frames(rig, "calibration", steps=1, start_mm=120.0)
    # the face line: a point z up the plate leans z·sin t along e_p and sinks z·(1 − cos t)
    D0 = 120.0 - rig.stage.d0_mm
    z_t = rig.stage.calibration_table_z_mm
    t = math.radians(tilt)
    (u1, v1), (u2, v2) = (g.pixel_from_sheet(D0 + z * math.sin(t), z_t + z * math.cos(t))
                          for z in (10.0, 80.0))
    predicted = (u2 - u1) / (v2 - v1)               # du/dv of the stripe [px/px]
    rows = _rows(truth)
    u, _ = _cog(img)
    slope = np.polyfit(rows, u[rows], 1)[0]
    assert abs(predicted) * len(rows) > 3.0          # a 3° lean moves the stripe ends by > 3 px
    assert slope == pytest.approx(predicted, rel=0.01)
    assert np.polyfit(rows, truth.stripe_u[rows], 1)[0] == pytest.approx(predicted, rel=1e-4)


# ------------------------------------------------------------------ laser
def test_bowed_and_drifting_sheet_is_rendered_where_the_truth_says(variant):
    """A 20 mrad bow and 2 mrad pointing jitter move the stripe; image and truth agree."""
    from scheimpflug.model.camera import project_points
    from sim.lightsheet import bow_angle_rad, light_sheet, sheet_coordinates

    opts = {"steps": 2, "start_mm": 40.0, "step_mm": 150.0}
    rig = _rig(laser={"line_bow_mrad": 20.0, "pointing_jitter_urad": 2000.0})
    sc, err = _frames(rig, "calibration", **opts)
    _, ref = _frames(_rig(), "calibration", **opts)
    for (img, truth), (img0, truth0) in zip(err, ref):
        rows = _rows(truth)
        moved = truth.stripe_u[rows] - truth0.stripe_u[rows]
        assert np.abs(moved).max() > 0.3                 # the errors move the stripe visibly …
        du = (_cog(img)[0] - _cog(img0)[0])[rows]
        np.testing.assert_allclose(du, moved, atol=0.03)  # … and the image follows the truth
    # bow alone, no drift: the lit point leaves the plane by r·β(α), exactly where the camera sees it
    bowed = _rig(laser={"line_bow_mrad": 20.0})
    sh = light_sheet(bowed)
    sc, [(img, truth)] = _frames(bowed, "calibration", steps=1, start_mm=40.0)
    rows = _rows(truth)
    ref_from_rig = sc.frames[0].ref_from_part @ np.linalg.inv(sc.frames[0].rig_from_part)
    p_rig = (np.linalg.inv(ref_from_rig)[:3, :3] @ truth.stripe_point_mm[rows].T).T \
        + np.linalg.inv(ref_from_rig)[:3, 3]
    r, alpha, offset = sheet_coordinates(sh, p_rig)
    np.testing.assert_allclose(offset, r * bow_angle_rad(sh, alpha), atol=1e-6)
    np.testing.assert_allclose(project_points(bowed, p_rig).uv_px[:, 0], truth.stripe_u[rows], atol=1e-6)


def test_powell_fan_profile_scales_the_stripe_as_defined(variant):
    from sim.lightsheet import light_sheet, powell_factor, sheet_coordinates

    rig = _rig(laser={"fan_edge_ratio": 3.0, "fan_angle_deg": 16.0})
    flat = _rig(laser={"fan_angle_deg": 16.0})
    sc, [(img, truth)] = _frames(rig, "calibration", spp=256, steps=1, start_mm=200.0)
    _, [(img0, _)] = _frames(flat, "calibration", spp=256, steps=1, start_mm=200.0)
    rows = _rows(truth, margin=6)
    ref_from_rig = sc.frames[0].ref_from_part @ np.linalg.inv(sc.frames[0].rig_from_part)
    rig_from_ref = np.linalg.inv(ref_from_rig)
    p = truth.stripe_point_mm[rows] @ rig_from_ref[:3, :3].T + rig_from_ref[:3, 3]
    alpha = sheet_coordinates(light_sheet(rig), p)[1]
    expected = powell_factor(light_sheet(rig), alpha)
    assert np.ptp(expected) > 0.3
    ratio = _cog(img)[1][rows] / _cog(img0)[1][rows]
    np.testing.assert_allclose(ratio, expected, rtol=0.01)


# ------------------------------------------------------------------ the frame folder
def test_frame_folder_records_what_the_erring_instrument_did(variant, tmp_path):
    from sim.writer import read_png, render_folder

    rig = _rig(stage={"translation_periodic_um": 30.0, "translation_repeatability_um": 5.0,
                      "pitch_urad": 200.0, "plate_height_error_mm": 0.2},
               sensor={"prnu_percent": 1.0, "dsnu_e": 2.0, "exposure_jitter_percent": 1.0},
               laser={"pointing_jitter_urad": 50.0})
    opts = {"steps": 2, "start_mm": 30.0, "step_mm": 100.0}
    for run in ("a", "b"):
        render_folder(rig, "calibration", tmp_path / run, seed=3, spp=16, warn=lambda m: None, **opts)
    man = json.loads((tmp_path / "a" / "manifest.json").read_text())
    assert [e["stage_mm"] for e in man["frames"]] == [30.0, 130.0]          # commanded
    assert man["scenario_params"]["plate_height_mm"] == 89.0                # what the user is told
    assert man["scenario_params"]["plate"]["height_mm"] == pytest.approx(89.2)
    for e in man["frames"]:
        act = e["actual"]
        assert set(act) >= {"stage", "exposure_factor", "pointing_urad", "lens_centre_x_mm"}
        assert act["stage"]["stage_mm"] != e["stage_mm"] and act["exposure_factor"] != 1.0
        with np.load(tmp_path / "a" / e["truth"]) as z:   # the face at the real stage position …
            rows = np.isfinite(z["stripe_u"])
            x = z["stripe_point_mm"][rows]
            # … leaning by the carriage's pitch about the face bottom
            z_rel = x[:, 2] - rig.stage.calibration_table_z_mm
            lean = math.tan(1e-6 * act["stage"]["pitch_urad"]) * z_rel
            np.testing.assert_allclose(x[:, 0] - lean, act["stage"]["stage_mm"] - rig.stage.axis_mm,
                                       atol=1e-4)
    maps = np.load(tmp_path / "a" / "truth" / "sensor_maps.npz")
    assert maps["prnu_gain"].shape == (rig.sensor.rows, rig.sensor.columns)
    # same seed, same frames and truth, bit for bit
    for e in man["frames"]:
        # exact: same run
        assert np.array_equal(read_png(tmp_path / "a" / e["file"]), read_png(tmp_path / "b" / e["file"]))
        # exact: same run
        assert (tmp_path / "a" / e["truth"]).read_bytes() == (tmp_path / "b" / e["truth"]).read_bytes()


def test_rotary_errors_truth_stays_on_the_mesh(variant, tmp_path):
    from scheimpflug.io.ply import read_mesh
    from scheimpflug.scoring import PointToMesh
    from sim.scenarios import frame_draws
    from sim.writer import render_folder

    rig = _rig(stage={"rotary_eccentricity_deg": 0.5, "rotary_repeatability_deg": 0.05,
                      "wobble_urad": 2000.0, "radial_error_um": 200.0})
    render_folder(rig, "rotary", tmp_path, seed=2, spp=16, warn=lambda m: None, part="tape",
                  step_deg=60.0, frames=3)
    man = json.loads((tmp_path / "manifest.json").read_text())
    v, f, _ = read_mesh(tmp_path / "truth" / "mesh.ply")
    p2m = PointToMesh(v, f)
    for i, e in enumerate(man["frames"]):
        st = e["actual"]["stage"]
        theta = e["angle_deg"]
        # θ_a = θ + A·sin θ + σ·z, z the frame's stage draw
        expected = 0.5 * math.sin(math.radians(theta)) + 0.05 * frame_draws(2, i)[0]
        assert st["angle_error_deg"] == pytest.approx(expected, abs=1e-12)
        assert st["angle_deg"] == pytest.approx(theta + expected, abs=1e-12)
        with np.load(tmp_path / e["truth"]) as z:
            pts = z["stripe_point_mm"][np.isfinite(z["stripe_u"])]
        assert len(pts) > 50
        assert np.abs(p2m.query(pts).distance_mm).max() < 1e-3


@pytest.mark.parametrize("scenario, options", [
    ("calibration", ["--steps", "2", "--step-mm", "120"]),
    ("blocker", []),
    ("rotary", ["--part", "pile", "--step-deg", "120", "--frames", "2"]),
])
def test_render_cli_with_the_as_built_preset(variant, tmp_path, scenario, options):
    """`scheimpflug render SCENARIO --preset paper-as-built` works for every scenario."""
    from scheimpflug.app.cli import main

    assert main(["render", scenario, "--preset", "paper-as-built", "--binning", "8", "--spp", "8",
                 "--quiet", "--out", str(tmp_path), *options]) == 0
    man = json.loads((tmp_path / "manifest.json").read_text())
    assert man["rig"]["laser"]["line_bow_mrad"] == 0.5 and man["complete"]
    # issue 10's light is on too: 3 bounces, subsurface, surface speckle
    assert man["rig"]["twin"] == {"bounces": 3, "subsurface": True, "speckle_model": "surface", "camera_spp": 0}
    from sim.writer import read_png

    lit = 0
    for e in man["frames"]:
        img = read_png(tmp_path / e["file"])
        assert img.shape == (man["rig"]["sensor"]["rows"], man["rig"]["sensor"]["columns"])
        with np.load(tmp_path / e["truth"]) as z:
            rows = np.isfinite(z["stripe_u"])
            assert np.all(np.isfinite(z["stripe_point_mm"][rows]))
            assert np.all((z["secondary_fraction"][rows] >= 0) & (z["secondary_fraction"][rows] <= 1))
            if scenario == "rotary":   # the cardboard box and the paper tape scatter light inside
                translucent = rows & np.isin(z["stripe_object_id"], (2, 3))
                lit += translucent.sum()
                assert np.all(z["subsurface_fraction"][translucent] > 0)
            else:                      # the metal plate and blocker stay opaque
                assert np.all(z["subsurface_fraction"][rows] == 0)
    assert scenario != "rotary" or lit > 10
    assert all("actual" in e for e in man["frames"])
    assert (tmp_path / "truth" / "sensor_maps.npz").exists()
