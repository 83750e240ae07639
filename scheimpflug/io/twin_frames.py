"""A twin's frames read as the real camera's were imported: one path from colour files to grey frames.

A twin rendered with a camera chain writes its frames as its camera does (RGB JPEG or 8-bit RGB
PNG); the real frames went through ``scheimpflug import`` (one channel, the stripe's direction).
:func:`grey_twin_frames` takes the twin's colour frames through that same import
(:func:`scheimpflug.io.importer.import_frames`) with the real folder's ``channel`` and its
``stripe_along`` *known* (``stripe_known``: the twin's camera is the real one, so the direction is
not looked for in the frames — a faint or glaring twin stripe cannot make the import refuse), and
the twin's own ``angle_deg``.  A folder of grey frames is used as it is.  ``compare`` and the scan
identification (``sim.identify.scan``) both read a twin's frames through it.
"""

from __future__ import annotations

import json
from pathlib import Path

from scheimpflug.callbacks import ProgressCallback
from scheimpflug.errors import FrameError

__all__ = ["colour_frame_entries", "grey_twin_frames"]


def colour_frame_entries(folder: str | Path) -> list[dict] | None:
    """The manifest's frame entries of a folder whose frames are colour files, else None.

    Parameters
    ----------
    folder : str or Path
        A frame folder (``manifest.json`` + frames).

    Returns
    -------
    list of dict or None
        The entries when the first frame is a colour file (a twin written as its camera writes);
        None for grey frames, or a folder whose manifest or first frame cannot be read (opening
        the folder names what is wrong with it).
    """
    import cv2

    folder = Path(folder)
    try:
        entries = json.loads((folder / "manifest.json").read_text("utf-8"))["frames"]
        img = cv2.imread(str(folder / entries[0]["file"]), cv2.IMREAD_UNCHANGED)
    except (OSError, ValueError, KeyError, IndexError, TypeError):
        return None
    return entries if img is not None and img.ndim == 3 else None


def grey_twin_frames(folder: str | Path, out: str | Path, *, channel: str | None, stripe_along: str,
                     progress: ProgressCallback | None = None) -> Path:
    """A twin's frame folder as grey frames, imported as the real frames were (module docstring).

    Parameters
    ----------
    folder : str or Path
        The twin's frame folder (``render rotary``): every frame with its ``angle_deg``.
    out : str or Path
        Where the grey frame folder is imported to when the frames are colour files (must not
        exist, or be empty; written atomically by the importer).  Frames in angle order.
    channel : str or None
        How a colour file becomes one frame: the real folder's manifest ``channel`` (None: "r").
    stripe_along : {"columns", "rows"}
        The real folder's stripe direction, recorded as known (not detected, never refused).
    progress : ProgressCallback, optional
        ``progress(done, total)`` over the import (reading and writing each frame).

    Returns
    -------
    Path
        ``out`` when the frames were imported; ``folder`` itself when they are grey.

    Raises
    ------
    FrameError
        A colour frame without ``angle_deg``, a bad ``stripe_along``, or what
        :func:`scheimpflug.io.importer.import_frames` refuses (a bad frame, an output not empty).
    """
    from scheimpflug.io.importer import frames_with_angles, import_frames

    folder = Path(folder)
    entries = colour_frame_entries(folder)
    if entries is None:
        return folder
    missing = [e.get("file") for e in entries if e.get("angle_deg") is None]
    if missing:
        raise FrameError(f"{str(folder)!r}: frame {missing[0]!r} has no angle_deg: not a rotary render to pair "
                         "with a real scan by angle")
    frames = frames_with_angles([folder / e["file"] for e in entries], [e["angle_deg"] for e in entries])
    return import_frames(frames, out, channel=channel or "r", stripe_along=stripe_along, stripe_known=True,
                         progress=progress)
