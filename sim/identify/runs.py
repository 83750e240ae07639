"""One run of an identification: render its experiments on its rig, measure every figure — resumable.

A run renders the experiments of its plan (:attr:`sim.identify.spec.RunPlan.experiments`)
with the twin: the plate frames, then (when a figure needs them) the blocker and
the rotary scans of the pile and the cylinder, each processed as the spec says
(:mod:`sim.identify.figures`).  A design run measures the fitted figures'
experiments, a held-out run everything.

Files: the run works in ``runs/.NNNNNN.partial/`` (frame folders resume frame by
frame) and writes ``run.json`` there; the folder is then renamed to
``runs/NNNNNN/`` (the frame folders removed unless ``keep_frames``).  A run whose
final folder holds ``run.json`` is done and never run again.

A run whose frames cannot give a figure (no plate edge in view, no blocker
stripe) records the figure as None with the reason, not an exception; a failure
of the machinery (the renderer, the disk) raises, and the job tries the run again.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import time
from pathlib import Path

from scheimpflug.callbacks import ProgressCallback
from scheimpflug.errors import ScheimpflugError, StudyError
from scheimpflug.io.atomic import write_json_atomic
from scheimpflug.model.binning import binned_rig
from scheimpflug.model.rig import rig_from_dict

from ..threads import configure_threads
from .figures import FIGURES, measure_axis, measure_calibration, measure_cylinder, measure_pile
from .spec import RunPlan

__all__ = ["PROGRESS_UNITS", "RUN_FILE", "measure_rig", "run_folder", "run_one"]

RUN_FILE = "run.json"
#: Progress units of one run [-].
PROGRESS_UNITS = 10


def run_folder(root: str | os.PathLike, index: int, partial: bool = False) -> Path:
    """The folder of run ``index`` in an identification folder.

    Parameters
    ----------
    root : path
        The identification folder.
    index : int
        Run number [-].
    partial : bool
        The working folder (``runs/.NNNNNN.partial``) instead of the final one.

    Returns
    -------
    Path
        ``root/runs/NNNNNN`` or ``root/runs/.NNNNNN.partial``.
    """
    name = f".{index:06d}.partial" if partial else f"{index:06d}"
    return Path(root) / "runs" / name


def _render(rig_b, scenario: str, out: Path, seed: int, spp, **options) -> Path:
    from ..writer import render_folder

    render_folder(rig_b, scenario, out, seed=seed, spp=spp, warn=lambda msg: None, truth_pixels_every=0, **options)
    return out


def _reason(exc: BaseException) -> str:
    return " ".join(str(exc).split())


def measure_rig(rig, experiments, experiment, work: str | os.PathLike, seed: int,
                progress: ProgressCallback | None = None) -> tuple[dict, dict]:
    """Render ``experiments`` of ``rig`` into ``work`` and measure every figure they give.

    Parameters
    ----------
    rig : Rig
        The full-size rig (binned here by ``experiment.binning``).
    experiments : sequence of str
        The experiments (:data:`sim.identify.figures.EXPERIMENTS`, prefix-closed).
    experiment : sim.identify.spec.Experiment
        How they are rendered and processed.
    work : path
        Folder for the frame folders (resumable).
    seed : int
        Render seed of every scenario [-].
    progress : ProgressCallback, optional
        ``progress(done, total)`` over the experiments.

    Returns
    -------
    figures : dict
        Figure name → value (None where the frames could not give it), for every figure of the
        rendered experiments.
    reasons : dict
        Figure name → why it is None.

    Raises
    ------
    RenderError
        The renderer cannot run, or a file cannot be written.
    """
    work = Path(work)
    rig_b = binned_rig(rig, experiment.binning)
    figures = {n: None for n, f in FIGURES.items() if f.experiment in experiments}
    reasons: dict = {}
    report = progress or (lambda done, total: None)
    report(0, len(experiments))
    folder = _render(rig_b, "calibration", work / "calibration", seed, experiment.spp, **experiment.calibration)
    try:
        values, cal = measure_calibration(folder, experiment.detector, experiment.method, experiment.binning)
    except (ScheimpflugError, ValueError) as exc:
        return figures, _failed(experiments, exc, reasons)
    figures.update({k: v for k, v in values.items() if k in figures})
    report(1, len(experiments))
    if "blocker" in experiments:
        folder = _render(rig_b, "blocker", work / "blocker", seed, experiment.spp)
        try:
            figures["axis_mm"] = measure_axis(folder, cal, experiment.detector)
        except (ScheimpflugError, ValueError) as exc:
            return _finite(figures, _failed(experiments[1:], exc, reasons))
        report(2, len(experiments))
        _scans(rig_b, experiments, experiment, work, seed, cal, figures, reasons, report)
    return _finite(figures, reasons)


def _failed(names, exc: BaseException, reasons: dict) -> dict:
    """Every figure of the experiments ``names`` not measured, for the reason ``exc``."""
    for n, f in FIGURES.items():
        if f.experiment in names:
            reasons[n] = _reason(exc)
    return reasons


def _scans(rig_b, experiments, experiment, work: Path, seed: int, cal, figures: dict, reasons: dict,
           report) -> None:
    """The rotary scans (pile, cylinder) the experiments ask for, with the run's calibration and axis."""
    scans = (("pile", experiment.pile_step_deg, measure_pile), ("cylinder", experiment.cylinder_step_deg,
                                                                 measure_cylinder))
    for k, (name, step_deg, measure) in enumerate(scans, start=3):
        if name not in experiments:
            continue
        folder = _render(rig_b, "rotary", work / name, seed, experiment.spp, part=name, step_deg=step_deg)
        try:
            figures.update(measure(folder, cal, figures["axis_mm"], experiment.stripe, rig_b.stage.rotary_table_z_mm))
        except (ScheimpflugError, ValueError) as exc:
            _failed((name,), exc, reasons)
        report(min(k, len(experiments)), len(experiments))


def _finite(figures: dict, reasons: dict) -> tuple[dict, dict]:
    """Non-finite values (a fit over too few points, an R² of exactly 1) become None with a reason."""
    out = {}
    for name, v in figures.items():
        ok = v is not None and math.isfinite(v)
        scale = FIGURES[name].scale
        ok = ok and not (scale == "log" and v <= 0) and not (scale == "log1m" and v >= 1)
        out[name] = float(v) if ok else None
        if not ok and name not in reasons:
            reasons[name] = "too few points in its region" if v is None or not math.isfinite(v) else \
                f"{v:g} is outside the figure's scale ({scale})"
    return out, reasons


def _units(progress: ProgressCallback | None):
    if progress is None:
        return None

    def scaled(done: int, total: int) -> None:
        progress(min(PROGRESS_UNITS, done * PROGRESS_UNITS // max(total, 1)), PROGRESS_UNITS)
    return scaled


def run_one(plan: RunPlan, root: str | os.PathLike, progress: ProgressCallback | None = None,
            threads: int | None = None) -> dict:
    """Run (or resume) run ``plan.index`` of the identification in ``root`` (module docstring).

    Parameters
    ----------
    plan : RunPlan
        What the run renders (:func:`sim.identify.spec.plan_run`).
    root : path
        The identification folder (``runs/`` exists).
    progress : ProgressCallback, optional
        ``progress(done, PROGRESS_UNITS)`` over the run's experiments.
    threads : int, optional
        Size this process's thread pools first (:func:`sim.threads.configure_threads`).

    Returns
    -------
    dict
        The run's record (``run.json``): ``run``, ``role``, ``seed``, ``values``, ``unit``,
        ``figures`` (name → value or None), ``reasons``, ``seconds``.

    Raises
    ------
    StudyError
        The final folder exists without ``run.json`` (damaged or foreign).
    RenderError
        The renderer cannot run, or a file cannot be written.
    """
    if threads:
        configure_threads(threads)
    final = run_folder(root, plan.index)
    if (final / RUN_FILE).is_file():
        return json.loads((final / RUN_FILE).read_text("utf-8"))
    if final.exists():
        raise StudyError(f"run folder {str(final)!r} exists but has no {RUN_FILE}: delete it and rerun")
    t0, c0 = time.perf_counter(), time.process_time()
    partial = run_folder(root, plan.index, partial=True)
    partial.mkdir(parents=True, exist_ok=True)
    figures, reasons = measure_rig(rig_from_dict(plan.rig), plan.experiments, plan.experiment, partial,
                                   plan.seed, _units(progress))
    record = {"run": plan.index, "role": plan.role, "seed": plan.seed, "values": plan.values,
              "unit": list(plan.unit), "experiments": list(plan.experiments), "figures": figures,
              "reasons": reasons, "seconds": {"wall": time.perf_counter() - t0, "cpu": time.process_time() - c0}}
    if not plan.keep_frames:
        for p in partial.iterdir():
            if p.is_dir():
                shutil.rmtree(p)
    write_json_atomic(partial / RUN_FILE, json.loads(json.dumps(record, default=float)))
    os.replace(partial, final)
    return record
