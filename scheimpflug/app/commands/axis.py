"""`scheimpflug axis DIR --calibration CAL.json`: rotary axis position (paper Section 4)."""

from __future__ import annotations

import sys

from scheimpflug.app.commands._common import add_allow_incomplete_option, number, open_frames, print_json


def add_parser(sub):
    p = sub.add_parser("axis", help="locate the rotary axis from blocker frames",
                       description="Rotary axis position in stage coordinates from the blocker "
                                   "frame(s), corrected for the blocker's half-thickness; "
                                   "optionally cross-checked with a cylinder scan.")
    p.add_argument("dir", metavar="DIR", help="frame folder of the blocker")
    p.add_argument("--calibration", required=True, metavar="CAL.json",
                   help="calibration written by 'scheimpflug calibrate --out' (paper or general model) "
                        "or '--opencv'")
    p.add_argument("--json", action="store_true", help="print the result as one JSON object")
    p.add_argument("--blocker-thickness-mm", type=number(0, 100, hi_open=True, unit="mm"), default=None,
                   help="blocker thickness [mm] (default: manifest scenario_params."
                        "blocker_thickness_mm, else 2.0)")
    p.add_argument("--cylinder-scan", metavar="DIR2",
                   help="cross-check: frame folder of a cylinder turning on the stage")
    p.add_argument("--cylinder-radius-mm", type=number(0, 1e4, lo_open=True, unit="mm"), default=50.0,
                   help="radius of that cylinder [mm] (default 50: the paper's Ø100 mm)")
    add_allow_incomplete_option(p)
    p.set_defaults(func=_run)
    return p


def _check_stripe_direction(calibration, folder) -> None:
    """Refuse a folder whose stripe_along contradicts the calibration (issue 34 item 3)."""
    from scheimpflug.calibration.direction import stripe_direction_problem
    from scheimpflug.errors import CalibrationError

    problem = stripe_direction_problem(calibration, folder.columns, folder.rows, folder.stripe_along)
    if problem:
        raise CalibrationError(f"the calibration cannot be applied to {str(folder.path)!r}: {problem}")


def _run(args) -> int:
    from scheimpflug.axis import locate_axis, locate_axis_from_cylinder
    from scheimpflug.calibration import load_calibration

    cal = load_calibration(args.calibration)
    blocker = open_frames(args.dir, args)
    cylinder = open_frames(args.cylinder_scan, args) if args.cylinder_scan else None
    for folder in (blocker, cylinder):
        if folder is not None:
            _check_stripe_direction(cal, folder)
    res = locate_axis(blocker, cal, blocker_thickness_mm=args.blocker_thickness_mm)
    out = res.to_json_dict()
    cyl = None
    if args.cylinder_scan:
        cyl = locate_axis_from_cylinder(cylinder, cal, args.cylinder_radius_mm)
        out["cylinder"] = cyl.to_json_dict()
        out["cylinder_minus_blocker_mm"] = cyl.axis_mm - res.axis_mm
    for name, reason in res.skipped:
        print(f"warning: {name}: skipped: {reason}", file=sys.stderr)
    for note in res.warnings:
        print(f"warning: {note}", file=sys.stderr)
    if args.json:
        print_json(out)
        return 0
    print(f"axis = {res.axis_mm:.3f} mm (stage coordinate): blocker face {res.face_mm:.3f} mm "
          f"at column {res.column_px:.2f} + half of {res.blocker_thickness_mm:g} mm "
          f"({res.thickness_source}); spread {res.spread_mm:.3f} mm over {res.n_rows} rows")
    if cyl is not None:
        print(f"cylinder cross-check: axis = {cyl.axis_mm:.3f} mm (e = {cyl.eccentricity_mm:.3f} mm, "
              f"rms {cyl.rms_mm:.3f} mm, {cyl.n_frames} frames); difference "
              f"{cyl.axis_mm - res.axis_mm:+.3f} mm")
    return 0
