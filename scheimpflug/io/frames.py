"""Frame folders: ``manifest.json`` + ``frames/*.png`` (docs/reference/interface.md), read and validated.

A frame folder is what ``scheimpflug render`` writes and what a real camera
rig provides.  The pipeline reads only the manifest and the frames, so real
and simulated data go through the same code.

Validation raises :class:`~scheimpflug.errors.FrameError` with the file and the
reason: a missing folder or manifest, bad JSON, missing keys, a missing,
unreadable or corrupt PNG, a frame whose size differs from the manifest's rig
(``sensor.rows × sensor.columns``) or from the first frame (no rig), a colour
frame or an unsupported dtype (only 8- and 16-bit grayscale), values above the
manifest's ADC range (``adc_bits``; MSB-aligned codes — every value a multiple of
``2**(16 − adc_bits)`` — are accepted and saturate at ``(2**adc_bits − 1) ·
2**(16 − adc_bits)``), a frame listed twice (:func:`check_distinct_frames`).

Edited or interrupted folders:

* a manifest saying ``"complete": false`` (a render interrupted, or still
  running) is refused, saying how to resume it (the render's own command, from
  its lock file when one was left) or naming the process still writing it;
  ``allow_incomplete=True`` uses the frames present, with a warning;
* a frame that ``checksums.jsonl`` records (what ``render`` wrote:
  :class:`scheimpflug.io.folder.FileLedger`) is verified when it is read — its
  size, then its SHA-256 — and a frame replaced or altered since is refused,
  naming it (a few ms per frame: the file is read once, hashed and decoded from
  memory);
* in a rotary scan (scenario ``rotary``) two frames at one ``angle_deg`` are
  warned about, naming them, and so are angles out of frame order in a folder
  written by ``render`` or ``import`` (both list frames in angle order: two
  angles swapped by an edit).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import warnings
from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from scheimpflug.errors import FrameError
from scheimpflug.io.folder import LEDGER_NAME, FileLedger, bytes_mismatch, describe_owner, lock_owner
from scheimpflug.model.rig import KEY_RANGES, key_in_range

__all__ = ["MAX_SIDE_PX", "STRIPE_ALONG", "FrameFolder", "FrameRecord", "check_distinct_frames", "open_frame_folder",
           "radians_note", "read_frame", "scenario_number"]

MAX_SIDE_PX = 65535
"""Largest frame side a manifest may declare (the rig's ``sensor.rows``/``columns`` range) [px]."""
STRIPE_ALONG = ("columns", "rows")
"""Values of a manifest's ``stripe_along``: the stripe runs down the image (one point per row) or across it."""


@dataclass(frozen=True)
class FrameRecord:
    """One entry of the manifest's ``frames`` list.

    Parameters
    ----------
    file : str
        Path relative to the folder (``frames/00000.png``).
    stage_mm : float or None, optional
        Translation stage coordinate [mm].
    angle_deg : float or None, optional
        Rotary stage angle [deg].
    exposure_ms : float or None, optional
        Exposure [ms].
    seed : int or None, optional
        Render seed.
    extra : dict, optional
        Every other key of the entry.
    """

    file: str
    stage_mm: float | None = None
    angle_deg: float | None = None
    exposure_ms: float | None = None
    seed: int | None = None
    extra: dict = field(default_factory=dict)


@dataclass(frozen=True)
class FrameFolder:
    """A validated frame folder; frames are read lazily.

    Build it with :func:`open_frame_folder`.  ``len(folder)`` is the number of
    frames; iterating yields ``(record, frame)`` pairs in manifest order.

    Parameters
    ----------
    path : Path
        The folder.
    rig : dict or None
        The manifest's rig tables, or None (real frames without a rig).
    scenario : str or None
        The manifest's scenario name.
    scenario_params : dict
        The manifest's ``scenario_params`` (may be empty).
    frames : tuple of FrameRecord
        One record per frame, in manifest order.
    rows, columns : int
        The expected frame shape [px].
    adc_bits : int or None, optional
        ADC depth from the rig (None if unknown) [bit].
    stripe_along : {"columns", "rows"}, optional
        Which way the laser stripe runs in the frames (the manifest's ``stripe_along``,
        default "columns": down the image, one stripe point per row; "rows": across it,
        one point per column — :func:`scheimpflug.stripe.oriented`).
    checksums : dict, optional
        Frame file (relative, as the manifest lists it) → ``{"bytes", "sha256"}`` recorded in the
        folder's ``checksums.jsonl`` when it was written; :meth:`read` verifies a frame against it.
    """

    path: Path
    rig: dict | None
    scenario: str | None
    scenario_params: dict
    frames: tuple[FrameRecord, ...]
    rows: int
    columns: int
    adc_bits: int | None = None
    stripe_along: str = "columns"
    checksums: dict = field(default_factory=dict, repr=False, compare=False)

    def __len__(self) -> int:
        return len(self.frames)

    def frame_path(self, i: int) -> Path:
        """Path of a frame's PNG file.

        Parameters
        ----------
        i : int
            Frame index in manifest order.

        Returns
        -------
        Path
            ``path / frames[i].file``.
        """
        return self.path / self.frames[i].file

    def read(self, i: int) -> np.ndarray:
        """Read one frame.

        Parameters
        ----------
        i : int
            Frame index in manifest order.

        Returns
        -------
        (rows, columns) ndarray uint8 or uint16
            The frame as stored [DN].

        Raises
        ------
        FrameError
            If the file is missing, unreadable, corrupt, not grayscale, not 8-
            or 16-bit, or not of the folder's shape (see :func:`read_frame`), or
            holds values above the manifest's ADC range ``2**adc_bits − 1`` that
            are not MSB-aligned codes (every value a multiple of the shift), or
            is not the file ``checksums.jsonl`` records (size or SHA-256).
        """
        want = self.checksums.get(self.frames[i].file)
        if want is None:
            frame = read_frame(self.frame_path(i), (self.rows, self.columns))
        else:
            frame = self._read_verified(i, want)
        self._check_adc_range(i, frame)
        return frame

    def _read_verified(self, i: int, want: dict) -> np.ndarray:
        """Read a frame's bytes once, check them against their ledger record, decode them."""
        p = self.frame_path(i)
        try:
            data = p.read_bytes()
        except FileNotFoundError:
            raise FrameError(f"frame {str(p)!r} does not exist") from None
        except OSError as exc:
            raise FrameError(f"frame {str(p)!r} cannot be read: {exc.strerror or exc}") from None
        reason = bytes_mismatch(data, want)
        if reason:
            raise FrameError(f"frame {str(p)!r} is not the file that was written there ({reason}, "
                             f"{LEDGER_NAME}): it was replaced or altered since; render the folder again with "
                             "the same command (frames that do not match their record are rendered again)")
        img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED) if data else None
        return _checked_image(p, img, (self.rows, self.columns))

    def _check_adc_range(self, i: int, frame: np.ndarray) -> None:
        """Refuse values above the manifest's ADC range unless they are MSB-aligned codes."""
        if self.adc_bits is None or self.adc_bits >= 8 * frame.itemsize:
            return
        top = (1 << self.adc_bits) - 1
        peak = int(frame.max())
        if peak <= top or _msb_shift(frame, self.adc_bits):
            return
        raise FrameError(f"frame {str(self.frame_path(i))!r} has values up to {peak}, above {top} = "
                         f"2**{self.adc_bits} − 1 (adc_bits in the manifest): the frames hold at least "
                         f"{peak.bit_length()}-bit data, so the manifest's adc_bits is wrong")

    def __iter__(self) -> Iterator[tuple[FrameRecord, np.ndarray]]:
        for i, rec in enumerate(self.frames):
            yield rec, self.read(i)

    def map_frames(self, fn: Callable[[FrameRecord, np.ndarray], Any],
                   workers: int | None = None) -> Iterator[Any]:
        """Yield ``fn(record, frame)`` for every frame, in order, decoding on threads.

        PNG decoding (OpenCV) and the numba stripe kernels release the GIL, so
        ``workers`` threads overlap them.  At most ``2 × workers`` frames are
        in flight, which bounds memory.

        Parameters
        ----------
        fn : callable
            ``fn(record, frame)`` with a :class:`FrameRecord` and the frame
            (as :meth:`read` returns it); called on worker threads.
        workers : int, optional
            Number of threads; default the CPU count, at most 4; 1 runs in the
            calling thread.

        Yields
        ------
        object
            ``fn``'s result for each frame, in manifest order; an exception in
            reading or in ``fn`` is raised here.
        """
        n = workers or min(4, os.cpu_count() or 1)
        work = lambda i: fn(self.frames[i], self.read(i))  # noqa: E731
        if n <= 1:
            yield from (work(i) for i in range(len(self.frames)))
            return
        with ThreadPoolExecutor(max_workers=n) as pool:
            pending: deque = deque()
            for i in range(len(self.frames)):
                pending.append(pool.submit(work, i))
                if len(pending) >= 2 * n:
                    yield pending.popleft().result()
            while pending:
                yield pending.popleft().result()

    def rig_value(self, table: str, key: str) -> float | None:
        """A positive number of the manifest's rig tables, or None where the manifest has none.

        Parameters
        ----------
        table, key : str
            E.g. ``"lens"``, ``"focal_length_mm"``.

        Returns
        -------
        float or None
            The value; None when the manifest has no rig, no such table or no such key.

        Raises
        ------
        FrameError
            Naming the key, when the table is not an object or the value is not a
            finite number > 0 within the key's range (:data:`scheimpflug.model.rig.KEY_RANGES`).
        """
        tab = (self.rig or {}).get(table)
        if tab is None:
            return None
        if not isinstance(tab, dict):
            raise FrameError(f"{str(self.path / 'manifest.json')!r}: rig.{table} must be an object")
        value = tab.get(key)
        if value is None:
            return None
        if not (_finite_number(value) and value > 0 and key_in_range(table, key, value)):
            where = KEY_RANGES.get(table, {}).get(key, "(0, inf)")
            raise FrameError(f"{str(self.path / 'manifest.json')!r}: rig.{table}.{key} = {value!r:.40} "
                             f"must be a finite number > 0 in {where}")
        return float(value)

    def saturation_dn(self, frame: np.ndarray) -> float:
        """Saturation level of a frame of this folder.

        Parameters
        ----------
        frame : ndarray uint8 or uint16
            A frame read from this folder [DN].

        Returns
        -------
        float
            ``2**adc_bits − 1`` when the manifest gives the ADC depth and the
            frame stays within it; ``(2**adc_bits − 1) · 2**shift`` when its
            values exceed that but are all multiples of ``2**shift`` (codes
            stored MSB-aligned, ``shift`` = the word's bits − adc_bits); else
            the dtype's maximum [DN].
        """
        top = float(np.iinfo(frame.dtype).max)
        if self.adc_bits is not None and self.adc_bits < 8 * frame.itemsize:
            level = float(2 ** self.adc_bits - 1)
            if float(frame.max()) <= level:
                return level
            shift = _msb_shift(frame, self.adc_bits)
            if shift:
                return level * 2 ** shift
        return top


def _msb_shift(frame: np.ndarray, adc_bits: int) -> int:
    """The shift of MSB-aligned codes (word bits − adc_bits) if every value is a multiple of 2**shift, else 0."""
    shift = 8 * frame.itemsize - adc_bits
    return shift if shift > 0 and not np.any(frame & ((1 << shift) - 1)) else 0


def radians_note(angles_deg) -> str | None:
    """A warning when rotary angles span one turn in radians, not degrees, else None.

    ``n ≥ 8`` angles spanning ``2π (n − 1)/n`` (to 2 %) are read as one turn in
    radians: ``angle_deg`` must be degrees.

    Parameters
    ----------
    angles_deg : sequence of float
        The frames' rotary angles [deg].

    Returns
    -------
    str or None
        The warning.
    """
    a = np.asarray([x for x in angles_deg if x is not None], np.float64)
    n = a.size
    if n < 8:
        return None
    span = float(a.max() - a.min())
    if 0.98 * 2 * math.pi * (n - 1) / n <= span <= 2 * math.pi * (1 + 1e-6):
        return (f"the angles span {span:.4g}° over {n} frames, one turn in radians: are they radians? "
                "angle_deg must be in degrees")
    return None


def check_distinct_frames(folder: FrameFolder, indices=None) -> None:
    """Refuse a frame listed twice: one file in two entries, or one file's bytes under two names.

    A frame counted twice counts one measurement twice: it shrinks the standard
    errors and weights that frame double without adding information.

    Parameters
    ----------
    folder : FrameFolder
        The opened folder.
    indices : iterable of int, optional
        The entries whose content is compared (e.g. the frames a calibration
        uses); default every entry.  Files named twice are refused among all.

    Raises
    ------
    FrameError
        Naming both entries.
    """
    mpath = str(folder.path / "manifest.json")
    seen: dict[str, int] = {}
    for i, rec in enumerate(folder.frames):
        key = os.path.normcase(os.path.realpath(folder.path / rec.file))
        if key in seen:
            raise FrameError(f"{mpath!r}: frames[{seen[key]}] and frames[{i}] both list {rec.file!r}: a frame "
                             "listed twice counts one measurement twice")
        seen[key] = i
    chosen = range(len(folder)) if indices is None else sorted(set(indices))
    by_size: dict[int, list[int]] = {}
    for i in chosen:
        by_size.setdefault(folder.frame_path(i).stat().st_size, []).append(i)
    for group in (g for g in by_size.values() if len(g) > 1):
        by_hash: dict[str, int] = {}
        for i in group:
            digest = hashlib.sha256(folder.frame_path(i).read_bytes()).hexdigest()
            if digest in by_hash:
                j = by_hash[digest]
                raise FrameError(f"{mpath!r}: frames[{j}] ({folder.frames[j].file}) and frames[{i}] "
                                 f"({folder.frames[i].file}) hold the same file content: one measurement "
                                 "listed twice under two names")
            by_hash[digest] = i


def read_frame(path: str | Path, expected_shape: tuple[int, int] | None = None) -> np.ndarray:
    """Read one grayscale PNG frame unchanged (8- or 16-bit).

    Parameters
    ----------
    path : str or Path
        The PNG file.
    expected_shape : tuple of int, optional
        (rows, columns) the frame must have [px]; not checked if None.

    Returns
    -------
    (rows, columns) ndarray uint8 or uint16
        The frame as stored [DN] (a single-channel 3-D image is squeezed).

    Raises
    ------
    FrameError
        Naming the file, for a missing, unreadable or corrupt file, a colour
        image, another dtype, or a shape other than ``expected_shape``.
    """
    p = Path(path)
    if not p.is_file():
        raise FrameError(f"frame {str(p)!r} does not exist")
    return _checked_image(p, cv2.imread(str(p), cv2.IMREAD_UNCHANGED), expected_shape)


def _checked_image(p: Path, img: np.ndarray | None, expected_shape: tuple[int, int] | None) -> np.ndarray:
    """A decoded frame checked as :func:`read_frame` says (None: not decodable)."""
    if img is None:
        raise FrameError(f"frame {str(p)!r} is unreadable or corrupt (not a PNG OpenCV can decode)")
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim != 2:
        raise FrameError(f"frame {str(p)!r} has {img.shape[2]} channels: frames must be grayscale")
    if img.dtype not in (np.uint8, np.uint16):
        raise FrameError(f"frame {str(p)!r} has dtype {img.dtype}: frames must be 8- or 16-bit")
    if expected_shape is not None and tuple(img.shape) != tuple(expected_shape):
        raise FrameError(f"frame {str(p)!r} is {img.shape[0]} rows × {img.shape[1]} columns, "
                         f"expected {expected_shape[0]} × {expected_shape[1]} (sensor rows × columns)")
    return img


def _load_manifest(folder: Path) -> dict:
    if not folder.is_dir():
        raise FrameError(f"frame folder {str(folder)!r} does not exist or is not a folder")
    mpath = folder / "manifest.json"
    if not mpath.is_file():
        raise FrameError(f"frame folder {str(folder)!r} has no manifest.json")
    try:
        data = json.loads(mpath.read_text("utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise FrameError(f"{str(mpath)!r} cannot be read: {exc}") from None
    except json.JSONDecodeError as exc:
        raise FrameError(f"{str(mpath)!r} is not valid JSON: {exc}") from None
    if not isinstance(data, dict):
        raise FrameError(f"{str(mpath)!r} must hold a JSON object")
    if "frames" not in data:
        raise FrameError(f"{str(mpath)!r} has no 'frames' key")
    if not isinstance(data["frames"], list) or not data["frames"]:
        raise FrameError(f"{str(mpath)!r}: 'frames' must be a non-empty list")
    return data


def _finite_number(value: Any) -> bool:
    """A JSON number that is finite as a float (not a boolean, string, NaN, ±inf or a huge integer)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:          # an integer beyond the float range
        return False


def _number(mpath: Path, i: int, entry: dict, key: str) -> float | None:
    value = entry.get(key)
    if value is None:
        return None
    if not _finite_number(value):
        raise FrameError(f"{str(mpath)!r}: frames[{i}].{key} = {value!r:.40} must be a finite number")
    return float(value)


def _record(mpath: Path, i: int, entry: Any) -> FrameRecord:
    if not isinstance(entry, dict) or not isinstance(entry.get("file"), str):
        raise FrameError(f"{str(mpath)!r}: frames[{i}] must be an object with a 'file' string")
    known = {"file", "stage_mm", "angle_deg", "exposure_ms", "seed"}
    seed = entry.get("seed")
    return FrameRecord(file=entry["file"], stage_mm=_number(mpath, i, entry, "stage_mm"),
                       angle_deg=_number(mpath, i, entry, "angle_deg"),
                       exposure_ms=_number(mpath, i, entry, "exposure_ms"),
                       seed=int(seed) if isinstance(seed, int) and not isinstance(seed, bool) else None,
                       extra={k: v for k, v in entry.items() if k not in known})


def _whole(mpath: Path, sensor: dict, key: str, lo: int, hi: int, required: bool,
           where: str = "rig.sensor.") -> int | None:
    """sensor[key] as an integer in [lo, hi] (an integral float is fine), or FrameError."""
    value = sensor.get(key)
    if value is None and not required:
        return None
    ok = _finite_number(value) and float(value).is_integer() and lo <= value <= hi
    if not ok:
        shown = repr(value) if len(repr(value)) <= 40 else repr(value)[:20] + "…"
        raise FrameError(f"{str(mpath)!r}: {where}{key} = {shown} must be an integer in "
                         f"[{lo}, {hi}]")
    return int(value)


def _sensor_shape(mpath: Path, rig: Any) -> tuple[int, int, int | None] | None:
    if rig is None:
        return None
    sensor = rig.get("sensor") if isinstance(rig, dict) else None
    if not isinstance(sensor, dict):
        raise FrameError(f"{str(mpath)!r}: 'rig' must hold a 'sensor' table")
    rows = _whole(mpath, sensor, "rows", 1, MAX_SIDE_PX, True)
    cols = _whole(mpath, sensor, "columns", 1, MAX_SIDE_PX, True)
    return rows, cols, _whole(mpath, sensor, "adc_bits", 1, 16, False)


def open_frame_folder(path: str | Path, *, allow_incomplete: bool = False, opt_in: str | None = None) -> FrameFolder:
    """Open and validate a frame folder (manifest and file list; frames read lazily).

    Every listed frame must exist; the first one is decoded to check (or, with
    no rig in the manifest, to set) the frame size.  The folder's
    ``checksums.jsonl``, where there is one, is kept to verify each frame when it
    is read (:meth:`FrameFolder.read`).

    Parameters
    ----------
    path : str or Path
        The folder holding ``manifest.json`` and ``frames/`` (docs/reference/interface.md).
    allow_incomplete : bool, default False
        Open a folder whose manifest says ``"complete": false`` (an interrupted
        render) with the frames present, and warn; by default it is refused.
    opt_in : str, optional
        How the caller's user allows that (e.g. "pass --allow-incomplete"), said in the refusal.

    Returns
    -------
    FrameFolder
        The validated folder.

    Raises
    ------
    FrameError
        Naming the file and the reason: a missing folder or manifest, bad JSON,
        a missing or empty ``frames`` list, a malformed entry or non-finite
        number, a manifest saying ``"complete": false`` (how to resume the render,
        or which process still writes it), a missing frame file, a rig without
        integer sensor rows and columns, a non-object ``scenario_params``, or a
        bad first frame (:func:`read_frame`).

    Warns
    -----
    UserWarning
        An unfinished folder opened with ``allow_incomplete``; in a rotary scan, two
        frames at one angle or angles out of frame order (module docstring); frames that
        ``checksums.jsonl`` does not record (not verified).
    """
    folder = Path(path)
    data = _load_manifest(folder)
    mpath = folder / "manifest.json"
    records = tuple(_record(mpath, i, e) for i, e in enumerate(data["frames"]))
    records = _complete_records(folder, data, records, allow_incomplete, opt_in)
    for rec in records:
        if not (folder / rec.file).is_file():
            raise FrameError(f"frame {str(folder / rec.file)!r} listed in {str(mpath)!r} does not exist")
    shape = _sensor_shape(mpath, data.get("rig"))
    first = read_frame(folder / records[0].file, shape[:2] if shape else None)
    rows, cols = (shape[0], shape[1]) if shape else first.shape
    params = data.get("scenario_params") or {}
    if not isinstance(params, dict):
        raise FrameError(f"{str(mpath)!r}: 'scenario_params' must be an object")
    bits = shape[2] if shape else None
    if bits is None and data.get("adc_bits") is not None:   # real frames imported without a rig
        bits = _whole(mpath, data, "adc_bits", 1, 16, True, where="")
    along = data.get("stripe_along", "columns")
    if along not in STRIPE_ALONG:
        raise FrameError(f"{str(mpath)!r}: stripe_along = {along!r:.40} must be one of {', '.join(STRIPE_ALONG)}")
    for note in _angle_notes(data, records):
        warnings.warn(f"{str(mpath)!r}: {note}", stacklevel=2)
    return FrameFolder(path=folder, rig=data.get("rig"), scenario=data.get("scenario"),
                       scenario_params=params, frames=records, rows=int(rows), columns=int(cols),
                       adc_bits=bits, stripe_along=along, checksums=_checksums(folder, records))


def _complete_records(folder: Path, data: dict, records: tuple, allow: bool, opt_in: str | None) -> tuple:
    """The records to use: all of a finished folder; of an unfinished one, refused or the frames present."""
    complete = data.get("complete")
    if complete is None or complete is True:
        return records
    if complete is not False:
        raise FrameError(f"{str(folder / 'manifest.json')!r}: complete = {complete!r:.40} must be true or false")
    present = tuple(r for r in records if (folder / r.file).is_file())
    text = _unfinished(folder, records, present)
    if not present:
        raise FrameError(f"{text}; no frame is written yet")
    if not allow:
        raise FrameError(text + (f"; or {opt_in} to use the {len(present)} frames present" if opt_in else ""))
    warnings.warn(f"{text}; using the {len(present)} frames present", stacklevel=3)
    return present


def _unfinished(folder: Path, records: tuple, present: tuple) -> str:
    """Why a folder whose manifest says "complete": false is unfinished, and what to do."""
    missing = next((r.file for r in records if not (folder / r.file).is_file()), None)
    head = (f"frame folder {str(folder)!r} is unfinished: its manifest.json says \"complete\": false "
            f"({len(present)} of {len(records)} frames written" + (f", first missing {missing})" if missing else ")"))
    owner, alive = lock_owner(folder)
    if alive:
        return f"{head}: it is being written now by {describe_owner(owner)}; wait for it to finish"
    command = (owner or {}).get("program")
    how = (f"run its command again to resume it: {command}" if command else
           "run the same `scheimpflug render` command again to resume it")
    since = f" (pid {owner.get('pid')}, started {owner.get('started')}, no longer runs)" if owner else ""
    return (f"{head}: the render that writes it was interrupted{since}; {how} — frames already finished are "
            f"kept (verified against {LEDGER_NAME})")


def _checksums(folder: Path, records: tuple) -> dict:
    """The ledger's record of each listed frame; warns about frames it does not record."""
    if not (folder / LEDGER_NAME).is_file():
        return {}
    recorded = FileLedger(folder).by_file()
    sums = {r.file: recorded[r.file] for r in records if r.file in recorded}
    unrecorded = [r.file for r in records if r.file not in recorded]
    if unrecorded:
        warnings.warn(f"{str(folder / LEDGER_NAME)!r} does not record {len(unrecorded)} of the {len(records)} "
                      f"frames (first {unrecorded[0]}): they are used unverified", stacklevel=3)
    return sums


def _angle_notes(data: dict, records: tuple) -> list[str]:
    """Warnings about a rotary scan's angles: two frames at one angle; angles out of frame order."""
    if data.get("scenario") != "rotary":
        return []
    indexed = [(i, r) for i, r in enumerate(records) if r.angle_deg is not None]
    notes = _same_angle_note(indexed)
    if "render" in data or data.get("source") == "scheimpflug import":   # writers that list frames in angle order
        notes += _order_note(indexed, "render" if "render" in data else "import")
    return notes


def _same_angle_note(indexed: list) -> list[str]:
    seen: dict[float, tuple[int, str]] = {}
    pairs = []
    for i, r in indexed:
        if r.angle_deg in seen:
            pairs.append((*seen[r.angle_deg], i, r))
        seen.setdefault(r.angle_deg, (i, r.file))
    if not pairs:
        return []
    j, first, i, r = pairs[0]
    more = f" ({len(pairs)} such frames)" if len(pairs) > 1 else ""
    return [f"frames[{j}] ({first}) and frames[{i}] ({r.file}) are at the same angle_deg = {r.angle_deg:g}{more}: "
            "one view counted twice, or a typo in the manifest"]


def _order_note(indexed: list, writer: str) -> list[str]:
    a = np.array([r.angle_deg for _, r in indexed])
    step = np.diff(a)
    if not (np.any(step > 0) and np.any(step < 0)):
        return []
    sign = 1.0 if np.sum(step > 0) >= np.sum(step < 0) else -1.0
    k = int(np.flatnonzero(step * sign < 0)[0])
    (i0, r0), (i1, r1) = indexed[k], indexed[k + 1]
    return [f"the angles are out of frame order: frames[{i1}] ({r1.file}) at {r1.angle_deg:g}° follows frames[{i0}] "
            f"({r0.file}) at {r0.angle_deg:g}°, though `{writer}` lists frames in angle order: was the manifest "
            "edited (angles swapped)?"]


def scenario_number(folder: FrameFolder, key: str, default: float, lo: float, hi: float) -> float:
    """A number of the manifest's ``scenario_params`` checked against its range.

    Parameters
    ----------
    folder : FrameFolder
        The opened folder.
    key : str
        Key in ``scenario_params`` (e.g. ``plate_height_mm``).
    default : float
        Value when the key is absent.
    lo, hi : float
        The value must be finite and in (lo, hi].

    Returns
    -------
    float
        The value, or ``default``.

    Raises
    ------
    FrameError
        Naming the manifest and the key, for a value that is not a finite
        number in (lo, hi] (a string, null, an object, NaN …).
    """
    if key not in folder.scenario_params:
        return float(default)
    value = folder.scenario_params[key]
    ok = _finite_number(value) and lo < value <= hi
    if not ok:
        raise FrameError(f"{str(folder.path / 'manifest.json')!r}: scenario_params.{key} = "
                         f"{value!r:.40} must be a finite number in ({lo:g}, {hi:g}]")
    return float(value)
