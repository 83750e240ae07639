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

from scheimpflug.calibration import Calibration, applicability_problem
from scheimpflug.errors import CalibrationError, FrameError
from scheimpflug.io.frames import FrameFolder, check_distinct_frames, open_frame_folder
from scheimpflug.stripe import extract_stripes, image_pixels, oriented, saturated_fraction

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
"""Blocker thickness when neither the option nor the manifest gives one [mm]."""
_MIN_COS = 0.3     # blocker frames closer to edge-on than ~73° are skipped
_MIN_ROWS = 20     # fewer lit rows: no blocker in view
_MAX_SLOPE = 0.05  # a blocker face images as a vertical stripe: |du/dv| above this is not one [px/px]
_MAX_FACE_SPREAD_MM = 1.0   # robust σ of the face's stage coordinate over rows above this: not flat
_WARN_DISAGREE_MM = 1.0     # per-frame axis estimates spreading more than this: warn …
_MAX_DISAGREE_MM = 5.0      # … more than this: not one blocker at one place, refused


@dataclass(frozen=True)
class AxisResult:
    """Rotary axis from blocker frames (:func:`locate_axis`).

    Parameters
    ----------
    axis_mm : float
        Axis position, stage coordinate (same frame as d0) [mm]: the median of
        the per-frame estimates.
    face_mm : float
        Median stage coordinate of the blocker face over frames [mm].
    column_px : float
        Median stripe column over frames [px].
    blocker_thickness_mm : float
        Thickness used [mm].
    thickness_source : str
        "option", "manifest" or "default".
    per_frame_axis_mm : tuple of float
        Axis estimate of every usable frame [mm].
    spread_mm : float
        Robust σ (1.4826 MAD) of the stage coordinate over all lit rows, each
        about its frame's face [mm].
    n_rows : int
        Lit rows used [-].
    skipped : tuple of (str, str), optional
        (file, reason) of frames not used.
    warnings : tuple of str, optional
        Plausibility warnings (no scenario in the manifest, a stripe that is
        not straight and vertical, frames that disagree), one line each.
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
    warnings: tuple[str, ...] = ()

    def to_json_dict(self) -> dict:
        """The result as a JSON-ready dict.

        Returns
        -------
        dict
            Every field under its own name (tuples as lists); ``skipped`` as a
            list of ``{"file", "reason"}`` objects.
        """
        return {"axis_mm": self.axis_mm, "face_mm": self.face_mm, "column_px": self.column_px,
                "blocker_thickness_mm": self.blocker_thickness_mm,
                "thickness_source": self.thickness_source,
                "per_frame_axis_mm": list(self.per_frame_axis_mm), "spread_mm": self.spread_mm,
                "n_rows": self.n_rows,
                "skipped": [{"file": f, "reason": r} for f, r in self.skipped],
                "warnings": list(self.warnings)}


@dataclass(frozen=True)
class CylinderAxisFit:
    """Rotary axis from a cylinder scan (:func:`axis_from_cylinder_scan`).

    Parameters
    ----------
    axis_mm : float
        A, axis position in stage coordinates [mm].
    eccentricity_mm : float
        e, distance of the cylinder's centre from the axis [mm].
    phase_deg : float
        ψ, wrapped to [−180, 180] [deg].
    radius_mm : float
        R used [mm].
    rms_mm : float
        RMS residual of the fit [mm].
    n_frames : int
        Frames used [-].
    """

    axis_mm: float
    eccentricity_mm: float
    phase_deg: float
    radius_mm: float
    rms_mm: float
    n_frames: int

    def to_json_dict(self) -> dict:
        """The fit as a JSON-ready dict.

        Returns
        -------
        dict
            Every field under its own name.
        """
        return {"axis_mm": self.axis_mm, "eccentricity_mm": self.eccentricity_mm,
                "phase_deg": self.phase_deg, "radius_mm": self.radius_mm, "rms_mm": self.rms_mm,
                "n_frames": self.n_frames}


def _stage_of_rows(frame, calibration: Calibration, saturation_dn, detector, with_rows=False, along="columns"):
    """Stage coordinates [mm] of the stripe in every lit line, its positions across them [px] (and the lines).

    Lines are rows (columns for a stripe along the rows: :func:`scheimpflug.stripe.oriented`).
    """
    frame = oriented(frame, along)
    prof = extract_stripes(frame, detector, saturation_dn=saturation_dn, window_px="auto")
    if len(prof) < _MIN_ROWS:
        sat = saturated_fraction(frame, saturation_dn)
        if sat > 0.5:
            raise CalibrationError(f"frame saturated ({100 * sat:.0f} % of the pixels at the saturation "
                                   "level): lower the exposure or the laser power")
        raise CalibrationError(f"no stripe ({len(prof)} lit rows < {_MIN_ROWS})")
    s, _ = calibration.stage_from_pixel(*image_pixels(prof.rows, prof.u, along))
    return (s, prof.u, prof.rows) if with_rows else (s, prof.u)


def axis_from_faces(face_mm, thickness_mm: float, angles_deg=None) -> np.ndarray:
    """Axis estimates from blocker face positions (module docstring).

    Parameters
    ----------
    face_mm : array_like float
        Stage coordinates of the blocker face toward the laser [mm].
    thickness_mm : float
        Blocker thickness t [mm].
    angles_deg : array_like float, optional
        Blocker angle θ from facing the laser, per face [deg]; None: all
        facing the laser (θ = 0).

    Returns
    -------
    ndarray float64
        ``face + t / (2 |cos θ|)`` [mm], broadcast shape of the inputs.
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
    """Rotary axis position from the blocker frame(s) of a frame folder (module docstring).

    Parameters
    ----------
    folder : str, Path or FrameFolder
        Blocker frames; ``angle_deg`` in the manifest (optional) is the
        blocker's turn from facing the laser.
    calibration : Calibration
        The rig's calibration (pixel → stage coordinate, paper Eq. 11).
    blocker_thickness_mm : float, optional
        Blocker thickness [mm]; default the manifest's
        ``scenario_params.blocker_thickness_mm``, else
        :data:`DEFAULT_BLOCKER_THICKNESS_MM`.
    detector : str, default "cog"
        Stripe centre method (:func:`scheimpflug.stripe.extract_stripes`).

    Returns
    -------
    AxisResult
        The axis position, its per-frame estimates and spread, the frames
        skipped (nearly edge-on, |cos θ| < 0.3, or with fewer than 20 lit rows)
        and plausibility warnings (no scenario in the manifest; a stripe that
        is not straight and vertical; frames 1–5 mm apart).

    Raises
    ------
    CalibrationError
        If no frame is usable, the calibration cannot apply to these frames,
        the manifest names another scenario or the frames lie at several
        translation stage positions (a calibration folder is not a blocker),
        the axis falls outside the depth range the calibration covers, or the
        frames put it more than 5 mm apart.
    FrameError
        If the frame size differs from the calibration's, the thickness is
        not a number in [0, 100) mm, a frame is listed twice
        (:func:`scheimpflug.io.frames.check_distinct_frames`), or the folder or
        a frame is invalid.
    """
    ff = folder if isinstance(folder, FrameFolder) else open_frame_folder(folder)
    _check_size(ff, calibration)
    notes = _check_blocker_folder(ff)
    t, src = _thickness(ff, blocker_thickness_mm)
    axes, faces, cols, all_s, skipped, used = [], [], [], [], [], []
    for i, rec in enumerate(ff.frames):
        cos = 1.0 if rec.angle_deg is None else abs(math.cos(math.radians(rec.angle_deg)))
        if cos < _MIN_COS:
            skipped.append((rec.file, f"blocker nearly edge-on (angle {rec.angle_deg} deg)"))
            continue
        frame = ff.read(i)
        try:
            s, u, rows = _stage_of_rows(frame, calibration, ff.saturation_dn(frame), detector, True,
                                        ff.stripe_along)
        except CalibrationError as exc:
            skipped.append((rec.file, str(exc)))
            continue
        face = float(np.median(s))
        used.append(i)
        notes += _stripe_shape_notes(rec.file, u, rows, s - face)
        faces.append(face)
        cols.append(float(np.median(u)))
        axes.append(face + 0.5 * t / cos)
        all_s.append(s - face)
    if not axes:
        reasons = "; ".join(f"{f}: {r}" for f, r in skipped[:3])
        raise CalibrationError(f"no usable blocker frame in {str(ff.path)!r} ({reasons})")
    check_distinct_frames(ff, used)
    notes += _check_axis_result(ff, calibration, axes, t)
    dev = np.concatenate(all_s)
    return AxisResult(axis_mm=float(np.median(axes)), face_mm=float(np.median(faces)),
                      column_px=float(np.median(cols)), blocker_thickness_mm=t,
                      thickness_source=src, per_frame_axis_mm=tuple(axes),
                      spread_mm=float(1.4826 * np.median(np.abs(dev))), n_rows=int(dev.size),
                      skipped=tuple(skipped), warnings=tuple(notes))


def _check_blocker_folder(ff: FrameFolder) -> list[str]:
    """Refuse a folder that says it is not a blocker; warn when nothing says what it is."""
    where = str(ff.path)
    if isinstance(ff.scenario, str) and ff.scenario != "blocker":
        raise CalibrationError(f"{where!r} holds a {ff.scenario!r} scenario (manifest), not blocker "
                               "frames: give the folder of the blocker")
    stages = {r.stage_mm for r in ff.frames if r.stage_mm is not None}
    if len(stages) > 1:
        raise CalibrationError(f"{where!r}: the frames are at {len(stages)} translation stage positions "
                               "(stage_mm): a calibration sequence, not blocker frames")
    if ff.scenario is None:
        return [f"{where!r}: the manifest names no scenario: cannot check that these are blocker frames "
                "(the result is checked for plausibility only)"]
    return []


def _stripe_shape_notes(file: str, u: np.ndarray, rows: np.ndarray, dev_mm: np.ndarray) -> list[str]:
    """A blocker face images as a straight vertical stripe: warn when this one is not."""
    slope = float(np.polyfit(rows.astype(np.float64), u, 1)[0]) if np.ptp(rows) > 0 else 0.0
    spread = float(1.4826 * np.median(np.abs(dev_mm)))
    notes = []
    if abs(slope) > _MAX_SLOPE:
        notes.append(f"{file}: the stripe is not vertical (slope {slope:+.3f} px/px, > {_MAX_SLOPE}): "
                     "not a blocker face, or a rolled sensor")
    if spread > _MAX_FACE_SPREAD_MM:
        notes.append(f"{file}: the stripe is not straight (its stage coordinate spreads {spread:.3g} mm "
                     f"over the rows, > {_MAX_FACE_SPREAD_MM:g} mm): not a flat blocker face")
    return notes


def _check_axis_result(ff: FrameFolder, cal: Calibration, axes: list, t: float) -> list[str]:
    """The axis must lie in the calibrated depth range and the frames must agree."""
    n = ff.columns
    ends, _ = cal.stage_from_pixel(np.array([-0.5, n - 0.5]), np.full(2, 0.5 * (ff.rows - 1)))
    lo, hi = float(np.min(ends)) - t, float(np.max(ends)) + t
    axis = float(np.median(axes))
    if not lo <= axis <= hi:
        raise CalibrationError(f"the axis {axis:.3f} mm lies outside the depth range the calibration "
                               f"covers ({lo + t:.2f} … {hi - t:.2f} mm): wrong calibration or folder")
    disagree = float(np.ptp(axes))
    if disagree > _MAX_DISAGREE_MM:
        raise CalibrationError(f"{str(ff.path)!r}: the frames put the axis {disagree:.3g} mm apart "
                               f"({min(axes):.2f} … {max(axes):.2f} mm): not one blocker at one place")
    if disagree > _WARN_DISAGREE_MM:
        return [f"the blocker frames disagree by {disagree:.3g} mm on the axis position"]
    return []


def _check_size(ff: FrameFolder, cal: Calibration) -> None:
    if cal.columns and cal.rows and (ff.columns, ff.rows) != (cal.columns, cal.rows):
        raise FrameError(f"frames in {str(ff.path)!r} are {ff.rows} × {ff.columns} but the "
                         f"calibration was made with {cal.rows} × {cal.columns} (rows × columns)")
    problem = applicability_problem(cal, ff)
    if problem:
        raise CalibrationError(f"the calibration cannot be applied to {str(ff.path)!r}: {problem}")


def axis_from_cylinder_scan(angles_deg, near_stage_mm, radius_mm: float) -> CylinderAxisFit:
    """Fit ``s_near(θ) = A + e cos(θ+ψ) − sqrt(R² − e² sin²(θ+ψ))`` (module docstring).

    A linear first-harmonic fit gives the start; nonlinear least squares
    with 0 ≤ e < R then fits A, e and ψ.

    Parameters
    ----------
    angles_deg : (n,) array_like float
        Rotary stage angles θ [deg].
    near_stage_mm : (n,) array_like float
        Stage coordinate of the cylinder's near side in each frame [mm].
    radius_mm : float
        R, the cylinder's radius [mm], > 0.

    Returns
    -------
    CylinderAxisFit
        A, e, ψ, R, the RMS residual and the number of frames.

    Raises
    ------
    ValueError
        If the arrays are not 1-D of the same length, or ``radius_mm`` ≤ 0.
    CalibrationError
        With fewer than 3 frames, or angles spread over less than 30°.
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
    """Near-side stage coordinate of a cylinder in every usable frame of a scan.

    Frames with fewer than 20 lit rows are left out silently.

    Parameters
    ----------
    folder : str, Path or FrameFolder
        Cylinder scan frames, each with ``angle_deg`` in the manifest.
    calibration : Calibration
        The rig's calibration (pixel → stage coordinate, paper Eq. 11).
    detector : str, default "cog"
        Stripe centre method (:func:`scheimpflug.stripe.extract_stripes`).

    Returns
    -------
    angles_deg : (n,) ndarray float64
        Rotary stage angle of each usable frame [deg].
    near_stage_mm : (n,) ndarray float64
        Median stage coordinate of the stripe over the frame's lit rows [mm].

    Raises
    ------
    FrameError
        If a frame has no ``angle_deg``, the frame size differs from the
        calibration's, a frame is listed twice, or the folder or a frame is invalid.
    """
    ff = folder if isinstance(folder, FrameFolder) else open_frame_folder(folder)
    _check_size(ff, calibration)
    angles, near, used = [], [], []
    for i, rec in enumerate(ff.frames):
        if rec.angle_deg is None:
            raise FrameError(f"cylinder scan frame {rec.file!r} has no 'angle_deg' in the manifest")
        frame = ff.read(i)
        try:
            s, _ = _stage_of_rows(frame, calibration, ff.saturation_dn(frame), detector, along=ff.stripe_along)
        except CalibrationError:
            continue
        angles.append(rec.angle_deg)
        near.append(float(np.median(s)))
        used.append(i)
    check_distinct_frames(ff, used)
    return np.array(angles), np.array(near)


def locate_axis_from_cylinder(folder, calibration: Calibration, radius_mm: float, *,
                              detector: str = "cog") -> CylinderAxisFit:
    """Rotary axis from a frame folder of a turning cylinder of known radius.

    :func:`cylinder_near_positions` then :func:`axis_from_cylinder_scan`.

    Parameters
    ----------
    folder : str, Path or FrameFolder
        Cylinder scan frames, each with ``angle_deg`` in the manifest.
    calibration : Calibration
        The rig's calibration.
    radius_mm : float
        The cylinder's radius R [mm].
    detector : str, default "cog"
        Stripe centre method (:func:`scheimpflug.stripe.extract_stripes`).

    Returns
    -------
    CylinderAxisFit
        The fitted axis position, eccentricity and phase.

    Raises
    ------
    FrameError
        As :func:`cylinder_near_positions`.
    CalibrationError, ValueError
        As :func:`axis_from_cylinder_scan`.
    """
    angles, near = cylinder_near_positions(folder, calibration, detector=detector)
    return axis_from_cylinder_scan(angles, near, radius_mm)
