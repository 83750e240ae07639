"""The turntable's top found from a scan's still table line: its height along the axis and its tilt.

A turntable scanner's sheet crosses the table's top in a line that the camera sees in
every frame beside the part.  The top of a real table is not quite where a calibration puts
the table plane (the plane through the calibrated axis point perpendicular to the axis): it
may lie higher or lower along the axis, and a top that is not square to the bearing axis
wobbles as the table turns — its line moves once per turn.

The model, in the table's own frame (origin the calibrated axis point on the table plane, z the
axis upward, x the table's x at angle 0; it turns with the table, so at angle θ the table
frame is ``camera_from_table · R_z(θ)``): the top is the plane through (0, 0, h) with the unit
normal

    n0 = (sin τ cos ψ, sin τ sin ψ, cos τ),

the axis tilted by τ toward the azimuth ψ (from the table's x toward its y), turned about the
disc's own axis a' through (0, 0, h): at angle θ its normal in the camera frame is
``R_cam · R_b · R_z(θ) · n0`` and it passes through the axis point plus h along the axis.
``R_b`` leans the disc's axis from the calibrated one by β toward the line's direction L in
the table plane (the sheet ∩ the table plane, from the points' spread): on FabScan's frames the
mean line's slope is not the calibrated table plane's (a lean of −0.7°, from the calibrated
axis, the sheet or the camera model — the line cannot tell which), and a lean about L itself
does not move the line at all, so β toward L is the one lean the frames show.  The still top
(τ = 0) has three parameters the line fixes (h, β and none other); the wobble adds τ and ψ.

The fit (:func:`fit_table_top`) takes the table line's stripe points of every frame, mapped
by the calibration onto the sheet (3-D, camera frame), and minimises each point's *image*
distance from its frame's line along the image column, to first order: a point X(u, v) of
the sheet seen at pixel (u, v) lies a signed distance ``n·(X − q)`` from the plane; moving v
by dv moves it by ``n·∂X/∂v·dv``, so the observed row minus the row where the plane crosses
that column is ``r = n·(X − q) / (n·∂X/∂v)`` [px] — the figure a per-column comparison of
the lines measures.  The parameters are h, β and the tilt vector (τ cos ψ, τ sin ψ) (no
singularity at τ = 0); τ, ψ and their standard errors follow from it.  Standard errors are
``s²·(JᵀJ)⁻¹`` with s the residual RMS: the points taken as independent, which they are not
quite (a frame's points share its stripe's errors), so they are a lower bound.

:func:`table_top_of_folder` picks the points from a frame folder: the stripe points of a column
range, in each frame the inliers of a seeded RANSAC line (:func:`scheimpflug.fixed_lines.line_inliers`,
per frame because the line moves between frames), ``∂X/∂v`` by a central difference of the
calibration's ``camera_from_pixel``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

__all__ = ["TableTop", "disc_radius_mm", "fit_table_top", "lean_rotation", "table_line_points", "table_top_of_folder",
           "table_top_plane", "tilt_normal"]


@dataclass(frozen=True)
class TableTop:
    """The turntable's top fitted from its line (module docstring).

    Parameters
    ----------
    offset_mm : float
        h: the top's centre along the axis from the calibrated table plane, + up the axis [mm].
    tilt_deg : float
        τ: the angle between the top's normal and the axis [deg], ≥ 0.
    azimuth_deg : float
        ψ: the direction the normal leans to in the table's own frame, from its x toward its y
        [deg], in (−180, 180].
    lean_deg : float
        |β|: the lean of the disc's own axis from the calibrated axis [deg], ≥ 0.
    lean_azimuth_deg : float
        The direction it leans to in the table's frame at angle 0 (±L, module docstring) [deg].
    offset_se_mm, tilt_se_deg, azimuth_se_deg, lean_se_deg : float
        Standard errors (module docstring; the azimuth's is inf at τ = 0) [mm], [deg], [deg], [deg].
    rms_px : float
        RMS of the points' image residuals along the column [px].
    n_points, n_frames : int
        Points and frames that contributed [-].
    """

    offset_mm: float
    tilt_deg: float
    azimuth_deg: float
    lean_deg: float
    lean_azimuth_deg: float
    offset_se_mm: float
    tilt_se_deg: float
    azimuth_se_deg: float
    lean_se_deg: float
    rms_px: float
    n_points: int
    n_frames: int

    def to_json_dict(self) -> dict:
        """The figures as a JSON-ready dict.

        Returns
        -------
        dict
            Every field under its own name (a non-finite one None).
        """
        from scheimpflug.io.atomic import finite_json

        return finite_json(asdict(self))

    def rig_keys(self) -> dict:
        """The ``[stage]`` keys of the twin's disc (:class:`scheimpflug.model.tables.Stage`).

        Returns
        -------
        dict
            ``table_top_offset_mm``, ``table_tilt_deg``, ``table_tilt_azimuth_deg``,
            ``table_axis_tilt_deg``, ``table_axis_tilt_azimuth_deg``.
        """
        return {"table_top_offset_mm": self.offset_mm, "table_tilt_deg": self.tilt_deg,
                "table_tilt_azimuth_deg": self.azimuth_deg, "table_axis_tilt_deg": self.lean_deg,
                "table_axis_tilt_azimuth_deg": self.lean_azimuth_deg}


def tilt_normal(tilt_deg: float, azimuth_deg: float) -> np.ndarray:
    """The top's unit normal n0 in the table's own frame (module docstring).

    Parameters
    ----------
    tilt_deg, azimuth_deg : float
        τ and ψ [deg].

    Returns
    -------
    (3,) ndarray float64
        (sin τ cos ψ, sin τ sin ψ, cos τ).
    """
    t, p = math.radians(tilt_deg), math.radians(azimuth_deg)
    return np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])


def _rotation(vector_rad) -> np.ndarray:
    """Rotation matrix of a rotation vector (Rodrigues)."""
    k = np.asarray(vector_rad, np.float64)
    t = float(np.linalg.norm(k))
    if t == 0.0:
        return np.eye(3)
    k = k / t
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(t) * kx + (1.0 - math.cos(t)) * kx @ kx


def lean_rotation(lean_deg: float, lean_azimuth_deg: float) -> np.ndarray:
    """R_b: the rotation that leans the table's z by β toward an azimuth (module docstring).

    Parameters
    ----------
    lean_deg, lean_azimuth_deg : float
        β and its azimuth in the table's frame [deg].

    Returns
    -------
    (3, 3) ndarray float64
        The rotation about (−sin ψ_b, cos ψ_b, 0) by β: e_z onto (sin β cos ψ_b, sin β sin ψ_b, cos β).
    """
    b, p = math.radians(lean_deg), math.radians(lean_azimuth_deg)
    return _rotation([-b * math.sin(p), b * math.cos(p), 0.0])


def table_top_plane(camera_from_table, angle_deg: float, offset_mm: float, tilt_deg: float,
                    azimuth_deg: float, lean_deg: float = 0.0,
                    lean_azimuth_deg: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """The top's plane at a table angle, in the camera frame.

    Parameters
    ----------
    camera_from_table : (4, 4) array_like float
        The table's own frame at angle 0 in the camera frame (module docstring) [mm].
    angle_deg : float
        Table angle θ [deg].
    offset_mm, tilt_deg, azimuth_deg : float
        h [mm], τ and ψ [deg].
    lean_deg, lean_azimuth_deg : float, default 0.0
        The disc axis's lean β and its azimuth [deg].

    Returns
    -------
    normal : (3,) ndarray float64
        Unit normal ``R_cam · R_b · R_z(θ) · n0`` [-].
    point_mm : (3,) ndarray float64
        The top's centre, the axis point plus h along the axis [mm].
    """
    m = np.asarray(camera_from_table, np.float64)
    c, s = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))
    n0 = tilt_normal(tilt_deg, azimuth_deg)
    n_t = np.array([c * n0[0] - s * n0[1], s * n0[0] + c * n0[1], n0[2]])
    return m[:3, :3] @ lean_rotation(lean_deg, lean_azimuth_deg) @ n_t, m[:3, 3] + offset_mm * m[:3, 2]


def _residuals_px(x, p_t, g_t, cos_t, sin_t, lean_axis) -> np.ndarray:
    """Image residuals along the column of points in the table frame at 0 (module docstring)."""
    h, b, tx, ty = x
    tau = math.hypot(tx, ty)
    k = math.sin(tau) / tau if tau > 0 else 1.0
    n0 = (k * tx, k * ty, math.cos(tau))
    n = np.stack([cos_t * n0[0] - sin_t * n0[1], sin_t * n0[0] + cos_t * n0[1], np.full_like(cos_t, n0[2])], axis=1)
    n = n @ _rotation(b * lean_axis).T
    return np.einsum("ij,ij->i", p_t - (0.0, 0.0, h), n) / np.einsum("ij,ij->i", g_t, n)


def fit_table_top(points_mm, dpoint_dv_mm, frame, angles_deg, camera_from_table, *,
                  fit_tilt: bool = True, fit_lean: bool = True) -> TableTop:
    """Fit h, β, τ, ψ of the table's top to its line's points of every frame (module docstring).

    Parameters
    ----------
    points_mm : (n, 3) array_like float
        The line's stripe points on the sheet, camera frame [mm].
    dpoint_dv_mm : (n, 3) array_like float
        ∂X/∂v at each point: how its sheet point moves per pixel down its image column [mm/px].
    frame : (n,) array_like int
        Each point's frame index into ``angles_deg``.
    angles_deg : (m,) array_like float
        Each frame's table angle θ [deg].
    camera_from_table : (4, 4) array_like float
        The table's own frame at angle 0 in the camera frame [mm].
    fit_tilt : bool, default True
        Fit the wobbling tilt τ, ψ; False: τ = 0.
    fit_lean : bool, default True
        Fit the lean β of the disc's axis toward the line's direction; False: β = 0.  With
        neither, h alone has a closed form: the weighted mean of the points' heights, weights
        (1 / ∂z/∂v)².

    Returns
    -------
    TableTop
        The fit and its figures.

    Raises
    ------
    ValueError
        Mismatched shapes, fewer finite points than 2 per parameter, or a tilt fitted from one angle
        alone (a tilt needs the line at two angles at least).
    """
    from scipy.optimize import least_squares

    p, g = np.asarray(points_mm, np.float64), np.asarray(dpoint_dv_mm, np.float64)
    f, a = np.asarray(frame), np.asarray(angles_deg, np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or g.shape != p.shape or f.shape != (len(p),):
        raise ValueError(f"points {p.shape}, derivatives {g.shape} and frames {f.shape}: expected (n, 3), (n, 3), (n,)")
    ok = np.all(np.isfinite(p), axis=1) & np.all(np.isfinite(g), axis=1)
    p, g, f = p[ok], g[ok], f[ok].astype(np.int64)
    free = np.array([True, fit_lean, fit_tilt, fit_tilt])
    if len(p) < 2 * free.sum():
        raise ValueError(f"the table's top needs at least {2 * free.sum()} finite points, got {len(p)}")
    if fit_tilt and len(np.unique(np.mod(a[f], 360.0))) < 2:
        raise ValueError("a tilted top is fitted from its line at two table angles at least; all points are at one")
    m = np.asarray(camera_from_table, np.float64)
    p_t, g_t = (p - m[:3, 3]) @ m[:3, :3], g @ m[:3, :3]
    along = np.linalg.svd(p_t[:, :2] - p_t[:, :2].mean(axis=0), full_matrices=False)[2][0]
    lean_axis = np.array([-along[1], along[0], 0.0])          # e_z × L: a lean toward the line L
    th = np.radians(a[f])
    cos_t, sin_t = np.cos(th), np.sin(th)

    def fun(y):
        x = np.zeros(4)
        x[free] = y
        return _residuals_px(x, p_t, g_t, cos_t, sin_t, lean_axis)

    n_par = int(free.sum())
    sol = least_squares(fun, np.zeros(n_par), method="lm", x_scale=np.full(n_par, 1e-2), xtol=1e-15, ftol=1e-15,
                        gtol=1e-15)
    x, cov = np.zeros(4), np.zeros((4, 4))
    x[free] = sol.x
    r = sol.fun
    cov[np.ix_(free, free)] = float(r @ r) / max(len(r) - n_par, 1) * np.linalg.pinv(sol.jac.T @ sol.jac)
    h, b = float(x[0]), float(x[1])
    tau, psi, se_tau, se_psi = 0.0, 0.0, 0.0, math.inf
    t = x[2:]
    if fit_tilt and np.hypot(*t) > 0:
        tau = float(np.hypot(*t))
        u = t / tau
        w = np.array([-u[1], u[0]])
        c = cov[2:, 2:]
        psi = math.atan2(t[1], t[0])
        se_tau, se_psi = math.sqrt(max(u @ c @ u, 0.0)), math.sqrt(max(w @ c @ w, 0.0)) / tau
    lean_az = math.degrees(math.atan2(along[1], along[0])) + (180.0 if b < 0 else 0.0)
    lean_az = (lean_az + 180.0) % 360.0 - 180.0
    return TableTop(h, math.degrees(tau), math.degrees(psi), math.degrees(abs(b)), lean_az,
                    math.sqrt(max(cov[0, 0], 0.0)), math.degrees(se_tau), math.degrees(se_psi),
                    math.degrees(math.sqrt(max(cov[1, 1], 0.0))), float(np.sqrt(np.mean(r ** 2))), int(len(r)),
                    int(len(np.unique(f))))


def table_top_of_folder(folder, calibration, columns, camera_from_table, *, detector: str = "cog",
                        frames=None, threshold_px: float = 2.0, stripes=None) -> TableTop:
    """The table's top fitted from a frame folder's table line (module docstring).

    Parameters
    ----------
    folder : FrameFolder
        A rotary scan (:func:`scheimpflug.io.frames.open_frame_folder`), ``angle_deg`` per frame.
    calibration : SheetModel
        Its calibration, with the sheet in its camera frame (``camera_from_pixel``).
    columns : (float, float)
        The image column range [px] where the table's line shows.
    camera_from_table : (4, 4) array_like float
        The table's own frame at angle 0 in the calibration's camera frame [mm].
    detector : str, default "cog"
        The stripe detector (:mod:`scheimpflug.stripe`).
    frames : sequence of int, optional
        The frames to use (default all).
    threshold_px : float, default 2.0
        Largest distance of a point from its frame's RANSAC line [px].
    stripes : FolderStripes, optional
        The folder's stripes already extracted with that detector (kept saturated samples):
        :func:`table_line_points`.

    Returns
    -------
    TableTop
        The fit (:func:`fit_table_top`).

    Raises
    ------
    ValueError
        A frame without ``angle_deg``, a range holding fewer than 6 line points, or
        :func:`fit_table_top`'s.
    """
    angles = [r.angle_deg for r in folder.frames]
    if any(x is None for x in angles):
        raise ValueError(f"{folder.path}: every frame needs its angle_deg to fit the table's top")
    u, v, f = table_line_points(folder, columns, detector=detector, frames=frames, threshold_px=threshold_px,
                                stripes=stripes)
    if len(u) < 6:
        raise ValueError(f"columns {columns[0]:g}:{columns[1]:g} hold fewer than 6 line points: no table line there")
    x = np.asarray(calibration.camera_from_pixel(u, v), np.float64)
    dv = 0.5
    g = (np.asarray(calibration.camera_from_pixel(u, v + dv), np.float64)
         - np.asarray(calibration.camera_from_pixel(u, v - dv), np.float64)) / (2.0 * dv)
    return fit_table_top(x, g, f, np.asarray(angles, np.float64), camera_from_table)


def table_line_points(folder, columns, *, detector: str = "cog", frames=None, threshold_px: float = 2.0,
                      stripes=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The stripe points of a still line that may move between frames: a column range, per frame its RANSAC line.

    Parameters
    ----------
    folder : FrameFolder
        The frames (:func:`scheimpflug.io.frames.open_frame_folder`).
    columns : (float, float)
        The image column range [px].
    detector : str, default "cog"
        The stripe detector (:mod:`scheimpflug.stripe`).
    frames : sequence of int, optional
        The frames to use (default all).
    threshold_px : float, default 2.0
        Largest distance of a point from its frame's line [px]
        (:func:`scheimpflug.fixed_lines.line_inliers`, seeded, 100 pairs tried).
    stripes : FolderStripes, optional
        The folder's stripes already extracted with ``detector`` (kept saturated samples,
        :func:`scheimpflug.reconstruct.extract_folder_stripes`); default: extracted here.

    Returns
    -------
    u_px, v_px : (n,) ndarray float64
        The kept points (image column, row) [px].
    frame : (n,) ndarray int64
        Each point's frame index.
    """
    from scheimpflug.fixed_lines import line_inliers
    from scheimpflug.reconstruct import extract_folder_stripes
    from scheimpflug.stripe import image_pixels

    st = extract_folder_stripes(folder, detector, keep_saturated=True) if stripes is None else stripes
    c0, c1 = columns
    us, vs, fs = [np.zeros(0)], [np.zeros(0)], [np.zeros(0, np.int64)]
    for i in range(len(st.rows)) if frames is None else frames:
        u, v = image_pixels(st.rows[i], st.u[i], st.along)
        sel = (u >= c0) & (u <= c1)
        if sel.sum() < 3:
            continue
        u, v = u[sel], v[sel]
        keep = line_inliers(u, v, threshold_px=threshold_px, trials=100)
        us.append(u[keep])
        vs.append(v[keep])
        fs.append(np.full(int(keep.sum()), i, np.int64))
    return np.concatenate(us), np.concatenate(vs), np.concatenate(fs)


def disc_radius_mm(calibration, u_px, v_px, *, band_mm: float = 10.0, quantile: float = 0.99) -> float | None:
    """The table disc's radius: how far from the axis the sheet's line on the table reaches.

    The sheet crosses the table's top in a line from the axis outward; where the top ends the
    line turns down the disc's rim (a cylinder about the axis: the points keep their distance
    from the axis and drop along it).  The disc's radius is the far end of the table's points:
    the ``quantile`` of their distance from the axis, over the points within ``band_mm`` of the
    calibrated table plane (the top and the rim's upper part; the floor and walls beyond are
    farther from the plane).  On FabScan's ``scan-2_1`` the line turns down the rim at 58.5 mm
    from the axis, where its config's ``turntable.radius`` (70 mm) is the radius it scans within.

    Parameters
    ----------
    calibration : SheetModel
        The scan's calibration, with a turntable axis
        (:func:`scheimpflug.still_points.axis_coordinates_mm`).
    u_px, v_px : (n,) array_like float
        The table region's stripe points of every frame, column and row [px].
    band_mm : float, default 10.0
        Largest distance from the calibrated table plane along the axis [mm].
    quantile : float, default 0.99
        The quantile of the distances taken as the rim (robust to a few stray points) [-].

    Returns
    -------
    float or None
        The radius [mm]; None without an axis or with fewer than 20 points in the band.
    """
    from scheimpflug.still_points import axis_coordinates_mm

    found = axis_coordinates_mm(calibration, u_px, v_px)
    if found is None:
        return None
    r, h = found
    ok = np.isfinite(r) & np.isfinite(h) & (np.abs(h) <= band_mm)
    if np.count_nonzero(ok) < 20:
        return None
    return float(np.quantile(r[ok], quantile))
