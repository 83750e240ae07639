"""`scheimpflug import FRAMES… --out DIR`: real PNG/TIFF/JPEG frames + positions, angles or poses → a frame folder.

The work is :func:`scheimpflug.io.importer.import_frames`; this command expands folders (natural
order: ``frame2`` before ``frame10``), warns when files listed one by one come in the order a shell
glob gives (``frame10`` before ``frame2``) and that order sets their angles or poses, shows a progress
bar once an import has run for a second (``--quiet``: none), and prints what was imported: the
order used (first and last names with their position), the stripe's direction and how it was found,
a pattern set's poses and lights.
"""

from __future__ import annotations

import json
import sys
import time
import warnings
from pathlib import Path

from scheimpflug.app.commands._common import number, print_json

__all__ = ["add_parser"]

_SUFFIXES = (".png", ".tif", ".tiff", ".jpg", ".jpeg")
_BAR_DELAY_S = 1.0          # an import shorter than this shows no bar
_SHOWN = 3                  # names shown at each end of the order


def add_parser(sub):
    p = sub.add_parser("import", help="build a frame folder from real PNG/TIFF/JPEG frames",
                       description="Copy PNG, TIFF or JPEG frames (8, 12 or 16 bit; grey, or colour with "
                                   "--channel) into a frame folder (manifest.json + frames/) with their stage "
                                   "positions or rotary angles (a CSV, the file names, or --angles-deg), or as "
                                   "a pattern set (--scenario target); laser-off backgrounds are subtracted. "
                                   "Truncated, multi-page and mixed colour/grey files are refused; the stripe's "
                                   "direction is found in the frames (or given, and checked; or known: "
                                   "--stripe-known). A rig file is optional.")
    p.add_argument("frames", nargs="+", metavar="FRAMES",
                   help="frame files, or folders (their .png/.tif/.tiff/.jpg files in natural order: frame2 "
                        "before frame10)")
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
    p.add_argument("--stripe-along", choices=("auto", "columns", "rows"), default="auto",
                   help="which way the laser stripe runs in the frames: columns (down the image: one point "
                        "per row) or rows (across it: one point per column); auto (default) finds it in the "
                        "frames that show the laser, and a direction the frames contradict is refused")
    p.add_argument("--stripe-known", action="store_true",
                   help="with --stripe-along columns|rows: the direction is known (e.g. a twin's frames of the "
                        "real camera): not looked for in the frames, never refused or warned of")
    p.add_argument("--exif-orientation", choices=("stored", "apply"), default="stored",
                   help="frames whose EXIF orientation tag asks viewers to turn them: imported as stored "
                        "(default, with a warning; a calibration of the stored frames needs them so) or turned "
                        "as viewers turn them (apply)")
    p.add_argument("--room-light", action="store_true",
                   help="a pattern set (--scenario target) taken in room light: each pose's laser frame and "
                        "its laser-off (flood) frame are a pair (recorded in the manifest)")
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
    p.add_argument("--plate-height-mm", type=number(0, 1e4, lo_open=True, unit="mm"), default=None,
                   help="calibration plate height [mm], recorded for 'calibrate'")
    p.add_argument("--quiet", action="store_true", help="no progress display")
    p.add_argument("--json", action="store_true", help="print a JSON summary")
    p.set_defaults(func=_run)
    return p


def _expand(items) -> list[Path]:
    """Files as given; a folder's frame files in natural order."""
    from scheimpflug.io.importer import natural_key

    out = []
    for item in map(Path, items):
        if item.is_dir():
            out += sorted((f for f in item.iterdir() if f.suffix.lower() in _SUFFIXES), key=natural_key)
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


def _warn_text_order(args, files) -> None:
    """Files in a shell glob's text order (frame10 before frame2) where their order sets angles or poses."""
    from scheimpflug.io.importer import natural_key

    by_order = args.angles_deg or (args.scenario == "target" and not args.positions)
    natural = sorted(files, key=natural_key)
    if not by_order or files == natural or files != sorted(files, key=lambda f: f.name):
        return
    k = next(i for i, (a, b) in enumerate(zip(files, natural)) if a != b)
    warnings.warn(f"the frames are taken in the order given, which sorts their names as text ({files[k].name!r} "
                  f"before {natural[k].name!r}, as a shell's * does): their {'angles' if args.angles_deg else 'poses'} "
                  "follow that order; list them in natural order, or give their folder (sorted naturally)",
                  stacklevel=2)


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


class _LateBar:
    """A progress callback whose bar is drawn only once the import has run for ``_BAR_DELAY_S``."""

    def __init__(self, quiet: bool) -> None:
        from scheimpflug.app.progress import Progress

        self.quiet, self.bar = quiet, Progress(0, label="import", quiet=True)

    def __call__(self, done: int, total: int) -> None:
        if self.bar.quiet and not self.quiet and time.perf_counter() - self.bar.t0 >= _BAR_DELAY_S:
            self.bar.quiet = False
        self.bar(done, total)

    def close(self) -> None:
        self.bar.close()


def _run(args) -> int:
    from scheimpflug.errors import FrameError
    from scheimpflug.io.importer import import_frames
    from scheimpflug.model.rig import load_rig, rig_to_dict

    files = _expand(args.frames)
    if not files:
        raise FrameError(f"no .png/.tif/.tiff/.jpg frames in {' '.join(args.frames)}")
    rig = rig_to_dict(load_rig(args.rig)) if args.rig else None
    params = {"plate_height_mm": args.plate_height_mm} if args.plate_height_mm is not None else None
    bar = _LateBar(args.quiet)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        frames = _frames(args, files)
        _warn_text_order(args, files)
        out = import_frames(frames, args.out, rig=rig, adc_bits=args.adc_bits, scenario=args.scenario,
                            scenario_params=params, msb_aligned=args.msb_aligned, channel=args.channel,
                            backgrounds=_backgrounds(args, files), stripe_along=args.stripe_along,
                            stripe_known=args.stripe_known, exif_orientation=args.exif_orientation,
                            room_light=args.room_light, progress=bar)
    bar.close()
    for w in caught:
        print(f"warning: {w.message}", file=sys.stderr)
    summary = _summary(out, frames[0].key, json.loads((out / "manifest.json").read_text("utf-8")))
    print(_summary_text(summary), file=sys.stderr)
    if args.json:
        print_json(summary)
    return 0


def _summary(out: Path, key: str, manifest: dict) -> dict:
    """What was imported, from the manifest written: counts, order, stripe, a pattern set's poses."""
    entries = manifest["frames"]
    order = [{"file": Path(e["source_file"]).name, "as": e["file"],
              **{k: e[k] for k in ("stage_mm", "angle_deg", "pose", "light") if k in e}} for e in entries]
    values = [e["pose"] if key == "pose" else e[key] for e in entries]
    summary = {"out": str(out), "frames": len(entries), "key": key, "range": [min(values), max(values)],
               "stripe_along": manifest["stripe_along"], "stripe_detection": manifest.get("stripe_detection"),
               "order": order}
    if key == "pose":
        poses: dict[int, set] = {}
        for e in entries:
            poses.setdefault(e["pose"], set()).add(e["light"])
        lights = sorted({light for s in poses.values() for light in s})
        summary.update(poses=len(poses), lights={light: sum(light in s for s in poses.values()) for light in lights},
                       room_light=bool(manifest["scenario_params"].get("room_light")))
    return summary


def _summary_text(s: dict) -> str:
    if s["key"] == "pose":
        lights = ", ".join(f"{n} {light}" for light, n in s["lights"].items())
        head = (f"import: {s['poses']} poses, {s['frames']} frames ({s['poses']} poses: {lights})"
                f"{', room light' if s['room_light'] else ''} → {s['out']}")
    else:
        head = (f"import: {s['frames']} frames ({s['key']} {s['range'][0]:g} … {s['range'][1]:g}) → {s['out']}")
    return "\n".join((head, "  order: " + _order_text(s["order"], s["key"]), "  stripe: " + _stripe_text(s)))


def _order_text(order: list[dict], key: str) -> str:
    def one(o):
        return f"{o['file']} (pose {o['pose']} {o['light']})" if key == "pose" else f"{o['file']} ({o[key]:g})"

    if len(order) <= 2 * _SHOWN:
        return ", ".join(map(one, order))
    return ", ".join(map(one, order[:_SHOWN])) + ", …, " + ", ".join(map(one, order[-_SHOWN:]))


def _stripe_text(s: dict) -> str:
    along, d = s["stripe_along"], s["stripe_detection"] or {}
    way = {"columns": "down the image, one point per row", "rows": "across the image, one point per column"}
    head = f"stripe_along {along} ({way[along]})"
    if d.get("known"):
        return head + ", known (not looked for in the frames)"
    if not d.get("examined"):
        return head + ", as given" if d.get("given") not in (None, "auto") else head + ": no laser frames to examine"
    seen = f"{d.get(along, 0)} of the {d['examined']} frame(s) that show the laser"
    if d.get("given") == "auto":
        return head + (f", found in {seen}" if d.get("found") else f": assumed, no stripe found in {d['examined']} "
                                                                   "frame(s)")
    return head + f", as given; the frames agree in {seen}"
