"""The exact profile the laser sheet cuts from a part at a given stage angle.

Stage frame at angle θ: the part (in its own frame) is turned by +θ about z;
the sheet is the plane y = 0, +x along the laser's propagation direction.
"""

from __future__ import annotations

import numpy as np
import trimesh

from .part import yaw_matrix

__all__ = ["sheet_section"]


def sheet_section(mesh: trimesh.Trimesh, angle_deg: float = 0.0) -> np.ndarray:
    """Section of a part by the laser sheet at a stage angle.

    Ideal stage: the part is turned by +θ about ``z`` and cut by the plane
    y = 0 (trimesh's ``mesh_plane``); the table height and the stage's tilt and
    runout are not applied.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        The part, part frame [mm].
    angle_deg : float, default 0.0
        Stage angle θ, counter-clockwise seen from above [deg].

    Returns
    -------
    (k, 2, 2) float
        Segment end points as (x, z) in the sheet [mm] (x along the
        propagation direction from the axis, z up from the table).
    """
    m = yaw_matrix(angle_deg)
    verts = np.asarray(mesh.vertices) @ m[:3, :3].T
    turned = trimesh.Trimesh(verts, mesh.faces, process=False)
    seg = trimesh.intersections.mesh_plane(turned, plane_normal=[0.0, 1.0, 0.0],
                                           plane_origin=[0.0, 0.0, 0.0])
    return np.asarray(seg, dtype=float).reshape(-1, 2, 3)[:, :, [0, 2]]
