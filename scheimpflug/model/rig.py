"""The rig: lens, laser sheet, sensor, stages and environment as frozen dataclasses.

The rig is the single description of an instrument, real or simulated.  It is
read from the TOML rig file of docs/reference/interface.md (one table per dataclass below) or
taken from a built-in preset (``paper``).  Every key has a unit in its name
where doubt is possible; derived quantities (tilt, hinge points, F², C) are
computed in :mod:`scheimpflug.model.hinge`, never stored here.

Rig frame (docs/explanation/design-notes.md §2): origin at the lens centre, +x along the optical axis
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
    "ERROR_MODELS",
    "TWIN_EFFECTS",
    "ERROR_MODEL_SHAPES",
    "Environment",
    "KEY_RANGES",
    "Laser",
    "MAX_TILT_DEG",
    "Lens",
    "PRESETS",
    "Rig",
    "Sensor",
    "Stage",
    "active_error_models",
    "is_realistic",
    "Twin",
    "load_preset",
    "load_rig",
    "preset_tables",
    "read_toml",
    "rig_from_dict",
    "rig_to_dict",
    "rig_to_toml",
    "key_in_range",
    "validate_rig",
    "with_error_models",
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
    focal_length_error_mm : float, default 0.0
        The lens's real focal length minus ``focal_length_mm`` [mm], in
        [-1000, 1000] and within ±20 % of ``focal_length_mm``.  The twin focuses such a lens as a user would: it moves
        the lens along its axis until the sheet point imaged at the sensor
        centre is sharp (:func:`scheimpflug.model.camera.lens_state`); the
        sensor stays where the nominal design puts it.  Error model, 0 = off.
    focus_error_um : float, default 0.0
        Axial lens position left wrong after focusing, + toward the object
        [µm], in [-5000, 5000].  Error model, 0 = off.

    Notes
    -----
    There is no key for a thick lens's principal-plane separation: a thick
    lens focused on the sheet maps the sheet onto the sensor exactly as the
    thin lens does (its image space is only shifted by the separation, which
    focusing absorbs); `docs/explanation/twin-optics.md` ("Error models") shows it and what it does change.
    """

    focal_length_mm: float = 55.0
    f_number: float = 5.6
    k1: float = 0.0
    k2: float = 0.0
    focal_length_error_mm: float = 0.0
    focus_error_um: float = 0.0


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
    line_bow_mrad : float, default 0.0
        Bow ("smile") of the sheet: a fan ray at fan angle α leaves the sheet
        plane by the transverse angle b·(2α/F)², b this value, toward the
        camera side (+n) when > 0 [mrad], in [-50, 50].  On a screen at
        distance r the line bends by the sagitta r·b between its centre and
        its ends (:func:`sim.lightsheet.bow_angle_rad`).  Error model, 0 = off.
    fan_edge_ratio : float, default 1.0
        Non-uniform fan (Powell-lens profile): radiant intensity at the fan
        edge over that at its centre, the profile 1 + (R − 1)·(2α/F)²,
        total power kept [-], in [0.05, 20].  1 = flat fan (off).
    pointing_jitter_urad : float, default 0.0
        Pointing drift between frames: RMS of a random rotation of the sheet
        about the laser origin, drawn per frame and per axis (about the
        vertical in-sheet axis and about the propagation direction) [µrad],
        in [0, 1e5].  Error model, 0 = off.
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
    line_bow_mrad: float = 0.0
    fan_edge_ratio: float = 1.0
    pointing_jitter_urad: float = 0.0


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
    prnu_percent : float, default 0.0
        Photo-response non-uniformity: RMS of the pixels' gain about its mean,
        in % of the mean [%], in [0, 50].  A fixed map per sensor.  Error model, 0 = off.
    dsnu_e : float, default 0.0
        Dark-signal non-uniformity: RMS of the pixels' dark offset [e⁻], in
        [0, 1e4].  A fixed map per sensor.  Error model, 0 = off.
    hot_pixel_fraction : float, default 0.0
        Fraction of pixels that are hot [-], in [0, 0.1].  Error model, 0 = off.
    hot_pixel_e : float, default 0.0
        Extra dark signal of a hot pixel during the exposure [e⁻], in [0, 1e6].
    exposure_jitter_percent : float, default 0.0
        RMS of the frame-to-frame error of the exposure time, in % of
        ``exposure_ms`` [%], in [0, 30].  Drawn per frame.  Error model, 0 = off.
    pattern_seed : int, default 0
        Seed of the fixed-pattern maps (PRNU, DSNU, hot pixels): one physical
        sensor, the same maps in every frame and run [-], in [0, 4294967295].
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
    prnu_percent: float = 0.0
    dsnu_e: float = 0.0
    hot_pixel_fraction: float = 0.0
    hot_pixel_e: float = 0.0
    exposure_jitter_percent: float = 0.0
    pattern_seed: int = 0


@dataclass(frozen=True)
class Stage:
    """Translation and rotary stages (docs/reference/interface.md stage conventions; the ``[stage]`` table).

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
    translation_scale_ppm : float, default 0.0
        Systematic scale error: the carriage moves s·(1 + k·1e-6) for a command
        s [ppm], in [-1e4, 1e4].
    translation_periodic_um : float, default 0.0
        Amplitude of the lead screw's periodic error, once per screw turn,
        A·sin(2π s / lead) [µm], in [0, 1000].
    translation_lead_mm : float, default 1.0
        Lead of the screw: travel per turn, the period of that error [mm], in (0, 100].
    translation_repeatability_um : float, default 0.0
        RMS (1σ) of the random positioning error, drawn per frame [µm], in [0, 1000].
    translation_travel_mm : float, default 300.0
        Travel over which straightness, pitch and yaw are specified [mm], in (0, 1e4].
    straightness_lateral_um, straightness_vertical_um : float, default 0.0
        Straightness of travel: the carriage's deviation along the sheet normal
        (+n, camera side) and up (+z), a parabolic bow peaking at mid travel,
        zero at its ends [µm], each in [-1000, 1000].
    pitch_urad, yaw_urad : float, default 0.0
        Angular deviation of the carriage about the horizontal axis ⊥ travel
        (pitch: + tips the plate's top toward +propagation) and about the
        vertical (yaw: + turns counter-clockwise seen from above), linear over
        the travel from −value to +value, zero at mid travel; about the
        carriage point under the plate's measured face [µrad], each in
        [-1e5, 1e5].
    rotary_eccentricity_deg : float, default 0.0
        Angle error of an eccentric encoder (or worm gear), once per turn:
        the table turns θ + A·sin θ for a command θ [deg], in [-1, 1].
    rotary_repeatability_deg : float, default 0.0
        RMS (1σ) of the random angle error, drawn per frame [deg], in [0, 1].
    wobble_urad : float, default 0.0
        Amplitude of the table's tilt error motion, twice per turn [µrad],
        in [0, 1e5] (the once-per-turn part is a constant tilt: ``axis_tilt_deg``).
    radial_error_um : float, default 0.0
        Amplitude of the table's radial error motion, twice per turn [µm], in
        [0, 1000] (the once-per-turn part is a centring error: ``runout_um``).
    plate_height_error_mm : float, default 0.0
        The plate's real height minus the nominal one the calibration is told
        [mm], in [-10, 10].
    plate_flatness_um : float, default 0.0
        Flatness of the measured face, peak to valley: a paraboloid bow, its
        centre nearer the laser than its corners when > 0 [µm], in [-5000, 5000].
    plate_edge_break_mm : float, default 0.0
        45° chamfer of the measured face's top and bottom edges (broken edges,
        ISO 13715) [mm], in [0, 2]; the sheet lights the chamfers too
        (:func:`scenes.generators.plate`).
    plate_tilt_deg : float, default 0.0
        Tilt of the measured face about its horizontal axis (the plate leans,
        its top toward +propagation when > 0) [deg], in [-10, 10].
    plate_yaw_deg : float, default 0.0
        Rotation of the plate about the vertical, counter-clockwise seen from
        above [deg], in [-10, 10].

    Notes
    -----
    The ``translation_*``, ``straightness_*``, ``pitch_urad`` and ``yaw_urad``
    keys are the translation stage's error models, the ``rotary_*``,
    ``wobble_urad`` and ``radial_error_um`` keys the rotary stage's (both
    simulated in :mod:`sim.stages`), the ``plate_*`` keys the calibration
    plate's (:func:`scenes.generators.plate`, :mod:`sim.scenarios`); each is
    off at its default.  Straightness, pitch and yaw are defined over the
    stage coordinate s ∈ [0, translation_travel_mm] and continue the same
    polynomial outside it.  The frame folder's manifest keeps the commanded
    ``stage_mm`` / ``angle_deg``; what the stage really did is in each
    frame's ``actual`` entry.
    """

    d0_mm: float | None = None
    axis_mm: float | None = None
    calibration_table_z_mm: float | None = None
    calibration_plate_height_mm: float | None = None
    rotary_table_z_mm: float | None = None
    axis_tilt_deg: float = 0.0
    axis_tilt_azimuth_deg: float = 0.0
    runout_um: float = 0.0
    translation_scale_ppm: float = 0.0
    translation_periodic_um: float = 0.0
    translation_lead_mm: float = 1.0
    translation_repeatability_um: float = 0.0
    translation_travel_mm: float = 300.0
    straightness_lateral_um: float = 0.0
    straightness_vertical_um: float = 0.0
    pitch_urad: float = 0.0
    yaw_urad: float = 0.0
    rotary_eccentricity_deg: float = 0.0
    rotary_repeatability_deg: float = 0.0
    wobble_urad: float = 0.0
    radial_error_um: float = 0.0
    plate_height_error_mm: float = 0.0
    plate_flatness_um: float = 0.0
    plate_edge_break_mm: float = 0.0
    plate_tilt_deg: float = 0.0
    plate_yaw_deg: float = 0.0


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
        band [W/m²], in [0, 1e5]: a uniform environment of radiance E/π.
    flood_irradiance_w_m2 : float, default 0.0
        The flood light (a square, uniformly emitting area light facing its aim
        point): the irradiance it gives a surface facing it at the aim point, within
        the camera's band [W/m²], in [0, 1e5]; 0 = no flood light.  The aim point is
        the sheet point imaged at the sensor centre.
    flood_size_mm : float, default 200.0
        Side of the flood light's square [mm], in (0, 1e5].
    flood_distance_mm : float, default 400.0
        Distance of the light's centre from the aim point [mm], in (0, 1e6].
    flood_azimuth_deg : float, default 30.0
        Direction of the light seen from the aim point: turned about +z from the
        horizontal direction toward the lens centre, counter-clockwise seen from
        above [deg], in [-180, 180].
    flood_elevation_deg : float, default 30.0
        Elevation of that direction above the horizontal [deg], in [-89, 89].
    """

    ambient_irradiance_w_m2: float = 0.02
    flood_irradiance_w_m2: float = 0.0
    flood_size_mm: float = 200.0
    flood_distance_mm: float = 400.0
    flood_azimuth_deg: float = 30.0
    flood_elevation_deg: float = 30.0


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
    camera_spp : int
        Samples per pixel of the camera pass (:mod:`sim.camera_pass`: every pixel's
        area and the lens aperture sampled, the scene's environment and flood light
        traced, ``bounces`` deep) for all light but the laser's; 0 = the coarse ambient
        pass of :mod:`sim.render` (one chief ray per 8 × 8 pixels, no defocus, no
        flood light) [-], range [0, 4096].
    """

    bounces: int = 1
    subsurface: bool = False
    speckle_model: str = "surface"
    camera_spp: int = 0


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

PRESETS = ("paper", "paper-as-built")
"""Names of the built-in rigs (:func:`load_preset`): ``paper``, the ideal paper rig, and
``paper-as-built``, the same rig with every modelled error source at the values of the
kind of parts the paper used (each value's source in ``presets/paper-as-built.toml``)."""

KEY_RANGES: dict[str, dict[str, str]] = {
    "lens": {"focal_length_mm": "[0.5, 5000]", "f_number": "[0.5, 256]", "k1": "[-10, 10]",
             "k2": "[-10, 10]", "focal_length_error_mm": "[-1000, 1000]",
             "focus_error_um": "[-5000, 5000]"},
    "laser": {"scheimpflug_distance_mm": "(0, 1e5]", "tan_phi": "[-100, 100]",
              "wavelength_nm": "[0.1, 1e5]", "power_mw": "[0, 1e6]", "origin_x_mm": "[-1e5, 1e5]",
              "waist_um": "(0, 1e5]", "waist_distance_mm": "[-1e6, 1e6]",
              "divergence_mrad": "[0, 1000]", "fan_angle_deg": "(0, 180)", "fan_edge_deg": "[0, 90]",
              "speckle_contrast": "[0, 1]", "line_bow_mrad": "[-50, 50]", "fan_edge_ratio": "[0.05, 20]",
              "pointing_jitter_urad": "[0, 1e5]"},
    "sensor": {"pixel_pitch_um": "[0.1, 1000]", "columns": "[1, 65535]", "rows": "[1, 65535]",
               "hinge_column": "[-1e7, 1e7]", "axis_row": "[-1e7, 1e7]", "roll_deg": "(-45, 45)",
               "tilt_error_deg": "(-30, 30)", "offset_u_px": "[-1e5, 1e5]",
               "offset_v_px": "[-1e5, 1e5]", "offset_normal_um": "[-1e5, 1e5]",
               "quantum_efficiency": "(0, 1]", "full_well_e": "(0, 1e8]", "read_noise_e": "[0, 1e6]",
               "dark_offset_dn": "[0, 65535]", "adc_bits": "[1, 16]", "gain_e_per_dn": "[0, 1e8]",
               "exposure_ms": "(0, 1e6]", "prnu_percent": "[0, 50]", "dsnu_e": "[0, 1e4]",
               "hot_pixel_fraction": "[0, 0.1]", "hot_pixel_e": "[0, 1e6]",
               "exposure_jitter_percent": "[0, 30]", "pattern_seed": "[0, 4294967295]"},
    "stage": {"d0_mm": "[-1e6, 1e6]", "axis_mm": "[-1e6, 1e6]",
              "calibration_table_z_mm": "[-1e5, 1e5]", "calibration_plate_height_mm": "(0, 1e4]",
              "rotary_table_z_mm": "[-1e5, 1e5]",
              "axis_tilt_deg": "[0, 10)", "axis_tilt_azimuth_deg": "[-360, 360]",
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
    _validate_error_models(rig)
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


#: The error models' switches, by source: each model is off when all its keys hold
#: their defaults (``fan_edge_ratio`` 1, every other 0).  Keys that only shape a model
#: (``translation_lead_mm``, ``translation_travel_mm``, ``hot_pixel_e``,
#: ``pattern_seed``) are not switches.
ERROR_MODELS: dict[str, tuple[str, ...]] = {
    "translation stage": ("stage.translation_scale_ppm", "stage.translation_periodic_um",
                          "stage.translation_repeatability_um", "stage.straightness_lateral_um",
                          "stage.straightness_vertical_um", "stage.pitch_urad", "stage.yaw_urad"),
    "rotary stage": ("stage.rotary_eccentricity_deg", "stage.rotary_repeatability_deg",
                     "stage.wobble_urad", "stage.radial_error_um"),
    "calibration plate": ("stage.plate_height_error_mm", "stage.plate_flatness_um",
                          "stage.plate_edge_break_mm", "stage.plate_tilt_deg", "stage.plate_yaw_deg"),
    "laser": ("laser.line_bow_mrad", "laser.fan_edge_ratio", "laser.pointing_jitter_urad"),
    "speckle": ("laser.speckle_contrast",),
    "lens": ("lens.focal_length_error_mm", "lens.focus_error_um", "lens.k1", "lens.k2"),
    "sensor": ("sensor.prnu_percent", "sensor.dsnu_e", "sensor.hot_pixel_fraction",
               "sensor.exposure_jitter_percent"),
}


#: Keys that shape an error model without switching it on, copied with it by
#: :func:`with_error_models`.
ERROR_MODEL_SHAPES: dict[str, tuple[str, ...]] = {
    "translation stage": ("stage.translation_lead_mm", "stage.translation_travel_mm"),
    "sensor": ("sensor.hot_pixel_e", "sensor.pattern_seed"),
    "speckle": ("twin.speckle_model",),
}


#: The twin's physical light (``[twin]``, issue 10), by effect: each is off at its
#: default (``bounces`` 1, ``subsurface`` false).  Not error models of the instrument
#: (:func:`active_error_models` ignores them: the geometry and the truth stay the
#: ideal rig's), but sources of the as-built rig's error all the same, which
#: :func:`with_error_models` takes one at a time like the error models.
TWIN_EFFECTS: dict[str, tuple[str, ...]] = {
    "inter-reflections": ("twin.bounces",),
    "subsurface": ("twin.subsurface",),
}


def active_error_models(rig: Rig) -> tuple[str, ...]:
    """The error-model keys of a rig that are on.

    Parameters
    ----------
    rig : Rig
        The instrument.

    Returns
    -------
    tuple of str
        ``"table.key"`` of every key of :data:`ERROR_MODELS` whose value
        differs from its default, in the order of :data:`ERROR_MODELS`; empty
        for an ideal rig.
    """
    on = []
    for keys in ERROR_MODELS.values():
        for key in keys:
            table, name = key.split(".")
            obj = getattr(rig, table)
            default = next(f.default for f in dataclasses.fields(obj) if f.name == name)
            if getattr(obj, name) != default:
                on.append(key)
    return tuple(on)


def is_realistic(rig: Rig) -> bool:
    """Whether the rig's twin is more than the ideal first-surface one.

    The twin's physical light (:data:`TWIN_EFFECTS`, surface-attached speckle) costs
    ≈ 3 × an ideal frame's time and ≈ 2.5 × its memory (benchmarks/RESULTS.md); the
    render's job sizing and its ``--workers auto`` depend on it.

    Parameters
    ----------
    rig : Rig
        The rig.

    Returns
    -------
    bool
        True with ``[twin] bounces`` > 1, ``subsurface`` on, or surface-attached speckle
        (``speckle_model = "surface"`` with ``[laser] speckle_contrast`` > 0).
    """
    t = rig.twin
    return t.bounces > 1 or bool(t.subsurface) or (t.speckle_model == "surface"
                                                      and rig.laser.speckle_contrast > 0)


def with_error_models(rig: Rig, source: Rig, groups) -> Rig:
    """A rig with some error models taken from another rig.

    Parameters
    ----------
    rig : Rig
        The base instrument (e.g. the ideal ``paper`` preset).
    source : Rig
        The rig whose error-model values are taken (e.g. ``paper-as-built``).
    groups : iterable of str
        Names of :data:`ERROR_MODELS` groups (``"translation stage"``, ``"sensor"`` …)
        or of :data:`TWIN_EFFECTS` (``"inter-reflections"``, ``"subsurface"``).

    Returns
    -------
    Rig
        ``rig`` with every key of those groups (switches of :data:`ERROR_MODELS` and
        :data:`TWIN_EFFECTS`, shapes of :data:`ERROR_MODEL_SHAPES`) set to its value in
        ``source``.

    Raises
    ------
    RigError
        For an unknown group name.
    """
    tables: dict[str, dict[str, Any]] = {}
    known = {**ERROR_MODELS, **TWIN_EFFECTS}
    for group in groups:
        if group not in known:
            raise RigError(f"unknown error model {group!r} (known: {', '.join(known)})")
        for key in known[group] + ERROR_MODEL_SHAPES.get(group, ()):
            table, name = key.split(".")
            tables.setdefault(table, {})[name] = getattr(getattr(source, table), name)
    return rig.replace(**tables) if tables else rig


def _validate_error_models(rig: Rig) -> None:
    f, df = rig.lens.focal_length_mm, rig.lens.focal_length_error_mm
    _require(abs(df) <= 0.2 * f, "lens", "focal_length_error_mm", df,
             f"must be within ±20 % of focal_length_mm (±{0.2 * f:.4g} mm)")


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
        The rig file (docs/reference/interface.md).

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
    return rig_from_dict(read_toml(path, "rig file", RigError))


def read_toml(path: str | Path, what: str, error: type[Exception] = RigError) -> dict:
    """Read a UTF-8 TOML file (rig file, dataset or study spec) with one clear error.

    Parameters
    ----------
    path : str or Path
        The file.
    what : str
        What the file is, for the message (``"rig file"``, ``"spec file"``).
    error : type of Exception, default RigError
        The error class raised (the caller's typed error).

    Returns
    -------
    dict
        The parsed tables.

    Raises
    ------
    Exception
        ``error``, naming the file: it is missing, unreadable, not UTF-8 or not valid TOML.
    """
    p = Path(path)
    try:
        text = p.read_bytes().decode("utf-8")
    except FileNotFoundError:
        raise error(f"{what} {str(p)!r} does not exist") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise error(f"{what} {str(p)!r} cannot be read: {exc}") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{what} {str(p)!r} is not valid TOML: {exc}") from None


def load_preset(name: str) -> Rig:
    """A built-in rig by name.

    Parameters
    ----------
    name : str
        One of :data:`PRESETS` (``paper``: docs/explanation/design-notes.md §2 with f/5.6;
        ``paper-as-built``: the same with its error models on).

    Returns
    -------
    Rig
        The preset, read from ``scheimpflug/model/presets/<name>.toml``.

    Raises
    ------
    RigError
        If ``name`` is not a known preset.
    """
    return rig_from_dict(preset_tables(name))


def preset_tables(name: str) -> dict:
    """The tables of a built-in rig as its file gives them (before defaults are filled in).

    Parameters
    ----------
    name : str
        One of :data:`PRESETS`.

    Returns
    -------
    dict
        ``{table: {key: value}}`` of ``scheimpflug/model/presets/<name>.toml``.

    Raises
    ------
    RigError
        If ``name`` is not a known preset.
    """
    if name not in PRESETS:
        raise RigError(f"unknown preset {name!r} (known: {', '.join(PRESETS)})")
    text = resources.files("scheimpflug.model").joinpath("presets", f"{name}.toml").read_text("utf-8")
    return tomllib.loads(text)
