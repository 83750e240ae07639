"""Surface-model files: STL or PLY by the file name's suffix, written atomically.

``.stl``: binary STL (little-endian float32 normals and vertices, one record
per face; the per-face attribute word is 0), which every CAD, slicer and
inspection tool reads.  STL has no room for face properties.

``.ply``: binary PLY with double vertices and the scalar face properties
given (a surface model's ``fill`` and ``body``, :mod:`scheimpflug.meshing`),
through :func:`scheimpflug.io.ply.write_mesh_ply`; read back with
:func:`scheimpflug.io.ply.read_triangle_mesh`.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from scheimpflug.errors import MeshError
from scheimpflug.io.atomic import atomic_path
from scheimpflug.io.folder import unwritable_reason
from scheimpflug.io.ply import write_mesh_ply

__all__ = ["MESH_SUFFIXES", "check_mesh_destination", "write_mesh", "write_stl"]

#: File suffixes :func:`write_mesh` writes.
MESH_SUFFIXES = (".ply", ".stl")

_STL_RECORD = np.dtype([("normal", "<f4", (3,)), ("v", "<f4", (3, 3)), ("attr", "<u2")])


def write_stl(path: str | os.PathLike, vertices: np.ndarray, faces: np.ndarray, header: str = "") -> Path:
    """Write a triangle mesh as a binary STL, atomically.

    Parameters
    ----------
    path : path-like
        Destination ``.stl``.
    vertices : (nv, 3) float
        Vertex positions [mm] (written as float32).
    faces : (m, 3) int
        Triangles, counter-clockwise seen from outside.
    header : str
        Text for the 80-byte header (cut to fit; it never starts with "solid").

    Returns
    -------
    Path
        ``path``.
    """
    t = np.asarray(vertices, np.float64)[np.asarray(faces, np.int64)]
    n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    rec = np.zeros(len(t), dtype=_STL_RECORD)
    rec["normal"] = np.divide(n, norm, out=np.zeros_like(n), where=norm > 0)
    rec["v"] = t
    text = ("binary STL, mm; " + header).encode("ascii", "replace")[:80].ljust(80, b" ")
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(text)
        fh.write(np.uint32(len(t)).tobytes())
        fh.write(rec.tobytes())
    return Path(path)


def check_mesh_destination(path: str | os.PathLike) -> Path:
    """Check, before any work, that a surface model can be written to ``path``.

    Parameters
    ----------
    path : path-like
        Destination ``.stl`` or ``.ply``.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    MeshError
        Another suffix, a folder in the way, or a folder that cannot be
        created or written.
    """
    p = Path(path)
    if p.suffix.lower() not in MESH_SUFFIXES:
        raise MeshError(f"model file {str(p)!r}: the name must end in .stl or .ply")
    if p.is_dir():
        raise MeshError(f"model file {str(p)!r} is a folder")
    parent, reason = unwritable_reason(p.parent)
    if reason:
        raise MeshError(f"model file {str(p)!r} cannot be written: {str(parent)!r} is not a writable folder")
    if p.exists() and not os.access(p, os.W_OK):
        raise MeshError(f"model file {str(p)!r} cannot be written: the file is read-only")
    return p


def write_mesh(path: str | os.PathLike, vertices: np.ndarray, faces: np.ndarray,
               face_properties: dict | None = None, comment: str = "") -> Path:
    """Write a triangle mesh as STL or PLY, chosen by the suffix, atomically.

    Parameters
    ----------
    path : path-like
        Destination ``.stl`` or ``.ply``.
    vertices : (nv, 3) float
        Vertex positions [mm].
    faces : (m, 3) int
        Triangles, counter-clockwise seen from outside.
    face_properties : dict of str to (m,) array, optional
        Scalar face properties (PLY only; STL has none).
    comment : str
        A line for the file header.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    MeshError
        An unknown suffix or a destination that cannot be written.
    """
    p = check_mesh_destination(path)
    try:
        if p.suffix.lower() == ".stl":
            return write_stl(p, vertices, faces, header=comment)
        return write_mesh_ply(p, vertices, faces, None, comments=(comment,) if comment else (),
                              face_properties=face_properties)
    except OSError as exc:
        raise MeshError(f"model file {str(p)!r} cannot be written: {exc.strerror or exc}") from None
