"""`scheimpflug dataset make|verify|score`: regression datasets from the twin, checked and used.

``make SPEC.toml --out DIR [--workers N | --scheduler ADDRESS] [--format png|zarr]``
    every sample of the spec (format: :mod:`sim.dataset.spec`), resumable, on Dask
    (:mod:`sim.dataset.make`); exit 1 when some samples failed twice (listed).
``verify DIR [--json]``
    re-hash every file against the ledger; exit 1 on a missing, corrupt or extra file or a frame
    listed twice.
``score DIR --detector NAME|MODULE:FUNCTION [--baseline …] [--max-regression-px X] [--json]``
    error statistics of a detector against the per-row truth (:mod:`scheimpflug.dataset`);
    exit 1 when it regresses against the baseline (|bias|, RMS or p99 worse by more than X px, a
    figure the baseline has missing, or a higher missed, outlier or false-detection rate).
"""

from __future__ import annotations

import sys

from scheimpflug.app.commands._common import print_json
from scheimpflug.errors import DatasetError

__all__ = ["add_parser"]


def add_parser(sub):
    p = sub.add_parser("dataset", help="make, verify and score regression datasets",
                       description="Regression datasets: many seeded samples of the twin with exact "
                                   "truth, an index, resumable, on Dask; verification; detector scoring.")
    dsub = p.add_subparsers(dest="dataset_command", metavar="SUBCOMMAND", required=True)

    m = dsub.add_parser("make", help="make (or resume) a dataset from a spec",
                        description="Render every sample of SPEC.toml into DIR (resumable).")
    m.add_argument("spec", metavar="SPEC.toml", help="the dataset spec (TOML: samples, rig, scenario, variations)")
    m.add_argument("--out", required=True, metavar="DIR", help="dataset folder (created; a rerun resumes)")
    g = m.add_mutually_exclusive_group()
    g.add_argument("--workers", type=int, default=1, metavar="N",
                   help="1 = in this process (default); N >= 2 = a local Dask cluster of N processes")
    g.add_argument("--scheduler", metavar="ADDRESS", help="attach to a running Dask scheduler")
    m.add_argument("--format", choices=("png", "zarr"), default="png",
                   help="16-bit PNG frame folders (default) or one Zarr store")
    m.add_argument("--retries", type=int, default=1, help="tries again per failed sample (default 1)")
    m.add_argument("--connect-timeout", type=float, default=10.0, metavar="S",
                   help="seconds to wait for --scheduler (default 10)")
    m.add_argument("--quiet", action="store_true", help="no progress bar")
    m.add_argument("--json", action="store_true", help="print a JSON summary on stdout")
    m.set_defaults(func=_make)

    v = dsub.add_parser("verify", help="re-hash every file of a dataset against its index",
                        description="Report missing, corrupt and extra files and frames listed twice in "
                                    "the index (the same file, or the same content under two names); "
                                    "exit 1 if any.")
    v.add_argument("dir", metavar="DIR", help="the dataset folder")
    v.add_argument("--json", action="store_true", help="print the counts as one JSON object")
    v.add_argument("--quiet", action="store_true", help="no progress bar")
    v.set_defaults(func=_verify)

    s = dsub.add_parser("score", help="score a stripe detector against the per-row truth",
                        description="Bias, RMS, p99, outlier/missed/false rates of a detector, with "
                                    "breakdowns; compared with a baseline for CI.")
    s.add_argument("dir", metavar="DIR", help="the dataset folder")
    s.add_argument("--detector", required=True, metavar="NAME|MODULE:FUNCTION",
                   help="cog, gaussian3, blais-rioux, edge, or your own MODULE:FUNCTION / FILE.py:FUNCTION")
    s.add_argument("--baseline", metavar="NAME|MODULE:FUNCTION", help="detector to compare with")
    s.add_argument("--max-regression-px", type=float, default=None, metavar="X",
                   help="exit 1 when the detector regresses against the baseline: |bias|, RMS or p99 worse "
                        "by more than X px, a figure the baseline has missing (a detector that finds "
                        "nothing has no RMS), or a missed, outlier or false-detection rate higher by more "
                        "than --max-rate-increase")
    s.add_argument("--max-rate-increase", type=float, default=0.0, metavar="R",
                   help="allowed increase of the missed, outlier and false-detection rates over the "
                        "baseline's, as a fraction of the rows (default 0: any increase regresses)")
    g = s.add_mutually_exclusive_group()
    g.add_argument("--workers", type=int, default=1, metavar="N",
                   help="1 = in this process (default); N >= 2 = a local Dask cluster of N processes")
    g.add_argument("--scheduler", metavar="ADDRESS", help="attach to a running Dask scheduler")
    s.add_argument("--where", action="append", default=[], metavar="COLUMN=VALUE",
                   help="score only the frames whose index rows match (repeatable), e.g. "
                        "materials=cardboard or scenario=rotary")
    s.add_argument("--plot", metavar="FILE.png", help="error vs distance and vs angle of incidence")
    s.add_argument("--json", action="store_true", help="print the scores as one JSON object")
    s.add_argument("--quiet", action="store_true", help="no progress bar")
    s.set_defaults(func=_score)
    return p


def _warn(msg: str) -> None:
    print(f"scheimpflug dataset: warning: {msg}", file=sys.stderr)


def _make(args) -> int:
    from scheimpflug.app.progress import Progress
    from sim.dataset import load_spec, make_dataset

    spec = load_spec(args.spec)
    if args.retries < 0:
        raise DatasetError(f"--retries {args.retries}: must be >= 0")
    with Progress(0, label="dataset make", quiet=args.quiet) as bar:
        result = make_dataset(spec, args.out, storage=args.format, workers=args.workers,
                              scheduler=args.scheduler, retries=args.retries,
                              connect_timeout_s=args.connect_timeout, progress=bar, warn=_warn)
    summary = {"out": str(args.out), "samples": result.samples, "samples_done": result.samples_done,
               "samples_made": result.samples_made, "failures": result.failures,
               "frames": result.frames, "frames_rendered": result.frames_rendered,
               "complete": result.complete, "seconds": result.seconds,
               "frames_per_s": (result.frames_rendered / result.seconds["wall"]
                                if result.seconds.get("wall") else None)}
    if args.json:
        print_json(summary)
    if result.failures:
        print(f"scheimpflug dataset make: {len(result.failures)} of {result.samples} samples failed "
              f"(reasons in {args.out}/dataset.json); rerun to try them again", file=sys.stderr)
        return 1
    return 0


def _verify(args) -> int:
    from scheimpflug.app.progress import Progress
    from scheimpflug.dataset import verify_dataset

    with Progress(0, label="dataset verify", quiet=args.quiet or args.json) as bar:
        rep = verify_dataset(args.dir, progress=bar)
    if args.json:
        print_json(rep.to_json())
    else:
        print(f"{rep.frames} frames, {rep.files} files: {len(rep.missing)} missing, "
              f"{len(rep.corrupt)} corrupt, {len(rep.extra)} extra"
              + (f", {len(rep.duplicates)} listed twice" if rep.duplicates else ""))
        for kind in ("missing", "corrupt", "extra"):
            for path in getattr(rep, kind)[:20]:
                print(f"  {kind}: {path}")
        for text in rep.duplicates[:20]:
            print(f"  duplicate: {text}")
    return 0 if rep.ok else 1


def _score(args) -> int:
    from scheimpflug.app.progress import Progress
    from scheimpflug.dataset import compare_scores, load_detector, open_dataset, score_dataset
    from sim.dataset import Engine, EngineError

    if args.max_regression_px is not None and args.baseline is None:
        raise DatasetError("--max-regression-px needs --baseline")
    if args.max_regression_px is not None and not 0 <= args.max_regression_px < float("inf"):
        raise DatasetError(f"--max-regression-px {args.max_regression_px}: must be a number >= 0")
    if not 0 <= args.max_rate_increase <= 1:
        raise DatasetError(f"--max-rate-increase {args.max_rate_increase}: must be a fraction in [0, 1]")
    ds = open_dataset(args.dir)
    if args.where:
        ds = ds.filter(**dict(_condition(w) for w in args.where))
    load_detector(args.detector)
    if args.baseline:
        load_detector(args.baseline)
    reports = {}
    with Engine(workers=args.workers, scheduler=args.scheduler) as engine:
        for role, det in (("detector", args.detector), ("baseline", args.baseline)):
            if det is None:
                continue
            with Progress(0, label=f"score {det}", quiet=args.quiet or args.json) as bar:
                try:
                    reports[role] = score_dataset(ds, det, map_fn=_mapper(engine), progress=bar)
                except EngineError as exc:       # the detector ended its worker process
                    raise DatasetError(f"the detector {det!r} failed: {exc}") from None
    out = reports["detector"].to_json()
    status = 0
    if "baseline" in reports:
        out["baseline"] = reports["baseline"].to_json()
        cmp = compare_scores(reports["detector"], reports["baseline"],
                             args.max_regression_px if args.max_regression_px is not None else 0.0,
                             args.max_rate_increase)
        out.update(cmp)
        if args.max_regression_px is None:
            out["regression"] = None
        elif cmp["regression"]:
            status = 1
    if args.plot:
        from scheimpflug.app.dataset_plot import plot_scores

        plot_scores(args.plot, reports)
    if args.json:
        print_json(out)
    else:
        _print_score(out)
    if status:
        print(f"scheimpflug dataset score: {args.detector} regresses against {args.baseline}: "
              f"{'; '.join(out['reasons'])}", file=sys.stderr)
    return status


def _condition(text: str) -> tuple[str, object]:
    import json

    key, sep, value = text.partition("=")
    if not sep or not key:
        raise DatasetError(f"--where {text!r}: expected COLUMN=VALUE")
    try:
        parsed = json.loads(value)
    except ValueError:
        parsed = value
    return key, parsed


def _mapper(engine):
    if not engine.distributed:
        return None

    def run(fn, items):
        for _, res in engine.map(lambda item, progress=None, threads=None: fn(item), items,
                                 key=lambda rows: f"the score of sample {rows[0]['sample']}"):
            if isinstance(res, BaseException):
                raise res
            yield res

    return run


def _fmt(v, unit=""):
    return "–" if v is None else f"{v:.4f}{unit}" if isinstance(v, float) else str(v)


def _print_score(out: dict) -> None:
    def line(name, s):
        return (f"{name:<22s} rows {s['n_rows']:>9d}  bias {_fmt(s['bias_px'])}  rms {_fmt(s['rms_px'])}  "
                f"p99 {_fmt(s['p99_px'])}  outliers {_fmt(s['outlier_rate'])}  "
                f"missed {_fmt(s['missed_rate'])}  false {_fmt(s['false_rate'])}")

    for role in ("detector", "baseline"):
        rep = out if role == "detector" else out.get("baseline")
        if rep is None:
            continue
        print(f"{role} {rep['detector']} ({rep['frames']} frames) [px]")
        print("  " + line("all", rep))
        for key in ("by_material", "by_scenario", "by_distance_mm", "by_incidence_deg"):
            for group, s in rep[key].items():
                print("  " + line(f"{key[3:]} {group}", s))
    if out.get("regression") is not None:
        print(f"regression: {out['regression']} (|bias| {_fmt(out['d_abs_bias_px'])}, rms "
              f"{_fmt(out['d_rms_px'])}, p99 {_fmt(out['d_p99_px'])} px worse than the baseline; "
              f"allowed {out['max_regression_px']}; missed {_fmt(out['d_missed_rate'])}, outliers "
              f"{_fmt(out['d_outlier_rate'])}, false {_fmt(out['d_false_rate'])} higher; allowed "
              f"{out['max_rate_increase']})")
