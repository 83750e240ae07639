"""What stands around a scan: walls behind the rotary table, or a housing.

``--background walls|box|none`` of a scan scenario (``render rotary``, ``render blocker``).
The parts are fixed in the **stage frame** (:mod:`sim.stages`: origin on the rotary axis
at the meridian height, +x along the laser's propagation, +z up, the sheet is the plane
y = 0); the turntable's part turns in front of them.  Dimensions scale with the reach of
the rig's view beyond the axis, ``far_mm`` (the distance along +x from the axis to the
far end of the measuring range), so that the walls stand where the camera still sees
them — as a scanner's back walls do (``sim.backgrounds.scan_background``: the view's far
end beyond the axis, at most 150 mm, or the distance given):

``walls`` (FabScan-like)
    two vertical boards meeting behind the table in a corner ``0.9·far_mm`` beyond the
    axis on the camera's line of sight through it, each at 45° to that line (a V
    opening toward the camera), from the table up to ``height_mm``; the sheet, at an
    angle to the line of sight, crosses each board once, so every frame shows two
    fixed straight segments beside the part's profile.
``box``
    a housing open toward the camera: a back wall across the line of sight at
    ``0.9·far_mm``, two side walls parallel to it at ±``0.9·far_mm``, a floor (the
    table's plane: the part stands on it) and a ceiling at ``height_mm``.

Each board is ``BOARD_MM`` thick; the material is a tag of :data:`scenes.MATERIALS`
(default ``cardboard``: a plain wooden or card board, matte).  Object ids start at
``FIRST_ID`` (101) so they never clash with a part's.
"""

from __future__ import annotations

import math

import numpy as np

from scheimpflug.errors import MeshError

from .part import MATERIALS, Part
from .revolve import box_mesh

__all__ = [
    "BACKGROUNDS",
    "BOARD_MM",
    "FIRST_ID",
    "TABLE_SAGITTA_MM",
    "background_parts",
    "oriented_board",
    "table_disc",
]

BACKGROUNDS = ("none", "walls", "box")
#: thickness of a background board [mm]
BOARD_MM = 10.0
#: object id of the first background part
FIRST_ID = 101
#: largest chord sagitta of the turntable disc's polygonal rim [mm]
TABLE_SAGITTA_MM = 1e-3


def _board(name: str, centre, size, yaw_deg: float, material: str, object_id: int) -> Part:
    """A box of ``size`` (length along its x, thickness, height) centred at ``centre``, turned about z."""
    centre = np.asarray(centre, dtype=float)
    lo, hi = -0.5 * np.asarray(size, float), 0.5 * np.asarray(size, float)
    mesh = box_mesh(lo, hi)
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    m = np.eye(4)
    m[:2, :2] = [[c, -s], [s, c]]
    m[:3, 3] = centre
    mesh.apply_transform(m)
    return Part(name, mesh, material, {"kind": "board", "size_mm": list(map(float, size)), "yaw_deg": yaw_deg,
                                       "centre_mm": list(map(float, centre)), "mesh_from_part": np.eye(4).tolist()},
                object_id)


def oriented_board(name: str, stage_from_board, length_mm: float, width_mm: float, thickness_mm: float,
                   material: str, object_id: int) -> Part:
    """A board of any orientation: its face the plane y = 0 of its own frame, the board behind it.

    Parameters
    ----------
    name : str
        The part's name.
    stage_from_board : (4, 4) array_like float
        Pose of the board frame in the stage frame: x along its length, y its face's normal
        (toward the side seen), z along its width, the origin at the face's centre [mm].
    length_mm, width_mm, thickness_mm : float
        Extents along x, z and behind the face (−y) [mm], > 0.
    material : str
        Material tag (:data:`scenes.MATERIALS`).
    object_id : int
        The part's object id.

    Returns
    -------
    Part
        The board, its vertices in the stage frame; ``analytic`` records the pose and sizes.

    Raises
    ------
    MeshError
        An unknown material or a size that is not > 0.
    """
    if material not in MATERIALS:
        raise MeshError(f"board {name!r}: material {material!r} unknown (known: {', '.join(MATERIALS)})")
    sizes = (length_mm, width_mm, thickness_mm)
    if not all(math.isfinite(x) and x > 0 for x in sizes):
        raise MeshError(f"board {name!r}: length, width and thickness {sizes!r} mm must be > 0")
    m = np.asarray(stage_from_board, dtype=float)
    mesh = box_mesh(np.array([-0.5 * length_mm, -thickness_mm, -0.5 * width_mm]),
                    np.array([0.5 * length_mm, 0.0, 0.5 * width_mm]))
    mesh.apply_transform(m)
    return Part(name, mesh, material, {"kind": "board", "size_mm": [float(x) for x in sizes],
                                       "stage_from_board": m.tolist(), "mesh_from_part": np.eye(4).tolist()},
                object_id)


def table_disc(radius_mm: float, thickness_mm: float, material: str, stage_from_table, object_id: int) -> Part:
    """The turntable's disc: its top the table plane, centred on the rotary axis.

    Parameters
    ----------
    radius_mm : float
        Radius of the disc [mm], > 0.
    thickness_mm : float
        Thickness below its top [mm], > 0.
    material : str
        Material tag (:data:`scenes.MATERIALS`).
    stage_from_table : (4, 4) array_like float
        Pose of the table frame in the stage frame: z the table's up (the rotary axis), the origin
        the table's centre on its top [mm].
    object_id : int
        The part's object id.

    Returns
    -------
    Part
        The disc, its vertices in the stage frame (a polygon of sagitta ≤ :data:`TABLE_SAGITTA_MM`;
        its top face lies exactly in the table plane); ``analytic`` records the pose and sizes.

    Raises
    ------
    MeshError
        An unknown material or a size that is not > 0.
    """
    from .generators import cylinder

    if material not in MATERIALS:
        raise MeshError(f"turntable disc: material {material!r} unknown (known: {', '.join(MATERIALS)})")
    if not all(math.isfinite(x) and x > 0 for x in (radius_mm, thickness_mm)):
        raise MeshError(f"turntable disc: radius {radius_mm!r} mm and thickness {thickness_mm!r} mm must be > 0")
    m = np.asarray(stage_from_table, dtype=float)
    disc = cylinder(2.0 * radius_mm, thickness_mm, max_sagitta_mm=TABLE_SAGITTA_MM, material=material)
    mesh = disc.mesh.copy().apply_transform(m @ np.array([[1.0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, -thickness_mm],
                                                          [0, 0, 0, 1]]))
    return Part("table", mesh, material, {"kind": "table_disc", "radius_mm": float(radius_mm),
                                          "thickness_mm": float(thickness_mm), "stage_from_table": m.tolist(),
                                          "segments": disc.analytic["segments"],
                                          "mesh_from_part": np.eye(4).tolist()}, object_id)


def background_parts(kind: str, far_mm: float, table_z_mm: float, height_mm: float = 250.0,
                     material: str = "cardboard", view_dir=(1.0, 0.0)) -> tuple[Part, ...]:
    """The background parts of a scan, in the stage frame (module docstring).

    Parameters
    ----------
    kind : {"none", "walls", "box"}
        What stands around the table.
    far_mm : float
        Where the boards stand: the walls' corner / the box's back wall at ``0.9·far_mm``
        beyond the rotary axis [mm] (> 0).
    table_z_mm : float
        Height of the table top in the stage frame [mm].
    height_mm : float, default 250.0
        Height of the walls above the table [mm].
    material : str, default "cardboard"
        Material tag of the boards.
    view_dir : (2,) float, default (1, 0)
        Horizontal direction (x, y) from the camera through the axis, stage frame [-]: the
        corner and the back wall lie on it, behind the axis as the camera sees it.

    Returns
    -------
    tuple of Part
        Empty for ``"none"``.

    Raises
    ------
    MeshError
        For an unknown kind or material, or a size that is not > 0.
    """
    if kind not in BACKGROUNDS:
        raise MeshError(f"--background {kind!r}: unknown (known: {', '.join(BACKGROUNDS)})")
    if material not in MATERIALS:
        raise MeshError(f"--background-material {material!r}: unknown (known: {', '.join(MATERIALS)})")
    if not (math.isfinite(far_mm) and far_mm > 0 and math.isfinite(height_mm) and height_mm > 0):
        raise MeshError(f"background: the view's reach {far_mm!r} mm and the wall height {height_mm!r} mm "
                        "must be > 0")
    if kind == "none":
        return ()
    w = np.array([view_dir[0], view_dir[1], 0.0], dtype=float)
    w /= np.linalg.norm(w)
    side = np.array([-w[1], w[0], 0.0])
    yaw = math.degrees(math.atan2(w[1], w[0]))
    r, t = 0.9 * far_mm, BOARD_MM
    zc = table_z_mm + 0.5 * height_mm
    if kind == "walls":
        return tuple(_wall(i, sign, r * w, w, side, t, height_mm, zc, material) for i, sign in enumerate((1.0, -1.0)))
    span = 2.0 * r
    return (_board("back", (r + 0.5 * t) * w + [0, 0, zc], (t, span, height_mm), yaw, material, FIRST_ID),
            _board("side1", (r + 0.5 * t) * side + [0, 0, zc], (span, t, height_mm), yaw, material, FIRST_ID + 1),
            _board("side2", -(r + 0.5 * t) * side + [0, 0, zc], (span, t, height_mm), yaw, material, FIRST_ID + 2),
            _board("floor", (0.0, 0.0, table_z_mm - 0.5 * t - 0.5), (span, span, t), yaw, material, FIRST_ID + 3),
            _board("ceiling", (0.0, 0.0, table_z_mm + height_mm + 0.5 * t), (span, span, t), yaw, material,
                   FIRST_ID + 4))


def _wall(i: int, sign: float, corner, w, side, t: float, height_mm: float, zc: float, material: str) -> Part:
    """One of the two walls: from the corner toward the front at 45° to −w, its face toward the axis."""
    a = math.sqrt(0.5)
    d = -a * w + sign * a * side                         # along the wall, from the corner to the front
    n = -a * w - sign * a * side                         # its face's normal, toward the axis
    length = 2.0 * np.linalg.norm(corner)
    centre = corner + 0.5 * length * d - 0.5 * t * n + np.array([0.0, 0.0, zc])
    return _board(f"wall{i + 1}", centre, (length, t, height_mm), math.degrees(math.atan2(d[1], d[0])),
                  material, FIRST_ID + i)
