"""
A scanned cloud coloured by its error
=====================================

The whole chain on a 4 × 4 binned sensor: calibrate from plate frames, locate
the rotary axis from a blocker, scan the knurled cylinder in 15° steps,
reconstruct the cloud and measure every point's signed distance to the mesh the
twin rendered. The knurled band at the bottom and the occlusion edges show up
at once.
"""

import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from scheimpflug import (
                         PointToMesh,
                         calibrate_folder,
                         distance_stats,
                         extract_folder,
                         load_preset,
                         locate_axis,
                         open_frame_folder,
                         read_mesh,
                         reconstruct_profiles,
)
from scheimpflug.model.binning import binned_rig
from sim import render_folder

rig = binned_rig(load_preset("paper"), 4)
out = Path(tempfile.mkdtemp(prefix="scheimpflug-scan-"))
render_folder(rig, "calibration", out / "cal", steps=9, step_mm=26.0, start_mm=31.0, truth_pixels_every=0)
render_folder(rig, "blocker", out / "blk", truth_pixels_every=0)
render_folder(rig, "rotary", out / "scan", part="cylinder", step_deg=15.0, truth_pixels_every=0)

calibration = calibrate_folder(out / "cal").best
axis_mm = locate_axis(out / "blk", calibration).axis_mm
scan = open_frame_folder(out / "scan")
rows, us, peaks, _ = extract_folder(scan, "cog")
cloud = reconstruct_profiles(rows, us, [f.angle_deg for f in scan.frames], calibration, axis_mm)

vertices, faces, _ = read_mesh(out / "scan" / "truth" / "mesh.ply")
d = PointToMesh(vertices, faces).query(cloud.xyz_mm)
stats = distance_stats(d.distance_mm, d.signed)
print(f"axis {axis_mm:.3f} mm; {len(cloud)} points; RMS {stats['rms_mm']:.4f} mm, "
      f"p95 {stats['p95_mm']:.4f} mm, max {stats['max_mm']:.4f} mm")

# %%
# The cylinder unrolled: angle round the axis against height, each point
# coloured by its signed distance to the true surface (outside positive).

xyz = cloud.xyz_mm
theta = np.degrees(np.arctan2(xyz[:, 1], xyz[:, 0]))
lim = np.percentile(np.abs(d.distance_mm), 99)
fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(11, 4.8), gridspec_kw={"width_ratios": [2, 1]})
sc = ax0.scatter(theta, xyz[:, 2], c=d.distance_mm, s=1.5, cmap="coolwarm", vmin=-lim, vmax=lim)
fig.colorbar(sc, ax=ax0, label="signed distance to the mesh [mm]")
ax0.set(xlabel="angle round the axis [deg]", ylabel="height z [mm]", title="cylinder, unrolled")

ax1.hist(d.distance_mm, bins=80, range=(-lim, lim), color="0.3")
ax1.set(xlabel="signed distance [mm]", ylabel="points", title=f"RMS {stats['rms_mm'] * 1000:.1f} µm")
fig.tight_layout()
