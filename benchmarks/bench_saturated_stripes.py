"""Saturated stripe rows dropped, centred on their plateau, or centred on their edges (issue 34 items 16 and 3).

Prints, for each rule of ``reconstruct --saturated`` (``drop``: the default before issue 34;
``plateau``: the old ``--keep-saturated``; ``edges``: the default now):

* FabScanPi ``scan-2_1`` (all 200 frames of one turn, ``../shared/realdata/``, imported as
  ``bench_real_frames.py`` does, reconstructed through FabScan's ``dummy.config.json``): the
  cloud's points with the default quality filter and without, the bust's points (the part:
  within 38 mm of the axis, 2–85 mm above the table), the saturated rows, the two still back
  walls' straightness, stillness and bow (:mod:`scheimpflug.fixed_lines`; FabScan's points,
  camera matrix alone), and the stripe's scatter along the bust (second differences of the
  centres of three consecutive lines of one frame, /√6: a surface is smooth over three pixels)
  for its saturated and unsaturated rows, beside the stated centre σ; and item 3: the same frames
  with ``stripe_along`` "columns" (imported without ``--stripe-along rows`` before ``import``
  found the direction itself), reconstructed by the library without the check (before) and by
  ``reconstruct`` (after: refused).
* The twin (rendered here at ``--binning``, unless the folders exist): the paper rig at
  4 × and 16 × its exposure (``sensor.exposure_ms`` 2 and 8), the knurled metal cylinder and
  the pile of sundries, 36 frames 10° apart, calibrated from the paper rig's own calibration
  run; each rule's cloud scored against ``truth/mesh.ply`` (``evaluate``) and its stripe
  centres against the exact per-row truth (``truth/NNNNN.npz`` ``stripe_u``), with the
  saturated rows' stated σ (``centre_sigma_px``) against their errors.

Usage::

    python benchmarks/bench_saturated_stripes.py [--realdata ../shared/realdata] [--out /tmp/bench_saturated]
        [--binning 2] [--skip-twin] [--skip-fabscan]
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
RULES = ("drop", "plateau", "edges")
WALLS = {"left": (0, 190), "right": (1310, 1460)}          # scan-2_1's wall columns (bench_real_frames.py)
TWIN = {"cyl-exp2": ("cylinder", 2.0), "pile-exp8": ("pile", 8.0)}
AXIS_MM = 179.45                                           # the paper rig's rotary axis (rig key stage.axis_mm)


def run(*args, check=True) -> subprocess.CompletedProcess:
    """This checkout's command line; its completed process."""
    cmd = [sys.executable, "-m", "scheimpflug", *map(str, args)]
    done = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    if check and done.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{done.stderr}")
    return done


def rms(a) -> float:
    a = np.asarray(a, np.float64)
    return float(np.sqrt(np.mean(a ** 2))) if a.size else float("nan")


def along_scatter(st) -> dict:
    """Scatter of the centres along the stripe (second differences /√6), saturated and unsaturated lines [px]."""
    out = {}
    for label, want in (("saturated", True), ("unsaturated", False)):
        d2, sig = [], []
        for r, u, s, sg in zip(st.rows, st.u, st.saturated, st.centre_sigma_px):
            ok = (r[2:] - r[:-2] == 2) & (np.abs(np.diff(u)[1:]) < 2) & (np.abs(np.diff(u)[:-1]) < 2)
            c = ok & (s[1:-1] == want) & (s[2:] == want) & (s[:-2] == want)
            d2.append((u[2:] - 2 * u[1:-1] + u[:-2])[c])
            sig.append(sg[1:-1][c])
        d2, sig = np.concatenate(d2), np.concatenate(sig)
        out[label] = {"triples": int(d2.size), "robust_px": float(1.4826 * np.median(np.abs(d2)) / np.sqrt(6))
                      if d2.size else float("nan"), "rms_px": rms(d2) / np.sqrt(6),
                      "stated_sigma_median_px": float(np.nanmedian(sig)) if d2.size else float("nan")}
    return out


def walls(st, config: Path) -> dict:
    """The back walls' figures from one extraction (FabScan's points: camera matrix alone)."""
    from scheimpflug.calibration.fabscan import read_fabscan
    from scheimpflug.fixed_lines import fixed_line, line_inliers
    from scheimpflug.stripe import image_pixels

    u, v = image_pixels(np.concatenate(st.rows), np.concatenate(st.u), st.along)
    sat = np.concatenate(st.saturated)
    frame = np.concatenate([np.full(len(r), i) for i, r in enumerate(st.rows)])
    model = read_fabscan(config)
    res = {}
    for wall, (c0, c1) in WALLS.items():
        sel = (u >= c0) & (u <= c1)
        keep = line_inliers(u[sel], v[sel])
        s, h = model.stage_from_pixel(u[sel][keep], v[sel][keep])
        fig = fixed_line(s, h, frame[sel][keep]).to_json_dict()
        res[wall] = {**{k: round(x, 4) if isinstance(x, float) else x for k, x in fig.items()},
                     "saturated_points": int(sat[sel][keep].sum())}
    return res


def bust_points(ply: Path) -> int:
    """Points of the part in a cloud: within 38 mm of the axis, 2–85 mm above the table (bench_real_frames.draw)."""
    from scheimpflug.io.ply import read_point_cloud

    xyz = read_point_cloud(ply).xyz_mm
    r = np.hypot(xyz[:, 0], xyz[:, 1])
    z0 = np.percentile(xyz[r < 38, 2], 0.5)
    return int(np.count_nonzero((r < 38) & (xyz[:, 2] > z0 + 2.0) & (xyz[:, 2] < z0 + 85.0)))


def fabscan(realdata: Path, out: Path) -> dict:
    from scheimpflug.calibration.fabscan import fabscan_angles_deg
    from scheimpflug.io.frames import open_frame_folder
    from scheimpflug.reconstruct import extract_folder_stripes

    config = realdata / "fabscan" / "dummy.config.json"
    files = sorted(glob.glob(str(realdata / "fabscan" / "scan-2_1" / "*.jpg")))
    angles = fabscan_angles_deg(len(files), 6400, resolution=2)
    used = [f for f, a in zip(files, angles) if a > -360.0 - 1e-9]
    folder = out / "scan-2_1"
    if not (folder / "manifest.json").is_file():
        run("import", *used, "--channel", "r", "--stripe-along", "rows", "--quiet",
            f"--angles-deg={','.join(f'{a:.10g}' for a in angles[:len(used)])}", "--out", folder)
    ff = open_frame_folder(folder)
    res = {"frames": len(ff)}
    for rule in RULES:
        t0 = time.perf_counter()
        d = json.loads(run("reconstruct", folder, "--calibration", config, "--saturated", rule, "--json", "--quiet",
                           "--force", "--out", out / f"fab-{rule}.ply").stdout)
        seconds = time.perf_counter() - t0
        nf = json.loads(run("reconstruct", folder, "--calibration", config, "--saturated", rule, "--json", "--quiet",
                            "--force", "--no-quality-filter", "--out", out / f"fab-{rule}-all.ply").stdout)
        st = extract_folder_stripes(ff, "cog", saturated=rule)
        res[rule] = {"points": d["n_points"], "bust_points": bust_points(out / f"fab-{rule}.ply"),
                     "points_no_filter": nf["n_points"],
                     "bust_points_no_filter": bust_points(out / f"fab-{rule}-all.ply"),
                     "saturated_rows": d["saturated_rows"], "saturated_points": d["saturated_points"],
                     "dropped_uncertain_saturated": d["quality_filter"]["uncertain_saturated"],
                     "reconstruct_s": round(seconds, 1), "walls": walls(st, config),
                     "along_stripe_scatter": along_scatter(st)}
    res["item3"] = item3(ff, folder, config, out)
    return res


def item3(ff, folder: Path, config: Path, out: Path) -> dict:
    """The frames with stripe_along 'columns': the library's cloud without the check, and reconstruct's answer."""
    import shutil

    from scheimpflug.calibration.fabscan import read_fabscan
    from scheimpflug.io.frames import open_frame_folder
    from scheimpflug.reconstruct import extract_folder_stripes, reconstruct_profiles

    wrong = out / "scan-2_1-columns"
    if wrong.exists():
        shutil.rmtree(wrong)
    wrong.mkdir()
    (wrong / "frames").symlink_to((folder / "frames").resolve())
    manifest = json.loads((folder / "manifest.json").read_text())
    manifest["stripe_along"] = "columns"
    (wrong / "manifest.json").write_text(json.dumps(manifest))
    wf = open_frame_folder(wrong)
    st = extract_folder_stripes(wf, "cog")
    cloud = reconstruct_profiles(st.rows, st.u, [r.angle_deg for r in wf.frames], read_fabscan(config), None,
                                 along=st.along)
    done = run("reconstruct", wrong, "--calibration", config, "--out", out / "wrong.ply", "--quiet", "--force",
               check=False)
    return {"before_points_without_check": len(cloud), "after_exit_status": done.returncode,
            "after_message": done.stderr.strip().splitlines()[-1] if done.stderr.strip() else ""}


def render_twin(out: Path, binning: int) -> dict:
    """The twin's folders (rendered when absent): the calibration and the bright scans."""
    preset = (ROOT / "scheimpflug" / "model" / "presets" / "paper.toml").read_text()
    cal = out / f"cal-b{binning}"
    if not (cal / "manifest.json").is_file():
        run("render", "calibration", "--preset", "paper", "--binning", binning, "--out", cal, "--quiet")
    if not (out / f"cal-b{binning}.json").is_file():
        run("calibrate", cal, "--out", out / f"cal-b{binning}.json", "--quiet")
    folders = {}
    for name, (part, exposure) in TWIN.items():
        rig = out / f"{name}.toml"
        lines = [f"exposure_ms = {exposure}" if ln.startswith("exposure_ms") else ln for ln in preset.splitlines()]
        rig.write_text("\n".join(lines) + "\n")
        folder = out / f"{name}-b{binning}"
        if not (folder / "manifest.json").is_file():
            run("render", "rotary", "--rig", rig, "--part", part, "--binning", binning, "--step-deg", 10,
                "--out", folder, "--quiet")
        folders[name] = folder
    return {"calibration": out / f"cal-b{binning}.json", "folders": folders}


def truth_errors(folder: Path, rule: str) -> dict:
    """Stripe centres against the twin's exact per-row truth: saturated and unsaturated rows [px]."""
    from scheimpflug.io.frames import open_frame_folder
    from scheimpflug.reconstruct import extract_folder_stripes

    ff = open_frame_folder(folder)
    st = extract_folder_stripes(ff, "cog", saturated=rule)
    err = {True: [], False: []}
    z = {True: [], False: []}
    for i in range(len(ff)):
        truth = np.load(folder / "truth" / f"{i:05d}.npz")["stripe_u"]
        e = st.u[i] - truth[st.rows[i]]
        ok = np.isfinite(e) & (np.abs(e) < 3.0)       # rows with a true stripe (a wrong peak is another matter)
        for s in (True, False):
            m = ok & (st.saturated[i] == s)
            err[s].append(e[m])
            z[s].append(e[m] / st.centre_sigma_px[i][m])
    out = {}
    for s, label in ((True, "saturated"), (False, "unsaturated")):
        e, zz = np.concatenate(err[s]), np.concatenate(z[s])
        out[label] = {"rows": int(e.size), "rms_px": rms(e), "bias_px": float(e.mean()) if e.size else float("nan"),
                      "z_rms": rms(zz[np.isfinite(zz)]),
                      "share_abs_z_over_3": float(np.mean(np.abs(zz) > 3)) if zz.size else float("nan")}
    return out


def twin(out: Path, binning: int) -> dict:
    made = render_twin(out, binning)
    res = {"binning": binning, "axis_mm": AXIS_MM}
    for name, folder in made["folders"].items():
        res[name] = {}
        for rule in RULES:
            row = {}
            for label, extra in (("filter", []), ("no_filter", ["--no-quality-filter"])):
                ply = out / f"{name}-{rule}-{label}.ply"
                d = json.loads(run("reconstruct", folder, "--calibration", made["calibration"], "--axis-mm", AXIS_MM,
                                   "--saturated", rule, "--json", "--quiet", "--force", "--out", ply, *extra).stdout)
                e = json.loads(run("evaluate", ply, "--mesh", folder / "truth" / "mesh.ply", "--json").stdout)
                row[label] = {"points": d["n_points"], "saturated_rows": d["saturated_rows"],
                              "saturated_points": d["saturated_points"],
                              **{k: round(e[k], 4) for k in ("rms_mm", "mean_abs_mm", "p95_mm", "max_mm")}}
            row["centres_vs_truth"] = truth_errors(folder, rule)
            res[name][rule] = row
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--realdata", type=Path, default=ROOT.parent / "shared" / "realdata")
    ap.add_argument("--out", type=Path, default=Path("/tmp/bench_saturated"))
    ap.add_argument("--binning", type=int, default=2, help="the twin's binning (default 2)")
    ap.add_argument("--skip-twin", action="store_true")
    ap.add_argument("--skip-fabscan", action="store_true")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    report = {}
    if not args.skip_fabscan:
        if args.realdata.is_dir():
            report["fabscan scan-2_1"] = fabscan(args.realdata, args.out)
        else:
            report["fabscan scan-2_1"] = f"skipped: {args.realdata} is absent"
    if not args.skip_twin:
        report["twin"] = twin(args.out, args.binning)
    print(json.dumps(report, indent=1, default=str))


if __name__ == "__main__":
    main()
