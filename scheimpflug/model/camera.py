"""Thin-lens camera with a tilted (and possibly misaligned) sensor: exact, vectorised.

This is the single source of truth for where the sensor sits and how any 3-D
point images onto it.  The renderer, the ground truth and the design tool all
use it.

Model
-----
* Ideal thin lens at the rig origin, lens plane x = 0, focal length f,
  aperture a disc of diameter f/N in the lens plane.
* A rig point P (x > 0) has the conjugate P' = −f/(x − f)·P (Gaussian lens
  equation; Newton's x·x' = −f² with x, x' from the focal planes, paper Eq. 1).
* Distortion acts on the chief ray: the image point keeps its axial
  position x' but its lateral offset is scaled by 1 + k1·t² + k2·t⁴ with
  t = tan θ = √(y² + z²)/x the object-side field angle; with k3, p1, p2 or an
  aspect ratio ≠ 1, OpenCV's model moves it (:mod:`scheimpflug.model.distortion`).
* The sensor is tilted by the hinge rule (``[sensor] image_distance_mm`` = 0) or,
  for an ordinary camera, perpendicular to the optical axis at the image
  distance b: then pixel (u, v) of a point is OpenCV's pinhole projection with
  fx = b / p, fy = fx·aspect_ratio and the principal point given by the offsets.
* The sensor is a plane (:class:`SensorPose`); the *image* of P on it is where
  the (distorted) chief ray through the lens centre meets the sensor.  The blur
  is the section of the cone from the aperture to P' by the sensor.
* A real lens (:func:`lens_state`): focal length f + Δf
  (``lens.focal_length_error_mm``), focused like a user focuses it — moved
  along its axis to c = (δ, 0, 0) until the sheet point imaged at the sensor
  centre is sharp — then left off by ``lens.focus_error_um``.  The sensor stays
  at its design pose.  Every formula above then holds relative to c (P − c,
  conjugate c + m·(P − c), chief rays from c).  The ideal lens has c = 0.

Sensor frame: pixel (u, v) sits at ``origin + u·p·e_u + v·p·e_v``; columns u
run along the tilt (toward the image hinge), rows v increase downward in the
upright image (+z' on the sensor, the image being inverted).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from scheimpflug.model._checks import check_last_dim
from scheimpflug.model.distortion import distort_tangents, is_radial, tangents_jacobian, undistort_tangents
from scheimpflug.model.hinge import hinge_geometry
from scheimpflug.model.rig import Rig

__all__ = [
    "LensState",
    "Projection",
    "SensorPose",
    "blur_footprint_px",
    "chief_ray_from_pixel",
    "conjugate_point",
    "lens_centre_mm",
    "lens_state",
    "pixel_from_sensor_point",
    "project_points",
    "sensor_point_from_pixel",
    "sensor_pose",
    "sheet_jacobian",
    "sheet_point_from_pixel",
    "stripe_along",
]


@dataclass(frozen=True)
class SensorPose:
    """Pose of the sensor plane in the rig frame.

    Build it with :func:`sensor_pose`.  Pixel (u, v) sits at
    ``origin_mm + u·pitch_mm·u_dir + v·pitch_mm·v_dir``.

    Parameters
    ----------
    origin_mm : (3,) ndarray float
        Rig-frame position of the centre of pixel (0, 0) [mm].
    u_dir, v_dir : (3,) ndarray float
        Rig-frame unit vectors of increasing column and row [-].
    pitch_mm : float
        Pixel pitch [mm].
    columns, rows : int
        Sensor size [px].
    """

    origin_mm: np.ndarray
    u_dir: np.ndarray
    v_dir: np.ndarray
    pitch_mm: float
    columns: int
    rows: int

    @property
    def normal(self) -> np.ndarray:
        """Unit normal e_u × e_v in the rig frame, (3,) float [-].

        It points toward the lens for the Scheimpflug pose.
        """
        n = np.cross(self.u_dir, self.v_dir)
        return n / np.linalg.norm(n)

    @property
    def rig_from_sensor(self) -> np.ndarray:
        """Homogeneous (4, 4) float transform from sensor coordinates to the rig frame [mm].

        Sensor coordinates (a, b, c): a = u·p, b = v·p, c along :attr:`normal`.
        """
        m = np.eye(4)
        m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = self.u_dir, self.v_dir, self.normal, self.origin_mm
        return m


def _rotation(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    """Rodrigues rotation matrix about the unit ``axis``, (3, 3)."""
    k = axis / np.linalg.norm(axis)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle_rad) * kx + (1 - math.cos(angle_rad)) * kx @ kx


def sensor_pose(rig: Rig) -> SensorPose:
    """The sensor pose of a rig: the Scheimpflug pose plus the rig's misalignments.

    Parameters
    ----------
    rig : Rig
        The instrument (its ``[sensor]`` table gives size, pitch, hinge pixel
        and misalignments).

    Returns
    -------
    SensorPose
        The sensor plane in the rig frame.

    Notes
    -----
    Ideal pose: pixel (u_h, v_h) at the image hinge H' = (−f, f·tan φ, 0),
    e_u = (sin β, cos β, 0) (parallel to O→H, paper Eq. 6), e_v = +z.  An
    ordinary camera's (``image_distance_mm`` b > 0): the centre pixel at
    (−b, 0, 0), e_u = +y, e_v = +z; its roll, offsets (the principal point)
    and tilt error then act alike.
    Roll (about the normal) and tilt error (about the row direction, i.e. a
    change of β) turn the sensor about its centre pixel; then the offsets
    (u, v in pixels, normal in µm) translate it.
    """
    s = rig.sensor
    if s.image_distance_mm > 0:
        p, e_u, e_v = s.pixel_pitch_um * 1e-3, np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0])
        axis = np.array([-s.image_distance_mm, 0.0, 0.0])
        origin = axis - 0.5 * (s.columns - 1) * p * e_u - 0.5 * (s.rows - 1) * p * e_v
    else:
        g = hinge_geometry(rig)
        p = g.pixel_pitch_mm
        e_u, e_v = g.sensor_u_dir, np.array([0.0, 0.0, 1.0])
        origin = g.image_hinge_mm - s.hinge_column * p * e_u - s.axis_row * p * e_v
    centre = origin + 0.5 * (s.columns - 1) * p * e_u + 0.5 * (s.rows - 1) * p * e_v
    normal = np.cross(e_u, e_v)
    rot = _rotation(e_v, math.radians(s.tilt_error_deg)) @ _rotation(normal, math.radians(s.roll_deg))
    e_u2, e_v2 = rot @ e_u, rot @ e_v
    n2 = np.cross(e_u2, e_v2)
    shift = s.offset_u_px * p * e_u2 + s.offset_v_px * p * e_v2 + s.offset_normal_um * 1e-3 * n2
    origin2 = centre + rot @ (origin - centre) + shift
    return SensorPose(origin2, e_u2, e_v2, p, s.columns, s.rows)


# ------------------------------------------------------------------ lens model


@dataclass(frozen=True)
class LensState:
    """The real lens of a rig: its focal length and where focusing put it.

    Build it with :func:`lens_state`.

    Parameters
    ----------
    focal_length_mm : float
        Real focal length f + Δf [mm].
    centre_x_mm : float
        Axial position δ of the lens centre in the rig frame [mm] (0 for the
        ideal lens; the rig frame stays the design's).
    focus_shift_mm : float
        The part of δ that focusing the real lens took [mm]
        (``centre_x_mm`` minus the focus error).
    """

    focal_length_mm: float
    centre_x_mm: float
    focus_shift_mm: float


def _distorted_lateral(rig: Rig, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
    """x·D(y/x, z/x): the lateral offsets (…, 2) at depth x of the distorted chief ray (general model)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        a = np.stack([y / x, z / x], axis=-1)
    return x[..., None] * distort_tangents(rig.lens, rig.sensor.roll_deg, a)


def _conjugate(p: np.ndarray, f: float, cx: float, rig: Rig) -> np.ndarray:
    """Conjugate c + m·(P − c) about the lens centre c = (cx, 0, 0), lateral part distorted."""
    k1, k2 = rig.lens.k1, rig.lens.k2
    x = p[..., 0] - cx
    with np.errstate(divide="ignore", invalid="ignore"):
        m = np.where(x != f, -f / (x - f), np.nan)
        t2 = (p[..., 1] ** 2 + p[..., 2] ** 2) / (x * x)
    if not is_radial(rig.lens):
        lat = _distorted_lateral(rig, x, p[..., 1], p[..., 2])
        img = m[..., None] * np.stack([x, lat[..., 0], lat[..., 1]], axis=-1)
        img[..., 0] += cx
        return img
    img = m[..., None] * np.stack([x, p[..., 1], p[..., 2]], axis=-1)
    s = _distortion_scale(t2, k1, k2)
    img[..., 1] *= s
    img[..., 2] *= s
    img[..., 0] += cx
    return img


@functools.lru_cache(maxsize=64)
def lens_state(rig: Rig) -> LensState:
    """Focal length and position of a rig's real lens (module docstring).

    Parameters
    ----------
    rig : Rig
        The instrument (``lens.focal_length_error_mm``, ``lens.focus_error_um``).

    Returns
    -------
    LensState
        f' = f + Δf; δ solves (c + m·(P_c − c) − O)·n = 0 for the design's sheet
        point P_c of the sensor centre (secant method to 1e-12 mm), plus the
        focus error; δ = 0 and f' = f exactly for an ideal lens.
    """
    lens = rig.lens
    f = lens.focal_length_mm + lens.focal_length_error_mm
    err = lens.focus_error_um * 1e-3
    if lens.focal_length_error_mm == 0.0:
        return LensState(f, err, 0.0)
    pose = sensor_pose(rig)
    centre = np.array([0.5 * (pose.columns - 1), 0.5 * (pose.rows - 1)])
    w = _chief_dir_from_sensor(rig, sensor_point_from_pixel(pose, centre), 0.0)
    d, t = rig.laser.scheimpflug_distance_mm, rig.laser.tan_phi
    pc = d / (w[1] + w[0] * t) * w

    def g(cx: float) -> float:
        return float((_conjugate(pc, f, cx, rig) - pose.origin_mm) @ pose.normal)

    a, b = 0.0, lens.focal_length_error_mm
    ga, gb = g(a), g(b)
    for _ in range(60):
        if gb == ga or abs(b - a) < 1e-12:
            break
        a, b, ga = b, b - gb * (b - a) / (gb - ga), gb
        gb = g(b)
    return LensState(f, b + err, b)


def lens_centre_mm(rig: Rig) -> np.ndarray:
    """Where the real lens's centre is, in the rig frame.

    Parameters
    ----------
    rig : Rig
        The instrument.

    Returns
    -------
    (3,) float64
        c = (δ, 0, 0) [mm] (:func:`lens_state`); the origin for an ideal lens.
    """
    return np.array([lens_state(rig).centre_x_mm, 0.0, 0.0])


def _distortion_scale(t2, k1: float, k2: float):
    return 1.0 + k1 * t2 + k2 * t2 * t2


def _undistort_tan(td2, k1: float, k2: float, iters: int = 20):
    """Solve t·s(t²) = t_d for t² given t_d² (Newton on r = t·s(t²)), vectorised."""
    if k1 == 0.0 and k2 == 0.0:
        return np.ones_like(td2)
    td = np.sqrt(td2)
    t = td.copy()
    for _ in range(iters):
        f = t * _distortion_scale(t * t, k1, k2) - td
        df = 1.0 + 3.0 * k1 * t * t + 5.0 * k2 * t**4
        t = t - f / df
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(td > 0, t / np.where(td > 0, td, 1.0), 1.0)  # ratio t / t_d


def conjugate_point(rig: Rig, points_mm) -> np.ndarray:
    """Image-side conjugate P' of rig points, distortion included.

    Parameters
    ----------
    rig : Rig
        The instrument (focal length and distortion k1, k2 of its lens).
    points_mm : (..., 3) array_like float
        Object points P in the rig frame [mm].

    Returns
    -------
    (..., 3) ndarray float64
        P' = −f/(x − f)·P in the rig frame [mm], its lateral part (y, z)
        scaled by the distortion factor 1 + k1·t² + k2·t⁴ (t = tan θ).
        Points at x = f (the front focal plane) have no finite image: NaN.
        For a real lens (:func:`lens_state`) f is f + Δf and x, P are taken
        relative to its centre c.

    Raises
    ------
    ValueError
        If ``points_mm`` is not of shape ``(..., 3)``.

    Notes
    -----
    The Gaussian lens equation; Newton's x·x' = −f² with x, x' measured from
    the focal planes (paper Eq. 1).
    """
    p = check_last_dim("points_mm", points_mm, 3)
    ls = lens_state(rig)
    if ls.centre_x_mm != 0.0 or ls.focal_length_mm != rig.lens.focal_length_mm or not is_radial(rig.lens):
        return _conjugate(p, ls.focal_length_mm, ls.centre_x_mm, rig)
    f = rig.lens.focal_length_mm
    x = p[..., 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        m = np.where(x != f, -f / (x - f), np.nan)
        t2 = (p[..., 1] ** 2 + p[..., 2] ** 2) / (x * x)
    img = m[..., None] * p
    s = _distortion_scale(t2, rig.lens.k1, rig.lens.k2)
    img[..., 1] *= s
    img[..., 2] *= s
    return img


def _chief_dir_image(rig: Rig, points_mm: np.ndarray) -> np.ndarray:
    """Direction of the (distorted) chief ray behind the lens for object points, (…, 3)."""
    p = np.asarray(points_mm, dtype=np.float64)
    x = p[..., 0] - lens_state(rig).centre_x_mm
    if not is_radial(rig.lens):
        lat = _distorted_lateral(rig, x, p[..., 1], p[..., 2])
        return np.stack([-x, -lat[..., 0], -lat[..., 1]], axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        t2 = (p[..., 1] ** 2 + p[..., 2] ** 2) / (x * x)
    s = _distortion_scale(t2, rig.lens.k1, rig.lens.k2)
    return np.stack([-x, -p[..., 1] * s, -p[..., 2] * s], axis=-1)


def _hit_plane(pose: SensorPose, start: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """Intersection of lines start + λ·direction with the sensor plane, (…, 3)."""
    n = pose.normal
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = ((pose.origin_mm - start) @ n) / (direction @ n)
    return start + lam[..., None] * direction


def pixel_from_sensor_point(pose: SensorPose, q_mm) -> np.ndarray:
    """Pixel coordinates of rig-frame points lying in the sensor plane.

    Parameters
    ----------
    pose : SensorPose
        The sensor plane.
    q_mm : (..., 3) array_like float
        Points in the rig frame [mm]; their component along the sensor
        normal is ignored (orthogonal projection onto the plane).

    Returns
    -------
    (..., 2) ndarray float64
        Pixel coordinates (u, v) [px].

    Raises
    ------
    ValueError
        If ``q_mm`` is not of shape ``(..., 3)``.
    """
    rel = check_last_dim("q_mm", q_mm, 3) - pose.origin_mm
    return np.stack([rel @ pose.u_dir, rel @ pose.v_dir], axis=-1) / pose.pitch_mm


def sensor_point_from_pixel(pose: SensorPose, uv_px) -> np.ndarray:
    """Rig-frame position of pixel coordinates on the sensor plane.

    Parameters
    ----------
    pose : SensorPose
        The sensor plane.
    uv_px : (..., 2) array_like float
        Pixel coordinates (u, v) [px].

    Returns
    -------
    (..., 3) ndarray float64
        ``origin + u·p·e_u + v·p·e_v`` in the rig frame [mm].

    Raises
    ------
    ValueError
        If ``uv_px`` is not of shape ``(..., 2)``.
    """
    uv = check_last_dim("uv_px", uv_px, 2)
    return (pose.origin_mm + uv[..., :1] * pose.pitch_mm * pose.u_dir
            + uv[..., 1:2] * pose.pitch_mm * pose.v_dir)


@dataclass(frozen=True)
class Projection:
    """Result of :func:`project_points` (all arrays share the points' leading shape ``...``).

    Parameters
    ----------
    uv_px : (..., 2) ndarray float64
        Pixel where the (distorted) chief ray meets the sensor [px].
    image_point_mm : (..., 3) ndarray float64
        Conjugate point P' in the rig frame [mm].
    defocus_mm : (...) ndarray float64
        Signed distance from the sensor plane to P' along the sensor normal
        [mm] (0 for points on the sheet of an ideal rig).
    blur_diameter_mm : (...) ndarray float64
        Diameter of the thin-lens circle of confusion, i.e. the cone's section
        by the plane parallel to the lens through the chief-ray hit:
        A·|x_hit − x'|/|x'| with A = f/N [mm].
    """

    uv_px: np.ndarray
    image_point_mm: np.ndarray
    defocus_mm: np.ndarray
    blur_diameter_mm: np.ndarray


def project_points(rig: Rig, points_mm, pose: SensorPose | None = None) -> Projection:
    """Project rig-frame points onto the tilted sensor.

    Works for any point, on the sheet or off it; for sheet points of an ideal
    rig the result equals the closed forms of :mod:`scheimpflug.model.hinge`.

    Parameters
    ----------
    rig : Rig
        The instrument.
    points_mm : (..., 3) array_like float
        Object points in the rig frame, in front of the lens (x > f) [mm].
    pose : SensorPose, optional
        Sensor pose; default :func:`sensor_pose` of ``rig``.

    Returns
    -------
    Projection
        Pixel, conjugate point, defocus and blur diameter of each point.

    Raises
    ------
    ValueError
        If ``points_mm`` is not of shape ``(..., 3)``.
    """
    pose = sensor_pose(rig) if pose is None else pose
    p = check_last_dim("points_mm", points_mm, 3)
    img = conjugate_point(rig, p)
    c = lens_centre_mm(rig)
    hit = _hit_plane(pose, c, _chief_dir_image(rig, p))
    aperture = rig.lens.focal_length_mm / rig.lens.f_number
    with np.errstate(divide="ignore", invalid="ignore"):
        blur = aperture * np.abs(hit[..., 0] - img[..., 0]) / np.abs(img[..., 0] - c[0])
    defocus = (img - pose.origin_mm) @ pose.normal
    return Projection(pixel_from_sensor_point(pose, hit), img, defocus, blur)


def blur_footprint_px(rig: Rig, points_mm, pose: SensorPose | None = None,
                      n_angles: int = 72) -> tuple[np.ndarray, np.ndarray]:
    """Full extent of the blur spot on the sensor, along columns and rows.

    Marginal rays from ``n_angles`` points on the aperture rim through the
    conjugate point P' are intersected with the (tilted) sensor plane; the
    extents of that section along the columns and rows are returned.

    Parameters
    ----------
    rig : Rig
        The instrument (focal length, f-number and distortion of its lens).
    points_mm : (..., 3) array_like float
        Object points in the rig frame [mm].
    pose : SensorPose, optional
        Sensor pose; default :func:`sensor_pose` of ``rig``.
    n_angles : int, default 72
        Number of rim points sampled on the aperture [-].

    Returns
    -------
    du_px, dv_px : (...) ndarray float64
        Peak-to-peak extent Δu, Δv of the blur spot [px].

    Raises
    ------
    ValueError
        If ``points_mm`` is not of shape ``(..., 3)``.
    """
    pose = sensor_pose(rig) if pose is None else pose
    img = conjugate_point(rig, points_mm)[..., None, :]
    a = 0.5 * rig.lens.focal_length_mm / rig.lens.f_number
    psi = np.linspace(0.0, 2 * np.pi, n_angles, endpoint=False)
    rim = np.stack([np.full_like(psi, lens_state(rig).centre_x_mm), a * np.cos(psi), a * np.sin(psi)],
                   axis=-1)
    uv = pixel_from_sensor_point(pose, _hit_plane(pose, rim, img - rim))
    return np.ptp(uv[..., 0], axis=-1), np.ptp(uv[..., 1], axis=-1)


def chief_ray_from_pixel(rig: Rig, uv_px, pose: SensorPose | None = None) -> np.ndarray:
    """Object-side direction of the chief ray of pixels (distortion undone).

    Parameters
    ----------
    rig : Rig
        The instrument (distortion k1, k2 of its lens).
    uv_px : (..., 2) array_like float
        Pixel coordinates (u, v) [px].
    pose : SensorPose, optional
        Sensor pose; default :func:`sensor_pose` of ``rig``.

    Returns
    -------
    (..., 3) ndarray float64
        Unit direction in the rig frame [-]; the ray starts at the lens centre
        (the rig origin; :func:`lens_centre_mm` for a real lens).

    Raises
    ------
    ValueError
        If ``uv_px`` is not of shape ``(..., 2)``.
    """
    pose = sensor_pose(rig) if pose is None else pose
    q = sensor_point_from_pixel(pose, uv_px)
    return _chief_dir_from_sensor(rig, q, lens_state(rig).centre_x_mm)


def _chief_dir_from_sensor(rig: Rig, q: np.ndarray, cx: float) -> np.ndarray:
    """Unit object-side chief-ray directions of sensor points q, lens centre at (cx, 0, 0)."""
    qx = q[..., 0] - cx
    if not is_radial(rig.lens):
        with np.errstate(divide="ignore", invalid="ignore"):
            a_d = np.stack([q[..., 1] / qx, q[..., 2] / qx], axis=-1)
        a = undistort_tangents(rig.lens, rig.sensor.roll_deg, a_d)
        w = -qx[..., None] * np.stack([np.ones_like(qx), a[..., 0], a[..., 1]], axis=-1)
        return w / np.linalg.norm(w, axis=-1, keepdims=True)
    lat2 = (q[..., 1] ** 2 + q[..., 2] ** 2) / (qx ** 2)  # distorted tan² of the field angle
    ratio = _undistort_tan(lat2, rig.lens.k1, rig.lens.k2)
    w = np.stack([-qx, -q[..., 1] * ratio, -q[..., 2] * ratio], axis=-1)
    return w / np.linalg.norm(w, axis=-1, keepdims=True)


def sheet_point_from_pixel(rig: Rig, uv_px, pose: SensorPose | None = None) -> np.ndarray:
    """Rig-frame point where the chief ray of pixels meets the laser sheet.

    Parameters
    ----------
    rig : Rig
        The instrument (lens distortion; the sheet ``y = d − x·tan φ``).
    uv_px : (..., 2) array_like float
        Pixel coordinates (u, v) [px].
    pose : SensorPose, optional
        Sensor pose; default :func:`sensor_pose` of ``rig``.

    Returns
    -------
    (..., 3) ndarray float64
        Sheet points in the rig frame [mm]; NaN for rays parallel to the
        sheet or meeting it behind the lens.

    Raises
    ------
    ValueError
        If ``uv_px`` is not of shape ``(..., 2)``.
    """
    w = chief_ray_from_pixel(rig, uv_px, pose)
    c = lens_centre_mm(rig)
    d, t = rig.laser.scheimpflug_distance_mm - c[0] * rig.laser.tan_phi, rig.laser.tan_phi
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = d / (w[..., 1] + w[..., 0] * t)
    lam = np.where(lam > 0, lam, np.nan)
    return c + lam[..., None] * w


def sheet_jacobian(rig: Rig, uv_px, pose: SensorPose | None = None) -> np.ndarray:
    """Exact Jacobian ∂P/∂(u, v) of :func:`sheet_point_from_pixel`.

    Parameters
    ----------
    rig : Rig
        The instrument (lens distortion; the sheet ``y = d − x·tan φ``).
    uv_px : (..., 2) array_like float
        Pixel coordinates (u, v) [px].
    pose : SensorPose, optional
        Sensor pose; default :func:`sensor_pose` of ``rig``.

    Returns
    -------
    (..., 3, 2) ndarray float64
        J[..., :, 0] = ∂P/∂u and J[..., :, 1] = ∂P/∂v in the rig frame [mm/px]; NaN
        where the chief ray misses the sheet in front of the lens.

    Raises
    ------
    ValueError
        If ``uv_px`` is not of shape ``(..., 2)``.

    Notes
    -----
    The chain of :func:`sheet_point_from_pixel` differentiated term by term: pixel →
    sensor point q = O + p·(u·e_u + v·e_v) → distorted tangents a_d = (q_y, q_z)/(q_x − c_x)
    → object tangents a (∂a/∂a_d the inverse of
    :func:`scheimpflug.model.distortion.tangents_jacobian`) → P = c + λ·(1, a_y, a_z)
    with λ = d'/(a_y + tan φ), d' = d − c_x·tan φ.
    """
    pose = sensor_pose(rig) if pose is None else pose
    q = sensor_point_from_pixel(pose, uv_px)
    c = lens_centre_mm(rig)
    with np.errstate(divide="ignore", invalid="ignore"):
        qx = q[..., 0] - c[0]
        a_d = np.stack([q[..., 1] / qx, q[..., 2] / qx], axis=-1)
        dad_dq = np.zeros(q.shape[:-1] + (2, 3))
        dad_dq[..., 0, 0], dad_dq[..., 0, 1] = -q[..., 1] / qx**2, 1.0 / qx
        dad_dq[..., 1, 0], dad_dq[..., 1, 2] = -q[..., 2] / qx**2, 1.0 / qx
    a = undistort_tangents(rig.lens, rig.sensor.roll_deg, a_d)
    da_dad = np.linalg.inv(tangents_jacobian(rig.lens, rig.sensor.roll_deg, a))
    t = rig.laser.tan_phi
    d = rig.laser.scheimpflug_distance_mm - c[0] * t
    s = a[..., 0] + t
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = np.where(d / s > 0, d / s, np.nan)
        k = -lam / s                                    # ∂λ/∂a_y
    dp_da = np.zeros(q.shape[:-1] + (3, 2))
    dp_da[..., 0, 0] = k
    dp_da[..., 1, 0] = lam + a[..., 0] * k
    dp_da[..., 2, 0], dp_da[..., 2, 1] = a[..., 1] * k, lam
    dq_duv = pose.pitch_mm * np.stack([pose.u_dir, pose.v_dir], axis=-1)
    return dp_da @ da_dad @ dad_dq @ dq_duv


def stripe_along(rig: Rig) -> str:
    """Which way a turning part's stripe runs in the rig's frames: down the columns or along the rows.

    A part on the rotary table is cut by the sheet along the table's axis, the
    rig's +z in the sheet; its stripe runs the way +z images.  Measured at the
    sheet point the frame's centre pixel sees, over a step of 1 mm along +z.

    Parameters
    ----------
    rig : Rig
        The instrument.

    Returns
    -------
    {"columns", "rows"}
        "columns" when +z images more along the columns (v) than the rows (one stripe
        point per row: the Scheimpflug profiler's), "rows" otherwise (one per column:
        e.g. FabScan's camera, turned by 90°) — a frame folder's ``stripe_along``.
    """
    centre = np.array([0.5 * (rig.sensor.columns - 1), 0.5 * (rig.sensor.rows - 1)])
    p = sheet_point_from_pixel(rig, centre)
    if not np.all(np.isfinite(p)):
        return "columns"
    uv = project_points(rig, np.stack([p - [0.0, 0.0, 0.5], p + [0.0, 0.0, 0.5]])).uv_px
    du, dv = np.abs(uv[1] - uv[0])
    return "rows" if du > dv else "columns"
