"""Reading any calibration file as a sheet model (:class:`scheimpflug.calibration.model.SheetModel`).

:func:`load_sheet_model` reads what ``scheimpflug calibrate`` writes — the
paper form, the general model, the target calibration — and an OpenCV calibration (our ``--opencv``
export, or any JSON/YAML with ``camera_matrix``, ``dist_coeffs`` and
``laser_plane``: :func:`scheimpflug.calibration.opencv.read_opencv`) and FabScan's
``config.json`` (its first laser, its points as FabScan makes them:
:func:`scheimpflug.calibration.fabscan.read_fabscan`).  Calibration
files written before the calibration became a package (``model`` absent or
``"paper"``, ``"general"``) read as they always did.

Every file records the frame size it was made for and every reader checks the
record (:func:`scheimpflug.calibration.model.frame_size_from_json`): an OpenCV
export is read by its ``"format"``, whatever model made it (its ``image_size``
is its size; before, an export of a target calibration was read as a target
calibration file and lost it).  A file of an earlier version without a size
still loads; applying it to frames warns that the size cannot be checked.
"""

from __future__ import annotations

import json
from pathlib import Path

from scheimpflug.calibration.fabscan import is_fabscan_config, read_fabscan
from scheimpflug.calibration.general import GeneralCalibration
from scheimpflug.calibration.model import MODELS
from scheimpflug.calibration.opencv import FORMAT as OPENCV_FORMAT
from scheimpflug.calibration.opencv import YAML_SUFFIXES, read_opencv
from scheimpflug.calibration.paper import Calibration
from scheimpflug.calibration.target import TargetCalibration
from scheimpflug.errors import CalibrationError

__all__ = ["load_calibration", "load_sheet_model"]


def _read_json(p: Path) -> dict:
    try:
        d = json.loads(p.read_text("utf-8"))
    except FileNotFoundError:
        raise CalibrationError(f"calibration file {str(p)!r} does not exist") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CalibrationError(f"calibration file {str(p)!r} is unreadable: {exc}") from None
    if not isinstance(d, dict):
        raise CalibrationError(f"calibration file {str(p)!r} must hold a JSON object")
    return d


def _from_dict(p: Path, d: dict):
    model = d.get("model")
    if model is not None and model not in MODELS:
        raise CalibrationError(f"calibration file {str(p)!r}: \"model\": {model!r:.40} is not a known model "
                               f"(known: {', '.join(MODELS)})")
    try:
        if model == "general":
            return GeneralCalibration.from_json_dict(d)
        if model == "target":
            return TargetCalibration.from_json_dict(d)
    except CalibrationError as exc:
        raise CalibrationError(f"calibration file {str(p)!r}: {exc}") from None
    return Calibration.load(p)


def load_sheet_model(path: str | Path):
    """Read any calibration file as a sheet model (module docstring).

    Parameters
    ----------
    path : str or Path
        A calibration JSON of ``scheimpflug calibrate`` (paper form, general model, target), an OpenCV
        calibration (JSON with ``camera_matrix``, or ``.yml``/``.yaml``/``.xml``) or FabScan's
        ``config.json``.

    Returns
    -------
    SheetModel
        :class:`~scheimpflug.calibration.paper.Calibration`,
        :class:`~scheimpflug.calibration.general.GeneralCalibration` or
        :class:`~scheimpflug.calibration.target.TargetCalibration`.

    Raises
    ------
    CalibrationError
        A missing, unreadable or malformed file, a ``"model"`` that is not one of :data:`MODELS`,
        or a foreign calibration this pipeline cannot hold (the reason named).
    """
    p = Path(path)
    if p.suffix.lower() in YAML_SUFFIXES:
        return read_opencv(p)
    d = _read_json(p)
    if is_fabscan_config(d):
        return read_fabscan(p)
    if d.get("format") == OPENCV_FORMAT or ("camera_matrix" in d and d.get("model") != "target"):
        return read_opencv(p)         # our export (whatever its "model" says) or a foreign OpenCV file
    return _from_dict(p, d)


#: The name this function had in ``scheimpflug.io.opencv`` (before the calibration package).
load_calibration = load_sheet_model
