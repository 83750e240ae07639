"""What the studio's page draws, from the engine of ``design``: meridian plane, field, datasheet, curves.

Every figure here comes from :mod:`scheimpflug.model.hinge` (paper Eqs. 5, 11, 12 and their
derivatives) and :mod:`scheimpflug.model.camera` (the sensor pose, misalignments included); the page
only draws them.  Points are in the rig frame's meridian plane (x along the optical axis toward the
object, y toward the laser side) [mm]; sheet coordinates are (D, h): distance along the sheet from the
object hinge and height [mm].

The wedge of acceptable focus is that of a thin lens of aperture A = f/N and a circle of confusion of
one pixel (c = p): a sensor point Q, the image of an object point on its chief ray, is sharp enough
when the image lies within a_s/(1 + N·c/f) … a_s/(1 − N·c/f) of the lens along that ray (a_s the
sensor point's distance behind the lens), the cone's section by the plane ⊥ the axis at the sensor
point then being at most c across.  The conjugates of those two image lines (the sensor line scaled
about the lens centre) bound the wedge; the plane of sharp focus is the conjugate of the sensor line
itself, the sheet for a sensor tilted by the hinge rule.
"""

from __future__ import annotations

import math

import numpy as np

from scheimpflug.model.camera import sensor_point_from_pixel, sensor_pose
from scheimpflug.model.hinge import HingeGeometry, hinge_geometry
from scheimpflug.model.rig import Rig

__all__ = ["FAR_CLIP", "SAMPLES", "curves", "datasheet", "f_number_for_focus", "field_view", "focus_map",
           "focus_wedge", "meridian_view", "studio_views"]

SAMPLES = 33
"""Columns sampled across the sensor for the wedge and the curves (ends included) [-]."""

FAR_CLIP = 3.0
"""A wedge limit at infinity is drawn at this multiple of the sharp point's distance along its ray [-]."""


def _xy(points: np.ndarray) -> list[list[float]]:
    return np.round(np.asarray(points)[..., :2], 4).tolist()


def _object_from_image(q: np.ndarray, f: float) -> np.ndarray:
    """Conjugate P = f/(x' + f)·Q of image points behind an ideal thin lens at the origin, (n, 3) [mm]."""
    with np.errstate(divide="ignore", invalid="ignore"):
        m = f / (q[:, 0] + f)
    return m[:, None] * q


def _sheet_on_ray(q: np.ndarray, g: HingeGeometry) -> np.ndarray:
    """Where the chief ray of each sensor point meets the sheet y = d − x·tan φ, (n, 3) [mm]."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t = g.scheimpflug_distance_mm / (q[:, 1] + q[:, 0] * g.tan_phi)
    return t[:, None] * q


def _columns(rig: Rig, n: int = SAMPLES) -> np.ndarray:
    return np.linspace(-0.5, rig.sensor.columns - 0.5, n)


def focus_wedge(rig: Rig, columns_px: np.ndarray, rows_px: np.ndarray | None = None) -> dict:
    """Plane of sharp focus, the wedge of acceptable focus and the sheet along the chief rays of columns.

    Parameters
    ----------
    rig : Rig
        The instrument (its sensor pose with misalignments, the ideal lens).
    columns_px : (n,) array_like float
        Columns [px].
    rows_px : (n,) array_like float, optional
        Their rows [px]; default the sensor's meridian row ``axis_row``.

    Returns
    -------
    dict
        ``sensor``, ``sharp``, ``near``, ``far``, ``sheet``: (n, 3) ndarray float64 of rig points [mm]
        (the far limit at :data:`FAR_CLIP` times the sharp point's distance where it is at infinity);
        ``far_infinite`` (n,) bool; ``margin_mm`` (n,) float64: how far the sheet point lies inside the
        wedge along its chief ray (negative: out of acceptable focus) [mm]; ``dof_mm`` (n,) float64:
        the wedge's length along each chief ray [mm] (inf where the far limit is at infinity).
    """
    f, N = rig.lens.focal_length_mm, rig.lens.f_number
    k = N * rig.sensor.pixel_pitch_um * 1e-3 / f
    u = np.asarray(columns_px, dtype=np.float64)
    v = np.full_like(u, rig.sensor.axis_row) if rows_px is None else np.asarray(rows_px, dtype=np.float64)
    q = sensor_point_from_pixel(sensor_pose(rig), np.stack([u, v], axis=-1))
    sharp = _object_from_image(q, f)
    near = _object_from_image(q / (1.0 - k), f) if k < 1 else np.full_like(q, np.nan)
    far = _object_from_image(q / (1.0 + k), f)
    infinite = ~(far[:, 0] > sharp[:, 0]) | ~np.isfinite(far[:, 0])
    far[infinite] = FAR_CLIP * sharp[infinite]
    sheet = _sheet_on_ray(q, hinge_geometry(rig))
    r_sheet, r_near, r_far = (np.linalg.norm(p, axis=1) for p in (sheet, near, far))
    r_far = np.where(infinite, np.inf, r_far)
    on_side = sheet[:, 0] > 0
    margin = np.where(on_side, np.minimum(r_sheet - r_near, r_far - r_sheet), -np.inf)
    return {"sensor": q, "sharp": sharp, "near": near, "far": far, "sheet": sheet, "far_infinite": infinite,
            "margin_mm": margin, "dof_mm": r_far - r_near}


def meridian_view(rig: Rig) -> dict:
    """The meridian plane to scale: lens, sensor, sheet, Scheimpflug and hinge lines, focus and its wedge.

    Parameters
    ----------
    rig : Rig
        The instrument.

    Returns
    -------
    dict
        Rig-frame (x, y) points [mm]: ``lens`` (the aperture's ends, diameter f/N), ``sensor`` (the
        sensor's ends on the meridian row), ``laser`` (the laser exit), ``sheet`` (exit → beyond the far
        end), ``range`` (the sheet between the first and last column), ``scheimpflug_point`` O' (where
        sheet, lens plane and sensor plane meet: the Scheimpflug line seen end-on), ``object_hinge`` H
        and ``image_hinge`` H' (the hinge line seen end-on: the plane of sharp focus meets the front
        focal plane), ``focal_length_mm``, ``sharp`` (the plane of sharp focus over the sensor),
        ``wedge`` (polygon of acceptable focus), ``far_infinite`` (the wedge's far side at infinity
        somewhere), ``axis`` (the rotary axis on the sheet).
    """
    g = hinge_geometry(rig)
    f, s = g.focal_length_mm, rig.sensor
    w = focus_wedge(rig, _columns(rig))
    D = g.distance_from_column(np.array([0.0, s.columns - 1.0]))
    H, e = g.object_hinge_mm, g.propagation_dir
    x0 = rig.laser.origin_x_mm
    laser = np.array([x0, g.scheimpflug_distance_mm - x0 * g.tan_phi, 0.0])
    axis_d = rig.stage.axis_mm - rig.stage.d0_mm
    half = 0.5 * f / rig.lens.f_number
    return {
        "lens": [[0.0, -half], [0.0, half]],
        "sensor": _xy(w["sensor"][[0, -1]]),
        "laser": _xy(laser),
        "sheet": _xy(np.array([laser, H + 1.15 * max(D[1], axis_d) * e])),
        "range": _xy(np.array([H + D[0] * e, H + D[1] * e])),
        "scheimpflug_point": _xy(g.scheimpflug_point_mm),
        "object_hinge": _xy(H),
        "image_hinge": _xy(g.image_hinge_mm),
        "focal_length_mm": f,
        "sharp": _xy(w["sharp"][[0, -1]]),
        "wedge": _xy(np.concatenate([w["near"], w["far"][::-1]])),
        "far_infinite": bool(w["far_infinite"].any()),
        "axis": _xy(H + axis_d * e),
    }


def field_view(rig: Rig) -> dict:
    """The field on the sheet: the trapezoid the sensor sees, in sheet coordinates (D, h) [mm].

    Parameters
    ----------
    rig : Rig
        The instrument (ideal geometry, as ``design``).

    Returns
    -------
    dict
        ``trapezoid`` (4 corners (D, h): first column top, last column top, last column bottom,
        first column bottom; pixel edges) [mm], ``laser_d_mm`` (the laser exit's D) [mm],
        ``axis_d_mm`` (the rotary axis) [mm], ``rotary_table_z_mm`` and ``plate`` (the calibration
        plate's bottom and top heights) [mm], ``d0_mm`` (stage coordinate of D = 0) [mm].
    """
    g = hinge_geometry(rig)
    s, st = rig.sensor, rig.stage
    u = np.array([-0.5, s.columns - 0.5, s.columns - 0.5, -0.5])
    v = np.array([-0.5, -0.5, s.rows - 0.5, s.rows - 0.5])
    D, h = g.sheet_from_pixel(u, v)
    x0 = rig.laser.origin_x_mm
    laser = np.array([x0, g.scheimpflug_distance_mm - x0 * g.tan_phi, 0.0])
    plate = [st.calibration_table_z_mm, st.calibration_table_z_mm + st.calibration_plate_height_mm]
    return {"trapezoid": np.round(np.stack([D, h], axis=-1), 4).tolist(),
            "laser_d_mm": float(g.sheet_from_rig(laser)[0]), "axis_d_mm": st.axis_mm - st.d0_mm,
            "rotary_table_z_mm": st.rotary_table_z_mm, "plate": plate, "d0_mm": st.d0_mm}


# (key, label, unit, the design --json field it equals when the sub-pixel factor is 1, or "")
_ROWS = (
    ("range_z_mm", "measurement range Z", "mm", "depth_range_mm"),
    ("clearance_mm", "clearance distance (laser exit → near end, along the sheet)", "mm", ""),
    ("standoff_mm", "lens centre → near end of the range", "mm", ""),
    ("field_x_near_mm", "field of view X, near", "mm", "height_range_near_mm"),
    ("field_x_far_mm", "field of view X, far", "mm", "height_range_far_mm"),
    ("dx_near_um", "ΔX (height) near", "µm", ""),
    ("dx_middle_um", "ΔX (height) middle", "µm", "height_resolution_center_mm"),
    ("dx_far_um", "ΔX (height) far", "µm", ""),
    ("dz_near_um", "ΔZ (distance) near", "µm", ""),
    ("dz_middle_um", "ΔZ (distance) middle", "µm", "distance_resolution_center_mm"),
    ("dz_far_um", "ΔZ (distance) far", "µm", ""),
    ("tilt_deg", "sensor tilt β (hinge rule)", "deg", "tilt_deg"),
    ("dof_middle_mm", "depth of focus along the line of sight, middle (CoC = 1 px)", "mm", ""),
    ("focus_margin_mm", "sheet inside the wedge of focus by at least", "mm", ""),
    ("subpixel_factor", "sub-pixel factor (ΔX, ΔZ = per pixel ÷ this)", "-", ""),
)


def datasheet(rig: Rig, report: dict, subpixel: float = 1.0) -> list[dict]:
    """The rig as vendors of laser-line profilers write a datasheet.

    Parameters
    ----------
    rig : Rig
        The instrument.
    report : dict
        Its ``design`` figures (:func:`scheimpflug.model.design.design_report`).
    subpixel : float, default 1
        The sub-pixel factor the stripe detector is credited with: ΔX and ΔZ are the per-pixel
        resolutions divided by it [-].

    Returns
    -------
    list of dict
        One row per figure: ``key``, ``label``, ``unit``, ``value`` (None where undefined) and
        ``design`` (the ``design --json`` field it equals at sub-pixel factor 1 — in mm where the row
        is in µm — or ""). Near, middle and far are the first, the middle (``columns // 2``) and the
        last column, as in ``design``.
    """
    g = hinge_geometry(rig)
    s = rig.sensor
    u = np.array([0.0, s.columns // 2, s.columns - 1.0])
    dz = g.distance_resolution(u) * 1e3 / subpixel
    dx = g.height_resolution(u) * 1e3 / subpixel
    d_near = report["distance_range_mm"][0]
    near_point = g.object_hinge_mm + d_near * g.propagation_dir
    w = focus_wedge(rig, np.array([-0.5, s.columns // 2, s.columns - 0.5]))
    margin = focus_wedge(rig, _columns(rig))["margin_mm"].min()
    values = {
        "range_z_mm": report["depth_range_mm"], "clearance_mm": d_near - field_view(rig)["laser_d_mm"],
        "standoff_mm": float(np.linalg.norm(near_point)),
        "field_x_near_mm": report["height_range_near_mm"], "field_x_far_mm": report["height_range_far_mm"],
        "dx_near_um": dx[0], "dx_middle_um": dx[1], "dx_far_um": dx[2],
        "dz_near_um": dz[0], "dz_middle_um": dz[1], "dz_far_um": dz[2],
        "tilt_deg": report["tilt_deg"], "dof_middle_mm": w["dof_mm"][1], "focus_margin_mm": margin,
        "subpixel_factor": subpixel,
    }
    return [{"key": key, "label": label, "unit": unit, "value": _finite(values[key]), "design": design}
            for key, label, unit, design in _ROWS]


def _finite(x) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None


def curves(rig: Rig, subpixel: float = 1.0) -> dict:
    """Resolution and focus over the sensor's columns (the maps over the sensor: the ideal rig's depend
    on the column only).

    Returns
    -------
    dict
        ``distance_mm`` (D of each sampled column), ``dz_um`` and ``dx_um`` (per pixel ÷ ``subpixel``),
        ``margin_mm`` (the sheet inside the wedge of focus), lists of :data:`SAMPLES` values.
    """
    g = hinge_geometry(rig)
    u = np.linspace(0.0, rig.sensor.columns - 1.0, SAMPLES)
    w = focus_wedge(rig, u)
    return {"distance_mm": g.distance_from_column(u).tolist(),
            "dz_um": (g.distance_resolution(u) * 1e3 / subpixel).tolist(),
            "dx_um": (g.height_resolution(u) * 1e3 / subpixel).tolist(),
            "margin_mm": [_finite(m) for m in w["margin_mm"]]}


def focus_map(rig: Rig, n_columns: int = SAMPLES, n_rows: int = 17) -> dict:
    """The sheet's margin inside the wedge of focus over the whole sensor.

    A sensor turned about its normal (``roll_deg``) or shifted has a margin that changes along the
    rows as well; the ideal sensor's depends on the column only.

    Parameters
    ----------
    rig : Rig
        The instrument.
    n_columns, n_rows : int
        Grid of pixel centres sampled, sensor edges included [-].

    Returns
    -------
    dict
        ``columns_px`` (n_columns,), ``rows_px`` (n_rows,) [px] and ``margin_mm`` (n_rows lists of
        n_columns values, None where the sheet is behind the camera) [mm].
    """
    s = rig.sensor
    u = np.linspace(-0.5, s.columns - 0.5, n_columns)
    v = np.linspace(-0.5, s.rows - 0.5, n_rows)
    uu, vv = np.meshgrid(u, v)
    m = focus_wedge(rig, uu.ravel(), vv.ravel())["margin_mm"].reshape(uu.shape)
    return {"columns_px": u.tolist(), "rows_px": v.tolist(),
            "margin_mm": [[_finite(x) for x in row] for row in np.round(m, 5)]}


def studio_views(rig: Rig, report: dict, subpixel: float = 1.0) -> dict:
    """Everything the page draws for a rig besides the ``design`` figures.

    Parameters
    ----------
    rig : Rig
        The instrument.
    report : dict
        Its ``design`` figures.
    subpixel : float, default 1
        The datasheet's sub-pixel factor [-].

    Returns
    -------
    dict
        ``meridian`` (:func:`meridian_view`), ``field`` (:func:`field_view`), ``datasheet``
        (:func:`datasheet`), ``curves`` (:func:`curves`), ``focus_map`` (:func:`focus_map`).
    """
    return {"meridian": meridian_view(rig), "field": field_view(rig), "datasheet": datasheet(rig, report, subpixel),
            "curves": curves(rig, subpixel), "focus_map": focus_map(rig)}


def f_number_for_focus(rig: Rig, lo: float = 0.5, hi: float = 256.0) -> dict:
    """The smallest f-number whose wedge of focus holds the whole sheet's thickness over the range.

    The sheet's margin inside the wedge (:func:`focus_wedge`, over :data:`SAMPLES` columns) grows
    with the f-number; bisection finds the smallest N at which it reaches the sheet's half-thickness
    at its waist (``laser.waist_um``) at every column — the widest aperture, the most light, that keeps
    the whole sheet sharp to one pixel.  A sensor tilted by the hinge rule has the sheet as its plane
    of sharp focus, so every N in the lens key's range does (the answer is ``lo``); a mis-tilted one
    needs a smaller aperture.

    Parameters
    ----------
    rig : Rig
        The instrument.
    lo, hi : float
        The f-numbers searched (the ``lens.f_number`` key's range) [-].

    Returns
    -------
    dict
        ``f_number`` (None when even ``hi`` is not enough), ``needed_mm`` (the half-thickness) [mm],
        ``margin_mm`` (the margin at that f-number, or at ``hi``) [mm].
    """
    need = rig.laser.waist_um * 1e-3
    cols = _columns(rig)

    def margin(n: float) -> float:
        return float(focus_wedge(rig.replace(lens={"f_number": n}, rederive=False), cols)["margin_mm"].min())

    if margin(hi) < need:
        return {"f_number": None, "needed_mm": need, "margin_mm": _finite(margin(hi))}
    if margin(lo) >= need:
        return {"f_number": lo, "needed_mm": need, "margin_mm": _finite(margin(lo))}
    for _ in range(40):
        mid = math.sqrt(lo * hi)
        lo, hi = (mid, hi) if margin(mid) < need else (lo, mid)
    return {"f_number": hi, "needed_mm": need, "margin_mm": _finite(margin(hi))}
