"""
A rendered frame with its truth overlaid
========================================

The digital twin renders a frame of the paper's pile (a knurled ring under a
cardboard box under a tape roll) on the rotary stage
and writes, beside the 16-bit PNG, the exact stripe centre of every sensor row
from geometry. Here both are read back and the truth is drawn over the frame.
A 4 × 4 binned sensor keeps it to a few seconds.
"""

import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from scheimpflug import load_preset, open_frame_folder
from scheimpflug.model.binning import binned_rig
from sim import render_folder

rig = binned_rig(load_preset("paper"), 4)             # 304 × 484 px, the same geometry
out = Path(tempfile.mkdtemp(prefix="scheimpflug-frame-"))
render_folder(rig, "rotary", out / "scan", part="pile", step_deg=90.0, truth_pixels_every=0)

folder = open_frame_folder(out / "scan")
image = folder.read(0)                                 # (rows, columns) uint16, raw ADC value
truth = np.load(out / "scan" / "truth" / "00000.npz")   # frame 0's exact truth
stripe_u = truth["stripe_u"]                           # (rows,) exact stripe centre [px], NaN = none
print(f"{len(folder)} frames of {image.shape[1]} × {image.shape[0]} px; "
      f"{np.isfinite(stripe_u).sum()} rows with a stripe; truth arrays: {sorted(truth.files)[:6]} …")

# %%
# The frame (left) and a close-up of the stripe with the exact centres (right):
# columns run along the sheet (distance), rows along height.

rows = np.arange(image.shape[0])
fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(11, 5.5), gridspec_kw={"width_ratios": [1, 1.3]})
ax0.imshow(image, cmap="gray", vmax=np.percentile(image, 99.9), aspect="auto")
ax0.plot(stripe_u[::3] + 6, rows[::3], ".", color="tab:red", ms=1.5, label="exact stripe centre (shifted 6 px)")
ax0.set(title="rendered frame, the pile at 0°", xlabel="column u [px]", ylabel="row v [px]")
ax0.legend(loc="lower left")

lit = np.flatnonzero(np.isfinite(stripe_u))
r0, r1 = lit[len(lit) // 2] - 15, lit[len(lit) // 2] + 15
u0 = int(np.nanmin(stripe_u[r0:r1])) - 6
crop = image[r0:r1, u0:u0 + 14]
ax1.imshow(crop, cmap="magma", extent=(u0 - 0.5, u0 + 13.5, r1 - 0.5, r0 - 0.5), aspect="auto")
ax1.plot(stripe_u[r0:r1], rows[r0:r1], "o", color="cyan", ms=4, label="exact centre per row")
ax1.set(title="close-up: 30 rows of the stripe", xlabel="column u [px]", ylabel="row v [px]")
ax1.legend(loc="lower left")
fig.tight_layout()
