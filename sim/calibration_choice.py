"""Which calibration for my rig?  The paper's method, the general model and the pattern calibration, side by side.

One rig, one set of scans (the paper cylinder and the paper pile on the
rotary stage), several calibrations of it, every one scored against what the
twin rendered (issue 24 item 5):

``paper``, ``paper-9``, ``paper-5``
    The paper's method (:mod:`scheimpflug.calibration.paper`, its best estimate)
    from the plate frames on the translation stage — all of them, 9 and 5
    evenly picked — with the rotary axis from the blocker frames.
``general``
    The general model (homography with distortion,
    :mod:`scheimpflug.calibration.general`) from the same plate frames and blocker.
``target``, ``target-10``, ``target-5``
    The pattern calibration (:mod:`scheimpflug.calibration.target`): a printed
    ChArUco board in hand-held poses (all, the first 10, the first 5), the laser
    line on each pose, and the board standing on the rotary table for the axis
    (no stage, no blocker).
``target+blocker``
    The pattern calibration's camera and plane with the rotary axis from the blocker frames:
    its position and its direction in the sheet (the blocker face's stripe line), no table poses.
``target-bow``, ``target-scale``
    The pattern calibration with a print error the calibration does not know of: the board bowed
    by ``bow_mm`` toward the camera, or printed ``scale`` times its nominal size.

Figures, none needing the calibrations to share a frame with the truth:

sheet (``sheet_rms_mm``, ``sheet_max_mm``)
    The exact stripe pixels of the scan frames (truth ``stripe_u``) mapped to the
    camera frame by the calibration, against their true points after the best
    rigid motion: the pixel → sheet mapping itself, detection noise excluded.
laser plane (``plane_normal_deg``, ``plane_distance_mm``)
    The sheet in the calibration's own camera frame against the rig's (the paper
    form decomposed with the rig's lens and pitch).
axis (``axis_offset_mm``, ``axis_angle_deg``)
    The rotary axis (the blocker's position in the sheet, or the table poses'
    line) in the truth frame through that same rigid motion: its distance from the
    true axis at the sheet and the angle between them.
scans
    Cylinder: the smooth band's fitted diameter against the part's
    (``cylinder_diameter_error_mm``) and its form (the fit's RMS,
    ``cylinder_form_rms_mm``); pile: the box side's plane RMSE (the paper's figure,
    ``box_plane_rmse_mm``) and the knurled ring's fitted diameter error
    (``ring_diameter_error_mm``).  Detection is the same for every calibration:
    the stripes are extracted once.
VDI/VDE 2634-2 (``vdi``, with ``ChoicePlan.acceptance``)
    PF, PS, SD, F of the acceptance test's quick plan, its artefacts rendered once and
    reconstructed with each calibration.

Run from :func:`compare_calibrations`; ``benchmarks/bench_calibration_choice.py``
prints the table, the demo report has a short version.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scheimpflug.model.binning import binned_rig
from scheimpflug.model.rig import Rig

__all__ = ["CHOICE_FIGURES", "ChoicePlan", "compare_calibrations"]

#: The figures of each calibration (module docstring), in the table's order.
CHOICE_FIGURES = ("sheet_rms_mm", "sheet_max_mm", "plane_normal_deg", "plane_distance_mm", "axis_offset_mm",
                  "axis_angle_deg", "cylinder_diameter_error_mm", "cylinder_form_rms_mm", "box_plane_rmse_mm",
                  "ring_diameter_error_mm")


@dataclass(frozen=True)
class ChoicePlan:
    """What :func:`compare_calibrations` renders and which calibrations it makes.

    Parameters
    ----------
    binning : int, default 1
        k × k binned sensor [-].
    plate_steps, plate_step_mm, plate_start_mm : int, float, float
        The plate frames on the translation stage (the paper's 27 × 10 mm from −10 mm).
    plate_subsets : tuple of int
        Fewer plate frames, evenly picked (``paper-N``).
    poses : int, default 20
        Hand-held poses of the board.
    pose_subsets : tuple of int
        Fewer poses, the first N (``target-N``).
    table_step_deg : float, default 30.0
        The board on the rotary table every this many degrees (where it is seen).
    pattern : str
        The board (:mod:`scheimpflug.calibration.pattern`).
    bow_mm, scale : float
        The print errors of ``target-bow`` and ``target-scale`` (0 and 1: left out).
    cylinder_step_deg, pile_step_deg : float
        The scans' rotary steps [deg] (0: left out).
    camera_spp : int, default 16
        The camera pass's samples per pixel for the board's flood-lit frames.
    acceptance : bool, default False
        Also the VDI/VDE 2634-2 figures of every calibration (:func:`sim.acceptance.acceptance_by_calibration`,
        the quick plan of spheres, ball bars and planes, rendered once).
    """

    binning: int = 1
    plate_steps: int = 27
    plate_step_mm: float = 10.0
    plate_start_mm: float = -10.0
    plate_subsets: tuple = (9, 5)
    poses: int = 20
    pose_subsets: tuple = (10, 5)
    table_step_deg: float = 30.0
    pattern: str = "charuco:11x8:15:11"
    bow_mm: float = 0.5
    scale: float = 1.003
    cylinder_step_deg: float = 10.0
    pile_step_deg: float = 10.0
    camera_spp: int = 16
    acceptance: bool = False


def _log_to(log):
    return log or (lambda msg: None)


def _render(rig: Rig, name: str, out: Path, seed: int, **options) -> Path:
    from sim.writer import render_folder

    render_folder(rig, name, out, seed=seed, truth_pixels_every=0, warn=lambda msg: None, **options)
    return out


def _camera_rig(rig: Rig, spp: int) -> Rig:
    from sim.target import DEFAULT_FLOOD_W_M2

    flood = rig.environment.flood_irradiance_w_m2 or DEFAULT_FLOOD_W_M2
    return rig.replace(environment={"flood_irradiance_w_m2": flood}, twin={"camera_spp": spp})


def _scaled_pattern(pattern: str, scale: float) -> str:
    """The spec of a board printed ``scale`` times its nominal size (every length scaled)."""
    head, _, rest = pattern.partition(":")
    grid, _, lengths = rest.partition(":")
    parts = lengths.split(":")
    scaled = [f"{float(x) * scale:.6g}" if x.replace(".", "", 1).isdigit() else x for x in parts]
    return ":".join([head, grid, *scaled])


def _with_blocker_axis(calibration, blocker: Path):
    """A target calibration's camera and plane with the rotary axis of the blocker frames, direction included.

    The blocker's face stands parallel to the rotary axis: its stripe is a line of the sheet
    along the axis.  The sheet's height axis is turned onto that line (fitted to every frame's
    stripe, s = a + b·h), then the axis's stage coordinate is located as for any calibration.
    """
    from scheimpflug.axis import locate_axis
    from scheimpflug.calibration.model import sheet_frame_from_plane
    from scheimpflug.io.frames import open_frame_folder
    from scheimpflug.stripe import extract_stripes

    origin, e_s, e_h = sheet_frame_from_plane(calibration.laser_plane)
    up = dataclasses.replace(calibration, homography=np.column_stack([e_s, e_h, origin]), axis=None)
    ff = open_frame_folder(blocker)
    s, h = [], []
    for i in range(len(ff)):
        prof = extract_stripes(ff.read(i), "cog", window_px="auto")
        si, hi = up.stage_from_pixel(prof.u, prof.rows)
        s.append(si)
        h.append(hi)
    slope = np.polyfit(np.concatenate(h), np.concatenate(s), 1)[0]      # ds/dh of the face's line
    new_h = (e_h + slope * e_s) / math.hypot(1.0, slope)
    new_s = (e_s - slope * e_h) / math.hypot(1.0, slope)
    model = dataclasses.replace(up, homography=np.column_stack([new_s, new_h, origin]))
    return model, float(locate_axis(blocker, model).axis_mm)


def _subset(folder, keep) -> object:
    from scheimpflug.io.frames import open_frame_folder

    ff = open_frame_folder(folder)
    return dataclasses.replace(ff, frames=tuple(r for i, r in enumerate(ff.frames) if keep(i, r)))


def _even(n_total: int, n: int) -> set:
    return {int(round(k)) for k in np.linspace(0, n_total - 1, n)}


# ---------------------------------------------------------------- the truth


def _truth(folder: Path) -> dict:
    """The rig's sheet and axis in the twin's camera frame, and the camera-from-stage transform."""
    from scheimpflug.model.rig import rig_from_dict
    from sim.stages import rig_from_stage
    from sim.truth import opencv_laser_plane

    m = json.loads((folder / "manifest.json").read_text())
    rt = json.loads((folder / "truth" / "rig_truth.json").read_text())
    rig = rig_from_dict(m["rig"])
    c = np.array(rt["opencv"]["camera_from_rig"])
    plane = opencv_laser_plane(rig)
    rs = rig_from_stage(rig)
    cs = c @ rs
    return {"plane": plane, "axis_point": cs[:3, 3], "axis_dir": cs[:3, 2], "camera_from_rig": c,
            "axis_mm": float(rt["axis_mm"]), "hinge_px": rt["hinge_px"]}


def _truth_pixels(folder: Path, camera_from_rig: np.ndarray, every: int = 4) -> tuple:
    """Exact stripe pixels of a rotary scan's frames and their true points in the twin's camera frame.

    The truth points are in the part's frame at θ = 0 (:mod:`sim.truth`); a frame saw them with
    the part at ``stage_from_part(θ)`` (the stage's nominal motion: an as-built stage's random
    wobble and radial error, micrometres, are left out).
    """
    from scheimpflug.model.rig import rig_from_dict
    from sim.stages import invert, rig_from_stage, stage_from_part

    m = json.loads((folder / "manifest.json").read_text())
    rig = rig_from_dict(m["rig"])
    base = camera_from_rig @ rig_from_stage(rig)
    ref_from_part = stage_from_part(rig, 0.0)
    u, v, pts = [], [], []
    for f in m["frames"]:
        z = np.load(folder / f["truth"])
        rows = np.flatnonzero(np.isfinite(z["stripe_u"]))[::every]
        if rows.size:
            c = base @ stage_from_part(rig, float(f["angle_deg"])) @ invert(ref_from_part)
            u.append(z["stripe_u"][rows])
            v.append(rows.astype(float))
            pts.append(z["stripe_point_mm"][rows] @ c[:3, :3].T + c[:3, 3])
    return np.concatenate(u), np.concatenate(v), np.concatenate(pts)


# ---------------------------------------------------------------- one calibration's figures


def _camera_points(model, u, v, rig_b: Rig) -> np.ndarray:
    from scheimpflug.calibration import GeneralCalibration

    if isinstance(model, GeneralCalibration):
        return model.camera_from_pixel(u, v)
    return model.camera_from_pixel(u, v, rig_b.lens.focal_length_mm)


def _model_plane(model, rig_b: Rig) -> np.ndarray:
    from scheimpflug.calibration.opencv import opencv_dict

    if getattr(model, "laser_plane", None) is not None:
        return np.asarray(model.laser_plane)
    return np.asarray(opencv_dict(model, rig_b.lens.focal_length_mm, rig_b.sensor.pixel_pitch_um)["laser_plane"])


def _model_axis(model, axis_mm, rig_b: Rig) -> tuple[np.ndarray, np.ndarray]:
    """A point and the direction of the calibration's rotary axis in its camera frame."""
    from scheimpflug.calibration import GeneralCalibration
    from scheimpflug.calibration.camera import ideal_camera
    from scheimpflug.reconstruct import calibration_axis

    if axis_mm is None:
        axis, _ = calibration_axis(model)
        return np.asarray(axis["origin_mm"]), np.asarray(axis["direction"])
    if isinstance(model, GeneralCalibration):
        g = model.metric_scale() * model.homography
    else:                              # the paper form decomposed as _camera_points does (one stage mm = 1 mm)
        _, g = ideal_camera(model, rig_b.lens.focal_length_mm, rig_b.sensor.pixel_pitch_um)
        g = g / np.linalg.norm(g[:, 0])
    return g[:, 2] + axis_mm * g[:, 0], g[:, 1]


def _calibration_figures(model, axis_mm, truth: dict, pixels: tuple, rig_b: Rig) -> dict:
    u, v, true_cam = pixels
    ours = _camera_points(model, u, v, rig_b)
    from scheimpflug.fitting import fit_rigid

    ok = np.all(np.isfinite(ours), axis=1)
    r, t, _ = fit_rigid(ours[ok], true_cam[ok])
    resid = np.linalg.norm(ours[ok] @ r.T + t - true_cam[ok], axis=1)
    plane = _model_plane(model, rig_b)
    q, w = _model_axis(model, axis_mm, rig_b)
    q, w = r @ q + t, r @ w
    w_true = truth["axis_dir"] / np.linalg.norm(truth["axis_dir"])
    rel = q - truth["axis_point"]
    return {"sheet_rms_mm": float(np.sqrt(np.mean(resid ** 2))), "sheet_max_mm": float(resid.max()),
            "plane_normal_deg": float(math.degrees(math.acos(min(1.0, abs(plane[:3] @ truth["plane"][:3]))))),
            "plane_distance_mm": float(abs(plane[3]) - abs(truth["plane"][3])),
            "axis_offset_mm": float(np.linalg.norm(rel - (rel @ w_true) * w_true)),
            "axis_angle_deg": float(math.degrees(math.acos(min(1.0, abs(w @ w_true) / np.linalg.norm(w)))))}


def _scan_samples(folder: Path, st) -> dict:
    """A scan's stripe samples (frame pixels, angles) with the true part-frame point and object of each.

    The figures select their points by this truth (the same points for every calibration), and
    fit them where each calibration puts them.
    """
    from scheimpflug.stripe import image_pixels

    m = json.loads((folder / "manifest.json").read_text())
    true, obj = [], []
    for f, rows in zip(m["frames"], st.rows):
        z = np.load(folder / f["truth"])
        true.append(z["stripe_point_mm"][rows])
        obj.append(z["stripe_object_id"][rows])
    lines, across = np.concatenate(st.rows), np.concatenate(st.u)
    u, v = image_pixels(lines, across, st.along)
    angles = np.concatenate([np.full(len(r), float(f["angle_deg"])) for f, r in zip(m["frames"], st.rows)])
    return {"u": u, "v": v, "angle_deg": angles, "true": np.concatenate(true), "object": np.concatenate(obj)}


def _scan_figures(model, axis_mm, scans: dict, rig_b: Rig) -> dict:
    import scenes
    from scheimpflug.fitting import fit_circle_top_view, fit_cylinder, fit_plane_paper
    from scheimpflug.reconstruct import points_from_pixels
    from sim.identify.figures import box_side_mask

    out = dict.fromkeys(CHOICE_FIGURES[6:], math.nan)
    table = rig_b.stage.rotary_table_z_mm
    for name, smp in scans.items():
        xyz = points_from_pixels(smp["u"], smp["v"], smp["angle_deg"], model, axis_mm)
        ok = np.all(np.isfinite(xyz), axis=1) & np.all(np.isfinite(smp["true"]), axis=1)
        tz = smp["true"][:, 2]
        if name == "cylinder":
            part = scenes.load_part("cylinder").parts[0]
            z_lo, z_hi = np.asarray(part.analytic["smooth_z_range_mm"]) + table
            sel = ok & (tz > z_lo + 2.0) & (tz < z_hi - 2.0)
            if sel.sum() > 100:
                fit = fit_cylinder(xyz[sel], axis_guess=np.array([0.0, 0.0, 1.0]))
                out["cylinder_diameter_error_mm"] = float(fit.diameter_mm - part.analytic["diameter_mm"])
                out["cylinder_form_rms_mm"] = float(fit.rms_mm)
        elif name == "pile":
            parts = {p.analytic.get("kind"): p for p in scenes.load_part("pile").parts}
            sel = ok & box_side_mask(np.where(ok[:, None], smp["true"], 0.0), table, parts["box"].analytic, 5.0, 3.0)
            if sel.sum() >= 10:
                out["box_plane_rmse_mm"] = float(fit_plane_paper(xyz[sel]).rmse_mm)
            ring = parts["knurled_ring"]
            sel = (ok & (smp["object"] == ring.object_id) & (tz > table + ring.analytic["z0_mm"] + 1.0)
                   & (tz < table + ring.analytic["z1_mm"] - 1.0))
            if sel.sum() >= 10:
                out["ring_diameter_error_mm"] = float(fit_circle_top_view(xyz[sel]).diameter_mm
                                                      - ring.analytic["od_mm"])
    return out


# ---------------------------------------------------------------- the run


def compare_calibrations(rig: Rig, plan: ChoicePlan, out, *, seed: int = 0,
                         log: Callable[[str], None] | None = None) -> dict:
    """Render the frames, make every calibration of the plan, score each (module docstring).

    Parameters
    ----------
    rig : Rig
        The instrument (full size; the plan bins it).
    plan : ChoicePlan
        What to render and calibrate.
    out : path
        Working folder (frame folders ``plate``, ``blocker``, ``target``, ``table``, ``cylinder``,
        ``pile``, and the print-error boards).
    seed : int, default 0
        Run seed.
    log : callable, optional
        Receives one line per step.

    Returns
    -------
    dict
        ``methods``: name → figures (:data:`CHOICE_FIGURES`, plus ``seconds`` to calibrate and
        ``frames`` used), ``plan``, ``binning``, ``seconds`` (per render and in all).

    Raises
    ------
    ValueError
        A plan that scans no part (both rotary steps 0).
    CalibrationError
        A calibration that fails on the rendered frames (too few poses found, …).
    """
    from scheimpflug.axis import locate_axis
    from scheimpflug.calibration import calibrate_folder
    from scheimpflug.calibration.general import calibrate_sheet_folder
    from scheimpflug.calibration.target import calibrate_target_folder
    from scheimpflug.io.frames import open_frame_folder
    from scheimpflug.reconstruct import extract_folder_stripes

    say = _log_to(log)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t_all = time.perf_counter()
    rig_b = binned_rig(rig, plan.binning)
    cam_rig = _camera_rig(rig_b, plan.camera_spp)
    seconds: dict = {}

    def timed(name, fn, *a, **k):
        say(name)
        t0 = time.perf_counter()
        r = fn(*a, **k)
        seconds[name] = round(time.perf_counter() - t0, 2)
        return r

    plate = timed("render plate", _render, rig_b, "calibration", out / "plate", seed, steps=plan.plate_steps,
                  step_mm=plan.plate_step_mm, start_mm=plan.plate_start_mm)
    blocker = timed("render blocker", _render, rig_b, "blocker", out / "blocker", seed)
    boards = {"": plan.pattern}
    if plan.bow_mm:
        boards["bow"] = plan.pattern
    if plan.scale != 1.0:
        boards["scale"] = _scaled_pattern(plan.pattern, plan.scale)
    for tag, spec in boards.items():
        extra = {"bow_mm": plan.bow_mm} if tag == "bow" else {}
        timed(f"render board {tag or 'as specified'}", _render, cam_rig, "target", out / f"target{tag}", seed,
              pattern=spec, poses=plan.poses, **extra)
        timed(f"render board on the table {tag}", _render, cam_rig, "target", out / f"table{tag}", seed,
              pattern=spec, on_table=True, step_deg=plan.table_step_deg, lights=("flood",), **extra)
    scans, pixels, truth = {}, [], None
    for part, step in (("cylinder", plan.cylinder_step_deg), ("pile", plan.pile_step_deg)):
        if step > 0:
            folder = timed(f"render {part}", _render, rig_b, "rotary", out / part, seed, part=part, step_deg=step)
            st = timed(f"extract {part}", extract_folder_stripes, open_frame_folder(folder), "cog")
            scans[part] = _scan_samples(folder, st)
            truth = truth or _truth(folder)
            pixels.append(_truth_pixels(folder, truth["camera_from_rig"]))
    if truth is None:
        raise ValueError("the plan scans no part (cylinder_step_deg and pile_step_deg are 0)")
    pixels = tuple(np.concatenate(x) for x in zip(*pixels))
    models: dict = {}
    ff_plate = open_frame_folder(plate)
    n_plate = len(ff_plate)

    def plate_model(name, n, general=False):
        keep = _even(n_plate, n)
        ff = dataclasses.replace(ff_plate, frames=tuple(r for i, r in enumerate(ff_plate.frames) if i in keep))
        t0 = time.perf_counter()
        if general:
            model = calibrate_sheet_folder(ff, model="general", focal_length_mm=rig_b.lens.focal_length_mm,
                                           pixel_pitch_um=rig_b.sensor.pixel_pitch_um).chosen
        else:
            model = calibrate_folder(ff).best
        axis = locate_axis(blocker, model).axis_mm
        models[name] = (model, float(axis), time.perf_counter() - t0, n)

    def target_model(name, tag, n_poses):
        hand = _subset(out / f"target{tag}", lambda i, r: r.extra.get("pose", 0) < n_poses)
        t0 = time.perf_counter()
        res = calibrate_target_folder(hand, plan.pattern, table=out / f"table{tag}")
        models[name] = (res.calibration, None, time.perf_counter() - t0, len(res.calibration.poses_used))
        if name == "target":          # the same camera and plane, the axis from the blocker instead
            t0 = time.perf_counter()
            model, axis = _with_blocker_axis(res.calibration, blocker)
            models["target+blocker"] = (model, axis, models[name][2] + time.perf_counter() - t0, models[name][3])

    for name, n, general in (("paper", n_plate, False), ("general", n_plate, True),
                             *((f"paper-{k}", k, False) for k in plan.plate_subsets if k < n_plate)):
        timed(f"calibrate {name}", plate_model, name, n, general)
    for name, tag, n in (("target", "", plan.poses), *((f"target-{k}", "", k) for k in plan.pose_subsets),
                         *((f"target-{t}", t, plan.poses) for t in boards if t)):
        timed(f"calibrate {name}", target_model, name, tag, n)
    methods = {}
    for name, (model, axis_mm, secs, n) in models.items():
        figures = _calibration_figures(model, axis_mm, truth, pixels, rig_b)
        figures.update(_scan_figures(model, axis_mm, scans, rig_b))
        methods[name] = {**figures, "calibrate_s": round(secs, 2), "frames": n}
    if plan.acceptance:
        from sim.acceptance import acceptance_by_calibration

        vdi = timed("VDI/VDE 2634-2", acceptance_by_calibration, rig, out / "acceptance",
                    {k: (m[0], m[1]) for k, m in models.items()}, binning=plan.binning, seed=seed, log=say)
        for name, v in vdi.items():
            methods[name]["vdi"] = {k: v.get(k) for k in ("PF_mm", "PS_mm", "SD_mm", "F_mm", "failed")}
    seconds["total"] = round(time.perf_counter() - t_all, 1)
    return {"methods": methods, "plan": dataclasses.asdict(plan), "binning": plan.binning, "seconds": seconds}
