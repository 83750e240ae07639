"""Renderer core (sim.render / sim.scene / sim.lightsheet): checks against closed forms.

Poses are built here from the docs/reference/interface.md conventions (not taken from sim.stages) so the
renderer is checked against an independent statement of where the plate is.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from scheimpflug.model.camera import SensorPose, blur_footprint_px, conjugate_point, project_points
from scheimpflug.model.hinge import hinge_geometry
from scheimpflug.model.rig import load_preset

pytestmark = pytest.mark.render

E_Z = np.array([0.0, 0.0, 1.0])


# ------------------------------------------------------------------ helpers
def plate_mesh(height_mm=89.0, width_mm=200.0, thickness_mm=5.0, z0_mm=0.0):
    """Calibration plate in its part frame: measured face x = 0 (facing −x), bottom at z0."""
    m = trimesh.creation.box([thickness_mm, width_mm, height_mm])
    m.apply_translation([thickness_mm / 2, 0.0, z0_mm + height_mm / 2])
    return m


def rig_from_plate(rig, distance_mm, table_z_mm=None):
    """[e_p, n, e_z | H + D·e_p + z_table·e_z] (docs/reference/interface.md translation stage)."""
    g = hinge_geometry(rig)
    z = rig.stage.calibration_table_z_mm if table_z_mm is None else table_z_mm
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2] = g.propagation_dir, g.sheet_normal, E_Z
    m[:3, 3] = g.object_hinge_mm + distance_mm * g.propagation_dir + z * E_Z
    return m


def stripe_cog(img, half_window=12):
    """Per-row windowed centre of gravity around the row maximum [px] and the row peak."""
    u0 = np.argmax(img, axis=1)
    cols = np.clip(u0[:, None] + np.arange(-half_window, half_window + 1), 0, img.shape[1] - 1)
    vals = np.take_along_axis(img, cols, 1).astype(np.float64)
    s = vals.sum(1)
    centre = (vals * cols).sum(1) / np.where(s > 0, s, 1.0)
    rms = np.sqrt((vals * (cols - centre[:, None]) ** 2).sum(1) / np.where(s > 0, s, 1.0))
    return centre, img.max(1), rms


def lit_rows(peak, fraction=0.3):
    """Rows whose peak exceeds ``fraction`` of the median lit peak, minus the two edge rows each side."""
    rows = np.nonzero(peak > fraction * np.median(peak[peak > 0]))[0]
    return rows[2:-2]


def dark_rig(rig, **sensor):
    """No ambient light (the laser alone), optional sensor changes."""
    return rig.replace(environment={"ambient_irradiance_w_m2": 0.0}, sensor=sensor)


def make(rig, parts, **settings):
    from sim.render import Renderer, RenderSettings
    from sim.scene import SimScene

    scene = SimScene(parts)
    return Renderer(rig, scene, RenderSettings(**settings))


# ------------------------------------------------------------------ (1) closed form
@pytest.mark.parametrize("axis_row", [32.0, -1029.0], ids=["meridian", "paper-rows-1800"])
def test_plate_stripe_centre_matches_hinge_closed_form(variant, axis_row):
    """Noise-free plate: windowed CoG within 0.02 px of u_h + F²/(s − d0) in every lit row.

    Paper columns (1216) and hinge; 64 rows, either around the meridian or standing in
    for paper rows 1800–1863 (axis_row shifted so the geometry is the paper's).
    """
    rig = dark_rig(load_preset("paper"), rows=64, axis_row=axis_row)
    g = hinge_geometry(rig)
    table = -60.0 if axis_row > 0 else -150.0
    r = make(rig, [(plate_mesh(120.0, z0_mm=0.0), "tape", 1)], samples_per_row=512)
    d0 = rig.stage.d0_mm
    for s in (-10.0, 120.0, 240.0):  # stage positions [mm]
        img = r.render(rig_from_plate(rig, s - d0, table), seed=3)
        centre, peak, _ = stripe_cog(img)
        rows = lit_rows(peak)
        assert len(rows) >= 50, f"s = {s}: only {len(rows)} lit rows"
        expected = g.hinge_column + g.F2_px_mm / (s - d0)
        err = centre[rows] - expected
        assert np.abs(err).max() < 0.02, (s, expected, np.abs(err).max())


# ------------------------------------------------------------------ (2) focus over the range
def _thin_sheet_rig(**sensor):
    # A sheet far thinner than a pixel footprint over the whole range, so the stripe width
    # shows the camera's focus alone: w0 = 5 µm needs λ ≤ ~2 nm for a Gaussian beam to stay
    # that thin over 280 mm (w ≤ 10 µm here) — a geometric test beam, not a real laser.
    return dark_rig(load_preset("paper"), **sensor).replace(
        laser={"wavelength_nm": 1.0, "waist_um": 5.0, "divergence_mrad": 0.064,
               "waist_distance_mm": 640.0})


def _untilted_pose(rig, column_px):
    """Sensor parallel to the lens plane, focused on the sheet point imaged at ``column_px``."""
    g = hinge_geometry(rig)
    p_mid = g.rig_from_sheet(g.distance_from_column(column_px), 0.0)
    img = conjugate_point(rig, p_mid)
    p = g.pixel_pitch_mm
    u_dir, v_dir = np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0])
    s = rig.sensor
    origin = img - 0.5 * (s.columns - 1) * p * u_dir - s.axis_row * p * v_dir
    return SensorPose(origin, u_dir, v_dir, p, s.columns, s.rows)


def test_scheimpflug_keeps_stripe_sharp_untilted_sensor_blurs_ends(variant):
    from sim.render import Renderer, RenderSettings
    from sim.scene import SimScene

    rig = _thin_sheet_rig(rows=32, axis_row=16.0)
    g = hinge_geometry(rig)
    scene = SimScene([(plate_mesh(120.0), "tape", 1)])
    settings = RenderSettings(samples_per_row=256, pixel_filter="tent")
    tilted = Renderer(rig, scene, settings)
    flat_pose = _untilted_pose(rig, 608.5)
    flat = Renderer(rig, scene, settings, pose=flat_pose)
    # near end, mid-range, far end; half-integer columns: an in-focus thin stripe then
    # splits evenly between two pixels (rms width 0.5 px with the tent pixel filter)
    columns = (60.5, 608.5, 1150.5)
    widths = {"tilted": [], "flat": []}
    for u in columns:
        pose = rig_from_plate(rig, float(g.distance_from_column(u)), -60.0)
        for name, r in (("tilted", tilted), ("flat", flat)):
            img = r.render(pose, seed=1)
            _, peak, rms = stripe_cog(img, half_window=60)
            rows = lit_rows(peak, 0.05)
            widths[name].append(float(np.median(rms[rows])))
    w_t, w_f = np.array(widths["tilted"]), np.array(widths["flat"])
    assert w_t.max() / w_t.min() < 1.2 and w_t.max() < 0.6, w_t
    # untilted: as sharp at mid-range, blurred at both ends (thin-lens blur of tens of px)
    assert w_f[1] < 1.2 * w_t[1], (w_f, w_t)
    assert min(w_f[0], w_f[2]) > 5.0 * w_t.max(), (w_f, w_t)


# ------------------------------------------------------------------ (3) circle of confusion
def test_off_sheet_point_blurs_to_thin_lens_circle_of_confusion(variant):
    rig = dark_rig(load_preset("paper"))
    g = hinge_geometry(rig)
    r = make(rig, [(plate_mesh(10.0, z0_mm=-500.0), "tape", 1)], pixel_filter="box")
    # off the sheet, toward / away from the camera [mm]; blur 40–50 px
    for distance, offset in ((600.0, 40.0), (480.0, -32.0), (480.0, 0.25)):
        point = g.rig_from_sheet(distance, 5.0) + offset * g.sheet_normal
        spot = r.render_point_source(point, 1e-3, n_samples=400_000, seed=2)
        du, dv = blur_footprint_px(rig, point)
        rows, cols = np.nonzero(spot > 1e-4 * spot.max())
        # extent between the outermost lit pixel centres (+1: a box pixel catches light up
        # to half a pixel beyond its centre on each side)
        ext_u, ext_v = np.ptp(cols) + 1.0, np.ptp(rows) + 1.0
        if abs(offset) < 1:  # 0.25 mm off the sheet: a sharp spot (blur ≪ 1 px)
            assert du < 0.5 and ext_u <= 2 and ext_v <= 2, (du, ext_u, ext_v)
            continue
        assert du > 30 and dv > 30, (du, dv)
        assert abs(ext_u / du - 1) < 0.05 and abs(ext_v / dv - 1) < 0.05, (ext_u, du, ext_v, dv)
        # second moments: a uniformly filled ellipse of full extent E has σ = E/4
        vv, uu = np.indices(spot.shape)
        w = spot / spot.sum()
        c = np.array([(w * uu).sum(), (w * vv).sum()])
        sigma = np.sqrt([(w * (uu - c[0]) ** 2).sum(), (w * (vv - c[1]) ** 2).sum()])
        np.testing.assert_allclose(4 * sigma, [du, dv], rtol=0.05)
        # centroid of a thin-lens blur spot ≈ the chief-ray image (within a few % of the blur)
        assert np.linalg.norm(c - project_points(rig, point).uv_px) < 0.05 * du


# ------------------------------------------------------------------ (4) laser-side occlusion
def test_part_hidden_from_laser_stays_dark(variant):
    """A short blocker near the laser shadows the lower part of a plate behind it."""
    rig = dark_rig(load_preset("paper"), rows=400, axis_row=200.0)
    g = hinge_geometry(rig)
    back = plate_mesh(120.0)
    blocker = plate_mesh(58.0, width_mm=40.0, thickness_mm=2.0)
    pose_back = rig_from_plate(rig, 690.0, -60.0)
    pose_block = rig_from_plate(rig, 470.0, -60.0)  # z ∈ [−60, −2] near the laser
    r = make(rig, [(back, "tape", 1), (blocker, "tape", 2)], samples_per_row=64)
    img = r.render(np.stack([pose_back, pose_block]), seed=0)
    u_back = g.column_from_distance(690.0)
    band = img[:, int(u_back) - 8: int(u_back) + 9].sum(1)
    # heights on the back plate: lit above the shadow line of the blocker top, dark below
    origin = np.array([rig.laser.origin_x_mm, rig.laser.scheimpflug_distance_mm, 0.0])
    r_block = (g.rig_from_sheet(470.0, 0.0) - origin) @ g.propagation_dir
    r_back = (g.rig_from_sheet(690.0, 0.0) - origin) @ g.propagation_dir
    z_shadow = -2.0 * r_back / r_block  # top edge of the shadow on the back plate [mm]
    _, v_shadow = g.pixel_from_sheet(690.0, z_shadow)
    _, v_bottom = g.pixel_from_sheet(690.0, -60.0)
    lit = band[: int(v_shadow) - 5]
    shadow = band[int(v_shadow) + 5: min(int(v_bottom) - 2, rig.sensor.rows)]
    assert len(shadow) > 100 and len(lit) > 100 and lit.min() > 0, (len(shadow), len(lit))
    assert shadow.max() < 1e-6 * np.median(lit), shadow.max()
    # and the blocker itself is lit, at its own column
    u_block = g.column_from_distance(470.0)
    assert img[:, int(u_block) - 8: int(u_block) + 9].max() > 0.1 * img.max()


# ------------------------------------------------------------------ (5) seeds
def test_same_seed_bit_identical_different_seed_differs(variant):
    rig = load_preset("paper").replace(sensor={"rows": 48, "axis_row": 24.0})
    r = make(rig, [(plate_mesh(120.0), "metal", 1)], samples_per_row=16)
    pose = rig_from_plate(rig, 600.0, -60.0)
    a, b = r.render(pose, seed=5), r.render(pose, seed=5)
    c = r.render(pose, seed=6)
    assert a.dtype == np.float32 and a.shape == (48, 1216)
    assert np.array_equal(a, b)  # exact: same run
    assert not np.array_equal(a, c)
    # a fresh renderer on a fresh scene reproduces it too
    r2 = make(rig, [(plate_mesh(120.0), "metal", 1)], samples_per_row=16)
    assert np.array_equal(a, r2.render(pose, seed=5))  # exact: same run


# ------------------------------------------------------------------ energy
def test_laser_energy_matches_closed_form(variant):
    """Total electrons of a Lambertian plate = ∫ I(α)·(ρ/π)·cos θ_c·A_ap·cos θ_A/|P|² dα · t·QE/(hν)."""
    from sim.lightsheet import light_sheet, radiant_intensity_w_per_rad

    rig = dark_rig(load_preset("paper"), rows=400, axis_row=200.0)
    g = hinge_geometry(rig)
    D, z0, h = 600.0, -10.0, 20.0  # plate face fully in view
    r = make(rig, [(plate_mesh(h, z0_mm=0.0), "tape", 1)], samples_per_row=64)
    img = r.render(rig_from_plate(rig, D, z0), seed=0)
    sheet = light_sheet(rig)
    rho = 0.55  # tape albedo (sim.materials default)
    dist = (g.object_hinge_mm - sheet.origin_mm) @ g.propagation_dir + D
    alpha = np.linspace(math.atan2(z0, dist), math.atan2(z0 + h, dist), 20001)
    p = sheet.origin_mm + dist * g.propagation_dir + (dist * np.tan(alpha))[:, None] * E_Z
    to_lens = -p / np.linalg.norm(p, axis=1, keepdims=True)
    cos_c = to_lens @ (-g.propagation_dir)
    cos_a = -to_lens[:, 0]
    area = math.pi * (0.5 * rig.lens.focal_length_mm / rig.lens.f_number) ** 2
    integrand = radiant_intensity_w_per_rad(sheet, alpha) * rho / math.pi * cos_c * area * cos_a \
        / (p**2).sum(1)
    flux = np.trapezoid(integrand, alpha)
    photon = 6.62607015e-34 * 299792458.0 / (rig.laser.wavelength_nm * 1e-9)
    expected = flux * rig.sensor.exposure_ms * 1e-3 * rig.sensor.quantum_efficiency / photon
    assert img.sum() == pytest.approx(expected, rel=0.01)


def test_ambient_lambertian_plate_matches_radiance_formula(variant):
    """Ambient only: pixel electrons = ρ/π·E·A_pix·A_ap·cos θ_q·cos θ_A/|q|²·t·QE/(hν)."""
    from scheimpflug.model.camera import sensor_point_from_pixel, sensor_pose

    rig = load_preset("paper").replace(sensor={"rows": 64, "axis_row": 32.0},
                                       laser={"power_mw": 0.0},
                                       environment={"ambient_irradiance_w_m2": 1.0})
    r = make(rig, [(plate_mesh(120.0), "cardboard", 1)], ambient_step_px=4)
    img = r.render(rig_from_plate(rig, 600.0, -60.0), seed=0)
    pose = sensor_pose(rig)
    uv = np.array([[300.0, 30.0], [800.0, 10.0]])
    q = sensor_point_from_pixel(pose, uv)
    qn = np.linalg.norm(q, axis=1)
    g = pose.pitch_mm**2 * math.pi * (0.5 * 55 / 5.6) ** 2 * np.abs(q[:, 0]) / qn \
        * np.abs(q @ pose.normal) / qn / qn**2 * 1e-6
    photon = 6.62607015e-34 * 299792458.0 / 450e-9
    expected = 0.35 / math.pi * 1.0 * g * rig.sensor.exposure_ms * 1e-3 * 0.75 / photon
    got = img[uv[:, 1].astype(int), uv[:, 0].astype(int)]
    np.testing.assert_allclose(got, expected, rtol=0.01)


# ------------------------------------------------------------------ scene queries
def test_scene_intersect_and_occluded(variant):
    from sim.scene import SimScene

    near = trimesh.creation.box([10, 10, 10])
    far = trimesh.creation.box([10, 100, 100])
    scene = SimScene([(far, "tape", 4), (near, "metal", 9)])
    t_far, t_near = np.eye(4), np.eye(4)
    t_far[0, 3], t_near[0, 3] = 600.0, 300.0
    scene.set_pose(np.stack([t_far, t_near]))
    hits = scene.intersect(np.zeros((3, 3)), [[1, 0, 0], [600, 30, 0], [0, 1, 0]])
    np.testing.assert_allclose(hits.t[:2], [295.0, math.hypot(595, 29.75)], rtol=1e-6)
    np.testing.assert_array_equal(hits.object_id, [9, 4, 0])  # exact: integers
    assert np.isinf(hits.t[2]) and np.isnan(hits.point_mm[2]).all()
    np.testing.assert_allclose(hits.normal[0], [-1, 0, 0], atol=1e-6)
    occ = scene.occluded(np.zeros((3, 3)), [[700, 0, 0], [595, 30, 0], [200, 0, 0]])
    np.testing.assert_array_equal(occ, [True, False, False])  # exact: integers
    shifted = t_far.copy()
    shifted[0, 3] = 700.0
    scene.set_pose(np.stack([shifted, t_far]))  # moved without rebuilding the scene
    assert scene.intersect(np.zeros((1, 3)), [[1, 0, 0]]).t[0] == pytest.approx(595.0)
