"""Surface models of rotary scans (scheimpflug.meshing) and their volumetric numbers, on synthetic grids.

The scans here are drawn from analytic surfaces of revolution, sampled the way
a rotary scan samples them: frame i at angle θ_i sees, on row j (height z_j,
rows counted downwards as on the sensor), the part's outermost point at that
height on the laser side (azimuth π − θ_i).  Faces no horizontal ray reaches
(shoulders, the top, the underside of an overhang, a bore) are therefore never
measured — exactly the gaps the meshing rule must close.  Truth volumes come
from closed forms or from an independent numerical integral of the analytic
radius, never from the model.
"""

import math

import numpy as np
import pytest

from scheimpflug.errors import MeshError
from scheimpflug.meshing import FILL_CAP, FILL_GAP, FILL_MEASURED, FILL_TABLE, ModelSettings, model_from_cloud
from scheimpflug.reconstruct import PointCloud
from scheimpflug.scoring import PointToMesh, is_closed_mesh
from scheimpflug.volumetry import mesh_volume_mm3, section, solid_summary, volume_from_sections_mm3

TABLE = -70.0


def synthetic_scan(radius, height_mm, dz_mm=0.1, n_frames=360, noise_mm=0.0, rng=None, drop=None):
    """PointCloud of a rotary scan of the surface r = radius(phi, z) (z from the table; NaN: no point)."""
    z = height_mm - dz_mm * (np.arange(int(height_mm / dz_mm)) + 0.5)       # row j: top to bottom
    theta = np.arange(n_frames) * 360.0 / n_frames
    phi = np.pi - np.radians(theta)[:, None]
    r = radius(phi, z[None, :]) * np.ones((n_frames, len(z)))
    if noise_mm:
        r = r + rng.normal(0.0, noise_mm, r.shape)
    if drop is not None:
        r[drop] = np.nan
    i, j = np.nonzero(np.isfinite(r))
    xyz = np.stack([r[i, j] * np.cos(phi[i, 0]), r[i, j] * np.sin(phi[i, 0]), z[j] + TABLE], axis=1)
    return PointCloud(xyz_mm=xyz, angle_deg=theta[i], row=j, intensity=np.ones(len(i)), frame=i)


def per_body_closed(model) -> bool:
    return all(is_closed_mesh(model.faces[model.face_body == b]) for b in range(model.n_bodies))


# ------------------------------------------------------------------ acceptance on analytic parts


def test_knurled_paper_cylinder_volume_within_0p2_percent():
    """The paper's cylinder (Ø100 × 108, diamond knurl on the bottom 20 mm) at 0.5° steps."""
    import scenes
    from scenes import knurl_radius_mm

    spec = scenes.load_part("cylinder").parts[0].analytic["knurl"]

    def radius(phi, z):
        return np.where(z < 20.0, knurl_radius_mm(phi, z, spec), 50.0)

    model = model_from_cloud(synthetic_scan(radius, 108.0, n_frames=720), ModelSettings(table_z_mm=TABLE))
    # truth, independently: the smooth part in closed form, the band by a fine midpoint integral of r²/2
    th = (np.arange(8000) + 0.5) * 2 * np.pi / 8000
    zb = (np.arange(800) + 0.5) * 20.0 / 800
    band = np.sum(0.5 * knurl_radius_mm(th[:, None], zb[None, :], spec) ** 2) * (2 * np.pi / 8000) * (20.0 / 800)
    truth = math.pi * 50.0**2 * 88.0 + band
    grooves = math.pi * 50.0**2 * 20.0 - band
    assert 1500 < grooves < 1800                                       # the knurl takes ≈ 0.2 % away
    assert model.n_bodies == 1 and per_body_closed(model)
    assert abs(mesh_volume_mm3(model.vertices_mm, model.faces) / truth - 1) < 2e-3


def stepped_radius(phi, z):
    """Base Ø80 × 30, shoulder to Ø50, wall to z = 60, cone to Ø30 at z = 80, flat top."""
    r = np.where(z < 30, 40.0, np.where(z < 60, 25.0, 25.0 - (z - 60.0) * 0.5))
    return np.where(z <= 80.0, r, np.nan)


STEPPED_VOLUME = math.pi * (40**2 * 30 + 25**2 * 30 + 20.0 / 3 * (25**2 + 25 * 15 + 15**2))


def test_stepped_part_analytic_volume_within_0p5_percent():
    model = model_from_cloud(synthetic_scan(stepped_radius, 80.0), ModelSettings(table_z_mm=TABLE))
    assert per_body_closed(model)
    v = mesh_volume_mm3(model.vertices_mm, model.faces)
    assert abs(v / STEPPED_VOLUME - 1) < 5e-3
    # the shoulder the sheet never reaches is bridged: one body, the shoulder marked as a gap
    assert model.n_bodies == 1
    gap = model.faces[model.face_fill == FILL_GAP]
    assert np.allclose(model.vertices_mm[gap][:, :, 2], TABLE + 30.0, atol=0.06)
    assert abs(volume_from_sections_mm3(model.vertices_mm, model.faces) / v - 1) < 1e-3
    apart = model_from_cloud(synthetic_scan(stepped_radius, 80.0),
                             ModelSettings(table_z_mm=TABLE, join_gap_steps=0))
    assert apart.n_bodies == 2 and per_body_closed(apart)          # kept apart: each capped at the step
    assert mesh_volume_mm3(apart.vertices_mm, apart.faces) == pytest.approx(v, rel=2e-3)


def test_sections_of_the_stepped_part():
    model = model_from_cloud(synthetic_scan(stepped_radius, 80.0), ModelSettings(table_z_mm=TABLE))
    for z, r in ((15.0, 40.0), (45.0, 25.0), (70.0, 20.0)):
        s = section(model.vertices_mm, model.faces, TABLE + z)
        # a 360-gon inscribed in the circle: area short by ≈ (2π/360)²/6 = 5e-5
        assert s.area_mm2 == pytest.approx(math.pi * r * r, rel=2e-4)
        assert s.diameter_mm == pytest.approx(2 * r, rel=1e-4)
        assert s.width_mm == pytest.approx(2 * r, abs=0.01)
        assert s.perimeter_mm == pytest.approx(2 * math.pi * r, rel=1e-4)


def test_hidden_bore_is_capped_marked_and_its_volume_error_shows():
    """A cup (Ø60 × 50, Ø40 bore 40 deep from the top): no profile sees the bore, the cap fills it."""
    model = model_from_cloud(synthetic_scan(lambda p, z: 30.0 + 0 * z, 50.0), ModelSettings(table_z_mm=TABLE))
    truth = math.pi * 30**2 * 50 - math.pi * 20**2 * 40
    v = mesh_volume_mm3(model.vertices_mm, model.faces)
    assert per_body_closed(model)
    assert v - truth == pytest.approx(math.pi * 20**2 * 40, rel=5e-3)   # the error is the bore's volume
    top = model.faces[model.face_fill == FILL_CAP]
    assert len(top) == 360 and np.allclose(model.vertices_mm[top][:, :, 2], TABLE + 50 - 0.05)
    assert np.any(model.face_fill == FILL_TABLE) and np.any(model.face_fill == FILL_MEASURED)


def test_overhang_underside_is_closed_and_marked():
    """A mushroom: stem Ø20 up to z = 30, head Ø60 from 30 to 45; the head's underside is never seen."""
    model = model_from_cloud(synthetic_scan(lambda p, z: np.where(z < 30, 10.0, 30.0), 45.0),
                             ModelSettings(table_z_mm=TABLE))
    assert model.n_bodies == 1 and per_body_closed(model)
    truth = math.pi * (10**2 * 30 + 30**2 * 15)
    assert mesh_volume_mm3(model.vertices_mm, model.faces) == pytest.approx(truth, rel=5e-3)
    # the underside: bridged from the stem's last row (z = 29.95) to the head's first (30.05), marked
    under = model.faces[model.face_fill == FILL_GAP]
    assert len(under) > 0 and np.allclose(model.vertices_mm[under][:, :, 2], TABLE + 30.0, atol=0.06)
    r = np.hypot(*model.vertices_mm[under][:, :, :2].reshape(-1, 2).T)
    assert r.min() == pytest.approx(10.0, abs=0.01) and r.max() == pytest.approx(30.0, abs=0.01)
    apart = model_from_cloud(synthetic_scan(lambda p, z: np.where(z < 30, 10.0, 30.0), 45.0),
                             ModelSettings(table_z_mm=TABLE, join_gap_steps=0))
    # kept apart: every cap lies at the outermost sampled row, half a row (0.05 mm) inside the true end
    sampled = truth - math.pi * (30**2 * 0.1 + 10**2 * 0.05)
    assert apart.n_bodies == 2
    assert mesh_volume_mm3(apart.vertices_mm, apart.faces) == pytest.approx(sampled, rel=2e-4)


# ------------------------------------------------------------------ the rule's pieces


def test_faces_point_outwards_and_distances_are_small():
    model = model_from_cloud(synthetic_scan(stepped_radius, 80.0), ModelSettings(table_z_mm=TABLE))
    for b in range(model.n_bodies):
        f = model.faces[model.face_body == b]
        assert mesh_volume_mm3(model.vertices_mm, f) > 0
    # a point 1 mm outside the wall at mid-height is outside the closed model (positive signed distance)
    pm = PointToMesh(model.vertices_mm, model.faces)
    d = pm.query(np.array([[26.0, 0.0, TABLE + 45.0], [24.0, 0.0, TABLE + 45.0]])).distance_mm
    assert d[0] == pytest.approx(1.0, abs=0.01) and d[1] == pytest.approx(-1.0, abs=0.01)


def test_short_gaps_are_bridged_and_marked():
    drop = np.zeros((360, 500), bool)
    drop[100, 200:210] = True             # ten rows missing in one frame
    drop[150:152, :] = True               # two whole frames missing
    model = model_from_cloud(synthetic_scan(lambda p, z: 30.0 + 0 * z, 50.0, drop=drop),
                             ModelSettings(table_z_mm=TABLE))
    assert model.n_bodies == 1 and per_body_closed(model)
    gap = model.faces[model.face_fill == FILL_GAP]
    assert len(gap) > 0
    ang = np.degrees(np.arctan2(model.vertices_mm[gap][:, :, 1], model.vertices_mm[gap][:, :, 0])) % 360
    # frames 149 → 152 (azimuth 180 − θ: 31° … 28°) and frame 100 (80°) ± one step
    assert np.all(((ang > 26.9) & (ang < 32.1)) | ((ang > 78.9) & (ang < 81.1)))
    assert mesh_volume_mm3(model.vertices_mm, model.faces) == pytest.approx(math.pi * 900 * 49.95, rel=2e-4)


def test_two_parts_side_by_side_stay_apart():
    """Two cylinders at different heights ranges on one turn: two bodies that share no vertex."""
    def radius(phi, z):
        return np.where(z < 20, 30.0, np.where((z > 40) & (z < 60), 15.0, np.nan))

    model = model_from_cloud(synthetic_scan(radius, 60.0), ModelSettings(table_z_mm=TABLE))
    assert model.n_bodies == 2 and per_body_closed(model)
    shared = set(np.unique(model.faces[model.face_body == 0])) & set(np.unique(model.faces[model.face_body == 1]))
    assert not shared
    numbers = solid_summary(model.vertices_mm, model.faces, model.face_body)
    vols = sorted(b["volume_mm3"] for b in numbers["bodies"])
    assert vols[0] == pytest.approx(math.pi * 15**2 * 19.9, rel=2e-4)   # top part: capped at both end rows
    assert vols[1] == pytest.approx(math.pi * 30**2 * 19.95, rel=2e-4)  # on the table


def test_noise_points_are_not_used(rng):
    cloud = synthetic_scan(lambda p, z: 30.0 + 0 * z, 50.0)
    stray = PointCloud(np.array([[0.0, 200.0, 0.0], [0.0, -250.0, 10.0]]), np.array([3.0, 7.0]),
                       np.array([1000, 1001]), np.ones(2), np.array([3, 7]))
    both = PointCloud(*(np.concatenate([getattr(cloud, k), getattr(stray, k)])
                        for k in ("xyz_mm", "angle_deg", "row", "intensity", "frame")))
    model = model_from_cloud(both, ModelSettings(table_z_mm=TABLE))
    assert model.n_points_unused == 2 and model.n_bodies == 1


def test_partial_turn_is_closed_by_a_side_strip():
    cloud = synthetic_scan(lambda p, z: 30.0 + 0 * z, 50.0, n_frames=360)
    keep = cloud.angle_deg < 90.0
    part = PointCloud(*(getattr(cloud, k)[keep] for k in ("xyz_mm", "angle_deg", "row", "intensity", "frame")))
    model = model_from_cloud(part, ModelSettings(table_z_mm=TABLE))
    assert model.n_bodies == 1 and per_body_closed(model)
    assert np.any(model.face_fill == 4)


def test_without_a_table_the_bottom_is_capped():
    model = model_from_cloud(synthetic_scan(lambda p, z: 30.0 + 0 * z, 50.0), ModelSettings())
    assert not np.any(model.face_fill == FILL_TABLE)
    assert mesh_volume_mm3(model.vertices_mm, model.faces) == pytest.approx(math.pi * 900 * 49.9, rel=1e-3)


@pytest.mark.parametrize("bad", [
    PointCloud(np.zeros((0, 3)), np.zeros(0), np.zeros(0, int), np.zeros(0)),
    PointCloud(np.ones((5, 3)), np.full(5, np.nan), np.full(5, -1), np.ones(5)),
    PointCloud(np.ones((5, 3)), np.array([0.0, 0, 1, 1, 1]), np.arange(5), np.ones(5)),
])
def test_bad_clouds_give_one_clear_error(bad):
    with pytest.raises(MeshError, match="no usable frames|not a rotary scan|at least 3 rotary angles"):
        model_from_cloud(bad)


def test_settings_are_validated():
    with pytest.raises(MeshError, match="max_step_mm"):
        ModelSettings(max_step_mm=-1.0)
    with pytest.raises(MeshError, match="min_overlap"):
        ModelSettings(min_overlap=0.0)
