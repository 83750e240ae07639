"""Atomic file writing: a reader never sees a half-written file.

Everything is written to a temporary name in the destination folder and then
renamed over the final name (``os.replace`` is atomic on POSIX).
:func:`target_path` names the file a temporary stands for (messages name
the real target, never a temporary name); :func:`finite_json` makes any
result strict JSON (undefined numbers become ``null``).
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import re
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

__all__ = ["atomic_path", "finite_json", "target_path", "target_text", "write_bytes_atomic", "write_json_atomic",
           "write_text_atomic"]


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it to ``path`` on success.

    The temporary file keeps ``path``'s suffix (or ``suffix``) so that writers
    that choose the format from the extension (OpenCV, trimesh) still work.
    On an exception the temporary file is removed and ``path`` is untouched.

    Parameters
    ----------
    path : str or os.PathLike
        The final file; its parent folders are created.
    suffix : str, optional
        Suffix of the temporary name; default ``path``'s own suffix.

    Yields
    ------
    Path
        An empty temporary file in ``path``'s folder (mode as the umask gives
        a new file) to write; it is renamed over ``path`` when the ``with``
        block ends without an exception.
    """
    final = Path(path)
    final.parent.mkdir(parents=True, exist_ok=True)
    sfx = suffix if suffix is not None else final.suffix
    fd, tmp_name = tempfile.mkstemp(prefix=f".{final.stem}.", suffix=".tmp" + sfx, dir=final.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp makes 0600; give the file the usual mode
    try:
        yield tmp
        os.replace(tmp, final)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        raise


def _read_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_UMASK = _read_umask()  # read once at import: os.umask is process-wide, not thread-safe


def write_bytes_atomic(path: str | os.PathLike, data: bytes) -> None:
    """Write bytes to a file atomically.

    Parameters
    ----------
    path : str or os.PathLike
        The destination file.
    data : bytes
        The content.
    """
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    """Write text to a file atomically, encoded as UTF-8.

    Parameters
    ----------
    path : str or os.PathLike
        The destination file.
    text : str
        The content.
    """
    write_bytes_atomic(path, text.encode("utf-8"))


def write_json_atomic(path: str | os.PathLike, obj, indent: int = 2) -> None:
    """Write an object as JSON to a file atomically, with a final newline.

    Parameters
    ----------
    path : str or os.PathLike
        The destination file.
    obj : object
        Anything :func:`json.dumps` serialises.
    indent : int, default 2
        Indentation of the JSON text.

    Raises
    ------
    ValueError
        If ``obj`` holds NaN or ±inf (not JSON); nothing is written.
    TypeError
        If ``obj`` holds something JSON cannot represent; nothing is written.
    """
    write_text_atomic(path, json.dumps(obj, indent=indent, allow_nan=False) + "\n")


#: temporary names and the part of them that is the real name: atomic_path's ``.STEM.XXXXXXXX.tmpSFX``,
#: a frame loop's ``.NAME.tmpPID-THREAD``, a work folder's ``.NAME.partial``
_TEMPORARY = (re.compile(r"^\.(?P<stem>.+)\.[A-Za-z0-9_]{8}\.tmp(?P<suffix>\.[^.]*)?$"),
              re.compile(r"^\.(?P<stem>.+)\.tmp\d+-\d+$"),
              re.compile(r"^\.(?P<stem>.+)\.partial$"))


def target_path(path: str | os.PathLike) -> str:
    """The path a temporary name stands for (every temporary component replaced by its target).

    ``samples/.000003.partial/frames/.00002.png.tmp12-34`` → ``samples/000003/frames/00002.png``;
    ``.index.k3j4l5m6.tmp.parquet`` → ``index.parquet``; other paths are returned as they are.

    Parameters
    ----------
    path : str or os.PathLike
        A path, perhaps of a temporary file or inside a work folder.

    Returns
    -------
    str
        The path of the real target.
    """
    text = os.fspath(path)
    if not text:
        return text
    parts = []
    for part in text.split(os.sep):
        for pattern in _TEMPORARY:
            m = pattern.match(part)
            if m:
                part = m.group("stem") + (m.groupdict().get("suffix") or "")
                break
        parts.append(part)
    return os.sep.join(parts)


def target_text(text: str) -> str:
    """A message with every temporary path in it replaced by its target (:func:`target_path`).

    Parameters
    ----------
    text : str
        A message that may name temporary files or work folders.

    Returns
    -------
    str
        The message naming the real targets.
    """
    return re.sub(r"[^\s'\"()]+", lambda m: target_path(m.group()) if "." in m.group() else m.group(), str(text))


def finite_json(obj: Any) -> Any:
    """``obj`` with every NaN or ±inf float replaced by None (JSON ``null``: undefined).

    Dicts, lists and tuples are copied recursively (tuples become lists); numpy
    scalars and arrays become Python numbers and lists.

    Parameters
    ----------
    obj : object
        A JSON-like value.

    Returns
    -------
    object
        The same value, strict JSON (:func:`json.dumps` with ``allow_nan=False`` accepts it).
    """
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: finite_json(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_json(v) for v in obj]
    if hasattr(obj, "dtype") and hasattr(obj, "tolist"):     # numpy scalars and arrays
        return finite_json(obj.tolist())
    return obj
