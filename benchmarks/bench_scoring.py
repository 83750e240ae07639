"""Point-to-mesh distance throughput (scheimpflug.scoring) against the alternatives.

Prints points/s of ``PointToMesh.query`` for 1e6 points within ±0.1 mm of a
cylinder surface (the scoring case: a measured cloud against its true mesh)
for a ~80k and a ~1M triangle mesh, the tree build time, the accuracy against
the analytic distance, and, in the same run on a subset, the rate of
point-cloud-utils' ``closest_points_on_mesh`` and of trimesh's
``proximity.closest_point`` (which needs the optional ``rtree`` package) as
ratios.

    .venv/bin/python benchmarks/bench_scoring.py [--points N] [--subset N]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np


def cylinder_mesh(radius_mm: float, height_mm: float, sections: int, rings: int):
    """Closed cylinder, ``sections`` around, ``rings`` bands of quads along the height."""
    import trimesh

    m = trimesh.creation.cylinder(radius=radius_mm, height=height_mm, sections=sections)
    # split the long side quads into bands so the mesh resembles a scanned part's tessellation
    z = np.linspace(-height_mm / 2, height_mm / 2, rings + 1)
    ang = np.linspace(0, 2 * np.pi, sections, endpoint=False)
    ring = np.stack([np.cos(ang) * radius_mm, np.sin(ang) * radius_mm], axis=1)
    v = np.concatenate([np.column_stack([ring, np.full(sections, zz)]) for zz in z])
    faces = []
    for r in range(rings):
        a = r * sections + np.arange(sections)
        b = r * sections + (np.arange(sections) + 1) % sections
        faces += [np.column_stack([a, b, b + sections]), np.column_stack([a, b + sections, a + sections])]
    c0, c1 = len(v), len(v) + 1
    v = np.vstack([v, [0, 0, -height_mm / 2], [0, 0, height_mm / 2]])
    a = np.arange(sections)
    b = (a + 1) % sections
    faces += [np.column_stack([np.full(sections, c0), b, a]),
              np.column_stack([np.full(sections, c1), a + rings * sections, b + rings * sections])]
    return trimesh.Trimesh(v, np.vstack(faces), process=False)


def surface_points(n: int, radius_mm: float, height_mm: float, seed: int = 0):
    rng = np.random.default_rng(seed)
    ang = rng.uniform(0, 2 * np.pi, n)
    z = rng.uniform(-0.45 * height_mm, 0.45 * height_mm, n)
    r = radius_mm + rng.uniform(-0.1, 0.1, n)
    return np.column_stack([r * np.cos(ang), r * np.sin(ang), z]), r - radius_mm


def timed(fn, *args):
    t0 = time.perf_counter()
    out = fn(*args)
    return out, time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--subset", type=int, default=20_000)
    args = ap.parse_args()
    import numba

    from scheimpflug.scoring import PointToMesh

    print(f"cores: {os.cpu_count()}, numba threads: {numba.get_num_threads()}")
    PointToMesh(*_small()).query(np.zeros((10, 3)))          # compile / load the numba cache
    radius, height = 50.0, 108.0
    pts, truth = surface_points(args.points, radius, height)
    for sections, rings in ((2000, 20), (5000, 100)):
        mesh = cylinder_mesh(radius, height, sections, rings)
        pm, t_build = timed(PointToMesh, mesh.vertices, mesh.faces)
        res, t_q = timed(pm.query, pts)
        sag = radius * (1 - np.cos(np.pi / sections))
        err = np.abs(res.distance_mm - truth).max()
        print(f"\nmesh: {len(mesh.faces)} triangles (closed={pm.closed}), build {t_build:.2f} s")
        print(f"  PointToMesh.query: {args.points} points in {t_q:.3f} s = {args.points / t_q / 1e6:.2f} M points/s"
              f"  (max |d - analytic| {err:.2e} mm, faceting sagitta {sag:.2e} mm, signed={res.signed})")
        sub = pts[: args.subset]
        _, t_sub = timed(pm.query, sub)
        _compare(mesh, sub, t_sub, res.distance_mm[: args.subset], args.points / t_q)


def _compare(mesh, sub, t_sub, ours, full_rate) -> None:
    """Rates on the subset; ratios both on the subset and against the full-run rate."""
    import point_cloud_utils as pcu

    n = len(sub)
    (d_pcu, _, _), t_pcu = timed(pcu.closest_points_on_mesh, sub, np.asarray(mesh.vertices),
                                 np.asarray(mesh.faces, dtype=np.int32))
    print(f"  subset {n}: ours {n / t_sub / 1e6:.2f} M/s; point-cloud-utils closest_points_on_mesh "
          f"{n / t_pcu / 1e6:.3f} M/s -> ratio {t_pcu / t_sub:.1f}x on the subset, "
          f"{full_rate * t_pcu / n:.0f}x vs the full run "
          f"(max diff {np.abs(np.abs(ours) - d_pcu).max():.1e} mm)")
    try:
        import trimesh
        (_, d_tm, _), t_tm = timed(trimesh.proximity.closest_point, mesh, sub)
    except ImportError as exc:
        print(f"  trimesh.proximity.closest_point: not run ({exc})")
        return
    print(f"  trimesh closest_point {n / t_tm / 1e6:.4f} M/s -> ratio {t_tm / t_sub:.1f}x on the subset, "
          f"{full_rate * t_tm / n:.0f}x vs the full run "
          f"(max diff {np.abs(np.abs(ours) - d_tm).max():.1e} mm)")


def _small():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    return v, np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


if __name__ == "__main__":
    main()
