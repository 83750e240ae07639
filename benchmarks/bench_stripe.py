"""Stripe-extraction throughput on full 1936 × 1216 uint16 frames (frames in memory),
and PNG decoding separately.

    .venv/bin/python benchmarks/bench_stripe.py [--frames N] [--threads T]

Prints frames/s per method and multi-peak rule, and the PNG decode time.  The
frames are synthetic calibration-plate frames (tests/synth_frames.py: 12-bit,
shot + read noise, a σ = 1.6 px stripe over ≈ 1600 rows).  Numbers depend on
what else runs on the machine: run it on an idle one.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numba
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from synth_frames import Camera, Geometry, PlateScene, plate_frame  # noqa: E402

from scheimpflug.stripe import extract_stripes  # noqa: E402


def _rate(frames, reps, **kw) -> float:
    extract_stripes(frames[0], **kw)  # JIT warm-up
    t0 = time.perf_counter()
    for _ in range(reps):
        for f in frames:
            extract_stripes(f, **kw)
    return reps * len(frames) / (time.perf_counter() - t0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=8, help="distinct frames in memory")
    ap.add_argument("--reps", type=int, default=50, help="passes over them")
    ap.add_argument("--threads", type=int, default=numba.config.NUMBA_NUM_THREADS)
    args = ap.parse_args()
    numba.set_num_threads(args.threads)
    rng = np.random.default_rng(0)
    geo = Geometry()
    frames = [plate_frame(geo, s, PlateScene(), Camera(), rng)[0]
              for s in np.linspace(0, 240, args.frames)]
    print(f"frames {geo.rows} × {geo.columns} uint16, {args.frames} distinct × {args.reps} passes, "
          f"{args.threads} thread(s)")
    for method in ("cog", "gaussian3", "blais-rioux", "edge"):
        for rule in ("nearest", "strongest"):
            r = _rate(frames, args.reps, method=method, multi_peak=rule)
            print(f"  {method:12s} multi_peak={rule:9s} {r:8.0f} frames/s  ({1e3 / r:.2f} ms/frame)")
    with tempfile.TemporaryDirectory() as tmp:
        paths = []
        for i, f in enumerate(frames):
            p = str(Path(tmp) / f"{i:05d}.png")
            cv2.imwrite(p, f)
            paths.append(p)
        cv2.imread(paths[0], cv2.IMREAD_UNCHANGED)
        t0 = time.perf_counter()
        n = 0
        for _ in range(max(args.reps // 10, 1)):
            for p in paths:
                cv2.imread(p, cv2.IMREAD_UNCHANGED)
                n += 1
        dt = (time.perf_counter() - t0) / n
    print(f"  PNG decode (cv2.imread, 16-bit): {1e3 * dt:.2f} ms/frame = {1 / dt:.0f} frames/s")


if __name__ == "__main__":
    main()
