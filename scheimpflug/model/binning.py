"""Binned read-out of a rig's sensor: a reduced-resolution sensor with the same geometry."""

from __future__ import annotations

from scheimpflug.model.rig import Rig

__all__ = ["binned_rig"]


def binned_rig(rig: Rig, k: int) -> Rig:
    """The same rig read out with k × k binning (a reduced-resolution sensor, same geometry).

    Parameters
    ----------
    rig : Rig
        The instrument at full resolution.
    k : int
        Binning factor, >= 1 [-].

    Returns
    -------
    Rig
        ``rig`` itself for k = 1, else a copy with the sensor table rescaled
        (see Notes).

    Raises
    ------
    ValueError
        If ``k`` is not an integer >= 1 (booleans refused), or if the sensor
        has fewer than ``k`` columns or rows.

    Notes
    -----
    A binned pixel j covers original pixels k·j … k·j + k − 1, so its centre is at
    original coordinate u = k·j + (k − 1)/2.  Hence: pitch × k; columns and rows
    // k (a remainder at the far edge is dropped); hinge_column, axis_row →
    (x − (k − 1)/2)/k; pixel offsets / k (for an ordinary camera, ``image_distance_mm`` > 0, the
    offsets that keep its principal point at (x − (k − 1)/2)/k).  Sensor plane, hinge and sheet are
    unchanged, so F² [px·mm] scales by 1/k and C is unchanged.  Photometry:
    a binned pixel has k² times the area, so the exposure time is divided by k²
    — a binned pixel collects the charge an unbinned one would (the operator
    re-exposes), and frames stay as far from saturation as at full resolution;
    full well, read noise and ADC are those of the rig's sensor table.  The camera's
    sharpening (``[chain] sharpen_sigma_px``, in frame pixels) is divided by k (at least
    0.3 px, its range's floor).  Keys
    that the rule derived for ``rig`` (stage positions, exposure) are derived
    again for the binned sensor (:mod:`scheimpflug.model.plan`: its pixel
    margins are in the pixels the pipeline reads, its exposure is the one that
    suits the binned pixels); keys the rig sets are kept.
    """
    if not isinstance(k, int) or isinstance(k, bool) or k < 1:
        raise ValueError(f"binning must be an integer >= 1, got {k!r}")
    if k == 1:
        return rig
    s = rig.sensor
    if s.columns < k or s.rows < k:
        raise ValueError(f"binning {k} leaves no pixel of a {s.columns} × {s.rows} sensor")
    c = (k - 1) / 2
    off_u, off_v = s.offset_u_px / k, s.offset_v_px / k
    if s.image_distance_mm > 0:       # an ordinary camera: keep its principal point (a remainder is dropped)
        pp_u, pp_v = 0.5 * (s.columns - 1) - s.offset_u_px, 0.5 * (s.rows - 1) - s.offset_v_px
        off_u = 0.5 * (s.columns // k - 1) - (pp_u - c) / k
        off_v = 0.5 * (s.rows // k - 1) - (pp_v - c) / k
    # the camera's sharpening works in the frame's pixels: its Gaussian keeps its size on the sensor
    chain = {"sharpen_sigma_px": max(rig.chain.sharpen_sigma_px / k, 0.3)}
    return rig.replace(chain=chain, sensor={
        "pixel_pitch_um": s.pixel_pitch_um * k, "columns": s.columns // k, "rows": s.rows // k,
        "hinge_column": (s.hinge_column - c) / k, "axis_row": (s.axis_row - c) / k,
        "offset_u_px": off_u, "offset_v_px": off_v,
        "exposure_ms": None if "sensor.exposure_ms" in rig.derived else s.exposure_ms / (k * k)})
