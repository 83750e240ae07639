"""Hinge-rule geometry against closed forms (docs/explanation/design-notes.md §3, paper Eqs. 1, 5, 6, 8, 11–14).

The expected values are computed here from the textbook formulas (Gaussian
lens equation, Newton's form), independently of scheimpflug.model.hinge/camera.
"""

import math

import numpy as np
import pytest

from scheimpflug.model.camera import (
    SensorPose,
    blur_footprint_px,
    project_points,
    sensor_point_from_pixel,
    sensor_pose,
    sheet_point_from_pixel,
)
from scheimpflug.model.design import design_report, focal_length_from_endpoint
from scheimpflug.model.hinge import hinge_geometry
from scheimpflug.model.rig import rig_from_dict


def _rig(f=55.0, d=150.0, t=0.2075, **sensor):
    return rig_from_dict({"lens": {"focal_length_mm": f}, "laser": {"scheimpflug_distance_mm": d, "tan_phi": t},
                          "sensor": sensor})


def _sheet_points(rig, rng, n=200):
    """Random rig points on the sheet y = d − x·tan φ, x in the working range."""
    f, d, t = rig.lens.focal_length_mm, rig.laser.scheimpflug_distance_mm, rig.laser.tan_phi
    x = rng.uniform(3 * f, 15 * f, n)
    z = rng.uniform(-60, 60, n)
    return np.stack([x, d - x * t, z], axis=-1)


def _gauss_conjugate(f, p):
    """Textbook thin lens: 1/a + 1/b = 1/f, image inverted through the centre."""
    a = p[..., 0]
    b = f * a / (a - f)
    return -(b / a)[..., None] * p


RIGS = [dict(), dict(f=35.0, d=100.0, t=0.1), dict(f=85.0, d=300.0, t=0.5), dict(f=55.0, d=150.0, t=0.0),
        dict(f=50.0, d=120.0, t=-0.3)]


@pytest.mark.parametrize("kw", RIGS)
def test_conjugates_of_the_sheet_lie_on_the_tilted_sensor(kw, rng):
    """Paper Eq. 5: the image of the sheet is a plane through (0, d) with tan β = f/(d − f tan φ)."""
    rig = _rig(**kw)
    f, d, t = rig.lens.focal_length_mm, rig.laser.scheimpflug_distance_mm, rig.laser.tan_phi
    img = _gauss_conjugate(f, _sheet_points(rig, rng))
    # the line through (0, d) and each image point makes angle β with the lens plane (x = 0)
    tan_b = -img[:, 0] / (d - img[:, 1])
    np.testing.assert_allclose(tan_b, f / (d - f * t), rtol=1e-12)
    pose = sensor_pose(rig)
    np.testing.assert_allclose((img - pose.origin_mm) @ pose.normal, 0.0, atol=1e-9)
    np.testing.assert_allclose(math.tan(hinge_geometry(rig).beta_rad), f / (d - f * t), rtol=1e-14)


@pytest.mark.parametrize("kw", RIGS)
def test_hinge_line_is_parallel_to_the_sensor(kw):
    """Paper Eq. 6: the line from the lens centre to the object hinge H = (f, d − f tan φ) ∥ sensor."""
    rig = _rig(**kw)
    f, d, t = rig.lens.focal_length_mm, rig.laser.scheimpflug_distance_mm, rig.laser.tan_phi
    oh = np.array([f, d - f * t, 0.0])
    pose = sensor_pose(rig)
    assert abs(np.dot(oh / np.linalg.norm(oh), pose.normal)) < 1e-14
    np.testing.assert_allclose(hinge_geometry(rig).object_hinge_mm, oh, rtol=0, atol=1e-12)


@pytest.mark.parametrize("kw", RIGS)
def test_newton_for_random_sheet_points_through_the_general_projection(kw, rng):
    """x·x' = −f² (x, x' from the front/back focal planes) for the pixel each sheet point lands on."""
    rig = _rig(**kw)
    f = rig.lens.focal_length_mm
    p = _sheet_points(rig, rng)
    uv = project_points(rig, p).uv_px
    q = sensor_point_from_pixel(sensor_pose(rig), uv)
    np.testing.assert_allclose((p[:, 0] - f) * (q[:, 0] + f), -f * f, rtol=1e-10)
    # and the pixel holds the textbook conjugate (in focus: the sheet is on the sensor)
    np.testing.assert_allclose(q, _gauss_conjugate(f, p), atol=1e-9)


def test_closed_forms_match_the_general_projection(paper_rig, rng):
    """D = F²/(u − u_h), h = C (v − v_h)/(u − u_h) with F² = −f²/(p cos φ sin β), C = f/sin β."""
    f, d, t, p = 55.0, 150.0, 0.2075, 5.86e-3
    beta = math.atan(f / (d - f * t))
    F2 = -f * f / (p * math.cos(math.atan(t)) * math.sin(beta))
    C = f / math.sin(beta)
    D = rng.uniform(450, 720, 300)
    h = rng.uniform(-50, 50, 300)
    g = hinge_geometry(paper_rig)
    uv = project_points(paper_rig, g.rig_from_sheet(D, h)).uv_px
    np.testing.assert_allclose(F2 / (uv[:, 0] - 3196.0), D, rtol=1e-11)
    np.testing.assert_allclose(C * (uv[:, 1] - 771.0) / (uv[:, 0] - 3196.0), h, atol=1e-9)


def test_lines_parallel_to_propagation_image_through_the_hinge_pixel(paper_rig):
    """Paper Eq. 8: a sheet line at constant height images to a straight line through (u_h, v_h)."""
    g = hinge_geometry(paper_rig)
    for h in (-54.0, -10.0, 35.0):
        uv = project_points(paper_rig, g.rig_from_sheet(np.linspace(450, 720, 25), np.full(25, h))).uv_px
        coef = np.polyfit(uv[:, 0], uv[:, 1], 1)
        assert np.max(np.abs(np.polyval(coef, uv[:, 0]) - uv[:, 1])) < 1e-8  # straight
        assert abs(np.polyval(coef, 3196.0) - 771.0) < 1e-6  # through the hinge pixel


@pytest.mark.parametrize("mis", [{}, {"roll_deg": 1.5, "tilt_error_deg": -0.7, "offset_u_px": 12.0,
                                      "offset_v_px": -4.0, "offset_normal_um": 30.0}])
def test_round_trip_pixel_sheet_pixel(mis, rng):
    rig = rig_from_dict({"sensor": mis, "lens": {"k1": 0.02, "k2": -0.004} if mis else {}})
    uv = np.stack([rng.uniform(0, 1215, 500), rng.uniform(0, 1935, 500)], axis=-1)
    back = project_points(rig, sheet_point_from_pixel(rig, uv)).uv_px
    np.testing.assert_allclose(back, uv, atol=1e-9, rtol=0)


def test_closed_form_round_trip(paper_rig, rng):
    g = hinge_geometry(paper_rig)
    u, v = rng.uniform(0, 1215, 100), rng.uniform(0, 1935, 100)
    u2, v2 = g.pixel_from_sheet(*g.sheet_from_pixel(u, v))
    np.testing.assert_allclose(np.stack([u2, v2]), np.stack([u, v]), atol=1e-9, rtol=0)


def test_off_sheet_point_has_the_thin_lens_blur_circle(paper_rig):
    """Along one chief ray: c = A·|v_s − v|/v with v = f·x/(x − f) (textbook circle of confusion)."""
    f, N = 55.0, 5.6
    g = hinge_geometry(paper_rig)
    p0 = g.rig_from_sheet(np.array(600.0), np.array(10.0))
    for k in (0.9, 0.97, 1.05, 1.2):
        p = p0 * k  # same chief ray, another distance
        v_s, v = f * p0[0] / (p0[0] - f), f * p[0] / (p[0] - f)
        c = (f / N) * abs(v_s - v) / v
        pr = project_points(paper_rig, p)
        assert abs(pr.blur_diameter_mm - c) < 1e-12 * max(c, 1)
        # the spot on the tilted sensor: along rows (parallel to the lens plane) it is the circle
        du, dv = blur_footprint_px(paper_rig, p)
        assert abs(dv * 5.86e-3 / c - 1) < 0.05
        assert du * 5.86e-3 > c  # stretched along the tilt direction


def test_zero_tilt_sensor_behaves_as_a_normal_camera(rng):
    """A sensor parallel to the lens plane at image distance b: pinhole projection and textbook blur."""
    rig = _rig()
    f, b, p = 55.0, 60.0, 5.86e-3
    pose = SensorPose(origin_mm=np.array([-b, 600 * p, 500 * p]), u_dir=np.array([0.0, -1.0, 0.0]),
                      v_dir=np.array([0.0, 0.0, -1.0]), pitch_mm=p, columns=1200, rows=1000)
    pts = np.stack([rng.uniform(300, 900, 50), rng.uniform(-40, 40, 50), rng.uniform(-40, 40, 50)], -1)
    pr = project_points(rig, pts, pose)
    u_pin = 600 + b * pts[:, 1] / pts[:, 0] / p
    v_pin = 500 + b * pts[:, 2] / pts[:, 0] / p
    np.testing.assert_allclose(pr.uv_px, np.stack([u_pin, v_pin], -1), atol=1e-9)
    v_img = f * pts[:, 0] / (pts[:, 0] - f)
    np.testing.assert_allclose(pr.blur_diameter_mm, (f / 5.6) * np.abs(b - v_img) / v_img, rtol=1e-12)


def test_sheet_parallel_to_axis_phi_zero():
    """φ = 0: tan β = f/d, D is the depth beyond the focal plane and F² = −f²/(p sin β)."""
    rig = _rig(t=0.0)
    g = hinge_geometry(rig)
    assert math.isclose(g.tan_beta, 55.0 / 150.0, rel_tol=1e-15)
    x = np.array([300.0, 500.0])
    uv = project_points(rig, np.stack([x, [150.0, 150.0], [0.0, 0.0]], -1)).uv_px
    np.testing.assert_allclose(g.F2_px_mm / (uv[:, 0] - 3196.0), x - 55.0, rtol=1e-12)
    assert math.isclose(g.F2_px_mm, -55.0**2 / (5.86e-3 * math.sin(math.atan(55 / 150))), rel_tol=1e-14)


# Nominal column of docs/explanation/design-notes.md §3 (value, significant figures given there)
NOMINAL = {
    "tilt_deg": (21.646, 5), "tan_beta": (0.39686, 5), "F2_px_mm": (-1.4292e6, 5), "C_mm": (149.10, 5),
    "depth_range_mm": (274.3, 4), "distance_resolution_center_mm": (0.213, 3),
    "height_resolution_center_mm": (0.058, 2), "height_range_near_mm": (90.3, 3),
    "height_range_far_mm": (145.8, 4), "focal_length_check_mm": (55.0, 3),
}


def _sig(x, n):
    return float(f"{x:.{n - 1}e}")


@pytest.mark.parametrize("key", sorted(NOMINAL))
def test_paper_preset_reproduces_the_nominal_column(paper_rig, key):
    value, digits = NOMINAL[key]
    assert _sig(design_report(paper_rig)[key], digits) == pytest.approx(value, rel=1e-12)


def test_paper_distance_range(paper_rig):
    near, far = design_report(paper_rig)["distance_range_mm"]
    assert (_sig(near, 4), _sig(far, 4)) == (447.2, 721.5)


def test_paper_focal_length_check_eqs_13_14(paper_rig):
    """Eqs. 13–14: the twin images stage zero (D = 466 mm) at column 129.0 and gives back f = 55.0;
    the paper's own column 97 gives 55.29 (the paper, rounding x_M' to −6.71 mm, wrote 55.33)."""
    g = hinge_geometry(paper_rig)
    u0 = float(g.column_from_distance(466.0))
    assert round(u0, 1) == 129.0
    assert _sig(focal_length_from_endpoint(g, u0, 466.0), 3) == 55.0
    f97 = focal_length_from_endpoint(g, 97.0, 466.0)
    assert abs(f97 - 55.33) / 55.33 < 0.001
