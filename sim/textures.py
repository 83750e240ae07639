"""Albedo textures evaluated in Dr.Jit at a hit's texture coordinates (u, v) [mm].

A part's ``texture`` (:class:`scenes.Part`) is a dict; this module turns it
into a Dr.Jit function of the hit's interpolated vertex texture coordinates
(``SurfaceInteraction3f.uv``, millimetres): the renderer multiplies a textured
part's BSDF (a matte Lambertian of albedo 1, :mod:`sim.scene`) by it.  The
same functions as :func:`scenes.patterns.texture_albedo` (the numpy
reference), written once more for the JIT:

* patterns (chessboard, ChArUco, circles: :mod:`scenes.patterns`) exactly —
  no texels: an edge is sharp wherever the pixel and aperture samples land,
  so the camera's anti-aliasing is the pixel's area and the lens's blur only;
* ``image``: bilinear between texel centres, clamped at the edges;
* ``uniform``: one albedo.
"""

from __future__ import annotations

import numpy as np

__all__ = ["TextureFunction", "texture_function"]


class TextureFunction:
    """A texture dict as a Dr.Jit function ``albedo(uv)``.

    Parameters
    ----------
    texture : dict
        The texture (:func:`scenes.patterns.texture_albedo` lists the kinds).
    mi : module
        The ``mitsuba`` module (a JIT variant set).
    dr : module
        The ``drjit`` module.

    Raises
    ------
    ValueError
        For an unknown texture kind.
    """

    def __init__(self, texture: dict, mi, dr) -> None:
        self._mi, self._dr, self.t = mi, dr, texture
        kind = texture.get("kind")
        if kind not in ("chessboard", "charuco", "circles", "image", "uniform"):
            raise ValueError(f"texture kind {kind!r} unknown (known: chessboard, charuco, circles, "
                             "image, uniform)")
        self.kind = kind
        if kind == "charuco":
            self._charuco_tables()
        if kind == "image":
            img = np.asarray(texture["albedo"], dtype=np.float32)
            self._h, self._w = img.shape
            self._img = mi.Float(np.ascontiguousarray(img).ravel())

    def _charuco_tables(self) -> None:
        mi, t = self._mi, self.t
        self._slot = mi.Int32(np.asarray(t["square_marker"], np.int32).ravel())
        origin = np.asarray(t["marker_origin_mm"], np.float32)
        self._ox, self._oy = mi.Float(origin[:, 0].copy()), mi.Float(origin[:, 1].copy())
        bits = np.asarray(t["marker_bits"], np.float32)
        self._cells = int(bits.shape[1])
        self._bits = mi.Float(bits.ravel())

    def __call__(self, uv):
        """Albedo at texture coordinates.

        Parameters
        ----------
        uv : mitsuba.Point2f
            Texture coordinates [mm].

        Returns
        -------
        mitsuba.Float
            The albedo [-].
        """
        if self.kind == "uniform":
            return self._mi.Float(float(self.t["albedo"])) + 0.0 * uv.x
        if self.kind == "image":
            return self._image(uv)
        ink = self._ink(uv.x, uv.y)
        return self._dr.select(ink, float(self.t["black"]), float(self.t["white"]))

    def _ink(self, x, y):
        mi, dr, t = self._mi, self._dr, self.t
        s = float(t["pitch_mm"])
        if self.kind == "circles":
            i = dr.clip(dr.round(x / s), 0.0, t["cols"] - 1.0)
            j = dr.clip(dr.round(y / s), 0.0, t["rows"] - 1.0)
            dx, dy = x - i * s, y - j * s
            return dx * dx + dy * dy <= (0.5 * float(t["diameter_mm"])) ** 2
        n_c, n_r = (t["cols"] + 1, t["rows"] + 1) if self.kind == "chessboard" else (t["cols"], t["rows"])
        first_black = True if self.kind == "chessboard" else bool(t["first_black"])
        i = mi.Int32(dr.floor(x / s)) + 1
        j = mi.Int32(dr.floor(y / s)) + 1
        inside = (i >= 0) & (i < n_c) & (j >= 0) & (j < n_r)
        even = ((i + j) & 1) == 0
        black = even if first_black else ~even
        if self.kind == "chessboard":
            return inside & black
        return inside & (black | self._marker_ink(x, y, i, j, inside, n_c, n_r))

    def _marker_ink(self, x, y, i, j, inside, n_c: int, n_r: int):
        mi, dr = self._mi, self._dr
        ic, jc = dr.clip(i, 0, n_c - 1), dr.clip(j, 0, n_r - 1)
        slot = dr.gather(mi.Int32, self._slot, mi.UInt32(jc * n_c + ic), inside)
        has = inside & (slot >= 0)
        k = mi.UInt32(dr.maximum(slot, 0))
        ox, oy = dr.gather(mi.Float, self._ox, k, has), dr.gather(mi.Float, self._oy, k, has)
        n = self._cells
        cell = float(self.t["marker_mm"]) / n
        a = mi.Int32(dr.floor((x - ox) / cell))
        b = mi.Int32(dr.floor((y - oy) / cell))
        in_marker = has & (a >= 0) & (a < n) & (b >= 0) & (b < n)
        idx = k * (n * n) + mi.UInt32(dr.clip(b, 0, n - 1) * n + dr.clip(a, 0, n - 1))
        white = dr.gather(mi.Float, self._bits, idx, in_marker) > 0.5
        return in_marker & ~white

    def _image(self, uv):
        mi, dr, t = self._mi, self._dr, self.t
        u0, v0, u1, v1 = (float(c) for c in t["extent_mm"])
        w, h = self._w, self._h
        fx = dr.clip((uv.x - u0) * (w / (u1 - u0)) - 0.5, 0.0, w - 1.0)
        fy = dr.clip((uv.y - v0) * (h / (v1 - v0)) - 0.5, 0.0, h - 1.0)
        c0 = dr.minimum(mi.Int32(dr.floor(fx)), max(w - 2, 0))
        r0 = dr.minimum(mi.Int32(dr.floor(fy)), max(h - 2, 0))
        c1, r1 = dr.minimum(c0 + 1, w - 1), dr.minimum(r0 + 1, h - 1)
        ax, ay = fx - mi.Float(c0), fy - mi.Float(r0)

        def at(r, c):
            return dr.gather(mi.Float, self._img, mi.UInt32(r * w + c))

        top = at(r0, c0) * (1.0 - ax) + at(r0, c1) * ax
        bottom = at(r1, c0) * (1.0 - ax) + at(r1, c1) * ax
        return top * (1.0 - ay) + bottom * ay


def texture_function(texture: dict, mi, dr) -> TextureFunction:
    """The Dr.Jit albedo function of a texture dict.

    Parameters
    ----------
    texture : dict
        The texture (:func:`scenes.patterns.texture_albedo`).
    mi : module
        The ``mitsuba`` module (a JIT variant set).
    dr : module
        The ``drjit`` module.

    Returns
    -------
    TextureFunction
        ``albedo(uv: mi.Point2f) -> mi.Float``.

    Raises
    ------
    ValueError
        For an unknown texture kind.
    """
    return TextureFunction(texture, mi, dr)
