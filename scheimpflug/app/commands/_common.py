"""Options and helpers shared by several subcommands.

* ``--rig``/``--preset`` (:func:`add_rig_options`, :func:`rig_from_args`);
* numbers on the command line: :func:`number` and :func:`integer` are argparse
  ``type=`` functions that accept only finite values in a stated range, so a
  bad value is refused with the option named (``argument --min-snr: must be a
  finite number in (0, 1e+04]``) before any work;
* outputs: :func:`check_output` refuses an output that is a folder, an input of
  the same command (or a file a frame folder manages), or an existing file
  without ``--force`` (:func:`add_force_option`), and an unwritable folder;
* :func:`print_json`: exactly one JSON object on stdout, with ``null`` where a
  value is undefined (JSON has no NaN or infinity);
* frame folders: :func:`add_allow_incomplete_option` (``--allow-incomplete``) and
  :func:`open_frames`, which opens a folder as the option says (an unfinished
  render — manifest ``"complete": false`` — is refused with how to resume it,
  or used as far as it got with a warning).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from scheimpflug.errors import ScheimpflugError
from scheimpflug.io.atomic import finite_json
from scheimpflug.io.folder import MANAGED_NAMES, unwritable_reason
from scheimpflug.model.rig import PRESETS, Rig, load_preset, load_rig

__all__ = ["PLOT_FORMATS", "add_allow_incomplete_option", "add_force_option", "add_rig_options", "check_output",
           "check_plot", "finite_json", "integer", "number", "open_frames", "print_json", "rig_from_args"]


def add_rig_options(parser: argparse.ArgumentParser) -> None:
    """``--rig FILE.toml`` or ``--preset NAME`` (default: the paper rig)."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--rig", metavar="RIG.toml", help="rig file (TOML; keys in docs/reference/rig-keys.md)")
    group.add_argument("--preset", choices=PRESETS, help="built-in rig (default: paper)")


def rig_from_args(args: argparse.Namespace) -> Rig:
    if getattr(args, "rig", None):
        return load_rig(args.rig)
    return load_preset(getattr(args, "preset", None) or "paper")


def print_json(obj: Any) -> None:
    """Exactly one JSON object on stdout; undefined (non-finite) numbers become ``null``."""
    sys.stdout.write(json.dumps(finite_json(obj), indent=2, allow_nan=False) + "\n")
    sys.stdout.flush()


# ------------------------------------------------------------------ numbers on the command line


def _interval(lo: float, hi: float, lo_open: bool, hi_open: bool) -> str:
    return f"{'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"


def number(lo: float, hi: float, *, lo_open: bool = False, hi_open: bool = False,
           unit: str = "") -> Callable[[str], float]:
    """An argparse ``type=``: a finite float within [lo, hi] (ends open if asked).

    A refused value is reported by argparse as ``argument --name: VALUE: must be a
    finite number in (lo, hi] UNIT``: one line naming the option.
    """
    where = _interval(lo, hi, lo_open, hi_open) + (f" {unit}" if unit else "")

    def parse(text: str) -> float:
        try:
            x = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number (expected one in {where})") from None
        ok = math.isfinite(x) and (lo < x if lo_open else lo <= x) and (x < hi if hi_open else x <= hi)
        if not ok:
            raise argparse.ArgumentTypeError(f"{text}: must be a finite number in {where}")
        return x

    parse.__name__ = "number"
    return parse


def integer(lo: int, hi: int) -> Callable[[str], int]:
    """An argparse ``type=``: an integer within [lo, hi], refused with the option named."""

    def parse(text: str) -> int:
        try:
            n = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not an integer (expected one in "
                                             f"[{lo}, {hi}])") from None
        if not lo <= n <= hi:
            raise argparse.ArgumentTypeError(f"{text}: must be an integer in [{lo}, {hi}]")
        return n

    parse.__name__ = "integer"
    return parse


# ------------------------------------------------------------------ outputs


def add_force_option(parser: argparse.ArgumentParser) -> None:
    """``--force``: overwrite existing output files (otherwise they are refused)."""
    parser.add_argument("--force", action="store_true",
                        help="overwrite output files that already exist (default: refuse)")


def _inside(path: Path, folder: Path) -> Path | None:
    try:
        return path.relative_to(folder)
    except ValueError:
        return None


def check_output(path: str | os.PathLike | None, option: str, *, force: bool = False,
                 inputs: Iterable[str | os.PathLike | None] = (),
                 folders: Iterable[str | os.PathLike | None] = ()) -> None:
    """Refuse an output file that cannot or must not be written, before any work.

    Refused: a folder; one of the command's ``inputs``; a file a frame folder of
    ``folders`` manages (its manifest, ``frames/``, ``truth/``, its lock and
    checksum files); an existing file unless ``force``; a location whose
    nearest existing folder is not writable.  Nothing happens for None.

    Raises
    ------
    ScheimpflugError
        Naming the option, the path and the reason.
    """
    if path is None:
        return
    p = Path(path)
    full = p.resolve()
    if p.is_dir():
        raise ScheimpflugError(f"{option} {str(p)!r} is a folder: give a file name")
    for src in inputs:
        if src is not None and Path(src).exists() and full == Path(src).resolve():
            raise ScheimpflugError(f"{option} {str(p)!r} is an input of this command: it would be "
                                   "overwritten; choose another name")
    for folder in folders:
        rel = _inside(full, Path(folder).resolve()) if folder is not None else None
        if rel is not None and rel.parts and rel.parts[0] in MANAGED_NAMES:
            raise ScheimpflugError(f"{option} {str(p)!r} lies among the files of the input frame "
                                   f"folder {str(folder)!r} ({rel.parts[0]}): choose another place")
    if p.exists() and not force:
        raise ScheimpflugError(f"{option} {str(p)!r} already exists: pass --force to overwrite it")
    _check_writable(p, option)


def _check_writable(p: Path, option: str) -> None:
    probe, reason = unwritable_reason(p.parent if str(p.parent) else Path("."))
    if reason == "is not a folder":
        raise ScheimpflugError(f"{option} {str(p)!r}: {str(probe)!r} is not a folder")
    if reason:
        raise ScheimpflugError(f"{option} {str(p)!r}: cannot write there (permission denied)")


PLOT_FORMATS = ("eps", "jpeg", "jpg", "pdf", "png", "ps", "svg", "svgz", "tif", "tiff", "webp")
"""File extensions a ``--plot`` option accepts (formats matplotlib writes)."""


def check_plot(path: str | os.PathLike | None, option: str = "--plot", **kwargs) -> None:
    """:func:`check_output` for a figure, and its extension must name an image format.

    Raises
    ------
    ScheimpflugError
        As :func:`check_output`, or for an unknown extension (the known ones listed).
    """
    if path is None:
        return
    ext = Path(path).suffix.lower().lstrip(".")
    if ext not in PLOT_FORMATS:
        shown = f".{ext}" if ext else "(no extension)"
        raise ScheimpflugError(f"{option} {str(path)!r}: unknown image format {shown} "
                               f"(known: {', '.join('.' + e for e in PLOT_FORMATS)})")
    check_output(path, option, **kwargs)


# ------------------------------------------------------------------ frame folders


def add_allow_incomplete_option(parser: argparse.ArgumentParser) -> None:
    """``--allow-incomplete``: use the frames present in a folder whose render was interrupted."""
    parser.add_argument("--allow-incomplete", action="store_true",
                        help="use the frames present in a frame folder whose render was interrupted (its "
                             "manifest says \"complete\": false); default: refused, saying how to resume it")


def open_frames(path: str | os.PathLike, args: argparse.Namespace):
    """Open a frame folder as ``--allow-incomplete`` says; the warnings it gives printed as one line each.

    Returns
    -------
    FrameFolder
        :func:`scheimpflug.io.frames.open_frame_folder` of ``path``.

    Raises
    ------
    FrameError
        As :func:`~scheimpflug.io.frames.open_frame_folder`; an unfinished folder without the option
        says how to resume it, and that ``--allow-incomplete`` uses the frames present.
    """
    import warnings

    from scheimpflug.io.frames import open_frame_folder

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        folder = open_frame_folder(path, allow_incomplete=bool(getattr(args, "allow_incomplete", False)),
                                   opt_in="pass --allow-incomplete" if hasattr(args, "allow_incomplete") else None)
    for w in caught:
        print(f"warning: {w.message}", file=sys.stderr)
    return folder
