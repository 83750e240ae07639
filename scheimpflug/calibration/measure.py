"""Measuring one calibration frame: plate endpoints, pattern corners, laser points on a pattern.

A plate frame (the paper's calibration, :mod:`scheimpflug.calibration.paper`)
shows one vertical stripe on the plate's face: :func:`measure_plate_frame`
gives its line ``u = a + b v`` (stripe centres with iterative MAD rejection)
and the sub-pixel rows where it ends at the plate's two edges (a band beside
the stripe falling to 50 % between its plateau and the background).
:func:`double_stripe_rows` and :func:`frame_diagnosis` say what in a frame may
bias its stripe (a reflection, a background gradient, a hot column).
:class:`CalibrationTolerances` holds every threshold of the measurement and of
the paper's fits, one reason each.

The stripe centre is measured with a centre detector, not the paper's
light-bar edge: an edge sits ``σ·sqrt(2 ln 2)`` beyond the centre, an offset
that varies with the stripe width across the sensor and biases ``u_h``
(``detector="edge"`` measures that edge sub-pixel).  ``detector="paper"`` measures a
plate frame as the paper did, in whole pixels (its positions are pixel indices:
the first endpoint at ``px = 97``): the light bar's right boundary at half
maximum (the red line of its Fig. 3a), the bar's first and last rows at half its
peak as the endpoints, and one column per frame, the red pixel of the bar's middle
row, for F²; with ``method="paper"`` it reproduces the paper's processing, so the
twin's frames can be measured as the paper measured its own.  The default is the windowed
centre of gravity (``cog``, ±(⌈3σ⌉ + 1) px, at least ±3, σ the frame's stripe width:
``window_px="auto"`` of :func:`scheimpflug.stripe.extract_stripes`; a fixed
±7 px window cuts wide stripes' tails and adds the noise of 14 background
pixels to narrow ones): every row of a plate frame sees the stripe
at the same sub-pixel phase, so a detector's phase-dependent bias does not
average out over rows; on noisy 2 px-wide stripes the 3-point Gaussian's
(noise-induced, log-nonlinearity) bias reaches 0.02 px per frame and moves
``d0`` by ≈ 0.1 mm, the centre of gravity's stays below 0.003 px.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy import optimize, special
from scipy.ndimage import uniform_filter1d

from scheimpflug.calibration.detectability import lattice_views
from scheimpflug.calibration.pattern import aruco_dictionary, charuco_board, charuco_layout
from scheimpflug.errors import CalibrationError
from scheimpflug.stripe import extract_stripes, image_pixels, oriented, saturated_fraction

__all__ = [
    "MAX_WINDOW_PX",
    "MIN_WINDOW_PX",
    "WINDOW_FRACTION",
    "CalibrationTolerances",
    "PatternDetection",
    "PlateMeasurement",
    "check_plate_orientation",
    "corner_windows_px",
    "detect_pattern",
    "double_stripe_rows",
    "frame_diagnosis",
    "measure_plate_frame",
    "MODEL_PATCH_STEPS",
    "refine_corners",
    "refine_corners_model",
    "stripe_points",
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
    recommended_frames : int, default 6
        Fewer usable frames give a warning: the refined fit has three unknowns
        (u_h, F², d0), so with 3 frames it is exactly determined (no σ) and with
        4–5 its σ rests on one or two degrees of freedom [-].
    fit_outlier_ratio : float, default 10.0
        A frame whose column the distance fit u = u_h + F²/(s − d0) of the
        other frames misses by more than this many times their robust residual
        σ … [-]
    fit_outlier_floor_px : float, default 0.1
        … and by more than this floor is an outlier (a wrong stage position):
        left out and named (≥ 6 frames) [px].
    stage_order_px : float, default 0.5
        Sorted by stage position, a stripe may step back by at most this much,
        and frames at one position may differ by at most this much [px].
    second_peak_ratio : float, default 0.5
        A row holds two stripes when a second, separate peak (≥ 3 px away, the
        profile dipping below 60 % of it in between) reaches this fraction of
        the stripe's height above the background [-].
    double_rows_fraction : float, default 0.2
        A frame with two stripes in more than this fraction of its lit rows is
        skipped (a reflection or a second laser line biases its centres) [-].
    gradient_noise_ratio : float, default 20.0
        A background that changes across the frame by more than this many times
        its noise is a gradient (ambient light), named in messages [-].
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
    recommended_frames: int = 6   # fewer usable frames: warn (3 unknowns in the refined fit) [-]
    fit_outlier_ratio: float = 10.0  # leave-one-out miss beyond this many robust σ of the others …
    fit_outlier_floor_px: float = 0.1  # … and beyond this floor: a wrong stage position [px]
    stage_order_px: float = 0.5   # a stripe stepping back (or apart at one s) by more: refused [px]
    second_peak_ratio: float = 0.5  # a second peak this high (of the stripe's) in a row: two stripes [-]
    double_rows_fraction: float = 0.2  # a frame with two stripes in more of its rows is skipped [-]
    gradient_noise_ratio: float = 20.0  # background change across the frame above this × noise [-]



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
    file : str, default ""
        The frame's file (for messages); empty when unknown.
    diagnosis : str, default ""
        What in the frame may bias its stripe (rows with two peaks, a background
        gradient, a constant column: :func:`frame_diagnosis`); named when the
        frame's stage position is questioned.
    """

    stage_mm: float
    u_mean_px: float
    n_rows: int
    line: tuple[float, float]
    top_px: tuple[float, float] | None
    bottom_px: tuple[float, float] | None
    rows: np.ndarray = field(repr=False)
    u: np.ndarray = field(repr=False)
    file: str = ""
    diagnosis: str = ""

    def name(self) -> str:
        """The frame's file, or its stage position when the file is unknown.

        Returns
        -------
        str
            ``file`` or ``"stage s mm"``.
        """
        return self.file or f"stage {self.stage_mm:g} mm"

    def cause(self) -> str:
        """`` — but FILE shows …`` when the frame has a :attr:`diagnosis`, else empty.

        Returns
        -------
        str
            A clause to append to a message that questions the frame's stage position.
        """
        return f" — but {self.name()} shows {self.diagnosis}, which moves its stripe" if self.diagnosis else ""



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
    The crossing is the first row below the level scanning outward from
    ``edge_inset_rows`` inside ``v_end``.  Where that row is already below it —
    dim light beyond the bright face that the stripe detector still counts as
    lit, such as a broken (chamfered) plate edge in a well-exposed frame — the
    scan starts at the plateau's innermost row instead and the crossing is the
    first row below the level whose next row is below it too (a one-row speckle
    dip inside the face is passed over).
    """
    n = frame.shape[0]
    ins, gap, cnt = tol.edge_inset_rows, tol.background_gap_rows, tol.plateau_rows
    inner = v_end - direction * np.arange(ins, ins + cnt)
    outer = v_end + direction * np.arange(gap, gap + cnt)
    if inner.min() < 0 or inner.max() >= n or outer.min() < 0 or outer.max() >= n:
        return None
    plateau = np.median(_band_profile(frame, inner, line, side, tol.band_px))
    bg = np.median(_band_profile(frame, outer, line, side, tol.band_px))
    if plateau <= bg:
        return None
    level = 0.5 * (plateau + bg)
    scan = v_end - direction * ins + direction * np.arange(0, ins + gap + 1)
    prof = _band_profile(frame, scan, line, side, tol.band_px)
    below = np.flatnonzero(prof < level)
    if below.size == 0:
        return None
    if below[0] == 0:
        return _edge_from_plateau(frame, line, v_end, direction, side, tol, level)
    j = below[0]
    frac = (prof[j - 1] - level) / (prof[j - 1] - prof[j])
    return float(scan[j - 1] + direction * frac)


def _edge_from_plateau(frame, line, v_end: int, direction: int, side: int,
                       tol: CalibrationTolerances, level: float) -> float | None:
    """:func:`_edge_row`'s crossing scanned from the plateau's innermost row (its docstring)."""
    ins, gap, cnt = tol.edge_inset_rows, tol.background_gap_rows, tol.plateau_rows
    scan = v_end - direction * (ins + cnt - 1) + direction * np.arange(0, ins + cnt + gap)
    prof = _band_profile(frame, scan, line, side, tol.band_px)
    low = prof < level
    for j in range(1, len(scan) - 1):
        if low[j] and low[j + 1] and not low[j - 1]:
            frac = (prof[j - 1] - level) / (prof[j - 1] - prof[j])
            return float(scan[j - 1] + direction * frac)
    return None


def measure_plate_frame(frame: np.ndarray, stage_mm: float, *, detector: str = "cog",
                        saturation_dn: float | None = None,
                        tol: CalibrationTolerances = CalibrationTolerances(),
                        window_px: int | str = "auto") -> PlateMeasurement:
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
        "paper": the paper's own processing in whole pixels — the light bar's
        right boundary at half maximum, its endpoints the first and last rows of
        the bar at half its peak, the frame's column that of the bar's middle row
        (module docstring).
    saturation_dn : float, optional
        Saturation level [DN]; default the dtype's maximum.
    tol : CalibrationTolerances, optional
        Thresholds; default :class:`CalibrationTolerances`'s.
    window_px : int or "auto", default "auto"
        Detector window (:func:`scheimpflug.stripe.extract_stripes`): "auto"
        widens it beyond 7 px for stripes wider than σ = 7/3 px.

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
    prof = extract_stripes(frame, detector, saturation_dn=saturation_dn, window_px=window_px)
    if len(prof) < tol.min_rows:
        raise CalibrationError(_no_stripe(frame, len(prof), tol.min_rows, saturation_dn))
    v = prof.rows.astype(np.float64)
    keep, line = _robust_line(v, prof.u, tol)
    if keep.sum() < tol.min_rows:
        raise CalibrationError(f"no straight stripe ({int(keep.sum())} rows on a line)")
    if prof.saturated[keep].mean() > 0.5:
        raise CalibrationError("stripe saturated in most rows: lower the exposure")
    double = double_stripe_rows(frame, prof.rows[keep], prof.u[keep], tol.second_peak_ratio)
    if double.sum() > tol.double_rows_fraction * keep.sum():
        raise CalibrationError(f"two stripes: {int(double.sum())} of its {int(keep.sum())} lit rows show a second "
                               "peak of comparable height beside the stripe (a reflection or a second laser "
                               "line): its stripe centres would be biased")
    diagnosis = frame_diagnosis(frame, prof.rows[keep], prof.u[keep], double, tol)
    if detector == "paper":
        return dataclasses.replace(_paper_plate_frame(prof, keep, line, stage_mm, frame.shape[0]),
                                   diagnosis=diagnosis)
    rows_in = prof.rows[keep]
    ends = []
    for v_end, direction, side in ((rows_in.min(), -1, -1), (rows_in.max(), +1, +1)):
        ve = _edge_row(frame, line, int(v_end), direction, side, tol)
        ends.append(None if ve is None else (line[0] + line[1] * ve, ve))
    return PlateMeasurement(stage_mm=float(stage_mm), u_mean_px=float(prof.u[keep].mean()),
                            n_rows=int(keep.sum()), line=line, top_px=ends[0], bottom_px=ends[1],
                            rows=rows_in, u=prof.u[keep], diagnosis=diagnosis)


def double_stripe_rows(frame: np.ndarray, rows: np.ndarray, u_px: np.ndarray, ratio: float = 0.5,
                       half_px: int = 24) -> np.ndarray:
    """Which rows hold a second stripe: a separate peak of comparable height beside the found one.

    The frame is averaged over 9 rows first (a speckle grain is a few rows
    tall, a stripe runs on).  In each row a window of ``±half_px`` columns is
    centred on the brightest pixel near the found centre; a second local maximum at least 3 columns away
    is a second peak when it rises above the window's median by at least
    ``ratio`` of the brightest pixel's height and by 8 × the row's noise, and
    the profile between the two dips below 60 % of it.  A second *stripe* (a
    reflection, a second laser line) keeps its distance from the first along
    the rows; the grains of a wide speckled stripe make second peaks at any
    distance: only rows whose second peak lies within ±1 px of the frame's most
    common distance count.

    Parameters
    ----------
    frame : (rows, columns) ndarray
        The frame [DN].
    rows : (n,) ndarray int
        The rows where a stripe was found [px].
    u_px : (n,) ndarray float
        Its centre in each of them [px].
    ratio : float, default 0.5
        The second peak's height over the stripe's [-].
    half_px : int, default 24
        Half-width of the window searched [px].

    Returns
    -------
    (n,) ndarray bool
        True for a row with two stripes.
    """
    rows = np.asarray(rows, np.int64)
    if rows.size == 0:
        return np.zeros(0, bool)
    n_cols = frame.shape[1]
    offs = np.arange(-half_px, half_px + 1)
    cols = np.clip(np.rint(np.asarray(u_px)).astype(np.int64)[:, None] + offs, 0, n_cols - 1)
    lo, hi = int(rows.min()), int(rows.max()) + 1
    band = uniform_filter1d(frame[max(lo - 4, 0):hi + 4].astype(np.float32), 9, axis=0, mode="nearest")
    smooth = band[rows - max(lo - 4, 0)]                 # 9 rows averaged: speckle grains fade, stripes stay
    x = np.take_along_axis(smooth, cols, axis=1).astype(np.float64)
    top = cols[np.arange(rows.size), np.argmax(x, axis=1)]
    x = np.take_along_axis(smooth, np.clip(top[:, None] + offs, 0, n_cols - 1), axis=1).astype(np.float64)
    y = x - np.median(x, axis=1, keepdims=True)
    noise = 1.4826 * np.median(np.abs(np.diff(x, axis=1)), axis=1) / math.sqrt(2) + 0.5
    main = y[:, half_px]
    offset = np.zeros(rows.size, np.int64)             # distance of the nearest second peak, 0: none
    for side in (y[:, half_px:], y[:, half_px::-1]):
        lows = np.minimum.accumulate(side, axis=1)
        peak = (side[:, 2:-1] >= side[:, 1:-2]) & (side[:, 2:-1] > side[:, 3:])
        high = side[:, 2:-1] >= np.maximum(ratio * main, 8 * noise)[:, None]
        dip = lows[:, 1:-2] < 0.6 * side[:, 2:-1]
        hit = peak & high & dip & (np.arange(2, side.shape[1] - 1) >= 3)
        j = np.where(hit.any(axis=1), np.argmax(hit, axis=1) + 2, 0)
        offset = np.where((offset == 0) | ((j > 0) & (j < offset)), j, offset)
    if not offset.any():
        return offset > 0
    counts = np.convolve(np.bincount(offset[offset > 0], minlength=half_px + 2), np.ones(3), "same")
    common = int(np.argmax(counts))
    return (offset > 0) & (np.abs(offset - common) <= 1)


def frame_diagnosis(frame: np.ndarray, rows: np.ndarray, u_px: np.ndarray, double: np.ndarray,
                    tol: CalibrationTolerances = CalibrationTolerances()) -> str:
    """What in a plate frame may bias its stripe, in words (empty when nothing is seen).

    Three causes are looked for: rows with two stripes (``double``, from
    :func:`double_stripe_rows`; at least 3 and 2 % of the rows); a background that changes across the frame
    (the 5th percentile of each column over (at least 256 of) the rows, its straight-line change
    from the first to the last column, above ``gradient_noise_ratio`` × its
    scatter); a constant column (the stripe's column bright in every row, beyond
    the plate's edges too — its 5th percentile that much above the columns two
    beside it, its direct neighbours not: one pixel wide, a hot or stuck column,
    not a plate's stripe).

    Parameters
    ----------
    frame : (rows, columns) ndarray
        The frame [DN].
    rows : (n,) ndarray int
        Rows of the stripe [px].
    u_px : (n,) ndarray float
        Its centres [px].
    double : (n,) ndarray bool
        Rows with two stripes.
    tol : CalibrationTolerances
        ``gradient_noise_ratio``.

    Returns
    -------
    str
        E.g. ``"a second stripe in 12 of 140 rows"``; causes joined by "and".
    """
    out = []
    if double.sum() >= max(3, 0.02 * double.size):
        out.append(f"a second stripe in {int(double.sum())} of {double.size} rows (a reflection?)")
    sub = frame[::max(1, frame.shape[0] // 256)]          # ≥ 256 rows suffice for a percentile
    kth = int(0.05 * (sub.shape[0] - 1))
    floor = np.partition(sub, kth, axis=0)[kth].astype(np.float64)
    k = np.arange(floor.size, dtype=np.float64)
    slope, icpt = np.polyfit(k, floor, 1)
    scatter = 1.4826 * float(np.median(np.abs(floor - (slope * k + icpt)))) + 0.5
    across = abs(slope) * (floor.size - 1)
    if across > tol.gradient_noise_ratio * scatter:
        out.append(f"a background gradient ({across:.0f} DN across the frame: ambient light?)")
    u = np.asarray(u_px, np.float64)
    if u.size and 2 <= round(float(np.median(u))) < floor.size - 2:
        c = round(float(np.median(u)))
        lift = floor[c] - max(floor[c - 2], floor[c + 2])
        narrow = max(floor[c - 1], floor[c + 1]) - max(floor[c - 2], floor[c + 2]) < 0.1 * lift
        if lift > tol.gradient_noise_ratio * scatter and narrow:
            out.append(f"a constant column (column {c} bright in every row, beyond the plate too: a hot or "
                       "stuck column?)")
    return " and ".join(out)


def _paper_plate_frame(prof, keep: np.ndarray, line, stage_mm: float, n_rows: int) -> PlateMeasurement:
    """The paper's own measurement of a plate frame (Section 3, Fig. 3), in whole pixels.

    The light bar is the rows (on the stripe's line) whose peak reaches half the
    bar's median peak; the red line is each row's right boundary at half maximum
    (``prof``: method "paper", whole pixels); its endpoints are the bar's first and
    last rows with their red pixels (None where the bar touches the frame's border);
    the frame's one column ``px(M')`` is the red pixel of the bar's middle row.
    """
    bar = keep & (prof.peak >= 0.5 * np.median(prof.peak[keep]))
    rows, u = prof.rows[bar], prof.u[bar]
    if rows.size == 0:
        raise CalibrationError("no light bar at half its maximum")
    mid = int(np.argmin(np.abs(rows - 0.5 * (rows[0] + rows[-1]))))
    top = (float(u[0]), float(rows[0])) if rows[0] > 0 else None
    bottom = (float(u[-1]), float(rows[-1])) if rows[-1] < n_rows - 1 else None
    return PlateMeasurement(stage_mm=float(stage_mm), u_mean_px=float(u[mid]), n_rows=int(bar.sum()),
                            line=line, top_px=top, bottom_px=bottom, rows=rows, u=u)


# ---------------------------------------------------------------- the fits


def _no_stripe(frame: np.ndarray, n_rows: int, min_rows: int, saturation_dn: float | None) -> str:
    """Why a frame gave too few stripe rows: saturated, or no stripe."""
    sat = saturated_fraction(frame, saturation_dn)
    if sat > 0.5:
        return (f"frame saturated ({100 * sat:.0f} % of the pixels at the saturation level): no stripe "
                "can be found; lower the exposure or the laser power")
    seen = frame_diagnosis(frame, np.zeros(0, np.int64), np.zeros(0), np.zeros(0, bool))
    return f"no stripe ({n_rows} lit rows < {min_rows})" + (f": the frame shows {seen}" if seen else "")




# ---------------------------------------------------------------- pattern corners

#: The sub-pixel window's half-size is this fraction of the corner's shorter square side [-]
#: (module docstring of :func:`refine_corners`): 11–18 px on the 3DScanScience frames (squares
#: 53–89 px), where the notebook's ±11 px reproduces; ±5 px there moves fx by +1.7 px.
WINDOW_FRACTION = 0.2
#: The window's half-size stays in [MIN_WINDOW_PX, MAX_WINDOW_PX] [px].
MIN_WINDOW_PX, MAX_WINDOW_PX = 2, 30
_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 60, 1e-4)


@dataclass(frozen=True)
class PatternDetection:
    """The pattern's corners found in one frame (:func:`detect_pattern`).

    Parameters
    ----------
    ids : (n,) ndarray int64
        Index of each corner in the pattern's grid (:meth:`PatternSpec.corner_ids` order).
    corners_px : (n, 2) ndarray float64
        Their sub-pixel image positions (u, v) [px].
    window_px : (n,) ndarray int64
        Half-size of each corner's sub-pixel window [px] (:func:`refine_corners`).
    file : str, default ""
        The frame's file, for messages.
    """

    ids: np.ndarray
    corners_px: np.ndarray
    window_px: np.ndarray = field(repr=False)
    file: str = ""

    def __len__(self) -> int:
        return len(self.ids)


def _to_uint8(frame: np.ndarray) -> np.ndarray:
    """The frame stretched between its 1st and 99.5th percentile to 8 bits (what OpenCV's detectors take)."""
    x = np.asarray(frame, np.float32)
    lo, hi = np.percentile(x[:: max(1, x.shape[0] // 512), :: max(1, x.shape[1] // 512)], (1.0, 99.5))
    if hi <= lo:
        hi = lo + 1.0
    return np.clip((x - lo) * (255.0 / (hi - lo)), 0, 255).astype(np.uint8)


def _neighbour_spacing(spec, ids: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Each corner's shortest distance to a grid neighbour that was found (NaN when none) [px]."""
    nc, nr = spec.grid_shape
    grid = np.full((nr + 2, nc + 2, 2), np.nan)
    ij = spec.corner_ids()[ids]
    grid[ij[:, 1] + 1, ij[:, 0] + 1] = corners
    out = np.full(len(ids), np.inf)
    for di, dj in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        nb = grid[ij[:, 1] + 1 + dj, ij[:, 0] + 1 + di]
        d = np.linalg.norm(nb - corners, axis=1)
        out = np.fmin(out, np.where(np.isfinite(d), d, np.inf))
    return np.where(np.isfinite(out), out, np.nan)


def corner_windows_px(spec, ids: np.ndarray, corners_px: np.ndarray) -> np.ndarray:
    """The sub-pixel window of each corner by the rule of :func:`refine_corners` [px].

    Parameters
    ----------
    spec : PatternSpec
        The pattern (its grid; for ChArUco the marker's margin in its white squares).
    ids : (n,) array_like int
        Corner indices in the grid.
    corners_px : (n, 2) array_like float
        Their (initial) image positions [px].

    Returns
    -------
    (n,) ndarray int64
        Half-sizes [px]: :data:`WINDOW_FRACTION` × the corner's shortest side to a found neighbour
        (for ChArUco at most 0.8 × the markers' margin in the same units), clamped to
        [:data:`MIN_WINDOW_PX`, :data:`MAX_WINDOW_PX`]; a corner without a found neighbour takes the
        median of the others.
    """
    side = _neighbour_spacing(spec, np.asarray(ids, np.int64), np.asarray(corners_px, np.float64))
    if not np.isfinite(side).any():
        return np.full(len(side), MIN_WINDOW_PX, np.int64)
    side = np.where(np.isfinite(side), side, np.nanmedian(side))
    fraction = WINDOW_FRACTION
    if spec.kind == "charuco":
        margin = 0.5 * (spec.pitch_mm - spec.marker_mm) / spec.pitch_mm
        fraction = min(fraction, 0.8 * margin)
    return np.clip(np.round(fraction * side), MIN_WINDOW_PX, MAX_WINDOW_PX).astype(np.int64)


def refine_corners(image: np.ndarray, corners_px: np.ndarray, windows_px: np.ndarray) -> np.ndarray:
    """Sub-pixel corners by ``cv2.cornerSubPix``, each with its own window.

    The rule (:func:`corner_windows_px`): the window's half-size is a fifth of the
    corner's shorter square side in pixels — it holds the four squares that meet at
    the corner and no other corner or edge (which lie a side away), with room for a
    blurred edge's gradient.  A fixed small window on large squares sees too little of
    the edges (the 3DScanScience frames: ±5 px moves fx by 1.7 px against the ±11 px
    the notebook used, ±9…±17 px agree within 0.3 px); a large one on small squares
    reaches the neighbours.

    Parameters
    ----------
    image : (rows, columns) ndarray
        The frame [DN].
    corners_px : (n, 2) array_like float
        Initial corners [px].
    windows_px : (n,) array_like int
        Half-sizes of their windows [px].

    Returns
    -------
    (n, 2) ndarray float64
        Refined corners [px].
    """
    img = np.asarray(image, np.float32)
    out = np.asarray(corners_px, np.float64).copy()
    w = np.asarray(windows_px, np.int64)
    for size in np.unique(w):
        sel = w == size
        pts = out[sel].astype(np.float32).reshape(-1, 1, 2)
        out[sel] = cv2.cornerSubPix(img, pts, (int(size), int(size)), (-1, -1), _SUBPIX_CRITERIA).reshape(-1, 2)
    return out


#: Half-width of the model fit's patch in grid steps (the neighbouring corners lie 1 step away) [-].
MODEL_PATCH_STEPS = 0.4
_MIN_PATCH_PIXELS = 30


def _grid_axes(spec, ids: np.ndarray, corners: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Image steps of one grid column and one grid row at every corner (the grid's homography's Jacobian)."""
    ij = spec.corner_ids()[ids].astype(np.float64)
    if len(ij) < 4:
        return None
    h, _ = cv2.findHomography(ij, corners, 0)
    if h is None:
        return None
    p = np.c_[ij, np.ones(len(ij))] @ h.T
    w = p[:, 2:3]
    xy = p[:, :2] / w
    return (h[:2, 0][None] - xy * h[2, 0]) / w, (h[:2, 1][None] - xy * h[2, 1]) / w


def _patch(img: np.ndarray, c0: np.ndarray, a: np.ndarray, white_margin: float | None, white_sign: float):
    """Pixels (x, y) and values within ±MODEL_PATCH_STEPS grid steps of a corner; ChArUco's markers left out."""
    rho = MODEL_PATCH_STEPS
    ext = np.abs(a).sum(axis=1) * rho
    x0, x1 = int(np.floor(c0[0] - ext[0])), int(np.ceil(c0[0] + ext[0]))
    y0, y1 = int(np.floor(c0[1] - ext[1])), int(np.ceil(c0[1] + ext[1]))
    if x0 < 0 or y0 < 0 or x1 >= img.shape[1] or y1 >= img.shape[0]:
        return None
    yy, xx = np.mgrid[y0:y1 + 1, x0:x1 + 1]
    xy = np.c_[xx.ravel(), yy.ravel()].astype(np.float64)
    g = (xy - c0) @ np.linalg.inv(a).T
    keep = (np.abs(g) < rho).all(axis=1)
    if white_margin is not None:
        white = np.sign(g[:, 0]) * np.sign(g[:, 1]) == white_sign
        keep &= ~(white & (np.minimum(np.abs(g[:, 0]), np.abs(g[:, 1])) > white_margin))
    if keep.sum() < _MIN_PATCH_PIXELS:
        return None
    return xy[keep], img[yy.ravel()[keep], xx.ravel()[keep]]


def _saddle_terms(xy: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The blurred-corner model's shape e = erf(d1/s)·erf(d2/s) at the pixels and its (n, 5) derivatives in p."""
    d = xy - p[:2]
    n1, n2 = np.array([math.cos(p[2]), math.sin(p[2])]), np.array([math.cos(p[3]), math.sin(p[3])])
    d1, d2 = d @ n1, d @ n2
    s = abs(p[4]) + 0.3
    e1, e2 = special.erf(d1 / s), special.erf(d2 / s)
    g1 = (2.0 / math.sqrt(math.pi)) * np.exp(-(d1 / s) ** 2) / s      # d erf(d1/s) / d d1
    g2 = (2.0 / math.sqrt(math.pi)) * np.exp(-(d2 / s) ** 2) / s
    t1, t2 = g1 * e2, e1 * g2
    ds = -(t1 * d1 + t2 * d2) / s * (1.0 if p[4] >= 0 else -1.0)
    jac = np.column_stack([-(t1 * n1[0] + t2 * n2[0]), -(t1 * n1[1] + t2 * n2[1]),
                           t1 * (d @ np.array([-n1[1], n1[0]])), t2 * (d @ np.array([-n2[1], n2[0]])), ds])
    return e1 * e2, jac


def _fit_saddle(xy: np.ndarray, values: np.ndarray, c0: np.ndarray, a: np.ndarray) -> np.ndarray | None:
    """The corner of the blurred-saddle model fitted to a patch (variable projection), or None.

    The levels (a, b) by linear least squares at each step; the Jacobian is Kaufman's,
    (I − P)·b·∂e/∂p (P the projection on the levels' columns): it gives the exact gradient
    of the projected residual, so the same minimum as finite differences, at a fifth of the
    evaluations.
    """
    last: dict = {}

    def solve(p):
        if last.get("p") is None or not np.array_equal(last["p"], p):     # exact: the same point again
            e, de = _saddle_terms(xy, p)
            q, rr = np.linalg.qr(np.c_[np.ones_like(e), e])       # one factorisation: levels and projection
            qv = q.T @ values
            r = q @ qv - values
            b = qv[1] / rr[1, 1] if abs(rr[1, 1]) > 1e-12 * abs(rr[0, 0]) else 0.0   # 0: e flat, no corner
            dm = b * de
            last.update(p=p.copy(), r=r, jac=dm - q @ (q.T @ dm))
        return last

    angles = [math.atan2(a[1, k], a[0, k]) + 0.5 * math.pi for k in (0, 1)]   # normals of the two edges
    p0 = np.array([c0[0], c0[1], angles[0], angles[1], 2.0])
    sol = optimize.least_squares(lambda p: solve(p)["r"], p0, jac=lambda p: solve(p)["jac"], method="lm",
                                 x_scale=[1.0, 1.0, 0.05, 0.05, 1.0], xtol=1e-10, ftol=1e-12, max_nfev=400)
    side = min(np.hypot(*a[:, 0]), np.hypot(*a[:, 1]))
    c = sol.x[:2]
    return c if sol.success and np.hypot(*(c - c0)) < 0.3 * side else None


def refine_corners_model(image: np.ndarray, spec, ids: np.ndarray, corners_px: np.ndarray) -> np.ndarray:
    """Sub-pixel corners by fitting a blurred corner's model, for blurred (defocused) patterns.

    Near a chessboard corner the image of a print blurred by a point-symmetric spread
    is ``a + b·erf(d₁/s)·erf(d₂/s)`` to first order, ``d₁, d₂`` the distances to the
    two edges through the corner (straight lines under perspective); the model and
    the ideal corner are both symmetric under a half turn about the corner, so the
    fitted corner is unbiased by the blur where ``cv2.cornerSubPix``'s gradient
    condition is not (its window rarely holds the whole blurred edge pair).  The
    patch is ±:data:`MODEL_PATCH_STEPS` grid steps about the corner in the grid's
    local frame (the homography of all corners found); on a ChArUco board the white
    squares' pixels farther than 0.6 × the markers' margin from both edges are left out.
    Fitted: the corner (2), the two edge directions (2), the blur ``s`` (1); the
    levels ``a, b`` by linear least squares at each step.  On the twin's blurred
    paper-rig frames (spot 3–14 px): median error 0.04–0.06 px against the exact
    corners, ``cornerSubPix`` 0.15–0.30 px (benchmarks/RESULTS.md).

    Parameters
    ----------
    image : (rows, columns) ndarray
        The frame [DN].
    spec : PatternSpec
        The pattern.
    ids : (n,) array_like int
        Corner indices in its grid.
    corners_px : (n, 2) array_like float
        Initial corners (within a few pixels) [px].

    Returns
    -------
    (n, 2) ndarray float64
        Refined corners [px]; NaN where the fit fails or moves the corner by more than
        0.3 of the shorter square side (a corner lost in blur or clutter), or with fewer
        than 4 corners (no local grid).
    """
    img = np.asarray(image, np.float64)
    ids = np.asarray(ids, np.int64)
    c0 = np.asarray(corners_px, np.float64)
    out = np.full_like(c0, np.nan)
    axes = _grid_axes(spec, ids, c0)
    if axes is None:
        return out
    margin, square_marker = None, None
    if spec.kind == "charuco":
        margin = 0.6 * 0.5 * (spec.pitch_mm - spec.marker_mm) / spec.pitch_mm
        square_marker = charuco_layout(spec)["square_marker"]
    ij = spec.corner_ids()[ids]
    for k in range(len(ids)):
        a = np.column_stack([axes[0][k], axes[1][k]])
        sign = 0.0 if square_marker is None else (1.0 if square_marker[ij[k, 1] + 1, ij[k, 0] + 1] >= 0 else -1.0)
        patch = _patch(img, c0[k], a, margin, sign)
        if patch is not None:
            c = _fit_saddle(*patch, c0[k], a)
            if c is not None:
                out[k] = c
    return out


def _extends_beyond(gray: np.ndarray, corners: np.ndarray, size: tuple[int, int]) -> bool:
    """Whether the squares go on past a found grid: it is part of a larger board (another spec).

    Through the grid's homography, the centres of the outermost ring of squares (half a step
    outside the outer corners) alternate dark and light; a step further out lies the print's
    margin.  Where that next ring alternates too, with at least half the board's contrast,
    the detector found a sub-board.
    """
    nc, nr = size
    j, i = np.mgrid[0:nr, 0:nc]
    h, _ = cv2.findHomography(np.c_[i.ravel(), j.ravel()].astype(np.float64), corners, 0)
    if h is None:
        return False
    for ring, other in ((np.arange(-1, nc) + 0.5, None), (None, np.arange(-1, nr) + 0.5)):
        for edge in ((-0.5, -1.5), (nr - 0.5, nr + 0.5)) if other is None else ((-0.5, -1.5), (nc - 0.5, nc + 0.5)):
            vals = []
            for pos in edge:
                pts = np.c_[ring, np.full(ring.size, pos)] if other is None else np.c_[np.full(other.size, pos), other]
                q = np.c_[pts, np.ones(len(pts))] @ h.T
                uv = np.rint(q[:, :2] / q[:, 2:]).astype(np.int64)
                if (uv < 0).any() or (uv[:, 0] >= gray.shape[1]).any() or (uv[:, 1] >= gray.shape[0]).any():
                    vals = []
                    break
                vals.append(gray[uv[:, 1], uv[:, 0]].astype(np.float64))
            if len(vals) == 2:
                contrast = np.abs(np.diff(vals[0])).mean()
                if contrast > 0 and np.abs(np.diff(vals[1])).mean() > 0.5 * contrast:
                    return True
    return False


#: Rectified views (after the lattice view) that the slow pass of a chessboard's detector is run on
#: (``cv2.findChessboardCornersSB``, ≈ 0.1–0.3 s a view; the quick pass, the quadrilateral detector
#: with its quick check, ≈ 0.03 s, runs on every view) [-].
SADDLE_VIEWS = 4
#: Seed of OpenCV's global RNG before each chessboard search: ``findChessboardCornersSB`` draws from it,
#: so without a seed its answer for one frame depended on what OpenCV did before in the process.
CHESSBOARD_RNG_SEED = 0x5EED


def _outer_ring_alternates(gray: np.ndarray, corners: np.ndarray, size: tuple[int, int]) -> bool:
    """Whether a found grid sits on the squares: its outermost ring of squares alternates as its inner ones do.

    Through the grid's homography, the centres of the squares between the corners alternate dark and
    light with the board's contrast, and so do those of the outermost ring (half a step outside the
    outer corners) on every side.  A grid OpenCV's quick passes lay across the print at a slant
    (found where a board of another size is seen obliquely) samples that ring half on squares,
    half on their edges: its contrast falls below half the inner squares'.
    """
    nc, nr = size
    j, i = np.mgrid[0:nr, 0:nc]
    h, _ = cv2.findHomography(np.c_[i.ravel(), j.ravel()].astype(np.float64), corners, 0)
    if h is None:
        return False

    def sample(pts):
        q = np.c_[pts, np.ones(len(pts))] @ h.T
        uv = np.rint(q[:, :2] / q[:, 2:]).astype(np.int64)
        inside = (uv[:, 0] >= 0) & (uv[:, 1] >= 0) & (uv[:, 0] < gray.shape[1]) & (uv[:, 1] < gray.shape[0])
        return gray[uv[inside, 1], uv[inside, 0]].astype(np.float64) if inside.all() else None

    inner = [sample(np.c_[np.arange(nc - 1) + 0.5, np.full(nc - 1, r + 0.5)]) for r in range(nr - 1)]
    contrast = np.mean([np.abs(np.diff(v)).mean() for v in inner if v is not None and len(v) > 1] or [0.0])
    rings = [np.c_[np.arange(-1, nc) + 0.5, np.full(nc + 1, pos)] for pos in (-0.5, nr - 0.5)]
    rings += [np.c_[np.full(nr + 1, pos), np.arange(-1, nr) + 0.5] for pos in (-0.5, nc - 0.5)]
    for ring in rings:
        v = sample(ring)
        if v is not None and np.abs(np.diff(v)).mean() < 0.5 * contrast:
            return False
    return contrast > 0


def _chessboard_corners(gray: np.ndarray, spec, mode: str = "full") -> np.ndarray | None:
    """The whole chessboard's inner corners in an 8-bit image (OpenCV's order), or None.

    ``mode`` "full" (the frame itself): ``cv2.findChessboardCornersSB`` (exhaustive, accurate),
    else ``cv2.findChessboardCorners`` (adaptive threshold); "quads" (a rectified view): the
    latter with its quick check only; "saddles" (a rectified view): the former without its
    exhaustive search and accuracy pass.  A grid that goes on past the spec's
    (:func:`_extends_beyond`) is a larger board: None.
    """
    size = spec.grid_shape
    ok, c = False, None
    cv2.setRNGSeed(CHESSBOARD_RNG_SEED)     # the detector draws from OpenCV's global RNG: the same answer always
    if mode in ("full", "saddles"):
        flags = cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY if mode == "full" else 0
        ok, c = cv2.findChessboardCornersSB(gray, size, flags)
    if not ok and mode in ("full", "quads"):
        flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
        ok, c = cv2.findChessboardCorners(gray, size, flags | (cv2.CALIB_CB_FAST_CHECK if mode == "quads" else 0))
    if not ok:
        return None
    c = c.reshape(-1, 2).astype(np.float64)
    return None if _extends_beyond(gray, c, size) else c


def _markers_on_one_board(found: dict, obj: np.ndarray) -> dict:
    """The markers one homography of the board explains (a board of another layout puts them at random).

    The threshold, a third of the median marker side in the image, passes a strongly distorting
    lens and a marker's corner noise; a misread id or a marker of another board lies squares off.
    """
    if len(found) < 4:
        return found
    keys = list(found)
    src = np.concatenate([obj[k] for k in keys])
    dst = np.concatenate([found[k] for k in keys])
    side = float(np.median([np.linalg.norm(found[k][1] - found[k][0]) for k in keys]))
    _, mask = cv2.findHomography(src, dst, cv2.RANSAC, max(2.0, side / 3.0))
    if mask is None:
        return {}
    inlier = mask.ravel().reshape(len(keys), 4).all(axis=1)
    return {k: found[k] for k, ok in zip(keys, inlier) if ok} if inlier.sum() >= 0.5 * len(keys) else {}


def _charuco_corners(gray: np.ndarray, spec) -> tuple[np.ndarray, np.ndarray] | None:
    """ChArUco corners from the markers found (partial boards too): ids and image positions.

    Each inner corner touches two white squares (diagonally); when the markers in
    both were found, their 8 corners give a homography from the pattern frame to the
    image that places the corner for the sub-pixel refinement (a corner with one of
    them missing is left out: extrapolated from farther markers it lands pixels off).
    """
    board = charuco_board(spec)
    detector = cv2.aruco.ArucoDetector(aruco_dictionary(spec), cv2.aruco.DetectorParameters())
    m_corners, m_ids, _ = detector.detectMarkers(gray)
    if m_ids is None or len(m_ids) == 0:
        return None
    obj = np.asarray(board.getObjPoints(), np.float64)[:, :, :2] - spec.pitch_mm   # pattern frame (x, y)
    slot = {int(k): i for i, k in enumerate(np.asarray(board.getIds()).ravel())}
    if sum(int(k) not in slot for k in m_ids.ravel()) >= 2:
        return None                        # markers this board does not hold: another board
    found = {slot[int(k)]: np.asarray(c, np.float64).reshape(4, 2) for k, c in zip(m_ids.ravel(), m_corners)
             if int(k) in slot}
    found = _markers_on_one_board(found, obj)
    if len(found) < 2:
        return None
    centres = {k: obj[k].mean(axis=0) for k in found}
    xy = spec.corners_mm()
    ids, pts = [], []
    for j, p in enumerate(xy):
        near = [k for k, c in centres.items() if np.max(np.abs(c - p)) < 0.75 * spec.pitch_mm]
        if len(near) < 2:            # both markers that touch the corner: no extrapolation
            continue
        src = np.concatenate([obj[k] for k in near])
        dst = np.concatenate([found[k] for k in near])
        h, _ = cv2.findHomography(src, dst, 0)
        if h is None:
            continue
        q = h @ np.array([p[0], p[1], 1.0])
        ids.append(j)
        pts.append(q[:2] / q[2])
    return (np.array(ids, np.int64), np.array(pts, np.float64)) if ids else None


def _consistent_with_grid(spec, ids: np.ndarray, corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The corners a robust grid homography keeps (a misread marker places its corners elsewhere).

    The threshold, a tenth of the median square side, passes the bending of a strongly distorting
    lens across a board and rejects a corner one square (or more) off.
    """
    if len(ids) < 5:
        return ids, corners
    side = _neighbour_spacing(spec, ids, corners)
    tol = max(2.0, 0.1 * float(np.nanmedian(side))) if np.isfinite(side).any() else 2.0
    ij = spec.corner_ids()[ids].astype(np.float64)
    _, mask = cv2.findHomography(ij, corners, cv2.RANSAC, tol)
    keep = mask.ravel().astype(bool) if mask is not None else np.ones(len(ids), bool)
    return ids[keep], corners[keep]


def _find_grid(gray: np.ndarray, spec, mode: str = "full") -> tuple[np.ndarray, np.ndarray] | None:
    """OpenCV's detector of the pattern's kind on one 8-bit image: corner ids and positions, or None.

    ``mode`` is the chessboard's pass (:func:`_chessboard_corners`); the other kinds have one
    detector, run in the "full" and "quads" passes.
    """
    if spec.kind == "chessboard":
        c = _chessboard_corners(gray, spec, mode)
        return None if c is None else (np.arange(len(c), dtype=np.int64), c)
    if mode == "saddles":
        return None
    if spec.kind == "circles":
        ok, c = cv2.findCirclesGrid(gray, spec.grid_shape, flags=cv2.CALIB_CB_SYMMETRIC_GRID)
        if not ok:
            ok, c = cv2.findCirclesGrid(255 - gray, spec.grid_shape, flags=cv2.CALIB_CB_SYMMETRIC_GRID)
        return (np.arange(len(spec.corner_ids())), c.reshape(-1, 2).astype(np.float64)) if ok else None
    return _charuco_corners(gray, spec)


def _inside(corners: np.ndarray, shape) -> np.ndarray:
    """Corners at least 1 px inside the frame's pixel centres (2 px from the far edges)."""
    return ((corners[:, 0] > 1) & (corners[:, 1] > 1) & (corners[:, 0] < shape[1] - 2)
            & (corners[:, 1] < shape[0] - 2))


def _attempts(gray: np.ndarray, spec, views):
    """(view, pass) in the order tried: frame, lattice views, every view's quick pass, the first views' slow one.

    The lattice views (:func:`scheimpflug.calibration.detectability.lattice_views`) are the first
    view (or the frame) corrected by the print's own lattice, three readings of it: tried first
    with the quick pass, the most likely with the slow one too.
    """
    yield None, "full"
    lattice = lattice_views(gray, views[0] if views else None) if spec.kind != "circles" else []
    for view in lattice:
        yield view, "quads"
    for view in lattice[:1]:
        yield view, "saddles"
    for view in views:
        yield view, "quads"
    for view in views[:SADDLE_VIEWS]:
        yield view, "saddles"


def _find_in_views(gray: np.ndarray, spec, views) -> tuple[np.ndarray, np.ndarray] | None:
    """The pattern in the frame, else in the first view that shows it, corners mapped back to the frame.

    A chessboard or circle grid counts where all its corners map inside the frame; a ChArUco
    board is looked for in every view until one shows all its corners, and the view with the
    most corners wins (a partial board in the frame may be whole in a view).
    """
    best, n_all, warped = None, len(spec.corner_ids()), {}
    for view, mode in _attempts(gray, spec, tuple(views)):
        if view is None:
            found = _find_grid(gray, spec, mode)
        else:
            if id(view) not in warped:
                warped[id(view)] = view.warp(gray)
            found = _find_grid(warped[id(view)], spec, mode)
        if found is None:
            continue
        ids, c = found
        if view is not None:
            if spec.kind == "chessboard" and not _outer_ring_alternates(warped[id(view)], c, spec.grid_shape):
                continue            # a grid laid across the print at a slant, not on its squares
            c = view.image_from_view(c)
            if spec.kind == "chessboard" and _extends_beyond(gray, c, spec.grid_shape):
                continue            # a sub-board in the frame itself (the view's margin may have hidden it)
        if spec.kind != "charuco":
            if spec.kind == "circles" or _inside(c, gray.shape).all():
                return ids, c
            continue
        if best is None or len(ids) > len(best[0]):
            best = (ids, c)
        if len(ids) == n_all:
            break
    return best


def detect_pattern(frame: np.ndarray, spec, *, refine: str = "model", file: str = "",
                   views=()) -> PatternDetection | None:
    """Find a printed pattern's corners in one flood-lit frame (OpenCV's detectors, sub-pixel).

    Chessboard: ``cv2.findChessboardCornersSB`` (exhaustive, accurate), else
    ``cv2.findChessboardCorners``: the whole board or nothing (a chessboard has no
    marks that tell which corner is which in a partial view).  ChArUco: the ArUco
    markers found (any number ≥ 2; partly visible boards) place each inner corner
    near them (:func:`_charuco_corners`).  Circles: ``cv2.findCirclesGrid`` (symmetric
    grid; its blob centres, not refined).  Where the frame itself does not show the
    pattern, each of ``views`` is tried in turn (a frame rectified by a homography:
    :func:`scheimpflug.calibration.detectability.print_views` for a Scheimpflug rig's
    oblique, sheared view of a print); the corners found in a view are mapped back to the
    frame by the view's inverse homography.  Chessboard and ChArUco corners are then
    refined on the frame itself by :func:`refine_corners_model` (``refine="model"``, the
    default: unbiased by defocus; a corner it loses is dropped) or by ``cv2.cornerSubPix``
    (``refine="subpix"``, :func:`refine_corners` with the window of :func:`corner_windows_px`):
    the resampling of a view never enters a corner's sub-pixel position.

    Parameters
    ----------
    frame : (rows, columns) ndarray
        The frame [DN].
    spec : PatternSpec
        The pattern (:func:`scheimpflug.calibration.pattern.parse_pattern`).
    refine : {"model", "subpix"}, default "model"
        The sub-pixel refinement (above).
    file : str, default ""
        The frame's file, recorded.
    views : sequence of PatternView, default ()
        Rectified views to try after the frame
        (:class:`scheimpflug.calibration.detectability.PatternView`).

    Returns
    -------
    PatternDetection or None
        The corners found, or None when the pattern is not found (or fewer than 4 corners remain).

    Raises
    ------
    ValueError
        An unknown ``refine``.
    """
    if refine not in ("model", "subpix"):
        raise ValueError(f"refine must be 'model' or 'subpix', got {refine!r}")
    gray = _to_uint8(frame)
    found = _find_in_views(gray, spec, views)
    if found is None:
        return None
    ids, c = found
    if spec.kind == "circles":
        return PatternDetection(ids, c, np.zeros(len(ids), np.int64), file)
    if spec.kind == "charuco":
        keep = _inside(c, gray.shape)
        ids, c = _consistent_with_grid(spec, ids[keep], c[keep])
        if len(ids) < 4:
            return None
    win = corner_windows_px(spec, ids, c)
    if refine == "subpix":
        return PatternDetection(ids, refine_corners(frame, c, win), win, file)
    fine = refine_corners_model(frame, spec, ids, c)
    ok = np.isfinite(fine[:, 0])
    if ok.sum() < 4:
        return None
    return PatternDetection(ids[ok], fine[ok], np.zeros(int(ok.sum()), np.int64), file)


# ---------------------------------------------------------------- laser points on a pattern


def stripe_points(frame: np.ndarray, *, background: np.ndarray | None = None, along: str = "columns",
                  detector: str = "cog", saturation_dn: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The laser stripe's sub-pixel points of one frame, one per row (or per column).

    Parameters
    ----------
    frame : (rows, columns) ndarray
        The laser frame [DN].
    background : (rows, columns) ndarray, optional
        The same view with the laser off (subtracted, clipped at 0) [DN].
    along : {"columns", "rows"}, default "columns"
        Which way the stripe runs in the image: "columns" (down the image, one point per
        row: the Scheimpflug profiler's), "rows" (across it, one point per column).
    detector : str, default "cog"
        Stripe centre method (:func:`scheimpflug.stripe.extract_stripes`).
    saturation_dn : float, optional
        Saturation level [DN].

    Returns
    -------
    u_px, v_px : (n,) ndarray float64
        The points [px].

    Raises
    ------
    ValueError
        ``along`` neither "rows" nor "columns", or a background of another shape.
    """
    img = np.asarray(frame)
    if background is not None:
        bg = np.asarray(background)
        if bg.shape != img.shape:
            raise ValueError(f"the background is {bg.shape}, the frame {img.shape}")
        img = np.clip(img.astype(np.float64) - bg.astype(np.float64), 0.0, None)
    prof = extract_stripes(oriented(img, along), detector, saturation_dn=saturation_dn, window_px="auto")
    keep = ~prof.saturated
    return image_pixels(prof.rows[keep], prof.u[keep], along)


def check_plate_orientation(folder) -> None:
    """Refuse plate frames whose stripe runs along the rows (the plate methods measure one point per row).

    The paper's method and the general model measure the plate's stripe row by row and its two
    ends as the first and last lit rows (the hinge geometry of a sensor whose columns are
    distances).  A camera turned by 90° (``stripe_along = "rows"`` in the manifest) would need
    its frames turned back first.

    Parameters
    ----------
    folder : scheimpflug.io.frames.FrameFolder
        The plate frames.

    Raises
    ------
    CalibrationError
        For a folder whose manifest says ``stripe_along = "rows"``.
    """
    if getattr(folder, "stripe_along", "columns") == "rows":
        raise CalibrationError(f"{str(folder.path)!r}: the stripe runs along the rows (manifest stripe_along): "
                               "the plate methods (paper, general) need it down the columns, one point per row; "
                               "turn the frames by 90° before importing them, or calibrate with a pattern "
                               "(--method target)")
