"""OpenCV's chessboard corners on the twin's flood-lit target frames, against the truth and the blur.

    .venv/bin/python benchmarks/bench_target_corners.py [--poses 12] [--spp 64] [--tilt-deg 35]
        [--pattern chessboard:8x6:6]

The paper rig, a board that fits its 110 mm tall view (default ``chessboard:8x6:6``), hand-held poses of
``sim.target.target_scenario`` (seed 5), sensor noise off: each pose's flood-lit frame is rendered by
the camera pass (``--spp`` samples per pixel, box pixels, a window around the board), the board is
found by ``cv2.findChessboardCorners`` and refined by ``cv2.cornerSubPix`` (11 × 11 window).
Per pose: the corners' mean blur extent (``pattern_blur_px``, the thin-lens circle of confusion
along the columns), the RMS of the detected corners against ``pattern_corners_px`` (the chief ray)
and against ``pattern_centroid_px`` (the light centroid of each corner's blur spot), and how far
those two truths lie apart.  First the in-focus poses (tilt 0, in the sheet), then tilted ones.
"""

from __future__ import annotations

import argparse

import cv2
import numpy as np

from scenes.patterns import parse_pattern
from scheimpflug.model.camera import sensor_pose
from scheimpflug.model.rig import load_preset


def _rows(rig, spec, sc, spp):
    from sim.camera_pass import CameraPass, CameraSettings, sensor_window
    from sim.scene import SimScene
    from sim.target import pattern_truth
    from sim.truth import SceneCaster

    scene = SimScene(sc.assembly.parts)
    lit = rig.replace(environment={"flood_irradiance_w_m2": 0.0, "ambient_irradiance_w_m2": 30.0})
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-4)
    for f in sc.frames:
        scene.set_pose(f.rig_from_part)
        t = pattern_truth(rig, sc, f, SceneCaster(scene), {})
        truth, centroid, blur = t["pattern_corners_px"], t["pattern_centroid_px"], t["pattern_blur_px"]
        if not np.isfinite(truth).all():
            yield f.pose_index, None
            continue
        lo = np.maximum(np.floor(truth.min(0)).astype(int) - 60, 0)
        hi = np.minimum(np.ceil(truth.max(0)).astype(int) + 60, [rig.sensor.columns, rig.sensor.rows])
        window = sensor_window(sensor_pose(rig), int(lo[0]), int(lo[1]), int(hi[0] - lo[0]), int(hi[1] - lo[1]))
        img = CameraPass(lit, scene, CameraSettings(spp=spp, pixel_filter="box"), pose=window).render(
            f.rig_from_part, f.seed)
        g8 = np.clip(img / np.percentile(img, 99.5) * 240, 0, 255).astype(np.uint8)
        found, start = cv2.findChessboardCorners(g8, spec.grid_shape)
        if not found:
            yield f.pose_index, ("not found", float(np.mean(blur)))
            continue
        c = cv2.cornerSubPix((img / img.max()).astype(np.float32), start, (11, 11), (-1, -1), crit).reshape(-1, 2) + lo
        k = np.linalg.norm(c[:, None] - truth[None], axis=2).argmin(1)

        def rms(a, b):
            return float(np.sqrt(((a - b) ** 2).sum(1).mean()))

        yield f.pose_index, (float(np.mean(blur)), rms(c, truth[k]), rms(c, centroid[k]),
                             float(np.max(np.linalg.norm(truth - centroid, axis=1))))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--poses", type=int, default=12)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--tilt-deg", type=float, default=35.0)
    ap.add_argument("--pattern", default="chessboard:8x6:6")
    args = ap.parse_args()
    from sim.target import target_scenario

    rig = load_preset("paper").replace(environment={"flood_irradiance_w_m2": 20.0})
    spec = parse_pattern(args.pattern)
    for title, tilt, off in (("in focus (in the sheet)", 0.0, 0.0), (f"hand-held, tilts ±{args.tilt_deg:g}°",
                                                                       args.tilt_deg, 5.0)):
        sc = target_scenario(rig, seed=5, pattern=spec.text, poses=args.poses, tilt_deg=tilt, off_sheet_mm=off,
                             lights=("flood",))
        print(f"{title}: pose | mean blur [px] | RMS vs chief ray [px] | RMS vs blur centroid [px] | "
              "max |chief ray − centroid| [px]")
        for pose, row in _rows(rig, spec, sc, args.spp):
            if row is None:
                print(f"  {pose:2d} | partly out of view")
            elif row[0] == "not found":
                print(f"  {pose:2d} | {row[1]:.1f} | OpenCV finds no board")
            else:
                print(f"  {pose:2d} | {row[0]:.1f} | {row[1]:.4f} | {row[2]:.4f} | {row[3]:.4f}", flush=True)


if __name__ == "__main__":
    main()
