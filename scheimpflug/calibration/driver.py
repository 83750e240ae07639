"""One folder driver for every calibration method: :func:`calibrate_folder`.

========  ===========================================================  ==========================
method    what the frames show                                         result
========  ===========================================================  ==========================
best      a plate moved along the sheet on a translation stage         :class:`CalibrationResult`
paper     (the same) — the paper's endpoint estimate                   :class:`CalibrationResult`
refined   (the same) — the refined joint fit                           :class:`CalibrationResult`
general   (the same) — homography ∘ radial distortion                  :class:`SheetModelResult`
auto      (the same) — general or paper form by the F-test             :class:`SheetModelResult`
target    a printed pattern in poses, the laser line on it (no stage)  :class:`TargetResult`
========  ===========================================================  ==========================

Every result's ``model`` is the sheet model it gives
(:class:`scheimpflug.calibration.model.SheetModel`).
"""

from __future__ import annotations

from pathlib import Path

from scheimpflug.calibration import general, paper, target
from scheimpflug.io.frames import FrameFolder

__all__ = ["METHODS", "calibrate_folder"]

#: The methods :func:`calibrate_folder` knows (module docstring).
METHODS = ("best", "paper", "refined", "general", "auto", "target")


def calibrate_folder(folder: str | Path | FrameFolder, plate_height_mm: float | None = None, *,
                     method: str = "best", **options):
    """Calibrate a frame folder by one method (module docstring's table).

    Parameters
    ----------
    folder : path or FrameFolder
        The calibration frames.
    plate_height_mm : float, optional
        Plate height [mm] (plate methods; default the manifest's, else 89).
    method : str, default "best"
        One of :data:`METHODS`.
    **options
        The method's own options: ``detector``, ``progress``, ``tol``, ``accuracy`` (every plate
        method; :func:`scheimpflug.calibration.paper.calibrate_folder`), ``focal_length_mm``,
        ``pixel_pitch_um``, ``fit_k2``, ``extra_points``, ``alpha``, ``min_rss_drop`` (general, auto:
        :func:`scheimpflug.calibration.general.calibrate_sheet_folder`), ``pattern`` (required),
        ``tilt``, ``pixel_pitch_um``, ``distortion``, ``refine``, ``detector``, ``stripe_along``,
        ``progress`` (target: :func:`scheimpflug.calibration.target.calibrate_target_folder`).

    Returns
    -------
    CalibrationResult, SheetModelResult or TargetResult
        The method's result; its ``model`` is the sheet model.

    Raises
    ------
    ValueError
        An unknown method.
    CalibrationError
        The method's own (too few usable frames, …).
    """
    if method in ("best", "paper", "refined"):
        return paper.calibrate_folder(folder, plate_height_mm, method=method, **options)
    if method in ("general", "auto"):
        return general.calibrate_sheet_folder(folder, plate_height_mm, model=method, **options)
    if method == "target":
        if "pattern" not in options:
            raise ValueError("method 'target' needs pattern=SPEC")
        return target.calibrate_target_folder(folder, **options)
    raise ValueError(f"unknown calibration method {method!r} (known: {', '.join(METHODS)})")
