"""Figures of ``scheimpflug dataset score``: a detector's error vs distance and vs angle of incidence."""

from __future__ import annotations

from pathlib import Path

__all__ = ["plot_scores"]


def _bins(groups: dict) -> tuple[list, list]:
    centres, stats = [], []
    for label, s in groups.items():
        lo, _, hi = label.partition("–")
        try:
            centres.append(0.5 * (float(lo) + float(hi)))
        except ValueError:
            continue
        stats.append(s.summary())
    order = sorted(range(len(centres)), key=centres.__getitem__)
    return [centres[i] for i in order], [stats[i] for i in order]


def plot_scores(path, reports: dict) -> Path:
    """Bias, RMS and p99 per distance bin and per incidence bin, detector (and baseline).

    ``reports`` maps a role ("detector", "baseline") to a ``scheimpflug.dataset.ScoreReport``.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from scheimpflug.io.atomic import atomic_path

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), constrained_layout=True)
    for ax, key, xlabel in ((axes[0], "distance_mm", "distance D along the sheet [mm]"),
                            (axes[1], "incidence_deg", "angle of incidence [deg]")):
        for role, style in (("detector", "-"), ("baseline", "--")):
            rep = reports.get(role)
            if rep is None:
                continue
            x, s = _bins(rep.breakdown.get(key, {}))
            for stat, colour in (("bias_px", "C0"), ("rms_px", "C1"), ("p99_px", "C3")):
                y = [v[stat] if v[stat] is not None else float("nan") for v in s]
                ax.plot(x, y, style, marker="o", ms=3, color=colour, label=f"{rep.detector} {stat[:-3]}")
        ax.axhline(0.0, color="0.6", lw=0.8)
        ax.set_xlabel(xlabel)
        ax.set_ylabel("error [px]")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle("stripe-centre error against the per-row truth (bias, RMS over |e| ≤ 1 px; p99 of |e|)")
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
    return Path(path)
