"""Render-core speed and stripe-centre render noise (sim.render), paper rig, full resolution.

Prints, for each laser sample count (RenderSettings.samples_per_row):
  * the stripe-centre Monte Carlo noise: the same calibration plate (Lambertian, ambient
    off) rendered with different seeds; per row the windowed centre of gravity (±12 px
    around the row maximum); its std over seeds, averaged over the lit rows, at the near
    end, mid-range and far end of the depth range (and the worst row);
  * frames/s of Renderer.render (laser + ambient, expected electrons, no sensor noise or
    PNG) for the plate and for the paper cylinder (scenes preset, 1.1 M triangles) turning
    on the rotary stage, with the share of each stage of the frame.

    .venv/bin/python benchmarks/bench_render.py [--spp 16 32 64] [--frames 40] [--seeds 6]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import trimesh

from scheimpflug.model.hinge import hinge_geometry
from scheimpflug.model.rig import load_preset


def plate_pose(rig, distance_mm):
    g = hinge_geometry(rig)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2] = g.propagation_dir, g.sheet_normal, [0.0, 0.0, 1.0]
    m[:3, 3] = g.object_hinge_mm + distance_mm * g.propagation_dir \
        + rig.stage.calibration_table_z_mm * np.array([0.0, 0.0, 1.0])
    return m


def plate_part():
    m = trimesh.creation.box([5.0, 200.0, 89.0])
    m.apply_translation([2.5, 0.0, 44.5])
    return [(m, "tape", 1)]


def cog(img, w=12):
    u0 = np.argmax(img, axis=1)
    cols = np.clip(u0[:, None] + np.arange(-w, w + 1), 0, img.shape[1] - 1)
    v = np.take_along_axis(img, cols, 1).astype(np.float64)
    s = v.sum(1)
    return (v * cols).sum(1) / np.where(s > 0, s, 1.0), img.max(1)


def noise(rig, spp, seeds):
    from sim.render import Renderer, RenderSettings
    from sim.scene import SimScene

    dark = rig.replace(environment={"ambient_irradiance_w_m2": 0.0})
    r = Renderer(dark, SimScene(plate_part()), RenderSettings(samples_per_row=spp))
    g = hinge_geometry(rig)
    out = []
    for u in (60.0, 608.0, 1150.0):
        D = float(g.distance_from_column(u))
        cs, pk = zip(*(cog(r.render(plate_pose(rig, D), seed)) for seed in range(seeds)))
        cs = np.array(cs)
        peak = np.array(pk)[0]
        lit = np.nonzero(peak > 0.3 * np.median(peak[peak > 0]))[0][2:-2]
        std = cs[:, lit].std(0, ddof=1)
        out.append((u, D, std.mean(), std.max(), float(np.median(peak[lit]))))
    return out


def timed(fn, n):
    fn(0)
    t0 = time.perf_counter()
    for k in range(n):
        fn(k + 1)
    return (time.perf_counter() - t0) / n


def fps(rig, parts, poses, spp, frames):
    from sim.render import Renderer, RenderSettings
    from sim.scene import SimScene

    t0 = time.perf_counter()
    scene = SimScene(parts)
    build = time.perf_counter() - t0
    r = Renderer(rig, scene, RenderSettings(samples_per_row=spp))
    t_frame = timed(lambda k: r.render(poses[k % len(poses)], k), frames)

    def laser(k):
        scene.set_pose(poses[k % len(poses)])
        r._frame = scene.transforms_dr()
        r._laser_splats(r._key(k))

    def ambient(k):
        scene.set_pose(poses[k % len(poses)])
        r._frame = scene.transforms_dr()
        r._ambient_image(r._key(k))

    return build, t_frame, timed(laser, frames), timed(ambient, frames)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spp", type=int, nargs="+", default=[16, 32, 64])
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--seeds", type=int, default=6)
    ap.add_argument("--no-cylinder", action="store_true")
    args = ap.parse_args()
    from sim.variant import select_variant

    print(f"variant: {select_variant()}")
    rig = load_preset("paper")
    plate_poses = [plate_pose(rig, D) for D in np.linspace(460.0, 710.0, 16)]
    cyl = None
    if not args.no_cylinder:
        from scenes import load_part
        from sim.stages import rig_from_stage, stage_from_part

        parts = load_part("cylinder").parts
        cyl_poses = [rig_from_stage(rig) @ stage_from_part(rig, 0.5 * k) for k in range(720)]
        cyl = (parts, cyl_poses, sum(len(p.mesh.faces) for p in parts))
    for spp in args.spp:
        print(f"\n== samples_per_row = {spp}  (laser rays/frame ≈ {spp * rig.sensor.rows})")
        for u, D, mean_std, max_std, peak in noise(rig, spp, args.seeds):
            print(f"  stripe-centre render noise, plate at u={u:6.1f} (D={D:6.1f} mm): "
                  f"mean std {mean_std:.4f} px, worst row {max_std:.4f} px, "
                  f"peak {peak:.0f} e- (tape, albedo 0.55)")
        b, t, tl, ta = fps(rig, plate_part(), plate_poses, spp, args.frames)
        print(f"  plate   : {1 / t:6.1f} frames/s ({t * 1e3:.1f} ms/frame: laser pass "
              f"{tl * 1e3:.1f} ms, ambient pass {ta * 1e3:.1f} ms, rest {(t - tl - ta) * 1e3:.1f} ms)")
        if cyl is not None:
            b, t, tl, ta = fps(rig, cyl[0], cyl[1], spp, args.frames)
            print(f"  cylinder: {1 / t:6.1f} frames/s ({t * 1e3:.1f} ms/frame: laser pass "
                  f"{tl * 1e3:.1f} ms, ambient pass {ta * 1e3:.1f} ms, rest "
                  f"{(t - tl - ta) * 1e3:.1f} ms); scene build {b:.2f} s for {cyl[2]} triangles")


if __name__ == "__main__":
    main()
