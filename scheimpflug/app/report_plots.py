"""Figures of the demo report (matplotlib, Agg): every axis labelled, with units.

Pure plotting functions: arrays in, one PNG out (written atomically).
"""

from __future__ import annotations

import numpy as np

from scheimpflug.io.atomic import atomic_path

__all__ = [
    "plot_model_distance",
    "plot_sections",
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


def plot_sections(vertices_mm: np.ndarray, faces: np.ndarray, z_mm, path, title: str = "cross-sections",
                  n_curve: int = 400) -> None:
    """Outlines of a closed mesh's sections at heights ``z_mm`` (top view) and its area over height."""
    from scheimpflug.volumetry import section, section_areas_mm2

    plt = _plt()
    z = vertices_mm[:, 2]
    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(12, 5.4))
    colours = plt.cm.viridis(np.linspace(0, 1, max(len(z_mm), 1)))
    for zk, c in zip(z_mm, colours):
        s = section(vertices_mm, faces, zk)
        for seg in s.segments_mm:
            ax0.plot(seg[:, 0], seg[:, 1], "-", color=c, lw=0.8)
        ax0.plot([], [], "-", color=c, label=f"z = {zk:.2f} mm: A = {s.area_mm2:.1f} mm², Ø_eq {s.diameter_mm:.3f} mm")
    ax0.set_aspect("equal", adjustable="datalim")
    ax0.set_xlabel("x [mm]")
    ax0.set_ylabel("y [mm]")
    ax0.legend(fontsize=7, loc="center")    # outlines ring the centre: the legend fits inside
    ax0.set_title("section outlines, top view", fontsize=9)
    ax0.grid(alpha=0.3)
    zz = np.linspace(z.min(), z.max(), n_curve + 2)[1:-1]
    ax1.plot(section_areas_mm2(vertices_mm, faces, zz), zz, "k-", lw=1)
    for zk, c in zip(z_mm, colours):
        ax1.axhline(zk, color=c, lw=0.8, ls="--")
    ax1.set_xlabel("section area A(z) [mm²]")
    ax1.set_ylabel("height z [mm]")
    ax1.set_title("area over height (its integral is the volume)", fontsize=9)
    ax1.grid(alpha=0.3)
    fig.suptitle(title)
    fig.tight_layout()
    _save(fig, path)


def _view_basis(azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    """Rows: screen right, screen up, toward the viewer (a camera looking at the origin)."""
    az, el = np.radians(azimuth_deg), np.radians(elevation_deg)
    back = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    right = np.cross([0.0, 0.0, 1.0], back)
    right /= np.linalg.norm(right)
    return np.stack([right, np.cross(back, right), back])


def _zbuffer(points: np.ndarray, values: np.ndarray, shade: np.ndarray, basis: np.ndarray, px: int,
             spacing_mm: float):
    """Nearest sample per pixel of an orthographic view: (image of values, image of shading, extent).

    Each sample covers a square of about twice ``spacing_mm`` (the samples' mean spacing): random
    samples leave gaps, through which the far side would show.
    """
    uvw = points @ basis.T
    lo, hi = uvw[:, :2].min(axis=0), uvw[:, :2].max(axis=0)
    scale = (px - 1) / max(hi - lo)
    ij0 = np.floor((uvw[:, :2] - lo) * scale).astype(np.int64)
    k = int(np.clip(np.ceil(2.0 * spacing_mm * scale), 1, 5))   # random samples: twice the mean spacing
    offsets = np.array([(a, b) for a in range(k) for b in range(k)]) - (k - 1) // 2
    ij = np.clip((ij0[None] + offsets[:, None]).reshape(-1, 2), 0, px - 1)
    depth, values, shade = (np.tile(a, len(offsets)) for a in (uvw[:, 2], values, shade))
    uvw = np.column_stack([ij, depth])
    key = ij[:, 1] * px + ij[:, 0]
    order = np.lexsort((-uvw[:, 2], key))
    first = np.ones(len(order), bool)
    first[1:] = key[order][1:] != key[order][:-1]
    pick = order[first]
    img = np.full(px * px, np.nan)
    sh = np.full(px * px, np.nan)
    img[key[pick]], sh[key[pick]] = values[pick], shade[pick]
    extent = [lo[0], lo[0] + (px - 1) / scale, lo[1], lo[1] + (px - 1) / scale]
    return img.reshape(px, px), sh.reshape(px, px), extent


def plot_model_distance(points_mm: np.ndarray, normals: np.ndarray, distance_mm: np.ndarray, path,
                        title: str, views=((-60.0, 20.0), (30.0, 60.0)), px: int = 700,
                        limit_mm: float | None = None, spacing_mm: float = 0.3) -> None:
    """Rendered views of a surface (dense samples with normals) coloured by signed distance to the truth.

    Orthographic views with a z-buffer; Lambert shading from the sample normals darkens the colour
    so that the shape reads; the colour scale is symmetric (blue inside, red outside the material).
    """
    plt = _plt()
    lim = limit_mm or float(np.percentile(np.abs(distance_mm), 98)) or 1.0
    fig, axes = plt.subplots(1, len(views), figsize=(6.4 * len(views), 6.2), squeeze=False)
    cmap = plt.get_cmap("coolwarm")
    for ax, (az, el) in zip(axes[0], views):
        basis = _view_basis(az, el)
        shade = 0.35 + 0.65 * np.abs(normals @ basis[2])
        img, sh, extent = _zbuffer(points_mm, distance_mm, shade, basis, px, spacing_mm)
        rgba = cmap(np.clip((img + lim) / (2 * lim), 0, 1))
        rgba[..., :3] *= np.nan_to_num(sh, nan=1.0)[..., None]
        rgba[np.isnan(img)] = [1.0, 1.0, 1.0, 1.0]
        ax.imshow(rgba, origin="lower", extent=extent, interpolation="nearest")
        ax.set_title(f"view from azimuth {az:.0f}°, elevation {el:.0f}°", fontsize=9)
        ax.set_xlabel("screen x [mm]")
        ax.set_ylabel("screen y [mm]")
    sm = plt.cm.ScalarMappable(cmap=cmap, norm=plt.Normalize(-lim, lim))
    fig.colorbar(sm, ax=axes[0].tolist(), fraction=0.025, label="signed distance to the true surface [mm]")
    fig.suptitle(title)
    _save(fig, path)
