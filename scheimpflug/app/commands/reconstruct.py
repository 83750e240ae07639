"""`scheimpflug reconstruct DIR`: rotary scan + calibration + axis → point cloud (PLY)."""

from __future__ import annotations

import sys
import time

from scheimpflug.app.commands._common import print_json

_METHODS = ("gaussian3", "cog", "blais-rioux", "edge")


def add_parser(sub):
    p = sub.add_parser("reconstruct", help="rotary scan → point cloud in the part frame (PLY)",
                       description="Extract the stripe of every frame of a rotary scan, map it "
                                   "to the light sheet with the calibration (paper Eqs. 11–12) and "
                                   "rotate it into the part frame (INTERFACE.md stage conventions). "
                                   "Writes a binary PLY coloured by height with per-point angle, "
                                   "row and intensity.")
    p.add_argument("dir", metavar="DIR", help="rotary scan folder (manifest.json + frames/)")
    p.add_argument("--calibration", required=True, metavar="CAL.json",
                   help="calibration written by 'scheimpflug calibrate --out'")
    axis = p.add_mutually_exclusive_group(required=True)
    axis.add_argument("--axis-mm", type=float, metavar="A",
                      help="rotary axis position, stage coordinate [mm]")
    axis.add_argument("--axis-from", metavar="DIR", help="locate the axis from a blocker folder")
    p.add_argument("--out", required=True, metavar="CLOUD.ply", help="output point cloud")
    p.add_argument("--method", choices=_METHODS, default="cog",
                   help="sub-pixel stripe detector (default cog: the most accurate on rendered "
                        "and on speckled stripes, benchmarks/RESULTS.md)")
    p.add_argument("--multi-peak", choices=("nearest", "strongest", "track"), default="nearest",
                   help="rule for rows with several peaks (inter-reflections): 'track' picks the "
                        "most continuous, narrow, bright one (default nearest)")
    p.add_argument("--min-snr", type=float, default=6.0,
                   help="detection threshold, peak over background noise [-] (default 6)")
    p.add_argument("--keep-saturated", action="store_true",
                   help="keep rows whose stripe peak is saturated (dropped by default: biased)")
    p.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    p.add_argument("--quiet", action="store_true", help="no progress display")
    p.set_defaults(func=_run)
    return p


def _axis_mm(args, calibration) -> tuple[float, str]:
    if args.axis_mm is not None:
        return float(args.axis_mm), "option"
    from scheimpflug.axis import locate_axis

    return float(locate_axis(args.axis_from, calibration).axis_mm), f"located from {args.axis_from}"


def _check_folder(folder, calibration) -> None:
    from scheimpflug.errors import CalibrationError, FrameError

    missing = [i for i, r in enumerate(folder.frames) if r.angle_deg is None]
    if missing:
        raise FrameError(f"{folder.path}: frame {missing[0]} ({folder.frames[missing[0]].file}) has no "
                         f"'angle_deg': not a rotary scan")
    cal_shape = (calibration.rows, calibration.columns)
    if all(cal_shape) and cal_shape != (folder.rows, folder.columns):
        raise CalibrationError(f"calibration was made for {cal_shape[0]} × {cal_shape[1]} frames, "
                               f"the scan has {folder.rows} × {folder.columns}")


def _extract(folder, args):
    """Per-frame (rows, u, intensity) of the detected stripe, and counters."""
    from scheimpflug.app.progress import Progress
    from scheimpflug.reconstruct import extract_folder

    with Progress(0, label="extract", quiet=args.quiet) as bar:
        return extract_folder(folder, args.method, min_snr=args.min_snr,
                              keep_saturated=args.keep_saturated, progress=bar,
                              multi_peak=args.multi_peak)


def _run(args) -> int:
    from scheimpflug.calibration import Calibration
    from scheimpflug.errors import FrameError
    from scheimpflug.io.frames import open_frame_folder
    from scheimpflug.io.ply import write_point_cloud
    from scheimpflug.reconstruct import reconstruct_profiles

    t0 = time.perf_counter()
    calibration = Calibration.load(args.calibration)
    folder = open_frame_folder(args.dir)
    _check_folder(folder, calibration)
    axis_mm, axis_source = _axis_mm(args, calibration)
    rows, us, peaks, stats = _extract(folder, args)
    cloud = reconstruct_profiles(rows, us, [r.angle_deg for r in folder.frames], calibration,
                                 axis_mm, intensity=peaks)
    if len(cloud) == 0:
        raise FrameError(f"{args.dir}: no stripe found in any of the {len(folder)} frames "
                         f"({stats['saturated_rows']} saturated rows dropped)")
    write_point_cloud(args.out, cloud, comment=f"scheimpflug reconstruct {args.dir} axis_mm={axis_mm:.6g}")
    summary = {"out": str(args.out), "n_points": len(cloud), "n_frames": len(folder),
               "axis_mm": axis_mm, "axis_source": axis_source, "method": args.method,
               **stats, "seconds": round(time.perf_counter() - t0, 3)}
    print(f"reconstruct: {summary['n_points']} points from {summary['n_frames']} frames "
          f"({stats['blank_frames']} without stripe, {stats['saturated_rows']} saturated rows"
          f"{' kept' if args.keep_saturated else ' dropped'}), axis {axis_mm:.3f} mm "
          f"({axis_source}), {summary['seconds']:.1f} s → {args.out}", file=sys.stderr)
    if args.json:
        print_json(summary)
    return 0
