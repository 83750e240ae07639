"""The OpenCV export with a distorting lens: lengths in the camera frame against the pipeline's (issue 25).

    python benchmarks/bench_opencv_metric.py [--binning 4] [--out DIR]

Renders the calibration plate on the paper rig with k1 = −0.05, k1 = −0.05 and a 0.5° sensor
roll, and k1 = −0.2; calibrates each (`calibrate --model auto --opencv`), then measures every
frame's plate height (top to bottom edge) twice: through OpenCV as a user would
(`cv2.undistortPoints` with the default criteria, the ray met with `laser_plane`, the distance
of the two camera-frame points) and through the pipeline (`stage_from_pixel`, the distance on
the sheet).  Prints the mean and largest difference, the plate's 89 mm as a reference, and how
far the exported sheet axes are from orthonormal.
"""

import argparse
import json
import tempfile
from pathlib import Path

import cv2
import numpy as np

RIGS = {"k1 −0.05": "[lens]\nk1 = -0.05\n", "k1 −0.05, roll 0.5°": "[lens]\nk1 = -0.05\n[sensor]\nroll_deg = 0.5\n",
        "k1 −0.2": "[lens]\nk1 = -0.2\n"}


def _camera_points(d: dict, uv: np.ndarray) -> np.ndarray:
    a, b, c, dd = d["laser_plane"]
    xy = cv2.undistortPoints(uv.reshape(-1, 1, 2), np.array(d["camera_matrix"]),
                             np.array(d["dist_coeffs"])).reshape(-1, 2)
    ray = np.column_stack([xy, np.ones(len(xy))])
    return ray * (-dd / (ray @ [a, b, c]))[:, None]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--binning", type=int, default=4)
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    from scheimpflug.app.cli import main as cli
    from scheimpflug.calibration import load_calibration, measure_plate_frame
    from scheimpflug.io.frames import open_frame_folder

    root = Path(args.out or tempfile.mkdtemp())
    root.mkdir(parents=True, exist_ok=True)
    print(f"binning {args.binning}; plate height through OpenCV (camera frame) minus through the pipeline [mm]")
    for k, (name, text) in enumerate(RIGS.items()):
        key = f"rig{k}"
        (root / f"{key}.toml").write_text(text)
        folder, cal, cv = root / key, root / f"{key}.json", root / f"{key}_cv.json"
        cli(["render", "calibration", "--rig", str(root / f"{key}.toml"), "--binning", str(args.binning),
             "--truth-pixels", "none", "--quiet", "--out", str(folder)])
        cli(["calibrate", str(folder), "--quiet", "--out", str(cal), "--opencv", str(cv), "--force"])
        d, model = json.loads(cv.read_text()), load_calibration(cal)
        ff = open_frame_folder(folder)
        diff, height = [], []
        for i, rec in enumerate(ff.frames):
            frame = ff.read(i)
            m = measure_plate_frame(frame, rec.stage_mm, saturation_dn=ff.saturation_dn(frame))
            if m.top_px is None or m.bottom_px is None:
                continue
            uv = np.array([m.top_px, m.bottom_px])
            x = _camera_points(d, uv)
            s, h = model.stage_from_pixel(uv[:, 0], uv[:, 1])
            sheet = float(np.hypot(s[0] - s[1], h[0] - h[1]))
            diff.append(float(np.linalg.norm(x[0] - x[1])) - sheet)
            height.append(sheet)
        diff = np.array(diff)
        print(f"{name:20s} model {getattr(model, 'method', '?'):8s} frames {len(diff):2d}  camera − pipeline "
              f"mean {diff.mean():+.4f}, largest {diff[np.argmax(np.abs(diff))]:+.4f} mm "
              f"({100 * diff.mean() / np.mean(height):+.3f} %); pipeline plate {np.mean(height):.3f} mm; "
              f"sheet axes off orthonormal by {d['sheet_frame'].get('metric_error', float('nan')):.2g}")


if __name__ == "__main__":
    main()
