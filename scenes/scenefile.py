"""Scene files (TOML): parts with poses, materials, parameters and seeded variations.

Format (all lengths in mm, angles in degrees; see ``scenes/examples/``)::

    name = "pile-variations"     # optional, default: the file name
    seed = 0                     # optional base seed, combined with the run's --seed

    [[parts]]                    # one table per part, object ids 1, 2, ... in this order
    name = "ring"                # unique; referenced by `on` and [variation.<name>]
    preset = "knurled-ring"      # a preset name (scenes.PART_NAMES) ...
    # mesh = "bracket.stl"       # ... or a mesh file, relative to this scene file
    # units = "mm"               # mesh files only: "mm", "m" or "inch"
    # axis_offset_mm = [0, 0]    # mesh files only: (x, y) of the rotary axis in the file
    position_mm = [-6, -4, 0]    # where the part's origin goes (default [0, 0, 0])
    yaw_deg = 0.0                # turn about the part's own z axis, before the move
    on = "box"                   # optional: z is measured from the top of that (earlier) part
    material = "knurled-metal"   # optional: override the preset's material tag
    seed = 0                     # optional: per-part offset of the random stream
    [parts.params]               # generator parameters overriding the preset's
    height_mm = 15.0             # (pile: ring = {...}, box = {...}, tape = {...})

    [variation.ring]             # ranges drawn from the seed for part "ring"
    height_mm = [12.0, 18.0]                     # uniform in [lo, hi]
    pattern = { choices = ["straight", "diamond"] }
    position_mm = [[-10, 10], [-10, 10], 0]      # per axis: fixed or [lo, hi]
    yaw_deg = [0, 360]
    "ring.height_mm" = [12, 18]                  # dotted: nested params (pile)

Each part draws from its own stream, ``numpy.random.default_rng([file seed,
run seed, crc32(part name), part seed])``, keys in sorted order: the same file
and seed give bit-identical meshes, and editing one part's variation does not
change the others.  Variation values replace ``position_mm``/``yaw_deg`` or
the matching ``params``.  Collisions between varied parts are not checked.
"""

from __future__ import annotations

import math
import os
import tomllib
import zlib
from dataclasses import replace
from pathlib import Path

import numpy as np

from scheimpflug.errors import MeshError

from .meshfile import load_mesh
from .part import Assembly, Part
from .presets import PART_NAMES, build_preset

__all__ = ["load_scene"]

_PART_KEYS = {"name", "preset", "mesh", "units", "axis_offset_mm", "position_mm", "yaw_deg",
              "on", "material", "seed", "params"}
_TOP_KEYS = {"name", "seed", "parts", "variation"}


def _fail(path: Path, msg: str) -> MeshError:
    return MeshError(f"{path}: {msg}")


def _read_toml(path: Path) -> dict:
    if not path.is_file():
        raise MeshError(f"{path}: no such scene file")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise _fail(path, f"not a valid TOML scene ({exc})") from None
    unknown = sorted(set(data) - _TOP_KEYS)
    if unknown:
        raise _fail(path, f"unknown key {unknown[0]!r} (known: {', '.join(sorted(_TOP_KEYS))})")
    if not isinstance(data.get("parts"), list) or not data["parts"]:
        raise _fail(path, "needs at least one [[parts]] table")
    return data


def _seed(path: Path, where: str, value) -> int:
    if not isinstance(value, int) or isinstance(value, bool) or value < 0:
        raise _fail(path, f"{where} = {value!r}: must be an integer >= 0")
    return value


def _draw(path: Path, where: str, spec, rng: np.random.Generator):
    """One value from a variation spec: [lo, hi], {choices = [...]}, or a fixed value."""
    if isinstance(spec, dict):
        choices = spec.get("choices")
        if set(spec) != {"choices"} or not isinstance(choices, list) or not choices:
            raise _fail(path, f"{where}: a table must be {{ choices = [...] }}")
        return choices[int(rng.integers(len(choices)))]
    if isinstance(spec, list) and len(spec) == 2 and all(_is_num(v) for v in spec):
        lo, hi = float(spec[0]), float(spec[1])
        if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
            raise _fail(path, f"{where} = {spec!r}: need finite lo <= hi")
        return float(rng.uniform(lo, hi))
    if _is_num(spec) or isinstance(spec, str):
        return spec
    raise _fail(path, f"{where} = {spec!r}: expected [lo, hi], {{ choices = [...] }} or a value")


def _is_num(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _vary(path: Path, part: dict, variation: dict, rng: np.random.Generator) -> dict:
    part = dict(part, params=_nested_copy(part.get("params", {})))
    for key in sorted(variation):
        where = f"variation.{part['name']}.{key}"
        if key == "position_mm":
            spec = variation[key]
            if not isinstance(spec, list) or len(spec) != 3:
                raise _fail(path, f"{where}: must be a list of 3 entries (value or [lo, hi])")
            part[key] = [_draw(path, f"{where}[{i}]", s, rng) for i, s in enumerate(spec)]
        elif key == "yaw_deg":
            part[key] = _draw(path, where, variation[key], rng)
        else:
            *outer, leaf = key.split(".")
            target = part["params"]
            for k in outer:
                target = target.setdefault(k, {})
            target[leaf] = _draw(path, where, variation[key], rng)
    return part


def _nested_copy(d: dict) -> dict:
    return {k: _nested_copy(v) if isinstance(v, dict) else v for k, v in d.items()}


def _check_part(path: Path, i: int, part) -> str:
    if not isinstance(part, dict):
        raise _fail(path, f"parts[{i}] must be a table")
    unknown = sorted(set(part) - _PART_KEYS)
    if unknown:
        raise _fail(path, f"parts[{i}]: unknown key {unknown[0]!r} (known: {', '.join(sorted(_PART_KEYS))})")
    if ("preset" in part) == ("mesh" in part):
        raise _fail(path, f"parts[{i}]: give exactly one of 'preset' or 'mesh'")
    if "preset" in part and part["preset"] not in PART_NAMES:
        raise _fail(path, f"parts[{i}]: unknown preset {part['preset']!r} (known: {', '.join(PART_NAMES)})")
    name = part.get("name", part.get("preset") or Path(str(part.get("mesh"))).stem)
    if not isinstance(name, str) or not name:
        raise _fail(path, f"parts[{i}]: name must be a non-empty string")
    return name


def _build(path: Path, part: dict) -> list[Part]:
    extra = {"material": part["material"]} if "material" in part else {}
    if "preset" in part:
        if "units" in part or "axis_offset_mm" in part:
            raise _fail(path, f"part {part['name']!r}: units/axis_offset_mm apply to mesh files only")
        params = dict(part.get("params", {}))
        if part["preset"] != "pile":
            params = {**params, **extra}
        parts = list(build_preset(part["preset"], **params).parts)
        if part["preset"] == "pile" and extra:
            parts = [replace(p, material=extra["material"]) for p in parts]
        return parts
    if part.get("params"):
        raise _fail(path, f"part {part['name']!r}: params apply to presets only")
    mesh_path = (path.parent / str(part["mesh"])).resolve()
    return [load_mesh(mesh_path, units=part.get("units", "mm"),
                      axis_offset_mm=part.get("axis_offset_mm", (0.0, 0.0)), **extra)]


def _pose(path: Path, part: dict, built: dict) -> tuple[list, float]:
    pos = part.get("position_mm", [0.0, 0.0, 0.0])
    if not isinstance(pos, list) or len(pos) != 3 or not all(_is_num(v) for v in pos):
        raise _fail(path, f"part {part['name']!r}: position_mm must be [x, y, z] numbers")
    yaw = part.get("yaw_deg", 0.0)
    if not _is_num(yaw):
        raise _fail(path, f"part {part['name']!r}: yaw_deg must be a number")
    pos = [float(v) for v in pos]
    if "on" in part:
        if part["on"] not in built:
            raise _fail(path, f"part {part['name']!r}: on = {part['on']!r} is not an earlier part")
        pos[2] += max(float(p.mesh.bounds[1, 2]) for p in built[part["on"]])
    return pos, float(yaw)


def load_scene(path: str | os.PathLike, seed: int | None = None) -> Assembly:
    """Build the :class:`Assembly` described by a scene file (format in the module doc).

    Parameters
    ----------
    path : str or os.PathLike
        Scene TOML file; mesh files in it are relative to its folder.
    seed : int or None, optional
        Run seed (≥ 0) combined with the file's ``seed``; None → 0.

    Returns
    -------
    Assembly
        The parts posed in the part frame, object ids 1, 2, … in file order.

    Raises
    ------
    MeshError
        Unreadable TOML, unknown keys/presets/parts, non-unique part names,
        bad seeds or ranges, bad mesh files.
    """
    path = Path(path)
    data = _read_toml(path)
    base = _seed(path, "seed", data.get("seed", 0))
    run = _seed(path, "run seed", 0 if seed is None else seed)
    variation = data.get("variation", {})
    names = [_check_part(path, i, p) for i, p in enumerate(data["parts"])]
    if len(set(names)) != len(names):
        raise _fail(path, "part names must be unique (set 'name' in each [[parts]])")
    missing = sorted(set(variation) - set(names))
    if missing:
        raise _fail(path, f"[variation.{missing[0]}] names no part (parts: {', '.join(names)})")
    built: dict[str, list[Part]] = {}
    for name, raw in zip(names, data["parts"]):
        part = dict(raw, name=name)
        pseed = _seed(path, f"part {name!r} seed", part.get("seed", 0))
        rng = np.random.default_rng([base, run, zlib.crc32(name.encode()), pseed])
        part = _vary(path, part, variation.get(name, {}), rng)
        pos, yaw = _pose(path, part, built)
        try:
            group = _build(path, part)
        except MeshError as exc:
            msg = str(exc)
            raise (exc if msg.startswith(str(path)) else _fail(path, f"part {name!r}: {msg}")) from None
        built[name] = [p.posed(pos, yaw) for p in group]
    return _assemble(str(data.get("name", path.stem)), built)


def _assemble(name: str, built: dict[str, list[Part]]) -> Assembly:
    parts = []
    for pname, group in built.items():
        for p in group:
            label = pname if len(group) == 1 else f"{pname}.{p.name}"
            parts.append(replace(p, name=label, object_id=len(parts) + 1))
    return Assembly(name=name, parts=tuple(parts))
