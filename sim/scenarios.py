"""Render scenarios: what is on the stages and where, frame by frame.

A :class:`Scenario` is an :class:`~scenes.part.Assembly` (in its part frame)
plus one :class:`FrameSpec` per frame (the assembly's pose, the stage reading
and the frame's noise seed).  Three scenarios (INTERFACE.md):

``calibration``
    The calibration plate (:func:`scenes.generators.plate`, height
    ``plate_height_mm``) on the translation stage at s = start + i·step
    (:func:`sim.stages.rig_from_plate`).  Defaults: 27 steps of 10 mm from −10 mm (s = −10 … 250, all inside the paper rig's −18.8 … 255.5 mm view).
    The paper used 27 × 20 mm, but that spans 520 mm while its depth range is
    only ≈ 277 mm, so half of those frames would be empty; ``step_mm=20``
    reproduces the paper literally and the out-of-view frames are listed in
    :attr:`Scenario.warnings`.
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
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from scheimpflug.errors import ScheimpflugError
from scheimpflug.model.hinge import hinge_geometry
from scheimpflug.model.rig import Rig

from .stages import rig_from_plate, rig_from_stage, stage_from_part

__all__ = [
    "SCENARIOS",
    "FrameSpec",
    "Scenario",
    "blocker_scenario",
    "build_scenario",
    "calibration_scenario",
    "frame_seed",
    "load_assembly",
    "rotary_scenario",
]

SCENARIOS = ("blocker", "calibration", "rotary")


def frame_seed(seed: int, index: int) -> int:
    """The 32-bit seed of frame ``index`` of a run seeded with ``seed``."""
    if seed < 0 or index < 0:
        raise ValueError(f"seed and frame index must be >= 0, got {seed}, {index}")
    return int(np.random.SeedSequence((int(seed), int(index))).generate_state(1, np.uint32)[0])


@dataclass(frozen=True, eq=False)
class FrameSpec:
    """One frame to render.

    index : frame number (file ``frames/{index:05d}.png``).
    rig_from_part : (4, 4) float, pose of the assembly (part frame) in the rig frame.
    ref_from_part : (4, 4) float, part frame → truth reference frame (the stage frame
        with the part at θ = 0 for the rotary stage; the stage frame for the plate).
    seed : 32-bit frame seed (renderer and sensor noise).
    stage_mm : translation-stage coordinate s [mm] (calibration), else None.
    angle_deg : rotary-stage angle θ [deg] (blocker, rotary), else None.
    """

    index: int
    rig_from_part: np.ndarray
    ref_from_part: np.ndarray
    seed: int
    stage_mm: float | None = None
    angle_deg: float | None = None

    def stage_entry(self) -> dict:
        """The manifest's stage key of this frame: ``{"stage_mm": s}`` or ``{"angle_deg": θ}``."""
        if self.stage_mm is not None:
            return {"stage_mm": float(self.stage_mm)}
        return {"angle_deg": float(self.angle_deg)}


@dataclass(frozen=True, eq=False)
class Scenario:
    """A scenario ready to render.

    name : one of :data:`SCENARIOS`.
    params : JSON-ready scenario parameters (written to the manifest).
    assembly : the parts, in the part frame.
    frames : tuple of :class:`FrameSpec`.
    mesh_ref_from_part : (4, 4) pose of ``truth/mesh.ply`` (the assembly in the reference frame).
    truth_pixels_every : per-pixel truth every N-th frame (0 = never).
    warnings : human-readable warnings (e.g. frames predicted to hold no stripe).
    expected_empty : indices of the frames predicted to hold no stripe (already warned about).
    """

    name: str
    params: dict
    assembly: object
    frames: tuple
    mesh_ref_from_part: np.ndarray
    truth_pixels_every: int = 1
    warnings: tuple = field(default_factory=tuple)
    expected_empty: frozenset = frozenset()

    def wants_pixel_truth(self, index: int) -> bool:
        """Whether frame ``index`` gets per-pixel truth maps."""
        return self.truth_pixels_every > 0 and index % self.truth_pixels_every == 0


# ------------------------------------------------------------------ parts


def load_assembly(name_or_path: str, seed: int = 0, **overrides):
    """An :class:`~scenes.part.Assembly` from a scenes preset name, mesh file or scene file.

    Thin wrapper of :func:`scenes.load_part`; an unknown part raises
    :class:`~scheimpflug.errors.MeshError` listing the known names.
    """
    from scenes import load_part

    return load_part(name_or_path, seed=seed, **overrides)


# ------------------------------------------------------------------ scenarios


def _positive_int(name: str, value: int) -> None:
    if not isinstance(value, int) or isinstance(value, bool) or value < 1:
        raise ScheimpflugError(f"--{name.replace('_', '-')} = {value!r}: must be an integer >= 1")


def _positive(name: str, value: float) -> None:
    if not (math.isfinite(value) and value > 0):
        raise ScheimpflugError(f"--{name.replace('_', '-')} = {value!r}: must be a number > 0")


def calibration_scenario(rig: Rig, seed: int = 0, steps: int = 27, step_mm: float = 10.0,
                         start_mm: float = -10.0, plate_height_mm: float = 89.0,
                         truth_pixels_every: int = 1) -> Scenario:
    """The calibration plate on the translation stage at s = start + i·step [mm]."""
    _positive_int("steps", steps)
    _positive("step_mm", step_mm)
    _positive("plate_height_mm", plate_height_mm)
    if not math.isfinite(start_mm):
        raise ScheimpflugError(f"--start-mm = {start_mm!r}: must be a finite number")
    assembly = load_assembly("plate", height_mm=plate_height_mm)
    ref_from_rig = np.linalg.inv(rig_from_stage(rig))
    frames = []
    for i in range(steps):
        s = start_mm + i * step_mm
        pose = rig_from_plate(rig, s)
        frames.append(FrameSpec(i, pose, ref_from_rig @ pose, frame_seed(seed, i), stage_mm=s))
    params = {"steps": steps, "step_mm": step_mm, "start_mm": start_mm,
              "plate_height_mm": plate_height_mm, "part": "plate",
              "plate": assembly.parts[0].analytic}
    empty, warnings = _plate_view_warnings(rig, frames)
    return Scenario("calibration", params, assembly, tuple(frames), frames[0].ref_from_part,
                    truth_pixels_every, warnings, empty)


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


def _rotary_frames(rig: Rig, seed: int, angles) -> tuple:
    rig_from_st = rig_from_stage(rig)
    ref_from_part = stage_from_part(rig, 0.0)
    return tuple(FrameSpec(i, rig_from_st @ stage_from_part(rig, a), ref_from_part,
                           frame_seed(seed, i), angle_deg=float(a))
                 for i, a in enumerate(angles))


def blocker_scenario(rig: Rig, seed: int = 0, frames: int = 1, thickness_mm: float = 2.0,
                     truth_pixels_every: int = 1) -> Scenario:
    """The blocker on the rotary stage at θ = 0, ``frames`` times (different noise seeds)."""
    _positive_int("frames", frames)
    _positive("blocker_thickness_mm", thickness_mm)
    assembly = load_assembly("blocker", thickness_mm=thickness_mm)
    specs = _rotary_frames(rig, seed, [0.0] * frames)
    params = {"frames": frames, "blocker_thickness_mm": thickness_mm, "part": "blocker",
              "blocker": assembly.parts[0].analytic}
    return Scenario("blocker", params, assembly, specs, stage_from_part(rig, 0.0),
                    truth_pixels_every)


def rotary_scenario(rig: Rig, seed: int = 0, part: str = "cylinder", step_deg: float = 0.5,
                    frames: int | None = None, truth_pixels_every: int = 30) -> Scenario:
    """A part on the rotary stage at θ_i = i·step_deg over one turn (or the first ``frames``)."""
    _positive("step_deg", step_deg)
    n_turn = max(1, int(round(360.0 / step_deg)))
    if frames is not None:
        _positive_int("frames", frames)
        n_turn = min(n_turn, frames)
    assembly = load_assembly(part, seed=seed)
    specs = _rotary_frames(rig, seed, [i * step_deg for i in range(n_turn)])
    params = {"part": part, "step_deg": step_deg, "frames": n_turn,
              "parts": [{"name": p.name, "object_id": p.object_id, "material": p.material,
                         "analytic": p.analytic} for p in assembly.parts]}
    return Scenario("rotary", params, assembly, specs, stage_from_part(rig, 0.0),
                    truth_pixels_every)


def build_scenario(name: str, rig: Rig, seed: int = 0, **options) -> Scenario:
    """Dispatch by scenario name; unknown names raise listing :data:`SCENARIOS`."""
    table = {"blocker": blocker_scenario, "calibration": calibration_scenario,
             "rotary": rotary_scenario}
    if name not in table:
        raise ScheimpflugError(f"unknown scenario {name!r} (known: {', '.join(SCENARIOS)})")
    return table[name](rig, seed=seed, **options)
