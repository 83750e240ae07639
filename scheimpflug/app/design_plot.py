"""Design figure: the meridian-plane layout and resolution/height-range curves.

matplotlib with the Agg backend (no screen needed).
"""

from __future__ import annotations

import numpy as np

from scheimpflug.io.atomic import atomic_path
from scheimpflug.model.camera import sensor_point_from_pixel, sensor_pose
from scheimpflug.model.hinge import hinge_geometry
from scheimpflug.model.rig import Rig

__all__ = ["plot_design"]


def plot_design(rig: Rig, path: str) -> None:
    """Write a two-panel PNG: layout (left) and resolution vs distance (right)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(14, 5.6), gridspec_kw={"width_ratios": [1.5, 1]})
    _draw_layout(ax0, rig)
    _draw_curves(ax1, rig)
    fig.suptitle(f"Scheimpflug design: f = {rig.lens.focal_length_mm:g} mm, d = "
                 f"{rig.laser.scheimpflug_distance_mm:g} mm, tan φ = {rig.laser.tan_phi:g}, "
                 f"β = {hinge_geometry(rig).tilt_deg:.3f}°")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def _draw_layout(ax, rig: Rig) -> None:
    _layout_lines(ax, rig, annotate=True)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (optical axis) [mm]")
    ax.set_ylabel("y [mm]")
    ax.set_title("meridian plane (z = 0)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="lower right")
    f = rig.lens.focal_length_mm
    d = rig.laser.scheimpflug_distance_mm
    inset = ax.inset_axes([0.60, 0.56, 0.39, 0.43])
    _layout_lines(inset, rig, annotate=False)
    inset.set_xlim(-1.6 * f, 1.6 * f)
    inset.set_ylim(-0.3 * d, 1.1 * d)
    inset.set_aspect("equal", adjustable="box")
    inset.set_title("lens region (zoom) [mm]", fontsize=7)
    inset.tick_params(labelsize=6)
    ax.indicate_inset_zoom(inset, edgecolor="0.4")


def _layout_lines(ax, rig: Rig, annotate: bool) -> None:
    g = hinge_geometry(rig)
    s = rig.sensor
    f, d = g.focal_length_mm, g.scheimpflug_distance_mm
    D = g.distance_from_column(np.array([0.0, s.columns - 1.0]))
    H = g.object_hinge_mm
    far = H + (D[1] * 1.08) * g.propagation_dir
    laser0 = np.array([rig.laser.origin_x_mm, d - rig.laser.origin_x_mm * g.tan_phi, 0.0])
    ax.plot([laser0[0], far[0]], [laser0[1], far[1]], color="tab:blue", lw=1.2, label="laser sheet")
    rng = np.array([H + D[0] * g.propagation_dir, H + D[1] * g.propagation_dir])
    ax.plot(rng[:, 0], rng[:, 1], color="tab:blue", lw=5, alpha=0.45, label="working range (on sensor)")
    pose = sensor_pose(rig)
    corners = sensor_point_from_pixel(pose, np.array([[-0.5, s.axis_row], [s.columns - 0.5, s.axis_row]]))
    ax.plot(corners[:, 0], corners[:, 1], color="tab:red", lw=4, label="sensor (tilted)")
    sens_line = np.array([g.scheimpflug_point_mm, g.image_hinge_mm + 0.3 * (g.image_hinge_mm - g.scheimpflug_point_mm)])
    ax.plot(sens_line[:, 0], sens_line[:, 1], color="tab:red", lw=0.8, ls="--", label="sensor plane")
    ax.plot([0, 0], [-0.35 * d, 1.1 * d], color="k", lw=1.0, label="lens plane")
    ax.plot([-f, -f], [-0.35 * d, 1.1 * d], color="0.5", lw=0.8, ls=":", label="focal planes")
    ax.plot([f, f], [-0.35 * d, 1.1 * d], color="0.5", lw=0.8, ls=":")
    ax.plot([-1.3 * f, far[0]], [0, 0], color="0.3", lw=0.6, ls="-.", label="optical axis")
    ax.plot([0, H[0] * 1.6], [0, H[1] * 1.6], color="tab:green", lw=0.8, ls="--", label="hinge line O→H ∥ sensor")
    for pt, name in ((H, "H"), (g.image_hinge_mm, "H'"), (g.scheimpflug_point_mm, "O'"), (np.zeros(3), "O")):
        ax.plot(pt[0], pt[1], "ko", ms=3)
        ax.annotate(name, (pt[0], pt[1]), textcoords="offset points", xytext=(4, 4))
    for Dk in (D[0], D[1]) if annotate else ():
        p = H + Dk * g.propagation_dir
        ax.annotate(f"D = {Dk:.1f} mm", (p[0], p[1]), textcoords="offset points", xytext=(0, 10),
                    ha="center", fontsize=8)


def _draw_curves(ax, rig: Rig) -> None:
    g = hinge_geometry(rig)
    s = rig.sensor
    u = np.linspace(0.0, s.columns - 1.0, 200)
    D = g.distance_from_column(u)
    ax.plot(D, g.distance_resolution(u) * 1e3, color="tab:blue", label="distance resolution |dD/du|")
    ax.plot(D, g.height_resolution(u) * 1e3, color="tab:orange", label="height resolution |dh/dv|")
    ax.set_xlabel("distance along the sheet from the object hinge D [mm]")
    ax.set_ylabel("resolution [µm/px]")
    ax.grid(alpha=0.3)
    ax2 = ax.twinx()
    ax2.plot(D, g.height_resolution(u) * s.rows, color="tab:green", ls="--",
             label="height range (full sensor)")
    ax2.set_ylabel("height range [mm]")
    lines = ax.get_lines() + ax2.get_lines()
    ax.legend(lines, [ln.get_label() for ln in lines], fontsize=8, loc="upper left")
    ax.set_title("resolution and height range vs distance (Eqs. 11–12)")
