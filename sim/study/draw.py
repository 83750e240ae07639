"""One draw of a study: render, calibrate, scan the artefacts, score — resumable like a dataset sample.

A draw (a design of a sweep, a Monte Carlo draw of a tolerance study) runs
the VDI/VDE 2634-2 chain of :func:`sim.acceptance.run_acceptance` on its rig:
calibration from rendered plate frames (the spec's model), the blocker, the
artefacts as rotary scans, the quality parameters; plus the closed-form design
numbers and the calibration's field error (:func:`sim.study.geometric.sheet_field_error`).

Files: the draw works in ``draws/.NNNNNN.partial/`` (frame folders resume frame
by frame) and writes ``draw.json`` there (and, for a sweep, ``design.toml``: the
design's rig file, to start a tolerance study from); the folder is then renamed to
``draws/NNNNNN/`` (the frame folders removed unless ``keep_frames``).  A draw
whose final folder holds ``draw.json`` is done and is never run again.

A design that cannot measure (the plate, the blocker or an artefact out of
view; a design that cannot be placed) gives a record with ``status`` and
``reason``, not an exception; a failure of the machinery (the renderer, the
disk) raises, and the study tries the draw again.
"""

from __future__ import annotations

import json
import os
import shutil
import time
from pathlib import Path

from scheimpflug.callbacks import ProgressCallback
from scheimpflug.errors import RenderError, ScheimpflugError, StudyError
from scheimpflug.io.atomic import write_json_atomic, write_text_atomic
from scheimpflug.model.binning import binned_rig
from scheimpflug.model.rig import rig_from_dict, rig_to_toml

from ..acceptance import run_acceptance
from ..threads import configure_threads
from .geometric import sheet_field_error
from .outputs import design_numbers, measured_outputs
from .spec import DrawPlan

__all__ = ["DESIGN_FILE", "DRAW_FILE", "PROGRESS_UNITS", "draw_folder", "run_draw"]

DRAW_FILE = "draw.json"
#: The design's full-size rig file in a sweep's draw folder (derived keys written as numbers).
DESIGN_FILE = "design.toml"
#: Progress units of one draw (its scans are reported as a fraction of these) [-].
PROGRESS_UNITS = 10


def draw_folder(root: str | os.PathLike, index: int, partial: bool = False) -> Path:
    """The folder of draw ``index`` in a study folder.

    Parameters
    ----------
    root : path
        The study folder.
    index : int
        Draw number [-].
    partial : bool
        The working folder (``draws/.NNNNNN.partial``) instead of the final one.

    Returns
    -------
    Path
        ``root/draws/NNNNNN`` or ``root/draws/.NNNNNN.partial``.
    """
    name = f".{index:06d}.partial" if partial else f"{index:06d}"
    return Path(root) / "draws" / name


def _units(progress: ProgressCallback | None):
    if progress is None:
        return None

    def scaled(done: int, total: int) -> None:
        progress(min(PROGRESS_UNITS, done * PROGRESS_UNITS // max(total, 1)), PROGRESS_UNITS)
    return scaled


def _measure(plan: DrawPlan, rig, work: Path, progress) -> tuple[dict, dict]:
    a = plan.artefacts
    nominal = rig_from_dict(plan.nominal)
    res = run_acceptance(rig, work, model=plan.model, binning=a.binning, quick=a.quick, frames=a.frames,
                         seed=plan.seed, spp=a.spp, exclude_fraction=a.exclude_fraction, kinds=a.kinds,
                         material=a.material, plan_rig=nominal, calibration_options=plan.calibration,
                         progress=progress, warn=lambda msg: None)
    rig_b = binned_rig(rig, a.binning)
    out = measured_outputs(res, rig_b, binned_rig(nominal, a.binning), a.binning)
    out.update(sheet_field_error(rig_b, res["sheet_model"]))
    out["extraction_rms_mm"] = res["extraction_rms_mm"]
    extra = {"positions": res["positions"], "calibration": res["calibration"], "L0_mm": res["L0_mm"]}
    if a.part:
        extra["part"] = _scan_part(plan, rig_b, work / "part", res["sheet_model"], res["axis_mm"])
        out["part_rms_mm"] = extra["part"]["rms_mm"]
    return out, extra


def _scan_part(plan: DrawPlan, rig_b, work: Path, calibration, axis_mm: float) -> dict:
    """The user part as a rotary scan, reconstructed with the draw's calibration, scored against its mesh."""
    from scheimpflug.io.frames import open_frame_folder
    from scheimpflug.io.ply import read_triangle_mesh
    from scheimpflug.reconstruct import extract_folder, reconstruct_profiles
    from scheimpflug.scoring import score_points

    from ..writer import render_folder

    a = plan.artefacts
    render_folder(rig_b, "rotary", work, seed=plan.seed, spp=a.spp, warn=lambda msg: None, truth_pixels_every=0,
                  part=a.part, step_deg=a.part_step_deg)
    ff = open_frame_folder(work)
    rows, us, peaks, _ = extract_folder(ff, "cog")
    cloud = reconstruct_profiles(rows, us, [r.angle_deg for r in ff.frames], calibration, axis_mm, intensity=peaks)
    if len(cloud.xyz_mm) == 0:
        raise StudyError(f"the part {a.part!r} gave no points: it is not in view of this rig")
    mesh = read_triangle_mesh(work / "truth" / "mesh.ply")
    st = score_points(cloud.xyz_mm, mesh.vertices, mesh.faces)
    return {k: st[k] for k in ("n_points", "rms_mm", "mean_abs_mm", "p95_mm", "max_mm")}


def run_draw(plan: DrawPlan, root: str | os.PathLike, progress: ProgressCallback | None = None,
             threads: int | None = None) -> dict:
    """Run (or resume) draw ``plan.index`` of the study in ``root`` (module docstring).

    Parameters
    ----------
    plan : DrawPlan
        What the draw runs (:func:`sim.study.spec.plan_draws`).
    root : path
        The study folder (``draws/`` exists).
    progress : ProgressCallback, optional
        ``progress(done, PROGRESS_UNITS)`` over the draw's scans.
    threads : int, optional
        Size this process's thread pools first (:func:`sim.threads.configure_threads`).

    Returns
    -------
    dict
        The draw's record (what ``draw.json`` holds): ``draw``, ``status`` (``ok``,
        ``not-measured``, ``not-placed``), ``reason``, ``seed``, ``values``, ``deviations``,
        ``unit``, ``design`` (:func:`sim.study.outputs.design_numbers`), ``outputs``
        (:func:`sim.study.outputs.measured_outputs`, None unless measured), ``detail``
        (per position, the calibration), ``seconds``.

    Raises
    ------
    StudyError
        The final folder exists without ``draw.json`` (damaged or foreign).
    RenderError
        The renderer cannot run, or a file cannot be written.
    """
    if threads:
        configure_threads(threads)
    final = draw_folder(root, plan.index)
    if (final / DRAW_FILE).is_file():
        return json.loads((final / DRAW_FILE).read_text("utf-8"))
    if final.exists():
        raise StudyError(f"draw folder {str(final)!r} exists but has no {DRAW_FILE}: delete it and rerun")
    t0, c0 = time.perf_counter(), time.process_time()
    partial = draw_folder(root, plan.index, partial=True)
    partial.mkdir(parents=True, exist_ok=True)
    rig = rig_from_dict(plan.rig)
    record = {"draw": plan.index, "status": "ok", "reason": "", "seed": plan.seed, "values": plan.values,
              "deviations": plan.deviations, "unit": list(plan.unit), "design": design_numbers(rig),
              "outputs": None, "detail": None}
    if not plan.deviations:          # a sweep's design: its rig file, for the tolerance study that follows
        write_text_atomic(partial / DESIGN_FILE, rig_to_toml(rig))
    if plan.status:
        record.update(status="not-placed", reason=plan.status)
    elif plan.artefacts.kinds:
        try:
            record["outputs"], record["detail"] = _measure(plan, rig, partial, _units(progress))
        except RenderError:
            raise
        except (ScheimpflugError, ValueError) as exc:
            record.update(status="not-measured", reason=" ".join(str(exc).split()))
    record["seconds"] = {"wall": time.perf_counter() - t0, "cpu": time.process_time() - c0}
    _finish(partial, final, record, plan.keep_frames)
    return record


def _finish(partial: Path, final: Path, record: dict, keep_frames: bool) -> None:
    if not keep_frames:
        for p in partial.iterdir():
            if p.is_dir():
                shutil.rmtree(p)
    write_json_atomic(partial / DRAW_FILE, json.loads(json.dumps(record, default=float)))
    os.replace(partial, final)
