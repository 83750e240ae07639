"""The digital twin: a Scheimpflug light-sheet profiler rendered with Mitsuba 3 / Dr.Jit.

Modules: :mod:`.variant` (Mitsuba variant and LLVM detection), :mod:`.scene`
(parts as a Mitsuba scene, ray queries), :mod:`.materials`, :mod:`.lightsheet`
(the Gaussian light sheet), :mod:`.render` (light-tracing renderer onto the
tilted thin-lens camera), :mod:`.sensor` (electrons → DN), :mod:`.stages`,
:mod:`.truth` (exact ground truth from geometry), :mod:`.scenarios` and
:mod:`.writer` (the frame folder); the camera chain of real scanners
(:mod:`.chain`: glare, mosaic, blooming, tone, JPEG); the physical light beyond the ideal twin:
:mod:`.lens` (the light tracer's camera connection), :mod:`.transport`
(inter-reflections), :mod:`.subsurface` (random walks in translucent
materials), :mod:`.speckle` (speckle attached to the lit surface).

Entry points: :func:`render_folder` (a named scenario of a rig into a frame
folder: the library's ``render``), :func:`render_scenario` with a
:class:`MitsubaTwin`, :func:`build_scenario`, and the parts of the twin
(:class:`Renderer`, :class:`SensorModel`, :func:`stripe_truth` …).

The names in ``__all__`` are imported on first use (PEP 562), so ``import sim``
stays cheap and imports neither Mitsuba nor Dr.Jit.
"""

from __future__ import annotations

import importlib
import os

# numba's OpenMP workers otherwise spin after each parallel kernel and steal the
# cores from Dr.Jit's render threads and the PNG encoder (measured: 157 → 138 ms
# per full frame, benchmarks/RESULTS.md).  Set before numba starts OpenMP.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

_EXPORTS = {
    "CameraPass": "sim.camera_pass",
    "CameraSettings": "sim.camera_pass",
    "ChainModel": "sim.chain",
    "FrameSpec": "sim.scenarios",
    "LightSheet": "sim.lightsheet",
    "MaterialSettings": "sim.materials",
    "MitsubaTwin": "sim.writer",
    "RenderSettings": "sim.render",
    "RenderStats": "sim.writer",
    "Renderer": "sim.render",
    "SCENARIOS": "sim.scenarios",
    "Scenario": "sim.scenarios",
    "SensorModel": "sim.sensor",
    "SimScene": "sim.scene",
    "StripeTruth": "sim.truth",
    "Twin": "sim.writer",
    "apply_chain": "sim.chain",
    "apply_sensor": "sim.sensor",
    "build_scenario": "sim.scenarios",
    "frame_rng": "sim.sensor",
    "frame_seed": "sim.scenarios",
    "light_sheet": "sim.lightsheet",
    "pixel_truth": "sim.truth",
    "read_png": "sim.writer",
    "render_folder": "sim.writer",
    "render_scenario": "sim.writer",
    "rig_from_plate": "sim.stages",
    "rig_from_stage": "sim.stages",
    "rig_truth": "sim.truth",
    "select_variant": "sim.variant",
    "stage_from_part": "sim.stages",
    "stripe_truth": "sim.truth",
    "target_scenario": "sim.target",
    "write_png": "sim.writer",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    """Import an exported name from its module on first use (PEP 562)."""
    if name in _EXPORTS:
        value = getattr(importlib.import_module(_EXPORTS[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'sim' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
