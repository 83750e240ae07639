"""Calibration without a translation stage: a printed pattern in several poses and the laser line on it.

What every open laser-line scanner and the industrial sheet-of-light tools do
(Horus/Ciclop, FabScan, HALCON): the pattern's corners in the flood-lit frames
give the camera (OpenCV's pinhole model with distortion, ``cv2.calibrateCamera``)
and each pose's plane; the laser line on the pattern in the laser frames,
lifted onto that pose's plane, gives 3-D points of the sheet; a robust plane
fit gives the laser plane; pattern poses on the rotary table give its axis.
The result is a sheet model (:class:`TargetCalibration`) that ``reconstruct``
uses like any other.

The frames (``scenario`` ``target``, :mod:`sim.target` or ``import --scenario target``)
carry per frame ``pose`` (index) and ``light``: ``"flood"`` (the pattern lit, the
laser off), ``"laser"`` or ``"both"`` (the laser line on the pattern), ``"background"``
(that pose's laser view with the laser off: subtracted from its laser frame);
table poses carry ``angle_deg``.

The tilt of a Scheimpflug camera
--------------------------------
OpenCV's tilted-sensor terms τx, τy cannot be told from the pattern by a lens
without distortion: ``K·T(τ)·R = K'·R'`` with ``K' = K·P_Z(τ)`` (upper triangular, the
same square-pixel form) and ``R' = R_tilt(τ)·R`` — every τ reproduces the same image of
every pose, only the principal point, the principal distance and a common rotation
of the poses change.  (With distortion the distortion's centre breaks the tie, weakly.)
A pinhole camera has no optical axis; a lens has one, and a camera focused on the
sheet fixes it: the thin lens images the sensor plane S (normal ``n_s``, distance
``d_s`` behind the centre) onto the plane ``(d_s·a − f·n_s)·X = d_s·f`` (``a`` the
lens axis, ``f`` its focal length).  That plane is the laser plane (``n_L·X = D_L``)
exactly when

    a = f · (n_s / d_s + n_L / D_L),       1 / f = | n_s / d_s + n_L / D_L |

(the Scheimpflug and hinge conditions in one line; for an untilted camera and sheet it
is the lens equation 1/f = 1/d_s + 1/D).  With the pixel pitch (``d_s`` in mm) the
calibration therefore finds the lens axis, τx, τy, the principal point and the lens's
own focal length (``tilt="focus"``, the default when the frames' rig is a Scheimpflug
rig): the pattern is fitted with τ held at a value (0 at first), the laser plane and the
focus condition give the axis, the camera is re-expressed about it
(:func:`scheimpflug.calibration.camera.camera_from_sensor_pose`) and fitted again with τ
held there.  ``tilt="none"``: τ = 0 (an ordinary camera); ``tilt="free"``: OpenCV fits τ
(identified only by the distortion).

Accuracy statements
-------------------
Per-parameter standard errors of the camera are OpenCV's (``calibrateCameraExtended``:
σ of the reprojection residuals through the Jacobian; null for a parameter held fixed);
the laser plane's and the focus condition's are jackknife estimates over the poses (each
pose's plane error moves all its laser points together, which a fit to the points alone
would not show).  The reprojection RMS is over every corner used.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from scheimpflug.calibration.camera import OpenCVCamera, camera_from_sensor_pose
from scheimpflug.calibration.detectability import frame_views, pattern_advice, rig_from_manifest
from scheimpflug.calibration.general import GeneralCalibration
from scheimpflug.calibration.laser_background import (
    BACKGROUND_MODES,
    SHARED_FRACTION,
    board_mask,
    difference_noise,
    frame_noise_dn,
    line_points,
    noise_map,
    same_light,
    shared_fraction,
    subtract_background,
    within_board,
)
from scheimpflug.calibration.measure import detect_pattern
from scheimpflug.calibration.model import check_laser_plane, frame_size_from_json, sheet_frame_from_plane, size_problem
from scheimpflug.calibration.pattern import parse_pattern
from scheimpflug.callbacks import ProgressCallback, report
from scheimpflug.errors import CalibrationError
from scheimpflug.io.frames import FrameFolder, open_frame_folder

__all__ = [
    "DISTORTION_MODELS",
    "LIGHTS",
    "TILT_MODES",
    "TargetCalibration",
    "TargetResult",
    "axis_in_sheet",
    "blur_centroid_offsets",
    "calibrate_target_folder",
    "fit_laser_plane",
    "focus_axis",
    "rotary_axis_from_planes",
]

#: Frame lights of a target folder (module docstring).
LIGHTS = ("flood", "laser", "both", "background")
#: How τx, τy are found (module docstring): "rig" holds the manifest rig's design tilt.
TILT_MODES = ("focus", "rig", "none", "free")
#: Distortion terms fitted: OpenCV's coefficients left free.
DISTORTION_MODELS = {"none": (), "k1": ("k1",), "k1k2": ("k1", "k2"), "opencv5": ("k1", "k2", "p1", "p2", "k3")}
#: Fewer usable poses cannot calibrate a camera (Zhang: 2 constraints each, 4–5 unknowns) [-].
MIN_POSES = 3
#: Poses whose normals all lie within this angle of each other are parallel: no focal length [deg].
PARALLEL_DEG = 2.0
_STDERR_NAMES = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6",
                 "s1", "s2", "s3", "s4", "tau_x", "tau_y")
_OUTLIER_PX = 1.0          # corners off by more than max(this, 5 robust σ) are dropped and refitted [px]
_LASER_OUTLIER_SIGMAS = 4.0
#: Repeated flood frames of one pose whose corners differ by more than this RMS show different poses [px]
#: (a board on a stand re-photographed moves < 0.1 px; the corners' own noise is ≈ 0.05 px).
REPEAT_PX = 1.0
#: A laser point belongs to its pose's line within this distance, in its own pixels: the stripe's centre is
#: good to ≈ 0.1 px, a noise peak picked where the line is faint lands anywhere across the board [px].
LINE_TOL_PX = 1.5
#: Fewer points on a straight line are no laser line on the board [-].
MIN_LINE_POINTS = 10
#: … and so is a line holding less than this fraction of the points found on the board: the laser's
#: trace holds most of them (the twin's: 40–100 %), a line through noise or the print's edges a few
#: (9–10 % in a room-lit set searched without its laser-off frames) [-].
MIN_LINE_FRACTION = 0.3
#: A pose's laser line whose points lie a median distance beyond this many pixels of its footprint off
#: the plane of all poses' lines is not on it [px] (the twin's lines: < 0.5 px).
OFF_PLANE_PX = 3.0


# ---------------------------------------------------------------- the sheet model


@dataclass(frozen=True)
class TargetCalibration(GeneralCalibration):
    """A target calibration as a sheet model: OpenCV's camera, the laser plane and the sheet frame.

    The mapping is :class:`~scheimpflug.calibration.general.GeneralCalibration`'s with the
    metric homography ``G = [e_s, e_h, origin]`` of the laser plane's sheet frame
    (:func:`scheimpflug.calibration.model.sheet_frame_from_plane`; ``e_h`` along the rotary
    axis when one was measured).  Without laser frames it is a camera calibration only
    (``laser_plane`` None): it maps no pixel to the sheet.

    Parameters
    ----------
    camera : OpenCVCamera
        The camera [px, -].
    homography : (3, 3) float
        ``[e_s, e_h, origin]`` (camera frame, mm), NaN without a laser plane.
    columns, rows : int
        Image size [px].
    plate_height_mm : float
        Unused (a plate calibration's; the interface of the general model).
    n_frames : int
        Frames in the folder [-].
    residual_rms_px : float
        The reprojection RMS again (the general model's name for its fit's residual) [px].
    field_sigma_mm : dict
        Unused (empty).
    paper : None
        No paper-form estimate (no stage).
    selection : dict
        Unused (empty).
    laser_plane : (4,) float or None
        ``[a, b, c, d]``, unit normal, d < 0, camera frame [mm].
    pattern : str
        The pattern spec.
    reprojection_rms_px : float
        RMS reprojection error over every corner used [px].
    poses_used : tuple of dict
        ``{"pose", "file", "corners"}`` per pose used.
    poses_skipped : tuple of dict
        ``{"pose", "file", "reason"}`` per pose left out.
    stderr : dict
        Standard errors: the camera's parameters (``fx`` … ``tau_y``; None when held fixed)
        [px, -, rad], ``laser_plane_normal_deg``, ``laser_plane_distance_mm``; with the focus
        condition ``tau_x_deg``, ``tau_y_deg``, ``lens_focal_length_mm`` (jackknife over poses).
    laser_plane_rms_mm : float
        RMS distance of the laser points used from the plane [mm].
    laser_points : int
        Laser points used [-].
    axis : dict or None
        The rotary axis (``point_mm``, ``direction``, ``axis_mm`` in sheet coordinates,
        ``angle_to_sheet_deg``, ``distance_to_sheet_mm``, ``poses``), or None.
    tilt : dict
        How τ was found: ``mode`` and, for "focus", ``lens_focal_length_mm`` and ``pixel_pitch_um``.
    """

    laser_plane: np.ndarray | None = None
    pattern: str = ""
    reprojection_rms_px: float = math.nan
    poses_used: tuple = ()
    poses_skipped: tuple = ()
    stderr: dict = field(default_factory=dict, compare=False)
    laser_plane_rms_mm: float = math.nan
    laser_points: int = 0
    axis: dict | None = field(default=None, compare=False)
    tilt: dict = field(default_factory=dict, compare=False)

    method = "target"

    def _need_plane(self) -> None:
        if self.laser_plane is None:
            raise CalibrationError("the target calibration has no laser plane (no laser frames: a camera "
                                   "calibration only): it maps no pixel to the sheet")

    def stage_from_pixel(self, u, v) -> tuple[np.ndarray, np.ndarray]:
        """Sheet coordinates of pixels (:class:`~scheimpflug.calibration.general.GeneralCalibration`'s).

        Parameters
        ----------
        u, v : array_like float
            Column and row [px], broadcast together.

        Returns
        -------
        stage_mm, h_mm : ndarray float64
            [mm].

        Raises
        ------
        CalibrationError
            Without a laser plane.
        """
        self._need_plane()
        return super().stage_from_pixel(u, v)

    def pixel_from_stage(self, stage_mm, h_mm) -> tuple[np.ndarray, np.ndarray]:
        """Pixel of sheet points.

        Parameters
        ----------
        stage_mm, h_mm : array_like float
            Sheet coordinates [mm], broadcast together.

        Returns
        -------
        u_px, v_px : ndarray float64
            [px].

        Raises
        ------
        CalibrationError
            Without a laser plane.
        """
        self._need_plane()
        return super().pixel_from_stage(stage_mm, h_mm)

    def problem(self, columns: int | None = None, rows: int | None = None) -> str | None:
        """What keeps this calibration from mapping frames of a size to the sheet, or None.

        Parameters
        ----------
        columns, rows : int, optional
            The frames' size [px]; frames of another size than the calibration records
            are refused (:func:`~scheimpflug.calibration.model.size_problem`).

        Returns
        -------
        str or None
            Frames of another size, or "no laser plane …" for a camera calibration only.
        """
        size = size_problem(self, columns, rows)
        if size:
            return size
        return None if self.laser_plane is not None else (
            "the target calibration has no laser plane (made without laser frames): a camera calibration only")

    def to_json_dict(self) -> dict[str, Any]:
        """The calibration file (docs/reference/interface.md ``calibrate --method target`` fields).

        Returns
        -------
        dict
            ``model`` "target", ``camera_matrix``, ``dist_coeffs`` (14), ``image_size``,
            ``reprojection_rms_px``, ``poses_used``, ``poses_skipped``, ``laser_plane``
            (null without laser frames), ``laser_plane_rms_mm``, ``laser_points``, ``axis``,
            ``sheet_frame``, ``stderr``, ``tilt``, ``pattern``, ``columns``, ``rows``.
        """
        d: dict[str, Any] = {"model": "target", "pattern": self.pattern, **self.camera.to_json_dict(),
                             "image_size": [int(self.columns), int(self.rows)] if self.columns and self.rows else None,
                             "columns": int(self.columns), "rows": int(self.rows),
                             "reprojection_rms_px": _num(self.reprojection_rms_px),
                             "poses_used": [dict(p) for p in self.poses_used],
                             "poses_skipped": [dict(p) for p in self.poses_skipped],
                             "laser_plane": None if self.laser_plane is None else [float(x) for x in self.laser_plane],
                             "laser_plane_rms_mm": _num(self.laser_plane_rms_mm),
                             "laser_points": int(self.laser_points), "axis": self.axis,
                             "stderr": {k: _num(v) for k, v in self.stderr.items()}, "tilt": self.tilt,
                             "n_frames": int(self.n_frames)}
        if self.laser_plane is not None:
            o, e_s, e_h = self.sheet_frame()
            d["sheet_frame"] = {"origin_mm": o.tolist(), "stage_axis": e_s.tolist(), "height_axis": e_h.tolist()}
        return d

    @classmethod
    def from_json_dict(cls, d: dict) -> TargetCalibration:
        """Read the form of :meth:`to_json_dict`.

        Parameters
        ----------
        d : dict
            A target calibration file's content.

        Returns
        -------
        TargetCalibration
            The calibration.

        Raises
        ------
        CalibrationError
            A missing or malformed field, a laser plane with a non-unit normal, a sheet frame off it,
            a malformed frame size (``columns``/``rows`` or ``image_size``:
            :func:`~scheimpflug.calibration.model.frame_size_from_json`).
        """
        try:
            columns, rows = frame_size_from_json(d)
            camera = OpenCVCamera.from_json_dict(d)
            plane = None if d.get("laser_plane") is None else check_laser_plane(d["laser_plane"])
            g = _homography_of(d.get("sheet_frame"), plane)
            return cls(camera=camera, homography=g, columns=columns, rows=rows,
                       n_frames=int(d.get("n_frames", 0)), laser_plane=plane, pattern=str(d.get("pattern", "")),
                       reprojection_rms_px=_float(d.get("reprojection_rms_px")),
                       poses_used=tuple(d.get("poses_used") or ()), poses_skipped=tuple(d.get("poses_skipped") or ()),
                       stderr=dict(d.get("stderr") or {}), laser_plane_rms_mm=_float(d.get("laser_plane_rms_mm")),
                       laser_points=int(d.get("laser_points", 0)), axis=d.get("axis"), tilt=dict(d.get("tilt") or {}))
        except CalibrationError:
            raise
        except KeyError as exc:
            raise CalibrationError(f"target calibration data lacks the field {exc.args[0]!r}") from None
        except (TypeError, ValueError, IndexError) as exc:
            raise CalibrationError(f"target calibration data garbles a field: {exc}") from None


def _num(x):
    return None if x is None or not math.isfinite(float(x)) else float(x)


def _float(x) -> float:
    return math.nan if x is None else float(x)


def _homography_of(sheet_frame: dict | None, plane: np.ndarray | None) -> np.ndarray:
    if plane is None:
        return np.full((3, 3), np.nan)
    if sheet_frame is None:
        o, e_s, e_h = sheet_frame_from_plane(plane)
    else:
        o, e_s, e_h = (np.asarray(sheet_frame[k], np.float64) for k in ("origin_mm", "stage_axis", "height_axis"))
        if abs(plane[:3] @ o + plane[3]) > 1e-6 * max(1.0, abs(plane[3])):
            raise CalibrationError("the sheet frame's origin is not on the laser plane")
    return np.column_stack([e_s, e_h, o])


@dataclass(frozen=True)
class TargetResult:
    """A target calibration and what it measured on the way.

    Parameters
    ----------
    calibration : TargetCalibration
        The sheet model.
    detections : dict
        Pose index → :class:`~scheimpflug.calibration.measure.PatternDetection` of its flood frame.
    camera_from_pattern : dict
        Pose index → (4, 4) pose of the pattern in the camera frame [mm].
    laser_points_mm : dict
        Pose index → (n, 3) laser points lifted onto that pose's plane, camera frame [mm].
    warnings : tuple of str
        What the user should know (poses skipped, the tilt held, a line missing, figures far from
        the rig's, …).
    laser_poses : tuple of dict
        Per pose with laser frames: ``pose`` (the manifest's id), ``laser_frames``, ``background``
        (what was subtracted from each, and why), ``points_found`` (the whole frame),
        ``points_on_board`` (on the printed pattern), ``points_in_plane_fit`` (not rejected by
        the plane fit), and a ``note`` where the pose adds nothing to the plane.
    nominal : dict
        The calibration against the frame folder's rig (``plane_distance_mm``,
        ``lens_focal_length_mm``, ``principal_distance_mm``: calibrated, nominal, relative,
        tolerance — :class:`NominalTolerances`); empty without a rig.
    """

    calibration: TargetCalibration
    detections: dict = field(repr=False)
    camera_from_pattern: dict = field(repr=False)
    laser_points_mm: dict = field(repr=False)
    warnings: tuple = ()
    laser_poses: tuple = ()
    nominal: dict = field(default_factory=dict)

    @property
    def model(self) -> TargetCalibration:
        """The sheet model this calibration gives: :attr:`calibration`."""
        return self.calibration


# ---------------------------------------------------------------- geometry


def fit_laser_plane(points_mm: np.ndarray, n_sigma: float = _LASER_OUTLIER_SIGMAS) -> tuple[np.ndarray, np.ndarray]:
    """A robust plane through 3-D points: total least squares, outliers beyond ``n_sigma`` robust σ dropped.

    Parameters
    ----------
    points_mm : (n, 3) array_like float
        Points [mm] (n ≥ 3, not collinear).
    n_sigma : float, default 4
        Rejection threshold in robust σ (1.4826 × MAD of the distances) [-].

    Returns
    -------
    plane : (4,) float64
        ``[a, b, c, d]`` with a unit normal and d ≤ 0 [-, mm].
    inliers : (n,) bool
        The points kept.

    Raises
    ------
    CalibrationError
        Fewer than 3 points, or points on a line (the laser seen on one pose only: no plane).
    """
    p = np.asarray(points_mm, np.float64).reshape(-1, 3)
    keep = np.all(np.isfinite(p), axis=1)
    if keep.sum() < 3:
        raise CalibrationError(f"the laser plane needs at least 3 laser points on the pattern; {int(keep.sum())} found")
    for _ in range(10):
        c = p[keep].mean(axis=0)
        _, sv, vt = np.linalg.svd(p[keep] - c, full_matrices=False)
        if sv[1] < 1e-6 * max(sv[0], 1e-12):
            raise CalibrationError("the laser points lie on a line (the laser seen on one pose only, or on parallel "
                                   "poses along one line): they do not fix a plane")
        n = vt[2]
        r = (p - c) @ n
        sigma = 1.4826 * np.median(np.abs(r[keep])) + 1e-9
        new = np.all(np.isfinite(p), axis=1) & (np.abs(r) <= n_sigma * sigma)
        if np.array_equal(new, keep):
            break
        keep = new
    d = -float(n @ c)
    if d > 0:
        n, d = -n, -d
    return np.array([*n, d]), keep


def _sensor_plane(camera: OpenCVCamera, pitch_mm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The camera's virtual sensor plane: pixel (0, 0)'s point, and one column's and one row's step [mm].

    The plane of :func:`camera_from_sensor_pose`: through the principal point's point
    ``(0, 0, f·p)`` with OpenCV's tilted normal; pixel (u, v) is where its distortion-free
    ray meets it.
    """
    bare = OpenCVCamera(camera.camera_matrix, np.r_[np.zeros(12), camera.dist_coeffs[12:]])
    n = _rot_tilt(bare).T @ np.array([0.0, 0.0, 1.0])
    x, y = bare.normalized_from_pixel(np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]))
    rays = np.stack([x, y, np.ones(3)], axis=1)
    z0 = camera.focal_px * pitch_mm
    pts = rays * (z0 * n[2] / (rays @ n))[:, None]
    return pts[0], pts[1] - pts[0], pts[2] - pts[0]


def _rot_tilt(camera: OpenCVCamera) -> np.ndarray:
    """``R_Y(τy)·R_X(τx)`` of OpenCV's tilt (its sensor normal is ``Rᵀ e_z``)."""
    cx, sx = math.cos(camera.tau_x_rad), math.sin(camera.tau_x_rad)
    cy, sy = math.cos(camera.tau_y_rad), math.sin(camera.tau_y_rad)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cx, sx], [0.0, -sx, cx]])
    ry = np.array([[cy, 0.0, -sy], [0.0, 1.0, 0.0], [sy, 0.0, cy]])
    return ry @ rx


def focus_axis(camera: OpenCVCamera, plane: np.ndarray, pixel_pitch_um: float) -> tuple[np.ndarray, float]:
    """The lens axis and focal length that focus the camera's sensor on the laser plane (module docstring).

    Parameters
    ----------
    camera : OpenCVCamera
        The camera (any τ: its sensor plane is :func:`_sensor_plane`'s).
    plane : (4,) array_like float
        The laser plane in the camera frame (unit normal, d < 0) [mm].
    pixel_pitch_um : float
        The sensor's pixel pitch [µm].

    Returns
    -------
    axis : (3,) float64
        Unit lens axis, camera frame [-] (``(0, 0, 1)`` when the camera's own axis focuses it).
    focal_length_mm : float
        The thin lens's focal length [mm].
    """
    origin, du, dv = _sensor_plane(camera, pixel_pitch_um * 1e-3)
    n_s = np.cross(du, dv)
    n_s /= np.linalg.norm(n_s)
    d_s = float(n_s @ origin)
    if d_s < 0:
        n_s, d_s = -n_s, -d_s
    p = check_laser_plane(plane)
    v = n_s / d_s + p[:3] / (-p[3])
    f = 1.0 / float(np.linalg.norm(v))
    return v * f, f


def _tilted_from_axis(camera: OpenCVCamera, axis: np.ndarray,
                      pixel_pitch_um: float) -> tuple[OpenCVCamera, np.ndarray]:
    """The camera re-expressed about a lens axis: OpenCV's tilted camera there, and new_from_old (3, 3).

    The real sensor is the point reflection of the virtual one (:func:`_sensor_plane`);
    its pose and the new optical axis give the tilted camera (:func:`camera_from_sensor_pose`);
    the distortion terms are kept (the refit that follows moves them to the new centre).
    """
    p = pixel_pitch_um * 1e-3
    origin, du, dv = _sensor_plane(camera, p)
    z = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    rot = np.vstack([x, np.cross(z, x), z])
    cam, new_from_old = camera_from_sensor_pose(-origin, -du / p, -dv / p, p, rot)
    d = camera.dist_coeffs.copy()
    d[12], d[13] = cam.tau_x_rad, cam.tau_y_rad
    return OpenCVCamera(cam.camera_matrix, d), new_from_old


def _aperture_quadrature(radius_mm: float, nodes: int) -> tuple[np.ndarray, np.ndarray]:
    """Points (lens plane z = 0) and area weights of a disc quadrature: Gauss–Legendre in r², trapezoid in φ."""
    x, w = np.polynomial.legendre.leggauss(nodes)
    r = radius_mm * np.sqrt(0.5 * (x + 1.0))
    m = 4 * nodes
    phi = (np.arange(m) + 0.5) * (2 * math.pi / m)
    rr, pp = np.meshgrid(r, phi, indexing="ij")
    weights = np.repeat(0.5 * w * math.pi * radius_mm ** 2 / m, m)
    pts = np.stack([(rr * np.cos(pp)).ravel(), (rr * np.sin(pp)).ravel(), np.zeros(rr.size)], axis=1)
    return pts, weights


def blur_centroid_offsets(camera: OpenCVCamera, points_mm: np.ndarray, focal_length_mm: float, f_number: float,
                          pixel_pitch_um: float, samples: int = 12) -> np.ndarray:
    """Where a defocused point's light centroid lies on the tilted sensor, relative to its chief ray [px].

    A thin lens at the origin with its axis along the camera's z (the focus condition's
    frame) images a point X at ``X' = −f·X/(X_z − f)``; the rays from the aperture disc
    (radius ``f/(2N)``, Fibonacci samples) through X' meet the real sensor in the blur spot,
    each weighted by the étendue (``|d_z|·|d·n|/|d|⁴``, d the ray from the sensor point to the
    aperture point), integrated over the disc by Gauss–Legendre in r² and the trapezoid rule in
    the angle (exact to < 1e-6 px with the default samples; a Fibonacci set of 256 points is off by
    0.05 px on a 30 px spot).  A tilted sensor cuts the light cone off its axis: the spot's centroid
    is not the chief ray's pixel, by up to a few % of the blur — on the twin's paper rig up to
    0.14 px for corners blurred over 30 px, enough to move the principal point by 20 px and
    the laser plane's normal by 0.12° when left in the corners (benchmarks/RESULTS.md).  A
    corner's detector (:func:`scheimpflug.calibration.measure.refine_corners_model`) sees the
    spot's centroid (a point-symmetric corner blurred by a shifted spot is shifted by it).

    Parameters
    ----------
    camera : OpenCVCamera
        The camera, in the frame whose z is the lens axis (after the focus condition).
    points_mm : (n, 3) array_like float
        Object points in that frame [mm].
    focal_length_mm : float
        The thin lens's focal length [mm].
    f_number : float
        Its f-number [-].
    pixel_pitch_um : float
        The sensor's pixel pitch [µm].
    samples : int, default 12
        Gauss–Legendre nodes in r² (four times as many angles).

    Returns
    -------
    (n, 2) float64
        Centroid − chief-ray pixel (u, v) [px].
    """
    pitch = pixel_pitch_um * 1e-3
    origin, du, dv = _sensor_plane(camera, pitch)
    o, eu, ev = -origin, -du, -dv                                      # the real sensor behind the lens
    normal = np.cross(eu, ev)
    normal /= np.linalg.norm(normal)
    x = np.asarray(points_mm, np.float64).reshape(-1, 3)
    f = float(focal_length_mm)
    img = -f * x / (x[:, 2:3] - f)
    ap, area = _aperture_quadrature(0.5 * f / f_number, samples)

    def pixel(q):
        rel = q - o
        a = np.array([[eu @ eu, eu @ ev], [eu @ ev, ev @ ev]])
        return np.linalg.solve(a, np.stack([rel @ eu, rel @ ev], axis=-1)[..., None])[..., 0]

    w = img[:, None, :] - ap[None]
    lam = ((o - ap[None]) @ normal) / (w @ normal)
    q = ap[None] + lam[..., None] * w
    d = ap[None] - q
    weight = area[None] * np.abs(d[..., 2]) * np.abs(d @ normal) / (d ** 2).sum(-1) ** 2
    centroid = (pixel(q) * weight[..., None]).sum(1) / weight.sum(1)[:, None]
    chief = pixel(img * ((o @ normal) / (img @ normal))[:, None])
    return centroid - chief


def rotary_axis_from_planes(planes: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """The axis about which planes turn: the poses' common rotation axis from their planes alone.

    A plane turned about an axis keeps its angle to it and its distance from every point
    of it: the normals lie on a circle of the unit sphere about the axis direction ω (the
    smallest principal direction of the centred normals), and ``n_i·q + d_i = c`` for a point q
    of the axis (linear least squares in q ⟂ ω and c).  The in-plane labelling of the corners
    does not enter (a chessboard's half-turn ambiguity is harmless).

    Parameters
    ----------
    planes : (k, 4) array_like float
        ``[a, b, c, d]`` per pose (unit normals), camera frame; k ≥ 3 at distinct angles [mm].

    Returns
    -------
    point_mm : (3,) float64
        The axis point nearest the camera's centre [mm].
    direction : (3,) float64
        Unit direction (pointing up in the image: −y) [-].
    rms_mm : float
        RMS of ``n_i·q + d_i − c`` [mm].

    Raises
    ------
    CalibrationError
        Fewer than 3 planes, or normals that do not turn (parallel poses).
    """
    p = np.asarray(planes, np.float64).reshape(-1, 4)
    if len(p) < 3:
        raise CalibrationError(f"the rotary axis needs at least 3 table poses; {len(p)} found")
    n = p[:, :3]
    _, sv, vt = np.linalg.svd(n - n.mean(axis=0), full_matrices=False)
    if sv[1] < 1e-3 * len(p) ** 0.5:
        raise CalibrationError("the table poses do not turn (their planes are parallel): no rotary axis")
    w = vt[2] if vt[2][1] < 0 else -vt[2]
    b1 = np.cross(w, [1.0, 0.0, 0.0] if abs(w[0]) < 0.9 else [0.0, 1.0, 0.0])
    b1 /= np.linalg.norm(b1)
    b2 = np.cross(w, b1)
    a = np.column_stack([n @ b1, n @ b2, -np.ones(len(p))])
    sol, *_ = np.linalg.lstsq(a, -p[:, 3], rcond=None)
    q = sol[0] * b1 + sol[1] * b2
    r = a @ sol + p[:, 3]
    return q, w, float(np.sqrt(np.mean(r ** 2)))


# ---------------------------------------------------------------- the frames of a target folder


@dataclass(frozen=True)
class _Pose:
    index: int                         # the manifest's pose id (frames without one: ids after the largest)
    flood: int | None                  # frame index of the (first) flood-lit frame
    laser: tuple[int, ...] = ()        # laser frames
    background: int | None = None      # laser-off frame of the laser view
    angle_deg: float | None = None     # table angle, for table poses
    repeats: tuple[int, ...] = ()      # more flood-lit frames of the same pose
    laser_off: tuple = ()              # per laser frame: the frame subtracted from it, or None (_paired)
    laser_noise: tuple = ()            # per laser frame: σ [DN], or (levels, σ) of a difference (_paired)
    laser_skip: tuple = ()             # per laser frame: why it holds no findable line, or None


def _light(rec) -> str:
    light = rec.extra.get("light", "flood")
    if light not in LIGHTS:
        raise CalibrationError(f"{rec.file}: light {light!r:.30} is not one of {', '.join(LIGHTS)}")
    return light


def _pose_id(rec) -> int | None:
    key = rec.extra.get("pose")
    if key is None:
        return None
    if isinstance(key, bool) or not isinstance(key, int) or key < 0:
        raise CalibrationError(f"{rec.file}: pose {key!r:.30} is not an integer >= 0")
    return key


def _pose_slots(ff: FrameFolder) -> dict[int, dict]:
    """Frame indices per pose id and light; a frame without a pose is a flood frame of its own."""
    ids = [_pose_id(rec) for rec in ff.frames]
    auto = max((k for k in ids if k is not None), default=-1) + 1
    poses: dict[int, dict] = {}
    for i, (rec, key) in enumerate(zip(ff.frames, ids)):
        light = _light(rec)
        if key is None:
            if light != "flood":
                raise CalibrationError(f"{rec.file}: a {light} frame needs the 'pose' of its flood-lit frame in "
                                       "the manifest")
            key, auto = auto, auto + 1
        slot = poses.setdefault(key, {"flood": [], "laser": [], "background": [], "angle": None})
        slot["laser" if light == "both" else light].append(i)
        if rec.angle_deg is not None:
            slot["angle"] = rec.angle_deg
    return poses


def _group_poses(ff: FrameFolder, notes: list | None = None) -> list[_Pose]:
    """The folder's frames by pose (manifest ``pose``), in pose-id order.

    With ``notes`` (a room-light set), laser frames without a flood-lit frame of their pose —
    without their laser-off partner — are left out and named there instead of refused.

    Raises
    ------
    CalibrationError
        Laser frames without a flood-lit frame of their pose (without ``notes``), two laser-off
        frames of one pose, a pose id that is not an integer >= 0.
    """
    out, orphans = [], []
    for key, v in sorted(_pose_slots(ff).items()):
        if len(v["background"]) > 1:
            raise CalibrationError(f"pose {key} has {len(v['background'])} laser-off frames ('background': "
                                   + ", ".join(ff.frames[i].file for i in v["background"][:3])
                                   + "): one per pose, or give each its own pose")
        if not v["flood"]:
            orphans += [ff.frames[i].file for i in v["laser"]]
            continue
        out.append(_Pose(key, v["flood"][0], tuple(v["laser"]), (v["background"] or [None])[0], v["angle"],
                         tuple(v["flood"][1:])))
    if orphans and notes is not None:
        notes += [f"{f}: a laser frame without its laser-off partner (no flood-lit frame of its pose): left out"
                  for f in orphans]
    elif orphans:
        raise CalibrationError(f"{len(orphans)} laser frame(s) without their flood-lit pose frame (the pattern "
                               f"seen with the flood light; same 'pose' in the manifest): {', '.join(orphans[:3])}"
                               + (" …" if len(orphans) > 3 else ""))
    return out


# ---------------------------------------------------------------- finding the pattern


def _detect_all(ff: FrameFolder, poses, spec, refine: str, progress) -> tuple[dict, list]:
    """The pattern in each pose's flood frame, in the frame or in views rectified by the folder's rig.

    The views (:func:`scheimpflug.calibration.detectability.frame_views`): the manifest rig's
    print planes when it has one at the frames' size (a Scheimpflug camera's oblique view of a
    print), else the frame stretched along its distance axis.
    """
    found, skipped = {}, []
    views = frame_views(ff.rig, (ff.rows, ff.columns), spec, ff.stripe_along)
    for k, pose in enumerate(poses):
        report(progress, k, len(poses))
        rec = ff.frames[pose.flood]
        det = detect_pattern(ff.read(pose.flood), spec, refine=refine, file=rec.file, views=views)
        if det is None:
            skipped.append({"pose": pose.index, "file": rec.file, "reason": f"pattern {spec.text} not found"})
        elif len(det) < 6:
            skipped.append({"pose": pose.index, "file": rec.file, "reason": f"only {len(det)} corners found"})
        else:
            found[pose.index] = det
    report(progress, len(poses), len(poses))
    return found, skipped


def _merged(dets: list, files: list[str], pose: int) -> tuple:
    """One detection from repeated flood frames of one pose: corners averaged, or an error if they moved."""
    first = dets[0]
    for det, file in zip(dets[1:], files[1:]):
        common, ia, ib = np.intersect1d(first.ids, det.ids, return_indices=True)
        if len(common) == 0:
            continue
        rms = float(np.sqrt(np.mean(np.sum((first.corners_px[ia] - det.corners_px[ib]) ** 2, axis=1))))
        if rms > REPEAT_PX:
            raise CalibrationError(f"pose {pose} has flood-lit frames showing the pattern in different places "
                                   f"({files[0]} and {file}: corners {rms:.2g} px apart RMS): one flood frame "
                                   "per pose, or give each its own pose id")
    ids = np.unique(np.concatenate([d.ids for d in dets]))
    sums, counts = np.zeros((len(ids), 2)), np.zeros(len(ids))
    for det in dets:
        k = np.searchsorted(ids, det.ids)
        np.add.at(sums, k, det.corners_px)
        np.add.at(counts, k, 1.0)
    windows = np.zeros(len(ids), np.int64)
    for det in dets[::-1]:
        windows[np.searchsorted(ids, det.ids)] = det.window_px
    return replace(first, ids=ids, corners_px=sums / counts[:, None], window_px=windows)


def _merge_repeats(ff: FrameFolder, poses, dets: dict, skipped: list, spec, refine: str, notes: list) -> None:
    """Fold each pose's repeated flood frames into its detection (in place): never one dropped unsaid."""
    for pose in poses:
        if not pose.repeats:
            continue
        frames = [pose.flood, *pose.repeats]
        files = [ff.frames[i].file for i in frames]
        found = [(dets[pose.index], files[0])] if pose.index in dets else []
        views = frame_views(ff.rig, (ff.rows, ff.columns), spec, ff.stripe_along)
        for i, file in zip(pose.repeats, files[1:]):
            det = detect_pattern(ff.read(i), spec, refine=refine, file=file, views=views)
            if det is not None and len(det) >= 6:
                found.append((det, file))
        if not found:
            notes.append(f"pose {pose.index}: pattern found in none of its {len(frames)} flood-lit frames")
            continue
        dets[pose.index] = _merged([d for d, _ in found], [f for _, f in found], pose.index)
        skipped[:] = [s for s in skipped if s["pose"] != pose.index]
        notes.append(f"pose {pose.index}: {len(frames)} flood-lit frames ({', '.join(files)}); the pattern found in "
                     f"{len(found)}" + (", their corners averaged" if len(found) > 1 else ""))


def _size_hint(ff: FrameFolder, poses, spec) -> str:
    """Why the spec's pattern is found in no frame: what the manifest's rig says, what the first frame shows.

    With a rig read out at the frames' size that cannot show the pattern whole and resolved
    (:meth:`PatternAdvice.problem <scheimpflug.calibration.detectability.PatternAdvice.problem>`),
    the rig's reason (:meth:`~scheimpflug.calibration.detectability.PatternAdvice.hint`): a grid of
    another size found in such frames would be no evidence (a sub-board of the real one is found as
    readily).  Otherwise the grid sizes near the spec's that the first frame shows (chessboards) or
    its ChArUco markers, and with a rig, where the rig says the pattern is found.
    """
    rig = rig_from_manifest(ff.rig)
    advice = pattern_advice(rig, spec) if rig is not None and (rig.sensor.rows, rig.sensor.columns) == (
        ff.rows, ff.columns) else None
    if advice is not None and advice.problem() is not None:
        return "; " + advice.hint()
    frame = ff.read(poses[0].flood)
    seen = ""
    if spec.kind == "chessboard":
        from scheimpflug.calibration.measure import _chessboard_corners, _to_uint8

        gray = _to_uint8(frame)
        c, r = spec.grid_shape
        for dc, dr in sorted(((a, b) for a in range(-2, 3) for b in range(-2, 3) if a or b),
                             key=lambda t: (abs(t[0]) + abs(t[1]), abs(t[0] - t[1]), -t[0] - t[1])):
            size = (c + dc, r + dr)
            if min(size) >= 2 and _chessboard_corners(gray, replace(spec, cols=size[0], rows=size[1])) is not None:
                seen = f"; is the pattern {size[0]} × {size[1]} (inner corners)?"
                break
    if spec.kind == "charuco":
        from scheimpflug.calibration.pattern import aruco_dictionary

        _, ids, _ = cv2.aruco.ArucoDetector(aruco_dictionary(spec)).detectMarkers(
            np.clip(frame.astype(np.float32) * (255.0 / max(float(frame.max()), 1.0)), 0, 255).astype(np.uint8))
        n = 0 if ids is None else len(ids)
        held = (spec.cols * spec.rows) // 2
        if n and int(ids.max()) >= held:
            seen = (f"; {n} {spec.dictionary} markers seen with ids up to {int(ids.max())}, a {spec.cols} × "
                    f"{spec.rows} board holds {held} (ids 0–{held - 1}): is the board larger?")
        elif n:
            seen = (f"; {n} {spec.dictionary} markers seen, not where a {spec.cols} × {spec.rows} board with "
                    f"{spec.pitch_mm:g} mm squares puts them: is the board smaller or another layout?")
    return seen or ("; " + advice.hint() if advice is not None else "")


def _check_not_parallel(dets: dict, spec, size) -> None:
    """Refuse poses whose planes are all parallel (the vanishing lines agree: no focal length)."""
    f = float(max(size))
    k = np.array([[f, 0.0, 0.5 * size[0]], [0.0, f, 0.5 * size[1]], [0.0, 0.0, 1.0]])
    normals = []
    for d in dets.values():
        h, _ = cv2.findHomography(spec.corners_mm()[d.ids], d.corners_px, 0)
        if h is None:
            continue
        n = k.T @ np.linalg.inv(h).T @ np.array([0.0, 0.0, 1.0])      # the plane's normal (any K: parallel stays)
        normals.append(n / np.linalg.norm(n))
    if len(normals) < 2:
        return
    nn = np.array(normals)
    spread = np.degrees(np.arccos(np.clip(np.abs(nn @ nn.T), -1.0, 1.0))).max()
    if spread < PARALLEL_DEG:
        raise CalibrationError(f"degenerate poses: all {len(normals)} poses of the pattern are parallel (their planes "
                               f"within {spread:.2g}° of each other): the focal length is undetermined; tilt the "
                               "pattern between poses (by 20° or more about both axes)")


# ---------------------------------------------------------------- the camera


def _rig_camera(ff: FrameFolder) -> OpenCVCamera | None:
    """The design camera of the manifest's rig (the twin's, or a real rig's file), or None."""
    if not isinstance(ff.rig, dict):
        return None
    try:
        from scheimpflug.model.camera import lens_centre_mm, sensor_pose
        from scheimpflug.model.rig import rig_from_dict

        rig = rig_from_dict(ff.rig)
        pose = sensor_pose(rig)
        cam, _ = camera_from_sensor_pose(pose.origin_mm - lens_centre_mm(rig), pose.u_dir, pose.v_dir, pose.pitch_mm)
    except (ValueError, TypeError, KeyError, ArithmeticError):
        return None
    d = np.zeros(14)
    d[0], d[1], d[12], d[13] = rig.lens.k1, rig.lens.k2, cam.tau_x_rad, cam.tau_y_rad
    return OpenCVCamera(cam.camera_matrix, d)


@dataclass(frozen=True)
class NominalTolerances:
    """How far a target calibration may lie from the frame folder's rig before it is warned about.

    A pattern whose square size is given wrong by x % scales every distance the calibration
    measures by x % — the poses, the laser plane — while the reprojection error stays as it
    was: only the rig's own figures can tell.  Each tolerance is what a built rig keeps from
    its design.

    Parameters
    ----------
    plane_distance : float, default 0.02
        The laser plane's distance from the lens centre against the rig's sheet (d·cos φ):
        a line laser mounted within a few millimetres of its place at 150 mm [-].
    lens_focal_length : float, default 0.02
        The lens's focal length found by the focus condition against the rig's (a lens's
        marked focal length holds to about 1–2 %) [-].
    principal_distance : float, default 0.02
        The camera's principal distance ``fx · pitch`` against the design camera's [-].
    """

    plane_distance: float = 0.02
    lens_focal_length: float = 0.02
    principal_distance: float = 0.02


def _rig_sheet_distance_mm(ff: FrameFolder) -> float | None:
    """The rig's sheet distance from the lens centre, d·cos φ [mm], or None without a (valid) rig."""
    if not isinstance(ff.rig, dict):
        return None
    try:
        from scheimpflug.model.rig import rig_from_dict

        laser = rig_from_dict(ff.rig).laser
    except (ValueError, TypeError, KeyError, ArithmeticError):
        return None
    return laser.scheimpflug_distance_mm * math.cos(math.atan(laser.tan_phi))


def _nominal_check(ff: FrameFolder, fit: _Fit, plane, tilt_info: dict, pitch_um: float | None,
                   tol: NominalTolerances = NominalTolerances()) -> tuple[dict, list[str]]:
    """The calibration against the frame folder's rig: each figure, its nominal value, and warnings."""
    rig_cam = _rig_camera(ff)
    pairs = {}
    if plane is not None and _rig_sheet_distance_mm(ff):
        pairs["plane_distance"] = (abs(float(plane[3])), _rig_sheet_distance_mm(ff), "mm",
                                   "the laser plane's distance from the lens centre")
    if "lens_focal_length_mm" in tilt_info and ff.rig_value("lens", "focal_length_mm"):
        pairs["lens_focal_length"] = (tilt_info["lens_focal_length_mm"], ff.rig_value("lens", "focal_length_mm"),
                                      "mm", "the lens's focal length (focus condition)")
    if rig_cam is not None and pitch_um:
        pairs["principal_distance"] = (fit.camera.focal_px * pitch_um * 1e-3, rig_cam.focal_px * pitch_um * 1e-3,
                                       "mm", "the principal distance fx·pitch")
    out, notes = {}, []
    for key, (got, nominal, unit, what) in pairs.items():
        rel = got / nominal - 1.0
        limit = getattr(tol, key)
        out[key + "_" + unit] = {"calibrated": got, "nominal": nominal, "relative": rel, "tolerance": limit}
        if abs(rel) > limit:
            notes.append(f"{what} is {got:.4g} {unit}, the rig's {nominal:.4g} {unit} ({100 * rel:+.2f} %, beyond "
                         f"{100 * limit:g} %): is the pattern's square size right? A size wrong by x % scales every "
                         "distance by x % and leaves the reprojection error as it is")
    return out, notes


def _centred(camera: OpenCVCamera, size) -> OpenCVCamera:
    """The same images from the gauge whose principal point is the image's centre (module docstring).

    ``K·T(τ)`` ≡ ``K'·T(0)`` with ``K' = K·P_Z(τ)`` (poses turned by ``R_tilt(τ)``); the τ₀ that
    puts ``K'·P_Z(τ₀)⁻¹``'s principal point at the centre solves ``tan τy = (c'x − W/2)/f'`` and
    ``sin τx / (cos τx cos τy) = (H/2 − c'y)/f'``.  OpenCV refuses a first guess whose principal
    point lies outside the image, as a Scheimpflug camera's does at τ = 0; in this gauge it never
    does.  The distortion is kept (the fit moves it).
    """
    r = _rot_tilt(camera)
    pz = np.array([[r[2, 2], 0.0, -r[0, 2]], [0.0, r[2, 2], -r[1, 2]], [0.0, 0.0, 1.0]])
    k = camera.camera_matrix @ pz
    k = k / k[2, 2]
    f, cx, cy = 0.5 * (k[0, 0] + k[1, 1]), k[0, 2], k[1, 2]
    tau_y = math.atan((cx - 0.5 * size[0]) / f)
    tau_x = math.atan((0.5 * size[1] - cy) / f * math.cos(tau_y))
    r0 = _rot_tilt(OpenCVCamera(np.eye(3), np.r_[np.zeros(12), tau_x, tau_y]))
    pz0 = np.array([[r0[2, 2], 0.0, -r0[0, 2]], [0.0, r0[2, 2], -r0[1, 2]], [0.0, 0.0, 1.0]])
    k0 = k @ np.linalg.inv(pz0)
    k0 = k0 / k0[2, 2]
    d = camera.dist_coeffs.copy()
    d[12], d[13] = tau_x, tau_y
    return OpenCVCamera(np.array([[k0[0, 0], 0.0, k0[0, 2]], [0.0, k0[1, 1], k0[1, 2]], [0.0, 0.0, 1.0]]), d)


def _zhang(homographies: list[np.ndarray], size) -> np.ndarray:
    """Zhang's closed-form intrinsics (zero skew) from plane homographies; the image centre when it fails."""
    def v(h, i, j):
        return np.array([h[0, i] * h[0, j], h[0, i] * h[1, j] + h[1, i] * h[0, j], h[1, i] * h[1, j],
                         h[2, i] * h[0, j] + h[0, i] * h[2, j], h[2, i] * h[1, j] + h[1, i] * h[2, j],
                         h[2, i] * h[2, j]])
    rows = []
    for h in homographies:
        h = h / np.linalg.norm(h)
        rows += [v(h, 0, 1), v(h, 0, 0) - v(h, 1, 1)]
    rows.append([0.0, 1.0, 0.0, 0.0, 0.0, 0.0])                       # zero skew: B12 = 0
    b = np.linalg.svd(np.array(rows))[2][-1]
    b11, b12, b22, b13, b23, b33 = b
    try:
        v0 = (b12 * b13 - b11 * b23) / (b11 * b22 - b12 ** 2)
        lam = b33 - (b13 ** 2 + v0 * (b12 * b13 - b11 * b23)) / b11
        alpha, beta = math.sqrt(lam / b11), math.sqrt(lam * b11 / (b11 * b22 - b12 ** 2))
        u0 = -b13 * alpha ** 2 / lam
    except (ValueError, ZeroDivisionError):
        f = float(max(size))
        return np.array([[f, 0.0, 0.5 * size[0]], [0.0, f, 0.5 * size[1]], [0.0, 0.0, 1.0]])
    return np.array([[alpha, 0.0, u0], [0.0, beta, v0], [0.0, 0.0, 1.0]])


def _flags(distortion: str, tilt_free: bool, square: bool) -> int:
    free = DISTORTION_MODELS[distortion]
    flags = cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_TILTED_MODEL | cv2.CALIB_FIX_S1_S2_S3_S4
    flags |= 0 if tilt_free else cv2.CALIB_FIX_TAUX_TAUY
    flags |= cv2.CALIB_FIX_ASPECT_RATIO if square else 0
    for name, flag in (("k1", cv2.CALIB_FIX_K1), ("k2", cv2.CALIB_FIX_K2), ("k3", cv2.CALIB_FIX_K3)):
        flags |= 0 if name in free else flag
    flags |= cv2.CALIB_FIX_K4 | cv2.CALIB_FIX_K5 | cv2.CALIB_FIX_K6
    flags |= 0 if "p1" in free else cv2.CALIB_ZERO_TANGENT_DIST
    return flags


@dataclass
class _Fit:
    camera: OpenCVCamera
    poses: dict                        # pose index → (4, 4) camera_from_pattern
    rms_px: float
    stderr: dict
    used: dict                         # pose index → corners used


def _calibrate(dets: dict, spec, size, start: OpenCVCamera, flags: int) -> _Fit:
    """``cv2.calibrateCameraExtended`` from ``start`` (τ held where it is, if the flags hold it).

    OpenCV refuses a first guess whose principal point lies outside the image; such a camera is
    fitted in the centred gauge and turned back to ``start``'s τ (exact without distortion:
    ``K = K₀·P_Z(τ₀)·P_Z(τ)⁻¹``, poses turned by ``R_tilt(τ)ᵀ·R_tilt(τ₀)``).
    """
    inside = 0 <= start.principal_px[0] < size[0] and 0 <= start.principal_px[1] < size[1]
    if inside or not flags & cv2.CALIB_FIX_TAUX_TAUY:
        return _calibrate_once(dets, spec, size, start, flags)
    fit = _calibrate_once(dets, spec, size, _centred(start, size), flags)
    return _regauged(fit, start)


def _pz(camera: OpenCVCamera) -> np.ndarray:
    r = _rot_tilt(camera)
    return np.array([[r[2, 2], 0.0, -r[0, 2]], [0.0, r[2, 2], -r[1, 2]], [0.0, 0.0, 1.0]])


def _regauged(fit: _Fit, target: OpenCVCamera) -> _Fit:
    """The fit expressed with ``target``'s τ (the gauge change of :func:`_calibrate`)."""
    k = fit.camera.camera_matrix @ _pz(fit.camera) @ np.linalg.inv(_pz(target))
    k = k / k[2, 2]
    d = fit.camera.dist_coeffs.copy()
    d[12:] = target.dist_coeffs[12:]
    cam = OpenCVCamera(np.array([[k[0, 0], 0.0, k[0, 2]], [0.0, k[1, 1], k[1, 2]], [0.0, 0.0, 1.0]]), d)
    turn = np.eye(4)
    turn[:3, :3] = _rot_tilt(target).T @ _rot_tilt(fit.camera)
    poses = {key: turn @ m for key, m in fit.poses.items()}
    stderr = {**fit.stderr, "cx": None, "cy": None}
    return _Fit(cam, poses, fit.rms_px, stderr, fit.used)


def _reprojection(obj, img, keys, rvecs, tvecs, kk, dd) -> dict:
    out = {}
    for k, rv, tv in zip(keys, rvecs, tvecs):
        proj, _ = cv2.projectPoints(obj[k], rv, tv, kk, dd)
        out[k] = np.linalg.norm(proj.reshape(-1, 2) - img[k], axis=1)
    return out


def _calibrate_once(dets: dict, spec, size, start: OpenCVCamera, flags: int) -> _Fit:
    """One ``cv2.calibrateCameraExtended``; corners beyond max(1 px, 5 robust σ) dropped and refitted."""
    keys = sorted(dets)
    obj = {k: spec.object_points()[dets[k].ids] for k in keys}
    img = {k: dets[k].corners_px.astype(np.float32) for k in keys}
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 300, 1e-12)
    last = (keys, obj, img)
    for attempt in range(3):
        try:
            out = cv2.calibrateCameraExtended([obj[k] for k in keys], [img[k] for k in keys], tuple(size),
                                              start.camera_matrix.copy(), start.dist_coeffs.copy(), flags=flags,
                                              criteria=crit)
        except cv2.error as exc:
            if attempt == 0:
                raise CalibrationError(f"OpenCV's camera fit failed on {len(keys)} poses: "
                                       f"{str(exc).strip().splitlines()[-1]}") from None
            keys, obj, img = last       # the refit without the outliers left the image (ill-posed): keep the last
            break
        rms, kk, dd, rvecs, tvecs, sd_int = out[:6]
        res = _reprojection(obj, img, keys, rvecs, tvecs, kk, dd)
        allr = np.concatenate(list(res.values()))
        limit = max(_OUTLIER_PX, 5.0 * 1.4826 * float(np.median(allr)))
        if allr.max() <= limit or attempt == 2:
            break
        last = (keys, dict(obj), dict(img))
        for k in keys:
            keep = res[k] <= limit
            obj[k], img[k] = obj[k][keep], img[k][keep]
        keys = [k for k in keys if len(obj[k]) >= 6]
        start = OpenCVCamera(kk, dd.ravel())
    poses = {}
    for k, rv, tv in zip(keys, rvecs, tvecs):
        m = np.eye(4)
        m[:3, :3], m[:3, 3] = cv2.Rodrigues(rv)[0], tv.ravel()
        poses[k] = m
    sd = np.asarray(sd_int, np.float64).ravel()
    stderr = {name: (float(x) if x > 0 else None) for name, x in zip(_STDERR_NAMES, sd)}
    return _Fit(OpenCVCamera(kk, dd.ravel()), poses, float(rms), stderr, {k: len(obj[k]) for k in keys})


# ---------------------------------------------------------------- the laser


def _lift_local(camera: OpenCVCamera, pose: np.ndarray, u, v) -> tuple[np.ndarray, np.ndarray]:
    """Pixels lifted onto a pose's plane: camera-frame points [mm] and pattern-frame (x, y) [mm] (NaN behind)."""
    x, y = camera.normalized_from_pixel(u, v)
    ray = np.stack([x, y, np.ones_like(x)], axis=-1)
    n, o = pose[:3, 2], pose[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (n @ o) / (ray @ n)
    t = np.where(t > 0, t, np.nan)
    pts = ray * t[:, None]
    return pts, ((pts - o) @ pose[:3, :3])[:, :2]


def _lift(camera: OpenCVCamera, pose: np.ndarray, u, v, spec) -> tuple[np.ndarray, int]:
    """Laser pixels lifted onto a pose's plane and kept where they fall on the printed pattern.

    Returns the points on one straight line there (the laser's trace on a flat board:
    :func:`_line_inliers`; none if fewer than ``MIN_LINE_POINTS`` or ``MIN_LINE_FRACTION`` of
    those on the pattern) [mm], and how many fell on the pattern.
    """
    u, v = np.asarray(u, np.float64), np.asarray(v, np.float64)
    pts, local = _lift_local(camera, pose, u, v)
    x0, y0, x1, y1 = spec.extent_mm()
    with np.errstate(invalid="ignore"):
        on = (local[:, 0] >= x0) & (local[:, 0] <= x1) & (local[:, 1] >= y0) & (local[:, 1] <= y1)
    if on.sum() < MIN_LINE_POINTS:
        return pts[:0], int(on.sum())
    scale = np.maximum(*(np.linalg.norm(_lift_local(camera, pose, u[on] + du, v[on] + dv)[1] - local[on], axis=1)
                         for du, dv in ((1.0, 0.0), (0.0, 1.0))))
    keep = _line_inliers(local[on], scale)
    line = keep.sum() >= max(MIN_LINE_POINTS, MIN_LINE_FRACTION * on.sum())
    return (pts[on][keep] if line else pts[:0]), int(on.sum())


def _line_inliers(xy: np.ndarray, scale_mm: np.ndarray, tol_px: float = LINE_TOL_PX, trials: int = 256) -> np.ndarray:
    """The points of the one straight line most of them lie on (RANSAC, then total least squares).

    Parameters
    ----------
    xy : (n, 2) float
        Points in the board's plane [mm].
    scale_mm : (n,) float
        Each point's footprint: millimetres per pixel there [mm/px].
    tol_px : float
        A point belongs to the line within this distance, in its own pixels [px].
    trials : int
        Point pairs tried (seeded: the same points give the same answer).

    Returns
    -------
    (n,) bool
        The line's points.
    """
    n = len(xy)
    if n < 2:
        return np.zeros(n, bool)
    rng = np.random.default_rng(0x1A5E)
    i, j = rng.integers(0, n, trials), rng.integers(0, n, trials)
    d = xy[j] - xy[i]
    length = np.hypot(d[:, 0], d[:, 1])
    ok = length > 0
    normal = np.c_[-d[ok, 1], d[ok, 0]] / length[ok, None]
    if not ok.any():
        return np.zeros(n, bool)
    r = np.abs(np.einsum("tk,tnk->tn", normal, xy[None, :, :] - xy[i[ok], None, :])) / scale_mm
    best = r[np.argmax((r < tol_px).sum(axis=1))] < tol_px
    for _ in range(4):
        if best.sum() < 2:
            break
        c = xy[best].mean(axis=0)
        nrm = np.linalg.svd(xy[best] - c, full_matrices=False)[2][1]
        new = np.abs((xy - c) @ nrm) / scale_mm < tol_px
        if np.array_equal(new, best):
            break
        best = new
    return best


def _board_outline_px(camera: OpenCVCamera, pose: np.ndarray, spec, per_side: int = 16) -> np.ndarray:
    """The printed area's outline in the image (its sides sampled, so that distortion bends them) [px]."""
    x0, y0, x1, y1 = spec.extent_mm()
    s = np.linspace(0.0, 1.0, per_side, endpoint=False)
    xs, ys = x0 + s * (x1 - x0), y0 + s * (y1 - y0)
    xy = np.concatenate([np.c_[xs, np.full_like(s, y0)], np.c_[np.full_like(s, x1), ys],
                         np.c_[xs[::-1] + (x1 - x0) / per_side, np.full_like(s, y1)],
                         np.c_[np.full_like(s, x0), ys[::-1] + (y1 - y0) / per_side]])
    p = np.c_[xy, np.zeros(len(xy))] @ pose[:3, :3].T + pose[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        u, v = camera.pixel_from_normalized(p[:, 0] / p[:, 2], p[:, 1] / p[:, 2])
    return np.where((p[:, 2] > 0)[:, None], np.c_[u, v], np.nan)


def _laser_image(ff: FrameFolder, i: int, laser_off: int | None, noise) -> tuple[np.ndarray, np.ndarray, Any]:
    """A laser frame with its laser-off frame subtracted (or as it is), the frame, and the noise (σ or a map)."""
    frame = ff.read(i)
    if laser_off is None:
        return frame, frame, noise
    off = ff.read(laser_off)
    return subtract_background(frame, off), frame, noise_map(off, noise)


def _pose_laser(ff: FrameFolder, pose: _Pose, fit: _Fit, spec, along: str, detector: str,
                counts: dict | None = None) -> np.ndarray:
    """One pose's laser points on the board's line, lifted onto its plane [mm].

    ``counts`` gets ``found`` (the whole frame), ``on_board`` (on the printed pattern) and
    ``on_line`` (on its straight line).
    """
    mask = board_mask(_board_outline_px(fit.camera, fit.poses[pose.index], spec), (ff.rows, ff.columns))
    pts = []
    for i, off, noise, skip in zip(pose.laser, pose.laser_off, pose.laser_noise, pose.laser_skip):
        if skip:
            continue
        img, frame, noise = _laser_image(ff, i, off, noise)
        sat = ff.saturation_dn(frame)
        if counts is not None:
            counts["found"] = counts.get("found", 0) + len(line_points(img, noise, along=along, detector=detector,
                                                                       saturation_dn=sat)[0])
        u, v = line_points(within_board(img, mask, along), noise, along=along, detector=detector, saturation_dn=sat)
        if len(u):
            line, on_board = _lift(fit.camera, fit.poses[pose.index], u, v, spec)
            pts.append(line)
            if counts is not None:
                counts["on_board"] = counts.get("on_board", 0) + on_board
    out = np.concatenate(pts) if pts else np.zeros((0, 3))
    if counts is not None:
        counts["on_line"] = len(out)
    return out


def _laser_points(ff: FrameFolder, poses, fit: _Fit, spec, along: str, detector: str) -> dict:
    out = {}
    for pose in poses:
        if pose.index not in fit.poses or not pose.laser:
            continue
        pts = _pose_laser(ff, pose, fit, spec, along, detector)
        if len(pts) >= 3:
            out[pose.index] = pts
    return out


def _laser_off_of(ff: FrameFolder, pose: _Pose, i: int, mode: str, room_light: bool) -> tuple[int | None, str]:
    """The laser-off frame subtracted from laser frame ``i`` of a pose, and why.

    See the module docstring of :mod:`scheimpflug.calibration.laser_background`.
    """
    if mode == "none":
        return None, "none (--laser-background none)"
    if pose.background is not None:
        return pose.background, f"its laser-off frame {ff.frames[pose.background].file}"
    flood = ff.frames[pose.flood].file
    if mode == "pose":
        return pose.flood, f"its pose's flood frame {flood} (--laser-background pose)"
    match = same_light(ff.read(i), ff.read(pose.flood))
    if room_light:
        return pose.flood, f"its pose's flood frame {flood} (room light; {match.reason()})"
    if match.agree:
        return pose.flood, f"its pose's flood frame {flood} (the same light: {match.reason()})"
    return None, f"none: its pose's flood frame {flood} was taken under other light ({match.reason()})"


def _paired(ff: FrameFolder, poses: list[_Pose], mode: str, room_light: bool,
            along: str) -> tuple[list[_Pose], dict]:
    """The poses with each laser frame's laser-off frame chosen, and what was chosen per laser frame."""
    if mode not in BACKGROUND_MODES:
        raise CalibrationError(f"--laser-background {mode!r}: one of {', '.join(BACKGROUND_MODES)}")
    out, used = [], {}
    for pose in poses:
        chosen = [_laser_off_of(ff, pose, i, mode, room_light) for i in pose.laser]
        used.update({i: why for i, (_, why) in zip(pose.laser, chosen)})
        noise = [frame_noise_dn(ff.read(i)) if off is None else difference_noise(ff.read(i), ff.read(off))
                 for i, (off, _) in zip(pose.laser, chosen)]
        skip = [None if off is not None else _scene_not_laser(ff, pose, i, along) for i, (off, _) in
                zip(pose.laser, chosen)]
        out.append(replace(pose, laser_off=tuple(off for off, _ in chosen), laser_noise=tuple(noise),
                           laser_skip=tuple(skip)))
    return out, used


def _scene_not_laser(ff: FrameFolder, pose: _Pose, i: int, along: str) -> str | None:
    """Why laser frame ``i``, found without a subtraction, shows the scene and not the laser, or None."""
    off = pose.background if pose.background is not None else pose.flood
    frame = ff.read(i)
    shared = shared_fraction(frame, ff.read(off), along=along, saturation_dn=ff.saturation_dn(frame))
    if shared <= SHARED_FRACTION:
        return None
    return (f"no laser line: {100 * shared:.0f} % of what it shows is in its pose's laser-off frame "
            f"{ff.frames[off].file} too (the print, not the laser), and no laser-off frame was subtracted")


def _laser_report(ff: FrameFolder, poses, fit: _Fit, spec, along: str, detector: str, used: dict,
                  plane) -> tuple[list[dict], list[str]]:
    """Per laser pose: its frames, the background used, the points found, on the board and in the plane fit."""
    rows, notes, pts = [], [], {}
    for pose in poses:
        if not pose.laser:
            continue
        files = [ff.frames[i].file for i in pose.laser]
        row = {"pose": pose.index, "laser_frames": files, "background": [used[i] for i in pose.laser],
               "points_found": 0, "points_on_board": 0, "points_on_line": 0, "points_in_plane_fit": 0}
        if pose.index not in fit.poses:
            row["note"] = "the pattern was not found in its flood-lit frame: no plane to lift the line onto"
        else:
            counts: dict = {}
            pts[pose.index] = _pose_laser(ff, pose, fit, spec, along, detector, counts)
            row.update(points_found=counts.get("found", 0), points_on_board=counts.get("on_board", 0),
                       points_on_line=counts.get("on_line", 0))
            if len(pts[pose.index]) >= 3:
                row["line_residual_mm"] = _line_residual(pts[pose.index])
            if row["points_on_line"] < 3:
                row["note"] = _no_line(row, pose)
                notes.append(f"pose {pose.index} ({', '.join(files)}): {row['note']}")
        rows.append(row)
    if plane is not None:
        _count_plane_inliers(rows, pts, plane)
    for row in rows:
        if plane is None:
            row["points_in_plane_fit"] = None
        row["dropped"] = {"off_the_pattern": max(row["points_found"] - row["points_on_board"], 0),
                          "off_its_line": row["points_on_board"] - row["points_on_line"],
                          "plane_fit_outliers": None if plane is None else
                          row["points_on_line"] - row["points_in_plane_fit"]}
    return rows, notes


def _no_laser_anywhere(ff: FrameFolder, poses) -> None:
    """Refuse laser frames of which none had a laser-off frame subtracted and none shows the line."""
    laser = [(pose, i, off) for pose in poses for i, off in zip(pose.laser, pose.laser_off)]
    if not laser or any(off is not None for _, _, off in laser):
        return
    shown = "; ".join(f"pose {p.index}: {ff.frames[i].file}" for p, i, _ in laser[:4])
    shown += " …" if len(laser) > 4 else ""
    raise CalibrationError(
        f"no laser line on the pattern in any of the {len(laser)} laser frame(s), and none had a laser-off frame "
        "subtracted: on a lit board the line is only the difference of a laser frame and the same view with the "
        "laser off. Take each pose twice with the same exposure, laser off and laser on, and give both the pose's "
        "id (light 'flood' and 'laser'; import --room-light), or --laser-background pose (" + shown + ")")


def _line_residual(points_mm: np.ndarray) -> dict:
    """How straight a pose's laser points are: distances from their total-least-squares 3-D line [mm]."""
    c = points_mm.mean(axis=0)
    d = np.linalg.svd(points_mm - c, full_matrices=False)[2][0]
    r = np.linalg.norm(np.cross(points_mm - c, d), axis=1)
    return {"median": float(np.median(r)), "rms": float(np.sqrt(np.mean(r**2))), "p95": float(np.percentile(r, 95)),
            "length": float(np.ptp((points_mm - c) @ d))}


def _no_line(row: dict, pose: _Pose) -> str:
    skips = [s for s in pose.laser_skip if s]
    if skips:
        return skips[0]
    if row["points_found"] == 0:
        bg = "" if any(off is not None for off in pose.laser_off) else " (no laser-off frame subtracted)"
        return f"no laser line found{bg}: it adds nothing to the laser plane"
    return (f"{row['points_found']} laser points found, {row['points_on_board']} on the printed pattern, "
            f"{row['points_on_line']} on one straight line there: it adds nothing to the laser plane")


def _count_plane_inliers(rows: list[dict], pts: dict, plane) -> None:
    """Each pose's points within the plane fit's outlier threshold (the same rule as :func:`fit_laser_plane`)."""
    used = {k: v for k, v in pts.items() if len(v) >= 3}
    if not used:
        return
    allp = np.concatenate(list(used.values()))
    try:
        _, keep = fit_laser_plane(allp)
    except CalibrationError:
        return
    start = 0
    for k, v in used.items():
        n = int(keep[start:start + len(v)].sum())
        start += len(v)
        next(r for r in rows if r["pose"] == k)["points_in_plane_fit"] = n


def _lines_on_one_plane(points: dict, poses: list, fit: _Fit, notes: list) -> tuple[dict, list]:
    """The poses whose laser line lies on the plane the lines share; the others left out, said.

    A pose's line lies off the plane when its points' median distance from the robust plane
    of all exceeds ``OFF_PLANE_PX`` pixels of the pose's footprint (``z / f``): a pattern's
    edge or a reflection taken for the line, a pose's plane found wrong.

    With two poses there is no majority: either line off their common plane refuses both.

    Raises
    ------
    CalibrationError
        Fewer than 2 poses' lines on one plane.
    """
    if len(points) < 2:
        return points, poses
    plane = _plane_and_spread(points)[0]
    off = {}
    for k, p in points.items():
        footprint_mm = float(np.median(p[:, 2])) / fit.camera.focal_px
        px = float(np.median(np.abs(p @ plane[:3] + plane[3]))) / footprint_mm
        if px > OFF_PLANE_PX:
            off[k] = px
    if not off:
        return points, poses
    if len(points) - len(off) < 2 or (len(points) == 2 and off):
        corners = sorted(fit.used.values())
        raise CalibrationError(f"the laser lines found on {len(points)} poses do not lie on one plane (median "
                               f"{min(off.values()):.3g} … {max(off.values()):.3g} px off the plane of all): either "
                               "what was found is not the laser's line (on a lit board subtract each pose's laser-off "
                               "frame: --laser-background auto or pose) or the poses' planes are off (a pattern too "
                               f"small to fix each pose: {corners[0]}–{corners[-1]} corners per pose, reprojection "
                               f"{fit.rms_px:.3g} px RMS)")
    for k, px in sorted(off.items()):
        notes.append(f"pose {k}: its laser line lies {px:.3g} px (median) off the plane the other poses' lines "
                     "share: left out")
    why = "its line lies off the plane the other poses' lines share"
    poses = [replace(p, laser_skip=tuple(why for _ in p.laser)) if p.index in off else p for p in poses]
    return {k: v for k, v in points.items() if k not in off}, poses


def _plane_and_spread(points: dict) -> tuple[np.ndarray, float, int, dict]:
    """The laser plane, its RMS [mm], the points used, and the jackknife σ over poses."""
    if len(points) < 2:
        raise CalibrationError(f"the laser plane needs the laser line on at least 2 poses of the pattern; "
                               f"{len(points)} pose(s) show it")
    allp = np.concatenate(list(points.values()))
    plane, keep = fit_laser_plane(allp)
    r = allp[keep] @ plane[:3] + plane[3]
    sigma = {}
    if len(points) >= 3:
        jack = []
        for k in points:
            rest = np.concatenate([v for j, v in points.items() if j != k])
            try:
                jack.append(fit_laser_plane(rest)[0])
            except CalibrationError:
                continue
        if len(jack) >= 3:
            jack = np.array([j if j[:3] @ plane[:3] > 0 else -j for j in jack])
            m = len(jack)
            ang = np.degrees(np.arccos(np.clip(jack[:, :3] @ plane[:3], -1.0, 1.0)))
            spread_d = np.sum((jack[:, 3] - jack[:, 3].mean()) ** 2)
            sigma = {"laser_plane_normal_deg": float(math.sqrt((m - 1) / m * np.sum(ang ** 2))),
                     "laser_plane_distance_mm": float(math.sqrt((m - 1) / m * spread_d))}
    return plane, float(np.sqrt(np.mean(r ** 2))), int(keep.sum()), sigma


# ---------------------------------------------------------------- the tilt, the axis, the result


def _pose_plane(m: np.ndarray) -> np.ndarray:
    n = m[:3, 2]
    d = -float(n @ m[:3, 3])
    return np.array([*n, d]) if d < 0 else -np.array([*n, d])


def _refocus(ff, poses, dets, spec, size, fit: _Fit, plane, pitch_um, flags, along, detector):
    """Iterate the focus condition (module docstring): axis → tilted camera → refit → laser plane."""
    for _ in range(4):
        axis, _ = focus_axis(fit.camera, plane, pitch_um)
        if np.degrees(math.acos(min(1.0, abs(axis[2]) / np.linalg.norm(axis)))) < 1e-5:
            break
        start, _ = _tilted_from_axis(fit.camera, axis, pitch_um)
        fit = _calibrate(dets, spec, size, start, flags)
        points = _laser_points(ff, poses, fit, spec, along, detector)
        plane = _plane_and_spread(points)[0]
    return fit, plane


def _add_frame_sigma(sigma: dict, fit: _Fit, plane: np.ndarray) -> None:
    """The laser plane's normal σ with the camera frame's own: the principal point's error turns it.

    A principal point off by δc turns the camera frame (and every pose and the laser plane in
    it) by δc/f about the other image axis; the jackknife over poses, made with the camera
    held, does not see that.  σ_n² = σ_jack² + Σ (σ_c/f)²·|n × axis|².
    """
    if "laser_plane_normal_deg" not in sigma:
        return
    f = fit.camera.focal_px
    n = plane[:3]
    total = math.radians(sigma["laser_plane_normal_deg"]) ** 2
    for key, axis in (("cx", (0.0, 1.0, 0.0)), ("cy", (1.0, 0.0, 0.0))):
        if fit.stderr.get(key):
            total += (fit.stderr[key] / f) ** 2 * float(np.linalg.norm(np.cross(n, axis))) ** 2
    sigma["laser_plane_normal_deg"] = math.degrees(math.sqrt(total))


def _deblur(ff, poses, dets, spec, size, fit: _Fit, plane, pitch_um, flags, along, detector, f_number):
    """Take the blur spots' centroid shift out of the corners, refit, refocus (twice: it converges)."""
    for _ in range(2):
        _, f_lens = focus_axis(fit.camera, plane, pitch_um)
        fixed = {}
        for k, det in dets.items():
            if k not in fit.poses:
                continue
            m = fit.poses[k]
            x = spec.object_points()[det.ids].astype(np.float64) @ m[:3, :3].T + m[:3, 3]
            shift = blur_centroid_offsets(fit.camera, x, f_lens, f_number, pitch_um)
            fixed[k] = replace(det, corners_px=det.corners_px - shift)
        fit = _calibrate(fixed, spec, size, fit.camera, flags)
        plane = _plane_and_spread(_laser_points(ff, poses, fit, spec, along, detector))[0]
        fit, plane = _refocus(ff, poses, fixed, spec, size, fit, plane, pitch_um, flags, along, detector)
    return fit, plane


def _focus_spread(camera: OpenCVCamera, points: dict, pitch_um: float) -> dict:
    """Jackknife σ of τx, τy and the lens focal length over the laser poses."""
    if len(points) < 3:
        return {}
    rows = []
    for k in points:
        rest = {j: v for j, v in points.items() if j != k}
        try:
            plane = _plane_and_spread(rest)[0]
        except CalibrationError:
            continue
        a, f = focus_axis(camera, plane, pitch_um)
        rows.append((math.degrees(-a[1]), math.degrees(a[0]), f))
    if len(rows) < 3:
        return {}
    r = np.array(rows)
    m = len(r)
    sd = np.sqrt((m - 1) / m * np.sum((r - r.mean(axis=0)) ** 2, axis=0))
    return {"tau_x_deg": float(sd[0]), "tau_y_deg": float(sd[1]), "lens_focal_length_mm": float(sd[2])}


def axis_in_sheet(point_mm, direction, plane, e_s, e_h, origin) -> dict:
    """A rotary axis of the camera frame as the pipeline holds it: its stage coordinate in the sheet.

    The pipeline's part frame has the axis in the sheet, along ``e_h``
    (:func:`scheimpflug.reconstruct.part_from_sheet`).  A measured axis is projected into the
    laser plane; ``axis_mm`` is the stage coordinate of the projection at ``h = 0``; how far the
    axis is from lying in the sheet is kept beside it.

    Parameters
    ----------
    point_mm, direction : (3,) array_like float
        A point of the axis [mm] and its direction, camera frame.
    plane : (4,) array_like float
        The laser plane ``[a, b, c, d]`` (unit normal).
    e_s, e_h, origin : (3,) array_like float
        The sheet frame (:func:`scheimpflug.calibration.model.sheet_frame_from_plane`).

    Returns
    -------
    dict
        ``axis_mm`` [mm], ``point_mm``, ``direction``, ``origin_mm`` (the axis point whose
        projection into the sheet is at h = 0: the part frame's origin,
        :func:`scheimpflug.reconstruct.part_from_camera`), ``angle_to_sheet_deg`` [deg] and
        ``distance_to_sheet_mm`` (of that point) [mm].
    """
    q, w = np.asarray(point_mm, np.float64), np.asarray(direction, np.float64)
    w = w / np.linalg.norm(w)
    n, d = np.asarray(plane[:3], np.float64), float(plane[3])
    e_s, e_h, origin = (np.asarray(x, np.float64) for x in (e_s, e_h, origin))
    qp = q - (n @ q + d) * n
    wp = w - (n @ w) * n
    lam = -((qp - origin) @ e_h) / (wp @ e_h) if abs(wp @ e_h) > 1e-12 else 0.0
    foot = qp + lam * wp
    on_axis = q + lam * w
    return {"axis_mm": float((foot - origin) @ e_s), "point_mm": q.tolist(), "direction": w.tolist(),
            "origin_mm": on_axis.tolist(),
            "angle_to_sheet_deg": float(math.degrees(math.asin(min(1.0, abs(n @ w))))),
            "distance_to_sheet_mm": float(n @ on_axis + d)}


def _table_axis(table_planes: list, plane, e_s, e_h, origin) -> dict | None:
    """The rotary axis of the table poses' planes, in the camera frame and in sheet coordinates."""
    if len(table_planes) < 3:
        return None
    q, w, rms = rotary_axis_from_planes(np.array(table_planes))
    return {**axis_in_sheet(q, w, plane, e_s, e_h, origin), "poses": len(table_planes), "plane_rms_mm": rms}


def _table_planes(poses, fit: _Fit, table: FrameFolder | None, spec, refine: str, notes: list) -> list:
    """Planes of the table poses: this folder's (``angle_deg``) and those of a table folder (solvePnP)."""
    planes = [_pose_plane(fit.poses[p.index]) for p in poses if p.angle_deg is not None and p.index in fit.poses]
    if table is None:
        return planes
    k, d = fit.camera.camera_matrix, fit.camera.dist_coeffs
    views = frame_views(table.rig, (table.rows, table.columns), spec, table.stripe_along)
    for pose in _group_poses(table):
        rec = table.frames[pose.flood]
        det = detect_pattern(table.read(pose.flood), spec, refine=refine, file=rec.file, views=views)
        if det is None or len(det) < 6:
            notes.append(f"table {rec.file}: skipped: pattern {spec.text} not found")
            continue
        ok, rv, tv = cv2.solvePnP(spec.object_points()[det.ids], det.corners_px.astype(np.float32), k, d)
        if ok:
            m = np.eye(4)
            m[:3, :3], m[:3, 3] = cv2.Rodrigues(rv)[0], tv.ravel()
            planes.append(_pose_plane(m))
    return planes


def _tilt_mode(tilt: str, rig_cam: OpenCVCamera | None, has_laser: bool, pitch_um: float | None) -> str:
    if tilt not in (*TILT_MODES, "auto"):
        raise CalibrationError(f"unknown tilt mode {tilt!r} (known: auto, {', '.join(TILT_MODES)})")
    tilted = rig_cam is not None and abs(rig_cam.tau_y_rad) + abs(rig_cam.tau_x_rad) > math.radians(0.5)
    if tilt == "auto":
        tilt = ("focus" if has_laser and pitch_um else "rig") if tilted else "none"
    if tilt == "rig" and rig_cam is None:
        raise CalibrationError("--tilt rig holds the manifest rig's design tilt: the manifest has no rig")
    if tilt == "focus" and not pitch_um:
        raise CalibrationError("--tilt focus needs the pixel pitch (the manifest's rig, --rig or --pixel-pitch-um): "
                               "the focus condition is in millimetres")
    return tilt


def calibrate_target_folder(folder: str | Path | FrameFolder, pattern: str, *, tilt: str = "auto",
                            pixel_pitch_um: float | None = None, f_number: float | None = None,
                            distortion: str = "k1k2", refine: str = "model",
                            detector: str = "cog", stripe_along: str | None = None, table=None,
                            laser_background: str = "auto", room_light: bool | None = None,
                            progress: ProgressCallback | None = None) -> TargetResult:
    """Calibrate the camera and the laser plane from a folder of pattern frames (module docstring).

    Parameters
    ----------
    folder : path or FrameFolder
        The target frames (``pose``, ``light`` and, on the table, ``angle_deg`` per frame).
    pattern : str
        The pattern spec (:func:`scheimpflug.calibration.pattern.parse_pattern`).
    tilt : {"auto", "focus", "rig", "none", "free"}, default "auto"
        How τx, τy are found; "rig": held at the manifest rig's design (a gauge: module docstring);
        "auto": "focus" for a tilted rig (the manifest's) with laser frames and a known pixel pitch,
        "rig" for one without laser frames, else "none".
    pixel_pitch_um : float, optional
        The sensor's pixel pitch [µm]; default the manifest's rig's.
    f_number : float, optional
        The lens's f-number at the calibration [-]; default the manifest's rig's.  With the focus
        condition it sizes the blur spots whose centroid shift is taken out of the corners
        (:func:`blur_centroid_offsets`); without it the shift stays (and biases the principal point).
    distortion : str, default "k1k2"
        The distortion terms fitted (a key of :data:`DISTORTION_MODELS`).
    refine : {"model", "subpix"}, default "model"
        The corners' sub-pixel refinement (:func:`scheimpflug.calibration.measure.detect_pattern`).
    detector : str, default "cog"
        Stripe centre method of the laser frames.
    stripe_along : {"columns", "rows"}, optional
        Which way the laser line runs in the image (:func:`scheimpflug.calibration.measure.stripe_points`);
        default the folder's (its manifest's ``stripe_along``, else "columns").
    table : path or FrameFolder, optional
        A folder of the pattern standing on the rotary table (``render target --on-table``): its poses,
        found with the calibrated camera, give the rotary axis (:func:`rotary_axis_from_planes`).
        Table poses (``angle_deg``) in ``folder`` itself count too.
    laser_background : {"auto", "pose", "none"}, default "auto"
        What is subtracted from a laser frame before its line is found: a pose's laser-off frame
        (``light`` "background") always, unless "none"; otherwise its flood-lit frame — "pose":
        always, "auto": when the two were taken under the same light
        (:func:`scheimpflug.calibration.laser_background.same_light`) or in room light.
    room_light : bool, optional
        The set was taken in room light: each pose's flood frame is its laser frames' laser-off
        frame (a warning where their light disagrees).  Default: the manifest's
        ``scenario_params.room_light``.
    progress : ProgressCallback, optional
        ``progress(done, total)`` over the flood frames.

    Returns
    -------
    TargetResult
        The calibration (:class:`TargetCalibration`) and its measurements.

    Raises
    ------
    CalibrationError
        One line naming the problem: the pattern found in no frame (with the size it seems to
        have), fewer than 3 usable poses, parallel poses, laser frames without their flood-lit
        frame, the laser on fewer than 2 poses, an unknown tilt, distortion or laser-background
        mode, flood frames of one pose showing it in different places, laser frames of which none
        had its laser-off frame subtracted and none shows the line (take laser-off frames).
    MeshError
        A bad pattern spec.
    """
    ff = folder if isinstance(folder, FrameFolder) else open_frame_folder(folder)
    spec = parse_pattern(pattern)
    if distortion not in DISTORTION_MODELS:
        raise CalibrationError(f"unknown distortion model {distortion!r} (known: {', '.join(DISTORTION_MODELS)})")
    if room_light is None:
        room_light = bool(ff.scenario_params.get("room_light", False))
    notes: list[str] = []
    poses = _group_poses(ff, notes if room_light else None)
    if not poses:
        raise CalibrationError(f"{str(ff.path)!r} holds no flood-lit frame of the pattern (light 'flood')")
    poses, background_used = _paired(ff, poses, laser_background, room_light, stripe_along or ff.stripe_along)
    dets, skipped = _detect_all(ff, poses, spec, refine, progress)
    _merge_repeats(ff, poses, dets, skipped, spec, refine, notes)
    if not dets:
        raise CalibrationError(f"pattern {spec.text} found in 0 of {len(poses)} flood-lit frames"
                               + _size_hint(ff, poses, spec))
    if len(dets) < MIN_POSES:
        raise CalibrationError(f"only {len(dets)} usable pose(s) of {len(poses)} (the pattern found); need at least "
                               f"{MIN_POSES}: " + "; ".join(f"{s['file']}: {s['reason']}" for s in skipped[:3]))
    size = (ff.columns, ff.rows)
    _check_not_parallel(dets, spec, size)
    rig_cam = _rig_camera(ff)
    pitch = pixel_pitch_um or ff.rig_value("sensor", "pixel_pitch_um")
    has_laser = any(p.laser and p.index in dets for p in poses)
    mode = _tilt_mode(tilt, rig_cam, has_laser, pitch)
    notes += [f"{s['file']}: skipped: {s['reason']}" for s in skipped]
    f_number = f_number or ff.rig_value("lens", "f_number")
    table_ff = None if table is None else (table if isinstance(table, FrameFolder) else open_frame_folder(table))
    return _calibrate_found(ff, poses, dets, skipped, spec, size, rig_cam, pitch, mode, distortion,
                            detector, stripe_along or ff.stripe_along, notes, f_number, table_ff, refine,
                            background_used)


def _untilted(camera: OpenCVCamera) -> OpenCVCamera:
    """The same images with τ = 0: ``K' = K·P_Z(τ)`` (module docstring; the distortion dropped)."""
    k = camera.camera_matrix @ _pz(camera)
    k = k / k[2, 2]
    return OpenCVCamera(np.array([[k[0, 0], 0.0, k[0, 2]], [0.0, k[1, 1], k[1, 2]], [0.0, 0.0, 1.0]]), np.zeros(14))


def _start_camera(dets: dict, spec, size, rig_cam: OpenCVCamera | None, mode: str) -> OpenCVCamera:
    """The fit's first guess: the rig's design camera, else Zhang's closed form (τ = 0); no distortion."""
    if rig_cam is not None:
        cam = _untilted(rig_cam) if mode == "none" else rig_cam
    else:
        hs = [cv2.findHomography(spec.corners_mm()[d.ids], d.corners_px, 0)[0] for d in dets.values()]
        cam = OpenCVCamera(_zhang([h for h in hs if h is not None], size), np.zeros(14))
    inside = 0 <= cam.principal_px[0] < size[0] and 0 <= cam.principal_px[1] < size[1]
    if mode == "free" and not inside:
        cam = _centred(cam, size)
    d = np.zeros(14)
    d[12:] = cam.dist_coeffs[12:]
    return OpenCVCamera(cam.camera_matrix, d)


def _calibrate_found(ff, poses, dets, skipped, spec, size, rig_cam, pitch, mode, distortion, detector, along,
                     notes, f_number, table=None, refine="model", background_used=None) -> TargetResult:
    flags = _flags(distortion, mode == "free", square=mode in ("focus", "rig"))
    fit = _calibrate(dets, spec, size, _start_camera(dets, spec, size, rig_cam, mode), flags)
    points = _laser_points(ff, poses, fit, spec, along, detector)
    plane, plane_rms, n_laser, plane_sigma, tilt_info = None, math.nan, 0, {}, {"mode": mode}
    if not points and any(p.laser for p in poses):
        _no_laser_anywhere(ff, poses)
        notes.append("no laser point on the pattern in any laser frame: a camera calibration only")
    if len(points) == 1:
        notes.append(f"the laser line on one pose only (pose {next(iter(points))}): no laser plane (it needs the line "
                     "on 2 poses or more); its points are in laser_poses")
        points = {}
    if points:
        points, poses = _lines_on_one_plane(points, poses, fit, notes)
        plane = _plane_and_spread(points)[0]
        if mode == "focus":
            fit, plane = _refocus(ff, poses, dets, spec, size, fit, plane, pitch, flags, along, detector)
            if f_number:
                fit, plane = _deblur(ff, poses, dets, spec, size, fit, plane, pitch, flags, along, detector,
                                     f_number)
            points = _laser_points(ff, poses, fit, spec, along, detector)
        plane, plane_rms, n_laser, plane_sigma = _plane_and_spread(points)
        if mode == "focus":
            _, f_lens = focus_axis(fit.camera, plane, pitch)
            tilt_info.update(lens_focal_length_mm=f_lens, pixel_pitch_um=pitch, f_number=f_number,
                             blur_centroids_corrected=bool(f_number))
            plane_sigma.update(_focus_spread(fit.camera, points, pitch))
            if not f_number:
                notes.append("no f-number (the manifest's rig or --f-number): the blur spots' centroid shift on "
                             "the tilted sensor is left in the corners")
        _add_frame_sigma(plane_sigma, fit, plane)
    elif mode == "focus":
        notes.append("no laser frames: τ is held where the fit started (without the laser plane the focus "
                     "condition cannot fix it; the tilt and the principal point are then a gauge)")
    used = [{"pose": k, "file": dets[k].file, "corners": n} for k, n in sorted(fit.used.items())]
    lost = [{"pose": k, "file": dets[k].file, "reason": "too few corners after dropping outliers"}
            for k in sorted(dets) if k not in fit.used]
    planes = _table_planes(poses, fit, table, spec, refine, notes)
    if 0 < len(planes) < 3:
        notes.append(f"{len(planes)} table pose(s) found: the rotary axis needs at least 3")
    cal = _calibration(fit, plane, planes, spec, size, skipped + lost, used, plane_rms, n_laser,
                       {**fit.stderr, **plane_sigma}, tilt_info, len(ff))
    laser_poses, laser_notes = _laser_report(ff, poses, fit, spec, along, detector, background_used or {}, plane)
    nominal, nominal_notes = _nominal_check(ff, fit, plane, tilt_info, pitch)
    return TargetResult(cal, dets, fit.poses, points, tuple(notes + laser_notes + nominal_notes), laser_poses,
                        nominal)


def _calibration(fit: _Fit, plane, table_planes, spec, size, skipped, used, plane_rms, n_laser, stderr, tilt_info,
                 n_frames) -> TargetCalibration:
    g, axis = np.full((3, 3), np.nan), None
    if plane is not None:
        o, e_s, e_h = sheet_frame_from_plane(plane)
        axis = _table_axis(table_planes, plane, e_s, e_h, o)
        if axis is not None:
            o, e_s, e_h = sheet_frame_from_plane(plane, np.asarray(axis["direction"]))
            axis = _table_axis(table_planes, plane, e_s, e_h, o)
        g = np.column_stack([e_s, e_h, o])
    return TargetCalibration(camera=fit.camera, homography=g, columns=int(size[0]), rows=int(size[1]),
                             n_frames=n_frames, residual_rms_px=fit.rms_px, laser_plane=plane, pattern=spec.text,
                             reprojection_rms_px=fit.rms_px, poses_used=tuple(used), poses_skipped=tuple(skipped),
                             stderr=stderr, laser_plane_rms_mm=plane_rms, laser_points=n_laser, axis=axis,
                             tilt=tilt_info)
