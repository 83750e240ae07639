"""A scan's background (:mod:`scenes.backgrounds`) in the twin: placed, posed and in the truth.

The background boards stand still in the stage frame while the rotary table turns the
part: the twin poses them with ``rig_from_stage`` every frame (per-part poses of
:meth:`sim.scene.SimScene.set_pose`; Mitsuba then rebuilds its BVH per frame, measured in
``benchmarks/RESULTS.md``).  The laser lights them as any part, the camera pass lights
them with the flood light and the environment, and their stripe is in the frame's truth:
:func:`background_truth` cuts them by the sheet like the part and keeps, per row, the
crossing with the smallest u as the primary (the stripe rule of :mod:`sim.truth`),
``stripe_count`` counting both.  ``truth/background.ply`` holds them in the stage frame.

A scanner's housing (:mod:`scheimpflug.model.housing`, ``render --housing FILE``) is given in the
instrument frame — the rig's OpenCV camera frame (:func:`sim.truth.opencv_camera`) — and placed
in the stage frame by :func:`housing_parts`; it stands still like the walls and is in the
truth the same way.  So does the turntable's disc (``[stage] table_radius_mm``,
:func:`table_parts`), its top square to the axis.

A disc whose top is tilted to its bearing axis (``[stage] table_tilt_deg`` > 0,
:mod:`scheimpflug.turntable_top`) turns with the table: its part is marked
``analytic["turns_with_table"]``, its vertices are given in the stage frame at θ = 0, and in
every frame it is turned about its own axis as the part turns (:func:`turning_pose`)
and cut by the sheet at that pose in the frame's truth; ``truth/background.ply`` holds it at θ = 0.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from scheimpflug.model.camera import lens_centre_mm, sheet_point_from_pixel
from scheimpflug.model.hinge import hinge_geometry
from scheimpflug.model.housing import check_sheet_seen
from scheimpflug.model.rig import Rig

from .stages import (
    axis_distance_mm,
    invert,
    ref_from_stage,
    rig_from_stage,
    rotation_vector,
    stage_from_part,
    transform_points,
    translation,
)

__all__ = ["MAX_DISTANCE_MM", "background_poses", "background_truth", "camera_from_table", "housing_parts",
           "scan_background", "table_parts", "turning_pose", "turns_with_table"]


#: farthest default distance of the background beyond the axis [mm] (a scanner's housing is that small)
MAX_DISTANCE_MM = 150.0


def scan_background(rig: Rig, kind: str, material: str = "cardboard", height_mm: float = 250.0,
                    distance_mm: float | None = None) -> tuple:
    """The background parts of a scan of ``rig``, in the stage frame.

    Parameters
    ----------
    rig : Rig
        The rig (its view's far end beyond the axis, the rotary table's height).
    kind : {"none", "walls", "box"}
        :func:`scenes.backgrounds.background_parts`.
    material : str, default "cardboard"
        Material tag of the boards.
    height_mm : float, default 250.0
        Wall height above the table [mm].
    distance_mm : float, optional
        Reach beyond the axis that places the boards [mm] (:func:`scenes.backgrounds.background_parts`);
        default the view's far end beyond the axis, at most :data:`MAX_DISTANCE_MM`.

    Returns
    -------
    tuple of scenes.Part
        The boards (empty for ``"none"``); for a table whose up is the stage's −z
        (``axis_tilt_deg`` > 170), standing on the table's side, upward for the table.

    Raises
    ------
    MeshError
        For an unknown kind or material, or a rig whose view ends before its axis.
    """
    from scenes.backgrounds import background_parts

    if distance_mm is None:
        g = hinge_geometry(rig)
        d_far = float(max(g.distance_from_column([-0.5, rig.sensor.columns - 0.5])))
        distance_mm = min(d_far - axis_distance_mm(rig), MAX_DISTANCE_MM / 0.9)
    lens = invert(rig_from_stage(rig)) @ np.append(lens_centre_mm(rig), 1.0)     # the camera, stage frame
    if rig.stage.axis_tilt_deg < 90.0:
        return background_parts(kind, distance_mm, rig.stage.rotary_table_z_mm, height_mm, material,
                                view_dir=(-lens[0], -lens[1]))
    flip = np.diag([1.0, -1.0, -1.0, 1.0])      # a table up the stage's −z: built upright, turned back
    lens = flip @ lens
    parts = background_parts(kind, distance_mm, -rig.stage.rotary_table_z_mm, height_mm, material,
                             view_dir=(-lens[0], -lens[1]))
    return tuple(dataclasses.replace(q, mesh=q.mesh.copy().apply_transform(flip)) for q in parts)


def housing_parts(rig: Rig, boards, first_id: int | None = None) -> tuple:
    """A housing's boards as parts in the stage frame (module docstring).

    Parameters
    ----------
    rig : Rig
        The rig (its OpenCV camera frame is the boards' frame).
    boards : sequence of scheimpflug.model.housing.Board
        The boards, instrument (camera) frame.
    first_id : int, optional
        Object id of the first board (default :data:`scenes.backgrounds.FIRST_ID`).

    Returns
    -------
    tuple of scenes.Part
        One part per board, vertices in the stage frame.

    Raises
    ------
    MeshError
        An unknown material or a size that is not > 0.
    RigError
        A housing that hides the whole sheet from the camera: every ray from the camera to
        the sheet's part its pixels see (a 32 × 32 grid over the frame) passes through a
        board (:func:`scheimpflug.model.housing.check_sheet_seen`, the board named).
    """
    from scenes.backgrounds import FIRST_ID, oriented_board

    from .truth import opencv_camera

    _, camera_from_rig = opencv_camera(rig)
    check_sheet_seen(boards, np.zeros(3), transform_points(camera_from_rig, _sheet_seen_mm(rig)))
    stage_from_camera = invert(rig_from_stage(rig)) @ invert(camera_from_rig)
    first = FIRST_ID if first_id is None else first_id
    parts = []
    for i, b in enumerate(boards):
        camera_from_board = np.eye(4)
        camera_from_board[:3, :3] = np.column_stack([b.length_dir, b.normal, np.cross(b.length_dir, b.normal)])
        camera_from_board[:3, 3] = b.centre_mm
        parts.append(oriented_board(b.name, stage_from_camera @ camera_from_board, b.length_mm, b.width_mm,
                                    b.thickness_mm, b.material, first + i))
    return tuple(parts)


def table_parts(rig: Rig, object_id: int) -> tuple:
    """The turntable's disc of a rig (``[stage] table_radius_mm`` > 0), in the stage frame.

    The disc is centred on the bearing axis, its top the table plane (the part frame's z = 0 at
    θ = 0 without the runout, which moves the part, not the table) raised along the axis by
    ``table_top_offset_mm``.  Square to the axis (``table_tilt_deg`` = 0) it stands still: it is
    rotationally symmetric about the axis it turns on, so turning it changes nothing the camera
    sees (to its rim's polygon); the table's error motions (``wobble_urad``,
    ``radial_error_um``) move the part only.  With a tilt its top's normal leans by
    ``table_tilt_deg`` toward ``table_tilt_azimuth_deg`` in the table's own frame (about the
    top's centre) and the disc turns with the table (module docstring): its pose at θ is
    ``stage_from_part(θ)`` (error motions included) composed with that tilt.

    Parameters
    ----------
    rig : Rig
        The rig (``stage.table_radius_mm``, ``table_thickness_mm``, ``table_material``,
        ``table_top_offset_mm``, ``table_tilt_deg``, ``table_tilt_azimuth_deg`` and the
        rotary stage's pose).
    object_id : int
        The disc's object id.

    Returns
    -------
    tuple of scenes.Part
        The disc (vertices in the stage frame at θ = 0; ``analytic["turns_with_table"]`` when
        tilted), or empty when ``table_radius_mm`` is 0.

    Raises
    ------
    MeshError
        An unknown material.
    """
    from scenes.backgrounds import table_disc

    st = rig.stage
    if not st.table_radius_mm > 0:
        return ()
    stage_from_table = stage_from_part(rig, 0.0) @ translation((-0.5e-3 * st.runout_um, 0.0,
                                                                st.table_top_offset_mm))
    if st.table_axis_tilt_deg != 0.0:          # the disc's own axis, leaning about its top's centre
        stage_from_table = stage_from_table @ _lean(st.table_axis_tilt_deg, st.table_axis_tilt_azimuth_deg)
    if st.table_tilt_deg == 0.0:
        return (table_disc(st.table_radius_mm, st.table_thickness_mm, st.table_material, stage_from_table,
                           object_id),)
    disc = table_disc(st.table_radius_mm, st.table_thickness_mm, st.table_material,
                      stage_from_table @ _lean(st.table_tilt_deg, st.table_tilt_azimuth_deg), object_id)
    return (dataclasses.replace(disc, analytic={**disc.analytic, "turns_with_table": True,
                                                "stage_from_axis": stage_from_table.tolist()}),)


def _lean(tilt_deg: float, azimuth_deg: float) -> np.ndarray:
    """The rotation that turns e_z by ``tilt_deg`` toward ``azimuth_deg`` (as the stage's own tilt)."""
    tau, psi = math.radians(tilt_deg), math.radians(azimuth_deg)
    return rotation_vector([-tau * math.sin(psi), tau * math.cos(psi), 0.0])


def turns_with_table(part) -> bool:
    """Whether a background part turns with the table (a tilted disc, :func:`table_parts`).

    Parameters
    ----------
    part : scenes.Part
        A background part.

    Returns
    -------
    bool
        Its ``analytic["turns_with_table"]``.
    """
    return bool(part.analytic.get("turns_with_table", False))


def turning_pose(rig: Rig, part, rig_from_part) -> np.ndarray:
    """Where a part that turns with the table is at a frame, in the stage frame, from its pose at θ = 0.

    Parameters
    ----------
    rig : Rig
        The rig.
    part : scenes.Part
        A part of :func:`table_parts` that turns (``analytic["stage_from_axis"]`` A: its own axis
        frame, z the axis it turns about, at θ = 0).
    rig_from_part : (4, 4) array_like float
        The frame's pose of the scanned part (``FrameSpec.rig_from_part``).

    Returns
    -------
    (4, 4) float64
        ``A · D · A⁻¹``: the turn D of the part since θ = 0, ``T(e) · stage_from_part(0)⁻¹ ·
        stage_from_rig · rig_from_part · T(−e)`` (R_z(θ) for a stage without error motions, e
        the runout's eccentricity), made about the disc's own axis.
    """
    a = np.asarray(part.analytic["stage_from_axis"], np.float64)
    e = translation((0.5e-3 * rig.stage.runout_um, 0.0, 0.0))
    d = e @ invert(stage_from_part(rig, 0.0)) @ invert(rig_from_stage(rig)) @ np.asarray(rig_from_part) @ invert(e)
    return a @ d @ invert(a)


def background_poses(rig: Rig, parts):
    """The per-frame pose of each background part, as a function of the part's pose.

    Parameters
    ----------
    rig : Rig
        The rig.
    parts : sequence of scenes.Part
        The background parts (vertices in the stage frame at θ = 0).

    Returns
    -------
    callable
        ``poses(rig_from_part) -> list of (4, 4)``: ``rig_from_stage`` for a still part,
        ``rig_from_stage · turning_pose(...)`` for one that turns with the table (:func:`turning_pose`).
    """
    still = rig_from_stage(rig)
    turns = [turns_with_table(p) for p in parts]

    def poses(rig_from_part) -> list:
        return [still @ turning_pose(rig, p, rig_from_part) if t else still for p, t in zip(parts, turns)]

    return poses


def camera_from_table(rig: Rig) -> np.ndarray:
    """The table's own frame at θ = 0 in the rig's OpenCV camera frame (:mod:`scheimpflug.turntable_top`).

    Parameters
    ----------
    rig : Rig
        The rig.

    Returns
    -------
    (4, 4) float64
        The part frame at θ = 0 moved back onto the bearing axis (the runout taken out): origin
        the table's centre on the table plane, z the table's up, x the table's x [mm].
    """
    from .truth import opencv_camera

    _, camera_from_rig = opencv_camera(rig)
    return camera_from_rig @ rig_from_stage(rig) @ stage_from_part(rig, 0.0) @ translation(
        (-0.5e-3 * rig.stage.runout_um, 0.0, 0.0))


def _sheet_seen_mm(rig: Rig, n: int = 32) -> np.ndarray:
    """Rig-frame points where an n × n grid of pixel rays over the frame meets the sheet (in front only)."""
    u = np.linspace(0.0, rig.sensor.columns - 1.0, n)
    v = np.linspace(0.0, rig.sensor.rows - 1.0, n)
    uv = np.stack(np.meshgrid(u, v), axis=-1).reshape(-1, 2)
    p = sheet_point_from_pixel(rig, uv)
    return p[np.all(np.isfinite(p), axis=1)]


def _merge(a: dict, b: dict) -> dict:
    """Per row the primary crossing of two stripe truths (smallest u), counts added."""
    ua, ub = a["stripe_u"], b["stripe_u"]
    take_b = np.isfinite(ub) & ~(ua <= ub)
    out = dict(a)
    out["stripe_u"] = np.where(take_b, ub, ua)
    out["stripe_point_mm"] = np.where(take_b[:, None], b["stripe_point_mm"], a["stripe_point_mm"])
    out["stripe_object_id"] = np.where(take_b, b["stripe_object_id"], a["stripe_object_id"]).astype(
        a["stripe_object_id"].dtype)
    out["stripe_count"] = np.minimum(a["stripe_count"].astype(np.int64) + b["stripe_count"], 255).astype(
        a["stripe_count"].dtype)
    return out


def background_truth(rig: Rig, scenario, frame, caster, arrays: dict) -> dict:
    """The frame's stripe truth with the background's crossings merged in (module docstring).

    Parameters
    ----------
    rig : Rig
        The instrument.
    scenario : Scenario
        A scan scenario with ``background`` parts (stage frame).
    frame : FrameSpec
        The frame (its laser pose).
    caster : RayCaster
        Queries on the whole scene posed for the frame (part and background).
    arrays : dict
        The frame's truth arrays (the part's stripe); not changed.

    Returns
    -------
    dict
        The arrays with the merged stripe.
    """
    from .truth import stripe_truth

    mesh = _background_mesh(scenario)
    owner = mesh[3]
    if (owner >= 0).any():              # a tilted disc: at this frame's pose, in the stage frame
        verts = mesh[0].copy()
        for i in np.unique(owner[owner >= 0]):
            sel = owner == i
            verts[sel] = transform_points(turning_pose(rig, scenario.background[i], frame.rig_from_part), verts[sel])
        mesh = (verts, *mesh[1:])
    bg = stripe_truth(rig, mesh[0], mesh[1], mesh[2], rig_from_stage(rig), ref_from_stage(rig), caster,
                      rig_from_laser=frame.rig_from_laser).arrays()
    return _merge(arrays, bg)


def _background_mesh(scenario) -> tuple:
    cache = getattr(scenario, "_background_mesh_cache", None)
    if cache is None:
        parts = scenario.background
        verts, faces, ids, turns, offset = [], [], [], [], 0
        for i, p in enumerate(parts):
            verts.append(np.asarray(p.mesh.vertices, dtype=np.float64))
            turns.append(np.full(len(p.mesh.vertices), i if turns_with_table(p) else -1))   # owner, or −1: still
            faces.append(np.asarray(p.mesh.faces, dtype=np.int64) + offset)
            ids.append(np.full(len(p.mesh.faces), p.object_id, dtype=np.int32))
            offset += len(p.mesh.vertices)
        cache = (np.concatenate(verts), np.concatenate(faces), np.concatenate(ids), np.concatenate(turns))
        object.__setattr__(scenario, "_background_mesh_cache", cache)
    return cache
