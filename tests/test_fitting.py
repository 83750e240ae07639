"""Fits recover known parameters from synthetic points in random poses."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from scheimpflug.fitting import (
    fit_circle,
    fit_circle_top_view,
    fit_cylinder,
    fit_plane,
    fit_plane_paper,
    fit_rigid,
)


@pytest.fixture
def rng():
    return np.random.default_rng(20240917)


def _angle_deg(a, b):
    return np.degrees(np.arccos(min(1.0, abs(np.dot(a, b)) / np.linalg.norm(a) / np.linalg.norm(b))))


@pytest.mark.parametrize("trial", range(5))
def test_plane_random_pose(rng, trial):
    rot = Rotation.random(random_state=rng.integers(1 << 31))
    offset = rng.uniform(-200, 200)
    local = np.column_stack([rng.uniform(-40, 40, 2000), rng.uniform(-30, 30, 2000),
                             offset + rng.normal(0, 0.02, 2000)])
    fit = fit_plane(rot.apply(local))
    normal = rot.apply([0, 0, 1.0])
    # 2000 points with sigma 0.02 mm over ±35 mm: normal tilt error ~ 0.02/(20*sqrt(2000)) rad
    assert _angle_deg(fit.normal, normal) < 0.005
    assert abs(abs(fit.offset_mm) - abs(offset)) < 0.005
    assert fit.rms_mm == pytest.approx(0.02, rel=0.1)


def test_plane_paper_form_recovers_coefficients(rng):
    # the paper's box side: y = -67.24 + 0.3902 x + 0.03029 z, noise 0.1775 mm in y
    x, z = rng.uniform(50, 250, 5000), rng.uniform(-30, 30, 5000)
    y = -67.24 + 0.3902 * x + 0.03029 * z + rng.normal(0, 0.1775, 5000)
    fit = fit_plane_paper(np.column_stack([x, y, z]))
    assert fit.a_mm == pytest.approx(-67.24, abs=0.03)
    assert fit.b == pytest.approx(0.3902, abs=2e-4)
    assert fit.c == pytest.approx(0.03029, abs=5e-4)
    assert fit.rmse_mm == pytest.approx(0.1775, rel=0.03)
    assert fit.rms_orthogonal_mm == pytest.approx(fit.rmse_mm / np.sqrt(1 + fit.b ** 2 + fit.c ** 2))


@pytest.mark.parametrize("trial", range(4))
def test_cylinder_random_pose(rng, trial):
    rot = Rotation.random(random_state=rng.integers(1 << 31))
    centre = rng.uniform(-100, 100, 3)
    n = 4000
    ang = rng.uniform(0, 2 * np.pi, n)
    h = rng.uniform(-54, 54, n)
    r = 50 + rng.normal(0, 0.02, n)
    pts = rot.apply(np.column_stack([r * np.cos(ang), r * np.sin(ang), h])) + centre
    fit = fit_cylinder(pts)
    axis = rot.apply([0, 0, 1.0])
    assert _angle_deg(fit.axis, axis) < 0.005
    assert fit.diameter_mm == pytest.approx(100.0, abs=0.005)
    assert fit.height_mm == pytest.approx(108.0, abs=0.2)
    # the centre lies on the true axis within 0.005 mm
    off = fit.centre_mm - centre
    assert np.linalg.norm(off - (off @ axis) * axis) < 0.005
    assert fit.rms_mm == pytest.approx(0.02, rel=0.1)


def test_cylinder_half_arc_with_guess(rng):
    rot = Rotation.random(random_state=7)
    ang = rng.uniform(0, np.pi, 3000)          # half the surface, as one side of a scan
    h = rng.uniform(-20, 20, 3000)
    pts = rot.apply(np.column_stack([34.5 * np.cos(ang), 34.5 * np.sin(ang), h]))
    pts += rng.normal(0, 0.01, pts.shape)
    fit = fit_cylinder(pts, axis_guess=rot.apply([0.05, 0.0, 1.0]))
    assert _angle_deg(fit.axis, rot.apply([0, 0, 1.0])) < 0.02
    assert fit.diameter_mm == pytest.approx(69.0, abs=0.01)


@pytest.mark.parametrize("method", ["pratt", "kasa"])
def test_circle_partial_arc(rng, method):
    centre = np.array([12.3, -45.6])
    ang = rng.uniform(0.3, 0.3 + 1.5 * np.pi, 2000)
    r = 34.5 + rng.normal(0, 0.05, ang.size)
    xy = centre + np.column_stack([r * np.cos(ang), r * np.sin(ang)])
    fit = fit_circle(xy, method=method)
    assert np.allclose(fit.centre_mm, centre, atol=0.01)
    assert fit.diameter_mm == pytest.approx(69.0, abs=0.01)
    # mean |N(0, s)| = s * sqrt(2/pi)
    assert fit.mean_abs_error_mm == pytest.approx(0.05 * np.sqrt(2 / np.pi), rel=0.08)


def test_circle_algebraic_exact_without_noise():
    ang = np.linspace(0, 1.0, 7)               # a short arc: exact data, any method is exact
    xy = np.column_stack([3 + 60 * np.cos(ang), -2 + 60 * np.sin(ang)])
    for method in ("pratt", "kasa"):
        fit = fit_circle(xy, method=method, refine=False)
        assert np.allclose(fit.centre_mm, [3, -2], atol=1e-7)
        assert fit.radius_mm == pytest.approx(60, abs=1e-7)


def test_circle_top_view_ignores_height(rng):
    ang = rng.uniform(0, 2 * np.pi, 500)
    pts = np.column_stack([5 + 60 * np.cos(ang), 7 + 60 * np.sin(ang), rng.uniform(-50, 50, 500)])
    fit = fit_circle_top_view(pts)
    assert fit.diameter_mm == pytest.approx(120, abs=1e-8)
    assert np.allclose(fit.centre_mm, [5, 7], atol=1e-8)


@pytest.mark.parametrize("fn, pts", [
    (fit_plane, np.zeros((2, 3))),
    (fit_plane, np.column_stack([np.arange(10.0), np.arange(10.0), np.arange(10.0)])),  # collinear
    (fit_plane, np.zeros((10, 2))),
    (fit_cylinder, np.column_stack([np.arange(10.0), np.zeros(10), np.arange(10.0) ** 2])),  # planar
    (fit_circle, np.column_stack([np.arange(10.0), 2 * np.arange(10.0)])),                  # a line
    (fit_circle, np.full((5, 2), np.nan)),
])
def test_degenerate_sets_raise(fn, pts):
    with pytest.raises(ValueError):
        fn(pts)


def test_fit_rigid_recovers_a_known_motion_and_tells_a_mirror_image():
    rng = np.random.default_rng(4)
    a = rng.uniform(-50, 50, (200, 3))
    r0 = Rotation.from_rotvec([0.3, -0.2, 1.1]).as_matrix()
    t0 = np.array([12.0, -3.0, 150.0])
    b = a @ r0.T + t0
    r, t, rms = fit_rigid(a, b)
    np.testing.assert_allclose(r, r0, atol=1e-12)
    np.testing.assert_allclose(t, t0, atol=1e-10)
    assert rms < 1e-10 and np.linalg.det(r) > 0
    mirrored = b * np.array([1.0, 1.0, -1.0])           # b's mirror image: no rotation maps a onto it
    assert fit_rigid(a, mirrored)[2] > 10.0 and fit_rigid(a, mirrored, mirror=True)[2] < 1e-10
    with pytest.raises(ValueError, match="n >= 3"):
        fit_rigid(a[:2], b[:2])
