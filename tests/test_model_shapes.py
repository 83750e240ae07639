"""Shape checks at the door of the model's geometry functions (kornia's template: bad input, output shape).

Every public function of :mod:`scheimpflug.model.camera` and :mod:`scheimpflug.model.hinge`
that takes point or pixel arrays refuses a wrong shape with a ValueError saying what it
expected and what came, and keeps working (with the leading shape preserved) on right ones.
"""

import re

import numpy as np
import pytest

from scheimpflug.calibration import Calibration
from scheimpflug.model.camera import (
    blur_footprint_px,
    chief_ray_from_pixel,
    conjugate_point,
    pixel_from_sensor_point,
    project_points,
    sensor_point_from_pixel,
    sensor_pose,
    sheet_point_from_pixel,
)
from scheimpflug.model.hinge import hinge_geometry, pixel_from_stage, stage_from_pixel, stage_jacobian

# (name, argument name, last dimension, call(rig, array))
POINT_FUNCTIONS = [
    ("conjugate_point", "points_mm", 3, lambda rig, a: conjugate_point(rig, a)),
    ("project_points", "points_mm", 3, lambda rig, a: project_points(rig, a).uv_px),
    ("blur_footprint_px", "points_mm", 3, lambda rig, a: blur_footprint_px(rig, a, n_angles=8)[0]),
    ("pixel_from_sensor_point", "q_mm", 3, lambda rig, a: pixel_from_sensor_point(sensor_pose(rig), a)),
    ("sheet_from_rig", "points_mm", 3, lambda rig, a: hinge_geometry(rig).sheet_from_rig(a)[0]),
    ("sensor_point_from_pixel", "uv_px", 2, lambda rig, a: sensor_point_from_pixel(sensor_pose(rig), a)),
    ("chief_ray_from_pixel", "uv_px", 2, lambda rig, a: chief_ray_from_pixel(rig, a)),
    ("sheet_point_from_pixel", "uv_px", 2, lambda rig, a: sheet_point_from_pixel(rig, a)),
]
IDS = [f[0] for f in POINT_FUNCTIONS]


def _valid(rig, n_last: int, shape: tuple) -> np.ndarray:
    """Points on the sheet in the working range (n_last = 3) or pixels on the sensor (n_last = 2)."""
    g = hinge_geometry(rig)
    k = int(np.prod(shape, dtype=int))
    t = np.linspace(0.1, 0.9, k).reshape(shape)
    if n_last == 3:
        return g.rig_from_sheet(500.0 + 150.0 * t, 40.0 * (t - 0.5))
    return np.stack([t * rig.sensor.columns, (1 - t) * rig.sensor.rows], axis=-1)


@pytest.mark.parametrize(("name", "arg", "n", "call"), POINT_FUNCTIONS, ids=IDS)
@pytest.mark.parametrize("bad_shape", [(5, 1), (5, 4), (), (2, 3, 6)])
def test_wrong_last_dimension_is_refused(paper_rig, name, arg, n, call, bad_shape):
    bad = np.ones(bad_shape)
    with pytest.raises(ValueError, match=re.escape(f"{arg} must have shape (..., {n}), got {bad.shape}")):
        call(paper_rig, bad)


@pytest.mark.parametrize(("name", "arg", "n", "call"), POINT_FUNCTIONS, ids=IDS)
def test_the_other_width_is_refused(paper_rig, name, arg, n, call):
    """Pixels where points are due and points where pixels are due: the mix-up the check is for."""
    other = 5 - n                      # 3 → 2, 2 → 3
    with pytest.raises(ValueError, match=re.escape(f"got (5, {other})")):
        call(paper_rig, np.ones((5, other)))


@pytest.mark.parametrize(("name", "arg", "n", "call"), POINT_FUNCTIONS, ids=IDS)
@pytest.mark.parametrize("lead", [(), (7,), (2, 4)])
def test_right_shapes_keep_their_leading_shape(paper_rig, name, arg, n, call, lead):
    out = np.asarray(call(paper_rig, _valid(paper_rig, n, lead) if lead else _valid(paper_rig, n, (1,))[0]))
    assert out.shape[:len(lead)] == lead
    assert np.all(np.isfinite(out))


def test_sensor_point_from_pixel_no_longer_slices_wide_arrays(paper_rig):
    """Before the check, an (n, 3) array silently used its first two columns."""
    pose = sensor_pose(paper_rig)
    uv = _valid(paper_rig, 2, (6,))
    with pytest.raises(ValueError, match=re.escape("uv_px must have shape (..., 2), got (6, 3)")):
        sensor_point_from_pixel(pose, np.column_stack([uv, np.zeros(6)]))
    # the right shape still round-trips through the sensor plane
    back = pixel_from_sensor_point(pose, sensor_point_from_pixel(pose, uv.reshape(2, 3, 2)))
    np.testing.assert_allclose(back, uv.reshape(2, 3, 2), atol=1e-9)


def test_hinge_closed_forms_refuse_shapes_that_do_not_broadcast():
    k = (3196.0, 771.0, -1.0e5, -466.0, 200.0)
    with pytest.raises(ValueError, match=re.escape("u_px and v_px must broadcast together, "
                                                   "got shapes (5,) and (3,)")):
        stage_from_pixel(np.arange(5.0), np.arange(3.0), *k)
    with pytest.raises(ValueError, match=re.escape("stage_mm and h_mm must broadcast together")):
        pixel_from_stage(np.arange(5.0), np.arange(3.0), *k)
    with pytest.raises(ValueError, match=re.escape("u_px and v_px must broadcast together")):
        stage_jacobian(np.arange(4.0), np.ones((2, 3)), k[0], k[1], k[2], k[4])
    cal = Calibration(*k[:3], 0.0, k[3], k[4], 0.0, (1.0, 1.0), "refined", 1216, 1936)
    with pytest.raises(ValueError, match="must broadcast together"):
        cal.stage_from_pixel(np.arange(5.0), np.arange(3.0))


def test_hinge_closed_forms_still_broadcast(paper_rig):
    g = hinge_geometry(paper_rig)
    u = np.linspace(0.0, 1215.0, 6).reshape(2, 3)
    D, h = g.sheet_from_pixel(u, 100.0)                       # (2, 3) with a scalar row
    assert D.shape == h.shape == (2, 3)
    u2, v2 = g.pixel_from_sheet(D, h[:1])                      # (2, 3) with (1, 3)
    np.testing.assert_allclose(u2, u, atol=1e-9)
    np.testing.assert_allclose(v2[0], 100.0, atol=1e-9)
    assert g.rig_from_sheet(D, 0.0).shape == (2, 3, 3)
    with pytest.raises(ValueError, match=re.escape("distance_mm and height_mm must broadcast together")):
        g.rig_from_sheet(np.ones(5), np.ones(3))
