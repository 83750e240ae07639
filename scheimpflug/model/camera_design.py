"""Design figures of an ordinary camera on the sheet: what it sees, how finely, where it is sharp.

An ordinary camera (``[sensor] image_distance_mm`` b > 0: the sensor perpendicular to the
optical axis) does not follow the hinge rule, so the closed forms of
:mod:`scheimpflug.model.hinge` (F², C, the tilt) do not describe it.  Its figures come
instead from the exact camera model the twin renders with (:mod:`scheimpflug.model.camera`):

* the field — the image of the sensor's border on the sheet
  (:func:`~scheimpflug.model.camera.sheet_point_from_pixel` of its outer pixel edges);
* the resolutions ΔZ = |∂D/∂a| and ΔX = |∂h/∂b| from the exact Jacobian
  (:func:`~scheimpflug.model.camera.sheet_jacobian`), a the sensor axis along which
  the distance D changes most (the stripe's position), b the other (along the stripe);
* acceptable focus where the thin-lens circle of confusion
  (:func:`~scheimpflug.model.camera.project_points`) is at most one pixel.

Sheet coordinates are the Scheimpflug rig's: D along the sheet from the object hinge
H = (f, d − f·tan φ, 0) (the sheet on the front focal plane, the origin of the stage
coordinates ``rig from-calibration`` writes), h = z above the meridian plane.
Pure functions; :func:`scheimpflug.model.design.design_report` calls
:func:`ordinary_camera_report`.
"""

from __future__ import annotations

import math

import numpy as np

from scheimpflug.model.camera import (
    lens_centre_mm,
    project_points,
    sensor_point_from_pixel,
    sensor_pose,
    sheet_jacobian,
    sheet_point_from_pixel,
)
from scheimpflug.model.distortion import fold_radius
from scheimpflug.model.hinge import hinge_geometry
from scheimpflug.model.plan import PART_MARGIN_PX, RotaryPlan
from scheimpflug.model.rig import DERIVED_STAGE_KEYS, Rig
from scheimpflug.model.volume import bisect_boundary, laser_fan

__all__ = [
    "HINGE_ONLY_KEYS",
    "distance_axis",
    "field_border_px",
    "focus_range_mm",
    "ordinary_camera_report",
    "ordinary_rotary_plan",
    "sheet_coordinates",
]

# design keys that only the hinge rule defines: null for an ordinary camera
HINGE_ONLY_KEYS = ("tilt_deg", "tan_beta", "hinge_px", "F2_px_mm", "C_mm", "image_hinge_mm",
                   "axis_column_px", "stage_zero_column_px", "focal_length_check_mm")
_BORDER_SAMPLES = 257      # samples per side of the sensor's border [-]
_FOCUS_SAMPLES = 2001      # samples of the middle line for the focus search [-]
_PART_SAMPLES = 65         # samples per side of a part's section by the sheet [-]
_REFERENCE_ASPECT = 2.0    # reference part: height = 2 × radius (as plan.py's) [-]

HINGE_NOTE = ("an ordinary camera (sensor perpendicular to the optical axis, [sensor] image_distance_mm > 0) "
              "does not follow the hinge rule: tilt_deg, tan_beta, hinge_px, F2_px_mm, C_mm, image_hinge_mm, "
              "axis_column_px, stage_zero_column_px and focal_length_check_mm are null; the figures come "
              "from the exact camera model (scheimpflug.model.camera)")
PLANS_NOTE = ("calibration_plan is null (its rule uses the hinge rule's working volume, "
              "scheimpflug.model.volume); rotary_plan is the camera model's (ordinary_rotary_plan)")


def sheet_coordinates(rig: Rig, points_mm) -> np.ndarray:
    """Sheet coordinates (D, h) of rig-frame points.

    Parameters
    ----------
    rig : Rig
        The instrument (f, d, tan φ).
    points_mm : (..., 3) array_like float
        Points in the rig frame [mm].

    Returns
    -------
    (..., 2) ndarray float64
        D along the sheet from the object hinge, h = z [mm].
    """
    D, h, _ = hinge_geometry(rig).sheet_from_rig(points_mm)
    return np.stack([D, h], axis=-1)


def _dh_jacobian(rig: Rig, uv_px) -> np.ndarray:
    """∂(D, h)/∂(u, v), (..., 2, 2) [mm/px]."""
    g = hinge_geometry(rig)
    rows = np.stack([g.propagation_dir, np.array([0.0, 0.0, 1.0])])
    return rows @ sheet_jacobian(rig, uv_px)


def distance_axis(rig: Rig) -> int:
    """The sensor axis along which the distance on the sheet changes most, at the sensor's centre.

    Parameters
    ----------
    rig : Rig
        The instrument.

    Returns
    -------
    int
        0 when D changes most along the columns index u (the stripe runs down the columns,
        one point per row), 1 along the rows index v (one point per column) [-].
    """
    s = rig.sensor
    j = _dh_jacobian(rig, np.array([0.5 * (s.columns - 1), 0.5 * (s.rows - 1)]))
    return 0 if abs(j[0, 0]) >= abs(j[0, 1]) else 1


def _uv(axis: int, a, b) -> np.ndarray:
    """Pixels (u, v) of positions a along the distance axis and b along the other, broadcast."""
    a, b = np.broadcast_arrays(np.asarray(a, np.float64), np.asarray(b, np.float64))
    return np.stack([a, b], axis=-1) if axis == 0 else np.stack([b, a], axis=-1)


def field_border_px(columns: int, rows: int, n: int = _BORDER_SAMPLES) -> np.ndarray:
    """The outer edge of a sensor, as pixel coordinates going round it.

    Parameters
    ----------
    columns, rows : int
        Sensor size [px].
    n : int
        Samples per side [-].

    Returns
    -------
    (4·n, 2) ndarray float64
        (u, v) along the four sides from the corner (−½, −½) through (N_u − ½, −½),
        (N_u − ½, N_v − ½) and (−½, N_v − ½) [px].
    """
    c = np.array([[-0.5, -0.5], [columns - 0.5, -0.5], [columns - 0.5, rows - 0.5], [-0.5, rows - 0.5]])
    t = np.linspace(0.0, 1.0, n, endpoint=False)[:, None]
    return np.concatenate([c[i] + t * (c[(i + 1) % 4] - c[i]) for i in range(4)])


def _blur_px(rig: Rig, uv_px) -> np.ndarray:
    """Circle of confusion of the sheet points pixels see, in pixels."""
    p = sheet_point_from_pixel(rig, uv_px)
    return project_points(rig, p).blur_diameter_mm / (rig.sensor.pixel_pitch_um * 1e-3)


def focus_range_mm(rig: Rig, axis: int, n: int = _FOCUS_SAMPLES) -> tuple[list[float] | None, list[float]]:
    """Where the sheet is in acceptable focus along the sensor's middle line.

    Parameters
    ----------
    rig : Rig
        The instrument (focal length, f-number and focus of its lens).
    axis : int
        The distance axis (:func:`distance_axis`).
    n : int
        Samples of the line before the boundaries are bisected [-].

    Returns
    -------
    range_mm : list of float or None
        [D where the sheet enters, D where it leaves] acceptable focus (a circle of
        confusion of at most one pixel) over the largest such stretch of the middle line,
        from edge to edge of the sensor, near end first [mm]; None when no point of it is sharp.
    line_px : list of float
        The same two ends as positions along the distance axis [px] (empty when None).
    """
    s = rig.sensor
    n_a, n_b = (s.columns, s.rows) if axis == 0 else (s.rows, s.columns)
    b_mid = 0.5 * (n_b - 1)
    a = np.linspace(-0.5, n_a - 0.5, n)
    sharp = _blur_px(rig, _uv(axis, a, b_mid)) <= 1.0
    if not sharp.any():
        return None, []
    runs = np.flatnonzero(np.diff(np.concatenate([[0], sharp.astype(np.int8), [0]])))
    starts, ends = runs[::2], runs[1::2] - 1
    i = int(np.argmax(ends - starts))
    lo, hi = float(a[starts[i]]), float(a[ends[i]])

    def ok(x: float) -> bool:
        return bool(_blur_px(rig, _uv(axis, x, b_mid)) <= 1.0)

    if starts[i] > 0:
        lo = bisect_boundary(ok, lo, float(a[starts[i] - 1]))
    if ends[i] < n - 1:
        hi = bisect_boundary(ok, hi, float(a[ends[i] + 1]))
    d = sheet_coordinates(rig, sheet_point_from_pixel(rig, _uv(axis, np.array([lo, hi]), b_mid)))[:, 0]
    if d[0] > d[1]:
        return [float(d[1]), float(d[0])], [hi, lo]
    return [float(d[0]), float(d[1])], [lo, hi]


def _none_if_nan(x):
    """Floats (nested in lists) with NaN and infinities as None."""
    if isinstance(x, (list, tuple)):
        return [_none_if_nan(v) for v in x]
    x = float(x)
    return x if math.isfinite(x) else None


def _field(rig: Rig) -> dict:
    """The sensor's border on the sheet: corners, ranges."""
    s = rig.sensor
    border = sheet_coordinates(rig, sheet_point_from_pixel(rig, field_border_px(s.columns, s.rows)))
    corners_px = np.array([[-0.5, -0.5], [s.columns - 0.5, -0.5], [s.columns - 0.5, s.rows - 0.5],
                           [-0.5, s.rows - 0.5]])
    corners = sheet_point_from_pixel(rig, corners_px)
    bounded = bool(np.all(np.isfinite(border)))
    return {
        "field_corners_px": corners_px.tolist(),
        "field_corners_mm": _none_if_nan(corners.tolist()),
        "field_corners_sheet_mm": _none_if_nan(sheet_coordinates(rig, corners).tolist()),
        "field_bounded": bounded,
        "field_distance_range_mm": ([float(border[:, 0].min()), float(border[:, 0].max())] if bounded
                                    else [None, None]),
        "field_height_range_mm": ([float(border[:, 1].min()), float(border[:, 1].max())] if bounded
                                  else [None, None]),
    }


def _fold_note(rig: Rig) -> list[str]:
    """A note when the sensor's corners see beyond the distortion's fold (:func:`fold_radius`)."""
    s = rig.sensor
    corners = np.array([[-0.5, -0.5], [s.columns - 0.5, -0.5], [s.columns - 0.5, s.rows - 0.5], [-0.5, s.rows - 0.5]])
    q = sensor_point_from_pixel(sensor_pose(rig), corners) - lens_centre_mm(rig)
    r = float(np.max(np.hypot(q[:, 1], q[:, 2]) / np.abs(q[:, 0])))
    fold = fold_radius(rig.lens)
    if r <= fold:
        return []
    return [f"the distortion folds back at the normalised radius {fold:.4g}, inside the frame (its corners reach "
            f"{r:.4g}): the field's border beyond it is the model's, not the lens's"]


def _coverage(rig: Rig, axis: int) -> dict:
    """Distance range, fields of view at near and far, resolutions at near, middle and far."""
    s = rig.sensor
    n_a, n_b = (s.columns, s.rows) if axis == 0 else (s.rows, s.columns)
    b_mid = 0.5 * (n_b - 1)
    ends = sheet_coordinates(rig, sheet_point_from_pixel(rig, _uv(axis, np.array([0.0, n_a - 1.0]), b_mid)))
    near_first = not ends[0, 0] > ends[1, 0]
    a_pts = np.array([0.0, n_a // 2, n_a - 1.0]) if near_first else np.array([n_a - 1.0, n_a // 2, 0.0])
    edges = np.array([-0.5, n_a - 0.5]) if near_first else np.array([n_a - 0.5, -0.5])
    top = sheet_coordinates(rig, sheet_point_from_pixel(rig, _uv(axis, edges, -0.5)))
    bottom = sheet_coordinates(rig, sheet_point_from_pixel(rig, _uv(axis, edges, n_b - 0.5)))
    pts = _uv(axis, a_pts, b_mid)
    j = _dh_jacobian(rig, pts)
    dz, dx = np.abs(j[:, 0, axis]), np.abs(j[:, 1, 1 - axis])
    d_near, d_far = (ends[0, 0], ends[1, 0]) if near_first else (ends[1, 0], ends[0, 0])
    return {
        "distance_axis": "columns" if axis == 0 else "rows",
        "near_line_px": float(a_pts[0]),
        "distance_range_mm": _none_if_nan([d_near, d_far]),
        "depth_range_mm": _none_if_nan(d_far - d_near),
        "distance_resolution_center_mm": _none_if_nan(dz[1]),
        "height_resolution_center_mm": _none_if_nan(dx[1]),
        "center_column_px": float(pts[1, 0]),
        "center_row_px": float(pts[1, 1]),
        "height_range_near_mm": _none_if_nan(abs(top[0, 1] - bottom[0, 1])),
        "height_range_far_mm": _none_if_nan(abs(top[1, 1] - bottom[1, 1])),
        "resolution_points_px": pts.tolist(),
        "distance_resolution_mm": _none_if_nan(dz.tolist()),
        "height_resolution_mm": _none_if_nan(dx.tolist()),
        "jacobian_mm_per_px": _none_if_nan(j.tolist()),
    }


def _focus(rig: Rig, axis: int, cov: dict) -> dict:
    """The lens's focus, the blur at near, middle and far, where the sheet is sharp."""
    s, lens = rig.sensor, rig.lens
    f, b = lens.focal_length_mm, s.image_distance_mm
    rng, line = focus_range_mm(rig, axis)
    blur = _blur_px(rig, np.asarray(cov["resolution_points_px"]))
    return {
        "focus_distance_mm": f * b / (b - f) if b > f else None,
        "blur_px": _none_if_nan(blur.tolist()),
        "focus_range_mm": rng,
        "focus_range_line_px": line,
        "sheet_in_focus": rng is not None and sorted(line) == [-0.5, (s.columns, s.rows)[axis] - 0.5],
    }


def _rotary_axis(rig: Rig) -> dict:
    """Where the rotary axis meets the table, on the sensor, and whether that is in view."""
    st, s = rig.stage, rig.sensor
    g = hinge_geometry(rig)
    d_axis = st.axis_mm - st.d0_mm
    point = g.object_hinge_mm + d_axis * g.propagation_dir + np.array([0.0, 0.0, st.rotary_table_z_mm])
    uv = project_points(rig, point).uv_px
    inside = bool(np.all(np.isfinite(uv)) and -0.5 <= uv[0] <= s.columns - 0.5 and -0.5 <= uv[1] <= s.rows - 0.5)
    return {"rotary_axis_px": _none_if_nan(uv.tolist()), "rotary_axis_in_view": inside}


def _in_view(rig: Rig, dh_mm: np.ndarray) -> bool:
    """Whether sheet points (D, h) all image inside the sensor (PART_MARGIN_PX from its border) and are lit."""
    g = hinge_geometry(rig)
    s = rig.sensor
    p = g.object_hinge_mm + dh_mm[:, :1] * g.propagation_dir + dh_mm[:, 1:] * np.array([0.0, 0.0, 1.0])
    uv = project_points(rig, p).uv_px
    m = PART_MARGIN_PX - 0.5
    seen = (uv[:, 0] >= m) & (uv[:, 0] <= s.columns - 1 - m) & (uv[:, 1] >= m) & (uv[:, 1] <= s.rows - 1 - m)
    origin, fan_tan = laser_fan(rig)
    lit = np.abs(dh_mm[:, 1]) <= fan_tan * (dh_mm[:, 0] - origin)
    return bool(np.all(seen & lit))


def _section(d_axis: float, z: float, up: float, radius: float, height: float) -> np.ndarray:
    """The border of the rectangle D ∈ [D_a − R, D_a + R], h from z to z + up·H, (4·n, 2) [mm]."""
    t = np.linspace(0.0, 1.0, _PART_SAMPLES)
    d = d_axis - radius + 2 * radius * t
    h = z + up * height * t
    return np.concatenate([np.column_stack([d, np.full_like(d, z)]), np.column_stack([d, np.full_like(d, h[-1])]),
                           np.column_stack([np.full_like(h, d[0]), h]), np.column_stack([np.full_like(h, d[-1]), h])])


def _largest(fits, upper: float) -> float:
    """Largest x in [0, upper] with ``fits(x)`` (monotone), 0 if none."""
    if not fits(1e-9):
        return 0.0
    return upper if fits(upper) else bisect_boundary(fits, 1e-9, upper)


def ordinary_rotary_plan(rig: Rig) -> RotaryPlan:
    """The largest parts that stay in view at every angle on an ordinary camera's rotary table.

    Parameters
    ----------
    rig : Rig
        The rig (``[sensor] image_distance_mm`` > 0, its stage keys resolved).

    Returns
    -------
    RotaryPlan
        As :func:`scheimpflug.model.plan.rotary_plan`: a part on the axis is cut by the sheet
        along D ∈ [D_a − R, D_a + R] and from the table height z up the table's up (+z, or −z
        when ``[stage] axis_tilt_deg`` > 90°, FabScan's); it stays in view at every angle iff
        that section's border images inside the sensor, :data:`PART_MARGIN_PX` pixels from its
        border (:func:`~scheimpflug.model.camera.project_points`), and is lit by the fan.  The
        axis's tilt and offset are left out, as the Scheimpflug rig's plan leaves them.
    """
    st = rig.stage
    d_axis, z = st.axis_mm - st.d0_mm, st.rotary_table_z_mm
    up = 1.0 if st.axis_tilt_deg <= 90.0 else -1.0
    if not _in_view(rig, np.array([[d_axis, z]])):
        return RotaryPlan(st.axis_mm, d_axis, z, False, 0.0, 0.0, 0.0, 0.0)
    upper = 2.0 * _field_size_mm(rig)
    ref = _largest(lambda r: _in_view(rig, _section(d_axis, z, up, r, _REFERENCE_ASPECT * r)), upper)
    flat = _largest(lambda r: _in_view(rig, _section(d_axis, z, up, r, 0.0)), upper)
    thin = _largest(lambda h: _in_view(rig, _section(d_axis, z, up, 0.0, h)), upper)
    return RotaryPlan(st.axis_mm, d_axis, z, True, ref, _REFERENCE_ASPECT * ref, flat, thin)


def _field_size_mm(rig: Rig) -> float:
    """An upper bound of the field's size on the sheet [mm] (1e4 when it reaches the horizon)."""
    s = rig.sensor
    border = sheet_coordinates(rig, sheet_point_from_pixel(rig, field_border_px(s.columns, s.rows, 33)))
    return float(np.ptp(border, axis=0).max()) if np.all(np.isfinite(border)) else 1e4


def _axis_warning(rig: Rig, axis: dict) -> list[str]:
    if axis["rotary_axis_in_view"]:
        return []
    st = rig.stage
    return [f"[stage] axis_mm = {st.axis_mm:g} with rotary_table_z_mm = {st.rotary_table_z_mm:g}: the rotary "
            f"axis meets the table at pixel {axis['rotary_axis_px']}, outside the "
            f"{rig.sensor.columns} × {rig.sensor.rows} frame"]


def ordinary_camera_report(rig: Rig) -> dict:
    """The design figures of an ordinary-camera rig as a JSON-ready dict.

    Parameters
    ----------
    rig : Rig
        The instrument, ``[sensor] image_distance_mm`` > 0.

    Returns
    -------
    dict
        The keys of :func:`scheimpflug.model.design.design_report` with the same meaning
        (``distance_range_mm`` [near, far] along the middle line of the distance axis,
        ``depth_range_mm``, ``height_range_near_mm`` / ``_far_mm`` (the sensor's full
        extent across, at the outer edges of the near and far lines),
        ``distance_resolution_center_mm``, ``height_resolution_center_mm``,
        ``center_column_px``, ``object_hinge_mm``, ``sensor_distance_to_lens_mm``,
        ``stage_range_mm``, ``axis_distance_mm``, ``stage``, ``derived``, ``warnings``);
        :data:`HINGE_ONLY_KEYS` and ``calibration_plan`` None; ``rotary_plan``
        (:func:`ordinary_rotary_plan`); and
        ``sensor_kind`` ("ordinary"), ``notes``, the field (``field_corners_px``,
        ``field_corners_mm`` (rig frame), ``field_corners_sheet_mm`` ((D, h)),
        ``field_bounded``, ``field_distance_range_mm``, ``field_height_range_mm``), the
        resolutions (``distance_axis``, ``near_line_px``, ``center_row_px``,
        ``resolution_points_px``, ``distance_resolution_mm`` and ``height_resolution_mm``
        [near, middle, far], ``jacobian_mm_per_px`` ∂(D, h)/∂(u, v) there), the focus
        (``focus_distance_mm``, ``blur_px`` [near, middle, far], ``focus_range_mm``,
        ``focus_range_line_px``, ``sheet_in_focus``), ``clearance_mm`` (laser origin →
        near end along the sheet), ``standoff_mm`` (lens centre → near end),
        ``rotary_axis_px`` and ``rotary_axis_in_view``.  Lengths [mm], pixels [px].
    """
    axis = distance_axis(rig)
    cov = _coverage(rig, axis)
    g = hinge_geometry(rig)
    st, lz = rig.stage, rig.laser
    d_near, d_far = cov["distance_range_mm"]
    laser = np.array([lz.origin_x_mm, lz.scheimpflug_distance_mm - lz.origin_x_mm * lz.tan_phi, 0.0])
    pose = sensor_pose(rig)
    centre = pose.origin_mm + 0.5 * pose.pitch_mm * ((pose.columns - 1) * pose.u_dir + (pose.rows - 1) * pose.v_dir)
    lens_c = lens_centre_mm(rig)
    near_point = g.object_hinge_mm + (d_near if d_near is not None else math.nan) * g.propagation_dir
    rot = _rotary_axis(rig)
    return {
        "sensor_kind": "ordinary",
        **dict.fromkeys(HINGE_ONLY_KEYS),
        **cov,
        **_field(rig),
        **_focus(rig, axis, cov),
        "object_hinge_mm": g.object_hinge_mm.tolist(),
        "sensor_distance_to_lens_mm": float(np.linalg.norm(centre - lens_c)),
        "stage_range_mm": _none_if_nan([x + st.d0_mm if x is not None else math.nan for x in (d_near, d_far)]),
        "axis_distance_mm": st.axis_mm - st.d0_mm,
        "clearance_mm": _none_if_nan(d_near - float(g.sheet_from_rig(laser)[0]) if d_near is not None else math.nan),
        "standoff_mm": _none_if_nan(np.linalg.norm(near_point - lens_c)),
        **rot,
        "stage": {k: getattr(st, k) for k in DERIVED_STAGE_KEYS},
        "derived": list(rig.derived),
        "calibration_plan": None,
        "rotary_plan": ordinary_rotary_plan(rig).to_json_dict(),
        "notes": [HINGE_NOTE, PLANS_NOTE, *_fold_note(rig)],
        "warnings": _axis_warning(rig, rot),
    }
