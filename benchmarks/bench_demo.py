"""Wall time and peak memory of `scheimpflug demo` (full or --quick) on this machine.

    python benchmarks/bench_demo.py [--quick] [--out DIR]

Runs the demo in a child process and prints the wall time, the peak resident
memory of the child, and the demo's own per-stage seconds (summary.json).
"""

import argparse
import json
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
    ap.add_argument("--out", help="output folder (default: a temporary one, removed afterwards)")
    args = ap.parse_args()
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="bench-demo-"))
    cmd = [sys.executable, "-m", "scheimpflug", "demo", "--out", str(out), "--quiet"]
    if args.quick:
        cmd.append("--quick")
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True)
    wall = time.perf_counter() - t0
    peak_mb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0
    summary = json.loads((out / "summary.json").read_text())
    print(f"demo{' --quick' if args.quick else ''}: wall {wall:.1f} s, peak RSS {peak_mb:.0f} MB")
    for stage, sec in summary["seconds"].items():
        print(f"  {stage:<32s} {sec:7.1f} s")
    if not args.out:
        shutil.rmtree(out, ignore_errors=True)


if __name__ == "__main__":
    main()
