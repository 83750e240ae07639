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
from scheimpflug.io.atomic import atomic_path

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
    """4 × 4 rigid transform ``T(position) · Rz(yaw)``.

    Parameters
    ----------
    yaw_deg : rotation about +z, counter-clockwise seen from above [deg].
    position_mm : (3,) float, translation applied after the rotation [mm].

    Returns
    -------
    (4, 4) float
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

    Attributes
    ----------
    name : str, e.g. ``"ring"``.
    mesh : trimesh.Trimesh, triangles in [mm], in the assembly frame (see module doc).
    material : one of :data:`MATERIALS`.
    analytic : dict, JSON-serialisable exact description: ``kind``, dimensions
        [mm], knurl parameters, and ``mesh_from_part`` (4 × 4 nested list).
    object_id : int, 1-based id, unique within an assembly (0 = background).
    """

    name: str
    mesh: trimesh.Trimesh
    material: str = "metal"
    analytic: dict = field(default_factory=dict)
    object_id: int = 1

    def __post_init__(self) -> None:
        if self.material not in MATERIALS:
            raise MeshError(f"part {self.name!r}: unknown material {self.material!r} "
                            f"(known: {', '.join(MATERIALS)})")
        if not isinstance(self.object_id, int) or self.object_id < 0:
            raise MeshError(f"part {self.name!r}: object_id must be an int >= 0, got {self.object_id!r}")
        if len(self.mesh.faces) == 0:
            raise MeshError(f"part {self.name!r}: mesh has no triangles")
        _check_json(self.name, self.analytic)

    @property
    def mesh_from_part(self) -> np.ndarray:
        """(4, 4) float: own (analytic) frame → mesh frame."""
        return np.asarray(self.analytic.get("mesh_from_part", np.eye(4).tolist()), dtype=float)

    def transformed(self, b_from_mesh: np.ndarray) -> Part:
        """The part moved by the rigid 4 × 4 transform ``b_from_mesh`` (analytic pose updated)."""
        m = np.asarray(b_from_mesh, dtype=float)
        mesh = self.mesh.copy()
        mesh.apply_transform(m)
        analytic = dict(self.analytic, mesh_from_part=(m @ self.mesh_from_part).tolist())
        return replace(self, mesh=mesh, analytic=analytic)

    def posed(self, position_mm=(0.0, 0.0, 0.0), yaw_deg: float = 0.0) -> Part:
        """The part turned by ``yaw_deg`` about its ``z`` axis, then moved by ``position_mm``."""
        return self.transformed(yaw_matrix(yaw_deg, position_mm))

    @property
    def triangle_count(self) -> int:
        return int(len(self.mesh.faces))


@dataclass(frozen=True, eq=False)
class Assembly:
    """Parts posed together in the assembly (= part) frame [mm].

    Attributes
    ----------
    name : str, preset name, mesh file name or scene name.
    parts : tuple of :class:`Part`, object ids 1..n in order.
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
        """All parts in one mesh (faces in part order; see :meth:`face_object_ids`)."""
        verts, faces, offset = [], [], 0
        for p in self.parts:
            verts.append(np.asarray(p.mesh.vertices, dtype=float))
            faces.append(np.asarray(p.mesh.faces, dtype=np.int64) + offset)
            offset += len(p.mesh.vertices)
        return trimesh.Trimesh(np.concatenate(verts), np.concatenate(faces), process=False)

    def face_object_ids(self) -> np.ndarray:
        """(m,) int32 object id of each face of :meth:`combined_mesh`."""
        return np.concatenate([np.full(len(p.mesh.faces), p.object_id, dtype=np.int32)
                               for p in self.parts])

    @property
    def bounds_mm(self) -> np.ndarray:
        """(2, 3) float: [[xmin, ymin, zmin], [xmax, ymax, zmax]] [mm]."""
        b = np.array([p.mesh.bounds for p in self.parts])
        return np.array([b[:, 0].min(axis=0), b[:, 1].max(axis=0)])

    @property
    def triangle_count(self) -> int:
        return sum(p.triangle_count for p in self.parts)

    def transformed(self, b_from_assembly: np.ndarray) -> Assembly:
        """The whole assembly moved by a rigid 4 × 4 transform (e.g. ``stage_from_part``)."""
        return replace(self, parts=tuple(p.transformed(b_from_assembly) for p in self.parts))

    def summary(self) -> dict:
        """JSON-ready figures: per-part triangle counts, mesh memory [bytes], bounds [mm]."""
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
        """
        mesh = self.combined_mesh()
        header = _ply_header(self, len(mesh.vertices), len(mesh.faces))
        faces = np.empty(len(mesh.faces), dtype=_FACE_DTYPE)
        faces["n"], faces["v"], faces["id"] = 3, mesh.faces, self.face_object_ids()
        with atomic_path(path) as tmp, open(tmp, "wb") as fh:
            fh.write(header.encode("ascii"))
            fh.write(np.ascontiguousarray(mesh.vertices, dtype="<f8").tobytes())
            fh.write(faces.tobytes())
        return Path(path)


def _ply_header(asm: Assembly, n_vertices: int, n_faces: int) -> str:
    lines = ["ply", "format binary_little_endian 1.0",
             f"comment scheimpflug scene {asm.name.replace(chr(10), ' ')}; units mm"]
    lines += [f"comment object_id {p.object_id} {p.name} {p.material}" for p in asm.parts]
    lines += [f"element vertex {n_vertices}", "property double x", "property double y",
              "property double z", f"element face {n_faces}",
              "property list uchar int vertex_indices", "property int object_id", "end_header"]
    return "\n".join(lines) + "\n"


_FACE_DTYPE = np.dtype([("n", "u1"), ("v", "<i4", (3,)), ("id", "<i4")])
_OUR_PROPS = ["property double x", "property double y", "property double z",
              "property list uchar int vertex_indices", "property int object_id"]


def _read_own_ply(data: bytes):
    """Fast path for the exact layout written by :meth:`Assembly.to_ply`; None otherwise."""
    end = data.find(b"end_header\n")
    if not data.startswith(b"ply\n") or end < 0:
        return None
    lines = data[:end].decode("ascii", "replace").splitlines()
    if "format binary_little_endian 1.0" not in lines:
        return None
    props = [ln for ln in lines if ln.startswith("property")]
    counts = [int(ln.split()[2]) for ln in lines if ln.startswith("element")]
    elements = [ln.split()[1] for ln in lines if ln.startswith("element")]
    if props != _OUR_PROPS or elements != ["vertex", "face"]:
        return None
    nv, nf = counts
    body = memoryview(data)[end + len(b"end_header\n"):]
    if len(body) != nv * 24 + nf * _FACE_DTYPE.itemsize:
        raise ValueError(f"body has {len(body)} bytes, header announces {nv} vertices and {nf} faces")
    verts = np.frombuffer(body[:nv * 24], dtype="<f8").reshape(nv, 3)
    faces = np.frombuffer(body[nv * 24:], dtype=_FACE_DTYPE)
    if np.any(faces["n"] != 3) or (nf and (faces["v"].min() < 0 or faces["v"].max() >= nv)):
        raise ValueError("faces are not triangles or index missing vertices")
    mesh = trimesh.Trimesh(verts.astype(float), faces["v"].astype(np.int64), process=False)
    return mesh, faces["id"].astype(np.int32)


def read_ply(path: str | os.PathLike) -> tuple[trimesh.Trimesh, np.ndarray]:
    """Read a truth PLY (as written by :meth:`Assembly.to_ply`, or any triangle PLY).

    Returns
    -------
    mesh : trimesh.Trimesh [mm], faces in file order.
    object_ids : (m,) int32 per face (all 1 if the file has no ``object_id``).
    """
    path = Path(path)
    try:
        own = _read_own_ply(path.read_bytes())
        if own is not None:
            return own
        mesh = trimesh.load(path, file_type="ply", process=False, force="mesh")
    except Exception as exc:  # trimesh raises many kinds on corrupt input
        raise MeshError(f"{path}: cannot read PLY ({exc})") from None
    raw = mesh.metadata.get("_ply_raw", {}).get("face", {}).get("data")
    names = getattr(getattr(raw, "dtype", None), "names", None) or ()
    ids = raw["object_id"] if "object_id" in names else np.ones(len(mesh.faces), dtype=np.int32)
    return mesh, np.asarray(ids, dtype=np.int32).reshape(-1)


def warn_mesh(message: str) -> None:
    """Emit a :class:`MeshWarning` attributed to the caller of the public function."""
    warnings.warn(message, MeshWarning, stacklevel=4)
