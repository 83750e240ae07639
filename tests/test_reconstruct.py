"""Reconstruction core: closed-form round trip from known part-frame points."""

import types

import numpy as np
import pytest

from scheimpflug.model.hinge import stage_from_pixel as sheet_from_pixel
from scheimpflug.reconstruct import PointCloud, part_from_sheet, points_from_pixels, reconstruct_profiles

# paper-rig nominal constants (docs/explanation/design-notes.md §3), independent of the code under test
CAL = types.SimpleNamespace(hinge_u_px=3196.0, hinge_v_px=771.0, F2_px_mm=-1.4292e6,
                            d0_mm=-466.0, C_mm=149.10)
AXIS_MM = 179.45


def _pixels_of(points, angle_deg):
    """Invert the closed forms: part point → sheet (rotate by +θ) → (u, v)."""
    th = np.radians(angle_deg)
    x, y, z = points.T
    r = x * np.cos(th) - y * np.sin(th)              # R_z(θ)·p has y' = x sin θ + y cos θ = 0
    s = r + AXIS_MM
    du = CAL.F2_px_mm / (s - CAL.d0_mm)
    return CAL.hinge_u_px + du, CAL.hinge_v_px + du * z / CAL.C_mm


def test_sheet_point_at_angle_zero_is_on_x_axis():
    s, h = sheet_from_pixel(3196.0 + CAL.F2_px_mm / (AXIS_MM + 40 - CAL.d0_mm), 771.0, 3196.0, 771.0,
                            CAL.F2_px_mm, CAL.d0_mm, CAL.C_mm)
    assert s == pytest.approx(AXIS_MM + 40, abs=1e-9) and h == 0
    np.testing.assert_allclose(part_from_sheet(s, h, 0.0, AXIS_MM), [[40, 0, 0]], atol=1e-9)
    # a quarter turn counter-clockwise brings the part's -y side into the sheet at +x
    np.testing.assert_allclose(part_from_sheet(s, h, 90.0, AXIS_MM), [[0, -40, 0]], atol=1e-9)


def test_round_trip_random_points_and_angles(rng):
    n_frames = 24
    angles = np.sort(rng.uniform(-180, 180, n_frames))
    rows, us, truth = [], [], []
    for th in angles:
        # points of the part that lie in the sheet at this angle: p = R_z(-θ)(r, 0, h)
        r = rng.uniform(-60, 60, 50)
        h = rng.uniform(-40, 40, 50)
        t = np.radians(th)
        pts = np.column_stack([r * np.cos(t), -r * np.sin(t), h])
        u, v = _pixels_of(pts, th)
        rows.append(v)
        us.append(u)
        truth.append(pts)
    cloud = reconstruct_profiles(rows, us, angles, CAL, AXIS_MM,
                                 intensity=[np.full(len(u), 7.0) for u in us])
    # rows are stored as int, so compare the xyz from the exact (float) rows
    xyz = points_from_pixels(np.concatenate(us), np.concatenate(rows), np.repeat(angles, 50), CAL, AXIS_MM)
    np.testing.assert_allclose(xyz, np.vstack(truth), atol=1e-9, rtol=0)
    assert len(cloud) == n_frames * 50
    np.testing.assert_allclose(cloud.xyz_mm[:, :2], np.vstack(truth)[:, :2], atol=1e-9)
    assert np.all(cloud.intensity == 7.0)
    assert np.array_equal(cloud.angle_deg, np.repeat(angles, 50))  # exact: copy


def test_integer_rows_round_trip(rng):
    angles = [0.0, 33.0]
    rows = [np.arange(100, 400, 7), np.arange(900, 1500, 11)]
    us = [rng.uniform(0, 1215, len(r)) for r in rows]
    cloud = reconstruct_profiles(rows, us, angles, CAL, AXIS_MM)
    back_u, back_v = _pixels_of(cloud.xyz_mm, cloud.angle_deg)
    np.testing.assert_allclose(back_u, np.concatenate(us), atol=1e-9)
    np.testing.assert_allclose(back_v, np.concatenate(rows), atol=1e-9)
    assert cloud.row.dtype == np.int64 and np.array_equal(cloud.row, np.concatenate(rows))  # exact: integers


def test_hinge_column_dropped():
    cloud = reconstruct_profiles([np.array([1, 2, 3])], [np.array([100.0, 3196.0, np.nan])], [0.0],
                                 CAL, AXIS_MM)
    assert len(cloud) == 1 and np.all(np.isfinite(cloud.xyz_mm))


def test_empty_scan_gives_empty_cloud():
    cloud = reconstruct_profiles([np.zeros(0, int)], [np.zeros(0)], [0.0], CAL, AXIS_MM)
    assert len(cloud) == 0 and cloud.xyz_mm.shape == (0, 3)


@pytest.mark.parametrize("rows, u, angles", [
    ([np.arange(3)], [np.zeros(3)], [0.0, 1.0]),
    ([np.arange(3)], [np.zeros(4)], [0.0]),
])
def test_mismatched_inputs_raise(rows, u, angles):
    with pytest.raises(ValueError):
        reconstruct_profiles(rows, u, angles, CAL, AXIS_MM)


def test_point_cloud_shape_check():
    with pytest.raises(ValueError):
        PointCloud(np.zeros((3, 3)), np.zeros(2), np.zeros(3, int), np.zeros(3))
