"""Wall time and peak memory of `scheimpflug demo` (full or --quick) on this machine.

    python benchmarks/bench_demo.py [--quick] [--ideal-only] [--out DIR]

Runs the demo in a child process and prints the wall time, the CPU time and
the peak resident memory of the child, the demo's own per-stage seconds
(summary.json) and their sums for the ideal twin, the as-built column and the
error budget by source.  On a shared machine the CPU time is the steadier
figure: state the load average beside any wall time.
"""

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--ideal-only", action="store_true", help="the ideal twin alone (no as-built, no budget)")
    ap.add_argument("--out", help="output folder (default: a temporary one, removed afterwards)")
    args = ap.parse_args()
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="bench-demo-"))
    cmd = [sys.executable, "-m", "scheimpflug", "demo", "--out", str(out), "--quiet"]
    cmd += ["--quick"] * args.quick + ["--ideal-only"] * args.ideal_only
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True)
    wall = time.perf_counter() - t0
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    peak_mb = usage.ru_maxrss / 1024.0
    summary = json.loads((out / "summary.json").read_text())
    flags = "".join(f" --{f}" for f, on in (("quick", args.quick), ("ideal-only", args.ideal_only)) if on)
    print(f"demo{flags}: wall {wall:.1f} s, CPU {usage.ru_utime + usage.ru_stime:.1f} s, peak RSS "
          f"{peak_mb:.0f} MB (load average at start {load:.2f}, at end {os.getloadavg()[0]:.2f})")
    groups: dict[str, float] = {}
    for stage, sec in summary["seconds"].items():
        print(f"  {stage:<56s} {sec:7.1f} s")
        if stage != "total":
            group = stage.split(":")[0] if ":" in stage else "ideal"
            group = "budget by source" if group.startswith("budget") else group
            groups[group] = groups.get(group, 0.0) + sec
    for group, sec in groups.items():
        print(f"  sum {group:<52s} {sec:7.1f} s")
    if not args.out:
        shutil.rmtree(out, ignore_errors=True)


if __name__ == "__main__":
    main()
