"""A rig file by the instrument's parts: ``[camera]``, ``[laser] plane``, ``[turntable]``.

A rig file may describe a camera-and-sheet instrument by its calibration instead of
the Scheimpflug keys (docs/reference/interface.md, "Rig file by parts"), in one
*instrument frame* [mm] (:mod:`scheimpflug.model.instrument`)::

    [camera]
    preset = "rpi-v2-binned"      # optional: pitch, f-number and frame size of a named camera
    fx_px = 1254.7                # focal lengths [px]
    fy_px = 1254.9
    cx_px = 819.5                 # principal point [px], 0-based pixel centres
    cy_px = 615.5
    distortion = [k1, k2, p1, p2, k3]   # OpenCV's order: 0, 4, 5, 8, 12 or 14 terms [-]
    width_px = 1640               # frame size [px]
    height_px = 1232
    pixel_pitch_um = 2.24         # [µm]
    f_number = 2.0                # [-]
    focus = "sheet"               # the sheet point the image centre sees, or a distance [mm]
    instrument_from_camera = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]  # 4 × 4 [mm]

    [laser]
    plane = { normal = [nx, ny, nz], distance_mm = 120.0 }   # or { normal = [...], point_mm = [x, y, z] }
    emitter_mm = [x, y, z]        # optional: the laser's position [mm]
    wavelength_nm = 650.0         # and any other [laser] key but those the plane replaces

    [turntable]                   # optional
    axis_point_mm = [x, y, z]     # the table's centre, on its top [mm]
    axis_direction = [ux, uy, uz] # unit upward direction of the axis [-]
    radius_mm = 70.0              # optional: the table's disc, its top the table plane (0 = none) [mm]
    thickness_mm = 10.0           # optional: the disc's thickness below its top [mm]
    material = "cardboard"        # optional: the disc's material (a tag of scenes.MATERIALS)

The file's other tables (``[lens]``, ``[sensor]``, ``[stage]``, ``[environment]``,
``[twin]``, ``[chain]``) give the keys the parts do not: noise, error models, light,
the camera chain.  The keys the parts replace (:data:`REPLACED_KEYS`: the lens, the
sensor's geometry, d and tan φ, the stage's positions) may not be given too.  The
rig is :func:`scheimpflug.model.instrument.rig_from_instrument` of these parts,
exactly — the same :class:`~scheimpflug.model.rig.Rig` as the Scheimpflug keys
:func:`~scheimpflug.model.instrument.rig_file_text` writes for it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from scheimpflug.errors import RigError
from scheimpflug.model.assembly import Rig, housing_lines, rig_to_dict, toml_value
from scheimpflug.model.instrument import (
    Camera,
    Instrument,
    Sheet,
    Turntable,
    camera_preset,
    rig_frame,
    rig_from_instrument,
)
from scheimpflug.model.tables import Laser

__all__ = [
    "CAMERA_KEYS",
    "LASER_PART_KEYS",
    "PART_TABLES",
    "REPLACED_KEYS",
    "TURNTABLE_KEYS",
    "instrument_from_tables",
    "is_by_parts",
    "rig_from_parts",
    "rig_parts_text",
]

#: The tables only a rig file by parts has.
PART_TABLES = ("camera", "turntable")
#: The keys of ``[camera]``.
CAMERA_KEYS = ("preset", "fx_px", "fy_px", "cx_px", "cy_px", "distortion", "width_px", "height_px",
               "pixel_pitch_um", "f_number", "focus", "instrument_from_camera")
#: The keys of ``[turntable]``.
TURNTABLE_KEYS = ("axis_point_mm", "axis_direction", "radius_mm", "thickness_mm", "material")
#: The keys of ``[laser]`` only a rig file by parts has.
LASER_PART_KEYS = ("plane", "emitter_mm")
#: The ``[laser]`` keys of the sheet's light (:class:`~scheimpflug.model.instrument.Sheet`).
_LIGHT_KEYS = ("fan_angle_deg", "wavelength_nm", "waist_um", "divergence_mrad", "power_mw")
#: The Scheimpflug keys the parts set, ``{table: (keys, what replaces them)}``: a rig file by
#: parts may not give them (:func:`rig_from_parts`).
REPLACED_KEYS: dict[str, tuple[tuple[str, ...], str]] = {
    "lens": (("focal_length_mm", "f_number", "k1", "k2", "k3", "p1", "p2", "aspect_ratio"),
             "[camera] (fx_px, fy_px, distortion, pixel_pitch_um, f_number, focus)"),
    "sensor": (("pixel_pitch_um", "columns", "rows", "hinge_column", "axis_row", "roll_deg", "tilt_error_deg",
                "offset_u_px", "offset_v_px", "offset_normal_um", "image_distance_mm"),
               "[camera] (fx_px, cx_px, cy_px, width_px, height_px, pixel_pitch_um, instrument_from_camera)"),
    "laser": (("scheimpflug_distance_mm", "tan_phi", "origin_x_mm", "waist_distance_mm"),
              "[laser] plane and emitter_mm (the waist at the turntable's axis)"),
    "stage": (("d0_mm", "axis_mm", "calibration_table_z_mm", "calibration_plate_height_mm", "rotary_table_z_mm",
               "axis_tilt_deg", "axis_tilt_azimuth_deg", "axis_offset_mm", "table_radius_mm", "table_thickness_mm",
               "table_material"),
              "[turntable] (axis_point_mm, axis_direction, radius_mm, thickness_mm, material; without it the axis "
              "at the focus)"),
}
#: A rig key no calibration gives → where the file by parts writes it.
_UNKNOWN_IN_PARTS = {"sensor.pixel_pitch_um": "camera.pixel_pitch_um", "lens.f_number": "camera.f_number",
                     "stage.table_radius_mm": "turntable.radius_mm",
                     "stage.table_thickness_mm": "turntable.thickness_mm", "stage.table_material": "turntable.material"}


def is_by_parts(data: Mapping[str, Any]) -> bool:
    """Whether rig tables describe the instrument by its parts.

    Parameters
    ----------
    data : Mapping[str, Any]
        ``{table: {key: value}}`` of a rig file.

    Returns
    -------
    bool
        True when it has ``[camera]``, ``[turntable]`` or a ``[laser] plane``.
    """
    laser = data.get("laser")
    return any(t in data for t in PART_TABLES) or (isinstance(laser, Mapping) and "plane" in laser)


# ---------------------------------------------------------------- reading values


def _number(table: str, key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise RigError(f"[{table}] {key} = {value!r:.40}: must be a finite number")
    return float(value)


def _integer(table: str, key: str, value: Any) -> int:
    x = _number(table, key, value)
    if not x.is_integer() or x < 1:
        raise RigError(f"[{table}] {key} = {value!r}: must be a whole number of pixels ≥ 1")
    return int(x)


def _vector(table: str, key: str, value: Any, size: int = 3) -> np.ndarray:
    if isinstance(value, (str, bytes, Mapping)) or not hasattr(value, "__len__") or len(value) != size:
        raise RigError(f"[{table}] {key} = {value!r:.60}: must be {size} numbers")
    return np.array([_number(table, key, v) for v in value], np.float64)


def _matrix(table: str, key: str, value: Any) -> np.ndarray:
    if isinstance(value, (str, bytes, Mapping)) or not hasattr(value, "__len__") or len(value) != 4:
        raise RigError(f"[{table}] {key}: must be a 4 × 4 matrix (4 rows of 4 numbers) [mm]")
    return np.vstack([_vector(table, key, row, 4) for row in value])


def _table(data: Mapping[str, Any], name: str, known) -> dict:
    values = data.get(name, {})
    if not isinstance(values, Mapping):
        raise RigError(f"[{name}] must be a table of keys, got {type(values).__name__}")
    unknown = sorted(set(values) - set(known))
    if unknown:
        raise RigError(f"[{name}] unknown key {unknown[0]!r} (known keys: {', '.join(known)})")
    return dict(values)


def _check_no_replaced(data: Mapping[str, Any]) -> None:
    for table, (keys, by) in REPLACED_KEYS.items():
        values = data.get(table, {})
        given = [k for k in keys if isinstance(values, Mapping) and k in values]
        if given:
            raise RigError(f"[{table}] {given[0]} and {by}: a rig file by parts gives the instrument by its "
                           f"parts, not by the Scheimpflug keys they replace; leave [{table}] {given[0]} out "
                           "(or write the Scheimpflug form without [camera], [laser] plane, [turntable])")


def _camera(data: Mapping[str, Any]) -> Camera:
    c = _table(data, "camera", CAMERA_KEYS)
    if "camera" not in data:
        raise RigError("a rig file by parts ([laser] plane or [turntable]) needs a [camera] table")
    extra: dict[str, Any] = {}
    if "preset" in c:
        if not isinstance(c["preset"], str):
            raise RigError(f"[camera] preset = {c['preset']!r:.40}: must be a camera preset's name")
        p = camera_preset(c["preset"])
        extra = {"pixel_pitch_um": p.pixel_pitch_um, "f_number": p.f_number, "width_px": p.width_px,
                 "height_px": p.height_px}
    needed = ("fx_px", "fy_px", "cx_px", "cy_px", "width_px", "height_px")
    missing = [k for k in needed if k not in c and k not in extra]
    if missing:
        raise RigError(f"[camera] {missing[0]} is missing (a camera needs fx_px, fy_px, cx_px, cy_px, width_px, "
                       "height_px; a preset gives the frame size)")
    kw = {**extra, **{k: c[k] for k in ("pixel_pitch_um", "f_number", "width_px", "height_px") if k in c}}
    for k in ("pixel_pitch_um", "f_number"):
        if k in kw and not _number("camera", k, kw[k]) > 0:
            raise RigError(f"[camera] {k} = {kw[k]!r}: must be > 0")
    distortion = c.get("distortion", [])
    if isinstance(distortion, (str, bytes, Mapping)) or not hasattr(distortion, "__len__"):
        raise RigError(f"[camera] distortion = {distortion!r:.40}: must be a list of OpenCV's coefficients")
    focus = c.get("focus", "sheet")
    if focus != "sheet" and not (isinstance(focus, (int, float)) and not isinstance(focus, bool) and focus > 0):
        raise RigError(f"[camera] focus = {focus!r:.40}: must be \"sheet\" or a distance > 0 [mm]")
    return Camera(fx_px=_number("camera", "fx_px", c["fx_px"]), fy_px=_number("camera", "fy_px", c["fy_px"]),
                  cx_px=_number("camera", "cx_px", c["cx_px"]), cy_px=_number("camera", "cy_px", c["cy_px"]),
                  width_px=_integer("camera", "width_px", kw["width_px"]),
                  height_px=_integer("camera", "height_px", kw["height_px"]),
                  distortion=tuple(_number("camera", "distortion", x) for x in distortion),
                  **{k: float(kw[k]) for k in ("pixel_pitch_um", "f_number") if k in kw},
                  focus_distance_mm=None if focus == "sheet" else float(focus),
                  instrument_from_camera=_matrix("camera", "instrument_from_camera", c["instrument_from_camera"])
                  if "instrument_from_camera" in c else np.eye(4))


def _sheet(laser: Mapping[str, Any]) -> Sheet:
    plane = laser.get("plane")
    if not isinstance(plane, Mapping):
        raise RigError("[laser] plane is missing or not a table: a rig file by parts gives the sheet as "
                       "plane = { normal = [nx, ny, nz], distance_mm = D } or { normal = [...], point_mm = [x, y, z] }")
    known = ("normal", "distance_mm", "point_mm")
    unknown = sorted(set(plane) - set(known))
    if unknown or "normal" not in plane or ("distance_mm" in plane) == ("point_mm" in plane):
        raise RigError(f"[laser] plane = {dict(plane)!r:.80}: needs normal and one of distance_mm, point_mm")
    normal = _vector("laser", "plane.normal", plane["normal"])
    distance = (_number("laser", "plane.distance_mm", plane["distance_mm"]) if "distance_mm" in plane
                else float(normal @ _vector("laser", "plane.point_mm", plane["point_mm"])))
    emitter = _vector("laser", "emitter_mm", laser["emitter_mm"]) if "emitter_mm" in laser else None
    default = Laser()
    light = {k: _number("laser", k, laser.get(k, getattr(default, k))) for k in _LIGHT_KEYS}
    return Sheet(normal, distance, emitter, **light)


def _turntable(data: Mapping[str, Any]) -> Turntable | None:
    if "turntable" not in data:
        return None
    t = _table(data, "turntable", TURNTABLE_KEYS)
    missing = [k for k in TURNTABLE_KEYS[:2] if k not in t]
    if missing:
        raise RigError(f"[turntable] {missing[0]} is missing (a turntable needs axis_point_mm and axis_direction)")
    default = Turntable(np.zeros(3), np.zeros(3))
    material = t.get("material", default.material)
    if not isinstance(material, str):
        raise RigError(f"[turntable] material = {material!r:.40}: must be a string (a tag of scenes.MATERIALS)")
    return Turntable(_vector("turntable", "axis_point_mm", t["axis_point_mm"]),
                     _vector("turntable", "axis_direction", t["axis_direction"]),
                     _number("turntable", "radius_mm", t.get("radius_mm", default.radius_mm)),
                     _number("turntable", "thickness_mm", t.get("thickness_mm", default.thickness_mm)), material)


def instrument_from_tables(data: Mapping[str, Any]) -> tuple[Instrument, dict[str, dict[str, Any]]]:
    """The instrument of a rig file by parts, and the file's other keys.

    Parameters
    ----------
    data : Mapping[str, Any]
        ``{table: {key: value}}`` of a rig file by parts (module docstring).

    Returns
    -------
    Instrument
        Camera, sheet and turntable (none without ``[turntable]``).
    dict
        The other tables' keys (``[laser]`` without its parts' keys and light), the base
        of :func:`~scheimpflug.model.instrument.rig_from_instrument`.

    Raises
    ------
    RigError
        A Scheimpflug key the parts replace (both named), a missing ``[camera]`` or
        ``[laser] plane``, an unknown key of ``[camera]`` or ``[turntable]``, a value of
        the wrong kind, an unknown camera preset.
    """
    _check_no_replaced(data)
    laser = data.get("laser", {})
    if not isinstance(laser, Mapping):
        raise RigError(f"[laser] must be a table of keys, got {type(laser).__name__}")
    inst = Instrument(_camera(data), _sheet(laser), _turntable(data))
    rest = {name: values for name, values in data.items() if name not in PART_TABLES and name != "laser"}
    rest["laser"] = {k: v for k, v in laser.items() if k not in LASER_PART_KEYS and k not in _LIGHT_KEYS}
    for name, values in rest.items():
        if not isinstance(values, Mapping):
            raise RigError(f"[{name}] must be a table of keys, got {type(values).__name__}")
    return inst, rest


def rig_from_parts(data: Mapping[str, Any]) -> Rig:
    """The rig of a rig file by parts (module docstring).

    Parameters
    ----------
    data : Mapping[str, Any]
        ``{table: {key: value}}`` of the file.

    Returns
    -------
    Rig
        :func:`~scheimpflug.model.instrument.rig_from_instrument` of its parts, the file's
        other keys kept; ``[sensor] exposure_ms`` 1 ms unless given (nothing derived).

    Raises
    ------
    RigError
        From :func:`instrument_from_tables` and
        :func:`~scheimpflug.model.instrument.rig_from_instrument` (a singular camera matrix,
        a zero or non-unit normal, a sheet behind the camera or never in view …).
    """
    inst, rest = instrument_from_tables(data)
    exposure = rest.get("sensor", {}).get("exposure_ms", 1.0)
    return rig_from_instrument(inst, rest, exposure_ms=exposure)


# ---------------------------------------------------------------- writing


def _lines(table: str, values: Mapping[str, Any], unknown) -> list[str]:
    out = [f"[{table}]"]
    for k, v in values.items():
        note = "  # unknown: a default, ready for identification" if f"{table}.{k}" in unknown else ""
        out.append(f"{k} = {toml_value(v)}{note}")
    return out + [""]


def rig_parts_text(rig: Rig, inst: Instrument, source: str) -> str:
    """The rig file by parts of an instrument (module docstring): the same rig as its Scheimpflug form.

    Parameters
    ----------
    rig : Rig
        :func:`~scheimpflug.model.instrument.rig_from_instrument` of ``inst`` (its other keys:
        noise, error models, light, chain).
    inst : Instrument
        The instrument.
    source : str
        Where it came from (a file name), for the header.

    Returns
    -------
    str
        TOML text :func:`scheimpflug.model.rig.load_rig` reads back into ``rig``.
    """
    cam, sh = inst.camera, inst.sheet
    unknown = {_UNKNOWN_IN_PARTS.get(k, k) for k in inst.unknown}
    camera = {"fx_px": cam.fx_px, "fy_px": cam.fy_px, "cx_px": cam.cx_px, "cy_px": cam.cy_px,
              "distortion": [float(x) for x in cam.distortion], "width_px": int(cam.width_px),
              "height_px": int(cam.height_px), "pixel_pitch_um": cam.pixel_pitch_um, "f_number": cam.f_number,
              "focus": "sheet" if cam.focus_distance_mm is None else cam.focus_distance_mm,
              "instrument_from_camera": np.asarray(cam.instrument_from_camera, np.float64).tolist()}
    tables = rig_to_dict(rig)
    laser = {"plane": None, **({} if sh.emitter_mm is None else {"emitter_mm": sh.emitter_mm}),
             **{k: v for k, v in tables["laser"].items() if k not in REPLACED_KEYS["laser"][0]}}
    normal = ", ".join(repr(float(x)) for x in np.asarray(sh.normal, np.float64))
    lines = _lines("camera", camera, unknown)
    body = _lines("laser", laser, unknown)
    body[1] = f"plane = {{ normal = [{normal}], distance_mm = {float(sh.distance_mm)!r} }}"
    lines += body
    if inst.turntable is not None:
        tt = inst.turntable
        lines += _lines("turntable", {"axis_point_mm": tt.axis_point_mm, "axis_direction": tt.axis_direction,
                                      "radius_mm": tt.radius_mm, "thickness_mm": tt.thickness_mm,
                                      "material": tt.material}, unknown)
    for name, values in tables.items():
        if name == "housing":
            lines += housing_lines(values["board"])
            continue
        if name == "laser":
            continue
        kept = {k: v for k, v in values.items() if k not in REPLACED_KEYS.get(name, ((), ""))[0]}
        if kept:
            lines += _lines(name, kept, unknown)
    frame = rig_frame(inst)
    rows = "\n".join("#   " + "  ".join(f"{x: .12g}" for x in r) for r in frame.rig_from_instrument)
    head = (f"# Rig of the instrument calibrated in {source} (scheimpflug rig from-calibration --form parts).\n"
            "# By its parts (docs/reference/interface.md): the camera as calibrated, the laser plane, the "
            "turntable,\n# in the instrument frame (the calibration's camera frame) [mm]; rig_from_instrument:\n"
            f"{rows}\n# Unknown (defaults written, ready for identification): {', '.join(inst.unknown) or 'none'}.\n\n")
    return head + "\n".join(lines)
