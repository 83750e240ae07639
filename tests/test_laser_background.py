"""A laser frame's laser-off frame (issue 38): the light check, the noise, the board, the line's points.

Synthetic frames with known noise, gain and line (no renderer); the real Ciclop/Horus frames of
``../shared/realdata/3dscanscience/laser-on-pattern`` where the folder exists (skipped, saying so,
where it does not).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from scheimpflug.app.cli import main
from scheimpflug.calibration.laser_background import (
    LINE_SIGMAS,
    board_mask,
    difference_noise,
    frame_noise_dn,
    line_points,
    noise_map,
    same_light,
    shared_fraction,
    within_board,
)

REAL = Path(__file__).resolve().parents[2] / "shared" / "realdata"
DSS = REAL / "3dscanscience"


def _scene(rng, shape=(240, 320), level=1500.0):
    """A lit board: a chessboard of 40 px squares (white 1, black 0.08) times ``level`` [DN]."""
    r, c = np.indices(shape)
    albedo = np.where(((r // 40) + (c // 40)) % 2 == 0, 1.0, 0.08)
    return level * albedo


def _line(shape, u0=150.3, slope=0.05, peak=300.0, sigma=1.2):
    r, c = np.indices(shape)
    return peak * np.exp(-0.5 * ((c - (u0 + slope * r)) / sigma) ** 2)


@pytest.mark.parametrize("sigma", [0.8, 4.0, 20.0])
def test_the_frames_own_noise_is_found_despite_its_print(sigma):
    rng = np.random.default_rng(3)
    frame = _scene(rng) + rng.normal(0, sigma, (240, 320))
    assert frame_noise_dn(frame) == pytest.approx(sigma, rel=0.1)        # the print's edges left out
    assert frame_noise_dn(np.zeros((50, 50))) == pytest.approx(1 / np.sqrt(12))   # quantisation at least


def test_the_same_light_is_told_from_another_exposure_and_another_view():
    rng = np.random.default_rng(4)
    scene = _scene(rng)
    noise = lambda: rng.normal(0, 12.0, scene.shape)                         # noqa: E731
    laser = scene + _line(scene.shape) + noise()
    assert same_light(laser, scene + noise()).agree                          # the pose's laser-off frame
    assert same_light(laser, scene + 0.3 * _scene(rng) + noise()).agree is False     # another exposure
    moved = np.roll(scene, 7, axis=1)
    verdict = same_light(laser, moved + noise())                             # the board moved between shots
    assert not verdict.agree and "beyond" in verdict.reason()
    dark = same_light(0.05 * scene + _line(scene.shape) + noise(), scene + noise())   # a dark laser frame
    assert not dark.agree and "brighter" in dark.reason()
    # the laser's own glow over the room does not break the pair
    glow = 15.0 * np.exp(-np.indices(scene.shape)[1] / 200.0)
    assert same_light(laser + glow, scene + noise()).agree


def test_the_noise_of_a_difference_grows_with_the_light_as_shot_noise_does():
    rng = np.random.default_rng(7)
    scene = _scene(rng, level=2000.0) + 20.0                                 # black squares 180, white 2020 DN
    sigma = lambda level: np.sqrt(4.0 + 0.5 * level)                         # noqa: E731  read + shot noise
    shot = lambda: scene + rng.normal(0.0, 1.0, scene.shape) * sigma(scene)  # noqa: E731
    laser, off = shot() + _line(scene.shape), shot()
    levels, sig = difference_noise(laser, off)
    # the difference of two frames: √2 σ(level); the line's pixels do not move the robust spread
    for lvl in (180.0, 2020.0):
        assert np.interp(lvl, levels, sig) == pytest.approx(np.sqrt(2) * sigma(lvl), rel=0.08)
    u, v = line_points(np.clip(laser - off, 0, None), noise_map(off, (levels, sig)))
    assert np.all(np.abs(u - (150.3 + 0.05 * v)) < 1.5)                     # the white squares' noise is no line


def test_the_line_is_found_in_the_difference_and_not_in_the_noise():
    rng = np.random.default_rng(5)
    scene = _scene(rng)
    laser, off = scene + _line(scene.shape) + rng.normal(0, 12, scene.shape), scene + rng.normal(0, 12, scene.shape)
    noise = np.hypot(frame_noise_dn(laser), frame_noise_dn(off))
    u, v = line_points(np.clip(laser - off, 0, None), noise)
    truth = 150.3 + 0.05 * v
    white = ((v // 40) + (np.rint(truth) // 40)) % 2 == 0
    assert len(u) > 0.4 * 240 and np.all(np.abs(u - truth) < 1.0)          # no noise peak taken for the line
    # where the line is bright: the centre of gravity of ±5 px with σ_diff = 17 DN on a 300 DN, σ = 1.2 px
    # line scatters by √(2·Σj²)·σ_diff / (peak·σ·√(2π)) ≈ 0.2 px (clipping at 0 adds a little)
    err = (u - truth)[white]
    assert np.sqrt(np.mean(err**2)) < 0.3 and abs(err.mean()) < 0.1
    # a line weaker than LINE_SIGMAS × the noise is not claimed
    faint = scene + _line(scene.shape, peak=2.0 * 12) + rng.normal(0, 12, scene.shape)
    assert len(line_points(np.clip(faint - off, 0, None), noise)[0]) < 0.1 * 240
    assert LINE_SIGMAS >= 5


def test_what_the_laser_off_frame_shows_too_is_not_the_laser():
    rng = np.random.default_rng(6)
    scene = _scene(rng)
    lit = scene + _line(scene.shape, peak=300) + rng.normal(0, 12, scene.shape)
    assert shared_fraction(lit, scene + rng.normal(0, 12, scene.shape)) > 0.2       # the print, row after row
    dark_laser = _line(scene.shape, peak=300) + rng.normal(0, 2, scene.shape)        # a dark room's laser frame
    assert shared_fraction(dark_laser, scene + rng.normal(0, 12, scene.shape)) < 0.05


def test_the_search_is_bounded_by_the_board_without_a_step_at_its_edge():
    img = np.zeros((60, 80))
    img[:, 20:60] = 50.0                                                    # the board's own level
    img[:, 5] = 400.0                                                       # the line on the floor beside it
    img[:, 40] += 100.0                                                     # the line on the board
    mask = board_mask([(20, -1), (59, -1), (59, 61), (20, 61)], img.shape)      # pixel centres, inclusive
    assert mask[:, 20:60].all() and not mask[:, :20].any() and not mask[:, 60:].any()
    bounded = within_board(img, mask)
    assert np.all(bounded[:, :20] == 50.0) and np.all(bounded[:, 60:] == 50.0)
    u, _ = line_points(bounded, 1.0)
    assert np.allclose(u, 40.0)                                             # not the floor's, not the edge
    assert np.array_equal(within_board(img.T, mask.T, "rows"), bounded.T)  # exact: copy (the same values moved)


@pytest.mark.skipif(not DSS.is_dir(), reason=f"real frames absent ({DSS}): see its README")
def test_the_ciclop_laser_on_pattern_frames_give_a_straight_line_on_the_pattern(tmp_path, capsys):
    """Horus's own frames: the chessboard poses give the camera, the laser-on-pattern pose its line."""
    lp = DSS / "laser-on-pattern"
    csv = tmp_path / "poses.csv"
    rows = [f"frame{k}.jpg,{k},flood" for k in range(6)]                  # 6 poses: enough for the camera
    rows += ["pattern.png,16,flood", "laser-0-255-255-8-x.png,16,laser",
             "laser-background-0-255-255-8-x.png,16,background"]
    csv.write_text("file,pose,light\n" + "\n".join(rows) + "\n")
    folder = tmp_path / "dss"
    cams = [str(DSS / "camera-calibration" / f"frame{k}.jpg") for k in range(6)]
    assert main(["import", *cams, str(lp / "pattern.png"),
                 str(lp / "laser-0-255-255-8-x.png"), str(lp / "laser-background-0-255-255-8-x.png"),
                 "--scenario", "target", "--positions", str(csv),
                 "--channel", "r", "--out", str(folder), "--quiet"]) == 0
    capsys.readouterr()
    # Horus's pattern: 11 × 6 inner corners, 13 mm squares (its settings' defaults)
    assert main(["calibrate", str(folder), "--method", "target", "--pattern", "chessboard:11x6:13",
                 "--distortion", "opencv5", "--refine", "subpix", "--json", "--quiet"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["laser_plane"] is None and any("one pose only (pose 16)" in w for w in d["warnings"])
    (row,) = d["laser_poses"]
    assert row["pose"] == 16 and row["background"][0].startswith("its laser-off frame")
    # measured: 740 found in the frame, 475 on the printed pattern, 419 on one straight line 91 mm long,
    # 0.050 mm median and 0.084 mm RMS from it (one of the two lasers' lines on the board)
    assert row["points_on_line"] > 300 and row["line_residual_mm"]["length"] > 60
    assert row["line_residual_mm"]["median"] < 0.1 and row["line_residual_mm"]["rms"] < 0.15
    assert row["points_found"] > row["points_on_board"] >= row["points_on_line"]
