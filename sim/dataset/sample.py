"""Make one sample of a dataset: a frame folder (PNG) or frames in the Zarr store, with truth.

A sample is made in ``samples/.NNNNNN.partial/`` and renamed to ``samples/NNNNNN/``
when every frame, the manifest and ``sample.json`` are written: a sample folder
without the ``.partial`` suffix is complete.  Inside the partial folder every file
is written atomically and a frame counts as done when its last file exists (PNG:
the frame after its truth; Zarr: the frame chunk after the truth chunks), so a
killed run loses at most the frames in flight; rerunning resumes the partial
folder frame by frame (the manifest must describe the same sample, see
:func:`sim.writer.prepare_folder`).  While a sample is partial, the size and SHA-256
of every finished frame's files go to the partial folder's ``checksums.jsonl``
(:class:`scheimpflug.io.folder.FileLedger`, as in a render's frame folder); a
resumed sample skips only the frames whose files match their record and renders
the others again (a frame truncated or altered after a kill is never kept).
A complete sample's record is its ``sample.json``; the ledger is removed then.

The frame loop (:func:`make_sample`) renders, adds sensor noise and computes the
per-row truth (:class:`sim.truth.SceneTruth`) on the calling thread — these use
the posed Mitsuba scene — and hands encoding, hashing and writing to one
background thread (PNG through libdeflate, Zarr chunks through Blosc, both
release the GIL), at most two frames behind.  The Mitsuba scene and the truth's
per-scene data are cached per process and reused by the next sample with the
same scene, rig and render settings.

``sample.json`` (deterministic: no times, no host names) holds the sample's index
rows and its files with their SHA-256 (:mod:`scheimpflug.dataset`).  Truth meshes
are stored once per content in ``meshes/SHA256.ply`` and hard-linked into the
samples' ``truth/`` folders (a file's ``link`` in the ledger names its pool file).
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import os
import shutil
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from scheimpflug.callbacks import ProgressCallback, report
from scheimpflug.dataset import TRUTH_ARRAYS, ZARR_STORE, file_sha256
from scheimpflug.errors import RenderError
from scheimpflug.io.atomic import atomic_path, finite_json, write_json_atomic
from scheimpflug.io.folder import LEDGER_NAME, FileLedger

from ..scenarios import Scenario, build_scenario, reuse_assemblies
from ..sensor import SensorModel, apply_sensor, frame_rng
from ..stages import invert
from ..threads import configure_threads
from ..truth import SceneTruth, pixel_directions, pixel_truth
from ..writer import (
    _scene_truth_files,
    build_manifest,
    encode_npz,
    encode_png16,
    frame_file_names,
    frame_paths,
    generator_info,
    index_ranges,
    prepare_folder,
)
from .spec import SamplePlan

__all__ = ["SampleResult", "ZarrLayout", "configure_threads", "make_sample", "sample_folder"]

SAMPLE_FILE = "sample.json"


def sample_folder(root: Path, k: int, partial: bool = False) -> Path:
    """Folder of sample ``k`` in the dataset ``root`` (``samples/NNNNNN`` or its partial twin).

    Parameters
    ----------
    root : Path
        The dataset folder.
    k : int
        Sample number.
    partial : bool
        The in-progress folder ``samples/.NNNNNN.partial`` instead.

    Returns
    -------
    Path
        The folder (not created).
    """
    name = f".{k:06d}.partial" if partial else f"{k:06d}"
    return Path(root) / "samples" / name


@dataclass(frozen=True)
class ZarrLayout:
    """Where a sample's frames go in the Zarr store.

    Parameters
    ----------
    offset : int
        Position of the sample's frame 0 in the store's arrays [-].
    codec : dict
        Blosc settings (``cname``, ``clevel``, ``shuffle``) of every array.
    """

    offset: int
    codec: dict


@dataclass
class SampleResult:
    """What making a sample produced.

    Parameters
    ----------
    sample : int
        Sample number.
    record : dict
        ``sample.json`` (index rows and files).
    frames_rendered : int
        Frames rendered in this run (the others were done before) [-].
    seconds : dict
        Time per stage [s]: ``setup``, ``render``, ``noise``, ``truth``, ``write`` (background
        thread), ``wall``; CPU time of this process (all its threads) [s]: ``cpu_setup``,
        ``cpu_loop`` (the frame loop), ``cpu_finish`` (manifest, hashes, meshes, rename).
    """

    sample: int
    record: dict
    frames_rendered: int = 0
    seconds: dict = field(default_factory=dict)


# ------------------------------------------------------------------ per-process state

_CACHE: dict = {}
_ASSEMBLIES: dict = {}      # the last part built (sim.scenarios.reuse_assemblies)
_MESH: dict = {}            # the last sample's pooled truth mesh (_link_pooled_mesh)


def _twin_key(plan: SamplePlan) -> str:
    frame_keys = {"steps", "step_mm", "start_mm", "step_deg", "frames"}
    scene_seed = plan.seed if plan.part.endswith(".toml") else None
    return json.dumps({"kind": plan.kind, "options": {k: v for k, v in plan.options.items()
                                                      if k not in frame_keys},
                       "scene_seed": scene_seed, "material": plan.material,
                       "materials": plan.materials, "rig": plan.rig, "spp": plan.spp}, sort_keys=True)


def _twin(plan: SamplePlan, rig, scenario: Scenario, warn):
    """The Mitsuba twin and scene truth of ``scenario``, reused from the previous sample if equal."""
    import warnings

    from ..materials import MaterialSettings
    from ..writer import MitsubaTwin

    key = _twin_key(plan)
    if _CACHE.get("key") != key:
        _CACHE.clear()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            twin = MitsubaTwin(rig, scenario.assembly, spp=plan.spp,
                               materials=MaterialSettings(**plan.materials) if plan.materials else None)
        for w in caught:
            warn(str(w.message))
        mesh = scenario.assembly.combined_mesh()
        truth = SceneTruth(rig, np.asarray(mesh.vertices, dtype=np.float64),
                           np.asarray(mesh.faces, dtype=np.int64), scenario.assembly.face_object_ids())
        _CACHE.update(key=key, twin=twin, truth=truth)
    twin = _CACHE["twin"]
    twin._posed = None
    return twin, _CACHE["truth"]


# ------------------------------------------------------------------ scenario


def _scenario(plan: SamplePlan, rig) -> Scenario:
    with reuse_assemblies(_ASSEMBLIES):          # the next sample of the same part reuses its mesh
        scenario = build_scenario(plan.kind, rig, seed=plan.seed,
                                  truth_pixels_every=plan.truth_pixels_every, **plan.options)
    if plan.material:
        from scenes.part import Assembly

        parts = tuple(dataclasses.replace(p, material=plan.material) for p in scenario.assembly.parts)
        params = dict(scenario.params, material_override=plan.material)
        if "parts" in params:
            params["parts"] = [dict(p, material=plan.material) for p in params["parts"]]
        scenario = dataclasses.replace(scenario, params=params,
                                       assembly=Assembly(name=scenario.assembly.name, parts=parts))
    if len(scenario.frames) != plan.frames:
        raise RenderError(f"sample {plan.index}: the scenario has {len(scenario.frames)} frames, "
                          f"the plan {plan.frames} (spec and sim.scenarios disagree)")
    return scenario


def _object_materials(scenario: Scenario) -> str:
    return ";".join(f"{p.object_id}:{p.material}" for p in scenario.assembly.parts)


# ------------------------------------------------------------------ sinks


def _sha(data) -> str:
    return hashlib.sha256(data).hexdigest()


def _write_atomic(path: Path, data) -> None:
    """Write ``data`` to a temporary name beside ``path``, then rename it over ``path``.

    The frame loop's lean :func:`scheimpflug.io.atomic.atomic_path` (seven files per Zarr
    frame): one name per process and thread instead of ``mkstemp``, the mode from the
    umask at ``open``, the folder created only when missing.  The temporary name
    (``.NAME.tmpPID-THREAD``) matches the patterns that resuming removes.
    """
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}-{threading.get_ident()}")
    flags = os.O_WRONLY | os.O_CREAT | os.O_TRUNC | getattr(os, "O_BINARY", 0)
    try:
        fd = os.open(tmp, flags, 0o666)
    except FileNotFoundError:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(tmp, flags, 0o666)
    try:
        with open(fd, "wb", closefd=True) as fh:
            fh.write(data)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


class _Ledgered:
    """What both sinks share: the partial folder's ledger of finished frames (module docstring)."""

    ledger: FileLedger

    def ledger_files(self, index: int) -> list[str]:
        """The frame's files relative to the partial folder, its last (the one marking it done) last."""
        raise NotImplementedError

    def root_path(self, rel: str) -> str:
        """A ledger path (relative to the partial folder) as the index names it (from the dataset root)."""
        raise NotImplementedError

    def _record(self, index: int, files: dict) -> None:
        """Append the frame's files (``(path from the dataset root, sha256, bytes)``) to the ledger."""
        rels = self.ledger_files(index)
        items = [files["file"], files["truth_file"], *files["other"]]
        by_path = {p: {"bytes": int(b), "sha256": h} for p, h, b in items}
        self.ledger.record(index, rels, {rel: by_path[self.root_path(rel)] for rel in rels})

    def done(self, indices, warn) -> set[int]:
        """Frames whose files all match their record; warns about present frames that do not."""
        done, bad = set(), {}
        for i in indices:
            rels = self.ledger_files(i)
            if not (self.ledger.folder / rels[-1]).exists():
                continue
            reason = self.ledger.mismatch(i, rels)
            if reason is None:
                done.add(i)
            else:
                bad[i] = reason
        if bad:
            first = min(bad)
            warn(f"rendering again {len(bad)} frame(s) whose files do not match {LEDGER_NAME}: "
                 f"{index_ranges(bad)} (frame {first}: {bad[first]})")
        return done


class _PngSink(_Ledgered):
    """Frames as 16-bit PNG and truth as ``.npz`` in the sample's frame folder."""

    def __init__(self, folder: Path, rel: str) -> None:
        self.folder, self.rel = folder, rel
        self.ledger = FileLedger(folder)

    def ledger_files(self, index: int) -> list[str]:
        return frame_file_names(index)[::-1]       # truth, then the PNG (written last)

    def root_path(self, rel: str) -> str:
        return f"{self.rel}/{rel}"

    def write(self, index: int, image: np.ndarray, truth: dict) -> dict:
        png_path, npz_path = frame_paths(self.folder, index)
        npz, png = encode_npz(truth), encode_png16(image)
        _write_atomic(npz_path, npz)
        _write_atomic(png_path, png)               # last: its presence marks the frame done
        files = self._files(index, _sha(png), len(png), _sha(npz), len(npz))
        self._record(index, files)
        return files

    def read(self, index: int) -> tuple[dict, dict]:
        png_path, npz_path = frame_paths(self.folder, index)
        with np.load(npz_path) as z:
            truth = {k: z[k] for k in z.files}
        return truth, self._files(index, file_sha256(png_path), png_path.stat().st_size,
                                  file_sha256(npz_path), npz_path.stat().st_size)

    def _files(self, index, png_sha, png_bytes, npz_sha, npz_bytes) -> dict:
        png_rel, npz_rel = (p.relative_to(self.folder).as_posix() for p in frame_paths(self.folder, index))
        return {"file": (f"{self.rel}/{png_rel}", png_sha, png_bytes),
                "truth_file": (f"{self.rel}/{npz_rel}", npz_sha, npz_bytes), "other": []}


class _ZarrSink(_Ledgered):
    """Frames and per-row truth as chunks of the dataset's Zarr store (one frame per chunk).

    Chunks are encoded here with numcodecs' Blosc — byte for byte what Zarr writes for
    the store's codec (a test checks it) — and written atomically under Zarr's chunk keys.
    The ledger is the partial sample folder's; its paths lead to the store (``../../frames.zarr/…``).
    """

    def __init__(self, root: Path, layout: ZarrLayout, partial: Path) -> None:
        import numcodecs

        self.root, self.offset = Path(root), layout.offset
        self.ledger = FileLedger(partial)
        shuffle = {"bitshuffle": numcodecs.Blosc.BITSHUFFLE, "shuffle": numcodecs.Blosc.SHUFFLE,
                   "noshuffle": numcodecs.Blosc.NOSHUFFLE}[layout.codec["shuffle"]]
        self.codec = numcodecs.Blosc(cname=layout.codec["cname"], clevel=layout.codec["clevel"],
                                     shuffle=shuffle, blocksize=layout.codec.get("blocksize", 0))

    def _rel(self, name: str, index: int) -> str:
        g = self.offset + index
        tail = {"frames": ".0.0", "stripe_point_mm": ".0.0"}.get(name, ".0")
        return f"{ZARR_STORE}/{name}/c.{g}{tail}"

    def ledger_files(self, index: int) -> list[str]:
        return [f"../../{self._rel(name, index)}" for name in (*TRUTH_ARRAYS, "frames")]

    def root_path(self, rel: str) -> str:
        return rel.removeprefix("../../")

    def write(self, index: int, image: np.ndarray, truth: dict) -> dict:
        files = {}
        for name in (*TRUTH_ARRAYS, "frames"):          # the frame last: it marks the frame done
            dtype = TRUTH_ARRAYS[name][0] if name != "frames" else "uint16"
            value = image if name == "frames" else truth[name]
            data = self.codec.encode(np.ascontiguousarray(value, dtype=dtype))
            rel = self._rel(name, index)
            _write_atomic(self.root / rel, data)
            files[name] = (rel, _sha(data), len(data))
        packed = self._pack(files)
        self._record(index, packed)
        return packed

    def read(self, index: int) -> tuple[dict, dict]:
        files, truth = {}, {}
        for name in (*TRUTH_ARRAYS, "frames"):
            rel = self._rel(name, index)
            data = (self.root / rel).read_bytes()
            files[name] = (rel, _sha(data), len(data))
            if name != "frames":
                dtype, shape, _ = TRUTH_ARRAYS[name]
                flat = np.frombuffer(self.codec.decode(data), dtype=dtype)
                truth[name] = flat.reshape(-1, *shape) if shape else flat
        return truth, self._pack(files)

    @staticmethod
    def _pack(files: dict) -> dict:
        return {"file": files["frames"], "truth_file": files["stripe_u"],
                "other": [v for k, v in files.items() if k not in ("frames", "stripe_u")]}


# ------------------------------------------------------------------ records


def _truth_stats(truth: dict) -> dict:
    u = truth["stripe_u"]
    lit = np.isfinite(u)

    def agg(fn, values):
        v = values[np.isfinite(values)]
        return float(fn(v)) if v.size else float("nan")

    return {"lit_rows": int(lit.sum()), "multi_rows": int((truth["stripe_count"] > 1).sum()),
            "u_min_px": agg(np.min, u), "u_max_px": agg(np.max, u),
            "distance_min_mm": agg(np.min, truth["stripe_distance_mm"]),
            "distance_max_mm": agg(np.max, truth["stripe_distance_mm"]),
            "incidence_mean_deg": agg(np.mean, truth["stripe_incidence_deg"])}


def _drawn_value(v):
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else str(v)


def _row(plan: SamplePlan, scenario: Scenario, rig, frame, files: dict, truth: dict,
         storage: str, offset: int) -> dict:
    mats = sorted({p.material for p in scenario.assembly.parts})
    row = {"sample": plan.index, "frame": frame.index,
           "file": files["file"][0], "sha256": files["file"][1],
           "truth_file": files["truth_file"][0], "truth_sha256": files["truth_file"][1],
           "scenario": plan.kind,
           "stage_mm": float(frame.stage_mm) if frame.stage_mm is not None else float("nan"),
           "angle_deg": float(frame.angle_deg) if frame.angle_deg is not None else float("nan"),
           "seed": int(frame.seed), "sample_seed": int(plan.seed), "part": plan.part,
           "materials": ",".join(mats), "object_materials": _object_materials(scenario),
           "binning": plan.binning, "rows": rig.sensor.rows, "columns": rig.sensor.columns,
           "zarr_index": offset + frame.index if storage == "zarr" else -1,
           **_truth_stats(truth)}
    row.update({k: _drawn_value(v) for k, v in sorted(plan.drawn.items())})
    return row


def _file_entries(files: dict, k: int, frame: int) -> list[dict]:
    items = [files["file"], files["truth_file"], *files["other"]]
    return [{"path": p, "sha256": s, "bytes": int(b), "sample": k, "frame": frame, "link": None}
            for p, s, b in items]


# ------------------------------------------------------------------ the sample


def make_sample(plan: SamplePlan, root: str | os.PathLike, storage: str = "png",
                zarr: ZarrLayout | None = None, progress: ProgressCallback | None = None,
                warn: Callable[[str], None] | None = None, threads: int | None = None) -> SampleResult:
    """Make sample ``plan.index`` of the dataset in ``root`` (resuming its partial folder).

    Parameters
    ----------
    plan : SamplePlan
        What the sample draws (:func:`sim.dataset.spec.plan_sample`).
    root : path
        The dataset folder (``samples/`` and, for Zarr, ``frames.zarr`` exist).
    storage : {"png", "zarr"}
        Where frames and truth go.
    zarr : ZarrLayout, optional
        Required for ``storage="zarr"``.
    progress : ProgressCallback, optional
        ``progress(done, total)`` over the sample's frames.
    warn : callable, optional
        Receives warnings (one line each); default: ignored.
    threads : int, optional
        Size this process's thread pools first (:func:`configure_threads`).

    Returns
    -------
    SampleResult
        The sample's record and timings.

    Raises
    ------
    RenderError
        When the sample cannot be rendered or written.
    ScheimpflugError
        A bad part, rig or scenario option (e.g. a part file that does not exist).
    """
    if threads:
        configure_threads(threads)
    warn = warn or (lambda msg: None)
    root = Path(root)
    final = sample_folder(root, plan.index)
    if (final / SAMPLE_FILE).is_file():
        return SampleResult(plan.index, json.loads((final / SAMPLE_FILE).read_text("utf-8")))
    if final.exists():
        raise RenderError(f"sample folder {str(final)!r} exists but has no {SAMPLE_FILE} (it was not "
                          "made by this program or was damaged): delete it and rerun")
    t0, c0 = time.perf_counter(), time.process_time()
    rig = plan.build_rig()
    scenario = _scenario(plan, rig)
    twin, scene_truth = _twin(plan, rig, scenario, warn)
    partial = sample_folder(root, plan.index, partial=True)
    manifest = _manifest(plan, rig, scenario, twin, storage, zarr)
    prepare_folder(partial, manifest)
    _link_pooled_mesh(root, partial, scenario)
    _scene_truth_files(partial, rig, scenario)
    sink = _PngSink(partial, final.relative_to(root).as_posix()) if storage == "png" \
        else _ZarrSink(root, zarr, partial)
    seconds = {"setup": time.perf_counter() - t0, "render": 0.0, "noise": 0.0, "truth": 0.0, "write": 0.0,
               "cpu_setup": time.process_time() - c0}
    c1 = time.process_time()
    done = sink.done([f.index for f in scenario.frames], warn)
    results = _frame_loop(plan, rig, scenario, twin, scene_truth, sink,
                          [f for f in scenario.frames if f.index not in done], seconds, progress,
                          len(done))
    seconds["cpu_loop"] = time.process_time() - c1
    for f in scenario.frames:
        if f.index in done:
            results[f.index] = sink.read(f.index)
    c2 = time.process_time()
    record = _finish(plan, root, partial, final, manifest, scenario, rig, results, storage,
                     zarr.offset if zarr else 0)
    _remember_pooled_mesh(record, final.relative_to(root).as_posix(), scenario)
    seconds["cpu_finish"] = time.process_time() - c2
    seconds["wall"] = time.perf_counter() - t0
    return SampleResult(plan.index, record, len(scenario.frames) - len(done), seconds)


def _manifest(plan, rig, scenario, twin, storage, zarr) -> dict:
    manifest = build_manifest(rig, scenario, plan.seed, twin.spp, twin.variant, generator_info(),
                              twin.describe())
    manifest["dataset_sample"] = {"sample": plan.index, "drawn": plan.drawn}
    if storage == "zarr":
        manifest["storage"] = "zarr"
        for entry, f in zip(manifest["frames"], scenario.frames):
            g = zarr.offset + f.index
            entry["file"] = f"../../{ZARR_STORE}/frames/c.{g}.0.0"
            entry["truth"] = f"../../{ZARR_STORE} (index {g})"
            entry["zarr_index"] = g
    return manifest


def _frame_loop(plan, rig, scenario, twin, scene_truth, sink, todo, seconds, progress,
                n_done) -> dict:
    """Render, noise and truth here; encode and write on one background thread (one frame behind).

    The noise stays here: Dr.Jit's kernels of two threads sharing a worker's one-thread
    pool measured slower (2 workers, Zarr: 64 against 50–58 ms CPU per frame).
    """
    model = SensorModel.from_rig(rig)
    total = len(scenario.frames)
    report(progress, n_done, total)
    results, pending = {}, []
    directions = None

    def finish(fut):
        nonlocal n_done
        index, files, truth, dt = fut.result()
        results[index] = (truth, files)
        seconds["write"] += dt
        n_done += 1
        report(progress, n_done, total)

    with ThreadPoolExecutor(max_workers=1) as pool:
        for frame in todo:
            t0 = time.perf_counter()
            electrons = twin.render(frame)
            t1 = time.perf_counter()
            image = apply_sensor(electrons, model, frame_rng(frame.seed, 0), None, frame.exposure_factor)
            t2 = time.perf_counter()
            truth, extra = scene_truth.frame(frame.rig_from_part, frame.ref_from_part, twin.caster(frame),
                                             frame.rig_from_laser)
            arrays = {**truth.arrays(), **extra}
            if scenario.wants_pixel_truth(frame.index):
                directions = pixel_directions(rig) if directions is None else directions
                ref_from_rig = frame.ref_from_part @ invert(frame.rig_from_part)
                arrays["point_mm"], arrays["object_id"] = pixel_truth(rig, twin.caster(frame),
                                                                      ref_from_rig, directions)
            t3 = time.perf_counter()
            seconds["render"] += t1 - t0
            seconds["noise"] += t2 - t1
            seconds["truth"] += t3 - t2
            while pending:               # the frame before (written meanwhile) first: a
                finish(pending.pop(0))   # failure stops the loop before this frame is written
            pending.append(pool.submit(_write_one, sink, frame.index, image, arrays))
        for fut in pending:
            finish(fut)
    return results


def _write_one(sink, index, image, arrays):
    t0 = time.perf_counter()
    files = sink.write(index, image, arrays)
    return index, files, arrays, time.perf_counter() - t0


def _finish(plan, root, partial, final, manifest, scenario, rig, results, storage, offset) -> dict:
    rows, files = [], []
    no_stripe = []
    for f in scenario.frames:
        truth, ffiles = results[f.index]
        rows.append(_row(plan, scenario, rig, f, ffiles, truth, storage, offset))
        files += _file_entries(ffiles, plan.index, f.index)
        if not np.isfinite(truth["stripe_u"]).any():
            no_stripe.append(f.index)
    write_json_atomic(partial / "manifest.json", dict(manifest, complete=True,
                                                      frames_without_stripe=no_stripe))
    sha = {p: file_sha256(p) for p in sorted((partial / "truth").glob("*.ply"))}
    shared = {p.name: _share(root, p, h) for p, h in sha.items()}
    rel = final.relative_to(root).as_posix()
    for p in sorted(partial.rglob("*")):
        if p.is_file() and p.name not in (SAMPLE_FILE, LEDGER_NAME) and p.parent != partial / "frames" \
                and not (p.parent == partial / "truth" and p.suffix == ".npz"):
            link = shared.get(p.name) if p.parent == partial / "truth" else None
            files.append({"path": f"{rel}/{p.relative_to(partial).as_posix()}",
                          "sha256": sha.get(p) or file_sha256(p), "bytes": p.stat().st_size,
                          "sample": plan.index, "frame": -1, "link": link})
    record = {"sample": plan.index, "seed": plan.seed, "kind": plan.kind, "part": plan.part,
              "frames": len(scenario.frames), "drawn": plan.drawn,
              "parts": [{"object_id": p.object_id, "name": p.name, "material": p.material}
                        for p in scenario.assembly.parts],
              "frames_without_stripe": no_stripe, "rows": rows, "files": files}
    write_json_atomic(partial / SAMPLE_FILE, finite_json(record))
    _commit(partial, final)
    (final / LEDGER_NAME).unlink(missing_ok=True)      # sample.json is the complete sample's record
    return json.loads((final / SAMPLE_FILE).read_text("utf-8"))


MESH_POOL = "meshes"


def _share(root: Path, path: Path, sha256: str) -> str | None:
    """Make ``path`` a hard link of the identical file ``root/meshes/SHA256.ply``; return that.

    Samples of the same part and pose share one copy of its (often 30 MB) truth mesh on
    disk; every sample folder still holds its ``truth/mesh.ply``.  Returns the pool file
    relative to ``root``, or None when hard links are not possible (the file stays a copy).
    """
    pool = root / MESH_POOL
    target = pool / f"{sha256}{path.suffix}"
    try:
        pool.mkdir(exist_ok=True)
        for src, dst in ((path, target), (target, path)):
            if dst == target and target.exists():
                continue
            if dst == path and os.path.samefile(target, path):
                break
            with atomic_path(dst) as tmp:
                tmp.unlink()
                os.link(src, tmp)
    except OSError:
        return None
    return target.relative_to(root).as_posix()


def _link_pooled_mesh(root: Path, partial: Path, scenario: Scenario) -> None:
    """Hard-link the previous sample's pooled ``truth/mesh.ply`` when this sample's is the same.

    The same assembly object (:func:`sim.scenarios.reuse_assemblies`) in the same pose
    writes the same bytes; linking the pool file saves writing ≈ 30 MB per sample.
    Anything unusual (no pool file, no hard links) leaves the mesh to be written.
    """
    path = partial / "truth" / "mesh.ply"
    if path.exists() or _MESH.get("assembly") is not scenario.assembly \
            or _MESH.get("pose") != np.asarray(scenario.mesh_ref_from_part, dtype=np.float64).tobytes():
        return
    try:
        with atomic_path(path) as tmp:
            tmp.unlink()
            os.link(root / _MESH["pool"], tmp)
    except OSError:
        return


def _remember_pooled_mesh(record: dict, rel: str, scenario: Scenario) -> None:
    link = next((f["link"] for f in record["files"] if f["path"] == f"{rel}/truth/mesh.ply"), None)
    _MESH.clear()
    if link:
        _MESH.update(assembly=scenario.assembly, pool=link,
                     pose=np.asarray(scenario.mesh_ref_from_part, dtype=np.float64).tobytes())


def _commit(partial: Path, final: Path) -> None:
    """Rename the finished partial folder into place (the sample's commit)."""
    try:
        os.rename(partial, final)
    except OSError:
        if (final / SAMPLE_FILE).is_file():       # made meanwhile by a duplicate task
            shutil.rmtree(partial, ignore_errors=True)
            return
        raise
