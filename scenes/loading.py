"""One entry point for ``--part``: a preset name, a mesh file or a scene file."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from scheimpflug.errors import MeshError

from .meshfile import MESH_SUFFIXES, load_mesh
from .part import Assembly
from .presets import PART_NAMES, build_preset
from .scenefile import load_scene

__all__ = ["load_part"]


def load_part(name_or_path: str | os.PathLike, *, seed: int | None = 0, units: str = "mm",
              axis_offset_mm=(0.0, 0.0), **overrides) -> Assembly:
    """The assembly to scan: a preset, a user mesh or a scene file.

    Parameters
    ----------
    name_or_path : str or os.PathLike
        A name of :data:`PART_NAMES`, or a path ending in .stl/.ply/.obj
        (a user mesh) or .toml (a scene file).
    seed : int or None, default 0
        Run seed for scene files with a ``[variation]`` table; presets and
        meshes do not depend on it.
    units : str, default "mm"
        Unit of a mesh file: "mm", "m" or "inch" (presets and scene files: only "mm").
    axis_offset_mm : (2,) array_like, default (0, 0)
        (x, y) of the rotary axis in the given geometry's frame [mm]; the
        assembly is shifted by −offset.
    **overrides
        Preset generator parameters (e.g. ``height_mm=50``); for a mesh file
        ``material`` and ``name``; none for a scene file.

    Returns
    -------
    Assembly
        The parts in the part frame (rotary axis on ``z``).

    Raises
    ------
    MeshError
        Unknown name, bad file, bad parameter, units or overrides where they
        do not apply, or an ``axis_offset_mm`` that is not two finite numbers.
    """
    key = str(name_or_path)
    suffix = Path(key).suffix.lower()
    if key in PART_NAMES:
        if units != "mm":
            raise MeshError(f"units = {units!r}: preset parts are in mm; units apply to mesh files")
        asm = build_preset(key, **overrides)
    elif suffix in MESH_SUFFIXES:
        unknown = sorted(set(overrides) - {"material", "name"})
        if unknown:
            raise MeshError(f"{key}: option {unknown[0]!r} does not apply to a mesh file")
        part = load_mesh(key, units=units, axis_offset_mm=(0.0, 0.0), **overrides)
        asm = Assembly(name=part.name, parts=(part,))
    elif suffix == ".toml":
        if overrides or units != "mm":
            raise MeshError(f"{key}: parameters and units go inside a scene file, not on the command line")
        asm = load_scene(key, seed=seed)
    else:
        raise MeshError(f"unknown part {key!r} (known: {', '.join(PART_NAMES)}; "
                        "or a mesh file .stl/.ply/.obj, or a scene file .toml)")
    return _shift(asm, axis_offset_mm)


def _shift(asm: Assembly, axis_offset_mm) -> Assembly:
    off = np.asarray(axis_offset_mm, dtype=float).reshape(-1)
    if off.shape != (2,) or not np.all(np.isfinite(off)):
        raise MeshError(f"axis_offset_mm must be two finite numbers (x, y), got {axis_offset_mm!r}")
    if not np.any(off):
        return asm
    m = np.eye(4)
    m[:2, 3] = -off
    return asm.transformed(m)
