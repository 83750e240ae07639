"""`scheimpflug calibrate DIR`: the paper's parameter-free calibration (+ refined fit)."""

from __future__ import annotations

import math
import sys
import warnings

from scheimpflug.app.commands._common import print_json


def add_parser(sub):
    p = sub.add_parser("calibrate", help="calibrate from plate frames (paper Section 3)",
                       description="Calibrate from a frame folder of a plate moved along the "
                                   "sheet: image hinge, F², d0 and C (paper Eqs. 11–12), by the "
                                   "paper's endpoint method and by a refined joint fit, with the "
                                   "standard errors of every constant.")
    p.add_argument("dir", metavar="DIR", help="frame folder (manifest.json + frames/)")
    p.add_argument("--plate-height-mm", type=float, default=None,
                   help="plate height [mm] (default: manifest scenario_params or 89)")
    p.add_argument("--out", metavar="CAL.json", help="write the calibration here")
    p.add_argument("--json", action="store_true", help="print the result as one JSON object")
    p.add_argument("--plot", metavar="FILE.png", help="draw the paper's Fig. 3(b)/(c)")
    p.add_argument("--method", choices=("paper", "refined", "best"), default="best",
                   help="estimate to use (default best: smaller standard error of u_h)")
    p.add_argument("--detector", choices=("gaussian3", "cog", "blais-rioux", "edge"),
                   default="cog",
                   help="stripe detector (default cog: windowed centre of gravity, unbiased on "
                        "wide stripes; edge = the paper's light-bar edge)")
    g = p.add_argument_group("stated accuracy (a warning when 2 standard errors exceed it)")
    g.add_argument("--accuracy-hinge-px", type=float, default=0.5, help="u_h and v_h [px] (default 0.5)")
    g.add_argument("--accuracy-relative", type=float, default=5e-4,
                   help="F² and C, relative (default 5e-4 = 0.05 %%)")
    g.add_argument("--accuracy-d0-resolution", type=float, default=0.1,
                   help="d0, in units of the distance resolution at the centre column (default 0.1)")
    p.add_argument("--quiet", action="store_true", help="no progress display")
    p.set_defaults(func=_run)
    return p


def _pm(x: float, fmt: str) -> str:
    return "–" if not math.isfinite(x) else format(x, fmt)


def _summary(res) -> str:
    lines = []
    for c in (res.paper, res.refined):
        mark = "*" if c is res.best else " "
        lines.append(f"{mark} {c.method:8s} hinge = ({c.hinge_u_px:9.2f} ± {_pm(c.hinge_u_sigma_px, '.3g')}, "
                     f"{c.hinge_v_px:8.2f} ± {_pm(c.hinge_v_sigma_px, '.3g')}) px  "
                     f"F² = {c.F2_px_mm:.6g} ± {_pm(c.F2_stderr_px_mm, '.3g')} px·mm  "
                     f"d0 = {c.d0_mm:.3f} ± {_pm(c.d0_sigma_mm, '.3g')} mm  "
                     f"C = {c.C_mm:.4f} ± {_pm(c.C_stderr_mm, '.3g')} mm")
    b = res.best
    r2 = res.paper.endpoint_fit_r2
    lines.append("  (± standard errors)  per-frame spread σ(F²) = "
                 f"{_pm(b.F2_sigma_px_mm, '.3g')} px·mm, σ(C) = {_pm(b.C_sigma_mm, '.3g')} mm")
    lines.append(f"  endpoint fits R² = {r2[0]:.6f} (top), {r2[1]:.6f} (bottom); "
                 f"{len(res.measurements)} frames used ({b.n_frames_both_edges} with both plate edges), "
                 f"{len(res.skipped)} skipped")
    return "\n".join(lines)


def _run(args) -> int:
    from scheimpflug.app.progress import Progress
    from scheimpflug.calibration import CalibrationAccuracy, calibrate_folder

    acc = CalibrationAccuracy(hinge_px=args.accuracy_hinge_px, relative=args.accuracy_relative,
                              d0_resolution=args.accuracy_d0_resolution)
    with warnings.catch_warnings(), Progress(0, label="calibrate", quiet=args.quiet) as bar:
        warnings.simplefilter("ignore")
        res = calibrate_folder(args.dir, args.plate_height_mm, method=args.method,
                               detector=args.detector, progress=bar, accuracy=acc)
    for name, reason in res.skipped:
        print(f"warning: {name}: skipped: {reason}", file=sys.stderr)
    if res.partial:
        names = ", ".join(f"{f} (no {edge} edge)" for f, edge in res.partial)
        print(f"note: {len(res.partial)} frame(s) show one plate edge only; they give the distance "
              f"relation and that edge: {names}", file=sys.stderr)
    for w in res.best.warnings:
        print(f"warning: {w}", file=sys.stderr)
    if args.out:
        res.best.save(args.out)
    if args.plot:
        from scheimpflug.app.calibration_plot import plot_calibration
        plot_calibration(res, args.plot)
    if args.json:
        d = res.best.to_json_dict()
        d["skipped"] = [{"file": f, "reason": r} for f, r in res.skipped]
        d["one_edge"] = [{"file": f, "missing": e} for f, e in res.partial]
        print_json(d)
    else:
        print(_summary(res))
    return 0
