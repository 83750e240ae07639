"""Volumetric numbers of a closed triangle mesh: volume, surface area, height, cross-sections.

Two independent routes to the volume, reported side by side:

* **divergence theorem** on the closed, outward-oriented mesh: the sum of the
  signed volumes of the tetrahedra spanned by the origin and each face,

      V = (1/6) Σ_f  a_f · (b_f × c_f)

  (exact for the mesh; the area is Σ ½|(b − a) × (c − a)|);
* **sections**: the area A(z) of the horizontal cross-section at height z,
  integrated over the height by the midpoint rule,

      V ≈ Σ_k A(z_k) Δz,   z_k = z_min + (k + ½) Δz.

A section is the set of segments where the plane z = z_k cuts the faces.  On
a closed, consistently oriented mesh the segments form closed loops
traversed counter-clockwise (seen from +z) around material, so the area is
the shoelace sum ½ Σ (x₁ y₂ − x₂ y₁) over the oriented segments, with no
need to assemble the loops: each segment runs from the crossing of the face
edge that goes down through the plane to the crossing of the edge that goes
up.  The section's *equivalent diameter* is √(4A/π) (the diameter of the
circle of the same area); its *width* is the largest distance between two
of its points (Feret diameter).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from scheimpflug.errors import MeshError

__all__ = [
    "Section",
    "mesh_area_mm2",
    "mesh_volume_mm3",
    "section",
    "section_areas_mm2",
    "solid_summary",
    "volume_from_sections_mm3",
]


def _triangles(vertices, faces) -> np.ndarray:
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
        raise MeshError(f"a mesh needs (n, 3) vertices and (m >= 1, 3) faces, got {v.shape} and {f.shape}")
    if f.min() < 0 or f.max() >= len(v):
        raise MeshError("mesh faces index vertices that do not exist")
    return v[f]


def mesh_volume_mm3(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Enclosed volume of a closed mesh by the divergence theorem.

    Parameters
    ----------
    vertices : (n, 3) float
        Vertex positions [mm].
    faces : (m, 3) int
        Triangles, counter-clockwise seen from outside.

    Returns
    -------
    float
        Signed volume [mm³]: positive for outward-oriented faces; only
        meaningful for a closed mesh.

    Raises
    ------
    MeshError
        Malformed arrays.
    """
    return float(_face_volumes(_triangles(vertices, faces)).sum())


def _face_volumes(t: np.ndarray) -> np.ndarray:
    """(m,) signed volume of the tetrahedron (origin, a, b, c) of each face [mm³]."""
    a, b, c = t[:, 0], t[:, 1], t[:, 2]
    det = (a[:, 0] * (b[:, 1] * c[:, 2] - b[:, 2] * c[:, 1]) - a[:, 1] * (b[:, 0] * c[:, 2] - b[:, 2] * c[:, 0])
           + a[:, 2] * (b[:, 0] * c[:, 1] - b[:, 1] * c[:, 0]))
    return det / 6.0


def _face_areas(t: np.ndarray) -> np.ndarray:
    """(m,) area of each face [mm²]."""
    e1, e2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    cx = e1[:, 1] * e2[:, 2] - e1[:, 2] * e2[:, 1]
    cy = e1[:, 2] * e2[:, 0] - e1[:, 0] * e2[:, 2]
    cz = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    return 0.5 * np.sqrt(cx * cx + cy * cy + cz * cz)


def mesh_area_mm2(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Surface area of a triangle mesh.

    Parameters
    ----------
    vertices : (n, 3) float
        Vertex positions [mm].
    faces : (m, 3) int
        Triangles.

    Returns
    -------
    float
        Σ ½ |(b − a) × (c − a)| [mm²].
    """
    return float(_face_areas(_triangles(vertices, faces)).sum())


@dataclass(frozen=True)
class _SortedFaces:
    """Each face's vertices sorted by height, and whether that order is a rotation of the face's."""

    lo: np.ndarray      # (m, 3)
    mid: np.ndarray
    hi: np.ndarray
    even: np.ndarray    # (m,) bool

    @classmethod
    def of(cls, t: np.ndarray) -> _SortedFaces:
        order = np.argsort(t[:, :, 2], axis=1, kind="stable")
        rows = np.arange(len(t))[:, None]
        s = t[rows, order]
        even = ((order[:, 1] - order[:, 0]) % 3) == 1
        return cls(lo=s[:, 0], mid=s[:, 1], hi=s[:, 2], even=even)


def _on_edge(a: np.ndarray, b: np.ndarray, z: np.ndarray) -> np.ndarray:
    dz = b[:, 2] - a[:, 2]
    s = np.divide(z - a[:, 2], dz, out=np.zeros_like(z), where=dz != 0)
    return a[:, :2] + s[:, None] * (b[:, :2] - a[:, :2])


def _crossings(sf: _SortedFaces, face: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Oriented section segments (start, end (k, 2)) of faces straddling the planes z (k,).

    The plane crosses the edge lo→hi and one of lo→mid, mid→hi.  With the
    vertices in the face's own (counter-clockwise) order a rotation of
    (lo, mid, hi), the edge hi→lo goes down through the plane and the short
    one up: the segment runs from the long edge's crossing to the short one's
    (the other way round otherwise).
    """
    lo, mid, hi = sf.lo[face], sf.mid[face], sf.hi[face]
    long_ = _on_edge(lo, hi, z)
    upper = z >= mid[:, 2]
    short = np.where(upper[:, None], _on_edge(mid, hi, z), _on_edge(lo, mid, z))
    even = sf.even[face][:, None]
    return np.where(even, long_, short), np.where(even, short, long_)


def _pairs(face_ids: np.ndarray, k_lo: np.ndarray, k_hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(face, section) index pairs of faces that straddle planes k_lo .. k_hi − 1 each."""
    n = np.maximum(k_hi - k_lo, 0)
    face = np.repeat(face_ids, n)
    start = np.repeat(k_lo - np.concatenate([[0], np.cumsum(n)[:-1]]), n)
    return face, start + np.arange(n.sum())


_CHUNK_FACES = 500_000  # faces per pass of the section sum: bounds the temporary arrays


def _section_areas(sf: _SortedFaces, z_sorted: np.ndarray) -> np.ndarray:
    """Areas at sorted heights: lo < z ≤ hi picks the faces a plane crosses (module docstring)."""
    k_lo = np.searchsorted(z_sorted, sf.lo[:, 2], side="right")
    k_hi = np.searchsorted(z_sorted, sf.hi[:, 2], side="right")
    busy = np.flatnonzero(k_hi > k_lo)
    out = np.zeros(len(z_sorted))
    for ids in np.array_split(busy, max(1, -(-len(busy) // _CHUNK_FACES))):
        face, k = _pairs(ids, k_lo[ids], k_hi[ids])
        p, q = _crossings(sf, face, z_sorted[k])
        out += np.bincount(k, weights=0.5 * (p[:, 0] * q[:, 1] - q[:, 0] * p[:, 1]), minlength=len(z_sorted))
    return out


def section_areas_mm2(vertices: np.ndarray, faces: np.ndarray, z_mm) -> np.ndarray:
    """Areas of the horizontal cross-sections of a closed mesh at several heights.

    Parameters
    ----------
    vertices : (n, 3) float
        Vertex positions [mm].
    faces : (m, 3) int
        Closed, outward-oriented triangles.
    z_mm : (k,) float
        Heights of the section planes [mm].

    Returns
    -------
    (k,) float
        Area of material in each plane [mm²] (the shoelace sum of the
        oriented section segments; module docstring).
    """
    sf = _SortedFaces.of(_triangles(vertices, faces))
    z = np.asarray(z_mm, dtype=np.float64).ravel()
    order = np.argsort(z)
    out = np.empty(len(z))
    out[order] = _section_areas(sf, z[order])
    return out


@dataclass(frozen=True)
class Section:
    """One horizontal cross-section of a closed mesh.

    Parameters
    ----------
    z_mm : float
        Height of the plane [mm].
    area_mm2 : float
        Area of material [mm²].
    perimeter_mm : float
        Total length of the section's outlines [mm].
    diameter_mm : float
        Equivalent diameter √(4A/π) [mm].
    width_mm : float
        Largest distance between two points of the section (Feret) [mm].
    segments_mm : (s, 2, 2) float
        The oriented outline segments (x, y) [mm].
    """

    z_mm: float
    area_mm2: float
    perimeter_mm: float
    diameter_mm: float
    width_mm: float
    segments_mm: np.ndarray

    def to_dict(self) -> dict:
        """JSON-ready numbers (no segments).

        Returns
        -------
        dict
            ``z_mm``, ``area_mm2``, ``perimeter_mm``, ``diameter_mm``, ``width_mm``.
        """
        return {"z_mm": self.z_mm, "area_mm2": self.area_mm2, "perimeter_mm": self.perimeter_mm,
                "diameter_mm": self.diameter_mm, "width_mm": self.width_mm}


def _width(points: np.ndarray) -> float:
    if len(points) < 2:
        return 0.0
    try:
        points = points[ConvexHull(points).vertices]
    except (QhullError, ValueError):
        pass
    d = np.linalg.norm(points[:, None] - points[None], axis=-1)
    return float(d.max())


def section(vertices: np.ndarray, faces: np.ndarray, z_mm: float) -> Section:
    """The horizontal cross-section of a closed mesh at height ``z_mm``.

    Parameters
    ----------
    vertices : (n, 3) float
        Vertex positions [mm].
    faces : (m, 3) int
        Closed, outward-oriented triangles.
    z_mm : float
        Height of the plane [mm].

    Returns
    -------
    Section
        Area, perimeter, equivalent diameter, width and outline (all zero and
        empty when the plane misses the mesh).
    """
    return _section(_SortedFaces.of(_triangles(vertices, faces)), z_mm)


def _section(sf: _SortedFaces, z_mm: float) -> Section:
    z = float(z_mm)
    face = np.flatnonzero((sf.lo[:, 2] < z) & (sf.hi[:, 2] >= z))
    p, q = _crossings(sf, face, np.full(len(face), z))
    area = float(0.5 * np.sum(p[:, 0] * q[:, 1] - q[:, 0] * p[:, 1]))
    perimeter = float(np.linalg.norm(q - p, axis=1).sum())
    return Section(z_mm=z, area_mm2=area, perimeter_mm=perimeter,
                   diameter_mm=math.sqrt(4.0 * max(area, 0.0) / math.pi),
                   width_mm=_width(np.concatenate([p, q])), segments_mm=np.stack([p, q], axis=1))


def volume_from_sections_mm3(vertices: np.ndarray, faces: np.ndarray, n_slices: int = 2000) -> float:
    """Volume by integrating the section areas over the height (midpoint rule).

    Parameters
    ----------
    vertices : (n, 3) float
        Vertex positions [mm].
    faces : (m, 3) int
        Closed, outward-oriented triangles.
    n_slices : int
        Number of slabs over the mesh's height [-].

    Returns
    -------
    float
        Σ A(z_k) Δz [mm³] (module docstring).

    Raises
    ------
    MeshError
        ``n_slices`` < 1 or a malformed mesh.
    """
    if n_slices < 1:
        raise MeshError(f"n_slices = {n_slices}: must be >= 1")
    return _volume_from_sections(_SortedFaces.of(_triangles(vertices, faces)), n_slices)


def _volume_from_sections(sf: _SortedFaces, n_slices: int) -> float:
    z0, z1 = float(sf.lo[:, 2].min()), float(sf.hi[:, 2].max())
    dz = (z1 - z0) / n_slices
    return float(_section_areas(sf, z0 + dz * (np.arange(n_slices) + 0.5)).sum() * dz)


def solid_summary(vertices: np.ndarray, faces: np.ndarray, face_body: np.ndarray | None = None,
                  section_z_mm=(), n_slices: int = 2000, measured: np.ndarray | None = None) -> dict:
    """The volumetric numbers of a closed mesh, whole and per body.

    Parameters
    ----------
    vertices : (n, 3) float
        Vertex positions [mm].
    faces : (m, 3) int
        Closed, outward-oriented triangles.
    face_body : (m,) int, optional
        Body of each face (one entry per body in ``bodies``).
    section_z_mm : sequence of float
        Heights of the reported cross-sections [mm].
    n_slices : int
        Slabs of the section-integral volume [-].
    measured : (m,) bool, optional
        Faces that were measured (adds ``measured_area_share``).

    Returns
    -------
    dict
        ``volume_mm3`` (divergence theorem), ``volume_from_sections_mm3``,
        ``area_mm2``, ``height_mm``, ``z_range_mm`` (over the faces' vertices),
        ``sections`` (list of :meth:`Section.to_dict`), ``bodies`` (per body:
        ``body``, ``volume_mm3``, ``area_mm2``, ``height_mm``, ``z_range_mm``)
        and, with ``measured``, ``measured_area_share``.
    """
    t = _triangles(vertices, faces)
    sf = _SortedFaces.of(t)
    vol, area = _face_volumes(t), _face_areas(t)
    z_lo, z_hi = float(sf.lo[:, 2].min()), float(sf.hi[:, 2].max())
    out = {"volume_mm3": float(vol.sum()), "volume_from_sections_mm3": _volume_from_sections(sf, n_slices),
           "area_mm2": float(area.sum()), "height_mm": z_hi - z_lo, "z_range_mm": [z_lo, z_hi],
           "sections": [_section(sf, zk).to_dict() for zk in section_z_mm]}
    if measured is not None:
        out["measured_area_share"] = float(area[np.asarray(measured, bool)].sum() / out["area_mm2"])
    body = np.zeros(len(t), np.int64) if face_body is None else np.asarray(face_body, np.int64)
    out["bodies"] = _body_numbers(body, vol, area, sf.lo[:, 2], sf.hi[:, 2])
    return out


def _body_numbers(body: np.ndarray, vol: np.ndarray, area: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> list:
    ids, first = np.unique(body, return_inverse=True)
    order = np.argsort(first, kind="stable")
    starts = np.searchsorted(first[order], np.arange(len(ids)))
    zmin, zmax = np.minimum.reduceat(lo[order], starts), np.maximum.reduceat(hi[order], starts)
    v, a = np.bincount(first, vol, len(ids)), np.bincount(first, area, len(ids))
    return [{"body": int(k), "volume_mm3": float(v[i]), "area_mm2": float(a[i]), "height_mm": float(zmax[i] - zmin[i]),
             "z_range_mm": [float(zmin[i]), float(zmax[i])]} for i, k in enumerate(ids)]
