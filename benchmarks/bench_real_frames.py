"""Real frames through the pipeline, against their makers' results (issue 24 item 4).

Reads ``../shared/realdata/`` (never copied into the project; see its README for
the licences) and prints:

* FabScanPi ``scan-2_1`` (and ``scan-2_2``): imported as the camera stored them
  (8-bit RGB JPEG, red channel, stripe along the rows, FabScan's angle rule),
  reconstructed through FabScan's own ``dummy.config.json``
  (:mod:`scheimpflug.calibration.fabscan`); the cloud against FabScan's own
  triangulation formulae (re-implemented here from its source, not imported);
  the two still back walls' straightness and stillness in the sheet
  (:mod:`scheimpflug.fixed_lines`), with FabScan's points (camera matrix alone)
  and with its calibrated distortion applied; the cloud as PLY and a picture.
* 3DScanScience ``camera-calibration``: the notebook's recipe on the frames as
  stored (the relation fx, fy, cx, cy = our fy, fx, 1279 − cy, cx checked) and
  this pipeline's pattern calibration (``calibrate --method target``) against
  the notebook's printed camera matrix.

Usage::

    python benchmarks/bench_real_frames.py [--realdata ../shared/realdata] [--out /tmp/real]
        [--picture docs/fabscan_real_cloud.png]
"""

from __future__ import annotations

import argparse
import glob
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
# The notebook "4.2. Camera calibration" (3DScanScience, commit 29d70ad) printed, in its turned frames:
NOTEBOOK = {"fx": 1430.39147, "fy": 1429.66307, "cx": 636.403930, "cy": 478.032706}
# The FabScan frames' wall regions (image columns of the stored frames) [px].
WALLS = {"scan-2_1": {"left": (0, 190), "right": (1310, 1460)},
         "scan-2_2": {"left": (0, 180), "right": (1300, 1470)}}


def run(*args) -> str:
    """Run the command line (this checkout's), return its standard output."""
    cmd = [sys.executable, "-m", "scheimpflug", *map(str, args)]
    done = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{done.stderr}")
    return done.stdout


def fabscan_points(rows, across, angles_deg, config: dict) -> np.ndarray:
    """FabScan's own points (FSImageProcessor.compute_point_cloud) of stripe points of the stored frames."""
    c = config["calibration"]
    k = np.asarray(c["camera_matrix"], float)
    n, d = np.asarray(c["laser_planes"][0]["normal"], float), float(c["laser_planes"][0]["distance"])
    r, t = np.asarray(c["platform_rotation"], float), np.asarray(c["platform_translation"], float)
    w = int(config["camera"]["resolution"]["height"])          # the turned image's width
    out = []
    for line, a, ang in zip(rows, across, angles_deg):
        u, v = np.asarray(line, float), np.asarray(a, float)    # stored: column = line, row = across
        u2, v2 = (w - 1) - v, u                                  # cv2.transpose, then cv2.flip(…, 1)
        x = np.stack([(u2 - k[0, 2]) / k[0, 0], (v2 - k[1, 2]) / k[1, 1], np.ones_like(u2)])
        xc = d / (n @ x) * x
        xp = r.T @ (xc - t[:, None])
        th = np.radians(-ang)                                    # FabScan's angle of the picture
        rz = np.array([[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1]])
        out.append((rz @ xp).T)
    return np.concatenate(out)


def rigid_rms(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """RMS after the best proper rigid motion a → b, and after the best mirror one [mm]."""
    from scheimpflug.fitting import fit_rigid

    return fit_rigid(a, b)[2], fit_rigid(a, b, mirror=True)[2]


def fabscan(realdata: Path, out: Path, name: str, picture: Path | None) -> dict:
    from scheimpflug.calibration.fabscan import fabscan_angles_deg, read_fabscan
    from scheimpflug.fixed_lines import fixed_line, line_inliers
    from scheimpflug.io.frames import open_frame_folder
    from scheimpflug.reconstruct import extract_folder_stripes, reconstruct_profiles
    from scheimpflug.stripe import image_pixels

    config_path = realdata / "fabscan" / "dummy.config.json"
    config = json.loads(config_path.read_text())
    files = sorted(glob.glob(str(realdata / "fabscan" / name / "*.jpg")))
    steps = int(config["turntable"]["steps"])
    angles = fabscan_angles_deg(len(files), steps, resolution=int(name.split("-")[1].split("_")[0]))
    used = [f for f, a in zip(files, angles) if a > -360.0 - 1e-9]          # one turn: the pictures FabScan reads
    folder = out / name
    t0 = time.perf_counter()
    run("import", *used, "--channel", "r", "--stripe-along", "rows",
        f"--angles-deg={','.join(f'{a:.10g}' for a in angles[:len(used)])}", "--out", folder)
    t_import = time.perf_counter() - t0
    t0 = time.perf_counter()
    summary = json.loads(run("reconstruct", folder, "--calibration", config_path, "--out", out / f"{name}.ply",
                             "--keep-saturated", "--no-quality-filter", "--json", "--quiet"))
    t_rec = time.perf_counter() - t0
    ff = open_frame_folder(folder)
    st = extract_folder_stripes(ff, "cog", keep_saturated=True)
    ang = [r.angle_deg for r in ff.frames]
    res = {"frames": len(ff), "files": len(files), "points": summary["n_points"], "import_s": round(t_import, 1),
           "reconstruct_s": round(t_rec, 1), "axis": summary["axis_source"]}
    cal = read_fabscan(config_path)
    ours = reconstruct_profiles(st.rows, st.u, ang, cal, None, along="rows")
    theirs = fabscan_points(st.rows, st.u, ang, config)
    res["vs_fabscan_rigid_rms_mm"], res["vs_fabscan_mirror_rms_mm"] = rigid_rms(ours.xyz_mm, theirs)
    in_sheet = reconstruct_profiles(st.rows, st.u, ang, cal, cal.axis["axis_mm"], along="rows")
    res["axis_in_sheet_rigid_rms_mm"] = rigid_rms(in_sheet.xyz_mm, theirs)[0]
    lines = np.concatenate(st.rows)
    across = np.concatenate(st.u)
    frame = np.concatenate([np.full(len(r), i) for i, r in enumerate(st.rows)])
    u, v = image_pixels(lines, across, "rows")
    for wall, (c0, c1) in WALLS[name].items():
        sel = (u >= c0) & (u <= c1)
        keep = line_inliers(u[sel], v[sel])
        # in the image [px]: no calibration (a straight wall is a straight image line through an ideal lens)
        res[f"wall_{wall}_image_px"] = fixed_line(u[sel][keep], v[sel][keep], frame[sel][keep]).to_json_dict()
        if name != "scan-2_1":         # the second laser: dummy.config.json holds laser 0's plane only
            continue
        for use in ("as-fabscan", "apply"):
            model = read_fabscan(config_path, distortion=use)
            s, h = model.stage_from_pixel(u[sel][keep], v[sel][keep])
            res[f"wall_{wall}_{use}"] = fixed_line(s, h, frame[sel][keep]).to_json_dict()
    if picture is not None:
        draw(ours.xyz_mm, picture, name)
    return res


def draw(xyz: np.ndarray, path: Path, name: str) -> None:
    """The part's cloud in three views: the walls and the table left out (r ≤ 38 mm, 2–85 mm above the table)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    r = np.hypot(xyz[:, 0], xyz[:, 1])
    z0 = np.percentile(xyz[r < 38, 2], 0.5)                 # the table's top
    keep = (r < 38) & (xyz[:, 2] > z0 + 2.0) & (xyz[:, 2] < z0 + 85.0)
    p = xyz[keep][::2]
    fig = plt.figure(figsize=(12, 4.8), constrained_layout=True)
    for k, (i, j, title) in enumerate(((0, 2, "front (x, z)"), (1, 2, "side (y, z)"))):
        ax = fig.add_subplot(1, 3, k + 1)
        ax.scatter(p[:, i], p[:, j], s=0.02, c=p[:, 2], cmap="viridis", rasterized=True)
        ax.set_aspect("equal")
        ax.set_title(title)
        ax.set_xlabel("mm")
    ax = fig.add_subplot(1, 3, 3, projection="3d")
    q = p[::4]
    ax.scatter(q[:, 0], q[:, 1], q[:, 2], s=0.05, c=q[:, 2], cmap="viridis", rasterized=True)
    ax.view_init(elev=15, azim=-60)
    ax.set_box_aspect(np.ptp(q, axis=0))
    ax.set_title("perspective")
    fig.suptitle(f"FabScanPi {name} (real JPEG frames): {len(p):,} of the part's points (every 2nd), this "
                 "pipeline through FabScan's own calibration", fontsize=10)
    fig.savefig(path, dpi=90)
    plt.close(fig)


def notebook(realdata: Path, out: Path) -> dict:
    import cv2

    files = sorted(glob.glob(str(realdata / "3dscanscience" / "camera-calibration" / "frame*.jpg")))
    rows, columns = 6, 11
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.001)
    objp = np.zeros((rows * columns, 3), np.float32)
    objp[:, :2] = np.mgrid[0:columns, 0:rows].T.reshape(-1, 2)
    obj, img = [], []
    for f in files:                                  # the notebook's recipe, on the frames as stored
        g = cv2.cvtColor(cv2.imread(f), cv2.COLOR_BGR2GRAY)
        ok, c = cv2.findChessboardCorners(g, (columns, rows), None)
        if ok:
            cv2.cornerSubPix(g, c, (11, 11), (-1, -1), crit)
            obj.append(objp)
            img.append(c)
    _, k, _, _, _ = cv2.calibrateCamera(obj, img, g.shape[::-1], None, None)
    expect = {"fx": NOTEBOOK["fy"], "fy": NOTEBOOK["fx"], "cx": NOTEBOOK["cy"], "cy": 1279 - NOTEBOOK["cx"]}
    res = {"expected_as_stored": expect,
           "notebook_recipe": {"fx": k[0, 0], "fy": k[1, 1], "cx": k[0, 2], "cy": k[1, 2]}}
    folder = out / "dss"
    run("import", realdata / "3dscanscience" / "camera-calibration", "--scenario", "target", "--channel", "gray",
        "--out", folder)
    for label, extra in (("target_model_opencv5", ["--distortion", "opencv5"]),
                         ("target_subpix_opencv5", ["--distortion", "opencv5", "--refine", "subpix"]),
                         ("target_default", [])):
        t0 = time.perf_counter()
        d = json.loads(run("calibrate", folder, "--method", "target", "--pattern", "chessboard:11x6:10", "--json",
                           "--quiet", *extra))
        km = d["camera_matrix"]
        got = {"fx": km[0][0], "fy": km[1][1], "cx": km[0][2], "cy": km[1][2]}
        res[label] = {"camera": got, "minus_notebook": {q: got[q] - expect[q] for q in got},
                      "stderr": {q: d["stderr"].get(q) for q in got}, "rms_px": d["reprojection_rms_px"],
                      "poses_used": len(d["poses_used"]), "dist_coeffs": d["dist_coeffs"][:5],
                      "seconds": round(time.perf_counter() - t0, 1)}
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--realdata", type=Path, default=ROOT.parent / "shared" / "realdata")
    ap.add_argument("--out", type=Path, default=Path("/tmp/bench_real_frames"))
    ap.add_argument("--picture", type=Path, default=None, help="write the scan-2_1 cloud's picture here")
    args = ap.parse_args()
    if not args.realdata.is_dir():
        raise SystemExit(f"{args.realdata} is absent: nothing to measure")
    args.out.mkdir(parents=True, exist_ok=True)
    for p in args.out.iterdir():
        subprocess.run(["rm", "-rf", str(p)], check=True)
    report = {"3dscanscience": notebook(args.realdata, args.out)}
    for name in ("scan-2_1", "scan-2_2"):
        report[f"fabscan {name}"] = fabscan(args.realdata, args.out, name,
                                            args.picture if name == "scan-2_1" else None)
    print(json.dumps(report, indent=1, default=float))


if __name__ == "__main__":
    main()
