"""Measuring one calibration frame: plate endpoints (and, in :mod:`.target`, pattern corners and laser points).

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

import numpy as np
from scipy.ndimage import uniform_filter1d

from scheimpflug.errors import CalibrationError
from scheimpflug.stripe import extract_stripes, saturated_fraction

__all__ = [
    "CalibrationTolerances",
    "PlateMeasurement",
    "double_stripe_rows",
    "frame_diagnosis",
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


