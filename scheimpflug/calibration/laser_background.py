"""A laser frame's background: the same view with the laser off, and the board the line may fall on.

Users calibrate a laser-line scanner where it stands, with the room lit.  Each pose of
the pattern is then photographed twice with the same camera settings: with the laser
off (the pattern lit by the room: the *flood* frame of a pattern set) and with it on.
On a white, lit board the laser line is only the difference of the two — the red
channel is near its top with or without the laser — so the laser-off frame is the
laser frame's background: subtracted, the line stands alone (Horus/Ciclop and
FabScanPi take such pairs and subtract them).

Whether two frames were taken under the same light
    is told by their difference ``D = L − F`` where the laser-off frame shows the scene
    lit (its local level above ``LIT_FRACTION`` of its 99th percentile: in a dark room
    the unlit rest of two frames agrees whatever the light on the board).  Under the
    same light and exposure ``D`` holds noise and the laser (its line, its glow and
    speckle where its light scatters about the room), none of it the print; under
    another exposure, another light or a board moved between the shots the print shows
    in ``D``.  So (:func:`same_light`):

    * the print's share of the difference, ``c = <D', F'> / <F', F'>`` over the lit
      pixels (``X'`` the high-pass ``X − box(X, 31 px)``, the brightest 2 % of ``D`` —
      the line — left out), lies within ``±GAIN_TOLERANCE``: a laser-off frame at another
      exposure gives ``c`` = the gain ratio − 1 (−1 for a dark room's laser frame beside
      a flood-lit one), a moved board ≈ −0.6, a camera whose automatic exposure dims
      by 10–14 % with the laser on (Horus's own Logitech C270 frames) −0.10 … −0.14;
    * the median of ``D`` does not fall below ``−LEVEL_FACTOR`` × the noise, nor below
      ``−LEVEL_FRACTION`` of the laser-off frame's median level there: a laser-off frame
      brighter than its laser frame would wipe the line out.

    Each frame's noise is estimated from its own pixels: the robust spread (1.4826 ×
    the median absolute deviation) of its second differences along the rows over √6
    (white noise of σ gives second differences of σ·√6; the median leaves the pattern's
    edges out), and at least the quantisation's 1/√12 DN.

The line's points
    are the stripe's centres (:func:`scheimpflug.stripe.extract_stripes`) whose peak
    stands ``LINE_SIGMAS`` × the image's noise above its local background
    (:func:`line_points`): where the line is faint — on a black square — a row's highest
    noise peak would otherwise be taken for it.  The noise of a difference is both
    frames' together and grows with the light (shot noise: a white square is noisier
    than a black one), so it is taken at each point from the difference's own
    photon-transfer curve (:func:`difference_noise`).

What the laser-off frame shows too
    is not the laser.  Without a subtraction (``--laser-background none``, or a pose
    whose laser-off frame was taken under other light) a lit board's print — the middle
    of a white square between black ones, row after row — can pass for a line; a laser
    frame whose line points are mostly where its laser-off frame has them too
    (:func:`shared_fraction` above ``SHARED_FRACTION``) holds no laser line that can be
    found that way.

The board
    The line's points count only where they fall on the printed pattern: the
    pattern's printed area, projected into the frame by the pose the flood frame gave
    (:func:`board_mask`), bounds the search before the stripe is found (:func:`within_board`), so that the
    line on the floor, a cabinet or a reflection beside the board cannot take a row's
    or a column's peak.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from scheimpflug.stripe import extract_stripes, image_pixels, oriented

__all__ = [
    "BACKGROUND_MODES",
    "LINE_SIGMAS",
    "QUANTISATION_DN",
    "LightMatch",
    "board_mask",
    "difference_noise",
    "frame_noise_dn",
    "line_points",
    "local_level",
    "noise_map",
    "same_light",
    "shared_fraction",
    "subtract_background",
    "within_board",
]

#: ``calibrate --laser-background``: the pose's laser-off frame subtracted when the light agrees (auto),
#: always (pose), or never (none).
BACKGROUND_MODES = ("auto", "pose", "none")
#: The print's share of a difference two frames of one light may hold (module docstring) [-]: subtracted,
#: a laser-off frame this far off leaves a quarter of the print's contrast, against all of it unsubtracted.
GAIN_TOLERANCE = 0.25
#: The difference's median may fall this many noise σ below zero [-] …
LEVEL_FACTOR = 3.0
#: … or this fraction of the laser-off frame's median level, whichever is larger [-].
LEVEL_FRACTION = 0.02
#: A stripe point's peak must stand this many noise σ above its background: a row of 1000 pixels of
#: Gaussian noise peaks at ≈ 3.3 σ, so 6 σ leaves the noise out and keeps a line of a few DN [-].
LINE_SIGMAS = 6.0
#: A laser frame's line point and its laser-off frame's are the same place within this distance [px].
SHARED_TOL_PX = 1.5
#: A laser frame whose line points are more than this fraction where its laser-off frame has them too
#: shows the scene, not the laser: ≤ 0.5 % in the twin's dark pattern sets, 32–78 % in a room-lit set
#: found without its laser-off frames (benchmarks/RESULTS.md) [-].
SHARED_FRACTION = 0.2
#: The frames are compared where the laser-off frame's level exceeds this fraction of its 99th percentile:
#: a board lit in a dark room covers a small part of the frame, whose dark rest would agree anyway [-].
LIT_FRACTION = 0.1
#: Side of the box filter whose output is a pixel's level for its noise (:func:`difference_noise`) [px].
LEVEL_PX = 5
#: Side of the box filter whose output is a frame's smooth part, left out of the print's share [px].
SMOOTH_PX = 31
#: The quantisation's own noise, the least a frame of whole DN has [DN].
QUANTISATION_DN = 1.0 / math.sqrt(12.0)


def _robust_sigma(x: np.ndarray) -> float:
    return 1.4826 * float(np.median(np.abs(x - np.median(x)))) if x.size else 0.0


def frame_noise_dn(frame) -> float:
    """The per-pixel noise of a frame from its own pixels (module docstring) [DN].

    Parameters
    ----------
    frame : (rows, columns) array_like
        The frame [DN].

    Returns
    -------
    float
        σ [DN]: the robust spread of the second differences along the rows over √6, at least
        :data:`QUANTISATION_DN`.

    Raises
    ------
    ValueError
        Not a 2-D frame of at least 3 columns.
    """
    f = np.asarray(frame, np.float64)
    if f.ndim != 2 or f.shape[1] < 3:
        raise ValueError(f"a frame must be 2-D with at least 3 columns, got shape {f.shape}")
    return max(_robust_sigma(f[:, :-2] - 2.0 * f[:, 1:-1] + f[:, 2:]) / math.sqrt(6.0), QUANTISATION_DN)


@dataclass(frozen=True)
class LightMatch:
    """Whether a laser frame and a laser-off frame were taken under the same light (:func:`same_light`).

    Parameters
    ----------
    agree : bool
        The laser-off frame can be the laser frame's background.
    gain : float
        The print's share of the difference ``c`` (module docstring) [-].
    tolerance : float
        How far it may lie from 0 [-].
    level_dn : float
        Median of the difference ``laser − laser-off`` [DN].
    floor_dn : float
        How far below zero the median may fall [DN] (negative).
    noise_dn : float
        The two frames' noise together, √(σ_L² + σ_F²) [DN].
    """

    agree: bool
    gain: float
    tolerance: float
    level_dn: float
    floor_dn: float
    noise_dn: float

    def reason(self) -> str:
        """Why the frames do or do not agree, in one phrase.

        Returns
        -------
        str
            The figures compared.
        """
        if self.level_dn < self.floor_dn:
            return (f"the laser-off frame is brighter (median difference {self.level_dn:.3g} DN, below "
                    f"{self.floor_dn:.3g}): another exposure or light")
        verdict = "within" if abs(self.gain) <= self.tolerance else "beyond"
        return (f"the print shows in their difference at {100 * self.gain:+.0f} % of its contrast, {verdict} "
                f"±{100 * self.tolerance:.0f} %")


def _pair(laser, laser_off, dtype=np.float64) -> tuple[np.ndarray, np.ndarray]:
    """A laser frame and its laser-off frame as arrays of one shape (``dtype`` None: as they are).

    Raises
    ------
    ValueError
        Shapes that differ, naming both.
    """
    a, b = np.asarray(laser, dtype), np.asarray(laser_off, dtype)
    if a.shape != b.shape:
        raise ValueError(f"the laser frame is {a.shape}, the laser-off frame {b.shape}")
    return a, b


def same_light(laser, laser_off) -> LightMatch:
    """Whether ``laser_off`` is ``laser``'s view under the same light, the laser off (module docstring).

    Parameters
    ----------
    laser, laser_off : (rows, columns) array_like
        The laser frame and the candidate laser-off frame [DN].

    Returns
    -------
    LightMatch
        The verdict and its figures.

    Raises
    ------
    ValueError
        Frames of different shapes.
    """
    a, b = _pair(laser, laser_off)
    lit = _lit(b)
    noise = math.hypot(_noise_where(a, lit), _noise_where(b, lit))
    d = a - b
    gain = _print_share(d, b, lit)
    level = float(np.median(d[lit]))
    floor = -max(LEVEL_FACTOR * noise, LEVEL_FRACTION * float(np.median(b[lit])))
    agree = abs(gain) <= GAIN_TOLERANCE and level >= floor
    return LightMatch(bool(agree), gain, GAIN_TOLERANCE, level, floor, noise)


def _print_share(d: np.ndarray, off: np.ndarray, lit: np.ndarray) -> float:
    """``<D', F'> / <F', F'>`` over the lit pixels, the line (the brightest 2 % of D) left out."""
    def high(x):
        return (x - cv2.blur(x, (SMOOTH_PX, SMOOTH_PX), borderType=cv2.BORDER_REFLECT))[lit]

    dh, fh = high(d), high(off)
    keep = d[lit] < np.percentile(d[lit], 98)
    denom = float(fh[keep] @ fh[keep])
    return float(dh[keep] @ fh[keep]) / denom if denom > 0 else 0.0


def _lit(frame: np.ndarray) -> np.ndarray:
    """Where the laser-off frame shows the scene lit: what the two frames are compared on.

    Its level above ``LIT_FRACTION`` of its 99th percentile and 5 σ of its noise; all of it
    when too little is lit to say (under 1 %).
    """
    level = local_level(frame)
    lit = level > max(LIT_FRACTION * float(np.percentile(level, 99)), 5.0 * frame_noise_dn(frame))
    return lit if lit.mean() >= 0.01 else np.ones(frame.shape, bool)


def _noise_where(frame: np.ndarray, where: np.ndarray) -> float:
    """:func:`frame_noise_dn` over the pixels ``where`` (the second differences centred there)."""
    d2 = frame[:, :-2] - 2.0 * frame[:, 1:-1] + frame[:, 2:]
    return max(_robust_sigma(d2[where[:, 1:-1]]) / math.sqrt(6.0), QUANTISATION_DN)


def subtract_background(frame, background) -> np.ndarray:
    """``frame − background``, clipped at 0 (float64) [DN].

    Parameters
    ----------
    frame, background : (rows, columns) array_like
        The laser frame and its laser-off frame [DN].

    Returns
    -------
    (rows, columns) float64
        The difference [DN].

    Raises
    ------
    ValueError
        Frames of different shapes.
    """
    a, b = _pair(frame, background)
    return np.clip(a - b, 0.0, None)


def board_mask(outline_px, shape: tuple[int, int]) -> np.ndarray:
    """Pixels inside the board's outline in the image.

    Parameters
    ----------
    outline_px : (n, 2) array_like float
        The outline's vertices (u, v) in order [px]; non-finite vertices are dropped.
    shape : (int, int)
        The frame's (rows, columns).

    Returns
    -------
    (rows, columns) bool
        True inside (an outline of fewer than 3 finite vertices: nothing).
    """
    pts = np.asarray(outline_px, np.float64).reshape(-1, 2)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    mask = np.zeros(shape, np.uint8)
    if len(pts) >= 3:
        lim = 4.0 * max(shape)
        poly = np.clip(np.rint(pts * 16.0), -lim * 16, lim * 16).astype(np.int32)
        cv2.fillPoly(mask, [poly], 1, lineType=cv2.LINE_8, shift=4)
    return mask.astype(bool)


def line_points(image, noise_dn, *, along: str = "columns", detector: str = "cog",
                saturation_dn: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The laser line's points in a (background-subtracted) laser image, one per row or column.

    Parameters
    ----------
    image : (rows, columns) array_like
        The laser frame, its laser-off frame subtracted where there is one [DN].
    noise_dn : float or (rows, columns) array_like
        The image's per-pixel noise [DN]: one σ for the frame (:func:`frame_noise_dn`) or a map
        of it (a difference's: :func:`difference_noise`), taken where each point's peak is.
    along : {"columns", "rows"}, default "columns"
        Which way the line runs in the image (:func:`scheimpflug.stripe.oriented`).
    detector : str, default "cog"
        Stripe centre method (:func:`scheimpflug.stripe.extract_stripes`).
    saturation_dn : float, optional
        Saturation level of the laser frame [DN]: saturated peaks are left out.

    Returns
    -------
    u_px, v_px : (n,) ndarray float64
        The points whose peak stands at least ``LINE_SIGMAS`` × ``noise_dn`` above the
        local background [px].

    Raises
    ------
    ValueError
        ``along`` neither "rows" nor "columns"; a negative or non-finite ``noise_dn``, or a map of
        another shape than the image.
    """
    img = np.asarray(image)
    noise = np.asarray(noise_dn, np.float64)
    if noise.ndim not in (0, 2) or (noise.ndim == 2 and noise.shape != img.shape):
        raise ValueError(f"noise_dn must be one number or a map of the image's shape {img.shape}, got {noise.shape}")
    if not (np.all(np.isfinite(noise)) and np.all(noise >= 0)):
        raise ValueError("noise_dn must be finite and >= 0")
    prof = extract_stripes(oriented(img, along), detector, saturation_dn=saturation_dn, window_px="auto")
    u, v = image_pixels(prof.rows, prof.u, along)
    if noise.ndim == 2:
        col = np.clip(np.rint(u), 0, img.shape[1] - 1).astype(np.int64)
        noise = noise[np.clip(np.rint(v), 0, img.shape[0] - 1).astype(np.int64), col]
    keep = ~prof.saturated & (prof.peak >= LINE_SIGMAS * noise)
    return u[keep], v[keep]


def difference_noise(laser, laser_off, bins: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """The noise of ``laser − laser_off`` against the laser-off frame's level (a photon-transfer curve).

    A camera's noise grows with the signal (shot noise): on a lit board the white squares are
    noisier than the black ones and than the dark room around, so one σ for the frame lets the
    white squares' noise pass for a faint line.  The difference of two frames of one view is
    that noise alone off the line; its robust spread (1.4826 × the median absolute deviation,
    which the line's few pixels do not move) in bins of the level gives σ at each level.  The
    level is the laser-off frame smoothed over ``LEVEL_PX`` × ``LEVEL_PX`` pixels
    (:func:`local_level`): binned by its own noisy value, a bin would hold the pixels whose
    noise happened to fall there and the difference's spread would come out as one frame's,
    not two frames'.

    Parameters
    ----------
    laser, laser_off : (rows, columns) array_like
        The laser frame and its laser-off frame, taken under the same light [DN].
    bins : int, default 16
        Level bins (quantiles of the laser-off frame; fewer where its levels repeat).

    Returns
    -------
    levels_dn, sigma_dn : (m,) ndarray float64
        Each bin's median level and the difference's σ there (at least √2 × the quantisation's)
        [DN]; :func:`noise_map` makes the map of it.

    Raises
    ------
    ValueError
        Frames of different shapes, fewer than 2 bins.
    """
    a, b = _pair(laser, laser_off)
    if bins < 2:
        raise ValueError(f"bins must be >= 2, got {bins}")
    d, level = (a - b).ravel(), local_level(b).ravel()
    edges = np.unique(np.quantile(level, np.linspace(0.0, 1.0, bins + 1)))
    which = np.clip(np.searchsorted(edges, level, side="right") - 1, 0, max(len(edges) - 2, 0))
    levels, sigmas = [], []
    for k in range(max(len(edges) - 1, 1)):
        sel = which == k
        if sel.sum() >= 64:
            levels.append(float(np.median(level[sel])))
            sigmas.append(_robust_sigma(d[sel]))
    if not levels:
        levels, sigmas = [float(np.median(level))], [_robust_sigma(d)]
    floor = math.sqrt(2.0) * QUANTISATION_DN
    return np.array(levels), np.maximum(np.array(sigmas), floor)


def shared_fraction(laser, laser_off, *, along: str = "columns", detector: str = "cog",
                    saturation_dn: float | None = None, tol_px: float = SHARED_TOL_PX) -> float:
    """The fraction of a laser frame's line points that its laser-off frame shows too.

    What a laser frame shows at the same place as the same view with the laser off is the scene —
    the pattern's print, a lit edge — not the laser: a frame whose line points are mostly such
    holds no laser line that can be found without subtracting its laser-off frame.

    Parameters
    ----------
    laser, laser_off : (rows, columns) array_like
        The laser frame and the same view with the laser off (any exposure) [DN].
    along : {"columns", "rows"}, default "columns"
        Which way the line runs in the image.
    detector : str, default "cog"
        Stripe centre method.
    saturation_dn : float, optional
        Saturation level [DN].
    tol_px : float
        Two points of one row (or column) within this distance are the same place [px].

    Returns
    -------
    float
        In [0, 1]; 0 when the laser frame shows no line point.

    Raises
    ------
    ValueError
        Frames of different shapes, a bad ``along``.
    """
    a, b = _pair(laser, laser_off, None)
    mine = line_points(a, frame_noise_dn(a), along=along, detector=detector, saturation_dn=saturation_dn)
    theirs = line_points(b, frame_noise_dn(b), along=along, detector=detector, saturation_dn=saturation_dn)
    line, across = (1, 0) if along == "columns" else (0, 1)
    if len(mine[0]) == 0:
        return 0.0
    where = dict(zip(np.rint(theirs[line]).astype(np.int64).tolist(), theirs[across].tolist()))
    near = [abs(where.get(k, np.inf) - x) <= tol_px for k, x in zip(np.rint(mine[line]).astype(np.int64).tolist(),
                                                                    mine[across].tolist())]
    return float(np.mean(near))


def within_board(image, mask, along: str = "columns") -> np.ndarray:
    """The image where the board is, its edge values carried outward along each search line.

    A stripe is searched along each row (``along`` "columns") or each column ("rows").  Setting
    the pixels off the board to 0 would make a step at the board's edge that the search could
    take for a stripe; here each search line holds, off the board, the board's value at its
    nearer edge, so nothing off the board can stand out.  Search lines that miss the board
    are 0.

    Parameters
    ----------
    image : (rows, columns) array_like
        The (background-subtracted) laser image [DN].
    mask : (rows, columns) bool
        The board (:func:`board_mask`).
    along : {"columns", "rows"}, default "columns"
        Which way the line runs (the search runs across it).

    Returns
    -------
    (rows, columns) float64
        The image.

    Raises
    ------
    ValueError
        Shapes that differ, a bad ``along``.
    """
    img, m = np.asarray(image, np.float64), np.asarray(mask, bool)
    if img.shape != m.shape:
        raise ValueError(f"the image is {img.shape}, the mask {m.shape}")
    if along not in ("columns", "rows"):
        raise ValueError(f"along must be 'columns' or 'rows', got {along!r}")
    if along == "rows":
        return within_board(img.T, m.T).T
    n = img.shape[1]
    hit = m.any(axis=1)
    first = np.argmax(m, axis=1)
    last = n - 1 - np.argmax(m[:, ::-1], axis=1)
    j = np.clip(np.arange(n)[None, :], first[:, None], last[:, None])
    out = np.take_along_axis(img, j, axis=1)
    out[~hit] = 0.0
    return out


def local_level(frame) -> np.ndarray:
    """A frame's level without its noise: its mean over ``LEVEL_PX`` × ``LEVEL_PX`` pixels [DN].

    Parameters
    ----------
    frame : (rows, columns) array_like
        The frame [DN].

    Returns
    -------
    (rows, columns) float64
        The smoothed frame [DN].
    """
    return cv2.blur(np.asarray(frame, np.float64), (LEVEL_PX, LEVEL_PX), borderType=cv2.BORDER_REFLECT)


def noise_map(laser_off, table) -> np.ndarray:
    """The noise of a difference at each pixel, from its laser-off frame and :func:`difference_noise`.

    Parameters
    ----------
    laser_off : (rows, columns) array_like
        The laser-off frame [DN].
    table : (levels_dn, sigma_dn)
        :func:`difference_noise`'s result.

    Returns
    -------
    (rows, columns) float64
        σ [DN].
    """
    levels, sigmas = table
    return np.interp(local_level(laser_off), levels, sigmas)
