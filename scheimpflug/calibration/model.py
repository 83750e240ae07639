"""The sheet-model interface every calibration implements, and the sheet's frame in the camera frame.

A calibration of a light-sheet profiler is a *sheet model*: the mapping
between a pixel and the point of the laser sheet it sees.  Three methods make
one (:data:`MODELS`): the paper's form (:mod:`scheimpflug.calibration.paper`,
Eqs. 11–12), the general model (:mod:`scheimpflug.calibration.general`,
homography ∘ distortion) and the target calibration
(:mod:`scheimpflug.calibration.target`, a camera and a laser plane from a
printed pattern); a foreign calibration (an OpenCV camera and laser plane,
FabScan's ``config.json``) reads as one too (:mod:`scheimpflug.calibration.load`).
Every consumer (reconstruction, the axis locator, the acceptance test, the
OpenCV export) sees only :class:`SheetModel`.

Sheet coordinates
-----------------
A point of the sheet is ``(s, h)`` [mm]: ``s`` the stage coordinate along the
laser's propagation, ``h`` the height (docs/reference/interface.md stage
conventions).  In OpenCV's camera frame (x right along the columns, y down
along the rows, z forward) the sheet is the plane ``origin + s·e_s + h·e_h``
with ``e_s ⟂ e_h`` unit vectors (a metric plane: lengths in ``(s, h)`` are
lengths in the camera frame).  The paper's and the general model's frame comes
from the translation stage (one stage millimetre is one millimetre of ``e_s``;
``h = 0`` on the row through the image hinge).  A calibration without a stage
knows only the plane; :func:`sheet_frame_from_plane` fixes its frame by a
rule: ``e_h`` the rotary axis's direction when one was measured, else the
image's *up* direction (−y), each projected into the plane; ``e_s = e_h × n``
turned to point away from the camera (the propagation direction of a sheet the
camera looks along); the origin where the optical axis meets the plane, so
that ``h = 0`` is the sheet's line in the plane of the optical axis — the
meridian plane of a rig whose rows are vertical.

Frame size
----------
A calibration holds for frames of one size: another binning or region of
interest maps every pixel to a wrong sheet point without any error.  Every
calibration file therefore records the frame size it was made for (``columns``
and ``rows`` [px]; the OpenCV export ``image_size`` = [columns, rows];
FabScan's ``camera.resolution``), every reader checks it
(:func:`frame_size_from_json`) and every model's ``problem(columns, rows)``
refuses frames of another size (:func:`size_problem`).  A file written before
the size was recorded still loads; applying it warns that the size cannot be
checked (:func:`unknown_size_note`).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from scheimpflug.errors import CalibrationError

__all__ = [
    "MAX_SIDE_PX",
    "MODELS",
    "SheetModel",
    "check_laser_plane",
    "frame_size_from_json",
    "metric_error",
    "numbers_text",
    "plane_from_sheet_frame",
    "sheet_frame_from_plane",
    "size_problem",
    "unknown_size_note",
]

#: The calibration models a calibration file's ``"model"`` may name.
MODELS = ("paper", "general", "target")

_UNIT_TOL = 1e-6      # a laser plane's normal may differ from unit length by this much [-]
MAX_SIDE_PX = 65535
"""Largest frame side a calibration file may record (a frame folder's limit too) [px]."""


# A Protocol is never instantiated: its (*args, **kwargs) constructor has nothing to document.
class SheetModel(Protocol):  # numpydoc ignore=PR01
    """What the pipeline needs of a calibration: pixel ↔ sheet point, in sheet and camera coordinates.

    :class:`scheimpflug.calibration.paper.Calibration`,
    :class:`scheimpflug.calibration.general.GeneralCalibration` and
    :class:`scheimpflug.calibration.target.TargetCalibration` implement it;
    reconstruction, the axis locator and the acceptance test take any of them.

    Attributes
    ----------
    columns, rows : int
        Sensor size the calibration was made with [px] (0 = unknown).
    method : str
        Which method made it (e.g. "refined", "general", "target").
    """

    columns: int
    rows: int
    method: str

    def stage_from_pixel(self, u, v) -> tuple[np.ndarray, np.ndarray]:
        """Stage coordinate and height of pixels.

        Parameters
        ----------
        u, v : array_like float
            Column and row [px].

        Returns
        -------
        stage_mm, h_mm : ndarray float64
            [mm].
        """

    def pixel_from_stage(self, stage_mm, h_mm) -> tuple[np.ndarray, np.ndarray]:
        """Pixel of sheet points.

        Parameters
        ----------
        stage_mm, h_mm : array_like float
            Stage coordinate and height [mm].

        Returns
        -------
        u_px, v_px : ndarray float64
            [px].
        """

    def camera_from_pixel(self, u, v) -> np.ndarray:
        """The sheet point a pixel sees, in OpenCV's camera frame.

        Parameters
        ----------
        u, v : array_like float
            Column and row [px].

        Returns
        -------
        (..., 3) float64
            X, Y, Z [mm].
        """

    def pixel_from_camera(self, points_mm) -> tuple[np.ndarray, np.ndarray]:
        """Pixel of camera-frame points.

        Parameters
        ----------
        points_mm : (..., 3) array_like float
            X, Y, Z [mm].

        Returns
        -------
        u_px, v_px : ndarray float64
            [px].
        """

    def to_json_dict(self) -> dict:
        """The calibration file's content.

        Returns
        -------
        dict
            JSON-ready; ``load_sheet_model`` reads it back.
        """


def check_laser_plane(plane, what: str = "laser plane") -> np.ndarray:
    """A laser plane ``[a, b, c, d]`` (``a·X + b·Y + c·Z + d = 0``, camera frame) checked.

    Parameters
    ----------
    plane : (4,) array_like float
        (a, b, c) the unit normal, d [mm].
    what : str
        Its name in the message.

    Returns
    -------
    (4,) float64
        The plane, sign chosen so that d < 0 (the normal points away from the camera).

    Raises
    ------
    CalibrationError
        Not 4 finite numbers, a normal of non-unit length (naming it: the plane's d would be in
        other units), or a plane through the camera's centre (d = 0: the camera would see it edge-on).
    """
    p = np.asarray(plane, np.float64).ravel()
    if p.size != 4 or not np.all(np.isfinite(p)):
        raise CalibrationError(f"{what} must be 4 finite numbers [a, b, c, d], got {numbers_text(plane)}")
    norm = float(np.linalg.norm(p[:3]))
    if abs(norm - 1.0) > _UNIT_TOL:
        raise CalibrationError(f"{what}'s normal (a, b, c) has length {norm:.6g}, not 1: a·X + b·Y + c·Z + d = 0 "
                               "needs a unit normal (d is then the distance from the camera in mm)")
    if abs(p[3]) < 1e-9:
        raise CalibrationError(f"{what} passes through the camera's centre (d = 0): the camera sees it edge-on")
    return p if p[3] < 0 else -p


def plane_from_sheet_frame(origin_mm, e_s, e_h) -> np.ndarray:
    """The plane ``[a, b, c, d]`` of a sheet frame (unit normal, d < 0).

    Parameters
    ----------
    origin_mm, e_s, e_h : (3,) array_like float
        The sheet's origin [mm] and its two axes in the camera frame.

    Returns
    -------
    (4,) float64
        ``n = e_s × e_h`` normalized, turned so that ``d = −n·origin < 0``.
    """
    n = np.cross(np.asarray(e_s, np.float64), np.asarray(e_h, np.float64))
    n /= np.linalg.norm(n)
    o = np.asarray(origin_mm, np.float64)
    if n @ o < 0:
        n = -n
    return np.array([*n, -float(n @ o)])


def sheet_frame_from_plane(plane, axis_dir=None, *, axis_up: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The sheet frame of a laser plane by the module docstring's rule.

    Parameters
    ----------
    plane : (4,) array_like float
        ``[a, b, c, d]`` in the camera frame (unit normal) [-, mm].
    axis_dir : (3,) array_like float, optional
        The rotary axis's direction in the camera frame (either sign: the one pointing up in the
        image is taken); default none: the image's up direction (−y).
    axis_up : bool, default False
        ``axis_dir`` points up (e.g. a turntable's z axis from its calibration): its sign is kept,
        whatever the image's orientation (a camera turned by 90° sees the axis along its rows).

    Returns
    -------
    origin_mm : (3,) float64
        Where the optical axis (the camera's z axis) meets the plane [mm].
    e_s, e_h : (3,) float64
        Orthonormal axes in the plane: stage (away from the camera) and height (up).

    Raises
    ------
    CalibrationError
        A plane containing the optical axis's direction (the camera sees it edge-on), a plane
        meeting the optical axis behind the camera (a sheet the camera sees lies in front of
        it: the sign of d is wrong), or an up direction perpendicular to the plane.
    """
    p = check_laser_plane(plane)
    n, d = p[:3], p[3]
    if abs(n[2]) < 1e-9:
        raise CalibrationError("the laser plane is parallel to the optical axis: the camera sees it edge-on")
    origin = np.array([0.0, 0.0, -d / n[2]])
    if origin[2] <= 0:
        raise CalibrationError(f"the laser plane {numbers_text(p)} meets the optical axis behind the camera "
                               f"(at Z = {origin[2]:.6g} mm): the sheet a camera sees lies in front of it; is "
                               "the sign of the plane's distance wrong?")
    up = np.array([0.0, -1.0, 0.0]) if axis_dir is None else np.asarray(axis_dir, np.float64)
    up = up - (up @ n) * n
    if np.linalg.norm(up) < 1e-6:
        raise CalibrationError("the up direction (rotary axis or image rows) is perpendicular to the laser plane")
    e_h = up / np.linalg.norm(up)
    if e_h[1] > 0 and not (axis_up and axis_dir is not None):     # up in the image: −y
        e_h = -e_h
    e_s = np.cross(e_h, n)
    if e_s[2] < 0:
        e_s = -e_s
    return origin, e_s, e_h


def metric_error(e_s, e_h) -> float:
    """How far two sheet axes are from orthonormal (0 for a metric frame) [-].

    Parameters
    ----------
    e_s, e_h : (3,) array_like float
        The axes.

    Returns
    -------
    float
        max(|‖e_s‖ − 1|, |‖e_h‖ − 1|, |e_s·e_h|).
    """
    a, b = np.asarray(e_s, np.float64), np.asarray(e_h, np.float64)
    return float(max(abs(np.linalg.norm(a) - 1.0), abs(np.linalg.norm(b) - 1.0), abs(a @ b)))


def numbers_text(values, digits: int = 6) -> str:
    """Numbers for a message: ``[0.8, nan, 0.6]`` (never ``np.float64(nan)`` or ``array(...)``).

    Parameters
    ----------
    values : array_like or object
        The numbers (any nesting); anything that is not numeric is shown by ``repr`` (cut at 60).
    digits : int, default 6
        Significant digits.

    Returns
    -------
    str
        The text.
    """
    try:
        a = np.asarray(values, np.float64)
    except (TypeError, ValueError):
        return f"{values!r:.60}"
    if a.ndim == 0:
        return f"{float(a):.{digits}g}"
    return "[" + ", ".join(numbers_text(x, digits) for x in a) + "]"


def _side(value, key: str) -> int:
    """A frame side [px]: an integer in [0, MAX_SIDE_PX] (an integral float is fine; 0 = unknown)."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise CalibrationError(f"{key} = {value!r:.40} must be a whole number of pixels")
    v = float(value)
    if not (np.isfinite(v) and v.is_integer() and 0 <= v <= MAX_SIDE_PX):
        raise CalibrationError(f"{key} = {numbers_text(v)} must be a whole number of pixels in [0, {MAX_SIDE_PX}]")
    return int(v)


def _image_size(value) -> tuple[int, int]:
    a = np.asarray(value, dtype=object).ravel() if value is not None else np.empty(0)
    if a.size != 2:
        raise CalibrationError(f"image_size must be [columns, rows], got {numbers_text(value)}")
    size = (_side(a[0], "image_size[0] (columns)"), _side(a[1], "image_size[1] (rows)"))
    if 0 in size:
        raise CalibrationError(f"image_size = {list(size)} must be two sides > 0 [px]")
    return size


def frame_size_from_json(d: dict) -> tuple[int, int]:
    """The frame size a calibration file records: ``columns`` and ``rows``, or ``image_size``.

    Parameters
    ----------
    d : dict
        The file's content (``columns``/``rows`` [px]; ``image_size`` = [columns, rows] [px];
        either or both, agreeing).

    Returns
    -------
    columns, rows : int
        [px]; (0, 0) when the file records none (written before sizes were recorded).

    Raises
    ------
    CalibrationError
        A side that is not a whole number in [0, 65535], one of ``columns``/``rows`` without
        the other, or ``image_size`` and ``columns``/``rows`` that disagree.
    """
    cols, rows = d.get("columns"), d.get("rows")
    if (cols is None) != (rows is None):
        given = "columns" if rows is None else "rows"
        raise CalibrationError(f"the calibration gives {given} but not {'rows' if rows is None else 'columns'}: "
                               "the frame size needs both")
    size = (0, 0) if cols is None else (_side(cols, "columns"), _side(rows, "rows"))
    if (size[0] == 0) != (size[1] == 0):
        raise CalibrationError(f"columns = {size[0]}, rows = {size[1]}: a frame size needs both sides > 0 "
                               "(or both 0: unknown)")
    if d.get("image_size") is None:
        return size
    image = _image_size(d["image_size"])
    if all(size) and image != size:
        raise CalibrationError(f"image_size {list(image)} and columns × rows {size[0]} × {size[1]} disagree")
    return image


def size_problem(model, columns: int | None, rows: int | None) -> str | None:
    """Why a calibration does not fit frames of this size, or None (also when either size is unknown).

    Parameters
    ----------
    model : SheetModel
        The calibration (``columns``, ``rows``; 0 = unknown).
    columns, rows : int or None
        The frames' size [px] (None: unknown).

    Returns
    -------
    str or None
        Both sizes (rows × columns) and, when the sides scale alike, the binning it suggests.
    """
    cal = (int(getattr(model, "rows", 0) or 0), int(getattr(model, "columns", 0) or 0))
    if not (all(cal) and columns and rows) or cal == (rows, columns):
        return None
    ratio = columns / cal[1]                       # binning grows as the image shrinks
    hint = f" (a calibration made at {ratio:g} × this binning)" if ratio == rows / cal[0] else ""
    return (f"the calibration was made for {cal[0]} × {cal[1]} frames, the frames are {rows} × {columns} "
            f"(rows × columns){hint}")


def unknown_size_note(columns: int, rows: int) -> str:
    """The warning for a calibration that records no frame size (a file of an earlier version).

    Parameters
    ----------
    columns, rows : int
        The frames' size [px].

    Returns
    -------
    str
        What cannot be checked and how to fix it.
    """
    return (f"the calibration records no frame size (a file written before the size was recorded, or a "
            f"foreign one without image_size): whether it was made for these {rows} × {columns} frames "
            "(rows × columns) cannot be checked, and one of another binning gives wrong points without "
            "an error; add \"columns\" and \"rows\" (or \"image_size\": [columns, rows]) to the file, "
            "or calibrate again")
