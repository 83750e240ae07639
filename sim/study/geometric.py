"""The acceptance test without rendering: the exact stripe of every row in place of rendered frames.

A draw of a study renders plate frames, a blocker and the artefact scans,
then runs the pipeline (:func:`sim.acceptance.run_acceptance`).  This module
runs the *same* chain on noise-free synthetic data: for every frame of the
same scenarios, the exact stripe centre of every sensor row
(:class:`sim.truth.SceneTruth`: the sheet cut through the posed meshes,
projected by the exact camera of :mod:`scheimpflug.model.camera`, visibility
and laser occlusion by ray casting) stands in for the stripe detector, and the
plate's edges are the exact projections of the sheet's cut through the plate's
top and bottom edges (sub-row endpoints).  Calibration
(:func:`scheimpflug.calibration.calibrate_measurements`, the general model of
:mod:`scheimpflug.sheet_model`), axis location, reconstruction and the
VDI/VDE 2634-2 evaluation are the pipeline's own.  What remains is what the
rig's geometry does to the measurement: misalignments, distortion, stage and
plate errors — every error model the twin's poses and camera carry — without
noise, speckle, blur or the detector's bias.  It takes about a second where a
rendered draw takes tens, which makes finite differences (the analytic
propagation, :mod:`sim.study.propagation`) affordable.

The sheet-field error (:func:`sheet_field_error`) is the calibration's own
error over the field of view: for a grid of pixels, the sheet point the
as-built camera sees (:func:`scheimpflug.model.camera.sheet_point_from_pixel`)
against the one the calibration maps the pixel to; its mean is removed (a
constant shift of the sheet coordinates moves the axis with it and no form,
size or distance measure sees it).
"""

from __future__ import annotations

import hashlib

import numpy as np

from scheimpflug import acceptance as vdi
from scheimpflug.axis import axis_from_faces
from scheimpflug.calibration import CalibrationTolerances, PlateMeasurement, calibrate_measurements
from scheimpflug.errors import CalibrationError
from scheimpflug.model.binning import binned_rig
from scheimpflug.model.camera import project_points, sheet_point_from_pixel
from scheimpflug.model.hinge import hinge_geometry
from scheimpflug.model.rig import Rig
from scheimpflug.reconstruct import reconstruct_profiles
from scheimpflug.sheet_model import fit_sheet_models

from ..acceptance import acceptance_plan, calibration_constants, position_scenario, score_position
from ..scenarios import build_scenario
from ..stages import invert, rig_from_stage, transform_points
from ..truth import SceneCaster, SceneTruth, sheet_section

__all__ = ["FIELD_GRID", "GeometricTwin", "sheet_field_error"]

#: Pixels per side of the grid over which the sheet-field error is evaluated [-].
FIELD_GRID = 16
_FIELD_INSET = 0.04     # the grid stays this fraction of the sensor inside its borders [-]


def sheet_field_error(rig: Rig, calibration) -> dict:
    """The calibration's mapping error over the field of view (module docstring).

    Parameters
    ----------
    rig : Rig
        The instrument as built (the sensor size of the calibration).
    calibration : SheetModel
        Pixel → (stage coordinate, height) (paper form or general model).

    Returns
    -------
    dict
        ``field_rms_mm`` and ``field_max_mm``: RMS and largest length of the error vector
        (Δs, Δh) over a :data:`FIELD_GRID`² grid of pixels after removing its mean [mm];
        ``field_offset_mm``: the mean removed, [Δs, Δh] [mm].
    """
    s = rig.sensor
    u, v = np.meshgrid(np.linspace(_FIELD_INSET, 1 - _FIELD_INSET, FIELD_GRID) * (s.columns - 1),
                       np.linspace(_FIELD_INSET, 1 - _FIELD_INSET, FIELD_GRID) * (s.rows - 1))
    u, v = u.ravel(), v.ravel()
    true = transform_points(invert(rig_from_stage(rig)), sheet_point_from_pixel(rig, np.stack([u, v], -1)))
    s_true, h_true = true[:, 0] + rig.stage.axis_mm, true[:, 2]
    s_cal, h_cal = calibration.stage_from_pixel(u, v)
    err = np.stack([s_cal - s_true, h_cal - h_true], axis=1)
    ok = np.all(np.isfinite(err), axis=1)
    if not ok.any():
        return {"field_rms_mm": None, "field_max_mm": None, "field_offset_mm": None}
    mean = err[ok].mean(axis=0)
    length = np.linalg.norm(err[ok] - mean, axis=1)
    return {"field_rms_mm": float(np.sqrt(np.mean(length ** 2))), "field_max_mm": float(length.max()),
            "field_offset_mm": mean.tolist()}


class GeometricTwin:
    """Noise-free acceptance test of as-built rigs around one design (module docstring).

    The artefact plan and the calibration plan come from the design (``plan_rig``),
    so every rig evaluated scans the same artefacts at the same stage positions.

    Parameters
    ----------
    plan_rig : Rig
        The design (full size): its closed forms place the artefacts.
    kinds : iterable of str
        Artefact kinds (``sphere``, ``ball_bar``, ``plane``).
    binning : int
        k × k binned sensor (the rows the stripe is sampled on).
    quick : bool
        The reduced artefact plan.
    frames : int or None
        Frames per crossing.
    model : {"paper", "general", "auto"}
        Calibration model.
    exclude_fraction : float
        Outlier fraction excluded per measurement [-].
    calibration_options : dict, optional
        Options of the calibration scenario (as :func:`sim.acceptance.run_acceptance`).
    """

    def __init__(self, plan_rig: Rig, kinds=("sphere", "ball_bar", "plane"), binning: int = 1,
                 quick: bool = True, frames: int | None = None, model: str = "paper",
                 exclude_fraction: float = vdi.EXCLUDE_FRACTION, calibration_options: dict | None = None) -> None:
        self.binning, self.model, self.exclude_fraction = binning, model, exclude_fraction
        self.calibration_options = dict(calibration_options or {})
        self.volume, self.plan = acceptance_plan(binned_rig(plan_rig, binning), quick, frames, kinds)
        self._scenes: dict = {}

    # ---------------------------------------------------------------- truth of a scenario
    def _scene(self, assembly, mesh):
        from ..scene import SimScene

        key = hashlib.sha1(mesh[0].tobytes() + mesh[1].tobytes()).hexdigest()
        if key not in self._scenes:
            self._scenes[key] = SimScene(assembly.parts)
        return self._scenes[key]

    def _truths(self, rig_b: Rig, scenario) -> tuple[list, tuple]:
        m = scenario.assembly.combined_mesh()
        mesh = (np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64),
                scenario.assembly.face_object_ids())
        scene = self._scene(scenario.assembly, mesh)
        truth = SceneTruth(rig_b, *mesh)
        out = []
        for frame in scenario.frames:
            scene.set_pose(frame.rig_from_part)
            out.append(truth.frame(frame.rig_from_part, frame.ref_from_part, SceneCaster(scene),
                                   frame.rig_from_laser)[0])
        return out, mesh

    # ---------------------------------------------------------------- calibration
    def _plate_measurement(self, rig_b: Rig, frame, truth, mesh, tol: CalibrationTolerances):
        rows = np.flatnonzero(np.isfinite(truth.stripe_u))
        if len(rows) < tol.min_rows:
            return None
        u = truth.stripe_u[rows]
        b, a = np.polyfit(rows.astype(float), u, 1)
        top, bottom = _plate_edges(rig_b, frame, mesh, tol)
        return PlateMeasurement(stage_mm=float(frame.stage_mm), u_mean_px=float(u.mean()), n_rows=len(rows),
                                line=(float(a), float(b)), top_px=top, bottom_px=bottom,
                                rows=rows.astype(np.int64), u=u)

    def _calibrate(self, rig_b: Rig):
        scn = build_scenario("calibration", rig_b, 0, truth_pixels_every=0, **self.calibration_options)
        truths, mesh = self._truths(rig_b, scn)
        tol = CalibrationTolerances()
        ms = [m for f, t in zip(scn.frames, truths)
              if (m := self._plate_measurement(rig_b, f, t, mesh, tol)) is not None]
        both = [m for m in ms if m.top_px is not None and m.bottom_px is not None]
        s = rig_b.sensor
        paper = calibrate_measurements(both, plate_height_mm=float(scn.params["plate_height_mm"]),
                                       columns=s.columns, rows=s.rows)
        if self.model == "paper":
            return paper.best, paper, "paper"
        try:
            _, _, general, sel = fit_sheet_models(ms, paper, focal_length_mm=rig_b.lens.focal_length_mm,
                                                  pixel_pitch_um=s.pixel_pitch_um)
        except CalibrationError:
            if self.model == "general":
                raise
            return paper.best, paper, "paper"
        choice = sel.chosen if self.model == "auto" else "general"
        return (general, paper, "general") if choice == "general" else (paper.best, paper, "paper")

    def _axis(self, rig_b: Rig, calibration) -> float:
        scn = build_scenario("blocker", rig_b, 0, truth_pixels_every=0)
        truths, _ = self._truths(rig_b, scn)
        faces = []
        for t in truths:
            rows = np.flatnonzero(np.isfinite(t.stripe_u))
            if len(rows) < 20:
                continue
            s, _ = calibration.stage_from_pixel(t.stripe_u[rows], rows.astype(float))
            faces.append(float(np.median(s)))
        if not faces:
            raise CalibrationError("no usable blocker frame: the blocker is not in view of this rig")
        thickness = float(scn.params["blocker_thickness_mm"])
        return float(np.median(axis_from_faces(np.asarray(faces), thickness)))

    # ---------------------------------------------------------------- one rig
    def evaluate(self, rig: Rig) -> dict:
        """The noise-free acceptance test of one as-built rig.

        Parameters
        ----------
        rig : Rig
            The rig as built (full size; binned here like the design).

        Returns
        -------
        dict
            ``PF_mm``, ``PS_mm``, ``SD_mm``, ``F_mm``, ``L0_mm``, ``positions`` (per kind),
            ``axis_mm``, ``calibration`` (``model``, ``constants``: paper-form constants of the
            binned sensor) and the fields of :func:`sheet_field_error`.

        Raises
        ------
        CalibrationError
            When the plate or the blocker is not in view.
        ScheimpflugError
            When an artefact is not in view (fewer than 20 points on it).
        """
        rig_b = binned_rig(rig, self.binning)
        chosen, paper, name = self._calibrate(rig_b)
        axis_mm = self._axis(rig_b, chosen)
        rows = {"sphere": [], "ball_bar": [], "plane": []}
        for pos in self.plan:
            scn = position_scenario(rig_b, pos, 0)
            truths, _ = self._truths(rig_b, scn)
            r = [np.flatnonzero(np.isfinite(t.stripe_u)) for t in truths]
            us = [t.stripe_u[k] for t, k in zip(truths, r)]
            cloud = reconstruct_profiles(r, us, [f.angle_deg for f in scn.frames], chosen, axis_mm)
            res, _ = score_position(rig_b, pos, cloud, self.exclude_fraction)
            rows[pos.kind].append(res)
        table = vdi.summarize(rows["sphere"], rows["ball_bar"], rows["plane"], self.volume["L0_mm"])
        return {**table, "positions": rows, "axis_mm": axis_mm,
                "calibration": {"model": name, "constants": calibration_constants(paper.best)},
                **sheet_field_error(rig_b, chosen)}


def _plate_edges(rig_b: Rig, frame, mesh, tol: CalibrationTolerances):
    """Exact (u, v) of the plate's top and bottom edges on the stripe, None where not measurable.

    The sheet's mid-plane cuts the posed plate; of the cut's points those on the face
    toward the laser (the nearer half of the cut's depth along the sheet) give the edges
    (highest and lowest), projected by the exact camera.  An edge closer to the sensor's
    border than the edge finder's background band is not measurable (as in the frames).
    """
    g = hinge_geometry(rig_b)
    part_from_rig = invert(frame.rig_from_part)
    seg, _ = sheet_section(*mesh, transform_points(part_from_rig, g.object_hinge_mm),
                           part_from_rig[:3, :3] @ g.sheet_normal)
    if len(seg) == 0:
        return None, None
    pts = transform_points(frame.rig_from_part, seg.reshape(-1, 3))
    depth = (pts - g.object_hinge_mm) @ g.propagation_dir
    face = pts[depth <= depth.min() + 0.5 * np.ptp(depth)]
    ends = face[[np.argmax(face[:, 2]), np.argmin(face[:, 2])]]
    uv = project_points(rig_b, ends).uv_px
    margin = tol.background_gap_rows + tol.plateau_rows
    rows = rig_b.sensor.rows
    return tuple((float(p[0]), float(p[1])) if margin <= p[1] <= rows - 1 - margin else None for p in uv)
