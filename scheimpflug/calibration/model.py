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
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from scheimpflug.errors import CalibrationError

__all__ = [
    "MODELS",
    "SheetModel",
    "check_laser_plane",
    "metric_error",
    "plane_from_sheet_frame",
    "sheet_frame_from_plane",
]

#: The calibration models a calibration file's ``"model"`` may name.
MODELS = ("paper", "general", "target")

_UNIT_TOL = 1e-6      # a laser plane's normal may differ from unit length by this much [-]


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
        raise CalibrationError(f"{what} must be 4 finite numbers [a, b, c, d], got {plane!r:.60}")
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
        A plane containing the optical axis's direction (the camera sees it edge-on), or an up
        direction perpendicular to the plane.
    """
    p = check_laser_plane(plane)
    n, d = p[:3], p[3]
    if abs(n[2]) < 1e-9:
        raise CalibrationError("the laser plane is parallel to the optical axis: the camera sees it edge-on")
    origin = np.array([0.0, 0.0, -d / n[2]])
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
