"""Point-to-mesh distance throughput (scheimpflug.scoring) against the alternatives, like with like.

For 1e6 points within ±0.1 mm of a cylinder surface (the scoring case: a
measured cloud against its true mesh), on a ~80 k and a ~1 M triangle mesh:
our tree build, our query rate and the accuracy against the analytic distance.
Then, on the same ``--subset`` points and in the same run, three comparisons
that say what each side includes:

* end to end — our build + query against point-cloud-utils'
  ``closest_points_on_mesh`` (libigl builds its AABB tree inside every call,
  so one call is build + query) and against trimesh's
  ``proximity.closest_point`` on a fresh mesh (its rtree is built on the
  first call; needs the optional ``rtree`` package);
* query only — our query against point-cloud-utils' call (which still
  includes its build: this ratio flatters us and is printed only beside the
  end-to-end one).

    .venv/bin/python benchmarks/bench_scoring.py [--points N] [--subset N]

point-cloud-utils is in the ``bench`` extra (``pip install -e '.[bench]'``).
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np


def cylinder_mesh(radius_mm: float, height_mm: float, sections: int, rings: int):
    """Closed cylinder, ``sections`` around, ``rings`` bands of quads along the height."""
    import trimesh

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
    ap.add_argument("--subset", type=int, default=200_000, help="points of the comparisons")
    args = ap.parse_args()
    import numba

    from scheimpflug.scoring import PointToMesh

    print(f"cores: {os.cpu_count()}, numba threads: {numba.get_num_threads()}, load {os.getloadavg()[0]:.2f}")
    PointToMesh(*_small()).query(np.zeros((10, 3)))          # compile / load the numba cache
    radius, height = 50.0, 108.0
    pts, truth = surface_points(args.points, radius, height)
    for sections, rings in ((2000, 20), (5000, 100)):
        mesh = cylinder_mesh(radius, height, sections, rings)
        pm, t_build = timed(PointToMesh, mesh.vertices, mesh.faces)
        res, t_q = timed(pm.query, pts)
        sag = radius * (1 - np.cos(np.pi / sections))
        err = np.abs(res.distance_mm - truth).max()
        print(f"\nmesh: {len(mesh.faces)} triangles (closed={pm.closed}), our build {t_build:.2f} s")
        print(f"  PointToMesh.query: {args.points} points in {t_q:.3f} s = {args.points / t_q / 1e6:.2f} M points/s"
              f"  (max |d - analytic| {err:.2e} mm, faceting sagitta {sag:.2e} mm, signed={res.signed})")
        _compare(mesh, pts[: args.subset], res.distance_mm[: args.subset])


def _compare(mesh, sub, ours) -> None:
    """Ours (build + query, and query alone) against point-cloud-utils and trimesh on ``sub``."""
    import point_cloud_utils as pcu
    import trimesh

    from scheimpflug.scoring import PointToMesh

    n = len(sub)
    pm, t_build = timed(PointToMesh, mesh.vertices, mesh.faces)
    _, t_query = timed(pm.query, sub)
    t_ours = t_build + t_query
    (d_pcu, _, _), t_pcu = timed(pcu.closest_points_on_mesh, sub, np.asarray(mesh.vertices),
                                 np.asarray(mesh.faces, dtype=np.int32))
    print(f"  {n} points, end to end (build + query): ours {t_ours:.3f} s "
          f"(build {t_build:.3f} + query {t_query:.3f}); point-cloud-utils {t_pcu:.3f} s "
          f"-> {t_pcu / t_ours:.1f}x; query alone vs point-cloud-utils' call {t_pcu / t_query:.1f}x "
          f"(max diff {np.abs(np.abs(ours) - d_pcu).max():.1e} mm)")
    fresh = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    k = min(n, 20_000)
    try:
        (_, d_tm, _), t_tm = timed(trimesh.proximity.closest_point, fresh, sub[:k])
    except ImportError as exc:
        print(f"  trimesh.proximity.closest_point: not run ({exc})")
        return
    _, t_query_k = timed(pm.query, sub[:k])
    print(f"  {k} points, end to end: trimesh closest_point (rtree built on first call) {t_tm:.2f} s, "
          f"ours {t_build + t_query_k:.3f} s -> {t_tm / (t_build + t_query_k):.0f}x "
          f"(max diff {np.abs(np.abs(ours[:k]) - d_tm).max():.1e} mm)")


def _small():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    return v, np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


if __name__ == "__main__":
    main()
