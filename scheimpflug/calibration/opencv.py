"""The instrument as OpenCV users hold it: camera matrix, distortion with τx, τy, laser plane.

``scheimpflug calibrate DIR --opencv FILE.json`` (docs/reference/interface.md "OpenCV
export") writes::

    {"camera_matrix": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]],
     "dist_coeffs": [k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4, tau_x, tau_y],
     "image_size": [columns, rows],
     "laser_plane": [a, b, c, d],
     "sheet_frame": {"origin_mm": [X, Y, Z], "stage_axis": [...], "height_axis": [...]},
     "model": "paper" | "general", "assumptions": {...}, "format": "scheimpflug-opencv/1"}

in OpenCV's camera frame (x right along the columns, y down along the rows,
z forward; :mod:`scheimpflug.calibration.camera`).  ``cv2.projectPoints`` of a
sheet point ``X = origin + s·stage_axis + h·height_axis`` (stage coordinate
``s``, height ``h`` [mm]) with ``rvec = tvec = 0`` gives the pixel the
pipeline's calibration gives; a pixel's ray (``cv2.undistortPoints``) meets
the laser plane ``a·X + b·Y + c·Z + d = 0`` ((a, b, c) a unit vector, d < 0,
lengths in mm) at that point.  A ``.yml``, ``.yaml`` or ``.xml`` name writes
the same keys with ``cv2.FileStorage``.

What is assumed
---------------
A calibration fixes the pixel ↔ sheet mapping, a plane-to-plane homography
(with distortion).  A camera matrix and a pose hold more: no homography tells
the focal length, the pixel pitch or where the optical axis is.  The paper
form is decomposed into the ideal Scheimpflug rig with the rig's focal length
``f`` and pixel pitch ``p`` (:func:`scheimpflug.calibration.camera.ideal_camera`):
``fx = fy`` is then the sensor's distance from the lens centre along the
optical axis over ``p`` (≈ d·tan β / p, not f / p: the sensor of a Scheimpflug
rig sits beyond the focal plane), ``(cx, cy)`` where the optical axis meets the
sensor, ``τy = β`` and ``τx = 0``.  The general model carries its own
intrinsics (the same decomposition, its principal point and distance refined
with the distortion: :mod:`scheimpflug.calibration.general`); the target
calibration its own camera and laser plane (:mod:`scheimpflug.calibration.target`).  The metric scale of the
camera frame is set by the stage: one stage millimetre is one millimetre of
``stage_axis``.  For both models the sheet is a metric plane in the camera
frame — ``stage_axis`` and ``height_axis`` are orthonormal — so that a point
measured through OpenCV (``undistortPoints`` ∩ ``laser_plane``) lies at the
pipeline's ``(s, h)`` and lengths in the camera frame are lengths on the sheet,
with a distorting lens too (before issue 25 the general model's sheet axes were
those of a free homography: 0.1–0.3 % apart in length on a k1 = −0.05 … −0.2
twin).  Other intrinsics reproduce the same pixels with another plane; these are
the physical ones when ``f`` and ``p`` are right.

Reading one back (:func:`read_opencv`) gives the same mapping.  A foreign OpenCV
calibration — ``camera_matrix``, ``dist_coeffs`` (any of OpenCV's lengths, every
term) and ``laser_plane``, without a ``sheet_frame`` — reads as a sheet model too;
its sheet frame follows the rule of :func:`scheimpflug.calibration.model.sheet_frame_from_plane`.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from scheimpflug.calibration.camera import (
    DEFAULT_FOCAL_LENGTH_MM,
    DEFAULT_PIXEL_PITCH_UM,
    OpenCVCamera,
    TiltedCamera,
    ideal_camera,
)
from scheimpflug.calibration.general import GeneralCalibration
from scheimpflug.calibration.model import (
    check_laser_plane,
    frame_size_from_json,
    metric_error,
    sheet_frame_from_plane,
)
from scheimpflug.errors import CalibrationError
from scheimpflug.io.atomic import atomic_path, write_json_atomic

__all__ = ["FORMAT", "YAML_SUFFIXES", "as_general", "opencv_dict", "read_opencv", "write_opencv"]

FORMAT = "scheimpflug-opencv/1"
#: File suffixes written and read through ``cv2.FileStorage`` (anything else is JSON).
YAML_SUFFIXES = (".yml", ".yaml", ".xml")


def as_general(calibration, focal_length_mm: float = DEFAULT_FOCAL_LENGTH_MM,
               pixel_pitch_um: float = DEFAULT_PIXEL_PITCH_UM) -> GeneralCalibration:
    """Any calibration as a camera + sheet homography (the paper form decomposed, module docstring).

    Parameters
    ----------
    calibration : Calibration or GeneralCalibration
        The calibration.
    focal_length_mm, pixel_pitch_um : float
        Focal length [mm] and pixel pitch [µm] assumed for the paper form's decomposition.

    Returns
    -------
    GeneralCalibration
        The same pixel mapping (exactly, for the paper form: no distortion).
    """
    if isinstance(calibration, GeneralCalibration):
        return calibration
    camera, g = ideal_camera(calibration, focal_length_mm, pixel_pitch_um)
    return GeneralCalibration(camera=camera, homography=g, columns=calibration.columns,
                              rows=calibration.rows, plate_height_mm=calibration.plate_height_mm,
                              n_frames=calibration.n_frames, paper=calibration)


def opencv_dict(calibration, focal_length_mm: float = DEFAULT_FOCAL_LENGTH_MM,
                pixel_pitch_um: float = DEFAULT_PIXEL_PITCH_UM, assumed: bool = False) -> dict[str, Any]:
    """The OpenCV export of a calibration (module docstring), JSON-ready.

    Parameters
    ----------
    calibration : Calibration or GeneralCalibration
        The calibration.
    focal_length_mm, pixel_pitch_um : float
        Focal length [mm] and pixel pitch [µm] of the decomposition.
    assumed : bool
        Whether f and p were assumed (no rig given); written to ``assumptions``.

    Returns
    -------
    dict
        ``camera_matrix``, ``dist_coeffs`` (14), ``image_size`` ([columns, rows]; None for a
        calibration that records no frame size), ``laser_plane``, ``sheet_frame``
        (with ``metric_error``: how far its axes are from orthonormal, 0 to rounding for a
        calibration of this version; a general model written before issue 25 shows its
        0.1–0.3 %), ``model``, ``assumptions``, ``format``.
    """
    gen = as_general(calibration, focal_length_mm, pixel_pitch_um)
    mu = gen.metric_scale()
    g = gen.homography
    origin, e_s, e_h = mu * g[:, 2], mu * g[:, 0], mu * g[:, 1]
    n = np.cross(e_s, e_h)
    n /= np.linalg.norm(n)
    if n @ origin < 0:
        n = -n
    model = ("target" if getattr(calibration, "method", "") == "target" else
             "general" if isinstance(calibration, GeneralCalibration) else "paper")
    return {"format": FORMAT, "model": model,
            "camera_matrix": gen.camera.camera_matrix.tolist(),
            "dist_coeffs": gen.camera.dist_coeffs.tolist(),
            "image_size": [int(gen.columns), int(gen.rows)] if gen.columns and gen.rows else None,
            "laser_plane": [*map(float, n), float(-n @ origin)],
            "sheet_frame": {"origin_mm": origin.tolist(), "stage_axis": e_s.tolist(),
                            "height_axis": e_h.tolist(),
                            "metric_error": metric_error(e_s, e_h)},
            "assumptions": {"focal_length_mm": focal_length_mm, "pixel_pitch_um": pixel_pitch_um,
                            "source": "assumed (no rig given)" if assumed else "rig",
                            "metric_scale": "one stage millimetre = one millimetre of stage_axis"}}


def write_opencv(path: str | Path, calibration, focal_length_mm: float = DEFAULT_FOCAL_LENGTH_MM,
                 pixel_pitch_um: float = DEFAULT_PIXEL_PITCH_UM, assumed: bool = False) -> dict[str, Any]:
    """Write the OpenCV export to ``path`` atomically (JSON, or YAML/XML by ``cv2.FileStorage``).

    Parameters
    ----------
    path : str or Path
        Output file; ``.yml``, ``.yaml`` or ``.xml`` use ``cv2.FileStorage``, anything else JSON.
    calibration : Calibration or GeneralCalibration
        The calibration.
    focal_length_mm, pixel_pitch_um : float
        Focal length [mm] and pixel pitch [µm] of the decomposition.
    assumed : bool
        Whether f and p were assumed.

    Returns
    -------
    dict
        What was written (:func:`opencv_dict`).

    Raises
    ------
    CalibrationError
        A calibration that records no frame size: the export must say which frames it holds for.
    """
    d = opencv_dict(calibration, focal_length_mm, pixel_pitch_um, assumed)
    if d["image_size"] is None:
        raise CalibrationError(f"{str(path)!r}: the calibration records no frame size (columns × rows): an "
                               "OpenCV export must carry the image_size its frames had")
    p = Path(path)
    if p.suffix.lower() not in YAML_SUFFIXES:
        write_json_atomic(p, d)
        return d
    with atomic_path(p) as tmp:
        fs = cv2.FileStorage(str(tmp), cv2.FILE_STORAGE_WRITE)
        for key in ("camera_matrix", "dist_coeffs", "image_size", "laser_plane"):
            fs.write(key, np.asarray(d[key], np.float64))
        for key in ("origin_mm", "stage_axis", "height_axis"):
            fs.write(f"sheet_{key}", np.asarray(d["sheet_frame"][key], np.float64))
        fs.write("model", d["model"])
        fs.release()
    return d


def _read_any(p: Path) -> dict:
    if p.suffix.lower() not in YAML_SUFFIXES:
        d = json.loads(p.read_text("utf-8"))
        if not isinstance(d, dict):
            raise ValueError("not a JSON object")
        return d
    fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_READ)
    if not fs.isOpened():
        raise ValueError("cv2.FileStorage cannot open it")
    mat = lambda k: fs.getNode(k).mat()  # noqa: E731
    d = {k: mat(k) for k in ("camera_matrix", "dist_coeffs", "image_size", "laser_plane")}
    frame = {k: mat(f"sheet_{k}") for k in ("origin_mm", "stage_axis", "height_axis")}
    fs.release()
    if all(v is not None for v in frame.values()):
        d["sheet_frame"] = frame
    return d


def _camera(K: np.ndarray, dist: np.ndarray):
    """OpenCV's camera: a TiltedCamera where it is one (square pixels, k1, k2, τ), else an OpenCVCamera."""
    cam = OpenCVCamera(K, dist)
    d = cam.dist_coeffs
    square = abs(K[0, 0] - K[1, 1]) <= 1e-9 * abs(K[0, 0])
    if square and not np.any(np.delete(d, [0, 1, 12, 13])):
        return TiltedCamera(float(K[0, 0]), (float(K[0, 2]), float(K[1, 2])), float(d[12]),
                            float(d[13]), float(d[0]), float(d[1]))
    return cam


def _sheet_homography(d: dict, plane: np.ndarray) -> np.ndarray:
    """G = [stage_axis, height_axis, origin] of the file's sheet frame, or of the plane's rule."""
    sf = d.get("sheet_frame")
    if sf is None:
        origin, e_s, e_h = sheet_frame_from_plane(plane)
        return np.column_stack([e_s, e_h, origin])
    return np.column_stack([np.asarray(sf[k], np.float64).ravel()
                            for k in ("stage_axis", "height_axis", "origin_mm")])


def read_opencv(path: str | Path) -> GeneralCalibration:
    """Read an OpenCV calibration as a sheet model (an export of ours gives the same mapping back).

    Parameters
    ----------
    path : str or Path
        A file written by :func:`write_opencv` (JSON, YAML or XML), or any JSON with
        ``camera_matrix``, ``dist_coeffs`` and ``laser_plane`` (module docstring); ``image_size``
        [columns, rows] (the frames it holds for) is read and checked where the file has it.

    Returns
    -------
    GeneralCalibration
        Camera and sheet homography ``G = [stage_axis, height_axis, origin]``; ``columns``,
        ``rows`` from ``image_size`` (0 without one: applying it warns that the size cannot be
        checked, :func:`scheimpflug.calibration.paper.applicability_problem`).

    Raises
    ------
    CalibrationError
        A missing or unreadable file, a missing key (named), a singular or non-finite camera matrix, a
        non-finite distortion term (named), a laser plane with a non-unit normal or behind the camera,
        a malformed ``image_size``, or a sheet frame off the laser plane.
    """
    p = Path(path)
    if not p.is_file():
        raise CalibrationError(f"OpenCV calibration {str(p)!r} does not exist")
    try:
        d = _read_any(p)
        missing = [k for k in ("camera_matrix", "dist_coeffs", "laser_plane") if d.get(k) is None]
        if missing:
            raise CalibrationError(f"the key{'s' * (len(missing) > 1)} {', '.join(missing)} "
                                   f"{'are' if len(missing) > 1 else 'is'} missing (camera_matrix, dist_coeffs "
                                   "and laser_plane are needed)")
        columns, rows = frame_size_from_json({"image_size": d.get("image_size")})
        cam = _camera(np.asarray(d["camera_matrix"], np.float64),
                      np.asarray(d["dist_coeffs"], np.float64).ravel())
        plane = check_laser_plane(d["laser_plane"])
        g = _sheet_homography(d, plane)
    except CalibrationError as exc:
        raise CalibrationError(f"OpenCV calibration {str(p)!r}: {exc}") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, KeyError, TypeError, ValueError,
            cv2.error) as exc:
        raise CalibrationError(f"OpenCV calibration {str(p)!r}: {exc}") from None
    off = abs(plane[:3] @ g[:, 2] + plane[3])
    if g.shape != (3, 3) or not math.isfinite(off) or off > 1e-6 * max(1.0, abs(plane[3])):
        raise CalibrationError(f"OpenCV calibration {str(p)!r}: the sheet frame's origin is not on the "
                               f"laser plane (off by {off:.3g} mm)")
    return GeneralCalibration(camera=cam, homography=g / g[2, 2], columns=columns, rows=rows)
