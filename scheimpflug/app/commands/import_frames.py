"""`scheimpflug import FRAMES… --out DIR`: real PNG/TIFF frames + positions → a frame folder."""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

from scheimpflug.app.commands._common import print_json

__all__ = ["add_parser"]

_SUFFIXES = (".png", ".tif", ".tiff")


def add_parser(sub):
    p = sub.add_parser("import", help="build a frame folder from real PNG/TIFF frames and stage positions",
                       description="Copy PNG or TIFF frames (8, 12 or 16 bit) into a frame folder "
                                   "(manifest.json + frames/) with their stage positions or rotary "
                                   "angles, from a CSV or from the file names. A rig file is optional.")
    p.add_argument("frames", nargs="+", metavar="FRAMES",
                   help="frame files, or folders (their .png/.tif/.tiff files, sorted by name)")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--positions", metavar="CSV",
                     help="CSV with a header: file, and stage_mm or angle_deg")
    src.add_argument("--positions-from-names", metavar="PATTERN",
                     help="file-name pattern with {stage_mm} or {angle_deg} and * wildcards, "
                          "e.g. 'plate_{stage_mm}.tif' ('p' may stand for the decimal point)")
    p.add_argument("--out", required=True, metavar="DIR", help="frame folder to create (new or empty)")
    p.add_argument("--rig", metavar="RIG.toml", help="rig file to record in the manifest (optional)")
    p.add_argument("--adc-bits", type=int, default=None,
                   help="ADC depth, e.g. 12 for a 12-bit camera's 16-bit files (default: the files' depth)")
    p.add_argument("--msb-aligned", action="store_true",
                   help="the files hold --adc-bits codes shifted to the top of the word (e.g. 12-bit "
                        "values × 16 in 16-bit files): shift them back on import")
    p.add_argument("--scenario", choices=("calibration", "blocker", "rotary"), default=None,
                   help="what the frames show (default calibration for stage positions, rotary for angles)")
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


def _run(args) -> int:
    from scheimpflug.errors import FrameError
    from scheimpflug.io.importer import import_frames, positions_from_csv, positions_from_names
    from scheimpflug.model.rig import load_rig, rig_to_dict

    files = _expand(args.frames)
    if not files:
        raise FrameError(f"no .png/.tif/.tiff frames in {' '.join(args.frames)}")
    rig = rig_to_dict(load_rig(args.rig)) if args.rig else None
    params = {"plate_height_mm": args.plate_height_mm} if args.plate_height_mm is not None else None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        frames = (positions_from_csv(files, args.positions) if args.positions
                  else positions_from_names(files, args.positions_from_names))
        out = import_frames(frames, args.out, rig=rig, adc_bits=args.adc_bits, scenario=args.scenario,
                            scenario_params=params, msb_aligned=args.msb_aligned)
    for w in caught:
        print(f"warning: {w.message}", file=sys.stderr)
    summary = {"out": str(out), "frames": len(frames), "key": frames[0].key,
               "range": [min(f.value for f in frames), max(f.value for f in frames)]}
    print(f"import: {len(frames)} frames ({frames[0].key} {summary['range'][0]:g} … {summary['range'][1]:g}) "
          f"→ {out}", file=sys.stderr)
    if args.json:
        print_json(summary)
    return 0
