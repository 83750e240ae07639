"""Where the rotary axis lies along the sheet, in stage coordinates (paper Section 4).

**Blocker** (the paper's method): a thin vertical plate stands on the rotary
stage through its axis, facing the laser; its stripe's column gives, through
the calibration (paper Eq. 11), the stage coordinate of the face toward the
laser.  The paper read column 965 → 179.45 mm and ignored the plate's
thickness; here the face lies ``t/2`` before the axis along the propagation
direction, so ``axis = face + t/2``.  A frame with ``angle_deg = θ`` is taken as
the blocker turned by θ from facing the laser (θ = 0: face normal along the
propagation direction); the sheet then meets its face ``t / (2 |cos θ|)`` before
the axis.  Frames with ``|cos θ| < 0.3`` (nearly edge-on) are skipped.  The
face position of a frame is the median over its lit rows, so the fan's ends
and stray reflections do not pull it.

Blocker thickness: the ``--blocker-thickness-mm`` option if given, else the
manifest's ``scenario_params.blocker_thickness_mm`` (the twin writes it), else
2.0 mm (a typical sheet-metal blocker; the error is half the difference).

**Cylinder cross-check** (beyond the paper): a cylinder of known radius ``R``
on the rotary stage, its centre ``e`` off the axis at phase ψ.  At stage angle
θ the sheet (which contains the axis) meets its near side at

    s_near(θ) = A + e cos(θ + ψ) − sqrt(R² − e² sin²(θ + ψ))

with ``A`` the axis position; ``A, e, ψ`` are fitted by nonlinear least squares
to the per-frame median stripe position.  A concentric cylinder (e = 0) gives
``A = s_near + R`` directly.  R must be known: for small e it is nearly
degenerate with A (only the weak second harmonic e²/(4R) separates them).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import optimize

from scheimpflug.calibration import Calibration
from scheimpflug.errors import CalibrationError, FrameError
from scheimpflug.io.frames import FrameFolder, open_frame_folder
from scheimpflug.stripe import extract_stripes

__all__ = [
    "AxisResult",
    "CylinderAxisFit",
    "DEFAULT_BLOCKER_THICKNESS_MM",
    "axis_from_cylinder_scan",
    "axis_from_faces",
    "cylinder_near_positions",
    "locate_axis",
    "locate_axis_from_cylinder",
]

DEFAULT_BLOCKER_THICKNESS_MM = 2.0
_MIN_COS = 0.3     # blocker frames closer to edge-on than ~73° are skipped
_MIN_ROWS = 20     # fewer lit rows: no blocker in view


@dataclass(frozen=True)
class AxisResult:
    """Rotary axis from blocker frames.

    axis_mm : axis position, stage coordinate (same frame as d0) [mm].
    face_mm : median stage coordinate of the blocker face over frames [mm].
    column_px : median stripe column over frames [px].
    blocker_thickness_mm : thickness used [mm].
    thickness_source : "option", "manifest" or "default".
    per_frame_axis_mm : axis estimate of every usable frame [mm].
    spread_mm : robust σ (1.4826 MAD) of the stage coordinate over all lit rows [mm].
    n_rows : lit rows used [-].
    skipped : (file, reason) of frames not used.
    """

    axis_mm: float
    face_mm: float
    column_px: float
    blocker_thickness_mm: float
    thickness_source: str
    per_frame_axis_mm: tuple[float, ...]
    spread_mm: float
    n_rows: int
    skipped: tuple[tuple[str, str], ...] = ()

    def to_json_dict(self) -> dict:
        return {"axis_mm": self.axis_mm, "face_mm": self.face_mm, "column_px": self.column_px,
                "blocker_thickness_mm": self.blocker_thickness_mm,
                "thickness_source": self.thickness_source,
                "per_frame_axis_mm": list(self.per_frame_axis_mm), "spread_mm": self.spread_mm,
                "n_rows": self.n_rows,
                "skipped": [{"file": f, "reason": r} for f, r in self.skipped]}


@dataclass(frozen=True)
class CylinderAxisFit:
    """Rotary axis from a cylinder scan.

    axis_mm : A, axis position in stage coordinates [mm].
    eccentricity_mm : e, distance of the cylinder's centre from the axis [mm].
    phase_deg : ψ [deg].
    radius_mm : R used [mm].
    rms_mm : RMS residual of the fit [mm].
    n_frames : frames used [-].
    """

    axis_mm: float
    eccentricity_mm: float
    phase_deg: float
    radius_mm: float
    rms_mm: float
    n_frames: int

    def to_json_dict(self) -> dict:
        return {"axis_mm": self.axis_mm, "eccentricity_mm": self.eccentricity_mm,
                "phase_deg": self.phase_deg, "radius_mm": self.radius_mm, "rms_mm": self.rms_mm,
                "n_frames": self.n_frames}


def _stage_of_rows(frame, calibration: Calibration, saturation_dn, detector):
    """Stage coordinates [mm] of the stripe in every lit row (and the columns [px])."""
    prof = extract_stripes(frame, detector, saturation_dn=saturation_dn)
    if len(prof) < _MIN_ROWS:
        raise CalibrationError(f"no stripe ({len(prof)} lit rows < {_MIN_ROWS})")
    s, _ = calibration.stage_from_pixel(prof.u, prof.rows)
    return s, prof.u


def axis_from_faces(face_mm, thickness_mm: float, angles_deg=None) -> np.ndarray:
    """Axis estimates [mm] from blocker face positions [mm] (module docstring).

    ``angles_deg`` (or None = all facing the laser) sets the 1/|cos θ| factor.
    """
    face = np.asarray(face_mm, dtype=np.float64)
    if angles_deg is None:
        return face + 0.5 * thickness_mm
    cos = np.abs(np.cos(np.radians(np.asarray(angles_deg, dtype=np.float64))))
    return face + 0.5 * thickness_mm / cos


def _thickness(ff: FrameFolder, option: float | None) -> tuple[float, str]:
    if option is not None:
        t, src = float(option), "option"
    elif "blocker_thickness_mm" in ff.scenario_params:
        t, src = ff.scenario_params["blocker_thickness_mm"], "manifest"
    else:
        t, src = DEFAULT_BLOCKER_THICKNESS_MM, "default"
    if isinstance(t, bool) or not isinstance(t, (int, float)) or not (0 <= t < 100):
        raise FrameError(f"blocker thickness {t!r} ({src}) must be a number in [0, 100) mm")
    return float(t), src


def locate_axis(folder: str | Path | FrameFolder, calibration: Calibration, *,
                blocker_thickness_mm: float | None = None,
                detector: str = "cog") -> AxisResult:
    """Rotary axis position from the blocker frame(s) of ``folder`` (module docstring)."""
    ff = folder if isinstance(folder, FrameFolder) else open_frame_folder(folder)
    _check_size(ff, calibration)
    t, src = _thickness(ff, blocker_thickness_mm)
    axes, faces, cols, all_s, skipped = [], [], [], [], []
    for i, rec in enumerate(ff.frames):
        cos = 1.0 if rec.angle_deg is None else abs(math.cos(math.radians(rec.angle_deg)))
        if cos < _MIN_COS:
            skipped.append((rec.file, f"blocker nearly edge-on (angle {rec.angle_deg} deg)"))
            continue
        frame = ff.read(i)
        try:
            s, u = _stage_of_rows(frame, calibration, ff.saturation_dn(frame), detector)
        except CalibrationError as exc:
            skipped.append((rec.file, str(exc)))
            continue
        face = float(np.median(s))
        faces.append(face)
        cols.append(float(np.median(u)))
        axes.append(face + 0.5 * t / cos)
        all_s.append(s - face)
    if not axes:
        reasons = "; ".join(f"{f}: {r}" for f, r in skipped[:3])
        raise CalibrationError(f"no usable blocker frame in {str(ff.path)!r} ({reasons})")
    dev = np.concatenate(all_s)
    return AxisResult(axis_mm=float(np.median(axes)), face_mm=float(np.median(faces)),
                      column_px=float(np.median(cols)), blocker_thickness_mm=t,
                      thickness_source=src, per_frame_axis_mm=tuple(axes),
                      spread_mm=float(1.4826 * np.median(np.abs(dev))), n_rows=int(dev.size),
                      skipped=tuple(skipped))


def _check_size(ff: FrameFolder, cal: Calibration) -> None:
    if cal.columns and cal.rows and (ff.columns, ff.rows) != (cal.columns, cal.rows):
        raise FrameError(f"frames in {str(ff.path)!r} are {ff.rows} × {ff.columns} but the "
                         f"calibration was made with {cal.rows} × {cal.columns} (rows × columns)")


def axis_from_cylinder_scan(angles_deg, near_stage_mm, radius_mm: float) -> CylinderAxisFit:
    """Fit ``s_near(θ) = A + e cos(θ+ψ) − sqrt(R² − e² sin²(θ+ψ))`` (module docstring).

    Parameters
    ----------
    angles_deg : (n,) float — stage angles [deg].
    near_stage_mm : (n,) float — stage coordinate of the cylinder's near side [mm].
    radius_mm : R, the cylinder's radius [mm].
    """
    th = np.radians(np.asarray(angles_deg, dtype=np.float64))
    x = np.asarray(near_stage_mm, dtype=np.float64)
    R = float(radius_mm)
    if th.shape != x.shape or th.ndim != 1:
        raise ValueError("angles_deg and near_stage_mm must be (n,) arrays of the same length")
    if not R > 0:
        raise ValueError(f"radius_mm must be > 0, got {radius_mm}")
    if th.size < 3 or np.ptp(np.mod(th, 2 * np.pi)) < np.radians(30):
        raise CalibrationError("a cylinder scan needs ≥ 3 frames spread over ≥ 30° of rotation")
    A0 = np.column_stack([np.ones_like(th), np.cos(th), np.sin(th)])
    (a, b, c), *_ = np.linalg.lstsq(A0, x, rcond=None)
    e0, psi0 = math.hypot(b, c), math.atan2(-c, b)

    def resid(p):
        A, e, psi = p
        ph = th + psi
        return A + e * np.cos(ph) - np.sqrt(np.maximum(R * R - (e * np.sin(ph)) ** 2, 0.0)) - x

    sol = optimize.least_squares(resid, x0=[a + R, min(e0, 0.9 * R), psi0],
                                 bounds=([-np.inf, 0.0, -np.inf], [np.inf, 0.999 * R, np.inf]))
    A, e, psi = sol.x
    return CylinderAxisFit(axis_mm=float(A), eccentricity_mm=float(e),
                           phase_deg=float(np.degrees(math.remainder(psi, 2 * math.pi))),
                           radius_mm=R, rms_mm=float(np.sqrt(np.mean(sol.fun ** 2))),
                           n_frames=int(th.size))


def cylinder_near_positions(folder: str | Path | FrameFolder, calibration: Calibration, *,
                            detector: str = "cog"):
    """(angles_deg, near_stage_mm) per usable frame of a cylinder scan: median over lit rows."""
    ff = folder if isinstance(folder, FrameFolder) else open_frame_folder(folder)
    _check_size(ff, calibration)
    angles, near = [], []
    for i, rec in enumerate(ff.frames):
        if rec.angle_deg is None:
            raise FrameError(f"cylinder scan frame {rec.file!r} has no 'angle_deg' in the manifest")
        frame = ff.read(i)
        try:
            s, _ = _stage_of_rows(frame, calibration, ff.saturation_dn(frame), detector)
        except CalibrationError:
            continue
        angles.append(rec.angle_deg)
        near.append(float(np.median(s)))
    return np.array(angles), np.array(near)


def locate_axis_from_cylinder(folder, calibration: Calibration, radius_mm: float, *,
                              detector: str = "cog") -> CylinderAxisFit:
    """Rotary axis from a frame folder of a cylinder of radius ``radius_mm`` [mm] turning."""
    angles, near = cylinder_near_positions(folder, calibration, detector=detector)
    return axis_from_cylinder_scan(angles, near, radius_mm)
