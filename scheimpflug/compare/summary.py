"""A real scan against a twin's frames: the comparison's one object (``scheimpflug compare --json``).

Per region (:data:`scheimpflug.compare.pairing.REGION_NAMES` present): the stripe position
difference twin − real over the paired frames' lines where both show the stripe
(``position_px``: ``rms``, ``mean`` [px], ``n`` line pairs), and each figure of
:mod:`scheimpflug.compare.figures` as ``{real, twin}`` (medians over the paired frames).  Per
detector, with a calibration: :func:`scheimpflug.compare.detectors.detector_figures`.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scheimpflug.callbacks import ProgressCallback
from scheimpflug.compare.detectors import WALLS
from scheimpflug.compare.figures import FIGURES, FolderMeasures, measure_folder
from scheimpflug.compare.pairing import REGION_NAMES, FramePairs
from scheimpflug.errors import FrameError

__all__ = ["Comparison", "compare_folders", "position_differences", "twin_frames_and_regions"]


@dataclass(frozen=True)
class Comparison:
    """The measurements behind a comparison (for its pictures) and its JSON object.

    Parameters
    ----------
    real, twin : FolderMeasures
        The paired frames' measures, in pair order.
    result : dict
        The JSON object (module docstring).
    """

    real: FolderMeasures
    twin: FolderMeasures
    result: dict


def twin_frames_and_regions(path) -> tuple[Path, dict | None]:
    """The frame folder of a twin argument, and the regions its ``twin.json`` records.

    Parameters
    ----------
    path : str or Path
        A frame folder (it holds ``manifest.json``), or a twin folder holding ``twin.json`` and a
        frame folder ``frames/``.

    Returns
    -------
    folder : Path
        The frame folder.
    regions : dict of str to (float, float) or None
        ``twin.json``'s ``regions`` (names of :data:`REGION_NAMES`), or None where there is none.

    Raises
    ------
    FrameError
        A twin.json that is not a JSON object or whose regions are not ranges.
    """
    p = Path(path)
    spec = p / "twin.json"
    folder = p / "frames" if not (p / "manifest.json").is_file() and (p / "frames" / "manifest.json").is_file() \
        else p
    if not spec.is_file():
        return folder, None
    try:
        data = json.loads(spec.read_text("utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise FrameError(f"{str(spec)!r} cannot be read as JSON: {exc}") from None
    if not isinstance(data, dict):
        raise FrameError(f"{str(spec)!r} is not a JSON object")
    regions = data.get("regions")
    if regions is None:
        return folder, None
    if not isinstance(regions, dict):
        raise FrameError(f"{str(spec)!r}: regions must be an object of name: [lo, hi]")
    out = {}
    for name, rng in regions.items():
        ok = (isinstance(rng, (list, tuple)) and len(rng) == 2
              and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in rng))
        if not ok:
            raise FrameError(f"{str(spec)!r}: region {name!r} must be [lo, hi] [px], got {rng!r:.60}")
        if name in REGION_NAMES:
            out[name] = (float(rng[0]), float(rng[1]))
    return folder, out


def position_differences(real: FolderMeasures, twin: FolderMeasures) -> dict[str, np.ndarray]:
    """Per region, twin − real stripe position over the paired frames' lines where both show it [px].

    Parameters
    ----------
    real, twin : FolderMeasures
        Measured on paired frames, in pair order, with the same regions.

    Returns
    -------
    dict of str to ndarray float64
        Per region, the differences (flattened over frames and lines).
    """
    out = {}
    for r, pos in real.positions.items():
        d = twin.positions[r] - pos
        out[r] = d[np.isfinite(d)]
    return out


def _position_json(d: np.ndarray) -> dict:
    if len(d) == 0:
        return {"rms": math.nan, "mean": math.nan, "n": 0}
    return {"rms": float(np.sqrt(np.mean(d ** 2))), "mean": float(np.mean(d)), "n": int(len(d))}


def _median(v: np.ndarray) -> float:
    v = v[np.isfinite(v)]
    return float(np.median(v)) if len(v) else math.nan


def compare_folders(real, twin, regions: dict, pairs: FramePairs, *, detector: str = "cog",
                    progress: ProgressCallback | None = None, wall_detectors=()) -> Comparison:
    """Measure the paired frames of both folders and build the comparison's object (no detectors' block).

    Parameters
    ----------
    real, twin : FrameFolder
        The real scan and the twin's frames (same size and stripe orientation).
    regions : dict of str to (float, float)
        Per name, its along-stripe range [px] (:func:`scheimpflug.still_points.still_regions`).
    pairs : FramePairs
        The frames compared (:func:`scheimpflug.compare.pairing.pair_by_angle`).
    detector : str, default "cog"
        The stripe detector of the positions and figures.
    progress : ProgressCallback, optional
        ``progress(done, total)`` over both folders' frames.
    wall_detectors : sequence of str, default ()
        Detectors whose stripe points in the walls (:data:`scheimpflug.compare.detectors.WALLS`) are
        collected in the same reading of each frame (``real.wall_points``, ``twin.wall_points``: the
        input of :func:`scheimpflug.compare.detectors.detector_figures`).

    Returns
    -------
    Comparison
        ``result`` holds ``frames``, ``regions`` (module docstring) and ``detector``.

    Raises
    ------
    FrameError
        Folders of different frame sizes or stripe orientations, a bad region, an unreadable frame.
    """
    if (real.rows, real.columns) != (twin.rows, twin.columns):
        raise FrameError(f"the folders' frames differ in size: real {real.columns} × {real.rows}, twin "
                         f"{twin.columns} × {twin.rows} px (render the twin with the real camera's size)")
    if real.stripe_along != twin.stripe_along:
        raise FrameError(f"the folders' stripes run differently: real stripe_along = {real.stripe_along}, twin "
                         f"{twin.stripe_along}")
    n = len(pairs)
    half = (lambda done, total: progress(done, 2 * n)) if progress else None  # noqa: E731
    rest = (lambda done, total: progress(n + done, 2 * n)) if progress else None  # noqa: E731
    walls = {"walls": WALLS, "wall_detectors": tuple(wall_detectors)}
    rm = measure_folder(real, regions, frames=pairs.real, detector=detector, progress=half, **walls)
    tm = measure_folder(twin, regions, frames=pairs.twin, detector=detector, progress=rest, **walls)
    diffs = position_differences(rm, tm)
    out_regions = {}
    for r in (name for name in REGION_NAMES if name in rm.figures):
        block = {"position_px": _position_json(diffs[r])}
        for f in FIGURES:
            block[f] = {"real": _median(rm.figures[r][f]), "twin": _median(tm.figures[r][f])}
        out_regions[r] = block
    return Comparison(rm, tm, {"frames": n, "detector": detector, "regions": out_regions})
