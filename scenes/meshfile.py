"""User meshes (STL, PLY, OBJ) as parts.

The mesh is taken in the part's own frame: ``z = 0`` is the face that sits
on the stage table, ``+z`` up, the rotary axis is the mesh's ``z`` axis unless
``axis_offset_mm`` says where it is.  Lengths are in mm unless ``units`` is
``"m"`` or ``"inch"``.

Errors: a missing, empty, unreadable or non-mesh file (no triangles, an
unsupported extension) raises :class:`~scheimpflug.errors.MeshError` with the
file name and the reason.  A mesh that is not watertight, or that does not
stand on ``z = 0``, loads with a :class:`~scenes.part.MeshWarning`: scoring by
point-to-surface distance still works.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import trimesh

from scheimpflug.errors import MeshError

from .part import Part, warn_mesh

__all__ = ["MESH_SUFFIXES", "UNITS_MM", "load_mesh"]

MESH_SUFFIXES = (".obj", ".ply", ".stl")
#: length of one unit in mm
UNITS_MM = {"mm": 1.0, "m": 1000.0, "inch": 25.4, "in": 25.4}
_TABLE_TOL = 1e-6  # relative to the mesh size: lowest point this close to z = 0 is "on the table"


def _check_file(path: Path) -> None:
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise MeshError(f"{path}: not a mesh file (expected {', '.join(MESH_SUFFIXES)})")
    if not path.exists():
        raise MeshError(f"{path}: no such file")
    if not path.is_file():
        raise MeshError(f"{path}: not a regular file")
    if path.stat().st_size == 0:
        raise MeshError(f"{path}: file is empty")


def _check_stl(path: Path) -> None:
    """Refuse a file that is neither a binary STL (84 + 50·n bytes) nor an ASCII one ("solid").

    trimesh returns an empty mesh for some garbage (depending on which text
    decoders are installed); deciding here keeps the message the same everywhere.
    """
    size = path.stat().st_size
    with open(path, "rb") as fh:
        head = fh.read(84)
    n = int.from_bytes(head[80:84], "little") if len(head) == 84 else -1
    if n >= 0 and size == 84 + 50 * n:
        return
    if head.lstrip().lower().startswith(b"solid"):
        return
    raise MeshError(f"{path}: cannot read as STL mesh (not a binary STL: {size} bytes for a header of "
                    f"{max(n, 0)} triangles; not an ASCII STL: no 'solid' keyword)")


def _read(path: Path) -> trimesh.Trimesh:
    kind = path.suffix.lower().lstrip(".")
    if kind == "stl":
        _check_stl(path)
    try:
        mesh = trimesh.load(path, file_type=kind, force="mesh", process=True)
    except Exception as exc:  # trimesh raises many kinds on corrupt input
        raise MeshError(f"{path}: cannot read as {kind.upper()} mesh ({type(exc).__name__}: {exc})") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise MeshError(f"{path}: contains no triangles (a point cloud or an empty scene?)")
    verts = np.asarray(mesh.vertices, dtype=float)
    if not np.all(np.isfinite(verts)):
        raise MeshError(f"{path}: vertices contain NaN or infinity")
    return trimesh.Trimesh(verts, np.asarray(mesh.faces, dtype=np.int64), process=False)


def load_mesh(path: str | os.PathLike, *, units: str = "mm", axis_offset_mm=(0.0, 0.0),
              material: str = "metal", name: str | None = None, object_id: int = 1) -> Part:
    """A user mesh as a :class:`Part` in mm, with the rotary axis on ``z``.

    The file is read by trimesh (with its default processing: duplicate
    vertices merged), scaled to mm and shifted so the rotary axis is ``z``.

    Parameters
    ----------
    path : str or os.PathLike
        STL, PLY or OBJ file.
    units : str, default "mm"
        Length unit of the file: ``"mm"``, ``"m"`` or ``"inch"`` (also ``"in"``).
    axis_offset_mm : (2,) array_like, default (0, 0)
        (x, y) of the rotary axis in the file's frame, after unit conversion
        [mm]; the mesh is shifted by −offset.
    material : str, default "metal"
        A tag of :data:`~scenes.part.MATERIALS`.
    name : str, optional
        Part name; default the file name without its extension.
    object_id : int, default 1
        Object id of the part.

    Returns
    -------
    Part
        The mesh in the part frame [mm], with ``analytic = {"kind": "mesh",
        "file": ..., "units": ..., "axis_offset_mm": ..., "watertight": ...}``.

    Raises
    ------
    MeshError
        Unknown units; a missing, empty, unreadable or non-mesh file (no
        triangles, NaN vertices, an unsupported extension); a bad
        ``axis_offset_mm``; an unknown material.

    Warns
    -----
    MeshWarning
        When the mesh is not watertight, or its lowest point is not on the
        table (z = 0).
    """
    path = Path(path)
    if units not in UNITS_MM:
        raise MeshError(f"units {units!r} unknown (known: mm, m, inch)")
    _check_file(path)
    mesh = _read(path)
    offset = np.asarray(axis_offset_mm, dtype=float).reshape(-1)
    if offset.shape != (2,) or not np.all(np.isfinite(offset)):
        raise MeshError(f"axis_offset_mm must be two finite numbers (x, y), got {axis_offset_mm!r}")
    mesh.apply_scale(UNITS_MM[units])
    mesh.apply_translation([-offset[0], -offset[1], 0.0])
    _warn_if_odd(path, mesh)
    analytic = {"kind": "mesh", "file": str(path), "units": units,
                "axis_offset_mm": offset.tolist(), "watertight": bool(mesh.is_watertight),
                "mesh_from_part": np.eye(4).tolist()}
    return Part(name=name or path.stem, mesh=mesh, material=material, analytic=analytic,
                object_id=object_id)


def _warn_if_odd(path: Path, mesh: trimesh.Trimesh) -> None:
    if not mesh.is_watertight:
        warn_mesh(f"{path}: mesh is not watertight (holes or non-manifold edges); "
                  "it renders and scores, but volume and inside tests are unreliable")
    zmin, size = float(mesh.bounds[0, 2]), float(np.ptp(mesh.bounds, axis=0).max())
    if abs(zmin) > _TABLE_TOL * max(size, 1.0):
        warn_mesh(f"{path}: lowest point is at z = {zmin:.6g} mm, not on the stage table (z = 0)")
