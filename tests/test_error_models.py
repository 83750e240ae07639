"""Error models of the as-built instrument (issue 11), each against its own definition.

Stages, plate, laser sheet, lens and sensor; no rendering here (see
test_error_models_render.py for the rendered checks).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from scheimpflug.errors import MeshError, RigError
from scheimpflug.model.camera import (
    conjugate_point,
    lens_state,
    pixel_from_sensor_point,
    project_points,
    sensor_pose,
)
from scheimpflug.model.hinge import hinge_geometry
from scheimpflug.model.rig import ERROR_MODELS, active_error_models, load_preset
from sim.stages import (
    rig_from_plate,
    rotary_state,
    rotation_z,
    stage_from_part,
    transform_points,
    translation_state,
)


@pytest.fixture(scope="module")
def paper():
    return load_preset("paper")


# ------------------------------------------------------------------ rig keys
def test_error_models_are_off_by_default_and_validated(paper):
    assert active_error_models(paper) == ()
    keys = [k for v in ERROR_MODELS.values() for k in v]
    assert len(keys) == len(set(keys)) >= 20
    for table, key, bad in (("stage", "wobble_urad", -1.0), ("sensor", "prnu_percent", 60.0),
                            ("laser", "fan_edge_ratio", 0.0), ("lens", "focal_length_error_mm", 20.0),
                            ("stage", "translation_lead_mm", 0.0)):
        with pytest.raises(RigError, match=key):
            paper.replace(**{table: {key: bad}})
    on = paper.replace(stage={"pitch_urad": 5.0}, laser={"fan_edge_ratio": 0.9})
    assert active_error_models(on) == ("stage.pitch_urad", "laser.fan_edge_ratio")


def test_as_built_preset_has_the_twins_light_on_as_sources_of_its_own(paper):
    """paper-as-built renders issue 10's light; each effect can be taken alone, like an error model."""
    from scheimpflug.model.rig import TWIN_EFFECTS, with_error_models

    ab = load_preset("paper-as-built")
    assert (ab.twin.bounces, ab.twin.subsurface, ab.twin.speckle_model) == (3, True, "surface")
    assert ab.laser.speckle_contrast > 0
    # the light is not an error model of the instrument: geometry and truth stay the ideal rig's
    assert active_error_models(paper.replace(twin={"bounces": 3, "subsurface": True})) == ()
    assert set(TWIN_EFFECTS) == {"inter-reflections", "subsurface"}
    alone = with_error_models(paper, ab, ["inter-reflections"])
    assert alone == paper.replace(twin={"bounces": 3})
    assert with_error_models(paper, ab, ["subsurface"]) == paper.replace(twin={"subsurface": True})
    speckle = with_error_models(paper.replace(twin={"speckle_model": "sensor"}), ab, ["speckle"])
    assert (speckle.laser.speckle_contrast, speckle.twin.speckle_model) == (ab.laser.speckle_contrast, "surface")
    with pytest.raises(RigError, match="inter-reflections"):
        with_error_models(paper, ab, ["reflections"])


# ------------------------------------------------------------------ translation stage
def test_periodic_scale_and_random_positioning(paper):
    A, lead, k = 40.0, 2.0, 250.0          # µm, mm, ppm
    rig = paper.replace(stage={"translation_periodic_um": A, "translation_lead_mm": lead,
                               "translation_scale_ppm": k})
    g = hinge_geometry(rig)
    for s in (0.0, 100.5, 100.25, 201.75):
        st = translation_state(rig, s)
        expected = s + 1e-6 * k * s + 1e-3 * A * math.sin(2 * math.pi * s / lead)
        assert st.stage_mm == pytest.approx(expected, abs=1e-12)
        # the plate's measured face is where the carriage really went: D = s_a − d0
        D, h, off = g.sheet_from_rig(transform_points(rig_from_plate(rig, s, st), [0.0, 0.0, 20.0]))
        assert D == pytest.approx(expected - rig.stage.d0_mm, abs=1e-9)
        assert off == pytest.approx(0.0, abs=1e-9)
    # repeatability: σ·z, a standard normal draw per move
    rep = paper.replace(stage={"translation_repeatability_um": 3.0})
    assert translation_state(rep, 50.0, z=-1.5).stage_mm == pytest.approx(50.0 - 0.0045, abs=1e-12)


def test_straightness_pitch_and_yaw_move_the_carriage_as_defined(paper):
    L, S_lat, S_vert, P, Y = 400.0, 12.0, -8.0, 300.0, -200.0
    rig = paper.replace(stage={"translation_travel_mm": L, "straightness_lateral_um": S_lat,
                               "straightness_vertical_um": S_vert, "pitch_urad": P, "yaw_urad": Y})
    g = hinge_geometry(rig)
    for s in (0.0, 100.0, 200.0, 400.0):
        x = s / L
        st = translation_state(rig, s)
        assert (st.lateral_um, st.vertical_um) == pytest.approx((4 * x * (1 - x) * S_lat,
                                                                 4 * x * (1 - x) * S_vert))
        assert (st.pitch_urad, st.yaw_urad) == pytest.approx(((2 * x - 1) * P, (2 * x - 1) * Y))
        m = rig_from_plate(rig, s, st)
        # the rotation centre (face bottom centre) is only displaced by the straightness
        D, h, off = g.sheet_from_rig(transform_points(m, [0.0, 0.0, 0.0]))
        assert D == pytest.approx(s - rig.stage.d0_mm, abs=1e-9)
        assert off == pytest.approx(1e-3 * st.lateral_um, abs=1e-12)
        assert h == pytest.approx(rig.stage.calibration_table_z_mm + 1e-3 * st.vertical_um, abs=1e-12)
        # a point 80 mm up the face leans by 80·pitch along the propagation direction
        D_top = g.sheet_from_rig(transform_points(m, [0.0, 0.0, 80.0]))[0]
        assert D_top - D == pytest.approx(80.0 * math.sin(1e-6 * st.pitch_urad), abs=1e-9)
        # a point 50 mm across the face turns by yaw toward −propagation for +n
        D_side = g.sheet_from_rig(transform_points(m, [0.0, 50.0, 0.0]))[0]
        assert D_side - D == pytest.approx(-50.0 * math.sin(1e-6 * st.yaw_urad), abs=1e-9)


# ------------------------------------------------------------------ rotary stage
def test_rotary_angle_error_wobble_and_radial_motion(paper):
    A, sig, W, R = 0.03, 0.01, 40.0, 6.0
    rig = paper.replace(stage={"rotary_eccentricity_deg": A, "rotary_repeatability_deg": sig,
                               "wobble_urad": W, "radial_error_um": R})
    z_t = rig.stage.rotary_table_z_mm
    for theta, z in ((0.0, 0.0), (90.0, 1.0), (200.0, -2.0)):
        st = rotary_state(rig, theta, z)
        ta = theta + A * math.sin(math.radians(theta)) + sig * z
        assert st.angle_deg == pytest.approx(ta, abs=1e-12)
        c, s = math.cos(2 * math.radians(ta)), math.sin(2 * math.radians(ta))
        assert st.wobble_urad == pytest.approx((W * c, W * s))
        assert st.radial_um == pytest.approx((R * c, R * s))
        m = stage_from_part(rig, theta, st)
        # the table centre is displaced by the radial error motion only
        np.testing.assert_allclose(transform_points(m, [0, 0, 0]),
                                   [1e-3 * R * c, 1e-3 * R * s, z_t], atol=1e-12)
        # the part's axis is tilted by the wobble vector: e_z → e_z + w × e_z
        w = 1e-6 * np.array([W * c, W * s, 0.0])
        np.testing.assert_allclose(m[:3, 2], np.array([0, 0, 1.0]) + np.cross(w, [0, 0, 1.0]),
                                   atol=1e-9)
        # and the part turned by the real angle about it (first order in w: |w|²·r ≈ 1e-7 mm)
        p = transform_points(rotation_z(ta), [50.0, 0.0, 0.0])
        expected = p + np.cross(w, p) + [1e-3 * R * c, 1e-3 * R * s, z_t]
        np.testing.assert_allclose(transform_points(m, [50.0, 0.0, 0.0]), expected, atol=1e-6)


# ------------------------------------------------------------------ calibration plate
def test_plate_flatness_height_and_watertight_mesh():
    from scenes.generators import plate, plate_face_x_mm

    flat, bowed = plate(height_mm=89.1), plate(height_mm=89.1, flatness_um=40.0)
    assert bowed.mesh.is_watertight and bowed.analytic["flatness_um"] == 40.0
    np.testing.assert_allclose(np.ptp(bowed.mesh.vertices[:, 2]), 89.1)
    front = bowed.mesh.vertices[bowed.mesh.vertices[:, 0] <= 0.0]   # the side walls have x > 0
    np.testing.assert_allclose(front[:, 0], plate_face_x_mm(front[:, 1], front[:, 2], 120.0, 89.1, 40.0),
                               atol=1e-12)
    assert front[:, 0].min() == pytest.approx(-0.040, abs=1e-3)     # the centre: F nearer the laser
    assert np.ptp(front[:, 0]) == pytest.approx(0.040, abs=1e-3)    # peak to valley = F
    # the bow adds the paraboloid's volume over the face
    yy, zz = np.meshgrid(np.linspace(-60, 60, 601), np.linspace(0, 89.1, 601))
    extra = -plate_face_x_mm(yy, zz, 120.0, 89.1, 40.0).mean() * 120.0 * 89.1
    assert bowed.mesh.volume - flat.mesh.volume == pytest.approx(extra, rel=0.02)


def test_plate_edge_break_is_a_45_degree_chamfer_of_the_measured_face():
    """Chamfer c: the face spans z ∈ [c, h − c] at x = 0, each chamfer removes a c²/2 prism over the
    width, the back and the outline stay; with a bow the chamfers move with the face."""
    from scenes.generators import plate

    c, w, h, t = 0.3, 120.0, 89.0, 5.0
    cut = plate(edge_break_mm=c)
    m = cut.mesh
    assert m.is_watertight and cut.analytic["edge_break_mm"] == c
    assert m.volume == pytest.approx(w * (t * h - c * c), rel=1e-12)
    np.testing.assert_allclose(m.bounds, [[0, -w / 2, 0], [t, w / 2, h]])
    face = m.vertices[m.vertices[:, 0] == 0.0]
    np.testing.assert_allclose(sorted(set(face[:, 2])), [c, h - c])
    # a ray along +x at height z hits the chamfer at x = c − z (bottom) or z − (h − c) (top)
    z = np.array([0.05, 0.15, 0.25, h - 0.25, h - 0.05])
    origins = np.column_stack([np.full(z.size, -10.0), np.zeros(z.size), z])
    locs, idx, _ = m.ray.intersects_location(origins, np.tile([1.0, 0.0, 0.0], (z.size, 1)), multiple_hits=False)
    hit_x = locs[np.argsort(idx), 0]
    np.testing.assert_allclose(hit_x, np.where(z < h / 2, c - z, z - (h - c)), atol=1e-9)
    both = plate(edge_break_mm=c, flatness_um=30.0).mesh
    assert both.is_watertight
    assert plate(flatness_um=30.0).mesh.volume - both.volume == pytest.approx(w * c * c, rel=1e-3)
    with pytest.raises(MeshError):
        plate(edge_break_mm=6.0)


# ------------------------------------------------------------------ laser sheet
def test_powell_profile_conserves_power_and_has_its_edge_ratio(paper):
    from sim.lightsheet import light_sheet, powell_factor, radiant_intensity_w_per_rad

    for ratio in (0.7, 1.0, 1.6):
        sh = light_sheet(paper.replace(laser={"fan_edge_ratio": ratio, "fan_edge_deg": 2.0}))
        a = np.linspace(-1.0, 1.0, 400_001)
        power = np.trapezoid(radiant_intensity_w_per_rad(sh, a), a)
        assert power == pytest.approx(sh.power_w, rel=1e-6)
        half = 0.5 * sh.fan_full_rad
        assert powell_factor(sh, half) / powell_factor(sh, 0.0) == pytest.approx(ratio, rel=1e-12)


def test_bowed_sheet_offset_and_pointing_pose(paper):
    from sim.lightsheet import (
        bow_angle_rad,
        light_sheet,
        pointing_pose,
        posed_sheet,
        sheet_coordinates,
        sheet_offset_mm,
    )

    rig = paper.replace(laser={"line_bow_mrad": 2.0, "pointing_jitter_urad": 100.0})
    sh = light_sheet(rig)
    # a screen ⊥ e_p at distance r: the line's ends leave the plane by r·b, its centre not at all
    r, half = 600.0, 0.5 * sh.fan_full_rad
    edge = sh.origin_mm + r * (math.cos(half) * sh.prop_dir + math.sin(half) * sh.up)
    edge = edge + r * bow_angle_rad(sh, half) * sh.normal
    assert bow_angle_rad(sh, half) == pytest.approx(2e-3)
    assert sheet_offset_mm(sh, edge) == pytest.approx(0.0, abs=1e-9)
    assert sheet_coordinates(sh, edge)[2] == pytest.approx(r * 2e-3, rel=1e-9)
    # pointing: a rotation about the laser origin by σ·(z1·e_z + z2·e_p)
    m = pointing_pose(rig, 1.5, -0.5)
    np.testing.assert_allclose(transform_points(m, sh.origin_mm), sh.origin_mm, atol=1e-12)
    moved = posed_sheet(sh, m)
    w = 1e-4 * (1.5 * sh.up - 0.5 * sh.prop_dir)
    np.testing.assert_allclose(moved.normal, sh.normal + np.cross(w, sh.normal), atol=1e-8)
    assert pointing_pose(paper, 1.0, 1.0) is None


# ------------------------------------------------------------------ lens
def test_real_focal_length_is_focused_at_the_sensor_centre(paper):
    rig = paper.replace(lens={"focal_length_error_mm": 0.33})
    ls = lens_state(rig)
    assert ls.focal_length_mm == pytest.approx(55.33)
    pose = sensor_pose(rig)
    # the design's sheet point at the sensor centre is sharp: its conjugate lies on the sensor
    g = hinge_geometry(paper)
    centre = np.array([0.5 * (pose.columns - 1), 0.5 * (pose.rows - 1)])
    p = g.rig_from_sheet(*g.sheet_from_pixel(centre[0], centre[1]))
    x = p[0] - ls.centre_x_mm            # Gaussian lens equation about the moved lens
    img = np.array([ls.centre_x_mm, 0, 0]) - ls.focal_length_mm / (x - ls.focal_length_mm) \
        * (p - [ls.centre_x_mm, 0, 0])
    assert abs((img - pose.origin_mm) @ pose.normal) < 1e-9
    np.testing.assert_allclose(conjugate_point(rig, p), img, atol=1e-9)
    # focusing a longer lens moved it toward the object by ≈ Δf·(1 + m)², m ≈ f/(x − f)
    m = 55.0 / (p[0] - 55.0)
    assert ls.focus_shift_mm == pytest.approx(0.33 * (1 + m) ** 2, rel=0.05)
    # a focus error on top moves the lens by exactly that much
    off = lens_state(rig.replace(lens={"focus_error_um": 50.0}))
    assert off.centre_x_mm - ls.centre_x_mm == pytest.approx(0.050, abs=1e-9)
    # the real lens magnifies more: the sheet's image spreads by (x'/x)/(x'0/x0) across columns
    u_ideal = project_points(paper, p).uv_px
    u_real = project_points(rig, p).uv_px
    assert np.linalg.norm(u_real - u_ideal) < 5.0   # near the centre, the mapping barely moves


def test_thick_lens_focused_on_the_sheet_images_it_like_the_thin_lens(paper):
    """A thick lens (principal points H, H' = H + h·x) focused on the sheet: image space shifted by h.

    Independent model: object rays aim at H (the rig origin), image-side rays leave H' parallel
    to them and converge at the conjugate H' + m·(P − H); focusing puts the sensor at its thin-lens
    pose + h·x.  Its pixels equal the thin lens's, so the principal-plane separation needs no key.
    """
    import dataclasses

    rig, h = paper, -12.0                      # a hiatus of −12 mm (assumed; any value)
    pose = sensor_pose(rig)
    g = hinge_geometry(rig)
    pts = np.array([g.rig_from_sheet(D, z) for D in (450.0, 600.0, 710.0) for z in (-40.0, 0.0, 60.0)])
    f = rig.lens.focal_length_mm
    h_img = np.array([h, 0.0, 0.0])            # H', the rear principal point (H at the origin)
    image = h_img + (-f / (pts[:, 0] - f))[:, None] * pts
    focused = dataclasses.replace(pose, origin_mm=pose.origin_mm + h_img)
    n = focused.normal
    lam = ((focused.origin_mm - h_img) @ n) / ((image - h_img) @ n)   # chief ray from H'
    uv_thick = pixel_from_sensor_point(focused, h_img + lam[:, None] * (image - h_img))
    np.testing.assert_allclose(uv_thick, project_points(rig, pts).uv_px, atol=1e-9)
    # unfocused (the sensor left at the thin-lens pose), the hiatus is a focus error of h
    assert np.all(np.abs((image - pose.origin_mm) @ pose.normal) > 0.5 * abs(h) * abs(n[0]))


# ------------------------------------------------------------------ sensor
def _flat_frames(rig, lam, seeds, backend, factor=1.0):
    from sim.sensor import SensorModel, apply_sensor, frame_rng

    model = SensorModel.from_rig(rig)
    img = np.full((rig.sensor.rows, rig.sensor.columns), lam, np.float32)
    return [apply_sensor(img, model, frame_rng(s, 0), backend, factor).astype(np.float64) for s in seeds]


def _spatial_fixed_variance(a, b):
    """EMVA 1288 style: the spatial covariance of two frames holds only the fixed pattern."""
    return float(np.mean((a - a.mean()) * (b - b.mean())))


@pytest.mark.parametrize("backend", ["numba", "drjit"])
def test_prnu_of_x_percent_gives_a_flat_field_of_x_percent_spatial_sigma(paper, backend):
    if backend == "drjit":
        from sim.sensor import _drjit_llvm

        if _drjit_llvm() is None:
            pytest.skip("no Dr.Jit LLVM backend")
    rig = paper.replace(sensor={"rows": 200, "columns": 300, "prnu_percent": 1.5,
                                "read_noise_e": 0.0, "dark_offset_dn": 0.0, "gain_e_per_dn": 1.0,
                                "adc_bits": 16, "full_well_e": 60000.0})
    lam = 20000.0
    a, b = _flat_frames(rig, lam, (1, 2), backend)
    sigma_fixed = math.sqrt(_spatial_fixed_variance(a, b))
    # 60 000 pixels: the estimate's relative error is ≈ 1/√(2·60000)·√(1 + (shot/fixed)²) < 1 %
    assert sigma_fixed / lam == pytest.approx(0.015, rel=0.03)
    # the temporal part (difference of two frames) is shot noise alone: var = 2λ
    assert np.var(a - b) == pytest.approx(2 * lam, rel=0.03)
    # the pattern is the sensor's: the same map in every frame and run, another with another seed
    c = _flat_frames(rig.replace(sensor={"pattern_seed": 7}), lam, (3,), backend)[0]
    assert _spatial_fixed_variance(a, c) < 0.1 * sigma_fixed**2


def test_dsnu_hot_pixels_and_exposure_jitter(paper):
    from sim.sensor import exposure_scale

    rig = paper.replace(sensor={"rows": 200, "columns": 300, "dsnu_e": 4.0, "hot_pixel_fraction": 0.01,
                                "hot_pixel_e": 500.0, "read_noise_e": 2.0, "gain_e_per_dn": 1.0,
                                "dark_offset_dn": 100.0, "adc_bits": 16})
    a, b = _flat_frames(rig, 0.0, (3, 4), "numba")
    hot = (a > 100 + 250) & (b > 100 + 250)
    assert hot.mean() == pytest.approx(0.01, rel=0.15)
    cold_a, cold_b = a[~hot], b[~hot]
    assert math.sqrt(_spatial_fixed_variance(cold_a, cold_b)) == pytest.approx(4.0, rel=0.05)
    assert np.median(a[hot]) == pytest.approx(600.0, abs=10.0)
    # exposure jitter: the frame's signal scales by 1 + (p/100)·z
    jit = paper.replace(sensor={"exposure_jitter_percent": 2.0})
    assert exposure_scale(jit, -1.5) == pytest.approx(0.97) and exposure_scale(paper, 3.0) == 1.0
    flat = paper.replace(sensor={"rows": 100, "columns": 100, "read_noise_e": 0.0, "gain_e_per_dn": 1.0,
                                 "dark_offset_dn": 0.0, "adc_bits": 16, "full_well_e": 60000.0})
    f1, f2 = (_flat_frames(flat, 10000.0, (5,), "numba", k)[0].mean() for k in (1.0, 0.97))
    assert f2 / f1 == pytest.approx(0.97, abs=0.001)


def test_sensor_errors_bit_reproducible_on_both_backends(paper):
    from sim.sensor import _drjit_llvm

    rig = paper.replace(sensor={"rows": 64, "columns": 80, "prnu_percent": 1.0, "dsnu_e": 2.0,
                                "hot_pixel_fraction": 0.01, "hot_pixel_e": 100.0})
    backends = ["numba"] + (["drjit"] if _drjit_llvm() is not None else [])
    for backend in backends:
        x, y = _flat_frames(rig, 300.0, (9, 9), backend)
        assert np.array_equal(x, y)  # exact: same run
    if len(backends) == 2:   # the same model on both: equal means, equal fixed pattern
        n, d = (_flat_frames(rig, 300.0, (1, 2), b) for b in backends)
        assert abs(n[0].mean() - d[0].mean()) < 0.5
        assert _spatial_fixed_variance(n[0], d[1]) == pytest.approx(_spatial_fixed_variance(n[0], n[1]),
                                                                     rel=0.1)


def test_dataset_truth_follows_the_erring_sheet_and_lens(paper):
    """SceneTruth (the datasets' fast truth) = stripe_truth for a drifted, bowed sheet and a moved lens."""
    from sim.scenarios import calibration_scenario
    from sim.truth import BruteForceCaster, SceneTruth, stripe_truth

    rig = paper.replace(laser={"line_bow_mrad": 5.0, "pointing_jitter_urad": 500.0},
                        lens={"focal_length_error_mm": 0.5, "focus_error_um": 40.0},
                        sensor={"rows": 400, "axis_row": 200.0}, stage={"plate_tilt_deg": 1.0})
    sc = calibration_scenario(rig, steps=2, start_mm=20.0, step_mm=150.0)
    mesh = sc.assembly.combined_mesh()
    v, f, ids = np.asarray(mesh.vertices), np.asarray(mesh.faces), sc.assembly.face_object_ids()
    fast = SceneTruth(rig, v, f, ids)
    for fr in sc.frames:
        assert fr.rig_from_laser is not None
        caster = BruteForceCaster(transform_points(fr.rig_from_part, v), f, ids)
        ref = stripe_truth(rig, v, f, ids, fr.rig_from_part, fr.ref_from_part, caster,
                           rig_from_laser=fr.rig_from_laser)
        got, extra = fast.frame(fr.rig_from_part, fr.ref_from_part, caster, fr.rig_from_laser)
        rows = np.isfinite(ref.stripe_u)
        assert rows.sum() > 100
        np.testing.assert_array_equal(np.isfinite(got.stripe_u), rows)  # exact: integers
        np.testing.assert_allclose(got.stripe_u[rows], ref.stripe_u[rows], atol=1e-6)
        np.testing.assert_allclose(got.stripe_point_mm[rows], ref.stripe_point_mm[rows], atol=1e-6)
        assert np.isfinite(extra["stripe_incidence_deg"][rows]).all()
