"""A calibration file as an instrument description (:mod:`scheimpflug.model.instrument`).

:func:`instrument_from_calibration` reads what :func:`scheimpflug.calibration.load.load_sheet_model`
reads — this project's target calibration, an OpenCV calibration (our ``--opencv`` export or a
foreign JSON/YAML with ``camera_matrix``, ``dist_coeffs``, ``laser_plane``) — and FabScanPi's
``config.json`` (``"as-fabscan"``, the default: FabScan's own model of its frames, the
camera matrix alone, as its own points and ``reconstruct --calibration`` read the file — its
calibrated k3 = −1.15 folds back inside the frame and bends the straight back walls;
``"apply"``: that calibrated distortion as the lens), in the orientation of the frames as the
camera stored them (:mod:`scheimpflug.calibration.fabscan`).  The instrument frame is the
camera frame of those frames.  What a calibration does not give comes from a named camera
(:data:`scheimpflug.model.instrument.CAMERA_PRESETS`) or is listed in ``Instrument.unknown``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from scheimpflug.calibration.fabscan import is_fabscan_config, read_fabscan
from scheimpflug.calibration.general import GeneralCalibration
from scheimpflug.calibration.load import load_sheet_model
from scheimpflug.errors import CalibrationError, RigError
from scheimpflug.model.instrument import Camera, Instrument, Sheet, Turntable, camera_preset

__all__ = ["UNKNOWN_WITHOUT_PRESET", "UNKNOWN_ALWAYS", "calibration_sheet_model", "instrument_from_calibration"]

#: Rig keys no calibration gives (defaults written, ready for identification).
UNKNOWN_ALWAYS = ("laser.origin_x_mm", "laser.wavelength_nm", "laser.power_mw", "laser.waist_um",
                  "laser.divergence_mrad", "laser.fan_angle_deg", "sensor.exposure_ms",
                  "sensor.quantum_efficiency", "sensor.full_well_e", "sensor.read_noise_e",
                  "stage.calibration_table_z_mm", "stage.calibration_plate_height_mm")
#: Rig keys a camera preset gives (unknown without one).
UNKNOWN_WITHOUT_PRESET = ("sensor.pixel_pitch_um", "lens.f_number", "lens.focal_length_mm")


def _is_fabscan(p: Path) -> bool:
    if p.suffix.lower() != ".json":
        return False
    try:
        return is_fabscan_config(json.loads(p.read_text("utf-8")))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return False


def _sheet_model(p: Path, fabscan_distortion: str = "as-fabscan"):
    model = read_fabscan(p, distortion=fabscan_distortion) if _is_fabscan(p) else load_sheet_model(p)
    if not isinstance(model, GeneralCalibration) or not hasattr(model.camera, "camera_matrix"):
        raise CalibrationError(f"calibration {str(p)!r} holds no camera (a paper-form calibration): build the "
                               "rig from the rig file it was made with")
    if int(model.columns) <= 0 or int(model.rows) <= 0:
        raise CalibrationError(f"calibration {str(p)!r} gives no frame size (image_size): the camera's width "
                               "and height are needed")
    return model


def calibration_sheet_model(path: str | Path, fabscan_distortion: str = "as-fabscan"):
    """The calibration of a file as :func:`instrument_from_calibration` reads it (a camera and a sheet).

    Parameters
    ----------
    path : str or Path
        A target calibration, an OpenCV calibration or FabScanPi's ``config.json``.
    fabscan_distortion : {"apply", "as-fabscan"}, default "as-fabscan"
        As in :func:`instrument_from_calibration`.

    Returns
    -------
    GeneralCalibration
        With ``camera`` (camera matrix, distortion), the sheet in its camera frame and the frame size.

    Raises
    ------
    CalibrationError
        The file's own errors, a calibration without a camera or a frame size.
    """
    return _sheet_model(Path(path), fabscan_distortion)


def _plane(model) -> tuple[np.ndarray, float]:
    """Unit normal and distance (n·X = distance > 0) of the calibration's sheet, camera frame."""
    origin, e_s, e_h = model.sheet_frame()
    n = np.cross(e_s, e_h)
    norm = float(np.linalg.norm(n))
    if not norm > 0:
        raise CalibrationError("the calibration gives no laser sheet (its sheet frame is degenerate): a camera-only "
                               "calibration, e.g. `calibrate --method target` without laser frames at two or more "
                               "poses; a twin needs the sheet's plane — calibrate with laser frames, or give an OpenCV "
                               "export holding its laser_plane")
    n = n / norm
    dist = float(n @ origin)
    return (n, dist) if dist >= 0 else (-n, -dist)


def _turntable(model, fabscan: bool) -> Turntable | None:
    """The calibration's rotary axis; FabScan's platform origin is the table's centre on its top."""
    axis = getattr(model, "axis", None)
    if not axis:
        return None
    w = np.asarray(axis["direction"], np.float64)
    w = w / np.linalg.norm(w)
    if not fabscan and w[1] > 0:         # a target calibration's axis: the sign that points up in the image
        w = -w
    radius = ((getattr(model, "tilt", None) or {}).get("turntable") or {}).get("radius") if fabscan else None
    if isinstance(radius, bool) or not isinstance(radius, (int, float)) or not (math.isfinite(radius) and radius > 0):
        return Turntable(np.asarray(axis["point_mm"], np.float64), w)
    return Turntable(np.asarray(axis["point_mm"], np.float64), w, radius_mm=float(radius))


def instrument_from_calibration(path: str | Path, preset: str | None = None, *,
                                turntable: bool = True, fabscan_distortion: str = "as-fabscan") -> Instrument:
    """The instrument a calibration file describes (module docstring).

    Parameters
    ----------
    path : str or Path
        A target calibration, an OpenCV calibration or FabScanPi's ``config.json``.
    preset : str, optional
        A named camera (:data:`scheimpflug.model.instrument.CAMERA_PRESETS`) giving the pixel
        pitch and the f-number; its frame size must be the calibration's.
    turntable : bool, default True
        Keep the calibration's rotary axis (False: none, the stage keys placed by rule).
    fabscan_distortion : {"apply", "as-fabscan"}, default "as-fabscan"
        For FabScan's ``config.json``: its calibrated distortion as the lens, or FabScan's own
        model of its frames, the camera matrix alone (:mod:`scheimpflug.calibration.fabscan`).

    Returns
    -------
    Instrument
        Camera (K, distortion, size; pose the identity: the instrument frame is the camera
        frame), sheet, turntable and the unknown keys.

    Raises
    ------
    CalibrationError
        The file's own errors (unreadable, singular camera matrix, non-unit normal, plane
        behind the camera …), a calibration without a camera or a frame size.
    RigError
        An unknown preset, or a preset whose frame size differs from the calibration's.
    """
    p = Path(path)
    fabscan = _is_fabscan(p)
    model = _sheet_model(p, fabscan_distortion)
    k, dist = np.asarray(model.camera.camera_matrix, np.float64), np.asarray(model.camera.dist_coeffs, np.float64)
    if k[0, 1] != 0.0:
        raise CalibrationError(f"calibration {str(p)!r}: the camera matrix has a skew K[0, 1] = {k[0, 1]:g} px; the "
                               "twin's sensor has square-grid pixels (recalibrate without skew)")
    extra = {}
    unknown = list(UNKNOWN_ALWAYS)
    if preset is not None:
        cp = camera_preset(preset)
        if (cp.width_px, cp.height_px) != (int(model.columns), int(model.rows)):
            raise RigError(f"camera preset {preset!r} is a {cp.width_px} × {cp.height_px} mode; the calibration is "
                           f"for {int(model.columns)} × {int(model.rows)} frames")
        extra = {"pixel_pitch_um": cp.pixel_pitch_um, "f_number": cp.f_number}
    else:
        unknown += list(UNKNOWN_WITHOUT_PRESET)
    cam = Camera(float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2]), int(model.columns),
                 int(model.rows), tuple(float(x) for x in dist), **extra)
    n, d = _plane(model)
    table = _turntable(model, fabscan) if turntable else None
    if table is not None:                             # the disc's size and material: FabScan's radius at most
        unknown += ["stage.table_thickness_mm", "stage.table_material"]
        unknown += ["stage.table_radius_mm"] if table.radius_mm == 0 else []
    if table is None:
        unknown += ["stage.axis_mm", "stage.rotary_table_z_mm"]
    elif not fabscan:
        unknown += ["stage.rotary_table_z_mm"]       # the axis point need not be on the table's top
    return Instrument(cam, Sheet(n, d), table, tuple(sorted(set(unknown))))
