"""Real frames without a manifest: PNG or TIFF files + stage positions → a frame folder.

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
    size and bit depth.  They are copied losslessly to 16-bit (or 8-bit) PNG,
    ordered by position.
Backgrounds
    laser-off frames of the same views (``backgrounds``, one per frame, in the
    frames' order): subtracted on import (clipped at 0), so that ambient light
    and lit surroundings leave the stripe alone; the manifest names each
    frame's background.
Frames without positions
    a pattern set (``scenario="target"``, :func:`target_frames`): each frame a
    pose (``pose``, ``light``: flood), or from a CSV with ``file``, ``pose``,
    ``light`` (and ``angle_deg`` for table poses); a scan with rotary angles
    given as ``START:STEP`` or a list (:func:`frames_with_angles`).
Stripe orientation
    ``stripe_along`` ``"columns"`` (the stripe runs down the image: one point
    per row, the Scheimpflug profiler's) or ``"rows"`` (across it: one point per
    column, e.g. FabScan's frames); recorded in the manifest, where the
    pipeline's extraction follows it.
Positions
    a CSV with a header naming ``file`` and ``stage_mm`` (translation stage,
    calibration plates) or ``angle_deg`` (rotary stage); ``file`` is matched
    against each frame's path as given or its file name; or a file-name
    pattern with one placeholder ``{stage_mm}`` or ``{angle_deg}`` and ``*``
    wildcards, e.g. ``plate_{stage_mm}mm.tif`` or ``scan_*_{angle_deg}.png``
    (matched against the file name; ``p`` stands for a decimal point, so
    ``plate_12p5mm`` reads 12.5).
Rig
    optional: the calibration needs none; given, it goes into the manifest
    and its sensor size must match the frames.

Bad input — a frame without a position, a non-numeric position, a file
given twice (or listed twice in the CSV), one image under two names, values
above the stated ADC range (``adc_bits``; MSB-aligned data are named as such:
``msb_aligned`` shifts them back), mixed sizes or bit depths, a colour or
unreadable file — raises one :class:`FrameError` naming the file; nothing is
written unless every frame is good (the folder is built under a temporary
name and renamed; another import filling the same folder meanwhile is named).
Warnings: CSV rows for files not given, two frames at one position, rotary
angles that span one turn in radians.
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
import tempfile
import warnings
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from scheimpflug.errors import FrameError
from scheimpflug.io.frames import STRIPE_ALONG, radians_note

__all__ = ["CHANNELS", "ImportedFrame", "frames_with_angles", "import_frames", "parse_angles", "positions_from_csv",
           "positions_from_names", "read_image", "target_frames"]

FORMAT = "scheimpflug-frames/1"
_KEYS = ("stage_mm", "angle_deg")
#: Colour channels a colour frame can be read as (``read_image``), besides a weighting "wr,wg,wb".
CHANNELS = ("r", "g", "b", "gray")
_LIGHTS = ("flood", "laser", "both", "background")
_NUMBER = r"[-+]?(?:\d+(?:[.p]\d*)?|[.p]\d+)(?:[eE][-+]?\d+)?"


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


def read_image(path: str | Path, channel: str | None = None) -> np.ndarray:
    """Read an 8- or 16-bit PNG, TIFF or JPEG as one grey frame (module docstring).

    Parameters
    ----------
    path : str or Path
        The file.
    channel : str, optional
        For a colour file: "r", "g", "b", "gray" or "wr,wg,wb" (weights of red, green, blue).

    Returns
    -------
    (rows, columns) uint8 or uint16
        The frame [DN].

    Raises
    ------
    FrameError
        Missing, unreadable, colour without ``channel`` or of another depth, naming the file;
        a bad ``channel``.
    """
    p = Path(path)
    if not p.is_file():
        raise FrameError(f"frame {str(p)!r} does not exist")
    img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    if img is None and p.suffix.lower() in (".tif", ".tiff"):
        img = _read_tifffile(p)
    if img is None:
        raise FrameError(f"frame {str(p)!r} is unreadable or corrupt (not a PNG, TIFF or JPEG OpenCV can decode)")
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.dtype not in (np.uint8, np.uint16):
        raise FrameError(f"frame {str(p)!r} has dtype {img.dtype}: frames must be 8- or 16-bit integers")
    if img.ndim == 3:
        if channel is None:
            raise FrameError(f"frame {str(p)!r} has {img.shape[2]} channels (colour): give --channel r|g|b|gray "
                             "or a weighting wr,wg,wb (a red laser: r)")
        img = _one_channel(img, channel, p)
    elif img.ndim != 2:
        raise FrameError(f"frame {str(p)!r} has shape {img.shape}: not an image")
    return img


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


def _csv_positions(p: Path, header: list[str], rows) -> tuple[str, dict[str, tuple[int, str]]]:
    """The position key and ``file → (line, text)``; a file listed twice is refused."""
    keys = [k for k in _KEYS if k in header]
    if "file" not in header or len(keys) != 1:
        raise FrameError(f"positions file {str(p)!r} needs a header with 'file' and one of "
                         f"'stage_mm' or 'angle_deg' (got {', '.join(header) or 'nothing'})")
    col_file, col_pos = header.index("file"), header.index(keys[0])
    table: dict[str, tuple[int, str]] = {}
    for line, row in rows:
        name = row[col_file].strip() if col_file < len(row) else ""
        text = row[col_pos] if col_pos < len(row) else ""
        if name in table:
            raise FrameError(f"positions file {str(p)!r} lists {name!r} twice (lines {table[name][0]} and "
                             f"{line}): one row per frame")
        table[name] = (line, text)
    return keys[0], table


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
        Unreadable CSV, no ``file`` or position column, a file listed twice, a frame
        without a row, a non-numeric value.

    Warns
    -----
    UserWarning
        Rows for files not among ``frames`` (named).
    """
    p = Path(csv_path)
    key, table = _csv_positions(p, *_csv_table(p))
    out, used = [], set()
    for f in map(Path, frames):
        name = str(f) if str(f) in table else f.name
        if name not in table:
            raise FrameError(f"frame {str(f)!r} has no row in {str(p)!r}")
        used.add(name)
        out.append(ImportedFrame(f, key, _number(table[name][1], f"{str(p)!r}, frame {str(f)!r}")))
    unused = [n for n in table if n not in used]
    if unused:
        shown = ", ".join(repr(n) for n in unused[:5]) + (f" and {len(unused) - 5} more" if len(unused) > 5 else "")
        warnings.warn(f"{str(p)!r}: {len(unused)} row(s) for files not given are left out: {shown}",
                      stacklevel=2)
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
        A CSV without those columns, a frame without a row, a bad pose or light.
    """
    frames = [Path(f) for f in frames]
    if csv_path is None:
        return [ImportedFrame(f, "pose", float(k), {"pose": k, "light": "flood"}) for k, f in enumerate(frames)]
    p = Path(csv_path)
    header, rows = _csv_table(p)
    if not {"file", "pose", "light"} <= set(header):
        raise FrameError(f"positions file {str(p)!r} for a target set needs a header with file, pose, light "
                         f"(and angle_deg for table poses); got {', '.join(header) or 'nothing'}")
    table = {r[header.index("file")].strip(): (line, r) for line, r in rows}
    out = []
    for k, f in enumerate(frames):
        name = str(f) if str(f) in table else f.name
        if name not in table:
            raise FrameError(f"frame {str(f)!r} has no row in {str(p)!r}")
        line, row = table[name]
        cell = lambda key, row=row: row[header.index(key)].strip() if header.index(key) < len(row) else ""  # noqa: E731
        light = cell("light")
        if light not in _LIGHTS or not re.fullmatch(r"\d+", cell("pose")):
            raise FrameError(f"{str(p)!r} line {line}: pose must be an integer >= 0 and light one of "
                             f"{', '.join(_LIGHTS)} (got {cell('pose')!r}, {light!r})")
        extra = {"pose": int(cell("pose")), "light": light}
        if "angle_deg" in header and cell("angle_deg"):
            extra["angle_deg"] = _number(cell("angle_deg"), f"{str(p)!r} line {line}")
        out.append(ImportedFrame(f, "pose", float(k), extra))
    return out


def _check_rig(rig: dict | None, shape: tuple[int, int]) -> None:
    if rig is None:
        return
    s = rig.get("sensor", {})
    if (s.get("rows"), s.get("columns")) != shape:
        raise FrameError(f"the rig's sensor is {s.get('rows')} × {s.get('columns')} (rows × columns) but the "
                         f"frames are {shape[0]} × {shape[1]}")


def _load_all(frames: list[ImportedFrame], channel: str | None = None,
              backgrounds: dict | None = None) -> list[np.ndarray]:
    images, first = [], None
    for fr in frames:
        img = read_image(fr.path, channel)
        bg = (backgrounds or {}).get(fr.path)
        if bg is not None:
            back = read_image(bg, channel)
            if back.shape != img.shape or back.dtype != img.dtype:
                raise FrameError(f"background {str(bg)!r} is {back.shape[0]} × {back.shape[1]} ({back.dtype}), its "
                                 f"frame {str(fr.path)!r} {img.shape[0]} × {img.shape[1]} ({img.dtype})")
            img = np.clip(img.astype(np.int64) - back, 0, None).astype(img.dtype)
        if first is None:
            first = (img.shape, img.dtype, fr.path)
        elif img.shape != first[0]:
            raise FrameError(f"frame {str(fr.path)!r} is {img.shape[0]} × {img.shape[1]}, but "
                             f"{str(first[2])!r} is {first[0][0]} × {first[0][1]}: all frames must have one size")
        elif img.dtype != first[1]:
            raise FrameError(f"frame {str(fr.path)!r} is {8 * img.itemsize}-bit, but {str(first[2])!r} is "
                             f"{8 * first[1].itemsize}-bit: all frames must have one bit depth")
        images.append(img)
    return images


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


def import_frames(frames: list[ImportedFrame], out: str | Path, *, rig: dict | None = None,
                  adc_bits: int | None = None, scenario: str | None = None,
                  scenario_params: dict | None = None, msb_aligned: bool = False, channel: str | None = None,
                  backgrounds=None, stripe_along: str = "columns") -> Path:
    """Write a frame folder (manifest + PNG frames) from source frames with positions.

    Parameters
    ----------
    frames : list of ImportedFrame
        Sources and positions (all ``stage_mm`` or all ``angle_deg``).
    out : str or Path
        The frame folder to create (must not exist, or be empty).
    rig : dict, optional
        Rig tables (``rig_to_dict``) written to the manifest; its sensor size must match.
    adc_bits : int, optional
        ADC depth (saturation at 2**bits − 1); default the files' bit depth (8 or 16).
        Every value must lie within 0 … 2**bits − 1.
    scenario : str, optional
        Scenario name; default "calibration" for stage positions, "rotary" for angles.
    scenario_params : dict, optional
        E.g. ``{"plate_height_mm": 89}``.
    msb_aligned : bool, default False
        The files hold ``adc_bits`` codes shifted left to the top of the word (a 12-bit
        camera's 16-bit files with values × 16): they are shifted back (the lowest bits
        must be 0).
    channel : str, optional
        How a colour file becomes one frame (:func:`read_image`).
    backgrounds : sequence of path, optional
        One laser-off frame per frame, in the order of ``frames`` (subtracted).
    stripe_along : {"columns", "rows"}, default "columns"
        Which way the stripe runs in the frames (recorded; module docstring).

    Returns
    -------
    Path
        The folder.

    Raises
    ------
    FrameError
        No frames, mixed keys, bad frames (:func:`read_image`), a file given twice or one
        image under two names, values beyond the ADC range (naming the file, the largest
        value and what it suggests), a rig of another size, an out folder that is not empty
        (or filled meanwhile by another import), a bad ``adc_bits``.

    Warns
    -----
    UserWarning
        Two frames at the same position; angles that look like radians.
    """
    if not frames:
        raise FrameError("no frames to import")
    if len({f.key for f in frames}) != 1:
        raise FrameError("frames mix stage positions and angles")
    if stripe_along not in STRIPE_ALONG:
        raise FrameError(f"--stripe-along {stripe_along!r}: one of {', '.join(STRIPE_ALONG)}")
    if channel is not None:
        _weights(channel)                     # a bad --channel is refused even where every file is grey
    bgs = _pair_backgrounds(frames, backgrounds)
    frames = sorted(frames, key=lambda f: f.value)        # stable: equal positions keep their order
    images = _load_all(frames, channel, bgs)
    _check_distinct(frames, images, warn_equal=frames[0].key != "pose")
    _check_rig(rig, images[0].shape)
    depth = 8 * images[0].itemsize
    bits = depth if adc_bits is None else int(adc_bits)
    if not 1 <= bits <= depth:
        raise FrameError(f"adc_bits = {adc_bits}: must be in 1..{depth} for {depth}-bit frames")
    images = _adc_range(images, frames, bits, adc_bits, msb_aligned)
    _warn_radians(frames)
    out = Path(out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise FrameError(f"output folder {str(out)!r} exists and is not empty")
    default = {"stage_mm": "calibration", "angle_deg": "rotary", "pose": "target"}[frames[0].key]
    manifest = {"format": FORMAT, "complete": True, "scenario": scenario or default,
                "scenario_params": scenario_params or {}, "adc_bits": bits, "stripe_along": stripe_along,
                "source": "scheimpflug import", "frames": []}
    if channel is not None:
        manifest["channel"] = channel
    if rig is not None:
        manifest["rig"] = rig
    _write(out, manifest, frames, images, bgs)
    return out


def _warn_radians(frames: list[ImportedFrame]) -> None:
    """Rotary angles spanning one turn in radians look like radians (:func:`radians_note`)."""
    note = radians_note([f.value for f in frames]) if frames[0].key == "angle_deg" else None
    if note:
        warnings.warn(note, stacklevel=3)


def _write(out: Path, manifest: dict, frames: list[ImportedFrame], images: list[np.ndarray],
           bgs: dict) -> None:
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        (tmp / "frames").mkdir()
        for i, (fr, img) in enumerate(zip(frames, images)):
            name = f"frames/{i:05d}.png"
            if not cv2.imwrite(str(tmp / name), img):
                raise FrameError(f"cannot write {str(out / name)!r}")
            entry = {"file": name} if fr.key == "pose" else {"file": name, fr.key: fr.value}
            entry.update(fr.extra or {})
            entry["source_file"] = str(fr.path)
            if bgs.get(fr.path) is not None:
                entry["background_file"] = str(bgs[fr.path])
            manifest["frames"].append(entry)
        (tmp / "manifest.json").write_text(json.dumps(manifest, indent=1), "utf-8")
        _move_into_place(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


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
