"""Which way a turning part's stripe runs in the frames, by the calibration (issue 34 item 3).

A part on a rotary table turns about a vertical axis that lies in the laser
sheet; the sheet cuts it along that axis's direction, so the stripe on the part
runs, in the image, the way the sheet's *height* axis ``e_h`` images.  Every
sheet model knows that direction: :meth:`SheetModel.pixel_from_stage` at two
heights of one sheet point.  A Scheimpflug rig with rows along the height (the
paper's) images it down the columns, one stripe point per row
(``stripe_along = "columns"``); a camera turned by 90° (FabScan's, Ciclop's)
across the image (``"rows"``).  A frame folder whose ``stripe_along`` says the
other way is read across its stripe: every line then meets the stripe once at
most, and the cloud is a few scattered points with exit status 0 (FabScan's
frames without ``--stripe-along rows``: 1384 points instead of 2497).

The direction is taken at the sheet point the view's centre pixel sees, over a
height step of the sheet extent of ±5 pixels there; it counts as along the
columns (rows) within :data:`CLEAR_DEG` of them, else it is oblique and nothing
is decided.  The sheet frame's ``e_h`` is the rotary axis for the paper's and the
general model (the stage's vertical), for a target calibration with table
poses and for FabScan's turntable; a target calibration without table poses
takes the image's up direction for it (:func:`scheimpflug.calibration.model.sheet_frame_from_plane`),
and the check then says what that convention implies: an axis along the image's
up direction.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["CLEAR_DEG", "height_direction_px", "stripe_along_from_calibration", "stripe_direction_problem"]

CLEAR_DEG = 30.0
"""The height axis images within this angle of the columns (rows) for a clear direction [deg]."""
_PROBE_PX = 5.0      # half the pixel step whose sheet extent sets the height step [px]


def height_direction_px(calibration, columns: int, rows: int) -> np.ndarray | None:
    """The image direction of the sheet's height axis at the view's centre.

    Parameters
    ----------
    calibration : SheetModel
        Any calibration (``stage_from_pixel`` and ``pixel_from_stage``).
    columns, rows : int
        Frame size [px], > 0.

    Returns
    -------
    (2,) ndarray float64 or None
        Unit vector ``(du, dv)`` [-] along which a height step of the centre's sheet point
        moves its pixel; None where the calibration maps the centre to no sheet point or the
        step to no finite pixels.

    Raises
    ------
    ValueError
        A frame size that is not positive.
    """
    if not (columns > 0 and rows > 0):
        raise ValueError(f"need a frame size > 0, got {columns} × {rows}")
    uc, vc = 0.5 * (columns - 1), 0.5 * (rows - 1)
    du = np.array([0.0, _PROBE_PX, -_PROBE_PX, 0.0, 0.0])
    dv = np.array([0.0, 0.0, 0.0, _PROBE_PX, -_PROBE_PX])
    with np.errstate(all="ignore"):
        s, h = (np.asarray(a, np.float64) for a in calibration.stage_from_pixel(uc + du, vc + dv))
        if not (np.all(np.isfinite(s)) and np.all(np.isfinite(h))):
            return None
        step = float(np.max(np.hypot(s[1:] - s[0], h[1:] - h[0])))
        u, v = (np.asarray(a, np.float64) for a in calibration.pixel_from_stage(
            np.full(2, s[0]), h[0] + np.array([-step, step])))
    d = np.array([u[1] - u[0], v[1] - v[0]])
    norm = float(np.hypot(*d))
    return d / norm if step > 0 and np.isfinite(norm) and norm > 0 else None


def stripe_along_from_calibration(calibration, columns: int, rows: int) -> str | None:
    """Which way a turning part's stripe runs in frames of this calibration (module docstring).

    Parameters
    ----------
    calibration : SheetModel
        Any calibration.
    columns, rows : int
        Frame size [px], > 0.

    Returns
    -------
    {"columns", "rows"} or None
        "columns" when the sheet's height axis images within :data:`CLEAR_DEG` of the
        columns (down the image), "rows" within it of the rows; None when oblique or
        not measurable.

    Raises
    ------
    ValueError
        A frame size that is not positive.
    """
    d = height_direction_px(calibration, columns, rows)
    if d is None:
        return None
    angle = math.degrees(math.atan2(abs(d[0]), abs(d[1])))          # 0: down the columns
    if angle <= CLEAR_DEG:
        return "columns"
    if angle >= 90.0 - CLEAR_DEG:
        return "rows"
    return None


def stripe_direction_problem(calibration, columns: int, rows: int, along: str) -> str | None:
    """Why a frame folder's ``stripe_along`` contradicts the calibration, or None.

    Parameters
    ----------
    calibration : SheetModel
        The calibration the folder is to be measured with.
    columns, rows : int
        The folder's frame size [px], > 0.
    along : {"columns", "rows"}
        The folder's ``stripe_along``.

    Returns
    -------
    str or None
        The contradiction, naming both directions and the fix (import again with
        ``--stripe-along``); None when they agree or the calibration decides nothing.

    Raises
    ------
    ValueError
        ``along`` neither "columns" nor "rows", or a frame size that is not positive.
    """
    if along not in ("columns", "rows"):
        raise ValueError(f"along must be 'columns' or 'rows', got {along!r}")
    expected = stripe_along_from_calibration(calibration, columns, rows)
    if expected is None or expected == along:
        return None
    across = {"columns": "down the image, one point per row", "rows": "across the image, one point per column"}
    return (f"the frames say the stripe runs along the {along} (stripe_along = {along!r}: {across[along]}), "
            f"but the calibration's sheet images a turning part's stripe along the {expected} "
            f"({across[expected]}): import the frames again with --stripe-along {expected} (or set "
            f"\"stripe_along\": \"{expected}\" in manifest.json)")
