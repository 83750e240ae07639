"""An instrument by its parts: a calibrated camera, a laser sheet, a turntable — and its exact rig.

A real laser-line scanner is described by its calibration, not by the paper's
Scheimpflug parameters: an OpenCV camera (fx, fy, cx, cy, distortion, pose), a
laser plane and a turntable axis, all in one *instrument frame* [mm].  This
module holds that description (:class:`Camera`, :class:`Sheet`,
:class:`Turntable`, :class:`Instrument`) and its one conversion to the
:class:`~scheimpflug.model.rig.Rig` the twin renders (:func:`rig_from_instrument`):
no second camera model, no second renderer.

The conversion (:func:`rig_frame`)
----------------------------------
* The lens centre is the camera's centre; the rig's +x is the camera's +Z (the
  optical axis).  The rig's +y is the sheet normal's part across the axis
  (the sign that makes the sheet's distance positive), +z = x × y: so the
  sheet contains +z and reads ``y = d − x·tan φ`` with
  ``tan φ = n_x / n_y``, ``d = D / n_y`` (n the unit normal in the rig frame,
  ``n·X = D > 0``).
* The sensor is perpendicular to the axis (``[sensor] image_distance_mm`` b =
  fx · pitch), its pixel axes turned about the axis by ``roll_deg`` ψ (the
  camera's X = −e_u, Y = −e_v: the image is inverted behind the lens), the
  principal point (cx, cy) at ``offset_u_px = (columns − 1)/2 − cx``,
  ``offset_v_px = (rows − 1)/2 − cy``.
* The distortion is OpenCV's on the camera's normalised coordinates
  (:mod:`scheimpflug.model.distortion`): k1, k2, k3, p1, p2 as calibrated,
  ``aspect_ratio = fy/fx``.  Terms beyond k3 (k4 … k6, s1 … s4, τx, τy)
  are refused unless zero.
* The lens focuses at ``focus_distance_mm`` s (default: the sheet point the
  image centre sees): f = b·s / (b + s).  The focal length changes the blur,
  never where a point images.
* The turntable's centre and up give the ``[stage]`` keys exactly: the axis
  along the sheet (``axis_mm``, d0 = 0), its height (``rotary_table_z_mm``),
  its offset from the sheet (``axis_offset_mm``) and its lean from the rig's
  +z (``axis_tilt_deg``, ``axis_tilt_azimuth_deg``) — over 170° when the sheet
  lies on the camera's right (FabScan's): the rig frame is then upside down
  in the world, and so is the table in it.

Then :func:`scheimpflug.model.camera.project_points` of a point X_c of the
camera frame, moved to ``rig_from_camera · X_c``, is ``cv2.projectPoints`` of
X_c with K and the distortion (tests/test_instrument.py: < 1e-6 px).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from scheimpflug.errors import RigError
from scheimpflug.model.assembly import Rig, rig_from_tables, rig_to_dict, rig_to_toml
from scheimpflug.model.distortion import fold_radius, undistort_tangents
from scheimpflug.model.tables import Lens

__all__ = [
    "CAMERA_PRESETS",
    "Camera",
    "CameraPreset",
    "DISTORTION_TERMS",
    "Instrument",
    "RigFrame",
    "Sheet",
    "Turntable",
    "camera_preset",
    "rig_file_text",
    "rig_frame",
    "rig_from_instrument",
]

#: OpenCV's distortion terms in its order (5, 8, 12 or 14 of them).
DISTORTION_TERMS = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4", "tau_x", "tau_y")
_SIZES = (0, 4, 5, 8, 12, 14)
#: Tolerance on the unit length of a plane normal or an axis direction [-].
UNIT_TOL = 1e-6
#: Largest axis tilt the rig's rotary stage holds (``[stage] axis_tilt_deg``) [deg].
_MAX_TABLE_TILT_DEG = 10.0


@dataclass(frozen=True)
class CameraPreset:
    """What a named camera gives that a calibration lacks.

    Parameters
    ----------
    name : str
        The preset's name.
    pixel_pitch_um : float
        Pixel pitch of the read-out mode [µm].
    focal_length_mm : float
        The lens's nominal focal length [mm] (recorded; the rig's f follows from fx and the focus).
    f_number : float
        Aperture [-].
    width_px, height_px : int
        The mode's frame size [px].
    source : str
        Where the numbers come from.
    """

    name: str
    pixel_pitch_um: float
    focal_length_mm: float
    f_number: float
    width_px: int
    height_px: int
    source: str


_RPI = ("Raspberry Pi Camera Module v2 documentation (raspberrypi.com/documentation/accessories/camera.html): "
        "Sony IMX219, 1.12 µm pixels, 3280 × 2464, f = 3.04 mm, f/2.0")
#: Named cameras (``--preset``), each value's source in ``source``.
CAMERA_PRESETS: dict[str, CameraPreset] = {
    "rpi-v2": CameraPreset("rpi-v2", 1.12, 3.04, 2.0, 3280, 2464, _RPI),
    "rpi-v2-binned": CameraPreset("rpi-v2-binned", 2.24, 3.04, 2.0, 1640, 1232,
                                  _RPI + "; the 2 × 2 binned 1640 × 1232 mode (2.24 µm) FabScanPi's frames use"),
}


def camera_preset(name: str) -> CameraPreset:
    """A named camera (:data:`CAMERA_PRESETS`).

    Parameters
    ----------
    name : str
        The preset's name.

    Returns
    -------
    CameraPreset
        Its pitch, lens, aperture, frame size and source.

    Raises
    ------
    RigError
        For an unknown name (the known ones listed).
    """
    if name not in CAMERA_PRESETS:
        raise RigError(f"unknown camera preset {name!r} (known: {', '.join(CAMERA_PRESETS)})")
    return CAMERA_PRESETS[name]


@dataclass(frozen=True, eq=False)
class Camera:
    """A calibrated camera (OpenCV's pinhole model with distortion).

    Parameters
    ----------
    fx_px, fy_px : float
        Focal lengths [px], > 0.
    cx_px, cy_px : float
        Principal point [px] (0-based pixel centres).
    width_px, height_px : int
        Frame size [px].
    distortion : tuple of float, default ()
        OpenCV's coefficients in its order (:data:`DISTORTION_TERMS`; 0, 4, 5, 8, 12 or 14) [-].
    pixel_pitch_um : float, default 2.24
        Pixel pitch [µm] (only the blur and the light depend on it).
    f_number : float, default 2.0
        Aperture [-].
    focus_distance_mm : float or None, default None
        Object distance the lens focuses, along the axis [mm]; None: the sheet point the image centre sees.
    instrument_from_camera : (4, 4) ndarray, default identity
        Pose of the camera frame (OpenCV's: X along columns, Y along rows, Z forward) [mm].
    """

    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float
    width_px: int
    height_px: int
    distortion: tuple = ()
    pixel_pitch_um: float = 2.24
    f_number: float = 2.0
    focus_distance_mm: float | None = None
    instrument_from_camera: np.ndarray = field(default_factory=lambda: np.eye(4))


@dataclass(frozen=True, eq=False)
class Sheet:
    """The laser sheet: its plane ``normal·X = distance_mm`` in the instrument frame, and its light.

    Parameters
    ----------
    normal : (3,) ndarray
        Unit normal [-].
    distance_mm : float
        Plane offset along the normal [mm].
    emitter_mm : (3,) ndarray or None, default None
        The laser's position [mm]; None: the sheet's point in the lens plane on the axis side.
    fan_angle_deg, wavelength_nm, waist_um, divergence_mrad, power_mw : float
        The ``[laser]`` keys of the same names [deg, nm, µm, mrad, mW].
    """

    normal: np.ndarray
    distance_mm: float
    emitter_mm: np.ndarray | None = None
    fan_angle_deg: float = 60.0
    wavelength_nm: float = 650.0
    waist_um: float = 150.0
    divergence_mrad: float = 1.5
    power_mw: float = 5.0


@dataclass(frozen=True, eq=False)
class Turntable:
    """The rotary table: its centre on the table's top and the axis's upward direction (the table's up).

    Parameters
    ----------
    axis_point_mm : (3,) ndarray
        The table's centre, on its top [mm], instrument frame.
    axis_direction : (3,) ndarray
        Unit upward direction of the axis [-].
    radius_mm : float, default 0.0
        Radius of the table's disc [mm] (0 = no disc in the twin; ``[stage] table_radius_mm``).
    thickness_mm : float, default 10.0
        The disc's thickness below its top [mm] (``[stage] table_thickness_mm``).
    material : str, default "cardboard"
        The disc's material tag (``[stage] table_material``).
    """

    axis_point_mm: np.ndarray
    axis_direction: np.ndarray
    radius_mm: float = 0.0
    thickness_mm: float = 10.0
    material: str = "cardboard"


@dataclass(frozen=True, eq=False)
class Instrument:
    """A camera-and-sheet instrument in one frame.

    Parameters
    ----------
    camera : Camera
        The camera.
    sheet : Sheet
        The laser sheet.
    turntable : Turntable or None, default None
        The rotary table, if any.
    unknown : tuple of str, default ()
        ``"table.key"`` of the rig keys no source gave (defaults, ready for identification).
    """

    camera: Camera
    sheet: Sheet
    turntable: Turntable | None = None
    unknown: tuple = ()


@dataclass(frozen=True, eq=False)
class RigFrame:
    """Where the rig frame sits: the result of :func:`rig_frame`.

    Parameters
    ----------
    rig_from_camera : (4, 4) ndarray
        Camera frame → rig frame [mm] (a rotation: the lens centre is the camera centre).
    rig_from_instrument : (4, 4) ndarray
        Instrument frame → rig frame [mm].
    distance_mm : float
        d of the sheet ``y = d − x·tan φ`` [mm].
    tan_phi : float
        tan φ [-].
    roll_deg : float
        Roll ψ of the pixel axes about the optical axis [deg].
    """

    rig_from_camera: np.ndarray
    rig_from_instrument: np.ndarray
    distance_mm: float
    tan_phi: float
    roll_deg: float


# ---------------------------------------------------------------- checks


def _unit(v, what: str) -> np.ndarray:
    a = np.asarray(v, np.float64).ravel()
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise RigError(f"{what} must be 3 finite numbers, got {a.tolist()!r:.80}")
    norm = float(np.linalg.norm(a))
    if norm == 0.0:
        raise RigError(f"{what} is zero: it gives no direction")
    if abs(norm - 1.0) > UNIT_TOL:
        raise RigError(f"{what} {a.tolist()} has length {norm:.9g}, not 1: a unit vector is needed "
                       "(a plane's distance is then in mm)")
    return a / norm


def _check_camera(cam: Camera) -> None:
    k = (cam.fx_px, cam.fy_px, cam.cx_px, cam.cy_px)
    if not all(math.isfinite(x) for x in k) or cam.fx_px <= 0 or cam.fy_px <= 0:
        raise RigError(f"singular camera matrix: fx = {cam.fx_px!r}, fy = {cam.fy_px!r} px (both must be "
                       f"finite and > 0, cx, cy finite: {cam.cx_px!r}, {cam.cy_px!r})")
    if not (0.5 <= cam.fy_px / cam.fx_px <= 2.0):
        raise RigError(f"fy/fx = {cam.fy_px / cam.fx_px:.6g} outside [0.5, 2]: not a camera this rig can hold")
    d = tuple(float(x) for x in cam.distortion)
    if len(d) not in _SIZES or not all(math.isfinite(x) for x in d):
        raise RigError(f"distortion must be 0, 4, 5, 8, 12 or 14 finite numbers (OpenCV's order), got {len(d)}")
    for name, value in zip(DISTORTION_TERMS[5:], d[5:]):
        if value != 0.0:
            raise RigError(f"distortion term {name} = {value:g} is not supported by the twin's lens (k1, k2, "
                           "p1, p2, k3 only): recalibrate without it (e.g. no CALIB_RATIONAL_MODEL, "
                           "CALIB_THIN_PRISM_MODEL or CALIB_TILTED_MODEL)")
    m = np.asarray(cam.instrument_from_camera, np.float64)
    r = m[:3, :3] if m.shape == (4, 4) else np.zeros((3, 3))
    if m.shape != (4, 4) or np.abs(r.T @ r - np.eye(3)).max() > 1e-9 or np.linalg.det(r) < 0:
        raise RigError("instrument_from_camera must be a 4 × 4 rigid transform (an orthonormal rotation, det +1)")


def _lens(cam: Camera, f_mm: float = 1.0, f_number: float = 2.0) -> Lens:
    d = [*map(float, cam.distortion), *([0.0] * 5)][:5]
    return Lens(focal_length_mm=f_mm, f_number=f_number, k1=d[0], k2=d[1], k3=d[4], p1=d[2], p2=d[3],
                aspect_ratio=cam.fy_px / cam.fx_px)


def _fold_warning(cam: Camera) -> str | None:
    """A note when the frame's corners see beyond the distortion's fold (:func:`fold_radius`)."""
    fold = fold_radius(_lens(cam))
    u = np.array([0.0, cam.width_px - 1.0])
    v = np.array([0.0, cam.height_px - 1.0])
    r = float(np.hypot(*np.meshgrid((u - cam.cx_px) / cam.fx_px, (v - cam.cy_px) / cam.fy_px)).max())
    if r <= fold:
        return None
    return (f"the distortion (k1, k2, k3 = {list(cam.distortion)[:2] + list(cam.distortion)[4:5]}) folds back at the "
            f"normalised radius {fold:.4g}, inside the frame (its corners reach {r:.4g}): pixels beyond it see "
            "directions the calibration never saw, twice; the twin renders the model there, not the lens")


def _view_rays(cam: Camera, n: int = 17) -> np.ndarray:
    """Camera-frame rays (X/Z, Y/Z, 1) of an n × n grid over the frame, the centre first, (n² + 1, 3)."""
    u = np.linspace(0.0, cam.width_px - 1.0, n)
    v = np.linspace(0.0, cam.height_px - 1.0, n)
    uu, vv = np.meshgrid(u, v)
    uv = np.column_stack([np.r_[(cam.width_px - 1) / 2, uu.ravel()], np.r_[(cam.height_px - 1) / 2, vv.ravel()]])
    md = np.column_stack([(uv[:, 0] - cam.cx_px) / cam.fx_px, (uv[:, 1] - cam.cy_px) / cam.fx_px])
    m = -undistort_tangents(_lens(cam), 0.0, -md)      # roll 0: the rig tangents are −m
    return np.column_stack([m, np.ones(len(m))])


def _camera_plane(inst: Instrument) -> tuple[np.ndarray, float]:
    """The sheet in the camera frame: unit n_c and D_c > 0 with n_c·X = D_c."""
    n = _unit(inst.sheet.normal, "the sheet's normal")
    if not math.isfinite(inst.sheet.distance_mm):
        raise RigError(f"the sheet's distance {inst.sheet.distance_mm!r} mm is not a finite number")
    m = np.asarray(inst.camera.instrument_from_camera, np.float64)
    n_c, d_c = m[:3, :3].T @ n, float(inst.sheet.distance_mm - n @ m[:3, 3])
    if abs(d_c) < 1e-9:
        raise RigError("the sheet passes through the camera's centre: the camera sees it edge-on")
    return (n_c, d_c) if d_c > 0 else (-n_c, -d_c)


def _sheet_depths(inst: Instrument, n_c: np.ndarray, d_c: float) -> np.ndarray:
    """Depth Z [mm] where each view ray meets the sheet, NaN where it meets it behind the camera."""
    w = _view_rays(inst.camera)
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = d_c / (w @ n_c)
    return np.where(lam > 0, lam, np.nan)


# ---------------------------------------------------------------- conversion


def rig_frame(inst: Instrument) -> RigFrame:
    """The rig frame of an instrument (module docstring: x the optical axis, z in the sheet).

    Parameters
    ----------
    inst : Instrument
        The instrument.

    Returns
    -------
    RigFrame
        ``rig_from_camera``, ``rig_from_instrument``, d, tan φ and the pixel axes' roll.

    Raises
    ------
    RigError
        A singular camera matrix, an unsupported distortion term, a zero or non-unit
        normal, a sheet through the camera, perpendicular to the optical axis
        (|tan φ| > 100), or behind the camera / never in the view.
    """
    _check_camera(inst.camera)
    n_c, d_c = _camera_plane(inst)
    if np.all(np.isnan(_sheet_depths(inst, n_c, d_c))):
        raise RigError(f"the sheet (normal {np.round(n_c, 6).tolist()}, distance {d_c:.6g} mm in the camera frame) "
                       "lies behind the camera or outside its view: no pixel sees it in front")
    x = np.array([0.0, 0.0, 1.0])
    lateral = n_c - (n_c @ x) * x
    if np.linalg.norm(lateral) * 100 < abs(n_c @ x):
        raise RigError(f"the sheet is (nearly) perpendicular to the optical axis (|tan φ| = "
                       f"{abs(n_c @ x) / max(np.linalg.norm(lateral), 1e-300):.4g} > 100): a light-sheet "
                       "camera must look along the sheet, not at it")
    y = lateral / np.linalg.norm(lateral)
    rot = np.vstack([x, y, np.cross(x, y)])          # rows: the rig axes in the camera frame
    rig_from_camera = np.eye(4)
    rig_from_camera[:3, :3] = rot
    ex = rot @ np.array([1.0, 0.0, 0.0])             # the camera's X (columns) in the rig frame = −e_u
    roll = math.degrees(math.atan2(-ex[2], -ex[1]))
    cam_from_inst = np.linalg.inv(np.asarray(inst.camera.instrument_from_camera, np.float64))
    return RigFrame(rig_from_camera, rig_from_camera @ cam_from_inst, d_c / float(n_c @ y),
                    float(n_c @ x) / float(n_c @ y), roll)


def _focus_mm(inst: Instrument, n_c: np.ndarray, d_c: float) -> float:
    if inst.camera.focus_distance_mm is not None:
        return float(inst.camera.focus_distance_mm)
    depths = _sheet_depths(inst, n_c, d_c)
    return float(depths[0]) if math.isfinite(depths[0]) else float(np.nanmedian(depths))


def _lens_table(inst: Instrument, n_c: np.ndarray, d_c: float) -> dict:
    cam = inst.camera
    b = cam.fx_px * cam.pixel_pitch_um * 1e-3
    s = _focus_mm(inst, n_c, d_c)
    if not s > 0:
        raise RigError(f"focus distance {s!r} mm: must be > 0 (in front of the camera)")
    lens = _lens(cam, b * s / (b + s), cam.f_number)
    return {k: getattr(lens, k) for k in ("focal_length_mm", "f_number", "k1", "k2", "k3", "p1", "p2",
                                          "aspect_ratio")}


def _sensor_table(inst: Instrument, frame: RigFrame) -> dict:
    cam = inst.camera
    return {"pixel_pitch_um": cam.pixel_pitch_um, "columns": int(cam.width_px), "rows": int(cam.height_px),
            "image_distance_mm": cam.fx_px * cam.pixel_pitch_um * 1e-3, "roll_deg": frame.roll_deg,
            "offset_u_px": 0.5 * (cam.width_px - 1) - cam.cx_px, "offset_v_px": 0.5 * (cam.height_px - 1) - cam.cy_px,
            "hinge_column": 0.0, "axis_row": 0.0, "tilt_error_deg": 0.0, "offset_normal_um": 0.0}


def _to_rig(frame: RigFrame, point) -> np.ndarray:
    return frame.rig_from_instrument[:3, :3] @ np.asarray(point, np.float64) + frame.rig_from_instrument[:3, 3]


def _laser_table(inst: Instrument, frame: RigFrame, f_mm: float, axis_d_mm: float) -> dict:
    """The ``[laser]`` keys; the waist at the axis (D from the hinge at x = f, the origin at x = origin_x_mm)."""
    sh = inst.sheet
    origin_x = 0.0 if sh.emitter_mm is None else float(_to_rig(frame, sh.emitter_mm)[0])
    origin_to_hinge = (f_mm - origin_x) / math.cos(math.atan(frame.tan_phi))
    return {"scheimpflug_distance_mm": frame.distance_mm, "tan_phi": frame.tan_phi, "origin_x_mm": origin_x,
            "wavelength_nm": sh.wavelength_nm, "power_mw": sh.power_mw, "waist_um": sh.waist_um,
            "divergence_mrad": sh.divergence_mrad, "fan_angle_deg": sh.fan_angle_deg,
            "waist_distance_mm": axis_d_mm + origin_to_hinge}


def _stage_table(inst: Instrument, frame: RigFrame, f_mm: float, focus_mm: float) -> dict:
    """d0 = 0 (stage coordinates are distances from the object hinge), the axis and its table.

    The table's centre p (rig frame) is ``H + axis_mm·e_p + axis_offset_mm·n + rotary_table_z_mm·e_z``
    (H the object hinge; :mod:`sim.stages`), exactly: an axis that misses the sheet keeps its offset.
    The table's up w gives ``axis_tilt_deg`` = ∠(w, +z) and the azimuth it leans to; over 170° the
    table's up is the rig's −z (the sheet on the camera's right, seen from behind, with the table
    below: the rig frame is upside down in the world).
    """
    phi = math.atan(frame.tan_phi)
    prop = np.array([math.cos(phi), -math.sin(phi), 0.0])
    normal = np.array([math.sin(phi), math.cos(phi), 0.0])
    hinge = np.array([f_mm, frame.distance_mm - f_mm * frame.tan_phi, 0.0])
    if inst.turntable is None:
        p = np.array([focus_mm, frame.distance_mm - focus_mm * frame.tan_phi, 0.0])
        tilt, azimuth, table_z, offset = 0.0, 0.0, -50.0, 0.0
    else:
        p = _to_rig(frame, inst.turntable.axis_point_mm)
        w = frame.rig_from_instrument[:3, :3] @ _unit(inst.turntable.axis_direction, "the turntable's axis")
        tilt = math.degrees(math.acos(max(-1.0, min(1.0, float(w[2])))))
        if _MAX_TABLE_TILT_DEG <= tilt <= 180.0 - _MAX_TABLE_TILT_DEG:
            raise RigError(f"the turntable's axis leans {tilt:.3g}° from the sheet's vertical (the rig's +z): the "
                           f"rig's rotary stage holds less than {_MAX_TABLE_TILT_DEG:g}° from it, or more than "
                           f"{180 - _MAX_TABLE_TILT_DEG:g}° (a table up the rig's −z; [stage] axis_tilt_deg)")
        lean = math.hypot(float(w @ normal), float(w @ prop))
        azimuth = math.degrees(math.atan2(w @ normal, w @ prop)) if lean > 0 else 0.0
        table_z, offset = float(p[2]), float((p - hinge) @ normal)
    disc = {} if inst.turntable is None else {
        "table_radius_mm": float(inst.turntable.radius_mm), "table_thickness_mm": float(inst.turntable.thickness_mm),
        "table_material": inst.turntable.material}
    return {"d0_mm": 0.0, "axis_mm": float((p - hinge) @ prop), "rotary_table_z_mm": table_z, "axis_tilt_deg": tilt,
            "axis_tilt_azimuth_deg": azimuth, "axis_offset_mm": offset, "calibration_table_z_mm": table_z,
            "calibration_plate_height_mm": 20.0, **disc}


def rig_from_instrument(inst: Instrument, base: Rig | Mapping[str, Any] | None = None,
                        exposure_ms: float = 1.0) -> Rig:
    """The rig of an instrument, exactly (module docstring).

    Parameters
    ----------
    inst : Instrument
        The instrument.
    base : Rig or Mapping[str, Any], optional
        Where the keys the instrument does not set come from (sensor noise, environment, twin):
        a rig, or its tables ``{table: {key: value}}`` as a rig file gives them; default the
        defaults of :class:`~scheimpflug.model.rig.Rig`'s tables.
    exposure_ms : float, default 1.0
        ``[sensor] exposure_ms`` [ms] (a calibration does not give it).

    Returns
    -------
    Rig
        Lens, laser, sensor and stage keys set from the instrument (nothing derived by the
        Scheimpflug plan's rule); d0 = 0, so a stage coordinate is the distance from the object
        hinge along the sheet.

    Raises
    ------
    RigError
        From :func:`rig_frame`; a turntable leaning 10° to 170° from the sheet's vertical; a
        rig the values make impossible (the key named, ``(instrument)`` appended).

    Warns
    -----
    UserWarning
        The distortion folds back inside the frame (:func:`scheimpflug.model.distortion.fold_radius`).
    """
    frame = rig_frame(inst)
    note = _fold_warning(inst.camera)
    if note:
        warnings.warn(note, stacklevel=2)
    n_c, d_c = _camera_plane(inst)
    lens = _lens_table(inst, n_c, d_c)
    focus = _focus_mm(inst, n_c, d_c)
    stage = _stage_table(inst, frame, lens["focal_length_mm"], focus)
    if isinstance(base, Rig):
        data = rig_to_dict(base)
    else:
        data = {name: dict(values) for name, values in (base or {}).items()}
    tables = {"lens": lens, "sensor": {**_sensor_table(inst, frame), "exposure_ms": exposure_ms},
              "laser": _laser_table(inst, frame, lens["focal_length_mm"], stage["axis_mm"]), "stage": stage}
    for name, values in tables.items():
        data[name] = {**data.get(name, {}), **values}
    try:
        return rig_from_tables(data)
    except RigError as exc:
        raise RigError(f"{exc} (instrument)") from None



def _mark_unknown(text: str, unknown) -> str:
    lines, table = [], ""
    for line in text.splitlines():
        if line.startswith("["):
            table = line.strip("[]")
        key = line.split(" = ")[0]
        if f"{table}.{key}" in unknown:
            line += "  # unknown: a default, ready for identification"
        lines.append(line)
    return "\n".join(lines) + "\n"


def rig_file_text(rig: Rig, inst: Instrument, source: str) -> str:
    """The rig file of an instrument's rig: the keys, the unknown ones marked, the frames in the header.

    Parameters
    ----------
    rig : Rig
        :func:`rig_from_instrument` of ``inst``.
    inst : Instrument
        The instrument.
    source : str
        Where the instrument came from (a file name), for the header.

    Returns
    -------
    str
        TOML text :func:`scheimpflug.model.rig.load_rig` reads; comments give the source, the
        camera as calibrated, ``rig_from_instrument`` and the list of unknown keys.
    """
    cam, frame = inst.camera, rig_frame(inst)
    rows = "\n".join("#   " + "  ".join(f"{x: .12g}" for x in r) for r in frame.rig_from_instrument)
    head = (f"# Rig of the instrument calibrated in {source} (scheimpflug rig from-calibration).\n"
            f"# Camera: fx {cam.fx_px!r}, fy {cam.fy_px!r}, cx {cam.cx_px!r}, cy {cam.cy_px!r} px, "
            f"{cam.width_px} × {cam.height_px} px, distortion {list(cam.distortion)[:5]}.\n"
            "# An ordinary camera (sensor.image_distance_mm = fx · pitch, principal point by the offsets, "
            "roll of the pixel axes);\n# the sheet y = d − x·tan φ is the calibration's plane.  "
            "rig_from_instrument (the instrument frame is the calibration's camera frame) [mm]:\n"
            f"{rows}\n# Unknown (defaults written, ready for identification): {', '.join(inst.unknown) or 'none'}.\n\n")
    return head + _mark_unknown(rig_to_toml(rig), set(inst.unknown))
