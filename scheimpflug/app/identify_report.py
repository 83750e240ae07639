"""An identification's report: ``DIR/report.md`` with its tables, the pairs plot and the predictive plot."""

from __future__ import annotations

import math
from pathlib import Path

from scheimpflug.app.identify_plot import plot_pairs, plot_predictive
from scheimpflug.io.atomic import write_text_atomic

__all__ = ["held_out_lines", "parameter_lines", "write_identify_report"]


def _f(x, fmt: str = "{:.4g}") -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "–"
    return fmt.format(x)


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    return ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)] + ["| " + " | ".join(r) + " |" for r in rows]


def parameter_lines(summary: dict) -> list[str]:
    """One plain line per free parameter: mean and 90 % interval, or not identifiable."""
    out = []
    for p in summary["parameters"]:
        if p["identifiable"]:
            edge = p.get("at_prior_edge")
            bound = p["prior"]["hi" if edge == "upper" else "lo"] if edge else None
            note = (f" — at the prior's {edge} end ({bound:g}): the figures ask for more than the prior allows"
                    if edge else "")
            out.append(f"{p['key']} = {p['mean']:.4g}, 90 % interval [{p['lo90']:.4g}, {p['hi90']:.4g}]{note}")
        else:
            out.append(f"{p['key']}: not identifiable — the fitted figures leave it flat over its prior "
                       f"{p['prior']['form']} (90 % interval [{p['lo90']:.4g}, {p['hi90']:.4g}], "
                       f"{100 * p['width_ratio']:.0f} % of the prior's)")
    return out


def held_out_lines(summary: dict) -> list[str]:
    """One plain line per held-out figure: measured, predicted 90 % interval, inside or outside."""
    out = []
    for h in summary["held_out"]:
        if h["inside"] is None:
            out.append(f"held out {h['figure']}: measured {h['measured']:g}; not predicted (only "
                       f"{h['draws_measured']} of {h['draws']} posterior draws measured it)")
            continue
        word = "inside" if h["inside"] else "OUTSIDE"
        extra = ""
        if not h["inside"] and h.get("inside_within_uncertainty"):
            extra = " (inside once its stated uncertainty is allowed for)"
        out.append(f"held out {h['figure']}: measured {h['measured']:g}, predicted [{h['predicted_lo90']:.4g}, "
                   f"{h['predicted_hi90']:.4g}] (90 %, median {h['predicted_median']:.4g}, "
                   f"{h['draws_measured']} draws): {word}{extra}")
    return out


def _parameter_table(summary: dict) -> list[str]:
    rows = [[f"`{p['key']}`", p["prior"]["form"], _f(p["mean"]), _f(p["sd"], "{:.3g}"),
             f"[{_f(p['lo90'])}, {_f(p['hi90'])}]", f"{100 * p['width_ratio']:.0f} %",
             ("yes" if p["identifiable"] else "**no (flat)**")
             + (f", at the prior's {p['at_prior_edge']} end" if p.get("at_prior_edge") else "")]
            for p in summary["parameters"]]
    return _table(["parameter", "prior", "posterior mean", "sd", "90 % interval", "width / prior's",
                   "identifiable"], rows)


def _correlation_table(summary: dict) -> list[str]:
    keys, m = summary["correlation"]["keys"], summary["correlation"]["matrix"]
    return _table(["", *(f"`{k}`" for k in keys)],
                  [[f"`{k}`", *(f"{m[i][j]:+.2f}" for j in range(len(keys)))] for i, k in enumerate(keys)])


def _surrogate_table(summary: dict) -> list[str]:
    rows = [[f"`{name}`", c["scale"], str(c["n"]), _f(c["noise"], "{:.3g}"), _f(c["rmse"], "{:.3g}"),
             _f(c["error"], "{:.3g}"), _f(c["uncertainty"], "{:.3g}"), _f(c["z_rms"], "{:.2f}"),
             "yes" if c["ok"] else "**no**"] for name, c in summary["surrogate_cv_error"].items()]
    return _table(["fitted figure", "scale", "runs", "twin noise τ", "LOO RMSE", "surrogate error",
                   "measurement σ", "LOO z RMS", "error < σ"], rows)


def _interval_table(rows: list[dict]) -> list[str]:
    out = [[f"`{r['figure']}`", _f(r["measured"]) + ("" if r["uncertainty"] is None else f" ± {r['uncertainty']:.3g}"),
            f"[{_f(r['predicted_lo90'])}, {_f(r['predicted_hi90'])}]", _f(r["predicted_median"]),
            f"{r['draws_measured']} of {r['draws']}",
            "–" if r["inside"] is None else ("inside" if r["inside"] else "**outside**")] for r in rows]
    return _table(["figure", "measured", "90 % predictive interval", "median", "draws", "measured is"], out)


def write_identify_report(result, out) -> Path:
    """Write ``report.md``, ``pairs.png`` and ``predictive.png`` for a finished identification.

    ``result`` is a :class:`sim.identify.IdentifyResult` with its summary; returns the report's path.
    """
    out = Path(out)
    spec, s, fit = result.spec, result.summary, result.fit
    plot_pairs(spec.parameters, s, fit["samples"], fit.get("weights"), [r["unit"] for r in result.design],
               out / "pairs.png")
    rows = [dict(r, kind="held out") for r in s["held_out"]] + [dict(r, kind="fitted") for r in s["fitted"]]
    draws = {r["figure"]: [h["figures"].get(r["figure"]) for h in result.held_out] for r in rows}
    from sim.identify.figures import FIGURES

    if rows:
        plot_predictive(rows, draws, {k: f.unit for k, f in FIGURES.items()}, out / "predictive.png")
    method = ("a Gaussian-process surrogate per fitted figure, MCMC on it" if s["method"] == "surrogate"
              else "ABC on the design runs")
    lines = [f"# Identification: {spec.name}", ""]
    if spec.description:
        lines += [spec.description, ""]
    refine = f" and {s['runs']['refine']} where a first fit's posterior is" if s["runs"].get("refine") else ""
    lines += [f"Base rig `{spec.rig_source}`; {len(spec.parameters)} free parameters; {s['runs']['design']} twin "
              f"runs over the prior (a Latin hypercube){refine}, the surrogate's design; {s['runs']['held_out']} "
              f"at posterior draws; estimate: {method}.", "", *(f"- {t}" for t in parameter_lines(s)), ""]
    if s["fallback"]:
        lines += [f"**Fallback:** {s['fallback']}.", ""]
    lines += ["Fitted: " + ", ".join(f"`{f.name}` = {f.describe()}" for f in spec.fitted) + ".", "",
              "## Posterior", "", *_parameter_table(s), "", "Correlation (unit coordinates of the priors):", "",
              *_correlation_table(s), "", "![pairs plot](pairs.png)", ""]
    if s.get("mcmc"):
        m = s["mcmc"]
        lines += [f"MCMC: {m['chains']} chains × {m['steps']} steps, acceptance {m['acceptance']:.2f}, split R̂ "
                  + ", ".join(f"{x:.3f}" for x in m["rhat"]) + ".", ""]
    if s.get("abc"):
        lines += [f"ABC: effective sample size {s['abc']['effective_sample_size']:.1f} of {s['abc']['runs']} "
                  "runs.", ""]
    lines += ["## Surrogates (leave-one-out cross-validation, on each figure's scale)", "", *_surrogate_table(s), "",
              "The surrogate error is the LOO RMSE with the twin's own noise τ taken out, √max(RMSE² − τ², 0); "
              "it must stay below the measurement σ for the MCMC to be used.", ""]
    if rows:
        lines += ["## Held-out figures (never fitted), predicted at the posterior draws", "",
                  *_interval_table(s["held_out"]), "", *(f"- {t}" for t in held_out_lines(s)), "",
                  "## The fitted figures at the same draws (a check of the fit)", "", *_interval_table(s["fitted"]),
                  "", "![predictive intervals](predictive.png)", "",
                  "Predictive intervals are order statistics of the draws: [x₍ₖ₎, x₍ₙ₊₁₋ₖ₎] with k = ⌊0.05 (n + 1)⌋ "
                  "holds a new draw with probability (n + 1 − 2k)/(n + 1) ≥ 0.9.", ""]
    lines += ["The identified rig: `identified.toml` (posterior means; intervals in comments).", ""]
    path = out / "report.md"
    write_text_atomic(path, "\n".join(lines) + "\n")
    return path
