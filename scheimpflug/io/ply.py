"""PLY files: reconstructed point clouds (write, read back) and truth meshes (read).

Point clouds are binary little-endian PLY with one ``vertex`` element::

    property float x, y, z            part frame [mm]
    property uchar red, green, blue   colour by height z (perceptual colormap, viridis)
    property float angle_deg          rotary angle of the frame [deg]
    property int row                  sensor row [px]
    property float intensity          stripe peak above background [DN]
    property int frame                frame index in the scan (−1: unknown)
    property float stripe_width_px    RMS width of the stripe in the point's row [px]
    property float snr                stripe peak over the background noise [-]
    property float incidence_laser_deg   angle between surface normal and laser ray [deg]
    property float incidence_camera_deg  angle between surface normal and line of sight [deg]
    property uchar sweep_edge         1: a partly lit edge of the sheet's sweep, 0: not, 255: unknown
    property uchar saturated          1: the stripe's peak was clipped in the point's row, 0: not, 255: unknown
    property float centre_sigma_px    standard uncertainty of the stripe centre from the noise [px]

(the point quality, :mod:`scheimpflug.point_quality`; NaN where a quality is
unknown) which any viewer (MeshLab, CloudCompare, Open3D) shows coloured, and
whose extra properties those tools keep as scalar fields; a reader that does
not know the quality properties skips them by name, as PLY allows.  The reader
accepts any PLY whose vertex element has x, y, z (ascii or binary, either byte
order); missing extras come back as NaN / −1, missing quality fields as None.

Meshes (the twin's ``truth/mesh.ply``: double vertices and an ``object_id``
per face; a surface model's ``fill`` and ``body`` per face,
:mod:`scheimpflug.meshing`) are written by :func:`write_mesh_ply`, the one
writer whose exact header matters.  Every file is read by one path, trimesh's
loader (:func:`read_point_cloud`, :func:`read_triangle_mesh` and its
shorthand :func:`read_mesh`; PLY, STL, OBJ, …; 18 ms for the 31 MB,
1.09 M-triangle cylinder mesh), with a header check that turns a non-PLY into
one clear error; a PLY's scalar face properties are returned per face, and a
multi-object file (an OBJ with several objects) gets one ``object_id`` per
object.
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

_CLOUD_DTYPE = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"),
                         ("blue", "u1"), ("angle_deg", "<f4"), ("row", "<i4"), ("intensity", "<f4"),
                         ("frame", "<i4"), ("stripe_width_px", "<f4"), ("snr", "<f4"),
                         ("incidence_laser_deg", "<f4"), ("incidence_camera_deg", "<f4"), ("sweep_edge", "u1"),
                         ("saturated", "u1"), ("centre_sigma_px", "<f4")])
_QUALITY_FLOATS = ("stripe_width_px", "snr", "incidence_laser_deg", "incidence_camera_deg", "centre_sigma_px")
_QUALITY_FLAGS = ("sweep_edge", "saturated")
_EDGE_UNKNOWN = 255
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
        Points in the part frame [mm] with angle, row, intensity and frame
        index (stored as float32 / int32; frame −1 when unknown), and the
        point quality (float32, NaN when unknown; ``sweep_edge`` and ``saturated`` uchar,
        255 unknown).
    comment : str, optional
        Extra header comment (one line: whitespace runs are collapsed, and
        non-ASCII characters escaped as Python's ``backslashreplace`` does, a
        PLY header being ASCII;
        e.g. the command that made it).

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
    for name in _QUALITY_FLOATS:
        data[name] = getattr(cloud, name) if getattr(cloud, name) is not None else np.nan
    for name in _QUALITY_FLAGS:
        flag = getattr(cloud, name)
        data[name] = _EDGE_UNKNOWN if flag is None else np.asarray(flag, bool)
    lines = ["ply", "format binary_little_endian 1.0",
             "comment scheimpflug point cloud; part frame; units mm; colour = height (viridis)"]
    lines += [f"comment {_ascii(comment)}"] if comment else []
    lines += [f"element vertex {len(cloud)}"]
    lines += [f"property {_PLY_NAME[data.dtype[n].str[1:]]} {n}" for n in data.dtype.names]
    header = "\n".join(lines + ["end_header"]) + "\n"
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(data.tobytes())
    return Path(path)


def write_mesh_ply(path: str | os.PathLike, vertices_mm, faces, face_object_id=None,
                   comments: tuple[str, ...] = (), face_properties: dict | None = None) -> Path:
    """Write a triangle mesh with per-face properties as binary PLY, atomically.

    The layout (the twin's ``truth/mesh.ply``) is ``element vertex`` with
    ``double x, y, z`` and ``element face`` with ``list uchar int
    vertex_indices`` and ``int object_id``: doubles keep the exact geometry
    that was rendered, and the object id says which part each face belongs
    to.  Further scalar face properties (a surface model's ``uchar fill`` and
    ``int body``) follow.  :func:`read_triangle_mesh` reads them back (as does
    any PLY reader).

    Parameters
    ----------
    path : str or os.PathLike
        Destination ``.ply``; written to a temporary name, then renamed.
    vertices_mm : (nv, 3) array_like float
        Vertex positions [mm].
    faces : (m, 3) array_like int
        Vertex indices of each triangle.
    face_object_id : (m,) array_like int or None
        Object id of each face (None: no ``object_id`` property).
    comments : tuple of str, optional
        Header comment lines (newlines are replaced by spaces, non-ASCII
        characters escaped as Python's ``backslashreplace`` does).
    face_properties : dict of str to (m,) array_like, optional
        More scalar face properties, written as ``uchar`` (uint8 arrays),
        ``int`` (other integers) or ``double``.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    ValueError
        Shapes that do not match, or face indices outside the vertex list.
    """
    v = np.ascontiguousarray(vertices_mm, dtype="<f8")
    f = np.asarray(faces)
    props = {} if face_object_id is None else {"object_id": np.asarray(face_object_id)}
    props.update({k: np.asarray(a) for k, a in (face_properties or {}).items()})
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"need vertices (nv, 3) and faces (m, 3), got {v.shape} and {f.shape}")
    bad = [k for k, a in props.items() if a.shape != (len(f),)]
    if bad:
        raise ValueError(f"face property {bad[0]!r} must have shape ({len(f)},), got {props[bad[0]].shape}")
    if len(f) and (f.min() < 0 or f.max() >= len(v)):
        raise ValueError(f"face indices must lie in [0, {len(v)}), got [{f.min()}, {f.max()}]")
    kinds = {k: ("u1" if a.dtype == np.uint8 else "<i4" if a.dtype.kind in "iub" else "<f8")
             for k, a in props.items()}
    table = np.empty(len(f), dtype=np.dtype([("n", "u1"), ("v", "<i4", (3,))] + list(kinds.items())))
    table["n"], table["v"] = 3, f
    for k, a in props.items():
        table[k] = a
    names = {"u1": "uchar", "<i4": "int", "<f8": "double"}
    lines = ["ply", "format binary_little_endian 1.0"]
    lines += [f"comment {_ascii(c)}" for c in comments]
    lines += [f"element vertex {len(v)}", "property double x", "property double y", "property double z",
              f"element face {len(f)}", "property list uchar int vertex_indices"]
    lines += [f"property {names[kind]} {k}" for k, kind in kinds.items()] + ["end_header"]
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(("\n".join(lines) + "\n").encode("ascii"))
        fh.write(v.tobytes())
        fh.write(table.tobytes())
    return Path(path)


def _ascii(text) -> str:
    """One header comment line in ASCII (PLY headers are ASCII), non-ASCII backslash-escaped."""
    return " ".join(str(text).split()).encode("ascii", "backslashreplace").decode("ascii")


def _check_ply_header(path: Path) -> list[tuple[str, int]]:
    """The (element, count) list of a PLY header; MeshError for a file that is not a PLY.

    Also refuses counts the file cannot hold (every item of an element takes at
    least one byte in binary, two in ASCII), before any reader allocates for them.
    """
    with open(path, "rb") as fh:
        head = fh.read(65536)
    end = head.find(b"end_header")
    if not head.startswith(b"ply"):
        raise MeshError(f"{str(path)!r} is not a PLY file (no 'ply' magic line)")
    if end < 0:
        raise MeshError(f"{str(path)!r}: PLY header has no 'end_header'")
    elements, ascii_body = [], False
    for line in head[:end].decode("ascii", "replace").splitlines():
        words = line.split()
        if len(words) >= 2 and words[0] == "format":
            ascii_body = words[1] == "ascii"
        if len(words) == 3 and words[0] == "element":
            if not words[2].isdigit():
                raise MeshError(f"{str(path)!r}: malformed PLY header line {line.strip()!r}")
            elements.append((words[1], int(words[2])))
    body = path.stat().st_size - (head.find(b"\n", end) + 1)
    items = sum(n for _, n in elements) * (2 if ascii_body else 1)
    if items > body:
        what = ", ".join(f"{n} {name}" for name, n in elements)
        raise MeshError(f"{str(path)!r}: the PLY header announces {what} but only {max(body, 0)} bytes "
                        "follow it: the file is truncated, empty or corrupt")
    return elements


def _load(path: str | os.PathLike, what: str):
    """Read ``path`` with trimesh's loader (the one reader of this module), errors as MeshError."""
    import trimesh

    p = Path(path)
    if p.is_dir():
        truth = p / "truth" / "mesh.ply"
        hint = f" (did you mean {str(truth)!r}?)" if truth.is_file() else ""
        raise MeshError(f"{what} {str(p)!r} is a folder, not a file{hint}")
    if not p.is_file():
        raise MeshError(f"{what} {str(p)!r} does not exist")
    elements = _check_ply_header(p) if p.suffix.lower() == ".ply" else None
    try:
        loaded = trimesh.load(str(p), process=False)
    except Exception as exc:  # trimesh raises many kinds on corrupt input
        if "unexpected length" in str(exc):
            raise MeshError(f"{what} {str(p)!r} is truncated or corrupt: the PLY body does not match "
                            "its header") from None
        raise MeshError(f"{what} {str(p)!r} is unreadable: {type(exc).__name__}: {exc}") from None
    return loaded, elements


def _ply_raw(loaded, element: str) -> dict[str, np.ndarray] | None:
    """The properties of a PLY element as trimesh read it, name → (n,) array, or None.

    trimesh keeps binary elements as one structured array and ascii ones as a
    dict of (n, 1) arrays; both come back as a dict of flat arrays.
    """
    meta = getattr(loaded, "metadata", None)
    raw = meta.get("_ply_raw") if isinstance(meta, dict) else None
    if raw is None or element not in raw:
        return None
    data = raw[element]["data"]
    names = data.keys() if isinstance(data, dict) else (data.dtype.names or ())
    return {name: np.asarray(data[name]).reshape(len(np.asarray(data[name])), -1)[:, 0] for name in names}


def read_point_cloud(path: str | os.PathLike) -> PointCloud:
    """Read a point cloud PLY (the vertex element; any faces after it are ignored).

    Parameters
    ----------
    path : str or os.PathLike
        A PLY file (ascii or binary, either byte order) whose vertex element
        has scalar properties x, y, z.

    Returns
    -------
    PointCloud
        Points (n, 3) float64 [mm] (part frame for the clouds this toolkit
        writes); ``angle_deg`` and ``intensity`` NaN and ``row`` and
        ``frame`` −1 where the file lacks them; each quality field None
        where the file lacks it (``sweep_edge`` and ``saturated`` also when every value is 255,
        unknown).

    Raises
    ------
    MeshError
        Missing, non-PLY, truncated or malformed file, or no x, y, z.
    """
    loaded, elements = _load(path, "point cloud")
    if elements is None:
        raise MeshError(f"point cloud {str(path)!r} must be a .ply file")
    if dict(elements).get("vertex") == 0:
        return PointCloud(np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int64), np.zeros(0))
    data = _ply_raw(loaded, "vertex") or {}
    if not {"x", "y", "z"} <= set(data):
        raise MeshError(f"{str(path)!r}: PLY vertices lack x, y, z")
    n = len(data["x"])

    def get(name: str, fill: float) -> np.ndarray:
        return data[name].astype(np.float64) if name in data else np.full(n, fill)

    xyz = np.column_stack([get("x", 0), get("y", 0), get("z", 0)])
    quality = {name: data[name].astype(np.float64) for name in _QUALITY_FLOATS if name in data}
    for name in _QUALITY_FLAGS:
        flag = data.get(name)
        if flag is not None and np.any(flag != _EDGE_UNKNOWN):
            quality[name] = flag == 1
    return PointCloud(xyz_mm=xyz, angle_deg=get("angle_deg", np.nan),
                      row=get("row", -1).astype(np.int64), intensity=get("intensity", np.nan),
                      frame=get("frame", -1).astype(np.int64), **quality)


@dataclass(frozen=True)
class TriangleMesh:
    """A triangle mesh as read from a file, with its per-face properties.

    Parameters
    ----------
    vertices : (nv, 3) ndarray float64
        Vertex positions, in the file's frame and units [mm].
    faces : (m, 3) ndarray int64
        Vertex indices of each triangle, in file order.
    face_properties : dict of str to (m,) ndarray
        Scalar face properties of a PLY (``object_id``, a surface model's
        ``fill`` and ``body``, ...); for a file with several objects (a
        trimesh Scene), ``object_id`` = the object's index + 1.
    """

    vertices: np.ndarray
    faces: np.ndarray
    face_properties: dict


def read_triangle_mesh(path: str | os.PathLike) -> TriangleMesh:
    """Read a triangle mesh and its face properties (coincident vertices welded, faces in file order).

    Parameters
    ----------
    path : str or os.PathLike
        PLY, STL, OBJ or any format trimesh reads.

    Returns
    -------
    TriangleMesh
        Vertices [mm], faces and the scalar face properties.

    Raises
    ------
    MeshError
        Missing, unreadable or empty file, or a file without triangles.
    """
    import trimesh

    loaded, elements = _load(path, "mesh")
    p = Path(path)
    props = {}
    if isinstance(loaded, trimesh.Scene):
        geoms = [g for g in loaded.dump() if isinstance(g, trimesh.Trimesh) and len(g.faces)]
        if not geoms:
            raise MeshError(f"{str(p)!r} holds no triangles (not a mesh)")
        props["object_id"] = np.concatenate([np.full(len(g.faces), k + 1) for k, g in enumerate(geoms)])
        loaded = trimesh.util.concatenate(geoms)
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise MeshError(f"{str(p)!r} holds no triangles (not a mesh: {type(loaded).__name__})")
    if elements is None:             # STL, OBJ: faces may carry their own vertices; weld them
        n_faces = len(loaded.faces)
        loaded.merge_vertices()
        if len(loaded.faces) != n_faces:
            raise MeshError(f"{str(p)!r}: internal error, welding vertices changed the face count")
    nv = len(loaded.vertices)
    if loaded.faces.min() < 0 or loaded.faces.max() >= nv:
        raise MeshError(f"{str(p)!r}: face indices outside the {nv} vertices (corrupt mesh)")
    raw = _ply_raw(loaded, "face") or {}
    props.update({k: a for k, a in raw.items() if k not in ("vertex_indices", "vertex_index")
                  and a.shape == (len(loaded.faces),)})
    return TriangleMesh(vertices=np.asarray(loaded.vertices, np.float64),
                        faces=np.asarray(loaded.faces, np.int64), face_properties=props)


def read_mesh(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Read a triangle mesh for scoring (:func:`read_triangle_mesh`, object ids only).

    Parameters
    ----------
    path : str or os.PathLike
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
