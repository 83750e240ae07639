"""``scheimpflug design``: what a rig sees and how finely; or which rig covers a wanted range."""

from __future__ import annotations

import argparse
import math
import sys

from scheimpflug.app.commands._common import (
    add_force_option,
    add_rig_options,
    check_output,
    check_plot,
    number,
    print_json,
    rig_from_args,
)
from scheimpflug.calibration.detectability import format_square_advice, square_advice
from scheimpflug.errors import RigError
from scheimpflug.model.design import design_report, inverse_design
from scheimpflug.model.rig import Rig, rig_to_toml

__all__ = ["add_parser", "format_ordinary_report", "format_report"]

# (key, label, unit, formula / reference, format)
_ROWS = [
    ("tilt_deg", "sensor tilt β", "deg", "tan β = f/(d − f·tan φ)  [paper Eq. 5]", "{:.4f}"),
    ("tan_beta", "tan β", "-", "[paper Eq. 5]", "{:.5f}"),
    ("F2_px_mm", "F²", "px·mm", "−f²/(p·cos φ·sin β); D = F²/(u − u_h)  [Eqs. 1, 11]", "{:.6g}"),
    ("C_mm", "C", "mm", "f/sin β; h = C·(v − v_h)/(u − u_h)  [Eqs. 8, 12]", "{:.5g}"),
    ("depth_range_mm", "depth range over the sensor", "mm", "D(last col) − D(col 0)  [Eq. 11]", "{:.2f}"),
    ("distance_resolution_center_mm", "distance resolution at centre", "mm/px", "|F²|/(u − u_h)²", "{:.4f}"),
    ("height_resolution_center_mm", "height resolution at centre", "mm/px", "C/|u − u_h|", "{:.4f}"),
    ("height_range_near_mm", "height range, near end", "mm", "C·rows/|u − u_h| at the first column's edge", "{:.2f}"),
    ("height_range_far_mm", "height range, far end", "mm", "C·rows/|u − u_h| at the last column's edge", "{:.2f}"),
    ("sensor_distance_to_lens_mm", "sensor centre to lens centre", "mm", "", "{:.2f}"),
    ("axis_distance_mm", "rotary axis from the hinge", "mm", "axis_mm − d0", "{:.2f}"),
    ("axis_column_px", "rotary axis column", "px", "u_h + F²/D_axis", "{:.1f}"),
    ("stage_zero_column_px", "column of stage zero", "px", "u_h + F²/(−d0)", "{:.1f}"),
    ("focal_length_check_mm", "f recovered at stage zero", "mm", "√(−x_M'·x_M)  [Eqs. 13–14, 1]", "{:.3f}"),
]


def add_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "design",
        help="design report of a rig (tilt, hinge, ranges, resolution) or an inverse design",
        description="Print the hinge-rule design of a rig: sensor tilt, hinge, calibration constants, "
                    "depth and height ranges, resolutions (docs/explanation/design-notes.md §3, paper Eqs. 5, 11, 12), "
                    "and the printed calibration patterns it can detect at binnings 1, 2 and 4. "
                    "An ordinary camera (a [camera] table, or rig from-calibration) gets its field on the sheet, "
                    "resolutions and depth of field from the exact camera model instead. "
                    "With --near-mm/--far-mm, find instead the sheet angle or baseline, tilt and sensor "
                    "placement that cover a wanted working range with the rig's lens and sensor.",
    )
    add_rig_options(p)
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.add_argument("--plot", metavar="FILE.png",
                   help="draw the meridian-plane layout and resolution curves (a Scheimpflug rig only)")
    inv = p.add_argument_group("inverse design (distances along the sheet from the Scheimpflug line / laser)")
    length = number(0, 1e6, lo_open=True, unit="mm")
    inv.add_argument("--near-mm", type=length, help="wanted near end of the working range [mm]")
    inv.add_argument("--far-mm", type=length, help="wanted far end of the working range [mm]")
    pick = inv.add_mutually_exclusive_group()
    pick.add_argument("--tan-phi", type=number(-100, 100),
                      help="keep this sheet angle, solve the baseline d")
    pick.add_argument("--baseline-mm", type=number(0, 1e5, lo_open=True, unit="mm"),
                      help="keep this baseline d, solve the sheet angle")
    inv.add_argument("--write-rig", metavar="RIG.toml", help="write the designed rig file")
    add_force_option(p)
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    check_output(args.write_rig, "--write-rig", force=args.force, inputs=[args.rig])
    check_plot(args.plot, force=args.force, inputs=[args.rig, args.write_rig])
    rig = rig_from_args(args)
    source = args.rig or f"preset '{args.preset or 'paper'}'"
    if args.near_mm is not None or args.far_mm is not None:
        rig = _inverse(args, rig)
        source = (f"inverse design for {args.near_mm:g}–{args.far_mm:g} mm along the sheet, "
                  f"lens and sensor of {source}")
    ordinary = rig.sensor.image_distance_mm > 0
    if args.plot and ordinary:
        raise RigError("--plot draws the meridian-plane layout of a Scheimpflug rig (the hinge rule's tilted "
                       "sensor); this rig has an ordinary camera ([sensor] image_distance_mm > 0): leave --plot out")
    report = design_report(rig)
    report["pattern_advice"] = None if ordinary else square_advice(rig)
    for w in report["warnings"]:
        print(f"scheimpflug design: warning: {w}", file=sys.stderr)
    if args.plot:
        from scheimpflug.app.design_plot import plot_design

        plot_design(rig, args.plot)
        print(f"wrote {args.plot}", file=sys.stderr)
    if args.json:
        print_json(report)
    else:
        sys.stdout.write(format_report(rig, report, source))
    return 0


def _inverse(args: argparse.Namespace, rig: Rig) -> Rig:
    if args.near_mm is None or args.far_mm is None:
        raise RigError("inverse design needs both --near-mm and --far-mm")
    tan_phi, base = args.tan_phi, args.baseline_mm
    if tan_phi is None and base is None:
        tan_phi = rig.laser.tan_phi
    choice = inverse_design(rig.lens.focal_length_mm, rig.sensor.pixel_pitch_um, rig.sensor.columns,
                            args.near_mm, args.far_mm, tan_phi=tan_phi, scheimpflug_distance_mm=base)
    new = rig.replace(laser={"tan_phi": choice.tan_phi,
                             "scheimpflug_distance_mm": choice.scheimpflug_distance_mm},
                      sensor={"hinge_column": choice.hinge_column})
    if args.write_rig:
        from scheimpflug.io.atomic import write_text_atomic

        write_text_atomic(args.write_rig, rig_to_toml(new))
        print(f"wrote {args.write_rig}", file=sys.stderr)
    return new


def format_report(rig: Rig, rep: dict, source: str) -> str:
    """Human-readable design table with units and the paper's equation numbers.

    With ``rep["pattern_advice"]`` (:func:`scheimpflug.calibration.detectability.square_advice`),
    the printed patterns the rig can detect at binnings 1, 2 and 4 close the table.  An
    ordinary camera's report (``rep["sensor_kind"] == "ordinary"``) is printed by
    :func:`format_ordinary_report`.
    """
    if rep.get("sensor_kind") == "ordinary":
        return format_ordinary_report(rig, rep, source)
    L, S, s = rig.lens, rig.laser, rig.sensor
    lines = [
        f"Scheimpflug design — rig: {source}",
        f"  lens    f = {L.focal_length_mm:g} mm, f/{L.f_number:g}",
        f"  sheet   d = {S.scheimpflug_distance_mm:g} mm, tan φ = {S.tan_phi:g} "
        f"(φ = {math.degrees(math.atan(S.tan_phi)):.3f}°)",
        f"  sensor  {s.columns} × {s.rows} px (columns × rows), p = {s.pixel_pitch_um:g} µm, "
        f"hinge (u_h, v_h) = ({s.hinge_column:g}, {s.axis_row:g}) px",
        "",
        f"  {'quantity':<32s} {'value':>14s}  {'unit':<6s} formula [reference]",
        "  " + "-" * 100,
    ]
    d_near, d_far = rep["distance_range_mm"]
    lines.append(f"  {'distance range (D from hinge)':<32s} {f'{d_near:.2f} … {d_far:.2f}':>14s}  "
                 f"{'mm':<6s} F²/(u − u_h) at columns 0 and {s.columns - 1}  [Eq. 11]")
    for key, label, unit, ref, fmt in _ROWS:
        value = "–" if rep[key] is None else fmt.format(rep[key])
        lines.append(f"  {label:<32s} {value:>14s}  {unit:<6s} {ref}")
    oh, ih = rep["object_hinge_mm"], rep["image_hinge_mm"]
    lines += [
        "",
        f"  object hinge H  = ({oh[0]:.3f}, {oh[1]:.3f}, 0) mm  (front focal plane ∩ sheet)",
        f"  image hinge  H' = ({ih[0]:.3f}, {ih[1]:.3f}, 0) mm  (back focal plane ∩ sensor; O→H ∥ sensor, Eq. 6)",
        f"  stage coordinates in view: {rep['stage_range_mm'][0]:.2f} … {rep['stage_range_mm'][1]:.2f} mm "
        f"(d0 = {rig.stage.d0_mm:g} mm)",
        "  frame: origin at the lens centre, +x optical axis, +z up; D along the sheet from the object hinge",
        "",
        *_plan_lines(rig, rep),
        *(format_square_advice(rep["pattern_advice"]) + [""] if "pattern_advice" in rep else []),
    ]
    return "\n".join(lines)


def _plan_lines(rig: Rig, rep: dict) -> list[str]:
    """The stage settings, the calibration plan and the rotary plan, with the warnings."""
    derived = set(rep["derived"])
    keys = ", ".join(f"{k} = {v:g}{' (derived)' if f'stage.{k}' in derived else ''}"
                     for k, v in rep["stage"].items())
    optics = (f"  laser waist at {rig.laser.waist_distance_mm:g} mm from the origin"
              f"{' (derived)' if 'laser.waist_distance_mm' in derived else ''}; exposure "
              f"{rig.sensor.exposure_ms:g} ms{' (derived)' if 'sensor.exposure_ms' in derived else ''}")
    c, r = rep["calibration_plan"], rep["rotary_plan"]
    last = c["start_mm"] + (c["steps"] - 1) * c["step_mm"]
    lines = [f"  stage   {keys}", optics,
             "          (derived: by the rule of scheimpflug.model.plan, from the working volume)" if derived else "",
             f"  calibration plan  plate {c['plate_height_mm']:g} mm on a table at {c['table_z_mm']:g} mm; "
             f"{c['steps']} frames, s = {c['start_mm']:g} … {last:.6g} mm in steps of {c['step_mm']:g} mm; "
             f"both plate edges in view in {c['both_edges_frames']} of {c['steps']}"]
    if c["note"]:
        lines.append(f"                    {c['note']}")
    if r["in_view"]:
        lines += [f"  rotary plan       axis at s = {r['axis_mm']:g} mm (D = {r['axis_distance_mm']:.2f} mm, "
                  f"column {rep['axis_column_px']:.1f}), table at {r['table_z_mm']:g} mm",
                  f"                    in view at every angle: a cylinder of radius {r['part_radius_mm']:.1f} mm "
                  f"and height {r['part_height_mm']:.1f} mm; a flat part up to radius "
                  f"{r['max_radius_mm']:.1f} mm, a thin one up to {r['max_height_mm']:.1f} mm high"]
    else:
        lines.append(f"  rotary plan       axis at s = {r['axis_mm']:g} mm: OUT OF VIEW (see the warning)")
    lines += [f"  WARNING: {w}" for w in rep["warnings"]]
    return [line for line in lines if line] + [""]


def _mm(x, fmt: str = "{:.2f}") -> str:
    return "–" if x is None else fmt.format(x)


def format_ordinary_report(rig: Rig, rep: dict, source: str) -> str:
    """Human-readable design table of an ordinary-camera rig (:mod:`scheimpflug.model.camera_design`)."""
    L, S, s = rig.lens, rig.laser, rig.sensor
    d_near, d_far = rep["distance_range_mm"]
    along = "row" if rep["distance_axis"] == "rows" else "column"
    across = "column" if along == "row" else "row"
    n_a = s.rows if along == "row" else s.columns
    far_line = n_a - 1 if rep["near_line_px"] == 0 else 0
    (fd0, fd1), (fh0, fh1) = rep["field_distance_range_mm"], rep["field_height_range_mm"]
    res = [f"{_mm(a, '{:.4f}')} / {_mm(b, '{:.4f}')}" for a, b in
           zip(rep["distance_resolution_mm"], rep["height_resolution_mm"])]
    lines = [
        f"Ordinary-camera design — rig: {source}",
        f"  lens    f = {L.focal_length_mm:.6g} mm, f/{L.f_number:g}, focused at {_mm(rep['focus_distance_mm'])} mm "
        f"along the optical axis; k1 k2 k3 p1 p2 = {L.k1:g} {L.k2:g} {L.k3:g} {L.p1:g} {L.p2:g}",
        f"  sheet   d = {S.scheimpflug_distance_mm:.6g} mm, tan φ = {S.tan_phi:.6g} "
        f"(φ = {math.degrees(math.atan(S.tan_phi)):.3f}°)",
        f"  sensor  {s.columns} × {s.rows} px (columns × rows), p = {s.pixel_pitch_um:g} µm, perpendicular to the "
        f"optical axis at b = {s.image_distance_mm:.6g} mm, roll {s.roll_deg:.3f}°",
        "  no hinge rule: tilt, hinge, F² and C do not apply (null in --json); figures from the exact camera model",
        "",
        f"  {'quantity':<34s} {'value':>22s}  {'unit':<6s} how",
        "  " + "-" * 100,
        f"  {'field on the sheet, D':<34s} {f'{_mm(fd0)} … {_mm(fd1)}':>22s}  {'mm':<6s} "
        "the sensor's border (outer pixel edges) on the sheet",
        f"  {'field on the sheet, h':<34s} {f'{_mm(fh0)} … {_mm(fh1)}':>22s}  {'mm':<6s} "
        "(D from the object hinge, h = z)",
        f"  {'distance range (D from hinge)':<34s} {f'{_mm(d_near)} … {_mm(d_far)}':>22s}  {'mm':<6s} "
        f"{along}s {rep['near_line_px']:g} (near) and {far_line} (far), middle {across}",
        f"  {'depth range over the sensor':<34s} {_mm(rep['depth_range_mm']):>22s}  mm",
        f"  {'field of view across, near':<34s} {_mm(rep['height_range_near_mm']):>22s}  {'mm':<6s} "
        f"all {across}s at the near {along}'s outer edge",
        f"  {'field of view across, far':<34s} {_mm(rep['height_range_far_mm']):>22s}  {'mm':<6s} "
        f"all {across}s at the far {along}'s outer edge",
        f"  {'ΔZ / ΔX near':<34s} {res[0]:>22s}  {'mm/px':<6s} |∂D/∂{along}| / |∂h/∂{across}|, exact Jacobian",
        f"  {'ΔZ / ΔX middle':<34s} {res[1]:>22s}  {'mm/px':<6s} at pixel "
        f"({rep['center_column_px']:g}, {rep['center_row_px']:g})",
        f"  {'ΔZ / ΔX far':<34s} {res[2]:>22s}  mm/px",
        f"  {'blur near / middle / far':<34s} {' / '.join(_mm(b) for b in rep['blur_px']):>22s}  {'px':<6s} "
        "circle of confusion at the lens's f-number and focus",
        *_focus_lines(rep, along),
        f"  {'clearance (laser → near end)':<34s} {_mm(rep['clearance_mm']):>22s}  {'mm':<6s} "
        f"along the sheet, laser origin at x = {S.origin_x_mm:g} mm",
        f"  {'standoff (lens → near end)':<34s} {_mm(rep['standoff_mm']):>22s}  mm",
        f"  {'sensor centre to lens centre':<34s} {rep['sensor_distance_to_lens_mm']:>22.4f}  mm",
        "",
        "  frame: origin at the lens centre, +x optical axis, +z up; D along the sheet from the object hinge "
        f"H = ({rep['object_hinge_mm'][0]:.3f}, {rep['object_hinge_mm'][1]:.3f}, 0) mm",
        *_ordinary_plan_lines(rep),
    ]
    return "\n".join(lines)


def _focus_lines(rep: dict, along: str) -> list[str]:
    if rep["focus_range_mm"] is None:
        return ["  acceptable focus (CoC ≤ 1 px)   nowhere on the sensor's middle line"]
    lo, hi = rep["focus_range_mm"]
    a, b = rep["focus_range_line_px"]
    where = ("the whole middle line" if rep["sheet_in_focus"]
             else f"the sheet leaves it at D = {lo:.2f} and {hi:.2f} mm ({along}s {a:.1f} and {b:.1f})")
    return [f"  {'acceptable focus (CoC ≤ 1 px)':<34s} {f'{lo:.2f} … {hi:.2f}':>22s}  {'mm':<6s} {where}"]


def _ordinary_plan_lines(rep: dict) -> list[str]:
    uv = rep["rotary_axis_px"]
    at = "–" if uv is None or None in uv else f"({uv[0]:.1f}, {uv[1]:.1f})"
    r = rep["rotary_plan"]
    lines = [f"  rotary plan       axis at D = {rep['axis_distance_mm']:.2f} mm meets the table "
             f"(h = {r['table_z_mm']:.2f} mm) at pixel {at}: {'in view' if r['in_view'] else 'OUT OF VIEW'}"]
    if r["in_view"]:
        lines.append(f"                    in view at every angle: a cylinder of radius {r['part_radius_mm']:.1f} mm "
                     f"and height {r['part_height_mm']:.1f} mm; a flat part up to radius {r['max_radius_mm']:.1f} mm, "
                     f"a thin one up to {r['max_height_mm']:.1f} mm high")
    lines += ["  calibration plan  not given: its rule uses the hinge rule's working volume (scheimpflug.model.volume)",
              "  pattern advice    not given: it uses the hinge rule's rectification"]
    return lines + [f"  WARNING: {w}" for w in rep["warnings"]] + [""]
