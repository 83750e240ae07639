"""Scene presets: build time, triangle counts, mesh memory, peak memory while building.

Run:  .venv/bin/python benchmarks/bench_scenes.py [--json]

Figures per preset: build time [s] (best of 3), triangles, vertices, mesh
arrays [MB] (vertices + faces as held by trimesh), peak Python allocation
while building [MB] (tracemalloc), truth-PLY write time [s] and size [MB].
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import scenes  # noqa: E402


def _best_time(fn, repeat: int = 3) -> tuple[float, object]:
    best, out = float("inf"), None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def _peak_mb(fn) -> float:
    tracemalloc.start()
    fn()
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return peak / 1e6


def bench(name: str) -> dict:
    build_s, asm = _best_time(lambda: scenes.load_part(name))
    s = asm.summary()
    with tempfile.TemporaryDirectory() as tmp:
        ply = Path(tmp) / "mesh.ply"
        t0 = time.perf_counter()
        asm.to_ply(ply)
        ply_s, ply_mb = time.perf_counter() - t0, ply.stat().st_size / 1e6
    t0 = time.perf_counter()
    watertight = all(p.mesh.is_watertight for p in asm.parts)
    wt_s = time.perf_counter() - t0
    return {"part": name, "build_s": round(build_s, 3), "triangles": s["triangles"],
            "vertices": sum(p["vertices"] for p in s["parts"]),
            "mesh_mb": round(s["mesh_bytes"] / 1e6, 1),
            "peak_build_mb": round(_peak_mb(lambda: scenes.load_part(name)), 1),
            "ply_write_s": round(ply_s, 3), "ply_mb": round(ply_mb, 1),
            "watertight": watertight, "watertight_check_s": round(wt_s, 3)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true", help="one JSON object on stdout")
    args = ap.parse_args()
    rows = [bench(n) for n in scenes.PART_NAMES]
    maxrss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3
    if args.json:
        print(json.dumps({"presets": rows, "process_max_rss_mb": round(maxrss_mb, 1),
                          "cpus": os.cpu_count()}))
        return
    keys = list(rows[0])
    print("  ".join(f"{k:>14s}" for k in keys))
    for r in rows:
        print("  ".join(f"{str(r[k]):>14s}" for k in keys))
    print(f"process max RSS: {maxrss_mb:.0f} MB  ({os.cpu_count()} CPUs)")


if __name__ == "__main__":
    main()
