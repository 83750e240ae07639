"""Parts and assemblies: a watertight mesh [mm] plus its exact analytic description.

A :class:`Part` is one rigid body (one object id in the renderer's truth
images); an :class:`Assembly` is the set of parts on the rotary or translation
stage, already posed in the assembly frame.

Frames
------
Part frame = assembly frame: millimetres, ``z = 0`` is the face that sits on
the stage table, ``+z`` up, the rotary axis is the ``z`` axis.  The simulator
places the assembly on the table and turns it about ``z`` by the stage angle.

``Part.analytic`` describes the body in its *own* frame (axis along ``z``,
base at ``z = 0``); ``analytic["mesh_from_part"]`` is the 4 × 4 matrix that
maps that own frame to the frame ``Part.mesh`` is expressed in (identity for a
freshly generated part; ``T(position) · Rz(yaw)`` once posed).
"""

from __future__ import annotations

import json
import math
import os
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import trimesh

from scheimpflug.errors import MeshError
from scheimpflug.io.ply import read_mesh, write_mesh_ply

__all__ = [
    "MATERIALS",
    "Assembly",
    "MeshWarning",
    "Part",
    "read_ply",
    "yaw_matrix",
]

#: Material tags the renderer maps to BSDFs.
MATERIALS = ("metal", "knurled-metal", "cardboard", "tape", "paper", "white-plastic", "marble")


class MeshWarning(UserWarning):
    """A usable but suspicious mesh: not watertight, not standing on the table, ..."""


def yaw_matrix(yaw_deg: float, position_mm=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Rigid transform ``T(position) · Rz(yaw)``.

    Parameters
    ----------
    yaw_deg : float
        Rotation about +z, counter-clockwise seen from above [deg].
    position_mm : (3,) array_like, default (0, 0, 0)
        Translation applied after the rotation [mm].

    Returns
    -------
    (4, 4) float
        The homogeneous transform.
    """
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    m = np.eye(4)
    m[:2, :2] = [[c, -s], [s, c]]
    m[:3, 3] = np.asarray(position_mm, dtype=float).reshape(3)
    return m


def _check_json(name: str, analytic: dict) -> None:
    try:
        json.dumps(analytic, allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise MeshError(f"part {name!r}: analytic description is not JSON-serialisable ({exc})") from None


@dataclass(frozen=True, eq=False)
class Part:
    """One rigid body of a scene.

    Frozen; validated on construction.

    Parameters
    ----------
    name : str
        Part name, e.g. ``"ring"``.
    mesh : trimesh.Trimesh
        Triangles in the assembly frame [mm] (see the module docstring).
    material : str, default "metal"
        One of :data:`MATERIALS`.
    analytic : dict, optional
        JSON-serialisable exact description: ``kind``, dimensions [mm], knurl
        parameters, and ``mesh_from_part`` (4 × 4 nested list).
    object_id : int, default 1
        1-based id, unique within an assembly (0 = background).
    texture : dict, optional
        An albedo map on the surface (``kind``: a pattern of :mod:`scenes.patterns`,
        ``"image"`` — ``albedo`` (H, W) in [0, 1] over ``extent_mm`` [u0, v0, u1, v1] —
        or ``"uniform"`` — ``albedo``), in the texture coordinates (u, v) [mm]; the
        renderer then shades the part as a matte (Lambertian) surface of that albedo.
        None = the material's own reflectance.
    uv_mm : (m, 2) ndarray float, optional
        Texture coordinates (u, v) of each mesh vertex [mm]; None with a texture =
        planar coordinates (``texture["planar"]``: ``origin_mm``, ``u_axis``, ``v_axis``
        in the part frame; default the part's x and y).

    Raises
    ------
    MeshError
        For an unknown material, an object id that is not an int ≥ 0, a mesh
        without triangles, an analytic description that is not
        JSON-serialisable (NaN included), or ``uv_mm`` not of shape (vertices, 2).
    """

    name: str
    mesh: trimesh.Trimesh
    material: str = "metal"
    analytic: dict = field(default_factory=dict)
    object_id: int = 1
    texture: dict | None = None
    uv_mm: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.material not in MATERIALS:
            raise MeshError(f"part {self.name!r}: unknown material {self.material!r} "
                            f"(known: {', '.join(MATERIALS)})")
        if not isinstance(self.object_id, int) or self.object_id < 0:
            raise MeshError(f"part {self.name!r}: object_id must be an int >= 0, got {self.object_id!r}")
        if len(self.mesh.faces) == 0:
            raise MeshError(f"part {self.name!r}: mesh has no triangles")
        _check_json(self.name, self.analytic)
        if self.uv_mm is not None and np.shape(self.uv_mm) != (len(self.mesh.vertices), 2):
            raise MeshError(f"part {self.name!r}: uv_mm must be ({len(self.mesh.vertices)}, 2), "
                            f"got {np.shape(self.uv_mm)}")

    @property
    def mesh_from_part(self) -> np.ndarray:
        """Own (analytic) frame → mesh frame, (4, 4) float [mm] (identity if not set)."""
        return np.asarray(self.analytic.get("mesh_from_part", np.eye(4).tolist()), dtype=float)

    def transformed(self, b_from_mesh: np.ndarray) -> Part:
        """The part moved by a rigid transform.

        Parameters
        ----------
        b_from_mesh : (4, 4) array_like
            Rigid transform from the mesh's frame to the new frame b [mm].

        Returns
        -------
        Part
            A copy with the mesh in frame b and ``analytic["mesh_from_part"]``
            updated to ``b_from_mesh @ mesh_from_part``.
        """
        m = np.asarray(b_from_mesh, dtype=float)
        mesh = self.mesh.copy()
        mesh.apply_transform(m)
        analytic = dict(self.analytic, mesh_from_part=(m @ self.mesh_from_part).tolist())
        return replace(self, mesh=mesh, analytic=analytic)

    def posed(self, position_mm=(0.0, 0.0, 0.0), yaw_deg: float = 0.0) -> Part:
        """The part turned about its ``z`` axis, then moved.

        Parameters
        ----------
        position_mm : (3,) array_like, default (0, 0, 0)
            Translation applied after the rotation [mm].
        yaw_deg : float, default 0.0
            Rotation about +z, counter-clockwise seen from above [deg].

        Returns
        -------
        Part
            ``self.transformed(yaw_matrix(yaw_deg, position_mm))``.
        """
        return self.transformed(yaw_matrix(yaw_deg, position_mm))

    @property
    def triangle_count(self) -> int:
        """Number of triangles of the mesh [-]."""
        return int(len(self.mesh.faces))


@dataclass(frozen=True, eq=False)
class Assembly:
    """Parts posed together in the assembly (= part) frame [mm].

    Frozen; validated on construction.

    Parameters
    ----------
    name : str
        Preset name, mesh file name or scene name.
    parts : sequence of Part
        The parts (stored as a tuple), object ids 1..n in order.

    Raises
    ------
    MeshError
        When there is no part, or object ids repeat or are 0.
    """

    name: str
    parts: tuple = ()

    def __post_init__(self) -> None:
        if not self.parts:
            raise MeshError(f"assembly {self.name!r} has no parts")
        ids = [p.object_id for p in self.parts]
        if len(set(ids)) != len(ids) or 0 in ids:
            raise MeshError(f"assembly {self.name!r}: object ids must be unique and >= 1, got {ids}")
        object.__setattr__(self, "parts", tuple(self.parts))

    def combined_mesh(self) -> trimesh.Trimesh:
        """All parts in one mesh.

        Returns
        -------
        trimesh.Trimesh
            Vertices and faces of every part, concatenated in part order
            (not processed: no vertex is merged), assembly frame [mm];
            :meth:`face_object_ids` gives each face's part.
        """
        verts, faces, offset = [], [], 0
        for p in self.parts:
            verts.append(np.asarray(p.mesh.vertices, dtype=float))
            faces.append(np.asarray(p.mesh.faces, dtype=np.int64) + offset)
            offset += len(p.mesh.vertices)
        return trimesh.Trimesh(np.concatenate(verts), np.concatenate(faces), process=False)

    def face_object_ids(self) -> np.ndarray:
        """Object id of each face of :meth:`combined_mesh`.

        Returns
        -------
        (m,) int32
            The object id of the part each face belongs to.
        """
        return np.concatenate([np.full(len(p.mesh.faces), p.object_id, dtype=np.int32)
                               for p in self.parts])

    @property
    def bounds_mm(self) -> np.ndarray:
        """(2, 3) float: [[xmin, ymin, zmin], [xmax, ymax, zmax]] [mm]."""
        b = np.array([p.mesh.bounds for p in self.parts])
        return np.array([b[:, 0].min(axis=0), b[:, 1].max(axis=0)])

    @property
    def triangle_count(self) -> int:
        """Number of triangles of all parts [-]."""
        return sum(p.triangle_count for p in self.parts)

    def transformed(self, b_from_assembly: np.ndarray) -> Assembly:
        """The whole assembly moved by a rigid transform.

        Parameters
        ----------
        b_from_assembly : (4, 4) array_like
            Rigid transform from the assembly frame to frame b (e.g.
            ``stage_from_part``) [mm].

        Returns
        -------
        Assembly
            A copy with every part moved (:meth:`Part.transformed`).
        """
        return replace(self, parts=tuple(p.transformed(b_from_assembly) for p in self.parts))

    def summary(self) -> dict:
        """Figures of the assembly, JSON-ready.

        Returns
        -------
        dict
            ``name``, ``triangles``, ``mesh_bytes`` (vertex and face arrays)
            [bytes], ``bounds_mm`` [mm], and ``parts``: per part its name,
            object id, material, analytic ``kind``, triangle and vertex counts
            and mesh bytes.
        """
        parts = [{"name": p.name, "object_id": p.object_id, "material": p.material,
                  "kind": p.analytic.get("kind"), "triangles": p.triangle_count,
                  "vertices": int(len(p.mesh.vertices)),
                  "mesh_bytes": int(p.mesh.vertices.nbytes + p.mesh.faces.nbytes)}
                 for p in self.parts]
        return {"name": self.name, "triangles": self.triangle_count,
                "mesh_bytes": sum(p["mesh_bytes"] for p in parts),
                "bounds_mm": self.bounds_mm.tolist(), "parts": parts}

    def to_ply(self, path: str | os.PathLike) -> Path:
        """Write one binary PLY [mm] with a per-face ``object_id`` (atomic write).

        Vertices are stored as doubles (``x y z``), faces as ``vertex_indices``
        (uchar count, int indices) followed by ``int object_id``.  A comment
        line lists ``object_id name material`` for each part.

        Parameters
        ----------
        path : str or os.PathLike
            Destination file (written to a temporary name, then renamed).

        Returns
        -------
        pathlib.Path
            ``path``.
        """
        mesh = self.combined_mesh()
        comments = [f"scheimpflug scene {self.name}; units mm"]
        comments += [f"object_id {p.object_id} {p.name} {p.material}" for p in self.parts]
        return write_mesh_ply(path, mesh.vertices, mesh.faces, self.face_object_ids(), tuple(comments))


def read_ply(path: str | os.PathLike) -> tuple[trimesh.Trimesh, np.ndarray]:
    """Read a truth PLY (as written by :meth:`Assembly.to_ply`, or any triangle PLY).

    Read by :func:`scheimpflug.io.ply.read_mesh`, the project's one mesh
    reader (trimesh's loader; vertices as stored, no welding).

    Parameters
    ----------
    path : str or os.PathLike
        The PLY file.

    Returns
    -------
    mesh : trimesh.Trimesh
        The mesh [mm] (not processed), faces in file order.
    object_ids : (m,) int32
        Object id per face (all 1 if the file has no ``object_id``).

    Raises
    ------
    MeshError
        When the file cannot be read or parsed (including a body whose size
        does not match the header, non-triangle faces or out-of-range indices).
    """
    path = Path(path)
    try:
        vertices, faces, ids = read_mesh(path)
    except MeshError as exc:
        raise MeshError(f"{path}: cannot read PLY ({exc})") from None
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    ids = np.ones(len(faces), dtype=np.int32) if ids is None else ids.astype(np.int32)
    return mesh, ids


def warn_mesh(message: str) -> None:
    """Emit a :class:`MeshWarning` attributed to the caller of the public function."""
    warnings.warn(message, MeshWarning, stacklevel=4)
