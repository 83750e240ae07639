"""Frames of one render in several worker processes (``scheimpflug render --workers N``).

The frames of a scenario are independent given the run's seed (each frame is
rendered from its own seed, and the renderer's caches are built from their keys
alone), so a scan is rendered by N worker processes at once, frame by frame,
with the same files as one process writes, bit for bit:

* each worker is started with *spawn* (Dr.Jit registers no fork handlers),
  sizes its Dr.Jit, numba, Blosc and BLAS thread pools to ``cores // N`` and tunes
  malloc (:func:`sim.threads.configure_threads`), builds the scenario and its
  own twin once, then renders the frames it is handed: render, sensor noise,
  truth, and the encoded truth file and PNG (:func:`sim.writer.encode_npz`,
  :func:`sim.writer.encode_png16`);
* the main process builds no twin (it takes the scenario from the first
  worker): it holds the folder's lock, checks and resumes the folder, hands the
  frames out in order (at most 2 per worker in flight), writes each finished
  frame's truth and PNG atomically and records them in the ledger
  (``checksums.jsonl``), reports one progress count and writes the manifest:
  everything :func:`sim.writer.render_scenario` does, with the same rules
  (:mod:`sim.writer`).

Failures: an exception in a worker stops the run and is raised once, naming
the frame (a :class:`~scheimpflug.errors.ScheimpflugError` keeps its type; any
other error becomes a :class:`~scheimpflug.errors.RenderError` chained to it);
a worker that dies (killed, out of memory) is a :class:`RenderError` naming the
frames in flight; Ctrl-C and SIGTERM stop the workers.  Workers never write
into the folder, so every file there is complete (the frames written before
the stop stay, and a rerun resumes).  Workers ignore SIGINT (the main process
stops them) and die with the main process (Linux: ``PR_SET_PDEATHSIG``).
"""

from __future__ import annotations

import multiprocessing
import signal
import sys
import threading
import time
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from pathlib import Path

from scheimpflug.callbacks import ProgressCallback
from scheimpflug.errors import RenderError, ScheimpflugError
from scheimpflug.io.atomic import write_bytes_atomic
from scheimpflug.model.rig import Rig, is_realistic

from .threads import configure_threads, cores
from .writer import (
    RenderStats,
    build_run,
    describe_frame,
    encode_npz,
    encode_png16,
    frame_file_names,
    frame_paths,
    frame_products,
    index_ranges,
    render_locked,
    run_locked,
    scene_arrays,
)

__all__ = ["AUTO_MIN_PIXELS", "RenderJob", "auto_workers", "render_with_workers"]

#: Frames handed to each worker at most at a time (one rendering, one queued).
IN_FLIGHT_PER_WORKER = 2


#: ``auto_workers`` starts workers only for a job of at least this many pixels (frames ×
#: rows × columns; 60 full paper frames).  Two workers start ≈ 2 s later than one process
#: (each one imports, builds its twin and warms its first frame on one core).  Against
#: the pipelined one-process loop of issue 27 they are about even on 90 realistic full
#: frames (21.8 against 22.8 s) and 1.10× faster on a 360-frame scan (57.0 against
#: 62.8 s; it was 1.73× against the loop before; benchmarks/RESULTS.md).
AUTO_MIN_PIXELS = 60 * 1936 * 1216


def auto_workers(rig: Rig, frames: int, n_cores: int | None = None,
                 worker_bytes: float | None = None, ram_bytes: float | None = None) -> int:
    """Worker processes for ``--workers auto``: one per core for a realistic twin's long job, else 1.

    The realistic twin's frame costs ≈ 0.3 s of CPU on one core; two single-threaded
    workers on 2 cores render 1.10× the frames per second of one pipelined process
    using both (a 360-frame pile scan, start-up included, benchmarks/RESULTS.md); the ideal
    twin keeps one process (its frames are cheap, the workers' start-up and memory
    are not: 2 workers gain ≈ 1.2× per frame and start ≈ 1.3 s later).

    Parameters
    ----------
    rig : Rig
        The rig (binned already).
    frames : int
        Frames of the job [-].
    n_cores : int, optional
        Cores available (default: this process's, :func:`sim.threads.cores`).
    worker_bytes : float, optional
        Memory of one worker [B]; with ``ram_bytes``, the workers are capped to half the RAM.
    ram_bytes : float, optional
        The machine's memory [B].

    Returns
    -------
    int
        ≥ 1: ``n_cores`` when the twin is realistic
        (:func:`scheimpflug.model.rig.is_realistic`) and the job holds at least
        :data:`AUTO_MIN_PIXELS` pixels, 1 otherwise.
    """
    n = cores() if n_cores is None else int(n_cores)
    if not is_realistic(rig) or frames * rig.sensor.rows * rig.sensor.columns < AUTO_MIN_PIXELS:
        return 1
    if worker_bytes and ram_bytes:
        n = min(n, int(0.5 * ram_bytes // worker_bytes))
    return max(1, n)


@dataclass(frozen=True)
class RenderJob:
    """What a render worker needs to build its scenario and twin (picklable).

    Parameters
    ----------
    rig : Rig
        The instrument (binned already, if wanted).
    scenario_name : str
        The scenario (:func:`sim.scenarios.build_scenario`).
    seed : int
        Run seed.
    spp : int or None
        Laser samples per lit sensor row (None: the renderer's default).
    options : dict
        The scenario's options (``steps``, ``part``, ``truth_pixels_every`` …).
    twin_factory : callable, optional
        ``twin_factory(rig, assembly, spp=…)`` returns the twin (an importable,
        picklable function or class); default :class:`sim.writer.MitsubaTwin`.
    """

    rig: Rig
    scenario_name: str
    seed: int = 0
    spp: int | None = None
    options: dict = field(default_factory=dict)
    twin_factory: Callable | None = None


# ------------------------------------------------------------------ worker side

_STATE: dict = {}


@dataclass
class _FrameResult:
    index: int
    npz: bytes
    png: bytes
    seconds: dict
    no_stripe: bool
    warnings: list


def _die_with_parent() -> None:
    """Linux: this process gets SIGKILL when the process that started it ends."""
    import ctypes
    import ctypes.util

    if not sys.platform.startswith("linux"):
        return
    try:
        ctypes.CDLL(ctypes.util.find_library("c")).prctl(1, signal.SIGKILL)   # PR_SET_PDEATHSIG
    except (OSError, AttributeError, TypeError):  # pragma: no cover - no prctl
        pass


def _init_worker(job: RenderJob, threads: int) -> None:
    """Worker initializer: signals, thread pools, then the scenario and twin (errors kept)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)     # the main process stops the workers
    _die_with_parent()
    configure_threads(threads)
    try:
        _STATE.update(_build(job))
    except BaseException as exc:  # noqa: BLE001 - raised again by the worker's first task
        _STATE["error"] = exc


def _build(job: RenderJob) -> dict:
    from .sensor import SensorModel

    scenario, twin, manifest, messages = build_run(job.rig, job.scenario_name, job.seed, job.spp, job.options,
                                                   job.twin_factory)
    return {"job": job, "scenario": scenario, "twin": twin, "manifest": manifest, "warnings": messages,
            "mesh": scene_arrays(scenario), "frames": {f.index: f for f in scenario.frames},
            "model": SensorModel.from_rig(job.rig)}


def _state() -> dict:
    if "error" in _STATE:
        raise _STATE["error"]
    return _STATE


def _manifest_task() -> tuple[dict, object, list]:
    """The run's manifest (as :func:`sim.writer.render_folder` builds it), scenario and warnings."""
    st = _state()
    return st["manifest"], st["scenario"], st["warnings"]


def _ready_task() -> bool:
    _state()
    return True


def _frame_task(index: int) -> _FrameResult:
    """Render frame ``index``: its encoded truth file and PNG, stage times, warnings."""
    st = _state()
    frame = st["frames"][index]
    stats, warns = RenderStats(), []
    image, arrays = frame_products(st["job"].rig, st["scenario"], st["twin"], frame, stats,
                                    warns.append, st["mesh"], st["model"])
    t0 = time.perf_counter()
    npz = encode_npz(arrays)
    t1 = time.perf_counter()
    png = encode_png16(image)
    stats.seconds["truth_write"] += t1 - t0
    stats.seconds["png"] += time.perf_counter() - t1
    return _FrameResult(index, npz, png, dict(stats.seconds), bool(stats.frames_without_stripe),
                        warns)


# ------------------------------------------------------------------ main side


class _Pool:
    """A spawned process pool whose workers are stopped (not awaited) when leaving by an error."""

    def __init__(self, job: RenderJob, workers: int) -> None:
        threads = max(1, cores() // workers)
        self.executor = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"),
                                            initializer=_init_worker, initargs=(job, threads))
        self.workers, self.processes = workers, []
        self._first, self._others = None, []

    def launch(self) -> None:
        """Start every worker at once (each builds its scenario and twin); returns at once."""
        self._first = self.executor.submit(_manifest_task)
        self._others = [self.executor.submit(_ready_task) for _ in range(self.workers - 1)]
        self.processes = list(getattr(self.executor, "_processes", {}).values())

    def manifest(self, warn) -> tuple[dict, object]:
        """Manifest and scenario from the first worker once all are ready (or its setup error)."""
        try:
            manifest, scenario, messages = self._first.result()
            for fut in self._others:
                fut.result()
        except BrokenProcessPool:
            raise RenderError(f"the render workers could not start ({self._exit_codes()}; a script that "
                              "renders with workers >= 2 must run its top-level code under "
                              "'if __name__ == \"__main__\":', since spawned workers import it)") from None
        for msg in messages:
            warn(msg)
        return manifest, scenario

    def _exit_codes(self) -> str:
        codes = [p.exitcode for p in self.processes if p.exitcode is not None]
        if any(c != -signal.SIGTERM for c in codes):     # not the ones the pool stopped itself
            codes = [c for c in codes if c != -signal.SIGTERM]
        return f"exit code {', '.join(map(str, codes))}" if codes else "no exit code"

    def __enter__(self) -> _Pool:
        return self

    def __exit__(self, kind, exc, tb) -> None:
        if kind is None:
            self.executor.shutdown(wait=True)
            return
        self.executor.shutdown(wait=False, cancel_futures=True)
        for p in self.processes:
            if p.is_alive():
                p.terminate()
        for p in self.processes:
            p.join(10)


def _died_error(pool: _Pool, inflight) -> RenderError:
    """The error for a worker process that ended while ``inflight`` frames were being rendered."""
    time.sleep(0.1)     # let the dead process's exit code arrive
    indices = sorted(f.index for f in inflight)
    when = f"while frames {index_ranges(indices)} were in flight" if indices else "between frames"
    return RenderError(f"a render worker process ended unexpectedly ({pool._exit_codes()}: killed, "
                       f"or out of memory?) {when}; the frames already written are complete: "
                       "rerun to resume")


def _frame_error(exc: BaseException, frame, pool: _Pool, inflight) -> Exception:
    """One error for a frame that failed in a worker (or whose worker died)."""
    where = f"frame {frame.index} ({describe_frame(frame)})"
    if isinstance(exc, BrokenProcessPool):
        return _died_error(pool, [frame, *inflight])
    if isinstance(exc, ScheimpflugError):
        try:
            return type(exc)(f"{where}: {exc}")
        except Exception:  # noqa: BLE001 - an error type with another constructor
            pass
    err = RenderError(f"{where} failed in a render worker: {type(exc).__name__}: {exc}")
    err.__cause__ = exc
    return err


def _write_result(out: Path, result: _FrameResult, stats: RenderStats, ledger) -> None:
    """Write a finished frame's truth, then its PNG (atomically), and record both."""
    png, npz = frame_paths(out, result.index)
    t0 = time.perf_counter()
    write_bytes_atomic(npz, result.npz)
    t1 = time.perf_counter()
    try:
        write_bytes_atomic(png, result.png)
    except OSError as exc:
        raise RenderError(f"cannot write frame {str(png)!r}: {exc.strerror or exc}") from None
    stats.seconds["truth_write"] += t1 - t0
    stats.seconds["png"] += time.perf_counter() - t1
    ledger.record(result.index, frame_file_names(result.index))


def _merge(stats: RenderStats, result: _FrameResult, warn) -> None:
    for key, sec in result.seconds.items():
        stats.seconds[key] = stats.seconds.get(key, 0.0) + sec
    stats.frames_rendered += 1
    if result.no_stripe:
        stats.frames_without_stripe.append(result.index)
    for msg in result.warnings:
        warn(msg)


def _pool_loop(pool: _Pool, out: Path, warn, todo, stats, bar, ledger) -> None:
    """Hand ``todo`` out in order; write each frame as it comes back."""
    frames = iter(todo)
    inflight: dict = {}

    def hand_out() -> None:
        frame = next(frames, None)
        if frame is None:
            return
        try:
            inflight[pool.executor.submit(_frame_task, frame.index)] = frame
        except BrokenProcessPool:    # a worker died after the last result came back
            raise _died_error(pool, inflight.values()) from None

    for _ in range(IN_FLIGHT_PER_WORKER * pool.workers):
        hand_out()
    while inflight:
        done, _ = wait(list(inflight), return_when=FIRST_COMPLETED)
        for fut in sorted(done, key=lambda f: inflight[f].index):
            frame = inflight.pop(fut)
            exc = fut.exception()
            if exc is not None:
                raise _frame_error(exc, frame, pool, inflight.values())
            result = fut.result()
            _write_result(out, result, stats, ledger)
            _merge(stats, result, warn)
            stats.frames_without_stripe.sort()
            bar.update()
            hand_out()


class _TermAsInterrupt:
    """While active (main thread only): SIGTERM raises KeyboardInterrupt, so the workers are stopped."""

    def __enter__(self):
        self.old = None
        if threading.current_thread() is threading.main_thread():
            self.old = signal.signal(signal.SIGTERM, self._raise)
        return self

    @staticmethod
    def _raise(signum, frame):
        raise KeyboardInterrupt(f"signal {signum}")

    def __exit__(self, *exc) -> None:
        if self.old is not None:
            signal.signal(signal.SIGTERM, self.old)


def render_with_workers(job: RenderJob, out, workers: int, progress: ProgressCallback | None = None,
                        warn: Callable[[str], None] | None = None) -> tuple[RenderStats, dict]:
    """Render a scenario into a frame folder with ``workers`` spawned worker processes.

    The files are those of :func:`sim.writer.render_folder` with one process, bit
    for bit; the folder rules (lock, resume, ledger, atomic writes, manifest) are the
    same (module docstring).  The workers are spawned, so they import the calling
    script's ``__main__``: a script must keep its top-level code under
    ``if __name__ == "__main__":``.

    Parameters
    ----------
    job : RenderJob
        Rig, scenario, seed, samples and scenario options.
    out : str or pathlib.Path
        The frame folder (created, or resumed when it holds the same run).
    workers : int
        Worker processes (≥ 1); each sizes its thread pools to ``cores // workers``.
    progress : ProgressCallback, optional
        ``progress(done, total)`` after each frame written.
    warn : callable, optional
        Receives each warning as one line; default: print to stderr.

    Returns
    -------
    stats : RenderStats
        Frame counts and timings (``seconds``: the workers' stage times summed,
        plus the main process's writes).
    manifest : dict
        The manifest as first written (``complete`` false).

    Raises
    ------
    RenderError
        A bad ``workers``, a worker that cannot start or dies, a frame that failed in
        a worker (the message names it), and everything :func:`sim.writer.render_scenario`
        raises.
    ScheimpflugError
        A worker's own error (its type kept, the frame named), an unknown scenario or
        option, a bad part.
    """
    if not isinstance(workers, int) or workers < 1:
        raise RenderError(f"--workers {workers!r}: must be an integer >= 1")
    warn = warn or (lambda msg: print(f"warning: {msg}", file=sys.stderr))
    out = Path(out)
    with _TermAsInterrupt(), _Pool(job, workers) as pool:
        pool.launch()
        manifest, scenario = pool.manifest(warn)

        def loop(todo, stats, bar, ledger):
            _pool_loop(pool, out, warn, todo, stats, bar, ledger)

        stats = run_locked(out, warn, lambda: render_locked(job.rig, scenario, out, manifest,
                                                          progress, warn, loop))
    return stats, manifest
