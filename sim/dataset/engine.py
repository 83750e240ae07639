"""Where dataset work runs: this process, a local Dask cluster, or a running Dask scheduler.

:class:`Engine` maps a picklable function over items and yields ``(item, result or
exception)`` as they finish:

* ``workers=1`` (default) — in this process, one item after the other;
* ``workers=N ≥ 2`` — a Dask ``LocalCluster`` of N worker processes started with
  *spawn* (Dr.Jit registers no fork handlers), one task thread each, bound to
  127.0.0.1, no dashboard; each worker sizes its Dr.Jit, numba and Blosc thread
  pools to ``cores // N``;
* ``scheduler="tcp://HOST:PORT"`` — attach to a running cluster (``dask
  scheduler`` + ``dask worker``, dask-jobqueue on Slurm, Kubernetes …).

On Dask, each worker sizes its pools to the cores it may run on divided by the
number of workers on its host (tasks run one at a time per worker: start
workers with ``--nthreads 1``).

Progress: a function run by the engine may take a ``progress`` keyword; on a Dask
worker it reports through the scheduler's event log (``log_event`` on the topic
``scheimpflug-progress``), throttled to a few messages per second, and the
client sums the latest report of every item.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from typing import Any

from scheimpflug.errors import ScheimpflugError

from ..threads import cores as _cores

__all__ = ["Engine", "EngineError"]

TOPIC = "scheimpflug-progress"


class EngineError(ScheimpflugError, RuntimeError):
    """The engine cannot start or reach its cluster (message says which and why)."""


class _Reporter:
    """A worker-side ``progress(done, total)`` that posts to the scheduler's event log."""

    def __init__(self, item_key: str, every_s: float = 0.25) -> None:
        self.key, self.every_s, self.last = item_key, every_s, 0.0

    def __call__(self, done: int, total: int) -> None:
        now = time.monotonic()
        if done < total and now - self.last < self.every_s:
            return
        self.last = now
        try:
            from distributed import get_worker

            get_worker().log_event(TOPIC, {"key": self.key, "done": int(done), "total": int(total)})
        except (ImportError, ValueError):  # not on a worker
            pass


def _run_on_worker(fn, item, key: str, workers_by_host: dict):
    """Task body on a Dask worker: ``fn(item, progress=…, threads=…)``.

    ``threads`` = this host's cores / the workers on this host.
    """
    from urllib.parse import urlparse

    from distributed import get_worker

    host = urlparse(get_worker().address).hostname
    threads = max(1, _cores() // max(1, workers_by_host.get(host, 1)))
    return fn(item, progress=_Reporter(key), threads=threads)


def _task_failure(fut, name: str) -> BaseException:
    """The exception of a failed Dask task; a worker that died running it is one :class:`EngineError`."""
    from distributed import KilledWorker

    result = fut.exception()
    if isinstance(result, KilledWorker):
        return EngineError(f"the worker process running {name} died each time it ran it (killed, out of "
                           "memory, or the task ended its process, e.g. with os._exit)")
    if not isinstance(result, BaseException):
        return RuntimeError(f"task {name} ended as {fut.status}")
    return result


class Engine:
    """Run work here, on a local Dask cluster or on a running one (module docstring).

    Parameters
    ----------
    workers : int
        1 = this process; N ≥ 2 = a spawned ``LocalCluster`` of N processes.
    scheduler : str, optional
        Address of a running Dask scheduler to attach to instead.
    timeout_s : float
        How long to wait for a scheduler [s].
    progress : callable, optional
        ``progress(done, total)`` over the units the mapped function reports
        (e.g. frames), summed over items.

    Raises
    ------
    EngineError
        ``workers < 1``, both ``workers`` and ``scheduler``, or a scheduler that cannot be reached.
    """

    def __init__(self, workers: int = 1, scheduler: str | None = None, timeout_s: float = 10.0,
                 progress: Callable[[int, int], None] | None = None) -> None:
        if not isinstance(workers, int) or workers < 1:
            raise EngineError(f"--workers {workers!r}: must be an integer >= 1")
        if scheduler and workers != 1:
            raise EngineError("give either --workers or --scheduler, not both")
        self.workers, self.scheduler, self.timeout_s = workers, scheduler, timeout_s
        self.progress = progress
        self.client = self.cluster = None
        self._latest: dict[str, tuple[int, int]] = {}
        self._lock = threading.Lock()
        self._base, self._grand_total = 0, 0

    # ---------------------------------------------------------------- life cycle
    @property
    def distributed(self) -> bool:
        """Whether work goes to Dask (a local cluster or an attached scheduler)."""
        return self.scheduler is not None or self.workers >= 2

    def __enter__(self) -> Engine:
        if self.scheduler:
            self._attach()
        elif self.workers >= 2:
            self._start_local()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Disconnect, and stop the local cluster if this engine started it."""
        for obj in (self.client, self.cluster):
            if obj is not None:
                try:
                    obj.close()
                except Exception:  # noqa: BLE001 - closing a dying cluster may raise anything
                    pass
        self.client = self.cluster = None

    def _start_local(self) -> None:
        import tempfile

        import dask
        from distributed import Client, LocalCluster

        # spawn: Dr.Jit registers no fork handlers; no statistical profiler sampling the task
        # thread every 10 ms (the nanny hands this configuration to its worker process); Dask's
        # own logs below CRITICAL silenced: a task's failure comes back to the caller, which
        # reports it in one line (no "Compute Failed" traceback blocks on stderr)
        dask.config.set({"distributed.worker.multiprocessing-method": "spawn",
                         "distributed.worker.daemon": False,
                         "distributed.worker.profile.enabled": False})
        try:
            self.cluster = LocalCluster(n_workers=self.workers, threads_per_worker=1, processes=True,
                                        host="127.0.0.1", dashboard_address="127.0.0.1:0",
                                        local_directory=tempfile.gettempdir(), silence_logs=logging.CRITICAL)
            self.client = Client(self.cluster)
        except Exception as exc:  # noqa: BLE001 - whatever keeps the cluster from starting
            self.close()
            raise EngineError(f"cannot start a local Dask cluster of {self.workers} workers: {exc}") from None
        self._subscribe()

    def _attach(self) -> None:
        from distributed import Client

        try:
            self.client = Client(self.scheduler, timeout=f"{self.timeout_s}s")
        except (OSError, TimeoutError) as exc:
            raise EngineError(f"cannot reach the Dask scheduler at {self.scheduler!r}: {exc}") from None
        except ValueError as exc:
            raise EngineError(f"--scheduler {self.scheduler!r}: {exc}") from None
        try:
            self.client.wait_for_workers(1, timeout=self.timeout_s)
        except (OSError, TimeoutError):
            self.close()
            raise EngineError(f"the Dask scheduler at {self.scheduler!r} has no workers "
                              f"(waited {self.timeout_s:g} s); start some (dask worker ADDRESS)") from None
        self._subscribe()

    def _workers_by_host(self) -> dict:
        from urllib.parse import urlparse

        count: dict = {}
        for address in self.client.scheduler_info().get("workers", {}):
            host = urlparse(address).hostname
            count[host] = count.get(host, 0) + 1
        return count

    def _subscribe(self) -> None:
        if self.progress is not None:
            self.client.subscribe_topic(TOPIC, self._on_event)

    def _on_event(self, event) -> None:
        _, msg = event
        with self._lock:
            old = self._latest.get(msg.get("key"))
            if old is None:
                return
            self._latest[msg["key"]] = (max(old[0], msg["done"]), msg["total"])
        self._report()

    # ---------------------------------------------------------------- progress
    def _report(self, final_key: str | None = None, total: int | None = None) -> None:
        if self.progress is None:
            return
        with self._lock:
            if final_key is not None:
                self._latest[final_key] = (total, total)
            done = sum(d for d, _ in self._latest.values())
        self.progress(done + self._base, self._grand_total)

    # ---------------------------------------------------------------- mapping
    def map(self, fn: Callable[..., Any], items: Iterable, key: Callable[[Any], str] = str,
            sizes: Callable[[Any], int] | None = None, window: int | None = None,
            base: int = 0, grand_total: int | None = None) -> Iterator[tuple[Any, Any]]:
        """Yield ``(item, fn(item, progress=…, threads=…))`` or ``(item, exception)`` as items finish.

        Parameters
        ----------
        fn : callable
            ``fn(item, progress=callback, threads=n)``; picklable for Dask.
        items : iterable
            Work items (picklable).
        key : callable
            A unique name per item (Dask task key, progress bookkeeping).
        sizes : callable, optional
            Units of progress of an item (e.g. its frames); default 1.
        window : int, optional
            Items in flight at most (default 4 per worker).
        base : int
            Units already done before this map (added to the progress).
        grand_total : int, optional
            Units in all (default: the sum of ``sizes`` over ``items``).

        Yields
        ------
        tuple
            ``(item, result)`` or ``(item, exception)``.
        """
        items = list(items)
        size = sizes or (lambda item: 1)
        self._base = base
        self._grand_total = grand_total if grand_total is not None else base + sum(size(i) for i in items)
        self._latest = {}
        if not self.distributed:
            yield from self._map_here(fn, items, key, size)
            return
        yield from self._map_dask(fn, items, key, size, window or 4 * max(1, self._n_workers()))

    def _n_workers(self) -> int:
        return len(self.client.scheduler_info().get("workers", {})) or self.workers

    def _map_here(self, fn, items, key, size):
        threads = _cores()
        for item in items:
            k = key(item)

            def progress(done, total, k=k):
                with self._lock:
                    self._latest[k] = (done, total)
                self._report()

            try:
                result = fn(item, progress=progress, threads=threads)
            except (KeyboardInterrupt, SystemExit):
                raise
            except Exception as exc:  # noqa: BLE001 - recorded per item by the caller
                result = exc
            self._report(k, size(item))
            yield item, result

    def _map_dask(self, fn, items, key, size, window):
        from distributed import as_completed

        todo = list(items)
        hosts = self._workers_by_host()
        pending = {}
        ac = as_completed()
        token = f"{os.getpid()}-{time.monotonic_ns()}"

        def submit(item):
            k = f"{key(item)}-{token}"
            with self._lock:
                self._latest[k] = (0, size(item))
            fut = self.client.submit(_run_on_worker, fn, item, k, hosts, key=k, pure=False)
            pending[k] = (item, fut)
            ac.add(fut)

        for item in todo[:window]:
            submit(item)
        todo = todo[window:]
        try:
            for fut in ac:
                item, _ = pending.pop(fut.key)
                if fut.status == "finished":
                    result = fut.result()
                else:
                    result = _task_failure(fut, key(item))
                fut.release()
                self._report(fut.key, size(item))
                if todo:
                    submit(todo.pop(0))
                yield item, result
        finally:
            if pending:
                self.client.cancel([f for _, f in pending.values()])
