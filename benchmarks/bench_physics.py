"""Figures of the twin's physical light (issue 10) that the tests check only as pass/fail.

Prints, at full paper resolution unless said otherwise:

1. marble (Jensen et al.'s medium) — the stripe's RMS width and the stripe-centre bias of
   three detectors against the geometric truth, as a distance along the sheet [µm], for
   the calibration plate turned by 0–45° (Godin et al. 2001 measured ≈ 40 µm on marble);
   the same for cardboard;
2. speckle — stripe-centre scatter vs Dorsch, Häusler & Herrmann's δz = λ/(2π·sin u·sin θ)
   at three distances: the paper rig (f/5.6, 150 µm sheet focused at 640 mm) and f/16 with
   the sheet focused on the plate (the regime of their derivation);
3. speckle statistics on a uniformly lit plate (4 × 4 binned): contrast before pixel
   integration, grain (half width of the autocovariance / 0.4217) vs 1.22·λ·N·(1 + m).

    .venv/bin/python benchmarks/bench_physics.py [1] [2] [3]      (default: all three)
"""

from __future__ import annotations

import math
import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402
import trimesh  # noqa: E402

from scheimpflug.model.hinge import hinge_geometry  # noqa: E402
from scheimpflug.model.rig import load_preset  # noqa: E402
from scheimpflug.stripe import extract_stripes  # noqa: E402


def plate_pose(rig, distance_mm, yaw_deg=0.0, lift_mm=0.0):
    g = hinge_geometry(rig)
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    m = np.eye(4)
    m[:3, 0] = c * g.propagation_dir + s * g.sheet_normal
    m[:3, 1] = -s * g.propagation_dir + c * g.sheet_normal
    m[:3, 2] = [0.0, 0.0, 1.0]
    m[:3, 3] = g.object_hinge_mm + distance_mm * g.propagation_dir + [0.0, 0.0, lift_mm]
    return m


def translucent_bias() -> None:
    from sim.render import Renderer, RenderSettings
    from sim.scene import SimScene
    from sim.truth import BruteForceCaster, stripe_truth

    rig = load_preset("paper").replace(environment={"ambient_irradiance_w_m2": 0.0})
    g = hinge_geometry(rig)
    plate = trimesh.creation.box([30.0, 200.0, 40.0])
    plate.apply_translation([15.0, 0.0, 0.0])
    ids = np.ones(len(plate.faces), int)
    print("1. translucent plate at D = 600 mm: stripe RMS width [px] and centre bias along the sheet "
          "[µm] (subsurface − opaque stand-in)")
    for tag in ("marble", "cardboard"):
        r = {s: Renderer(rig.replace(twin={"subsurface": s}), SimScene([(plate, tag, 1)], subsurface=s),
                         RenderSettings(samples_per_row=64)) for s in (False, True)}
        for yaw in (0.0, 15.0, 30.0, 45.0):
            pose = plate_pose(rig, 600.0, yaw)
            truth = stripe_truth(rig, plate.vertices, plate.faces, ids, pose, pose, BruteForceCaster(
                plate.vertices @ pose[:3, :3].T + pose[:3, 3], plate.faces, ids))
            rows = np.nonzero(np.isfinite(truth.stripe_u))[0][20:-20]
            d_mm = float(g.distance_from_column(np.median(truth.stripe_u[rows])))
            mm_per_px = d_mm**2 / abs(g.F2_px_mm)
            line, width = f"   {tag:9s} yaw {yaw:4.0f}°:", {}
            img = {s: r[s].render(pose, 1).astype(np.float64) for s in (False, True)}
            cols = np.arange(img[True].shape[1])
            for s in (False, True):
                prof = img[s][rows]
                mean = (prof * cols).sum(1) / prof.sum(1)
                width[s] = np.median(np.sqrt((prof * (cols - mean[:, None]) ** 2).sum(1) / prof.sum(1)))
            line += f" width {width[False]:.2f} → {width[True]:.2f} px;"
            for method in ("gaussian3", "cog", "blais-rioux"):
                bias = []
                for s in (False, True):
                    # noiseless images: the flanks' "noise" is the halo's slope, so a low
                    # detection threshold (the default 6 loses most marble rows at 45°)
                    p = extract_stripes(img[s], method, window_px=6, min_snr=1.0)
                    ok = np.isin(p.rows, rows)
                    bias.append(np.median(p.u[ok] - truth.stripe_u[p.rows[ok]]))
                line += f" {method} {1e3 * (bias[1] - bias[0]) * mm_per_px:+5.0f}"
            print(line)


def dorsch() -> None:
    from sim.render import Renderer, RenderSettings
    from sim.scene import SimScene
    from sim.truth import laser_origin_mm

    print("\n2. speckle: stripe-centre scatter (cog ±6 px, speckle-free render as reference) vs "
          "Dorsch et al.'s δz")
    plate = trimesh.creation.box([5.0, 200.0, 40.0])
    plate.apply_translation([2.5, 0.0, 0.0])
    for f_number, focused in ((5.6, False), (16.0, True)):
        base = load_preset("paper").replace(lens={"f_number": f_number},
                                            laser={"speckle_contrast": 1.0},
                                            environment={"ambient_irradiance_w_m2": 0.0})
        g = hinge_geometry(base)
        for distance in (470.0, 585.0, 700.0):
            point = g.object_hinge_mm + distance * g.propagation_dir
            rig = base.replace(laser={"waist_distance_mm": float(np.linalg.norm(
                point - laser_origin_mm(base)))}) if focused else base
            pose = plate_pose(rig, distance)
            c = [extract_stripes(Renderer(rig, SimScene([(plate, "metal", 1)]), RenderSettings(
                speckle=s)).render(pose, 1), "cog", window_px=6) for s in (True, False)]
            rows, ia, ib = np.intersect1d(c[0].rows, c[1].rows, return_indices=True)
            du = (c[0].u[ia] - c[1].u[ib])[5:-5]
            d_mm = float(g.distance_from_column(np.median(c[1].u[ib])))
            dz = np.std(du) * d_mm**2 / abs(g.F2_px_mm)
            dist = np.linalg.norm(point)
            sin_u = 0.5 * rig.lens.focal_length_mm / rig.lens.f_number / dist
            sin_t = np.linalg.norm(np.cross(g.propagation_dir, -point / dist))
            ref = rig.laser.wavelength_nm * 1e-6 / (2 * math.pi * sin_u * sin_t)
            print(f"   f/{f_number:<4g} {'sheet focused on the plate' if focused else 'paper sheet':26s} "
                  f"D {d_mm:5.0f} mm: δu {np.std(du):.3f} px, δz {1e3 * dz:5.1f} µm, Dorsch "
                  f"{1e3 * ref:5.1f} µm, ratio {dz / ref:.2f}")


def statistics() -> None:
    from scheimpflug.model.binning import binned_rig
    from scheimpflug.model.camera import project_points, sensor_pose
    from sim.scene import SimScene
    from sim.speckle import SurfaceSpeckle

    rig = binned_rig(load_preset("paper"), 4)
    g = hinge_geometry(rig)
    point = g.object_hinge_mm + 600.0 * g.propagation_dir
    n = -point / np.linalg.norm(point)
    pose = np.eye(4)
    pose[:3, 0] = -n
    pose[:3, 1] = np.cross([0.0, 0.0, 1.0], -n) / np.linalg.norm(np.cross([0.0, 0.0, 1.0], -n))
    pose[:3, 2] = np.cross(pose[:3, 0], pose[:3, 1])
    pose[:3, 3] = point
    plate = trimesh.creation.box([2.0, 200.0, 200.0])
    plate.apply_translation([1.0, 0.0, 0.0])
    scene = SimScene([(plate, "metal", 1)])
    scene.set_pose(pose)
    model = SurfaceSpeckle(rig, sensor_pose(rig), scene, seed=3)
    u, v = project_points(rig, point).uv_px
    img = np.zeros((rig.sensor.rows, rig.sensor.columns), np.float32)
    r0, c0 = int(v) - 24, int(u) - 24
    img[r0:r0 + 48, c0:c0 + 48] = 100.0
    pix = model.pixel_speckle(img, keep_fine=True)
    s = model.fine
    tiles = model.last_fine
    tr0, tc0 = min(k[0] for k in tiles), min(k[1] for k in tiles)
    mosaic = np.zeros(((max(k[0] for k in tiles) - tr0 + 1) * 16 * s, (max(k[1] for k in tiles) - tc0 + 1) * 16 * s))
    for (tr, tc), fine in tiles.items():
        mosaic[(tr - tr0) * 16 * s:(tr - tr0 + 1) * 16 * s, (tc - tc0) * 16 * s:(tc - tc0 + 1) * 16 * s] = fine
    a, b = (r0 + 2 - tr0 * 16) * s, (c0 + 2 - tc0 * 16) * s
    field = mosaic[a:a + 44 * s, b:b + 44 * s]
    x = field - field.mean()
    acov = np.real(np.fft.ifft2(np.abs(np.fft.fft2(x)) ** 2))
    acov /= acov[0, 0]

    def hwhm(p):
        i = int(np.argmax(p < 0.5))
        return (i - 1) + (p[i - 1] - 0.5) / (p[i - 1] - p[i])

    f = rig.lens.focal_length_mm
    grain = model.grain_px(f / (point[0] - f))
    block = pix[r0 + 4:r0 + 44, c0 + 4:c0 + 44]
    print(f"\n3. speckle on a uniformly lit plate (4 × 4 binned, {s} × {s} fine samples per pixel): "
          f"contrast {field.std() / field.mean():.3f} before and {block.std() / block.mean():.3f} "
          f"after pixel integration; grain along the rows {hwhm(acov[:, 0]) / s / 0.4217:.4f} px, "
          f"along the columns {hwhm(acov[0, :]) / s / 0.4217:.4f} px, formula {grain:.4f} px "
          f"(columns longer by the sensor tilt's 1/cos ψ)")


def main() -> None:
    parts = {"1": translucent_bias, "2": dorsch, "3": statistics}
    print(f"load average: {os.getloadavg()}")
    for key in (sys.argv[1:] or list(parts)):
        parts[key]()


if __name__ == "__main__":
    main()
