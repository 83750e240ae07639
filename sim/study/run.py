"""``scheimpflug study sweep|tolerance``: every draw of a spec into a study folder, resumable, on Dask.

Order of work (nothing is written before the spec, every draw's rig and the
output folder have been checked):

1. parse the spec and plan every draw (:mod:`sim.study.spec`): an impossible
   design or drawn rig is one :class:`StudyError` naming it;
2. check the output folder: writable; empty, or a study of the *same* kind, spec
   and rig file (:mod:`sim.jobfolder`);
3. write ``study.json`` (``"complete": false``);
4. run the draws not yet complete (:func:`sim.study.draw.run_draw`) on the dataset
   engine (:class:`sim.dataset.engine.Engine`: this process, a local Dask cluster,
   or a scheduler); a draw that fails (the machinery, not the design) is retried,
   then recorded as failed while the others go on;
5. tolerance studies: the analytic propagation (:func:`sim.study.propagation.propagate`,
   in this process, seconds; kept in ``analytic.json`` for reruns);
6. the table ``draws.parquet`` and ``draws.csv`` (one row per draw), the analysis
   (:mod:`sim.study.analysis`) in ``summary.json``, and ``study.json`` complete.

One run at a time writes a study folder (``.scheimpflug.lock``, the datasets' lock).
Rerunning the same command resumes: complete draws are kept, a draw killed
mid-way continues frame by frame, nothing is run twice; the numbers do not
depend on the number of workers.
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
from scheimpflug.io.atomic import atomic_path, finite_json, write_json_atomic

from ..dataset.engine import Engine
from ..jobfolder import JobKind, open_job, remove_temporaries, run_with_retries
from ..writer import generator_info
from .analysis import analyse_sweep, analyse_tolerance, table_rows
from .draw import DRAW_FILE, PROGRESS_UNITS, draw_folder, run_draw
from .spec import DrawPlan, StudySpec, check_constraints, plan_draws

__all__ = ["ANALYTIC_FILE", "META_FILE", "STUDY_FORMAT", "SUMMARY_FILE", "TABLE_FILE", "StudyResult", "run_study"]

STUDY_FORMAT = 1
META_FILE = "study.json"
SUMMARY_FILE = "summary.json"
ANALYTIC_FILE = "analytic.json"
TABLE_FILE = "draws.parquet"
#: the study folder as a job (:mod:`sim.jobfolder`)
STUDY_JOB = JobKind(error=StudyError, meta_file=META_FILE, noun="study", folder_noun="study folder", owner="run",
                    what={"format": "another version of this program", "kind": "the other study command",
                          "spec": "a different spec", "inputs": "another rig file"})


@dataclass
class StudyResult:
    """What :func:`run_study` did and found.

    Parameters
    ----------
    path : Path
        The study folder.
    spec : StudySpec
        The study.
    records : list of dict
        Every complete draw's record, in draw order.
    rows : list of dict
        The table (:func:`sim.study.analysis.table_rows`).
    summary : dict
        ``summary.json``: the analysis, the analytic propagation (tolerance), counts, timings.
    failures : list of dict
        ``{"draw": k, "error": reason}`` of draws that failed twice.
    draws_run : int
        Draws completed by this run [-].
    """

    path: Path
    spec: StudySpec
    records: list = field(default_factory=list)
    rows: list = field(default_factory=list)
    summary: dict = field(default_factory=dict)
    failures: list = field(default_factory=list)
    draws_run: int = 0

    @property
    def complete(self) -> bool:
        """Every planned draw is done."""
        return not self.failures and len(self.records) == self.summary.get("planned", -1)


def _identity(spec: StudySpec) -> dict:
    inputs = {}
    for p in spec.input_files():
        try:
            name = p.relative_to(spec.folder).as_posix()
        except ValueError:
            name = str(p)
        inputs[name] = file_sha256(p)
    return {"format": STUDY_FORMAT, "kind": spec.kind, "spec": spec.raw, "inputs": inputs}


class _Job:
    """Picklable ``plan → record`` for the engine."""

    def __init__(self, root: str) -> None:
        self.root = root

    def __call__(self, plan: DrawPlan, progress=None, threads=None) -> dict:
        return run_draw(plan, self.root, progress=progress, threads=threads)


def _load_records(out: Path, plans: list[DrawPlan]) -> dict[int, dict]:
    records = {}
    for p in plans:
        path = draw_folder(out, p.index) / DRAW_FILE
        if path.is_file():
            try:
                records[p.index] = json.loads(path.read_text("utf-8"))
            except (OSError, ValueError) as exc:
                raise StudyError(f"{str(path)!r} cannot be read ({exc}): delete that draw folder and rerun") from None
    return records


def run_study(spec: StudySpec, out, *, workers: int = 1, scheduler: str | None = None, retries: int = 1,
              connect_timeout_s: float = 10.0, near_mm: float | None = None, far_mm: float | None = None,
              max_error_mm: float | None = None, progress: ProgressCallback | None = None,
              warn: Callable[[str], None] | None = None) -> StudyResult:
    """Run (or resume) the study of ``spec`` in ``out`` (module docstring).

    Parameters
    ----------
    spec : StudySpec
        The parsed spec (:func:`sim.study.spec.load_study_spec`).
    out : path
        The study folder (created).
    workers : int
        1 = in this process; N ≥ 2 = a local Dask cluster of N spawned workers.
    scheduler : str, optional
        Address of a running Dask scheduler to use instead.
    retries : int
        How often a failed draw is tried again before it is recorded as failed.
    connect_timeout_s : float
        How long to wait for ``scheduler`` [s].
    near_mm, far_mm, max_error_mm : float, optional
        Sweep constraints (:func:`sim.study.analysis.analyse_sweep`); ``max_error_mm`` defaults
        to the spec's.
    progress : ProgressCallback, optional
        ``progress(done, total)`` over all draws (each counts :data:`sim.study.draw.PROGRESS_UNITS`;
        the analytic propagation adds one unit per evaluation).
    warn : callable, optional
        Receives warnings, one line each (default: stderr).

    Returns
    -------
    StudyResult
        Records, table, summary, failures.

    Raises
    ------
    StudyError
        An impossible design or draw, an unwritable output folder, a folder holding another
        study or being written by another run (:class:`scheimpflug.io.folder.FolderLock`), a
        damaged draw folder.
    EngineError
        A cluster that cannot start or a scheduler that cannot be reached.
    """
    warn = warn or (lambda msg: print(f"warning: {msg}", file=sys.stderr))
    out = Path(out)
    check_constraints(spec, near_mm, far_mm, max_error_mm if max_error_mm is not None else spec.max_error_mm)
    plans = plan_draws(spec)
    identity = _identity(spec)
    with open_job(out, STUDY_JOB, identity, warn):     # checked, created, locked: sim.jobfolder
        return _run_locked(spec, out, plans, identity, workers, scheduler, retries, connect_timeout_s,
                           (near_mm, far_mm, max_error_mm), progress, warn)


def _run_locked(spec, out, plans, identity, workers, scheduler, retries, connect_timeout_s, constraints,
                progress, warn) -> StudyResult:
    t0 = time.perf_counter()
    result = StudyResult(out, spec)
    with Engine(workers=workers, scheduler=scheduler, timeout_s=connect_timeout_s, progress=progress) as engine:
        (out / "draws").mkdir(parents=True, exist_ok=True)
        remove_temporaries(out, ("draws",))
        info = {**identity, "complete": False, "name": spec.name, "generator": generator_info(),
                "planned": len(plans), "engine": {"workers": engine.workers, "scheduler": engine.scheduler}}
        write_json_atomic(out / META_FILE, info)
        records = _load_records(out, plans)
        _run(engine, plans, out, records, result, retries, warn)
    analytic = _analytic(spec, out, progress, len(plans)) if spec.kind == "tolerance" else None
    _finish(spec, out, info, plans, records, result, analytic, constraints, time.perf_counter() - t0)
    return result


def _run(engine: Engine, plans, out: Path, records: dict, result: StudyResult, retries: int, warn) -> None:
    todo = [p for p in plans if p.index not in records]

    def done(plan, res) -> None:
        records[plan.index] = res
        result.draws_run += 1

    result.failures = run_with_retries(
        engine, _Job(str(out)), todo, noun="draw", key=lambda p: f"draw-{p.index:06d}",
        size=lambda p: PROGRESS_UNITS, base=PROGRESS_UNITS * (len(plans) - len(todo)),
        grand_total=PROGRESS_UNITS * len(plans), retries=retries, warn=warn, on_done=done, fatal=(StudyError,))


def _analytic(spec: StudySpec, out: Path, progress, n_plans: int) -> dict | None:
    from .propagation import propagate

    path = out / ANALYTIC_FILE
    if path.is_file():
        return json.loads(path.read_text("utf-8"))
    base = PROGRESS_UNITS * n_plans

    def shifted(done: int, total: int) -> None:
        if progress is not None:
            progress(base + done, base + total)
    try:
        res = propagate(spec, progress=shifted)
    except (StudyError, ValueError) as exc:
        return {"error": str(exc)}
    except Exception as exc:  # noqa: BLE001 - the design cannot measure: reported, not fatal
        return {"error": " ".join(f"{type(exc).__name__}: {exc}".split())}
    write_json_atomic(path, json.loads(json.dumps(res, default=float)))
    return res


def _write_table(out: Path, rows: list[dict]) -> None:
    import pyarrow as pa
    import pyarrow.csv as pacsv
    import pyarrow.parquet as pq

    table = pa.Table.from_pylist(rows)
    with atomic_path(out / TABLE_FILE) as tmp:
        pq.write_table(table, tmp)
    with atomic_path(out / "draws.csv") as tmp:
        pacsv.write_csv(table, tmp)


def _finish(spec, out, info, plans, records, result, analytic, constraints, wall_s) -> None:
    recs = [records[k] for k in sorted(records)]
    rows = table_rows(spec, recs)
    if rows:
        _write_table(out, rows)
    near, far, max_err = constraints
    summary = {"kind": spec.kind, "name": spec.name, "planned": len(plans), "draws": len(recs),
               "failures": result.failures, "metric": spec.metric, "wall_s": wall_s,
               "cpu_s_draws": sum(r["seconds"]["cpu"] for r in recs)}
    if spec.kind == "tolerance":
        usable = analytic if analytic and "error" not in analytic else None
        summary.update(analyse_tolerance(spec, recs, usable) if recs else {"sensitivity": []})
        summary["draws"] = len(recs)
        summary["analytic"] = analytic
    else:
        summary.update(analyse_sweep(spec, rows, near, far, max_err if max_err is not None else spec.max_error_mm))
    summary = finite_json(json.loads(json.dumps(summary, default=float)))
    write_json_atomic(out / SUMMARY_FILE, summary)
    result.records, result.rows, result.summary = recs, rows, summary
    write_json_atomic(out / META_FILE, dict(info, complete=result.complete, draws=len(recs),
                                            failures=result.failures, last_run={"wall_s": round(wall_s, 3),
                                                                                "draws_run": result.draws_run}))
