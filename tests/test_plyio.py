"""PLY point cloud round trip, mesh reading with object ids, bad files."""

import numpy as np
import pytest
import trimesh

from scheimpflug.errors import MeshError
from scheimpflug.io.ply import height_colors, read_mesh, read_point_cloud, write_point_cloud
from scheimpflug.reconstruct import PointCloud


def _cloud(rng, n=1000):
    return PointCloud(xyz_mm=rng.uniform(-100, 100, (n, 3)), angle_deg=rng.uniform(0, 360, n),
                      row=rng.integers(0, 1936, n), intensity=rng.uniform(0, 4000, n))


def test_round_trip(tmp_path, rng):
    cloud = _cloud(rng)
    path = write_point_cloud(tmp_path / "c.ply", cloud, comment="test\nsecond line")
    back = read_point_cloud(path)
    # float32 storage: relative precision 6e-8 → < 1e-5 mm at 100 mm
    np.testing.assert_allclose(back.xyz_mm, cloud.xyz_mm, atol=1e-5, rtol=0)
    np.testing.assert_allclose(back.angle_deg, cloud.angle_deg, rtol=1e-6)
    np.testing.assert_allclose(back.intensity, cloud.intensity, rtol=1e-6)
    assert np.array_equal(back.row, cloud.row)  # exact: integers
    assert np.all(back.frame == -1)                      # no frame index given: unknown
    # the binary layout: header + 31 bytes per point + 22 of the point quality (5 float, 2 uchar: the
    # saturation flag and the centre's σ of issue 34 among them)
    header_len = path.read_bytes().index(b"end_header\n") + len(b"end_header\n")
    assert path.stat().st_size == header_len + 53 * len(cloud)
    assert not list(tmp_path.glob(".*tmp*"))            # atomic write left no temporary


def test_readable_by_trimesh_with_colours(tmp_path, rng):
    cloud = _cloud(rng, 50)
    path = write_point_cloud(tmp_path / "c.ply", cloud)
    pc = trimesh.load(path)
    assert len(pc.vertices) == 50
    assert pc.colors.shape == (50, 4)


def test_height_colours_follow_height():
    z = np.linspace(-10, 10, 101)
    rgb = height_colors(z).astype(int)
    # viridis: low = dark purple (68, 1, 84), high = yellow (253, 231, 37)
    assert np.abs(rgb[0] - [68, 1, 84]).max() <= 3
    assert np.abs(rgb[-1] - [253, 231, 37]).max() <= 3
    assert rgb[:, 1].tolist() == sorted(rgb[:, 1].tolist())   # green rises monotonically in viridis


def test_empty_cloud_round_trip(tmp_path):
    empty = PointCloud(np.zeros((0, 3)), np.zeros(0), np.zeros(0, int), np.zeros(0))
    assert len(read_point_cloud(write_point_cloud(tmp_path / "e.ply", empty))) == 0


def test_ascii_cloud_with_only_xyz(tmp_path):
    path = tmp_path / "a.ply"
    path.write_text("ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
                    "property float z\nend_header\n1 2 3\n4 5 6\n")
    back = read_point_cloud(path)
    assert back.xyz_mm.tolist() == [[1, 2, 3], [4, 5, 6]]
    assert np.all(np.isnan(back.angle_deg)) and np.all(back.row == -1)


@pytest.mark.parametrize("content", [
    b"",
    b"not a ply at all",
    b"ply\nformat binary_little_endian 1.0\nelement vertex 10\nproperty float x\nproperty float y\n"
    b"property float z\nend_header\n" + b"\0" * 17,                      # truncated body
    b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\nend_header\n" + b"\0" * 4,
    b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\n",   # no end_header
])
def test_bad_cloud_files(tmp_path, content):
    path = tmp_path / "bad.ply"
    path.write_bytes(content)
    with pytest.raises(MeshError):
        read_point_cloud(path)


def test_missing_cloud(tmp_path):
    with pytest.raises(MeshError, match="does not exist"):
        read_point_cloud(tmp_path / "nope.ply")


def _ply_with_ids(path, mesh, ids):
    header = ("ply\nformat binary_little_endian 1.0\n"
              f"element vertex {len(mesh.vertices)}\nproperty double x\nproperty double y\n"
              f"property double z\nelement face {len(mesh.faces)}\n"
              "property list uchar int vertex_indices\nproperty int object_id\nend_header\n")
    faces = np.empty(len(mesh.faces), dtype=[("n", "u1"), ("v", "<i4", (3,)), ("id", "<i4")])
    faces["n"], faces["v"], faces["id"] = 3, mesh.faces, ids
    path.write_bytes(header.encode() + np.asarray(mesh.vertices, "<f8").tobytes() + faces.tobytes())


def test_read_mesh_with_object_ids(tmp_path):
    mesh = trimesh.creation.box(extents=[1, 2, 3])
    ids = np.arange(len(mesh.faces)) % 3 + 1
    _ply_with_ids(tmp_path / "m.ply", mesh, ids)
    v, f, got = read_mesh(tmp_path / "m.ply")
    np.testing.assert_array_equal(v, mesh.vertices)  # exact: copy
    np.testing.assert_array_equal(f, mesh.faces)
    np.testing.assert_array_equal(got, ids)  # exact: integers


def test_read_stl_has_no_ids(tmp_path):
    mesh = trimesh.creation.icosphere(subdivisions=1)
    mesh.export(tmp_path / "s.stl")
    v, f, ids = read_mesh(tmp_path / "s.stl")
    assert len(f) == 80 and ids is None


def test_read_mesh_bad_inputs(tmp_path):
    with pytest.raises(MeshError, match="does not exist"):
        read_mesh(tmp_path / "none.stl")
    (tmp_path / "junk.ply").write_bytes(b"ply\ngarbage")
    with pytest.raises(MeshError):
        read_mesh(tmp_path / "junk.ply")
    # a point cloud is not a mesh
    write_point_cloud(tmp_path / "cloud.ply",
                      PointCloud(np.eye(3), np.zeros(3), np.zeros(3, int), np.zeros(3)))
    with pytest.raises(MeshError, match="not a mesh"):
        read_mesh(tmp_path / "cloud.ply")
