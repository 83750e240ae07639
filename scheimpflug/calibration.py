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

The default ("best") is the estimate with the smaller standard error of
``u_h`` (propagated from each fit's residuals); with usable frames that is
nearly always the refined one.

Conventions (DESIGN.md §3): columns ``u`` increase with distance toward the
hinge (``u − u_h < 0``, ``F² < 0``); rows ``v`` increase downward, a point
above the optical axis (``h > 0``) images at ``v < v_h``.  Pixel ``k``'s centre
is ``u = k``.

The stripe centre is measured with a centre detector, not the paper's
light-bar edge: an edge sits ``σ·sqrt(2 ln 2)`` beyond the centre, an offset
that varies with the stripe width across the sensor and biases ``u_h``
(``detector="edge"`` reproduces the paper).  The default is the windowed
centre of gravity (``cog``, ±7 px): every row of a plate frame sees the stripe
at the same sub-pixel phase, so a detector's phase-dependent bias does not
average out over rows; on noisy 2 px-wide stripes the 3-point Gaussian's
(noise-induced, log-nonlinearity) bias reaches 0.02 px per frame and moves
``d0`` by ≈ 0.1 mm, the centre of gravity's stays below 0.003 px.
"""

from __future__ import annotations

import json
import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy import optimize

from scheimpflug.callbacks import report
from scheimpflug.errors import CalibrationError
from scheimpflug.io.atomic import write_json_atomic
from scheimpflug.io.frames import FrameFolder, open_frame_folder
from scheimpflug.model.hinge import pixel_from_stage, stage_from_pixel
from scheimpflug.stripe import extract_stripes

__all__ = [
    "Calibration",
    "CalibrationResult",
    "CalibrationTolerances",
    "PlateMeasurement",
    "calibrate_folder",
    "calibrate_measurements",
    "measure_plate_frame",
]


@dataclass(frozen=True)
class CalibrationTolerances:
    """Thresholds of the plate measurement, one reason each.

    Parameters
    ----------
    min_rows : int, default 20
        Fewer lit rows: no plate in view [rows].
    outlier_floor_px : float, default 0.5
        Never reject stripe points closer than this to the line [px].
    outlier_mads : float, default 4.0
        Reject points beyond this many robust σ (1.4826 × MAD) from the line [-].
    band_px : int, default 4
        Half-band beside the stripe summed for the edge profile [px].
    edge_inset_rows : int, default 4
        Plateau starts this far inside the edge (blur ≈ 1 px) [rows].
    plateau_rows : int, default 12
        Rows averaged (median) for the plateau / background level [rows].
    background_gap_rows : int, default 6
        Background rows start this far outside the edge [rows].
    min_frames : int, default 3
        Fewer usable frames cannot fix a line and a hinge [-].
    min_slope_gap : float, default 1e-3
        Endpoint slopes closer than this are parallel [-].
    """

    min_rows: int = 20            # fewer lit rows: no plate in view [rows]
    outlier_floor_px: float = 0.5  # never reject stripe points closer than this to the line [px]
    outlier_mads: float = 4.0     # reject points beyond this many robust σ from the line [-]
    band_px: int = 4              # half-band beside the stripe summed for the edge profile [px]
    edge_inset_rows: int = 4      # plateau starts this far inside the edge (blur ≈ 1 px) [rows]
    plateau_rows: int = 12        # rows averaged for the plateau / background level [rows]
    background_gap_rows: int = 6  # background rows start this far outside the edge [rows]
    min_frames: int = 3           # fewer usable frames cannot fix a line and a hinge [-]
    min_slope_gap: float = 1e-3   # endpoint slopes closer than this are parallel [-]


# ---------------------------------------------------------------- result types


@dataclass(frozen=True)
class Calibration:
    """A calibration: pixel (u, v) → stage coordinate and height (paper Eqs. 11–12).

    Parameters
    ----------
    hinge_u_px, hinge_v_px : float
        Image hinge (u_h, v_h) [px].
    F2_px_mm : float
        F², distance constant [px·mm] (negative).
    F2_sigma_px_mm : float
        Spread (sample σ) of the per-frame F² [px·mm].
    d0_mm : float
        Stage coordinate of the object hinge [mm].
    C_mm : float
        Height constant [mm].
    C_sigma_mm : float
        Spread (sample σ) of the per-frame C [mm].
    endpoint_fit_r2 : tuple of float
        R² of the (top, bottom) endpoint line fits [-].
    method : str
        "paper" or "refined".
    columns, rows : int
        Sensor size the calibration was made with [px] (0 if unknown).
    plate_height_mm : float, default 89.0
        The calibration plate's height [mm].
    n_frames : int, default 0
        Frames used [-].
    hinge_u_sigma_px : float, default nan
        Standard error of u_h [px].
    estimates : dict, optional
        JSON dicts of both estimates (``{"paper": ..., "refined": ...}``);
        not compared or hashed.
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
    estimates: dict = field(default_factory=dict, compare=False, hash=False, repr=False)

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
                "F2_sigma_px_mm": self.F2_sigma_px_mm, "d0_mm": self.d0_mm, "C_mm": self.C_mm,
                "C_sigma_mm": self.C_sigma_mm, "endpoint_fit_r2": list(self.endpoint_fit_r2),
                "hinge_u_sigma_px": _json_float(self.hinge_u_sigma_px), "method": self.method,
                "n_frames": self.n_frames}

    def to_json_dict(self) -> dict[str, Any]:
        """The calibration as the JSON object of ``calibration.json``.

        Returns
        -------
        dict
            INTERFACE.md calibrate fields (``hinge_px``, ``F2_px_mm``,
            ``F2_sigma_px_mm``, ``d0_mm``, ``C_mm``, ``C_sigma_mm``,
            ``endpoint_fit_r2``, ``hinge_u_sigma_px`` (None if not finite),
            ``method``, ``n_frames``), plus ``columns``, ``rows``,
            ``plate_height_mm`` and both estimates (``paper``, ``refined``).
        """
        d = self._core_dict()
        d.update(columns=self.columns, rows=self.rows, plate_height_mm=self.plate_height_mm)
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
        """A calibration from the JSON object :meth:`to_json_dict` writes.

        Parameters
        ----------
        d : dict
            Needs ``hinge_px``, ``F2_px_mm``, ``d0_mm`` and ``C_mm``; other
            fields take defaults (NaN σ, method "paper", size 0, 89 mm plate).

        Returns
        -------
        Calibration
            The calibration (values are not range-checked; :meth:`load` does).

        Raises
        ------
        CalibrationError
            If a required field is missing or a field has the wrong type.
        """
        try:
            r2 = d.get("endpoint_fit_r2", [math.nan, math.nan])
            return cls(hinge_u_px=float(d["hinge_px"][0]), hinge_v_px=float(d["hinge_px"][1]),
                       F2_px_mm=float(d["F2_px_mm"]),
                       F2_sigma_px_mm=float(d.get("F2_sigma_px_mm", math.nan)),
                       d0_mm=float(d["d0_mm"]), C_mm=float(d["C_mm"]),
                       C_sigma_mm=float(d.get("C_sigma_mm", math.nan)),
                       endpoint_fit_r2=(float(r2[0]), float(r2[1])),
                       method=str(d.get("method", "paper")), columns=int(d.get("columns", 0)),
                       rows=int(d.get("rows", 0)),
                       plate_height_mm=float(d.get("plate_height_mm", 89.0)),
                       n_frames=int(d.get("n_frames", 0)),
                       hinge_u_sigma_px=float(d.get("hinge_u_sigma_px") or math.nan),
                       estimates={k: d[k] for k in ("paper", "refined") if k in d})
        except (KeyError, TypeError, ValueError, IndexError) as exc:
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
            garbles a field, or does not have F² < 0, C > 0 and a finite d0.
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
        cal = cls.from_json_dict(d)
        if not (cal.F2_px_mm < 0 and cal.C_mm > 0 and math.isfinite(cal.d0_mm)):
            raise CalibrationError(f"calibration file {str(p)!r}: need F2_px_mm < 0 and C_mm > 0")
        return cal


def _json_float(x: float):
    return None if x is None or not math.isfinite(x) else float(x)


@dataclass(frozen=True)
class PlateMeasurement:
    """What one calibration frame gives (:func:`measure_plate_frame`).

    Parameters
    ----------
    stage_mm : float
        Stage coordinate [mm].
    u_mean_px : float
        Mean stripe centre over the lit (inlier) rows [px].
    n_rows : int
        Lit inlier rows on the plate [-].
    line : tuple of float
        (a, b) of the stripe line u = a + b v [px, px/px].
    top_px, bottom_px : tuple of float or None
        (u, v) of the top and bottom endpoints on the stripe line, or None if
        not measurable [px].
    rows : (n,) ndarray int64
        Rows of the inlier stripe points [px].
    u : (n,) ndarray float64
        Columns of the inlier stripe points [px].
    """

    stage_mm: float
    u_mean_px: float
    n_rows: int
    line: tuple[float, float]
    top_px: tuple[float, float] | None
    bottom_px: tuple[float, float] | None
    rows: np.ndarray = field(repr=False)
    u: np.ndarray = field(repr=False)


@dataclass(frozen=True)
class CalibrationResult:
    """Both estimates, the chosen one and the diagnostics for plots.

    Parameters
    ----------
    best : Calibration
        The chosen estimate.
    paper, refined : Calibration
        Both estimates (module docstring).
    measurements : tuple of PlateMeasurement
        The usable frames' measurements (both endpoints measured).
    skipped : tuple of (str, str)
        (file or index, reason) of every frame not used.
    top_line, bottom_line : tuple of float
        (m, b) of the paper's endpoint fits v = m u + b [px/px, px].
    """

    best: Calibration
    paper: Calibration
    refined: Calibration
    measurements: tuple[PlateMeasurement, ...]
    skipped: tuple[tuple[str, str], ...]
    top_line: tuple[float, float]
    bottom_line: tuple[float, float]


# ---------------------------------------------------------------- one frame


def _robust_line(v: np.ndarray, u: np.ndarray, tol: CalibrationTolerances) -> tuple[np.ndarray, tuple]:
    """Fit u = a + b v with iterative MAD rejection; return inlier mask and (a, b)."""
    keep = np.abs(u - np.median(u)) < 10.0
    a, b = float(np.median(u)), 0.0
    for _ in range(5):
        if keep.sum() < 3:
            break
        b, a = np.polyfit(v[keep], u[keep], 1)
        r = u - (a + b * v)
        mad = 1.4826 * np.median(np.abs(r[keep]))
        new = np.abs(r) <= max(tol.outlier_mads * mad, tol.outlier_floor_px)
        if np.array_equal(new, keep):
            break
        keep = new
    return keep, (float(a), float(b))


def _band_profile(frame: np.ndarray, rows: np.ndarray, line, side: int, band: int) -> np.ndarray:
    """Sum of ``band + 1`` pixels from the stripe centre toward ``side`` (±1), per row."""
    a, b = line
    centre = np.rint(a + b * rows).astype(np.int64)
    offs = np.arange(band + 1) * side
    cols = np.clip(centre[:, None] + offs[None, :], 0, frame.shape[1] - 1)
    return frame[rows[:, None], cols].astype(np.float64).sum(axis=1)


def _edge_row(frame, line, v_end: int, direction: int, side: int,
              tol: CalibrationTolerances) -> float | None:
    """Sub-pixel row where the stripe ends (50 % of plateau above background).

    ``v_end`` is the last lit row, ``direction`` −1 for the top edge, +1 for the
    bottom one; the band is summed on ``side`` of the stripe, away from light
    that may continue past the edge (table in front, scene behind the plate).
    """
    n = frame.shape[0]
    ins, gap, cnt = tol.edge_inset_rows, tol.background_gap_rows, tol.plateau_rows
    inner = v_end - direction * np.arange(ins, ins + cnt)
    outer = v_end + direction * np.arange(gap, gap + cnt)
    if inner.min() < 0 or inner.max() >= n or outer.min() < 0 or outer.max() >= n:
        return None
    plateau = np.median(_band_profile(frame, inner, line, side, tol.band_px))
    bg = np.median(_band_profile(frame, outer, line, side, tol.band_px))
    level = 0.5 * (plateau + bg)
    scan = v_end - direction * ins + direction * np.arange(0, ins + gap + 1)
    prof = _band_profile(frame, scan, line, side, tol.band_px)
    below = np.flatnonzero(prof < level)
    if plateau <= bg or below.size == 0 or below[0] == 0:
        return None
    j = below[0]
    frac = (prof[j - 1] - level) / (prof[j - 1] - prof[j])
    return float(scan[j - 1] + direction * frac)


def measure_plate_frame(frame: np.ndarray, stage_mm: float, *, detector: str = "cog",
                        saturation_dn: float | None = None,
                        tol: CalibrationTolerances = CalibrationTolerances()) -> PlateMeasurement:
    """Stripe line and sub-pixel plate endpoints of one calibration frame.

    The stripe centres (``detector``) are fitted by a line u = a + b v with
    iterative MAD rejection; each endpoint is the sub-pixel row where a band
    beside the stripe falls to 50 % between its plateau and the background.

    Parameters
    ----------
    frame : (rows, columns) ndarray
        The frame [DN].
    stage_mm : float
        Stage coordinate of the plate in this frame [mm].
    detector : str, default "cog"
        Stripe centre method (:func:`scheimpflug.stripe.extract_stripes`).
    saturation_dn : float, optional
        Saturation level [DN]; default the dtype's maximum.
    tol : CalibrationTolerances, optional
        Thresholds; default :class:`CalibrationTolerances`'s.

    Returns
    -------
    PlateMeasurement
        The stripe line and endpoints; an endpoint that cannot be measured
        (edge outside the frame, no plateau) is None.

    Raises
    ------
    CalibrationError
        With the reason, when the frame holds no usable plate stripe: too few
        lit rows, too few rows on a line, or the stripe saturated in most rows.
    """
    prof = extract_stripes(frame, detector, saturation_dn=saturation_dn)
    if len(prof) < tol.min_rows:
        raise CalibrationError(f"no stripe ({len(prof)} lit rows < {tol.min_rows})")
    v = prof.rows.astype(np.float64)
    keep, line = _robust_line(v, prof.u, tol)
    if keep.sum() < tol.min_rows:
        raise CalibrationError(f"no straight stripe ({int(keep.sum())} rows on a line)")
    if prof.saturated[keep].mean() > 0.5:
        raise CalibrationError("stripe saturated in most rows: lower the exposure")
    rows_in = prof.rows[keep]
    ends = []
    for v_end, direction, side in ((rows_in.min(), -1, -1), (rows_in.max(), +1, +1)):
        ve = _edge_row(frame, line, int(v_end), direction, side, tol)
        ends.append(None if ve is None else (line[0] + line[1] * ve, ve))
    return PlateMeasurement(stage_mm=float(stage_mm), u_mean_px=float(prof.u[keep].mean()),
                            n_rows=int(keep.sum()), line=line, top_px=ends[0], bottom_px=ends[1],
                            rows=rows_in, u=prof.u[keep])


# ---------------------------------------------------------------- the fits


def _line_fit(x: np.ndarray, y: np.ndarray):
    """Y = m x + b: (m, b), R², and the 2×2 covariance of (m, b)."""
    A = np.column_stack([x, np.ones_like(x)])
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    r = y - A @ coef
    ss_tot = float(np.sum((y - y.mean()) ** 2))
    r2 = 1.0 - float(r @ r) / ss_tot if ss_tot > 0 else math.nan
    dof = max(len(x) - 2, 1)
    cov = np.linalg.inv(A.T @ A) * float(r @ r) / dof
    return (float(coef[0]), float(coef[1])), r2, cov


def _intersect(t, b):
    u = (b[1] - t[1]) / (t[0] - b[0])
    return u, t[0] * u + t[1]


def _per_frame_C(H, uh, vh, top, bot):
    at = (top[:, 1] - vh) / (top[:, 0] - uh)
    ab = (bot[:, 1] - vh) / (bot[:, 0] - uh)
    return H / (at - ab)


def _std(x: np.ndarray) -> float:
    return float(np.std(x, ddof=1)) if len(x) > 1 else math.nan


def _paper_estimate(s, u, top, bot, H, tol):
    """The paper's Section 3 calibration (see module docstring)."""
    lt, r2t, cov_t = _line_fit(top[:, 0], top[:, 1])
    lb, r2b, cov_b = _line_fit(bot[:, 0], bot[:, 1])
    if abs(lt[0] - lb[0]) < tol.min_slope_gap:
        raise CalibrationError(f"the endpoint lines are parallel (slopes {lt[0]:.5g} and {lb[0]:.5g}):"
                               " the plate edges do not converge to a hinge")
    uh, vh = _intersect(lt, lb)
    # standard error of u_h: numerical Jacobian of the intersection
    p0 = np.array([*lt, *lb])
    J = np.zeros(4)
    for i in range(4):
        dp = np.zeros(4)
        dp[i] = 1e-7 * max(1.0, abs(p0[i]))
        up = _intersect(p0[:2] + dp[:2], p0[2:] + dp[2:])[0]
        um = _intersect(p0[:2] - dp[:2], p0[2:] - dp[2:])[0]
        J[i] = (up - um) / (2 * dp[i])
    cov = np.zeros((4, 4))
    cov[:2, :2], cov[2:, 2:] = cov_t, cov_b
    sig_uh = float(math.sqrt(max(J @ cov @ J, 0.0)))
    (F2_fit, d0), _, _ = _line_fit(1.0 / (u - uh), s)
    F2_i = (u - uh) * (s - d0)
    C_i = _per_frame_C(H, uh, vh, top, bot)
    return dict(hinge_u_px=uh, hinge_v_px=vh, F2_px_mm=float(F2_i.mean()),
                F2_sigma_px_mm=_std(F2_i), d0_mm=float(d0), C_mm=float(C_i.mean()),
                C_sigma_mm=_std(C_i), endpoint_fit_r2=(r2t, r2b), hinge_u_sigma_px=sig_uh), lt, lb


def _distance_fit(s: np.ndarray, u: np.ndarray, guess_d0: float | None):
    """Least squares u = u_h + F²/(s − d0): (u_h, F², d0), σ(u_h)."""
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
    dof = max(len(s) - 3, 1)
    r = sol.fun
    try:
        cov = np.linalg.inv(sol.jac.T @ sol.jac) * float(r @ r) / dof
        sig = float(math.sqrt(max(cov[0, 0], 0.0)))
    except np.linalg.LinAlgError:
        sig = math.nan
    return sol.x, sig


def _refined_estimate(s, u, top, bot, H, r2, guess_d0):
    """Joint distance fit + endpoint fit through the hinge (module docstring)."""
    (uh, F2, d0), sig_uh = _distance_fit(s, u, guess_d0)
    if not (F2 < 0 and np.all(s > d0)):
        raise CalibrationError(f"the distance relation gives F² = {F2:.4g} px·mm, d0 = {d0:.4g} mm:"
                               " not a Scheimpflug geometry (need F² < 0 and every s > d0)")
    n = len(top)
    A = np.zeros((2 * n, 3))
    A[:, 0] = 1.0
    A[:n, 1] = top[:, 0] - uh
    A[n:, 2] = bot[:, 0] - uh
    (vh, at, ab), *_ = np.linalg.lstsq(A, np.concatenate([top[:, 1], bot[:, 1]]), rcond=None)
    F2_i = (u - uh) * (s - d0)
    C_i = _per_frame_C(H, uh, vh, top, bot)
    return dict(hinge_u_px=float(uh), hinge_v_px=float(vh), F2_px_mm=float(F2),
                F2_sigma_px_mm=_std(F2_i), d0_mm=float(d0), C_mm=float(H / (at - ab)),
                C_sigma_mm=_std(C_i), endpoint_fit_r2=r2, hinge_u_sigma_px=sig_uh)


def calibrate_measurements(measurements, *, plate_height_mm: float = 89.0, columns: int = 0,
                           rows: int = 0, method: str = "best",
                           tol: CalibrationTolerances = CalibrationTolerances(),
                           skipped=()) -> CalibrationResult:
    """Both estimates from per-frame plate measurements (pure; no I/O).

    Parameters
    ----------
    measurements : iterable of PlateMeasurement
        Per-frame measurements; those without both endpoints are left out.
    plate_height_mm : float, default 89.0
        Plate height H [mm], > 0.
    columns, rows : int, default 0
        Sensor size, recorded in the calibration [px].
    method : {"best", "paper", "refined"}, default "best"
        Which estimate becomes ``best``; "best" takes the one with the smaller
        standard error of u_h.
    tol : CalibrationTolerances, optional
        Thresholds; default :class:`CalibrationTolerances`'s.
    skipped : iterable of (str, str), optional
        (file or index, reason) of frames already skipped, passed through.

    Returns
    -------
    CalibrationResult
        Both estimates, the chosen one and the diagnostics.

    Raises
    ------
    ValueError
        For an unknown ``method``.
    CalibrationError
        If the plate height is not > 0, fewer than ``tol.min_frames`` frames
        have both edges, the plate did not move, the endpoint lines are
        parallel, or the distance fit is not a Scheimpflug geometry
        (F² ≥ 0 or a stage position not beyond d0).
    """
    if method not in ("best", "paper", "refined"):
        raise ValueError(f"unknown calibration method {method!r} (paper, refined, best)")
    if not plate_height_mm > 0:
        raise CalibrationError(f"plate height must be > 0 mm, got {plate_height_mm}")
    ms = tuple(m for m in measurements if m.top_px is not None and m.bottom_px is not None)
    if len(ms) < tol.min_frames:
        raise CalibrationError(f"only {len(ms)} usable calibration frame(s) (a stripe with both plate "
                               f"edges in view); need at least {tol.min_frames}")
    s = np.array([m.stage_mm for m in ms])
    u = np.array([m.u_mean_px for m in ms])
    if np.ptp(s) <= 0 or np.ptp(u) < 1.0:
        raise CalibrationError(f"the plate did not move: stage positions span {np.ptp(s):.4g} mm and "
                               f"the stripe {np.ptp(u):.3g} px")
    top = np.array([m.top_px for m in ms])
    bot = np.array([m.bottom_px for m in ms])
    H = float(plate_height_mm)
    pap, lt, lb = _paper_estimate(s, u, top, bot, H, tol)
    ref = _refined_estimate(s, u, top, bot, H, pap["endpoint_fit_r2"], pap["d0_mm"])
    common = dict(columns=int(columns), rows=int(rows), plate_height_mm=H, n_frames=len(ms))
    estimates = {"paper": _estimate_json(pap), "refined": _estimate_json(ref)}
    paper = Calibration(**pap, method="paper", estimates=estimates, **common)
    refined = Calibration(**ref, method="refined", estimates=estimates, **common)
    if method == "best":
        sp, sr = paper.hinge_u_sigma_px, refined.hinge_u_sigma_px
        best = paper if (math.isfinite(sp) and not (sr <= sp)) else refined
    else:
        best = paper if method == "paper" else refined
    return CalibrationResult(best=best, paper=paper, refined=refined, measurements=ms,
                             skipped=tuple(skipped), top_line=lt, bottom_line=lb)


def _estimate_json(e: dict) -> dict:
    return {"hinge_px": [e["hinge_u_px"], e["hinge_v_px"]], "F2_px_mm": e["F2_px_mm"],
            "F2_sigma_px_mm": _json_float(e["F2_sigma_px_mm"]), "d0_mm": e["d0_mm"],
            "C_mm": e["C_mm"], "C_sigma_mm": _json_float(e["C_sigma_mm"]),
            "endpoint_fit_r2": [_json_float(x) for x in e["endpoint_fit_r2"]],
            "hinge_u_sigma_px": _json_float(e["hinge_u_sigma_px"])}


def calibrate_folder(folder: str | Path | FrameFolder, plate_height_mm: float | None = None, *,
                     method: str = "best", detector: str = "cog", progress=None,
                     tol: CalibrationTolerances = CalibrationTolerances()) -> CalibrationResult:
    """Calibrate from a frame folder of plate frames (INTERFACE.md).

    Frames without a stripe, without both plate edges in view or saturated are
    skipped with a warning (``CalibrationResult.skipped``).

    Parameters
    ----------
    folder : str, Path or FrameFolder
        Plate frames, each with ``stage_mm`` in the manifest.
    plate_height_mm : float, optional
        Plate height [mm]; default the manifest's
        ``scenario_params.plate_height_mm`` or 89 mm (the paper's).
    method : {"best", "paper", "refined"}, default "best"
        Which estimate becomes ``best``.
    detector : str, default "cog"
        Stripe centre method (:func:`scheimpflug.stripe.extract_stripes`).
    progress : ProgressCallback, optional
        ``progress(done, total)`` before each frame and once at the end
        (:mod:`scheimpflug.callbacks`).
    tol : CalibrationTolerances, optional
        Thresholds; default :class:`CalibrationTolerances`'s.

    Returns
    -------
    CalibrationResult
        Both estimates, the chosen one, the measurements and the skipped frames.

    Raises
    ------
    CalibrationError
        If a frame has no ``stage_mm``, or the usable frames cannot determine
        the calibration (:func:`calibrate_measurements`).
    FrameError
        If the folder or a frame is missing or invalid.
    ValueError
        For an unknown ``method``.

    Warns
    -----
    UserWarning
        For each skipped frame, with its file and the reason.
    """
    ff = folder if isinstance(folder, FrameFolder) else open_frame_folder(folder)
    if plate_height_mm is None:
        plate_height_mm = float(ff.scenario_params.get("plate_height_mm", 89.0))
    missing = [r.file for r in ff.frames if r.stage_mm is None]
    if missing:
        raise CalibrationError(f"calibration frames need 'stage_mm' in the manifest; "
                               f"{missing[0]!r} has none")
    ms, skipped = [], []
    for i in range(len(ff)):
        report(progress, i, len(ff))
        rec = ff.frames[i]
        frame = ff.read(i)
        try:
            m = measure_plate_frame(frame, rec.stage_mm, detector=detector,
                                    saturation_dn=ff.saturation_dn(frame), tol=tol)
        except CalibrationError as exc:
            skipped.append((rec.file, str(exc)))
            warnings.warn(f"{rec.file}: skipped: {exc}", stacklevel=2)
            continue
        if m.top_px is None or m.bottom_px is None:
            skipped.append((rec.file, "plate edge outside the frame"))
            warnings.warn(f"{rec.file}: skipped: plate edge outside the frame", stacklevel=2)
            continue
        ms.append(m)
    report(progress, len(ff), len(ff))
    return calibrate_measurements(ms, plate_height_mm=plate_height_mm, columns=ff.columns,
                                  rows=ff.rows, method=method, tol=tol, skipped=skipped)
