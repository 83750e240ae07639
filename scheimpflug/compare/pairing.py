"""Which frames of two folders are compared: a selection of the real folder's, paired by table angle.

A real scan and a twin's render of it are two frame folders of one scan.  A real frame and a twin
frame are a *pair* when their manifests give the same ``angle_deg`` (within :data:`ANGLE_TOL_DEG`,
modulo 360°); the order of the frames in either folder does not matter.  The frames compared are
chosen among the real folder's by their index in its manifest (:func:`select_frames`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from scheimpflug.errors import FrameError, ScheimpflugError

__all__ = ["ANGLE_TOL_DEG", "REGION_NAMES", "FramePairs", "pair_by_angle", "parse_regions", "select_frames"]

ANGLE_TOL_DEG = 1e-3
"""Two frames are at the same table angle when their angles differ by less than this, modulo 360° [deg]."""
REGION_NAMES = ("wall_left", "wall_right", "part", "table")
"""The regions a comparison knows (:func:`scheimpflug.still_points.still_regions`)."""


def select_frames(text: str, n_frames: int) -> np.ndarray:
    """Frame indices of a selection: ``all``, ``even``, ``odd``, ``A:B[:STEP]`` or ``I,J,K``.

    ``A:B[:STEP]`` is Python's ``range(A, B, STEP)``: A, A + STEP, … below B (STEP default 1).

    Parameters
    ----------
    text : str
        The selection.
    n_frames : int
        Frames of the folder it selects from [-].

    Returns
    -------
    ndarray int64
        The indices, increasing, without repeats.

    Raises
    ------
    ScheimpflugError
        Not one of the forms, a step ≤ 0, an index outside ``0 … n_frames − 1``, or an empty selection.
    """
    t = str(text).strip().lower()
    if t in ("all", "even", "odd"):
        idx = np.arange(n_frames)[{"all": slice(None), "even": slice(0, None, 2), "odd": slice(1, None, 2)}[t]]
    elif ":" in t:
        idx = _range(t, n_frames)
    else:
        try:
            idx = np.array([int(x) for x in t.split(",")], dtype=np.int64)
        except ValueError:
            raise ScheimpflugError(f"--frames {text!r}: expected all, even, odd, A:B[:STEP] or a list "
                                   "I,J,K of frame indices") from None
    idx = np.unique(np.asarray(idx, dtype=np.int64))
    bad = idx[(idx < 0) | (idx >= n_frames)]
    if len(bad):
        raise ScheimpflugError(f"--frames {text!r}: frame {int(bad[0])} is not a frame of the real folder "
                               f"(it holds frames 0–{n_frames - 1})")
    if len(idx) == 0:
        raise ScheimpflugError(f"--frames {text!r} selects no frame of the real folder's {n_frames}")
    return idx


def _range(t: str, n_frames: int) -> np.ndarray:
    parts = t.split(":")
    try:
        if len(parts) not in (2, 3):
            raise ValueError
        a, b = int(parts[0]), int(parts[1])
        step = int(parts[2]) if len(parts) == 3 else 1
    except ValueError:
        raise ScheimpflugError(f"--frames {t!r}: a range is A:B[:STEP] with whole numbers "
                               "(Python's range: A, A + STEP, … below B)") from None
    if step <= 0:
        raise ScheimpflugError(f"--frames {t!r}: the step must be ≥ 1")
    if a < 0 or b > n_frames:
        raise ScheimpflugError(f"--frames {t!r}: the range must lie within 0:{n_frames} (the real folder's "
                               "frames)")
    return np.arange(a, b, step)


def parse_regions(text: str) -> dict[str, tuple[float, float]]:
    """Regions of ``--regions NAME=LO:HI,...`` (along-stripe pixels, inclusive).

    Parameters
    ----------
    text : str
        E.g. ``wall_left=0:190,part=200:1300``.

    Returns
    -------
    dict of str to (float, float)
        Per name (one of :data:`REGION_NAMES`), its range [px].

    Raises
    ------
    ScheimpflugError
        An unknown or repeated name, or a range that is not LO:HI with finite LO ≤ HI.
    """
    out: dict[str, tuple[float, float]] = {}
    for item in str(text).split(","):
        name, sep, rng = item.strip().partition("=")
        if not sep:
            raise ScheimpflugError(f"--regions {item!r}: expected NAME=LO:HI (names: {', '.join(REGION_NAMES)})")
        if name not in REGION_NAMES:
            raise ScheimpflugError(f"--regions: unknown region {name!r} (known: {', '.join(REGION_NAMES)})")
        if name in out:
            raise ScheimpflugError(f"--regions: region {name!r} given twice")
        try:
            lo, hi = (float(x) for x in rng.split(":"))
        except ValueError:
            raise ScheimpflugError(f"--regions {item!r}: the range must be LO:HI [px]") from None
        if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
            raise ScheimpflugError(f"--regions {item!r}: the range must be finite with LO ≤ HI [px]")
        out[name] = (lo, hi)
    return out


@dataclass(frozen=True)
class FramePairs:
    """Real and twin frames at the same table angle.

    Parameters
    ----------
    real, twin : (n,) ndarray int64
        Paired frame indices (manifest order of each folder), in the real selection's order.
    angles_deg : (n,) ndarray float64
        The real frames' angles [deg].
    unmatched_real : tuple of int
        Selected real frames without a twin frame at their angle.
    """

    real: np.ndarray
    twin: np.ndarray
    angles_deg: np.ndarray
    unmatched_real: tuple = ()

    def __len__(self) -> int:
        return len(self.real)


def _angles(folder, name: str) -> np.ndarray:
    a = np.array([np.nan if r.angle_deg is None else float(r.angle_deg) for r in folder.frames])
    if not np.isfinite(a).any():
        raise FrameError(f"the {name} folder {str(folder.path)!r} gives no frame an angle_deg: frames are "
                         "paired by their table angle (import with --angles-deg, render rotary)")
    return a


def pair_by_angle(real, twin, selected) -> FramePairs:
    """Pair the selected real frames with the twin frames at their ``angle_deg``.

    Parameters
    ----------
    real, twin : FrameFolder
        The two folders.
    selected : sequence of int
        Real frame indices (:func:`select_frames`).

    Returns
    -------
    FramePairs
        The pairs; each selected real frame's nearest twin angle within :data:`ANGLE_TOL_DEG`.

    Raises
    ------
    FrameError
        A folder without angles, or no selected real frame with a twin frame at its angle.
    """
    ra, ta = _angles(real, "real"), _angles(twin, "twin")
    pr, pt, unmatched = [], [], []
    for i in selected:
        d = np.abs((ta - ra[i] + 180.0) % 360.0 - 180.0)
        j = int(np.nanargmin(d)) if np.isfinite(d).any() else -1
        if j >= 0 and d[j] < ANGLE_TOL_DEG:
            pr.append(int(i))
            pt.append(j)
        else:
            unmatched.append(int(i))
    if not pr:
        raise FrameError(f"no selected real frame has a twin frame at its angle: real angles "
                         f"{_span(ra[np.asarray(selected)])}, twin angles {_span(ta)} (render the twin at the "
                         "real scan's angles: render rotary --angles-deg as the import's)")
    return FramePairs(np.array(pr, np.int64), np.array(pt, np.int64), ra[pr], tuple(unmatched))


def _span(a: np.ndarray) -> str:
    a = a[np.isfinite(a)]
    return f"{a.min():g}…{a.max():g}° ({len(a)} frames)" if len(a) else "none"
