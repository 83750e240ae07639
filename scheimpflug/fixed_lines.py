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

A still surface as a board of the twin's housing (:func:`wall_board`)
    The wall's points, mapped by the calibration into its camera frame, lie on
    one straight 3-D line (the sheet ∩ the wall).  One laser fixes that line,
    not the wall's tilt about it; every tilt gives the same laser line, so the
    board is taken through the line perpendicular to the sheet, its face toward
    the camera (:class:`scheimpflug.model.housing.Board`).  Its length covers the
    points and a margin; its width across the sheet is a choice.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scheimpflug.model.housing import Board

__all__ = ["FixedLine", "fixed_line", "line_inliers", "wall_board", "walls_of_folder"]


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


def _distinct_up_to_3(p: np.ndarray) -> int:
    """How many distinct rows ``p`` has, counted up to 3 (in O(n): no sort)."""
    seen = np.zeros(len(p), bool)
    for k in range(3):
        rest = np.flatnonzero(~seen)
        if len(rest) == 0:
            return k
        seen |= np.all(p == p[rest[0]], axis=1)
    return 3


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
        Fewer than 3 distinct finite points.
    """
    s, h = np.asarray(stage_mm, np.float64), np.asarray(h_mm, np.float64)
    f = np.asarray(frame)
    ok = np.isfinite(s) & np.isfinite(h)
    s, h, f = s[ok], h[ok], f[ok]
    p = np.stack([s, h], axis=1)
    distinct = _distinct_up_to_3(p)
    if distinct < 3:          # e.g. one point repeated: no direction, and the bow's fit is singular
        raise ValueError(f"a line needs at least 3 distinct finite points, got {distinct}")
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


def wall_board(calibration, u_px, v_px, name: str, *, margin_mm: float = 10.0, width_mm: float = 60.0,
               material: str = "cardboard") -> Board:
    """The board of a still wall whose stripe points are given (module docstring).

    Parameters
    ----------
    calibration : SheetModel
        A calibration with the sheet in its camera frame (``camera_from_pixel``, ``sheet_frame``:
        a target, general or FabScan calibration).
    u_px, v_px : (n,) array_like float
        The wall's stripe points, all frames (e.g. :func:`line_inliers` of a column range) [px].
    name : str
        The board's name.
    margin_mm : float, default 10.0
        Length added beyond the points at each end [mm].
    width_mm : float, default 60.0
        The board's extent across the sheet [mm].
    material : str, default "cardboard"
        Its material tag.

    Returns
    -------
    Board
        In the calibration's camera frame: the face through the points' 3-D line (total least
        squares), perpendicular to the sheet, its normal toward the camera.

    Raises
    ------
    ValueError
        Fewer than 2 finite points, or points that do not spread along a line.
    """
    p = np.asarray(calibration.camera_from_pixel(np.asarray(u_px, np.float64), np.asarray(v_px, np.float64)))
    p = p[np.all(np.isfinite(p), axis=1)]
    if len(p) < 2:
        raise ValueError(f"a wall needs at least 2 finite points on the sheet, got {len(p)}")
    c = p.mean(axis=0)
    _, sv, vt = np.linalg.svd(p - c, full_matrices=False)
    if not sv[0] > 0:
        raise ValueError("the wall's points do not spread along a line (all at one point)")
    d = vt[0]
    _, e_s, e_h = calibration.sheet_frame()
    n_sheet = np.cross(e_s, e_h)
    normal = np.cross(n_sheet / np.linalg.norm(n_sheet), d)
    normal /= np.linalg.norm(normal)
    if normal @ c > 0:                       # the face toward the camera (at the origin)
        normal = -normal
    t = (p - c) @ d
    centre = c + 0.5 * (t.min() + t.max()) * d
    return Board(name, centre, normal, d, float(np.ptp(t)) + 2.0 * margin_mm, float(width_mm), 10.0, material)


def walls_of_folder(folder, calibration, column_ranges, detector: str = "cog", *,
                    stripes=None) -> tuple[tuple, list]:
    """The still walls of a scan as housing boards, one column range of its frames per wall.

    Parameters
    ----------
    folder : FrameFolder
        The scan (:func:`scheimpflug.io.frames.open_frame_folder`; its ``stripe_along`` followed).
    calibration : SheetModel
        Its calibration, with the sheet in its camera frame (as :func:`wall_board`).
    column_ranges : sequence of (float, float)
        Image column ranges [px], one per wall, where its stripe shows.
    detector : str, default "cog"
        The stripe detector (:mod:`scheimpflug.stripe`).
    stripes : FolderStripes, optional
        The folder's stripes already extracted with that detector (kept saturated samples):
        :func:`scheimpflug.reconstruct.extract_folder_stripes`; default: extracted here.

    Returns
    -------
    boards : tuple of Board
        ``wall1``, ``wall2`` … in the calibration's camera frame (:func:`wall_board`).
    figures : list of dict
        Per wall: ``columns_px``, ``points`` and ``frames`` kept by :func:`line_inliers`, and
        the straightness ``rms_mm`` of :func:`fixed_line`.

    Raises
    ------
    ValueError
        A range holding fewer than 3 stripe points.
    """
    from scheimpflug.reconstruct import extract_folder_stripes
    from scheimpflug.stripe import image_pixels

    st = extract_folder_stripes(folder, detector, keep_saturated=True) if stripes is None else stripes
    u, v = image_pixels(np.concatenate(st.rows), np.concatenate(st.u), st.along)
    frame = np.concatenate([np.full(len(r), i) for i, r in enumerate(st.rows)])
    boards, figures = [], []
    for i, (c0, c1) in enumerate(column_ranges):
        sel = np.flatnonzero((u >= c0) & (u <= c1))
        if len(sel) < 3:
            raise ValueError(f"columns {c0:g}:{c1:g} hold {len(sel)} stripe points: no wall there")
        sel = sel[line_inliers(u[sel], v[sel])]
        boards.append(wall_board(calibration, u[sel], v[sel], f"wall{i + 1}"))
        s, h = calibration.stage_from_pixel(u[sel], v[sel])
        line = fixed_line(s, h, frame[sel])
        figures.append({"columns_px": [float(c0), float(c1)], "points": int(len(sel)),
                        "frames": line.n_frames, "rms_mm": line.rms_mm})
    return tuple(boards), figures
