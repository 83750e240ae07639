"""VDI/VDE 2634 Part 2 quality parameters of an optical 3-D measuring system, by definition.

The guideline states a system's accuracy by four figures measured on
calibrated artefacts placed in the measuring volume (diagonal ``L0``):

``PF`` probing error, form
    Range of the radial distances of the measured points of a sphere from
    its least-squares sphere with **free radius** (max − min) [mm].
``PS`` probing error, size
    Diameter of that least-squares sphere minus the calibrated diameter [mm] (signed).
``SD`` sphere-spacing error
    Distance between the centres of the two least-squares spheres (free
    radius) of a ball bar minus the calibrated distance [mm] (signed).
``F`` flatness measurement error
    Range of the signed distances of the measured points of a plane from its
    least-squares plane (max − min) [mm].

Each is measured in several positions (sphere ≥ 10, ball bar 7, plane 6)
and the system's figure is the largest over its positions (for PS and SD:
the largest in magnitude, with its sign).  The guideline permits excluding
up to 0.3 % of the points of each measurement as outliers; here that is an
explicit choice (``exclude_fraction``, default 0.003 = applied): the
points farthest from the first least-squares fit are dropped, the fit is
repeated, and the number dropped is reported.  ``exclude_fraction = 0``
evaluates every point.

Pure functions on (n, 3) float64 point sets in millimetres; the scan plan
and rendering live in :mod:`sim.acceptance`.

References
----------
VDI/VDE 2634 Blatt 2, *Optische 3-D-Messsysteme — Bildgebende Systeme mit
flächenhafter Antastung*, 2012, §§ 5–6 (quality parameters, artefacts:
sphere Ø 0.1–0.2·L0, ball bar ≥ 0.3·L0, plane ≥ 0.5·L0).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from scheimpflug.fitting import fit_plane

__all__ = [
    "EXCLUDE_FRACTION",
    "SphereFit",
    "fit_sphere",
    "flatness_error",
    "measuring_volume_diagonal",
    "probing_errors",
    "sphere_spacing_error",
    "summarize",
]

#: Fraction of the points VDI/VDE 2634-2 permits excluding as outliers [-].
EXCLUDE_FRACTION = 0.003


def _points(points, min_n: int, what: str) -> np.ndarray:
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"{what} needs an (n, 3) array of points, got shape {p.shape}")
    p = p[np.all(np.isfinite(p), axis=1)]
    if len(p) < min_n:
        raise ValueError(f"{what} needs at least {min_n} finite points, got {len(p)}")
    return p


@dataclass(frozen=True)
class SphereFit:
    """Least-squares sphere with free radius.

    Parameters
    ----------
    centre_mm : (3,) float
        Centre [mm].
    radius_mm : float
        Radius [mm].
    residuals_mm : (n,) float
        Radial distances of the points from the sphere ``|p − c| − r`` [mm].
    rms_mm : float
        RMS of the residuals [mm].
    """

    centre_mm: np.ndarray
    radius_mm: float
    residuals_mm: np.ndarray
    rms_mm: float


def fit_sphere(points) -> SphereFit:
    """Least-squares sphere with free radius: algebraic start, geometric refinement.

    Parameters
    ----------
    points : (n, 3) float
        Points on a sphere (n ≥ 4, not coplanar) [mm].

    Returns
    -------
    SphereFit
        Minimises Σ (|p − c| − r)² (Levenberg–Marquardt from the linear fit
        of ``|p|² = 2 c·p + r² − |c|²``).

    Raises
    ------
    ValueError
        Too few finite points, or a coplanar set.
    """
    p = _points(points, 4, "a sphere fit")
    mean = p.mean(axis=0)
    q = p - mean
    if np.linalg.svd(q, compute_uv=False)[2] <= 1e-9 * max(np.abs(q).max(), 1e-300):
        raise ValueError("degenerate point set for a sphere fit (the points are coplanar)")
    design = np.column_stack([2 * q, np.ones(len(q))])
    sol = np.linalg.lstsq(design, (q * q).sum(axis=1), rcond=None)[0]
    c0, r0 = sol[:3], math.sqrt(max(sol[3] + sol[:3] @ sol[:3], 1e-300))

    def fun(x):
        return np.linalg.norm(q - x[:3], axis=1) - x[3]

    def jac(x):
        d = q - x[:3]
        n = np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
        return np.column_stack([-d / n, -np.ones(len(q))])

    x = least_squares(fun, np.r_[c0, r0], jac=jac, method="lm", xtol=1e-14, ftol=1e-14).x
    res = fun(x)
    return SphereFit(centre_mm=x[:3] + mean, radius_mm=float(abs(x[3])), residuals_mm=res,
                     rms_mm=float(np.sqrt(np.mean(res ** 2))))


def _excluded(points: np.ndarray, residuals: np.ndarray, fraction: float) -> tuple[np.ndarray, int]:
    """Drop the ⌊fraction·n⌋ points with the largest |residual|; (kept points, number dropped)."""
    if not 0 <= fraction < 1:
        raise ValueError(f"exclude_fraction must be in [0, 1), got {fraction}")
    k = int(math.floor(fraction * len(points)))
    if k == 0:
        return points, 0
    keep = np.argsort(np.abs(residuals))[: len(points) - k]
    return points[np.sort(keep)], k


def probing_errors(points, diameter_mm: float, exclude_fraction: float = EXCLUDE_FRACTION) -> dict:
    """PF and PS of one sphere measurement (module docstring).

    Parameters
    ----------
    points : (n, 3) float
        Measured points of the sphere [mm].
    diameter_mm : float
        Calibrated diameter [mm].
    exclude_fraction : float
        Fraction of points that may be excluded as outliers (0.003 in the guideline; 0 = none) [-].

    Returns
    -------
    dict
        ``PF_mm`` (range of the radial residuals), ``PS_mm`` (fitted minus calibrated
        diameter), ``diameter_mm`` (fitted), ``centre_mm``, ``rms_mm``, ``n_points``, ``n_excluded``.
    """
    p = _points(points, 4, "PF/PS")
    fit = fit_sphere(p)
    kept, k = _excluded(p, fit.residuals_mm, exclude_fraction)
    if k:
        fit = fit_sphere(kept)
    r = fit.residuals_mm
    return {"PF_mm": float(r.max() - r.min()), "PS_mm": float(2 * fit.radius_mm - diameter_mm),
            "diameter_mm": 2 * fit.radius_mm, "centre_mm": fit.centre_mm.tolist(), "rms_mm": fit.rms_mm,
            "n_points": int(len(p)), "n_excluded": k}


def sphere_spacing_error(points_a, points_b, distance_mm: float,
                         exclude_fraction: float = EXCLUDE_FRACTION) -> dict:
    """SD of one ball-bar measurement: distance of the fitted centres minus the calibrated.

    Parameters
    ----------
    points_a, points_b : (n, 3) float
        Measured points of the two spheres [mm].
    distance_mm : float
        Calibrated centre distance [mm].
    exclude_fraction : float
        Outlier fraction excluded per sphere [-].

    Returns
    -------
    dict
        ``SD_mm``, ``distance_mm`` (measured), and the two spheres' :func:`probing_errors`
        (``sphere_a``, ``sphere_b``; their diameters are not compared to anything).
    """
    a = probing_errors(points_a, 0.0, exclude_fraction)
    b = probing_errors(points_b, 0.0, exclude_fraction)
    d = float(np.linalg.norm(np.subtract(a["centre_mm"], b["centre_mm"])))
    return {"SD_mm": d - distance_mm, "distance_mm": d, "sphere_a": a, "sphere_b": b}


def flatness_error(points, exclude_fraction: float = EXCLUDE_FRACTION) -> dict:
    """F of one plane measurement: range of the signed distances from the least-squares plane.

    Parameters
    ----------
    points : (n, 3) float
        Measured points of the plane [mm].
    exclude_fraction : float
        Outlier fraction excluded [-].

    Returns
    -------
    dict
        ``F_mm``, ``rms_mm``, ``normal``, ``n_points``, ``n_excluded``.
    """
    p = _points(points, 3, "F")
    fit = fit_plane(p)
    kept, k = _excluded(p, fit.residuals_mm, exclude_fraction)
    if k:
        fit = fit_plane(kept)
    r = fit.residuals_mm
    return {"F_mm": float(r.max() - r.min()), "rms_mm": fit.rms_mm, "normal": fit.normal.tolist(),
            "n_points": int(len(p)), "n_excluded": k}


def measuring_volume_diagonal(stage_near_mm: float, stage_far_mm: float, axis_mm: float,
                              height_per_distance: float, distance_near_mm: float) -> dict:
    """L0 of a rotary light-sheet scanner's measuring volume.

    The measuring volume is the cylinder about the rotary axis that every turn
    brings through the sheet's field on both sides of the axis: radius
    ``R = min(axis − s_near, s_far − axis)``; its height is the field's height
    at the nearest distance it reaches, ``(D_near_axis)·height_per_distance``
    (the height range grows in proportion to the distance from the object
    hinge, docs/explanation/design-notes.md §3).  ``L0`` is its diagonal ``√((2R)² + H²)``.

    Parameters
    ----------
    stage_near_mm, stage_far_mm : float
        Stage coordinates of the field's near and far ends [mm].
    axis_mm : float
        Stage coordinate of the rotary axis [mm].
    height_per_distance : float
        Field height per unit distance from the object hinge (rows · C / |F²|) [-].
    distance_near_mm : float
        Distance from the object hinge of the stage coordinate ``axis − R`` [mm].

    Returns
    -------
    dict
        ``L0_mm``, ``radius_mm``, ``height_mm``.

    Raises
    ------
    ValueError
        The axis is outside the field.
    """
    R = min(axis_mm - stage_near_mm, stage_far_mm - axis_mm)
    if not R > 0:
        raise ValueError(f"the rotary axis ({axis_mm:g} mm) lies outside the field "
                         f"[{stage_near_mm:g}, {stage_far_mm:g}] mm")
    H = height_per_distance * distance_near_mm
    return {"L0_mm": math.hypot(2 * R, H), "radius_mm": R, "height_mm": H}


def summarize(sphere: list[dict], ball_bar: list[dict], plane: list[dict], L0_mm: float) -> dict:
    """The table of quality parameters: the largest over positions.

    Parameters
    ----------
    sphere, ball_bar, plane : list of dict
        Per-position results of :func:`probing_errors`, :func:`sphere_spacing_error`,
        :func:`flatness_error`.
    L0_mm : float
        Measuring volume diagonal [mm].

    Returns
    -------
    dict
        ``PF_mm``, ``PS_mm``, ``SD_mm`` (largest magnitude, signed), ``F_mm``, ``L0_mm`` and
        ``positions`` (counts); None for a parameter without positions.
    """
    def largest(rows, key, signed=False):
        vals = [r[key] for r in rows]
        if not vals:
            return None
        return float(max(vals, key=abs)) if signed else float(max(vals))

    return {"PF_mm": largest(sphere, "PF_mm"), "PS_mm": largest(sphere, "PS_mm", True),
            "SD_mm": largest(ball_bar, "SD_mm", True), "F_mm": largest(plane, "F_mm"),
            "L0_mm": float(L0_mm),
            "positions": {"sphere": len(sphere), "ball_bar": len(ball_bar), "plane": len(plane)}}
