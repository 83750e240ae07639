"""Every rig key's physical range, the checks of a whole rig, and the reading of one key's value.

:data:`KEY_RANGES` holds one range per key of the rig file's tables
(:mod:`scheimpflug.model.tables`); :func:`validate_rig` refuses a value outside it,
or a set of values that cannot be a rig (the relations between keys), with a
:class:`~scheimpflug.errors.RigError` naming the key; :func:`table_from_values`
reads one table of a rig file into its dataclass.  All are importable from
:mod:`scheimpflug.model.rig` too.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from scheimpflug.errors import RigError
from scheimpflug.model.chain import CHAIN_KEY_RANGES, validate_chain
from scheimpflug.model.tables import SPECKLE_MODELS, TABLE_MATERIALS, TABLES, Laser, Lens, Sensor, Stage, Twin

if TYPE_CHECKING:
    from scheimpflug.model.assembly import Rig

__all__ = [
    "KEY_RANGES",
    "MAX_TILT_DEG",
    "key_in_range",
    "table_from_values",
    "validate_rig",
]

KEY_RANGES: dict[str, dict[str, str]] = {
    "lens": {"focal_length_mm": "[0.5, 5000]", "f_number": "[0.5, 256]", "k1": "[-10, 10]",
             "k2": "[-10, 10]", "k3": "[-100, 100]", "p1": "[-1, 1]", "p2": "[-1, 1]",
             "aspect_ratio": "[0.5, 2]", "focal_length_error_mm": "[-1000, 1000]",
             "focus_error_um": "[-5000, 5000]"},
    "laser": {"scheimpflug_distance_mm": "(0, 1e5]", "tan_phi": "[-100, 100]",
              "wavelength_nm": "[0.1, 1e5]", "power_mw": "[0, 1e6]", "origin_x_mm": "[-1e5, 1e5]",
              "waist_um": "(0, 1e5]", "waist_distance_mm": "[-1e6, 1e6]",
              "divergence_mrad": "[0, 1000]", "fan_angle_deg": "(0, 180)", "fan_edge_deg": "[0, 90]",
              "speckle_contrast": "[0, 1]", "line_bow_mrad": "[-50, 50]", "fan_edge_ratio": "[0.05, 20]",
              "pointing_jitter_urad": "[0, 1e5]"},
    "sensor": {"pixel_pitch_um": "[0.1, 1000]", "columns": "[1, 65535]", "rows": "[1, 65535]",
               "hinge_column": "[-1e7, 1e7]", "axis_row": "[-1e7, 1e7]", "roll_deg": "[-180, 180]",
               "tilt_error_deg": "(-30, 30)", "offset_u_px": "[-1e5, 1e5]",
               "offset_v_px": "[-1e5, 1e5]", "offset_normal_um": "[-1e5, 1e5]", "image_distance_mm": "[0, 1e5]",
               "quantum_efficiency": "(0, 1]", "full_well_e": "(0, 1e8]", "read_noise_e": "[0, 1e6]",
               "dark_offset_dn": "[0, 65535]", "adc_bits": "[1, 16]", "gain_e_per_dn": "[0, 1e8]",
               "exposure_ms": "(0, 1e6]", "prnu_percent": "[0, 50]", "dsnu_e": "[0, 1e4]",
               "hot_pixel_fraction": "[0, 0.1]", "hot_pixel_e": "[0, 1e6]",
               "exposure_jitter_percent": "[0, 30]", "pattern_seed": "[0, 4294967295]"},
    "stage": {"d0_mm": "[-1e6, 1e6]", "axis_mm": "[-1e6, 1e6]",
              "calibration_table_z_mm": "[-1e5, 1e5]", "calibration_plate_height_mm": "(0, 1e4]",
              "rotary_table_z_mm": "[-1e5, 1e5]",
              "axis_tilt_deg": "[0, 180]", "axis_tilt_azimuth_deg": "[-360, 360]",
              "axis_offset_mm": "[-1e4, 1e4]", "table_radius_mm": "[0, 1e5]", "table_thickness_mm": "(0, 1e4]",
              "table_top_offset_mm": "[-100, 100]", "table_tilt_deg": "[0, 10]",
              "table_tilt_azimuth_deg": "[-360, 360]", "table_axis_tilt_deg": "[0, 10]",
              "table_axis_tilt_azimuth_deg": "[-360, 360]",
              "table_material": "{" + ", ".join(f'"{m}"' for m in TABLE_MATERIALS) + "}",
              "runout_um": "[0, 1e5]", "translation_scale_ppm": "[-1e4, 1e4]",
              "translation_periodic_um": "[0, 1000]", "translation_lead_mm": "(0, 100]",
              "translation_repeatability_um": "[0, 1000]", "translation_travel_mm": "(0, 1e4]",
              "straightness_lateral_um": "[-1000, 1000]", "straightness_vertical_um": "[-1000, 1000]",
              "pitch_urad": "[-1e5, 1e5]", "yaw_urad": "[-1e5, 1e5]", "rotary_eccentricity_deg": "[-1, 1]",
              "rotary_repeatability_deg": "[0, 1]", "wobble_urad": "[0, 1e5]",
              "radial_error_um": "[0, 1000]", "plate_height_error_mm": "[-10, 10]",
              "plate_flatness_um": "[-5000, 5000]", "plate_edge_break_mm": "[0, 2]",
              "plate_tilt_deg": "[-10, 10]",
              "plate_yaw_deg": "[-10, 10]"},
    "environment": {"ambient_irradiance_w_m2": "[0, 1e5]", "flood_irradiance_w_m2": "[0, 1e5]",
                    "flood_size_mm": "(0, 1e5]", "flood_distance_mm": "(0, 1e6]",
                    "flood_azimuth_deg": "[-180, 180]", "flood_elevation_deg": "[-89, 89]"},
    "twin": {"bounces": "[1, 64]", "subsurface": "{true, false}",
             "speckle_model": '{"surface", "sensor"}', "camera_spp": "[0, 4096]"},
    "chain": CHAIN_KEY_RANGES,
}
"""The physical range of every rig key, ``{table: {key: "[lo, hi]"}}`` (``(`` / ``)`` = open end).

Keys that are not numbers give their allowed values as ``{a, b}``.

One table for all keys, documented beside each key (the dataclass docstrings
and ``presets/paper.toml``).  The ranges are wide — every real profiler lies far
inside them — and narrow enough that no computation of the model over- or
underflows for values inside them; :func:`validate_rig` refuses a value outside
its range with a :class:`RigError` naming the key and the range.  Relations
between keys (``d − f·tan φ > 0``, the sensor tilt, the hinge beyond the last
column, the diffraction limit, the dark offset below full scale) are checked
besides.
"""

MAX_TILT_DEG = 85.0
"""Largest sensor tilt β = atan(f / (d − f·tan φ)) a rig may have [deg] (paper Eq. 5)."""


def _parse_range(text: str) -> tuple[float, float, bool, bool]:
    lo, hi = (float(x) for x in text[1:-1].split(","))
    return lo, hi, text[0] == "(", text[-1] == ")"


def _in_range(value: float, text: str) -> bool:
    lo, hi, lo_open, hi_open = _parse_range(text)
    return (lo < value if lo_open else lo <= value) and (value < hi if hi_open else value <= hi)


def key_in_range(table: str, key: str, value: float) -> bool:
    """Whether a value lies in a rig key's physical range (:data:`KEY_RANGES`).

    Parameters
    ----------
    table, key : str
        The rig key, e.g. ``"sensor"``, ``"pixel_pitch_um"``.
    value : float
        The value (an int of any size is compared exactly).

    Returns
    -------
    bool
        True inside the range; also True for a key without a range.
    """
    text = KEY_RANGES.get(table, {}).get(key)
    return text is None or text[0] == "{" or _in_range(value, text)


def _show(value: Any) -> str:
    """A value for an error message: its repr, cut to 40 characters."""
    text = repr(value)
    return text if len(text) <= 40 else f"{text[:20]}…({len(text)} characters)"

# ---------------------------------------------------------------- validation


def _require(cond: bool, table: str, key: str, value: Any, reason: str) -> None:
    if not cond:
        raise RigError(f"[{table}] {key} = {_show(value)}: {reason}")


def _check_fields(table: str, obj: Any) -> None:
    hints = typing.get_type_hints(type(obj))
    ranges = KEY_RANGES.get(table, {})
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        kind = hints[f.name]
        if kind == float | None:
            if value is None:
                continue
            kind = float
        if kind is bool:
            _require(isinstance(value, bool), table, f.name, value, "must be true or false")
        elif kind is str:
            _require(isinstance(value, str), table, f.name, value, "must be a string")
        elif kind is int:
            _require(isinstance(value, int) and not isinstance(value, bool), table, f.name,
                     value, "must be an integer")
        elif kind is float:
            _require(isinstance(value, (int, float)) and not isinstance(value, bool), table,
                     f.name, value, "must be a number")
            _require(not isinstance(value, float) or math.isfinite(value), table, f.name, value,
                     "must be a finite number")
        if f.name in ranges and kind in (int, float):   # exact int vs float: no overflow
            _require(_in_range(value, ranges[f.name]), table, f.name, value,
                     f"out of range: must be in {ranges[f.name]}")


def validate_rig(rig: Rig) -> None:
    """Check that a rig is possible.

    Parameters
    ----------
    rig : Rig
        The rig to check (called by ``Rig.__post_init__``).

    Raises
    ------
    RigError
        Naming the table, key, value and reason: a table of the wrong type, a
        non-integer or non-finite value, or a physically impossible one (e.g.
        f ≤ 0, d − f·tan φ ≤ 0, the hinge column inside the sensor, a
        divergence below the diffraction limit).
    """
    for name, cls in TABLES.items():
        obj = getattr(rig, name)
        if not isinstance(obj, cls):
            raise RigError(f"[{name}] must be a {cls.__name__}, got {type(obj).__name__}")
        _check_fields(name, obj)
    _validate_lens(rig.lens)
    _validate_laser(rig.laser, rig.lens)
    _validate_sensor(rig.sensor, rig.lens)
    _validate_stage(rig.stage)
    _validate_error_models(rig)
    _require(rig.environment.ambient_irradiance_w_m2 >= 0, "environment",
             "ambient_irradiance_w_m2", rig.environment.ambient_irradiance_w_m2,
             "must be >= 0")
    _validate_twin(rig.twin)
    validate_chain(rig.chain)


def _validate_twin(t: Twin) -> None:
    _require(1 <= t.bounces <= 64, "twin", "bounces", t.bounces,
             "must be 1 (first surface only) … 64")
    _require(t.speckle_model in SPECKLE_MODELS, "twin", "speckle_model", t.speckle_model,
             f"must be one of {', '.join(repr(m) for m in SPECKLE_MODELS)}")


def _validate_lens(lens: Lens) -> None:
    _require(lens.focal_length_mm > 0, "lens", "focal_length_mm", lens.focal_length_mm,
             "a thin lens needs a positive focal length")
    _require(lens.f_number > 0, "lens", "f_number", lens.f_number, "must be > 0")


def _validate_laser(laser: Laser, lens: Lens) -> None:
    f, d, t = lens.focal_length_mm, laser.scheimpflug_distance_mm, laser.tan_phi
    _require(d > 0, "laser", "scheimpflug_distance_mm", d,
             "the Scheimpflug line must lie beside the lens (d > 0)")
    _require(d - f * t > 0, "laser", "tan_phi", t,
             f"d − f·tan φ = {d - f * t:.6g} mm must be > 0: the sheet must cross the front "
             "focal plane on the laser's side of the axis (paper Eq. 5)")
    tilt = math.degrees(math.atan2(f, d - f * t))
    _require(tilt <= MAX_TILT_DEG, "laser", "tan_phi", t,
             f"the sensor tilt β = atan(f/(d − f·tan φ)) = {tilt:.4g}° must be at most "
             f"{MAX_TILT_DEG:g}° (paper Eq. 5): d − f·tan φ = {d - f * t:.4g} mm is too small for "
             f"f = {f:g} mm and d = {d:g} mm")
    _require(laser.wavelength_nm > 0, "laser", "wavelength_nm", laser.wavelength_nm, "must be > 0")
    _require(laser.power_mw >= 0, "laser", "power_mw", laser.power_mw, "must be >= 0")
    _require(laser.origin_x_mm < f, "laser", "origin_x_mm", laser.origin_x_mm,
             "the laser origin must lie before the object hinge (x < f)")
    _require(laser.waist_um > 0, "laser", "waist_um", laser.waist_um, "must be > 0")
    limit = laser.wavelength_nm * 1e-3 / (math.pi * laser.waist_um)  # [rad]
    _require(laser.divergence_mrad * 1e-3 >= limit * (1 - 1e-9), "laser", "divergence_mrad",
             laser.divergence_mrad,
             f"below the diffraction limit λ/(π·w0) = {limit * 1e3:.4g} mrad for this waist")
    _require(0 < laser.fan_angle_deg < 180, "laser", "fan_angle_deg", laser.fan_angle_deg,
             "must be in (0, 180)")
    _require(laser.fan_edge_deg >= 0, "laser", "fan_edge_deg", laser.fan_edge_deg, "must be >= 0")
    _require(0 <= laser.speckle_contrast <= 1, "laser", "speckle_contrast",
             laser.speckle_contrast, "must be in [0, 1]")


def _validate_sensor(s: Sensor, lens: Lens) -> None:
    _require(s.pixel_pitch_um > 0, "sensor", "pixel_pitch_um", s.pixel_pitch_um, "must be > 0")
    _require(s.columns > 0, "sensor", "columns", s.columns, "must be > 0")
    _require(s.rows > 0, "sensor", "rows", s.rows, "must be > 0")
    ordinary = s.image_distance_mm > 0      # no hinge, any roll of the pixel axes
    if ordinary:
        _require(s.image_distance_mm > lens.focal_length_mm, "sensor", "image_distance_mm",
                 s.image_distance_mm, f"must exceed the focal length {lens.focal_length_mm:g} mm (the "
                 "sensor behind the focal plane: the lens focuses at a finite distance)")
    _require(ordinary or s.hinge_column > s.columns - 0.5, "sensor", "hinge_column", s.hinge_column,
             f"the image hinge must lie beyond the last column (> {s.columns - 0.5}): a sensor "
             "that contains or straddles the hinge would image points at or inside the focal "
             "length; columns increase toward the hinge (flip frames left-right if your camera "
             "reads out the other way)")
    _require(0 < s.quantum_efficiency <= 1, "sensor", "quantum_efficiency",
             s.quantum_efficiency, "must be in (0, 1]")
    _require(s.full_well_e > 0, "sensor", "full_well_e", s.full_well_e, "must be > 0")
    _require(s.read_noise_e >= 0, "sensor", "read_noise_e", s.read_noise_e, "must be >= 0")
    _require(1 <= s.adc_bits <= 16, "sensor", "adc_bits", s.adc_bits,
             "must be 1..16 (frames are 16-bit PNG)")
    _require(0 <= s.dark_offset_dn < 2 ** s.adc_bits, "sensor", "dark_offset_dn",
             s.dark_offset_dn, f"must be in [0, {2 ** s.adc_bits})")
    _require(s.gain_e_per_dn >= 0, "sensor", "gain_e_per_dn", s.gain_e_per_dn,
             "must be >= 0 (0 = full well at full scale)")
    if s.exposure_ms is not None:
        _require(s.exposure_ms > 0, "sensor", "exposure_ms", s.exposure_ms, "must be > 0")
    _require(ordinary or abs(s.roll_deg) < 45, "sensor", "roll_deg", s.roll_deg,
             "must be within ±45° (a Scheimpflug sensor)")
    _require(abs(s.tilt_error_deg) < 30, "sensor", "tilt_error_deg", s.tilt_error_deg,
             "must be within ±30°")


def _validate_stage(st: Stage) -> None:
    if st.calibration_plate_height_mm is not None:
        _require(st.calibration_plate_height_mm > 0, "stage", "calibration_plate_height_mm",
                 st.calibration_plate_height_mm, "must be > 0")
    _require(0 <= st.axis_tilt_deg < 10 or 170 < st.axis_tilt_deg <= 180, "stage", "axis_tilt_deg",
             st.axis_tilt_deg, "must be in [0, 10) (a table up the rig's +z) or (170, 180] (up its −z)")
    _require(st.runout_um >= 0, "stage", "runout_um", st.runout_um, "must be >= 0")
    _require(st.table_material in TABLE_MATERIALS, "stage", "table_material", st.table_material,
             f"must be one of {', '.join(TABLE_MATERIALS)} (scenes.MATERIALS)")


def _validate_error_models(rig: Rig) -> None:
    f, df = rig.lens.focal_length_mm, rig.lens.focal_length_error_mm
    _require(abs(df) <= 0.2 * f, "lens", "focal_length_error_mm", df,
             f"must be within ±20 % of focal_length_mm (±{0.2 * f:.4g} mm)")





def _coerce(table: str, key: str, kind: Any, value: Any) -> Any:
    if kind is bool:
        if isinstance(value, bool):
            return value
        raise RigError(f"[{table}] {key} = {_show(value)}: must be true or false")
    if kind is str:
        if isinstance(value, str):
            return value
        raise RigError(f"[{table}] {key} = {_show(value)}: must be a string")
    if kind == float | None:
        if value is None:
            return None
        kind = float
    if isinstance(value, bool):
        raise RigError(f"[{table}] {key} = {value!r}: must be a number, not a boolean")
    if kind is float and isinstance(value, (int, float)):
        try:
            return float(value)
        except OverflowError:
            raise RigError(f"[{table}] {key} = {_show(value)}: out of range: must be in "
                           f"{KEY_RANGES.get(table, {}).get(key, 'the float range')}") from None
    if kind is int and isinstance(value, int):
        return value
    if kind is int and isinstance(value, float) and value.is_integer():
        return int(value)
    want = "an integer" if kind is int else "a number"
    raise RigError(f"[{table}] {key} = {_show(value)}: must be {want}")


def table_from_values(name: str, cls: type, values: Any) -> Any:
    """One table of a rig file as its dataclass, each value checked for its key's type.

    Parameters
    ----------
    name : str
        The table's name (``"lens"``, ``"laser"`` …), for the messages.
    cls : type
        Its dataclass (:data:`scheimpflug.model.tables.TABLES`).
    values : Mapping[str, Any]
        ``{key: value}`` as in the file; integral floats are accepted for integer keys.

    Returns
    -------
    object
        ``cls(**values)``, the values coerced (ints to floats for float keys).

    Raises
    ------
    RigError
        For a non-table, an unknown key, or a value of the wrong type.
    """
    if not isinstance(values, Mapping):
        raise RigError(f"[{name}] must be a table of keys, got {type(values).__name__}")
    hints = typing.get_type_hints(cls)
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(values) - known)
    if unknown:
        raise RigError(f"[{name}] unknown key {unknown[0]!r} (known keys: {', '.join(sorted(known))})")
    return cls(**{k: _coerce(name, k, hints[k], v) for k, v in values.items()})
