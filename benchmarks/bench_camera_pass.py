"""Speed and noise of the camera pass (sim.camera_pass) on a full paper frame (1216 × 1936).

    .venv/bin/python benchmarks/bench_camera_pass.py [--repeat 5] [--threads N]

Scenes, each lit by the environment (1 W/m²) and the flood light (20 W/m²):

* ``pattern``  — the 10 × 8 chessboard of 7 mm in the sheet (most rays miss it: the cheap case);
* ``wall``     — a matte textured wall filling the view (every ray hits, every shadow ray is cast);
* ``cylinder`` — the paper's knurled cylinder (1.09 M triangles) on the rotary table.

Per scene: the median wall time of one frame at 1 sample per pixel over ``--repeat`` frames
(after one frame of warm-up: compiling the kernel), split into the kernel launches
(``trace``: ray generation, intersection, shading, shadow rays, accumulation) and the
read-out to numpy (``readout``); the same without the flood light (no next-event shadow ray);
then 16 spp.  Noise: the relative scatter of a flood-lit
uniform white plate (pixels minus a 9 × 9 box mean) at 1, 4, 16, 64 spp.  The machine's
load average is printed before and after (other processes share the cores).
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import numpy as np
import trimesh

from scheimpflug.model.camera import sensor_pose
from scheimpflug.model.hinge import hinge_geometry
from scheimpflug.model.rig import load_preset


def _facing(origin, x, y):
    m = np.eye(4)
    x = np.asarray(x, float) / np.linalg.norm(x)
    y = np.asarray(y, float) - (np.asarray(y, float) @ x) * x
    y /= np.linalg.norm(y)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = x, y, np.cross(x, y), origin
    return m


class _Wall:
    def __init__(self):
        from scenes.patterns import parse_pattern

        self.mesh = trimesh.creation.box([2000.0, 2000.0, 2.0])
        self.texture = parse_pattern("chessboard:200x200:10").texture()
        self.uv_mm = np.asarray(self.mesh.vertices)[:, :2] + 1000.0
        self.material, self.object_id, self.name = "paper", 1, "wall"


def _scenes(rig):
    from scenes.patterns import target_assembly
    from sim.scenarios import build_scenario

    g = hinge_geometry(rig)
    base = g.rig_from_sheet(600.0, 0.0)
    n = g.sheet_normal if g.sheet_normal @ -base > 0 else -g.sheet_normal
    x = g.propagation_dir
    y = np.cross(-n, x)
    target = target_assembly("chessboard:10x8:7")
    yield "pattern", target.parts, _facing(base - 35.0 * x - 28.0 * y, x, y)
    yield "wall", [_Wall()], _facing(base + 300.0 * x - 400.0 * n, n, [0.0, 0.0, -1.0])
    cyl = build_scenario("rotary", rig, part="cylinder", step_deg=90.0, truth_pixels_every=0)
    yield "cylinder", cyl.assembly.parts, cyl.frames[0].rig_from_part


def _time(cp, pose, repeat):
    cp.render(pose, seed=0)                      # warm-up: the kernel is compiled once
    walls, trace, readout = [], [], []
    for k in range(repeat):
        t = dict(cp.timings)
        t0 = time.perf_counter()
        cp.render(pose, seed=k + 1)
        walls.append(time.perf_counter() - t0)
        trace.append(cp.timings["trace"] - t["trace"])
        readout.append(cp.timings["readout"] - t["readout"])
    return statistics.median(walls), statistics.median(trace), statistics.median(readout)


def _noise(rig, spp_list):
    from scipy import ndimage

    from sim.camera_pass import CameraPass, CameraSettings, sensor_window
    from sim.scene import SimScene

    g = hinge_geometry(rig)
    box = trimesh.creation.box([400.0, 400.0, 2.0])
    scene = SimScene([(box, "tape", 1)])
    pose = sensor_window(sensor_pose(rig), 300, 700, 300, 200)
    part = _facing(g.rig_from_sheet(600.0, 0.0), g.propagation_dir, [0.0, 0.0, -1.0])
    out = []
    for spp in spp_list:
        img = CameraPass(rig, scene, CameraSettings(spp=spp, pixel_filter="box"), pose=pose).render(part, seed=1)
        smooth = ndimage.uniform_filter(img.astype(np.float64), 9)
        out.append((spp, float(((img - smooth) / smooth)[10:-10, 10:-10].std())))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--threads", type=int, default=0, help="Dr.Jit threads (0 = all cores)")
    args = ap.parse_args()
    import drjit as dr

    from sim.camera_pass import CameraPass, CameraSettings
    from sim.scene import SimScene

    if args.threads:
        dr.set_thread_count(args.threads)
    print(f"cores {os.cpu_count()}, Dr.Jit threads {dr.thread_count()}, load average before "
          f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    rig = load_preset("paper").replace(environment={"ambient_irradiance_w_m2": 1.0, "flood_irradiance_w_m2": 20.0})
    print("| scene | triangles | 1 spp frame [ms] | trace [ms] | readout [ms] | 1 spp, no flood light [ms] | "
          "16 spp frame [ms] |")
    print("|---|---|---|---|---|---|---|")
    for name, parts, pose in _scenes(rig):
        scene = SimScene(parts)
        tri = sum(len(sp.faces) for sp in scene.specs)
        one = _time(CameraPass(rig, scene, CameraSettings(spp=1)), pose, args.repeat)
        dark = _time(CameraPass(rig, scene, CameraSettings(spp=1), flood=None), pose, args.repeat)
        many = _time(CameraPass(rig, scene, CameraSettings(spp=16)), pose, max(1, args.repeat // 2))
        print(f"| {name} | {tri:,} | {one[0] * 1e3:.0f} | {one[1] * 1e3:.0f} | {one[2] * 1e3:.0f} | "
              f"{dark[0] * 1e3:.0f} | {many[0] * 1e3:.0f} |", flush=True)
    print("noise of a flood-lit white plate (relative scatter per pixel):",
          ", ".join(f"{spp} spp {v * 100:.2f} %" for spp, v in _noise(rig, (1, 4, 16, 64))))
    print(f"load average after {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
