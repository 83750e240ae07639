"""``scheimpflug identify``: the whole identification in one folder, resumable, on the dataset engine.

Order of work (nothing is written before the spec, every design run's rig and
the output folder have been checked):

1. parse the spec and plan the design runs (:mod:`sim.identify.spec`);
2. check the output folder: writable; empty, or an identification of the *same*
   spec and rig file (:mod:`sim.jobfolder`);
3. write ``identify.json`` (``"complete": false``);
4. run the design runs not yet complete (:func:`sim.identify.runs.run_one`) on the
   engine (:class:`sim.dataset.engine.Engine`: this process, a local Dask cluster, or
   a scheduler); a run that fails (the machinery) is retried, then recorded as failed —
   the fit waits until every design run is complete (rerun to retry); with ``refine``,
   the refinement runs' places (:func:`sim.identify.fit.refinement_draws`, kept in
   ``refine.json``) and the refinement runs;
5. the fit (:func:`sim.identify.fit.fit_posterior`), kept in ``posterior.json``: a rerun
   reads it back, so that the held-out runs already made stay the posterior's;
6. the held-out runs at the posterior draws (the runs after the design's);
7. ``summary.json`` (the held-out figures' 90 % predictive intervals, inside or outside,
   the fitted figures at the same draws), ``identified.toml`` (the base rig with the
   posterior means, each interval in a comment), ``identify.json`` complete.

One run at a time writes the folder (``.scheimpflug.lock``); rerunning the same
command resumes; the numbers do not depend on the number of workers.
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from scheimpflug.callbacks import ProgressCallback
from scheimpflug.dataset import file_sha256
from scheimpflug.errors import StudyError
from scheimpflug.io.atomic import finite_json, write_json_atomic, write_text_atomic
from scheimpflug.model.rig import rig_from_dict, rig_to_toml

from ..dataset.engine import Engine
from ..jobfolder import JobKind, open_job, remove_temporaries, run_with_retries
from ..study.spec import _with_value
from ..writer import generator_info
from .fit import fit_posterior, refinement_draws
from .posterior import predictive_interval
from .runs import PROGRESS_UNITS, RUN_FILE, run_folder, run_one
from .spec import IdentifySpec, RunPlan, plan_design, plan_run

__all__ = ["IDENTIFIED_FILE", "IDENTIFY_FORMAT", "META_FILE", "POSTERIOR_FILE", "SUMMARY_FILE", "IdentifyResult",
           "identified_rig_text", "run_identify", "summarise_identification"]

IDENTIFY_FORMAT = 1
META_FILE = "identify.json"
POSTERIOR_FILE = "posterior.json"
REFINE_FILE = "refine.json"
SUMMARY_FILE = "summary.json"
IDENTIFIED_FILE = "identified.toml"
IDENTIFY_JOB = JobKind(error=StudyError, meta_file=META_FILE, noun="identification",
                       folder_noun="identification folder", owner="run",
                       what={"format": "another version of this program", "spec": "a different spec",
                             "inputs": "another rig file"},
                       differs=("output folder {out!r} holds an {noun} made with {what} ({where!r} differs); "
                                "choose another --out or delete the folder"))


@dataclass
class IdentifyResult:
    """What :func:`run_identify` did and found.

    Parameters
    ----------
    path : Path
        The identification folder.
    spec : IdentifySpec
        The spec.
    design, held_out : list of dict
        The runs' records, in run order.
    fit : dict
        ``posterior.json`` (:func:`sim.identify.fit.fit_posterior`); empty before the fit.
    summary : dict
        ``summary.json``.
    failures : list of dict
        ``{"run": k, "error": reason}`` of runs that failed every time.
    runs_done : int
        Runs completed by this call [-].
    """

    path: Path
    spec: IdentifySpec
    design: list = field(default_factory=list)
    held_out: list = field(default_factory=list)
    fit: dict = field(default_factory=dict)
    summary: dict = field(default_factory=dict)
    failures: list = field(default_factory=list)
    runs_done: int = 0

    @property
    def complete(self) -> bool:
        """Every planned run is done and the summary written."""
        return bool(self.summary.get("complete"))


class _Job:
    """Picklable ``plan → record`` for the engine."""

    def __init__(self, root: str) -> None:
        self.root = root

    def __call__(self, plan: RunPlan, progress=None, threads=None) -> dict:
        return run_one(plan, self.root, progress=progress, threads=threads)


def _identity(spec: IdentifySpec) -> dict:
    inputs = {}
    for p in spec.input_files():
        try:
            name = p.relative_to(spec.folder).as_posix()
        except ValueError:
            name = str(p)
        inputs[name] = file_sha256(p)
    return {"format": IDENTIFY_FORMAT, "kind": "identify", "spec": spec.raw, "inputs": inputs}


def _load_records(out: Path, plans: list[RunPlan]) -> dict[int, dict]:
    records = {}
    for p in plans:
        path = run_folder(out, p.index) / RUN_FILE
        if path.is_file():
            try:
                records[p.index] = json.loads(path.read_text("utf-8"))
            except (OSError, ValueError) as exc:
                raise StudyError(f"{str(path)!r} cannot be read ({exc}): delete that run folder and rerun") from None
    return records


def run_identify(spec: IdentifySpec, out, *, workers: int = 1, scheduler: str | None = None, retries: int = 1,
                 connect_timeout_s: float = 10.0, progress: ProgressCallback | None = None,
                 warn: Callable[[str], None] | None = None) -> IdentifyResult:
    """Run (or resume) the identification of ``spec`` in ``out`` (module docstring).

    Parameters
    ----------
    spec : IdentifySpec
        The parsed spec (:func:`sim.identify.spec.load_identify_spec`).
    out : path
        The identification folder (created).
    workers : int
        1 = in this process; N ≥ 2 = a local Dask cluster of N spawned workers.
    scheduler : str, optional
        Address of a running Dask scheduler to use instead.
    retries : int
        How often a failed run is tried again.
    connect_timeout_s : float
        How long to wait for ``scheduler`` [s].
    progress : ProgressCallback, optional
        ``progress(done, total)`` over all runs (:data:`sim.identify.runs.PROGRESS_UNITS` each).
    warn : callable, optional
        Receives warnings, one line each (default: stderr).

    Returns
    -------
    IdentifyResult
        Records, posterior, summary, failures.

    Raises
    ------
    StudyError
        An unwritable output folder, a folder holding another job or being written by another
        run, a damaged run folder, a fitted figure the design runs could not measure.
    EngineError
        A cluster that cannot start or a scheduler that cannot be reached.
    """
    warn = warn or (lambda msg: print(f"warning: {msg}", file=sys.stderr))
    out = Path(out)
    design = plan_design(spec)
    identity = _identity(spec)
    with open_job(out, IDENTIFY_JOB, identity, warn):
        t0 = time.perf_counter()
        result = IdentifyResult(out, spec)
        with Engine(workers=workers, scheduler=scheduler, timeout_s=connect_timeout_s, progress=progress) as engine:
            (out / "runs").mkdir(parents=True, exist_ok=True)
            remove_temporaries(out, ("runs",))
            planned = {"design": spec.runs, "refine": spec.refine,
                       "held_out": spec.posterior_draws if spec.held_out else 0}
            info = {**identity, "complete": False, "name": spec.name, "generator": generator_info(),
                    "planned": planned, "engine": {"workers": engine.workers, "scheduler": engine.scheduler}}
            write_json_atomic(out / META_FILE, info)
            total = PROGRESS_UNITS * sum(planned.values())
            records = _run(engine, design, out, result, retries, warn, 0, total)
            result.design = [records[p.index] for p in design if p.index in records]
            if not result.failures and spec.refine:
                refine = _refine_plans(spec, out, result.design)
                records = _run(engine, refine, out, result, retries, warn, PROGRESS_UNITS * spec.runs, total)
                result.design += [records[p.index] for p in refine if p.index in records]
            if result.failures:
                _finish(out, info, result, time.perf_counter() - t0)
                return result
            result.fit = _fit(spec, out, result.design, warn)
            held = _held_out_plans(spec, result.fit)
            hrec = _run(engine, held, out, result, retries, warn, PROGRESS_UNITS * (spec.runs + spec.refine), total)
            result.held_out = [hrec[p.index] for p in held if p.index in hrec]
        if not result.failures:
            result.summary = summarise_identification(spec, result.fit, result.design, result.held_out)
            write_text_atomic(out / IDENTIFIED_FILE, identified_rig_text(spec, result.summary))
        _finish(out, info, result, time.perf_counter() - t0)
        return result


def _run(engine, plans, out: Path, result: IdentifyResult, retries: int, warn, base: int, total: int) -> dict:
    records = _load_records(out, plans)
    todo = [p for p in plans if p.index not in records]

    def done(plan, res) -> None:
        records[plan.index] = res
        result.runs_done += 1

    result.failures += run_with_retries(
        engine, _Job(str(out)), todo, noun="run", key=lambda p: f"run-{p.index:06d}",
        size=lambda p: PROGRESS_UNITS, base=base + PROGRESS_UNITS * (len(plans) - len(todo)), grand_total=total,
        retries=retries, warn=warn, on_done=done, fatal=(StudyError,))
    return records


def _fit(spec: IdentifySpec, out: Path, design: list[dict], warn) -> dict:
    path = out / POSTERIOR_FILE
    if path.is_file():
        try:
            return json.loads(path.read_text("utf-8"))
        except (OSError, ValueError) as exc:
            raise StudyError(f"{str(path)!r} cannot be read ({exc}): delete it and rerun (the fit is redone "
                             "from the design runs; delete the held-out runs too)") from None
    fit = finite_json(json.loads(json.dumps(fit_posterior(spec, design, warn=warn), default=float)))
    write_json_atomic(path, fit)
    return fit


def _refine_plans(spec: IdentifySpec, out: Path, design: list[dict]) -> list[RunPlan]:
    path = out / REFINE_FILE
    if path.is_file():
        try:
            units = json.loads(path.read_text("utf-8"))["units"]
        except (OSError, ValueError, KeyError) as exc:
            raise StudyError(f"{str(path)!r} cannot be read ({exc}): delete it and the refinement runs, "
                             "and rerun") from None
    else:
        units = refinement_draws(spec, design)
        write_json_atomic(path, {"units": units})
    return [plan_run(spec, spec.runs + i, u, "refine") for i, u in enumerate(units)]


def _held_out_plans(spec: IdentifySpec, fit: dict) -> list[RunPlan]:
    if not spec.held_out:
        return []
    first = spec.runs + spec.refine
    return [plan_run(spec, first + i, u, "held-out") for i, u in enumerate(fit["draws"])]


# ------------------------------------------------------------------ summary


def _interval_row(f, values: list) -> dict:
    pi = predictive_interval(values)
    inside = None if pi["lo90"] is None else bool(pi["lo90"] <= f.measured <= pi["hi90"])
    row = {"figure": f.name, "measured": f.measured, "uncertainty": f.uncertainty,
           "predicted_lo90": pi["lo90"], "predicted_hi90": pi["hi90"], "predicted_median": pi["median"],
           "coverage": pi["coverage"], "draws_measured": pi["n"], "draws": len(values), "inside": inside}
    if f.uncertainty is not None and inside is not None:
        row["inside_within_uncertainty"] = bool(pi["lo90"] - f.uncertainty <= f.measured
                                                <= pi["hi90"] + f.uncertainty)
    return row


def summarise_identification(spec: IdentifySpec, fit: dict, design: list[dict], held: list[dict]) -> dict:
    """The identification's summary: parameters, held-out predictions, the fitted figures' check.

    Parameters
    ----------
    spec : IdentifySpec
        The spec.
    fit : dict
        The posterior (:func:`sim.identify.fit.fit_posterior`).
    design, held : list of dict
        The design and held-out runs' records.

    Returns
    -------
    dict
        ``parameters`` (``key``, ``mean``, ``lo90``, ``hi90``, ``identifiable`` and more),
        ``correlation`` ({``keys``, ``matrix``}), ``held_out`` and ``fitted`` (per figure: the
        measured value, the 90 % predictive interval of the posterior draws, ``inside``),
        ``surrogate_cv_error``, ``method``, ``fallback``, ``inference``, ``runs``, ``complete``.
    """
    not_measured = {f.name: [r["run"] for r in design if r["figures"].get(f.name) is None] for f in spec.fitted}
    return {
        "name": spec.name, "method": fit["method"], "fallback": fit["fallback"], "complete": True,
        "inference": fit.get("inference", "hand+hand"),      # a fit of an earlier version: the hand backends
        "parameters": fit["summary"]["parameters"],
        "correlation": {"keys": spec.keys, "matrix": fit["summary"]["correlation"]},
        "held_out": [_interval_row(f, [r["figures"].get(f.name) for r in held]) for f in spec.held_out],
        "fitted": [_interval_row(f, [r["figures"].get(f.name) for r in held]) for f in spec.fitted] if held else [],
        "surrogate_cv_error": fit["surrogate_cv_error"], "mcmc": fit.get("mcmc"), "abc": fit.get("abc"),
        "noise_correlation": fit.get("noise_correlation"),
        "runs": {"design": spec.runs, "refine": spec.refine, "held_out": len(held),
                 "design_not_measured": {k: v for k, v in not_measured.items() if v},
                 "held_out_reasons": _reasons(spec, held),
                 "cpu_s": sum(r["seconds"]["cpu"] for r in design + held),
                 "wall_s_runs": sum(r["seconds"]["wall"] for r in design + held)},
    }


def _reasons(spec: IdentifySpec, held: list[dict]) -> dict:
    out = {}
    for f in spec.held_out + spec.fitted:
        why = sorted({r["reasons"].get(f.name, "") for r in held if r["figures"].get(f.name) is None} - {""})
        if why:
            out[f.name] = why
    return out


def _finish(out: Path, info: dict, result: IdentifyResult, wall_s: float) -> None:
    if result.summary:
        result.summary["runs"].update(done_now=result.runs_done, failures=result.failures, wall_s=wall_s)
        result.summary = finite_json(json.loads(json.dumps(result.summary, default=float)))
        write_json_atomic(out / SUMMARY_FILE, result.summary)
    write_json_atomic(out / META_FILE, dict(info, complete=result.complete, failures=result.failures,
                                            last_run={"wall_s": round(wall_s, 3), "runs_done": result.runs_done}))


# ------------------------------------------------------------------ the identified rig


def _comment(p: dict) -> str:
    prior = p["prior"]
    if p["identifiable"]:
        return (f"identified: 90 % interval [{p['lo90']:.4g}, {p['hi90']:.4g}], posterior sd {p['sd']:.3g}; "
                f"prior {prior['form']}")
    return (f"NOT identifiable: the fitted figures leave it flat over its prior {prior['form']} (90 % interval "
            f"[{p['lo90']:.4g}, {p['hi90']:.4g}]); this mean is the prior's, not a measurement")


def identified_rig_text(spec: IdentifySpec, summary: dict) -> str:
    """``identified.toml``: the base rig with the posterior means, each interval in a comment.

    Parameters
    ----------
    spec : IdentifySpec
        The spec.
    summary : dict
        :func:`summarise_identification`'s result.

    Returns
    -------
    str
        A rig file (TOML) that :func:`scheimpflug.model.rig.load_rig` reads.
    """
    tables = spec.rig_tables
    comments = {}
    for p in summary["parameters"]:
        tables = _with_value(tables, p["key"], float(f"{p['mean']:.4g}"))
        comments[p["key"]] = _comment(p)
    text = rig_to_toml(rig_from_dict(tables))
    lines, table = [], ""
    for line in text.splitlines():
        if line.startswith("[") and line.endswith("]"):
            table = line[1:-1]
        key = f"{table}.{line.split('=', 1)[0].strip()}" if "=" in line else ""
        lines.append(f"{line}  # {comments[key]}" if key in comments else line)
    fitted = ", ".join(f"{f.name} = {f.describe()}" for f in spec.fitted)
    head = [f"# The rig identified by `scheimpflug identify` ({spec.name}, {summary['method']}): the base rig "
            f"({spec.rig_source}) with the posterior means of {', '.join(spec.keys)}.",
            f"# Fitted: {fitted}.",
            *(f"# Held out: {h['figure']} measured {h['measured']:g}, predicted "
              + (f"[{h['predicted_lo90']:.4g}, {h['predicted_hi90']:.4g}] (90 %): "
                 f"{'inside' if h['inside'] else 'OUTSIDE'}" if h["inside"] is not None else "not predicted")
              + "." for h in summary["held_out"]), ""]
    return "\n".join(head + lines) + "\n"

