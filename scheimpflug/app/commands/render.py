"""`scheimpflug render SCENARIO --out DIR`: the digital twin writes a frame folder.

Scenarios (docs/reference/interface.md): ``calibration`` (plate on the translation stage),
``blocker`` (thin plate on the rotary axis), ``rotary`` (a part on the rotary
stage), ``target`` (a printed pattern, hand-held or on the table: :mod:`sim.target`;
its options and the camera pass's in :mod:`scheimpflug.app.commands._target`);
``--background walls|box`` stands boards around the rotary table (:mod:`sim.backgrounds`).
The folder layout, the truth files and the restart rules are
documented in :mod:`sim.writer` and :mod:`sim.truth`.

``--binning K`` renders a reduced sensor with the same geometry (k × k
binning: pitch × k, columns, rows, hinge column and axis row / k; see
:func:`scheimpflug.model.binning.binned_rig`): the quick mode of the demo and of tests.

Before any rendering the job is sized (:func:`sim.writer.estimate_job`: frames,
folder size, memory): a job that cannot fit (more memory than the machine has,
more output than the free disk space) is refused with the numbers, and one
above :data:`CONFIRM_FRAMES` frames or :data:`CONFIRM_BYTES` bytes needs
``--yes``.

``--workers N`` renders the frames in N spawned worker processes
(:mod:`sim.workers`; the same files bit for bit); ``auto`` (default,
:func:`sim.workers.auto_workers`) uses one per core for a realistic twin's job of
at least ~60 full frames, else this process alone.
"""

from __future__ import annotations

import sys

from scheimpflug.app.commands._common import add_rig_options, integer, number, print_json, rig_from_args
from scheimpflug.app.commands._target import TARGET_OPTIONS, add_target_options, camera_rig, target_options
from scheimpflug.calibration.detectability import format_pattern_advice, pattern_advice
from scheimpflug.calibration.pattern import parse_pattern
from scheimpflug.errors import RenderError, ScheimpflugError

__all__ = ["CONFIRM_BYTES", "CONFIRM_FRAMES", "add_parser"]

CONFIRM_FRAMES = 10_000
"""A render of more frames than this needs ``--yes`` (the paper's largest scan has 720)."""
CONFIRM_BYTES = 20e9
"""A render expected to write more than this [B] needs ``--yes``."""

_SCENARIOS = ("blocker", "calibration", "rotary", "target")
_BACKGROUND = ("background", "background_material", "background_height_mm", "background_distance_mm")
# option → scenarios it applies to
_APPLIES = {
    "steps": ("calibration",), "step_mm": ("calibration",), "start_mm": ("calibration",),
    "plate_height_mm": ("calibration",), "part": ("rotary",), "step_deg": ("rotary", "target"),
    "axis_mm": ("blocker", "rotary"), "frames": ("blocker", "rotary"), "housing": ("rotary",),
    "angles_deg": ("rotary",), "twin": ("rotary",), "part_material": ("rotary",),
    "blocker_thickness_mm": ("blocker",), "room_light": ("target",),
    "pose_from": ("target",), "pose_calibration": ("target",), "pose_channel": ("target",),
    **{k: ("target",) for k in TARGET_OPTIONS},
    **{k: ("blocker", "rotary") for k in ("background", "background_material", "background_height_mm",
                                          "background_distance_mm")},
}


def add_parser(sub):
    p = sub.add_parser(
        "render", help="render a scenario with the digital twin into a frame folder",
        description="Render frames and exact ground truth of a scenario into DIR "
                    "(manifest.json, frames/, truth/). An interrupted run restarts where it stopped.")
    p.add_argument("scenario", metavar="SCENARIO", help="calibration | blocker | rotary | target")
    add_rig_options(p)
    p.add_argument("--out", required=True, metavar="DIR", help="output frame folder")
    p.add_argument("--seed", type=integer(0, 2**31 - 1), default=0, help="run seed (default 0)")
    p.add_argument("--spp", type=integer(1, 2**31 - 1), default=None,
                   help="laser samples per sensor row of the light tracer "
                        "(RenderSettings.samples_per_row; default: the renderer's 32); at most 8 GB of "
                        "laser samples per frame: spp x rows <= 3.8e8 with 1 bounce, 3.8e7 with more")
    p.add_argument("--bounces", type=integer(1, 64), default=None, metavar="N",
                   help="light-path depth of the laser: 1 = first surface only, N > 1 follows "
                        "inter-reflections (default: the rig's [twin] bounces: 1 in paper, 3 in paper-as-built)")
    p.add_argument("--subsurface", action="store_true", default=None,
                   help="translucent materials scatter light inside (rig key [twin] subsurface)")
    p.add_argument("--binning", type=integer(1, 4096), default=1, metavar="K",
                   help="k × k binned sensor, same geometry (quick mode; default 1)")
    p.add_argument("--truth-pixels", default=None, metavar="every|N|none",
                   help="per-pixel truth maps: every frame, every N-th, or none "
                        "(default: every frame for calibration/blocker, every 30th for rotary, none for target)")
    g = p.add_argument_group("calibration")
    g.add_argument("--steps", type=integer(1, 10**9),
                   help="number of plate positions (default: the rig's plan, 27)")
    g.add_argument("--step-mm", type=number(0, 1e5, lo_open=True, unit="mm"),
                   help="stage step [mm] (default: the rig's plan, spanning the positions where both plate "
                        "edges are in view; see 'scheimpflug design')")
    g.add_argument("--start-mm", type=number(-1e6, 1e6, unit="mm"),
                   help="first stage position s [mm] (default: the rig's plan)")
    g.add_argument("--plate-height-mm", type=number(0, 1e4, lo_open=True, unit="mm"),
                   help="plate height [mm] (default: the rig's [stage] calibration_plate_height_mm)")
    g = p.add_argument_group("blocker and rotary")
    g.add_argument("--part", help="rotary: part name or mesh file (default cylinder)")
    g.add_argument("--part-material", metavar="TAG",
                   help="rotary: the part's material tag (metal, knurled-metal, cardboard, tape, paper, "
                        "white-plastic, marble) for a mesh file or every part of a preset (default: the "
                        "part's own, metal for a mesh; with --twin the twin's); a translucent tag scatters "
                        "inside with --subsurface or the rig's [twin] subsurface")
    g.add_argument("--step-deg", type=number(0, 360, lo_open=True, unit="deg"),
                   help="rotary: angle step [deg] (default 0.5)")
    g.add_argument("--axis-mm", type=number(-1e6, 1e6, unit="mm"),
                   help="rotary axis position [mm] (default: the rig's)")
    g.add_argument("--frames", type=integer(1, 10**9), help="blocker: number of frames (default 1); "
                                                            "rotary: render only the first N")
    g.add_argument("--housing", metavar="HOUSING.toml",
                   help="rotary: a scanner's fixed boards (walls, floor) in the instrument frame, the rig's "
                        "camera frame (docs/reference/interface.md; scheimpflug rig housing writes one); "
                        "refused beside a rig file's own [[housing.board]], which renders without it")
    g.add_argument("--angles-deg", type=_angles, metavar="START:STEP|A,B,...",
                   help="rotary: the frames' angles [deg]: one turn from START by STEP, or a list "
                        "(write --angles-deg=-360:1.8 for a negative start); default: --step-deg's turn, "
                        "with --twin the real scan's angles")
    g.add_argument("--twin", metavar="TWIN_DIR",
                   help="rotary: render a twin built by 'twin build' (its rig — the identified one when "
                        "there is one —, part.ply, its material and medium, and housing.toml); not with --rig, "
                        "--preset, --part, --housing")
    g.add_argument("--blocker-thickness-mm", type=number(0, 100, lo_open=True, hi_open=True, unit="mm"),
                   help="blocker thickness [mm] (default 2)")
    add_target_options(p)
    p.add_argument("--workers", type=_workers, default="auto", metavar="N|auto",
                   help="worker processes rendering frames at once, each with cores/N threads; the "
                        "files are the same bit for bit (default auto: one per core when the twin is "
                        "realistic — bounces > 1, subsurface or surface speckle — and the job holds at "
                        "least ~60 full frames, else 1)")
    p.add_argument("--yes", action="store_true",
                   help=f"start a job above {CONFIRM_FRAMES:,} frames or {CONFIRM_BYTES / 1e9:g} GB of "
                        "output without asking (it is refused otherwise)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--json", action="store_true", help="print a JSON summary on stdout")
    p.set_defaults(func=_run)
    return p


def _workers(text: str):
    """``--workers``: 'auto' or an integer >= 1."""
    import argparse

    if text == "auto":
        return text
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: expected 'auto' or an integer >= 1")
    return n


def _angles(text: str) -> list[float]:
    """``--angles-deg``: ``START:STEP`` (one turn) or a comma-separated list [deg]."""
    import argparse
    import math

    try:
        if ":" in text:
            start, step = (float(x) for x in text.split(":"))
            if not (math.isfinite(start) and math.isfinite(step) and 0 < step <= 360):
                raise ValueError
            return [start + i * step for i in range(max(1, int(round(360.0 / step))))]
        angles = [float(x) for x in text.split(",")]
        if not all(math.isfinite(a) for a in angles):
            raise ValueError
        return angles
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected START:STEP (0 < STEP <= 360) or a list A,B,... "
                                         "of finite angles [deg]") from None


def _apply_twin(args) -> None:
    """``--twin``: the twin folder's rig, part, part material and housing as the options, its scan's angles."""
    if not args.twin:
        return
    given = [flag for flag, v in (("--rig", args.rig), ("--preset", args.preset), ("--part", args.part),
                                  ("--housing", args.housing)) if v]
    if given:
        raise ScheimpflugError(f"--twin gives the rig, the part and the housing: not with {', '.join(given)}")
    from sim.twin import load_twin

    twin = load_twin(args.twin)
    args.rig, args.part = str(twin.rig), str(twin.part)
    args.housing = str(twin.housing) if twin.housing else None
    args.twin_materials = twin.materials or None
    if args.part_material is None:
        args.part_material = twin.part_material
    if args.angles_deg is None and args.step_deg is None:
        args.angles_deg = twin.angles_deg or None


def _truth_every(value: str | None, scenario: str) -> int:
    if value is None:
        return {"rotary": 30, "target": 0}.get(scenario, 1)
    if value == "every":
        return 1
    if value == "none":
        return 0
    try:
        n = int(value)
    except ValueError:
        n = 0
    if n < 1:
        raise ScheimpflugError(f"--truth-pixels {value!r}: expected 'every', 'none' or an integer >= 1")
    return n


def _scenario_options(args) -> dict:
    for key, scen in _APPLIES.items():
        if getattr(args, key) is not None and args.scenario not in scen:
            flag = "--" + key.replace("_", "-")
            raise ScheimpflugError(f"{flag} applies to the {' and '.join(scen)} scenario"
                                   f"{'s' if len(scen) > 1 else ''} only, not {args.scenario!r}")
    names = {"calibration": ("steps", "step_mm", "start_mm", "plate_height_mm"),
             "blocker": ("frames", *_BACKGROUND),
             "rotary": ("part", "part_material", "step_deg", "frames", "housing", "angles_deg", *_BACKGROUND),
             "target": ()}[args.scenario]
    opts = {k: getattr(args, k) for k in names if getattr(args, k) is not None}
    if args.scenario == "target":
        opts.update(target_options(args))
    if args.scenario == "blocker" and args.blocker_thickness_mm is not None:
        opts["thickness_mm"] = args.blocker_thickness_mm
    opts["truth_pixels_every"] = _truth_every(args.truth_pixels, args.scenario)
    return opts


def _rig(args):
    from scheimpflug.model.binning import binned_rig

    rig = camera_rig(args, rig_from_args(args), args.scenario)
    if args.bounces is not None:
        if args.bounces < 1:
            raise ScheimpflugError(f"--bounces {args.bounces}: must be an integer >= 1")
        rig = rig.replace(twin={"bounces": args.bounces})
    if args.subsurface:
        rig = rig.replace(twin={"subsurface": True})
    if args.axis_mm is not None and args.scenario in _APPLIES["axis_mm"]:
        rig = rig.replace(stage={"axis_mm": args.axis_mm})
    if args.binning < 1:
        raise ScheimpflugError(f"--binning {args.binning}: must be an integer >= 1")
    try:
        return binned_rig(rig, args.binning)
    except ValueError as exc:
        raise ScheimpflugError(f"--binning {args.binning}: {exc}") from None


def _check_spp(spp: int | None, rig) -> None:
    """Refuse an ``--spp`` whose laser samples per frame would not fit in memory (:mod:`sim.render_limits`)."""
    from sim.render_limits import check_laser_samples

    if spp is not None:
        check_laser_samples(spp, rig.sensor.rows, rig.twin.bounces, "--spp")


def _check_out(path: str) -> None:
    """Fail before any rendering when ``--out`` cannot be a writable folder."""
    from sim.jobfolder import check_writable

    check_writable(path, RenderError)


def _check_job(args, rig, opts: dict) -> int:
    """Size the job before anything is built or written; refuse what cannot fit, ask above a size.

    Returns the number of worker processes (``--workers``, 'auto' resolved).
    """
    import os
    import shutil
    from pathlib import Path

    from sim.render_limits import laser_memory_bytes
    from sim.scenarios import frame_count
    from sim.workers import auto_workers
    from sim.writer import estimate_job

    frames = frame_count(args.scenario, **opts)
    ram = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    workers = args.workers
    if workers == "auto":
        one = estimate_job(rig, frames, opts["truth_pixels_every"]).memory_bytes
        workers = auto_workers(rig, frames, worker_bytes=one, ram_bytes=ram)
    job = estimate_job(rig, frames, opts["truth_pixels_every"], workers)
    laser = laser_memory_bytes(args.spp or 32, rig.sensor.rows, rig.twin.bounces) * max(workers, 1)
    if job.memory_bytes + laser > ram:
        raise RenderError(f"this job needs about {(job.memory_bytes + laser) / 1e9:.3g} GB of memory "
                          f"({job.describe()}), this machine has {ram / 1e9:.3g} GB: use --binning")
    probe = Path(args.out)
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    free = shutil.disk_usage(probe).free if probe.is_dir() else None
    if free is not None and job.output_bytes > free:
        raise RenderError(f"this job writes about {job.output_bytes / 1e9:.3g} GB ({job.describe()}) "
                          f"but {str(probe)!r} has {free / 1e9:.3g} GB free")
    if (job.frames > CONFIRM_FRAMES or job.output_bytes > CONFIRM_BYTES) and not args.yes:
        raise RenderError(f"a large job: {job.describe()}; pass --yes to start it")
    if not args.quiet:
        print(f"scheimpflug render: {job.describe()}"
              f"{f', {workers} worker processes' if workers > 1 else ''}", file=sys.stderr)
    return workers


def _run(args) -> int:
    from scheimpflug.app.progress import Progress
    from sim.scenarios import SCENARIOS
    from sim.writer import render_folder

    if args.scenario not in SCENARIOS:
        raise ScheimpflugError(f"unknown scenario {args.scenario!r} (known: {', '.join(SCENARIOS)})")
    if args.twin and args.scenario == "rotary":
        _apply_twin(args)
    if args.angles_deg is not None and args.step_deg is not None:
        raise ScheimpflugError("--angles-deg and --step-deg: give one (the angles, or a turn by its step)")
    opts = _scenario_options(args)
    if args.seed < 0:
        raise ScheimpflugError(f"--seed {args.seed}: must be >= 0")
    if args.spp is not None and args.spp < 1:
        raise ScheimpflugError(f"--spp {args.spp}: must be >= 1")
    rig = _rig(args)
    if args.scenario == "target":
        _given_poses(args, rig, opts)
    _check_spp(args.spp, rig)
    workers = _check_job(args, rig, opts)
    _check_out(args.out)
    if args.scenario == "target":
        _pattern_advice(args, rig, opts)

    def warn(msg):
        print(f"scheimpflug render: warning: {msg}", file=sys.stderr)

    materials = getattr(args, "twin_materials", None)
    if materials:
        from sim.materials import MaterialSettings

        materials = MaterialSettings(**materials)          # the twin's identified albedo, roughness, part medium
    with Progress(0, label=f"render {args.scenario}", quiet=args.quiet) as bar:
        stats, manifest = render_folder(rig, args.scenario, args.out, seed=args.seed, spp=args.spp,
                                        progress=bar, warn=warn, workers=workers, materials=materials or None,
                                        **opts)
    if args.json:
        print_json(_summary(args, stats, manifest, workers))
    return 0


def _given_poses(args, rig, opts: dict) -> None:
    """``--pose-from``: the real frames' poses of the pattern, in the rig frame (``opts["rig_from_patterns"]``)."""
    if not args.pose_from:
        if args.pose_calibration or args.pose_channel:
            raise ScheimpflugError("--pose-calibration and --pose-channel go with --pose-from FRAME[,FRAME...]")
        return
    if not args.pose_calibration:
        raise ScheimpflugError("--pose-from needs --pose-calibration CAL.json (the camera that places the pattern)")
    if args.poses is not None or args.on_table:
        raise ScheimpflugError("--pose-from gives the poses: not with --poses or --on-table")
    from scheimpflug.board_laser import frame_poses
    from sim.pose_twin import rig_from_camera_poses

    files = [f for f in args.pose_from.split(",") if f]
    poses = frame_poses(files, args.pose_calibration, opts["pattern"], args.pose_channel or "gray")
    opts["rig_from_patterns"] = rig_from_camera_poses(rig, poses)


def _pattern_advice(args, rig, opts: dict) -> None:
    """Say, before anything is rendered, whether this rig and read-out can find the pattern (stderr).

    The scenario's options are checked first (:func:`sim.scenarios.build_scenario`: a bad option is
    the one line of its error, not after the advice).  The advice of
    :func:`scheimpflug.calibration.detectability.pattern_advice`: the squares' size in pixels over
    the depth range and where the whole print fits; a pattern the rig cannot show whole and
    resolved anywhere is a warning (it is legal to render it), printed with ``--quiet`` too.
    """
    from sim.scenarios import build_scenario

    build_scenario("target", rig, seed=args.seed, **opts)
    pattern, quiet = opts["pattern"], args.quiet
    advice = pattern_advice(rig, parse_pattern(pattern))
    if not quiet:
        for line in format_pattern_advice(advice):
            print(f"scheimpflug render: {line}", file=sys.stderr)
    if advice.problem():
        print(f"scheimpflug render: warning: {advice.problem()}; calibrate --method target will find it in few "
              "poses, if any", file=sys.stderr)


def _summary(args, stats, manifest, workers: int) -> dict:
    return {"out": str(args.out), "scenario": manifest["scenario"], "frames": stats.frames_total,
            "frames_rendered": stats.frames_rendered, "frames_skipped": stats.frames_skipped,
            "frames_without_stripe": stats.frames_without_stripe, "wall_s": stats.wall_s,
            "seconds": stats.seconds, "spp": manifest["render"]["spp"],
            "variant": manifest["render"]["variant"], "workers": workers}
