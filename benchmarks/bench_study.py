"""The worked example of `scheimpflug study` (docs/tutorials/tolerance-study.md), timed: a design sweep for a
300–600 mm range on a metal part, then the tolerance study of the design it ranks first.

    python benchmarks/bench_study.py [--workers 2] [--out DIR]

Prints the wall time of each step, the CPU time of the draws (summed over the workers),
the load average before and after, the sweep's best designs and the tolerance ranking.
"""

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "studies" / "examples"


def _run(args, argv):
    from scheimpflug.app.cli import main as cli

    t0 = time.perf_counter()
    status = cli(argv)
    return status, time.perf_counter() - t0


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    root = Path(args.out or tempfile.mkdtemp())
    load0 = os.getloadavg()
    s1, t1 = _run(args, ["study", "sweep", str(EXAMPLES / "sweep_300_600.toml"), "--out", str(root / "sweep"),
                         "--workers", str(args.workers), "--near-mm", "300", "--far-mm", "600",
                         "--max-error-mm", "0.1", "--quiet"])
    sweep = json.loads((root / "sweep" / "summary.json").read_text())
    s2, t2 = _run(args, ["study", "tolerance", str(EXAMPLES / "tolerance_300_600.toml"),
                         "--out", str(root / "tolerance"), "--workers", str(args.workers), "--quiet"])
    tol = json.loads((root / "tolerance" / "summary.json").read_text())
    load1 = os.getloadavg()
    print(f"load average before {load0[0]:.1f} / {load0[1]:.1f} / {load0[2]:.1f}, "
          f"after {load1[0]:.1f} / {load1[1]:.1f} / {load1[2]:.1f}; {args.workers} workers")
    print(f"sweep:     {sweep['designs']} designs ({sweep['measured']} measured) in {t1:.0f} s wall, "
          f"draws {sweep['cpu_s_draws']:.0f} s CPU (exit {s1})")
    print(f"tolerance: {tol['draws']} draws in {t2:.0f} s wall, draws {tol['cpu_s_draws']:.0f} s CPU, "
          f"analytic {tol['analytic']['evaluations']} evaluations in {tol['analytic']['seconds']:.1f} s (exit {s2})")
    print(f"total {t1 + t2:.0f} s wall")
    for b in sweep["best"][:3]:
        vals = ", ".join(f"{k[4:]} = {v:.5g}" for k, v in b.items() if k.startswith("rig."))
        print(f"  design {b['draw']}: {vals}: |SD| = {abs(b['SD_mm']) * 1e3:.1f} µm")
    for line in tol["ranking"]:
        print("  " + line)
    print(f"outputs in {root}")


if __name__ == "__main__":
    main()
