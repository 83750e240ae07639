"""A watertight surface model of a rotary scan, meshed on the scan's own grid (frame × row).

A rotary scan is a structured grid: frame ``i`` (rotary angle θ_i) gives one
profile, at most one point per sensor row ``v``.  Every point of a
:class:`~scheimpflug.reconstruct.PointCloud` keeps its frame and row, so the
surface can be meshed directly on that grid, without the smoothing of a
generic reconstruction: each triangle joins measured points of two
neighbouring profiles.

The rule (what is joined, what is filled)
-----------------------------------------
1. **Profiles → segments.**  Within a frame, consecutive points (in row order)
   belong to one *segment* when they are at most ``max_step_mm`` apart in 3-D
   (default: ``step_factor`` × the scan's median row-to-row step, i.e. 20 rows
   of a steep wall).  A larger jump is a discontinuity: an occlusion edge, a
   face the sheet never reaches, or another body.  Rows missing inside a
   segment (a short gap) are bridged by the straight join of the points on
   either side.  A profile is also cut where its neighbouring profile is cut
   between two runs of ``min_points`` or more, at its largest step within the
   rows of that cut if that step is at least ¼ ``max_step_mm``, so that a
   face seen sparsely at some angles only (a shoulder) does not join two runs
   in some profiles and not in others.  Segments of
   fewer than ``min_points`` points are noise and are not used.
2. **Segments → bodies.**  A segment is linked to one segment of the next
   frame (one to one, largest overlap first) when their height ranges overlap
   by at least ``min_overlap`` of the shorter one and their mid-points lie
   within ``max_step_mm + 6·r·Δθ`` horizontally (r the distance from the axis:
   the profile may move along a face seen at up to ≈ 80° incidence).  A
   segment with no partner in the next frame may link over missing frames,
   up to ``max_gap_deg`` (default 3 × the angular step).  A chain of linked
   segments is one **body**; chains of fewer than ``min_profiles`` profiles
   are not used.  Bodies never share a vertex: several parts stay apart, and
   a face no profile sees (a shoulder above the laser, the face where one
   part stands on another) separates bodies — a stepped part can come out as
   stacked bodies whose volumes add up.
3. **Bodies → closed surfaces.**  Neighbouring profiles of a body are joined
   by a triangle strip that advances row by row on both (the grid's own
   neighbours).  A chain that goes all the way round is closed on itself; one
   that does not (a body seen over part of the turn only) is closed by a strip
   from its last profile back to its first (``side``).  The bottom ends of the
   profiles are carried straight down to the rotary-table plane
   (``table_z_mm``) and closed there by a flat disc when they end within
   ``table_gap_mm`` of it (``table``); any other open end — a top that no
   profile reached, the bottom of a body standing on another — is closed by a
   cap: a fan from the loop's centre (the rotary axis when the loop winds
   round it) at the loop's mean height (``cap``).

Every face carries a fill code (:data:`FILL_NAMES`): ``measured`` (three
measured points of neighbouring rows and frames), ``gap`` (a bridged gap of
rows or frames), ``table``, ``cap`` or ``side``: everything but ``measured``
is *not measured*.  The result is watertight and consistently oriented
(outward normals) body by body: every edge is shared by exactly two faces
traversing it in opposite directions.

Limits: a cap is a fan, so a strongly non-convex open outline (a top cap of
a part with a bore) is filled — and the volume error of that fill is what
the scoring reports, not hidden.  Bodies that touch are not merged, and
caps and side strips may cut through other bodies.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from scheimpflug.errors import MeshError

__all__ = [
    "FILL_CAP",
    "FILL_GAP",
    "FILL_MEASURED",
    "FILL_NAMES",
    "FILL_SIDE",
    "FILL_TABLE",
    "ModelSettings",
    "SurfaceModel",
    "model_from_cloud",
]

FILL_MEASURED, FILL_GAP, FILL_TABLE, FILL_CAP, FILL_SIDE = 0, 1, 2, 3, 4
#: Name of each fill code (index = code).
FILL_NAMES = ("measured", "gap", "table", "cap", "side")

_LINK_INCIDENCE = 6.0   # horizontal link slack per r·Δθ: tan(80.5°), faces seen up to ≈ 80° incidence
_MEASURED_ROW_SPAN = 2  # a measured triangle spans at most this many rows (neighbours shift by a row)
_PROPAGATE = 0.25       # a neighbour's cut is copied only onto a step of at least this × max_step_mm


@dataclass(frozen=True)
class ModelSettings:
    """The meshing rule's parameters (module docstring, "The rule").

    Parameters
    ----------
    max_step_mm : float or None
        Largest 3-D step between consecutive points of one profile segment
        [mm]; None: ``step_factor`` × the scan's median row-to-row step.
    step_factor : float
        Multiple of the median row-to-row step used when ``max_step_mm`` is
        None [-] (20: a wall sloping up to ≈ 87°, or a 20-row gap).
    max_gap_deg : float or None
        Largest angle between two linked profiles [deg]; None: 3 × the scan's
        angular step (up to two missing frames bridged).
    min_overlap : float
        Height-range overlap needed to link segments of neighbouring frames,
        as a fraction of the shorter one [-].
    table_z_mm : float or None
        Height of the rotary-table plane in the part frame [mm] (the rig's
        ``stage.rotary_table_z_mm``); None: no table, every open end is capped.
    table_gap_mm : float
        A body whose bottom loop ends (median) within this height of the table
        is closed on the table [mm].
    min_points : int
        Fewest points of a usable profile segment [-].
    min_profiles : int
        Fewest profiles of a usable body [-].
    join_gap_steps : float
        Join a body that stands on another in every profile into one body
        when the height gap between them is at most this many median
        row-to-row steps (rule 2) [-]; 0 keeps stacked bodies apart.

    Raises
    ------
    MeshError
        A value out of its range (named with the reason).
    """

    max_step_mm: float | None = None
    step_factor: float = 20.0
    max_gap_deg: float | None = None
    min_overlap: float = 0.5
    table_z_mm: float | None = None
    table_gap_mm: float = 3.0
    min_points: int = 5
    min_profiles: int = 3
    join_gap_steps: float = 3.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.join_gap_steps) and self.join_gap_steps >= 0):
            raise MeshError(f"model setting join_gap_steps = {self.join_gap_steps!r}: must be a finite number >= 0")
        positive = {"step_factor": self.step_factor, "table_gap_mm": self.table_gap_mm,
                    "max_step_mm": self.max_step_mm, "max_gap_deg": self.max_gap_deg}
        for name, value in positive.items():
            if value is not None and not (math.isfinite(value) and value > 0):
                raise MeshError(f"model setting {name} = {value!r}: must be a finite number > 0")
        if not 0 < self.min_overlap <= 1:
            raise MeshError(f"model setting min_overlap = {self.min_overlap!r}: must be in (0, 1]")
        if self.table_z_mm is not None and not math.isfinite(self.table_z_mm):
            raise MeshError(f"model setting table_z_mm = {self.table_z_mm!r}: must be finite")
        if self.min_points < 2 or self.min_profiles < 3:
            raise MeshError(f"model settings min_points = {self.min_points} (>= 2) and min_profiles = "
                            f"{self.min_profiles} (>= 3) out of range")


@dataclass(frozen=True)
class SurfaceModel:
    """A closed triangle mesh of a scan, with the provenance of every face.

    Parameters
    ----------
    vertices_mm : (nv, 3) float
        Vertices in the part frame [mm]: the measured points, plus the table
        and cap vertices the closing added.
    faces : (m, 3) int
        Triangles, counter-clockwise seen from outside (outward normals).
    face_fill : (m,) uint8
        Fill code of each face (:data:`FILL_NAMES`; 0 = measured).
    face_body : (m,) int
        Body of each face, 0 .. n_bodies − 1.
    n_points_used : int
        Points of the cloud that are vertices of the model [-].
    n_points_unused : int
        Points left out (noise segments, bodies too small) [-].
    step_deg : float
        Angular step of the scan [deg].
    max_step_mm : float
        The profile continuity threshold used [mm].
    """

    vertices_mm: np.ndarray
    faces: np.ndarray
    face_fill: np.ndarray
    face_body: np.ndarray
    n_points_used: int
    n_points_unused: int
    step_deg: float
    max_step_mm: float

    @property
    def n_bodies(self) -> int:
        """Number of bodies [-]."""
        return int(self.face_body.max()) + 1 if len(self.face_body) else 0

    @property
    def measured(self) -> np.ndarray:
        """(m,) bool: faces joining measured neighbours (fill code 0)."""
        return self.face_fill == FILL_MEASURED


# ------------------------------------------------------------------ the grid


@dataclass(frozen=True)
class _Grid:
    """The cloud's points sorted by (frame, row); frames sorted by angle."""

    xyz: np.ndarray          # (n, 3) [mm]
    row: np.ndarray          # (n,) [px]
    frame: np.ndarray        # (n,) compact frame index 0 .. F−1, in angle order
    source: np.ndarray       # (n,) index of each point in the cloud
    angle_deg: np.ndarray    # (F,) angle of each frame, in [0, 360)
    step_deg: float
    periodic: bool


def _frame_keys(cloud) -> np.ndarray:
    frame = getattr(cloud, "frame", None)
    if frame is not None and len(frame) and np.all(np.asarray(frame) >= 0):
        return np.asarray(frame, dtype=np.int64)
    return np.round(np.asarray(cloud.angle_deg, np.float64) * 1e6).astype(np.int64)


def _check_rotary(cloud) -> None:
    if len(cloud) == 0:
        raise MeshError("the scan has no usable frames: no point to build a model from")
    angle, row = np.asarray(cloud.angle_deg, np.float64), np.asarray(cloud.row)
    if not np.all(np.isfinite(angle)) or np.any(row < 0):
        raise MeshError("the point cloud is not a rotary scan: its points carry no rotary angle and "
                        "sensor row (PLY properties angle_deg and row), so there is no grid to mesh; "
                        "a generic cloud needs a generic reconstruction (reconstruct --model-method "
                        "poisson, with the optional Open3D)")


def _build_grid(cloud, max_gap_deg: float | None) -> _Grid:
    _check_rotary(cloud)
    keys = _frame_keys(cloud)
    ukeys, inverse = np.unique(keys, return_inverse=True)
    angle_of_key = np.zeros(len(ukeys))
    angle_of_key[inverse] = np.mod(np.asarray(cloud.angle_deg, np.float64), 360.0)
    if len(ukeys) < 3:
        raise MeshError(f"the scan has {len(ukeys)} usable frame(s): a model needs profiles from "
                        f"at least 3 rotary angles")
    by_angle = np.argsort(angle_of_key, kind="stable")
    rank = np.empty_like(by_angle)
    rank[by_angle] = np.arange(len(by_angle))
    frame = rank[inverse]
    row = np.asarray(cloud.row, np.int64)
    order = np.lexsort((row, frame))
    first = np.ones(len(order), bool)                     # one point per (frame, row)
    first[1:] = (frame[order][1:] != frame[order][:-1]) | (row[order][1:] != row[order][:-1])
    order = order[first]
    angles = angle_of_key[by_angle]
    step = float(np.median(np.diff(angles))) if len(angles) > 1 else 360.0
    gap = max_gap_deg if max_gap_deg is not None else 3.0 * step
    periodic = (360.0 - (angles[-1] - angles[0])) <= gap + 1e-9
    return _Grid(xyz=np.asarray(cloud.xyz_mm, np.float64)[order], row=row[order], frame=frame[order],
                 source=order, angle_deg=angles, step_deg=step, periodic=bool(periodic))


# ------------------------------------------------------------------ segments


@dataclass(frozen=True)
class _Segments:
    """Runs of continuous points of one profile: [start, end) into the grid arrays."""

    start: np.ndarray
    end: np.ndarray
    frame: np.ndarray
    z_lo: np.ndarray
    z_hi: np.ndarray
    mid_xy: np.ndarray       # (k, 2) horizontal position of the middle point [mm]


def _median_row_step(grid: _Grid) -> float:
    d = np.linalg.norm(np.diff(grid.xyz, axis=0), axis=1)
    neighbours = (np.diff(grid.frame) == 0) & (np.diff(grid.row) == 1)
    pool = d[neighbours] if neighbours.any() else d[np.diff(grid.frame) == 0]
    if pool.size == 0:
        raise MeshError("no profile of the scan has two points: nothing to mesh")
    return float(np.median(pool))


def _initial_cuts(grid: _Grid, max_step_mm: float) -> np.ndarray:
    """cut[k]: no join between sorted points k and k + 1 (another frame, or a step > max_step_mm)."""
    d = np.linalg.norm(np.diff(grid.xyz, axis=0), axis=1)
    return (np.diff(grid.frame) != 0) | (d > max_step_mm)


def _real_breaks(grid: _Grid, cut: np.ndarray, lo: int, hi: int, min_points: int) -> list[tuple[int, int]]:
    """Rows (last of one, first of the next) between consecutive runs of >= min_points of one frame.

    Shorter runs between them (a few points on a grazing face, noise) are skipped over.
    """
    edges = np.concatenate([[-1], np.flatnonzero(cut[lo:hi - 1]), [hi - lo - 1]])
    long_runs = np.flatnonzero(np.diff(edges) >= min_points)
    return [(int(grid.row[lo + edges[a + 1]]), int(grid.row[lo + edges[b] + 1]))
            for a, b in zip(long_runs[:-1], long_runs[1:])]


def _cut_like(grid: _Grid, cut: np.ndarray, lo: int, hi: int, rows: tuple[int, int], min_points: int,
              min_step_mm: float) -> None:
    """Cut frame [lo, hi) where a neighbour is cut between ``rows``, at its largest step nearby.

    Only a step of at least ``min_step_mm`` is cut.
    """
    r = grid.row[lo:hi]
    w = max(2, rows[1] - rows[0])
    window = (r[:-1] >= rows[0] - w) & (r[1:] <= rows[1] + w)
    if not window.any() or cut[lo:hi - 1][window].any():
        return
    cuts = np.concatenate([[-1], np.flatnonzero(cut[lo:hi - 1]), [hi - lo - 1]])
    k_all = np.flatnonzero(window)
    seg = np.searchsorted(cuts, k_all, side="left")
    room = (k_all - cuts[seg - 1] >= min_points) & (cuts[seg] - k_all >= min_points)
    if not room.any():
        return
    k_all = k_all[room]
    step = np.linalg.norm(grid.xyz[lo + k_all + 1] - grid.xyz[lo + k_all], axis=1)
    if step.max() >= min_step_mm:
        cut[lo + k_all[np.argmax(step)]] = True


def _propagate_cuts(grid: _Grid, cut: np.ndarray, min_points: int, max_gap_deg: float,
                    max_step_mm: float) -> None:
    """Cut every profile where its neighbour is cut between two real runs (in place).

    A face seen in some frames only (a shoulder reached at some angles) would
    otherwise join two runs in those frames and not in the others; a forward,
    a backward and a second forward sweep carry each break round the turn.
    """
    n = len(grid.angle_deg)
    bounds = np.searchsorted(grid.frame, np.arange(n + 1))
    for step, frames in ((-1, range(n)), (1, range(n - 1, -1, -1)), (-1, range(n))):
        for f in frames:
            g = f + step
            if grid.periodic:
                g %= n
            elif not 0 <= g < n:
                continue
            if min(_angle_gap(grid, f, g), _angle_gap(grid, g, f)) > max_gap_deg + 1e-9:
                continue
            for rows in _real_breaks(grid, cut, bounds[g], bounds[g + 1], min_points):
                _cut_like(grid, cut, bounds[f], bounds[f + 1], rows, min_points, _PROPAGATE * max_step_mm)


def _segments(grid: _Grid, cut: np.ndarray, min_points: int, max_step_mm: float) -> _Segments:
    start = np.concatenate([[0], np.flatnonzero(cut) + 1])
    end = np.concatenate([start[1:], [len(grid.row)]])
    keep = end - start >= min_points
    start, end = start[keep], end[keep]
    if len(start) == 0:
        raise MeshError(f"no profile has {min_points} continuous points (steps ≤ {max_step_mm:.3g} mm): "
                        f"nothing to mesh")
    z = grid.xyz[:, 2]
    z_lo = np.minimum.reduceat(z, start)
    z_hi = np.maximum.reduceat(z, start)
    mid = grid.xyz[(start + end) // 2, :2]
    return _Segments(start=start, end=end, frame=grid.frame[start], z_lo=z_lo, z_hi=z_hi, mid_xy=mid)


# ------------------------------------------------------------------ linking


def _link_score(seg: _Segments, a: int, b: int, pad: float, min_overlap: float, slack_mm: float) -> float:
    """Overlap of segments a and b [mm] if they may be linked, else −1."""
    overlap = min(seg.z_hi[a], seg.z_hi[b]) - max(seg.z_lo[a], seg.z_lo[b]) + pad
    shorter = min(seg.z_hi[a] - seg.z_lo[a], seg.z_hi[b] - seg.z_lo[b]) + pad
    if overlap < min_overlap * shorter:
        return -1.0
    if np.hypot(*(seg.mid_xy[a] - seg.mid_xy[b])) > slack_mm:
        return -1.0
    return overlap


def _frame_ranges(seg: _Segments, n_frames: int) -> tuple[np.ndarray, np.ndarray]:
    lo = np.searchsorted(seg.frame, np.arange(n_frames), side="left")
    hi = np.searchsorted(seg.frame, np.arange(n_frames), side="right")
    return lo, hi


def _angle_gap(grid: _Grid, f: int, g: int) -> float:
    return float(np.mod(grid.angle_deg[g] - grid.angle_deg[f], 360.0)) or 360.0


def _match_frames(grid, seg, ranges, f, g, succ, pred, settings, max_step) -> None:
    """Link free segments of frame f to free segments of frame g, largest overlap first."""
    gap_rad = math.radians(_angle_gap(grid, f, g))
    cands = []
    for a in range(ranges[0][f], ranges[1][f]):
        if succ[a] >= 0:
            continue
        r = float(np.hypot(*seg.mid_xy[a]))
        slack = max_step + _LINK_INCIDENCE * r * gap_rad
        for b in range(ranges[0][g], ranges[1][g]):
            if pred[b] < 0:
                score = _link_score(seg, a, b, max_step, settings.min_overlap, slack)
                if score >= 0:
                    cands.append((score, a, b))
    for _, a, b in sorted(cands, reverse=True):
        if succ[a] < 0 and pred[b] < 0:
            succ[a], pred[b] = b, a


def _link(grid: _Grid, seg: _Segments, settings: ModelSettings, max_step: float,
          max_gap_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Successor / predecessor of every segment (−1: none)."""
    n_frames = len(grid.angle_deg)
    ranges = _frame_ranges(seg, n_frames)
    succ = np.full(len(seg.start), -1)
    pred = np.full(len(seg.start), -1)
    last = n_frames if grid.periodic else n_frames - 1
    for skip in range(1, n_frames):
        any_pair = False
        for f in range(last):
            g = f + skip if not grid.periodic else (f + skip) % n_frames
            if g >= n_frames or _angle_gap(grid, f, g) > max_gap_deg + 1e-9:
                continue
            any_pair = True
            _match_frames(grid, seg, ranges, f, g, succ, pred, settings, max_step)
        if not any_pair:
            break
    return succ, pred


def _chains(succ: np.ndarray, pred: np.ndarray) -> list[tuple[list[int], bool]]:
    """Paths (from segments without a predecessor) and cycles of the link graph."""
    seen = np.zeros(len(succ), bool)
    out = []
    for start in [*np.flatnonzero(pred < 0), *range(len(succ))]:
        if seen[start]:
            continue
        chain, s = [], int(start)
        while s >= 0 and not seen[s]:
            seen[s] = True
            chain.append(s)
            s = int(succ[s])
        out.append((chain, s == chain[0] and pred[start] >= 0))
    return out


# ------------------------------------------------------------------ closing a body


def _zipper(ka: np.ndarray, kb: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Merge two increasing key sequences into a strip of triangles.

    Returns, per triangle, the index into A and into B of its first two
    vertices and whether the third is the next vertex of A (else of B).
    """
    keys = np.concatenate([ka[1:], kb[1:]])
    is_a = np.concatenate([np.ones(len(ka) - 1, bool), np.zeros(len(kb) - 1, bool)])
    order = np.lexsort((~is_a, keys))
    is_a = is_a[order]
    a_prev = np.cumsum(is_a) - is_a
    b_prev = np.cumsum(~is_a) - ~is_a
    return a_prev, b_prev, is_a


def _strip(ia, ka, ib, kb) -> np.ndarray:
    """(t, 3) triangles joining profile A (vertex ids ia, keys ka) to profile B."""
    a, b, is_a = _zipper(ka, kb)
    third = np.where(is_a, ia[np.minimum(a + 1, len(ia) - 1)], ib[np.minimum(b + 1, len(ib) - 1)])
    return np.stack([ia[a], ib[b], third], axis=1)


@dataclass
class _Body:
    """Vertices and faces of one body under construction (local vertex ids)."""

    xyz: list
    faces: list
    fill: list
    part: list               # per profile: which of its stacked segments each point belongs to
    n_vertices: int = 0

    def add_vertices(self, xyz: np.ndarray) -> np.ndarray:
        ids = np.arange(self.n_vertices, self.n_vertices + len(xyz))
        self.xyz.append(np.asarray(xyz, np.float64).reshape(-1, 3))
        self.n_vertices += len(xyz)
        return ids

    def add_faces(self, faces: np.ndarray, fill) -> None:
        self.faces.append(np.asarray(faces, np.int64).reshape(-1, 3))
        self.fill.append(np.broadcast_to(np.asarray(fill, np.uint8), (len(self.faces[-1]),)))


def _profiles(grid: _Grid, seg: _Segments, chain: list[list[int]], body: _Body):
    """Per profile (its segments in row order): vertex ids, row keys; and whether rows run downwards."""
    ids, keys = [], []
    for prof in chain:
        idx = np.concatenate([np.arange(seg.start[s], seg.end[s]) for s in prof])
        ids.append(body.add_vertices(grid.xyz[idx]))
        keys.append(grid.row[idx].astype(np.float64))
        body.part.append(np.repeat(np.arange(len(prof)), seg.end[prof] - seg.start[prof]))
    z_first = np.mean([grid.xyz[seg.start[p[0]], 2] for p in chain])
    z_last = np.mean([grid.xyz[seg.end[p[-1]] - 1, 2] for p in chain])
    return ids, keys, bool(z_last < z_first)


def _stack_gap(grid: _Grid, seg: _Segments, upper: dict, lower: dict) -> float:
    """Median height of the gap from each profile of ``upper`` down to ``lower`` (frame → segments) [mm].

    +inf unless ``upper`` lies above ``lower`` (in rows) in every frame.
    """
    gaps = []
    for f, up in upper.items():
        lo = lower[f]
        if grid.row[seg.end[up[-1]] - 1] >= grid.row[seg.start[lo[0]]]:
            return math.inf
        gaps.append(grid.xyz[seg.end[up[-1]] - 1, 2] - grid.xyz[seg.start[lo[0]], 2])
    return float(np.median(gaps))


def _join_stacked(grid: _Grid, seg: _Segments, bodies: list, max_gap_mm: float) -> list:
    """Join cyclic bodies that stand on each other in every frame into one (module docstring, rule 2)."""
    bodies = list(bodies)
    joined = True
    while joined:
        joined = False
        for a, b in ((a, b) for a in range(len(bodies)) for b in range(len(bodies)) if a != b):
            (ca, cyc_a), (cb, cyc_b) = bodies[a], bodies[b]
            ma = {int(seg.frame[p[0]]): p for p in ca}
            mb = {int(seg.frame[p[0]]): p for p in cb}
            if not (cyc_a and cyc_b and ma.keys() == mb.keys() and len(ma) == len(ca) == len(cb)):
                continue
            if abs(_stack_gap(grid, seg, ma, mb)) <= max_gap_mm:
                bodies[a] = ([ma[int(seg.frame[p[0]])] + mb[int(seg.frame[p[0]])] for p in ca], True)
                del bodies[b]
                joined = True
                break
    return bodies


def _add_table_skirt(body: _Body, ids, keys, down: bool, table_z: float) -> None:
    """Carry every profile's bottom point straight down to the table (in place)."""
    k_extra = (max(k[-1] for k in keys) + 1.0) if down else (min(k[0] for k in keys) - 1.0)
    xyz = np.concatenate(body.xyz)
    for j in range(len(ids)):
        end = ids[j][-1] if down else ids[j][0]
        foot = body.add_vertices(np.array([[*xyz[end, :2], table_z]]))
        if down:
            ids[j], keys[j] = np.append(ids[j], foot), np.append(keys[j], k_extra)
        else:
            ids[j], keys[j] = np.insert(ids[j], 0, foot), np.insert(keys[j], 0, k_extra)


def _bottom_on_table(body: _Body, ids, down: bool, settings: ModelSettings) -> bool:
    if settings.table_z_mm is None:
        return False
    xyz = np.concatenate(body.xyz)
    bottom = xyz[[i[-1] if down else i[0] for i in ids], 2]
    return bool(abs(np.median(bottom) - settings.table_z_mm) <= settings.table_gap_mm)


def _fill_of_strips(tri: np.ndarray, strip_fill: np.ndarray, rows_of, part_of, n_measured: int) -> np.ndarray:
    """Fill code of strip triangles.

    Measured: three measured points of neighbouring rows of one segment, in
    neighbouring frames; table: a table vertex; side; else gap.
    """
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    ra, rb, rc = rows_of[a], rows_of[b], rows_of[c]
    span = np.maximum(np.maximum(ra, rb), rc) - np.minimum(np.minimum(ra, rb), rc)
    same_part = (part_of[a] == part_of[b]) & (part_of[b] == part_of[c])
    table = (a >= n_measured) | (b >= n_measured) | (c >= n_measured)
    measured = (strip_fill == FILL_MEASURED) & (span <= _MEASURED_ROW_SPAN) & same_part
    fill = np.where(measured, FILL_MEASURED, np.where(strip_fill == FILL_SIDE, FILL_SIDE, FILL_GAP))
    return np.where(table & (fill != FILL_SIDE), FILL_TABLE, fill).astype(np.uint8)


def _strips(body, ids, keys, angles, cyclic, step_deg, n_measured) -> None:
    """Strips between neighbouring profiles (and the closing strip of a path)."""
    rows_of = np.zeros(body.n_vertices)
    rows_of[np.concatenate(ids)] = np.concatenate(keys)
    part_of = np.zeros(body.n_vertices, np.int64)
    part_of[:n_measured] = np.concatenate(body.part)
    tris, fills = [], []
    m = len(ids)
    for j in range(m):
        k = (j + 1) % m
        tris.append(_strip(ids[j], keys[j], ids[k], keys[k]))
        if k == 0 and not cyclic:
            fills.append(np.full(len(tris[-1]), FILL_SIDE, np.uint8))
        else:
            neighbours = np.mod(angles[k] - angles[j], 360.0) <= 1.5 * step_deg
            fills.append(np.full(len(tris[-1]), FILL_MEASURED if neighbours else FILL_GAP, np.uint8))
    tri = np.concatenate(tris)
    body.add_faces(tri, _fill_of_strips(tri, np.concatenate(fills), rows_of, part_of, n_measured))


def _cap(body: _Body, loop: np.ndarray, reverse: bool, z: float | None, around_axis: bool, fill: int) -> None:
    """Close the loop of vertex ids (in profile order) by a fan from its centre."""
    xyz = np.concatenate(body.xyz)[loop]
    centre = np.array([0.0, 0.0, 0.0]) if around_axis else xyz.mean(axis=0)
    centre[2] = xyz[:, 2].mean() if z is None else z
    c = body.add_vertices(centre[None])[0]
    nxt = np.roll(loop, -1)
    tri = np.stack([nxt, loop, np.full(len(loop), c)], 1) if not reverse else \
        np.stack([loop, nxt, np.full(len(loop), c)], 1)
    body.add_faces(tri, fill)


def _winds_round_axis(xyz: np.ndarray, angles_deg: np.ndarray) -> bool:
    """Whether a cyclic loop of profile points is star-shaped about the axis (all on one side)."""
    th = np.radians(angles_deg)
    sheet = xyz[:, 0] * np.cos(th) - xyz[:, 1] * np.sin(th)
    return bool(np.all(sheet < 0) or np.all(sheet > 0))


def _close_body(grid: _Grid, seg: _Segments, chain: list[list[int]], cyclic: bool,
                settings: ModelSettings) -> _Body:
    body = _Body([], [], [], [])
    ids, keys, down = _profiles(grid, seg, chain, body)
    n_measured = body.n_vertices
    angles = grid.angle_deg[seg.frame[[p[0] for p in chain]]]
    starts = np.array([i[0] for i in ids])
    ends = np.array([i[-1] for i in ids])
    xyz = np.concatenate(body.xyz)
    around = cyclic and _winds_round_axis(xyz[starts], angles) and _winds_round_axis(xyz[ends], angles)
    on_table = _bottom_on_table(body, ids, down, settings)
    if on_table:
        _add_table_skirt(body, ids, keys, down, settings.table_z_mm)
    _strips(body, ids, keys, angles, cyclic, grid.step_deg, n_measured)
    starts = np.array([i[0] for i in ids])
    ends = np.array([i[-1] for i in ids])
    bottom_z = settings.table_z_mm if on_table else None
    _cap(body, starts, False, None if down else bottom_z, around,
         FILL_TABLE if (on_table and not down) else FILL_CAP)
    _cap(body, ends, True, bottom_z if down else None, around,
         FILL_TABLE if (on_table and down) else FILL_CAP)
    return body


@numba.njit(cache=True)
def _signed_volume(xyz: np.ndarray, faces: np.ndarray) -> float:
    total = 0.0
    for i in range(faces.shape[0]):
        a, b, c = xyz[faces[i, 0]], xyz[faces[i, 1]], xyz[faces[i, 2]]
        total += (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
                  + a[2] * (b[0] * c[1] - b[1] * c[0]))
    return total / 6.0


# ------------------------------------------------------------------ entry point


def model_from_cloud(cloud, settings: ModelSettings | None = None) -> SurfaceModel:
    """Watertight surface model of a rotary scan's point cloud (module docstring: the rule).

    Parameters
    ----------
    cloud : scheimpflug.reconstruct.PointCloud
        Points in the part frame [mm] with their rotary angle [deg], sensor
        row [px] and (optionally) frame index: the scan's grid.
    settings : ModelSettings, optional
        Parameters of the rule (defaults: :class:`ModelSettings`; give the
        table height for a bottom closed on the table).

    Returns
    -------
    SurfaceModel
        Closed, outward-oriented triangle mesh, one closed shell per body, with
        a fill code and a body index per face.

    Raises
    ------
    MeshError
        An empty scan, fewer than 3 rotary angles, a cloud without rotary
        provenance (not a rotary scan), or no usable profile segment.
    """
    settings = settings or ModelSettings()
    grid = _build_grid(cloud, settings.max_gap_deg)
    row_step = _median_row_step(grid)
    max_step = settings.max_step_mm or settings.step_factor * row_step
    max_gap = settings.max_gap_deg if settings.max_gap_deg is not None else 3.0 * grid.step_deg
    cut = _initial_cuts(grid, max_step)
    _propagate_cuts(grid, cut, settings.min_points, max_gap, max_step)
    seg = _segments(grid, cut, settings.min_points, max_step)
    succ, pred = _link(grid, seg, settings, max_step, max_gap)
    bodies = [([[s] for s in c], cyc) for c, cyc in _chains(succ, pred) if len(c) >= settings.min_profiles]
    if settings.join_gap_steps > 0:
        bodies = _join_stacked(grid, seg, bodies, settings.join_gap_steps * row_step)
    if not bodies:
        raise MeshError(f"no body is seen in {settings.min_profiles} or more neighbouring profiles: "
                        f"nothing to mesh")
    return _assemble(grid, seg, bodies, settings, max_step)


def _assemble(grid, seg, bodies, settings, max_step) -> SurfaceModel:
    xyz, faces, fill, body_of, offset, used = [], [], [], [], 0, 0
    for k, (chain, cyclic) in enumerate(bodies):
        b = _close_body(grid, seg, chain, cyclic, settings)
        v, f = np.concatenate(b.xyz), np.concatenate(b.faces)
        if _signed_volume(v, f) < 0:
            f = f[:, [0, 2, 1]]
        xyz.append(v)
        faces.append(f + offset)
        fill.append(np.concatenate(b.fill))
        body_of.append(np.full(len(f), k, np.int64))
        offset += len(v)
        used += int(sum(seg.end[s] - seg.start[s] for p in chain for s in p))
    return SurfaceModel(vertices_mm=np.concatenate(xyz), faces=np.concatenate(faces),
                        face_fill=np.concatenate(fill).astype(np.uint8), face_body=np.concatenate(body_of),
                        n_points_used=used, n_points_unused=int(len(grid.row) - used),
                        step_deg=grid.step_deg, max_step_mm=float(max_step))
