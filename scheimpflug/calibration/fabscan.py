"""FabScan's calibration (FabScanPi-Server's ``config.json``) as a sheet model of the frames as stored.

FabScanPi (an open turntable laser scanner) keeps its calibration in the
``calibration`` table of its ``config.json``: the camera matrix, a 5-term
OpenCV distortion vector, one laser plane per laser (``normal``, unit, and
``distance`` [mm]: ``normal·X = distance`` in the camera frame, with the fit's
``deviation`` [mm]) and the turntable's pose (``platform_rotation`` R and
``platform_translation`` t [mm]: a point of the platform frame ``X_p`` is at
``X_c = R·X_p + t`` in the camera frame; the platform's z axis is the rotary
axis).  What follows is read from FabScanPi-Server's source at commit
``afdcbb9f8c77957523932090ab02307c635128ab`` (GPL-2.0; read, not copied):

Frame orientation (``FSImageProcessor.rotate_image``)
    FabScan turns every camera frame before it measures it: the transpose when
    ``camera.rotate`` is "True", then a left–right flip (``camera.hflip``), then
    an up–down flip (``camera.vflip``).  Its camera matrix and planes describe
    the *turned* image.  This reader expresses them for the frames as the
    camera stored them (what ``scheimpflug import`` copies), by the pixel map
    ``p' = A·p + b`` of those steps: the camera frame of the files is
    ``X = M·X'`` with ``M = diag(Aᵀ, 1)``, the camera matrix's focal lengths and
    principal point follow, and the tangential distortion ``(p2, p1)`` turns as
    a vector (radial terms are unchanged).  With ``rotate`` the laser line of a
    turntable scanner runs along the files' rows (``stripe_along = "rows"``).
Distortion (``FSImageProcessor.compute_camera_point_cloud``)
    FabScan finds its points, and its laser plane at calibration, from the
    camera matrix alone — ``x = ((u − cx)/fx, (v − cy)/fy, 1)``, the point
    ``d / (n·x) · x`` — and uses the distortion only for the pattern's pose
    (``cv2.solvePnP``); ``camera.undistort`` "False" says its frames are not
    undistorted either.  ``distortion="as-fabscan"`` (the default) keeps that:
    the points are FabScan's own.  ``"apply"`` uses the calibrated distortion
    (the lens as the calibration found it, with a plane that was fitted without
    it).
Angles (``FSScanActor``, ``FSImageWorker``)
    With ``turntable.steps`` motor steps per turn and ``degree_per_step`` of
    the resolution setting (defaults 3.6, 1.8, 0.8° for low, medium, high in
    ``FSConfig``), the table moves ``int(deg / (360 / steps))`` steps per picture,
    ``N = steps // that`` pictures per turn, and picture ``k = 1 … N`` is
    processed at ``angle = k · 360 / N`` turned into the platform frame by
    ``R_z(angle)`` (:func:`fabscan_angles_deg`).  This pipeline's part frame
    turns the other way (``R_z(−θ)``, docs/reference/interface.md): a FabScan
    picture at FabScan's angle ``a`` is at ``θ = −a``.

The rotary axis is recorded as a target calibration's (``axis``:
:func:`scheimpflug.calibration.target.axis_in_sheet`), so ``reconstruct`` needs no
``--axis-mm``; the sheet frame's height axis is the platform's z axis projected
into the laser plane.  The pipeline's part frame holds the axis in the sheet:
the distance and angle by which FabScan's calibrated axis misses its laser
plane are reported (``axis.distance_to_sheet_mm``, ``axis.angle_to_sheet_deg``).
"""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import numpy as np

from scheimpflug.calibration.camera import OpenCVCamera
from scheimpflug.calibration.model import MAX_SIDE_PX, check_laser_plane, numbers_text, sheet_frame_from_plane
from scheimpflug.calibration.target import TargetCalibration, axis_in_sheet
from scheimpflug.errors import CalibrationError

__all__ = ["DISTORTION_USES", "fabscan_angles_deg", "is_fabscan_config", "pixel_map", "read_fabscan"]

#: How the FabScan distortion is used (module docstring).
DISTORTION_USES = ("as-fabscan", "apply")
#: ``FSConfig``'s default degrees per picture of the resolution settings 1, 2, 3 (low, medium, high).
_DEGREES = {1: 3.6, 2: 1.8, 3: 0.8}


def is_fabscan_config(d) -> bool:
    """Whether a parsed JSON document is FabScan's ``config.json`` (a ``calibration`` with ``laser_planes``).

    Parameters
    ----------
    d : object
        The parsed JSON.

    Returns
    -------
    bool
        True for FabScan's configuration file.
    """
    return isinstance(d, dict) and isinstance(d.get("calibration"), dict) and "laser_planes" in d["calibration"]


def _flag(camera: dict, key: str) -> bool:
    value = camera.get(key, "False")
    return value is True or (isinstance(value, str) and value.strip().lower() == "true")


def pixel_map(width: int, height: int, rotate: bool, hflip: bool, vflip: bool) -> tuple[np.ndarray, np.ndarray, tuple]:
    """FabScan's turned-image pixel of a stored frame's pixel: ``p' = A·p + b`` (module docstring).

    Parameters
    ----------
    width, height : int
        The stored frames' size [px].
    rotate, hflip, vflip : bool
        ``camera.rotate`` (transpose), ``camera.hflip``, ``camera.vflip``, applied in that order.

    Returns
    -------
    A : (2, 2) float64
        A signed permutation [-].
    b : (2,) float64
        The offset [px].
    size : (int, int)
        The turned image's (width, height) [px].
    """
    a, b, w, h = np.eye(2), np.zeros(2), int(width), int(height)
    if rotate:
        a, b, w, h = a[::-1].copy(), b[::-1].copy(), h, w
    if hflip:
        a[0], b[0] = -a[0], (w - 1) - b[0]
    if vflip:
        a[1], b[1] = -a[1], (h - 1) - b[1]
    return a, b, (w, h)


def fabscan_angles_deg(n_frames: int, steps_per_turn: int = 3200, resolution: int = 2,
                       degree_per_step: float | None = None) -> np.ndarray:
    """Rotary angles θ of a FabScan scan's pictures in this pipeline's convention, in the order taken.

    The module docstring gives FabScan's rule and the sign.

    Parameters
    ----------
    n_frames : int
        Pictures [-] (the first ``N`` of a turn are used; a file beyond them is the next turn's).
    steps_per_turn : int, default 3200
        ``turntable.steps`` of the config [-].
    resolution : {1, 2, 3}, default 2
        The scan's resolution setting (low, medium, high).
    degree_per_step : float, optional
        ``turntable.degree_per_step`` of that setting in the config (default FSConfig's) [deg].

    Returns
    -------
    (n_frames,) float64
        θ_k = −(k + 1)·360/N [deg], k = 0 … n_frames − 1.

    Raises
    ------
    CalibrationError
        An unknown resolution or a step count that gives no picture.
    """
    if degree_per_step is None:
        if resolution not in _DEGREES:
            raise CalibrationError(f"FabScan resolution setting {resolution!r}: 1, 2 or 3 (low, medium, high)")
        degree_per_step = _DEGREES[resolution]
    steps = int(degree_per_step / (360.0 / steps_per_turn))
    if steps < 1:
        raise CalibrationError(f"{degree_per_step} deg per picture is less than one of {steps_per_turn} motor steps")
    n = steps_per_turn // steps
    return -(np.arange(n_frames, dtype=np.float64) + 1.0) * 360.0 / n


def _camera(k_fab: np.ndarray, dist: np.ndarray, a: np.ndarray, b: np.ndarray) -> OpenCVCamera:
    """The camera of the stored frames: ``u = Aᵀ(p' − b)``, normalized ``x = Aᵀ x'``."""
    f_fab = np.array([k_fab[0, 0], k_fab[1, 1]])
    c_fab = np.array([k_fab[0, 2], k_fab[1, 2]])
    f = np.abs(a.T) @ f_fab                        # A is a signed permutation: the focal lengths swap
    c = a.T @ (c_fab - b)
    d = np.zeros(14)
    d[: dist.size] = dist
    p_vec = a.T @ np.array([d[3], d[2]])           # (p2, p1) turns as a vector
    d[3], d[2] = p_vec
    return OpenCVCamera(np.array([[f[0], 0.0, c[0]], [0.0, f[1], c[1]], [0.0, 0.0, 1.0]]), d)


def _numbers(table: dict, key: str, size: int | tuple, where: str = "calibration") -> np.ndarray:
    """``table[key]`` as finite float64 numbers of a shape (an int: a vector of that length), or the error."""
    if not isinstance(table, dict) or table.get(key) is None:
        raise CalibrationError(f"{where}.{key} is missing")
    try:
        a = np.asarray(table[key], np.float64)
    except (TypeError, ValueError):
        raise CalibrationError(f"{where}.{key} must be numbers, got {table[key]!r:.60}") from None
    if isinstance(size, int):
        a = a.ravel() if a.ndim <= 2 else a
    want = (size,) if isinstance(size, int) else size
    if a.shape != want:
        what = f"{size} numbers" if isinstance(size, int) else f"a {' × '.join(map(str, size))} matrix"
        raise CalibrationError(f"{where}.{key} must be {what}, got {a.size} (shape {a.shape})")
    if not np.all(np.isfinite(a)):
        raise CalibrationError(f"{where}.{key} = {numbers_text(a)} holds a value that is not a finite number")
    return a


def _laser(cal: dict, laser: int) -> tuple[np.ndarray, float, float]:
    """Laser ``laser``'s unit normal, distance [mm] and fit deviation [mm] (NaN when not given), checked."""
    planes = cal.get("laser_planes")
    if not isinstance(planes, list):
        raise CalibrationError(f"calibration.laser_planes must be a list of planes, got {planes!r:.40}")
    if not 0 <= laser < len(planes):
        raise CalibrationError(f"laser {laser} has no plane (the file holds {len(planes)} laser "
                               f"plane(s){': laser 0' if len(planes) == 1 else ''})")
    where = f"calibration.laser_planes[{laser}]"
    if not isinstance(planes[laser], dict):
        raise CalibrationError(f"{where} must be an object with normal and distance")
    normal = _numbers(planes[laser], "normal", 3, where)
    dist = float(_numbers(planes[laser], "distance", 1, where)[0])
    length = float(np.linalg.norm(normal))
    if abs(length - 1.0) > 1e-6:
        raise CalibrationError(f"{where}.normal = {numbers_text(normal)} has length {length:.6g}, not 1: FabScan's "
                               "plane normal·X = distance needs a unit normal (the distance is then in mm)")
    dev = planes[laser].get("deviation")
    deviation = math.nan if dev is None else float(_numbers(planes[laser], "deviation", 1, where)[0])
    return normal, dist, deviation


def _check_in_front(k_fab: np.ndarray, size: tuple, normal: np.ndarray, dist: float, laser: int) -> None:
    """FabScan's point of the frame's centre pixel, ``distance / (n·x) · x``, must lie in front of the camera."""
    x = np.linalg.solve(k_fab, [(size[0] - 1) / 2.0, (size[1] - 1) / 2.0, 1.0])
    z = dist / float(normal @ x) if normal @ x != 0 else math.inf
    if not (0 < z < math.inf):
        raise CalibrationError(f"calibration.laser_planes[{laser}]: the plane normal·X = distance (normal "
                               f"{numbers_text(normal)}, distance {dist:.6g} mm) lies behind the camera where the "
                               f"frame's centre looks (FabScan's point there: Z = {z:.6g} mm): the sheet a camera sees "
                               "lies in front of it; is the sign of the distance wrong?")


def _rotation(cal: dict) -> np.ndarray:
    r = _numbers(cal, "platform_rotation", (3, 3))
    err = float(np.abs(r.T @ r - np.eye(3)).max())
    if err > 1e-6 or np.linalg.det(r) < 0:
        why = f"RᵀR differs from the identity by {err:.3g}" if err > 1e-6 else "its determinant is −1 (a reflection)"
        raise CalibrationError(f"calibration.platform_rotation is not a rotation: {why} (a 3 × 3 orthonormal "
                               "matrix with determinant +1)")
    return r


def _principal_point_note(k_fab: np.ndarray, size: tuple) -> str | None:
    c = k_fab[:2, 2]
    if 0 <= c[0] <= size[0] - 1 and 0 <= c[1] <= size[1] - 1:
        return None
    return (f"FabScan's principal point ({c[0]:.6g}, {c[1]:.6g}) px lies outside its turned {size[0]} × {size[1]} "
            "frame (width × height, from camera.resolution and camera.rotate): was the camera matrix made at "
            "another resolution or orientation than camera.resolution says?")


def read_fabscan(path: str | Path, *, laser: int = 0, distortion: str = "as-fabscan") -> TargetCalibration:
    """Read FabScan's ``config.json`` as the sheet model of its frames as stored (module docstring).

    Parameters
    ----------
    path : str or Path
        FabScanPi-Server's ``config.json``.
    laser : int, default 0
        Which laser's plane (FabScan numbers them from 0).
    distortion : {"as-fabscan", "apply"}, default "as-fabscan"
        Whether the points are FabScan's (camera matrix alone) or use the calibrated distortion.

    Returns
    -------
    TargetCalibration
        Camera, laser plane, sheet frame and rotary axis in the stored frames' camera frame;
        ``tilt`` records the source (``{"mode": "fabscan", …}``).

    Raises
    ------
    CalibrationError
        Naming the field: a missing or unreadable file, no calibration in it, a missing or
        non-finite camera matrix, distortion, normal, distance, rotation or translation; a laser
        without a plane, a normal of another length than 1 (of the wrong size, zero), a plane
        behind the camera (a negative distance), a singular camera matrix, a platform rotation
        that is not one (not orthonormal, or a reflection), a turntable behind the camera, a
        missing ``camera.resolution``; an unknown ``distortion``.

    Warns
    -----
    UserWarning
        FabScan's principal point outside its turned frame (a camera matrix of another resolution).
    """
    p = Path(path)
    if distortion not in DISTORTION_USES:
        raise CalibrationError(f"distortion {distortion!r}: one of {', '.join(DISTORTION_USES)}")
    try:
        d = json.loads(p.read_text("utf-8"))
    except FileNotFoundError:
        raise CalibrationError(f"FabScan config {str(p)!r} does not exist") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CalibrationError(f"FabScan config {str(p)!r} is unreadable: {exc}") from None
    if not is_fabscan_config(d):
        raise CalibrationError(f"{str(p)!r} is no FabScan config.json (no calibration.laser_planes)")
    try:
        return _from_config(d, laser, distortion, str(p))
    except CalibrationError as exc:
        raise CalibrationError(f"FabScan config {str(p)!r}: {exc}") from None
    except (KeyError, TypeError, ValueError, IndexError, np.linalg.LinAlgError) as exc:
        raise CalibrationError(f"FabScan config {str(p)!r} garbles a field: {exc}") from None


def _resolution(camera: dict) -> tuple[int, int]:
    res = camera.get("resolution") if isinstance(camera, dict) else None
    res = res if isinstance(res, dict) else {}
    if not all(isinstance(res.get(k), int) and not isinstance(res.get(k), bool) and 0 < res[k] <= MAX_SIDE_PX
               for k in ("width", "height")):
        raise CalibrationError("camera.resolution needs the frames' width and height [px] (the size the camera "
                               "stores, before FabScan turns them)")
    return int(res["width"]), int(res["height"])


def _from_config(d: dict, laser: int, distortion: str, where: str) -> TargetCalibration:
    cal, camera = d["calibration"], d.get("camera") or {}
    width, height = _resolution(camera)
    a, b, turned = pixel_map(width, height, _flag(camera, "rotate"), _flag(camera, "hflip"), _flag(camera, "vflip"))
    k_fab = OpenCVCamera(_numbers(cal, "camera_matrix", (3, 3)), np.zeros(5)).camera_matrix   # checked as given
    dist = np.asarray(cal.get("distortion_vector") or [], np.float64).ravel()
    if dist.size:
        dist = _numbers(cal, "distortion_vector", dist.size)
    cam = _camera(k_fab, dist if distortion == "apply" else np.zeros(0), a, b)
    normal, dist_mm, deviation = _laser(cal, laser)
    _check_in_front(k_fab, turned, normal, dist_mm, laser)
    r, t = _rotation(cal), _numbers(cal, "platform_translation", 3)
    if not t[2] > 0:
        raise CalibrationError(f"calibration.platform_translation = {numbers_text(t)} puts the turntable at Z = "
                               f"{t[2]:.6g} mm, not in front of the camera")
    note = _principal_point_note(k_fab, turned)
    if note:
        warnings.warn(f"{where}: {note}", stacklevel=4)
    m = np.eye(3)
    m[:2, :2] = a.T
    plane = check_laser_plane([*(m @ normal), -dist_mm], f"laser {laser}'s plane")
    w = m @ r[:, 2]
    origin, e_s, e_h = sheet_frame_from_plane(plane, axis_dir=w, axis_up=True)
    axis = axis_in_sheet(m @ t, w, plane, e_s, e_h, origin)
    tilt = {"mode": "fabscan", "laser": int(laser), "distortion": distortion,
            "laser_plane_deviation_mm": deviation, "orientation": {
                "rotate": _flag(camera, "rotate"), "hflip": _flag(camera, "hflip"), "vflip": _flag(camera, "vflip")},
            "turntable": {k: (d.get("turntable") or {}).get(k) for k in ("steps", "radius", "height")}}
    return TargetCalibration(camera=cam, homography=np.column_stack([e_s, e_h, origin]), columns=width,
                             rows=height, n_frames=0, laser_plane=plane, pattern="fabscan config.json",
                             laser_plane_rms_mm=deviation, axis=axis, tilt=tilt)
