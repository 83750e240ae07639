"""Reconstruction: stripe profiles of a rotary scan → a point cloud in the part frame.

Each frame's stripe gives, per row v, a column u.  The calibration maps the
pixel to a stage coordinate and a height on the light sheet (paper Eqs. 11–12)

    s(u)    = F² / (u − u_h) + d0          [mm]
    h(u, v) = C · (v − v_h) / (u − u_h)    [mm]

and the rotary stage's angle θ of the frame turns the sheet point back into
the part's own frame (INTERFACE.md stage conventions):

    p_part = R_z(−θ) · (s − axis_mm, 0, h) = ((s − a) cos θ, −(s − a) sin θ, h)

The part frame has its origin on the rotary axis at the height of the meridian
plane (the optical axis), +z up and +x along the laser propagation at θ = 0,
i.e. the frame of the twin's ``truth/mesh.ply``.

Everything here is pure numpy; reading frames, extracting stripes and writing
the PLY happen in ``scheimpflug.commands.reconstruct``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Protocol, Sequence

import numpy as np

__all__ = [
    "PointCloud",
    "SheetCalibration",
    "extract_folder",
    "part_from_sheet",
    "points_from_pixels",
    "reconstruct_profiles",
    "sheet_from_pixel",
]


class SheetCalibration(Protocol):
    """What reconstruction needs of a calibration (``scheimpflug.calibration.Calibration`` has it)."""

    hinge_u_px: float
    hinge_v_px: float
    F2_px_mm: float
    d0_mm: float
    C_mm: float


@dataclass(frozen=True)
class PointCloud:
    """A reconstructed point cloud with per-point provenance.

    Attributes
    ----------
    xyz_mm : (n, 3) float
        Points in the part frame [mm].
    angle_deg : (n,) float
        Rotary stage angle of the frame the point came from [deg].
    row : (n,) int
        Sensor row v of the stripe sample [px].
    intensity : (n,) float
        Stripe peak height above background [DN].
    """

    xyz_mm: np.ndarray
    angle_deg: np.ndarray
    row: np.ndarray
    intensity: np.ndarray

    def __post_init__(self) -> None:
        n = np.asarray(self.xyz_mm).shape[0]
        if np.asarray(self.xyz_mm).shape != (n, 3):
            raise ValueError(f"xyz_mm must be (n, 3), got {np.asarray(self.xyz_mm).shape}")
        for name in ("angle_deg", "row", "intensity"):
            if np.asarray(getattr(self, name)).shape != (n,):
                raise ValueError(f"{name} must have shape ({n},), got {np.asarray(getattr(self, name)).shape}")

    def __len__(self) -> int:
        return int(self.xyz_mm.shape[0])


def sheet_from_pixel(u, v, hinge_u_px: float, hinge_v_px: float, F2_px_mm: float,
                     d0_mm: float, C_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Stage coordinate and height of pixels on the light sheet (paper Eqs. 11–12).

    Parameters
    ----------
    u, v : array_like float
        Column and row of the stripe [px] (broadcast together).
    hinge_u_px, hinge_v_px : float
        Image hinge (u_h, v_h) [px].
    F2_px_mm : float
        Distance constant F² [px·mm].
    d0_mm : float
        Stage coordinate of the object hinge [mm].
    C_mm : float
        Height constant [mm].

    Returns
    -------
    stage_mm, h_mm : ndarray float
        ``F²/(u − u_h) + d0`` and ``C (v − v_h)/(u − u_h)`` [mm]; NaN where u = u_h.
    """
    du = np.asarray(u, dtype=np.float64) - hinge_u_px
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(du != 0, 1.0 / np.where(du != 0, du, 1.0), np.nan)
    return F2_px_mm * inv + d0_mm, C_mm * (np.asarray(v, dtype=np.float64) - hinge_v_px) * inv


def part_from_sheet(stage_mm, h_mm, angle_deg, axis_mm: float) -> np.ndarray:
    """Part-frame points of sheet points seen at rotary angle θ.

    Parameters
    ----------
    stage_mm, h_mm : array_like float
        Stage coordinate along the sheet and height [mm].
    angle_deg : array_like float
        Rotary stage angle θ of each point's frame [deg] (broadcast).
    axis_mm : float
        Stage coordinate of the rotary axis [mm].

    Returns
    -------
    (n, 3) float
        ``R_z(−θ) · (s − axis_mm, 0, h)`` [mm].
    """
    s, h, th = np.broadcast_arrays(np.asarray(stage_mm, np.float64), np.asarray(h_mm, np.float64),
                                   np.radians(np.asarray(angle_deg, np.float64)))
    r = s - axis_mm
    return np.stack([r * np.cos(th), -r * np.sin(th), h], axis=-1).reshape(-1, 3)


def points_from_pixels(u, v, angle_deg, calibration: SheetCalibration, axis_mm: float) -> np.ndarray:
    """Part-frame points (n, 3) [mm] of stripe pixels (u, v) [px] seen at angles [deg]."""
    s, h = sheet_from_pixel(u, v, calibration.hinge_u_px, calibration.hinge_v_px,
                            calibration.F2_px_mm, calibration.d0_mm, calibration.C_mm)
    return part_from_sheet(s, h, angle_deg, axis_mm)


def reconstruct_profiles(rows: Sequence[np.ndarray], u: Sequence[np.ndarray],
                         angles_deg: Iterable[float], calibration: SheetCalibration,
                         axis_mm: float, intensity: Sequence[np.ndarray] | None = None) -> PointCloud:
    """Point cloud of a rotary scan from per-frame stripe samples.

    Parameters
    ----------
    rows : sequence of (n_i,) int
        Rows of the stripe samples of each frame [px].
    u : sequence of (n_i,) float
        Stripe columns of each frame [px].
    angles_deg : iterable of float
        Rotary angle of each frame [deg].
    calibration : SheetCalibration
        Hinge, F², d0, C (e.g. ``Calibration.load(...)``).
    axis_mm : float
        Stage coordinate of the rotary axis [mm].
    intensity : sequence of (n_i,) float, optional
        Per-sample intensity [DN] (default NaN).

    Returns
    -------
    PointCloud
        Samples with a non-finite u (or u = u_h) are dropped.
    """
    angles = np.asarray(list(angles_deg), dtype=np.float64)
    if not (len(rows) == len(u) == len(angles)) or (intensity is not None and len(intensity) != len(u)):
        raise ValueError(f"rows, u, intensity and angles must have one entry per frame "
                         f"(got {len(rows)}, {len(u)}, {len(intensity) if intensity is not None else '-'}, "
                         f"{len(angles)})")
    sizes = [np.asarray(x).size for x in u]
    if any(np.asarray(r).size != n for r, n in zip(rows, sizes)):
        raise ValueError("each frame needs as many rows as u values")
    cat = (lambda xs: np.concatenate([np.asarray(x, np.float64).ravel() for x in xs])
           if len(xs) else np.zeros(0))
    uu, vv = cat(u), cat(rows)
    ii = cat(intensity) if intensity is not None else np.full(uu.size, np.nan)
    aa = np.repeat(angles, sizes)
    xyz = points_from_pixels(uu, vv, aa, calibration, axis_mm)
    ok = np.all(np.isfinite(xyz), axis=1)
    return PointCloud(xyz_mm=xyz[ok], angle_deg=aa[ok], row=vv[ok].astype(np.int64),
                      intensity=ii[ok])


def extract_folder(folder, method: str = "cog", *, min_snr: float = 6.0,
                   keep_saturated: bool = False, quiet: bool = False, label: str = "extract"):
    """Stripe samples of every frame of a :class:`~scheimpflug.frames.FrameFolder`.

    Frames are decoded and extracted on threads (:meth:`FrameFolder.map_frames`)
    with a progress bar.  Returns ``(rows, u, peak, stats)``: three lists with
    one array per frame, and counters ``blank_frames`` and ``saturated_rows``.
    Saturated rows are dropped unless ``keep_saturated``.
    """
    from .progress import Progress
    from .stripe import extract_stripes

    def one(rec, frame):
        return extract_stripes(frame, method, min_snr=min_snr, saturation_dn=folder.saturation_dn(frame))

    rows, us, peaks = [], [], []
    stats = {"blank_frames": 0, "saturated_rows": 0}
    with Progress(len(folder), label=label, quiet=quiet) as bar:
        for prof in folder.map_frames(one):
            keep = slice(None) if keep_saturated else ~prof.saturated
            stats["saturated_rows"] += int(prof.saturated.sum())
            stats["blank_frames"] += int(len(prof) == 0)
            rows.append(prof.rows[keep])
            us.append(prof.u[keep])
            peaks.append(prof.peak[keep])
            bar.update()
    return rows, us, peaks, stats
