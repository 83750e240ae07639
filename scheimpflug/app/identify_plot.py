"""Figures of an identification: the posterior's pairs plot and the held-out figures' predictive intervals."""

from __future__ import annotations

import math

import numpy as np

from scheimpflug.app.plotting import pyplot as _plt
from scheimpflug.app.plotting import save_tight as _save

__all__ = ["plot_pairs", "plot_predictive"]




def _log_axis(axis) -> None:
    """A log axis labelled 5, 10, 20 … rather than 4×10⁰, 10¹ …"""
    import matplotlib.ticker as mt

    axis.set_major_locator(mt.LogLocator(subs=(1.0, 2.0, 5.0)))
    axis.set_major_formatter(mt.FuncFormatter(lambda x, _: f"{x:g}"))
    axis.set_minor_formatter(mt.NullFormatter())


def plot_pairs(parameters, summary: dict, samples, weights, design_units, path) -> None:
    """Pairs plot of the posterior: marginals on the diagonal, samples below it, correlations above.

    ``parameters`` are the spec's (:class:`sim.identify.spec.Parameter`); ``samples`` and
    ``design_units`` are unit coordinates (shown as the keys' values; log axes for log-uniform
    priors); ``weights`` the ABC weights or None.
    """
    plt = _plt()
    d = len(parameters)
    s = np.asarray(samples, dtype=float).reshape(-1, d)
    du = np.asarray(design_units, dtype=float).reshape(-1, d)
    w = None if weights is None else np.asarray(weights, dtype=float)
    vals = np.stack([p.value(s[:, i]) for i, p in enumerate(parameters)], axis=1)
    dvals = np.stack([p.value(du[:, i]) for i, p in enumerate(parameters)], axis=1)
    fig, axes = plt.subplots(d, d, figsize=(2.9 * d + 0.6, 2.9 * d + 0.3), squeeze=False)
    rows = summary["parameters"]
    for i, p in enumerate(parameters):
        for j, q in enumerate(parameters):
            ax = axes[i, j]
            if j > i:
                ax.axis("off")
                r = summary["correlation"]["matrix"][i][j]
                ax.text(0.5, 0.5, f"r = {r:+.2f}", ha="center", va="center", fontsize=12, transform=ax.transAxes)
                continue
            if i == j:
                bins = np.geomspace(p.lo, p.hi, 31) if p.prior == "log-uniform" else np.linspace(p.lo, p.hi, 31)
                ax.hist(vals[:, i], bins=bins, weights=w, color="tab:blue", alpha=0.75, density=True)
                for x in (rows[i]["lo90"], rows[i]["hi90"]):
                    ax.axvline(x, color="k", ls="--", lw=0.8)
                flag = "" if rows[i]["identifiable"] else " — flat"
                ax.set_title(f"{p.key}{flag}", fontsize=9)
                ax.set_yticks([])
            else:
                size = 2.0 if w is None else 4000 * w
                ax.scatter(vals[:, j], vals[:, i], s=size, alpha=0.15 if w is None else 0.6, color="tab:blue",
                           lw=0)
                ax.scatter(dvals[:, j], dvals[:, i], s=12, marker="x", color="0.4", lw=0.8, label="design runs")
                ax.set_ylim(p.lo, p.hi)
                if p.prior == "log-uniform":
                    ax.set_yscale("log")
                    _log_axis(ax.yaxis)
            ax.set_xlim(q.lo, q.hi)
            if q.prior == "log-uniform":
                ax.set_xscale("log")
                _log_axis(ax.xaxis)
            if i == d - 1:
                ax.set_xlabel(q.key, fontsize=8)
            if j == 0 and i > 0:
                ax.set_ylabel(p.key, fontsize=8)
    if d > 1:
        axes[1, 0].legend(fontsize=7, loc="best")
    fig.suptitle("posterior of the free parameters (dashed: 90 % interval; ×: the twin's design runs)", fontsize=10)
    _save(fig, path)


def plot_predictive(rows: list[dict], draws: dict, units: dict, path) -> None:
    """Per figure: the values at the posterior draws, their 90 % predictive interval and the measurement.

    ``rows`` are the summary's ``held_out`` then ``fitted`` rows (with a ``kind`` key), ``draws``
    the figure's values at the draws by name, ``units`` the figures' units.
    """
    plt = _plt()
    n = max(1, len(rows))
    fig, axes = plt.subplots(n, 1, figsize=(7.5, 1.35 * n + 0.6), squeeze=False)
    for ax, r in zip(axes[:, 0], rows):
        v = [x for x in draws.get(r["figure"], []) if x is not None and math.isfinite(x)]
        ax.scatter(v, np.zeros(len(v)), s=14, color="tab:blue", alpha=0.6, label="posterior draws")
        if r["predicted_lo90"] is not None:
            ax.hlines(0, r["predicted_lo90"], r["predicted_hi90"], color="tab:blue", lw=6, alpha=0.35,
                      label="90 % predictive interval")
        err = r.get("uncertainty")
        ax.errorbar([r["measured"]], [0], xerr=None if err is None else [[err], [err]], fmt="D", color="tab:red",
                    ms=7, capsize=4, label="measured")
        state = "–" if r["inside"] is None else ("inside" if r["inside"] else "OUTSIDE")
        ax.set_title(f"{r['kind']}: {r['figure']} [{units.get(r['figure'], '')}] — measured {state}", fontsize=9)
        ax.set_yticks([])
        lo = min(v + [r["measured"] - (err or 0)])
        hi = max(v + [r["measured"] + (err or 0)])
        pad = 0.08 * (hi - lo) if hi > lo else 0.1 * abs(hi) + 1e-12
        ax.set_xlim(lo - pad, hi + pad)
    axes[0, 0].legend(fontsize=7, loc="upper right", ncol=3)
    fig.tight_layout()
    _save(fig, path)
