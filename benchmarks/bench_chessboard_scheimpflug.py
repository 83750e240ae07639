"""A printed chessboard on Scheimpflug frames (issue 34 item 15): found how often, and the calibration from it.

    .venv/bin/python benchmarks/bench_chessboard_scheimpflug.py [--out DIR] [--binnings 1,2]
        [--squares 8,15] [--rigs paper,benchmarks/fabscan_like.toml] [--poses 20] [--seed 0]
        [--issue] [--json FILE]

Per rig, binning and square size: the pattern is the largest chessboard of that square the rig's
advice says is found whole in its view (``scheimpflug design``), at most ``--max-corners`` (the issue's
10 × 7; ``--pattern`` overrides it), photographed by
``render target`` in ``--poses`` hand-held poses (the module's default tilts ±35°, turns ±30°,
±5 mm off the sheet) with their centres where the advice says the whole print fits the view
(``--depth-range-mm``) and centred in height (``--height-range-mm``: the print's half diagonal
inside the heights seen at mid-depth), flood and laser frames.  ``calibrate --method target``
(:func:`scheimpflug.calibration.target.calibrate_target_folder`) then finds the pattern and
calibrates.  ``--issue`` adds the issue's own run: the paper rig at binning 2,
``chessboard:10x7:8``, poses anywhere in view (no ranges).

Figures, against the frames' truth (``truth/``), none from the calibration's own code:

* *whole*: the poses whose printed squares lie wholly on the sensor (the pattern's outer corners,
  ``spec.extent_mm()``, projected with the truth's ``camera_from_pattern`` and OpenCV camera of
  ``truth/rig_truth.json``; a chessboard is found only whole); *sharp*: of those, the ones whose every
  corner's blur spot (``pattern_blur_px``) is at most half the distance to its nearest grid
  neighbour in the image (``pattern_corners_px``); *found*: the poses the calibration detected
  (6 corners or more after refinement), counted among the whole-and-sharp ones, among the whole
  ones and in all;
* the focal length's error against the truth's ``camera_matrix`` [%]; τx, τy against its tilt [°];
  the laser plane's normal (angle) and distance against the rig's sheet in the truth's camera
  frame [°, mm]; the reprojection RMS [px]; the corners' RMS against the truth's blur centroids
  (``pattern_centroid_px``) over the poses found [px].

The pattern calibration's acceptance (benchmarks/RESULTS.md, issue 24): focal length within 0.1 %,
laser plane within 0.05° and 0.05 mm, at full resolution.  Full-resolution renders take minutes a
pose set on two cores; run it in the background.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from scheimpflug.app.cli import main
from scheimpflug.calibration.detectability import frame_views, pattern_advice, square_advice
from scheimpflug.calibration.measure import detect_pattern
from scheimpflug.calibration.pattern import parse_pattern
from scheimpflug.calibration.target import calibrate_target_folder
from scheimpflug.io.frames import open_frame_folder
from scheimpflug.model.binning import binned_rig
from scheimpflug.model.hinge import hinge_geometry
from scheimpflug.model.rig import load_preset, load_rig, rig_from_dict

SHARP = 0.5     # a corner is sharp when its blur spot is at most this fraction of its square side [-]


def _rig(name: str):
    return load_preset(name) if not name.endswith(".toml") else load_rig(name)


def _rig_args(name: str) -> list[str]:
    return ["--rig", name] if name.endswith(".toml") else ["--preset", name]


def _ranges(rig, spec) -> tuple[tuple[float, float], tuple[float, float]] | None:
    """Where the advice puts the poses' centres: D where the whole print fits and is found, heights centred."""
    adv = pattern_advice(rig, spec)
    if adv.usable_mm is None:
        return None
    lo, hi = adv.usable_mm
    g = hinge_geometry(rig)
    mid = 0.5 * (lo + hi)
    u = float(g.column_from_distance(mid))
    _, h = g.sheet_from_pixel(np.array([u, u]), np.array([-0.5, rig.sensor.rows - 0.5]))
    x0, y0, x1, y1 = spec.extent_mm()
    half = 0.5 * math.hypot(x1 - x0, y1 - y0)
    h_lo, h_hi = float(min(h)) + half, float(max(h)) - half
    if h_lo > h_hi:
        h_lo = h_hi = 0.5 * (float(min(h)) + float(max(h)))
    return (lo, hi), (h_lo, h_hi)


def _render(out: Path, rig_name: str, binning: int, pattern: str, poses: int, seed: int, ranges) -> None:
    if (out / "manifest.json").exists() and json.loads((out / "manifest.json").read_text()).get("complete"):
        return
    args = ["render", "target", *_rig_args(rig_name), "--binning", str(binning), "--pattern", pattern,
            "--poses", str(poses), "--seed", str(seed), "--out", str(out), "--quiet"]
    if ranges is not None:
        (d0, d1), (h0, h1) = ranges
        args += [f"--depth-range-mm={d0:.1f}:{d1:.1f}", f"--height-range-mm={h0:.1f}:{h1:.1f}"]
    if main(args) != 0:
        raise SystemExit(f"render failed: {' '.join(args)}")


def _whole(cam: dict, spec, m: np.ndarray) -> bool:
    """Whether the printed squares lie wholly on the sensor (the outer corners projected by the truth)."""
    x0, y0, x1, y1 = spec.extent_mm()
    pts = np.array([[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0]], np.float64)
    uv, _ = cv2.projectPoints(pts, cv2.Rodrigues(m[:3, :3])[0], m[:3, 3], np.array(cam["camera_matrix"]),
                              np.array(cam["dist_coeffs"]))
    w, h = cam["image_size"]
    uv = uv.reshape(-1, 2)
    return bool(((uv >= -0.5) & (uv <= np.array([w, h]) - 0.5)).all())


def _sharp(spec, z) -> bool:
    """Every corner's blur spot at most SHARP × its shortest grid step in the image."""
    nc, nr = spec.grid_shape
    g = z["pattern_corners_px"].reshape(nr, nc, 2)
    step = np.full((nr, nc), np.inf)
    for axis in (0, 1):
        d = np.linalg.norm(np.diff(g, axis=axis), axis=2)
        lo = [slice(None)] * 2
        hi = [slice(None)] * 2
        lo[axis], hi[axis] = slice(None, -1), slice(1, None)
        step[tuple(lo)] = np.fmin(step[tuple(lo)], d)
        step[tuple(hi)] = np.fmin(step[tuple(hi)], d)
    return bool(np.all(z["pattern_blur_px"] <= SHARP * step.ravel()))


def _truth_plane(folder: Path) -> np.ndarray:
    """The twin's sheet in the camera frame of ``truth/rig_truth.json``'s ``opencv``."""
    from sim.truth import opencv_laser_plane

    return opencv_laser_plane(rig_from_dict(json.loads((folder / "manifest.json").read_text())["rig"]))


def _poses(folder: Path, spec, cam: dict) -> dict:
    """Pose index → (whole, sharp, flood truth) from the truth files."""
    out = {}
    for f in json.loads((folder / "manifest.json").read_text())["frames"]:
        if f.get("light") != "flood":
            continue
        z = np.load(folder / f["truth"])
        whole = _whole(cam, spec, z["camera_from_pattern"]) and bool(np.isfinite(z["pattern_corners_px"]).all())
        out[f["pose"]] = (whole, whole and _sharp(spec, z), z)
    return out


def _found(folder: Path, spec) -> set:
    """The poses whose flood frame shows the pattern (6 corners or more), as the calibration looks for it."""
    ff = open_frame_folder(folder)
    views = frame_views(ff.rig, (ff.rows, ff.columns), spec, ff.stripe_along)
    out = set()
    for i, rec in enumerate(ff.frames):
        if rec.extra.get("light") == "flood":
            det = detect_pattern(ff.read(i), spec, views=views)
            if det is not None and len(det) >= 6:
                out.add(rec.extra.get("pose"))
    return out


def _figures(folder: Path, pattern: str) -> dict:
    spec = parse_pattern(pattern)
    cam = json.loads((folder / "truth" / "rig_truth.json").read_text())["opencv"]
    truth = _poses(folder, spec, cam)
    t0 = time.time()
    try:
        res = calibrate_target_folder(folder, pattern)
    except Exception as exc:                       # a figure of its own: the calibration refused (detection
                                                   # counted apart, below)
        res, error = None, f"{type(exc).__name__}: {exc}"
    wall = time.time() - t0
    found = set(res.detections) if res is not None else _found(folder, spec)
    whole = {k for k, v in truth.items() if v[0]}
    sharp = {k for k, v in truth.items() if v[1]}
    row = {"pattern": pattern, "poses": len(truth), "whole": len(whole), "whole_sharp": len(sharp),
           "found": len(found), "found_of_whole_sharp": len(found & sharp), "found_of_whole": len(found & whole),
           "calibrate_s": wall}
    if res is None:
        return {**row, "error": error}
    errs = []
    n = len(spec.corner_ids())
    for k, det in res.detections.items():
        ref = truth[k][2]["pattern_centroid_px"]
        e = [np.linalg.norm(det.corners_px - ref[ids], axis=1) for ids in (det.ids, n - 1 - det.ids)]
        errs.append(min(e, key=lambda x: float(np.nanmean(x ** 2))))      # a chessboard's half-turn ambiguity
    d = res.calibration.to_json_dict()
    k, k0 = np.array(d["camera_matrix"]), np.array(cam["camera_matrix"])
    dist, dist0 = np.array(d["dist_coeffs"]), np.array(cam["dist_coeffs"])
    row.update(fx_error_percent=100 * (k[0, 0] / k0[0, 0] - 1),
               tau_y_error_deg=math.degrees(dist[13] - dist0[13]), tau_x_error_deg=math.degrees(dist[12] - dist0[12]),
               reprojection_rms_px=d["reprojection_rms_px"], poses_used=len(d["poses_used"]),
               corner_rms_px=float(np.sqrt(np.nanmean(np.concatenate(errs) ** 2))) if errs else None)
    if d["laser_plane"] is not None:
        pl, plane = np.array(d["laser_plane"]), _truth_plane(folder)
        row.update(plane_normal_deg=math.degrees(math.acos(min(1.0, abs(pl[:3] @ plane[:3])))),
                   plane_distance_mm=float(pl[3] - plane[3]), laser_points=d["laser_points"])
    return row


def _capped(pattern: str | None, cap: str) -> str | None:
    """The advice's board with at most ``cap`` (COLSxROWS) inner corners."""
    if pattern is None:
        return None
    spec = parse_pattern(pattern)
    c, r = (int(x) for x in cap.split("x"))
    return f"chessboard:{min(spec.cols, c)}x{min(spec.rows, r)}:{spec.pitch_mm:g}"


def _cases(args) -> list[tuple]:
    cases = []
    if args.issue:
        cases.append(("paper", 2, "chessboard:10x7:8", False))
    for rig_name in args.rigs.split(","):
        for b in (int(x) for x in args.binnings.split(",")):
            adv = square_advice(_rig(rig_name), binnings=(b,), squares_mm=[float(s) for s in args.squares.split(",")])
            for square, pattern in adv["binnings"][0]["largest_chessboard"].items():
                pattern = args.pattern or _capped(pattern, args.max_corners)
                if pattern is None:
                    print(f"{rig_name} b{b}: no chessboard of {square} mm squares is found whole", file=sys.stderr)
                    continue
                cases.append((rig_name, b, pattern, True))
    return cases


def _print(rig_name: str, binning: int, row: dict) -> None:
    head = (f"{rig_name:>28s} b{binning} {row['pattern']:<20s} "
            f"found {row['found_of_whole_sharp']}/{row['whole_sharp']} whole+sharp "
            f"({row['found_of_whole']}/{row['whole']} whole, {row['found']}/{row['poses']} all)")
    if "error" in row:
        print(f"{head}  calibration refused: {row['error']}", flush=True)
        return
    plane = (f"plane {row['plane_normal_deg']:.4f}° {row['plane_distance_mm']:+.4f} mm"
             if "plane_normal_deg" in row else "no laser plane")
    print(f"{head}  fx {row['fx_error_percent']:+.4f} %  τy {row['tau_y_error_deg']:+.4f}°  "
          f"τx {row['tau_x_error_deg']:+.4f}°  {plane}  reproj {row['reprojection_rms_px']:.3f} px  "
          f"corners {row['corner_rms_px']:.3f} px  ({row['poses_used']} poses, {row['calibrate_s']:.0f} s)", flush=True)


def run(argv=None) -> list[dict]:
    """Render, calibrate, print one line per case; the rows (for ``--json``)."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default="bench_chessboard_out", help="folder for the frame sets (resumed)")
    p.add_argument("--binnings", default="1,2")
    p.add_argument("--squares", default="8,15", help="square sizes [mm]")
    p.add_argument("--rigs", default="paper,benchmarks/fabscan_like.toml")
    p.add_argument("--pattern", help="one pattern for every case instead of the advice's")
    p.add_argument("--max-corners", default="10x7", help="cap on the advice's board, inner corners (default the "
                   "issue's 10x7)")
    p.add_argument("--poses", type=int, default=20)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--issue", action="store_true", help="add the issue's run (paper, binning 2, poses anywhere)")
    p.add_argument("--json", help="write the rows to this file")
    args = p.parse_args(argv)
    rows = []
    for rig_name, binning, pattern, ranged in _cases(args):
        rig = binned_rig(_rig(rig_name), binning)
        ranges = _ranges(rig, parse_pattern(pattern)) if ranged else None
        if ranged and ranges is None:
            print(f"{rig_name} b{binning} {pattern}: the advice finds no distance where it is found whole", flush=True)
            continue
        where = f"_D{ranges[0][0]:.0f}-{ranges[0][1]:.0f}" if ranged else "_anywhere"
        tag = f"{Path(rig_name).stem}_b{binning}_{pattern.replace(':', '_')}{where}"
        folder = Path(args.out) / tag
        t0 = time.time()
        _render(folder, rig_name, binning, pattern, args.poses, args.seed, ranges)
        row = {"rig": rig_name, "binning": binning, "ranges": ranges, "render_s": time.time() - t0,
               **_figures(folder, pattern)}
        _print(rig_name, binning, row)
        rows.append(row)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2, default=float))
    return rows


if __name__ == "__main__":
    run()
