"""Stages: where the translation-stage plate and the rotary-stage part sit (4×4, float64).

Frames (INTERFACE.md "Stage conventions"):

* **rig frame** — origin at the lens centre, +x optical axis, +z up.
* **stage frame** — origin on the rotary axis at the height of the optical
  axis (z_rig = 0); +x = propagation direction e_p = (cos φ, −sin φ, 0);
  +z = rig +z; +y = z × x = the sheet normal n = (sin φ, cos φ, 0).  The sheet
  is the plane y = 0.  ``rig_from_stage = [e_p, n, e_z | H + D_axis·e_p]`` with
  H the object hinge and ``D_axis = axis_mm − d0_mm``.
* **part frame** — the frame of :mod:`scenes` parts: z = 0 on the stage
  table, the rotary axis is the z axis.
* **plate frame** — the calibration plate's part frame: its measured face is
  x = 0 (facing −x, toward the laser), its bottom at z = 0.

Rotary stage, ideal: ``stage_from_part(θ) = R_z(θ)·T(0, 0, rotary_table_z_mm)``,
θ > 0 counter-clockwise seen from above.

Rotary stage, imperfect (``rig.stage``):

* ``axis_tilt_deg`` τ toward ``axis_tilt_azimuth_deg`` ψ (0 = toward +x of the
  stage frame, 90 = toward +y): the bearing axis is the unit vector
  a = (sin τ cos ψ, sin τ sin ψ, cos τ), through the table centre
  (0, 0, rotary_table_z_mm).  The table — and the part on it — is
  perpendicular to that axis and turns about it.
* ``runout_um`` — radial runout as a dial indicator reads it (total indicator
  reading, peak to peak over one turn): the part's own axis is displaced from
  the bearing axis by e = runout/2 along the part's +x, so the displacement
  turns with the part (once per turn).

Together: ``stage_from_part(θ) = T(0, 0, z_t) · R_tilt · R_z(θ) · T(e, 0, 0)``,
where R_tilt turns e_z onto a about the horizontal axis (−sin ψ, cos ψ, 0).
With τ = 0 and e = 0 this is the ideal pose.  The *reference frame* of the
truth (``truth/mesh.ply``, truth points) is the stage frame with the part at
θ = 0: ``ref_from_part = stage_from_part(0)``.

Translation stage: the plate's measured face at stage coordinate s lies at
D = s − d0 from the object hinge:
``rig_from_plate(s) = [e_p, n, e_z | H + (s − d0)·e_p + calibration_table_z_mm·e_z]``.
"""

from __future__ import annotations

import math

import numpy as np

from scheimpflug.model.hinge import hinge_geometry
from scheimpflug.model.rig import Rig

__all__ = [
    "axis_distance_mm",
    "invert",
    "rig_from_plate",
    "rig_from_stage",
    "rotation_z",
    "stage_from_part",
    "stage_from_plate",
    "transform_points",
    "translation",
]


def translation(t_mm) -> np.ndarray:
    """Homogeneous translation.

    Parameters
    ----------
    t_mm : (3,) array_like
        Translation vector [mm].

    Returns
    -------
    (4, 4) float64
        T(t).
    """
    m = np.eye(4)
    m[:3, 3] = np.asarray(t_mm, dtype=np.float64)
    return m


def rotation_z(angle_deg: float) -> np.ndarray:
    """Homogeneous rotation about +z.

    Parameters
    ----------
    angle_deg : float
        Rotation angle, counter-clockwise seen from above (+z) [deg].

    Returns
    -------
    (4, 4) float64
        R_z(angle).
    """
    c, s = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))
    m = np.eye(4)
    m[:2, :2] = [[c, -s], [s, c]]
    return m


def _rotation_axis_angle(axis, angle_rad: float) -> np.ndarray:
    """4×4 Rodrigues rotation about the unit ``axis``."""
    k = np.asarray(axis, dtype=np.float64)
    k = k / np.linalg.norm(k)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    m = np.eye(4)
    m[:3, :3] = np.eye(3) + math.sin(angle_rad) * kx + (1 - math.cos(angle_rad)) * kx @ kx
    return m


def invert(b_from_a: np.ndarray) -> np.ndarray:
    """Inverse of a rigid transform.

    Parameters
    ----------
    b_from_a : (4, 4) array_like
        Rigid homogeneous transform (rotation + translation) [mm].

    Returns
    -------
    (4, 4) float64
        a_from_b = [Rᵀ | −Rᵀ·t]; exact only for a rigid transform (the
        rotation block is transposed, not inverted).

    Raises
    ------
    ValueError
        When ``b_from_a`` is not 4×4.
    """
    m = np.asarray(b_from_a, dtype=np.float64)
    if m.shape != (4, 4):
        raise ValueError(f"a transform must be 4×4, got shape {m.shape}")
    out = np.eye(4)
    out[:3, :3] = m[:3, :3].T
    out[:3, 3] = -m[:3, :3].T @ m[:3, 3]
    return out


def transform_points(b_from_a: np.ndarray, points_mm) -> np.ndarray:
    """Apply a homogeneous transform to points.

    Parameters
    ----------
    b_from_a : (4, 4) ndarray
        Transform from frame a to frame b [mm].
    points_mm : (..., 3) array_like
        Points in frame a [mm].

    Returns
    -------
    (..., 3) float64
        The points in frame b [mm].

    Raises
    ------
    ValueError
        When the points' last axis is not of length 3.
    """
    p = np.asarray(points_mm, dtype=np.float64)
    if p.shape[-1] != 3:
        raise ValueError(f"points must have shape (..., 3), got {p.shape}")
    return p @ b_from_a[:3, :3].T + b_from_a[:3, 3]


def axis_distance_mm(rig: Rig) -> float:
    """Distance of the rotary axis from the object hinge along the sheet.

    Parameters
    ----------
    rig : Rig
        The rig (``stage.axis_mm``, ``stage.d0_mm``).

    Returns
    -------
    float
        D_axis = axis_mm − d0_mm [mm].
    """
    return rig.stage.axis_mm - rig.stage.d0_mm


def _sheet_frame(rig: Rig, origin_mm) -> np.ndarray:
    g = hinge_geometry(rig)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2] = g.propagation_dir, g.sheet_normal, (0.0, 0.0, 1.0)
    m[:3, 3] = origin_mm
    return m


def rig_from_stage(rig: Rig) -> np.ndarray:
    """Pose of the stage frame in the rig frame.

    Parameters
    ----------
    rig : Rig
        The rig (hinge geometry, ``stage.axis_mm``, ``stage.d0_mm``).

    Returns
    -------
    (4, 4) float64
        rig_from_stage: rotation columns [e_p, n, e_z] (propagation direction,
        sheet normal, up), origin H + D_axis·e_p on the rotary axis at the
        height of the optical axis (H the object hinge) [mm].
    """
    g = hinge_geometry(rig)
    return _sheet_frame(rig, g.object_hinge_mm + axis_distance_mm(rig) * g.propagation_dir)


def stage_from_part(rig: Rig, angle_deg: float) -> np.ndarray:
    """Pose of a part on the rotary stage, in the stage frame.

    Parameters
    ----------
    rig : Rig
        The rig (``stage.rotary_table_z_mm``, ``axis_tilt_deg``,
        ``axis_tilt_azimuth_deg``, ``runout_um``).
    angle_deg : float
        Stage angle θ, counter-clockwise seen from above [deg].

    Returns
    -------
    (4, 4) float64
        stage_from_part [mm].

    Notes
    -----
    ``T(0, 0, z_t) · R_tilt · R_z(θ) · T(runout/2, 0, 0)`` (module docstring),
    R_tilt the rotation by τ that turns e_z onto the bearing axis; the ideal
    stage (τ = 0, no runout) gives ``R_z(θ)·T(0, 0, rotary_table_z_mm)``.
    """
    st = rig.stage
    tau, psi = math.radians(st.axis_tilt_deg), math.radians(st.axis_tilt_azimuth_deg)
    tilt = _rotation_axis_angle((-math.sin(psi), math.cos(psi), 0.0), tau)
    ecc = translation((0.5 * st.runout_um * 1e-3, 0.0, 0.0))
    return translation((0.0, 0.0, st.rotary_table_z_mm)) @ tilt @ rotation_z(angle_deg) @ ecc


def rig_from_plate(rig: Rig, stage_mm: float) -> np.ndarray:
    """Pose of the calibration plate in the rig frame.

    Parameters
    ----------
    rig : Rig
        The rig (hinge geometry, ``stage.d0_mm``, ``stage.calibration_table_z_mm``).
    stage_mm : float
        Translation-stage coordinate s of the plate's measured face [mm].

    Returns
    -------
    (4, 4) float64
        rig_from_plate: rotation columns [e_p, n, e_z], origin
        H + (s − d0)·e_p + calibration_table_z_mm·e_z [mm].
    """
    g = hinge_geometry(rig)
    D = stage_mm - rig.stage.d0_mm
    return _sheet_frame(rig, g.object_hinge_mm + D * g.propagation_dir
                        + rig.stage.calibration_table_z_mm * np.array([0.0, 0.0, 1.0]))


def stage_from_plate(rig: Rig, stage_mm: float) -> np.ndarray:
    """Pose of the calibration plate in the stage frame.

    Parameters
    ----------
    rig : Rig
        The rig.
    stage_mm : float
        Translation-stage coordinate s of the plate's measured face [mm].

    Returns
    -------
    (4, 4) float64
        stage_from_plate: a pure translation (s − axis_mm, 0,
        calibration_table_z_mm) [mm].
    """
    return invert(rig_from_stage(rig)) @ rig_from_plate(rig, stage_mm)
