"""`scheimpflug evaluate CLOUD.ply --mesh TRUTH [--model MODEL]`: point-to-mesh scores, the paper's fits,
and the two-sided scores of a surface model."""

from __future__ import annotations

import sys

from scheimpflug.app.commands._common import number, print_json

_FITS = ("plane", "plane-paper", "cylinder", "circle")


def add_parser(sub):
    p = sub.add_parser("evaluate", help="score a point cloud against the true mesh",
                       description="Point-to-mesh distances of a point cloud (signed when the mesh "
                                   "is closed), with a per-body breakdown and the paper's fits "
                                   "(plane, cylinder, circle in top view).")
    p.add_argument("cloud", metavar="CLOUD.ply", help="point cloud (from 'scheimpflug reconstruct')")
    p.add_argument("--mesh", required=True, metavar="TRUTH.ply",
                   help="true surface (PLY/STL/OBJ) in the cloud's frame (the twin's truth/mesh.ply)")
    p.add_argument("--fit", action="append", choices=_FITS, default=[],
                   help="also fit this shape to the points (repeatable; with --region, to that "
                        "region's points)")
    p.add_argument("--region", action="append", type=int, default=None, metavar="ID",
                   help="score and fit only the points nearest to this object id / body (repeatable)")
    p.add_argument("--z-range", nargs=2, type=number(-1e6, 1e6, unit="mm"), metavar=("ZMIN", "ZMAX"),
                   help="keep only points with ZMIN <= z <= ZMAX [mm] (e.g. the smooth band)")
    g = p.add_argument_group("two-sided scoring of a surface model (docs/howto/surface-model.md)")
    g.add_argument("--model", metavar="MODEL.ply|stl",
                   help="also score this surface model (from 'reconstruct --model') against the truth both "
                        "ways: coverage, Hausdorff and mean distances, volume error")
    g.add_argument("--samples", type=int, default=200_000, metavar="N",
                   help="area-uniform samples drawn on each surface (default 200000)")
    g.add_argument("--seed", type=int, default=0, help="seed of the samples (default 0)")
    g.add_argument("--coverage-mm", type=float, default=0.1, metavar="D",
                   help="a true point within D of the model is covered [mm] (default 0.1)")
    p.add_argument("--json", action="store_true", help="print the result as one JSON object")
    p.set_defaults(func=_run)
    return p


def _fits(names, xyz) -> dict:
    from scheimpflug.fitting import fit_circle_top_view, fit_cylinder, fit_plane, fit_plane_paper

    fns = {"plane": fit_plane, "plane-paper": fit_plane_paper, "circle": fit_circle_top_view,
           "cylinder": lambda p: fit_cylinder(p, axis_guess=[0.0, 0.0, 1.0])}
    out = {}
    for name in dict.fromkeys(names):
        try:
            out[name] = fns[name](xyz).to_dict()
        except ValueError as exc:
            out[name] = {"error": str(exc)}
    return out


def _select(args, cloud):
    """Points kept by --z-range, and the number of non-finite points left out."""
    import numpy as np

    from scheimpflug.errors import MeshError

    xyz = cloud.xyz_mm
    if len(xyz) == 0:
        raise MeshError(f"point cloud {args.cloud!r} is empty")
    from scheimpflug.scoring import MAX_COORDINATE_MM

    finite = np.all(np.isfinite(xyz), axis=1)
    dropped = int((~finite).sum())
    with np.errstate(invalid="ignore"):
        far = finite & np.any(np.abs(xyz) > MAX_COORDINATE_MM, axis=1)
    if dropped or far.any():
        print(f"warning: {dropped + int(far.sum())} of {len(xyz)} points of {args.cloud!r} have a "
              f"non-finite coordinate (NaN or inf: {dropped}) or one beyond ±{MAX_COORDINATE_MM:g} mm "
              f"({int(far.sum())}) and are left out", file=sys.stderr)
        xyz = xyz[finite & ~far]
        dropped += int(far.sum())
    if args.z_range:
        lo, hi = sorted(args.z_range)
        xyz = xyz[(xyz[:, 2] >= lo) & (xyz[:, 2] <= hi)]
    if len(xyz) == 0:
        raise MeshError(f"no finite points of {args.cloud!r} left to score"
                        + (f" in z {args.z_range}" if args.z_range else ""))
    return xyz, dropped


def _mismatch(xyz, vertices, distance_mm) -> str | None:
    """A gross unit, scale or placement mismatch of cloud and mesh (``scale_warning``), or None."""
    from scheimpflug.scoring import placement_mismatch, scale_mismatch

    return scale_mismatch(xyz, vertices) or placement_mismatch(xyz, distance_mm, vertices)


def _run(args) -> int:
    import numpy as np

    from scheimpflug.io.ply import read_mesh, read_point_cloud
    from scheimpflug.scoring import PointToMesh, body_labels, distance_stats

    cloud = read_point_cloud(args.cloud)
    xyz, dropped = _select(args, cloud)
    vertices, faces, ids = read_mesh(args.mesh)
    pm = PointToMesh(vertices, faces)
    res = pm.query(xyz)
    scale = _mismatch(xyz, vertices, res.distance_mm)
    labels_all = ids if ids is not None else body_labels(pm.faces)
    if ids is not None and len(ids) != len(pm.faces):
        from scheimpflug.errors import MeshError
        raise MeshError(f"{args.mesh!r}: object_id has {len(ids)} values for {len(pm.faces)} faces")
    labels = labels_all[res.face]
    keep = np.ones(len(xyz), bool)
    if args.region:
        keep = np.isin(labels, args.region)
        if not keep.any():
            from scheimpflug.errors import MeshError
            raise MeshError(f"no points lie nearest to region(s) {args.region} of {args.mesh!r} "
                            f"(known: {sorted(set(labels_all.tolist()))})")
    d = res.distance_mm[keep]
    out = {**distance_stats(d, res.signed), "distance_kind": "signed" if res.signed else "unsigned",
           "cloud": str(args.cloud), "mesh": str(args.mesh), "n_faces": int(len(pm.faces)),
           "n_points_read": len(cloud), "n_dropped": dropped, "scale_warning": scale}
    if args.region:
        out["region_filter"] = list(args.region)
    unique = np.unique(labels_all)
    if len(unique) > 1:
        out["region_key"] = "object_id" if ids is not None else "body"
        out["regions"] = {str(int(k)): distance_stats(res.distance_mm[keep & (labels == k)], res.signed)
                          for k in unique if np.any(keep & (labels == k))}
    if args.fit:
        out["fits"] = _fits(args.fit, xyz[keep])
    if args.model:
        from scheimpflug.app.model_scoring import score_model

        out.update(score_model(pm, labels_all, args.model, samples=args.samples, seed=args.seed,
                               coverage_mm=args.coverage_mm))
    if scale:
        print(f"warning: {scale}", file=sys.stderr)
    _print(out, args)
    return 0


def _print(out: dict, args) -> None:
    if args.json:
        print_json(out)
        return
    print(f"{out['n_points']} points vs {out['n_faces']} faces ({out['distance_kind']} distance): "
          f"RMS {out['rms_mm']:.4f} mm, mean |d| {out['mean_abs_mm']:.4f} mm, "
          f"p95 {out['p95_mm']:.4f} mm, max {out['max_mm']:.4f} mm")
    if "mean_signed_mm" in out:
        print(f"  signed mean {out['mean_signed_mm']:+.4f} mm, std {out['std_signed_mm']:.4f} mm, "
              f"{100 * out['fraction_inside']:.1f} % inside")
    for k, s in out.get("regions", {}).items():
        print(f"  {out['region_key']} {k}: {s['n_points']} points, RMS {s['rms_mm']:.4f} mm, "
              f"p95 {s['p95_mm']:.4f} mm, max {s['max_mm']:.4f} mm")
    for name, fit in out.get("fits", {}).items():
        shown = {k: v for k, v in fit.items() if k != "n_points"}
        print(f"  fit {name}: " + ", ".join(f"{k}={_fmt(v)}" for k, v in shown.items()))
    if "coverage" in out:
        from scheimpflug.app.model_scoring import model_lines

        print("\n".join(model_lines(out)))
    sys.stdout.flush()


def _fmt(v):
    if isinstance(v, float):
        return f"{v:.6g}"
    if isinstance(v, list):
        return "[" + ", ".join(f"{x:.6g}" for x in v) + "]"
    return str(v)
