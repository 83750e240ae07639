"""OpenCV's lens distortion on the rig's field-angle tangents (forward and inverse), float64.

The thin lens of :mod:`scheimpflug.model.camera` bends each chief ray: an object
point P (rig frame, x along the optical axis, relative to the lens centre) has
the field-angle tangents ``a = (y/x, z/x)``; its chief ray leaves the lens with
the tangents ``a_d = D(a)``.  ``D`` is OpenCV's distortion model (radial k1, k2,
k3; tangential p1, p2) on the normalised coordinates of the camera whose x runs
along the sensor's columns and y along its rows,

    m = −E(ψ)·a,   E(ψ) = [[cos ψ, sin ψ], [−sin ψ, cos ψ]]   (ψ = ``[sensor] roll_deg``)

    m_d = m·(1 + k1 r² + k2 r⁴ + k3 r⁶) + (2 p1 x y + p2 (r² + 2x²), p1 (r² + 2y²) + 2 p2 x y),
    m_d,y ← ρ·m_d,y  (ρ = ``[lens] aspect_ratio`` = fy/fx),   a_d = −E(ψ)ᵀ·m_d

(the camera frame: X = −e_u, Y = −e_v of the unrolled sensor, the image being
inverted).  With p1 = p2 = k3 = 0 and ρ = 1 it is the radial scaling
``a_d = a·(1 + k1 t² + k2 t⁴)``, t = |a|, of the rig's lens since the paper
rig; :func:`is_radial` says when a caller may keep that closed form.

References
----------
OpenCV, *Camera Calibration and 3D Reconstruction* (``cv::projectPoints``): the
distortion model on normalised coordinates (Brown–Conrady).
"""

from __future__ import annotations

import math

import numpy as np

from scheimpflug.model._checks import check_last_dim

__all__ = ["distort_tangents", "fold_radius", "is_radial", "tangents_jacobian", "undistort_tangents"]


def is_radial(lens) -> bool:
    """Whether a lens's distortion is the radial k1, k2 scaling alone.

    Parameters
    ----------
    lens : scheimpflug.model.rig.Lens
        The lens (``k3``, ``p1``, ``p2``, ``aspect_ratio``).

    Returns
    -------
    bool
        True when k3 = p1 = p2 = 0 and the aspect ratio is 1.
    """
    return lens.k3 == 0.0 and lens.p1 == 0.0 and lens.p2 == 0.0 and lens.aspect_ratio == 1.0


def _frame(roll_deg: float) -> np.ndarray:
    """E(ψ), the (2, 2) map of rig tangents (y, z) to the sensor axes (u, v), before the sign."""
    c, s = math.cos(math.radians(roll_deg)), math.sin(math.radians(roll_deg))
    return np.array([[c, s], [-s, c]])


def _opencv(lens, m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's distorted (x_d, y_d) of normalised (…, 2) coordinates, before the aspect stretch."""
    x, y = m[..., 0], m[..., 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (lens.k1 + r2 * (lens.k2 + r2 * lens.k3))
    xd = x * radial + 2.0 * lens.p1 * x * y + lens.p2 * (r2 + 2.0 * x * x)
    yd = y * radial + lens.p1 * (r2 + 2.0 * y * y) + 2.0 * lens.p2 * x * y
    return xd, yd


def _jacobian(lens, m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """∂(x_d, y_d)/∂(x, y) of :func:`_opencv`: (a, b, c, d) of [[a, b], [c, d]], each (…)."""
    x, y = m[..., 0], m[..., 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (lens.k1 + r2 * (lens.k2 + r2 * lens.k3))
    dr = lens.k1 + r2 * (2.0 * lens.k2 + 3.0 * r2 * lens.k3)       # d radial / d r²
    off = 2.0 * x * y * dr + 2.0 * lens.p1 * x + 2.0 * lens.p2 * y
    return (radial + 2.0 * x * x * dr + 2.0 * lens.p1 * y + 6.0 * lens.p2 * x, off, off,
            radial + 2.0 * y * y * dr + 6.0 * lens.p1 * y + 2.0 * lens.p2 * x)


def distort_tangents(lens, roll_deg: float, tangents) -> np.ndarray:
    """Chief-ray tangents behind the lens of object tangents (module docstring).

    Parameters
    ----------
    lens : scheimpflug.model.rig.Lens
        The lens (k1, k2, k3, p1, p2, aspect_ratio).
    roll_deg : float
        Roll ψ of the sensor's pixel axes about the optical axis [deg].
    tangents : (..., 2) array_like float
        Object-side field-angle tangents a = (y/x, z/x) in the rig frame [-].

    Returns
    -------
    (..., 2) ndarray float64
        The distorted tangents a_d [-].

    Raises
    ------
    ValueError
        If ``tangents`` is not of shape ``(..., 2)``.
    """
    a = check_last_dim("tangents", tangents, 2)
    e = _frame(roll_deg)
    xd, yd = _opencv(lens, -(a @ e.T))
    return -(np.stack([xd, lens.aspect_ratio * yd], axis=-1) @ e)


def tangents_jacobian(lens, roll_deg: float, tangents) -> np.ndarray:
    """∂a_d/∂a of :func:`distort_tangents`: how the distorted tangents follow the object tangents.

    Parameters
    ----------
    lens : scheimpflug.model.rig.Lens
        The lens (k1, k2, k3, p1, p2, aspect_ratio).
    roll_deg : float
        Roll ψ of the sensor's pixel axes about the optical axis [deg].
    tangents : (..., 2) array_like float
        Object-side field-angle tangents a = (y/x, z/x) in the rig frame [-].

    Returns
    -------
    (..., 2, 2) ndarray float64
        J[..., i, j] = ∂a_d[i]/∂a[j] [-].

    Raises
    ------
    ValueError
        If ``tangents`` is not of shape ``(..., 2)``.

    Notes
    -----
    a_d = −Eᵀ·A·d(−E·a) (E the roll frame, A = diag(1, aspect ratio), d OpenCV's
    distortion), so ∂a_d/∂a = Eᵀ·A·J_d(−E·a)·E with J_d OpenCV's Jacobian.
    """
    a = check_last_dim("tangents", tangents, 2)
    e = _frame(roll_deg)
    ja, jb, jc, jd = _jacobian(lens, -(a @ e.T))
    ar = lens.aspect_ratio
    j = np.stack([np.stack([ja, jb], axis=-1), np.stack([ar * jc, ar * jd], axis=-1)], axis=-2)
    return e.T @ j @ e


def undistort_tangents(lens, roll_deg: float, tangents, iterations: int = 30) -> np.ndarray:
    """Object tangents of distorted chief-ray tangents: the inverse of :func:`distort_tangents`.

    Parameters
    ----------
    lens : scheimpflug.model.rig.Lens
        The lens (k1, k2, k3, p1, p2, aspect_ratio).
    roll_deg : float
        Roll ψ of the sensor's pixel axes about the optical axis [deg].
    tangents : (..., 2) array_like float
        Distorted tangents a_d in the rig frame [-].
    iterations : int, default 30
        Newton steps on the 2 × 2 system (quadratic convergence inside the
        distortion's monotonic field) [-].

    Returns
    -------
    (..., 2) ndarray float64
        The object tangents a with ``distort_tangents(a) = a_d`` [-] (to ≈ 1e-15
        where the model is invertible).

    Raises
    ------
    ValueError
        If ``tangents`` is not of shape ``(..., 2)``.
    """
    a_d = check_last_dim("tangents", tangents, 2)
    e = _frame(roll_deg)
    target = -(a_d @ e.T)
    target = np.stack([target[..., 0], target[..., 1] / lens.aspect_ratio], axis=-1)
    m = target.copy()
    for _ in range(iterations):
        xd, yd = _opencv(lens, m)
        ja, jb, jc, jd = _jacobian(lens, m)
        rx, ry = xd - target[..., 0], yd - target[..., 1]
        det = ja * jd - jb * jc
        m = m - np.stack([jd * rx - jb * ry, ja * ry - jc * rx], axis=-1) / det[..., None]
    return -(m @ e)


def fold_radius(lens) -> float:
    """The distorted radius beyond which the radial distortion folds back (not one-to-one).

    Parameters
    ----------
    lens : scheimpflug.model.rig.Lens
        The lens (k1, k2, k3; the tangential terms and the aspect ratio are left out).

    Returns
    -------
    float
        r_d = r·(1 + k1 r² + k2 r⁴ + k3 r⁶) at the smallest r > 0 where its slope
        1 + 3 k1 r² + 5 k2 r⁴ + 7 k3 r⁶ reaches 0 [-] (normalised units, like x/z);
        inf when the distortion is monotonic for every r.

    Notes
    -----
    A fitted polynomial holds only where the calibration saw corners; beyond the fold a
    camera's pixels see the same directions twice, which no lens does.
    """
    roots = np.roots([7.0 * lens.k3, 5.0 * lens.k2, 3.0 * lens.k1, 1.0])
    s = [r.real for r in roots if abs(r.imag) < 1e-12 and r.real > 0]
    if not s:
        return math.inf
    s0 = min(s)
    return math.sqrt(s0) * (1.0 + s0 * (lens.k1 + s0 * (lens.k2 + s0 * lens.k3)))
