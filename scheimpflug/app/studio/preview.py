"""A preview frame: the part on the rotary table at a table angle, rendered by the twin, binned.

The library's render (:func:`sim.writer.render_folder`, scenario ``rotary``) of the rig binned k × k
(:func:`scheimpflug.model.binning.binned_rig`) into a temporary frame folder; the frame is returned
as an 8-bit PNG for the page (the 16-bit frame scaled to its brightest pixel).  The rotary scenario
turns the table by i·step from 0, so an angle θ ≠ 0 is the second frame of a two-frame run at step
θ.  One render at a time (it takes both cores); of the requests waiting,
only the newest renders — the others answer at once that a newer one came (:class:`Superseded`).
"""

from __future__ import annotations

import tempfile
import threading
import time
from pathlib import Path

from scheimpflug.errors import ScheimpflugError
from scheimpflug.model.binning import binned_rig
from scheimpflug.model.rig import Rig

__all__ = ["MAX_PREVIEW_PIXELS", "PreviewQueue", "Superseded", "render_preview"]

MAX_PREVIEW_PIXELS = 2_000_000
"""Largest binned frame a preview renders [px] (the paper sensor binned 4 × 4: 0.15 Mpx)."""


class Superseded(ScheimpflugError):
    """A newer preview was asked for while this one waited: it is not rendered."""


def render_preview(rig: Rig, part: str, angle_deg: float, binning: int = 4,
                   cache: dict | None = None, source: str | None = None) -> tuple[bytes, float]:
    """Render one binned frame of a preset part at a table angle.

    Parameters
    ----------
    rig : Rig
        The instrument (full resolution; binned here).
    part : str
        A preset part of :data:`scenes.PART_NAMES`.
    angle_deg : float
        Table angle [deg], in [0, 360).
    binning : int, default 4
        k of the k × k binned sensor [-].
    cache : dict, optional
        Keeps the last part built (:func:`sim.scenarios.reuse_assemblies`: a million-face part costs
        ≈ 0.4 s to build) across calls.
    source : str, optional
        A mesh file to render instead of the preset (an upload the server checked).

    Returns
    -------
    png : bytes
        The frame as an 8-bit grey PNG, scaled to its brightest pixel.
    seconds : float
        The render's wall time [s].

    Raises
    ------
    MeshError
        For an unknown part.
    ScheimpflugError
        For a binned frame of more than :data:`MAX_PREVIEW_PIXELS`.
    RenderError
        When the renderer cannot start.
    """
    import cv2
    import numpy as np

    from scheimpflug.app.studio.occlusion import check_part
    from sim.scenarios import reuse_assemblies
    from sim.writer import render_folder

    if source is None:
        check_part(part)
    angle = float(angle_deg) % 360.0
    small = binned_rig(rig, binning)
    pixels = small.sensor.columns * small.sensor.rows
    if pixels > MAX_PREVIEW_PIXELS:
        raise ScheimpflugError(f"a preview of {small.sensor.columns} × {small.sensor.rows} px ({binning} × {binning} "
                               f"binned): at most {MAX_PREVIEW_PIXELS / 1e6:g} Mpx; use the render command")
    options = {"step_deg": 360.0, "frames": 1} if angle == 0 else {"step_deg": angle, "frames": 2}
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="studio-preview-") as tmp, reuse_assemblies({} if cache is None else cache):
        out = Path(tmp) / "frames"
        render_folder(small, "rotary", out, part=part if source is None else source, warn=lambda _line: None,
                      **options)
        name = sorted((out / "frames").glob("*.png"))[-1]
        image = cv2.imread(str(name), cv2.IMREAD_UNCHANGED)
    seconds = time.perf_counter() - t0
    top = float(max(image.max(), 1))            # shown scaled to its brightest pixel: the stripe white
    ok, png = cv2.imencode(".png", np.clip(image.astype(np.float64) * (255.0 / top), 0, 255).astype(np.uint8))
    if not ok:
        raise ScheimpflugError("the preview frame could not be encoded as PNG")
    return png.tobytes(), seconds


class PreviewQueue:
    """One preview render at a time; of the requests waiting, only the newest renders."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._newest = 0
        self._count = threading.Lock()
        self._parts: dict = {}          # the last part built, reused by the next render

    def render(self, rig: Rig, part: str, angle_deg: float, binning: int = 4,
               source: str | None = None) -> tuple[bytes, float]:
        """:func:`render_preview`, unless a newer request came while this one waited.

        Raises
        ------
        Superseded
            A newer request came first: this one is not rendered.
        """
        with self._count:
            self._newest += 1
            mine = self._newest
        with self._lock:
            if mine != self._newest:
                raise Superseded("a newer preview was asked for: this one is not rendered")
            return render_preview(rig, part, angle_deg, binning, cache=self._parts, source=source)
