"""Scoring a point cloud against the true surface: point-to-mesh distances.

The distance of every measured point to the nearest point of a triangle mesh
is computed exactly (not to the nearest vertex) with a bounding-volume
hierarchy compiled by numba and queried in parallel.  When the mesh is closed
(watertight, consistently wound) the distance is signed, positive outside the
material and negative inside, by the angle-weighted pseudo-normal of the
nearest feature (face, edge or vertex) of the nearest triangle, which gives the
correct sign for every point of a closed mesh (Bærentzen & Aanæs 2005).

Two-sided scoring (a surface model against the truth) samples both surfaces
area-uniformly with a seed and measures each set against the other mesh:
the truth → model distances say how much of the true surface the model
covers (``coverage``: the share within 0.1 mm), the model → truth distances
how far the model strays; the symmetric Hausdorff distance is the larger of
the two maxima over the samples, the symmetric mean the average of the two
means.

Statistics follow docs/reference/interface.md: ``n_points``, ``rms_mm``, ``mean_abs_mm``,
``p95_mm``, ``max_mm`` (all on the distance magnitude), plus the signed mean
and standard deviation when the sign is known, and a per-body breakdown when
the faces carry an object id (or the mesh has several connected bodies).

References
----------
J. A. Bærentzen, H. Aanæs, "Signed distance computation using the angle
weighted pseudonormal", IEEE TVCG 11(3), 2005.
C. Ericson, *Real-Time Collision Detection*, 2005, §5.1.5 (closest point on a
triangle).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from scheimpflug.errors import MeshError

__all__ = [
    "MAX_COORDINATE_MM",
    "MeshDistance",
    "PointToMesh",
    "TwoSidedDistance",
    "body_labels",
    "distance_stats",
    "is_closed_mesh",
    "point_to_mesh",
    "sample_surface",
    "placement_mismatch",
    "scale_mismatch",
    "score_points",
    "two_sided_distance",
]

MAX_COORDINATE_MM = 1e12
"""Largest |coordinate| of a point or a mesh vertex that can be scored [mm] (1000 km: no part is
larger; squared distances of coordinates beyond ≈ 1e154 overflow float64)."""

UNIT_FACTORS = (("metres", 1000.0), ("inches", 25.4), ("cm", 10.0))
"""Units whose factor to mm a cloud-to-mesh size ratio is compared with (:func:`scale_mismatch`)."""
_UNIT_MATCH = 0.15      # a size ratio within 15 % of a unit factor names the unit [-]
_GROSS_RATIO = 30.0     # a size ratio beyond this (either way) is a mismatch whatever the unit [-]
OFF_MESH_FRACTION = 0.05
"""A cloud whose median point-to-mesh distance exceeds this share of the mesh's size lies off the mesh
(:func:`placement_mismatch`) [-]."""

_LEAF_SIZE = 4          # triangles per BVH leaf: 4 balances box tests against triangle tests
_STACK = 128            # traversal stack depth; a median-split tree on 1e9 faces is < 64 deep
_BLOCK = 256            # points per parallel work item (the previous face seeds the next query)
_VERTEX, _EDGE, _FACE = 0, 3, 6   # region codes: vertex k -> k, edge k (v_k -> v_k+1) -> 3 + k, face -> 6


# --------------------------------------------------------------------------- numba kernels


@numba.njit(cache=True)
def _build_bvh(tri_min, tri_max, centroid, leaf_size):
    """Median-split BVH over triangle boxes; returns node arrays and the face order."""
    n = centroid.shape[0]
    order = np.arange(n)
    max_nodes = 2 * n + 1
    node_min = np.empty((max_nodes, 3))
    node_max = np.empty((max_nodes, 3))
    child = np.full(max_nodes, -1, dtype=np.int64)     # left child; right = child + 1
    start = np.zeros(max_nodes, dtype=np.int64)
    count = np.zeros(max_nodes, dtype=np.int64)
    stack = np.empty((128, 3), dtype=np.int64)
    stack[0, 0], stack[0, 1], stack[0, 2] = 0, 0, n
    sp, n_nodes = 1, 1
    while sp > 0:
        sp -= 1
        node, s, e = stack[sp, 0], stack[sp, 1], stack[sp, 2]
        lo = np.full(3, np.inf)
        hi = np.full(3, -np.inf)
        clo = np.full(3, np.inf)
        chi = np.full(3, -np.inf)
        for i in range(s, e):
            t = order[i]
            for k in range(3):
                lo[k] = min(lo[k], tri_min[t, k])
                hi[k] = max(hi[k], tri_max[t, k])
                clo[k] = min(clo[k], centroid[t, k])
                chi[k] = max(chi[k], centroid[t, k])
        node_min[node] = lo
        node_max[node] = hi
        if e - s <= leaf_size:
            start[node], count[node] = s, e - s
            continue
        axis = np.argmax(chi - clo)
        seg = order[s:e].copy()
        order[s:e] = seg[np.argsort(centroid[seg, axis], kind="mergesort")]
        mid = (s + e) // 2
        child[node] = n_nodes
        stack[sp, 0], stack[sp, 1], stack[sp, 2] = n_nodes, s, mid
        stack[sp + 1, 0], stack[sp + 1, 1], stack[sp + 1, 2] = n_nodes + 1, mid, e
        sp += 2
        n_nodes += 2
    return node_min[:n_nodes], node_max[:n_nodes], child[:n_nodes], start[:n_nodes], count[:n_nodes], order


@numba.njit(cache=True, inline="always")
def _closest_on_segment(px, py, pz, ax, ay, az, bx, by, bz):
    """Closest point of segment ab to p, and its parameter t in [0, 1] (0 for a point)."""
    dx, dy, dz = bx - ax, by - ay, bz - az
    dd = dx * dx + dy * dy + dz * dz
    t = 0.0
    if dd > 0.0:
        t = min(max(((px - ax) * dx + (py - ay) * dy + (pz - az) * dz) / dd, 0.0), 1.0)
    return ax + t * dx, ay + t * dy, az + t * dz, t


@numba.njit(cache=True)
def _closest_on_degenerate(px, py, pz, ax, ay, az, bx, by, bz, cx, cy, cz):
    """Closest point of a zero-area triangle (a segment or a point): the nearest of its edges."""
    best, out = np.inf, (ax, ay, az, 0)
    edges = ((ax, ay, az, bx, by, bz, 3, 0, 1), (bx, by, bz, cx, cy, cz, 4, 1, 2),
             (cx, cy, cz, ax, ay, az, 5, 2, 0))
    for e in edges:
        qx, qy, qz, t = _closest_on_segment(px, py, pz, e[0], e[1], e[2], e[3], e[4], e[5])
        d2 = (qx - px) ** 2 + (qy - py) ** 2 + (qz - pz) ** 2
        if d2 < best:
            code = e[7] if t <= 0.0 else (e[8] if t >= 1.0 else e[6])
            best, out = d2, (qx, qy, qz, code)
    return out


@numba.njit(cache=True, inline="always")
def _closest_on_triangle(px, py, pz, ax, ay, az, bx, by, bz, cx, cy, cz):
    """Closest point of triangle abc to p and the feature it lies on (Ericson §5.1.5).

    A zero-area triangle (collinear or coincident corners) is a segment or a point:
    the nearest point of its edges (:func:`_closest_on_degenerate`).
    """
    abx, aby, abz = bx - ax, by - ay, bz - az
    acx, acy, acz = cx - ax, cy - ay, cz - az
    nx, ny, nz = aby * acz - abz * acy, abz * acx - abx * acz, abx * acy - aby * acx
    if nx * nx + ny * ny + nz * nz == 0.0:
        return _closest_on_degenerate(px, py, pz, ax, ay, az, bx, by, bz, cx, cy, cz)
    apx, apy, apz = px - ax, py - ay, pz - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        return ax, ay, az, 0
    bpx, bpy, bpz = px - bx, py - by, pz - bz
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    if d3 >= 0.0 and d4 <= d3:
        return bx, by, bz, 1
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        v = d1 / (d1 - d3)
        return ax + v * abx, ay + v * aby, az + v * abz, 3
    cpx, cpy, cpz = px - cx, py - cy, pz - cz
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    if d6 >= 0.0 and d5 <= d6:
        return cx, cy, cz, 2
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        w = d2 / (d2 - d6)
        return ax + w * acx, ay + w * acy, az + w * acz, 5
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return bx + w * (cx - bx), by + w * (cy - by), bz + w * (cz - bz), 4
    den = va + vb + vc
    if den <= 0.0:                       # degenerate (zero-area) triangle
        return ax, ay, az, 0
    v = vb / den
    w = vc / den
    return ax + abx * v + acx * w, ay + aby * v + acy * w, az + abz * v + acz * w, 6


@numba.njit(cache=True, inline="always")
def _box_dist2(px, py, pz, lo, hi):
    dx = max(lo[0] - px, 0.0, px - hi[0])
    dy = max(lo[1] - py, 0.0, py - hi[1])
    dz = max(lo[2] - pz, 0.0, pz - hi[2])
    return dx * dx + dy * dy + dz * dz


@numba.njit(cache=True, inline="always")
def _tri_dist2(px, py, pz, tri, f):
    cx, cy, cz, code = _closest_on_triangle(
        px, py, pz, tri[f, 0, 0], tri[f, 0, 1], tri[f, 0, 2], tri[f, 1, 0], tri[f, 1, 1],
        tri[f, 1, 2], tri[f, 2, 0], tri[f, 2, 1], tri[f, 2, 2])
    dx, dy, dz = px - cx, py - cy, pz - cz
    return dx * dx + dy * dy + dz * dz, cx, cy, cz, code


@numba.njit(cache=True, parallel=True)
def _query(points, visit, tri, node_min, node_max, child, start, count, order,
           out_d2, out_face, out_code, out_closest):
    n = points.shape[0]
    n_blocks = (n + _BLOCK - 1) // _BLOCK
    for b in numba.prange(n_blocks):
        stack = np.empty(_STACK, dtype=np.int64)
        stack_d2 = np.empty(_STACK)
        hint = order[0]
        for k in range(b * _BLOCK, min(n, (b + 1) * _BLOCK)):
            i = visit[k]
            px, py, pz = points[i, 0], points[i, 1], points[i, 2]
            best, cx, cy, cz, code = _tri_dist2(px, py, pz, tri, hint)
            best_f = hint
            stack[0] = 0
            stack_d2[0] = 0.0
            sp = 1
            while sp > 0:
                sp -= 1
                node = stack[sp]
                if stack_d2[sp] >= best:
                    continue
                if child[node] < 0:
                    for j in range(start[node], start[node] + count[node]):
                        f = order[j]
                        d2, qx, qy, qz, qc = _tri_dist2(px, py, pz, tri, f)
                        if d2 < best:
                            best, cx, cy, cz, code, best_f = d2, qx, qy, qz, qc, f
                    continue
                left = child[node]
                dl = _box_dist2(px, py, pz, node_min[left], node_max[left])
                dr = _box_dist2(px, py, pz, node_min[left + 1], node_max[left + 1])
                near, far, dn, df = left, left + 1, dl, dr
                if dr < dl:
                    near, far, dn, df = left + 1, left, dr, dl
                if df < best:
                    stack[sp] = far
                    stack_d2[sp] = df
                    sp += 1
                if dn < best:
                    stack[sp] = near
                    stack_d2[sp] = dn
                    sp += 1
            out_d2[i] = best
            out_face[i] = best_f
            out_code[i] = code
            out_closest[i, 0], out_closest[i, 1], out_closest[i, 2] = cx, cy, cz
            hint = best_f


@numba.njit(cache=True)
def _spread_bits(x):
    """Spread the low 21 bits of ``x`` to every third bit (Morton code)."""
    x &= 0x1FFFFF
    x = (x | (x << 32)) & 0x1F00000000FFFF
    x = (x | (x << 16)) & 0x1F0000FF0000FF
    x = (x | (x << 8)) & 0x100F00F00F00F00F
    x = (x | (x << 4)) & 0x10C30C30C30C30C3
    x = (x | (x << 2)) & 0x1249249249249249
    return x


@numba.njit(cache=True, parallel=True)
def _morton_keys(points):
    lo = np.empty(3)
    scale = np.empty(3)
    for k in range(3):
        lo[k] = points[:, k].min()
        span = points[:, k].max() - lo[k]
        scale[k] = (2 ** 21 - 1) / span if span > 0 else 0.0
    keys = np.empty(points.shape[0], dtype=np.int64)
    for i in numba.prange(points.shape[0]):
        key = 0
        for k in range(3):
            key |= _spread_bits(np.int64((points[i, k] - lo[k]) * scale[k])) << k
        keys[i] = key
    return keys


# --------------------------------------------------------------------------- mesh preparation


def _check_mesh(vertices, faces) -> tuple[np.ndarray, np.ndarray]:
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) < 3:
        raise MeshError(f"mesh vertices must be an (n >= 3, 3) array, got shape {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
        raise MeshError(f"mesh faces must be an (m >= 1, 3) array of triangles, got shape {f.shape}")
    if not np.issubdtype(f.dtype, np.integer) or f.min() < 0 or f.max() >= len(v):
        raise MeshError("mesh faces must index existing vertices")
    if not np.all(np.isfinite(v)):
        raise MeshError("mesh vertices contain NaN or infinite coordinates")
    if np.abs(v).max() > MAX_COORDINATE_MM:
        raise MeshError(f"mesh vertices reach {np.abs(v).max():.3g} mm: beyond ±{MAX_COORDINATE_MM:g} mm "
                        "nothing can be scored (not a part in mm)")
    return v, f.astype(np.int64)


def is_closed_mesh(faces: np.ndarray) -> bool:
    """Whether every edge is shared by exactly two faces traversing it in opposite directions.

    Parameters
    ----------
    faces : (m, 3) int
        Triangle vertex indices.

    Returns
    -------
    bool
        True for a watertight, consistently wound mesh (a valid sign of distance).
    """
    f = np.asarray(faces, dtype=np.int64)
    n = int(f.max()) + 1
    a, b = f.ravel(), np.roll(f, -1, axis=1).ravel()       # directed edges v_k -> v_k+1
    key = np.sort(a * n + b)
    if np.any(key[1:] == key[:-1]):
        return False                      # an edge used twice in the same direction
    rev = b * n + a
    pos = np.minimum(np.searchsorted(key, rev), len(key) - 1)
    return bool(np.all(key[pos] == rev))


def _pseudo_normals(v: np.ndarray, f: np.ndarray):
    """Face normals, per-face edge pseudo-normals and angle-weighted vertex pseudo-normals."""
    tri = v[f]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(fn, axis=1, keepdims=True)
    fn = np.divide(fn, norm, out=np.zeros_like(fn), where=norm > 0)
    vn = np.zeros_like(v)
    for k in range(3):
        e1 = tri[:, (k + 1) % 3] - tri[:, k]
        e2 = tri[:, (k + 2) % 3] - tri[:, k]
        cosang = np.einsum("ij,ij->i", e1, e2) / np.maximum(
            np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1), 1e-300)
        vn += _scatter_add(f[:, k], fn * np.arccos(np.clip(cosang, -1.0, 1.0))[:, None], len(v))
    a, b = f.ravel(), np.roll(f, -1, axis=1).ravel()       # edge k of a face: v_k -> v_k+1
    _, inverse = np.unique(np.minimum(a, b) * len(v) + np.maximum(a, b), return_inverse=True)
    en = _scatter_add(inverse.ravel(), np.repeat(fn, 3, axis=0), int(inverse.max()) + 1)
    return fn, en[inverse.reshape(-1, 3)], vn


def _scatter_add(index: np.ndarray, values: np.ndarray, size: int) -> np.ndarray:
    """``out[index[i]] += values[i]`` for (n, 3) values (np.add.at, faster)."""
    return np.stack([np.bincount(index, weights=values[:, k], minlength=size) for k in range(3)], axis=1)


def body_labels(faces: np.ndarray) -> np.ndarray:
    """Connected component (body) of every face, faces linked through shared vertices.

    Parameters
    ----------
    faces : (m, 3) array_like int
        Triangle vertex indices.

    Returns
    -------
    (m,) ndarray int64
        Body index per face, 0 .. n_bodies - 1, numbered by first appearance.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    f = np.asarray(faces, dtype=np.int64)
    n_v = int(f.max()) + 1
    rows = np.repeat(np.arange(len(f)), 3)
    graph = coo_matrix((np.ones(rows.size), (rows, f.ravel())), shape=(len(f), n_v)).tocsr()
    _, vlab = connected_components(graph.T @ graph, directed=False)
    flab = vlab[f[:, 0]]
    _, first = np.unique(flab, return_index=True)
    renumber = np.empty(flab.max() + 1, dtype=np.int64)
    renumber[flab[np.sort(first)]] = np.arange(len(first))
    return renumber[flab]


@dataclass(frozen=True)
class MeshDistance:
    """Point-to-mesh distances of a set of points (:meth:`PointToMesh.query`).

    Parameters
    ----------
    distance_mm : (n,) ndarray float64
        Distance to the mesh [mm]; signed (positive outside) when ``signed``.
    face : (n,) ndarray int64
        Index of the nearest face.
    closest_mm : (n, 3) ndarray float64
        Nearest point on the mesh, in the mesh's frame [mm].
    signed : bool
        Whether ``distance_mm`` carries a sign (mesh closed and consistently wound).
    """

    distance_mm: np.ndarray
    face: np.ndarray
    closest_mm: np.ndarray
    signed: bool


class PointToMesh:
    """A triangle mesh prepared for fast exact point-to-mesh distance queries.

    Parameters
    ----------
    vertices : (nv, 3) array_like float
        Vertex positions [mm], nv >= 3, all finite.
    faces : (m, 3) array_like int
        Triangles (vertex indices), m >= 1; counter-clockwise seen from outside
        for a closed mesh (an inward-wound closed mesh is detected by its
        negative volume and handled).
    signed : bool
        Sign the distances of a closed mesh (default); False skips the
        closedness test and the pseudo-normals (unsigned distances, faster
        to build).

    Attributes
    ----------
    vertices : (nv, 3) ndarray float64
        Vertex positions [mm].
    faces : (m, 3) ndarray int64
        Triangles.
    triangles : (m, 3, 3) ndarray float64
        Corner positions of every triangle [mm].
    closed : bool
        Whether the mesh is closed and consistently wound
        (:func:`is_closed_mesh`): then distances are signed.

    Raises
    ------
    MeshError
        If the arrays have the wrong shape, faces index missing vertices or
        are not integers, or a vertex is not finite or beyond
        :data:`MAX_COORDINATE_MM`.

    Notes
    -----
    Building the tree costs about 1 s per million faces; queries run at
    several million points per second on two cores for points near the
    surface (see ``benchmarks/bench_scoring.py``).
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, signed: bool = True) -> None:
        v, f = _check_mesh(vertices, faces)
        self.vertices, self.faces = v, f
        self.triangles = np.ascontiguousarray(v[f])
        self.closed = bool(signed) and is_closed_mesh(f)
        lo, hi = self.triangles.min(axis=1), self.triangles.max(axis=1)
        (self._node_min, self._node_max, self._child, self._start, self._count,
         self._order) = _build_bvh(lo, hi, self.triangles.mean(axis=1), _LEAF_SIZE)
        self._normals = _pseudo_normals(v, f) if self.closed else None
        self._orientation = 1.0
        if self.closed and _signed_volume(self.triangles) < 0:
            self._orientation = -1.0

    def query(self, points: np.ndarray) -> MeshDistance:
        """Exact distances of points to the mesh.

        Parameters
        ----------
        points : (n, 3) array_like float
            Query points in the mesh's frame [mm], all finite.

        Returns
        -------
        MeshDistance
            Distance (signed when the mesh is closed), nearest face and point.

        Raises
        ------
        ValueError
            If ``points`` is not (n, 3) or holds NaN or infinite coordinates, or
            coordinates beyond :data:`MAX_COORDINATE_MM`.
        """
        p = np.ascontiguousarray(points, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3:
            raise ValueError(f"points must be an (n, 3) array, got shape {p.shape}")
        if not np.all(np.isfinite(p)):
            raise ValueError("points contain NaN or infinite coordinates")
        if p.size and np.abs(p).max() > MAX_COORDINATE_MM:
            raise ValueError(f"points reach {np.abs(p).max():.3g} mm, beyond ±{MAX_COORDINATE_MM:g} mm")
        n = len(p)
        d2, face = np.empty(n), np.empty(n, dtype=np.int64)
        code, closest = np.empty(n, dtype=np.int64), np.empty((n, 3))
        if n:
            # spatially coherent order: each query starts from the previous point's face
            visit = np.argsort(_morton_keys(p), kind="stable")
            _query(p, visit, self.triangles, self._node_min, self._node_max, self._child,
                   self._start, self._count, self._order, d2, face, code, closest)
        dist = np.sqrt(d2)
        if self.closed:
            dist = dist * self._sign(p, face, code, closest)
        return MeshDistance(distance_mm=dist, face=face, closest_mm=closest, signed=self.closed)

    def _sign(self, p, face, code, closest) -> np.ndarray:
        fn, en, vn = self._normals
        normal = fn[face].copy()
        on_edge = (code >= _EDGE) & (code < _FACE)
        normal[on_edge] = en[face[on_edge], code[on_edge] - _EDGE]
        on_vertex = code < _EDGE
        normal[on_vertex] = vn[self.faces[face[on_vertex], code[on_vertex]]]
        s = np.einsum("ij,ij->i", p - closest, normal) * self._orientation
        return np.where(s < 0, -1.0, 1.0)


def _signed_volume(tri: np.ndarray) -> float:
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    det = (a[:, 0] * (b[:, 1] * c[:, 2] - b[:, 2] * c[:, 1]) - a[:, 1] * (b[:, 0] * c[:, 2] - b[:, 2] * c[:, 0])
           + a[:, 2] * (b[:, 0] * c[:, 1] - b[:, 1] * c[:, 0]))
    return float(det.sum() / 6.0)


def point_to_mesh(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> MeshDistance:
    """Exact distance of every point to a triangle mesh (signed when the mesh is closed).

    Parameters
    ----------
    points : (n, 3) array_like float
        Query points in the mesh's frame [mm].
    vertices : (nv, 3) array_like float
        Mesh vertices [mm].
    faces : (m, 3) array_like int
        Mesh triangles.

    Returns
    -------
    MeshDistance
        Distance, nearest face and nearest point of every point.

    Raises
    ------
    MeshError
        For an invalid mesh (see :class:`PointToMesh`).
    ValueError
        For points not (n, 3) or not finite.
    """
    return PointToMesh(vertices, faces).query(points)


def distance_stats(distance_mm: np.ndarray, signed: bool) -> dict:
    """Summary statistics of point-to-mesh distances (docs/reference/interface.md evaluate fields).

    Parameters
    ----------
    distance_mm : (n,) float
        Distances [mm], signed or not.
    signed : bool
        Whether the sign is meaningful (adds ``mean_signed_mm`` and ``std_signed_mm``).

    Returns
    -------
    dict
        ``n_points``, ``rms_mm``, ``mean_abs_mm``, ``p95_mm`` (95th percentile of
        |d|), ``max_mm`` (max |d|), and when signed ``mean_signed_mm``,
        ``std_signed_mm``, ``fraction_inside``.

    Raises
    ------
    ValueError
        If there are no distances.
    """
    d = np.asarray(distance_mm, dtype=np.float64)
    if d.size == 0:
        raise ValueError("no distances to summarise (empty point cloud)")
    a = np.abs(d)
    out = {
        "n_points": int(d.size),
        "rms_mm": float(np.sqrt(np.mean(d * d))),
        "mean_abs_mm": float(a.mean()),
        "p95_mm": float(np.percentile(a, 95)),
        "max_mm": float(a.max()),
    }
    if signed:
        out.update(mean_signed_mm=float(d.mean()), std_signed_mm=float(d.std()),
                   fraction_inside=float(np.mean(d < 0)))
    return out


def score_points(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
                 face_object_id: np.ndarray | None = None) -> dict:
    """Score a point cloud against a mesh: overall statistics and a per-body breakdown.

    Parameters
    ----------
    points : (n, 3) array_like float
        Measured points in the mesh's frame (the part frame for a scan) [mm].
    vertices : (nv, 3) array_like float
        Vertices of the true surface [mm] (see :func:`point_to_mesh`).
    faces : (m, 3) array_like int
        Triangles of the true surface.
    face_object_id : (m,) array_like int, optional
        Object id per face (the twin's ``truth/mesh.ply`` ``object_id``).  When
        absent, connected components of the mesh are the bodies.

    Returns
    -------
    dict
        :func:`distance_stats` fields, ``distance_kind`` ("signed" or
        "unsigned"), ``n_faces``, and ``region_key`` ("object_id" or "body")
        with ``regions``: {id: stats} over the points whose nearest face
        belongs to that body (only when there are ≥ 2 bodies).

    Raises
    ------
    ValueError
        If ``points`` is not a non-empty (n, 3) array, or holds non-finite
        coordinates.
    MeshError
        For an invalid mesh, or ``face_object_id`` not of one value per face.
    """
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) == 0:
        raise ValueError(f"points must be a non-empty (n, 3) array, got shape {p.shape}")
    pm = PointToMesh(vertices, faces)
    res = pm.query(p)
    out = distance_stats(res.distance_mm, res.signed)
    out["distance_kind"] = "signed" if res.signed else "unsigned"
    out["n_faces"] = int(len(pm.faces))
    if face_object_id is not None:
        ids = np.asarray(face_object_id).astype(np.int64).ravel()
        if ids.shape != (len(pm.faces),):
            raise MeshError(f"object_id has {ids.size} values for {len(pm.faces)} faces")
        region_key = "object_id"
    else:
        ids = body_labels(pm.faces)
        region_key = "body"
    labels = ids[res.face]
    unique = np.unique(ids)
    if len(unique) > 1:
        out["region_key"] = region_key
        out["regions"] = {str(int(k)): distance_stats(res.distance_mm[labels == k], res.signed)
                          for k in unique if np.any(labels == k)}
    return out


# --------------------------------------------------------------------------- two-sided scoring


def sample_surface(vertices: np.ndarray, faces: np.ndarray, n: int,
                   seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Points drawn uniformly over the area of a triangle mesh.

    Parameters
    ----------
    vertices : (nv, 3) float
        Vertex positions [mm].
    faces : (m, 3) int
        Triangles.
    n : int
        Number of points [-].
    seed : int
        Seed of the generator (same seed, same points).

    Returns
    -------
    points : (n, 3) float
        Samples on the surface [mm].
    face : (n,) int
        The face each sample lies on.

    Raises
    ------
    MeshError
        A malformed mesh, a mesh of zero area or ``n`` < 1.
    """
    v, f = _check_mesh(vertices, faces)
    if n < 1:
        raise MeshError(f"number of surface samples = {n}: must be >= 1")
    t = v[f]
    area = 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)
    total = area.sum()
    if not total > 0:
        raise MeshError("the mesh has zero area: nothing to sample")
    rng = np.random.default_rng(seed)
    face = np.minimum(np.searchsorted(np.cumsum(area) / total, rng.random(n), side="right"), len(f) - 1)
    r1, r2 = rng.random(n), rng.random(n)
    s1 = np.sqrt(r1)
    w = np.stack([1.0 - s1, s1 * (1.0 - r2), s1 * r2], axis=1)
    return np.einsum("nk,nkj->nj", w, t[face]), face


@dataclass(frozen=True)
class TwoSidedDistance:
    """Distances between a model surface and the true surface, both ways.

    Parameters
    ----------
    truth_points_mm : (n, 3) float
        Area-uniform samples of the true surface [mm].
    truth_to_model_mm : (n,) float
        Unsigned distance of each to the model [mm].
    model_points_mm : (k, 3) float
        Area-uniform samples of the model surface [mm].
    model_face : (k,) int
        Model face of each model sample.
    model_to_truth_mm : (k,) float
        Distance of each to the truth [mm], signed (+ outside the material)
        when the truth is closed.
    truth_face : (k,) int
        Nearest truth face of each model sample.
    signed : bool
        Whether ``model_to_truth_mm`` carries a sign.
    hausdorff_mm : float
        Symmetric Hausdorff distance over the samples [mm] (a lower bound of
        the exact one, within about the samples' spacing times the surface's
        slope change).
    coverage_mm : float
        Distance under which a true point counts as covered [mm].
    """

    truth_points_mm: np.ndarray
    truth_to_model_mm: np.ndarray
    model_points_mm: np.ndarray
    model_face: np.ndarray
    model_to_truth_mm: np.ndarray
    truth_face: np.ndarray
    signed: bool
    hausdorff_mm: float
    coverage_mm: float

    @property
    def coverage(self) -> float:
        """Share of the true surface within ``coverage_mm`` of the model [-]."""
        return float(np.mean(self.truth_to_model_mm <= self.coverage_mm))

    @property
    def mean_mm(self) -> float:
        """Symmetric mean distance: the average of the two one-sided means [mm]."""
        return 0.5 * float(np.mean(self.truth_to_model_mm) + np.mean(np.abs(self.model_to_truth_mm)))

    def to_dict(self) -> dict:
        """JSON-ready summary.

        Returns
        -------
        dict
            ``coverage``, ``coverage_mm``, ``hausdorff_mm``, ``mean_mm``, and the
            :func:`distance_stats` of ``truth_to_model`` and ``model_to_truth``.
        """
        return {"coverage": self.coverage, "coverage_mm": self.coverage_mm,
                "hausdorff_mm": self.hausdorff_mm, "mean_mm": self.mean_mm,
                "truth_to_model": distance_stats(self.truth_to_model_mm, False),
                "model_to_truth": distance_stats(self.model_to_truth_mm, self.signed)}


def two_sided_distance(truth: PointToMesh, model: PointToMesh, n_samples: int = 200_000,
                       seed: int = 0, coverage_mm: float = 0.1) -> TwoSidedDistance:
    """Score a surface model against the true surface in both directions.

    Parameters
    ----------
    truth : PointToMesh
        The true surface, prepared for queries.
    model : PointToMesh
        The model surface, prepared for queries.
    n_samples : int
        Area-uniform samples drawn on each surface [-].
    seed : int
        Seed of the samples (truth: ``seed``, model: ``seed + 1``).
    coverage_mm : float
        A true point within this distance of the model is covered [mm].

    Returns
    -------
    TwoSidedDistance
        Samples, distances both ways, Hausdorff distance and coverage.

    Raises
    ------
    MeshError
        ``coverage_mm`` not > 0, or a mesh of zero area.
    """
    if not coverage_mm > 0:
        raise MeshError(f"coverage distance = {coverage_mm!r} mm: must be > 0")
    t_pts, _ = sample_surface(truth.vertices, truth.faces, n_samples, seed)
    m_pts, m_face = sample_surface(model.vertices, model.faces, n_samples, seed + 1)
    t_to_m = np.abs(model.query(t_pts).distance_mm)
    m_res = truth.query(m_pts)
    hausdorff = max(float(t_to_m.max()), float(np.abs(m_res.distance_mm).max()))
    return TwoSidedDistance(truth_points_mm=t_pts, truth_to_model_mm=t_to_m, model_points_mm=m_pts,
                            model_face=m_face, model_to_truth_mm=m_res.distance_mm, truth_face=m_res.face,
                            signed=m_res.signed, hausdorff_mm=hausdorff, coverage_mm=float(coverage_mm))


def _box_size(xyz: np.ndarray) -> float:
    """Diagonal of the 0.5–99.5 % box of up to 100 000 of the points (a few strays do not count) [mm]."""
    step = max(1, len(xyz) // 100_000)
    lo, hi = np.percentile(xyz[::step], [0.5, 99.5], axis=0)
    return float(np.linalg.norm(hi - lo))


def scale_mismatch(points_mm: np.ndarray, vertices_mm: np.ndarray) -> str | None:
    """A gross scale mismatch between a cloud and a mesh, in words, or None.

    The sizes compared are the diagonals of their bounding boxes (the cloud's
    0.5–99.5 % box).  A ratio within 15 % of a unit factor (1000: metres, 25.4:
    inches, 10: cm, either way) names the unit; any ratio beyond 30 either way
    is a mismatch too.  A scan covering part of the mesh gives a ratio a little
    above 1, never a unit factor by chance alone unless it covers a tenth.

    Parameters
    ----------
    points_mm : (n, 3) float
        The cloud's points (finite) [mm as claimed].
    vertices_mm : (m, 3) float
        The mesh's vertices [mm as claimed].

    Returns
    -------
    str or None
        What the ratio suggests, or None when the sizes are alike.
    """
    a, b = _box_size(np.asarray(points_mm, np.float64)), _box_size(np.asarray(vertices_mm, np.float64))
    if not (a > 0 and b > 0):
        return None
    ratio = b / a                          # > 1: the cloud is smaller than the mesh
    for name, factor in UNIT_FACTORS:
        for r, which, other in ((ratio, "cloud", "mesh"), (1 / ratio, "mesh", "cloud")):
            if abs(r / factor - 1) < _UNIT_MATCH:
                return (f"the {which} is {r:.4g} × smaller than the {other} (bounding boxes {min(a, b):.4g} "
                        f"and {max(a, b):.4g}): the {which} looks like it is in {name}, not mm; the "
                        "distances below are meaningless until both are in mm")
    if max(ratio, 1 / ratio) > _GROSS_RATIO:
        small = "cloud" if ratio > 1 else "mesh"
        return (f"the {small} is {max(ratio, 1 / ratio):.4g} × smaller than the other (bounding boxes "
                f"{min(a, b):.4g} and {max(a, b):.4g}): not the same part, or another unit")
    return None


def placement_mismatch(points_mm: np.ndarray, distance_mm: np.ndarray, vertices_mm: np.ndarray) -> str | None:
    """A cloud lying off its mesh (offset, turned or another part), in words, or None.

    The criterion: the median distance of the points to the mesh exceeds
    :data:`OFF_MESH_FRACTION` (5 %) of the mesh's size (the diagonal of its
    bounding box).  A scan in the mesh's frame lies on its surface within the
    instrument's error, well under 1 % of a part's size, also when it covers
    only part of the mesh or holds strays (the median ignores up to half of the
    points); a scan in another frame (an offset origin, another axis position)
    or of another scale (a calibration of another binning: 30 % on a sphere is
    8.7 % of its box diagonal) lies farther.  The message gives the median
    distance, how far the cloud's box centre is from the mesh's and both sizes.

    Parameters
    ----------
    points_mm : (n, 3) float
        The cloud's points [mm].
    distance_mm : (n,) float
        Their distances to the mesh (signed or not) [mm].
    vertices_mm : (m, 3) float
        The mesh's vertices [mm].

    Returns
    -------
    str or None
        What is off, or None when the cloud lies on the mesh.
    """
    d = np.abs(np.asarray(distance_mm, np.float64))
    d = d[np.isfinite(d)]
    v = np.asarray(vertices_mm, np.float64)
    size = float(np.linalg.norm(v.max(axis=0) - v.min(axis=0))) if len(v) else 0.0
    if not (len(d) and size > 0):
        return None
    median = float(np.median(d))
    if median <= OFF_MESH_FRACTION * size:
        return None
    p = np.asarray(points_mm, np.float64)
    offset = 0.5 * (p.min(axis=0) + p.max(axis=0)) - 0.5 * (v.min(axis=0) + v.max(axis=0))
    return (f"the cloud lies off the mesh: its points' median distance to it is {median:.4g} mm, "
            f"{100 * median / size:.0f} % of the mesh's size (bounding-box diagonal {size:.4g} mm, the cloud's "
            f"{_box_size(p):.4g} mm; above {100 * OFF_MESH_FRACTION:.0f} %), its box centre "
            f"{np.linalg.norm(offset):.4g} mm from the mesh's (x, y, z {offset[0]:+.4g}, {offset[1]:+.4g}, "
            f"{offset[2]:+.4g} mm): not in the mesh's frame (another origin or axis position), of another scale (a "
            "calibration of other frames) or not the same part; the distances below measure that")
