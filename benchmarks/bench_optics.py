"""Speed of the realistic twin (issue 10, item 6) and of the ideal path, and the media's reflectance.

Prints

1. the ideal path (``[twin]`` defaults: one bounce, opaque, no speckle): render-only
   ms/frame of the paper pile at full resolution; with ``--baseline DIR`` the same
   measurement of another checkout (e.g. the main branch before issue 10) in a
   subprocess, alternating A/B/A/B in one run so that the machine's load hits both;
2. the realistic frame loop: 3 bounces, subsurface scattering and surface speckle
   (``speckle_contrast`` 0.7), full paper resolution, sensor noise, 16-bit PNG and the
   stripe truth (incl. the secondary-light truth), through :func:`sim.writer.render_scenario`
   exactly as ``scheimpflug render`` runs it — frames/s and the share of every stage
   (the renderer's own stages from :attr:`sim.render.Renderer.timings`), and the
   CPU time of all the process's threads per frame (a figure that the machine's
   other load does not inflate; half of it bounds the wall time on 2 idle cores);
3. with ``--workers N``: the same realistic pile through :func:`sim.writer.render_folder`
   (what ``scheimpflug render --workers`` runs: spawned worker processes, the main
   process writing), with 1 and N workers alternated in one run, each in a fresh
   process: wall time of the whole render (start-up included), frames/s of the frame
   loop after its first 2·N frames (warm-up: spawning, JIT kernels), and the peak
   resident memory of the main process plus its workers (sampled every 0.1 s);
4. the total diffuse reflectance of each translucent material at normal incidence
   (:func:`sim.subsurface.total_reflectance`, the table of :mod:`sim.materials`).

    .venv/bin/python benchmarks/bench_optics.py [--frames 40] [--part pile] [--baseline ../main] [--cpu]
                                                [--workers 2] [--skip-ideal] [--skip-loop]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

_IDEAL = r"""
import json, sys, time
sys.path.insert(0, {root!r})
from scheimpflug.model.rig import load_preset
from sim.scenarios import rotary_scenario
from sim.writer import MitsubaTwin
rig = load_preset("paper")
sc = rotary_scenario(rig, part={part!r}, step_deg=2.0, frames={frames} + 3)
tw = MitsubaTwin(rig, sc.assembly)
for f in sc.frames[:3]:
    tw.render(f)
t0, c0 = time.perf_counter(), time.process_time()
for f in sc.frames[3:]:
    tw.render(f)
print(json.dumps({{"ms": 1e3 * (time.perf_counter() - t0) / {frames},
                  "cpu_ms": 1e3 * (time.process_time() - c0) / {frames}}}))
"""


def ideal_ms(root: str, part: str, frames: int) -> tuple[float, float]:
    """Render-only (wall, CPU) ms/frame of the ideal twin of checkout ``root`` (fresh process)."""
    code = _IDEAL.format(root=str(root), part=part, frames=frames)
    env = dict(os.environ, PYTHONPATH=str(root))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                         check=True).stdout
    r = json.loads(out.strip().splitlines()[-1])
    return r["ms"], r["cpu_ms"]


def realistic(part: str, frames: int) -> None:
    from scheimpflug.model.rig import load_preset
    from sim.scenarios import rotary_scenario
    from sim.writer import MitsubaTwin, build_manifest, render_scenario

    rig = load_preset("paper").replace(twin={"bounces": 3, "subsurface": True},
                                       laser={"speckle_contrast": 0.7})
    warm = rotary_scenario(rig, part=part, step_deg=2.0, frames=3, truth_pixels_every=0)
    twin = MitsubaTwin(rig, warm.assembly)
    with tempfile.TemporaryDirectory() as tmp:                 # JIT kernels, numba caches
        render_scenario(rig, warm, Path(tmp) / "w", twin,
                        build_manifest(rig, warm, 0, twin.spp, twin.variant), warn=lambda m: None)
    scenario = rotary_scenario(rig, part=part, step_deg=2.0, frames=frames, truth_pixels_every=0)
    twin.renderer.timings = dict.fromkeys(twin.renderer.timings, 0.0)
    c0, t0 = time.process_time(), time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        stats = render_scenario(rig, scenario, Path(tmp) / "scan", twin,
                                build_manifest(rig, scenario, 0, twin.spp, twin.variant),
                                warn=lambda m: None)
    cpu = (time.process_time() - c0) / frames
    wall = (time.perf_counter() - t0) / frames
    print(f"\nrealistic frame loop, {part}, {frames} frames at full resolution "
          f"(bounces 3, subsurface, surface speckle 0.7, noise, PNG, stripe truth):")
    print(f"  {1e3 * wall:.0f} ms/frame = {1 / wall:.2f} frames/s; CPU of all threads "
          f"{1e3 * cpu:.0f} ms/frame (on 2 otherwise idle cores ≥ {0.5e3 * cpu:.0f} ms/frame wall)")
    parts = {**{f"render: {k}": v for k, v in twin.renderer.timings.items()},
             **{k: v for k, v in stats.seconds.items() if k != "render" and v > 0}}
    other = stats.seconds["render"] - sum(twin.renderer.timings.values())
    parts["render: other (pose, Python)"] = other
    clock = "CPU" if sim_clock_is_cpu() else "wall"
    print(f"  stages ({clock} time; shares of the loop's {clock} time):")
    for name, sec in parts.items():
        print(f"  {name:34s} {1e3 * sec / frames:7.1f} ms/frame  {100 * sec / stats.wall_s:5.1f} %")


def _rss_bytes(pid: int) -> int:
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


def _peak_rss_sampler(peak: list, stop) -> None:
    """Keep ``peak[0]`` the largest RSS of this process plus its live children [B]."""
    import multiprocessing

    while not stop.wait(0.1):
        now = _rss_bytes(os.getpid()) + sum(_rss_bytes(p.pid) for p in multiprocessing.active_children())
        peak[0] = max(peak[0], now)


def folder_run(part: str, frames: int, workers: int, ideal: bool = False) -> dict:
    """One render through render_folder in this process (``--folder-run``): times, RSS.

    Realistic twin (3 bounces, subsurface, surface speckle 0.7), or the ``[twin]`` defaults.
    """
    import threading

    from scheimpflug.model.rig import load_preset
    from sim.writer import render_folder

    rig = load_preset("paper")
    if not ideal:
        rig = rig.replace(twin={"bounces": 3, "subsurface": True}, laser={"speckle_contrast": 0.7})
    stamps, peak, stop = [], [0], threading.Event()
    sampler = threading.Thread(target=_peak_rss_sampler, args=(peak, stop), daemon=True)
    sampler.start()
    t0, c0 = time.perf_counter(), time.process_time()
    with tempfile.TemporaryDirectory() as tmp:
        render_folder(rig, "rotary", Path(tmp) / "scan", seed=0, warn=lambda m: None,
                      progress=lambda d, t: stamps.append(time.perf_counter()), workers=workers,
                      part=part, step_deg=2.0, frames=frames, truth_pixels_every=0)
    wall = time.perf_counter() - t0
    stop.set()
    sampler.join()
    warm = 2 * workers                      # stamps[k] = time frame k was written (stamps[0]: start)
    rate = (frames - warm) / (stamps[frames] - stamps[warm])
    return {"workers": workers, "wall_s": wall, "frames_per_s": rate, "peak_rss_gb": peak[0] / 1e9,
            "main_cpu_s": time.process_time() - c0}


def folder_runs(part: str, frames: int, workers: int, ideal: bool = False) -> None:
    """render_folder with 1 and ``workers`` workers, alternated twice, each in a fresh process."""
    here = Path(__file__).resolve()
    print(f"\nrender_folder, {'ideal' if ideal else 'realistic'} {part}, {frames} full frames (as "
          f"`scheimpflug render --workers N` writes them), fresh process per run, load {os.getloadavg()}:")
    for n in (1, workers, 1, workers):
        out = subprocess.run([sys.executable, str(here), "--folder-run", str(n), "--frames", str(frames),
                              "--part", part] + (["--ideal-twin"] if ideal else []),
                             capture_output=True, text=True, check=True).stdout
        r = json.loads(out.strip().splitlines()[-1])
        print(f"  workers {n}: {r['frames_per_s']:.2f} frames/s after {2 * n} warm-up frames "
              f"({1e3 / r['frames_per_s']:.0f} ms/frame); whole render {r['wall_s']:.1f} s "
              f"({frames / r['wall_s']:.2f} frames/s with start-up); peak RSS (main + workers) "
              f"{r['peak_rss_gb']:.2f} GB; load now {os.getloadavg()[0]:.2f}")


def sim_clock_is_cpu() -> bool:
    """Whether :func:`cpu_stage_clocks` is in effect."""
    import sim.render

    return sim.render.time.perf_counter is time.process_time


def cpu_stage_clocks() -> None:
    """Make the renderer's and the frame loop's stage timers read process CPU time."""
    import types

    import sim.render
    import sim.writer

    clock = types.SimpleNamespace(perf_counter=time.process_time, process_time=time.process_time,
                                  time=time.time, sleep=time.sleep)
    sim.render.time = clock
    sim.writer.time = clock


def reflectances() -> None:
    import mitsuba as mi

    from sim.materials import TRANSLUCENT
    from sim.subsurface import total_reflectance
    from sim.variant import select_variant

    mi.set_variant(select_variant())
    print("\ntotal diffuse reflectance at normal incidence (2e5 paths, walks ≤ 1024 events):")
    for tag, medium in TRANSLUCENT.items():
        print(f"  {tag:14s} R = {total_reflectance(medium, 200_000, max_steps=1024):.3f}   "
              f"(opaque stand-in albedo {medium.albedo})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--part", default="pile")
    ap.add_argument("--baseline", default=None, help="another checkout to time the ideal path of")
    ap.add_argument("--skip-ideal", action="store_true")
    ap.add_argument("--cpu", action="store_true",
                    help="stage shares of the realistic loop in CPU time of all threads "
                         "(for a loaded machine) instead of wall time")
    ap.add_argument("--skip-loop", action="store_true", help="skip the in-process realistic loop")
    ap.add_argument("--workers", type=int, default=None,
                    help="also time render_folder with 1 and this many worker processes")
    ap.add_argument("--folder-run", type=int, default=None, help=argparse.SUPPRESS)
    ap.add_argument("--ideal-twin", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.folder_run is not None:
        print(json.dumps(folder_run(args.part, args.frames, args.folder_run, args.ideal_twin)))
        return
    if args.cpu:
        cpu_stage_clocks()
    print(f"load average at start: {os.getloadavg()}")
    here = Path(__file__).resolve().parents[1]
    if not args.skip_ideal:
        runs = {"this": [], "baseline": []}
        for _ in range(2):
            runs["this"].append(ideal_ms(here, args.part, args.frames))
            if args.baseline:
                runs["baseline"].append(ideal_ms(Path(args.baseline).resolve(), args.part, args.frames))
        print(f"ideal path, {args.part}, render only, full resolution ({args.frames} frames × 2):")
        for k, v in runs.items():
            if v:
                print(f"  {k:9s} wall {' / '.join(f'{x[0]:.1f}' for x in v)} ms/frame,"
                      f" CPU {' / '.join(f'{x[1]:.1f}' for x in v)} ms/frame")
    t0 = time.perf_counter()
    if not args.skip_loop:
        realistic(args.part, args.frames)
    if args.workers:
        folder_runs(args.part, args.frames, args.workers)
        if not args.skip_ideal:
            folder_runs(args.part, args.frames, args.workers, ideal=True)
    reflectances()
    print(f"\nload average at end: {os.getloadavg()} ({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
