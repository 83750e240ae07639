"""What a study's draws say: the table, distributions, sensitivities, rankings, limits, best designs.

Tolerance study
---------------
Per output (:data:`sim.study.outputs.OUTPUTS`): the distribution over the
draws (mean = the bias, σ, percentiles), the Monte Carlo slopes (least squares
of the output on every key's deviation: the bias per unit of each key, beside
the analytic Jacobian), and the global sensitivity of the spec's method
(:mod:`scheimpflug.sensitivity`: Sobol S1/ST or Morris μ*).  For the spec's
metric, the ranking in plain language, and — with ``max_error_mm`` — the
tolerance each key may have for the metric to stay below it in 95 % of builds
(|mean| + 1.96 σ ≤ target), the other tolerances as specified.  The limits
use the analytic response of each key (a quadratic through its finite-difference
points; moments over the tolerance's distribution by quadrature): they describe
the geometry and leave out the extraction noise, which the Monte Carlo shows.

Measured draws.  A draw that could not measure (``not-measured``: a plate or an
artefact out of view), or that measured but gave no value of an output, is
counted per output (``missing``: which draws, and why) and left out of that
output's statistics, never silently.  Draws with the same deviations and the same
render seed are the same rig measured twice (Saltelli's scheme repeats rows for
one tolerance): they count once.  The rules (:data:`MIN_DISTINCT_DRAWS`):

* a σ needs at least 3 distinct draws that measured the output (else None, with
  the reason); Monte Carlo slopes need one more distinct draw than keys + 1;
* the Monte Carlo ranking (Sobol / Morris indices, or a single tolerance's
  100 % with common noise) needs *every* draw to measure the metric (the
  estimators use the whole design; the draws that fail are not a random subset)
  and at least 3 distinct draws, and a metric that varies; otherwise the ranking
  says so, and ranks by the analytic first-order shares when the analytic
  propagation is available, or not at all.

Sweep
-----
The table of designs (closed forms and measured errors), the designs that
meet the constraints (``near_mm``/``far_mm`` covered, |metric| ≤
``max_error_mm``) ranked by |metric|, and the Pareto front of depth range
(more is better) against |metric| (less is better).
"""

from __future__ import annotations

import math

import numpy as np

from scheimpflug.model.design import pareto_front
from scheimpflug.sensitivity import (
    SensitivityIndex,
    deviation_from_unit,
    morris_indices,
    rank_indices,
    sobol_indices,
)

from .outputs import OUTPUTS, output_label, unit_of
from .spec import METRICS, StudySpec

__all__ = ["MIN_DISTINCT_DRAWS", "Z95", "analyse_sweep", "analyse_tolerance", "best_designs", "describe_missing",
           "metric_missing", "table_rows", "tolerance_limit"]

#: Two-sided 95 % quantile of the normal distribution: the "95 % of builds" bound is |mean| + Z95·σ [-].
Z95 = 1.959963984540054
_QUADRATURE = 401       # quantile points of a tolerance's distribution in the limits' moments [-]
_RANGE_SLACK_MM = 1e-3  # a design placed to cover near…far exactly covers it (rounding) [mm]
#: Fewest distinct draws (rigs) measuring an output that give its σ, and a Monte Carlo ranking [-].
MIN_DISTINCT_DRAWS = 3


def _value(x) -> float:
    return math.nan if x is None else float(x)


def table_rows(spec: StudySpec, records: list[dict]) -> list[dict]:
    """One flat row per draw (the Parquet/CSV table), in draw order.

    Parameters
    ----------
    spec : StudySpec
        The study.
    records : list of dict
        The draws' records (:func:`sim.study.draw.run_draw`), any order.

    Returns
    -------
    list of dict
        ``draw``, ``status``, ``reason``, ``seed``, ``rig.KEY`` (the draw's value of every swept /
        toleranced / placed key), ``dev.KEY`` (tolerance deviations), the closed-form design
        numbers, every output (NaN where not measured), the calibrated constants ``cal.*`` and
        ``seconds``.
    """
    rows = []
    for r in sorted(records, key=lambda r: r["draw"]):
        row = {"draw": r["draw"], "status": r["status"], "reason": r["reason"], "seed": r["seed"]}
        row.update({f"rig.{k}": float(v) for k, v in r["values"].items()})
        row.update({f"dev.{k}": float(v) for k, v in r["deviations"].items()})
        row.update({k: float(v) for k, v in r["design"].items()})
        outs = r["outputs"] or {}
        row.update({k: _value(outs.get(k)) for k in OUTPUTS})
        row.update({k: _value(v) for k, v in outs.items() if k.startswith("cal.")})
        row["seconds"] = float(r["seconds"]["wall"])
        rows.append(row)
    return rows


def _first_of_each_rig(records: list[dict]) -> np.ndarray:
    """True for the first draw of each distinct (deviations, seed): a repeated rig counts once."""
    seen, first = set(), []
    for r in records:
        key = (tuple(sorted((k, float(v)) for k, v in r["deviations"].items())), r["seed"])
        first.append(key not in seen)
        seen.add(key)
    return np.array(first, dtype=bool)


def _stats(y: np.ndarray, first: np.ndarray, draws: list[int]) -> dict:
    measured = np.isfinite(y)
    use = measured & first
    missing = [int(d) for d, ok in zip(draws, measured) if not ok]
    base = {"n": int(use.sum()), "measured": int(measured.sum()), "missing": missing}
    if not use.any():
        return base
    v = y[use]
    p = np.percentile(v, [5, 50, 95])
    out = {**base, "mean": float(v.mean()), "std": float(v.std(ddof=1)) if v.size >= MIN_DISTINCT_DRAWS else None,
           "min": float(v.min()), "p5": float(p[0]), "median": float(p[1]), "p95": float(p[2]),
           "max": float(v.max())}
    if out["std"] is None:
        out["std_note"] = (f"no σ: {v.size} distinct draw(s) measured it ({int(measured.sum())} with repeats), "
                           f"a σ needs at least {MIN_DISTINCT_DRAWS}")
    return out


def _slopes(x: np.ndarray, y: np.ndarray, keys: list[str], first: np.ndarray) -> dict:
    ok = np.isfinite(y) & first
    if ok.sum() <= len(keys) + 1:
        return dict.fromkeys(keys)
    a = np.column_stack([np.ones(ok.sum()), x[ok]])
    coef, *_ = np.linalg.lstsq(a, y[ok], rcond=None)
    return {k: float(c) for k, c in zip(keys, coef[1:])}


def _indices(spec: StudySpec, q: np.ndarray, y: np.ndarray, first: np.ndarray):
    """The Monte Carlo indices of one output and a note; None and the reason under the rules (module docstring)."""
    bad = ~np.isfinite(y)
    if bad.any():
        return None, (f"{int(bad.sum())} of {y.size} draw(s) without this output: no Monte Carlo {spec.method} "
                      "indices (they need every draw)")
    distinct = np.unique(y[first]).size
    if int(first.sum()) < MIN_DISTINCT_DRAWS:
        return None, f"{int(first.sum())} distinct draw(s): no Monte Carlo indices (they need {MIN_DISTINCT_DRAWS})"
    if distinct < 2:
        return None, "the output takes one value over every draw: nothing to rank"
    if len(spec.keys) == 1 and spec.noise == "common" and spec.method == "sobol":
        # one tolerance, one noise seed: everything that varies between draws is that key's
        return [SensitivityIndex(spec.keys[0], 1.0, 1.0, 0.0, 0.0)], "a single tolerance with common noise: S1 = ST = 1"
    if spec.method == "sobol":
        return sobol_indices(spec.keys, y, spec.seed), ""
    return morris_indices(spec.keys, q, y, spec.seed), ""


def analyse_tolerance(spec: StudySpec, records: list[dict], analytic: dict | None) -> dict:
    """Distributions, Monte Carlo slopes, sensitivities, the ranking and the limits (module docstring).

    Parameters
    ----------
    spec : StudySpec
        The tolerance study.
    records : list of dict
        Every draw's record.
    analytic : dict or None
        :func:`sim.study.propagation.propagate` (None: no analytic comparison, no limits).

    Returns
    -------
    dict
        ``draws`` (complete), ``draws_measured``, ``outputs`` (per output: ``label``, ``unit``,
        ``distribution``, ``slopes``, ``indices``, ``note``), ``sensitivity`` (the metric's
        indices, most important first: docs/reference/interface.md), ``ranking`` (sentences), ``limits``
        (per key), ``comparison`` (per output and key: Monte Carlo slope against the analytic
        Jacobian; Monte Carlo σ against the first-order σ).
    """
    recs = sorted(records, key=lambda r: r["draw"])
    keys = spec.keys
    x = np.array([[r["deviations"][k] for k in keys] for r in recs], dtype=np.float64).reshape(len(recs), -1)
    q = np.array([r["unit"] for r in recs], dtype=np.float64).reshape(len(recs), -1)
    first = _first_of_each_rig(recs)
    draws = [r["draw"] for r in recs]
    outputs = {}
    for name in OUTPUTS:
        y = np.array([_value((r["outputs"] or {}).get(name)) for r in recs])
        idx, note = _indices(spec, q, y, first)
        outputs[name] = {"label": output_label(name), "unit": unit_of(name), "distribution": _stats(y, first, draws),
                         "slopes": _slopes(x, y, keys, first), "note": note,
                         "indices": None if idx is None else [s.to_json() for s in rank_indices(idx)]}
    metric = outputs[spec.metric]
    limits = {t.key: tolerance_limit(spec, analytic, t.key) for t in spec.tolerances} \
        if analytic and spec.max_error_mm else {}
    missing = metric_missing(spec.metric, recs)
    return {"draws": len(recs), "draws_measured": int(sum(r["status"] == "ok" for r in recs)),
            "draws_distinct": int(first.sum()), "metric_measured": len(recs) - len(missing),
            "metric_missing": missing, "outputs": outputs, "sensitivity": metric["indices"] or [], "limits": limits,
            "ranking": _ranking(spec, metric, analytic, limits, len(recs), missing),
            "comparison": _comparison(outputs, analytic)}


def metric_missing(metric: str, records: list[dict]) -> list[dict]:
    """The draws that did not give the metric, and why.

    Parameters
    ----------
    metric : str
        Output name (``SD_mm`` …).
    records : list of dict
        The draws' records (:func:`sim.study.draw.run_draw`).

    Returns
    -------
    list of dict
        ``draw``, ``status``, ``reason`` (the draw's own, or that it measured without this output), in
        draw order.
    """
    out = []
    for r in sorted(records, key=lambda r: r["draw"]):
        if math.isfinite(_value((r["outputs"] or {}).get(metric))):
            continue
        reason = r["reason"] or (f"measured, but without a {metric}" if r["status"] == "ok" else r["status"])
        out.append({"draw": int(r["draw"]), "status": r["status"], "reason": reason})
    return out


def describe_missing(metric: str, missing: list[dict], total: int, noun: str = "draws") -> str:
    """One sentence: how many draws measured the metric, which did not and the commonest reason.

    Parameters
    ----------
    metric : str
        Output name.
    missing : list of dict
        :func:`metric_missing`.
    total : int
        Draws (designs) complete [-].
    noun : str
        ``draws`` or ``designs``.

    Returns
    -------
    str
        E.g. ``"2 of 6 draws measured the SD_mm; not draws 0, 3, 4, 5 (4 × only 0 usable …)"``;
        "" when none is missing.
    """
    if not missing:
        return ""
    which = ", ".join(str(m["draw"]) for m in missing[:12]) + (", …" if len(missing) > 12 else "")
    reasons: dict[str, int] = {}
    for m in missing:
        reasons[m["reason"]] = reasons.get(m["reason"], 0) + 1
    top, count = max(reasons.items(), key=lambda kv: kv[1])
    why = f"{count} × {top}" + (f"; {len(reasons) - 1} other reason(s)" if len(reasons) > 1 else "")
    return f"{total - len(missing)} of {total} {noun} measured the {metric}; not {noun} {which} ({why})"


def _comparison(outputs: dict, analytic: dict | None) -> dict:
    if not analytic:
        return {}
    out = {}
    for name, o in outputs.items():
        jac = analytic["jacobian"][name]
        out[name] = {"slope_monte_carlo": o["slopes"], "jacobian_analytic": jac,
                     "std_monte_carlo": o["distribution"].get("std"),
                     "std_first_order": analytic["std_linear"][name],
                     "mean_monte_carlo": o["distribution"].get("mean"), "nominal_analytic": analytic["nominal"][name]}
    return out


# ------------------------------------------------------------------ plain language


def _share(spec: StudySpec, entry: dict, analytic: dict | None, n: int) -> tuple[float | None, str]:
    if entry.get("first_order") is not None:
        conf = entry.get("first_order_conf") or 0.0
        how = f"Sobol first-order index, {n} draws" if len(spec.keys) > 1 or spec.noise != "common" else \
            f"the only tolerance, with common noise, {n} draws"
        if conf > 0.1:
            how += f"; ±{100 * conf:.0f} % at 95 %: more draws would settle it"
        return entry["first_order"], how
    if analytic and analytic["shares"][spec.metric].get(entry["key"]) is not None:
        return analytic["shares"][spec.metric][entry["key"]], "first-order analytic share"
    return None, ""


def _ranking(spec: StudySpec, metric: dict, analytic: dict | None, limits: dict, n: int,
             missing: list[dict]) -> list[str]:
    tol = {t.key: t for t in spec.tolerances}
    order = metric["indices"] or []
    label = METRICS[spec.metric]
    lines = []
    if not order:
        why = describe_missing(spec.metric, missing, n) or metric["note"]
        shares = (analytic or {}).get("shares", {}).get(spec.metric, {})
        if any(shares.get(k) is not None for k in spec.keys):
            lines.append(f"no Monte Carlo ranking of the {label}: {why}; ranked by the analytic first-order "
                         "shares (geometry only) instead")
            order = sorted(({"key": k, "first_order": None} for k in spec.keys),
                           key=lambda e: -(shares.get(e["key"]) or 0.0))
        else:
            instead = "the analytic propagation is not available" if not analytic else \
                "the analytic propagation gives no first-order share either (the design does not measure at ±1 σ)"
            return [f"not ranked: {why}; {instead}"]
    for entry in order:
        key, t = entry["key"], tol[entry["key"]]
        share, how = _share(spec, entry, analytic, n)
        if share is None and entry.get("mu_star") is not None:
            text = (f"{key} ({t.describe()}) moves the {label} by {entry['mu_star'] * 1e3:.3g} µm on average "
                    f"over its range (Morris μ*)")
        else:
            pct = "—" if share is None else f"{100 * min(max(share, 0.0), 1.0):.0f} %"
            text = f"{key} ({t.describe()}) contributes {pct} of the variance of the {label} ({how})"
        lines.append(text + _limit_text(spec, t, limits.get(key)))
    return lines


def _limit_text(spec: StudySpec, t, lim: dict | None) -> str:
    if not lim:
        return ""
    unit = unit_of(t.key)
    target = f"{spec.max_error_mm * 1e3:g} µm"
    if lim["status"] == "exceeded":
        return f"; the other tolerances alone already exceed {target} (95 % of builds)"
    if lim["status"] == "free":
        return f"; it does not limit the {METRICS[spec.metric]} (below {target} up to 1000× its tolerance)"
    what = "half-width" if t.kind == "uniform" else "σ"
    return (f"; keep it under {lim['allowed']:.3g}{' ' if unit not in ('°', '%') else ''}{unit} ({what}) "
            f"to stay below {target} (95 % of builds, first-order geometric model, the other tolerances "
            "as specified)")


# ------------------------------------------------------------------ limits


def _response_model(analytic: dict, key: str, name: str):
    cur = analytic["responses"][key]
    x = np.asarray(cur["x"], dtype=np.float64)
    y = np.array([_value(v) for v in cur["outputs"][name]])
    ok = np.isfinite(y)
    if ok.sum() < 3:
        return None
    p = np.polyfit(x[ok], y[ok], 2)
    return lambda z: np.polyval(p, z) - np.polyval(p, 0.0)


def _moments(t, model, scale: float) -> tuple[float, float]:
    q = (np.arange(_QUADRATURE) + 0.5) / _QUADRATURE
    x = deviation_from_unit(q, t.kind, scale * t.width, "sobol")
    e = model(np.abs(x) if t.magnitude else x)
    return float(e.mean()), float(e.var())


def tolerance_limit(spec: StudySpec, analytic: dict, key: str) -> dict:
    """The largest tolerance of ``key`` that keeps the metric below ``max_error_mm`` in 95 % of builds.

    Parameters
    ----------
    spec : StudySpec
        The tolerance study (``metric``, ``max_error_mm``, the tolerances).
    analytic : dict
        :func:`sim.study.propagation.propagate`.
    key : str
        The key whose tolerance is scaled; the others stay as specified.

    Returns
    -------
    dict
        ``status``: ``limited`` (``allowed``: the half-width or σ, in the key's unit, and
        ``scale``: allowed / specified), ``free`` (below the target up to 1000× the tolerance),
        ``exceeded`` (the others alone exceed it) or ``unknown`` (no analytic response).
    """
    tols = {t.key: t for t in spec.tolerances}
    models = {k: _response_model(analytic, k, spec.metric) for k in tols}
    if any(m is None for m in models.values()):
        return {"status": "unknown"}
    y0 = _value(analytic["nominal"][spec.metric])
    y0 = 0.0 if not math.isfinite(y0) else y0
    fixed = [_moments(tols[k], models[k], 1.0) for k in tols if k != key]

    def bound(scale: float) -> float:
        m, v = _moments(tols[key], models[key], scale)
        mean = y0 + m + sum(f[0] for f in fixed)
        return abs(mean) + Z95 * math.sqrt(v + sum(f[1] for f in fixed))

    target = spec.max_error_mm
    if bound(0.0) > target:
        return {"status": "exceeded"}
    lo, hi = 1e-6, 1000.0
    if bound(hi) <= target:
        return {"status": "free"}
    if bound(lo) > target:
        lo = 0.0
    else:
        while hi / lo > 1 + 1e-6:
            mid = math.sqrt(lo * hi)
            lo, hi = (mid, hi) if bound(mid) <= target else (lo, mid)
    return {"status": "limited", "scale": lo, "allowed": lo * tols[key].width}


# ------------------------------------------------------------------ sweeps


def best_designs(rows: list[dict], metric: str, near_mm: float | None = None, far_mm: float | None = None,
                 max_error_mm: float | None = None) -> list[dict]:
    """The measured designs that meet the constraints, best (smallest |metric|) first.

    Parameters
    ----------
    rows : list of dict
        :func:`table_rows` of a sweep.
    metric : str
        The error ranked (``SD_mm`` …).
    near_mm, far_mm : float, optional
        The range a design must cover (along the sheet from the laser) [mm].
    max_error_mm : float, optional
        Largest |metric| allowed [mm].

    Returns
    -------
    list of dict
        ``draw``, the design's values, ``near_mm``, ``far_mm``, the metric, the depth range
        and the resolutions.  A sweep without artefacts (closed forms only) is ranked by the
        distance resolution at the centre instead.
    """
    measured = any(math.isfinite(r.get(metric, math.nan)) for r in rows)
    out = []
    for r in rows:
        err = r.get(metric, math.nan)
        if r["status"] != "ok" or (measured and not math.isfinite(err)):
            continue
        if near_mm is not None and r["near_mm"] > near_mm + _RANGE_SLACK_MM:
            continue
        if far_mm is not None and r["far_mm"] < far_mm - _RANGE_SLACK_MM:
            continue
        if measured and max_error_mm is not None and abs(err) > max_error_mm:
            continue
        out.append(r)
    rank = metric if measured else "distance_resolution_center_mm"
    out.sort(key=lambda r: (abs(r[rank]), r["draw"]))
    swept = [k for k in rows[0] if k.startswith("rig.")] if rows else []
    cols = ["draw", *swept, "near_mm", "far_mm",
            "depth_range_mm", metric, "distance_resolution_center_mm", "height_resolution_center_mm"]
    return [{c: r[c] for c in cols if c in r} for r in out]


def _rows_missing(metric: str, rows: list[dict]) -> list[dict]:
    out = []
    for r in rows:
        if r["status"] == "ok" and math.isfinite(r.get(metric, math.nan)):
            continue
        reason = r["reason"] or (f"measured, but without a {metric}" if r["status"] == "ok" else r["status"])
        out.append({"draw": int(r["draw"]), "status": r["status"], "reason": reason})
    return out


def analyse_sweep(spec: StudySpec, rows: list[dict], near_mm: float | None = None, far_mm: float | None = None,
                  max_error_mm: float | None = None) -> dict:
    """Counts, the best designs under the constraints and the Pareto front of a sweep (module docstring).

    Parameters
    ----------
    spec : StudySpec
        The sweep.
    rows : list of dict
        :func:`table_rows`.
    near_mm, far_mm, max_error_mm : float, optional
        The constraints (:func:`best_designs`).

    Returns
    -------
    dict
        ``designs``, ``measured`` (designs with the metric), ``not_measured`` (draw, reason: the designs
        that could not measure), ``metric_missing`` (every design without the metric, measured or not,
        with the reason; empty for a sweep of closed forms only), ``constraints``, ``best``
        (:func:`best_designs`), ``pareto`` (draws on the front of depth range against |metric|,
        by increasing error).
    """
    metric = spec.metric
    err = np.array([abs(r.get(metric, math.nan)) if r["status"] == "ok" else math.nan for r in rows])
    depth = np.array([r["depth_range_mm"] for r in rows])
    front = pareto_front(depth, err) if spec.artefacts.kinds else np.zeros(0, dtype=np.int64)
    return {"designs": len(rows), "measured": int(np.isfinite(err).sum()),
            "not_measured": [{"draw": r["draw"], "status": r["status"], "reason": r["reason"]}
                             for r in rows if r["status"] != "ok"],
            "metric_missing": _rows_missing(metric, rows) if spec.artefacts.kinds else [],
            "constraints": {"near_mm": near_mm, "far_mm": far_mm, "max_error_mm": max_error_mm, "metric": metric},
            "best": best_designs(rows, metric, near_mm, far_mm, max_error_mm),
            "pareto": [int(rows[i]["draw"]) for i in front]}
