"""Folders with one writer at a time, whose finished files can be verified.

The pieces that every writer of a frame folder (``sim.writer``), a dataset
or a study uses (the job skeleton on top of them is ``sim.jobfolder``):

* :func:`unwritable_reason` — the one check, before any work, that new files
  can be made at a path (the nearest existing folder, and why not);
  :func:`make_writable_folder` creates a folder and proves it by writing a
  probe file (``.write-probe-PID-THREAD``, :data:`PROBE_PREFIX`; no content).

* :class:`FolderLock` — an exclusive lock on a folder: the lock file
  ``DIR/.scheimpflug.lock`` holds the owner's pid, host, start time and
  program, and is locked with ``flock(2)`` while the writer runs; a second
  writer is refused with one error naming the owner.  The kernel drops the
  lock when its process dies, so a lock file left by a killed writer is
  *stale*: the next writer takes it over and says so.  On file systems without
  ``flock`` the file's existence is the lock (created with ``O_EXCL``), and a
  lock file of a process no longer running on this host is stale.
* :class:`FileLedger` — ``DIR/checksums.jsonl``: one JSON line per finished
  frame, ``{"frame": 5, "files": {"frames/00005.png": {"bytes": …, "sha256":
  …}, …}}``, appended when the frame's files are written.  A resumed run
  verifies every file it would skip against its record (size, then SHA-256)
  and redoes what does not match or was never recorded.  At the end of a run
  the ledger is rewritten sorted by frame, one line per frame, so a resumed
  folder has the same ledger as one written in a single run.

:data:`MANAGED_NAMES` are the names in a frame folder that its writer owns;
commands refuse to write an output among them.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import os
import socket
import sys
import threading
import time
from pathlib import Path

from scheimpflug.errors import LockError, ScheimpflugError
from scheimpflug.io.atomic import write_text_atomic

__all__ = ["LEDGER_NAME", "LOCK_NAME", "MANAGED_NAMES", "PROBE_PREFIX", "FileLedger", "FolderLock", "bytes_mismatch",
           "describe_owner", "file_record", "lock_owner", "make_writable_folder", "unwritable_reason"]

LOCK_NAME = ".scheimpflug.lock"
"""Lock file of a folder being written (:class:`FolderLock`)."""
LEDGER_NAME = "checksums.jsonl"
"""Size and SHA-256 of every finished frame's files (:class:`FileLedger`)."""
MANAGED_NAMES = ("manifest.json", "frames", "truth", LOCK_NAME, LEDGER_NAME)
"""Top-level names of a frame folder that belong to its writer."""
PROBE_PREFIX = ".write-probe-"
"""Name prefix of the empty file :func:`make_writable_folder` writes and removes (no content)."""

_NO_FLOCK = {errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS, errno.EINVAL}


def unwritable_reason(path: str | os.PathLike) -> tuple[Path, str | None]:
    """The nearest existing folder at or above ``path``, and why no file can be created there.

    Parameters
    ----------
    path : str or os.PathLike
        A folder or file that may not exist yet.

    Returns
    -------
    probe : Path
        ``path`` itself if it exists, else its nearest existing ancestor.
    reason : str or None
        ``"is not a folder"``, ``"is not writable"`` (no write or search permission),
        or None when files can be created there.
    """
    probe = Path(path)
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    if not probe.is_dir():
        return probe, "is not a folder"
    if not os.access(probe, os.W_OK | os.X_OK):
        return probe, "is not writable"
    return probe, None


def make_writable_folder(folder: str | os.PathLike) -> None:
    """Create ``folder`` (and its parents) and prove a file can be written in it.

    Writes and removes an empty probe file named ``PROBE_PREFIX + PID-THREAD`` (a
    folder that another process probes at the same moment holds no content).

    Parameters
    ----------
    folder : str or os.PathLike
        The folder.

    Raises
    ------
    OSError
        When the folder cannot be created or written (the caller names it).
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    probe = folder / f"{PROBE_PREFIX}{os.getpid()}-{threading.get_ident()}"
    probe.write_bytes(b"")
    probe.unlink()


def _owner() -> dict:
    return {"pid": os.getpid(), "host": socket.gethostname(),
            "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "program": " ".join(sys.argv)[:200]}


def describe_owner(owner: dict | None) -> str:
    """A lock owner in words: pid, host, start and program (:func:`lock_owner`).

    Parameters
    ----------
    owner : dict or None
        The lock file's content.

    Returns
    -------
    str
        E.g. "pid 41 on host 'lab' since 2025-01-02T03:04:05+0000 (scheimpflug render …)".
    """
    if not owner:
        return "another process (no owner recorded)"
    return (f"pid {owner.get('pid')} on host {owner.get('host')!r} since {owner.get('started')} "
            f"({owner.get('program') or 'unknown program'})")


def _pid_alive(pid) -> bool:
    if not isinstance(pid, int) or pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def lock_owner(folder: str | os.PathLike) -> tuple[dict | None, bool]:
    """Who holds or held a folder's lock, and whether that process still runs (read only).

    Parameters
    ----------
    folder : str or os.PathLike
        The folder.

    Returns
    -------
    owner : dict or None
        The lock file's owner (pid, host, started, program); None without a lock file.
    alive : bool
        The owner runs on this host now (its pid exists); False for a lock left by a killed
        writer (stale) or one of another host (unknown).
    """
    try:
        data = json.loads((Path(folder) / LOCK_NAME).read_text("utf-8") or "null")
    except (OSError, ValueError):
        return None, False
    if not isinstance(data, dict):
        return None, False
    return data, data.get("host") == socket.gethostname() and _pid_alive(data.get("pid"))


class FolderLock:
    """An exclusive, inter-process lock on a folder (module docstring); a context manager.

    Parameters
    ----------
    folder : str or os.PathLike
        The folder to lock; it must exist.
    error : type of ScheimpflugError, default LockError
        The error raised when another writer holds the folder (a writer may
        want its own type, e.g. ``RenderError``).

    Attributes
    ----------
    path : Path
        The lock file.
    stale_owner : dict or None
        The owner recorded in a stale lock file taken over (pid, host,
        started, program), else None.
    """

    def __init__(self, folder: str | os.PathLike, error: type[ScheimpflugError] = LockError) -> None:
        self.folder = Path(folder)
        self.path = self.folder / LOCK_NAME
        self.error = error
        self.stale_owner: dict | None = None
        self._fd: int | None = None
        self._flock = True

    def __enter__(self) -> FolderLock:
        self.acquire()
        return self

    def __exit__(self, *exc) -> None:
        self.release()

    def _read_owner(self) -> dict | None:
        try:
            data = json.loads(self.path.read_text("utf-8") or "null")
        except (OSError, ValueError):
            return None
        return data if isinstance(data, dict) else None

    def _busy(self, owner: dict | None) -> ScheimpflugError:
        return self.error(f"folder {str(self.folder)!r} is being written by {describe_owner(owner)}: "
                          "one writer at a time; wait for it to finish or stop it (a lock left by a "
                          f"crashed writer is taken over automatically; {LOCK_NAME} names the owner)")

    def acquire(self) -> None:
        """Take the lock or raise; a stale lock file is taken over (``stale_owner``).

        Raises
        ------
        ScheimpflugError
            ``error``, naming the owner, when another writer holds the folder.
        OSError
            When the lock file cannot be created or written (a read-only folder, a full disk:
            then no lock file is left); its ``filename`` is the lock file.
        """
        for _ in range(20):
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                locked = self._try_flock(fd)
            except BaseException:
                os.close(fd)
                raise
            if not locked:
                os.close(fd)
                self._acquire_exclusive()
                return
            if self._same_file(fd):
                self._claim(fd)
                return
            os.close(fd)          # the previous owner removed the file as we opened it: retry
        raise self._busy(self._read_owner())  # pragma: no cover - 20 lost races in a row

    def _try_flock(self, fd: int) -> bool:
        """Lock ``fd``; False if the file system has no flock; raise if another holds it."""
        import fcntl

        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise self._busy(self._read_owner()) from None
        except OSError as exc:
            if exc.errno in _NO_FLOCK:
                return False
            raise
        return True

    def _same_file(self, fd: int) -> bool:
        try:
            st = os.stat(self.path)
        except FileNotFoundError:
            return False
        return os.fstat(fd).st_ino == st.st_ino and os.fstat(fd).st_dev == st.st_dev

    def _claim(self, fd: int) -> None:
        """Write this process as the owner; a write that fails (a full disk) leaves no lock file."""
        previous = self._read_owner()
        data = json.dumps(_owner()).encode("utf-8")
        try:
            os.ftruncate(fd, 0)
            if os.pwrite(fd, data, 0) != len(data):
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        except OSError as exc:
            with contextlib.suppress(OSError):
                self.path.unlink()          # an empty lock file would name no owner
            os.close(fd)
            raise OSError(exc.errno, exc.strerror or str(exc), str(self.path)) from None
        if previous:
            self.stale_owner = previous
        self._fd = fd

    def _acquire_exclusive(self) -> None:
        """No flock here: the lock is the file's exclusive creation; stale if its pid is gone."""
        self._flock = False
        owner = self._read_owner()
        if owner is not None:
            if owner.get("host") != socket.gethostname() or _pid_alive(owner.get("pid")):
                raise self._busy(owner)
            self.stale_owner = owner
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()
        try:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o644)
        except FileExistsError:
            raise self._busy(self._read_owner()) from None
        self._claim(fd)

    def release(self) -> None:
        """Remove the lock file and drop the lock (nothing if not held)."""
        if self._fd is None:
            return
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()
        os.close(self._fd)
        self._fd = None


# ------------------------------------------------------------------ the ledger


def file_record(path: str | os.PathLike) -> dict:
    """Size and SHA-256 of a file.

    Parameters
    ----------
    path : str or os.PathLike
        The file.

    Returns
    -------
    dict
        ``{"bytes": int, "sha256": str}`` (hex digest).
    """
    with open(path, "rb") as fh:
        digest = hashlib.file_digest(fh, "sha256").hexdigest()
        size = fh.tell()
    return {"bytes": size, "sha256": digest}


def bytes_mismatch(data: bytes, want: dict) -> str | None:
    """Why a file's content is not the one a ledger recorded, or None (size, then SHA-256).

    Parameters
    ----------
    data : bytes
        The file's content.
    want : dict
        Its record, ``{"bytes": int, "sha256": str}``.

    Returns
    -------
    str or None
        "N bytes, recorded M" or "content differs from its record (SHA-256)"; None when it matches.
    """
    if len(data) != want.get("bytes"):
        return f"{len(data)} bytes, recorded {want.get('bytes')}"
    if hashlib.sha256(data).hexdigest() != want.get("sha256"):
        return "content differs from its record (SHA-256)"
    return None


class FileLedger:
    """The ``checksums.jsonl`` of a folder: what each finished frame's files must be.

    Parameters
    ----------
    folder : str or os.PathLike
        The folder (the ledger is ``folder / LEDGER_NAME``; read if it exists).
        Lines that do not parse (a write cut short) are ignored.

    Attributes
    ----------
    records : dict of int to dict
        Frame index → {relative path: {"bytes", "sha256"}}; the last line of a
        frame wins.
    """

    def __init__(self, folder: str | os.PathLike) -> None:
        self.folder = Path(folder)
        self.path = self.folder / LEDGER_NAME
        self.records: dict[int, dict[str, dict]] = {}
        self._mutex = threading.Lock()
        self._read()

    def _read(self) -> None:
        try:
            lines = self.path.read_text("utf-8", errors="replace").splitlines()
        except FileNotFoundError:
            return
        for line in lines:
            try:
                entry = json.loads(line)
                index, files = int(entry["frame"]), dict(entry["files"])
            except (ValueError, KeyError, TypeError):
                continue
            self.records[index] = files

    def record(self, index: int, files: list[str], known: dict | None = None) -> None:
        """Hash a finished frame's files and append their record.

        Parameters
        ----------
        index : int
            Frame index.
        files : list of str
            The frame's files, relative to the folder (``frames/00005.png``).
        known : dict, optional
            Relative path → ``{"bytes", "sha256"}`` of files the caller has just written and
            hashed (they are not read again).
        """
        known = known or {}
        entry = {rel: dict(known[rel]) if rel in known else file_record(self.folder / rel) for rel in files}
        line = json.dumps({"frame": int(index), "files": entry}, sort_keys=True) + "\n"
        with self._mutex:
            with open(self.path, "a", encoding="utf-8") as fh:
                fh.write(line)
            self.records[int(index)] = entry

    def mismatch(self, index: int, files: list[str]) -> str | None:
        """Why a frame's files on disk are not the ones recorded, or None if they are.

        Parameters
        ----------
        index : int
            Frame index.
        files : list of str
            The frame's files, relative to the folder.

        Returns
        -------
        str or None
            The first reason ("not recorded", "missing", "N bytes, recorded
            M", "content differs from its record (SHA-256)"), naming the file;
            None when every file matches its size and SHA-256.
        """
        rec = self.records.get(int(index))
        if rec is None:
            return f"not recorded in {LEDGER_NAME}"
        for rel in files:
            want, p = rec.get(rel), self.folder / rel
            if want is None:
                return f"{rel} not recorded in {LEDGER_NAME}"
            if not p.is_file():
                return f"{rel} is missing"
            size = p.stat().st_size
            if size != want.get("bytes"):
                return f"{rel} has {size} bytes, recorded {want.get('bytes')}"
            if file_record(p)["sha256"] != want.get("sha256"):
                return f"{rel}: content differs from its record (SHA-256)"
        return None

    def by_file(self) -> dict[str, dict]:
        """Every recorded file's record, by its path relative to the folder.

        Returns
        -------
        dict of str to dict
            ``"frames/00005.png"`` → ``{"bytes", "sha256"}`` (the last record of a frame wins).
        """
        with self._mutex:
            return {rel: dict(rec) for i in sorted(self.records) for rel, rec in self.records[i].items()
                    if isinstance(rec, dict)}

    def write_sorted(self) -> None:
        """Rewrite the ledger atomically, one line per frame in frame order."""
        with self._mutex:
            text = "".join(json.dumps({"frame": i, "files": self.records[i]}, sort_keys=True) + "\n"
                           for i in sorted(self.records))
            write_text_atomic(self.path, text)
