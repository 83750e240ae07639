"""A study's report: ``DIR/report.md`` with its tables and figures (sweep or tolerance study)."""

from __future__ import annotations

import math
from pathlib import Path

from scheimpflug.app.study_plot import (
    plot_distributions,
    plot_pareto,
    plot_sensitivity,
    plot_sweep,
    plot_tornado,
)
from scheimpflug.io.atomic import write_text_atomic

__all__ = ["write_study_report"]

_DIST_OUTPUTS = ("SD_mm", "PS_mm", "PF_mm", "F_mm", "axis_error_mm", "field_rms_mm",
                 "err.hinge_u_px", "err.hinge_v_px", "err.F2_px_mm", "err.d0_mm", "err.C_mm")
_SIGNED = ("SD_mm", "PS_mm", "axis_error_mm", "err.hinge_u_px", "err.hinge_v_px", "err.F2_px_mm",
           "err.d0_mm", "err.C_mm")


def _f(x, fmt: str = "{:.4g}") -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "–"
    return fmt.format(x)


def _um(x) -> str:
    return _f(None if x is None else x * 1e3, "{:.1f}")


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    return ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)] + ["| " + " | ".join(r) + " |" for r in rows]


def write_study_report(result, out) -> Path:
    """Write ``report.md`` and its figures for a finished :class:`sim.study.StudyResult`.

    Parameters
    ----------
    result : sim.study.StudyResult
        The study.
    out : path
        The study folder.

    Returns
    -------
    Path
        The report's path.
    """
    out = Path(out)
    lines = _tolerance(result, out) if result.spec.kind == "tolerance" else _sweep(result, out)
    path = out / "report.md"
    write_text_atomic(path, "\n".join(lines) + "\n")
    return path


def _header(result, title: str) -> list[str]:
    spec, s = result.spec, result.summary
    a = spec.artefacts
    kinds = ", ".join(a.kinds) or "none (closed forms only)"
    lines = [f"# {title}: {spec.name}", "", spec.description or "", "",
             f"- rig: {spec.rig_source}; calibration model: {spec.model}; metric: {spec.metric}",
             f"- artefacts: {kinds}; {'quick' if a.quick else 'full'} plan; {a.material}; binning {a.binning}",
             f"- draws: {s['draws']} of {s['planned']} complete, {_measured(s)}; seed {spec.seed}; "
             f"noise {spec.noise}",
             f"- wall time of the last run {s['wall_s']:.0f} s; CPU time of all draws {s['cpu_s_draws']:.0f} s", ""]
    if s.get("failures"):
        lines += ["**Failed draws** (rerun the command to try them again):", ""]
        lines += [f"- draw {f['draw']}: {f['error']}" for f in s["failures"]] + [""]
    return lines


def _measured(s: dict) -> str:
    """How many complete draws measured the metric, and which did not (the summary's counts)."""
    from sim.study.analysis import describe_missing

    total = s.get("designs", s["draws"])
    missing = s.get("metric_missing") or []
    noun = "designs" if s["kind"] == "sweep" else "draws"
    return describe_missing(s["metric"], missing, total, noun) or f"all {total} measured the {s['metric']}"


# ------------------------------------------------------------------ sweep


def _sweep(result, out: Path) -> list[str]:
    spec, s, rows = result.spec, result.summary, result.rows
    keys = spec.keys
    lines = _header(result, "Design sweep")
    if rows:
        plot_sweep(rows, keys, spec.metric, out / "sweep.png")
        c = s["constraints"]
        plot_pareto(rows, spec.metric, s["pareto"], out / "pareto.png", c["near_mm"], c["far_mm"], c["max_error_mm"])
    c = s["constraints"]
    want = ", ".join(f"{k} {v:g}" for k, v in (("near ≤", c["near_mm"]), ("far ≥", c["far_mm"]),
                                               (f"|{spec.metric}| ≤", c["max_error_mm"])) if v is not None)
    lines += ["## Best designs", "", f"Constraints: {want or 'none'}; ranked by |{spec.metric}|.", ""]
    if s["best"]:
        cols = list(s["best"][0])
        lines += _table(cols, [[_f(b[k]) for k in cols] for b in s["best"][:10]]) + [""]
    else:
        lines += ["No measured design meets the constraints.", ""]
    lines += ["## All designs", ""]
    errs = [("SD_mm", "SD [µm]"), ("PF_mm", "PF [µm]"), ("PS_mm", "PS [µm]"), ("F_mm", "F [µm]")]
    if spec.artefacts.part:
        errs.append(("part_rms_mm", "part RMS [µm]"))
    head = ["draw", *keys, "near [mm]", "far [mm]", "depth [mm]", "dist. res. [µm/px]", "height res. [µm/px]",
            *[h for _, h in errs], "status"]
    body = [[str(r["draw"]), *[_f(r.get(f"rig.{k}")) for k in keys], _f(r["near_mm"], "{:.1f}"),
             _f(r["far_mm"], "{:.1f}"), _f(r["depth_range_mm"], "{:.1f}"),
             _um(r["distance_resolution_center_mm"]), _um(r["height_resolution_center_mm"]),
             *[_um(r.get(k)) for k, _ in errs], r["status"] + (f": {r['reason']}" if r["reason"] else "")]
            for r in rows]
    lines += _table(head, body) + [""]
    lines += ["Range: along the sheet from the laser (Scheimpflug line); resolutions at the centre column "
              "(closed forms of the full-size sensor). Errors: VDI/VDE 2634-2 quality parameters measured in "
              f"the twin (binning {spec.artefacts.binning}).", ""]
    if rows:
        lines += ["![accuracy, range and resolution against the swept keys](sweep.png)", "",
                  f"![Pareto front: depth range against |{spec.metric}|](pareto.png)", "",
                  f"Pareto front (draws): {', '.join(map(str, s['pareto'])) or '–'}", ""]
    lines += ["Files: `draws.parquet` and `draws.csv` (one row per design), `summary.json`, "
              "`draws/NNNNNN/draw.json`.", ""]
    return lines


# ------------------------------------------------------------------ tolerance


def _tolerance(result, out: Path) -> list[str]:
    spec, s = result.spec, result.summary
    an = s.get("analytic") if s.get("analytic") and "error" not in s["analytic"] else None
    metric = spec.metric
    label = s["outputs"][metric]["label"] if s.get("outputs") else metric
    lines = _header(result, "Tolerance study")
    lines += ["## Ranking", ""] + [f"- {t}" for t in s.get("ranking", [])] + [""]
    if s.get("analytic") and "error" in s["analytic"]:
        lines += [f"Analytic propagation not available: {s['analytic']['error']}", ""]
    lines += _sensitivity_table(spec, s, an, metric, label)
    if an:
        plot_tornado(an, spec.tolerances, metric, label, out / "tornado.png")
        lines += ["![tornado chart](tornado.png)", ""]
    if s.get("sensitivity") or an:
        plot_sensitivity(s.get("sensitivity") or [], an["shares"][metric] if an else None, label,
                         out / "sensitivity.png")
        lines += ["![sensitivity indices](sensitivity.png)", ""]
    lines += _distribution_table(s, an)
    names = [n for n in _DIST_OUTPUTS if n in s.get("outputs", {}) and s["outputs"][n]["distribution"].get("n")]
    if result.records and names:            # no draw measured anything: no histogram to draw
        plot_distributions(result.records, an, names, {n: s["outputs"][n]["label"] for n in names},
                           out / "distributions.png", signed=_SIGNED)
        lines += ["![distributions over the draws, with the first-order normal](distributions.png)", ""]
    lines += _slope_table(spec, s, an)
    if an:
        none = [k for k, v in an["geometric_effect"].items() if not v]
        lines += [f"Analytic propagation: {an['evaluations']} noise-free geometric evaluations in "
                  f"{an['seconds']:.1f} s.", ""]
        if none:
            lines += [f"No geometric effect (only the rendered Monte Carlo sees them): {', '.join(none)}.", ""]
    lines += ["Files: `draws.parquet` and `draws.csv` (one row per draw), `summary.json`, `analytic.json`, "
              "`draws/NNNNNN/draw.json`.", ""]
    return lines


def _sensitivity_table(spec, s, an, metric, label) -> list[str]:
    tol = {t.key: t for t in spec.tolerances}
    idx = {e["key"]: e for e in s.get("sensitivity", [])}
    comp = (s.get("comparison") or {}).get(metric, {})
    head = ["key", "tolerance", "S1", "ST", "Morris μ* [µm]", "analytic share",
            "slope MC [µm/unit]", "∂/∂x analytic [µm/unit]", "limit"]
    rows = []
    for key in (list(idx) or spec.keys):
        e, lim = idx.get(key, {}), (s.get("limits") or {}).get(key)
        lim_text = "–" if not lim else (_f(lim.get("allowed")) if lim["status"] == "limited" else lim["status"])
        rows.append([key, tol[key].describe(), _f(e.get("first_order"), "{:.2f}"), _f(e.get("total"), "{:.2f}"),
                     _um(e.get("mu_star")), _f(an["shares"][metric].get(key), "{:.2f}") if an else "–",
                     _um((comp.get("slope_monte_carlo") or {}).get(key)),
                     _um((comp.get("jacobian_analytic") or {}).get(key)), lim_text])
    return [f"## Sensitivity of the {label}", ""] + _table(head, rows) + [""]


def _distribution_table(s, an) -> list[str]:
    head = ["output", "mean (bias)", "σ Monte Carlo", "σ first order", "p5", "p95", "unit"]
    rows = []
    for name in _DIST_OUTPUTS:
        o = s["outputs"].get(name)
        if not o or not o["distribution"].get("n"):
            continue
        d = o["distribution"]
        scale, unit = (1e3, "µm") if o["unit"] == "mm" else (1.0, o["unit"])
        v = lambda x, scale=scale: _f(None if x is None else x * scale)  # noqa: E731
        first = an["std_linear"].get(name) if an else None
        sigma = v(d.get("std")) if d.get("std") is not None else f"– ({d['n']} distinct draw(s))"
        odd = d.get("missing") or d.get("measured", d["n"]) != d["n"]
        count = f" ({d['n']} distinct of {d['measured']} measured; missing in {len(d.get('missing') or [])})"
        rows.append([o["label"] + (count if odd else ""),
                     v(d.get("mean")), sigma, v(first) if name in _SIGNED else "(not linear)",
                     v(d.get("p5")), v(d.get("p95")), unit])
    return ["## Distributions over the draws", ""] + _table(head, rows) + [
        "", "Each distinct rig counts once (draws with the same deviations and seed are one measurement); "
            "a σ needs at least 3 distinct draws that measured the output.",
        "", "Calibration errors are the calibrated paper-form constants minus the design's closed forms "
            "(full-size sensor). PF, F and the field error are ranges or norms: their first order is not "
            "meaningful at a perfect rig.", ""]


def _slope_table(spec, s, an) -> list[str]:
    if not s.get("comparison"):
        return []
    head = ["output", *[f"{k} MC / analytic" for k in spec.keys]]
    rows = []
    for name in _SIGNED:
        c = s["comparison"][name]
        cells = []
        for k in spec.keys:
            mc, a = (c["slope_monte_carlo"] or {}).get(k), (c["jacobian_analytic"] or {}).get(k)
            cells.append(f"{_f(mc)} / {_f(a)}")
        rows.append([s["outputs"][name]["label"], *cells])
    return ["## Bias per unit of each key: Monte Carlo slope against the analytic Jacobian", ""] + \
        _table(head, rows) + ["", "Units: the output's unit per unit of the key.", ""]
