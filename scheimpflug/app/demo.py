"""The main job: the paper's experiments in the digital twin, scored against the truth.

``run_demo`` renders the calibration sequence and calibrates; renders the
blocker and locates the rotary axis; scans the paper's cylinder (0.5° steps)
and the pile (1° steps); reconstructs both; scores them against the meshes that
were rendered; and writes ``report.md`` with its figures, the clouds and the
calibration JSON.  ``quick=True`` runs the same pipeline on a 4 × 4 binned
sensor with fewer frames (about a minute).  From each cloud it also builds
the watertight surface model on the scan's grid (:mod:`scheimpflug.meshing`)
and scores it against the truth both ways (volume, coverage, Hausdorff).

Beside the ideal twin (the ``paper`` preset) the demo runs the same
experiments with the twin *as built* (``paper-as-built``: every modelled error
source on, at the values of the kind of parts the paper used) on a reduced plan
(:func:`as_built_plan_for`), and an *error budget by source*: the calibration,
blocker and pile rendered once with no error, once with each source alone and
once with all of them, on a binned plan with few frames
(:func:`budget_plan_for`), so the report can say which source dominates each of
the paper's figures.

Everything the report says is measured in this run; the paper's numbers come
from the seed paper (docs/explanation/design-notes.md §3–4) and are labelled as such.
"""

from __future__ import annotations

import hashlib
import json
import math
import resource
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scheimpflug.errors import ScheimpflugError
from scheimpflug.io.atomic import finite_json, write_json_atomic, write_text_atomic
from scheimpflug.model.binning import binned_rig
from scheimpflug.model.rig import ERROR_MODELS, TWIN_EFFECTS, Rig, rig_to_toml, with_error_models

__all__ = ["DemoPlan", "PAPER", "as_built_plan_for", "budget_plan_for", "plan_for", "run_demo"]

# The seed paper's numbers (Sections 3–4, docs/explanation/design-notes.md §3–4).
PAPER = {
    "hinge_px": [3196.0, 771.0], "F2_px_mm": -1.446e6, "F2_sigma_px_mm": 581.0, "d0_mm": -466.0,
    "C_mm": 145.91, "C_sigma_mm": 0.2014, "endpoint_fit_r2": [0.9998, 0.9998],
    "depth_range_mm": 276.7, "height_range_near_mm": 88.0, "height_range_far_mm": 143.0,
    "distance_resolution_center_mm": 0.22, "height_resolution_center_mm": 0.05, "axis_mm": 179.45,
    "axis_column_px": 965.0, "cylinder_height_mm": 108.0, "cylinder_diameter_mm": 100.0,
    "ring_diameter_mm": 69.0, "ring_mean_error_mm": 2.0, "box_plane_rmse_mm": 0.1775,
    "box_plane": [-67.24, 0.3902, 0.03029],
}


@dataclass(frozen=True)
class DemoPlan:
    """What the demo renders: sensor binning and the frames of each experiment.

    ``cylinder_step_deg`` or ``pile_step_deg`` 0 leaves that scan out.
    """

    binning: int
    calibration_steps: int
    calibration_step_mm: float
    calibration_start_mm: float
    cylinder_step_deg: float
    pile_step_deg: float


def plan_for(quick: bool) -> DemoPlan:
    """The paper's resolution and step sizes, or the quick plan (4 × 4 binning, coarse steps)."""
    if quick:
        return DemoPlan(binning=4, calibration_steps=9, calibration_step_mm=28.0, calibration_start_mm=15.0,
                        cylinder_step_deg=10.0, pile_step_deg=10.0)
    return DemoPlan(binning=1, calibration_steps=27, calibration_step_mm=10.0, calibration_start_mm=-10.0,
                    cylinder_step_deg=0.5, pile_step_deg=1.0)


def as_built_plan_for(quick: bool) -> DemoPlan:
    """The as-built column's plan: the paper's resolution and calibration, coarser rotary steps.

    Full: 27 calibration frames at full resolution (σ(F²), σ(C) are per-frame
    scatters, so the frames are the paper's), the cylinder at 12° and the pile at
    6° steps (plane RMSE and circle error are per-point statistics; fewer
    frames, the same statistic).  The as-built frames carry the twin's physical
    light (3 bounces, subsurface scattering, surface speckle), ≈ 3 × the ideal
    frame's cost, hence the coarser steps than the ideal column's 0.5° and 1°.
    Quick: the quick plan's 4 × 4 binning and pile steps, no cylinder, and 9 plate
    positions from 31 to 239 mm, where both plate edges are in view.
    """
    if quick:
        return DemoPlan(binning=4, calibration_steps=9, calibration_step_mm=26.0, calibration_start_mm=31.0,
                        cylinder_step_deg=0.0, pile_step_deg=10.0)
    return DemoPlan(binning=1, calibration_steps=27, calibration_step_mm=10.0, calibration_start_mm=-10.0,
                    cylinder_step_deg=12.0, pile_step_deg=6.0)


def budget_plan_for(quick: bool) -> DemoPlan:
    """The error budget's plan: binned, few frames, no cylinder (calibration, blocker, pile only).

    The plate positions (31 … 239 mm) all show both plate edges at 4 × 4 binning.
    Quick: no pile either (the budget then covers σ(F²), σ(C) and the axis), to keep
    ``--quick`` within a minute.
    """
    if quick:
        return DemoPlan(binning=4, calibration_steps=7, calibration_step_mm=35.0, calibration_start_mm=31.0,
                        cylinder_step_deg=0.0, pile_step_deg=0.0)
    return DemoPlan(binning=4, calibration_steps=9, calibration_step_mm=26.0, calibration_start_mm=31.0,
                    cylinder_step_deg=0.0, pile_step_deg=15.0)


def _log(msg: str) -> None:
    print(f"demo: {msg}", file=sys.stderr, flush=True)


class _Timer:
    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}

    def run(self, name: str, fn, *args, **kw):
        _log(f"── {name}")
        t0 = time.perf_counter()
        out = fn(*args, **kw)
        self.seconds[name] = time.perf_counter() - t0
        return out


def _render(scenario: str, out: Path, rig: Rig, plan: DemoPlan, seed: int, quiet: bool,
            **options) -> Path:
    """Render one scenario with the twin (the library, not the command line) into ``out``."""
    from scheimpflug.app.progress import Progress
    from sim.writer import render_folder

    def warn(msg: str) -> None:
        _log(f"warning: {msg}")

    with Progress(0, label=f"render {scenario}", quiet=quiet) as bar:
        render_folder(binned_rig(rig, plan.binning), scenario, out, seed=seed, progress=bar, warn=warn,
                      truth_pixels_every=0, **options)
    return out


# ------------------------------------------------------------------ experiments


def _calibrate(folder: Path, out: Path, report: Path | None) -> dict:
    from scheimpflug.app.calibration_plot import plot_calibration
    from scheimpflug.app.report_plots import plot_superimposed_frames
    from scheimpflug.calibration import calibrate_folder
    from scheimpflug.io.frames import open_frame_folder

    result = calibrate_folder(folder)
    result.best.save(out / "calibration.json")
    truth = json.loads((folder / "truth" / "rig_truth.json").read_text())
    if report is None:
        return {"result": result, "truth": truth}
    plot_calibration(result, report / "calibration_fits.png")
    ff = open_frame_folder(folder)
    pick = range(0, len(ff), max(1, len(ff) // 9))
    plot_superimposed_frames([ff.read(i) for i in pick], report / "calibration_frames.png",
                             "superimposed calibration frames\n(the plate at several stage positions, paper Fig. 3a)")
    return {"result": result, "truth": truth}


def _axis(folder: Path, calibration) -> dict:
    from scheimpflug.axis import locate_axis

    res = locate_axis(folder, calibration)
    return {"axis_mm": float(res.axis_mm), "detail": res.to_json_dict()}


def _scan(folder: Path, calibration, axis_mm: float, cloud_path: Path, quiet: bool,
          method: str = "cog", every: int = 1) -> dict:
    """Extract (stripe ``method``, every ``every``-th frame), reconstruct, write the PLY and
    score against truth/mesh.ply."""
    import dataclasses

    from scheimpflug.app.progress import Progress
    from scheimpflug.io.frames import open_frame_folder
    from scheimpflug.io.ply import write_point_cloud
    from scheimpflug.reconstruct import extract_folder, reconstruct_profiles
    from scheimpflug.scoring import distance_stats

    ff = open_frame_folder(folder)
    if every > 1:
        ff = dataclasses.replace(ff, frames=ff.frames[::every])
    with Progress(0, label="reconstruct", quiet=quiet) as bar:
        rows, us, peaks, stats = extract_folder(ff, method, progress=bar)
    cloud = reconstruct_profiles(rows, us, [r.angle_deg for r in ff.frames], calibration, axis_mm,
                                 intensity=peaks)
    if len(cloud) == 0:
        raise ScheimpflugError(f"{folder}: no stripe found in any frame")
    write_point_cloud(cloud_path, cloud, comment=f"scheimpflug demo, axis_mm={axis_mm:.6g}")
    truth_pm, object_id = _truth_scorer(folder / "truth" / "mesh.ply")
    dist = truth_pm.query(cloud.xyz_mm)
    body = object_id[dist.face] if object_id is not None else np.zeros(len(cloud), np.int64)
    return {"folder": ff, "rows": rows, "u": us, "cloud": cloud, "distance": dist.distance_mm,
            "truth_pm": truth_pm, "object_id": object_id,
            "signed": bool(dist.signed), "body": body, "stats": distance_stats(dist.distance_mm, dist.signed),
            "extract": stats}


_TRUTH_SCORERS: dict[str, tuple] = {}
"""Point-to-mesh scorers of truth meshes already read, by the SHA-256 of the file's bytes: the
as-built column and every run of the budget score against the same rendered parts, and
building the scorer of the pile (665 k faces) takes ≈ 1 s."""


def _truth_scorer(path: Path):
    """(PointToMesh, object ids or None) of the truth mesh ``path``, built once per content."""
    from scheimpflug.io.ply import read_mesh
    from scheimpflug.scoring import PointToMesh

    key = hashlib.sha256(path.read_bytes()).hexdigest()
    if key not in _TRUTH_SCORERS:
        if len(_TRUTH_SCORERS) >= 4:
            _TRUTH_SCORERS.pop(next(iter(_TRUTH_SCORERS)))
        vertices, faces, object_id = read_mesh(path)
        _TRUTH_SCORERS[key] = (PointToMesh(vertices, faces), object_id)
    return _TRUTH_SCORERS[key]


_EDGE_MARGIN_MM = 1.0  # points this close to the smooth band's ends count as neither smooth nor knurled


def _model(scan: dict, rig: Rig, path: Path, samples: int, names: dict | None = None) -> dict:
    """Watertight model of a scan on its grid, its volumetric numbers and its two-sided scores."""
    from scheimpflug.app.model_scoring import score_model_mesh
    from scheimpflug.io.meshfile import write_mesh
    from scheimpflug.meshing import FILL_NAMES, ModelSettings, model_from_cloud
    from scheimpflug.scoring import body_labels
    from scheimpflug.volumetry import solid_summary

    t0 = time.perf_counter()
    model = model_from_cloud(scan["cloud"], ModelSettings(table_z_mm=rig.stage.rotary_table_z_mm))
    seconds = time.perf_counter() - t0
    write_mesh(path, model.vertices_mm, model.faces,
               {"fill": model.face_fill, "body": model.face_body.astype(np.int32)},
               comment="scheimpflug demo surface model")
    pm = scan["truth_pm"]
    labels = scan["object_id"] if scan["object_id"] is not None else body_labels(pm.faces)
    scores, ts = score_model_mesh(pm, labels, model.vertices_mm, model.faces, model.face_body, model.face_fill,
                                  samples=samples, seed=0)
    numbers = solid_summary(model.vertices_mm, model.faces, model.face_body, measured=model.measured)
    t = model.vertices_mm[model.faces]
    normals = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])[ts.model_face]
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    return {"numbers": {**numbers, **{k: v for k, v in scores.items() if k != "volume_mm3"},
                        "seconds": seconds, "n_faces": int(len(model.faces)), "n_bodies": model.n_bodies,
                        "faces_by_fill": dict(zip(FILL_NAMES, np.bincount(model.face_fill, minlength=5).tolist())),
                        "object_names": {str(k): v for k, v in (names or {}).items()}},
            "samples": ts.model_points_mm, "normals": normals, "distance": ts.model_to_truth_mm, "file": path.name,
            "spacing_mm": float(np.sqrt(numbers["area_mm2"] / samples))}


def _cylinder_metrics(scan: dict, rig: Rig) -> dict:
    import scenes
    from scheimpflug.fitting import fit_cylinder
    from scheimpflug.scoring import distance_stats

    part = scenes.load_part("cylinder").parts[0]
    z_lo, z_hi = (np.asarray(part.analytic["smooth_z_range_mm"]) + rig.stage.rotary_table_z_mm)
    z = scan["cloud"].xyz_mm[:, 2]
    smooth = (z > z_lo + _EDGE_MARGIN_MM) & (z < z_hi - _EDGE_MARGIN_MM)
    fit = fit_cylinder(scan["cloud"].xyz_mm[smooth], axis_guess=np.array([0.0, 0.0, 1.0]))
    return {"smooth": distance_stats(scan["distance"][smooth], scan["signed"]),
            "smooth_z_range_mm": [float(z_lo), float(z_hi)],
            "smooth_mask": smooth, "knurl_mask": z < z_lo - _EDGE_MARGIN_MM,
            "fit": fit.to_dict(), "diameter_mm": fit.diameter_mm,
            "height_mm": float(np.percentile(z, 99.99) - np.percentile(z, 0.01)),
            "true_diameter_mm": part.analytic["diameter_mm"], "true_height_mm": part.analytic["height_mm"]}


def _box_side_plane(rig: Rig, box: dict) -> tuple[np.ndarray, float, np.ndarray]:
    """The long side facing +y of the box with analytic description ``box``, in the stage
    frame: unit normal, offset (n·x = offset) [mm] and the box's mesh_from_part (4, 4)
    (:func:`sim.identify.figures.box_side_plane`, which ``identify`` measures with too)."""
    from sim.identify.figures import box_side_plane

    return box_side_plane(rig.stage.rotary_table_z_mm, box)


def _box_side_points(xyz: np.ndarray, rig: Rig, box: dict, inset_mm: float = 5.0,
                     band_mm: float = 3.0) -> np.ndarray:
    """Points within ``band_mm`` of the box's +y side and ``inset_mm`` inside its edges
    (the paper's hand-drawn region of interest, Fig. 8), as a boolean mask
    (:func:`sim.identify.figures.box_side_mask`)."""
    from sim.identify.figures import box_side_mask

    return box_side_mask(xyz, rig.stage.rotary_table_z_mm, box, inset_mm, band_mm)


def _pile_metrics(scan: dict, rig: Rig) -> dict:
    import scenes
    from scheimpflug.fitting import fit_circle_top_view, fit_plane_paper
    from scheimpflug.scoring import distance_stats

    parts = {p.analytic.get("kind"): p for p in scenes.load_part("pile").parts}
    xyz, dist = scan["cloud"].xyz_mm, scan["distance"]
    table = rig.stage.rotary_table_z_mm
    ring = parts["knurled_ring"].analytic
    in_ring = (xyz[:, 2] > table + ring["z0_mm"] + 1.0) & (xyz[:, 2] < table + ring["z1_mm"] - 1.0)
    circle = fit_circle_top_view(xyz[in_ring]) if in_ring.sum() >= 10 else None
    sel = _box_side_points(xyz, rig, parts["box"].analytic)
    plane = fit_plane_paper(xyz[sel]) if sel.sum() >= 10 else None
    regions = {}
    for oid, p in ((p.object_id, p) for p in parts.values()):
        mask = scan["body"] == oid
        if mask.any():
            regions[p.name] = distance_stats(dist[mask], scan["signed"])
    n, off, _ = _box_side_plane(rig, parts["box"].analytic)
    truth_plane = [off / n[1], -n[0] / n[1], -n[2] / n[1]]  # y = a + b x + c z of the true side
    return {"ring": circle.to_dict() if circle else None, "ring_points": xyz[in_ring],
            "ring_true_diameter_mm": ring["od_mm"],
            "ring_root_diameter_mm": 2.0 * ring["knurl"]["root_radius_mm"],
            "box_plane": plane.to_dict() if plane else None, "box_points": xyz[sel],
            "box_plane_truth": truth_plane, "regions": regions}


def _budget(axis_mm: float, scan: dict, rig_truth: dict, calibration, cyl_m: dict) -> dict:
    """Error budget of the cylinder scan, for the whole scan and for its smooth part.

    Extraction: measured stripe columns vs the exact per-row truth, converted to
    mm with the rig's true constants; calibration: the fitted constants vs the
    rig's over the sensor; total: point-to-mesh distances.  The smooth part keeps
    the rows and points whose true height lies in the cylinder's smooth band.
    """
    from scheimpflug.budget import calibration_error, error_budget, extraction_error

    ff = scan["folder"]
    truths = [np.load(ff.path / rec.extra["truth"]) for rec in ff.frames]
    z_lo = cyl_m["smooth_z_range_mm"][0] + _EDGE_MARGIN_MM
    z_hi = cyl_m["smooth_z_range_mm"][1] - _EDGE_MARGIN_MM
    truth_u = [t["stripe_u"] for t in truths]
    smooth_u = [np.where((t["stripe_point_mm"][:, 2] > z_lo) & (t["stripe_point_mm"][:, 2] < z_hi),
                         t["stripe_u"], np.nan) for t in truths]
    calib = calibration_error(calibration, rig_truth, ff.columns, ff.rows, axis_mm=axis_mm,
                              axis_truth_mm=rig_truth.get("axis_mm"))
    smooth = cyl_m["smooth_mask"]
    return {
        "whole scan": error_budget(extraction_error(scan["rows"], scan["u"], truth_u, rig_truth), calib,
                                   scan["distance"], scan["signed"]),
        "smooth part": error_budget(extraction_error(scan["rows"], scan["u"], smooth_u, rig_truth), calib,
                                    scan["distance"][smooth], scan["signed"]),
    }


# ------------------------------------------------------------------ driver


def run_demo(out: str | Path, *, quick: bool = False, rig: Rig | None = None, seed: int = 0,
             quiet: bool = False, as_built: Rig | None | bool = None) -> dict:
    """Run the whole demo into ``out``; return the summary dict (also written as summary.json).

    ``as_built``: the rig of the "twin, as built" column and of the error budget by
    source; None = the ``paper-as-built`` preset when ``rig`` is the paper preset (or
    not given), else none; False = none (the ideal twin alone, as before issue 11).
    """
    from scheimpflug.model.rig import load_preset

    paper = load_preset("paper")
    rig = rig or paper
    if as_built is None:
        as_built = load_preset("paper-as-built") if rig == paper else False
    plan = plan_for(quick)
    out = Path(out)
    report = out / "report"
    try:
        report.mkdir(parents=True, exist_ok=True)
        write_text_atomic(out / "rig.toml", rig_to_toml(rig))
        if as_built:
            write_text_atomic(out / "rig-as-built.toml", rig_to_toml(as_built))
    except OSError as exc:
        raise ScheimpflugError(f"cannot write the demo into {str(out)!r}: {exc.strerror or exc}") from None
    timer = _Timer()
    t_start = time.perf_counter()
    ideal = _experiments(rig, plan, out, seed, quiet, timer, report=report, models=True)
    summary = _summary(rig, plan, quick, ideal, timer, t_start)
    if as_built:
        ab_plan = as_built_plan_for(quick)
        summary["as_the_paper"] = _as_the_paper(rig, plan, out, ideal, quiet, timer,
                                                pile_step_deg=ab_plan.pile_step_deg)
        ab = _experiments(as_built, ab_plan, out / "as-built", seed, quiet, timer, label="as built: ")
        summary["as_built"] = _summary(as_built, ab_plan, quick, ab, timer, t_start)
        summary["as_built"]["as_the_paper"] = _as_the_paper(as_built, ab_plan, out / "as-built", ab, quiet,
                                                            timer, label="as built: ")
        summary["source_budget"] = _source_budget(rig, as_built, budget_plan_for(quick), out / "budget",
                                                  seed, quiet, timer)
    if rig == paper:
        rigs = {"ideal": rig, **({"as built": as_built} if as_built and not quick else {})}
        summary["calibration_choice"] = timer.run("which calibration (paper, general, pattern)",
                                                  _calibration_choice, rigs, quick, out / "choice", seed)
    summary["seconds"] = dict(timer.seconds)
    timer.run("figures + report", _write_report, out, report, summary, ideal)
    summary["seconds"]["total"] = time.perf_counter() - t_start
    summary["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    write_json_atomic(out / "summary.json", finite_json(summary))
    _print_summary(summary, out)
    return summary


def _experiments(rig: Rig, plan: DemoPlan, out: Path, seed: int, quiet: bool, timer: _Timer,
                 report: Path | None = None, label: str = "", models: bool = False) -> dict:
    """Calibration, axis, cylinder (if planned) and pile of one rig into ``out``.

    Figures only with ``report``; the watertight models of the cylinder and the pile
    (and their scores) only with ``models``.
    """
    out.mkdir(parents=True, exist_ok=True)
    cal_dir = timer.run(f"{label}render calibration", _render, "calibration", out / "calibration", rig,
                        plan, seed, quiet, steps=plan.calibration_steps, step_mm=plan.calibration_step_mm,
                        start_mm=plan.calibration_start_mm)
    cal = timer.run(f"{label}calibrate", _calibrate, cal_dir, out, report)
    calibration = cal["result"].best
    blk_dir = timer.run(f"{label}render blocker", _render, "blocker", out / "blocker", rig, plan, seed, quiet)
    axis = timer.run(f"{label}locate axis", _axis, blk_dir, calibration)
    res = {"cal": cal, "axis": axis, "cyl": None, "cyl_m": None, "budget": None}
    if plan.cylinder_step_deg > 0:
        cyl_dir = timer.run(f"{label}render cylinder scan", _render, "rotary", out / "cylinder", rig, plan,
                            seed, quiet, part="cylinder", step_deg=plan.cylinder_step_deg)
        res["cyl"] = timer.run(f"{label}reconstruct + score cylinder", _scan, cyl_dir, calibration,
                               axis["axis_mm"], out / "cylinder.ply", quiet)
        res["cyl_m"] = _cylinder_metrics(res["cyl"], rig)
    res["pile"] = res["pile_m"] = None
    if plan.pile_step_deg > 0:
        pile_dir = timer.run(f"{label}render pile scan", _render, "rotary", out / "pile", rig, plan, seed,
                             quiet, part="pile", step_deg=plan.pile_step_deg)
        res["pile"] = timer.run(f"{label}reconstruct + score pile", _scan, pile_dir, calibration,
                                axis["axis_mm"], out / "pile.ply", quiet)
        if models and res["cyl"] is not None:
            _models(res, rig, out, plan.binning > 1, timer)
        res["pile_m"] = _pile_metrics(res["pile"], rig)
    if res["cyl"] is not None:
        res["budget"] = _budget(axis["axis_mm"], res["cyl"], cal["truth"], calibration, res["cyl_m"])
    return res


def _as_the_paper(rig: Rig, plan: DemoPlan, out: Path, res: dict, quiet: bool, timer: _Timer,
                  label: str = "", pile_step_deg: float | None = None) -> dict:
    """The run's own frames measured as the paper measured its frames: in whole pixels.

    The paper's Section 3 processing (:func:`scheimpflug.calibration.measure_plate_frame`,
    detector "paper": the light bar's right boundary at half maximum in whole pixels,
    the bar's end rows as endpoints, one column per frame; the paper's estimate), the
    axis from the blocker's boundary and the pile's stripes in whole pixels (stripe
    method "paper"), scored like the sub-pixel pipeline's.  The frames are the ones
    already rendered: the difference to the run's own figures is the processing alone.
    ``pile_step_deg`` thins the pile to that step (the as-built column's, so that both
    columns' pile figures come from the same number of frames).
    """
    from scheimpflug.axis import locate_axis
    from scheimpflug.calibration import calibrate_folder

    result = timer.run(f"{label}calibrate as the paper", calibrate_folder, out / "calibration",
                       method="paper", detector="paper")
    cal = result.best
    axis_mm = float(locate_axis(out / "blocker", cal, detector="paper").axis_mm)
    got = {"calibration": cal.to_json_dict(), "axis_mm": axis_mm, "box_plane": None, "ring": None,
           "binning": plan.binning, "endpoint_lines": _endpoint_lines(result)}
    if res["pile"] is not None:
        every = max(1, round((pile_step_deg or plan.pile_step_deg) / plan.pile_step_deg))
        scan = timer.run(f"{label}reconstruct + score pile as the paper", _scan, out / "pile", cal, axis_mm,
                         out / "pile-as-the-paper.ply", quiet, method="paper", every=every)
        m = _pile_metrics(scan, rig)
        got.update(box_plane=m["box_plane"], ring=m["ring"], pile_step_deg=plan.pile_step_deg * every)
    return got


#: The paper's endpoint lines (Section 3, Fig. 3b): their slopes as printed except the second,
#: printed 0.2048 — only 0.2408 puts the two lines' intersection at the paper's own hinge
#: (3196, 771) —, and its 27 frames 10 mm apart from its first endpoint (Eq. 11: px 93 … 1204;
#: with the 20 mm it states, frames 15–27 would lie beyond the sensor).
PAPER_ENDPOINT_SLOPES = (-0.3693, 0.2408)
PAPER_FRAME_STAGES_MM = tuple(10.0 * k for k in range(27))


def _endpoint_lines(result) -> dict | None:
    """How far the plate endpoints scatter about their two lines, and the σ(C) that implies.

    ``result`` a :class:`scheimpflug.calibration.CalibrationResult` (method "paper").
    Returns the lines' slopes, R² and residual σ [px] (from R², as the paper's are), the σ(C)
    the closed form (:func:`scheimpflug.calibration.c_sigma_from_endpoint_fits`) gives from
    them beside the measured one, and the same for the paper's own reported figures (its
    residuals inferred from its R² over its frames); None with fewer than 3 frames that
    show both plate edges or an endpoint fit's R² outside (0, 1] (no line residual to speak of).
    """
    from scheimpflug.calibration import c_sigma_from_endpoint_fits, endpoint_residual_px

    both = [m for m in result.measurements if m.top_px is not None and m.bottom_px is not None]
    if len(both) < 3 or not all(0.0 < r2 <= 1.0 for r2 in result.paper.endpoint_fit_r2):
        return None
    cal = result.paper
    slopes = (result.top_line[0], result.bottom_line[0])
    u = np.array([m.u_mean_px for m in both])
    # each line's R² is over the frames that show its edge: its residual over their columns
    edge_u = [[m.top_px[0] for m in result.measurements if m.top_px is not None],
              [m.bottom_px[0] for m in result.measurements if m.bottom_px is not None]]
    resid = tuple(endpoint_residual_px(a, r2, cols)
                  for a, r2, cols in zip(slopes, cal.endpoint_fit_r2, edge_u, strict=True))
    (uh, _), r2 = PAPER["hinge_px"], PAPER["endpoint_fit_r2"]
    paper_u = uh + PAPER["F2_px_mm"] / (np.array(PAPER_FRAME_STAGES_MM) - PAPER["d0_mm"])
    paper_resid = tuple(endpoint_residual_px(a, q, paper_u) for a, q in zip(PAPER_ENDPOINT_SLOPES, r2, strict=True))
    return {"slopes": list(slopes), "r2": list(cal.endpoint_fit_r2), "residual_px": list(resid),
            "C_sigma_mm": cal.C_sigma_mm,
            "C_sigma_implied_mm": c_sigma_from_endpoint_fits(cal.C_mm, slopes, resid, u, cal.hinge_u_px),
            "paper": {"slopes": list(PAPER_ENDPOINT_SLOPES), "r2": list(r2), "residual_px": list(paper_resid),
                      "C_sigma_mm": PAPER["C_sigma_mm"],
                      "C_sigma_implied_mm": c_sigma_from_endpoint_fits(PAPER["C_mm"], PAPER_ENDPOINT_SLOPES,
                                                                       paper_resid, paper_u, uh)}}


def _models(res: dict, rig: Rig, out: Path, quick: bool, timer: _Timer) -> None:
    """The cylinder's and the pile's watertight models and their scores, into res["cyl"/"pile"]["model"]."""
    import scenes

    samples = 100_000 if quick else 400_000   # area-uniform samples per surface (scores, rendered view)
    names = {p.object_id: p.name for p in scenes.load_part("pile").parts}
    res["cyl"]["model"] = timer.run("model + score cylinder", _model, res["cyl"], rig,
                                    out / "cylinder_model.ply", samples)
    res["pile"]["model"] = timer.run("model + score pile", _model, res["pile"], rig, out / "pile_model.ply",
                                     samples, names)


# ------------------------------------------------------------------ error budget by source


def _budget_figures(res: dict, binning: int) -> dict:
    """The paper's scatter figures of one budget run; σ(F²) in full-resolution px·mm (× binning)."""
    best = res["cal"]["result"].best.to_json_dict()
    ring, box = (res["pile_m"]["ring"], res["pile_m"]["box_plane"]) if res["pile_m"] else (None, None)
    return {"F2_sigma_px_mm": _times(best.get("F2_sigma_px_mm"), binning),
            "C_sigma_mm": best.get("C_sigma_mm"),
            "box_plane_rmse_mm": box["rmse_mm"] if box else None,
            "ring_mean_error_mm": ring["mean_abs_error_mm"] if ring else None,
            "axis_error_mm": res["axis"]["axis_mm"] - res["cal"]["truth"].get("axis_mm", float("nan"))}


def _times(x, k: int):
    return None if x is None else float(x) * k


#: The figures of the budget by source, the key of each in the summary and its label.
BUDGET_FIGURES = (("F2_sigma_px_mm", "σ(F²) [px·mm]"), ("C_sigma_mm", "σ(C) [mm]"),
                  ("box_plane_rmse_mm", "box side plane RMSE [mm]"),
                  ("ring_mean_error_mm", "ring mean \\|error\\| [mm]"),
                  ("axis_error_mm", "axis error [mm]"))


def _source_budget(ideal: Rig, as_built: Rig, plan: DemoPlan, out: Path, seed: int, quiet: bool,
                   timer: _Timer) -> dict:
    """The budget plan with no error, each error source alone, and all of them (the as-built rig).

    The sources are the error models (:data:`ERROR_MODELS`) and the twin's physical
    light (:data:`TWIN_EFFECTS`: inter-reflections, subsurface scattering) that the
    as-built rig switches on; the speckle source is named after its model
    (``"surface speckle"``).
    """
    groups = [g for g in (*ERROR_MODELS, *TWIN_EFFECTS) if with_error_models(ideal, as_built, [g]) != ideal]
    runs = [(_source_name(g, as_built), with_error_models(ideal, as_built, [g])) for g in groups]
    sources = [name for name, _ in runs]
    runs = [("none (ideal)", ideal)] + runs + [("all (as built)", as_built)]
    rows = {}
    for i, (name, rig) in enumerate(runs):
        res = _experiments(rig, plan, out / f"{i:02d}", seed, quiet, timer, label=f"budget {name}: ")
        rows[name] = _budget_figures(res, plan.binning)
    return {"plan": plan.__dict__, "sources": sources, "rows": rows,
            "dominant": _dominant(rows, sources)}


def choice_plan_for(quick: bool):
    """The plan of the report's "which calibration" section (:mod:`sim.calibration_choice`).

    4 × 4 binned, like the error budget: the paper's 27 plate frames, 20 hand-held board poses,
    the board on the table every 30°, the cylinder and the pile at 10°; no subsets and no print
    errors (those are ``benchmarks/bench_calibration_choice.py``'s).  Quick: 9 plate frames,
    10 poses, the table every 45°, the cylinder at 20° and no pile.
    """
    from sim.calibration_choice import ChoicePlan

    if quick:
        return ChoicePlan(binning=4, plate_steps=9, plate_step_mm=26.0, plate_start_mm=31.0, plate_subsets=(),
                          poses=10, pose_subsets=(), table_step_deg=45.0, bow_mm=0.0, scale=1.0,
                          cylinder_step_deg=20.0, pile_step_deg=0.0, camera_spp=4)
    return ChoicePlan(binning=4, plate_subsets=(), pose_subsets=(), bow_mm=0.0, scale=1.0, camera_spp=8)


def _calibration_choice(rigs: dict, quick: bool, out: Path, seed: int) -> dict:
    """:func:`sim.calibration_choice.compare_calibrations` of each rig (name → rig), JSON-ready."""
    from sim.calibration_choice import compare_calibrations

    plan = choice_plan_for(quick)
    return {name: compare_calibrations(rig, plan, out / name.replace(" ", "-"), seed=seed,
                                       log=lambda msg, n=name: _log(f"   {n}: {msg}"))
            for name, rig in rigs.items()}


def _source_name(group: str, as_built: Rig) -> str:
    return f"{as_built.twin.speckle_model} speckle" if group == "speckle" else group


#: A source dominates a figure only if, alone, it raises the figure at least this much
#: above the ideal run's value (relative); below it the plan cannot tell sources apart.
DOMINANCE_MIN_RISE = 0.10


def _dominant(rows: dict, sources: list) -> dict:
    """Per figure: the source alone whose value lies furthest above the ideal run's (in quadrature).

    None when no source alone raises |value| by :data:`DOMINANCE_MIN_RISE` over the ideal run's.
    """
    out = {}
    base = rows["none (ideal)"]
    for key, _ in BUDGET_FIGURES:
        b = abs(base[key] or 0.0)
        excess = {s: math.sqrt(max(0.0, rows[s][key] ** 2 - b * b)) for s in sources
                  if rows[s][key] is not None and abs(rows[s][key]) >= (1 + DOMINANCE_MIN_RISE) * b}
        out[key] = max(excess, key=excess.get) if excess and max(excess.values()) > 0 else None
    return out


def _summary(rig, plan, quick, res: dict, timer, t_start) -> dict:
    from scheimpflug.model.design import coverage, design_report

    cal, axis, pile, pile_m = res["cal"], res["axis"], res["pile"], res["pile_m"]
    cyl, cyl_m = res["cyl"], res["cyl_m"]
    result = cal["result"]
    best = result.best
    truth = cal["truth"]
    ff = pile["folder"]
    cols, rows = ff.columns, ff.rows
    cov = coverage(best.hinge_u_px, best.hinge_v_px, best.F2_px_mm, best.C_mm, cols, rows)
    twin_design = {k: cov[k] for k in ("depth_range_mm", "height_range_near_mm", "height_range_far_mm",
                                       "distance_resolution_center_mm", "height_resolution_center_mm")}
    true_design = design_report(binned_rig(rig, plan.binning))
    s = {
        "quick": quick, "plan": plan.__dict__, "sensor": [rows, cols], "twin": rig.twin.__dict__,
        "calibration": {"best": best.to_json_dict(), "paper": result.paper.to_json_dict(),
                        "refined": result.refined.to_json_dict(), "truth": truth, "twin_design": twin_design,
                        "true_design": true_design, "skipped": [list(s) for s in result.skipped]},
        "axis": {"axis_mm": axis["axis_mm"], "truth_mm": truth.get("axis_mm", rig.stage.axis_mm),
                 "column_px": float(best.pixel_from_stage(axis["axis_mm"], 0.0)[0])},
        "cylinder": None,
        "pile": {"n_points": len(pile["cloud"]), "all": pile["stats"], "regions": pile_m["regions"],
                 "ring": pile_m["ring"], "ring_true_diameter_mm": pile_m["ring_true_diameter_mm"],
                 "ring_root_diameter_mm": pile_m["ring_root_diameter_mm"],
                 "box_plane": pile_m["box_plane"], "box_plane_truth": pile_m["box_plane_truth"],
                 "extract": pile["extract"]},
        "budget": res["budget"], "seconds": dict(timer.seconds), "paper": PAPER,
    }
    if "model" in pile:
        s["models"] = {"cylinder": cyl["model"]["numbers"], "pile": pile["model"]["numbers"]}
    if cyl is not None:
        s["cylinder"] = {"n_points": len(cyl["cloud"]), "all": cyl["stats"], "smooth": cyl_m["smooth"],
                         "fit": cyl_m["fit"], "height_mm": cyl_m["height_mm"],
                         "true_diameter_mm": cyl_m["true_diameter_mm"],
                         "true_height_mm": cyl_m["true_height_mm"], "extract": cyl["extract"]}
    return s


def _write_report(out: Path, report: Path, s: dict, ideal: dict) -> None:
    from scheimpflug.app.report_md import write_report

    write_report(out, report, s, ideal["cyl"], ideal["cyl_m"], ideal["pile"], ideal["pile_m"])


def _num(x) -> str:
    return "–" if x is None else f"{x:.4g}"


def _print_summary(s: dict, out: Path) -> None:
    c = s["calibration"]["best"]
    t = s["calibration"]["truth"]
    lines = [
        "",
        "Summary (twin vs truth)",
        f"  hinge        ({c['hinge_px'][0]:.2f}, {c['hinge_px'][1]:.2f}) px   truth "
        f"({t['hinge_u_px']:.2f}, {t['hinge_v_px']:.2f})",
        f"  F²           {c['F2_px_mm']:.6g} px·mm   truth {t['F2_px_mm']:.6g}",
        f"  C            {c['C_mm']:.5g} mm   truth {t['C_mm']:.5g}",
        f"  d0           {c['d0_mm']:.3f} mm   truth {t['d0_mm']:.3f}",
        f"  axis         {s['axis']['axis_mm']:.3f} mm   truth {s['axis']['truth_mm']:.3f}",
        f"  cylinder     Ø {s['cylinder']['fit']['diameter_mm']:.3f} mm (truth {s['cylinder']['true_diameter_mm']:g}), "
        f"RMS to mesh {s['cylinder']['smooth']['rms_mm']:.4f} mm on the smooth part",
    ]
    if s["pile"]["ring"]:
        lines.append(f"  ring         Ø {s['pile']['ring']['diameter_mm']:.2f} mm (truth "
                     f"{s['pile']['ring_true_diameter_mm']:g}), mean |error| "
                     f"{s['pile']['ring']['mean_abs_error_mm']:.3f} mm")
    if s["pile"]["box_plane"]:
        lines.append(f"  box side     plane RMSE {s['pile']['box_plane']['rmse_mm']:.4f} mm")
    ab = s.get("as_built")
    if ab:
        k = ab["plan"]["binning"]  # σ(F²) in full-resolution px·mm, like the paper's
        c = ab["calibration"]["best"]
        ring, box = ab["pile"]["ring"] or {}, ab["pile"]["box_plane"] or {}
        lines.append(f"  as built     σ(F²) {_num(_times(c.get('F2_sigma_px_mm'), k))} px·mm, σ(C) "
                     f"{_num(c.get('C_sigma_mm'))} mm, box RMSE {_num(box.get('rmse_mm'))} mm, ring mean "
                     f"|error| {_num(ring.get('mean_abs_error_mm'))} mm (paper 581, 0.20, 0.1775, ≈ 2)")
        if "as_the_paper" in ab:
            p = ab["as_the_paper"]
            c, ring, box = p["calibration"], p["ring"] or {}, p["box_plane"] or {}
            lines.append(f"  as built, measured as the paper (whole pixels{', binned' if k > 1 else ''}): σ(F²) "
                         f"{_num(_times(c.get('F2_sigma_px_mm'), k))} px·mm, σ(C) {_num(c.get('C_sigma_mm'))} mm, "
                         f"box RMSE {_num(box.get('rmse_mm'))} mm, ring mean |error| "
                         f"{_num(ring.get('mean_abs_error_mm'))} mm")
            e = p.get("endpoint_lines")
            if e:
                lines.append(f"  endpoints    scatter about their lines {_num(k * min(e['residual_px']))}, "
                             f"{_num(k * max(e['residual_px']))} full-resolution px (paper, from its R²: "
                             f"{_num(min(e['paper']['residual_px']))}, {_num(max(e['paper']['residual_px']))} "
                             f"px): σ(C) {_num(e['C_sigma_implied_mm'])} mm implied (paper "
                             f"{_num(e['paper']['C_sigma_implied_mm'])} implied, "
                             f"{_num(e['paper']['C_sigma_mm'])} reported)")
    for name, m in s.get("models", {}).items():
        if m.get("true_volume_mm3"):
            lines.append(f"  {name + ' model':<12} volume {m['volume_mm3']:.6g} mm³ vs truth "
                         f"{m['true_volume_mm3']:.6g} mm³ "
                         f"({100 * m['volume_error_mm3'] / m['true_volume_mm3']:+.2f} %), coverage "
                         f"{100 * m['coverage']:.1f} %")
    lines += [f"  time         {s['seconds']['total']:.1f} s, peak memory {s['peak_rss_mb']:.0f} MB",
              f"  report       {out / 'report' / 'report.md'}", ""]
    print("\n".join(lines), file=sys.stderr)
