"""`scheimpflug calibrate DIR`: the paper's parameter-free calibration (+ refined fit)."""

from __future__ import annotations

import sys
import warnings

from scheimpflug.app.commands._common import add_force_option, check_output, check_plot, number, print_json


def add_parser(sub):
    p = sub.add_parser("calibrate", help="calibrate from plate frames (paper Section 3)",
                       description="Calibrate from a frame folder of a plate moved along the "
                                   "sheet: image hinge, F², d0 and C (paper Eqs. 11–12), by the "
                                   "paper's endpoint method and by a refined joint fit.")
    p.add_argument("dir", metavar="DIR", help="frame folder (manifest.json + frames/)")
    p.add_argument("--plate-height-mm", type=number(0, 1e4, lo_open=True, unit="mm"), default=None,
                   help="plate height [mm] (default: manifest scenario_params or 89)")
    p.add_argument("--out", metavar="CAL.json", help="write the calibration here")
    p.add_argument("--json", action="store_true", help="print the result as one JSON object")
    p.add_argument("--plot", metavar="FILE.png", help="draw the paper's Fig. 3(b)/(c)")
    add_force_option(p)
    p.add_argument("--method", choices=("paper", "refined", "best"), default="best",
                   help="estimate to use (default best: smaller standard error of u_h)")
    p.add_argument("--detector", choices=("gaussian3", "cog", "blais-rioux", "edge"),
                   default="cog",
                   help="stripe detector (default cog: windowed centre of gravity, unbiased on "
                        "wide stripes; edge = the paper's light-bar edge)")
    p.add_argument("--quiet", action="store_true", help="no progress display")
    p.set_defaults(func=_run)
    return p


def _sig(x: float) -> str:
    """A standard error for the summary; "undefined" when it is NaN (exactly determined fit)."""
    return f"{x:.3g}" if x == x else "undefined"


def _summary(res) -> str:
    lines = []
    for c in (res.paper, res.refined):
        mark = "*" if c is res.best else " "
        lines.append(f"{mark} {c.method:8s} hinge = ({c.hinge_u_px:9.2f}, {c.hinge_v_px:8.2f}) px "
                     f"(σu {_sig(c.hinge_u_sigma_px)})  F² = {c.F2_px_mm:.6g} ± {_sig(c.F2_sigma_px_mm)} "
                     f"px·mm  d0 = {c.d0_mm:.3f} mm  C = {c.C_mm:.4f} ± {_sig(c.C_sigma_mm)} mm")
    r2 = res.paper.endpoint_fit_r2
    lines.append(f"  endpoint fits R² = {r2[0]:.6f} (top), {r2[1]:.6f} (bottom); "
                 f"{len(res.measurements)} frames used, {len(res.skipped)} skipped")
    return "\n".join(lines)


def _run(args) -> int:
    from scheimpflug.app.progress import Progress
    from scheimpflug.calibration import calibrate_folder

    check_output(args.out, "--out", force=args.force, folders=[args.dir])
    check_plot(args.plot, force=args.force, folders=[args.dir], inputs=[args.out])
    with warnings.catch_warnings(), Progress(0, label="calibrate", quiet=args.quiet) as bar:
        warnings.simplefilter("ignore")
        res = calibrate_folder(args.dir, args.plate_height_mm, method=args.method,
                               detector=args.detector, progress=bar)
    for name, reason in res.skipped:
        print(f"warning: {name}: skipped: {reason}", file=sys.stderr)
    for note in res.warnings:
        print(f"warning: {note}", file=sys.stderr)
    if args.out:
        res.best.save(args.out)
    if args.plot:
        from scheimpflug.app.calibration_plot import plot_calibration
        plot_calibration(res, args.plot)
    if args.json:
        d = res.best.to_json_dict()
        d["skipped"] = [{"file": f, "reason": r} for f, r in res.skipped]
        d["warnings"] = list(res.warnings)
        print_json(d)
    else:
        print(_summary(res))
    return 0
