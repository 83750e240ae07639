"""A tilted-sensor pinhole camera with radial distortion: OpenCV's ``CALIB_TILTED_MODEL``.

The general calibration (:mod:`scheimpflug.sheet_model`) and the OpenCV
export (:mod:`scheimpflug.io.opencv`) share this one camera model, so that
``cv2.projectPoints`` with the exported parameters reproduces the pipeline's
pixel mapping exactly.

Camera frame (OpenCV's): origin at the projection centre (the thin lens'
centre), ``Z`` forward along the optical axis, ``X`` right along the columns,
``Y`` down along the rows.  A point ``(X, Y, Z)`` images at

1. normalized coordinates ``x = X/Z``, ``y = Y/Z`` (the tangent of the field
   angle, object side);
2. radial distortion ``(x, y) · (1 + k1 r² + k2 r⁴)``, ``r² = x² + y²``
   (:mod:`scheimpflug.model.camera` distorts the chief ray in exactly this way);
3. the tilted sensor: OpenCV's matrix ``T(τx, τy) = P_Z · R_Y(τy) · R_X(τx)``
   applied to ``(x_d, y_d, 1)`` and divided by its third component;
4. pixels ``u = f·x_t + c_x``, ``v = f·y_t + c_y`` (square pixels, no skew).

Physically: the sensor is a plane meeting the optical axis at pixel
``(c_x, c_y)``, a distance ``f·p`` from the centre (``p`` the pixel pitch),
with normal ``R^T e_z`` and axes ``R^T e_x``, ``R^T e_y``
(``R = R_Y(τy) R_X(τx)``).  :func:`camera_from_sensor_pose` finds these
values for any sensor plane behind a thin lens.

References
----------
OpenCV, *Camera Calibration and 3D Reconstruction* (``calib3d``): the
tilted-sensor model of ``CALIB_TILTED_MODEL`` and ``computeTiltProjectionMatrix``.
A. Louhichi et al., "Self-calibration of Scheimpflug cameras", 2007.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import optimize

__all__ = [
    "CAMERA_FROM_RIG",
    "TiltedCamera",
    "camera_from_sensor_pose",
    "tilt_matrix",
]

#: OpenCV camera frame from the rig frame (docs/explanation/design-notes.md §2): X = −y_rig, Y = −z_rig, Z = x_rig.
CAMERA_FROM_RIG = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])


def _rot_x(tau: float) -> np.ndarray:
    c, s = math.cos(tau), math.sin(tau)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]])


def _rot_y(tau: float) -> np.ndarray:
    c, s = math.cos(tau), math.sin(tau)
    return np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])


def _rot_z(gamma: float) -> np.ndarray:
    c, s = math.cos(gamma), math.sin(gamma)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def tilt_matrix(tau_x_rad: float, tau_y_rad: float) -> np.ndarray:
    """OpenCV's tilt projection ``T = P_Z · R_Y(τy) · R_X(τx)`` (``computeTiltProjectionMatrix``).

    Parameters
    ----------
    tau_x_rad, tau_y_rad : float
        Tilt angles τx, τy of the sensor [rad].

    Returns
    -------
    (3, 3) float
        Maps homogeneous distorted normalized coordinates to the tilted sensor's.
    """
    r = _rot_y(tau_y_rad) @ _rot_x(tau_x_rad)
    proj = np.array([[r[2, 2], 0.0, -r[0, 2]], [0.0, r[2, 2], -r[1, 2]], [0.0, 0.0, 1.0]])
    return proj @ r


def _apply(m: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Projective map of 2-D points by a 3×3 matrix (NaN where the third component is 0)."""
    w = m[2, 0] * x + m[2, 1] * y + m[2, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(w != 0, 1.0 / np.where(w != 0, w, 1.0), np.nan)
    return (m[0, 0] * x + m[0, 1] * y + m[0, 2]) * inv, (m[1, 0] * x + m[1, 1] * y + m[1, 2]) * inv


def _undistort_ratio(rd2: np.ndarray, k1: float, k2: float, iterations: int = 12) -> np.ndarray:
    """R / r_d solving r (1 + k1 r² + k2 r⁴) = r_d by Newton's method, vectorised."""
    if k1 == 0.0 and k2 == 0.0:
        return np.ones_like(rd2)
    rd = np.sqrt(rd2)
    r = rd.copy()
    for _ in range(iterations):
        r2 = r * r
        g = r * (1.0 + k1 * r2 + k2 * r2 * r2) - rd
        r = r - g / (1.0 + 3.0 * k1 * r2 + 5.0 * k2 * r2 * r2)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(rd > 0, r / np.where(rd > 0, rd, 1.0), 1.0)


@dataclass(frozen=True)
class TiltedCamera:
    """Intrinsics of OpenCV's tilted pinhole model with radial distortion (module docstring).

    Parameters
    ----------
    focal_px : float
        Principal distance over the pixel pitch, ``fx = fy`` [px].
    principal_px : tuple of float
        Principal point ``(c_x, c_y)``: where the optical axis meets the sensor [px].
    tau_x_rad, tau_y_rad : float
        Sensor tilt τx, τy of ``CALIB_TILTED_MODEL`` [rad].
    k1, k2 : float
        Radial distortion of the normalized coordinates [-].
    """

    focal_px: float
    principal_px: tuple[float, float]
    tau_x_rad: float = 0.0
    tau_y_rad: float = 0.0
    k1: float = 0.0
    k2: float = 0.0

    @property
    def tilt(self) -> np.ndarray:
        """OpenCV's tilt projection matrix :func:`tilt_matrix`, (3, 3)."""
        return tilt_matrix(self.tau_x_rad, self.tau_y_rad)

    @property
    def camera_matrix(self) -> np.ndarray:
        """OpenCV's camera matrix ``[[f, 0, c_x], [0, f, c_y], [0, 0, 1]]``, (3, 3) [px]."""
        cx, cy = self.principal_px
        return np.array([[self.focal_px, 0.0, cx], [0.0, self.focal_px, cy], [0.0, 0.0, 1.0]])

    @property
    def dist_coeffs(self) -> np.ndarray:
        """OpenCV's 14 distortion coefficients ``[k1, k2, p1, p2, k3, k4, k5, k6, s1..s4, τx, τy]``, (14,)."""
        d = np.zeros(14)
        d[0], d[1], d[12], d[13] = self.k1, self.k2, self.tau_x_rad, self.tau_y_rad
        return d

    def pixel_from_normalized(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """Pixel of undistorted normalized coordinates (distortion, tilt, camera matrix).

        Parameters
        ----------
        x, y : array_like float
            ``X/Z`` and ``Y/Z`` in the camera frame [-], broadcast together.

        Returns
        -------
        u_px, v_px : ndarray float64
            Column and row [px].
        """
        x, y = np.broadcast_arrays(np.asarray(x, np.float64), np.asarray(y, np.float64))
        r2 = x * x + y * y
        scale = 1.0 + self.k1 * r2 + self.k2 * r2 * r2
        xt, yt = _apply(self.tilt, x * scale, y * scale)
        cx, cy = self.principal_px
        return self.focal_px * xt + cx, self.focal_px * yt + cy

    def normalized_from_pixel(self, u, v) -> tuple[np.ndarray, np.ndarray]:
        """Undistorted normalized coordinates of pixels: the inverse of :meth:`pixel_from_normalized`.

        Parameters
        ----------
        u, v : array_like float
            Column and row [px], broadcast together.

        Returns
        -------
        x, y : ndarray float64
            ``X/Z`` and ``Y/Z`` of the pixel's ray in the camera frame [-].
        """
        cx, cy = self.principal_px
        xt = (np.asarray(u, np.float64) - cx) / self.focal_px
        yt = (np.asarray(v, np.float64) - cy) / self.focal_px
        xd, yd = _apply(np.linalg.inv(self.tilt), xt, yt)
        ratio = _undistort_ratio(xd * xd + yd * yd, self.k1, self.k2)
        return xd * ratio, yd * ratio

    def to_json_dict(self) -> dict:
        """JSON form: ``focal_px``, ``principal_px``, ``tau_deg`` [τx, τy], ``k1``, ``k2``.

        Returns
        -------
        dict
            JSON-ready values [px, deg, -].
        """
        return {"focal_px": self.focal_px, "principal_px": list(self.principal_px),
                "tau_deg": [math.degrees(self.tau_x_rad), math.degrees(self.tau_y_rad)],
                "k1": self.k1, "k2": self.k2}

    @classmethod
    def from_json_dict(cls, d: dict) -> TiltedCamera:
        """Inverse of :meth:`to_json_dict`.

        Parameters
        ----------
        d : dict
            As written by :meth:`to_json_dict`.

        Returns
        -------
        TiltedCamera
            The camera.
        """
        tau = d.get("tau_deg", [0.0, 0.0])
        return cls(focal_px=float(d["focal_px"]),
                   principal_px=(float(d["principal_px"][0]), float(d["principal_px"][1])),
                   tau_x_rad=math.radians(float(tau[0])), tau_y_rad=math.radians(float(tau[1])),
                   k1=float(d.get("k1", 0.0)), k2=float(d.get("k2", 0.0)))


def _tau_from_normal(n: np.ndarray) -> tuple[float, float]:
    """τx, τy whose ``R^T e_z = (sin τy, −sin τx cos τy, cos τx cos τy)`` is the unit normal ``n``."""
    return math.atan2(-n[1], n[2]), math.asin(max(-1.0, min(1.0, n[0])))


def _axis_mismatch(gamma: float, e_u: np.ndarray, normal: np.ndarray) -> float:
    """Component of the sensor's column axis along OpenCV's row axis after turning the frame by γ."""
    rz = _rot_z(gamma)
    tx, ty = _tau_from_normal(rz @ normal)
    r = _rot_y(ty) @ _rot_x(tx)
    return float(r[1] @ (rz @ e_u))


def _frame_rotation(e_u: np.ndarray, e_v: np.ndarray) -> float:
    """The turn γ of the camera frame about Z that makes OpenCV's tilted axes the sensor's [rad]."""
    normal = np.cross(e_u, e_v)
    grid = np.linspace(-math.pi / 4, math.pi / 4, 91)
    vals = [_axis_mismatch(g, e_u, normal) for g in grid]
    for a, b, fa, fb in zip(grid[:-1], grid[1:], vals[:-1], vals[1:]):
        if fa == 0.0:
            return float(a)
        if fa * fb < 0:
            return float(optimize.brentq(_axis_mismatch, a, b, args=(e_u, normal), xtol=1e-15))
    raise ValueError("the sensor's column axis is more than 45° from the camera's X axis")


def camera_from_sensor_pose(origin_mm, u_dir, v_dir, pitch_mm: float,
                            camera_from_rig: np.ndarray = CAMERA_FROM_RIG) -> tuple[TiltedCamera, np.ndarray]:
    """OpenCV's tilted camera of a sensor plane behind a lens centred at the origin.

    The sensor behind the lens sees an inverted image; its point reflection
    through the centre is the virtual sensor in front that OpenCV models.

    Parameters
    ----------
    origin_mm : (3,) float
        Position of pixel (0, 0)'s centre in the source frame [mm] (rig frame by default).
    u_dir, v_dir : (3,) float
        Unit directions of increasing column and row, same frame.
    pitch_mm : float
        Pixel pitch [mm].
    camera_from_rig : (3, 3) float
        Rotation from the source frame to an OpenCV-like camera frame (Z along the optical axis).

    Returns
    -------
    camera : TiltedCamera
        Focal length, principal point and tilt (no distortion).
    camera_from_source : (3, 3) float
        The rotation to the camera frame of ``camera``: ``camera_from_rig`` turned
        about Z so that OpenCV's tilted axes are the sensor's.

    Raises
    ------
    ValueError
        If the sensor plane is parallel to the optical axis or turned more than 45°.
    """
    c = np.asarray(camera_from_rig, np.float64)
    q0 = c @ -np.asarray(origin_mm, np.float64)
    e_u, e_v = c @ -np.asarray(u_dir, np.float64), c @ -np.asarray(v_dir, np.float64)
    a = np.column_stack([e_u * pitch_mm, e_v * pitch_mm, [0.0, 0.0, -1.0]])
    if abs(np.linalg.det(a)) < 1e-12 * pitch_mm ** 2:
        raise ValueError("the sensor plane is parallel to the optical axis")
    cx, cy, z0 = np.linalg.solve(a, -q0)
    gamma = _frame_rotation(e_u, e_v)
    rz = _rot_z(gamma)
    normal = np.cross(e_u, e_v)
    tx, ty = _tau_from_normal(rz @ normal)
    return TiltedCamera(float(z0 / pitch_mm), (float(cx), float(cy)), tx, ty), rz @ c
