"""Geometric fits used to score scans: plane, cylinder, circle in top view.

All fits are least squares on float64 arrays of points in millimetres and
return frozen dataclasses with the fitted parameters, the residuals and their
RMS.  ``to_dict()`` gives the JSON form used by ``scheimpflug evaluate``.

- :func:`fit_plane` — total least squares (orthogonal distances, SVD), the
  best plane whatever its orientation.
- :func:`fit_plane_paper` — the paper's form ``y = a + b·x + c·z`` (ordinary
  least squares on y), with its RMSE of the y residuals, for direct comparison
  with the paper's box side (RMSE 0.1775 mm, y = −67.24 + 0.3902x + 0.03029z).
- :func:`fit_cylinder` — axis direction, axis point, radius, height extent,
  by Gauss–Newton on the orthogonal distance to the surface.
- :func:`fit_circle` / :func:`fit_circle_top_view` — Pratt's algebraic fit
  (or Kåsa's) refined by geometric least squares; diameter and mean |error|.
- :func:`fit_rigid` — the rigid motion between two corresponding point sets
  (Kabsch), to compare a measurement with its truth up to where its frame is.

References
----------
V. Pratt, "Direct least-squares fitting of algebraic surfaces", SIGGRAPH 1987.
I. Kåsa, "A circle fitting procedure and its error analysis", IEEE TIM 1976.
N. Chernov, *Circular and Linear Regression*, CRC 2010, ch. 5.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import eig
from scipy.optimize import least_squares

__all__ = [
    "CircleFit",
    "CylinderFit",
    "PaperPlaneFit",
    "PlaneFit",
    "fit_circle",
    "fit_circle_top_view",
    "fit_cylinder",
    "fit_plane",
    "fit_plane_paper",
    "fit_rigid",
]


def _points(points, dim: int, min_n: int, what: str) -> np.ndarray:
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != dim:
        raise ValueError(f"{what} fit needs an (n, {dim}) array of points, got shape {p.shape}")
    p = p[np.all(np.isfinite(p), axis=1)]
    if len(p) < min_n:
        raise ValueError(f"{what} fit needs at least {min_n} finite points, got {len(p)}")
    return p


def _rank_check(centred: np.ndarray, rank: int, what: str) -> np.ndarray:
    """Singular values of the centred points; refuse sets spanning fewer than ``rank`` dimensions."""
    s = np.linalg.svd(centred, compute_uv=False)
    if s[0] == 0 or s[rank - 1] <= 1e-9 * s[0]:
        raise ValueError(f"degenerate point set for a {what} fit (points do not span "
                         f"{rank} dimensions)")
    return s


# --------------------------------------------------------------------------- plane


@dataclass(frozen=True)
class PlaneFit:
    """Plane ``normal · x = offset_mm`` (unit normal, sign chosen with normal[argmax|n|] > 0).

    Parameters
    ----------
    normal : (3,) ndarray float
        Unit normal, in the points' frame [-].
    offset_mm : float
        Signed distance of the plane from the origin [mm].
    centroid_mm : (3,) ndarray float
        Centroid of the fitted points, on the plane [mm].
    residuals_mm : (n,) ndarray float
        Signed orthogonal distances of the points [mm].
    rms_mm : float
        RMS of the residuals [mm].
    """

    normal: np.ndarray
    offset_mm: float
    centroid_mm: np.ndarray
    residuals_mm: np.ndarray
    rms_mm: float

    def to_dict(self) -> dict:
        """The fit as the JSON object of ``scheimpflug evaluate``.

        Returns
        -------
        dict
            ``normal``, ``offset_mm``, ``centroid_mm``, ``rms_mm``, ``n_points``;
            arrays as lists, residuals left out.
        """
        return {"normal": self.normal.tolist(), "offset_mm": self.offset_mm,
                "centroid_mm": self.centroid_mm.tolist(), "rms_mm": self.rms_mm,
                "n_points": int(self.residuals_mm.size)}


def fit_plane(points: np.ndarray) -> PlaneFit:
    """Total-least-squares plane through points (orthogonal distances, SVD).

    Parameters
    ----------
    points : (n, 3) array_like float
        Points [mm], any frame; rows with a non-finite coordinate are dropped.
        At least 3 finite points, not collinear.

    Returns
    -------
    PlaneFit
        The plane (in the points' frame), residuals and RMS.

    Raises
    ------
    ValueError
        If ``points`` is not (n, 3), has fewer than 3 finite points, or they
        are collinear (do not span 2 dimensions).
    """
    p = _points(points, 3, 3, "plane")
    c = p.mean(axis=0)
    _rank_check(p - c, 2, "plane")
    normal = np.linalg.svd(p - c, full_matrices=False)[2][2]
    if normal[np.argmax(np.abs(normal))] < 0:
        normal = -normal
    res = (p - c) @ normal
    return PlaneFit(normal=normal, offset_mm=float(normal @ c), centroid_mm=c,
                    residuals_mm=res, rms_mm=float(np.sqrt(np.mean(res ** 2))))


@dataclass(frozen=True)
class PaperPlaneFit:
    """The paper's plane ``y = a + b·x + c·z`` (x, y, z in mm).

    Parameters
    ----------
    a_mm : float
        Intercept [mm].
    b, c : float
        Slopes dy/dx and dy/dz [-].
    residuals_y_mm : (n,) ndarray float
        y residuals [mm].
    rmse_mm : float
        RMS of the y residuals [mm] (the paper's RMSE).
    rms_orthogonal_mm : float
        RMS distance to the plane along its normal [mm] (= rmse / √(1 + b² + c²)).
    """

    a_mm: float
    b: float
    c: float
    residuals_y_mm: np.ndarray
    rmse_mm: float
    rms_orthogonal_mm: float

    def to_dict(self) -> dict:
        """The fit as the JSON object of ``scheimpflug evaluate``.

        Returns
        -------
        dict
            ``a_mm``, ``b``, ``c``, ``rmse_mm``, ``rms_orthogonal_mm``, ``n_points``;
            arrays as lists, residuals left out.
        """
        return {"a_mm": self.a_mm, "b": self.b, "c": self.c, "rmse_mm": self.rmse_mm,
                "rms_orthogonal_mm": self.rms_orthogonal_mm,
                "n_points": int(self.residuals_y_mm.size)}


def fit_plane_paper(points: np.ndarray) -> PaperPlaneFit:
    """Least-squares ``y = a + b x + c z`` through points (paper §4 form).

    Only meaningful for planes not parallel to y (a box side seen roughly
    face-on along y); use :func:`fit_plane` for arbitrary orientations.

    Parameters
    ----------
    points : (n, 3) array_like float
        Points [mm] (part frame for a scan); rows with a non-finite
        coordinate are dropped.  At least 3 finite points.

    Returns
    -------
    PaperPlaneFit
        Coefficients, y residuals, RMSE and orthogonal RMS.

    Raises
    ------
    ValueError
        If ``points`` is not (n, 3), has fewer than 3 finite points, or their
        (x, z) do not span 2 dimensions.
    """
    p = _points(points, 3, 3, "plane")
    design = np.column_stack([np.ones(len(p)), p[:, 0], p[:, 2]])
    _rank_check(design[:, 1:] - design[:, 1:].mean(axis=0), 2, "y = a + b x + c z plane")
    coef = np.linalg.lstsq(design, p[:, 1], rcond=None)[0]
    res = p[:, 1] - design @ coef
    rmse = float(np.sqrt(np.mean(res ** 2)))
    return PaperPlaneFit(a_mm=float(coef[0]), b=float(coef[1]), c=float(coef[2]),
                         residuals_y_mm=res, rmse_mm=rmse,
                         rms_orthogonal_mm=rmse / float(np.sqrt(1 + coef[1] ** 2 + coef[2] ** 2)))


# --------------------------------------------------------------------------- circle


@dataclass(frozen=True)
class CircleFit:
    """Circle in a plane (top view: x, y).

    Parameters
    ----------
    centre_mm : (2,) ndarray float
        Centre [mm].
    radius_mm, diameter_mm : float
        Radius and diameter [mm].
    residuals_mm : (n,) ndarray float
        Signed radial errors |p − centre| − radius [mm].
    mean_abs_error_mm, rms_mm : float
        Mean absolute and RMS radial error [mm].
    """

    centre_mm: np.ndarray
    radius_mm: float
    diameter_mm: float
    residuals_mm: np.ndarray
    mean_abs_error_mm: float
    rms_mm: float

    def to_dict(self) -> dict:
        """The fit as the JSON object of ``scheimpflug evaluate``.

        Returns
        -------
        dict
            ``centre_mm``, ``radius_mm``, ``diameter_mm``, ``mean_abs_error_mm``, ``rms_mm``, ``n_points``;
            arrays as lists, residuals left out.
        """
        return {"centre_mm": self.centre_mm.tolist(), "radius_mm": self.radius_mm,
                "diameter_mm": self.diameter_mm, "mean_abs_error_mm": self.mean_abs_error_mm,
                "rms_mm": self.rms_mm, "n_points": int(self.residuals_mm.size)}


def _circle_kasa(xy: np.ndarray) -> tuple[np.ndarray, float]:
    design = np.column_stack([xy, np.ones(len(xy))])
    sol = np.linalg.lstsq(design, (xy ** 2).sum(axis=1), rcond=None)[0]
    centre = sol[:2] / 2
    return centre, float(np.sqrt(max(sol[2] + centre @ centre, 0.0)))


def _circle_pratt(xy: np.ndarray) -> tuple[np.ndarray, float]:
    """Pratt: min Σ(A z + B x + C y + D)² subject to B² + C² − 4AD = 1 (generalised eigenproblem)."""
    z = (xy ** 2).sum(axis=1)
    data = np.column_stack([z, xy, np.ones(len(xy))])
    moments = data.T @ data / len(xy)
    constraint = np.array([[0, 0, 0, -2], [0, 1, 0, 0], [0, 0, 1, 0], [-2, 0, 0, 0]], float)
    w, v = eig(moments, constraint)
    w = np.real(w)
    ok = np.isfinite(w) & (w > -1e-12 * max(1.0, np.abs(moments).max()))
    if not np.any(ok):
        return _circle_kasa(xy)
    vec = np.real(v[:, np.flatnonzero(ok)[np.argmin(w[ok])]])
    a, b, c, d = vec
    if abs(a) < 1e-300:
        return _circle_kasa(xy)
    centre = np.array([-b / (2 * a), -c / (2 * a)])
    return centre, float(np.sqrt(max(b * b + c * c - 4 * a * d, 0.0)) / (2 * abs(a)))


def fit_circle(xy: np.ndarray, method: str = "pratt", refine: bool = True) -> CircleFit:
    """Circle through 2-D points: algebraic fit, then geometric least squares.

    Parameters
    ----------
    xy : (n, 2) array_like float
        Points [mm]; rows with a non-finite coordinate are dropped.  At least
        3 finite points, not collinear.
    method : {"pratt", "kasa"}, default "pratt"
        Algebraic fit used as the start (Kåsa is biased towards small radii on
        short arcs; Pratt is not, to first order).
    refine : bool, default True
        Minimise Σ (|p − c| − r)² from the algebraic start (Gauss–Newton / LM).

    Returns
    -------
    CircleFit
        Centre, radius, diameter and radial residuals.

    Raises
    ------
    ValueError
        If ``xy`` is not (n, 2), has fewer than 3 finite points, the points
        are collinear, or ``method`` is unknown.
    """
    p = _points(xy, 2, 3, "circle")
    mean = p.mean(axis=0)
    q = p - mean
    _rank_check(q, 2, "circle")
    if method not in ("pratt", "kasa"):
        raise ValueError(f"unknown circle fit method {method!r} (use 'pratt' or 'kasa')")
    centre, radius = (_circle_pratt if method == "pratt" else _circle_kasa)(q)
    if refine:
        centre, radius = _circle_geometric(q, centre, radius)
    res = np.linalg.norm(q - centre, axis=1) - radius
    return CircleFit(centre_mm=centre + mean, radius_mm=radius, diameter_mm=2 * radius,
                     residuals_mm=res, mean_abs_error_mm=float(np.abs(res).mean()),
                     rms_mm=float(np.sqrt(np.mean(res ** 2))))


def _circle_geometric(q, centre, radius):
    def fun(x):
        return np.linalg.norm(q - x[:2], axis=1) - x[2]

    def jac(x):
        diff = q - x[:2]
        rr = np.maximum(np.linalg.norm(diff, axis=1, keepdims=True), 1e-300)
        return np.column_stack([-diff / rr, -np.ones(len(q))])

    sol = least_squares(fun, np.r_[centre, radius], jac=jac, method="lm", xtol=1e-14, ftol=1e-14)
    return sol.x[:2], float(abs(sol.x[2]))


def fit_circle_top_view(points: np.ndarray, method: str = "pratt") -> CircleFit:
    """Circle fit of 3-D points seen from above (their x, y), as the paper's ring.

    Parameters
    ----------
    points : (n, 3) array_like float
        Points [mm] (part frame for a scan, z up); z is ignored.
    method : {"pratt", "kasa"}, default "pratt"
        Algebraic start of :func:`fit_circle` (refined geometrically).

    Returns
    -------
    CircleFit
        The circle in the x, y plane.

    Raises
    ------
    ValueError
        As :func:`fit_circle` (for ``points`` not (n, 3) as well).
    """
    p = _points(points, 3, 3, "circle")
    return fit_circle(p[:, :2], method=method)


# --------------------------------------------------------------------------- cylinder


@dataclass(frozen=True)
class CylinderFit:
    """Right circular cylinder.

    Parameters
    ----------
    axis : (3,) ndarray float
        Unit axis direction (sign chosen with axis[argmax|a|] > 0) [-].
    centre_mm : (3,) ndarray float
        Point on the axis at the middle of the points' extent along it [mm].
    radius_mm, diameter_mm : float
        Radius and diameter [mm].
    height_mm : float
        Extent of the points along the axis [mm].
    residuals_mm : (n,) ndarray float
        Signed radial errors (distance to the axis − radius) [mm].
    rms_mm : float
        RMS of the residuals [mm].
    """

    axis: np.ndarray
    centre_mm: np.ndarray
    radius_mm: float
    diameter_mm: float
    height_mm: float
    residuals_mm: np.ndarray
    rms_mm: float

    def to_dict(self) -> dict:
        """The fit as the JSON object of ``scheimpflug evaluate``.

        Returns
        -------
        dict
            ``axis``, ``centre_mm``, ``radius_mm``, ``diameter_mm``, ``height_mm``, ``rms_mm``, ``n_points``;
            arrays as lists, residuals left out.
        """
        return {"axis": self.axis.tolist(), "centre_mm": self.centre_mm.tolist(),
                "radius_mm": self.radius_mm, "diameter_mm": self.diameter_mm,
                "height_mm": self.height_mm, "rms_mm": self.rms_mm,
                "n_points": int(self.residuals_mm.size)}


def _frame(axis: np.ndarray) -> np.ndarray:
    """Rows e1, e2, e3 of an orthonormal frame with e3 = axis."""
    e3 = axis / np.linalg.norm(axis)
    helper = np.eye(3)[np.argmin(np.abs(e3))]
    e1 = np.cross(e3, helper)
    e1 /= np.linalg.norm(e1)
    return np.array([e1, np.cross(e3, e1), e3])


def _cylinder_from_axis(q: np.ndarray, axis: np.ndarray):
    """Refine a cylinder from a start axis; returns (axis, point, radius, rms)."""
    basis = _frame(axis)
    local = q @ basis.T
    centre2, radius = _circle_pratt(local[:, :2])

    def unpack(x):
        direction = basis[2] + x[0] * basis[0] + x[1] * basis[1]
        return direction / np.linalg.norm(direction), x[2] * basis[0] + x[3] * basis[1]

    def fun(x):
        direction, point = unpack(x)
        d = q - point
        return np.linalg.norm(d - np.outer(d @ direction, direction), axis=1) - x[4]

    sol = least_squares(fun, np.r_[0.0, 0.0, centre2, radius], method="lm", x_scale="jac",
                        xtol=1e-13, ftol=1e-13)
    direction, point = unpack(sol.x)
    return direction, point, abs(float(sol.x[4])), float(np.sqrt(np.mean(sol.fun ** 2)))


def fit_cylinder(points: np.ndarray, axis_guess: np.ndarray | None = None) -> CylinderFit:
    """Least-squares cylinder through points on its lateral surface.

    Parameters
    ----------
    points : (n, 3) array_like float
        Points on the lateral surface [mm] (no end caps: select them first);
        rows with a non-finite coordinate are dropped.  At least 6 finite
        points spanning 3 dimensions.
    axis_guess : (3,) array_like float, optional
        Approximate axis direction.  Without it the three principal directions
        of the points are each tried as start and the best fit is kept.

    Returns
    -------
    CylinderFit
        Axis, centre, radius, height and radial residuals, in the points' frame.

    Raises
    ------
    ValueError
        If ``points`` is not (n, 3), has fewer than 6 finite points or they do
        not span 3 dimensions, or ``axis_guess`` is not a non-zero 3-vector.

    Notes
    -----
    Minimises Σ (dist(p, axis) − r)² over the axis direction (2 parameters
    about the start), an axis point (2) and the radius, with
    Levenberg–Marquardt.  An arc of the lateral surface well under 90° makes
    the radius poorly determined; the fit still returns its least-squares
    answer.
    """
    p = _points(points, 3, 6, "cylinder")
    mean = p.mean(axis=0)
    q = p - mean
    _rank_check(q, 3, "cylinder")
    if axis_guess is not None:
        starts = [np.asarray(axis_guess, dtype=np.float64)]
        if starts[0].shape != (3,) or not np.linalg.norm(starts[0]) > 0:
            raise ValueError("axis_guess must be a non-zero 3-vector")
    else:
        starts = list(np.linalg.svd(q, full_matrices=False)[2])
    best = min((_cylinder_from_axis(q, a) for a in starts), key=lambda fit: fit[3])
    direction, point, radius, _ = best
    if direction[np.argmax(np.abs(direction))] < 0:
        direction = -direction
    t = (q - point) @ direction
    radial = q - point - np.outer(t, direction)
    res = np.linalg.norm(radial, axis=1) - radius
    centre = mean + point + direction * 0.5 * (t.min() + t.max())
    return CylinderFit(axis=direction, centre_mm=centre, radius_mm=radius, diameter_mm=2 * radius,
                       height_mm=float(t.max() - t.min()), residuals_mm=res,
                       rms_mm=float(np.sqrt(np.mean(res ** 2))))


def fit_rigid(a, b, *, mirror: bool = False) -> tuple[np.ndarray, np.ndarray, float]:
    """The rigid motion that best maps point set ``a`` onto ``b`` (Kabsch): ``b ≈ R·a + t``.

    Parameters
    ----------
    a, b : (n, 3) array_like float
        Corresponding points [mm], n ≥ 3.
    mirror : bool, default False
        Fit the best *improper* motion (det R = −1) instead: how far ``a`` is from ``b``'s mirror
        image (a frame turned the wrong way shows as a small RMS here).

    Returns
    -------
    R : (3, 3) float64
        Rotation (det +1; −1 with ``mirror``).
    t : (3,) float64
        Translation [mm].
    rms_mm : float
        RMS of ``b − (R·a + t)`` [mm].

    Raises
    ------
    ValueError
        Point sets of other shapes, or fewer than 3 points.
    """
    p, q = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or p.shape != q.shape or len(p) < 3:
        raise ValueError(f"fit_rigid needs two (n, 3) point sets of one size, n >= 3; got {p.shape}, {q.shape}")
    cp, cq = p.mean(axis=0), q.mean(axis=0)
    u, _, vt = np.linalg.svd((p - cp).T @ (q - cq))
    sign = np.sign(np.linalg.det(vt.T @ u.T)) * (-1.0 if mirror else 1.0)
    r = vt.T @ np.diag([1.0, 1.0, sign]) @ u.T
    t = cq - r @ cp
    return r, t, float(np.sqrt(np.mean(np.sum((p @ r.T + t - q) ** 2, axis=1))))
