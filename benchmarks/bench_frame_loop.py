"""Today's frame loop against this checkout's, side by side in one run (issue 27).

Each measurement is a fresh process that imports the twin of one checkout (``--baseline
DIR``, e.g. an export of the commit before issue 27, or this checkout) and renders a
rotary scan exactly as ``scheimpflug render`` does — :func:`sim.writer.render_scenario`
with that checkout's default frame loop: render, sensor noise, 16-bit PNG, the exact
stripe truth (and, on the realistic twin, the secondary-light truth), no per-pixel truth
— into a fresh folder, after ``--warmup`` frames rendered into another one (JIT kernels,
numba caches, subsurface tables).  The two checkouts alternate (base, this, base, this,
…) so that the machine's load hits both; the ratios are taken run by run.

Printed per run and checkout: frames/s of the frame loop (wall) and the CPU time of all
the process's threads per frame (``time.process_time``), both in the steady state — from
the second frame written to the last, which leaves out the loop's set-up (this
checkout's truth sorts the mesh's faces once per run, ≈ 0.5–1.3 s for the cylinder) —
and for the whole loop ("all"); the frame loop's stages as
``RenderStats.seconds`` holds them (wall time of each stage; in a pipelined loop the
other threads' stages — ``finish``, the image finished on a second thread, ``png``,
``truth_write``, and the sheet's cut inside ``truth`` — overlap the render and do not
add up to the frame time; ``truth`` also holds the run's one-off face sort),
and the process's peak resident memory (``ru_maxrss``); the 1-minute load average at
the start of each measurement.

``--stages`` adds, per checkout, the CPU time (all threads) of each stage run alone
one after the other on the same frames: render, noise, truth, PNG encoding.

    .venv/bin/python benchmarks/bench_frame_loop.py --baseline /tmp/base --twin ideal --frames 60
    .venv/bin/python benchmarks/bench_frame_loop.py --baseline /tmp/base --twin realistic --frames 30
    python benchmarks/bench_frame_loop.py --baseline /tmp/base --binning 4 --part pile --step-deg 5 --frames 72

The twins: ``ideal`` — the ``paper`` preset (one bounce, opaque, no speckle), the paper
cylinder (1.09 M triangles) at 0.5° steps, as ``benchmarks/bench_scan.py``; ``realistic``
— the ``paper`` preset with ``[twin] bounces = 3``, ``subsurface = true`` and
``speckle_contrast`` 0.7 (surface speckle), the paper pile at 2° steps, as
``benchmarks/bench_optics.py``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

_CHILD = r"""
import json, os, resource, sys, tempfile, time
sys.path.insert(0, {root!r})
import numpy as np
from scheimpflug.model.rig import load_preset
from sim.scenarios import rotary_scenario
from sim.writer import MitsubaTwin, build_manifest, generator_info, render_scenario
from scheimpflug.model.binning import binned_rig
twin_kind, part, step, frames, warm, stages = {twin!r}, {part!r}, {step!r}, {frames}, {warm}, {stages}
rig = binned_rig(load_preset("paper"), {binning}) if {binning} > 1 else load_preset("paper")
if twin_kind == "realistic":
    rig = rig.replace(twin={{"bounces": 3, "subsurface": True}}, laser={{"speckle_contrast": 0.7}})
scenario = rotary_scenario(rig, part=part, step_deg=step, frames=warm + frames, truth_pixels_every=0)
twin = MitsubaTwin(rig, scenario.assembly)
warm_sc = rotary_scenario(rig, part=part, step_deg=step, frames=warm, truth_pixels_every=0)
import dataclasses
out = {{}}
with tempfile.TemporaryDirectory() as tmp:
    man = build_manifest(rig, warm_sc, 0, twin.spp, twin.variant, generator_info(), twin.describe())
    render_scenario(rig, warm_sc, os.path.join(tmp, "warm"), twin, man, warn=lambda m: None)
    main = dataclasses.replace(scenario, frames=scenario.frames[warm:])
    man = build_manifest(rig, main, 0, twin.spp, twin.variant, generator_info(), twin.describe())
    stamps = []
    t0, c0 = time.perf_counter(), time.process_time()
    stats = render_scenario(rig, main, os.path.join(tmp, "scan"), twin, man, warn=lambda m: None,
                            progress=lambda d, t: stamps.append((time.perf_counter(), time.process_time(), d)))
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    n = stats.frames_rendered
    (ta, ca, da), (tb, cb, db) = next(s for s in stamps if s[2] >= 2), stamps[-1]
    out.update(fps=(db - da) / (tb - ta), cpu_ms=1e3 * (cb - ca) / (db - da),
               wall_ms=1e3 * (tb - ta) / (db - da), fps_all=n / wall, cpu_ms_all=1e3 * cpu / n,
               stages_ms={{k: 1e3 * v / n for k, v in stats.seconds.items() if v > 0}})
if stages:
    from sim.writer import RenderStats, _frame_truth, _twin_light, encode_png16, scene_arrays
    from sim.sensor import SensorModel, apply_sensor, frame_rng
    mesh, model, st = scene_arrays(scenario), SensorModel.from_rig(rig), RenderStats()
    acc = np.zeros(4)
    sel = scenario.frames[warm:warm + min(frames, 12)]
    f0 = scenario.frames[0]
    twin.render(f0)
    _frame_truth(rig, scenario, f0, twin.caster(f0), st, mesh, _twin_light(twin, f0))   # per-run set-up
    for f in sel:
        t = [time.process_time()]
        e = twin.render(f); t.append(time.process_time())
        img = apply_sensor(e, model, frame_rng(f.seed, 0), None, 1.0); t.append(time.process_time())
        _frame_truth(rig, scenario, f, twin.caster(f), st, mesh, _twin_light(twin, f)); t.append(time.process_time())
        encode_png16(img); t.append(time.process_time())
        acc += np.diff(t)
    out["stage_cpu_ms"] = dict(zip(("render", "noise", "truth", "png"), (1e3 * acc / len(sel)).tolist()))
out["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print("RESULT " + json.dumps(out))
"""

_TWINS = {"ideal": ("cylinder", 0.5), "realistic": ("pile", 2.0)}


def measure(root: Path, twin: str, frames: int, warm: int, stages: bool, part: str | None,
            binning: int = 1, step_deg: float | None = None) -> dict:
    """One fresh process of checkout ``root``: the frame loop's figures (see the module docstring)."""
    default_part, step = _TWINS[twin]
    step = step_deg or step
    code = _CHILD.format(root=str(root), twin=twin, part=part or default_part, step=step, binning=binning,
                         frames=frames, warm=warm, stages=stages)
    load = os.getloadavg()[0]
    env = dict(os.environ, PYTHONPATH=str(root))
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                          cwd=str(root))
    line = next((x for x in proc.stdout.splitlines() if x.startswith("RESULT ")), None)
    if proc.returncode != 0 or line is None:
        raise SystemExit(f"measurement in {root} failed:\n{proc.stderr[-3000:]}")
    result = json.loads(line[len("RESULT "):])
    result["load"] = load
    return result


def _row(name: str, r: dict) -> str:
    st = ", ".join(f"{k} {v:.1f}" for k, v in r["stages_ms"].items())
    extra = ""
    if "stage_cpu_ms" in r:
        extra = "; alone, CPU ms: " + ", ".join(f"{k} {v:.1f}" for k, v in r["stage_cpu_ms"].items())
    return (f"  {name:5s} {r['fps']:6.2f} frames/s  {r['wall_ms']:6.1f} ms/frame wall  "
            f"{r['cpu_ms']:6.1f} ms/frame CPU  (all: {r['fps_all']:.2f} frames/s, "
            f"{r['cpu_ms_all']:.1f} ms CPU)  peak {r['peak_rss_mb']:6.0f} MB  (load {r['load']:.1f})\n"
            f"        stages, wall ms/frame: {st}{extra}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", required=True, type=Path,
                    help="checkout of today's code (e.g. 'git archive <commit> | tar -x -C DIR')")
    ap.add_argument("--twin", nargs="+", default=["ideal", "realistic"], choices=sorted(_TWINS))
    ap.add_argument("--frames", type=int, default=40, help="frames measured per run")
    ap.add_argument("--warmup", type=int, default=4, help="frames rendered first, not measured")
    ap.add_argument("--runs", type=int, default=2, help="alternating base/this pairs")
    ap.add_argument("--part", default=None, help="part (default: cylinder ideal, pile realistic)")
    ap.add_argument("--stages", action="store_true", help="also each stage's CPU time alone")
    ap.add_argument("--binning", type=int, default=1, help="k × k binned sensor (default 1: full frames)")
    ap.add_argument("--step-deg", type=float, default=None,
                    help="turn between frames (default: 0.5° ideal, 2° realistic)")
    args = ap.parse_args()
    print(f"{os.cpu_count()} cores; base = {args.baseline.resolve()}, this = {ROOT}")
    for twin in args.twin:
        size = "full" if args.binning == 1 else f"{args.binning} × {args.binning} binned"
        print(f"\n{twin} twin, {args.frames} {size} frames per run after {args.warmup} warm-up frames")
        ratios = []
        for k in range(args.runs):
            base = measure(args.baseline, twin, args.frames, args.warmup, args.stages, args.part,
                           args.binning, args.step_deg)
            this = measure(ROOT, twin, args.frames, args.warmup, args.stages, args.part,
                           args.binning, args.step_deg)
            print(f" run {k + 1}")
            print(_row("base", base))
            print(_row("this", this))
            ratios.append((this["fps"] / base["fps"], base["cpu_ms"] / this["cpu_ms"]))
            print(f"  this / base: {ratios[-1][0]:.2f}× frames/s, {ratios[-1][1]:.2f}× less CPU per frame")
        fps = sorted(r[0] for r in ratios)
        print(f" {twin}: frames/s ratio this/base over {len(ratios)} runs: "
              + ", ".join(f"{r:.2f}" for r in fps))
    print(f"\nload average at the end: {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
