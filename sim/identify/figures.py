"""The figures an identification fits and predicts: each defined by an experiment and its processing.

A *figure* is one number an instrument reports about itself — σ(F²) of its
calibration, the RMSE of a plane fitted to a box side — measured on frames of
one *experiment* with one *processing*, so that the twin and the instrument are
measured alike.  The experiments are the paper's (docs/explanation/design-notes.md
§4): the plate frames of the calibration, the blocker on the rotary axis, the pile
(knurled ring, cardboard box, tape roll) and the cylinder as rotary scans; every
experiment after the calibration uses the run's own calibration and axis.  The
processing is the command line's: ``detector`` and ``method`` of ``calibrate``
(``--detector paper --method paper`` is the paper's Section 3 in whole pixels),
``detector`` of ``axis``, ``stripe`` of ``reconstruct --method``.

The registry :data:`FIGURES` names every figure, its experiment, its unit and the
*scale* the statistics work on: ``log`` for positive scatters and errors (a
relative uncertainty is a constant width there), ``log1m`` for an R² (its
1 − R² on a log scale), ``linear`` for the rest.  The pile's figures are measured
as the demo measures them (``scheimpflug.app.demo``): the ring's top-view circle
over the knurled band, the paper's plane fit ``y = a + b x + c z`` of the box's
+y side within 5 mm of its edges.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scheimpflug.errors import ScheimpflugError

__all__ = ["EXPERIMENTS", "FIGURES", "FigureDef", "box_side_mask", "box_side_plane", "from_scale",
           "measure_axis", "measure_calibration", "measure_cylinder", "measure_pile", "scale_sigma", "to_scale"]

#: The experiments in the order a run renders them; each needs the ones before it
#: (the calibration for every later one, the axis for the rotary scans).
EXPERIMENTS = ("calibration", "blocker", "pile", "cylinder")


@dataclass(frozen=True)
class FigureDef:
    """One figure of the registry.

    Parameters
    ----------
    name : str
        Its key in a spec (``C_sigma_mm``).
    experiment : str
        The experiment it is measured on (one of :data:`EXPERIMENTS`).
    scale : {"log", "log1m", "linear"}
        The scale the surrogate and the likelihood use (module docstring).
    unit : str
        Its unit, for reports.
    text : str
        What it is, in one line.
    """

    name: str
    experiment: str
    scale: str
    unit: str
    text: str


_F = FigureDef
FIGURES: dict[str, FigureDef] = {f.name: f for f in (
    _F("F2_sigma_px_mm", "calibration", "log", "px·mm",
       "σ(F²): spread of the per-frame F² over the plate frames (full-resolution px·mm)"),
    _F("C_sigma_mm", "calibration", "log", "mm", "σ(C): spread of the per-frame C over the plate frames"),
    _F("endpoint_r2", "calibration", "log1m", "-",
       "the plate endpoints' two line fits pooled: 1 − √((1 − R²_top)(1 − R²_bottom))"),
    _F("endpoint_r2_top", "calibration", "log1m", "-", "R² of the top endpoints' line fit"),
    _F("endpoint_r2_bottom", "calibration", "log1m", "-", "R² of the bottom endpoints' line fit"),
    _F("F2_px_mm", "calibration", "linear", "px·mm", "F², the distance constant (full-resolution px·mm)"),
    _F("C_mm", "calibration", "linear", "mm", "C, the height constant"),
    _F("d0_mm", "calibration", "linear", "mm", "d0, the object hinge's stage coordinate"),
    _F("stripe_peak_dn", "calibration", "log", "DN",
       "the plate stripe's brightness: median over frames of the median peak height above background"),
    _F("stripe_peak_cv", "calibration", "log", "-",
       "the plate stripe's row-to-row modulation: median over frames of std/mean of the peak height"),
    _F("axis_mm", "blocker", "linear", "mm", "the rotary axis's stage coordinate, from the blocker"),
    _F("box_plane_rmse_mm", "pile", "log", "mm",
       "RMSE of the paper's plane fit y = a + b x + c z to the pile box's +y side (5 mm inside its edges)"),
    _F("ring_mean_error_mm", "pile", "log", "mm",
       "mean |error| of the knurled ring's top-view circle fit over its band"),
    _F("ring_diameter_mm", "pile", "linear", "mm", "diameter of the knurled ring's top-view circle fit"),
    _F("cylinder_diameter_mm", "cylinder", "linear", "mm", "diameter of a cylinder fit to the smooth band"),
    _F("cylinder_height_mm", "cylinder", "linear", "mm", "height of the cloud (0.01 % to 99.99 % of z)"),
)}


# ------------------------------------------------------------------ scales


def to_scale(scale: str, y):
    """A figure's value on its statistical scale.

    Parameters
    ----------
    scale : {"log", "log1m", "linear"}
        The figure's scale.
    y : float or ndarray
        Values in the figure's unit.

    Returns
    -------
    float or ndarray
        ``ln y``, ``ln(1 − y)`` or ``y``.
    """
    y = np.asarray(y, dtype=np.float64)
    out = np.log(y) if scale == "log" else np.log1p(-y) if scale == "log1m" else y
    return float(out) if out.ndim == 0 else out


def from_scale(scale: str, z):
    """Inverse of :func:`to_scale`.

    Parameters
    ----------
    scale : {"log", "log1m", "linear"}
        The figure's scale.
    z : float or ndarray
        Values on the scale.

    Returns
    -------
    float or ndarray
        Values in the figure's unit.
    """
    z = np.asarray(z, dtype=np.float64)
    out = np.exp(z) if scale == "log" else -np.expm1(z) if scale == "log1m" else z
    return float(out) if out.ndim == 0 else out


def scale_sigma(scale: str, measured: float, absolute: float | None, relative: float | None) -> float:
    """A measurement uncertainty (1 σ) on the figure's scale, to first order.

    Parameters
    ----------
    scale : {"log", "log1m", "linear"}
        The figure's scale.
    measured : float
        The measured value [figure unit].
    absolute : float or None
        Uncertainty in the figure's unit.
    relative : float or None
        Uncertainty as a fraction of the value [-] (used when ``absolute`` is None).

    Returns
    -------
    float
        σ on the scale: ``u / y`` (log), ``u / (1 − y)`` (log1m), ``u`` (linear), with
        ``u = relative · |y|`` for a relative uncertainty.
    """
    u = absolute if absolute is not None else relative * abs(measured)
    if scale == "log":
        return u / measured
    if scale == "log1m":
        return u / (1.0 - measured)
    return u


# ------------------------------------------------------------------ the calibration


def _pooled_r2(r2: tuple[float, float]) -> float:
    return 1.0 - math.sqrt(max(1.0 - r2[0], 0.0) * max(1.0 - r2[1], 0.0))


def _stripe_peaks(folder) -> tuple[float, float]:
    """(median peak [DN], median row-to-row coefficient of variation [-]) over the plate frames."""
    from scheimpflug.io.frames import open_frame_folder
    from scheimpflug.stripe import extract_stripes

    ff = open_frame_folder(folder)
    level, cv = [], []
    for i in range(len(ff)):
        frame = ff.read(i)
        prof = extract_stripes(frame, "cog", saturation_dn=ff.saturation_dn(frame))
        if len(prof) >= 10:
            level.append(float(np.median(prof.peak)))
            cv.append(float(np.std(prof.peak) / np.mean(prof.peak)))
    if not level:
        return math.nan, math.nan
    return float(np.median(level)), float(np.median(cv))


def measure_calibration(folder: str | Path, detector: str, method: str, binning: int) -> tuple[dict, object]:
    """The calibration figures of one run's plate frames, calibrated as the spec says.

    Parameters
    ----------
    folder : path
        The rendered calibration frame folder.
    detector : str
        ``calibrate --detector`` (``paper``: the paper's whole-pixel processing).
    method : str
        ``calibrate --method`` (``paper``, ``refined`` or ``best``).
    binning : int
        The frames' binning: σ(F²) and F² are reported in full-resolution px·mm (× binning).

    Returns
    -------
    figures : dict
        Every calibration figure of :data:`FIGURES` by name.
    calibration : scheimpflug.calibration.Calibration
        The chosen estimate (for the later experiments).

    Raises
    ------
    CalibrationError
        The frames cannot be calibrated (no stripe, the fits fail).
    """
    from scheimpflug.calibration import calibrate_folder

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cal = calibrate_folder(folder, method=method, detector=detector).best
    peak, cv = _stripe_peaks(folder)
    r2 = tuple(float(x) for x in cal.endpoint_fit_r2)
    figures = {"F2_sigma_px_mm": cal.F2_sigma_px_mm * binning, "C_sigma_mm": cal.C_sigma_mm,
               "endpoint_r2": _pooled_r2(r2), "endpoint_r2_top": r2[0], "endpoint_r2_bottom": r2[1],
               "F2_px_mm": cal.F2_px_mm * binning, "C_mm": cal.C_mm, "d0_mm": cal.d0_mm,
               "stripe_peak_dn": peak, "stripe_peak_cv": cv}
    return {k: float(v) for k, v in figures.items()}, cal


def measure_axis(folder: str | Path, calibration, detector: str) -> float:
    """The rotary axis's stage coordinate from the run's blocker frames.

    Parameters
    ----------
    folder : path
        The rendered blocker frame folder.
    calibration : scheimpflug.calibration.Calibration
        The run's calibration.
    detector : str
        ``axis --detector``.

    Returns
    -------
    float
        The axis [mm].

    Raises
    ------
    CalibrationError
        No usable blocker frame (:func:`scheimpflug.axis.locate_axis`).
    """
    from scheimpflug.axis import locate_axis

    return float(locate_axis(folder, calibration, detector=detector).axis_mm)


# ------------------------------------------------------------------ rotary scans


def _cloud(folder: str | Path, calibration, axis_mm: float, stripe: str) -> np.ndarray:
    """(n, 3) points of a rotary scan in the part frame [mm], as the demo reconstructs them."""
    from scheimpflug.io.frames import open_frame_folder
    from scheimpflug.reconstruct import extract_folder, reconstruct_profiles

    ff = open_frame_folder(folder)
    rows, us, peaks, _ = extract_folder(ff, stripe)
    cloud = reconstruct_profiles(rows, us, [r.angle_deg for r in ff.frames], calibration, axis_mm, intensity=peaks)
    if len(cloud) == 0:
        raise ScheimpflugError(f"{str(folder)!r}: no stripe found in any frame")
    return cloud.xyz_mm


def box_side_plane(table_z_mm: float, box: dict) -> tuple[np.ndarray, float, np.ndarray]:
    """The long side facing +y of a box part, in the stage frame.

    Parameters
    ----------
    table_z_mm : float
        The rotary table's height (``stage.rotary_table_z_mm``) [mm].
    box : dict
        The box's analytic description (``Part.analytic`` of :func:`scenes.generators.box`).

    Returns
    -------
    normal : (3,) ndarray
        Unit normal of the side.
    offset_mm : float
        Its offset: ``normal · x = offset`` [mm].
    mesh_from_part : (4, 4) ndarray
        The box's pose.
    """
    m = np.asarray(box["mesh_from_part"], dtype=np.float64)
    plane = next(p for p in box["planes"] if p["normal"] == [0.0, 1.0, 0.0])
    n = m[:3, :3] @ np.asarray(plane["normal"], dtype=np.float64)
    t = m[:3, 3] + np.array([0.0, 0.0, table_z_mm])
    return n, float(n @ t + plane["offset_mm"]), m


def box_side_mask(xyz_mm: np.ndarray, table_z_mm: float, box: dict, inset_mm: float = 5.0,
                  band_mm: float = 3.0) -> np.ndarray:
    """Points within ``band_mm`` of the box's +y side and ``inset_mm`` inside its edges.

    The paper's hand-drawn region of interest (its Fig. 8), as the demo selects it.

    Parameters
    ----------
    xyz_mm : (n, 3) ndarray
        Points in the stage frame [mm].
    table_z_mm : float
        The rotary table's height [mm].
    box : dict
        The box's analytic description.
    inset_mm, band_mm : float
        Margin inside the side's edges and half-width of the band about the side [mm].

    Returns
    -------
    (n,) ndarray of bool
        The selected points.
    """
    n, off, m = box_side_plane(table_z_mm, box)
    t = m[:3, 3] + np.array([0.0, 0.0, table_z_mm])
    local = (xyz_mm - t) @ m[:3, :3]
    half_len = 0.5 * box["length_mm"] - inset_mm
    return ((np.abs(xyz_mm @ n - off) < band_mm) & (np.abs(local[:, 0]) < half_len)
            & (local[:, 2] > inset_mm) & (local[:, 2] < box["height_mm"] - inset_mm))


def measure_pile(folder: str | Path, calibration, axis_mm: float, stripe: str, table_z_mm: float) -> dict:
    """The pile's figures: the box side's plane RMSE, the ring's circle error and diameter.

    Parameters
    ----------
    folder : path
        The rendered rotary scan of the ``pile`` part.
    calibration : scheimpflug.calibration.Calibration
        The run's calibration.
    axis_mm : float
        The run's rotary axis [mm].
    stripe : str
        ``reconstruct --method``.
    table_z_mm : float
        The rotary table's height [mm].

    Returns
    -------
    dict
        ``box_plane_rmse_mm``, ``ring_mean_error_mm``, ``ring_diameter_mm`` (NaN with fewer
        than 10 points in the region).

    Raises
    ------
    ScheimpflugError
        No stripe in any frame.
    """
    import scenes
    from scheimpflug.fitting import fit_circle_top_view, fit_plane_paper

    xyz = _cloud(folder, calibration, axis_mm, stripe)
    parts = {p.analytic.get("kind"): p.analytic for p in scenes.load_part("pile").parts}
    ring = parts["knurled_ring"]
    in_ring = (xyz[:, 2] > table_z_mm + ring["z0_mm"] + 1.0) & (xyz[:, 2] < table_z_mm + ring["z1_mm"] - 1.0)
    circle = fit_circle_top_view(xyz[in_ring]) if in_ring.sum() >= 10 else None
    sel = box_side_mask(xyz, table_z_mm, parts["box"])
    plane = fit_plane_paper(xyz[sel]) if sel.sum() >= 10 else None
    return {"box_plane_rmse_mm": plane.rmse_mm if plane else math.nan,
            "ring_mean_error_mm": circle.mean_abs_error_mm if circle else math.nan,
            "ring_diameter_mm": circle.diameter_mm if circle else math.nan}


_EDGE_MARGIN_MM = 1.0  # points this close to the smooth band's ends count as neither smooth nor knurled


def measure_cylinder(folder: str | Path, calibration, axis_mm: float, stripe: str, table_z_mm: float) -> dict:
    """The cylinder's figures: the diameter of a cylinder fitted to its smooth band, its height.

    Parameters
    ----------
    folder : path
        The rendered rotary scan of the ``cylinder`` part.
    calibration : scheimpflug.calibration.Calibration
        The run's calibration.
    axis_mm : float
        The run's rotary axis [mm].
    stripe : str
        ``reconstruct --method``.
    table_z_mm : float
        The rotary table's height [mm].

    Returns
    -------
    dict
        ``cylinder_diameter_mm`` and ``cylinder_height_mm``.

    Raises
    ------
    ScheimpflugError
        No stripe in any frame; too few points in the smooth band for the fit.
    """
    import scenes
    from scheimpflug.fitting import fit_cylinder

    xyz = _cloud(folder, calibration, axis_mm, stripe)
    part = scenes.load_part("cylinder").parts[0]
    z_lo, z_hi = np.asarray(part.analytic["smooth_z_range_mm"]) + table_z_mm
    z = xyz[:, 2]
    smooth = (z > z_lo + _EDGE_MARGIN_MM) & (z < z_hi - _EDGE_MARGIN_MM)
    fit = fit_cylinder(xyz[smooth], axis_guess=np.array([0.0, 0.0, 1.0]))
    return {"cylinder_diameter_mm": float(fit.diameter_mm),
            "cylinder_height_mm": float(np.percentile(z, 99.99) - np.percentile(z, 0.01))}
