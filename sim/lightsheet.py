"""The laser light sheet: geometry, Gaussian thickness, fan profile, power and speckle.

Model
-----
The laser origin O_l = (x_l, d − x_l·tan φ, 0) lies on the sheet ``y = d − x·tan φ``
in the meridian plane.  Inside the sheet a ray leaves O_l at fan angle α
(0 along the propagation direction e_p = (cos φ, −sin φ, 0), positive toward
+z): in-sheet direction d_s(α) = cos α·e_p + sin α·e_z, in-sheet distance r.

*Fan.*  Radiant intensity per radian of fan angle (uniform over the fan, as a
Powell-lens line generator aims for), with soft edges made by convolving the
box of full width F with a Gaussian of standard deviation σ_e::

    I(α) = P/F · ½·[erf((α + F/2)/(√2 σ_e)) − erf((α − F/2)/(√2 σ_e))]   [W/rad]

σ_e = fan_edge / 2.563 so that ``fan_edge_deg`` is the 10 %–90 % width of the
edge.  ∫ I dα = P exactly (energy conserving).

*Thickness.*  Across the sheet (along its normal n) the irradiance is Gaussian
with 1/e² half-width

    w(r) = √(w0² + θ²·(r − r_w)²)        (waist_um, waist_distance_mm, divergence_mrad)

i.e. standard deviation s(r) = w(r)/2.  The renderer represents it by a ray
ensemble: each ray has an offset x0 at the waist, x0 ~ N(0, (w0/2)²), and a
transverse angle a ~ N(0, (θ/2)²), independent; its offset at distance r,
x0 + a·(r − r_w), is then N(0, s(r)²) at *every* r — the Gaussian-beam width
law is reproduced exactly, and each ray carries a fixed share of the power,
so energy is conserved by construction.  For sampling, the same joint
Gaussian is factorised at a reference distance r_ref (where the fan ray hits
the scene): offset δ = o(r_ref) ~ N(0, s(r_ref)²) first (stratified), then
a | δ ~ N(k·δ, σ_a²) (:func:`conditional_angle`).

*Irradiance* on a surface at in-sheet distance r (closed form, used by tests
and ground truth): E = I(α)/r · exp(−o²/2s²)/(√(2π)·s) · |cos θ_i|  [W/mm²],
o the offset from the sheet plane, θ_i the incidence angle.

*Speckle* (optional, contrast C = ``speckle_contrast``): a multiplicative,
mean-1 random pattern on the sensor (laser light only).  The objective speckle
of a rough surface seen through an aperture f/N has, on the sensor, a grain
(Airy radius of the coherent PSF) of 1.22·λ·N·(1 + m), m the lateral
magnification, and an intensity correlation area A_c = (4/π)·(λ·N·(1+m))²
(Goodman, *Speckle Phenomena in Optics*, §4.6 and §5.2).  A pixel integrates
M ≈ 1 + A_pix/A_c correlation cells, which lowers the pixel-value contrast to
C/√M.  The pattern is a circular-complex Gaussian field low-passed by the
coherent transfer function (a disc of radius 1/(λ·N·(1+m)), only applied when
that is below the pixel Nyquist band), squared, normalised to mean 1, and
mixed as 1 + (C/√M)·(X − 1) (≥ 0 for C ≤ 1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import erf

from scheimpflug.model.hinge import hinge_geometry
from scheimpflug.model.rig import Rig

__all__ = [
    "LightSheet",
    "beam_half_width_mm",
    "conditional_angle",
    "fan_profile",
    "irradiance_w_mm2",
    "light_sheet",
    "radiant_intensity_w_per_rad",
    "sheet_coordinates",
    "speckle_grain_um",
    "speckle_pattern",
    "visible_fan_interval",
]

EDGE_10_90 = 2.5631031310892007  # 10–90 % width of an erf edge in units of its σ


@dataclass(frozen=True)
class LightSheet:
    """The laser sheet of a rig, in the rig frame.

    Built from a rig by :func:`light_sheet`; the model is in the module docstring.

    Parameters
    ----------
    origin_mm : (3,) float
        Laser origin O_l, rig frame [mm].
    prop_dir : (3,) float
        Unit propagation direction e_p = (cos φ, −sin φ, 0), rig frame [-].
    normal : (3,) float
        Unit sheet normal n (toward +y), rig frame [-].
    up : (3,) float
        Unit in-sheet up direction e_z = (0, 0, 1), rig frame [-].
    power_w : float
        Total power in the fan P [W].
    wavelength_nm : float
        Laser wavelength λ [nm].
    waist_mm : float
        w0, 1/e² half-thickness at the waist [mm].
    waist_distance_mm : float
        r_w, in-sheet distance of the waist from O_l [mm].
    divergence_rad : float
        θ, far-field 1/e² half-angle of the thickness [rad].
    fan_full_rad : float
        F, full fan angle [rad].
    edge_sigma_rad : float
        σ_e of the soft fan edge [rad] (``fan_edge_deg`` / 2.563).
    speckle_contrast : float
        Speckle contrast C before pixel integration [-].
    """

    origin_mm: np.ndarray
    prop_dir: np.ndarray
    normal: np.ndarray
    up: np.ndarray
    power_w: float
    wavelength_nm: float
    waist_mm: float
    waist_distance_mm: float
    divergence_rad: float
    fan_full_rad: float
    edge_sigma_rad: float
    speckle_contrast: float


def light_sheet(rig: Rig) -> LightSheet:
    """The light sheet of a rig.

    The sheet's geometry (propagation direction, normal) comes from
    :func:`scheimpflug.model.hinge.hinge_geometry`; power, wavelength,
    thickness and fan from ``rig.laser``, converted to SI-like units
    (mW → W, µm → mm, mrad → rad, deg → rad).

    Parameters
    ----------
    rig : Rig
        The rig; its laser origin sits at ``x = laser.origin_x_mm`` on the
        sheet ``y = d − x·tan φ`` in the meridian plane ``z = 0``.

    Returns
    -------
    LightSheet
        The sheet in the rig frame.
    """
    g = hinge_geometry(rig)
    las = rig.laser
    x = las.origin_x_mm
    origin = np.array([x, las.scheimpflug_distance_mm - x * las.tan_phi, 0.0])
    return LightSheet(
        origin_mm=origin, prop_dir=g.propagation_dir, normal=g.sheet_normal,
        up=np.array([0.0, 0.0, 1.0]), power_w=las.power_mw * 1e-3,
        wavelength_nm=las.wavelength_nm, waist_mm=las.waist_um * 1e-3,
        waist_distance_mm=las.waist_distance_mm, divergence_rad=las.divergence_mrad * 1e-3,
        fan_full_rad=math.radians(las.fan_angle_deg),
        edge_sigma_rad=math.radians(las.fan_edge_deg) / EDGE_10_90,
        speckle_contrast=las.speckle_contrast)


def beam_half_width_mm(sheet: LightSheet, r_mm) -> np.ndarray:
    """1/e² half-thickness of the sheet at an in-sheet distance.

    Parameters
    ----------
    sheet : LightSheet
        The light sheet.
    r_mm : float or array_like
        In-sheet distance r from the laser origin [mm].

    Returns
    -------
    ndarray
        w(r) [mm], same shape as ``r_mm``.

    Notes
    -----
    Gaussian-beam width law w(r) = √(w0² + θ²·(r − r_w)²).
    """
    dr = np.asarray(r_mm, dtype=np.float64) - sheet.waist_distance_mm
    return np.sqrt(sheet.waist_mm**2 + (sheet.divergence_rad * dr) ** 2)


def fan_profile(sheet: LightSheet, alpha_rad) -> np.ndarray:
    """Relative fan profile of the sheet.

    Parameters
    ----------
    sheet : LightSheet
        The light sheet.
    alpha_rad : float or array_like
        Fan angle α (0 along the propagation direction, positive toward +z) [rad].

    Returns
    -------
    ndarray
        g(α) ∈ [0, 1] [-], same shape as ``alpha_rad``.

    Notes
    -----
    A box of full width F convolved with a Gaussian of standard deviation σ_e:
    g(α) = ½·[erf((α + F/2)/(√2 σ_e)) − erf((α − F/2)/(√2 σ_e))], so that
    ∫ g dα = F; a hard box (|α| ≤ F/2) when σ_e = 0.
    """
    a = np.asarray(alpha_rad, dtype=np.float64)
    half = 0.5 * sheet.fan_full_rad
    if sheet.edge_sigma_rad == 0.0:
        return (np.abs(a) <= half).astype(np.float64)
    k = 1.0 / (math.sqrt(2.0) * sheet.edge_sigma_rad)
    return 0.5 * (erf((a + half) * k) - erf((a - half) * k))


def radiant_intensity_w_per_rad(sheet: LightSheet, alpha_rad) -> np.ndarray:
    """Power per radian of fan angle.

    Parameters
    ----------
    sheet : LightSheet
        The light sheet.
    alpha_rad : float or array_like
        Fan angle α [rad].

    Returns
    -------
    ndarray
        I(α) = P·g(α)/F [W/rad], same shape as ``alpha_rad``; ∫ I dα = P.
    """
    return sheet.power_w * fan_profile(sheet, alpha_rad) / sheet.fan_full_rad


def sheet_coordinates(sheet: LightSheet, points_mm) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Coordinates of points relative to the sheet.

    Parameters
    ----------
    sheet : LightSheet
        The light sheet.
    points_mm : (..., 3) array_like
        Points, rig frame [mm].

    Returns
    -------
    r_mm : (...) ndarray
        In-sheet distance from the laser origin (of the point's projection on
        the sheet plane) [mm].
    alpha_rad : (...) ndarray
        Fan angle α [rad].
    offset_mm : (...) ndarray
        Signed offset o from the sheet plane along its normal [mm].
    """
    rel = np.asarray(points_mm, dtype=np.float64) - sheet.origin_mm
    along, height, offset = rel @ sheet.prop_dir, rel @ sheet.up, rel @ sheet.normal
    return np.hypot(along, height), np.arctan2(height, along), offset


def irradiance_w_mm2(sheet: LightSheet, points_mm, normals=None) -> np.ndarray:
    """Laser irradiance at points, ignoring occlusion.

    Parameters
    ----------
    sheet : LightSheet
        The light sheet.
    points_mm : (..., 3) array_like
        Points, rig frame [mm].
    normals : (..., 3) array_like, optional
        Surface normals at the points, rig frame (need not be unit); the
        cosine of incidence is applied.  None: surface perpendicular to the beam.

    Returns
    -------
    (...) ndarray
        Irradiance E [W/mm²].

    Notes
    -----
    E = I(α)/r · exp(−o²/2s²)/(√(2π)·s) · |cos θ_i| with s = w(r)/2, the
    closed form of the module docstring.  Small-angle model (θ, offsets ≪ 1).
    """
    r, alpha, o = sheet_coordinates(sheet, points_mm)
    s = 0.5 * beam_half_width_mm(sheet, r)
    e = radiant_intensity_w_per_rad(sheet, alpha) / r * np.exp(-0.5 * (o / s) ** 2) \
        / (math.sqrt(2 * math.pi) * s)
    if normals is None:
        return e
    d = np.cos(alpha)[..., None] * sheet.prop_dir + np.sin(alpha)[..., None] * sheet.up
    n = np.asarray(normals, dtype=np.float64)
    return e * np.abs(np.sum(d * n, axis=-1)) / np.linalg.norm(n, axis=-1)


def conditional_angle(sheet: LightSheet, r_ref_mm) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Factorise the sheet's ray ensemble at a reference distance.

    Parameters
    ----------
    sheet : LightSheet
        The light sheet.
    r_ref_mm : float or array_like
        Reference in-sheet distance r_ref (where the fan ray hits the scene) [mm].

    Returns
    -------
    s_ref_mm : ndarray
        Standard deviation of the offset at r_ref [mm].
    k_rad_per_mm : ndarray
        Slope of the conditional mean angle [rad/mm].
    sigma_a_rad : ndarray
        Conditional standard deviation of the transverse angle [rad].

    Notes
    -----
    Offset at r_ref: δ ~ N(0, s_ref²); angle given δ: a ~ N(k·δ, σ_a²), where with
    Δ = r_ref − r_w: s_ref = w(r_ref)/2, k = θ²Δ/w(r_ref)², σ_a = (θ/2)·w0/w(r_ref).
    This is the same joint Gaussian as offset at the waist x0 ~ N(0, (w0/2)²)
    and angle a ~ N(0, (θ/2)²), independent.
    """
    w = beam_half_width_mm(sheet, r_ref_mm)
    delta = np.asarray(r_ref_mm, dtype=np.float64) - sheet.waist_distance_mm
    theta = sheet.divergence_rad
    return 0.5 * w, theta**2 * delta / w**2, 0.5 * theta * sheet.waist_mm / w


def visible_fan_interval(sheet: LightSheet, sheet_points_mm, margin_rad: float) -> tuple[float, float]:
    """Fan-angle interval that covers the given points.

    Used to aim the light rays at what the camera can see (e.g. the sensor
    border imaged onto the sheet).

    Parameters
    ----------
    sheet : LightSheet
        The light sheet.
    sheet_points_mm : (..., 3) array_like
        Points, rig frame [mm].
    margin_rad : float
        Widening of the interval on both sides [rad].

    Returns
    -------
    alpha_min_rad : float
        Lower fan angle [rad].
    alpha_max_rad : float
        Upper fan angle [rad].

    Notes
    -----
    The interval is clipped to the fan, ±(F/2 + 4σ_e); it is that whole
    range when a point is not finite or lies at or behind the laser origin
    along the propagation direction.
    """
    half = 0.5 * sheet.fan_full_rad + 4.0 * sheet.edge_sigma_rad
    pts = np.asarray(sheet_points_mm, dtype=np.float64).reshape(-1, 3)
    rel = pts - sheet.origin_mm
    along = rel @ sheet.prop_dir
    if not np.isfinite(pts).all() or (along <= 0).any():
        return float(-half), float(half)
    alpha = np.arctan2(rel @ sheet.up, along)
    return float(max(-half, alpha.min() - margin_rad)), float(min(half, alpha.max() + margin_rad))


def speckle_grain_um(wavelength_nm: float, f_number: float, magnification: float) -> float:
    """Speckle grain on the sensor.

    Parameters
    ----------
    wavelength_nm : float
        Laser wavelength λ [nm].
    f_number : float
        Aperture N [-].
    magnification : float
        Lateral magnification m (its absolute value is used) [-].

    Returns
    -------
    float
        Grain 1.22·λ·N·(1 + |m|), the coherent Airy radius [µm].

    References
    ----------
    .. [1] J. W. Goodman, *Speckle Phenomena in Optics*, §4.6 and §5.2.
    """
    return 1.22 * wavelength_nm * 1e-3 * f_number * (1.0 + abs(magnification))


def speckle_pattern(shape: tuple[int, int], contrast: float, grain_px: float,
                    seed: int) -> np.ndarray:
    """Mean-1 multiplicative speckle pattern, pixel-integrated.

    Parameters
    ----------
    shape : tuple of int
        ``(rows, columns)`` of the pattern [px].
    contrast : float
        Speckle contrast C before pixel integration, 0 … 1 [-].
    grain_px : float
        Grain size 1.22·λ·N_eff on the sensor [px].
    seed : int
        Seed of the pattern (same seed → same pattern).

    Returns
    -------
    (rows, columns) float64
        1 + (C/√M)·(X − 1), X the low-passed speckle intensity normalised to
        mean 1 (≥ 0 for C ≤ 1); all ones when ``contrast`` is 0.

    Notes
    -----
    See the module docstring: pixel-value contrast C/√M, M = 1 + 1/A_c,
    A_c = (4/π)·(grain_px/1.22)² [px²].  The circular-complex Gaussian field
    is low-passed by a disc of radius 1.22/grain_px [cycles/px] only when
    that is below the pixel band (√2/2 cycles/px).

    References
    ----------
    .. [1] J. W. Goodman, *Speckle Phenomena in Optics*, §4.6 and §5.2.
    """
    if contrast == 0.0:
        return np.ones(shape)
    rng = np.random.default_rng(seed)
    field = rng.standard_normal(shape) + 1j * rng.standard_normal(shape)
    cutoff = 1.22 / grain_px  # coherent cut-off [cycles/px]
    power = 2.0
    if cutoff < 0.5 * math.sqrt(2.0):
        fu = np.fft.fftfreq(shape[1])[None, :]
        fv = np.fft.fftfreq(shape[0])[:, None]
        h = (fu**2 + fv**2 <= cutoff**2).astype(np.float64)
        field = np.fft.ifft2(np.fft.fft2(field) * h)
        power = 2.0 * h.mean()
    x = (field.real**2 + field.imag**2) / power
    a_c = 4.0 / math.pi * (grain_px / 1.22) ** 2
    c_pix = contrast / math.sqrt(1.0 + 1.0 / a_c)
    return 1.0 + c_pix * (x - 1.0)
