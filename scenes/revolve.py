"""Watertight meshes built directly from vertex grids (no boolean operations).

A body of revolution — with or without a height field on its surface — is a
stack of *rows*: row ``j`` is the ring of points ``(r[j, i] cos θ_i,
r[j, i] sin θ_i, z[j])``.  Consecutive rows are joined by a band of quads; a
row with ``r = 0`` is a pole (a disc cap); two consecutive rows at the same
height are a horizontal shoulder.  Vertices that coincide between consecutive
rows are shared, so the result is watertight with no degenerate triangles.

Rows must run so that the material lies on the left of the profile when
walked in (r, z) with +r to the right and +z up (e.g. outer wall upwards, top
inwards): faces then point outwards (positive volume).
"""

from __future__ import annotations

import math

import numpy as np
import trimesh

__all__ = ["box_mesh", "revolved_mesh", "segments_for_sagitta"]

_MERGE_TOL_MM = 1e-9  # vertices of consecutive rows closer than this are one vertex


def segments_for_sagitta(radius_mm: float, max_sagitta_mm: float, multiple: int = 4) -> int:
    """Number of polygon sides keeping the chord sagitta ≤ ``max_sagitta_mm``.

    Parameters
    ----------
    radius_mm : float
        Circle radius R (> 0) [mm].
    max_sagitta_mm : float
        Largest allowed sagitta s (> 0) [mm].
    multiple : int, default 4
        The count is rounded up to a multiple of this.

    Returns
    -------
    int
        Number of sides n (at least 8, before rounding up).

    Raises
    ------
    ValueError
        When ``radius_mm`` or ``max_sagitta_mm`` is not > 0.

    Notes
    -----
    Sagitta of a chord spanning 2π/n on a circle of radius R:
    s = R (1 − cos(π/n)) ≈ R π² / (2 n²), so n = ⌈π / acos(1 − s/R)⌉, rounded
    up to a multiple of ``multiple``.  R = 50 mm, s = 1 µm gives n = 497.
    """
    if radius_mm <= 0 or max_sagitta_mm <= 0:
        raise ValueError("radius_mm and max_sagitta_mm must be > 0")
    ratio = min(max_sagitta_mm / radius_mm, 1.0)
    n = max(8, math.ceil(math.pi / math.acos(1.0 - ratio)))
    return int(-(-n // multiple) * multiple)


def _vertex_index(z: np.ndarray, r: np.ndarray) -> np.ndarray:
    """(m, n) int: index of each grid vertex after merging coincident ones."""
    m, n = r.shape
    idx = np.arange(m * n, dtype=np.int64).reshape(m, n)
    for j in range(m):
        if np.all(np.abs(r[j]) <= _MERGE_TOL_MM):
            idx[j] = idx[j, 0]
        elif j > 0 and abs(z[j] - z[j - 1]) <= _MERGE_TOL_MM:
            same = np.abs(r[j] - r[j - 1]) <= _MERGE_TOL_MM
            idx[j, same] = idx[j - 1, same]
    return idx


def _quad_faces(idx: np.ndarray, r: np.ndarray, r_mid: np.ndarray | None, closed: bool) -> np.ndarray:
    """(k, 3) int triangles of the quads between consecutive rows."""
    rows = np.arange(idx.shape[0] - (0 if closed else 1))
    nxt = (rows + 1) % idx.shape[0]
    a, b = idx[rows], np.roll(idx[rows], -1, axis=1)
    c, d = np.roll(idx[nxt], -1, axis=1), idx[nxt]
    use_bd = np.zeros(a.shape, dtype=bool)
    if r_mid is not None:  # the diagonal whose midpoint lies closer to the exact surface
        ra, rb = r[rows], np.roll(r[rows], -1, axis=1)
        rc, rd = np.roll(r[nxt], -1, axis=1), r[nxt]
        err_ac = np.abs(0.5 * (ra + rc) - r_mid)
        err_bd = np.abs(0.5 * (rb + rd) - r_mid)
        use_bd = np.nan_to_num(err_bd, nan=np.inf) < np.nan_to_num(err_ac, nan=np.inf) - 1e-12
    t1 = np.where(use_bd[..., None], np.stack([a, b, d], -1), np.stack([a, b, c], -1))
    t2 = np.where(use_bd[..., None], np.stack([b, c, d], -1), np.stack([a, c, d], -1))
    faces = np.concatenate([t1.reshape(-1, 3), t2.reshape(-1, 3)])
    ok = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
    return faces[ok]


def revolved_mesh(theta_rad: np.ndarray, z_mm: np.ndarray, r_mm: np.ndarray, *,
                  closed: bool = False, r_mid_mm: np.ndarray | None = None) -> trimesh.Trimesh:
    """Watertight mesh of a stack of rings (see module doc).

    Parameters
    ----------
    theta_rad : (n,) float
        Increasing angles in [0, 2π) [rad].
    z_mm : (m,) float
        Height of each row [mm].
    r_mm : (m, n) float
        Radius of each grid vertex [mm]; a row of zeros is a pole.
    closed : bool, default False
        Join the last row back to the first (a tube/annulus); otherwise
        the first and last rows must be poles.
    r_mid_mm : (m − 1, n) or (m, n) float, optional
        Exact radius at each quad's centre; used to pick the quad diagonal
        closest to the true surface (NaN: don't care).

    Returns
    -------
    trimesh.Trimesh
        The mesh, part frame [mm], with outward faces when the rows follow the
        module docstring's orientation; ``process=False``, unused vertices
        dropped, coincident vertices of consecutive rows shared.

    Raises
    ------
    ValueError
        When ``r_mm`` is not of shape ``(len(z_mm), len(theta_rad))``.
    """
    theta = np.asarray(theta_rad, dtype=float)
    z = np.asarray(z_mm, dtype=float)
    r = np.asarray(r_mm, dtype=float)
    if r.shape != (len(z), len(theta)):
        raise ValueError(f"r_mm must have shape {(len(z), len(theta))}, got {r.shape}")
    idx = _vertex_index(z, r)
    faces = _quad_faces(idx, r, r_mid_mm, closed)
    xyz = np.stack([r * np.cos(theta), r * np.sin(theta), np.broadcast_to(z[:, None], r.shape)], -1)
    used, inverse = np.unique(faces, return_inverse=True)
    return trimesh.Trimesh(xyz.reshape(-1, 3)[used], inverse.reshape(-1, 3), process=False)


def box_mesh(lo_mm, hi_mm) -> trimesh.Trimesh:
    """Axis-aligned box between two corners.

    Parameters
    ----------
    lo_mm : (3,) array_like
        Lower corner (xmin, ymin, zmin) [mm].
    hi_mm : (3,) array_like
        Upper corner [mm], greater than ``lo_mm`` on every axis.

    Returns
    -------
    trimesh.Trimesh
        12 outward triangles, ``process=False``.

    Raises
    ------
    ValueError
        When ``hi_mm`` is not greater than ``lo_mm`` on every axis.
    """
    lo, hi = np.asarray(lo_mm, dtype=float), np.asarray(hi_mm, dtype=float)
    if np.any(hi <= lo):
        raise ValueError(f"box corners must satisfy hi > lo, got {lo} and {hi}")
    box = trimesh.creation.box(bounds=np.array([lo, hi]))
    return trimesh.Trimesh(np.asarray(box.vertices, dtype=float), np.asarray(box.faces), process=False)
