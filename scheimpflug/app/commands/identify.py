"""`scheimpflug identify SPEC.toml --out DIR [--workers N | --scheduler ADDRESS] [--json]`.

The unknown parameters of one instrument from its own measured figures: twin runs
over the free parameters' priors, a surrogate of every fitted figure, the posterior
(mean, 90 % interval, correlations, which parameters the figures leave flat), the
held-out figures predicted at posterior draws (inside or outside their 90 %
interval), ``DIR/identified.toml``, ``DIR/report.md`` with the pairs and predictive
plots.  Resumes when run again (format: :mod:`sim.identify.spec`; job:
:mod:`sim.identify.job`).
"""

from __future__ import annotations

import sys

from scheimpflug.app.commands._common import print_json
from scheimpflug.errors import StudyError

__all__ = ["add_parser"]


def add_parser(sub):
    p = sub.add_parser("identify", help="identify a rig's unknown parameters from its measured figures",
                       description="Identify the unknown parameters of one instrument from its measured figures "
                                   "with the twin: runs over the priors, a Gaussian-process surrogate per fitted "
                                   "figure, MCMC (or ABC), the posterior with its uncertainty, and the held-out "
                                   "figures predicted at posterior draws.")
    p.add_argument("spec", metavar="SPEC.toml",
                   help="the identification spec (TOML: [identify], [rig], [parameters], [experiment], [fitted], "
                        "[held_out])")
    p.add_argument("--out", required=True, metavar="DIR", help="identification folder (created; a rerun resumes)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--workers", type=int, default=1, metavar="N",
                   help="1 = in this process (default); N >= 2 = a local Dask cluster of N processes")
    g.add_argument("--scheduler", metavar="ADDRESS", help="attach to a running Dask scheduler")
    p.add_argument("--retries", type=int, default=1, help="tries again per failed run (default 1)")
    p.add_argument("--connect-timeout", type=float, default=10.0, metavar="S",
                   help="seconds to wait for --scheduler (default 10)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--json", action="store_true", help="print the result as one JSON object")
    p.set_defaults(func=_run)
    return p


def _warn(msg: str) -> None:
    print(f"scheimpflug identify: warning: {msg}", file=sys.stderr)


def _json(result, report) -> dict:
    s = result.summary
    keep = ("key", "mean", "lo90", "hi90", "identifiable", "sd", "median", "width_ratio", "at_prior_edge", "prior")
    held = ("figure", "measured", "predicted_lo90", "predicted_hi90", "inside", "uncertainty", "predicted_median",
            "coverage", "draws_measured", "draws", "inside_within_uncertainty")
    return {"out": str(result.path), "report": str(report), "identified": str(result.path / "identified.toml"),
            "method": s["method"], "fallback": s["fallback"],
            "parameters": [{k: p[k] for k in keep if k in p} for p in s["parameters"]],
            "held_out": [{k: h[k] for k in held if k in h} for h in s["held_out"]],
            "fitted": [{k: h[k] for k in held if k in h} for h in s["fitted"]],
            "correlation": s["correlation"], "surrogate_cv_error": s["surrogate_cv_error"], "runs": s["runs"],
            "mcmc": s.get("mcmc"), "abc": s.get("abc")}


def _run(args) -> int:
    from scheimpflug.app.identify_report import held_out_lines, parameter_lines, write_identify_report
    from scheimpflug.app.progress import Progress
    from sim.identify import load_identify_spec, run_identify

    spec = load_identify_spec(args.spec)
    if args.retries < 0:
        raise StudyError(f"--retries {args.retries}: must be >= 0")
    if args.workers < 1:
        raise StudyError(f"--workers {args.workers}: must be an integer >= 1")
    with Progress(0, label="identify", quiet=args.quiet) as bar:
        result = run_identify(spec, args.out, workers=args.workers, scheduler=args.scheduler, retries=args.retries,
                              connect_timeout_s=args.connect_timeout, progress=bar, warn=_warn)
    stream = sys.stderr if args.json else sys.stdout
    if not result.complete:
        print(f"{len(result.failures)} runs failed; rerun the same command to retry them", file=stream)
        return 1
    report = write_identify_report(result, args.out)
    s = result.summary
    how = "surrogate + MCMC" if s["method"] == "surrogate" else "ABC"
    n = s["runs"]["design"] + s["runs"].get("refine", 0)
    text = [f"identified from {n} twin runs ({how}); report: {report}",
            *(f"  {t}" for t in parameter_lines(s)), *(f"  {t}" for t in held_out_lines(s)),
            f"  identified rig: {result.path / 'identified.toml'}"]
    if s["fallback"]:
        text.insert(1, f"  {s['fallback']}")
    print("\n".join(text), file=stream)
    if args.json:
        print_json(_json(result, report))
    return 0
