"""The working volume of a rig: the part of the sheet its sensor sees and its laser lights.

Working volume (ideal rig: no misalignment, no distortion)
----------------------------------------------------------
In sheet coordinates (D along the sheet from the object hinge, h above the
meridian plane), paper Eqs. 11–12 make the view a wedge from the hinge: the
sensor's columns ``m … N_u − 1 − m`` see ``D_near … D_far``, and at distance D
the rows ``m − ½ … N_v − ½ − m`` see

    h_top(D) = C·(v_h − m + ½)·D/|F²|,   h_bottom(D) = C·(v_h − N_v + ½ + m)·D/|F²|

(``m`` a margin in pixels).  The laser lights ``|h| ≤ tan(F/2 − e)·(D − D_l)``
(fan F, soft edge e, laser origin at D_l); the working volume is the
intersection.  Its top is concave and its bottom convex in D, so a part that
spans ``D_a − R … D_a + R`` is in view at every angle iff it is at both ends.

Besides the volume (:func:`working_volume`, :func:`calibration_volume`,
:func:`plate_interval_mm`), the light along the sheet that the rules of
:mod:`scheimpflug.model.plan` use: the laser's distance, the sheet's
thickness, the stripe's width and a white surface's signal.  Importable from
:mod:`scheimpflug.model.plan` too.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from scheimpflug.model.hinge import hinge_geometry

if TYPE_CHECKING:
    from scheimpflug.model.assembly import Rig

__all__ = [
    "EDGE_MARGIN_ROWS",
    "STRIPE_MARGIN_COLUMNS",
    "WorkingVolume",
    "bisect_boundary",
    "calibration_volume",
    "lambertian_peak_electrons_per_ms",
    "laser_distance_mm",
    "laser_fan",
    "plate_interval_mm",
    "sheet_half_width_mm",
    "stripe_sigma_px",
    "working_volume",
]

EDGE_MARGIN_ROWS = 24        # rows between a plate edge and the sensor border (edge finder: 18) [px]
STRIPE_MARGIN_COLUMNS = 8    # columns between a plate stripe and the sensor's ends (cog window ±7) [px]
_GRID = 2001                 # samples of D for the interval searches [-]


# ---------------------------------------------------------------- the working volume


@dataclass(frozen=True)
class WorkingVolume:
    """The part of the sheet that a rig sees and lights, in sheet coordinates (D, h).

    Parameters
    ----------
    near_mm, far_mm : float
        Distances D from the object hinge seen by the first and last usable
        columns [mm].
    top_slope, bottom_slope : float
        The sensor's top and bottom rows see ``h = slope·D`` [-].
    fan_origin_mm : float
        D of the laser origin (negative: before the hinge) [mm].
    fan_tan : float
        Tangent of the usable half fan angle [-].
    """

    near_mm: float
    far_mm: float
    top_slope: float
    bottom_slope: float
    fan_origin_mm: float
    fan_tan: float

    def top_mm(self, distance_mm):
        """Highest height in view at distance D.

        Parameters
        ----------
        distance_mm : array_like float
            D from the object hinge [mm].

        Returns
        -------
        ndarray float64
            ``min(top_slope·D, fan_tan·(D − D_l))`` [mm].
        """
        D = np.asarray(distance_mm, dtype=np.float64)
        return np.minimum(self.top_slope * D, self.fan_tan * (D - self.fan_origin_mm))

    def bottom_mm(self, distance_mm):
        """Lowest height in view at distance D.

        Parameters
        ----------
        distance_mm : array_like float
            D from the object hinge [mm].

        Returns
        -------
        ndarray float64
            ``max(bottom_slope·D, −fan_tan·(D − D_l))`` [mm].
        """
        D = np.asarray(distance_mm, dtype=np.float64)
        return np.maximum(self.bottom_slope * D, -self.fan_tan * (D - self.fan_origin_mm))

    def grid(self, n: int = _GRID) -> np.ndarray:
        """Distances sampling the depth range.

        Parameters
        ----------
        n : int
            Number of samples.

        Returns
        -------
        ndarray float64, shape (n,)
            Evenly spaced D from ``near_mm`` to ``far_mm`` [mm].
        """
        return np.linspace(self.near_mm, self.far_mm, n)


def working_volume(rig: Rig, margin_rows: float = 0.0,
                   margin_columns: float | tuple[float, float] = 0.0) -> WorkingVolume:
    """The working volume of a rig's ideal geometry, inside pixel margins.

    Parameters
    ----------
    rig : Rig
        The rig; only its lens, laser and sensor tables are read.
    margin_rows : float
        Rows kept free at the top and bottom (capped at a sixth of the
        sensor so that a small or binned sensor keeps a view) [px].
    margin_columns : float or tuple of float
        Columns kept free at the near (column 0) and far ends, one value for
        both or a (near, far) pair (capped at a sixth of the sensor) [px].

    Returns
    -------
    WorkingVolume
        The volume (module docstring).
    """
    g = hinge_geometry(rig)
    s = rig.sensor
    mr = min(float(margin_rows), s.rows / 6.0)
    mc = np.broadcast_to(np.asarray(margin_columns, dtype=np.float64), (2,))
    mc = np.minimum(mc, s.columns / 6.0)
    near, far = (float(x) for x in g.distance_from_column([mc[0], s.columns - 1.0 - mc[1]]))
    k = g.C_mm / abs(g.F2_px_mm)
    origin, fan_tan = laser_fan(rig)
    return WorkingVolume(near_mm=near, far_mm=far, top_slope=k * (s.axis_row - mr + 0.5),
                         bottom_slope=k * (s.axis_row - s.rows + 0.5 + mr),
                         fan_origin_mm=origin, fan_tan=fan_tan)


def laser_fan(rig: Rig) -> tuple[float, float]:
    """Where the laser's fan starts on the sheet and how wide it lights.

    Parameters
    ----------
    rig : Rig
        The rig (its lens focal length and laser keys).

    Returns
    -------
    origin_mm : float
        D of the laser origin from the object hinge (negative: before it) [mm].
    fan_tan : float
        tan(F/2 − e), the usable half fan (at least F/4): the laser lights
        ``|h| ≤ fan_tan·(D − origin_mm)`` [-].
    """
    laser = rig.laser
    half_fan = math.radians(0.5 * laser.fan_angle_deg - laser.fan_edge_deg)
    half_fan = max(half_fan, math.radians(0.25 * laser.fan_angle_deg))
    origin = (laser.origin_x_mm - rig.lens.focal_length_mm) * math.hypot(1.0, laser.tan_phi)
    return origin, math.tan(half_fan)


def calibration_volume(rig: Rig) -> WorkingVolume:
    """The working volume where a calibration plate's stripe and both edges can be measured.

    Parameters
    ----------
    rig : Rig
        The rig; its laser's ``waist_distance_mm`` must be set.

    Returns
    -------
    WorkingVolume
        :data:`EDGE_MARGIN_ROWS` rows free at the top and bottom; at each end
        of the columns :data:`STRIPE_MARGIN_COLUMNS` or, for a wider stripe
        there, ⌈3σ⌉ + 2 columns (:func:`stripe_sigma_px`: the detector's
        window must fit on the sensor).
    """
    ends = hinge_geometry(rig).distance_from_column([0.0, rig.sensor.columns - 1.0])
    margins = tuple(max(STRIPE_MARGIN_COLUMNS, math.ceil(3.0 * stripe_sigma_px(rig, float(D))) + 2)
                    for D in ends)
    return working_volume(rig, EDGE_MARGIN_ROWS, margins)


def bisect_boundary(cond, a: float, b: float, iters: int = 60) -> float:
    """The boundary between ``a`` (where ``cond`` holds) and ``b`` (where it fails).

    Parameters
    ----------
    cond : callable
        ``cond(x) -> bool``.
    a, b : float
        A point where ``cond`` holds and one where it fails [any unit].
    iters : int, default 60
        Halvings of the interval [-].

    Returns
    -------
    float
        The last point found where ``cond`` holds (within ``|b − a|·2⁻ⁱᵗᵉʳˢ`` of the boundary).
    """
    for _ in range(iters):
        m = 0.5 * (a + b)
        if cond(m):
            a = m
        else:
            b = m
    return a


def _interval(cond, vol: WorkingVolume) -> tuple[float, float] | None:
    """The stretch of the depth range where the vectorised ``cond(D)`` holds (an interval)."""
    D = vol.grid()
    ok = np.asarray(cond(D), dtype=bool)
    if not ok.any():
        return None
    i, j = int(np.argmax(ok)), len(ok) - 1 - int(np.argmax(ok[::-1]))
    lo = D[i] if i == 0 else bisect_boundary(lambda x: bool(cond(np.array([x]))[0]), D[i], D[i - 1])
    hi = D[j] if j == len(D) - 1 else bisect_boundary(lambda x: bool(cond(np.array([x]))[0]), D[j], D[j + 1])
    return float(lo), float(hi)


def plate_interval_mm(vol: WorkingVolume, plate_height_mm: float,
                      table_z_mm: float) -> tuple[float, float] | None:
    """Where both edges of a calibration plate are in view.

    Parameters
    ----------
    vol : WorkingVolume
        The volume (with the edge margins).
    plate_height_mm, table_z_mm : float
        The plate spans heights ``table_z … table_z + height`` [mm].

    Returns
    -------
    tuple of float or None
        The interval of D [mm] where both edges are in view, or None.
    """
    z, top = float(table_z_mm), float(table_z_mm) + float(plate_height_mm)
    return _interval(lambda D: (vol.bottom_mm(D) <= z) & (top <= vol.top_mm(D)), vol)



def laser_distance_mm(rig: Rig, distance_mm):
    """In-sheet distance from the laser origin of a sheet point at distance D from the hinge.

    Parameters
    ----------
    rig : Rig
        The rig (lens and laser are read).
    distance_mm : array_like float
        D from the object hinge [mm].

    Returns
    -------
    ndarray float64
        ``D − D_l`` with ``D_l = (origin_x − f)/cos φ`` the laser origin's D [mm].
    """
    origin = (rig.laser.origin_x_mm - rig.lens.focal_length_mm) * math.hypot(1.0, rig.laser.tan_phi)
    return np.asarray(distance_mm, dtype=np.float64) - origin


def sheet_half_width_mm(rig: Rig, distance_mm: float) -> float:
    """1/e² half thickness of the sheet at a distance D from the hinge (Gaussian-beam law).

    Parameters
    ----------
    rig : Rig
        The rig; its laser's ``waist_distance_mm`` must be set.
    distance_mm : float
        D from the object hinge [mm].

    Returns
    -------
    float
        w = √(w0² + θ²·(r − r_w)²) at r = D − D_l [mm].
    """
    L = rig.laser
    r = float(laser_distance_mm(rig, distance_mm))
    return math.hypot(L.waist_um * 1e-3, L.divergence_mrad * 1e-3 * (r - L.waist_distance_mm))


def stripe_sigma_px(rig: Rig, distance_mm: float) -> float:
    """Standard deviation across the columns of the stripe on a surface facing the laser.

    Parameters
    ----------
    rig : Rig
        The rig (ideal geometry).
    distance_mm : float
        D of the surface from the object hinge [mm].

    Returns
    -------
    float
        ``(w/2)·|du/dδ|`` [px]: the sheet's Gaussian σ = w/2 across its plane,
        δ along the sheet normal, imaged by the chief ray through the lens
        centre onto the tilted sensor (u = u_h + (s_h − s)/p with s the
        position along the sensor from the Scheimpflug line, s = d/(cos β −
        sin β·y/x) for a point (x, y)).
    """
    g = hinge_geometry(rig)
    x, y, _ = g.rig_from_sheet(distance_mm, 0.0)
    b, phi = g.beta_rad, g.phi_rad
    denom = math.cos(b) - math.sin(b) * y / x
    dratio = (math.cos(phi) * x - y * math.sin(phi)) / (x * x)   # d(y/x)/dδ along n = (sin φ, cos φ)
    ds = g.scheimpflug_distance_mm * math.sin(b) * dratio / denom ** 2
    return 0.5 * sheet_half_width_mm(rig, distance_mm) * abs(ds) / g.pixel_pitch_mm


def lambertian_peak_electrons_per_ms(rig: Rig, distance_mm: float, albedo: float = 1.0) -> float:
    """Stripe peak on a Lambertian surface that faces the laser, in the meridian plane (closed form).

    Parameters
    ----------
    rig : Rig
        The rig; its laser's ``waist_distance_mm`` must be set.
    distance_mm : float
        D of the surface from the object hinge [mm].
    albedo : float
        Lambertian albedo of the surface [-].

    Returns
    -------
    float
        Expected photo-electrons per millisecond of exposure in the pixel at
        the stripe's centre [e⁻/ms].

    Notes
    -----
    Fan of power P spread evenly over F: I = P/F [W/rad]; at in-sheet distance
    r the peak irradiance is E = I/(r·√(2π)·w(r)/2), w the 1/e² half
    thickness (:func:`sheet_half_width_mm`); radiance ρE/π; image irradiance
    π·L·cos⁴θ/(4·N²·(1 + m)²) with m = f/(x − f) the magnification and θ the
    field angle; times the pixel area, the quantum efficiency and λ/(h·c),
    and the share of a Gaussian stripe of σ pixels (:func:`stripe_sigma_px`)
    that its centre pixel holds relative to a uniform patch,
    √(2π)·σ·erf(1/(2√2·σ)).  The tilted sensor's obliquity and the fan's soft
    edge are left out: a first-order figure for choosing an exposure (within
    ≈ 15 % of the twin's on a Lambertian plate at the paper's resolution).
    """
    L, lens, s = rig.laser, rig.lens, rig.sensor
    r = float(laser_distance_mm(rig, distance_mm))
    w = sheet_half_width_mm(rig, distance_mm)
    irradiance = L.power_mw * 1e-3 / math.radians(L.fan_angle_deg) / (r * math.sqrt(2 * math.pi) * 0.5 * w)
    x, y, _ = hinge_geometry(rig).rig_from_sheet(distance_mm, 0.0)
    m = lens.focal_length_mm / (x - lens.focal_length_mm)
    cos4 = (x * x / (x * x + y * y)) ** 2
    image = albedo * irradiance / (4 * lens.f_number ** 2 * (1 + m) ** 2) * cos4  # [W/mm²]
    sigma = stripe_sigma_px(rig, distance_mm)
    share = math.sqrt(2 * math.pi) * sigma * math.erf(1 / (2 * math.sqrt(2) * sigma))
    photon_j = 6.62607015e-34 * 299792458.0 / (L.wavelength_nm * 1e-9)
    return image * (s.pixel_pitch_um * 1e-3) ** 2 * share * s.quantum_efficiency / photon_j * 1e-3
