"""Reconstruction: stripe profiles of a rotary scan → a point cloud in the part frame.

Each frame's stripe gives, per row v, a column u.  The calibration maps the
pixel to a stage coordinate and a height on the light sheet (paper Eqs. 11–12)

    s(u)    = F² / (u − u_h) + d0          [mm]
    h(u, v) = C · (v − v_h) / (u − u_h)    [mm]

and the rotary stage's angle θ of the frame turns the sheet point back into
the part's own frame (docs/reference/interface.md stage conventions):

    p_part = R_z(−θ) · (s − axis_mm, 0, h) = ((s − a) cos θ, −(s − a) sin θ, h)

The part frame has its origin on the rotary axis at the height of the meridian
plane (the optical axis), +z up and +x along the laser propagation at θ = 0,
i.e. the frame of the twin's ``truth/mesh.ply``.

Everything here is pure numpy; reading frames, extracting stripes and writing
the PLY happen in ``scheimpflug.app.commands.reconstruct``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from scheimpflug.callbacks import ProgressCallback, report
from scheimpflug.model.hinge import stage_from_pixel
from scheimpflug.model.rig import Sensor
from scheimpflug.point_quality import centre_crb_px, stripe_widths_px
from scheimpflug.stripe import (
    DEFAULT_WINDOW_PX,
    extract_stripes,
    image_pixels,
    measured_stripe_sigma_px,
    oriented,
    saturated_fraction,
    stripe_window_px,
)

__all__ = [
    "ISOLATION_PX",
    "FolderStripes",
    "PointCloud",
    "SATURATED_CHOICES",
    "SheetCalibration",
    "calibration_axis",
    "dn_per_electron",
    "extract_folder",
    "extract_folder_stripes",
    "isolated_rows",
    "part_from_camera",
    "part_from_sheet",
    "points_from_pixels",
    "reconstruct_profiles",
    "sheet_from_pixels",
]


# A Protocol is never instantiated: its (*args, **kwargs) constructor has nothing to document.
class SheetCalibration(Protocol):  # numpydoc ignore=PR01
    """The paper form's constants (``scheimpflug.calibration.Calibration`` has them).

    Reconstruction takes any object with a ``stage_from_pixel(u, v)`` method
    (:class:`scheimpflug.sheet_model.SheetModel`: the paper form or the general
    model); a bare set of these constants is mapped with paper Eqs. 11–12.

    Attributes
    ----------
    hinge_u_px, hinge_v_px : float
        Image hinge (u_h, v_h) [px].
    F2_px_mm : float
        Distance constant F² [px·mm].
    d0_mm : float
        Stage coordinate of the object hinge [mm].
    C_mm : float
        Height constant C [mm].
    """

    hinge_u_px: float
    hinge_v_px: float
    F2_px_mm: float
    d0_mm: float
    C_mm: float


def sheet_from_pixels(u, v, calibration) -> tuple[np.ndarray, np.ndarray]:
    """Stage coordinate and height of pixels through any calibration.

    Parameters
    ----------
    u, v : array_like float
        Column and row [px].
    calibration : SheetModel or SheetCalibration
        An object with ``stage_from_pixel(u, v)`` (paper form or general model), or the
        paper constants alone.

    Returns
    -------
    stage_mm, h_mm : ndarray float64
        [mm].
    """
    if hasattr(calibration, "stage_from_pixel"):
        return calibration.stage_from_pixel(u, v)
    return stage_from_pixel(u, v, calibration.hinge_u_px, calibration.hinge_v_px,
                            calibration.F2_px_mm, calibration.d0_mm, calibration.C_mm)


@dataclass(frozen=True)
class PointCloud:
    """A reconstructed point cloud with per-point provenance.

    ``len(cloud)`` is the number of points n.

    Parameters
    ----------
    xyz_mm : (n, 3) ndarray float
        Points in the part frame [mm].
    angle_deg : (n,) ndarray float
        Rotary stage angle of the frame the point came from [deg].
    row : (n,) ndarray int
        Sensor row v of the stripe sample [px] (its column when the stripe runs along the
        rows: the line of the scan grid).
    intensity : (n,) ndarray float
        Stripe peak height above background [DN].
    frame : (n,) ndarray int or None
        Index of the frame the point came from, in the scan's frame order
        (−1 or None when unknown).  With ``row`` it places every point on
        the scan's grid (frame × row), which :mod:`scheimpflug.meshing` meshes.
    stripe_width_px, snr : (n,) ndarray float or None
        The point's measured quality (:mod:`scheimpflug.point_quality`): the
        stripe's RMS width in its row [px] and the peak's signal-to-noise
        ratio [-]; NaN or None when unknown.
    incidence_laser_deg, incidence_camera_deg : (n,) ndarray float or None
        Angles between the estimated surface normal and the laser ray / the
        camera's line of sight [deg] (NaN or None: unknown).
    sweep_edge : (n,) ndarray bool or None
        A partly lit edge of the sheet's sweep: the same row is empty in an
        adjacent frame of the scan and the point is dimmer than Lambert's law
        and that row's neighbour say (:func:`scheimpflug.point_quality.sweep_edges`;
        None: unknown).
    saturated : (n,) ndarray bool or None
        The stripe's peak was clipped at the saturation level in the point's row:
        its centre is the midpoint of the profile's two edges
        (:func:`scheimpflug.stripe.extract_stripes`, ``saturated="edges"``), its
        ``intensity`` and ``snr`` are lower bounds (None: unknown).
    centre_sigma_px : (n,) ndarray float or None
        Standard uncertainty of the stripe centre from the noise [px]: a saturated
        row's propagated through its two edges (:class:`scheimpflug.stripe.StripeProfile`'s
        ``u_sigma``), an unsaturated row's Cramér–Rao bound from its width and SNR
        (:func:`scheimpflug.point_quality.centre_crb_px`); NaN or None when unknown.

    Raises
    ------
    ValueError
        If ``xyz_mm`` is not (n, 3) or another array is not (n,).
    """

    xyz_mm: np.ndarray
    angle_deg: np.ndarray
    row: np.ndarray
    intensity: np.ndarray
    frame: np.ndarray | None = None
    stripe_width_px: np.ndarray | None = None
    snr: np.ndarray | None = None
    incidence_laser_deg: np.ndarray | None = None
    incidence_camera_deg: np.ndarray | None = None
    sweep_edge: np.ndarray | None = None
    saturated: np.ndarray | None = None
    centre_sigma_px: np.ndarray | None = None

    _PER_POINT = ("angle_deg", "row", "intensity", "frame", "stripe_width_px", "snr",
                  "incidence_laser_deg", "incidence_camera_deg", "sweep_edge", "saturated", "centre_sigma_px")

    def __post_init__(self) -> None:
        n = np.asarray(self.xyz_mm).shape[0]
        if np.asarray(self.xyz_mm).shape != (n, 3):
            raise ValueError(f"xyz_mm must be (n, 3), got {np.asarray(self.xyz_mm).shape}")
        for name in self._PER_POINT:
            if getattr(self, name) is not None and np.asarray(getattr(self, name)).shape != (n,):
                raise ValueError(f"{name} must have shape ({n},), got {np.asarray(getattr(self, name)).shape}")

    def __len__(self) -> int:
        return int(self.xyz_mm.shape[0])

    def select(self, keep) -> PointCloud:
        """The points where ``keep`` holds, with all their per-point fields.

        Parameters
        ----------
        keep : (n,) array_like bool or int
            Mask or indices of the points kept.

        Returns
        -------
        PointCloud
            The subset (fields that are None stay None).
        """
        def pick(a):
            return None if a is None else np.asarray(a)[keep]

        return PointCloud(xyz_mm=np.asarray(self.xyz_mm)[keep],
                          **{name: pick(getattr(self, name)) for name in self._PER_POINT})


def part_from_sheet(stage_mm, h_mm, angle_deg, axis_mm: float) -> np.ndarray:
    """Part-frame points of sheet points seen at rotary angle θ.

    Parameters
    ----------
    stage_mm, h_mm : array_like float
        Stage coordinate along the sheet and height above the meridian plane [mm].
    angle_deg : array_like float
        Rotary stage angle θ of each point's frame [deg]; the three inputs
        broadcast together.
    axis_mm : float
        Stage coordinate of the rotary axis [mm].

    Returns
    -------
    (n, 3) ndarray float64
        ``R_z(−θ) · (s − axis_mm, 0, h)`` in the part frame [mm], n the size
        of the broadcast inputs (flattened).
    """
    s, h, th = np.broadcast_arrays(np.asarray(stage_mm, np.float64), np.asarray(h_mm, np.float64),
                                   np.radians(np.asarray(angle_deg, np.float64)))
    r = s - axis_mm
    return np.stack([r * np.cos(th), -r * np.sin(th), h], axis=-1).reshape(-1, 3)


def part_from_camera(points_mm, angle_deg, axis: dict, e_s) -> np.ndarray:
    """Part-frame points of camera-frame points seen at rotary angle θ, about an axis measured in 3-D.

    A calibration that measured the rotary axis (a pattern on the table, a foreign
    calibration's turntable pose) knows it as a line of the camera frame, which
    need not lie in the sheet.  The part frame is then the axis's own: ``z`` along
    the axis (``direction``, turned to the sheet's height axis), ``x`` the
    sheet's stage axis ``e_s`` made perpendicular to it, ``y = z × x``, the origin
    at ``origin_mm`` (the axis point at the sheet's h = 0), turned by ``R_z(−θ)``.
    For an axis in the sheet this is :func:`part_from_sheet` exactly.

    Parameters
    ----------
    points_mm : (n, 3) array_like float
        Camera-frame points [mm].
    angle_deg : array_like float
        Rotary angle θ of each point's frame [deg] (broadcast to n).
    axis : dict
        ``direction`` (3,) and ``origin_mm`` (3,) (or ``point_mm``) of the axis, camera frame
        (:func:`scheimpflug.calibration.target.axis_in_sheet`).
    e_s : (3,) array_like float
        The sheet's stage axis, camera frame [-].

    Returns
    -------
    (n, 3) ndarray float64
        Points in the part frame [mm].
    """
    x = np.asarray(points_mm, np.float64).reshape(-1, 3)
    z = np.asarray(axis["direction"], np.float64)
    z = z / np.linalg.norm(z)
    e = np.asarray(e_s, np.float64)
    xa = e - (e @ z) * z
    xa /= np.linalg.norm(xa)
    ya = np.cross(z, xa)
    rel = x - np.asarray(axis.get("origin_mm", axis["point_mm"]), np.float64)
    a, b, c = rel @ xa, rel @ ya, rel @ z
    th = np.radians(np.broadcast_to(np.asarray(angle_deg, np.float64), a.shape))
    cos, sin = np.cos(th), np.sin(th)
    return np.stack([a * cos + b * sin, -a * sin + b * cos, c], axis=-1)


def calibration_axis(calibration) -> tuple[dict, np.ndarray] | None:
    """The rotary axis a calibration measured in 3-D, and its sheet's stage axis, or None.

    Parameters
    ----------
    calibration : SheetModel
        A calibration; a target calibration with table poses and FabScan's carry an axis.

    Returns
    -------
    (dict, (3,) ndarray) or None
        The axis (:func:`scheimpflug.calibration.target.axis_in_sheet`'s keys; ``direction``
        turned to point along the sheet's height axis) and ``e_s`` (camera frame); None for a
        calibration without one.
    """
    axis = getattr(calibration, "axis", None)
    if not isinstance(axis, dict) or "direction" not in axis or not hasattr(calibration, "sheet_frame"):
        return None
    _, e_s, e_h = calibration.sheet_frame()
    w = np.asarray(axis["direction"], np.float64)
    return {**axis, "direction": (w if w @ e_h >= 0 else -w).tolist()}, e_s


def points_from_pixels(u, v, angle_deg, calibration, axis_mm: float | None) -> np.ndarray:
    """Part-frame points of stripe pixels seen at rotary angles (the sheet mapping, then the stage).

    Parameters
    ----------
    u, v : array_like float
        Stripe column and row on the sensor [px].
    angle_deg : array_like float
        Rotary stage angle of each pixel's frame [deg]; ``u``, ``v`` and
        ``angle_deg`` broadcast together.
    calibration : SheetModel or SheetCalibration
        Paper form or general model (:func:`sheet_from_pixels`).
    axis_mm : float or None
        Stage coordinate of the rotary axis [mm] (the axis in the sheet: :func:`part_from_sheet`);
        None: the calibration's own axis, measured in 3-D (:func:`part_from_camera`; a target
        calibration with table poses, FabScan's turntable).

    Returns
    -------
    (n, 3) ndarray float64
        Points in the part frame [mm] (flattened); NaN for u = u_h.

    Raises
    ------
    ValueError
        If ``u`` and ``v`` do not broadcast together, or ``axis_mm`` is None for a calibration
        without a 3-D axis.
    """
    if axis_mm is None:
        found = calibration_axis(calibration)
        if found is None:
            raise ValueError("axis_mm is None but the calibration holds no rotary axis")
        uu, vv, aa = np.broadcast_arrays(np.asarray(u, np.float64), np.asarray(v, np.float64),
                                         np.asarray(angle_deg, np.float64))
        return part_from_camera(calibration.camera_from_pixel(uu.ravel(), vv.ravel()), aa.ravel(), *found)
    s, h = sheet_from_pixels(u, v, calibration)
    return part_from_sheet(s, h, angle_deg, axis_mm)


def reconstruct_profiles(rows: Sequence[np.ndarray], u: Sequence[np.ndarray],
                         angles_deg: Iterable[float], calibration,
                         axis_mm: float, intensity: Sequence[np.ndarray] | None = None,
                         snr: Sequence[np.ndarray] | None = None,
                         stripe_width_px: Sequence[np.ndarray] | None = None,
                         along: str = "columns", saturated: Sequence[np.ndarray] | None = None,
                         centre_sigma_px: Sequence[np.ndarray] | None = None) -> PointCloud:
    """Point cloud of a rotary scan from per-frame stripe samples.

    Parameters
    ----------
    rows : sequence of (n_i,) int
        Rows of the stripe samples of each frame (columns for ``along="rows"``) [px].
    u : sequence of (n_i,) float
        Stripe columns of each frame (rows for ``along="rows"``) [px].
    angles_deg : iterable of float
        Rotary angle of each frame [deg].
    calibration : SheetModel or SheetCalibration
        Paper form or general model (``scheimpflug.sheet_model.load_sheet_model(...)``).
    axis_mm : float or None
        Stage coordinate of the rotary axis [mm]; None: the calibration's 3-D axis
        (:func:`points_from_pixels`).
    intensity : sequence of (n_i,) float, optional
        Per-sample intensity [DN] (default NaN).
    snr, stripe_width_px : sequence of (n_i,) float, optional
        Per-sample peak SNR [-] and stripe RMS width [px] (:class:`FolderStripes`;
        default: the cloud has none).
    along : {"columns", "rows"}, default "columns"
        The frames' stripe orientation (:func:`scheimpflug.stripe.image_pixels`).
    saturated, centre_sigma_px : sequence of (n_i,) bool / float, optional
        Per-sample saturation flag and centre uncertainty [px] (:class:`FolderStripes`;
        default: the cloud has none).

    Returns
    -------
    PointCloud
        Points in the part frame; samples with a non-finite u (or u = u_h)
        are dropped.  Every point keeps its frame index and line (``row``: its
        place on the scan's grid).

    Raises
    ------
    ValueError
        If ``rows``, ``u``, ``angles_deg`` (and ``intensity``, ``snr``,
        ``stripe_width_px``, ``saturated``, ``centre_sigma_px``) do not have one entry
        per frame, or a frame's ``rows`` and ``u`` differ in size.
    """
    angles = np.asarray(list(angles_deg), dtype=np.float64)
    if not (len(rows) == len(u) == len(angles)) or (intensity is not None and len(intensity) != len(u)):
        raise ValueError(f"rows, u, intensity and angles must have one entry per frame "
                         f"(got {len(rows)}, {len(u)}, {len(intensity) if intensity is not None else '-'}, "
                         f"{len(angles)})")
    sizes = [np.asarray(x).size for x in u]
    if any(np.asarray(r).size != n for r, n in zip(rows, sizes)):
        raise ValueError("each frame needs as many rows as u values")

    def cat(xs) -> np.ndarray:
        return np.concatenate([np.asarray(x, np.float64).ravel() for x in xs]) if len(xs) else np.zeros(0)

    uu, vv = cat(u), cat(rows)
    ii = cat(intensity) if intensity is not None else np.full(uu.size, np.nan)
    aa = np.repeat(angles, sizes)
    ff = np.repeat(np.arange(len(angles), dtype=np.int64), sizes)
    xyz = points_from_pixels(*image_pixels(vv, uu, along), aa, calibration, axis_mm)
    ok = np.all(np.isfinite(xyz), axis=1)
    extra = {}
    for name, per_frame in (("snr", snr), ("stripe_width_px", stripe_width_px), ("saturated", saturated),
                            ("centre_sigma_px", centre_sigma_px)):
        if per_frame is not None:
            if len(per_frame) != len(u) or any(np.asarray(x).size != k for x, k in zip(per_frame, sizes)):
                raise ValueError(f"{name} needs one value per stripe sample of every frame")
            extra[name] = cat(per_frame)[ok]
    if "saturated" in extra:
        extra["saturated"] = extra["saturated"] > 0.5
    return PointCloud(xyz_mm=xyz[ok], angle_deg=aa[ok], row=vv[ok].astype(np.int64),
                      intensity=ii[ok], frame=ff[ok], **extra)


ISOLATION_PX = 2.0  # a row's stripe needs a neighbour row's within this many columns [px]


def isolated_rows(rows: np.ndarray, u: np.ndarray, max_gap_px: float = ISOLATION_PX) -> np.ndarray:
    """Which stripe samples of one frame have no neighbour in the adjacent rows.

    Parameters
    ----------
    rows : (n,) ndarray int
        Rows of the samples, increasing [px].
    u : (n,) ndarray float
        Their columns [px].
    max_gap_px : float
        A sample in row r ± 1 within this many columns counts as a neighbour [px].

    Returns
    -------
    (n,) ndarray bool
        True where neither row r − 1 nor row r + 1 holds a sample within
        ``max_gap_px`` of the sample's column.
    """
    rows = np.asarray(rows)
    u = np.asarray(u, dtype=np.float64)
    if rows.size == 0:
        return np.zeros(0, dtype=bool)
    lone = np.ones(rows.size, dtype=bool)
    for step in (-1, 1):
        j = np.searchsorted(rows, rows + step)
        j = np.clip(j, 0, rows.size - 1)
        near = (rows[j] == rows + step) & (np.abs(u[j] - u) <= max_gap_px)
        lone &= ~near
    return lone


@dataclass(frozen=True)
class FolderStripes:
    """The stripe samples of every frame of a folder, with their measured quality.

    A sample is a *line* of the frame (a row; a column when the stripe runs along the
    rows, ``along="rows"``: :func:`scheimpflug.stripe.oriented`) and the stripe's sub-pixel
    position across it; :func:`scheimpflug.stripe.image_pixels` gives the frame pixel.

    Parameters
    ----------
    rows : list of (n_i,) ndarray int64
        Lines of each frame's samples (rows, or columns for ``along="rows"``) [px], in manifest order.
    u : list of (n_i,) ndarray float64
        Stripe positions across the lines (columns, or rows for ``along="rows"``) [px].
    peak : list of (n_i,) ndarray float64
        Peak height above the local background [DN].
    snr : list of (n_i,) ndarray float64
        Peak signal-to-noise ratio, the detector's score [-].
    stripe_width_px : list of (n_i,) ndarray float64
        RMS width of the stripe in each row [px] (:func:`scheimpflug.point_quality.stripe_widths_px`).
    stats : dict
        Counters of :func:`extract_folder`.
    along : {"columns", "rows"}, optional
        The folder's stripe orientation (default "columns").
    saturated : list of (n_i,) ndarray bool, optional
        The sample's peak was clipped (its centre from the edges, :data:`SATURATED_CHOICES`).
    centre_sigma_px : list of (n_i,) ndarray float64, optional
        Standard uncertainty of each centre from the noise [px]
        (:attr:`scheimpflug.reconstruct.PointCloud.centre_sigma_px`).
    """

    rows: list
    u: list
    peak: list
    snr: list
    stripe_width_px: list
    stats: dict
    along: str = "columns"
    saturated: list | None = None
    centre_sigma_px: list | None = None

    def select(self, keep) -> FolderStripes:
        """The same stripes with only the kept samples of each frame (``stats`` unchanged).

        Parameters
        ----------
        keep : list of (n_i,) array_like bool
            Per frame, which samples to keep.

        Returns
        -------
        FolderStripes
            The subset (per-sample lists that are None stay None).

        Raises
        ------
        ValueError
            ``keep`` not one mask per frame of each frame's size.
        """
        if len(keep) != len(self.rows) or any(np.shape(k) != np.shape(r) for k, r in zip(keep, self.rows)):
            raise ValueError("keep needs one boolean mask per frame, of the frame's number of samples")
        masks = [np.asarray(k, bool) for k in keep]

        def pick(values):
            return None if values is None else [np.asarray(v)[k] for v, k in zip(values, masks)]

        return FolderStripes(pick(self.rows), pick(self.u), pick(self.peak), pick(self.snr),
                             pick(self.stripe_width_px), self.stats, self.along, pick(self.saturated),
                             pick(self.centre_sigma_px))


SATURATED_CHOICES = ("edges", "drop", "plateau")
"""What :func:`extract_folder_stripes` does with a saturated row: its centre from the clipped
profile's two edges with its own uncertainty (the default), drop it (the default before
issue 34), or the middle of the run of saturated pixels (``--keep-saturated`` before issue 34)."""


def dn_per_electron(folder) -> float:
    """A frame folder's camera noise gain from its manifest's rig, 0 where unknown.

    Parameters
    ----------
    folder : scheimpflug.io.frames.FrameFolder
        The frames; a rendered folder's rig has the sensor's ``gain_e_per_dn`` (0: full
        well at full scale, ``full_well_e / (2**adc_bits − 1 − dark_offset_dn)``).

    Returns
    -------
    float
        DN per photo-electron [DN]; 0 for a folder without a sensor table (real frames:
        the noise's signal dependence unknown).
    """
    sensor = folder.rig.get("sensor") if isinstance(folder.rig, dict) else None
    if not isinstance(sensor, dict):
        return 0.0

    def value(key):
        v = sensor.get(key, getattr(Sensor, key))
        ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
        return float(v) if ok else float(getattr(Sensor, key))

    gain = value("gain_e_per_dn")
    if gain <= 0:
        gain = value("full_well_e") / max(2.0 ** value("adc_bits") - 1.0 - value("dark_offset_dn"), 1.0)
    return 1.0 / gain if gain > 0 else 0.0


def _centre_sigma(prof, width: np.ndarray) -> np.ndarray:
    """A profile's centre uncertainty: the edges' for clipped rows, the Cramér–Rao bound elsewhere [px]."""
    crb = centre_crb_px(width, prof.score)
    sat = prof.u_sigma if prof.u_sigma is not None else np.full(len(prof), np.nan)
    return np.where(prof.saturated, sat, crb)


def extract_folder_stripes(folder, method: str = "cog", *, min_snr: float = 6.0,
                           keep_saturated: bool | None = None, progress: ProgressCallback | None = None,
                           multi_peak: str = "nearest", window_px: int | str = "auto",
                           drop_isolated: bool = False, saturated: str = "edges") -> FolderStripes:
    """Stripe samples of every frame of a frame folder, with each row's SNR and stripe width.

    Parameters
    ----------
    folder : scheimpflug.io.frames.FrameFolder
        The frames (an opened folder, not a path).
    method : str, default "cog"
        Stripe centre method (:func:`scheimpflug.stripe.extract_stripes`).
    min_snr : float, default 6.0
        Detection threshold [-].
    keep_saturated : bool, optional
        The option before issue 34: True is ``saturated="edges"``, False ``"drop"``.
    progress : ProgressCallback, optional
        ``progress(done, total)`` after each frame (:mod:`scheimpflug.callbacks`).
    multi_peak : str
        Rule for rows with several peaks (:data:`scheimpflug.stripe.MULTI_PEAK_RULES`).
    window_px : int or "auto", default "auto"
        Detector window (:func:`extract_folder`).
    drop_isolated : bool, default False
        Drop lone rows (:func:`extract_folder`).
    saturated : {"edges", "drop", "plateau"}, default "edges"
        Rows whose stripe peak is saturated (:data:`SATURATED_CHOICES`); the noise of
        their edges grows with the signal by the folder's :func:`dn_per_electron`.

    Returns
    -------
    FolderStripes
        Per-frame arrays and counters (with each sample's saturation flag and centre
        uncertainty).

    Raises
    ------
    FrameError
        If a frame is missing or invalid.
    ValueError
        For an unknown ``method`` or ``saturated`` rule, or a bad ``min_snr``.
    """
    if keep_saturated is not None:
        saturated = "edges" if keep_saturated else "drop"
    if saturated not in SATURATED_CHOICES:
        raise ValueError(f"saturated must be one of {', '.join(SATURATED_CHOICES)}, got {saturated!r}")
    along = getattr(folder, "stripe_along", "columns")
    rule = {"saturated": "plateau" if saturated == "plateau" else "edges", "dn_per_electron": dn_per_electron(folder)}

    def one(rec, frame):
        frame = oriented(frame, along)
        sat = folder.saturation_dn(frame)
        prof = extract_stripes(frame, method, min_snr=min_snr, multi_peak=multi_peak,
                               saturation_dn=sat, window_px=window_px, **rule)
        win = window_px if isinstance(window_px, int) else \
            stripe_window_px(measured_stripe_sigma_px(frame, prof, DEFAULT_WINDOW_PX))
        width = stripe_widths_px(frame, prof.rows, prof.u, prof.background, min(win, 28))
        return prof, width, saturated_fraction(frame, sat) > 0.5

    out = FolderStripes([], [], [], [], [], {"blank_frames": 0, "saturated_rows": 0, "isolated_rows": 0,
                                            "saturated_frames": 0}, along, [], [])
    stats = out.stats
    for prof, width, blown in folder.map_frames(one):
        keep = ~prof.saturated if saturated == "drop" else np.ones(len(prof), dtype=bool)
        lone = isolated_rows(prof.rows, prof.u)
        stats["isolated_rows"] += int(lone.sum())
        if drop_isolated:
            keep &= ~lone
        stats["saturated_rows"] += int(prof.saturated.sum())
        stats["blank_frames"] += int(len(prof) == 0)
        stats["saturated_frames"] += int(blown)
        for field_, values in zip((out.rows, out.u, out.peak, out.snr, out.stripe_width_px, out.saturated,
                                   out.centre_sigma_px),
                                  (prof.rows, prof.u, prof.peak, prof.score, width, prof.saturated,
                                   _centre_sigma(prof, width))):
            field_.append(values[keep])
        report(progress, len(out.rows), len(folder))
    return out


def extract_folder(folder, method: str = "cog", *, min_snr: float = 6.0,
                   keep_saturated: bool | None = None, progress: ProgressCallback | None = None,
                   multi_peak: str = "nearest", window_px: int | str = "auto",
                   drop_isolated: bool = False, saturated: str = "edges"):
    """Stripe samples of every frame of a frame folder.

    Frames are decoded and extracted on threads (:meth:`FrameFolder.map_frames`).

    Parameters
    ----------
    folder : scheimpflug.io.frames.FrameFolder
        The frames (an opened folder, not a path).
    method : str, default "cog"
        Stripe centre method (:func:`scheimpflug.stripe.extract_stripes`).
    min_snr : float, default 6.0
        Detection threshold [-].
    keep_saturated : bool, optional
        The option before issue 34: True is ``saturated="edges"``, False ``"drop"``.
    progress : ProgressCallback, optional
        ``progress(done, total)`` after each frame (:mod:`scheimpflug.callbacks`).
    multi_peak : str
        Rule for rows with several peaks (:data:`scheimpflug.stripe.MULTI_PEAK_RULES`).
    window_px : int or "auto", default "auto"
        Detector window (:func:`scheimpflug.stripe.extract_stripes`): "auto"
        widens it beyond 7 px, frame by frame, for stripes wider than σ = 7/3 px.
    drop_isolated : bool, default False
        Drop a row's stripe when neither adjacent row has one within
        :data:`ISOLATION_PX` columns (:func:`isolated_rows`): a surface images to
        a run of rows, a lone detection is noise or stray light at a part's edge.
    saturated : {"edges", "drop", "plateau"}, default "edges"
        Rows whose stripe peak is saturated (:data:`SATURATED_CHOICES`).

    Returns
    -------
    rows, u, peak : list of ndarray
        One array per frame, in manifest order: rows (int64) [px], stripe
        columns (float64) [px], peak height above background (float64) [DN].
    stats : dict
        Counters ``blank_frames`` (no stripe row), ``saturated_rows``
        (counted whether kept or not), ``isolated_rows`` (dropped or not) and
        ``saturated_frames`` (more than half of the pixels at the saturation
        level: blown out).

    Raises
    ------
    FrameError
        If a frame is missing or invalid.
    ValueError
        For an unknown ``method`` or ``saturated`` rule, or a bad ``min_snr``.
    """
    res = extract_folder_stripes(folder, method, min_snr=min_snr, keep_saturated=keep_saturated,
                                 progress=progress, multi_peak=multi_peak, window_px=window_px,
                                 drop_isolated=drop_isolated, saturated=saturated)
    return res.rows, res.u, res.peak, res.stats
