"""Points that do not turn with the table: a turntable scan's housing told from its part.

A turntable scanner's part turns between frames; its housing (back walls, a
frame) does not.  The stripe on a still surface therefore stands at the same
image position in every frame that shows it, while the stripe on the part
moves as the part turns.  Two tests follow, both in the image, before any
calibration:

still point (:func:`still_mask`)
    A stripe point is *still* when, on the same along-stripe line of the image
    (the same column for a stripe along the rows), the stripe sits within
    ``tol_px`` of it across the line in most frames: more than half of the
    frames that show the stripe on that line, and at least a quarter of all
    frames (a wall the part hides in up to three frames in four still counts),
    and at least 3 frames.
still regions (:func:`still_regions`)
    Contiguous ranges of the along-stripe image coordinate where the stripe
    stands still across frames (a line's positions within ``tol_px`` of their
    median in more than half the frames that show it), named by their side of
    the range where it moves (``part``): ``wall_left``, ``wall_right``; and
    ``table`` for a still range whose 3-D points lie within the turntable's
    radius of its axis and within ``TABLE_BAND_MM`` of its plane (a calibration
    with a turntable axis and radius; the axis point is the table's centre on
    its top, as FabScan's platform translation; the table turns, but a disc
    turning about its own axis looks still, with the wobble of its tilt, hence
    a looser tolerance than the points').  Without such a calibration the
    table, if still, is named as a wall by its side.

A surface of revolution about the axis looks still too (the table's top, a
part's cap on the axis): still means "does not move in the image", which is
"belongs to the housing" only off the turntable; :func:`beyond_turntable`
gives FabScan's own rule (the points beyond the turntable's radius of its
axis), which :mod:`scheimpflug.reconstruct` applies with this one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["HousingSplit", "axis_coordinates_mm", "beyond_turntable", "on_lines", "separate_housing", "still_mask",
           "still_regions", "turntable_radius_mm"]

MIN_RUN_PX = 8            # shortest range of lines taken as a region (shorter: a detector's stray lines) [px]
TABLE_BAND_MM = 10.0      # a table's points: within this of the turntable's plane along its axis [mm]
REGION_TOL_PX = 6.0       # a still line's positions within this of their median (the table's wobble) [px]


def _along_axis(u_px: np.ndarray, v_px: np.ndarray) -> str:
    """``"u"`` when the column is the along-stripe (integer) coordinate, ``"v"`` when the row is."""
    u_int = bool(np.all(u_px == np.round(u_px)))
    v_int = bool(np.all(v_px == np.round(v_px)))
    if u_int != v_int:
        return "u" if u_int else "v"
    raise ValueError("cannot tell the along-stripe coordinate (neither or both of u, v are whole pixels): "
                     "give along='rows' or along='columns'")


def _lines_and_across(u_px, v_px, along: str | None) -> tuple[np.ndarray, np.ndarray]:
    """The along-stripe line index (int64) and the position across it [px] of each point."""
    u, v = np.asarray(u_px, np.float64).ravel(), np.asarray(v_px, np.float64).ravel()
    if u.shape != v.shape:
        raise ValueError(f"u_px and v_px differ in size ({u.size} and {v.size})")
    if along is None:
        axis = _along_axis(u, v) if u.size else "u"
    elif along in ("rows", "columns"):
        axis = "u" if along == "rows" else "v"      # a stripe along the rows: one point per column
    else:
        raise ValueError(f"along must be 'rows', 'columns' or None, got {along!r}")
    return (np.round(u).astype(np.int64), v) if axis == "u" else (np.round(v).astype(np.int64), u)


def _window_counts(line: np.ndarray, across: np.ndarray, tol_px: float) -> np.ndarray:
    """Per point, the points on its line within ``tol_px`` across of it (itself included)."""
    if line.size == 0:
        return np.zeros(0, np.int64)
    span = float(np.ptp(across)) + 4.0 * tol_px + 1.0
    key = (line - line.min()).astype(np.float64) * span + (across - across.min())
    s = np.sort(key)
    return np.searchsorted(s, key + tol_px, "right") - np.searchsorted(s, key - tol_px, "left")


def _frames_per_line(line: np.ndarray, frame: np.ndarray) -> np.ndarray:
    """Per point, how many distinct frames show the stripe on its line."""
    pairs = np.unique(np.stack([line, frame], axis=1), axis=0)
    lines, shown = np.unique(pairs[:, 0], return_counts=True)
    return shown[np.searchsorted(lines, line)]


def still_mask(u_px, v_px, frame, *, tol_px: float = 1.0, min_frames: int | None = None,
               along: str | None = None) -> np.ndarray:
    """Which stripe points stand where the stripe stands in most frames (module docstring).

    Parameters
    ----------
    u_px, v_px : (n,) array_like float
        Stripe points in the frame as stored, column and row [px], all frames together
        (:func:`scheimpflug.stripe.image_pixels`).
    frame : (n,) array_like int
        The frame of each point.
    tol_px : float, default 1.0
        Largest distance across the line from the point of another frame's stripe [px].
    min_frames : int, optional
        Frames the stripe must stand there in (the point's own included); default: more than
        half the frames that show the stripe on that line, at least a quarter of all frames,
        at least 3.
    along : {"rows", "columns"}, optional
        The stripe's orientation (along the rows: one point per column); default: the
        coordinate that holds whole pixels (the line index).

    Returns
    -------
    (n,) ndarray bool
        True for a still point.

    Raises
    ------
    ValueError
        Inputs of different sizes, ``tol_px`` not positive, or an orientation that cannot be told.

    Notes
    -----
    Points are counted, one per frame on a line (as :func:`scheimpflug.reconstruct.extract_folder_stripes`
    gives them); a detector giving several points of one frame on one line within ``2·tol_px``
    would count that frame twice.
    """
    if not (isinstance(tol_px, (int, float)) and math.isfinite(tol_px) and tol_px > 0):
        raise ValueError(f"tol_px must be a positive number of pixels, got {tol_px!r}")
    line, across = _lines_and_across(u_px, v_px, along)
    f = np.asarray(frame).ravel()
    if f.shape != line.shape:
        raise ValueError(f"frame has {f.size} entries for {line.size} points")
    if line.size == 0:
        return np.zeros(0, bool)
    counts = _window_counts(line, across, float(tol_px))
    if min_frames is not None:
        return counts >= int(min_frames)
    n_frames = len(np.unique(f))
    need = np.maximum(np.floor(0.5 * _frames_per_line(line, f)) + 1, max(3, math.ceil(0.25 * n_frames)))
    return counts >= need


def turntable_radius_mm(calibration) -> float | None:
    """The turntable's radius a calibration gives (FabScan's ``turntable.radius``), or None.

    Parameters
    ----------
    calibration : SheetModel
        Any calibration; FabScan's (:func:`scheimpflug.calibration.fabscan.read_fabscan`) keeps its
        config's ``turntable`` block.

    Returns
    -------
    float or None
        The radius [mm], None when the calibration gives none (or not a positive number).
    """
    tilt = getattr(calibration, "tilt", None)
    r = ((tilt or {}).get("turntable") or {}).get("radius") if isinstance(tilt, dict) else None
    if isinstance(r, bool) or not isinstance(r, (int, float)) or not (math.isfinite(r) and r > 0):
        return None
    return float(r)


def axis_coordinates_mm(calibration, u_px, v_px) -> tuple[np.ndarray, np.ndarray] | None:
    """Stripe points in the turntable's cylinder coordinates: distance from the axis and height along it.

    Parameters
    ----------
    calibration : SheetModel
        A calibration with a turntable axis (:func:`scheimpflug.reconstruct.calibration_axis`)
        and ``camera_from_pixel``.
    u_px, v_px : (n,) array_like float
        Stripe points, column and row [px].

    Returns
    -------
    tuple of two (n,) ndarray float or None
        The distance from the axis and the height along it above the axis point (the
        calibrated table plane) [mm]; None when the calibration gives no axis.
    """
    from scheimpflug.reconstruct import calibration_axis

    found = calibration_axis(calibration) if calibration is not None else None
    if found is None or not hasattr(calibration, "camera_from_pixel"):
        return None
    axis, _ = found
    w = np.asarray(axis["direction"], np.float64)
    w = w / np.linalg.norm(w)
    p = np.asarray(calibration.camera_from_pixel(np.asarray(u_px, np.float64), np.asarray(v_px, np.float64)))
    rel = p.reshape(-1, 3) - np.asarray(axis.get("point_mm", axis.get("origin_mm")), np.float64)
    h = rel @ w
    return np.linalg.norm(rel - np.outer(h, w), axis=1), h


def beyond_turntable(calibration, u_px, v_px) -> np.ndarray | None:
    """FabScan's rule: which stripe points lie beyond the turntable's radius of its axis.

    Parameters
    ----------
    calibration : SheetModel
        A calibration with a turntable axis (``axis``) and radius (:func:`turntable_radius_mm`).
    u_px, v_px : (n,) array_like float
        Stripe points, column and row [px].

    Returns
    -------
    (n,) ndarray bool or None
        True beyond the radius (points off the sheet, NaN, count as beyond); None when the
        calibration gives no axis or no radius.
    """
    radius = turntable_radius_mm(calibration)
    found = axis_coordinates_mm(calibration, u_px, v_px) if radius is not None else None
    if found is None:
        return None
    return ~(found[0] <= radius)


def _line_stats(stripes, tol_px: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
    """Per along-stripe line: index, median across position, frames showing it, frames within tol."""
    rows = [np.asarray(r, np.int64) for r in stripes.rows]
    n_frames = sum(1 for r in rows if r.size)
    line = np.concatenate(rows) if rows else np.zeros(0, np.int64)
    across = np.concatenate([np.asarray(u, np.float64) for u in stripes.u]) if rows else np.zeros(0)
    order = np.lexsort((across, line))
    line, across = line[order], across[order]
    lines, start, shown = np.unique(line, return_index=True, return_counts=True)
    med = np.array([np.median(across[a:a + n]) for a, n in zip(start, shown)])
    near = np.array([np.count_nonzero(np.abs(across[a:a + n] - m) <= tol_px)
                     for a, n, m in zip(start, shown, med)], np.int64)
    return lines, med, shown, near, n_frames


def _runs(lines: np.ndarray, flag: np.ndarray, max_gap_px: int = 3) -> list[tuple[int, int]]:
    """Contiguous ranges ``(first, last)`` of flagged lines (gaps up to ``max_gap_px`` bridged), ≥ MIN_RUN_PX long."""
    sel = lines[flag]
    if sel.size == 0:
        return []
    cut = np.flatnonzero(np.diff(sel) > max_gap_px + 1)
    starts, ends = np.r_[0, cut + 1], np.r_[cut, sel.size - 1]
    return [(int(sel[a]), int(sel[b])) for a, b in zip(starts, ends) if sel[b] - sel[a] + 1 >= MIN_RUN_PX]


def _on_table(lines, med, along, calibration) -> np.ndarray:
    """Per line: its median point lies within the turntable's radius of the axis and near the table's plane."""
    from scheimpflug.stripe import image_pixels

    radius = turntable_radius_mm(calibration) if calibration is not None else None
    if radius is None or lines.size == 0:
        return np.zeros(lines.shape, bool)
    u, v = image_pixels(lines, med, along)
    found = axis_coordinates_mm(calibration, u, v)
    if found is None:
        return np.zeros(lines.shape, bool)
    return (found[0] <= radius) & (np.abs(found[1]) <= TABLE_BAND_MM)


def _side(run, part) -> str:
    """``wall_left`` or ``wall_right``: the side of the part's range a still run lies on."""
    centre = 0.5 * (run[0] + run[1])
    return "wall_left" if part is None or centre < 0.5 * (part[0] + part[1]) else "wall_right"


def still_regions(stripes, calibration=None, *, tol_px: float = REGION_TOL_PX) -> dict[str, tuple[float, float]]:
    """The ranges of the along-stripe image coordinate where the stripe stands still, and where it moves.

    Parameters
    ----------
    stripes : FolderStripes
        A scan's stripes (:func:`scheimpflug.reconstruct.extract_folder_stripes`): ``rows`` the
        along-stripe line of each point, ``u`` its position across, ``along`` the orientation.
    calibration : SheetModel, optional
        The scan's calibration; with a turntable axis and radius (FabScan's) the still lines whose
        3-D points lie within the radius of the axis and within ``TABLE_BAND_MM`` of the table's
        plane are the ``table`` (line by line: a still range running from the table onto a wall
        is split where it leaves the table).
    tol_px : float, default 6.0
        A still line: more than half the frames that show it (and at least a quarter of all
        frames) put the stripe within this of the line's median position [px] (loose enough for
        a turning table's wobble; a part's stripe moves by tens of pixels).

    Returns
    -------
    dict of str to (float, float)
        ``part``: first and last line where the stripe moves; ``wall_left``, ``wall_right``,
        ``table``: still ranges (those present; two still ranges of one name merged into the
        range that holds both) [px, inclusive, along-stripe: columns for a stripe along the rows].
        Empty for a scan without frames.

    Raises
    ------
    ValueError
        ``tol_px`` not positive.
    """
    if not (isinstance(tol_px, (int, float)) and math.isfinite(tol_px) and tol_px > 0):
        raise ValueError(f"tol_px must be a positive number of pixels, got {tol_px!r}")
    lines, med, shown, near, n_frames = _line_stats(stripes, float(tol_px))
    if lines.size == 0:
        return {}
    enough = shown >= max(3, math.ceil(0.25 * n_frames))
    still = enough & (near > 0.5 * shown)
    moving_runs = _runs(lines, enough & ~still)
    part = (moving_runs[0][0], moving_runs[-1][1]) if moving_runs else None
    table = _on_table(lines, med, getattr(stripes, "along", "columns"), calibration)
    named = [("table", run) for run in _runs(lines, still & table)]
    named += [(None, run) for run in _runs(lines, still & ~table)]
    regions: dict[str, tuple[float, float]] = {}
    for name, run in named:
        if part is not None and part[0] <= 0.5 * (run[0] + run[1]) <= part[1]:
            continue                                  # still inside the part's range: the part near the axis
        name = name or _side(run, part)
        lo, hi = regions.get(name, (run[0], run[1]))
        regions[name] = (float(min(lo, run[0])), float(max(hi, run[1])))
    if part is not None:
        regions["part"] = (float(part[0]), float(part[1]))
    return regions


@dataclass(frozen=True)
class HousingSplit:
    """A scan's stripe points split into the housing's and the rest (:func:`separate_housing`).

    Parameters
    ----------
    keep : list of (n_i,) ndarray bool
        Per frame, the samples kept (not the housing's).
    still : int
        Samples dropped as still points on a wall's lines [-].
    beyond_turntable : int
        Samples dropped (and not already still) beyond the turntable's radius of its axis [-].
    regions : dict
        :func:`still_regions` of the scan.
    radius_mm : float or None
        The turntable's radius used, None without one [mm].
    note : str or None
        Why nothing was dropped, when nothing could be told apart.
    """

    keep: list
    still: int
    beyond_turntable: int
    regions: dict
    radius_mm: float | None = None
    note: str | None = None

    def to_json_dict(self) -> dict:
        """The counts and regions as a JSON-ready dict.

        Returns
        -------
        dict
            ``dropped`` (total), ``still``, ``beyond_turntable``, ``turntable_radius_mm``,
            ``regions`` (name → [first, last] px) and ``note``.
        """
        return {"dropped": self.still + self.beyond_turntable, "still": self.still,
                "beyond_turntable": self.beyond_turntable, "turntable_radius_mm": self.radius_mm,
                "regions": {k: [v[0], v[1]] for k, v in self.regions.items()}, "note": self.note}


def on_lines(stripes, ranges) -> list:
    """Per frame, which samples lie on the along-stripe lines of any of the given ranges.

    Parameters
    ----------
    stripes : FolderStripes
        A scan's stripes.
    ranges : iterable of (float, float)
        Inclusive ranges of the along-stripe line [px] (values of :func:`still_regions`).

    Returns
    -------
    list of (n_i,) ndarray bool
        One mask per frame.
    """
    ranges = list(ranges)
    return [np.any([(np.asarray(r) >= lo) & (np.asarray(r) <= hi) for lo, hi in ranges], axis=0)
            if ranges and len(r) else np.zeros(len(r), bool) for r in stripes.rows]


def _per_frame(mask: np.ndarray, stripes) -> list:
    """A flat per-sample mask cut into one array per frame."""
    return np.split(mask, np.cumsum([len(r) for r in stripes.rows])[:-1]) if stripes.rows else []


def separate_housing(stripes, calibration=None, *, tol_px: float = 1.0) -> HousingSplit:
    """The samples of a scan that are not its housing's (module docstring).

    Dropped: the still points (:func:`still_mask`) on the lines of a still wall
    (``wall_left``/``wall_right`` of :func:`still_regions`: the part's own still points near
    its axis and the turning table are kept), and, with a calibration that gives the
    turntable's axis and radius, every point beyond that radius (FabScan's rule,
    :func:`beyond_turntable`).  A scan whose stripe moves nowhere (no part, or a part of
    revolution about the axis) has nothing dropped as still, and says so in ``note``.

    Parameters
    ----------
    stripes : FolderStripes
        The scan's stripes (:func:`scheimpflug.reconstruct.extract_folder_stripes`).
    calibration : SheetModel, optional
        Its calibration (the ``table`` region and FabScan's radius rule need its axis and radius).
    tol_px : float, default 1.0
        :func:`still_mask`'s tolerance [px].

    Returns
    -------
    HousingSplit
        The kept samples per frame and the counts.
    """
    from scheimpflug.stripe import image_pixels

    regions = still_regions(stripes, calibration)
    line = np.concatenate([np.asarray(r, np.int64) for r in stripes.rows]) if stripes.rows else np.zeros(0, int)
    across = np.concatenate([np.asarray(u, np.float64) for u in stripes.u]) if stripes.rows else np.zeros(0)
    frame = np.concatenate([np.full(len(r), i) for i, r in enumerate(stripes.rows)]) if stripes.rows else line
    u, v = image_pixels(line, across, stripes.along)
    walls = [regions[k] for k in ("wall_left", "wall_right") if k in regions]
    note = None
    if "part" not in regions:
        note = "the stripe moves on no line (no part, or a part of revolution about the axis): no still point dropped"
        still = np.zeros(line.size, bool)
    else:
        still = still_mask(u, v, frame, tol_px=tol_px, along=stripes.along) & np.concatenate(
            on_lines(stripes, walls) or [np.zeros(0, bool)])
    beyond = beyond_turntable(calibration, u, v) if calibration is not None and line.size else None
    beyond = np.zeros(line.size, bool) if beyond is None else beyond
    return HousingSplit(keep=_per_frame(~(still | beyond), stripes), still=int(still.sum()),
                        beyond_turntable=int((beyond & ~still).sum()), regions=regions,
                        radius_mm=turntable_radius_mm(calibration) if calibration is not None else None, note=note)
