"""The paper's parameter-free calibration (Section 3) and a refined joint fit.

A plate of known height ``H`` (89 mm) stands on the translation stage and is
moved along the laser's propagation direction; at every stage coordinate
``s_i`` the sheet draws a vertical stripe on its face.  No rig parameter is
needed: from the frames alone we get

* **paper** estimate (paper Section 3, Fig. 3):
  the stripe's top and bottom endpoints (the plate's edges, sub-pixel) lie on
  two straight image lines through the image hinge (paper Eq. 8); each is
  fitted by least squares ``v = m u + b`` (R² reported) and their intersection
  is the hinge ``(u_h, v_h)``.  ``s`` is fitted linearly against
  ``1 / (u − u_h)``: slope F², intercept ``d0`` (Eq. 11).  Then per frame
  ``F²_i = (u_i − u_h)(s_i − d0)`` (mean and σ reported, as the paper's
  E(F²) and σ(F²)) and ``C_i = H / [(v_t − v_h)/(u_t − u_h) − (v_b − v_h)/(u_b − u_h)]``
  (Eq. 12 at both edges; mean and σ).
* **refined** estimate (beyond the paper): the paper finds ``u_h`` by
  extrapolating two lines fitted over ≈ 1200 columns to ≈ 3200, which
  magnifies the endpoint noise ≈ 5×.  The distance relation itself,
  ``u_i = u_h + F² / (s_i − d0)``, fixes ``u_h``, ``F²`` and ``d0`` jointly
  from the stripe centre of every lit row (one mean per frame), fitted by
  nonlinear least squares in ``u`` (the measured quantity; the stage
  positions are exact).  With ``u_h`` known, ``v_h`` and the two edge slopes
  ``a_t, a_b`` follow from one linear fit of all endpoints,
  ``v = v_h + (u − u_h) a``, and ``C = H / (a_t − a_b)``.  σ(F²) and σ(C) are
  the spreads of the per-frame values, as in the paper.

Every frame with a plate stripe takes part: a frame that shows one plate edge
only (the other beyond the sensor's rows) still gives its distance relation
and that edge's endpoint; C's per-frame spread uses the frames with both.

**Standard errors** (the calibration states its own accuracy): the refined
distance fit's covariance is σ_u²·(JᵀJ)⁻¹ with σ_u² = RSS/(n − 3) from its
residuals in u (one mean column per frame, n frames); the endpoint fit's is
σ_v²·(AᵀA)⁻¹ with σ_v² = RSS/(m − 3) (m endpoints), plus u_h's error carried
through the fit's dependence on u_h; C = H/(a_t − a_b) by its gradient.  The
paper estimate's σ(u_h), σ(v_h) come from the two endpoint lines' covariances
(intersection Jacobian), its σ(F²), σ(d0), σ(C) by the delta method (numerical
Jacobian of the whole estimate) with σ_u from the refined fit and each line's
own residual σ on its rows.  An exactly determined fit (n = 3, m = 3, a line
through 2 points) cannot show its noise: its standard errors are NaN (null in
JSON), never a tiny number.  They are first-order, noise-only figures: a bias
common to all frames (a miscalibrated stage, a lens error) is not in them.
:func:`accuracy_warnings` says when they are too large for a stated accuracy
(:class:`CalibrationAccuracy`) or do not exist.

The default ("best") is the estimate with the smaller standard error of
``u_h``; with usable frames that is nearly always the refined one.

Conventions (docs/explanation/design-notes.md §3): columns ``u`` increase with distance toward the
hinge (``u − u_h < 0``, ``F² < 0``); rows ``v`` increase downward, a point
above the optical axis (``h > 0``) images at ``v < v_h``.  Pixel ``k``'s centre
is ``u = k``.

How one plate frame is measured (stripe centres, sub-pixel endpoints, the detectors)
is :mod:`scheimpflug.calibration.measure`'s.
"""

from __future__ import annotations

import dataclasses
import json
import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy import optimize

from scheimpflug.calibration.camera import DEFAULT_FOCAL_LENGTH_MM, DEFAULT_PIXEL_PITCH_UM, ideal_camera
from scheimpflug.calibration.measure import (
    CalibrationTolerances,
    PlateMeasurement,
    check_plate_orientation,
    measure_plate_frame,
)
from scheimpflug.calibration.model import frame_size_from_json, size_problem, unknown_size_note
from scheimpflug.callbacks import report
from scheimpflug.errors import CalibrationError
from scheimpflug.io.atomic import write_json_atomic
from scheimpflug.io.frames import FrameFolder, check_distinct_frames, open_frame_folder, scenario_number
from scheimpflug.model.hinge import HingeGeometry, pixel_from_stage, stage_from_pixel

__all__ = [
    "Calibration",
    "CalibrationAccuracy",
    "CalibrationResult",
    "accuracy_warnings",
    "applicability_problem",
    "c_sigma_from_endpoint_fits",
    "check_against_manifest",
    "check_axis_position",
    "check_used_frames_distinct",
    "calibrate_folder",
    "calibrate_measurements",
    "endpoint_residual_px",
]


#: The thresholds a calibration uses unless given others.
DEFAULT_TOLERANCES = CalibrationTolerances()

_MAX_CONDITION = 1e12
"""A fit whose column-scaled normal matrix is worse conditioned than this is nearly singular:
its standard errors are undefined (NaN, null in JSON) [-]."""


# ---------------------------------------------------------------- result types


@dataclass(frozen=True)
class Calibration:
    """A calibration: pixel (u, v) → stage coordinate and height (paper Eqs. 11–12).

    Two kinds of uncertainty are reported.  ``F2_sigma_px_mm`` and
    ``C_sigma_mm`` are the paper's σ(F²) and σ(C): the *spread* of the
    per-frame values (docs/reference/interface.md).  The ``*_stderr_*`` fields and
    ``hinge_u_sigma_px``, ``hinge_v_sigma_px``, ``d0_sigma_mm`` are *standard
    errors* of the fitted constants, propagated to first order from the
    measurement noise that the fits' residuals show (module docstring); NaN
    (null in JSON) when a fit is exactly determined and cannot show its noise.

    Parameters
    ----------
    hinge_u_px, hinge_v_px : float
        Image hinge (u_h, v_h) [px].
    F2_px_mm : float
        F², distance constant [px·mm] (negative).
    F2_sigma_px_mm : float
        Spread (standard deviation) of the per-frame F² [px·mm].
    d0_mm : float
        Stage coordinate of the object hinge [mm].
    C_mm : float
        Height constant [mm].
    C_sigma_mm : float
        Spread of the per-frame C (frames with both plate edges) [mm].
    endpoint_fit_r2 : tuple of float
        R² of the (top, bottom) endpoint line fits [-].
    method : str
        "paper" or "refined".
    columns, rows : int
        Sensor size the calibration was made with [px].
    plate_height_mm : float
        The calibration plate's height [mm].
    n_frames : int
        Frames used (every frame with a plate stripe) [-].
    hinge_u_sigma_px, hinge_v_sigma_px : float
        Standard errors of u_h and v_h [px].
    F2_stderr_px_mm : float
        Standard error of F² [px·mm].
    d0_sigma_mm : float
        Standard error of d0 [mm].
    C_stderr_mm : float
        Standard error of C [mm].
    n_frames_both_edges : int
        Frames that showed both plate edges [-].
    warnings : tuple of str
        Accuracy warnings (:func:`accuracy_warnings`).
    estimates : dict
        JSON dicts of both estimates (``{"paper": ..., "refined": ...}``).
    pixel_pitch_um : float
        Pixel pitch of the frames it was made with (the manifest's rig, binned) [µm];
        NaN when unknown (no rig, or a file written before it was recorded).
    stage_range_mm : tuple of float
        Lowest and highest stage position of the frames used [mm] (NaN: unknown).
    """

    hinge_u_px: float
    hinge_v_px: float
    F2_px_mm: float
    F2_sigma_px_mm: float
    d0_mm: float
    C_mm: float
    C_sigma_mm: float
    endpoint_fit_r2: tuple[float, float]
    method: str
    columns: int
    rows: int
    plate_height_mm: float = 89.0
    n_frames: int = 0
    hinge_u_sigma_px: float = math.nan
    hinge_v_sigma_px: float = math.nan
    F2_stderr_px_mm: float = math.nan
    d0_sigma_mm: float = math.nan
    C_stderr_mm: float = math.nan
    n_frames_both_edges: int = 0
    warnings: tuple[str, ...] = field(default=(), compare=False, hash=False)
    estimates: dict = field(default_factory=dict, compare=False, hash=False, repr=False)
    pixel_pitch_um: float = math.nan
    stage_range_mm: tuple[float, float] = (math.nan, math.nan)

    def stage_from_pixel(self, u, v) -> tuple[np.ndarray, np.ndarray]:
        """Stage coordinate and height of pixel (u, v) (paper Eqs. 11–12).

        Parameters
        ----------
        u, v : array_like float
            Column and row on the sensor [px], shapes that broadcast together.

        Returns
        -------
        stage_mm, h_mm : ndarray float64
            ``F²/(u − u_h) + d0`` and ``C·(v − v_h)/(u − u_h)`` [mm]; NaN at u = u_h
            (:func:`scheimpflug.model.hinge.stage_from_pixel`).

        Raises
        ------
        ValueError
            If ``u`` and ``v`` do not broadcast together.
        """
        return stage_from_pixel(u, v, *self.constants())

    def pixel_from_stage(self, stage_mm, h_mm) -> tuple[np.ndarray, np.ndarray]:
        """Pixel of a sheet point: the inverse of :meth:`stage_from_pixel`.

        Parameters
        ----------
        stage_mm, h_mm : array_like float
            Stage coordinate and height above the meridian plane [mm], shapes
            that broadcast together.

        Returns
        -------
        u_px, v_px : ndarray float64
            Pixel (u, v) [px]; NaN at ``stage_mm = d0``
            (:func:`scheimpflug.model.hinge.pixel_from_stage`).

        Raises
        ------
        ValueError
            If ``stage_mm`` and ``h_mm`` do not broadcast together.
        """
        return pixel_from_stage(stage_mm, h_mm, *self.constants())

    def _decomposed(self, focal_length_mm: float | None):
        pitch = self.pixel_pitch_um if math.isfinite(self.pixel_pitch_um) else DEFAULT_PIXEL_PITCH_UM
        camera, g = ideal_camera(self, focal_length_mm or DEFAULT_FOCAL_LENGTH_MM, pitch)
        return camera, g / np.linalg.norm(g[:, 0])

    def camera_from_pixel(self, u, v, focal_length_mm: float | None = None) -> np.ndarray:
        """The sheet point a pixel sees, in OpenCV's camera frame of the ideal rig behind the constants.

        The constants fix the mapping, not the camera: it is decomposed with the
        lens's focal length and the recorded pixel pitch (:func:`scheimpflug.calibration.camera.ideal_camera`;
        defaults: the paper's 55 mm and 5.86 µm where not known).

        Parameters
        ----------
        u, v : array_like float
            Column and row [px], broadcast together.
        focal_length_mm : float, optional
            The lens's focal length [mm] (default 55).

        Returns
        -------
        (..., 3) float64
            X, Y, Z [mm] (one stage millimetre is one millimetre).

        Raises
        ------
        CalibrationError
            The constants are not an ideal Scheimpflug rig with that focal length and pitch.
        """
        _, g = self._decomposed(focal_length_mm)
        s, h = np.broadcast_arrays(*self.stage_from_pixel(u, v))
        return s[..., None] * g[:, 0] + h[..., None] * g[:, 1] + g[:, 2]

    def pixel_from_camera(self, points_mm, focal_length_mm: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Pixel of camera-frame points, through the decomposed camera (:meth:`camera_from_pixel`).

        Parameters
        ----------
        points_mm : (..., 3) array_like float
            X, Y, Z [mm].
        focal_length_mm : float, optional
            The lens's focal length [mm] (default 55).

        Returns
        -------
        u_px, v_px : ndarray float64
            Column and row [px].

        Raises
        ------
        CalibrationError
            As :meth:`camera_from_pixel`.
        """
        camera, _ = self._decomposed(focal_length_mm)
        q = np.asarray(points_mm, np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            return camera.pixel_from_normalized(q[..., 0] / q[..., 2], q[..., 1] / q[..., 2])

    def constants(self) -> tuple[float, float, float, float, float]:
        """The calibration constants in the order of the hinge functions.

        Returns
        -------
        tuple of float
            (u_h [px], v_h [px], F² [px·mm], d0 [mm], C [mm]), as
            :func:`scheimpflug.model.hinge.stage_from_pixel` takes them.
        """
        return self.hinge_u_px, self.hinge_v_px, self.F2_px_mm, self.d0_mm, self.C_mm

    def _core_dict(self) -> dict[str, Any]:
        return {"hinge_px": [self.hinge_u_px, self.hinge_v_px], "F2_px_mm": self.F2_px_mm,
                "F2_sigma_px_mm": _json_float(self.F2_sigma_px_mm), "d0_mm": self.d0_mm,
                "C_mm": self.C_mm, "C_sigma_mm": _json_float(self.C_sigma_mm),
                "endpoint_fit_r2": [_json_float(x) for x in self.endpoint_fit_r2],
                "hinge_u_sigma_px": _json_float(self.hinge_u_sigma_px),
                "hinge_v_sigma_px": _json_float(self.hinge_v_sigma_px),
                "F2_stderr_px_mm": _json_float(self.F2_stderr_px_mm),
                "d0_sigma_mm": _json_float(self.d0_sigma_mm),
                "C_stderr_mm": _json_float(self.C_stderr_mm), "method": self.method,
                "n_frames": self.n_frames, "n_frames_both_edges": self.n_frames_both_edges}

    def to_json_dict(self) -> dict[str, Any]:
        """docs/reference/interface.md calibrate fields, the standard errors, both estimates and the sensor size.

        Returns
        -------
        dict
            JSON-ready; a value that does not exist (a spread of one frame, the
            standard error of an exactly determined fit) is None.
        """
        d = self._core_dict()
        d.update(columns=self.columns, rows=self.rows, plate_height_mm=self.plate_height_mm,
                 pixel_pitch_um=_json_float(self.pixel_pitch_um),
                 stage_range_mm=[_json_float(x) for x in self.stage_range_mm], warnings=list(self.warnings))
        d.update({k: v for k, v in self.estimates.items()})
        return d

    def save(self, path: str | Path) -> None:
        """Write :meth:`to_json_dict` to a file atomically.

        Parameters
        ----------
        path : str or Path
            Destination JSON file.
        """
        write_json_atomic(path, self.to_json_dict())

    @classmethod
    def from_json_dict(cls, d: dict) -> Calibration:
        """A calibration from the dict of :meth:`to_json_dict` (or of ``calibrate --json``).

        Parameters
        ----------
        d : dict
            Needs ``hinge_px``, ``F2_px_mm``, ``d0_mm``, ``C_mm``; the rest is optional.

        Returns
        -------
        Calibration
            The calibration (absent or null uncertainties are NaN).

        Raises
        ------
        CalibrationError
            A required field is missing or not a number, or the frame size is malformed
            (:func:`scheimpflug.calibration.model.frame_size_from_json`).
        """
        try:
            columns, rows = frame_size_from_json(d)
        except CalibrationError as exc:
            raise CalibrationError(f"calibration data garbles a field: {exc}") from None
        try:
            r2 = d.get("endpoint_fit_r2") or [None, None]
            return cls(hinge_u_px=_num(d["hinge_px"][0]), hinge_v_px=_num(d["hinge_px"][1]),
                       F2_px_mm=_num(d["F2_px_mm"]), F2_sigma_px_mm=_float(d, "F2_sigma_px_mm"),
                       d0_mm=_num(d["d0_mm"]), C_mm=_num(d["C_mm"]), C_sigma_mm=_float(d, "C_sigma_mm"),
                       endpoint_fit_r2=(_float(r2, 0), _float(r2, 1)),
                       method=str(d.get("method", "paper")), columns=columns, rows=rows,
                       plate_height_mm=_num(d.get("plate_height_mm", 89.0)),
                       n_frames=_whole(d.get("n_frames", 0)),
                       hinge_u_sigma_px=_float(d, "hinge_u_sigma_px"),
                       hinge_v_sigma_px=_float(d, "hinge_v_sigma_px"),
                       F2_stderr_px_mm=_float(d, "F2_stderr_px_mm"), d0_sigma_mm=_float(d, "d0_sigma_mm"),
                       C_stderr_mm=_float(d, "C_stderr_mm"),
                       n_frames_both_edges=_whole(d.get("n_frames_both_edges", 0)),
                       warnings=tuple(str(w) for w in d.get("warnings", ())),
                       estimates={k: d[k] for k in ("paper", "refined") if k in d},
                       pixel_pitch_um=_float(d, "pixel_pitch_um"),
                       stage_range_mm=_pair(d.get("stage_range_mm")))
        except (KeyError, TypeError, ValueError, IndexError, OverflowError) as exc:
            raise CalibrationError(f"calibration data lacks or garbles a field: {exc!r}") from None

    @classmethod
    def load(cls, path: str | Path) -> Calibration:
        """Read a calibration JSON written by :meth:`save` (or by ``scheimpflug calibrate``).

        Parameters
        ----------
        path : str or Path
            The calibration file.

        Returns
        -------
        Calibration
            The calibration.

        Raises
        ------
        CalibrationError
            If the file is missing, unreadable or not a JSON object, lacks or
            garbles a field, or describes an impossible calibration
            (:meth:`problem`).
        """
        p = Path(path)
        try:
            d = json.loads(p.read_text("utf-8"))
        except FileNotFoundError:
            raise CalibrationError(f"calibration file {str(p)!r} does not exist") from None
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise CalibrationError(f"calibration file {str(p)!r} is unreadable: {exc}") from None
        if not isinstance(d, dict):
            raise CalibrationError(f"calibration file {str(p)!r} must hold a JSON object")
        try:
            cal = cls.from_json_dict(d)
        except CalibrationError as exc:
            raise CalibrationError(f"calibration file {str(p)!r}: {exc}") from None
        problem = cal.problem()
        if problem:
            raise CalibrationError(f"calibration file {str(p)!r}: {problem}")
        return cal

    def problem(self, columns: int | None = None, rows: int | None = None) -> str | None:
        """What makes this calibration impossible, or inapplicable to frames of a size, or None.

        Parameters
        ----------
        columns : int, optional
            Columns of the frames it will be applied to [px]; default the
            calibration's own (0: unknown, the hinge check is skipped).
        rows : int, optional
            Rows of those frames [px]; with ``columns``, frames of another size than
            the calibration records are refused (:func:`~scheimpflug.calibration.model.size_problem`).

        Returns
        -------
        str or None
            The first problem, naming the field: frames of another size, a
            non-finite constant, a σ that is negative or infinite, F² ≥ 0,
            C ≤ 0, a value beyond any rig (|u_h|, |v_h| > 1e7 px, |d0| > 1e6
            mm), the image hinge not beyond the last column (the sensor would
            contain the hinge), a plate height not > 0; None if none.
        """
        size = size_problem(self, columns, rows)
        if size:
            return size
        names = ("hinge_u_px", "hinge_v_px", "F2_px_mm", "d0_mm", "C_mm")
        for name, value in zip(names, self.constants()):
            if not math.isfinite(value):
                return f"{name} = {value} must be finite"
        for name in ("F2_sigma_px_mm", "C_sigma_mm", *_STDERR_KEYS):
            value = getattr(self, name)
            if not (math.isnan(value) or 0 <= value < math.inf):
                return f"{name} = {value} must be >= 0 (or null: undefined)"
        if not self.F2_px_mm < 0:
            return f"F2_px_mm = {self.F2_px_mm:.6g} must be < 0 (columns increase toward the hinge)"
        if not self.C_mm > 0:
            return f"C_mm = {self.C_mm:.6g} must be > 0"
        if max(abs(self.hinge_u_px), abs(self.hinge_v_px)) > 1e7 or abs(self.d0_mm) > 1e6:
            return "hinge_px beyond ±1e7 px or d0_mm beyond ±1e6 mm: not a rig's calibration"
        n = self.columns if columns is None else columns
        if n and not self.hinge_u_px > n - 0.5:
            return (f"image hinge u_h = {self.hinge_u_px:.6g} px lies inside the {n}-column sensor: it "
                    f"must lie beyond the last column (> {n - 0.5}); a hinge on the sensor images "
                    "points at infinity")
        if not (math.isfinite(self.plate_height_mm) and self.plate_height_mm > 0):
            return f"plate_height_mm = {self.plate_height_mm} must be > 0"
        if not (math.isnan(self.pixel_pitch_um) or 0 < self.pixel_pitch_um < 1e4):
            return f"pixel_pitch_um = {self.pixel_pitch_um} must be > 0 (or null: unknown)"
        return None




def _json_float(x: float):
    return None if x is None or not math.isfinite(x) else float(x)


def _float(d, key) -> float:
    """``d[key]`` as a float; NaN when absent or null; a boolean or a string is refused."""
    try:
        value = d[key]
    except (KeyError, IndexError, TypeError):
        return math.nan
    try:
        return _num(value)
    except TypeError as exc:
        raise TypeError(f"{key}: {exc}") from None


def _num(x) -> float:
    """A JSON number as float; null = undefined = NaN; booleans and strings are refused."""
    if x is None:
        return math.nan
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        raise TypeError(f"{x!r:.40} is not a number")
    return float(x)


def _pair(x) -> tuple[float, float]:
    """A JSON [lo, hi] pair of numbers (null entries NaN); absent: (NaN, NaN)."""
    if x is None:
        return (math.nan, math.nan)
    if not isinstance(x, (list, tuple)) or len(x) != 2:
        raise ValueError(f"{x!r:.40} is not a [lo, hi] pair")
    return (_num(x[0]), _num(x[1]))


def _whole(x) -> int:
    """A JSON count as int in [0, 65535] (an integral float is fine)."""
    v = _num(x)
    if not (v.is_integer() and 0 <= v <= 65535):
        raise ValueError(f"{x!r:.40} is not a count in [0, 65535]")
    return int(v)




@dataclass(frozen=True)
class CalibrationResult:
    """Both estimates, the chosen one and the diagnostics for plots.

    Parameters
    ----------
    best : Calibration
        The chosen estimate.
    paper, refined : Calibration
        Both estimates.
    measurements : tuple of PlateMeasurement
        The usable frames' measurements.
    skipped : tuple of (str, str)
        (file or index, reason) of every frame not used.
    top_line, bottom_line : tuple of float
        (m, b) of the paper's endpoint fits v = m u + b.
    partial : tuple of (str, str), default ()
        (file, "top" or "bottom": the edge not seen) of frames used with one edge.
    warnings : tuple of str, default ()
        What the user should know about the frames (too few of them, the
        estimate preferred because the other's σ is undefined), one line each;
        the estimates' own accuracy warnings are in ``Calibration.warnings``.
    """

    best: Calibration
    paper: Calibration
    refined: Calibration
    measurements: tuple[PlateMeasurement, ...]
    skipped: tuple[tuple[str, str], ...]
    top_line: tuple[float, float]
    bottom_line: tuple[float, float]
    partial: tuple[tuple[str, str], ...] = ()
    warnings: tuple[str, ...] = ()

    @property
    def model(self) -> Calibration:
        """The sheet model this calibration gives: :attr:`best`."""
        return self.best


# ---------------------------------------------------------------- the fits


def _line_fit(x: np.ndarray, y: np.ndarray):
    """Y = m x + b: (m, b), R², and the 2×2 covariance of (m, b) (None when exactly determined)."""
    A = np.column_stack([x, np.ones_like(x)])
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    r = y - A @ coef
    ss_tot = float(np.sum((y - y.mean()) ** 2))
    r2 = 1.0 - float(r @ r) / ss_tot if ss_tot > 0 else math.nan
    dof = len(x) - 2
    cov = np.linalg.inv(A.T @ A) * float(r @ r) / dof if dof > 0 else None
    return (float(coef[0]), float(coef[1])), r2, cov


def _intersect(t, b):
    u = (b[1] - t[1]) / (t[0] - b[0])
    return u, t[0] * u + t[1]


def _per_frame_C(H, uh, vh, top, bot):
    at = (top[:, 1] - vh) / (top[:, 0] - uh)
    ab = (bot[:, 1] - vh) / (bot[:, 0] - uh)
    return H / (at - ab)


def endpoint_residual_px(slope: float, r2: float, u_px) -> float:
    """Residual σ of an endpoint line that a reported R² implies [px].

    A line ``v = a u + b`` fitted by least squares to points whose columns
    ``u_px`` spread with variance s² (population variance, as R² uses) has
    ``var(v) = a² s² + σ²`` and ``R² = 1 − σ²/var(v)``, so
    ``σ = |a| · s · sqrt((1 − R²) / R²)`` (σ² the residuals' mean square).

    Parameters
    ----------
    slope : float
        The line's slope a [px/px].
    r2 : float
        Its coefficient of determination, 0 < R² ≤ 1 [-].
    u_px : (n,) array_like
        The columns of the fitted endpoints (one per frame) [px].

    Returns
    -------
    float
        The residual σ in rows [px].

    Raises
    ------
    ValueError
        If R² is not in (0, 1] or fewer than 3 finite columns are given.
    """
    u = np.asarray(u_px, dtype=np.float64)
    if not 0.0 < r2 <= 1.0 or u.size < 3 or not np.all(np.isfinite(u)):
        raise ValueError(f"need 0 < R² ≤ 1 and ≥ 3 finite columns (R² = {r2}, {u.size} columns)")
    return abs(slope) * float(u.std()) * math.sqrt((1.0 - r2) / r2)


def c_sigma_from_endpoint_fits(C_mm: float, slopes: tuple[float, float], residuals_px: tuple[float, float],
                               u_px, hinge_u_px: float) -> float:
    """σ(C) that the plate endpoints' scatter about their two lines implies (closed form) [mm].

    Per frame ``C_i = H / (α_t − α_b)``, ``α = (v − v_h)/(u − u_h)`` (paper Eq. 12
    at both edges).  An endpoint lying r rows off its line moves its α by
    ``r/(u − u_h)`` (a column error δu moves it as a row error −a·δu would), so
    independent residuals of σ_t and σ_b rows on the two lines scatter C by

        σ(C) / C = sqrt(σ_t² + σ_b²) · rms(1/(u − u_h)) / |a_t − a_b|

    over the frames (first order; the hinge's own error adds a smooth trend of
    C_i with u that this leaves out).  With :func:`endpoint_residual_px` it
    turns a reported R² into the σ(C) it implies: the paper's R² = 0.9998 for
    both lines, over its 27 frames, implies σ(C) ≈ 0.20 mm — the 0.2014 it
    reports (benchmarks/RESULTS.md).

    Parameters
    ----------
    C_mm : float
        The height coefficient C [mm].
    slopes : (float, float)
        The two endpoint lines' slopes a_t, a_b [px/px].
    residuals_px : (float, float)
        The residual σ of each line, in rows [px].
    u_px : (n,) array_like
        The frames' columns [px] (the sensor frame of docs/explanation/design-notes.md §3).
    hinge_u_px : float
        The image hinge's column u_h [px].

    Returns
    -------
    float
        σ(C) [mm].

    Raises
    ------
    ValueError
        If the two slopes are equal, no frame is given, or a frame lies on the hinge column.
    """
    u = np.asarray(u_px, dtype=np.float64)
    gap = abs(slopes[0] - slopes[1])
    d = u - hinge_u_px
    if gap <= 0.0 or u.size == 0 or not np.all(np.isfinite(d)) or np.any(d == 0.0):
        raise ValueError("need two converging endpoint lines and frames off the hinge column")
    rms_inv = math.sqrt(float(np.mean(1.0 / d ** 2)))
    return abs(C_mm) * math.hypot(*residuals_px) * rms_inv / gap


def _std(x: np.ndarray) -> float:
    return float(np.std(x, ddof=1)) if len(x) > 1 else math.nan


def _sqrt_or_nan(var) -> float:
    return math.nan if var is None or not np.isfinite(var) else math.sqrt(max(float(var), 0.0))


@dataclass(frozen=True)
class _Data:
    """The measurements of a calibration: one entry per frame with a plate stripe."""

    s: np.ndarray      # (n,) stage coordinates [mm]
    u: np.ndarray      # (n,) mean stripe column [px]
    top: np.ndarray    # (n, 2) top endpoint (u, v), NaN where the edge was not seen [px]
    bot: np.ndarray    # (n, 2) bottom endpoint [px]
    H: float           # plate height [mm]

    @property
    def has_t(self) -> np.ndarray:
        return np.isfinite(self.top[:, 1])

    @property
    def has_b(self) -> np.ndarray:
        return np.isfinite(self.bot[:, 1])

    @property
    def both(self) -> np.ndarray:
        return self.has_t & self.has_b

    def with_values(self, u, vt, vb) -> _Data:
        """The same frames with other stripe columns and endpoint rows (for the delta method)."""
        top, bot = self.top.copy(), self.bot.copy()
        top[self.has_t, 1], bot[self.has_b, 1] = vt, vb
        return _Data(self.s, u, top, bot, self.H)


def _endpoints(ms) -> tuple[np.ndarray, np.ndarray]:
    nan = (math.nan, math.nan)
    return (np.array([m.top_px if m.top_px is not None else nan for m in ms], dtype=np.float64),
            np.array([m.bottom_px if m.bottom_px is not None else nan for m in ms], dtype=np.float64))


def _paper_values(d: _Data, tol: CalibrationTolerances) -> dict:
    """The paper's Section 3 estimate, values only (module docstring)."""
    top, bot = d.top[d.has_t], d.bot[d.has_b]
    lt, r2t, cov_t = _line_fit(top[:, 0], top[:, 1])
    lb, r2b, cov_b = _line_fit(bot[:, 0], bot[:, 1])
    if abs(lt[0] - lb[0]) < tol.min_slope_gap:
        raise CalibrationError(f"the endpoint lines are parallel (slopes {lt[0]:.5g} and {lb[0]:.5g}):"
                               " the plate edges do not converge to a hinge")
    uh, vh = _intersect(lt, lb)
    (_, d0), _, _ = _line_fit(1.0 / (d.u - uh), d.s)
    F2_i = (d.u - uh) * (d.s - d0)
    both = d.both
    C_i = (_per_frame_C(d.H, uh, vh, d.top[both], d.bot[both]) if both.any()
           else np.array([d.H / (lt[0] - lb[0])]))
    return dict(hinge_u_px=uh, hinge_v_px=vh, F2_px_mm=float(F2_i.mean()), F2_sigma_px_mm=_std(F2_i),
                d0_mm=float(d0), C_mm=float(C_i.mean()), C_sigma_mm=_std(C_i) if both.any() else math.nan,
                endpoint_fit_r2=(r2t, r2b), lines=(lt, lb, cov_t, cov_b))


def _intersection_sigmas(lt, lb, cov_t, cov_b) -> tuple[float, float]:
    """Standard errors of the intersection (u_h, v_h) of two fitted lines (numerical Jacobian)."""
    if cov_t is None or cov_b is None:
        return math.nan, math.nan
    p0 = np.array([*lt, *lb])
    J = np.zeros((2, 4))
    for i in range(4):
        dp = np.zeros(4)
        dp[i] = 1e-7 * max(1.0, abs(p0[i]))
        up = _intersect(p0[:2] + dp[:2], p0[2:] + dp[2:])
        um = _intersect(p0[:2] - dp[:2], p0[2:] - dp[2:])
        J[:, i] = (np.subtract(up, um)) / (2 * dp[i])
    cov = np.zeros((4, 4))
    cov[:2, :2], cov[2:, 2:] = cov_t, cov_b
    return _sqrt_or_nan(J[0] @ cov @ J[0]), _sqrt_or_nan(J[1] @ cov @ J[1])


def _line_sigma(x: np.ndarray, y: np.ndarray) -> float | None:
    """Residual standard deviation of a straight-line fit (None when exactly determined)."""
    if len(x) <= 2:
        return None
    (m, b), _, _ = _line_fit(x, y)
    r = y - (m * x + b)
    return math.sqrt(float(r @ r) / (len(x) - 2))


def _paper_stderr(d: _Data, tol: CalibrationTolerances, sigma_u: float | None) -> dict:
    """Standard errors of the paper's F², d0 and C by the delta method.

    Noise: ``sigma_u`` on every stripe column (the refined distance fit's
    residuals), each endpoint line's own residual σ on its rows.
    """
    sig_t = _line_sigma(d.top[d.has_t, 0], d.top[d.has_t, 1])
    sig_b = _line_sigma(d.bot[d.has_b, 0], d.bot[d.has_b, 1])
    keys = ("F2_px_mm", "d0_mm", "C_mm")
    if sigma_u is None or sig_t is None or sig_b is None:
        return dict.fromkeys(("F2_stderr_px_mm", "d0_sigma_mm", "C_stderr_mm"), math.nan)
    x0 = np.concatenate([d.u, d.top[d.has_t, 1], d.bot[d.has_b, 1]])
    n, nt = len(d.u), int(d.has_t.sum())
    sig = np.concatenate([np.full(n, sigma_u), np.full(nt, sig_t), np.full(len(x0) - n - nt, sig_b)])

    def values(x):
        e = _paper_values(d.with_values(x[:n], x[n:n + nt], x[n + nt:]), tol)
        return np.array([e[k] for k in keys])

    var = np.zeros(3)
    for i in range(len(x0)):
        dx = np.zeros_like(x0)
        dx[i] = 1e-4
        var += ((values(x0 + dx) - values(x0 - dx)) / 2e-4 * sig[i]) ** 2
    return dict(zip(("F2_stderr_px_mm", "d0_sigma_mm", "C_stderr_mm"), (math.sqrt(v) for v in var)))


def _paper_estimate(d: _Data, tol: CalibrationTolerances, sigma_u: float | None):
    """The paper's estimate with its standard errors; also the two endpoint lines."""
    e = _paper_values(d, tol)
    lt, lb, cov_t, cov_b = e.pop("lines")
    e["hinge_u_sigma_px"], e["hinge_v_sigma_px"] = _intersection_sigmas(lt, lb, cov_t, cov_b)
    e.update(_paper_stderr(d, tol, sigma_u))
    return e, lt, lb


def _scaled_covariance(J: np.ndarray, rss: float, dof: int) -> np.ndarray | None:
    """σ²·(JᵀJ)⁻¹ with σ² = rss/dof; None if dof ≤ 0 or JᵀJ is singular or nearly so.

    Nearly singular: the column-scaled Jacobian's condition number squared
    exceeds :data:`_MAX_CONDITION` (its standard errors would be noise).
    """
    if dof <= 0:
        return None
    scale = np.linalg.norm(J, axis=0)
    if not np.all(scale > 0) or np.linalg.cond(J / scale) ** 2 > _MAX_CONDITION:
        return None
    try:
        return np.linalg.inv(J.T @ J) * rss / dof
    except np.linalg.LinAlgError:
        return None


def _distance_fit(s: np.ndarray, u: np.ndarray, guess_d0: float | None):
    """Least squares u = u_h + F²/(s − d0): (u_h, F², d0), their covariance, σ of u.

    The covariance and the residual σ are None when the fit is exactly determined.
    """
    span = float(s.max() - s.min())

    def linear(d0):
        A = np.column_stack([np.ones_like(s), 1.0 / (s - d0)])
        coef, *_ = np.linalg.lstsq(A, u, rcond=None)
        return coef, float(np.sum((u - A @ coef) ** 2))

    # variable projection on a grid of hinge offsets, then a joint polish
    offsets = span * np.geomspace(1e-2, 1e3, 400)
    grid = s.min() - offsets
    if guess_d0 is not None and guess_d0 < s.min():
        grid = np.append(grid, guess_d0)
    d0 = grid[int(np.argmin([linear(g)[1] for g in grid]))]
    (uh, F2), _ = linear(d0)

    def resid(p):
        return u - (p[0] + p[1] / (s - p[2]))

    sol = optimize.least_squares(resid, x0=[uh, F2, d0], x_scale=[100.0, 1e5, 10.0],
                                 xtol=1e-14, ftol=1e-14, gtol=1e-14)
    rss, dof = float(sol.fun @ sol.fun), len(s) - 3
    cov = _scaled_covariance(sol.jac, rss, dof)
    return sol.x, cov, (math.sqrt(rss / dof) if dof > 0 else None)


def _endpoint_system(d: _Data, uh: float) -> tuple[np.ndarray, np.ndarray]:
    """Design matrix and rows of the endpoint fit v = v_h + (u − u_h)·a_t (top) or ·a_b (bottom)."""
    top, bot = d.top[d.has_t], d.bot[d.has_b]
    nt = len(top)
    A = np.zeros((nt + len(bot), 3))
    A[:, 0] = 1.0
    A[:nt, 1] = top[:, 0] - uh
    A[nt:, 2] = bot[:, 0] - uh
    return A, np.concatenate([top[:, 1], bot[:, 1]])


def _endpoint_fit(d: _Data, uh: float, sig_uh: float):
    """(v_h, a_t, a_b) through the hinge column, and their covariance (fit + u_h's error)."""
    A, y = _endpoint_system(d, uh)
    theta, *_ = np.linalg.lstsq(A, y, rcond=None)
    r = y - A @ theta
    cov = _scaled_covariance(A, float(r @ r), len(y) - 3)
    if cov is not None and math.isfinite(sig_uh):
        h = 1e-3 * max(1.0, abs(uh))
        g = (np.linalg.lstsq(*_endpoint_system(d, uh + h), rcond=None)[0]
             - np.linalg.lstsq(*_endpoint_system(d, uh - h), rcond=None)[0]) / (2 * h)
        cov = cov + np.outer(g, g) * sig_uh ** 2
    elif cov is not None:
        cov = None
    return theta, cov


def _refined_estimate(d: _Data, r2, guess_d0):
    """Joint distance fit + endpoint fit through the hinge (module docstring); also σ of u."""
    (uh, F2, d0), cov_d, sigma_u = _distance_fit(d.s, d.u, guess_d0)
    if not (F2 < 0 and np.all(d.s > d0)):
        raise CalibrationError(f"the distance relation gives F² = {F2:.4g} px·mm, d0 = {d0:.4g} mm:"
                               " not a Scheimpflug geometry (need F² < 0 and every s > d0)")
    sd = np.sqrt(np.maximum(np.diag(cov_d), 0.0)) if cov_d is not None else np.full(3, math.nan)
    (vh, at, ab), cov_e = _endpoint_fit(d, uh, sd[0])
    grad_C = d.H / (at - ab) ** 2 * np.array([0.0, -1.0, 1.0])
    F2_i = (d.u - uh) * (d.s - d0)
    C_i = _per_frame_C(d.H, uh, vh, d.top[d.both], d.bot[d.both])
    # exactly determined (3 frames, 3 unknowns): every F2_i equals F² by construction
    sig_F2 = _std(F2_i) if len(d.s) > 3 else math.nan
    return dict(hinge_u_px=float(uh), hinge_v_px=float(vh), F2_px_mm=float(F2),
                F2_sigma_px_mm=sig_F2, d0_mm=float(d0), C_mm=float(d.H / (at - ab)),
                C_sigma_mm=_std(C_i), endpoint_fit_r2=r2, hinge_u_sigma_px=float(sd[0]),
                hinge_v_sigma_px=_sqrt_or_nan(None if cov_e is None else cov_e[0, 0]),
                F2_stderr_px_mm=float(sd[1]), d0_sigma_mm=float(sd[2]),
                C_stderr_mm=_sqrt_or_nan(None if cov_e is None else grad_C @ cov_e @ grad_C)), sigma_u


def _skip_summary(skipped) -> str:
    """``; N frame(s) skipped: k × reason, …`` grouping the skip reasons by their first clause."""
    if not skipped:
        return ""
    groups: dict[str, list[tuple[str, str]]] = {}
    for name, reason in skipped:
        groups.setdefault(str(reason).split(" (")[0].split(":")[0], []).append((str(name), str(reason)))
    parts = []
    for head, items in sorted(groups.items(), key=lambda kv: -len(kv[1])):
        others = [n for n, _ in items[1:3]] + ([f"{len(items) - 3} more"] if len(items) > 3 else [])
        parts.append(f"{len(items)} × {head} ({items[0][0]}: {items[0][1]}"
                     + (f"; also {', '.join(others)}" if others else "") + ")")
    return f"; {len(skipped)} frame(s) skipped: {'; '.join(parts)}"


def _measurement_data(measurements, plate_height_mm: float, tol: CalibrationTolerances,
                      skipped=()) -> _Data:
    """Check the frames and gather their measurements (every frame with a plate stripe)."""
    ms = tuple(measurements)
    if len(ms) < tol.min_frames:
        raise CalibrationError(f"only {len(ms)} usable calibration frame(s) (a plate stripe); "
                               f"need at least {tol.min_frames}{_skip_summary(skipped)}")
    top, bot = _endpoints(ms)
    d = _Data(np.array([m.stage_mm for m in ms]), np.array([m.u_mean_px for m in ms]), top, bot,
              float(plate_height_mm))
    if np.ptp(d.s) <= 0 or np.ptp(d.u) < 1.0:
        causes = sorted({m.diagnosis for m in ms if m.diagnosis})
        raise CalibrationError(f"the plate did not move: stage positions span {np.ptp(d.s):.4g} mm and "
                               f"the stripe {np.ptp(d.u):.3g} px"
                               + (f"; the frames show {causes[0]}" if causes else ""))
    nt, nb = int(d.has_t.sum()), int(d.has_b.sum())
    if nt < 2 or nb < 2:
        raise CalibrationError(f"{nt} frame(s) show the plate's top edge and {nb} its bottom edge; need "
                               "at least 2 of each (lower the plate's table or use a shorter plate)")
    return d


def calibrate_measurements(measurements, *, plate_height_mm: float = 89.0, columns: int = 0,
                           rows: int = 0, method: str = "best",
                           tol: CalibrationTolerances = DEFAULT_TOLERANCES,
                           skipped=(), accuracy: CalibrationAccuracy | None = None,
                           pixel_pitch_um: float = math.nan) -> CalibrationResult:
    """Both estimates from per-frame plate measurements (pure; no I/O).

    Every frame with a plate stripe gives the distance relation; the frames
    that show the top (bottom) edge give the top (bottom) endpoint line; C's
    per-frame spread uses the frames that show both.

    Parameters
    ----------
    measurements : iterable of PlateMeasurement
        One per usable frame (:func:`measure_plate_frame`).
    plate_height_mm : float
        Plate height H [mm].
    columns, rows : int
        Sensor size [px] (recorded; ``columns`` also sets the distance
        resolution of the d0 accuracy check).
    method : {"best", "paper", "refined"}
        Which estimate becomes ``best`` ("best": the smaller σ(u_h)).
    tol : CalibrationTolerances
        Thresholds.
    skipped : sequence of (str, str)
        Frames not used and why (recorded).
    accuracy : CalibrationAccuracy, optional
        The accuracy the calibration must state (default the class defaults);
        :func:`accuracy_warnings` fills each estimate's ``warnings``.
    pixel_pitch_um : float, optional
        Pixel pitch of the frames [µm], recorded (NaN: unknown).

    Returns
    -------
    CalibrationResult
        Both estimates, the chosen one and the diagnostics.

    Raises
    ------
    ValueError
        Unknown ``method``.
    CalibrationError
        Non-positive or non-finite plate height, too few frames or edges, a
        plate that did not move, stage positions that contradict the frames
        (two frames at one position with different stripes, a swapped pair,
        frames flipped left–right), parallel endpoint lines, a non-Scheimpflug
        distance relation.  A single frame whose stage position the others
        contradict (≥ 6 frames) is left out and named in ``skipped``.
    """
    if method not in ("best", "paper", "refined"):
        raise ValueError(f"unknown calibration method {method!r} (paper, refined, best)")
    if not (math.isfinite(plate_height_mm) and plate_height_mm > 0):
        raise CalibrationError(f"plate height must be a finite number > 0 mm, got {plate_height_mm}")
    ms = tuple(measurements)
    _check_stage_positions(ms, tol)
    ms, outliers, notes = _reject_distance_outliers(ms, tol)
    d = _measurement_data(ms, plate_height_mm, tol, tuple(skipped) + outliers)
    pap0 = _paper_values(d, tol)
    ref, sigma_u = _refined_estimate(d, pap0["endpoint_fit_r2"], pap0["d0_mm"])
    pap, lt, lb = _paper_estimate(d, tol, sigma_u)
    common = dict(columns=int(columns), rows=int(rows), plate_height_mm=d.H, n_frames=len(ms),
                  n_frames_both_edges=int(d.both.sum()), pixel_pitch_um=float(pixel_pitch_um),
                  stage_range_mm=(float(d.s.min()), float(d.s.max())))
    estimates = {"paper": _estimate_json(pap), "refined": _estimate_json(ref)}
    acc = accuracy or CalibrationAccuracy()
    paper, refined = (_with_warnings(Calibration(**e, method=name, estimates=estimates, **common), acc)
                      for e, name in ((pap, "paper"), (ref, "refined")))
    best, why = _choose(paper, refined, method)
    notes += _frame_count_notes(len(ms), tol) + why
    return CalibrationResult(best=best, paper=paper, refined=refined, measurements=ms,
                             skipped=tuple(skipped) + outliers, top_line=lt, bottom_line=lb,
                             warnings=tuple(notes))


def _check_stage_positions(ms, tol: CalibrationTolerances) -> None:
    """Refuse stage positions that contradict the frames (a typo in the manifest, flipped frames).

    Columns grow toward the hinge as the plate moves away (u = u_h + F²/(s − d0),
    F² < 0): sorted by stage position, the stripe columns must increase.  Equal
    positions must show the stripe at the same column.
    """
    s = np.array([m.stage_mm for m in ms])
    u = np.array([m.u_mean_px for m in ms])
    order = np.argsort(s, kind="stable")
    du = np.diff(u[order])
    floor = tol.stage_order_px
    if len(du) >= 2 and np.all(du < -floor):
        raise CalibrationError(
            "the stripe moves to smaller columns as the stage moves away from the camera: the frames "
            "look flipped left–right (columns must increase toward the image hinge, the far end of "
            "the range); flip the frames horizontally (or check the stage_mm sign)")
    for k in range(len(du)):
        a, b = ms[order[k]], ms[order[k + 1]]
        if s[order[k + 1]] == s[order[k]] and abs(du[k]) > floor:
            raise CalibrationError(
                f"{a.name()} and {b.name()} have the same stage position s = {a.stage_mm:g} mm but "
                f"their stripes lie {abs(du[k]):.3g} px apart: is a stage_mm in the manifest wrong?"
                f"{a.cause()}{b.cause()}")
        if du[k] < -floor:
            raise CalibrationError(
                f"stage positions and stripe columns disagree: {a.name()} (s = {a.stage_mm:g} mm, "
                f"u = {a.u_mean_px:.2f} px) and {b.name()} (s = {b.stage_mm:g} mm, "
                f"u = {b.u_mean_px:.2f} px); the stripe must move toward the hinge as s grows: "
                f"is a stage_mm in the manifest wrong or swapped?{a.cause()}{b.cause()}")


def _reject_distance_outliers(ms, tol: CalibrationTolerances):
    """Leave out, one at a time, frames whose stage position the others contradict.

    Leave-one-out test of u = u_h + F²/(s − d0): each frame's column is
    predicted by the fit of all the others; a frame whose prediction error
    exceeds ``fit_outlier_ratio`` times the others' robust residual σ (1.4826 ×
    MAD, scaled by √(m/(m − 3)) for the three fitted unknowns) and
    ``fit_outlier_floor_px`` is left out, worst first.  Needs ≥ 6 frames (the
    others then leave ≥ 2 degrees of freedom).  At most a quarter of the
    frames may go: beyond that the model, not a stage position, is what fails,
    and only a warning is given.

    Returns
    -------
    ms : tuple of PlateMeasurement
        The frames kept.
    outliers : tuple of (str, str)
        (frame, reason) of the frames left out.
    notes : list of str
        Warnings.
    """
    ms, outliers, n0 = tuple(ms), [], len(ms)
    while len(ms) >= 6:
        s = np.array([m.stage_mm for m in ms])
        u = np.array([m.u_mean_px for m in ms])
        err, scale = _leave_one_out(s, u)
        ratio = np.abs(err) / np.maximum(scale, 1e-12)
        worst = int(np.argmax(np.where(np.abs(err) > tol.fit_outlier_floor_px, ratio, 0.0)))
        if not (abs(err[worst]) > tol.fit_outlier_floor_px and ratio[worst] > tol.fit_outlier_ratio):
            break
        if len(outliers) + 1 > n0 // 4:
            return ms, tuple(outliers), [
                f"the distance fit u = u_h + F²/(s − d0) contradicts several frames (up to "
                f"{abs(err[worst]):.3g} px): the paper's model may not describe this rig (lens "
                "distortion, sensor roll) or several stage positions are wrong"]
        outliers.append((ms[worst].name(), f"outlier in the distance fit: the other frames put its stripe "
                         f"{err[worst]:+.3g} px from where it is ({ratio[worst]:.0f} × their residual σ "
                         f"{scale[worst]:.2g} px): " + (f"it shows {ms[worst].diagnosis}"
                                                        if ms[worst].diagnosis else
                                                        f"is its stage_mm ({ms[worst].stage_mm:g} mm) wrong?")))
        ms = ms[:worst] + ms[worst + 1:]
    return ms, tuple(outliers), []


def _leave_one_out(s: np.ndarray, u: np.ndarray):
    """Per frame: (column − prediction of the others' fit, the others' robust residual σ) [px]."""
    x0, _, _ = _distance_fit(s, u, None)
    err, scale = np.empty(len(s)), np.empty(len(s))
    for i in range(len(s)):
        k = np.arange(len(s)) != i
        sk, uk = s[k], u[k]
        sol = optimize.least_squares(lambda q, sk=sk, uk=uk: uk - (q[0] + q[1] / (sk - q[2])), x0,
                                     x_scale=[100.0, 1e5, 10.0])
        q = sol.x
        err[i] = u[i] - (q[0] + q[1] / (s[i] - q[2]))
        m = int(k.sum())
        scale[i] = 1.4826 * float(np.median(np.abs(sol.fun))) * math.sqrt(m / (m - 3))
    return err, scale


def _frame_count_notes(n: int, tol: CalibrationTolerances) -> list[str]:
    if n >= tol.recommended_frames:
        return []
    return [f"only {n} usable calibration frames (recommended: at least {tol.recommended_frames}): "
            "the refined fit has 3 unknowns (u_h, F², d0), so its standard errors are "
            + ("undefined" if n <= 3 else f"poorly determined ({n - 3} degree(s) of freedom)")]


def _choose(paper: Calibration, refined: Calibration, method: str) -> tuple[Calibration, list[str]]:
    """The estimate for ``method``; "best" prefers a defined σ(u_h), then the smaller one."""
    if method != "best":
        return (paper if method == "paper" else refined), []
    sp, sr = paper.hinge_u_sigma_px, refined.hinge_u_sigma_px
    if math.isfinite(sr) and (not math.isfinite(sp) or sr <= sp):
        return refined, []
    if math.isfinite(sp):
        why = [] if math.isfinite(sr) else [
            "the refined fit's σ(u_h) is undefined (exactly determined or nearly singular): "
            "using the paper's over-determined estimate"]
        return paper, why
    return refined, ["no estimate has a defined σ(u_h): using the refined one"]


def _with_warnings(cal: Calibration, accuracy: CalibrationAccuracy) -> Calibration:
    return dataclasses.replace(cal, warnings=accuracy_warnings(cal, accuracy))


_STDERR_KEYS = ("hinge_u_sigma_px", "hinge_v_sigma_px", "F2_stderr_px_mm", "d0_sigma_mm", "C_stderr_mm")


def _estimate_json(e: dict) -> dict:
    return {"hinge_px": [e["hinge_u_px"], e["hinge_v_px"]], "F2_px_mm": e["F2_px_mm"],
            "F2_sigma_px_mm": _json_float(e["F2_sigma_px_mm"]), "d0_mm": e["d0_mm"],
            "C_mm": e["C_mm"], "C_sigma_mm": _json_float(e["C_sigma_mm"]),
            "endpoint_fit_r2": [_json_float(x) for x in e["endpoint_fit_r2"]],
            **{k: _json_float(e[k]) for k in _STDERR_KEYS}}


# ---------------------------------------------------------------- stated accuracy


@dataclass(frozen=True)
class CalibrationAccuracy:
    """The accuracy a calibration must be able to state, and the check's coverage factor.

    Defaults: the closed-loop targets of the twin (tests/test_any_rig.py).

    Parameters
    ----------
    hinge_px : float, default 0.5
        Target for u_h and v_h [px].
    relative : float, default 5e-4
        Target for F² and C, relative [-].
    d0_resolution : float, default 0.1
        Target for d0 in units of the distance resolution at the centre
        column, |F²|/(N_u/2 − u_h)² [-].
    coverage : float, default 2.0
        A constant meets its target when ``coverage × standard error ≤ target`` [-].
    """

    hinge_px: float = 0.5
    relative: float = 5e-4
    d0_resolution: float = 0.1
    coverage: float = 2.0


def _accuracy_checks(cal: Calibration, acc: CalibrationAccuracy) -> list[tuple[str, float, float, str]]:
    """(name, standard error, target, unit) of every constant the calibration states."""
    checks = [("u_h", cal.hinge_u_sigma_px, acc.hinge_px, "px"),
              ("v_h", cal.hinge_v_sigma_px, acc.hinge_px, "px"),
              ("F²", cal.F2_stderr_px_mm / abs(cal.F2_px_mm), acc.relative, "(relative)"),
              ("C", cal.C_stderr_mm / abs(cal.C_mm), acc.relative, "(relative)")]
    if cal.columns > 0:
        res = abs(cal.F2_px_mm) / (cal.columns // 2 - cal.hinge_u_px) ** 2
        checks.append(("d0", cal.d0_sigma_mm, acc.d0_resolution * res, "mm"))
    return checks


def accuracy_warnings(cal: Calibration,
                      accuracy: CalibrationAccuracy = CalibrationAccuracy()) -> tuple[str, ...]:
    """Warnings when a calibration cannot state, or does not reach, a stated accuracy.

    Rule: a constant is too uncertain when ``coverage × standard error``
    exceeds its target (:class:`CalibrationAccuracy`); a constant whose
    standard error does not exist (an exactly determined fit: 3 frames for
    u_h, F² and d0, or 3 plate edges for v_h and the two edge slopes) cannot
    state its accuracy.  Either way the plan is too thin: more frames, or a
    longer stage range, shrink the standard errors.

    Parameters
    ----------
    cal : Calibration
        The calibration with its standard errors.
    accuracy : CalibrationAccuracy
        The targets.

    Returns
    -------
    tuple of str
        At most two lines (constants without a standard error; constants
        beyond their target); empty when the calibration meets every target.
    """
    checks = _accuracy_checks(cal, accuracy)
    unknown = [name for name, sig, _, _ in checks if not math.isfinite(sig)]
    k = accuracy.coverage
    over = [f"{k:g}σ({name}) = {k * sig:.3g} {unit} > {target:.3g} {unit}"
            for name, sig, target, unit in checks if math.isfinite(sig) and k * sig > target]
    out = []
    if unknown:
        out.append(f"the calibration cannot state the accuracy of {', '.join(unknown)}: its fits are "
                   f"exactly determined ({cal.n_frames} frames, {cal.n_frames_both_edges} with both plate "
                   "edges); add calibration frames")
    if over:
        out.append(f"the calibration plan is too thin for the stated accuracy: {'; '.join(over)}; "
                   "add frames or span more of the depth range")
    return tuple(out)


def calibrate_folder(folder: str | Path | FrameFolder, plate_height_mm: float | None = None, *,
                     method: str = "best", detector: str = "cog", progress=None,
                     tol: CalibrationTolerances = DEFAULT_TOLERANCES,
                     accuracy: CalibrationAccuracy | None = None) -> CalibrationResult:
    """Calibrate from a frame folder of plate frames (docs/reference/interface.md).

    Frames without a stripe or saturated are skipped with a warning
    (``CalibrationResult.skipped``); frames that show one plate edge only are
    used for the distance relation and that edge (``CalibrationResult.partial``).

    Parameters
    ----------
    folder : path or FrameFolder
        Frames with ``stage_mm``.
    plate_height_mm : float, optional
        Plate height [mm]; default the manifest's
        ``scenario_params.plate_height_mm`` or 89 mm (the paper's).
    method : {"best", "paper", "refined"}
        Which estimate becomes ``best``.
    detector : str
        Stripe centre method (:func:`scheimpflug.stripe.extract_stripes`), or
        "paper" (:func:`measure_plate_frame`).
    progress : ProgressCallback, optional
        ``progress(done, total)`` after each frame (:mod:`scheimpflug.callbacks`).
    tol : CalibrationTolerances
        Thresholds of the plate measurement.
    accuracy : CalibrationAccuracy, optional
        The accuracy to state (:func:`accuracy_warnings`).

    Returns
    -------
    CalibrationResult
        Both estimates and the diagnostics.

    Raises
    ------
    CalibrationError
        A frame without ``stage_mm``, or the fits fail
        (:func:`calibrate_measurements`).
    """
    ff = folder if isinstance(folder, FrameFolder) else open_frame_folder(folder)
    check_plate_orientation(ff)
    if plate_height_mm is None:
        plate_height_mm = scenario_number(ff, "plate_height_mm", 89.0, 0.0, 1e4)
    missing = [r.file for r in ff.frames if r.stage_mm is None]
    if missing:
        raise CalibrationError(f"calibration frames need 'stage_mm' in the manifest; "
                               f"{missing[0]!r} has none")
    ms, skipped, partial = [], [], []
    for i in range(len(ff)):
        report(progress, i, len(ff))
        rec = ff.frames[i]
        frame = ff.read(i)
        try:
            m = dataclasses.replace(measure_plate_frame(frame, rec.stage_mm, detector=detector,
                                                        saturation_dn=ff.saturation_dn(frame), tol=tol),
                                    file=rec.file)
        except CalibrationError as exc:
            skipped.append((rec.file, str(exc)))
            warnings.warn(f"{rec.file}: skipped: {exc}", stacklevel=2)
            continue
        if m.top_px is None or m.bottom_px is None:
            partial.append((rec.file, "top" if m.top_px is None else "bottom"))
        ms.append(m)
    report(progress, len(ff), len(ff))
    check_used_frames_distinct(ff, ms)
    res = calibrate_measurements(ms, plate_height_mm=plate_height_mm, columns=ff.columns,
                                 rows=ff.rows, method=method, tol=tol, skipped=skipped, accuracy=accuracy,
                                 pixel_pitch_um=ff.rig_value("sensor", "pixel_pitch_um") or math.nan)
    return check_against_manifest(ff, dataclasses.replace(res, partial=tuple(partial)))


# ---------------------------------------------------------------- what the manifest knows

_UNITS = (("cm", 10.0), ("inches", 25.4), ("m", 1000.0))
_UNIT_MATCH = 0.03     # F² within 3 % of the rig's / a unit factor names the unit of the stage positions [-]
_PLATE_MATCH = 0.10    # C further than 10 % from the rig's questions the plate height [-]
_HINGE_MATCH = 0.25    # u_h further than 25 % from the rig's hinge column: another binning or sensor [-]


def check_used_frames_distinct(ff: FrameFolder, measurements) -> None:
    """Refuse a frame listed twice among the frames a calibration uses (:func:`check_distinct_frames`).

    Parameters
    ----------
    ff : FrameFolder
        The calibration folder.
    measurements : iterable of PlateMeasurement
        The frames with a plate stripe (their ``file`` names the entry).

    Raises
    ------
    FrameError
        Naming both entries.
    """
    index = {rec.file: i for i, rec in enumerate(ff.frames)}
    check_distinct_frames(ff, [index[m.file] for m in measurements if m.file in index])


def _stated(rig: dict, table: str, key: str) -> float | None:
    """A finite number the manifest's rig states (a default the rig file leaves out is not stated)."""
    value = rig.get(table, {}).get(key) if isinstance(rig.get(table), dict) else None
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    return float(value) if ok else None


def _rig_geometry(ff: FrameFolder) -> HingeGeometry | None:
    """The ideal geometry of what the manifest's rig states, or None (no rig, or one that states less).

    Only stated values count: a partial rig's missing keys would take the paper's defaults.
    """
    if not isinstance(ff.rig, dict):
        return None
    keys = (("lens", "focal_length_mm"), ("laser", "scheimpflug_distance_mm"), ("laser", "tan_phi"),
            ("sensor", "pixel_pitch_um"), ("sensor", "hinge_column"), ("sensor", "axis_row"))
    values = [_stated(ff.rig, t, k) for t, k in keys]
    if any(v is None for v in values) or values[0] <= 0 or values[3] <= 0:
        return None
    f, d, tan_phi, pitch_um, u_h, v_h = values
    geo = HingeGeometry(f, d, tan_phi, pitch_um * 1e-3, u_h, v_h)
    try:
        ok = math.isfinite(geo.F2_px_mm) and math.isfinite(geo.C_mm) and geo.C_mm > 0
    except (ValueError, ZeroDivisionError):
        ok = False
    return geo if ok else None


def check_against_manifest(ff: FrameFolder, result: CalibrationResult) -> CalibrationResult:
    """Check a calibration against what its frames' manifest knows: the rig's geometry.

    * frames upside down: the calibration's hinge row ``v_h`` far from the rig's
      ``axis_row`` while its mirror image ``rows − 1 − v_h`` lies near it (refused);
    * stage positions in other units: the fitted F² a unit factor (10 cm, 25.4 in,
      1000 m, within 3 %) off the rig's ``−f²/(p cos φ sin β)`` (refused, naming the unit);
    * a wrong plate height: C more than 10 % off the rig's ``f / sin β`` (C scales with
      the plate height): a warning giving the plate height the rig implies.

    Parameters
    ----------
    ff : FrameFolder
        The calibration folder (what its manifest's rig states: f, d, tan φ, the pixel
        pitch, the hinge column and axis row; nothing is checked when it states less).
    result : CalibrationResult
        The calibration of its frames.

    Returns
    -------
    CalibrationResult
        ``result`` with the warnings added.

    Raises
    ------
    CalibrationError
        Frames upside down, stage positions in cm, inches or m, with the reason.
    """
    geo = _rig_geometry(ff)
    if geo is None:
        return result
    cal = result.best
    _check_upright(cal, geo, ff.rows)
    _check_stage_units(cal, geo)
    notes = _plate_height_notes(cal, geo)
    return dataclasses.replace(result, warnings=tuple(result.warnings) + notes) if notes else result


def _check_upright(cal: Calibration, geo: HingeGeometry, rows: int) -> None:
    off = abs(cal.hinge_v_px - geo.axis_row)
    mirrored = rows - 1 - cal.hinge_v_px
    off_mirrored = abs(mirrored - geo.axis_row)
    if off > max(8.0, 0.05 * rows) and off_mirrored < 0.25 * off:
        raise CalibrationError(
            f"the frames look upside down: the calibration's hinge row v_h = {cal.hinge_v_px:.1f} px lies "
            f"{off:.0f} px from the rig's axis_row {geo.axis_row:g} px (manifest), its mirror image "
            f"rows − 1 − v_h = {mirrored:.1f} px only {off_mirrored:.1f} px: flip the frames vertically "
            "(heights would come out mirrored)")


def _check_stage_units(cal: Calibration, geo: HingeGeometry) -> None:
    ratio = cal.F2_px_mm / geo.F2_px_mm
    for name, factor in _UNITS:
        if abs(ratio * factor - 1.0) < _UNIT_MATCH:
            raise CalibrationError(
                f"the stage positions look like {name}, not mm: the fitted F² = {cal.F2_px_mm:.5g} px·mm is "
                f"1/{factor:g} of the rig's {geo.F2_px_mm:.5g} px·mm (−f²/(p·cos φ·sin β), manifest); give "
                f"stage_mm in millimetres (× {factor:g})")


def _plate_height_notes(cal: Calibration, geo: HingeGeometry) -> tuple[str, ...]:
    ratio = cal.C_mm / geo.C_mm
    if abs(ratio - 1.0) <= _PLATE_MATCH:
        return ()
    return (f"C = {cal.C_mm:.5g} mm is {ratio:.3f} × the rig's {geo.C_mm:.5g} mm (f / sin β, manifest): is "
            f"the plate height {cal.plate_height_mm:g} mm right? With the rig's C the plate would be "
            f"{cal.plate_height_mm / ratio:.4g} mm high (C and every height scale with it)",)


def applicability_problem(calibration, folder: FrameFolder) -> str | None:
    """Why a calibration cannot be applied to a folder's frames, or None.

    Checked: the frame size the calibration was made with
    (:func:`~scheimpflug.calibration.model.size_problem`; a calibration that
    records none — a file of an earlier version — is applied with a warning,
    :func:`~scheimpflug.calibration.model.unknown_size_note`); the
    calibration's own consistency (its ``problem(columns, rows)``); the pixel
    pitch it records against the manifest rig's (another binning); its image
    hinge ``u_h`` against the rig's ``hinge_column`` (within 25 %: another
    binning or sensor, also for calibrations that record no size).

    Parameters
    ----------
    calibration : SheetModel
        The calibration (a general model is also checked through its paper estimate).
    folder : FrameFolder
        The frames.

    Returns
    -------
    str or None
        The reason, naming both values.

    Warns
    -----
    UserWarning
        The calibration records no frame size: it cannot be checked.
    """
    problem = size_problem(calibration, folder.columns, folder.rows)
    if problem:
        return problem
    if not (calibration.columns and calibration.rows):
        warnings.warn(unknown_size_note(folder.columns, folder.rows), stacklevel=2)
    if hasattr(calibration, "problem"):
        problem = calibration.problem(folder.columns, folder.rows)
    paper = calibration if isinstance(calibration, Calibration) else getattr(calibration, "paper", None)
    if problem is None and paper is not None:
        problem = _pitch_or_hinge_problem(paper, folder)
    return problem


_AXIS_SPANS = 2.0    # an axis further than this many depth ranges beyond the range: a typo or a unit [-]


def check_axis_position(axis_mm: float, calibration, columns: int, rows: int) -> str | None:
    """Refuse a rotary axis far outside the depth range a calibration covers; warn outside it.

    The depth range is the stage coordinate of the first and last column edges
    on the middle row (the calibration's own image size when it records one,
    else the frames').  A part's seen surface lies in it and its axis at most a
    radius away: an axis further than :data:`_AXIS_SPANS` × the range's span
    beyond either end (a part radius above twice the depth range) is a typo or
    a unit error (1794.5 for 179.45, mm as cm) and is refused.  Outside the
    range, or outside the stage range of the calibration's own frames (when
    recorded: the mapping is extrapolated there), a warning.

    Parameters
    ----------
    axis_mm : float
        The rotary axis position, stage coordinate [mm].
    calibration : Calibration or GeneralCalibration
        The calibration.
    columns, rows : int
        Size of the frames it is applied to [px].

    Returns
    -------
    str or None
        The warning, or None.

    Raises
    ------
    CalibrationError
        The axis too far outside the depth range, naming the range.
    """
    n_u, n_v = (calibration.columns, calibration.rows) if calibration.columns and calibration.rows \
        else (columns, rows)
    ends, _ = calibration.stage_from_pixel(np.array([-0.5, n_u - 0.5]), np.full(2, 0.5 * (n_v - 1)))
    lo, hi = float(np.nanmin(ends)), float(np.nanmax(ends))
    margin = _AXIS_SPANS * (hi - lo)
    if not lo - margin <= axis_mm <= hi + margin:
        raise CalibrationError(f"the rotary axis {axis_mm:g} mm lies far outside the depth range the calibration "
                               f"covers ({lo:.2f} … {hi:.2f} mm, stage coordinate; more than twice its span "
                               "beyond it): a typo or another unit?")
    paper = calibration if isinstance(calibration, Calibration) else getattr(calibration, "paper", None)
    s_lo, s_hi = paper.stage_range_mm if paper is not None else (math.nan, math.nan)
    if not lo <= axis_mm <= hi:
        return (f"the rotary axis {axis_mm:g} mm lies outside the depth range the calibration covers "
                f"({lo:.2f} … {hi:.2f} mm): only a part whose radius reaches into it is seen")
    if math.isfinite(s_lo) and math.isfinite(s_hi) and not s_lo <= axis_mm <= s_hi:
        return (f"the rotary axis {axis_mm:g} mm lies outside the stage range of the calibration frames "
                f"({s_lo:g} … {s_hi:g} mm): the mapping there is extrapolated")
    return None


def _pitch_or_hinge_problem(cal: Calibration, folder: FrameFolder) -> str | None:
    pitch = folder.rig_value("sensor", "pixel_pitch_um")
    if pitch and math.isfinite(cal.pixel_pitch_um) and abs(cal.pixel_pitch_um / pitch - 1) > 1e-6:
        return (f"the calibration was made with {cal.pixel_pitch_um:g} µm pixels, the frames' rig has "
                f"{pitch:g} µm (a calibration made at {cal.pixel_pitch_um / pitch:.3g} × this binning, or for "
                "another sensor)")
    hinge = (folder.rig or {}).get("sensor", {}).get("hinge_column") if isinstance(folder.rig, dict) else None
    if isinstance(hinge, (int, float)) and not isinstance(hinge, bool) and hinge > 0:
        ratio = cal.hinge_u_px / hinge
        if abs(ratio - 1) > _HINGE_MATCH:
            return (f"the calibration's image hinge u_h = {cal.hinge_u_px:.1f} px is {ratio:.3g} × the frames' "
                    f"rig hinge_column {hinge:g} px (manifest): a calibration made at another binning or "
                    "for another sensor")
    return None
