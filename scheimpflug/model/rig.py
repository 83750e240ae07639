"""The rig: lens, laser sheet, sensor, stages and environment as frozen dataclasses.

The rig is the single description of an instrument, real or simulated.  It is
read from the TOML rig file of INTERFACE.md (one table per dataclass below) or
taken from a built-in preset (``paper``).  Every key has a unit in its name
where doubt is possible; derived quantities (tilt, hinge points, F², C) are
computed in :mod:`scheimpflug.model.hinge`, never stored here.

Rig frame (DESIGN.md §2): origin at the lens centre, +x along the optical axis
toward the object, +z up, +y = z × x; lengths in mm, angles in degrees at
interfaces.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
import typing
from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from scheimpflug.errors import RigError
from scheimpflug.model.plan import resolve_defaults

__all__ = [
    "DERIVED_KEYS",
    "DERIVED_STAGE_KEYS",
    "Environment",
    "KEY_RANGES",
    "Laser",
    "MAX_TILT_DEG",
    "Lens",
    "PRESETS",
    "Rig",
    "Sensor",
    "Stage",
    "Twin",
    "load_preset",
    "load_rig",
    "rig_from_dict",
    "rig_to_dict",
    "rig_to_toml",
    "key_in_range",
    "validate_rig",
]


@dataclass(frozen=True)
class Lens:
    """Ideal thin lens (the ``[lens]`` table of the rig file).

    Parameters
    ----------
    focal_length_mm : float, default 55.0
        Focal length f [mm], in [0.5, 5000].
    f_number : float, default 5.6
        N, aperture diameter = f / N [-], in [0.5, 256].
    k1, k2 : float, default 0.0
        Radial distortion of the chief-ray angle,
        tan θ_d = tan θ (1 + k1 t² + k2 t⁴) with t = tan θ [-]; 0 for an ideal lens;
        each in [-10, 10].
    """

    focal_length_mm: float = 55.0
    f_number: float = 5.6
    k1: float = 0.0
    k2: float = 0.0


@dataclass(frozen=True)
class Laser:
    """Line laser spreading a vertical sheet ``y = d − x·tan φ`` in the rig frame (the ``[laser]`` table).

    Parameters
    ----------
    scheimpflug_distance_mm : float, default 150.0
        d, lens centre to the Scheimpflug line [mm], in (0, 1e5].
    tan_phi : float, default 0.2075
        tan φ, sheet angle to the optical axis [-], in [-100, 100]; d − f·tan φ
        must be > 0 and the sensor tilt β = atan(f/(d − f·tan φ)) at most
        :data:`MAX_TILT_DEG` (paper Eq. 5).
    wavelength_nm : float, default 450.0
        Laser wavelength [nm], in [0.1, 1e5] (below ≈ 200 nm only for test beams that must stay thin).
    power_mw : float, default 3.0
        Optical power in the whole fan [mW], in [0, 1e6].
    origin_x_mm : float, default 0.0
        x of the laser origin on the sheet, in the meridian plane [mm], in
        [-1e5, 1e5] and < f.
    waist_um : float, default 150.0
        1/e² half-thickness of the sheet at its waist [µm], in (0, 1e5].
    waist_distance_mm : float or None, default None
        Distance of the waist from the origin along the sheet [mm], in [-1e6, 1e6].
        Paper 640 (assumed: focused near the rotary axis); left out (None), the
        waist sits at the rotary axis (:mod:`scheimpflug.model.plan`).
    divergence_mrad : float, default 1.5
        Far-field 1/e² half-angle of the thickness [mrad], in [0, 1000] and
        ≥ λ / (π w0), the diffraction limit.
    fan_angle_deg : float, default 40.0
        Full opening of the fan in the sheet [deg], in (0, 180).
    fan_edge_deg : float, default 1.0
        Width of the soft fan edge (Gaussian roll-off) [deg], in [0, 90].
    speckle_contrast : float, default 0.0
        Multiplicative speckle contrast, 0 = off, 1 = fully developed [-], in [0, 1].
    """

    scheimpflug_distance_mm: float = 150.0
    tan_phi: float = 0.2075
    wavelength_nm: float = 450.0
    power_mw: float = 3.0
    origin_x_mm: float = 0.0
    waist_um: float = 150.0
    waist_distance_mm: float | None = None
    divergence_mrad: float = 1.5
    fan_angle_deg: float = 40.0
    fan_edge_deg: float = 1.0
    speckle_contrast: float = 0.0


@dataclass(frozen=True)
class Sensor:
    """Image sensor, tilted by the Scheimpflug angle, placement set by the hinge pixel (the ``[sensor]`` table).

    Parameters
    ----------
    pixel_pitch_um : float, default 5.86
        Pixel pitch p [µm], in [0.1, 1000].
    columns, rows : int, default 1216, 1936
        N_u × N_v [px], each in [1, 65535]; columns run along the tilt (distance)
        direction and increase toward the image hinge; rows run along height,
        increasing downward.
    hinge_column : float, default 3196.0
        u_h, column of the image hinge [px], in [-1e7, 1e7]; must lie beyond the
        last column.
    axis_row : float, default 771.0
        v_h, row of the meridian plane [px], in [-1e7, 1e7].
    roll_deg, tilt_error_deg : float, default 0.0
        Misalignment of the sensor about its normal and about its row axis
        (changes β), through the sensor centre [deg]; in (-45, 45) and (-30, 30).
    offset_u_px, offset_v_px, offset_normal_um : float, default 0.0
        Sensor displacement along columns, rows and the normal [px, px, µm],
        each in [-1e5, 1e5].
    quantum_efficiency : float, default 0.75
        Electrons per photon at the laser wavelength [-], in (0, 1].
    full_well_e : float, default 32000.0
        Saturation charge [e⁻], in (0, 1e8].
    read_noise_e : float, default 6.0
        RMS read noise [e⁻], in [0, 1e6].
    dark_offset_dn : float, default 16.0
        Black level added by the ADC [DN], in [0, 65535] and below 2**adc_bits.
    adc_bits : int, default 12
        ADC depth [bit], in [1, 16]; frames are stored as 16-bit PNG.
    gain_e_per_dn : float, default 0.0
        Conversion gain; 0 = full well maps to full scale [e⁻/DN], in [0, 1e8].
    exposure_ms : float or None, default None
        Exposure time [ms], in (0, 1e6].  Paper 0.5; left out (None), the exposure
        at which a white Lambertian surface on the rotary axis, facing the laser,
        peaks at 1/6 of the full well (closed form,
        :func:`scheimpflug.model.plan.lambertian_peak_electrons_per_ms`).
    """

    pixel_pitch_um: float = 5.86
    columns: int = 1216
    rows: int = 1936
    hinge_column: float = 3196.0
    axis_row: float = 771.0
    roll_deg: float = 0.0
    tilt_error_deg: float = 0.0
    offset_u_px: float = 0.0
    offset_v_px: float = 0.0
    offset_normal_um: float = 0.0
    quantum_efficiency: float = 0.75
    full_well_e: float = 32000.0
    read_noise_e: float = 6.0
    dark_offset_dn: float = 16.0
    adc_bits: int = 12
    gain_e_per_dn: float = 0.0
    exposure_ms: float | None = None


@dataclass(frozen=True)
class Stage:
    """Translation and rotary stages (INTERFACE.md stage conventions; the ``[stage]`` table).

    The five position keys (:data:`DERIVED_STAGE_KEYS`) may be left out of a
    rig file (None here): a :class:`Rig` then derives them from its working
    volume by the rule of :mod:`scheimpflug.model.plan` — stage zero at the
    near end of the view, the tallest plate that shows both edges over the
    whole depth range, the axis where the largest cylinder as tall as it is
    wide stays in view at every angle.  A built :class:`Rig` always holds
    numbers; :attr:`Rig.derived` names the keys that were derived.  The paper
    preset sets them all (the values below).

    Parameters
    ----------
    d0_mm : float or None, default None
        Stage coordinate of the object hinge; a face at stage s is at
        D = s − d0 [mm], in [-1e6, 1e6] (0 is fine: the stage zero at the hinge).
        Paper −466; rule: −⌊D at column 0⌋.
    axis_mm : float or None, default None
        Rotary axis position in stage coordinates [mm], in [-1e6, 1e6].  Paper 179.45.
    calibration_table_z_mm : float or None, default None
        Height of the translation stage's table (plate bottom) above the
        meridian plane [mm], in [-1e5, 1e5].  Paper −54.
    calibration_plate_height_mm : float or None, default None
        Height of the calibration plate on that table [mm], in (0, 1e4].  Paper 89.
    rotary_table_z_mm : float or None, default None
        Height of the rotary stage's table above the meridian plane
        (negative: below) [mm], in [-1e5, 1e5].  Paper −70.
    axis_tilt_deg, axis_tilt_azimuth_deg : float, default 0.0
        Tilt of the rotary axis from vertical, in [0, 10), and the direction it
        leans to (0 = toward +propagation), in [-360, 360] [deg].
    runout_um : float, default 0.0
        Radial runout of the rotary axis (once per turn) [µm], in [0, 1e5].
    """

    d0_mm: float | None = None
    axis_mm: float | None = None
    calibration_table_z_mm: float | None = None
    calibration_plate_height_mm: float | None = None
    rotary_table_z_mm: float | None = None
    axis_tilt_deg: float = 0.0
    axis_tilt_azimuth_deg: float = 0.0
    runout_um: float = 0.0


#: Stage keys that a rig may leave out; :mod:`scheimpflug.model.plan` derives them.
DERIVED_STAGE_KEYS = ("d0_mm", "axis_mm", "calibration_table_z_mm", "calibration_plate_height_mm",
                      "rotary_table_z_mm")
#: Every key a rig may leave out, as ``"table.key"`` (derived in this order).
DERIVED_KEYS = ("laser.waist_distance_mm", "sensor.exposure_ms", *(f"stage.{k}" for k in DERIVED_STAGE_KEYS))


@dataclass(frozen=True)
class Environment:
    """Light that is not the laser (the ``[environment]`` table).

    Parameters
    ----------
    ambient_irradiance_w_m2 : float, default 0.02
        Diffuse ambient irradiance on the scene within the camera's spectral
        band [W/m²], in [0, 1e5].
    """

    ambient_irradiance_w_m2: float = 0.02


SPECKLE_MODELS = ("surface", "sensor")


@dataclass(frozen=True)
class Twin:
    """How the digital twin renders this instrument (ignored by the measurement pipeline).

    The defaults are the ideal twin: first-surface light only, opaque materials.

    Parameters
    ----------
    bounces : int
        Light-path depth of the laser pass: 1 = the first surface the sheet meets only;
        N > 1 also follows the light N − 1 more times from surface to surface
        (inter-reflections) [-], range [1, 64].
    subsurface : bool
        Translucent materials (cardboard, paper, tape, plastic, marble) carry a
        scattering interior below a rough dielectric boundary and the light random-walks
        inside (true), or are opaque Lambertian surfaces (false); range {true, false}.
    speckle_model : str
        ``"surface"`` — speckle formed by coherent imaging of scatterers attached to the
        lit surface (moves with the part); ``"sensor"`` — a random pattern fixed to the
        sensor.  Its strength is ``[laser] speckle_contrast`` (0 = no speckle); range
        {"surface", "sensor"}.
    """

    bounces: int = 1
    subsurface: bool = False
    speckle_model: str = "surface"


@dataclass(frozen=True)
class Rig:
    """A whole instrument: one table of the rig file per field.

    The rig is validated on construction (:func:`validate_rig`); keys left as
    None (:data:`DERIVED_KEYS`: the stage positions, the laser's waist, the
    exposure) are then derived from the rig's working volume
    (:func:`scheimpflug.model.plan.resolve_defaults`), so ``rig.stage.d0_mm``
    and the others are always numbers, and :attr:`derived` names them.

    Parameters
    ----------
    lens : Lens, optional
        The ``[lens]`` table; default the paper lens.
    laser : Laser, optional
        The ``[laser]`` table; default the paper laser.
    sensor : Sensor, optional
        The ``[sensor]`` table; default the paper sensor.
    stage : Stage, optional
        The ``[stage]`` table; default: every position key derived.
    environment : Environment, optional
        The ``[environment]`` table; default the paper's ambient light.
    twin : Twin, optional
        The ``[twin]`` table (how the digital twin renders); default the ideal twin.

    Attributes
    ----------
    derived : tuple of str
        The keys that were derived rather than given, as ``"table.key"`` (not
        part of the rig's value: two rigs with the same numbers are equal).

    Raises
    ------
    RigError
        If a table has the wrong type, a key the wrong type or a non-finite
        value, or the values are impossible (the message names the key).
    """

    lens: Lens = field(default_factory=Lens)
    laser: Laser = field(default_factory=Laser)
    sensor: Sensor = field(default_factory=Sensor)
    stage: Stage = field(default_factory=Stage)
    environment: Environment = field(default_factory=Environment)
    twin: Twin = field(default_factory=Twin)
    derived: tuple[str, ...] = field(default=(), init=False, compare=False, repr=False)

    def __post_init__(self) -> None:
        validate_rig(self)
        laser, sensor, stage, derived = resolve_defaults(self)
        for name, table in (("laser", laser), ("sensor", sensor), ("stage", stage)):
            object.__setattr__(self, name, table)
        object.__setattr__(self, "derived", tuple(k for k in DERIVED_KEYS if k in derived))
        if derived:
            try:                     # derived values must lie in their ranges too
                validate_rig(self)
            except RigError as exc:
                raise RigError(f"{exc} (derived from the other keys: set it in the rig file)") from None

    def replace(self, *, rederive: bool = True, **tables: Mapping[str, Any]) -> Rig:
        """A copy with some keys changed, e.g. ``rig.replace(lens={"f_number": 8})``.

        Parameters
        ----------
        rederive : bool, default True
            Derive again, for the new rig, the keys that were derived for this
            one (unless given); False keeps their values.  A key given as None
            is derived.
        **tables : Mapping[str, Any]
            Per table name (``lens``, ``laser``, ``sensor``, ``stage``,
            ``environment``), the keys to change and their new values.

        Returns
        -------
        Rig
            The new, validated rig; ``self`` is unchanged.

        Raises
        ------
        RigError
            For an unknown table or key, or if the changed rig is invalid.
        """
        data: dict[str, dict[str, Any]] = rig_to_dict(self)
        for table, values in tables.items():
            if table not in data:
                raise RigError(f"unknown rig table [{table}]")
            data[table].update(values)
        given = {f"{t}.{k}" for t, values in tables.items() for k in values}
        again = tuple(k for k in self.derived if k not in given)
        if rederive:
            for key in again:
                table, name = key.split(".")
                data[table][name] = None
        new = rig_from_dict(data)
        if not rederive:
            object.__setattr__(new, "derived", tuple(k for k in DERIVED_KEYS if k in again or k in new.derived))
        return new


_TABLES: dict[str, type] = {
    "lens": Lens,
    "laser": Laser,
    "sensor": Sensor,
    "stage": Stage,
    "environment": Environment,
    "twin": Twin,
}

PRESETS = ("paper",)
"""Names of the built-in rigs (:func:`load_preset`)."""

KEY_RANGES: dict[str, dict[str, str]] = {
    "lens": {"focal_length_mm": "[0.5, 5000]", "f_number": "[0.5, 256]", "k1": "[-10, 10]",
             "k2": "[-10, 10]"},
    "laser": {"scheimpflug_distance_mm": "(0, 1e5]", "tan_phi": "[-100, 100]",
              "wavelength_nm": "[0.1, 1e5]", "power_mw": "[0, 1e6]", "origin_x_mm": "[-1e5, 1e5]",
              "waist_um": "(0, 1e5]", "waist_distance_mm": "[-1e6, 1e6]",
              "divergence_mrad": "[0, 1000]", "fan_angle_deg": "(0, 180)", "fan_edge_deg": "[0, 90]",
              "speckle_contrast": "[0, 1]"},
    "sensor": {"pixel_pitch_um": "[0.1, 1000]", "columns": "[1, 65535]", "rows": "[1, 65535]",
               "hinge_column": "[-1e7, 1e7]", "axis_row": "[-1e7, 1e7]", "roll_deg": "(-45, 45)",
               "tilt_error_deg": "(-30, 30)", "offset_u_px": "[-1e5, 1e5]",
               "offset_v_px": "[-1e5, 1e5]", "offset_normal_um": "[-1e5, 1e5]",
               "quantum_efficiency": "(0, 1]", "full_well_e": "(0, 1e8]", "read_noise_e": "[0, 1e6]",
               "dark_offset_dn": "[0, 65535]", "adc_bits": "[1, 16]", "gain_e_per_dn": "[0, 1e8]",
               "exposure_ms": "(0, 1e6]"},
    "stage": {"d0_mm": "[-1e6, 1e6]", "axis_mm": "[-1e6, 1e6]",
              "calibration_table_z_mm": "[-1e5, 1e5]", "calibration_plate_height_mm": "(0, 1e4]",
              "rotary_table_z_mm": "[-1e5, 1e5]",
              "axis_tilt_deg": "[0, 10)", "axis_tilt_azimuth_deg": "[-360, 360]",
              "runout_um": "[0, 1e5]"},
    "environment": {"ambient_irradiance_w_m2": "[0, 1e5]"},
    "twin": {"bounces": "[1, 64]", "subsurface": "{true, false}",
             "speckle_model": '{"surface", "sensor"}'},
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
    for name, cls in _TABLES.items():
        obj = getattr(rig, name)
        if not isinstance(obj, cls):
            raise RigError(f"[{name}] must be a {cls.__name__}, got {type(obj).__name__}")
        _check_fields(name, obj)
    _validate_lens(rig.lens)
    _validate_laser(rig.laser, rig.lens)
    _validate_sensor(rig.sensor)
    _validate_stage(rig.stage)
    _require(rig.environment.ambient_irradiance_w_m2 >= 0, "environment",
             "ambient_irradiance_w_m2", rig.environment.ambient_irradiance_w_m2,
             "must be >= 0")
    _validate_twin(rig.twin)


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


def _validate_sensor(s: Sensor) -> None:
    _require(s.pixel_pitch_um > 0, "sensor", "pixel_pitch_um", s.pixel_pitch_um, "must be > 0")
    _require(s.columns > 0, "sensor", "columns", s.columns, "must be > 0")
    _require(s.rows > 0, "sensor", "rows", s.rows, "must be > 0")
    _require(s.hinge_column > s.columns - 0.5, "sensor", "hinge_column", s.hinge_column,
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
    _require(abs(s.roll_deg) < 45, "sensor", "roll_deg", s.roll_deg, "must be within ±45°")
    _require(abs(s.tilt_error_deg) < 30, "sensor", "tilt_error_deg", s.tilt_error_deg,
             "must be within ±30°")


def _validate_stage(st: Stage) -> None:
    if st.calibration_plate_height_mm is not None:
        _require(st.calibration_plate_height_mm > 0, "stage", "calibration_plate_height_mm",
                 st.calibration_plate_height_mm, "must be > 0")
    _require(0 <= st.axis_tilt_deg < 10, "stage", "axis_tilt_deg", st.axis_tilt_deg,
             "must be in [0, 10)")
    _require(st.runout_um >= 0, "stage", "runout_um", st.runout_um, "must be >= 0")


# ---------------------------------------------------------------- (de)serialisation


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


def _table_from_dict(name: str, cls: type, values: Any) -> Any:
    if not isinstance(values, Mapping):
        raise RigError(f"[{name}] must be a table of keys, got {type(values).__name__}")
    hints = typing.get_type_hints(cls)
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(values) - known)
    if unknown:
        raise RigError(f"[{name}] unknown key {unknown[0]!r} (known keys: {', '.join(sorted(known))})")
    return cls(**{k: _coerce(name, k, hints[k], v) for k, v in values.items()})


def rig_from_dict(data: Mapping[str, Any]) -> Rig:
    """Build a rig from nested tables.

    Missing keys take their defaults: the paper's values, except the keys of
    :data:`DERIVED_KEYS` (the stage positions, the laser's waist distance, the
    exposure), which are derived from the rig's working volume
    (:mod:`scheimpflug.model.plan`); None also means "derive".

    Parameters
    ----------
    data : Mapping[str, Any]
        ``{table: {key: value}}`` as in the rig file (or ``manifest.json``);
        integral floats are accepted for integer keys.

    Returns
    -------
    Rig
        The validated rig, its stage keys resolved.

    Raises
    ------
    RigError
        For a non-table, an unknown table or key, a boolean or non-numeric
        value, or an invalid rig.
    """
    if not isinstance(data, Mapping):
        raise RigError(f"a rig must be a table of tables, got {type(data).__name__}")
    unknown = sorted(set(data) - set(_TABLES))
    if unknown:
        raise RigError(f"unknown rig table [{unknown[0]}] (known: {', '.join(_TABLES)})")
    parts = {name: _table_from_dict(name, cls, data.get(name, {})) for name, cls in _TABLES.items()}
    return Rig(**parts)


def rig_to_dict(rig: Rig) -> dict[str, dict[str, Any]]:
    """Nested plain tables, as in the rig file (and in ``manifest.json``).

    Parameters
    ----------
    rig : Rig
        The instrument.

    Returns
    -------
    dict of str to dict
        ``{table: {key: value}}``, every key of every table; derived stage
        keys hold the values the rule gave them.
    """
    return {name: dataclasses.asdict(getattr(rig, name)) for name in _TABLES}


def rig_to_toml(rig: Rig) -> str:
    """The rig file text of a rig (every key, with its value).

    Parameters
    ----------
    rig : Rig
        The instrument.

    Returns
    -------
    str
        TOML text, one ``[table]`` per rig table; :func:`load_rig` reads it
        back.  Keys that the rule derived carry the comment ``# derived``.
    """
    lines: list[str] = []
    for name, table in rig_to_dict(rig).items():
        lines.append(f"[{name}]")
        for k, v in table.items():
            note = "  # derived (scheimpflug.model.plan)" if f"{name}.{k}" in rig.derived else ""
            lines.append(f"{k} = {_toml_value(v)}{note}")
        lines.append("")
    return "\n".join(lines)


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    return repr(value)


def load_rig(path: str | Path) -> Rig:
    """Read a TOML rig file.

    Parameters
    ----------
    path : str or Path
        The rig file (INTERFACE.md).

    Returns
    -------
    Rig
        The validated rig; keys not in the file take their defaults
        (:func:`rig_from_dict`).

    Raises
    ------
    RigError
        If the file is missing, unreadable, not UTF-8, not valid TOML, or
        describes an invalid rig.
    """
    p = Path(path)
    try:
        text = p.read_bytes().decode("utf-8")
    except FileNotFoundError:
        raise RigError(f"rig file {str(p)!r} does not exist") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise RigError(f"rig file {str(p)!r} cannot be read: {exc}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise RigError(f"rig file {str(p)!r} is not valid TOML: {exc}") from None
    return rig_from_dict(data)


def load_preset(name: str) -> Rig:
    """A built-in rig by name.

    Parameters
    ----------
    name : str
        One of :data:`PRESETS` (``paper``: DESIGN.md §2 with f/5.6).

    Returns
    -------
    Rig
        The preset, read from ``scheimpflug/model/presets/<name>.toml``.

    Raises
    ------
    RigError
        If ``name`` is not a known preset.
    """
    if name not in PRESETS:
        raise RigError(f"unknown preset {name!r} (known: {', '.join(PRESETS)})")
    text = resources.files("scheimpflug.model").joinpath("presets", f"{name}.toml").read_text("utf-8")
    return rig_from_dict(tomllib.loads(text))
