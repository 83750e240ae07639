"""Occlusion on a part: which of the sheet's line on it the camera sees, and what laser and camera shadow take.

The part (a preset of :data:`scenes.PART_NAMES`) sits on the rotary table as the twin places it
(:func:`sim.stages.rig_from_stage` · :func:`sim.stages.stage_from_part`, the ideal stage turned to the
table angle).  The sheet cuts it along a profile (:func:`trimesh.intersections.mesh_plane`, the exact
section of its mesh); each piece of that profile is

* ``seen``: the laser reaches it (nothing on the segment from the laser exit to it) and the camera
  sees it (nothing on the segment from it to the lens centre), inside the sensor's field;
* ``out_of_view``: lit and in the camera's line of sight, but outside the sensor's field;
* ``camera_shadow``: lit, hidden from the camera;
* ``laser_shadow``: in the camera's line of sight, not reached by the laser;
* ``unreached``: neither (the part's far side).

Fractions are of the profile's length; "per turn" sums them over the table angles of one turn
(every point of the surface crosses the sheet once per turn).  Segments are tested with the twin's
Mitsuba scene (:class:`sim.scene.SimScene`: its BVH, rays moved instead of the mesh), ≈ 40 ms an
angle for a million-triangle part; a renderer that cannot start is said as a :class:`RenderError`.
"""

from __future__ import annotations

import functools
import threading
import warnings

import numpy as np

from scheimpflug.errors import MeshError
from scheimpflug.model.hinge import hinge_geometry
from scheimpflug.model.rig import Rig

__all__ = ["CLASSES", "EPS_MM", "check_part", "occlusion"]

CLASSES = ("seen", "out_of_view", "camera_shadow", "laser_shadow", "unreached")
"""What a piece of the profile is, in the order of the page's legend."""

EPS_MM = 0.01
"""Length left out at both ends of a shadow segment, so that a surface does not shadow itself [mm]."""

_LOCK = threading.Lock()        # one Mitsuba query at a time (the server answers in several threads)


def check_part(name: str) -> None:
    """Refuse a part that is not a preset (the page names presets; uploads come as files).

    Raises
    ------
    MeshError
        Naming the known parts.
    """
    import scenes

    if name not in scenes.PART_NAMES:
        raise MeshError(f"part = {name[:40]!r}: unknown (known: {', '.join(scenes.PART_NAMES)}, or a mesh "
                        "uploaded to this studio)")


@functools.lru_cache(maxsize=4)
def _part(source: str):
    """The part's combined mesh and its Mitsuba scene, built once per part (≈ 1 s for a large one)."""
    from scenes.loading import load_part
    from sim.scene import SimScene

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")             # an upload's warnings were said when it came
        asm = load_part(source)
    return asm.combined_mesh(), SimScene(list(asm.parts))


def _profile(rig: Rig, mesh, angle_deg: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pieces of the section (rig-frame ends (n, 2, 3)) and their lengths (n,), and rig_from_part (4, 4)."""
    import trimesh

    from sim.stages import rig_from_stage, stage_from_part

    g = hinge_geometry(rig)
    rig_from_part = rig_from_stage(rig) @ stage_from_part(rig, angle_deg)
    part_from_rig = np.linalg.inv(rig_from_part)
    normal = part_from_rig[:3, :3] @ g.sheet_normal
    origin = (part_from_rig @ np.append(g.scheimpflug_point_mm, 1.0))[:3]
    seg = np.asarray(trimesh.intersections.mesh_plane(mesh, normal, origin), dtype=float).reshape(-1, 2, 3)
    ends = seg @ rig_from_part[:3, :3].T + rig_from_part[:3, 3]
    return ends, np.linalg.norm(seg[:, 1] - seg[:, 0], axis=1), rig_from_part


def _classes(rig: Rig, scene, points: np.ndarray) -> np.ndarray:
    """Class index (into :data:`CLASSES`) of each profile point (n, 3) [mm]."""
    g = hinge_geometry(rig)
    x0 = rig.laser.origin_x_mm
    laser = np.array([x0, g.scheimpflug_distance_mm - x0 * g.tan_phi, 0.0])
    lit = ~scene.occluded(np.broadcast_to(laser, points.shape).copy(), points, eps_mm=EPS_MM)
    visible = ~scene.occluded(points, np.zeros_like(points), eps_mm=EPS_MM)
    d, h, _ = g.sheet_from_rig(points)
    u, v = g.pixel_from_sheet(d, h)
    s = rig.sensor
    in_view = (u >= -0.5) & (u <= s.columns - 0.5) & (v >= -0.5) & (v <= s.rows - 0.5) & (d > 0)
    out = np.full(len(points), CLASSES.index("unreached"))
    out[lit & visible & in_view] = CLASSES.index("seen")
    out[lit & visible & ~in_view] = CLASSES.index("out_of_view")
    out[lit & ~visible] = CLASSES.index("camera_shadow")
    out[~lit & visible] = CLASSES.index("laser_shadow")
    return out


def _fractions(kinds: np.ndarray, lengths: np.ndarray) -> dict[str, float]:
    total = float(lengths.sum())
    return {c: (float(lengths[kinds == i].sum()) / total if total > 0 else 0.0) for i, c in enumerate(CLASSES)}


def occlusion(rig: Rig, part: str, angle_deg: float, turn_steps: int = 0, source: str | None = None) -> dict:
    """What the sheet's line on a part is at one table angle (and, if asked, over one turn).

    Parameters
    ----------
    rig : Rig
        The instrument (its stage places the part: ``axis_mm``, ``d0_mm``, ``rotary_table_z_mm``).
    part : str
        A preset part of :data:`scenes.PART_NAMES` (no files: the page cannot name one).
    angle_deg : float
        Table angle, counter-clockwise seen from above [deg].
    turn_steps : int, default 0
        Table angles over one turn for the ``turn`` fractions (0: not computed) [-].
    source : str, optional
        A mesh file (mm, rotary axis on z) to load instead of the preset: an upload the server
        checked; ``part`` then only names it.

    Returns
    -------
    dict
        ``part``, ``angle_deg``; ``segments``: per profile piece [D0, h0, D1, h1, class index], its
        ends in sheet coordinates [mm] (classified at its midpoint); ``classes`` (:data:`CLASSES`);
        ``fractions`` at this angle and, with ``turn_steps``, ``turn`` (over one turn), each
        ``{class: fraction of the profile's length}``; ``length_mm`` (the profile's length at this
        angle).

    Raises
    ------
    MeshError
        For an unknown part.
    RenderError
        When the twin's renderer cannot start (no JIT variant: no libLLVM).
    """
    if source is None:
        check_part(part)
    mesh, scene = _part(part if source is None else source)
    g = hinge_geometry(rig)
    with _LOCK:
        ends, lengths, pose = _profile(rig, mesh, angle_deg)
        scene.set_pose(pose)
        kinds = _classes(rig, scene, ends.mean(axis=1)) if len(ends) else np.zeros(0, int)
        turn = _turn(rig, mesh, scene, turn_steps) if turn_steps else None
    d, h, _ = g.sheet_from_rig(ends)
    out = {"part": part, "angle_deg": angle_deg, "classes": list(CLASSES),
           "segments": np.round(np.column_stack([d[:, 0], h[:, 0], d[:, 1], h[:, 1], kinds]), 3).tolist(),
           "fractions": _fractions(kinds, lengths), "length_mm": float(lengths.sum())}
    if turn is not None:
        out["turn"] = turn
    return out


def _turn(rig: Rig, mesh, scene, steps: int) -> dict[str, float]:
    kinds, lengths = [], []
    for angle in np.arange(steps) * (360.0 / steps):
        ends, length, pose = _profile(rig, mesh, float(angle))
        if len(ends):
            scene.set_pose(pose)
            kinds.append(_classes(rig, scene, ends.mean(axis=1)))
            lengths.append(length)
    if not kinds:
        return _fractions(np.zeros(0, int), np.zeros(0))
    return _fractions(np.concatenate(kinds), np.concatenate(lengths))
