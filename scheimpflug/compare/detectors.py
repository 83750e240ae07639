"""The still walls as every stripe detector sees them, on real and twin frames, with the twin's spread.

For each detector of :data:`scheimpflug.stripe.METHODS` and each folder, the stripe points of the
paired frames within a wall's region (``wall_left``, ``wall_right``) are kept by the seeded RANSAC
line of :func:`scheimpflug.fixed_lines.line_inliers` (the part's stripe crossing the range does not
count), mapped into the sheet by the calibration, and measured by
:func:`scheimpflug.fixed_lines.fixed_line`: its straightness (``rms_mm``) and stillness.  A
detector's figure over several walls is the root mean square of the walls' figures.

The twin's 90 % interval
    A percentile bootstrap over the twin's frames: :data:`BOOTSTRAP_DRAWS` resamples (seeded,
    :data:`BOOTSTRAP_SEED`) of its paired frames with replacement, each frame's inlier points
    taken whole (a frame drawn twice counts as two frames), the figures of each resample; the
    interval is their 5th and 95th percentiles.  It is the spread of the figure over the twin's
    frame-to-frame variation (speckle, noise, the part's shadow) for that many frames: a real
    figure outside it is a difference the frames' variation does not explain.
"""

from __future__ import annotations

import math

import numpy as np

from scheimpflug.callbacks import ProgressCallback, report

__all__ = ["BOOTSTRAP_DRAWS", "BOOTSTRAP_SEED", "WALLS", "detector_figures", "frame_wall_points", "joined_wall_points",
           "wall_points"]

WALLS = ("wall_left", "wall_right")
"""The regions whose lines are walls."""
BOOTSTRAP_DRAWS = 200
"""Resamples of the twin's frames for its 90 % interval [-]."""
BOOTSTRAP_SEED = 0
"""Seed of the bootstrap's random draws."""


def frame_wall_points(frame, walls: dict, detectors, *, saturation_dn: float, dn_per_electron: float,
                      along: str, extracted: dict | None = None) -> dict:
    """The stripe points in each wall's lines, per detector, of one oriented frame.

    The whole frame is searched (the "auto" window and the noise floor are the frame's, as
    :func:`scheimpflug.fixed_lines.walls_of_folder` has them), the points in each wall's lines kept.

    Parameters
    ----------
    frame : (lines, across) ndarray
        A frame as the detector reads it (:func:`scheimpflug.stripe.oriented`) [DN].
    walls : dict of str to ndarray int64
        Per wall, its lines (:func:`scheimpflug.compare.figures.region_lines`), increasing [px].
    detectors : sequence of str
        Stripe centre methods (:data:`scheimpflug.stripe.METHODS`).
    saturation_dn : float
        The frame's saturation level [DN].
    dn_per_electron : float
        The folder's noise gain (:func:`scheimpflug.reconstruct.dn_per_electron`) [DN].
    along : {"columns", "rows"}
        The folder's ``stripe_along`` (to turn the points back into image pixels).
    extracted : dict of str to StripeProfile, optional
        Profiles of this frame already extracted with the same options (``window_px="auto"``,
        ``saturated="edges"``, this saturation and gain), e.g. the figure pass's: used, not
        extracted again.

    Returns
    -------
    dict of str to dict of str to (u_px, v_px)
        Per detector and wall: the points' image pixels [px] (float64).
    """
    from scheimpflug.stripe import extract_stripes, image_pixels

    out = {}
    for d in detectors:
        prof = (extracted or {}).get(d)
        if prof is None:
            prof = extract_stripes(frame, d, window_px="auto", saturation_dn=saturation_dn, saturated="edges",
                                   dn_per_electron=dn_per_electron)
        out[d] = {}
        for w, lines in walls.items():
            m = (prof.rows >= lines[0]) & (prof.rows <= lines[-1])
            out[d][w] = image_pixels(prof.rows[m], prof.u[m], along)
    return out


def joined_wall_points(per_frame: list) -> dict:
    """:func:`frame_wall_points` of successive frames joined into one set per detector and wall.

    Parameters
    ----------
    per_frame : list of dict
        :func:`frame_wall_points` of each frame, in order (all of the same detectors and walls).

    Returns
    -------
    dict of str to dict of str to (u_px, v_px, frame)
        Per detector and wall: image pixels [px] and the position of the point's frame in ``per_frame``
        (int64).
    """
    if not per_frame:
        return {}
    out = {}
    for d, walls in per_frame[0].items():
        out[d] = {}
        for w in walls:
            u = [p[d][w][0] for p in per_frame]
            v = [p[d][w][1] for p in per_frame]
            f = [np.full(len(x), j, np.int64) for j, x in enumerate(u)]
            out[d][w] = (np.concatenate(u), np.concatenate(v), np.concatenate(f))
    return out


def wall_points(folder, frames, walls: dict, detectors, progress: ProgressCallback | None = None) -> dict:
    """The stripe points in each wall's region, per detector, of the given frames.

    Each frame read once and searched whole by every detector (:func:`frame_wall_points`);
    ``compare`` collects the same points in its figure pass
    (:func:`scheimpflug.compare.figures.measure_folder`'s ``wall_detectors``).

    Parameters
    ----------
    folder : FrameFolder
        The frames.
    frames : sequence of int
        Frame indices (manifest order).
    walls : dict of str to ndarray int64
        Per wall, its lines (:func:`scheimpflug.compare.figures.region_lines`) [px].
    detectors : sequence of str
        Stripe centre methods (:data:`scheimpflug.stripe.METHODS`).
    progress : ProgressCallback, optional
        ``progress(done, total)`` after each frame.

    Returns
    -------
    dict of str to dict of str to (u_px, v_px, frame)
        Per detector and wall: image pixels [px] (float64) and the position of the point's frame in
        ``frames`` (int64).
    """
    from scheimpflug.reconstruct import dn_per_electron
    from scheimpflug.stripe import oriented

    gain = dn_per_electron(folder)
    per_frame = []
    frames = list(frames)
    for j, i in enumerate(frames):
        raw = folder.read(int(i))
        per_frame.append(frame_wall_points(oriented(raw, folder.stripe_along), walls, detectors,
                                           saturation_dn=folder.saturation_dn(raw), dn_per_electron=gain,
                                           along=folder.stripe_along))
        report(progress, j + 1, len(frames))
    if not per_frame:
        empty = (np.zeros(0), np.zeros(0), np.zeros(0, np.int64))
        return {d: dict.fromkeys(walls, empty) for d in detectors}
    return joined_wall_points(per_frame)


def _sheet_points(points: dict, calibration) -> dict:
    """Per wall, the RANSAC line's points in the sheet: (stage_mm, h_mm, frame); walls with < 3 left out."""
    from scheimpflug.fixed_lines import line_inliers

    out = {}
    for w, (u, v, f) in points.items():
        if len(u) < 3:
            continue
        keep = line_inliers(u, v)
        if keep.sum() < 3:
            continue
        s, h = calibration.stage_from_pixel(u[keep], v[keep])
        ok = np.isfinite(s) & np.isfinite(h)
        if ok.sum() >= 3:
            out[w] = (np.asarray(s)[ok], np.asarray(h)[ok], f[keep][ok])
    return out


def _figures(sheet: dict) -> tuple[float, float]:
    """Straightness and stillness over the walls (RMS of the walls' figures) [mm]; NaN without a wall.

    A wall without 3 distinct points (a bootstrap draw of one frame's single point, repeated) is left out.
    """
    from scheimpflug.fixed_lines import fixed_line

    lines = []
    for pts in sheet.values():
        try:
            lines.append(fixed_line(*pts))
        except ValueError:
            continue
    if not lines:
        return math.nan, math.nan
    return (float(np.sqrt(np.mean([x.rms_mm ** 2 for x in lines]))),
            float(np.sqrt(np.mean([x.stillness_mm ** 2 for x in lines]))))


def _by_frame(sheet: dict, n_frames: int) -> dict:
    """Per wall, its points sorted by frame (stable: a frame's points in their order) and each frame's span."""
    out = {}
    for w, (s, h, f) in sheet.items():
        order = np.argsort(f, kind="stable")
        starts = np.searchsorted(f[order], np.arange(n_frames), side="left")
        ends = np.searchsorted(f[order], np.arange(n_frames), side="right")
        out[w] = (s[order], h[order], starts, ends - starts)
    return out


def _resampled(grouped: dict, draw: np.ndarray) -> dict:
    """The walls' points of the frames ``draw`` (positions; a frame drawn k times counts as k frames).

    ``grouped``: :func:`_by_frame`.  Frame ``draw[n]``'s points come n-th, in their own order,
    labelled n.
    """
    out = {}
    for w, (s, h, starts, counts) in grouped.items():
        lengths = counts[draw]
        total = int(lengths.sum())
        if total < 3:
            continue
        first = np.cumsum(lengths) - lengths                      # where each drawn frame's points begin
        idx = np.repeat(starts[draw] - first, lengths) + np.arange(total)
        out[w] = (s[idx], h[idx], np.repeat(np.arange(len(draw)), lengths))
    return out


def _bootstrap(sheet: dict, n_frames: int, draws: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    grouped = _by_frame(sheet, n_frames)
    st, sl = np.full(draws, np.nan), np.full(draws, np.nan)
    for b in range(draws):
        st[b], sl[b] = _figures(_resampled(grouped, rng.integers(0, n_frames, n_frames)))
    return st, sl


def _quantiles(x: np.ndarray) -> tuple[float, float]:
    x = x[np.isfinite(x)]
    return (float(np.percentile(x, 5)), float(np.percentile(x, 95))) if len(x) else (math.nan, math.nan)


def detector_figures(real_points: dict, twin_points: dict, calibration, n_twin_frames: int, *,
                     draws: int = BOOTSTRAP_DRAWS, seed: int = BOOTSTRAP_SEED) -> dict:
    """Per detector, the walls' straightness and stillness on real and twin frames, with the twin's interval.

    Parameters
    ----------
    real_points, twin_points : dict
        :func:`wall_points` of the paired real and twin frames.
    calibration : SheetModel
        Anything with ``stage_from_pixel(u, v)`` (a loaded calibration).
    n_twin_frames : int
        Twin frames measured (the bootstrap's resample size) [-].
    draws : int, default :data:`BOOTSTRAP_DRAWS`
        Bootstrap resamples [-].
    seed : int, default :data:`BOOTSTRAP_SEED`
        Their seed.

    Returns
    -------
    dict of str to dict
        Per detector: ``straightness_mm`` and ``stillness_mm``, each ``{real, twin, twin_lo90,
        twin_hi90}`` [mm] (NaN where a folder's walls hold fewer than 3 line points).
    """
    out = {}
    for d in real_points:
        real, twin = _sheet_points(real_points[d], calibration), _sheet_points(twin_points[d], calibration)
        r, t = _figures(real), _figures(twin)
        bst, bsl = _bootstrap(twin, n_twin_frames, draws, seed) if twin else (np.array([]), np.array([]))
        out[d] = {name: dict(zip(("real", "twin", "twin_lo90", "twin_hi90"), (r[k], t[k], *_quantiles(b))))
                  for k, (name, b) in enumerate((("straightness_mm", bst), ("stillness_mm", bsl)))}
    return out
