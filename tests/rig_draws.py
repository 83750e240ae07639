"""Seeded random rigs nobody tuned for (test and benchmark helper).

A rig is drawn in the ranges of issue 16: f 12–100 mm, d 50–400 mm,
tan φ −0.3 … 0.5, pitch 2–10 µm, a sensor whose long side has 640–5000 px
and short side 480–4000 px (aspect 1.2–1.8, mounted landscape or portrait),
the image hinge 1.5–3.5 sensor widths beyond column 0 and the axis row in the
middle 40 % of the rows.  Only the lens, the sheet geometry and the sensor
geometry are drawn: everything else (stages, plate, laser waist, exposure)
takes the rig-aware defaults of :mod:`scheimpflug.model.plan`.  Draws with
d − f·tan φ < 0.2·d (the sensor tilted past ≈ 80°) are redrawn.

The binning that keeps a test short: ``k = max(1, min(columns // 400,
rows // 300))``, at most 2 when the binned sensor would keep fewer than 240
rows (the plate needs rows for both edges and their margins).
"""

from __future__ import annotations

import numpy as np

__all__ = ["binning_for", "draw_rig", "draw_rigs"]


def draw_rig(rng: np.random.Generator) -> dict:
    """One random rig as rig-file tables (lens, laser, sensor geometry only)."""
    while True:
        f = float(rng.uniform(12.0, 100.0))
        d = float(rng.uniform(50.0, 400.0))
        t = float(rng.uniform(-0.3, 0.5))
        if d - f * t >= 0.2 * d:
            break
    long_side = int(rng.integers(640, 5001))
    short_side = int(np.clip(round(long_side / rng.uniform(1.2, 1.8)), 480, 4000))
    columns, rows = (long_side, short_side) if rng.random() < 0.5 else (short_side, long_side)
    return {"lens": {"focal_length_mm": round(f, 3)},
            "laser": {"scheimpflug_distance_mm": round(d, 3), "tan_phi": round(t, 4)},
            "sensor": {"pixel_pitch_um": round(float(rng.uniform(2.0, 10.0)), 3), "columns": columns,
                       "rows": rows, "hinge_column": round(columns * float(rng.uniform(1.5, 3.5)), 2),
                       "axis_row": round(rows * float(rng.uniform(0.3, 0.7)), 2)}}


def draw_rigs(seed: int, n: int) -> list[dict]:
    """``n`` rigs from one seed (the same seed gives the same rigs)."""
    rng = np.random.default_rng(seed)
    return [draw_rig(rng) for _ in range(n)]


def binning_for(columns: int, rows: int) -> int:
    """The k × k binning that keeps a closed-loop test short (module docstring)."""
    k = max(1, min(columns // 400, rows // 300))
    while k > 1 and rows // k < 240:
        k -= 1
    return k
