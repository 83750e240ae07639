"""Scheimpflug light-sheet profiler: the instrument's own pipeline.

Layers (ARCHITECTURE.md): :mod:`scheimpflug.model` (rig, hinge geometry,
camera, design), :mod:`scheimpflug.io` (frame folders, PLY, atomic files), the
core modules here (:mod:`.stripe`, :mod:`.calibration`, :mod:`.axis`,
:mod:`.reconstruct`, :mod:`.scoring`, :mod:`.fitting`, :mod:`.budget`,
:mod:`.errors`, :mod:`.callbacks`) and the application
(:mod:`scheimpflug.app`: command line, demo, reports).  Pure numpy/scipy/OpenCV;
the twin (:mod:`sim`) and the parts (:mod:`scenes`) are separate packages.

The names in ``__all__`` are imported on first use, so ``import scheimpflug``
stays cheap.
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

_EXPORTS = {
    "Calibration": "scheimpflug.calibration",
    "CalibrationError": "scheimpflug.errors",
    "FrameError": "scheimpflug.errors",
    "MeshError": "scheimpflug.errors",
    "PointCloud": "scheimpflug.reconstruct",
    "PointToMesh": "scheimpflug.scoring",
    "RenderError": "scheimpflug.errors",
    "Rig": "scheimpflug.model.rig",
    "RigError": "scheimpflug.errors",
    "ScheimpflugError": "scheimpflug.errors",
    "calibrate_folder": "scheimpflug.calibration",
    "design_report": "scheimpflug.model.design",
    "distance_stats": "scheimpflug.scoring",
    "extract_folder": "scheimpflug.reconstruct",
    "extract_stripes": "scheimpflug.stripe",
    "hinge_geometry": "scheimpflug.model.hinge",
    "load_preset": "scheimpflug.model.rig",
    "load_rig": "scheimpflug.model.rig",
    "locate_axis": "scheimpflug.axis",
    "open_frame_folder": "scheimpflug.io.frames",
    "pixel_from_stage": "scheimpflug.model.hinge",
    "read_mesh": "scheimpflug.io.ply",
    "read_point_cloud": "scheimpflug.io.ply",
    "reconstruct_profiles": "scheimpflug.reconstruct",
    "stage_from_pixel": "scheimpflug.model.hinge",
    "write_point_cloud": "scheimpflug.io.ply",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    """Import an exported name from its module on first use (PEP 562)."""
    if name in _EXPORTS:
        value = getattr(importlib.import_module(_EXPORTS[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'scheimpflug' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
