"""Image-level figures of a frame folder's stripe, per region: what a twin's frames must match.

Each frame is read as the stripe detector reads it (:func:`scheimpflug.stripe.oriented`):
its *lines* run across the stripe, one line per along-stripe pixel (a column when the
stripe runs along the rows).  A *region* is a closed range ``(lo, hi)`` of that
along-stripe coordinate [px] (a wall, the part, the table:
:func:`scheimpflug.still_points.still_regions`); it holds the lines ``ceil(lo) … floor(hi)``.

In every line of a region where the detector (one of :data:`scheimpflug.stripe.METHODS`)
finds the stripe, the profile across it is taken around the detected centre ``u``
(offset ``d`` = pixel − round(u)) and measured with windows in units of the stripe's
own width ``W`` (the region's median FWHM in that frame):

core
    ``|d| ≤ 3 W`` (:data:`CORE_FWHM`).
halo
    ``3 W < |d| ≤ 3 W + HALO_WIDTH_PX``.
background
    ``3 W + HALO_WIDTH_PX < |d| ≤ 3 W + HALO_WIDTH_PX + BACKGROUND_WIDTH_PX``, both sides.

All of it is measured along the frame's line (a column for a stripe along the rows), not normal
to the stripe: where the stripe slants by ``s`` px per px in the image, widths are
``√(1 + s²)`` times the width normal to it (the FabScan table's stripe, ``s`` ≈ 2, reads 2.5 × as
wide).  A real frame and a twin frame of one pose slant alike, so the comparison is fair.

The figures of one region in one frame:

``fwhm_px``
    Median over the lines of the profile's width at half its height above the line's
    background (linear interpolation between the pixels where it crosses, searched
    outward from the peak).  A saturated line is measured as recorded: the width at
    half the *clipped plateau's* height (wider than the unclipped stripe's FWHM would be;
    a twin that saturates alike records the same width).
``peak_dn``
    Median over the lines of the highest pixel within the core [DN above 0, the folder's
    own DN: 0–255 for 8-bit frames such as imported JPEG].
``saturated_fraction``
    Fraction of the detected lines whose highest core pixel reaches the folder's
    saturation level (:meth:`scheimpflug.io.frames.FrameFolder.saturation_dn`).
``halo_fraction``
    Light in the halo window over the light in the core, background removed, summed over
    all detected lines (a ratio of sums; clipped lines included, as recorded).
``background_dn``
    Median of the background windows' pixels [DN].
``noise_dn``
    Robust standard deviation of the background windows' pixels about their own line's median:
    the standard deviation of those deviations without their lowest and highest 1 % (by rank;
    stray light and hot pixels trimmed), divided by 0.9346 so that Gaussian noise of σ gives σ [DN].
    (Not the median absolute deviation: on 8-bit frames with a dark background most pixels
    hold one value and it would be 0.)
``speckle_contrast``
    Standard deviation over mean of the core's integrated light per line, divided by its
    slow trend (a running median over :data:`SPECKLE_TREND_LINES` detected lines), over
    the unsaturated detected lines (at least :data:`MIN_SPECKLE_LINES`, else NaN).
``detection_rate``
    Detected lines over the region's lines.
``moat_dn``
    The lowest level of the region's mean profile across the stripe (the detected lines'
    profiles about their centre pixels, each line's background removed, averaged) between one
    and three stripe widths from the centre (``W < |d| ≤ 3 W``) [DN]: below 0 where the camera's
    sharpening digs a moat beside the stripe (FabScan's walls: about −0.9 DN on a 1 DN
    floor), above 0 where glare or a glow lifts the flanks.

:func:`folder_figures` gives each figure's median over the selected frames;
:func:`stripe_positions` the detected centre ``u`` [px] per frame and line (NaN where none).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.ndimage import median_filter

from scheimpflug.callbacks import ProgressCallback, report
from scheimpflug.errors import FrameError

__all__ = ["BACKGROUND_WIDTH_PX", "CORE_FWHM", "FIGURES", "FolderMeasures", "HALO_WIDTH_PX",
           "MIN_SPECKLE_LINES", "NOISE_TRIM", "PROFILE_REACH_PX", "SPECKLE_TREND_LINES", "extract", "folder_figures",
           "measure_folder", "measure_frame", "region_lines", "stripe_positions"]

CORE_FWHM = 3.0
"""Half-width of the core window in stripe widths (FWHM) [-]."""
HALO_WIDTH_PX = 32
"""Width of the halo window beyond the core, each side [px]."""
BACKGROUND_WIDTH_PX = 16
"""Width of the background window beyond the halo window, each side [px]."""
PROBE_PX = 64
"""Reach of the first look at a line's profile, before its width is known [px]."""
SPECKLE_TREND_LINES = 31
"""Running-median length of the slow trend removed before the speckle contrast [lines]."""
MIN_SPECKLE_LINES = SPECKLE_TREND_LINES
"""Fewest unsaturated detected lines for a speckle contrast (a shorter run is all trend) [lines]."""
FIGURES = ("fwhm_px", "peak_dn", "saturated_fraction", "halo_fraction", "background_dn", "noise_dn",
           "speckle_contrast", "detection_rate", "moat_dn")
"""The image-level figures, in the order of the JSON reference."""
PROFILE_REACH_PX = 96
"""Reach of the mean profile across the stripe kept for pictures (:attr:`FolderMeasures.profiles`) [px]."""
NOISE_TRIM = 0.01
"""Fraction of the background deviations trimmed off each tail before their standard deviation [-]."""
_TRIMMED_TO_STD = 0.934593
"""Standard deviation of a normal distribution trimmed at its 1st and 99th percentiles, over σ [-]."""


@dataclass(frozen=True)
class FolderMeasures:
    """The figures and stripe positions of a folder's selected frames, per region.

    Parameters
    ----------
    frames : (n,) ndarray int64
        Frame indices measured (manifest order of the folder), in the order asked.
    angles_deg : (n,) ndarray float64
        Their manifest ``angle_deg`` (NaN where none) [deg].
    lines : dict of str to (m_r,) ndarray int64
        Per region, its lines (along-stripe pixels) [px].
    positions : dict of str to (n, m_r) ndarray float64
        Per region, the stripe's centre across each line (NaN where not detected) [px].
    figures : dict of str to dict of str to (n,) ndarray float64
        Per region, per figure of :data:`FIGURES`, its value in each frame.
    profiles : dict of str to (n, 2 PROFILE_REACH_PX + 1) ndarray float64
        Per region and frame, the mean profile across the stripe over the detected lines, each
        line's taken around its centre pixel (offsets −PROFILE_REACH_PX … +PROFILE_REACH_PX) [DN];
        NaN where none.
    wall_points : dict, default {}
        With ``wall_detectors`` (:func:`measure_folder`): per detector and wall, the stripe points of
        the frames in the wall's lines (:func:`scheimpflug.compare.detectors.joined_wall_points`).
    """

    frames: np.ndarray
    angles_deg: np.ndarray
    lines: dict
    positions: dict
    figures: dict
    profiles: dict
    wall_points: dict = field(default_factory=dict)


def region_lines(regions, n_lines: int) -> dict[str, np.ndarray]:
    """The lines of each region: ``ceil(lo) … floor(hi)``, within the frame.

    Parameters
    ----------
    regions : dict of str to (float, float)
        Per name, its closed along-stripe range ``(lo, hi)`` [px].
    n_lines : int
        Lines of the oriented frame (along-stripe pixels) [px].

    Returns
    -------
    dict of str to ndarray int64
        Per region, its lines [px].

    Raises
    ------
    FrameError
        A range that is not two finite numbers lo ≤ hi, or holds no line of the frame.
    """
    out = {}
    for name, rng in regions.items():
        try:
            lo, hi = (float(x) for x in rng)
        except (TypeError, ValueError):
            raise FrameError(f"region {name!r}: {rng!r} is not a range (lo, hi) [px]") from None
        if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
            raise FrameError(f"region {name!r}: {lo:g}:{hi:g} is not a range lo ≤ hi [px]")
        a, b = max(math.ceil(lo), 0), min(math.floor(hi), n_lines - 1)
        if a > b:
            raise FrameError(f"region {name!r}: {lo:g}:{hi:g} holds none of the frame's {n_lines} "
                             "along-stripe pixels")
        out[name] = np.arange(a, b + 1, dtype=np.int64)
    return out


def _gather(frame: np.ndarray, lines: np.ndarray, centre: np.ndarray, reach: int) -> np.ndarray:
    """(n, 2 reach + 1) profile across each line around its centre pixel; NaN outside the frame."""
    d = np.arange(-reach, reach + 1)
    idx = centre[:, None] + d[None, :]
    inside = (idx >= 0) & (idx < frame.shape[1])
    prof = frame[lines[:, None], np.clip(idx, 0, frame.shape[1] - 1)].astype(np.float64)
    prof[~inside] = np.nan
    return prof


def _fwhm(q: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Width at half height of each row of ``q`` (background removed), searched outward from ``k`` [px]."""
    n, m = q.shape
    i = np.arange(n)
    half = q[i, k] / 2.0
    j = np.arange(m)[None, :]
    below = q < half[:, None]                      # NaN compares False: no crossing outside the frame
    right = below & (j > k[:, None])
    left = below & (j < k[:, None])
    has = right.any(axis=1) & left.any(axis=1) & (half > 0)
    jr = np.argmax(right, axis=1)
    jl = m - 1 - np.argmax(left[:, ::-1], axis=1)
    jr1, jl1 = np.maximum(jr - 1, 0), np.minimum(jl + 1, m - 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        xr = jr1 + (q[i, jr1] - half) / (q[i, jr1] - q[i, jr])
        xl = jl + (half - q[i, jl]) / (q[i, jl1] - q[i, jl])
    return np.where(has, xr - xl, np.nan)


def _background(prof: np.ndarray, dist: np.ndarray, inner: float, outer: float) -> np.ndarray:
    """Median of each row's pixels with inner < |d| ≤ outer [DN] (NaN where none)."""
    sel = (dist > inner) & (dist <= outer)
    win = prof[:, sel]
    ok = np.isfinite(win).any(axis=1)
    out = np.full(len(prof), np.nan)
    if ok.any():
        out[ok] = np.nanmedian(win[ok], axis=1)
    return out


def _speckle(core_dn: np.ndarray) -> float:
    """Contrast of the core's light per line about its running-median trend [-]."""
    if len(core_dn) < MIN_SPECKLE_LINES:
        return math.nan
    trend = median_filter(core_dn, size=min(SPECKLE_TREND_LINES, len(core_dn)), mode="nearest")
    ok = trend > 0
    if ok.sum() < MIN_SPECKLE_LINES:
        return math.nan
    r = core_dn[ok] / trend[ok]
    return float(np.std(r) / np.mean(r))


def _trimmed_std(dev: np.ndarray) -> float:
    """Standard deviation of the deviations within their 1st–99th percentiles, scaled to σ [DN]."""
    if dev.size < 3:
        return math.nan
    k = int(round(NOISE_TRIM * dev.size))
    kept = np.sort(dev)[k:dev.size - k]          # by rank: ties of integer frames trimmed alike
    return float(np.std(kept) / _TRIMMED_TO_STD)


def _nan_figures(rate: float) -> dict[str, float]:
    out = dict.fromkeys(FIGURES, math.nan)
    out["detection_rate"] = rate
    return out


def _mean_profile(frame: np.ndarray, lines: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Mean profile across the stripe over the lines, around each line's centre pixel [DN]."""
    if len(lines) == 0:
        return np.full(2 * PROFILE_REACH_PX + 1, np.nan)
    prof = _gather(frame, lines, np.rint(u).astype(np.int64), PROFILE_REACH_PX)
    ok = np.isfinite(prof).any(axis=0)
    out = np.full(prof.shape[1], np.nan)
    out[ok] = np.nanmean(prof[:, ok], axis=0)
    return out


def _region_figures(frame: np.ndarray, lines: np.ndarray, u: np.ndarray, n_lines: int,
                    saturation_dn: float) -> dict[str, float]:
    """The figures of one region of one oriented frame (module docstring)."""
    if len(lines) == 0:
        return _nan_figures(0.0)
    centre = np.rint(u).astype(np.int64)
    prof = _gather(frame, lines, centre, PROBE_PX)
    dist = np.abs(np.arange(-PROBE_PX, PROBE_PX + 1))
    k0 = np.nanargmax(np.where(dist[None, :] <= 3, prof, -np.inf), axis=1)
    bg0 = _background(prof, dist, PROBE_PX - BACKGROUND_WIDTH_PX, PROBE_PX)
    width = float(np.nanmedian(_fwhm(prof - bg0[:, None], k0))) if np.isfinite(bg0).any() else math.nan
    if not math.isfinite(width):
        width = 1.0
    core = CORE_FWHM * width
    halo_out = core + HALO_WIDTH_PX
    bg_out = halo_out + BACKGROUND_WIDTH_PX
    reach = max(int(math.ceil(bg_out)), 4)
    prof = _gather(frame, lines, centre, reach)
    dist = np.abs(np.arange(-reach, reach + 1))
    bg = _background(prof, dist, halo_out, bg_out)
    q = prof - bg[:, None]
    in_core = dist <= max(core, 1.0)
    k = np.nanargmax(np.where(in_core[None, :], prof, -np.inf), axis=1)
    peak = prof[np.arange(len(lines)), k]
    sat = peak >= saturation_dn
    core_dn = np.nansum(np.where(in_core[None, :], q, 0.0), axis=1)
    halo_dn = np.nansum(np.where(((dist > core) & (dist <= halo_out))[None, :], q, 0.0), axis=1)
    bgwin = prof[:, (dist > halo_out) & (dist <= bg_out)]
    dev = (bgwin - bg[:, None])[np.isfinite(bgwin)]
    total_core = float(np.sum(core_dn))
    return {
        "fwhm_px": float(np.nanmedian(_fwhm(q, k))) if len(lines) else math.nan,
        "peak_dn": float(np.median(peak)),
        "saturated_fraction": float(np.mean(sat)),
        "halo_fraction": float(np.sum(halo_dn) / total_core) if total_core > 0 else math.nan,
        "background_dn": float(np.nanmedian(bgwin)) if np.isfinite(bgwin).any() else math.nan,
        "noise_dn": _trimmed_std(dev),
        "speckle_contrast": _speckle(core_dn[~sat]),
        "detection_rate": len(lines) / n_lines,
        "moat_dn": _moat(q, dist, width, core),
    }


def _moat(q: np.ndarray, dist: np.ndarray, width: float, core: float) -> float:
    """Lowest level of the mean background-removed profile with width < |d| ≤ core [DN] (NaN where none)."""
    band = (dist > width) & (dist <= core)
    cols = q[:, band]
    ok = np.isfinite(cols).any(axis=0)
    if not ok.any():
        return math.nan
    return float(np.min(np.nanmean(cols[:, ok], axis=0)))


def extract(frame, detector: str, *, saturation_dn: float, dn_per_electron: float = 0.0):
    """The stripe of one oriented frame as every pass of a comparison finds it.

    :func:`scheimpflug.stripe.extract_stripes` with the window fitted to the frame's stripe
    (``window_px="auto"``), a saturated line's centre from its edges, ``saturation_dn`` and
    ``dn_per_electron``.

    Parameters
    ----------
    frame : (lines, across) ndarray
        A frame as the detector reads it (:func:`scheimpflug.stripe.oriented`) [DN].
    detector : str
        Stripe centre method (:data:`scheimpflug.stripe.METHODS`).
    saturation_dn : float
        The frame's saturation level [DN].
    dn_per_electron : float, default 0.0
        The folder's noise gain [DN].

    Returns
    -------
    StripeProfile
        The stripe points, one per line where it is found.
    """
    from scheimpflug.stripe import extract_stripes

    return extract_stripes(frame, detector, window_px="auto", saturation_dn=saturation_dn, saturated="edges",
                           dn_per_electron=dn_per_electron)


def measure_frame(frame, regions, *, saturation_dn: float, detector: str = "cog", dn_per_electron: float = 0.0,
                  profile=None) -> dict[str, tuple[np.ndarray, dict[str, float], np.ndarray]]:
    """The stripe positions and figures of one oriented frame, per region.

    Parameters
    ----------
    frame : (lines, across) ndarray
        A frame as the detector reads it (:func:`scheimpflug.stripe.oriented`) [DN].
    regions : dict of str to ndarray int64
        Per region, its lines (:func:`region_lines`) [px].
    saturation_dn : float
        The frame's saturation level [DN].
    detector : str, default "cog"
        Stripe centre method (:data:`scheimpflug.stripe.METHODS`).
    dn_per_electron : float, default 0.0
        The folder's noise gain (:func:`scheimpflug.reconstruct.dn_per_electron`) [DN].
    profile : StripeProfile, optional
        The frame's stripe, :func:`extract` of it with these options (default: extracted here).

    Returns
    -------
    dict of str to (positions, figures, profile)
        Per region: the stripe centre across each of its lines, NaN where none [px]
        ((m_r,) float64), its figures (module docstring) and its mean profile across the stripe
        (:attr:`FolderMeasures.profiles`) [DN].
    """
    prof = profile if profile is not None else extract(frame, detector, saturation_dn=saturation_dn,
                                                        dn_per_electron=dn_per_electron)
    out = {}
    for name, lines in regions.items():
        pos = np.full(len(lines), np.nan)
        m = (prof.rows >= lines[0]) & (prof.rows <= lines[-1])
        pos[prof.rows[m] - lines[0]] = prof.u[m]
        out[name] = (pos, _region_figures(frame, prof.rows[m], prof.u[m], len(lines), saturation_dn),
                     _mean_profile(frame, prof.rows[m], prof.u[m]))
    return out


def _open(folder):
    from scheimpflug.io.frames import open_frame_folder

    return open_frame_folder(folder) if isinstance(folder, (str, Path)) else folder


def _frame_indices(folder, frames) -> np.ndarray:
    if frames is None:
        return np.arange(len(folder), dtype=np.int64)
    idx = np.asarray(list(frames), dtype=np.int64).reshape(-1)
    bad = idx[(idx < 0) | (idx >= len(folder))]
    if len(bad):
        raise FrameError(f"frame {int(bad[0])} is not a frame of {str(folder.path)!r} "
                         f"(it holds frames 0–{len(folder) - 1})")
    return idx


def measure_folder(folder, regions, *, frames=None, detector: str = "cog", progress: ProgressCallback | None = None,
                   walls=(), wall_detectors=()) -> FolderMeasures:
    """Stripe positions and figures of a folder's frames, per region and frame (module docstring).

    Parameters
    ----------
    folder : str, Path or FrameFolder
        A frame folder (:func:`scheimpflug.io.frames.open_frame_folder`).
    regions : dict of str to (float, float)
        Per name, its along-stripe range ``(lo, hi)`` [px] (:func:`region_lines`).
    frames : sequence of int, optional
        Frame indices (manifest order); default all.
    detector : str, default "cog"
        Stripe centre method (:data:`scheimpflug.stripe.METHODS`).
    progress : ProgressCallback, optional
        ``progress(done, total)`` after each frame.
    walls : sequence of str, default ()
        Regions whose lines are walls (:data:`scheimpflug.compare.detectors.WALLS`).
    wall_detectors : sequence of str, default ()
        Detectors whose stripe points in the walls' lines are collected from the same reading of
        each frame (:func:`scheimpflug.compare.detectors.frame_wall_points`; ``detector``'s own
        extraction shared): :attr:`FolderMeasures.wall_points`.

    Returns
    -------
    FolderMeasures
        The positions and the per-frame figures (and the walls' points).

    Raises
    ------
    FrameError
        A frame index outside the folder, a bad region, an unreadable frame.
    """
    from scheimpflug.compare.detectors import frame_wall_points, joined_wall_points
    from scheimpflug.reconstruct import dn_per_electron
    from scheimpflug.stripe import oriented

    folder = _open(folder)
    idx = _frame_indices(folder, frames)
    n_lines = folder.columns if folder.stripe_along == "rows" else folder.rows
    lines = region_lines(regions, n_lines)
    wall_lines = {w: lines[w] for w in walls if w in lines} if wall_detectors else {}
    gain = dn_per_electron(folder)
    positions = {r: np.full((len(idx), len(v)), np.nan) for r, v in lines.items()}
    figures = {r: {f: np.full(len(idx), np.nan) for f in FIGURES} for r in lines}
    profiles = {r: np.full((len(idx), 2 * PROFILE_REACH_PX + 1), np.nan) for r in lines}
    walls_per_frame = []
    for j, i in enumerate(idx):
        raw = folder.read(int(i))
        frame, sat = oriented(raw, folder.stripe_along), folder.saturation_dn(raw)
        prof = extract(frame, detector, saturation_dn=sat, dn_per_electron=gain)
        got = measure_frame(frame, lines, saturation_dn=sat, detector=detector, dn_per_electron=gain, profile=prof)
        for r, (pos, figs, mean_prof) in got.items():
            positions[r][j] = pos
            profiles[r][j] = mean_prof
            for f, v in figs.items():
                figures[r][f][j] = v
        if wall_lines:
            walls_per_frame.append(frame_wall_points(frame, wall_lines, wall_detectors, saturation_dn=sat,
                                                     dn_per_electron=gain, along=folder.stripe_along,
                                                     extracted={detector: prof}))
        report(progress, j + 1, len(idx))
    angles = np.array([np.nan if folder.frames[i].angle_deg is None else folder.frames[i].angle_deg
                       for i in idx], dtype=np.float64)
    return FolderMeasures(idx, angles, lines, positions, figures, profiles, joined_wall_points(walls_per_frame))


def folder_figures(folder, regions, *, frames=None, detector: str = "cog") -> dict[str, dict[str, float]]:
    """Per region, each figure's median over the selected frames (module docstring).

    Parameters
    ----------
    folder : str, Path or FrameFolder
        A frame folder.
    regions : dict of str to (float, float)
        Per name, its along-stripe range ``(lo, hi)`` [px]
        (:func:`scheimpflug.still_points.still_regions`).
    frames : sequence of int, optional
        Frame indices (manifest order); default all.
    detector : str, default "cog"
        Stripe centre method (:data:`scheimpflug.stripe.METHODS`).

    Returns
    -------
    dict of str to dict of str to float
        ``{region: {figure: median}}`` for the figures of :data:`FIGURES` (NaN where no
        frame gave a value); levels in the folder's own DN.

    Raises
    ------
    FrameError
        A frame index outside the folder, a bad region, an unreadable frame.
    """
    m = measure_folder(folder, regions, frames=frames, detector=detector)
    return {r: {f: _nanmedian(v) for f, v in figs.items()} for r, figs in m.figures.items()}


def stripe_positions(folder, regions, *, frames=None, detector: str = "cog") -> dict[str, np.ndarray]:
    """Per region, the stripe's position across each along-stripe pixel, per frame.

    Parameters
    ----------
    folder : str, Path or FrameFolder
        A frame folder.
    regions : dict of str to (float, float)
        Per name, its along-stripe range ``(lo, hi)`` [px]: lines ``ceil(lo) … floor(hi)``.
    frames : sequence of int, optional
        Frame indices (manifest order); default all.
    detector : str, default "cog"
        Stripe centre method (:data:`scheimpflug.stripe.METHODS`).

    Returns
    -------
    dict of str to (n_frames, m_r) ndarray float64
        Row ``j`` is frame ``frames[j]``, column ``c`` the line ``ceil(lo) + c`` (clipped to the
        frame); the centre across it [px], NaN where the stripe was not detected.  Pair frames of
        two folders by their ``angle_deg`` before subtracting.

    Raises
    ------
    FrameError
        A frame index outside the folder, a bad region, an unreadable frame.
    """
    return measure_folder(folder, regions, frames=frames, detector=detector).positions


def _nanmedian(v: np.ndarray) -> float:
    v = v[np.isfinite(v)]
    return float(np.median(v)) if len(v) else math.nan
