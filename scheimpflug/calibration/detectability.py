"""Printed patterns on a Scheimpflug rig: rectified views for the detector, and what a rig can detect.

A Scheimpflug camera sees its sheet obliquely (the paper rig ≈ 78° from the sheet's
normal): a print held in the sheet is imaged foreshortened along the columns (they are
distances), sheared (the rows of constant height converge on the image hinge) and
magnified ≈ 1.6 × more at the near end than at the far end.  OpenCV's chessboard,
ChArUco and circle-grid detectors, made for near-frontal views, give up on such frames
(issue 34 item 15).  A rig knows the homography from its image to any plane (its chief
rays): warped by it, a print in that plane is seen frontal — square squares of one size
over the whole depth range.

Views
-----
:func:`print_views` gives, for a rig, the homographies ``view_from_image`` of
:data:`PRINT_TURNS_DEG`: the sheet itself and planes turned from it about the vertical
and about the propagation direction (a hand-held print is rarely in the sheet: a turn
about the vertical stretches it along the distance axis, a tilt about the propagation
direction shears it), each scaled so that a square of the pattern spans
:attr:`DetectionLimits.view_square_px` pixels of the view (at the view's anchor, the
sheet point the sensor's centre sees).  :func:`lattice_views` corrects a view by the print's
own lattice (the autocorrelation's dips and the edges' directions give its two square
steps), whatever the print's turn.  The detector runs on the frame itself first, then on
the lattice views of the first view, then on each view in turn; corners found in a view
are mapped back by the inverse homography and refined on the original frame
(:func:`scheimpflug.calibration.measure.detect_pattern`), so the resampling never enters a
corner's sub-pixel position.  Without a rig, :func:`generic_views` stretches the frame
along its distance axis instead (and the lattice views correct the first stretch).

What a rig can detect
---------------------
A square of side ``s`` in the sheet spans ``s / |dD/du|`` columns and ``s / |dh/dv|`` rows
(paper Eqs. 11–12: ``|dD/du| = |F²|/(u − u_h)²``, ``|dh/dv| = C/|u − u_h|``), smallest
across the columns at the far end.  A rectified view adds no information: the detector
needs the squares resolved in the frame itself.  :class:`DetectionLimits` holds the
smallest resolved feature per pattern kind (where the twin's patterns were found, each
value's reason); :func:`pattern_advice` says, for a rig (and
its binning), where a pattern is detectable and whether it fits the view;
:func:`square_advice` gives the smallest detectable square and the largest board that fits.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from scheimpflug.model.camera import chief_ray_from_pixel, lens_centre_mm, sensor_pose, sheet_point_from_pixel
from scheimpflug.model.hinge import hinge_geometry
from scheimpflug.model.rig import Rig

__all__ = [
    "A4_PRINT_MM",
    "PRINT_TURNS_DEG",
    "DetectionLimits",
    "PatternAdvice",
    "PatternView",
    "format_pattern_advice",
    "format_square_advice",
    "frame_views",
    "generic_views",
    "largest_chessboard",
    "lattice_view",
    "lattice_views",
    "pattern_advice",
    "plane_from_image",
    "print_views",
    "rig_from_manifest",
    "square_advice",
    "square_size_px",
]

#: Print planes of the views, (turn about the vertical, tilt about the propagation direction) from
#: the sheet [deg], in the order they are tried (the order that found the twin's hand-held poses
#: soonest: benchmarks/bench_chessboard_scheimpflug.py).  A turn stretches the print along the
#: distance axis of the sheet's view, a tilt shears it by tan θ·sin(tilt) (θ ≈ 78° on the paper rig).
PRINT_TURNS_DEG = ((0.0, 0.0), (-20.0, 18.0), (0.0, -18.0), (-20.0, 0.0), (0.0, 18.0),
                   (25.0, 18.0), (-20.0, -18.0), (25.0, -18.0), (0.0, 35.0), (0.0, -35.0))


#: The printed area of an A4 sheet inside 10 mm margins, landscape (w × h) [mm]: the largest board advised.
A4_PRINT_MM = (277.0, 190.0)


@dataclass(frozen=True)
class DetectionLimits:
    """Thresholds of the rectified detection and of the advice, one reason each.

    Parameters
    ----------
    view_square_px : float, default 24.0
        A square (dot pitch) spans this many pixels of a view at its anchor: OpenCV's
        detectors find 20–40 px squares most surely [px].
    min_view_square_px : float, default 12.0
        A view too large at ``view_square_px`` is scaled down to at most this [px].
    max_view_px : int, default 2048
        Larger views are tiled (a view's side) [px].
    max_tiles : int, default 4
        A view needing more tiles is left out [-].
    chessboard_min_px : float, default 6.0
        A chessboard's (and ChArUco's) square must span at least this many pixels of the
        frame along both image axes to be found surely: of the twin's whole, sharp boards
        (paper rig at binnings 4 and 8, the FabScan-like rig at 2) whose smallest square spanned
        3.4–5.4 px, 7 of 13 were found; the boards missed with larger squares were missed for
        their pose, not their size [px].
    charuco_cell_min_px : float, default 1.8
        A ChArUco marker's bit cell must span at least this many pixels to be read: markers
        read at 1.7 px, none at 1.65 px (paper rig, binning 4, ``DICT_4X4_50``) [px].
    circles_min_px : float, default 4.0
        A dot's diameter must span at least this many pixels to be a blob: found at 4.2 px
        (paper rig, binning 4) [px].
    fit_fraction : float, default 1.0
        A print fits the view at a distance when its diagonal is at most this fraction of
        the height the sensor sees there (any in-plane turn then stays within the rows) [-].
    """

    view_square_px: float = 24.0       # squares of 20–40 px are found most surely [px]
    min_view_square_px: float = 12.0   # a large view is scaled down to no less [px]
    max_view_px: int = 2048            # larger views are tiled [px]
    max_tiles: int = 4                 # a view needing more tiles is left out [-]
    chessboard_min_px: float = 6.0     # a square resolved along both axes of the frame [px]
    charuco_cell_min_px: float = 1.8   # a marker's bit cell resolved [px]
    circles_min_px: float = 4.0        # a dot resolved [px]
    fit_fraction: float = 1.0          # the print's diagonal within this of the height in view [-]


@dataclass(frozen=True)
class PatternView:
    """One rectified view of a frame in which the detector looks for a pattern.

    Parameters
    ----------
    name : str
        What it rectifies, e.g. ``"sheet"``, ``"turn -20° tilt 18°"``, ``"stretch 3×"``.
    view_from_image : (3, 3) ndarray float64
        Homography from the frame's pixels (u, v) to the view's [px].
    size : tuple of int
        (columns, rows) of the view [px].
    """

    name: str
    view_from_image: np.ndarray
    size: tuple[int, int]

    def warp(self, gray: np.ndarray) -> np.ndarray:
        """The view of an 8-bit frame (bilinear; a frame much finer than the view is halved first).

        Parameters
        ----------
        gray : (rows, columns) ndarray uint8
            The frame.

        Returns
        -------
        (size[1], size[0]) ndarray uint8
            The view; black outside the frame.
        """
        h, img = self.view_from_image, gray
        while _min_scale(h, img.shape) < 0.5 and min(img.shape) >= 64:   # no aliasing: halve the frame
            r, c = img.shape[0] // 2, img.shape[1] // 2
            img = cv2.resize(img[:2 * r, :2 * c], (c, r), interpolation=cv2.INTER_AREA)
            h = h @ np.array([[2.0, 0.0, 0.5], [0.0, 2.0, 0.5], [0.0, 0.0, 1.0]])   # pixel j covers 2j, 2j + 1
        return cv2.warpPerspective(img, h, self.size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                                   borderValue=0)

    def image_from_view(self, points_px: np.ndarray) -> np.ndarray:
        """Frame pixels of view points.

        Parameters
        ----------
        points_px : (n, 2) array_like float
            Points of the view (u, v) [px].

        Returns
        -------
        (n, 2) ndarray float64
            The same points in the frame [px].
        """
        p = np.asarray(points_px, np.float64).reshape(-1, 2)
        q = np.c_[p, np.ones(len(p))] @ np.linalg.inv(self.view_from_image).T
        return q[:, :2] / q[:, 2:]


def _min_scale(h: np.ndarray, shape) -> float:
    """The smallest singular value of the homography's Jacobian at the frame's centre [view px / frame px]."""
    u, v = 0.5 * (shape[1] - 1), 0.5 * (shape[0] - 1)
    q = h @ np.array([u, v, 1.0])
    j = (h[:2, :2] - np.outer(q[:2] / q[2], h[2, :2])) / q[2]
    return float(np.linalg.svd(j, compute_uv=False)[-1])


# ---------------------------------------------------------------- geometry of the rig


def rig_from_manifest(rig_table) -> Rig | None:
    """The rig of a frame folder's manifest (``FrameFolder.rig``), or None when it has none or it is unreadable.

    Parameters
    ----------
    rig_table : dict or None
        The manifest's ``rig`` table.

    Returns
    -------
    Rig or None
        The rig.
    """
    if not isinstance(rig_table, dict):
        return None
    from scheimpflug.model.rig import rig_from_dict

    try:
        return rig_from_dict(rig_table)
    except (ValueError, TypeError, KeyError, ArithmeticError):
        return None


def _rotation(axis, angle_rad: float) -> np.ndarray:
    k = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(angle_rad) * kx + (1.0 - math.cos(angle_rad)) * kx @ kx


def plane_from_image(rig: Rig, turn_deg: float = 0.0, tilt_deg: float = 0.0) -> np.ndarray | None:
    """The homography from a rig's pixels to a print plane's coordinates (its chief rays).

    The plane passes through the sheet point the sensor's centre sees (the anchor), turned
    from the sheet by ``turn_deg`` about the vertical and tilted by ``tilt_deg`` about the
    propagation direction.  Its coordinates (a, b) [mm] run along the turned propagation
    direction and downward, from the anchor: a print in it, columns along the propagation
    direction and rows downward (:mod:`sim.target`'s hand-held pose before its turns), is
    seen as printed.  Fitted (least squares) to the chief rays of 7 × 7 pixels over the
    sensor: exact without lens distortion.

    Parameters
    ----------
    rig : Rig
        The instrument (a binned read-out: :func:`scheimpflug.model.binning.binned_rig`).
    turn_deg, tilt_deg : float
        The plane's turn about the vertical (+z) and tilt about the propagation direction
        from the sheet [deg].

    Returns
    -------
    (3, 3) ndarray float64 or None
        ``plane_from_image``: (u, v, 1) [px] → (a, b, 1) [mm]; None where a pixel's chief ray
        misses the plane (parallel to it, or meeting it behind the lens).
    """
    g = hinge_geometry(rig)
    pose = sensor_pose(rig)
    cols, rows = pose.columns, pose.rows
    uu, vv = np.meshgrid(np.linspace(-0.5, cols - 0.5, 7), np.linspace(-0.5, rows - 0.5, 7))
    uv = np.c_[uu.ravel(), vv.ravel()]
    c = lens_centre_mm(rig)
    anchor = sheet_point_from_pixel(rig, np.array([0.5 * (cols - 1), 0.5 * (rows - 1)]), pose)
    if not np.isfinite(anchor).all():
        return None
    r = _rotation([0.0, 0.0, 1.0], math.radians(turn_deg)) @ _rotation(g.propagation_dir, math.radians(tilt_deg))
    e_a, e_b = r @ g.propagation_dir, r @ np.array([0.0, 0.0, -1.0])
    n = np.cross(e_a, e_b)
    d = chief_ray_from_pixel(rig, uv, pose)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = ((anchor - c) @ n) / (d @ n)
    if not (np.isfinite(t).all() and (t > 0).all()):
        return None
    x = c + t[:, None] * d
    return _homography(uv, np.c_[(x - anchor) @ e_a, (x - anchor) @ e_b])


def _normalising(p: np.ndarray) -> np.ndarray:
    """Hartley's similarity: the points' centroid to the origin, their mean distance to √2."""
    c = p.mean(axis=0)
    s = math.sqrt(2.0) / max(float(np.mean(np.linalg.norm(p - c, axis=1))), 1e-300)
    return np.array([[s, 0.0, -s * c[0]], [0.0, s, -s * c[1]], [0.0, 0.0, 1.0]])


def _homography(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """The least-squares homography dst ~ H·src of n ≥ 4 point pairs (normalised DLT, float64), (3, 3)."""
    ts, td = _normalising(src), _normalising(dst)
    a = np.c_[src, np.ones(len(src))] @ ts.T
    b = np.c_[dst, np.ones(len(dst))] @ td.T
    z = np.zeros_like(a)
    m = np.vstack([np.c_[a, z, -b[:, :1] * a], np.c_[z, a, -b[:, 1:2] * a]])
    h = np.linalg.svd(m)[2][-1].reshape(3, 3)
    h = np.linalg.solve(td, h @ ts)
    return h / h[2, 2]


def square_size_px(rig: Rig, square_mm: float, u_px=None) -> tuple[np.ndarray, np.ndarray]:
    """How many pixels a square of the print spans, held in the sheet, by column (paper Eqs. 11–12).

    Parameters
    ----------
    rig : Rig
        The instrument (binned read-out for a binning).
    square_mm : float
        The square's side (a dot pitch, a dot's diameter) [mm].
    u_px : array_like float, optional
        Columns [px]; default the first and the last.

    Returns
    -------
    across_px : ndarray float64
        Along the columns (the distance axis): ``s·(u − u_h)²/|F²|`` [px].
    down_px : ndarray float64
        Along the rows (height): ``s·|u − u_h|/C`` [px].
    """
    g = hinge_geometry(rig)
    u = np.asarray([0.0, rig.sensor.columns - 1.0] if u_px is None else u_px, np.float64)
    return square_mm / g.distance_resolution(u), square_mm / g.height_resolution(u)


# ---------------------------------------------------------------- views


def _footprint(h: np.ndarray, shape_cr, band=None) -> np.ndarray:
    """The corners of the frame (or of its band of columns ``band`` = (u0, u1)) through ``h``, (4, 2)."""
    cols, rows = shape_cr
    u0, u1 = (-0.5, cols - 0.5) if band is None else band
    corners = np.array([[u0, -0.5], [u1, -0.5], [u1, rows - 0.5], [u0, rows - 0.5]])
    q = np.c_[corners, np.ones(4)] @ h.T
    return q[:, :2] / q[:, 2:]


def _scaled(h: np.ndarray, scale: float, lo) -> np.ndarray:
    return np.array([[scale, 0.0, -scale * lo[0]], [0.0, scale, -scale * lo[1]], [0.0, 0.0, 1.0]]) @ h


def _view_of_plane(name: str, plane_from_img: np.ndarray, shape_cr, pitch_mm: float, extent_mm: float,
                   limits: DetectionLimits, band=None) -> list[PatternView]:
    """One plane's view (or its tiles) of the frame's band of columns, scaled or tiled when large.

    A square spans ``view_square_px`` at the anchor; a view too large for ``max_view_px`` is
    scaled down to ``min_view_square_px``, then tiled with overlaps of a whole print.
    """
    q = _footprint(plane_from_img, shape_cr, band)
    lo, span = q.min(axis=0), np.ptp(q, axis=0)
    scale = limits.view_square_px / pitch_mm
    if span.max() * scale > limits.max_view_px:
        scale = max(limits.max_view_px / span.max(), limits.min_view_square_px / pitch_mm)
    margin = 2.0 * limits.view_square_px
    size = np.ceil(span * scale + 2 * margin).astype(int)
    h = _scaled(plane_from_img, scale, lo - margin / scale)
    if size.max() <= limits.max_view_px:
        return [PatternView(name, h, (int(size[0]), int(size[1])))]
    overlap = extent_mm * scale + 2 * margin                       # a whole print in some tile
    step = limits.max_view_px - overlap
    if step <= 0:
        return []
    n = np.maximum(1, np.ceil((size - overlap) / step)).astype(int)
    if n.prod() > limits.max_tiles:
        return []
    tiles = []
    for i in range(n[0]):
        for j in range(n[1]):
            x0, y0 = i * step, j * step
            w, hh = min(limits.max_view_px, size[0] - x0), min(limits.max_view_px, size[1] - y0)
            shift = np.array([[1.0, 0.0, -x0], [0.0, 1.0, -y0], [0.0, 0.0, 1.0]])
            tiles.append(PatternView(f"{name} tile {i},{j}", shift @ h, (int(w), int(hh))))
    return tiles


def _chiral(h: np.ndarray, shape_cr) -> np.ndarray:
    """The view mirrored back when the plane's coordinates mirror the frame (ChArUco markers read mirrored)."""
    u, v = 0.5 * (shape_cr[0] - 1), 0.5 * (shape_cr[1] - 1)
    q = h @ np.array([u, v, 1.0])
    j = (h[:2, :2] - np.outer(q[:2] / q[2], h[2, :2])) / q[2]
    return h if np.linalg.det(j) > 0 else np.diag([-1.0, 1.0, 1.0]) @ h


def print_views(rig: Rig, spec, limits: DetectionLimits = DetectionLimits()) -> tuple[PatternView, ...]:
    """The rectified views of a rig's frames in which to look for a pattern (module docstring).

    Parameters
    ----------
    rig : Rig
        The instrument as its frames were read out (binned: the manifest's rig).
    spec : PatternSpec
        The pattern (its square or dot pitch sets the views' scale, its extent the tiles' overlap).
    limits : DetectionLimits, optional
        Sizes of the views.

    Returns
    -------
    tuple of PatternView
        One view per plane of :data:`PRINT_TURNS_DEG` (in that order; a plane whose view
        would need more than ``max_tiles`` tiles, or that a chief ray misses, is left out), of
        the band of columns where the pattern is resolved (:func:`pattern_advice`); none when
        it is resolved nowhere.
    """
    shape = (rig.sensor.columns, rig.sensor.rows)
    x0, y0, x1, y1 = spec.extent_mm()
    extent = math.hypot(x1 - x0, y1 - y0)
    u, _ = _depths(rig)
    ok = _resolved(rig, spec, limits, u)
    if not ok.any():
        return ()
    step = u[1] - u[0]
    band = (max(u[ok].min() - step, -0.5), min(u[ok].max() + step, rig.sensor.columns - 0.5))
    out: list[PatternView] = []
    for turn, tilt in PRINT_TURNS_DEG:
        h = plane_from_image(rig, turn, tilt)
        if h is None:
            continue
        name = "sheet" if turn == 0 and tilt == 0 else f"turn {turn:g}° tilt {tilt:g}°"
        out += _view_of_plane(name, _chiral(h, shape), shape, spec.pitch_mm, extent, limits, band)
    return tuple(out)


def frame_views(rig_table, shape, spec, along: str = "columns",
                limits: DetectionLimits = DetectionLimits()) -> tuple[PatternView, ...]:
    """The views to look for a pattern in a folder's frames: its rig's, else generic ones.

    Parameters
    ----------
    rig_table : dict or None
        The folder manifest's ``rig`` (:attr:`scheimpflug.io.frames.FrameFolder.rig`).
    shape : tuple of int
        The frames' (rows, columns) [px].
    spec : PatternSpec
        The pattern.
    along : {"columns", "rows"}, default "columns"
        Which way the laser stripe runs in the frames (the folder's ``stripe_along``).
    limits : DetectionLimits, optional
        Sizes of the views.

    Returns
    -------
    tuple of PatternView
        :func:`print_views` of the rig when it is readable and read out at the frames' size
        (and the stripe runs down the columns, as the rig's sensor has it) — none when the rig
        resolves the pattern nowhere (:func:`pattern_advice`: a view adds no information) —
        else :func:`generic_views`.
    """
    rig = rig_from_manifest(rig_table)
    if rig is not None and along == "columns" and (rig.sensor.rows, rig.sensor.columns) == tuple(shape):
        if pattern_advice(rig, spec, limits).detectable_mm is None:
            return ()                      # resolved nowhere: no view shows it (the frame itself is tried)
        views = print_views(rig, spec, limits)
        if views:
            return views
    return generic_views(shape, along, limits)


# ---------------------------------------------------------------- the print's own lattice


def _autocorrelation(view: np.ndarray, valid: np.ndarray, sigma_px: float, lag_px: int) -> np.ndarray:
    """Normalised autocorrelation of the view's high-passed valid pixels, lags within ±lag_px, (2·lag + 1)²."""
    x = view.astype(np.float32)
    hp = (x - cv2.GaussianBlur(x, (0, 0), sigma_px)) * valid
    rows, cols = cv2.getOptimalDFTSize(hp.shape[0] + lag_px), cv2.getOptimalDFTSize(hp.shape[1] + lag_px)
    f = np.fft.rfft2(hp, (rows, cols))
    r = np.fft.irfft2(f.real ** 2 + f.imag ** 2, (rows, cols))
    if not r[0, 0] > 0:
        return np.zeros((2 * lag_px + 1, 2 * lag_px + 1))
    r = np.roll(r, (lag_px, lag_px), axis=(0, 1))[:2 * lag_px + 1, :2 * lag_px + 1]
    return r / r[lag_px, lag_px]


def _edge_histogram(view: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Gradient energy by direction modulo 180° over the valid pixels, 360 bins of 0.5°, smoothed over 2.5°."""
    g = cv2.GaussianBlur(view.astype(np.float32), (0, 0), 1.0)
    gx, gy = cv2.Sobel(g, cv2.CV_32F, 1, 0), cv2.Sobel(g, cv2.CV_32F, 0, 1)
    weight = np.hypot(gx, gy) * valid
    theta = np.mod(np.degrees(np.arctan2(gy, gx)), 180.0)
    hist = np.bincount(np.minimum((theta * 2).astype(np.int64), 359).ravel(), weight.ravel(), 360)
    return np.convolve(np.r_[hist[-2:], hist, hist[:2]], np.ones(5), "same")[2:-2]


def _edge_share(hist: np.ndarray, step: np.ndarray) -> float:
    """The histogram's mass within ±5° of the normal of a step (edges along it)."""
    normal = math.degrees(math.atan2(step[0], -step[1])) % 180.0
    k = np.arange(360) * 0.5
    near = np.abs((k - normal + 90.0) % 180.0 - 90.0) <= 5.0
    return float(hist[near].sum())


def _lattice_vectors(view: np.ndarray, valid: np.ndarray, r: np.ndarray, count: int = 1,
                     min_depth: float = 0.05) -> list[tuple[np.ndarray, np.ndarray]]:
    """The chessboard's two square steps in a view, most likely first (at most ``count``; none without a lattice).

    A chessboard's autocorrelation ``R`` dips at a one-square shift (black onto white) and
    peaks at a diagonal one: among the twelve nearest local minima deeper than ``min_depth``
    the pairs (a₁, a₂), not collinear, with ``R(a₁ + a₂) + R(a₁ − a₂) − R(a₁) − R(a₂)``
    within half of the best.  Every odd lattice vector dips as deep (a₁ and a₁ + 2a₂ span one
    square too, sheared): the pairs that span the smallest cell (one square) come first, the
    one whose two directions carry the most edges (the gradient's directions,
    :func:`_edge_share`) first among them; then the others by the same share.
    """
    lag = r.shape[0] // 2
    lows = (r == cv2.erode(r.astype(np.float32), np.ones((3, 3), np.uint8))) & (r < -min_depth)
    yy, xx = np.mgrid[-lag:lag + 1, -lag:lag + 1]
    lows &= np.hypot(xx, yy) > 2
    pts = np.c_[xx[lows], yy[lows]].astype(np.float64)
    pts = pts[np.argsort(np.hypot(pts[:, 0], pts[:, 1]))[:12]]

    def at(p):
        i, j = int(round(p[1])) + lag, int(round(p[0])) + lag
        return r[i, j] if 0 <= i < r.shape[0] and 0 <= j < r.shape[1] else 0.0

    pairs = [(at(p + q) + at(p - q) - at(p) - at(q), abs(p[0] * q[1] - p[1] * q[0]), p, q)
             for k, p in enumerate(pts) for q in pts[k + 1:]
             if abs(p @ q) < 0.95 * np.linalg.norm(p) * np.linalg.norm(q)]
    if not pairs:
        return []
    top = max(x[0] for x in pairs)
    good = [x for x in pairs if x[0] >= 0.5 * top]
    cell = min(x[1] for x in good)
    hist = _edge_histogram(view, valid)
    ranked = sorted(good, key=lambda x: (x[1] > 1.15 * cell, -_edge_share(hist, x[2]) - _edge_share(hist, x[3])))
    return [(x[2], x[3]) for x in ranked[:count]]


def lattice_views(gray: np.ndarray, base: PatternView | None, limits: DetectionLimits = DetectionLimits(),
                  square_px: float | None = None, count: int = 3) -> list[PatternView]:
    """Views in which the print's squares are square: ``base`` corrected by the lattice it shows.

    The print's two square steps in the base view (:func:`_lattice_vectors`, from the
    autocorrelation of the view high-passed at the squares' scale) give the affine map
    ``A = [a₁ a₂]`` of a unit square to the view; the new view is ``S·A⁻¹`` of the base
    (``S`` = ``view_square_px``), so a print that the base shows stretched or sheared
    (turned or tilted out of the base's plane) is shown with square squares.  Blur and a steep
    view make the steps ambiguous: up to ``count`` readings, most likely first.

    Parameters
    ----------
    gray : (rows, columns) ndarray uint8
        The frame.
    base : PatternView or None
        The view to correct (None: the frame itself).
    limits : DetectionLimits, optional
        ``view_square_px``, ``min_view_square_px``, ``max_view_px``.
    square_px : float, optional
        The squares' expected size in the base view [px]; default ``view_square_px`` for a
        view, 16 for the frame itself.
    count : int, default 3
        Readings of the lattice tried [-].

    Returns
    -------
    list of PatternView
        The corrected views; empty without a lattice (no print, or a print too blurred); a
        reading whose view would exceed ``max_view_px`` at ``min_view_square_px`` is left out.
    """
    shape_cr = (gray.shape[1], gray.shape[0])
    if base is None:
        view, valid, h0, name = gray, np.ones(gray.shape, bool), np.eye(3), "the frame"
        sq = float(square_px or 16.0)
    else:
        view, h0, name = base.warp(gray), base.view_from_image, base.name
        valid = cv2.erode(base.warp(np.full(gray.shape, 255, np.uint8)), np.ones((5, 5), np.uint8)) > 0
        sq = float(square_px or limits.view_square_px)
    valid = valid & (cv2.GaussianBlur((view > 0).astype(np.float32), (0, 0), 2.0) > 0.99)   # black: no print
    out = []
    for k, steps in enumerate(_lattice_vectors(view, valid, _autocorrelation(view, valid, sq, int(6 * sq)), count)):
        a = np.column_stack(steps)
        if np.linalg.det(a) < 0:
            a = a[:, ::-1]
        fix = np.eye(3)
        fix[:2, :2] = np.linalg.inv(a)
        h = fix @ h0                                      # one square per unit
        q = _footprint(h, shape_cr)
        lo, span = q.min(axis=0), np.ptp(q, axis=0)
        scale = min(limits.view_square_px, limits.max_view_px / max(span.max(), 1e-9))
        if np.isfinite(span).all() and scale >= limits.min_view_square_px:
            size = np.ceil(span * scale).astype(int) + 1
            out.append(PatternView(f"lattice {k + 1} of {name}", _scaled(h, scale, lo), (int(size[0]), int(size[1]))))
    return out


def lattice_view(gray: np.ndarray, base: PatternView | None, limits: DetectionLimits = DetectionLimits(),
                 square_px: float | None = None) -> PatternView | None:
    """The most likely of :func:`lattice_views`, or None.

    Parameters
    ----------
    gray : (rows, columns) ndarray uint8
        The frame.
    base : PatternView or None
        The view to correct (None: the frame itself).
    limits : DetectionLimits, optional
        Sizes of the view.
    square_px : float, optional
        The squares' expected size in the base view [px].

    Returns
    -------
    PatternView or None
        The corrected view.
    """
    views = lattice_views(gray, base, limits, square_px, count=1)
    return views[0] if views else None


#: Stretches of the frame along its distance axis tried without a rig [-].
GENERIC_STRETCHES = (2.0, 3.5)


def generic_views(shape, along: str = "columns",
                  limits: DetectionLimits = DetectionLimits()) -> tuple[PatternView, ...]:
    """Views of a frame without a rig: the frame stretched along its distance axis.

    A Scheimpflug camera foreshortens a print along the image axis that measures distance:
    the columns when the stripe runs down the columns (``along = "columns"``), the rows when
    it runs across the image.

    Parameters
    ----------
    shape : tuple of int
        The frame's (rows, columns) [px].
    along : {"columns", "rows"}, default "columns"
        Which way the laser stripe runs (:func:`scheimpflug.calibration.measure.stripe_points`).
    limits : DetectionLimits, optional
        ``max_view_px`` caps the stretched side.

    Returns
    -------
    tuple of PatternView
        One view per factor of :data:`GENERIC_STRETCHES` (capped at ``max_view_px``).
    """
    rows, cols = int(shape[0]), int(shape[1])
    out = []
    for k in GENERIC_STRETCHES:
        if along == "rows":
            k = min(k, limits.max_view_px / rows)
            h, size = np.diag([1.0, k, 1.0]), (cols, int(math.ceil(rows * k)))
        else:
            k = min(k, limits.max_view_px / cols)
            h, size = np.diag([k, 1.0, 1.0]), (int(math.ceil(cols * k)), rows)
        if k > 1.2:
            h[:2, 2] = 0.5 * (np.diag(h)[:2] - 1.0)           # pixel centres map to pixel centres
            out.append(PatternView(f"stretch {k:.3g}×", h, size))
    return tuple(out)


# ---------------------------------------------------------------- what a rig can detect


def _depths(rig: Rig, n: int = 257) -> tuple[np.ndarray, np.ndarray]:
    """Columns across the sensor and the distance each sees [px, mm] (paper Eq. 11)."""
    u = np.linspace(0.0, rig.sensor.columns - 1.0, n)
    return u, hinge_geometry(rig).distance_from_column(u)


def _feature(spec) -> tuple[float, str, float]:
    """The pattern's smallest feature that must be resolved: size [mm], name, kind's threshold key."""
    if spec.kind == "circles":
        return spec.diameter_mm, "dot", "circles_min_px"
    if spec.kind == "charuco":
        from scheimpflug.calibration.pattern import aruco_dictionary

        cells = aruco_dictionary(spec).markerSize + 2
        return spec.marker_mm / cells, "marker bit", "charuco_cell_min_px"
    return spec.pitch_mm, "square", "chessboard_min_px"


def _interval(d: np.ndarray, ok: np.ndarray) -> tuple[float, float] | None:
    return (float(d[ok].min()), float(d[ok].max())) if ok.any() else None


@dataclass(frozen=True)
class PatternAdvice:
    """What a rig, read out as its frames are, can detect of one pattern (:func:`pattern_advice`).

    Parameters
    ----------
    pattern : str
        The pattern spec.
    columns, rows : int
        The read-out's size [px].
    depth_mm : tuple of float
        Distance D from the object hinge seen by the first and the last column [mm].
    square_px : tuple of tuple of float
        A square (dot pitch) in the sheet at those two ends: (across the columns, down the rows) [px].
    feature : str
        The feature that must be resolved: ``"square"``, ``"marker bit"``, ``"dot"``.
    feature_px : tuple of float
        Its smallest image size (the shorter axis) at the two ends [px].
    min_feature_px : float
        What OpenCV's detector needs (:class:`DetectionLimits`) [px].
    detectable_mm : tuple of float or None
        The D range where the feature is resolved, or None (nowhere) [mm].
    fits_mm : tuple of float or None
        The D range where the whole print fits the view at any in-plane turn (its diagonal
        within ``fit_fraction`` of the height seen, its centre a half-diagonal inside the
        depth range), or None [mm].
    min_square_mm : float
        The smallest square (dot pitch) of this kind of pattern resolved over the whole depth
        range (ChArUco: with this pattern's marker-to-square ratio) [mm].
    """

    pattern: str
    columns: int
    rows: int
    depth_mm: tuple[float, float]
    square_px: tuple[tuple[float, float], tuple[float, float]]
    feature: str
    feature_px: tuple[float, float]
    min_feature_px: float
    detectable_mm: tuple[float, float] | None
    fits_mm: tuple[float, float] | None
    min_square_mm: float

    @property
    def usable_mm(self) -> tuple[float, float] | None:
        """The D range where the print is resolved and (but for ChArUco, found in part) wholly in view, or None [mm]."""
        if self.feature == "marker bit":
            return self.detectable_mm
        if self.detectable_mm is None or self.fits_mm is None:
            return None
        lo, hi = max(self.detectable_mm[0], self.fits_mm[0]), min(self.detectable_mm[1], self.fits_mm[1])
        return (lo, hi) if lo <= hi else None

    def problem(self) -> str | None:
        """Why the pattern is not found surely on this rig (a warning before rendering or printing), or None.

        The sizes are those of a print held in the sheet, the camera's most oblique view of it:
        a print tilted toward the camera shows larger squares, and may still be found in some
        poses.

        Returns
        -------
        str or None
            Too small to resolve anywhere, too large for the view, or only resolved where it
            does not fit; None when there is a range of distances where it is found whole.
        """
        if self.detectable_mm is None:
            return (f"{self.pattern}: its {self.feature}s span at most {max(self.feature_px):.1f} px here, "
                    f"OpenCV's detector finds them surely from {self.min_feature_px:g} px: use squares of at "
                    f"least {self.min_square_mm:.3g} mm (or a finer read-out)")
        if self.fits_mm is None and self.feature != "marker bit":
            return (f"{self.pattern}: the print does not fit the view whole at any distance: use fewer or "
                    "smaller squares")
        if self.usable_mm is None:
            (r0, r1), (f0, f1) = self.detectable_mm, self.fits_mm
            return (f"{self.pattern}: its {self.feature}s span {self.min_feature_px:g} px or more only at "
                    f"D = {r0:.0f}–{r1:.0f} mm, the whole print fits the view only at D = {f0:.0f}–{f1:.0f} mm: "
                    f"never both (squares of {self.min_square_mm:.3g} mm would be)")
        return None

    def hint(self) -> str:
        """Why a pattern found in no frame may not be, from the rig: a clause for the error message.

        Returns
        -------
        str
            The problem (:meth:`problem`) when the rig cannot show it; else where it is found
            and the question whether the poses were there.
        """
        why = self.problem()
        if why is not None:
            return f"the frames' rig says: {why.split(': ', 1)[1]}"
        lo, hi = self.usable_mm
        if self.feature == "marker bit":
            return (f"the frames' rig says its markers are read at D = {lo:.0f}–{hi:.0f} mm from the object hinge "
                    f"(bit cells ≥ {self.min_feature_px:g} px there): were the poses there?")
        return (f"the frames' rig says it is found held whole in view at D = {lo:.0f}–{hi:.0f} mm from the object "
                f"hinge (its {self.feature}s ≥ {self.min_feature_px:g} px there): were the poses there, each "
                "showing the whole pattern?")


def _resolved(rig: Rig, spec, limits: DetectionLimits, u_px: np.ndarray) -> np.ndarray:
    """Whether a print held in the sheet is resolved at each column (its feature, and a ChArUco's square)."""
    across, down = square_size_px(rig, 1.0, u_px)
    size_mm, _, key = _feature(spec)
    finest = np.minimum(across, down)
    ok = size_mm * finest >= getattr(limits, key)
    return ok & (spec.pitch_mm * finest >= limits.chessboard_min_px) if spec.kind == "charuco" else ok


def pattern_advice(rig: Rig, spec, limits: DetectionLimits = DetectionLimits()) -> PatternAdvice:
    """Where on a rig's sheet a pattern is detectable and wholly in view (module docstring).

    Parameters
    ----------
    rig : Rig
        The instrument as read out (binned: :func:`scheimpflug.model.binning.binned_rig`).
    spec : PatternSpec
        The pattern.
    limits : DetectionLimits, optional
        The detector's needs.

    Returns
    -------
    PatternAdvice
        Sizes in pixels at both ends of the depth range and the ranges of D where the pattern
        is resolved and fits (a print held in the sheet: the camera's most oblique view of it).
    """
    u, d = _depths(rig)
    across, down = square_size_px(rig, 1.0, u)
    size_mm, name, key = _feature(spec)
    need = getattr(limits, key)
    feature = size_mm * np.minimum(across, down)
    resolved = _resolved(rig, spec, limits, u)
    x0, y0, x1, y1 = spec.extent_mm()
    diag = math.hypot(x1 - x0, y1 - y0)
    height = rig.sensor.rows / down
    d_lo, d_hi = float(np.nanmin(d)), float(np.nanmax(d))
    fits = (diag <= limits.fit_fraction * height) & (d >= d_lo + 0.5 * diag) & (d <= d_hi - 0.5 * diag)
    worst = float(np.min(np.minimum(across, down)))
    ratio = spec.pitch_mm / size_mm
    min_sq = max(need / worst * ratio, limits.chessboard_min_px / worst if spec.kind == "charuco" else 0.0)
    ends = [0, -1]
    return PatternAdvice(
        pattern=spec.text, columns=int(rig.sensor.columns), rows=int(rig.sensor.rows),
        depth_mm=(float(d[0]), float(d[-1])),
        square_px=tuple((float(spec.pitch_mm * across[k]), float(spec.pitch_mm * down[k])) for k in ends),
        feature=name, feature_px=tuple(float(feature[k]) for k in ends), min_feature_px=float(need),
        detectable_mm=_interval(d, resolved), fits_mm=_interval(d, fits), min_square_mm=float(min_sq))


def format_pattern_advice(adv: PatternAdvice) -> list[str]:
    """The advice for one pattern as lines of text (``render target`` prints them before rendering).

    Parameters
    ----------
    adv : PatternAdvice
        From :func:`pattern_advice`.

    Returns
    -------
    list of str
        Three lines, without a trailing newline.
    """
    (a0, d0), (a1, d1) = adv.square_px
    lines = [f"pattern {adv.pattern} on this rig ({adv.columns} × {adv.rows} px): a square held in the sheet "
             f"spans {a0:.1f} × {d0:.1f} px (columns × rows) at D = {adv.depth_mm[0]:.0f} mm, "
             f"{a1:.1f} × {d1:.1f} px at D = {adv.depth_mm[1]:.0f} mm"]
    if adv.detectable_mm is None:
        lines.append(f"  not found anywhere: its {adv.feature}s span at most {max(adv.feature_px):.1f} px, OpenCV's "
                     f"detector needs {adv.min_feature_px:g} px (squares of {adv.min_square_mm:.3g} mm or more "
                     "would be found over the whole depth range)")
    else:
        lo, hi = adv.detectable_mm
        whole = (lo, hi) == tuple(sorted(adv.depth_mm))
        where = "over the whole depth range" if whole else f"at D = {lo:.0f}–{hi:.0f} mm"
        lines.append(f"  found (in the frames rectified by the rig's homographies) where its {adv.feature}s span "
                     f"≥ {adv.min_feature_px:g} px: {where}; squares of {adv.min_square_mm:.3g} mm or more are found "
                     "over the whole depth range")
    if adv.fits_mm is None:
        lines.append("  the whole print fits the view at no distance: print fewer or smaller squares")
    else:
        lo, hi = adv.fits_mm
        lines.append(f"  the whole print fits the view, turned any way in its plane, at D = {lo:.0f}–{hi:.0f} mm "
                     f"(render target --depth-range-mm {lo:.0f}:{hi:.0f})"
                     + ("; a chessboard is found only whole" if adv.pattern.startswith("chessboard") else ""))
    return lines


def largest_chessboard(rig: Rig, square_mm: float, limits: DetectionLimits = DetectionLimits()) -> str | None:
    """The largest 4:3 chessboard of a square size a rig finds whole in view, as a pattern spec.

    Where its squares are resolved (:func:`pattern_advice`'s rule: at least ``chessboard_min_px``
    along both image axes), at the middle of that range of distances, its diagonal at most
    ``fit_fraction`` of the height in view (any in-plane turn stays within the rows): 0.8 and
    0.6 of that diagonal in squares along and across the sheet, less one for inner corners, and
    printable on an A4 sheet (:data:`A4_PRINT_MM`).

    Parameters
    ----------
    rig : Rig
        The instrument as read out (binned: :func:`scheimpflug.model.binning.binned_rig`).
    square_mm : float
        The square's side [mm].
    limits : DetectionLimits, optional
        The detector's needs.

    Returns
    -------
    str or None
        ``chessboard:COLSxROWS:SQUARE`` (inner corners), or None when the squares are resolved
        nowhere or no board of 3 × 3 squares fits.
    """
    g = hinge_geometry(rig)
    u, d = _depths(rig)
    across, down = square_size_px(rig, square_mm, u)
    ok = np.minimum(across, down) >= limits.chessboard_min_px
    if not ok.any():
        return None
    mid = 0.5 * (d[ok].min() + d[ok].max())
    height = rig.sensor.rows * float(g.height_resolution(g.column_from_distance(mid)))
    diag = limits.fit_fraction * height
    cols = int(min(0.8 * diag, A4_PRINT_MM[0]) // square_mm) - 1
    rows = int(min(0.6 * diag, A4_PRINT_MM[1]) // square_mm) - 1
    return f"chessboard:{cols}x{rows}:{square_mm:g}" if min(cols, rows) >= 2 else None


def square_advice(rig: Rig, binnings=(1, 2, 4), squares_mm=(8.0, 15.0),
                  limits: DetectionLimits = DetectionLimits()) -> dict:
    """The patterns a rig can detect at each binning: smallest squares, largest boards (``design``).

    Parameters
    ----------
    rig : Rig
        The instrument at full resolution.
    binnings : sequence of int, default (1, 2, 4)
        Read-outs (:func:`scheimpflug.model.binning.binned_rig`).
    squares_mm : sequence of float, default (8, 15)
        Square sizes for which the largest chessboard is given [mm].
    limits : DetectionLimits, optional
        The detector's needs.

    Returns
    -------
    dict
        ``depth_mm`` [near, far]; ``binnings``: one dict per read-out with ``binning``,
        ``px_per_mm_across`` and ``px_per_mm_down`` [near, far] (a print in the sheet),
        ``chessboard_square_mm`` [over the whole depth range, at its near end],
        ``charuco_marker_mm`` (a 4 × 4 marker's bit cell resolved over the whole range) and
        ``circles_diameter_mm`` (the same) [mm], ``largest_chessboard`` {square [mm]: spec or None}
        (:func:`largest_chessboard`).
    """
    from scheimpflug.model.binning import binned_rig

    u = np.array([0.0, rig.sensor.columns - 1.0])
    out = {"depth_mm": [float(x) for x in hinge_geometry(rig).distance_from_column(u)], "binnings": []}
    for k in binnings:
        try:
            r = binned_rig(rig, int(k))
        except ValueError:
            continue
        across, down = square_size_px(r, 1.0, np.array([0.0, r.sensor.columns - 1.0]))
        worst = np.minimum(across, down)
        out["binnings"].append({
            "binning": int(k), "px_per_mm_across": across.tolist(), "px_per_mm_down": down.tolist(),
            "chessboard_square_mm": [float(limits.chessboard_min_px / worst.min()),
                                     float(limits.chessboard_min_px / worst.max())],
            "charuco_marker_mm": float(6 * limits.charuco_cell_min_px / worst.min()),
            "circles_diameter_mm": float(limits.circles_min_px / worst.min()),
            "largest_chessboard": {f"{s:g}": largest_chessboard(r, s, limits) for s in squares_mm}})
    return out


def format_square_advice(adv: dict) -> list[str]:
    """:func:`square_advice` as lines of text (``design`` prints them).

    Parameters
    ----------
    adv : dict
        From :func:`square_advice`.

    Returns
    -------
    list of str
        A heading and three lines per binning.
    """
    near, far = adv["depth_mm"]
    lines = [f"  printed patterns  a print held in the sheet, D = {near:.0f} … {far:.0f} mm, found by OpenCV's "
             "detectors in the frames rectified by the rig's homographies"]
    for b in adv["binnings"]:
        (a0, a1), (d0, d1) = b["px_per_mm_across"], b["px_per_mm_down"]
        every, near_only = b["chessboard_square_mm"]
        boards = ", ".join(v or f"none of {k} mm squares" for k, v in b["largest_chessboard"].items())
        lines += [f"    binning {b['binning']}: 1 mm spans {a0:.2f} … {a1:.2f} px across the columns, "
                  f"{d0:.2f} … {d1:.2f} px down the rows (near … far end)",
                  f"               found over the whole depth range: chessboard squares ≥ {every:.3g} mm "
                  f"({near_only:.2g} mm at the near end), ChArUco 4 × 4 markers ≥ {b['charuco_marker_mm']:.3g} mm, "
                  "circle dots ≥ "
                  f"{b['circles_diameter_mm']:.3g} mm",
                  f"               largest chessboard whole in view (turned any way) where found: {boards}"]
    return lines
