"""Scenario ``render target`` (sim.target): frames, manifest, exact truth, OpenCV's detector, bad input.

References: OpenCV's own ``projectPoints`` with the camera of ``truth/rig_truth.json``;
OpenCV's chessboard detector on the twin's frames and on an exact image of the same board
drawn here without the renderer (the pattern's albedo through the in-focus plane's
homography, box-integrated over each pixel by supersampling).
"""

from __future__ import annotations

import json
import math
import tomllib

import numpy as np
import pytest

from scheimpflug.app.cli import main
from scheimpflug.model.rig import load_preset, rig_from_dict

pytestmark = pytest.mark.render

ISSUE_RIG = """[lens]
focal_length_mm = 35.0
[laser]
scheimpflug_distance_mm = 120.0
tan_phi = 0.3
[sensor]
pixel_pitch_um = 3.45
columns = 2048
rows = 2448
hinge_column = 4100.0
axis_row = 1300.0
"""


@pytest.fixture(scope="module")
def target_folder(tmp_path_factory):
    out = tmp_path_factory.mktemp("target") / "tgt"
    code = main(["render", "target", "--preset", "paper", "--pattern", "chessboard:10x8:7", "--poses", "2",
                 "--binning", "4", "--camera-spp", "2", "--out", str(out), "--quiet"])
    assert code == 0
    return out


def test_target_frames_carry_pose_light_and_exposure(target_folder, variant):
    m = json.loads((target_folder / "manifest.json").read_text())
    assert m["scenario"] == "target" and m["complete"] is True
    frames = m["frames"]
    assert [(f["pose"], f["light"]) for f in frames] == [(0, "flood"), (0, "laser"), (1, "flood"), (1, "laser")]
    assert all("stage_mm" not in f and "angle_deg" not in f for f in frames)
    flood_ms, laser_ms = frames[0]["exposure_ms"], frames[1]["exposure_ms"]
    assert laser_ms == m["rig"]["sensor"]["exposure_ms"] and flood_ms != laser_ms
    assert m["rig"]["environment"]["flood_irradiance_w_m2"] == 20.0 and m["rig"]["twin"]["camera_spp"] == 2
    assert m["render"]["camera_pass"]["spp"] == 2 and "pattern" in m["truth"]
    from sim.writer import read_png

    flood_img, laser_img = (read_png(target_folder / f["file"]).astype(float) for f in frames[:2])
    assert flood_img.max() > 4 * laser_img.max() > 0              # the print flood-lit, the laser line alone
    for f in frames:
        z = np.load(target_folder / f["truth"])
        stripe = np.isfinite(z["stripe_u"]).sum()
        assert (stripe == 0) == (f["light"] == "flood"), (f, stripe)
        assert z["pattern_corners_px"].shape == (80, 2) and z["pattern_corner_ids"].shape == (80, 2)
        assert np.isfinite(z["pattern_corners_px"]).any()


def test_corner_truth_is_opencvs_projection_of_the_rig_truth_camera(target_folder, variant):
    import cv2

    from scenes.patterns import parse_pattern

    cam = json.loads((target_folder / "truth" / "rig_truth.json").read_text())["opencv"]
    k, dist = np.array(cam["camera_matrix"]), np.array(cam["dist_coeffs"])
    assert len(dist) == 14 and cam["tau_deg"][1] == pytest.approx(21.646, abs=1e-3)   # the paper's tilt
    spec = parse_pattern("chessboard:10x8:7")
    z = np.load(target_folder / "truth" / "00000.npz")
    assert np.array_equal(z["pattern_corner_ids"], spec.corner_ids())  # exact: integers
    obj = np.c_[spec.corners_mm(), np.zeros(80)]
    c_from_p = z["camera_from_pattern"]
    rvec, _ = cv2.Rodrigues(c_from_p[:3, :3])
    uv, _ = cv2.projectPoints(obj, rvec, c_from_p[:3, 3], k, dist)
    seen = np.isfinite(z["pattern_corners_px"][:, 0])
    np.testing.assert_allclose(uv.reshape(-1, 2)[seen], z["pattern_corners_px"][seen], atol=1e-6)
    # the pose is a rigid motion and the camera frame's is the truth's
    r = z["rig_from_pattern"][:3, :3]
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(np.array(cam["camera_from_rig"]) @ z["rig_from_pattern"], c_from_p, atol=1e-9)


@pytest.mark.parametrize("args, words", [
    (["--pattern", "hexagons:3x3:5"], "unknown pattern"),
    (["--pattern", "chessboard:10x8:7", "--plate-mm", "60x60"], "needs a plate of at least"),
    (["--pattern", "chessboard:10x8:7", "--poses", "0"], "--poses 0"),
    (["--pattern", "chessboard:10x8:7", "--depth-range-mm", "5000:6000"], "can never be in view"),
    (["--pattern", "chessboard:10x8:7", "--on-table"], "--on-table needs --step-deg"),
    (["--pattern", "chessboard:10x8:7", "--lights", "sun"], "--lights"),
    ([], "needs --pattern"),
])
def test_bad_target_input_is_one_clear_line(tmp_path, capsys, args, words):
    out = tmp_path / "t"
    code = main(["render", "target", "--preset", "paper", "--binning", "8", "--out", str(out), "--quiet", *args])
    err = capsys.readouterr().err.strip()
    assert code != 0 and words in err and len(err.splitlines()) == 1, err
    assert not out.exists() or not any(out.iterdir())


def test_table_poses_turn_the_pattern_about_the_rotary_axis(variant):
    from sim.stages import invert, rig_from_stage
    from sim.target import target_scenario

    rig = load_preset("paper").replace(environment={"flood_irradiance_w_m2": 20.0})
    sc = target_scenario(rig, pattern="chessboard:10x8:7", on_table=True, step_deg=20.0, lights=("flood",))
    angles = [f.angle_deg for f in sc.frames]
    assert len(angles) >= 4 and angles[0] == 0.0
    stage_from_rig = invert(rig_from_stage(rig))
    part_from_pattern = np.array(sc.params["part_from_pattern"])
    origins = np.array([(stage_from_rig @ f.rig_from_part @ part_from_pattern)[:3, 3] for f in sc.frames])
    r = np.hypot(origins[:, 0], origins[:, 1])
    np.testing.assert_allclose(r, r[0], atol=1e-9)                    # a circle about the axis (stage z)
    np.testing.assert_allclose(origins[:, 2], origins[0, 2], atol=1e-9)
    # at 0° the print lies in the sheet (stage y = 0), its bottom edge on the table
    m0 = stage_from_rig @ sc.frames[0].rig_from_part @ part_from_pattern
    assert abs(m0[1, 2]) == pytest.approx(1.0) and abs(m0[1, 3]) < 1e-9


def _exact_board_image(spec, corners_px, shape, sub=8, black=0.05, white=0.85):
    """The board drawn without the renderer: albedo at pixel sub-samples through the plane's homography."""
    import cv2

    from scenes.patterns import texture_albedo

    h, _ = cv2.findHomography(corners_px, spec.corners_mm(), 0)      # image → pattern (exact: a central projection)
    vv, uu = np.mgrid[0:shape[0], 0:shape[1]].astype(float)
    off = (np.arange(sub) + 0.5) / sub - 0.5
    img = np.zeros(shape)
    tex = spec.texture(black, white)
    for du in off:
        for dv in off:
            p = np.stack([uu + du, vv + dv, np.ones_like(uu)], -1) @ h.T
            img += texture_albedo(tex, p[..., :2] / p[..., 2:])
    return img / sub**2


class Backdrop:
    """A dark wall 300 mm behind the first pose's print (duck-typed scenes.Part)."""

    def __init__(self, rig_from_pattern):
        import trimesh

        self.mesh = trimesh.creation.box([2000.0, 2000.0, 1.0])
        self.mesh.apply_translation([0.0, 0.0, 300.0])
        self.texture, self.uv_mm = {"kind": "uniform", "albedo": 0.02}, None
        self.material, self.object_id, self.name = "cardboard", 9, "backdrop"


def _subpix(img, start):
    import cv2

    f = (img / img.max()).astype(np.float32)
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-4)
    corners = start.astype(np.float32).reshape(-1, 1, 2).copy()
    return cv2.cornerSubPix(f, corners, (11, 11), (-1, -1), crit).reshape(-1, 2)


def _rms(a, b):
    return float(np.sqrt(((a - b) ** 2).sum(1).mean()))


@pytest.mark.parametrize("which", ["paper", "issue-rig"])
def test_opencv_finds_in_focus_corners_where_the_truth_puts_them(variant, which):
    """Poses in the sharp plane, noise off: findChessboardCorners + cornerSubPix on the twin's frame
    agrees with pattern_corners_px as on an exact image of the same board (and within its noise with noise on)."""
    import cv2

    from scenes.patterns import parse_pattern
    from scheimpflug.model.camera import sensor_pose
    from sim.camera_pass import CameraPass, CameraSettings, sensor_window
    from sim.scene import SimScene
    from sim.sensor import SensorModel, apply_sensor, frame_rng
    from sim.target import pattern_truth, target_scenario
    from sim.truth import SceneCaster

    rig = load_preset("paper") if which == "paper" else rig_from_dict(tomllib.loads(ISSUE_RIG))
    if which != "paper":
        from scheimpflug.model.binning import binned_rig

        rig = binned_rig(rig, 2)
    rig = rig.replace(environment={"flood_irradiance_w_m2": 20.0})
    spec = parse_pattern("chessboard:10x8:7")
    from scheimpflug.model.hinge import hinge_geometry

    d_lo, d_hi = sorted(hinge_geometry(rig).distance_from_column([0.0, rig.sensor.columns - 1.0]))
    mid, half = 0.5 * (d_lo + d_hi), 0.15 * (d_hi - d_lo)      # centres in the middle of the view
    sc = target_scenario(rig, seed=3, pattern=spec.text, poses=12, tilt_deg=0.0, off_sheet_mm=0.0, roll_deg=20.0,
                         depth_range_mm=(mid - half, mid + half), height_range_mm=(-5.0, 5.0), lights=("flood",))
    backdrop = Backdrop(sc.frames[0].rig_from_part)             # a dark wall behind: the board on black
    scene = SimScene([*sc.assembly.parts, backdrop])
    lit = rig.replace(environment={"flood_irradiance_w_m2": 0.0, "ambient_irradiance_w_m2": 30.0})
    from scheimpflug.calibration.measure import refine_corners_model

    twin_err, exact_err, between, model_err, done, missed = [], [], [], [], 0, 0
    for f in sc.frames:
        poses = np.stack([f.rig_from_part, f.rig_from_part, sc.frames[0].rig_from_part])
        scene.set_pose(poses)
        truth = pattern_truth(rig, sc, f, SceneCaster(scene), {})["pattern_corners_px"]
        if not np.isfinite(truth).all():
            continue                                    # partly out of view: the whole board is needed
        lo = np.maximum(np.floor(truth.min(0)).astype(int) - 40, 0)
        hi = np.minimum(np.ceil(truth.max(0)).astype(int) + 40, [rig.sensor.columns, rig.sensor.rows])
        window = sensor_window(sensor_pose(rig), int(lo[0]), int(lo[1]), int(hi[0] - lo[0]), int(hi[1] - lo[1]))
        cp = CameraPass(lit, scene, CameraSettings(spp=64, pixel_filter="box"), pose=window)
        img = cp.render(poses, f.seed).astype(np.float64)
        truth = truth - lo
        g8 = np.clip(img / np.percentile(img, 99.5) * 240, 0, 255).astype(np.uint8)
        found, start = cv2.findChessboardCorners(g8, spec.grid_shape)
        missed += not found
        if not found:                                   # the detector's limit, not the truth's: counted
            continue
        start = start.reshape(-1, 2)
        order = np.linalg.norm(start[:, None] - truth[None], axis=2).argmin(1)
        exact = _exact_board_image(spec, truth, img.shape)
        ours, ref = _subpix(img, start), _subpix(exact, start)
        fitted = refine_corners_model(img, spec, order, start)      # this project's refinement (issue 24)
        refined = np.isfinite(fitted).all(1)                         # NaN: a patch leaves the window
        assert refined.mean() > 0.8, refined.mean()
        model_err.append(_rms(fitted[refined], truth[order][refined]))
        twin_err.append(_rms(ours, truth[order]))
        exact_err.append(_rms(ref, truth[order]))
        between.append(_rms(ours, ref))
        if done == 0:                                   # sensor noise on: its scatter over 4 draws
            model = SensorModel.from_rig(lit)
            noisy = [_subpix(apply_sensor(img.astype(np.float32), model, frame_rng(k, 0)).astype(np.float64), start)
                     for k in range(4)]
            scatter = float(np.sqrt(np.mean(np.var(np.stack(noisy), axis=0, ddof=1).sum(-1))))
            noisy_err = float(np.mean([_rms(n, truth[order]) for n in noisy]))
            assert noisy_err <= 1.25 * math.hypot(twin_err[-1], scatter), (noisy_err, twin_err[-1], scatter)
        done += 1
        if done == 2:
            break
    assert done == 2 and missed <= 2, (done, missed)
    print(f"{which}: twin {np.round(twin_err, 4)} exact image {np.round(exact_err, 4)} between {np.round(between, 4)} "
          f"model fit {np.round(model_err, 4)}")
    # the issue's 0.05 px: OpenCV's detector cannot (0.055–0.062 px off on an exact image of the board, its
    # pixel-locking on sharp edges); the blurred-corner model fit of the calibration does, on the twin's frames
    assert np.sqrt(np.mean(np.square(model_err))) < 0.05, model_err
    # the twin's frame gives the detector the corners an exact image gives it (its own pixel-locking bias)
    assert max(between) < 0.02, between
    assert np.sqrt(np.mean(np.square(twin_err))) <= np.sqrt(np.mean(np.square(exact_err))) + 0.01


def test_walls_stand_still_behind_the_turning_part(tmp_path, variant):
    """--background walls: their stripe is in the truth, in the same place in every frame, and lit in the frame."""
    from sim.scenarios import rotary_scenario
    from sim.writer import read_png

    out = tmp_path / "walls"
    assert main(["render", "rotary", "--preset", "paper", "--part", "tape", "--step-deg", "90", "--frames", "2",
                 "--background", "walls", "--flood-w-m2", "1", "--camera-spp", "1", "--binning", "8",
                 "--truth-pixels", "none", "--out", str(out), "--quiet"]) == 0
    assert (out / "truth" / "background.ply").exists()
    m = json.loads((out / "manifest.json").read_text())
    assert m["scenario_params"]["background"]["kind"] == "walls"
    z = [np.load(out / "truth" / f"{i:05d}.npz") for i in range(2)]
    wall = [(t["stripe_object_id"] >= 101) for t in z]
    both = wall[0] & wall[1]
    assert both.sum() >= 5, [w.sum() for w in wall]
    np.testing.assert_allclose(z[0]["stripe_u"][both], z[1]["stripe_u"][both], atol=1e-6)   # the walls do not turn
    img = read_png(out / "frames" / "00000.png").astype(float)
    rows = np.nonzero(both)[0]
    cols = np.round(z[0]["stripe_u"][rows]).astype(int)
    assert np.median(img[rows, cols]) > 2 * np.median(img)          # the laser on the wall, in the frame
    # without a background the scenario is what it was
    rig = load_preset("paper")
    plain = rotary_scenario(rig, part="tape", step_deg=90.0, frames=2)
    assert plain.background == () and plain.frame_truth is None and "background" not in plain.params


def test_a_box_housing_stands_still_and_is_lit_around_the_part(tmp_path, variant):
    """--background box: the part in a housing; the laser meets its walls at the same place in every frame."""
    out = tmp_path / "box"
    assert main(["render", "rotary", "--preset", "paper", "--part", "tape", "--step-deg", "90", "--frames", "2",
                 "--background", "box", "--flood-w-m2", "1", "--camera-spp", "1", "--binning", "8",
                 "--truth-pixels", "none", "--out", str(out), "--quiet"]) == 0
    m = json.loads((out / "manifest.json").read_text())
    assert m["scenario_params"]["background"]["kind"] == "box" and (out / "truth" / "background.ply").exists()
    z = [np.load(out / "truth" / f"{i:05d}.npz") for i in range(2)]
    housing = [(t["stripe_object_id"] >= 101) for t in z]
    both = housing[0] & housing[1]
    assert both.sum() >= 5, [h.sum() for h in housing]
    np.testing.assert_allclose(z[0]["stripe_u"][both], z[1]["stripe_u"][both], atol=1e-6)
    from sim.writer import read_png

    img = read_png(out / "frames" / "00000.png").astype(float)
    rows = np.nonzero(both)[0]
    assert np.median(img[rows, np.round(z[0]["stripe_u"][rows]).astype(int)]) > 2 * np.median(img)


def test_the_corner_models_derivatives_are_its_finite_differences():
    """The blurred-corner fit's analytic Jacobian (Kaufman's variable projection) against central differences."""
    from scheimpflug.calibration.measure import _saddle_terms

    rng = np.random.default_rng(3)
    xy = rng.uniform(-6, 6, (300, 2)) + [40.0, 30.0]
    for p in (np.array([40.3, 29.6, 0.3, 1.9, 1.7]), np.array([39.8, 30.2, -0.4, 1.2, -0.9])):
        _, jac = _saddle_terms(xy, p)
        for k in range(5):
            h = np.zeros(5)
            h[k] = 1e-6
            fd = (_saddle_terms(xy, p + h)[0] - _saddle_terms(xy, p - h)[0]) / 2e-6
            np.testing.assert_allclose(jac[:, k], fd, atol=1e-6, rtol=1e-5)
