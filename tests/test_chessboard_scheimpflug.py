"""A printed chessboard on Scheimpflug frames (issue 34 item 15): found, and what a rig can find, said first.

A Scheimpflug camera sees a print held in its sheet foreshortened along the columns and sheared;
OpenCV's detectors alone found the twin's chessboard in 1 of 20 hand-held poses (paper rig, binning
2, ``chessboard:10x7:8``) and in 2 of 10 wholly visible ones at binning 4.  References, none from
the detection's own code: the twin's truth (``pattern_corners_px``, ``pattern_centroid_px``,
``pattern_blur_px``, ``camera_from_pattern`` and the OpenCV camera of ``truth/rig_truth.json``),
the hinge closed forms (paper Eqs. 11–12) and a chessboard drawn through a known affine map.
Binned (4 × 4) frames keep it fast; the full-resolution figures are
benchmarks/bench_chessboard_scheimpflug.py's.
"""

from __future__ import annotations

import json
import math
import shutil

import cv2
import numpy as np
import pytest

from scheimpflug.app.cli import main
from scheimpflug.calibration.detectability import (
    PatternView,
    frame_views,
    generic_views,
    lattice_view,
    pattern_advice,
    plane_from_image,
    print_views,
    square_advice,
)
from scheimpflug.calibration.measure import _find_grid, detect_pattern
from scheimpflug.calibration.pattern import parse_pattern
from scheimpflug.calibration.target import calibrate_target_folder
from scheimpflug.errors import CalibrationError
from scheimpflug.io.frames import open_frame_folder
from scheimpflug.model.binning import binned_rig
from scheimpflug.model.hinge import hinge_geometry

PATTERN = "chessboard:10x7:8"          # the board
SHARP = 0.5                            # a corner's blur spot at most half its grid step: sharp


# ---------------------------------------------------------------- the twin's frames


@pytest.fixture(scope="module")
def frames(tmp_path_factory, variant):
    """Fourteen hand-held poses at binning 4, tilted ±20° (the benchmark's ±35°), centred where the advice puts them."""
    out = tmp_path_factory.mktemp("chess") / "b4"
    adv = pattern_advice(binned_rig(_paper(), 4), parse_pattern(PATTERN))
    lo, hi = adv.usable_mm
    assert main(["render", "target", "--preset", "paper", "--binning", "4", "--pattern", PATTERN, "--poses", "14",
                 "--tilt-deg", "20", "--lights", "flood", f"--depth-range-mm={lo:.0f}:{hi:.0f}",
                 "--height-range-mm=-19:-6", "--out", str(out), "--quiet"]) == 0
    return out


def _paper():
    from scheimpflug.model.rig import load_preset

    return load_preset("paper")


def _whole_and_sharp(folder, spec) -> dict:
    """Pose → truth for the poses whose printed squares lie wholly on the sensor, every corner sharp."""
    cam = json.loads((folder / "truth" / "rig_truth.json").read_text())["opencv"]
    x0, y0, x1, y1 = spec.extent_mm()
    outline = np.array([[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0]], np.float64)
    nc, nr = spec.grid_shape
    out = {}
    for f in json.loads((folder / "manifest.json").read_text())["frames"]:
        z = np.load(folder / f["truth"])
        m = z["camera_from_pattern"]
        uv, _ = cv2.projectPoints(outline, cv2.Rodrigues(m[:3, :3])[0], m[:3, 3], np.array(cam["camera_matrix"]),
                                  np.array(cam["dist_coeffs"]))
        c = z["pattern_corners_px"]
        if not (((uv >= -0.5) & (uv <= np.array(cam["image_size"]) - 0.5)).all() and np.isfinite(c).all()):
            continue
        g = c.reshape(nr, nc, 2)
        step = np.full((nr, nc), np.inf)
        d0, d1 = np.linalg.norm(np.diff(g, axis=0), axis=2), np.linalg.norm(np.diff(g, axis=1), axis=2)
        step[:-1], step[1:] = np.fmin(step[:-1], d0), np.fmin(step[1:], d0)
        step[:, :-1], step[:, 1:] = np.fmin(step[:, :-1], d1), np.fmin(step[:, 1:], d1)
        if np.all(z["pattern_blur_px"] <= SHARP * step.ravel()):
            out[f["pose"]] = z
    return out


def _centroid_rms(det, z, n: int) -> float:
    """RMS of detected corners against the truth's blur centroids (a chessboard's half-turn either way)."""
    ref = z["pattern_centroid_px"]
    return min(float(np.sqrt(np.mean(np.sum((det.corners_px - ref[ids]) ** 2, axis=1))))
               for ids in (det.ids, n - 1 - det.ids))


@pytest.mark.render
def test_a_chessboard_is_found_on_scheimpflug_frames_wherever_it_is_whole_and_sharp(frames):
    """``calibrate --method target``'s detection finds ≥ 80 % of the wholly visible, sharp boards, to 0.3 px."""
    spec = parse_pattern(PATTERN)
    truth = _whole_and_sharp(frames, spec)
    res = calibrate_target_folder(frames, PATTERN)          # flood frames only: a camera calibration
    found = set(res.detections) & set(truth)
    assert len(truth) >= 5                                    # the test means something
    assert len(found) >= 0.8 * len(truth)                     # OpenCV alone: 3 of these 9
    n = len(spec.corner_ids())
    for k in found:
        det = res.detections[k]
        assert len(det) >= 0.9 * n
        assert _centroid_rms(det, truth[k], n) < 0.3          # refined on the frame itself [px]


@pytest.mark.render
def test_without_a_rig_the_frame_stretched_and_its_own_lattice_find_it(frames, tmp_path):
    """Real frames may come without a rig: the generic views (the frame stretched along its distance axis,
    and each view's own lattice) find ≥ 80 % of the whole, sharp boards."""
    spec = parse_pattern(PATTERN)
    bare = tmp_path / "bare"
    shutil.copytree(frames, bare)
    m = json.loads((bare / "manifest.json").read_text())
    del m["rig"]
    (bare / "manifest.json").write_text(json.dumps(m))
    ff = open_frame_folder(bare)
    assert ff.rig is None
    views = frame_views(ff.rig, (ff.rows, ff.columns), spec, ff.stripe_along)
    assert [v.name for v in views] == [v.name for v in generic_views((ff.rows, ff.columns))]
    truth = _whole_and_sharp(frames, spec)
    found = 0
    for i, rec in enumerate(ff.frames):
        if rec.extra.get("pose") in truth:
            found += detect_pattern(ff.read(i), spec, views=views) is not None
    assert found >= 0.8 * len(truth)


@pytest.mark.render
def test_a_pattern_found_nowhere_is_explained_by_the_rig_not_guessed_from_counts(tmp_path, variant):
    """Squares of 1.5 mm at binning 8 span under 2 px: the error says so, from the rig (no 'is the pattern 8 × 7?')."""
    out = tmp_path / "tiny"
    assert main(["render", "target", "--preset", "paper", "--binning", "8", "--pattern", "chessboard:10x7:1.5",
                 "--poses", "2", "--lights", "flood", "--out", str(out), "--quiet"]) == 0
    with pytest.raises(CalibrationError) as exc:
        calibrate_target_folder(out, "chessboard:10x7:1.5")
    msg = str(exc.value)
    assert "found in 0 of 2" in msg and "the frames' rig says" in msg and "squares of at least" in msg
    assert "is the pattern" not in msg


# ---------------------------------------------------------------- the views (no rendering)


def test_the_sheet_view_is_the_hinge_closed_form(paper_rig):
    """Pixels through the sheet plane's homography land on (D − D₀, −(h − h₀)) of paper Eqs. 11–12."""
    rig = binned_rig(paper_rig, 2)
    h = plane_from_image(rig, 0.0, 0.0)
    g = hinge_geometry(rig)
    u, v = np.meshgrid(np.linspace(0, rig.sensor.columns - 1, 5), np.linspace(0, rig.sensor.rows - 1, 5))
    d, hh = g.sheet_from_pixel(u.ravel(), v.ravel())
    d0, h0 = g.sheet_from_pixel(0.5 * (rig.sensor.columns - 1), 0.5 * (rig.sensor.rows - 1))
    q = np.c_[u.ravel(), v.ravel(), np.ones(u.size)] @ h.T
    ab = q[:, :2] / q[:, 2:]
    np.testing.assert_allclose(ab[:, 0], d - d0, atol=1e-6)
    np.testing.assert_allclose(ab[:, 1], -(hh - h0), atol=1e-6)


def test_views_map_back_exactly_and_keep_the_print_unmirrored(paper_rig):
    """image_from_view undoes view_from_image; no view mirrors the frame (ChArUco markers read mirrored)."""
    rig = binned_rig(paper_rig, 4)
    views = print_views(rig, parse_pattern(PATTERN)) + generic_views((rig.sensor.rows, rig.sensor.columns))
    assert views and views[0].name == "sheet"
    p = np.array([[3.0, 5.0], [150.0, 240.0], [300.0, 480.0]])
    for view in views:
        q = np.c_[p, np.ones(3)] @ view.view_from_image.T
        np.testing.assert_allclose(view.image_from_view(q[:, :2] / q[:, 2:]), p, atol=1e-9)
        j = view.view_from_image[:2, :2] - np.outer(q[1, :2] / q[1, 2], view.view_from_image[2, :2])
        assert np.linalg.det(j) > 0, view.name


def _board(a: np.ndarray, square: float, shape=(520, 760)) -> np.ndarray:
    """A 10 × 7 chessboard seen through x = A·g + t (g in squares), 2 × 2 supersampled, lightly blurred."""
    ss = 2
    yy, xx = np.mgrid[0:shape[0] * ss, 0:shape[1] * ss] / ss
    t = np.array([shape[1] / 2, shape[0] / 2])
    g = np.linalg.solve(a * square, np.stack([xx.ravel() - t[0], yy.ravel() - t[1]]))
    i, j = np.floor(g[0] + 5.5), np.floor(g[1] + 4.0)
    on = (i >= 0) & (i < 11) & (j >= 0) & (j < 8)
    plate = (np.abs(g[0]) < 6.5) & (np.abs(g[1]) < 5.0)
    val = np.where(on, np.where((i + j) % 2 == 0, 30.0, 220.0), np.where(plate, 220.0, 0.0))
    img = val.reshape(shape[0] * ss, shape[1] * ss).reshape(shape[0], ss, shape[1], ss).mean(axis=(1, 3))
    return np.clip(cv2.GaussianBlur(img, (0, 0), 1.0), 0, 255).astype(np.uint8)


def test_the_lattice_view_squares_a_sheared_stretched_board():
    """A board stretched 3 × and sheared by 1.2 (a print turned and tilted out of the view's plane):
    in its lattice view the two grid steps are square within 10 % and the board is found."""
    a = np.array([[3.0, 1.2], [0.0, 1.0]]) @ np.array([[math.cos(0.3), -math.sin(0.3)], [math.sin(0.3), math.cos(0.3)]])
    img = _board(a, 8.0)
    spec = parse_pattern(PATTERN)
    view = lattice_view(img, None, square_px=14.0)
    assert view is not None
    steps = view.view_from_image[:2, :2] @ (8.0 * a)      # the grid's unit steps in the view (affine here)
    lengths = np.linalg.norm(steps, axis=0)
    assert abs(lengths[0] / lengths[1] - 1) < 0.1
    assert abs(steps[:, 0] @ steps[:, 1]) / lengths.prod() < 0.1
    assert _find_grid(view.warp(img), spec, "saddles") is not None


# ---------------------------------------------------------------- the advice


def test_the_advice_is_the_closed_form_of_the_square_size(paper_rig):
    """A square's pixels across the columns and down the rows are s·(u − u_h)²/|F²| and s·|u − u_h|/C."""
    for k in (1, 2, 4):
        rig = binned_rig(paper_rig, k)
        g = hinge_geometry(rig)
        adv = pattern_advice(rig, parse_pattern(PATTERN))
        for end, u in zip(adv.square_px, (0.0, rig.sensor.columns - 1.0)):
            du = u - rig.sensor.hinge_column
            assert end[0] == pytest.approx(8.0 * du ** 2 / abs(g.F2_px_mm), rel=1e-9)
            assert end[1] == pytest.approx(8.0 * abs(du) / g.C_mm, rel=1e-9)
    b8 = pattern_advice(binned_rig(paper_rig, 8), parse_pattern("chessboard:10x7:1.5"))
    assert b8.detectable_mm is None and "squares of at least" in b8.problem()
    assert pattern_advice(paper_rig, parse_pattern(PATTERN)).problem() is None
    big = pattern_advice(paper_rig, parse_pattern("chessboard:20x14:8"))      # 168 × 120 mm: never whole in view
    assert big.fits_mm is None and "does not fit" in big.problem()
    charuco = pattern_advice(paper_rig, parse_pattern("charuco:20x14:8:6:DICT_4X4_250"))  # found in part: fits or not
    assert charuco.fits_mm is None and charuco.problem() is None


def test_design_prints_the_detectable_patterns(capsys):
    assert main(["design", "--preset", "paper"]) == 0
    text = capsys.readouterr().out
    assert "printed patterns" in text and "binning 4" in text and "chessboard:10x7:8" in text
    assert main(["design", "--preset", "paper", "--json"]) == 0
    adv = json.loads(capsys.readouterr().out)["pattern_advice"]
    assert [b["binning"] for b in adv["binnings"]] == [1, 2, 4]
    assert adv == json.loads(json.dumps(square_advice(_paper())))
    smallest = [b["chessboard_square_mm"][0] for b in adv["binnings"]]
    assert smallest[1] == pytest.approx(2 * smallest[0], rel=0.01)            # binning 2: pixels twice as large


@pytest.mark.render
def test_render_target_says_before_rendering_whether_the_pattern_is_found(tmp_path, capsys, variant):
    assert main(["render", "target", "--preset", "paper", "--binning", "8", "--pattern", "chessboard:10x7:1.5",
                 "--poses", "1", "--lights", "flood", "--out", str(tmp_path / "a"), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "warning: chessboard:10x7:1.5" in err and "will find it in few poses, if any" in err
    assert main(["render", "target", "--preset", "paper", "--binning", "8", "--pattern", "chessboard:6x4:8",
                 "--poses", "1", "--lights", "flood", "--out", str(tmp_path / "b")]) == 0
    err = capsys.readouterr().err
    assert "pattern chessboard:6x4:8 on this rig (152 × 242 px)" in err and "warning" not in err


def test_a_view_of_the_identity_is_the_frame():
    img = (np.arange(40 * 60) % 251).astype(np.uint8).reshape(40, 60)
    view = PatternView("frame", np.eye(3), (60, 40))
    np.testing.assert_array_equal(view.warp(img), img)       # exact: integers (uint8 through the identity)


@pytest.mark.render
def test_the_answer_does_not_depend_on_what_opencv_drew_before_and_a_slanted_grid_is_not_a_board(tmp_path, variant):
    """``findChessboardCornersSB`` draws from OpenCV's global RNG: unseeded, a 5 × 4 grid was "found" in the
    first of these 6 × 5 boards' frames after 4 of 12 RNG states (2, 3, 4, 10; the full suite's state, not a
    lone test's), laid across the print at a slant in a rectified view.  Seeded per search, and such a grid
    refused because its outer ring of squares does not alternate, every state gives one answer: the 6 × 5
    board in every frame, the 5 × 4 in none."""
    flat = tmp_path / "flat"
    assert main(["render", "target", "--preset", "paper", "--pattern", "chessboard:6x5:12", "--binning", "4",
                 "--quiet", "--poses", "4", "--tilt-deg", "0", "--roll-deg", "0", "--off-sheet-mm", "0",
                 "--lights", "flood", "--depth-range-mm", "560:600", "--height-range-mm=-5:5",
                 "--out", str(flat)]) == 0
    ff = open_frame_folder(flat)
    frames = [ff.read(i) for i in range(len(ff))]
    sub, whole = parse_pattern("chessboard:5x4:12"), parse_pattern("chessboard:6x5:12")
    views = frame_views(ff.rig, (ff.rows, ff.columns), sub, ff.stripe_along)
    for seed in (2, 3, 4, 10):                   # the states that fooled the unseeded search
        cv2.setRNGSeed(seed)
        assert detect_pattern(frames[0], sub, views=views) is None, seed
    views = frame_views(ff.rig, (ff.rows, ff.columns), whole, ff.stripe_along)
    for seed in (0, 2):
        cv2.setRNGSeed(seed)
        assert all(detect_pattern(f, whole, views=views) is not None for f in frames), seed
