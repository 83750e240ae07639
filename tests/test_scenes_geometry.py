"""scenes/: generated parts against closed-form dimensions, volumes, areas, knurl geometry and sections."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

import scenes
from scenes.revolve import segments_for_sagitta


def _polygon_area(r, n):
    """Area of a regular n-gon inscribed in a circle of radius r."""
    return 0.5 * n * r * r * math.sin(2 * math.pi / n)


# ---------------------------------------------------------------- boxes and plates

def test_plate_follows_the_frame_convention():
    p = scenes.plate(120.0, 89.0, 5.0)
    np.testing.assert_allclose(p.mesh.bounds, [[0, -60, 0], [5, 60, 89]], atol=0)
    assert p.analytic["measured_face_x_mm"] == 0.0 and p.analytic["height_mm"] == 89.0
    assert p.mesh.volume == pytest.approx(120 * 89 * 5, rel=1e-12)
    assert p.mesh.area == pytest.approx(2 * (120 * 89 + 120 * 5 + 89 * 5), rel=1e-12)
    # the face at x = 0 points to -x (towards the laser)
    at0 = np.all(np.abs(p.mesh.vertices[p.mesh.faces][:, :, 0]) < 1e-12, axis=1)
    np.testing.assert_allclose(p.mesh.face_normals[at0], [[-1, 0, 0]] * at0.sum(), atol=1e-12)


def test_blocker_is_centred_on_the_axis_and_exposes_its_thickness():
    b = scenes.blocker(thickness_mm=2.0)
    np.testing.assert_allclose(b.mesh.bounds[:, 0], [-1.0, 1.0], atol=0)
    assert b.analytic["thickness_mm"] == 2.0 and b.analytic["laser_face_x_mm"] == -1.0
    assert b.mesh.bounds[0, 2] == 0.0


def test_box_dimensions_volume_area():
    b = scenes.box(252, 165, 62)
    np.testing.assert_allclose(np.ptp(b.mesh.bounds, axis=0), [252, 165, 62], atol=1e-12)
    assert b.mesh.volume == pytest.approx(252 * 165 * 62, rel=1e-12)
    assert b.mesh.area == pytest.approx(2 * (252 * 165 + 252 * 62 + 165 * 62), rel=1e-12)
    assert b.material == "cardboard"


# ---------------------------------------------------------------- bodies of revolution

def test_segments_for_sagitta_matches_the_chord_formula():
    n = segments_for_sagitta(50.0, 1e-3, multiple=1)
    assert n == 497  # π / acos(1 − 1e-3/50) = 496.7
    assert 50 * (1 - math.cos(math.pi / n)) <= 1e-3 < 50 * (1 - math.cos(math.pi / (n - 1)))


def test_cylinder_volume_area_and_sagitta():
    c = scenes.cylinder(100.0, 108.0)
    n = c.analytic["segments"]
    assert c.mesh.is_watertight and c.mesh.is_winding_consistent
    assert c.mesh.volume == pytest.approx(math.pi * 50**2 * 108, rel=5e-3)  # acceptance: 0.5 %
    assert c.mesh.volume == pytest.approx(_polygon_area(50, n) * 108, rel=1e-10)
    side = n * 2 * 50 * math.sin(math.pi / n) * 108
    assert c.mesh.area == pytest.approx(2 * _polygon_area(50, n) + side, rel=1e-10)
    assert c.mesh.area == pytest.approx(2 * math.pi * 50 * (50 + 108), rel=1e-5)
    assert 50 * (1 - math.cos(math.pi / n)) <= 1e-4  # documented 0.1 µm sagitta
    r = np.hypot(*c.mesh.vertices[:, :2].T)
    assert np.all((np.abs(r - 50) < 1e-9) | (r < 1e-9))


def test_tape_roll_volume_and_area():
    t = scenes.tape_roll(120.0, 76.0, 48.0)
    assert t.mesh.is_watertight and t.mesh.is_winding_consistent
    assert t.mesh.volume == pytest.approx(math.pi * (60**2 - 38**2) * 48, rel=1e-5)
    area = 2 * math.pi * (60 + 38) * 48 + 2 * math.pi * (60**2 - 38**2)
    assert t.mesh.area == pytest.approx(area, rel=1e-5)
    np.testing.assert_allclose(t.mesh.bounds, [[-60, -60, 0], [60, 60, 48]], atol=1e-9)


@pytest.mark.parametrize("stand", [0.0, 30.0])
def test_sphere_is_inscribed_within_its_sagitta(stand):
    s = scenes.sphere(25.4, stand_height_mm=stand)
    c, R = np.array(s.analytic["centre_mm"]), 12.7
    assert s.mesh.is_watertight
    assert s.mesh.bounds[0, 2] == pytest.approx(0.0, abs=1e-12)
    if stand == 0.0:
        d = np.linalg.norm(s.mesh.vertices - c, axis=1)
        np.testing.assert_allclose(d, R, atol=1e-9)
        # inscribed polyhedron: every face plane lies between R − sagitta and R
        sag = R - np.min(np.abs(np.einsum("ij,ij->i", s.mesh.face_normals, s.mesh.triangles_center - c)))
        assert 0 < sag <= 1e-3  # documented default: 1 µm
        v = 4 / 3 * math.pi
        assert v * (R - sag) ** 3 <= s.mesh.volume <= v * R**3
        assert 4 * math.pi * (R - sag) ** 2 <= s.mesh.area <= 4 * math.pi * R**2


def test_ball_bar_centre_distance():
    bb = scenes.ball_bar(20.0, 100.0)
    c = np.array(bb.analytic["centres_mm"])
    assert np.linalg.norm(c[1] - c[0]) == pytest.approx(100.0, abs=1e-12)
    v = bb.mesh.vertices
    on_sphere = [np.abs(np.linalg.norm(v - ci, axis=1) - 10.0) < 1e-9 for ci in c]
    assert on_sphere[0].sum() > 1000 and on_sphere[1].sum() > 1000
    assert bb.mesh.is_watertight  # every shell closed (spheres and posts)


# ---------------------------------------------------------------- knurls

@pytest.fixture(scope="module")
def small_knurl():
    """A 30 mm high Ø100 cylinder with a 10 mm diamond band from z = 5 (small but full resolution)."""
    return scenes.knurled_cylinder(100.0, 30.0, band_z0_mm=5.0, band_height_mm=10.0,
                                   pitch_mm=1.0, depth_mm=0.4, helix_deg=30.0)


def test_knurl_pitch_is_snapped_to_close_the_circle(small_knurl):
    k = small_knurl.analytic["knurl"]
    n = round(2 * math.pi * 50 * math.cos(math.radians(30)) / 1.0)
    assert k["teeth_around"] == n == 272
    assert k["pitch_mm"] == pytest.approx(2 * math.pi * 50 * math.cos(math.radians(30)) / n, rel=1e-14)


def test_knurled_cylinder_is_watertight_with_exact_smooth_parts(small_knurl):
    m = small_knurl.mesh
    assert m.is_watertight and m.is_winding_consistent and m.volume > 0
    np.testing.assert_allclose(m.bounds, [[-50, -50, 0], [50, 50, 30]], atol=1e-9)
    assert small_knurl.analytic["smooth_z_ranges_mm"] == [[0.0, 5.0], [15.0, 30.0]]


@pytest.mark.parametrize("pattern, helix, mean_w, mean_w2", [
    ("diamond", 30.0, 2 / 3, 1 / 2),   # w = 1 − min(U, V), U, V uniform: E w = 2/3, E w² = 1/2
    ("straight", 0.0, 1 / 2, 1 / 3),   # w = 1 − U: E w = 1/2, E w² = 1/3
])
def test_knurl_removed_volume_matches_the_height_field_mean(pattern, helix, mean_w, mean_w2):
    R, H, band, d = 50.0, 30.0, 10.0, 0.4  # band = 5 axial periods (p / sin 30° = 2 mm)
    part = scenes.knurled_cylinder(2 * R, H, band_z0_mm=5.0, band_height_mm=band, pattern=pattern,
                                   helix_deg=helix, pitch_mm=1.0, depth_mm=d)
    n = part.analytic["segments"]
    removed = _polygon_area(R, n) * H - part.mesh.volume
    # per unit height: ∫ (R² − r²)/2 dθ = π E[2 R δ − δ²], δ = d w
    expected = math.pi * (2 * R * d * mean_w - d * d * mean_w2) * band
    assert removed == pytest.approx(expected, rel=2e-3)


def test_knurl_mesh_equals_the_analytic_height_field(small_knurl):
    spec = small_knurl.analytic["knurl"]
    m = small_knurl.mesh
    z0, z1 = spec["band_z_range_mm"]
    tri = m.triangles
    inside = np.all((tri[:, :, 2] > z0 - 1e-9) & (tri[:, :, 2] < z1 - 0.2), axis=1)
    inside &= np.abs(m.face_normals[:, 2]) < 0.9  # the knurled wall, not the horizontal shoulder
    v = tri[inside].reshape(-1, 3)
    r_true = scenes.knurl_radius_mm(np.arctan2(v[:, 1], v[:, 0]), v[:, 2], spec)
    np.testing.assert_allclose(np.hypot(v[:, 0], v[:, 1]), r_true, atol=1e-9)
    # random points on the facets: the chosen diagonals follow the surface
    rng = np.random.default_rng(5)
    faces = rng.choice(np.flatnonzero(inside), 20000)
    w = rng.dirichlet([1, 1, 1], len(faces))
    p = np.einsum("ij,ijk->ik", w, tri[faces])
    r_true = scenes.knurl_radius_mm(np.arctan2(p[:, 1], p[:, 0]), p[:, 2], spec)
    # Bound: chord sagitta R dθ²/8 (1.7e-5 mm) plus the polar-angle shift of a point on a planar
    # facet whose vertices differ in radius (δθ ≤ Δr dθ / r ≈ 0.11 · 0.00165 / 49.6 rad) times
    # dr/dθ ≤ 2 d R cos α / p ≈ 35 mm/rad: ≈ 1.3e-4 mm.  A wrong diagonal at a groove or crest
    # would be off by ~1e-2 mm.
    err = np.hypot(p[:, 0], p[:, 1]) - r_true
    assert np.all(np.abs(err) <= 1.5e-4)


def test_knurl_edges_are_small_compared_with_the_sheet(small_knurl):
    spec = small_knurl.analytic["knurl"]
    tri = small_knurl.mesh.triangles
    z0, z1 = spec["band_z_range_mm"]
    inside = np.all((tri[:, :, 2] > z0 + 1e-9) & (tri[:, :, 2] < z1 - 1e-9), axis=1)
    # grid spacing along the arc and along z ≤ max_edge_mm = 0.15 mm
    th = np.unique(np.round(np.arctan2(tri[inside, :, 1], tri[inside, :, 0]), 12))
    zs = np.unique(np.round(tri[inside, :, 2], 12))
    assert 50 * np.max(np.diff(th)) <= 0.15 and np.max(np.diff(zs)) <= 0.15
    # 3-D edges (with the flank slope) stay below the sheet's ≈ 0.3 mm full 1/e² thickness
    e = np.linalg.norm(tri[inside] - np.roll(tri[inside], 1, axis=1), axis=2)
    assert e.max() <= 0.25


def _crests(values, top, tol=1e-5):
    return values >= top - tol


def test_knurl_pitch_depth_and_helix_measured_back_from_sections(small_knurl):
    """Axial section through a crest column: triangle wave of period p/sin α and depth d;
    horizontal section where a = b: triangle wave with N crests around; tan α = p_c / p_z."""
    R, d = 50.0, 0.4
    seg = scenes.sheet_section(small_knurl.mesh, angle_deg=1e-7)  # half plane θ ≈ 0, x > 0
    pts = seg.reshape(-1, 2)
    pts = pts[(pts[:, 0] > 0) & (pts[:, 1] > 5.0) & (pts[:, 1] < 15.0)]
    pts = pts[np.argsort(pts[:, 1])]
    r = pts[:, 0]
    assert r.max() - r.min() == pytest.approx(d, abs=1e-5)                       # depth
    zc = pts[_crests(r, R), 1]
    zc = zc[np.r_[True, np.diff(zc) > 1e-3]]
    p_z = np.median(np.diff(zc))
    # horizontal section at z = z0 + p_z, just above the grid row
    z_cut = 5.0 + p_z + 1e-7
    ring = trimesh.intersections.mesh_plane(small_knurl.mesh, [0, 0, 1], [0, 0, z_cut]).reshape(-1, 3)
    rr, th = np.hypot(ring[:, 0], ring[:, 1]), np.arctan2(ring[:, 1], ring[:, 0])
    assert rr.max() - rr.min() == pytest.approx(d, abs=1e-5)
    n_teeth = len(np.unique(np.round(th[_crests(rr, R)] * 1e5)))
    p_c = 2 * math.pi * R / n_teeth
    helix = math.degrees(math.atan(p_c / p_z))
    pitch = p_c * math.cos(math.radians(helix))
    assert n_teeth == 272
    assert helix == pytest.approx(30.0, abs=0.05)
    assert pitch == pytest.approx(1.0, rel=2e-3)  # snapped to 272 teeth: 1.00026


def test_sheet_section_of_the_knurl_equals_the_analytic_profile(small_knurl):
    spec = small_knurl.analytic["knurl"]
    angle = 17.3
    pts = scenes.sheet_section(small_knurl.mesh, angle).reshape(-1, 2)
    band = pts[(pts[:, 0] > 0) & (pts[:, 1] > 5.0 + 1e-6) & (pts[:, 1] < 15.0 - 0.2)]
    # a point (x, z) of the sheet at stage angle A is at part angle −A, radius x
    r_true = scenes.knurl_radius_mm(math.radians(-angle), band[:, 1], spec)
    assert len(band) > 100
    np.testing.assert_allclose(band[:, 0], r_true, atol=1.5e-4)  # bound: see the facet test above


def test_sheet_section_of_an_offset_cylinder_at_a_known_angle():
    R, (ex, ey), angle = 50.0, (12.0, -7.0), 37.0
    part = scenes.cylinder(2 * R, 60.0).posed((ex, ey, 0.0))
    pts = scenes.sheet_section(part.mesh, angle).reshape(-1, 2)
    wall = pts[(pts[:, 1] > 1e-6) & (pts[:, 1] < 60 - 1e-6)]
    a = math.radians(angle)
    cx, cy = ex * math.cos(a) - ey * math.sin(a), ex * math.sin(a) + ey * math.cos(a)
    half = math.sqrt(R**2 - cy**2)  # the plane y = 0 cuts the circle at x = cx ± sqrt(R² − cy²)
    expected = np.where(wall[:, 0] > cx, cx + half, cx - half)
    sag = R * (1 - math.cos(math.pi / part.analytic["segments"]))
    np.testing.assert_allclose(wall[:, 0], expected, atol=2 * sag)
    assert np.any(wall[:, 0] > cx) and np.any(wall[:, 0] < cx)


# ---------------------------------------------------------------- presets

@pytest.fixture(scope="module")
def cylinder_preset():
    return scenes.load_part("cylinder")


def test_cylinder_preset_is_the_papers(cylinder_preset):
    (p,) = cylinder_preset.parts
    a = p.analytic
    assert (a["diameter_mm"], a["height_mm"]) == (100.0, 108.0)
    assert a["smooth_z_range_mm"] == [20.0, 108.0]
    assert a["knurl"]["band_z_range_mm"] == [0.0, 20.0] and a["knurl"]["pattern"] == "diamond"
    assert p.mesh.is_watertight
    np.testing.assert_allclose(cylinder_preset.bounds_mm, [[-50, -50, 0], [50, 50, 108]], atol=1e-9)
    assert p.mesh.volume == pytest.approx(math.pi * 50**2 * 108, rel=5e-3)
    s = cylinder_preset.summary()
    assert s["mesh_bytes"] < 100e6 and s["triangles"] < 2_000_000


def test_pile_stacks_ring_box_tape_off_centre():
    pile = scenes.load_part("pile")
    ring, box, tape = pile.parts
    assert [p.object_id for p in pile.parts] == [1, 2, 3]
    assert (ring.material, box.material, tape.material) == ("knurled-metal", "cardboard", "tape")
    assert ring.analytic["od_mm"] == 69.0 and tape.analytic["od_mm"] == 120.0
    assert (box.analytic["length_mm"], box.analytic["width_mm"], box.analytic["height_mm"]) == (252, 165, 62)
    assert ring.mesh.bounds[0, 2] == 0.0
    assert box.mesh.bounds[0, 2] == pytest.approx(ring.mesh.bounds[1, 2], abs=1e-12)
    assert tape.mesh.bounds[0, 2] == pytest.approx(box.mesh.bounds[1, 2], abs=1e-12)
    assert 115 <= pile.bounds_mm[1, 2] <= 135
    # unbalanced: the box's centre is not over the ring's axis
    ring_c = np.array(ring.mesh_from_part)[:2, 3]
    box_c = np.array(box.mesh_from_part)[:2, 3]
    assert np.linalg.norm(box_c - ring_c) > 30
    # the tape rests fully on the box: its footprint lies inside the box top (box frame)
    box_from_asm = np.linalg.inv(box.mesh_from_part)
    t = (box_from_asm @ np.r_[tape.mesh_from_part[:2, 3], 0, 1])[:2]
    assert abs(t[0]) + 60 <= 126 and abs(t[1]) + 60 <= 82.5


@pytest.mark.parametrize("name", ["plate", "box", "tape", "blocker", "sphere", "ball-bar", "knurled-ring"])
def test_presets_are_watertight_and_stand_on_the_table(name):
    asm = scenes.load_part(name)
    for p in asm.parts:
        assert p.mesh.is_watertight, p.name
        assert p.material in scenes.MATERIALS
    assert asm.bounds_mm[0, 2] == pytest.approx(0.0, abs=1e-12)


def test_knurled_ring_dimensions_and_volume():
    ring = scenes.knurled_ring(69.0, 45.0, 15.0, pitch_mm=1.2, depth_mm=0.5, max_edge_mm=0.3)
    np.testing.assert_allclose(ring.mesh.bounds, [[-34.5, -34.5, 0], [34.5, 34.5, 15]], atol=1e-9)
    r = np.hypot(*ring.mesh.vertices[:, :2].T)
    assert r.min() == pytest.approx(22.5, abs=1e-9)
    n = ring.analytic["segments"]
    ro, ri, d = 34.5, 22.5, 0.5
    # 15 mm is not a multiple of the axial period (2.4 mm): the band mean is near, not at, 2/3
    removed = (_polygon_area(ro, n) - _polygon_area(ri, n)) * 15 - ring.mesh.volume
    assert removed == pytest.approx(math.pi * (2 * ro * d * 2 / 3 - d * d / 2) * 15, rel=0.02)
