"""`scheimpflug reconstruct DIR`: rotary scan + calibration + axis → point cloud (PLY) [+ surface model].

``reconstruct CLOUD.ply --model OUT.stl`` meshes a cloud written earlier (its
points keep their frame and row) without the frames.
"""

from __future__ import annotations

import sys
import time

from scheimpflug.app.commands._common import (
    add_allow_incomplete_option,
    add_force_option,
    check_output,
    check_plot,
    number,
    open_frames,
    print_json,
)
from scheimpflug.app.commands._model import add_model_options
from scheimpflug.app.commands._quality import add_quality_options, detection_snr, quality_from_args

_METHODS = ("gaussian3", "cog", "blais-rioux", "edge", "paper")
_SATURATED_TEXT = {"edges": " centred on their edges", "drop": " dropped", "plateau": " centred on their plateau"}


def add_parser(sub):
    p = sub.add_parser("reconstruct", help="rotary scan → point cloud in the part frame (PLY)",
                       description="Extract the stripe of every frame of a rotary scan, map it "
                                   "to the light sheet with the calibration (paper Eqs. 11–12) and "
                                   "rotate it into the part frame (docs/reference/interface.md stage conventions). "
                                   "Writes a binary PLY coloured by height with per-point angle, "
                                   "row, intensity, frame and quality (stripe width, SNR, laser and "
                                   "camera incidence, sweep edge), keeping the points that pass the "
                                   "quality filter; with --model also a watertight mesh of "
                                   "the part and its volume, area and sections.")
    p.add_argument("dir", metavar="DIR|CLOUD.ply",
                   help="rotary scan folder (manifest.json + frames/), or a cloud from an earlier "
                        "'reconstruct' to mesh with --model")
    p.add_argument("--calibration", metavar="CAL.json",
                   help="calibration written by 'scheimpflug calibrate --out' (paper or general model) "
                        "or '--opencv' (needed for a folder)")
    axis = p.add_mutually_exclusive_group()
    axis.add_argument("--axis-mm", type=number(-1e6, 1e6, unit="mm"), metavar="A",
                      help="rotary axis position, stage coordinate [mm] (default: the calibration's, when a "
                           "target calibration found it from table poses)")
    axis.add_argument("--axis-from", metavar="DIR", help="locate the axis from a blocker folder")
    p.add_argument("--out", metavar="CLOUD.ply", help="output point cloud (needed for a folder)")
    add_force_option(p)
    add_allow_incomplete_option(p)
    p.add_argument("--method", choices=_METHODS, default="cog",
                   help="sub-pixel stripe detector (default cog: the most accurate on rendered "
                        "and on speckled stripes, benchmarks/RESULTS.md; paper = the paper's red "
                        "pixels: the light bar's right boundary in whole pixels)")
    p.add_argument("--multi-peak", choices=("nearest", "strongest", "track"), default="nearest",
                   help="rule for rows with several peaks (inter-reflections): 'track' picks the "
                        "most continuous, narrow, bright one (default nearest)")
    add_quality_options(p)
    sat = p.add_mutually_exclusive_group()
    sat.add_argument("--saturated", choices=("edges", "drop", "plateau"), default="edges",
                     help="rows whose stripe peak is saturated (cheap cameras clip the stripe): 'edges' "
                          "(default) centres them on the midpoint of the clipped profile's two edges (at 0.3 "
                          "of the plateau's height: scheimpflug.stripe), each point with its own uncertainty "
                          "(PLY properties saturated, centre_sigma_px); 'drop' leaves them out (the default "
                          "before issue 34); 'plateau' takes the middle of the run of saturated pixels (the "
                          "old --keep-saturated)")
    sat.add_argument("--keep-saturated", action="store_const", const="edges", dest="saturated",
                     help="the same as --saturated edges")
    p.add_argument("--drop-isolated", action="store_true",
                   help="drop a row's stripe when neither adjacent row has one within 2 px "
                        "(lone detections: noise or stray light at a part's edge)")
    housing = p.add_mutually_exclusive_group()
    housing.add_argument("--keep-housing", action="store_true",
                         help="keep the housing's points of a real scan (default for a folder written by "
                              "'import': drop the still points on the still walls' lines and, when the "
                              "calibration gives the turntable's radius, the points beyond it)")
    housing.add_argument("--drop-housing", action="store_true",
                         help="drop the housing's points of a rendered scan too (default for a rendered "
                              "folder: keep every point; its parts are often surfaces of revolution about "
                              "the axis, which stand still)")
    p.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    p.add_argument("--quiet", action="store_true", help="no progress display")
    add_model_options(p)
    p.set_defaults(func=_run)
    return p


def _calibration_axis(path) -> float | None:
    """The rotary axis a calibration file holds (a target calibration with table poses, FabScan's), or None."""
    import math

    from scheimpflug.calibration import load_calibration

    axis = getattr(load_calibration(path), "axis", None)      # a bad calibration is its own error (item 13)
    try:
        value = float(axis["axis_mm"]) if isinstance(axis, dict) else None
    except (ValueError, TypeError, KeyError):
        return None
    return value if value is not None and math.isfinite(value) else None


def _axis_mm(args, calibration, folder) -> tuple[float, str]:
    if args.axis_mm is None and not args.axis_from:
        value = getattr(calibration, "axis", None) or {}
        off = (f": {value['angle_to_sheet_deg']:.2f}° and {abs(value['distance_to_sheet_mm']):.2f} mm from the sheet"
               if "angle_to_sheet_deg" in value and "distance_to_sheet_mm" in value else "")
        return float(value["axis_mm"]), f"the calibration's, measured in 3-D{off}"
    if args.axis_mm is not None:
        _warn_axis_outside(args.axis_mm, calibration, folder)
        return float(args.axis_mm), "option"
    from scheimpflug.axis import locate_axis

    blocker = open_frames(args.axis_from, args)
    _check_stripe_direction(calibration, blocker)
    res = locate_axis(blocker, calibration)
    for note in res.warnings:
        print(f"warning: --axis-from: {note}", file=sys.stderr)
    return float(res.axis_mm), f"located from {args.axis_from}"


def _warn_axis_outside(axis_mm: float, calibration, folder) -> None:
    """A rotary axis outside the depth range the calibration covers is refused (a typo or a unit)."""
    from scheimpflug.calibration import check_axis_position

    note = check_axis_position(axis_mm, calibration, folder.columns, folder.rows)
    if note:
        print(f"warning: --axis-mm: {note}", file=sys.stderr)


def _check_folder(folder, calibration) -> None:
    from scheimpflug.errors import CalibrationError, FrameError

    missing = [i for i, r in enumerate(folder.frames) if r.angle_deg is None]
    if missing:
        raise FrameError(f"{folder.path}: frame {missing[0]} ({folder.frames[missing[0]].file}) has no "
                         f"'angle_deg': not a rotary scan")
    from scheimpflug.calibration import applicability_problem
    from scheimpflug.io.frames import radians_note

    note = radians_note([r.angle_deg for r in folder.frames])
    if note:
        print(f"warning: {folder.path}: {note}", file=sys.stderr)
    problem = applicability_problem(calibration, folder)
    if problem:
        raise CalibrationError(f"the calibration cannot be applied to {str(folder.path)!r}: {problem}")
    _check_stripe_direction(calibration, folder)


def _check_stripe_direction(calibration, folder) -> None:
    """Refuse a folder whose stripe_along contradicts the calibration (issue 34 item 3)."""
    from scheimpflug.calibration.direction import stripe_direction_problem
    from scheimpflug.errors import CalibrationError

    problem = stripe_direction_problem(calibration, folder.columns, folder.rows, folder.stripe_along)
    if problem:
        raise CalibrationError(f"the calibration cannot be applied to {str(folder.path)!r}: {problem}")


def _extract(folder, args):
    """The detected stripe of every frame with its quality (FolderStripes)."""
    from scheimpflug.app.progress import Progress
    from scheimpflug.reconstruct import extract_folder_stripes

    with Progress(0, label="extract", quiet=args.quiet) as bar:
        return extract_folder_stripes(folder, args.method, min_snr=detection_snr(args),
                                      saturated=args.saturated, progress=bar,
                                      multi_peak=args.multi_peak, drop_isolated=args.drop_isolated)


def _check_args(args) -> bool:
    """Whether the input is a cloud file; one clear error for missing options."""
    from pathlib import Path

    from scheimpflug.app.commands._model import check_model_args
    from scheimpflug.errors import ScheimpflugError

    is_cloud = Path(args.dir).suffix.lower() == ".ply" and not Path(args.dir).is_dir()
    if is_cloud and not args.model:
        raise ScheimpflugError(f"{args.dir}: a point cloud as input needs --model (what to build from it)")
    if not is_cloud:
        missing = [name for name, v in (("--calibration", args.calibration), ("--out", args.out),
                                        ("--axis-mm or --axis-from", args.axis_mm is not None or args.axis_from
                                         or (args.calibration and _calibration_axis(args.calibration) is not None)))
                   if not v]
        if missing:
            raise ScheimpflugError(f"reconstructing the folder {args.dir} needs {', '.join(missing)}")
    check_model_args(args)
    _check_outputs(args, is_cloud)
    return is_cloud


def _check_outputs(args, is_cloud: bool) -> None:
    """Refuse outputs that are inputs, folders or existing files (without --force), before any work."""
    inputs = [args.dir] if is_cloud else [args.calibration]
    folders = [] if is_cloud else [args.dir, args.axis_from]
    if not is_cloud:
        check_output(args.out, "--out", force=args.force, inputs=inputs, folders=folders)
    check_output(args.model, "--model", force=args.force, inputs=inputs + [args.out], folders=folders)
    check_plot(args.sections_plot, "--sections-plot", force=args.force,
               inputs=inputs + [args.out, args.model], folders=folders)


def _from_folder(args, t0: float):
    from scheimpflug.calibration import load_calibration
    from scheimpflug.errors import FrameError
    from scheimpflug.io.ply import write_point_cloud
    from scheimpflug.reconstruct import reconstruct_profiles

    quality_from_args(args)                      # contradictory filter options: refused before any work
    calibration = load_calibration(args.calibration)
    folder = open_frames(args.dir, args)
    _check_folder(folder, calibration)
    axis_mm, axis_source = _axis_mm(args, calibration, folder)
    st = _extract(folder, args)
    from scheimpflug.io.frames import check_distinct_frames

    check_distinct_frames(folder, [i for i, r in enumerate(st.rows) if len(r)])   # a frame listed twice
    st, housing = _drop_housing(args, folder, st, calibration)
    stats = st.stats
    own_axis = args.axis_mm is None and not args.axis_from     # the calibration's, a line in 3-D
    cloud = reconstruct_profiles(st.rows, st.u, [r.angle_deg for r in folder.frames], calibration,
                                 None if own_axis else axis_mm, intensity=st.peak, snr=st.snr,
                                 stripe_width_px=st.stripe_width_px, along=st.along, saturated=st.saturated,
                                 centre_sigma_px=st.centre_sigma_px)
    if len(cloud):
        cloud, quality = _apply_quality(args, cloud, calibration, folder, axis_mm)
        if len(cloud) == 0:
            raise FrameError(f"{args.dir}: the quality filter dropped all {quality['n_points']} points "
                             f"({_dropped_text(quality)}): see --max-incidence-deg, --min-snr, "
                             "--no-quality-filter")
    if len(cloud) == 0:
        saturated = (f"; {stats['saturated_frames']} of them saturated (most pixels at the saturation "
                     "level): lower the exposure" if stats["saturated_frames"] else "")
        raise FrameError(f"{args.dir}: no stripe found in any of the {len(folder)} frames "
                         f"({stats['saturated_rows']} saturated rows{_SATURATED_TEXT[args.saturated]}{saturated}): "
                         "no usable frame")
    summary = {"out": str(args.out), "n_points": len(cloud), "n_frames": len(folder),
               "axis_mm": axis_mm, "axis_source": axis_source, "method": args.method,
               "saturated": args.saturated, **stats, "saturated_points": int(cloud.saturated.sum()),
               "quality_filter": quality, "housing": housing, "seconds": round(time.perf_counter() - t0, 3)}
    kept = (f"; quality filter: {_dropped_text(quality)} dropped of {quality['n_points']}"
            if quality["filter"] else "; no quality filter")
    print(f"reconstruct: {summary['n_points']} points from {summary['n_frames']} frames "
          f"({stats['blank_frames']} without stripe, {stats['saturated_rows']} saturated rows"
          f"{_SATURATED_TEXT[args.saturated]}{kept}), axis {axis_mm:.3f} mm "
          f"({axis_source}), {summary['seconds']:.1f} s → {args.out}", file=sys.stderr)
    return cloud, folder, summary, lambda: write_point_cloud(
        args.out, cloud, comment=f"scheimpflug reconstruct {args.dir} axis_mm={axis_mm:.6g}")


def imported_scan(folder) -> bool:
    """Whether a frame folder holds real frames (written by ``scheimpflug import``), not rendered ones."""
    import json

    try:
        return json.loads((folder.path / "manifest.json").read_text()).get("source") == "scheimpflug import"
    except (OSError, ValueError, AttributeError):
        return False


def _drop_housing(args, folder, st, calibration):
    """The stripes without the housing's points, as the options and the folder say; and the summary block."""
    from scheimpflug.errors import FrameError
    from scheimpflug.still_points import separate_housing

    real = imported_scan(folder)
    reason = ("--keep-housing" if args.keep_housing else "--drop-housing" if args.drop_housing
              else "a real scan (written by 'import')" if real else "a rendered scan: every point kept")
    if args.keep_housing or not (real or args.drop_housing):
        return st, {"applied": False, "reason": reason}
    split = separate_housing(st, calibration)
    n_before = sum(len(r) for r in st.rows)
    block = {"applied": True, "reason": reason, **split.to_json_dict()}
    if n_before and block["dropped"] == n_before:
        raise FrameError(f"{args.dir}: all {n_before} stripe points are the housing's (still, or beyond the "
                         "turntable's radius): see --keep-housing")
    radius = f", {split.beyond_turntable} beyond the turntable's {split.radius_mm:g} mm radius" \
        if split.radius_mm is not None else ", no turntable radius in the calibration"
    print(f"reconstruct: housing: {block['dropped']} of {n_before} stripe points dropped ({split.still} still on "
          f"the walls' lines{radius}){'; ' + split.note if split.note else ''}; --keep-housing keeps them",
          file=sys.stderr)
    return st.select(split.keep), block


def _apply_quality(args, cloud, calibration, folder, axis_mm: float):
    """The cloud with its incidences and sweep edges, filtered as the options say; and the counts."""
    from scheimpflug.app.commands._quality import measure_quality
    from scheimpflug.point_quality import filter_counts, quality_mask

    cloud, note = measure_quality(cloud, calibration, folder, axis_mm)
    if note:
        print(f"warning: point quality: {note}", file=sys.stderr)
    quality = quality_from_args(args)
    if quality is None:
        return cloud, {"filter": None, "n_points": len(cloud), "n_kept": len(cloud)}
    counts = filter_counts(cloud, quality)
    return cloud.select(quality_mask(cloud, quality)), {"filter": quality.to_json_dict(), **counts}


def _dropped_text(q: dict) -> str:
    return (f"{q['n_points'] - q['n_kept']} ({q['low_snr']} SNR < {q['filter']['min_snr']:g}, "
            f"{q['uncertain_saturated']} saturated with a centre less certain than that SNR gives, "
            f"{q['laser_incidence']} laser and {q['camera_incidence']} camera incidence > "
            f"{q['filter']['max_incidence_deg']:g}°, {q['sweep_edge']} on the sweep edge)")


def _model(args, cloud, folder, summary: dict, write_cloud) -> None:
    """Build the model first, then write the cloud and the model: a meshing error leaves no file."""
    from scheimpflug.app.commands._model import (
        make_model,
        model_summary,
        print_model_line,
        table_z_from_folder,
        write_model,
    )

    t0 = time.perf_counter()
    table_z = table_z_from_folder(args, folder)
    model = make_model(cloud, args, table_z)
    seconds = time.perf_counter() - t0
    write_cloud()
    numbers = model_summary(model, args.section_z)
    write_model(args.model, model, comment=f"scheimpflug reconstruct {args.dir} --model-method {args.model_method}")
    if args.sections_plot:
        from scheimpflug.app.report_plots import plot_sections

        plot_sections(model.vertices_mm, model.faces, [s["z_mm"] for s in numbers["sections"]], args.sections_plot)
    summary.update(model=str(args.model), model_method=args.model_method, table_z_mm=table_z,
                   model_seconds=round(seconds, 3), **numbers)
    print_model_line(numbers, args.model, sys.stderr)


def _run(args) -> int:
    t0 = time.perf_counter()
    if _check_args(args):
        from scheimpflug.io.ply import read_point_cloud

        cloud, folder = read_point_cloud(args.dir), None
        summary = {"cloud": str(args.dir), "n_points": len(cloud)}
        write_cloud = lambda: None  # noqa: E731  (the cloud is the input)
    else:
        cloud, folder, summary, write_cloud = _from_folder(args, t0)
    if args.model:
        _model(args, cloud, folder, summary, write_cloud)
    else:
        write_cloud()
    if args.json:
        print_json(summary)
    return 0
