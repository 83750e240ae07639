"""Moved: the general model is :mod:`scheimpflug.calibration.general` (issue 24).

This module re-exports its names (and the sheet-model interface) so that code written
before the calibration became a package keeps working; new code imports from
:mod:`scheimpflug.calibration`.
"""

from scheimpflug.calibration.camera import DEFAULT_FOCAL_LENGTH_MM, DEFAULT_PIXEL_PITCH_UM, ideal_camera
from scheimpflug.calibration.general import (
    GeneralCalibration,
    ModelSelection,
    SheetFit,
    SheetModelResult,
    calibrate_sheet_folder,
    fit_sheet_models,
    select_model,
)
from scheimpflug.calibration.load import load_sheet_model
from scheimpflug.calibration.model import MODELS, SheetModel

__all__ = [
    "DEFAULT_FOCAL_LENGTH_MM",
    "DEFAULT_PIXEL_PITCH_UM",
    "GeneralCalibration",
    "MODELS",
    "ModelSelection",
    "SheetFit",
    "SheetModel",
    "SheetModelResult",
    "calibrate_sheet_folder",
    "fit_sheet_models",
    "ideal_camera",
    "load_sheet_model",
    "select_model",
]
