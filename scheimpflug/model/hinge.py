"""Hinge-rule geometry of an ideal Scheimpflug light-sheet rig (closed forms).

All functions are pure, vectorised over numpy arrays and float64.  Frames and
symbols follow DESIGN.md §2–3: the rig frame has its origin at the lens centre,
+x along the optical axis toward the object, +z up.  The laser sheet is the
vertical plane ``y = d − x·tan φ``; ``D`` is the distance along the sheet from
the object hinge H (positive in the propagation direction) and ``h`` the height
above the meridian plane.

References
----------
Paper Eqs. 1–2 (Newton), 5 (tilt), 6 (hinge line ∥ sensor), 8 (height ratio),
11–12 (calibration forms): ``../shared/seed/scheimpflug-lidar-calibration-paper.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

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
        Column and row [px], broadcast together.
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
        ``s = F²/(u − u_h) + d0`` (Eq. 11) [mm].
    h_mm : ndarray float64
        ``h = C·(v − v_h)/(u − u_h)`` (Eq. 12) [mm], positive above the
        meridian plane for ``v < v_h``.

    Notes
    -----
    At ``u = u_h`` (the image hinge) the sheet point lies at infinity: both
    outputs are NaN there, never ±inf.
    """
    inv = _inverse_or_nan(np.asarray(u_px, dtype=np.float64) - hinge_u_px)
    dv = np.asarray(v_px, dtype=np.float64) - hinge_v_px
    return F2_px_mm * inv + d0_mm, C_mm * dv * inv


def pixel_from_stage(stage_mm, h_mm, hinge_u_px: float, hinge_v_px: float, F2_px_mm: float,
                     d0_mm: float, C_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Pixel of a sheet point: the inverse of :func:`stage_from_pixel`.

    Parameters
    ----------
    stage_mm, h_mm : array_like float
        Stage coordinate along the sheet and height [mm], broadcast together.
    hinge_u_px, hinge_v_px, F2_px_mm, d0_mm, C_mm : float
        Calibration constants as in :func:`stage_from_pixel`.

    Returns
    -------
    u_px, v_px : ndarray float64
        ``u = u_h + F²/(s − d0)``, ``v = v_h + h·(u − u_h)/C`` [px]; NaN at
        ``s = d0`` (the object hinge images at infinity).
    """
    du = F2_px_mm * _inverse_or_nan(np.asarray(stage_mm, dtype=np.float64) - d0_mm)
    return hinge_u_px + du, hinge_v_px + du * np.asarray(h_mm, dtype=np.float64) / C_mm


def stage_jacobian(u_px, v_px, hinge_u_px: float, hinge_v_px: float, F2_px_mm: float,
                   C_mm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Derivatives of :func:`stage_from_pixel` with respect to the pixel.

    Parameters
    ----------
    u_px, v_px : array_like float
        Column and row [px].
    hinge_u_px, hinge_v_px, F2_px_mm, C_mm : float
        Calibration constants as in :func:`stage_from_pixel`.

    Returns
    -------
    ds_du : ndarray float64
        ``−F²/(u − u_h)²`` [mm/px].
    dh_du : ndarray float64
        ``−C·(v − v_h)/(u − u_h)²`` [mm/px].
    dh_dv : ndarray float64
        ``C/(u − u_h)`` [mm/px] (negative: rows increase downward).
    """
    inv = _inverse_or_nan(np.asarray(u_px, dtype=np.float64) - hinge_u_px)
    dv = np.asarray(v_px, dtype=np.float64) - hinge_v_px
    return -F2_px_mm * inv ** 2, -C_mm * dv * inv ** 2, C_mm * inv


def tilt_rad(focal_length_mm: float, scheimpflug_distance_mm: float, tan_phi: float) -> float:
    """Sensor tilt β to the lens plane, tan β = f / (d − f·tan φ) (paper Eq. 5) [rad]."""
    return math.atan2(focal_length_mm, scheimpflug_distance_mm - focal_length_mm * tan_phi)


@dataclass(frozen=True)
class HingeGeometry:
    """Derived geometry of an ideal rig (no misalignment, no distortion).

    Build it with :func:`hinge_geometry`; every attribute is computed from the
    rig's parameters, nothing is stored twice.
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
        """D(u) = F²/(u − u_h), distance along the sheet from the object hinge [mm] (NaN at u_h)."""
        return stage_from_pixel(u_px, self.axis_row, *self._constants())[0]

    def column_from_distance(self, distance_mm) -> np.ndarray:
        """u(D) = u_h + F²/D [px] (NaN at D = 0)."""
        return pixel_from_stage(distance_mm, 0.0, *self._constants())[0]

    def pixel_from_sheet(self, distance_mm, height_mm) -> tuple[np.ndarray, np.ndarray]:
        """Pixel (u, v) of the sheet point (D, h): u = u_h + F²/D, v = v_h + h·(u − u_h)/C [px]."""
        return pixel_from_stage(distance_mm, height_mm, *self._constants())

    def sheet_from_pixel(self, u_px, v_px) -> tuple[np.ndarray, np.ndarray]:
        """Sheet point (D, h) [mm] seen by pixel (u, v): paper Eqs. 11–12 (NaN at u = u_h)."""
        return stage_from_pixel(u_px, v_px, *self._constants())

    def rig_from_sheet(self, distance_mm, height_mm) -> np.ndarray:
        """Rig-frame point of sheet coordinates (D, h): H + D·e_prop + h·e_z, (..., 3) [mm]."""
        D = np.asarray(distance_mm, dtype=np.float64)[..., None]
        h = np.asarray(height_mm, dtype=np.float64)[..., None]
        return self.object_hinge_mm + D * self.propagation_dir + h * np.array([0.0, 0.0, 1.0])

    def sheet_from_rig(self, points_mm) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Sheet coordinates (D, h, offset) of rig points (..., 3) [mm].

        ``offset`` is the signed distance from the sheet plane along
        :attr:`sheet_normal` (positive toward the camera side).
        """
        rel = np.asarray(points_mm, dtype=np.float64) - self.object_hinge_mm
        return rel @ self.propagation_dir, rel[..., 2], rel @ self.sheet_normal

    # ------------------------------------------------------------ resolution
    def distance_resolution(self, u_px) -> np.ndarray:
        """|dD/du| = |F²|/(u − u_h)² [mm/px]."""
        ds_du, _, _ = stage_jacobian(u_px, self.axis_row, self.hinge_column, self.axis_row,
                                     self.F2_px_mm, self.C_mm)
        return np.abs(ds_du)

    def height_resolution(self, u_px) -> np.ndarray:
        """|dh/dv| = C/|u − u_h| [mm/px]."""
        _, _, dh_dv = stage_jacobian(u_px, self.axis_row, self.hinge_column, self.axis_row,
                                     self.F2_px_mm, self.C_mm)
        return np.abs(dh_dv)


def hinge_geometry(rig: Rig) -> HingeGeometry:
    """The ideal-rig :class:`HingeGeometry` of ``rig`` (misalignments ignored)."""
    return HingeGeometry(
        focal_length_mm=rig.lens.focal_length_mm,
        scheimpflug_distance_mm=rig.laser.scheimpflug_distance_mm,
        tan_phi=rig.laser.tan_phi,
        pixel_pitch_mm=rig.sensor.pixel_pitch_um * 1e-3,
        hinge_column=rig.sensor.hinge_column,
        axis_row=rig.sensor.axis_row,
    )
