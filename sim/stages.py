"""Stages: where the translation-stage plate and the rotary-stage part sit (4×4, float64).

Frames (docs/reference/interface.md "Stage conventions"):

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
  (0, δ, rotary_table_z_mm) (``axis_offset_mm`` δ: an axis that misses the
  sheet).  The table — and the part on it — is perpendicular to that axis
  and turns about it.  τ over 170° is a table whose up is the stage's −z (a
  rig frame upside down in the world, ``[stage] axis_tilt_deg``).
* ``runout_um`` — radial runout as a dial indicator reads it (total indicator
  reading, peak to peak over one turn): the part's own axis is displaced from
  the bearing axis by e = runout/2 along the part's +x, so the displacement
  turns with the part (once per turn).

Together: ``stage_from_part(θ) = T(0, δ, z_t) · R_tilt · R_z(θ) · T(e, 0, 0)``,
where R_tilt turns e_z onto a about the horizontal axis (−sin ψ, cos ψ, 0).
With τ = 0 and e = 0 this is the ideal pose.  The *reference frame* of the
truth (``truth/mesh.ply``, truth points) is the stage frame with the part at
θ = 0: ``ref_from_part = ref_from_stage · stage_from_part(0)``, where
:func:`ref_from_stage` is the identity for a table up the stage's +z, and for
one up its −z (τ > 170°: an instrument's calibrated turntable) the
turntable's own frame — z its up, as the pipeline's part frame of a
calibrated axis.

Rotary stage, error motions (:class:`RotaryState`; each off at 0): the table
turns to θ_a = θ + A·sin θ + ε for a command θ (``rotary_eccentricity_deg`` A,
an eccentric encoder or worm wheel, zero at home; ε ~ N(0, σ²) per move,
``rotary_repeatability_deg`` σ); at θ_a its tilt error motion is a rotation by
the vector W·(cos 2θ_a, sin 2θ_a, 0) (``wobble_urad`` W) about the table centre
and its radial error motion the shift R·(cos 2θ_a, sin 2θ_a, 0)
(``radial_error_um`` R), both twice per turn — the once-per-turn parts are a
constant tilt and a centring error, which ``axis_tilt_deg`` and ``runout_um``
already are.  With them
``stage_from_part(θ) = T(r(θ_a)) · T(0, δ, z_t) · R(w(θ_a)) · R_tilt · R_z(θ_a) · T(e, 0, 0)``.
The truth's reference frame stays the ideal stage at θ = 0.

Translation stage: the plate's measured face at stage coordinate s lies at
D = s − d0 from the object hinge:
``rig_from_plate(s) = [e_p, n, e_z | H + (s − d0)·e_p + calibration_table_z_mm·e_z]``.

Translation stage, errors (:class:`TranslationState`; each off at 0).  For a
command s the carriage goes to s_a = s·(1 + k·1e-6) + A·sin(2π s / lead) + ε
(``translation_scale_ppm`` k, ``translation_periodic_um`` A, ε ~ N(0, σ²) per
move, ``translation_repeatability_um`` σ); with x = s/L (L =
``translation_travel_mm``) it is displaced by 4x(1 − x)·S_lat along the sheet
normal and 4x(1 − x)·S_vert up (``straightness_*``), and turned by
(2x − 1)·P about the sheet normal (pitch: the top toward +propagation) and
(2x − 1)·Y about the vertical (yaw), about the carriage point under the
plate's measured face (``pitch_urad``, ``yaw_urad``):
``rig_from_plate(s) = [e_p, n, e_z | H + (s_a − d0)·e_p + z_c·e_z + lat·n + vert·e_z] · R_z(yaw) · R_n(pitch)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from scheimpflug.model.hinge import hinge_geometry
from scheimpflug.model.rig import Rig

__all__ = [
    "RotaryState",
    "TranslationState",
    "axis_distance_mm",
    "invert",
    "ref_from_stage",
    "rig_from_plate",
    "rig_from_stage",
    "rotary_state",
    "rotation_vector",
    "rotation_z",
    "stage_from_part",
    "stage_from_plate",
    "transform_points",
    "translation",
    "translation_state",
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


def ref_from_stage(rig: Rig) -> np.ndarray:
    """The truth's reference frame from the stage frame (module docstring).

    Parameters
    ----------
    rig : Rig
        The rig (``stage.axis_tilt_deg``, ``axis_tilt_azimuth_deg``, ``axis_offset_mm``,
        ``rotary_table_z_mm``).

    Returns
    -------
    (4, 4) float64
        The identity for a table whose up is the stage's +z (τ < 90°: its tilt is an error the
        truth shows).  For one whose up is the stage's −z (τ > 170°, which only an instrument's
        calibrated turntable gives, :mod:`scheimpflug.model.instrument`) the turntable's own
        frame, the pipeline's part frame of a calibrated axis: z its up a, the origin on its
        axis where it crosses the stage's z = 0 (the optical axis's height), x the propagation
        direction made perpendicular to a, y = z × x.
    """
    st = rig.stage
    if st.axis_tilt_deg < 90.0:
        return np.eye(4)
    tau, psi = math.radians(st.axis_tilt_deg), math.radians(st.axis_tilt_azimuth_deg)
    z = np.array([math.sin(tau) * math.cos(psi), math.sin(tau) * math.sin(psi), math.cos(tau)])
    x = np.array([1.0, 0.0, 0.0]) - z[0] * z
    x /= np.linalg.norm(x)
    rot = np.vstack([x, np.cross(z, x), z])
    origin = np.array([0.0, st.axis_offset_mm, st.rotary_table_z_mm]) - (st.rotary_table_z_mm / z[2]) * z
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = rot, -rot @ origin
    return m


def rotation_vector(vector_rad) -> np.ndarray:
    """Homogeneous rotation by a rotation vector (axis × angle).

    Parameters
    ----------
    vector_rad : (3,) array_like
        Rotation vector: unit axis times the angle [rad]; zero = identity.

    Returns
    -------
    (4, 4) float64
        The rotation (Rodrigues), about the origin.
    """
    v = np.asarray(vector_rad, dtype=np.float64)
    angle = float(np.linalg.norm(v))
    if angle == 0.0:
        return np.eye(4)
    return _rotation_axis_angle(v / angle, angle)


@dataclass(frozen=True)
class RotaryState:
    """Where an erring rotary stage really is for one command (module docstring).

    Parameters
    ----------
    command_deg : float
        Commanded angle θ [deg].
    angle_deg : float
        Angle the table really turned to, θ_a [deg].
    wobble_urad : (2,) tuple of float
        Tilt error motion, the x and y components of the rotation vector in the
        stage frame [µrad].
    radial_um : (2,) tuple of float
        Radial error motion, the table centre's shift along stage x and y [µm].
    """

    command_deg: float
    angle_deg: float
    wobble_urad: tuple = (0.0, 0.0)
    radial_um: tuple = (0.0, 0.0)

    def to_dict(self) -> dict:
        """The realised values for the manifest.

        Returns
        -------
        dict
            ``angle_deg``, ``angle_error_deg``, ``wobble_urad`` [x, y],
            ``radial_um`` [x, y].
        """
        return {"angle_deg": self.angle_deg, "angle_error_deg": self.angle_deg - self.command_deg,
                "wobble_urad": list(self.wobble_urad), "radial_um": list(self.radial_um)}


def rotary_state(rig: Rig, angle_deg: float, z: float = 0.0) -> RotaryState:
    """The rotary stage's real angle and error motions for a commanded angle.

    Parameters
    ----------
    rig : Rig
        The rig (``rotary_eccentricity_deg``, ``rotary_repeatability_deg``,
        ``wobble_urad``, ``radial_error_um``).
    angle_deg : float
        Commanded angle θ [deg].
    z : float, default 0.0
        Standard normal draw of this move's random angle error [-].

    Returns
    -------
    RotaryState
        θ_a = θ + A·sin θ + σ·z; wobble W·(cos 2θ_a, sin 2θ_a) [µrad] and radial
        error motion R·(cos 2θ_a, sin 2θ_a) [µm] (module docstring).
    """
    st = rig.stage
    actual = angle_deg + st.rotary_eccentricity_deg * math.sin(math.radians(angle_deg)) \
        + st.rotary_repeatability_deg * z
    c, s = math.cos(2 * math.radians(actual)), math.sin(2 * math.radians(actual))
    return RotaryState(float(angle_deg), float(actual), (st.wobble_urad * c, st.wobble_urad * s),
                       (st.radial_error_um * c, st.radial_error_um * s))


def stage_from_part(rig: Rig, angle_deg: float, state: RotaryState | None = None) -> np.ndarray:
    """Pose of a part on the rotary stage, in the stage frame.

    Parameters
    ----------
    rig : Rig
        The rig (``stage.rotary_table_z_mm``, ``axis_tilt_deg``,
        ``axis_tilt_azimuth_deg``, ``axis_offset_mm``, ``runout_um``).
    angle_deg : float
        Stage angle θ, counter-clockwise seen from above [deg].
    state : RotaryState, optional
        The erring stage's real angle and error motions for this command
        (:func:`rotary_state`); None = the stage goes exactly to ``angle_deg``.

    Returns
    -------
    (4, 4) float64
        stage_from_part [mm].

    Notes
    -----
    ``T(r) · T(0, δ, z_t) · R(w) · R_tilt · R_z(θ_a) · T(runout/2, 0, 0)``
    (module docstring), R_tilt the rotation by τ that turns e_z onto the
    bearing axis; the ideal stage (τ = 0, no runout, no state) gives
    ``R_z(θ)·T(0, 0, rotary_table_z_mm)``.
    """
    st = rig.stage
    tau, psi = math.radians(st.axis_tilt_deg), math.radians(st.axis_tilt_azimuth_deg)
    tilt = _rotation_axis_angle((-math.sin(psi), math.cos(psi), 0.0), tau)
    ecc = translation((0.5 * st.runout_um * 1e-3, 0.0, 0.0))
    table = translation((0.0, st.axis_offset_mm, st.rotary_table_z_mm))
    if state is None:
        return table @ tilt @ rotation_z(angle_deg) @ ecc
    wob = rotation_vector([1e-6 * state.wobble_urad[0], 1e-6 * state.wobble_urad[1], 0.0])
    radial = translation([1e-3 * state.radial_um[0], 1e-3 * state.radial_um[1], 0.0])
    return radial @ table @ wob @ tilt @ rotation_z(state.angle_deg) @ ecc


@dataclass(frozen=True)
class TranslationState:
    """Where an erring translation stage really puts its carriage for one command.

    Parameters
    ----------
    command_mm : float
        Commanded stage coordinate s [mm].
    stage_mm : float
        Coordinate the carriage really went to, s_a [mm].
    lateral_um : float, default 0.0
        Straightness deviation along the sheet normal [µm].
    vertical_um : float, default 0.0
        Straightness deviation up [µm].
    pitch_urad : float, default 0.0
        Pitch of the carriage (about the sheet normal) [µrad].
    yaw_urad : float, default 0.0
        Yaw of the carriage (about the vertical) [µrad].
    """

    command_mm: float
    stage_mm: float
    lateral_um: float = 0.0
    vertical_um: float = 0.0
    pitch_urad: float = 0.0
    yaw_urad: float = 0.0

    def to_dict(self) -> dict:
        """The realised values for the manifest.

        Returns
        -------
        dict
            ``stage_mm`` (where the carriage went), ``position_error_um``,
            ``lateral_um``, ``vertical_um``, ``pitch_urad``, ``yaw_urad``.
        """
        return {"stage_mm": self.stage_mm,
                "position_error_um": 1e3 * (self.stage_mm - self.command_mm),
                "lateral_um": self.lateral_um, "vertical_um": self.vertical_um,
                "pitch_urad": self.pitch_urad, "yaw_urad": self.yaw_urad}


def translation_state(rig: Rig, stage_mm: float, z: float = 0.0) -> TranslationState:
    """The translation stage's real position and attitude for a commanded coordinate.

    Parameters
    ----------
    rig : Rig
        The rig (the ``translation_*``, ``straightness_*``, ``pitch_urad``,
        ``yaw_urad`` keys of ``rig.stage``).
    stage_mm : float
        Commanded stage coordinate s [mm].
    z : float, default 0.0
        Standard normal draw of this move's random positioning error [-].

    Returns
    -------
    TranslationState
        s_a = s·(1 + k·1e-6) + A·sin(2π s/lead) + σ·z; with x = s/L:
        straightness 4x(1 − x)·S, pitch and yaw (2x − 1)·value (module docstring).
    """
    st = rig.stage
    err_um = st.translation_scale_ppm * 1e-3 * stage_mm \
        + st.translation_periodic_um * math.sin(2 * math.pi * stage_mm / st.translation_lead_mm) \
        + st.translation_repeatability_um * z
    x = stage_mm / st.translation_travel_mm
    bow, ramp = 4.0 * x * (1.0 - x), 2.0 * x - 1.0
    return TranslationState(float(stage_mm), float(stage_mm + 1e-3 * err_um),
                            bow * st.straightness_lateral_um, bow * st.straightness_vertical_um,
                            ramp * st.pitch_urad, ramp * st.yaw_urad)


def rig_from_plate(rig: Rig, stage_mm: float, state: TranslationState | None = None) -> np.ndarray:
    """Pose of the calibration plate in the rig frame.

    Parameters
    ----------
    rig : Rig
        The rig (hinge geometry, ``stage.d0_mm``, ``stage.calibration_table_z_mm``).
    stage_mm : float
        Translation-stage coordinate s of the plate's measured face [mm].
    state : TranslationState, optional
        The erring stage's real position and attitude for this command
        (:func:`translation_state`); None = exactly at ``stage_mm``.

    Returns
    -------
    (4, 4) float64
        rig_from_plate: rotation columns [e_p, n, e_z], origin
        H + (s − d0)·e_p + calibration_table_z_mm·e_z [mm]; with a state, the
        carriage's displacement and R_z(yaw)·R_n(pitch) (module docstring).
    """
    g = hinge_geometry(rig)
    if state is None:
        D = stage_mm - rig.stage.d0_mm
        return _sheet_frame(rig, g.object_hinge_mm + D * g.propagation_dir
                            + rig.stage.calibration_table_z_mm * np.array([0.0, 0.0, 1.0]))
    D = state.stage_mm - rig.stage.d0_mm
    origin = g.object_hinge_mm + D * g.propagation_dir + 1e-3 * state.lateral_um * g.sheet_normal \
        + (rig.stage.calibration_table_z_mm + 1e-3 * state.vertical_um) * np.array([0.0, 0.0, 1.0])
    turn = rotation_vector([0.0, 0.0, 1e-6 * state.yaw_urad]) \
        @ rotation_vector([0.0, 1e-6 * state.pitch_urad, 0.0])
    return _sheet_frame(rig, origin) @ turn


def stage_from_plate(rig: Rig, stage_mm: float, state: TranslationState | None = None) -> np.ndarray:
    """Pose of the calibration plate in the stage frame.

    Parameters
    ----------
    rig : Rig
        The rig.
    stage_mm : float
        Translation-stage coordinate s of the plate's measured face [mm].
    state : TranslationState, optional
        The erring stage's real position and attitude (:func:`translation_state`).

    Returns
    -------
    (4, 4) float64
        stage_from_plate: without a state a pure translation (s − axis_mm, 0,
        calibration_table_z_mm) [mm].
    """
    return invert(rig_from_stage(rig)) @ rig_from_plate(rig, stage_mm, state)
