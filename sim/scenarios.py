"""Render scenarios: what is on the stages and where, frame by frame.

A :class:`Scenario` is an :class:`~scenes.part.Assembly` (in its part frame)
plus one :class:`FrameSpec` per frame (the assembly's pose, the stage reading
and the frame's noise seed).  Three scenarios (docs/reference/interface.md):

``calibration``
    The calibration plate (:func:`scenes.generators.plate`, height
    ``plate_height_mm``) on the translation stage at s = start + i·step
    (:func:`sim.stages.rig_from_plate`).  Defaults: the rig's calibration plan
    (:func:`scheimpflug.model.plan.calibration_plan`): the rig's plate
    (``[stage] calibration_plate_height_mm``), 27 frames spanning the stretch
    of the depth range where both plate edges are in view (paper rig:
    s = −12.1 … 250.5 mm in 10.1 mm steps).  The paper used 27 × 20 mm, but
    that spans 520 mm while its depth range is only ≈ 277 mm, so half of those
    frames would be empty; ``step_mm=20`` reproduces the paper literally and
    the out-of-view frames are listed in :attr:`Scenario.warnings`, as are
    frames that show one plate edge only.
``blocker``
    The blocker part on the rotary stage at θ = 0 (faces ⊥ e_p); ``frames``
    identical poses with different noise seeds (default 1).
``rotary``
    A part (scenes preset name or mesh file) on the rotary stage at
    θ_i = i·step_deg, i = 0 … round(360/step) − 1 (optionally only the first
    ``frames``).

Frame seeds: frame i of a run with seed S uses ``frame_seed(S, i)``, a 32-bit
integer from ``SeedSequence((S, i))``; the renderer and the sensor noise of that
frame depend only on it (it is written to the manifest).

Error models (``rig`` keys, each off by default; :func:`scheimpflug.model.rig.active_error_models`):
the stage moves where its error model puts it (:func:`sim.stages.translation_state`,
:func:`sim.stages.rotary_state`), the plate is made and mounted as the rig says
(height error, flatness, tilt, yaw), the sheet points where this frame's pointing
draw turns it (:func:`sim.lightsheet.pointing_pose`) and the exposure is this
frame's (:func:`sim.sensor.exposure_scale`).  The random parts come from four
standard normal draws per frame (:func:`frame_draws`: stage, pointing ×2,
exposure; always all four, so switching one model on leaves the others' draws
unchanged).  The frame's pose, sheet and exposure are what is rendered and what
the truth is computed from; the manifest keeps the *commanded* ``stage_mm`` /
``angle_deg`` and adds the realised values as the frame's ``actual`` entry.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from scheimpflug.errors import MeshError, RigError, ScheimpflugError
from scheimpflug.model.camera import lens_state
from scheimpflug.model.hinge import hinge_geometry
from scheimpflug.model.plan import (
    CALIBRATION_STEPS,
    EDGE_MARGIN_ROWS,
    axis_warnings,
    calibration_plan,
    calibration_volume,
    plate_interval_mm,
    plate_warnings,
)
from scheimpflug.model.rig import Rig, active_error_models

from .lightsheet import pointing_pose
from .sensor import exposure_scale
from .stages import (
    ref_from_stage,
    rig_from_plate,
    rig_from_stage,
    rotary_state,
    rotation_vector,
    stage_from_part,
    translation_state,
)

__all__ = [
    "SCENARIOS",
    "FrameSpec",
    "Scenario",
    "blocker_scenario",
    "build_scenario",
    "calibration_scenario",
    "frame_count",
    "frame_draws",
    "frame_errors",
    "frame_seed",
    "load_assembly",
    "reuse_assemblies",
    "rotary_scenario",
]

SCENARIOS = ("blocker", "calibration", "rotary", "target")


def frame_seed(seed: int, index: int) -> int:
    """The 32-bit seed of one frame of a run.

    Parameters
    ----------
    seed : int
        Run seed (≥ 0).
    index : int
        Frame index (≥ 0).

    Returns
    -------
    int
        The frame's seed in [0, 2**32): the first 32-bit word of
        ``numpy.random.SeedSequence((seed, index))``.

    Raises
    ------
    ValueError
        When ``seed`` or ``index`` is negative.
    """
    if seed < 0 or index < 0:
        raise ValueError(f"seed and frame index must be >= 0, got {seed}, {index}")
    return int(np.random.SeedSequence((int(seed), int(index))).generate_state(1, np.uint32)[0])


_STREAM_ERRORS = 0xE770  # the error models' stream of a frame


def frame_draws(seed: int, index: int) -> np.ndarray:
    """The standard normal draws of one frame's random error models.

    Parameters
    ----------
    seed : int
        Run seed (≥ 0).
    index : int
        Frame index (≥ 0).

    Returns
    -------
    (4,) float64
        z for the stage's random error (translation or rotary), the pointing
        about e_z and about e_p, and the exposure, from
        ``SeedSequence((seed, index, 0xE770))``.

    Raises
    ------
    ValueError
        When ``seed`` or ``index`` is negative.
    """
    if seed < 0 or index < 0:
        raise ValueError(f"seed and frame index must be >= 0, got {seed}, {index}")
    ss = np.random.SeedSequence((int(seed), int(index), _STREAM_ERRORS))
    return np.random.Generator(np.random.PCG64(ss)).standard_normal(4)


@dataclass(frozen=True, eq=False)
class FrameSpec:
    """One frame to render.

    Parameters
    ----------
    index : int
        Frame number (file ``frames/{index:05d}.png``).
    rig_from_part : (4, 4) float
        Pose of the assembly (part frame) in the rig frame [mm].
    ref_from_part : (4, 4) float
        Part frame → truth reference frame [mm] (the stage frame with the part
        at θ = 0 for the rotary stage; the stage frame for the plate).
    seed : int
        32-bit frame seed (renderer and sensor noise).
    stage_mm : float or None, default None
        Translation-stage coordinate s [mm] (calibration), else None.
    angle_deg : float or None, default None
        Rotary-stage angle θ [deg] (blocker, rotary), else None.
    rig_from_laser : (4, 4) float or None, default None
        This frame's pose of the laser sheet (pointing drift) [mm]; None = nominal.
    exposure_factor : float, default 1.0
        This frame's real exposure over the nominal one [-].
    actual : dict or None, default None
        JSON-ready realised values of the rig's error models in this frame
        (the manifest's ``actual`` entry); None for an ideal rig.
    light : {"flood", "laser", "both"} or None, default None
        The frame's lighting (scenario ``target``, :mod:`sim.target`); None = a scan's
        frame (the laser, the rig's environment and flood light).
    pose_index : int or None, default None
        Index of the pattern pose the frame shows (scenario ``target``).
    exposure_ms : float or None, default None
        The frame's commanded exposure [ms]; None = the rig's ``sensor.exposure_ms``.
    flood_scale : float, default 1.0
        The flood light's level in this frame over the rig's [-].
    camera_seed : int or None, default None
        The camera pass's seed (its Monte Carlo estimate of the flood light and the environment);
        None = ``seed``.  A frame that shows the same lit scene as another one (a room-light
        target's laser frame and its pose's flood frame: :mod:`sim.target`) takes that frame's,
        so that the two differ by the laser and the sensor's noise only, as two photographs do.
    """

    index: int
    rig_from_part: np.ndarray
    ref_from_part: np.ndarray
    seed: int
    stage_mm: float | None = None
    angle_deg: float | None = None
    rig_from_laser: np.ndarray | None = None
    exposure_factor: float = 1.0
    actual: dict | None = None
    light: str | None = None
    pose_index: int | None = None
    exposure_ms: float | None = None
    flood_scale: float = 1.0
    camera_seed: int | None = None

    def stage_entry(self) -> dict:
        """The manifest's stage entry of this frame.

        Returns
        -------
        dict
            ``{"stage_mm": s}`` [mm] when the frame has a translation-stage
            coordinate, ``{"angle_deg": θ}`` [deg] when it has a rotary-stage
            angle, else ``{}`` (a hand-held target pose); plus ``pose`` and ``light``
            for a target frame.
        """
        out = {}
        if self.stage_mm is not None:
            out = {"stage_mm": float(self.stage_mm)}
        elif self.angle_deg is not None:
            out = {"angle_deg": float(self.angle_deg)}
        if self.light is not None:
            out.update(pose=int(self.pose_index), light=self.light)
        return out


@dataclass(frozen=True, eq=False)
class Scenario:
    """A scenario ready to render.

    Parameters
    ----------
    name : str
        One of :data:`SCENARIOS`.
    params : dict
        JSON-ready scenario parameters (written to the manifest).
    assembly : scenes.Assembly
        The parts, in the part frame.
    frames : tuple of FrameSpec
        The frames, in order.
    mesh_ref_from_part : (4, 4) float
        Pose of ``truth/mesh.ply``: the assembly in the reference frame [mm].
    truth_pixels_every : int, default 1
        Per-pixel truth every N-th frame (0 = never).
    warnings : tuple of str, default ()
        Human-readable warnings (e.g. frames predicted to hold no stripe).
    expected_empty : frozenset of int, default frozenset()
        Indices of the frames predicted to hold no stripe (already warned about).
    frame_truth : callable or None, default None
        ``frame_truth(rig, scenario, frame, caster, arrays) -> arrays``: the scenario's
        own truth added to a frame's (:func:`sim.target.pattern_truth`,
        :func:`sim.backgrounds.background_truth`); None = none.
    background : tuple of scenes.Part, default ()
        Parts fixed in the stage frame around the stages (:mod:`sim.backgrounds`).
    """

    name: str
    params: dict
    assembly: object
    frames: tuple
    mesh_ref_from_part: np.ndarray
    truth_pixels_every: int = 1
    warnings: tuple = field(default_factory=tuple)
    expected_empty: frozenset = frozenset()
    frame_truth: object = None
    background: tuple = ()

    def wants_pixel_truth(self, index: int) -> bool:
        """Whether a frame gets per-pixel truth maps.

        Parameters
        ----------
        index : int
            Frame index.

        Returns
        -------
        bool
            True when ``truth_pixels_every`` > 0 and divides ``index``.
        """
        return self.truth_pixels_every > 0 and index % self.truth_pixels_every == 0


# ------------------------------------------------------------------ parts


def load_assembly(name_or_path: str, seed: int = 0, **overrides):
    """An assembly from a scenes preset name, mesh file or scene file.

    Thin wrapper of :func:`scenes.load_part`.

    Parameters
    ----------
    name_or_path : str
        A preset name of :data:`scenes.PART_NAMES`, or the path of a mesh file
        (.stl/.ply/.obj) or scene file (.toml).
    seed : int, default 0
        Seed of the part's random variations.
    **overrides
        Preset parameters (e.g. ``height_mm`` for the plate), passed on.

    Returns
    -------
    scenes.Assembly
        The parts, in the part frame.

    Raises
    ------
    MeshError
        For an unknown part (the message lists the known names) or a bad file.
    """
    from scenes import load_part

    if _REUSE is None:
        return load_part(name_or_path, seed=seed, **overrides)
    import json
    from pathlib import Path

    # presets and mesh files do not depend on the seed (scenes.load_part); scene files do
    seeded = Path(str(name_or_path)).suffix.lower() == ".toml"
    key = json.dumps([str(name_or_path), seed if seeded else None, overrides], sort_keys=True, default=repr)
    if key not in _REUSE:
        _REUSE.clear()                              # one assembly kept: a million-face part is ≈ 50 MB
        _REUSE[key] = load_part(name_or_path, seed=seed, **overrides)
    return _REUSE[key]


_REUSE: dict | None = None


@contextlib.contextmanager
def reuse_assemblies(cache: dict) -> Iterator[None]:
    """Within the block, :func:`load_assembly` reuses the last assembly built with the same arguments.

    For callers that build many scenarios of the same part in one process (the dataset
    maker: rebuilding the paper cylinder's 1.09 M faces costs ≈ 0.4 s per sample).  The
    assemblies are shared, so they must not be modified (they are frozen dataclasses;
    their mesh arrays are not written by this package).  Presets and mesh files are
    keyed by name and overrides (they do not depend on the seed), scene files also by
    the seed; a mesh or scene file is read once per cache.

    Parameters
    ----------
    cache : dict
        Where the last assembly is kept (the caller owns it and may keep it across blocks).

    Yields
    ------
    None
        Nothing; the reuse ends with the block.
    """
    global _REUSE
    previous, _REUSE = _REUSE, cache
    try:
        yield
    finally:
        _REUSE = previous


# ------------------------------------------------------------------ scenarios


def _positive_int(name: str, value: int) -> None:
    if not isinstance(value, int) or isinstance(value, bool) or value < 1:
        raise ScheimpflugError(f"--{name.replace('_', '-')} = {value!r}: must be an integer >= 1")


def _positive(name: str, value: float) -> None:
    if not (math.isfinite(value) and value > 0):
        raise ScheimpflugError(f"--{name.replace('_', '-')} = {value!r}: must be a number > 0")


def calibration_scenario(rig: Rig, seed: int = 0, steps: int | None = None, step_mm: float | None = None,
                         start_mm: float | None = None, plate_height_mm: float | None = None,
                         truth_pixels_every: int = 1) -> Scenario:
    """The calibration plate on the translation stage at s = start + i·step.

    Parameters
    ----------
    rig : Rig
        The rig.
    seed : int, default 0
        Run seed (frame seeds by :func:`frame_seed`).
    steps : int, optional
        Number of frames (≥ 1); default the rig's calibration plan (27).
    step_mm, start_mm : float, optional
        Stage step (> 0) and coordinate of the first frame [mm]; default the
        rig's calibration plan (:func:`scheimpflug.model.plan.calibration_plan`:
        the stretch of the depth range where both plate edges are in view).
    plate_height_mm : float, optional
        Height of the plate (> 0) [mm]; default the rig's
        ``calibration_plate_height_mm``.
    truth_pixels_every : int, default 1
        Per-pixel truth every N-th frame (0 = never).

    Returns
    -------
    Scenario
        Frames with ``stage_mm``; the reference frame is the stage frame;
        frames whose plate lies outside the view (closed form) are listed in
        ``warnings`` and ``expected_empty``; ``warnings`` also lists frames that
        show one plate edge only and the stage setting that hides the plate.

    Raises
    ------
    ScheimpflugError
        When ``steps`` is not an integer ≥ 1, ``step_mm`` or
        ``plate_height_mm`` is not > 0, or ``start_mm`` is not finite.
    """
    if plate_height_mm is not None:
        _positive("plate_height_mm", plate_height_mm)
    if steps is not None:
        _positive_int("steps", steps)
    plan = calibration_plan(rig, plate_height_mm, steps or CALIBRATION_STEPS)
    steps, plate_height_mm = plan.steps, plan.plate_height_mm
    step_mm = plan.step_mm if step_mm is None else step_mm
    start_mm = plan.start_mm if start_mm is None else start_mm
    if steps > 1:
        _positive("step_mm", step_mm)
    if not math.isfinite(start_mm):
        raise ScheimpflugError(f"--start-mm = {start_mm!r}: must be a finite number")
    st = rig.stage
    shape = {k: v for k, v in (("flatness_um", st.plate_flatness_um), ("edge_break_mm", st.plate_edge_break_mm))
             if v}
    assembly = load_assembly("plate", height_mm=plate_height_mm + st.plate_height_error_mm, **shape)
    ref_from_rig = np.linalg.inv(rig_from_stage(rig))
    frames = []
    for i in range(steps):
        s = round(start_mm + i * step_mm, 9)  # 30.3, not 30.299999999999997, in the manifest
        frames.append(_plate_frame(rig, seed, i, s, ref_from_rig))
    params = {"steps": steps, "step_mm": step_mm, "start_mm": start_mm,
              "plate_height_mm": plate_height_mm, "part": "plate",
              "plate": assembly.parts[0].analytic}
    empty, warnings = _plate_view_warnings(rig, frames)
    warnings += _edge_warnings(rig, frames, plate_height_mm, empty)
    return Scenario("calibration", params, assembly, tuple(frames), frames[0].ref_from_part,
                    truth_pixels_every, warnings, empty)


def _plate_mount(rig: Rig) -> np.ndarray:
    """The plate on the carriage: R_z(yaw)·R_n(tilt) about its face's bottom centre (4, 4)."""
    st = rig.stage
    return rotation_vector([0.0, 0.0, np.radians(st.plate_yaw_deg)]) \
        @ rotation_vector([0.0, np.radians(st.plate_tilt_deg), 0.0])


def frame_errors(rig: Rig, seed: int, index: int) -> tuple:
    """The realised error models of one frame (:func:`frame_draws`).

    Parameters
    ----------
    rig : Rig
        The rig (its error models).
    seed : int
        Run seed (≥ 0).
    index : int
        Frame index (≥ 0).

    Returns
    -------
    tuple
        (z draws (4,), rig_from_laser (4, 4) or None, exposure factor [-], the manifest's
        ``actual`` dict or None for an ideal rig).
    """
    return _frame_errors(rig, seed, index)


def _frame_errors(rig: Rig, seed: int, index: int) -> tuple:
    """(z draws, rig_from_laser, exposure factor, actual dict or None) of one frame."""
    z = frame_draws(seed, index)
    laser = pointing_pose(rig, z[1], z[2])
    factor = exposure_scale(rig, z[3])
    if not active_error_models(rig):
        return z, laser, factor, None
    actual = {"exposure_factor": factor,
              "pointing_urad": [rig.laser.pointing_jitter_urad * z[1],
                                rig.laser.pointing_jitter_urad * z[2]],
              "lens_centre_x_mm": lens_state(rig).centre_x_mm}
    return z, laser, factor, actual


def _plate_frame(rig: Rig, seed: int, i: int, s: float, ref_from_rig: np.ndarray) -> FrameSpec:
    z, laser, factor, actual = _frame_errors(rig, seed, i)
    if actual is None:
        pose = rig_from_plate(rig, s)
    else:
        state = translation_state(rig, s, z[0])
        pose = rig_from_plate(rig, s, state) @ _plate_mount(rig)
        actual = dict(actual, stage=state.to_dict())
    return FrameSpec(i, pose, ref_from_rig @ pose, frame_seed(seed, i), stage_mm=s,
                     rig_from_laser=laser, exposure_factor=factor, actual=actual)


def _edge_warnings(rig: Rig, frames, plate_height_mm: float, empty: frozenset) -> tuple:
    """Frames in view that show one plate edge only, and the stage key that hides the plate."""
    vol = calibration_volume(rig)
    both = plate_interval_mm(vol, plate_height_mm, rig.stage.calibration_table_z_mm)
    d0 = rig.stage.d0_mm
    one = [f for f in frames if f.index not in empty
           and not (both and both[0] - 1e-9 <= f.stage_mm - d0 <= both[1] + 1e-9)]
    if not one:
        return ()
    where = (f"both edges are in view for s in [{both[0] + d0:.2f}, {both[1] + d0:.2f}] mm" if both
             else "no stage position shows both edges")
    return (f"{len(one)} of {len(frames)} calibration frames may show one plate edge only ({where}; "
            f"{EDGE_MARGIN_ROWS} rows of margin): they give the distance relation, not C or v_h: "
            f"s = {', '.join(f'{f.stage_mm:g}' for f in one)} mm", *plate_warnings(rig, plate_height_mm))


def _plate_view_warnings(rig: Rig, frames) -> tuple[frozenset, tuple]:
    """Frames whose plate face lies outside the columns' distance range (closed form)."""
    g = hinge_geometry(rig)
    d_near, d_far = sorted(g.distance_from_column([-0.5, rig.sensor.columns - 0.5]))
    out = [f for f in frames if not d_near <= f.stage_mm - rig.stage.d0_mm <= d_far]
    if not out:
        return frozenset(), ()
    listed = ", ".join(f"{f.stage_mm:g}" for f in out)
    lo, hi = d_near + rig.stage.d0_mm, d_far + rig.stage.d0_mm
    return frozenset(f.index for f in out), (
        f"{len(out)} of {len(frames)} calibration frames put the plate outside the view "
        f"(stage s must lie in [{lo:.1f}, {hi:.1f}] mm; these frames hold no stripe): "
        f"s = {listed} mm",)


def _reference_pose(rig: Rig) -> np.ndarray:
    """ref_from_part of the rotary part at θ = 0: stage frame or turntable frame (:func:`sim.stages.ref_from_stage`)."""
    if rig.stage.axis_tilt_deg < 90.0:
        return stage_from_part(rig, 0.0)           # the stage frame itself: bit for bit as before
    return ref_from_stage(rig) @ stage_from_part(rig, 0.0)


def _rotary_frames(rig: Rig, seed: int, angles) -> tuple:
    rig_from_st = rig_from_stage(rig)
    ref_from_part = _reference_pose(rig)
    return tuple(_rotary_frame(rig, seed, i, float(a), rig_from_st, ref_from_part)
                 for i, a in enumerate(angles))


def _rotary_frame(rig: Rig, seed: int, i: int, angle: float, rig_from_st, ref_from_part) -> FrameSpec:
    z, laser, factor, actual = _frame_errors(rig, seed, i)
    if actual is None:
        pose = stage_from_part(rig, angle)
    else:
        state = rotary_state(rig, angle, z[0])
        pose = stage_from_part(rig, angle, state)
        actual = dict(actual, stage=state.to_dict())
    return FrameSpec(i, rig_from_st @ pose, ref_from_part, frame_seed(seed, i), angle_deg=angle,
                     rig_from_laser=laser, exposure_factor=factor, actual=actual)


def blocker_scenario(rig: Rig, seed: int = 0, frames: int = 1, thickness_mm: float = 2.0,
                     truth_pixels_every: int = 1, background: str = "none",
                     background_material: str = "cardboard", background_height_mm: float = 250.0,
                     background_distance_mm: float | None = None) -> Scenario:
    """The blocker on the rotary stage at θ = 0, several times with different noise seeds.

    Parameters
    ----------
    rig : Rig
        The rig.
    seed : int, default 0
        Run seed (frame seeds by :func:`frame_seed`).
    frames : int, default 1
        Number of identical poses (≥ 1).
    thickness_mm : float, default 2.0
        Blocker thickness (> 0) [mm].
    truth_pixels_every : int, default 1
        Per-pixel truth every N-th frame (0 = never).
    background : {"none", "walls", "box"}, default "none"
        What stands around the table (:mod:`sim.backgrounds`).
    background_material : str, default "cardboard"
        Its material tag.
    background_height_mm : float, default 250.0
        Its height above the table [mm].
    background_distance_mm : float, optional
        Where it stands beyond the axis (:func:`sim.backgrounds.scan_background`) [mm].

    Returns
    -------
    Scenario
        Frames with ``angle_deg`` = 0; the reference frame is the stage frame
        with the part at θ = 0.

    Raises
    ------
    ScheimpflugError
        When ``frames`` is not an integer ≥ 1 or ``thickness_mm`` is not > 0.
    MeshError
        For an unknown background or material.
    """
    _positive_int("frames", frames)
    _positive("blocker_thickness_mm", thickness_mm)
    assembly = load_assembly("blocker", thickness_mm=thickness_mm)
    specs = _rotary_frames(rig, seed, [0.0] * frames)
    params = {"frames": frames, "blocker_thickness_mm": thickness_mm, "part": "blocker",
              "blocker": assembly.parts[0].analytic}
    scenario = Scenario("blocker", params, assembly, specs, _reference_pose(rig),
                        truth_pixels_every, tuple(axis_warnings(rig)))
    return _with_background(rig, scenario, background, background_material, background_height_mm,
                            background_distance_mm)


def _with_background(rig: Rig, scenario: Scenario, kind: str, material: str, height_mm: float,
                     distance_mm: float | None = None, housing: str | None = None) -> Scenario:
    """The scenario with background parts, a housing and the table's disc in the stage frame.

    None of them: the scenario unchanged, bit for bit.
    """
    import dataclasses

    from scenes.backgrounds import FIRST_ID
    from scheimpflug.model.housing import load_housing

    from .backgrounds import background_truth, housing_parts, scan_background, table_parts

    if housing is not None and rig.housing:
        raise RigError(f"--housing {str(housing)!r} and the rig's [housing] ({len(rig.housing)} board(s)) both give "
                       "a housing: give one (take [housing] out of the rig file, or leave out --housing)")
    parts = scan_background(rig, kind, material, height_mm, distance_mm)
    boards = load_housing(housing) if housing is not None else rig.housing
    boxes = housing_parts(rig, boards, FIRST_ID + len(parts)) if boards else ()
    table = table_parts(rig, FIRST_ID + len(parts) + len(boxes))
    if not parts and not boxes and not table:
        return scenario
    params = dict(scenario.params)
    if parts:
        params["background"] = {"kind": kind, "material": material, "height_mm": height_mm,
                                "distance_mm": distance_mm, "parts": [p.analytic for p in parts]}
    if boxes:
        params["housing"] = {"file": str(housing) if housing is not None else "rig [housing]",
                             "boards": [b.to_dict() for b in boards]}
    if table:
        params["table"] = {"object_id": table[0].object_id, "material": table[0].material, **table[0].analytic}
    return dataclasses.replace(scenario, params=params, background=parts + boxes + table,
                               frame_truth=background_truth)


def rotary_scenario(rig: Rig, seed: int = 0, part: str = "cylinder", step_deg: float = 0.5,
                    frames: int | None = None, truth_pixels_every: int = 30, background: str = "none",
                    background_material: str = "cardboard", background_height_mm: float = 250.0,
                    background_distance_mm: float | None = None, housing: str | None = None,
                    angles_deg=None, part_material: str | None = None) -> Scenario:
    """A part on the rotary stage at θ_i = i·step_deg over one turn (or at given angles).

    Parameters
    ----------
    rig : Rig
        The rig (stage pose, axis tilt and runout).
    seed : int, default 0
        Run seed: frame seeds (:func:`frame_seed`) and the part's random variations.
    part : str, default "cylinder"
        A scenes preset name, mesh file or scene file (:func:`load_assembly`).
    step_deg : float, default 0.5
        Stage step (> 0) [deg]; one turn is round(360/step_deg) frames (at least 1).
    frames : int, optional
        Render only the first ``frames`` (≥ 1) of the turn.
    truth_pixels_every : int, default 30
        Per-pixel truth every N-th frame (0 = never).
    background : {"none", "walls", "box"}, default "none"
        What stands around the table (:mod:`sim.backgrounds`).
    background_material : str, default "cardboard"
        Its material tag.
    background_height_mm : float, default 250.0
        Its height above the table [mm].
    background_distance_mm : float, optional
        Where it stands beyond the axis (:func:`sim.backgrounds.scan_background`) [mm].
    housing : str, optional
        A housing file (:mod:`scheimpflug.model.housing`): boards in the instrument frame
        that stand still beside the table (:func:`sim.backgrounds.housing_parts`); default
        the rig's own (``rig.housing``, ``[[housing.board]]`` of the rig file).
    angles_deg : sequence of float, optional
        The frames' angles [deg], frame i at ``angles_deg[i]`` (``step_deg`` then unused;
        ``frames`` still keeps the first N); recorded as ``angles_deg`` in the params.
    part_material : str, optional
        The part's material tag (:data:`sim.materials.MATERIALS`) for a mesh file (passed to
        :func:`load_assembly` as ``material``) or every part of a preset; default the part's own
        (a mesh: ``metal``).  Recorded as ``part_material`` in the params.

    Returns
    -------
    Scenario
        Frames with ``angle_deg``; the reference frame is the stage frame with
        the part at θ = 0.

    Raises
    ------
    ScheimpflugError
        When ``step_deg`` is not > 0 or ``frames`` is not an integer ≥ 1.
    MeshError
        For an unknown part or a bad mesh or scene file, or an unknown background or material
        (``part_material`` included; a scene file's parts keep the file's tags: refused).
    RigError
        For a bad housing file (:func:`scheimpflug.model.housing.load_housing`), a housing file
        given beside the rig's own housing, or a housing that hides the whole sheet from the
        camera (:func:`sim.backgrounds.housing_parts`).
    """
    _positive("step_deg", step_deg)
    angles = None if angles_deg is None else _angle_list(angles_deg)
    n_turn = max(1, int(round(360.0 / step_deg))) if angles is None else len(angles)
    if frames is not None:
        _positive_int("frames", frames)
        n_turn = min(n_turn, frames)
    assembly = _rotary_assembly(part, seed, part_material)
    specs = _rotary_frames(rig, seed, [i * step_deg for i in range(n_turn)] if angles is None else angles[:n_turn])
    params = {"part": part, "step_deg": step_deg, "frames": n_turn,
              "parts": [{"name": p.name, "object_id": p.object_id, "material": p.material,
                         "analytic": p.analytic} for p in assembly.parts]}
    if angles is not None:
        params["angles_deg"] = angles[:n_turn]
    if part_material is not None:
        params["part_material"] = part_material
    scenario = Scenario("rotary", params, assembly, specs, _reference_pose(rig),
                        truth_pixels_every, tuple(axis_warnings(rig)))
    return _with_background(rig, scenario, background, background_material, background_height_mm,
                            background_distance_mm, housing)


def _rotary_assembly(part: str, seed: int, material: str | None):
    """The rotary part, its material tag set (a mesh file: ``load_assembly(material=)``; a preset: each part's)."""
    import dataclasses
    from pathlib import Path

    from scenes.meshfile import MESH_SUFFIXES

    from .materials import MATERIALS

    if material is None:
        return load_assembly(part, seed=seed)
    if material not in MATERIALS:
        raise MeshError(f"part_material {material!r}: unknown material tag (known: {', '.join(MATERIALS)})")
    suffix = Path(str(part)).suffix.lower()
    if suffix == ".toml":
        raise MeshError(f"part_material {material!r}: {part!r} is a scene file, which gives its parts' "
                        "materials itself (set them in the file)")
    if suffix in MESH_SUFFIXES:
        return load_assembly(part, seed=seed, material=material)
    asm = load_assembly(part, seed=seed)
    return dataclasses.replace(asm, parts=tuple(dataclasses.replace(p, material=material) for p in asm.parts))


def _angle_list(angles_deg) -> list[float]:
    """Explicit rotary angles: at least one, each a finite number [deg]."""
    try:
        angles = [float(a) for a in angles_deg]
    except (TypeError, ValueError):
        raise ScheimpflugError(f"angles_deg must be a list of numbers [deg], got {angles_deg!r}") from None
    if not angles or not all(math.isfinite(a) for a in angles):
        raise ScheimpflugError(f"angles_deg must hold at least one finite angle [deg], got {angles_deg!r}")
    return angles


def frame_count(name: str, **options) -> int:
    """How many frames a scenario will have, from its options alone (nothing is built).

    Lets a caller size a job before building it (a billion frames would take
    long to build, let alone render).

    Parameters
    ----------
    name : str
        One of :data:`SCENARIOS`.
    **options
        Options of the scenario's builder (``steps``, ``frames``, ``step_deg`` …);
        the others take the builder's defaults.

    Returns
    -------
    int
        The number of frames (a non-numeric option counts as its default; the
        builder refuses it later).

    Raises
    ------
    ScheimpflugError
        For an unknown scenario name.
    """
    import inspect

    table = {"blocker": blocker_scenario, "calibration": calibration_scenario,
             "rotary": rotary_scenario}
    if name == "target":
        from .target import target_frame_count

        return target_frame_count(**{k: v for k, v in options.items() if v is not None})
    if name not in table:
        raise ScheimpflugError(f"unknown scenario {name!r} (known: {', '.join(SCENARIOS)})")
    opts = {k: p.default for k, p in inspect.signature(table[name]).parameters.items()}
    opts.update({k: v for k, v in options.items() if v is not None})
    if name == "calibration":
        return max(1, int(opts["steps"] or CALIBRATION_STEPS))
    if name == "blocker":
        return max(1, int(opts["frames"]))
    step = float(opts["step_deg"])
    n = max(1, int(round(360.0 / step))) if math.isfinite(step) and step > 0 else 1
    if opts.get("angles_deg") is not None:
        n = max(1, len(opts["angles_deg"]))
    return min(n, int(opts["frames"])) if opts.get("frames") else n


def build_scenario(name: str, rig: Rig, seed: int = 0, **options) -> Scenario:
    """Build a scenario by name.

    Parameters
    ----------
    name : str
        One of :data:`SCENARIOS`: ``blocker``, ``calibration``, ``rotary``, ``target``.
    rig : Rig
        The rig.
    seed : int, default 0
        Run seed.
    **options
        Keyword arguments of :func:`blocker_scenario`,
        :func:`calibration_scenario`, :func:`rotary_scenario` or
        :func:`sim.target.target_scenario`.

    Returns
    -------
    Scenario
        The scenario ready to render.

    Raises
    ------
    ScheimpflugError
        For an unknown scenario name (the message lists :data:`SCENARIOS`), or
        an invalid option value (see the builders).
    """
    from .target import target_scenario  # it builds on this module

    table = {"blocker": blocker_scenario, "calibration": calibration_scenario,
             "rotary": rotary_scenario, "target": target_scenario}
    if name not in table:
        raise ScheimpflugError(f"unknown scenario {name!r} (known: {', '.join(SCENARIOS)})")
    return table[name](rig, seed=seed, **options)
