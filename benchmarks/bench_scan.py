"""Wall time and peak memory of a rotary scan of the paper cylinder, and where the time goes.

Runs the same code path as ``scheimpflug render rotary --part cylinder`` (the
frame loop of :mod:`sim.writer` with the Mitsuba twin) at full resolution and
prints, per frame and in total: render (light tracing + ambient, incl. the
per-frame scene update), geometric stripe truth, per-pixel truth (every N-th
frame), sensor noise, truth-file write and PNG write; and the peak resident
memory (``resource.getrusage(RUSAGE_SELF).ru_maxrss``).

The paper's scan is 720 frames (0.5° steps).  ``--frames N`` renders only the
first N and extrapolates linearly to 720 (said so in the output); the set-up
(scene load, JIT compilation, first-frame warm-up) is reported separately and
not extrapolated.  A PNG encoder comparison (zlib level × strategy) on one
rendered frame is printed too.

Usage::

    .venv/bin/python benchmarks/bench_scan.py                # 60 frames, extrapolated
    .venv/bin/python benchmarks/bench_scan.py --frames 720   # the whole scan (≈ 15–25 min)
"""

from __future__ import annotations

import argparse
import resource
import shutil
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from scheimpflug.app.progress import Progress  # noqa: E402
from scheimpflug.model.rig import load_preset  # noqa: E402
from sim.scenarios import rotary_scenario  # noqa: E402
from sim.writer import MitsubaTwin, build_manifest, generator_info, read_png, render_scenario  # noqa: E402


def _png_table(image: np.ndarray) -> None:
    import cv2

    from sim.writer import encode_png16

    print("\nPNG encoding of one frame (best of 3):")
    for level in (1, 2):
        best = 1e9
        for _ in range(3):
            t = time.perf_counter()
            buf = encode_png16(image, level)
            best = min(best, time.perf_counter() - t)
        print(f"  sim.writer.encode_png16 level {level}   {best * 1e3:6.1f} ms  {len(buf) / 1e6:5.2f} MB"
              + ("   (used)" if level == 1 else ""))
    names = {cv2.IMWRITE_PNG_STRATEGY_DEFAULT: "default", cv2.IMWRITE_PNG_STRATEGY_FILTERED: "filtered",
             cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY: "huffman", cv2.IMWRITE_PNG_STRATEGY_RLE: "rle"}
    for level in (0, 1, 3):
        for strat, name in names.items():
            best, size = 1e9, 0
            for _ in range(3):
                t = time.perf_counter()
                ok, buf = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, level,
                                                       cv2.IMWRITE_PNG_STRATEGY, strat])
                best, size = min(best, time.perf_counter() - t), len(buf)
            print(f"  cv2.imencode level {level} {name:9s} {best * 1e3:6.1f} ms  {size / 1e6:5.2f} MB")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=60, help="frames to render (720 = whole scan)")
    ap.add_argument("--part", default="cylinder")
    ap.add_argument("--step-deg", type=float, default=0.5)
    ap.add_argument("--truth-pixels", type=int, default=30, help="per-pixel truth every N-th frame")
    ap.add_argument("--spp", type=int, default=None, help="laser samples per row (renderer default)")
    ap.add_argument("--overlap", action="store_true",
                    help="write PNG and truth on a background thread (png/truth_write times then "
                         "overlap the next frame and do not add up to the wall time)")
    ap.add_argument("--keep", metavar="DIR", help="render into DIR and keep it")
    args = ap.parse_args()

    rig = load_preset("paper")
    out = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="bench_scan_"))
    t0 = time.perf_counter()
    scenario = rotary_scenario(rig, seed=0, part=args.part, step_deg=args.step_deg,
                               frames=args.frames, truth_pixels_every=args.truth_pixels)
    twin = MitsubaTwin(rig, scenario.assembly, spp=args.spp)
    setup_s = time.perf_counter() - t0
    manifest = build_manifest(rig, scenario, 0, twin.spp, twin.variant, generator_info(),
                              twin.describe())
    with Progress(0, label="render") as bar:
        stats = render_scenario(rig, scenario, out, twin, manifest, progress=bar,
                                overlap=args.overlap)
    rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    n = stats.frames_rendered
    disk_mb = sum(p.stat().st_size for p in out.rglob("*") if p.is_file()) / 1e6

    print(f"\nrotary scan of {args.part!r}: {n} frames at {args.step_deg}° "
          f"({rig.sensor.columns}×{rig.sensor.rows} px, variant {twin.variant}, "
          f"{twin.spp_field} {twin.spp}, per-pixel truth every {args.truth_pixels}, "
          f"{scenario.assembly.triangle_count} triangles, "
          f"{'overlapped' if args.overlap else 'sequential'} writer)")
    print(f"set-up (part, scene load): {setup_s:.1f} s")
    print(f"frame loop wall time: {stats.wall_s:.1f} s = {stats.wall_s / n * 1e3:.0f} ms/frame "
          f"({n / stats.wall_s:.2f} frames/s)")
    print("time per part (sum over frames" + ("; truth_write/png ran in the writer thread)"
                                              if args.overlap else "):"))
    total = sum(stats.seconds.values())
    for key, s in stats.seconds.items():
        print(f"  {key:13s} {s:8.2f} s  {s / n * 1e3:8.1f} ms/frame  {100 * s / total:5.1f} %")
    print(f"peak memory (ru_maxrss): {rss_mb:.0f} MB")
    print(f"output on disk: {disk_mb:.0f} MB ({disk_mb / n:.1f} MB/frame)")
    if n < 720:
        est = stats.wall_s / n * 720
        print(f"EXTRAPOLATED to 720 frames (linear in frames, from {n}): "
              f"{est:.0f} s = {est / 60:.1f} min + set-up; disk ≈ {disk_mb / n * 720:.0f} MB")
    _png_table(read_png(out / "frames" / f"{scenario.frames[-1].index:05d}.png"))
    if not args.keep:
        shutil.rmtree(out, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
