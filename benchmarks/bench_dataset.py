"""Throughput of the dataset frame loop (``scheimpflug dataset make``) at full paper resolution.

The paper cylinder (1.09 M triangles) on the rotary stage, full 1936 × 1216 frames with
sensor noise and the exact per-row stripe truth (+ distance and incidence per row), no
per-pixel truth; written to Zarr (Blosc/zstd + bit-shuffle) or 16-bit PNG + ``.npz``.
Each configuration makes ``--samples`` samples of ``--frames`` frames into a fresh
folder and reports:

* the steady-state frame rate: frames completed between the moment the first
  ``warm`` frames (2 per worker) were done and the end, over that time (taken from
  the aggregated progress) — excludes cluster start, scene loading and JIT warm-up;
* the end-to-end wall time and rate (everything included);
* the time per stage summed over the workers (render, noise, truth on the worker's
  main thread; write = encode + hash + write on its background thread);
* bytes per frame on disk.

Run (from the repository root)::

    .venv/bin/python benchmarks/bench_dataset.py                       # zarr and png, 1 and 2 workers
    .venv/bin/python benchmarks/bench_dataset.py --formats zarr --workers 2 --frames 120

A cost model for N machines follows from the printed frames/hour/core and bytes/frame.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from sim.dataset import make_dataset, parse_spec  # noqa: E402


def _spec(samples: int, frames: int, part: str) -> dict:
    return {"dataset": {"seed": 1, "samples": samples, "name": "bench"},
            "rig": {"preset": "paper"},
            "scenario": {"kind": "rotary", "part": part, "step_deg": 360.0 / frames, "binning": 1}}


def run(fmt: str, workers: int, samples: int, frames: int, part: str) -> dict:
    spec = parse_spec(_spec(samples, frames, part))
    out = Path(tempfile.mkdtemp(prefix=f"bench_dataset_{fmt}_{workers}_"))
    shutil.rmtree(out)
    stamps: list[tuple[float, int]] = []
    t0 = time.perf_counter()
    res = make_dataset(spec, out, storage=fmt, workers=workers,
                       progress=lambda d, t: stamps.append((time.perf_counter(), d)))
    wall = time.perf_counter() - t0
    total = samples * frames
    warm = 2 * workers
    t_warm = next(t for t, d in stamps if d >= warm)
    t_end = next(t for t, d in stamps if d >= total)
    size = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
    frame_bytes = sum(p.stat().st_size for p in (out.rglob("frames/*.png") if fmt == "png"
                                                  else (out / "frames.zarr" / "frames").rglob("*"))
                      if p.is_file() and p.name != "zarr.json")
    shutil.rmtree(out, ignore_errors=True)
    assert res.complete and res.frames == total
    return {"fmt": fmt, "workers": workers, "steady_fps": (total - warm) / (t_end - t_warm),
            "wall_s": wall, "fps_end_to_end": total / wall, "seconds": res.seconds,
            "bytes_per_frame": size / total, "frame_bytes": frame_bytes / total, "frames": total}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--formats", nargs="+", default=["zarr", "png"], choices=["zarr", "png"])
    ap.add_argument("--workers", nargs="+", type=int, default=[1, 2])
    ap.add_argument("--samples", type=int, default=2, help="samples (one scene load each per worker)")
    ap.add_argument("--frames", type=int, default=90, help="frames per sample")
    ap.add_argument("--part", default="cylinder")
    args = ap.parse_args()
    print(f"load average before: {os.getloadavg()[0]:.2f} (1 min) on {os.cpu_count()} cores")
    rows = []
    for fmt in args.formats:
        for w in args.workers:
            r = run(fmt, w, args.samples, args.frames, args.part)
            rows.append(r)
            s, n = r["seconds"], r["frames"]
            print(f"{fmt:4s} workers {w}: steady {r['steady_fps']:5.1f} frames/s, end to end "
                  f"{r['fps_end_to_end']:5.1f} frames/s ({r['wall_s']:.1f} s for {n} frames); per frame "
                  f"(summed over workers) render {s['render'] / n * 1e3:.1f}, noise {s['noise'] / n * 1e3:.1f}, "
                  f"truth {s['truth'] / n * 1e3:.1f}, write {s['write'] / n * 1e3:.1f} ms (background); "
                  f"{r['bytes_per_frame'] / 1e6:.2f} MB/frame on disk ({r['frame_bytes'] / 1e6:.2f} MB the image)",
                  flush=True)
    cores = os.cpu_count() or 1
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    print("cost model (steady state, this machine):")
    for r in rows:
        per_core_h = r["steady_fps"] * 3600 / cores
        print(f"  {r['fmt']} {r['workers']} worker(s): {per_core_h:,.0f} frames/hour/core; "
              f"1 M frames ≈ {1e6 / (r['steady_fps'] * 3600):.1f} h on one such machine, "
              f"{r['bytes_per_frame'] * 1e6 / 1e9:.0f} GB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
