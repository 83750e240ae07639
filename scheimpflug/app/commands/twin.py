"""`scheimpflug twin build SCAN_DIR --calibration CAL --out TWIN_DIR`: the twin of the scanner that took a scan.

Steps and folder layout: :mod:`sim.twin.build`, :mod:`sim.twin.layout`; ``render rotary
--twin TWIN_DIR`` renders the result.  A rerun resumes: a step whose inputs did not change
is skipped.
"""

from __future__ import annotations

import sys

from scheimpflug.app.commands._common import print_json
from scheimpflug.errors import ScheimpflugError

__all__ = ["add_parser"]


def add_parser(sub):
    p = sub.add_parser("twin", help="the twin of a real scanner from one of its scans (twin build)",
                       description="Build the twin of the instrument that took a real rotary scan: the rig from "
                                   "its calibration, the housing from the scan's still walls, the part's model "
                                   "from the scan, the unknowns identified from its frames "
                                   "(docs/reference/interface.md, the twin folder).")
    tsub = p.add_subparsers(dest="twin_command", metavar="ACTION", required=True)
    b = tsub.add_parser("build", help="build (or resume) a twin folder from a scan and its calibration",
                        description="Steps: rig.toml (rig from-calibration), the still and moving regions, "
                                    "housing.toml (the still walls), part.ply (the part's watertight model from "
                                    "the scan, housing and table taken out), the identification (fitted on "
                                    "--fit-frames, checked on --held-frames), twin.json.  Each step is skipped on "
                                    "a rerun when its inputs did not change.")
    b.add_argument("scan", metavar="SCAN_DIR", help="the real rotary scan (a folder written by 'import', with angles)")
    b.add_argument("--calibration", metavar="CAL", required=True,
                   help="its calibration (target, OpenCV, or FabScanPi's config.json)")
    b.add_argument("--out", metavar="TWIN_DIR", required=True, help="the twin folder (created; a rerun resumes)")
    b.add_argument("--preset", metavar="NAME", help="named camera of the rig (as rig from-calibration --preset)")
    b.add_argument("--chain", metavar="CAMERA", help="named camera chain (as rig from-calibration --chain)")
    b.add_argument("--fabscan-distortion", choices=("apply", "as-fabscan"), default="as-fabscan",
                   help="FabScanPi config.json: as in rig from-calibration (default as-fabscan)")
    b.add_argument("--fit-frames", default="even", metavar="even|odd|I,J,...",
                   help="frames the identification fits (default even: a few even-numbered frames spread over "
                        "the turn)")
    b.add_argument("--held-frames", default="odd", metavar="even|odd|I,J,...",
                   help="frames it holds out (default odd)")
    b.add_argument("--runs", type=int, default=None, metavar="N", help="design runs of the identification")
    b.add_argument("--part-material", default="white-plastic", metavar="TAG",
                   help="the part's material tag (default white-plastic: a translucent medium whose "
                        "scattering coefficient and diffusion length the identification fits; metal: an opaque "
                        "rough metal, its roughness fitted; any tag of render --part-material, not the table's "
                        "or housing's)")
    b.add_argument("--inference", default="hand+hand", metavar="SURROGATE+SAMPLER",
                   help="the identification's inference backend: surrogate hand|sklearn, sampler hand|emcee "
                        "(default hand+hand; benchmarks/inference_backends.py compares them)")
    b.add_argument("--sharpening", action="store_true",
                   help="identify the camera's sharpening too ([chain] sharpen_amount, sharpen_sigma_px: the dark "
                        "moat beside a stripe on a dark ground; off by default, benchmarks/RESULTS.md says why)")
    b.add_argument("--no-identify", action="store_true", help="leave the identification out (recorded 'not run')")
    b.add_argument("--quiet", action="store_true", help="no progress display")
    b.add_argument("--json", action="store_true", help="print twin.json as one JSON object")
    b.set_defaults(func=_run_build)
    return p


def _run_build(args) -> int:
    import contextlib

    from scheimpflug.app.progress import Progress
    from scheimpflug.model.chain import CAMERA_PRESETS
    from sim.twin import BuildOptions, build_twin

    if args.chain and args.chain not in CAMERA_PRESETS[1:]:
        raise ScheimpflugError(f"--chain {args.chain!r}: unknown camera (known: {', '.join(CAMERA_PRESETS[1:])})")
    if args.runs is not None and args.runs < 1:
        raise ScheimpflugError(f"--runs {args.runs}: must be an integer >= 1")
    opts = BuildOptions(preset=args.preset, chain=args.chain, fabscan_distortion=args.fabscan_distortion,
                        fit_frames=args.fit_frames, held_frames=args.held_frames, identify=not args.no_identify,
                        runs=args.runs, part_material=args.part_material, inference=args.inference,
                        sharpening=args.sharpening)

    @contextlib.contextmanager
    def bar(label):
        with Progress(0, label=label, quiet=args.quiet) as p:
            yield p

    def say(msg):
        if not args.quiet:
            print(msg, file=sys.stderr)

    meta = build_twin(args.scan, args.calibration, args.out, opts, progress_factory=bar, say=say,
                      warn=lambda m: print(f"scheimpflug twin build: warning: {m}", file=sys.stderr))
    part, housing = meta["part"], meta["housing"]
    ident = meta["steps"]["identify"]
    print(f"twin build: {args.out}: part {part['n_bodies']} bod{'y' if part['n_bodies'] == 1 else 'ies'} "
          f"({part['n_points']} points, {part['volume_mm3']:.6g} mm³), "
          f"{len(housing['boards'])} housing board(s){'; ' + housing['note'] if housing['note'] else ''}, "
          f"regions {', '.join(f'{k} {v[0]:g}-{v[1]:g}' for k, v in meta['regions'].items())} px, "
          f"identification {ident['status']}{' (' + ident['reason'] + ')' if ident.get('reason') else ''}",
          file=sys.stderr)
    if args.json:
        print_json(meta)
    return 0
