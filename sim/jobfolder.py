"""Resumable job folders (datasets, studies): writable, empty or the same job, never two jobs in one.

A job folder holds a metadata file whose *identity* fields (the spec, the
storage, the input files' hashes, the format version) say which job it is.
Rerunning the same job resumes it; a different job in the same folder is one
clear error naming the first field that differs.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from scheimpflug.io.folder import LOCK_NAME

__all__ = ["check_identity", "check_writable", "first_difference"]


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
    out = Path(out)
    probe = out
    while not probe.exists():
        probe = probe.parent
    if not probe.is_dir() or not os.access(probe, os.W_OK | os.X_OK):
        what = "is not a folder" if not probe.is_dir() else "is not writable"
        raise error(f"output folder {str(out)!r} is not writable: {str(probe)!r} {what}")


def first_difference(old, new, prefix: str = "") -> str:
    """The dotted path of the first entry in which two JSON-like values differ.

    Parameters
    ----------
    old, new : object
        Nested dicts / values.
    prefix : str
        Path so far.

    Returns
    -------
    str
        ``"spec.study.seed"``-like path ("" when the top level differs).
    """
    if isinstance(old, dict) and isinstance(new, dict):
        for key in sorted(set(old) | set(new), key=str):
            if json.dumps(old.get(key), sort_keys=True) != json.dumps(new.get(key), sort_keys=True):
                return first_difference(old.get(key), new.get(key), f"{prefix}{key}.")
    return prefix.rstrip(".")


def check_identity(out: str | os.PathLike, meta_file: str, identity: dict, what: dict,
                   error: type[Exception], noun: str = "dataset") -> dict | None:
    """The existing metadata of the same job in ``out``; None for a new or empty folder; else raise.

    Parameters
    ----------
    out : path
        The job folder.
    meta_file : str
        Name of the metadata file in it.
    identity : dict
        The identity fields of this job (compared one by one; ``inputs`` only over the files
        both runs know: a file missing before may appear now).
    what : dict
        Per identity field, how to name a difference ("a different spec" …).
    error : type
        The exception class to raise.
    noun : str
        What the folder holds ("dataset", "study").

    Returns
    -------
    dict or None
        The old metadata.

    Raises
    ------
    Exception
        ``error``: a folder without the metadata file that holds anything but a lock file
        (:class:`scheimpflug.io.folder.FolderLock`), an unreadable metadata file, or another job.
    """
    out = Path(out)
    if not out.exists():
        return None
    meta = out / meta_file
    if not meta.is_file():
        others = sorted(p.name for p in out.iterdir() if p.name != LOCK_NAME) if out.is_dir() else []
        if others:
            first = others[0]
            raise error(f"output folder {str(out)!r} is not empty and holds no {meta_file} "
                        f"(found {first!r}); choose a new or empty folder")
        return None
    try:
        old = json.loads(meta.read_text("utf-8"))
    except (OSError, ValueError) as exc:
        raise error(f"{str(meta)!r} cannot be read ({exc}); remove the folder or choose another --out") from None
    for key, now in identity.items():
        before = old.get(key)
        if key == "inputs" and isinstance(before, dict):
            before = {k: v for k, v in before.items() if k in now}
            now = {k: v for k, v in now.items() if k in before}
        if json.dumps(before, sort_keys=True) != json.dumps(now, sort_keys=True):
            where = first_difference({key: before}, {key: now})
            raise error(f"output folder {str(out)!r} holds a {noun} made with {what[key]} "
                        f"({where!r} differs); choose another --out or delete the folder")
    return old
