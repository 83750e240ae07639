"""Matplotlib for the reports' figures: the Agg backend, PNGs written atomically."""

from __future__ import annotations

from pathlib import Path

from scheimpflug.io.atomic import atomic_path

__all__ = ["pyplot", "save_tight"]


def pyplot():
    """``matplotlib.pyplot`` on the Agg backend (no display needed).

    Returns
    -------
    module
        ``matplotlib.pyplot``.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_tight(fig, path) -> None:
    """Write a figure as a PNG (110 dpi, tight bounding box) atomically, then close it.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        The figure.
    path : str or Path
        The PNG file.
    """
    with atomic_path(Path(path)) as tmp:
        fig.savefig(tmp, dpi=110, bbox_inches="tight", format="png")
    pyplot().close(fig)
