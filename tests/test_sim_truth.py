"""Ground truth from geometry: closed forms for the plate, occlusion, cylinder, seeding."""

import hashlib
import math

import numpy as np
import pytest
import trimesh

from scheimpflug.model.binning import binned_rig
from scheimpflug.model.hinge import hinge_geometry
from scheimpflug.model.rig import load_preset
from sim.scenarios import calibration_scenario
from sim.stages import rig_from_stage, stage_from_part, transform_points
from sim.truth import (
    BruteForceCaster,
    laser_origin_mm,
    pixel_truth,
    rig_truth,
    row_crossings,
    sheet_section,
    stripe_truth,
)


@pytest.fixture(scope="module")
def rig():
    return load_preset("paper")


def _truth(rig, mesh, rig_from_part, ref_from_part, ids=None):
    ids = np.ones(len(mesh.faces), int) if ids is None else ids
    caster = BruteForceCaster(transform_points(rig_from_part, mesh.vertices), mesh.faces, ids)
    return stripe_truth(rig, mesh.vertices, mesh.faces, ids, rig_from_part, ref_from_part, caster)


@pytest.mark.parametrize("s", [0.0, 90.0, 255.0])
def test_plate_stripe_is_the_closed_form_in_every_covered_row(rig, s):
    g = hinge_geometry(rig)
    sc = calibration_scenario(rig, steps=1, start_mm=s)
    frame = sc.frames[0]
    mesh = sc.assembly.combined_mesh()
    st = _truth(rig, mesh, frame.rig_from_part, frame.ref_from_part)
    D = s - rig.stage.d0_mm
    z0 = rig.stage.calibration_table_z_mm
    u_exp = g.hinge_column + g.F2_px_mm / D
    _, v_top = g.pixel_from_sheet(D, z0 + 89.0)
    _, v_bottom = g.pixel_from_sheet(D, z0)
    covered = np.arange(math.ceil(v_top), math.floor(v_bottom) + 1)
    covered = covered[(covered >= 0) & (covered < rig.sensor.rows)]
    lit = np.flatnonzero(np.isfinite(st.stripe_u))
    np.testing.assert_array_equal(lit, covered)  # exact: integers
    np.testing.assert_allclose(st.stripe_u[covered], u_exp, atol=1e-6)
    assert np.all(st.stripe_count[covered] == 1)
    assert np.all(st.stripe_object_id[covered] == 1)
    # the 3-D point: on the face (stage x = s - axis_mm), in the sheet, at the row's height
    p = st.stripe_point_mm[covered]
    np.testing.assert_allclose(p[:, 0], s - rig.stage.axis_mm, atol=1e-9)
    np.testing.assert_allclose(p[:, 1], 0.0, atol=1e-9)
    _, v = g.pixel_from_sheet(D, p[:, 2])
    np.testing.assert_allclose(v, covered, atol=1e-6)


def test_laser_occluded_part_has_nan_truth_camera_occluded_too(rig):
    g = hinge_geometry(rig)
    plate = trimesh.creation.box(extents=(5.0, 60.0, 40.0))          # centred, faces ⊥ x
    rig_from_plate = np.eye(4)
    rig_from_plate[:3, :3] = np.column_stack([g.propagation_dir, g.sheet_normal, [0, 0, 1]])
    rig_from_plate[:3, 3] = g.rig_from_sheet(600.0, 0.0) + 2.5 * g.propagation_dir
    ref = np.eye(4)
    alone = _truth(rig, plate, rig_from_plate, ref)
    assert np.isfinite(alone.stripe_u).sum() > 100

    def with_blocker(centre_rig):
        blocker = trimesh.creation.box(extents=(20.0, 20.0, 20.0))
        blocker.apply_translation(centre_rig)
        both = trimesh.util.concatenate([plate.copy().apply_transform(rig_from_plate), blocker])
        ids = np.r_[np.ones(12, int), np.full(12, 2)]
        return _truth(rig, both, np.eye(4), ref, ids)

    # a cube in the sheet near the laser (D = 200 mm, out of view): the plate is in its shadow
    # (the shadow of a ±10 mm cube at 200 mm covers ±30 mm at 600 mm > the plate's ±20 mm)
    shadowed = with_blocker(laser_origin_mm(rig) + 200.0 * g.propagation_dir)
    assert np.isnan(shadowed.stripe_u).all() and (shadowed.stripe_count == 0).all()
    # a cube beside the sheet on the camera's side, on the line of sight: hidden from the camera
    los = g.rig_from_sheet(600.0, 0.0)
    hidden = with_blocker(0.5 * los)
    assert abs(g.sheet_from_rig(0.5 * los)[2]) > 20  # the cube is off the sheet: the laser passes
    assert np.isnan(hidden.stripe_u[int(g.axis_row) - 5:int(g.axis_row) + 5]).all()


def test_cylinder_truth_points_lie_on_the_cylinder_and_in_the_sheet(rig):
    R, n_seg = 50.0, 720
    cyl = trimesh.creation.cylinder(radius=R, height=108.0, sections=n_seg)
    cyl.apply_translation((0, 0, 54.0))                                 # base on the table
    theta = 17.0
    rig_from_part = rig_from_stage(rig) @ stage_from_part(rig, theta)
    ref_from_part = stage_from_part(rig, 0.0)
    st = _truth(rig, cyl, rig_from_part, ref_from_part)
    ok = np.isfinite(st.stripe_u)
    assert ok.sum() > 500
    p_ref = st.stripe_point_mm[ok]
    r = np.hypot(p_ref[:, 0], p_ref[:, 1])
    # on the polygonal mesh: between the inscribed and circumscribed radii of the 720-gon
    assert np.all(r <= R + 1e-9) and np.all(r >= R * math.cos(math.pi / n_seg) - 1e-9)
    # in the sheet of frame θ: mapped back to the stage frame at θ its y is 0 and the stripe
    # sits on the near side of the axis (x < 0, toward the laser)
    p_stage = transform_points(stage_from_part(rig, theta) @ np.linalg.inv(ref_from_part), p_ref)
    np.testing.assert_allclose(p_stage[:, 1], 0.0, atol=1e-9)
    assert np.all(p_stage[:, 0] < 0)
    # and the INTERFACE formula maps (D, h) of the truth pixel back to the same point
    g = hinge_geometry(rig)
    D, h = g.sheet_from_pixel(st.stripe_u[ok], np.flatnonzero(ok))
    assert np.max(np.abs(D - (p_stage[:, 0] + rig.stage.axis_mm - rig.stage.d0_mm))) < 1e-6


def test_sheet_section_through_vertices_has_no_gaps():
    # a plane exactly through vertices of a box (z = 0 of a box spanning ±1): closed loop
    box = trimesh.creation.box(extents=(2.0, 2.0, 2.0))
    seg, _ = sheet_section(box.vertices, box.faces, np.ones(12), [0, 0, 1.0], [0, 0, 1.0])
    pts = np.round(seg.reshape(-1, 3), 12)
    assert np.allclose(pts[:, 2], 1.0)
    # every end point is shared by an even number of segment ends (closed polyline)
    _, counts = np.unique(pts, axis=0, return_counts=True)
    assert np.all(counts % 2 == 0)


def test_row_crossings_on_a_misaligned_sensor_hit_the_row_centre(rig):
    r = rig.replace(sensor={"roll_deg": 1.5, "offset_v_px": 3.3}, lens={"k1": 0.02})
    g = hinge_geometry(r)
    seg = np.stack([g.rig_from_sheet(500.0, -40.0), g.rig_from_sheet(650.0, 60.0)])[None]
    rows, u, pts, _ = row_crossings(r, seg)
    from scheimpflug.model.camera import project_points
    uv = project_points(r, pts).uv_px
    np.testing.assert_allclose(uv[:, 1], rows, atol=1e-8)
    np.testing.assert_allclose(uv[:, 0], u, atol=1e-12)
    assert len(rows) > 500 and np.all(np.diff(rows) == 1)


def test_pixel_truth_plate_and_background(rig):
    rb = binned_rig(rig, 16)
    g = hinge_geometry(rb)
    sc = calibration_scenario(rb, steps=1, start_mm=120.0)
    f = sc.frames[0]
    mesh = sc.assembly.combined_mesh()
    caster = BruteForceCaster(transform_points(f.rig_from_part, mesh.vertices), mesh.faces,
                              np.ones(len(mesh.faces), int))
    ref_from_rig = f.ref_from_part @ np.linalg.inv(f.rig_from_part)
    point, obj = pixel_truth(rb, caster, ref_from_rig)
    assert point.shape == (rb.sensor.rows, rb.sensor.columns, 3) and point.dtype == np.float32
    assert obj.dtype == np.uint16
    hit = obj == 1
    assert 0 < hit.sum() < hit.size
    assert np.isnan(point[~hit]).all()
    # pixels on the plate's stripe column see the measured face at stage x = s - axis
    u_col = int(round(float(g.column_from_distance(120.0 - rb.stage.d0_mm))))
    col = point[hit[:, u_col], u_col]
    assert len(col) > 10
    assert np.all(np.abs(col[:, 0] - (120.0 - rb.stage.axis_mm)) < 0.05)


def test_rig_truth_is_the_closed_form(rig):
    t = rig_truth(rig)
    g = hinge_geometry(rig)
    assert t["hinge_px"] == [3196.0, 771.0]
    assert t["F2_px_mm"] == pytest.approx(-1.4292e6, rel=1e-4)
    assert t["C_mm"] == pytest.approx(149.10, abs=0.01)
    assert t["D_axis_mm"] == pytest.approx(645.45)
    assert t["ideal"] is True
    assert rig_truth(rig.replace(sensor={"roll_deg": 0.1}))["ideal"] is False
    assert t["tilt_deg"] == pytest.approx(g.tilt_deg)


def test_binned_rig_keeps_the_geometry(rig):
    from scheimpflug.model.camera import project_points
    rb = binned_rig(rig, 4)
    P = hinge_geometry(rig).rig_from_sheet(np.array([480.0, 600.0, 700.0]), np.array([-30, 5, 50.]))
    uv, uvb = project_points(rig, P).uv_px, project_points(rb, P).uv_px
    np.testing.assert_allclose(uvb, (uv - 1.5) / 4, atol=1e-9)
    assert (rb.sensor.columns, rb.sensor.rows) == (304, 484)
    assert hinge_geometry(rb).F2_px_mm == pytest.approx(hinge_geometry(rig).F2_px_mm / 4)


def test_same_geometry_same_truth_hash(rig):
    sc = calibration_scenario(rig, steps=1, start_mm=40.0)
    f = sc.frames[0]
    mesh = sc.assembly.combined_mesh()

    def digest():
        st = _truth(rig, mesh, f.rig_from_part, f.ref_from_part)
        return hashlib.sha256(b"".join(a.tobytes() for a in st.arrays().values())).hexdigest()

    assert digest() == digest()


@pytest.mark.render
def test_scenes_cylinder_truth_with_the_mitsuba_scene(rig):
    """The paper cylinder (scenes preset, smooth wall sagitta 0.1 µm) through SimScene:
    truth points on the wall to < 1 µm above the knurl, in the sheet, on their rows."""
    from sim.scenarios import rotary_scenario
    from sim.scene import SimScene
    from sim.truth import SceneCaster

    sc = rotary_scenario(rig, part="cylinder", step_deg=37.0, frames=2)
    asm = sc.assembly
    analytic = asm.parts[0].analytic
    R = analytic["radius_mm"]
    knurl_top = analytic["smooth_z_range_mm"][0] + rig.stage.rotary_table_z_mm
    mesh = asm.combined_mesh()
    ids = asm.face_object_ids()
    scene = SimScene(asm.parts)
    f = sc.frames[1]
    scene.set_pose(f.rig_from_part)
    st = stripe_truth(rig, mesh.vertices, mesh.faces, ids, f.rig_from_part, f.ref_from_part,
                      SceneCaster(scene))
    ok = np.isfinite(st.stripe_u)
    p = st.stripe_point_mm[ok]
    assert ok.sum() > 1000
    smooth = p[:, 2] > knurl_top + 0.5
    r = np.hypot(p[smooth, 0], p[smooth, 1])
    assert np.max(np.abs(r - R)) < 1e-3
    p_stage = transform_points(stage_from_part(rig, 37.0) @ np.linalg.inv(f.ref_from_part), p)
    np.testing.assert_allclose(p_stage[:, 1], 0.0, atol=1e-9)
    # each truth point, projected with the camera model, lands on its row centre
    from scheimpflug.model.camera import project_points
    rig_from_ref = f.rig_from_part @ np.linalg.inv(f.ref_from_part)
    uv = project_points(rig, transform_points(rig_from_ref, p)).uv_px
    np.testing.assert_allclose(uv[:, 1], np.flatnonzero(ok), atol=1e-6)
    np.testing.assert_allclose(uv[:, 0], st.stripe_u[ok], atol=1e-6)


def test_part_off_the_sheet_gives_an_empty_truth(rig):
    box = trimesh.creation.box(extents=(10.0, 10.0, 10.0))
    box.apply_translation((600.0, 500.0, 0.0))                        # far beside the sheet
    ids = np.ones(12, int)
    st = stripe_truth(rig, box.vertices, box.faces, ids, np.eye(4), np.eye(4),
                      BruteForceCaster(box.vertices, box.faces, ids))
    assert np.isnan(st.stripe_u).all() and np.isnan(st.stripe_point_mm).all()
    assert (st.stripe_count == 0).all() and (st.stripe_object_id == 0).all()
