"""``scheimpflug dataset make``: every sample of a spec into a dataset folder, resumable.

Order of work (nothing is written before the spec, every sample's draw and the
output folder have been checked):

1. parse the spec and draw every sample (:mod:`sim.dataset.spec`);
2. check the output folder: writable; empty, or a dataset of the *same* spec,
   storage and input files (else one :class:`DatasetError` naming the difference);
3. write ``dataset.json`` (``"complete": false``) and, for Zarr, create the store;
4. make the samples not yet complete (:func:`sim.dataset.sample.make_sample`) on the
   :class:`~sim.dataset.engine.Engine`; a sample that fails is retried, and if it
   fails again its reason is recorded in ``dataset.json`` while the rest go on;
5. rewrite ``index.parquet`` and ``files.parquet`` atomically (every 30 s while
   running, on Ctrl-C, at the end) from the complete samples' ``sample.json``;
   write the dataset card ``README.md`` and the final ``dataset.json``.

Rerunning the same command resumes: complete samples are kept, partial ones
resume frame by frame, nothing is made twice.
"""

from __future__ import annotations

import json
import os
import shutil
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from scheimpflug.callbacks import ProgressCallback
from scheimpflug.dataset import (
    CARD_FILE,
    DATASET_FORMAT,
    FILES_FILE,
    INDEX_FILE,
    META_FILE,
    TRUTH_ARRAYS,
    ZARR_STORE,
    file_sha256,
)
from scheimpflug.errors import DatasetError
from scheimpflug.io.atomic import atomic_path, write_json_atomic, write_text_atomic
from scheimpflug.io.folder import LEDGER_NAME, FileLedger

from ..jobfolder import JobKind, check_identity, open_job, remove_temporaries, run_with_retries
from ..writer import estimate_job, generator_info
from .engine import Engine
from .sample import SAMPLE_FILE, ZarrLayout, make_sample, sample_folder
from .spec import DatasetSpec, SamplePlan, frames_bound, plan_sample

__all__ = ["MAX_SAMPLES", "MAX_SAMPLE_FRAMES", "STORAGES", "ZARR_CODEC", "MakeResult", "make_dataset",
           "size_dataset"]

#: Samples of one dataset at most: every sample is planned (its draws and rig checked) before the
#: first frame, ≈ 4 ms each (measured: 3.9 ms per sample of a rotary spec with one rig variation), so
#: 100 000 samples take ≈ 7 min to plan.
MAX_SAMPLES = 100_000
#: Frames of one sample at most: a sample's frames and manifest are built in memory before it renders.
MAX_SAMPLE_FRAMES = 100_000

STORAGES = ("png", "zarr")
#: Blosc settings of every Zarr array: zstd level 1 with bit-shuffle, 2 MiB blocks (lossless).
#: On a full noisy paper frame (4.7 MB raw): ≈ 3.6 ms and 0.95 MB with one thread; Blosc's
#: automatic block size gave ≈ 6.5 ms and 1.07 MB, lz4 2.6 ms and 1.35 MB, PNG (libdeflate
#: level 1) ≈ 20 ms and 0.97 MB (benchmarks/RESULTS.md).
ZARR_CODEC = {"cname": "zstd", "clevel": 1, "shuffle": "bitshuffle", "blocksize": 1 << 21}
_IDENTITY = ("format", "spec", "storage", "inputs")
_FLUSH_S = 30.0
_STORAGE_TEXT = {"png": "16-bit PNG frame folders in samples/",
                 "zarr": "Zarr store frames.zarr, Blosc/zstd + bit-shuffle, one frame per chunk"}


@dataclass
class MakeResult:
    """What :func:`make_dataset` did.

    Parameters
    ----------
    path : Path
        The dataset folder.
    samples : int
        Samples in the spec [-].
    samples_done : int
        Samples complete now [-].
    samples_made : int
        Samples completed by this run [-].
    failures : list of dict
        ``{"sample": k, "error": reason}`` of the samples that failed twice.
    frames : int
        Frames of the complete samples [-].
    frames_rendered : int
        Frames rendered by this run [-].
    seconds : dict
        ``wall`` and the sum over samples of ``setup``, ``render``, ``noise``, ``truth``,
        ``write`` [s].
    """

    path: Path
    samples: int
    samples_done: int = 0
    samples_made: int = 0
    failures: list = field(default_factory=list)
    frames: int = 0
    frames_rendered: int = 0
    seconds: dict = field(default_factory=dict)

    @property
    def complete(self) -> bool:
        """Every sample of the spec is made."""
        return self.samples_done == self.samples


# ------------------------------------------------------------------ checks


def size_dataset(spec: DatasetSpec, out, workers: int = 1) -> dict:
    """Size a dataset from its spec alone (nothing drawn, built or written) and refuse what cannot be made.

    Parameters
    ----------
    spec : DatasetSpec
        The parsed spec.
    out : path
        The dataset folder (its nearest existing folder's free space is compared).
    workers : int
        Worker processes (each holds a renderer in memory).

    Returns
    -------
    dict
        ``samples``, ``frames_per_sample`` (upper bound), ``frames``, ``output_bytes``,
        ``memory_bytes``.

    Raises
    ------
    DatasetError
        More than :data:`MAX_SAMPLES` samples or :data:`MAX_SAMPLE_FRAMES` frames per sample, more
        output than the free disk space, more memory than the machine has; each naming the size.
    """
    import shutil

    from scheimpflug.io.folder import unwritable_reason
    from scheimpflug.model.binning import binned_rig
    from scheimpflug.model.rig import rig_from_dict

    from .spec import _candidates, _truth_every

    if spec.samples > MAX_SAMPLES:
        raise DatasetError(f"dataset.samples = {spec.samples:,}: at most {MAX_SAMPLES:,} samples per dataset "
                           f"(each is planned before the first frame, ≈ 4 ms per sample: "
                           f"{spec.samples * 0.004 / 3600:.3g} h here); split the spec into several datasets")
    frames, why = frames_bound(spec)
    if frames > MAX_SAMPLE_FRAMES:
        raise DatasetError(f"{why} gives up to {frames:,} frames per sample; at most {MAX_SAMPLE_FRAMES:,} "
                           "(a sample's frames are built in memory before it renders)")
    binning = int(min(_candidates(spec, "binning") or [1]))
    rig = binned_rig(rig_from_dict(spec.rig), max(1, binning))
    every = _truth_every("spec", spec.scenario.get("truth_pixels", "none"))
    job = estimate_job(rig, spec.samples * frames, every, workers)
    what = f"{job.describe()} ({spec.samples:,} samples × up to {frames:,} frames)"
    probe, _ = unwritable_reason(out)
    free = shutil.disk_usage(probe).free if probe.is_dir() else None
    if free is not None and job.output_bytes > free:
        raise DatasetError(f"this dataset is {what}, but {str(probe)!r} has {free / 1e9:.3g} GB free")
    ram = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    if job.memory_bytes > ram:
        raise DatasetError(f"this dataset is {what}, but this machine has {ram / 1e9:.3g} GB of memory: "
                           "use a larger binning or fewer --workers")
    return {"samples": spec.samples, "frames_per_sample": frames, "frames": spec.samples * frames,
            "output_bytes": job.output_bytes, "memory_bytes": job.memory_bytes}


def _plans(spec: DatasetSpec, storage: str) -> list[SamplePlan]:
    if storage not in STORAGES:
        raise DatasetError(f"--format {storage!r}: unknown (known: {', '.join(STORAGES)})")
    plans = [plan_sample(spec, k) for k in range(spec.samples)]
    if storage == "zarr":
        shapes = {(p.rig["sensor"]["rows"], p.rig["sensor"]["columns"]) for p in plans}
        if len(shapes) > 1:
            raise DatasetError(f"--format zarr needs one frame size for every sample, but the spec "
                               f"draws {len(shapes)} (binning or sensor size varies); use --format png")
        if any(p.truth_pixels_every for p in plans):
            raise DatasetError("scenario.truth_pixels: per-pixel truth maps are written with "
                               "--format png only")
    return plans


def _inputs(spec: DatasetSpec) -> dict:
    out = {}
    for p in spec.input_files():
        try:
            name = p.relative_to(spec.folder).as_posix()
        except ValueError:
            name = str(p)
        out[name] = file_sha256(p)
    return out


def _identity(spec: DatasetSpec, storage: str) -> dict:
    return {"format": DATASET_FORMAT, "spec": spec.raw, "storage": storage, "inputs": _inputs(spec)}


#: the dataset folder as a job (:mod:`sim.jobfolder`)
DATASET_JOB = JobKind(error=DatasetError, meta_file=META_FILE, noun="dataset", folder_noun="dataset folder",
                      what={"spec": "a different spec", "storage": "another --format",
                            "inputs": "other input files (a rig, mesh or scene file changed)",
                            "format": "another version of this program"})


def _check_existing(out: Path, identity: dict) -> dict | None:
    """The existing ``dataset.json`` of the same spec, None for an empty/new folder; else raise."""
    return check_identity(out, DATASET_JOB, {k: identity[k] for k in _IDENTITY})


# ------------------------------------------------------------------ the store


def _create_store(out: Path, plans: list[SamplePlan], name: str) -> list[int]:
    """Create the Zarr arrays (if absent); return each sample's frame offset."""
    import zarr
    from zarr.codecs import BloscCodec

    offsets, n = [], 0
    for p in plans:
        offsets.append(n)
        n += p.frames
    rows, cols = plans[0].rig["sensor"]["rows"], plans[0].rig["sensor"]["columns"]
    path = out / ZARR_STORE
    group = zarr.open_group(str(path), mode="a", attributes={"format": DATASET_FORMAT, "dataset": name})
    codec = BloscCodec(**ZARR_CODEC)
    arrays = {"frames": ("uint16", (rows, cols), 0, ("frame", "row", "column"))}
    for key, (dtype, tail, fill) in TRUTH_ARRAYS.items():
        arrays[key] = (dtype, (rows, *tail), fill, ("frame", "row", *(["xyz"] if tail else [])))
    for key, (dtype, tail, fill, dims) in arrays.items():
        if key in group:
            if group[key].shape != (n, *tail):
                raise DatasetError(f"{str(path)!r}: array {key!r} has shape {group[key].shape}, "
                                   f"expected {(n, *tail)}; delete the folder to start over")
            continue
        group.create_array(key, shape=(n, *tail), chunks=(1, *tail), dtype=dtype, fill_value=fill,
                           compressors=codec, dimension_names=dims,
                           chunk_key_encoding={"name": "default", "separator": "."})
    return offsets


# ------------------------------------------------------------------ index and ledger


@dataclass
class _Part:
    """A complete sample's share of the index and the ledger, as Arrow tables."""

    rows: object
    files: object
    frames: int
    lit_rows: int
    bytes: dict
    pool: dict


def _part(out: Path, k: int, record: dict) -> _Part:
    import pyarrow as pa

    sj = sample_folder(out, k) / SAMPLE_FILE
    files = [*record["files"], {"path": sj.relative_to(out).as_posix(), "sha256": file_sha256(sj),
                                "bytes": sj.stat().st_size, "sample": k, "frame": -1, "link": None}]
    frame_files = {r["file"] for r in record["rows"]}
    kinds = {"frames": 0, "truth": 0, "other": 0}
    pool = {}
    for f in files:
        if f.get("link"):
            pool[f["link"]] = (f["sha256"], f["bytes"])
            continue
        kinds["frames" if f["path"] in frame_files else "truth" if f["frame"] >= 0 else "other"] += f["bytes"]
    return _Part(pa.Table.from_pylist(record["rows"]), pa.Table.from_pylist(files), len(record["rows"]),
                 sum(r["lit_rows"] for r in record["rows"]), kinds, pool)


def _load_parts(out: Path, plans: list[SamplePlan], warn) -> dict[int, _Part]:
    """The complete samples whose files all match their record; the others are reopened to be made again.

    A rerun over a dataset repairs it: every file of a complete sample is checked against its
    ``sample.json`` (size, then SHA-256, as a resumed render checks the frames it skips) and
    ``sample.json`` against the last ``files.parquet``; a sample with a missing or damaged file goes
    back to its partial folder, where only what does not match is made again.
    """
    listed = _listed_hashes(out)
    _HASHES.clear()
    parts = {}
    for p in plans:
        final = sample_folder(out, p.index)
        if not final.exists():
            continue
        record, damage = _check_sample(out, p.index, listed)
        if damage is None:
            (final / LEDGER_NAME).unlink(missing_ok=True)      # left by a kill just after the commit
            parts[p.index] = _part(out, p.index, record)
            continue
        warn(f"sample {p.index} is damaged ({damage}); making it again")
        _reopen(out, p.index, record, damage)
    _repair_pool(out, parts)
    return parts


def _listed_hashes(out: Path) -> dict[str, str]:
    """Path → SHA-256 of the last ``files.parquet`` (empty when there is none or it is unreadable)."""
    try:
        import pyarrow.parquet as pq

        table = pq.read_table(out / FILES_FILE, columns=["path", "sha256"]).to_pydict()
    except Exception:  # noqa: BLE001 - a missing or damaged ledger is rewritten from the samples
        return {}
    return dict(zip(table["path"], table["sha256"]))


def _file_problem(out: Path, entry: dict) -> str | None:
    """Why a listed file does not match its record (missing, size, SHA-256), or None."""
    path = out / entry["path"]
    if not path.is_file():
        return f"{entry['path']} is missing"
    st = path.stat()
    if st.st_size != entry["bytes"]:
        return f"{entry['path']} has {st.st_size} bytes, recorded {entry['bytes']}"
    key = (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)     # hard links (pooled meshes): hashed once
    if key not in _HASHES:
        _HASHES[key] = file_sha256(path)
    if _HASHES[key] != entry["sha256"]:
        return f"{entry['path']}: content differs from its record (SHA-256)"
    return None


_HASHES: dict = {}


def _check_sample(out: Path, k: int, listed: dict) -> tuple[dict | None, str | None]:
    """A complete sample's record and the first reason it is damaged (None if every file matches)."""
    from concurrent.futures import ThreadPoolExecutor

    sj = sample_folder(out, k) / SAMPLE_FILE
    rel = sj.relative_to(out).as_posix()
    if not sj.is_file():
        return None, f"{rel} is missing"
    try:
        record = json.loads(sj.read_text("utf-8"))
        files = [f for f in record["files"] if isinstance(f["path"], str)]
        _part(out, k, record)
    except (OSError, ValueError, KeyError, TypeError) as exc:
        return None, f"{rel} cannot be read: {' '.join(str(exc).split())}"
    if rel in listed and file_sha256(sj) != listed[rel]:
        return None, f"{rel}: content differs from files.parquet (SHA-256)"
    with ThreadPoolExecutor(max_workers=4) as pool:
        problems = [r for r in pool.map(lambda f: _file_problem(out, f), files) if r]
    if not problems:
        return record, None
    more = f" and {len(problems) - 1} more" if len(problems) > 1 else ""
    return record, problems[0] + more


def _reopen(out: Path, k: int, record: dict | None, damage: str) -> None:
    """Move a damaged complete sample back to its partial folder, with a ledger of its frames' records.

    Damaged scene files are removed (made again); a damaged ``sample.json`` or manifest, which
    cannot be checked or rebuilt alone, sends the whole sample back to be made anew.
    """
    final, partial = sample_folder(out, k), sample_folder(out, k, partial=True)
    if partial.exists():
        shutil.rmtree(partial)                      # a leftover of an earlier run: the sample is complete
    prefix = final.relative_to(out).as_posix() + "/"
    bad = [f for f in (record or {}).get("files", []) if _file_problem(out, f)]
    if record is None or any(f["path"] == prefix + "manifest.json" for f in bad):
        shutil.rmtree(final)
        return
    os.rename(final, partial)
    (partial / SAMPLE_FILE).unlink(missing_ok=True)
    ledger = FileLedger(partial)
    frames: dict[int, dict] = {}
    for f in record["files"]:
        if f["frame"] >= 0:
            rel = f["path"][len(prefix):] if f["path"].startswith(prefix) else f"../../{f['path']}"
            frames.setdefault(f["frame"], {})[rel] = {"bytes": f["bytes"], "sha256": f["sha256"]}
    for i in sorted(frames):
        ledger.record(i, list(frames[i]), frames[i])
    for f in bad:
        if f["frame"] < 0 and f["path"].startswith(prefix):
            (partial / f["path"][len(prefix):]).unlink(missing_ok=True)
            if f.get("link") and _file_problem(out, {**f, "path": f["link"]}):
                (out / f["link"]).unlink(missing_ok=True)      # the pooled copy (same inode) is damaged too


def _repair_pool(out: Path, parts: dict[int, _Part]) -> None:
    """Hard-link a missing or damaged pooled mesh again from an intact sample's copy."""
    seen = set()
    for part in (parts[k] for k in sorted(parts)):
        for link, (sha, size) in part.pool.items():
            if link in seen or _file_problem(out, {"path": link, "sha256": sha, "bytes": size}) is None:
                seen.add(link)
                continue
            seen.add(link)
            source = next(out / f["path"] for f in part.files.to_pylist() if f.get("link") == link)
            with atomic_path(out / link) as tmp:
                tmp.unlink()
                os.link(source, tmp)


def _write_parquet(path: Path, tables: list) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pa.concat_tables(tables, promote_options="default")
    with atomic_path(path) as tmp:
        pq.write_table(table, tmp)


def _write_index(out: Path, parts: dict[int, _Part]) -> dict:
    if not parts:
        return {"frames": 0, "lit_rows": 0, "bytes": {}}
    import pyarrow as pa

    keys = sorted(parts)
    pool = {}
    for k in keys:
        pool.update(parts[k].pool)
    shared = pa.Table.from_pylist([{"path": p, "sha256": s, "bytes": b, "sample": -1, "frame": -1,
                                    "link": None} for p, (s, b) in sorted(pool.items())])
    _write_parquet(out / INDEX_FILE, [parts[k].rows for k in keys])
    _write_parquet(out / FILES_FILE, [parts[k].files for k in keys] + ([shared] if pool else []))
    kinds = {kind: sum(parts[k].bytes[kind] for k in keys) for kind in ("frames", "truth", "other")}
    kinds["truth"] += sum(b for _, b in pool.values())
    return {"frames": sum(parts[k].frames for k in keys), "lit_rows": sum(parts[k].lit_rows for k in keys),
            "bytes": {**kinds, "total": sum(kinds.values())}}


# ------------------------------------------------------------------ the job


def make_dataset(spec: DatasetSpec, out, *, storage: str = "png", workers: int = 1,
                 scheduler: str | None = None, retries: int = 1, connect_timeout_s: float = 10.0,
                 progress: ProgressCallback | None = None,
                 warn: Callable[[str], None] | None = None) -> MakeResult:
    """Make (or resume) the dataset of ``spec`` in ``out``.

    Parameters
    ----------
    spec : DatasetSpec
        The parsed spec (:func:`sim.dataset.spec.load_spec`).
    out : path
        The dataset folder (created).
    storage : {"png", "zarr"}
        16-bit PNG frame folders, or one Zarr store (Blosc/zstd, bit-shuffle, one frame
        per chunk).
    workers : int
        1 = in this process; N ≥ 2 = a local Dask cluster of N spawned workers.
    scheduler : str, optional
        Address of a running Dask scheduler to use instead.
    retries : int
        How often a failed sample is tried again before it is recorded as failed.
    connect_timeout_s : float
        How long to wait for ``scheduler`` [s].
    progress : ProgressCallback, optional
        ``progress(done, total)`` over all frames of the spec.
    warn : callable, optional
        Receives warnings, one line each (default: stderr).

    Returns
    -------
    MakeResult
        Counts, failures and timings.

    Raises
    ------
    DatasetError
        A job too large for this machine (:func:`size_dataset`), a bad storage, a drawn rig
        that is impossible, an unwritable output folder, a folder holding another dataset.
    EngineError
        A cluster that cannot start or a scheduler that cannot be reached.
    """
    warn = warn or (lambda msg: print(f"warning: {msg}", file=sys.stderr))
    out = Path(out)
    size_dataset(spec, out, workers if isinstance(workers, int) and workers > 1 else 1)   # before planning
    plans = _plans(spec, storage)
    identity = _identity(spec, storage)
    # checked, created, locked (one `make` per dataset folder at a time): sim.jobfolder
    with open_job(out, DATASET_JOB, {k: identity[k] for k in _IDENTITY}, warn) as old:
        return _make_locked(spec, out, plans, identity, old, storage, workers, scheduler, retries,
                            connect_timeout_s, progress, warn)


def _make_locked(spec, out, plans, identity, old, storage, workers, scheduler, retries, connect_timeout_s,
                 progress, warn) -> MakeResult:
    if old is not None and old.get("generator", {}).get("versions") != generator_info()["versions"]:
        warn("the dataset was started with other library versions; frames made now may differ")
    t0 = time.perf_counter()
    with Engine(workers=workers, scheduler=scheduler, timeout_s=connect_timeout_s,
                progress=progress) as engine:
        try:
            (out / "samples").mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise DatasetError(f"output folder {str(out)!r} is not writable: {exc.strerror or exc}") from None
        remove_temporaries(out, ("samples",), deep=(ZARR_STORE,))
        offsets = _create_store(out, plans, spec.name) if storage == "zarr" else [0] * len(plans)
        info = _info(spec, identity, plans, storage, engine)
        write_json_atomic(out / META_FILE, info)
        result = MakeResult(out, spec.samples)
        records = _load_parts(out, plans, warn)
        try:
            _run(engine, plans, offsets, out, storage, records, result, retries, warn)
        except KeyboardInterrupt:
            _finish(out, spec, info, plans, records, result, storage, time.perf_counter() - t0)
            raise
    _finish(out, spec, info, plans, records, result, storage, time.perf_counter() - t0)
    return result


def _info(spec, identity, plans, storage, engine) -> dict:
    sensor = plans[0].rig["sensor"]
    info = {**identity, "complete": False, "name": spec.name, "description": spec.description,
            "spec_sha256": spec.sha256(), "generator": generator_info(),
            "adc_bits": sensor["adc_bits"],
            "planned": {"samples": spec.samples, "frames": sum(p.frames for p in plans)},
            "engine": {"workers": engine.workers, "scheduler": engine.scheduler}}
    if storage == "zarr":
        info["zarr"] = {"store": ZARR_STORE, "codec": {"blosc": ZARR_CODEC},
                        "arrays": ["frames", *TRUTH_ARRAYS], "chunks": "one frame per chunk",
                        "frame_shape": [sensor["rows"], sensor["columns"]]}
    return info


class _Job:
    """Picklable ``plan → SampleResult`` for the engine."""

    def __init__(self, out: str, storage: str, offsets: list[int]) -> None:
        self.out, self.storage, self.offsets = out, storage, offsets

    def __call__(self, plan: SamplePlan, progress=None, threads=None):
        layout = ZarrLayout(self.offsets[plan.index], ZARR_CODEC) if self.storage == "zarr" else None
        return make_sample(plan, self.out, self.storage, layout, progress=progress, threads=threads)


def _run(engine, plans, offsets, out, storage, records, result, retries, warn) -> None:
    last_flush = [time.monotonic()]

    def done(plan, res) -> None:
        records[plan.index] = _part(out, plan.index, res.record)
        result.samples_made += 1
        result.frames_rendered += res.frames_rendered
        for k, v in res.seconds.items():
            result.seconds[k] = result.seconds.get(k, 0.0) + v
        if time.monotonic() - last_flush[0] > _FLUSH_S:
            _write_index(out, records)
            last_flush[0] = time.monotonic()

    result.failures = run_with_retries(
        engine, _Job(str(out), storage, offsets), [p for p in plans if p.index not in records], noun="sample",
        key=lambda p: f"sample-{p.index:06d}", size=lambda p: p.frames,
        base=sum(p.frames for p in plans if p.index in records), grand_total=sum(p.frames for p in plans),
        retries=retries, warn=warn, on_done=done)


def _finish(out, spec, info, plans, records, result, storage, wall_s) -> None:
    counts = _write_index(out, records)
    result.samples_done = len(records)
    result.frames = counts["frames"]
    result.seconds["wall"] = wall_s
    final = dict(info, complete=result.complete,
                 counts={"samples": spec.samples, "samples_done": len(records),
                         "samples_failed": len(result.failures), "frames": counts["frames"],
                         "lit_rows": counts.get("lit_rows", 0)},
                 bytes=counts["bytes"], failures=result.failures,
                 last_run={"wall_s": round(wall_s, 3), "samples_made": result.samples_made,
                           "frames_rendered": result.frames_rendered})
    write_json_atomic(out / META_FILE, final)
    write_text_atomic(out / CARD_FILE, _card(spec, final, storage))
    if result.complete:
        partial_root = out / "samples"
        for p in partial_root.glob(".*.partial"):
            shutil.rmtree(p, ignore_errors=True)


def _card(spec: DatasetSpec, info: dict, storage: str) -> str:
    c, b = info["counts"], info.get("bytes", {})
    lines = [f"# {spec.name}", "", spec.description or "A regression dataset made by "
             "`scheimpflug dataset make`.", "",
             f"- {c['samples_done']} of {c['samples']} samples, {c['frames']} frames, "
             f"{c['lit_rows']} rows with a stripe; {'complete' if info['complete'] else 'INCOMPLETE'}",
             f"- storage: {storage} ({_STORAGE_TEXT[storage]})",
             f"- size: {b.get('total', 0) / 1e6:.1f} MB (frames {b.get('frames', 0) / 1e6:.1f} MB, "
             f"truth {b.get('truth', 0) / 1e6:.1f} MB)",
             f"- base seed {spec.seed}; sample k's seed derives from (seed, k) only",
             f"- generator: scheimpflug {info['generator']['versions'].get('scheimpflug')}, "
             f"mitsuba {info['generator']['versions'].get('mitsuba')}, "
             f"drjit {info['generator']['versions'].get('drjit')}", ""]
    if info["failures"]:
        lines += ["## Failed samples", ""] + [f"- {f['sample']}: {f['error']}" for f in info["failures"]] + [""]
    lines += ["## Spec", "", "```json", json.dumps(spec.raw, indent=2), "```", "",
              "## Reading it", "", "```python", "from scheimpflug.dataset import open_dataset",
              "ds = open_dataset('.')", "frame = ds[0]            # .image, .truth, .meta",
              "metal = ds.filter(materials='metal')", "```", "",
              "Files: `dataset.json` (spec, versions, counts), `index.parquet` (one row per frame), "
              "`files.parquet` (every file with its SHA-256; `scheimpflug dataset verify` checks "
              "them), `samples/NNNNNN/` (manifest, truth" + (", frames" if storage == "png" else "")
              + ")" + (", `frames.zarr/`" if storage == "zarr" else "") + ".", ""]
    return "\n".join(lines)
