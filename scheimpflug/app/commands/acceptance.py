"""`scheimpflug acceptance`: VDI/VDE 2634-2 quality parameters (PF, PS, SD, F) in the twin."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from scheimpflug.app.commands._common import add_rig_options, integer, print_json, rig_from_args
from scheimpflug.app.commands._quality import add_quality_options, quality_from_args

__all__ = ["add_parser"]


def add_parser(sub):
    p = sub.add_parser("acceptance", help="VDI/VDE 2634-2 acceptance test in the twin (PF, PS, SD, F)",
                       description="Render a sphere (10 positions), a ball bar (7) and a plane (6) on the "
                                   "rotary stage, reconstruct them through the pipeline (calibration "
                                   "frames, blocker, scans) and evaluate the VDI/VDE 2634-2 quality "
                                   "parameters: the table (largest over positions), per-position detail, "
                                   "a figure and JSON.  The headline figures are those of the points "
                                   "that pass the point-quality filter (as 'reconstruct' writes them); "
                                   "the figures of every point follow as 'unfiltered'.")
    add_rig_options(p)
    p.add_argument("--out", metavar="DIR", default="acceptance",
                   help="working folder: frame folders, acceptance.json, acceptance.png (default ./acceptance)")
    p.add_argument("--model", choices=("paper", "general", "auto"), default="auto",
                   help="calibration model (default auto; 'paper' on a distorting rig shows what an "
                        "unmodelled distortion costs)")
    p.add_argument("--binning", type=integer(1, 4096), default=1, metavar="K",
                   help="k × k binned sensor (default 1)")
    p.add_argument("--quick", action="store_true",
                   help="2 sphere, 1 ball-bar and 1 plane position with fewer frames (not the guideline's "
                        "count: a smoke test)")
    p.add_argument("--frames", type=int, default=None,
                   help="frames per sphere crossing / plane scan (default 21; 9 with --quick)")
    p.add_argument("--no-exclusion", action="store_true",
                   help="evaluate every point (default: exclude the 0.3 %% the guideline permits)")
    add_quality_options(p)
    p.add_argument("--seed", type=int, default=0, help="run seed (default 0)")
    p.add_argument("--json", action="store_true", help="print the result as one JSON object")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_run)
    return p


def _table(r: dict) -> str:
    um = lambda x: "—" if x is None else f"{x * 1e3:8.1f} µm"  # noqa: E731
    n = r["positions"]
    lines = [f"VDI/VDE 2634-2 in the twin (L0 = {r['L0_mm']:.1f} mm; calibration {r['calibration']['model']}; "
             f"0.3 % exclusion {'applied' if r['exclude_fraction'] else 'not applied'})",
             f"  PF (probing error, form)     {um(r['PF_mm'])}   max over {len(n['sphere'])} sphere positions",
             f"  PS (probing error, size)     {um(r['PS_mm'])}   largest |PS|",
             f"  SD (sphere-spacing error)    {um(r['SD_mm'])}   largest |SD| over "
             f"{len(n['ball_bar'])} ball-bar positions",
             f"  F  (flatness error)          {um(r['F_mm'])}   max over {len(n['plane'])} plane positions",
             f"  stripe extraction error on the sheet: range {um(r['extraction_range_mm'])}, "
             f"RMS {um(r['extraction_rms_mm'])}"]
    q, raw = r.get("quality_filter"), r.get("unfiltered") or {}
    lines.insert(1, "  quality filter: " + (f"incidence ≤ {q['max_incidence_deg']:g}°, SNR ≥ {q['min_snr']:g}"
                                           f"{', sweep edges dropped' if q['drop_sweep_edges'] else ''}"
                                           if q else "off (every point)"))
    if q:
        lines.insert(6, f"  every point (unfiltered):    PF {um(raw.get('PF_mm'))}, PS {um(raw.get('PS_mm'))}, "
                        f"SD {um(raw.get('SD_mm'))}, F {um(raw.get('F_mm'))}")
    for kind in ("sphere", "ball_bar", "plane"):
        for row in n[kind]:
            key = {"sphere": "PF_mm", "ball_bar": "SD_mm", "plane": "F_mm"}[kind]
            extra = f"  PS {row['PS_mm'] * 1e3:+.1f} µm" if kind == "sphere" else ""
            lines.append(f"    {row['name']:12s} {key[:-3]} {row[key] * 1e3:+8.1f} µm{extra}  "
                         f"({row['n_frames']} frames)")
    return "\n".join(lines)


def _run(args) -> int:
    from scheimpflug.app.acceptance_plot import plot_acceptance
    from scheimpflug.app.progress import Progress
    from scheimpflug.errors import ScheimpflugError
    from scheimpflug.io.atomic import write_json_atomic
    from sim.acceptance import run_acceptance

    rig = rig_from_args(args)
    _check_binning(rig, args.binning)
    if args.no_quality_filter and args.min_snr is not None:
        raise ScheimpflugError("--no-quality-filter keeps every point: it cannot be combined with --min-snr")
    quality = quality_from_args(args)
    out = Path(args.out)
    with Progress(0, label="acceptance", quiet=args.quiet) as bar:
        res = run_acceptance(rig, out, model=args.model, binning=args.binning, quick=args.quick,
                             frames=args.frames, seed=args.seed, exclude_fraction=0.0 if args.no_exclusion
                             else 0.003, quality=quality, progress=bar, warn=lambda m: None)
    plot_acceptance(res, out / "acceptance.png")
    data = {k: v for k, v in res.items() if k not in ("points", "sheet_model")}
    data = json.loads(json.dumps(data, default=float))
    write_json_atomic(out / "acceptance.json", data)
    print(_table(res), file=sys.stderr if args.json else sys.stdout)
    if args.json:
        print_json(data)
    return 0


def _check_binning(rig, k: int) -> None:
    """One line, before any work, for a binning that leaves no pixel of the rig's sensor."""
    from scheimpflug.errors import ScheimpflugError
    from scheimpflug.model.binning import binned_rig

    try:
        binned_rig(rig, k)
    except ValueError as exc:
        raise ScheimpflugError(f"--binning {k}: {exc}") from None
