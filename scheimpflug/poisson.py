"""The generic alternative: screened Poisson surface reconstruction of any point cloud (Open3D).

Where the grid method of :mod:`scheimpflug.meshing` cannot apply — a cloud
without rotary provenance (a user's cloud from another instrument, a merged
cloud) — a Poisson reconstruction (Kazhdan & Hoppe 2013) fits an implicit
surface to oriented points and extracts its zero level set.  It needs
normals: for a rotary scan they are turned toward the laser of the point's
frame (the laser comes from −x of the stage frame, i.e. from
R_z(−θ)·(−1, 0, 0) in the part frame); for a cloud without angles, away from
the cloud's centroid (right for convex, centred parts only).  The Poisson
surface is smooth where the grid method is exact, and it closes every hole
by its own extrapolation rather than by a stated rule.  Faces farther than
``support_mm`` from every measured point are marked *not measured*
(:data:`scheimpflug.meshing.FILL_GAP`).

Open3D is an optional dependency (``pip install .[poisson]``; on Linux it
also needs the system's libusb-1.0).  Without it :func:`poisson_model`
raises a :class:`~scheimpflug.errors.MeshError` that says so.

References
----------
M. Kazhdan, H. Hoppe, "Screened Poisson surface reconstruction", ACM TOG 32(3), 2013.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from scheimpflug.errors import MeshError
from scheimpflug.meshing import FILL_GAP, FILL_MEASURED, SurfaceModel

__all__ = ["poisson_model"]


def _open3d():
    try:
        import open3d
    except Exception as exc:  # ImportError, or a missing system library (OSError)
        raise MeshError("the Poisson reconstruction needs Open3D, an optional dependency: "
                        f"pip install 'scheimpflug[poisson]' ({type(exc).__name__}: {exc})") from None
    return open3d


def _normals_towards_sensor(o3d, pcd, cloud) -> None:
    angle = np.asarray(cloud.angle_deg, np.float64)
    normals = np.asarray(pcd.normals)
    if np.all(np.isfinite(angle)):
        th = np.radians(angle)
        toward = np.stack([-np.cos(th), np.sin(th), np.zeros_like(th)], axis=1)
    else:
        toward = cloud.xyz_mm - cloud.xyz_mm.mean(axis=0)
    flip = np.einsum("ij,ij->i", normals, toward) < 0
    normals[flip] *= -1.0
    pcd.normals = o3d.utility.Vector3dVector(normals)


def poisson_model(cloud, depth: int = 9, support_mm: float = 1.0, neighbours: int = 30) -> SurfaceModel:
    """Screened Poisson surface of a point cloud (module docstring).

    Parameters
    ----------
    cloud : scheimpflug.reconstruct.PointCloud
        Points in the part frame [mm]; rotary angles [deg] when known.
    depth : int
        Octree depth of the Poisson solve [-] (9: 512 cells across the cloud).
    support_mm : float
        Faces farther than this from every point are marked not measured [mm].
    neighbours : int
        Points used to estimate each normal [-].

    Returns
    -------
    SurfaceModel
        The Poisson surface, one body (``face_body`` 0); ``step_deg`` and
        ``max_step_mm`` are NaN.

    Raises
    ------
    MeshError
        Open3D missing, fewer than 100 points, or an empty reconstruction.
    """
    o3d = _open3d()
    if len(cloud) < 100:
        raise MeshError(f"the Poisson reconstruction needs at least 100 points, the cloud has {len(cloud)}")
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(cloud.xyz_mm, np.float64)))
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn=neighbours))
    _normals_towards_sensor(o3d, pcd, cloud)
    mesh, _ = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(pcd, depth=depth)
    v, f = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.triangles, np.int64)
    if len(f) == 0:
        raise MeshError("the Poisson reconstruction returned no surface")
    dist, _ = cKDTree(cloud.xyz_mm).query(v[f].mean(axis=1))
    fill = np.where(dist <= support_mm, FILL_MEASURED, FILL_GAP).astype(np.uint8)
    return SurfaceModel(vertices_mm=v, faces=f, face_fill=fill, face_body=np.zeros(len(f), np.int64),
                        n_points_used=len(cloud), n_points_unused=0, step_deg=float("nan"),
                        max_step_mm=float("nan"))
