"""``scheimpflug demo``: the paper's experiments in the twin, with a report scored against the truth."""

from __future__ import annotations

import argparse

from scheimpflug.app.commands._common import add_rig_options, rig_from_args

__all__ = ["add_parser"]


def add_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "demo", help="reproduce the paper in the digital twin and write a report",
        description="Render the paper's calibration sequence, blocker, cylinder scan (0.5° steps) and "
                    "pile scan (1° steps) with the digital twin; calibrate, locate the axis, "
                    "reconstruct and score against the rendered meshes; write report/report.md, the "
                    "point clouds and the calibration into --out. Beside the ideal twin it runs the "
                    "twin as built (preset paper-as-built: every modelled error source on) and an "
                    "error budget by source on reduced plans. --quick does the same on binned "
                    "sensors with coarse steps (about a minute).")
    add_rig_options(p)
    p.add_argument("--out", default="demo-out", metavar="DIR", help="output folder (default ./demo-out)")
    p.add_argument("--quick", action="store_true", help="reduced resolution and frames (~1 minute)")
    p.add_argument("--seed", type=int, default=0, help="run seed (default 0)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument("--ideal-only", action="store_true",
                   help="the ideal twin alone: no as-built column, no error budget by source")
    p.set_defaults(func=_run)
    return p


def _run(args: argparse.Namespace) -> int:
    from scheimpflug.app.demo import run_demo

    run_demo(args.out, quick=args.quick, rig=rig_from_args(args), seed=args.seed, quiet=args.quiet,
             as_built=False if args.ideal_only else None)
    return 0
