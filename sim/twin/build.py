"""``twin build``: the twin of the instrument that took a real rotary scan, step by step, resumable.

Steps, each recorded in ``TWIN_DIR/twin.json`` with the key of its inputs (hashes of the
scan's manifest, the calibration file, the files of earlier steps, the options): a rerun
skips a step whose key is the same and whose output files are there with the hashes it
recorded, and redoes it otherwise.

1. ``regions``: the scan's still and moving ranges (:func:`scheimpflug.still_points.still_regions`)
   and its housing split (:func:`scheimpflug.still_points.separate_housing`), kept in ``twin.json``;
2. ``table``: the turntable's top (height along the axis, lean, wobble) fitted from the still table
   line (:func:`scheimpflug.turntable_top.table_top_of_folder`, as ``rig housing --table``) and the
   disc's radius where that line turns down its rim (:func:`scheimpflug.turntable_top.disc_radius_mm`),
   as ``[stage]`` keys; none when the scan shows no table line or the rig has no disc;
3. ``rig``: ``rig.toml`` by ``rig from-calibration`` (:func:`scheimpflug.model.instrument.rig_from_instrument`)
   with the table's keys;
4. ``housing``: ``housing.toml``, one board per straight still segment of each wall region
   (:func:`scheimpflug.fixed_lines.wall_board`, as ``rig housing``); the table is the rig's disc, not a
   wall.  A scan with no still wall has no housing: said, not an error;
5. ``part``: ``part.ply`` from the scan's part points (:func:`sim.twin.part.part_model`);
6. ``identify``: :func:`sim.identify.scan.identify_scan` into ``TWIN_DIR/identify/`` (its own resumable
   job; when its inputs changed — another part material, other frames — the old folder is replaced);
   recorded "not run" with the reason when skipped (``identify=False``) or unavailable.

The part's material (``part_material``, default ``white-plastic``: a translucent medium whose
scattering and absorption the identification fits; ``metal`` the old opaque model) is recorded in
``twin.json`` as ``part_material``: its ``tag`` and, for a translucent tag, its ``medium`` (the
identified one, or the tag's tabulated medium without an identification).

The folder is a job folder (:func:`sim.jobfolder.open_job`): its identity is the twin format
and the source (the scan's manifest and the calibration file, by hash); another scan's or
another version's folder is one clear error, before anything is written.
"""

from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from scheimpflug.errors import CalibrationError, FrameError, MeshError, ScheimpflugError
from scheimpflug.io.atomic import finite_json, write_json_atomic, write_text_atomic

from ..jobfolder import JobKind, open_job, remove_temporaries
from .layout import HOUSING_FILE, IDENTIFY_DIR, PART_FILE, RIG_FILE, TWIN_FILE, TWIN_FORMAT

__all__ = ["BuildOptions", "build_twin", "frame_selection"]

MIN_WALL_POINTS = 50      # fewest still points of a wall segment made a board [-]
MIN_WALL_PX = 20          # shortest wall segment along the stripe made a board [px]
MAX_SEGMENTS = 3          # straight segments tried per wall region [-]
MIN_SEGMENT_SHARE = 0.1   # a further segment holds at least this share of the first one's points (not a corner's) [-]

_TWIN_JOB = JobKind(error=ScheimpflugError, meta_file=TWIN_FILE, noun="twin", folder_noun="twin folder",
                    what={"format": "another version of this program", "source": "another scan or calibration"},
                    differs=("twin folder {out!r} holds a {noun} made from {what} ({where!r} differs); "
                             "choose another --out or delete the folder"),
                    subset_keys=("source",), own_dirs=())


@dataclass(frozen=True)
class BuildOptions:
    """The options of a twin build.

    Parameters
    ----------
    preset : str or None
        Named camera of the rig (``rig from-calibration --preset``).
    chain : str or None
        Named camera chain (``--chain``).
    fabscan_distortion : {"as-fabscan", "apply"}
        How a FabScanPi config is read (``rig from-calibration --fabscan-distortion``).
    fit_frames, held_frames : str
        ``even``, ``odd`` or a comma-separated list of frame indices (:func:`frame_selection`).
    identify : bool
        Run the identification step.
    runs : int or None
        Design runs of the identification (None: its default).
    detector : str
        Stripe detector of the regions and the part (``cog``).
    part_material : str
        The part's material tag (:data:`sim.materials.MATERIALS`; default
        :data:`sim.identify.scan.DEFAULT_PART_MATERIAL`, translucent).
    inference : str
        The identification's inference backend, ``"SURROGATE+SAMPLER"``
        (:func:`sim.identify.fit.parse_inference`; default ``hand+hand``).
    sharpening : bool
        Identify the camera's sharpening too (``chain.sharpen_amount``, ``chain.sharpen_sigma_px``;
        :func:`sim.identify.scan.default_unknowns`).
    """

    preset: str | None = None
    chain: str | None = None
    fabscan_distortion: str = "as-fabscan"
    fit_frames: str = "even"
    held_frames: str = "odd"
    identify: bool = True
    runs: int | None = None
    detector: str = "cog"
    part_material: str = "white-plastic"
    inference: str = "hand+hand"
    sharpening: bool = False


def frame_selection(text: str, n_frames: int) -> list[int] | None:
    """Frames named by ``even``, ``odd`` or a list of indices; None for the identification's default.

    Parameters
    ----------
    text : str
        ``even`` / ``odd`` (the identification's default: a few even- or odd-numbered frames
        spread over the turn) or ``I,J,…``.
    n_frames : int
        Frames of the scan [-].

    Returns
    -------
    list of int or None
        The indices; for ``even``/``odd`` those of :func:`sim.identify.scan.default_frames`.

    Raises
    ------
    ScheimpflugError
        Not a list of indices within the scan.
    """
    if text in ("even", "odd"):
        from sim.identify.scan import default_frames

        return default_frames(n_frames, 0 if text == "even" else 1)
    try:
        frames = [int(x) for x in text.split(",")]
    except ValueError:
        raise ScheimpflugError(f"frames {text!r}: expected even, odd or a list of frame indices I,J,...") from None
    bad = [i for i in frames if not 0 <= i < n_frames]
    if bad:
        raise ScheimpflugError(f"frames {text!r}: frame {bad[0]} is not in the scan (0 … {n_frames - 1})")
    return frames


def _sha(path: Path) -> str:
    from scheimpflug.dataset import file_sha256

    return file_sha256(path)


def _key(obj) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()


class _Scan:
    """The scan and its calibration, read once; the stripes extracted on first use."""

    def __init__(self, scan_dir: Path, calibration: Path, opts: BuildOptions, progress_factory):
        from scheimpflug.calibration.instrument import calibration_sheet_model
        from scheimpflug.io.frames import open_frame_folder

        self.folder = open_frame_folder(scan_dir)
        self.cal = calibration_sheet_model(calibration, opts.fabscan_distortion)
        self.opts, self._progress, self._stripes, self._split = opts, progress_factory, None, None
        self.angles = _angles(self.folder)
        _check_applicable(self.cal, self.folder)

    @property
    def split(self):
        """The scan's housing split (:func:`scheimpflug.still_points.separate_housing`), computed once."""
        if self._split is None:
            from scheimpflug.still_points import separate_housing

            self._split = separate_housing(self.stripes, self.cal)
        return self._split

    @property
    def stripes(self):
        if self._stripes is None:
            from scheimpflug.reconstruct import extract_folder_stripes

            with self._progress("twin build: stripes") as bar:
                self._stripes = extract_folder_stripes(self.folder, self.opts.detector, keep_saturated=True,
                                                       progress=bar)
        return self._stripes


def _angles(folder) -> list[float]:
    if folder.scenario not in (None, "rotary"):
        raise FrameError(f"{folder.path}: scenario {folder.scenario!r}, not a rotary scan")
    missing = [i for i, r in enumerate(folder.frames) if r.angle_deg is None]
    if missing:
        raise FrameError(f"{folder.path}: frame {missing[0]} ({folder.frames[missing[0]].file}) has no 'angle_deg': "
                         "not a rotary scan (import it with --angles-deg)")
    return [float(r.angle_deg) for r in folder.frames]


def _check_applicable(cal, folder) -> None:
    from scheimpflug.calibration import applicability_problem
    from scheimpflug.calibration.direction import stripe_direction_problem

    problem = applicability_problem(cal, folder) or stripe_direction_problem(
        cal, folder.columns, folder.rows, folder.stripe_along)
    if problem:
        raise CalibrationError(f"the calibration cannot be applied to {str(folder.path)!r}: {problem}")


# ------------------------------------------------------------------ the steps


def _base_rig(scan: _Scan, calibration: Path):
    """The rig ``rig from-calibration`` builds (with the chain) and its instrument, in memory."""
    from scheimpflug.calibration.instrument import instrument_from_calibration
    from scheimpflug.model.chain import expand_chain_table
    from scheimpflug.model.instrument import rig_from_instrument

    o = scan.opts
    inst = instrument_from_calibration(calibration, o.preset, fabscan_distortion=o.fabscan_distortion)
    rig = rig_from_instrument(inst)
    if o.chain:
        rig = rig.replace(chain=dict(expand_chain_table({"preset": o.chain})))
    return rig, inst


def _step_table(scan: _Scan, calibration: Path, regions: dict) -> dict:
    """The table's top fitted from the scan's still table line (:mod:`scheimpflug.turntable_top`), as rig keys.

    The table region holds the top's line and, beyond the disc's radius, the line down its rim: the
    radius first (where the line turns down), then the top fitted on the lines inside it.
    """
    from scheimpflug.turntable_top import table_top_of_folder
    from sim.backgrounds import camera_from_table

    if "table" not in regions:
        return {"keys": {}, "fit": None,
                "note": "no still table line in the scan: the disc where the calibration puts it"}
    rig, _ = _base_rig(scan, calibration)
    if not rig.stage.table_radius_mm > 0:
        return {"keys": {}, "fit": None, "note": "the rig has no table disc ([stage] table_radius_mm = 0)"}
    radius, top = _disc_radius_and_top(scan, regions["table"])
    if top is None:
        return {"keys": {}, "fit": None, "radius_mm": radius, "note": "no line of the table's top inside its rim"}
    try:
        fit = table_top_of_folder(scan.folder, scan.cal, top, camera_from_table(rig), detector=scan.opts.detector,
                                  stripes=scan.stripes)
    except ValueError as exc:
        return {"keys": {}, "fit": None, "radius_mm": radius, "note": f"the table's top not fitted: {exc}"}
    keys = fit.rig_keys()
    if radius is not None:
        keys["table_radius_mm"] = radius
    return {"keys": keys, "fit": fit.to_json_dict(), "radius_mm": radius, "top_lines_px": list(top), "note": None}


RIM_MARGIN_MM = 1.0   # the top's lines: their points this much inside the disc's radius at least [mm]


def _disc_radius_and_top(scan: _Scan, table: tuple) -> tuple[float | None, tuple[float, float] | None]:
    """The disc's radius and the range of the top's lines [mm], [px].

    The radius: where the table's line turns down its rim; the top: the longest run of the table
    region's lines whose median point lies inside it by :data:`RIM_MARGIN_MM`.
    """
    from scheimpflug.still_points import axis_coordinates_mm, on_lines
    from scheimpflug.stripe import image_pixels
    from scheimpflug.turntable_top import disc_radius_mm

    st = scan.stripes
    sel = np.concatenate(on_lines(st, [table]))
    line = np.concatenate(st.rows)[sel]
    u, v = image_pixels(line, np.concatenate(st.u)[sel], st.along)
    radius = disc_radius_mm(scan.cal, u, v)
    found = axis_coordinates_mm(scan.cal, u, v)
    if radius is None or found is None:
        return radius, (float(table[0]), float(table[1]))
    lines = np.unique(line)
    r_med = np.array([np.median(found[0][line == k]) for k in lines])
    inside = lines[r_med < radius - RIM_MARGIN_MM]
    if inside.size < 2:
        return radius, None
    cut = np.flatnonzero(np.diff(inside) > 4)
    runs = np.split(inside, cut + 1)
    run = max(runs, key=len)
    return radius, (float(run[0]), float(run[-1]))


def _step_rig(twin_dir: Path, scan: _Scan, calibration: Path, table: dict) -> dict:
    from scheimpflug.model.instrument import rig_file_text
    from scheimpflug.model.rigfile import with_stage_keys

    rig, inst = _base_rig(scan, calibration)
    text = rig_file_text(rig, inst, str(calibration))
    if table["keys"]:
        text = with_stage_keys(text, table["keys"], "table keys fitted by scheimpflug twin build from the scan's "
                               "table line (scheimpflug.turntable_top)")
    write_text_atomic(twin_dir / RIG_FILE, text)
    return {"unknown": list(inst.unknown), "table_keys": table["keys"]}


def _step_regions(twin_dir: Path, scan: _Scan) -> dict:
    split = scan.split
    return {"regions": {k: [v[0], v[1]] for k, v in split.regions.items()}, "housing_split": split.to_json_dict()}


def _wall_segments(u, v, line, name: str, cal) -> tuple[list, list]:
    """Boards of the straight segments of one wall region's still points (RANSAC, largest first)."""
    from scheimpflug.fixed_lines import fixed_line, line_inliers, wall_board

    boards, figures, rest = [], [], np.arange(len(u))
    for k in range(1, MAX_SEGMENTS + 1):
        if len(rest) < MIN_WALL_POINTS:
            break
        inl = rest[line_inliers(u[rest], v[rest])]
        least = max(MIN_WALL_POINTS, MIN_SEGMENT_SHARE * (figures[0]["points"] if figures else 0))
        if len(inl) < least or np.ptp(line[inl]) < MIN_WALL_PX:
            break
        boards.append(wall_board(cal, u[inl], v[inl], f"{name}_{k}", margin_mm=0.0))
        s, h = cal.stage_from_pixel(u[inl], v[inl])
        figures.append({"board": f"{name}_{k}", "lines_px": [float(line[inl].min()), float(line[inl].max())],
                        "points": int(len(inl)), "straightness_mm": fixed_line(s, h, np.zeros(len(inl))).rms_mm})
        rest = np.setdiff1d(rest, inl)
    return boards, figures


def _step_housing(twin_dir: Path, scan: _Scan, regions: dict) -> dict:
    from scheimpflug.model.housing import housing_to_toml
    from scheimpflug.still_points import on_lines, still_mask
    from scheimpflug.stripe import image_pixels

    st = scan.stripes
    line = np.concatenate(st.rows)
    u, v = image_pixels(line, np.concatenate(st.u), st.along)
    frame = np.concatenate([np.full(len(r), i) for i, r in enumerate(st.rows)])
    still = still_mask(u, v, frame, along=st.along)
    boards, figures = [], []
    for name in ("wall_left", "wall_right"):
        if name in regions:
            sel = np.flatnonzero(still & np.concatenate(on_lines(st, [regions[name]])))
            b, f = _wall_segments(u[sel], v[sel], line[sel], name, scan.cal)
            boards += b
            figures += f
    path = twin_dir / HOUSING_FILE
    if not boards:
        path.unlink(missing_ok=True)
        return {"file": None, "boards": [], "note": "no still wall in the scan: the twin has no housing"}
    comment = (f"Housing of the still walls of {scan.folder.path} (scheimpflug twin build).\n"
               "Instrument frame: the calibration's camera frame [mm].\n" +
               "\n".join(f"{f['board']}: lines {f['lines_px']} px, {f['points']} still points, straightness "
                         f"{f['straightness_mm']:.3f} mm" for f in figures))
    write_text_atomic(path, housing_to_toml(boards, comment))
    return {"file": HOUSING_FILE, "boards": figures, "note": None}


def _step_part(twin_dir: Path, scan: _Scan, regions: dict) -> dict:
    from scheimpflug.io.meshfile import write_mesh
    from scheimpflug.model.rig import load_rig
    from scheimpflug.still_points import on_lines

    from .part import part_model

    st = scan.stripes
    if "part" not in regions:
        raise FrameError(f"{scan.folder.path}: the stripe moves on no line: no part turning on the table to model")
    keep = [k & p for k, p in zip(scan.split.keep, on_lines(st, [regions["part"]]))]
    model = part_model(st.select(keep), scan.angles, scan.cal, load_rig(twin_dir / RIG_FILE))
    write_mesh(twin_dir / PART_FILE, model.vertices_mm, model.faces,
               comment=f"scheimpflug twin build: the part of {scan.folder.path}, part frame (z = 0 on the table)")
    return model.to_json_dict()


def _step_identify(twin_dir: Path, scan_dir: Path, scan: _Scan, regions: dict, progress_factory, warn) -> dict:
    try:
        from sim.identify.scan import identify_scan
    except ImportError as exc:
        return {"status": "not run", "reason": f"the identification is not available ({exc})"}
    n = len(scan.folder)
    fit, held = (frame_selection(t, n) for t in (scan.opts.fit_frames, scan.opts.held_frames))
    with progress_factory("twin build: identify") as bar:
        result = identify_scan(twin_dir, scan_dir, {k: tuple(v) for k, v in regions.items()}, fit_frames=fit,
                               held_frames=held, out=twin_dir / IDENTIFY_DIR, runs=scan.opts.runs, progress=bar,
                               warn=warn, part_material=scan.opts.part_material, inference=scan.opts.inference,
                               sharpening=scan.opts.sharpening)
    return {"status": "done", "result": json.loads(json.dumps(finite_json(result), default=float))}


# ------------------------------------------------------------------ the job


def _done(meta: dict, name: str, key: str, twin_dir: Path) -> bool:
    """Whether step ``name`` is recorded with this key and its files are there as recorded."""
    rec = (meta.get("steps") or {}).get(name) or {}
    if rec.get("key") != key or rec.get("status") != "done":
        return False
    return all((twin_dir / f).is_file() and _sha(twin_dir / f) == h for f, h in (rec.get("files") or {}).items())


def _record(meta: dict, name: str, key: str, twin_dir: Path, files: list, result: dict, t0: float) -> None:
    meta.setdefault("steps", {})[name] = {
        "status": "done", "key": key, "files": {f: _sha(twin_dir / f) for f in files if (twin_dir / f).is_file()},
        "seconds": round(time.perf_counter() - t0, 3), "result": result}


def build_twin(scan_dir, calibration, out, options: BuildOptions | None = None, *,
               progress_factory: Callable | None = None, say: Callable[[str], None] | None = None,
               warn: Callable[[str], None] | None = None) -> dict:
    """Build (or resume) the twin of the instrument that took a rotary scan (module docstring).

    Parameters
    ----------
    scan_dir : path
        The real scan: a rotary frame folder with ``angle_deg`` per frame (``scheimpflug import``).
    calibration : path
        Its calibration (a target calibration, an OpenCV calibration, FabScanPi's config.json).
    out : path
        The twin folder (created; a rerun resumes).
    options : BuildOptions, optional
        The build's options.
    progress_factory : callable, optional
        ``progress_factory(label)`` → a context manager yielding a ``progress(done, total)``
        callback (:class:`scheimpflug.app.progress.Progress`); default: none.
    say : callable, optional
        Receives one line per step (done, skipped).
    warn : callable, optional
        Receives warnings.

    Returns
    -------
    dict
        The content of ``twin.json`` (:mod:`sim.twin.layout`).

    Raises
    ------
    FrameError
        Not a rotary scan, frames without angles, no part turning.
    CalibrationError
        A calibration that cannot be read or applied to the frames (another size, another stripe
        direction).
    ScheimpflugError
        A twin folder from another scan, calibration or version; a bad frame selection.
    MeshError
        An unknown part material tag.
    """
    import contextlib

    opts = options or BuildOptions()
    _check_part_material(opts.part_material)
    _check_inference(opts.inference)
    say, warn = say or (lambda m: None), warn or (lambda m: None)
    progress_factory = progress_factory or (lambda label: contextlib.nullcontext(None))
    scan_dir, calibration, twin_dir = Path(scan_dir), Path(calibration), Path(out)
    scan = _Scan(scan_dir, calibration, opts, progress_factory)   # bad input: refused before anything is made
    manifest_sha, cal_sha = _sha(scan_dir / "manifest.json"), _sha(calibration)
    identity = {"format": TWIN_FORMAT, "source": {"scan_manifest_sha256": manifest_sha, "calibration_sha256": cal_sha}}
    with open_job(twin_dir, _TWIN_JOB, identity, warn) as old:
        remove_temporaries(twin_dir, ())
        meta = dict(old or {})
        meta.update(identity, complete=False, source={**identity["source"], "scan": str(scan_dir.resolve()),
                    "calibration": str(calibration.resolve()), "n_frames": len(scan.folder),
                    "columns": scan.folder.columns, "rows": scan.folder.rows,
                    "stripe_along": scan.folder.stripe_along},
                    options=asdict(opts), angles_deg=scan.angles)
        _run_steps(meta, twin_dir, scan_dir, scan, calibration, (manifest_sha, cal_sha), progress_factory, say, warn)
        meta["complete"] = True
        write_json_atomic(twin_dir / TWIN_FILE, finite_json(meta))
    return meta


def _run_steps(meta, twin_dir, scan_dir, scan, calibration, shas, progress_factory, say, warn) -> None:
    o = scan.opts
    base = {"scan": shas[0], "calibration": shas[1], "fabscan_distortion": o.fabscan_distortion}
    steps = [
        ("regions", lambda: {**base, "detector": o.detector}, [], lambda: _step_regions(twin_dir, scan)),
        ("table", lambda: {**base, "detector": o.detector, "preset": o.preset, "regions": _regions(meta)}, [],
         lambda: _step_table(scan, calibration, _regions(meta))),
        ("rig", lambda: {**base, "preset": o.preset, "chain": o.chain, "table": _table(meta)}, [RIG_FILE],
         lambda: _step_rig(twin_dir, scan, calibration, _table(meta))),
        ("housing", lambda: {**base, "detector": o.detector}, [HOUSING_FILE],
         lambda: _step_housing(twin_dir, scan, _regions(meta))),
        ("part", lambda: {**base, "detector": o.detector, "rig": _sha(twin_dir / RIG_FILE)}, [PART_FILE],
         lambda: _step_part(twin_dir, scan, _regions(meta))),
    ]
    for name, key_of, files, run in steps:
        _one_step(meta, twin_dir, name, _key(key_of()), files, run, say)
    meta["regions"] = _regions(meta)
    meta["housing"] = meta["steps"]["housing"]["result"]
    meta["part"] = meta["steps"]["part"]["result"]
    meta["table"] = _table(meta)
    meta["files"] = {"rig": RIG_FILE, "part": PART_FILE,
                     "housing": HOUSING_FILE if (twin_dir / HOUSING_FILE).is_file() else None,
                     "identified_rig": None}
    _identify(meta, twin_dir, scan_dir, scan, progress_factory, say, warn)


def _inference_key(name: str) -> dict:
    """The backend among the identification's inputs when it is not the default (earlier folders resume)."""
    from sim.identify.fit import DEFAULT_INFERENCE, parse_inference

    got = parse_inference(name)
    return {} if got == DEFAULT_INFERENCE else {"inference": f"{got.surrogate}+{got.sampler}"}


def _check_inference(name: str) -> None:
    """An unknown inference backend refused before anything is made (ScheimpflugError)."""
    from sim.identify.fit import parse_inference

    try:
        parse_inference(name)
    except ScheimpflugError as exc:
        raise ScheimpflugError(f"--inference: {exc}") from None


def _check_part_material(tag: str) -> None:
    from sim.materials import MATERIALS

    if tag not in MATERIALS:
        raise MeshError(f"part material {tag!r}: unknown material tag (known: {', '.join(MATERIALS)})")


def _part_material(tag: str) -> dict:
    """``twin.json``'s ``part_material`` without an identification: the tag and its tabulated medium."""
    from sim.materials import TRANSLUCENT

    return {"tag": tag, "medium": asdict(TRANSLUCENT[tag]) if tag in TRANSLUCENT else None}


def _regions(meta: dict) -> dict:
    return meta["steps"]["regions"]["result"]["regions"]


def _table(meta: dict) -> dict:
    return meta["steps"]["table"]["result"]


def _one_step(meta, twin_dir, name, key, files, run, say) -> None:
    if _done(meta, name, key, twin_dir):
        say(f"twin build: {name}: done before, inputs unchanged: skipped")
        return
    t0 = time.perf_counter()
    result = run()
    _record(meta, name, key, twin_dir, files, result, t0)
    write_json_atomic(twin_dir / TWIN_FILE, finite_json(meta))       # resumable from here
    say(f"twin build: {name}: done in {time.perf_counter() - t0:.1f} s")


def _identify(meta, twin_dir, scan_dir, scan, progress_factory, say, warn) -> None:
    o = scan.opts
    files = [RIG_FILE, PART_FILE] + ([HOUSING_FILE] if meta["files"]["housing"] else [])
    key = _key({"files": {f: _sha(twin_dir / f) for f in files}, "scan": meta["source"]["scan_manifest_sha256"],
                "regions": meta["regions"], "fit": o.fit_frames, "held": o.held_frames, "runs": o.runs,
                "part_material": o.part_material, **_inference_key(o.inference),
                **({"sharpening": True} if o.sharpening else {})})
    old = (meta.get("steps") or {}).get("identify") or {}
    if o.identify and old.get("key") not in (None, key) and (twin_dir / IDENTIFY_DIR).is_dir():
        import shutil

        shutil.rmtree(twin_dir / IDENTIFY_DIR)       # its inputs changed: the old job would be refused
        say("twin build: identify: its inputs changed: the old identification removed")
    if not o.identify:
        rec = {"status": "not run", "reason": "--no-identify"}
    elif _done(meta, "identify", key, twin_dir):
        say("twin build: identify: done before, inputs unchanged: skipped")
        rec = meta["steps"]["identify"]
    else:
        t0 = time.perf_counter()
        rec = {**_step_identify(twin_dir, scan_dir, scan, meta["regions"], progress_factory, warn), "key": key,
               "seconds": round(time.perf_counter() - t0, 3)}
        if rec["status"] == "done":
            rec["files"] = {f"{IDENTIFY_DIR}/identified.toml": _sha(twin_dir / IDENTIFY_DIR / "identified.toml")}
        say(f"twin build: identify: {rec['status']}{': ' + rec['reason'] if rec.get('reason') else ''}")
    meta["steps"]["identify"] = rec
    result = rec.get("result") or {}
    meta["identified"] = result.get("identified")
    meta["figures"] = result.get("figures")
    meta["part_material"] = result.get("part_material") or _part_material(o.part_material)
    if rec["status"] == "done":
        meta["files"]["identified_rig"] = f"{IDENTIFY_DIR}/identified.toml"
