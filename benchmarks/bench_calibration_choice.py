"""Which calibration for my rig? The paper's method, the general model and the pattern calibration (issue 24 item 5).

Runs :func:`sim.calibration_choice.compare_calibrations` on the ideal paper rig
and the as-built one (``paper-as-built``) and prints one table per rig: the
calibrations (all plate frames, fewer; the general model; the pattern with 20,
10 and 5 poses; the board bowed or mis-scaled) against the rendered truth.

Usage::

    python benchmarks/bench_calibration_choice.py [--binning 1] [--rigs paper paper-as-built]
        [--out /tmp/bench_choice] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import math
import resource
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

LABELS = {"sheet_rms_mm": "sheet RMS", "sheet_max_mm": "sheet max", "plane_normal_deg": "normal [°]",
          "plane_distance_mm": "plane d", "axis_offset_mm": "axis off", "axis_angle_deg": "axis [°]",
          "cylinder_diameter_error_mm": "cyl Ø err", "cylinder_form_rms_mm": "cyl form",
          "box_plane_rmse_mm": "box RMSE", "ring_diameter_error_mm": "ring Ø err", "calibrate_s": "cal [s]",
          "frames": "frames"}


def table(name: str, res: dict) -> str:
    keys = list(LABELS)
    rows = [f"{name} ({res['binning']} × {res['binning']} binned; lengths in mm)",
            "| calibration | " + " | ".join(LABELS[k] for k in keys) + " |",
            "|---|" + "---|" * len(keys)]
    for method, m in res["methods"].items():
        cells = []
        for k in keys:
            v = m.get(k)
            cells.append("–" if v is None or (isinstance(v, float) and not math.isfinite(v)) else
                         (f"{v:d}" if isinstance(v, int) else f"{v:.4g}"))
        rows.append(f"| {method} | " + " | ".join(cells) + " |")
    if any("vdi" in m for m in res["methods"].values()):
        rows += ["", "VDI/VDE 2634-2, the acceptance test's quick plan (artefacts rendered once) [mm]",
                 "| calibration | PF | PS | SD | F | not measured |", "|---|---|---|---|---|---|"]
        for method, m in res["methods"].items():
            v = m.get("vdi") or {}
            rows.append(f"| {method} | " + " | ".join("–" if v.get(k) is None else f"{v[k]:.4g}"
                                                       for k in ("PF_mm", "PS_mm", "SD_mm", "F_mm"))
                        + f" | {len(v.get('failed') or [])} |")
    return "\n".join(rows)


def main() -> None:
    from scheimpflug.model.rig import load_preset
    from sim.calibration_choice import ChoicePlan, compare_calibrations

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--binning", type=int, default=1)
    ap.add_argument("--rigs", nargs="+", default=["paper", "paper-as-built"])
    ap.add_argument("--out", type=Path, default=Path("/tmp/bench_choice"))
    ap.add_argument("--json", type=Path, default=None, help="write every figure here")
    ap.add_argument("--no-vdi", action="store_true", help="leave the VDI/VDE 2634-2 figures out")
    args = ap.parse_args()
    plan = ChoicePlan(binning=args.binning, acceptance=not args.no_vdi)
    report = {}
    for name in args.rigs:
        t0 = time.perf_counter()
        report[name] = compare_calibrations(load_preset(name), plan, args.out / name,
                                            log=lambda msg, n=name, t=t0: print(
                                                f"{n}: {msg} ({time.perf_counter() - t:.0f} s)",
                                                file=sys.stderr, flush=True))
        print(table(name, report[name]), flush=True)
        print(f"  renders and calibrations: {report[name]['seconds']['total']} s\n", flush=True)
    print(f"peak RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")
    if args.json:
        args.json.write_text(json.dumps(report, indent=1, default=float))


if __name__ == "__main__":
    main()
