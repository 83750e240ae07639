"""Calibration of a light-sheet profiler: one sheet-model interface, one module per method.

* :mod:`~scheimpflug.calibration.model` — the interface every calibration implements
  (:class:`SheetModel`: pixel ↔ sheet point, in sheet and camera coordinates) and the
  sheet's frame in the camera frame;
* :mod:`~scheimpflug.calibration.measure` — what one frame gives: the plate's stripe and
  endpoints, the pattern's corners, the laser's points on a pattern;
* :mod:`~scheimpflug.calibration.paper` — the paper's calibration (Section 3) and a refined
  joint fit, on a translation stage;
* :mod:`~scheimpflug.calibration.general` — homography ∘ radial distortion from the same
  plate frames, and the F-test that chooses between the two;
* :mod:`~scheimpflug.calibration.target` — without a stage: a printed pattern in several
  poses and the laser line on it (OpenCV's tilted camera and a laser plane);
* :mod:`~scheimpflug.calibration.camera` — OpenCV's camera models; :mod:`~scheimpflug.calibration.pattern`
  — printed patterns' geometry; :mod:`~scheimpflug.calibration.opencv` — the OpenCV export;
  :mod:`~scheimpflug.calibration.foreign` — other tools' calibration files;
  :mod:`~scheimpflug.calibration.load` — reading any calibration file;
  :mod:`~scheimpflug.calibration.driver` — :func:`calibrate_folder`, one driver for every method.

The names of the module ``scheimpflug.calibration`` before it became this package are
re-exported here.
"""

from scheimpflug.calibration.camera import (
    CAMERA_FROM_RIG,
    DEFAULT_FOCAL_LENGTH_MM,
    DEFAULT_PIXEL_PITCH_UM,
    OpenCVCamera,
    TiltedCamera,
    camera_from_sensor_pose,
    ideal_camera,
    tilt_matrix,
)
from scheimpflug.calibration.driver import METHODS, calibrate_folder
from scheimpflug.calibration.general import (
    GeneralCalibration,
    ModelSelection,
    SheetFit,
    SheetModelResult,
    calibrate_sheet_folder,
    fit_sheet_models,
    select_model,
)
from scheimpflug.calibration.load import load_calibration, load_sheet_model
from scheimpflug.calibration.measure import (
    CalibrationTolerances,
    PlateMeasurement,
    double_stripe_rows,
    frame_diagnosis,
    measure_plate_frame,
)
from scheimpflug.calibration.model import MODELS, SheetModel
from scheimpflug.calibration.opencv import opencv_dict, read_opencv, write_opencv
from scheimpflug.calibration.paper import (
    Calibration,
    CalibrationAccuracy,
    CalibrationResult,
    accuracy_warnings,
    applicability_problem,
    c_sigma_from_endpoint_fits,
    calibrate_measurements,
    check_against_manifest,
    check_axis_position,
    check_used_frames_distinct,
    endpoint_residual_px,
)
from scheimpflug.calibration.pattern import PatternSpec, parse_pattern
from scheimpflug.calibration.target import TargetCalibration, TargetResult, calibrate_target_folder

__all__ = [
    "CAMERA_FROM_RIG",
    "Calibration",
    "CalibrationAccuracy",
    "CalibrationResult",
    "CalibrationTolerances",
    "DEFAULT_FOCAL_LENGTH_MM",
    "DEFAULT_PIXEL_PITCH_UM",
    "GeneralCalibration",
    "METHODS",
    "MODELS",
    "ModelSelection",
    "OpenCVCamera",
    "PatternSpec",
    "PlateMeasurement",
    "SheetFit",
    "SheetModel",
    "SheetModelResult",
    "TargetCalibration",
    "TargetResult",
    "TiltedCamera",
    "accuracy_warnings",
    "applicability_problem",
    "c_sigma_from_endpoint_fits",
    "calibrate_folder",
    "calibrate_measurements",
    "calibrate_sheet_folder",
    "calibrate_target_folder",
    "camera_from_sensor_pose",
    "check_against_manifest",
    "check_axis_position",
    "check_used_frames_distinct",
    "double_stripe_rows",
    "endpoint_residual_px",
    "fit_sheet_models",
    "frame_diagnosis",
    "ideal_camera",
    "load_calibration",
    "load_sheet_model",
    "measure_plate_frame",
    "opencv_dict",
    "parse_pattern",
    "read_opencv",
    "select_model",
    "tilt_matrix",
    "write_opencv",
]
