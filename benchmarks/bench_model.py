"""Surface models: meshing time against reconstruction time, and the grid method against Poisson.

    python benchmarks/bench_model.py [--scan DIR] [--pile DIR] [--repeat 3] [--poisson]

``--scan`` is a rendered 720-frame scan of the paper's cylinder (e.g. the
``cylinder/`` folder of a full ``scheimpflug demo`` run; without it, one is
rendered at full resolution into a temporary folder, ≈ 1–2 min).  The scan is
reconstructed with the rig's true constants (``truth/rig_truth.json``):

* **reconstruction**: ``extract_folder`` (decode + stripe extraction, threads)
  + ``reconstruct_profiles`` — the cloud, best of ``--repeat``;
* **meshing**: ``model_from_cloud`` on that cloud (table closed on the rig's
  table plane) — best of ``--repeat``;

and prints both and their ratio (the issue asks for meshing ≤ 10 % of the
reconstruction).  With ``--poisson`` (needs Open3D) it also builds Open3D's
screened Poisson surface of the cylinder and, with ``--pile DIR``, of the pile,
and prints for both methods the volume against the truth mesh, the coverage,
the symmetric mean and Hausdorff distances and the time.
"""

import argparse
import json
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np


def _calibration(scan: Path):
    t = json.loads((scan / "truth" / "rig_truth.json").read_text())
    cal = SimpleNamespace(hinge_u_px=t["hinge_u_px"], hinge_v_px=t["hinge_v_px"], F2_px_mm=t["F2_px_mm"],
                          d0_mm=t["d0_mm"], C_mm=t["C_mm"])
    return cal, t["axis_mm"]


def _best(fn, repeat):
    times, out = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), out


def _render_cylinder(root: Path) -> Path:
    from scheimpflug.app.cli import main

    out = root / "cylinder"
    assert main(["render", "rotary", "--part", "cylinder", "--step-deg", "0.5", "--truth-pixels", "none",
                 "--out", str(out), "--quiet"]) == 0
    return out


def _cloud(scan: Path):
    from scheimpflug.io.frames import open_frame_folder
    from scheimpflug.reconstruct import extract_folder, reconstruct_profiles

    cal, axis = _calibration(scan)
    ff = open_frame_folder(scan)
    rows, us, peaks, _ = extract_folder(ff, "cog")
    return reconstruct_profiles(rows, us, [r.angle_deg for r in ff.frames], cal, axis, intensity=peaks)


def _table_z(scan: Path) -> float:
    return json.loads((scan / "manifest.json").read_text())["rig"]["stage"]["rotary_table_z_mm"]


def timing(scan: Path, repeat: int):
    from scheimpflug.meshing import ModelSettings, model_from_cloud

    t_rec, cloud = _best(lambda: _cloud(scan), repeat)
    settings = ModelSettings(table_z_mm=_table_z(scan))
    t_mesh, model = _best(lambda: model_from_cloud(cloud, settings), repeat)
    print(f"scan {scan}: {len(cloud)} points from {len(np.unique(cloud.frame))} frames")
    print(f"  reconstruction (extract + reconstruct_profiles): {t_rec:.2f} s")
    print(f"  meshing (model_from_cloud): {t_mesh:.3f} s → {len(model.faces)} faces, {model.n_bodies} body(ies)")
    print(f"  meshing / reconstruction: {100 * t_mesh / t_rec:.1f} %")
    return cloud, model, t_mesh


def compare(name: str, scan: Path, cloud, grid_model, t_grid: float) -> None:
    from scheimpflug.app.model_scoring import score_model_mesh
    from scheimpflug.io.ply import read_mesh
    from scheimpflug.poisson import poisson_model
    from scheimpflug.scoring import PointToMesh

    v, f, oid = read_mesh(scan / "truth" / "mesh.ply")
    pm = PointToMesh(v, f)
    labels = oid if oid is not None else np.zeros(len(f), np.int64)
    t0 = time.perf_counter()
    poisson = poisson_model(cloud)
    t_poisson = time.perf_counter() - t0
    for method, m, t in (("grid", grid_model, t_grid), ("poisson", poisson, t_poisson)):
        s, _ = score_model_mesh(pm, labels, m.vertices_mm, m.faces, m.face_body, m.face_fill,
                                samples=200_000, seed=0)
        rel = 100 * s["volume_error_mm3"] / s["true_volume_mm3"]
        print(f"  {name:8s} {method:8s} volume {s['volume_mm3']:.6g} mm³ (truth {s['true_volume_mm3']:.6g}, "
              f"{rel:+.3f} %), coverage {100 * s['coverage']:.1f} %, mean {s['mean_mm']:.4f} mm, "
              f"Hausdorff {s['hausdorff_mm']:.3f} mm, watertight {s['model_watertight']}, {t:.2f} s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scan", type=Path, help="720-frame cylinder scan (default: render one)")
    ap.add_argument("--pile", type=Path, help="pile scan for the Poisson comparison")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--poisson", action="store_true", help="compare with Open3D's Poisson surface")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        scan = args.scan or _render_cylinder(Path(tmp))
        cloud, model, t_mesh = timing(scan, args.repeat)
        if args.poisson:
            compare("cylinder", scan, cloud, model, t_mesh)
            if args.pile:
                from scheimpflug.meshing import ModelSettings, model_from_cloud

                pile_cloud = _cloud(args.pile)
                t0 = time.perf_counter()
                pile_model = model_from_cloud(pile_cloud, ModelSettings(table_z_mm=_table_z(args.pile)))
                compare("pile", args.pile, pile_cloud, pile_model, time.perf_counter() - t0)


if __name__ == "__main__":
    main()
