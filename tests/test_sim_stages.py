"""Stage transforms against the docs/reference/interface.md conventions (known truth)."""

import math

import numpy as np
import pytest

from scheimpflug.model.hinge import hinge_geometry
from scheimpflug.model.rig import load_preset
from sim.stages import (
    axis_distance_mm,
    invert,
    rig_from_plate,
    rig_from_stage,
    rotation_z,
    stage_from_part,
    stage_from_plate,
    transform_points,
)


@pytest.fixture(scope="module")
def rig():
    return load_preset("paper")


def test_rig_from_stage_axes_and_origin(rig):
    g = hinge_geometry(rig)
    m = rig_from_stage(rig)
    np.testing.assert_allclose(m[:3, :3].T @ m[:3, :3], np.eye(3), atol=1e-15)
    assert np.linalg.det(m[:3, :3]) == pytest.approx(1.0)
    # the origin lies on the sheet at D = axis_mm - d0 = 645.45 mm, h = 0
    D, h, off = g.sheet_from_rig(m[:3, 3])
    assert D == pytest.approx(179.45 + 466.0, abs=1e-12)
    assert h == pytest.approx(0.0, abs=1e-12) and off == pytest.approx(0.0, abs=1e-12)
    # stage y = 0 is the sheet: random stage points with y = 0 have zero sheet offset
    p = np.random.default_rng(1).uniform(-100, 100, (50, 3))
    p[:, 1] = 0
    _, _, off = g.sheet_from_rig(transform_points(m, p))
    np.testing.assert_allclose(off, 0, atol=1e-12)
    # stage +y is the camera side (positive sheet offset)
    assert g.sheet_from_rig(transform_points(m, [0, 1.0, 0]))[2] == pytest.approx(1.0)


def test_point_on_axis_fixed_and_quarter_turn(rig):
    for theta in (0.0, 33.0, 90.0, 271.5):
        m = stage_from_part(rig, theta)
        z_t = rig.stage.rotary_table_z_mm
        np.testing.assert_allclose(transform_points(m, [0, 0, 12.5]), [0, 0, 12.5 + z_t], atol=1e-12)
    r, z = 50.0, 20.0
    p = transform_points(stage_from_part(rig, 90.0), [r, 0, z])
    np.testing.assert_allclose(p, [0, r, z + rig.stage.rotary_table_z_mm], atol=1e-12)


def test_interface_formula_inverts_the_rotary_stage(rig):
    # A part point seen on the sheet at (D, h) in the frame at θ is, in the reference
    # frame (stage frame, part at θ = 0), R_z(-θ)·(D - D_axis, 0, h).
    g = hinge_geometry(rig)
    rng = np.random.default_rng(2)
    ref_from_part = stage_from_part(rig, 0.0)
    for theta in rng.uniform(0, 360, 5):
        D, h = rng.uniform(450, 720), rng.uniform(-60, 60)
        p_rig = g.rig_from_sheet(D, h)
        p_part = transform_points(invert(rig_from_stage(rig) @ stage_from_part(rig, theta)), p_rig)
        p_ref = transform_points(ref_from_part, p_part)
        expected = transform_points(rotation_z(-theta), [D - axis_distance_mm(rig), 0, h])
        np.testing.assert_allclose(p_ref, expected, atol=1e-9)


def test_translation_stage_face_at_s_minus_d0(rig):
    g = hinge_geometry(rig)
    for s in (0.0, 130.0, 260.0):
        m = rig_from_plate(rig, s)
        corners = transform_points(m, [[0, -20, 0], [0, 25, 89.0], [0, 0, 40.0]])
        D, h, off = g.sheet_from_rig(corners)
        np.testing.assert_allclose(D, s - rig.stage.d0_mm, atol=1e-12)
        np.testing.assert_allclose(h, np.array([0, 89.0, 40.0]) + rig.stage.calibration_table_z_mm,
                                   atol=1e-12)
        np.testing.assert_allclose(off, [-20, 25, 0], atol=1e-12)
        np.testing.assert_allclose(stage_from_plate(rig, s),
                                   [[1, 0, 0, s - rig.stage.axis_mm], [0, 1, 0, 0],
                                    [0, 0, 1, rig.stage.calibration_table_z_mm], [0, 0, 0, 1]],
                                   atol=1e-12)


def test_axis_tilt_tilts_the_rotation_axis(rig):
    tau, psi = 2.0, 30.0
    r = rig.replace(stage={"axis_tilt_deg": tau, "axis_tilt_azimuth_deg": psi})
    t, p = math.radians(tau), math.radians(psi)
    a = np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])
    z_t = r.stage.rotary_table_z_mm
    for theta in (0.0, 90.0, 200.0):
        m = stage_from_part(r, theta)
        # the part's z axis is the bearing axis a through the table centre
        np.testing.assert_allclose(m[:3, 2], a, atol=1e-12)
        np.testing.assert_allclose(transform_points(m, [0, 0, 100.0]), [0, 0, z_t] + 100 * a,
                                   atol=1e-12)
    # a point off the axis moves on a circle about a: its projection on a is constant
    pts = np.array([transform_points(stage_from_part(r, th), [40.0, 10.0, 5.0]) - [0, 0, z_t]
                    for th in np.linspace(0, 350, 8)])
    np.testing.assert_allclose(pts @ a, (pts @ a)[0], atol=1e-12)


def test_runout_is_once_per_turn_with_tir_amplitude(rig):
    r = rig.replace(stage={"runout_um": 20.0})
    # the part's own axis (part origin) circles the bearing axis with radius 10 µm
    centres = np.array([transform_points(stage_from_part(r, th), [0, 0, 0])
                        for th in np.linspace(0, 360, 73)])
    radius = np.hypot(centres[:, 0], centres[:, 1])
    np.testing.assert_allclose(radius, 0.010, atol=1e-12)
    # a dial indicator on the part axis along +x reads 20 µm peak to peak
    assert np.ptp(centres[:, 0]) == pytest.approx(0.020, abs=1e-12)


def test_invert_round_trip(rig):
    m = rig_from_stage(rig) @ stage_from_part(rig.replace(stage={"axis_tilt_deg": 1.0}), 37.0)
    np.testing.assert_allclose(invert(m) @ m, np.eye(4), atol=1e-12)
    with pytest.raises(ValueError, match="4×4"):
        invert(np.eye(3))
