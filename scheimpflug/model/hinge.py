"""Hinge-rule geometry of an ideal Scheimpflug light-sheet rig (closed forms).

All functions are pure, vectorised over numpy arrays and float64.  Frames and
symbols follow docs/explanation/design-notes.md §2–3: the rig frame has its origin at the lens centre,
+x along the optical axis toward the object, +z up.  The laser sheet is the
vertical plane ``y = d − x·tan φ``; ``D`` is the distance along the sheet from
the object hinge H (positive in the propagation direction) and ``h`` the height
above the meridian plane.

References
----------
Paper Eqs. 1–2 (Newton), 5 (tilt), 6 (hinge line ∥ sensor), 8 (height ratio),
11–12 (calibration forms): the seed paper (docs/citing.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from scheimpflug.model._checks import check_broadcast, check_last_dim

if TYPE_CHECKING:  # the rig imports this module (its stage plan needs the closed forms)
    from scheimpflug.model.rig import Rig

__all__ = [
    "HingeGeometry",
    "hinge_geometry",
    "pixel_from_stage",
    "stage_from_pixel",
    "stage_jacobian",
    "tilt_rad",
]


# ---------------------------------------------------------------- paper Eqs. 11–12, once


def _inverse_or_nan(x: np.ndarray) -> np.ndarray:
    """1/x, NaN where x = 0 (a point at infinity has no finite image or sheet point)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(x != 0, 1.0 / np.where(x != 0, x, 1.0), np.nan)


def stage_from_pixel(u_px, v_px, hinge_u_px: float, hinge_v_px: float, F2_px_mm: float,
                     d0_mm: float, C_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Stage coordinate and height of a pixel on the light sheet (paper Eqs. 11–12).

    The only implementation of the calibration relations; everything that maps
    pixels to the sheet calls it (with ``d0_mm = 0`` for the distance ``D``
    from the object hinge).

    Parameters
    ----------
    u_px, v_px : array_like float
        Column and row on the sensor [px], shapes that broadcast together.
    hinge_u_px, hinge_v_px : float
        Image hinge (u_h, v_h) [px].
    F2_px_mm : float
        Distance constant F² [px·mm] (negative: columns increase toward the hinge).
    d0_mm : float
        Stage coordinate of the object hinge [mm].
    C_mm : float
        Height constant C [mm].

    Returns
    -------
    stage_mm : ndarray float64
        ``s = F²/(u − u_h) + d0`` (paper Eq. 11), the stage coordinate of the
        sheet point [mm], broadcast shape of ``u_px`` and ``v_px``.
    h_mm : ndarray float64
        ``h = C·(v − v_h)/(u − u_h)`` (paper Eq. 12), the height above the
        meridian plane [mm], positive for ``v < v_h``.

    Raises
    ------
    ValueError
        If ``u_px`` and ``v_px`` do not broadcast together.

    Notes
    -----
    At ``u = u_h`` (the image hinge) the sheet point lies at infinity: both
    outputs are NaN there, never ±inf.

    Examples
    --------
    The paper's calibration (Eqs. 11–12 with its constants): its first plate
    frame, at column 97 and stage 0, and a point at the sensor's centre column.

    >>> s, h = stage_from_pixel([97.0, 608.0], [700.0, 500.0], 3196.0, 771.0, -1.446e6, -466.0, 145.91)
    >>> s.round(2).tolist(), h.round(3).tolist()
    ([0.6, 92.73], [3.343, 15.279])
    """
    u, v = check_broadcast(u_px=u_px, v_px=v_px)
    inv = _inverse_or_nan(u - hinge_u_px)
    dv = v - hinge_v_px
    return F2_px_mm * inv + d0_mm, C_mm * dv * inv


def pixel_from_stage(stage_mm, h_mm, hinge_u_px: float, hinge_v_px: float, F2_px_mm: float,
                     d0_mm: float, C_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Pixel of a sheet point: the inverse of :func:`stage_from_pixel` (paper Eqs. 11–12).

    Parameters
    ----------
    stage_mm, h_mm : array_like float
        Stage coordinate along the sheet and height above the meridian plane
        [mm], shapes that broadcast together.
    hinge_u_px, hinge_v_px, F2_px_mm, d0_mm, C_mm : float
        Calibration constants as in :func:`stage_from_pixel` [px, px, px·mm, mm, mm].

    Returns
    -------
    u_px, v_px : ndarray float64
        ``u = u_h + F²/(s − d0)``, ``v = v_h + h·(u − u_h)/C`` [px]; NaN at
        ``s = d0`` (the object hinge images at infinity).

    Raises
    ------
    ValueError
        If ``stage_mm`` and ``h_mm`` do not broadcast together.

    Examples
    --------
    The round trip through :func:`stage_from_pixel` returns the pixel:

    >>> cal = (3196.0, 771.0, -1.446e6, -466.0, 145.91)
    >>> u, v = pixel_from_stage(*stage_from_pixel(608.0, 500.0, *cal), *cal)
    >>> round(float(u), 9), round(float(v), 9)
    (608.0, 500.0)
    """
    s, h = check_broadcast(stage_mm=stage_mm, h_mm=h_mm)
    du = F2_px_mm * _inverse_or_nan(s - d0_mm)
    return hinge_u_px + du, hinge_v_px + du * h / C_mm


def stage_jacobian(u_px, v_px, hinge_u_px: float, hinge_v_px: float, F2_px_mm: float,
                   C_mm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Derivatives of :func:`stage_from_pixel` with respect to the pixel.

    Parameters
    ----------
    u_px, v_px : array_like float
        Column and row on the sensor [px], shapes that broadcast together.
    hinge_u_px, hinge_v_px, F2_px_mm, C_mm : float
        Calibration constants as in :func:`stage_from_pixel` [px, px, px·mm, mm].

    Returns
    -------
    ds_du : ndarray float64
        ``−F²/(u − u_h)²`` [mm/px].
    dh_du : ndarray float64
        ``−C·(v − v_h)/(u − u_h)²`` [mm/px].
    dh_dv : ndarray float64
        ``C/(u − u_h)`` [mm/px] (negative: rows increase downward).

    Raises
    ------
    ValueError
        If ``u_px`` and ``v_px`` do not broadcast together.

    Notes
    -----
    All three are NaN at ``u = u_h``, like :func:`stage_from_pixel`.
    """
    u, v = check_broadcast(u_px=u_px, v_px=v_px)
    inv = _inverse_or_nan(u - hinge_u_px)
    dv = v - hinge_v_px
    return -F2_px_mm * inv ** 2, -C_mm * dv * inv ** 2, C_mm * inv


def tilt_rad(focal_length_mm: float, scheimpflug_distance_mm: float, tan_phi: float) -> float:
    """Sensor tilt β to the lens plane (paper Eq. 5).

    Parameters
    ----------
    focal_length_mm : float
        Focal length f [mm].
    scheimpflug_distance_mm : float
        Distance d from the lens centre to the Scheimpflug line [mm].
    tan_phi : float
        Tangent of the sheet angle φ to the optical axis [-].

    Returns
    -------
    float
        β = atan2(f, d − f·tan φ), i.e. tan β = f / (d − f·tan φ) [rad].

    Examples
    --------
    The paper's rig (f = 55 mm, d = 150 mm, tan φ = 0.2075; it measured tan β = 0.3969):

    >>> import math
    >>> beta = tilt_rad(55.0, 150.0, 0.2075)
    >>> round(math.degrees(beta), 4), round(math.tan(beta), 5)
    (21.6462, 0.39686)
    """
    return math.atan2(focal_length_mm, scheimpflug_distance_mm - focal_length_mm * tan_phi)


@dataclass(frozen=True)
class HingeGeometry:
    """Derived geometry of an ideal rig (no misalignment, no distortion).

    Build it with :func:`hinge_geometry`; every property is computed from the
    six parameters below, nothing is stored twice.  Points are in the rig
    frame (origin at the lens centre, +x along the optical axis toward the
    object, +z up); sheet coordinates are (D, h): distance along the sheet
    from the object hinge H and height above the meridian plane.

    Parameters
    ----------
    focal_length_mm : float
        Focal length f [mm].
    scheimpflug_distance_mm : float
        Distance d from the lens centre to the Scheimpflug line [mm].
    tan_phi : float
        Tangent of the sheet angle φ to the optical axis [-].
    pixel_pitch_mm : float
        Pixel pitch p [mm].
    hinge_column : float
        Column u_h of the image hinge [px].
    axis_row : float
        Row v_h of the meridian plane [px].
    """

    focal_length_mm: float
    scheimpflug_distance_mm: float
    tan_phi: float
    pixel_pitch_mm: float
    hinge_column: float
    axis_row: float

    # ------------------------------------------------------------ angles
    @property
    def beta_rad(self) -> float:
        """Sensor tilt β (paper Eq. 5) [rad]."""
        return tilt_rad(self.focal_length_mm, self.scheimpflug_distance_mm, self.tan_phi)

    @property
    def tilt_deg(self) -> float:
        """Sensor tilt β [deg]."""
        return math.degrees(self.beta_rad)

    @property
    def tan_beta(self) -> float:
        """Tangent of the sensor tilt, tan β = f / (d − f·tan φ) (paper Eq. 5) [-]."""
        return self.focal_length_mm / (self.scheimpflug_distance_mm - self.focal_length_mm * self.tan_phi)

    @property
    def phi_rad(self) -> float:
        """Sheet angle φ to the optical axis [rad]."""
        return math.atan(self.tan_phi)

    # ------------------------------------------------------------ points and directions
    @property
    def object_hinge_mm(self) -> np.ndarray:
        """Object hinge H = (f, d − f·tan φ, 0): the sheet on the front focal plane, (3,) [mm]."""
        f = self.focal_length_mm
        return np.array([f, self.scheimpflug_distance_mm - f * self.tan_phi, 0.0])

    @property
    def image_hinge_mm(self) -> np.ndarray:
        """Image hinge H' = (−f, f·tan φ, 0): the sensor on the back focal plane, (3,) [mm]."""
        f = self.focal_length_mm
        return np.array([-f, f * self.tan_phi, 0.0])

    @property
    def scheimpflug_point_mm(self) -> np.ndarray:
        """Scheimpflug point O' = (0, d, 0) where sheet, lens plane and sensor meet, (3,) [mm]."""
        return np.array([0.0, self.scheimpflug_distance_mm, 0.0])

    @property
    def propagation_dir(self) -> np.ndarray:
        """Unit propagation direction of the sheet (cos φ, −sin φ, 0), (3,)."""
        phi = self.phi_rad
        return np.array([math.cos(phi), -math.sin(phi), 0.0])

    @property
    def sheet_normal(self) -> np.ndarray:
        """Unit normal of the sheet (sin φ, cos φ, 0), pointing to +y (the camera side), (3,)."""
        phi = self.phi_rad
        return np.array([math.sin(phi), math.cos(phi), 0.0])

    @property
    def sensor_u_dir(self) -> np.ndarray:
        """Unit direction of increasing column on the ideal sensor, (sin β, cos β, 0), (3,)."""
        b = self.beta_rad
        return np.array([math.sin(b), math.cos(b), 0.0])

    # ------------------------------------------------------------ calibration constants
    @property
    def F2_px_mm(self) -> float:
        """F² = −f² / (p·cos φ·sin β), so that D = F²/(u − u_h) (paper Eq. 11) [px·mm]."""
        f, p = self.focal_length_mm, self.pixel_pitch_mm
        return -f * f / (p * math.cos(self.phi_rad) * math.sin(self.beta_rad))

    @property
    def C_mm(self) -> float:
        """C = f / sin β, so that h = C·(v − v_h)/(u − u_h) (paper Eq. 12) [mm]."""
        return self.focal_length_mm / math.sin(self.beta_rad)

    # ------------------------------------------------------------ sheet ↔ pixel (closed forms)
    def _constants(self) -> tuple[float, float, float, float, float]:
        return self.hinge_column, self.axis_row, self.F2_px_mm, 0.0, self.C_mm

    def distance_from_column(self, u_px) -> np.ndarray:
        """Distance along the sheet from the object hinge seen by a column (paper Eq. 11).

        Parameters
        ----------
        u_px : array_like float
            Column [px].

        Returns
        -------
        ndarray float64
            D(u) = F²/(u − u_h) [mm], shape of ``u_px``; NaN at u = u_h.
        """
        return stage_from_pixel(u_px, self.axis_row, *self._constants())[0]

    def column_from_distance(self, distance_mm) -> np.ndarray:
        """Column that sees a distance along the sheet: the inverse of :meth:`distance_from_column`.

        Parameters
        ----------
        distance_mm : array_like float
            Distance D along the sheet from the object hinge [mm].

        Returns
        -------
        ndarray float64
            u(D) = u_h + F²/D [px], shape of ``distance_mm``; NaN at D = 0.
        """
        return pixel_from_stage(distance_mm, 0.0, *self._constants())[0]

    def pixel_from_sheet(self, distance_mm, height_mm) -> tuple[np.ndarray, np.ndarray]:
        """Pixel of a sheet point (paper Eqs. 11–12, inverted).

        Parameters
        ----------
        distance_mm, height_mm : array_like float
            Sheet coordinates (D, h) [mm], shapes that broadcast together.

        Returns
        -------
        u_px, v_px : ndarray float64
            u = u_h + F²/D, v = v_h + h·(u − u_h)/C [px]; NaN at D = 0.
        """
        return pixel_from_stage(distance_mm, height_mm, *self._constants())

    def sheet_from_pixel(self, u_px, v_px) -> tuple[np.ndarray, np.ndarray]:
        """Sheet point seen by a pixel (paper Eqs. 11–12).

        Parameters
        ----------
        u_px, v_px : array_like float
            Column and row [px], shapes that broadcast together.

        Returns
        -------
        distance_mm, height_mm : ndarray float64
            Sheet coordinates (D, h) [mm]; NaN at u = u_h.
        """
        return stage_from_pixel(u_px, v_px, *self._constants())

    def rig_from_sheet(self, distance_mm, height_mm) -> np.ndarray:
        """Rig-frame point of sheet coordinates.

        Parameters
        ----------
        distance_mm, height_mm : array_like float
            Sheet coordinates (D, h) [mm], shapes that broadcast together.

        Returns
        -------
        (..., 3) ndarray float64
            H + D·e_prop + h·e_z in the rig frame [mm], with ``...`` the
            broadcast shape of the inputs.

        Raises
        ------
        ValueError
            If ``distance_mm`` and ``height_mm`` do not broadcast together.
        """
        D, h = (a[..., None] for a in check_broadcast(distance_mm=distance_mm, height_mm=height_mm))
        return self.object_hinge_mm + D * self.propagation_dir + h * np.array([0.0, 0.0, 1.0])

    def sheet_from_rig(self, points_mm) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Sheet coordinates of rig-frame points.

        Parameters
        ----------
        points_mm : (..., 3) array_like float
            Points in the rig frame [mm].

        Returns
        -------
        distance_mm : (...) ndarray float64
            D, along :attr:`propagation_dir` from the object hinge [mm].
        height_mm : (...) ndarray float64
            h, the z coordinate [mm].
        offset_mm : (...) ndarray float64
            Signed distance from the sheet plane along :attr:`sheet_normal`
            (positive toward the camera side) [mm].

        Raises
        ------
        ValueError
            If ``points_mm`` is not of shape ``(..., 3)``.
        """
        rel = check_last_dim("points_mm", points_mm, 3) - self.object_hinge_mm
        return rel @ self.propagation_dir, rel[..., 2], rel @ self.sheet_normal

    # ------------------------------------------------------------ resolution
    def distance_resolution(self, u_px) -> np.ndarray:
        """Distance resolution along the sheet per column step.

        Parameters
        ----------
        u_px : array_like float
            Column [px].

        Returns
        -------
        ndarray float64
            |dD/du| = |F²|/(u − u_h)² [mm/px], shape of ``u_px``.
        """
        ds_du, _, _ = stage_jacobian(u_px, self.axis_row, self.hinge_column, self.axis_row,
                                     self.F2_px_mm, self.C_mm)
        return np.abs(ds_du)

    def height_resolution(self, u_px) -> np.ndarray:
        """Height resolution per row step.

        Parameters
        ----------
        u_px : array_like float
            Column [px].

        Returns
        -------
        ndarray float64
            |dh/dv| = C/|u − u_h| [mm/px], shape of ``u_px``.
        """
        _, _, dh_dv = stage_jacobian(u_px, self.axis_row, self.hinge_column, self.axis_row,
                                     self.F2_px_mm, self.C_mm)
        return np.abs(dh_dv)


def hinge_geometry(rig: Rig) -> HingeGeometry:
    """The ideal-rig geometry of a rig (misalignments and distortion ignored).

    Parameters
    ----------
    rig : Rig
        The instrument.

    Returns
    -------
    HingeGeometry
        Built from the lens focal length, the laser's d and tan φ, the pixel
        pitch, the hinge column and the axis row.
    """
    return HingeGeometry(
        focal_length_mm=rig.lens.focal_length_mm,
        scheimpflug_distance_mm=rig.laser.scheimpflug_distance_mm,
        tan_phi=rig.laser.tan_phi,
        pixel_pitch_mm=rig.sensor.pixel_pitch_um * 1e-3,
        hinge_column=rig.sensor.hinge_column,
        axis_row=rig.sensor.axis_row,
    )
