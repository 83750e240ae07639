"""The light that is not the laser: a uniform diffuse environment and a flood light.

Both come from the rig's ``[environment]`` table (:class:`scheimpflug.model.rig.Environment`):

* **environment** — uniform radiance L_env = E_amb/π from every direction
  (``ambient_irradiance_w_m2`` = E_amb: the irradiance it gives an unoccluded
  surface);
* **flood light** — a square of side a, emitting uniformly (Lambertian, radiance
  L_e, one-sided) toward its aim point, the sheet point imaged at the sensor centre,
  from ``flood_distance_mm`` away in the direction (``flood_azimuth_deg``,
  ``flood_elevation_deg``) — azimuth about +z from the horizontal direction toward
  the lens centre.  L_e is set so that a surface facing the light at the aim point
  receives ``flood_irradiance_w_m2``::

      E = π·L_e·F,   F = 4·F_c(a/2, a/2, d)

  with F_c the configuration factor from a differential area to a parallel
  rectangle X × Y at distance d above one of its corners (Howell, *A Catalog of
  Radiation Heat Transfer Configuration Factors*, C-11)::

      F_c = 1/(2π)·[x/√(1+x²)·atan(y/√(1+x²)) + y/√(1+y²)·atan(x/√(1+y²))],  x = X/d, y = Y/d.

The flood light is not part of the scene's geometry: it casts no shadow of
itself and the camera does not see it.  Radiances are within the camera's band,
converted to photo-electrons at the laser's wavelength (as the ambient pass does).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from scheimpflug.errors import RenderError
from scheimpflug.model.camera import lens_centre_mm, sensor_pose, sheet_point_from_pixel
from scheimpflug.model.rig import Rig

__all__ = [
    "FloodLight",
    "corner_factor",
    "flood_aim_point_mm",
    "flood_light",
    "rectangle_irradiance_factor",
]


@dataclass(frozen=True)
class FloodLight:
    """A square area light (rig frame).

    Parameters
    ----------
    centre_mm : (3,) float
        Centre of the square [mm].
    normal : (3,) float
        Unit normal of the emitting side (toward the aim point) [-].
    e1, e2 : (3,) float
        Unit edge directions (e1 horizontal, e2 = normal × e1) [-].
    size_mm : float
        Side of the square [mm].
    radiance_w_m2_sr : float
        Emitted radiance L_e [W/(m²·sr)].
    aim_mm : (3,) float
        The aim point [mm].
    """

    centre_mm: np.ndarray
    normal: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    size_mm: float
    radiance_w_m2_sr: float
    aim_mm: np.ndarray

    @property
    def area_mm2(self) -> float:
        """Area of the square [mm²]."""
        return self.size_mm**2


def corner_factor(x_mm: float, y_mm: float, d_mm: float) -> float:
    """Configuration factor from a differential area to a parallel rectangle above one of its corners.

    Parameters
    ----------
    x_mm, y_mm : float
        Rectangle sides [mm].
    d_mm : float
        Distance between the planes [mm].

    Returns
    -------
    float
        F_c (module docstring) [-]; 1/4 for an infinite rectangle.
    """
    x, y = x_mm / d_mm, y_mm / d_mm
    ax, ay = math.sqrt(1 + x * x), math.sqrt(1 + y * y)
    return (x / ax * math.atan(y / ax) + y / ay * math.atan(x / ay)) / (2 * math.pi)


def rectangle_irradiance_factor(width_mm: float, height_mm: float, d_mm: float) -> float:
    """E/L of a uniformly emitting rectangle on a parallel surface below its centre.

    Parameters
    ----------
    width_mm, height_mm : float
        Rectangle sides [mm].
    d_mm : float
        Distance [mm].

    Returns
    -------
    float
        π·4·F_c(w/2, h/2, d) [sr]: irradiance per unit radiance.
    """
    return math.pi * 4.0 * corner_factor(0.5 * width_mm, 0.5 * height_mm, d_mm)


def flood_aim_point_mm(rig: Rig) -> np.ndarray:
    """The flood light's aim point: the sheet point imaged at the sensor centre.

    Parameters
    ----------
    rig : Rig
        The instrument.

    Returns
    -------
    (3,) float64
        Rig frame [mm].

    Raises
    ------
    RenderError
        When the sensor centre's chief ray does not meet the sheet.
    """
    pose = sensor_pose(rig)
    centre = np.array([0.5 * (pose.columns - 1), 0.5 * (pose.rows - 1)])
    aim = sheet_point_from_pixel(rig, centre, pose)
    if not np.isfinite(aim).all():
        raise RenderError("the flood light has no aim point: the sensor centre's chief ray misses the sheet")
    return aim


def flood_light(rig: Rig) -> FloodLight | None:
    """The rig's flood light (module docstring), or None when it is off.

    Parameters
    ----------
    rig : Rig
        The instrument (``[environment] flood_*``).

    Returns
    -------
    FloodLight or None
        None when ``flood_irradiance_w_m2`` is 0.

    Raises
    ------
    RenderError
        When the light has no aim point (:func:`flood_aim_point_mm`).
    """
    env = rig.environment
    if env.flood_irradiance_w_m2 == 0.0:
        return None
    aim = flood_aim_point_mm(rig)
    to_lens = lens_centre_mm(rig) - aim
    h = np.array([to_lens[0], to_lens[1], 0.0])
    h = h / np.linalg.norm(h)
    az, el = math.radians(env.flood_azimuth_deg), math.radians(env.flood_elevation_deg)
    h = np.array([math.cos(az) * h[0] - math.sin(az) * h[1], math.sin(az) * h[0] + math.cos(az) * h[1], 0.0])
    direction = math.cos(el) * h + np.array([0.0, 0.0, math.sin(el)])
    normal = -direction
    e1 = np.cross([0.0, 0.0, 1.0], normal)
    e1 = e1 / np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    a, d = env.flood_size_mm, env.flood_distance_mm
    radiance = env.flood_irradiance_w_m2 / rectangle_irradiance_factor(a, a, d)
    return FloodLight(aim + d * direction, normal, e1, e2, float(a), float(radiance), aim)
