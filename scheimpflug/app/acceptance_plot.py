"""Figures of the VDI/VDE 2634-2 acceptance test: the table per position and the residual clouds."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from scheimpflug import acceptance as vdi
from scheimpflug.fitting import fit_plane
from scheimpflug.io.atomic import atomic_path

__all__ = ["plot_acceptance"]


def _bars(ax, rows, key, title, unit="mm"):
    names = [r["name"] for r in rows]
    vals = [r[key] * 1e3 for r in rows]
    ax.bar(range(len(vals)), vals, color="tab:blue")
    ax.set_xticks(range(len(vals)), names, rotation=60, fontsize=7)
    ax.axhline(0, color="k", lw=0.5)
    ax.set_title(title, fontsize=9)
    ax.set_ylabel("µm")


def _residual_cloud(ax, pts, kind, title):
    if kind == "plane":
        fit = fit_plane(pts)
        r = fit.residuals_mm
    else:
        fit = vdi.fit_sphere(pts)
        r = fit.residuals_mm
    sc = ax.scatter(pts[:, 0], pts[:, 2], c=r * 1e3, s=2, cmap="coolwarm",
                    vmin=-np.abs(r).max() * 1e3, vmax=np.abs(r).max() * 1e3)
    ax.set_aspect("equal")
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("z [mm]")
    return sc


def plot_acceptance(result: dict, path: str | Path) -> None:
    """Per-position PF, PS, SD, F and the residuals of the worst sphere and plane, to ``path``."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pos = result["positions"]
    fig, axes = plt.subplots(2, 3, figsize=(13, 8))
    _bars(axes[0, 0], pos["sphere"], "PF_mm", f"PF per sphere position (max {result['PF_mm'] * 1e3:.1f} µm)")
    _bars(axes[0, 1], pos["sphere"], "PS_mm",
          f"PS per sphere position (max |PS| {abs(result['PS_mm']) * 1e3:.1f} µm)")
    if pos["ball_bar"]:
        _bars(axes[0, 2], pos["ball_bar"], "SD_mm",
              f"SD per ball-bar position (max |SD| {abs(result['SD_mm']) * 1e3:.1f} µm)")
    if pos["plane"]:
        _bars(axes[1, 0], pos["plane"], "F_mm", f"F per plane position (max {result['F_mm'] * 1e3:.1f} µm)")
    pts = result.get("points", {})
    worst = max(pos["sphere"], key=lambda r: r["PF_mm"])
    fig.colorbar(_residual_cloud(axes[1, 1], pts[worst["name"]], "sphere",
                                 f"{worst['name']}: radial residual [µm]"), ax=axes[1, 1])
    if pos["plane"]:
        wp = max(pos["plane"], key=lambda r: r["F_mm"])
        fig.colorbar(_residual_cloud(axes[1, 2], pts[wp["name"]], "plane",
                                     f"{wp['name']}: distance from the plane [µm]"), ax=axes[1, 2])
    fig.suptitle(f"VDI/VDE 2634-2 in the twin: L0 = {result['L0_mm']:.1f} mm, calibration model "
                 f"{result['calibration']['model']}", fontsize=11)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
