"""Real frames without a manifest: PNG or TIFF files + stage positions → a frame folder.

``scheimpflug import FRAMES... (--positions CSV | --positions-from-names PATTERN) --out DIR``
builds the frame folder of docs/reference/interface.md (``manifest.json`` + ``frames/NNNNN.png``)
from a camera's files, so that ``calibrate``, ``axis`` and ``reconstruct`` read
real frames the same way as the twin's.

Frames
    PNG or TIFF, grayscale, 8 or 16 bit (a 12-bit camera's frames are 16-bit
    files; give ``adc_bits = 12`` so that saturation is found at 4095), read
    with OpenCV (``tifffile``, when installed, is tried for TIFFs OpenCV cannot
    decode).  Every frame must have the first frame's size and bit depth.  They
    are copied losslessly to 16-bit (or 8-bit) PNG, ordered by position.
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

Bad input — a frame without a position, a non-numeric position, mixed sizes
or bit depths, a colour or unreadable file — raises one :class:`FrameError`
naming the file; nothing is written unless every frame is good (the folder is
built under a temporary name and renamed).
"""

from __future__ import annotations

import csv
import json
import math
import os
import re
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from scheimpflug.errors import FrameError

__all__ = ["ImportedFrame", "import_frames", "positions_from_csv", "positions_from_names", "read_image"]

FORMAT = "scheimpflug-frames/1"
_KEYS = ("stage_mm", "angle_deg")
_NUMBER = r"[-+]?(?:\d+(?:[.p]\d*)?|[.p]\d+)(?:[eE][-+]?\d+)?"


@dataclass(frozen=True)
class ImportedFrame:
    """One source frame and its stage reading.

    Parameters
    ----------
    path : Path
        The source file.
    key : str
        "stage_mm" or "angle_deg".
    value : float
        The position [mm] or angle [deg].
    """

    path: Path
    key: str
    value: float


def read_image(path: str | Path) -> np.ndarray:
    """Read a grayscale 8- or 16-bit PNG or TIFF unchanged.

    Parameters
    ----------
    path : str or Path
        The file.

    Returns
    -------
    (rows, columns) uint8 or uint16
        The frame [DN].

    Raises
    ------
    FrameError
        Missing, unreadable, colour or of another depth, naming the file.
    """
    p = Path(path)
    if not p.is_file():
        raise FrameError(f"frame {str(p)!r} does not exist")
    img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    if img is None and p.suffix.lower() in (".tif", ".tiff"):
        img = _read_tifffile(p)
    if img is None:
        raise FrameError(f"frame {str(p)!r} is unreadable or corrupt (not a PNG or TIFF OpenCV can decode)")
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim != 2:
        raise FrameError(f"frame {str(p)!r} has {img.shape[2]} channels: frames must be grayscale")
    if img.dtype not in (np.uint8, np.uint16):
        raise FrameError(f"frame {str(p)!r} has dtype {img.dtype}: frames must be 8- or 16-bit integers")
    return img


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


def positions_from_csv(frames, csv_path: str | Path) -> list[ImportedFrame]:
    """Stage positions or angles of ``frames`` from a CSV (module docstring).

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
        Unreadable CSV, no ``file`` or position column, a frame without a row, a non-numeric value.
    """
    p = Path(csv_path)
    try:
        with p.open(newline="", encoding="utf-8") as fh:
            rows = list(csv.DictReader(fh))
            header = rows[0].keys() if rows else []
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise FrameError(f"positions file {str(p)!r} cannot be read: {exc}") from None
    keys = [k for k in _KEYS if k in header]
    if "file" not in header or len(keys) != 1:
        raise FrameError(f"positions file {str(p)!r} needs a header with 'file' and one of "
                         f"'stage_mm' or 'angle_deg' (got {', '.join(header) or 'nothing'})")
    table = {r["file"].strip(): r[keys[0]] for r in rows}
    out = []
    for f in map(Path, frames):
        text = table.get(str(f), table.get(f.name))
        if text is None:
            raise FrameError(f"frame {str(f)!r} has no row in {str(p)!r}")
        out.append(ImportedFrame(f, keys[0], _number(text, f"{str(p)!r}, frame {str(f)!r}")))
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


def _check_rig(rig: dict | None, shape: tuple[int, int]) -> None:
    if rig is None:
        return
    s = rig.get("sensor", {})
    if (s.get("rows"), s.get("columns")) != shape:
        raise FrameError(f"the rig's sensor is {s.get('rows')} × {s.get('columns')} (rows × columns) but the "
                         f"frames are {shape[0]} × {shape[1]}")


def _load_all(frames: list[ImportedFrame]) -> list[np.ndarray]:
    images, first = [], None
    for fr in frames:
        img = read_image(fr.path)
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


def import_frames(frames: list[ImportedFrame], out: str | Path, *, rig: dict | None = None,
                  adc_bits: int | None = None, scenario: str | None = None,
                  scenario_params: dict | None = None) -> Path:
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
    scenario : str, optional
        Scenario name; default "calibration" for stage positions, "rotary" for angles.
    scenario_params : dict, optional
        E.g. ``{"plate_height_mm": 89}``.

    Returns
    -------
    Path
        The folder.

    Raises
    ------
    FrameError
        No frames, mixed keys, bad frames (:func:`read_image`), a rig of another size, an
        out folder that is not empty, a bad ``adc_bits``.
    """
    if not frames:
        raise FrameError("no frames to import")
    if len({f.key for f in frames}) != 1:
        raise FrameError("frames mix stage positions and angles")
    frames = sorted(frames, key=lambda f: f.value)        # stable: equal positions keep their order
    images = _load_all(frames)
    _check_rig(rig, images[0].shape)
    depth = 8 * images[0].itemsize
    bits = depth if adc_bits is None else int(adc_bits)
    if not 1 <= bits <= depth:
        raise FrameError(f"adc_bits = {adc_bits}: must be in 1..{depth} for {depth}-bit frames")
    out = Path(out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise FrameError(f"output folder {str(out)!r} exists and is not empty")
    manifest = {"format": FORMAT, "complete": True,
                "scenario": scenario or ("calibration" if frames[0].key == "stage_mm" else "rotary"),
                "scenario_params": scenario_params or {}, "adc_bits": bits,
                "source": "scheimpflug import", "frames": []}
    if rig is not None:
        manifest["rig"] = rig
    _write(out, manifest, frames, images)
    return out


def _write(out: Path, manifest: dict, frames: list[ImportedFrame], images: list[np.ndarray]) -> None:
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        (tmp / "frames").mkdir()
        for i, (fr, img) in enumerate(zip(frames, images)):
            name = f"frames/{i:05d}.png"
            if not cv2.imwrite(str(tmp / name), img):
                raise FrameError(f"cannot write {str(out / name)!r}")
            manifest["frames"].append({"file": name, fr.key: fr.value, "source_file": str(fr.path)})
        (tmp / "manifest.json").write_text(json.dumps(manifest, indent=1), "utf-8")
        if out.exists():
            out.rmdir()
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
