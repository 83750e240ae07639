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
from pathlib import Path

import numpy as np

from scheimpflug.calibration.camera import OpenCVCamera
from scheimpflug.calibration.model import check_laser_plane, sheet_frame_from_plane
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


def _laser(cal: dict, laser: int, where: str) -> tuple[np.ndarray, float, float]:
    planes = cal.get("laser_planes") or []
    if not isinstance(planes, list) or not (0 <= laser < len(planes)):
        raise CalibrationError(f"{where}: laser {laser} has no plane (the file holds {len(planes)} laser "
                               f"plane(s){': laser 0' if len(planes) == 1 else ''})")
    p = planes[laser]
    normal = np.asarray(p["normal"], np.float64).ravel()
    dist = float(p["distance"])
    return normal, dist, float(p.get("deviation", math.nan))


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
        A missing or unreadable file, no calibration in it, a laser without a plane, a non-unit
        normal (naming it), a singular camera matrix, an unknown ``distortion``.
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
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise CalibrationError(f"FabScan config {str(p)!r} lacks or garbles a field: {exc!r}") from None


def _from_config(d: dict, laser: int, distortion: str, where: str) -> TargetCalibration:
    cal, camera = d["calibration"], d.get("camera") or {}
    res = camera.get("resolution") or {}
    if not all(isinstance(res.get(k), int) and res[k] > 0 for k in ("width", "height")):
        raise CalibrationError("camera.resolution needs the frames' width and height [px] (the size the camera "
                               "stores, before FabScan turns them)")
    width, height = int(res["width"]), int(res["height"])
    a, b, _ = pixel_map(width, height, _flag(camera, "rotate"), _flag(camera, "hflip"), _flag(camera, "vflip"))
    k_fab = OpenCVCamera(np.asarray(cal["camera_matrix"], np.float64), np.zeros(5)).camera_matrix   # checked as given
    dist = np.asarray(cal.get("distortion_vector") or [], np.float64).ravel()
    cam = _camera(k_fab, dist if distortion == "apply" else np.zeros(0), a, b)
    m = np.eye(3)
    m[:2, :2] = a.T
    normal, dist_mm, deviation = _laser(cal, laser, where)
    plane = check_laser_plane([*(m @ normal), -dist_mm], f"laser {laser}'s plane")
    r = np.asarray(cal["platform_rotation"], np.float64)
    t = np.asarray(cal["platform_translation"], np.float64).ravel()
    if r.shape != (3, 3) or not np.allclose(r.T @ r, np.eye(3), atol=1e-6) or t.size != 3:
        raise CalibrationError("platform_rotation must be a 3 × 3 rotation and platform_translation 3 numbers")
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
