"""Flat surfaces that stand still while the part turns: a calibration checked on real frames without a reference.

A turntable scanner's back walls (FabScan's plywood housing) do not turn.  The
laser sheet meets a flat wall in a straight line, so in every frame of a scan
the stripe's points on that wall map, through a correct calibration, onto one
and the same straight line of the sheet.  Two figures follow, both in the
sheet's own millimetres:

straightness
    RMS distance, within the sheet, of the wall's points of all frames from
    their best straight line (total least squares) [mm].  A lens distortion
    the calibration gets wrong bends the line (a quadratic term), a wrong
    scale does not show; stripe noise and speckle set the floor.
stillness
    RMS over frames of each frame's mean offset from that line [mm]: the wall
    must not move (a part's shadow or a reflection that takes the stripe off
    the wall shows here).

The wall's 3-D points (camera frame) lie on the laser plane, so they lie on a
line, not on a plane one could fit: "the points lie on the wall's plane in
every frame" is measured as their distance from the wall's line within the
sheet — the distance from the plane through that line perpendicular to the
sheet.  The points of one wall are picked in the image (a column range) and
kept by a seeded RANSAC line fit, so that the part's stripe where it crosses
the range does not count.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["FixedLine", "fixed_line", "line_inliers"]


@dataclass(frozen=True)
class FixedLine:
    """Figures of one still surface's line (module docstring).

    Parameters
    ----------
    rms_mm : float
        Straightness: RMS distance of the points from their line, within the sheet [mm].
    bow_mm : float
        The line's sagitta from a quadratic fit over its length (a bent line: a distortion) [mm].
    stillness_mm : float
        RMS over frames of the frame's mean offset from the line [mm].
    length_mm : float
        Extent of the points along the line [mm].
    n_points, n_frames : int
        Points and frames that contributed [-].
    """

    rms_mm: float
    bow_mm: float
    stillness_mm: float
    length_mm: float
    n_points: int
    n_frames: int

    def to_json_dict(self) -> dict:
        """The figures as a JSON-ready dict.

        Returns
        -------
        dict
            Every field under its own name.
        """
        return {k: getattr(self, k) for k in ("rms_mm", "bow_mm", "stillness_mm", "length_mm", "n_points",
                                               "n_frames")}


def line_inliers(u, v, threshold_px: float = 2.0, trials: int = 500, seed: int = 0) -> np.ndarray:
    """The points of the dominant straight line of image points (seeded RANSAC).

    Parameters
    ----------
    u, v : (n,) array_like float
        Image points [px].
    threshold_px : float, default 2.0
        Largest distance of an inlier from the line [px].
    trials : int, default 500
        Random pairs tried [-].
    seed : int, default 0
        Random seed (same seed, same inliers).

    Returns
    -------
    (n,) ndarray bool
        Inliers of the line with most of them.

    Raises
    ------
    ValueError
        Fewer than 2 points.
    """
    p = np.stack([np.asarray(u, np.float64), np.asarray(v, np.float64)], axis=1)
    if len(p) < 2:
        raise ValueError(f"a line needs at least 2 points, got {len(p)}")
    rng = np.random.default_rng(seed)
    best = np.zeros(len(p), bool)
    for _ in range(trials):
        i, j = rng.choice(len(p), 2, replace=False)
        d = p[j] - p[i]
        norm = float(np.hypot(*d))
        if norm == 0.0:
            continue
        k = np.abs((p - p[i]) @ (np.array([-d[1], d[0]]) / norm)) < threshold_px
        if k.sum() > best.sum():
            best = k
    return best


def fixed_line(stage_mm, h_mm, frame) -> FixedLine:
    """Straightness and stillness of one still surface's stripe points (module docstring).

    Parameters
    ----------
    stage_mm, h_mm : (n,) array_like float
        The points in the sheet [mm].
    frame : (n,) array_like int
        The frame of each point.

    Returns
    -------
    FixedLine
        The figures.

    Raises
    ------
    ValueError
        Fewer than 3 finite points.
    """
    s, h = np.asarray(stage_mm, np.float64), np.asarray(h_mm, np.float64)
    f = np.asarray(frame)
    ok = np.isfinite(s) & np.isfinite(h)
    s, h, f = s[ok], h[ok], f[ok]
    if len(s) < 3:
        raise ValueError(f"a line needs at least 3 finite points, got {len(s)}")
    p = np.stack([s, h], axis=1)
    c = p.mean(axis=0)
    _, _, vt = np.linalg.svd(p - c, full_matrices=False)
    t, r = (p - c) @ vt[0], (p - c) @ vt[1]
    q = np.polyfit(t, r, 2)
    half = 0.5 * float(np.ptp(t))
    frames = np.unique(f)
    offsets = np.array([r[f == k].mean() for k in frames])
    return FixedLine(rms_mm=float(np.sqrt(np.mean(r ** 2))), bow_mm=float(q[0] * half ** 2),
                     stillness_mm=float(np.sqrt(np.mean(offsets ** 2))), length_mm=float(np.ptp(t)),
                     n_points=int(len(s)), n_frames=int(len(frames)))
