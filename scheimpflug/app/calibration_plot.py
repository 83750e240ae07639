"""The paper's Fig. 3(b)/(c) for a calibration: endpoint lines and the distance fit.

(b) the plate's top and bottom endpoints (v against u) with the two fitted
lines extended to their intersection, the image hinge; (c) stage coordinate
against 1/(u − u_h) with the fitted line whose intercept is d0 (paper Eq. 11),
for the chosen estimate.  Drawn with matplotlib's Agg backend (no display).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from scheimpflug.calibration import CalibrationResult
from scheimpflug.io.atomic import atomic_path

__all__ = ["plot_calibration"]


def plot_calibration(result: CalibrationResult, path: str | Path) -> None:
    """Write the two-panel calibration figure to ``path`` (PNG/PDF/SVG by extension)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cal, pap = result.best, result.paper
    top = np.array([m.top_px for m in result.measurements if m.top_px is not None])
    bot = np.array([m.bottom_px for m in result.measurements if m.bottom_px is not None])
    s = np.array([m.stage_mm for m in result.measurements])
    u = np.array([m.u_mean_px for m in result.measurements])
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.5))
    uu = np.linspace(0.0, pap.hinge_u_px * 1.02, 200)
    for pts, (m, b), name, colour in ((top, result.top_line, "top", "C0"),
                                      (bot, result.bottom_line, "bottom", "C1")):
        ax1.plot(pts[:, 0], pts[:, 1], "o", ms=3, color=colour, label=f"{name} endpoints")
        ax1.plot(uu, m * uu + b, "-", lw=0.8, color=colour,
                 label=f"v = {m:.4f} u + {b:.1f}")
    ax1.plot([pap.hinge_u_px], [pap.hinge_v_px], "k+", ms=10,
             label=f"hinge ({pap.hinge_u_px:.1f}, {pap.hinge_v_px:.1f})")
    ax1.invert_yaxis()
    ax1.set_xlabel("column u [px]")
    ax1.set_ylabel("row v [px]")
    ax1.set_title(f"(b) endpoint fits, R² = {pap.endpoint_fit_r2[0]:.7f} / "
                  f"{pap.endpoint_fit_r2[1]:.7f}")
    ax1.legend(fontsize=7)
    x = 1.0 / (u - cal.hinge_u_px)
    xx = np.linspace(x.min(), x.max(), 50)
    ax2.plot(1e3 * x, s, "o", ms=3, label="frames")
    ax2.plot(1e3 * xx, cal.F2_px_mm * xx + cal.d0_mm, "-", lw=0.8,
             label=f"s = {cal.F2_px_mm:.6g}·x + ({cal.d0_mm:.3f})")
    ax2.set_xlabel("x = 1 / (u − u_h) [10⁻³ / px]")
    ax2.set_ylabel("stage coordinate s [mm]")
    ax2.set_title(f"(c) distance fit ({cal.method}): d0 = {cal.d0_mm:.2f} mm")
    ax2.legend(fontsize=7)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120)
    plt.close(fig)
