"""A printed pattern's pose in one real frame, and a laser line on it, in a calibration's camera frame.

What a camera-and-sheet scanner's laser-on-pattern frames give (Ciclop/Horus: the pattern on
the turntable, a laser-off and a laser-on frame per turntable angle; issue 36 item 6):

* :func:`board_pose` — ``camera_from_pattern`` of the pattern a frame shows: its corners
  (:func:`scheimpflug.calibration.measure.detect_pattern`, ``cv2.cornerSubPix``) and
  ``cv2.solvePnP`` with the calibration's camera matrix and distortion.  A dim laser-off
  frame is tried at gains ×1, ×2, ×4, ×8 (clipped to 8 bits) until the whole board is found;
  the gain used is returned.
* :func:`board_line_points` — the laser line's points on the pattern: the stripe of a
  laser-minus-background frame (:func:`scheimpflug.stripe.extract_stripes`, one centre per
  row, within a column range that holds one laser's line), each pixel's ray
  (``cv2.undistortPoints``) met with the pattern's plane, kept where it falls on the printed
  squares.
* :func:`fit_line_3d`, :func:`plane_through_line` — a line's straight 3-D fit, and the plane through
  it and a chosen emitter position (one pose: the choice of the emitter is the plane's).
* :func:`plane_of_lines` — the laser's plane from its lines on two poses or more (least squares,
  the normal the smallest singular vector): with one pose the plane is not determined (any plane
  through the line gives the same line on that board).

Frames: the calibration's OpenCV camera frame (x along the columns, y down the rows, z forward)
[mm]; the pattern frame of :meth:`scheimpflug.calibration.pattern.PatternSpec.object_points`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from scheimpflug.errors import CalibrationError

__all__ = ["BoardLine", "board_line_points", "board_pose", "camera_of_calibration", "fit_line_3d", "frame_poses",
           "plane_of_lines", "plane_through_line"]

#: Gains tried on a frame where the pattern is not found as recorded (a dim laser-off frame).
POSE_GAINS = (1.0, 2.0, 4.0, 8.0)


@dataclass(frozen=True)
class BoardLine:
    """A laser line's points on a pattern (:func:`board_line_points`).

    Parameters
    ----------
    points_mm : (n, 3) ndarray float64
        The points in the camera frame [mm].
    uv_px : (n, 2) ndarray float64
        Their image positions (column u, row v) [px].
    print_xy_mm : (n, 2) ndarray float64
        Their positions on the print (pattern frame x, y) [mm].
    """

    points_mm: np.ndarray
    uv_px: np.ndarray
    print_xy_mm: np.ndarray


def board_pose(frame, camera_matrix, dist_coeffs, spec) -> tuple[np.ndarray, float, float]:
    """The pattern's pose in one frame.

    Parameters
    ----------
    frame : (rows, columns) array_like
        One channel of the frame [DN] (a uint16 frame is read as 8 bits, / 257).
    camera_matrix : (3, 3) array_like float
        The calibration's K [px].
    dist_coeffs : array_like float
        Its distortion (OpenCV's order).
    spec : PatternSpec
        The pattern (:func:`scheimpflug.calibration.pattern.parse_pattern`).

    Returns
    -------
    camera_from_pattern : (4, 4) ndarray float64
        The pattern frame in the camera frame [mm].
    gain : float
        The gain at which the whole pattern was found (:data:`POSE_GAINS`) [-].
    rms_px : float
        Reprojection RMS of its corners [px].

    Raises
    ------
    CalibrationError
        When the whole pattern is found at none of the gains.
    """
    import cv2

    from scheimpflug.calibration.measure import detect_pattern

    f = np.asarray(frame, np.float64) / (257.0 if np.asarray(frame).dtype == np.uint16 else 1.0)
    k = np.asarray(camera_matrix, np.float64)
    d = np.asarray(dist_coeffs, np.float64).ravel()
    for gain in POSE_GAINS:
        det = detect_pattern(np.clip(f * gain, 0, 255).astype(np.uint8), spec, refine="subpix")
        if det is not None and len(det) == len(spec.corner_ids()):
            break
    else:
        raise CalibrationError(f"the pattern {spec.text} is not found whole in the frame at gains "
                               f"{', '.join(f'{g:g}' for g in POSE_GAINS)}")
    obj = spec.object_points()[det.ids].astype(np.float64)
    ok, rv, tv = cv2.solvePnP(obj, det.corners_px.astype(np.float64), k, d)
    if not ok:
        raise CalibrationError("solvePnP found no pose for the pattern's corners")
    proj, _ = cv2.projectPoints(obj, rv, tv, k, d)
    rms = float(np.sqrt(np.mean(np.sum((proj[:, 0] - det.corners_px) ** 2, axis=1))))
    m = np.eye(4)
    m[:3, :3] = cv2.Rodrigues(rv)[0]
    m[:3, 3] = tv.ravel()
    return m, float(gain), rms


def board_line_points(laser_minus_background, camera_matrix, dist_coeffs, camera_from_pattern, spec,
                      columns_px: tuple[float, float], *, detector: str = "cog") -> BoardLine:
    """One laser's line on the pattern, from a laser-minus-background frame (module docstring).

    Parameters
    ----------
    laser_minus_background : (rows, columns) array_like float
        Laser frame minus its laser-off frame, one channel [DN]; the line runs down the image.
    camera_matrix, dist_coeffs : array_like
        The calibration's camera.
    camera_from_pattern : (4, 4) array_like float
        The pattern's pose (:func:`board_pose`) [mm].
    spec : PatternSpec
        The pattern.
    columns_px : (float, float)
        The column range [lo, hi) holding this laser's line (the frame is zeroed outside it) [px].
    detector : str, default "cog"
        Stripe centre method (:data:`scheimpflug.stripe.METHODS`).

    Returns
    -------
    BoardLine
        The points that fall on the printed squares (:meth:`PatternSpec.extent_mm`).
    """
    import cv2

    from scheimpflug.stripe import extract_stripes

    f = np.clip(np.asarray(laser_minus_background, np.float64), 0.0, None)
    lo, hi = (int(math.floor(columns_px[0])), int(math.ceil(columns_px[1])))
    masked = np.zeros_like(f)
    masked[:, max(lo, 0):hi] = f[:, max(lo, 0):hi]
    prof = extract_stripes(masked, detector, window_px="auto", saturation_dn=None)
    uv = np.column_stack([prof.u, prof.rows.astype(np.float64)])
    m = np.asarray(camera_from_pattern, np.float64)
    xy = cv2.undistortPoints(uv[:, None, :], np.asarray(camera_matrix, np.float64),
                             np.asarray(dist_coeffs, np.float64).ravel())[:, 0]
    ray = np.column_stack([xy, np.ones(len(xy))])
    normal = m[:3, 2]
    points = ray * ((normal @ m[:3, 3]) / (ray @ normal))[:, None]
    local = (points - m[:3, 3]) @ m[:3, :3]
    x0, y0, x1, y1 = spec.extent_mm()
    on = (local[:, 0] >= x0) & (local[:, 0] <= x1) & (local[:, 1] >= y0) & (local[:, 1] <= y1)
    return BoardLine(points[on], uv[on], local[on, :2])


def plane_of_lines(lines) -> tuple[np.ndarray, float, float]:
    """The plane through a laser's lines on two poses or more (least squares).

    Parameters
    ----------
    lines : sequence of BoardLine
        The same laser's line on each pose.

    Returns
    -------
    normal : (3,) ndarray float64
        Unit normal, signed so that ``normal · X = distance`` with distance > 0 (camera frame).
    distance_mm : float
        The plane's distance from the camera's centre [mm].
    rms_mm : float
        RMS distance of the points from the plane [mm].

    Raises
    ------
    CalibrationError
        Fewer than two lines, or lines that do not span a plane (all on one line).
    """
    if len(lines) < 2:
        raise CalibrationError("a laser plane needs its line on 2 poses or more: one line lies in every plane "
                               "through it")
    p = np.concatenate([np.asarray(ln.points_mm, np.float64) for ln in lines])
    c = p.mean(axis=0)
    _, s, vt = np.linalg.svd(p - c, full_matrices=False)
    if not s[1] > 1e-3 * s[0]:
        raise CalibrationError("the lines lie on one straight line: they do not determine a plane")
    n = vt[2]
    dist = float(n @ c)
    if dist < 0:
        n, dist = -n, -dist
    return n, dist, float(np.sqrt(np.mean(((p - c) @ vt[2]) ** 2)))


def fit_line_3d(line: BoardLine, *, reject_mm: float = 1.0) -> tuple[np.ndarray, np.ndarray, float]:
    """A straight 3-D line through a laser line's points (least squares, points beyond ``reject_mm`` dropped once).

    Parameters
    ----------
    line : BoardLine
        The points.
    reject_mm : float, default 1.0
        Points farther than this from the first fit are left out of the second [mm].

    Returns
    -------
    point : (3,) ndarray float64
        The points' centroid [mm].
    direction : (3,) ndarray float64
        Unit direction.
    rms_mm : float
        RMS distance of the kept points from the line [mm].

    Raises
    ------
    CalibrationError
        Fewer than 3 points.
    """
    p = np.asarray(line.points_mm, np.float64)
    if len(p) < 3:
        raise CalibrationError(f"a laser line needs 3 points or more on the pattern, got {len(p)}")
    keep = np.ones(len(p), bool)
    for _ in range(2):
        c = p[keep].mean(axis=0)
        w = np.linalg.svd(p[keep] - c, full_matrices=False)[2][0]
        dev = (p - c) - np.outer((p - c) @ w, w)
        dist = np.linalg.norm(dev, axis=1)
        keep = dist <= reject_mm
    return c, w, float(np.sqrt(np.mean(dist[keep] ** 2)))


def plane_through_line(point, direction, emitter_mm) -> tuple[np.ndarray, float]:
    """The plane through a 3-D line and an emitter's position.

    Parameters
    ----------
    point, direction : (3,) array_like float
        The line (:func:`fit_line_3d`) [mm].
    emitter_mm : (3,) array_like float
        The laser's emitter (not on the line) [mm].

    Returns
    -------
    normal : (3,) ndarray float64
        Unit normal with ``normal · X = distance`` > 0.
    distance_mm : float
        [mm].

    Raises
    ------
    CalibrationError
        An emitter on the line (no plane).
    """
    c, w, e = (np.asarray(x, np.float64) for x in (point, direction, emitter_mm))
    n = np.cross(w, e - c)
    norm = float(np.linalg.norm(n))
    if not norm > 1e-9 * max(1.0, float(np.linalg.norm(e - c))):
        raise CalibrationError("the emitter lies on the laser's line: it does not choose a plane")
    n = n / norm
    dist = float(n @ c)
    return (n, dist) if dist > 0 else (-n, -dist)


def camera_of_calibration(path) -> tuple[np.ndarray, np.ndarray]:
    """The camera matrix and distortion of a calibration JSON file (``camera_matrix``, ``dist_coeffs``).

    Parameters
    ----------
    path : str or Path
        A target calibration (``scheimpflug calibrate --out``) or an OpenCV calibration (JSON).

    Returns
    -------
    camera_matrix : (3, 3) ndarray float64
        [px].
    dist_coeffs : (n,) ndarray float64
        OpenCV's order.

    Raises
    ------
    CalibrationError
        Unreadable, or without the two keys.
    """
    import json
    from pathlib import Path

    try:
        d = json.loads(Path(path).read_text("utf-8"))
        k = np.asarray(d["camera_matrix"], np.float64)
        dist = np.asarray(d["dist_coeffs"], np.float64).ravel()
    except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError) as exc:
        raise CalibrationError(f"calibration {str(path)!r}: a JSON file with camera_matrix and dist_coeffs is "
                               f"needed ({type(exc).__name__}: {exc})") from None
    if k.shape != (3, 3) or not np.isfinite(k).all() or not np.isfinite(dist).all():
        raise CalibrationError(f"calibration {str(path)!r}: camera_matrix must be 3 × 3 finite numbers")
    return k, dist


def frame_poses(files, calibration, pattern: str, channel: str = "gray") -> list[np.ndarray]:
    """``camera_from_pattern`` of the pattern in each of some real frames (:func:`board_pose`).

    Parameters
    ----------
    files : sequence of str or Path
        Frames showing the whole pattern (a laser-off frame will do; a dim one is brightened).
    calibration : str or Path
        The camera's calibration (:func:`camera_of_calibration`).
    pattern : str
        The pattern spec (``chessboard:11x6:13``).
    channel : str, default "gray"
        For colour files (:func:`scheimpflug.io.importer.read_image`).

    Returns
    -------
    list of (4, 4) ndarray float64
        Per file, the pattern frame in the calibration's camera frame [mm].

    Raises
    ------
    CalibrationError
        A bad calibration, or a frame where the whole pattern is not found (naming it).
    FrameError
        An unreadable frame.
    """
    from scheimpflug.calibration.pattern import parse_pattern
    from scheimpflug.io.importer import read_image

    k, dist = camera_of_calibration(calibration)
    spec = parse_pattern(pattern)
    out = []
    for f in files:
        try:
            out.append(board_pose(read_image(f, channel), k, dist, spec)[0])
        except CalibrationError as exc:
            raise CalibrationError(f"{str(f)!r}: {exc}") from None
    return out
