"""Regression datasets: open, filter and read them, verify their files, score stripe detectors.

A dataset folder (``scheimpflug dataset make``, docs/reference/interface.md "Datasets")::

    DIR/dataset.json          spec, generator versions, counts, bytes, failures
    DIR/index.parquet         one row per frame (columns below)
    DIR/files.parquet         every file of the dataset with its SHA-256 (path, sha256, bytes,
                              sample, frame; frame = −1 for a sample's own files)
    DIR/README.md             the dataset card
    DIR/samples/NNNNNN/       one frame folder per sample (manifest.json, frames/, truth/)
                              + sample.json (its index rows and files)
    DIR/meshes/SHA256.ply     each distinct truth mesh once; the samples' truth/*.ply are
                              hard links to these (the ledger's ``link`` column)
    DIR/frames.zarr/          with --format zarr: frames and per-row truth, one frame per chunk

Index columns: ``sample``, ``frame`` (within the sample), ``file`` (the frame's file
relative to DIR), ``sha256``, ``truth_file``, ``truth_sha256``, ``scenario``,
``stage_mm`` and ``angle_deg`` (NaN where not applicable), ``seed`` (frame seed),
``sample_seed``, ``part``, ``materials`` (the parts' material tags, comma-separated),
``object_materials`` ("id:tag;…"), ``binning``, ``rows``, ``columns``, ``zarr_index``
(position in the Zarr arrays, −1 for PNG), the truth statistics ``lit_rows``,
``multi_rows`` (rows with several crossings), ``u_min_px``, ``u_max_px``,
``distance_min_mm``, ``distance_max_mm``, ``incidence_mean_deg``, and one column per
drawn value (``rig.sensor.roll_deg``, ``scenario.part``, ``materials.metal_alpha`` …).

Per-row truth of a frame (``Frame.truth``): ``stripe_u`` (rows,) [px] (NaN = none),
``stripe_point_mm`` (rows, 3) [mm], ``stripe_object_id`` (rows,), ``stripe_count``
(rows,), ``stripe_distance_mm`` (rows,) — D of the stripe point along the sheet from
the object hinge [mm] — and ``stripe_incidence_deg`` (rows,) — the laser's angle of
incidence on the surface there [deg] (``sim.truth.SceneTruth``).

Scoring a detector (:func:`score_dataset`).  A detector is a function
``detect(frame) -> centres``: ``frame`` a (rows, columns) uint16 array of raw ADC
values [DN], ``centres`` a (rows,) float array, the sub-pixel column of the stripe
centre in every row [px] (pixel k's centre is at u = k), NaN where it finds none.
Per row with truth and a detection, the error is e = detected − truth (a detection of
±inf is a detection, infinitely wrong).  Statistics:
``bias_px`` and ``rms_px`` — mean and RMS of e over the rows with |e| ≤ 1 px
(inliers); ``p99_px`` — 99th percentile of |e| over all rows with both (to the
0.0005 px bin below 2 px, exact above 1e5 px: never capped; ``null`` in JSON when it is
infinite, with ``infinite_rows`` saying how many rows were); ``outlier_rate`` — share of
those with |e| > 1 px; ``missed_rate`` — share of truth rows without a detection;
``false_rate`` — share of rows without truth where the detector found a stripe.  The
same statistics are broken down by material, distance, angle of incidence and scenario.

The regression gate (:func:`compare_scores`): a detector regresses against a baseline
when its |bias|, RMS or p99 is worse by more than ``max_regression_px``, when it lacks a
figure the baseline has (a detector that finds nothing has no RMS), or when its missed,
outlier or false-detection rate is higher than the baseline's by more than
``max_rate_increase`` (default 0: any increase).
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import json
import math
import os
import sys
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from scheimpflug.callbacks import ProgressCallback, report
from scheimpflug.errors import DatasetError
from scheimpflug.io.folder import LOCK_NAME

__all__ = [
    "DATASET_FORMAT",
    "DETECTORS",
    "TRUTH_ARRAYS",
    "Dataset",
    "ErrorStats",
    "Frame",
    "ScoreReport",
    "VerifyReport",
    "compare_scores",
    "file_sha256",
    "load_detector",
    "open_dataset",
    "read_info",
    "score_dataset",
    "score_frame",
    "score_sample",
    "verify_dataset",
]

DATASET_FORMAT = "scheimpflug-dataset/1"
INDEX_FILE, FILES_FILE, CARD_FILE, META_FILE = "index.parquet", "files.parquet", "README.md", "dataset.json"
ZARR_STORE = "frames.zarr"
#: per-row truth arrays: name → (dtype, trailing shape, fill value for "none")
TRUTH_ARRAYS = {
    "stripe_u": ("float64", (), float("nan")),
    "stripe_point_mm": ("float64", (3,), float("nan")),
    "stripe_object_id": ("int16", (), 0),
    "stripe_count": ("uint8", (), 0),
    "stripe_distance_mm": ("float64", (), float("nan")),
    "stripe_incidence_deg": ("float64", (), float("nan")),
}
#: the project's detectors by name (scheimpflug.stripe methods)
DETECTORS = ("blais-rioux", "cog", "edge", "gaussian3", "paper")
OUTLIER_PX = 1.0
DISTANCE_BIN_MM = 25.0
INCIDENCE_BIN_DEG = 10.0


def file_sha256(path: str | os.PathLike) -> str:
    """SHA-256 of a file's bytes, hex.

    Parameters
    ----------
    path : path
        The file.

    Returns
    -------
    str
        64 hex digits.
    """
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


# ------------------------------------------------------------------ opening and reading


@dataclass(frozen=True)
class Frame:
    """One frame of a dataset with its truth and metadata.

    Parameters
    ----------
    image : (rows, columns) uint16
        Raw ADC values [DN].
    truth : dict
        Per-row truth arrays (:data:`TRUTH_ARRAYS`; module docstring).
    meta : dict
        The frame's index row.
    """

    image: np.ndarray
    truth: dict
    meta: dict


class Dataset:
    """A dataset folder opened for reading (:func:`open_dataset`); a view on some of its frames.

    Parameters
    ----------
    path : Path
        The dataset folder.
    info : dict
        ``dataset.json``.
    index : pyarrow.Table
        The index rows of this view.

    Notes
    -----
    ``len(ds)`` frames; ``ds[i]`` is a :class:`Frame`; iterating yields frames in index
    order; :meth:`filter` narrows the view; :meth:`frames_dask` and :meth:`to_xarray`
    read lazily.
    """

    def __init__(self, path: Path, info: dict, index) -> None:
        self.path = Path(path)
        self.info = info
        self.index = index
        self._rows = None
        self._zarr = None

    # ---------------------------------------------------------------- description
    @property
    def storage(self) -> str:
        """``"png"`` or ``"zarr"``."""
        return self.info.get("storage", "png")

    @property
    def spec(self) -> dict:
        """The spec the dataset was made from (as written)."""
        return self.info.get("spec", {})

    @property
    def complete(self) -> bool:
        """Whether every sample of the spec was made."""
        return bool(self.info.get("complete"))

    @property
    def samples(self) -> list[int]:
        """Sample numbers present in this view, ascending."""
        return sorted(set(self.index.column("sample").to_pylist()))

    def __len__(self) -> int:
        return self.index.num_rows

    def __repr__(self) -> str:
        return (f"Dataset({str(self.path)!r}, {len(self)} frames, {len(self.samples)} samples, "
                f"{self.storage})")

    def rows(self) -> list[dict]:
        """The index rows of this view as dicts.

        Returns
        -------
        list of dict
            One per frame, in index order.
        """
        if self._rows is None:
            self._rows = self.index.to_pylist()
        return self._rows

    def to_pandas(self):
        """The index of this view as a pandas DataFrame (needs pandas).

        Returns
        -------
        pandas.DataFrame
            One row per frame.
        """
        return self.index.to_pandas()

    # ---------------------------------------------------------------- selecting
    def filter(self, expression=None, **conditions) -> Dataset:
        """The frames whose index rows match.

        Parameters
        ----------
        expression : pyarrow.compute.Expression, optional
            Any pyarrow filter, e.g. ``pc.field("stage_mm") > 50``.
        **conditions
            ``column=value`` (equal), ``column=[v1, v2]`` (one of) or
            ``column=(lo, hi)`` (lo ≤ value ≤ hi); dotted column names go through
            ``expression`` or ``**{"rig.sensor.roll_deg": (0, 0.1)}``.

        Returns
        -------
        Dataset
            A view on the matching frames.

        Raises
        ------
        DatasetError
            For an unknown column.
        """
        import pyarrow.compute as pc

        mask = None
        for column, cond in conditions.items():
            if column not in self.index.column_names:
                raise DatasetError(f"filter: unknown index column {column!r} "
                                   f"(columns: {', '.join(self.index.column_names)})")
            f = pc.field(column)
            if isinstance(cond, tuple) and len(cond) == 2:
                term = (f >= cond[0]) & (f <= cond[1])
            elif isinstance(cond, (list, set, frozenset)):
                term = f.isin(list(cond))
            else:
                term = f == cond
            mask = term if mask is None else mask & term
        if expression is not None:
            mask = expression if mask is None else mask & expression
        table = self.index if mask is None else self.index.filter(mask)
        view = Dataset(self.path, self.info, table)
        view._zarr = self._zarr
        return view

    def sample(self, k: int) -> Dataset:
        """The frames of sample ``k``.

        Parameters
        ----------
        k : int
            Sample number.

        Returns
        -------
        Dataset
            A view on that sample's frames.
        """
        return self.filter(sample=int(k))

    def sample_folder(self, k: int) -> Path:
        """The frame folder of sample ``k`` (``samples/NNNNNN``).

        Parameters
        ----------
        k : int
            Sample number.

        Returns
        -------
        Path
            The folder (for PNG datasets a frame folder ``calibrate``/``reconstruct`` read).
        """
        return self.path / "samples" / f"{int(k):06d}"

    # ---------------------------------------------------------------- reading
    def __getitem__(self, i: int) -> Frame:
        n = len(self)
        if not -n <= i < n:
            raise IndexError(f"frame {i} out of range (dataset view of {n} frames)")
        meta = self._rows[i] if self._rows is not None else self.index.slice(i % n, 1).to_pylist()[0]
        return Frame(self.read_image(meta), self.read_truth(meta), meta)

    def __iter__(self) -> Iterator[Frame]:
        for batch in self.index.to_batches(max_chunksize=256):
            for meta in batch.to_pylist():
                yield Frame(self.read_image(meta), self.read_truth(meta), meta)

    def read_image(self, meta: dict) -> np.ndarray:
        """The image of the frame with index row ``meta``.

        Parameters
        ----------
        meta : dict
            An index row.

        Returns
        -------
        (rows, columns) uint16
            Raw ADC values [DN].
        """
        if self.storage == "zarr":
            return np.asarray(self._store()["frames"][int(meta["zarr_index"])])
        from scheimpflug.io.frames import read_frame

        return read_frame(self.path / meta["file"], (int(meta["rows"]), int(meta["columns"])))

    def read_truth(self, meta: dict) -> dict:
        """The per-row truth of the frame with index row ``meta``.

        Parameters
        ----------
        meta : dict
            An index row.

        Returns
        -------
        dict
            :data:`TRUTH_ARRAYS` by name.

        Raises
        ------
        DatasetError
            For a missing or unreadable truth file.
        """
        if self.storage == "zarr":
            store, g = self._store(), int(meta["zarr_index"])
            return {name: np.asarray(store[name][g]) for name in TRUTH_ARRAYS}
        path = self.path / meta["truth_file"]
        try:
            with np.load(path) as z:
                return {name: z[name] for name in TRUTH_ARRAYS if name in z.files}
        except (OSError, ValueError, KeyError) as exc:
            raise DatasetError(f"truth file {str(path)!r} cannot be read: {exc}") from None

    def _store(self):
        if self._zarr is None:
            import zarr

            self._zarr = zarr.open_group(str(self.path / ZARR_STORE), mode="r")
        return self._zarr

    def frames_dask(self):
        """All frames of this view as a lazy Dask array (frames, rows, columns) uint16.

        Returns
        -------
        dask.array.Array
            Zarr: the store's chunks (one frame per chunk); PNG: one delayed decode per frame.

        Raises
        ------
        DatasetError
            When the frames of the view differ in size (samples with other binnings).
        """
        import dask
        import dask.array as da

        rows = self.rows()
        shapes = {(int(r["rows"]), int(r["columns"])) for r in rows}
        if len(shapes) > 1:
            raise DatasetError(f"the frames of this view have {len(shapes)} different sizes; "
                               "filter on 'binning' (or rows/columns) first")
        if self.storage == "zarr":
            arr = da.from_zarr(str(self.path / ZARR_STORE), component="frames")
            return arr[np.asarray([int(r["zarr_index"]) for r in rows], dtype=np.int64)]
        (shape,) = shapes or {(0, 0)}
        read = dask.delayed(_read_png, pure=True)
        parts = [da.from_delayed(read(str(self.path / r["file"]), shape), shape, dtype=np.uint16)
                 for r in rows]
        return da.stack(parts) if parts else da.zeros((0, *shape), dtype=np.uint16)

    def to_xarray(self):
        """The Zarr store as a lazy xarray Dataset (frames and per-row truth), this view's frames.

        Returns
        -------
        xarray.Dataset
            Variables ``frames`` (frame, row, column) and the truth arrays (frame, row[, xyz]).

        Raises
        ------
        DatasetError
            For a PNG dataset.
        """
        if self.storage != "zarr":
            raise DatasetError("to_xarray needs a Zarr dataset (made with --format zarr); "
                               "use frames_dask() for PNG frames")
        import xarray as xr

        xds = xr.open_zarr(str(self.path / ZARR_STORE), consolidated=False)
        return xds.isel(frame=[int(r["zarr_index"]) for r in self.rows()])


def _read_png(path: str, shape: tuple[int, int]) -> np.ndarray:
    from scheimpflug.io.frames import read_frame

    return read_frame(path, shape)


def open_dataset(path: str | os.PathLike) -> Dataset:
    """Open a dataset folder (``dataset.json`` + ``index.parquet``).

    Parameters
    ----------
    path : path
        The dataset folder.

    Returns
    -------
    Dataset
        All its frames.

    Raises
    ------
    DatasetError
        A missing folder, ``dataset.json`` or index, or one that cannot be read.
    """
    import pyarrow.parquet as pq

    folder = Path(path)
    info = read_info(folder)
    index_path = folder / INDEX_FILE
    if not index_path.is_file():
        raise DatasetError(f"dataset {str(folder)!r} has no {INDEX_FILE} (no sample finished yet?)")
    try:
        index = pq.read_table(index_path)
    except Exception as exc:  # noqa: BLE001 - pyarrow raises several types
        raise DatasetError(f"{str(index_path)!r} cannot be read: {exc}") from None
    return Dataset(folder, info, index)


def read_info(folder: Path) -> dict:
    """``dataset.json`` of a dataset folder, checked.

    Parameters
    ----------
    folder : Path
        The dataset folder.

    Returns
    -------
    dict
        Its contents.

    Raises
    ------
    DatasetError
        A missing folder or file, bad JSON or another format.
    """
    if not folder.is_dir():
        raise DatasetError(f"dataset folder {str(folder)!r} does not exist")
    meta = folder / META_FILE
    if not meta.is_file():
        raise DatasetError(f"{str(folder)!r} is not a dataset folder (no {META_FILE})")
    try:
        info = json.loads(meta.read_text("utf-8"))
    except (OSError, ValueError) as exc:
        raise DatasetError(f"{str(meta)!r} cannot be read: {exc}") from None
    if not isinstance(info, dict) or info.get("format") != DATASET_FORMAT:
        raise DatasetError(f"{str(meta)!r} is not a {DATASET_FORMAT} dataset description")
    return info


# ------------------------------------------------------------------ verification


@dataclass
class VerifyReport:
    """What :func:`verify_dataset` found.

    Parameters
    ----------
    frames : int
        Frames in the index [-].
    files : int
        Files in the ledger (``files.parquet``) [-].
    missing : list of str
        Listed files that do not exist (paths relative to the folder).
    corrupt : list of str
        Listed files whose SHA-256 differs.
    extra : list of str
        Files in the folder that no ledger lists (temporaries included).
    duplicates : list of str
        Frames listed twice in the index (the same file twice, or the same content under two
        names) and files listed twice in the ledger, each naming both entries.
    """

    frames: int = 0
    files: int = 0
    missing: list = field(default_factory=list)
    corrupt: list = field(default_factory=list)
    extra: list = field(default_factory=list)
    duplicates: list = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """No missing, corrupt, extra or duplicate file."""
        return not (self.missing or self.corrupt or self.extra or self.duplicates)

    def to_json(self, limit: int = 20) -> dict:
        """The JSON of ``dataset verify --json`` (docs/reference/interface.md: frames, missing, corrupt, extra).

        Parameters
        ----------
        limit : int
            At most this many paths listed per kind.

        Returns
        -------
        dict
            Counts, ``ok`` and the first paths of each kind.
        """
        return {"frames": self.frames, "files": self.files, "missing": len(self.missing),
                "corrupt": len(self.corrupt), "extra": len(self.extra), "duplicates": len(self.duplicates),
                "ok": self.ok, "missing_files": self.missing[:limit], "corrupt_files": self.corrupt[:limit],
                "extra_files": self.extra[:limit], "duplicate_frames": self.duplicates[:limit]}


#: files of a dataset folder that no ledger lists (they describe the ledger or are rewritten)
_UNLISTED = {META_FILE, INDEX_FILE, FILES_FILE, CARD_FILE, LOCK_NAME}


def verify_dataset(path: str | os.PathLike, progress: ProgressCallback | None = None,
                   threads: int | None = None) -> VerifyReport:
    """Re-hash every file of a dataset against its ledger; list missing, corrupt and extra files.

    Parameters
    ----------
    path : path
        The dataset folder.
    progress : ProgressCallback, optional
        ``progress(done, total)`` over the files.
    threads : int, optional
        Hashing threads (default: the CPU count, at most 8).

    Returns
    -------
    VerifyReport
        The findings; a frame listed twice in the index (the same measurement counted twice)
        is a finding too, naming both entries.

    Raises
    ------
    DatasetError
        When the folder is not a dataset or its ledgers cannot be read.
    """
    import pyarrow.parquet as pq

    folder = Path(path)
    read_info(folder)
    try:
        ledger = pq.read_table(folder / FILES_FILE).to_pydict()
        index = pq.read_table(folder / INDEX_FILE,
                              columns=["sample", "frame", "file", "sha256", "lit_rows"]).to_pydict()
        frames = len(index["file"])
    except FileNotFoundError as exc:
        raise DatasetError(f"dataset {str(folder)!r} has no ledger ({exc.filename})") from None
    except Exception as exc:  # noqa: BLE001
        raise DatasetError(f"dataset {str(folder)!r}: the ledgers cannot be read: {exc}") from None
    expected = dict(zip(ledger["path"], ledger["sha256"]))
    result = VerifyReport(frames=frames, files=len(expected), duplicates=_duplicates(index, ledger["path"]))
    items = sorted(expected.items())

    def check(item):
        rel, digest = item
        p = folder / rel
        if not p.is_file():
            return "missing", rel
        return ("ok" if file_sha256(p) == digest else "corrupt"), rel

    with ThreadPoolExecutor(max_workers=threads or min(8, os.cpu_count() or 1)) as pool:
        for done, (status, rel) in enumerate(pool.map(check, items), start=1):
            if status != "ok":
                getattr(result, status).append(rel)
            report(progress, done, len(items))
    result.extra = _extra_files(folder, set(expected))
    return result


def _duplicates(index: dict, ledger_paths: list) -> list[str]:
    """Frames the index lists twice (same file, or same SHA-256 under two names); ledger paths listed twice.

    Two frames without a stripe may hold the same bytes (a blank frame of a noiseless sensor): only
    frames with a lit row count as the same content.
    """
    found, by_file, by_sha = [], {}, {}
    for s_, f_, path, sha, lit in zip(index["sample"], index["frame"], index["file"], index["sha256"],
                                      index["lit_rows"]):
        entry = f"sample {s_} frame {f_} ({path})"
        if path in by_file:
            found.append(f"{by_file[path]} and {entry}: the same file listed twice")
        elif lit and sha in by_sha:
            found.append(f"{by_sha[sha]} and {entry}: the same content (SHA-256) under two names")
        by_file.setdefault(path, entry)
        if lit:
            by_sha.setdefault(sha, entry)
    seen = set()
    for path in ledger_paths:
        if path in seen:
            found.append(f"{path} is listed twice in {FILES_FILE}")
        seen.add(path)
    return found


def _extra_files(folder: Path, listed: set) -> list[str]:
    extra = []
    for root, dirs, files in os.walk(folder):
        dirs.sort()
        for name in sorted(files):
            rel = Path(root, name).relative_to(folder).as_posix()
            if rel in listed or rel in _UNLISTED or (rel.startswith(ZARR_STORE + "/")
                                                     and name == "zarr.json"):
                continue
            extra.append(rel)
    return extra


# ------------------------------------------------------------------ detectors


def load_detector(spec: str) -> tuple[str, Callable[[np.ndarray], np.ndarray]]:
    """A detector by name (:data:`DETECTORS`) or ``MODULE:FUNCTION`` (or ``FILE.py:FUNCTION``).

    Parameters
    ----------
    spec : str
        ``cog``, ``gaussian3``, ``blais-rioux``, ``edge``, ``package.module:function`` or
        ``path/to/file.py:function``.

    Returns
    -------
    name : str
        ``spec`` as given.
    detect : callable
        ``detect(frame) -> (rows,) float`` (module docstring).

    Raises
    ------
    DatasetError
        An unknown name, a module that cannot be imported, a missing or non-callable function.
    """
    if spec in DETECTORS:
        return spec, _ProjectDetector(spec)
    module_name, sep, func = spec.rpartition(":")
    if not sep or not module_name or not func:
        raise DatasetError(f"detector {spec!r}: expected one of {', '.join(DETECTORS)} or "
                           "MODULE:FUNCTION")
    try:
        if module_name.endswith(".py"):
            mod = _module_from_file(Path(module_name))
        else:
            mod = importlib.import_module(module_name)
    except DatasetError:
        raise
    except (Exception, SystemExit) as exc:  # noqa: BLE001 - whatever the user's module raises (sys.exit too)
        raise DatasetError(f"detector {spec!r}: cannot import {module_name!r}: "
                           f"{type(exc).__name__}: {exc}") from None
    fn = getattr(mod, func, None)
    if not callable(fn):
        raise DatasetError(f"detector {spec!r}: {module_name!r} has no function {func!r}")
    return spec, fn


def _module_from_file(path: Path):
    if not path.is_file():
        raise DatasetError(f"detector file {str(path)!r} does not exist")
    name = f"_scheimpflug_detector_{hashlib.sha1(str(path.resolve()).encode()).hexdigest()[:12]}"
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod


class _ProjectDetector:
    """A project detector as ``frame → (rows,) centres`` (saturation at the ADC full scale).

    :func:`scheimpflug.stripe.extract_stripes` with the method of that name.
    """

    def __init__(self, method: str, saturation_dn: float | None = None) -> None:
        self.method, self.saturation_dn = method, saturation_dn

    def __call__(self, frame: np.ndarray) -> np.ndarray:
        from scheimpflug.stripe import extract_stripes

        prof = extract_stripes(frame, self.method, saturation_dn=self.saturation_dn)
        out = np.full(frame.shape[0], np.nan)
        out[prof.rows] = prof.u
        return out


# ------------------------------------------------------------------ statistics


#: |e| histogram edges [px]: 0.0005 px steps to 2 px, then geometric (0.5 %) to 1e5 px
_EDGES = np.unique(np.r_[np.arange(0.0, 2.0, 0.0005), 2.0 * 1.005 ** np.arange(0, 2170)])


@dataclass
class ErrorStats:
    """Mergeable error statistics of a detector against the per-row truth.

    Parameters
    ----------
    truth_rows : int
        Rows with a truth stripe [-].
    matched : int
        Truth rows with a detection [-].
    empty_rows : int
        Rows without truth [-].
    false_rows : int
        Rows without truth where the detector found a stripe [-].
    inliers : int
        Matched rows with |e| ≤ 1 px [-].
    sum_e, sum_e2 : list of float
        Partial sums Σe [px] and Σe² [px²] over the inliers, one per :meth:`add`; they
        are added with ``math.fsum`` (exactly rounded), so the result does not depend on
        the order in which partial statistics are merged.
    hist : (bins,) int64
        Histogram of |e| ≤ ``_EDGES[-1]`` over the matched rows (edges ``_EDGES``).
    tail : list of float
        |e| of the matched rows beyond the histogram (> ``_EDGES[-1]`` px, ±inf included), kept
        exactly [px].
    """

    truth_rows: int = 0
    matched: int = 0
    empty_rows: int = 0
    false_rows: int = 0
    inliers: int = 0
    sum_e: list = field(default_factory=list)
    sum_e2: list = field(default_factory=list)
    hist: np.ndarray = field(default_factory=lambda: np.zeros(len(_EDGES), dtype=np.int64))
    tail: list = field(default_factory=list)

    def add(self, detected: np.ndarray, truth: np.ndarray) -> None:
        """Count one frame's rows (or any subset of rows).

        Parameters
        ----------
        detected : (n,) float
            Detected centres [px], NaN = none.
        truth : (n,) float
            Truth centres [px], NaN = none.
        """
        has_t, has_d = np.isfinite(truth), ~np.isnan(detected)      # NaN = none; ±inf is a detection
        both = has_t & has_d
        e = detected[both] - truth[both]
        inl = np.abs(e) <= OUTLIER_PX
        self.truth_rows += int(has_t.sum())
        self.matched += int(both.sum())
        self.empty_rows += int((~has_t).sum())
        self.false_rows += int((~has_t & has_d).sum())
        self.inliers += int(inl.sum())
        self.sum_e.append(float(e[inl].sum()))
        self.sum_e2.append(float((e[inl] ** 2).sum()))
        a = np.abs(e)
        beyond = ~(a <= _EDGES[-1])
        self.tail += a[beyond].tolist()
        idx = np.clip(np.searchsorted(_EDGES, a[~beyond], side="right") - 1, 0, len(_EDGES) - 1)
        self.hist += np.bincount(idx, minlength=len(_EDGES))

    def merge(self, other: ErrorStats) -> ErrorStats:
        """Add ``other``'s counts to these (in place).

        Parameters
        ----------
        other : ErrorStats
            Statistics of other rows.

        Returns
        -------
        ErrorStats
            ``self``.
        """
        for name in ("truth_rows", "matched", "empty_rows", "false_rows", "inliers", "sum_e", "sum_e2", "tail"):
            setattr(self, name, getattr(self, name) + getattr(other, name))
        self.hist = self.hist + other.hist
        return self

    def quantile(self, q: float) -> float:
        """Quantile of |e| over the matched rows [px] (upper edge of its histogram bin).

        Parameters
        ----------
        q : float
            In [0, 1].

        Returns
        -------
        float
            NaN when no row matched; beyond the histogram the exact order statistic of the
            tail (inf if it is infinite).
        """
        if self.matched == 0:
            return float("nan")
        cum = np.cumsum(self.hist)
        target = q * self.matched
        if cum[-1] >= target and cum[-1] > 0:
            k = int(np.searchsorted(cum, target, side="left"))
            return float(_EDGES[min(k + 1, len(_EDGES) - 1)])
        rank = max(1, math.ceil(target - cum[-1]))
        return float(sorted(self.tail)[min(rank, len(self.tail)) - 1])

    def summary(self) -> dict:
        """The statistics (module docstring) as a JSON-ready dict.

        Returns
        -------
        dict
            ``n_rows``, ``bias_px``, ``rms_px``, ``p99_px``, ``outlier_rate``,
            ``missed_rate``, ``false_rate``, ``matched_rows``, ``empty_rows``,
            ``infinite_rows`` (matched rows with an infinite error).
        """
        def ratio(a, b):
            return a / b if b else None

        bias = ratio(math.fsum(self.sum_e), self.inliers)
        rms = math.sqrt(math.fsum(self.sum_e2) / self.inliers) if self.inliers else None
        p99 = self.quantile(0.99)
        return {"n_rows": self.truth_rows, "matched_rows": self.matched, "empty_rows": self.empty_rows,
                "bias_px": bias, "rms_px": rms, "p99_px": None if math.isnan(p99) else p99,
                "outlier_rate": ratio(self.matched - self.inliers, self.matched),
                "missed_rate": ratio(self.truth_rows - self.matched, self.truth_rows),
                "false_rate": ratio(self.false_rows, self.empty_rows),
                "infinite_rows": sum(1 for v in self.tail if v == math.inf)}


#: breakdown name → how a row's group is found
_BREAKDOWNS = ("material", "distance_mm", "incidence_deg", "scenario")


def _groups(truth: dict, meta: dict, has_t: np.ndarray) -> dict[str, np.ndarray]:
    """Per-row group labels of each breakdown (object array of str; "" for rows without truth)."""
    n = len(has_t)
    materials = dict(_parse_materials(meta.get("object_materials", "")))
    ids = truth["stripe_object_id"].astype(np.int64)
    mat = np.array([materials.get(int(i), "none") if t else "" for i, t in zip(ids, has_t)], dtype=object)
    out = {"material": mat, "scenario": np.where(has_t, str(meta.get("scenario", "")), "").astype(object)}
    for name, key, width in (("distance_mm", "stripe_distance_mm", DISTANCE_BIN_MM),
                             ("incidence_deg", "stripe_incidence_deg", INCIDENCE_BIN_DEG)):
        values = truth.get(key, np.full(n, np.nan))
        lo = np.floor(values / width) * width
        out[name] = np.array([f"{a:g}–{a + width:g}" if t and math.isfinite(a) else ""
                              for a, t in zip(lo, has_t)], dtype=object)
    return out


def _parse_materials(text: str) -> list[tuple[int, str]]:
    pairs = []
    for item in str(text or "").split(";"):
        if ":" in item:
            k, _, v = item.partition(":")
            pairs.append((int(k), v))
    return pairs


def score_frame(detect: Callable, image: np.ndarray, truth: dict, meta: dict,
                stats: dict) -> None:
    """Score one frame into ``stats`` (``{"all": ErrorStats, breakdown: {group: ErrorStats}}``).

    Parameters
    ----------
    detect : callable
        The detector.
    image : (rows, columns) uint16
        The frame [DN].
    truth : dict
        Its per-row truth.
    meta : dict
        Its index row.
    stats : dict
        Accumulators, updated in place.

    Raises
    ------
    DatasetError
        When the detector fails or returns something other than (rows,) numbers.
    """
    try:
        found = np.asarray(detect(image), dtype=np.float64)
    except (Exception, SystemExit) as exc:  # noqa: BLE001 - the user's code (sys.exit is its failure too)
        raise DatasetError(f"the detector failed on sample {meta.get('sample')} frame "
                           f"{meta.get('frame')}: {type(exc).__name__}: {exc}") from None
    rows = image.shape[0]
    if found.shape != (rows,):
        raise DatasetError(f"the detector returned shape {found.shape} for a frame of {rows} rows; "
                           f"it must return ({rows},) sub-pixel centres, NaN where none")
    u = np.asarray(truth["stripe_u"], dtype=np.float64)
    stats.setdefault("all", ErrorStats()).add(found, u)
    has_t = np.isfinite(u)
    for name, labels in _groups(truth, meta, has_t).items():
        table = stats.setdefault(name, {})
        for label in sorted(set(labels[has_t])):
            sel = labels == label
            table.setdefault(label, ErrorStats()).add(found[sel], u[sel])


def score_sample(path: str, rows: list[dict], detector: str, progress=None) -> dict:
    """Score a detector on some frames of a dataset (one sample: the unit of parallel work).

    Parameters
    ----------
    path : str
        The dataset folder.
    rows : list of dict
        The frames' index rows.
    detector : str
        Detector spec (:func:`load_detector`).
    progress : callable, optional
        ``progress(done, total)`` over the frames.

    Returns
    -------
    dict
        Accumulators: ``{"all": ErrorStats, "material": {…}, …, "frames": n}``.
    """
    ds = _reader(path)
    _, detect = load_detector(detector)
    if isinstance(detect, _ProjectDetector):
        bits = ds.info.get("adc_bits")
        detect = _ProjectDetector(detect.method, float(2 ** bits - 1) if bits else None)
    stats: dict = {"all": ErrorStats()}
    for i, meta in enumerate(rows):
        score_frame(detect, ds.read_image(meta), ds.read_truth(meta), meta, stats)
        report(progress, i + 1, len(rows))
    stats["frames"] = len(rows)
    return stats


_READERS: dict = {}


def _reader(path: str) -> Dataset:
    """A :class:`Dataset` for reading frames of ``path`` (index not loaded), cached per process."""
    key = str(Path(path).resolve())
    if key not in _READERS:
        import pyarrow as pa

        _READERS.clear()
        _READERS[key] = Dataset(Path(path), read_info(Path(path)), pa.table({}))
    return _READERS[key]


def _merge(total: dict, part: dict) -> dict:
    for key, value in part.items():
        if key == "frames":
            total["frames"] = total.get("frames", 0) + value
        elif isinstance(value, ErrorStats):
            total.setdefault(key, ErrorStats()).merge(value)
        else:
            _merge(total.setdefault(key, {}), value)
    return total


@dataclass
class ScoreReport:
    """A detector's statistics over a dataset (:func:`score_dataset`).

    Parameters
    ----------
    detector : str
        The detector spec.
    frames : int
        Frames scored [-].
    overall : ErrorStats
        All rows.
    breakdown : dict
        ``{"material": {group: ErrorStats}, "distance_mm": …, "incidence_deg": …,
        "scenario": …}``.
    """

    detector: str
    frames: int
    overall: ErrorStats
    breakdown: dict

    def to_json(self) -> dict:
        """The JSON of ``dataset score --json``.

        docs/reference/interface.md fields (``detector``, ``n_rows``, ``bias_px``, ``rms_px``, ``p99_px``,
        ``outlier_rate``, ``missed_rate``) plus ``false_rate``, ``frames`` and the breakdowns.

        Returns
        -------
        dict
            JSON-ready.
        """
        out = {"detector": self.detector, "frames": self.frames, **self.overall.summary()}
        for name in _BREAKDOWNS:
            groups = self.breakdown.get(name, {})
            out[f"by_{name}"] = {g: groups[g].summary() for g in sorted(groups, key=_group_key)}
        return out


def _group_key(label: str):
    head = label.split("–")[0]
    try:
        return (0, float(head), label)
    except ValueError:
        return (1, 0.0, label)


def score_dataset(dataset: Dataset, detector: str,
                  map_fn: Callable[[Callable, Iterable], Iterator] | None = None,
                  progress: ProgressCallback | None = None) -> ScoreReport:
    """Score a detector over every frame of a dataset view, sample by sample.

    Parameters
    ----------
    dataset : Dataset
        The dataset or a filtered view (its frames, grouped by sample).
    detector : str
        Detector spec (:func:`load_detector`); checked here before any work.
    map_fn : callable, optional
        ``map_fn(fn, items)`` yielding ``fn(item)`` results in any order (e.g. a Dask
        engine's map); default: in this process, in order.
    progress : ProgressCallback, optional
        ``progress(done, total)`` over the samples.

    Returns
    -------
    ScoreReport
        Overall statistics and breakdowns.

    Raises
    ------
    DatasetError
        An unknown detector, an empty dataset, a failing detector.
    """
    load_detector(detector)
    groups: dict[int, list] = {}
    for batch in dataset.index.to_batches(max_chunksize=4096):
        for meta in batch.to_pylist():
            groups.setdefault(meta["sample"], []).append(meta)
    if not groups:
        raise DatasetError(f"dataset {str(dataset.path)!r} holds no frames to score")
    work = _SampleScorer(str(dataset.path), detector)
    results = (map_fn or map)(work, [groups[k] for k in sorted(groups)])
    total: dict = {"all": ErrorStats()}
    for done, part in enumerate(results, start=1):
        _merge(total, part)
        report(progress, done, len(groups))
    overall = total.pop("all")
    frames = total.pop("frames", 0)
    return ScoreReport(detector, frames, overall, total)


class _SampleScorer:
    """Picklable ``index rows of a sample → accumulators`` (for process pools and Dask)."""

    def __init__(self, path: str, detector: str) -> None:
        self.path, self.detector = path, detector

    def __call__(self, rows: list[dict]) -> dict:
        return score_sample(self.path, rows, self.detector)


#: the gate's figures: JSON key of the difference → (summary key, unit, |value| compared)
_GATE_PX = {"d_abs_bias_px": ("bias_px", True), "d_rms_px": ("rms_px", False), "d_p99_px": ("p99_px", False)}
_GATE_RATES = {"d_missed_rate": "missed_rate", "d_outlier_rate": "outlier_rate", "d_false_rate": "false_rate"}


def compare_scores(score: ScoreReport, baseline: ScoreReport, max_regression_px: float,
                   max_rate_increase: float = 0.0) -> dict:
    """Whether a detector regresses against a baseline (the rule in the module docstring).

    Parameters
    ----------
    score, baseline : ScoreReport
        The detector's and the baseline's statistics on the same frames.
    max_regression_px : float
        Allowed worsening of |bias|, RMS and p99 [px].
    max_rate_increase : float
        Allowed increase of the missed, outlier and false-detection rates [-] (0: none).

    Returns
    -------
    dict
        ``regression`` (bool), ``reasons`` (one phrase per figure that regressed),
        ``max_regression_px``, ``max_rate_increase`` and the differences ``d_abs_bias_px``,
        ``d_rms_px``, ``d_p99_px``, ``d_missed_rate``, ``d_outlier_rate``, ``d_false_rate``
        (detector − baseline, positive = worse; None when either lacks the figure).
    """
    a, b = score.overall.summary(), baseline.overall.summary()
    d, reasons = {}, []
    for name, (key, absolute) in _GATE_PX.items():
        d[name] = _worse(a[key], b[key], absolute)
        reasons += _regressed(key, a[key], b[key], d[name], max_regression_px, "px")
    for name, key in _GATE_RATES.items():
        d[name] = _worse(a[key], b[key], False)
        reasons += _regressed(key, a[key], b[key], d[name], max_rate_increase, "")
    return {"regression": bool(reasons), "reasons": reasons, "max_regression_px": max_regression_px,
            "max_rate_increase": max_rate_increase, **d}


def _worse(x, y, absolute: bool):
    """Detector − baseline (of |values| if ``absolute``); None when either is missing."""
    if x is None or y is None:
        return None
    x, y = (abs(x), abs(y)) if absolute else (x, y)
    if math.isinf(x) and math.isinf(y):
        return 0.0
    return x - y


def _regressed(key: str, x, y, diff, allowed: float, unit: str) -> list[str]:
    """One phrase if the figure ``key`` regressed: missing while the baseline has it, or worse."""
    if x is None and y is not None:
        return [f"no {key} (the baseline's is {y:.4g}{unit and ' ' + unit})"]
    if diff is not None and (diff > allowed or math.isnan(diff)):
        return [f"{key} {x:.4g} against {y:.4g}{unit and ' ' + unit} (allowed +{allowed:g})"]
    return []

