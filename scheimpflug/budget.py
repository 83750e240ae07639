"""Error budget of a simulated scan: where the error comes from.

Three stages, each against its own ground truth from the digital twin:

1. **Extraction** — measured stripe columns vs the exact stripe centre per
   row (``truth/NNNNN.npz`` ``stripe_u``): bias and RMS in pixels, and the
   same converted to millimetres on the sheet with the local derivatives of
   the calibration (|∂D/∂u| = |F²|/(u − u_h)², ∂h/∂u = −C (v − v_h)/(u − u_h)²).
2. **Calibration** — the fitted constants (u_h, v_h, F², d0, C, axis) vs the
   rig's closed forms, per parameter, and their combined effect in mm over the
   sensor: stage-coordinate error, height error and — for a rotary scan — the
   radial error δs − δaxis (an axis located with the same calibration cancels
   most of a d0 error).
3. **Total** — the reconstructed points vs the true mesh (point-to-mesh).

If extraction and calibration errors are independent, total RMS² ≈
extraction RMS² + calibration RMS² (+ whatever neither captures: occlusion,
wrong-surface hits, speckle, the mesh's own faceting); ``summary`` shows the
three side by side so the user sees which dominates.

All functions are pure; the demo reads the truth files and calls them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from scheimpflug.model.hinge import stage_from_pixel, stage_jacobian
from scheimpflug.reconstruct import SheetCalibration
from scheimpflug.scoring import distance_stats

__all__ = [
    "CALIBRATION_PARAMETERS",
    "calibration_error",
    "error_budget",
    "extraction_error",
    "sheet_shift_mm",
]

CALIBRATION_PARAMETERS = ("hinge_u_px", "hinge_v_px", "F2_px_mm", "d0_mm", "C_mm")
"""The compared calibration constants, in the order of the hinge functions."""
_MATCH_PX = 3.0   # a measured column farther than this from the true centre is a wrong detection [px]


def _get(obj, name: str) -> float:
    return float(obj[name] if isinstance(obj, Mapping) else getattr(obj, name))


def sheet_shift_mm(du_px, u_px, v_px, calibration: SheetCalibration) -> tuple[np.ndarray, np.ndarray]:
    """First-order shift on the sheet of a column error ``du`` at pixel (u, v).

    Parameters
    ----------
    du_px, u_px, v_px : array_like float
        Column error, column and row [px].
    calibration : SheetCalibration
        Constants (attributes or mapping keys hinge_u_px, hinge_v_px, F2_px_mm, C_mm).

    Returns
    -------
    dD_mm, dh_mm : ndarray float
        Shift along the sheet (stage coordinate) and in height [mm]:
        −F² du/(u − u_h)² and −C (v − v_h) du/(u − u_h)².

    Raises
    ------
    ValueError
        If ``u_px`` and ``v_px`` do not broadcast together.
    """
    du = np.asarray(du_px, np.float64)
    ds_du, dh_du, _ = stage_jacobian(u_px, v_px, *(_get(calibration, k) for k in
                                                   ("hinge_u_px", "hinge_v_px", "F2_px_mm", "C_mm")))
    return ds_du * du, dh_du * du


def _abs_stats(x: np.ndarray, unit: str) -> dict:
    if x.size == 0:
        return {f"bias_{unit}": None, f"rms_{unit}": None, f"p95_abs_{unit}": None,
                f"max_abs_{unit}": None}
    a = np.abs(x)
    return {f"bias_{unit}": float(x.mean()), f"rms_{unit}": float(np.sqrt(np.mean(x * x))),
            f"std_{unit}": float(x.std()), f"p95_abs_{unit}": float(np.percentile(a, 95)),
            f"max_abs_{unit}": float(a.max())}


def extraction_error(measured_rows: Sequence[np.ndarray], measured_u: Sequence[np.ndarray],
                     truth_u: Sequence[np.ndarray], calibration: SheetCalibration | None = None,
                     match_px: float = _MATCH_PX) -> dict:
    """Stripe extraction error against the exact stripe centre per row.

    Parameters
    ----------
    measured_rows, measured_u : sequences (one per frame) of (n_i,) int / float
        Rows and columns of the detected stripe [px].
    truth_u : sequence (one per frame) of (rows,) float
        Exact stripe-centre column per sensor row [px], NaN where there is none.
    calibration : SheetCalibration, optional
        To convert to mm on the sheet (:func:`sheet_shift_mm`); use the rig's
        true constants so the conversion itself carries no calibration error.
    match_px : float, default 3.0
        Measured columns farther than this from the truth are counted as wrong
        detections (another surface, a reflection) and kept out of bias/RMS [px].

    Returns
    -------
    dict
        Counts (``n_truth_rows``, ``n_detected``, ``n_matched``, ``n_missed``,
        ``n_spurious`` (detections where the truth has no stripe),
        ``n_wrong`` (beyond ``match_px``)), ``bias_px``, ``rms_px``, ``std_px``,
        ``p95_abs_px``, ``max_abs_px`` over matched rows, and with a
        calibration the same for ``distance`` (``*_distance_mm``, along the
        sheet) and ``sheet_rms_mm`` (in-plane, distance and height together).
        Statistics are None when no row matched.

    Raises
    ------
    ValueError
        If the three sequences differ in length, or a frame's rows do not
        match its columns in shape or fall outside the truth rows.
    """
    if not (len(measured_rows) == len(measured_u) == len(truth_u)):
        raise ValueError("measured_rows, measured_u and truth_u need one entry per frame")
    err, uu, vv = [], [], []
    counts = dict(n_truth_rows=0, n_detected=0, n_matched=0, n_missed=0, n_spurious=0, n_wrong=0)
    for rows, u, tu in zip(measured_rows, measured_u, truth_u):
        rows = np.asarray(rows, np.int64)
        u, tu = np.asarray(u, np.float64), np.asarray(tu, np.float64)
        if rows.shape != u.shape or (rows.size and (rows.min() < 0 or rows.max() >= tu.size)):
            raise ValueError("measured rows must match u in shape and index the truth rows")
        t = tu[rows]
        has = np.isfinite(t) & np.isfinite(u)
        e = u[has] - t[has]
        good = np.abs(e) <= match_px
        counts["n_truth_rows"] += int(np.isfinite(tu).sum())
        counts["n_detected"] += int(rows.size)
        counts["n_matched"] += int(good.sum())
        counts["n_spurious"] += int((~np.isfinite(t)).sum())
        counts["n_wrong"] += int((~good).sum())
        counts["n_missed"] += int(np.isfinite(tu).sum() - has.sum())
        err.append(e[good])
        uu.append(t[has][good])
        vv.append(rows[has][good])
    e = np.concatenate(err) if err else np.zeros(0)
    out = {**counts, **_abs_stats(e, "px")}
    if calibration is not None:
        dd, dh = sheet_shift_mm(e, np.concatenate(uu) if uu else e, np.concatenate(vv) if vv else e,
                                calibration)
        out.update({k.replace("_mm", "_distance_mm"): v for k, v in _abs_stats(dd, "mm").items()})
        out["sheet_rms_mm"] = float(np.sqrt(np.mean(dd ** 2 + dh ** 2))) if e.size else None
    return out


def calibration_error(calibration: SheetCalibration, truth: SheetCalibration, columns: int,
                      rows: int, axis_mm: float | None = None, axis_truth_mm: float | None = None,
                      grid: int = 64) -> dict:
    """Calibration constants vs the rig's truth and their effect in mm over the sensor.

    Parameters
    ----------
    calibration, truth : SheetCalibration (objects or mappings)
        Fitted and true hinge_u_px, hinge_v_px, F2_px_mm, d0_mm, C_mm.
    columns, rows : int
        Sensor size [px]; the effect is evaluated on a ``grid`` × ``grid`` set
        of pixels spanning it.
    axis_mm, axis_truth_mm : float, optional
        Located and true rotary axis (stage coordinate) [mm].
    grid : int, default 64
        Number of pixels along each sensor axis in the evaluation grid [-].

    Returns
    -------
    dict
        ``parameters``: {name: {value, truth, error, relative_error}};
        ``stage_error_mm`` and ``height_error_mm`` over the grid (rms, max_abs,
        near (column 0) and far (last column) mean); with both axes,
        ``axis_error_mm`` and ``radial_error_mm`` (δs − δaxis); ``rms_mm``: the
        in-sheet RMS (radial when the axis is known, else stage) with height.

    Raises
    ------
    ValueError
        If ``columns`` or ``rows`` is less than 2.
    """
    if columns < 2 or rows < 2:
        raise ValueError("columns and rows must be at least 2")
    params = {}
    for name in CALIBRATION_PARAMETERS:
        value, true = _get(calibration, name), _get(truth, name)
        params[name] = {"value": value, "truth": true, "error": value - true,
                        "relative_error": (value - true) / true if true else None}
    u, v = np.meshgrid(np.linspace(0, columns - 1, grid), np.linspace(0, rows - 1, grid))
    s1, h1 = stage_from_pixel(u, v, *(_get(calibration, k) for k in CALIBRATION_PARAMETERS))
    s0, h0 = stage_from_pixel(u, v, *(_get(truth, k) for k in CALIBRATION_PARAMETERS))
    ds, dh = s1 - s0, h1 - h0
    out = {"parameters": params, "stage_error_mm": _field_stats(ds), "height_error_mm": _field_stats(dh)}
    radial = ds
    if axis_mm is not None and axis_truth_mm is not None:
        out["axis_error_mm"] = float(axis_mm - axis_truth_mm)
        radial = ds - out["axis_error_mm"]
        out["radial_error_mm"] = _field_stats(radial)
    out["rms_mm"] = float(np.sqrt(np.mean(radial ** 2 + dh ** 2)))
    return out


def _field_stats(x: np.ndarray) -> dict:
    return {"rms": float(np.sqrt(np.mean(x ** 2))), "max_abs": float(np.abs(x).max()),
            "near_mean": float(x[:, 0].mean()), "far_mean": float(x[:, -1].mean())}


def error_budget(extraction: dict | None = None, calibration: dict | None = None,
                 distance_mm: np.ndarray | None = None, signed: bool = False) -> dict:
    """Assemble the three stages and a one-line-per-stage summary.

    Parameters
    ----------
    extraction : dict, optional
        :func:`extraction_error` output (with a calibration, for mm figures).
    calibration : dict, optional
        :func:`calibration_error` output.
    distance_mm : (n,) float, optional
        Point-to-mesh distances of the reconstruction [mm] (``scoring``).
    signed : bool, default False
        Whether ``distance_mm`` is signed.

    Returns
    -------
    dict
        ``extraction``, ``calibration``, ``total`` (:func:`~scheimpflug.scoring.distance_stats`)
        and ``summary``: {extraction_rms_mm, calibration_rms_mm, total_rms_mm,
        quadrature_mm = √(extraction² + calibration²), unexplained_rms_mm =
        √max(total² − quadrature², 0)}.
    """
    out: dict = {}
    summary: dict = {}
    if extraction is not None:
        out["extraction"] = extraction
        summary["extraction_rms_mm"] = extraction.get("sheet_rms_mm")
    if calibration is not None:
        out["calibration"] = calibration
        summary["calibration_rms_mm"] = calibration["rms_mm"]
    if distance_mm is not None:
        out["total"] = distance_stats(distance_mm, signed)
        summary["total_rms_mm"] = out["total"]["rms_mm"]
    parts = [summary.get("extraction_rms_mm"), summary.get("calibration_rms_mm")]
    if all(p is not None for p in parts):
        summary["quadrature_mm"] = float(np.hypot(*parts))
        if "total_rms_mm" in summary:
            summary["unexplained_rms_mm"] = float(
                np.sqrt(max(summary["total_rms_mm"] ** 2 - summary["quadrature_mm"] ** 2, 0.0)))
    out["summary"] = summary
    return out
