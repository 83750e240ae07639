"""Pictures of a comparison of real frames with a twin's (``scheimpflug compare --report DIR``).

* ``frame_NNNN.png`` per chosen pair (NNNN its real frame): per region, the real frame, the twin's and their difference
  (twin − real), cropped around the stripe, the stripe running left to right (the frame as stored
  for a stripe along the rows; transposed otherwise), the detected centres marked;
* ``profiles.png``: per region, the mean profile across the stripe, real and twin overlaid, linear
  and logarithmic (the halo and the background show on the second);
* ``positions.png``: per region, the histogram of the position differences twin − real.
"""

from __future__ import annotations

import math

import numpy as np

from scheimpflug.app.plotting import pyplot as _plt
from scheimpflug.app.plotting import save_tight as _save

__all__ = ["CROP_MARGIN_PX", "plot_frame_pair", "plot_position_histograms", "plot_profiles"]

CROP_MARGIN_PX = 30
"""Pixels shown across the stripe beyond its detected centres, each side [px]."""
_REAL, _TWIN = "#1f5fa8", "#d2553a"




def _crop(lines: np.ndarray, pos: np.ndarray, n_across: int) -> tuple[int, int] | None:
    """Across-stripe range showing the region's detected centres with a margin, or None."""
    p = pos[np.isfinite(pos)]
    if not len(p):
        return None
    lo = max(int(math.floor(p.min())) - CROP_MARGIN_PX, 0)
    hi = min(int(math.ceil(p.max())) + CROP_MARGIN_PX, n_across - 1)
    return lo, hi


def plot_frame_pair(real_frame: np.ndarray, twin_frame: np.ndarray, lines: dict, real_pos: dict,
                    twin_pos: dict, title: str, path, *, saturation_dn: float) -> None:
    """One pair of frames, per region: real | twin | twin − real, cropped around the stripe.

    Parameters
    ----------
    real_frame, twin_frame : (lines, across) ndarray
        The two frames as the detector reads them (:func:`scheimpflug.stripe.oriented`) [DN].
    lines : dict of str to ndarray int64
        Per region, its lines [px].
    real_pos, twin_pos : dict of str to (m_r,) ndarray float64
        Per region, the detected centres in this frame (NaN where none) [px].
    title : str
        The figure's title.
    path : str or Path
        PNG to write.
    saturation_dn : float
        Top of the grey scale [DN].
    """
    plt = _plt()
    shown = []
    for r, ln in lines.items():
        both = np.concatenate([real_pos[r], twin_pos[r]])
        crop = _crop(ln, both, real_frame.shape[1])
        if crop is not None:
            shown.append((r, ln, crop))
    if not shown:
        shown = [(r, ln, (0, real_frame.shape[1] - 1)) for r, ln in lines.items()]
    aspects = [(hi - lo + 1) / max(len(ln), 1) for _, ln, (lo, hi) in shown]
    heights = [min(max(a * 4.6, 1.2), 6.0) for a in aspects]
    fig, axes = plt.subplots(len(shown), 3, figsize=(16, sum(heights) + 0.9 * len(shown) + 0.8),
                             gridspec_kw={"height_ratios": heights}, squeeze=False)
    for k, (r, ln, (lo, hi)) in enumerate(shown):
        a, b = int(ln[0]), int(ln[-1])
        real = real_frame[a:b + 1, lo:hi + 1].astype(np.float64).T
        twin = twin_frame[a:b + 1, lo:hi + 1].astype(np.float64).T
        diff = twin - real
        top = max(float(np.nanmax(real)) if real.size else 1.0, float(np.nanmax(twin)) if twin.size else 1.0, 1.0)
        lim = max(float(np.nanmax(np.abs(diff))) if diff.size else 1.0, 1.0)
        ext = (a - 0.5, b + 0.5, hi + 0.5, lo - 0.5)
        for c, (img, name, cmap, vmin, vmax) in enumerate((
                (real, "real", "gray", 0.0, top), (twin, "twin", "gray", 0.0, top),
                (diff, "twin − real", "RdBu_r", -lim, lim))):
            ax = axes[k, c]
            im = ax.imshow(img, cmap=cmap, vmin=vmin, vmax=vmax, extent=ext, aspect="equal",
                           interpolation="antialiased")
            ax.set_title(f"{r}: {name}", fontsize=10, loc="left")
            ax.set_xlabel("along the stripe [px]", fontsize=8)
            ax.tick_params(labelsize=8)
            if c == 0:
                ax.set_ylabel("across [px]", fontsize=8)
            fig.colorbar(im, ax=ax, pad=0.02, fraction=0.04, shrink=0.9).set_label("DN", fontsize=8)
    fig.suptitle(f"{title}  (grey scale to the brighter crop's maximum; saturation at {saturation_dn:g} DN)",
                 fontsize=11)
    fig.tight_layout()
    _save(fig, path)


def plot_profiles(real_profiles: dict, twin_profiles: dict, real_fwhm: dict, path) -> None:
    """Per region, the mean profile across the stripe (median over frames), real and twin overlaid.

    Parameters
    ----------
    real_profiles, twin_profiles : dict of str to (n, 2 R + 1) ndarray float64
        :attr:`scheimpflug.compare.figures.FolderMeasures.profiles` [DN].
    real_fwhm : dict of str to float
        Per region, the real stripe's FWHM (the ±3 FWHM core marked) [px].
    path : str or Path
        PNG to write.
    """
    plt = _plt()
    names = list(real_profiles)
    fig, axes = plt.subplots(2, len(names), figsize=(4.2 * len(names) + 0.8, 7.2), squeeze=False)
    for j, r in enumerate(names):
        reach = (real_profiles[r].shape[1] - 1) // 2
        d = np.arange(-reach, reach + 1)
        for row, log in enumerate((False, True)):
            ax = axes[row, j]
            for prof, label, colour, style, lw in ((real_profiles[r], "real", _REAL, "-", 2.2),
                                                   (twin_profiles[r], "twin", _TWIN, "--", 1.3)):
                y = _median_rows(prof)
                if log:
                    y = np.where(y > 0, y, np.nan)
                ax.plot(d, y, style, color=colour, label=label, lw=lw)
            w = real_fwhm.get(r, math.nan)
            if math.isfinite(w):
                for s in (-3 * w, 3 * w):
                    ax.axvline(s, color="0.6", ls="--", lw=0.8)
                ax.set_xlim(-min(reach, 3 * w + 48), min(reach, 3 * w + 48))   # out to the background window
            if log:
                ax.set_yscale("log")
            ax.set_xlabel("across the stripe, from its centre pixel [px]")
            ax.set_ylabel("level [DN], median over frames" + (" (log)" if log else ""), fontsize=9)
            ax.grid(alpha=0.3)
            if row == 0:
                ax.set_title(r)
                ax.legend(fontsize=9, title="dashed: ±3 FWHM (real)", title_fontsize=8)
    fig.tight_layout()
    _save(fig, path)


def _median_rows(prof: np.ndarray) -> np.ndarray:
    out = np.full(prof.shape[1], np.nan)
    ok = np.isfinite(prof).any(axis=0)
    if ok.any():
        out[ok] = np.nanmedian(prof[:, ok], axis=0)
    return out


def plot_position_histograms(diffs: dict, path) -> None:
    """Per region, the histogram of the stripe position differences twin − real.

    Parameters
    ----------
    diffs : dict of str to ndarray float64
        :func:`scheimpflug.compare.summary.position_differences` [px].
    path : str or Path
        PNG to write.
    """
    plt = _plt()
    names = list(diffs)
    fig, axes = plt.subplots(1, len(names), figsize=(4.2 * len(names) + 0.8, 3.6), squeeze=False)
    for j, r in enumerate(names):
        ax, d = axes[0, j], diffs[r]
        if len(d):
            lim = max(float(np.percentile(np.abs(d), 99)), 0.5)
            ax.hist(np.clip(d, -lim, lim), bins=61, range=(-lim, lim), color="0.35")
            rms, mean = float(np.sqrt(np.mean(d ** 2))), float(np.mean(d))
            ax.set_title(f"{r}: rms {rms:.3f}, mean {mean:+.3f} px\n{len(d)} line pairs", fontsize=10)
        else:
            ax.set_title(f"{r}: no line with the stripe in both", fontsize=10)
        ax.set_xlabel("position twin − real [px] (clipped at the 99th percentile)")
        ax.set_ylabel("lines")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    _save(fig, path)
