"""Closed-loop accuracy of the cylinder scan, speckle off and on (issue: pipeline acceptance).

    python benchmarks/bench_accuracy.py [--step-deg 2] [--speckle 0 0.5 1.0] [--binning 1]

For each speckle contrast: render the calibration plate, the blocker and the
paper's cylinder with the twin (paper rig), calibrate, locate the axis,
reconstruct, and score the smooth part of the cylinder against the rendered
mesh (RMS point-to-mesh, fitted diameter).  Prints one line per contrast.
"""

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np


def run(contrast: float, step_deg: float, binning: int, root: Path, methods) -> list[dict]:
    import scenes
    from scheimpflug.app.cli import main
    from scheimpflug.axis import locate_axis
    from scheimpflug.calibration import calibrate_folder
    from scheimpflug.fitting import fit_cylinder
    from scheimpflug.io.frames import open_frame_folder
    from scheimpflug.io.ply import read_mesh
    from scheimpflug.model.rig import load_preset, rig_to_toml
    from scheimpflug.reconstruct import extract_folder, reconstruct_profiles
    from scheimpflug.scoring import PointToMesh

    rig = load_preset("paper").replace(laser={"speckle_contrast": contrast})
    out = root / f"speckle{contrast:g}"
    out.mkdir(parents=True)
    (out / "rig.toml").write_text(rig_to_toml(rig))
    common = ["--rig", str(out / "rig.toml"), "--binning", str(binning), "--truth-pixels", "none", "--quiet"]
    for args in (["calibration", "--out", str(out / "cal")], ["blocker", "--out", str(out / "blk")],
                 ["rotary", "--part", "cylinder", "--step-deg", str(step_deg), "--out", str(out / "cyl")]):
        assert main(["render", *args, *common]) == 0
    cal = calibrate_folder(out / "cal").best
    axis_mm = locate_axis(out / "blk", cal).axis_mm
    ff = open_frame_folder(out / "cyl")
    part = scenes.load_part("cylinder").parts[0]
    z_lo, z_hi = np.asarray(part.analytic["smooth_z_range_mm"]) + rig.stage.rotary_table_z_mm
    v, f, _ = read_mesh(out / "cyl" / "truth" / "mesh.ply")
    tree = PointToMesh(v, f)
    results = []
    for method in methods:
        rows, us, _, _ = extract_folder(ff, method)
        cloud = reconstruct_profiles(rows, us, [r.angle_deg for r in ff.frames], cal, axis_mm)
        xyz = cloud.xyz_mm[(cloud.xyz_mm[:, 2] > z_lo + 1) & (cloud.xyz_mm[:, 2] < z_hi - 1)]
        d = tree.query(xyz).distance_mm
        fit = fit_cylinder(xyz, axis_guess=np.array([0.0, 0.0, 1.0]))
        results.append({"method": method, "contrast": contrast, "points": len(xyz),
                        "rms_mm": float(np.sqrt(np.mean(d**2))), "diameter_mm": fit.diameter_mm,
                        "axis_mm": axis_mm, "u_h": cal.hinge_u_px, "d0": cal.d0_mm})
    return results


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--step-deg", type=float, default=2.0)
    ap.add_argument("--speckle", type=float, nargs="+", default=[0.0, 0.5, 1.0])
    ap.add_argument("--binning", type=int, default=1)
    ap.add_argument("--methods", nargs="+", default=["gaussian3", "cog"],
                    help="stripe detectors used for the reconstruction")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench-acc-") as tmp:
        for c in args.speckle:
            t0 = time.perf_counter()
            for r in run(c, args.step_deg, args.binning, Path(tmp), args.methods):
                print(f"speckle contrast {c:4.2f}, {r['method']:<9s}: smooth-part RMS to mesh "
                      f"{r['rms_mm']:.4f} mm, diameter {r['diameter_mm']:.4f} mm (truth 100), "
                      f"{r['points']} points, axis {r['axis_mm']:.3f} mm, u_h {r['u_h']:.2f} px, "
                      f"d0 {r['d0']:.3f} mm [{time.perf_counter() - t0:.0f} s]", flush=True)


if __name__ == "__main__":
    main()
