"""A pattern-and-laser calibration in room light against the same poses in a dark room (issue 38).

    .venv/bin/python benchmarks/bench_room_light.py [--poses 20] [--binning 1] [--room-w-m2 170]
        [--pattern charuco:9x6:15:11] [--out DIR] [--figure docs/room_light_pose.png]

The paper rig, hand-held poses (``render target``, seed 0, D 520–650 mm, h ±15 mm), rendered twice:
in a dark room (flood frames with the flood light, laser frames with the laser only: the twin's
usual sets) and in room light (``--room-light``: the room's light in every frame at the flood
frames' exposure, as users take them).  Printed: how much the laser raises the board's brightest
pixels in room light (per pose: max of the laser frame over the 99.9th percentile of its laser-off
frame), and for each set and each ``--laser-background`` the laser plane against the twin's
(angle [deg], distance [mm]), the stated σ, the laser points and the poses whose line was found.
With ``--figure`` a room-light pose is drawn: its laser frame, its laser-off frame and their
difference.  The frame folders are kept in ``--out`` (rendered again only when absent).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import time
from pathlib import Path

import cv2
import numpy as np

from scheimpflug.app.cli import main


def _truth_plane(folder: Path) -> np.ndarray:
    from scheimpflug.model.rig import rig_from_dict
    from sim.truth import opencv_laser_plane

    return opencv_laser_plane(rig_from_dict(json.loads((folder / "manifest.json").read_text())["rig"]))


def _render(out: Path, args, *extra) -> Path:
    if not (out / "manifest.json").exists() or not json.loads((out / "manifest.json").read_text())["complete"]:
        t = time.perf_counter()
        assert main(["render", "target", "--preset", "paper", "--pattern", args.pattern, "--binning",
                     str(args.binning), "--poses", str(args.poses), "--depth-range-mm", "520:650",
                     "--height-range-mm=-15:15", "--quiet", "--out", str(out), *extra]) == 0
        print(f"rendered {out.name} in {time.perf_counter() - t:.0f} s")
    return out


def _raised(folder: Path) -> list[float]:
    frames = json.loads((folder / "manifest.json").read_text())["frames"]
    out = []
    for flood, laser in zip(frames[::2], frames[1::2]):
        f = cv2.imread(str(folder / flood["file"]), cv2.IMREAD_UNCHANGED).astype(float)
        g = cv2.imread(str(folder / laser["file"]), cv2.IMREAD_UNCHANGED).astype(float)
        out.append(g.max() / np.percentile(f, 99.9) - 1.0)
    return out


def _calibrate(folder: Path, args, background: str) -> None:
    cal = folder.parent / f"{folder.name}-{background}.json"
    t = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()):
        code = main(["calibrate", str(folder), "--method", "target", "--pattern", args.pattern, "--laser-background",
                     background, "--out", str(cal), "--force", "--quiet"])
    took = time.perf_counter() - t
    if code != 0:
        print(f"  {folder.name:6s} --laser-background {background:4s}: refused (exit {code}), {took:.0f} s")
        return
    d = json.loads(cal.read_text())
    truth, pl, se = _truth_plane(folder), np.array(d["laser_plane"]), d["stderr"]
    ang = math.degrees(math.acos(min(1.0, abs(pl[:3] @ truth[:3]))))
    lines = sum(1 for r in d["laser_poses"] if (r["points_in_plane_fit"] or 0) > 0)
    sigma = (f"σ {se['laser_plane_normal_deg']:.4f}°, {se['laser_plane_distance_mm']:.4f} mm"
             if "laser_plane_normal_deg" in se else "no σ: fewer than 3 poses")
    print(f"  {folder.name:6s} --laser-background {background:4s}: plane {ang:.4f}° and {pl[3] - truth[3]:+.4f} mm "
          f"from the twin's ({sigma}), "
          f"{d['laser_points']} points, the line on {lines} of {len(d['laser_poses'])} poses, {took:.0f} s")


def _figure(folder: Path, path: Path, pose: int) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    frames = json.loads((folder / "manifest.json").read_text())["frames"]
    off = cv2.imread(str(folder / frames[2 * pose]["file"]), cv2.IMREAD_UNCHANGED).astype(float)
    on = cv2.imread(str(folder / frames[2 * pose + 1]["file"]), cv2.IMREAD_UNCHANGED).astype(float)
    top = np.percentile(on, 99.9)
    fig, axes = plt.subplots(1, 3, figsize=(11, 5.6), constrained_layout=True)
    for ax, img, title, vmax in ((axes[0], on, "laser frame (room light + laser)", top),
                                 (axes[1], off, "laser-off frame of the same pose", top),
                                 (axes[2], np.clip(on - off, 0, None), "difference: the line alone",
                                  np.percentile(on - off, 99.99))):
        ax.imshow(img, cmap="gray", vmin=0, vmax=vmax)
        ax.set_title(title, fontsize=10)
        ax.set_xticks([])
        ax.set_yticks([])
    fig.suptitle(f"A room-light pose of the twin (paper rig, pose {pose}): the laser raises the board by "
                 f"{100 * (on.max() / np.percentile(off, 99.9) - 1):.0f} %", fontsize=11)
    fig.savefig(path, dpi=90)
    from PIL import Image  # 64 grey levels are all the picture has: a third of the bytes

    Image.open(path).convert("RGB").quantize(colors=64, method=Image.Quantize.MEDIANCUT).save(path, optimize=True)
    print(f"figure: {path}")


def main_(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--poses", type=int, default=20)
    p.add_argument("--binning", type=int, default=1)
    p.add_argument("--room-w-m2", type=float, default=170.0)
    p.add_argument("--pattern", default="charuco:9x6:15:11")
    p.add_argument("--out", default="bench-room-light")
    p.add_argument("--figure", default=None)
    p.add_argument("--figure-pose", type=int, default=1)
    args = p.parse_args(argv)
    root = Path(args.out)
    root.mkdir(exist_ok=True)
    dark = _render(root / "dark", args)
    room = _render(root / "room", args, "--room-light", f"{args.room_w_m2:g}")
    r = _raised(room)
    print(f"room light {args.room_w_m2:g} W/m², binning {args.binning}, {args.poses} poses: the laser raises the "
          f"board's brightest pixels by {100 * min(r):.0f} … {100 * max(r):.0f} % (median {100 * np.median(r):.0f} %)")
    _calibrate(dark, args, "auto")
    for background in ("auto", "pose", "none"):
        _calibrate(room, args, background)
    if args.figure:
        _figure(room, Path(args.figure), args.figure_pose)


if __name__ == "__main__":
    main_()
