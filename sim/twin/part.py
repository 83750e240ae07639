"""The part's model from its own scan, in the frame the twin renders parts in.

A real rotary scan's stripe points, the housing's taken out
(:func:`scheimpflug.still_points.separate_housing`) and only those on the lines where
the stripe moves (the ``part`` region of :func:`scheimpflug.still_points.still_regions`:
not the walls, not the turntable's own line), are mapped through the calibration into
the pipeline's part frame of a calibrated axis (:func:`scheimpflug.reconstruct.reconstruct_profiles`),
meshed by the grid rule of :mod:`scheimpflug.meshing` (watertight bodies, closed on the
table plane), and moved into the part frame of :mod:`scenes` parts, the frame
``render rotary --part MESH`` places on the table: z = 0 on the table's top, z its up,
the rotary axis the z axis.  Points lower than :data:`TABLE_CLEARANCE_MM` above the
table's top are left out (the table's own stripe meets the part's foot there, and a
detector's noise puts some of them below the table); the grid rule closes the part's
foot on the table's plane.

The two frames (:mod:`sim.stages`): the truth's reference frame of a rig whose table is
the calibration's turntable is the turntable's own frame, which is the pipeline's part
frame of its calibrated axis; a part is placed in it by ``ref_from_part = ref_from_stage
· stage_from_part(0)``.  So the model's vertices go into the part frame by
``part_from_ref = ref_from_part⁻¹``, and the twin's part stands where the real one stood
(its axis the table's, its foot on the table's plane).

Bodies: the grid rule keeps every surface it can close as its own body; noise and the
table's fringe give small ones.  Bodies below :data:`MIN_BODY_SHARE` of the largest's
volume are left out, and the count is said.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scheimpflug.errors import MeshError

__all__ = ["MIN_BODY_SHARE", "PartModel", "part_model", "part_from_reference"]

MIN_BODY_SHARE = 0.01     # a body under this share of the largest body's volume is noise, not the part [-]
TABLE_CLEARANCE_MM = 0.5  # points lower than this above the table's top are the table's or the foot's noise [mm]


@dataclass(frozen=True)
class PartModel:
    """The part's mesh from a scan (module docstring).

    Parameters
    ----------
    vertices_mm : (nv, 3) ndarray float64
        Vertices in the part frame (z = 0 on the table's top, the axis the z axis) [mm].
    faces : (m, 3) ndarray int64
        Triangles, outward normals.
    n_points : int
        Stripe points meshed [-].
    n_bodies : int
        Bodies kept [-].
    n_bodies_dropped : int
        Small bodies left out [-].
    volume_mm3 : float
        Volume of the kept bodies [mm³].
    """

    vertices_mm: np.ndarray
    faces: np.ndarray
    n_points: int
    n_bodies: int
    n_bodies_dropped: int
    volume_mm3: float

    def to_json_dict(self) -> dict:
        """The figures as a JSON-ready dict.

        Returns
        -------
        dict
            ``n_points``, ``n_bodies``, ``n_bodies_dropped``, ``volume_mm3``, ``n_faces`` and the
            height range ``z_range_mm``.
        """
        z = self.vertices_mm[:, 2]
        return {"n_points": self.n_points, "n_bodies": self.n_bodies, "n_bodies_dropped": self.n_bodies_dropped,
                "volume_mm3": self.volume_mm3, "n_faces": int(len(self.faces)),
                "z_range_mm": [float(z.min()), float(z.max())]}


def part_from_reference(rig) -> np.ndarray:
    """The transform from the truth's reference frame (the pipeline's part frame) to the part frame.

    Parameters
    ----------
    rig : Rig
        The twin's rig (its stage: axis tilt, offset, table height).

    Returns
    -------
    (4, 4) ndarray float64
        ``part_from_ref = (ref_from_stage · stage_from_part(0))⁻¹`` (:mod:`sim.stages`).
    """
    from sim.stages import ref_from_stage, stage_from_part

    return np.linalg.inv(ref_from_stage(rig) @ stage_from_part(rig, 0.0))


def _signed_volume(v: np.ndarray, f: np.ndarray) -> float:
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def _keep_bodies(model) -> tuple[np.ndarray, np.ndarray, int, int, float]:
    """The bodies of at least MIN_BODY_SHARE of the largest's volume: vertices, faces (reindexed), counts."""
    bodies = np.unique(model.face_body)
    vols = np.array([abs(_signed_volume(model.vertices_mm, model.faces[model.face_body == b])) for b in bodies])
    keep = bodies[vols >= MIN_BODY_SHARE * vols.max()]
    faces = model.faces[np.isin(model.face_body, keep)]
    used, inverse = np.unique(faces, return_inverse=True)
    return (model.vertices_mm[used], inverse.reshape(-1, 3).astype(np.int64), int(len(keep)),
            int(len(bodies) - len(keep)), float(vols[np.isin(bodies, keep)].sum()))


def part_model(stripes, angles_deg, calibration, rig) -> PartModel:
    """The part's watertight mesh from its scan's part points (module docstring).

    Parameters
    ----------
    stripes : FolderStripes
        The part's stripe points only (housing and table taken out: :meth:`FolderStripes.select`).
    angles_deg : sequence of float
        Each frame's turntable angle [deg].
    calibration : SheetModel
        The scan's calibration, with its turntable axis (FabScan's, a target calibration with
        table poses).
    rig : Rig
        The twin's rig from that calibration (``rig from-calibration``): its table gives the
        part frame.

    Returns
    -------
    PartModel
        The mesh in the part frame.

    Raises
    ------
    MeshError
        No rotary axis in the calibration, or no body the grid rule can close.
    """
    from scheimpflug.meshing import ModelSettings, model_from_cloud
    from scheimpflug.reconstruct import calibration_axis, reconstruct_profiles

    if calibration_axis(calibration) is None:
        raise MeshError("the part's model needs the calibration's turntable axis (FabScan's config, a target "
                        "calibration with table poses); this calibration has none")
    cloud = reconstruct_profiles(stripes.rows, stripes.u, list(angles_deg), calibration, None,
                                 intensity=stripes.peak, snr=stripes.snr, along=stripes.along)
    if len(cloud) == 0:
        raise MeshError("no part point to mesh (every stripe point was the housing's or the table's)")
    part_from_ref = part_from_reference(rig)
    ref_from_part = np.linalg.inv(part_from_ref)
    table_z = float(ref_from_part[2, 3])             # the table's top in the pipeline's part frame
    height = cloud.xyz_mm @ part_from_ref[2, :3] + part_from_ref[2, 3]
    cloud = cloud.select(height >= TABLE_CLEARANCE_MM)
    if len(cloud) == 0:
        raise MeshError(f"no part point stands {TABLE_CLEARANCE_MM} mm above the table")
    model = model_from_cloud(cloud, ModelSettings(table_z_mm=table_z))
    if len(model.faces) == 0:
        raise MeshError(f"the grid rule closed no body from the {len(cloud)} part points")
    v, f, n_bodies, dropped, volume = _keep_bodies(model)
    v = v @ part_from_ref[:3, :3].T + part_from_ref[:3, 3]
    return PartModel(v, f, int(len(cloud)), n_bodies, dropped, volume)
