"""
The paper's calibration fits
============================

Nine frames of the 89 mm plate on the translation stage, rendered on a 4 × 4
binned sensor, then calibrated from the frames alone as in the paper (Fig. 3):
the plate's top and bottom endpoints lie on two lines through the image hinge
(Eq. 8), and the stage position is linear in 1/(u − u_h) with slope F² and
intercept d0 (Eq. 11).
"""

import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from scheimpflug import calibrate_folder, load_preset
from scheimpflug.model.binning import binned_rig
from scheimpflug.model.hinge import hinge_geometry
from sim import render_folder

rig = binned_rig(load_preset("paper"), 4)
out = Path(tempfile.mkdtemp(prefix="scheimpflug-cal-"))
render_folder(rig, "calibration", out / "cal", steps=9, step_mm=26.0, start_mm=31.0)

result = calibrate_folder(out / "cal")
cal, truth = result.best, hinge_geometry(rig)
print(f"estimate used: {cal.method}")
print(f"hinge (u_h, v_h) = ({cal.hinge_u_px:.2f}, {cal.hinge_v_px:.2f}) px   design "
      f"({truth.hinge_column:.2f}, {truth.axis_row:.2f})")
print(f"F² = {cal.F2_px_mm:.6g} px·mm (σ {cal.F2_sigma_px_mm:.3g})   design {truth.F2_px_mm:.6g}")
print(f"d0 = {cal.d0_mm:.3f} mm   C = {cal.C_mm:.3f} mm (σ {cal.C_sigma_mm:.3g})   design C {truth.C_mm:.3f}")

# %%
# Left: the endpoints and their two fitted lines, which meet at the image
# hinge beyond the sensor's last column. Right: the stage position against
# 1/(u − u_h), a straight line.

m = result.measurements
top = np.array([x.top_px for x in m if x.top_px is not None])
bottom = np.array([x.bottom_px for x in m if x.bottom_px is not None])
uu = np.linspace(0, cal.hinge_u_px, 50)

fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(11, 4.6))
ax0.plot(top[:, 0], top[:, 1], "o", label="top endpoints")
ax0.plot(bottom[:, 0], bottom[:, 1], "s", label="bottom endpoints")
for (slope, intercept), style in ((result.top_line, "C0-"), (result.bottom_line, "C1-")):
    ax0.plot(uu, slope * uu + intercept, style, lw=0.8)
ax0.plot(cal.hinge_u_px, cal.hinge_v_px, "k*", ms=12, label="image hinge")
ax0.axvspan(0, rig.sensor.columns - 1, color="0.9", zorder=0, label="sensor")
ax0.invert_yaxis()
ax0.set(xlabel="column u [px]", ylabel="row v [px]", title="endpoint lines (paper Fig. 3b)")
ax0.legend(fontsize=9)

u = np.array([x.u_mean_px for x in m])
s = np.array([x.stage_mm for x in m])
x = 1.0 / (u - cal.hinge_u_px)
ax1.plot(x, s, "o", label="frames")
ax1.plot(x, cal.F2_px_mm * x + cal.d0_mm, "-", lw=0.8, label="s = F²/(u − u_h) + d0")
ax1.set(xlabel="1 / (u − u_h) [1/px]", ylabel="stage position s [mm]", title="distance fit (paper Fig. 3c)")
ax1.legend(fontsize=9)
fig.tight_layout()
