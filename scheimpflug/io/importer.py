"""Real frames without a manifest: PNG, TIFF or JPEG files + stage positions → a frame folder.

``scheimpflug import FRAMES... (--positions CSV | --positions-from-names PATTERN) --out DIR``
builds the frame folder of docs/reference/interface.md (``manifest.json`` + ``frames/NNNNN.png``)
from a camera's files, so that ``calibrate``, ``axis`` and ``reconstruct`` read
real frames the same way as the twin's.

Frames
    PNG, TIFF or JPEG, 8 or 16 bit (a 12-bit camera's frames are 16-bit
    files; give ``adc_bits = 12`` so that saturation is found at 4095), read
    with OpenCV (``tifffile``, when installed, is tried for TIFFs OpenCV cannot
    decode); grey, or colour with ``channel`` — ``"r"``, ``"g"``, ``"b"`` (a red
    laser: ``"r"``), ``"gray"`` (OpenCV's luminance, 0.299 R + 0.587 G + 0.114 B)
    or a weighting ``"wr,wg,wb"`` (rounded to the file's depth; a colour file
    without ``channel`` is refused).  Every frame must have the first frame's
    size and bit depth, and all frames and backgrounds must be colour or all
    grey (a grey file's luminance does not compare with a colour file's red).
    They are copied losslessly to 16-bit (or 8-bit) PNG, ordered by position.
Files checked before they are decoded
    A JPEG must reach its end-of-image marker (``FFD9``) and a PNG its ``IEND``
    chunk, a TIFF's image data must lie within the file: a file cut short (which
    libjpeg decodes with its missing lower part grey) is refused as truncated.
    A multi-page TIFF (or an animated PNG) is refused with its page count.  The
    EXIF orientation (JPEG, TIFF, PNG ``eXIf``) is read: by default the frames
    are imported as stored (a calibration of stored frames — FabScan's — needs
    them so) with a warning naming each tagged file and what its tag asks
    viewers to do; ``exif_orientation="apply"`` turns them as viewers do.  The
    manifest records the tag of each tagged frame and which was done.
Backgrounds
    laser-off frames of the same views (``backgrounds``, one per frame, in the
    frames' order): subtracted on import (clipped at 0), so that ambient light
    and lit surroundings leave the stripe alone; the manifest names each
    frame's background.
Frames without positions
    a pattern set (``scenario="target"``, :func:`target_frames`): each frame a
    pose (``pose``, ``light``: flood), or from a CSV with ``file``, ``pose``,
    ``light`` (and ``angle_deg`` for table poses); a scan with rotary angles
    given as ``START:STEP`` or a list (:func:`frames_with_angles`).  Taken in
    room light (``room_light``), a pattern set's laser frame and the laser-off
    (``flood``) frame of its pose are a pair: the manifest says ``scenario_params.room_light``
    and names each laser frame's ``laser_off_file``.
Stripe orientation
    ``stripe_along`` ``"columns"`` (the stripe runs down the image: one point
    per row, the Scheimpflug profiler's) or ``"rows"`` (across it: one point per
    column, e.g. FabScan's frames); by default (``"auto"``) found in the frames
    that show the laser (:func:`stripe_direction`; a pattern set's laser frames,
    in room light less their pose's laser-off frame).  A given direction that
    the frames clearly contradict is refused, a weak contradiction is a warning.
    A *known* direction (``stripe_known``: the caller knows it, e.g. a twin's
    frames of a real camera whose folder records it) is not looked for in the
    frames and never refused or warned of: a faint or glaring stripe cannot stop
    the import.  Recorded in the manifest (``stripe_along``, and ``stripe_detection``:
    what was given, found, and how many frames said which; ``known`` true and
    nothing examined for a known direction), where the pipeline's extraction
    follows it.
Positions
    a CSV with a header naming ``file`` and ``stage_mm`` (translation stage,
    calibration plates) or ``angle_deg`` (rotary stage); ``file`` is matched
    against each frame's path as given or its file name; or a file-name
    pattern with one placeholder ``{stage_mm}`` or ``{angle_deg}`` and ``*``
    wildcards, e.g. ``plate_{stage_mm}mm.tif`` or ``scan_*_{angle_deg}.png``
    (matched against the file name; ``p`` stands for a decimal point, so
    ``plate_12p5mm`` reads 12.5).  Frames in a folder are taken in natural order
    (:func:`natural_key`: ``frame2`` before ``frame10``).
Rig
    optional: the calibration needs none; given, it goes into the manifest
    and its sensor size must match the frames.

Bad input — a frame without a position, a non-numeric position, a file
given twice (or listed twice in a CSV), a CSV row too short for its header,
one image under two names, values above the stated ADC range (``adc_bits``;
MSB-aligned data are named as such: ``msb_aligned`` shifts them back), mixed
sizes, bit depths or colour and grey, a truncated, multi-page, colour or
unreadable file, a scenario parameter that is not a finite number (a plate
height ≤ 0), an output that is a file or not empty — raises one
:class:`FrameError` naming the file; nothing is written unless every frame is
good (the folder is built under a temporary name, ``.NAME.xxxxxxxx`` beside it,
locked by its owner (:class:`~scheimpflug.io.folder.FolderLock`) and renamed
with the umask's mode; another import filling the same folder meanwhile is
named; a temporary folder left by an import that was killed is removed by the
next import into the same place, one without an owner is named).  Warnings: CSV
rows for files not given, two frames at one position, rotary angles that span
one turn in radians, EXIF orientation tags, a ``channel`` for grey frames, no
stripe found, a room-light laser frame without its laser-off frame.
"""

from __future__ import annotations

import csv
import errno
import hashlib
import json
import math
import os
import re
import shutil
import struct
import tempfile
import warnings
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from scheimpflug.callbacks import ProgressCallback, report
from scheimpflug.errors import FrameError
from scheimpflug.io.folder import LOCK_NAME, FolderLock, unwritable_reason
from scheimpflug.io.frames import STRIPE_ALONG, radians_note

__all__ = ["CHANNELS", "EXIF_ORIENTATIONS", "ImportedFrame", "frames_with_angles", "import_frames", "natural_key",
           "parse_angles", "positions_from_csv", "positions_from_names", "read_image", "stripe_direction",
           "target_frames"]

FORMAT = "scheimpflug-frames/1"
_KEYS = ("stage_mm", "angle_deg")
#: Colour channels a colour frame can be read as (``read_image``), besides a weighting "wr,wg,wb".
CHANNELS = ("r", "g", "b", "gray")
_LIGHTS = ("flood", "laser", "both", "background")
_LASER_LIGHTS = ("laser", "both")
_NUMBER = r"[-+]?(?:\d+(?:[.p]\d*)?|[.p]\d+)(?:[eE][-+]?\d+)?"
_STRIPE_CHOICES = ("auto", *STRIPE_ALONG)
_EXIF_CHOICES = ("stored", "apply")
#: What each EXIF orientation (TIFF tag 274) asks a viewer to do with the image as stored.
EXIF_ORIENTATIONS = {1: "show it as stored", 2: "mirror it left–right", 3: "turn it by 180°",
                     4: "mirror it top–bottom", 5: "mirror it across its main diagonal (transpose)",
                     6: "turn it 90° clockwise", 7: "mirror it across its anti-diagonal",
                     8: "turn it 90° counter-clockwise"}
_WAY = {"columns": "down the image (one point per row)", "rows": "across the image (one point per column)"}


@dataclass(frozen=True)
class _StripeRule:
    """How :func:`stripe_direction` tells a laser stripe from the rest of a frame (values with their reasons)."""

    noise_factor: float = 6.0    # a line's peak stands this many noise σ above the line's median …
    top_share: float = 0.3       # … and this share of the frame's stripe level (90th percentile of line maxima)
    width_share: float = 0.05    # at most this share of the line above half the peak: narrow …
    min_width_px: float = 8.0    # … or this many pixels (a blurred stripe on a small frame) [px]
    jump_px: int = 3             # neighbouring lines' peaks at most this far apart [px]: one ridge …
    min_run: int = 8             # … over at least this many consecutive lines (texture and edges give short runs)
    min_cover: float = 0.25      # a stripe gives a point in this share of its lines (real stripes 36–86 %;
    #                              chessboards, textures ≤ 8 %, a dark board's bright square edges 22 %: FabScan,
    #                              3DScanScience frames)
    ratio: float = 2.0           # … and this many times the points of the other direction (FabScan: ≥ 2.7)
    disagree_share: float = 0.2  # frames of the minority direction beyond this share: the set is ambiguous


_RULE = _StripeRule()


@dataclass(frozen=True)
class ImportedFrame:
    """One source frame and its stage reading.

    Parameters
    ----------
    path : Path
        The source file.
    key : str
        "stage_mm", "angle_deg", or "pose" (a pattern set's frame: ``value`` its order).
    value : float
        The position [mm] or angle [deg] (pose: the frame's place in the given order).
    extra : dict, optional
        More manifest keys of the frame (``pose``, ``light``, ``angle_deg`` of a table pose).
    """

    path: Path
    key: str
    value: float
    extra: dict | None = None


def natural_key(name: str | os.PathLike) -> tuple:
    """Sort key of a file name in natural order: digits compare as numbers (``frame2`` before ``frame10``).

    Parameters
    ----------
    name : str or os.PathLike
        A file name or path (its last component is compared).

    Returns
    -------
    tuple
        The key; names equal as numbers (``f01``, ``f1``) fall back to their text.
    """
    text = Path(name).name
    parts = [int(p) if i % 2 else p for i, p in enumerate(re.split(r"(\d+)", text))]
    return (parts, text)


# ------------------------------------------------------------------ the files' structure, before decoding


@dataclass(frozen=True)
class _Facts:
    """What a file's structure says: its EXIF orientation, its number of images, why it is cut short."""

    orientation: int | None = None
    pages: int = 1
    kind: str = ""
    truncated: str | None = None


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_TIFF_MAGIC = (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+")
_JPEG_NO_LENGTH = frozenset({0x00, 0x01, 0xFF, *range(0xD0, 0xD8)})   # stuffing, TEM, fill, restart markers
_TIFF_INT = {1: "B", 3: "H", 4: "I", 16: "Q"}                          # BYTE, SHORT, LONG, LONG8


def _file_facts(p: Path) -> _Facts:
    """Walk a JPEG's markers, a PNG's chunks or a TIFF's directories (others: nothing known)."""
    data = p.read_bytes()
    if data[:2] == b"\xff\xd8":
        return _jpeg_facts(data)
    if data[:8] == _PNG_SIGNATURE:
        return _png_facts(data)
    if data[:4] in _TIFF_MAGIC:
        return _tiff_facts(data)
    return _Facts()


def _jpeg_facts(data: bytes) -> _Facts:
    """Markers up to the end-of-image marker FFD9 (entropy-coded data skipped); the EXIF orientation."""
    pos, orientation, n = 2, None, len(data)
    while 0 <= (pos := data.find(b"\xff", pos)) < n - 1:
        marker = data[pos + 1]
        if marker == 0xD9:
            return _Facts(orientation, kind="JPEG")
        if marker in _JPEG_NO_LENGTH:
            pos += 1 if marker == 0xFF else 2
            continue
        end = pos + 2 + int.from_bytes(data[pos + 2:pos + 4], "big")
        if end > n:
            break
        if marker == 0xE1 and orientation is None and data[pos + 4:pos + 10] == b"Exif\x00\x00":
            orientation = _tiff_orientation(data[pos + 10:end])
        pos = end
    return _Facts(orientation, kind="JPEG", truncated="it ends before its end-of-image marker (FFD9)")


def _png_facts(data: bytes) -> _Facts:
    """Chunks up to IEND; the ``eXIf`` orientation and an animated PNG's frame count (``acTL``)."""
    pos, orientation, pages, n = 8, None, 1, len(data)
    while pos + 12 <= n:
        length = int.from_bytes(data[pos:pos + 4], "big")
        kind, end = data[pos + 4:pos + 8], pos + 12 + length
        if end > n:
            break
        if kind == b"IEND":
            return _Facts(orientation, pages, "PNG (animated)")
        if kind == b"eXIf":
            orientation = _tiff_orientation(data[pos + 8:end - 4])
        elif kind == b"acTL" and length >= 4:
            pages = int.from_bytes(data[pos + 8:pos + 12], "big")
        pos = end
    return _Facts(orientation, pages, "PNG (animated)", truncated="it ends before its IEND chunk")


def _tiff_layout(data: bytes) -> tuple[str, bool, int] | None:
    """Byte order (``<`` or ``>``), BigTIFF or not, and the first directory's offset; None if no TIFF header."""
    if data[:2] not in (b"II", b"MM") or len(data) < 8:
        return None
    e = "<" if data[:2] == b"II" else ">"
    magic = struct.unpack_from(e + "H", data, 2)[0]
    if magic == 42:
        return e, False, struct.unpack_from(e + "I", data, 4)[0]
    if magic == 43 and len(data) >= 16:
        return e, True, struct.unpack_from(e + "Q", data, 8)[0]
    return None


def _tiff_ifd(data: bytes, layout: tuple[str, bool, int], offset: int,
              wanted: tuple[int, ...] = ()) -> tuple[dict[int, list[int]], int]:
    """The ``wanted`` integer tags of the directory at ``offset`` and the next one's offset (struct.error if cut)."""
    e, big, _ = layout
    count_fmt, size, off_fmt = ("Q", 20, "Q") if big else ("H", 12, "I")
    (count,) = struct.unpack_from(e + count_fmt, data, offset)
    start, tags = offset + (8 if big else 2), {}
    for k in range(count):
        at = start + k * size
        tag, typ = struct.unpack_from(e + "HH", data, at)
        if tag in wanted and typ in _TIFF_INT:
            (n,) = struct.unpack_from(e + off_fmt, data, at + 4)
            tags[tag] = _tiff_values(data, e, _TIFF_INT[typ], n, at + (12 if big else 8), off_fmt)
    (nxt,) = struct.unpack_from(e + off_fmt, data, start + count * size)
    return tags, nxt


def _tiff_values(data: bytes, e: str, fmt: str, n: int, at: int, off_fmt: str) -> list[int]:
    """``n`` integers of a directory entry: in its value field if they fit, else where it points."""
    if n > len(data):
        raise struct.error("count beyond the file")
    if n * struct.calcsize(fmt) > struct.calcsize(off_fmt):
        (at,) = struct.unpack_from(e + off_fmt, data, at)
    return list(struct.unpack_from(f"{e}{n}{fmt}", data, at))


def _tiff_orientation(block: bytes) -> int | None:
    """The orientation tag (274) of an EXIF block (a TIFF structure), None if absent or malformed."""
    layout = _tiff_layout(block)
    if layout is None:
        return None
    try:
        value = _tiff_ifd(block, layout, layout[2], (274,))[0].get(274, [None])[0]
    except struct.error:
        return None
    return value if value in EXIF_ORIENTATIONS else None


def _tiff_facts(data: bytes) -> _Facts:
    """A TIFF's pages, the first page's orientation, and whether its strips or tiles lie within the file."""
    layout = _tiff_layout(data)
    try:
        tags, nxt = _tiff_ifd(data, layout, layout[2], (273, 274, 279, 324, 325)) if layout else ({}, 0)
    except struct.error:
        return _Facts(kind="TIFF")              # OpenCV and tifffile decide
    orientation = tags.get(274, [None])[0]
    pages = 1 + _more_pages(data, layout, nxt) if layout else 1
    facts = _Facts(orientation if orientation in EXIF_ORIENTATIONS else None, pages, "TIFF")
    offsets, counts = tags.get(273, []) + tags.get(324, []), tags.get(279, []) + tags.get(325, [])
    end = max((o + c for o, c in zip(offsets, counts)), default=0)
    if end > len(data):
        return _Facts(facts.orientation, facts.pages, "TIFF",
                      f"its image data run to byte {end}, but the file has {len(data)} bytes")
    return facts


def _more_pages(data: bytes, layout: tuple[str, bool, int], offset: int) -> int:
    """Directories after the first one (a multi-page TIFF), following the chain to its end or a loop."""
    seen = {layout[2]}
    while offset and offset not in seen and len(seen) <= 65536:
        seen.add(offset)
        try:
            offset = _tiff_ifd(data, layout, offset)[1]
        except struct.error:
            break
    return len(seen) - 1


def _check_facts(p: Path, facts: _Facts) -> None:
    if facts.truncated:
        raise FrameError(f"frame {str(p)!r} is truncated: {facts.truncated} (a copy cut short? its missing part "
                         "would be decoded as grey); copy the file again")
    if facts.pages > 1:
        raise FrameError(f"frame {str(p)!r} holds {facts.pages} pages (a multi-page {facts.kind}): only its first "
                         "would be imported; give one image per file")


# ------------------------------------------------------------------ reading one file


@dataclass(frozen=True)
class _Source:
    """One file read as a grey frame: the frame, whether the file was colour, its EXIF orientation."""

    image: np.ndarray
    colour: bool
    orientation: int | None


def read_image(path: str | Path, channel: str | None = None, exif_orientation: str = "stored") -> np.ndarray:
    """Read an 8- or 16-bit PNG, TIFF or JPEG as one grey frame (module docstring).

    Parameters
    ----------
    path : str or Path
        The file.
    channel : str, optional
        For a colour file: "r", "g", "b", "gray" or "wr,wg,wb" (weights of red, green, blue).
    exif_orientation : {"stored", "apply"}, default "stored"
        The frame as stored, or turned as its EXIF orientation tells viewers to.

    Returns
    -------
    (rows, columns) uint8 or uint16
        The frame [DN].

    Raises
    ------
    FrameError
        Missing, truncated, multi-page, unreadable, colour without ``channel`` or of another depth, naming
        the file; a bad ``channel``.
    """
    return _read(Path(path), channel, exif_orientation).image


def _read(p: Path, channel: str | None, exif: str) -> _Source:
    if not p.is_file():
        raise FrameError(f"frame {str(p)!r} does not exist")
    facts = _file_facts(p)
    _check_facts(p, facts)
    img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    if img is None and p.suffix.lower() in (".tif", ".tiff"):
        img = _read_tifffile(p)
    if img is None:
        raise FrameError(f"frame {str(p)!r} is unreadable or corrupt (not a PNG, TIFF or JPEG OpenCV can decode)")
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.dtype not in (np.uint8, np.uint16):
        raise FrameError(f"frame {str(p)!r} has dtype {img.dtype}: frames must be 8- or 16-bit integers")
    colour = img.ndim == 3
    if colour:
        if channel is None:
            raise FrameError(f"frame {str(p)!r} has {img.shape[2]} channels (colour): give --channel r|g|b|gray "
                             "or a weighting wr,wg,wb (a red laser: r)")
        img = _one_channel(img, channel, p)
    elif img.ndim != 2:
        raise FrameError(f"frame {str(p)!r} has shape {img.shape}: not an image")
    if exif == "apply":
        img = _orient(img, facts.orientation)
    return _Source(img, colour, facts.orientation)


_ORIENT = {2: lambda a: a[:, ::-1], 3: lambda a: a[::-1, ::-1], 4: lambda a: a[::-1], 5: lambda a: a.T,
           6: lambda a: np.rot90(a, -1), 7: lambda a: np.rot90(a, 2).T, 8: lambda a: np.rot90(a, 1)}


def _orient(img: np.ndarray, tag: int | None) -> np.ndarray:
    """The image as a viewer shows it under EXIF orientation ``tag`` (1 or None: as stored)."""
    turn = _ORIENT.get(tag)
    return img if turn is None else np.ascontiguousarray(turn(img))


def _weights(channel: str) -> np.ndarray:
    """(w_b, w_g, w_r) of a channel name or a weighting "wr,wg,wb" (OpenCV stores BGR)."""
    named = {"r": (0.0, 0.0, 1.0), "g": (0.0, 1.0, 0.0), "b": (1.0, 0.0, 0.0), "gray": (0.114, 0.587, 0.299)}
    if channel in named:
        return np.array(named[channel])
    try:
        w = [float(x) for x in channel.split(",")]
    except ValueError:
        w = []
    if len(w) != 3 or not all(math.isfinite(x) and x >= 0 for x in w) or sum(w) <= 0:
        raise FrameError(f"--channel {channel!r}: one of {', '.join(CHANNELS)} or three weights wr,wg,wb >= 0")
    return np.array(w[::-1])


def _one_channel(img: np.ndarray, channel: str, p: Path) -> np.ndarray:
    w = _weights(channel)
    if img.shape[2] == 4:
        img = img[:, :, :3]
    if img.shape[2] != 3:
        raise FrameError(f"frame {str(p)!r} has {img.shape[2]} channels: neither grey nor colour")
    if channel in ("r", "g", "b"):            # one weight 1, two 0: the channel itself, as the weighting gives it
        return np.ascontiguousarray(img[:, :, int(np.argmax(w))])
    top = float(np.iinfo(img.dtype).max)
    grey = img.astype(np.float64) @ w
    return np.clip(np.rint(grey), 0, top).astype(img.dtype)


def _read_tifffile(p: Path):
    try:
        import tifffile
    except ImportError:
        return None
    try:
        return np.asarray(tifffile.imread(str(p)))
    except Exception:  # noqa: BLE001 - any decoder failure is "unreadable"
        return None


# ------------------------------------------------------------------ positions: CSV, file names, angles, poses


def _number(text: str, where: str) -> float:
    try:
        value = float(text.strip().replace("p", "."))
    except ValueError:
        raise FrameError(f"{where}: position {text!r} is not a number") from None
    if not math.isfinite(value):
        raise FrameError(f"{where}: position {text!r} is not a finite number")
    return value


def _csv_table(p: Path) -> tuple[list[str], list[tuple[int, list[str]]]]:
    """Header and (line number, cells) of the non-blank rows of a CSV (a UTF-8 BOM is dropped)."""
    try:
        with p.open(newline="", encoding="utf-8-sig") as fh:
            rows = [(i + 1, row) for i, row in enumerate(csv.reader(fh)) if any(c.strip() for c in row)]
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise FrameError(f"positions file {str(p)!r} cannot be read: {exc}") from None
    if not rows:
        return [], []
    return [c.strip() for c in rows[0][1]], rows[1:]


def _csv_rows(p: Path, header: list[str], rows, needed: tuple[str, ...]) -> dict[str, tuple[int, list[str]]]:
    """``file → (line, cells)``; a row short of a ``needed`` column, without a file or listing one twice: refused."""
    last = max(header.index(k) for k in needed)
    col_file = header.index("file")
    table: dict[str, tuple[int, list[str]]] = {}
    for line, row in rows:
        if len(row) <= last:
            raise FrameError(f"{str(p)!r} line {line} has {len(row)} cell(s) but needs {last + 1} "
                             f"({', '.join(header[:last + 1])}): a short row")
        name = row[col_file].strip()
        if not name:
            raise FrameError(f"{str(p)!r} line {line}: the file cell is empty")
        if name in table:
            raise FrameError(f"positions file {str(p)!r} lists {name!r} twice (lines {table[name][0]} and "
                             f"{line}): one row per frame")
        table[name] = (line, row)
    return table


def _row_of(f: Path, table: dict, p: Path) -> str:
    """The CSV name of frame ``f``: its path as given, or its file name."""
    name = str(f) if str(f) in table else f.name
    if name not in table:
        raise FrameError(f"frame {str(f)!r} has no row in {str(p)!r}")
    return name


def _warn_unused(p: Path, table: dict, used: set) -> None:
    unused = [n for n in table if n not in used]
    if unused:
        shown = ", ".join(repr(n) for n in unused[:5]) + (f" and {len(unused) - 5} more" if len(unused) > 5 else "")
        warnings.warn(f"{str(p)!r}: {len(unused)} row(s) for files not given are left out: {shown}",
                      stacklevel=3)


def positions_from_csv(frames, csv_path: str | Path) -> list[ImportedFrame]:
    """Stage positions or angles of ``frames`` from a CSV (module docstring).

    Blank lines are skipped and a UTF-8 byte-order mark is accepted.  Rows for
    files that are not among ``frames`` are left out with a warning naming them.

    Parameters
    ----------
    frames : sequence of path
        The source frames.
    csv_path : str or Path
        CSV with a header: ``file`` and ``stage_mm`` or ``angle_deg``.

    Returns
    -------
    list of ImportedFrame
        In the order of ``frames``.

    Raises
    ------
    FrameError
        Unreadable CSV, no ``file`` or position column, a row too short for them, a file
        listed twice, a frame without a row, a non-numeric value.

    Warns
    -----
    UserWarning
        Rows for files not among ``frames`` (named).
    """
    p = Path(csv_path)
    header, rows = _csv_table(p)
    keys = [k for k in _KEYS if k in header]
    if "file" not in header or len(keys) != 1:
        raise FrameError(f"positions file {str(p)!r} needs a header with 'file' and one of "
                         f"'stage_mm' or 'angle_deg' (got {', '.join(header) or 'nothing'})")
    table, col = _csv_rows(p, header, rows, ("file", keys[0])), header.index(keys[0])
    out, used = [], set()
    for f in map(Path, frames):
        name = _row_of(f, table, p)
        used.add(name)
        line, row = table[name]
        out.append(ImportedFrame(f, keys[0], _number(row[col], f"{str(p)!r} line {line}, frame {str(f)!r}")))
    _warn_unused(p, table, used)
    return out


def positions_from_names(frames, pattern: str) -> list[ImportedFrame]:
    """Stage positions or angles of ``frames`` read from their file names (module docstring).

    Parameters
    ----------
    frames : sequence of path
        The source frames.
    pattern : str
        File-name pattern with one ``{stage_mm}`` or ``{angle_deg}`` and optional ``*``.

    Returns
    -------
    list of ImportedFrame
        In the order of ``frames``.

    Raises
    ------
    FrameError
        A pattern without one placeholder, a name that does not match, a non-numeric value.
    """
    keys = [k for k in _KEYS if "{" + k + "}" in pattern]
    if len(keys) != 1 or pattern.count("{") != 1:
        raise FrameError(f"--positions-from-names {pattern!r}: needs exactly one placeholder, "
                         "{stage_mm} or {angle_deg}")
    head, tail = pattern.split("{" + keys[0] + "}")
    glob = lambda s: ".*?".join(re.escape(x) for x in s.split("*"))  # noqa: E731
    rx = re.compile(glob(head) + "(?P<value>.*?)" + glob(tail))
    out = []
    for f in map(Path, frames):
        m = rx.fullmatch(f.name)
        if m is None:
            raise FrameError(f"frame {str(f)!r}: its name does not match the pattern {pattern!r}")
        if re.fullmatch(_NUMBER, m["value"]) is None:
            raise FrameError(f"frame {str(f)!r}: position {m['value']!r} in its name is not a number")
        out.append(ImportedFrame(f, keys[0], _number(m["value"], f"frame {str(f)!r}")))
    return out


def parse_angles(text: str, n: int) -> list[float]:
    """Rotary angles of n frames: ``START:STEP`` or a comma-separated list [deg].

    Parameters
    ----------
    text : str
        ``"START:STEP"`` (frame k at START + k·STEP) or ``"a,b,c,…"`` (one per frame).
    n : int
        Number of frames.

    Returns
    -------
    list of float
        n angles [deg].

    Raises
    ------
    FrameError
        Not numbers, a list of another length, a zero step.
    """
    step = None
    try:
        if ":" in text:
            start, step = (float(x) for x in text.split(":"))
            values = [round(start + k * step, 10) for k in range(n)]      # 1.8 · 199: no 358.20000000000005
        else:
            values = [float(x) for x in text.split(",")]
    except ValueError:
        raise FrameError(f"--angles-deg {text!r}: START:STEP or a list of numbers [deg]") from None
    if step == 0:
        raise FrameError(f"--angles-deg {text!r}: the step must not be 0")
    if len(values) != n:
        raise FrameError(f"--angles-deg lists {len(values)} angles for {n} frames")
    if not all(math.isfinite(v) for v in values):
        raise FrameError(f"--angles-deg {text!r}: angles must be finite")
    return values


def frames_with_angles(frames, angles_deg) -> list[ImportedFrame]:
    """Frames of a rotary scan with their angles, in the given order.

    Parameters
    ----------
    frames : sequence of path
        The source frames.
    angles_deg : sequence of float
        One angle per frame [deg] (:func:`parse_angles`).

    Returns
    -------
    list of ImportedFrame
        ``angle_deg`` frames.
    """
    return [ImportedFrame(Path(f), "angle_deg", float(a)) for f, a in zip(frames, angles_deg)]


def target_frames(frames, csv_path: str | Path | None = None) -> list[ImportedFrame]:
    """Frames of a pattern set (scenario ``target``): each its own flood-lit pose, or as a CSV says.

    Rows for files that are not among ``frames`` are left out with a warning naming them.

    Parameters
    ----------
    frames : sequence of path
        The source frames.
    csv_path : str or Path, optional
        CSV with ``file``, ``pose`` (an integer), ``light`` (flood, laser, both, background) and,
        for table poses, ``angle_deg``.

    Returns
    -------
    list of ImportedFrame
        Key "pose", in the given order.

    Raises
    ------
    FrameError
        A CSV without those columns, a row too short for them (naming the line), a file listed
        twice, a frame without a row, a bad pose or light.

    Warns
    -----
    UserWarning
        Rows for files not among ``frames`` (named).
    """
    frames = [Path(f) for f in frames]
    if csv_path is None:
        return [ImportedFrame(f, "pose", float(k), {"pose": k, "light": "flood"}) for k, f in enumerate(frames)]
    p = Path(csv_path)
    header, rows = _csv_table(p)
    if not {"file", "pose", "light"} <= set(header):
        raise FrameError(f"positions file {str(p)!r} for a target set needs a header with file, pose, light "
                         f"(and angle_deg for table poses); got {', '.join(header) or 'nothing'}")
    table = _csv_rows(p, header, rows, ("file", "pose", "light"))
    out, used = [], set()
    for k, f in enumerate(frames):
        name = _row_of(f, table, p)
        used.add(name)
        out.append(ImportedFrame(f, "pose", float(k), _pose_cells(p, header, *table[name])))
    _warn_unused(p, table, used)
    return out


def _pose_cells(p: Path, header: list[str], line: int, row: list[str]) -> dict:
    """A target CSV row's ``pose``, ``light`` and ``angle_deg``, checked."""
    cell = lambda key: row[header.index(key)].strip() if header.index(key) < len(row) else ""  # noqa: E731
    light, pose = cell("light"), cell("pose")
    if light not in _LIGHTS or not re.fullmatch(r"\d+", pose):
        raise FrameError(f"{str(p)!r} line {line}: pose must be an integer >= 0 and light one of "
                         f"{', '.join(_LIGHTS)} (got {pose!r}, {light!r})")
    extra = {"pose": int(pose), "light": light}
    if "angle_deg" in header and cell("angle_deg"):
        extra["angle_deg"] = _number(cell("angle_deg"), f"{str(p)!r} line {line}")
    return extra


# ------------------------------------------------------------------ loading and checking the frames


def _check_rig(rig: dict | None, shape: tuple[int, int]) -> None:
    if rig is None:
        return
    s = rig.get("sensor", {})
    if (s.get("rows"), s.get("columns")) != shape:
        raise FrameError(f"the rig's sensor is {s.get('rows')} × {s.get('columns')} (rows × columns) but the "
                         f"frames are {shape[0]} × {shape[1]}")


def _load_all(frames: list[ImportedFrame], channel: str | None = None, backgrounds: dict | None = None,
              exif: str = "stored", progress: ProgressCallback | None = None) -> tuple[list[np.ndarray], list]:
    """Every frame less its background; the sources (colour, EXIF orientation) of the frames."""
    images, sources = [], []
    for k, fr in enumerate(frames):
        src = _read(fr.path, channel, exif)
        if sources:
            _same_kind(fr.path, src, frames[0].path, sources[0])
        img = _less_background(fr.path, src, (backgrounds or {}).get(fr.path), channel, exif)
        if images:
            _same_form(fr.path, img, frames[0].path, images[0])
        images.append(img)
        sources.append(src)
        report(progress, k + 1, 2 * len(frames))
    return images, sources


def _same_kind(path: Path, src: _Source, first: Path, first_src: _Source, what: str = "frame") -> None:
    """Refuse a grey file beside a colour one (a channel of one, the luminance of the other)."""
    if src.colour != first_src.colour:
        grey, colour = (first, path) if src.colour else (path, first)
        raise FrameError(f"{what} {str(grey)!r} is grey but {str(colour)!r} is colour: a colour file gives its "
                         "--channel, a grey one its luminance, and the two do not compare; give all frames and "
                         "backgrounds in colour, or all grey")


def _less_background(path: Path, src: _Source, bg: Path | None, channel: str | None, exif: str) -> np.ndarray:
    """The frame less its laser-off background (clipped at 0), both of one kind and form."""
    if bg is None:
        return src.image
    back = _read(bg, channel, exif)
    _same_kind(bg, back, path, src, "background")
    img = src.image
    if back.image.shape != img.shape or back.image.dtype != img.dtype:
        raise FrameError(f"background {str(bg)!r} is {back.image.shape[0]} × {back.image.shape[1]} "
                         f"({back.image.dtype}), its frame {str(path)!r} {img.shape[0]} × {img.shape[1]} ({img.dtype})")
    return np.clip(img.astype(np.int64) - back.image, 0, None).astype(img.dtype)


def _same_form(path: Path, img: np.ndarray, first: Path, first_img: np.ndarray) -> None:
    if img.shape != first_img.shape:
        raise FrameError(f"frame {str(path)!r} is {img.shape[0]} × {img.shape[1]}, but {str(first)!r} is "
                         f"{first_img.shape[0]} × {first_img.shape[1]}: all frames must have one size")
    if img.dtype != first_img.dtype:
        raise FrameError(f"frame {str(path)!r} is {8 * img.itemsize}-bit, but {str(first)!r} is "
                         f"{8 * first_img.itemsize}-bit: all frames must have one bit depth")


def _pair_backgrounds(frames: list[ImportedFrame], backgrounds) -> dict:
    """Frame path → its background path (one per frame, same order), checked."""
    if backgrounds is None:
        return {}
    bgs = [Path(b) for b in backgrounds]
    if len(bgs) != len(frames):
        raise FrameError(f"{len(bgs)} background frame(s) for {len(frames)} frames: give one laser-off frame per frame")
    return {fr.path: b for fr, b in zip(frames, bgs)}


def _check_distinct(frames: list[ImportedFrame], images: list[np.ndarray], warn_equal: bool = True) -> None:
    """Refuse a file given twice or one image under two names; warn of two frames at one position."""
    seen: dict = {}
    for fr in frames:
        key = os.path.realpath(fr.path)
        if key in seen:
            raise FrameError(f"frame {str(fr.path)!r} is given twice ({str(seen[key])!r}): each frame "
                             "must be imported once (a frame counted twice shrinks the standard errors "
                             "without adding a measurement)")
        seen[key] = fr.path
    by_content: dict = {}
    for fr, img in zip(frames, images):
        digest = hashlib.sha256(img.tobytes()).hexdigest()
        if digest in by_content:
            raise FrameError(f"frames {str(by_content[digest])!r} and {str(fr.path)!r} hold the same image: "
                             "one measurement under two names; import it once")
        by_content[digest] = fr.path
    for a, b in zip(frames, frames[1:]) if warn_equal else ():
        if a.value == b.value:
            warnings.warn(f"frames {str(a.path)!r} and {str(b.path)!r} are at the same {a.key} = {a.value:g}: "
                          "repeated frames count as independent measurements", stacklevel=3)


def _adc_range(images: list[np.ndarray], frames: list[ImportedFrame], bits: int, adc_bits,
               msb_aligned: bool) -> list[np.ndarray]:
    """Check every frame against the ADC range 0 … 2**bits − 1; shift MSB-aligned data down."""
    depth = 8 * images[0].itemsize
    shift = depth - bits
    if msb_aligned:
        if adc_bits is None or shift == 0:
            raise FrameError("--msb-aligned needs --adc-bits below the files' bit depth "
                             f"({depth}): the number of bits the camera's codes have")
        for fr, img in zip(frames, images):
            if np.any(img & ((1 << shift) - 1)):
                raise FrameError(f"frame {str(fr.path)!r} has values whose lowest {shift} bits are not 0: "
                                 f"not {bits}-bit codes stored MSB-aligned in {depth} bits")
        return [img >> shift for img in images]
    top = (1 << bits) - 1
    for fr, img in zip(frames, images):
        peak = int(img.max())
        if peak > top:
            raise FrameError(f"frame {str(fr.path)!r} has values up to {peak}, above {top} = 2**{bits} − 1 "
                             f"(--adc-bits {bits}): {_adc_hint(images, bits, depth, peak)}")
    return images


def _adc_hint(images: list[np.ndarray], bits: int, depth: int, peak: int) -> str:
    """What values beyond the stated ADC range suggest."""
    shift = depth - bits
    if all(not np.any(img & ((1 << shift) - 1)) for img in images):
        return (f"every value is a multiple of {1 << shift}: the data look MSB-aligned ({bits}-bit codes "
                f"shifted left by {shift} bits); pass --msb-aligned to import them as {bits}-bit codes")
    need = int(peak).bit_length()
    return f"the frames hold at least {need}-bit data: give the camera's real ADC depth (--adc-bits {need} or more)"


def _warn_orientations(sources: list[_Source], frames: list[ImportedFrame], exif: str) -> None:
    """Name the frames whose EXIF orientation asks viewers to turn or mirror them, and what was done."""
    tagged = [(fr.path, s.orientation) for fr, s in zip(frames, sources) if s.orientation not in (None, 1)]
    if not tagged or exif == "apply":
        return
    shown = ", ".join(f"{str(p)!r} (orientation {t}: {EXIF_ORIENTATIONS[t]})" for p, t in tagged[:3])
    more = f" and {len(tagged) - 3} more" if len(tagged) > 3 else ""
    warnings.warn(f"{len(tagged)} frame(s) carry an EXIF orientation tag telling viewers to turn or mirror them: "
                  f"{shown}{more}; imported as stored (not turned), as a calibration of the stored frames "
                  "expects; --exif-orientation apply turns them as viewers do", stacklevel=3)


def _warn_radians(frames: list[ImportedFrame]) -> None:
    """Rotary angles spanning one turn in radians look like radians (:func:`radians_note`)."""
    note = radians_note([f.value for f in frames]) if frames[0].key == "angle_deg" else None
    if note:
        warnings.warn(note, stacklevel=3)


# ------------------------------------------------------------------ which way the stripe runs


def stripe_direction(image: np.ndarray) -> str | None:
    """Which way the brightest narrow ridge of a frame runs: down the image, across it, or neither.

    A laser stripe that runs down the image has, in most rows, one narrow peak
    well above the row's median, and the peaks of neighbouring rows lie side by
    side; one that runs across it has that in most columns.  Each direction's
    count of such lines (in runs of consecutive lines, so that texture and edges
    do not count) is the number of stripe points its extraction would get; the
    direction wins that covers a quarter of its lines and gives twice the other's
    points (the values of ``_StripeRule``, measured on real stripes — FabScan,
    3DScanScience — and on chessboards and textured views without a laser).

    Parameters
    ----------
    image : (rows, columns) ndarray
        One grey frame (laser-off background removed where there is one) [DN].

    Returns
    -------
    {"columns", "rows"} or None
        ``"columns"``: the stripe runs down the image (one point per row); ``"rows"``: across it
        (one point per column); None: no clear stripe (none, or as much of it either way).
    """
    img = np.asarray(image)
    if img.ndim != 2 or min(img.shape) < 2 * _RULE.min_run:
        return None
    level = _ridge_level(img)
    down, across = _ridge_points(img, level), _ridge_points(img.T, level)
    if down >= _RULE.min_cover * img.shape[0] and down >= _RULE.ratio * across:
        return "columns"
    if across >= _RULE.min_cover * img.shape[1] and across >= _RULE.ratio * down:
        return "rows"
    return None


def _ridge_level(img: np.ndarray) -> float:
    """The height above its line's median a stripe's peak must have [DN] (noise and stripe level)."""
    back = float(np.median(img[::4, ::4]))
    sigma = 1.4826 * float(np.median(np.abs(np.diff(img[::4].astype(np.float32), axis=1)))) / math.sqrt(2)
    top = max(np.percentile(img.max(axis=1), 90), np.percentile(img.max(axis=0), 90)) - back
    return max(_RULE.noise_factor * sigma, _RULE.top_share * float(top), 1.0)


def _ridge_points(lines: np.ndarray, level: float) -> int:
    """Lines (rows of ``lines``) whose one narrow peak of height ``level`` continues a long run of such lines."""
    med = np.median(lines[:, ::4], axis=1)
    height = lines.max(axis=1) - med
    width = np.count_nonzero(lines > (med + height / 2)[:, None], axis=1)
    good = (height >= level) & (width <= max(_RULE.min_width_px, _RULE.width_share * lines.shape[1]))
    link = good[:-1] & good[1:] & (np.abs(np.diff(lines.argmax(axis=1))) <= _RULE.jump_px)
    edges = np.flatnonzero(np.diff(np.concatenate(([0], link.astype(np.int8), [0]))))
    run = edges[1::2] - edges[::2] + 1
    return int(run[run >= _RULE.min_run].sum())


def _stripe_votes(frames: list[ImportedFrame], images: list[np.ndarray],
                  partners: dict[int, int]) -> tuple[dict[str, list[Path]], int]:
    """Frames whose stripe runs each way, and how many frames were examined (those that show the laser)."""
    votes: dict[str, list[Path]] = {"columns": [], "rows": []}
    examined = 0
    for i, (fr, img) in enumerate(zip(frames, images)):
        if fr.key == "pose" and (fr.extra or {}).get("light") not in _LASER_LIGHTS:
            continue
        if i in partners:                       # room light: the line is the difference
            img = np.clip(img.astype(np.int64) - images[partners[i]], 0, None)
        way = stripe_direction(img)
        examined += 1
        if way is not None:
            votes[way].append(fr.path)
    return votes, examined


def _names(paths: list[Path], k: int = 3) -> str:
    return ", ".join(repr(p.name) for p in paths[:k]) + (f" and {len(paths) - k} more" if len(paths) > k else "")


def _decide_stripe(given: str, votes: dict[str, list[Path]], examined: int) -> tuple[str, dict]:
    """The stripe direction to record and the manifest's ``stripe_detection``; refuse or warn of contradictions."""
    n = {k: len(v) for k, v in votes.items()}
    found = None if n["columns"] == n["rows"] else max(STRIPE_ALONG, key=n.get)
    record = {"given": given, "found": found, "examined": examined, "columns": n["columns"], "rows": n["rows"],
              "unclear": examined - n["columns"] - n["rows"]}
    if given == "auto":
        return _auto_stripe(votes, examined, found), record
    _check_given_stripe(given, votes, examined)
    return given, record


def _auto_stripe(votes: dict[str, list[Path]], examined: int, found: str | None) -> str:
    n = {k: len(v) for k, v in votes.items()}
    if n["columns"] + n["rows"] == 0:
        if examined:
            warnings.warn(f"no laser stripe found in the {examined} frame(s) that show the laser (a narrow bright "
                          "line in most rows or most columns): stripe_along = columns assumed (down the image); "
                          "give --stripe-along rows if the line runs across the image", stacklevel=3)
        return "columns"
    other = "rows" if found == "columns" else "columns"
    if found is None or n[other] > _RULE.disagree_share * (n["columns"] + n["rows"]):
        raise FrameError(f"the frames disagree on the stripe's direction: it runs {_WAY['columns']} in "
                         f"{n['columns']} frame(s) ({_names(votes['columns'])}) and {_WAY['rows']} in {n['rows']} "
                         f"({_names(votes['rows'])}): give --stripe-along columns or rows (and check the frames)")
    if n[other]:
        warnings.warn(f"{n[other]} of {examined} frames look as if the stripe ran {_WAY[other]} "
                      f"({_names(votes[other])}); stripe_along = {found}, found in {n[found]}", stacklevel=3)
    return found


def _known_stripe(given: str) -> tuple[str, dict]:
    """A known direction and its ``stripe_detection``: nothing examined, nothing refused."""
    return given, {"given": given, "known": True, "found": None, "examined": 0, "columns": 0, "rows": 0,
                   "unclear": 0}


def _check_given_stripe(given: str, votes: dict[str, list[Path]], examined: int) -> None:
    other = "rows" if given == "columns" else "columns"
    mine, theirs = len(votes[given]), len(votes[other])
    if theirs <= mine:
        return
    msg = (f"--stripe-along {given}, but the stripe runs {_WAY[other]} in {theirs} of the {examined} frame(s) "
           f"that show the laser ({_names(votes[other])}) and {_WAY[given]} in {mine}")
    if theirs >= max(1.0, examined / 2) and theirs >= 4 * mine:
        raise FrameError(msg + ": the pipeline would measure across the stripe; leave --stripe-along out (import "
                               f"finds the direction) or give --stripe-along {other}")
    warnings.warn(msg + "; kept as given: check the frames", stacklevel=3)


# ------------------------------------------------------------------ pattern sets in room light


def _laser_off_partners(frames: list[ImportedFrame], room_light: bool) -> dict[int, int]:
    """Each room-light laser frame's index → its pose's one laser-off (flood) frame; warns of laser frames without."""
    if not room_light:
        return {}
    flood: dict[int, list[int]] = {}
    for i, fr in enumerate(frames):
        if fr.extra["light"] == "flood":
            flood.setdefault(fr.extra["pose"], []).append(i)
    lasers = [i for i, fr in enumerate(frames) if fr.extra["light"] == "laser"]
    pairs = {i: flood[frames[i].extra["pose"]][0] for i in lasers if len(flood.get(frames[i].extra["pose"], [])) == 1}
    alone = [frames[i] for i in lasers if not flood.get(frames[i].extra["pose"])]
    several = [frames[i] for i in lasers if len(flood.get(frames[i].extra["pose"], [])) > 1]
    if not lasers:
        warnings.warn("--room-light: the set has no laser frames (light 'laser' in a --positions CSV): nothing "
                      "to pair", stacklevel=3)
    if alone:
        warnings.warn(f"room light: {len(alone)} laser frame(s) without a laser-off (flood) frame of their pose "
                      f"({_pose_names(alone)}): in room light their line cannot be told from the light; take one "
                      "laser-off frame per pose", stacklevel=3)
    if several:
        warnings.warn(f"room light: {len(several)} laser frame(s) whose pose has several laser-off frames "
                      f"({_pose_names(several)}): not paired; give one laser-off frame per pose", stacklevel=3)
    return pairs


def _pose_names(frames: list[ImportedFrame]) -> str:
    shown = ", ".join(f"{f.path.name!r} (pose {f.extra['pose']})" for f in frames[:3])
    return shown + (f" and {len(frames) - 3} more" if len(frames) > 3 else "")


# ------------------------------------------------------------------ the import


def import_frames(frames: list[ImportedFrame], out: str | Path, *, rig: dict | None = None,
                  adc_bits: int | None = None, scenario: str | None = None,
                  scenario_params: dict | None = None, msb_aligned: bool = False, channel: str | None = None,
                  backgrounds=None, stripe_along: str = "auto", stripe_known: bool = False,
                  exif_orientation: str = "stored", room_light: bool = False,
                  progress: ProgressCallback | None = None) -> Path:
    """Write a frame folder (manifest + PNG frames) from source frames with positions.

    Parameters
    ----------
    frames : list of ImportedFrame
        Sources and positions (all ``stage_mm``, all ``angle_deg`` or all ``pose``).
    out : str or Path
        The frame folder to create (must not exist, or be empty).
    rig : dict, optional
        Rig tables (``rig_to_dict``) written to the manifest; its sensor size must match.
    adc_bits : int, optional
        ADC depth (saturation at 2**bits − 1); default the files' bit depth (8 or 16).
        Every value must lie within 0 … 2**bits − 1.
    scenario : str, optional
        Scenario name; default "calibration" for stage positions, "rotary" for angles, "target" for poses.
    scenario_params : dict, optional
        E.g. ``{"plate_height_mm": 89}``: numbers must be finite (a plate height > 0).
    msb_aligned : bool, default False
        The files hold ``adc_bits`` codes shifted left to the top of the word (a 12-bit
        camera's 16-bit files with values × 16): they are shifted back (the lowest bits
        must be 0).
    channel : str, optional
        How a colour file becomes one frame (:func:`read_image`).
    backgrounds : sequence of path, optional
        One laser-off frame per frame, in the order of ``frames`` (subtracted).
    stripe_along : {"auto", "columns", "rows"}, default "auto"
        Which way the stripe runs in the frames; "auto" finds it (:func:`stripe_direction`).
        Recorded (module docstring).
    stripe_known : bool, default False
        ``stripe_along`` (``"columns"`` or ``"rows"``) is known, not to be checked: the frames
        are not examined for it and it is never refused or warned of (module docstring).
    exif_orientation : {"stored", "apply"}, default "stored"
        Frames with an EXIF orientation tag imported as stored (with a warning) or turned as
        viewers turn them.
    room_light : bool, default False
        A pattern set taken in room light: each laser frame's laser-off partner is its pose's
        flood frame (recorded: ``room_light``, ``laser_off_file``).
    progress : ProgressCallback, optional
        ``progress(done, total)`` after each frame read and each frame written.

    Returns
    -------
    Path
        The folder.

    Raises
    ------
    FrameError
        No frames, mixed keys, bad frames (:func:`read_image`), mixed colour and grey, a file
        given twice or one image under two names, values beyond the ADC range (naming the file,
        the largest value and what it suggests), a rig of another size, a stripe direction the
        frames contradict or frames that disagree on it, a non-finite scenario parameter, an
        output that is a file, not empty, not creatable (or filled meanwhile by another import),
        a bad ``adc_bits``, ``stripe_along``, ``exif_orientation``, ``room_light`` without poses or
        ``stripe_known`` without a direction.

    Warns
    -----
    UserWarning
        Two frames at the same position; angles that look like radians; EXIF orientation tags;
        ``channel`` for grey frames; no stripe found or a weak contradiction of ``stripe_along``;
        room-light laser frames without a laser-off frame; temporary folders of earlier imports
        into ``out`` (removed when their import is gone, named when no owner is recorded).
    """
    _check_request(frames, stripe_along, exif_orientation, channel, room_light)
    if stripe_known and stripe_along not in STRIPE_ALONG:
        raise FrameError(f"--stripe-known needs the direction: --stripe-along {' or '.join(STRIPE_ALONG)}, not "
                         f"{stripe_along!r}")
    params, out = _checked_params(scenario_params), Path(out)
    if room_light:
        params = {**params, "room_light": True}
    _check_out(out)
    bgs = _pair_backgrounds(frames, backgrounds)
    frames = sorted(frames, key=lambda f: f.value)        # stable: equal positions keep their order
    images, sources = _load_all(frames, channel, bgs, exif_orientation, progress)
    _check_distinct(frames, images, warn_equal=frames[0].key != "pose")
    _check_rig(rig, images[0].shape)
    bits = _bits(images, adc_bits)
    images = _adc_range(images, frames, bits, adc_bits, msb_aligned)
    _warn_radians(frames)
    _warn_orientations(sources, frames, exif_orientation)
    partners = _laser_off_partners(frames, room_light)
    along, detection = (_known_stripe(stripe_along) if stripe_known
                        else _decide_stripe(stripe_along, *_stripe_votes(frames, images, partners)))
    default = {"stage_mm": "calibration", "angle_deg": "rotary", "pose": "target"}[frames[0].key]
    manifest = {"format": FORMAT, "complete": True, "scenario": scenario or default, "scenario_params": params,
                "adc_bits": bits, "stripe_along": along, "stripe_detection": detection, "source": "scheimpflug import",
                **_import_keys(channel, sources, exif_orientation, room_light, rig),
                "frames": _entries(frames, bgs, sources, partners)}
    _write(out, manifest, images, progress)
    return out


def _check_request(frames: list[ImportedFrame], stripe_along: str, exif: str, channel: str | None,
                   room_light: bool) -> None:
    """The options, before any file is read."""
    if not frames:
        raise FrameError("no frames to import")
    if len({f.key for f in frames}) != 1:
        raise FrameError("frames mix stage positions and angles")
    if stripe_along not in _STRIPE_CHOICES:
        raise FrameError(f"--stripe-along {stripe_along!r}: one of {', '.join(_STRIPE_CHOICES)}")
    if exif not in _EXIF_CHOICES:
        raise FrameError(f"--exif-orientation {exif!r}: one of {', '.join(_EXIF_CHOICES)}")
    if channel is not None:
        _weights(channel)                     # a bad --channel is refused even where every file is grey
    if room_light and frames[0].key != "pose":
        raise FrameError("--room-light marks a pattern set's frames (--scenario target): each pose's laser frame "
                         "and its laser-off frame")


def _checked_params(params: dict | None) -> dict:
    """Scenario parameters whose numbers are finite (a plate height > 0): JSON has no NaN."""
    out = dict(params or {})
    for key, value in out.items():
        if isinstance(value, bool) or not isinstance(value, (int, float, np.number)):
            continue
        positive = key == "plate_height_mm"
        if not math.isfinite(float(value)) or (positive and float(value) <= 0):
            raise FrameError(f"{key} = {float(value):g}: must be a finite number{' > 0' if positive else ''}")
        out[key] = float(value) if isinstance(value, (float, np.floating)) else int(value)
    return out


def _bits(images: list[np.ndarray], adc_bits) -> int:
    depth = 8 * images[0].itemsize
    bits = depth if adc_bits is None else int(adc_bits)
    if not 1 <= bits <= depth:
        raise FrameError(f"adc_bits = {adc_bits}: must be in 1..{depth} for {depth}-bit frames")
    return bits


def _import_keys(channel: str | None, sources: list[_Source], exif: str, room_light: bool, rig: dict | None) -> dict:
    """The manifest's record of how the files were read: channel, EXIF orientation, rig.

    Room light is a scenario parameter (``scenario_params.room_light``, as ``render target
    --room-light`` writes it).
    """
    keys: dict = {}
    if channel is not None and sources[0].colour:
        keys["channel"] = channel
    elif channel is not None:
        warnings.warn(f"--channel {channel} has no effect: every frame is grey (not recorded)", stacklevel=3)
    if any(s.orientation not in (None, 1) for s in sources):
        keys["exif_orientation"] = "applied" if exif == "apply" else "stored"
    if rig is not None:
        keys["rig"] = rig
    return keys


def _entries(frames: list[ImportedFrame], bgs: dict, sources: list[_Source], partners: dict[int, int]) -> list[dict]:
    """The manifest's frame entries, ``frames/NNNNN.png`` in the sorted order."""
    entries = []
    for i, (fr, src) in enumerate(zip(frames, sources)):
        entry = {"file": f"frames/{i:05d}.png"} if fr.key == "pose" else {"file": f"frames/{i:05d}.png",
                                                                           fr.key: fr.value}
        entry.update(fr.extra or {})
        entry["source_file"] = str(fr.path)
        if bgs.get(fr.path) is not None:
            entry["background_file"] = str(bgs[fr.path])
        if src.orientation not in (None, 1):
            entry["exif_orientation"] = src.orientation
        if i in partners:
            entry["laser_off_file"] = f"frames/{partners[i]:05d}.png"
        entries.append(entry)
    return entries


# ------------------------------------------------------------------ writing: a temporary folder, renamed


def _check_out(out: Path) -> None:
    """Refuse an output that is a file, a folder that is not empty, or a place where no folder can be made."""
    if out.exists() and not out.is_dir():
        raise FrameError(f"output {str(out)!r} is a file, not a folder: give a new or empty folder")
    if out.is_dir() and any(out.iterdir()):
        raise FrameError(f"output folder {str(out)!r} exists and is not empty")
    probe, reason = unwritable_reason(out)
    if reason is not None:
        raise FrameError(f"output folder {str(out)!r} cannot be created: {str(probe)!r} {reason}")


def _write(out: Path, manifest: dict, images: list[np.ndarray], progress: ProgressCallback | None) -> None:
    """Frames and manifest into a locked temporary folder beside ``out``, renamed to ``out`` when complete."""
    tmp = _make_temporary(out)
    lock = FolderLock(tmp, error=FrameError)
    try:
        lock.acquire()
        (tmp / "frames").mkdir()
        os.chmod(tmp, (tmp / "frames").stat().st_mode & 0o7777)      # the umask's mode, not mkdtemp's 0700
        for i, img in enumerate(images):
            name = f"frames/{i:05d}.png"
            if not cv2.imwrite(str(tmp / name), img):
                raise FrameError(f"cannot write {str(out / name)!r}")
            report(progress, len(images) + i + 1, 2 * len(images))
        (tmp / "manifest.json").write_text(json.dumps(manifest, indent=1, allow_nan=False), "utf-8")
        _move_into_place(tmp, out)                # the lock moves with it: a temporary never lacks its owner
        (out / LOCK_NAME).unlink(missing_ok=True)
        lock.release()
    except BaseException:
        lock.release()
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def _make_temporary(out: Path) -> Path:
    """A new temporary folder ``.NAME.xxxxxxxx`` beside ``out``, after removing those of dead imports."""
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        _sweep_stale(out)
        return Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    except OSError as exc:
        raise FrameError(f"output folder {str(out)!r} cannot be created: {exc.strerror or exc}") from None


def _sweep_stale(out: Path) -> None:
    """Remove the temporary folders of imports into ``out`` that were killed; name those without an owner."""
    prefix = f".{out.name}."
    for cand in sorted(out.parent.iterdir()):
        tail = cand.name[len(prefix):] if cand.name.startswith(prefix) else ""
        if re.fullmatch(r"[a-z0-9_]{8}", tail) and cand.is_dir() and not cand.is_symlink():
            _remove_if_stale(cand, out)


def _remove_if_stale(cand: Path, out: Path) -> None:
    if not (cand / LOCK_NAME).is_file():
        warnings.warn(f"{str(cand)!r} looks like the temporary folder of an import into {str(out)!r} that was "
                      "stopped, but records no owner: left alone; remove it if no import is running", stacklevel=5)
        return
    lock = FolderLock(cand, error=FrameError)
    try:
        lock.acquire()
    except (FrameError, OSError):
        return                                  # its import is running (or it cannot be locked): leave it
    try:
        owner = lock.stale_owner
        if owner is not None:
            shutil.rmtree(cand, ignore_errors=True)
    finally:
        lock.release()
    if owner is not None:
        warnings.warn(f"removed {str(cand)!r}, the temporary folder an import into {str(out)!r} left when it was "
                      f"stopped (pid {owner.get('pid')}, started {owner.get('started')})", stacklevel=5)


def _move_into_place(tmp: Path, out: Path) -> None:
    """Rename the finished folder to ``out``; one clear error if another import filled it meanwhile."""
    try:
        if out.exists():
            out.rmdir()
        os.replace(tmp, out)
    except OSError as exc:
        if exc.errno in (errno.ENOTEMPTY, errno.EEXIST, errno.ENOTDIR):
            raise FrameError(f"output folder {str(out)!r} was filled while this import ran: another import "
                             "into the same folder? import into an empty folder, one at a time") from None
        raise
