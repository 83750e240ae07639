"""Figures of a study: accuracy, range and resolution against the swept keys; the Pareto front;
the tornado chart, the distributions and the sensitivities of a tolerance study."""

from __future__ import annotations

import math

import numpy as np

from scheimpflug.app.plotting import pyplot as _plt
from scheimpflug.app.plotting import save_tight as _save

__all__ = ["plot_distributions", "plot_pareto", "plot_sensitivity", "plot_sweep", "plot_tornado", "tornado_bars"]




def _col(rows, key):
    return np.array([r.get(key, math.nan) if r.get(key) is not None else math.nan for r in rows], dtype=float)


def plot_sweep(rows: list[dict], keys: list[str], metric: str, path) -> None:
    """Per swept key: the measured errors, the range and the resolutions of every design."""
    plt = _plt()
    n = max(1, len(keys))
    fig, axes = plt.subplots(n, 3, figsize=(14, 3.6 * n), squeeze=False)
    ok = np.array([r["status"] == "ok" for r in rows])
    for i, key in enumerate(keys):
        x = _col(rows, f"rig.{key}")
        ax = axes[i, 0]
        for name, style in (("SD_mm", "o"), ("PF_mm", "s"), ("PS_mm", "^"), ("F_mm", "d")):
            y = np.abs(_col(rows, name)) * 1e3
            if np.isfinite(y).any():
                tag = " (metric)" if name == metric else ""
                ax.plot(x[ok], y[ok], style, ms=5, alpha=0.8, label=f"|{name[:-3]}|{tag}")
        if (~ok).any():
            ax.plot(x[~ok], np.zeros((~ok).sum()), "x", color="k", label="not measured")
        ax.set_ylabel("error [µm]")
        ax.legend(fontsize=7)
        ax = axes[i, 1]
        ax.plot(x, _col(rows, "near_mm"), "v", label="near end")
        ax.plot(x, _col(rows, "far_mm"), "^", label="far end")
        ax.set_ylabel("range along the sheet from the laser [mm]")
        ax.legend(fontsize=7)
        ax = axes[i, 2]
        ax.plot(x, _col(rows, "distance_resolution_center_mm") * 1e3, "o", label="distance / px at centre")
        ax.plot(x, _col(rows, "height_resolution_center_mm") * 1e3, "s", label="height / px at centre")
        ax.set_ylabel("resolution [µm/px]")
        ax.legend(fontsize=7)
        for ax in axes[i]:
            ax.set_xlabel(key)
            ax.grid(alpha=0.3)
    axes[0, 0].set_title("measured accuracy (twin)")
    axes[0, 1].set_title("range (closed form)")
    axes[0, 2].set_title("resolution (closed form)")
    fig.tight_layout()
    _save(fig, path)


def plot_pareto(rows: list[dict], metric: str, front: list[int], path, near_mm=None, far_mm=None,
                max_error_mm=None) -> None:
    """Depth range against |metric| of every measured design, the Pareto front joined."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 5))
    depth = _col(rows, "depth_range_mm")
    err = np.abs(_col(rows, metric)) * 1e3
    ax.plot(err, depth, "o", color="tab:blue", alpha=0.6, label="designs")
    idx = {r["draw"]: i for i, r in enumerate(rows)}
    f = [idx[d] for d in front if d in idx]
    if f:
        ax.plot(err[f], depth[f], "-o", color="tab:red", label="Pareto front")
        for i in f:
            ax.annotate(str(rows[i]["draw"]), (err[i], depth[i]), fontsize=7, xytext=(3, 3),
                        textcoords="offset points")
    if max_error_mm is not None:
        ax.axvline(max_error_mm * 1e3, color="k", ls="--", lw=1, label="--max-error-mm")
    if near_mm is not None and far_mm is not None:
        ax.axhline(far_mm - near_mm, color="gray", ls=":", lw=1, label="wanted depth range")
    ax.set_xlabel(f"|{metric[:-3]}| measured in the twin [µm]")
    ax.set_ylabel("depth range over the sensor [mm]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    _save(fig, path)


def tornado_bars(analytic: dict, tolerances, metric: str) -> list[tuple[str, float, float]]:
    """(key, metric at the low end, at the high end) of each tolerance, others at the design, sorted.

    The ends are ±half-width (uniform) or ±2σ (normal), magnitudes 0 and the half-width / 2σ;
    values from the analytic response (quadratic through its finite-difference points).
    """
    out = []
    y0 = analytic["nominal"].get(metric)
    for t in tolerances:
        cur = analytic["responses"][t.key]
        x = np.asarray(cur["x"], dtype=float)
        y = np.array([math.nan if v is None else v for v in cur["outputs"][metric]], dtype=float)
        ok = np.isfinite(y)
        if ok.sum() < 3 or y0 is None:
            continue
        p = np.polyfit(x[ok], y[ok], 2)
        end = t.width if t.kind == "uniform" else 2 * t.width
        lo = 0.0 if t.magnitude else -end
        out.append((t.key, float(np.polyval(p, lo) - np.polyval(p, 0) + y0),
                    float(np.polyval(p, end) - np.polyval(p, 0) + y0)))
    return sorted(out, key=lambda b: -abs(b[2] - b[1]))


def plot_tornado(analytic: dict, tolerances, metric: str, label: str, path) -> None:
    """Tornado chart of the metric: each tolerance alone at its ends (analytic response)."""
    plt = _plt()
    bars = tornado_bars(analytic, tolerances, metric)
    y0 = (analytic["nominal"].get(metric) or 0.0) * 1e3
    fig, ax = plt.subplots(figsize=(8, 1.0 + 0.5 * max(1, len(bars))))
    for i, (_key, lo, hi) in enumerate(reversed(bars)):
        ax.barh(i, lo * 1e3 - y0, left=y0, color="tab:blue", alpha=0.8)
        ax.barh(i, hi * 1e3 - y0, left=y0, color="tab:orange", alpha=0.8)
    ax.set_yticks(range(len(bars)), [b[0] for b in reversed(bars)], fontsize=8)
    ax.axvline(y0, color="k", lw=0.8)
    ax.set_xlabel(f"{label} [µm] (blue: low end, orange: high end of the tolerance)")
    ax.set_title("tornado: each tolerance alone at its ends, the others at the design", fontsize=9)
    ax.grid(axis="x", alpha=0.3)
    _save(fig, path)


def _scale(name: str) -> tuple[float, str]:
    if name.endswith("_px_mm"):
        return 1.0, "px·mm"
    if name.endswith("_mm"):
        return 1e3, "µm"
    return 1.0, name.rsplit("_", 1)[-1]


def plot_distributions(records: list[dict], analytic: dict | None, names: list[str], labels: dict, path,
                       signed=()) -> None:
    """Histograms of outputs over the draws, with the first-order normal of the analytic propagation
    for the ``signed`` outputs (those whose first order is meaningful)."""
    plt = _plt()
    n = len(names)
    cols = min(3, n)
    rows_ = math.ceil(n / cols)
    fig, axes = plt.subplots(rows_, cols, figsize=(4.6 * cols, 3.4 * rows_), squeeze=False)
    for ax, name in zip(axes.ravel(), names):
        y = np.array([(r["outputs"] or {}).get(name) for r in records], dtype=float)
        y = y[np.isfinite(y)]
        scale, unit = _scale(name)
        if y.size:
            ax.hist(y * scale, bins=max(5, min(30, y.size // 2)), color="tab:blue", alpha=0.7, density=True,
                    label=f"Monte Carlo ({y.size})")
        if (name in signed and analytic and analytic["std_linear"].get(name)
                and analytic["nominal"].get(name) is not None):
            m, s = analytic["nominal"][name] * scale, analytic["std_linear"][name] * scale
            z = np.linspace(m - 4 * s, m + 4 * s, 200)
            ax.plot(z, np.exp(-0.5 * ((z - m) / s) ** 2) / (s * math.sqrt(2 * math.pi)), color="tab:red",
                    label="first order (analytic)")
        ax.set_title(labels.get(name, name), fontsize=9)
        ax.set_xlabel(unit)
        ax.legend(fontsize=7)
    for ax in axes.ravel()[n:]:
        ax.set_visible(False)
    fig.tight_layout()
    _save(fig, path)


def plot_sensitivity(indices: list[dict], analytic_shares: dict | None, label: str, path) -> None:
    """Sobol S1 and ST (Monte Carlo) or Morris μ*, beside the analytic first-order shares."""
    plt = _plt()
    keys = [e["key"] for e in indices] or list((analytic_shares or {}).keys())
    fig, ax = plt.subplots(figsize=(8, 1.2 + 0.5 * max(1, len(keys))))
    y = np.arange(len(keys))[::-1]
    if indices and indices[0].get("first_order") is not None:
        ax.barh(y + 0.25, [max(0.0, e["first_order"]) for e in indices], height=0.25, label="S1 (Monte Carlo)")
        ax.barh(y, [max(0.0, e["total"]) for e in indices], height=0.25, label="ST (Monte Carlo)")
    elif indices:
        mu = np.array([e["mu_star"] for e in indices])
        ax.barh(y + 0.25, mu / max(mu.max(), 1e-300), height=0.25, label="Morris μ* / max")
    if analytic_shares:
        ax.barh(y - 0.25, [analytic_shares.get(k) or 0.0 for k in keys], height=0.25,
                label="first-order share (analytic)")
    ax.set_yticks(y, keys, fontsize=8)
    ax.set_xlim(0, 1.05)
    ax.set_xlabel(f"share of the variance of the {label}")
    ax.legend(fontsize=7)
    ax.grid(axis="x", alpha=0.3)
    _save(fig, path)
