"""Scenario ``target``: a printed calibration pattern held in front of the rig, or standing on its table.

What a person calibrating a laser-line sensor without a translation stage does
(issue 23 → issue 24): photograph a printed pattern (:mod:`scenes.patterns`)
in many poses, flood-lit with the laser off, and with the laser on so that the
laser line on the pattern can be measured in its own frame.

Poses
-----
*Hand-held* (default, ``poses`` = 20): per pose, seeded draws
(``SeedSequence((seed, 0x7A26))``):

* the pattern's centre at the sheet point seen by a pixel drawn uniformly over
  the sensor (so: across the rig's depth and height ranges; a pattern near an
  edge is partly out of view), or, with ``depth_range_mm`` / ``height_range_mm``,
  at (D, h) drawn uniformly in those ranges of the sheet; then moved off the sheet
  along its normal by U(−``off_sheet_mm``, ``off_sheet_mm``);
* orientation: the print in the sheet plane (columns along the propagation
  direction, rows downward, facing the camera), turned in its plane by
  U(−``roll_deg``, ``roll_deg``), then tilted about its own column and row axes by
  U(−``tilt_deg``, ``tilt_deg``) each (default ±35°: a hand does not hold a board
  much steadier);
* a pose whose print the camera would see more than ``MAX_VIEW_DEG`` (85°) from its
  normal at the centre, or from behind, is drawn again (a person holds the print
  toward the camera).  A Scheimpflug camera sees its sheet obliquely (paper rig:
  ≈ 78° from the sheet's normal), so the tilts that turn the print toward the
  camera are the ones kept.

With ``tilt_deg = 0`` and ``off_sheet_mm = 0`` every pose lies in the sheet, the
sharp plane of the Scheimpflug camera.

*On the table* (``on_table``, ``step_deg``): the plate stands on the rotary table
(its bottom edge on it, the print's face through the axis, the pattern's centre
column on the axis); at θ = 0 the print lies in the sheet, facing the camera;
angles k·step over one turn at which the camera sees the face within 85° of
its normal are kept — the turntable scanners' way to find the axis.

Frames
------
Per pose, one frame per light of ``lights`` (default both, in this order):
``"flood"`` — the flood light on, the laser off, exposure ``flood_exposure_ms``
(default: white paper facing the flood light at its aim point reaches half the
full well); ``"laser"`` — the laser on, the flood light off (``laser_flood`` = 0)
or dimmed to that fraction (the manifest then says ``"both"``), the rig's exposure.
The environment (``[environment] ambient_irradiance_w_m2``) lights every frame.
The manifest records per frame ``pose`` (index), ``light`` and ``exposure_ms``
(and ``angle_deg`` on the table).

Truth per frame
---------------
From :func:`pattern_truth`, besides the laser's stripe of :mod:`sim.truth` (which is
empty in a flood frame):

``pattern_corners_px`` (n, 2) float64
    Every corner / dot centre where the chief ray through the lens centre meets
    the tilted sensor (:func:`scheimpflug.model.camera.project_points`) [px]; NaN
    when off the sensor, when the print faces away, or when something hides it
    from the lens centre.
``pattern_corner_ids`` (n, 2) int64
    (column, row) in the pattern's grid (:meth:`scenes.patterns.PatternSpec.corner_ids`).
``pattern_centroid_px`` (n, 2) float64
    The light centroid of each corner's blur spot (the point's image through the
    whole aperture, weighted by the étendue) [px]: where a defocused *point*
    appears.  It differs from the chief ray by a few % of the blur (the cone's
    section by a tilted sensor is not centred on the chief ray).
``pattern_blur_px`` (n,) float64
    Peak-to-peak extent of each corner's blur spot along the columns
    (:func:`scheimpflug.model.camera.blur_footprint_px`) [px].
``rig_from_pattern`` (4, 4) float64
    The pattern frame (:mod:`scenes.patterns`) in the rig frame [mm].
``camera_from_pattern`` (4, 4) float64
    The same in OpenCV's camera frame of ``truth/rig_truth.json`` (``opencv``):
    ``cv2.projectPoints`` of the corners' object points with it and that camera's
    matrix and 14 distortion terms gives ``pattern_corners_px``.
"""

from __future__ import annotations

import math

import numpy as np

from scheimpflug.errors import ScheimpflugError
from scheimpflug.model.camera import (
    blur_footprint_px,
    lens_centre_mm,
    project_points,
    sensor_pose,
    sheet_point_from_pixel,
)
from scheimpflug.model.hinge import hinge_geometry
from scheimpflug.model.rig import Rig

from .camera_pass import LIGHT_SPEED_M_S, PLANCK_J_S
from .lights import flood_aim_point_mm
from .scenarios import FrameSpec, Scenario, frame_errors, frame_seed
from .stages import invert, rig_from_stage, stage_from_part

__all__ = [
    "DEFAULT_FLOOD_W_M2",
    "MAX_VIEW_DEG",
    "TARGET_LIGHTS",
    "flood_exposure_ms",
    "pattern_truth",
    "target_frame_count",
    "target_scenario",
]

TARGET_LIGHTS = ("flood", "laser")
#: A print seen more than this far from its normal is not held that way [deg].
MAX_VIEW_DEG = 85.0
#: The flood light's level where the rig has none ([environment] flood_irradiance_w_m2 = 0) [W/m²]:
#: a bright work lamp's in-band irradiance (assumed).
DEFAULT_FLOOD_W_M2 = 20.0
_STREAM_POSES = 0x7A26
_MAX_DRAWS = 2000


def _fail(msg: str) -> ScheimpflugError:
    return ScheimpflugError(msg)


# ------------------------------------------------------------------ geometry helpers
def _rot(axis: int, angle_rad: float) -> np.ndarray:
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    m = np.eye(3)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
    return m


def _camera_side_normal(rig: Rig, point: np.ndarray) -> np.ndarray:
    n = hinge_geometry(rig).sheet_normal
    return n if n @ (lens_centre_mm(rig) - point) > 0 else -n


def _view_cos(rig: Rig, rig_from_pattern: np.ndarray, centre_xy) -> float:
    """Cos of the angle between the print's reader-side normal and the direction to the lens."""
    p = rig_from_pattern[:3, :3] @ np.array([centre_xy[0], centre_xy[1], 0.0]) + rig_from_pattern[:3, 3]
    to_lens = lens_centre_mm(rig) - p
    return float(-rig_from_pattern[:3, 2] @ to_lens / np.linalg.norm(to_lens))


def _sheet_base(rig: Rig, point: np.ndarray) -> np.ndarray:
    """Rotation of the print lying in the sheet: columns along e_p, rows down, z away from the camera."""
    g = hinge_geometry(rig)
    n_cam = _camera_side_normal(rig, point)
    x = g.propagation_dir
    z = -n_cam
    y = np.cross(z, x)
    return np.column_stack([x, y, z])


def _view_point(rig: Rig, rng: np.random.Generator, depth_range, height_range) -> np.ndarray:
    """Where a pose's centre lies on the sheet (module docstring)."""
    g = hinge_geometry(rig)
    if depth_range is None and height_range is None:
        pose = sensor_pose(rig)
        uv = [rng.uniform(-0.5, pose.columns - 0.5), rng.uniform(-0.5, pose.rows - 0.5)]
        return sheet_point_from_pixel(rig, np.array(uv), pose)
    d_lo, d_hi = depth_range if depth_range is not None else _view_depth(rig)
    d = rng.uniform(d_lo, d_hi)
    h_lo, h_hi = height_range if height_range is not None else _view_height(rig, d)
    return g.rig_from_sheet(d, rng.uniform(h_lo, h_hi))


def _view_depth(rig: Rig) -> tuple[float, float]:
    g = hinge_geometry(rig)
    lo, hi = sorted(float(x) for x in g.distance_from_column([-0.5, rig.sensor.columns - 0.5]))
    return lo, hi


def _view_height(rig: Rig, d_mm: float) -> tuple[float, float]:
    g = hinge_geometry(rig)
    u = float(g.column_from_distance(d_mm))
    pts = sheet_point_from_pixel(rig, np.array([[u, -0.5], [u, rig.sensor.rows - 0.5]]))
    return tuple(sorted(float(z) for z in pts[:, 2]))


def _check_ranges(rig: Rig, depth_range, height_range) -> None:
    """Refuse ranges of the sheet that lie wholly outside the view (closed form)."""
    lo, hi = _view_depth(rig)
    if depth_range is not None:
        a, b = depth_range
        if not (math.isfinite(a) and math.isfinite(b) and a <= b):
            raise _fail(f"--depth-range-mm {a:g}:{b:g}: must be two finite numbers LO <= HI [mm]")
        if b < lo or a > hi:
            raise _fail(f"--depth-range-mm {a:g}:{b:g}: poses there can never be in view (the camera sees "
                        f"the sheet at D in [{lo:.1f}, {hi:.1f}] mm from the object hinge)")
    if height_range is not None:
        a, b = height_range
        mid = 0.5 * (max(lo, depth_range[0]) + min(hi, depth_range[1])) if depth_range else 0.5 * (lo + hi)
        h_lo, h_hi = _view_height(rig, mid)
        if not (math.isfinite(a) and math.isfinite(b) and a <= b):
            raise _fail(f"--height-range-mm {a:g}:{b:g}: must be two finite numbers LO <= HI [mm]")
        if b < h_lo - 1e3 or a > h_hi + 1e3 or b < min(h_lo, h_hi) or a > max(h_lo, h_hi):
            raise _fail(f"--height-range-mm {a:g}:{b:g}: poses there can never be in view (at D = {mid:.0f} mm "
                        f"the camera sees heights in [{h_lo:.1f}, {h_hi:.1f}] mm)")


def _hand_held_pose(rig: Rig, rng, centre_xy, tilt_deg, roll_deg, off_sheet_mm, depth_range, height_range):
    """One drawn pose (rig_from_pattern) or None when the print would face away too far."""
    p0 = _view_point(rig, rng, depth_range, height_range)
    if not np.isfinite(p0).all():
        return None
    off = rng.uniform(-off_sheet_mm, off_sheet_mm) if off_sheet_mm > 0 else 0.0
    roll, t1, t2 = (rng.uniform(-lim, lim) if lim > 0 else 0.0
                    for lim in (roll_deg, tilt_deg, tilt_deg))
    r = _sheet_base(rig, p0) @ _rot(2, math.radians(roll)) @ _rot(0, math.radians(t1)) @ _rot(1, math.radians(t2))
    m = np.eye(4)
    m[:3, :3] = r
    m[:3, 3] = p0 + off * _camera_side_normal(rig, p0) - r @ np.array([centre_xy[0], centre_xy[1], 0.0])
    return m if _view_cos(rig, m, centre_xy) >= math.cos(math.radians(MAX_VIEW_DEG)) else None


def _hand_held_poses(rig: Rig, seed: int, n: int, centre_xy, tilt_deg, roll_deg, off_sheet_mm,
                     depth_range, height_range) -> list[np.ndarray]:
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence((int(seed), _STREAM_POSES))))
    out, draws = [], 0
    while len(out) < n:
        draws += 1
        if draws > _MAX_DRAWS * max(1, n) or (draws > _MAX_DRAWS and not out):
            raise _fail(f"no pose of the pattern can be in view: {draws} draws all showed the print more than "
                        f"{MAX_VIEW_DEG:g}° from its normal or from behind (tilts ±{tilt_deg:g}°)")
        m = _hand_held_pose(rig, rng, centre_xy, tilt_deg, roll_deg, off_sheet_mm, depth_range, height_range)
        if m is not None:
            out.append(m)
    return out


def _part_from_pattern(rig: Rig, spec, print_mm) -> np.ndarray:
    """The pattern frame in the upright part frame of the rotary table (module docstring).

    Print columns along ±x, rows down (−z), the print's face in the plane y = 0 with
    its reader side toward the camera at θ = 0, the centre column on the axis, the
    bottom edge on the table.
    """
    cam_stage = invert(rig_from_stage(rig)) @ np.append(lens_centre_mm(rig), 1.0)
    a = 1.0 if cam_stage[1] < 0 else -1.0        # z into the print = a·ŷ, away from the camera
    e = spec.extent_mm()
    m = np.eye(4)
    m[:3, :3] = np.column_stack([[a, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, a, 0.0]])
    m[:3, 3] = -m[:3, :3] @ np.array([0.5 * (e[0] + e[2]), print_mm[3], 0.0])
    return m


def _table_angles(rig: Rig, step_deg: float, part_from_pattern, centre_xy) -> list[float]:
    n = max(1, int(round(360.0 / step_deg)))
    rig_from_st = rig_from_stage(rig)
    keep = []
    for k in range(n):
        a = round(k * step_deg, 9)
        m = rig_from_st @ stage_from_part(rig, a) @ part_from_pattern
        if _view_cos(rig, m, centre_xy) >= math.cos(math.radians(MAX_VIEW_DEG)):
            keep.append(a)
    return keep


# ------------------------------------------------------------------ exposure
def flood_exposure_ms(rig: Rig, fraction: float = 0.5, white: float = 0.85) -> float:
    """Exposure at which white paper facing the flood light at its aim point reaches a fraction of the full well.

    Parameters
    ----------
    rig : Rig
        The instrument (its flood light and environment, lens, sensor).
    fraction : float, default 0.5
        Of the full well [-].
    white : float, default 0.85
        The paper's albedo [-].

    Returns
    -------
    float
        The exposure [ms]: e = ρ·(E_flood + E_amb)/π · A_pix·A_ap·cos θ_A·cos θ_q/|q − c|² · t·QE·λ/(hc)
        at the sensor centre (chief ray), solved for t.

    Raises
    ------
    ScheimpflugError
        When the scene has no light (flood and environment both 0).
    """
    env = rig.environment
    e_total = env.flood_irradiance_w_m2 + env.ambient_irradiance_w_m2
    if e_total <= 0:
        raise _fail("the target's flood frames need light: [environment] flood_irradiance_w_m2 and "
                    "ambient_irradiance_w_m2 are both 0")
    pose = sensor_pose(rig)
    q = pose.origin_mm + 0.5 * (pose.columns - 1) * pose.pitch_mm * pose.u_dir \
        + 0.5 * (pose.rows - 1) * pose.pitch_mm * pose.v_dir - lens_centre_mm(rig)
    qn = np.linalg.norm(q)
    a_ap = math.pi * (0.5 * rig.lens.focal_length_mm / rig.lens.f_number) ** 2
    g = pose.pitch_mm**2 * a_ap * abs(q[0]) / qn * abs(q @ pose.normal) / qn / qn**2 * 1e-6
    photon = PLANCK_J_S * LIGHT_SPEED_M_S / (rig.laser.wavelength_nm * 1e-9)
    e_per_ms = white * e_total / math.pi * g * 1e-3 * rig.sensor.quantum_efficiency / photon
    return float(fraction * rig.sensor.full_well_e / e_per_ms)


# ------------------------------------------------------------------ the scenario
def _lights(lights) -> tuple[str, ...]:
    if isinstance(lights, str):
        lights = tuple(x.strip() for x in lights.split(",") if x.strip())
    lights = tuple(lights)
    bad = [x for x in lights if x not in TARGET_LIGHTS]
    if not lights or bad or len(set(lights)) != len(lights):
        raise _fail(f"--lights {','.join(lights)!r}: a comma-separated list of flood, laser (each once)")
    return lights


def _check_options(poses, tilt_deg, roll_deg, off_sheet_mm, laser_flood, on_table, step_deg) -> None:
    if not on_table and (not isinstance(poses, int) or isinstance(poses, bool) or poses < 1):
        raise _fail(f"--poses {poses!r}: must be an integer >= 1")
    for name, v, hi in (("tilt_deg", tilt_deg, 80.0), ("roll_deg", roll_deg, 180.0),
                        ("off_sheet_mm", off_sheet_mm, 1e4), ("laser_flood", laser_flood, 1e3)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and 0 <= v <= hi):
            raise _fail(f"--{name.replace('_', '-')} {v!r}: must be a number in [0, {hi:g}]")
    if on_table and not (step_deg is not None and math.isfinite(step_deg) and 0 < step_deg <= 360):
        raise _fail(f"--step-deg {step_deg!r}: --on-table needs a step in (0, 360] [deg]")


def target_scenario(rig: Rig, seed: int = 0, pattern: str = "chessboard:10x8:7", poses: int = 20,
                    on_table: bool = False, step_deg: float | None = None, tilt_deg: float = 35.0,
                    roll_deg: float = 30.0, off_sheet_mm: float = 5.0, depth_range_mm=None,
                    height_range_mm=None, lights=TARGET_LIGHTS, laser_flood: float = 0.0,
                    flood_exposure: float | None = None, plate_mm=None, border_mm: float | None = None,
                    thickness_mm: float = 3.0, bow_mm: float = 0.0, plate_material: str = "white-plastic",
                    truth_pixels_every: int = 0, room_light: bool = False,
                    rig_from_patterns=None) -> Scenario:
    """The ``target`` scenario (module docstring).

    Parameters
    ----------
    rig : Rig
        The rig; it must have a flood light (``[environment] flood_irradiance_w_m2`` > 0)
        when flood frames are asked for.
    seed : int, default 0
        Run seed: the poses and the frame seeds.
    pattern : str, default "chessboard:10x8:7"
        Pattern spec (:func:`scenes.patterns.parse_pattern`).
    poses : int, default 20
        Hand-held poses (≥ 1).
    on_table : bool, default False
        The pattern on the rotary table instead (``step_deg`` needed).
    step_deg : float, optional
        Table step [deg].
    tilt_deg, roll_deg : float
        Tilt limit about the print's two axes, and in-plane turn limit [deg].
    off_sheet_mm : float, default 5.0
        Largest offset of a pose's centre from the sheet [mm].
    depth_range_mm, height_range_mm : (2,) float, optional
        Ranges of D (from the object hinge) and height on the sheet for the centres [mm];
        default: where the camera looks.
    lights : sequence of str or str, default ("flood", "laser")
        Frames per pose.
    laser_flood : float, default 0.0
        The flood light's level in laser frames [-] (0 = off: ``"laser"``; else ``"both"``).
    flood_exposure : float, optional
        Exposure of the flood frames [ms]; default :func:`flood_exposure_ms`.
    plate_mm : (2,) float, optional
        Plate width × height [mm] (:func:`scenes.patterns.target_assembly`; default the
        pattern plus its border).
    border_mm : float, optional
        Paper margin around the pattern [mm]; default one square.
    thickness_mm : float, default 3.0
        Plate thickness [mm].
    bow_mm : float, default 0.0
        Bow of the print, + toward the camera [mm].
    plate_material : str, default "white-plastic"
        Material tag of the plate.
    truth_pixels_every : int, default 0
        Per-pixel truth every N-th frame (0 = never).
    room_light : bool, default False
        The set as users take it in a lit room: the laser frames with the flood light on at the
        flood frames' level and their exposure (light ``"both"``), so that each pose's flood frame
        is its laser frame's laser-off frame (``scenario_params.room_light``; the rig's flood
        light is the room's).  The laser frame takes its flood frame's camera-pass estimate
        (``FrameSpec.camera_seed``): the two photographs differ by the laser and the sensor's
        noise, not by the twin's Monte Carlo noise.
    rig_from_patterns : sequence of (4, 4) array_like float, optional
        Given hand-held poses instead of drawn ones: the pattern frame in the rig frame [mm]
        (a real frame's pose, :mod:`sim.pose_twin`); ``poses``, the tilts, roll, offsets and
        ranges are then not used (``scenario_params.poses_given``).

    Returns
    -------
    Scenario
        ``name`` ``"target"``; frames with ``light``, ``pose_index`` and ``exposure_ms``;
        the flood frames are ``expected_empty`` (no laser); ``frame_truth`` =
        :func:`pattern_truth`.

    Raises
    ------
    ScheimpflugError
        A bad option (one line naming it): 0 poses, a tilt or roll out of range, a bad light
        list, no step on the table, ranges or a table that can never show the pattern, flood
        frames (or room light) without a flood light, room light with ``laser_flood``.
    MeshError
        An unknown pattern spec, or a pattern larger than the plate.
    """
    from scenes.patterns import parse_pattern, target_assembly

    spec = parse_pattern(pattern)
    lights = _lights(lights)
    _check_options(poses, tilt_deg, roll_deg, off_sheet_mm, laser_flood, on_table, step_deg)
    if room_light and laser_flood:
        raise _fail("--room-light lights the laser frames as the flood frames (the flood at its full level, the "
                    "flood frames' exposure): not with --laser-flood")
    if room_light and rig.environment.flood_irradiance_w_m2 <= 0:
        raise _fail("--room-light needs the room's light: its irradiance W/m² (render target --room-light W_M2)")
    if "flood" in lights and rig.environment.flood_irradiance_w_m2 <= 0:
        raise _fail("flood frames need the rig's flood light: set [environment] flood_irradiance_w_m2 > 0 "
                    "(render target --flood-w-m2)")
    _check_ranges(rig, depth_range_mm, height_range_mm)
    assembly = target_assembly(spec, plate_mm=plate_mm, border_mm=border_mm, thickness_mm=thickness_mm,
                               bow_mm=bow_mm, plate_material=plate_material)
    printed = assembly.parts[0].analytic
    e = spec.extent_mm()
    centre_xy = (0.5 * (e[0] + e[2]), 0.5 * (e[1] + e[3]))
    stage_from_rig = invert(rig_from_stage(rig))
    if on_table:
        part_from_pattern = _part_from_pattern(rig, spec, printed["print_mm"])
        assembly = assembly.transformed(part_from_pattern)
        angles = _table_angles(rig, step_deg, part_from_pattern, centre_xy)
        if not angles:
            raise _fail(f"--on-table --step-deg {step_deg:g}: at no angle does the camera see the print within "
                        f"{MAX_VIEW_DEG:g}° of its normal: poses that can never be in view")
        rig_from_parts = [rig_from_stage(rig) @ stage_from_part(rig, a) for a in angles]
    else:
        part_from_pattern = np.eye(4)
        given = _given_poses(rig_from_patterns, on_table)
        angles = [None] * (len(given) if given is not None else poses)
        rig_from_parts = given if given is not None else _hand_held_poses(
            rig, seed, poses, centre_xy, tilt_deg, roll_deg, off_sheet_mm, depth_range_mm, height_range_mm)
    t_flood = flood_exposure_ms(rig) if flood_exposure is None else float(flood_exposure)
    if not (math.isfinite(t_flood) and t_flood > 0):
        raise _fail(f"--flood-exposure-ms {flood_exposure!r}: must be > 0")
    frames = []
    for k, (m, angle) in enumerate(zip(rig_from_parts, angles)):
        for light in lights:
            i = len(frames)
            z, laser, factor, actual = frame_errors(rig, seed, i)
            level = 1.0 if light == "flood" or room_light else float(laser_flood)
            name = light if light == "flood" or level == 0 else "both"
            exposure = t_flood if light == "flood" or room_light else rig.sensor.exposure_ms
            shared = frames[-1].seed if room_light and light != "flood" and frames and frames[-1].pose_index == k \
                and frames[-1].light == "flood" else None
            frames.append(FrameSpec(i, m, stage_from_rig @ m, frame_seed(seed, i), angle_deg=angle,
                                    rig_from_laser=laser, exposure_factor=factor, actual=actual, light=name,
                                    pose_index=k, exposure_ms=exposure, flood_scale=level, camera_seed=shared))
    params = {"pattern": spec.text, "poses": len(rig_from_parts), "on_table": bool(on_table),
              "step_deg": step_deg, "tilt_deg": tilt_deg, "roll_deg": roll_deg, "off_sheet_mm": off_sheet_mm,
              "depth_range_mm": None if depth_range_mm is None else list(depth_range_mm),
              "height_range_mm": None if height_range_mm is None else list(height_range_mm),
              "lights": list(lights), "laser_flood": laser_flood, "flood_exposure_ms": t_flood,
              "room_light": bool(room_light), "poses_given": rig_from_patterns is not None,
              "room_light_w_m2": rig.environment.flood_irradiance_w_m2 if room_light else None,
              "part": "target", "print": printed, "part_from_pattern": part_from_pattern.tolist(),
              "plate_material": plate_material, "thickness_mm": thickness_mm,
              "flood_aim_mm": flood_aim_point_mm(rig).tolist() if rig.environment.flood_irradiance_w_m2 > 0 else None}
    empty = frozenset(f.index for f in frames if f.light == "flood")
    return Scenario("target", params, assembly, tuple(frames), stage_from_rig @ rig_from_parts[0],
                    truth_pixels_every, (), empty, frame_truth=pattern_truth)


def _given_poses(rig_from_patterns, on_table: bool):
    """The given poses checked (4 × 4 rigid transforms), or None."""
    if rig_from_patterns is None:
        return None
    if on_table:
        raise _fail("given poses of the pattern are hand-held poses: not with --on-table")
    out = []
    for m in rig_from_patterns:
        m = np.asarray(m, np.float64)
        r = m[:3, :3] if m.shape == (4, 4) else np.zeros((3, 3))
        if m.shape != (4, 4) or not np.isfinite(m).all() or np.abs(r.T @ r - np.eye(3)).max() > 1e-6 \
                or np.linalg.det(r) < 0:
            raise _fail("a given pose of the pattern must be a 4 × 4 rigid transform (rotation, det +1) [mm]")
        out.append(m)
    if not out:
        raise _fail("no given pose of the pattern")
    return out


def target_frame_count(on_table: bool = False, poses: int = 20, step_deg=None, lights=TARGET_LIGHTS,
                       rig_from_patterns=None, **_) -> int:
    """Frames of a target scenario from its options alone (an upper bound on the table).

    Parameters
    ----------
    on_table : bool, default False
        Table poses instead of hand-held ones.
    poses : int, default 20
        Hand-held poses.
    step_deg : float, optional
        Table step [deg].
    lights : sequence of str or str
        Frames per pose.
    rig_from_patterns : sequence, optional
        Given poses (their number is the poses').
    **_
        Other options (ignored).

    Returns
    -------
    int
        poses × lights (table: one turn's angles × lights).
    """
    try:
        n_lights = len(_lights(lights))
    except ScheimpflugError:
        n_lights = 2
    if on_table:
        step = float(step_deg) if step_deg and math.isfinite(float(step_deg)) and step_deg > 0 else 360.0
        return max(1, int(round(360.0 / step))) * n_lights
    if rig_from_patterns is not None:
        return max(1, len(rig_from_patterns)) * n_lights
    return max(1, int(poses) if isinstance(poses, int) else 20) * n_lights


# ------------------------------------------------------------------ truth
def _blank_stripe(arrays: dict) -> None:
    """The laser is off in a flood frame: no stripe."""
    for key, fill in (("stripe_u", np.nan), ("stripe_point_mm", np.nan), ("stripe_object_id", 0),
                      ("stripe_count", 0)):
        if key in arrays:
            arrays[key] = np.full_like(arrays[key], fill)


def _visible(rig: Rig, points, normal_reader, caster, uv) -> np.ndarray:
    pose = sensor_pose(rig)
    c = lens_centre_mm(rig)
    on = (uv[:, 0] >= -0.5) & (uv[:, 0] <= pose.columns - 0.5) & (uv[:, 1] >= -0.5) & (uv[:, 1] <= pose.rows - 0.5)
    to_lens = c - points
    dist = np.linalg.norm(to_lens, axis=1)
    facing = to_lens @ normal_reader > 0
    t, _ = caster.first_hit(np.repeat(c[None], len(points), 0), -to_lens / dist[:, None])
    clear = t >= dist - 0.01          # the first surface met is the print itself (0.01 mm: float32 geometry)
    return on & facing & clear & np.isfinite(uv).all(axis=1)


def _spot_centroids(rig: Rig, points, n: int = 256) -> np.ndarray:
    """Light centroid of each point's blur spot on the sensor (aperture samples, étendue weights) [px]."""
    from scheimpflug.model.camera import conjugate_point, pixel_from_sensor_point

    pose = sensor_pose(rig)
    c = lens_centre_mm(rig)
    a = 0.5 * rig.lens.focal_length_mm / rig.lens.f_number
    k = np.arange(n) + 0.5
    r, phi = a * np.sqrt(k / n), k * math.pi * (3 - math.sqrt(5))        # Fibonacci disc
    ap = np.stack([np.full(n, c[0]), r * np.cos(phi), r * np.sin(phi)], 1)
    img = conjugate_point(rig, points)[:, None, :]
    w = img - ap[None]
    lam = ((pose.origin_mm - ap[None]) @ pose.normal) / (w @ pose.normal)
    q = ap[None] + lam[..., None] * w
    d = ap[None] - q
    d2 = (d**2).sum(-1)
    weight = np.abs(d[..., 0]) * np.abs(d @ pose.normal) / d2**2
    uv = pixel_from_sensor_point(pose, q)
    return (uv * weight[..., None]).sum(1) / weight.sum(1)[:, None]


def pattern_truth(rig: Rig, scenario: Scenario, frame: FrameSpec, caster, arrays: dict) -> dict:
    """The pattern's truth of one target frame (module docstring), added to the frame's truth arrays.

    Parameters
    ----------
    rig : Rig
        The instrument.
    scenario : Scenario
        The target scenario (``params``: ``pattern``, ``print``, ``part_from_pattern``).
    frame : FrameSpec
        The frame (its pose; ``light``).
    caster : RayCaster
        First-hit queries on the scene posed for the frame (:mod:`sim.truth`).
    arrays : dict
        The frame's truth arrays so far (the laser's stripe); changed in place.

    Returns
    -------
    dict
        ``arrays`` with the keys of the module docstring (and the stripe blanked in a flood frame).
    """
    from scenes.patterns import parse_pattern, print_points_mm

    from .truth import opencv_camera

    if frame.light == "flood":
        _blank_stripe(arrays)
    p = scenario.params
    spec = parse_pattern(p["pattern"])
    rig_from_pattern = np.asarray(frame.rig_from_part) @ np.asarray(p["part_from_pattern"])
    local = print_points_mm(p["print"], spec.corners_mm())
    pts = local @ rig_from_pattern[:3, :3].T + rig_from_pattern[:3, 3]
    uv = project_points(rig, pts).uv_px
    seen = _visible(rig, pts, -rig_from_pattern[:3, 2], caster, uv)
    corners = np.where(seen[:, None], uv, np.nan)
    centroids = np.where(seen[:, None], _spot_centroids(rig, pts), np.nan)
    du, _ = blur_footprint_px(rig, pts)
    _, camera_from_rig = opencv_camera(rig)
    arrays.update(pattern_corners_px=corners, pattern_corner_ids=spec.corner_ids(),
                  pattern_centroid_px=centroids, pattern_blur_px=np.where(seen, du, np.nan),
                  rig_from_pattern=rig_from_pattern, camera_from_pattern=camera_from_rig @ rig_from_pattern)
    return arrays
