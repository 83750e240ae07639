"""`scheimpflug import FRAMES… --out DIR`: real PNG/TIFF/JPEG frames + positions, angles or poses → a frame folder."""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

from scheimpflug.app.commands._common import print_json

__all__ = ["add_parser"]

_SUFFIXES = (".png", ".tif", ".tiff", ".jpg", ".jpeg")


def add_parser(sub):
    p = sub.add_parser("import", help="build a frame folder from real PNG/TIFF/JPEG frames",
                       description="Copy PNG, TIFF or JPEG frames (8, 12 or 16 bit; grey, or colour with "
                                   "--channel) into a frame folder (manifest.json + frames/) with their stage "
                                   "positions or rotary angles (a CSV, the file names, or --angles-deg), or as "
                                   "a pattern set (--scenario target); laser-off backgrounds are subtracted. "
                                   "A rig file is optional.")
    p.add_argument("frames", nargs="+", metavar="FRAMES",
                   help="frame files, or folders (their .png/.tif/.tiff/.jpg files, sorted by name)")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--positions", metavar="CSV",
                     help="CSV with a header: file, and stage_mm or angle_deg (--scenario target: file, pose, "
                          "light and, for table poses, angle_deg)")
    src.add_argument("--positions-from-names", metavar="PATTERN",
                     help="file-name pattern with {stage_mm} or {angle_deg} and * wildcards, "
                          "e.g. 'plate_{stage_mm}.tif' ('p' may stand for the decimal point)")
    src.add_argument("--angles-deg", metavar="START:STEP|LIST",
                     help="rotary angles of the frames in the given order: START:STEP (frame k at START + "
                          "k·STEP) or a comma-separated list [deg]")
    p.add_argument("--channel", metavar="r|g|b|gray|WR,WG,WB",
                   help="how a colour frame becomes one grey frame: a channel (a red laser: r), gray "
                        "(luminance) or weights of red, green, blue (required for colour files)")
    bg = p.add_mutually_exclusive_group()
    bg.add_argument("--background", nargs="+", metavar="FILES",
                    help="laser-off frames of the same views, one per frame in the frames' order "
                         "(subtracted on import)")
    bg.add_argument("--background-names", metavar="OLD=NEW",
                    help="each frame's laser-off frame is the file whose name has OLD replaced by NEW, e.g. "
                         "'laser=laser-background'")
    p.add_argument("--stripe-along", choices=("columns", "rows"), default="columns",
                   help="which way the laser stripe runs in the frames: columns (down the image: one point "
                        "per row, default) or rows (across it: one point per column); the pipeline follows it")
    p.add_argument("--out", required=True, metavar="DIR", help="frame folder to create (new or empty)")
    p.add_argument("--rig", metavar="RIG.toml", help="rig file to record in the manifest (optional)")
    p.add_argument("--adc-bits", type=int, default=None,
                   help="ADC depth, e.g. 12 for a 12-bit camera's 16-bit files (default: the files' depth)")
    p.add_argument("--msb-aligned", action="store_true",
                   help="the files hold --adc-bits codes shifted to the top of the word (e.g. 12-bit "
                        "values × 16 in 16-bit files): shift them back on import")
    p.add_argument("--scenario", choices=("calibration", "blocker", "rotary", "target"), default=None,
                   help="what the frames show (default calibration for stage positions, rotary for angles); "
                        "target: a printed pattern's poses (each frame a flood-lit pose, or as --positions says)")
    p.add_argument("--plate-height-mm", type=float, default=None,
                   help="calibration plate height [mm], recorded for 'calibrate'")
    p.add_argument("--json", action="store_true", help="print a JSON summary")
    p.set_defaults(func=_run)
    return p


def _expand(items) -> list[Path]:
    out = []
    for item in map(Path, items):
        if item.is_dir():
            out += sorted(f for f in item.iterdir() if f.suffix.lower() in _SUFFIXES)
        else:
            out.append(item)
    return out


def _frames(args, files):
    from scheimpflug.errors import FrameError
    from scheimpflug.io.importer import (
        frames_with_angles,
        parse_angles,
        positions_from_csv,
        positions_from_names,
        target_frames,
    )

    if args.scenario == "target":
        if args.positions_from_names or args.angles_deg:
            raise FrameError("--scenario target takes its poses from --positions CSV (file, pose, light) or makes "
                             "each frame a pose: not --positions-from-names or --angles-deg")
        return target_frames(files, args.positions)
    if args.angles_deg:
        return frames_with_angles(files, parse_angles(args.angles_deg, len(files)))
    if args.positions:
        return positions_from_csv(files, args.positions)
    if args.positions_from_names:
        return positions_from_names(files, args.positions_from_names)
    raise FrameError("the frames need positions: --positions CSV, --positions-from-names PATTERN or --angles-deg "
                     "(or --scenario target for a pattern set)")


def _backgrounds(args, files):
    if args.background:
        return _expand(args.background)
    if not args.background_names:
        return None
    from scheimpflug.errors import FrameError

    old, sep, new = args.background_names.partition("=")
    if not sep or not old:
        raise FrameError(f"--background-names {args.background_names!r}: OLD=NEW")
    out = []
    for f in files:
        if old not in f.name:
            raise FrameError(f"--background-names: {f.name!r} does not contain {old!r}")
        out.append(f.with_name(f.name.replace(old, new, 1)))
    return out


def _run(args) -> int:
    from scheimpflug.errors import FrameError
    from scheimpflug.io.importer import import_frames
    from scheimpflug.model.rig import load_rig, rig_to_dict

    files = _expand(args.frames)
    if not files:
        raise FrameError(f"no .png/.tif/.tiff/.jpg frames in {' '.join(args.frames)}")
    rig = rig_to_dict(load_rig(args.rig)) if args.rig else None
    params = {"plate_height_mm": args.plate_height_mm} if args.plate_height_mm is not None else None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        frames = _frames(args, files)
        out = import_frames(frames, args.out, rig=rig, adc_bits=args.adc_bits, scenario=args.scenario,
                            scenario_params=params, msb_aligned=args.msb_aligned, channel=args.channel,
                            backgrounds=_backgrounds(args, files), stripe_along=args.stripe_along)
    for w in caught:
        print(f"warning: {w.message}", file=sys.stderr)
    summary = {"out": str(out), "frames": len(frames), "key": frames[0].key,
               "range": [min(f.value for f in frames), max(f.value for f in frames)]}
    print(f"import: {len(frames)} frames ({frames[0].key} {summary['range'][0]:g} … {summary['range'][1]:g}) "
          f"→ {out}", file=sys.stderr)
    if args.json:
        print_json(summary)
    return 0
