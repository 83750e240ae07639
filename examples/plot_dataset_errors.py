"""
A regression dataset and a detector's error histogram
=====================================================

Two seeded samples of the cylinder on the rotary stage (4 frames each, a 4 × 4
binned sensor, the sensor roll drawn per sample), made into a dataset folder
with an index; then a stripe detector is scored against the exact stripe
centre of every row — the same statistics as ``scheimpflug dataset score``.
"""

import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from scheimpflug.dataset import open_dataset, score_dataset
from scheimpflug.stripe import extract_stripes
from sim.dataset import make_dataset, parse_spec

spec = parse_spec({
    "dataset": {"seed": 1, "samples": 2, "name": "gallery"},
    "rig": {"preset": "paper", "variation": {"sensor.roll_deg": [-0.2, 0.2]}},
    "scenario": {"kind": "rotary", "part": "cylinder", "step_deg": 90.0, "binning": 4},
})
out = Path(tempfile.mkdtemp(prefix="scheimpflug-dataset-")) / "ds"
make_dataset(spec, out)

ds = open_dataset(out)
print(f"{len(ds)} frames; index columns: {ds.index.column_names[:8]} …")
report = score_dataset(ds, "cog")
print({k: round(v, 4) if isinstance(v, float) else v for k, v in report.overall.summary().items()})

# %%
# The same error by hand, row by row: detected minus exact centre, for two of
# the project's detectors. Any function ``detect(frame) -> (rows,) columns``
# can take their place (:doc:`/howto/own-detector`).

errors = {"cog": [], "gaussian3": []}
for frame in ds:
    truth = frame.truth["stripe_u"]
    for method, found in errors.items():
        p = extract_stripes(frame.image, method, window_px="auto")
        e = p.u - truth[p.rows]
        found.append(e[np.isfinite(e)])

fig, ax = plt.subplots(figsize=(8, 4.4))
for method, found in errors.items():
    e = np.concatenate(found)
    ax.hist(e, bins=120, range=(-0.3, 0.3), histtype="step", lw=1.4,
            label=f"{method}: bias {e.mean():+.4f} px, RMS {np.sqrt(np.mean(e ** 2)):.4f} px")
ax.set(xlabel="detected − exact stripe centre [px]", ylabel="rows", title=f"{len(ds)} frames, 2 samples")
ax.legend()
fig.tight_layout()
