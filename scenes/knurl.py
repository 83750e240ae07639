"""Knurls: an exact height field r(θ, z) on a cylinder, and a grid that meshes it exactly.

Geometry
--------
A knurl band on a cylinder of crest radius R, between heights z0 and z1, is
cut by V-grooves of normal pitch p (measured perpendicular to the grooves) and
depth d, running at the helix angle α to the cylinder axis.  With the
unwrapped arc length s = R θ and the groove phases

    a = (s cos α + (z − z0) sin α) / p,     b = (s cos α − (z − z0) sin α) / p,

and the triangle wave u(x) = 2 |x − round(x)| (0 at a groove bottom, 1 at a
crest), the surface radius is

    straight (one family, α = 0 is an axial straight knurl):  r = R − d (1 − u(a))
    diamond (both families, raised pyramids):                 r = R − d (1 − min(u(a), u(b)))

Crests sit on the nominal radius R, roots at R − d.  The number of grooves
around, N = round(2π R cos α / p), must be an integer for the pattern to close,
so the actual normal pitch is p = 2π R cos α / N (stored in the analytic
description); the circumferential pitch is p / cos α, the axial period of one
groove family p / sin α.

Exact meshing
-------------
On the grid θ_i = 2π i / (N k), z_j = z0 + j p / (k sin α) (k even) the phases
are a = (i + j)/k and b = (i − j)/k: groove bottoms and crests lie on grid
vertices, the pyramid edges on grid lines and the groove lines on quad
diagonals.  Choosing each quad's diagonal to follow the surface makes the
piecewise-planar mesh equal the height field (up to the chord sagitta of the
cylinder, ≈ R (π / (N k))² / 2, a few 1e-5 mm).  Only the last row below z1 is
approximate when the band height is not a multiple of the row step.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["PATTERNS", "knurl_grid", "knurl_radius_mm", "knurl_spec"]

PATTERNS = ("straight", "diamond")


def knurl_spec(radius_mm: float, z0_mm: float, z1_mm: float, *, pattern: str = "diamond",
               pitch_mm: float = 1.0, depth_mm: float = 0.4, helix_deg: float = 30.0) -> dict:
    """Exact (JSON-ready) description of a knurl band; the pitch is snapped to close the circle.

    Parameters
    ----------
    radius_mm : float
        Crest radius R [mm].
    z0_mm : float
        Lower band limit along the axis [mm].
    z1_mm : float
        Upper band limit along the axis [mm], z1 > z0.
    pattern : {"diamond", "straight"}
        ``"straight"`` (one groove family) or ``"diamond"`` (two, crossed; default).
    pitch_mm : float, default 1.0
        Requested normal pitch p [mm], 0 < p < R.
    depth_mm : float, default 0.4
        Groove depth d [mm], 0 < d < min(p, R).
    helix_deg : float, default 30.0
        Groove angle α to the axis [deg]; 0 ≤ α ≤ 60 (diamond: α > 0).

    Returns
    -------
    dict
        ``pattern, crest_radius_mm, root_radius_mm, depth_mm, pitch_mm``
        (actual), ``requested_pitch_mm, helix_deg, teeth_around`` (N ≥ 3),
        ``circumferential_pitch_mm, axial_period_mm`` (None, JSON ``null``, for
        α = 0), ``band_z_range_mm``; lengths [mm], angle [deg].

    Raises
    ------
    ValueError
        For an unknown pattern or a parameter outside the ranges above.
    """
    _validate(radius_mm, z0_mm, z1_mm, pattern, pitch_mm, depth_mm, helix_deg)
    cos_a = math.cos(math.radians(helix_deg))
    teeth = max(3, round(2 * math.pi * radius_mm * cos_a / pitch_mm))
    pitch = 2 * math.pi * radius_mm * cos_a / teeth
    sin_a = math.sin(math.radians(helix_deg))
    return {"pattern": pattern, "crest_radius_mm": float(radius_mm),
            "root_radius_mm": float(radius_mm - depth_mm), "depth_mm": float(depth_mm),
            "pitch_mm": pitch, "requested_pitch_mm": float(pitch_mm), "helix_deg": float(helix_deg),
            "teeth_around": int(teeth), "circumferential_pitch_mm": pitch / cos_a,
            "axial_period_mm": pitch / sin_a if sin_a > 0 else None,
            "band_z_range_mm": [float(z0_mm), float(z1_mm)]}


def _validate(radius_mm, z0_mm, z1_mm, pattern, pitch_mm, depth_mm, helix_deg) -> None:
    if pattern not in PATTERNS:
        raise ValueError(f"knurl pattern {pattern!r} unknown (known: {', '.join(PATTERNS)})")
    if not z1_mm > z0_mm:
        raise ValueError(f"knurl band must have z1 > z0, got [{z0_mm}, {z1_mm}] mm")
    if not 0 < pitch_mm < radius_mm:
        raise ValueError(f"knurl pitch_mm = {pitch_mm}: must be > 0 and < the radius {radius_mm} mm")
    if not 0 < depth_mm < min(pitch_mm, radius_mm):
        raise ValueError(f"knurl depth_mm = {depth_mm}: must be > 0 and < the pitch {pitch_mm} mm")
    if not 0 <= helix_deg <= 60 or (pattern == "diamond" and helix_deg <= 0):
        raise ValueError(f"knurl helix_deg = {helix_deg}: must be in [0, 60] deg (> 0 for diamond)")


def _tri(x: np.ndarray) -> np.ndarray:
    """Triangle wave: 0 at integers (groove bottom), 1 at half-integers (crest)."""
    return 2.0 * np.abs(x - np.round(x))


def knurl_radius_mm(theta_rad, z_mm, spec: dict) -> np.ndarray:
    """Exact surface radius of the knurl band at (θ, z).

    Parameters
    ----------
    theta_rad : float or array_like
        Angle about the axis [rad].
    z_mm : float or array_like
        Height [mm] (meaningful inside ``band_z_range_mm``).
    spec : dict
        From :func:`knurl_spec` (or a part's ``analytic["knurl"]``).

    Returns
    -------
    ndarray
        r(θ, z) [mm], the broadcast shape of ``theta_rad`` and ``z_mm``:
        between the root R − d and the crest R (module docstring).
    """
    r_c, p, d = spec["crest_radius_mm"], spec["pitch_mm"], spec["depth_mm"]
    alpha = math.radians(spec["helix_deg"])
    s = r_c * np.asarray(theta_rad, dtype=float) * math.cos(alpha)
    t = (np.asarray(z_mm, dtype=float) - spec["band_z_range_mm"][0]) * math.sin(alpha)
    ua = _tri((s + t) / p)
    u = ua if spec["pattern"] == "straight" else np.minimum(ua, _tri((s - t) / p))
    return r_c - d * (1.0 - u)


def knurl_grid(spec: dict, max_edge_mm: float = 0.15) -> tuple[np.ndarray, np.ndarray]:
    """Aligned grid (see module doc) with edges ≤ ``max_edge_mm`` along θ and z.

    Parameters
    ----------
    spec : dict
        From :func:`knurl_spec`.
    max_edge_mm : float, default 0.15
        Largest grid step along the circumference and along z [mm].

    Returns
    -------
    theta_rad : (N k,) float
        Angles 2π i / (N k), i = 0 … N k − 1 [rad]; k even, ≥ 4.
    z_mm : (m,) float
        Rows from z0 to z1 inclusive [mm] (only the two band ends for α = 0).

    Raises
    ------
    ValueError
        When ``max_edge_mm`` ≤ 0.
    """
    if max_edge_mm <= 0:
        raise ValueError(f"max_edge_mm = {max_edge_mm}: must be > 0")
    p, alpha = spec["pitch_mm"], math.radians(spec["helix_deg"])
    z0, z1 = spec["band_z_range_mm"]
    k = math.ceil(spec["circumferential_pitch_mm"] / max_edge_mm)
    if alpha > 0:
        k = max(k, math.ceil(p / (math.sin(alpha) * max_edge_mm)))
    k = max(4, k + (k % 2))
    theta = 2 * math.pi * np.arange(spec["teeth_around"] * k) / (spec["teeth_around"] * k)
    if alpha == 0:  # no variation along z: the two band ends are exact
        return theta, np.array([z0, z1], dtype=float)
    dz = p / (k * math.sin(alpha))
    n = int(math.floor((z1 - z0) / dz + 1e-9))
    z = z0 + dz * np.arange(n + 1)
    if z1 - z[-1] > 1e-9:
        z = np.append(z, z1)
    z[-1] = z1
    return theta, z
