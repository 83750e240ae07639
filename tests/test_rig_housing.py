"""A rig file's own housing (issue 35 item 5): ``[[housing.board]]`` or ``housing = "path"``, carried in
the :class:`Rig`, rendered by ``render rotary --rig`` without ``--housing``; refused together with
``--housing``, and refused when it hides the whole sheet from the camera (the board named).

The geometry of the hidden-sheet check is tested against segments whose crossing of a box is known
by construction.
"""

from __future__ import annotations

import json
import tomllib

import numpy as np
import pytest

from scheimpflug.app.cli import main
from scheimpflug.errors import RigError

BOARD = {"name": "back", "centre_mm": [0.0, 0.0, 100.0], "normal": [0.0, 0.0, -1.0], "length_dir": [1.0, 0.0, 0.0],
         "length_mm": 40.0, "width_mm": 20.0, "thickness_mm": 5.0}


def test_segments_blocked_by_a_board_known_by_construction():
    from scheimpflug.model.housing import housing_from_dict, segments_blocked

    (b,) = housing_from_dict({"board": [BOARD]})       # box x ∈ [−20, 20], y ∈ [−10, 10], z ∈ [100, 105]
    ends = np.array([[0.0, 0.0, 200.0],      # through the board
                     [0.0, 0.0, 100.0],      # ends on the face: seen, not blocked
                     [0.0, 0.0, 50.0],       # before it
                     [19.0, 9.0, 300.0],     # through, near the corner (x, y at z = 100: 6.3, 3)
                     [0.0, 40.0, 200.0],     # above it (y = 20 at z = 100)
                     [0.0, 0.0, 102.0]])     # inside its thickness
    assert segments_blocked(b, np.zeros(3), ends).tolist() == [True, False, False, True, False, True]


def test_check_sheet_seen_names_the_board():
    from scheimpflug.model.housing import check_sheet_seen, housing_from_dict

    boards = housing_from_dict({"board": [BOARD, {**BOARD, "name": "side", "centre_mm": [500.0, 0.0, 100.0]}]})
    far = np.array([[x, y, 300.0] for x in (-5.0, 5.0) for y in (-2.0, 2.0)])
    with pytest.raises(RigError, match="'back'"):
        check_sheet_seen(boards, np.zeros(3), far)
    check_sheet_seen(boards, np.zeros(3), np.vstack([far, [[0.0, 0.0, 80.0]]]))     # one point seen: fine


def test_rig_file_housing_inline_and_by_path(tmp_path, paper_rig):
    from scheimpflug.model.housing import housing_to_toml, load_housing
    from scheimpflug.model.rig import load_rig, rig_to_toml

    base = rig_to_toml(paper_rig)
    inline = tmp_path / "inline.toml"
    inline.write_text(base + "\n[[housing.board]]\n" + "\n".join(
        f"{k} = {json.dumps(v)}" for k, v in BOARD.items()) + "\n")
    rig = load_rig(inline)
    assert [b.name for b in rig.housing] == ["back"] and rig.housing[0].thickness_mm == 5.0
    assert rig.replace(lens={"f_number": 8.0}).housing == rig.housing         # kept by replace (binning)
    again = tmp_path / "again.toml"
    again.write_text(rig_to_toml(rig))                                         # written back, read back
    assert load_rig(again) == rig and load_rig(again).housing == rig.housing
    (tmp_path / "h").mkdir()
    (tmp_path / "h" / "walls.toml").write_text(housing_to_toml(rig.housing))
    by_path = tmp_path / "by_path.toml"
    by_path.write_text('housing = "h/walls.toml"\n' + base)
    assert load_rig(by_path) == rig and load_housing(tmp_path / "h" / "walls.toml") == rig.housing
    assert load_rig(tmp_path / "inline.toml") != paper_rig and paper_rig.housing == ()
    (tmp_path / "missing.toml").write_text('housing = "nowhere.toml"\n' + base)
    with pytest.raises(RigError, match="nowhere.toml"):
        load_rig(tmp_path / "missing.toml")
    (tmp_path / "bad.toml").write_text(base + "\n[[housing.board]]\nname = \"x\"\n")
    with pytest.raises(RigError, match=r"\[housing\].*normal is missing"):
        load_rig(tmp_path / "bad.toml")


@pytest.mark.render
def test_render_rotary_renders_the_rigs_housing(tmp_path, capsys, variant):
    """``render rotary --rig`` with ``[[housing.board]]``: the board stands in the frames (the truth's
    stripe on it), as with ``--housing``; both at once: one clear error; a board between the camera and
    the whole sheet: one clear error naming it, nothing written."""
    from scheimpflug.model.housing import Board, housing_to_toml
    from scheimpflug.model.rig import load_preset, rig_to_toml
    from sim.truth import opencv_laser_plane

    rig = load_preset("paper")
    plane = opencv_laser_plane(rig)                                     # n·X + d = 0, camera frame
    n = plane[:3] / np.linalg.norm(plane[:3])
    # a board across the sheet 700 mm down the optical axis, its face toward the camera: the sheet crosses it
    centre = np.array([0.0, 0.0, 700.0])
    centre -= (n @ centre + plane[3]) * n                               # on the sheet
    length = np.cross(n, [0.0, 0.0, 1.0])
    length /= np.linalg.norm(length)                                    # in the board, across the sheet
    normal = np.cross(length, np.cross([0.0, 0.0, 1.0], length))
    normal = normal / np.linalg.norm(normal) * (1.0 if normal @ centre < 0 else -1.0)
    wall = Board("wall", centre, normal, length, 400.0, 300.0)
    text = rig_to_toml(rig) + "\n" + housing_to_toml([wall]).replace("[[board]]", "[[housing.board]]")
    rig_path = tmp_path / "rig.toml"
    rig_path.write_text(text)
    out = tmp_path / "scan"
    assert main(["render", "rotary", "--rig", str(rig_path), "--part", "sphere", "--step-deg", "180", "--frames",
                 "1", "--binning", "8", "--out", str(out), "--quiet"]) == 0
    man = json.loads((out / "manifest.json").read_text())
    assert man["scenario_params"]["housing"]["file"] == "rig [housing]"
    ids = np.load(out / "truth" / "00000.npz")["stripe_object_id"]
    assert (ids == 101).sum() > 5                                        # the sheet lights the board
    (tmp_path / "h.toml").write_text(housing_to_toml([wall]))
    assert main(["render", "rotary", "--rig", str(rig_path), "--part", "sphere", "--step-deg", "180", "--frames",
                 "1", "--binning", "8", "--housing", str(tmp_path / "h.toml"), "--out", str(tmp_path / "both"),
                 "--quiet"]) != 0
    err = capsys.readouterr().err
    assert "--housing" in err and "[housing]" in err and "give one" in err and "internal" not in err
    assert not (tmp_path / "both").exists()
    # a board right in front of the lens, wider than the view: every ray to the sheet passes through it
    lid = Board("lid", np.array([0.0, 0.0, 5.0]), np.array([0.0, 0.0, -1.0]), np.array([1.0, 0.0, 0.0]),
                500.0, 500.0, 1.0)
    hidden = tmp_path / "hidden.toml"
    hidden.write_text(rig_to_toml(rig) + "\n" + housing_to_toml([lid]).replace("[[board]]", "[[housing.board]]"))
    with pytest.raises(RigError, match="hides the whole sheet.*'lid'"):
        from scheimpflug.model.rig import load_rig
        from sim.scenarios import rotary_scenario

        rotary_scenario(load_rig(hidden), part="sphere", step_deg=180.0, frames=1)
    assert main(["render", "rotary", "--rig", str(hidden), "--part", "sphere", "--step-deg", "180", "--frames", "1",
                 "--out", str(tmp_path / "hidden"), "--quiet"]) != 0
    err = capsys.readouterr().err.strip()
    assert "'lid'" in err and "internal" not in err and len(err.splitlines()) == 1
    assert not (tmp_path / "hidden").exists()


def test_rig_file_by_parts_holds_a_housing(tmp_path):
    """The form by parts keeps ``[[housing.board]]`` through ``rig_from_instrument`` and writes it back."""
    from scheimpflug.model.instrument_file import instrument_from_tables, rig_parts_text
    from scheimpflug.model.rig import load_rig

    text = """
[camera]
fx_px = 1000.0
fy_px = 1000.0
cx_px = 320.0
cy_px = 240.0
width_px = 640
height_px = 480
pixel_pitch_um = 5.0

[laser]
plane = { normal = [0.0, 0.6, 0.8], distance_mm = 200.0 }

[[housing.board]]
""" + "\n".join(f"{k} = {json.dumps(v)}" for k, v in {**BOARD, "centre_mm": [0.0, 0.0, 400.0]}.items()) + "\n"
    path = tmp_path / "parts.toml"
    path.write_text(text)
    rig = load_rig(path)
    assert [b.name for b in rig.housing] == ["back"]
    inst, _ = instrument_from_tables(tomllib.loads(text))
    again = tmp_path / "again.toml"
    again.write_text(rig_parts_text(rig, inst, "test"))
    assert load_rig(again).housing == rig.housing
