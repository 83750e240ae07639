"""Point-to-mesh distances against analytic distances (sphere, box), signs, statistics."""

import numpy as np
import pytest
import trimesh

from scheimpflug.errors import MeshError
from scheimpflug.scoring import (
    PointToMesh,
    body_labels,
    distance_stats,
    is_closed_mesh,
    point_to_mesh,
    score_points,
)


@pytest.fixture
def rng():
    return np.random.default_rng(5)


@pytest.fixture(scope="module")
def sphere():
    return trimesh.creation.icosphere(subdivisions=5, radius=20.0)   # 20480 faces


def _directions(rng, n):
    d = rng.normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def test_sphere_distance_within_sagitta(rng, sphere):
    # points at known radius: |d| = |r - R| up to the facets' sagitta (chord below the sphere)
    dirs = _directions(rng, 20000)
    r = rng.uniform(15, 25, len(dirs))
    res = point_to_mesh(dirs * r[:, None], sphere.vertices, sphere.faces)
    edge = sphere.edges_unique_length.max()
    sagitta = 20 - np.sqrt(20 ** 2 - (edge / np.sqrt(3)) ** 2)       # circumradius of the largest face
    assert res.signed
    assert np.all(np.abs(res.distance_mm - (r - 20)) <= sagitta + 1e-9)
    # the faceted surface is inside the sphere: distances are r - R or slightly more
    assert np.all(res.distance_mm - (r - 20) >= -1e-9)
    # outside the band between facets and sphere the sign is that of r - R
    clear = np.abs(r - 20) > sagitta
    assert np.all(np.sign(res.distance_mm[clear]) == np.sign(r[clear] - 20))


def test_box_exact_distances_and_signs(rng):
    box = trimesh.creation.box(extents=[40, 20, 10])
    pm = PointToMesh(box.vertices, box.faces)
    pts = rng.uniform(-30, 30, (5000, 3))
    half = np.array([20, 10, 5])
    q = np.abs(pts) - half
    outside = np.linalg.norm(np.maximum(q, 0), axis=1)
    inside = np.minimum(q.max(axis=1), 0)
    expected = outside + inside                        # analytic signed distance of a box
    res = pm.query(pts)
    np.testing.assert_allclose(res.distance_mm, expected, atol=1e-9)
    # closest points lie on the surface: their own distance is zero
    assert np.abs(pm.query(res.closest_mm).distance_mm).max() < 1e-9


def test_sign_near_edges_and_vertices():
    # points just outside the box's corners and edges: the face normal alone gives wrong signs here
    box = trimesh.creation.box(extents=[2, 2, 2])
    corners = np.array([[1, 1, 1], [-1, 1, -1], [1, -1, 0.0], [0.0, 1, 1]]) * 1.001
    res = point_to_mesh(corners, box.vertices, box.faces)
    assert np.all(res.distance_mm > 0)
    assert np.all(point_to_mesh(corners / 1.002, box.vertices, box.faces).distance_mm < 0)


def test_inverted_mesh_keeps_outside_positive(rng, sphere):
    dirs = _directions(rng, 200)
    res = point_to_mesh(dirs * 25, sphere.vertices, sphere.faces[:, ::-1])
    assert np.all(res.distance_mm > 0)


def test_open_mesh_is_unsigned(rng, sphere):
    faces = sphere.faces[1:]
    assert not is_closed_mesh(faces)
    res = point_to_mesh(_directions(rng, 100) * 10, sphere.vertices, faces)
    assert not res.signed and np.all(res.distance_mm > 0)


def test_matches_brute_force(rng):
    mesh = trimesh.creation.torus(major_radius=10, minor_radius=3)
    pts = rng.uniform(-15, 15, (300, 3))
    res = point_to_mesh(pts, mesh.vertices, mesh.faces)
    # brute force over every face with trimesh's vectorised closest point on triangles
    tri = mesh.triangles
    best = np.array([np.min(np.linalg.norm(
        trimesh.triangles.closest_point(tri, np.repeat(p[None], len(tri), 0)) - p, axis=1))
        for p in pts])
    np.testing.assert_allclose(np.abs(res.distance_mm), best, atol=1e-9)


def test_statistics_known_values():
    d = np.array([-3.0, 1.0, 1.0, -1.0])
    s = distance_stats(d, signed=True)
    assert s["n_points"] == 4
    assert s["rms_mm"] == pytest.approx(np.sqrt(12 / 4))
    assert s["mean_abs_mm"] == pytest.approx(1.5)
    assert s["max_mm"] == 3.0
    assert s["p95_mm"] == pytest.approx(np.percentile([3, 1, 1, 1], 95))
    assert s["mean_signed_mm"] == pytest.approx(-0.5)
    assert s["fraction_inside"] == 0.5
    assert "mean_signed_mm" not in distance_stats(d, signed=False)


def test_per_body_breakdown(rng):
    a = trimesh.creation.box(extents=[10, 10, 10])
    b = trimesh.creation.icosphere(subdivisions=3, radius=5.0)
    b.apply_translation([40, 0, 0])
    both = trimesh.util.concatenate([a, b])
    ids = np.r_[np.full(len(a.faces), 7), np.full(len(b.faces), 9)]
    pa = np.array([[5.5, 0, 0], [0, -5.5, 1]])                 # 0.5 mm outside the box
    pb = np.array([[40, 0, 5.2]])                               # ~0.2 mm outside the sphere
    out = score_points(np.vstack([pa, pb]), both.vertices, both.faces, face_object_id=ids)
    assert out["distance_kind"] == "signed"
    assert out["regions"]["7"]["n_points"] == 2
    assert out["regions"]["7"]["rms_mm"] == pytest.approx(0.5)
    assert out["regions"]["9"]["n_points"] == 1
    assert out["regions"]["9"]["max_mm"] == pytest.approx(0.2, abs=0.02)
    # without ids the connected bodies are found
    assert list(np.unique(body_labels(both.faces))) == [0, 1]
    out2 = score_points(np.vstack([pa, pb]), both.vertices, both.faces)
    assert out2["region_key"] == "body" and out2["regions"]["0"]["n_points"] == 2


@pytest.mark.parametrize("vertices, faces", [
    (np.zeros((0, 3)), np.zeros((0, 3), int)),
    (np.zeros((3, 3)), np.array([[0, 1, 5]])),
    (np.zeros((3, 2)), np.array([[0, 1, 2]])),
    (np.full((3, 3), np.nan), np.array([[0, 1, 2]])),
])
def test_bad_mesh_raises(vertices, faces):
    with pytest.raises(MeshError):
        PointToMesh(vertices, faces)


def test_bad_points_raise(sphere):
    with pytest.raises(ValueError):
        score_points(np.zeros((0, 3)), sphere.vertices, sphere.faces)
    with pytest.raises(ValueError):
        PointToMesh(sphere.vertices, sphere.faces).query(np.full((2, 3), np.nan))
