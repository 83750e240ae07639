"""`scheimpflug compare REAL_DIR TWIN_DIR`: a real scan's frames against a twin's, frame by frame and per region."""

from __future__ import annotations

import argparse
import json
import tempfile
import time
import warnings
from pathlib import Path

from scheimpflug.app.commands._common import (
    add_allow_incomplete_option,
    add_force_option,
    check_output,
    open_frames,
    print_json,
)
from scheimpflug.errors import ScheimpflugError
from scheimpflug.stripe import METHODS

REPORT_PAIRS = 3
"""Pairs pictured by --report: the first, the middle and the last compared."""


def add_parser(sub):
    p = sub.add_parser(
        "compare", help="compare a real scan's frames with a twin's, per region (walls, part, table)",
        description="Pair the frames of a real scan (an imported frame folder) and of a twin's render by "
                    "their table angle and compare them per region (each wall, the part, the table): the "
                    "stripe's position (twin − real), width (FWHM), peak level, saturated fraction, halo, "
                    "background level and noise, speckle contrast and detection rate; with --calibration, "
                    "the walls' straightness and stillness for every stripe detector, with the twin's 90 % "
                    "interval (a bootstrap over its frames). Levels in the frames' own DN.")
    p.add_argument("real", metavar="REAL_DIR", help="frame folder of the real scan (scheimpflug import)")
    p.add_argument("twin", metavar="TWIN_DIR",
                   help="frame folder of the twin's frames (render rotary), or a twin folder holding twin.json "
                        "and a frame folder frames/")
    p.add_argument("--frames", metavar="SEL", default="all",
                   help="real frames compared, by their index in REAL_DIR: all, even, odd, A:B[:STEP] "
                        "(Python's range) or I,J,K (default all); each paired with the twin frame at its angle")
    p.add_argument("--regions", metavar="NAME=LO:HI,...",
                   help="along-stripe pixel ranges (inclusive; columns for a stripe along the rows) of the "
                        "regions wall_left, wall_right, part, table (default: TWIN_DIR's twin.json, else found "
                        "in the real frames: still lines are walls or the table, the moving stripe the part)")
    p.add_argument("--calibration", metavar="FILE",
                   help="the real scanner's calibration (FabScanPi config.json, a calibrate --out or OpenCV "
                        "file): the detectors' wall figures need it (without it they are skipped, saying so)")
    p.add_argument("--detector", choices=METHODS, default="cog",
                   help="stripe detector of the positions and image figures (default cog)")
    p.add_argument("--json", action="store_true", help="print the result as one JSON object")
    p.add_argument("--report", metavar="DIR",
                   help="write pictures to DIR: frame_NNNN.png for the first, middle and last pair (NNNN the real "
                        "frame; real | twin | difference per region, cropped around the stripe), profiles.png "
                        "(across the stripe), positions.png (histograms of twin − real)")
    p.add_argument("--quiet", action="store_true", help="no progress display")
    add_allow_incomplete_option(p)
    add_force_option(p)
    p.set_defaults(func=_run)
    return p


def _regions(args, real, twin_regions, calibration, quiet: bool) -> tuple[dict, str]:
    """The regions and where they came from: --regions, twin.json, or found in the real frames."""
    from scheimpflug.compare.pairing import parse_regions

    if args.regions:
        return parse_regions(args.regions), "--regions"
    if twin_regions:
        return twin_regions, "twin.json"
    try:
        from scheimpflug.still_points import still_regions
    except ImportError:
        raise ScheimpflugError("no regions: give --regions NAME=LO:HI,... (this version cannot find them in "
                               "the frames)") from None
    from scheimpflug.app.progress import Progress
    from scheimpflug.reconstruct import extract_folder_stripes

    with Progress(0, label="compare regions", quiet=quiet) as bar:
        stripes = extract_folder_stripes(real, "cog", keep_saturated=True, progress=bar)
    found = still_regions(stripes, calibration)
    if not found:
        raise ScheimpflugError(f"no stripe found in {str(real.path)!r} to tell its regions: give --regions")
    return {k: tuple(float(x) for x in v) for k, v in found.items()}, "still_regions"


def _calibration(args, real):
    from scheimpflug.calibration import applicability_problem, load_calibration
    from scheimpflug.calibration.direction import stripe_direction_problem
    from scheimpflug.errors import CalibrationError

    cal = load_calibration(args.calibration)
    problem = applicability_problem(cal, real) or stripe_direction_problem(cal, real.columns, real.rows,
                                                                          real.stripe_along)
    if problem:
        raise CalibrationError(f"the calibration cannot be applied to {str(real.path)!r}: {problem}")
    return cal


def _report_paths(args) -> None:
    if not args.report:
        return
    d = Path(args.report)
    if d.exists() and not d.is_dir():
        raise ScheimpflugError(f"--report {args.report!r} is a file: give a folder")
    for name in ("profiles.png", "positions.png"):
        check_output(d / name, "--report", force=args.force, folders=[args.real, args.twin])


def _run(args: argparse.Namespace) -> int:
    from scheimpflug.compare.summary import twin_frames_and_regions

    t0 = time.perf_counter()
    quiet = args.quiet or False
    _report_paths(args)
    real = open_frames(args.real, args)
    twin_path, twin_regions = twin_frames_and_regions(args.twin)
    with tempfile.TemporaryDirectory(prefix="scheimpflug-compare-") as tmp:
        twin = _as_imported(Path(twin_path), real, Path(tmp) / "twin", args)
        return _compare(args, real, twin, twin_regions, t0, quiet)


def _as_imported(twin_path: Path, real, out: Path, args):
    """The twin's frame folder, its frames imported as the real ones were when its camera wrote colour files.

    A twin rendered with a camera chain writes RGB JPEG or PNG files, as the real camera; the
    real frames went through ``scheimpflug import`` (one channel, the stripe's direction): the
    twin's go through the same import here (:func:`scheimpflug.io.twin_frames.grey_twin_frames`:
    the real folder's ``channel``, its ``stripe_along`` as known — not detected, never refused —
    and the twin's angles), so both are read by one path.  Grey frame folders are used as they are.
    """
    from scheimpflug.app.progress import Progress
    from scheimpflug.io.twin_frames import colour_frame_entries, grey_twin_frames

    if colour_frame_entries(twin_path) is None:
        return open_frames(twin_path, args)
    manifest = json.loads((Path(real.path) / "manifest.json").read_text("utf-8"))
    with Progress(0, label="compare: import the twin's frames", quiet=args.quiet or False) as bar:
        folder = grey_twin_frames(twin_path, out, channel=manifest.get("channel"), stripe_along=real.stripe_along,
                                  progress=bar)
    return open_frames(folder, args)


def _compare(args, real, twin, twin_regions, t0: float, quiet: bool) -> int:
    from scheimpflug.app.progress import Progress
    from scheimpflug.compare.pairing import pair_by_angle, select_frames
    from scheimpflug.compare.summary import compare_folders

    calibration = _calibration(args, real) if args.calibration else None
    pairs = pair_by_angle(real, twin, select_frames(args.frames, len(real)))
    if pairs.unmatched_real:
        shown = ", ".join(str(i) for i in pairs.unmatched_real[:8]) + (" …" if len(pairs.unmatched_real) > 8 else "")
        warnings.warn(f"{len(pairs.unmatched_real)} selected real frame(s) have no twin frame at their angle and "
                      f"are not compared: {shown}", stacklevel=1)
    regions, source = _regions(args, real, twin_regions, calibration, quiet)
    with Progress(0, label="compare frames", quiet=quiet) as bar:
        comp = compare_folders(real, twin, regions, pairs, detector=args.detector, progress=bar,
                               wall_detectors=METHODS if calibration is not None else ())
    result = comp.result
    result.update({"pairs": [[int(r), int(t), float(a)] for r, t, a in zip(pairs.real, pairs.twin,
                                                                              pairs.angles_deg)],
                   "unmatched_real": [int(i) for i in pairs.unmatched_real], "regions_source": source,
                   "regions_px": {k: [float(v[0]), float(v[1])] for k, v in regions.items()},
                   "real": str(real.path), "twin": str(twin.path)})
    result.update(_detectors(pairs, comp, calibration))
    if args.report:
        result["report"] = _write_report(args.report, real, twin, pairs, comp, args.force)
    result["seconds"] = time.perf_counter() - t0
    if args.json:
        print_json(result)
    else:
        print(_table(result))
    return 0


def _detectors(pairs, comp, calibration) -> dict:
    """The detectors' block from the walls' points the frame pass collected (every detector, each frame read once)."""
    from scheimpflug.compare.detectors import BOOTSTRAP_DRAWS, BOOTSTRAP_SEED, WALLS, detector_figures

    walls = [w for w in WALLS if w in comp.real.lines]
    if calibration is None:
        return {"detectors": {}, "detectors_note": "skipped: no --calibration (the walls' figures are in the "
                                                    "sheet's millimetres)"}
    if not walls:
        return {"detectors": {}, "detectors_note": "skipped: no wall region (wall_left, wall_right)"}
    n = len(pairs)
    return {"detectors": detector_figures(comp.real.wall_points, comp.twin.wall_points, calibration, n),
            "detectors_note": f"walls {', '.join(walls)}; twin_lo90/hi90: percentile bootstrap over the twin's "
                              f"{n} frames ({BOOTSTRAP_DRAWS} draws, seed {BOOTSTRAP_SEED})"}


def _write_report(folder, real, twin, pairs, comp, force: bool) -> dict:
    from scheimpflug.app.compare_plot import plot_frame_pair, plot_position_histograms, plot_profiles
    from scheimpflug.compare.summary import position_differences
    from scheimpflug.stripe import oriented

    d = Path(folder)
    d.mkdir(parents=True, exist_ok=True)
    n = len(pairs)
    chosen = sorted({0, n // 2, n - 1})[:REPORT_PAIRS]
    written = []
    for j in chosen:
        path = d / f"frame_{int(pairs.real[j]):04d}.png"
        check_output(path, "--report", force=force)
        r_raw, t_raw = real.read(int(pairs.real[j])), twin.read(int(pairs.twin[j]))
        plot_frame_pair(oriented(r_raw, real.stripe_along), oriented(t_raw, twin.stripe_along), comp.real.lines,
                        {k: v[j] for k, v in comp.real.positions.items()},
                        {k: v[j] for k, v in comp.twin.positions.items()},
                        f"angle {pairs.angles_deg[j]:g}°: real frame {pairs.real[j]}, twin frame {pairs.twin[j]}",
                        path, saturation_dn=real.saturation_dn(r_raw))
        written.append(str(path))
    fwhm = {k: v["fwhm_px"]["real"] for k, v in comp.result["regions"].items()}
    plot_profiles(comp.real.profiles, comp.twin.profiles, fwhm, d / "profiles.png")
    plot_position_histograms(position_differences(comp.real, comp.twin), d / "positions.png")
    written += [str(d / "profiles.png"), str(d / "positions.png")]
    return {"folder": str(d), "files": written}


_ROWS = (("fwhm_px", "FWHM [px]", "{:.2f}"), ("peak_dn", "peak [DN]", "{:.1f}"),
         ("saturated_fraction", "saturated", "{:.3f}"), ("halo_fraction", "halo", "{:.3f}"),
         ("background_dn", "background [DN]", "{:.2f}"), ("noise_dn", "noise [DN]", "{:.2f}"),
         ("speckle_contrast", "speckle", "{:.3f}"), ("detection_rate", "detection", "{:.3f}"),
         ("moat_dn", "moat [DN]", "{:.2f}"))


def _cell(fmt: str, x) -> str:
    return "—" if x is None or x != x else fmt.format(x)


def _table(res: dict) -> str:
    regions = res["regions"]
    names = list(regions)
    w = 21
    out = [f"{res['frames']} frame pairs compared (detector {res['detector']}; regions from {res['regions_source']})",
           f"{'':18s}" + "".join(f"{n:>{w}s}" for n in names),
           f"{'':18s}" + "".join(f"{'real':>10s} {'twin':>10s}" for _ in names)]
    pos = [regions[n]["position_px"] for n in names]
    out.append(f"{'position rms [px]':18s}" + "".join(f"{_cell('{:.3f}', p['rms']):>{w}s}" for p in pos))
    out.append(f"{'position mean [px]':18s}" + "".join(f"{_cell('{:+.3f}', p['mean']):>{w}s}" for p in pos))
    for key, label, fmt in _ROWS:
        out.append(f"{label:18s}" + "".join(f"{_cell(fmt, regions[n][key]['real']):>10s} "
                                            f"{_cell(fmt, regions[n][key]['twin']):>10s}" for n in names))
    if res["detectors"]:
        out.append("walls per detector [mm]: straightness real / twin (twin 90 %), stillness real / twin (twin 90 %)")
        for det, v in res["detectors"].items():
            s, t = v["straightness_mm"], v["stillness_mm"]
            out.append(f"  {det:12s} {_cell('{:.3f}', s['real'])} / {_cell('{:.3f}', s['twin'])} "
                       f"({_cell('{:.3f}', s['twin_lo90'])}–{_cell('{:.3f}', s['twin_hi90'])})   "
                       f"{_cell('{:.3f}', t['real'])} / {_cell('{:.3f}', t['twin'])} "
                       f"({_cell('{:.3f}', t['twin_lo90'])}–{_cell('{:.3f}', t['twin_hi90'])})")
    else:
        out.append(f"detectors: {res['detectors_note']}")
    if "report" in res:
        out.append(f"pictures: {res['report']['folder']}")
    out.append(f"{res['seconds']:.1f} s")
    return "\n".join(out)
