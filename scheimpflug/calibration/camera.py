"""Cameras of the calibration: OpenCV's pinhole model with its tilted-sensor terms (``CALIB_TILTED_MODEL``).

Two classes, one model: :class:`TiltedCamera` (square pixels, radial k1, k2,
τx, τy: what the general calibration fits, :mod:`scheimpflug.calibration.general`)
and :class:`OpenCVCamera` (OpenCV's whole model: fx, fy, the 14 distortion
coefficients — what the target calibration fits and what foreign calibrations
hold, :mod:`scheimpflug.calibration.target`).  The general calibration, the target
calibration and the OpenCV export (:mod:`scheimpflug.calibration.opencv`) share
them, so that ``cv2.projectPoints`` with the exported parameters reproduces the
pipeline's pixel mapping exactly.  :func:`ideal_camera` decomposes the paper
form's constants into the ideal rig's camera and sheet.

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

from scheimpflug.errors import CalibrationError

__all__ = [
    "CAMERA_FROM_RIG",
    "DEFAULT_FOCAL_LENGTH_MM",
    "DEFAULT_PIXEL_PITCH_UM",
    "OpenCVCamera",
    "TiltedCamera",
    "camera_from_json",
    "camera_from_sensor_pose",
    "ideal_camera",
    "tilt_matrix",
]

#: Focal length assumed for the decomposition when no rig is given (the paper's lens) [mm].
DEFAULT_FOCAL_LENGTH_MM = 55.0
#: Pixel pitch assumed when no rig is given (the paper's IMX174) [µm].
DEFAULT_PIXEL_PITCH_UM = 5.86

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


# ---------------------------------------------------------------- OpenCV's whole model


def _opencv_distort(d: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's distortion of undistorted normalized coordinates (before the tilt), vectorised."""
    k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4 = d[:12]
    r2 = x * x + y * y
    r4 = r2 * r2
    radial = (1.0 + k1 * r2 + k2 * r4 + k3 * r4 * r2) / (1.0 + k4 * r2 + k5 * r4 + k6 * r4 * r2)
    xy = x * y
    return (x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x * x) + s1 * r2 + s2 * r4,
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * xy + s3 * r2 + s4 * r4)


@dataclass(frozen=True)
class OpenCVCamera:
    """OpenCV's pinhole camera with its 14 distortion coefficients (``cv2.projectPoints``'s model).

    Camera frame as :class:`TiltedCamera`'s.  A point's normalized coordinates
    ``(x, y) = (X/Z, Y/Z)`` are distorted (rational radial k1…k6, tangential
    p1, p2, thin prism s1…s4), tilted (τx, τy: :func:`tilt_matrix`) and mapped by
    the camera matrix ``u = fx·x_t + cx``, ``v = fy·y_t + cy`` (no skew).

    Parameters
    ----------
    camera_matrix : (3, 3) array_like float
        ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` [px].
    dist_coeffs : array_like float
        OpenCV's distortion vector in its order ``[k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4,
        τx, τy]`` (4, 5, 8, 12 or 14 values; the rest are 0; τ in radians) [-].

    Raises
    ------
    CalibrationError
        A camera matrix that is not 3 × 3 with fx, fy > 0, no skew and a last row (0, 0, 1), or a
        distortion vector of another length or with a non-finite value.
    """

    camera_matrix: np.ndarray
    dist_coeffs: np.ndarray

    def __post_init__(self) -> None:
        k = np.asarray(self.camera_matrix, np.float64)
        d = np.asarray(self.dist_coeffs, np.float64).ravel()
        problem = _camera_matrix_problem(k)
        if problem:
            raise CalibrationError(problem)
        if d.size not in (4, 5, 8, 12, 14):
            raise CalibrationError(f"dist_coeffs must be 4, 5, 8, 12 or 14 numbers (OpenCV's order), got {d.size}")
        bad = np.flatnonzero(~np.isfinite(d))
        if bad.size:
            raise CalibrationError(f"dist_coeffs[{bad[0]}] = {d[bad[0]]} is not a finite number (OpenCV's order: "
                                   "k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4, τx, τy)")
        object.__setattr__(self, "camera_matrix", k.copy())
        object.__setattr__(self, "dist_coeffs", np.concatenate([d, np.zeros(14 - d.size)]))

    @property
    def focal_px(self) -> float:
        """Mean of fx and fy [px]."""
        return 0.5 * float(self.camera_matrix[0, 0] + self.camera_matrix[1, 1])

    @property
    def principal_px(self) -> tuple[float, float]:
        """Principal point ``(c_x, c_y)`` [px]."""
        return float(self.camera_matrix[0, 2]), float(self.camera_matrix[1, 2])

    @property
    def tau_x_rad(self) -> float:
        """Sensor tilt τx [rad]."""
        return float(self.dist_coeffs[12])

    @property
    def tau_y_rad(self) -> float:
        """Sensor tilt τy [rad]."""
        return float(self.dist_coeffs[13])

    @property
    def tilt(self) -> np.ndarray:
        """OpenCV's tilt projection matrix :func:`tilt_matrix`, (3, 3)."""
        return tilt_matrix(self.tau_x_rad, self.tau_y_rad)

    def pixel_from_normalized(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """Pixel of undistorted normalized coordinates (``cv2.projectPoints`` of ``(x, y, 1)``).

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
        xd, yd = _opencv_distort(self.dist_coeffs, x, y)
        xt, yt = _apply(self.tilt, xd, yd)
        k = self.camera_matrix
        return k[0, 0] * xt + k[0, 2], k[1, 1] * yt + k[1, 2]

    def normalized_from_pixel(self, u, v, iterations: int = 30) -> tuple[np.ndarray, np.ndarray]:
        """Undistorted normalized coordinates of pixels: the inverse of :meth:`pixel_from_normalized`.

        The distortion is inverted by Newton's method on the 2 × 2 system per pixel
        (Jacobian by central differences), started at the distorted coordinates;
        converged to < 1e-13 in normalized units on the distortion of a real lens.

        Parameters
        ----------
        u, v : array_like float
            Column and row [px], broadcast together.
        iterations : int, default 30
            Newton steps at most.

        Returns
        -------
        x, y : ndarray float64
            ``X/Z`` and ``Y/Z`` of the pixel's ray [-]; NaN where the iteration does not converge
            (beyond the lens model's monotonic range).
        """
        k = self.camera_matrix
        xt = (np.asarray(u, np.float64) - k[0, 2]) / k[0, 0]
        yt = (np.asarray(v, np.float64) - k[1, 2]) / k[1, 1]
        xt, yt = np.broadcast_arrays(xt, yt)
        xd, yd = _apply(np.linalg.inv(self.tilt), xt, yt)
        return _undistort_newton(self.dist_coeffs, xd, yd, iterations)

    def to_json_dict(self) -> dict:
        """JSON form: ``camera_matrix`` (3 × 3) and ``dist_coeffs`` (14, OpenCV's order).

        Returns
        -------
        dict
            JSON-ready values [px, -].
        """
        return {"camera_matrix": self.camera_matrix.tolist(), "dist_coeffs": self.dist_coeffs.tolist()}

    @classmethod
    def from_json_dict(cls, d: dict) -> OpenCVCamera:
        """Inverse of :meth:`to_json_dict`.

        Parameters
        ----------
        d : dict
            ``camera_matrix`` and ``dist_coeffs``.

        Returns
        -------
        OpenCVCamera
            The camera.

        Raises
        ------
        CalibrationError
            A missing key or a value :class:`OpenCVCamera` refuses.
        """
        missing = [k for k in ("camera_matrix", "dist_coeffs") if k not in d]
        if missing:
            raise CalibrationError(f"the camera lacks {' and '.join(missing)}")
        try:
            k, dist = np.asarray(d["camera_matrix"], np.float64), np.asarray(d["dist_coeffs"], np.float64)
        except (TypeError, ValueError) as exc:
            raise CalibrationError(f"camera_matrix and dist_coeffs must be numbers: {exc}") from None
        return cls(k, dist)


def _camera_matrix_problem(k: np.ndarray) -> str | None:
    if k.shape != (3, 3):
        return f"camera_matrix must be a 3 × 3 matrix, got shape {k.shape}"
    bad = np.argwhere(~np.isfinite(k))
    if bad.size:
        (i, j), value = bad[0], k[tuple(bad[0])]
        return f"camera_matrix[{i}][{j}] = {value} is not a finite number: not a camera"
    if not (k[0, 0] > 0 and k[1, 1] > 0) or abs(np.linalg.det(k)) < 1e-12:
        return (f"camera_matrix is singular or has fx, fy <= 0 (fx = {k[0, 0]:.6g}, fy = {k[1, 1]:.6g} px): "
                "not a camera")
    if k[0, 1] != 0 or k[1, 0] != 0 or not np.allclose(k[2], [0.0, 0.0, 1.0]):
        return "camera_matrix must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew)"
    return None


def _undistort_newton(d: np.ndarray, xd: np.ndarray, yd: np.ndarray,
                      iterations: int) -> tuple[np.ndarray, np.ndarray]:
    """Solve distort(x, y) = (xd, yd) by Newton's method with a central-difference Jacobian."""
    if not np.any(d[:12]):
        return xd.copy(), yd.copy()
    x, y = xd.copy(), yd.copy()
    h = 1e-7
    for _ in range(iterations):
        fx, fy = _opencv_distort(d, x, y)
        rx, ry = fx - xd, fy - yd
        if np.nanmax(np.abs(np.concatenate([rx.ravel(), ry.ravel()])), initial=0.0) < 1e-15:
            break
        ax, ay = _opencv_distort(d, x + h, y)
        bx, by = _opencv_distort(d, x - h, y)
        cx, cy = _opencv_distort(d, x, y + h)
        ex, ey = _opencv_distort(d, x, y - h)
        j11, j21 = (ax - bx) / (2 * h), (ay - by) / (2 * h)
        j12, j22 = (cx - ex) / (2 * h), (cy - ey) / (2 * h)
        det = j11 * j22 - j12 * j21
        with np.errstate(divide="ignore", invalid="ignore"):
            x = x - (j22 * rx - j12 * ry) / det
            y = y - (-j21 * rx + j11 * ry) / det
    fx, fy = _opencv_distort(d, x, y)
    bad = ~(np.hypot(fx - xd, fy - yd) < 1e-9)
    return np.where(bad, np.nan, x), np.where(bad, np.nan, y)


def camera_from_json(d: dict):
    """The camera of a calibration file's ``camera`` table, whichever class wrote it.

    Parameters
    ----------
    d : dict
        :meth:`TiltedCamera.to_json_dict` (``focal_px`` …) or :meth:`OpenCVCamera.to_json_dict`
        (``camera_matrix``, ``dist_coeffs``).

    Returns
    -------
    TiltedCamera or OpenCVCamera
        The camera.

    Raises
    ------
    CalibrationError
        A table of neither form, or values the class refuses.
    """
    if not isinstance(d, dict):
        raise CalibrationError("the calibration's camera must be a JSON object")
    if "camera_matrix" in d:
        return OpenCVCamera.from_json_dict(d)
    try:
        return TiltedCamera.from_json_dict(d)
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise CalibrationError(f"camera lacks or garbles a field: {exc!r}") from None


# ---------------------------------------------------------------- the paper form as a camera


def ideal_camera(calibration, focal_length_mm: float = DEFAULT_FOCAL_LENGTH_MM,
                 pixel_pitch_um: float = DEFAULT_PIXEL_PITCH_UM) -> tuple[TiltedCamera, np.ndarray]:
    """The ideal Scheimpflug rig behind paper-form constants, as a camera and a sheet homography.

    The constants fix ``C = f / sin β`` and ``F² = −f² / (p cos φ sin β)``
    (docs/explanation/design-notes.md §3); with the focal length ``f`` and the pixel pitch ``p`` (the
    two things a homography cannot tell) they give the tilt β, the sheet
    angle φ and the Scheimpflug distance ``d = f/tan β + f tan φ``, and with
    ``(u_h, v_h)`` the sensor's place: the rig of :mod:`scheimpflug.model.camera`
    without misalignment.  Its camera reproduces the paper form's mapping
    exactly (the ideal rig's chief rays obey Eqs. 11–12).

    Parameters
    ----------
    calibration : Calibration
        Paper-form constants (u_h, v_h, F², d0, C): anything with ``constants()``.
    focal_length_mm : float
        Thin-lens focal length f [mm].
    pixel_pitch_um : float
        Pixel pitch p [µm].

    Returns
    -------
    camera : TiltedCamera
        Principal distance, principal point and tilt τy = β (no distortion).
    homography : (3, 3) float
        ``G``: (s, h, 1) → normalized camera coordinates, scaled to ``G[2, 2] = 1``.

    Raises
    ------
    CalibrationError
        The constants are not those of a Scheimpflug rig with this f and p
        (e.g. ``|cos φ| > 1``: the focal length or the pitch is wrong).
    """
    uh, vh, F2, d0, C = calibration.constants()
    f, p = float(focal_length_mm), float(pixel_pitch_um) * 1e-3
    sin_b = f / C
    cos_phi = -f * C / (F2 * p)
    if not (0 < sin_b < 1 and 0 < cos_phi <= 1 + 1e-12):
        raise CalibrationError(
            f"the calibration (F² = {F2:.6g} px·mm, C = {C:.6g} mm) is not an ideal Scheimpflug rig "
            f"with f = {f:g} mm and pixel pitch {p * 1e3:g} µm (sin β = {sin_b:.4g}, cos φ = "
            f"{cos_phi:.4g}): the focal length or the pixel pitch (binned?) is not the frames'")
    beta, phi = math.asin(sin_b), math.acos(min(cos_phi, 1.0))
    hinge_obj = np.array([f, f / math.tan(beta), 0.0])         # H = (f, d − f tan φ, 0)
    e_p = np.array([math.cos(phi), -math.sin(phi), 0.0])
    e_u = np.array([math.sin(beta), math.cos(beta), 0.0])
    e_v = np.array([0.0, 0.0, 1.0])
    origin = np.array([-f, f * math.tan(phi), 0.0]) - uh * p * e_u - vh * p * e_v
    camera, c = camera_from_sensor_pose(origin, e_u, e_v, p, CAMERA_FROM_RIG)
    g = np.column_stack([c @ e_p, c @ e_v, c @ (hinge_obj - d0 * e_p)])
    return camera, g / g[2, 2]
