"""PLY files: reconstructed point clouds (write, read back) and truth meshes (read).

Point clouds are binary little-endian PLY with one ``vertex`` element::

    property float x, y, z            part frame [mm]
    property uchar red, green, blue   colour by height z (perceptual colormap, viridis)
    property float angle_deg          rotary angle of the frame [deg]
    property int row                  sensor row [px]
    property float intensity          stripe peak above background [DN]
    property int frame                frame index in the scan (−1: unknown)

which any viewer (MeshLab, CloudCompare, Open3D) shows coloured, and whose
extra properties those tools keep as scalar fields.  The reader accepts any
PLY whose vertex element has x, y, z (ascii or binary, either byte order);
missing extras come back as NaN / −1.

Meshes are read with trimesh (PLY, STL, OBJ, ...) by one function,
:func:`read_triangle_mesh`, which also returns a PLY's scalar face properties:
``object_id`` (the twin's ``truth/mesh.ply``; a multi-object file such as an
OBJ with several objects gets one id per object), a surface model's ``fill``
and ``body`` (:mod:`scheimpflug.meshing`).  :func:`write_mesh_ply` writes a
binary PLY mesh (double vertices) with such face properties.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scheimpflug.errors import MeshError
from scheimpflug.io.atomic import atomic_path
from scheimpflug.reconstruct import PointCloud

__all__ = [
    "TriangleMesh",
    "height_colors",
    "read_mesh",
    "read_point_cloud",
    "read_triangle_mesh",
    "write_mesh_ply",
    "write_point_cloud",
]

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
    "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
_CLOUD_DTYPE = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"),
                         ("blue", "u1"), ("angle_deg", "<f4"), ("row", "<i4"), ("intensity", "<f4"),
                        ("frame", "<i4")])
_PLY_NAME = {"f4": "float", "u1": "uchar", "i4": "int"}


# matplotlib's "viridis" sampled at 17 equal steps (np.round(colormaps["viridis"](np.linspace(0, 1, 17))
# [:, :3] * 255), matplotlib 3.9); linear interpolation between them stays within 5.2 of 255 of the
# full table, plenty for colouring a cloud, and keeps matplotlib out of the instrument core.
_VIRIDIS_17 = np.array([
    [68, 1, 84], [72, 24, 106], [71, 45, 123], [66, 64, 134], [59, 82, 139], [51, 99, 141],
    [44, 114, 142], [38, 130, 142], [33, 145, 140], [31, 160, 136], [40, 174, 128], [63, 188, 115],
    [94, 201, 98], [132, 212, 75], [173, 220, 48], [216, 226, 25], [253, 231, 37]], dtype=np.float64)


def height_colors(z_mm: np.ndarray) -> np.ndarray:
    """Viridis colours of heights over their 1–99 % range.

    Parameters
    ----------
    z_mm : (n,) float
        Heights [mm].

    Returns
    -------
    (n, 3) uint8
        RGB, dark purple at the 1st percentile to yellow at the 99th.
    """
    z = np.asarray(z_mm, dtype=np.float64)
    if z.size == 0:
        return np.zeros((0, 3), np.uint8)
    lo, hi = np.percentile(z, [1, 99])
    t = np.clip((z - lo) / (hi - lo), 0, 1) if hi > lo else np.full(z.shape, 0.5)
    knots = np.linspace(0.0, 1.0, len(_VIRIDIS_17))
    rgb = np.stack([np.interp(t, knots, _VIRIDIS_17[:, i]) for i in range(3)], axis=-1)
    return np.round(rgb).astype(np.uint8)


def write_point_cloud(path: str | os.PathLike, cloud: PointCloud, comment: str = "") -> Path:
    """Write ``cloud`` as a binary PLY coloured by height, atomically.

    Parameters
    ----------
    path : str or os.PathLike
        Destination ``.ply``; written to a temporary name, then renamed.
    cloud : PointCloud
        Points in the part frame [mm] with angle, row and intensity (stored
        as float32 / int32).
    comment : str, optional
        Extra header comment (one line: whitespace runs are collapsed; e.g.
        the command that made it).

    Returns
    -------
    Path
        ``path``.
    """
    data = np.empty(len(cloud), dtype=_CLOUD_DTYPE)
    for k, name in enumerate("xyz"):
        data[name] = cloud.xyz_mm[:, k]
    rgb = height_colors(cloud.xyz_mm[:, 2])
    data["red"], data["green"], data["blue"] = rgb[:, 0], rgb[:, 1], rgb[:, 2]
    data["angle_deg"], data["row"], data["intensity"] = cloud.angle_deg, cloud.row, cloud.intensity
    data["frame"] = cloud.frame if cloud.frame is not None else -1
    lines = ["ply", "format binary_little_endian 1.0",
             "comment scheimpflug point cloud; part frame; units mm; colour = height (viridis)"]
    lines += [f"comment {' '.join(comment.split())}"] if comment else []
    lines += [f"element vertex {len(cloud)}"]
    lines += [f"property {_PLY_NAME[data.dtype[n].str[1:]]} {n}" for n in data.dtype.names]
    header = "\n".join(lines + ["end_header"]) + "\n"
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(data.tobytes())
    return Path(path)


def _parse_header(fh, path: Path) -> tuple[str, list]:
    if fh.readline().strip() != b"ply":
        raise MeshError(f"{str(path)!r} is not a PLY file (no 'ply' magic line)")
    fmt, elements = None, []
    while True:
        line = fh.readline()
        if not line:
            raise MeshError(f"{str(path)!r}: PLY header has no 'end_header'")
        words = line.decode("ascii", "replace").split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "end_header":
            break
        if words[0] == "format" and len(words) >= 2:
            fmt = words[1]
        elif words[0] == "element" and len(words) == 3 and words[2].isdigit():
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property" and elements and len(words) >= 3:
            elements[-1][2].append(words[1:])
        else:
            raise MeshError(f"{str(path)!r}: malformed PLY header line {line.strip()!r}")
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise MeshError(f"{str(path)!r}: unknown PLY format {fmt!r}")
    return fmt, elements


def _vertex_dtype(props: list, fmt: str, path: Path) -> np.dtype:
    order = ">" if fmt == "binary_big_endian" else "<"
    fields = []
    for p in props:
        if p[0] == "list" or p[0] not in _PLY_TYPES or len(p) != 2:
            raise MeshError(f"{str(path)!r}: unsupported vertex property {' '.join(p)!r}")
        fields.append((p[1], order + _PLY_TYPES[p[0]]))
    return np.dtype(fields)


def read_point_cloud(path: str | os.PathLike) -> PointCloud:
    """Read a point cloud PLY (the vertex element; any faces after it are ignored).

    Parameters
    ----------
    path : str or os.PathLike
        A PLY file (ascii or binary, either byte order) whose first element is
        ``vertex`` with scalar properties x, y, z.

    Returns
    -------
    PointCloud
        Points (n, 3) float64 [mm] (part frame for the clouds this toolkit
        writes); ``angle_deg`` and ``intensity`` NaN and ``row`` −1 where the
        file lacks them.

    Raises
    ------
    MeshError
        Missing, non-PLY, truncated or malformed file, list or unknown vertex
        properties, or no x, y, z.
    """
    p = Path(path)
    if not p.is_file():
        raise MeshError(f"point cloud {str(p)!r} does not exist")
    with open(p, "rb") as fh:
        fmt, elements = _parse_header(fh, p)
        if not elements or elements[0][0] != "vertex":
            raise MeshError(f"{str(p)!r}: the first PLY element must be 'vertex'")
        _, n, props = elements[0]
        dtype = _vertex_dtype(props, fmt, p)
        if not {"x", "y", "z"} <= set(dtype.names):
            raise MeshError(f"{str(p)!r}: PLY vertices lack x, y, z")
        data = _read_body(fh, fmt, dtype, n, p)

    def get(name: str, fill: float) -> np.ndarray:
        return data[name].astype(np.float64) if name in dtype.names else np.full(n, fill, np.float64)

    xyz = np.column_stack([data["x"], data["y"], data["z"]]).astype(np.float64)
    return PointCloud(xyz_mm=xyz, angle_deg=get("angle_deg", np.nan),
                      row=get("row", -1).astype(np.int64), intensity=get("intensity", np.nan),
                      frame=get("frame", -1).astype(np.int64))


def _read_body(fh, fmt: str, dtype: np.dtype, n: int, path: Path) -> np.ndarray:
    if fmt == "ascii":
        rows = [fh.readline().split() for _ in range(n)]
        if any(len(r) < len(dtype.names) for r in rows):
            raise MeshError(f"{str(path)!r}: truncated or malformed ascii PLY vertex data")
        try:
            table = np.array([r[:len(dtype.names)] for r in rows], dtype=np.float64).reshape(n, -1)
        except ValueError:
            raise MeshError(f"{str(path)!r}: non-numeric ascii PLY vertex data") from None
        out = np.empty(n, dtype=dtype)
        for k, name in enumerate(dtype.names):
            out[name] = table[:, k]
        return out
    raw = fh.read(n * dtype.itemsize)
    if len(raw) != n * dtype.itemsize:
        raise MeshError(f"{str(path)!r}: truncated PLY ({len(raw)} of {n * dtype.itemsize} bytes of "
                        f"vertex data)")
    return np.frombuffer(raw, dtype=dtype)


@dataclass(frozen=True)
class TriangleMesh:
    """A triangle mesh as read from a file, with its per-face properties.

    Parameters
    ----------
    vertices : (nv, 3) float
        Vertex positions [mm] (coincident vertices welded).
    faces : (m, 3) int
        Triangles, in file order.
    face_properties : dict of str to (m,) ndarray
        Scalar face properties of a PLY (``object_id``, a model's ``fill`` and
        ``body``, ...); for a file with several objects (a trimesh Scene),
        ``object_id`` = the object's index + 1.
    """

    vertices: np.ndarray
    faces: np.ndarray
    face_properties: dict


def _load_trimesh(p: Path):
    import trimesh

    if not p.is_file():
        raise MeshError(f"mesh {str(p)!r} does not exist")
    try:
        loaded = trimesh.load(str(p), process=False)
    except Exception as exc:  # trimesh raises many types for corrupt files
        raise MeshError(f"mesh {str(p)!r} is unreadable: {type(exc).__name__}: {exc}") from None
    props = {}
    if isinstance(loaded, trimesh.Scene):
        geoms = [g for g in loaded.dump() if isinstance(g, trimesh.Trimesh) and len(g.faces)]
        if not geoms:
            raise MeshError(f"{str(p)!r} holds no triangles (not a mesh)")
        props["object_id"] = np.concatenate([np.full(len(g.faces), k + 1) for k, g in enumerate(geoms)])
        loaded = trimesh.util.concatenate(geoms)
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise MeshError(f"{str(p)!r} holds no triangles (not a mesh: {type(loaded).__name__})")
    return loaded, props


def _ply_face_properties(loaded) -> dict:
    raw = loaded.metadata.get("_ply_raw") if isinstance(loaded.metadata, dict) else None
    if raw is None or "face" not in raw:
        return {}
    data = raw["face"]["data"]
    names = [n for n in (data.dtype.names or ()) if n not in ("vertex_indices", "vertex_index")]
    return {n: np.asarray(data[n]).ravel() for n in names if np.asarray(data[n]).ndim <= 2
            and np.asarray(data[n]).size == len(loaded.faces)}


def read_triangle_mesh(path: str | os.PathLike) -> TriangleMesh:
    """Read a triangle mesh and its face properties (coincident vertices welded, face order kept).

    Parameters
    ----------
    path : str or os.PathLike
        PLY, STL, OBJ or any format trimesh reads.

    Returns
    -------
    TriangleMesh
        Vertices [mm], faces and the PLY's scalar face properties.

    Raises
    ------
    MeshError
        Missing, unreadable or empty file, or a file without triangles.
    """
    p = Path(path)
    loaded, props = _load_trimesh(p)
    n_faces = len(loaded.faces)
    props.update(_ply_face_properties(loaded))
    loaded.merge_vertices()          # STL stores each face's own vertices: weld them (face order kept)
    if len(loaded.faces) != n_faces:
        raise MeshError(f"{str(p)!r}: internal error, welding vertices changed the face count")
    return TriangleMesh(vertices=np.asarray(loaded.vertices, np.float64),
                        faces=np.asarray(loaded.faces, np.int64), face_properties=props)


def read_mesh(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Read a triangle mesh for scoring (:func:`read_triangle_mesh`, object ids only).

    Parameters
    ----------
    path : path-like
        PLY, STL, OBJ or any format trimesh reads.

    Returns
    -------
    vertices : (nv, 3) ndarray float64
        Vertex positions, in the file's frame and units [mm] (the part frame
        for the twin's truth meshes).
    faces : (m, 3) ndarray int64
        Vertex indices of each triangle, in file order.
    face_object_id : (m,) ndarray int64 or None
        PLY ``object_id`` face property; for a file with several objects
        (a trimesh Scene), the object's index + 1; else None.

    Raises
    ------
    MeshError
        Missing, unreadable or empty file, or a file without triangles.
    """
    mesh = read_triangle_mesh(path)
    ids = mesh.face_properties.get("object_id")
    return mesh.vertices, mesh.faces, None if ids is None else np.asarray(ids).astype(np.int64)


_FACE_PLY = {"u1": "uchar", "i4": "int", "f4": "float", "f8": "double"}


def write_mesh_ply(path: str | os.PathLike, vertices: np.ndarray, faces: np.ndarray,
                   face_properties: dict | None = None, comment: str = "") -> Path:
    """Write a triangle mesh as a binary PLY with scalar face properties, atomically.

    Parameters
    ----------
    path : path-like
        Destination ``.ply``.
    vertices : (nv, 3) float
        Vertex positions [mm] (written as double).
    faces : (m, 3) int
        Triangles.
    face_properties : dict of str to (m,) array, optional
        Scalar face properties, written as ``uchar`` (uint8 arrays), ``int``,
        ``float`` or ``double`` (e.g. a model's ``fill`` and ``body``).
    comment : str
        Extra header comment (one line).

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    MeshError
        Malformed arrays or a face property of the wrong length or type.
    """
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3:
        raise MeshError(f"a mesh needs (n, 3) vertices and (m, 3) faces, got {v.shape} and {f.shape}")
    props = {k: np.asarray(a) for k, a in (face_properties or {}).items()}
    fields = [("n", "u1"), ("vertex_indices", "<i4", (3,))]
    for name, a in props.items():
        kind = a.dtype.str[1:] if a.dtype.str[1:] in _FACE_PLY else ("i4" if a.dtype.kind in "iub" else "f8")
        if a.shape != (len(f),):
            raise MeshError(f"face property {name!r} has shape {a.shape}, expected ({len(f)},)")
        fields.append((name, "<" + kind if kind != "u1" else "u1"))
    data = np.zeros(len(f), dtype=np.dtype(fields))
    data["n"], data["vertex_indices"] = 3, f
    for name, a in props.items():
        data[name] = a
    lines = ["ply", "format binary_little_endian 1.0", "comment scheimpflug mesh; units mm"]
    lines += [f"comment {' '.join(comment.split())}"] if comment else []
    lines += [f"element vertex {len(v)}", "property double x", "property double y", "property double z",
              f"element face {len(f)}", "property list uchar int vertex_indices"]
    lines += [f"property {_FACE_PLY[data.dtype[n].str[1:]]} {n}" for n in props]
    header = "\n".join(lines + ["end_header"]) + "\n"
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(v.astype("<f8").tobytes())
        fh.write(data.tobytes())
    return Path(path)
