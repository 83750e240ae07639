"""A general sheet-to-image calibration: homography ∘ radial distortion, beyond the paper.

The paper's calibration (:mod:`scheimpflug.calibration.paper`) has four constants
and holds for an ideal rig: iso-distance lines are columns only without sensor
roll, and a real lens distorts.  Here the pixel ↔ sheet relation is what a
pinhole camera with a tilted sensor and a distorting lens makes of a plane:

    (s, h)  --G-->  (x, y)  --distortion k1, k2-->  (x_d, y_d)  --tilt, camera matrix-->  (u, v)

* ``G`` maps the sheet's stage coordinate ``s`` and height ``h`` [mm] to the
  camera's undistorted normalized coordinates ``(x, y) = (X/Z, Y/Z)``: the
  sheet's pose in the camera frame, ``G = [r1 r2 t]`` with ``r1``, ``r2`` the
  stage and height axes — orthonormal: the sheet is a metric plane (rotation 3,
  translation 3 parameters), so that ``μ·G·(s, h, 1)`` are camera-frame points in
  millimetres and lengths there equal lengths on the sheet.
* ``k1, k2`` distort radially about the optical axis in normalized
  coordinates, then the tilted sensor and the camera matrix give pixels
  (:class:`scheimpflug.calibration.camera.TiltedCamera`, OpenCV's
  ``CALIB_TILTED_MODEL``; the twin's camera :mod:`scheimpflug.model.camera`
  is exactly this model, so roll, tilt error, offsets and distortion are all
  in it).  The principal point (2) and the principal distance (1) are fitted
  too: with a metric sheet they take up what a general homography's two extra
  degrees of freedom would hold (10 parameters with k1; one combination of the
  three is held by a prior, below).

What the plate frames determine
-------------------------------
A plate moved along the sheet gives, per frame, the image of one line of
known stage coordinate ``s_i`` (every lit row) and its two edges at heights
``h_b`` and ``h_b + H`` (H the plate height).  The iso-``s`` lines fix the
distance mapping and their convergence (the vanishing point of the vertical
direction; at infinity without roll or tilt); the edges are two lines through
the image hinge (the vanishing point of the propagation direction) whose
known separation fixes the height scale.  Distortion bends the straight
iso-``s`` lines (a plumb-line constraint): the bending across the columns
fixes ``k1`` (and ``k2``) and the distortion centre's row.  Not determined by
the plate:

* the height origin — any constant ``h`` offset fits the same data.  It is
  set as in the paper: ``h = 0`` on the image row through the hinge (the
  plate's bottom edge gets the height the paper estimate gives it).  With a
  rolled sensor this row is not the meridian plane: the whole sheet is then
  offset in height by a constant, which no form, size or distance measure
  sees;
* the displacement of points *along* an iso-``s`` line by distortion is seen
  only at the two edges, and the plate spans at the far end only ≈ 60 % of
  the rows: the radial model carries it to the rest of the field.  Where the
  plate leaves the field's height poorly covered, an extra target — a step
  block (faces at known stage offsets, edges at known heights) — adds points
  of known ``(s, h)``: pass them as ``extra_points`` to
  :func:`fit_sheet_models` (``u, v, s, h`` per point);
* the camera's intrinsics without distortion: a plane seen once fixes the
  principal point and distance only up to one combination (Zhang's two
  constraints for three unknowns).  The fit starts from a physical
  decomposition of the paper constants with the rig's focal length and pixel
  pitch (:func:`ideal_camera`) and ties the principal distance to it with a
  1 % prior (a pseudo-observation weighted by the stripe points' scatter);
  with distortion the bending of the iso-``s`` lines fixes the distortion
  centre — the principal point — and the data outweigh the prior.  The tilt
  stays the decomposition's.

Model selection (``--model auto``)
----------------------------------
Both forms are fitted by least squares to the same residuals: each stripe
point's stage coordinate against its frame's (converted to columns [px]) and
each edge's height against the plate's (converted to rows [px], weighted to
the stripe points' scatter).  The paper form (u_h, v_h, F², d0, C and the
plate's bottom height: 6 parameters) is nested in the general one (pose 6,
principal point and distance 3, k1: 10, or 11 with k2; the ideal rig's camera
with k1 = 0 is the paper form), so the F-test for nested models applies::

    F = ((RSS_paper − RSS_general) / (p_g − p_p)) / (RSS_general / (N − p_g))

The general model is chosen when the test rejects the paper form at
``alpha`` (default 0.001) **and** the general model removes at least
``min_rss_drop`` (default 20 %) of the paper form's residual sum of squares.
The second condition is an effect size: with tens of thousands of stripe
points, correlated within a frame (speckle, the detector's phase bias), the
F-test alone finds "significant" misfits far below the noise.  A 20 % drop
means the paper form misses a systematic signal of at least half the
extraction noise.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from scipy import optimize, stats
from scipy.spatial.transform import Rotation

from scheimpflug.calibration.camera import (
    DEFAULT_FOCAL_LENGTH_MM,
    DEFAULT_PIXEL_PITCH_UM,
    TiltedCamera,
    camera_from_json,
    ideal_camera,
)
from scheimpflug.calibration.measure import (
    CalibrationTolerances,
    PlateMeasurement,
    check_plate_orientation,
    measure_plate_frame,
)
from scheimpflug.calibration.model import frame_size_from_json, size_problem
from scheimpflug.calibration.paper import (
    Calibration,
    CalibrationAccuracy,
    CalibrationResult,
    calibrate_measurements,
    check_against_manifest,
    check_used_frames_distinct,
)
from scheimpflug.callbacks import ProgressCallback, report
from scheimpflug.errors import CalibrationError
from scheimpflug.io.atomic import write_json_atomic
from scheimpflug.io.frames import FrameFolder, open_frame_folder, scenario_number
from scheimpflug.model.hinge import stage_from_pixel

__all__ = [
    "DEFAULT_FOCAL_LENGTH_MM",
    "DEFAULT_PIXEL_PITCH_UM",
    "GeneralCalibration",
    "ModelSelection",
    "SheetFit",
    "SheetModelResult",
    "calibrate_sheet_folder",
    "fit_sheet_models",
    "ideal_camera",
    "select_model",
]


# ---------------------------------------------------------------- the general model


def _sheet_from_normalized(g_inv: np.ndarray, x, y) -> tuple[np.ndarray, np.ndarray]:
    w = g_inv[2, 0] * x + g_inv[2, 1] * y + g_inv[2, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        return ((g_inv[0, 0] * x + g_inv[0, 1] * y + g_inv[0, 2]) / w,
                (g_inv[1, 0] * x + g_inv[1, 1] * y + g_inv[1, 2]) / w)


@dataclass(frozen=True)
class GeneralCalibration:
    """The general calibration: sheet homography, radial distortion and a tilted camera.

    Parameters
    ----------
    camera : TiltedCamera
        Intrinsics and distortion (:mod:`scheimpflug.calibration.camera`; a
        :class:`~scheimpflug.calibration.camera.OpenCVCamera` for an imported OpenCV calibration).
    homography : (3, 3) float
        ``G``: (s [mm], h [mm], 1) → undistorted normalized camera coordinates (x, y, 1),
        up to scale.
    columns, rows : int
        Sensor size the calibration was made with [px].
    plate_height_mm : float
        The calibration plate's height [mm].
    n_frames : int
        Frames used [-].
    residual_rms_px : float
        RMS of the fit's residuals, in columns (stripe points) and rows (edges) [px].
    field_sigma_mm : dict
        Standard uncertainty of the mapping over the sensor (``stage_rms``, ``stage_max``,
        ``height_rms``, ``height_max``) [mm], from the fit's covariance.
    paper : Calibration or None
        The paper-form estimate made from the same frames (for reference).
    selection : dict
        Why this model was chosen (:class:`ModelSelection` as JSON).
    """

    camera: Any
    homography: np.ndarray
    columns: int
    rows: int
    plate_height_mm: float = 89.0
    n_frames: int = 0
    residual_rms_px: float = math.nan
    field_sigma_mm: dict = field(default_factory=dict, compare=False)
    paper: Calibration | None = field(default=None, compare=False, repr=False)
    selection: dict = field(default_factory=dict, compare=False, repr=False)

    method = "general"

    def stage_from_pixel(self, u, v) -> tuple[np.ndarray, np.ndarray]:
        """Stage coordinate and height of pixels on the sheet.

        Parameters
        ----------
        u, v : array_like float
            Column and row [px], broadcast together.

        Returns
        -------
        stage_mm, h_mm : ndarray float64
            Stage coordinate and height [mm]; NaN for a ray parallel to the sheet.
        """
        x, y = self.camera.normalized_from_pixel(u, v)
        return _sheet_from_normalized(np.linalg.inv(self.homography), x, y)

    def pixel_from_stage(self, stage_mm, h_mm) -> tuple[np.ndarray, np.ndarray]:
        """Pixel of sheet points: the inverse of :meth:`stage_from_pixel`.

        Parameters
        ----------
        stage_mm, h_mm : array_like float
            Stage coordinate and height [mm], broadcast together.

        Returns
        -------
        u_px, v_px : ndarray float64
            Column and row [px].
        """
        x, y = _sheet_from_normalized(self.homography, stage_mm, h_mm)
        return self.camera.pixel_from_normalized(x, y)

    def camera_points(self, stage_mm, h_mm, scale_mm: float | None = None) -> np.ndarray:
        """Camera-frame points (OpenCV's frame) of sheet points, ``μ·G·(s, h, 1)``.

        Parameters
        ----------
        stage_mm, h_mm : array_like float
            Stage coordinate and height [mm], broadcast together.
        scale_mm : float, optional
            μ; default :meth:`metric_scale` (one stage millimetre is one millimetre).

        Returns
        -------
        (..., 3) float
            X, Y, Z [mm]; ``cv2.projectPoints`` of them gives :meth:`pixel_from_stage`.
        """
        mu = self.metric_scale() if scale_mm is None else scale_mm
        s, h = np.broadcast_arrays(np.asarray(stage_mm, np.float64), np.asarray(h_mm, np.float64))
        g = self.homography
        return mu * (s[..., None] * g[:, 0] + h[..., None] * g[:, 1] + g[:, 2])

    def metric_scale(self) -> float:
        """μ making the stage axis a unit vector: ``1/|G e_s|`` (the stage travel is metric).

        Returns
        -------
        float
            Scale of :meth:`camera_points` [mm].
        """
        return float(1.0 / np.linalg.norm(self.homography[:, 0]))

    def sheet_frame(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The sheet's origin and axes in the camera frame (:mod:`scheimpflug.calibration.model`).

        Returns
        -------
        origin_mm, e_s, e_h : (3,) float64
            ``μ·G`` 's third, first and second columns [mm, -, -].
        """
        g = self.metric_scale() * self.homography
        return g[:, 2].copy(), g[:, 0].copy(), g[:, 1].copy()

    def camera_from_pixel(self, u, v) -> np.ndarray:
        """The sheet point a pixel sees, in OpenCV's camera frame (:meth:`camera_points` of it).

        Parameters
        ----------
        u, v : array_like float
            Column and row [px], broadcast together.

        Returns
        -------
        (..., 3) float64
            X, Y, Z [mm].
        """
        return self.camera_points(*self.stage_from_pixel(u, v))

    def pixel_from_camera(self, points_mm) -> tuple[np.ndarray, np.ndarray]:
        """Pixel of camera-frame points (the camera's projection; any point, not only the sheet's).

        Parameters
        ----------
        points_mm : (..., 3) array_like float
            X, Y, Z [mm].

        Returns
        -------
        u_px, v_px : ndarray float64
            Column and row [px].
        """
        q = np.asarray(points_mm, np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            return self.camera.pixel_from_normalized(q[..., 0] / q[..., 2], q[..., 1] / q[..., 2])

    def constants(self) -> tuple[float, float, float, float, float] | None:
        """The paper-form constants of the reference estimate (or None).

        Returns
        -------
        tuple or None
            (u_h, v_h, F², d0, C) of :attr:`paper`.
        """
        return None if self.paper is None else self.paper.constants()

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
            Frames of another size, or a homography that is not finite and invertible.
        """
        size = size_problem(self, columns, rows)
        if size:
            return size
        g = np.asarray(self.homography, np.float64)
        if g.shape != (3, 3) or not np.all(np.isfinite(g)) or abs(np.linalg.det(g)) < 1e-300:
            return "the sheet homography is not a finite, invertible 3 × 3 matrix"
        return None

    def to_json_dict(self) -> dict[str, Any]:
        """The calibration JSON: docs/reference/interface.md calibrate fields (of the paper estimate) and the model.

        Returns
        -------
        dict
            ``model`` = "general", ``general`` {camera, homography, residual_rms_px,
            field_sigma_mm}, ``selection``, and the paper estimate's fields.
        """
        d: dict[str, Any] = self.paper.to_json_dict() if self.paper is not None else {}
        d.update(model="general", columns=self.columns, rows=self.rows,
                 plate_height_mm=self.plate_height_mm, n_frames=self.n_frames)
        d["general"] = {"camera": self.camera.to_json_dict(), "homography": self.homography.tolist(),
                        "residual_rms_px": _json_float(self.residual_rms_px),
                        "field_sigma_mm": {k: _json_float(v) for k, v in self.field_sigma_mm.items()}}
        if self.selection:
            d["selection"] = self.selection
        return d

    def save(self, path: str | Path) -> None:
        """Write :meth:`to_json_dict` to ``path`` atomically.

        Parameters
        ----------
        path : str or Path
            Output JSON file.
        """
        write_json_atomic(path, self.to_json_dict())

    @classmethod
    def from_json_dict(cls, d: dict) -> GeneralCalibration:
        """Read the form written by :meth:`to_json_dict`.

        Parameters
        ----------
        d : dict
            Calibration JSON with a ``general`` table.

        Returns
        -------
        GeneralCalibration
            The calibration.

        Raises
        ------
        CalibrationError
            A field is missing or malformed, or the frame size is
            (:func:`~scheimpflug.calibration.model.frame_size_from_json`).
        """
        columns, rows = frame_size_from_json(d)
        try:
            g = d["general"]
            hom = np.asarray(g["homography"], dtype=np.float64)
            if hom.shape != (3, 3) or not np.all(np.isfinite(hom)):
                raise ValueError("homography must be a finite 3 × 3 matrix")
            paper = Calibration.from_json_dict(d) if "hinge_px" in d else None
            sigma = {k: (math.nan if v is None else float(v)) for k, v in g.get("field_sigma_mm", {}).items()}
            return cls(camera=camera_from_json(g["camera"]), homography=hom,
                       columns=columns, rows=rows, plate_height_mm=float(d.get("plate_height_mm", 89.0)),
                       n_frames=int(d.get("n_frames", 0)),
                       residual_rms_px=float(g.get("residual_rms_px") or math.nan),
                       field_sigma_mm=sigma, paper=paper, selection=d.get("selection", {}))
        except CalibrationError:
            raise
        except KeyError as exc:
            raise CalibrationError(f"general calibration data lacks the field {exc.args[0]!r}") from None
        except (TypeError, ValueError, IndexError) as exc:
            raise CalibrationError(f"general calibration data garbles a field: {exc}") from None


def _json_float(x):
    return None if x is None or not math.isfinite(x) else float(x)


# ---------------------------------------------------------------- least-squares fits


@dataclass(frozen=True)
class _Data:
    """The residual data of a calibration: stripe points and plate edges (weights fixed)."""

    u: np.ndarray          # stripe points [px]
    v: np.ndarray
    s: np.ndarray          # their frame's stage coordinate [mm]
    w: np.ndarray          # |du/ds| [px/mm]
    eu: np.ndarray         # edge points [px]
    ev: np.ndarray
    es: np.ndarray         # stage of the edge's frame [mm]
    top: np.ndarray        # True for a top edge
    ew: np.ndarray         # |dv/dh| [px/mm]
    xu: np.ndarray         # extra points of known (s, h) [px, mm]
    xv: np.ndarray
    xs: np.ndarray
    xh: np.ndarray
    xw: np.ndarray         # (|du/ds|, as stripe points) [px/mm]
    height_mm: float
    edge_weight: float = 1.0

    @property
    def n(self) -> int:
        return self.u.size + self.eu.size + 2 * self.xu.size


def _residuals(data: _Data, mapping: Callable, h_bottom: float) -> np.ndarray:
    """Stripe points (columns), edges (rows, weighted) and extra points [px]."""
    s, _ = mapping(data.u, data.v)
    es, eh = mapping(data.eu, data.ev)
    target = h_bottom + np.where(data.top, data.height_mm, 0.0)
    parts = [(s - data.s) * data.w, (eh - target) * data.ew * data.edge_weight]
    if data.xu.size:
        xs, xh = mapping(data.xu, data.xv)
        parts += [(xs - data.xs) * data.xw, (xh - data.xh) * data.xw]
    return np.concatenate(parts)


@dataclass(frozen=True)
class SheetFit:
    """One least-squares fit of a sheet model to the calibration data.

    Parameters
    ----------
    name : str
        "paper" or "general".
    n_parameters : int
        Free parameters p [-].
    n_observations : int
        Residuals N [-].
    rss_px2 : float
        Residual sum of squares [px²].
    params : (p,) float
        The fitted parameter vector.
    covariance : (p, p) float
        Its covariance (Jacobian, residual variance RSS / (N − p)).
    model : object
        The fitted mapping (:class:`Calibration` or :class:`GeneralCalibration`).
    mapping_of : callable
        ``mapping_of(params)`` → callable ``(u, v) → (s, h)`` (for uncertainty propagation).
    """

    name: str
    n_parameters: int
    n_observations: int
    rss_px2: float
    params: np.ndarray = field(repr=False)
    covariance: np.ndarray = field(repr=False)
    model: Any = field(repr=False)
    mapping_of: Callable = field(repr=False)

    @property
    def residual_rms_px(self) -> float:
        """RMS residual [px]."""
        return math.sqrt(self.rss_px2 / max(self.n_observations, 1))

    def field_sigma(self, u, v) -> tuple[np.ndarray, np.ndarray]:
        """Standard uncertainty of the mapped stage coordinate and height at pixels.

        First-order propagation of :attr:`covariance` through the mapping, along the
        covariance's eigenvectors (a weakly determined combination of parameters that
        barely moves the mapping then adds what it moves, not rounding noise).

        Parameters
        ----------
        u, v : array_like float
            Pixels [px], broadcast together.

        Returns
        -------
        sigma_stage_mm, sigma_h_mm : ndarray float
            [mm], same shape as the broadcast pixels.
        """
        u, v = np.broadcast_arrays(np.asarray(u, np.float64), np.asarray(v, np.float64))
        s0, h0 = self.mapping_of(self.params)(u, v)
        var_s, var_h = np.zeros(u.shape), np.zeros(u.shape)
        lam, vec = np.linalg.eigh(0.5 * (self.covariance + self.covariance.T))
        for i in np.flatnonzero(lam > 0):          # independent directions of the parameters' error
            s1, h1 = self.mapping_of(self.params + 1e-3 * math.sqrt(lam[i]) * vec[:, i])(u, v)
            var_s += ((s1 - s0) * 1e3) ** 2        # change per standard deviation along direction i
            var_h += ((h1 - h0) * 1e3) ** 2
        return np.sqrt(var_s), np.sqrt(var_h)


def _solve(fun: Callable, x0: np.ndarray, what: str) -> tuple[np.ndarray, np.ndarray, float, int]:
    """Levenberg–Marquardt on ``fun``: (x, covariance, RSS, N).

    A fit that stops at its evaluation limit (or on bad input) is not used as if it had
    converged: :class:`CalibrationError` naming ``what`` (the callers then keep the paper
    form, or refuse ``--model general``).
    """
    sol = optimize.least_squares(fun, x0, method="lm", x_scale="jac", xtol=1e-12, ftol=1e-12,
                                 gtol=1e-12, max_nfev=200 * (len(x0) + 1))
    if sol.status <= 0 or not np.all(np.isfinite(sol.fun)):
        raise CalibrationError(f"the {what}'s least squares did not converge ({sol.nfev} evaluations; "
                               f"{sol.message.rstrip('.')})")
    r = sol.fun
    rss = float(r @ r)
    dof = max(r.size - len(x0), 1)
    try:
        cov = np.linalg.pinv(sol.jac.T @ sol.jac) * rss / dof
    except np.linalg.LinAlgError:
        cov = np.full((len(x0), len(x0)), np.nan)
    return sol.x, cov, rss, r.size


def _paper_mapping(x: np.ndarray) -> Callable:
    uh, vh, F2, d0, C = x[:5]
    return lambda u, v: stage_from_pixel(u, v, uh, vh, F2, d0, C)


def _fit_paper(data: _Data, start: Calibration, h_bottom: float) -> SheetFit:
    """Least squares of the paper form (u_h, v_h, F², d0, C, h_b) on the common residuals."""
    x0 = np.array([*start.constants(), h_bottom])
    x, cov, rss, n = _solve(lambda x: _residuals(data, _paper_mapping(x), x[5]), x0, "paper form")
    cal = replace(start, hinge_u_px=float(x[0]), hinge_v_px=float(x[1]), F2_px_mm=float(x[2]),
                  d0_mm=float(x[3]), C_mm=float(x[4]), method="paper-lsq")
    return SheetFit("paper", 6, n, rss, x, cov, cal, _paper_mapping)


_FOCAL_PRIOR = 0.01   # relative σ of the principal distance about the rig's decomposition [-]


class _GeneralParams:
    """Parameter vector ↔ (camera, G): a metric sheet pose, the principal point and distance, distortion.

    ``x = [ω (3), δt (3), δc (2), k1, (k2), δf]``: ``G = [r1 r2 t]`` with
    ``[r1 r2 r1×r2] = exp([ω]×) R0`` and ``t = t0 + 100 mm · δt`` (``R0``, ``t0``
    the decomposition's pose, its axes orthonormal); the principal point
    ``c0 + 100 px · δc`` and the principal distance ``f0 · (1 + δf)``.
    """

    def __init__(self, camera: TiltedCamera, g0: np.ndarray, k2: bool):
        g = g0 / np.linalg.norm(g0[:, 0])
        self.r0 = np.column_stack([g[:, 0], g[:, 1], np.cross(g[:, 0], g[:, 1])])
        self.t0 = g[:, 2]
        self.camera, self.k2 = camera, k2
        self.n = 10 + k2

    def unpack(self, x: np.ndarray) -> tuple[TiltedCamera, np.ndarray]:
        r = Rotation.from_rotvec(x[:3]).as_matrix() @ self.r0
        g = np.column_stack([r[:, 0], r[:, 1], self.t0 + 100.0 * x[3:6]])
        cx, cy = self.camera.principal_px
        cam = replace(self.camera, principal_px=(cx + 100.0 * float(x[6]), cy + 100.0 * float(x[7])),
                      k1=float(x[8]), k2=float(x[9]) if self.k2 else 0.0,
                      focal_px=self.camera.focal_px * (1.0 + float(x[-1])))
        return cam, g / g[2, 2]

    def mapping_of(self, x: np.ndarray) -> Callable:
        cam, g = self.unpack(x)
        g_inv = np.linalg.inv(g)

        def mapping(u, v):
            xn, yn = cam.normalized_from_pixel(u, v)
            return _sheet_from_normalized(g_inv, xn, yn)
        return mapping


def _stripe_scatter_px(data: _Data) -> float:
    """Robust scatter of the stripe points about a smooth curve per frame [px] (≥ 1e-3)."""
    r = [_smooth_residuals(data.v[data.s == s], data.u[data.s == s]) for s in np.unique(data.s)]
    return max(_robust_sigma(np.concatenate(r)) if r else 0.0, 1e-3)


def _fit_general(data: _Data, camera: TiltedCamera, g0: np.ndarray, h_bottom: float,
                 k2: bool) -> tuple[SheetFit, _GeneralParams]:
    """Least squares of the metric sheet pose (6), the principal point and distance (3), k1 (k2).

    The height origin is fixed; the principal distance carries a 1 % prior
    (:data:`_FOCAL_PRIOR`), one pseudo-observation left out of the RSS and the
    observation count the F-test sees.
    """
    par = _GeneralParams(camera, g0, k2)
    weight = _stripe_scatter_px(data) / _FOCAL_PRIOR

    def fun(x):
        return np.append(_residuals(data, par.mapping_of(x), h_bottom), weight * x[-1])

    x, cov, rss, n = _solve(fun, np.zeros(par.n), "general model")
    rss -= float(weight * x[-1]) ** 2
    return SheetFit("general", par.n, n - 1, rss, x, cov, None, par.mapping_of), par


# ---------------------------------------------------------------- data from measurements


def _edge_arrays(ms: Sequence[PlateMeasurement]):
    eu, ev, es, top = [], [], [], []
    for m in ms:
        for pt, is_top in ((m.top_px, True), (m.bottom_px, False)):
            if pt is not None:
                eu.append(pt[0])
                ev.append(pt[1])
                es.append(m.stage_mm)
                top.append(is_top)
    return np.array(eu, float), np.array(ev, float), np.array(es, float), np.array(top, bool)


def _build_data(ms: Sequence[PlateMeasurement], start: Calibration, height_mm: float,
                extra_points: np.ndarray | None) -> _Data:
    """Stack stripe points and edges; weights |du/ds|, |dv/dh| from the starting estimate."""
    uh, _, F2, _, C = start.constants()
    u = np.concatenate([m.u for m in ms])
    v = np.concatenate([np.asarray(m.rows, float) for m in ms])
    s = np.concatenate([np.full(m.u.size, m.stage_mm) for m in ms])
    eu, ev, es, top = _edge_arrays(ms)
    x = np.zeros((0, 4)) if extra_points is None else np.asarray(extra_points, float).reshape(-1, 4)
    return _Data(u=u, v=v, s=s, w=(u - uh) ** 2 / abs(F2), eu=eu, ev=ev, es=es, top=top,
                 ew=np.abs(eu - uh) / C, xu=x[:, 0], xv=x[:, 1], xs=x[:, 2], xh=x[:, 3],
                 xw=(x[:, 0] - uh) ** 2 / abs(F2), height_mm=float(height_mm))


def _bottom_height(ms: Sequence[PlateMeasurement], cal: Calibration) -> float:
    """Mean height the paper estimate gives the plate's bottom edges (the height origin) [mm]."""
    b = np.array([m.bottom_px for m in ms if m.bottom_px is not None])
    t = np.array([m.top_px for m in ms if m.top_px is not None])
    hb = cal.stage_from_pixel(b[:, 0], b[:, 1])[1] if b.size else np.zeros(0)
    ht = cal.stage_from_pixel(t[:, 0], t[:, 1])[1] - cal.plate_height_mm if t.size else np.zeros(0)
    return float(np.mean(np.concatenate([hb, ht])))


def _robust_sigma(r: np.ndarray) -> float:
    return float(1.4826 * np.median(np.abs(r - np.median(r)))) if r.size else 0.0


def _smooth_residuals(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Residuals of a robust quadratic y(x): the scatter of points about a smooth curve."""
    if x.size < 6:
        return np.zeros(0)
    keep = np.ones(x.size, bool)
    for _ in range(3):
        r = y - np.polyval(np.polyfit(x[keep], y[keep], 2), x)
        sd = _robust_sigma(r[keep])
        new = np.abs(r) <= max(4 * sd, 1e-6)
        if new.sum() < 6:  # whole-pixel data: most residuals alike, the robust σ ≈ 0
            break
        keep = new
    return r


def _clean_edges(data: _Data, ms: Sequence[PlateMeasurement], n_sigma: float = 4.0) -> _Data:
    """Drop edge outliers and weight the edges to the stripe points' scatter, model-free.

    The stripe noise is the scatter of each frame's points about a quadratic
    u(v); the edge noise the scatter of the top (bottom) edges of all frames
    about a quadratic v(u) — the edge lines pass through the hinge and bend only
    with distortion.  Edges beyond ``n_sigma`` of it (an edge found a pixel off
    where the stripe steps to the next column) are dropped.
    """
    ra = np.concatenate([_smooth_residuals(np.asarray(m.rows, float), m.u) for m in ms])
    rb = np.zeros(data.eu.size)
    for flag in (True, False):
        sel = data.top == flag
        if sel.sum() >= 6:
            rb[sel] = _smooth_residuals(data.eu[sel], data.ev[sel])
    sb = _robust_sigma(rb)
    keep = np.abs(rb) <= n_sigma * sb if sb > 0 else np.ones(rb.size, bool)
    sa, sb = _robust_sigma(ra), _robust_sigma(rb[keep])
    weight = sa / sb if sa > 0 and sb > 0 else 1.0
    return replace(data, eu=data.eu[keep], ev=data.ev[keep], es=data.es[keep], top=data.top[keep],
                   ew=data.ew[keep], edge_weight=float(weight))


# ---------------------------------------------------------------- selection


@dataclass(frozen=True)
class ModelSelection:
    """The nested-model F-test of ``--model auto`` (module docstring).

    Parameters
    ----------
    chosen : str
        "paper" or "general".
    F : float
        F statistic [-].
    p_value : float
        Its upper-tail probability under the paper form [-].
    rss_paper_px2, rss_general_px2 : float
        Residual sums of squares [px²].
    dof : tuple of int
        (p_g − p_p, N − p_g).
    alpha : float
        Test level [-].
    min_rss_drop : float
        Required fractional drop of the RSS [-].
    reason : str
        One sentence saying why.
    """

    chosen: str
    F: float
    p_value: float
    rss_paper_px2: float
    rss_general_px2: float
    dof: tuple[int, int]
    alpha: float
    min_rss_drop: float
    reason: str

    def to_json_dict(self) -> dict:
        """JSON form of every attribute.

        Returns
        -------
        dict
            JSON-ready.
        """
        return {"chosen": self.chosen, "F": _json_float(self.F), "p_value": _json_float(self.p_value),
                "rss_paper_px2": _json_float(self.rss_paper_px2),
                "rss_general_px2": _json_float(self.rss_general_px2),
                "dof": list(self.dof), "alpha": self.alpha, "min_rss_drop": self.min_rss_drop,
                "reason": self.reason}


def select_model(paper: SheetFit, general: SheetFit, alpha: float = 1e-3,
                 min_rss_drop: float = 0.2) -> ModelSelection:
    """F-test of the paper form against the general model, with an effect-size floor.

    Parameters
    ----------
    paper, general : SheetFit
        Fits to the same residuals (the paper form nested in the general model).
    alpha : float
        Level of the F-test [-].
    min_rss_drop : float
        Fraction of the paper form's RSS the general model must remove [-].

    Returns
    -------
    ModelSelection
        The choice and its reason.
    """
    d1 = general.n_parameters - paper.n_parameters
    d2 = general.n_observations - general.n_parameters
    rp, rg = paper.rss_px2, general.rss_px2
    F = ((rp - rg) / d1) / (rg / d2) if rg > 0 else math.inf
    p = float(stats.f.sf(F, d1, d2)) if math.isfinite(F) else 0.0
    drop = 1.0 - rg / rp if rp > 0 else 0.0
    general_wins = p < alpha and drop >= min_rss_drop
    rms = (f"RMS residual {paper.residual_rms_px:.4f} px (paper) → {general.residual_rms_px:.4f} px "
           f"(general), {100 * drop:.1f} % of the RSS removed; F({d1}, {d2}) = {F:.4g}, p = {p:.3g}")
    if general_wins:
        reason = f"general: the paper form misses a systematic signal ({rms})"
    elif p >= alpha:
        reason = f"paper: the general model is not significantly better at α = {alpha:g} ({rms})"
    else:
        reason = (f"paper: significant but small improvement, below the {100 * min_rss_drop:.0f} % "
                  f"effect-size floor ({rms})")
    return ModelSelection("general" if general_wins else "paper", float(F), p, rp, rg, (d1, d2),
                          alpha, min_rss_drop, reason)


# ---------------------------------------------------------------- putting it together


@dataclass(frozen=True)
class SheetModelResult:
    """Both least-squares forms, the selection and the chosen model.

    Parameters
    ----------
    chosen : Calibration or GeneralCalibration
        The model the requested choice (paper, general, auto) gives.
    general : GeneralCalibration or None
        The general model (None when no camera fits the paper constants with the assumed
        focal length and pixel pitch; then ``paper_fit`` and ``general_fit`` are None too).
    paper : CalibrationResult
        The paper calibration (paper and refined estimates, :mod:`scheimpflug.calibration`).
    paper_fit, general_fit : SheetFit
        The two least-squares fits on common residuals (the F-test's).
    selection : ModelSelection
        The F-test.
    measurements : tuple of PlateMeasurement
        Every frame with a stripe (also those without both edges).
    skipped : tuple of (str, str)
        Frames without a stripe and why.
    """

    chosen: Any
    general: GeneralCalibration
    paper: CalibrationResult
    paper_fit: SheetFit
    general_fit: SheetFit
    selection: ModelSelection
    measurements: tuple
    skipped: tuple

    @property
    def model(self):
        """The sheet model this calibration gives: :attr:`chosen`."""
        return self.chosen


def _field_sigma(fit: SheetFit, columns: int, rows: int) -> dict:
    u, v = np.meshgrid(np.linspace(0, columns - 1, 16), np.linspace(0, rows - 1, 16))
    ss, sh = fit.field_sigma(u, v)
    return {"stage_rms": float(np.sqrt(np.nanmean(ss ** 2))), "stage_max": float(np.nanmax(ss)),
            "height_rms": float(np.sqrt(np.nanmean(sh ** 2))), "height_max": float(np.nanmax(sh))}


def fit_sheet_models(measurements: Sequence[PlateMeasurement], paper: CalibrationResult, *,
                     focal_length_mm: float = DEFAULT_FOCAL_LENGTH_MM,
                     pixel_pitch_um: float = DEFAULT_PIXEL_PITCH_UM, fit_k2: bool = False,
                     extra_points=None, alpha: float = 1e-3,
                     min_rss_drop: float = 0.2) -> tuple[SheetFit, SheetFit, GeneralCalibration, ModelSelection]:
    """Fit the paper form and the general model to the same residuals and compare them.

    Parameters
    ----------
    measurements : sequence of PlateMeasurement
        Every plate frame with a stripe (frames without both edges add stripe points only).
    paper : CalibrationResult
        The paper calibration of the same frames (the starting point and the height origin).
    focal_length_mm, pixel_pitch_um : float
        Lens focal length [mm] and pixel pitch [µm] for the camera's intrinsics (:func:`ideal_camera`).
    fit_k2 : bool
        Fit k2 too (over a field of ±6° the plate leaves it undetermined: off by default).
    extra_points : (n, 4) float, optional
        Points of an extra target: pixel u, v [px] and their known stage coordinate and height [mm].
    alpha, min_rss_drop : float
        The selection test's level and effect-size floor (:func:`select_model`).

    Returns
    -------
    paper_fit, general_fit : SheetFit
        The least-squares fits.
    general : GeneralCalibration
        The general model.
    selection : ModelSelection
        The F-test.
    """
    start = paper.best
    h_b = _bottom_height(paper.measurements, start)
    data = _clean_edges(_build_data(measurements, start, start.plate_height_mm, extra_points),
                        measurements)
    pfit = _fit_paper(data, start, h_b)
    camera, g0 = ideal_camera(start, focal_length_mm, pixel_pitch_um)
    gfit, par = _fit_general(data, camera, g0, h_b, fit_k2)
    cam, g = par.unpack(gfit.params)
    general = GeneralCalibration(camera=cam, homography=g, columns=start.columns, rows=start.rows,
                                 plate_height_mm=start.plate_height_mm, n_frames=len(measurements),
                                 residual_rms_px=gfit.residual_rms_px,
                                 field_sigma_mm=_field_sigma(gfit, start.columns or 2, start.rows or 2),
                                 paper=start)
    gfit = replace(gfit, model=general)
    sel = select_model(pfit, gfit, alpha, min_rss_drop)
    return pfit, gfit, replace(general, selection=sel.to_json_dict()), sel


def _rig_optics(ff: FrameFolder, focal_length_mm, pixel_pitch_um) -> tuple[float, float, str]:
    """F [mm], p [µm] and where they come from: the arguments, else the manifest's rig, else assumed."""
    f_rig, p_rig = ff.rig_value("lens", "focal_length_mm"), ff.rig_value("sensor", "pixel_pitch_um")
    f = focal_length_mm or f_rig or DEFAULT_FOCAL_LENGTH_MM
    p = pixel_pitch_um or p_rig or DEFAULT_PIXEL_PITCH_UM
    where = lambda given, rig: "given" if given else ("the manifest's rig" if rig else  # noqa: E731
                                                      "assumed: the manifest's rig has none")
    source = (f"f = {f:g} mm ({where(focal_length_mm, f_rig)}), pixel pitch {p:g} µm "
              f"({where(pixel_pitch_um, p_rig)})")
    return float(f), float(p), source


def _measure_all(ff: FrameFolder, detector: str, tol: CalibrationTolerances, progress):
    """Every frame's plate measurement; frames without a stripe and why; frames with one edge."""
    ms, skipped, partial = [], [], []
    for i in range(len(ff)):
        report(progress, i, len(ff))
        rec, frame = ff.frames[i], ff.read(i)
        try:
            m = replace(measure_plate_frame(frame, rec.stage_mm, detector=detector,
                                            saturation_dn=ff.saturation_dn(frame), tol=tol), file=rec.file)
        except CalibrationError as exc:
            skipped.append((rec.file, str(exc)))
            continue
        ms.append(m)
        if m.top_px is None or m.bottom_px is None:
            partial.append((rec.file, "top" if m.top_px is None else "bottom"))
    report(progress, len(ff), len(ff))
    return ms, skipped, partial


def calibrate_sheet_folder(folder: str | Path | FrameFolder, plate_height_mm: float | None = None, *,
                           model: str = "auto", method: str = "best", detector: str = "cog",
                           focal_length_mm: float | None = None, pixel_pitch_um: float | None = None,
                           fit_k2: bool = False, extra_points=None,
                           alpha: float = 1e-3, min_rss_drop: float = 0.2,
                           progress: ProgressCallback | None = None,
                           tol: CalibrationTolerances | None = None,
                           accuracy: CalibrationAccuracy | None = None) -> SheetModelResult:
    """Calibrate a plate folder with the paper form and the general model; choose one.

    Parameters
    ----------
    folder : str, Path or FrameFolder
        Plate frames with ``stage_mm``.
    plate_height_mm : float, optional
        Plate height [mm] (default the manifest's, else 89).
    model : {"paper", "general", "auto"}
        Which model becomes :attr:`SheetModelResult.chosen` (auto: :func:`select_model`).
    method : {"best", "paper", "refined"}
        The paper form's estimate (:func:`scheimpflug.calibration.calibrate_measurements`).
    detector : str
        Stripe detector.
    focal_length_mm, pixel_pitch_um : float, optional
        Lens focal length [mm] and pixel pitch [µm]; default the manifest's rig, else the
        paper's (assumed: they shape only the distortion's pattern, see :func:`ideal_camera`).
    fit_k2 : bool
        Fit k2 (:func:`fit_sheet_models`).
    extra_points : (n, 4) float, optional
        Extra target points (u, v [px], s, h [mm]).
    alpha, min_rss_drop : float
        The selection test (:func:`select_model`).
    progress : ProgressCallback, optional
        ``progress(done, total)`` per frame.
    tol : CalibrationTolerances, optional
        Plate measurement thresholds (default :class:`CalibrationTolerances`).
    accuracy : CalibrationAccuracy, optional
        The accuracy the paper form must state (:func:`scheimpflug.calibration.accuracy_warnings`).

    Returns
    -------
    SheetModelResult
        Both models, the F-test and the choice.

    Raises
    ------
    CalibrationError
        Unknown model, frames without ``stage_mm``, too few usable frames; with
        ``model="general"``, intrinsics inconsistent with the calibration or ``detector="paper"``
        (whole pixels: the general model is not fitted, the paper form is chosen, and the
        selection's reason says why).
    """
    if model not in ("paper", "general", "auto"):
        raise CalibrationError(f"unknown calibration model {model!r} (paper, general, auto)")
    tol = tol or CalibrationTolerances()
    ff = folder if isinstance(folder, FrameFolder) else open_frame_folder(folder)
    check_plate_orientation(ff)
    if plate_height_mm is None:
        plate_height_mm = scenario_number(ff, "plate_height_mm", 89.0, 0.0, 1e4)
    missing = [r.file for r in ff.frames if r.stage_mm is None]
    if missing:
        raise CalibrationError(f"calibration frames need 'stage_mm' in the manifest; {missing[0]!r} has none")
    ms, skipped, partial = _measure_all(ff, detector, tol, progress)
    check_used_frames_distinct(ff, ms)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        paper = calibrate_measurements(ms, plate_height_mm=plate_height_mm, columns=ff.columns,
                                       rows=ff.rows, method=method, tol=tol,
                                       skipped=tuple(skipped), accuracy=accuracy,
                                       pixel_pitch_um=ff.rig_value("sensor", "pixel_pitch_um") or math.nan)
    paper = check_against_manifest(ff, replace(paper, partial=tuple(partial)))
    f, p, source = _rig_optics(ff, focal_length_mm, pixel_pitch_um)
    left_out = {name for name, _ in paper.skipped}        # e.g. a frame at a wrong stage position
    ms = [m for m in ms if m.file not in left_out]
    if detector == "paper":
        # whole-pixel positions (±½ px) hide the general model's sub-pixel bending: its fit does not
        # converge (the paper rig's plate set: 2 200 evaluations, the distortion centre thousands of px off)
        why = ("the paper detector's whole-pixel stripe positions cannot determine the general model "
               "(its distortion bends the lines by less than their ½-px quantisation)")
        if model == "general":
            raise CalibrationError(f"--model general: {why}; use a sub-pixel detector")
        sel = ModelSelection("paper", math.nan, 1.0, math.nan, math.nan, (0, 0), alpha, min_rss_drop,
                             f"paper: {why}")
        return SheetModelResult(paper.best, None, paper, None, None, sel, tuple(ms), tuple(skipped))
    try:
        pfit, gfit, general, sel = fit_sheet_models(ms, paper, focal_length_mm=f, pixel_pitch_um=p,
                                                    fit_k2=fit_k2,
                                                    extra_points=extra_points, alpha=alpha,
                                                    min_rss_drop=min_rss_drop)
    except CalibrationError as exc:
        if model == "general":
            raise CalibrationError(f"--model general: {exc} [used {source}]") from None
        sel = ModelSelection("paper", math.nan, 1.0, math.nan, math.nan, (0, 0), alpha, min_rss_drop,
                             f"paper: the general model is unavailable ({exc})")
        return SheetModelResult(paper.best, None, paper, None, None, sel, tuple(ms), tuple(skipped))
    choice = sel.chosen if model == "auto" else model
    chosen = general if choice == "general" else paper.best
    return SheetModelResult(chosen, general, paper, pfit, gfit, sel, tuple(ms), tuple(skipped))
