"""VDI/VDE 2634-2 acceptance figures in the twin (issues 14, 25): the full plan on several rigs.

    python benchmarks/bench_acceptance.py [--binning 1] [--seed 0] [--runs ideal,dist,auto,asbuilt] [--out DIR]

Runs `scheimpflug acceptance` (10 sphere, 7 ball-bar, 6 plane positions) on the
ideal paper rig (model auto), on the paper rig with k1 = −0.05 (once with the
paper form, distortion not modelled, and once with `--model auto`) and on the
`paper-as-built` preset, and prints the tables: PF, PS, SD, F with the default
point-quality filter (the headline) and of every point (unfiltered), L0 and the
stripe-extraction error mapped to the sheet.
"""

import argparse
import json
import tempfile
import time
from pathlib import Path


def _runs(root: Path) -> dict:
    (root / "dist.toml").write_text("[lens]\nk1 = -0.05\n")
    return {"ideal": ("ideal paper rig, auto", ["--preset", "paper", "--model", "auto"]),
            "dist": ("k1 = -0.05, paper form", ["--rig", str(root / "dist.toml"), "--model", "paper"]),
            "auto": ("k1 = -0.05, auto", ["--rig", str(root / "dist.toml"), "--model", "auto"]),
            "asbuilt": ("paper-as-built, auto", ["--preset", "paper-as-built", "--model", "auto"])}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--binning", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--runs", default="ideal,dist,auto", help="comma-separated: ideal, dist, auto, asbuilt")
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    from scheimpflug.app.cli import main as cli

    root = Path(args.out or tempfile.mkdtemp())
    root.mkdir(parents=True, exist_ok=True)
    runs = _runs(root)
    print(f"binning {args.binning}, seed {args.seed}; values in µm (unfiltered: every point, no quality "
          "filter); extraction = stripe error on the sheet (range, RMS)")
    print(f"{'run':24s} {'model':8s} {'PF':>7s} {'PS':>7s} {'SD':>7s} {'F':>7s} | {'PF unf':>7s} {'PS unf':>7s} "
          f"{'SD unf':>7s} {'F unf':>7s} | {'L0 [mm]':>8s} {'extr. range':>12s} {'extr. RMS':>10s} {'time [s]':>9s}")
    for key in args.runs.split(","):
        name, opts = runs[key]
        t0 = time.perf_counter()
        out = root / f"{key}-b{args.binning}-s{args.seed}"
        cli(["acceptance", *opts, "--binning", str(args.binning), "--seed", str(args.seed), "--out", str(out),
             "--quiet"])
        r = json.loads((out / "acceptance.json").read_text())
        keys = ("PF_mm", "PS_mm", "SD_mm", "F_mm")
        um = [1e3 * r[k] for k in keys] + [1e3 * r["unfiltered"][k] for k in keys]
        print(f"{name:24s} {r['calibration']['model']:8s} {um[0]:7.1f} {um[1]:+7.1f} {um[2]:+7.1f} {um[3]:7.1f} | "
              f"{um[4]:7.1f} {um[5]:+7.1f} {um[6]:+7.1f} {um[7]:7.1f} | {r['L0_mm']:8.1f} "
              f"{1e3 * r['extraction_range_mm']:12.1f} {1e3 * r['extraction_rms_mm']:10.1f} "
              f"{time.perf_counter() - t0:9.0f}")


if __name__ == "__main__":
    main()
