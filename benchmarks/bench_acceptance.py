"""VDI/VDE 2634-2 acceptance figures in the twin (issue 14): the full plan on several rigs.

    python benchmarks/bench_acceptance.py [--binning 1] [--out DIR]

Runs `scheimpflug acceptance` (10 sphere, 7 ball-bar, 6 plane positions) on the
ideal paper rig (model auto) and on the paper rig with k1 = −0.05, once with the
paper form (distortion not modelled) and once with `--model auto`, and prints
the tables: PF, PS, SD, F, L0 and the stripe-extraction error mapped to the sheet.
"""

import argparse
import json
import tempfile
import time
from pathlib import Path


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--binning", type=int, default=1)
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    from scheimpflug.app.cli import main as cli

    root = Path(args.out or tempfile.mkdtemp())
    (root / "dist.toml").write_text("[lens]\nk1 = -0.05\n")
    runs = [("ideal paper rig, auto", ["--preset", "paper", "--model", "auto"]),
            ("k1 = -0.05, paper form", ["--rig", str(root / "dist.toml"), "--model", "paper"]),
            ("k1 = -0.05, auto", ["--rig", str(root / "dist.toml"), "--model", "auto"])]
    print(f"binning {args.binning}; values in µm; extraction = stripe error on the sheet (range, RMS)")
    print(f"{'run':26s} {'model':8s} {'PF':>7s} {'PS':>7s} {'SD':>7s} {'F':>7s} {'L0 [mm]':>8s} "
          f"{'extr. range':>12s} {'extr. RMS':>10s} {'time [s]':>9s}")
    for k, (name, opts) in enumerate(runs):
        t0 = time.perf_counter()
        out = root / f"run{k}"
        cli(["acceptance", *opts, "--binning", str(args.binning), "--out", str(out), "--quiet"])
        r = json.loads((out / "acceptance.json").read_text())
        um = [1e3 * r[key] for key in ("PF_mm", "PS_mm", "SD_mm", "F_mm")]
        print(f"{name:26s} {r['calibration']['model']:8s} {um[0]:7.1f} {um[1]:+7.1f} {um[2]:+7.1f} {um[3]:7.1f} "
              f"{r['L0_mm']:8.1f} {1e3 * r['extraction_range_mm']:12.1f} {1e3 * r['extraction_rms_mm']:10.1f} "
              f"{time.perf_counter() - t0:9.0f}")


if __name__ == "__main__":
    main()
