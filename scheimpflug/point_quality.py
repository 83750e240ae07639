"""The measured quality of every reconstructed point, and the filter a scanner applies with it.

A stripe centre is trustworthy where the sheet strikes the surface steeply and
the camera sees it steeply.  Where either grazes — a sphere's limb, the sheet
skimming a surface that turns away from it — the sheet's lit footprint on the
surface stretches as 1/cos θ of the incidence θ, the irradiance falls as cos θ,
and whatever makes the footprint asymmetric (curvature, the thickness of the
sheet seen from the side, the Lambertian fall-off across it) pulls the centre:
on the ideal paper rig those points carry stripe-centre errors of 0.1–0.7 mm
where the rest scatter by 0.01 mm (``benchmarks/RESULTS.md``).  Real scanners
attach a quality to every point and filter by it; so does this pipeline.

Per point, measured from the frames and the calibration only (never from truth):

``stripe_width_px``
    RMS width (Gaussian σ) of the stripe in the point's row, background
    subtracted, less the 1/12 px² of pixel integration [px]
    (:func:`stripe_widths_px`).
``snr``
    The stripe peak's height above the local background over the background's
    noise, the detector's own score [-] (:class:`scheimpflug.stripe.StripeProfile`).
``incidence_laser_deg``, ``incidence_camera_deg``
    Angles between the surface normal and the laser ray / the camera's line of
    sight at the point [deg], 0 = head-on, 90 = grazing (:func:`incidence_angles`).
    The normal is estimated from the scan's frame × row grid
    (:func:`grid_normals`): the tangent along the profile (neighbouring rows
    of the same frame) crossed with the tangent across profiles (the same row
    in neighbouring frames).  The laser ray runs from the laser origin to the
    point in the sheet; the line of sight from the point to the camera's
    centre; both are fixed by the calibration (:func:`sheet_geometry`).  NaN
    where the grid gives no normal (a single frame, a lone row).
``sweep_edge``
    The same row is empty in an adjacent frame (the sheet enters or leaves the
    surface between the two) and the point is lit at less than half of what
    the row's neighbour and Lambert's law predict: only part of the sheet's
    thickness lights it (:func:`sweep_edges`).
``saturated``, ``centre_sigma_px``
    The stripe's peak was clipped in the point's row, and the centre's standard
    uncertainty from the noise [px]: for a clipped row, propagated through its two
    edges (:func:`scheimpflug.stripe.extract_stripes`, module docstring step 5); for
    the others, the Cramér–Rao bound of its width and SNR (:func:`centre_crb_px`).

The default filter (:data:`DEFAULT_FILTER`)
-------------------------------------------
A point is kept when **both** incidences are at most ``max_incidence_deg``
(75°), its SNR is at least ``min_snr`` (13) and it is not on a sweep edge; a
NaN quality (not measurable) fails nothing.  A saturated point's SNR is that of
a clipped peak — a lower bound that says nothing of its centre, which comes
from the edges: it is kept instead when its ``centre_sigma_px`` is at most the
bound the SNR threshold guarantees an unsaturated stripe of its width,
``centre_crb_px(stripe_width_px, min_snr)`` (the clipped profile's width is
below the stripe's, so the test is, if anything, strict).  The thresholds come
from the physics, not from a fit to one scan:

* 75°: the footprint of the sheet is 1/cos 75° = 3.9 × as long as at normal
  incidence and the irradiance 0.26 × — there the footprint's length grows by
  6.5 % per degree (tan θ per radian) and its asymmetry on a curved surface
  (∝ tan θ / cos² θ) by × 3.4 from 75° to 80°;
* 13: the Cramér–Rao bound of a Gaussian stripe's centre under white noise,
  ``sqrt(2σ/√π) / SNR`` (:func:`centre_crb_px`), is 0.1 px for the twin's
  σ = 1.5 px stripe at SNR 13 — below the speckle floor of a real laser
  (≈ 0.15 px, docs/explanation/design-notes.md §5), so the points kept are never noise-limited
  worse than the instrument's own floor;
* the partly lit sweep edge: there only part of the sheet's thickness lights
  the surface (at half the irradiance the sheet's centre plane misses it by
  0.59 of the 1/e² half-thickness), and the camera sees the footprint's offset
  from the sheet's centre plane with the parallax of its triangulation angle.  On the ideal paper rig
  these are the points that set PF (0.1–0.7 mm off, all on sweep edges); their
  incidence, estimated from the same biased points, comes out 3–8° too low for
  the incidence criterion to catch them (``benchmarks/RESULTS.md``).

Pure numpy; no files (the PLY properties are :mod:`scheimpflug.io.ply`'s).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from scheimpflug.sheet_model import GeneralCalibration, ideal_camera

__all__ = [
    "DEFAULT_FILTER",
    "PARTLY_LIT_FRACTION",
    "QUALITY_FIELDS",
    "QualityFilter",
    "SheetGeometry",
    "assess_points",
    "centre_crb_px",
    "filter_counts",
    "grid_normals",
    "incidence_angles",
    "quality_mask",
    "sheet_geometry",
    "stripe_widths_px",
    "sweep_edges",
]

#: The per-point quality fields of :class:`scheimpflug.reconstruct.PointCloud` (and PLY properties).
QUALITY_FIELDS = ("stripe_width_px", "snr", "incidence_laser_deg", "incidence_camera_deg", "sweep_edge",
                  "saturated", "centre_sigma_px")


# ---------------------------------------------------------------- stripe width per row


def _second_moment(arr: np.ndarray, rows: np.ndarray, u: np.ndarray, bg: np.ndarray,
                   half: np.ndarray) -> np.ndarray:
    """RMS width [px] of ``arr − bg`` (positive part) over ±half columns around each u."""
    w_max = int(half.max())
    offs = np.arange(-w_max, w_max + 1)
    cols = np.rint(u).astype(np.int64)[:, None] + offs[None, :]
    inside = (cols >= 0) & (cols < arr.shape[1]) & (np.abs(offs)[None, :] <= half[:, None])
    vals = arr[rows[:, None], np.clip(cols, 0, arr.shape[1] - 1)] - bg[:, None]
    vals = np.where(inside, np.maximum(vals, 0.0), 0.0)
    total = vals.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = (vals * cols).sum(axis=1) / total
        var = (vals * (cols - mean[:, None]) ** 2).sum(axis=1) / total - 1.0 / 12.0
    return np.where(total > 0, np.sqrt(np.maximum(var, 0.0)), np.nan)


def stripe_widths_px(frame, rows, u, background, window_px: int = 7, max_window_px: int = 28) -> np.ndarray:
    """The stripe's RMS width in each row where it was found.

    Parameters
    ----------
    frame : (rows, columns) array_like
        The frame [DN].
    rows : (n,) array_like int
        Rows of the stripe samples [px].
    u : (n,) array_like float
        Their centres [px].
    background : (n,) array_like float
        Local background level of each row [DN] (the detector's).
    window_px : int
        First half window of the second moment [px] (the detector's window).
    max_window_px : int
        Widest half window: a row whose ±3σ exceeds the window is measured
        again with ±(⌈3σ⌉ + 1), up to this [px].

    Returns
    -------
    (n,) ndarray float64
        Background-subtracted RMS width about the row's own centroid, less the
        1/12 px² of pixel integration (Gaussian σ for a Gaussian stripe) [px];
        NaN for a row without signal above the background.

    Raises
    ------
    ValueError
        If ``rows``, ``u`` and ``background`` differ in size or a window is < 1.
    """
    rows, u = np.asarray(rows, np.int64), np.asarray(u, np.float64)
    bg = np.asarray(background, np.float64)
    if not (rows.shape == u.shape == bg.shape) or rows.ndim != 1:
        raise ValueError(f"rows, u and background must be (n,) alike, got {rows.shape}, {u.shape}, {bg.shape}")
    if not 1 <= window_px <= max_window_px:
        raise ValueError(f"need 1 <= window_px <= max_window_px, got {window_px}, {max_window_px}")
    if rows.size == 0:
        return np.zeros(0)
    arr = np.asarray(frame, np.float64)
    half = np.full(rows.size, int(window_px))
    sigma = _second_moment(arr, rows, u, bg, half)
    for _ in range(3):                         # widen where the stripe's tails pass the window
        want = np.minimum(np.ceil(3.0 * np.nan_to_num(sigma) - 1e-9).astype(np.int64) + 1, max_window_px)
        grow = want > half
        if not grow.any():
            break
        half = np.where(grow, want, half)
        sigma[grow] = _second_moment(arr, rows[grow], u[grow], bg[grow], half[grow])
    return sigma


def centre_crb_px(sigma_px, snr):
    """Cramér–Rao bound of a Gaussian stripe's centre under white noise.

    Parameters
    ----------
    sigma_px : array_like float
        Gaussian σ of the stripe [px].
    snr : array_like float
        Peak height over the noise's standard deviation [-].

    Returns
    -------
    ndarray float64
        ``sqrt(2σ/√π) / SNR`` [px]: the Fisher information of the centre of
        ``A exp(−(x − u)²/2σ²)`` sampled at unit pitch is ``A²√π / (2σ σ_n²)``.
    """
    sigma, s = np.asarray(sigma_px, np.float64), np.asarray(snr, np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.sqrt(2.0 * sigma / math.sqrt(math.pi)) / s


# ---------------------------------------------------------------- where the laser and the camera are


@dataclass(frozen=True)
class SheetGeometry:
    """The laser origin and the camera centre in the sheet's frame.

    The sheet frame is the stage frame's axes with the origin shifted to stage
    coordinate 0: ``(s, y, h)`` = stage coordinate along the propagation
    direction, offset across the sheet (+y = z × x, docs/reference/interface.md stage
    conventions) and height above the meridian plane [mm].

    Parameters
    ----------
    laser_mm : (3,) float
        Laser origin ``(s_L, 0, 0)`` [mm].
    camera_mm : (3,) float
        Camera's projection centre ``(s_O, y_O, h_O)`` [mm].
    """

    laser_mm: np.ndarray
    camera_mm: np.ndarray


def _sheet_axes(calibration, focal_length_mm: float, pixel_pitch_um: float) -> tuple[np.ndarray, ...]:
    """Camera-frame origin, stage axis and height axis of the sheet (metric) [mm]."""
    if isinstance(calibration, GeneralCalibration):
        g, mu = calibration.homography, calibration.metric_scale()
    else:
        _, g = ideal_camera(calibration, focal_length_mm, pixel_pitch_um)
        mu = 1.0 / float(np.linalg.norm(g[:, 0]))
    return mu * g[:, 2], mu * g[:, 0], mu * g[:, 1]


def sheet_geometry(calibration, focal_length_mm: float, pixel_pitch_um: float,
                   laser_origin_x_mm: float = 0.0) -> SheetGeometry:
    """Laser origin and camera centre in the sheet frame, from a calibration.

    The calibration maps the sheet into the camera's frame (the general model's
    homography; the paper form decomposed with the lens's focal length and the
    pixel pitch, :func:`scheimpflug.sheet_model.ideal_camera`): the camera
    centre is that frame's origin, and the laser origin is the sheet's point in
    the meridian plane at ``laser_origin_x_mm`` along the optical axis from the
    lens (0: in the lens plane, docs/explanation/design-notes.md §2).  An origin misplaced by δ along
    the sheet turns a ray at height h and distance D by ≈ h·δ/D² (0.8° for
    δ = 100 mm at the paper rig's h = 70 mm, D = 700 mm).

    Parameters
    ----------
    calibration : Calibration or GeneralCalibration
        Paper form or general model.
    focal_length_mm : float
        Focal length for the paper form's decomposition [mm].
    pixel_pitch_um : float
        Pixel pitch for the paper form's decomposition [µm].
    laser_origin_x_mm : float
        The laser origin's distance along the optical axis from the lens centre
        (the rig's ``laser.origin_x_mm``) [mm].

    Returns
    -------
    SheetGeometry
        In the sheet frame [mm].

    Raises
    ------
    CalibrationError
        The paper constants do not fit a Scheimpflug rig with this f and p.
    ValueError
        The sheet contains the optical axis direction (no laser origin on it).
    """
    origin, e_s, e_h = _sheet_axes(calibration, focal_length_mm, pixel_pitch_um)
    e_y = np.cross(e_h, e_s)
    e_y /= np.linalg.norm(e_y)
    coeff = np.linalg.solve(np.column_stack([e_s, e_y, e_h]), -origin)   # camera centre (0) = origin + …
    if abs(e_s[2]) < 1e-12:
        raise ValueError("the sheet's stage axis is perpendicular to the optical axis: no laser origin")
    s_laser = (laser_origin_x_mm - origin[2]) / e_s[2]                     # camera z = the optical axis
    return SheetGeometry(laser_mm=np.array([s_laser, 0.0, 0.0]), camera_mm=coeff)


# ---------------------------------------------------------------- the normal from the scan grid


def _runs(key: np.ndarray, param: np.ndarray, xyz: np.ndarray, max_param_gap: float,
          step_factor: float, min_step_mm: float) -> tuple[np.ndarray, np.ndarray, float]:
    """First and last index of each sorted point's run, and the median step [mm].

    A run breaks at a new key, a parameter gap over ``max_param_gap`` or a step
    longer than ``step_factor`` × the median step and ``min_step_mm``.
    """
    n = key.size
    step = np.linalg.norm(np.diff(xyz, axis=0), axis=1)
    same = (key[1:] == key[:-1]) & (np.diff(param) <= max_param_gap)
    typical = float(np.median(step[same])) if same.any() else 0.0
    same &= step <= max(step_factor * typical, min_step_mm)
    first = np.maximum.accumulate(np.r_[0, np.where(same, 0, np.arange(1, n))])
    last = np.minimum.accumulate(np.r_[np.where(same, n, np.arange(n - 1)), n - 1][::-1])[::-1]
    return first, last, typical


def _local_slopes(t: np.ndarray, p: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Slope dp/dt at each point from a quadratic (≥ 3 points) or linear fit over [lo, hi] about it."""
    n = t.size
    width = int((hi - lo).max()) if n else 0
    i = np.arange(n)
    mom = np.zeros((n, 5))
    rhs = np.zeros((n, 3, 3))
    for j in range(width + 1):
        q = lo + j
        ok = q <= hi
        qc = np.where(ok, q, i)
        tau = np.where(ok, t[qc] - t, 0.0)
        w = ok.astype(np.float64)
        powers = w[:, None] * tau[:, None] ** np.arange(5)[None, :]
        mom += powers
        rhs += powers[:, :3, None] * p[qc][:, None, :]
    quad = (hi - lo) >= 2
    out = np.full((n, 3), np.nan)
    a = mom[:, [[0, 1, 2], [1, 2, 3], [2, 3, 4]]]
    det3 = np.linalg.det(a[quad]) if quad.any() else np.zeros(0)
    good = np.zeros(n, dtype=bool)
    good[np.flatnonzero(quad)[np.abs(det3) > 1e-12]] = True
    if good.any():
        out[good] = np.linalg.solve(a[good], rhs[good])[:, 1, :]
    lin = ((hi - lo) == 1) & ~good
    if lin.any():
        b = mom[lin][:, [[0, 1], [1, 2]]]
        out[lin] = np.linalg.solve(b, rhs[lin][:, :2, :])[:, 1, :]
    return out


def _tangents(key, param, xyz, half_window_mm: float, max_param_gap: float) -> np.ndarray:
    """Tangent of each point over 2k + 1 points of its run (shifted inside it at its ends).

    The points are ordered by ``param`` within each ``key``; the fit's parameter is the
    chord length along the run (a stripe that runs along the rows, at the top of a
    section, moves far between rows: its position is no smooth function of the row).
    """
    order = np.lexsort((param, key))
    t, p = param[order].astype(np.float64), xyz[order]
    first, last, typical = _runs(key[order], t, p, max_param_gap, step_factor=10.0,
                                 min_step_mm=2.0 * half_window_mm)
    k = int(np.clip(round(half_window_mm / typical), 1, 50)) if typical > 0 else 1
    i = np.arange(t.size)
    lo = np.maximum(np.minimum(i - k, last - 2 * k), first)
    hi = np.minimum(lo + 2 * k, last)
    chord = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))]   # arc-length parameter
    out = np.empty((t.size, 3))
    out[order] = _local_slopes(chord, p, lo, hi)
    return out


def grid_normals(xyz_mm, frame, row, half_window_mm: float = 0.5) -> np.ndarray:
    """Unit surface normals of a scan's points from its frame × row grid.

    Along each frame's profile, the tangent is the least-squares slope of the
    points against their row over ±k rows; across profiles, against the frame
    index over ±k frames of the same row (k the number of grid steps spanning
    ``half_window_mm``, 1 … 50).  A run of neighbours breaks at a missing row
    (frame) gap of more than 2 (1) or at a jump longer than 10 × the median
    step (and than twice ``half_window_mm``): another surface.  The normal is
    the cross product of the two tangents.

    Parameters
    ----------
    xyz_mm : (n, 3) array_like float
        Points [mm], any frame.
    frame : (n,) array_like int
        Frame index of each point.
    row : (n,) array_like int
        Sensor row of each point [px].
    half_window_mm : float
        Half length of the neighbourhood along each direction [mm], > 0.

    Returns
    -------
    (n, 3) ndarray float64
        Unit normals in the frame of ``xyz_mm``, oriented arbitrarily (only
        their line matters); NaN where a direction has fewer than 2 points.

    Raises
    ------
    ValueError
        Shapes that do not match, or ``half_window_mm`` ≤ 0.
    """
    p = np.asarray(xyz_mm, np.float64)
    f, r = np.asarray(frame, np.int64), np.asarray(row, np.int64)
    if p.ndim != 2 or p.shape[1] != 3 or f.shape != (len(p),) or r.shape != (len(p),):
        raise ValueError(f"need xyz (n, 3), frame (n,) and row (n,), got {p.shape}, {f.shape}, {r.shape}")
    if not half_window_mm > 0:
        raise ValueError(f"half_window_mm must be > 0, got {half_window_mm}")
    if len(p) == 0:
        return np.zeros((0, 3))
    along = _tangents(f, r, p, half_window_mm, max_param_gap=2)
    across = _tangents(r, f, p, half_window_mm, max_param_gap=1)
    n = np.cross(along, across)
    with np.errstate(invalid="ignore", divide="ignore"):
        return n / np.linalg.norm(n, axis=1, keepdims=True)


def incidence_angles(xyz_mm, angle_deg, normal, geometry: SheetGeometry, axis_mm: float,
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Incidence of the laser ray and of the camera's line of sight at each point.

    Parameters
    ----------
    xyz_mm : (n, 3) array_like float
        Points in the reconstruction's part frame (:func:`scheimpflug.reconstruct.part_from_sheet`) [mm].
    angle_deg : (n,) array_like float
        Rotary angle θ of each point's frame [deg].
    normal : (n, 3) array_like float
        Unit surface normals in the same frame (:func:`grid_normals`), NaN where unknown.
    geometry : SheetGeometry
        Laser origin and camera centre in the sheet frame.
    axis_mm : float
        Stage coordinate of the rotary axis [mm].

    Returns
    -------
    laser_deg, camera_deg : (n,) ndarray float64
        Angles between the normal's line and the ray from the laser origin to
        the point, and the ray from the point to the camera centre, in [0, 90]
        [deg]; NaN where the normal is.
    """
    p = np.asarray(xyz_mm, np.float64)
    n = np.asarray(normal, np.float64)
    th = np.radians(np.asarray(angle_deg, np.float64))
    c, s = np.cos(th), np.sin(th)

    def to_sheet(v):                       # the frame of θ: R_z(θ)·v (part_from_sheet inverted)
        return np.column_stack([c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1], v[:, 2]])

    q = to_sheet(p) + np.array([axis_mm, 0.0, 0.0])
    nq = to_sheet(n)

    def angle(ray):
        with np.errstate(invalid="ignore", divide="ignore"):
            cos = np.abs(np.sum(nq * ray, axis=1)) / np.linalg.norm(ray, axis=1)
        return np.degrees(np.arccos(np.clip(cos, 0.0, 1.0)))

    return angle(q - geometry.laser_mm), angle(geometry.camera_mm - q)


#: A sweep-edge point lit at less than this fraction of its row's neighbour (Lambert-corrected) is
#: partly lit: the sheet's centre plane misses it by more than 0.59 of the 1/e² half-thickness [-].
PARTLY_LIT_FRACTION = 0.5


def _row_neighbours(f: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index of the point in the same row of frame f − 1 and of frame f + 1 (−1: none)."""
    span = int(r.max() - r.min()) + 3
    key = (f + 1) * span + (r - r.min() + 1)
    order = np.argsort(key, kind="stable")
    known = key[order]

    def at(df):
        q = key + df * span
        j = np.clip(np.searchsorted(known, q), 0, known.size - 1)
        return np.where(known[j] == q, order[j], -1)

    return at(-1), at(1)


def sweep_edges(frame, row, n_frames: int, intensity=None, incidence_laser_deg=None) -> np.ndarray:
    """Which points lie on a partly lit edge of the sheet's sweep over the surface.

    A point of frame f, row r is on the sweep edge when the scan has a frame
    f − 1 (or f + 1) and that frame has no point in row r: between the two
    frames the sheet entered or left the surface.  If it entered by less than
    its own thickness, only part of the sheet's profile lights the surface, the
    lit footprint's centre lies off the sheet's centre plane, and the camera
    sees that offset with the parallax of its triangulation angle γ (a
    footprint centred y off the plane moves the point by ≈ y·cot γ along the
    sheet: up to 0.85 mm on the paper rig, w = 0.15 mm, γ ≈ 10°).  Such a
    point is dimmer than the same row's point in the adjacent frame beyond
    what Lambert's law says: with ``intensity`` given, an edge point is flagged
    when its peak over cos(laser incidence) is below
    :data:`PARTLY_LIT_FRACTION` of its neighbour's (a row seen in one frame
    only is flagged); without, every edge point is.

    Parameters
    ----------
    frame : (n,) array_like int
        Frame index of each point, 0 … n_frames − 1.
    row : (n,) array_like int
        Sensor row of each point [px].
    n_frames : int
        Frames in the scan.
    intensity : (n,) array_like float, optional
        Stripe peak of each point above the background [DN].
    incidence_laser_deg : (n,) array_like float, optional
        Laser incidence of each point [deg] (NaN or None: no cos correction).

    Returns
    -------
    (n,) ndarray bool
        True on a (partly lit) sweep edge.

    Raises
    ------
    ValueError
        Shapes that differ, or a frame index outside 0 … n_frames − 1.
    """
    f, r = np.asarray(frame, np.int64), np.asarray(row, np.int64)
    if f.shape != r.shape or f.ndim != 1:
        raise ValueError(f"frame and row must be (n,) alike, got {f.shape} and {r.shape}")
    if f.size and (f.min() < 0 or f.max() >= n_frames):
        raise ValueError(f"frame indices must lie in [0, {n_frames}), got [{f.min()}, {f.max()}]")
    if f.size == 0:
        return np.zeros(0, dtype=bool)
    before, after = _row_neighbours(f, r)
    miss_before, miss_after = (f > 0) & (before < 0), (f < n_frames - 1) & (after < 0)
    edge = miss_before | miss_after
    if intensity is None:
        return edge
    cos = np.ones(f.size) if incidence_laser_deg is None else np.cos(np.radians(incidence_laser_deg))
    lit = np.asarray(intensity, np.float64) / np.where(np.isfinite(cos) & (cos > 0), cos, 1.0)
    other = np.where(miss_before, after, before)          # the row's neighbour on the surface's side
    with np.errstate(invalid="ignore", divide="ignore"):
        fraction = np.where(other >= 0, lit / lit[np.maximum(other, 0)], np.nan)
    return edge & ~(fraction >= PARTLY_LIT_FRACTION)


def assess_points(cloud, geometry: SheetGeometry, axis_mm: float, n_frames: int,
                  half_window_mm: float = 0.5):
    """A cloud with the incidences and the sweep edge of every point (the grid's measures).

    Parameters
    ----------
    cloud : scheimpflug.reconstruct.PointCloud
        A rotary scan's cloud with its frame and row per point (part frame of
        :func:`scheimpflug.reconstruct.part_from_sheet`).
    geometry : SheetGeometry
        Laser origin and camera centre (:func:`sheet_geometry`).
    axis_mm : float
        Stage coordinate of the rotary axis [mm].
    n_frames : int
        Frames in the scan.
    half_window_mm : float
        Neighbourhood of the normal's estimate (:func:`grid_normals`) [mm].

    Returns
    -------
    PointCloud
        ``cloud`` with ``incidence_laser_deg``, ``incidence_camera_deg`` and ``sweep_edge`` set.

    Raises
    ------
    ValueError
        If the cloud has no frame index per point.
    """
    import dataclasses

    if cloud.frame is None or (len(cloud) and np.min(cloud.frame) < 0):
        raise ValueError("the point quality needs every point's frame index (its place on the scan grid)")
    normal = grid_normals(cloud.xyz_mm, cloud.frame, cloud.row, half_window_mm)
    laser, camera = incidence_angles(cloud.xyz_mm, cloud.angle_deg, normal, geometry, axis_mm)
    edge = sweep_edges(cloud.frame, cloud.row, n_frames, cloud.intensity, laser)
    return dataclasses.replace(cloud, incidence_laser_deg=laser, incidence_camera_deg=camera, sweep_edge=edge)


# ---------------------------------------------------------------- the filter


@dataclass(frozen=True)
class QualityFilter:
    """Which points a scan keeps (module docstring: the default and why).

    Parameters
    ----------
    max_incidence_deg : float
        Largest laser and camera incidence kept [deg], in (0, 90]; 90 keeps all.
    min_snr : float
        Smallest peak SNR kept [-], ≥ 0.
    drop_sweep_edges : bool
        Drop the points on the sheet's sweep edge (:func:`sweep_edges`).
    """

    max_incidence_deg: float = 75.0
    min_snr: float = 13.0
    drop_sweep_edges: bool = True

    def __post_init__(self) -> None:
        if not 0 < self.max_incidence_deg <= 90:
            raise ValueError(f"max_incidence_deg must be in (0, 90], got {self.max_incidence_deg}")
        if not self.min_snr >= 0:
            raise ValueError(f"min_snr must be >= 0, got {self.min_snr}")

    def to_json_dict(self) -> dict:
        """The thresholds, JSON-ready.

        Returns
        -------
        dict
            ``max_incidence_deg`` [deg], ``min_snr`` [-], ``drop_sweep_edges``.
        """
        return {"max_incidence_deg": float(self.max_incidence_deg), "min_snr": float(self.min_snr),
                "drop_sweep_edges": bool(self.drop_sweep_edges)}


#: The filter ``reconstruct`` and ``acceptance`` apply unless told otherwise (module docstring).
DEFAULT_FILTER = QualityFilter()


def quality_mask(cloud, quality: QualityFilter) -> np.ndarray:
    """Which points of a cloud pass a quality filter.

    Parameters
    ----------
    cloud : scheimpflug.reconstruct.PointCloud
        Points with (some of) their quality fields; a field that is None or
        NaN is unknown and fails nothing.
    quality : QualityFilter
        The thresholds.

    Returns
    -------
    (n,) ndarray bool
        True where no known quality fails its threshold.
    """
    n = len(cloud)

    def fails(name, bad):
        x = getattr(cloud, name)
        if x is None:
            return np.zeros(n, dtype=bool)
        x = np.asarray(x, np.float64)
        with np.errstate(invalid="ignore"):
            return np.isfinite(x) & bad(x)

    sat = _saturated(cloud)
    out = ~((fails("snr", lambda x: x < quality.min_snr) & ~sat) | _uncertain_saturated(cloud, quality, sat)
            | fails("incidence_laser_deg", lambda x: x > quality.max_incidence_deg)
            | fails("incidence_camera_deg", lambda x: x > quality.max_incidence_deg))
    if quality.drop_sweep_edges and cloud.sweep_edge is not None:
        out &= ~np.asarray(cloud.sweep_edge, dtype=bool)
    return out


def _saturated(cloud) -> np.ndarray:
    """The cloud's saturation flags (all False where unknown)."""
    if cloud.saturated is None:
        return np.zeros(len(cloud), dtype=bool)
    return np.asarray(cloud.saturated, dtype=bool)


def _uncertain_saturated(cloud, quality: QualityFilter, sat: np.ndarray) -> np.ndarray:
    """Saturated points whose centre is less certain than ``min_snr`` makes an unsaturated one's."""
    if cloud.centre_sigma_px is None or cloud.stripe_width_px is None or not sat.any():
        return np.zeros(len(cloud), dtype=bool)
    sigma = np.asarray(cloud.centre_sigma_px, np.float64)
    bound = centre_crb_px(cloud.stripe_width_px, quality.min_snr)
    with np.errstate(invalid="ignore"):
        return sat & np.isfinite(sigma) & np.isfinite(bound) & (sigma > bound)


def filter_counts(cloud, quality: QualityFilter) -> dict:
    """How many points each criterion of a filter drops (a point may fail several).

    Parameters
    ----------
    cloud : scheimpflug.reconstruct.PointCloud
        Points with their quality fields.
    quality : QualityFilter
        The thresholds.

    Returns
    -------
    dict
        ``n_points``, ``n_kept``, ``low_snr`` (unsaturated points), ``uncertain_saturated``
        (saturated points whose centre σ exceeds the SNR threshold's bound), ``laser_incidence``,
        ``camera_incidence``, ``sweep_edge``.
    """
    def count(name, bad):
        x = getattr(cloud, name)
        if x is None:
            return 0
        with np.errstate(invalid="ignore"):
            return int(np.count_nonzero(bad(np.asarray(x, np.float64))))

    t = quality.max_incidence_deg
    edge = 0 if cloud.sweep_edge is None or not quality.drop_sweep_edges else int(np.count_nonzero(cloud.sweep_edge))
    sat = _saturated(cloud)
    with np.errstate(invalid="ignore"):
        low = 0 if cloud.snr is None else int(np.count_nonzero((np.asarray(cloud.snr, np.float64) < quality.min_snr)
                                                               & ~sat))
    return {"n_points": len(cloud), "n_kept": int(np.count_nonzero(quality_mask(cloud, quality))),
            "low_snr": low, "uncertain_saturated": int(np.count_nonzero(_uncertain_saturated(cloud, quality, sat))),
            "laser_incidence": count("incidence_laser_deg", lambda x: x > t),
            "camera_incidence": count("incidence_camera_deg", lambda x: x > t), "sweep_edge": edge}
