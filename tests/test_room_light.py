"""Pattern sets taken in room light (issue 38) and the pose bookkeeping of a pattern set (issue 34 items 6, 9).

The twin renders a set as users take it in a lit room (``render target --room-light``: the flood
light on in every frame at one exposure, the laser on in every second one).  References, none
from the calibration's code: the twin's exact laser plane (the rig's sheet in ``truth/rig_truth.json``'s
camera frame, as tests/test_target_calibration.py takes it), the frames themselves (how much the
laser raises the board), and the manifest's pose ids.  4 × 4-binned frames keep it fast; the
full-resolution figures are benchmarks/RESULTS.md's (``benchmarks/bench_room_light.py``).
"""

from __future__ import annotations

import json
import math
import shutil

import cv2
import numpy as np
import pytest

from scheimpflug.app.cli import main
from scheimpflug.calibration.target import calibrate_target_folder
from scheimpflug.errors import CalibrationError

PATTERN = "charuco:9x6:15:11"
ROOM_W_M2 = 170.0
FAST = {"tilt": "rig", "distortion": "none"}          # the pose bookkeeping needs no focus condition


def _truth_plane(folder):
    from scheimpflug.model.rig import rig_from_dict
    from sim.truth import opencv_laser_plane

    return opencv_laser_plane(rig_from_dict(json.loads((folder / "manifest.json").read_text())["rig"]))


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    out = tmp_path_factory.mktemp("room") / "set"
    assert main(["render", "target", "--preset", "paper", "--pattern", PATTERN, "--binning", "4", "--quiet",
                 "--poses", "6", "--depth-range-mm", "520:650", "--height-range-mm=-15:15",
                 "--room-light", f"{ROOM_W_M2:g}", "--out", str(out)]) == 0
    return out


def _edited(src, dst, edit):
    shutil.copytree(src, dst)
    (dst / "checksums.jsonl").unlink()              # an edited set: its frames' ledger no longer holds
    m = json.loads((dst / "manifest.json").read_text())
    edit(m, dst)
    (dst / "manifest.json").write_text(json.dumps(m))
    return dst


@pytest.mark.render
def test_a_room_light_set_is_taken_as_users_take_it(room, variant):
    m = json.loads((room / "manifest.json").read_text())
    assert m["scenario_params"]["room_light"] is True and m["scenario_params"]["room_light_w_m2"] == ROOM_W_M2
    frames = m["frames"]
    assert [f["light"] for f in frames[:4]] == ["flood", "both", "flood", "both"]
    assert len({f["exposure_ms"] for f in frames}) == 1                         # one exposure for both shots
    raised = []
    for flood, laser in zip(frames[::2], frames[1::2]):
        f = cv2.imread(str(room / flood["file"]), cv2.IMREAD_UNCHANGED).astype(float)
        g = cv2.imread(str(room / laser["file"]), cv2.IMREAD_UNCHANGED).astype(float)
        raised.append(g.max() / np.percentile(f, 99.9) - 1.0)
        # off the line the two photographs differ by the sensor's noise only (the same camera-pass estimate)
        assert np.median(np.abs(g - f)) < 0.05 * np.median(f)
    assert max(raised) <= 0.30          # the set: the laser raises the board's brightest pixels ≤ 30 %


@pytest.mark.render
def test_room_light_pairs_each_laser_frame_with_its_pose_and_finds_the_plane(room, tmp_path, capsys, variant):
    capsys.readouterr()
    assert main(["calibrate", str(room), "--method", "target", "--pattern", PATTERN, "--json", "--quiet"]) == 0
    d = json.loads(capsys.readouterr().out)
    rows = {r["pose"]: r for r in d["laser_poses"]}
    assert sorted(rows) == list(range(6))
    for k, r in rows.items():
        assert r["background"][0].startswith(f"its pose's flood frame frames/{2 * k:05d}.png"), r["background"]
        assert r["points_found"] >= r["points_on_line"] >= (r["points_in_plane_fit"] or 0)
    assert sum(r["points_in_plane_fit"] or 0 for r in rows.values()) == d["laser_points"]
    truth = _truth_plane(room)
    pl, se = np.array(d["laser_plane"]), d["stderr"]
    assert math.degrees(math.acos(min(1.0, pl[:3] @ truth[:3]))) < 3 * se["laser_plane_normal_deg"] + 0.02
    assert abs(pl[3] - truth[3]) < 3 * se["laser_plane_distance_mm"] + 0.02
    # poses whose line misses the printed pattern add nothing, and say so
    for r in rows.values():
        if r["points_on_line"] < 3:
            assert "adds nothing" in r["note"] and any(f"pose {r['pose']} " in w for w in d["warnings"])


@pytest.mark.render
def test_without_the_laser_off_frames_the_missing_line_is_said_per_pose(room, tmp_path, capsys, variant):
    out = tmp_path / "cal.json"
    capsys.readouterr()
    assert main(["calibrate", str(room), "--method", "target", "--pattern", PATTERN, "--laser-background", "none",
                 "--out", str(out), "--quiet"]) != 0
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err
    assert "no laser line on the pattern in any of the 6 laser frame(s)" in err and "laser off" in err
    assert "pose 0: frames/00001.png" in err and not out.exists()


@pytest.mark.render
def test_a_laser_frame_without_its_laser_off_partner_is_named_and_the_others_give_the_plane(room, tmp_path, variant):
    def drop_flood_of_pose_2(m, _):
        m["frames"] = [f for f in m["frames"] if not (f["pose"] == 2 and f["light"] == "flood")]

    folder = _edited(room, tmp_path / "orphan", drop_flood_of_pose_2)
    res = calibrate_target_folder(folder, PATTERN, **FAST)
    assert res.calibration.laser_plane is not None
    assert any("frames/00005.png: a laser frame without its laser-off partner" in w for w in res.warnings)
    assert 2 not in {r["pose"] for r in res.calibration.poses_used}


@pytest.mark.render
def test_pose_ids_repeated_and_moved_flood_frames(room, tmp_path, variant):
    def renumber(m, _):
        for f in m["frames"]:
            f["pose"] = 10 * f["pose"] + 7

    res = calibrate_target_folder(_edited(room, tmp_path / "ids", renumber), PATTERN, **FAST)
    assert {r["pose"] for r in res.calibration.poses_used} <= {7, 17, 27, 37, 47, 57}     # the manifest's ids
    assert {r["pose"] for r in res.laser_poses} == {7, 17, 27, 37, 47, 57}

    def repeat_pose_1(m, folder):                  # the same pose photographed twice (its own noise)
        img = cv2.imread(str(folder / "frames/00002.png"), cv2.IMREAD_UNCHANGED)
        noisy = np.clip(img + np.random.default_rng(1).normal(0, 3, img.shape), 0, 65535).astype(img.dtype)
        cv2.imwrite(str(folder / "frames/repeat.png"), noisy)
        m["frames"].append({**m["frames"][2], "file": "frames/repeat.png"})

    folder = _edited(room, tmp_path / "repeat", repeat_pose_1)
    res = calibrate_target_folder(folder, PATTERN, **FAST)
    assert 1 in {r["pose"] for r in res.calibration.poses_used}
    assert len(res.calibration.poses_used) + len(res.calibration.poses_skipped) == 6      # none dropped unsaid
    assert any("pose 1: 2 flood-lit frames" in w and "averaged" in w for w in res.warnings)

    def move_pose_4_into_pose_1(m, _):            # another pose labelled as pose 1: never dropped silently
        m["frames"] = [f for f in m["frames"] if not (f["pose"] == 4 and f["light"] != "flood")]
        for f in m["frames"]:
            f["pose"] = 1 if f["pose"] == 4 else f["pose"]

    with pytest.raises(CalibrationError, match="pose 1 has flood-lit frames showing the pattern in different places"):
        calibrate_target_folder(_edited(room, tmp_path / "moved", move_pose_4_into_pose_1), PATTERN, **FAST)


@pytest.mark.render
def test_a_wrong_square_size_is_warned_against_the_rigs_figures(room, variant):
    right = calibrate_target_folder(room, PATTERN, **FAST)
    wrong = calibrate_target_folder(room, "charuco:9x6:16:11.7333", **FAST)       # the print measured wrong
    assert not any("square size" in w for w in right.warnings)
    assert abs(right.nominal["plane_distance_mm"]["relative"]) < 0.02
    # every distance scales with the square: the plane's distance by 16/15 (the rig's sheet: d·cos φ)
    assert wrong.nominal["plane_distance_mm"]["relative"] == pytest.approx(16 / 15 - 1, abs=0.01)
    assert any("square size" in w and "plane's distance" in w for w in wrong.warnings)
    assert wrong.calibration.reprojection_rms_px == pytest.approx(right.calibration.reprojection_rms_px, rel=0.05)
