"""Figures of the demo report (matplotlib, Agg): every axis labelled, with units.

Pure plotting functions: arrays in, one PNG out (written atomically).
"""

from __future__ import annotations

import numpy as np

from scheimpflug.io.atomic import atomic_path

__all__ = [
    "plot_circle_fit",
    "plot_cloud_views",
    "plot_error_histograms",
    "plot_plane_fit",
    "plot_superimposed_frames",
]


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path) -> None:
    plt = _plt()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100, format="png")
    plt.close(fig)


def plot_superimposed_frames(frames: list[np.ndarray], path, title: str,
                             stripe_uv: list[np.ndarray] | None = None) -> None:
    """Maximum of several frames (paper Fig. 3a), optionally with the extracted stripes in red.

    frames : list of (rows, columns) arrays [DN]; stripe_uv : list of (n, 2) (u, v) [px].
    """
    plt = _plt()
    stack = np.max(np.stack([np.asarray(f, dtype=np.float32) for f in frames]), axis=0)
    fig, ax = plt.subplots(figsize=(6.4, 7.6))
    hi = np.percentile(stack, 99.9) or 1.0
    im = ax.imshow(stack, cmap="gray", vmin=0, vmax=hi, aspect="equal", interpolation="nearest")
    for uv in stripe_uv or []:
        ax.plot(uv[:, 0], uv[:, 1], ",", color="red", alpha=0.6)
    fig.colorbar(im, ax=ax, fraction=0.05, label="signal [DN]")
    ax.set_xlabel("column u [px] (distance →)")
    ax.set_ylabel("row v [px]")
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    _save(fig, path)


def plot_cloud_views(points_mm: np.ndarray, path, title: str, max_points: int = 60000,
                     seed: int = 0) -> None:
    """Point cloud (n, 3) [mm] from three views, coloured by height z."""
    plt = _plt()
    pts = np.asarray(points_mm, dtype=np.float64)
    if len(pts) > max_points:
        pts = pts[np.random.default_rng(seed).choice(len(pts), max_points, replace=False)]
    fig = plt.figure(figsize=(16, 5.2))
    ax = fig.add_subplot(1, 3, 1, projection="3d")
    sc = ax.scatter(pts[:, 0], pts[:, 1], pts[:, 2], c=pts[:, 2], s=0.3, cmap="viridis", linewidths=0)
    ax.view_init(elev=25, azim=-60)
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("y [mm]")
    ax.set_zlabel("z [mm]")
    ax.set_title("oblique", fontsize=9)
    _equal_3d(ax, pts)
    for k, (i, j, name) in enumerate(((0, 2, "side view (x–z)"), (0, 1, "top view (x–y)"))):
        ax2 = fig.add_subplot(1, 3, k + 2)
        ax2.scatter(pts[:, i], pts[:, j], c=pts[:, 2], s=0.2, cmap="viridis", linewidths=0)
        ax2.set_aspect("equal", adjustable="datalim")
        ax2.set_xlabel("xyz"[i] + " [mm]")
        ax2.set_ylabel("xyz"[j] + " [mm]")
        ax2.set_title(name, fontsize=9)
        ax2.grid(alpha=0.3)
    fig.colorbar(sc, ax=fig.axes, fraction=0.015, label="height z [mm]")
    fig.suptitle(title)
    _save(fig, path)


def _equal_3d(ax, pts: np.ndarray) -> None:
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    c, r = 0.5 * (lo + hi), 0.5 * np.max(hi - lo)
    ax.set_xlim(c[0] - r, c[0] + r)
    ax.set_ylim(c[1] - r, c[1] + r)
    ax.set_zlim(c[2] - r, c[2] + r)


def plot_circle_fit(xy_mm: np.ndarray, centre_mm, radius_mm: float, path, title: str,
                    true_radius_mm: float | None = None) -> None:
    """Top view of points (n, 2) [mm] with the fitted circle (paper Fig. 7c)."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6, 6))
    ax.plot(xy_mm[:, 0], xy_mm[:, 1], ".", ms=1, color="tab:red", label="measured points")
    t = np.linspace(0, 2 * np.pi, 400)
    ax.plot(centre_mm[0] + radius_mm * np.cos(t), centre_mm[1] + radius_mm * np.sin(t), "k-",
            lw=1.2, label=f"fitted circle Ø {2 * radius_mm:.2f} mm")
    if true_radius_mm is not None:
        ax.plot(centre_mm[0] + true_radius_mm * np.cos(t), centre_mm[1] + true_radius_mm * np.sin(t),
                "b--", lw=0.8, label=f"true Ø {2 * true_radius_mm:.2f} mm (at fitted centre)")
    ax.set_aspect("equal")
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("y [mm]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    _save(fig, path)


def plot_plane_fit(points_mm: np.ndarray, coef, path, title: str) -> None:
    """Plane fit y = a + b·x + c·z (paper Fig. 8): residuals over (x, z) and their histogram."""
    plt = _plt()
    a, b, c = coef
    res = points_mm[:, 1] - (a + b * points_mm[:, 0] + c * points_mm[:, 2])
    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(12, 4.6))
    lim = np.percentile(np.abs(res), 99) or 1.0
    sc = ax0.scatter(points_mm[:, 0], points_mm[:, 2], c=res, s=1, cmap="coolwarm", vmin=-lim, vmax=lim)
    fig.colorbar(sc, ax=ax0, label="residual y − ŷ [mm]")
    ax0.set_xlabel("x [mm]")
    ax0.set_ylabel("z [mm]")
    ax0.set_title(f"y = {a:.3f} + {b:.4f}·x + {c:.5f}·z", fontsize=9)
    ax1.hist(res, bins=80, color="tab:blue")
    ax1.set_xlabel("residual [mm]")
    ax1.set_ylabel("points")
    ax1.set_title(f"RMSE {np.sqrt(np.mean(res ** 2)):.4f} mm, n = {len(res)}", fontsize=9)
    fig.suptitle(title)
    fig.tight_layout()
    _save(fig, path)


def plot_error_histograms(errors: dict[str, np.ndarray], path, title: str) -> None:
    """Histograms of signed point-to-mesh distances [mm], one panel per named set."""
    plt = _plt()
    n = max(len(errors), 1)
    fig, axes = plt.subplots(1, n, figsize=(5 * n, 4), squeeze=False)
    for ax, (name, e) in zip(axes[0], errors.items()):
        e = np.asarray(e, dtype=np.float64)
        e = e[np.isfinite(e)]
        lim = np.percentile(np.abs(e), 99.5) if len(e) else 1.0
        ax.hist(np.clip(e, -lim, lim), bins=100, color="tab:purple")
        rms = np.sqrt(np.mean(e ** 2)) if len(e) else float("nan")
        ax.set_title(f"{name}: RMS {rms:.4f} mm, n = {len(e)}\n(tails clipped at the 99.5th percentile of |d|)",
                     fontsize=9)
        ax.set_xlabel("signed distance to the true surface [mm]")
        ax.set_ylabel("points")
    fig.suptitle(title)
    fig.tight_layout()
    _save(fig, path)
