"""The resumable job: one skeleton for the frame folder, the dataset and the study.

Every job of the twin that writes a folder — a render (:mod:`sim.writer`), a
dataset (:mod:`sim.dataset.make`), a study (:mod:`sim.study.run`) — runs the
same steps, implemented here once:

1. **writable** (:func:`check_writable`): before any work, the folder is, or can
   be created in, a writable folder;
2. **identity** (:func:`check_identity`): a folder holds a metadata file whose
   *identity* fields (spec, storage, input files' hashes, format version …) say
   which job it is; rerunning the same job resumes it, a different job in the same
   folder is one clear error naming the first field that differs, and a non-empty
   folder without the metadata file is refused — all before anything is created;
3. **lock** (:func:`open_job`): the folder is created (and proved writable by a probe
   file), then locked (:class:`scheimpflug.io.folder.FolderLock`: one writer at a
   time; a lock left by a killed writer is taken over with a warning naming it), the
   identity checked again under the lock, and the job's body run; an ``OSError`` in
   the body (a full disk) becomes one error naming the folder and the real file (never
   a temporary name), and a folder this run created is removed again when the job
   fails before writing anything;
4. **temporaries** (:func:`remove_temporaries`): files of killed writers (atomic
   writes' ``.NAME.….tmp…``, Zarr's ``….partial``) are removed before resuming;
5. **retries** (:func:`run_with_retries`): the items (samples, draws) not yet done
   run on the engine; one that fails is tried again, then recorded as failed while
   the others go on.

A :class:`JobKind` holds what differs between the three: the error type, the
metadata file, the nouns and the messages.
"""

from __future__ import annotations

import contextlib
import json
import os
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path

from scheimpflug.io.atomic import target_path, target_text
from scheimpflug.io.folder import LOCK_NAME, PROBE_PREFIX, FolderLock, make_writable_folder, unwritable_reason

__all__ = ["JobKind", "check_identity", "check_writable", "create_folder", "failure_reason", "first_difference",
           "is_temporary", "open_job", "remove_temporaries", "run_with_retries", "write_failure"]


@dataclass(frozen=True)
class JobKind:
    """What one kind of job folder is called and how its messages read.

    Parameters
    ----------
    error : type
        The error raised (a :class:`scheimpflug.errors.ScheimpflugError` subclass).
    meta_file : str
        The metadata file holding the identity (``dataset.json``, ``study.json``, ``manifest.json``).
    noun : str
        What the folder holds, in messages ("dataset", "study", "run").
    what : mapping of str to str
        Per identity field, how a difference is named ("a different spec" …); a field not
        listed is named "another <field>".
    folder_noun : str
        The folder in messages ("dataset folder", "frame folder").
    owner : str
        Who left a stale lock ("writer", "run").
    differs : str
        Message of another job in the folder; ``{out}``, ``{noun}``, ``{what}``, ``{where}`` are
        filled in.
    unreadable : str
        Message of an unreadable metadata file; ``{meta}`` and ``{exc}`` are filled in.
    depth : int or None
        How many levels of nested fields the differing path names (None: down to the leaf).
    subset_keys : tuple of str
        Identity fields (dicts) compared only over the keys both runs know (``inputs``: a file
        missing before may appear now).
    own_files : tuple of str
        Top-level names that are not content in a folder without the metadata file.
    own_dirs : tuple of str
        Top-level folders that are not content themselves (their files are).
    """

    error: type
    meta_file: str
    noun: str
    what: Mapping[str, str] = field(default_factory=dict)
    folder_noun: str = "output folder"
    owner: str = "writer"
    differs: str = ("output folder {out!r} holds a {noun} made with {what} ({where!r} differs); "
                    "choose another --out or delete the folder")
    unreadable: str = "{meta!r} cannot be read ({exc}); remove the folder or choose another --out"
    depth: int | None = None
    subset_keys: tuple = ("inputs",)
    own_files: tuple = (LOCK_NAME,)
    own_dirs: tuple = ()


# ------------------------------------------------------------------ 1. writable


def check_writable(out: str | os.PathLike, error: type[Exception]) -> None:
    """Raise ``error`` unless ``out`` is, or can be created in, a writable folder.

    Parameters
    ----------
    out : path
        The job folder (may not exist yet).
    error : type
        The exception class to raise (a :class:`scheimpflug.errors.ScheimpflugError`).

    Raises
    ------
    Exception
        ``error``, naming the folder and why.
    """
    probe, reason = unwritable_reason(out)
    if reason:
        raise error(f"output folder {str(Path(out))!r} is not writable: {str(probe)!r} {reason}")


def create_folder(out: str | os.PathLike, error: type[Exception]) -> bool:
    """Create ``out`` and prove that a file can be written in it.

    Parameters
    ----------
    out : path
        The job folder.
    error : type
        The exception class to raise.

    Returns
    -------
    bool
        Whether the folder was created now.

    Raises
    ------
    Exception
        ``error`` naming the folder and the system's reason.
    """
    out = Path(out)
    created = not out.exists()
    try:
        make_writable_folder(out)
    except OSError as exc:
        raise error(f"output folder {str(out)!r} is not writable: {exc.strerror or exc}") from None
    return created


# ------------------------------------------------------------------ 2. identity


def first_difference(old, new, prefix: str = "", depth: int | None = None) -> str:
    """The dotted path of the first entry in which two JSON-like values differ.

    Parameters
    ----------
    old, new : object
        Nested dicts / values.
    prefix : str
        Path so far.
    depth : int, optional
        Descend at most this many levels (None: to the first differing leaf).

    Returns
    -------
    str
        ``"spec.study.seed"``-like path ("" when the top level differs).
    """
    if isinstance(old, dict) and isinstance(new, dict) and (depth is None or depth > 0):
        for key in sorted(set(old) | set(new), key=str):
            if _dumps(old.get(key)) != _dumps(new.get(key)):
                return first_difference(old.get(key), new.get(key), f"{prefix}{key}.",
                                        None if depth is None else depth - 1)
    return prefix.rstrip(".")


def _dumps(value) -> str:
    return json.dumps(value, sort_keys=True)


def _content(out: Path, kind: JobKind) -> list[str]:
    """Entries of a folder without the metadata file that are content (not the writer's own)."""
    names = [p.name for p in out.iterdir() if p.name not in kind.own_files and p.name not in kind.own_dirs
             and not p.name.startswith(PROBE_PREFIX)]
    names += [f"{d}/{p.name}" for d in kind.own_dirs if (out / d).is_dir() for p in (out / d).iterdir()]
    return names


def check_identity(out: str | os.PathLike, kind: JobKind, identity: dict) -> dict | None:
    """The existing metadata of the same job in ``out``; None for a new or empty folder; else raise.

    Parameters
    ----------
    out : path
        The job folder.
    kind : JobKind
        The kind of job (metadata file, messages).
    identity : dict
        The identity fields of this job, compared one by one with the metadata's (the fields of
        ``kind.subset_keys`` only over the keys both know).

    Returns
    -------
    dict or None
        The old metadata.

    Raises
    ------
    ScheimpflugError
        ``kind.error``: a folder without the metadata file that holds content, an unreadable
        metadata file, or another job.
    """
    out = Path(out)
    if not out.exists():
        return None
    meta = out / kind.meta_file
    if not meta.is_file():
        others = _content(out, kind) if out.is_dir() else []
        if others:
            raise kind.error(f"output folder {str(out)!r} is not empty and holds no {kind.meta_file} "
                             f"(found {others[0]!r}); choose a new or empty folder")
        return None
    try:
        old = json.loads(meta.read_text("utf-8"))
    except (OSError, ValueError) as exc:
        raise kind.error(kind.unreadable.format(meta=str(meta), exc=exc)) from None
    if not isinstance(old, dict):
        raise kind.error(kind.unreadable.format(meta=str(meta), exc="not a JSON object"))
    for key, now in identity.items():
        before = old.get(key)
        if key in kind.subset_keys and isinstance(before, dict) and isinstance(now, dict):
            before = {k: v for k, v in before.items() if k in now}
            now = {k: v for k, v in now.items() if k in before}
        if _dumps(before) != _dumps(now):
            where = first_difference({key: before}, {key: now}, depth=None if kind.depth is None else kind.depth + 1)
            raise kind.error(kind.differs.format(out=str(out), noun=kind.noun, where=where,
                                                 what=kind.what.get(key, f"another {key}")))
    return old


# ------------------------------------------------------------------ 3. the lock and the body


@contextlib.contextmanager
def open_job(out: str | os.PathLike, kind: JobKind, identity: dict | None,
             warn: Callable[[str], None]) -> Iterator[dict | None]:
    """Run a job's body in its folder: checked, created, locked; errors named, nothing left behind.

    Order: :func:`check_writable`, :func:`check_identity` (before anything is created),
    :func:`create_folder`, the lock (a stale lock taken over with a warning), the identity
    again under the lock; then the ``with`` body.  An ``OSError`` of the body becomes one
    ``kind.error`` naming the folder, the reason and the real file; a folder created by this
    call is removed when the job fails and it is still empty.

    Parameters
    ----------
    out : path
        The job folder.
    kind : JobKind
        The kind of job.
    identity : dict or None
        The job's identity fields (None: no identity check here, e.g. the frame folder, which
        checks its manifest itself).
    warn : callable
        Receives the stale-lock warning.

    Yields
    ------
    dict or None
        The old metadata of the same job (resume), or None for a new folder.

    Raises
    ------
    ScheimpflugError
        ``kind.error``: an unwritable or foreign folder, another writer holding the lock, a
        write that failed.
    """
    out = Path(out)
    check_writable(out, kind.error)
    if identity is not None:
        check_identity(out, kind, identity)
    created = create_folder(out, kind.error)
    try:
        try:
            with FolderLock(out, error=kind.error) as lock:
                if lock.stale_owner:
                    warn(f"took over the lock left in {str(out)!r} by a {kind.owner} that is no longer "
                         f"running (pid {lock.stale_owner.get('pid')} on {lock.stale_owner.get('host')!r})")
                yield check_identity(out, kind, identity) if identity is not None else None
        except OSError as exc:          # the lock file or the body's writes (a full disk)
            raise kind.error(write_failure(out, kind, exc)) from None
    except BaseException:
        if created:
            with contextlib.suppress(OSError):
                out.rmdir()
        raise


def write_failure(out: Path, kind: JobKind, exc: OSError) -> str:
    """One line for a write that failed in a job folder, naming the real file (not a temporary).

    Parameters
    ----------
    out : Path
        The job folder.
    kind : JobKind
        The kind of job.
    exc : OSError
        The failure.

    Returns
    -------
    str
        ``"cannot write into the dataset folder 'D': No space left on device (D/index.parquet);
        nothing is half-written: fix the cause and rerun to resume"``.
    """
    where = f" ({target_path(exc.filename)})" if exc.filename else ""
    reason = target_text(exc.strerror or str(exc))
    return (f"cannot write into the {kind.folder_noun} {str(out)!r}: {reason}{where}; "
            "nothing is half-written: fix the cause and rerun to resume")


# ------------------------------------------------------------------ 4. temporaries


def is_temporary(path: Path) -> bool:
    """Whether ``path`` is a file a killed writer left: ``.NAME….tmp…`` or Zarr's ``….partial``.

    Parameters
    ----------
    path : Path
        A file or folder.

    Returns
    -------
    bool
        True for a temporary *file* (work folders ``.NNNNNN.partial`` are not).
    """
    name = path.name
    return ((name.startswith(".") and ".tmp" in name) or name.endswith(".partial")) and path.is_file()


def remove_temporaries(out: str | os.PathLike, folders: Iterable[str] = (), deep: Iterable[str] = ()) -> int:
    """Remove the temporary files of killed writers from a job folder.

    Parameters
    ----------
    out : path
        The job folder (searched, not recursively).
    folders : iterable of str
        Subfolders searched the same way (``frames``, ``samples`` …).
    deep : iterable of str
        Subfolders searched recursively (a Zarr store).

    Returns
    -------
    int
        Files removed.
    """
    out = Path(out)
    bases = [(out, "*")] + [(out / f, "*") for f in folders] + [(out / d, "**/*") for d in deep]
    removed = 0
    for base, pattern in bases:
        if not base.is_dir():
            continue
        for p in base.glob(pattern):
            if is_temporary(p):
                p.unlink(missing_ok=True)
                removed += 1
    return removed


# ------------------------------------------------------------------ 5. retries


def failure_reason(exc: BaseException) -> str:
    """One line for an item's failure: ``"ValueError: the reason"`` (whitespace collapsed).

    Parameters
    ----------
    exc : BaseException
        The failure.

    Returns
    -------
    str
        The exception's type and message on one line; temporary names replaced by their targets
        (:func:`scheimpflug.io.atomic.target_text`).
    """
    if isinstance(exc, OSError) and exc.filename:
        text = f"{type(exc).__name__}: {exc.strerror or exc} ({exc.filename})"
    else:
        text = f"{type(exc).__name__}: {exc}"
    return " ".join(target_text(text).split())


def run_with_retries(engine, fn: Callable, todo: list, *, noun: str, key: Callable, size: Callable,
                     base: int, grand_total: int, retries: int, warn: Callable[[str], None],
                     on_done: Callable, fatal: tuple = ()) -> list[dict]:
    """Run ``fn`` over ``todo`` on ``engine``; retry what fails; return what failed every time.

    Parameters
    ----------
    engine : sim.dataset.engine.Engine
        Where the items run.
    fn : callable
        ``fn(item, progress=…, threads=…)`` (picklable).
    todo : list
        Items with an ``index`` attribute (samples, draws).
    noun : str
        The item in messages and in the failure records ("sample", "draw").
    key, size : callable
        The engine's task key and progress units of an item.
    base, grand_total : int
        Progress units done before and in all [-].
    retries : int
        How often a failed item is tried again.
    warn : callable
        Receives "``noun`` k failed (…); it will be tried again" and, at the end, one
        "``noun`` k failed: …" line per item that failed every time.
    on_done : callable
        ``on_done(item, result)`` for every item that succeeds.
    fatal : tuple of type
        Exception types that stop the whole job (raised at once).

    Returns
    -------
    list of dict
        ``{noun: k, "error": reason}`` per item that failed every time, by k.

    Raises
    ------
    Exception
        The first failure of a ``fatal`` type.
    """
    errors: dict[int, str] = {}
    for attempt in range(retries + 1):
        if not todo:
            break
        failed = []
        for item, res in engine.map(fn, todo, key=key, sizes=size, base=base, grand_total=grand_total):
            if isinstance(res, BaseException):
                if fatal and isinstance(res, fatal):
                    raise res
                errors[item.index] = failure_reason(res)
                failed.append(item)
                if attempt < retries:
                    warn(f"{noun} {item.index} failed ({errors[item.index]}); it will be tried again")
                continue
            errors.pop(item.index, None)
            base += size(item)
            on_done(item, res)
        todo = failed
    failures = [{noun: k, "error": errors[k]} for k in sorted(errors)]
    by_reason: dict[str, list[int]] = {}
    for k in sorted(errors):
        by_reason.setdefault(errors[k], []).append(k)
    for reason, ks in by_reason.items():          # one line per reason
        warn(f"{noun} {ks[0]} failed: {reason}" if len(ks) == 1 else
             f"{noun}s {_ranges(ks)} failed: {reason}")
    return failures


def _ranges(indices: list[int]) -> str:
    """'0, 3–7, 9' for [0, 3, 4, 5, 6, 7, 9]."""
    parts, start = [], indices[0]
    for a, b in zip(indices, indices[1:] + [None]):
        if b != a + 1:
            parts.append(f"{start}" if start == a else f"{start}–{a}")
            start = b
    return ", ".join(parts)
