"""``scheimpflug rig``: rig files of instruments given by their calibration."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from scheimpflug.app.commands._common import add_force_option, check_output
from scheimpflug.calibration.instrument import instrument_from_calibration
from scheimpflug.errors import ScheimpflugError
from scheimpflug.io.atomic import write_text_atomic
from scheimpflug.model.chain import CAMERA_PRESETS as CHAIN_PRESETS
from scheimpflug.model.chain import expand_chain_table
from scheimpflug.model.housing import housing_to_toml
from scheimpflug.model.instrument import CAMERA_PRESETS, rig_file_text, rig_from_instrument
from scheimpflug.model.instrument_file import rig_parts_text

__all__ = ["add_parser"]


def add_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "rig",
        help="rig files of instruments given by their calibration (rig from-calibration)",
        description="Build the twin's rig of a camera-and-sheet instrument from its calibration: the camera "
                    "(K, distortion, frame size) as an ordinary camera, the laser plane as the sheet, the "
                    "turntable as the rotary stage (docs/reference/interface.md).",
    )
    rsub = p.add_subparsers(dest="rig_command", metavar="ACTION", required=True)
    fc = rsub.add_parser(
        "from-calibration",
        help="rig file from a calibration (target, OpenCV export, FabScanPi config.json)",
        description="Write the rig of the instrument a calibration describes: this project's target "
                    "calibration, an OpenCV calibration (JSON/YAML with camera_matrix, dist_coeffs, "
                    "laser_plane, image_size) or FabScanPi's config.json (its frames as stored, its "
                    "distortion applied).  Keys no calibration gives are written with defaults and "
                    "marked unknown.",
    )
    fc.add_argument("calibration", metavar="FILE", help="the calibration file")
    fc.add_argument("--out", metavar="RIG.toml", required=True, help="the rig file to write")
    fc.add_argument("--preset", metavar="NAME",
                    help=f"named camera giving the pixel pitch and f-number, its frame size the calibration's "
                         f"({', '.join(sorted(CAMERA_PRESETS))})")
    fc.add_argument("--no-turntable", action="store_true",
                    help="leave the calibration's rotary axis out (the stage keys are then placed by rule)")
    fc.add_argument("--fabscan-distortion", choices=("apply", "as-fabscan"), default="as-fabscan",
                    help="FabScanPi config.json: FabScan's own model of its frames, the camera matrix alone, "
                         "as reconstruct --calibration reads the file (as-fabscan, default), or its calibrated "
                         "distortion as the lens (apply; its k3 folds back inside the frame)")
    fc.add_argument("--form", choices=("scheimpflug", "parts"), default="scheimpflug",
                    help="the rig file's form: the Scheimpflug keys every tool and spec addresses (scheimpflug, "
                         "default) or the instrument by its parts, [camera], [laser] plane, [turntable] "
                         "(parts); both load as the same rig")
    fc.add_argument("--chain", metavar="CAMERA", choices=CHAIN_PRESETS[1:],
                    help="the [chain] table of a named camera (its colour mosaic, tone curve, 8 bits, JPEG, "
                         f"glare: {', '.join(CHAIN_PRESETS[1:])}), written out key by key for editing; "
                         "default: none (16-bit grey frames)")
    add_force_option(fc)
    fc.set_defaults(func=run_from_calibration)
    hs = rsub.add_parser(
        "housing",
        help="housing file of a scanner's still walls, found in its frames (rig housing)",
        description="Find still flat walls in a frame folder (a turntable scanner's back walls: one column "
                    "range of the frames per wall), map their stripe points through the calibration to "
                    "3-D lines and write them as boards of a housing file (instrument frame: the "
                    "calibration's camera frame) for render rotary --housing.  With --table, fit the "
                    "turntable's top from its line (its height along the axis, the lean of its mean "
                    "plane, the tilt that makes it wobble: scheimpflug.turntable_top) and write its "
                    "[stage] keys into the rig file --rig (built from the same calibration).",
    )
    hs.add_argument("folder", metavar="FOLDER", help="frame folder of a scan (scheimpflug import)")
    hs.add_argument("--calibration", metavar="FILE", required=True,
                    help="the calibration whose camera frame the boards are given in")
    hs.add_argument("--walls", metavar="C0:C1[,C0:C1 ...]",
                    help="image column ranges [px], one per wall, where its stripe shows in every frame "
                         "(written to --out)")
    hs.add_argument("--table", metavar="C0:C1",
                    help="image column range [px] where the turntable's top shows its line: fit the top and "
                         "write table_top_offset_mm, table_tilt_deg, table_tilt_azimuth_deg, "
                         "table_axis_tilt_deg, table_axis_tilt_azimuth_deg into --rig's [stage]")
    hs.add_argument("--rig", metavar="RIG.toml",
                    help="with --table: the rig file (rig from-calibration of the same calibration) whose "
                         "table frame the fit uses and whose [stage] it updates in place")
    hs.add_argument("--fabscan-distortion", choices=("apply", "as-fabscan"), default="as-fabscan",
                    help="FabScanPi config.json: as in rig from-calibration (use the rig's choice)")
    hs.add_argument("--out", metavar="HOUSING.toml", help="with --walls: the housing file to write")
    add_force_option(hs)
    hs.set_defaults(func=run_housing)
    return p


def run_from_calibration(args: argparse.Namespace) -> int:
    check_output(args.out, "--out", force=args.force, inputs=[args.calibration])
    inst = instrument_from_calibration(args.calibration, args.preset, turntable=not args.no_turntable,
                                       fabscan_distortion=args.fabscan_distortion)
    rig = rig_from_instrument(inst)
    if args.chain:                                   # a named camera's [chain], every key written out
        rig = rig.replace(chain=dict(expand_chain_table({"preset": args.chain})))
    text = (rig_parts_text(rig, inst, args.calibration) if args.form == "parts"
            else rig_file_text(rig, inst, args.calibration))
    write_text_atomic(args.out, text)
    print(f"wrote {args.out} (unknown: {', '.join(inst.unknown)})", file=sys.stderr)
    if args.fabscan_distortion == "apply" and _is_fabscan_file(args.calibration):
        print("note: the rig's lens has FabScan's calibrated distortion; reconstruct --calibration "
              f"{args.calibration} reads it as FabScan does (the camera matrix alone), so the twin's frames "
              "reconstruct through it with that difference (--fabscan-distortion as-fabscan: FabScan's own "
              "model)", file=sys.stderr)
    return 0


def _is_fabscan_file(path: str) -> bool:
    from scheimpflug.calibration.fabscan import is_fabscan_config

    try:
        return is_fabscan_config(json.loads(Path(path).read_text("utf-8")))
    except (OSError, UnicodeDecodeError, ValueError):
        return False


def _ranges(text: str, option: str = "--walls") -> list[tuple[float, float]]:
    out = []
    for item in text.split(","):
        try:
            a, b = (float(x) for x in item.split(":"))
        except ValueError:
            raise ScheimpflugError(f"{option} {text!r}: expected column ranges C0:C1[,C0:C1 ...]") from None
        if not a < b:
            raise ScheimpflugError(f"{option} {item!r}: the range's first column must be below its last")
        out.append((a, b))
    return out


def run_housing(args: argparse.Namespace) -> int:
    from scheimpflug.calibration.instrument import calibration_sheet_model
    from scheimpflug.fixed_lines import walls_of_folder
    from scheimpflug.io.frames import open_frame_folder
    from scheimpflug.reconstruct import extract_folder_stripes

    if not args.walls and not args.table:
        raise ScheimpflugError("rig housing: give --walls (with --out), --table (with --rig), or both")
    if args.walls and not args.out:
        raise ScheimpflugError("--walls needs --out HOUSING.toml (the housing file to write)")
    if args.out and not args.walls:
        raise ScheimpflugError("--out is the housing file of --walls: give --walls too "
                               "(the table's keys go into --rig)")
    if args.table and not args.rig:
        raise ScheimpflugError("--table needs --rig RIG.toml (the rig whose [stage] gets the table's keys)")
    if args.out:
        check_output(args.out, "--out", force=args.force, inputs=[args.calibration])
    ranges = _ranges(args.walls) if args.walls else []
    table = _ranges(args.table, "--table") if args.table else []
    if len(table) > 1:
        raise ScheimpflugError(f"--table {args.table!r}: one column range")
    cal = calibration_sheet_model(args.calibration, args.fabscan_distortion)
    folder = open_frame_folder(args.folder)
    stripes = extract_folder_stripes(folder, "cog", keep_saturated=True)      # once, for the walls and the table
    rig_text = _table_keys_text(folder, stripes, cal, table[0], args) if table else None
    if ranges:
        boards, figures = walls_of_folder(folder, cal, ranges, stripes=stripes)
        comment = (f"Housing found in {args.folder} through {args.calibration} (scheimpflug rig housing).\n"
                   "Instrument frame: the calibration's camera frame [mm].\n" +
                   "\n".join(f"{b.name}: columns {f['columns_px']}, {f['points']} points of {f['frames']} frames, "
                             f"straightness {f['rms_mm']:.3f} mm" for b, f in zip(boards, figures)))
        write_text_atomic(args.out, housing_to_toml(boards, comment))
        print(f"wrote {args.out} ({len(boards)} boards)", file=sys.stderr)
    if rig_text is not None:
        write_text_atomic(args.rig, rig_text)
        print(f"wrote the table's keys into {args.rig} [stage]", file=sys.stderr)
    return 0


def _table_keys_text(folder, stripes, cal, columns, args) -> str:
    """The rig file's text with the fitted table keys in ``[stage]`` (checked: it loads)."""
    import tomllib

    from scheimpflug.errors import RigError
    from scheimpflug.model.rigfile import load_rig, rig_from_dict, with_stage_keys
    from scheimpflug.turntable_top import table_top_of_folder
    from sim.backgrounds import camera_from_table

    rig = load_rig(args.rig)
    if rig.stage.axis_tilt_deg < 90.0 and not rig.stage.table_radius_mm > 0:
        print(f"note: {args.rig} has no table disc ([stage] table_radius_mm = 0): the keys do nothing until it has "
              "one", file=sys.stderr)
    try:
        top = table_top_of_folder(folder, cal, columns, camera_from_table(rig), stripes=stripes)
    except ValueError as exc:
        raise ScheimpflugError(f"--table {args.table}: {exc}") from None
    print(f"table top from {top.n_points} points of {top.n_frames} frames: offset {top.offset_mm:+.4f} ± "
          f"{top.offset_se_mm:.4f} mm along the axis, lean {top.lean_deg:.4f} ± {top.lean_se_deg:.4f}° toward "
          f"{top.lean_azimuth_deg:.2f}°, tilt {top.tilt_deg:.4f} ± {top.tilt_se_deg:.4f}° toward "
          f"{top.azimuth_deg:.2f} ± {top.azimuth_se_deg:.2f}°; residual {top.rms_px:.3f} px RMS along the column "
          "(standard errors: points taken as independent, a lower bound)", file=sys.stderr)
    text = with_stage_keys(Path(args.rig).read_text("utf-8"), top.rig_keys(),
                           f"table keys fitted by scheimpflug rig housing {args.folder} --table {args.table}")
    data = tomllib.loads(text)
    if isinstance(data.get("housing"), str):
        data.pop("housing")                  # its boards are not what is checked here
    try:
        rig_from_dict(data)
    except RigError as exc:
        raise ScheimpflugError(f"--table: the fitted keys do not make a valid rig: {exc}") from None
    return text
