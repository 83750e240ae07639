"""Sub-pixel laser-stripe extraction, one stripe position per image row.

In a Scheimpflug light-sheet frame the stripe runs roughly along the rows'
normal: every row ``v`` holds at most one directly lit surface point, seen at a
column ``u`` that encodes its distance along the sheet (docs/explanation/design-notes.md §3).  This
module finds that column in every row of a frame, vectorised over the frame in
a numba kernel that runs the rows in parallel.

Per row
-------
1. **Coarse peak.**  The column maximising the 3-tap smoothed row
   ``x[k-1] + 2 x[k] + x[k+1]``, then the raw maximum among its neighbours.
   The smoothing makes an isolated hot pixel lose against a stripe unless it is
   ≈ 1.8 × brighter than the stripe's peak.
2. **Local background and noise.**  Mean and variance of two flanks of
   ``flank_px`` pixels each, starting ``window_px + 1`` pixels either side of the
   peak (only the lower flank if their means differ by > 4 σ: another peak or
   an edge lies in the other).  ``noise = sqrt(var + 1/12)`` [DN] (the 1/12 DN² quantisation floor keeps
   noise-free frames finite), but never below the median of that noise over
   all rows of the frame (16 flank pixels can underestimate it badly on a dark,
   quantised background, letting 2 DN noise peaks through).
3. **Detection.**  ``score = (x[k] - background) / noise`` (a signal-to-noise
   ratio).  A row is kept when ``score >= min_snr`` (default 6: the largest of
   ≈ 1200 pure-noise pixels is ≈ 3.3 σ, so a blank row passes with probability
   < 1e-6).  A peak whose both neighbours are below ``hot_pixel_fraction``
   (10 %) of its height above background is a hot pixel, not a stripe (even a
   σ = 0.5 px stripe keeps its neighbours above 13 %): the row is rejected.
4. **Several peaks** (reflections from metal, ``multi_peak="nearest"``,
   the default): after the strongest peak is found, the row is scanned from
   column 0 toward it; the first *separate* peak (its maximum more than
   ``2 window_px + 1`` columns before the strongest, two consecutive pixels above
   the threshold) whose height is at least ``multi_peak_ratio`` (default 0.3)
   of the strongest's and which itself passes ``min_snr`` is taken instead.
   Reason: a row is (nearly) one ray of the fan (rows are lines through the
   object hinge, rays lines through the laser origin 55 mm away), and the
   directly lit point is the *first* surface along the ray, i.e. the smallest
   column (columns increase with distance); whatever lies further along the
   ray is in that surface's shadow and can only be lit by interreflection.
   ``multi_peak="strongest"`` keeps the strongest peak.  ``n_peaks`` records
   whether a second significant peak was seen (2) or not (1).

   ``multi_peak="track"`` (for inter-reflections, which can land on either side):
   every row keeps up to four separate peaks (local maxima above the detection
   threshold and ``multi_peak_ratio`` × the strongest, split by a dip below 70 % of
   the lower one), each with its sub-pixel centre, height and RMS width.  One peak
   per row is then chosen by dynamic programming down the rows (Viterbi), minimising
   −log(height/highest) + 2·(width/w₀ − 1.5)₊² + (order among the row's peaks,
   0 … 1: nearer preferred) per row and 2·min((Δu/1.5 px)², 9) between neighbouring
   rows, w₀ the frame's median width of single-peak rows.  A secondary reflection
   is usually dimmer, wider (it comes from off the sheet, out of the Scheimpflug
   focus) or breaks the stripe's continuity; a true depth step costs one capped
   jump.  Options: ``prior_u`` (e.g. the previous frame's stripe of a rotary scan,
   a further cost min(((u − prior)/2 px)², 9)) and ``expected_u`` (columns outside
   are never chosen).  On the twin's knurled ring with three bounces it halves the
   wrong-peak choices (``benchmarks/RESULTS.md``).
5. **Saturation.**  A row whose peak pixel reaches ``saturation_dn`` is
   flagged; every profile fit is meaningless on a clipped top, but its sides
   are intact.  With ``saturated="edges"`` (the default) the centre is the
   midpoint of the clipped profile's two edges at ``L = background +
   saturated_level × (saturation − background)``, the background and noise
   taken from flanks outside the whole run of clipped pixels.  Each edge is
   interpolated between the last pixel at or above L and the first below it,
   log-linearly (exact for a Gaussian's tail but its curvature), then moved out
   by ``t(1 − t) / (2 |x_e − u|)``: the Gaussian's log is a parabola of
   curvature −1/σ² whose slope at the edge is −|x_e − u|/σ², so the chord
   between the two pixels crosses L that much early, whatever σ.  Where the last
   pixel above L is itself clipped (a steep, narrow stripe) the edge is
   extrapolated from the two pixels outside it when they stand clear of the
   noise (≥ 5 σ), else it is the middle of the pixel interval it must lie in,
   with that interval's uniform variance.  On a noise-free pixel-integrated
   Gaussian (σ = 1.5–3 px, true peak 1.2–100 × the clip) the midpoint lies
   within 0.005 px of the centre; a plain linear interpolation errs by up to
   0.09 px RMS over sub-pixel phases, the run of saturated pixels' middle by
   up to half a pixel.

   The level: the paper's half height is the natural edge, but a real
   stripe is not symmetric (a thick sheet on a curved surface, a lens's
   blur), and its midpoint moves with the level.  ``saturated_level = 0.3``
   was measured best of 0.2–0.5 on both the twin and real frames.  Against
   the twin's exact per-row truth (binning 2, every 3rd of 36 frames), the
   clipped rows of the knurled metal cylinder at 4 × and of the pile of
   sundries at 16 × the paper rig's exposure err by 0.030 and 0.029 px RMS at
   0.3 (0.029 at 0.25, 0.038 and 0.035 at 0.2), 0.077 and 0.057 px at 0.5; on
   FabScan's real bust (every 4th frame of ``scan-2_1``) the centres of three
   consecutive clipped lines scatter by 0.077 px (robust; 0.117 RMS) at 0.3 and
   0.078 (0.237) at 0.5, the unsaturated lines' by 0.078 (0.150)
   (``benchmarks/bench_saturated_stripes.py`` for all frames).

   The centre's variance (``u_sigma``) propagates each pixel's noise,
   ``noise² + dn_per_electron × (x − background)`` (the flanks' white noise
   about each flank's straight line — a bright stripe's tails slope through
   them — floored at the frame's median row noise, plus shot noise when the
   camera's gain is known), through both interpolations, with the level's error from the
   flanks' mean (it cancels for a symmetric stripe).  The plateau's width
   enters through where the edges fall: the wider the plateau, the deeper in
   the tails, the flatter and noisier the edges.  It is the uncertainty from
   the noise, as the Cramér–Rao bound is for an unsaturated row
   (:func:`scheimpflug.point_quality.centre_crb_px`): the stripe's shape
   (asymmetry, speckle) is in neither.  Honest over noise draws
   (tests/test_saturated_stripes.py): the RMS of error / u_sigma is 0.9–1.2 for
   white noise (0.7 where the interval rule decides: cautious), 1.0–1.1 for
   shot noise with the camera's gain (without it the shot noise is missed:
   2–3 ×).  ``saturated="plateau"`` keeps the rule before issue 34, the middle
   of the run of saturated pixels (its ends known to a pixel: 1/24 px² of
   variance).  The edge methods ("edge", "paper") stay edges when the top is
   clipped, without ``u_sigma``.
6. **Sub-pixel position** by ``method``:

   ``"gaussian3"``  3-point Gaussian (log-parabola) through the peak and its
       neighbours, background subtracted; unbiased for Gaussian stripes.
   ``"cog"``  centre of gravity of ``x - background`` over ``±window_px``
       (needs a window ≥ ±3 σ of the stripe).
   ``"blais-rioux"``  zero crossing of the 4th-order derivative filter
       ``x[i+1] + x[i+2] - x[i-1] - x[i-2]`` (Blais & Rioux 1986), linearly
       interpolated.
   ``"edge"``  the paper's light-bar boundary: the first column right of the
       peak where the profile falls below ``background + edge_fraction ×
       (peak - background)``, linearly interpolated (paper Section 3).  This
       is an *edge*, not a centre: it lies ``σ·sqrt(2 ln(1/edge_fraction))``
       beyond the centre of a Gaussian stripe.
   ``"paper"``  the paper's red pixels (Figs. 3a, 5b): the same boundary in whole
       pixels — the last pixel right of the peak at or above that level, no
       interpolation.  The paper reports its image positions as pixel indices
       (the first frame's endpoint at ``px = 97``, the blocker at ``965``) and
       finds its edge error "about one pixel"; this rule reproduces that
       processing so that the twin's frames can be measured as the paper
       measured its own (:func:`scheimpflug.calibration.measure_plate_frame`).

Accuracy (tests/test_stripe.py, 12-bit frames with shot + read noise): the
windowed centre of gravity with ``window_px = ceil(3σ)`` is the best detector,
RMS error within 1.25 × the Cramér–Rao bound for σ = 1–2.5 px and
3000–30000 e⁻ per row, sub-pixel bias < 0.01 px; the 3-point Gaussian is
unbiased on noise-free stripes but 1.7–5 × the bound on wide noisy ones.

Pixel convention: column ``u = k`` is the centre of pixel ``k`` (0-based).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass

import numba as nb
import numpy as np

from scheimpflug.errors import FrameError

__all__ = [
    "DEFAULT_WINDOW_PX",
    "MIN_WINDOW_PX",
    "METHODS",
    "MULTI_PEAK_RULES",
    "PeakChoices",
    "SATURATED_RULES",
    "StripeProfile",
    "extract_stripes",
    "extract_stripes_batch",
    "image_pixels",
    "measured_stripe_sigma_px",
    "oriented",
    "peak_choices",
    "saturated_fraction",
    "stripe_window_px",
]

METHODS = ("blais-rioux", "cog", "edge", "gaussian3", "paper")
"""Sub-pixel methods of :func:`extract_stripes` (module docstring, step 6)."""
MULTI_PEAK_RULES = ("nearest", "strongest", "track")
"""Rules for rows with several peaks (module docstring, step 4)."""
SATURATED_RULES = ("plateau", "edges")
"""Centres of saturated rows (module docstring, step 5); the index is the kernels' code."""
_METHOD_CODE = {"gaussian3": 0, "cog": 1, "blais-rioux": 2, "edge": 3, "paper": 4}


def oriented(frame, along: str = "columns") -> np.ndarray:
    """The frame as the extraction reads it: the stripe running down the columns.

    The detector finds one stripe point per row.  A camera whose stripe runs
    across the image (``along="rows"``, e.g. a turntable scanner's camera turned
    by 90°) is read transposed, so that its *lines* (the rows of the returned
    array) are the frame's columns; :func:`image_pixels` turns the points back.

    Parameters
    ----------
    frame : (rows, columns) ndarray
        The frame as stored.
    along : {"columns", "rows"}, default "columns"
        Which way the stripe runs in ``frame`` (a frame folder's ``stripe_along``).

    Returns
    -------
    ndarray
        ``frame`` itself, or its transpose (C-contiguous) for "rows".

    Raises
    ------
    ValueError
        ``along`` neither "columns" nor "rows".
    """
    if along == "columns":
        return frame
    if along == "rows":
        return np.ascontiguousarray(np.asarray(frame).T)
    raise ValueError(f"along must be 'columns' or 'rows', got {along!r}")


def image_pixels(lines, across, along: str = "columns") -> tuple[np.ndarray, np.ndarray]:
    """Frame pixels ``(u, v)`` of stripe points found in the :func:`oriented` frame.

    Parameters
    ----------
    lines : array_like
        Line index of each point (a :class:`StripeProfile`'s ``rows``) [px].
    across : array_like float
        Its sub-pixel position across the line (the profile's ``u``) [px].
    along : {"columns", "rows"}, default "columns"
        The frame's stripe orientation.

    Returns
    -------
    u_px, v_px : ndarray float64
        Column and row in the frame as stored [px]: ``(across, lines)``, or
        ``(lines, across)`` for a stripe along the rows.

    Raises
    ------
    ValueError
        ``along`` neither "columns" nor "rows".
    """
    a, b = np.asarray(across, np.float64), np.asarray(lines, np.float64)
    if along == "columns":
        return a, b
    if along == "rows":
        return b, a
    raise ValueError(f"along must be 'columns' or 'rows', got {along!r}")


@dataclass(frozen=True)
class StripeProfile:
    """The stripe found in one frame, over the rows where it was detected.

    ``len(profile)`` is the number of rows n.  Coordinates are sensor pixels,
    column ``u = k`` at the centre of pixel ``k``.

    Parameters
    ----------
    rows : (n,) ndarray int64
        Row index v, increasing [px].
    u : (n,) ndarray float64
        Column of the stripe centre (or edge, method "edge") [px].
    score : (n,) ndarray float64
        Signal-to-noise ratio of the peak [-].
    peak : (n,) ndarray float64
        Peak height above the local background [DN].
    saturated : (n,) ndarray bool
        The peak pixel reached the saturation level.
    background : (n,) ndarray float64
        Local background level [DN].
    n_peaks : (n,) ndarray int8
        2 if a second significant peak was seen in the row, else 1.
    method : str
        The sub-pixel method used (one of :data:`METHODS`).
    u_sigma : (n,) ndarray float64, optional
        Standard uncertainty of a saturated row's centre from the noise and the
        edges' interpolation (module docstring, step 5) [px]; NaN in unsaturated
        rows (:func:`scheimpflug.point_quality.centre_crb_px` bounds theirs from
        the width and the SNR) and for the edge methods.
    """

    rows: np.ndarray
    u: np.ndarray
    score: np.ndarray
    peak: np.ndarray
    saturated: np.ndarray
    background: np.ndarray
    n_peaks: np.ndarray
    method: str
    u_sigma: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.rows.shape[0])


# ---------------------------------------------------------------- numba kernel


@nb.njit(cache=True, nogil=True)
def _side_stats(x, lo, hi):
    """Sum, sum of squares and count of x[lo:hi] (clipped)."""
    lo = max(lo, 0)
    hi = min(hi, x.shape[0])
    s = 0.0
    s2 = 0.0
    for j in range(lo, hi):
        v = float(x[j])
        s += v
        s2 += v * v
    return s, s2, max(hi - lo, 0)


@nb.njit(cache=True, nogil=True)
def _mean_var(s, s2, m):
    if m < 2:
        return np.nan, np.nan
    mean = s / m
    return mean, max(s2 / m - mean * mean, 0.0) * m / (m - 1)


@nb.njit(cache=True, nogil=True)
def _flank_stats(x, k, window, flank):
    """Background mean and variance from the flanks either side of ``k``.

    Both flanks are pooled unless their means differ by more than 4 noise σ
    (another peak or an edge in one of them): then the lower flank alone is used.
    """
    return _run_flank_stats(x, k, k, window, flank)


@nb.njit(cache=True, nogil=True)
def _run_flank_stats(x, lo, hi, window, flank):
    """:func:`_flank_stats` of a peak spanning ``lo`` … ``hi`` (a plateau of clipped pixels)."""
    sl, s2l, ml = _side_stats(x, lo - window - flank, lo - window)
    sr, s2r, mr = _side_stats(x, hi + window + 1, hi + window + 1 + flank)
    mean_l, var_l = _mean_var(sl, s2l, ml)
    mean_r, var_r = _mean_var(sr, s2r, mr)
    if np.isfinite(mean_l) and np.isfinite(mean_r):
        if abs(mean_l - mean_r) > 4.0 * math.sqrt(min(var_l, var_r) + 1.0 / 12.0):
            if mean_l < mean_r:
                return mean_l, var_l
            return mean_r, var_r
    return _mean_var(sl + sr, s2l + s2r, ml + mr)


@nb.njit(cache=True, nogil=True)
def _side_line_stats(x, lo, hi):
    """Sum, sum of squares, count of x[lo:hi] (clipped) and its residual sum of squares about its line."""
    lo = max(lo, 0)
    hi = min(hi, x.shape[0])
    m = max(hi - lo, 0)
    sj = sx = sjj = sjx = sxx = 0.0
    for j in range(lo, hi):
        v = float(x[j])
        t = float(j - lo)
        sj += t
        sx += v
        sjj += t * t
        sjx += t * v
        sxx += v * v
    if m < 3:
        return sx, sxx, m, 0.0
    vjx = sjx - sj * sx / m
    rss = (sxx - sx * sx / m) - vjx * vjx / (sjj - sj * sj / m)
    return sx, sxx, m, max(rss, 0.0)


@nb.njit(cache=True, nogil=True)
def _clipped_flanks(x, lo, hi, window, flank):
    """Background and noise variance of a clipped peak spanning ``lo`` … ``hi`` [DN, DN²].

    The flanks outside the whole plateau, pooled or the lower one alone as in
    :func:`_run_flank_stats`; the variance about each flank's straight line (a bright
    stripe's tails and the ambient light slope through the flanks: a slope is not noise).
    """
    sl, s2l, ml, rl = _side_line_stats(x, lo - window - flank, lo - window)
    sr, s2r, mr, rr = _side_line_stats(x, hi + window + 1, hi + window + 1 + flank)
    mean_l, var_l = _mean_var(sl, s2l, ml)
    mean_r, var_r = _mean_var(sr, s2r, mr)
    use_l = np.isfinite(mean_l)
    use_r = np.isfinite(mean_r)
    if use_l and use_r and abs(mean_l - mean_r) > 4.0 * math.sqrt(min(var_l, var_r) + 1.0 / 12.0):
        use_l, use_r = mean_l < mean_r, mean_l >= mean_r
    s = (sl if use_l else 0.0) + (sr if use_r else 0.0)
    m = (ml if use_l else 0) + (mr if use_r else 0)
    dof = (max(ml - 2, 0) if use_l else 0) + (max(mr - 2, 0) if use_r else 0)
    if m < 2 or dof == 0:
        return np.nan, np.nan
    return s / m, ((rl if use_l else 0.0) + (rr if use_r else 0.0)) / dof


@nb.njit(cache=True, nogil=True)
def _smoothed_argmax_int(x):
    """Argmax of ``x[k-1] + 2 x[k] + x[k+1]`` for integer rows (SIMD max + find)."""
    n = x.shape[0]
    best = np.uint32(0)
    for k in range(1, n - 1):
        s = np.uint32(x[k - 1]) + np.uint32(x[k]) + np.uint32(x[k]) + np.uint32(x[k + 1])
        best = max(best, s)
    for k in range(1, n - 1):
        s = np.uint32(x[k - 1]) + np.uint32(x[k]) + np.uint32(x[k]) + np.uint32(x[k + 1])
        if s == best:
            return k
    return 1


@nb.njit(cache=True, nogil=True)
def _smoothed_argmax_float(x):
    n = x.shape[0]
    best = -np.inf
    kb = 1
    for k in range(1, n - 1):
        s = float(x[k - 1]) + 2.0 * float(x[k]) + float(x[k + 1])
        if s > best:
            best = s
            kb = k
    return kb


@nb.njit(cache=True, nogil=True)
def _coarse_peak(x, is_int):
    """Argmax of the 3-tap smoothed row, refined to the raw maximum nearby."""
    n = x.shape[0]
    kb = _smoothed_argmax_int(x) if is_int else _smoothed_argmax_float(x)
    k = kb
    if x[kb - 1] > x[k]:
        k = kb - 1
    if x[kb + 1] > x[k]:
        k = kb + 1
    return min(max(k, 1), n - 2)


@nb.njit(cache=True, nogil=True)
def _subpixel(x, k, bg, method, window, edge_fraction):
    """Sub-pixel position of the stripe around integer peak ``k`` [px]."""
    n = x.shape[0]
    if method == 0:  # 3-point Gaussian
        a = float(x[k - 1]) - bg
        b = float(x[k]) - bg
        c = float(x[k + 1]) - bg
        if a > 0.0 and b > 0.0 and c > 0.0:
            la = math.log(a)
            lb = math.log(b)
            lc = math.log(c)
            den = la - 2.0 * lb + lc
            if den < 0.0:
                d = 0.5 * (la - lc) / den
                return k + min(max(d, -0.5), 0.5)
        den = a - 2.0 * b + c
        if den < 0.0:
            return k + min(max(0.5 * (a - c) / den, -0.5), 0.5)
        return float(k)
    if method == 1:  # windowed centre of gravity
        lo, hi = max(0, k - window), min(n, k + window + 1)
        sw = 0.0
        swj = 0.0
        for j in range(lo, hi):
            w = float(x[j]) - bg
            sw += w
            swj += w * j
        if sw > 0.0 and lo <= swj / sw <= hi - 1:
            return swj / sw
        # pixels below the background outweigh the peak (a step beside it): their negative weights
        # would throw the centre out of its own window; the peak's part above the background alone
        sw = 0.0
        swj = 0.0
        for j in range(lo, hi):
            w = max(float(x[j]) - bg, 0.0)
            sw += w
            swj += w * j
        if sw > 0.0:
            return swj / sw
        return float(k)
    if method == 2:  # Blais-Rioux 4th-order derivative zero crossing
        if k < 3 or k > n - 4:
            return float(k)
        g0 = float(x[k + 1]) + float(x[k + 2]) - float(x[k - 1]) - float(x[k - 2])
        if g0 >= 0.0:
            g1 = float(x[k + 2]) + float(x[k + 3]) - float(x[k]) - float(x[k - 1])
            if g0 - g1 > 0.0:
                return k + g0 / (g0 - g1)
            return float(k)
        gm = float(x[k]) + float(x[k + 1]) - float(x[k - 2]) - float(x[k - 3])
        if gm - g0 > 0.0:
            return k - 1 + gm / (gm - g0)
        return float(k)
    # edge (3) and paper (4): right boundary at a fraction of the peak height
    level = bg + edge_fraction * (float(x[k]) - bg)
    j = k
    while j + 1 < n and float(x[j + 1]) >= level:
        j += 1
    if j + 1 >= n:
        return np.nan
    if method == 4:  # the paper's red pixel: the boundary's last pixel, whole
        return float(j)
    hi = float(x[j])
    lo = float(x[j + 1])
    return j + (hi - level) / (hi - lo)


@nb.njit(cache=True, nogil=True)
def _nearer_peak(x, k, bg, amp, noise, window, ratio, min_snr):
    """First separate significant peak left of ``k`` (nearer the laser), or -1."""
    thresh = bg + max(ratio * amp, min_snr * noise)
    stop = k - 2 * window - 1
    j = 0
    while j < stop:
        if float(x[j]) >= thresh and float(x[j + 1]) >= thresh:
            while j + 1 < k and x[j + 1] >= x[j]:
                j += 1
            if j < stop:  # a separate local maximum, not the main peak's rising flank
                return max(j, 1)
            return -1
        j += 1
    return -1


@nb.njit(cache=True, nogil=True)
def _plateau(x, k, sat):
    """First and last pixel of the run of saturated pixels through ``k``."""
    n = x.shape[0]
    lo = k
    hi = k
    while lo > 0 and float(x[lo - 1]) >= sat:
        lo -= 1
    while hi + 1 < n and float(x[hi + 1]) >= sat:
        hi += 1
    return lo, hi


@nb.njit(cache=True, nogil=True)
def _plateau_centre(x, k, sat):
    """Middle of the run of saturated pixels through ``k`` [px] (the ``saturated="plateau"`` rule)."""
    lo, hi = _plateau(x, k, sat)
    return 0.5 * (lo + hi)


@nb.njit(cache=True, nogil=True)
def _extrapolated(x, q, step, bg, lv, b, t_min, noise2, dn_per_e):
    """The crossing of a steep edge from the two pixels outside it (``_crossing``'s returns).

    Log-linear through pixels q and q + step (b and c above the background), extrapolated
    inward to the level lv: t in [t_min, 0] from q.  NaN unless both are clear of the noise
    (c ≥ 5 σ) and the extrapolation stays between the clipped pixel and q.
    """
    q2 = q + step
    if q2 < 0 or q2 >= x.shape[0]:
        return np.nan, 0.0, 0.0, 0.0, 0.0, False
    c = float(x[q2]) - bg
    vb = noise2 + dn_per_e * b
    vc = noise2 + dn_per_e * max(c, 0.0)
    if not (c >= 5.0 * math.sqrt(vc) and b > c):
        return np.nan, 0.0, 0.0, 0.0, 0.0, False
    d = math.log(b) - math.log(c)
    t = (math.log(b) - math.log(lv)) / d
    if not t_min <= t <= 0.0:
        return np.nan, 0.0, 0.0, 0.0, 0.0, False
    dtb, dtc = (1.0 - t) / (b * d), t / (c * d)
    return q + step * t, dtb * dtb + dtc * dtc, dtb * dtb * (vb - noise2) + dtc * dtc * (vc - noise2), \
        -step / (lv * d), t, True


@nb.njit(cache=True, nogil=True)
def _crossing(x, k, step, bg, level, sat, noise2, dn_per_e):
    """Where a clipped profile falls through ``level``, walking from ``k`` by ``step`` (±1).

    Returns ``(position, white, shot, d_level, t, curved)``: the crossing [px]; the
    coefficient of the white noise variance in its variance [px²/DN²]; its variance
    from the signal-dependent noise and from the interval rule [px²]; its derivative
    with respect to the level [px/DN]; the fraction t of the pixel step; whether the
    Gaussian-tail curvature correction applies (module docstring, step 5).  NaN
    position where the profile does not fall below the level inside the row.
    """
    n = x.shape[0]
    p = k
    while 0 <= p + step < n and float(x[p + step]) >= level:
        p += step
    q = p + step
    if q < 0 or q >= n:
        return np.nan, 0.0, 0.0, 0.0, 0.0, False
    clipped = float(x[p]) >= sat
    a = (sat if clipped else float(x[p])) - bg
    lv = level - bg
    vb = noise2 + dn_per_e * max(float(x[q]) - bg, 0.0)
    b = max(float(x[q]) - bg, math.sqrt(vb))          # the log needs b > 0: floored at the noise
    if b >= lv:                                       # (noise floor above the level: linear)
        b = float(x[q]) - bg
        d = a - b
        t = (a - lv) / d
        dta, dtb, dtl = (1.0 - t) / d, t / d, -1.0 / d
        curved = False
    else:                                             # log-linear: exact for a Gaussian's tail but its curvature
        d = math.log(a) - math.log(b)
        t = (math.log(a) - math.log(lv)) / d
        dta, dtb, dtl = (1.0 - t) / (a * d), t / (b * d), -1.0 / (lv * d)
        curved = not clipped
    if clipped:                                       # x[p] ≥ sat > level: the crossing lies in [t, 1]
        out = _extrapolated(x, q, step, bg, lv, b, t - 1.0, noise2, dn_per_e)
        if np.isfinite(out[0]):
            return out
        model = (1.0 - t) ** 2 / 12.0
        t = 0.5 * (t + 1.0)
        return p + step * t, 0.25 * dtb * dtb, 0.25 * dtb * dtb * (vb - noise2) + model, \
            0.5 * step * dtl, t, False
    va_shot = dn_per_e * max(a, 0.0)
    white = dta * dta + dtb * dtb
    shot = dta * dta * va_shot + dtb * dtb * (vb - noise2)
    return p + step * t, white, shot, step * dtl, t, curved


@nb.njit(cache=True, nogil=True)
def _edges_centre(x, k, bg, noise, flank, sat, fraction, dn_per_e):
    """Centre of a clipped stripe: the midpoint of its two edges at ``fraction`` of the plateau.

    Returns ``(u, white, other)``: the centre [px] and its variance ``white · noise² +
    other`` [px²] (module docstring, step 5); the plateau's middle with variance
    1/24 px² when an edge lies outside the row.
    """
    level = bg + fraction * (sat - bg)
    noise2 = noise * noise
    xr, wr, sr, dr, tr, cr = _crossing(x, k, 1, bg, level, sat, noise2, dn_per_e)
    xl, wl, sl, dl, tl, cl = _crossing(x, k, -1, bg, level, sat, noise2, dn_per_e)
    if not (np.isfinite(xr) and np.isfinite(xl)):
        return _plateau_centre(x, k, sat), 0.0, 1.0 / 24.0
    c = 0.5 * (xr + xl)
    for _ in range(2):                                # the log interpolation's chord lies inside the
        er = tr * (1.0 - tr) / (2.0 * max(xr - c, 0.5)) if cr else 0.0   # Gaussian's log: edges move out
        el = tl * (1.0 - tl) / (2.0 * max(c - xl, 0.5)) if cl else 0.0
        c = 0.5 * (xr + er + xl - el)
    d_level = 0.5 * (dr + dl)                         # a common level error cancels for a symmetric stripe
    white = 0.25 * (wr + wl) + d_level * d_level * (1.0 - fraction) ** 2 / flank
    return c, white, 0.25 * (sr + sl)


@nb.njit(cache=True, nogil=True)
def _vertical_neighbour(frame, r, k):
    """The brighter of the pixels above and below (r, k) (−inf at the frame's edge)."""
    hi = -np.inf
    if r > 0:
        hi = max(hi, float(frame[r - 1, k]))
    if r + 1 < frame.shape[0]:
        hi = max(hi, float(frame[r + 1, k]))
    return hi


_TABLE = 11   # per-row fields: valid, u, score, peak, saturated, background, n_peaks, noise, white, other,
#              the noise of a clipped row's edges (u_sigma² = white · max(that, frame floor)² + other)


@nb.njit(cache=True, nogil=True)
def _centre(x, k, bg, noise, method, window, flank, sat, sat_opts, edge_fraction):
    """Sub-pixel position around peak ``k`` and, for a clipped one, its variance's two parts.

    ``sat_opts`` = (rule: 0 plateau, 1 edges; level [-]; DN per electron [DN]).  Returns
    ``(u, white, other, bg, noise)`` [px, px²/DN², px², DN, DN]: ``white`` and ``other`` NaN
    unless the peak is saturated and the method a centre (edges, 3 and 4, stay edges when
    clipped); a clipped peak's background and noise from flanks outside its whole plateau
    (those of ``k``, one end of it, may lie on the stripe's other side), the noise about each
    flank's line (:func:`_clipped_flanks`).
    """
    if float(x[k]) >= sat and method < 3:
        if sat_opts[0] != 1.0:
            return _plateau_centre(x, k, sat), 0.0, 1.0 / 24.0, bg, noise
        lo, hi = _plateau(x, k, sat)
        bg2, var2 = _clipped_flanks(x, lo, hi, window, flank)
        if np.isfinite(bg2):
            bg, noise = bg2, math.sqrt(var2 + 1.0 / 12.0)
        u, white, other = _edges_centre(x, k, bg, noise, flank, sat, sat_opts[1], sat_opts[2])
        return u, white, other, bg, noise
    return _subpixel(x, k, bg, method, window, edge_fraction), np.nan, np.nan, bg, noise


@nb.njit(cache=True, nogil=True)
def _one_row(frame, is_int, method, window, flank, min_snr, nearest, ratio, sat, edge_fraction,
             hot_fraction, sat_opts, out, r):
    """Fill ``out[r]``: valid, u, score, peak, saturated, background, n_peaks, noise, white, other."""
    x = frame[r]
    out[r, 0] = 0.0
    k = _coarse_peak(x, is_int)
    bg, var = _flank_stats(x, k, window, flank)
    if not np.isfinite(bg):
        return
    noise = math.sqrt(var + 1.0 / 12.0)
    out[r, 7] = noise
    amp = float(x[k]) - bg
    npk = 1.0
    if nearest:
        k2 = _nearer_peak(x, k, bg, amp, noise, window, ratio, min_snr)
        if k2 > 0:
            npk = 2.0
            bg2, var2 = _flank_stats(x, k2, window, flank)
            if np.isfinite(bg2):
                k = min(k2, x.shape[0] - 2)
                bg = bg2
                noise = math.sqrt(var2 + 1.0 / 12.0)
                amp = float(x[k]) - bg
    snr = amp / noise
    if not snr >= min_snr:
        return
    nb_hi = max(float(x[k - 1]), float(x[k + 1])) - bg
    if nb_hi < hot_fraction * amp and _vertical_neighbour(frame, r, k) - bg < hot_fraction * amp:
        return  # isolated in both directions: a hot pixel (a stripe narrower than a pixel is not)
    is_sat = float(x[k]) >= sat
    u, white, other, bg, sigma_noise = _centre(x, k, bg, noise, method, window, flank, sat, sat_opts,
                                               edge_fraction)
    if not np.isfinite(u):
        return
    amp = float(x[k]) - bg
    out[r, 0] = 1.0
    out[r, 1] = u
    out[r, 2] = amp / noise
    out[r, 3] = amp
    out[r, 4] = 1.0 if is_sat else 0.0
    out[r, 5] = bg
    out[r, 6] = npk
    out[r, 8] = white
    out[r, 9] = other
    out[r, 10] = sigma_noise


@nb.njit(cache=True, nogil=True, parallel=True)
def _extract_kernel(frame, is_int, method, window, flank, min_snr, nearest, ratio, sat,
                    edge_fraction, hot_fraction, sat_opts):
    rows = frame.shape[0]
    out = np.zeros((rows, _TABLE), dtype=np.float64)
    out[:, 7:] = np.nan
    for r in nb.prange(rows):
        _one_row(frame, is_int, method, window, flank, min_snr, nearest, ratio, sat,
                 edge_fraction, hot_fraction, sat_opts, out, r)
    return out


# ---------------------------------------------------------------- the "track" rule
_K = 4                 # candidate peaks kept per row
_CAND = 11             # fields per candidate: valid, u, snr, amp, saturated, bg, width, noise, white, other,
#                        the noise of a clipped candidate's edges


@nb.njit(cache=True, nogil=True)
def _separate_peaks(x, bg, thresh, dip, ks):
    """Columns of the separate local maxima above ``thresh``, at most ks.size, by column.

    Neighbouring maxima count as separate when the profile between them dips deeper than
    ``dip`` × the lower one's height above ``bg``.
    """
    n = x.shape[0]
    m = 0
    for k in range(1, n - 1):
        v = float(x[k])
        if v < thresh or v < float(x[k - 1]) or v <= float(x[k + 1]):
            continue
        if m > 0:
            j = ks[m - 1]
            low = v
            for q in range(j, k + 1):
                low = min(low, float(x[q]))
            if low - bg > dip * (min(v, float(x[j])) - bg):   # no real dip: same peak
                if v > float(x[j]):
                    ks[m - 1] = k
                continue
        if m == ks.shape[0]:
            break
        ks[m] = k
        m += 1
    return m


@nb.njit(cache=True, nogil=True)
def _peak_width(x, k, bg, window):
    """RMS width of x − bg (positive part) over ±window around k [px]."""
    n = x.shape[0]
    sw = 0.0
    s1 = 0.0
    s2 = 0.0
    for j in range(max(0, k - window), min(n, k + window + 1)):
        w = max(float(x[j]) - bg, 0.0)
        sw += w
        s1 += w * j
        s2 += w * j * j
    if sw <= 0.0:
        return 0.0
    m = s1 / sw
    return math.sqrt(max(s2 / sw - m * m, 0.0))


@nb.njit(cache=True, nogil=True)
def _row_candidates(x, is_int, method, window, flank, min_snr, ratio, dip, sat, edge_fraction,
                    hot_fraction, sat_opts, cand, r):
    """Fill cand[r, :, :] with up to _K separate significant peaks of row x (strongest first)."""
    k0 = _coarse_peak(x, is_int)
    bg0, var0 = _flank_stats(x, k0, window, flank)
    if not np.isfinite(bg0):
        return
    noise0 = math.sqrt(var0 + 1.0 / 12.0)
    thresh = bg0 + max(ratio * (float(x[k0]) - bg0), min_snr * noise0)
    ks = np.empty(16, np.int64)
    m = _separate_peaks(x, bg0, thresh, dip, ks)
    heights = np.empty(m)
    for i in range(m):
        heights[i] = float(x[ks[i]])
    order = np.argsort(-heights)
    slot = 0
    for oi in range(m):
        if slot == _K:
            break
        k = min(max(ks[order[oi]], 1), x.shape[0] - 2)
        bg, var = _flank_stats(x, k, window, flank)
        if not np.isfinite(bg):
            continue
        noise = math.sqrt(var + 1.0 / 12.0)
        amp = float(x[k]) - bg
        if not amp / noise >= min_snr:
            continue
        if max(float(x[k - 1]), float(x[k + 1])) - bg < hot_fraction * amp:
            continue
        is_sat = float(x[k]) >= sat
        u, white, other, bg, sigma_noise = _centre(x, k, bg, noise, method, window, flank, sat, sat_opts,
                                                   edge_fraction)
        if not np.isfinite(u):
            continue
        amp = float(x[k]) - bg
        c = cand[r, slot]
        c[0], c[1], c[2], c[3] = 1.0, u, amp / noise, amp
        c[4], c[5], c[6], c[7] = 1.0 if is_sat else 0.0, bg, _peak_width(x, k, bg, window), noise
        c[8], c[9], c[10] = white, other, sigma_noise
        slot += 1


@nb.njit(cache=True, nogil=True, parallel=True)
def _candidates_kernel(frame, is_int, method, window, flank, min_snr, ratio, dip, sat,
                       edge_fraction, hot_fraction, sat_opts):
    rows = frame.shape[0]
    cand = np.zeros((rows, _K, _CAND))
    for r in nb.prange(rows):
        _row_candidates(frame[r], is_int, method, window, flank, min_snr, ratio, dip, sat,
                        edge_fraction, hot_fraction, sat_opts, cand, r)
    return cand


@nb.njit(cache=True, nogil=True)
def _unary(cand, r, j, w_ref, weights, prior_u):
    """Cost of choosing candidate j of row r on its own (amplitude, width, order, prior)."""
    a_max = 0.0
    rank = 0
    n = 0
    for i in range(_K):
        if cand[r, i, 0] > 0.5:
            n += 1
            a_max = max(a_max, cand[r, i, 3])
            if cand[r, i, 1] < cand[r, j, 1]:
                rank += 1
    cost = weights[0] * math.log(a_max / max(cand[r, j, 3], 1e-12))
    excess = cand[r, j, 6] / w_ref - 1.5
    if excess > 0.0:
        cost += weights[1] * excess * excess
    if n > 1:
        cost += weights[2] * rank / (n - 1)
    if np.isfinite(prior_u[r]):
        d = (cand[r, j, 1] - prior_u[r]) / weights[5]
        cost += weights[4] * min(d * d, weights[6])
    return cost


@nb.njit(cache=True, nogil=True)
def _track(cand, w_ref, weights, prior_u):
    """Choose one candidate per row by dynamic programming over rows (Viterbi).

    Path cost = Σ unary + Σ between consecutive rows with candidates
    weights[3]·min(((u − u_prev)/σ_row)², cap_row); rows without candidates end a segment.
    Returns the chosen candidate index per row (−1 = none).
    """
    rows = cand.shape[0]
    cost = np.full((rows, _K), np.inf)
    back = np.full((rows, _K), -1, np.int64)
    choice = np.full(rows, -1, np.int64)
    sigma, cap = weights[7], weights[8]
    for r in range(rows):
        for j in range(_K):
            if cand[r, j, 0] < 0.5:
                continue
            u = _unary(cand, r, j, w_ref, weights, prior_u)
            best, arg = 0.0, -1
            if r > 0:
                best = np.inf
                for i in range(_K):
                    if cand[r - 1, i, 0] < 0.5:
                        continue
                    d = (cand[r, j, 1] - cand[r - 1, i, 1]) / sigma
                    c = cost[r - 1, i] + weights[3] * min(d * d, cap)
                    if c < best:
                        best, arg = c, i
                if arg < 0:
                    best = 0.0
            cost[r, j] = best + u
            back[r, j] = arg
    r = rows - 1
    while r >= 0:
        j_best, c_best = -1, np.inf
        for j in range(_K):
            if cost[r, j] < c_best:
                j_best, c_best = j, cost[r, j]
        if j_best < 0:
            r -= 1
            continue
        while r >= 0 and j_best >= 0:        # follow the segment back to its start
            choice[r] = j_best
            j_best = back[r, j_best]
            r -= 1
    return choice


#: Weights of the "track" rule: amplitude (−log of the height ratio to the row's highest),
#: width (excess over 1.5 × the frame's in-focus stripe width, squared), order (nearer
#: peaks preferred, as in "nearest"), continuity between rows, prior weight, prior σ [px],
#: prior cap, row σ [px], row cap.
TRACK_WEIGHTS = (1.0, 2.0, 1.0, 2.0, 1.0, 2.0, 9.0, 1.5, 9.0)


def _track_table(arr, is_int, method, window, flank, min_snr, ratio, sat, edge_fraction,
                 hot_fraction, sat_opts, prior_u, expected_u) -> np.ndarray:
    """The "track" rule: candidates per row, then the most continuous plausible choice."""
    cand = _candidates_kernel(arr, is_int, method, window, flank, min_snr, ratio, 0.7, sat,
                              edge_fraction, hot_fraction, sat_opts)
    if expected_u is not None:
        lo, hi = _range_bounds(expected_u, arr.shape[0])
        cand[(cand[:, :, 1] < lo[:, None]) | (cand[:, :, 1] > hi[:, None]), 0] = 0.0
    n_cand = (cand[:, :, 0] > 0.5).sum(axis=1)
    single = cand[n_cand == 1, 0, 6]
    widths = single[single > 0] if np.any(single > 0) else cand[n_cand > 0, 0, 6]
    w_ref = float(np.median(widths)) if widths.size else 1.0
    prior = np.full(arr.shape[0], np.nan) if prior_u is None else \
        np.asarray(prior_u, dtype=np.float64).reshape(arr.shape[0])
    choice = _track(cand, max(w_ref, 0.3), np.asarray(TRACK_WEIGHTS, np.float64), prior)
    out = np.zeros((arr.shape[0], _TABLE))
    out[:, 7:] = np.nan
    rows = np.nonzero(choice >= 0)[0]
    c = cand[rows, choice[rows]]
    out[rows, 0] = 1.0
    out[rows, 1:6] = c[:, 1:6]
    out[rows, 6] = np.minimum(n_cand[rows], 2)
    out[rows, 7:11] = c[:, 7:11]
    has = n_cand > 0
    out[has & (choice < 0), 7] = cand[has & (choice < 0), 0, 7]
    return out


# ---------------------------------------------------------------- public API


def _check_frame(frame) -> np.ndarray:
    arr = np.asarray(frame)
    if arr.ndim != 2:
        raise FrameError(f"a frame must be a 2-D (rows, columns) array, got shape {arr.shape}")
    if arr.shape[1] < 8 or arr.shape[0] < 1:
        raise FrameError(f"a frame needs at least 1 row and 8 columns, got shape {arr.shape}")
    if arr.dtype not in (np.uint8, np.uint16, np.float32, np.float64):
        if np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating):
            arr = arr.astype(np.float64)
        else:
            raise FrameError(f"a frame must hold numbers (uint8/uint16/float), got {arr.dtype}")
    return np.ascontiguousarray(arr)


def _default_saturation(dtype: np.dtype) -> float:
    if dtype == np.uint8:
        return 255.0
    if dtype == np.uint16:
        return 65535.0
    return math.inf


def extract_stripes(frame, method: str = "gaussian3", *, min_snr: float = 6.0,
                    window_px: int | str = 7, flank_px: int = 8, multi_peak: str = "nearest",
                    multi_peak_ratio: float = 0.3, saturation_dn: float | None = None,
                    edge_fraction: float = 0.5, hot_pixel_fraction: float = 0.1,
                    prior_u=None, expected_u=None, saturated: str = "edges",
                    saturated_level: float = 0.3, dn_per_electron: float = 0.0) -> StripeProfile:
    """Find the stripe in every row of ``frame``.

    Parameters
    ----------
    frame : (rows, columns) array_like uint8, uint16 or float
        One camera frame [DN]; other integer or float dtypes are converted to
        float64.  At least 1 row and 8 columns.
    method : {"gaussian3", "cog", "blais-rioux", "edge", "paper"}, default "gaussian3"
        Sub-pixel method (module docstring; "paper": whole pixels).
    min_snr : float, default 6.0
        Detection threshold on (peak − background) / noise [-], > 0.
    window_px : int or "auto", default 7
        Half-width of the centre-of-gravity window and the inner edge of the
        background flanks; use ≥ 3 σ of the stripe [px], >= 1.  "auto": 7, or
        ⌈3σ⌉ + 1 (at least 3) for the frame's stripe (:func:`stripe_window_px`).
    flank_px : int, default 8
        Width of each background flank [px], >= 2.
    multi_peak : {"nearest", "strongest", "track"}, default "nearest"
        Rule for rows with several peaks ("track": module docstring, step 4).
    multi_peak_ratio : float, default 0.3
        A nearer peak replaces the strongest when its height is at least this
        fraction of the strongest's; for "track", candidates must reach it [-],
        in (0, 1].
    saturation_dn : float, optional
        Level at which a pixel counts as saturated [DN]; default the dtype's
        maximum (255, 65535; none for floats).
    edge_fraction : float, default 0.5
        Fraction of the peak height that defines the edge (methods "edge" and "paper") [-],
        in (0, 1).
    hot_pixel_fraction : float, default 0.1
        A peak whose neighbours are both below this fraction of its height is
        rejected as a hot pixel [-].
    prior_u : (rows,) array_like float, optional
        "track" only: the stripe expected in each row, e.g. the previous frame's of a
        rotary scan (NaN where none) [px].
    expected_u : (lo, hi) or (rows, 2) array_like float, optional
        "track" only: columns where the stripe can be (the measuring range, a part's
        known envelope); peaks outside are ignored [px].
    saturated : {"edges", "plateau"}, default "edges"
        Centre of a saturated row for the centre methods (module docstring, step 5):
        the midpoint of the clipped profile's two edges, with its uncertainty, or the
        middle of the run of saturated pixels (before issue 34).
    saturated_level : float, default 0.3
        Fraction of the plateau's height above the background at which a saturated
        row's two edges are taken (module docstring, step 5) [-], in (0, 1).
    dn_per_electron : float, default 0.0
        The pixel noise's variance grows by this many DN² per DN of signal above the
        background (a linear camera's DN per photo-electron, 1 / conversion gain)
        [DN], >= 0; 0: the flanks' white noise everywhere.  Enters only the
        uncertainty of saturated rows (``u_sigma``).

    Returns
    -------
    StripeProfile
        Arrays over the rows where a stripe was detected, in increasing row order.

    Raises
    ------
    ValueError
        For an unknown ``method`` or ``multi_peak`` rule, or an option out of
        its range.
    FrameError
        If ``frame`` is not 2-D, has fewer than 1 row or 8 columns, or does not
        hold numbers.
    """
    if method not in _METHOD_CODE:
        raise ValueError(f"unknown stripe method {method!r} (known: {', '.join(METHODS)})")
    if multi_peak not in MULTI_PEAK_RULES:
        raise ValueError(f"unknown multi_peak rule {multi_peak!r} "
                         f"(known: {', '.join(MULTI_PEAK_RULES)})")
    if window_px == "auto":
        return _extract_auto(frame, method, min_snr=min_snr, flank_px=flank_px, multi_peak=multi_peak,
                             multi_peak_ratio=multi_peak_ratio, saturation_dn=saturation_dn,
                             edge_fraction=edge_fraction, hot_pixel_fraction=hot_pixel_fraction,
                             prior_u=prior_u, expected_u=expected_u, saturated=saturated,
                             saturated_level=saturated_level, dn_per_electron=dn_per_electron)
    if not (isinstance(window_px, (int, np.integer)) and window_px >= 1 and flank_px >= 2
            and 0 < edge_fraction < 1 and min_snr > 0 and 0 < multi_peak_ratio <= 1):
        raise ValueError("need window_px >= 1 (or 'auto'), flank_px >= 2, 0 < edge_fraction < 1, "
                         "min_snr > 0 and 0 < multi_peak_ratio <= 1")
    if saturated not in SATURATED_RULES or not (math.isfinite(dn_per_electron) and dn_per_electron >= 0
                                                and 0 < saturated_level < 1):
        raise ValueError(f"saturated must be one of {', '.join(SATURATED_RULES)} (got {saturated!r}), "
                         f"0 < saturated_level < 1 (got {saturated_level!r}) and dn_per_electron a finite "
                         f"number >= 0 (got {dn_per_electron!r})")
    arr = _check_frame(frame)
    sat = _default_saturation(arr.dtype) if saturation_dn is None else float(saturation_dn)
    is_int = arr.dtype in (np.uint8, np.uint16)
    args = (arr, is_int, _METHOD_CODE[method], int(window_px), int(flank_px), float(min_snr))
    rule = (float(SATURATED_RULES.index(saturated)), float(saturated_level), float(dn_per_electron))
    if multi_peak == "track":
        out = _track_table(*args, float(multi_peak_ratio), sat, float(edge_fraction),
                           float(hot_pixel_fraction), rule, prior_u, expected_u)
    else:
        out = _extract_kernel(*args, multi_peak == "nearest", float(multi_peak_ratio),
                              sat, float(edge_fraction), float(hot_pixel_fraction), rule)
    _apply_frame_noise_floor(out, float(min_snr))
    return _profile_from_table(out, method)


def _range_bounds(expected_u, rows: int) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) per row from (lo, hi) or (rows, 2) expected columns."""
    rng = np.asarray(expected_u, dtype=np.float64)
    if rng.shape not in ((2,), (rows, 2)):
        raise ValueError(f"expected_u must be (lo, hi) or ({rows}, 2), got shape {rng.shape}")
    return (np.broadcast_to(rng[..., 0], (rows,)).copy(),
            np.broadcast_to(rng[..., 1], (rows,)).copy())


DEFAULT_WINDOW_PX = 7   # centre-of-gravity half window before the stripe's width is known [px]
MIN_WINDOW_PX = 3       # narrowest "auto" window: ±3 px = ⌈3σ⌉ + 1 for stripes up to σ = 2/3 px [px]


def measured_stripe_sigma_px(frame, profile: StripeProfile, window_px: int) -> float:
    """The stripe's width (Gaussian σ) in a frame, from the rows where it was found.

    Parameters
    ----------
    frame : (rows, columns) array_like
        The frame [DN].
    profile : StripeProfile
        Its stripe (:func:`extract_stripes` with ``window_px``).
    window_px : int
        Half window around each centre over which the second moment is taken [px].

    Returns
    -------
    float
        Median over the unsaturated rows with SNR ≥ 20 of the background-
        subtracted second moment about the centre, less the 1/12 px² of
        pixel integration [px]; NaN without such rows.  A window narrower
        than 3σ underestimates it (the tails are cut): iterate.
    """
    keep = (profile.score >= 20) & ~profile.saturated
    if not keep.any():
        return math.nan
    arr = np.asarray(frame, dtype=np.float64)
    u, rows, bg = profile.u[keep], profile.rows[keep], profile.background[keep]
    cols = np.rint(u)[:, None].astype(np.int64) + np.arange(-window_px, window_px + 1)[None, :]
    inside = (cols >= 0) & (cols < arr.shape[1])
    vals = np.where(inside, arr[rows[:, None], np.clip(cols, 0, arr.shape[1] - 1)] - bg[:, None], 0.0)
    vals = np.maximum(vals, 0.0)
    total = vals.sum(axis=1)
    ok = total > 0
    var = (vals * (cols - u[:, None]) ** 2).sum(axis=1)[ok] / total[ok] - 1.0 / 12.0
    return float(np.sqrt(max(np.median(var), 0.0))) if ok.any() else math.nan


def stripe_window_px(sigma_px: float) -> int:
    """The centre-of-gravity half window for a stripe of width σ.

    Parameters
    ----------
    sigma_px : float
        Gaussian σ of the stripe [px] (NaN: unknown).

    Returns
    -------
    int
        ``max(MIN_WINDOW_PX, ⌈3σ⌉ + 1)`` [px]; 7 when σ is unknown.  A window
        under ±3σ cuts the tails and pulls the centre toward the window's
        integer centre (0.1 px at σ = 3.5 px in a ±7 window); the extra pixel
        holds the skewed tail of a thick sheet on a curved surface (on the
        paper's cylinder, σ = 1.3 px, ±4 px scatters 1.5 × more than ±5 … 9 px,
        which agree within 4 %); a window much
        wider than the stripe adds the noise of its background pixels and the
        error of the background level, weighted by their distance (on a
        σ = 0.5 px stripe a ±7 window triples the scatter of the plate's
        distance fit compared with ±3).
    """
    if not math.isfinite(sigma_px):
        return DEFAULT_WINDOW_PX
    return max(MIN_WINDOW_PX, math.ceil(3.0 * sigma_px - 1e-9) + 1)


def _extract_auto(frame, method: str, **options) -> StripeProfile:
    """:func:`extract_stripes` with the window fitted to the stripe: ±(⌈3σ⌉ + 1), at least ±3 px.

    A stripe much wider than the default window hides in its own flanks (the
    background estimate lands on the stripe): when the default window finds no
    row clear enough to measure the width, windows of 14 and 28 px are tried
    and the one that finds the most rows is kept before the width is measured.
    """
    window = DEFAULT_WINDOW_PX
    prof = extract_stripes(frame, method, window_px=window, **options)
    sigma = measured_stripe_sigma_px(frame, prof, window)
    if not math.isfinite(sigma):
        for wide in (2 * DEFAULT_WINDOW_PX, 4 * DEFAULT_WINDOW_PX):
            trial = extract_stripes(frame, method, window_px=wide, **options)
            if len(trial) > len(prof):
                prof, window = trial, wide
        sigma = measured_stripe_sigma_px(frame, prof, window)
    for _ in range(3):
        wanted = stripe_window_px(sigma)
        if wanted == window:
            break
        window = wanted
        prof = extract_stripes(frame, method, window_px=window, **options)
        sigma = measured_stripe_sigma_px(frame, prof, window)
    return prof


def _apply_frame_noise_floor(out: np.ndarray, min_snr: float) -> None:
    """Re-test detections against the frame's median row noise (in place).

    A 16-pixel flank can underestimate the noise badly (a dark, quantised
    background often has almost no spread), which let ≈ 2 DN noise peaks pass
    as stripes; the median of all rows' flank noise is a robust floor.
    """
    noise = out[:, 7]
    finite = noise[np.isfinite(noise)]
    if finite.size < 8:
        return
    floor = float(np.median(finite))
    valid = out[:, 0] > 0.5
    snr = out[:, 3] / np.maximum(noise, floor)
    out[:, 2] = np.where(valid, np.minimum(out[:, 2], snr), out[:, 2])
    out[:, 0] = np.where(valid & (snr >= min_snr), 1.0, 0.0)


def _edge_noise_floor(out: np.ndarray) -> float:
    """The frame's median row noise as the floor of the clipped rows' edge noise [DN] (0: too few rows).

    Each row's flank noise, a clipped row's about the flanks' lines (a frame of bright clipped
    stripes has their tails in every row's plain flanks): :func:`_apply_frame_noise_floor`'s
    guard against the 16 flank pixels' underestimates, without the tails.
    """
    noise = np.where(np.isfinite(out[:, 10]), out[:, 10], out[:, 7])
    finite = noise[np.isfinite(noise)]
    return float(np.median(finite)) if finite.size >= 8 else 0.0


def _profile_from_table(out: np.ndarray, method: str) -> StripeProfile:
    rows = np.flatnonzero(out[:, 0] > 0.5)
    t = out[rows]
    noise = np.maximum(t[:, 10], _edge_noise_floor(out))
    return StripeProfile(rows=rows.astype(np.int64), u=t[:, 1].copy(), score=t[:, 2].copy(),
                         peak=t[:, 3].copy(), saturated=t[:, 4] > 0.5,
                         background=t[:, 5].copy(), n_peaks=t[:, 6].astype(np.int8),
                         method=method, u_sigma=np.sqrt(t[:, 8] * noise * noise + t[:, 9]))


def saturated_fraction(frame, saturation_dn: float | None = None) -> float:
    """Fraction of a frame's pixels at or above the saturation level.

    Parameters
    ----------
    frame : (rows, columns) array_like
        One camera frame [DN].
    saturation_dn : float, optional
        Saturation level [DN]; default the dtype's maximum (255, 65535; none
        for floats, which then give 0).

    Returns
    -------
    float
        In [0, 1]; near 1 for a frame blown out by too long an exposure.
    """
    arr = np.asarray(frame)
    sat = _default_saturation(arr.dtype) if saturation_dn is None else float(saturation_dn)
    if arr.size == 0 or not math.isfinite(sat):
        return 0.0
    return float(np.count_nonzero(arr >= sat)) / arr.size


def extract_stripes_batch(frames: Iterable, method: str = "gaussian3",
                          **options) -> Iterator[StripeProfile]:
    """Extract the stripe of every frame of ``frames`` (lazily, in order).

    Each frame runs on all cores (rows in parallel), so frames are taken one
    at a time.

    Parameters
    ----------
    frames : iterable of (rows, columns) array_like
        Camera frames [DN], as :func:`extract_stripes` takes them.
    method : str, default "gaussian3"
        Sub-pixel method, one of :data:`METHODS`.
    **options
        Keyword options of :func:`extract_stripes`.

    Yields
    ------
    StripeProfile
        The stripe of each frame, in order; errors of
        :func:`extract_stripes` are raised when that frame is reached.
    """
    for frame in frames:
        yield extract_stripes(frame, method, **options)


# ---------------------------------------------------------------- scoring against truth


@dataclass(frozen=True)
class PeakChoices:
    """How a detector's per-row choices compare with the truth of one or more frames.

    Parameters
    ----------
    rows : int
        Rows where the truth has a stripe.
    correct : int
        Detections within the tolerance of the true stripe centre.
    secondary : int
        Wrong detections that sit on a peak of secondary light.
    other : int
        Other wrong detections (incl. detections in rows without a true stripe).
    missed : int
        Rows with a true stripe and no detection.
    """

    rows: int = 0
    correct: int = 0
    secondary: int = 0
    other: int = 0
    missed: int = 0

    def __add__(self, other: PeakChoices) -> PeakChoices:
        return PeakChoices(*(a + b for a, b in zip(
            (self.rows, self.correct, self.secondary, self.other, self.missed),
            (other.rows, other.correct, other.secondary, other.other, other.missed))))

    @property
    def secondary_rate(self) -> float:
        """Share of the true stripe's rows where a secondary peak was chosen [-]."""
        return self.secondary / self.rows if self.rows else 0.0


def peak_choices(profile: StripeProfile, stripe_u, secondary_u=None,
                 tol_px: float = 2.0) -> PeakChoices:
    """Count a detector's correct, secondary-peak and other choices in one frame.

    Parameters
    ----------
    profile : StripeProfile
        The detections.
    stripe_u : (rows,) float
        True stripe centre per row, NaN where none (truth file ``stripe_u``) [px].
    secondary_u : (rows, k) float, optional
        Columns of the secondary-light peaks per row, NaN padded (truth file
        ``secondary_u``) [px].
    tol_px : float
        A detection within this distance of the truth is correct; a wrong one within it
        of a secondary peak counts as a secondary choice [px].

    Returns
    -------
    PeakChoices
        The counts of this frame (add them up over frames with ``+``).

    Raises
    ------
    ValueError
        If the arrays do not match (rows) or ``tol_px`` ≤ 0.
    """
    truth = np.asarray(stripe_u, dtype=np.float64)
    if tol_px <= 0 or truth.ndim != 1 or (len(profile) and profile.rows.max() >= truth.size):
        raise ValueError("peak_choices: need tol_px > 0 and stripe_u (rows,) covering the profile")
    sec = np.full((truth.size, 1), np.nan) if secondary_u is None \
        else np.asarray(secondary_u, dtype=np.float64).reshape(truth.size, -1)
    has = np.isfinite(truth)
    det_u = np.full(truth.size, np.nan)
    det_u[profile.rows] = profile.u
    found = np.isfinite(det_u)
    right = found & has & (np.abs(det_u - truth) <= tol_px)
    wrong = found & ~right
    near_sec = np.any(np.abs(sec - det_u[:, None]) <= tol_px, axis=1)
    return PeakChoices(rows=int(has.sum()), correct=int(right.sum()),
                       secondary=int((wrong & near_sec).sum()),
                       other=int((wrong & ~near_sec).sum()), missed=int((has & ~found).sum()))
