"""Exact ground truth from geometry (never from the rendered image).

Per frame the twin knows, from the posed meshes alone:

**Stripe centre per row.**  The laser sheet's mid-plane (stage y = 0) cuts the
posed mesh in a polyline (:func:`sheet_section`).  For every sensor row r the
points of that polyline whose projection (:func:`scheimpflug.model.camera.project_points`,
the camera's definition, misalignments and distortion included) lies exactly on
the row's centre line v = r are found (:func:`row_crossings`; the projected
v along each segment is solved to < 1e-9 px).  A crossing counts only if it is

* visible: the ray from the lens centre to the point meets no surface more than
  ``TruthTolerances.visibility_mm`` before it (the chief ray of the point);
* lit: the segment from the laser origin to the point is likewise unobstructed,
  and the point lies inside the fan (elevation from the laser origin, in the
  sheet, within ±fan_angle_deg/2 — the nominal fan edge);
* on the sensor: −0.5 ≤ u ≤ columns − 0.5.

Several surviving crossings in one row (e.g. two surfaces at the same height
both in view) are counted in ``stripe_count``; the *primary* one kept in
``stripe_u`` / ``stripe_point_mm`` is the one with the smallest u, i.e. the
smallest distance D from the object hinge along the sheet (the surface nearest
the laser/camera side of the measuring range).

**Stripe along the rows.**  A camera in which a turning part's stripe runs
along the rows (:func:`scheimpflug.model.camera.stripe_along` "rows", e.g.
FabScan's, turned by 90°) has one stripe point per *column*: the truth is then
per line of the :func:`scheimpflug.stripe.oriented` frame (the transposed
frame the extraction reads) — the crossings with the column centre lines u = c,
``stripe_u`` (columns,) holding the row v of each, the primary the smallest v —
and the frame folder's manifest says ``stripe_along = "rows"``, as an imported
folder's does.  Every array below then has ``columns`` in place of ``rows``.

**Per-pixel truth.**  One chief ray per pixel centre (from the lens centre along
:func:`scheimpflug.model.camera.chief_ray_from_pixel`): the first surface it meets,
its 3-D point and object id (0 = nothing).

**Truth file** ``truth/NNNNN.npz`` (numpy ``savez_compressed``), keys:

======================= ======================  =============================================
key                     shape, dtype            meaning
======================= ======================  =============================================
``stripe_u``            (rows,) float64         exact stripe-centre column per row [px]; NaN = none
``stripe_point_mm``     (rows, 3) float64       its 3-D point in the reference frame [mm]; NaN = none
``stripe_object_id``    (rows,) int16           object id of that point (0 = none)
``stripe_count``        (rows,) uint8           number of visible, lit crossings in the row
``point_mm``            (rows, columns, 3) f32  per-pixel chief-ray hit, reference frame [mm]; NaN
                                                = nothing (only in frames with pixel truth)
``object_id``           (rows, columns) uint16  per-pixel object id, 0 = nothing (same frames)
``secondary_u``         (rows, 4) float32       columns of the peaks of secondary light in the
                                                row, strongest first [px]; NaN = none
``secondary_share``     (rows, 4) float32       each peak's light (±3 px) / the row's laser
                                                light [-]
``secondary_fraction``  (rows,) float32         all secondary light / the row's laser light [-]
``subsurface_fraction`` (rows,) float32         light that entered the first lit surface and
                                                left it elsewhere / the row's laser light [-]
======================= ======================  =============================================

**Secondary light** (:func:`secondary_truth`) is the one part of the truth that
comes from the renderer, not from geometry: the expected (noise- and
speckle-free) laser light of the frame split by origin — light that reached the
imaged surface after at least one earlier surface (inter-reflections, rig key
``[twin] bounces`` > 1) and light that left the first lit surface through its
subsurface.  Its peaks per row let a detector's wrong-peak choices be counted
against ``stripe_u``.  Without bounces or subsurface they are NaN / 0.

Reference frame: the stage frame of :mod:`sim.stages` with the part at
θ = 0 for the rotary stage (``truth/mesh.ply`` is in this frame, so truth points
lie on it); for the calibration plate, the stage frame itself (the plate moves
in it; ``truth/mesh.ply`` is the plate at the first stage position).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Protocol

import numba
import numpy as np

from scheimpflug.model.camera import (
    chief_ray_from_pixel,
    lens_centre_mm,
    lens_state,
    project_points,
    sensor_pose,
    stripe_along,
)
from scheimpflug.model.distortion import is_radial
from scheimpflug.model.hinge import hinge_geometry
from scheimpflug.model.rig import Rig, active_error_models

from .lightsheet import light_sheet, posed_sheet, sheet_offset_mm
from .stages import axis_distance_mm, invert, transform_points

__all__ = [
    "BruteForceCaster",
    "RayCaster",
    "SceneCaster",
    "SceneTruth",
    "StripeTruth",
    "TruthSection",
    "TruthTolerances",
    "laser_origin_mm",
    "opencv_camera",
    "opencv_laser_plane",
    "pixel_directions",
    "pixel_truth",
    "SECONDARY_PEAKS",
    "rig_truth",
    "row_crossings",
    "secondary_truth",
    "sheet_section",
    "stripe_truth",
    "surface_section",
]


@dataclass(frozen=True)
class TruthTolerances:
    """Numerical tolerances of the truth (one place, one reason each).

    Parameters
    ----------
    visibility_mm : float, default 0.005
        A surface closer than this to a point along its camera/laser ray does
        not hide it [mm]: ≫ float32 rounding of rig-frame vertices (≈ 3e-5 mm
        at 600 mm), ≪ any real occluder.
    row_residual_px : float, default 1e-9
        Stop refining a row crossing when |v − r| is below this [px].
    max_iterations : int, default 30
        At most this many secant steps per crossing [-].
    """

    #: a surface closer than this to a point along its camera/laser ray does not hide it [mm]:
    #: ≫ float32 rounding of rig-frame vertices (≈ 3e-5 mm at 600 mm), ≪ any real occluder.
    visibility_mm: float = 0.005
    #: stop refining a row crossing when |v − r| is below this [px].
    row_residual_px: float = 1e-9
    #: at most this many secant steps per crossing.
    max_iterations: int = 30


class RayCaster(Protocol):
    """First-hit ray queries in the rig frame, for the scene posed for the current frame.

    A structural type (:class:`typing.Protocol`): any object with a matching
    :meth:`first_hit` is a caster (:class:`SceneCaster`, :class:`BruteForceCaster`).

    Parameters
    ----------
    *args, **kwargs
        None: a protocol is a type to implement, not a class to instantiate.
    """

    def first_hit(self, origins_mm: np.ndarray, directions: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
        """First surface met by each ray.

        Parameters
        ----------
        origins_mm : (n, 3) ndarray
            Ray origins, rig frame [mm].
        directions : (n, 3) ndarray
            Unit ray directions, rig frame [-].

        Returns
        -------
        t_mm : (n,) ndarray
            Distance to the first hit [mm]; ``inf`` where nothing is hit.
        object_id : (n,) ndarray of int
            Object id of the hit part (0 = none).
        """


# ------------------------------------------------------------------ sheet section


def sheet_section(vertices_mm, faces, face_ids, plane_point_mm, plane_normal
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Cut a triangle mesh by a plane.

    Parameters
    ----------
    vertices_mm : (n, 3) float
        Mesh vertices, in any frame [mm].
    faces : (m, 3) int
        Vertex indices of the triangles.
    face_ids : (m,) int
        Object id per face.
    plane_point_mm : (3,) float
        A point of the plane, same frame as the vertices [mm].
    plane_normal : (3,) float
        The plane's normal (need not be unit), same frame.

    Returns
    -------
    segments : (k, 2, 3) float64
        One segment per cut face, same frame as the vertices [mm].
    segment_ids : (k,) int
        Object id of each segment's face.

    Notes
    -----
    Vertices with signed distance ≥ 0 count as above the plane, so a plane
    through vertices still gives a gap-free polyline (possibly with
    zero-length segments).  Each crossing edge is interpolated from its
    lower-indexed vertex, so neighbouring faces share bit-identical points.
    """
    v = np.asarray(vertices_mm, dtype=np.float64)
    n = np.asarray(plane_normal, dtype=np.float64)
    n = n / np.linalg.norm(n)
    d = v @ n - np.asarray(plane_point_mm, dtype=np.float64) @ n
    return surface_section(v, faces, face_ids, d)


def surface_section(vertices_mm, faces, face_ids, signed_distance_mm, return_faces: bool = False
                    ) -> tuple[np.ndarray, ...]:
    """Cut a triangle mesh by the zero set of a signed distance given at its vertices.

    Parameters
    ----------
    vertices_mm : (n, 3) float
        Mesh vertices, in any frame [mm].
    faces : (m, 3) int
        Vertex indices of the triangles.
    face_ids : (m,) int
        Object id per face.
    signed_distance_mm : (n,) float
        Signed distance of each vertex from the cutting surface [mm].
    return_faces : bool, default False
        Also return the index of each segment's face.

    Returns
    -------
    segments : (k, 2, 3) float64
        One segment per cut face, same frame as the vertices [mm]; crossings
        are interpolated linearly along the edges (exact for a plane; a
        chord of the true section for a curved surface).
    segment_ids : (k,) int
        Object id of each segment's face.
    face_index : (k,) int
        Index of each segment's face in ``faces`` (only with ``return_faces``).
    """
    v = np.asarray(vertices_mm, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    d = np.asarray(signed_distance_mm, dtype=np.float64)
    above_v = d >= 0
    cut = _cut_faces(above_v, f)
    fc = f[cut]
    ac = above_v[fc]
    pts = []
    for i, j in ((0, 1), (1, 2), (2, 0)):
        a, b = np.minimum(fc[:, i], fc[:, j]), np.maximum(fc[:, i], fc[:, j])
        crosses = ac[:, i] != ac[:, j]
        t = np.where(crosses, d[a], 0.0) / np.where(crosses, d[a] - d[b], 1.0)
        p = v[a] + t[:, None] * (v[b] - v[a])
        pts.append((p, crosses))
    p_all = np.stack([p for p, _ in pts], axis=1)          # (k, 3 edges, 3)
    m_all = np.stack([m for _, m in pts], axis=1)          # (k, 3) exactly two True
    order = np.argsort(~m_all, axis=1, kind="stable")[:, :2]
    segments = np.take_along_axis(p_all, order[:, :, None], axis=1)
    if return_faces:
        return segments, np.asarray(face_ids)[cut], np.flatnonzero(cut)
    return segments, np.asarray(face_ids)[cut]


@numba.njit(parallel=True, cache=True, nogil=True)
def _cut_faces(above, faces):  # pragma: no cover - compiled
    """(m,) bool: faces whose vertices lie on both sides (``above`` per vertex)."""
    cut = np.empty(faces.shape[0], dtype=np.bool_)
    for i in numba.prange(faces.shape[0]):
        n = int(above[faces[i, 0]]) + int(above[faces[i, 1]]) + int(above[faces[i, 2]])
        cut[i] = n == 1 or n == 2
    return cut


# ------------------------------------------------------------------ row crossings


def row_crossings(rig: Rig, segments_mm, tol: TruthTolerances = TruthTolerances(), pose=None,
                  along: str = "columns") -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Where projected segments cross row centre lines v = r (r = 0 … rows − 1), or column lines.

    Parameters
    ----------
    rig : Rig
        The rig; its camera model (:func:`scheimpflug.model.camera.project_points`)
        defines the projection.
    segments_mm : (k, 2, 3) float
        Segments, rig frame [mm] (in front of the lens).
    tol : TruthTolerances, optional
        Residual and iteration limit of the secant solve.
    pose : SensorPose, optional
        Sensor pose; default :func:`scheimpflug.model.camera.sensor_pose` (rig).
    along : {"columns", "rows"}, default "columns"
        The stripe's direction (:func:`scheimpflug.model.camera.stripe_along`): "rows"
        solves the column centre lines u = c instead (the lines of the
        :func:`scheimpflug.stripe.oriented` frame).

    Returns
    -------
    rows : (c,) int64
        Row index of each crossing (column index for ``along="rows"``).
    u_px : (c,) float64
        Column of the crossing [px] (its row for ``along="rows"``).
    points_mm : (c, 3) float64
        Point of the crossing, rig frame [mm].
    segment_index : (c,) int
        Which segment it lies on.

    Notes
    -----
    Rows are taken half-open, min(v0, v1) ≤ r < max(v0, v1), so a polyline
    vertex on a row centre is counted once.  The crossing parameter t along the
    segment starts from the linear-fractional v(t) through the projections of the
    end points and the midpoint — exact for a lens without distortion, where the
    pixel of a point is its central projection through the lens centre — and is
    refined by the secant method on the exact projection until |v − r| is below
    the tolerance.
    """
    pose = sensor_pose(rig) if pose is None else pose
    ax, n_lines = _line_axis(rig, along)
    seg = np.asarray(segments_mm, dtype=np.float64).reshape(-1, 2, 3)
    k = len(seg)
    mid = seg[:, 0] + 0.5 * (seg[:, 1] - seg[:, 0])
    v_all = project_points(rig, np.concatenate([seg.reshape(-1, 3), mid]), pose).uv_px[:, ax]
    v_end, v_mid = v_all[:2 * k].reshape(k, 2), v_all[2 * k:]
    lo, hi = np.minimum(v_end[:, 0], v_end[:, 1]), np.maximum(v_end[:, 0], v_end[:, 1])
    r_lo = np.clip(np.ceil(lo), 0, n_lines)
    r_hi = np.clip(np.ceil(hi), 0, n_lines)          # exclusive
    ok = np.isfinite(lo) & np.isfinite(hi)
    count = np.where(ok, r_hi - r_lo, 0).astype(np.int64)
    idx = np.repeat(np.arange(len(seg)), count)
    first = np.repeat(np.cumsum(count) - count, count)
    rows = (np.repeat(r_lo, count) + np.arange(count.sum()) - first).astype(np.int64)
    t, u = _solve_rows(rig, pose, seg[idx], v_end[idx], v_mid[idx], rows.astype(np.float64), tol, ax)
    pts = seg[idx, 0] + t[:, None] * (seg[idx, 1] - seg[idx, 0])
    return rows, u, pts, idx


def _line_axis(rig: Rig, along: str) -> tuple[int, int]:
    """The pixel coordinate fixed on a line (1: v for "columns", 0: u for "rows") and the number of lines."""
    if along == "columns":
        return 1, rig.sensor.rows
    if along == "rows":
        return 0, rig.sensor.columns
    raise ValueError(f"along must be 'columns' or 'rows', got {along!r}")


def _across_on_sensor(rig: Rig, along: str, across: np.ndarray) -> np.ndarray:
    """Whether positions across the lines lie on the sensor (−0.5 … size − 0.5)."""
    size = rig.sensor.columns if along == "columns" else rig.sensor.rows
    return (across >= -0.5) & (across <= size - 0.5)


def _solve_rows(rig, pose, seg, v_end, v_mid, target, tol, ax: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Solve v(P(t)) = target on each segment, t in [0, 1]; return t and u there (``ax`` 0: u ↔ v).

    Start: the linear-fractional v(t) = (v0 + b·t)/(1 + d·t) through t = 0, ½, 1 (exact
    without lens distortion), else the linear interpolation.  Then secant steps on the
    segments whose residual is above ``tol.row_residual_px``.
    """
    v0, v1, vm = v_end[:, 0], v_end[:, 1], v_mid
    with np.errstate(divide="ignore", invalid="ignore"):
        d = (2.0 * vm - v0 - v1) / (v1 - vm)
        b = v1 - v0 + v1 * d
        t_frac = (target - v0) / (b - target * d)
        t_lin = (target - v0) / (v1 - v0)
    t_lin = np.where(np.isfinite(t_lin), t_lin, 0.5)
    t1 = np.clip(np.where(np.isfinite(t_frac) & (t_frac >= 0) & (t_frac <= 1), t_frac, t_lin), 0.0, 1.0)
    uv = project_points(rig, seg[:, 0] + t1[:, None] * (seg[:, 1] - seg[:, 0]), pose).uv_px
    f1, u1 = uv[:, ax] - target, uv[:, 1 - ax]
    far = np.abs(t1 - 0.5) > 0.25                 # the other point of the first secant step
    t0 = np.where(far, 0.5, np.where(t1 < 0.5, 1.0, 0.0))
    f0 = np.where(far, vm, np.where(t1 < 0.5, v1, v0)) - target
    act = np.flatnonzero(np.abs(f1) > tol.row_residual_px)
    for _ in range(tol.max_iterations):
        if len(act) == 0:
            break
        a0, a1, b0, b1 = t0[act], t1[act], f0[act], f1[act]
        denom = b1 - b0
        with np.errstate(divide="ignore", invalid="ignore"):
            t2 = np.where(denom != 0, a1 - b1 * (a1 - a0) / denom, a1)
        t2 = np.clip(t2, 0.0, 1.0)
        sa = seg[act]
        uv = project_points(rig, sa[:, 0] + t2[:, None] * (sa[:, 1] - sa[:, 0]), pose).uv_px
        f2 = uv[:, ax] - target[act]
        t0[act], f0[act], t1[act], f1[act], u1[act] = a1, b1, t2, f2, uv[:, 1 - ax]
        act = act[np.abs(f2) > tol.row_residual_px]
    return t1, u1


# ------------------------------------------------------------------ visibility


def laser_origin_mm(rig: Rig) -> np.ndarray:
    """Position of the laser origin.

    Parameters
    ----------
    rig : Rig
        The rig (``laser.origin_x_mm``, ``laser.scheimpflug_distance_mm``,
        ``laser.tan_phi``).

    Returns
    -------
    (3,) float64
        The origin, rig frame [mm]: on the sheet ``y = d − x·tan φ`` at
        ``x = origin_x_mm``, ``z = 0``.
    """
    x = rig.laser.origin_x_mm
    return np.array([x, rig.laser.scheimpflug_distance_mm - x * rig.laser.tan_phi, 0.0])


def _unobstructed(caster: RayCaster, origin, points, tol: TruthTolerances) -> np.ndarray:
    """(n,) bool: the segment origin → point meets no surface before the point."""
    delta = points - origin
    dist = np.linalg.norm(delta, axis=1)
    if len(points) == 0:
        return np.zeros(0, dtype=bool)
    hit_t, _ = caster.first_hit(np.broadcast_to(origin, points.shape).copy(), delta / dist[:, None])
    return hit_t >= dist - tol.visibility_mm


def _in_fan(rig: Rig, points, sheet=None) -> np.ndarray:
    if sheet is not None:
        rel = points - sheet.origin_mm
        elevation = np.degrees(np.arctan2(rel @ sheet.up, rel @ sheet.prop_dir))
        return np.abs(elevation) <= 0.5 * rig.laser.fan_angle_deg
    g = hinge_geometry(rig)
    rel = points - laser_origin_mm(rig)
    elevation = np.degrees(np.arctan2(rel[:, 2], rel @ g.propagation_dir))
    return np.abs(elevation) <= 0.5 * rig.laser.fan_angle_deg


# ------------------------------------------------------------------ stripe truth


@dataclass(frozen=True, eq=False)
class StripeTruth:
    """Per-row stripe truth of one frame (see the module docstring for the meaning).

    Parameters
    ----------
    stripe_u : (rows,) float64
        Exact stripe-centre column per row [px]; NaN = none.
    stripe_point_mm : (rows, 3) float64
        Its 3-D point, reference frame [mm]; NaN = none.
    stripe_object_id : (rows,) int16
        Object id of that point (0 = none).
    stripe_count : (rows,) uint8
        Number of visible, lit crossings in the row (capped at 255).
    """

    stripe_u: np.ndarray
    stripe_point_mm: np.ndarray
    stripe_object_id: np.ndarray
    stripe_count: np.ndarray

    def arrays(self) -> dict:
        """The four arrays by their truth-file keys.

        Returns
        -------
        dict of str to ndarray
            ``stripe_u``, ``stripe_point_mm``, ``stripe_object_id``,
            ``stripe_count`` (the arrays themselves, not copies).
        """
        return {"stripe_u": self.stripe_u, "stripe_point_mm": self.stripe_point_mm,
                "stripe_object_id": self.stripe_object_id, "stripe_count": self.stripe_count}


def stripe_truth(rig: Rig, vertices_part_mm, faces, face_ids, rig_from_part, ref_from_part,
                 caster: RayCaster, tol: TruthTolerances = TruthTolerances(),
                 rig_from_laser=None) -> StripeTruth:
    """Exact stripe centre per row of one frame.

    The sheet's mid-plane cuts the mesh (in the part frame), the cut is
    moved to the rig frame, its crossings with the row centre lines are
    solved (:func:`row_crossings`), and those on the sensor, inside the fan,
    seen from the lens centre and lit from the laser origin are kept; per row
    the one with the smallest u is the primary (module docstring).

    Parameters
    ----------
    rig : Rig
        The rig.
    vertices_part_mm : (n, 3) float
        Scene mesh vertices, part frame [mm].
    faces : (m, 3) int
        Vertex indices of the triangles.
    face_ids : (m,) int
        Object id per face.
    rig_from_part : (4, 4) float
        Pose of the part in the rig frame for this frame [mm].
    ref_from_part : (4, 4) float
        Pose of the part in the truth's reference frame [mm].
    caster : RayCaster
        First-hit queries in the rig frame for the scene posed by ``rig_from_part``.
    tol : TruthTolerances, optional
        Visibility and row-solve tolerances.
    rig_from_laser : (4, 4) float, optional
        This frame's pose of the laser sheet (pointing drift,
        :func:`sim.lightsheet.pointing_pose`) [mm]; None = the nominal sheet.

    Returns
    -------
    StripeTruth
        Per-row stripe truth; points in the reference frame.

    Notes
    -----
    The cut is the sheet actually rendered: turned by ``rig_from_laser`` and,
    with ``laser.line_bow_mrad``, the bowed mid-surface o = r·β(α)
    (:func:`sim.lightsheet.sheet_offset_mm`); the lens centre is the real
    lens's (:func:`scheimpflug.model.camera.lens_centre_mm`).
    """
    part_from_rig = invert(rig_from_part)
    seg, seg_ids, tri_n = _cut(rig, vertices_part_mm, faces, face_ids, part_from_rig, rig_from_laser)
    seg = transform_points(rig_from_part, seg)
    front = (seg[:, :, 0] > lens_state(rig).focal_length_mm + lens_centre_mm(rig)[0]).all(axis=1)
    seg = seg[front]
    along = stripe_along(rig)
    ax, n_lines = _line_axis(rig, along)
    rows, u, pts, idx = row_crossings(rig, seg, tol, along=along)
    ids = seg_ids[idx] if len(idx) else np.zeros(0, dtype=np.int64)
    if tri_n is not None and len(idx):      # a bowed sheet: onto the curved section, exactly
        normals = tri_n[front][idx] @ rig_from_part[:3, :3].T
        pts = _onto_bowed_section(rig, posed_sheet(light_sheet(rig), rig_from_laser), pts,
                                  rows.astype(np.float64), normals, tol, ax=ax)
        u = project_points(rig, pts).uv_px[:, 1 - ax]
    sheet = None if rig_from_laser is None else posed_sheet(light_sheet(rig), rig_from_laser)
    keep = _across_on_sensor(rig, along, u) & _in_fan(rig, pts, sheet)
    rows, u, pts, ids = rows[keep], u[keep], pts[keep], ids[keep]
    keep = _unobstructed(caster, lens_centre_mm(rig), pts, tol)
    origin = laser_origin_mm(rig) if sheet is None else sheet.origin_mm
    keep[keep] = _unobstructed(caster, origin, pts[keep], tol)
    return _primary_per_row(n_lines, rows[keep], u[keep],
                            transform_points(ref_from_part @ part_from_rig, pts[keep]), ids[keep])


def _cut(rig, vertices_part_mm, faces, face_ids, part_from_rig, rig_from_laser):
    """The mesh cut by the frame's sheet, in the part frame (no mesh transform)."""
    if rig_from_laser is None and rig.laser.line_bow_mrad == 0.0:
        g = hinge_geometry(rig)
        plane_point = transform_points(part_from_rig, g.object_hinge_mm)
        plane_normal = part_from_rig[:3, :3] @ g.sheet_normal
        return (*sheet_section(vertices_part_mm, faces, face_ids, plane_point, plane_normal), None)
    sheet = posed_sheet(light_sheet(rig), rig_from_laser)
    rot = part_from_rig[:3, :3]       # the sheet in the part frame
    local = dataclasses.replace(sheet, origin_mm=transform_points(part_from_rig, sheet.origin_mm),
                                prop_dir=rot @ sheet.prop_dir, normal=rot @ sheet.normal,
                                up=rot @ sheet.up)
    v = np.asarray(vertices_part_mm, dtype=np.float64)
    seg, ids, face = surface_section(v, faces, face_ids, sheet_offset_mm(local, v), return_faces=True)
    if sheet.bow_rad == 0.0:
        return seg, ids, None
    tri = v[np.asarray(faces, dtype=np.int64)[face]]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    return seg, ids, n / np.linalg.norm(n, axis=1, keepdims=True)


def _onto_bowed_section(rig, sheet, pts, rows, normals, tol, iterations: int = 8, ax: int = 1):
    """Move row crossings found on chords onto the bowed sheet, within their triangle's plane.

    Two conditions, two unknowns per point (a displacement a·e1 + c·e2 in the plane):
    zero offset from the bowed mid-surface and the projection on the row centre; Newton
    with a finite-difference Jacobian (step 1e-4 mm).
    """
    e1 = np.cross(normals, sheet.normal)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(normals, e1)

    def residual(p):
        return np.stack([sheet_offset_mm(sheet, p), project_points(rig, p).uv_px[:, ax] - rows], axis=1)

    p = pts.copy()
    h = 1e-4
    for _ in range(iterations):
        f0 = residual(p)
        if np.all(np.abs(f0[:, 0]) < 1e-9) and np.all(np.abs(f0[:, 1]) < tol.row_residual_px):
            break
        j = np.stack([(residual(p + h * e) - f0) / h for e in (e1, e2)], axis=2)   # (n, 2, 2)
        det = j[:, 0, 0] * j[:, 1, 1] - j[:, 0, 1] * j[:, 1, 0]
        ok = np.abs(det) > 1e-300
        det = np.where(ok, det, 1.0)
        da = np.where(ok, -(j[:, 1, 1] * f0[:, 0] - j[:, 0, 1] * f0[:, 1]) / det, 0.0)
        dc = np.where(ok, -(-j[:, 1, 0] * f0[:, 0] + j[:, 0, 0] * f0[:, 1]) / det, 0.0)
        p = p + da[:, None] * e1 + dc[:, None] * e2
    return p


def _primary_per_row(n_rows, rows, u, pts_ref, ids) -> StripeTruth:
    stripe_u = np.full(n_rows, np.nan)
    points = np.full((n_rows, 3), np.nan)
    obj = np.zeros(n_rows, dtype=np.int16)
    count = np.minimum(np.bincount(rows, minlength=n_rows), 255).astype(np.uint8)
    order = np.lexsort((u, rows))           # by row, then by u ascending
    r_sorted = rows[order]
    first = order[np.unique(r_sorted, return_index=True)[1]]   # smallest u of each row
    stripe_u[rows[first]] = u[first]
    points[rows[first]] = pts_ref[first]
    obj[rows[first]] = ids[first]
    return StripeTruth(stripe_u, points, obj, count)


# ------------------------------------------------------------------ per-pixel truth


def pixel_directions(rig: Rig) -> np.ndarray:
    """Unit chief-ray directions of every pixel centre.

    They depend on the rig only: compute once per run and pass to :func:`pixel_truth`.

    Parameters
    ----------
    rig : Rig
        The rig (camera model and sensor size).

    Returns
    -------
    (rows·columns, 3) float64
        Directions from the lens centre, rig frame [-], row-major (pixel
        (u, v) at index v·columns + u).
    """
    n_r, n_c = rig.sensor.rows, rig.sensor.columns
    uv = np.stack(np.meshgrid(np.arange(n_c, dtype=np.float64),
                              np.arange(n_r, dtype=np.float64)), axis=-1).reshape(-1, 2)
    return chief_ray_from_pixel(rig, uv, sensor_pose(rig))


def pixel_truth(rig: Rig, caster: RayCaster, ref_from_rig, directions=None,
                rows_per_batch: int = 256) -> tuple[np.ndarray, np.ndarray]:
    """Chief-ray hit of every pixel centre.

    Parameters
    ----------
    rig : Rig
        The rig.
    caster : RayCaster
        First-hit queries in the rig frame for the scene posed for this frame.
    ref_from_rig : (4, 4) float
        Rig frame → truth reference frame [mm].
    directions : (rows·columns, 3) float, optional
        :func:`pixel_directions` of ``rig`` (computed here when not given).
    rows_per_batch : int, default 256
        Sensor rows whose rays are cast in one query (bounds memory) [-].

    Returns
    -------
    point_mm : (rows, columns, 3) float32
        Hit point, reference frame [mm]; NaN = none.
    object_id : (rows, columns) uint16
        Object id of the hit part, 0 = none.

    Raises
    ------
    ValueError
        When ``directions`` is not of shape ``(rows·columns, 3)``.
    """
    n_r, n_c = rig.sensor.rows, rig.sensor.columns
    w_all = pixel_directions(rig) if directions is None else directions
    if w_all.shape != (n_r * n_c, 3):
        raise ValueError(f"directions must have shape ({n_r * n_c}, 3), got {w_all.shape}")
    point = np.empty((n_r, n_c, 3), dtype=np.float32)
    obj = np.empty((n_r, n_c), dtype=np.uint16)
    rot, shift = np.asarray(ref_from_rig)[:3, :3], np.asarray(ref_from_rig)[:3, 3]
    c = lens_centre_mm(rig)
    shift = shift + rot @ c
    for r0 in range(0, n_r, rows_per_batch):
        r1 = min(n_r, r0 + rows_per_batch)
        w = w_all[r0 * n_c:r1 * n_c]
        t, ids = caster.first_hit(np.broadcast_to(c, w.shape).copy(), w)
        hit = np.isfinite(t)
        # p_ref = R·(c + t·w) + T = t·(R·w) + (R·c + T); misses → NaN
        p = np.where(hit, t, np.nan)[:, None] * (w @ rot.T) + shift
        point[r0:r1] = p.reshape(r1 - r0, n_c, 3)
        obj[r0:r1] = np.where(hit, ids, 0).reshape(r1 - r0, n_c)
    return point, obj


# ------------------------------------------------------------------ closed-form rig truth


def opencv_camera(rig: Rig):
    """The rig's camera as OpenCV's tilted pinhole model (``CALIB_TILTED_MODEL``), exactly.

    The thin lens images every point along its (distorted) chief ray through the lens
    centre onto the tilted sensor plane: a central projection with radial distortion of
    the field angle's tangent, which is OpenCV's model with ``fx = fy``, no skew and the
    tilt (τx, τy) of :func:`scheimpflug.tilted_camera.camera_from_sensor_pose` (the
    sensor's misalignments included).

    Parameters
    ----------
    rig : Rig
        The instrument.

    Returns
    -------
    camera : scheimpflug.tilted_camera.TiltedCamera
        Focal length [px], principal point [px], τx, τy [rad], k1, k2 [-].
    camera_from_rig : (4, 4) float64
        The OpenCV camera frame (origin at the lens centre, Z along the optical axis,
        X along the columns, Y along the rows) from the rig frame [mm].
    """
    from scheimpflug.tilted_camera import TiltedCamera, camera_from_sensor_pose

    pose = sensor_pose(rig)
    c = lens_centre_mm(rig)
    if rig.sensor.image_distance_mm > 0:     # an ordinary camera: its pixel axes turned by the roll, any angle
        r = math.radians(rig.sensor.roll_deg)
        rows = np.array([[0.0, -math.cos(r), -math.sin(r)], [0.0, math.sin(r), -math.cos(r)], [1.0, 0.0, 0.0]])
        cam, rot = camera_from_sensor_pose(pose.origin_mm - c, pose.u_dir, pose.v_dir, pose.pitch_mm, rows)
    else:
        cam, rot = camera_from_sensor_pose(pose.origin_mm - c, pose.u_dir, pose.v_dir, pose.pitch_mm)
    cam = TiltedCamera(cam.focal_px, cam.principal_px, cam.tau_x_rad, cam.tau_y_rad, rig.lens.k1, rig.lens.k2)
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = rot, -rot @ c
    return cam, m


def opencv_laser_plane(rig: Rig) -> np.ndarray:
    """The rig's laser sheet in the OpenCV camera frame of :func:`opencv_camera` (what a target calibration finds).

    Parameters
    ----------
    rig : Rig
        The instrument.

    Returns
    -------
    (4,) float64
        ``[a, b, c, d]``: the sheet's unit normal and its distance term, ``a·X + b·Y + c·Z + d = 0``,
        with d < 0 (the normal points away from the camera) [-, mm].  The nominal sheet
        (:func:`scheimpflug.model.hinge.hinge_geometry`): a frame's pointing drift is not in it.
    """
    _, camera_from_rig = opencv_camera(rig)
    g = hinge_geometry(rig)
    n = camera_from_rig[:3, :3] @ g.sheet_normal
    p = camera_from_rig[:3, :3] @ g.rig_from_sheet(600.0, 0.0) + camera_from_rig[:3, 3]
    return np.array([*n, -n @ p]) if n @ p > 0 else -np.array([*n, -n @ p])


def _opencv_truth(rig: Rig) -> dict:
    cam, camera_from_rig = opencv_camera(rig)
    k, dist = cam.camera_matrix.copy(), cam.dist_coeffs.copy()
    k[1, 1] *= rig.lens.aspect_ratio          # OpenCV's terms beyond k1, k2 (model.distortion)
    dist[2], dist[3], dist[4] = rig.lens.p1, rig.lens.p2, rig.lens.k3
    return {"camera_matrix": k.tolist(), "dist_coeffs": dist.tolist(),
            "image_size": [rig.sensor.columns, rig.sensor.rows],
            "tau_deg": [math.degrees(cam.tau_x_rad), math.degrees(cam.tau_y_rad)],
            "camera_from_rig": camera_from_rig.tolist(),
            "model": "OpenCV pinhole with CALIB_TILTED_MODEL (14 terms: k1, k2, p1, p2, k3, k4, k5, k6, "
                     "s1..s4, tau_x, tau_y); camera_from_rig maps rig-frame mm to its camera frame"}


def rig_truth(rig: Rig) -> dict:
    """Closed-form constants of a rig, JSON-ready.

    Parameters
    ----------
    rig : Rig
        The rig; constants from :func:`scheimpflug.model.hinge.hinge_geometry`.

    Returns
    -------
    dict
        ``hinge_px`` [u_h, v_h] (also as ``hinge_u_px``, ``hinge_v_px``) [px],
        ``F2_px_mm`` [px·mm], ``C_mm`` [mm], ``d0_mm`` [mm],
        ``axis_mm`` [mm] and ``D_axis_mm`` = axis_mm − d0_mm [mm], ``tilt_deg`` [deg],
        ``tan_beta`` [-], and ``ideal`` (bool): True when the rig has no sensor
        misalignment (roll, tilt error, offsets), no lens distortion (k1, k2),
        no stage axis tilt or runout and no error model on
        (:func:`scheimpflug.model.rig.active_error_models`); ``opencv``: the camera
        as OpenCV's tilted model (:func:`opencv_camera`) — ``camera_matrix`` [px],
        ``dist_coeffs`` (14, τx and τy in radians), ``image_size``, ``tau_deg``,
        ``camera_from_rig`` (4 × 4, mm), misalignments and distortion included.

    Notes
    -----
    These describe the *ideal* rig: misalignments and distortion are not in them.
    """
    g = hinge_geometry(rig)
    return {"hinge_px": [g.hinge_column, g.axis_row], "hinge_u_px": g.hinge_column,
            "hinge_v_px": g.axis_row, "F2_px_mm": g.F2_px_mm, "C_mm": g.C_mm,
            "d0_mm": rig.stage.d0_mm, "axis_mm": rig.stage.axis_mm,
            "D_axis_mm": axis_distance_mm(rig), "tilt_deg": g.tilt_deg,
            "tan_beta": g.tan_beta,
            "ideal": all(getattr(rig.sensor, k) == 0 for k in
                         ("roll_deg", "tilt_error_deg", "offset_u_px", "offset_v_px",
                          "offset_normal_um", "image_distance_mm")) and rig.lens.k1 == 0 and rig.lens.k2 == 0
            and is_radial(rig.lens)
            and rig.stage.axis_tilt_deg == 0 and rig.stage.runout_um == 0 and rig.stage.axis_offset_mm == 0
            and not active_error_models(rig), "opencv": _opencv_truth(rig)}


# ------------------------------------------------------------------ casters


class SceneCaster:
    """:class:`RayCaster` over a :class:`sim.scene.SimScene` (Mitsuba BVH, float32 geometry).

    The scene must already be posed for the frame (``SimScene.set_pose``).

    Parameters
    ----------
    scene : SimScene
        The posed scene (a JIT variant: :meth:`SimScene.intersect`).
    batch : int, default 1 << 20
        Rays per Mitsuba query (bounds memory) [-].
    """

    def __init__(self, scene, batch: int = 1 << 20) -> None:
        self.scene = scene
        self.batch = batch

    def first_hit(self, origins_mm, directions) -> tuple[np.ndarray, np.ndarray]:
        """First surface met by each ray.

        Parameters
        ----------
        origins_mm : (n, 3) array_like
            Ray origins, rig frame [mm].
        directions : (n, 3) array_like
            Ray directions, rig frame [-] (normalised by the scene).

        Returns
        -------
        t_mm : (n,) float64
            Distance to the first hit [mm]; ``inf`` where nothing is hit.
        object_id : (n,) int64
            Object id of the hit part (0 = none).

        Raises
        ------
        RenderError
            When the scene's variant is not a JIT variant.
        """
        o = np.asarray(origins_mm, dtype=np.float64)
        d = np.asarray(directions, dtype=np.float64)
        t = np.full(len(o), np.inf)
        ids = np.zeros(len(o), dtype=np.int64)
        for i in range(0, len(o), self.batch):
            t[i:i + self.batch], ids[i:i + self.batch] = self.scene.first_hit(o[i:i + self.batch],
                                                                              d[i:i + self.batch])
        return t, ids



class BruteForceCaster:
    """First-hit queries against every triangle (Möller–Trumbore, float64, numpy).

    Exact and dependency-free but O(rays × triangles): for small test scenes
    and for cross-checking :class:`sim.scene.SimScene`.

    Parameters
    ----------
    vertices_mm : (n, 3) float
        Mesh vertices, rig frame (the frame of the rays) [mm].
    faces : (m, 3) int
        Vertex indices of the triangles.
    face_ids : (m,) int
        Object id per face.
    chunk : int, default 2_000_000
        Ray × triangle pairs tested at once (bounds memory) [-].
    """

    def __init__(self, vertices_mm, faces, face_ids, chunk: int = 2_000_000) -> None:
        v = np.asarray(vertices_mm, dtype=np.float64)
        f = np.asarray(faces, dtype=np.int64)
        self.a, self.e1, self.e2 = v[f[:, 0]], v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]
        self.ids = np.asarray(face_ids)
        self.chunk = chunk

    def first_hit(self, origins_mm, directions) -> tuple[np.ndarray, np.ndarray]:
        """First triangle met by each ray (Möller–Trumbore, float64).

        Parameters
        ----------
        origins_mm : (n, 3) array_like
            Ray origins, rig frame [mm].
        directions : (n, 3) array_like
            Unit ray directions, rig frame [-] (t is in units of their length).

        Returns
        -------
        t_mm : (n,) float64
            Distance to the first hit, hits at t ≤ 1e-9 ignored [mm]; ``inf``
            where nothing is hit.
        object_id : (n,) int64
            Object id of the hit face (0 = none).
        """
        o = np.asarray(origins_mm, dtype=np.float64)
        d = np.asarray(directions, dtype=np.float64)
        t_best = np.full(len(o), np.inf)
        id_best = np.zeros(len(o), dtype=np.int64)
        step = max(1, self.chunk // max(1, len(self.a)))
        for i in range(0, len(o), step):
            t, k = self._hits(o[i:i + step], d[i:i + step])
            t_best[i:i + step], id_best[i:i + step] = t, np.where(np.isfinite(t), self.ids[k], 0)
        return t_best, id_best

    def _hits(self, o, d):
        p = np.cross(d[:, None, :], self.e2[None])                       # (r, m, 3)
        det = np.einsum("mk,rmk->rm", self.e1, p)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / det
            s = o[:, None, :] - self.a[None]
            bu = np.einsum("rmk,rmk->rm", s, p) * inv
            q = np.cross(s, self.e1[None])
            bv = np.einsum("rk,rmk->rm", d, q) * inv
            t = np.einsum("mk,rmk->rm", self.e2, q) * inv
            ok = (np.abs(det) > 1e-300) & (bu >= 0) & (bv >= 0) & (bu + bv <= 1) & (t > 1e-9)
        t = np.where(ok, t, np.inf)
        k = np.argmin(t, axis=1)
        return t[np.arange(len(o)), k], k


# ------------------------------------------------------------------ secondary light

#: Number of secondary-light peaks kept per row.
SECONDARY_PEAKS = 4


def secondary_truth(rows: int, laser=None, secondary=None, subsurface=None,
                    min_share: float = 0.02, half_window_px: int = 3) -> dict:
    """Where the frame's secondary light lands, per row (truth-file arrays).

    Parameters
    ----------
    rows : int
        Sensor rows.
    laser : (rows, columns) float, optional
        All expected laser electrons (no speckle, no noise) [e⁻]; None: no split exists
        (the ideal twin) and the arrays say "none".
    secondary : (rows, columns) float, optional
        The inter-reflected part of ``laser`` [e⁻].
    subsurface : (rows, columns) float, optional
        The first surface's subsurface part of ``laser`` [e⁻].
    min_share : float
        A peak must hold at least this share of the row's laser light [-].
    half_window_px : int
        A peak's light is summed over ±this many columns [px].

    Returns
    -------
    dict
        ``secondary_u`` (rows, 4) float32 [px], ``secondary_share`` (rows, 4) float32 [-],
        ``secondary_fraction`` (rows,) float32 [-], ``subsurface_fraction`` (rows,)
        float32 [-] (module docstring).
    """
    k = SECONDARY_PEAKS
    out = {"secondary_u": np.full((rows, k), np.nan, np.float32),
           "secondary_share": np.zeros((rows, k), np.float32),
           "secondary_fraction": np.zeros(rows, np.float32),
           "subsurface_fraction": np.zeros(rows, np.float32)}
    if laser is None:
        return out
    total = np.asarray(laser, np.float64).sum(axis=1)
    safe = np.where(total > 0, total, 1.0)
    if subsurface is not None:
        out["subsurface_fraction"][:] = np.asarray(subsurface, np.float64).sum(axis=1) / safe
    if secondary is None:
        return out
    sec = np.asarray(secondary, np.float64)
    out["secondary_fraction"][:] = sec.sum(axis=1) / safe
    _row_peaks(sec, total, float(min_share), int(half_window_px), out["secondary_u"],
               out["secondary_share"])
    return out


@numba.njit(cache=True, nogil=True, parallel=True)
def _row_peaks(sec, total, min_share, w, peak_u, peak_share):  # pragma: no cover - compiled
    """Strongest local maxima (±w) of each row of ``sec`` holding ≥ min_share of the row.

    Rows in parallel (each writes only its own row).
    """
    rows, cols = sec.shape
    k = peak_u.shape[1]
    for r in numba.prange(rows):
        if total[r] <= 0.0:
            continue
        cs = np.zeros(cols + 1)
        for c in range(cols):
            cs[c + 1] = cs[c] + sec[r, c]
        found = 0
        used = np.zeros(cols, np.bool_)
        while found < k:
            best, arg = 0.0, -1
            for c in range(cols):
                if not used[c]:
                    lo, hi = max(0, c - w), min(cols, c + w + 1)
                    if sec[r, c] > best and sec[r, c] >= sec[r, lo:hi].max():
                        best, arg = sec[r, c], c
            if arg < 0 or (2 * w + 1) * best < min_share * total[r]:
                break                       # no remaining peak can hold min_share of the row
            lo, hi = max(0, arg - w), min(cols, arg + w + 1)
            share = (cs[hi] - cs[lo]) / total[r]
            for c in range(max(0, arg - 2 * w), min(cols, arg + 2 * w + 1)):
                used[c] = True
            if share < min_share:
                continue
            wsum = 0.0
            usum = 0.0
            for c in range(lo, hi):
                wsum += sec[r, c]
                usum += sec[r, c] * c
            peak_u[r, found] = usum / wsum
            peak_share[r, found] = share
            found += 1


# ------------------------------------------------------------------ many frames of one scene


@numba.njit(cache=True, nogil=True)
def _section_faces(vertices, faces, candidates, point, normal):  # pragma: no cover - compiled
    """Sheet section of the ``candidates`` faces: (segments (k, 2, 3), their face indices (k,)).

    Same rule as :func:`sheet_section` (d ≥ 0 is above; crossings interpolated from the
    lower-indexed vertex; the two crossing edges taken in the order 01, 12, 20), with
    d = v·n − p·n evaluated component by component in a fixed order.
    """
    c = point[0] * normal[0] + point[1] * normal[1] + point[2] * normal[2]
    m = candidates.shape[0]
    seg = np.empty((m, 2, 3))
    face_of = np.empty(m, dtype=np.int64)
    dist = np.empty(3)
    k = 0
    for i in range(m):
        f = candidates[i]
        n_above = 0
        for j in range(3):
            v = faces[f, j]
            dist[j] = vertices[v, 0] * normal[0] + vertices[v, 1] * normal[1] \
                + vertices[v, 2] * normal[2] - c
            if dist[j] >= 0.0:
                n_above += 1
        if n_above == 0 or n_above == 3:
            continue
        q = 0
        for e in range(3):
            i0, i1 = e, (e + 1) % 3
            if (dist[i0] >= 0.0) == (dist[i1] >= 0.0):
                continue
            a, b = faces[f, i0], faces[f, i1]
            da, db = dist[i0], dist[i1]
            if b < a:
                a, b, da, db = b, a, db, da
            t = da / (da - db)
            for x in range(3):
                seg[k, q, x] = vertices[a, x] + t * (vertices[b, x] - vertices[a, x])
            q += 1
        face_of[k] = f
        k += 1
    return seg[:k], face_of[:k]


@dataclasses.dataclass(frozen=True)
class TruthSection:
    """A frame's candidate stripe points before the visibility test (:meth:`SceneTruth.section`).

    Parameters
    ----------
    rows : (k,) int
        Sensor row of each crossing.
    u_px : (k,) float
        Its column [px].
    points_mm : (k, 3) float
        Its point on the surface, rig frame [mm].
    faces : (k,) int
        The face it lies on.
    rig_from_part : (4, 4) float
        The frame's pose of the scene.
    ref_from_rig : (4, 4) float
        Rig frame → truth reference frame.
    lens_mm : (3,) float
        The lens centre the visibility is tested from, rig frame [mm].
    laser_mm : (3,) float
        The laser origin the lighting is tested from, rig frame [mm].
    """

    rows: np.ndarray
    u_px: np.ndarray
    points_mm: np.ndarray
    faces: np.ndarray
    rig_from_part: np.ndarray
    ref_from_rig: np.ndarray
    lens_mm: np.ndarray
    laser_mm: np.ndarray


class SceneTruth:
    """The per-row stripe truth of many frames of one scene, with per-scene data computed once.

    Equivalent to :func:`stripe_truth` frame by frame (same rules, same tolerances; the
    section's signed distances are evaluated in a fixed order, so results agree with it
    to rounding), but faster on big meshes: the faces are sorted once along a Morton
    curve into blocks of ``faces_per_cell`` with their bounding boxes, and each frame
    cuts only the faces of the blocks the sheet crosses; the two visibility casts go in
    one ray query.  Besides the truth of
    :func:`stripe_truth` it gives, per row, the distance D of the stripe point along the
    sheet from the object hinge and the laser's angle of incidence on the face it lies on.

    Parameters
    ----------
    rig : Rig
        The instrument.
    vertices_part_mm : (n, 3) float
        Scene mesh vertices in the part frame [mm].
    faces : (m, 3) int
        Triangles.
    face_ids : (m,) int
        Object id per face.
    faces_per_cell : int
        Faces per block [-].
    tol : TruthTolerances
        Numerical tolerances.
    """

    def __init__(self, rig: Rig, vertices_part_mm, faces, face_ids, faces_per_cell: int = 64,
                 tol: TruthTolerances = TruthTolerances()) -> None:
        self.rig, self.tol = rig, tol
        self.geometry = hinge_geometry(rig)
        self.pose = sensor_pose(rig)
        self.along = stripe_along(rig)
        self._ax, self.lines = _line_axis(rig, self.along)
        self.vertices = np.ascontiguousarray(vertices_part_mm, dtype=np.float64)
        self.faces = np.ascontiguousarray(faces, dtype=np.int64)
        self.face_ids = np.asarray(face_ids)
        tri = self.vertices[self.faces]                                  # (m, 3, 3)
        normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        length = np.linalg.norm(normals, axis=1)
        self.normals = normals / np.where(length > 0, length, 1.0)[:, None]
        self._build_cells(tri, faces_per_cell)

    def _build_cells(self, tri: np.ndarray, faces_per_cell: int) -> None:
        """Faces in Morton order of their centroids, in blocks of ``faces_per_cell`` with AABBs."""
        m = len(self.faces)
        lo, hi = self.vertices.min(axis=0), self.vertices.max(axis=0)
        q = ((tri.mean(axis=1) - lo) / np.maximum(hi - lo, 1e-9) * 1023).astype(np.uint64)
        key = np.zeros(m, dtype=np.uint64)
        for bit in range(10):
            for axis in range(3):
                key |= ((q[:, axis] >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit + axis)
        self._order = np.argsort(key, kind="stable")
        self._starts = np.arange(0, m, max(1, faces_per_cell))
        self._counts = np.diff(np.r_[self._starts, m])
        sorted_tri = tri[self._order]
        self._cell_lo = np.minimum.reduceat(sorted_tri.min(axis=1), self._starts, axis=0)
        self._cell_hi = np.maximum.reduceat(sorted_tri.max(axis=1), self._starts, axis=0)
        self._eps = 1e-9 * (1.0 + float(np.abs(self.vertices).max(initial=0.0)))

    def candidate_faces(self, plane_point_mm, plane_normal) -> np.ndarray:
        """Indices of the faces in blocks whose bounding box the plane meets (Morton order).

        Parameters
        ----------
        plane_point_mm : (3,) float
            A point of the plane, part frame [mm].
        plane_normal : (3,) float
            Its unit normal.

        Returns
        -------
        (k,) int64
            A superset of the faces the plane cuts.
        """
        return self.candidate_faces_near(plane_point_mm, plane_normal, 0.0)

    def frame(self, rig_from_part, ref_from_part, caster: RayCaster,
              rig_from_laser=None) -> tuple[StripeTruth, dict]:
        """Per-row truth of the frame with the scene posed by ``rig_from_part``.

        Parameters
        ----------
        rig_from_part : (4, 4) float
            Pose of the scene in the rig frame.
        ref_from_part : (4, 4) float
            Part frame → truth reference frame.
        caster : RayCaster
            First-hit queries for the scene posed by ``rig_from_part``.
        rig_from_laser : (4, 4) float, optional
            This frame's pose of the laser sheet (pointing drift) [mm]; None = nominal.
            With it, a bowed sheet or a moved lens (error models) the cut is the
            sheet actually rendered, as in :func:`stripe_truth`.

        Returns
        -------
        truth : StripeTruth
            As :func:`stripe_truth`.
        extra : dict
            ``stripe_distance_mm`` (rows,) float64: D of the stripe point along the sheet
            from the object hinge [mm], NaN = none; ``stripe_incidence_deg`` (rows,) float64:
            angle between the laser ray and the normal of the face the point lies on
            [deg], NaN = none.
        """
        return self.finish(self.section(rig_from_part, ref_from_part, rig_from_laser), caster)

    def section(self, rig_from_part, ref_from_part, rig_from_laser=None) -> TruthSection:
        """The half of :meth:`frame` that needs no scene query: the sheet's cut through the mesh.

        Numpy on the per-scene data (read only), so it may run on another thread while
        the scene is posed and rendered (the pipelined frame loop).

        Parameters
        ----------
        rig_from_part : (4, 4) float
            Pose of the scene in the rig frame.
        ref_from_part : (4, 4) float
            Part frame → truth reference frame.
        rig_from_laser : (4, 4) float, optional
            This frame's pose of the laser sheet, as in :meth:`frame` [mm].

        Returns
        -------
        TruthSection
            The candidate stripe points of each row, before the visibility test.
        """
        rig, g, tol = self.rig, self.geometry, self.tol
        part_from_rig = invert(rig_from_part)
        if rig_from_laser is not None or rig.laser.line_bow_mrad != 0.0 or lens_centre_mm(rig)[0] != 0.0:
            return self._section_erring(rig_from_part, ref_from_part, rig_from_laser)
        point = transform_points(part_from_rig, g.object_hinge_mm)
        normal = part_from_rig[:3, :3] @ g.sheet_normal
        normal = normal / np.linalg.norm(normal)
        seg, face_of = _section_faces(self.vertices, self.faces,
                                      self.candidate_faces(point, normal), point, normal)
        seg = transform_points(rig_from_part, seg)
        front = (seg[:, :, 0] > rig.lens.focal_length_mm).all(axis=1)
        seg, face_of = seg[front], face_of[front]
        rows, u, pts, idx = row_crossings(rig, seg, tol, self.pose, self.along)
        faces = face_of[idx]
        keep = _across_on_sensor(rig, self.along, u) & _in_fan(rig, pts)
        return TruthSection(rows[keep], u[keep], pts[keep], faces[keep], rig_from_part,
                            ref_from_part @ part_from_rig, np.zeros(3), laser_origin_mm(rig))

    def finish(self, section: TruthSection, caster: RayCaster) -> tuple[StripeTruth, dict]:
        """:meth:`frame` from its section: the visibility test on the posed scene, one point per row.

        Parameters
        ----------
        section : TruthSection
            The frame's section (:meth:`section`).
        caster : RayCaster
            First-hit queries for the scene posed as the section's ``rig_from_part``.

        Returns
        -------
        truth : StripeTruth
            As :meth:`frame`.
        extra : dict
            As :meth:`frame`.
        """
        sec = section
        keep = self._visible_and_lit(caster, sec.points_mm, sec.lens_mm, sec.laser_mm)
        rows, u, pts, faces = sec.rows[keep], sec.u_px[keep], sec.points_mm[keep], sec.faces[keep]
        truth, first = _primary_rows(self.lines, rows, u, transform_points(sec.ref_from_rig, pts),
                                     self.face_ids[faces] if len(faces) else np.zeros(0, np.int64))
        return truth, self._extras(rows[first], pts[first], faces[first], sec.rig_from_part, sec.laser_mm)

    def _section_erring(self, rig_from_part, ref_from_part, rig_from_laser) -> TruthSection:
        """:meth:`section` for a turned or bowed sheet or a moved lens (the rules of :func:`stripe_truth`)."""
        rig, tol = self.rig, self.tol
        part_from_rig = invert(rig_from_part)
        sheet = posed_sheet(light_sheet(rig), rig_from_laser)
        rot = part_from_rig[:3, :3]
        local = dataclasses.replace(sheet, origin_mm=transform_points(part_from_rig, sheet.origin_mm),
                                    prop_dir=rot @ sheet.prop_dir, normal=rot @ sheet.normal, up=rot @ sheet.up)
        reach = np.linalg.norm(self.vertices - local.origin_mm, axis=1).max(initial=0.0)
        bound = 1.5 * reach * abs(sheet.bow_rad)       # the bowed surface's largest offset in the fan
        cand = self.candidate_faces_near(local.origin_mm, local.normal, bound)
        used, sub = np.unique(self.faces[cand], return_inverse=True)
        d = sheet_offset_mm(local, self.vertices[used])
        seg, _, which = surface_section(self.vertices[used], sub.reshape(-1, 3), self.face_ids[cand], d,
                                        return_faces=True)
        face_of = cand[which]
        seg = transform_points(rig_from_part, seg)
        c = lens_centre_mm(rig)
        front = (seg[:, :, 0] > lens_state(rig).focal_length_mm + c[0]).all(axis=1)
        seg, face_of = seg[front], face_of[front]
        rows, u, pts, idx = row_crossings(rig, seg, tol, self.pose, self.along)
        faces = face_of[idx]
        if sheet.bow_rad != 0.0 and len(idx):
            pts = _onto_bowed_section(rig, sheet, pts, rows.astype(np.float64),
                                      self.normals[faces] @ rig_from_part[:3, :3].T, tol, ax=self._ax)
            u = project_points(rig, pts, self.pose).uv_px[:, 1 - self._ax]
        keep = _across_on_sensor(rig, self.along, u) & _in_fan(rig, pts, sheet)
        return TruthSection(rows[keep], u[keep], pts[keep], faces[keep], rig_from_part,
                            ref_from_part @ part_from_rig, c, np.asarray(sheet.origin_mm, np.float64))

    def candidate_faces_near(self, plane_point_mm, plane_normal, margin_mm: float) -> np.ndarray:
        """Faces in blocks whose bounding box comes within ``margin_mm`` of a plane.

        Parameters
        ----------
        plane_point_mm : (3,) float
            A point of the plane, part frame [mm].
        plane_normal : (3,) float
            Its unit normal.
        margin_mm : float
            Extra distance (≥ 0) a block may lie off the plane [mm].

        Returns
        -------
        (k,) int64
            A superset of the faces a surface within ``margin_mm`` of the plane cuts.
        """
        n = np.asarray(plane_normal, dtype=np.float64)
        centre = 0.5 * (self._cell_lo + self._cell_hi)
        radius = 0.5 * (self._cell_hi - self._cell_lo) @ np.abs(n)
        d = centre @ n - np.asarray(plane_point_mm, dtype=np.float64) @ n
        hit = np.flatnonzero(np.abs(d) <= radius + self._eps + margin_mm)
        if len(hit) == 0:
            return np.zeros(0, dtype=np.int64)
        counts = self._counts[hit]
        offsets = np.repeat(self._starts[hit] - np.cumsum(counts) + counts, counts)
        return self._order[offsets + np.arange(counts.sum())]

    def _visible_and_lit(self, caster: RayCaster, pts: np.ndarray, lens_mm=None,
                         laser_mm=None) -> np.ndarray:
        """(n,) bool: seen from the lens centre and lit by the laser (one ray query)."""
        n = len(pts)
        if n == 0:
            return np.zeros(0, dtype=bool)
        lens = np.zeros(3) if lens_mm is None else lens_mm
        laser = laser_origin_mm(self.rig) if laser_mm is None else laser_mm
        origins = np.concatenate([np.broadcast_to(lens, (n, 3)), np.broadcast_to(laser, (n, 3))])
        delta = np.concatenate([pts, pts]) - origins
        dist = np.linalg.norm(delta, axis=1)
        hit_t, _ = caster.first_hit(origins, delta / dist[:, None])
        ok = hit_t >= dist - self.tol.visibility_mm
        return ok[:n] & ok[n:]

    def _extras(self, rows, pts, faces, rig_from_part, laser_mm=None) -> dict:
        n_rows = self.lines
        distance = np.full(n_rows, np.nan)
        incidence = np.full(n_rows, np.nan)
        if len(rows):
            distance[rows] = (pts - self.geometry.object_hinge_mm) @ self.geometry.propagation_dir
            normal = self.normals[faces] @ np.asarray(rig_from_part)[:3, :3].T
            ray = pts - (laser_origin_mm(self.rig) if laser_mm is None else laser_mm)
            ray /= np.linalg.norm(ray, axis=1)[:, None]
            cos = np.clip(np.abs(np.sum(normal * ray, axis=1)), 0.0, 1.0)
            incidence[rows] = np.degrees(np.arccos(cos))
        return {"stripe_distance_mm": distance, "stripe_incidence_deg": incidence}


def _primary_rows(n_rows, rows, u, pts_ref, ids) -> tuple[StripeTruth, np.ndarray]:
    """:func:`_primary_per_row` that also returns which crossings were kept (one per row)."""
    stripe_u = np.full(n_rows, np.nan)
    points = np.full((n_rows, 3), np.nan)
    obj = np.zeros(n_rows, dtype=np.int16)
    count = np.minimum(np.bincount(rows, minlength=n_rows), 255).astype(np.uint8)
    order = np.lexsort((u, rows))
    first = order[np.unique(rows[order], return_index=True)[1]]
    stripe_u[rows[first]] = u[first]
    points[rows[first]] = pts_ref[first]
    obj[rows[first]] = ids[first]
    return StripeTruth(stripe_u, points, obj, count), first
