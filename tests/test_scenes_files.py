"""scenes/: presets by name, user mesh files, scene TOML files, truth PLY, errors and warnings."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import pytest
import trimesh

import scenes
from scheimpflug.errors import MeshError

EXAMPLES = Path(scenes.__file__).parent / "examples"


def _write_box_stl(path: Path, scale: float = 1.0, drop_face: bool = False, shift=(0, 0, 0)) -> Path:
    box = trimesh.creation.box(bounds=[[0, 0, 0], [10 * scale, 20 * scale, 30 * scale]])
    box.apply_translation(np.asarray(shift, dtype=float) * scale)
    if drop_face:
        box = trimesh.Trimesh(box.vertices, box.faces[1:], process=False)
    box.export(path)
    return path


# ---------------------------------------------------------------- presets

def test_part_names_are_sorted_and_complete():
    assert scenes.PART_NAMES == tuple(sorted(scenes.PART_NAMES))
    assert set(scenes.PART_NAMES) == {"plate", "cylinder", "knurled-ring", "box", "tape", "pile",
                                      "blocker", "sphere", "ball-bar"}


def test_unknown_part_lists_the_known_ones():
    with pytest.raises(MeshError, match="unknown part 'gear'.*ball-bar.*tape"):
        scenes.load_part("gear")


def test_preset_overrides_and_bad_parameters():
    asm = scenes.load_part("box", height_mm=40.0, material="metal")
    assert asm.parts[0].analytic["height_mm"] == 40.0 and asm.parts[0].material == "metal"
    with pytest.raises(MeshError, match="unknown parameter 'colour'"):
        scenes.load_part("box", colour="red")
    with pytest.raises(MeshError, match="height_mm = -1"):
        scenes.load_part("box", height_mm=-1)
    with pytest.raises(MeshError, match="unknown material 'wood'"):
        scenes.load_part("plate", material="wood")
    with pytest.raises(MeshError, match="units"):
        scenes.load_part("plate", units="inch")


def test_axis_offset_shifts_the_assembly():
    asm = scenes.load_part("blocker", axis_offset_mm=(3.0, -2.0))
    np.testing.assert_allclose(asm.bounds_mm[:, :2], [[-4.0, -28.0], [-2.0, 32.0]], atol=1e-12)


# ---------------------------------------------------------------- user meshes

@pytest.mark.parametrize("units, scale", [("mm", 1.0), ("m", 1e-3), ("inch", 1 / 25.4)])
def test_mesh_file_units(tmp_path, units, scale):
    path = _write_box_stl(tmp_path / "box.stl", scale)
    asm = scenes.load_part(path, units=units)
    np.testing.assert_allclose(asm.bounds_mm, [[0, 0, 0], [10, 20, 30]], atol=1e-6)
    assert asm.parts[0].mesh.volume == pytest.approx(6000.0, rel=1e-6)


@pytest.mark.parametrize("suffix", [".ply", ".obj"])
def test_mesh_file_formats_and_axis_offset(tmp_path, suffix):
    path = _write_box_stl(tmp_path / f"box{suffix}")
    asm = scenes.load_part(path, axis_offset_mm=(5.0, 10.0), material="cardboard")
    np.testing.assert_allclose(asm.bounds_mm, [[-5, -10, 0], [5, 10, 30]], atol=1e-9)
    assert asm.parts[0].material == "cardboard" and asm.parts[0].analytic["kind"] == "mesh"


def test_bad_mesh_files(tmp_path):
    empty = tmp_path / "empty.stl"
    empty.write_bytes(b"")
    garbage = tmp_path / "garbage.stl"
    garbage.write_bytes(bytes(np.random.default_rng(0).integers(0, 256, 100, dtype=np.uint8)))
    text = tmp_path / "notes.txt"
    text.write_text("not a mesh")
    cloud = tmp_path / "cloud.ply"
    trimesh.PointCloud(np.random.default_rng(1).random((50, 3))).export(cloud)
    with pytest.raises(MeshError, match="empty.stl: file is empty"):
        scenes.load_part(empty)
    with pytest.raises(MeshError, match="garbage.stl: cannot read as STL"):
        scenes.load_part(garbage)
    with pytest.raises(MeshError, match="unknown part .*notes.txt"):
        scenes.load_part(text)
    with pytest.raises(MeshError, match="notes.txt: not a mesh file"):
        scenes.load_mesh(text)
    with pytest.raises(MeshError, match="missing.obj: no such file"):
        scenes.load_part(tmp_path / "missing.obj")
    with pytest.raises(MeshError, match="cloud.ply: .*no triangles"):
        scenes.load_part(cloud)


def test_non_watertight_and_floating_meshes_warn(tmp_path):
    holey = _write_box_stl(tmp_path / "holey.stl", drop_face=True)
    with pytest.warns(scenes.MeshWarning, match="not watertight"):
        asm = scenes.load_part(holey)
    assert asm.parts[0].analytic["watertight"] is False
    floating = _write_box_stl(tmp_path / "floating.stl", shift=(0, 0, 4))
    with pytest.warns(scenes.MeshWarning, match="lowest point is at z = 4"):
        scenes.load_part(floating)
    good = _write_box_stl(tmp_path / "good.stl")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        scenes.load_part(good)


# ---------------------------------------------------------------- truth PLY

def test_to_ply_round_trip_with_object_ids(tmp_path):
    asm = scenes.load_scene(EXAMPLES / "pile_variations.toml", seed=2)
    out = asm.to_ply(tmp_path / "truth" / "mesh.ply")
    mesh, ids = scenes.read_ply(out)
    np.testing.assert_array_equal(mesh.vertices, asm.combined_mesh().vertices)  # exact: copy
    np.testing.assert_array_equal(mesh.faces, asm.combined_mesh().faces)
    counts = np.bincount(ids)
    assert counts[0] == 0 and [counts[p.object_id] for p in asm.parts] == [p.triangle_count for p in asm.parts]
    assert sorted(p.name for p in (tmp_path / "truth").iterdir()) == ["mesh.ply"]  # no temp left
    stage_from_part = scenes.yaw_matrix(30.0, (0.0, 179.45, -70.0))
    moved = asm.transformed(stage_from_part)
    np.testing.assert_allclose(moved.parts[0].mesh_from_part, stage_from_part @ asm.parts[0].mesh_from_part)


# ---------------------------------------------------------------- scene files

def test_example_scene_same_seed_same_mesh_other_seed_other_mesh():
    a = scenes.load_scene(EXAMPLES / "pile_variations.toml", seed=7)
    b = scenes.load_part(EXAMPLES / "pile_variations.toml", seed=7)
    c = scenes.load_scene(EXAMPLES / "pile_variations.toml", seed=8)
    for pa, pb in zip(a.parts, b.parts):
        np.testing.assert_array_equal(pa.mesh.vertices, pb.mesh.vertices)  # exact: same run
        np.testing.assert_array_equal(pa.mesh.faces, pb.mesh.faces)
    assert not np.array_equal(a.parts[0].mesh.vertices[:100], c.parts[0].mesh.vertices[:100]) \
        or a.parts[0].mesh.vertices.shape != c.parts[0].mesh.vertices.shape
    ring, box, tape = a.parts
    assert 12.0 <= ring.analytic["height_mm"] <= 18.0
    assert box.mesh.bounds[0, 2] == pytest.approx(ring.mesh.bounds[1, 2], abs=1e-12)  # on = "ring"
    assert tape.mesh.bounds[0, 2] == pytest.approx(box.mesh.bounds[1, 2], abs=1e-12)
    assert [p.object_id for p in a.parts] == [1, 2, 3]
    assert all(p.mesh.is_watertight for p in a.parts)


def test_variation_of_one_part_leaves_the_others(tmp_path):
    base = (EXAMPLES / "pile_variations.toml").read_text()
    edited = base.replace("width_mm = [40.0, 50.0]", "width_mm = [30.0, 35.0]")
    assert edited != base
    (tmp_path / "edited.toml").write_text(edited)
    a = scenes.load_scene(EXAMPLES / "pile_variations.toml", seed=1)
    b = scenes.load_scene(tmp_path / "edited.toml", seed=1)
    np.testing.assert_array_equal(a.parts[0].mesh.vertices, b.parts[0].mesh.vertices)  # exact: same run
    assert b.parts[2].analytic["width_mm"] < 35.0 <= 40.0 <= a.parts[2].analytic["width_mm"]


def test_scene_with_a_mesh_file_and_a_pose(tmp_path):
    _write_box_stl(tmp_path / "bracket.stl", scale=1e-3)
    (tmp_path / "scene.toml").write_text(
        'name = "s"\n[[parts]]\nmesh = "bracket.stl"\nunits = "m"\nposition_mm = [1, 2, 0]\n'
        'yaw_deg = 90.0\nmaterial = "tape"\n')
    asm = scenes.load_part(tmp_path / "scene.toml")
    (p,) = asm.parts
    assert p.name == "bracket" and p.material == "tape" and asm.name == "s"
    # box [0,10]×[0,20] turned 90° → x ∈ [−20, 0], y ∈ [0, 10]; then moved by (1, 2)
    np.testing.assert_allclose(asm.bounds_mm, [[-19, 2, 0], [1, 12, 30]], atol=1e-9)


@pytest.mark.parametrize("body, message", [
    ("[[parts]]\npreset = 'box'\ncolour = 'red'\n", "unknown key 'colour'"),
    ("[[parts]]\npreset = 'gear'\n", "unknown preset 'gear'"),
    ("[[parts]]\npreset = 'box'\nmesh = 'a.stl'\n", "exactly one of 'preset' or 'mesh'"),
    ("[[parts]]\npreset = 'box'\n[variation.ring]\nheight_mm = [1, 2]\n", r"\[variation.ring\] names no part"),
    ("[[parts]]\npreset = 'box'\n[variation.box]\nheight_mm = [5, 1]\n", "need finite lo <= hi"),
    ("[[parts]]\npreset = 'box'\non = 'table'\n", "on = 'table' is not an earlier part"),
    ("[[parts]]\npreset = 'box'\n[parts.params]\nheight_mm = -3\n", "part 'box': height_mm = -3"),
    ("[[parts]]\nmesh = 'nothere.stl'\n", "nothere.stl: no such file"),
    ("parts = 3\n", r"at least one \[\[parts\]\]"),
    ("[[parts]\n", "not a valid TOML scene"),
])
def test_bad_scene_files(tmp_path, body, message):
    path = tmp_path / "bad.toml"
    path.write_text(body)
    with pytest.raises(MeshError, match=message):
        scenes.load_scene(path)


def test_cylinder_example_is_offset():
    asm = scenes.load_part(EXAMPLES / "cylinder.toml")
    np.testing.assert_allclose(asm.bounds_mm, [[-45, -50, 0], [55, 50, 108]], atol=1e-9)
    assert math.isclose(asm.parts[0].analytic["knurl"]["helix_deg"], 30.0)


def test_read_ply_reads_plain_and_corrupt_files(tmp_path):
    plain = tmp_path / "plain.ply"
    trimesh.creation.box(bounds=[[0, 0, 0], [1, 2, 3]]).export(plain)
    mesh, ids = scenes.read_ply(plain)
    assert len(mesh.faces) == 12 and np.all(ids == 1)
    asm = scenes.load_part("plate")
    good = asm.to_ply(tmp_path / "good.ply")
    cut = tmp_path / "cut.ply"
    cut.write_bytes(good.read_bytes()[:-10])
    with pytest.raises(MeshError, match="cut.ply: cannot read PLY"):
        scenes.read_ply(cut)
