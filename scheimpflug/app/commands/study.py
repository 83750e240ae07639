"""`scheimpflug study sweep|tolerance`: design by simulation, end to end through the twin.

``sweep SPEC.toml --out DIR [--workers N | --scheduler ADDRESS] [--near-mm A --far-mm B --max-error-mm E]``
    every design of the spec's ``[sweep]`` (grid or Latin hypercube): closed-form numbers and the
    twin's measured VDI/VDE 2634-2 errors; the designs that meet the constraints.
``tolerance SPEC.toml --out DIR [--workers N | --scheduler ADDRESS]``
    Monte Carlo over the ``[tolerance]`` of one design: distributions, Sobol / Morris sensitivity,
    the analytic first-order propagation beside it, the ranking in plain language.

Both resume when run again (format: :mod:`sim.study.spec`; job: :mod:`sim.study.run`).
"""

from __future__ import annotations

import sys

from scheimpflug.app.commands._common import print_json
from scheimpflug.errors import StudyError

__all__ = ["add_parser"]


def _common(p) -> None:
    p.add_argument("spec", metavar="SPEC.toml",
                   help="the study spec (TOML: [study], [rig], [sweep] or [tolerance], [artefacts])")
    p.add_argument("--out", required=True, metavar="DIR", help="study folder (created; a rerun resumes)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--workers", type=int, default=1, metavar="N",
                   help="1 = in this process (default); N >= 2 = a local Dask cluster of N processes")
    g.add_argument("--scheduler", metavar="ADDRESS", help="attach to a running Dask scheduler")
    p.add_argument("--retries", type=int, default=1, help="tries again per failed draw (default 1)")
    p.add_argument("--connect-timeout", type=float, default=10.0, metavar="S",
                   help="seconds to wait for --scheduler (default 10)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--json", action="store_true", help="print the result as one JSON object")


def add_parser(sub):
    p = sub.add_parser("study", help="design sweeps and tolerance studies through the twin",
                       description="Design by simulation: sweep design parameters or draw tolerances of one "
                                   "design, run calibration, artefact scans and scoring in the twin for every "
                                   "draw, and rank designs and tolerances.")
    ssub = p.add_subparsers(dest="study_command", metavar="SUBCOMMAND", required=True)
    s = ssub.add_parser("sweep", help="closed forms and measured accuracy over a grid or Latin hypercube of designs",
                        description="Every design of the spec's [sweep]: closed-form ranges and resolutions "
                                    "and the twin's VDI/VDE 2634-2 errors; table, plots, best designs.")
    _common(s)
    s.add_argument("--near-mm", type=float, help="the design must see this near end (along the sheet from the laser)")
    s.add_argument("--far-mm", type=float, help="the design must see this far end")
    s.add_argument("--max-error-mm", type=float, help="largest |metric| allowed (default the spec's max_error_mm)")
    s.set_defaults(func=_sweep)
    t = ssub.add_parser("tolerance", help="Monte Carlo over the tolerances of one design, with sensitivity",
                        description="Draw the spec's [tolerance] keys, run every draw through the twin, and "
                                    "report distributions, Sobol/Morris indices, the analytic first-order "
                                    "propagation, a tornado chart and the ranking.")
    _common(t)
    t.set_defaults(func=_tolerance)
    return p


def _warn(msg: str) -> None:
    print(f"scheimpflug study: warning: {msg}", file=sys.stderr)


def _run(args, kind: str, **constraints):
    from scheimpflug.app.progress import Progress
    from scheimpflug.app.study_report import write_study_report
    from sim.study import load_study_spec, run_study

    spec = load_study_spec(args.spec, kind)
    if args.retries < 0:
        raise StudyError(f"--retries {args.retries}: must be >= 0")
    with Progress(0, label=f"study {kind}", quiet=args.quiet) as bar:
        result = run_study(spec, args.out, workers=args.workers, scheduler=args.scheduler, retries=args.retries,
                           connect_timeout_s=args.connect_timeout, progress=bar, warn=_warn, **constraints)
    report = write_study_report(result, args.out)
    return result, report


def _check_constraints(args) -> None:
    for name in ("near_mm", "far_mm", "max_error_mm"):
        v = getattr(args, name)
        if v is not None and not v > 0:
            raise StudyError(f"--{name.replace('_', '-')} {v}: must be > 0")
    if args.near_mm is not None and args.far_mm is not None and not args.near_mm < args.far_mm:
        raise StudyError(f"--near-mm {args.near_mm} must be smaller than --far-mm {args.far_mm}")


def _sweep(args) -> int:
    from sim.study.analysis import describe_missing

    _check_constraints(args)
    result, report = _run(args, "sweep", near_mm=args.near_mm, far_mm=args.far_mm, max_error_mm=args.max_error_mm)
    s = result.summary
    metric = s["metric"]
    text = [f"{s['designs']} designs, {s['measured']} measured the {metric}; report: {report}"]
    if s.get("metric_missing"):
        text.append(describe_missing(metric, s["metric_missing"], s["designs"], "designs"))
    if s["best"]:
        text.append(f"best designs (|{metric}| ascending, constraints {s['constraints']}):")
        for b in s["best"][:5]:
            vals = ", ".join(f"{k[4:]} = {v:.4g}" for k, v in b.items() if k.startswith("rig."))
            err = b.get(metric)
            text.append(f"  design {b['draw']}: {vals}; range {b['near_mm']:.1f}–{b['far_mm']:.1f} mm"
                        + (f"; |{metric[:-3]}| = {abs(err) * 1e3:.1f} µm" if err is not None else ""))
    else:
        text.append("no measured design meets the constraints")
    print("\n".join(text), file=sys.stderr if args.json else sys.stdout)
    if args.json:
        print_json({"kind": "sweep", "out": str(args.out), "report": str(report),
                    **{k: s[k] for k in ("designs", "measured", "best", "pareto", "not_measured", "metric_missing",
                                         "constraints", "failures", "metric")}})
    return 1 if s["failures"] else 0


def _tolerance(args) -> int:
    from sim.study.analysis import describe_missing

    result, report = _run(args, "tolerance")
    s = result.summary
    missing = describe_missing(s["metric"], s.get("metric_missing") or [], s["draws"])
    head = f"{s['draws']} of {s['planned']} draws complete, " + (
        missing or f"all measured the {s['metric']}") + f"; report: {report}"
    print("\n".join([head, *s.get("ranking", [])]),
          file=sys.stderr if args.json else sys.stdout)
    if args.json:
        an = s.get("analytic") or {}
        analytic = {k: v for k, v in an.items() if k != "responses"}
        print_json({"kind": "tolerance", "out": str(args.out), "report": str(report), "draws": s["draws"],
                    "planned": s["planned"], "draws_measured": s.get("draws_measured", 0),
                    "metric_measured": s.get("metric_measured", 0), "metric_missing": s.get("metric_missing", []),
                    "sensitivity": s.get("sensitivity", []), "ranking": s.get("ranking", []),
                    "limits": s.get("limits", {}), "metric": s["metric"],
                    "outputs": {k: v["distribution"] for k, v in s.get("outputs", {}).items()},
                    "comparison": s.get("comparison", {}), "analytic": analytic, "failures": s["failures"]})
    return 1 if s["failures"] else 0
