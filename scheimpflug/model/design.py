"""Design calculations: what a rig sees, how finely, and which tilt to set.

Forward: :func:`design_report` gives the tilt, hinge, calibration constants,
depth and height ranges and resolutions of a rig (docs/explanation/design-notes.md §3).  Inverse:
:func:`inverse_design` finds, for a lens and a sensor, the sheet-angle /
baseline pairs, tilts and sensor placements that cover a wanted working range.
Pure functions; the command line lives in :mod:`scheimpflug.app.commands.design`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq

from scheimpflug.errors import RigError
from scheimpflug.model.camera_design import ordinary_camera_report
from scheimpflug.model.hinge import HingeGeometry, hinge_geometry, stage_from_pixel, stage_jacobian, tilt_rad
from scheimpflug.model.plan import calibration_plan, rotary_plan, stage_warnings
from scheimpflug.model.rig import DERIVED_STAGE_KEYS, Rig

__all__ = [
    "DesignChoice",
    "coverage",
    "design_report",
    "focal_length_from_endpoint",
    "inverse_design",
    "pareto_front",
    "resolution_maps",
]


def coverage(hinge_u_px: float, hinge_v_px: float, F2_px_mm: float, C_mm: float,
             columns: int, rows: int) -> dict[str, float]:
    """What a sensor covers on the sheet, from the calibration constants alone.

    Parameters
    ----------
    hinge_u_px, hinge_v_px : float
        Image hinge (u_h, v_h) [px].
    F2_px_mm, C_mm : float
        Calibration constants F² [px·mm] and C [mm] (paper Eqs. 11–12).
    columns, rows : int
        Sensor size [px].

    Returns
    -------
    dict
        ``distance_range_mm`` ([D at column 0, D at the last column], from the
        object hinge), ``depth_range_mm``, ``height_range_near_mm`` and
        ``height_range_far_mm`` (the full sensor height mapped at the outer
        edges of the first and last columns), ``distance_resolution_center_mm``
        and ``height_resolution_center_mm`` (at column ``columns // 2``, per
        pixel) [mm], ``center_column_px`` [px].
    """
    k = (hinge_u_px, hinge_v_px, F2_px_mm, 0.0, C_mm)
    D, _ = stage_from_pixel(np.array([0.0, columns - 1.0]), hinge_v_px, *k)
    edges = np.array([-0.5, columns - 0.5])
    _, h_top = stage_from_pixel(edges, -0.5, *k)
    _, h_bottom = stage_from_pixel(edges, rows - 0.5, *k)
    u_mid = columns // 2
    ds_du, _, dh_dv = stage_jacobian(u_mid, hinge_v_px, hinge_u_px, hinge_v_px, F2_px_mm, C_mm)
    return {
        "distance_range_mm": [float(D[0]), float(D[1])],
        "depth_range_mm": float(D[1] - D[0]),
        "distance_resolution_center_mm": float(abs(ds_du)),
        "height_resolution_center_mm": float(abs(dh_dv)),
        "center_column_px": u_mid,
        "height_range_near_mm": float(abs(h_top[0] - h_bottom[0])),
        "height_range_far_mm": float(abs(h_top[1] - h_bottom[1])),
    }


def design_report(rig: Rig) -> dict:
    """The design figures of a rig as a JSON-ready dict (docs/reference/interface.md fields and more).

    Distances D are measured along the sheet from the object hinge [mm].
    The distance range is D at the centres of the first and last columns; the
    height ranges are the sensor's full height (rows × pitch) mapped at the
    outer edges of the first (near) and last (far) columns.

    Parameters
    ----------
    rig : Rig
        The instrument (ideal geometry: misalignments ignored).

    Returns
    -------
    dict
        ``tilt_deg`` [deg], ``tan_beta`` [-], ``hinge_px`` [u_h, v_h] [px],
        ``F2_px_mm`` [px·mm], ``C_mm`` [mm], the fields of :func:`coverage`,
        ``object_hinge_mm`` and ``image_hinge_mm`` (rig frame) [mm],
        ``sensor_distance_to_lens_mm`` (sensor centre, in the meridian plane)
        [mm], ``stage_range_mm`` (stage coordinates of the distance range)
        [mm], ``axis_distance_mm`` (rotary axis from the object hinge) [mm],
        ``axis_column_px`` and ``stage_zero_column_px`` (columns that see the
        rotary axis and stage coordinate 0) [px], ``focal_length_check_mm``
        (:func:`focal_length_from_endpoint` at stage 0) [mm]; ``stage`` (the
        stage position keys) [mm] and ``derived`` (the keys the rule derived,
        as ``"table.key"``); ``calibration_plan`` and ``rotary_plan``
        (:mod:`scheimpflug.model.plan`); ``warnings`` (stage settings that put
        the axis or the plate out of view, naming the key).  Figures that do
        not exist (the columns of stage zero and the f check when stage zero is
        not in front of the hinge, e.g. d0 = 0) are None.  For an ordinary camera
        (``[sensor] image_distance_mm`` > 0), which does not follow the hinge rule, the
        figures of :func:`scheimpflug.model.camera_design.ordinary_camera_report` instead:
        the same keys where the meaning is the same, the hinge rule's null, and the field,
        resolutions and focus from the exact camera model.

    Examples
    --------
    The paper's rig (the paper measured F² = −1.446e6 px·mm, C = 145.91 mm and a
    depth range of 276.7 mm with its real lens):

    >>> from scheimpflug.model.rig import load_preset
    >>> r = design_report(load_preset("paper"))
    >>> round(r["tilt_deg"], 3), round(r["F2_px_mm"] / 1e6, 4), round(r["C_mm"], 2), round(r["depth_range_mm"], 1)
    (21.646, -1.4292, 149.1, 274.3)
    """
    if rig.sensor.image_distance_mm > 0:
        return ordinary_camera_report(rig)
    g = hinge_geometry(rig)
    s = rig.sensor
    cov = coverage(s.hinge_column, s.axis_row, g.F2_px_mm, g.C_mm, s.columns, s.rows)
    d_near, d_far = cov["distance_range_mm"]
    d_hinge_stage0 = -rig.stage.d0_mm
    u_stage0 = float(g.column_from_distance(d_hinge_stage0)) if d_hinge_stage0 > 0 else None
    return {
        "tilt_deg": g.tilt_deg,
        "tan_beta": g.tan_beta,
        "hinge_px": [s.hinge_column, s.axis_row],
        "F2_px_mm": g.F2_px_mm,
        "C_mm": g.C_mm,
        **cov,
        "object_hinge_mm": g.object_hinge_mm.tolist(),
        "image_hinge_mm": g.image_hinge_mm.tolist(),
        "sensor_distance_to_lens_mm": _sensor_centre_distance(rig, g),
        "stage_range_mm": [d_near + rig.stage.d0_mm, d_far + rig.stage.d0_mm],
        "axis_distance_mm": rig.stage.axis_mm - rig.stage.d0_mm,
        "axis_column_px": _finite_or_none(g.column_from_distance(rig.stage.axis_mm - rig.stage.d0_mm)),
        "stage_zero_column_px": u_stage0,
        "focal_length_check_mm": (None if u_stage0 is None
                                  else _finite_or_none(focal_length_from_endpoint(g, u_stage0, d_hinge_stage0))),
        "stage": {k: getattr(rig.stage, k) for k in DERIVED_STAGE_KEYS},
        "derived": list(rig.derived),
        "calibration_plan": calibration_plan(rig).to_json_dict(),
        "rotary_plan": rotary_plan(rig).to_json_dict(),
        "warnings": stage_warnings(rig),
    }


def _finite_or_none(x) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None


def _sensor_centre_distance(rig: Rig, g: HingeGeometry) -> float:
    s = rig.sensor
    u_c = 0.5 * (s.columns - 1)
    q = g.image_hinge_mm + (u_c - s.hinge_column) * g.pixel_pitch_mm * g.sensor_u_dir
    return float(np.linalg.norm(q[:2]))


def focal_length_from_endpoint(g: HingeGeometry, u_px: float, distance_mm: float) -> float:
    """The paper's focal-length check from one calibrated point (paper Eqs. 13–14 and 1).

    Parameters
    ----------
    g : HingeGeometry
        The rig's ideal geometry (β, φ, p, u_h).
    u_px : float
        Column of the point [px].
    distance_mm : float
        Its distance D along the sheet from the object hinge [mm].

    Returns
    -------
    float
        f = √(−x_M'·x_M) [mm], with x_M' = (u − u_h)·sin β·p and
        x_M = D·cos φ (Newton's x·x' = −f², Eq. 1).

    Raises
    ------
    ValueError
        If x_M'·x_M > 0 (``math.sqrt`` of a negative number: the point and its
        column are on the same side of their focal planes).
    """
    x_img = (u_px - g.hinge_column) * math.sin(g.beta_rad) * g.pixel_pitch_mm
    x_obj = distance_mm * math.cos(g.phi_rad)
    return math.sqrt(-x_img * x_obj)


def resolution_maps(rig: Rig) -> dict[str, np.ndarray]:
    """Per-pixel resolution over the sensor (paper Eqs. 11–12 differentiated).

    Parameters
    ----------
    rig : Rig
        The instrument (ideal geometry: misalignments ignored).

    Returns
    -------
    dict of str to ndarray
        ``distance_mm`` (columns,) float64: D of each column [mm];
        ``distance_mm_per_px`` = |dD/du| and ``height_mm_per_px`` = |dh/dv|,
        each a read-only (rows, columns) float64 broadcast view [mm/px].
        For the ideal rig both depend on the column only.
    """
    g = hinge_geometry(rig)
    u = np.arange(rig.sensor.columns, dtype=np.float64)
    shape = (rig.sensor.rows, rig.sensor.columns)
    return {
        "distance_mm": g.distance_from_column(u),
        "distance_mm_per_px": np.broadcast_to(g.distance_resolution(u), shape),
        "height_mm_per_px": np.broadcast_to(g.height_resolution(u), shape),
    }


@dataclass(frozen=True)
class DesignChoice:
    """One rig layout that images a wanted working range onto the sensor (:func:`inverse_design`).

    Parameters
    ----------
    tan_phi : float
        tan φ, sheet angle to the optical axis [-].
    scheimpflug_distance_mm : float
        d, lens centre to the Scheimpflug line [mm].
    tilt_deg : float
        Sensor tilt β [deg].
    hinge_column : float
        u_h, where to place the sensor relative to the image hinge [px].
    F2_px_mm : float
        Calibration constant F² of that layout [px·mm].
    C_mm : float
        Calibration constant C of that layout [mm].
    """

    tan_phi: float
    scheimpflug_distance_mm: float
    tilt_deg: float
    hinge_column: float
    F2_px_mm: float
    C_mm: float


def inverse_design(focal_length_mm: float, pixel_pitch_um: float, columns: int,
                   near_mm: float, far_mm: float, *, tan_phi: float | None = None,
                   scheimpflug_distance_mm: float | None = None) -> DesignChoice:
    """Tilt, baseline and sensor placement that map ``near..far`` onto columns 0..N−1.

    Parameters
    ----------
    focal_length_mm : float
        Focal length f [mm].
    pixel_pitch_um : float
        Pixel pitch p [µm].
    columns : int
        Number of columns N [px], > 1.
    near_mm, far_mm : float
        Wanted range, distances along the sheet from the Scheimpflug line
        (where the laser sits) [mm], 0 < near < far.
    tan_phi : float, optional
        Sheet angle tan φ [-]; give exactly one of ``tan_phi`` or
        ``scheimpflug_distance_mm``, the other is solved for.
    scheimpflug_distance_mm : float, optional
        Baseline d [mm].

    Returns
    -------
    DesignChoice
        The layout: tan φ, d, β, u_h, F² and C.

    Raises
    ------
    RigError
        If both or neither of ``tan_phi`` and ``scheimpflug_distance_mm`` are
        given, the inputs are out of range, ``near`` lies inside the focal
        length along the sheet, the range needs sin β ≥ 1, or no sheet angle
        with |tan φ| ≤ 3 reaches the given baseline.

    Notes
    -----
    The hinge lies f/cos φ along the sheet from the Scheimpflug line, so
    D = L − f/cos φ.  D(u) = F²/(u − u_h) at u = 0 and N−1 gives
    u_h = (N−1)·D_far/(D_far − D_near) and F² = −D_near·u_h; then
    F² = −f²/(p·cos φ·sin β) with tan β = f/(d − f·tan φ) (paper Eq. 5) fixes
    the remaining unknown.
    """
    f, p = float(focal_length_mm), float(pixel_pitch_um) * 1e-3
    if (tan_phi is None) == (scheimpflug_distance_mm is None):
        raise RigError("inverse design: give exactly one of tan_phi or scheimpflug_distance_mm")
    if not (f > 0 and p > 0 and columns > 1 and 0 < near_mm < far_mm):
        raise RigError(f"inverse design: need f > 0, pitch > 0, columns > 1 and 0 < near < far "
                       f"(got f={f}, pitch={pixel_pitch_um} µm, columns={columns}, near={near_mm}, far={far_mm})")
    if tan_phi is None:
        tan_phi = _solve_tan_phi(f, p, columns, near_mm, far_mm, float(scheimpflug_distance_mm))
    cos_phi = 1.0 / math.hypot(1.0, tan_phi)
    d_near, d_far = near_mm - f / cos_phi, far_mm - f / cos_phi
    if d_near <= 0:
        raise RigError(f"inverse design: near = {near_mm} mm lies inside the focal length along the "
                       f"sheet (f/cos φ = {f / cos_phi:.2f} mm)")
    u_h = (columns - 1) * d_far / (d_far - d_near)
    f2 = -d_near * u_h
    sin_beta = f * f / (p * cos_phi * abs(f2))
    if sin_beta >= 1.0:
        raise RigError(f"inverse design: the range {near_mm}–{far_mm} mm needs sin β = {sin_beta:.3f} ≥ 1; "
                       "use a longer range, a longer focal length or a finer pixel pitch")
    beta = math.asin(sin_beta)
    d = f / math.tan(beta) + f * tan_phi
    if scheimpflug_distance_mm is not None and not math.isclose(d, scheimpflug_distance_mm, rel_tol=1e-6):
        raise RigError("inverse design: no sheet angle reaches this baseline")  # pragma: no cover
    return DesignChoice(tan_phi, d, math.degrees(beta), u_h, f2, f / sin_beta)


def _solve_tan_phi(f: float, p: float, columns: int, near: float, far: float, d: float) -> float:
    def residual(t: float) -> float:
        cos_phi = 1.0 / math.hypot(1.0, t)
        dn, df = near - f / cos_phi, far - f / cos_phi
        u_h = (columns - 1) * df / (df - dn)
        sin_beta = f * f / (p * cos_phi * dn * u_h)
        beta = tilt_rad(f, d, t)
        return sin_beta - math.sin(beta)

    grid = np.linspace(-3.0, min(3.0, (d / f) * (1 - 1e-9)), 601)
    vals = [residual(t) for t in grid]
    for a, b, fa, fb in zip(grid[:-1], grid[1:], vals[:-1], vals[1:]):
        if np.isfinite(fa) and np.isfinite(fb) and fa * fb <= 0:
            return brentq(residual, a, b, xtol=1e-14)
    hints = []
    for t in (0.0, 0.2, 0.5):
        try:
            c = inverse_design(f, p * 1e3, columns, near, far, tan_phi=t)
            hints.append(f"d = {c.scheimpflug_distance_mm:.1f} mm at tan φ = {t:g}")
        except RigError:
            pass
    hint = ("; baselines that work: " + ", ".join(hints)) if hints else ""
    raise RigError(f"inverse design: no sheet angle with |tan φ| ≤ 3 covers {near}–{far} mm "
                   f"with d = {d} mm (the baseline fixes the magnification){hint}")


def pareto_front(benefit, cost) -> np.ndarray:
    """The designs no other design beats on both counts (more benefit for no more cost).

    Parameters
    ----------
    benefit : (n,) array_like float
        What is wanted large (e.g. the depth range [mm]); NaN = not a candidate.
    cost : (n,) array_like float
        What is wanted small (e.g. the measured error [mm]); NaN = not a candidate.

    Returns
    -------
    (k,) ndarray int64
        Indices of the non-dominated designs, by increasing cost (ties: larger benefit
        first).  Design i is dominated when some j has benefit_j ≥ benefit_i and
        cost_j ≤ cost_i with at least one strict.

    Raises
    ------
    ValueError
        If the two arrays differ in shape or are not one-dimensional.
    """
    b = np.asarray(benefit, dtype=np.float64)
    c = np.asarray(cost, dtype=np.float64)
    if b.ndim != 1 or b.shape != c.shape:
        raise ValueError(f"benefit {b.shape} and cost {c.shape} must be equal-length 1-D arrays")
    ok = np.flatnonzero(np.isfinite(b) & np.isfinite(c))
    order = ok[np.lexsort((-b[ok], c[ok]))]
    front, best = [], -np.inf
    for i in order:
        if b[i] > best:
            front.append(i)
            best = b[i]
    return np.asarray(front, dtype=np.int64)
