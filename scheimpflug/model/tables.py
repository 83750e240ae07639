"""The rig file's tables as frozen dataclasses: lens, laser sheet, sensor, stages, environment, twin.

One dataclass per table of the rig file (docs/reference/interface.md); each
field is a key, its docstring entry the key's meaning and unit, its range in
:data:`scheimpflug.model.keys.KEY_RANGES`.  The whole instrument, these tables
together, is :class:`scheimpflug.model.assembly.Rig` (importable, as every name
here, from :mod:`scheimpflug.model.rig`).

Rig frame (docs/explanation/design-notes.md §2): origin at the lens centre, +x along the optical axis
toward the object, +z up, +y = z × x; lengths in mm, angles in degrees at
interfaces.
"""

from __future__ import annotations

from dataclasses import dataclass

from scheimpflug.model.chain import Chain

__all__ = [
    "DERIVED_KEYS",
    "DERIVED_STAGE_KEYS",
    "SPECKLE_MODELS",
    "TABLES",
    "TABLE_MATERIALS",
    "Environment",
    "Laser",
    "Lens",
    "Sensor",
    "Stage",
    "Twin",
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
    k3 : float, default 0.0
        Radial distortion's third term, the factor 1 + k1 r² + k2 r⁴ + k3 r⁶ on
        OpenCV's normalised image coordinates (r = tan θ) [-], in [-100, 100].
    p1, p2 : float, default 0.0
        OpenCV's tangential distortion on the normalised coordinates (x, y) of
        the camera whose x runs along the sensor's columns and y along its rows
        (the rig's −y, −z turned by ``[sensor] roll_deg``) [-], each in [-1, 1].
    aspect_ratio : float, default 1.0
        fy / fx of a calibrated camera: the normalised image coordinate along
        the rows is stretched by this factor (the image of non-square pixels,
        or of an anamorphic lens) [-], in [0.5, 2].
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
    k3: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    aspect_ratio: float = 1.0
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
        For a sensor perpendicular to the optical axis (``image_distance_mm`` > 0)
        ``roll_deg`` is the turn of its pixel axes about the axis, in [-180, 180].
    offset_u_px, offset_v_px, offset_normal_um : float, default 0.0
        Sensor displacement along columns, rows and the normal [px, px, µm],
        each in [-1e5, 1e5].  For a perpendicular sensor the optical axis meets
        it at pixel ((columns − 1)/2 − offset_u_px, (rows − 1)/2 − offset_v_px),
        the principal point.
    image_distance_mm : float, default 0.0
        0: the Scheimpflug sensor, tilted by the hinge rule (paper Eq. 5) and
        placed by ``hinge_column``, ``axis_row``.  > 0: an ordinary camera's
        sensor, perpendicular to the optical axis at this distance behind the
        lens centre (a calibration's principal distance fx · pitch), which
        must exceed the focal length; ``hinge_column`` and ``axis_row`` are
        then unused [mm], in [0, 1e5].
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
    image_distance_mm: float = 0.0
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
        Tilt of the rotary axis (the table's up) from the rig's +z, in [0, 180]
        (only [0, 10) or (170, 180] are a rotary stage), and the direction it leans to (0 = toward +propagation),
        in [-360, 360] [deg].  Over 170° the table's up is the rig's −z: a rig
        frame upside down in the world, as for an ordinary camera whose sheet
        lies on its right (:mod:`scheimpflug.model.instrument`); the plan's
        rules (:mod:`scheimpflug.model.plan`) assume an upward table.
    axis_offset_mm : float, default 0.0
        Offset of the table's centre from the sheet along the stage frame's +y
        (the sheet normal) [mm], in [-1e4, 1e4]: a calibrated axis that misses
        the laser plane (FabScan's table centre lies 0.49 mm off its plane).
    table_radius_mm : float, default 0.0
        Radius of the turntable's disc in the twin [mm], in [0, 1e5] (0 = no disc): a disc
        centred on the rotary axis whose top is the table plane (``rotary_table_z_mm``; the
        ``table_top_*``, ``table_tilt_*`` and ``table_axis_tilt_*`` keys move it); it stands still
        (rotationally symmetric about the bearing axis) unless its top is tilted, and is lit and in
        the truth like a housing board (:mod:`sim.backgrounds`).
    table_thickness_mm : float, default 10.0
        Thickness of that disc below its top [mm], in (0, 1e4].
    table_material : str, default "cardboard"
        The disc's material, a tag of ``scenes.MATERIALS``, in {"metal", "knurled-metal",
        "cardboard", "tape", "paper", "white-plastic", "marble"}.
    table_top_offset_mm : float, default 0.0
        Where the disc's top lies along the axis from the table plane, + up the axis [mm], in
        [-100, 100]: a real table's top need not be where a calibration puts its platform
        (``scheimpflug rig housing --table`` fits it, :mod:`scheimpflug.turntable_top`); the part
        stays on the table plane.
    table_tilt_deg, table_tilt_azimuth_deg : float, default 0.0
        Tilt of the disc's top to its bearing axis [deg], in [0, 10], and the direction its normal
        leans to in the table's own frame, from its x toward its y at angle 0 [deg], in [-360, 360]:
        the disc turns with the table about the axis, so its line wobbles once per turn
        (:mod:`scheimpflug.turntable_top`); 0 = a top square to the axis (the disc then stands
        still, as before).
    table_axis_tilt_deg, table_axis_tilt_azimuth_deg : float, default 0.0
        Lean of the disc's own axis (the one it turns about, through its top's centre) from the
        rotary axis [deg], in [0, 10], toward an azimuth in the table's frame at angle 0 [deg], in
        [-360, 360]: the mean plane of a real top need not be square to the calibrated axis
        (:mod:`scheimpflug.turntable_top`).  The part still turns about the rotary axis.
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
    axis_offset_mm: float = 0.0
    table_radius_mm: float = 0.0
    table_thickness_mm: float = 10.0
    table_material: str = "cardboard"
    table_top_offset_mm: float = 0.0
    table_tilt_deg: float = 0.0
    table_tilt_azimuth_deg: float = 0.0
    table_axis_tilt_deg: float = 0.0
    table_axis_tilt_azimuth_deg: float = 0.0
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


#: Material tags of the turntable's disc (``[stage] table_material``): ``scenes.MATERIALS``, which the
#: model may not import (tests/test_turntable_disc.py checks the two agree).
TABLE_MATERIALS = ("metal", "knurled-metal", "cardboard", "tape", "paper", "white-plastic", "marble")

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


#: The rig file's tables in the file's order, ``{table name: dataclass}``.
TABLES: dict[str, type] = {
    "lens": Lens,
    "laser": Laser,
    "sensor": Sensor,
    "stage": Stage,
    "environment": Environment,
    "twin": Twin,
    "chain": Chain,
}
