"""The point-quality options shared by `reconstruct` and `acceptance` (scheimpflug.point_quality)."""

from __future__ import annotations

import math

from scheimpflug.app.commands._common import number

__all__ = ["DETECTION_SNR", "add_quality_options", "detection_snr", "measure_quality", "quality_from_args"]

#: The detector's own threshold: stripe rows are found down to this peak SNR [-].
DETECTION_SNR = 6.0


def add_quality_options(p) -> None:
    """Add ``--max-incidence-deg``, ``--min-snr``, ``--keep-sweep-edges`` and ``--no-quality-filter``.

    Parameters
    ----------
    p : argparse.ArgumentParser
        The command's parser.
    """
    from scheimpflug.point_quality import DEFAULT_FILTER as d

    g = p.add_argument_group("point quality filter (scheimpflug.point_quality; default on)")
    g.add_argument("--max-incidence-deg", type=number(0, 90, lo_open=True, unit="deg"), default=None,
                   help=f"drop points whose laser or camera incidence (from the surface normal of the "
                        f"frame × row grid) exceeds this [deg] (default {d.max_incidence_deg:g}: the "
                        f"sheet's footprint is 1/cos = {1 / math.cos(math.radians(d.max_incidence_deg)):.1f} × "
                        "longer than head-on)")
    g.add_argument("--min-snr", type=number(0, 1e4, lo_open=True), default=None,
                   help=f"smallest stripe peak over the background noise of a point [-] (default "
                        f"{d.min_snr:g}: the centre's Cramér–Rao bound is then 0.1 px for a σ = 1.5 px "
                        f"stripe; with --no-quality-filter the detection threshold, default "
                        f"{DETECTION_SNR:g}); a saturated point, whose clipped peak's SNR says nothing of "
                        "its centre, is kept when its centre's σ is at most that bound for its width")
    g.add_argument("--keep-sweep-edges", action="store_true",
                   help="keep the points where the sheet enters or leaves the surface partly lit (the "
                        "same row empty in an adjacent frame and the point under half as bright as "
                        "that row's neighbour: biased by the sheet's thickness)")
    g.add_argument("--no-quality-filter", action="store_true",
                   help="keep every detected point (the qualities are still written)")


def quality_from_args(args):
    """The filter the options ask for, or None (``--no-quality-filter``).

    Parameters
    ----------
    args : argparse.Namespace
        Parsed options of :func:`add_quality_options`.

    Returns
    -------
    QualityFilter or None
        The default filter with the options' thresholds.

    Raises
    ------
    ScheimpflugError
        ``--no-quality-filter`` with a filter threshold.
    """
    import dataclasses

    from scheimpflug.errors import ScheimpflugError
    from scheimpflug.point_quality import DEFAULT_FILTER

    if args.no_quality_filter:
        if args.max_incidence_deg is not None or args.keep_sweep_edges:
            raise ScheimpflugError("--no-quality-filter keeps every point: it cannot be combined with "
                                   "--max-incidence-deg or --keep-sweep-edges")
        return None
    changes = {"max_incidence_deg": args.max_incidence_deg, "min_snr": args.min_snr}
    q = dataclasses.replace(DEFAULT_FILTER, **{k: v for k, v in changes.items() if v is not None})
    return dataclasses.replace(q, drop_sweep_edges=not args.keep_sweep_edges)


def detection_snr(args) -> float:
    """The detector's threshold: ``--min-snr`` without the filter, else the lower of it and 6.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed options of :func:`add_quality_options`.

    Returns
    -------
    float
        Peak SNR down to which stripe rows are detected [-].
    """
    if args.no_quality_filter:
        return float(args.min_snr) if args.min_snr is not None else DETECTION_SNR
    return min(DETECTION_SNR, float(args.min_snr)) if args.min_snr is not None else DETECTION_SNR


def _rig_number(folder, table: str, key: str, default: float) -> float:
    value = ((folder.rig or {}).get(table) or {}).get(key) if isinstance(folder.rig, dict) else None
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    return float(value) if ok else default


def measure_quality(cloud, calibration, folder, axis_mm: float):
    """A reconstructed cloud with its incidences and sweep edges (from the calibration and the manifest).

    Parameters
    ----------
    cloud : scheimpflug.reconstruct.PointCloud
        The scan's cloud (frame and row per point).
    calibration : SheetModel
        The calibration that made it.
    folder : scheimpflug.io.frames.FrameFolder
        The scan (its manifest's rig gives the focal length, pixel pitch and laser
        origin; without one, the paper rig's 55 mm, 5.86 µm and the lens plane).
    axis_mm : float
        Stage coordinate of the rotary axis [mm].

    Returns
    -------
    cloud : PointCloud
        With ``incidence_laser_deg``, ``incidence_camera_deg`` and ``sweep_edge``.
    note : str or None
        Why the incidences could not be measured (they stay unknown), else None.
    """
    from scheimpflug.errors import CalibrationError
    from scheimpflug.point_quality import assess_points, sheet_geometry, sweep_edges
    from scheimpflug.sheet_model import DEFAULT_FOCAL_LENGTH_MM, DEFAULT_PIXEL_PITCH_UM

    f = folder.rig_value("lens", "focal_length_mm") or DEFAULT_FOCAL_LENGTH_MM
    p = folder.rig_value("sensor", "pixel_pitch_um") or DEFAULT_PIXEL_PITCH_UM
    try:
        geometry = sheet_geometry(calibration, f, p, _rig_number(folder, "laser", "origin_x_mm", 0.0))
    except (CalibrationError, ValueError, ArithmeticError):
        import dataclasses

        edges = sweep_edges(cloud.frame, cloud.row, len(folder), cloud.intensity)
        return dataclasses.replace(cloud, sweep_edge=edges), (
            f"incidence angles not measured: the calibration is no Scheimpflug rig with f = {f:g} mm and "
            f"pixel pitch {p:g} µm (give the rig's lens and sensor in the manifest)")
    return assess_points(cloud, geometry, axis_mm, len(folder)), None
