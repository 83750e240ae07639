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

__all__ = ["BOOTSTRAP_DRAWS", "BOOTSTRAP_SEED", "WALLS", "detector_figures", "wall_points"]

WALLS = ("wall_left", "wall_right")
"""The regions whose lines are walls."""
BOOTSTRAP_DRAWS = 200
"""Resamples of the twin's frames for its 90 % interval [-]."""
BOOTSTRAP_SEED = 0
"""Seed of the bootstrap's random draws."""


def wall_points(folder, frames, walls: dict, detectors, progress: ProgressCallback | None = None) -> dict:
    """The stripe points in each wall's region, per detector, of the given frames.

    The whole frame is searched as :func:`scheimpflug.fixed_lines.walls_of_folder` does (the "auto"
    window from the frame's stripe), the points in each wall's lines kept.

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
    from scheimpflug.stripe import extract_stripes, image_pixels, oriented

    gain = dn_per_electron(folder)
    acc = {d: {w: ([], [], []) for w in walls} for d in detectors}
    for j, i in enumerate(frames):
        raw = folder.read(int(i))
        frame, sat = oriented(raw, folder.stripe_along), folder.saturation_dn(raw)
        for d in detectors:
            prof = extract_stripes(frame, d, window_px="auto", saturation_dn=sat, saturated="edges",
                                   dn_per_electron=gain)
            for w, lines in walls.items():
                m = (prof.rows >= lines[0]) & (prof.rows <= lines[-1])
                u, v = image_pixels(prof.rows[m], prof.u[m], folder.stripe_along)
                acc[d][w][0].append(u)
                acc[d][w][1].append(v)
                acc[d][w][2].append(np.full(int(m.sum()), j, np.int64))
        report(progress, j + 1, len(frames))
    return {d: {w: tuple(np.concatenate(a) for a in parts) for w, parts in per.items()}
            for d, per in acc.items()}


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
    """Straightness and stillness over the walls (RMS of the walls' figures) [mm]; NaN without a wall."""
    from scheimpflug.fixed_lines import fixed_line

    lines = [fixed_line(*pts) for pts in sheet.values()]
    if not lines:
        return math.nan, math.nan
    return (float(np.sqrt(np.mean([x.rms_mm ** 2 for x in lines]))),
            float(np.sqrt(np.mean([x.stillness_mm ** 2 for x in lines]))))


def _resampled(sheet: dict, draw: np.ndarray) -> dict:
    """The walls' points of the frames ``draw`` (positions; a frame drawn k times counts as k frames)."""
    out = {}
    for w, (s, h, f) in sheet.items():
        parts = [(s[f == k], h[f == k], np.full(int((f == k).sum()), n)) for n, k in enumerate(draw)]
        cat = tuple(np.concatenate(p) for p in zip(*parts))
        if len(cat[0]) >= 3:
            out[w] = cat
    return out


def _bootstrap(sheet: dict, n_frames: int, draws: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    st, sl = np.full(draws, np.nan), np.full(draws, np.nan)
    for b in range(draws):
        st[b], sl[b] = _figures(_resampled(sheet, rng.integers(0, n_frames, n_frames)))
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
